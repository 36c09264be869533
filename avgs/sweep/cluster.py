"""The runs of a sweep on Ray: the only module of the package that imports ``ray``.

Each run is one Ray task that asks for its CPU threads (``num_cpus``) and GPU share
(``num_gpus``, fractions let several runs share a GPU), so Ray never places more threads on
a machine than it has cores. A task whose worker dies (a lost node, an out-of-memory kill)
is placed again by Ray, up to :data:`LOST_RETRIES` times whatever ``--retries`` says (that
counts failures of the run itself), and resumes from the run's last checkpoint on whichever
node has room; beyond that the run is recorded as failed with why, its checkpoint kept for
the next sweep. Losing the head node, where the driver runs, ends the sweep (start it
again to resume). Without an address a local
Ray starts on this machine and stops at the end; with one, the sweep joins that cluster
(``ray start --head`` on one machine, ``ray start --address HEAD:6379`` on the others;
every machine sees the data and the output folder at the same paths and has ``avgs[scale]``
installed). Ctrl+C (or SIGTERM) cancels the runs still going: Ray kills their workers and
the ``avgs train`` each started (checkpoints are written atomically, so the last one is
whole), and the next sweep resumes them from it.
"""

from __future__ import annotations

import logging
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from avgs.sweep.execute import STOP_SECONDS, execute
from avgs.sweep.spec import Run
from avgs.sweep.state import end_unfinished

LOST_RETRIES = 3
"How many times a run's task is placed again after its worker or node is lost (Ray's ``max_retries``)."


def import_ray():
    try:
        import ray
    except ImportError:
        raise ValueError("avgs sweep runs on Ray, which is not installed: pip install 'avgs[scale]'") from None
    return ray


@contextmanager
def connected(address: str = "", num_cpus: int = 0) -> Iterator[dict]:
    """Ray started here (or joined at ``address``) for the block; yields its resources (``{"CPU": n, ...}``)."""
    ray = import_ray()
    quiet = dict(log_to_driver=False, logging_level=logging.WARNING)
    if address:
        ray.init(address=address, **quiet)
    else:
        # "local": a Ray of its own, never one found on the machine (RAY_ADDRESS, another user's `ray start`)
        ray.init(address="local", num_cpus=num_cpus or None, include_dashboard=False, **quiet)
    try:
        yield dict(ray.cluster_resources())
    finally:
        ray.shutdown()


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM to the sweep behaves as Ctrl+C: the runs are cancelled and the table printed."""
    def handler(signum, frame):
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_all(runs: list[Run], threads: int, gpus: float, retries: int, split: str,
            on_done: Callable[[Run, dict], None]) -> None:
    """Run every run on the connected Ray; ``on_done(run, record)`` as each ends (a task that
    raised, or whose worker was lost beyond its retries, gives a ``failed`` record)."""
    ray = import_ray()
    task = ray.remote(num_cpus=threads, num_gpus=gpus, max_retries=LOST_RETRIES, retry_exceptions=False)(_placed)
    with _sigterm_as_interrupt():
        pending = {task.options(name=f"avgs-sweep {run.name}").remote(run, threads, retries, split): run for run in runs}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    run = pending.pop(ref)
                    try:
                        record = ray.get(ref)
                    except ray.exceptions.RayTaskError as exc:  # raised by the run's own code (a busy folder, a bug)
                        record = {"run": run.name, "status": "failed", "reason": _first_line(exc)}
                    except Exception as exc:  # noqa: BLE001 - lost beyond its retries (worker, node, owner): the others go on
                        record = {"run": run.name, "status": "failed", "reason": _lost_reason(exc)}
                        end_unfinished(run.folder, "failed", record["reason"])
                    on_done(run, record)
        except KeyboardInterrupt:
            # Ray kills each worker and the processes it started; an avgs train that outlived its
            # worker would get SIGINT (execute._child_setup).
            for ref in pending:
                ray.cancel(ref, force=True)
            ray.wait(list(pending), num_returns=len(pending), timeout=STOP_SECONDS)
            for ref, run in pending.items():
                end_unfinished(run.folder, "interrupted", "the sweep was interrupted")
                on_done(run, {"run": run.name, "status": "interrupted", "reason": "the sweep was interrupted"})
            raise


def _placed(run: Run, threads: int, retries: int, split: str) -> dict:
    """:func:`execute` on a Ray worker, recording the node it landed on."""
    import ray

    return execute(run, threads, retries, split, node=ray.get_runtime_context().get_node_id())


def _lost_reason(exc: BaseException) -> str:
    """Why a run's task ended without a record, in one line, and what the next sweep does."""
    sentence = _first_line(exc).split(". ")[0].rstrip(".")  # Ray's advice follows the first sentence
    return f"lost: {sentence}; start the sweep again to resume from its checkpoint"


def _first_line(exc: BaseException) -> str:
    """What a task's exception says, in one line (the cause of a Ray task error, not its traceback)."""
    cause = getattr(exc, "cause", None)
    text = str(cause if cause is not None else exc).strip().splitlines()
    return f"{type(cause or exc).__name__}: {text[-1] if text else ''}"
