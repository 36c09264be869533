"""``avgs render scene.ckpt --listener X Y Z --yaw DEG --input mono.wav --output out.wav``:
binauralise a mono (or down-mixed stereo) WAV for one listener pose, world coordinates."""

from __future__ import annotations

import argparse
from pathlib import Path

from avgs.commands.flags import field_help
from avgs.config import SynthesisConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", metavar="scene.ckpt", help="Checkpoint written by 'avgs train'.")
    parser.add_argument("--listener", nargs=3, type=float, required=True, metavar=("X", "Y", "Z"), help="Listener position, world.")
    parser.add_argument("--yaw", type=float, required=True, metavar="DEG", help="Listener facing, degrees ccw from +x.")
    parser.add_argument("--source", nargs=3, type=float, metavar=("X", "Y", "Z"), help="Move the source (world; default: the trained one).")
    parser.add_argument("--input", required=True, metavar="mono.wav", help="Input audio, any length; stereo is down-mixed.")
    parser.add_argument("--output", required=True, metavar="out.wav", help="Binaural output (2 channels, float WAV).")
    parser.add_argument("--device", default="cpu", help="Torch device (cpu or cuda).")
    parser.add_argument("--phase-iterations", type=int, metavar="N",
                        help=field_help(SynthesisConfig, "phase_iterations") + f" Default {SynthesisConfig.phase_iterations}.")


def read_mono(path: str | Path, sample_rate: int):
    """``path`` as float32 mono at ``sample_rate`` (down-mixed, resampled with resample_poly)."""
    from math import gcd

    import numpy as np
    import soundfile as sf
    from scipy.signal import resample_poly

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: input audio not found")
    try:
        x, sr = sf.read(path, dtype="float32", always_2d=True)  # [T, C]
    except Exception as exc:
        raise ValueError(f"{path}: not a readable audio file ({exc})") from None
    if x.shape[0] == 0:
        raise ValueError(f"{path}: holds no samples")
    x = x.mean(axis=1)  # [T]
    if sr != sample_rate:
        g = gcd(int(sr), int(sample_rate))
        x = resample_poly(x, sample_rate // g, int(sr) // g).astype(np.float32)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{path}: holds NaN or Inf samples")
    return x


def synthesis_of(args: argparse.Namespace) -> SynthesisConfig:
    """The :class:`SynthesisConfig` that ``--phase-iterations`` asks for (defaults otherwise)."""
    if args.phase_iterations is None:
        return SynthesisConfig()
    if args.phase_iterations < 0:
        raise ValueError(f"--phase-iterations must be >= 0, got {args.phase_iterations}")
    return SynthesisConfig(phase_iterations=args.phase_iterations)


def run(args: argparse.Namespace) -> int:
    from avgs.atomic import write_wav
    from avgs.inference import SceneRenderer

    renderer = SceneRenderer.load(args.checkpoint, device=args.device, synthesis=synthesis_of(args))
    mono = read_mono(args.input, renderer.sample_rate)
    out = renderer.render(args.listener, args.yaw, mono, source=args.source)
    write_wav(args.output, out.binaural, renderer.sample_rate)
    side = "left" if out.theta > 0 else "right" if out.theta < 0 else "ahead"
    print(f"wrote {args.output} ({out.binaural.shape[1]} samples, source {abs(out.theta):.0f} deg to the {side})")
    return 0
