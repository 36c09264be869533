"""``avgs prune in.ckpt --out out.ckpt``: keep only the audio points some vicinity can use.

The region where listeners (and the source) may go is, in order: ``--region`` (world
box), the listener poses of ``--scene`` widened by ``--margin``, or the checkpoint's
scene bounds (the most conservative). Inside it the pruned model's masks equal the
original's (:mod:`avgs.render.prune`). G is dropped unless ``--keep-gaussians``.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", metavar="in.ckpt", help="Checkpoint to prune.")
    parser.add_argument("--out", required=True, metavar="out.ckpt", help="Pruned checkpoint to write (atomically).")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--region", type=float, nargs=6, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                       help="Walkable box in world coordinates (min corner, max corner).")
    where.add_argument("--scene", metavar="DATA_ROOT/SCENE_ID", help="Take the walkable box from this scene's listener poses.")
    parser.add_argument("--margin", type=float, default=0.25, help="Widen the --scene box by this much, world units (default 0.25).")
    parser.add_argument("--cell", type=float, help="Grid cell of the region cover, world units (default: 1/16 of the box).")
    parser.add_argument("--keep-gaussians", action="store_true", help="Keep G (for drawing) in the pruned checkpoint.")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from avgs.io.atomic import check_output
    from avgs.io.checkpoint import load_checkpoint, save_checkpoint
    from avgs.render.prune import prune_checkpoint, scene_listener_box

    check_output(args.out, inputs=[args.checkpoint, args.scene], what="--out")
    ckpt = load_checkpoint(args.checkpoint)
    region, listeners = None, None
    if args.region is not None:
        region = np.asarray(args.region, dtype=np.float64).reshape(2, 3)
    elif args.scene is not None:
        region, listeners = scene_listener_box(args.scene, args.margin)
    pruned, info = prune_checkpoint(ckpt, region, listeners_world=listeners, cell=args.cell, keep_gaussians=args.keep_gaussians)
    save_checkpoint(pruned, args.out)
    before, after = Path(args.checkpoint).stat().st_size, Path(args.out).stat().st_size
    print(
        f"wrote {args.out}: {info['points_after']} of {info['points_before']} audio points kept "
        f"(k = {info['k']} fixed), {before / 1e6:.2f} MB -> {after / 1e6:.2f} MB"
        + ("" if info["gaussians_kept"] else ", G dropped")
    )
    return 0
