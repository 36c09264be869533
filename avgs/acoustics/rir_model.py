"""RIRModel: G_a + F + the RIR variant of B, from (listener, yaw, source) to binaural impulse responses.

The impulse-response task (``avgs train --task rir``) trains on responses of many source
positions, so the source is an input per pose, not a constant of the scene: C_S is computed
per batch item (once per distinct source of a batch) from the source's own vicinity, and
``C = C_S (+) C_L`` feeds :class:`~avgs.acoustics.rir_binauralizer.RIRBinauralizer`. G_a, F,
the vicinity search and the caches are :class:`~avgs.acoustics.model.AVGSModel`'s.

From log magnitudes to sound (:func:`response_waveform`): the predicted STFT magnitudes
with a fixed-seed noise phase (independent per ear; a response's phase after the direct
sound is all but random), refined by a few iterations of fast Griffin-Lim
(:func:`avgs.dsp.phase_retrieval.griffin_lim`) so that the waveform's own STFT matches the magnitudes
better. ``RIRConfig.phase`` picks one; the training log holds the T60 / C50 / EDT of each on
the validation and held-out responses. Measured on rect_small (500 iterations, 60 val
responses): noise phase T60 30.2 %, C50 0.96 dB, EDT 0.037 s; 4 Griffin-Lim iterations 29.6 %,
0.96 dB, 0.036 s; 16 iterations 29.6 %, 1.02 dB, 0.037 s. The same within noise, and the
iterations cost 11 ms of a 25 ms render (one core): the default is the noise phase.

A pose's long-term ear gains ``|H_ear(f)|`` come from the energy of each bin over the
frames (the STFT's Parseval relation, :func:`ear_transfer`): what the propagation map and the
renderer's results report for this task."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from avgs import dsp
from avgs.acoustics.early_reflections import (WINDOW_S, ReflectionTest, early_ild, first_reflection, image_directions,
                                              wall_point_sets, wall_reflections)
from avgs.acoustics.field import AcousticField
from avgs.acoustics.interaural import (HEAD_RADIUS, SPEED_OF_SOUND, direct_level_db, ild_law, interaural_delay, itd_law,
                                      lagging_ear, local_correction, local_features)
from avgs.acoustics.line_of_sight import points_on_path
from avgs.acoustics.model import AVGSModel, ModelCache
from avgs.acoustics.points import AudioPoints
from avgs.acoustics.rir_binauralizer import RIRBinauralizer, never_blocked
from avgs.config import STFT, AcousticConfig, RIRConfig, STFTConfig, TrainConfig
from avgs.dsp.phase_retrieval import FrameGrid, frame_grid, griffin_lim
from avgs.data.frame import signed_direction
from avgs.threads import stopped

PHASE_SEED = 20240515
"Seed of the noise phase: fixed, so a predicted response is a deterministic function of the pose."

SILENCE_MARGIN = 0.5
"Nats (4.3 dB) above the floor that count as silence: ``|S| = max(e^y - e^(floor + margin), 0)``."


class RIRModel(AVGSModel):
    """Audio points G_a, acoustic field F and the RIR network (B's RIR variant).

    Shares G_a, F, the vicinity search, :meth:`context_at` and :meth:`source_context` with
    :class:`~avgs.acoustics.model.AVGSModel`; B is :class:`RIRBinauralizer`.
    """

    def __init__(self, points: AudioPoints, cfg: AcousticConfig, rir: RIRConfig, stft: STFTConfig = STFT,
                 vicinity_k: int | None = None):
        nn.Module.__init__(self)  # AVGSModel's own __init__ would build the binaural task's B
        if vicinity_k is not None and int(vicinity_k) < 1:
            raise ValueError(f"vicinity_k must be a positive number of points, got {vicinity_k!r}")
        if rir.frames < 1 or rir.length < 1:
            raise ValueError(f"the RIR model needs the responses' frames and length (>= 1), got {rir.frames}, {rir.length}")
        self.cfg, self.rir, self.stft = cfg, rir, stft
        self.points = points
        self.fixed_k = None if vicinity_k is None else int(vicinity_k)
        self.field = (
            AcousticField(points.alpha_dim, cfg.field_width, cfg.field_layers, cfg.context_dim) if cfg.use_context else None
        )
        self.binauralizer = RIRBinauralizer(rir, 2 * cfg.context_dim if cfg.use_context else None, stft.n_freq, rir.frames,
                                            stft.hop_length / stft.sample_rate)

    @classmethod
    def build(cls, points: AudioPoints, cfg: TrainConfig, stft: STFTConfig = STFT, vicinity_k: int | None = None):
        """This task's model for the training configuration ``cfg`` (its ``rir`` section sized to the responses)."""
        return cls(points, cfg.acoustic, cfg.rir, stft, vicinity_k=vicinity_k)

    @staticmethod
    def build_binauralizer(cfg: TrainConfig, stft: STFTConfig, context_dim: int | None) -> nn.Module:
        return RIRBinauralizer(cfg.rir, context_dim, stft.n_freq, cfg.rir.frames, stft.hop_length / stft.sample_rate)

    @staticmethod
    def config_problem(cfg: TrainConfig, stft: STFTConfig) -> str | None:
        r = cfg.rir
        if not (r.length >= 1 and r.frames == 1 + r.length // stft.hop_length):
            return ("task rir needs rir.length >= 1 samples and rir.frames = 1 + length // hop (the responses' STFT "
                    f"frames), got length {r.length!r}, frames {r.frames!r}")
        return None

    @torch.no_grad()
    def precompute(self) -> ModelCache:
        """The pose-independent parts: the time features ``[N, W]`` (in ``frequency``'s slot), F's per-point part."""
        points = None if self.field is None else self.field.point_features(self.points.alpha).contiguous()
        return ModelCache(self.binauralizer.time_features().contiguous(), points, self.points.X.t().contiguous())

    def contexts(self, listener: torch.Tensor, source: torch.Tensor, cache: ModelCache | None = None,
                 cached_source=None):
        """(C [B, 2c] or None, listener vicinity [B, k], source vicinity [B, k]) for listener, source [B, 3].

        ``cached_source``: :meth:`source_context` of the one source all B poses share (inference);
        else each distinct source of the batch gets its own C_S.
        """
        B = listener.shape[0]
        listener_idx = self.vicinity(listener, cache)  # [B, k]
        if cached_source is not None:
            c_s, idx = cached_source
            source_idx = idx[None].expand(B, -1)
            c_s = None if c_s is None else c_s[None].expand(B, -1)
        else:
            unique, inverse = torch.unique(source.detach(), dim=0, return_inverse=True)  # [S, 3], [B]
            idx = self.vicinity(unique, cache)  # [S, k]
            source_idx = idx[inverse]
            c_s = None if self.field is None else self.context_at(unique, idx, cache)[inverse]  # [B, c]
        if self.field is None:
            return None, listener_idx, source_idx
        c_l = self.context_at(listener, listener_idx, cache)  # [B, c]
        return torch.cat([c_s, c_l], dim=-1), listener_idx, source_idx

    def log_magnitudes(self, listener: torch.Tensor, yaw: torch.Tensor, source: torch.Tensor,
                       cache: ModelCache | None = None, cached_source=None, stop: Callable[[], bool] | None = None):
        """(log magnitudes [B, 2, F, N], listener vicinity [B, k], source vicinity [B, k]).

        listener, source [B, 3] normalised (source may be [3]: one for all); yaw [B] radians.
        ``stop``: asked between the contexts and the network (:class:`avgs.threads.Stopped`).
        """
        if source.dim() == 1:
            source = source[None].expand(listener.shape[0], -1)
        theta = signed_direction(listener, yaw, source)  # [B]
        context, lis_idx, src_idx = self.contexts(listener, source, cache, cached_source)
        stopped(stop, "log_magnitudes")
        t = None if cache is None else cache.frequency
        return self.binauralizer(listener, source, theta, yaw, context, t, walls=self.walls(listener, source)), lis_idx, src_idx

    def walls(self, listener: torch.Tensor, source: torch.Tensor) -> torch.Tensor | None:
        """The walls on each straight path ``[B]``, for B's wall term (``RIRConfig.wall_loss``), or None:
        the count of G_a's points along it (:func:`~avgs.acoustics.line_of_sight.points_on_path`, within
        ``wall_radius``) over the count from which a training pair was behind a wall (``wall_unit``); None
        also where training told no wall apart (one room): no count is made. listener, source [B, 3] normalised."""
        b = self.binauralizer
        if getattr(b, "wall_loss", None) is None or never_blocked(b.wall_unit):
            return None
        along = points_on_path(self.points.X.detach(), listener.detach(), source.detach(),
                               float(b.wall_radius), float(b.wall_margin))  # [B]
        return along.to(listener.dtype) / float(b.wall_unit)

    def magnitudes(self, log_mag: torch.Tensor) -> torch.Tensor:
        """STFT magnitudes of predicted log magnitudes: ``max(e^y - e^(floor + SILENCE_MARGIN), 0)``.

        The targets hold the floor wherever a response is quieter; a prediction scattered around
        it would otherwise be a constant noise plateau at the floor's level, which lengthens the
        decay (T60 measured about 2.5x too long on rect_small before this). Subtracting the
        threshold makes that region silent and changes louder bins by less than the floor."""
        return silenced_magnitudes(log_mag, self.binauralizer.log_floor)

    def forward(self, listener, yaw, source):
        """Training: log magnitudes [B, 2, F, N] and the vicinities (:meth:`log_magnitudes`)."""
        return self.log_magnitudes(listener, yaw, source)

    def direct_sound(self, listener: torch.Tensor, yaw: torch.Tensor, source: torch.Tensor) -> "DirectSound | None":
        """When the direct sound reaches each ear (``RIRConfig.direct_sound``), or None: listener, source
        [B, 3] normalised (source may be [3]), yaw [B] radians."""
        scale = self.binauralizer.itd_scale
        if scale is None or self.rir.sound_speed <= 0:
            return None
        if source.dim() == 1:
            source = source[None].expand(listener.shape[0], -1)
        distance = torch.linalg.vector_norm((source - listener).double(), dim=-1)  # [B]
        theta = signed_direction(listener.double(), yaw.double(), source.double())  # [B]
        b = self.binauralizer
        law = getattr(b, "ild_law", None)
        ild = None
        blocked = torch.zeros_like(distance, dtype=torch.bool)  # [B] the straight path behind a wall
        if law is not None:  # the head shadow where the straight path is free; behind a wall (NaN) B's ILD
            along = points_on_path(self.points.X.detach(), listener, source,
                                   float(b.sight_radius), float(b.sight_margin))
            blocked = along >= float(b.sight_blocked)
            ild = torch.full_like(distance, float("nan"))
            free = torch.nonzero(~blocked, as_tuple=True)[0]
            if free.numel():
                at = (listener[free], yaw[free], source[free], theta[free], distance[free])
                given = self.early_ild(*at)
                if getattr(b, "local_at", None) is not None:  # and the room's part near the training responses
                    where = local_features(at[0].double(), at[2].double(), at[3]) / b.local_scale.double()
                    given = given + local_correction(where, b.local_at.double(), b.local_residual.double())
                ild[free] = given
        energy = None
        level = getattr(b, "level_law", None)
        if level is not None:  # 1 / d^2 and the head's gain where the straight path is free; behind a wall B's
            nearest = HEAD_RADIUS * self.rir.sound_speed / SPEED_OF_SOUND  # the head's radius in the model's units
            energy = 10.0 ** (direct_level_db(theta, distance.clamp_min(nearest), level.double()) / 10.0)  # [B]
            energy = torch.where(blocked, torch.full_like(energy, float("nan")), energy)
        path, heard_from = distance, theta  # [B]: the first sound's path and direction
        use = getattr(b, "reflected_arrival", None)  # [2]: behind a wall, the first reflection's direction, its delay
        if use is not None and bool(blocked.any()) and bool((use > 0.5).any()):
            reflected_path, reflected_from = self.first_arrival(listener, yaw, source, blocked, distance, theta)
            heard_from = reflected_from if use[0] > 0.5 else theta
            path = reflected_path if use[1] > 0.5 else distance
        return DirectSound(path / self.rir.sound_speed, lagging_ear(self.head_itd(heard_from)), ild, energy)

    def head_itd(self, theta: torch.Tensor) -> torch.Tensor:
        """The head's ITD ``[...]`` seconds (> 0: the right ear later) of directions ``theta [...]`` radians, float64:
        the fitted law (``RIRConfig.direct_itd``), else Woodworth's sphere with the fitted scale."""
        b, theta = self.binauralizer, theta.double()
        law = getattr(b, "itd_law", None)
        return interaural_delay(theta, float(b.itd_scale)) if law is None else itd_law(theta, law.to(theta.device, torch.float64))

    def first_arrival(self, listener: torch.Tensor, yaw: torch.Tensor, source: torch.Tensor, blocked: torch.Tensor,
                      distance: torch.Tensor, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The first sound's path ``[B]`` and direction ``[B]`` (radians): where ``blocked [B]``, the shortest
        of the walls' first-order reflections whose legs are free
        (:func:`~avgs.acoustics.early_reflections.first_reflection`), else (and where none happens) the
        straight line's ``distance`` and ``theta``. listener, source [B, 3] normalised; yaw [B] radians."""
        setup = self.reflection_setup()
        if setup is None:
            return distance, theta
        walls, test, point_sets = setup
        at = torch.nonzero(blocked, as_tuple=True)[0]
        first = first_reflection(listener[at].detach(), source[at].detach(), walls, self.points.X.detach(), test, point_sets)
        found = at[first.found]
        if found.numel() == 0:
            return distance, theta
        path, heard_from = distance.clone(), theta.clone()
        path[found] = first.path[first.found].to(path)
        heard_from[found] = image_directions(listener[found], yaw[found], first.image[first.found][:, None])[:, 0].to(theta)
        return path, heard_from

    def reflection_setup(self) -> tuple[torch.Tensor, ReflectionTest, tuple] | None:
        """The walls found ``[P, 3]``, the reflections' test and each wall's point sets (kept while G_a is
        unchanged), or None without walls."""
        b = self.binauralizer
        walls = getattr(b, "reflecting_walls", None)
        if walls is not None:
            walls = walls[walls[:, :2].abs().sum(-1) > 0]  # [P, 3] the walls found (rows of zeros: none)
        if walls is None or walls.shape[0] == 0:
            return None
        test = ReflectionTest(float(b.reflection_radius), int(b.reflection_points), float(b.reflection_band),
                              float(b.sight_radius), float(b.sight_margin), float(b.sight_blocked))
        points = self.points.X.detach()
        key = (points.data_ptr(), tuple(points.shape), _version(points), walls.tolist(), test)
        if getattr(self, "_wall_points", (None,))[0] != key:  # each wall's own points and the rest: fixed while G_a is
            self._wall_points = (key, wall_point_sets(points, walls, test))
        return walls, test, self._wall_points[1]

    def early_ild(self, listener: torch.Tensor, yaw: torch.Tensor, source: torch.Tensor, theta: torch.Tensor,
                  distance: torch.Tensor) -> torch.Tensor:
        """The first 5 ms's ILD ``[B]`` dB where the straight path is free: the law at the direction ``theta [B]``,
        or, with the walls' reflections (``RIRConfig.early_reflections``), the direct sound's and theirs mixed
        (:func:`avgs.acoustics.early_reflections.early_ild`). listener, source [B, 3] normalised; yaw [B]
        radians; distance [B] the straight path."""
        b = self.binauralizer
        law = b.ild_law.double()
        setup = self.reflection_setup()
        if setup is None:
            return ild_law(theta, law)
        walls, test, point_sets = setup
        found = wall_reflections(listener.detach(), source.detach(), walls, self.points.X.detach(), test,
                                 longest=distance + WINDOW_S * self.rir.sound_speed, point_sets=point_sets)
        reflected = image_directions(listener, yaw, found.image)  # [B, P]
        return early_ild(theta, distance, reflected, found.path, found.happens, law, float(b.reflection_gain))


def _version(t: torch.Tensor) -> int:
    """``t``'s in-place version counter (0 for a tensor made in inference mode, which keeps none: it cannot change)."""
    try:
        return int(t._version)
    except RuntimeError:
        return 0


@dataclass(frozen=True)
class DirectSound:
    """When the direct sound reaches each ear of a batch of poses."""

    arrival: torch.Tensor  # [B] seconds: distance / c
    delays: torch.Tensor  # [B, 2] seconds each ear hears it after that (the ITD: avgs.acoustics.interaural.ear_delays)
    ild: torch.Tensor | None = None  # [B] dB, left over right, of the first 5 ms (avgs.acoustics.interaural.ild_law); None / NaN: B's
    energy: torch.Tensor | None = None  # [B] both ears' energy of the impulse's stretch (interaural.direct_level_db); None / NaN: B's


DIRECT_SECONDS = 0.005
"The direct sound's stretch after its arrival that both ears share (coherent), as the early ITD and ILD are measured."

FADE_SAMPLES = 16
"The gate before the arrival opens over this many samples (0.7 ms): no click."

IMPULSE_SECONDS = 0.002
"The stretch after each ear's arrival whose energy the direct sound's impulse takes (:func:`sharpen_direct_sound`)."

DIFFUSE_SHARE = 0.5
"The share of that stretch's amplitude left as it was: the head's own filtering of the direct sound, roughly."

IMPULSE_TAPS = 8
"Samples either side of the fractional impulse's centre (a Hann-windowed sinc)."


def silenced_magnitudes(log_mag: torch.Tensor, log_floor) -> torch.Tensor:
    """``max(e^y - e^(floor + SILENCE_MARGIN), 0)`` of log magnitudes ``y`` [...] (:meth:`RIRModel.magnitudes`)."""
    threshold = torch.exp(torch.as_tensor(log_floor, dtype=log_mag.dtype, device=log_mag.device) + SILENCE_MARGIN)
    return (torch.exp(log_mag) - threshold).clamp_min(0.0)


def ear_transfer(mag: torch.Tensor, stft: STFTConfig = STFT) -> torch.Tensor:
    """``|H(f)|`` [..., F] of a response from its STFT magnitudes [..., F, N]: ``sqrt(sum_t |S|^2 hop / sum(w^2))``
    (Parseval: an impulse response's STFT frames carry ``|H(f)|^2 sum(w^2) / hop`` per bin in all)."""
    window_power = float(dsp.window(stft.win_length, "cpu", torch.float64).square().sum())
    return torch.sqrt(mag.square().sum(-1) * (stft.hop_length / window_power))


@functools.lru_cache(maxsize=8)
def _noise_phase(n_freq: int, n_frames: int) -> torch.Tensor:
    """Unit phasors [2, F, N] complex64, one independent draw per ear, fixed seed."""
    g = torch.Generator().manual_seed(PHASE_SEED)
    angle = torch.rand(2, n_freq, n_frames, generator=g, dtype=torch.float64) * (2 * math.pi)
    return torch.polar(torch.ones_like(angle), angle).to(torch.complex64)


def _phases(n_freq: int, n_frames: int, stft: STFTConfig, direct: DirectSound | None) -> torch.Tensor:
    """The noise phase ``[2, F, N]``, or with ``direct`` ``[B, 2, F, N]``: the right ear takes the left's
    phase in the frames that overlap the direct sound's first :data:`DIRECT_SECONDS` (coherent ears)."""
    base = _noise_phase(n_freq, n_frames)
    if direct is None:
        return base
    hop = stft.hop_length / stft.sample_rate
    arrival = direct.arrival.detach().double().cpu()  # [B]: the phases are made on the CPU
    shared = torch.ceil((arrival + DIRECT_SECONDS + 0.5 * stft.n_fft / stft.sample_rate) / hop).long()  # [B]
    coherent = torch.arange(n_frames)[None, :] < shared[:, None]  # [B, N]
    right = torch.where(coherent[:, None, :], base[0], base[1])  # [B, F, N]
    return torch.stack([base[0].expand_as(right), right], dim=1)


def _np64(t: torch.Tensor) -> np.ndarray:
    """A tensor's values as a float64 NumPy array on the CPU (detached)."""
    return t.detach().to(device="cpu", dtype=torch.float64).numpy()


def place_direct_sound(h: torch.Tensor, direct: DirectSound, stft: STFTConfig = STFT) -> torch.Tensor:
    """Responses ``[B, 2, L]`` with nothing before the direct sound: each ear delayed by its ITD share
    (to the nearest sample: :func:`whole_sample_delay`), gated before ``arrival + delay`` (fractional; a
    raised-cosine over :data:`FADE_SAMPLES`),
    and the energy the gate took from the ear's first window given back to its next half window
    (the STFT frames spread the direct sound's energy over a window on both sides of it); then the
    direct sound made an impulse (:func:`sharpen_direct_sound`); with ``direct.energy`` (the level law,
    ``RIRConfig.direct_level``) at that energy, taken out of B's first window (:func:`_keep_window`).

    Last, the lagging ear's first :data:`DIRECT_SECONDS` become the leading ear's, delayed by the exact
    (fractional) difference of the arrivals and scaled (:func:`cohere_early`): the ears then differ there
    by the ITD alone. So the ITD is exact where it is heard and measured; after those milliseconds each ear
    is B's diffuse response (a noise phase), which a fraction of a sample does not change. (A fractional
    delay of the whole ear by FFT took 1.1 ms of the pose's 3.6 ms waveform.)

    The gate and the energy's return change only the samples from the gate's opening to a window after
    the arrival, and are worked out there, in float64. No gradient flows through it: the work is done in
    NumPy on the CPU, in place in one copy of the responses (the explorer makes one of these per pose of a
    drag: a few hundred small steps, in half the time they took in torch), and the result goes back to
    ``h``'s device and dtype."""
    fs, n_win = float(stft.sample_rate), stft.n_fft
    L = h.shape[-1]
    delays = _np64(direct.delays)  # [B, 2] seconds
    y = _whole_sample_delay(h.detach().to(device="cpu", dtype=torch.float32).numpy(), delays * fs)  # [B, 2, L] float32
    start = (_np64(direct.arrival)[:, None] + delays) * fs  # [B, 2] samples
    ild = None if direct.ild is None else _np64(direct.ild)  # [B] dB
    energy = None if direct.energy is None else _np64(direct.energy)  # [B]
    with np.errstate(all="ignore"):  # as torch: inf / NaN where the inputs say so, and no warning
        # Before the earliest gate every sample is 0; from a window after the latest arrival on, y as it is.
        lo, hi = _arrival_span(start, L, n_win)
        span = y[..., lo:hi].astype(np.float64)  # [B, 2, S]
        t = np.arange(lo, hi, dtype=np.float64)
        gated = span * _gate(t, start[..., None])
        window = (t < (start + n_win)[..., None]).astype(np.float64)  # the first window after the arrival, and before it
        before = np.square(y[..., :lo].astype(np.float64)).sum(-1) + (np.square(span) * window).sum(-1)  # [B, 2]
        after = (np.square(gated) * window).sum(-1)
        gain = np.where(after > 0, np.sqrt(before / np.maximum(after, 1e-300)), 1.0)
        back = 0.5 + 0.5 * np.cos(np.pi * np.clip((t - (start[..., None] + n_win / 2)) / (n_win / 2), 0.0, 1.0))
        out = y.astype(np.float64)
        out[..., :lo] = 0.0
        out[..., lo:hi] = gated * (1.0 + (gain[..., None] - 1.0) * back)
        early = (np.square(out[..., lo:hi]) * window).sum((-1, -2))  # [B] B's first window, both ears (before the impulse)
        out = _sharpen(out, start, fs, ild, energy)
        if energy is not None:  # the law's impulse comes out of B's first window (both ears), which holds it, not on top of it
            out = _keep_window(out, early, start, fs, n_win, np.isfinite(energy))
        out = _cohere(out, start, fs, ild)
    return torch.from_numpy(out).to(device=h.device, dtype=h.dtype)


def _keep_window(y: np.ndarray, early: np.ndarray, start: np.ndarray, fs: float, n_win: int,
                 given: np.ndarray) -> np.ndarray:
    """``y [B, 2, L]`` with, for the poses ``given [B]``, the rest of each ear's first window (after the
    impulse's stretch, up to ``n_win`` samples after ``start [B, 2]``) scaled so that the window holds
    ``early [B]`` again (both ears): B's first frames carry the direct sound's energy smeared over a
    window; a direct sound at the level law's energy replaces that share instead of adding to it.
    Where the law's impulse alone has more than ``early`` (near the source, where B's frames fall
    short), the rest keeps :data:`DIFFUSE_SHARE` of its amplitude. The last :data:`COHERE_FADE_SAMPLES`
    of the window ramp back to the ear's own level. Float64 NumPy, in place in ``y`` (returned)."""
    L = y.shape[-1]
    n_stretch = IMPULSE_SECONDS * fs
    lo, hi = _arrival_span(start, L, n_win)
    if lo >= hi:
        return y
    t = np.arange(lo, hi, dtype=np.float64) - start[..., None]  # [B, 2, S] samples from each ear's arrival
    span = y[..., lo:hi]
    inside = ((t >= -FADE_SAMPLES) & (t < n_stretch)).astype(np.float64)
    rest = ((t >= n_stretch) & (t < n_win)).astype(np.float64)
    have_in = (np.square(span) * inside).sum((-1, -2))  # [B]
    have_rest = (np.square(span) * rest).sum((-1, -2))
    floor = DIFFUSE_SHARE**2 * have_rest
    want = np.maximum(early - have_in, floor)
    g = np.where(given & (have_rest > 0), np.sqrt(want / np.maximum(have_rest, 1e-300)), 1.0)  # [B]
    ramp = np.clip((n_win - t) / COHERE_FADE_SAMPLES, 0.0, 1.0)  # [B, 2, S] 1 until the window's last samples, then to 0
    profile = 1.0 + (g[:, None, None] - 1.0) * rest * (0.5 - 0.5 * np.cos(np.pi * ramp))
    y[..., lo:hi] = span * profile
    return y


def _arrival_span(start, L: int, after: float, pad: int = 0) -> tuple[int, int]:
    """The samples ``lo .. hi - 1`` (within ``0 .. L``) that the direct sound's work changes: from
    :data:`FADE_SAMPLES` before the earliest arrival in ``start`` (samples, fractional) to ``after`` samples
    after the latest, widened by ``pad`` on both sides. Empty (``lo == hi``) when the arrivals are past the end."""
    lo = min(L, max(0, int(math.floor(float(start.min()))) - FADE_SAMPLES - pad))
    return lo, min(L, max(lo, int(math.ceil(float(start.max()) + after)) + pad + 1))


def _gate(t: np.ndarray, start) -> np.ndarray:
    """The gate before an arrival at ``start`` (samples) at sample times ``t``: 0, then a raised cosine over
    :data:`FADE_SAMPLES` up to 1 at ``start``."""
    opening = np.clip((t - (start - FADE_SAMPLES)) / FADE_SAMPLES, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * opening)


def whole_sample_delay(x: torch.Tensor, samples: torch.Tensor) -> torch.Tensor:
    """``x [..., L]`` delayed by ``samples [...]`` rounded to whole samples (either sign), zeros where
    nothing arrives yet (or any more)."""
    return torch.from_numpy(_whole_sample_delay(x.detach().cpu().numpy(), _np64(samples))).to(x.device)


def _whole_sample_delay(x: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """:func:`whole_sample_delay` in NumPy (``x``'s dtype)."""
    L = x.shape[-1]
    rows = x.reshape(-1, L)  # [R, L]
    shift = np.round(np.broadcast_to(samples, x.shape[:-1]).reshape(-1)).astype(np.int64).tolist()  # [R]
    out = np.zeros_like(rows)
    for r, k in enumerate(shift):
        if 0 <= k < L:
            out[r, k:] = rows[r, : L - k]
        elif -L < k < 0:
            out[r, :k] = rows[r, -k:]
    return out.reshape(x.shape)


def fractional_delay(x: torch.Tensor, samples: torch.Tensor) -> torch.Tensor:
    """``x [..., L]`` delayed by ``samples [...]`` (fractional, |delay| < L), by one FFT in ``x``'s
    precision, of a fast length >= 2 L: the band-limited delay's sinc tails reach more than L samples
    before wrapping around (at a length of L + 64 the response's first samples leak into its last
    at 0.3 % of the peak; here 4e-5)."""
    return torch.from_numpy(_fractional_delay(x.detach().cpu().numpy(), _np64(samples))).to(x.device)


def _fractional_delay(x: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """:func:`fractional_delay` in NumPy (SciPy's FFT keeps ``x``'s precision)."""
    from scipy.fft import irfft, next_fast_len, rfft

    L = x.shape[-1]
    size = next_fast_len(2 * L, real=True)
    freqs = np.fft.rfftfreq(size)  # [size // 2 + 1] cycles per sample, float64
    angle = (-2.0 * np.pi * freqs * np.asarray(samples, dtype=np.float64)[..., None]).astype(x.dtype)  # [..., K] radians
    return irfft(rfft(x, size) * (np.cos(angle) + 1j * np.sin(angle)), size)[..., :L]


def sharpen_direct_sound(y: torch.Tensor, start: torch.Tensor, fs: float, ild: torch.Tensor | None = None,
                         energy: torch.Tensor | None = None) -> torch.Tensor:
    """``y [B, 2, L]`` with each ear's first :data:`IMPULSE_SECONDS` after ``start [B, 2]`` (samples,
    fractional) made mostly an impulse at ``start``: the stretch keeps :data:`DIFFUSE_SHARE` of its
    amplitude and the rest of its energy becomes one band-limited impulse (a Hann-windowed sinc of
    :data:`IMPULSE_TAPS` samples each side) there. The energy, hence the level and every energy
    measure after 5 ms (C50, EDT, T60), is unchanged. Float64, on ``y``'s device.

    The STFT magnitudes spread the direct sound over a window of noise, whose peak is rarely the
    response's: on the two-room preset a quarter of the responses in sight of the source had their
    onset (-20 dB of the peak) 1-2 ms late. A direct sound is an impulse the head filters; as one it
    is the response's first peak, and both ears carry exactly the ITD it was given.

    ``ild [B]`` (dB, left over right; NaN: as without): the impulse's energy (both ears together, as above) is
    shared between the ears so that the first :data:`DIRECT_SECONDS` from the earlier arrival on
    (what :func:`avgs.evaluation.spatial.early_ild` reads) have that ILD, as far as the rest of
    that stretch allows (all the impulse in one ear at most).

    ``energy [B]`` (both ears; NaN: as without): the stretch's energy the direct sound's law gives
    (:func:`avgs.acoustics.interaural.direct_level_db`): the impulse takes what the remainder leaves of
    it (none when the remainder has more), shared between the ears as above; near the source B's first
    frames, which a network of the distance extrapolates, then no longer set the level."""
    with np.errstate(all="ignore"):
        out = _sharpen(_np64(y).copy(), _np64(start), fs, None if ild is None else _np64(ild),
                       None if energy is None else _np64(energy))
    return torch.from_numpy(out).to(y.device)


def _sharpen(y: np.ndarray, start: np.ndarray, fs: float, ild: np.ndarray | None = None,
             energy: np.ndarray | None = None) -> np.ndarray:
    """:func:`sharpen_direct_sound` in float64 NumPy, in place in ``y`` (returned)."""
    L = y.shape[-1]
    # Only the samples around the arrivals change: work on that span (the rest of y is returned as it is).
    lo, hi = _arrival_span(start, L, IMPULSE_SECONDS * fs, pad=IMPULSE_TAPS)
    if lo >= hi:
        return y
    span = y[..., lo:hi]  # [B, 2, S]
    offset = np.arange(lo, hi, dtype=np.float64) - start[..., None]  # [B, 2, S] samples from each ear's arrival
    stretch = ((offset >= -FADE_SAMPLES) & (offset < IMPULSE_SECONDS * fs)).astype(np.float64)
    stretch_energy = (np.square(span) * stretch).sum(-1)  # [B, 2]
    taper = np.where(np.abs(offset) < IMPULSE_TAPS, 0.5 + 0.5 * np.cos(np.pi * offset / IMPULSE_TAPS), 0.0)
    impulse = np.sinc(offset) * taper  # [B, 2, S]
    norm = np.maximum(np.sqrt(np.square(impulse).sum(-1, keepdims=True)), 1e-12)
    out = y  # (span, read above, is overwritten here)
    out[..., lo:hi] = span * (1.0 - stretch * (1.0 - DIFFUSE_SHARE))
    share = stretch_energy * (1.0 - DIFFUSE_SHARE**2)  # [B, 2] each ear's impulse energy
    if energy is not None:  # the law's total for the stretch: the impulse takes what the remainder leaves
        rest = (stretch_energy * DIFFUSE_SHARE**2).sum(-1)  # [B]
        total = share.sum(-1)
        wanted = np.where(np.isfinite(energy), np.maximum(energy - rest, 0.0), total)
        share = np.where(total[:, None] > 0, share * (wanted / np.maximum(total, 1e-300))[:, None], wanted[:, None] * 0.5)
    if ild is not None:
        share = _shared_for_ild(out, start, share, ild, fs)
    out[..., lo:hi] += impulse / norm * np.sqrt(share)[..., None]
    return out


COHERE_FADE_SAMPLES = 32
"Samples over which the lagging ear's coherent early stretch fades back into its own response (1.5 ms)."


def cohere_early(y: torch.Tensor, start: torch.Tensor, fs: float, ild: torch.Tensor | None = None) -> torch.Tensor:
    """``y [B, 2, L]`` with the lagging ear's first :data:`DIRECT_SECONDS` after its arrival replaced by the
    leading ear's, delayed by the difference of ``start [B, 2]`` (samples, fractional) and scaled to keep the
    lagging ear's energy over the :data:`DIRECT_SECONDS` from the earlier arrival on; then a :data:`COHERE_FADE_SAMPLES` crossfade back into its own samples.

    ``ild [B]`` (dB, left over right; NaN or None: as above): the two ears' energies over that stretch are
    shared anew, their sum kept, so that the stretch has that ILD: the lagging ear's copy takes its share,
    the leading ear a gain over the same samples (and a crossfade back to its own level after them).
    The impulse alone cannot always give it (:func:`sharpen_direct_sound`: B's remainder in the same
    milliseconds may lean the other way); a gain on one direct sound heard by both ears always can.

    Each ear's early stretch is a placed impulse plus B's diffuse remainder, in proportions that differ
    between the ears (the head shadow's ILD moves the impulse's energy, B sets the remainder's), so the
    interaural phase of their sum is not the ITD's: measured by GCC-PHAT over the first 5 ms
    (:func:`avgs.evaluation.spatial.response_itd`) the rendered ITD was a median 27 us off the one
    placed (two rooms, in sight of the source). A head in free field gives its ears the same direct
    sound, delayed and filtered; here the filter is a broadband gain, so the early ITD is the placed one
    and the early ILD (energy) is kept. The leading ear (without ``ild``), the stretch's energy and
    everything after it do not change. In ``y``'s dtype, on its device."""
    with np.errstate(all="ignore"):
        out = _cohere(y.detach().cpu().numpy().copy(), _np64(start), fs, None if ild is None else _np64(ild))
    return torch.from_numpy(out).to(y.device)


def _cohere(y: np.ndarray, start: np.ndarray, fs: float, ild: np.ndarray | None = None) -> np.ndarray:
    """:func:`cohere_early` in NumPy (``y``'s dtype), in place in ``y`` (returned): each pose reads its lagging
    ear's samples before it writes them, and its leading ear's energy before it scales them."""
    B, _, L = y.shape
    n_early = int(round(DIRECT_SECONDS * fs))
    out = y
    for b in range(B):
        lead = int(np.argmin(start[b]))
        lag = 1 - lead
        d = float(start[b, lag] - start[b, lead])  # samples, >= 0
        s0 = max(0, int(math.floor(float(start[b, lead]))) - FADE_SAMPLES - IMPULSE_TAPS)
        s1 = min(L, int(math.ceil(float(start[b, lead]))) + n_early + IMPULSE_TAPS)
        k = int(math.floor(d))
        a0, a1 = s0 + k, min(L, s1 + k + COHERE_FADE_SAMPLES)  # the lagging ear's span that changes
        if a1 - a0 <= COHERE_FADE_SAMPLES:
            continue
        n = a1 - a0
        core = min(n, s1 - s0)
        # the stretch the early ILD reads (from the earlier arrival on), and the lagging ear's energy there
        w0 = max(a0, int(math.floor(float(start[b, lead]))))
        w1 = min(a0 + core, w0 + n_early)
        energy = float(np.square(y[b, lag, w0:w1]).sum())
        level = None if ild is None else float(ild[b])
        if level is not None and math.isfinite(level):  # share the stretch's energy for the ILD, its sum kept
            lead_energy = float(np.square(y[b, lead, w0:w1]).sum())
            ratio = 10.0 ** ((level if lead == 0 else -level) / 10.0)  # leading over lagging ear
            total = lead_energy + energy
            if lead_energy > 0.0 and total > 0.0:
                energy = total / (1.0 + ratio)
                _scale_stretch(out[b, lead], s0, s1, math.sqrt(total * ratio / (1.0 + ratio) / lead_energy))
        source = np.zeros(n + 2 * IMPULSE_TAPS, dtype=y.dtype)  # the leading ear (its gain, fades and all), from s0 on
        got = out[b, lead, s0 : min(L, s0 + n)]
        source[: got.shape[0]] = got
        shifted = _fractional_delay(source[None], np.array([d - k]))[0, :n]  # lead moved by d
        # the lagging ear's gate, as place_direct_sound's: the delay's sinc tails reach before it
        shifted = shifted * _gate(np.arange(a0, a1, dtype=y.dtype), float(start[b, lag]))
        moved = float(np.square(shifted[w0 - a0 : w1 - a0]).sum())
        if moved <= 0.0:
            continue
        new = shifted * math.sqrt(energy / moved)  # the lagging ear's energy over the stretch: kept, or its ILD share
        fade = np.ones(n, dtype=y.dtype)
        tail = n - core  # the crossfade after the stretch, back to the lagging ear's own samples
        if tail > 0:
            fade[core:] = 0.5 + 0.5 * np.cos(np.pi * np.arange(1, tail + 1, dtype=y.dtype) / (tail + 1))
        out[b, lag, a0:a1] = new * fade + y[b, lag, a0:a1] * (1.0 - fade)
    return out


def _scale_stretch(x: np.ndarray, s0: int, s1: int, gain: float) -> None:
    """``x [L]`` times ``gain`` over samples ``s0 .. s1 - 1``, then back to 1 over :data:`COHERE_FADE_SAMPLES`
    (a raised cosine), in place. Before ``s0`` the ear is silent (its gate), so no fade is needed there."""
    L = x.shape[-1]
    s1 = min(s1, L)
    x[s0:s1] *= gain
    n = min(COHERE_FADE_SAMPLES, L - s1)
    if n > 0:
        t = np.arange(1, n + 1, dtype=x.dtype) / (COHERE_FADE_SAMPLES + 1)
        x[s1 : s1 + n] *= gain + (1.0 - gain) * (0.5 - 0.5 * np.cos(np.pi * t))


def _shared_for_ild(rest: np.ndarray, start: np.ndarray, share: np.ndarray, ild: np.ndarray, fs: float) -> np.ndarray:
    """Each ear's impulse energy ``[B, 2]``, their sum that of ``share [B, 2]``, such that the first
    DIRECT_SECONDS after the earlier arrival of ``start [B, 2]`` have ``ild [B]`` dB: with ``rest
    [B, 2, L]`` the response without its impulses there, ``left + rest_l = r (right + rest_r)``,
    r = 10^(ild / 10), clamped to [0, sum]. Float64 NumPy."""
    total = share.sum(-1)  # [B]
    L = rest.shape[-1]
    first = np.floor(start.min(-1)).astype(np.int64)  # [B] samples
    at = first[:, None] + np.arange(max(1, round(DIRECT_SECONDS * fs)))  # [B, n]
    inside = ((at >= 0) & (at < L)).astype(np.float64)
    index = np.broadcast_to(np.clip(at, 0, L - 1)[:, None, :], (at.shape[0], 2, at.shape[1]))
    stretch = np.take_along_axis(rest, index, -1) * inside[:, None, :]  # [B, 2, n]
    energies = np.square(stretch).sum(-1)  # [B, 2]
    r_l, r_r = energies[:, 0], energies[:, 1]
    ratio = 10.0 ** (ild / 10.0)
    left = np.clip((ratio * (total + r_r) - r_l) / (1.0 + ratio), 0.0, total)
    given = np.isfinite(ild)[:, None]  # NaN: that pose keeps its ears' own energies
    return np.where(given, np.stack([left, total - left], axis=-1), share)


def response_waveform(mag: torch.Tensor, length: int, stft: STFTConfig = STFT, phase: str = "griffin-lim",
                      iterations: int = 4, momentum: float = 0.99, direct: DirectSound | None = None,
                      stop: Callable[[], bool] | None = None) -> torch.Tensor:
    """Waveforms ``[..., 2, length]`` float32 of predicted STFT magnitudes ``[..., 2, F, N]`` (>= 0).

    ``phase="noise"``: the magnitudes with the fixed-seed noise phase, inverse STFT;
    ``"griffin-lim"``: that, refined by ``iterations`` of fast Griffin-Lim.

    Level: frames with unrelated phases overlap-add incoherently, so the inverse STFT of a
    noise-phased spectrogram carries about 6 dB less energy than its magnitudes (4 frames
    overlap at hop n_fft / 4); Griffin-Lim recovers part of it. Each ear's waveform is
    therefore scaled so that its STFT energy equals that of the magnitudes: the level is
    the model's, so that it falls with distance as predicted.

    ``direct`` (``[B]`` poses, ``mag [B, 2, F, N]``): the direct sound placed by geometry
    (:func:`place_direct_sound`): the ears share their phase over its first frames, then
    nothing arrives before distance / c, and the lagging ear hears it the ITD later.

    ``stop``: asked before the direct sound is placed; True abandons the waveform
    (:class:`avgs.threads.Stopped`: a caller that no longer wants it).
    """
    if phase not in ("noise", "griffin-lim"):
        raise ValueError(f"RIR phase must be 'noise' or 'griffin-lim', got {phase!r}")
    mag = mag.float()
    spec = mag * _phases(mag.shape[-2], mag.shape[-1], stft, direct).to(mag.device)  # [..., 2, F, N]
    its = iterations if phase == "griffin-lim" else 0
    want = mag.square().sum((-2, -1))  # [..., 2]
    n = mag.shape[-1]
    if its == 0 and n == dsp.n_frames(length, stft) and FrameGrid.covers(stft):
        # the inverse STFT and the STFT of its waveform on one padded signal (frame-major; torch.istft's and
        # torch.stft's to float rounding)
        grid = frame_grid(n, stft, torch.float32, str(mag.device))
        padded = grid.synthesise(spec.transpose(-1, -2).contiguous())  # [..., 2, padded samples]
        y = grid.waveform(padded, length)
        rebuilt = grid.analyse(grid.pad_ends(padded, length))  # [..., 2, N, F]
    else:
        y = griffin_lim(spec, mag, length, its, momentum, stft).float()  # [..., 2, length]
        rebuilt = dsp.stft(y, stft)
    got = (rebuilt * rebuilt.conj()).real.sum((-2, -1))  # [..., 2] the waveform's STFT energy
    gain = torch.where(got > 0, torch.sqrt(want / got.clamp_min(1e-30)), torch.zeros_like(got))
    y = y * gain[..., None]
    if direct is None:
        return y
    stopped(stop, "response_waveform")
    return place_direct_sound(y, direct, stft)
