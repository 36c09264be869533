"""Spatial cues (avgs.evaluation.spatial; docs/design.md, "Spatial cues"): ITD by GCC-PHAT,
onset, early ILD and lateralisation agreement on signals with known delays and levels, their
degenerate inputs, and the new columns of ``avgs eval`` for both tasks."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
import torch

from avgs.cli import main
from avgs.data.rwavs import RWAVSScene
from avgs.evaluation import binaural as evaluate, impulse_response as evaluate_rir, spatial

FS = 22050
US = 1e-6  # one microsecond in seconds


def noise(n: int = FS, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal(n)


def delayed(x: np.ndarray, samples: float) -> np.ndarray:
    """``x`` delayed by a (fractional) number of samples: a linear phase shift of its FFT (circular)."""
    f = np.fft.rfftfreq(len(x))
    return np.fft.irfft(np.fft.rfft(x) * np.exp(-2j * np.pi * f * samples), len(x))


def right_delayed(samples: float, seed: int = 0) -> np.ndarray:
    """``[2, FS]`` white noise whose right ear hears the left's signal ``samples`` later."""
    x = noise(seed=seed)
    return np.stack([x, delayed(x, samples)])


# -- ITD by GCC-PHAT -------------------------------------------------------------------------


@pytest.mark.parametrize("k", [3, -3, 8, -8, 14, -14])
def test_itd_of_a_whole_sample_delay_is_negative_when_the_left_ear_leads(k):
    """Right ear delayed by k > 0 samples: the left ear leads and the ITD is -k / fs."""
    x = noise(seed=abs(k))
    right = np.concatenate([np.zeros(k), x[: len(x) - k]]) if k >= 0 else np.concatenate([x[-k:], np.zeros(-k)])
    got = spatial.itd(np.stack([x, right]), FS)
    assert got == pytest.approx(-k / FS, abs=10 * US)
    assert (got < 0) == (k > 0)


@pytest.mark.parametrize("k", [5.5, -5.5, 2.25, 11.7])
def test_itd_of_a_fractional_delay_is_refined_by_the_parabola(k):
    got = spatial.itd(right_delayed(k), FS)
    assert got == pytest.approx(-k / FS, abs=10 * US)
    assert abs(got * FS - round(got * FS)) > 0.1 or k == round(k)  # not snapped to a whole sample


def test_swapped_ears_flip_the_sign():
    x = right_delayed(8)
    assert spatial.itd(x[::-1], FS) == pytest.approx(-spatial.itd(x, FS), abs=1e-9)
    assert spatial.itd(x[::-1], FS) == pytest.approx(8 / FS, abs=10 * US)


def test_a_delay_beyond_one_millisecond_is_not_found_outside_it():
    for k in (30, -30, 60):  # 1.36 ms, 2.7 ms
        got = spatial.itd(right_delayed(k), FS)
        assert abs(got) <= spatial.ITD_MAX_S
        assert abs(got - (-k / FS)) > 0.3e-3


def test_itd_is_the_same_for_torch_float32_and_any_scale():
    x = right_delayed(5.5)
    ref = spatial.itd(x, FS)
    assert spatial.itd(torch.from_numpy(x.astype(np.float32)), FS) == pytest.approx(ref, abs=1 * US)
    assert spatial.itd(np.stack([1e-3 * x[0], 40.0 * x[1]]), FS) == pytest.approx(ref, abs=1e-12)
    with pytest.raises(ValueError, match=r"expected a binaural signal \[2, T\]"):
        spatial.itd(x[:1], FS)


# -- a response: onset, direct-sound ITD, early ILD --------------------------------------------


def impulse_pair(n0: int, k: int, length: int = 4096, seed: int = 0) -> np.ndarray:
    """Left impulse 1 at ``n0``, right 0.5 at ``n0 + k``, and a decaying noise tail after both
    whose energy in the first 5 ms is 30 dB below the right ear's direct sound."""
    h = np.zeros((2, length))
    h[0, n0] = 1.0
    h[1, n0 + k] = 0.5
    start = max(n0, n0 + k) + 1
    n = np.arange(length)
    std = math.sqrt(0.25 * 1e-3 / spatial.early_samples(FS))
    tail = np.random.default_rng(seed).standard_normal((2, length)) * std * np.exp(-(n - start) / (0.1 * FS))
    return h + tail * (n >= start)


