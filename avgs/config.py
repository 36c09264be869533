"""Every configurable number of AV-GS, in one place, with the paper's defaults.

Each field carries a one-line docstring (the string literal after it). ``avgs train``
makes one flag of every field of the training configuration, with that docstring as its
help (:mod:`avgs.commands.flags`); a field's ``metadata={"flag": ...}`` names its flag
where the generated name would read badly. Modules receive these objects; none keeps a
default of its own. STFT settings live here and nowhere else. Why each default is what it
is, with the measurements behind it: docs/paper-deviations.md and docs/results.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal


@dataclass(frozen=True)
class STFTConfig:
    """Short-time Fourier transform settings (AV-NeRF's)."""

    sample_rate: int = 22050
    "Audio sample rate in Hz."
    n_fft: int = 512
    "FFT size; gives n_fft // 2 + 1 = 257 frequency bins."
    hop_length: int = 128
    "Hop between frames in samples."
    win_length: int = 512
    "Hann window length in samples."

    @property
    def n_freq(self) -> int:
        return self.n_fft // 2 + 1


@dataclass
class GaussianConfig:
    """Stage 1: the 3D Gaussian Splatting scene G warmed up on RGB views."""

    iterations: int = 3000
    "Warm-up iterations on RGB views (paper: 3k)."
    sh_degree: int = 3
    "Spherical-harmonics degree: (degree + 1)^2 * 3 = 48 colour coefficients."
    ssim_weight: float = 0.2
    "lambda in L = (1 - lambda) L1 + lambda (1 - SSIM)."
    lr_means: float = 1.6e-4
    "Position learning rate (3D-GS), times the scene extent, decays 100x."
    lr_sh0: float = 2.5e-3
    "Learning rate of the DC colour coefficient (3D-GS)."
    lr_shN: float = 2.5e-3 / 20
    "Learning rate of the higher SH coefficients (3D-GS)."
    lr_opacity: float = 0.05
    "Opacity learning rate (3D-GS)."
    lr_scale: float = 5e-3
    "Log-scale learning rate (3D-GS)."
    lr_quat: float = 1e-3
    "Quaternion learning rate (3D-GS)."
    sh_degree_interval: int = 1000
    "Add one SH degree every this many iterations (3D-GS)."
    densify_from: int = 500
    "First iteration of clone/split/prune densification (3D-GS)."
    densify_until: int = 15000
    "Last iteration of densification (3D-GS); the 3k warm-up densifies throughout."
    densify_every: int = 100
    "Densify every this many iterations (3D-GS)."
    densify_grad_threshold: float = 2e-4
    "Mean screen-space gradient above which a Gaussian is cloned or split (3D-GS)."
    reset_opacity_every: int = 3000
    "Reset opacities every this many iterations (3D-GS)."
    prune_opacity: float = 0.005
    "Prune Gaussians whose opacity falls below this (3D-GS)."
    grow_scale3d: float = 0.01
    "Above the gradient threshold, clone Gaussians at most this large (x scene extent), split larger ones (3D-GS)."
    prune_scale3d: float = 0.1
    "After the first opacity reset, prune Gaussians larger than this (x scene extent) (3D-GS)."
    max_gaussians: int = field(default=200_000, metadata={"flag": "max-gaussians"})
    "Hard cap on the number of Gaussians (keeps CPU training and drawing tractable)."
    init_points: int = 20_000
    "Initial points sampled from the scene geometry or a random box."
    image_downscale: int = field(default=1, metadata={"flag": "image-downscale"})
    "Train on frames downscaled by this factor."
    cpu_max_pixels: int = 128 * 96
    "On the CPU with image downscale 1: train on frames shrunk to at most this many pixels, minutes instead of hours (0: as they are)."
    cpu_max_gaussians: int = 20_000
    "On the CPU, when the frames were shrunk for it: at most this many Gaussians."
    backend: Literal["auto", "torch", "gsplat"] = "auto"
    "Rasterizer: gsplat when CUDA is present, else our pure-PyTorch rasterizer."
    log_every: int = 100
    "Write a stage-1 log record (loss, PSNR, Gaussian count) every this many iterations."


@dataclass
class AcousticConfig:
    """Stage 2: audio points G_a, acoustic field network F and binauralizer B."""

    alpha_init: str = "sh+r"
    "Parameters of G that initialise alpha: '+'-joined subset of sh, r, s, o (paper best: sh+r, 52 dims)."
    field_width: int = 64
    "Width of the acoustic field network F (paper: 64)."
    field_layers: int = 3
    "Linear layers of F."
    context_dim: int = 64
    "Output width of F per point; C = C_S (+) C_L has twice this."
    vicinity_percentile: float = 15.0
    "Percent of the audio points nearest the listener (and, separately, the source) used for context."
    binauralizer_width: int = 128
    "Width of the binauralizer MLPs (128 for RWAVS, 256 for RIR)."
    pe_frequencies: int = 10
    "Positional-encoding frequencies of the frequency query (and of Fourier direction features), log-spaced up to 2^(n-1)."
    position_frequencies: int = 4
    "Positional-encoding frequencies of the listener's (x, y), log-spaced up to 2^(n-1) (AV-NeRF: 10)."
    mixture_activation: Literal["relu", "sigmoid"] = "relu"
    "Last activation of the mixture mask: AV-NeRF's unbounded relu or the paper's sigmoid."
    direction_encoding: Literal["fourier", "harmonic"] = "harmonic"
    "Direction feature of B: circular harmonics of theta, or the paper's Fourier features of theta / (1.01 pi)."
    direction_harmonics: int = 4
    "Orders of the harmonic direction feature: cos(n theta), sin(n theta) for n = 1 .. this."
    direction_every_layer: bool = True
    "Give the direction feature to every layer of B's difference MLP (as AV-NeRF adds its direction to each); off: the first layer only (the paper's text)."
    post_conv: bool = False
    "AV-NeRF's optional time-frequency conv head on the ear magnitudes (avgs.acoustics.post_conv)."
    reverb_tail: bool = True
    "Add a learned late-reverberation tail to B's masks (avgs.acoustics.reverb_tail); off: the paper's masks only."
    interaural_delay: bool = True
    "Delay the ears by the spherical head's ITD of the source's direction, its scale fitted to the recordings (avgs.acoustics.interaural); off: both ears at once (the paper's)."
    use_context: bool = field(default=True, metadata={"flag": "context"})
    "Condition B on the scene context C from F (--no-context: the control model without it)."
    lambda_a: float = 1e-4
    "Weight of the volume regulariser L_v (the paper does not state it)."
    iterations: int = 40000
    "Stage-2 iterations (paper: 40k); the impulse-response task runs fewer on a scene of few responses (--rir-passes)."
    batch_size: int = 4
    "Training clips per iteration."
    lr: float = 5e-4
    "Adam learning rate of F and B, linear warm-up over 10 % then decay to 1 % (AV-NeRF)."
    lr_points: float = 1e-4
    "Learning rate of the audio point positions X."
    lr_alpha: float = 1e-3
    "Learning rate of the audio-guidance parameters alpha."
    lr_rt60: float = 1e-2
    "Learning rate of the tail's log RT60 per frequency (log seconds; warm-up and decay as F and B's)."
    warmup_fraction: float = 0.1
    "Fraction of iterations spent in linear learning-rate warm-up."
    final_lr_fraction: float = 0.01
    "Learning rate at the end, as a fraction of the peak."


@dataclass
class PointManagementConfig:
    """Audio-aware point management (paper §3.3): grow where gradients are large, prune outliers."""

    enabled: bool = field(default=True, metadata={"flag": "point-management"})
    "Audio-aware densification and pruning of the audio points."
    grad_threshold: float = 4e-4
    "tau_g (paper: 0.0004): averaged k * ||dL/dX|| above which a vicinity point spawns a new point."
    densify_max_fraction: float = 0.02
    "At most this fraction of the points spawn per densification step (the largest gradients)."
    densify_every: int = 500
    "Densification interval in iterations."
    densify_until_fraction: float = 0.5
    "Stop densifying after this fraction of stage 2."
    spawn_std: float = 0.02
    "Std of the Gaussian around a significant point from which new points are drawn (normalised units)."
    prune_every: int = 3000
    "Open3D radius outlier removal every this many iterations (paper: 3k)."
    prune_min_neighbors: int = 8
    "Points with fewer neighbours than this within the radius are removed (paper: 8)."
    prune_radius: float = 0.1
    "Radius of the outlier test in normalised scene units (paper: 0.1)."
    max_points: int = 60_000
    "Upper bound on the number of audio points."
    initial_points: int = field(default=0, metadata={"flag": "audio-points"})
    "Start G_a from a seeded random subset of this many of G's points (0: all of them, up to max_points)."
    prune_max_fraction: float = 0.5
    "Skip a pruning step that would remove more than this fraction of the points (a sparse G_a, not outliers)."


@dataclass
class RIRConfig:
    """The impulse-response task (SoundSpaces-like, many source positions): the RIR variant of B.

    The paper's appendix: no mixture mask; B's second MLP predicts the response for a time
    input. We predict it in time-frequency form: for a time input (one STFT frame) both ears'
    log magnitudes over all frequency bins (:mod:`avgs.acoustics.rir_binauralizer`); the
    waveform comes from those magnitudes with a phase (:mod:`avgs.acoustics.rir_model`).
    F, G_a, the vicinity, learning rates and iterations are those of :class:`AcousticConfig`.
    """

    width: int = 256
    "Width of the RIR network's MLPs (paper: 256 for RIR)."
    position_frequencies: int = 2
    "Positional-encoding frequencies of the listener's and the source's (x, y, z), log-spaced up to 2^(n-1) (more: memorises the training pairs)."
    time_frequencies: int = 10
    "Positional-encoding frequencies of the time input (the STFT frame, mapped onto [-0.99, 0.99])."
    direction_harmonics: int = 4
    "Orders of the direction feature: cos(n theta), sin(n theta) of the source's direction, and of the yaw, n = 1 .. this."
    arrival_frequencies: int = 0
    "Positional-encoding frequencies of each frame's time relative to the direct sound's arrival (distance / c); 0: off (measured no better on rect_small)."
    sound_speed: float = 0.0
    "Speed of sound in normalised units per second (set from the scene's frame at training: 343 m/s times its scale)."
    distance_slope: bool = False
    "Add the inverse-distance law's term: a learned slope per frame on the log source distance (the previous default; the knee below replaced it: rir_binauralizer.py)."
    distance_knee: bool = True
    "Add the direct-plus-diffuse law's term: per frame, 0.5 log(1 + r_t^2 / d^2) with a learned critical distance r_t (the direct sound's 1 / d near the source, the diffuse field's constant past r_t), relative to its value at the training pairs' mean distance, which a network alone flattens outside the training distances (rir_binauralizer.py)."
    smooth_bins: int = 9
    "The targets' power is averaged over this many neighbouring frequency bins before the log: the network learns the spectral envelope, not the random fine structure of a diffuse tail (1: none)."
    floor_db: float = -80.0
    "Log magnitudes are floored this far below the training responses' loudest STFT bin (rect_small: -60 cuts the decay, T60 38 %; -100 spends the loss on inaudible decay, C50 and EDT worse; -80: T60 25 %, C50 1.2 dB)."
    frames: int = 0
    "STFT frames of a response (0: taken from the scene's responses at training; stored with the checkpoint)."
    length: int = 0
    "Samples of a response (0: the scene's; stored with the checkpoint)."
    energy_weight: float = 1.0
    "Weight of the loss on each ear's energy per frequency bin (the log of the power summed over the frames) and on the ears' difference in it: the direct sound's few frames carry the level and the interaural difference, which the per-frame loss, dominated by the diffuse tail, learns too weakly (two_rooms: ILD 0.29 dB predicted against 1.54 dB true without it, 1.34 dB with it). 0: off."
    decay_weight: float = 1.0
    "Weight of the loss on each ear's energy decay curve (Schroeder; whole band and octave bands; in nats re its start, down to 50 dB): what T60, EDT and C50 read. Without it the per-frame log-magnitude loss averages the decays in the log domain and the predicted T60 comes out short (two_rooms, held out: -17 % bias, T60 error 18.5 %; with it and the energy loss 13.0 %). 0: off."
    direct_sound: bool = True
    "Put the direct sound where geometry says: nothing before distance / c, both ears coherent over its first 5 ms with the lagging ear delayed by the head's ITD (direct_itd; its first 5 ms the leading ear's, delayed and scaled), the early energy kept (avgs.acoustics.direct_placement.place_direct_sound); off: the noise phase from t = 0, the ears independent."
    direct_itd: bool = True
    "With direct_sound: the direct sound's ITD from a law of the source's direction (avgs.acoustics.interaural.itd_law, three sine harmonics) fitted to the early ITDs of the training responses in sight of the source, not from Woodworth's sphere with a fitted scale: a measured head's ITD has its own shape (fewer than 24 such responses: the sphere)."
    direct_ild: bool = True
    "With direct_sound: the early ILD (the first 5 ms) from a law of the source's direction fitted to the training responses in sight of the source (avgs.acoustics.interaural.ild_law, three sine harmonics), not from B's ears: the head shadow is the head's, which B learns from the room's whole response (two_rooms: early ILD error 2.72 / 3.24 -> 1.95 / 2.43 dB, val / held out), where the straight path is free (avgs.acoustics.line_of_sight: G_a's points along it, the threshold fitted to the training pairs' first arrivals); behind a wall, and with this off, B's."
    ild_local: bool = False
    "Off by default since early_reflections, which explain most of what it corrected and reach held-out sources, where it does not (six presets, three seeds, the walls' reflections with / without it: early ILD 1.14 / 1.17 dB on val, 1.17 / 1.06 dB held out). With direct_ild: the law corrected near the training responses in sight of the source by their early ILDs' residual from it (avgs.acoustics.interaural.local_correction: the 3 nearest in listener, source and direction, inverse-distance weighted): the floor's and the near walls' reflections in the first 5 ms depend on where the listener and source are, not on the direction alone (law alone / with this, on the simulator's own responses, held-out sources: 2.0 / 1.5 dB over six presets)."
    ild_table: int = 0
    "Entries of that correction (training responses in sight; set at training, stored with the checkpoint; 0: the law alone)."
    early_reflections: bool = True
    "With direct_ild: the first 5 ms's ILD from the direct sound and the walls' first-order reflections that arrive within them, each given the law at its own direction (avgs.acoustics.early_reflections: walls found in G_a's points by RANSAC, a reflection counted where the points put a wall at its reflection point and both its legs are free), the law and the walls' gain fitted together to the training responses in sight of the source, not from the law of the straight direction alone: the reflections off the walls beside the head arrive from other directions (six presets, three seeds, val / held out: early ILD 1.65 / 1.62 -> 1.17 / 1.06 dB; docs/results.md). No wall found: the law alone."
    reflected_arrival: bool = True
    "With early_reflections: behind a wall (the straight path's test), the first sound's direction (its ITD) and its delay from the shortest first-order reflection off the walls found whose legs are free (avgs.acoustics.early_reflections.first_reflection), each where the training pairs behind a wall are told better by it than by the straight line (their early ITDs, their onsets; the log's `arrival` record); else, and with this off, the straight line's. A simulator without diffraction or transmission brings the first sound behind a wall around through a reflection that passes the door (new scenes, three seeds, the direction chosen in all nine runs, the delay in one; lateralisation val / held out: two_rooms 92 -> 96 / 75 -> 82 %, u_room 85 -> 91 / 81 -> 81 %, three_rooms 63 -> 65 / 83 -> 83 %; on the six-preset table's seed-0 scenes held out +2 to +3 points in three_rooms and u_room, val -3 in u_room, two_rooms keeping the straight line; docs/results.md, the first sound behind a wall)."
    blocked_lag: bool = True
    "With direct_ild: behind a wall (the straight path's test), the first sound at distance / c plus a lag, the median of the training pairs behind a wall's onsets after distance / c (at least 0), where that tells their onsets better than the rule of reflected_arrival does (the log's `lag` record); else, and with this off, that rule's. A simulator without diffraction brings the first sound behind a wall around, later than the straight line and often later than the shortest first-order reflection (two rooms away, the ray-traced arrival, which no geometry here predicts: the shortest free path around the points' walls with its own fitted lag does no better; scripts/unreached_onset_trials.py). Where the training pairs behind a wall hear the direct sound at distance / c (sound through the wall), no lag is fitted. Quick models, seed 0, the same weights without / with it, onset error behind a wall val / held out: two_rooms 4.24 / 3.81 -> 1.59 / 1.29 ms, three_rooms 7.76 / 4.26 -> 4.44 / 3.24 ms (docs/results.md, the first sound behind walls: a fitted lag)."
    blocked_ild: bool = True
    "With direct_ild: behind a wall (the straight path's test), the first 5 ms's ILD B's own times a factor in [0, 1] fitted at the end of training on the training pairs behind a wall (the one of 0, 0.1, .. 1 whose responses' early ILDs are nearest theirs, by the median error; kept where it beats B's own: the log's `blocked_ild` record). A first sound that comes around walls, through a door and off the walls, reaches the two ears from many directions: its early ILD is smaller than the head's shadow of any one direction, and B, whose magnitudes follow the positions, gives it the ILD of nearby pairs in sight (six-preset defaults' checkpoints refitted, three seeds; docs/results.md, the early ILD behind a wall)."
    direct_level: bool = True
    "With direct_sound: the direct sound's energy from geometry where the straight path is free, 1 / d^2 times a gain of the direction (avgs.acoustics.interaural.direct_level_db) fitted to the training responses in sight of the source, taken out of B's first window, which holds it smeared (nearer than the head's radius, its value there: a source typed onto the listener is not 60 dB louder), not from B's first frames alone, which a network of the distance extrapolates near the source (the level against distance, max error over 0.5-5 m, three seeds: u_room 3.8-4.4 -> 1.8-2.2 dB, l_room 1.6-2.7 -> 0.4-0.6 dB; docs/rir_level_distance.md)."
    wall_loss: bool = True
    "With direct_sound: a learned log magnitude per frame that each wall on the straight path adds to the response (the scene's points along the path, within avgs.acoustics.line_of_sight.wall_radius, over the count from which a training pair was behind a wall, at most 3), learned from zero with the network: a term it cannot bend, as the distance law, where positions alone interpolate the level of a held-out source behind a wall from its neighbours in the listener's room (three_rooms, held-out sources behind the wall, three seeds: level error 2.95 -> 2.06 dB, bias +2.3 -> +1.4 dB; docs/rir_level_distance.md). No pair behind a wall in training: no term."
    phase: Literal["noise", "griffin-lim"] = "noise"
    "Waveform from the predicted magnitudes: a fixed-seed noise phase, or that phase refined by fast Griffin-Lim (same T60 / C50 / EDT on rect_small, 2.4x the render time)."
    phase_iterations: int = 4
    "Fast Griffin-Lim iterations with phase griffin-lim."
    eval_responses: int = 64
    "At most this many validation responses get T60 / C50 / EDT at each evaluation (log-magnitude error: all)."
    passes: float = 27.0
    "Stage 2's length in passes over the training responses (iterations = passes x responses / batch size), at least least_iterations and at most acoustic.iterations (the paper's 40k, which SoundSpaces' scenes of thousands of responses fill): a scene of a few hundred responses overfits long before 40k (docs/results.md, 'How long to train the impulse-response task'). 0: acoustic.iterations; giving --iterations sets it to 0."
    least_iterations: int = 3000
    "With passes: stage 2 runs at least this many iterations (four scenes of 228-448 responses: a whole schedule of 3000 is better than one of 6000 on 16 of 24 T60 / C50 / EDT scores, and than 12000 and 40000 on the validation error)."


@dataclass
class TrainConfig:
    """Both stages, bookkeeping and reproducibility."""

    gaussians: GaussianConfig = field(default_factory=GaussianConfig)
    acoustic: AcousticConfig = field(default_factory=AcousticConfig)
    points: PointManagementConfig = field(default_factory=PointManagementConfig)
    stft: STFTConfig = field(default_factory=STFTConfig)
    rir: RIRConfig = field(default_factory=RIRConfig)
    "The impulse-response task's network and synthesis (``avgs train --task rir``)."
    init: Literal["gs", "sfm"] = "gs"
    "Audio points from a warmed-up 3D-GS (gs) or straight from the scene geometry points (sfm)."
    seed: int = 0
    "Random seed; CPU training is reproducible for a fixed seed."
    device: Literal["cpu", "cuda"] = "cpu"
    "Torch device: cpu or cuda."
    checkpoint_every: int = 2000
    "Save the checkpoint atomically every this many stage-2 iterations."
    eval_every: int = 2000
    "Evaluate MAG/ENV on the validation split every this many iterations."
    log_every: int = 50
    "Write a JSON-lines log record every this many iterations."
    store_gaussians: bool = field(default=True, metadata={"flag": "gaussians"})
    "Keep G in the checkpoint (for drawing and listener views); off makes it smaller."

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        """From :meth:`to_dict` output, including that of older versions: unknown keys are
        ignored, a field added later takes the value that reproduces the old behaviour
        (:data:`ADDED_LATER`), and a retired variant (:data:`RETIRED`) is refused with a message."""
        d = dict(d)
        sub = {
            "gaussians": GaussianConfig,
            "acoustic": AcousticConfig,
            "points": PointManagementConfig,
            "stft": STFTConfig,
            "rir": RIRConfig,
        }
        for (section, name), (value, why) in RETIRED.items():
            if isinstance(d.get(section), dict) and d[section].get(name) == value:
                raise ValueError(f"trained with {section}.{name} = {value!r}, which this version no longer has: {why}")
        kwargs = {}
        names = {f.name for f in dataclasses.fields(cls)}
        for k, v in d.items():
            if k not in names:
                continue
            if k in sub:
                known = {f.name for f in dataclasses.fields(sub[k])}
                values = {**ADDED_LATER.get(k, {}), **v}
                kwargs[k] = sub[k](**{kk: vv for kk, vv in values.items() if kk in known})
            else:
                kwargs[k] = v
        return cls(**kwargs)

    def validate(self) -> "TrainConfig":
        """Raise ValueError naming the first value out of range; returns self."""
        g, a, p = self.gaussians, self.acoustic, self.points
        checks = [
            (a.iterations >= 1, "iterations", a.iterations, ">= 1"),
            (g.iterations >= 0, "stage1 iterations", g.iterations, ">= 0"),
            (g.image_downscale >= 1, "image downscale", g.image_downscale, ">= 1"),
            (g.max_gaussians >= 1, "max gaussians", g.max_gaussians, ">= 1"),
            (g.cpu_max_pixels >= 0 and g.cpu_max_gaussians >= 1, "stage1 CPU budget (pixels, Gaussians)",
             (g.cpu_max_pixels, g.cpu_max_gaussians), ">= 0 and >= 1"),
            (0 < a.vicinity_percentile <= 100, "vicinity percentile", a.vicinity_percentile, "in (0, 100]"),
            (a.direction_harmonics >= 1, "direction harmonics", a.direction_harmonics, ">= 1"),
            (a.position_frequencies >= 0, "position frequencies", a.position_frequencies, ">= 0"),
            (a.batch_size >= 1, "batch size", a.batch_size, ">= 1"),
            (min(a.field_width, a.field_layers, a.context_dim, a.binauralizer_width) >= 1,
             "field width/layers, context dim and binauralizer width",
             (a.field_width, a.field_layers, a.context_dim, a.binauralizer_width), ">= 1"),
            (a.pe_frequencies >= 0, "pe frequencies", a.pe_frequencies, ">= 0"),
            (p.initial_points >= 0, "audio points", p.initial_points, ">= 0"),
            (self.seed >= 0, "seed", self.seed, ">= 0"),
            (self.checkpoint_every >= 1 and self.eval_every >= 1, "checkpoint/eval interval",
             (self.checkpoint_every, self.eval_every), ">= 1"),
            (self.rir.width >= 1 and self.rir.direction_harmonics >= 1, "rir width and direction harmonics",
             (self.rir.width, self.rir.direction_harmonics), ">= 1"),
            (min(self.rir.position_frequencies, self.rir.time_frequencies, self.rir.frames, self.rir.length,
                 self.rir.arrival_frequencies, self.rir.sound_speed,
                 self.rir.phase_iterations, self.rir.eval_responses) >= 0,
             "rir position/time/arrival frequencies, frames, length, sound speed, phase iterations and eval responses",
             (self.rir.position_frequencies, self.rir.time_frequencies, self.rir.frames, self.rir.length,
              self.rir.arrival_frequencies, self.rir.sound_speed, self.rir.phase_iterations, self.rir.eval_responses), ">= 0"),
            (self.rir.floor_db < 0, "rir floor dB", self.rir.floor_db, "< 0"),
            (math.isfinite(self.rir.passes) and self.rir.passes >= 0, "rir passes", self.rir.passes, "finite and >= 0"),
            (self.rir.least_iterations >= 1, "rir least iterations", self.rir.least_iterations, ">= 1"),
            (self.rir.smooth_bins >= 1, "rir smooth bins", self.rir.smooth_bins, ">= 1"),
            (math.isfinite(self.rir.energy_weight) and self.rir.energy_weight >= 0, "rir energy weight", self.rir.energy_weight, "finite and >= 0"),
        ]
        for ok, what, value, expected in checks:
            if not ok:
                raise ValueError(f"{what} must be {expected}, got {value}")
        return self


MID_PHASE_ITERATIONS = 10
"""Fast Griffin-Lim iterations of the default synthesis (phase ``mid``): its MAG then beats 8 per ear
from the source's phase on each of our five scenes (benchmarks/syntheses.md)."""


@dataclass(frozen=True)
class SynthesisConfig:
    """How a pose's masks become a waveform (render time, not training).

    The masks are time-invariant, so a pose is a filter: its binaural impulse response
    (:mod:`avgs.acoustics.impulse_response`: a minimum-phase direct part and the
    reverberant tail as decaying noise). ``filter`` convolves the input with it: linear,
    what the explorer plays. ``spectrogram`` makes a waveform whose STFT magnitudes are B's
    predicted ear magnitudes (what MAG scores), with a phase:

    - ``mid`` (default): one phase, retrieved by fast Griffin-Lim (Perraudin et al. 2013;
      :mod:`avgs.dsp.phase_retrieval`) for the mid magnitudes ``s_m`` from the source's phase, and
      given to both ears, as the paper's masks give both ears the source's phase: half the
      cost of retrieving each ear's.
    - ``filter``: the phase of the input through the pose's filter, per ear.
    - ``source``: the source's (the paper's and AV-NeRF's synthesis).

    ``phase_iterations`` of fast Griffin-Lim refine it (``filter``/``source``: per ear).
    Speed and error of each: docs/results.md. Checkpoints with the conv head
    (``--post-conv``), whose output is not a filter, use the source's phase.
    """

    method: Literal["filter", "spectrogram"] = "spectrogram"
    "filter: convolve with the pose's binaural impulse response; spectrogram: the predicted ear magnitudes with a phase."
    phase: Literal["mid", "filter", "source"] = "mid"
    "With method spectrogram: one phase retrieved for the mid magnitudes (both ears), the filter output's, or the source's."
    phase_iterations: int | None = None
    "With method spectrogram: fast Griffin-Lim iterations (None: the phase's own, MID_PHASE_ITERATIONS for mid, 0 else)."
    phase_momentum: float = 0.99
    "Momentum of fast Griffin-Lim (0 is the original Griffin-Lim)."

    def __post_init__(self):
        if self.method not in ("filter", "spectrogram"):
            raise ValueError(f"synthesis method must be 'filter' or 'spectrogram', got {self.method!r}")
        if self.phase not in ("mid", "filter", "source"):
            raise ValueError(f"synthesis phase must be 'mid', 'filter' or 'source', got {self.phase!r}")
        if self.phase_iterations is not None and self.phase_iterations < 0:
            raise ValueError(f"phase_iterations must be >= 0, got {self.phase_iterations}")
        if not 0.0 <= self.phase_momentum < 1.0:
            raise ValueError(f"phase_momentum must be in [0, 1), got {self.phase_momentum}")

    @property
    def iterations(self) -> int:
        """Fast Griffin-Lim iterations this synthesis does (``phase_iterations`` or the phase's default)."""
        if self.method == "filter":
            return 0
        if self.phase_iterations is not None:
            return self.phase_iterations
        return MID_PHASE_ITERATIONS if self.phase == "mid" else 0


ADDED_LATER = {
    "acoustic": {"reverb_tail": False, "position_frequencies": 10, "direction_every_layer": False, "interaural_delay": False},
    "gaussians": {"cpu_max_pixels": 0},
    "rir": {"distance_slope": False, "distance_knee": False, "energy_weight": 0.0, "decay_weight": 0.0, "direct_sound": False,
            "direct_ild": False, "direct_itd": False, "ild_local": False, "ild_table": 0, "early_reflections": False, "reflected_arrival": False, "blocked_lag": False, "blocked_ild": False,
            "direct_level": False, "wall_loss": False, "passes": 0.0,
            "least_iterations": 3000},
}
"Fields absent from older stored configurations, with the value that the older code used."

RETIRED = {
    ("acoustic", "direction_encoding"): (
        "embedding",
        "AV-NeRF's learned direction embedding measured far worse than Fourier or harmonic features "
        "(docs/paper-deviations.md); retrain with the default harmonic features",
    ),
}
"Stored settings of variants that were removed: (section, field) -> (value, why), refused on load."


STFT = STFTConfig()
"The one STFT configuration used everywhere (AV-NeRF's)."
