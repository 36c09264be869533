"""One run of a sweep, on whichever machine it lands: ``avgs train`` (then ``avgs eval``) as subprocesses.

Each subprocess gets ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` and ``--threads`` equal to the
run's CPU share and writes to the run's ``train.out`` (appended, attempt after attempt). A
run whose checkpoint is not finished continues with ``--resume``; a failed attempt is
retried ``retries`` times, each from the last checkpoint. A cancelled sweep kills the Ray
workers of its runs with the processes they started; a subprocess that outlived its worker
gets SIGINT (Linux: ``PR_SET_PDEATHSIG``) and stops as after Ctrl+C, and an interrupt raised
in the worker itself sends it SIGINT too. Its last checkpoint is kept to resume from. The run
holds its folder's lock (:mod:`avgs.sweep.lock`) throughout, and so do its subprocesses: a
task placed again after a lost node waits until the lost one's ``avgs train`` has stopped.

A status record still ``running`` when a run starts belongs to an attempt that never ended
(its worker or node was lost, or the sweep itself was killed): it is kept in ``lost``
(``host``, Ray ``node``, the checkpoint's ``iteration`` it is resumed from).

:func:`execute` returns a plain dict (the status record, also written to ``status.json``):
``status`` is one of ``trained``, ``resumed`` (from ``resumed_from``), ``evaluated`` (finished
before, scored now), ``failed`` (with ``returncode``, ``reason`` and ``tail``); ``node`` is the
Ray node it ran on, ``lost`` the attempts before it that never ended.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from avgs.sweep.lock import run_lock
from avgs.sweep.spec import Run
from avgs.sweep.state import (FINISHED, INTERRUPTED, RUNNING, eval_fresh, eval_path, output_path, read_status,
                              run_state, write_status)

TAIL_LINES = 20
"Lines of a failed run's output kept in its status record."

STOP_SECONDS = 30.0
"How long an interrupted subprocess may take to stop after SIGINT before it is killed."


def _child_setup() -> None:  # pragma: no cover - runs in the child between fork and exec
    """The child takes SIGINT as Ctrl+C again (Ray's workers ignore SIGINT, and a child inherits
    that), and (Linux) gets SIGINT when the worker that started it dies: a cancelled or lost task."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
        libc.signal(signal.SIGINT, None)  # SIG_DFL: Python installs its KeyboardInterrupt handler at start
        libc.prctl(1, signal.SIGINT)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        pass


def _call(argv: list[str], log: Path, threads: int, cwd: Path | None = None, keep: tuple[int, ...] = ()) -> int:
    """Run ``argv`` with ``threads`` CPU threads, output appended to ``log``; its exit code.
    ``keep``: descriptors the child inherits (the run folder's lock).

    On KeyboardInterrupt (the task cancelled) the child is sent SIGINT, then killed after
    :data:`STOP_SECONDS`; the interrupt goes on.
    """
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads), PYTHONUNBUFFERED="1")
    with open(log, "a", encoding="utf-8") as out:
        out.write(f"$ {' '.join(argv)}\n")
        out.flush()
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT, env=env,
                                cwd=cwd if cwd is not None and Path(cwd).is_dir() else None,
                                start_new_session=True, pass_fds=keep, preexec_fn=_child_setup if sys.platform == "linux" else None)
        try:
            while True:  # short waits: a cancelled task's KeyboardInterrupt lands between them
                try:
                    return proc.wait(0.5)
                except subprocess.TimeoutExpired:
                    pass
        except BaseException:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(STOP_SECONDS)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            raise


def tail(log: Path, lines: int = TAIL_LINES) -> list[str]:
    """The last non-empty lines of a log (at most the last 64 KiB of it)."""
    try:
        with open(log, "rb") as f:
            f.seek(max(0, f.seek(0, os.SEEK_END) - 65536))
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return []
    return [line for line in text.splitlines() if line.strip()][-lines:]


def reason(lines: list[str]) -> str:
    """The line that says why a run failed: the last error line of its output, else its last line."""
    for line in reversed(lines):
        if "error" in line.lower() or "Error" in line or "Exception" in line:
            return line.strip()
    return lines[-1].strip() if lines else "no output"


def option_value(options: tuple[str, ...], flag: str) -> str | None:
    """The value a flag takes in ``options`` (``--flag V`` or ``--flag=V``; the last wins), or None."""
    value = None
    for i, option in enumerate(options):
        if option == flag and i + 1 < len(options):
            value = options[i + 1]
        elif option.startswith(flag + "="):
            value = option.split("=", 1)[1]
    return value


