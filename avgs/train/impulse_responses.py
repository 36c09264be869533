"""The impulse-response task's training hooks (``avgs train SCENE --task rir``,
:class:`ImpulseResponseTraining`, driven by the one loop of :mod:`avgs.train.pipeline`).

An RIR scene (``DATA_ROOT/<scene>/rir/``, :mod:`avgs.data.rir`) is also an RWAVS scene, so G_a
comes from stage 1 exactly as for the binaural task (``--init sfm`` takes scene.json's
surfaces and skips training G); its binaural clips are not read. Then G_a, F and the RIR network
(:class:`~avgs.acoustics.rir_model.RIRModel`) train on the log magnitudes of the training
responses (the STFT of each response, per ear, floored ``RIRConfig.floor_db`` below the
loudest training bin; no per-response normalisation, so level falls with distance):

    L = (1 - lambda_a) [MSE(log |S_pred|, log |S_gt|) + w_e L_energy + w_d L_decay] + lambda_a L_v

(L_energy: each ear's energy per bin and the ears' difference; L_decay: the energy decay
curves, :mod:`avgs.train.losses`; L_v: the vicinity points' prior, stage 2's)

with stage 2's optimiser groups, schedule, audio-aware point management and exact resume
(:class:`RIRTrainer` is a :class:`~avgs.train.stage2.Stage2Trainer` with another batch and
loss). Every ``eval_every`` iterations the log-magnitude RMSE on val (``val_logmag``) is
logged beside that of the training responses' mean (``val_logmag_mean``: predicting the mean
response); at the end T60 / C50 / EDT errors (:mod:`avgs.evaluation.metrics`) of the waveforms on val
and heldout, for each phase reconstruction (:func:`~avgs.acoustics.rir_model.response_waveform`).

Memory grows with the batch, not the scene: only positions are held per response; the responses
are read from the scene (:meth:`avgs.data.rir.RIRScene.read`) a batch or a chunk at a time and
their float32 STFT targets computed there, once per use (benchmarks/memory.md).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.interaural import DEFAULT_SCALE, fit_direct_level, fit_ild_law, fit_itd_law, fit_scale, ild_law
from avgs.acoustics.direct_placement import FADE_SAMPLES, IMPULSE_SECONDS
from avgs.acoustics.rir_model import RIRModel, response_waveform
from avgs.config import STFTConfig, TrainConfig
from avgs.data.frame import signed_direction
from avgs.data.rir import RIRScene
from avgs.data.rwavs import RWAVSScene
from avgs.evaluation import spatial
from avgs.train.direct_sound_fits import DirectSoundFits, local_table
from avgs.train.logging import JsonLinesLog, Unlogged
from avgs.train.losses import band_masks, decay_loss, energy_loss
from avgs.train.stage2 import Stage2Trainer

PHASES = {"noise": ("noise", 0), "griffin-lim 4": ("griffin-lim", 4), "griffin-lim 16": ("griffin-lim", 16)}
"Phase reconstructions compared at the end of training (T60 / C50 / EDT on val)."


def rir_quick_config(cfg: TrainConfig | None = None) -> TrainConfig:
    """The ``--quick`` preset of the RIR task: few iterations, a narrower network, stage 1 skipped (``init sfm``)."""
    from avgs.train.pipeline import quick_config

    cfg = quick_config(cfg)
    cfg.init = "sfm"
    cfg.store_gaussians = False
    cfg.acoustic.iterations, cfg.acoustic.batch_size = 300, 8
    cfg.acoustic.lr = 1e-3
    cfg.gaussians.init_points = 1500
    cfg.rir.width = 128
    cfg.rir.eval_responses = 16
    cfg.rir.passes = 0.0  # the preset's iterations, whatever the scene's size
    return cfg


def schedule_iterations(cfg: TrainConfig, responses: int) -> int:
    """Stage 2's iterations for ``responses`` training responses: ``cfg.rir.passes`` passes over them
    at ``cfg.acoustic.batch_size`` each, at least ``cfg.rir.least_iterations``, at most
    ``cfg.acoustic.iterations`` (all of those when passes is 0)."""
    if cfg.rir.passes <= 0:
        return cfg.acoustic.iterations
    sized = max(cfg.rir.least_iterations, math.ceil(cfg.rir.passes * responses / cfg.acoustic.batch_size))
    return min(cfg.acoustic.iterations, sized)


CHUNK = 32
"Responses read and transformed at a time outside the training step (statistics, evaluation)."


@dataclass(frozen=True)
class RIRData:
    """One split's rows as the trainer uses them: positions in memory (normalised, radians), the
    responses read from ``scene`` when asked for, with their floored log-magnitude targets."""

    listener: torch.Tensor  # [M, 3] float32
    source: torch.Tensor  # [M, 3] float32
    yaw: torch.Tensor  # [M] float32 radians
    scene: RIRScene
    split: str
    rows: np.ndarray  # [M] int64, rows of the split (RIRScene.index)
    log_floor: float
    stft: STFTConfig
    smooth_bins: int = 1

    def __len__(self) -> int:
        return int(self.listener.shape[0])

    def responses(self, idx) -> np.ndarray:
        """The responses [B, 2, L] float32 of rows ``idx`` of this set, read now."""
        return self.scene.read(self.split, self.rows[np.asarray(idx, dtype=np.int64).reshape(-1)])

    def log_mag(self, idx) -> torch.Tensor:
        """The targets [B, 2, F, N] float32 of rows ``idx``: floored log magnitudes of their responses."""
        return floored_log_magnitude(self.responses(idx), self.log_floor, self.stft, self.smooth_bins)

    def subset(self, pick) -> "RIRData":
        """The rows ``pick`` of this set."""
        pick = np.asarray(pick, dtype=np.int64).reshape(-1)
        t = torch.as_tensor(pick)
        return RIRData(self.listener[t], self.source[t], self.yaw[t], self.scene, self.split, self.rows[pick],
                       self.log_floor, self.stft, self.smooth_bins)

    def chunks(self, size: int = CHUNK):
        """Index ranges of at most ``size`` rows covering the set, in order."""
        return (np.arange(i, min(i + size, len(self))) for i in range(0, len(self), size))


def envelope_magnitude(rir, stft, smooth_bins: int = 1) -> torch.Tensor:
    """STFT magnitudes [..., F, N] of responses [..., L], their power averaged over ``smooth_bins``
    neighbouring bins (a centred box, shorter at the edges): the spectral envelope. The box keeps
    each frame's energy, so the level is unchanged."""
    power = dsp.magnitude(torch.as_tensor(np.asarray(rir, dtype=np.float32)), stft).square()  # [..., F, N]
    if smooth_bins > 1:
        lead, (F, N) = power.shape[:-2], power.shape[-2:]
        flat = power.reshape(-1, F, N).transpose(1, 2).reshape(-1, 1, F)  # [M N, 1, F]
        half = smooth_bins // 2
        kernel = torch.ones(1, 1, 2 * half + 1, dtype=power.dtype)
        total = torch.nn.functional.conv1d(flat, kernel, padding=half)
        count = torch.nn.functional.conv1d(torch.ones_like(flat[:1]), kernel, padding=half)
        power = (total / count).reshape(-1, N, F).transpose(1, 2).reshape(*lead, F, N)
    return power.sqrt()


