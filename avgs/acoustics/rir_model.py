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

import torch
from torch import nn

from avgs import dsp
from avgs.acoustics.direct_placement import DIRECT_SECONDS, DirectSound, place_direct_sound
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
        lag = getattr(b, "blocked_lag", None)  # behind a wall, the first sound this long after distance / c (fitted)
        if lag is not None and float(lag) > 0 and bool(blocked.any()):
            path = torch.where(blocked, distance + float(lag) * self.rir.sound_speed, path)
        shrink, ild_scale = getattr(b, "blocked_ild", None), None  # behind a wall, B's early ILD times this (fitted)
        if shrink is not None and float(shrink) != 1.0 and bool(blocked.any()):
            ild_scale = torch.where(blocked, torch.full_like(distance, float(shrink)), torch.full_like(distance, float("nan")))
        return DirectSound(path / self.rir.sound_speed, lagging_ear(self.head_itd(heard_from)), ild, energy, ild_scale)

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


def _shared_frames(direct: DirectSound, n_frames: int, stft: STFTConfig) -> torch.Tensor:
    """``[B]`` int64: how many first frames overlap the direct sound's first :data:`DIRECT_SECONDS` (where the
    ears share their phase), at most ``n_frames``."""
    hop = stft.hop_length / stft.sample_rate
    arrival = direct.arrival.detach().double().cpu()  # [B]: the phases are made on the CPU
    shared = torch.ceil((arrival + DIRECT_SECONDS + 0.5 * stft.n_fft / stft.sample_rate) / hop).long()  # [B]
    return shared.clamp(0, n_frames)


def _phases(n_freq: int, n_frames: int, stft: STFTConfig, direct: DirectSound | None) -> torch.Tensor:
    """The noise phase ``[2, F, N]``, or with ``direct`` ``[B, 2, F, N]``: the right ear takes the left's
    phase in the frames that overlap the direct sound's first :data:`DIRECT_SECONDS` (coherent ears)."""
    base = _noise_phase(n_freq, n_frames)
    if direct is None:
        return base
    coherent = torch.arange(n_frames)[None, :] < _shared_frames(direct, n_frames, stft)[:, None]  # [B, N]
    right = torch.where(coherent[:, None, :], base[0], base[1])  # [B, F, N]
    return torch.stack([base[0].expand_as(right), right], dim=1)


@functools.lru_cache(maxsize=8)
def _noise_rows(n_freq: int, n_frames: int) -> torch.Tensor:
    """:func:`_noise_phase` frame-major, ``[2, N, F]`` complex64 (contiguous)."""
    return _noise_phase(n_freq, n_frames).transpose(-1, -2).contiguous()


def _noise_spectrogram(mag: torch.Tensor, stft: STFTConfig, direct: DirectSound | None) -> torch.Tensor:
    """``mag [..., 2, F, N]`` (float32) with :func:`_phases`, frame-major: ``[..., 2, N, F]`` complex64, made in
    one pass (the product written frame-major, the coherent frames of the right ear overwritten after): the
    same numbers as ``(mag * _phases(...)).transpose(-1, -2).contiguous()`` in under half its time."""
    n_freq, n_frames = mag.shape[-2], mag.shape[-1]
    rows = _noise_rows(n_freq, n_frames).to(mag.device)  # [2, N, F]
    frames = mag.transpose(-1, -2)  # [..., 2, N, F] a view
    out = torch.empty(frames.shape, dtype=torch.complex64, device=mag.device)
    torch.mul(frames, rows, out=out)
    if direct is not None:  # [B, 2, F, N]: the right ear takes the left's phase over its first shared frames
        for b, k in enumerate(_shared_frames(direct, n_frames, stft).tolist()):
            torch.mul(frames[b, 1, :k], rows[0, :k], out=out[b, 1, :k])
    return out


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
    its = iterations if phase == "griffin-lim" else 0
    want = mag.square().sum((-2, -1))  # [..., 2]
    n = mag.shape[-1]
    if its == 0 and n == dsp.n_frames(length, stft) and FrameGrid.covers(stft):
        # the inverse STFT and the STFT of its waveform on one padded signal (frame-major; torch.istft's and
        # torch.stft's to float rounding)
        grid = frame_grid(n, stft, torch.float32, str(mag.device))
        padded = grid.synthesise(_noise_spectrogram(mag, stft, direct))  # [..., 2, padded samples]
        y = grid.waveform(padded, length)
        rebuilt = grid.analyse(grid.pad_ends(padded, length))  # [..., 2, N, F]
    else:
        spec = mag * _phases(mag.shape[-2], mag.shape[-1], stft, direct).to(mag.device)  # [..., 2, F, N]
        y = griffin_lim(spec, mag, length, its, momentum, stft).float()  # [..., 2, length]
        rebuilt = dsp.stft(y, stft)
    got = (rebuilt * rebuilt.conj()).real.sum((-2, -1))  # [..., 2] the waveform's STFT energy
    gain = torch.where(got > 0, torch.sqrt(want / got.clamp_min(1e-30)), torch.zeros_like(got))
    y = y * gain[..., None]
    if direct is None:
        return y
    stopped(stop, "response_waveform")
    return place_direct_sound(y, direct, stft)
