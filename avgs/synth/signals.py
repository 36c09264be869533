"""Deterministic mono source signals that exercise the spectrum, at 22050 Hz.

- ``speech``: glottal-like pulse trains (F0 drifting 90-220 Hz) through three formant
  resonators whose targets change per syllable, under a 4-5 Hz syllable envelope with
  pauses, plus unvoiced noise fricatives (3-8 kHz).
- ``music``: harmonic notes (8 partials, decaying) on a random pentatonic melody with
  chords, plus a noise hi-hat.
- Both carry short broadband noise bursts so every band is excited now and then.

The train part of a scene plays ``speech``; the val part plays ``music``
(:func:`scene_source`), a different kind of signal, as in AV-NeRF's protocol.
"""

from __future__ import annotations

import numpy as np

from avgs.config import STFT
from scipy.signal import lfilter

SAMPLE_RATE = STFT.sample_rate


def _resonator(x: np.ndarray, freq: float, bandwidth: float, sr: int) -> np.ndarray:
    r = np.exp(-np.pi * bandwidth / sr)
    theta = 2 * np.pi * freq / sr
    return lfilter([1 - r], [1, -2 * r * np.cos(theta), r * r], x)


def _bandpass_noise(n: int, lo: float, hi: float, rng: np.random.Generator, sr: int) -> np.ndarray:
    spec = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1 / sr)
    spec[(f < lo) | (f > hi)] = 0
    return np.fft.irfft(spec, n)


def noise_bursts(n: int, rng: np.random.Generator, rate_hz: float = 0.7, sr: int = SAMPLE_RATE) -> np.ndarray:
    """Short (20-80 ms) white-noise bursts at random times, about ``rate_hz`` per second: ``[n]``."""
    out = np.zeros(n)
    count = rng.poisson(rate_hz * n / sr)
    for _ in range(count):
        length = int(rng.uniform(0.02, 0.08) * sr)
        start = int(rng.integers(0, max(1, n - length)))
        env = np.hanning(length)
        out[start : start + length] += rng.uniform(0.3, 0.8) * env * rng.standard_normal(length)
    return out


def speech_like(n: int, rng: np.random.Generator, sr: int = SAMPLE_RATE) -> np.ndarray:
    """Speech-like signal ``[n]`` (see the module docstring), peak about 1."""
    t = np.arange(n) / sr
    out = np.zeros(n)
    pos = 0
    vowels = np.array([[730, 1090, 2440], [270, 2290, 3010], [530, 1840, 2480], [300, 870, 2240], [660, 1720, 2410]])
    while pos < n:
        length = int(rng.uniform(0.12, 0.3) * sr)
        stop = min(n, pos + length)
        seg = stop - pos
        if rng.random() < 0.15:  # a pause
            pos = stop + int(rng.uniform(0.05, 0.25) * sr)
            continue
        f0 = rng.uniform(90, 220) * (1 + 0.1 * np.sin(2 * np.pi * rng.uniform(1, 3) * t[pos:stop]))
        phase = np.cumsum(f0 / sr)
        pulses = np.diff(np.floor(phase), prepend=np.floor(phase[0])) > 0
        source = pulses.astype(np.float64) - pulses.mean()
        formants = vowels[rng.integers(len(vowels))] * rng.uniform(0.9, 1.1, 3)
        voiced = sum(g * _resonator(source, f, 80 + 0.05 * f, sr) for g, f in zip((1.0, 0.6, 0.3), formants))
        voiced /= max(np.max(np.abs(voiced)), 1e-9)
        env = np.sin(np.pi * np.arange(seg) / seg) ** 0.7
        out[pos:stop] += env * voiced
        if rng.random() < 0.4:  # a fricative after the vowel
            flen = min(int(rng.uniform(0.05, 0.12) * sr), n - stop)
            if flen > 16:
                fric = _bandpass_noise(flen, 3000, 8000, rng, sr)
                out[stop : stop + flen] += 0.35 * np.hanning(flen) * fric / max(np.max(np.abs(fric)), 1e-9)
                stop += flen
        pos = stop + int(rng.uniform(0.01, 0.05) * sr)
    return out


def music_like(n: int, rng: np.random.Generator, sr: int = SAMPLE_RATE) -> np.ndarray:
    """Music-like signal ``[n]`` (see the module docstring), peak about 1."""
    out = np.zeros(n)
    scale = np.array([0, 2, 4, 7, 9])
    beat = int(rng.uniform(0.18, 0.3) * sr)
    pos = 0
    while pos < n:
        length = beat * int(rng.integers(1, 4))
        stop = min(n, pos + length)
        tt = np.arange(stop - pos) / sr
        notes = [int(rng.choice(scale)) + 12 * int(rng.integers(-1, 2))]
        if rng.random() < 0.4:
            notes += [notes[0] + 4, notes[0] + 7]
        for note in notes:
            f0 = 220.0 * 2 ** (note / 12)
            for k in range(1, 9):
                if k * f0 < sr / 2 * 0.95:
                    out[pos:stop] += (0.6 / k) * np.exp(-tt * (2 + k)) * np.sin(2 * np.pi * k * f0 * tt + rng.uniform(0, 2 * np.pi))
        hat = min(int(0.03 * sr), stop - pos)
        if hat > 16:
            out[pos : pos + hat] += 0.15 * np.exp(-np.arange(hat) / (0.008 * sr)) * _bandpass_noise(hat, 5000, 10000, rng, sr)
        pos = stop
    return out / max(np.max(np.abs(out)), 1e-9)


KINDS = {"speech": speech_like, "music": music_like}


def source_signal(kind: str, n: int, rng: np.random.Generator, sr: int = SAMPLE_RATE) -> np.ndarray:
    """``n`` samples of signal ``kind`` (speech or music) plus noise bursts, peak 1: ``[n]`` float64."""
    if kind not in KINDS:
        raise ValueError(f"unknown signal kind {kind!r}; expected one of {', '.join(KINDS)}")
    x = KINDS[kind](n, rng, sr)
    x = x / max(np.max(np.abs(x)), 1e-9) + noise_bursts(n, rng, sr=sr)
    return x / max(np.max(np.abs(x)), 1e-9)


def scene_source(n_train_s: float, total_s: float, seed: int, sr: int = SAMPLE_RATE, fade_s: float = 0.05) -> np.ndarray:
    """The scene's whole mono source ``[round(total_s sr)]``: speech for the first
    ``n_train_s`` seconds (the train frames), music after (the val frames), joined by a
    short crossfade."""
    n = int(round(total_s * sr))
    cut = min(n, int(round(n_train_s * sr)))
    speech = source_signal("speech", n, np.random.default_rng([seed, 10]), sr)
    music = source_signal("music", n, np.random.default_rng([seed, 11]), sr)
    fade = np.clip((np.arange(n) - cut) / max(fade_s * sr, 1.0) + 0.5, 0.0, 1.0)  # 0 before cut, 1 after
    return (1 - fade) * speech + fade * music