def floored_log_magnitude(rir, log_floor: float, stft, smooth_bins: int = 1) -> torch.Tensor:
    """``log(max(envelope |STFT(rir)|, e^log_floor))``: responses [..., L] -> [..., F, N] float32."""
    return torch.log(envelope_magnitude(rir, stft, smooth_bins).clamp_min(math.exp(log_floor))).float()


def rir_data(scene: RIRScene, split: str, log_floor: float, stft, smooth_bins: int = 1) -> RIRData:
    """:class:`RIRData` of ``split`` of an :class:`~avgs.data.rir.RIRScene` (positions only; nothing read yet)."""
    rows = scene.index(split)
    return RIRData(
        listener=torch.as_tensor(np.asarray(rows.receiver), dtype=torch.float32),
        source=torch.as_tensor(np.asarray(rows.source), dtype=torch.float32),
        yaw=torch.as_tensor(np.radians(np.asarray(rows.yaw, dtype=np.float64)), dtype=torch.float32),
        scene=scene, split=split, rows=np.arange(len(rows), dtype=np.int64), log_floor=float(log_floor), stft=stft,
        smooth_bins=int(smooth_bins),
    )


def peak_magnitude(scene: RIRScene, split: str, stft) -> float:
    """The largest STFT magnitude of ``split``'s responses, read a chunk at a time."""
    n, peak = len(scene.index(split)), 0.0
    for i in range(0, n, CHUNK):
        h = scene.read(split, np.arange(i, min(i + CHUNK, n)))  # [C, 2, L]
        peak = max(peak, float(dsp.magnitude(torch.from_numpy(h), stft).max()))
    return peak


