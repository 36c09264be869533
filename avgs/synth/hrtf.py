"""The MIT KEMAR head (Gardner & Martin, MIT Media Lab tech. report #280, 1994).

The HRIRs ship inside the PyPI package ``slab`` (``slab/data/mit_kemar_normal_pinna.bz2``:
710 directions x 2 ears x 512 taps at 44.1 kHz, a bz2-compressed pickle of slab objects).
We locate the file with ``importlib.util.find_spec`` and never import ``slab`` (its import
fails where PortAudio is missing). The pickle is read with a restricted unpickler that
builds only numpy arrays and inert stand-ins for slab's two classes, so nothing in the
file can run code. Reading and resampling take ~0.3 s, so nothing is cached on disk.

Directions follow slab / SOFA: azimuth counter-clockwise from the front (90 deg = left),
elevation up from the horizontal plane; channel 0 is the left ear.

The raw MIT set carries the measurement loudspeaker and the ear canal (its mean over all
directions sits ~17 dB lower at 200-400 Hz than at 3 kHz), so :func:`kemar` applies
diffuse-field equalisation, as binaural renderers do: one minimum-phase filter, common
to every direction and both ears, that flattens the mean power response over
directions (boost capped at +20 dB). Interaural differences are untouched.
"""

from __future__ import annotations

import bz2
import functools
import importlib.util
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avgs.config import STFT

KEMAR_FILE = "data/mit_kemar_normal_pinna.bz2"
KEMAR_RATE = 44100
_NUMPY_GLOBALS = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "scalar"),
}


@dataclass(frozen=True)
class HRIRSet:
    """Measured head-related impulse responses."""

    irs: np.ndarray  # [D, 2, L] float64, channel 0 = left ear
    azimuth_deg: np.ndarray  # [D] counter-clockwise from the front
    elevation_deg: np.ndarray  # [D] up from the horizontal plane
    sample_rate: int


class _Inert:
    """Stand-in for slab's pickled classes: keeps the attributes, runs nothing."""

    def __setstate__(self, state):
        if isinstance(state, dict):
            self.__dict__.update(state)


class _RestrictedUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if module.split(".")[0] == "slab":
            return type(name, (_Inert,), {})
        if (module, name) in _NUMPY_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"KEMAR file: refusing to load {module}.{name}")


def kemar_path() -> Path:
    """Where the installed ``slab`` package keeps the KEMAR file (without importing slab)."""
    spec = importlib.util.find_spec("slab")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            "the MIT KEMAR HRIRs come from the PyPI package 'slab' (data file only), which is not "
            "installed; install it with `pip install slab`"
        )
    for location in spec.submodule_search_locations:
        path = Path(location) / KEMAR_FILE
        if path.is_file():
            return path
    raise FileNotFoundError(f"slab is installed but {KEMAR_FILE} is missing from {list(spec.submodule_search_locations)}")


def read_kemar(path: str | Path | None = None) -> HRIRSet:
    """The KEMAR HRIRs at their native 44.1 kHz."""
    path = Path(path) if path is not None else kemar_path()
    try:
        with bz2.BZ2File(path, "rb") as fh:
            obj = _RestrictedUnpickler(fh).load()
        data, sources = obj.data, np.asarray(obj.sources, dtype=np.float64)  # sources [D, 3] az, el, r
        irs = np.stack([np.asarray(f.data, dtype=np.float64).T for f in data])  # [D, 2, 512]
        rate = int(round(float(getattr(obj, "samplerate", KEMAR_RATE))))
    except (OSError, EOFError, AttributeError, TypeError, ValueError, pickle.UnpicklingError) as exc:
        raise ValueError(f"{path}: not the expected slab KEMAR file ({exc})") from None
    if irs.ndim != 3 or irs.shape[1] != 2 or sources.shape != (len(irs), 3):
        raise ValueError(f"{path}: expected [D, 2, L] HRIRs and [D, 3] directions, got {irs.shape} and {sources.shape}")
    return HRIRSet(irs, sources[:, 0], sources[:, 1], rate)


