"""Fused loops on the CPU for the synthesis' per-element work, compiled by numba.

Torch runs each element-wise step as its own pass over memory, with its own dispatch.
Three steps of every render are long chains of such passes over small arrays:

- the phase retrieval's magnitude projection, ``target * X / |X|`` on a spectrogram:
  |X|^2, its floor, 1/sqrt, times the target, a complex copy of the scale, the product
  (six passes, ten times a render);
- the tail's decayed power ``P(t) = w (P(t-1) + |S(t-1)|^2)``: by torch an FFT convolution
  along frames padded to twice the tail, or a Python loop over frames;
- the inverse STFT's overlap-add (:class:`avgs.dsp.phase_retrieval.FrameGrid`): a zeroed buffer,
  an accumulation per overlapping frame and the corrections at both ends, and the reflected
  padding of the STFT that follows it (eleven and ten times a render).

:func:`project_magnitudes`, :func:`decayed_power`, :func:`overlap_add` and :func:`reflect_ends`
do each as one loop (a render of a 1 s clip: the projection 8 us instead of 40, the tail 5 us
instead of 120 on our 2 cores; the overlap-add 17 us instead of 55, the padding 5 instead of 13).
They take torch tensors; on the CPU the loops run on their memory, elsewhere (CUDA) the
torch expressions run, which are also the reference the loops are tested against
(tests/test_kernels.py). The loops compile once per dtype on first use (about a second)
and numba keeps the result on disk beside this file, or in the user's cache folder where
this one is read-only.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

_LOOP = dict(cache=True, nogil=True, error_model="numpy", boundscheck=False,
             fastmath={"nnan", "ninf", "nsz", "contract"})  # IEEE sqrt and division: no approximate reciprocals


@njit(**_LOOP)
def _project(spec, target, floor, out):  # pragma: no cover - compiled
    """out = target * spec / max(|spec|, sqrt(floor)); spec, out: [M, 2F] (re, im interleaved); target [M, F]
    or [1, F] (the same row for all)."""
    m_rows, n_freq = spec.shape[0], target.shape[1]
    shared = target.shape[0] == 1
    for m in range(m_rows):
        x, tg, o = spec[m], target[0 if shared else m], out[m]
        for f in range(n_freq):
            re, im = x[2 * f], x[2 * f + 1]
            s = tg[f] / np.sqrt(max(re * re + im * im, floor))
            o[2 * f] = re * s
            o[2 * f + 1] = im * s


@njit(**_LOOP)
def _decayed(power, decay, state, out):  # pragma: no cover - compiled
    """out[m, t] = decay * (out[m, t-1] + power[m, t-1]), from state[m] = P(-1) + |S(-1)|^2; state updated."""
    m_rows, n, n_freq = power.shape
    for m in range(m_rows):
        acc = state[m]
        for t in range(n):
            p, o = power[m, t], out[m, t]
            for f in range(n_freq):
                a = acc[f] * decay[f]
                o[f] = a
                acc[f] = a + p[f]


@njit(**_LOOP)
def _overlap_add_row(frames, window, head, tail, out):  # pragma: no cover - compiled
    """One signal of :func:`_overlap_add`: frames [N, R hop], out [(N + R - 1) hop]."""
    n = frames.shape[0]
    overlap, hop = window.shape
    length, edge = out.shape[0], head.shape[0]
    for i in range(length):
        out[i] = 0.0
    for r in range(overlap):  # torch's order: each sample sums its frames by r
        off = r * hop
        for t in range(n):
            base = (t + r) * hop
            for j in range(hop):
                out[base + j] += frames[t, off + j] * window[r, j]
    for i in range(edge):
        out[i] *= head[i]
    if edge < length:
        for i in range(edge):
            out[length - edge + i] *= tail[i]


@njit(**_LOOP)
def _overlap_add(frames, window, head, tail, out):  # pragma: no cover - compiled
    """out[m, (t + r) hop + j] = sum_r frames[m, t, r hop + j] window[r, j], then the ends scaled:
    frames [M, N, R hop]; window [R, hop]; head, tail [E]; out [M, (N + R - 1) hop]."""
    for m in range(frames.shape[0]):
        _overlap_add_row(frames[m], window, head, tail, out[m])


@njit(**_LOOP)
def _reflect_ends(z, pad, length):  # pragma: no cover - compiled
    """z [M, P]'s first ``pad`` samples and those after ``pad + length`` rewritten in place as the
    centred STFT pads the waveform z[:, pad : pad + length] (reflected; zeros under half a window)."""
    m_rows, total = z.shape
    right = total - (pad + length)
    for m in range(m_rows):
        x = z[m]
        if length > pad:
            for i in range(pad):
                x[i] = x[2 * pad - i]
            for i in range(right):
                x[pad + length + i] = x[pad + length - 2 - i]
        else:
            for i in range(pad):
                x[i] = 0.0
            for i in range(right):
                x[pad + length + i] = 0.0


def on_cpu(*tensors: torch.Tensor) -> bool:
    """Whether the loops take ``tensors``: all in the CPU's memory and none needing a gradient."""
    return all(t.device.type == "cpu" and not t.requires_grad for t in tensors)


