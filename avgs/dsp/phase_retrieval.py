"""Phase retrieval: a waveform whose STFT magnitudes approach given ones (fast Griffin-Lim).

Griffin and Lim (1984) alternate two projections: onto the spectrograms that are the STFT
of some signal (inverse STFT, then STFT) and onto those with the target magnitudes (keep
the phase, restore the magnitudes); Perraudin, Balazs and Sondergaard (2013) add momentum
("fast Griffin-Lim"). Each iteration is one inverse STFT and one STFT, so its cost is what
matters: :class:`FrameGrid` does both on frames laid out frame-major ``[..., N, F]`` (the
FFTs' own layout) over the centred STFT's padded signal, with the window, the window-sum
normalisation and the magnitude projection folded into as few passes as possible: about
half the time of ``torch.istft`` / ``torch.stft`` and ``abs()`` per iteration.

- :func:`griffin_lim`: from a first guess ``[..., F, N]`` (the layout of :func:`avgs.dsp.stft`)
  to a waveform; long inputs in blocks, equal to one pass.
- :func:`retrieve_phase`: the unit phasors ``[..., N, F]`` of the last projection, for
  giving one retrieved phase to several magnitudes (the ears: :mod:`avgs.acoustics.synthesis`).

Each iteration pads the waveform as :func:`avgs.dsp.stft` does (its ends reflected), so
the iterations are those of ``torch.stft`` / ``torch.istft`` to float rounding.
"""

from __future__ import annotations

import functools

import torch

from avgs.config import STFT, STFTConfig
from avgs.dsp.kernels import on_cpu, overlap_add, project_magnitudes, reflect_ends

GRIFFIN_LIM_BLOCK_FRAMES = 4096
"Frames per block of :func:`griffin_lim` on long inputs (about 24 s at AV-NeRF's hop): memory stays bounded."


class FrameGrid:
    """The STFT of :mod:`avgs.dsp` for ``n_frames`` frames, frame-major, on the padded signal.

    The padded signal ``z [..., (n_frames + R - 1) hop]`` (R = n_fft / hop frames overlap
    each sample) starts ``n_fft / 2`` samples before the waveform, as the centred STFT's
    padding does: frame t covers ``z[t hop : t hop + n_fft]``. :meth:`analyse` is the STFT
    of ``z`` ([..., N, F] complex), :meth:`synthesise` the least-squares inverse (Griffin
    and Lim's; ``torch.istft``'s), :meth:`waveform` cuts the waveform out of ``z``.
    Needs ``win_length == n_fft`` and a hop that divides it.
    """

    @staticmethod
    def covers(cfg: STFTConfig) -> bool:
        """Whether ``cfg`` is an STFT this class does: window as long as the FFT, a hop dividing it."""
        return cfg.win_length == cfg.n_fft and cfg.n_fft % cfg.hop_length == 0

    def __init__(self, n_frames: int, cfg: STFTConfig = STFT, dtype: torch.dtype = torch.float32,
                 device: torch.device | str = "cpu"):
        if not self.covers(cfg):
            raise ValueError(f"FrameGrid needs win_length == n_fft and a hop dividing n_fft, got {cfg}")
        self.cfg, self.n_frames = cfg, int(n_frames)
        n, hop = cfg.n_fft, cfg.hop_length
        self.overlap = n // hop  # R
        with torch.inference_mode(False):  # cached: usable under autograd too
            w = torch.hann_window(n, dtype=torch.float64)
            w2 = w.square().view(self.overlap, hop)  # [R, hop]
            interior = w2.sum(0)  # [hop]: the window-sum where all R frames overlap (periodic in hop)
            envelope = torch.zeros(self.n_frames + self.overlap - 1, hop, dtype=torch.float64)
            for q in range(self.overlap):
                envelope[q : q + self.n_frames] += w2[q]
            # Where fewer than R frames overlap (the first and last (R - 1) hops) the sum is smaller.
            correction = torch.where(envelope > 1e-12, interior / envelope.clamp_min(1e-12), torch.zeros(()))
            self.window = w.to(device=device, dtype=dtype)  # [n_fft]
            self._synthesis_window = (w.view(self.overlap, hop) / interior).to(device=device, dtype=dtype)  # [R, hop]
            flat = correction.reshape(-1)
            self._edge = (self.overlap - 1) * hop
            if 2 * self._edge >= flat.numel():  # a few frames: every sample is near an end
                self._edge = flat.numel()
            self._head = flat[: self._edge].to(device=device, dtype=dtype)
            self._tail = flat[-self._edge :].to(device=device, dtype=dtype)

    @property
    def padded_length(self) -> int:
        return (self.n_frames + self.overlap - 1) * self.cfg.hop_length

    def analyse(self, z: torch.Tensor) -> torch.Tensor:
        """STFT ``[..., N, F]`` complex of the padded signal ``z [..., padded_length]``."""
        frames = z.unfold(-1, self.cfg.n_fft, self.cfg.hop_length)  # [..., N, n_fft], a view
        return torch.fft.rfft(frames * self.window)

    def synthesise(self, spec: torch.Tensor) -> torch.Tensor:
        """Padded signal ``[..., padded_length]`` of a spectrogram ``[..., N, F]``: windowed
        overlap-add divided by the window-sum (``torch.istft``'s inverse). On the CPU the
        overlap-add and the ends' corrections are one loop (:func:`avgs.dsp.kernels.overlap_add`)."""
        lead, n, hop = spec.shape[:-2], self.n_frames, self.cfg.hop_length
        frames = torch.fft.irfft(spec, self.cfg.n_fft)  # [..., N, n_fft]
        if on_cpu(frames):
            return overlap_add(frames, self._synthesis_window, self._head, self._tail)
        frames = frames.view(*lead, n, self.overlap, hop)  # [..., N, R, hop]
        out = torch.zeros(*lead, n + self.overlap - 1, hop, dtype=frames.dtype, device=frames.device)
        for q in range(self.overlap):
            out[..., q : q + n, :].addcmul_(frames[..., q, :], self._synthesis_window[q])
        out = out.view(*lead, -1)
        out[..., : self._edge] *= self._head
        if self._edge < out.shape[-1]:
            out[..., -self._edge :] *= self._tail
        return out

    def pad_ends(self, z: torch.Tensor, length: int) -> torch.Tensor:
        """``z`` with its padding rewritten in place as :func:`avgs.dsp.stft` pads the waveform of
        ``length`` samples in it (reflected at both ends; zeros when it is too short to reflect)."""
        pad = self.cfg.n_fft // 2
        if on_cpu(z) and z.is_contiguous() and not z.is_complex() and not torch.is_grad_enabled():  # in place: no graph to keep
            return reflect_ends(z, pad, length)
        x = z[..., pad : pad + length]
        right = z.shape[-1] - (pad + length)  # <= pad: the last frame ends before the STFT's padding does
        if length > pad:
            z[..., :pad] = x[..., 1 : pad + 1].flip(-1)
            z[..., pad + length :] = x[..., length - 1 - right : length - 1].flip(-1)
        else:
            z[..., :pad] = 0.0
            z[..., pad + length :] = 0.0
        return z

    def waveform(self, z: torch.Tensor, length: int) -> torch.Tensor:
        """The waveform ``[..., length]`` in the padded signal ``z`` (after its ``n_fft / 2`` padding samples)."""
        pad = self.cfg.n_fft // 2
        return z[..., pad : pad + length]