def _minimum_phase(magnitude: np.ndarray, n_fft: int) -> np.ndarray:
    """Minimum-phase impulse response ``[n_fft]`` with the given magnitude ``[n_fft // 2 + 1]`` (real cepstrum)."""
    cepstrum = np.fft.irfft(np.log(np.maximum(magnitude, 1e-9)), n_fft)
    folded = np.zeros(n_fft)
    folded[0], folded[n_fft // 2] = cepstrum[0], cepstrum[n_fft // 2]
    folded[1 : n_fft // 2] = 2 * cepstrum[1 : n_fft // 2]
    return np.fft.irfft(np.exp(np.fft.rfft(folded)), n_fft)


def diffuse_field_equalised(irs: np.ndarray, taps: int, max_boost_db: float = 20.0, n_fft: int = 2048) -> np.ndarray:
    """``irs [D, 2, L]`` filtered by one minimum-phase filter that makes their mean power
    response over directions and ears flat (0 dB), boost capped at ``max_boost_db``,
    smoothed over ~1/6 octave; truncated to ``taps`` with a short fade-out: ``[D, 2, taps]``."""
    from scipy.ndimage import uniform_filter1d
    from scipy.signal import fftconvolve

    power = np.mean(np.abs(np.fft.rfft(irs, n_fft, axis=-1)) ** 2, axis=(0, 1))  # [F]
    # ~1/6-octave smoothing: average in log-frequency by resampling onto a log grid
    bins = np.arange(1, len(power))
    log_grid = np.geomspace(1, len(power) - 1, 512)
    smooth_log = uniform_filter1d(np.interp(log_grid, bins, power[1:]), size=7, mode="nearest")
    smooth = np.concatenate([[smooth_log[0]], np.interp(bins, log_grid, smooth_log)])
    gain = np.minimum(1.0 / np.sqrt(np.maximum(smooth, 1e-12)), 10 ** (max_boost_db / 20))  # [F]
    eq = _minimum_phase(gain, n_fft)[: taps // 2]  # [taps / 2], front-loaded
    eq *= np.concatenate([np.ones(len(eq) - 16), np.hanning(32)[16:]])
    out = fftconvolve(irs, eq[None, None, :], axes=-1)[..., :taps]  # [D, 2, taps]
    fade = np.concatenate([np.ones(taps - 32), np.hanning(64)[32:]])
    return out * fade


@functools.lru_cache(maxsize=4)
def kemar(sample_rate: int = STFT.sample_rate, equalised: bool = True) -> HRIRSet:
    """The KEMAR HRIRs resampled to ``sample_rate`` (polyphase), diffuse-field equalised
    unless ``equalised=False`` (cached per process)."""
    from math import gcd

    from scipy.signal import resample_poly

    native = read_kemar()
    irs = native.irs
    if sample_rate != native.sample_rate:
        g = gcd(int(sample_rate), native.sample_rate)
        irs = resample_poly(irs, int(sample_rate) // g, native.sample_rate // g, axis=-1)  # [D, 2, L']
    if equalised:
        irs = diffuse_field_equalised(irs, taps=int(irs.shape[-1] * 1.5))
    return HRIRSet(irs, native.azimuth_deg, native.elevation_deg, int(sample_rate))


def pra_file_reader(sample_rate: int, equalised: bool = True):
    """A ``file_reader_callback`` for ``pyroomacoustics.directivities.MeasuredDirectivityFile``
    that serves the KEMAR set (:func:`kemar`): IRs ``(n_directions, n_ears, taps)``, directions
    as (azimuth, colatitude, distance) in radians, ears labelled ``left`` / ``right``."""
    hrirs = kemar(sample_rate, equalised)
    directions = np.stack(
        [np.radians(hrirs.azimuth_deg), np.radians(90.0 - hrirs.elevation_deg), np.ones_like(hrirs.azimuth_deg)]
    )  # [3, D]

    def reader(path=None, fs=None):
        return hrirs.irs, hrirs.sample_rate, directions, np.zeros((3, 2)), None, ["left", "right"]

    return reader


@functools.lru_cache(maxsize=4)
def frontal_delay(sample_rate: int = STFT.sample_rate, equalised: bool = True) -> int:
    """The head's own delay in samples: where its response to a source straight ahead
    (azimuth 0, elevation 0; both ears summed) peaks, counted from the response's first tap
    (23 at 22050 Hz equalised). pyroomacoustics places each image source's HRIR from that
    first tap, so responses carry this delay on top of the propagation."""
    hrirs = kemar(sample_rate, equalised)
    i = int(np.argmin(np.abs(hrirs.azimuth_deg) + np.abs(hrirs.elevation_deg)))
    return int(np.argmax(np.abs(hrirs.irs[i].sum(axis=0))))
