"""What a scene's two recordings must show of each other: sound in every channel, and the
binaural track heard when the source played it (docs/design.md, "Data layout (RWAVS)").

- :func:`check_not_silent`: a WAV (or one of its channels) whose every sample is below
  :data:`SILENT_PEAK` is refused (ValueError naming the file). Real recordings have quiet
  stretches and a noise floor, never a whole track of digital zeros.
- :func:`source_lag`: the delay of the binaural track behind the source track, by GCC-PHAT
  on a few short segments; :func:`warn_if_out_of_sync` warns when it is clearly longer
  than sound takes to cross any room (:data:`MAX_ACOUSTIC_LAG_S`), e.g. a WAV shifted
  by 0.5 s against the other (and so against the poses). A warning, not an error: the
  estimate is statistical, and a real recording whose recorder started late looks the same.

The lag estimate, robust by construction rather than by tuned thresholds:

- Each segment (:data:`SEGMENT_S` of binaural, against the source around it, lags within
  :data:`SEARCH_S`) votes for the lag of its largest cross-correlation peak. Signals are
  decimated by :data:`DECIMATION` first (resolution 0.7 ms, far below what matters here).
- A segment whose source looks like a shifted copy of itself (a tone, a loop, clicks, a
  steady beat: its own correlation has a second peak at least half the main one) cannot
  tell one lag from another and does not vote; nor does one that is silent.
- A segment whose best peak lies beyond :data:`MAX_ACOUSTIC_LAG_S` votes for it only when
  the best peak within that range is less than half as high; otherwise it votes "in sync".
- The lag is reported when at least :data:`MIN_VOTES` segments voted and
  :data:`AGREEMENT` of them agree within :data:`LAG_SPREAD_S` on one lag beyond the range.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy.fft import irfft, next_fast_len, rfft
from scipy.signal import resample_poly

SILENT_PEAK = 2.0**-24
"""Largest |sample| of a track that counts as silent: below the smallest step of 24-bit
audio, so no recorder's noise floor is under it."""
MAX_ACOUSTIC_LAG_S = 0.25
"""Longest plausible delay of the binaural track behind the source: sound travels 86 m in
0.25 s, more than any room or the outdoor scenes of RWAVS span, with its early echoes."""
SEGMENT_S = 2.0
"Binaural seconds per voting segment."
SEARCH_S = 1.0
"Largest lag searched, either way (seconds)."
MAX_SEGMENTS = 16
"Most segments looked at (spread evenly over the recording): the check stays cheap."
DECIMATION = 4
"Both tracks are decimated this many times before correlating (22050 Hz -> 5.5 kHz)."
PHAT_BETA = 0.8
"Spectral whitening of the cross-spectrum (1 = full PHAT); 0.8 keeps empty bins from dominating."
MIN_VOTES, AGREEMENT, LAG_SPREAD_S = 3, 0.6, 0.05
"At least 3 segments must vote, and 60 % of them within 50 ms of one lag, for a lag to be reported."
AMBIGUOUS = 0.5
"A second peak at least this fraction of the main one makes a segment's vote ambiguous."

CHANNEL_NAMES = {2: ("left", "right")}


def check_not_silent(path: Path, audio: np.ndarray) -> None:
    """ValueError naming ``path`` when ``audio [C, T]`` (or one channel of it) is all silence."""
    if audio.shape[-1] == 0:
        raise ValueError(f"{path}: holds no samples; expected a recording")
    # An error: a real recording has a noise floor even in its quietest stretch; a whole track
    # (or ear) of digital zeros is a file that was never written with sound.
    peaks = np.max(np.abs(audio), axis=-1)  # [C]
    if float(np.max(peaks)) < SILENT_PEAK:
        raise ValueError(
            f"{path}: every sample is silent (peak {float(np.max(peaks)):.3g}, {audio.shape[-1]} samples); "
            "expected a recording, which is never all digital zeros"
        )
    names = CHANNEL_NAMES.get(audio.shape[0], tuple(str(i) for i in range(audio.shape[0])))
    for c, peak in enumerate(peaks):
        if float(peak) < SILENT_PEAK:
            raise ValueError(
                f"{path}: channel {c} ({names[c]}) is silent (peak {float(peak):.3g}) while the other is not; "
                "expected sound in every channel"
            )