@pytest.mark.parametrize("k", [3, 8, 14, -5, -14, 0])
def test_a_delayed_impulse_pair_gives_its_onset_itd_and_ild(k):
    h = impulse_pair(200, k, seed=k + 20)
    assert spatial.onset(h) == min(200, 200 + k)  # the earlier of the two ears
    assert spatial.response_itd(h, FS) == pytest.approx(-k / FS, abs=10 * US)
    assert spatial.early_ild(h, FS) == pytest.approx(20 * math.log10(2), abs=0.1)  # 6.02 dB, left louder
    assert spatial.early_ild(h[::-1], FS) == pytest.approx(-20 * math.log10(2), abs=0.1)
    assert spatial.response_itd(h[::-1], FS) == pytest.approx(k / FS, abs=10 * US)


def test_onset_is_minus_20_db_of_the_peak():
    h = np.zeros((2, 100))
    h[1, 10] = 0.099  # below 0.1 of the peak
    h[1, 20] = 0.1  # exactly -20 dB: the onset
    h[0, 30] = -1.0  # the peak (its magnitude counts)
    assert spatial.onset(h) == 20
    assert spatial.early(h, FS).shape == (2, 110)  # round(5 ms x 22050 Hz)


def test_response_errors_of_known_pairs():
    gt, pred = impulse_pair(200, 8), impulse_pair(211, -3, seed=1)  # right ear first, at 208: onset 8 samples later
    errors = spatial.response_errors(pred, gt, FS)
    assert set(errors) == set(spatial.RESPONSE_METRICS)
    assert errors["onset_ms"] == pytest.approx(1000 * 8 / FS)
    assert errors["itd_us"] == pytest.approx(1e6 * 11 / FS, abs=10)  # -8 / fs against +3 / fs
    assert errors["ild_db"] == pytest.approx(0.0, abs=0.1)
    assert spatial.response_errors(gt, gt, FS) == {"onset_ms": 0.0, "itd_us": 0.0, "ild_db": 0.0}
    # through the task's own per-response errors
    assert {k: v for k, v in evaluate_rir.response_errors(gt, gt, FS).items() if k in errors} == dict.fromkeys(errors, 0.0)


def test_a_short_response_or_a_late_onset_is_zero_padded():
    h = impulse_pair(200, 8)
    late = h[:, : 200 + 20]  # the onset 20 samples before the end: the right ear's impulse is still inside
    assert spatial.early(late, FS).shape == (2, 110)
    assert spatial.response_itd(late, FS) == pytest.approx(-8 / FS, abs=10 * US)
    short = np.zeros((2, 12))
    short[0, 2], short[1, 5] = 1.0, 1.0
    assert spatial.onset(short) == 2 and spatial.response_itd(short, FS) == pytest.approx(-3 / FS, abs=10 * US)
    assert spatial.early_ild(short, FS) == pytest.approx(0.0)


# -- lateralisation agreement ----------------------------------------------------------------------


def test_lateralisation_counts_eligible_items_with_the_right_side():
    true = np.array([200, -300, 150, -150, 100, 149.9, 600, 400]) * US
    pred = np.array([60, -50, 49.9, 100, 500, -300, 0, -700]) * US
    # eligible (|true| >= 150 us): 200, -300, 150, -150, 600, 400 -> 6
    # agree (same sign, |pred| >= 50 us): 60 and -50 -> 2 (49.9 too small, 100 the wrong side, 0 none, -700 wrong)
    assert spatial.lateralisation(true, pred) == pytest.approx(100 * 2 / 6)
    assert spatial.lateralisation(true[:2], pred[:2]) == 100.0
    assert spatial.lateralisation([-150 * US], [50 * US]) == 0.0
    assert spatial.lateralisation([150e-6, -150e-6], [50e-6, -50e-6]) == 100.0  # the thresholds themselves count
    assert spatial.lateralisation([100 * US, -149 * US, 0.0], [500 * US, -500 * US, 0.0]) is None
    assert spatial.lateralisation([], []) is None
    assert spatial.lateralisation([300 * US, np.nan], [np.inf, 300 * US]) == 0.0  # non-finite: 0 s
    with pytest.raises(ValueError, match="2 true and 1 predicted"):
        spatial.lateralisation([1.0, 2.0], [1.0])


# -- degenerate inputs: defined values, no warnings ------------------------------------------------


