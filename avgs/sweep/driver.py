"""A sweep from start to end: which runs need work, those on Ray, then one report.

A run whose checkpoint is finished and scored is skipped (no Ray is started when none
needs work); an interrupted or failed one continues with ``--resume``; a new one trains.
At the end every finished run's score goes into ``OUT/results.json`` and ``OUT/results.md``
(:mod:`avgs.sweep.results`), written atomically, also after an interrupt (with what there is).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from avgs.io.atomic import write_json, write_text
from avgs.sweep import results
from avgs.sweep.spec import Run, SweepSpec
from avgs.sweep.state import RunState, check_folder, run_state

RESULTS_JSON, RESULTS_MD = "results.json", "results.md"


def plan(spec: SweepSpec, runs: list[Run]) -> list[tuple[Run, RunState]]:
    """Each run with where it stands; refuses folders made with other options (:func:`check_folder`)."""
    for run in runs:
        check_folder(run)
    return [(run, run_state(run, spec.eval_split)) for run in runs]


def check_resources(spec: SweepSpec, resources: dict) -> None:
    """Refuse runs that ask for more than the whole Ray cluster has (they would wait for ever)."""
    cpus, gpus = resources.get("CPU", 0), resources.get("GPU", 0)
    if spec.threads_per_run > cpus:
        raise ValueError(f"each run asks for {spec.threads_per_run} CPU threads; the Ray cluster has {cpus:g} CPUs")
    if spec.gpus_per_run > gpus:
        raise ValueError(f"each run asks for {spec.gpus_per_run:g} GPU; the Ray cluster has {gpus:g} GPUs")


def describe(run: Run, state: RunState, split: str) -> str:
    """What the sweep will do with a run, in words."""
    if state.training == "finished":
        return "score" if state.needs_work(split) else "skip (finished)"
    if state.training == "interrupted":
        return f"resume from iteration {state.iteration}"
    return "train"


def sweep(spec: SweepSpec, runs: list[Run], progress: bool = True, echo: Callable[[str], None] = print) -> dict:
    """Run what needs running, then write and return the report (:func:`results.collect`).

    KeyboardInterrupt (Ctrl+C, SIGTERM) cancels the runs still going; the report of what
    finished is written and returned with ``"interrupted": True``.
    """
    from tqdm.auto import tqdm

    planned = plan(spec, runs)
    todo = [run for run, state in planned if state.needs_work(spec.eval_split)]
    records: dict[str, dict] = {run.name: {"status": "skipped", "reason": "finished before"}
                                for run, state in planned if not state.needs_work(spec.eval_split)}
    out = Path(spec.out)
    interrupted = False
    echo(f"sweep: {len(runs)} runs, {len(todo)} to run, {len(runs) - len(todo)} finished before; folders under {out}")
    try:
        if todo:
            from avgs.sweep.cluster import connected, run_all

            with connected(spec.address, spec.num_cpus) as resources:
                check_resources(spec, resources)
                echo(f"sweep: Ray with {resources.get('CPU', 0):g} CPUs, {resources.get('GPU', 0):g} GPUs; each run "
                     f"takes {spec.threads_per_run} CPU thread(s) and {spec.gpus_per_run:g} GPU")
                bar = tqdm(total=len(todo), desc="sweep", unit="run", disable=not progress, dynamic_ncols=True)

                def done(run: Run, record: dict) -> None:
                    records[run.name] = record
                    bar.update(1)
                    failed = sum(r.get("status") == "failed" for r in records.values())
                    bar.set_postfix(failed=failed)
                    detail = f" ({record['reason']})" if record.get("reason") else ""
                    seconds = f" in {record['seconds']:.0f} s" if record.get("seconds") is not None else ""
                    (bar.write if progress else echo)(f"{run.name}: {record['status']}{seconds}{detail}")

                try:
                    run_all(todo, spec.threads_per_run, spec.gpus_per_run, spec.retries, spec.eval_split, done)
                finally:
                    bar.close()
    except KeyboardInterrupt:
        interrupted = True
    report = results.collect(runs, records, spec.eval_split)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / RESULTS_JSON, report)
    write_text(out / RESULTS_MD, results.format_markdown(report))
    report["interrupted"] = interrupted
    return report
