"""``avgs render scene.ckpt --listener X Y Z --yaw DEG --input mono.wav --output out.wav [--source X Y Z]``:
binauralise a mono (or down-mixed stereo) WAV for one listener pose, world coordinates.

With a checkpoint of the impulse-response task (``avgs train --task rir``) ``--source`` puts
the source anywhere: the input is convolved with the predicted binaural response. With a
one-source (binaural task) checkpoint a moved source changes only its direction, and the
command says so."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from avgs.commands.flags import field_help
from avgs.config import MID_PHASE_ITERATIONS, SynthesisConfig

if TYPE_CHECKING:
    import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", metavar="scene.ckpt", help="Checkpoint written by 'avgs train'.")
    parser.add_argument("--listener", nargs=3, type=float, required=True, metavar=("X", "Y", "Z"), help="Listener position, world.")
    parser.add_argument("--yaw", type=float, required=True, metavar="DEG", help="Listener facing, degrees ccw from +x.")
    parser.add_argument("--source", nargs=3, type=float, metavar=("X", "Y", "Z"),
                        help="Move the source (world; default: the trained one). A checkpoint of --task rir renders the "
                             "source there; a one-source checkpoint changes only the direction it is heard from.")
    parser.add_argument("--input", required=True, metavar="mono.wav", help="Input audio, any length; stereo is down-mixed.")
    parser.add_argument("--output", required=True, metavar="out.wav", help="Binaural output, 2 channels: .wav (32-bit float), .flac, .ogg or .mp3 by its "
                             "extension (a clip beyond full scale is scaled down to fit all but .wav, with a warning).")
    parser.add_argument("--device", default="cpu", help="Torch device (cpu or cuda).")
    add_synthesis_flags(parser)


def add_synthesis_flags(parser: argparse.ArgumentParser, prefix: str = "") -> None:
    """``--synthesis``, ``--phase`` and ``--phase-iterations``: the fields of :class:`SynthesisConfig`."""
    d = SynthesisConfig()
    parser.add_argument("--synthesis", choices=("filter", "spectrogram"), default=d.method,
                        help=prefix + field_help(SynthesisConfig, "method") + f" Default {d.method}.")
    parser.add_argument("--phase", choices=("mid", "filter", "source"), default=d.phase,
                        help=prefix + field_help(SynthesisConfig, "phase") + f" Default {d.phase}.")
    parser.add_argument("--phase-iterations", type=int, metavar="N", default=None,
                        help=prefix + "With method spectrogram: fast Griffin-Lim iterations. "
                        f"Default {MID_PHASE_ITERATIONS} for mid, 0 for the others.")


def synthesis_of(args: argparse.Namespace) -> SynthesisConfig:
    """The :class:`SynthesisConfig` of ``--synthesis``, ``--phase`` and ``--phase-iterations``."""
    if args.phase_iterations is not None and args.phase_iterations < 0:
        raise ValueError(f"--phase-iterations must be >= 0, got {args.phase_iterations}")
    return SynthesisConfig(method=args.synthesis, phase=args.phase, phase_iterations=args.phase_iterations)


WHOLE_SECONDS = 60.0
"Inputs up to this long render in one piece (twice as fast); longer ones block by block (avgs.render.chunked)."


def run(args: argparse.Namespace) -> int:
    from avgs.io.atomic import audio_format, check_output, write_audio
    from avgs.io.audio_input import read_mono
    from avgs.render.renderer import SceneRenderer

    check_output(args.output, inputs=[args.checkpoint, args.input], what="--output")
    fmt, subtype = audio_format(args.output, "--output")
    renderer = SceneRenderer.load(args.checkpoint, device=args.device, synthesis=synthesis_of(args))
    mono = read_mono(args.input, renderer.sample_rate)
    if len(mono) > WHOLE_SECONDS * renderer.sample_rate:  # in blocks: memory that does not grow with the clip
        from avgs.render.chunked import render_to_file

        out, n = render_to_file(renderer, args.output, args.listener, args.yaw, mono, source=args.source,
                                format=fmt, subtype=subtype)
    else:
        out = renderer.render(args.listener, args.yaw, mono, source=args.source)
        n = out.binaural.shape[1]
        write_audio(args.output, fit_format(out.binaural, subtype, args.output), renderer.sample_rate, fmt, subtype)
    side = "left" if out.theta > 0 else "right" if out.theta < 0 else "ahead"
    how = "; the predicted response of this source position" if renderer.source_aware else ""
    print(f"wrote {args.output} ({n} samples, source {abs(out.theta):.0f} deg to the {side}{how})")
    return 0


def fit_format(audio, subtype: str, path) -> "np.ndarray":
    """``audio [2, T]`` as it goes into a file of ``subtype``: unchanged for float samples, else scaled
    down to full scale when it peaks beyond it (a warning says by how much), so that nothing clips."""
    import warnings

    import numpy as np

    audio = np.asarray(audio, dtype=np.float32)
    peak = float(np.max(np.abs(audio))) if audio.size else 0.0
    if subtype in ("FLOAT", "DOUBLE") or peak <= 1.0:
        return audio
    warnings.warn(f"{path}: the render peaks at {20 * np.log10(peak):+.1f} dBFS; scaled down by that much to fit "
                  f"{subtype} (write a .wav to keep the level)", stacklevel=2)
    return audio / np.float32(peak)
