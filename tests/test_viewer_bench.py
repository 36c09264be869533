"""``avgs-viewer --bench`` end to end: the real window on an Xvfb of its own, driven by X events."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "assets" / "demo" / "scene.ckpt"

pytestmark = pytest.mark.gui


def test_the_bench_drives_the_real_window_and_writes_its_report(tmp_path):
    if not DEMO.is_file():
        pytest.skip("the bundled demo scene is missing (scripts/make_demo.sh)")
    out = tmp_path / "viewer.md"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}  # it starts its own Xvfb
    code = ("import sys; from avgs_viewer.bench import run_viewer_bench; "
            f"r = run_viewer_bench({str(DEMO)!r}, {str(out)!r}, n=3, idle_s=0.5, orbit_s=0.5); "
            "print(r['drag_to_audio']['n'], len(r['drag_to_audio_each_ms']), r['missed'], r['orbit']['frames'])")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr  # its Xvfb stopped before the interpreter's exit: no Xlib I/O error
    n, each, missed, frames = (int(v) for v in proc.stdout.split()[-4:])
    assert n == 3 and each == 3 and missed == 0 and frames > 0  # every drag heard, each kept for pooling; the orbit drew
    text = out.read_text()
    for line in ("real-event drag to audio: median ", "idle CPU: ", "orbit: ", "GL: ", "Command: "):
        assert line in text
    assert "drag end ->" not in text  # the state-driven numbers are gone


@pytest.mark.slow  # 15 s; the bench itself is driven in the default suite above
def test_on_a_one_source_scene_the_bench_times_the_full_render_after_each_release(tmp_path, one_source_ckpt):
    out = tmp_path / "viewer.md"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    code = ("from avgs_viewer.bench import run_viewer_bench; "
            f"r = run_viewer_bench({str(one_source_ckpt)!r}, {str(out)!r}, n=2, idle_s=0.5, orbit_s=0.5); "
            "f = r['drag_to_full_render']; print(r['drag_to_audio']['n'], f['n'], r['full_render_missed'], "
            "int(f['min_ms'] > r['settle_s'] * 1e3))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr
    heard, full, missed, after_settle = (int(v) for v in proc.stdout.split()[-4:])
    assert heard == 2 and full == 2 and missed == 0 and after_settle == 1  # never before the pose settled
    assert "| drag to full render | median " in out.read_text()


def test_a_bad_drag_count_is_one_clear_error(tmp_path, capsys):
    from avgs_viewer.app import main

    if not DEMO.is_file():
        pytest.skip("the bundled demo scene is missing (scripts/make_demo.sh)")
    out = tmp_path / "viewer.md"
    assert main([str(DEMO), "--bench", str(out), "--bench-drags", "0"]) == 2
    assert "--bench-drags must be at least 1, got 0" in capsys.readouterr().err
    assert not out.exists()