def _segment_starts(length: int, seg: int, search: int) -> list[int]:
    usable = length - seg - 2 * search
    if usable < 0:
        return []
    count = int(min(MAX_SEGMENTS, max(MIN_VOTES, usable // seg + 1)))
    return sorted({int(s) for s in np.linspace(search, search + usable, count)})


def _vote(mono: np.ndarray, binaural: np.ndarray, start: int, seg: int, search: int, sr: int) -> float | None:
    """This segment's lag in seconds (0.0 = in sync), or None when it cannot tell."""
    b = binaural[:, start : start + seg].astype(np.float64).sum(axis=0)  # [seg] both ears
    m = mono[start - search : start + seg + search].astype(np.float64)  # [seg + 2 search]
    if not (np.max(np.abs(b)) >= SILENT_PEAK and np.max(np.abs(m)) >= SILENT_PEAK):
        return None
    b, m = resample_poly(b, 1, DECIMATION), resample_poly(m, 1, DECIMATION)
    n, lags = len(b), search // DECIMATION
    n_fft = next_fast_len(2 * n + 2 * lags)
    conj_m = np.conj(rfft(m, n_fft))
    index = (np.arange(-lags, lags + 1) - lags) % n_fft  # lag l (binaural behind source) -> circular index
    seconds = np.arange(-lags, lags + 1) * DECIMATION / sr  # [2 lags + 1]

    def correlation(x: np.ndarray) -> np.ndarray:
        spectrum = rfft(x, n_fft) * conj_m
        weight = np.abs(spectrum)
        spectrum = spectrum / (weight + 1e-12 * float(np.max(weight)) + 1e-300) ** PHAT_BETA
        return np.abs(irfft(spectrum, n_fft)[index])  # [2 lags + 1]

    own = correlation(m[lags : lags + n])  # the source against itself: one peak at 0 unless it repeats
    if float(np.max(own[np.abs(seconds) > LAG_SPREAD_S])) >= AMBIGUOUS * float(np.max(own)):
        return None
    cross = correlation(b)
    best = int(np.argmax(cross))
    if abs(seconds[best]) <= MAX_ACOUSTIC_LAG_S:
        return 0.0
    within = float(np.max(cross[np.abs(seconds) <= MAX_ACOUSTIC_LAG_S]))
    return float(seconds[best]) if within < AMBIGUOUS * float(cross[best]) else 0.0


def source_lag(mono: np.ndarray, binaural: np.ndarray, sample_rate: int) -> float | None:
    """Seconds the binaural track ``[2, T]`` lags the source ``[T]`` by when that is clearly
    beyond :data:`MAX_ACOUSTIC_LAG_S` (negative: it leads), else None (in sync, or too
    little evidence: a short, silent or repetitive recording)."""
    seg, search = int(SEGMENT_S * sample_rate), int(SEARCH_S * sample_rate)
    length = min(mono.shape[-1], binaural.shape[-1])
    votes = [_vote(mono, binaural, s, seg, search, sample_rate) for s in _segment_starts(length, seg, search)]
    lags = np.array([v for v in votes if v is not None])
    if len(lags) < MIN_VOTES:
        return None
    middle = float(np.median(lags))
    agree = float(np.mean(np.abs(lags - middle) <= LAG_SPREAD_S))
    return middle if abs(middle) > MAX_ACOUSTIC_LAG_S and agree >= AGREEMENT else None


def warn_if_out_of_sync(binaural_path: Path, source_path: Path, mono: np.ndarray, binaural: np.ndarray, sample_rate: int) -> None:
    """A one-line warning when :func:`source_lag` finds the tracks out of sync."""
    lag = source_lag(mono, binaural, sample_rate)
    if lag is None:
        return
    # A warning, not an error: a real recording whose recorder started late looks just like this.
    ahead, behind = (source_path, binaural_path) if lag > 0 else (binaural_path, source_path)
    warnings.warn(
        f"{behind}: lags {ahead.name} by {abs(lag):.2f} s (cross-correlation of the two tracks); expected at most "
        f"{MAX_ACOUSTIC_LAG_S:g} s (sound crossing the scene), so one WAV is shifted against the other and the poses",
        UserWarning,
        stacklevel=3,
    )
