"""A pose as a filter: the binaural impulse response of B's masks.

B's masks are time-invariant, so what a pose does to any source is a linear filter. This
module writes that filter down as one binaural impulse response ``h [2, L]``; rendering
becomes FFT convolution (:func:`convolve`, and block by block
:class:`avgs.acoustics.convolution.BlockConvolver`), with no phase retrieval.

- **Direct part**: per ear, the minimum-phase filter whose magnitude is the ear's gain
  ``g_ear = m_m (1 +- m_d)`` at the STFT's bin frequencies (:func:`minimum_phase`): the
  same magnitude response as ``|S| g_ear``, causal, delayed by the ear's share of the
  interaural time difference (``Masks.delay``, :mod:`avgs.acoustics.interaural`).
- **Reverberant tail** (models with :mod:`avgs.acoustics.reverb_tail`): per ear, noise
  whose power in bin f decays by ``w_f`` per STFT hop, starting one hop after the direct
  sound, scaled by the ear's reverberant gain ``r_ear``. In expectation the output's STFT
  power is then ``(|S| g)^2 + r^2 P`` with ``P = sum_k w^k |S(t - k)|^2``: the mask
  model's ear magnitudes squared, as an artificial reverberator realises a decay
  (Jot's feedback delay networks; here the noise is drawn once, so a render is
  deterministic). The two ears get independent noise (a diffuse field's tail is
  incoherent between the ears above a few hundred Hz).

Calibration, from the STFT's Parseval relation (a white input x of unit variance has
``E|X(f, t)|^2 = sum(w^2)`` per frame, and ``sum_t |X(f, t)|^2 = |X(f)|^2 sum(w^2) / hop``):
the tail's frames carry ``|T(f, k)|^2 = r_f^2 w_f^k sum(w^2) / hop`` for k >= 1, so its
energy per bin is ``r^2 w / (1 - w)``, the tail's share of the mask model's power gain.
"""

from __future__ import annotations

import functools
import math

import scipy.fft
import torch

from avgs import dsp
from avgs.acoustics.synthesis import Masks, ear_gains, unit_phase
from avgs.config import STFT, STFTConfig

FLOOR_DB = -120.0
"Gains below the filter's loudest bin by more than this are raised to it (the log of 0 is not a number)."

OVERSAMPLE = 8
"The minimum-phase design's cepstrum is taken on a grid this many times finer than the STFT's (less aliasing)."

TAIL_FLOOR = 1e-7
"The tail is cut where its power in every bin has decayed below this (70 dB)."

MAX_TAIL_SECONDS = 8.0
"Longest tail (a reverberation time of about 7 s, far beyond any room the model has seen)."

CALIBRATION_PASSES = 2
"Rounds of measuring the tail's energy per bin and correcting it (the error falls about tenfold per round)."

TAIL_SEED = 20231123
"Seed of the tail's noise: fixed, so a render is a deterministic function of the pose."


