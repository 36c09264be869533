"""The RIR task's baselines (interpolation, real Opus / AAC round trips), metrics and ``avgs eval --task rir``.

Responses are real: a pyroomacoustics shoebox seen by two ears (unit tests), and the quick
scene of ``avgs synth --task rir --quick`` (the evaluator and the command line).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from avgs.evaluation import binaural as evaluate, codecs, impulse_response as evaluate_rir, interpolation as rir_baselines, metrics
from avgs.cli import main
from avgs.data.rir import RIRScene, RIRSet

FS = 22050


# -- real responses in memory ------------------------------------------------------------


def ears(receiver, yaw_deg: float, half: float = 0.09):
    """Left and right ear positions of a head at ``receiver`` facing ``yaw_deg`` (ccw from +x)."""
    a = math.radians(yaw_deg)
    left = np.array([-math.sin(a), math.cos(a), 0.0])
    return receiver + half * left, receiver - half * left


def room_responses(sources, receivers, yaws, length: int = 8192) -> np.ndarray:
    """``[S, R, Y, 2, length]`` responses of a 6 x 4 x 3 m shoebox (image sources) to two omni ears."""
    import pyroomacoustics as pra

    out = np.zeros((len(sources), len(receivers), len(yaws), 2, length), np.float32)
    for s, src in enumerate(sources):
        room = pra.ShoeBox([6.0, 4.0, 3.0], fs=FS, materials=pra.Material(0.3), max_order=10, air_absorption=False)
        room.add_source(src)
        mics = [e for r in receivers for y in yaws for e in ears(np.asarray(r, float), y)]
        room.add_microphone_array(np.array(mics).T)
        room.compute_rir()
        for k, h in enumerate(room.rir):
            pair, ear = divmod(k, 2)
            r, y = divmod(pair, len(yaws))
            n = min(length, len(h[0]))
            out[s, r, y, ear, :n] = h[0][:n]
    return out


def response_set(responses: np.ndarray, sources, receivers, yaws, rows) -> RIRSet:
    """The RIRSet of the ``(s, r, yaw index)`` triples ``rows`` of ``responses [S, R, Y, 2, L]``."""
    rows = list(rows)
    s = np.array([t[0] for t in rows], np.int64)
    r = np.array([t[1] for t in rows], np.int64)
    y = np.array([t[2] for t in rows], np.int64)
    return RIRSet(
        rir=np.ascontiguousarray(responses[s, r, y]),
        source=np.asarray(sources, np.float64)[s].reshape(-1, 3),
        receiver=np.asarray(receivers, np.float64)[r].reshape(-1, 3),
        yaw=np.asarray(yaws, np.float64)[y],
        source_index=s,
        receiver_index=r,
    )


SOURCES = [[1.0, 1.0, 1.5], [4.5, 1.2, 1.5], [2.5, 3.1, 1.5]]
GRID_X, GRID_Y = np.meshgrid(np.linspace(1.2, 4.8, 4), np.linspace(0.9, 3.1, 3))
RECEIVERS = np.stack([GRID_X.ravel(), GRID_Y.ravel(), np.full(GRID_X.size, 1.5)], axis=1)  # a 4 x 3 grid: degenerate for Delaunay
YAWS = [0.0, 90.0]


@pytest.fixture(scope="module")
def room():
    return room_responses(SOURCES, RECEIVERS, YAWS)


@pytest.fixture(scope="module")
def grid_train(room):
    rows = [(s, r, y) for s in range(len(SOURCES)) for r in range(len(RECEIVERS)) for y in range(len(YAWS))]
    return response_set(room, SOURCES, RECEIVERS, YAWS, rows)


# -- interpolation -----------------------------------------------------------------------


def test_interpolation_is_exact_at_training_points(grid_train):
    for method in (rir_baselines.nearest, rir_baselines.linear):
        out = method(grid_train, grid_train)
        assert out.shape == grid_train.rir.shape and out.dtype == np.float32
        np.testing.assert_array_equal(out, grid_train.rir)


def test_linear_at_a_midpoint_is_the_mean_and_nearest_picks_the_right_pair(room):
    # two receivers of one source, both yaws: the midpoint of the receivers is the mean
    train = response_set(room, SOURCES, RECEIVERS, YAWS, [(0, 0, 0), (0, 1, 0), (0, 0, 1), (0, 1, 1)])
    mid = 0.5 * (RECEIVERS[0] + RECEIVERS[1])
    near_1 = RECEIVERS[0] + 0.7 * (RECEIVERS[1] - RECEIVERS[0])
    query = RIRSet(np.zeros((3, 2, room.shape[-1]), np.float32), np.asarray(SOURCES, float)[[0, 0, 0]],
                   np.stack([mid, mid, near_1]), np.array([0.0, 90.0, 90.0]), np.zeros(3, np.int64), np.zeros(3, np.int64))
    lin = rir_baselines.linear(train, query)
    np.testing.assert_allclose(lin[0], 0.5 * (room[0, 0, 0] + room[0, 1, 0]), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(lin[1], 0.5 * (room[0, 0, 1] + room[0, 1, 1]), rtol=1e-6, atol=1e-9)  # the yaw's own responses
    np.testing.assert_allclose(lin[2], 0.3 * room[0, 0, 1] + 0.7 * room[0, 1, 1], rtol=1e-5, atol=1e-9)
    near = rir_baselines.nearest(train, query)
    np.testing.assert_array_equal(near[2], room[0, 1, 1])  # 70 % of the way to receiver 1, yaw 90

    # two sources, one receiver: the midpoint of the sources is the mean too
    train = response_set(room, SOURCES, RECEIVERS, YAWS, [(0, 5, 0), (1, 5, 0)])
    query = RIRSet(np.zeros((1, 2, room.shape[-1]), np.float32), 0.5 * (np.asarray(SOURCES[0]) + SOURCES[1])[None],
                   RECEIVERS[5][None], np.array([360.0]), np.zeros(1, np.int64), np.zeros(1, np.int64))  # 360 = yaw 0
    np.testing.assert_allclose(rir_baselines.linear(train, query)[0], 0.5 * (room[0, 5, 0] + room[1, 5, 0]), rtol=1e-6, atol=1e-9)


def test_linear_reproduces_a_linear_field_inside_the_hulls_and_is_nearest_outside():
    """On a field linear in the positions, interpolation on a degenerate grid is exact at any
    query inside both hulls (a new source included); outside them it takes the nearest."""
    sources = np.array([[0.0, 0.0, 1.5], [2.0, 0.0, 1.5], [0.0, 2.0, 1.5], [2.0, 2.0, 1.2]])
    gx, gy = np.meshgrid(np.linspace(0.0, 3.0, 4), np.linspace(0.0, 3.0, 4))
    receivers = np.stack([gx.ravel(), gy.ravel(), np.full(16, 1.5)], axis=1)
    coef = np.array([1.0, -2.0, 0.5, 3.0, 1.5, 0.0])

    def field(src, rec):  # [n, 2, 4]: a response whose every sample is linear in (source, receiver)
        v = np.concatenate([src, rec], axis=1) @ coef  # [n]
        return np.repeat(np.stack([v, -v], axis=1)[..., None], 4, axis=-1).astype(np.float32)

    s, r = np.meshgrid(np.arange(4), np.arange(16), indexing="ij")
    s, r = s.ravel(), r.ravel()
    train = RIRSet(field(sources[s], receivers[r]), sources[s], receivers[r], np.zeros(len(s)), s, r)
    q_src = np.array([[0.5, 0.7, 1.45], [1.0, 1.0, 1.4], [5.0, 5.0, 1.5]])
    q_rec = np.array([[1.3, 2.2, 1.5], [0.1, 2.9, 1.5], [0.2, 0.1, 1.5]])
    query = RIRSet(np.zeros((3, 2, 4), np.float32), q_src, q_rec, np.zeros(3), np.zeros(3, np.int64), np.zeros(3, np.int64))
    out = rir_baselines.linear(train, query)
    np.testing.assert_allclose(out[:2], field(q_src[:2], q_rec[:2]), rtol=1e-5, atol=1e-5)
    # the third source is outside the sources' hull: its nearest source (3), then linear over receivers
    np.testing.assert_allclose(out[2], field(sources[[3]], q_rec[[2]])[0], rtol=1e-5, atol=1e-5)


def test_a_yaw_the_training_set_lacks_is_an_error(grid_train):
    query = RIRSet(grid_train.rir[:1], grid_train.source[:1], grid_train.receiver[:1], np.array([45.0]),
                   grid_train.source_index[:1], grid_train.receiver_index[:1])
    for method in (rir_baselines.nearest, rir_baselines.linear):
        with pytest.raises(ValueError, match=r"no training responses at yaw 45 degrees \(the training set has yaws 0, 90\)"):
            method(grid_train, query)


# -- codecs ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(codecs.CODECS))
def test_codec_round_trip_keeps_the_response_and_is_lossy(room, name):
    codec = codecs.CODECS[name]
    x = room[0, 4, 1]  # [2, L] one binaural room response
    y, n_bytes = codecs.roundtrip(x, FS, codec)
    assert y.shape == x.shape and y.dtype == np.float32
    assert not np.array_equal(x, y)  # lossy
    seconds = x.shape[-1] / FS
    assert 0 < n_bytes * 8 / seconds < 2.0 * codec.bitrate  # about the stated bitrate (short stream: flush frames)
    for ear in range(2):
        assert np.corrcoef(x[ear], y[ear])[0, 1] > 0.9
        lags = np.correlate(y[ear].astype(float), x[ear].astype(float), mode="full")
        assert abs(int(np.argmax(lags)) - (x.shape[-1] - 1)) <= 3  # time-aligned within a few samples
        db = 10 * np.log10(np.sum(y[ear].astype(float) ** 2) / np.sum(x[ear].astype(float) ** 2))
        assert abs(db) < 1.0
    # the direct sound arrives where it did
    assert abs(int(np.argmax(np.abs(y[0]))) - int(np.argmax(np.abs(x[0])))) <= 3
    assert codecs.roundtrip(np.zeros_like(x), FS, codec).audio.max() == 0.0


def test_codec_delays_are_the_codecs_own():
    assert codecs.codec_delay(codecs.CODECS["aac"]) == 1024  # AAC's priming samples, not skipped without a container
    assert abs(codecs.codec_delay(codecs.CODECS["opus"])) <= 8  # the decoder skips Opus's pre-skip itself


def test_codec_methods_interpolate_the_decoded_responses(grid_train):
    out = rir_baselines.RIR_BASELINES["aac-nearest"](grid_train, grid_train)
    decoded = rir_baselines.decoded(grid_train, "aac")
    np.testing.assert_array_equal(out, decoded.rir)  # nearest at a training point: its decoded response
    assert decoded is rir_baselines.decoded(grid_train, "aac")  # decoded once per training set
    assert not np.array_equal(out, grid_train.rir)


# -- metrics through the evaluator ---------------------------------------------------------


def decaying_noise(t60s, length=FS, seed=0):
    """``[2, length]`` noise whose energy falls 60 dB in ``t60s[c]`` seconds on channel c."""
    rng = np.random.default_rng(seed)
    t = np.arange(length) / FS
    return np.stack([rng.standard_normal(length) * np.exp(-3 * math.log(10) * t / t60) for t60 in t60s])


def test_metrics_of_exponential_decays_recover_their_t60():
    gt = decaying_noise([0.4, 0.6])
    for ch, t60 in enumerate((0.4, 0.6)):
        assert metrics.rt60(gt[ch]) == pytest.approx(t60, rel=0.03)
        assert metrics.edt(gt[ch]) == pytest.approx(t60, rel=0.05)  # a single exponential: EDT = T60
        a = 6 * math.log(10) / t60  # energy decay rate, 1/s
        split = int(0.05 * FS + 1) / FS
        assert metrics.c50(gt[ch]) == pytest.approx(10 * math.log10(math.expm1(a * split)), abs=0.5)
    pred = decaying_noise([0.44, 0.66], seed=1)  # 10 % longer on both ears
    errors = evaluate_rir.response_errors(pred, gt, FS)
    assert errors["t60_pct"] == pytest.approx(10.0, abs=3.0)
    assert errors["edt_s"] == pytest.approx(0.05, abs=0.02)  # mean of 0.04 and 0.06
    assert evaluate_rir.response_errors(gt, gt, FS) == {"t60_pct": 0.0, "c50_db": 0.0, "edt_s": 0.0,
                                                        "onset_ms": 0.0, "itd_us": 0.0, "ild_db": 0.0}


# -- the evaluator and the command line on the quick scene -----------------------------------


@pytest.fixture(scope="module")
def quick_root(quick_rir_scene):
    """The data root of the shared quick impulse-response scene (read only)."""
    return quick_rir_scene.parent


def test_the_report_has_the_binaural_tasks_shape(quick_root, tmp_path):
    from rwavs_writer import write_scene

    methods = {name: rir_baselines.RIR_BASELINES[name] for name in ("nearest", "linear")}
    report = evaluate_rir.evaluate(methods, evaluate_rir.find_scenes(quick_root), split="val", progress=False)
    write_scene(tmp_path, "office_1", n_train=4, n_val=2, seed=1)
    binaural = evaluate.evaluate({"mono-mono": lambda c, s: np.stack([c.mono, c.mono])}, [tmp_path / "office_1"], progress=False)
    assert set(report) == set(binaural) | {"task"} and report["task"] == "rir"
    scene = RIRScene(quick_root / "quick_rect")
    assert report["clips"] == {"quick_rect": len(scene.responses("val"))}
    assert report["environments"] == {"quick_rect": evaluate_rir.environment_of(scene)}
    for name in methods:
        m = report["methods"][name]
        assert set(m) == set(binaural["methods"]["mono-mono"]) == {"scenes", "environments", "overall"}
        assert set(m["scenes"]) == {"quick_rect"} and set(m["environments"]) == set(report["environments"].values())
        assert list(m["overall"]) == list(evaluate_rir.RIR_METRICS) == ["t60_pct", "c50_db", "edt_s", "onset_ms",
                                                                        "itd_us", "ild_db", "lat_pct"]
        assert all(math.isfinite(v) and v >= 0 for k, v in m["overall"].items() if k != "lat_pct")
        assert m["overall"]["lat_pct"] is None or 0.0 <= m["overall"]["lat_pct"] <= 100.0
        assert m["overall"] == m["scenes"]["quick_rect"]  # one scene, one environment
    # scoring the training split: interpolation returns the responses themselves
    train = evaluate_rir.evaluate(methods, [quick_root / "quick_rect"], split="train", progress=False)
    for name in methods:
        got = dict(train["methods"][name]["overall"])
        assert got.pop("lat_pct") in (100.0, None)  # the true ITDs themselves: all agree (None: none eligible)
        assert got == {"t60_pct": 0.0, "c50_db": 0.0, "edt_s": 0.0, "onset_ms": 0.0, "itd_us": 0.0, "ild_db": 0.0}


def test_cli_scores_both_splits_and_writes_json(quick_root, tmp_path, capsys):
    out = tmp_path / "rir.json"
    argv = ["eval", "--task", "rir", str(quick_root), "--methods", "nearest,linear,opus-linear,aac-nearest",
            "--split", "both", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "val responses:" in printed and "heldout responses:" in printed and "aac-nearest" in printed
    report = json.loads(out.read_text())
    assert report["task"] == "rir" and set(report["splits"]) == {"val", "heldout"}
    for split, r in report["splits"].items():
        assert r["split"] == split and list(r["methods"]) == ["nearest", "linear", "opus-linear", "aac-nearest"]
        assert r["clips"]["quick_rect"] > 0


def test_cli_errors_are_one_clear_line(quick_root, tmp_path, capsys):
    assert main(["eval", "--task", "rir", str(quick_root), "--methods", "nearest,cubic"]) == 2
    err = capsys.readouterr().err
    assert "unknown RIR method 'cubic'; expected one of nearest, linear, opus-nearest" in err and "ckpt:PATH" in err
    assert main(["eval", "--task", "rir", str(quick_root), "--methods", "nearest,,linear"]) == 2
    assert "an empty method name" in capsys.readouterr().err
    assert main(["eval", "--task", "rir", str(tmp_path)]) == 2  # no scenes there
    assert "no impulse-response scenes" in capsys.readouterr().err
    assert main(["eval", "--task", "rir", str(quick_root), "--scene", "nowhere"]) == 2
    assert "no RIR scene named nowhere" in capsys.readouterr().err
    assert main(["eval", str(quick_root), "--split", "heldout"]) == 2  # the binaural task has no held-out sources
    assert main(["eval", "--task", "rir", str(quick_root), "--methods", f"ckpt:{tmp_path / 'none.ckpt'}"]) == 2
    assert "checkpoint missing" in capsys.readouterr().err


def test_the_default_methods_are_the_baselines():
    assert list(evaluate_rir.DEFAULT_METHODS) == list(rir_baselines.RIR_BASELINES)


@pytest.mark.slow
def test_a_checkpoint_is_scored_as_its_training_validated_it(quick_root, tmp_path, capsys):
    """``ckpt:PATH``, ``avgs:PATH`` and ``ckpt:DIR`` wrap ``SceneRenderer.predict_responses``;
    the scores equal the val / heldout T60, C50 and EDT that training logged (one scoring code)."""
    import torch

    ckpt = tmp_path / "models" / "quick_rect.ckpt"
    ckpt.parent.mkdir()
    assert main(["train", str(quick_root / "quick_rect"), "--task", "rir", "--quick", "--out", str(ckpt), "--no-progress"]) == 0
    final = [r for r in torch.load(ckpt, weights_only=True)["history"] if "val_t60" in r][-1]
    out = tmp_path / "scores.json"
    argv = ["eval", "--task", "rir", str(quick_root), "--methods", f"nearest,ckpt:{ckpt},avgs:{ckpt},ckpt:{ckpt.parent}",
            "--split", "both", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    report = json.loads(out.read_text())
    for split in ("val", "heldout"):
        methods = report["splits"][split]["methods"]
        for name in (f"ckpt:{ckpt}", f"avgs:{ckpt}", f"ckpt:{ckpt.parent}"):
            got = methods[name]["overall"]
            assert got["t60_pct"] == pytest.approx(final[f"{split}_t60"], rel=1e-6)
            assert got["c50_db"] == pytest.approx(final[f"{split}_c50"], rel=1e-6)
            assert got["edt_s"] == pytest.approx(final[f"{split}_edt"], rel=1e-6, abs=1e-9)
