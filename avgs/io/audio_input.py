"""Reading a user's audio file as the mono signal a scene binauralises.

One reader for ``avgs render`` and the explorer: any format libsndfile reads (WAV, FLAC,
OGG, ...), down-mixed to mono, resampled to the scene's rate with ``resample_poly``.
The header is checked before any sample is read: sample rates outside
[MIN_SAMPLE_RATE, MAX_SAMPLE_RATE] (a header declaring 1 Hz would be resampled to millions
of samples) and inputs longer than MAX_INPUT_SECONDS are refused, naming the file.
:func:`read_mono_noted` also says, in words, what it changed (a down-mix, a resampling, a cut).
"""

from __future__ import annotations

from math import gcd
from pathlib import Path

import numpy as np

MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 4000, 384000
"Input sample rates accepted (Hz)."
MAX_INPUT_SECONDS = 4 * 3600
"Longest input read (rendering runs in bounded memory; the signal itself must fit)."


def read_mono(path: str | Path, sample_rate: int, max_seconds: float | None = None) -> np.ndarray:
    """``path`` as float32 mono ``[T]`` at ``sample_rate``; ``max_seconds`` reads only the start."""
    return read_mono_noted(path, sample_rate, max_seconds)[0]


def read_mono_noted(path: str | Path, sample_rate: int, max_seconds: float | None = None
                    ) -> tuple[np.ndarray, list[str]]:
    """:func:`read_mono` and what it changed, in words: a note each for a down-mix, a resampling
    and a cut (``["down-mixed 2 channels to mono", "resampled 44100 Hz to 22050 Hz", ...]``)."""
    import soundfile as sf

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"audio file {path} does not exist")
    try:
        info = sf.info(str(path))
    except Exception as exc:  # soundfile raises its own LibsndfileError / RuntimeError
        raise ValueError(f"cannot read audio file {path}: {exc}") from None
    if not MIN_SAMPLE_RATE <= info.samplerate <= MAX_SAMPLE_RATE:
        raise ValueError(f"audio file {path}: sample rate {info.samplerate} Hz; expected {MIN_SAMPLE_RATE}-{MAX_SAMPLE_RATE} Hz")
    frames = info.frames if max_seconds is None else min(info.frames, int(np.ceil(max_seconds * info.samplerate)))
    if frames > MAX_INPUT_SECONDS * info.samplerate:
        raise ValueError(f"audio file {path}: {info.frames / info.samplerate:.0f} s long; at most {MAX_INPUT_SECONDS} s")
    try:
        x, sr = sf.read(str(path), frames=frames, dtype="float32", always_2d=True)  # [T, C]
    except Exception as exc:
        raise ValueError(f"cannot read audio file {path}: {exc}") from None
    if x.shape[0] == 0:
        raise ValueError(f"audio file {path} holds no samples")
    notes = []
    if x.shape[1] > 1:
        notes.append(f"down-mixed {x.shape[1]} channels to mono")
    if frames < info.frames:
        notes.append(f"cut to its first {max_seconds:g} s of {info.frames / info.samplerate:.1f} s")
    if sr != sample_rate:
        notes.append(f"resampled {sr} Hz to {sample_rate} Hz")
    x = x[:, 0] if x.shape[1] == 1 else x.mean(axis=1)  # [T]
    if sr != sample_rate:
        g = gcd(int(sr), int(sample_rate))
        from scipy.signal import resample_poly  # imported only here: scipy.signal costs a second or two

        x = resample_poly(x, sample_rate // g, int(sr) // g).astype(np.float32)
    if max_seconds is not None:
        x = x[: int(max_seconds * sample_rate)]
    if not np.all(np.isfinite(x)):
        raise ValueError(f"audio file {path} holds NaN or Inf samples")
    return np.ascontiguousarray(x, dtype=np.float32), notes
