"""Training for the impulse-response task (``avgs train SCENE --task rir``): scene folder in,
``scene.ckpt`` (+ log + curves) out, as the binaural task's pipeline (:mod:`avgs.train.pipeline`).

An RIR scene (``DATA_ROOT/<scene>/rir/``, :mod:`avgs.data.rir`) is also an RWAVS scene, so G_a
comes from stage 1 exactly as for the binaural task (``--init sfm`` takes scene.json's
surfaces and skips training G). Then G_a, F and the RIR network
(:class:`~avgs.acoustics.rir_model.RIRModel`) train on the log magnitudes of the training
responses (the STFT of each response, per ear, floored ``RIRConfig.floor_db`` below the
loudest training bin; no per-response normalisation, so level falls with distance):

    L = (1 - lambda_a) [MSE(log |S_pred|, log |S_gt|) + w_e L_energy + w_d L_decay] + lambda_a L_v

(L_energy: each ear's energy per bin and the ears' difference, :func:`energy_loss`; L_decay:
the energy decay curves, :func:`decay_loss`; L_v: the vicinity points' prior, stage 2's)

with stage 2's optimiser groups, schedule, audio-aware point management and exact resume
(:class:`RIRTrainer` is a :class:`~avgs.train.stage2.Stage2Trainer` with another batch and
loss). Every ``eval_every`` iterations the log-magnitude RMSE on val (``val_logmag``) is
logged beside that of the training responses' mean (``val_logmag_mean``: predicting the mean
response); at the end T60 / C50 / EDT errors (:mod:`avgs.evaluation.metrics`) of the waveforms on val
and heldout, for each phase reconstruction (:func:`~avgs.acoustics.rir_model.response_waveform`).
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.points import AudioPoints
from avgs.acoustics.rir_model import RIRModel, response_waveform, silenced_magnitudes
from avgs.io.checkpoint import build_checkpoint, outline_from_metadata, save_checkpoint
from avgs.config import TrainConfig
from avgs.train.logging import JsonLinesLog, log_paths, plot_curves
from avgs.train.stage2 import Stage2Trainer

TASK = "rir"
"The checkpoint's ``task`` for this training."

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
    return cfg


@dataclass(frozen=True)
class RIRData:
    """One split's responses as the trainer uses them (normalised positions, radians)."""

    listener: torch.Tensor  # [M, 3] float32
    source: torch.Tensor  # [M, 3] float32
    yaw: torch.Tensor  # [M] float32 radians
    log_mag: torch.Tensor  # [M, 2, F, N] float32, floored
    rir: np.ndarray  # [M, 2, L] float32, the responses themselves (for T60 / C50 / EDT)

    def __len__(self) -> int:
        return int(self.listener.shape[0])


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


def ear_energy(log_mag: torch.Tensor) -> torch.Tensor:
    """Each ear's energy per frequency bin, as the log of the power summed over the frames: [..., 2, F, N] -> [..., 2, F]."""
    return torch.logsumexp(2.0 * log_mag, dim=-1)


def energy_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """MSE of each ear's :func:`ear_energy` plus MSE of the ears' difference in it (the interaural level difference)."""
    e_pred, e_true = ear_energy(pred), ear_energy(target)  # [B, 2, F]
    ild_pred, ild_true = e_pred[:, 0] - e_pred[:, 1], e_true[:, 0] - e_true[:, 1]  # [B, F]
    return torch.nn.functional.mse_loss(e_pred, e_true) + torch.nn.functional.mse_loss(ild_pred, ild_true)


DECAY_BANDS_HZ = (250.0, 500.0, 1000.0, 2000.0, 4000.0)
"Edges between the octave bands whose energy decay :func:`decay_loss` fits (besides the whole band)."

DECAY_RANGE_DB = 50.0
"The decay loss looks at each curve down to this many dB below its start (T60 reads 5 to 35 dB, EDT 0 to 10)."