@functools.lru_cache(maxsize=16)
def frame_grid(n_frames: int, cfg: STFTConfig = STFT, dtype: torch.dtype = torch.float32, device: str = "cpu") -> FrameGrid:
    """A cached :class:`FrameGrid` (renders of the same length share one)."""
    return FrameGrid(n_frames, cfg, dtype, device)


def _grid_for(spec: torch.Tensor, cfg: STFTConfig) -> FrameGrid:
    real = torch.float64 if spec.dtype == torch.complex128 else torch.float32
    return frame_grid(spec.shape[-2], cfg, real, str(spec.device))


def _check(iterations: int, momentum: float) -> None:
    if iterations < 0 or not 0.0 <= momentum < 1.0:
        raise ValueError(f"phase retrieval needs iterations >= 0 and momentum in [0, 1), got {iterations}, {momentum}")


def _iterate(grid: FrameGrid, start: torch.Tensor, target: torch.Tensor, length: int, iterations: int,
             momentum: float, phase: bool) -> torch.Tensor:
    """Fast Griffin-Lim on frame-major spectrograms of a waveform of ``length`` samples.

    ``start`` complex, ``target`` real (>= 0), both [..., N, F]. Returns, with ``phase``, the
    unit phasors [..., N, F] of the last consistent spectrogram (the phase the last projection
    keeps; 0 where it is 0), else the padded signal of the last projection
    [..., padded_length]. With no iterations: ``start``'s phase, or its padded signal.

    The inverse STFT is linear, so the momentum step ``c_k = p_k + m (p_k - p_(k-1))`` is
    taken on the projections' padded signals (a quarter of the numbers of a spectrogram),
    and the magnitude projection is one loop on the CPU (:func:`avgs.dsp.kernels.project_magnitudes`).
    """
    if iterations == 0:
        return project_magnitudes(start) if phase else grid.synthesise(start)

    def consistent(z: torch.Tensor) -> torch.Tensor:
        """The STFT [..., N, F] of the padded signal z (its padding rewritten as the STFT pads)."""
        return grid.analyse(grid.pad_ends(z, length))

    z, previous = grid.synthesise(start), None  # padded signals: the current guess's, the last projection's
    for _ in range(iterations - 1):
        projected = grid.synthesise(project_magnitudes(consistent(z), target))  # the target magnitudes, rebuilt's phase
        z = projected if previous is None else torch.lerp(previous, projected, 1.0 + momentum)
        previous = projected
    rebuilt = consistent(z)
    return project_magnitudes(rebuilt) if phase else grid.synthesise(project_magnitudes(rebuilt, target))


