"""``avgs synth OUT_ROOT --preset office --scene-id office_1 --poses 100 --seed 0``:
generate one synthetic scene with physical ground truth in the RWAVS layout
(:mod:`avgs.synth`), and merge its source into ``OUT_ROOT/position.json``.

``avgs synth OUT_ROOT --task rir --preset rect_small``: an impulse-response scene (the same
RWAVS files for source 0, plus ``rir/``: binaural responses of every source, receiver and
orientation of a grid; docs/rir-layout.md). ``--task rir`` takes the six impulse-response
presets only; ``--task binaural`` takes every preset (an impulse-response preset's room makes
an ordinary binaural scene)."""

from __future__ import annotations

import argparse
import dataclasses

from avgs.commands.flags import field_help
from avgs.tasks import DEFAULT, TASKS, task_named




def add_arguments(parser: argparse.ArgumentParser) -> None:
    from avgs.synth.presets import ALL_PRESETS, RIR_PRESETS
    from avgs.synth.writer import SynthConfig

    parser.add_argument("out_root", metavar="OUT_ROOT", help="Data root; the scene goes to OUT_ROOT/SCENE_ID.")
    parser.add_argument("--task", choices=tuple(TASKS), default=DEFAULT,
                        help="binaural: an RWAVS scene (a binaural recording along listener poses); rir: an impulse-response "
                             f"scene (RWAVS files for source 0 plus rir/, docs/rir-layout.md; presets {', '.join(RIR_PRESETS)}).")
    parser.add_argument("--preset", choices=ALL_PRESETS, default=None,
                        help=field_help(SynthConfig, "preset") + " (default office; rect_small with --task rir)")
    parser.add_argument("--scene-id", metavar="ID", help="Scene folder name (default: PRESET_SEED).")
    parser.add_argument("--poses", type=int, metavar="N", help=field_help(SynthConfig, "poses") + " (default 100; 20 with --quick)")
    parser.add_argument("--seed", type=int, default=0, help=field_help(SynthConfig, "seed"))
    parser.add_argument("--val-fraction", type=float, default=0.2, metavar="F", help=field_help(SynthConfig, "val_fraction"))
    parser.add_argument("--quick", action="store_true", help=field_help(SynthConfig, "quick"))
    parser.add_argument("--overwrite", action="store_true", help="Replace an existing scene of the same id.")
    parser.add_argument("--workers", type=int, default=2, metavar="N", help=field_help(SynthConfig, "workers"))
    parser.add_argument("--width", type=int, metavar="PX", help=field_help(SynthConfig, "width") + " (default 256; 64 with --quick)")
    parser.add_argument("--height", type=int, metavar="PX", help=field_help(SynthConfig, "height") + " (default 192; 48 with --quick)")
    parser.add_argument("--fov", type=float, metavar="DEG", help=field_help(SynthConfig, "fov_deg") + " (default 70)")
    parser.add_argument("--receiver-spacing", type=float, metavar="M",
                        help="--task rir: receiver grid spacing in metres (default: the preset's).")
    parser.add_argument("--source-spacing", type=float, metavar="M",
                        help="--task rir: source grid spacing in metres (default: the preset's).")
    parser.add_argument("--raw-hrtf", action="store_true",
                        help="Keep the KEMAR head's own response instead of diffuse-field equalising it "
                             "(the ears' colouration stays in the audio, as in a binaural recording).")
    parser.add_argument("--no-progress", action="store_true", help="Hide the progress bar.")


def config_from_args(args: argparse.Namespace):
    """The :class:`SynthConfig` of ``--task binaural`` (and of the RWAVS part of ``--task rir``)."""
    from avgs.synth.writer import SynthConfig

    if args.preset is None:
        args.preset = "office"
    cfg = SynthConfig.quick_config(args.preset, args.seed) if args.quick else SynthConfig(preset=args.preset, seed=args.seed)
    cfg.val_fraction = args.val_fraction
    cfg.workers = args.workers
    for flag, name in (("poses", "poses"), ("width", "width"), ("height", "height"), ("fov", "fov_deg")):
        value = getattr(args, flag)
        if value is not None:
            setattr(cfg, name, value)
    if cfg.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {cfg.workers}")
    if cfg.width < 8 or cfg.height < 8:
        raise ValueError(f"--width and --height must be >= 8 pixels, got {cfg.width}x{cfg.height}")
    if not 1.0 <= cfg.fov_deg <= 170.0:
        raise ValueError(f"--fov must be in [1, 170] degrees, got {cfg.fov_deg}")
    cfg.split_sizes()  # validates --poses and --val-fraction
    if args.raw_hrtf:
        cfg.sim = dataclasses.replace(cfg.sim, hrtf_equalised=False)
    return cfg