def band_masks(n_freq: int, sample_rate: float, edges_hz=DECAY_BANDS_HZ) -> torch.Tensor:
    """[K, F] 0/1 float: the whole band, then one row per octave band between ``edges_hz`` (empty bands dropped)."""
    freqs = torch.linspace(0.0, sample_rate / 2.0, n_freq)  # [F]
    bounds = [0.0, *edges_hz, math.inf]
    rows = [torch.ones(n_freq)] + [((freqs >= lo) & (freqs < hi)).float() for lo, hi in zip(bounds[:-1], bounds[1:])]
    return torch.stack([r for r in rows if r.sum() > 0])


def decay_curves(power: torch.Tensor, bands: torch.Tensor) -> torch.Tensor:
    """Schroeder energy decay curves in nats of power re their start, per ear and band: STFT
    power [..., 2, F, N] -> [..., 2, K, N]; the curve bottoms out ``DECAY_RANGE_DB + 30`` dB down."""
    band_power = torch.einsum("kf,...fn->...kn", bands.to(power), power)  # [..., 2, K, N]
    edc = band_power.flip(-1).cumsum(-1).flip(-1)  # energy from frame n on
    start = edc[..., :1]
    return torch.log(edc + start * 10.0 ** (-(DECAY_RANGE_DB + 30.0) / 10.0) + 1e-30) - torch.log(start + 1e-30)


def decay_loss(pred: torch.Tensor, target: torch.Tensor, bands: torch.Tensor, log_floor: float) -> torch.Tensor:
    """MSE of the energy decay curves (:func:`decay_curves`) of predicted and true log magnitudes
    [B, 2, F, N], over the frames where the true curve is within ``DECAY_RANGE_DB`` of its start.

    The prediction's power is that of the magnitudes a waveform is made of
    (:func:`~avgs.acoustics.rir_model.silenced_magnitudes`: silence at the floor), the truth's
    that of the response with the floor's power taken off: the curves T60, EDT and C50 read."""
    floor_power = math.exp(2.0 * log_floor)
    d_pred = decay_curves(silenced_magnitudes(pred, log_floor).square(), bands)
    d_true = decay_curves((torch.exp(2.0 * target) - floor_power).clamp_min(0.0), bands)
    keep = (d_true > -DECAY_RANGE_DB / 10.0 * math.log(10.0)).float()
    return ((d_pred - d_true).square() * keep).sum() / keep.sum().clamp_min(1.0)


def floored_log_magnitude(rir, log_floor: float, stft, smooth_bins: int = 1) -> torch.Tensor:
    """``log(max(envelope |STFT(rir)|, e^log_floor))``: responses [..., L] -> [..., F, N] float32."""
    return torch.log(envelope_magnitude(rir, stft, smooth_bins).clamp_min(math.exp(log_floor))).float()


def rir_data(responses, log_floor: float, stft, smooth_bins: int = 1) -> RIRData:
    """:class:`RIRData` of an ``avgs.data.rir.RIRSet``."""
    return RIRData(
        listener=torch.as_tensor(np.asarray(responses.receiver), dtype=torch.float32),
        source=torch.as_tensor(np.asarray(responses.source), dtype=torch.float32),
        yaw=torch.as_tensor(np.radians(np.asarray(responses.yaw, dtype=np.float64)), dtype=torch.float32),
        log_mag=floored_log_magnitude(responses.rir, log_floor, stft, smooth_bins),
        rir=np.asarray(responses.rir, dtype=np.float32),
    )


