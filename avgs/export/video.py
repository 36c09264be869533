"""An MP4 written frame by frame through PyAV: H.264 (libx264 when PyAV's FFmpeg has it, else
MPEG-4 part 2) at a constant frame rate, and stereo AAC at the scene's sample rate."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

AAC_FRAME = 1024
"Samples per AAC frame."


def video_codec() -> str:
    """``libx264`` if this PyAV's FFmpeg has it, else ``mpeg4``."""
    import av

    return "libx264" if "libx264" in av.codecs_available else "mpeg4"


class VideoWriter:
    """``add_frame`` RGB pictures ``[H, W, 3]`` uint8 and ``add_audio`` ``[2, n]`` float32 in time
    order (interleaved as they come), then ``close``. ``path`` is written in place: give a temporary
    file (:func:`avgs.io.atomic.atomic_path`)."""

    def __init__(self, path: str | Path, width: int, height: int, fps: Fraction, sample_rate: int,
                 audio_bitrate: int = 160_000):
        import av

        self.codec = video_codec()
        self.fps = Fraction(fps).limit_denominator(1001)
        self.sample_rate = int(sample_rate)
        self.container = av.open(str(path), mode="w", format="mp4")
        self.video = self.container.add_stream(self.codec, rate=self.fps)
        self.video.width, self.video.height, self.video.pix_fmt = int(width), int(height), "yuv420p"
        if self.codec == "libx264":
            self.video.options = {"crf": "20", "preset": "veryfast"}
        else:
            self.video.bit_rate = 4_000_000
        self.audio = self.container.add_stream("aac", rate=self.sample_rate, layout="stereo")
        self.audio.bit_rate = int(audio_bitrate)
        self._pending = np.zeros((2, 0), dtype=np.float32)  # audio not yet in a whole AAC frame
        self.frames = 0
        self.samples = 0

    @property
    def queued(self) -> int:
        """Audio samples per channel given so far (encoded or waiting for a whole AAC frame)."""
        return self.samples + self._pending.shape[1]

    def add_frame(self, rgb: np.ndarray) -> None:
        import av

        rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
        if rgb.shape != (self.video.height, self.video.width, 3):
            raise ValueError(f"a video frame must be [{self.video.height}, {self.video.width}, 3] uint8, got {rgb.shape}")
        frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
        frame.pts = self.frames  # in 1 / fps, the encoder's time base
        self.frames += 1
        self.container.mux(self.video.encode(frame))

    def add_audio(self, samples: np.ndarray) -> None:
        samples = np.asarray(samples, dtype=np.float32)
        if samples.ndim != 2 or samples.shape[0] != 2:
            raise ValueError(f"audio must be [2, n], got shape {samples.shape}")
        self._pending = np.concatenate([self._pending, samples], axis=1)
        whole = self._pending.shape[1] // AAC_FRAME * AAC_FRAME
        for i in range(0, whole, AAC_FRAME):
            self._encode_audio(self._pending[:, i : i + AAC_FRAME])
        self._pending = self._pending[:, whole:]

    def _encode_audio(self, chunk: np.ndarray) -> None:
        import av

        frame = av.AudioFrame.from_ndarray(np.ascontiguousarray(chunk), format="fltp", layout="stereo")
        frame.sample_rate, frame.pts = self.sample_rate, self.samples  # in 1 / sample_rate
        self.samples += chunk.shape[1]
        self.container.mux(self.audio.encode(frame))

    def close(self) -> None:
        """Encode what is left (the last, shorter audio frame), flush both encoders and finish the file."""
        try:
            if self._pending.shape[1]:
                self._encode_audio(self._pending)
                self._pending = np.zeros((2, 0), dtype=np.float32)
            self.container.mux(self.video.encode(None))
            self.container.mux(self.audio.encode(None))
        finally:
            self.container.close()
