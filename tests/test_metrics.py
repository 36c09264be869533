"""Each metric against signals whose answer is known in closed form, and its degenerate cases."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from avgs.evaluation import metrics

FS = 22050


# -- MAG and ENV --------------------------------------------------------------------------

# A cosine exactly on STFT bin k0 over 43 whole windows plus one sample: every centred,
# reflect-padded frame sees the same periodic cosine, and the periodic Hann window's DFT
# has three non-zero bins (N/2 and two of -N/4). So each frame's one-sided spectrum is
# |X| = N/4 at k0 and N/8 at k0 +- 1, zero elsewhere: mean |X|^2 = (128^2 + 2 * 64^2) / 257.
N_FFT, K0 = 512, 40
T_BIN = 43 * N_FFT + 1
MEAN_POWER = (128.0**2 + 2 * 64.0**2) / 257


def on_bin_cosine(amplitude=1.0):
    n = np.arange(T_BIN)
    return amplitude * np.cos(2 * np.pi * K0 * n / N_FFT)


def test_mag_of_a_signal_against_itself_is_zero():
    x = np.random.default_rng(0).standard_normal((2, FS)).astype(np.float32)
    assert metrics.mag(x, x) == 0.0
    assert metrics.env(x, x) == 0.0


@pytest.mark.parametrize("gain", [0.0, 0.5, 2.0, 3.0])
def test_mag_of_a_scaled_copy_matches_the_closed_form(gain):
    gt = np.stack([on_bin_cosine(1.0), on_bin_cosine(0.5)])  # [2, T]
    # 2 * mean over both channels of (g - 1)^2 a_c^2 |X|^2 = (g - 1)^2 (1 + 0.25) * MEAN_POWER
    expected = (gain - 1) ** 2 * (1.0 + 0.25) * MEAN_POWER
    assert metrics.mag(gain * gt, gt) == pytest.approx(expected, rel=1e-9)


def test_mag_accepts_torch_and_averages_over_clips():
    gt = np.stack([on_bin_cosine(), on_bin_cosine()])
    batch_pred = np.stack([2 * gt, 3 * gt])  # [B=2, 2, T]
    batch_gt = np.stack([gt, gt])
    expected = 0.5 * (1 + 4) * 2 * MEAN_POWER
    assert metrics.mag(torch.from_numpy(batch_pred), torch.from_numpy(batch_gt)) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("gain", [0.0, 0.25, 1.7])
def test_env_of_a_scaled_copy_matches_the_closed_form(gain):
    # 100 whole periods in the window: the Hilbert envelope of a*cos is exactly a.
    n = np.arange(FS)
    tone = np.cos(2 * np.pi * 100 * n / FS)
    gt = np.stack([tone, 0.5 * tone])
    # sum over channels of RMSE = |g - 1| * (1 + 0.5)
    assert metrics.env(gain * gt, gt) == pytest.approx(abs(gain - 1) * 1.5, rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(metrics.envelope(tone), 1.0, atol=1e-9)


def test_mag_and_env_reject_mismatched_shapes():
    with pytest.raises(ValueError, match="same shape"):
        metrics.mag(np.zeros((2, 100)), np.zeros((2, 101)))
    with pytest.raises(ValueError, match=r"\[\.\.\., 2, T\]"):
        metrics.env(np.zeros((3, 100)), np.zeros((3, 100)))


@pytest.mark.parametrize("metric", [metrics.mag, metrics.env, metrics.ild_error, lambda p, g: metrics.ild(p)])
def test_empty_waveforms_are_refused_by_name(metric):
    with pytest.raises(ValueError, match=r"T >= 1, got \(2, 0\)"):
        metric(np.zeros((2, 0)), np.zeros((2, 0)))


def on_bin(k, amplitude=1.0):
    n = np.arange(T_BIN)
    return amplitude * np.cos(2 * np.pi * k * n / N_FFT)


def test_ild_counts_only_the_band_above_1500_hz():
    # bin 70 = 3.0 kHz carries 2:1 (+6.02 dB); bin 20 = 861 Hz (and its window leakage into
    # bins 19-21) lies below the band and would say the opposite side
    left = on_bin(70, 1.0) + on_bin(20, 0.1)
    right = on_bin(70, 0.5) + on_bin(20, 5.0)
    x = np.stack([left, right])
    assert float(metrics.ild(x)) == pytest.approx(20 * math.log10(2.0), abs=1e-9)
    assert metrics.ild_error(x[::-1], x) == pytest.approx(2 * 20 * math.log10(2.0), abs=1e-9)
    assert metrics.ild_error(3.0 * x, x) == pytest.approx(0.0, abs=1e-9)  # a common gain keeps the ILD
    batch = np.stack([x, x[::-1]])  # [2 clips, 2, T]
    np.testing.assert_allclose(metrics.ild(batch), [6.0206, -6.0206], atol=1e-4)


def test_ild_of_silence_is_defined():
    silent = np.zeros((2, 4000))
    one_ear = np.stack([np.zeros(T_BIN), on_bin(70)])
    assert float(metrics.ild(silent)) == 0.0
    assert float(metrics.ild(one_ear)) == -metrics.ILD_LIMIT_DB
    assert metrics.ild_error(np.full((2, 4000), np.nan), silent) == math.inf
    with pytest.raises(ValueError, match=r"\[\.\.\., 2, T\]"):
        metrics.ild(np.zeros((3, 100)))


# -- T60, C50, EDT -----------------------------------------------------------------------


def decaying_noise(rt60: float, seconds: float, seed: int = 0) -> np.ndarray:
    """White noise under an exponential envelope that falls 60 dB in ``rt60`` seconds."""
    t = np.arange(int(seconds * FS)) / FS
    return np.random.default_rng(seed).standard_normal(t.size) * 10 ** (-3 * t / rt60)


@pytest.mark.parametrize("rt60", [0.25, 0.5, 0.9])
def test_rt60_of_decaying_noise_within_3_percent(rt60):
    for seed in range(3):
        measured = metrics.rt60(decaying_noise(rt60, max(1.0, 2 * rt60), seed), FS)
        assert measured == pytest.approx(rt60, rel=0.03)


def test_t60_error_is_the_relative_difference_in_percent():
    gt = np.stack([decaying_noise(0.5, 1.0, 1), decaying_noise(0.5, 1.0, 2)])
    pred = np.stack([decaying_noise(0.6, 1.0, 3), decaying_noise(0.4, 1.0, 4)])
    expected = np.mean(
        [abs(metrics.rt60(p, FS) - metrics.rt60(g, FS)) / metrics.rt60(g, FS) * 100 for p, g in zip(pred, gt)]
    )
    assert metrics.t60_error(pred, gt) == pytest.approx(expected)
    assert 15 < metrics.t60_error(pred, gt) < 25  # ~20 % either way
    assert metrics.t60_error(gt, gt) == 0.0


def test_c50_splits_at_int_005_fs_plus_1():
    split = int(0.05 * FS + 1)
    assert split == 1103
    h = np.zeros(4000)
    h[split - 1], h[split] = math.sqrt(10.0), 1.0  # the last early and the first late sample
    assert metrics.c50(h, FS) == pytest.approx(10.0)


@pytest.mark.parametrize("c50_db", [-6.0, 0.0, 4.5, 20.0])
def test_c50_of_an_ir_with_a_chosen_energy_split(c50_db):
    rng = np.random.default_rng(7)
    split = int(0.05 * FS + 1)
    early = rng.standard_normal(split) * np.exp(-np.arange(split) / 300)
    late = rng.standard_normal(FS) * np.exp(-np.arange(FS) / 3000)
    late *= math.sqrt(np.sum(early**2) / np.sum(late**2) / 10 ** (c50_db / 10))
    h = np.concatenate([early, late])
    assert metrics.c50(h, FS) == pytest.approx(c50_db, abs=1e-9)
    assert metrics.c50_error(h, h) == 0.0
    h2 = np.concatenate([early, 2 * late])  # 4x the late energy: 10 log10(4) dB less clear
    assert metrics.c50_error(h2, h) == pytest.approx(10 * math.log10(4), abs=1e-9)


@pytest.mark.parametrize("edt_s", [0.1, 0.6, 1.2])
def test_edt_of_an_exponential_decay(edt_s):
    # h = exp(-t / tau): the Schroeder curve falls 10 dB at t = tau ln(10) / 2, so EDT = 3 tau ln 10.
    tau = edt_s / (3 * math.log(10))
    t = np.arange(int(max(1.0, 2 * edt_s) * FS)) / FS
    h = np.exp(-t / tau)
    assert metrics.edt(h, FS) == pytest.approx(edt_s, abs=6 / FS)
    h_other = np.exp(-t / (1.5 * tau))
    assert metrics.edt_error(h_other, h) == pytest.approx(0.5 * edt_s, abs=12 / FS)


# -- degenerate input: defined values, no exceptions, no warnings ---------------------------


@pytest.fixture
def no_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def test_all_zero_responses(no_warnings):
    z = np.zeros(FS)
    ir = decaying_noise(0.5, 1.0)
    assert metrics.rt60(z) is None
    assert metrics.t60_error(z, ir) == metrics.FAILED_T60_ERROR
    assert metrics.t60_error(ir, z) == metrics.FAILED_T60_ERROR
    assert metrics.c50(z) == 0.0 and metrics.edt(z) == 0.0
    assert metrics.c50_error(z, z) == 0.0 and metrics.edt_error(z, z) == 0.0
    assert metrics.mag(np.zeros((2, FS)), np.zeros((2, FS))) == 0.0
    assert metrics.env(np.zeros((2, FS)), np.zeros((2, FS))) == 0.0


def test_no_late_or_no_early_energy(no_warnings):
    h = np.zeros(FS)
    h[:100] = 1.0
    assert metrics.c50(h) == metrics.C50_LIMIT_DB
    h_late = np.zeros(FS)
    h_late[5000] = 1.0
    assert metrics.c50(h_late) == -metrics.C50_LIMIT_DB
    assert metrics.c50_error(h, h_late) == 2 * metrics.C50_LIMIT_DB


def test_curves_that_never_fall_far_enough(no_warnings):
    rising = np.r_[np.full(5, 0.1), 1.0]  # stops while loud: never 10 dB down before its last sample
    assert metrics.edt(rising, FS) == pytest.approx(6 * 6 / FS)
    flat = np.ones(2000)  # 10 dB down when 10 % of the energy is left
    assert metrics.edt(flat, FS) == pytest.approx(6 * 1801 / FS)
    assert metrics.edt(np.array([1.0, 0.0, 0.0]), FS) == pytest.approx(6 / FS)
    assert metrics.rt60(np.array([1.0])) is None
    assert metrics.rt60(np.r_[np.ones(3), np.zeros(10)]) is None  # falls under 5 dB only at its end
    assert metrics.rt60(rising) is None  # its curve never falls 5 dB
    assert metrics.t60_error(rising, rising) == metrics.FAILED_T60_ERROR


def test_nan_and_inf(no_warnings):
    bad = np.full((2, 1000), np.nan)
    ok = np.random.default_rng(0).standard_normal((2, 1000))
    assert metrics.mag(bad, ok) == math.inf and metrics.mag(ok, bad) == math.inf
    inf = ok.copy()
    inf[0, 3] = np.inf
    assert metrics.env(inf, ok) == math.inf
    assert metrics.rt60(bad[0]) is None
    assert metrics.t60_error(bad, ok) == metrics.FAILED_T60_ERROR
    assert metrics.c50(bad[0]) == 0.0 and metrics.edt(bad[0]) == 0.0
    assert math.isfinite(metrics.c50_error(bad, ok)) and math.isfinite(metrics.edt_error(bad, ok))
