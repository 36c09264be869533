"""What a run folder holds, read the same way by the sweep's driver and by the worker that runs it.

- *finished*: ``scene.ckpt`` exists and its training reached its last iteration (the last
  record of its history is ``avgs train``'s ``final`` one, written only when the loop ended);
- *interrupted*: ``scene.ckpt`` exists but is not finished (killed, failed, stopped): the
  run continues from it with ``--resume``, which is exact (:mod:`avgs.train.pipeline`);
- *new*: no checkpoint (a deleted checkpoint makes its run new again).

``status.json`` records what the sweep did with the folder (options, outcome, exit code, the
last lines of the log, the Ray node); it is written atomically when a run starts (``running``)
and when it ends; the driver ends it for a run whose worker could not (cancelled, lost beyond
its retries). A folder whose recorded options differ from the sweep's is refused rather than
mixed. ``sweep.lock`` is the lock a run holds while it works (:mod:`avgs.sweep.lock`).
``train.out`` collects the runs' stdout and stderr, attempt after attempt; ``eval-<split>.json``
is ``avgs eval``'s report of the checkpoint (``eval-<split>-<hash>.json`` with eval options),
fresh while newer than the checkpoint.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from avgs.io.atomic import write_json
from avgs.io.checkpoint_peek import peek_checkpoint
from avgs.sweep.spec import Run

STATUS = "status.json"
OUTPUT = "train.out"

NEW, INTERRUPTED, FINISHED = "new", "interrupted", "finished"

RUNNING = "running"
"A status record's status while its run works (left so by an attempt that never ended)."


def status_path(folder: Path) -> Path:
    return Path(folder) / STATUS


def output_path(folder: Path) -> Path:
    return Path(folder) / OUTPUT


def eval_path(run: Run, split: str) -> Path:
    """``eval-<split>.json``, or ``eval-<split>-<hash>.json`` with eval options (another scoring, another file)."""
    if not run.scoring:
        return run.folder / f"eval-{split}.json"
    digest = hashlib.sha256("\0".join(run.scoring).encode()).hexdigest()[:8]
    return run.folder / f"eval-{split}-{digest}.json"


def read_status(folder: Path) -> dict | None:
    """The folder's status record, or None when it has none (or an unreadable one)."""
    try:
        data = json.loads(status_path(folder).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def write_status(folder: Path, record: dict) -> None:
    write_json(status_path(folder), record)


def end_unfinished(folder: Path, status: str, reason: str) -> None:
    """Give a record still ``running`` (its worker ended without writing it) its ``status`` and ``reason``."""
    record = read_status(folder)
    if record is not None and record.get("status") == RUNNING:
        write_status(folder, {**record, "status": status, "reason": reason})


def checkpoint_progress(path: Path) -> tuple[int, bool] | None:
    """(stage-2 iteration saved, finished) of a checkpoint, or None when there is none or it cannot be read.

    Reads its plain values without torch (:func:`avgs.io.checkpoint_peek.peek_checkpoint`: a Ray
    worker on a busy node took 40 s to import torch for this) and without validating it (``avgs
    train --resume`` validates it, and reports a damaged one as the run's failure).
    """
    path = Path(path)
    if not path.is_file():
        return None
    try:
        ckpt = peek_checkpoint(path)
    except Exception:  # noqa: BLE001 - any unreadable file is "not finished"; resuming says why
        return (0, False)
    history = ckpt.get("history") if isinstance(ckpt, dict) else None
    state = ckpt.get("train_state") if isinstance(ckpt, dict) else None
    iteration = state.get("iteration", 0) if isinstance(state, dict) else 0
    finished = isinstance(history, list) and bool(history) and isinstance(history[-1], dict) and history[-1].get("stage") == "final"
    return (int(iteration) if isinstance(iteration, int) else 0, finished)


@dataclass(frozen=True)
class RunState:
    """Where one run stands: its training (new, interrupted, finished) and whether its score is fresh."""

    training: str
    iteration: int
    """Stage-2 iteration of its checkpoint (0 without one)."""
    scored: bool
    """Its ``eval-<split>.json`` is newer than its checkpoint (always False before it finished)."""

    def needs_work(self, split: str) -> bool:
        return self.training != FINISHED or (split != "none" and not self.scored)


def run_state(run: Run, split: str) -> RunState:
    progress = checkpoint_progress(run.checkpoint)
    if progress is None:
        return RunState(NEW, 0, False)
    iteration, finished = progress
    if not finished:
        return RunState(INTERRUPTED, iteration, False)
    return RunState(FINISHED, iteration, split != "none" and eval_fresh(run, split))


def eval_fresh(run: Run, split: str) -> bool:
    """The run's score of ``split`` exists and is newer than its checkpoint."""
    path = eval_path(run, split)
    try:
        return path.stat().st_mtime_ns >= run.checkpoint.stat().st_mtime_ns
    except OSError:
        return False


def check_folder(run: Run) -> None:
    """Refuse a run folder that another sweep made with different options."""
    status = read_status(run.folder)
    if status is None or "options" not in status:
        return
    if list(status["options"]) != list(run.options):
        raise ValueError(
            f"{run.folder}: made with the options {' '.join(status['options'])!r}, the sweep now gives "
            f"{' '.join(run.options)!r}; give the setting another name, another --out, or remove the folder"
        )


def scores_of(run: Run, split: str) -> tuple[dict[str, float], str] | None:
    """(``{MAG, ENV, ILD, MAGp}``, environment) of the run's scene from its fresh ``eval-<split>.json``, or None."""
    if not eval_fresh(run, split):
        return None
    try:
        report = json.loads(eval_path(run, split).read_text(encoding="utf-8"))
        (method,) = report["methods"].values()
        return dict(method["scenes"][run.scene]), report["environments"][run.scene]
    except (OSError, ValueError, KeyError, TypeError):
        return None