class RIRTrainer(Stage2Trainer):
    """Stage 2 for the RIR task: one optimisation step at a time; resumable through ``state_dict``."""

    name = "RIR training"

    def __init__(self, model: RIRModel, train_data: RIRData, cfg: TrainConfig, device: str | torch.device = "cpu"):
        self._init_optimisation(model, train_data, cfg, device)
        self._batch = {k: getattr(train_data, k).to(self.device) for k in ("listener", "source", "yaw", "log_mag")}
        self._bands = band_masks(cfg.stft.n_freq, cfg.stft.sample_rate).to(self.device)  # [K, F]

    def step(self) -> dict:
        """One iteration on a random batch of responses; returns the losses and point bookkeeping."""
        idx = self._begin_step()
        b = {k: v[idx] for k, v in self._batch.items()}
        pred, lis_idx, src_idx = self.model(b["listener"], b["yaw"], b["source"])  # [B, 2, F, N]
        loss_m = torch.nn.functional.mse_loss(pred, b["log_mag"])
        if self.cfg.rir.energy_weight > 0:
            loss_m = loss_m + self.cfg.rir.energy_weight * energy_loss(pred, b["log_mag"])
        if self.cfg.rir.decay_weight > 0:
            floor = float(self.model.binauralizer.log_floor)
            loss_m = loss_m + self.cfg.rir.decay_weight * decay_loss(pred, b["log_mag"], self._bands, floor)
        return self._update(loss_m, lis_idx, src_idx)

    @torch.no_grad()
    def predict(self, data: RIRData, chunk: int = 16) -> torch.Tensor:
        """Predicted log magnitudes [M, 2, F, N] of every response of ``data``."""
        self.model.eval()
        cache = self.model.precompute()
        out = [self.model.log_magnitudes(data.listener[i : i + chunk].to(self.device), data.yaw[i : i + chunk].to(self.device),
                                         data.source[i : i + chunk].to(self.device), cache)[0].cpu()
               for i in range(0, len(data), chunk)]
        return torch.cat(out)

    def evaluate(self, data: RIRData, prefix: str = "val") -> dict:
        """RMSE of the log magnitudes, the model's and the mean response's."""
        pred = self.predict(data)
        mean = self.model.binauralizer.mean.detach().cpu()
        return {f"{prefix}_logmag": float(torch.sqrt(torch.mean((pred - data.log_mag) ** 2))),
                f"{prefix}_logmag_mean": float(torch.sqrt(torch.mean((mean[None] - data.log_mag) ** 2)))}

    def room_metrics(self, data: RIRData, prefix: str, limit: int, phases=PHASES) -> dict:
        """T60 % / C50 dB / EDT s errors of the predicted waveforms on at most ``limit`` responses of
        ``data`` (evenly spaced), for each phase reconstruction; ``{prefix}_{metric}`` for the configured one."""
        from avgs.evaluation.metrics import c50_error, edt_error, t60_error

        if len(data) == 0 or limit < 1:
            return {}
        pick = np.unique(np.linspace(0, len(data) - 1, min(limit, len(data))).round().astype(int))
        sub = RIRData(data.listener[pick], data.source[pick], data.yaw[pick], data.log_mag[pick], data.rir[pick])
        mags = self.model.magnitudes(self.predict(sub))  # [M, 2, F, N]
        fs, length = self.cfg.stft.sample_rate, sub.rir.shape[-1]
        out: dict = {}
        rc = self.cfg.rir
        chosen = next((label for label, (ph, it) in phases.items() if ph == rc.phase and (ph == "noise" or it == rc.phase_iterations)), None)
        todo = dict(phases)
        if chosen is None:
            chosen = f"{rc.phase} {rc.phase_iterations}"
            todo[chosen] = (rc.phase, rc.phase_iterations)
        for label, (phase, its) in todo.items():
            wave = response_waveform(mags, length, self.cfg.stft, phase, its).numpy()  # [M, 2, L]
            errs = np.array([[t60_error(p, g, fs), c50_error(p, g, fs), edt_error(p, g, fs)] for p, g in zip(wave, sub.rir)])
            key = f"{prefix}_phase_{label.replace(' ', '_')}"
            out[key] = {"t60": float(errs[:, 0].mean()), "c50": float(errs[:, 1].mean()), "edt": float(errs[:, 2].mean())}
            if label == chosen:
                out.update({f"{prefix}_t60": out[key]["t60"], f"{prefix}_c50": out[key]["c50"], f"{prefix}_edt": out[key]["edt"]})
        return out


