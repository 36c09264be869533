"""B for the impulse-response task: the RIR variant of the binauralizer (paper appendix).

The paper drops the mixture mask and lets B's second MLP "predict the impulse response
directly for a corresponding time input". We take the time input to be one STFT frame of
the response and let the second MLP predict, for that frame, both ears' log magnitudes over
all F frequency bins (the time-frequency form). Per pose (listener, yaw, source)::

    e   = cos(n theta), sin(n theta), cos(n yaw), sin(n yaw),  n = 1 .. K   direction and facing
    d   = |source - listener|                                                distance (normalised)
    q   = ReLU(W_p [PE(listener) (+) PE(source) (+) e (+) log d] + b)        pose query
    q  += Linear(C)                                                          C = C_S (+) C_L (if used)
    h   = MLP_1(q) + q                                                       4 x (Linear + ReLU), residual
    per frame t (time input, mapped onto [-0.99, 0.99]; t_s its time in seconds, T the response's length):
    g0  = ReLU(h + W_t PE(t) + b_t + W_a PE((t_s - d / c) / T))              W_a: the arrival feature
    g   = MLP_2(g0, e) + g0                                                  4 x (Linear + ReLU); e enters every layer
    Y   = mean + Linear(g) + K_t(d) - K_t(dbar)              [2, F] log magnitudes of frame t, both ears
    K_t(d) = 0.5 log(1 + r_t^2 / d^2)                        the direct-plus-diffuse law, r_t learned per frame

``mean`` [2, F, N] is the training responses' mean log magnitude (a buffer stored with the
weights) and the head starts at zero, so an untrained network predicts the mean response
(plus the distance law at its starting critical distance: 0.2 dB at half the mean distance,
1 dB at a quarter) and training learns what each pose adds to it. There is no per-response
normalisation: the level of each response is part of its log magnitude, so the fall of
level with distance is learned, not removed. ``log_floor`` is the log of the smallest magnitude the targets hold
(``RIRConfig.floor_db`` below their loudest bin); a prediction at or below it is silence.

Why time-frequency and not one sample per time input: a response of L ~ 10^4 samples per
ear would be 10^4 rows through the MLP per pose (N ~ 10^2 frames here); and a log magnitude
is a smooth target (a sample of a response is not: its phase is all but random after the
first reflections). T60, C50 and EDT, the task's metrics, depend on the energy envelope,
which the log magnitudes carry. What it costs: a waveform needs a phase
(:func:`avgs.acoustics.rir_model.response_waveform`).

Continuous yaw: the facing enters only through cos / sin of theta and yaw, so any yaw is a
valid input, yaw + 360 gives the same features, and a small change of yaw gives a small
change of the output (a smooth network of smooth features). The data has four facings; in
between, the network interpolates (tests/test_rir_model.py checks both properties).

``log d`` is a function of the positions the paper's B already takes, given explicitly (the
level falls with it). With ``RIRConfig.distance_knee`` (the default) the output also holds
one term the network cannot bend, the room-acoustic law of a source's level against
distance (Hopkins and Stryker): direct energy falling as 1 / d^2 plus a diffuse energy that
does not fall, ``K_t(d) = 0.5 log(1 + r_t^2 / d^2)`` in log magnitude, with a critical
distance ``r_t`` per frame (``log_critical`` = log(r_t / dbar), -2 at the start: a small
correction) and ``dbar`` the training pairs' mean distance, where the term is zero. A ReLU
network alone flattens the fall of level outside and between the training pairs'
distances: on rect_large, with no training pair nearer than 0.89 m and none between 1.0 and
1.5 m, the level at 0.5 m was 3.5 dB low with no term; a slope per frame on log d
(``distance_slope``, the previous default: the 1 / d law at every distance) brought it to
0.3 dB but left the knee where the diffuse field takes over 2.1-2.4 dB high at 1.5 m (three
seeds); with the knee instead, every distance from 0.5 to 5 m is within 1.74-1.86 dB
(docs/results.md, "Impulse responses"). Both terms can be on (``distance_slope``).

The optional arrival feature (``RIRConfig.arrival_frequencies``, off by default): each
frame's time relative to the direct sound's arrival ``d / c`` (``RIRConfig.sound_speed``,
normalised units per second, set from the scene's frame at training). Measured on
data/rir/rect_small (500 iterations): with it (6 frequencies) val T60 24.8 %, C50 1.24 dB,
EDT 0.042 s, level against distance within 2.6 dB; without it 24.2 %, 1.20 dB, 0.041 s,
within 2.1 dB. No gain, so the paper's inputs are the default.

What made the task learnable at all, measured on rect_small: the targets' floor
(``RIRConfig.floor_db``). With a -100 dB floor the network memorised the training pairs
(train RMSE 0.45 nats, val 1.11 against the mean response's 0.79, on an earlier 6 x 15 grid);
at -80 dB it beats the mean on val and held-out sources. The 9-bin smoothing
(``smooth_bins``) is kept because a diffuse tail's per-bin fine structure is random; its
effect at -80 dB was not measured separately.

Inference caches ``W_t PE(t) + b_t`` for all frames (:meth:`RIRBinauralizer.time_features`).
"""

