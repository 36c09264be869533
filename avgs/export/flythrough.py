"""A listener path (:mod:`avgs.export.flypath`) into an MP4: what the listener hears and a picture.

The sound is the renderer's own stream (:meth:`~avgs.render.renderer.SceneRenderer.stream`: the
explorer's block convolution for the impulse-response task, the configured synthesis for the
binaural task) of the mono clip looped over the path, its pose moved every
:attr:`FlythroughConfig.audio_block` samples to the path's pose at the block's middle
(:meth:`~avgs.render.renderer.SceneRenderer.move_stream`, crossfaded: no clicks). Video frame
``i`` shows the pose at ``i / fps``, drawn by a ``frames(pose, heard)`` callable given the pose and
the :class:`~avgs.render.renderer.RenderResult` of the audio block playing then (its vicinity
sets): :func:`listener_frames` draws G from the listener's head; the explorer draws its 3D view
(``avgs_viewer.flythrough``). The track is scaled down only if it would clip.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from avgs.export.flypath import Keyframe, PathPose, check_keyframes, duration, pose_at
from avgs.export.video import VideoWriter
from avgs.io import atomic

Frames = Callable[[PathPose, object], np.ndarray]
"``frames(pose, heard)`` -> RGB ``[H, W, 3]`` uint8 of a pose (``heard``: the RenderResult playing then)."
Progress = Callable[[int, int], object]
"``progress(done, total)``; it may raise :class:`Cancelled` to stop (nothing is left written)."


class Cancelled(Exception):
    """Raised by a progress callback to stop an export."""


@dataclass(frozen=True)
class FlythroughConfig:
    fps: float = 30.0
    "Video frames per second."
    width: int = 640
    "Picture width, pixels (even: H.264's 4:2:0)."
    height: int = 480
    "Picture height, pixels (even)."
    audio_block: int = 1024
    "Samples between two pose moves of the sound (46 ms at 22050 Hz)."


@dataclass(frozen=True)
class FlythroughResult:
    path: Path
    frames: int  # video frames written
    samples: int  # audio samples per channel written
    codec: str  # the video codec used
    gain: float  # what the track was scaled by (1.0 unless it would have clipped)


def check_config(cfg: FlythroughConfig) -> FlythroughConfig:
    """``cfg`` checked: one ValueError naming the value and what is allowed."""
    if not (isinstance(cfg.fps, (int, float)) and math.isfinite(cfg.fps) and 1 <= cfg.fps <= 120):
        raise ValueError(f"fps must be a number from 1 to 120, got {cfg.fps!r}")
    for name in ("width", "height"):
        v = getattr(cfg, name)
        if not (isinstance(v, int) and 16 <= v <= 8192 and v % 2 == 0):
            raise ValueError(f"video {name} must be an even whole number of pixels from 16 to 8192, got {v!r}")
    if not (isinstance(cfg.audio_block, int) and 16 <= cfg.audio_block <= 1 << 16):
        raise ValueError(f"audio_block must be a whole number of samples from 16 to 65536, got {cfg.audio_block!r}")
    return cfg


def listener_frames(view, width: int, height: int) -> Frames:
    """Frames of G seen from the listener's head (:class:`~avgs.render.listener_view.ListenerView`)."""
    return lambda pose, heard: view.render(pose.listener, pose.yaw, width, height)


