"""``avgs info scene.ckpt [--json]``: what a checkpoint holds (source, bounds, point counts,
format version, sample rate, training configuration and final metrics)."""

from __future__ import annotations

import argparse
import math
import json

from avgs.tasks import task_named, task_of


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", metavar="scene.ckpt", help="Checkpoint written by 'avgs train'.")
    parser.add_argument("--json", action="store_true", help="Print one JSON object instead of text.")


def summary(path) -> dict:
    """Plain-value description of the checkpoint at ``path`` (world coordinates)."""
    from avgs.io.checkpoint import config_of, load_checkpoint, stft_of
    from avgs.data.frame import SceneFrame

    ckpt = load_checkpoint(path)
    frame = SceneFrame.from_dict(ckpt["frame"])
    cfg = config_of(ckpt)
    stft = stft_of(ckpt)
    g = ckpt.get("gaussians")
    scene = ckpt["scene"]
    return {
        "path": str(path),
        "format_version": int(ckpt["format_version"]),
        "scene": str(scene.get("name", "")),
        "source_position": [float(v) for v in frame.to_world(ckpt["source"].double().numpy())],
        "bounds": scene["bounds"].double().tolist(),
        "frame": frame.to_dict(),
        "audio_points": int(ckpt["audio_points"]["X"].shape[0]),
        "alpha_dim": int(ckpt["audio_points"]["alpha"].shape[1]),
        "gaussians": int(g["means"].shape[0]) if g else 0,
        "outline_segments": int(scene["outline"].shape[0]) if scene.get("outline") is not None else 0,
        "sample_rate": int(stft.sample_rate),
        "stft": {"n_fft": stft.n_fft, "hop_length": stft.hop_length, "win_length": stft.win_length},
        "iteration": trained_iteration(ckpt),
        "task": task_of(ckpt).name,
        "training": {
            "stage1_iterations": cfg.gaussians.iterations,
            "iterations": cfg.acoustic.iterations,
            "init": cfg.init,
            "alpha_init": cfg.acoustic.alpha_init,
            "vicinity_percentile": cfg.acoustic.vicinity_percentile,
            "use_context": cfg.acoustic.use_context,
            "point_management": cfg.points.enabled,
            "mixture_activation": cfg.acoustic.mixture_activation,
            "direction_encoding": cfg.acoustic.direction_encoding,
            "direction_every_layer": cfg.acoustic.direction_every_layer,
            "position_frequencies": cfg.acoustic.position_frequencies,
            "reverb_tail": cfg.acoustic.reverb_tail,
            "seed": cfg.seed,
        },
        "rt60_s": octave_rt60(ckpt["binauralizer"].get("reverb.log_rt60"), stft),
        "itd_scale_us": (None if ckpt["binauralizer"].get("itd_scale") is None
                         else 1e6 * float(ckpt["binauralizer"]["itd_scale"])),
        "itd_law_us": (None if ckpt["binauralizer"].get("itd_law") is None
                       else [1e6 * float(c) for c in ckpt["binauralizer"]["itd_law"]]),
        "ild_law_db": (None if ckpt["binauralizer"].get("ild_law") is None
                       else [float(c) for c in ckpt["binauralizer"]["ild_law"]]),
        "level_law_db": (None if ckpt["binauralizer"].get("level_law") is None
                         else [float(c) for c in ckpt["binauralizer"]["level_law"]]),
        "ild_local_responses": (None if ckpt["binauralizer"].get("local_residual") is None
                                else int(ckpt["binauralizer"]["local_residual"].numel())),
        "reflecting_walls": (None if ckpt["binauralizer"].get("reflecting_walls") is None
                             else int((ckpt["binauralizer"]["reflecting_walls"][:, :2].abs().sum(-1) > 0).sum())),
        "reflection_gain": (None if ckpt["binauralizer"].get("reflection_gain") is None
                            else float(ckpt["binauralizer"]["reflection_gain"])),
        "reflected_arrival": (None if ckpt["binauralizer"].get("reflected_arrival") is None
                              else [bool(float(v) > 0.5) for v in ckpt["binauralizer"]["reflected_arrival"]]),
        "blocked_lag_ms": (None if ckpt["binauralizer"].get("blocked_lag") is None
                           else 1e3 * float(ckpt["binauralizer"]["blocked_lag"])),
        "blocked_ild": (None if ckpt["binauralizer"].get("blocked_ild") is None
                        else float(ckpt["binauralizer"]["blocked_ild"])),
        "blocked_from_points": (None if ckpt["binauralizer"].get("sight_blocked") is None
                                else float(ckpt["binauralizer"]["sight_blocked"])),
        "wall_loss_db": (None if ckpt["binauralizer"].get("wall_loss") is None
                         else [20.0 / math.log(10.0) * float(v) for v in ckpt["binauralizer"]["wall_loss"]]),
        "wall_unit_points": (None if ckpt["binauralizer"].get("wall_unit") is None
                             else float(ckpt["binauralizer"]["wall_unit"])),
        "metrics": {k: v for k, v in dict(ckpt.get("metrics") or {}).items()},
    }