def rir_config_from_args(args: argparse.Namespace):
    """The :class:`RIRConfig` of ``--task rir``: the preset's grid and the hybrid simulation;
    the RWAVS part takes the binaural flags (--poses, --width, --height, --fov, --raw-hrtf)."""
    from avgs.synth.rir_writer import RIRConfig

    if args.preset is None:
        args.preset = "rect_small"
    make = RIRConfig.quick_config if args.quick else RIRConfig
    cfg = make(preset=args.preset, seed=args.seed, workers=args.workers)
    cfg.validate()  # the preset first: a binaural preset is refused by name
    synth = config_from_args(args)
    cfg.binaural = dataclasses.replace(synth, sim=dataclasses.replace(cfg.binaural.sim, hrtf_equalised=synth.sim.hrtf_equalised))
    changes = {"val_fraction": args.val_fraction}
    if args.receiver_spacing is not None:
        changes["receiver_spacing"] = args.receiver_spacing
    if args.source_spacing is not None:
        changes["source_spacing"] = args.source_spacing
    cfg.grid = dataclasses.replace(cfg.grid_config(), **changes)
    cfg.validate()
    return cfg


def run_rir(args: argparse.Namespace) -> int:
    from avgs.synth.rir_writer import write_rir_scene

    cfg = rir_config_from_args(args)
    scene_id = args.scene_id or f"{cfg.preset}_{cfg.seed}"
    result = write_rir_scene(args.out_root, scene_id, cfg, overwrite=args.overwrite, progress=not args.no_progress)
    g = result.grid
    counts = ", ".join(f"{len(g.splits[k])} {k}" for k in ("train", "val", "heldout"))
    rt = result.scene.rt60.get("broadband_s")
    rt_text = f"{rt:.3f} s" if rt is not None else "n/a"
    print(
        f"wrote {result.scene.scene_dir}: {len(g.sources)} sources x {len(g.receivers)} receivers ({counts} pairs), "
        f"{result.responses} responses of {result.length} samples; RT60 {rt_text}; responses {result.seconds_responses:.1f} s "
        f"({result.cpu_seconds_per_room:.2f} s per room on one core), {result.seconds_total:.1f} s in all"
    )
    if result.silent:
        print(f"note: {result.silent} of {result.responses} responses hold no sound: no image source up to the "
              "simulator's order reaches their listener, and ray tracing (the sound that finds its way around) is "
              "off; scene.json's rir.silent counts them")
    return 0


def run(args: argparse.Namespace) -> int:
    return task_named(args.task, "--task").part("synth")(args)


def run_binaural(args: argparse.Namespace) -> int:
    from avgs.synth.writer import write_scene

    for flag in ("receiver_spacing", "source_spacing"):
        if getattr(args, flag) is not None:
            raise ValueError(f"--{flag.replace('_', '-')} applies to --task rir only")
    cfg = config_from_args(args)
    scene_id = args.scene_id or f"{cfg.preset}_{cfg.seed}"
    result = write_scene(args.out_root, scene_id, cfg, overwrite=args.overwrite, progress=not args.no_progress)
    rt = result.rt60.get("broadband_s")
    rt_text = f"{rt:.3f} s" if rt is not None else "n/a"
    print(
        f"wrote {result.scene_dir} ({result.n_train} train + {result.n_val} val poses, {cfg.width}x{cfg.height} frames); "
        f"RT60 {rt_text}; {result.seconds_per_pose:.2f} s per pose ({result.cpu_seconds_per_pose:.2f} s on one core), "
        f"{result.seconds_total:.1f} s in all"
    )
    return 0
