"""``avgs eval DATA_ROOT``: score baselines and checkpoints, per scene, per environment and overall.

Binaural task (default, ``--task binaural``): MAG, ENV, ILD error and MAGp on the val
clips of scenes in the RWAVS layout. RIR task (``--task rir``): T60 %, C50 dB and EDT s of
predicted impulse responses on the val and/or held-out-source responses of impulse-response
scenes (``rir/index.json``); DATA_ROOT may then be several data roots or scene folders.

Prints a table per scene, per environment and overall (mean of the environment means,
as RWAVS); ``--json`` (or ``--out``) writes the same numbers. A scene's environment comes
from its scene.json ``"environment"``, else the name's prefix before ``_`` or ``-``, else
the name.
"""

from __future__ import annotations

import argparse

from avgs.evaluation.baselines import BASELINES
from avgs.commands.render import add_synthesis_flags

RIR_DEFAULT_METHODS = ("nearest", "linear", "opus-nearest", "opus-linear", "aac-nearest", "aac-linear")
"The RIR task's baselines (avgs.evaluation.interpolation.RIR_BASELINES), scored when no method is named."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data_root", metavar="DATA_ROOT", nargs="+",
                        help="Folder of scenes in the RWAVS layout (with position.json); --task rir: data roots or "
                             "scene folders, one or more.")
    parser.add_argument("--task", choices=("binaural", "rir"), default="binaural",
                        help="binaural: MAG, ENV, ILD, MAGp of binaural clips (default); rir: T60 %%, C50 dB, EDT s "
                             "of impulse responses.")
    parser.add_argument(
        "--method",
        action="append",
        metavar="NAME",
        help=f"Method to score, repeatable: {', '.join(BASELINES)} or ckpt:PATH (default: the baselines); "
             f"--task rir: {', '.join(RIR_DEFAULT_METHODS)}, ckpt:PATH or avgs:PATH (PATH a checkpoint or a folder "
             "of them, one per scene).",
    )
    parser.add_argument("--methods", metavar="A,B,...", help="Methods to score, comma-separated (joins --method).")
    parser.add_argument("--scene", action="append", metavar="ID", help="Scene folder name, repeatable (default: every scene).")
    parser.add_argument("--json", "--out", dest="json", metavar="OUT.json", help="Also write the scores as JSON (atomically).")
    parser.add_argument("--split", choices=("val", "train", "heldout", "both"), default=None,
                        help="Clips or responses to score (default: val). --task rir also takes heldout (pairs whose "
                             "source no training pair has) and both (val and heldout).")
    parser.add_argument("--device", default="cpu", help="Torch device for checkpoints (cpu or cuda).")
    add_synthesis_flags(parser, prefix="Checkpoints: ")
    parser.add_argument("--no-progress", action="store_true", help="Hide the progress bars.")


def _specs(args: argparse.Namespace, default) -> list[str]:
    specs = list(args.method or ())
    if args.methods is not None:
        names = [m.strip() for m in args.methods.split(",")]
        if not all(names):
            raise ValueError(f"--methods {args.methods!r}: an empty method name (expected NAME,NAME,...)")
        specs += names
    return list(dict.fromkeys(specs or default))


def _model_paths(specs: list[str], prefixes) -> list[str]:
    return [s[len(p) :] for s in specs for p in prefixes if s.startswith(p)]


def run(args: argparse.Namespace) -> int:
    if args.task == "rir":
        return run_rir(args)
    from avgs.evaluation import binaural as evaluate
    from avgs.io.atomic import check_output, write_json
    from avgs.commands.render import synthesis_of

    if len(args.data_root) != 1:
        raise ValueError(f"the binaural task takes one DATA_ROOT, got {len(args.data_root)}: {' '.join(args.data_root)}")
    data_root = args.data_root[0]
    split = args.split or "val"
    if split not in ("val", "train"):
        raise ValueError(f"--split {split}: the binaural task scores val or train clips (heldout and both are --task rir)")
    specs = _specs(args, BASELINES)
    if args.json:
        check_output(args.json, inputs=[data_root, *_model_paths(specs, (evaluate.CKPT_PREFIX,))], what="--json")
    scene_dirs = evaluate.find_scenes(data_root, args.scene)
    synthesis = synthesis_of(args)
    methods = {spec: evaluate.load_method(spec, device=args.device, synthesis=synthesis) for spec in specs}
    report = evaluate.evaluate(methods, scene_dirs, split=split, progress=not args.no_progress)
    print(evaluate.format_report(report))
    if args.json:
        write_json(args.json, report)
        print(f"wrote {args.json}")
    return 0


def run_rir(args: argparse.Namespace) -> int:
    from avgs.evaluation import impulse_response as evaluate_rir
    from avgs.io.atomic import check_output, write_json

    specs = _specs(args, RIR_DEFAULT_METHODS)
    for spec in specs:  # a bad name fails before any scene is read
        if not spec.startswith(evaluate_rir.MODEL_PREFIXES) and spec not in evaluate_rir.RIR_BASELINES:
            raise ValueError(f"unknown RIR method {spec!r}; expected one of {', '.join(evaluate_rir.method_names())}")
    if args.json:
        check_output(args.json, inputs=[*args.data_root, *_model_paths(specs, evaluate_rir.MODEL_PREFIXES)], what="--json")
    scene_dirs = evaluate_rir.find_scenes(args.data_root, args.scene)
    progress = not args.no_progress
    methods = {spec: evaluate_rir.load_method(spec, device=args.device, progress=progress) for spec in specs}
    report = evaluate_rir.evaluate(methods, scene_dirs, split=args.split or "val", progress=progress)
    print(evaluate_rir.format_rir_report(report))
    if args.json:
        write_json(args.json, report)
        print(f"wrote {args.json}")
    return 0