from __future__ import annotations

import torch
from torch import nn

from avgs.acoustics.early_reflections import MAX_WALLS, SURFACE_POINTS
from avgs.acoustics.encodings import encoded_dim, positional_encoding
from avgs.acoustics.interaural import DEFAULT_SCALE, ILD_HARMONICS, ITD_HARMONICS
from avgs.config import RIRConfig

NEVER_BLOCKED = 1e12
"The ``sight_blocked`` count of a model without the straight path's test: no path is blocked."


def never_blocked(count) -> bool:
    """Whether a fitted count (``sight_blocked``, ``wall_unit``; a tensor, a float or None) is
    :data:`NEVER_BLOCKED`: its float32 buffer holds 999 999 995 904, under 1e12 itself."""
    return count is None or float(count) >= 0.1 * NEVER_BLOCKED

MLP_LAYERS = 4
"Linear + ReLU layers of each of the two MLPs (as B's)."

ITD_BUFFERS = ("itd_scale", "itd_law")
"The direct sound's ITD, fitted at training (direct_sound, direct_itd): a checkpoint without them has none."

WALL_MAX = 3.0
"The most walls' worth of points along a path that the wall term counts (:meth:`RIRBinauralizer.forward`'s ``walls``)."

LEVEL_BUFFERS = ("level_law",)
"The direct sound's level, fitted at training (direct_sound, direct_level): a checkpoint without it has none."

WALL_BUFFERS = ("wall_loss", "wall_radius", "wall_margin", "wall_unit")
"B's wall term, fitted at training (direct_sound, wall_loss): a checkpoint without them has none."

REFLECTION_BUFFERS = ("reflecting_walls", "reflection_gain", "reflection_radius", "reflection_points", "reflection_band",
                      "reflected_arrival")
"The walls' first reflections (the early ILD; behind a wall, the arrival), fitted at training (direct_ild, early_reflections)."

ILD_BUFFERS = ("ild_law", "sight_radius", "sight_margin", "sight_blocked", "blocked_lag", "blocked_ild", "local_at", "local_residual",
               "local_scale") + REFLECTION_BUFFERS
"The direct sound's ILD, fitted at training (direct_ild, ild_local, early_reflections): a checkpoint without them has none."


def orientation_feature(theta: torch.Tensor, yaw: torch.Tensor, harmonics: int) -> torch.Tensor:
    """theta, yaw [B] radians -> [B, 4 K]: cos(n theta), sin(n theta), cos(n yaw), sin(n yaw), n = 1 .. K."""
    n = torch.arange(1, harmonics + 1, device=theta.device, dtype=theta.dtype)  # [K]
    t, y = theta[:, None] * n, yaw[:, None] * n  # [B, K]
    return torch.cat([torch.cos(t), torch.sin(t), torch.cos(y), torch.sin(y)], dim=-1)


