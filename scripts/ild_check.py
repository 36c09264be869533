"""How well checkpoints place a source left or right: their interaural level difference
(ILD above 1.5 kHz, :func:`avgs.evaluation.metrics.ild`) against the ground truth.

Two sets of poses, neither seen in training:

- the scene's validation clips;
- ``--probes N`` random poses 0.7-2 m from the source at its height, in the walkable
  area, with random yaw, rendered afresh by the simulator that made the scene
  (:func:`avgs.synth.simulate.binaural_rirs`; generated scenes only), playing the
  first validation clip.

For each: the correlation of predicted with true ILD, the mean absolute error in dB,
and how often the louder ear is the right one.

    .venv/bin/python scripts/ild_check.py data/demo/demo_house assets/demo/scene.ckpt --probes 40
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.signal import fftconvolve

from avgs.evaluation import metrics
from avgs.data.rwavs import RWAVSScene
from avgs.evaluation.binaural import CheckpointMethod


def probe_poses(scene_dir: str, n: int, mono: np.ndarray, seed: int = 0):
    """Up to ``n`` (listener [3] world, yaw degrees, true binaural [2, T]) around the source."""
    from avgs.synth.poses import is_walkable
    from avgs.synth.simulate import binaural_rirs, load_spec, load_settings

    spec, settings = load_spec(scene_dir), load_settings(scene_dir)
    source = np.asarray(spec.source, dtype=np.float64)
    rng = np.random.default_rng(seed)
    poses = []
    for _ in range(n):
        angle, radius = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(0.7, 2.0)
        listener = source + np.array([radius * math.cos(angle), radius * math.sin(angle), 0.0])
        yaw = float(rng.uniform(-180.0, 180.0))
        if not is_walkable(spec, listener[:2]):
            continue
        try:
            rir = binaural_rirs(spec, listener, yaw, settings)  # [2, L]
        except ValueError:  # inside furniture
            continue
        truth = np.stack([fftconvolve(mono, rir[c])[: mono.size] for c in range(2)])
        poses.append((listener, yaw, truth))
    return poses


def summary(pred: np.ndarray, true: np.ndarray) -> str:
    corr = float(np.corrcoef(pred, true)[0, 1])
    error = float(np.mean(np.abs(pred - true)))
    side = 100.0 * float(np.mean(np.sign(pred) == np.sign(true)))
    return f"corr {corr:5.2f}  error {error:5.2f} dB  right side {side:3.0f} %  (n {pred.size}, true ILD std {true.std():.2f} dB)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", help="scene folder (RWAVS layout)")
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--probes", type=int, default=0, metavar="N", help="random poses to simulate (generated scenes)")
    args = parser.parse_args()

    scene = RWAVSScene(args.scene)
    clips = scene.clips("val")
    mono = clips[0].mono.astype(np.float64)
    probes = probe_poses(args.scene, args.probes, mono) if args.probes else []
    val_true = np.array([float(metrics.ild(c.binaural)) for c in clips])
    probe_true = np.array([float(metrics.ild(t)) for _, _, t in probes])
    for path in args.checkpoints:
        method = CheckpointMethod(path)  # as `avgs eval` renders a clip
        val_pred = np.array([float(metrics.ild(method(c, scene).binaural)) for c in clips])
        print(f"{path}\n  val clips  {summary(val_pred, val_true)}")
        if probes:
            probe_pred = np.array([
                float(metrics.ild(method.renderer.render(tuple(p), yaw, mono.astype(np.float32)).binaural))
                for p, yaw, _ in probes
            ])
            print(f"  probes     {summary(probe_pred, probe_true)}")


if __name__ == "__main__":
    main()
