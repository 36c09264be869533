"""``avgs bench`` on a tiny scene: the report's structure, never its timings."""

from __future__ import annotations

import json

import pytest

from avgs.bench.latency import SYNTHESES
from avgs.bench.report import SECTIONS, headline
from avgs.bench.speed_error import simulator_available, summarise
from avgs.cli import main as cli_main
from rwavs_writer import write_scene


@pytest.mark.slow  # ~35 s: the whole `avgs bench --quick`, training its models (make test-all)
def test_bench_quick_writes_the_report(tmp_path, capsys, one_source_ckpt):
    """Every section, with a mask-model (binaural task) checkpoint for the latency section (the
    bundled demo is an impulse-response one: its source-aware render is timed in test_rir_model.py)."""
    scene = write_scene(tmp_path / "data", n_train=12, n_val=3, seed=0)
    out = tmp_path / "bench"
    argv = ["bench", "--quick", "--data", str(scene.scene_dir), "--out", str(out), "--presets", "",
            "--iterations", "8", "--points", "120", "--repeats", "3", "--ckpt", str(one_source_ckpt)]
    assert cli_main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("inference median ") and lines[-1].endswith(" ms per pose (cpu, demo scene)")
    float(lines[-1].split()[2])
    report = (out / "REPORT.md").read_text()
    headings = [line[3:] for line in report.splitlines() if line.startswith("## ")]
    assert headings == list(SECTIONS)
    assert "Command: `" in report and "| cpu |" in report
    for label in ("mono-mono", "mono-energy", "stereo-energy", "AV-GS vicinity 5 %", "AV-GS vicinity 25 %",
                  "pruned to walkable (exact)", "bfloat16", "uncached", "training-mode"):
        assert label in report
    for png in ("latency.png", "speed_error.png", "points.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    results = json.loads((out / "results.json").read_text())
    assert set(results["latency"]["cpu"]["stages"]) == {"vicinity", "field", "binauralizer", "synthesis"}  # no filter: mid phase
    assert set(results["latency"]["cpu"]["syntheses"]) == set(SYNTHESES)
    for label in SYNTHESES:  # each synthesis timed on the demo and scored on the bench's scene
        assert label in report
    assert set(results["latency"]["cpu"]["long"]) == {"10", "60"}
    for path in results["latency"]["cpu"]["paths"].values():  # the same model code without its caches
        assert path["max_abs_diff"] < 1e-4
    assert {t["stage"] for t in results["training"]} == {1, 2}
    assert (out / "work" / ".gitignore").read_text() == "*\n"  # trained bench models stay out of git


def test_a_partial_run_keeps_the_skipped_sections_with_their_run(tmp_path, capsys):
    """``--skip`` keeps each skipped section from OUT/results.json (here the repository's own, a real run), marked
    with that run's date and command, through a second partial run too; a --quick run does not mix with it, and a
    file that is not a bench's results is said so, not fatal."""
    from collections import Counter
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[1] / "benchmarks" / "results.json"
    before = json.loads(shipped.read_text())
    out = tmp_path / "bench"
    out.mkdir()
    (out / "results.json").write_text(shipped.read_text())
    skip = ["--skip", "latency", "--skip", "speed-error", "--skip", "training", "--presets", "", "--out", str(out)]
    for _ in range(2):  # the second run carries what the first carried, with the first provenance
        assert cli_main(["bench", *skip]) == 0
        results = json.loads((out / "results.json").read_text())
        for key in ("latency", "demo", "speed_error", "training"):
            assert results[key] == before[key]
        run = {"date_utc": before["machine"]["date_utc"], "command": before["machine"]["command"]}
        origin = {key: before.get("carried", {}).get(key, run) for key in ("latency", "demo", "speed_error", "training")}
        assert results["carried"] == origin  # the run that measured each, however often it was carried since
        assert results["machine"]["date_utc"] != run["date_utc"]  # this run's own machine record
    report = (out / "REPORT.md").read_text()
    assert [line[3:] for line in report.splitlines() if line.startswith("## ")] == list(SECTIONS)
    marks = Counter()  # each kept section says which run measured it (speed_error: and the point budgets)
    for key, sections in (("latency", 1), ("speed_error", 2), ("training", 1)):
        marks[f"*Kept from the run of {origin[key]['date_utc']} (`{origin[key]['command']}`)"] += sections
    assert {mark: report.count(mark) for mark in marks} == marks
    assert f"median **{before['latency']['cpu']['render']['median_ms']:.2f} ms** per pose" in report
    assert "(not run)" not in report

    quick = tmp_path / "quick"
    quick.mkdir()
    (quick / "results.json").write_text(shipped.read_text())
    capsys.readouterr()
    assert cli_main(["bench", "--quick", *skip[:-1], str(quick)]) == 0
    assert "is from a run without --quick" in capsys.readouterr().out
    results = json.loads((quick / "results.json").read_text())
    assert "carried" not in results and "latency" not in results
    (quick / "results.json").write_text("{not json")
    assert cli_main(["bench", *skip[:-1], str(quick)]) == 0
    assert "is not a results.json of avgs bench" in capsys.readouterr().out


def test_headline_compares_avgs_with_the_simulator():
    rows = [
        {"label": "AV-GS vicinity 15 %", "family": "AV-GS vicinity", "latency_ms": 2.0, "MAG": 0.5, "ENV": 0.1},
        {"label": "simulator order 2", "family": "simulator (image source)", "latency_ms": 80.0, "MAG": 0.4, "ENV": 0.1,
         "order": 2, "ray_tracing": False},
        {"label": "simulator order 10 + rays", "family": "simulator (rays)", "latency_ms": 1000.0, "MAG": 0.05, "ENV": 0.02,
         "order": 10, "ray_tracing": True},
    ]
    text = headline(summarise([{"rows": [dict(r, scene="s") for r in rows]}]))
    assert "500x" in text and "simulator order 2" in text and "40x" in text
    assert "eight phase iterations" not in text  # no synthesis rows in this run


def test_headline_says_whether_the_default_synthesis_matches_eight_iterations():
    ref = {"label": "AV-GS vicinity 15 %", "family": "AV-GS vicinity", "latency_ms": 5.0, "MAG": 0.120, "ENV": 0.05}
    eight = [{"label": f"AV-GS 15 % {p} phase + 8 iterations", "family": "AV-GS synthesis", "latency_ms": 9.0, "MAG": m,
              "ENV": 0.05} for p, m in (("filter", 0.121), ("source", 0.125))]
    text = headline(summarise([{"rows": [dict(r, scene="s") for r in [ref, *eight]]}]))
    assert "is at least as good in MAG as eight phase iterations per ear" in text
    assert "filter phase + 8 iterations 0.1210 / 0.0500 in 9.00 ms" in text
    worse = dict(ref, MAG=0.1215)
    text = headline(summarise([{"rows": [dict(r, scene="s") for r in [worse, *eight]]}]))
    assert "is not as good in MAG as eight phase iterations" in text


@pytest.mark.skipif(simulator_available() is not None, reason="scene generator not installed")
def test_simulator_points_on_a_generated_scene(tmp_path):
    from avgs.bench.speed_error import simulator_points
    from avgs.data.rwavs import RWAVSScene

    root = tmp_path / "synth"
    assert cli_main(["synth", str(root), "--preset", "office", "--scene-id", "o", "--poses", "8", "--quick", "--no-progress"]) == 0
    scene = RWAVSScene(root / "o")
    rows = simulator_points(root / "o", scene, orders=(0, 1), ray_tracing=(False,), max_poses=1)
    assert [r["label"] for r in rows] == ["simulator order 0", "simulator order 1"]
    assert all(r["latency_ms"] > 0 and r["MAG"] >= 0 and r["ENV"] >= 0 for r in rows)


def test_interleaved_timing_takes_turns_in_blocks():
    from avgs.bench.timing import time_interleaved

    calls = []
    t = time_interleaved({k: (lambda i, k=k: calls.append((k, i))) for k in "abc"}, repeats=5, block=2)
    # three rounds; each function: one untimed call, then two timed ones, on the same indices
    assert calls == [(k, i) for r in range(3) for k in "abc" for i in (2 * r, 2 * r, 2 * r + 1)]
    assert {k: v.n for k, v in t.items()} == {"a": 5, "b": 5, "c": 5}


def test_the_syntheses_are_timed_on_the_same_poses(one_source_ckpt):
    from avgs.bench.speed_error import synthesis_latencies
    from avgs.render.renderer import SceneRenderer

    seen = []

    class Spy:
        def __init__(self, r, name):
            self.r, self.name, self.sample_rate = r, name, r.sample_rate
            self.bounds, self.source = r.bounds, r.source

        def render(self, listener, yaw, mono):
            seen.append((self.name, tuple(listener), yaw))
            return self.r.render(listener, yaw, mono)

    r = SceneRenderer.load(one_source_ckpt)
    t = synthesis_latencies({"x": Spy(r, "x"), "y": Spy(r, "y")}, repeats=8)
    assert t["x"].n == t["y"].n == 8
    xs = [s[1:] for s in seen if s[0] == "x"]
    assert xs == [s[1:] for s in seen if s[0] == "y"]  # the same poses, in the same order
    assert len(set(xs)) == 8  # (the untimed call of a block repeats its first pose)


def test_the_default_is_also_timed_with_a_new_clip_at_every_pose(one_source_ckpt):
    """The bench's one-clip renders keep the clip's analysis (the explorer's case); beside them
    the default is timed with a clip no call before it used, on the same poses."""
    from avgs.bench.speed_error import NEW_CLIP, synthesis_latencies
    from avgs.render.renderer import SceneRenderer

    heard = {"same": [], "new": []}

    class Spy:
        def __init__(self, r, name):
            self.r, self.name, self.sample_rate = r, name, r.sample_rate
            self.bounds, self.source = r.bounds, r.source

        def render(self, listener, yaw, mono):
            heard[self.name].append((tuple(listener), yaw, mono.tobytes()))
            return self.r.render(listener, yaw, mono)

    r = SceneRenderer.load(one_source_ckpt)
    t = synthesis_latencies({"x": Spy(r, "same")}, repeats=8, new_clip=Spy(r, "new"))
    assert t[NEW_CLIP].n == t["x"].n == 8
    assert len({clip for *_, clip in heard["same"]}) == 1
    clips = [clip for *_, clip in heard["new"]]
    assert all(a != b for a, b in zip(clips, clips[1:]))  # the untimed call of a block too
    assert [p[:2] for p in heard["new"]] == [p[:2] for p in heard["same"]]  # the same poses, in the same order


def test_headline_gives_a_pose_with_a_new_clip_against_the_target():
    ref = {"label": "AV-GS vicinity 15 %", "family": "AV-GS vicinity", "latency_ms": 3.2, "MAG": 0.12, "ENV": 0.05,
           "new_clip_ms": 3.9}
    text = headline(summarise([{"rows": [dict(ref, scene="a")]}, {"rows": [dict(ref, scene="b", new_clip_ms=4.1)]}]))
    assert "**3.20 ms**" in text and "a new clip at every pose" in text and "**4.00 ms**" in text
    assert "at most 5 ms on 2 CPU cores" in text
