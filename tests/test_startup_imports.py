"""What a fresh process pays to read a checkpoint and a clip: no module it does not need.

Checkpoint validation builds the networks on PyTorch's meta device; a meta ``linspace`` or
multiply there imported sympy and ``torch._dynamo`` (1 s for a binaural checkpoint, 2.5 s for
the demo's, in every ``avgs`` command, the explorer and each flythrough). Reading a clip at the
scene's rate imported ``scipy.signal`` for a resampling it did not do, and the explorer's window
for the ENV metric it never computes (1-2 s). benchmarks/startup.md has the figures.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import soundfile as sf

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
PROBE = """
import json, sys
import avgs_viewer.window  # the explorer's modules (no display needed to import them)
from avgs.io.audio_input import read_mono
from avgs.io.checkpoint import load_checkpoint
for path in sys.argv[2:]:
    load_checkpoint(path)
read_mono(sys.argv[1], 22050)
print(json.dumps(sorted(m for m in ("sympy", "torch._dynamo", "scipy.signal") if m in sys.modules)))
"""


def test_the_explorer_reading_checkpoints_and_a_clip_imports_neither_sympy_dynamo_nor_scipy_signal(
        one_source_ckpt, tmp_path):
    clip = tmp_path / "clip.wav"
    sf.write(clip, np.zeros(2205, np.float32), 22050)
    checkpoints = [str(one_source_ckpt)] + ([str(DEMO)] if DEMO.is_file() else [])  # binaural, and the demo's RIR
    run = subprocess.run([sys.executable, "-c", PROBE, str(clip), *checkpoints], capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == []
