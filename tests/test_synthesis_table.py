"""scripts/synthesis_table.py on a trained one-source scene: every synthesis scored as `avgs eval` scores it."""

import importlib.util
import sys
from pathlib import Path

import pytest

from avgs.config import MID_PHASE_ITERATIONS, SynthesisConfig
from avgs.data.rwavs import RWAVSScene
from avgs.evaluation.binaural import CheckpointMethod, score_scene


def _script():
    file = Path(__file__).resolve().parents[1] / "scripts" / "synthesis_table.py"
    spec = importlib.util.spec_from_file_location(file.stem, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[file.stem] = module
    spec.loader.exec_module(module)
    return module


def test_the_table_scores_each_synthesis_as_avgs_eval_does(one_source_ckpt, tmp_path, capsys):
    m = _script()
    scene_dir = next(one_source_ckpt.parent.glob("*/transforms_train.json")).parent
    out = tmp_path / "table.md"
    assert m.main(["--scene", f"{scene_dir}={one_source_ckpt}", "--threads", "1", "--repeats", "1", "--out", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("Command: `") and "### Mean over the 1 scenes" in text
    rows = {line.split(" | ")[0][2:]: line.split(" | ") for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| synthesis") and scene_dir.name not in line}
    assert set(rows) == set(m.SYNTHESES)
    scene = RWAVSScene(scene_dir)
    for name in ("filter's phase", f"**mid phase, {MID_PHASE_ITERATIONS} iterations (default)**"):
        synthesis = m.SYNTHESES[name]
        want = score_scene(CheckpointMethod(one_source_ckpt, synthesis=synthesis), scene, progress=False)
        mag, env = float(rows[name][1]), float(rows[name][2])
        assert mag == pytest.approx(want["MAG"], abs=6e-5) and env == pytest.approx(want["ENV"], abs=6e-5)
    assert m.SYNTHESES[f"**mid phase, {MID_PHASE_ITERATIONS} iterations (default)**"] == SynthesisConfig()
    with pytest.raises(SystemExit):
        m.main(["--scene", str(scene_dir)])  # no checkpoint named