class RIRBinauralizer(nn.Module):
    """Log magnitudes ``[B, 2, F, N]`` of binaural responses from listener, source, facing and context."""

    reverb = None
    "No reverberant tail: the response holds the whole decay (what code written for B reads)."
    post_conv = None
    "No conv head."

    def __init__(self, cfg: RIRConfig, context_dim: int | None, n_freq: int, n_frames: int, hop_seconds: float):
        super().__init__()
        if n_frames < 1:
            raise ValueError(f"the RIR network needs the responses' number of STFT frames (>= 1), got {n_frames}")
        W = cfg.width
        self.cfg = cfg
        self.n_freq, self.n_frames, self.width = n_freq, n_frames, W
        self.register_buffer("mean", torch.zeros(2, n_freq, n_frames))  # [2, F, N] training mean log magnitude
        self.register_buffer("log_floor", torch.tensor(-30.0))  # log of the smallest target magnitude
        # On the CPU even under a meta device (checkpoint validation builds B there): a meta linspace or
        # multiply imports sympy and torch._dynamo, 2.5 s of every process that reads a checkpoint.
        cpu = torch.device("cpu")
        self.register_buffer("time_query", torch.linspace(-0.99, 0.99, n_frames, device=cpu)[:, None],
                             persistent=False)  # [N, 1]
        self.register_buffer("frame_seconds", torch.arange(n_frames, device=cpu) * float(hop_seconds),
                             persistent=False)  # [N]
        self.duration = max(n_frames * float(hop_seconds), 1e-9)  # T, seconds
        self.position_dim = encoded_dim(3, cfg.position_frequencies)
        self.direction_dim = 4 * cfg.direction_harmonics
        self.pose_proj = nn.Linear(2 * self.position_dim + self.direction_dim + 1, W)
        self.context_proj = nn.Linear(context_dim, W) if context_dim else None
        self.pose_mlp = nn.ModuleList(nn.Linear(W, W) for _ in range(MLP_LAYERS))
        self.time_proj = nn.Linear(encoded_dim(1, cfg.time_frequencies), W)
        self.arrival_proj = nn.Linear(encoded_dim(1, cfg.arrival_frequencies), W, bias=False) if cfg.arrival_frequencies else None
        self.time_mlp = nn.ModuleList(nn.Linear(W + self.direction_dim, W) for _ in range(MLP_LAYERS))
        self.head = nn.Linear(W, 2 * n_freq)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        if cfg.distance_slope:  # the inverse-distance law's term, one slope per frame (see the module docstring)
            self.distance_slope = nn.Parameter(torch.zeros(n_frames))  # [N]
        else:
            self.distance_slope = None
        if cfg.distance_knee:  # the direct-plus-diffuse law's term, one critical distance per frame
            self.log_critical = nn.Parameter(torch.full((n_frames,), -2.0))  # [N] log(r_t / mean distance)
        else:
            self.log_critical = None
        if cfg.distance_slope or cfg.distance_knee:
            self.register_buffer("log_distance_mean", torch.tensor(0.0))  # mean log distance of the training pairs
        if cfg.direct_sound:  # a / c of Woodworth's head, seconds: fitted to the training responses (avgs.train)
            self.register_buffer("itd_scale", torch.tensor(DEFAULT_SCALE))
        else:
            self.itd_scale = None
        if cfg.direct_sound and cfg.direct_itd:  # seconds per sine harmonic of the direction, fitted (avgs.train)
            self.register_buffer("itd_law", torch.zeros(ITD_HARMONICS))
        else:
            self.itd_law = None
        if cfg.direct_sound and cfg.direct_ild:  # dB per sine harmonic of the direction, fitted (avgs.train)
            self.register_buffer("ild_law", torch.zeros(ILD_HARMONICS))
            # The straight path's test (avgs.acoustics.line_of_sight), fitted with it: radius and margin in the
            # model's units; a path with at least `sight_blocked` points along it is behind a wall (never: NEVER_BLOCKED).
            self.register_buffer("sight_radius", torch.tensor(0.0))
            self.register_buffer("sight_margin", torch.tensor(0.0))
            self.register_buffer("sight_blocked", torch.tensor(NEVER_BLOCKED))
        else:
            self.ild_law = None
        if self.ild_law is not None and cfg.blocked_lag:  # seconds after distance / c of the first sound behind a wall (avgs.train)
            self.register_buffer("blocked_lag", torch.tensor(0.0))
        else:
            self.blocked_lag = None
        if self.ild_law is not None and cfg.blocked_ild:  # behind a wall, B's early ILD times this (fitted at the end: avgs.train)
            self.register_buffer("blocked_ild", torch.tensor(1.0))
        else:
            self.blocked_ild = None
        if cfg.direct_sound and cfg.direct_level:  # dB coefficients of the direct sound's level law (avgs.train)
            self.register_buffer("level_law", torch.zeros(3))
        else:
            self.level_law = None
        if cfg.direct_sound and cfg.wall_loss:  # log magnitude per frame lost per wall on the path
            self.wall_loss = nn.Parameter(torch.zeros(n_frames))  # [N]
            # the walls' count (fitted by avgs.train): the points within `wall_radius` of the path, not within
            # `wall_margin` of its ends (model units), over `wall_unit`, the count from which a training pair
            # was behind a wall (never: NEVER_BLOCKED)
            self.register_buffer("wall_radius", torch.tensor(0.0))
            self.register_buffer("wall_margin", torch.tensor(0.0))
            self.register_buffer("wall_unit", torch.tensor(NEVER_BLOCKED))
        else:
            self.wall_loss = None
        if cfg.direct_sound and cfg.direct_ild and cfg.ild_local and cfg.ild_table > 0:
            # the law's local correction (avgs.acoustics.interaural.local_correction), fitted by avgs.train:
            # where the training responses were [M, 6] (local_features over local_scale), their residual [M] dB
            self.register_buffer("local_at", torch.zeros(cfg.ild_table, 6))
            self.register_buffer("local_residual", torch.zeros(cfg.ild_table))
            self.register_buffer("local_scale", torch.ones(6))
        else:
            self.local_at = None
        if cfg.direct_sound and cfg.direct_ild and cfg.early_reflections:
            # the walls' first-order reflections in the first 5 ms (avgs.acoustics.early_reflections), fitted by
            # avgs.train: the walls' planes [MAX_WALLS, 3] (n_x, n_y, d in model units; rows of zeros: no wall),
            # their amplitude gain, and the reflection point's test (G_a's points within `reflection_radius`, at
            # least `reflection_points` of them) and the band of a wall's own points left out of its legs' test
            self.register_buffer("reflecting_walls", torch.zeros(MAX_WALLS, 3))
            self.register_buffer("reflection_gain", torch.tensor(0.0))
            self.register_buffer("reflection_radius", torch.tensor(0.0))
            self.register_buffer("reflection_points", torch.tensor(float(SURFACE_POINTS)))
            self.register_buffer("reflection_band", torch.tensor(0.0))
        else:
            self.reflecting_walls = None
        if self.reflecting_walls is not None and cfg.reflected_arrival:
            # [2]: behind a wall, the first sound's direction (its ITD) and its delay (the onset) from the walls' first
            # reflection (1) or the straight line (0), each as the training pairs behind a wall say (fitted by avgs.train)
            self.register_buffer("reflected_arrival", torch.zeros(2))
        else:
            self.reflected_arrival = None

    def time_features(self) -> torch.Tensor:
        """``W_t PE(t) + b_t`` for every frame ``[N, W]``: cacheable."""
        return self.time_proj(positional_encoding(self.time_query, self.cfg.time_frequencies))

    def forward(
        self, listener: torch.Tensor, source: torch.Tensor, theta: torch.Tensor, yaw: torch.Tensor,
        context: torch.Tensor | None = None, time_features: torch.Tensor | None = None,
        frames: torch.Tensor | None = None, bins: torch.Tensor | None = None, walls: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """listener, source [B, 3] normalised; theta, yaw [B] radians; context [B, C] or None;
        ``time_features``: :meth:`time_features`, cached at inference. Returns log magnitudes [B, 2, F, N].
        ``frames`` [n] / ``bins`` [f] (int64 indices; None: all): evaluate only those frames and
        bins, the same numbers as those entries of the whole output: [B, 2, f, n].
        ``walls`` [B]: the walls on each straight path (the scene's points along it over ``wall_unit``:
        :meth:`avgs.acoustics.rir_model.RIRModel.walls`); with ``RIRConfig.wall_loss`` each, up to
        :data:`WALL_MAX`, adds ``wall_loss`` per frame (None: no wall term)."""
        c = self.cfg
        B, W, F = listener.shape[0], self.width, self.n_freq
        e = orientation_feature(theta, yaw, c.direction_harmonics)  # [B, D]
        distance = torch.linalg.vector_norm(source - listener, dim=-1)  # [B]
        pose = torch.cat([positional_encoding(listener, c.position_frequencies),
                          positional_encoding(source, c.position_frequencies), e,
                          torch.log(distance.clamp_min(1e-3))[:, None]], dim=-1)  # [B, P]
        q = self.pose_proj(pose).relu()  # [B, W]
        if self.context_proj is not None:
            if context is None:
                raise ValueError("this RIR network was built with scene context; pass context [B, C]")
            q = q + self.context_proj(context)
        h = q
        for layer in self.pose_mlp:
            h = layer(h).relu()
        h = h + q  # [B, W] residual
        t = self.time_features() if time_features is None else time_features  # [N, W]
        mean, seconds, slope, knee = self.mean, self.frame_seconds, self.distance_slope, self.log_critical  # [2, F, N], [N], [N], [N]
        wall = None if walls is None else self.wall_loss  # [N]
        if frames is not None:  # a subset of the frames: [n] of each
            t, mean, seconds = t[frames], mean[..., frames], seconds[frames]
            slope = None if slope is None else slope[frames]
            knee = None if knee is None else knee[frames]
            wall = None if wall is None else wall[frames]
        head_w, head_b = self.head.weight, self.head.bias  # [2 F, W], [2 F]
        if bins is not None:  # a subset of the bins: the head's rows of both ears
            rows = torch.cat([bins, bins + F])
            head_w, head_b, mean, F = head_w[rows], head_b[rows], mean[:, bins], len(bins)
        N = t.shape[0]
        g0 = h[:, None, :] + t[None]  # [B, N, W]
        if self.arrival_proj is not None:
            speed = c.sound_speed if c.sound_speed > 0 else 1.0
            rel = (seconds[None] - distance[:, None] / speed) / self.duration  # [B, N]
            g0 = g0 + self.arrival_proj(positional_encoding(rel[..., None], c.arrival_frequencies))
        g0 = g0.relu()
        g = g0
        for layer in self.time_mlp:  # W_g g + (W_e e + b): the direction's part is one vector per pose
            ge = torch.addmm(layer.bias, e, layer.weight[:, W:].t())  # [B, W]
            g = (g @ layer.weight[:, :W].t()).add_(ge[:, None, :]).relu_()  # [B, N, W]
        g = g + g0
        out = torch.nn.functional.linear(g, head_w, head_b).view(B, N, 2, F).permute(0, 2, 3, 1)  # [B, 2, F, N]
        if slope is not None or knee is not None:
            log_d = torch.log(distance.clamp_min(1e-3)) - self.log_distance_mean  # [B] relative to the mean
        if slope is not None:
            out = out - log_d[:, None, None, None] * slope  # [B, 2, F, N]
        if knee is not None:  # 0.5 log(1 + r^2 / d^2), minus its value at the mean distance (log_d = 0)
            sp = torch.nn.functional.softplus
            law = 0.5 * (sp(2.0 * (knee[None] - log_d[:, None])) - sp(2.0 * knee))  # [B, N]
            out = out + law[:, None, None, :]
        if wall is not None:
            out = out + (walls.to(out.dtype).clamp(0.0, WALL_MAX)[:, None] * wall)[:, None, None, :]
        return out + mean
