"""The binaural task's training hooks (``avgs train SCENE``, :class:`BinauralTraining`, driven
by the one loop of :mod:`avgs.train.pipeline`): G_a, F and B on the scene's binaural clips of
one source (:class:`~avgs.train.stage2.Stage2Trainer`: the paper's L_m on the mixture and ear
magnitudes), validated by MAG and ENV of the default synthesis, as ``avgs eval`` scores them.
The ears' timing is not learned by gradient: the ITD scale of the spherical head
(:mod:`avgs.acoustics.interaural`) is fitted once to the ITDs the training recordings carry.
"""

from __future__ import annotations

import numpy as np
import torch

from avgs.acoustics.interaural import DEFAULT_SCALE, fit_scale
from avgs.acoustics.model import AVGSModel
from avgs.config import TrainConfig
from avgs.data.frame import signed_direction
from avgs.data.rwavs import RWAVSScene
from avgs.evaluation import spatial
from avgs.train.logging import JsonLinesLog
from avgs.train.stage2 import Stage2Trainer
from avgs.train.tasks import quick_config


class BinauralTraining:
    """:class:`~avgs.train.tasks.TaskTraining` of the binaural task."""

    label = "stage 2 (audio)"
    scores = ("val_mag", "val_env")
    quick_config = staticmethod(quick_config)

    def __init__(self, scene_dir, cfg: TrainConfig):
        self.scene = RWAVSScene(scene_dir, cfg.stft)
        if not self.scene.train:
            raise ValueError(f"{self.scene.root}: no training clips")
        self.val = None
        self.itd_scale: float | None = None  # fitted by configure() for a fresh run

    def configure(self, cfg: TrainConfig, log: JsonLinesLog) -> None:
        """With ``interaural_delay``, the ITD scale of Woodworth's head that the training
        recordings carry (:func:`~avgs.acoustics.interaural.fit_scale` of their GCC-PHAT ITDs)."""
        self.itd_scale = None
        if not cfg.acoustic.interaural_delay:
            return
        itds = [spatial.itd(c.binaural, cfg.stft.sample_rate) for c in self.scene.train]
        thetas = [float(signed_direction(torch.as_tensor(c.listener[None], dtype=torch.float64),
                                         torch.tensor([c.yaw], dtype=torch.float64),
                                         torch.as_tensor(self.scene.source, dtype=torch.float64))[0]) for c in self.scene.train]
        self.itd_scale = fit_scale(thetas, itds)
        log.write({"stage": "itd", "event": "fit", "scale_us": self.itd_scale * 1e6, "default_us": DEFAULT_SCALE * 1e6,
                   "clips": len(itds)})

    def trainer(self, model: AVGSModel, cfg: TrainConfig, resumed: bool) -> Stage2Trainer:
        if not resumed and self.itd_scale is not None:
            with torch.no_grad():
                model.binauralizer.itd_scale.fill_(self.itd_scale)
        trainer = Stage2Trainer(model, self.scene.dataset("train", cfg.stft), cfg, cfg.device)
        self.val = self.scene.dataset("val", cfg.stft) if self.scene.val else None
        return trainer

    def validate(self, trainer: Stage2Trainer) -> dict:
        return {} if self.val is None else trainer.evaluate(self.val)

    def final(self, trainer: Stage2Trainer, final: dict) -> dict:
        if final:
            return final
        final = {"iteration": trainer.iteration, "points": trainer.model.points.num_points}  # resumed at or past the end
        final.update(self.validate(trainer))
        return final

    def bounds(self, model: AVGSModel, gaussians: dict | None) -> np.ndarray:
        """Box [2, 3] (world) around the audio points, G, the listener poses and the source."""
        scene = self.scene
        parts = [model.points.X.detach().cpu().numpy().reshape(-1, 3), scene.source[None]]
        parts += [np.stack([c.listener for c in clips]) for clips in (scene.train, scene.val) if clips]
        if gaussians is not None and "means" in gaussians:
            parts.append(gaussians["means"].detach().cpu().numpy().reshape(-1, 3))
        pts = scene.frame.to_world(np.concatenate(parts).astype(np.float64))
        return np.stack([pts.min(0), pts.max(0)])

    def checkpoint_extra(self, metrics: dict | None) -> dict:
        return {"metrics": dict(metrics or {})}