def test_degenerate_inputs_give_the_documented_values_without_warnings():
    x = right_delayed(8)
    silent_left = x.copy()
    silent_left[0] = 0.0
    nan = x.copy()
    nan[1, 100] = np.nan
    inf = x.copy()
    inf[0, 5] = np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for bad in (np.zeros((2, FS)), silent_left, silent_left[::-1], nan, inf, np.zeros((2, 1)), np.zeros((2, 0)), x[:, :1]):
            assert spatial.itd(bad, FS) == 0.0
        assert spatial.itd(1e300 * x, FS) == pytest.approx(-8 / FS, abs=10 * US)  # no overflow
        assert spatial.itd(1e-300 * x, FS) == pytest.approx(-8 / FS, abs=10 * US)
        # responses
        h = impulse_pair(200, 8)
        h_nan = h.copy()
        h_nan[0, 3000] = np.nan
        right_only = h.copy()
        right_only[0] = 0.0
        assert spatial.onset(np.zeros((2, 500))) == 500 and spatial.onset(h_nan) == 4096
        assert spatial.onset(np.zeros((2, 0))) == 0
        assert spatial.early_ild(np.zeros((2, 500)), FS) == 0.0 and spatial.early_ild(h_nan, FS) == 0.0
        assert spatial.early_ild(right_only, FS) == -spatial.ILD_LIMIT_DB == -60.0
        assert spatial.early_ild(right_only[::-1], FS) == 60.0
        assert spatial.early_ild(1e300 * h, FS) == pytest.approx(6.02, abs=0.1)
        assert spatial.response_itd(np.zeros((2, 500)), FS) == 0.0 and spatial.response_itd(right_only, FS) == 0.0
        # errors: the worst case for a non-finite prediction or truth, finite for silence
        worst = {"onset_ms": 1000 * 4096 / FS, "itd_us": 2000.0, "ild_db": 120.0}
        assert spatial.response_errors(h_nan, h, FS) == worst and spatial.response_errors(h, h_nan, FS) == worst
        silent = spatial.response_errors(np.zeros_like(h), h, FS)
        assert silent["onset_ms"] == pytest.approx(1000 * (4096 - 200) / FS)  # the sound never arrives
        assert silent["itd_us"] == pytest.approx(1e6 * 8 / FS, abs=10) and silent["ild_db"] == pytest.approx(6.02, abs=0.1)
        assert spatial.clip_itds(nan, x, FS) == (0.0, pytest.approx(-8 / FS, abs=10 * US), 2000.0)
        assert spatial.clip_itd_error_us(np.zeros_like(x), x, FS) == pytest.approx(1e6 * 8 / FS, abs=10)
        errors = evaluate_rir.response_errors(h_nan, h, FS)
        assert all(math.isfinite(v) for v in errors.values())
        assert spatial.median([]) is None and spatial.median([3.0, 1.0, 100.0]) == 3.0


# -- the report: aggregation and table --------------------------------------------------------------


def test_aggregation_skips_none_and_the_table_says_n_a():
    scenes = {"a_1": {"ITD": 100.0, "LAT": None}, "a_2": {"ITD": 300.0, "LAT": 50.0}, "b": {"ITD": 10.0, "LAT": None}}
    out = evaluate.aggregate(scenes, {"a_1": "a", "a_2": "a", "b": "b"})
    assert out["environments"] == {"a": {"ITD": 200.0, "LAT": 50.0}, "b": {"ITD": 10.0, "LAT": None}}
    assert out["overall"] == {"ITD": 105.0, "LAT": 50.0}  # the mean of the environments' values that exist
    report = {"split": "val", "environments": {"a_1": "a", "a_2": "a", "b": "b"}, "clips": {"a_1": 1, "a_2": 1, "b": 1},
              "methods": {"m": out | {"scenes": scenes}}}
    table = evaluate.format_report(report, columns=(("ITD", 8, ".1f"), ("LAT", 7, ".1f")))
    rows = {line.split()[1]: line.split()[2:] for line in table.splitlines() if line.startswith("scene")}
    assert rows["a_1"] == ["100.0", "n/a"] and rows["a_2"] == ["300.0", "50.0"] and rows["b"] == ["10.0", "n/a"]
    assert table.splitlines()[-1].split() == ["overall", "105.0", "50.0"]
    json.dumps(report, allow_nan=False)  # None is null; nothing is NaN


# -- avgs eval end to end ---------------------------------------------------------------------


