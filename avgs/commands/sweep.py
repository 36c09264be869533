"""``avgs sweep``: train scenes x settings x seeds on Ray, resumable, then one table of scores.

    avgs sweep --data data/presets --scenes office_0 house_0 --setting avgs= \\
        --setting no-context=--no-context --seeds 0 1 2 --common="--iterations 2000" --out runs/main
    avgs sweep --config sweep.toml [--address HEAD:6379]

Each run is ``avgs train DATA/SCENE --out OUT/SCENE/SETTING/seedK/scene.ckpt COMMON SETTING --seed K``
(:mod:`avgs.sweep`). Started again, a sweep skips what finished, resumes what was
interrupted or failed, and trains what is new. Exit status 0 when every run finished,
1 when one failed, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import shlex

from avgs.commands.flags import field_help

EPILOG = """\
A TOML file (--config) takes the same fields (data, out, scenes, seeds, common, eval_options, threads_per_run,
gpus_per_run, retries, eval_split, address, num_cpus, and a [settings] table of name = "options");
flags given override it. Options strings are shell-quoted; write options that start with "--" as
--common="--iterations 2000". {scene} in an option is replaced by the scene's id.
Outputs: OUT/<scene>/<setting>/seed<k>/ (scene.ckpt with its log and curves, train.out, status.json,
eval-<split>.json), OUT/results.json and OUT/results.md.
Ray: pip install 'avgs[scale]'. Without --address a local Ray starts on this machine; for a cluster,
`ray start --head` on one machine, `ray start --address=HEAD:6379` on the others (same paths and
avgs[scale] everywhere), then --address HEAD:6379 (or auto on a cluster machine)."""


def _help(name: str) -> str:
    from avgs.sweep.spec import SweepSpec

    return field_help(SweepSpec, name).replace("%", "%%")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from avgs.sweep.spec import EVAL_SPLITS

    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--config", metavar="SWEEP.toml", help="Read the sweep from this TOML file (flags override it).")
    parser.add_argument("--data", metavar="DATA_ROOT", help=_help("data"))
    parser.add_argument("--scenes", nargs="+", metavar="ID", help=_help("scenes"))
    parser.add_argument("--setting", action="append", metavar="NAME=OPTIONS",
                        help="A setting and the avgs train options it adds, repeatable (--setting avgs= "
                             "--setting no-context=--no-context); replaces the TOML file's settings "
                             "(default: one setting, 'default', with no options).")
    parser.add_argument("--seeds", nargs="+", type=int, metavar="K", help=_help("seeds") + " (default: 0)")
    parser.add_argument("--common", metavar="OPTIONS", help=_help("common") + ' (e.g. --common="--iterations 2000")')
    parser.add_argument("--eval-options", metavar="OPTIONS",
                        help=_help("eval_options") + ' (e.g. --eval-options="--phase source --phase-iterations 8")')
    parser.add_argument("--out", metavar="DIR", help=_help("out") + " (default: runs/sweep)")
    parser.add_argument("--threads-per-run", type=int, metavar="N", help=_help("threads_per_run") + " (default: 1)")
    parser.add_argument("--gpus-per-run", type=float, metavar="X", help=_help("gpus_per_run") + " (default: 0)")
    parser.add_argument("--retries", type=int, metavar="N", help=_help("retries") + " (default: 1)")
    parser.add_argument("--eval-split", choices=EVAL_SPLITS, help=_help("eval_split") + " (default: val)")
    parser.add_argument("--address", metavar="ADDR", help=_help("address"))
    parser.add_argument("--num-cpus", type=int, metavar="N", help=_help("num_cpus"))
    parser.add_argument("--dry-run", action="store_true", help="Print each run, what it needs and its command; run nothing.")
    parser.add_argument("--no-progress", action="store_true", help="Hide the progress bar (one line per finished run instead).")


def parse_settings(values: list[str] | None) -> dict[str, str] | None:
    """``["NAME=OPTIONS", ...]`` -> ``{NAME: OPTIONS}`` (None when no --setting was given)."""
    if not values:
        return None
    settings: dict[str, str] = {}
    for value in values:
        name, sep, options = value.partition("=")
        if not sep or not name:
            raise ValueError(f"--setting {value!r}: expected NAME=OPTIONS (NAME= for no options)")
        if name in settings:
            raise ValueError(f"--setting {name!r} is given twice")
        settings[name] = options
    return settings


class _Refusal(argparse.ArgumentParser):
    """An ``avgs train`` parser whose errors are exceptions, to check each run's options before any run starts."""

    def error(self, message: str):
        raise ValueError(message)


def check_options(runs) -> None:
    """Every run's options parse as ``avgs train`` options (and make a valid configuration), and
    the eval options as ``avgs eval`` options."""
    from avgs.commands import eval as evaluation, train

    parser = _Refusal(prog="avgs train", add_help=False)
    train.add_arguments(parser)
    seen = set()
    for run in runs:
        if run.options in seen:
            continue
        seen.add(run.options)
        try:
            args = parser.parse_args([str(run.scene_dir), "--out", str(run.checkpoint), *run.options])
            train.config_from_args(args)
        except ValueError as exc:
            raise ValueError(f"setting {run.setting!r} ({shlex.join(run.options)}): {exc}") from None
    if runs and runs[0].scoring:
        parser = _Refusal(prog="avgs eval", add_help=False)
        evaluation.add_arguments(parser)
        try:
            parser.parse_args([str(runs[0].scene_dir.parent), "--method", "ckpt:scene.ckpt", *runs[0].scoring])
        except ValueError as exc:
            raise ValueError(f"--eval-options {shlex.join(runs[0].scoring)!r}: {exc}") from None


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from avgs.evaluation.binaural import find_scenes
    from avgs.sweep import results
    from avgs.sweep.driver import describe, plan, sweep
    from avgs.sweep.execute import train_argv
    from avgs.sweep.spec import expand, make_spec

    overrides = {"data": args.data, "out": args.out, "scenes": args.scenes, "settings": parse_settings(args.setting),
                 "seeds": args.seeds, "common": args.common, "eval_options": args.eval_options, "threads_per_run": args.threads_per_run,
                 "gpus_per_run": args.gpus_per_run, "retries": args.retries, "eval_split": args.eval_split,
                 "address": args.address, "num_cpus": args.num_cpus}
    spec = make_spec(args.config, overrides)
    out = Path(spec.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: not a folder")
    runs = expand(spec, find_scenes(spec.data, spec.scenes or None))
    check_options(runs)
    if args.dry_run:
        for run, state in plan(spec, runs):
            print(f"{run.name}: {describe(run, state, spec.eval_split)}")
            print(f"  avgs {shlex.join(train_argv(run, spec.threads_per_run, state.training == 'interrupted')[3:])}")
        return 0
    report = sweep(spec, runs, progress=not args.no_progress)
    print(results.format_runs(report))
    if spec.eval_split != "none":
        print(results.format_results(report))
    print(f"wrote {out / 'results.json'}, {out / 'results.md'}")
    if report["interrupted"]:
        print("interrupted: start the same sweep again to resume")
        return 130
    return 1 if any(r["status"] in ("failed", "interrupted", "not run") for r in report["runs"]) else 0
