"""Phase retrieval (avgs.dsp.phase_retrieval): the frame-major STFT pair against torch's, and
fast Griffin-Lim's convergence, blocks and settings."""

import numpy as np
import pytest
import torch

from avgs import dsp
from avgs.config import STFT, STFTConfig
from avgs.dsp.phase_retrieval import FrameGrid, _griffin_lim_plain, griffin_lim, retrieve_phase


def _noise(shape, seed):
    return torch.from_numpy(np.random.default_rng(seed).standard_normal(shape))


@pytest.mark.parametrize("length", [1, 100, 255, 300, 700, 7000, 22050, 22050 + 77])
def test_frame_grid_is_the_stft_and_its_inverse(length):
    """analyse() of the padded signal is dsp.stft, frame-major; synthesise() of any
    spectrogram, even an inconsistent one, is torch.istft's least-squares inverse; pad_ends
    pads as dsp.stft does (reflected, or zeros below half a window)."""
    x = _noise((2, length), length)  # float64
    spec = dsp.stft(x)  # [2, F, N]
    grid = FrameGrid(spec.shape[-1], dtype=torch.float64)
    padded = grid.pad_ends(torch.nn.functional.pad(x, (256, grid.padded_length - 256 - length)), length)
    assert torch.allclose(grid.analyse(padded), spec.transpose(-1, -2), atol=1e-9)
    assert torch.allclose(grid.waveform(grid.synthesise(spec.transpose(-1, -2)), length), x, atol=1e-9)
    wild = spec * torch.exp(1j * _noise(spec.shape, 1))  # not the STFT of any signal
    ours = grid.waveform(grid.synthesise(wild.transpose(-1, -2).contiguous()), length)
    assert torch.allclose(ours, dsp.istft(wild, length), atol=1e-9)


def test_frame_grid_refuses_a_window_shorter_than_the_fft():
    with pytest.raises(ValueError, match="win_length == n_fft"):
        FrameGrid(10, STFTConfig(win_length=256))


def _inconsistency(y: torch.Tensor, target: torch.Tensor) -> float:
    return float(torch.linalg.vector_norm(dsp.magnitude(y) - target) / torch.linalg.vector_norm(target))


def test_griffin_lim_keeps_a_consistent_spectrogram():
    """A true STFT is a fixed point: its own magnitudes and phase give the signal back."""
    x = _noise((2, 7000), 0).float()
    spec = dsp.stft(x)
    y = griffin_lim(spec, spec.abs(), 7000, iterations=8)
    assert torch.allclose(y, x, atol=1e-4)


def test_griffin_lim_brings_the_waveform_to_the_target_magnitudes():
    """Magnitudes reshaped in time (not a consistent STFT) with the original phase: each
    round of iterations brings the waveform's own magnitudes closer to the target, as far
    as torch.stft / torch.istft's iterations do."""
    x = _noise(22050, 1).float()
    spec = dsp.stft(x)
    n = spec.shape[-1]
    target = spec.abs() * (1.0 + 0.8 * torch.sin(torch.arange(n) / 3.0))  # [F, N], a tremolo of 6 frames
    start = target * spec / spec.abs()
    errors = [_inconsistency(griffin_lim(start, target, 22050, k), target) for k in (0, 2, 8, 32)]
    assert errors[0] > 0.05  # the plain iSTFT is 6-7 % off its target here
    assert errors[0] > errors[1] > errors[2] > errors[3]
    assert errors[2] < 0.85 * errors[0]
    plain = [_inconsistency(griffin_lim(start, target, 22050, 8, momentum=m), target) for m in (0.0, 0.99)]
    assert plain[1] < plain[0]  # momentum (fast Griffin-Lim) converges faster
    torch_stft = _griffin_lim_plain(start, target, 22050, 8, 0.99, STFT)  # the same with torch.stft / istft
    assert torch.allclose(griffin_lim(start, target, 22050, 8), torch_stft, atol=1e-4 * float(torch_stft.abs().max()))


@pytest.mark.parametrize("length", [300 * 128, 66167])
def test_griffin_lim_in_blocks_equals_one_pass(length):
    """Blocks with a margin of the iterations' reach give the one-pass waveform."""
    x = _noise((2, length), 2).float()
    spec = dsp.stft(x)
    target = spec.abs() * torch.linspace(0.2, 1.5, spec.shape[-2])[:, None]
    start = target * torch.exp(1j * _noise(spec.shape, 3).float())
    one = griffin_lim(start, target, length, 8, block_frames=10**9)
    for block in (16, 70):
        blocked = griffin_lim(start, target, length, 8, block_frames=block)
        assert torch.allclose(blocked, one, atol=1e-5 * float(one.abs().max()))
    assert torch.equal(griffin_lim(start, target, length, 0), dsp.istft(start, length))


def test_retrieved_phase_is_the_last_projection():
    """retrieve_phase gives the phase of the waveform griffin_lim returns: the target
    magnitudes with it, inverted, are that waveform."""
    x = _noise(9000, 4).float()
    spec = dsp.stft(x)
    target = spec.abs() * torch.linspace(1.5, 0.3, spec.shape[-2])[:, None]
    start = target * torch.exp(1j * _noise(spec.shape, 5).float())
    phase = retrieve_phase(target.T.contiguous(), start.T.contiguous(), 9000, 6)  # [N, F]
    assert torch.allclose(phase.abs(), torch.ones(()), atol=1e-5)
    y = dsp.istft((target.T * phase).T, 9000)
    assert torch.allclose(y, griffin_lim(start, target, 9000, 6), atol=1e-5 * float(y.abs().max()))
    assert torch.allclose(retrieve_phase(target.T, start.T, 9000, 0), (start / start.abs()).T, atol=1e-6)


def test_phase_retrieval_rejects_bad_settings():
    spec = dsp.stft(torch.zeros(1000))
    for iterations, momentum in ((-1, 0.5), (4, 1.0), (4, -0.1)):
        with pytest.raises(ValueError, match="iterations >= 0 and momentum in"):
            griffin_lim(spec, spec.abs(), 1000, iterations, momentum)
        with pytest.raises(ValueError, match="iterations >= 0 and momentum in"):
            retrieve_phase(spec.abs().T, spec.T, 1000, iterations, momentum)