def train_argv(run: Run, threads: int, resume: bool) -> list[str]:
    """``avgs train`` of one run (``--resume`` to continue its checkpoint)."""
    argv = [sys.executable, "-m", "avgs.cli", "--threads", str(threads), "train", str(run.scene_dir),
            "--out", str(run.checkpoint), *run.options, "--no-progress"]
    return argv + ["--resume"] if resume else argv


def eval_argv(run: Run, threads: int, split: str) -> list[str]:
    """``avgs eval`` of one run's checkpoint on its scene, into ``eval-<split>.json``."""
    argv = [sys.executable, "-m", "avgs.cli", "--threads", str(threads), "eval", str(run.scene_dir.parent),
            "--scene", run.scene, "--method", f"ckpt:{run.checkpoint}", "--split", split,
            "--json", str(eval_path(run, split)), "--no-progress", *run.scoring]
    for flag in ("--task", "--device"):  # the impulse-response task's runs are scored as such, on their device
        value = option_value(run.options, flag)
        if value:
            argv += [flag, value]
    return argv


def execute(run: Run, threads: int = 1, retries: int = 1, split: str = "val", node: str = "") -> dict:
    """Train (or resume) the run until its checkpoint is finished, then score it; the status record.

    ``node``: the Ray node it runs on (recorded). Raises :class:`~avgs.sweep.lock.FolderBusy`
    when another process keeps the run folder.
    """
    run.folder.mkdir(parents=True, exist_ok=True)
    log = output_path(run.folder)

    def waiting(holder: str) -> None:
        with open(log, "a", encoding="utf-8") as out:
            out.write(f"# waiting for the run folder, in use by {holder}\n")

    with run_lock(run.folder, on_wait=waiting) as lock:
        return _execute(run, threads, retries, split, node, log, lock)


def _execute(run: Run, threads: int, retries: int, split: str, node: str, log: Path, lock: int | None) -> dict:
    t0 = time.perf_counter()
    keep = () if lock is None else (lock,)
    state = run_state(run, split)
    record = {"run": run.name, "scene": run.scene, "setting": run.setting, "seed": run.seed,
              "options": list(run.options), "host": socket.gethostname(), "node": node, "status": RUNNING,
              "attempts": 0, "resumed_from": None, "returncode": None, "lost": _lost(run, state.iteration)}
    write_status(run.folder, record)
    trained = state.training != FINISHED
    try:
        while state.training != FINISHED and record["attempts"] <= retries:
            record["attempts"] += 1
            resume = state.training == INTERRUPTED
            if resume and record["resumed_from"] is None:
                record["resumed_from"] = state.iteration
            record["returncode"] = _call(train_argv(run, threads, resume), log, threads, run.workdir, keep)
            state = run_state(run, split)
        if state.training == FINISHED and split != "none" and not eval_fresh(run, split):
            code = _call(eval_argv(run, threads, split), log, threads, run.workdir, keep)
            if code != 0:
                return _end(run, record, t0, "failed", code, log, "eval")
    except BaseException:
        _end(run, record, t0, "interrupted", record["returncode"], log)
        raise
    if state.training != FINISHED:
        return _end(run, record, t0, "failed", record["returncode"], log)
    status = ("resumed" if record["resumed_from"] is not None else "trained") if trained else "evaluated"
    return _end(run, record, t0, status, record["returncode"], log)


def _lost(run: Run, iteration: int) -> list[dict]:
    """The attempts at ``run`` that never ended, when the folder's record is still ``running``: that
    one (with the checkpoint's ``iteration`` it left) after those its own record lists."""
    before = read_status(run.folder) or {}
    if before.get("status") != RUNNING:
        return []
    lost = [dict(x) for x in before.get("lost") or [] if isinstance(x, dict)]
    return lost + [{"host": before.get("host"), "node": before.get("node"), "iteration": iteration}]


def _end(run: Run, record: dict, t0: float, status: str, code: int | None, log: Path, stage: str = "train") -> dict:
    record.update(status=status, returncode=code, seconds=round(time.perf_counter() - t0, 2))
    if status in ("failed", "interrupted"):
        record["tail"] = tail(log)
        record["reason"] = (f"{stage}: exit code {code}: " if code is not None else f"{stage}: ") + reason(record["tail"])
    elif status == "resumed":
        record["reason"] = f"from iteration {record['resumed_from']}"
    if record["lost"]:
        lost = len(record["lost"])
        record["reason"] = (f"{record.get('reason')}; " if record.get("reason") else "") + (
            f"after {lost} lost attempt{'s' * (lost > 1)} (node {_short(record['lost'][-1].get('node'))})")
    write_status(run.folder, record)
    return record


def _short(node: str | None) -> str:
    """A Ray node id as ``ray status`` and the dashboard abbreviate it (its first 8 hex digits)."""
    return (node or "?")[:8]
