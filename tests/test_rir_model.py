"""The impulse-response task, model side: the RIR network, ``avgs train --task rir``, the
checkpoint, ``SceneRenderer`` with a moving source, ``avgs render --source`` and the bench.

Everything runs on a real scene made by ``avgs synth --task rir --quick`` (simulated
responses of several source positions) and a short ``--quick`` training; without that
command (the data side of the task) the tests that need it skip, saying so.
"""

from __future__ import annotations

import argparse
import json
import math
import warnings

import numpy as np
import pytest
import torch

from avgs import dsp
from avgs.acoustics.rir_binauralizer import RIRBinauralizer, orientation_feature
from avgs.acoustics.rir_model import ear_transfer, response_waveform
from avgs.io.checkpoint import load_checkpoint, save_checkpoint, untrained_checkpoint
from avgs.cli import main as cli_main
from avgs.config import STFT, RIRConfig
from avgs.render.renderer import OneSourceModel, SceneRenderer

ITERATIONS = 200
"Iterations of the fixture's quick training (a few seconds at the quick width)."


@pytest.fixture(scope="module")
def rir_scene(quick_rir_scene):
    """A quick RIR scene (``avgs synth --task rir --quick``; shared, read only)."""
    return quick_rir_scene


@pytest.fixture(scope="module")
def trained(rir_scene, tmp_path_factory):
    """(checkpoint path, final record) of a quick RIR training on ``rir_scene``."""
    from avgs.train.impulse_responses import rir_quick_config
    from avgs.train.pipeline import train_scene

    cfg = rir_quick_config()
    cfg.acoustic.iterations = ITERATIONS
    cfg.eval_every, cfg.checkpoint_every, cfg.log_every = 100, 100, 10
    out = tmp_path_factory.mktemp("rir_train") / "scene.ckpt"
    final = train_scene(rir_scene, out, cfg, task="rir", progress=False)
    return out, final


@pytest.fixture(scope="module")
def renderer(trained):
    return SceneRenderer.load(trained[0])


# -- pieces, on known signals ---------------------------------------------------------


def test_network_shapes_and_an_untrained_network_predicts_the_mean():
    cfg = RIRConfig(width=32, distance_knee=False)  # the law's term starts small, not at zero (test_rir_losses.py)
    net = RIRBinauralizer(cfg, 16, STFT.n_freq, 9, STFT.hop_length / STFT.sample_rate)
    with torch.no_grad():
        net.mean.copy_(torch.randn(2, STFT.n_freq, 9))
    B = 3
    out = net(torch.rand(B, 3), torch.rand(B, 3), torch.rand(B) * 6, torch.rand(B) * 6, torch.randn(B, 16))
    assert out.shape == (B, 2, STFT.n_freq, 9) and torch.isfinite(out).all()
    assert torch.equal(out, net.mean.expand(B, -1, -1, -1))  # the head starts at zero
    with pytest.raises(ValueError, match="context"):
        net(torch.rand(B, 3), torch.rand(B, 3), torch.zeros(B), torch.zeros(B))


def test_orientation_feature_is_periodic_in_yaw():
    yaw = torch.tensor([0.0, 2 * math.pi, 0.3], dtype=torch.float64)
    e = orientation_feature(torch.zeros(3, dtype=torch.float64), yaw, 4)
    assert e.shape == (3, 16)
    assert torch.allclose(e[0], e[1], atol=1e-12) and not torch.allclose(e[0], e[2])


def test_ear_transfer_of_an_impulse_is_its_gain():
    """Parseval: a delayed impulse of amplitude a has |H(f)| = a in every bin (away from the edges' padding)."""
    h = torch.zeros(2, 4096, dtype=torch.float64)
    h[0, 1000], h[1, 1200] = 0.5, 0.25
    gains = ear_transfer(dsp.magnitude(h), STFT)  # [2, F]
    assert torch.allclose(gains[0], torch.full_like(gains[0], 0.5), rtol=1e-6)
    assert torch.allclose(gains[1], torch.full_like(gains[1], 0.25), rtol=1e-6)


