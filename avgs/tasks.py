"""The task registry: what a checkpoint can be trained for, and each task's part in every layer.

A checkpoint's ``task`` (absent in files from before tasks: ``binaural``) names one
:class:`Task`; the renderer, the trainer, the evaluator, the checkpoint's validation and the
command line look it up here, once, and then talk to the part it names through that layer's
protocol. This is the only module that knows which tasks exist: nothing else branches on a
task's name.

The parts are named by import path (``module:attribute``) and imported on first use, as
plugin entry points are, so that this module sits below every layer that asks for it and
``import avgs`` stays light. ``tests/test_architecture.py`` resolves every one.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class Task:
    """One task and where its parts live."""

    name: str
    "The checkpoint's ``task`` and ``--task``'s value."
    summary: str
    "One line for ``--help`` and ``avgs info``."
    source_aware: bool
    "Trained on many source positions, so that a moved source is really heard."
    model: str
    "The nn.Module G_a + F + this task's B (:mod:`avgs.acoustics`): ``build(points, cfg, stft, vicinity_k)``, ``networks(...)``."
    renderer: str
    "Its :class:`~avgs.render.tasks.TaskModel` (:mod:`avgs.render`)."
    training: str
    "Its :class:`~avgs.train.tasks.TaskTraining` hooks (:mod:`avgs.train`)."
    evaluation: str
    "Its scoring module (:mod:`avgs.evaluation`): ``find_scenes``, ``load_method``, ``evaluate``, ``format_report``."
    data: str
    "The reader of its scenes' targets (:mod:`avgs.data`)."
    synth: str
    "``avgs synth --task NAME``'s writer of a scene with physical ground truth (:mod:`avgs.commands.synth`)."

    def part(self, which: str):
        """The object named by the field ``which`` (``"model"``, ``"renderer"``, ...), imported now."""
        module, _, attribute = getattr(self, which).partition(":")
        target = importlib.import_module(module)
        return getattr(target, attribute) if attribute else target


BINAURAL = Task(
    name="binaural",
    summary="binaural audio of one source (the paper's RWAVS task)",
    source_aware=False,
    model="avgs.acoustics.model:AVGSModel",
    renderer="avgs.render.binaural:BinauralTaskModel",
    training="avgs.train.binaural:BinauralTraining",
    evaluation="avgs.evaluation.binaural",
    data="avgs.data.rwavs:RWAVSScene",
    synth="avgs.commands.synth:run_binaural",
)

IMPULSE_RESPONSE = Task(
    name="rir",
    summary="binaural impulse responses of sources anywhere (the paper's SoundSpaces task)",
    source_aware=True,
    model="avgs.acoustics.rir_model:RIRModel",
    renderer="avgs.render.impulse_responses:ImpulseResponseTaskModel",
    training="avgs.train.impulse_responses:ImpulseResponseTraining",
    evaluation="avgs.evaluation.impulse_response",
    data="avgs.data.rir:RIRScene",
    synth="avgs.commands.synth:run_rir",
)

TASKS: dict[str, Task] = {t.name: t for t in (BINAURAL, IMPULSE_RESPONSE)}
"Every task by name."

DEFAULT = BINAURAL.name
"The task of a checkpoint that names none (files written before tasks) and of ``--task``'s default."


def task_named(name, where: str = "task") -> Task:
    """The :class:`Task` called ``name``; ValueError naming ``where`` and the known tasks otherwise."""
    task = TASKS.get(name) if isinstance(name, str) else None
    if task is None:
        raise ValueError(f"{where} must be one of {', '.join(map(repr, TASKS))}, got {name!r}")
    return task


def task_of(ckpt: dict) -> Task:
    """The task a checkpoint was trained for (``binaural`` for files without ``task``)."""
    return task_named(ckpt.get("task", DEFAULT), "the checkpoint's 'task'")
