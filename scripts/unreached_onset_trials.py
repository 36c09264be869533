"""How well can the onset of a response behind walls be told at all? Three predictors of each response's
onset, scored on the truth of a multi-room scene (docs/results.md, "The simulator's phantom direct sound"):

1. **The position's own onset** (a ceiling, no model): the median onset of the same source and receiver
   over the listener's orientations. What is left is how much the onset moves with the head's yaw alone.
2. **A fitted lag**: distance / c plus the median lag after it of the training responses behind a wall
   (the truth's own classification: a predictor that knew which responses are behind one).
3. **The shortest path around the walls plus a fitted lag**: the geodesic from the source to the
   receiver on a 2D grid of the checkpoint's G_a points (cells of ``--cell`` m holding at least two points
   between 0.5 and 2.2 m of height are walls; 16 neighbours; the height difference added), plus the
   median of the training responses' lag after it (behind a wall, as above).

Each prints the median |onset error| in ms over the responses behind a wall (true onset more than
``avgs.evaluation.spatial.IN_SIGHT_S`` after distance / c) of the validation pairs and the held-out
sources.

    .venv/bin/python scripts/unreached_onset_trials.py data/rir/three_rooms runs/three_rooms.ckpt
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from avgs.data.rir import RIRScene, RIRSet
from avgs.evaluation import spatial
from avgs.io.checkpoint import load_checkpoint
from avgs.train.impulse_responses import speed_of_sound

BAND_M = (0.5, 2.2)
"Heights (world z, m) whose points make the grid's walls: a door's opening is free there."

STEPS = ((1, 0), (0, 1), (1, 1), (1, -1), (2, 1), (1, 2), (2, -1), (1, -2))
"The grid's moves (and their opposites): 16 neighbours, a path within about 3 % of the straight one."


class WallGrid:
    """A floor plan of occupied cells from points ``[P, 3]`` (world, m), and shortest paths on it."""

    def __init__(self, points: np.ndarray, cell: float):
        band = points[(points[:, 2] > BAND_M[0]) & (points[:, 2] < BAND_M[1]), :2]
        self.cell, self.lo = cell, band.min(0) - 2 * cell
        self.shape = tuple(np.ceil((band.max(0) + 2 * cell - self.lo) / cell).astype(int))
        count = np.zeros(self.shape, dtype=np.int64)
        ij = np.floor((band - self.lo) / cell).astype(int)
        np.add.at(count, (ij[:, 0], ij[:, 1]), 1)
        self.wall = count >= 2
        self.graph = self._graph()

    def _graph(self) -> csr_matrix:
        nx, ny = self.shape
        index = np.arange(nx * ny).reshape(self.shape)
        rows, cols, lengths = [], [], []
        for dx, dy in STEPS:
            x = np.arange(max(0, -dx), nx - max(0, dx))
            y = np.arange(max(0, -dy), ny - max(0, dy))
            X, Y = np.meshgrid(x, y, indexing="ij")
            ok = ~self.wall[X, Y] & ~self.wall[X + dx, Y + dy]
            if abs(dx) == 2 or abs(dy) == 2:  # a knight's move passes the cells between
                sx, sy = np.sign(dx), np.sign(dy)
                ok &= ~self.wall[X + sx, Y + sy] & (~self.wall[X + sx, Y] | ~self.wall[X, Y + sy])
            rows.append(index[X, Y][ok])
            cols.append(index[X + dx, Y + dy][ok])
            lengths.append(np.full(int(ok.sum()), self.cell * float(np.hypot(dx, dy))))
        n = nx * ny
        return csr_matrix((np.concatenate(lengths), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))

    def _cells(self, p: np.ndarray) -> np.ndarray:
        ij = np.clip(np.floor((p[:, :2] - self.lo) / self.cell).astype(int), 0, np.array(self.shape) - 1)
        return ij[:, 0] * self.shape[1] + ij[:, 1]

    def paths(self, source: np.ndarray, receivers: np.ndarray) -> np.ndarray:
        """The shortest free path (m) from ``source [3]`` to each of ``receivers [N, 3]``; inf: none."""
        far = dijkstra(self.graph, directed=False, indices=int(self._cells(source[None])[0]))
        return np.hypot(far[self._cells(receivers)], receivers[:, 2] - source[2])


def cues(scene: RIRScene, rows: RIRSet, speed: float) -> dict[str, np.ndarray]:
    """World positions, straight distance (m), onset (s) and whether it is behind a wall, per response."""
    src, rec = scene.frame.to_world(rows.source), scene.frame.to_world(rows.receiver)
    distance = np.linalg.norm(src - rec, axis=1)
    onset = np.array([spatial.onset(h) for h in rows.rir]) / scene.sample_rate
    return {"src": src, "rec": rec, "distance": distance, "onset": onset,
            "behind": ~spatial.in_sight(onset, distance, speed),
            "position": np.unique(np.concatenate([src, rec], 1).round(4), axis=0, return_inverse=True)[1].ravel()}


def geodesic(grid: WallGrid, c: dict[str, np.ndarray]) -> np.ndarray:
    out = np.empty(len(c["distance"]))
    for source in np.unique(c["src"], axis=0):
        rows = np.all(c["src"] == source, axis=1)
        out[rows] = grid.paths(source, c["rec"][rows])
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene")
    parser.add_argument("checkpoint", help="its G_a points make the walls of the shortest path")
    parser.add_argument("--cell", type=float, default=0.1, help="the grid's cell, m (default 0.1)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    scene = RIRScene(args.scene)
    speed = speed_of_sound(scene)
    frame = scene.frame
    grid = WallGrid(frame.to_world(load_checkpoint(args.checkpoint)["audio_points"]["X"].double().numpy()), args.cell)
    train = cues(scene, scene.responses("train"), speed)
    train_geo = geodesic(grid, train)
    behind = train["behind"] & np.isfinite(train_geo)
    lag = float(np.median(train["onset"][train["behind"]] - train["distance"][train["behind"]] / speed))
    geo_lag = float(np.median(train["onset"][behind] - train_geo[behind] / speed))
    print(f"{args.scene}: {int(train['behind'].sum())} of {len(train['onset'])} training responses behind a wall; "
          f"their median lag after distance / c {1e3 * lag:.2f} ms, after the shortest path {1e3 * geo_lag:.2f} ms")
    for split in ("val", "heldout"):
        c = cues(scene, scene.responses(split), speed)
        rows = c["behind"]
        if not rows.any():
            print(f"{split}: no response behind a wall")
            continue
        own = np.array([np.median(c["onset"][c["position"] == p]) for p in c["position"]])
        geo = geodesic(grid, c)
        errors = {"the position's own onset (ceiling)": own,
                  "distance / c (the straight line)": c["distance"] / speed,
                  "distance / c + the fitted lag": c["distance"] / speed + lag,
                  "shortest path / c + its fitted lag": geo / speed + geo_lag}
        print(f"{split}: {int(rows.sum())} of {len(rows)} responses behind a wall, median |onset error| ms:")
        for name, predicted in errors.items():
            print(f"  {name:38s} {1e3 * np.median(np.abs(predicted[rows] - c['onset'][rows])):6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