def project_magnitudes(spec: torch.Tensor, target: torch.Tensor | None = None) -> torch.Tensor:
    """``target * spec / |spec|``: the magnitudes ``target`` [..., F] (>= 0, real) with the phase of
    ``spec`` [..., F] (complex); with no target, the unit phasors of ``spec``. A bin where
    ``spec`` is 0 gives 0 (its magnitude is floored at the dtype's smallest normal number)."""
    real = torch.float64 if spec.dtype == torch.complex128 else torch.float32
    floor = torch.finfo(real).tiny
    if not on_cpu(spec) or (target is not None and (not on_cpu(target) or target.dtype != real)):
        scale = (spec * spec.conj()).real.clamp_min(floor).rsqrt_()
        return spec * (scale if target is None else scale.mul_(target))
    n_freq = spec.shape[-1]
    c = spec.contiguous().numpy()  # complex; its numbers (re, im) interleaved, viewed as [rows, 2F] below
    rows = c.size // n_freq
    x = c.reshape(rows, n_freq).view(c.real.dtype)
    o = np.empty_like(x)
    if target is None:  # unit phasors: one row of ones for all
        tg = np.ones((1, n_freq), dtype=x.dtype)
    elif target.shape == spec.shape:
        tg = target.contiguous().numpy().reshape(rows, n_freq)
    elif target.shape[-1] == n_freq and target.numel() == n_freq:  # one row for all (as broadcasting it)
        tg = target.contiguous().numpy().reshape(1, n_freq)
    else:
        tg = target.expand(spec.shape).contiguous().numpy().reshape(rows, n_freq)
    _project(x, tg, x.dtype.type(floor), o)
    return torch.from_numpy(o.view(c.dtype).reshape(spec.shape))


def decayed_power(power: torch.Tensor, decay: torch.Tensor, state: torch.Tensor | None = None):
    """The tail's power frame by frame, ``P(t) = w (P(t-1) + |S(t-1)|^2)``, frame-major.

    power: ``|S|^2`` [..., N_t, F] (real, >= 0); decay: w [F]; ``state``: ``P + |S|^2`` of the
    frame before ([..., F]; None: silence before). Returns (P [..., N_t, F], the next state).
    """
    lead, (n, n_freq) = power.shape[:-2], power.shape[-2:]
    acc = torch.zeros(*lead, n_freq, dtype=power.dtype, device=power.device) if state is None else state.clone()
    if not on_cpu(power, decay, acc):
        out = torch.empty_like(power)
        for t in range(n):
            acc = acc * decay
            out[..., t, :] = acc
            acc = acc + power[..., t, :]
        return out, acc
    out = torch.empty(power.shape, dtype=power.dtype)
    flat = acc.reshape(-1, n_freq)
    _decayed(power.contiguous().reshape(-1, n, n_freq).numpy(), decay.to(power.dtype).contiguous().numpy(),
             flat.numpy(), out.view(-1, n, n_freq).numpy())
    return out, flat.view(acc.shape)


def overlap_add(frames: torch.Tensor, window: torch.Tensor, head: torch.Tensor, tail: torch.Tensor) -> torch.Tensor:
    """The inverse STFT's windowed overlap-add on the CPU (the loop; callers keep the torch form
    for other devices and autograd): ``frames`` [..., N, R hop] real, ``window`` [R, hop] (the
    synthesis window over the window-sum), ``head`` / ``tail`` [E] the corrections of the first
    and last E samples. Returns the padded signal [..., (N + R - 1) hop]."""
    lead, (n, width) = frames.shape[:-2], frames.shape[-2:]
    overlap, hop = window.shape
    out = torch.empty(*lead, (n + overlap - 1) * hop, dtype=frames.dtype)
    _overlap_add(frames.contiguous().reshape(-1, n, width).numpy(), window.contiguous().numpy(),
                 head.contiguous().numpy(), tail.contiguous().numpy(), out.view(-1, out.shape[-1]).numpy())
    return out


def reflect_ends(z: torch.Tensor, pad: int, length: int) -> torch.Tensor:
    """On the CPU, ``z`` [..., P] (contiguous) with its ``pad`` first samples and those after
    ``pad + length`` rewritten in place as the centred STFT pads the waveform between them:
    reflected at both ends (without repeating the end sample), zeros when the waveform is not
    longer than ``pad``. Returns ``z``."""
    _reflect_ends(z.view(-1, z.shape[-1]).numpy(), int(pad), int(length))
    return z
