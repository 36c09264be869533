"""``avgs eval DATA_ROOT``: MAG, ENV, ILD error and MAGp of baselines and checkpoints on the val clips.

Prints a table per scene, per environment and overall (mean of the environment means,
as RWAVS); ``--json`` writes the same numbers. A scene's environment comes from its
scene.json ``"environment"``, else the name's prefix before ``_`` or ``-``, else the name.
"""

from __future__ import annotations

import argparse

from avgs.baselines import BASELINES
from avgs.commands.render import add_synthesis_flags


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data_root", metavar="DATA_ROOT", help="Folder of scenes in the RWAVS layout (with position.json).")
    parser.add_argument(
        "--method",
        action="append",
        metavar="NAME",
        help=f"Method to score, repeatable: {', '.join(BASELINES)} or ckpt:PATH (default: the baselines).",
    )
    parser.add_argument("--scene", action="append", metavar="ID", help="Scene folder name, repeatable (default: every scene).")
    parser.add_argument("--json", metavar="OUT.json", help="Also write the scores as JSON (atomically).")
    parser.add_argument("--split", choices=("val", "train"), default="val", help="Clips to score (default: val).")
    parser.add_argument("--device", default="cpu", help="Torch device for checkpoints (cpu or cuda).")
    add_synthesis_flags(parser, prefix="Checkpoints: ")
    parser.add_argument("--no-progress", action="store_true", help="Hide the progress bars.")


def run(args: argparse.Namespace) -> int:
    from avgs import evaluate
    from avgs.atomic import check_output, write_json
    from avgs.commands.render import synthesis_of

    if args.json:
        ckpts = [m[len(evaluate.CKPT_PREFIX) :] for m in args.method or () if m.startswith(evaluate.CKPT_PREFIX)]
        check_output(args.json, inputs=[args.data_root, *ckpts], what="--json")
    specs = list(dict.fromkeys(args.method or BASELINES))
    scene_dirs = evaluate.find_scenes(args.data_root, args.scene)
    synthesis = synthesis_of(args)
    methods = {spec: evaluate.load_method(spec, device=args.device, synthesis=synthesis) for spec in specs}
    report = evaluate.evaluate(methods, scene_dirs, split=args.split, progress=not args.no_progress)
    print(evaluate.format_report(report))
    if args.json:
        write_json(args.json, report)
        print(f"wrote {args.json}")
    return 0
