"""``avgs train DATA_ROOT/SCENE_ID --out scene.ckpt``: both stages, with progress bars,
a JSON-lines log (``scene.ckpt.log.jsonl``) and loss / point-count curves
(``scene.ckpt.curves.png``) next to the checkpoint.

``--task rir`` trains the impulse-response task on a scene with ``rir/`` (``avgs synth --task
rir``): G_a and F as for the binaural task, and the RIR variant of B (:mod:`avgs.train.impulse_responses`);
``--no-context`` is its control without the scene context.

The model's flags are generated from :class:`avgs.config.TrainConfig` (:mod:`avgs.commands.flags`);
the ones written here are about the run itself.
"""

from __future__ import annotations

import argparse

from avgs.commands.flags import DEST, add_config_flags, apply_config_flags
from avgs.config import TrainConfig
from avgs.tasks import DEFAULT, TASKS, task_named

SECTIONS = {"": "", "acoustic": "", "points": "points-", "gaussians": "stage1-", "rir": "rir-"}
"TrainConfig's sections that get flags, with their flag prefixes (stft is AV-NeRF's and fixed)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="DATA_ROOT/SCENE_ID", help="Scene folder in the RWAVS layout.")
    parser.add_argument("--out", required=True, metavar="scene.ckpt", help="Checkpoint to write (atomically).")
    parser.add_argument("--task", choices=tuple(TASKS), default=DEFAULT,
                        help="; ".join(f"{t.name}: {t.summary}" for t in TASKS.values())
                             + f" (a scene written by 'avgs synth --task NAME'). Default {DEFAULT}.")
    parser.add_argument("--quick", action="store_true",
                        help="Tiny preset for tests: few iterations, small images (with --task rir: --init sfm, a narrower network).")
    parser.add_argument("--resume", action="store_true", help="Continue from the training state saved in --out.")
    parser.add_argument("--stage1-only", action="store_true",
                        help="Run stage 1 alone (frames and poses, no audio read) and write OUT.stage1.pt, which a "
                             "later run with the same --out and settings reuses.")
    parser.add_argument("--stage1", metavar="FILE",
                        help="Take G from this stage-1 file (from --stage1-only) instead of training it; "
                             "lets several stage-2 runs share one G.")
    parser.add_argument("--no-progress", action="store_true", help="Hide the progress bars.")
    defaults = TrainConfig()
    titles = {"": "run", "acoustic": "stage 2: G_a, F and B", "points": "audio point management", "gaussians": "stage 1: 3D-GS",
              "rir": "the impulse-response task (--task rir)"}
    for path, prefix in SECTIONS.items():
        add_config_flags(parser, {path: (getattr(defaults, path) if path else defaults, prefix)}, titles[path])


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """TrainConfig from the defaults (or the --quick preset) and the flags given."""
    from avgs.acoustics.points import parse_alpha_spec

    task = task_named(getattr(args, "task", DEFAULT), "--task")
    base = task.part("training").quick_config() if args.quick else TrainConfig()
    cfg = apply_config_flags(args, base)
    given = vars(args)
    if given.get(f"{DEST}acoustic.iterations") is not None and given.get(f"{DEST}rir.passes") is None:
        cfg.rir.passes = 0.0  # --iterations N means N, not a cap on the schedule sized to the data
    cfg.validate()
    parse_alpha_spec(cfg.acoustic.alpha_init)
    if cfg.device == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise ValueError("--device cuda: no CUDA device is available")
    return cfg


def check_training_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, outputs that would replace an input or a non-file (avgs.io.atomic.check_output)."""
    from avgs.io.atomic import check_output
    from avgs.train.logging import log_paths
    from avgs.train.stage1 import stage1_path

    inputs = [args.scene, args.stage1]
    check_output(args.out, inputs=inputs, what="--out")
    for derived in (*log_paths(args.out), stage1_path(args.out)):
        check_output(derived, inputs=inputs, what="--out's companion file")


def run(args: argparse.Namespace) -> int:
    from avgs.train.logging import log_paths
    from avgs.train.pipeline import run_stage1_only, train_scene

    cfg = config_from_args(args)
    check_training_outputs(args)
    if args.stage1_only:
        if args.stage1 or args.resume:
            raise ValueError("--stage1-only trains G; it takes neither --stage1 nor --resume")
        path = run_stage1_only(args.scene, args.out, cfg, progress=not args.no_progress)
        print(f"wrote {path} (stage 1: G for --out {args.out})")
        return 0
    final = train_scene(args.scene, args.out, cfg, task=args.task, resume=args.resume, progress=not args.no_progress,
                        stage1=args.stage1)
    log, png = log_paths(args.out)
    metrics = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in final.items()
                        if not isinstance(v, dict))
    print(f"wrote {args.out} ({metrics}); log {log}, curves {png}")
    return 0