def test_binaural_eval_reports_itd_and_lat(quick_scene, tmp_path, capsys):
    out = tmp_path / "scores.json"
    assert main(["eval", str(quick_scene.parent), "--json", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    print(printed)
    header = printed.splitlines()[2].split()
    assert header[:6] == ["MAG", "ENV", "ILD", "MAGp", "ITD", "LAT"]
    report = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in the report"))
    scene = RWAVSScene(quick_scene)
    true = [spatial.itd(c.binaural, scene.sample_rate) for c in scene.val]
    eligible = any(abs(t) >= spatial.LAT_TRUE_MIN_S for t in true)
    for name, result in report["methods"].items():
        for level in (result["scenes"][scene.name], result["overall"]):
            assert list(level) == list(evaluate.METRICS) == ["MAG", "ENV", "ILD", "MAGp", "ITD", "LAT"]
            assert math.isfinite(level["ITD"]) and level["ITD"] >= 0
            assert (level["LAT"] is None) == (not eligible)
            assert level["LAT"] is None or 0.0 <= level["LAT"] <= 100.0
    # Mono-Mono: the source in both ears, ITD 0: its error is the true |ITD|, and it never lateralises
    mono = report["methods"]["mono-mono"]["scenes"][scene.name]
    assert mono["ITD"] == pytest.approx(1e6 * np.median(np.abs(true)), rel=1e-9)
    if eligible:
        assert mono["LAT"] == 0.0
    # the truth itself scores ITD 0 and, with an eligible clip, LAT 100; the ears swapped, LAT 0
    oracle = evaluate.score_scene(lambda c, s: c.binaural, scene, progress=False)
    assert oracle["ITD"] == 0.0 and oracle["LAT"] == (100.0 if eligible else None)
    swapped = evaluate.score_scene(lambda c, s: c.binaural[::-1], scene, progress=False)
    assert swapped["ITD"] == pytest.approx(2e6 * np.median(np.abs(true)), abs=1e-6)
    assert swapped["LAT"] == (0.0 if eligible else None)


def test_rir_eval_reports_onset_itd_ild_and_lat(quick_rir_scene, tmp_path, capsys):
    out = tmp_path / "rir.json"
    argv = ["eval", "--task", "rir", str(quick_rir_scene.parent), "--methods", "nearest,linear", "--split", "both",
            "--json", str(out), "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    print(printed)
    assert "onset_ms" in printed and "lat_pct" in printed
    report = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in the report"))
    keys = ["t60_pct", "c50_db", "edt_s", "onset_ms", "itd_us", "ild_db", "lat_pct"]
    for split in ("val", "heldout"):
        for name in ("nearest", "linear"):
            overall = report["splits"][split]["methods"][name]["overall"]
            assert list(overall) == keys
            assert all(math.isfinite(overall[k]) and overall[k] >= 0 for k in keys[:-1])
            assert overall["lat_pct"] is None or 0.0 <= overall["lat_pct"] <= 100.0
    # the spatial medians are those of the per-response errors
    from avgs.data.rir import RIRScene
    from avgs.evaluation.interpolation import RIR_BASELINES

    scene = RIRScene(quick_rir_scene)
    train, query = scene.responses("train"), scene.responses("val")
    pred = RIR_BASELINES["nearest"](train, query)
    errors = [spatial.response_errors(p, g, scene.sample_rate) for p, g in zip(pred, query.rir)]
    got = report["splits"]["val"]["methods"]["nearest"]["scenes"][scene.name]
    for k in spatial.RESPONSE_METRICS:
        assert got[k] == pytest.approx(float(np.median([e[k] for e in errors])))
    true = [spatial.response_itd(g, scene.sample_rate) for g in query.rir]
    assert got["lat_pct"] == spatial.lateralisation(true, [spatial.response_itd(p, scene.sample_rate) for p in pred])
    # a scene's training responses predicted by interpolation are the responses themselves
    scores = evaluate_rir.score_scene(RIR_BASELINES["nearest"], scene, "train", progress=False)
    eligible = any(abs(spatial.response_itd(g, scene.sample_rate)) >= spatial.LAT_TRUE_MIN_S for g in train.rir)
    assert {k: scores[k] for k in spatial.RESPONSE_METRICS} == {"onset_ms": 0.0, "itd_us": 0.0, "ild_db": 0.0}
    assert scores["lat_pct"] == (100.0 if eligible else None)
