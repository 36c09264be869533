"""The direct sound of a predicted impulse response, placed by geometry (``RIRConfig.direct_sound``).

B's magnitudes with a noise phase spread the direct sound over a window of noise, with no delay between
the ears. :func:`place_direct_sound` puts it where the geometry says (:class:`DirectSound`, from
:meth:`avgs.acoustics.rir_model.RIRModel.direct_sound`): nothing before distance / c, each ear delayed by
its share of the ITD, the onset an impulse at the arrival (:func:`sharpen_direct_sound`) at the level law's
energy, and the two ears' first :data:`DIRECT_SECONDS` the same sound, delayed by the ITD alone
(:func:`cohere_early`). The work is a few hundred small steps on a few hundred samples per pose, done in
NumPy on the CPU (float64), where each step costs a fraction of a torch call; no gradient flows through it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from avgs.config import STFT, STFTConfig


@dataclass(frozen=True)
class DirectSound:
    """When the direct sound reaches each ear of a batch of poses."""

    arrival: torch.Tensor  # [B] seconds: distance / c
    delays: torch.Tensor  # [B, 2] seconds each ear hears it after that (the ITD: avgs.acoustics.interaural.ear_delays)
    ild: torch.Tensor | None = None  # [B] dB, left over right, of the first 5 ms (avgs.acoustics.interaural.ild_law); None / NaN: B's
    energy: torch.Tensor | None = None  # [B] both ears' energy of the impulse's stretch (interaural.direct_level_db); None / NaN: B's
    ild_scale: torch.Tensor | None = None  # [B] where ild is NaN, B's own early ILD times this; None / NaN: B's as it is


DIRECT_SECONDS = 0.005
"The direct sound's stretch after its arrival that both ears share (coherent), as the early ITD and ILD are measured."

FADE_SAMPLES = 16
"The gate before the arrival opens over this many samples (0.7 ms): no click."

IMPULSE_SECONDS = 0.002
"The stretch after each ear's arrival whose energy the direct sound's impulse takes (:func:`sharpen_direct_sound`)."

DIFFUSE_SHARE = 0.5
"The share of that stretch's amplitude left as it was: the head's own filtering of the direct sound, roughly."

IMPULSE_TAPS = 8
"Samples either side of the fractional impulse's centre (a Hann-windowed sinc)."


def _np64(t: torch.Tensor) -> np.ndarray:
    """A tensor's values as a float64 NumPy array on the CPU (detached)."""
    return t.detach().to(device="cpu", dtype=torch.float64).numpy()