def open_rir_scene(scene_dir):
    """The scene's responses (:class:`avgs.data.rir.RIRScene`)."""
    from avgs.data.rir import RIRScene

    return RIRScene(scene_dir)


SPEED_OF_SOUND = 343.0
"m/s, when the scene does not say which speed its simulator used."


def speed_of_sound(rir_scene) -> float:
    """The speed of sound (world units per second) of the scene's responses: scene.json's
    ``rir.speed_of_sound`` when it is there, else :data:`SPEED_OF_SOUND` (world units are metres)."""
    meta = getattr(rir_scene, "metadata", None)
    value = (meta or {}).get("rir", {}).get("speed_of_sound") if isinstance(meta, dict) else None
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) and value > 0 else SPEED_OF_SOUND


def _bounds_world(scene, rir_scene, X: torch.Tensor) -> np.ndarray:
    """Box [2, 3] (world) around the audio points, the receivers, the sources and the scene's own source."""
    parts = [X.detach().cpu().numpy().reshape(-1, 3), np.asarray(rir_scene.sources).reshape(-1, 3),
             np.asarray(rir_scene.receivers).reshape(-1, 3), np.asarray(scene.source).reshape(1, 3)]
    pts = scene.frame.to_world(np.concatenate(parts).astype(np.float64))
    return np.stack([pts.min(0), pts.max(0)])


