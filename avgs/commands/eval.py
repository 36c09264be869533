"""``avgs eval DATA_ROOT``: score baselines and checkpoints, per scene, per environment and overall.

Binaural task (default, ``--task binaural``): MAG, ENV, ILD error, MAGp, the median ITD error
(us) and the lateralisation agreement (%) on the val clips of scenes in the RWAVS layout. RIR
task (``--task rir``): T60 %, C50 dB, EDT s, and the median onset (ms), direct-sound ITD (us) and
early ILD (dB) errors and the lateralisation agreement of predicted impulse responses on the val
and/or held-out-source responses of impulse-response scenes (``rir/index.json``); DATA_ROOT may
then be several data roots or scene folders. Definitions: docs/design.md ("Metrics and
baselines", "Spatial cues").

Prints a table per scene, per environment and overall (mean of the environment means,
as RWAVS); ``--json`` (or ``--out``) writes the same numbers. A scene's environment comes
from its scene.json ``"environment"``, else the name's prefix before ``_`` or ``-``, else
the name.
"""

from __future__ import annotations

import argparse

from avgs.commands.render import add_synthesis_flags
from avgs.tasks import DEFAULT, TASKS, task_named


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data_root", metavar="DATA_ROOT", nargs="+",
                        help="Folder of scenes in the RWAVS layout (with position.json); --task rir: data roots or "
                             "scene folders, one or more.")
    parser.add_argument("--task", choices=tuple(TASKS), default=DEFAULT,
                        help="binaural: MAG, ENV, ILD, MAGp, ITD, LAT of binaural clips (default); rir: T60 %%, C50 dB, "
                             "EDT s, onset, ITD, ILD, LAT of impulse responses.")
    parser.add_argument(
        "--method",
        action="append",
        metavar="NAME",
        help="Method to score, repeatable: a baseline (binaural: mono-mono, mono-energy, stereo-energy, oracle-mask; "
             "rir: nearest, linear, opus-nearest, opus-linear, aac-nearest, aac-linear) or ckpt:PATH (PATH a "
             "checkpoint or a folder of them, one per scene; rir also avgs:PATH). Default: the task's baselines.",
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


def run(args: argparse.Namespace) -> int:
    from avgs.commands.render import synthesis_of
    from avgs.io.atomic import check_output, write_json

    evaluation = task_named(args.task, "--task").part("evaluation")
    specs = _specs(args, evaluation.DEFAULT_METHODS)
    split = args.split or evaluation.DEFAULT_SPLIT
    evaluation.check_request(args.data_root, specs, split)  # a bad name or split fails before any scene is read
    if args.json:
        check_output(args.json, inputs=[*args.data_root, *evaluation.checkpoint_paths(specs)], what="--json")
    scene_dirs = evaluation.scenes(args.data_root, args.scene)
    progress = not args.no_progress
    synthesis = synthesis_of(args)
    methods = {spec: evaluation.load_method(spec, device=args.device, synthesis=synthesis, progress=progress)
               for spec in specs}
    report = evaluation.evaluate(methods, scene_dirs, split=split, progress=progress)
    print(evaluation.format_report(report))
    if args.json:
        write_json(args.json, report)
        print(f"wrote {args.json}")
    return 0