def place_direct_sound(h: torch.Tensor, direct: DirectSound, stft: STFTConfig = STFT) -> torch.Tensor:
    """Responses ``[B, 2, L]`` with nothing before the direct sound: each ear delayed by its ITD share
    (to the nearest sample: :func:`whole_sample_delay`), gated before ``arrival + delay`` (fractional; a
    raised-cosine over :data:`FADE_SAMPLES`),
    and the energy the gate took from the ear's first window given back to its next half window
    (the STFT frames spread the direct sound's energy over a window on both sides of it); then the
    direct sound made an impulse (:func:`sharpen_direct_sound`); with ``direct.energy`` (the level law,
    ``RIRConfig.direct_level``) at that energy, taken out of B's first window (:func:`_keep_window`).

    Last, the lagging ear's first :data:`DIRECT_SECONDS` become the leading ear's, delayed by the exact
    (fractional) difference of the arrivals and scaled (:func:`cohere_early`): the ears then differ there
    by the ITD alone. So the ITD is exact where it is heard and measured; after those milliseconds each ear
    is B's diffuse response (a noise phase), which a fraction of a sample does not change. (A fractional
    delay of the whole ear by FFT took 1.1 ms of the pose's 3.6 ms waveform.)

    The gate and the energy's return change only the samples from the gate's opening to a window after
    the arrival, and are worked out there, in float64. No gradient flows through it: the work is done in
    NumPy on the CPU, in place in one copy of the responses (the explorer makes one of these per pose of a
    drag: a few hundred small steps, in half the time they took in torch), and the result goes back to
    ``h``'s device and dtype."""
    fs, n_win = float(stft.sample_rate), stft.n_fft
    L = h.shape[-1]
    delays = _np64(direct.delays)  # [B, 2] seconds
    y = _whole_sample_delay(h.detach().to(device="cpu", dtype=torch.float32).numpy(), delays * fs)  # [B, 2, L] float32
    start = (_np64(direct.arrival)[:, None] + delays) * fs  # [B, 2] samples
    ild = None if direct.ild is None else _np64(direct.ild)  # [B] dB
    energy = None if direct.energy is None else _np64(direct.energy)  # [B]
    with np.errstate(all="ignore"):  # as torch: inf / NaN where the inputs say so, and no warning
        # Before the earliest gate every sample is 0; from a window after the latest arrival on, y as it is.
        lo, hi = _arrival_span(start, L, n_win)
        span = y[..., lo:hi].astype(np.float64)  # [B, 2, S]
        t = np.arange(lo, hi, dtype=np.float64)
        gated = span * _gate(t, start[..., None])
        window = (t < (start + n_win)[..., None]).astype(np.float64)  # the first window after the arrival, and before it
        before = np.square(y[..., :lo].astype(np.float64)).sum(-1) + (np.square(span) * window).sum(-1)  # [B, 2]
        after = (np.square(gated) * window).sum(-1)
        gain = np.where(after > 0, np.sqrt(before / np.maximum(after, 1e-300)), 1.0)
        back = 0.5 + 0.5 * np.cos(np.pi * np.clip((t - (start[..., None] + n_win / 2)) / (n_win / 2), 0.0, 1.0))
        out = y.astype(np.float64)
        out[..., :lo] = 0.0
        out[..., lo:hi] = gated * (1.0 + (gain[..., None] - 1.0) * back)
        early = (np.square(out[..., lo:hi]) * window).sum((-1, -2))  # [B] B's first window, both ears (before the impulse)
        out = _sharpen(out, start, fs, ild, energy)
        if energy is not None:  # the law's impulse comes out of B's first window (both ears), which holds it, not on top of it
            out = _keep_window(out, early, start, fs, n_win, np.isfinite(energy))
        out = _cohere(out, start, fs, ild, None if direct.ild_scale is None else _np64(direct.ild_scale))
    return torch.from_numpy(out).to(device=h.device, dtype=h.dtype)


def _keep_window(y: np.ndarray, early: np.ndarray, start: np.ndarray, fs: float, n_win: int,
                 given: np.ndarray) -> np.ndarray:
    """``y [B, 2, L]`` with, for the poses ``given [B]``, the rest of each ear's first window (after the
    impulse's stretch, up to ``n_win`` samples after ``start [B, 2]``) scaled so that the window holds
    ``early [B]`` again (both ears): B's first frames carry the direct sound's energy smeared over a
    window; a direct sound at the level law's energy replaces that share instead of adding to it.
    Where the law's impulse alone has more than ``early`` (near the source, where B's frames fall
    short), the rest keeps :data:`DIFFUSE_SHARE` of its amplitude. The last :data:`COHERE_FADE_SAMPLES`
    of the window ramp back to the ear's own level. Float64 NumPy, in place in ``y`` (returned)."""
    L = y.shape[-1]
    n_stretch = IMPULSE_SECONDS * fs
    lo, hi = _arrival_span(start, L, n_win)
    if lo >= hi:
        return y
    t = np.arange(lo, hi, dtype=np.float64) - start[..., None]  # [B, 2, S] samples from each ear's arrival
    span = y[..., lo:hi]
    inside = ((t >= -FADE_SAMPLES) & (t < n_stretch)).astype(np.float64)
    rest = ((t >= n_stretch) & (t < n_win)).astype(np.float64)
    have_in = (np.square(span) * inside).sum((-1, -2))  # [B]
    have_rest = (np.square(span) * rest).sum((-1, -2))
    floor = DIFFUSE_SHARE**2 * have_rest
    want = np.maximum(early - have_in, floor)
    g = np.where(given & (have_rest > 0), np.sqrt(want / np.maximum(have_rest, 1e-300)), 1.0)  # [B]
    ramp = np.clip((n_win - t) / COHERE_FADE_SAMPLES, 0.0, 1.0)  # [B, 2, S] 1 until the window's last samples, then to 0
    profile = 1.0 + (g[:, None, None] - 1.0) * rest * (0.5 - 0.5 * np.cos(np.pi * ramp))
    y[..., lo:hi] = span * profile
    return y