def train_rir(
    scene_dir: str | Path,
    out: str | Path,
    cfg: TrainConfig | None = None,
    *,
    resume: bool = False,
    progress: bool = True,
    initial_points: AudioPoints | None = None,
    stage1: str | Path | None = None,
) -> dict:
    """Train the RIR task on one scene and write ``out``; returns the final log record.

    Arguments as :func:`avgs.train.pipeline.train_scene`. The responses' length and frames
    are set on ``cfg.rir`` from the scene (stored with the checkpoint).
    """
    from tqdm.auto import tqdm

    from avgs.data.rwavs import RWAVSScene
    from avgs.train.pipeline import _stage1, resume_from
    from avgs.train.stage1 import stage1_path

    cfg = copy.deepcopy(cfg or TrainConfig())
    out = Path(out)
    log_path, png_path = log_paths(out)
    scene = RWAVSScene(scene_dir, cfg.stft)
    rir_scene = open_rir_scene(scene_dir)
    if int(rir_scene.sample_rate) != cfg.stft.sample_rate:
        raise ValueError(f"{rir_scene.scene_dir}: responses at {rir_scene.sample_rate} Hz, the model runs at {cfg.stft.sample_rate} Hz")
    train_set = rir_scene.responses("train")
    if len(train_set) == 0:
        raise ValueError(f"{rir_scene.scene_dir}: no training responses")
    torch.manual_seed(cfg.seed)

    resumed = None
    if resume and out.is_file():
        resumed, cfg, log, points, gaussians = resume_from(out, cfg, log_path, TASK)
    else:
        cfg.rir.length = int(rir_scene.length)
        cfg.rir.frames = dsp.n_frames(cfg.rir.length, cfg.stft)
        cfg.rir.sound_speed = speed_of_sound(rir_scene) * scene.frame.scale  # normalised units per second
        log = JsonLinesLog(log_path)
        log.write({"stage": "rir", "event": "task", "task": TASK, "responses": len(train_set), "length": cfg.rir.length})
        t0 = time.perf_counter()
        if initial_points is not None:
            points, gaussians = initial_points, None
        else:
            points, gaussians = _stage1(scene, cfg, log, progress, stage1_path(out), Path(stage1) if stage1 else None)
        log.write({"stage": "stage1", "event": "done", "seconds": time.perf_counter() - t0, "points": points.num_points})
    if int(rir_scene.length) != cfg.rir.length:
        raise ValueError(f"{rir_scene.scene_dir}: responses of {rir_scene.length} samples, the checkpoint's of {cfg.rir.length}")

    torch.manual_seed(cfg.seed)
    model = RIRModel(points, cfg.acoustic, cfg.rir, cfg.stft)
    if resumed is not None:
        if model.field is not None:
            model.field.load_state_dict(resumed["field"])
        model.binauralizer.load_state_dict(resumed["binauralizer"])
        log_floor = float(model.binauralizer.log_floor)
    else:
        peak = float(dsp.magnitude(torch.as_tensor(train_set.rir), cfg.stft).max())
        if not (math.isfinite(peak) and peak > 0):
            raise ValueError(f"{rir_scene.scene_dir}: the training responses are silent or not finite")
        log_floor = math.log(peak) + cfg.rir.floor_db / 20.0 * math.log(10.0)
    train = rir_data(train_set, log_floor, cfg.stft, cfg.rir.smooth_bins)
    if resumed is None:
        with torch.no_grad():
            model.binauralizer.log_floor.fill_(log_floor)
            model.binauralizer.mean.copy_(train.log_mag.mean(0))
            if hasattr(model.binauralizer, "log_distance_mean"):
                model.binauralizer.log_distance_mean.fill_(
                    float(torch.log(torch.linalg.vector_norm(train.source - train.listener, dim=-1).clamp_min(1e-3)).mean()))
    trainer = RIRTrainer(model, train, cfg, cfg.device)
    if resumed is not None:
        try:
            trainer.load_state_dict(resumed["train_state"])
        except ValueError as exc:
            raise ValueError(f"{out}: cannot resume from its training state: {exc}") from None
        log.write({"stage": "resume", "iteration": trainer.iteration, "file": str(out)})
    splits = {name: rir_scene.responses(name) for name in ("val", "heldout")}
    evals = {name: rir_data(s, log_floor, cfg.stft, cfg.rir.smooth_bins) for name, s in splits.items() if len(s)}
    outline = outline_from_metadata(scene.metadata)
    positions = {"sources": torch.as_tensor(np.asarray(rir_scene.sources, dtype=np.float32)).reshape(-1, 3),
                 "receivers": torch.as_tensor(np.asarray(rir_scene.receivers, dtype=np.float32)).reshape(-1, 3)}

    def save(metrics: dict | None = None) -> None:
        ckpt = build_checkpoint(
            model, scene.frame, scene.source, cfg, history=log.records, gaussians=gaussians, name=scene.name,
            bounds_world=_bounds_world(scene, rir_scene, model.points.X), outline_world=outline, stft=cfg.stft,
            extra={"task": TASK, "rir": positions, "train_state": trainer.state_dict(),
                   "metrics": {k: v for k, v in (metrics or {}).items() if not isinstance(v, dict)}},
        )
        save_checkpoint(ckpt, out)

    total = cfg.acoustic.iterations
    final: dict = {}
    bar = tqdm(total=total, initial=trainer.iteration, desc="RIR training", disable=not progress, dynamic_ncols=True)
    t0 = time.perf_counter()
    while trainer.iteration < total:
        rec = trainer.step()
        it = trainer.iteration
        bar.update(1)
        record = {"stage": "stage2", "iteration": it, **rec}
        if "val" in evals and (it % cfg.eval_every == 0 or it == total):
            record.update(trainer.evaluate(evals["val"]))
            bar.set_postfix(loss=f"{rec['loss']:.4f}", logmag=f"{record['val_logmag']:.3f}")
        if it % cfg.log_every == 0 or it == total or rec["added"] or rec["removed"] or "val_logmag" in record:
            log.write({**record, "seconds": time.perf_counter() - t0})
        if it == total:
            final = {k: record[k] for k in ("iteration", "loss", "points", "val_logmag", "val_logmag_mean") if k in record}
        elif it % cfg.checkpoint_every == 0:
            save()
    bar.close()
    if not final:
        final = {"iteration": trainer.iteration, "points": model.points.num_points}
    for name, data in evals.items():
        final.update(trainer.evaluate(data, name))
        final.update(trainer.room_metrics(data, name, cfg.rir.eval_responses))
    log.write({"stage": "final", **final})
    save(final)
    plot_curves(log.records, png_path)
    return final
