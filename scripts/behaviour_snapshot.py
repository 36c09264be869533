"""A behaviour snapshot: renders, filters, streams, maps, predictions, training and eval of both
tasks, saved as arrays, so that a refactor can be shown to change nothing (bit for bit).

    PYTHONPATH=OLD_CHECKOUT .venv/bin/python scripts/behaviour_snapshot.py capture /tmp/before
    .venv/bin/python scripts/behaviour_snapshot.py capture /tmp/after
    .venv/bin/python scripts/behaviour_snapshot.py compare /tmp/before /tmp/after

``capture`` trains a one-source model (120 stage-2 iterations on tests/rwavs_writer's scene) and
an impulse-response model (60 iterations on a --quick RIR scene), then records their weights,
final metrics, renders of four poses in every synthesis, filters, masks, streams, fast and exact
propagation maps, predicted responses and ``avgs eval`` of both tasks; the same for the bundled
demo. About 20 s on one core. It runs on checkouts from before the task seam too (their import
paths are tried second). ``compare`` lists every array that differs (a field a newer version no
longer fills, None, is reported as such). What it showed: benchmarks/task_seam.md.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def capture(out: Path) -> None:
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    out.mkdir(parents=True, exist_ok=True)
    import avgs
    try:
        from avgs.render.propagation_map import compute_map
    except ImportError:
        from avgs.propagation_map import compute_map
    from avgs.config import SynthesisConfig
    res = {}
    def put(k, a):
        res[k] = np.asarray(a)

    def renderer_checks(tag, r, moved_source):
        rng = np.random.default_rng(0)
        mono = rng.standard_normal(22050).astype(np.float32) * 0.3
        lo, hi = r.bounds
        poses = [(lo + (hi - lo) * f, yaw) for f, yaw in ((0.3, 0.0), (0.7, 90.0), (0.5, 200.0), (1.3, 45.0))]
        for i, (p, yaw) in enumerate(poses):
            o = r.render(p, yaw, mono, magnitudes=True)
            put(f"{tag}/render{i}", o.binaural); put(f"{tag}/mags{i}", o.magnitudes)
            put(f"{tag}/mix{i}", o.mixture); put(f"{tag}/diff{i}", o.difference)
            put(f"{tag}/lv{i}", o.listener_vicinity); put(f"{tag}/sv{i}", o.source_vicinity); put(f"{tag}/theta{i}", o.theta)
            if o.reverb is not None: put(f"{tag}/rev{i}", o.reverb)
            f = r.binaural_filter(p, yaw)
            put(f"{tag}/filter{i}", f.impulse)
            m = r.masks(p, yaw, source=moved_source)
            put(f"{tag}/mmix{i}", m.mixture); put(f"{tag}/mdiff{i}", m.difference)
            for syn in (SynthesisConfig(method="filter"), SynthesisConfig(phase="filter"), SynthesisConfig(phase="source")):
                o = r.render(p, yaw, mono, synthesis=syn)
                put(f"{tag}/render{i}_{syn.method}_{syn.phase}", o.binaural)
            s = r.stream(p, yaw)
            blocks = [s.process(mono[j:j + 1000]) for j in range(0, len(mono), 1000)] + [s.flush()]
            put(f"{tag}/stream{i}", np.concatenate(blocks, axis=1))
        o = r.render(poses[0][0], 30.0, mono, source=moved_source)
        put(f"{tag}/moved", o.binaural)
        pm = compute_map(r, yaw=30.0, size=12)
        put(f"{tag}/map_level", pm.level); put(f"{tag}/map_ild", pm.ild)
        pm = compute_map(r, yaw=30.0, size=12, exact=True)
        put(f"{tag}/mapx_level", pm.level); put(f"{tag}/mapx_ild", pm.ild)
        put(f"{tag}/reach", r.reach_frames())
        put(f"{tag}/source_aware", r.source_aware)

    # 1. the demo checkpoint (rir task)
    r = avgs.SceneRenderer.load(str(ROOT / "assets" / "demo" / "scene.ckpt"))
    renderer_checks("demo", r, r.bounds.mean(0))
    src = r.frame.to_normalised(np.array([[2.0, 2.0, 1.5], [4.0, 3.0, 1.2]]))
    rec = r.frame.to_normalised(np.array([[3.0, 1.0, 1.5], [1.0, 2.5, 1.6]]))
    put("demo/predict", r.predict_responses(src, rec, [10.0, 250.0]))

    # 2. a one-source training (binaural task) + its renders
    from avgs.acoustics.points import AudioPoints
    from avgs.train.pipeline import quick_config, train_scene
    from rwavs_writer import write_scene as write_rwavs
    root = out / "scene_b"
    if not (root / "position.json").exists():
        write_rwavs(root, n_train=32, n_val=4, seed=1)
    scene_dir = next(p for p in root.iterdir() if p.is_dir())
    cfg = quick_config()
    cfg.acoustic.iterations, cfg.acoustic.binauralizer_width = 120, 64
    cfg.points.densify_every, cfg.points.prune_every = 40, 100
    cfg.eval_every = cfg.checkpoint_every = 60
    cfg.log_every = 30
    g = torch.Generator().manual_seed(0)
    points = AudioPoints(torch.rand(600, 3, generator=g) * 2 - 1, torch.randn(600, 52, generator=g))
    ck = out / "b.ckpt"
    for f in out.glob("b.*"): f.unlink()
    final = train_scene(scene_dir, ck, cfg, progress=False, initial_points=points)
    res["b/final"] = np.array(json.dumps(final, sort_keys=True))
    sd = torch.load(ck, weights_only=True)
    for k in ("field", "binauralizer"):
        for n, t in sd[k].items(): put(f"b/w/{k}/{n}", t.numpy())
    put("b/X", sd["audio_points"]["X"].numpy())
    rb = avgs.SceneRenderer.load(ck)
    renderer_checks("b", rb, rb.bounds.mean(0))

    # 3. tiny RIR training
    from avgs.cli import main
    rroot = out / "rir_root"
    if not (rroot / "quick_rect").exists():
        assert main(["synth", str(rroot), "--task", "rir", "--quick", "--scene-id", "quick_rect", "--workers", "1", "--no-progress"]) == 0
    try:
        from avgs.train.rir import train_rir
    except ImportError:
        def train_rir(*a, **k):
            return train_scene(*a, task="rir", **k)
    cfg = quick_config(); cfg.acoustic.iterations = 60; cfg.eval_every = cfg.checkpoint_every = 30; cfg.init = "sfm"
    cfg.rir.eval_responses = 8
    rk = out / "r.ckpt"
    for f in out.glob("r.*"): f.unlink()
    final = train_rir(rroot / "quick_rect", rk, cfg, progress=False)
    res["r/final"] = np.array(json.dumps(final, sort_keys=True))
    sd = torch.load(rk, weights_only=True)
    for k in ("field", "binauralizer"):
        for n, t in sd[k].items(): put(f"r/w/{k}/{n}", t.numpy())
    rr = avgs.SceneRenderer.load(rk)
    renderer_checks("r", rr, rr.bounds.mean(0) * 0.9)

    # 4. eval JSON both tasks
    for name, argv in (("eval_b", ["eval", str(root), "--method", "stereo-energy", "--method", f"ckpt:{ck}", "--json", str(out / "eval_b.json"), "--no-progress"]),
                       ("eval_r", ["eval", str(rroot), "--task", "rir", "--split", "both", "--json", str(out / "eval_r.json"), "--no-progress",
                                   "--method", "nearest", "--method", f"ckpt:{rk}"])):
        (out / f"{name}.json").unlink(missing_ok=True)
        assert main(argv) == 0
        res[name] = np.array((out / f"{name}.json").read_text())
    np.savez(out / "ref.npz", **res)
    print("captured", len(res))


def compare(a_dir: str, b_dir: str) -> int:
    """Print every array of two snapshots that differs; returns how many."""
    a = np.load(a_dir + "/ref.npz", allow_pickle=True)
    b = np.load(b_dir + "/ref.npz", allow_pickle=True)
    bad = 0
    for k in sorted(set(a) | set(b)):
        if k not in a or k not in b:
            print("missing", k, k in a, k in b)
            bad += 1
            continue
        x, y = a[k], b[k]
        if y.dtype == object and y.ndim == 0 and y.item() is None:
            print("now None", k)
            continue
        if x.dtype.kind in "US":
            if str(x).replace(a_dir, "X") != str(y).replace(b_dir, "X"):
                print("differs", k)
                bad += 1
            continue
        if x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
            d = np.nanmax(np.abs(x.astype(float) - y.astype(float))) if x.shape == y.shape else "shape"
            print("differs", k, d)
            bad += 1
    print(f"{len(a)} arrays, {bad} differ")
    return bad


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "capture":
        capture(Path(sys.argv[2]))
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(1 if compare(sys.argv[2], sys.argv[3]) else 0)
    else:
        sys.exit(__doc__)