def retrieve_phase(target: torch.Tensor, start: torch.Tensor, length: int, iterations: int, momentum: float = 0.99,
                   cfg: STFTConfig = STFT) -> torch.Tensor:
    """Unit phasors ``[..., N, F]`` (frame-major) that fast Griffin-Lim retrieves for magnitudes
    ``target [..., N, F]`` of a waveform of ``length`` samples, from the first guess ``start``
    (complex, frame-major; its phase is what counts). With no iterations: ``start``'s phase."""
    _check(iterations, momentum)
    grid = _grid_for(start, cfg)
    return _iterate(grid, start, target, length, iterations, momentum, phase=True)


def griffin_lim(
    spec: torch.Tensor, target: torch.Tensor, length: int, iterations: int, momentum: float = 0.99,
    cfg: STFTConfig = STFT, block_frames: int = GRIFFIN_LIM_BLOCK_FRAMES,
) -> torch.Tensor:
    """A waveform ``[..., length]`` whose STFT magnitudes approach ``target``, starting from ``spec``.

    spec: ``[..., F, N]`` complex, the first guess (magnitudes ``target`` with some phase);
    target: ``[..., F, N]`` >= 0 (the layout of :func:`avgs.dsp.stft`). Each iteration
    takes the STFT of the current waveform, keeps its phase and restores the target
    magnitudes, extrapolated by ``momentum`` (0 gives Griffin and Lim 1984); the waveform
    returned is that of the last projection. ``iterations = 0`` is the iSTFT of ``spec``.

    One iteration mixes a frame only with the frames its window overlaps, so after K
    iterations a frame depends on its neighbours within ``K (n_fft / hop)`` frames. Long
    inputs are therefore done in blocks of ``block_frames``, each with that many frames of
    margin on both sides, which gives the same waveform as one pass to float rounding
    with memory bounded by the block.
    """
    from avgs import dsp

    _check(iterations, momentum)
    if iterations == 0:
        return dsp.istft(spec, length, cfg)
    n = spec.shape[-1]
    reach = -(-cfg.n_fft // cfg.hop_length)  # frames a window overlaps on each side, plus one
    margin = reach * (iterations + 2)
    if n <= block_frames + 2 * margin:
        return _griffin_lim(spec, target, length, iterations, momentum, cfg)
    hop = cfg.hop_length
    out = torch.empty(*spec.shape[:-2], length, dtype=target.dtype, device=spec.device)
    for s in range(0, n, block_frames):
        e = min(n, s + block_frames)
        a, b = max(0, s - margin), min(n, e + margin)
        piece_len = length - a * hop if b == n else (b - a - 1) * hop  # centred frames a..b-1 exactly
        y = _griffin_lim(spec[..., a:b], target[..., a:b], piece_len, iterations, momentum, cfg)
        lo, hi = s * hop, (length if e == n else e * hop)
        out[..., lo:hi] = y[..., lo - a * hop : hi - a * hop]
    return out


def _griffin_lim(spec, target, length: int, iterations: int, momentum: float, cfg: STFTConfig) -> torch.Tensor:
    if not FrameGrid.covers(cfg):
        return _griffin_lim_plain(spec, target, length, iterations, momentum, cfg)
    grid = _grid_for(spec.transpose(-1, -2), cfg)
    z = _iterate(grid, spec.transpose(-1, -2).contiguous(), target.transpose(-1, -2).contiguous(), length,
                 iterations, momentum, phase=False)
    return grid.waveform(z, length).contiguous()


def _griffin_lim_plain(spec, target, length: int, iterations: int, momentum: float, cfg: STFTConfig) -> torch.Tensor:
    """The same with ``torch.stft`` / ``torch.istft``, for STFT settings :class:`FrameGrid` does not cover."""
    from avgs import dsp

    tiny = torch.finfo(target.dtype).tiny
    previous = None
    for _ in range(iterations):
        rebuilt = dsp.stft(dsp.istft(spec, length, cfg), cfg)  # [..., F, N], a consistent spectrogram
        projected = target * rebuilt / rebuilt.abs().clamp_min(tiny)
        spec = projected if previous is None else projected + momentum * (projected - previous)
        previous = projected
    return dsp.istft(spec if previous is None else previous, length, cfg)
