"""Slow: a real two-stage training run on a generated scene must beat the baselines.

Run with ``bash scripts/test.sh -m slow`` (a few minutes on two cores).
"""

from __future__ import annotations

import json

import pytest
import torch

from avgs.cli import main as cli_main

pytestmark = pytest.mark.slow


def test_trained_avgs_beats_stereo_energy_on_a_generated_office(tmp_path):
    from avgs.synth.writer import SynthConfig, write_scene

    torch.set_num_threads(1)
    root = tmp_path / "data"
    scene = write_scene(root, "office_t", SynthConfig.quick_config("office", seed=5, poses=80, workers=2),
                        progress=False).scene_dir
    runs = tmp_path / "runs"
    runs.mkdir()  # outputs go into existing folders only
    args = ["train", str(scene), "--out", str(runs / "office_t.ckpt"), "--quick", "--iterations", "1500",
            "--no-progress"]
    assert cli_main(args) == 0
    out = tmp_path / "scores.json"
    assert cli_main(["eval", str(root), "--method", "stereo-energy", "--method", "mono-mono",
                     "--method", f"ckpt:{runs}", "--json", str(out), "--no-progress"]) == 0
    scores = json.loads(out.read_text())["methods"]
    ours, stereo = scores[f"ckpt:{runs}"]["overall"], scores["stereo-energy"]["overall"]
    assert ours["MAG"] < stereo["MAG"] and ours["ENV"] < stereo["ENV"]
    assert ours["MAG"] < 0.5 * scores["mono-mono"]["overall"]["MAG"]

    # The reverberant tail learned the room: per octave band (500 Hz - 4 kHz) its RT60 is
    # nearer the one measured on the simulator's impulse responses than the 0.5 s
    # it started from, within 0.75x - 2.5x of it. This quick room rings for only ~0.15 s,
    # a couple of dozen STFT frames, and there the learned value runs long (1.7-2x): the
    # window's spread of the direct sound and the early reflections read as slower decay.
    import math

    from avgs.commands.info import summary

    learned = summary(runs / "office_t.ckpt")["rt60_s"]
    measured = json.loads((scene / "scene.json").read_text())["rt60"]["bands_s"]
    for band in ("500", "1000", "2000", "4000"):
        got, truth = learned[band], measured[band]
        assert 0.75 * truth <= got <= 2.5 * truth, (band, learned, measured)
        assert abs(math.log(got / truth)) < abs(math.log(0.5 / truth)), (band, learned, measured)