def mean_log_magnitude(data: RIRData) -> torch.Tensor:
    """The mean target [2, F, N] float32 over ``data``, summed a chunk at a time in float64."""
    total = None
    for idx in data.chunks():
        part = data.log_mag(idx).double().sum(0)  # [2, F, N]
        total = part if total is None else total + part
    return (total / len(data)).float()


class RIRTrainer(Stage2Trainer):
    """Stage 2 for the RIR task: one optimisation step at a time; resumable through ``state_dict``."""

    name = "RIR training"

    def __init__(self, model: RIRModel, train_data: RIRData, cfg: TrainConfig, device: str | torch.device = "cpu"):
        self._init_optimisation(model, train_data, cfg, device)
        self._batch = {k: getattr(train_data, k).to(self.device) for k in ("listener", "source", "yaw")}
        self._bands = band_masks(cfg.stft.n_freq, cfg.stft.sample_rate).to(self.device)  # [K, F]

    def step(self) -> dict:
        """One iteration on a random batch of responses; returns the losses and point bookkeeping."""
        idx = self._begin_step()
        b = {k: v[idx] for k, v in self._batch.items()}
        b["log_mag"] = self.data.log_mag(idx.cpu().numpy()).to(self.device)  # [B, 2, F, N], read for this batch
        pred, lis_idx, src_idx = self.model(b["listener"], b["yaw"], b["source"])  # [B, 2, F, N]
        loss_m = torch.nn.functional.mse_loss(pred, b["log_mag"])
        if self.cfg.rir.energy_weight > 0:
            loss_m = loss_m + self.cfg.rir.energy_weight * energy_loss(pred, b["log_mag"])
        if self.cfg.rir.decay_weight > 0:
            floor = float(self.model.binauralizer.log_floor)
            loss_m = loss_m + self.cfg.rir.decay_weight * decay_loss(pred, b["log_mag"], self._bands, floor)
        return self._update(loss_m, lis_idx, src_idx)

    @torch.no_grad()
    def predict(self, data: RIRData, rows=None, cache=None) -> torch.Tensor:
        """Predicted log magnitudes [B, 2, F, N] of rows ``rows`` of ``data`` (all when None)."""
        self.model.eval()
        cache = self.model.precompute() if cache is None else cache
        t = torch.arange(len(data)) if rows is None else torch.as_tensor(np.asarray(rows, dtype=np.int64)).reshape(-1)
        out = [self.model.log_magnitudes(data.listener[c].to(self.device), data.yaw[c].to(self.device),
                                         data.source[c].to(self.device), cache)[0].cpu() for c in t.split(16)]
        return torch.cat(out)

    @torch.no_grad()
    def evaluate(self, data: RIRData, prefix: str = "val", chunk: int = 16) -> dict:
        """RMSE of the log magnitudes, the model's and the mean response's, ``chunk`` responses at a time."""
        self.model.eval()
        cache = self.model.precompute()
        mean = self.model.binauralizer.mean.detach().cpu()
        sq_model = sq_mean = 0.0
        count = 0
        for idx in data.chunks(chunk):
            target = data.log_mag(idx)  # [C, 2, F, N]
            pred = self.predict(data, idx, cache)
            sq_model += float(torch.sum((pred - target).double() ** 2))
            sq_mean += float(torch.sum((mean[None] - target).double() ** 2))
            count += target.numel()
        return {f"{prefix}_logmag": math.sqrt(sq_model / count), f"{prefix}_logmag_mean": math.sqrt(sq_mean / count)}

    def room_metrics(self, data: RIRData, prefix: str, limit: int, phases=PHASES) -> dict:
        """T60 % / C50 dB / EDT s errors of the predicted waveforms on at most ``limit`` responses of
        ``data`` (evenly spaced), for each phase reconstruction; ``{prefix}_{metric}`` for the configured one."""
        from avgs.evaluation.metrics import c50_error, edt_error, t60_error

        if len(data) == 0 or limit < 1:
            return {}
        pick = np.unique(np.linspace(0, len(data) - 1, min(limit, len(data))).round().astype(int))
        sub = data.subset(pick)
        gt = sub.responses(np.arange(len(sub)))  # [M, 2, L]
        mags = self.model.magnitudes(self.predict(sub))  # [M, 2, F, N]
        direct = self.model.direct_sound(sub.listener.to(self.device), sub.yaw.to(self.device), sub.source.to(self.device))
        fs, length = self.cfg.stft.sample_rate, gt.shape[-1]
        out: dict = {}
        rc = self.cfg.rir
        chosen = next((label for label, (ph, it) in phases.items() if ph == rc.phase and (ph == "noise" or it == rc.phase_iterations)), None)
        todo = dict(phases)
        if chosen is None:
            chosen = f"{rc.phase} {rc.phase_iterations}"
            todo[chosen] = (rc.phase, rc.phase_iterations)
        for label, (phase, its) in todo.items():
            wave = response_waveform(mags, length, self.cfg.stft, phase, its, direct=direct).numpy()  # [M, 2, L]
            errs = np.array([[t60_error(p, g, fs), c50_error(p, g, fs), edt_error(p, g, fs)] for p, g in zip(wave, gt)])
            key = f"{prefix}_phase_{label.replace(' ', '_')}"
            out[key] = {"t60": float(errs[:, 0].mean()), "c50": float(errs[:, 1].mean()), "edt": float(errs[:, 2].mean())}
            if label == chosen:
                out.update({f"{prefix}_t60": out[key]["t60"], f"{prefix}_c50": out[key]["c50"], f"{prefix}_edt": out[key]["edt"]})
        return out