def test_response_waveform_keeps_the_energy_envelope():
    """A decaying noise response: the waveform rebuilt from its STFT magnitudes alone has the same
    energy per frame (within 1.5 dB where it matters) and the same decay (T60 within 10 %)."""
    from avgs.evaluation.metrics import rt60

    g = np.random.default_rng(0)
    t = np.arange(11025) / STFT.sample_rate
    h = (g.standard_normal((2, t.size)) * np.exp(-t / 0.05)).astype(np.float32)  # T60 = 3 ln(10) 0.05 s ~ 0.35 s
    mag = dsp.magnitude(torch.from_numpy(h))
    for phase, its in (("noise", 0), ("griffin-lim", 8)):
        y = response_waveform(mag, t.size, STFT, phase, its).numpy()
        assert y.shape == h.shape and np.all(np.isfinite(y))
        for c in range(2):
            assert abs(rt60(y[c]) - rt60(h[c])) / rt60(h[c]) < 0.1
        e_true = dsp.magnitude(torch.from_numpy(h)).square().sum(-2)[:, :40]
        e_pred = dsp.magnitude(torch.from_numpy(y)).square().sum(-2)[:, :40]
        assert float((10 * torch.log10(e_pred / e_true)).abs().max()) < 1.5


def test_a_one_source_checkpoint_warns_once_about_a_moved_source(tmp_path):
    pts = np.random.default_rng(0).uniform([0, 0, 0], [4, 3, 2.5], (300, 3))
    path = save_checkpoint(untrained_checkpoint(pts, [1.0, 1.0, 1.2]), tmp_path / "one.ckpt")
    r = SceneRenderer.load(path)
    assert r.task == "binaural" and not r.source_aware
    mono = np.random.default_rng(1).standard_normal(2048).astype(np.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r.render((2, 1.5, 1.2), 0.0, mono)  # the trained source: nothing to say
        r.render((2, 1.5, 1.2), 0.0, mono, source=r.source)
        a = r.render((2, 1.5, 1.2), 0.0, mono, source=(3.0, 2.0, 1.2))
        r.render((2, 1.5, 1.2), 0.0, mono, source=(3.5, 2.0, 1.2))
    said = [w for w in caught if issubclass(w.category, OneSourceModel)]
    assert len(said) == 1 and "one source position" in str(said[0].message)
    assert np.array_equal(a.binaural, r.render((2, 1.5, 1.2), 0.0, mono, source=(3.0, 2.0, 1.2)).binaural)  # behaviour kept


# -- training -------------------------------------------------------------------------


def test_training_learns_and_beats_the_mean_response(trained):
    out, final = trained
    from avgs.train.logging import log_paths

    records = [json.loads(line) for line in log_paths(out)[0].read_text().splitlines()]
    losses = [r["loss"] for r in records if r.get("stage") == "stage2" and "loss" in r]
    assert np.mean(losses[-5:]) < 0.7 * np.mean(losses[:5])
    assert final["val_logmag"] < final["val_logmag_mean"]  # better than predicting the mean response on val
    for split in ("val", "heldout"):
        if f"{split}_t60" in final:
            assert all(math.isfinite(final[f"{split}_{m}"]) for m in ("t60", "c50", "edt"))
    assert log_paths(out)[1].is_file()


def test_checkpoint_round_trip_and_validation(trained, tmp_path):
    out, _ = trained
    ckpt = load_checkpoint(out)
    assert ckpt["task"] == "rir" and ckpt["config"]["rir"]["frames"] == dsp.n_frames(ckpt["config"]["rir"]["length"])
    assert ckpt["rir"]["sources"].shape[1] == 3
    resaved = save_checkpoint(ckpt, tmp_path / "again.ckpt")
    again = SceneRenderer.load(resaved)
    r = SceneRenderer.load(out)
    lis, src = r.bounds.mean(0), r.training_sources[0]
    assert np.array_equal(again.binaural_filter(lis, 10.0, src).impulse, r.binaural_filter(lis, 10.0, src).impulse)

    def refused(edit, match):
        bad = load_checkpoint(out)
        edit(bad)
        path = save_checkpoint(bad, tmp_path / "bad.ckpt")
        with pytest.raises(ValueError, match=match):
            load_checkpoint(path)

    refused(lambda c: c["binauralizer"].__setitem__("mean", c["binauralizer"]["mean"][:, :, :-1]), "binauralizer.mean")
    refused(lambda c: c["binauralizer"]["head.weight"].fill_(float("nan")), "NaN")
    refused(lambda c: c.__setitem__("task", "speech"), "'task'")
    refused(lambda c: c["config"]["rir"].__setitem__("frames", 3), "rir.frames")
    refused(lambda c: c.__setitem__("task", "binaural"), "binauralizer")  # RIR weights are not B's
    old = load_checkpoint(out)
    del old["task"]  # a file from before tasks is a binaural one: the RIR weights do not fit it
    with pytest.raises(ValueError):
        load_checkpoint(save_checkpoint(old, tmp_path / "old.ckpt"))


def test_no_context_control_trains_from_the_command_line(rir_scene, tmp_path):
    out = tmp_path / "noctx.ckpt"
    assert cli_main(["train", str(rir_scene), "--task", "rir", "--quick", "--no-context", "--iterations", "20",
                     "--eval-every", "20", "--rir-eval-responses", "2", "--out", str(out), "--no-progress"]) == 0
    ckpt = load_checkpoint(out)
    assert ckpt["task"] == "rir" and ckpt["field"] == {} and not ckpt["config"]["acoustic"]["use_context"]
    r = SceneRenderer.load(out)
    h = r.binaural_filter(r.bounds.mean(0), 0.0, r.training_sources[0]).impulse
    assert h.shape == (2, r.config.rir.length) and np.all(np.isfinite(h))


def _train_killed_at(iteration: int, monkeypatch, *args, **kwargs) -> None:
    """``train_scene(*args, **kwargs)`` killed (KeyboardInterrupt) as its trainer reaches ``iteration``;
    the trainer's step is restored after."""
    import avgs.train.impulse_responses as rir_train
    from avgs.train.pipeline import train_scene

    step = rir_train.RIRTrainer.step

    def dying(self):
        if self.iteration == iteration:
            raise KeyboardInterrupt("killed")
        return step(self)

    monkeypatch.setattr(rir_train.RIRTrainer, "step", dying)
    with pytest.raises(KeyboardInterrupt):
        train_scene(*args, **kwargs)
    monkeypatch.setattr(rir_train.RIRTrainer, "step", step)


def test_a_killed_run_resumes_bit_exactly(rir_scene, tmp_path, monkeypatch):
    import avgs.train.impulse_responses as rir_train
    from avgs.train.pipeline import train_scene

    cfg = rir_train.rir_quick_config()
    cfg.acoustic.iterations, cfg.checkpoint_every, cfg.eval_every, cfg.rir.eval_responses = 30, 10, 30, 0
    train_scene(rir_scene, tmp_path / "full.ckpt", cfg, task="rir", progress=False)
    _train_killed_at(15, monkeypatch, rir_scene, tmp_path / "part.ckpt", cfg, task="rir", progress=False)
    assert load_checkpoint(tmp_path / "part.ckpt")["train_state"]["iteration"] == 10
    train_scene(rir_scene, tmp_path / "part.ckpt", cfg, task="rir", progress=False, resume=True)
    a, b = load_checkpoint(tmp_path / "full.ckpt"), load_checkpoint(tmp_path / "part.ckpt")
    assert torch.equal(a["audio_points"]["X"], b["audio_points"]["X"])
    assert all(torch.equal(a["binauralizer"][k], b["binauralizer"][k]) for k in a["binauralizer"])


def test_the_schedule_is_sized_to_the_training_responses_and_a_resume_keeps_it(rir_scene, tmp_path, monkeypatch):
    """``rir.passes`` passes over the training responses, not the preset's 300 iterations; a killed
    run resumes to the same end, and ``--iterations N`` on the command line means N."""
    import avgs.train.impulse_responses as rir_train
    from avgs.commands.train import add_arguments, config_from_args
    from avgs.data.rir import RIRScene
    from avgs.train.pipeline import train_scene

    responses = len(RIRScene(rir_scene).index("train"))
    cfg = rir_train.rir_quick_config()
    cfg.checkpoint_every, cfg.eval_every, cfg.rir.eval_responses = 10, 1000, 0
    cfg.rir.passes = 30 * cfg.acoustic.batch_size / responses + 0.01  # 31 iterations, against the preset's 300
    cfg.rir.least_iterations = 20
    expected = math.ceil(cfg.rir.passes * responses / cfg.acoustic.batch_size)
    assert expected == 31 and rir_train.schedule_iterations(cfg, responses) == expected
    assert rir_train.schedule_iterations(cfg, 1) == 20  # at least least_iterations
    _train_killed_at(15, monkeypatch, rir_scene, tmp_path / "sized.ckpt", cfg, task="rir", progress=False)
    resumed = rir_train.rir_quick_config()  # 300 iterations asked; the stored schedule's size wins
    resumed.rir.passes = 1.0
    final = train_scene(rir_scene, tmp_path / "sized.ckpt", resumed, task="rir", progress=False, resume=True)
    ckpt = load_checkpoint(tmp_path / "sized.ckpt")
    assert final["iteration"] == ckpt["train_state"]["iteration"] == ckpt["config"]["acoustic"]["iterations"] == expected
    schedule = [r for r in ckpt["history"] if r.get("event") == "schedule"]
    assert schedule and schedule[0]["iterations"] == expected and schedule[0]["responses"] == responses
    assert rir_train.schedule_iterations(cfg, 10**9) == cfg.acoustic.iterations  # at most the iterations asked

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    parse = lambda *flags: config_from_args(parser.parse_args([str(rir_scene), "--task", "rir", "--out", "x.ckpt", *flags]))  # noqa: E731
    assert parse().rir.passes == RIRConfig().passes > 0
    assert parse("--iterations", "6000").rir.passes == 0
    both = parse("--iterations", "6000", "--rir-passes", "5")
    assert (both.acoustic.iterations, both.rir.passes) == (6000, 5)
    with pytest.raises(ValueError, match="rir passes"):
        parse("--rir-passes", "nan")


# -- inference --------------------------------------------------------------------------


def test_render_with_a_source_convolves_with_the_predicted_response(renderer):
    r = renderer
    assert r.task == "rir" and r.source_aware
    lis, src = r.bounds.mean(0), r.training_sources[-1]
    f = r.binaural_filter(lis, 40.0, src)
    L = r.config.rir.length
    assert f.impulse.shape == (2, L) and f.impulse.dtype == np.float32 and np.all(np.isfinite(f.impulse))
    assert f.gains.shape == (2, r.n_freq) and f.mixture is None  # the response's own gains: no masks
    assert f.listener_vicinity.shape == f.source_vicinity.shape == (r.vicinity_size,)
    unit = np.zeros(L + 500, np.float32)
    unit[0] = 1.0
    out = r.render(lis, 40.0, unit, source=src)
    assert np.allclose(out.binaural[:, :L], f.impulse, atol=1e-6 * float(np.abs(f.impulse).max()))
    assert np.abs(out.binaural[:, L:]).max() < 1e-6 * float(np.abs(f.impulse).max())
    # linear: twice the input, twice the output; a delayed impulse, the response delayed
    delayed = np.roll(unit, 100)
    assert np.allclose(r.render(lis, 40.0, delayed, source=src).binaural[:, 100 : 100 + L], f.impulse, atol=1e-6)
    # the source matters: another source position gives another response
    other = r.binaural_filter(lis, 40.0, r.training_sources[0]).impulse
    assert not np.allclose(other, f.impulse)


def test_predict_responses_agrees_with_binaural_filter(renderer):
    r = renderer
    lis, src = r.bounds.mean(0) + [0.1, -0.2, 0.0], r.training_sources[0]
    batch = r.predict_responses(np.stack([r.frame.to_normalised(src)] * 3),
                                np.stack([r.frame.to_normalised(lis)] * 3), [15.0, 15.0, 200.0])
    assert batch.shape == (3, 2, r.config.rir.length) and batch.dtype == np.float32
    single = r.binaural_filter(lis, 15.0, src).impulse
    assert np.allclose(batch[0], single, atol=1e-5 * float(np.abs(single).max()))
    assert np.allclose(batch[0], batch[1], atol=1e-6 * float(np.abs(single).max()))
    assert not np.allclose(batch[0], batch[2])


def test_continuous_yaw(renderer):
    """yaw 360 == yaw 0 exactly; a small yaw change gives a small change, growing with the change."""
    r = renderer
    lis, src = r.bounds.mean(0), r.training_sources[0]
    src_n, lis_n = r.frame.to_normalised(src), r.frame.to_normalised(lis)
    as_model = dict(dtype=torch.float32)

    def log_mag(yaw):
        with torch.inference_mode():
            return r.model.log_magnitudes(torch.tensor(lis_n[None], **as_model), torch.tensor([math.radians(yaw % 360.0)], **as_model),
                                          torch.tensor(src_n, **as_model), r.cache)[0]

    assert np.array_equal(r.binaural_filter(lis, 0.0, src).impulse, r.binaural_filter(lis, 360.0, src).impulse)
    assert np.array_equal(r.binaural_filter(lis, -90.0, src).impulse, r.binaural_filter(lis, 270.0, src).impulse)
    base = log_mag(30.0)
    d = {step: float((log_mag(30.0 + step) - base).abs().mean()) for step in (0.01, 1.0, 90.0)}
    assert d[90.0] > 0
    assert d[0.01] < d[1.0] < d[90.0] and d[1.0] < 0.2 * d[90.0]


def test_propagation_map_masks_and_stream_work_on_an_rir_checkpoint(renderer):
    from avgs.render.cells import pose_levels
    from avgs.render.propagation_map import compute_map

    r = renderer
    src = r.training_sources[0]
    pm = compute_map(r, source=src, yaw=0.0, size=4)
    assert pm.complete and np.all(np.isfinite(pm.level)) and np.all(np.isfinite(pm.ild))
    m = r.masks(r.bounds.mean(0), 0.0, source=src)
    level, _ = pose_levels(m)
    assert math.isfinite(level) and m.binaural is None
    mono = np.random.default_rng(0).standard_normal(5000).astype(np.float32)
    s = r.stream(r.bounds.mean(0), 0.0, source=src)
    y = np.concatenate([s.process(mono[:1234]), s.process(mono[1234:]), s.flush()], axis=1)
    assert np.allclose(y, r.render(r.bounds.mean(0), 0.0, mono, source=src).binaural, atol=1e-5)


def test_render_command_with_a_source(trained, tmp_path):
    import soundfile as sf

    r = SceneRenderer.load(trained[0])
    wav = tmp_path / "in.wav"
    sf.write(wav, np.random.default_rng(0).standard_normal(4000).astype(np.float32) * 0.1, r.sample_rate, subtype="FLOAT")
    lis, src = r.bounds.mean(0), r.training_sources[1]
    out = tmp_path / "out.wav"
    assert cli_main(["render", str(trained[0]), "--listener", *map(str, lis), "--yaw", "30", "--source", *map(str, src),
                     "--input", str(wav), "--output", str(out)]) == 0
    y, sr = sf.read(out, dtype="float32", always_2d=True)
    mono, _ = sf.read(wav, dtype="float32")
    assert sr == r.sample_rate and y.shape == (4000, 2)
    assert np.allclose(y.T, r.render(lis, 30.0, mono, source=src).binaural, atol=1e-5)  # positions pass through decimal text


def test_bench_reports_the_source_aware_render(renderer, tmp_path):
    from avgs.bench.latency import measure

    out = measure(renderer, repeats=3)
    assert out["task"] == "rir" and out["source_aware"]["median_ms"] > 0
    assert {"vicinity + field", "network", "waveform", "direct sound", "convolution"} <= set(out["stages"])


# -- physics (slow) -------------------------------------------------------------------


def level_db(h) -> np.ndarray:
    """Level (dB) of responses [..., 2, L]: the two ears' mean energy."""
    return 10 * np.log10(np.mean(np.sum(np.asarray(h, dtype=np.float64) ** 2, -1), -1) + 1e-30)


def simulated_responses(scene_dir, sources_world, listener_world, yaw: float = 0.0) -> np.ndarray:
    """The simulator's truth [S, 2, L] for any sources, in the scene's own time frame and scale
    (what ``avgs synth --task rir`` writes: the emission delay cut off, scale 1)."""
    from avgs.synth.simulate import SimSettings, load_spec, receiver_rirs

    meta = json.loads((scene_dir / "scene.json").read_text())["rir"]
    settings = SimSettings.from_dict(meta["simulation"])
    offset, L = int(meta["removed_delay_samples"]), int(meta["length_samples"])
    h = receiver_rirs(load_spec(scene_dir), sources_world, listener_world, [yaw], settings)[:, 0]  # [S, 2, n]
    out = np.zeros((len(h), 2, L), np.float32)
    part = h[:, :, offset : offset + L]
    out[:, :, : part.shape[-1]] = part
    return out


@pytest.mark.slow
def test_level_against_source_distance_follows_the_simulator(tmp_path):
    """rect_small, 500 iterations: at a fixed listener, sources every 0.5 m along the longest line
    the room allows (0.5 m up to 5 m; 2 m in rect_small): the predicted level falls with distance
    and stays within 2 dB of the simulator's (measured with the distance law: -0.69, -0.27, -0.48,
    -0.69 dB at 0.5, 1, 1.5, 2 m; with the slope on log d before it: -2.6, -1.3, -0.9, -1.0 dB)."""
    from avgs.synth.poses import is_walkable
    from avgs.synth.simulate import load_spec
    from avgs.train.impulse_responses import rir_quick_config
    from avgs.train.pipeline import train_scene

    assert cli_main(["synth", str(tmp_path), "--task", "rir", "--preset", "rect_small", "--scene-id", "rs",
                     "--workers", "2", "--no-progress"]) == 0
    scene_dir = tmp_path / "rs"
    cfg = rir_quick_config()
    cfg.acoustic.iterations, cfg.rir.width, cfg.rir.eval_responses = 500, 256, 0
    train_scene(scene_dir, tmp_path / "rs.ckpt", cfg, task="rir", progress=False)
    r = SceneRenderer.load(tmp_path / "rs.ckpt")
    meta = json.loads((scene_dir / "scene.json").read_text())["rir"]
    receivers, z = np.asarray(meta["receivers_world"]), float(np.mean(np.asarray(meta["sources_world"])[:, 2]))
    listener = receivers[np.argmin(np.linalg.norm(receivers - receivers.mean(0), axis=1))]
    spec = load_spec(scene_dir)
    best: list = []
    for angle in np.radians(np.arange(0, 360, 15)):
        d = np.array([np.cos(angle), np.sin(angle)])
        line = []
        for x in np.arange(0.5, 5.01, 0.5):
            if not is_walkable(spec, listener[:2] + x * d):
                break
            line.append([*(listener[:2] + x * d), z])
        best = max(best, line, key=len)
    sources = np.asarray(best)
    assert len(sources) >= 3
    truth = level_db(simulated_responses(scene_dir, sources, listener))
    n = len(sources)
    pred = level_db(r.predict_responses(r.frame.to_normalised(sources), np.repeat(r.frame.to_normalised(listener)[None], n, 0),
                                        np.zeros(n)))
    assert np.max(np.abs(pred - truth)) < 2.0, (truth.round(2), pred.round(2))
    assert pred[0] > pred[-1] + 1.0  # it falls with distance


def test_the_noise_spectrogram_made_frame_major_is_the_product_transposed():
    """response_waveform's spectrogram, written frame-major in one pass, equals the noise phase times the
    magnitudes transposed, bit for bit: without a direct sound, and with one per pose whose coherent frames
    run from none to past the last frame."""
    from avgs.acoustics.direct_placement import DirectSound
    from avgs.acoustics.rir_model import _noise_spectrogram, _phases

    g = torch.Generator().manual_seed(4)
    mag = torch.rand(5, 2, STFT.n_fft // 2 + 1, 40, generator=g)  # [B, 2, F, N]
    arrival = torch.tensor([0.0, 0.01, 0.05, 0.2, 5.0], dtype=torch.float64)  # s: the last past the 40 frames
    direct = DirectSound(arrival, torch.zeros(5, 2, dtype=torch.float64))
    for d in (None, direct):
        want = (mag * _phases(mag.shape[-2], mag.shape[-1], STFT, d)).transpose(-1, -2).contiguous()
        got = _noise_spectrogram(mag, STFT, d)
        assert got.is_contiguous() and torch.equal(got, want)
    assert not torch.equal(_noise_spectrogram(mag, STFT, direct), _noise_spectrogram(mag, STFT, None))
