"""The binaural task's training hooks (``avgs train SCENE``, :class:`BinauralTraining`, driven
by the one loop of :mod:`avgs.train.pipeline`): G_a, F and B on the scene's binaural clips of
one source (:class:`~avgs.train.stage2.Stage2Trainer`: the paper's L_m on the mixture and ear
magnitudes), validated by MAG and ENV of the default synthesis, as ``avgs eval`` scores them.
"""

from __future__ import annotations

import numpy as np

from avgs.acoustics.model import AVGSModel
from avgs.config import TrainConfig
from avgs.data.rwavs import RWAVSScene
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

    def configure(self, cfg: TrainConfig, log: JsonLinesLog) -> None:
        """Nothing to size: the clips' STFT is the configuration's."""

    def trainer(self, model: AVGSModel, cfg: TrainConfig, resumed: bool) -> Stage2Trainer:
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
