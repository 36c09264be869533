"""What the one training loop (:func:`avgs.train.pipeline.train_scene`) asks of a task.

Each task of :mod:`avgs.tasks` names its hooks (``Task.training``):
:class:`~avgs.train.binaural.BinauralTraining` (binaural clips of one source) and
:class:`~avgs.train.impulse_responses.ImpulseResponseTraining` (responses of many sources).
The loop owns what every task shares: stage 1, the model built from the task's registry entry,
resume, the step loop, the evaluation and logging cadence, checkpoints and curves. The hooks
own the scene's targets, the trainer (its batch and loss: a
:class:`~avgs.train.stage2.Stage2Trainer`), the validation scores, the final metrics and
what the task adds to the checkpoint.
"""

from __future__ import annotations

import copy
from typing import Protocol

import numpy as np

from avgs.config import TrainConfig
from avgs.train.logging import JsonLinesLog
from avgs.train.stage2 import Stage2Trainer


def quick_config(cfg: TrainConfig | None = None) -> TrainConfig:
    """The ``--quick`` preset: a tiny run for tests and smoke checks (small images, few
    iterations); each task's ``quick_config`` starts from it."""
    cfg = copy.deepcopy(cfg or TrainConfig())
    g, a, p = cfg.gaussians, cfg.acoustic, cfg.points
    g.iterations, g.init_points, g.image_downscale = 30, 1500, 4
    g.densify_from, g.densify_every, g.sh_degree_interval = 10, 10, 10
    g.max_gaussians = 4000
    a.iterations, a.batch_size = 300, 4
    p.densify_every, p.prune_every, p.max_points = 50, 150, 4000
    cfg.checkpoint_every, cfg.eval_every, cfg.log_every = 100, 150, 10
    return cfg


class TaskTraining(Protocol):
    """One task's side of training a scene. Made from the scene folder and the run's
    configuration: it opens (never writes) the scene's files and checks its targets."""

    label: str
    "The progress bar's title."
    scores: tuple[str, ...]
    "Keys of :meth:`validate`'s scores, the first shown on the progress bar; they join the final record."
    scene: object
    "The scene's RWAVS side (:class:`~avgs.data.rwavs.RWAVSScene`): name, root, frame, source, metadata."

    @staticmethod
    def quick_config(cfg: TrainConfig | None = None) -> TrainConfig:
        """This task's ``--quick`` preset."""

    def configure(self, cfg: TrainConfig, log: JsonLinesLog) -> None:
        """A fresh run (not a resumed one), before stage 1: size ``cfg`` to the data, log what was set."""

    def trainer(self, model, cfg: TrainConfig, resumed: bool) -> Stage2Trainer:
        """The trainer of ``model`` on the training targets (a fresh model also initialised from them)."""

    def validate(self, trainer: Stage2Trainer) -> dict:
        """Validation scores now ({} without validation data)."""

    def final(self, trainer: Stage2Trainer, final: dict) -> dict:
        """The final record (``final``: the last iteration's, {} when resumed at the end)."""

    def bounds(self, model, gaussians: dict | None) -> np.ndarray:
        """The scene's box [2, 3] (world) that positions are kept inside."""

    def checkpoint_extra(self, metrics: dict | None) -> dict:
        """What this task adds to the checkpoint (and its ``metrics``)."""