SPEED_OF_SOUND = 343.0
"m/s, when the scene does not say which speed its simulator used."


def speed_of_sound(rir_scene) -> float:
    """The speed of sound (world units per second) of the scene's responses: scene.json's
    ``rir.speed_of_sound`` when it is there, else :data:`SPEED_OF_SOUND` (world units are metres)."""
    meta = getattr(rir_scene, "metadata", None)
    value = (meta or {}).get("rir", {}).get("speed_of_sound") if isinstance(meta, dict) else None
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) and value > 0 else SPEED_OF_SOUND


def direct_energy(h: np.ndarray, fs: float, itd: float, first: int | None = None) -> float:
    """Both ears' energy of a response ``h [2, L]`` over its direct sound's stretch, as
    :func:`~avgs.acoustics.direct_placement.sharpen_direct_sound` takes it: from FADE_SAMPLES before the onset to
    IMPULSE_SECONDS after, and the ITD ``itd`` (seconds) longer, which the lagging ear's stretch starts later.
    ``first``: the onset sample when the caller has it (:func:`avgs.evaluation.spatial.onset`)."""
    first = spatial.onset(h) if first is None else int(first)
    lo = max(0, first - FADE_SAMPLES)
    hi = min(h.shape[-1], first + int(round((IMPULSE_SECONDS + abs(itd)) * fs)))
    return float(np.sum(np.asarray(h[:, lo:hi], dtype=np.float64) ** 2))