def _arrival_span(start, L: int, after: float, pad: int = 0) -> tuple[int, int]:
    """The samples ``lo .. hi - 1`` (within ``0 .. L``) that the direct sound's work changes: from
    :data:`FADE_SAMPLES` before the earliest arrival in ``start`` (samples, fractional) to ``after`` samples
    after the latest, widened by ``pad`` on both sides. Empty (``lo == hi``) when the arrivals are past the end."""
    lo = min(L, max(0, int(math.floor(float(start.min()))) - FADE_SAMPLES - pad))
    return lo, min(L, max(lo, int(math.ceil(float(start.max()) + after)) + pad + 1))


def _gate(t: np.ndarray, start) -> np.ndarray:
    """The gate before an arrival at ``start`` (samples) at sample times ``t``: 0, then a raised cosine over
    :data:`FADE_SAMPLES` up to 1 at ``start``."""
    opening = np.clip((t - (start - FADE_SAMPLES)) / FADE_SAMPLES, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * opening)


def whole_sample_delay(x: torch.Tensor, samples: torch.Tensor) -> torch.Tensor:
    """``x [..., L]`` delayed by ``samples [...]`` rounded to whole samples (either sign), zeros where
    nothing arrives yet (or any more)."""
    return torch.from_numpy(_whole_sample_delay(x.detach().cpu().numpy(), _np64(samples))).to(x.device)