def trained_iteration(ckpt: dict) -> int | None:
    """The stage-2 iteration the checkpoint's weights are from: its training state's, else its final
    metrics' (a finished run saved without its training state), else the last logged one; None
    when nothing says (an untrained checkpoint)."""
    state = ckpt.get("train_state")
    if state is not None:
        return int(state["iteration"])
    final = (ckpt.get("metrics") or {}).get("iteration")
    if isinstance(final, int) and not isinstance(final, bool):
        return final
    logged = [r["iteration"] for r in ckpt["history"] if r.get("stage") in ("stage2", "final")
              and isinstance(r.get("iteration"), int) and not isinstance(r.get("iteration"), bool)]
    return max(logged) if logged else None


OCTAVE_BANDS_HZ = (125, 250, 500, 1000, 2000, 4000, 8000)


def octave_rt60(log_rt60, stft) -> dict[str, float] | None:
    """The learned RT60 per octave band (median over the band's bins), seconds; None without a tail."""
    if log_rt60 is None:
        return None
    import numpy as np

    from avgs.acoustics.reverb_tail import rt60_seconds

    rt60 = rt60_seconds(log_rt60.double()).numpy()  # [F]
    freqs = np.arange(len(rt60)) * stft.sample_rate / stft.n_fft
    bands = {}
    for fc in OCTAVE_BANDS_HZ:
        inside = (freqs >= fc / np.sqrt(2)) & (freqs < fc * np.sqrt(2))
        if inside.any():
            bands[str(fc)] = round(float(np.median(rt60[inside])), 4)
    return bands


def harmonics(coefficients: list[float], fmt: str) -> str:
    """``a sin theta + b sin 2theta - c sin 3theta`` of a law's coefficients."""
    out = ""
    for k, c in enumerate(coefficients, start=1):
        term = f"{abs(c):{fmt}} sin {k if k > 1 else ''}theta"
        out += (("-" if c < 0 else "") + term) if not out else (f" - {term}" if c < 0 else f" + {term}")
    return out


