"""The ``avgs`` command line: one sub-command per module in :mod:`avgs.commands`.

Each command module defines ``add_arguments(parser)`` and ``run(args) -> int``; it is
imported only when its command runs, so ``avgs --help`` starts fast and no command
pays for another's imports.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

COMMANDS: dict[str, str] = {
    "synth": "Generate a synthetic scene with physical ground truth in the RWAVS layout.",
    "train": "Train AV-GS (3D-GS warm-up, then the audio stage) on one scene.",
    "eval": "Score baselines and checkpoints (MAG, ENV) per scene, environment and overall.",
    "render": "Binauralise a mono WAV for a listener pose with a trained checkpoint.",
    "info": "Print what a checkpoint holds.",
    "prune": "Keep only the audio points some listener or source vicinity can use.",
    "bench": "Benchmark speed against error; writes benchmarks/REPORT.md.",
    "sweep": "Train scenes x settings x seeds on Ray (resumable), then score every run into one table.",
    "export": "Export what a listener hears: an impulse response (WAV), a grid of them (SOFA), a fly-through (MP4).",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="avgs", description="AV-GS: novel-view acoustic synthesis with audio-visual Gaussian splatting."
    )
    parser.add_argument("--version", action="version", version=f"avgs {package_version()}")
    parser.add_argument("--threads", type=int, metavar="N",
                        help="Torch CPU threads (default: OMP_NUM_THREADS if set, else the cores the machine's load "
                             "leaves free, so that concurrent runs do not oversubscribe them).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, help_text in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=f"avgs.commands.{name}")
        # Arguments are added lazily in main() for the chosen command only.
    return parser


def package_version() -> str:
    """The installed package's version (pyproject.toml), or "unknown" when it is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("avgs")
    except PackageNotFoundError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    # Find the command, then let its module add its own arguments.
    command = next((a for a in argv if a in COMMANDS), None)
    if command in COMMANDS:
        sub_action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        module = importlib.import_module(f"avgs.commands.{command}")
        module.add_arguments(sub_action.choices[command])
    args = parser.parse_args(argv)
    module = importlib.import_module(args._module)

    def one_line(message, category, filename, lineno, file=None, line=None):  # a warning is one line too
        print(f"avgs {args.command}: warning: {' '.join(str(message).split())}", file=sys.stderr)

    try:
        from avgs.threads import set_threads

        set_threads(args.threads)
        with warnings.catch_warnings():
            warnings.showwarning = one_line
            return int(module.run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:
        # Bad input (a malformed file or value: ValueError) or a file that cannot be read or
        # written (missing, a folder, no permission, disk full: OSError): one clear line naming
        # the file or value, no traceback. Anything else is a bug and keeps its traceback.
        print(f"avgs {args.command}: error: {error_line(exc)}", file=sys.stderr)
        return 2


def error_line(exc: BaseException) -> str:
    """The one line reporting ``exc``: an OS error as ``FILE: reason``, any message on one line."""
    text = str(exc)
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
        if exc.filename2 is not None:
            text += f" ({exc.filename2})"
    elif isinstance(exc, OSError) and exc.strerror and not exc.filename:
        text = exc.strerror
    return " ".join(text.split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
