"""``avgs train DATA_ROOT/SCENE_ID --out scene.ckpt``: both stages, with progress bars,
a JSON-lines log (``scene.ckpt.log.jsonl``) and loss / point-count curves
(``scene.ckpt.curves.png``) next to the checkpoint."""

from __future__ import annotations

import argparse

from avgs.config import DIRECTION_ENCODINGS, AcousticConfig, GaussianConfig, PointManagementConfig, TrainConfig, field_help


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="DATA_ROOT/SCENE_ID", help="Scene folder in the RWAVS layout.")
    parser.add_argument("--out", required=True, metavar="scene.ckpt", help="Checkpoint to write (atomically).")
    parser.add_argument("--quick", action="store_true", help="Tiny preset for tests: few iterations, small images.")
    parser.add_argument("--resume", action="store_true", help="Continue from the training state saved in --out.")
    parser.add_argument("--stage1-iterations", type=int, metavar="N", help=field_help(GaussianConfig, "iterations"))
    parser.add_argument("--image-downscale", type=int, metavar="F", help=field_help(GaussianConfig, "image_downscale"))
    parser.add_argument("--max-gaussians", type=int, metavar="N", help=field_help(GaussianConfig, "max_gaussians"))
    parser.add_argument("--stage1-only", action="store_true",
                        help="Run stage 1 alone (frames and poses, no audio read) and write OUT.stage1.pt, which a "
                             "later run with the same --out and settings reuses.")
    parser.add_argument("--stage1", metavar="FILE",
                        help="Take G from this stage-1 file (from --stage1-only) instead of training it; "
                             "lets several stage-2 runs share one G.")
    parser.add_argument("--iterations", type=int, metavar="N", help=field_help(AcousticConfig, "iterations"))
    parser.add_argument("--vicinity-percentile", type=float, metavar="P", help=field_help(AcousticConfig, "vicinity_percentile"))
    parser.add_argument("--alpha-init", metavar="SPEC", help=field_help(AcousticConfig, "alpha_init") + " (sh+r, sh, r, s, o, ...)")
    parser.add_argument("--init", choices=("gs", "sfm"), help=field_help(TrainConfig, "init"))
    parser.add_argument("--audio-points", type=int, metavar="N", help=field_help(PointManagementConfig, "initial_points"))
    parser.add_argument("--no-point-management", action="store_true", help="Turn audio-aware densification and pruning off.")
    parser.add_argument("--no-context", action="store_true", help="Drop the scene context C (the control model).")
    parser.add_argument("--post-conv", dest="post_conv", action="store_true", default=None,
                        help=field_help(AcousticConfig, "post_conv"))
    parser.add_argument("--no-post-conv", dest="post_conv", action="store_false")
    parser.add_argument("--reverb-tail", dest="reverb_tail", action="store_true", default=None,
                        help=field_help(AcousticConfig, "reverb_tail"))
    parser.add_argument("--no-reverb-tail", dest="reverb_tail", action="store_false",
                        help="B with the paper's time-invariant masks only (no reverberant tail).")
    parser.add_argument("--direction-encoding", choices=DIRECTION_ENCODINGS,
                        help=field_help(AcousticConfig, "direction_encoding"))
    parser.add_argument("--direction-harmonics", type=int, metavar="K", help=field_help(AcousticConfig, "direction_harmonics"))
    parser.add_argument("--position-frequencies", type=int, metavar="N", help=field_help(AcousticConfig, "position_frequencies"))
    parser.add_argument("--direction-first-layer", dest="direction_every_layer", action="store_false", default=None,
                        help="Give B's difference MLP the direction feature at its first layer only (the paper's "
                             "text; the default gives it to every layer).")
    parser.add_argument("--no-gaussians", action="store_true", help="Do not store G in the checkpoint.")
    parser.add_argument("--device", choices=("cpu", "cuda"), help=field_help(TrainConfig, "device"))
    parser.add_argument("--seed", type=int, help=field_help(TrainConfig, "seed"))
    parser.add_argument("--checkpoint-every", type=int, metavar="N", help=field_help(TrainConfig, "checkpoint_every"))
    parser.add_argument("--eval-every", type=int, metavar="N", help=field_help(TrainConfig, "eval_every"))
    parser.add_argument("--no-progress", action="store_true", help="Hide the progress bars.")


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """TrainConfig from the defaults (or the --quick preset) and the flags given."""
    from avgs.acoustics.points import parse_alpha_spec
    from avgs.train.pipeline import quick_config

    cfg = quick_config() if args.quick else TrainConfig()
    for flag, (obj, name) in {
        "stage1_iterations": (cfg.gaussians, "iterations"),
        "image_downscale": (cfg.gaussians, "image_downscale"),
        "max_gaussians": (cfg.gaussians, "max_gaussians"),
        "iterations": (cfg.acoustic, "iterations"),
        "vicinity_percentile": (cfg.acoustic, "vicinity_percentile"),
        "alpha_init": (cfg.acoustic, "alpha_init"),
        "post_conv": (cfg.acoustic, "post_conv"),
        "reverb_tail": (cfg.acoustic, "reverb_tail"),
        "direction_encoding": (cfg.acoustic, "direction_encoding"),
        "direction_harmonics": (cfg.acoustic, "direction_harmonics"),
        "position_frequencies": (cfg.acoustic, "position_frequencies"),
        "direction_every_layer": (cfg.acoustic, "direction_every_layer"),
        "audio_points": (cfg.points, "initial_points"),
        "init": (cfg, "init"),
        "device": (cfg, "device"),
        "seed": (cfg, "seed"),
        "checkpoint_every": (cfg, "checkpoint_every"),
        "eval_every": (cfg, "eval_every"),
    }.items():
        value = getattr(args, flag)
        if value is not None:
            setattr(obj, name, value)
    if cfg.acoustic.iterations < 1 or cfg.gaussians.iterations < 0:
        raise ValueError("--iterations must be >= 1 and --stage1-iterations >= 0")
    if cfg.gaussians.image_downscale < 1 or cfg.gaussians.max_gaussians < 1:
        raise ValueError("--image-downscale and --max-gaussians must be >= 1")
    if not 0 < cfg.acoustic.vicinity_percentile <= 100:
        raise ValueError(f"--vicinity-percentile must be in (0, 100], got {cfg.acoustic.vicinity_percentile}")
    if cfg.acoustic.direction_harmonics < 1 or cfg.acoustic.position_frequencies < 0:
        raise ValueError("--direction-harmonics must be >= 1 and --position-frequencies >= 0")
    parse_alpha_spec(cfg.acoustic.alpha_init)
    cfg.points.enabled = not args.no_point_management
    cfg.acoustic.use_context = not args.no_context
    cfg.store_gaussians = not args.no_gaussians
    if cfg.device == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise ValueError("--device cuda: no CUDA device is available")
    return cfg


def run(args: argparse.Namespace) -> int:
    from avgs.train.logging import log_paths
    from avgs.train.pipeline import run_stage1_only, train_scene

    cfg = config_from_args(args)
    if args.stage1_only:
        if args.stage1 or args.resume:
            raise ValueError("--stage1-only trains G; it takes neither --stage1 nor --resume")
        path = run_stage1_only(args.scene, args.out, cfg, progress=not args.no_progress)
        print(f"wrote {path} (stage 1: G for --out {args.out})")
        return 0
    final = train_scene(args.scene, args.out, cfg, resume=args.resume, progress=not args.no_progress, stage1=args.stage1)
    log, png = log_paths(args.out)
    metrics = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in final.items())
    print(f"wrote {args.out} ({metrics}); log {log}, curves {png}")
    return 0