def run(args: argparse.Namespace) -> int:
    info = summary(args.checkpoint)
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    from avgs.acoustics.rir_binauralizer import never_blocked

    src = ", ".join(f"{v:.3f}" for v in info["source_position"])
    lo, hi = (", ".join(f"{v:.2f}" for v in row) for row in info["bounds"])
    task = task_named(info["task"])
    print(f"{info['path']}: AV-GS checkpoint, format {info['format_version']}, scene {info['scene']!r}, task {task.name}: "
          f"{task.summary}; {'the source can move' if task.source_aware else 'one source position'}")
    print(f"  audio points {info['audio_points']} (alpha {info['alpha_dim']} dims), gaussians {info['gaussians']}, outline segments {info['outline_segments']}")
    print(f"  source ({src}) world; bounds ({lo}) .. ({hi})")
    print(f"  {info['sample_rate']} Hz, n_fft {info['stft']['n_fft']}, hop {info['stft']['hop_length']}")
    t = info["training"]
    at = "" if info["iteration"] is None else f"; at iteration {info['iteration']}"
    print("  trained " + ", ".join(f"{k} {v}" for k, v in t.items()) + at)
    if info["itd_scale_us"] is not None and info["itd_law_us"] is None:
        scale = info["itd_scale_us"]
        print(f"  ears: a spherical head's ITD, a / c = {scale:.0f} us (a = {scale * 0.0343:.1f} cm at 343 m/s; "
              f"{scale * (math.pi / 2 + 1):.0f} us at 90 degrees)")
    if info["itd_law_us"] is not None:
        print(f"  direct sound's ITD: {harmonics(info['itd_law_us'], '.0f')} us (fitted to the training responses in sight "
              "of the source)")
    if info["ild_law_db"] is not None:
        law = harmonics(info["ild_law_db"], ".1f")
        blocked = info["blocked_from_points"]
        where = ("everywhere (no wall told apart in training)" if never_blocked(blocked) else
                 f"where the straight path is free (behind a wall from {blocked:.0f} audio points along it: B's ILD)")
        local = info["ild_local_responses"]
        near = f", corrected near the {local} training responses in sight by their early ILDs" if local else ""
        walls = info["reflecting_walls"]
        mixed = (f", mixed with the first reflections off {walls} walls found in the audio points (gain "
                 f"{info['reflection_gain']:.2f})" if walls else "")
        print(f"  direct sound's ILD: {law} dB{mixed}{near}, {where}")
        arrival = info["reflected_arrival"]
        if arrival is not None and walls and not never_blocked(blocked):
            told = {True: "the walls' first reflection", False: "the straight line"}
            lag = info["blocked_lag_ms"]
            delay = f"the straight line plus {lag:.1f} ms" if lag else told[arrival[1]]
            print(f"  behind a wall, the first sound's direction from {told[arrival[0]]}, its delay from "
                  f"{delay} (as the training responses behind a wall say)")
        elif info["blocked_lag_ms"] and not never_blocked(blocked):
            print(f"  behind a wall, the first sound {info['blocked_lag_ms']:.1f} ms after the straight line "
                  "(as the training responses behind a wall say)")
        shrink = info["blocked_ild"]
        if shrink is not None and shrink != 1.0 and not never_blocked(blocked):
            print(f"  behind a wall, the first 5 ms's ILD {shrink:.1f} times the network's (as the training responses "
                  "behind a wall say)")
    if info["level_law_db"] is not None:
        c0, c1, c2 = info["level_law_db"]
        print(f"  direct sound's level: {c0:.1f} {'-' if c1 < 0 else '+'} {abs(c1):.1f} cos theta {'-' if c2 < 0 else '+'} "
              f"{abs(c2):.1f} cos 2theta - 20 log10 d dB (d in the model's units; fitted to the training responses in sight)")
    if info["wall_loss_db"] is not None:
        unit, loss = info["wall_unit_points"], info["wall_loss_db"]
        if never_blocked(unit):
            print("  walls: none told apart in training (no wall term)")
        else:
            db = [round(v, 1) + 0.0 for v in (loss[0], min(loss), loss[-1])]  # no "-0.0"
            print(f"  each wall on the straight path ({unit:.0f} audio points along it): {db[0]:+.1f} dB in the first frame, "
                  f"{db[1]:+.1f} dB at its strongest, {db[2]:+.1f} dB in the last")
    if info["rt60_s"]:
        print("  learned RT60 " + ", ".join(f"{fc} Hz {v:.2f} s" for fc, v in info["rt60_s"].items()))
    if info["metrics"]:
        print("  final " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in info["metrics"].items()))
    return 0