def minimum_phase(gain: torch.Tensor, n_fft: int, oversample: int = OVERSAMPLE, delay: torch.Tensor | None = None) -> torch.Tensor:
    """Minimum-phase impulse responses ``[..., n_fft]`` whose magnitude is ``gain [..., n_fft // 2 + 1]`` (>= 0),
    each delayed by ``delay`` [...] samples (fractional: a linear phase on the fine grid; None: none).

    Homomorphic design (Oppenheim & Schafer, ch. 13): the log magnitude, linearly
    interpolated onto a grid ``oversample`` times finer, its real cepstrum folded onto
    positive quefrencies, exponentiated; the response is cut to ``n_fft`` taps (the STFT's
    window: the mask model resolves nothing finer). Bins more than ``-FLOOR_DB`` below
    the loudest are raised to that floor; an all-zero gain gives a zero filter.
    """
    n_fine = n_fft * oversample
    peak = gain.amax(dim=-1, keepdim=True)  # [..., 1]
    floor = peak * 10.0 ** (FLOOR_DB / 20.0)
    log_mag = torch.log(torch.maximum(gain, floor).clamp_min(torch.finfo(gain.dtype).tiny))  # [..., F]
    fine = torch.nn.functional.interpolate(
        log_mag.reshape(-1, 1, log_mag.shape[-1]), size=n_fine // 2 + 1, mode="linear", align_corners=True
    ).reshape(*log_mag.shape[:-1], n_fine // 2 + 1)
    cepstrum = torch.fft.irfft(fine, n_fine)  # [..., n_fine] real, even
    fold = torch.zeros(n_fine, dtype=cepstrum.dtype, device=cepstrum.device)
    fold[0] = 1.0
    fold[1 : n_fine // 2] = 2.0
    fold[n_fine // 2] = 1.0
    spectrum = torch.exp(torch.fft.rfft(cepstrum * fold, n_fine))  # [..., n_fine // 2 + 1]
    if delay is not None:
        k = torch.arange(n_fine // 2 + 1, dtype=cepstrum.dtype, device=cepstrum.device)
        spectrum = spectrum * torch.polar(torch.ones_like(k), (-2.0 * math.pi / n_fine) * k * delay.to(cepstrum)[..., None])
    h = torch.fft.irfft(spectrum, n_fine)[..., :n_fft]
    fade = torch.ones(n_fft, dtype=h.dtype, device=h.device)
    taper = n_fft // 8  # the last taps, faded out: the cut leaves no step
    fade[-taper:] = 0.5 + 0.5 * torch.cos(torch.linspace(0.0, math.pi, taper, dtype=h.dtype, device=h.device))
    return h * fade * (peak > 0)


def tail_frames(decay: torch.Tensor, hop_seconds: float) -> int:
    """STFT frames the tail lasts: until ``max_f decay_f^k < TAIL_FLOOR``, at most ``MAX_TAIL_SECONDS``."""
    w = float(decay.detach().max())
    cap = max(2, int(MAX_TAIL_SECONDS / hop_seconds))  # (cap - 1) hops fit in MAX_TAIL_SECONDS
    if w <= 0.0:
        return 2
    if w >= 1.0:
        return cap
    return int(min(cap, math.ceil(math.log(TAIL_FLOOR) / math.log(w)) + 1))


@functools.lru_cache(maxsize=4)
def _noise(stft: STFTConfig) -> torch.Tensor:
    """Two independent unit-variance white noises [2, MAX_TAIL_SECONDS] (the ears' tails), float64:
    one draw per process, cut to each scene's tail, so a tail is the same whatever its length or dtype."""
    g = torch.Generator().manual_seed(TAIL_SEED)
    return torch.randn(2, int(MAX_TAIL_SECONDS * stft.sample_rate), generator=g, dtype=torch.float64)


def _noise_spectrogram(n_frames: int, stft: STFTConfig) -> torch.Tensor:
    """STFT [2, F, n_frames] (complex128) of the tails' noise, its first ``(n_frames - 1) hop`` samples."""
    return dsp.stft(_noise(stft)[:, : (n_frames - 1) * stft.hop_length], stft)  # [2, F, n_frames]


class TailShaper:
    """The tail's noise, shaped by the scene's decay once: per pose only the ears' gains change.

    ``decay [F]`` is scene-wide (a property of the room), so the decaying noise
    ``N(f, k) w_f^(k/2)`` is computed once; :meth:`__call__` scales it by a pose's
    reverberant gains and returns the tail's waveform.
    """

    def __init__(self, decay: torch.Tensor, stft: STFTConfig = STFT):
        self.stft = stft
        self.decay = decay.detach().double().cpu()
        hop_seconds = stft.hop_length / stft.sample_rate
        self.frames = tail_frames(self.decay, hop_seconds)  # K
        k = torch.arange(self.frames, dtype=torch.float64)  # [K]
        w = self.decay.clamp(0.0, 1.0)[:, None]  # [F, 1]
        envelope = torch.where(k > 0, w ** (0.5 * k), torch.zeros(()))  # [F, K], nothing at k = 0 (the direct part)
        window_power = float(dsp.window(stft.win_length, "cpu", torch.float64).square().sum())
        # E|N(f, k)|^2 = sum(w^2), so |T(f, k)|^2 = r^2 w^k sum(w^2) / hop in expectation: energy r^2 w / (1 - w) per bin.
        noise = _noise_spectrogram(self.frames, stft)  # [2, F, K]
        # One draw of noise puts more energy in some bins than others (each bin's energy is
        # a sum of a few random terms): scale each bin to its expected energy, so the tail
        # colours nothing the masks do not.
        weight = envelope.square()  # [F, K]
        drawn = (noise.abs().square() * weight).sum(-1, keepdim=True)  # [2, F, 1]
        expected = window_power * weight.sum(-1, keepdim=True)  # [F, 1]
        noise = noise * torch.sqrt(expected / drawn.clamp_min(1e-300))
        shaped = noise * (envelope / math.sqrt(stft.hop_length))  # [2, F, K]
        self.length = (self.frames - 1) * stft.hop_length  # samples
        # Shaped frames are not quite the STFT of any signal: the inverse STFT loses a few percent
        # of their energy, unevenly over bins. Measure the waveform's own energy per bin and correct.
        want = window_power * weight.sum(-1) / stft.hop_length  # [F]: sum_k |T|^2 for r = 1
        for _ in range(CALIBRATION_PASSES):
            got = dsp.stft(dsp.istft(shaped, self.length, stft), stft).abs().square().sum(-1)  # [2, F]
            shaped = shaped * torch.sqrt(want / got.clamp_min(1e-300))[..., None]
        self._shaped = shaped.to(torch.complex64)  # [2, F, K]

    def __call__(self, reverb: torch.Tensor) -> torch.Tensor:
        """Tails [B, 2, length] (float64) for reverberant gains ``reverb [B, 2, F]``."""
        spec = self._shaped[None] * reverb.detach().float().cpu()[..., None]  # [B, 2, F, K]
        return dsp.istft(spec, self.length, self.stft).double()


def impulse_response(masks: Masks, stft: STFTConfig = STFT, tail: TailShaper | None = None) -> torch.Tensor:
    """Binaural impulse responses ``[B, 2, L]`` (float64, CPU; channel 0 = left) of a batch of poses' masks.

    L is ``n_fft`` without a tail, else the tail's length (at least ``n_fft``). ``tail``: a
    :class:`TailShaper` for ``masks.decay`` (made here when not given; cache it per scene).
    """
    gains = ear_gains(masks.mixture.detach().double().cpu(), masks.difference.detach().double().cpu())  # [B, 2, F]
    delay = None if masks.delay is None else masks.delay.detach().double().cpu() * stft.sample_rate  # [B, 2] samples
    direct = minimum_phase(gains, stft.n_fft, delay=delay)  # [B, 2, n_fft]
    if masks.reverb is None:
        return direct
    tail = tail if tail is not None else TailShaper(masks.decay, stft)
    wet = tail(masks.reverb)  # [B, 2, L_tail]
    n = max(direct.shape[-1], wet.shape[-1])
    h = torch.nn.functional.pad(wet, (0, n - wet.shape[-1]))
    h[..., : direct.shape[-1]] += direct
    return h


def convolve(x: torch.Tensor, h: torch.Tensor, block: int = 1 << 17) -> torch.Tensor:
    """``x [T]`` convolved with ``h [C, L]``, cut to ``[C, T]`` (the input's length), by FFT.

    Inputs longer than ``block`` samples are convolved block by block (overlap-add), so
    memory stays bounded by the block and the response, whatever the input's length.
    """
    t, n = x.shape[-1], h.shape[-1]
    block = max(block, n)
    size = scipy.fft.next_fast_len(min(block, t) + n - 1, real=True)  # >= piece + n - 1: linear, not circular
    h_spec = torch.fft.rfft(h, size)  # [C, size // 2 + 1]
    y = torch.zeros(h.shape[0], t, dtype=torch.result_type(x, h), device=x.device)
    for start in range(0, t, block):
        piece = x[start : start + block]
        out = torch.fft.irfft(torch.fft.rfft(piece, size) * h_spec, size)  # [C, size]
        stop = min(t, start + size)
        y[:, start:stop] += out[:, : stop - start]
    return y


def filter_phase(mono: torch.Tensor, masks: Masks, stft: STFTConfig = STFT, tail: TailShaper | None = None) -> torch.Tensor:
    """Unit phasors ``[B, 2, F, N_t]`` of the STFT of each input ``mono [B, T]`` through its pose's
    filter (masks [B, ...]): the phase the default synthesis gives B's ear magnitudes
    (:func:`avgs.acoustics.synthesis.ear_spectrogram`), on the masks' device. ``tail``: a
    :class:`TailShaper` for ``masks.decay``."""
    h = impulse_response(masks, stft, tail)  # [B, 2, L] float64, CPU
    x = mono.detach().to("cpu", torch.float64)
    filtered = torch.stack([convolve(x[b], h[b]) for b in range(len(h))])  # [B, 2, T]
    return unit_phase(dsp.stft(filtered, stft)).to(device=masks.mixture.device, dtype=torch.complex64)
