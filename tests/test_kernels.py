"""The compiled loops of avgs.dsp.kernels against known values and against the torch expressions
they replace (which still run for tensors they do not take: CUDA, autograd)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from avgs.dsp.kernels import decayed_power, project_magnitudes


def _spec(shape, dtype, seed=0):
    g = torch.Generator().manual_seed(seed)
    real = torch.float64 if dtype == torch.complex128 else torch.float32
    return torch.complex(torch.randn(shape, generator=g, dtype=real), torch.randn(shape, generator=g, dtype=real))


def test_projection_of_known_values():
    spec = torch.tensor([[3 + 4j, 0j, -1e-3 + 0j, 5j]], dtype=torch.complex64)
    target = torch.tensor([[10.0, 2.0, 4.0, 0.0]])
    out = project_magnitudes(spec, target)
    torch.testing.assert_close(out, torch.tensor([[6 + 8j, 0j, -4 + 0j, 0j]], dtype=torch.complex64))
    torch.testing.assert_close(project_magnitudes(spec), torch.tensor([[0.6 + 0.8j, 0j, -1 + 0j, 1j]], dtype=torch.complex64))


@pytest.mark.parametrize("dtype", [torch.complex64, torch.complex128])
def test_projection_equals_the_torch_expression(dtype):
    """The loop and the torch expression it replaces (on tensors that need autograd, the
    expression runs): the same numbers to float rounding, batches and a broadcast target too."""
    spec = _spec((2, 3, 173, 257), dtype)
    spec[0, 1, 5, :7] = 0  # silent bins stay silent
    real = torch.float64 if dtype == torch.complex128 else torch.float32
    target = torch.rand(2, 3, 173, 257, dtype=real)
    eps = torch.finfo(real).eps
    for t in (target, target[0, 0, 0]):  # [..., F] and [F]
        loop = project_magnitudes(spec, t)
        expression = project_magnitudes(spec, t.clone().requires_grad_(True)).detach()
        torch.testing.assert_close(loop, expression, rtol=4 * eps, atol=0.0)
        assert bool((loop[0, 1, 5, :7] == 0).all())
    column = torch.rand(257, 1, dtype=real)  # as many numbers as a row, broadcast along the other axis
    square = _spec((257, 257), dtype, seed=1)
    torch.testing.assert_close(project_magnitudes(square, column),
                               project_magnitudes(square, column.clone().requires_grad_(True)).detach(), rtol=4 * eps, atol=0.0)
    unit = project_magnitudes(spec)
    nonzero = spec != 0
    torch.testing.assert_close(unit.abs()[nonzero], torch.ones_like(unit.abs()[nonzero]), rtol=4 * eps, atol=0.0)
    assert bool((unit[~nonzero] == 0).all())


def test_projection_takes_strided_input_and_leaves_it_alone():
    spec = _spec((257, 40), torch.complex64).transpose(0, 1)  # [40, 257], not contiguous
    before = spec.clone()
    out = project_magnitudes(spec, torch.ones(257))
    assert torch.equal(spec, before) and out.is_contiguous()
    torch.testing.assert_close(out.abs(), torch.ones(40, 257))


def _direct_sum(power: np.ndarray, w: np.ndarray) -> np.ndarray:
    """P[t] = sum_{k >= 1} w^k power[t - k], in float64, by its definition: [N, F]."""
    n = power.shape[0]
    out = np.zeros_like(power, dtype=np.float64)
    for t in range(n):
        for k in range(1, t + 1):
            out[t] += w ** k * power[t - k]
    return out


def test_decayed_power_is_the_decayed_sum_of_earlier_frames():
    rng = np.random.default_rng(1)
    power = rng.uniform(0, 3, size=(60, 5)).astype(np.float32)
    power[20:35] = 0.0  # a gap: the tail rings on
    w = np.array([0.0, 0.3, 0.9, 0.99, 1.0], dtype=np.float32)  # no tail ... no decay
    got, state = decayed_power(torch.from_numpy(power), torch.from_numpy(w))
    truth = _direct_sum(power.astype(np.float64), w.astype(np.float64))
    np.testing.assert_allclose(got.numpy(), truth, rtol=2e-6, atol=1e-6 * truth.max())
    np.testing.assert_allclose(state.numpy(), truth[-1] + power[-1], rtol=2e-6)  # P + |S|^2 of the last frame
    impulse = torch.zeros(8, 1)
    impulse[0] = 1.0
    np.testing.assert_allclose(decayed_power(impulse, torch.tensor([0.5]))[0][:, 0].numpy(),
                               [0, 0.5, 0.25, 0.125, 0.0625, 0.03125, 0.015625, 0.0078125])


def test_decayed_power_in_blocks_equals_one_pass_and_the_loop_it_replaces():
    """Carried from block to block by its state, the loop gives one pass's numbers; the torch
    loop (tensors needing autograd) the same."""
    g = torch.Generator().manual_seed(2)
    power = torch.rand(2, 300, 257, generator=g, dtype=torch.float64)
    w = torch.rand(257, generator=g, dtype=torch.float64) ** 0.1
    whole, end = decayed_power(power, w)
    pieces, state = [], None
    for a, b in ((0, 1), (1, 77), (77, 200), (200, 300)):
        p, state = decayed_power(power[:, a:b], w, state)
        pieces.append(p)
    assert torch.equal(torch.cat(pieces, dim=1), whole) and torch.equal(state, end)
    torch_loop, torch_end = decayed_power(power, w.clone().requires_grad_(True))
    torch.testing.assert_close(torch_loop.detach(), whole, rtol=1e-12, atol=0.0)
    torch.testing.assert_close(torch_end.detach(), end, rtol=1e-12, atol=0.0)


def test_decayed_power_leaves_the_state_it_was_given_alone():
    state = torch.ones(1, 3)
    decayed_power(torch.ones(1, 4, 3), torch.full((3,), 0.5), state)
    assert torch.equal(state, torch.ones(1, 3))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("length", [1, 100, 255, 300, 7000, 22050])
def test_overlap_add_and_padding_equal_the_torch_expressions(dtype, length):
    """FrameGrid's inverse STFT and its padding: the loops (overlap_add, reflect_ends) give the numbers
    of the torch expressions they replace bit for bit (those run under autograd), for a batch of
    signals, a few frames (every sample near an end) and many."""
    from avgs import dsp
    from avgs.dsp.phase_retrieval import FrameGrid

    n = dsp.n_frames(length)
    grid = FrameGrid(n, dtype=dtype)
    complex_dtype = torch.complex128 if dtype == torch.float64 else torch.complex64
    spec = _spec((2, 3, n, 257), complex_dtype, seed=length)
    loop = grid.synthesise(spec)
    expression = grid.synthesise(spec.clone().requires_grad_(True)).detach()
    assert loop.shape == (2, 3, grid.padded_length) and torch.equal(loop, expression)
    with torch.no_grad():
        padded = grid.pad_ends(loop.clone(), length)  # the loop: in place, no graph
    reference = grid.pad_ends(loop.clone().requires_grad_(True) * 1.0, length).detach()
    assert torch.equal(padded, reference)
    assert torch.equal(grid.waveform(padded, length), grid.waveform(loop, length))  # the waveform itself untouched
