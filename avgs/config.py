"""Every configurable number of AV-GS, in one place, with the paper's defaults.

Each field carries a one-line docstring (the string literal after it); the CLI reads
these for its ``--help``. STFT settings live here and nowhere else.
"""

from __future__ import annotations

import dataclasses
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
    max_gaussians: int = 200_000
    "Hard cap on the number of Gaussians (keeps CPU training and drawing tractable)."
    init_points: int = 20_000
    "Initial points sampled from the scene geometry or a random box."
    image_downscale: int = 1
    "Train on frames downscaled by this factor."
    backend: Literal["auto", "torch", "gsplat"] = "auto"
    "Rasterizer: gsplat when CUDA is present, else our pure-PyTorch rasterizer."
    log_every: int = 100
    "Write a stage-1 log record (loss, PSNR, Gaussian count) every this many iterations."


DIRECTION_ENCODINGS = ("embedding", "fourier", "harmonic")
"Direction features B can use (:mod:`avgs.acoustics.binauralizer`)."


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
    # Measured (four presets, --init sfm, 2000 iterations, val; `avgs eval` ILD error above
    # 1.5 kHz): 10 frequencies (up to 2^9 per normalised unit, wavelengths of ~0.01) let
    # B memorise the 200 training poses; 4 (up to 2^3, ~0.8 units) lowered MAG on all four
    # presets and the ILD error on three. See README "Direction and position features".
    position_frequencies: int = 4
    "Positional-encoding frequencies of the listener's (x, y), log-spaced up to 2^(n-1) (AV-NeRF: 10)."
    direction_embedding: int = 180
    "Number of learned, circularly interpolated direction embeddings (AV-NeRF)."
    # Measured (free-field test scene, 48 train poses, 1500 iterations; val MAG / ENV):
    # relu+embedding 0.860/0.156, sigmoid+embedding 0.736/0.151, relu+fourier 0.244/0.129,
    # sigmoid+fourier 0.243/0.127. relu kept: equal within noise and it can exceed gain 1
    # (the two clips are peak-normalised separately); fourier wins clearly.
    mixture_activation: Literal["relu", "sigmoid"] = "relu"
    "Last activation of the mixture mask: AV-NeRF's unbounded relu or the paper's sigmoid."
    # Then (same runs as position_frequencies; scripts/ild_check.py): with harmonic (4 orders)
    # and the 4-frequency listener encoding, the correlation of predicted with true ILD on
    # unseen poses rose in three presets of four (apartment 0.56 -> 0.63, outdoor 0.90 ->
    # 0.93), and the demo's from 0.41 to 0.68. Harmonic is periodic across the listener's
    # back and hands B sin(theta), the source's lateral offset, directly.
    direction_encoding: Literal["embedding", "fourier", "harmonic"] = "harmonic"
    "Direction feature of B: AV-NeRF's learned circular embedding added per layer, the paper's concatenated Fourier features, or circular harmonics of theta."
    direction_harmonics: int = 4
    "Orders of the harmonic direction feature: cos(n theta), sin(n theta) for n = 1 .. this."
    # Measured (four raw-head presets x three seeds, --init sfm, 2000 iterations, on an H100;
    # README "Direction at every layer"): with the feature at the first layer only, AV-GS
    # missed the direction in 8 runs of 12 (outdoors, 2 seeds: ILD error 7.6-7.8 dB, about
    # Mono-Mono's; house and apartment: 0.6-0.8 dB above the control); at every layer it
    # never did and is level with --no-context, and the equalised presets did not move
    # beyond the seed spread.
    direction_every_layer: bool = True
    "Concatenate the (fourier or harmonic) direction feature to every layer of B's difference MLP (AV-NeRF adds its embedding after each); off: the first layer only (the paper's text)."
    post_conv: bool = False
    "AV-NeRF's optional time-frequency conv head on the ear magnitudes (avgs.acoustics.post_conv)."
    reverb_tail: bool = True
    "Add a learned late-reverberation tail to B's masks (avgs.acoustics.reverb_tail); off: the paper's masks only."
    use_context: bool = True
    "Condition B on the scene context C (False: the --no-context control)."
    lambda_a: float = 1e-4
    "Weight of the volume regulariser L_v (the paper does not state it)."
    iterations: int = 40000
    "Stage-2 iterations (paper: 40k)."
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

    enabled: bool = True
    "Turn audio-aware densification and pruning on (--no-point-management turns it off)."
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
    initial_points: int = 0
    "Start G_a from a seeded random subset of this many of G's points (0: all of them, up to max_points)."
    prune_max_fraction: float = 0.5
    "Skip a pruning step that would remove more than this fraction of the points (a sparse G_a, not outliers)."


@dataclass
class TrainConfig:
    """Both stages, bookkeeping and reproducibility."""

    gaussians: GaussianConfig = field(default_factory=GaussianConfig)
    acoustic: AcousticConfig = field(default_factory=AcousticConfig)
    points: PointManagementConfig = field(default_factory=PointManagementConfig)
    stft: STFTConfig = field(default_factory=STFTConfig)
    init: Literal["gs", "sfm"] = "gs"
    "Audio points from a warmed-up 3D-GS (gs) or straight from the scene geometry points (sfm)."
    seed: int = 0
    "Random seed; CPU training is reproducible for a fixed seed."
    device: str = "cpu"
    "Torch device: cpu or cuda."
    checkpoint_every: int = 2000
    "Save the checkpoint atomically every this many stage-2 iterations."
    eval_every: int = 2000
    "Evaluate MAG/ENV on the validation split every this many iterations."
    log_every: int = 50
    "Write a JSON-lines log record every this many iterations."
    store_gaussians: bool = True
    "Keep G in the checkpoint (for drawing and listener views); off makes it smaller."

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        """From :meth:`to_dict` output, including that of older versions: unknown keys are
        ignored, and a field added later takes the value that reproduces the old behaviour."""
        d = dict(d)
        sub = {
            "gaussians": GaussianConfig,
            "acoustic": AcousticConfig,
            "points": PointManagementConfig,
            "stft": STFTConfig,
        }
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


@dataclass(frozen=True)
class SynthesisConfig:
    """How a waveform is made from B's predicted ear magnitudes (render time, not training).

    AV-NeRF and the paper take the source's phase. Those magnitudes with that phase are
    rarely the STFT of any signal, so the waveform's own spectrogram comes out blurred
    away from the prediction. A few iterations of fast Griffin-Lim (Perraudin et al.
    2013), starting from the source's phase, bring it back (:func:`avgs.dsp.griffin_lim`).
    """

    phase_iterations: int = 8
    "Fast Griffin-Lim iterations from the source's phase; 0 keeps the source's phase (the paper's)."
    phase_momentum: float = 0.99
    "Momentum of fast Griffin-Lim (0 is the original Griffin-Lim)."


ADDED_LATER = {"acoustic": {"reverb_tail": False, "position_frequencies": 10, "direction_every_layer": False}}
"Fields absent from older stored configurations, with the value that the older code used."


def field_help(dc: type, name: str) -> str:
    """The one-line docstring written under a dataclass field, for CLI help."""
    import ast
    import inspect
    import textwrap

    src = textwrap.dedent(inspect.getsource(dc))
    body = ast.parse(src).body[0].body
    for node, nxt in zip(body, body[1:]):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and node.target.id == name
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
        ):
            return str(nxt.value.value)
    return ""


STFT = STFTConfig()
"The one STFT configuration used everywhere (AV-NeRF's)."
