"""Level against source distance, and a source behind a wall: RIR checkpoints against the simulator.

The issue's check: *at a fixed listener, the predicted level against source distance
(0.5 to 5 m, same room) follows the simulator's truth within 2 dB, and a source behind a
wall is quieter than one at the same distance in the listener's room, as in the truth.*

Two experiments, each at one fixed listener (a training receiver of the scene, ear height),
each source at the scene's source height:

1. **Distance** (a single room, default ``data/rir/rect_large``): sources every 0.5 m on a
   straight line from the listener, 0.5 m up to 5 m or as far as the room allows (the
   receiver and direction, every 15 degrees, with the longest walkable line; ties: the
   listener nearest the middle of the receivers).
2. **Behind a wall** (a multi-room scene, default ``data/rir/two_rooms``): one source in the
   listener's room with a clear line of sight, one in another room at the same straight-line
   distance whose line to the listener crosses a partition, well clear of the doorway (every
   point within 1 m of it is hidden too); of those, the pair whose two sources stand nearest
   the scene's training sources, so that the check measures the wall and not extrapolation.

Truth: :func:`avgs.synth.simulate.receiver_rirs` with the scene's recorded simulation
settings (``scene.json`` ``rir.simulation``), the recorded delay cut off the front and cut to
the scene's length, exactly as ``avgs synth --task rir`` wrote the training responses.
Predictions: ``SceneRenderer.predict_responses`` of the AV-GS and the ``--no-context``
checkpoints of one sweep seed (``RUNS/<scene>/<setting>/seed<k>/scene.ckpt``), and the
``nearest`` baseline (:mod:`avgs.evaluation.interpolation`) on the scene's training responses.

Level: ``10 log10`` of the energy of the response (whole length), averaged over both ears
and the listener orientations ``--yaws`` (the scene's four by default, so the head's shadow
does not favour one source direction).

Outputs (atomic): a two-panel figure (``--figure``) and a markdown table (``--table``) with the
command, the checkpoints, every level (absolute, and relative to the nearest source) and the
largest |prediction - truth|, plain and after removing the constant offset that fits best
(the mean difference).

    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python scripts/rir_level_distance.py --seed 0
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avgs.io.atomic import atomic_path, check_output, write_text
from avgs.data.rir import RIRScene, RIRSet
from avgs.synth.poses import is_walkable
from avgs.synth.presets import SceneSpec
from avgs.synth.simulate import SimSettings, load_spec, receiver_rirs
from avgs.render.renderer import SceneRenderer
from avgs.evaluation.interpolation import INTERPOLATIONS

SOURCES_PER_ROOM = 3
"Sources simulated in one pyroomacoustics room (as ``avgs synth --task rir``: bounds the ray tracer's memory)."


# -- geometry ---------------------------------------------------------------------------


def _placeable(spec: SceneSpec) -> SceneSpec:
    """The spec whose walkable area is where a source may stand (no clearance from the scene's own source)."""
    return dataclasses.replace(spec, source_clearance=0.0)


def room_of(spec: SceneSpec, xy) -> int:
    """Index of the floor region (the room) holding ``xy`` (first match), -1 when none does."""
    p = np.asarray(xy, dtype=np.float64)[:2]
    for k, region in enumerate(spec.floors):
        c = np.asarray(region.corners, dtype=np.float64)  # [K, 2] convex, counter-clockwise
        edge, to_p = np.roll(c, -1, axis=0) - c, p - c
        if np.all(edge[:, 0] * to_p[:, 1] - edge[:, 1] * to_p[:, 0] >= -1e-9):
            return k
    return -1


def crosses_partition(spec: SceneSpec, a, b, height: float) -> bool:
    """Whether the segment ``a -> b`` (xy) passes through a partition standing at ``height`` (Liang-Barsky)."""
    a, b = np.asarray(a, dtype=np.float64)[:2], np.asarray(b, dtype=np.float64)[:2]
    d = b - a
    for box in spec.boxes:
        if box.kind != "partition" or not (box.lo[2] <= height <= box.hi[2]):
            continue
        t0, t1 = 0.0, 1.0
        for axis in range(2):
            lo, hi = box.lo[axis], box.hi[axis]
            if abs(d[axis]) < 1e-12:
                if not lo <= a[axis] <= hi:
                    t0, t1 = 1.0, 0.0
                    break
                continue
            u, v = sorted(((lo - a[axis]) / d[axis], (hi - a[axis]) / d[axis]))
            t0, t1 = max(t0, u), min(t1, v)
        if t0 < t1:
            return True
    return False


@dataclass(frozen=True)
class Line:
    """Sources on a straight line from the listener (world metres)."""

    listener: np.ndarray  # [3]
    direction: np.ndarray  # [2] unit, xy
    distances: np.ndarray  # [S] metres
    sources: np.ndarray  # [S, 3]


def source_line(spec: SceneSpec, receivers, source_z: float, distances, angle_step_deg: float = 15.0) -> Line:
    """The receiver and direction whose line of sources (at ``distances``, contiguous from the
    first) is longest while every source stands in the walkable area in the listener's room
    with a clear line of sight; ties: the receiver nearest the middle of the receivers, then
    the smaller angle."""
    receivers = np.asarray(receivers, dtype=np.float64).reshape(-1, 3)
    distances = np.asarray(distances, dtype=np.float64)
    place = _placeable(spec)
    middle = receivers[:, :2].mean(axis=0)
    best, best_key = None, None
    for i in np.argsort(np.linalg.norm(receivers[:, :2] - middle, axis=1), kind="stable"):
        listener = receivers[i]
        home = room_of(spec, listener)
        for angle in np.radians(np.arange(0.0, 360.0, angle_step_deg)):
            d = np.array([np.cos(angle), np.sin(angle)])
            n = 0
            for x in distances:
                p = listener[:2] + x * d
                if not (is_walkable(place, p) and room_of(spec, p) == home
                        and not crosses_partition(spec, listener, p, source_z)):
                    break
                n += 1
            if best_key is None or n > best_key:
                best_key, best = n, (listener, d)
    if not best_key:
        raise ValueError(f"{spec.preset}: no receiver has a walkable source at {distances[0]:g} m in any direction")
    listener, d = best
    used = distances[:best_key]
    sources = np.array([[*(listener[:2] + x * d), source_z] for x in used])  # [S, 3]
    return Line(listener=listener, direction=d, distances=used, sources=sources)


@dataclass(frozen=True)
class WallPair:
    """A listener, a source in its room and one behind a partition at the same distance (world metres)."""

    listener: np.ndarray  # [3]
    same_room: np.ndarray  # [3]
    behind: np.ndarray  # [3]
    distance: float
    margin: float  # every point within this radius of ``behind`` is hidden too


def wall_pair(spec: SceneSpec, receivers, source_z: float, distance: float, training_sources=None,
              min_margin: float = 1.0, angle_step_deg: float = 5.0,
              radii=tuple(np.round(np.arange(0.1, 2.01, 0.1), 2))) -> WallPair:
    """A training receiver as listener, a source in its room with a clear line of sight and one
    behind a partition, both at ``distance``.

    The hidden source must stay hidden for every point (16 probes) within ``min_margin`` of it
    (its margin: the largest radius of ``radii`` that does). Among those, the pair whose sources
    stand nearest the ``training_sources [K, 3]`` (world; the larger of the two distances to the
    nearest one), so that the check measures the wall and not extrapolation to unseen source
    positions; without training sources, the largest margin. Ties: the receiver nearest the
    middle of its room's receivers."""
    receivers = np.asarray(receivers, dtype=np.float64).reshape(-1, 3)
    known = None if training_sources is None else np.asarray(training_sources, dtype=np.float64).reshape(-1, 3)

    def support(p) -> float:  # metres from a point (xy) to the nearest training source
        return 0.0 if known is None else float(np.min(np.linalg.norm(known[:, :2] - np.asarray(p)[:2], axis=1)))

    place = _placeable(spec)
    ring = np.stack([np.cos(np.linspace(0, 2 * np.pi, 16, endpoint=False)),
                     np.sin(np.linspace(0, 2 * np.pi, 16, endpoint=False))], axis=1)  # [16, 2]
    angles = np.radians(np.arange(0.0, 360.0, angle_step_deg))
    best, best_key = None, None
    for listener in receivers:
        home = room_of(spec, listener)
        peers = receivers[[room_of(spec, r) == home for r in receivers]]
        centrality = -float(np.linalg.norm(listener[:2] - peers[:, :2].mean(axis=0)))
        points = listener[:2] + distance * np.stack([np.cos(angles), np.sin(angles)], axis=1)  # [A, 2]
        ok = np.array([is_walkable(place, p) for p in points])
        room = np.array([room_of(spec, p) for p in points])
        hidden = np.array([crosses_partition(spec, listener, p, source_z) for p in points])
        clear = np.flatnonzero(ok & (room == home) & ~hidden)
        if not clear.size:
            continue
        same = points[min(clear, key=lambda i: support(points[i]))]
        for j in np.flatnonzero(ok & (room != home) & (room >= 0) & hidden):
            margin = 0.0
            for r in radii:
                if not all(crosses_partition(spec, listener, points[j] + r * u, source_z) for u in ring):
                    break
                margin = r
            if margin < min_margin:
                continue
            key = (-round(max(support(same), support(points[j])), 6), 0.0 if known is not None else margin,
                   centrality)
            if best_key is None or key > best_key:
                best_key = key
                best = WallPair(listener=listener, same_room=np.array([*same, source_z]),
                                behind=np.array([*points[j], source_z]), distance=float(distance), margin=margin)
    if best is None:
        raise ValueError(f"{spec.preset}: no receiver has both a source in its room and one behind a partition "
                         f"at {distance:g} m; try another --wall-distance")
    return best


# -- responses --------------------------------------------------------------------------


def level_db(h) -> np.ndarray:
    """Level (dB) of responses ``[..., O, 2, L]``: the energy averaged over ears and orientations -> ``[...]``."""
    e = np.sum(np.asarray(h, dtype=np.float64) ** 2, axis=-1)  # [..., O, 2]
    return 10.0 * np.log10(np.mean(e, axis=(-2, -1)) + 1e-30)


def simulated(scene_dir: Path, sources, listener, yaws) -> np.ndarray:
    """The simulator's truth ``[S, O, 2, L]`` in the scene's time frame, scale and length
    (``scene.json`` ``rir``: settings, removed delay, length), a room per few sources."""
    meta = json.loads((scene_dir / "scene.json").read_text())
    if "rir" not in meta:
        raise ValueError(f"{scene_dir / 'scene.json'}: no 'rir' section; expected a scene of `avgs synth --task rir`")
    rir = meta["rir"]
    settings = SimSettings.from_dict(rir["simulation"])
    offset, length = int(rir["removed_delay_samples"]), int(rir["length_samples"])
    spec = load_spec(scene_dir)
    sources = np.asarray(sources, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((len(sources), len(yaws), 2, length), np.float32)
    for i in range(0, len(sources), SOURCES_PER_ROOM):
        h = receiver_rirs(spec, sources[i : i + SOURCES_PER_ROOM], listener, yaws, settings)  # [s, O, 2, n]
        part = h[..., offset : offset + length]
        out[i : i + SOURCES_PER_ROOM, ..., : part.shape[-1]] = part
    return out


def predicted(renderer: SceneRenderer, sources, listener, yaws) -> np.ndarray:
    """A checkpoint's responses ``[S, O, 2, L]`` (world positions in, normalised to the model's frame)."""
    src = renderer.frame.to_normalised(np.asarray(sources, dtype=np.float64).reshape(-1, 3))  # [S, 3]
    lis = renderer.frame.to_normalised(np.asarray(listener, dtype=np.float64).reshape(1, 3))  # [1, 3]
    s, o = len(src), len(yaws)
    h = renderer.predict_responses(np.repeat(src, o, axis=0), np.repeat(lis, s * o, axis=0),
                                   np.tile(np.asarray(yaws, dtype=np.float64), s))  # [S O, 2, L]
    return h.reshape(s, o, *h.shape[1:])


def interpolated(method: str, scene: RIRScene, sources, listener, yaws) -> np.ndarray:
    """A baseline of :mod:`avgs.evaluation.interpolation` on the training responses: ``[S, O, 2, L]``."""
    src = scene.frame.to_normalised(np.asarray(sources, dtype=np.float64).reshape(-1, 3))
    lis = scene.frame.to_normalised(np.asarray(listener, dtype=np.float64).reshape(1, 3))
    s, o = len(src), len(yaws)
    n = s * o
    query = RIRSet(rir=np.zeros((n, 2, scene.length), np.float32), source=np.repeat(src, o, axis=0),
                   receiver=np.repeat(lis, n, axis=0), yaw=np.tile(np.asarray(yaws, dtype=np.float64), s),
                   source_index=np.full(n, -1, np.int64), receiver_index=np.full(n, -1, np.int64))
    h = INTERPOLATIONS[method](scene.responses("train"), query)  # [S O, 2, L]
    return h.reshape(s, o, *h.shape[1:])


def finished_checkpoint(runs: Path, scene: str, setting: str, seed: int) -> Path:
    """``RUNS/<scene>/<setting>/seed<k>/scene.ckpt``, refused unless its run finished (``avgs sweep``'s
    status.json beside it, not running, failed or interrupted)."""
    folder = runs / scene / setting / f"seed{seed}"
    ckpt, status = folder / "scene.ckpt", folder / "status.json"
    if not ckpt.is_file():
        raise FileNotFoundError(f"{ckpt}: missing; expected a finished sweep run (is it still training?)")
    state = json.loads(status.read_text()).get("status") if status.is_file() else None
    if state in (None, "failed", "interrupted", "running"):
        raise ValueError(f"{status}: status {state!r}; expected a finished run")
    return ckpt


# -- report -----------------------------------------------------------------------------


def max_errors(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(max |pred - truth|, max |pred - truth - mean(pred - truth)|) in dB."""
    diff = np.asarray(pred) - np.asarray(truth)
    return float(np.max(np.abs(diff))), float(np.max(np.abs(diff - diff.mean())))


def draw(path: Path, line: Line, dist_levels: dict, wall: WallPair, wall_levels: dict, names: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    styles = {"truth": dict(color="black", marker="o", lw=2.2, zorder=5)}
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]
    markers = ["s", "^", "v", "D", "x"]
    for k, key in enumerate(m for m in dist_levels if m != "truth"):
        styles[key] = dict(color=colours[k % 5], marker=markers[k % 5], lw=1.4, ls="--" if k >= 2 else "-")
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw=dict(width_ratios=[1.35, 1]))
    for key, lv in dist_levels.items():
        a.plot(line.distances, lv, label=names[key], **styles[key])
    a.set_xscale("log")
    ticks = [t for t in (0.5, 1, 2, 3, 4, 5) if line.distances[0] - 1e-9 <= t <= line.distances[-1] + 1e-9]
    a.set_xticks(ticks, [f"{t:g}" for t in ticks])
    a.minorticks_off()
    a.set_xlabel("source distance (m, log scale)")
    a.set_ylabel("level (dB), mean over ears and yaws")
    a.set_title(f"(a) level against distance, {names['distance_scene']}\n"
                f"listener ({line.listener[0]:.2f}, {line.listener[1]:.2f}) m, sources along "
                f"({line.direction[0]:+.2f}, {line.direction[1]:+.2f})", fontsize=10)
    a.grid(True, alpha=0.3)
    a.legend(fontsize=9)

    keys = list(wall_levels)
    x = np.arange(len(keys))
    same = np.array([wall_levels[k][0] for k in keys])
    behind = np.array([wall_levels[k][1] for k in keys])
    b.vlines(x, np.minimum(same, behind), np.maximum(same, behind), color="0.6", lw=1.5, zorder=1)
    b.scatter(x, same, s=70, marker="o", color="tab:cyan", edgecolor="black", label="source in the same room", zorder=3)
    b.scatter(x, behind, s=70, marker="s", color="tab:gray", edgecolor="black", label="source behind the wall",
              zorder=3)
    for i in range(len(keys)):
        b.annotate(f"{behind[i] - same[i]:+.1f} dB", (x[i] + 0.08, (same[i] + behind[i]) / 2), va="center",
                   fontsize=9)
    low, high = float(min(same.min(), behind.min())), float(max(same.max(), behind.max()))
    b.set_ylim(low - 0.15 * (high - low) - 1.0, high + 0.15 * (high - low) + 1.0)
    b.set_xlim(-0.5, len(keys) - 0.5)
    b.set_xticks(x, [names[k] for k in keys], fontsize=9)
    b.set_ylabel("level (dB)")
    b.set_title(f"(b) behind a wall, {names['wall_scene']}: both sources {wall.distance:g} m away\n"
                "(labels: behind minus same room)", fontsize=10)
    b.grid(True, axis="y", alpha=0.3)
    b.legend(fontsize=9, loc="best")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def table(command: str, ckpts: dict, line: Line, dist_levels: dict, wall: WallPair, wall_levels: dict,
          names: dict, yaws, figure: Path) -> str:
    methods = [m for m in dist_levels if m != "truth"]
    out = [
        "# RIR level against source distance, and behind a wall",
        "",
        f"Made by `scripts/rir_level_distance.py` (figure: `{figure.name}`):",
        "",
        "```",
        command,
        "```",
        "",
        "Checkpoints:",
        "",
        *[f"- {names[k]}: `{v}`" for k, v in ckpts.items()],
        "",
        "Level: 10 log10 of the response's energy (whole length), averaged over both ears and the yaws "
        f"{', '.join(f'{y:g}' for y in yaws)} degrees. Truth: the simulator (`receiver_rirs`, the scene's "
        "recorded settings and delay). `nearest`: the training response of the nearest (source, receiver) pair.",
        "",
        f"## Level against distance ({names['distance_scene']})",
        "",
        f"Listener at ({', '.join(f'{v:.3f}' for v in line.listener)}) m, sources at height "
        f"{line.sources[0, 2]:g} m along ({line.direction[0]:+.3f}, {line.direction[1]:+.3f}).",
        "",
        "Absolute level (dB), and relative to the nearest source (dB, in brackets):",
        "",
        "| distance (m) | truth | " + " | ".join(names[m] for m in methods) + " |",
        "| --- | --- | " + " | ".join("---" for _ in methods) + " |",
    ]
    t = dist_levels["truth"]
    for i, d in enumerate(line.distances):
        cells = [f"{t[i]:.2f} ({t[i] - t[0]:+.2f})"]
        cells += [f"{dist_levels[m][i]:.2f} ({dist_levels[m][i] - dist_levels[m][0]:+.2f})" for m in methods]
        out.append(f"| {d:.1f} | " + " | ".join(cells) + " |")
    out += ["", "| method | max abs(pred - truth) (dB) | after removing the mean offset (dB) | mean offset (dB) "
            "| distances (m) within 2 dB |", "| --- | --- | --- | --- | --- |"]
    for m in methods:
        plain, centred = max_errors(dist_levels[m], t)
        within = ", ".join(f"{d:g}" for d, e in zip(line.distances, np.abs(dist_levels[m] - t)) if e <= 2.0)
        out.append(f"| {names[m]} | {plain:.2f} | {centred:.2f} | {np.mean(dist_levels[m] - t):+.2f} | {within} |")
    out += ["", f"The closest training (source, receiver) pair of {names['distance_scene']} is "
            f"{names['closest_pair']:.2f} m apart: nearer sources are extrapolation."]
    out += [
        "",
        f"## Behind a wall ({names['wall_scene']})",
        "",
        f"Listener at ({', '.join(f'{v:.3f}' for v in wall.listener)}) m; same-room source at "
        f"({', '.join(f'{v:.3f}' for v in wall.same_room)}), source behind the partition at "
        f"({', '.join(f'{v:.3f}' for v in wall.behind)}), both {wall.distance:g} m away (every point within "
        f"{wall.margin:g} m of the hidden source is hidden too).",
        "",
        "| method | same room (dB) | behind the wall (dB) | behind minus same (dB) | quieter behind? |",
        "| --- | --- | --- | --- | --- |",
    ]
    for k, (s, h) in wall_levels.items():
        out.append(f"| {names[k]} | {s:.2f} | {h:.2f} | {h - s:+.2f} | {'yes' if h < s else 'no'} |")
    return "\n".join(out) + "\n"


# -- command line -----------------------------------------------------------------------


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--distance-scene", type=Path, default=Path("data/rir/rect_large"),
                   help="a single-room RIR scene for the level against distance")
    p.add_argument("--wall-scene", type=Path, default=Path("data/rir/two_rooms"),
                   help="a multi-room RIR scene for the source behind a wall")
    p.add_argument("--runs", type=Path, default=Path("runs/rir"),
                   help="the sweep's folder: RUNS/<scene>/<setting>/seed<k>")
    p.add_argument("--seed", type=int, default=0, help="the sweep seed whose checkpoints are read")
    p.add_argument("--settings", nargs="*", default=["avgs", "no-context"],
                   help="the sweep settings to compare (none: truth and baselines only)")
    p.add_argument("--baselines", nargs="*", default=["nearest"], choices=sorted(INTERPOLATIONS),
                   help="interpolation baselines on the training responses")
    p.add_argument("--distances", type=float, nargs=3, default=[0.5, 5.0, 0.5], metavar=("FIRST", "LAST", "STEP"),
                   help="source distances (m), as far as the room allows")
    p.add_argument("--wall-distance", type=float, default=2.5, help="distance (m) of both sources of the wall check")
    p.add_argument("--yaws", type=float, nargs="+", default=None,
                   help="listener yaws (degrees) the level averages over; default: the scene's orientations")
    p.add_argument("--figure", type=Path, default=Path("docs/rir_level_distance.png"))
    p.add_argument("--table", type=Path, default=Path("docs/rir_level_distance.md"))
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    command = "OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python scripts/rir_level_distance.py " + " ".join(
        shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    inputs = [args.distance_scene, args.wall_scene, args.runs]
    figure = check_output(args.figure, inputs, "--figure")
    table_path = check_output(args.table, inputs, "--table")
    first, last, step = args.distances
    distances = np.arange(first, last + step / 2, step)

    names = {"truth": "truth (simulator)", "avgs": "AV-GS", "no-context": "AV-GS --no-context"}
    names.update({b: b for b in args.baselines})
    for s in args.settings:
        names.setdefault(s, s)
    scenes = {"distance": RIRScene(args.distance_scene), "wall": RIRScene(args.wall_scene)}
    ckpts = {}  # every checkpoint found (and its run finished) before any work
    for key, scene in scenes.items():
        names[f"{key}_scene"] = scene.name
        for setting in args.settings:
            ckpts[f"{setting}@{scene.name}"] = finished_checkpoint(args.runs, scene.name, setting, args.seed)
            names[f"{setting}@{scene.name}"] = f"{names[setting]} ({scene.name})"

    results = {}
    for key, scene in scenes.items():
        yaws = [float(y) for y in (args.yaws if args.yaws is not None else scene.orientations)]
        meta = scene.metadata["rir"]
        receivers = np.asarray(meta["receivers_world"], dtype=np.float64)
        z = float(np.mean(np.asarray(meta["sources_world"], dtype=np.float64)[:, 2]))
        spec = load_spec(scene.scene_dir)
        if key == "distance":
            geometry = source_line(spec, receivers, z, distances)
            sources, listener = geometry.sources, geometry.listener
        else:
            train = np.unique(scene.responses("train").source_index)
            geometry = wall_pair(spec, receivers, z, args.wall_distance,
                                 np.asarray(meta["sources_world"], dtype=np.float64)[train])
            sources, listener = np.stack([geometry.same_room, geometry.behind]), geometry.listener
        print(f"{scene.name}: listener {listener.round(3).tolist()}, {len(sources)} sources; simulating ...",
              flush=True)
        levels = {"truth": level_db(simulated(scene.scene_dir, sources, listener, yaws))}
        for setting in args.settings:
            levels[setting] = level_db(predicted(SceneRenderer.load(ckpts[f"{setting}@{scene.name}"]), sources,
                                                 listener, yaws))
        if key == "distance":
            train = scene.responses("train")
            names["closest_pair"] = float(np.min(np.linalg.norm(scene.frame.to_world(train.source)
                                                                - scene.frame.to_world(train.receiver), axis=1)))
        for b in args.baselines:
            levels[b] = level_db(interpolated(b, scene, sources, listener, yaws))
        for k, v in levels.items():
            print(f"  {names[k]:>22}: " + " ".join(f"{x:7.2f}" for x in v))
        results[key] = (geometry, levels, yaws)

    line, dist_levels, yaws = results["distance"]
    wall, wall_levels, _ = results["wall"]
    for m in dist_levels:
        if m != "truth":
            plain, centred = max_errors(dist_levels[m], dist_levels["truth"])
            print(f"distance, {names[m]}: max |pred - truth| {plain:.2f} dB, {centred:.2f} dB after the mean offset")
    for k, (s, h) in wall_levels.items():
        print(f"wall, {names[k]}: behind minus same room {h - s:+.2f} dB")
    draw(figure, line, dist_levels, wall, wall_levels, names)
    write_text(table_path, table(command, ckpts, line, dist_levels, wall, wall_levels, names, yaws, figure))
    print(f"wrote {figure} and {table_path}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except (FileNotFoundError, ValueError) as exc:  # a missing run or scene, a bad option: one line, no traceback
        print(f"rir_level_distance: {exc}", file=sys.stderr)
        sys.exit(1)