def binaural_track(renderer, keyframes: list[Keyframe], mono: np.ndarray, block: int,
                   progress: Progress | None = None) -> tuple[np.ndarray, list]:
    """The path's sound ``[2, T]`` float32 (T = the path's duration in samples) and the
    RenderResult of each audio block (without its impulse response)."""
    sr = renderer.sample_rate
    total = int(round(duration(keyframes) * sr))
    x = np.asarray(mono, dtype=np.float32).reshape(-1)
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError("the clip must hold at least one sample, all finite")
    x = np.resize(x, total)  # the clip looped over the path
    n_blocks = -(-total // block)

    def pose(k: int) -> PathPose:
        return pose_at(keyframes, (k * block + min(block, total - k * block) / 2.0) / sr)

    out, heard = [], []
    with warnings.catch_warnings(record=True) as caught:  # one line per kind, not one per block
        warnings.simplefilter("always")
        first = pose(0)
        stream = renderer.stream(first.listener, first.yaw, first.source)
        for k in range(n_blocks):
            p = pose(k)
            result = renderer.move_stream(stream, p.listener, p.yaw, p.source)  # from this block on, crossfaded
            heard.append(dataclasses.replace(result, impulse=None))
            out.append(stream.process(x[k * block : (k + 1) * block]))
            if progress is not None:
                progress(k + 1, n_blocks)
        out.append(stream.flush())
    _summarise(caught)
    return np.concatenate(out, axis=1)[:, :total].astype(np.float32), heard


def _summarise(caught: list) -> None:
    """Warn once per category of ``caught``: its first message and how many more there were."""
    by_kind: dict = {}
    for w in caught:
        by_kind.setdefault(w.category, []).append(str(w.message))
    for category, messages in by_kind.items():
        more = f" (and {len(messages) - 1} more along the path)" if len(messages) > 1 else ""
        warnings.warn(messages[0] + more, category, stacklevel=3)


def render_flythrough(renderer, keyframes, mono: np.ndarray, out: str | Path, frames: Frames,
                      config: FlythroughConfig = FlythroughConfig(), progress: Progress | None = None,
                      inputs=()) -> FlythroughResult:
    """Write the MP4 of ``keyframes`` (a list of :class:`Keyframe` or their dicts) heard through
    ``renderer`` (a :class:`~avgs.render.renderer.SceneRenderer`) with the clip ``mono`` looped;
    ``frames`` draws each picture. ``progress(done, total)`` counts audio blocks then video frames."""
    out = Path(out)
    if out.suffix.lower() != ".mp4":
        raise ValueError(f"a fly-through video must be written to a .mp4 file, got {out}")
    cfg = check_config(config)
    keyframes = check_keyframes(keyframes)
    atomic.check_output(out, inputs=inputs, what="video output")
    sr = renderer.sample_rate
    n_video = max(1, int(round(duration(keyframes) * cfg.fps)))
    n_blocks = -(-int(round(duration(keyframes) * sr)) // cfg.audio_block)
    steps = n_blocks + n_video
    track, heard = binaural_track(renderer, keyframes, mono, cfg.audio_block,
                                  None if progress is None else (lambda d, t: progress(d, steps)))
    top = float(np.abs(track).max()) if track.size else 0.0
    gain = 1.0 if top <= 0.99 else 0.99 / top
    track *= np.float32(gain)
    fps = Fraction(cfg.fps).limit_denominator(1001)
    with atomic.atomic_path(out) as tmp:
        writer = VideoWriter(tmp, cfg.width, cfg.height, fps, sr)
        try:
            for i in range(n_video):
                t = i / float(fps)
                block = min(int(t * sr) // cfg.audio_block, len(heard) - 1)
                writer.add_frame(frames(pose_at(keyframes, t), heard[block]))
                upto = min(track.shape[1], int(round((i + 1) / float(fps) * sr)))  # audio up to the next frame
                writer.add_audio(track[:, writer.queued : upto])
                if progress is not None:
                    progress(n_blocks + i + 1, steps)
            writer.add_audio(track[:, writer.queued :])
        finally:
            writer.close()
        codec, n_frames, n_samples = writer.codec, writer.frames, writer.samples
    return FlythroughResult(out, n_frames, n_samples, codec, gain)


def tqdm_progress(desc: str) -> tuple[Progress, Callable[[], None]]:
    """A tqdm bar as a progress callback, and a function closing it."""
    from tqdm import tqdm

    bar = tqdm(total=1, desc=desc, unit="step", dynamic_ncols=True)

    def update(done: int, total: int) -> None:
        if bar.total != total:
            bar.total = total
        bar.n = done
        bar.refresh()

    return update, bar.close