class ImpulseResponseTraining(DirectSoundFits):
    """:class:`~avgs.train.tasks.TaskTraining` of the impulse-response task."""

    label = "RIR training"
    scores = ("val_logmag", "val_logmag_mean")
    quick_config = staticmethod(rir_quick_config)

    def __init__(self, scene_dir, cfg: TrainConfig):
        self.scene = RWAVSScene(scene_dir, cfg.stft, audio=False)  # frame, source, metadata, frames for stage 1
        self.responses = RIRScene(scene_dir)
        if int(self.responses.sample_rate) != cfg.stft.sample_rate:
            raise ValueError(f"{self.responses.scene_dir}: responses at {self.responses.sample_rate} Hz, "
                             f"the model runs at {cfg.stft.sample_rate} Hz")
        self.train_set = self.responses.index("train")  # positions only: the responses are read a batch at a time
        if len(self.train_set) == 0:
            raise ValueError(f"{self.responses.scene_dir}: no training responses")
        self.evals: dict[str, RIRData] = {}
        self.itd_scale: float | None = None  # fitted by configure() for a fresh run
        self.itd_law: list[float] | None = None  # seconds per harmonic, likewise
        self.ild_law: list[float] | None = None  # dB per harmonic, fitted by configure() for a fresh run
        self.ild_table: tuple | None = None  # (local_at [M, 6], local_residual [M], local_scale [6]): the law's local correction
        self.level_law: list[float] | None = None  # dB coefficients of the direct sound's level law, likewise
        self._in_sight: np.ndarray | None = None  # [M] training pairs whose first arrival is the direct sound
        self._theta: torch.Tensor | None = None  # [M] their directions, radians
        self._ilds: np.ndarray | None = None  # [M] their early ILDs, dB
        self._itds: np.ndarray | None = None  # [M] their early ITDs, s (the metric's sign)
        self._onsets: np.ndarray | None = None  # [M] their onsets, s
        self._before_walls: tuple = (None, None)  # (ild_law, ild_table) before the walls' fit: refit_geometry starts there
        self._seed = int(cfg.seed)
        self._cfg = cfg  # the run's configuration (configure() may change it)
        self._log: JsonLinesLog | None = None

    def configure(self, cfg: TrainConfig, log: JsonLinesLog) -> None:
        """A fresh run: the responses' length and frames, and the speed of sound, into ``cfg.rir``; stage 2's
        iterations sized to the training responses (:func:`schedule_iterations`)."""
        self._cfg = cfg
        cfg.rir.length = int(self.responses.length)
        cfg.rir.frames = dsp.n_frames(cfg.rir.length, cfg.stft)
        cfg.rir.sound_speed = speed_of_sound(self.responses) * self.scene.frame.scale  # normalised units per second
        log.write({"stage": "rir", "event": "task", "task": "rir", "responses": len(self.train_set), "length": cfg.rir.length})
        limit = cfg.acoustic.iterations
        cfg.acoustic.iterations = schedule_iterations(cfg, len(self.train_set))
        if cfg.rir.passes > 0:
            log.write({"stage": "rir", "event": "schedule", "iterations": cfg.acoustic.iterations, "passes": cfg.rir.passes,
                       "responses": len(self.train_set), "batch_size": cfg.acoustic.batch_size, "at_most": limit})
        self.itd_scale, self.itd_law, self.ild_law, self._in_sight, self._log = None, None, None, None, log
        self.ild_table, self.level_law = None, None
        if cfg.rir.direct_sound:  # the head that the training responses' direct sounds carry
            train = self.train_set
            theta = signed_direction(torch.as_tensor(np.asarray(train.receiver), dtype=torch.float64),
                                     torch.as_tensor(np.radians(np.asarray(train.yaw, dtype=np.float64))),
                                     torch.as_tensor(np.asarray(train.source), dtype=torch.float64))
            n = len(train)
            fs = cfg.stft.sample_rate
            itds, ilds, onsets, directs = [], [], [], []
            for i in range(0, n, CHUNK):
                for h in self.responses.read("train", np.arange(i, min(i + CHUNK, n))):
                    first = spatial.onset(h)
                    itds.append(spatial.response_itd(h, fs))
                    ilds.append(spatial.early_ild(h, fs))
                    onsets.append(first / fs)
                    directs.append(direct_energy(h, fs, itds[-1], first))
            self.itd_scale = fit_scale(theta.numpy(), itds)
            log.write({"stage": "itd", "event": "fit", "scale_us": self.itd_scale * 1e6, "default_us": DEFAULT_SCALE * 1e6,
                       "responses": len(itds)})
            distance = np.linalg.norm(np.asarray(train.source, dtype=np.float64) - np.asarray(train.receiver, dtype=np.float64),
                                      axis=-1)  # [M] normalised units, as the speed of sound
            in_sight = spatial.in_sight(onsets, distance, cfg.rir.sound_speed)  # the first arrival is the direct sound
            self._in_sight = in_sight  # the straight path's tests are fitted on them with the model's points (trainer)
            self._theta, self._ilds = theta, np.asarray(ilds, dtype=np.float64)  # for the walls' reflections (trainer)
            self._itds, self._onsets = np.asarray(itds, dtype=np.float64), np.asarray(onsets)  # [M] s: behind a wall, the first arrival (trainer)
            if cfg.rir.direct_itd:  # the head's own ITD against the direction, from those responses
                law = fit_itd_law(theta.numpy()[in_sight], -np.asarray(itds)[in_sight])
                self.itd_law = None if law is None else [float(c) for c in law]
                cfg.rir.direct_itd = law is not None  # too few responses in sight: Woodworth's sphere, said in the log
                log.write({"stage": "itd", "event": "law", "harmonics_us": None if law is None else [1e6 * c for c in self.itd_law],
                           "responses": int(in_sight.sum())})
            if cfg.rir.direct_level:  # the direct sound's level: 1 / d^2 and the head's gain, from the same responses
                law = fit_direct_level(theta.numpy()[in_sight], distance[in_sight], np.asarray(directs)[in_sight])
                self.level_law = None if law is None else [float(c) for c in law]
                cfg.rir.direct_level = law is not None  # too few responses in sight: B's level, said in the log
                log.write({"stage": "level", "event": "fit", "coefficients_db": self.level_law, "responses": int(in_sight.sum())})
            if cfg.rir.direct_ild:  # the head shadow, from the same responses
                law = fit_ild_law(theta.numpy()[in_sight], np.asarray(ilds)[in_sight])
                self.ild_law = None if law is None else [float(c) for c in law]
                cfg.rir.direct_ild = law is not None  # too few responses in sight of the source: B's ILD, said in the log
                log.write({"stage": "ild", "event": "fit", "harmonics_db": self.ild_law, "responses": int(in_sight.sum())})
                cfg.rir.ild_table = 0
                if law is not None and cfg.rir.ild_local:  # what the room adds to the law near the training responses
                    self.ild_table = local_table(train, theta, np.asarray(ilds), in_sight,
                                                 ild_law(theta, torch.as_tensor(law, dtype=torch.float64)).numpy())
                    cfg.rir.ild_table = int(self.ild_table[1].shape[0])
                    log.write({"stage": "ild", "event": "local", "responses": cfg.rir.ild_table,
                               "median_abs_residual_db": float(self.ild_table[1].abs().median()) if cfg.rir.ild_table else None})
            self._before_walls = (self.ild_law, self.ild_table)  # what fit_reflections starts from (refit_geometry)

    def trainer(self, model: RIRModel, cfg: TrainConfig, resumed: bool) -> RIRTrainer:
        """The trainer on the training responses; a fresh model's floor, mean response and mean
        log distance set from them (a resumed one keeps its own)."""
        if int(self.responses.length) != cfg.rir.length:
            raise ValueError(f"{self.responses.scene_dir}: responses of {self.responses.length} samples, "
                             f"the checkpoint's of {cfg.rir.length}")
        if resumed and self._in_sight is None and cfg.rir.direct_sound:  # what the end's fits read (refit_geometry)
            self.configure(copy.deepcopy(cfg), Unlogged())  # the same measures of the training pairs; cfg as it was
            self._log = None
        if not resumed and self.itd_scale is not None:
            with torch.no_grad():
                model.binauralizer.itd_scale.fill_(self.itd_scale)
        if not resumed and self.itd_law is not None:
            with torch.no_grad():
                model.binauralizer.itd_law.copy_(torch.tensor(self.itd_law))
        if not resumed and self.level_law is not None and model.binauralizer.level_law is not None:
            with torch.no_grad():
                model.binauralizer.level_law.copy_(torch.tensor(self.level_law))
        if not resumed and self.ild_law is not None:
            with torch.no_grad():
                model.binauralizer.ild_law.copy_(torch.tensor(self.ild_law))
                if self.ild_table is not None and getattr(model.binauralizer, "local_at", None) is not None:
                    for name, value in zip(("local_at", "local_residual", "local_scale"), self.ild_table):
                        getattr(model.binauralizer, name).copy_(value)
            self._fit_sight(model)
            if getattr(model.binauralizer, "reflecting_walls", None) is not None:
                self.fit_reflections(model)
            if getattr(model.binauralizer, "blocked_lag", None) is not None:
                self.fit_lag(model)
        if not resumed and self._in_sight is not None and getattr(model.binauralizer, "wall_loss", None) is not None:
            self._fit_walls(model)
        if resumed:
            log_floor = float(model.binauralizer.log_floor)
        else:
            peak = peak_magnitude(self.responses, "train", cfg.stft)
            if not (math.isfinite(peak) and peak > 0):
                raise ValueError(f"{self.responses.scene_dir}: the training responses are silent or not finite")
            log_floor = math.log(peak) + cfg.rir.floor_db / 20.0 * math.log(10.0)
        train = rir_data(self.responses, "train", log_floor, cfg.stft, cfg.rir.smooth_bins)
        if not resumed:
            with torch.no_grad():
                model.binauralizer.log_floor.fill_(log_floor)
                model.binauralizer.mean.copy_(mean_log_magnitude(train))
                if hasattr(model.binauralizer, "log_distance_mean"):
                    model.binauralizer.log_distance_mean.fill_(
                        float(torch.log(torch.linalg.vector_norm(train.source - train.listener, dim=-1).clamp_min(1e-3)).mean()))
        self.evals = {name: rir_data(self.responses, name, log_floor, cfg.stft, cfg.rir.smooth_bins)
                      for name in ("val", "heldout") if len(self.responses.pairs[name])}
        return RIRTrainer(model, train, cfg, cfg.device)

    def validate(self, trainer: RIRTrainer) -> dict:
        return trainer.evaluate(self.evals["val"]) if "val" in self.evals else {}

    def final(self, trainer: RIRTrainer, final: dict) -> dict:
        """The straight path's tests fitted again on G_a as stage 2 left it (:meth:`refit_geometry`); behind a
        wall, the early ILD's factor fitted (:meth:`fit_blocked_ild`, B trained); then log magnitudes and
        T60 / C50 / EDT on every held-back split."""
        self.refit_geometry(trainer.model)
        if getattr(trainer.model.binauralizer, "blocked_ild", None) is not None:
            self.fit_blocked_ild(trainer.model)
        final = final or {"iteration": trainer.iteration, "points": trainer.model.points.num_points}
        for name, data in self.evals.items():
            final.update(trainer.evaluate(data, name))
            final.update(trainer.room_metrics(data, name, trainer.cfg.rir.eval_responses))
        return final

    def bounds(self, model: RIRModel, gaussians) -> np.ndarray:
        """Box [2, 3] (world) around the audio points, the receivers, the sources and the scene's own source."""
        r, scene = self.responses, self.scene
        parts = [model.points.X.detach().cpu().numpy().reshape(-1, 3), np.asarray(r.sources).reshape(-1, 3),
                 np.asarray(r.receivers).reshape(-1, 3), np.asarray(scene.source).reshape(1, 3)]
        pts = scene.frame.to_world(np.concatenate(parts).astype(np.float64))
        return np.stack([pts.min(0), pts.max(0)])

    def checkpoint_extra(self, metrics: dict | None) -> dict:
        """The training positions, and the final metrics that are numbers (the per-phase ones are dicts)."""
        positions = {"sources": torch.as_tensor(np.asarray(self.responses.sources, dtype=np.float32)).reshape(-1, 3),
                     "receivers": torch.as_tensor(np.asarray(self.responses.receivers, dtype=np.float32)).reshape(-1, 3)}
        return {"rir": positions, "metrics": {k: v for k, v in (metrics or {}).items() if not isinstance(v, dict)}}