def _whole_sample_delay(x: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """:func:`whole_sample_delay` in NumPy (``x``'s dtype)."""
    L = x.shape[-1]
    rows = x.reshape(-1, L)  # [R, L]
    shift = np.round(np.broadcast_to(samples, x.shape[:-1]).reshape(-1)).astype(np.int64).tolist()  # [R]
    out = np.zeros_like(rows)
    for r, k in enumerate(shift):
        if 0 <= k < L:
            out[r, k:] = rows[r, : L - k]
        elif -L < k < 0:
            out[r, :k] = rows[r, -k:]
    return out.reshape(x.shape)


def fractional_delay(x: torch.Tensor, samples: torch.Tensor) -> torch.Tensor:
    """``x [..., L]`` delayed by ``samples [...]`` (fractional, |delay| < L), by one FFT in ``x``'s
    precision, of a fast length >= 2 L: the band-limited delay's sinc tails reach more than L samples
    before wrapping around (at a length of L + 64 the response's first samples leak into its last
    at 0.3 % of the peak; here 4e-5)."""
    return torch.from_numpy(_fractional_delay(x.detach().cpu().numpy(), _np64(samples))).to(x.device)


def _fractional_delay(x: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """:func:`fractional_delay` in NumPy (SciPy's FFT keeps ``x``'s precision)."""
    from scipy.fft import irfft, next_fast_len, rfft

    L = x.shape[-1]
    size = next_fast_len(2 * L, real=True)
    freqs = np.fft.rfftfreq(size)  # [size // 2 + 1] cycles per sample, float64
    angle = (-2.0 * np.pi * freqs * np.asarray(samples, dtype=np.float64)[..., None]).astype(x.dtype)  # [..., K] radians
    return irfft(rfft(x, size) * (np.cos(angle) + 1j * np.sin(angle)), size)[..., :L]


def sharpen_direct_sound(y: torch.Tensor, start: torch.Tensor, fs: float, ild: torch.Tensor | None = None,
                         energy: torch.Tensor | None = None) -> torch.Tensor:
    """``y [B, 2, L]`` with each ear's first :data:`IMPULSE_SECONDS` after ``start [B, 2]`` (samples,
    fractional) made mostly an impulse at ``start``: the stretch keeps :data:`DIFFUSE_SHARE` of its
    amplitude and the rest of its energy becomes one band-limited impulse (a Hann-windowed sinc of
    :data:`IMPULSE_TAPS` samples each side) there. The energy, hence the level and every energy
    measure after 5 ms (C50, EDT, T60), is unchanged. Float64, on ``y``'s device.

    The STFT magnitudes spread the direct sound over a window of noise, whose peak is rarely the
    response's: on the two-room preset a quarter of the responses in sight of the source had their
    onset (-20 dB of the peak) 1-2 ms late. A direct sound is an impulse the head filters; as one it
    is the response's first peak, and both ears carry exactly the ITD it was given.

    ``ild [B]`` (dB, left over right; NaN: as without): the impulse's energy (both ears together, as above) is
    shared between the ears so that the first :data:`DIRECT_SECONDS` from the earlier arrival on
    (what :func:`avgs.evaluation.spatial.early_ild` reads) have that ILD, as far as the rest of
    that stretch allows (all the impulse in one ear at most).

    ``energy [B]`` (both ears; NaN: as without): the stretch's energy the direct sound's law gives
    (:func:`avgs.acoustics.interaural.direct_level_db`): the impulse takes what the remainder leaves of
    it (none when the remainder has more), shared between the ears as above; near the source B's first
    frames, which a network of the distance extrapolates, then no longer set the level."""
    with np.errstate(all="ignore"):
        out = _sharpen(_np64(y).copy(), _np64(start), fs, None if ild is None else _np64(ild),
                       None if energy is None else _np64(energy))
    return torch.from_numpy(out).to(y.device)


def _sharpen(y: np.ndarray, start: np.ndarray, fs: float, ild: np.ndarray | None = None,
             energy: np.ndarray | None = None) -> np.ndarray:
    """:func:`sharpen_direct_sound` in float64 NumPy, in place in ``y`` (returned)."""
    L = y.shape[-1]
    # Only the samples around the arrivals change: work on that span (the rest of y is returned as it is).
    lo, hi = _arrival_span(start, L, IMPULSE_SECONDS * fs, pad=IMPULSE_TAPS)
    if lo >= hi:
        return y
    span = y[..., lo:hi]  # [B, 2, S]
    offset = np.arange(lo, hi, dtype=np.float64) - start[..., None]  # [B, 2, S] samples from each ear's arrival
    stretch = ((offset >= -FADE_SAMPLES) & (offset < IMPULSE_SECONDS * fs)).astype(np.float64)
    stretch_energy = (np.square(span) * stretch).sum(-1)  # [B, 2]
    taper = np.where(np.abs(offset) < IMPULSE_TAPS, 0.5 + 0.5 * np.cos(np.pi * offset / IMPULSE_TAPS), 0.0)
    impulse = np.sinc(offset) * taper  # [B, 2, S]
    norm = np.maximum(np.sqrt(np.square(impulse).sum(-1, keepdims=True)), 1e-12)
    out = y  # (span, read above, is overwritten here)
    out[..., lo:hi] = span * (1.0 - stretch * (1.0 - DIFFUSE_SHARE))
    share = stretch_energy * (1.0 - DIFFUSE_SHARE**2)  # [B, 2] each ear's impulse energy
    if energy is not None:  # the law's total for the stretch: the impulse takes what the remainder leaves
        rest = (stretch_energy * DIFFUSE_SHARE**2).sum(-1)  # [B]
        total = share.sum(-1)
        wanted = np.where(np.isfinite(energy), np.maximum(energy - rest, 0.0), total)
        share = np.where(total[:, None] > 0, share * (wanted / np.maximum(total, 1e-300))[:, None], wanted[:, None] * 0.5)
    if ild is not None:
        share = _shared_for_ild(out, start, share, ild, fs)
    out[..., lo:hi] += impulse / norm * np.sqrt(share)[..., None]
    return out


COHERE_FADE_SAMPLES = 32
"Samples over which the lagging ear's coherent early stretch fades back into its own response (1.5 ms)."


def cohere_early(y: torch.Tensor, start: torch.Tensor, fs: float, ild: torch.Tensor | None = None) -> torch.Tensor:
    """``y [B, 2, L]`` with the lagging ear's first :data:`DIRECT_SECONDS` after its arrival replaced by the
    leading ear's, delayed by the difference of ``start [B, 2]`` (samples, fractional) and scaled to keep the
    lagging ear's energy over the :data:`DIRECT_SECONDS` from the earlier arrival on; then a :data:`COHERE_FADE_SAMPLES` crossfade back into its own samples.

    ``ild [B]`` (dB, left over right; NaN or None: as above): the two ears' energies over that stretch are
    shared anew, their sum kept, so that the stretch has that ILD: the lagging ear's copy takes its share,
    the leading ear a gain over the same samples (and a crossfade back to its own level after them).
    The impulse alone cannot always give it (:func:`sharpen_direct_sound`: B's remainder in the same
    milliseconds may lean the other way); a gain on one direct sound heard by both ears always can.

    Each ear's early stretch is a placed impulse plus B's diffuse remainder, in proportions that differ
    between the ears (the head shadow's ILD moves the impulse's energy, B sets the remainder's), so the
    interaural phase of their sum is not the ITD's: measured by GCC-PHAT over the first 5 ms
    (:func:`avgs.evaluation.spatial.response_itd`) the rendered ITD was a median 27 us off the one
    placed (two rooms, in sight of the source). A head in free field gives its ears the same direct
    sound, delayed and filtered; here the filter is a broadband gain, so the early ITD is the placed one
    and the early ILD (energy) is kept. The leading ear (without ``ild``), the stretch's energy and
    everything after it do not change. In ``y``'s dtype, on its device."""
    with np.errstate(all="ignore"):
        out = _cohere(y.detach().cpu().numpy().copy(), _np64(start), fs, None if ild is None else _np64(ild))
    return torch.from_numpy(out).to(y.device)


def _cohere(y: np.ndarray, start: np.ndarray, fs: float, ild: np.ndarray | None = None,
            scale: np.ndarray | None = None) -> np.ndarray:
    """:func:`cohere_early` in NumPy (``y``'s dtype), in place in ``y`` (returned): each pose reads its lagging
    ear's samples before it writes them, and its leading ear's energy before it scales them. ``scale [B]``
    (:attr:`DirectSound.ild_scale`): where ``ild`` is NaN (or None) and it is a number, the ILD asked for is
    the stretch's own times it."""
    B, _, L = y.shape
    n_early = int(round(DIRECT_SECONDS * fs))
    out = y
    for b in range(B):
        lead = int(np.argmin(start[b]))
        lag = 1 - lead
        d = float(start[b, lag] - start[b, lead])  # samples, >= 0
        s0 = max(0, int(math.floor(float(start[b, lead]))) - FADE_SAMPLES - IMPULSE_TAPS)
        s1 = min(L, int(math.ceil(float(start[b, lead]))) + n_early + IMPULSE_TAPS)
        k = int(math.floor(d))
        a0, a1 = s0 + k, min(L, s1 + k + COHERE_FADE_SAMPLES)  # the lagging ear's span that changes
        if a1 - a0 <= COHERE_FADE_SAMPLES:
            continue
        n = a1 - a0
        core = min(n, s1 - s0)
        # the stretch the early ILD reads (from the earlier arrival on), and the lagging ear's energy there
        w0 = max(a0, int(math.floor(float(start[b, lead]))))
        w1 = min(a0 + core, w0 + n_early)
        energy = float(np.square(y[b, lag, w0:w1]).sum())
        level = None if ild is None else float(ild[b])
        given = level is not None and math.isfinite(level)
        if given or (scale is not None and math.isfinite(float(scale[b]))):
            lead_energy = float(np.square(y[b, lead, w0:w1]).sum())
            if not given:  # the stretch's own ILD (left over right) times the scale; none where an ear is silent
                own = 10.0 * math.log10(lead_energy / energy) if lead_energy > 0.0 and energy > 0.0 else None
                level = None if own is None else float(scale[b]) * (own if lead == 0 else -own)
        if level is not None and math.isfinite(level):  # share the stretch's energy for the ILD, its sum kept
            ratio = 10.0 ** ((level if lead == 0 else -level) / 10.0)  # leading over lagging ear
            total = lead_energy + energy
            if lead_energy > 0.0 and total > 0.0:
                energy = total / (1.0 + ratio)
                _scale_stretch(out[b, lead], s0, s1, math.sqrt(total * ratio / (1.0 + ratio) / lead_energy))
        source = np.zeros(n + 2 * IMPULSE_TAPS, dtype=y.dtype)  # the leading ear (its gain, fades and all), from s0 on
        got = out[b, lead, s0 : min(L, s0 + n)]
        source[: got.shape[0]] = got
        shifted = _fractional_delay(source[None], np.array([d - k]))[0, :n]  # lead moved by d
        # the lagging ear's gate, as place_direct_sound's: the delay's sinc tails reach before it
        shifted = shifted * _gate(np.arange(a0, a1, dtype=y.dtype), float(start[b, lag]))
        moved = float(np.square(shifted[w0 - a0 : w1 - a0]).sum())
        if moved <= 0.0:
            continue
        new = shifted * math.sqrt(energy / moved)  # the lagging ear's energy over the stretch: kept, or its ILD share
        fade = np.ones(n, dtype=y.dtype)
        tail = n - core  # the crossfade after the stretch, back to the lagging ear's own samples
        if tail > 0:
            fade[core:] = 0.5 + 0.5 * np.cos(np.pi * np.arange(1, tail + 1, dtype=y.dtype) / (tail + 1))
        out[b, lag, a0:a1] = new * fade + y[b, lag, a0:a1] * (1.0 - fade)
    return out


def _scale_stretch(x: np.ndarray, s0: int, s1: int, gain: float) -> None:
    """``x [L]`` times ``gain`` over samples ``s0 .. s1 - 1``, then back to 1 over :data:`COHERE_FADE_SAMPLES`
    (a raised cosine), in place. Before ``s0`` the ear is silent (its gate), so no fade is needed there."""
    L = x.shape[-1]
    s1 = min(s1, L)
    x[s0:s1] *= gain
    n = min(COHERE_FADE_SAMPLES, L - s1)
    if n > 0:
        t = np.arange(1, n + 1, dtype=x.dtype) / (COHERE_FADE_SAMPLES + 1)
        x[s1 : s1 + n] *= gain + (1.0 - gain) * (0.5 - 0.5 * np.cos(np.pi * t))


def _shared_for_ild(rest: np.ndarray, start: np.ndarray, share: np.ndarray, ild: np.ndarray, fs: float) -> np.ndarray:
    """Each ear's impulse energy ``[B, 2]``, their sum that of ``share [B, 2]``, such that the first
    DIRECT_SECONDS after the earlier arrival of ``start [B, 2]`` have ``ild [B]`` dB: with ``rest
    [B, 2, L]`` the response without its impulses there, ``left + rest_l = r (right + rest_r)``,
    r = 10^(ild / 10), clamped to [0, sum]. Float64 NumPy."""
    total = share.sum(-1)  # [B]
    L = rest.shape[-1]
    first = np.floor(start.min(-1)).astype(np.int64)  # [B] samples
    at = first[:, None] + np.arange(max(1, round(DIRECT_SECONDS * fs)))  # [B, n]
    inside = ((at >= 0) & (at < L)).astype(np.float64)
    index = np.broadcast_to(np.clip(at, 0, L - 1)[:, None, :], (at.shape[0], 2, at.shape[1]))
    stretch = np.take_along_axis(rest, index, -1) * inside[:, None, :]  # [B, 2, n]
    energies = np.square(stretch).sum(-1)  # [B, 2]
    r_l, r_r = energies[:, 0], energies[:, 1]
    ratio = 10.0 ** (ild / 10.0)
    left = np.clip((ratio * (total + r_r) - r_l) / (1.0 + ratio), 0.0, total)
    given = np.isfinite(ild)[:, None]  # NaN: that pose keeps its ears' own energies
    return np.where(given, np.stack([left, total - left], axis=-1), share)
