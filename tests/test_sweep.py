"""``avgs sweep``: the grid (flags and TOML), where a run stands, the report over seeds, and a
real sweep on Ray: a run interrupted by SIGINT to the sweep and resumed, a run that fails.

The fast tests need no Ray: they train tiny runs in this process on the quick scene. The
Ray test (slow: about a minute on 2 shared cores) runs ``avgs sweep`` as a user would.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from avgs.io.atomic import write_json
from avgs.cli import main
from avgs.evaluation.binaural import CheckpointMethod, aggregate, evaluate
from avgs.sweep import results
from avgs.sweep.driver import check_resources
from avgs.sweep.spec import SweepSpec, expand, make_spec
from avgs.sweep.state import FINISHED, INTERRUPTED, NEW, check_folder, eval_path, run_state, write_status
from avgs.train import pipeline
from avgs.train.pipeline import quick_config, train_scene

TINY = "--quick --init sfm --no-gaussians --stage1-init-points 300"


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_grid_from_toml_and_flags(tmp_path):
    toml = write(tmp_path / "sweep.toml", """
data = "DATA"
out = "OUT"
seeds = [0, 2]
common = "--iterations 50 --stage1 'stage 1/{scene}.pt'"
threads-per-run = 2
[settings]
avgs = ""
no-context = ["--no-context"]
""")
    scenes = [tmp_path / "a", tmp_path / "b"]
    spec = make_spec(toml, {"out": str(tmp_path / "runs"), "seeds": None})
    assert spec.threads_per_run == 2 and spec.seeds == [0, 2] and spec.data == "DATA"
    runs = expand(spec, scenes)
    assert [r.name for r in runs] == [f"{s}/{c}/seed{k}" for s in "ab" for c in ("avgs", "no-context") for k in (0, 2)]
    run = runs[3]  # a/no-context/seed2
    assert run.folder == (tmp_path / "runs" / "a" / "no-context" / "seed2").resolve()
    assert run.checkpoint.name == "scene.ckpt"
    assert run.options == ("--iterations", "50", "--stage1", "stage 1/a.pt", "--no-context", "--seed", "2")
    gpu = expand(make_spec(toml, {"gpus_per_run": 0.25}), scenes[:1])[0]
    assert gpu.options[-4:] == ("--device", "cuda", "--seed", "0")
    with pytest.raises(ValueError, match="asks for 0.25 GPU; the Ray cluster has 0 GPUs"):
        check_resources(make_spec(toml, {"gpus_per_run": 0.25}), {"CPU": 16.0})
    with pytest.raises(ValueError, match="asks for 2 CPU threads; the Ray cluster has 1 CPUs"):
        check_resources(spec, {"CPU": 1.0})
    # Another scoring, another score file; none: eval-<split>.json.
    phase = expand(make_spec(toml, {"eval_options": "--phase source"}), scenes[:1])[0]
    assert phase.scoring == ("--phase", "source") and run.scoring == ()
    assert eval_path(run, "val").name == "eval-val.json"
    assert eval_path(phase, "val").name.startswith("eval-val-") and eval_path(phase, "val") != eval_path(phase, "train")

    bad = [
        ("unknown = 1\ndata = 'x'", "unknown key 'unknown'"),
        ("data = 'x'\nseeds = [0, 'one']", "expected a list of int"),
        ("data = 'x'\nthreads_per_run = 0", "threads per run must be >= 1"),
        ("data = 'x'\n[settings]\n'a b' = ''", "setting name 'a b'"),
        ("data = 'x'\nseeds = [1, 1]", "a seed is repeated"),
        ("data = 'x'\ncommon = \"--iterations '5\"", "No closing quotation"),
        ("data = = 'x'", "not valid TOML"),
    ]
    for text, message in bad:
        with pytest.raises(ValueError, match=message):
            make_spec(write(tmp_path / "bad.toml", text), {})
    for options, flag in (("--seed 3", "--seed"), ("--out=x.ckpt", "--out"), ("--resume", "--resume")):
        with pytest.raises(ValueError, match=f"{flag} is set by the sweep itself"):
            expand(SweepSpec(data="x", settings={"s": options}).validate(), scenes)
    with pytest.raises(ValueError, match="no data root"):
        make_spec(None, {})


def test_cli_dry_run_and_errors(quick_scene, tmp_path, capsys):
    root, out = str(quick_scene.parent), str(tmp_path / "runs")
    args = ["sweep", "--data", root, "--setting", "avgs=", "--setting", "nc=--no-context", "--seeds", "0", "1",
            f"--common={TINY} --iterations 7", "--out", out, "--dry-run"]
    assert main(args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "office_quick/avgs/seed0: train"
    assert lines[1].strip().startswith("avgs --threads 1 train ") and lines[1].endswith(
        "--iterations 7 --seed 0 --no-progress")
    assert [l.split(":")[0] for l in lines[::2]] == [f"office_quick/{s}/seed{k}" for s in ("avgs", "nc") for k in (0, 1)]

    def error(*argv) -> str:
        assert main(["sweep", "--data", root, "--out", out, "--dry-run", *argv]) == 2
        return capsys.readouterr().err

    assert "unrecognized arguments: --bogus" in error("--setting", "x=--bogus 3")
    assert "--setting 'avgs'" in error("--setting", "avgs")
    assert "--iterations: invalid int value" in error("--setting", "x=--iterations many")
    assert "office_nope" in error("--scenes", "office_nope")
    assert "--eval-options '--phase nope'" in error("--eval-options=--phase nope")
    assert "not a folder" in main_error(["sweep", "--data", root, "--out", str(quick_scene / "scene.json")], capsys)


def main_error(argv, capsys) -> str:
    assert main(argv) == 2
    return capsys.readouterr().err


@pytest.fixture(scope="module")
def tiny_runs(quick_scene, tmp_path_factory):
    """Two finished runs (seeds 0 and 1) and one interrupted (seed 2, its first checkpoint), trained here
    in run folders of a sweep; returns (spec, runs)."""
    out = tmp_path_factory.mktemp("sweep")
    spec = SweepSpec(data=str(quick_scene.parent), out=str(out), settings={"avgs": TINY}, seeds=[0, 1, 2, 3]).validate()
    runs = expand(spec, [quick_scene])
    for run in runs[:3]:
        cfg = quick_config()
        cfg.init, cfg.store_gaussians, cfg.seed = "sfm", False, run.seed
        cfg.gaussians.init_points, cfg.acoustic.iterations, cfg.checkpoint_every = 300, 6, 3
        run.folder.mkdir(parents=True)
        saved = []
        save = pipeline.save_checkpoint

        def first_only(ckpt, path, save=save, saved=saved):  # the checkpoint of a run stopped after iteration 3
            if saved and run.seed == 2:
                raise KeyboardInterrupt
            saved.append(path)
            return save(ckpt, path)

        pipeline.save_checkpoint = first_only
        try:
            train_scene(quick_scene, run.checkpoint, cfg, progress=False)
        except KeyboardInterrupt:
            pass
        finally:
            pipeline.save_checkpoint = save
    return spec, runs


def test_run_state(tiny_runs):
    spec, runs = tiny_runs
    states = [run_state(run, "val") for run in runs]
    assert [(s.training, s.iteration, s.scored) for s in states] == [
        (FINISHED, 6, False), (FINISHED, 6, False), (INTERRUPTED, 3, False), (NEW, 0, False)]
    assert [s.needs_work("val") for s in states] == [True, True, True, True]
    assert [s.needs_work("none") for s in states] == [False, False, True, True]
    # A folder made with other options is refused.
    write_status(runs[0].folder, {"options": ["--quick", "--seed", "0"]})
    with pytest.raises(ValueError, match="made with the options '--quick --seed 0'"):
        check_folder(runs[0])
    write_status(runs[0].folder, {"options": list(runs[0].options)})
    check_folder(runs[0])


def test_results_over_seeds(tiny_runs, quick_scene):
    spec, runs = tiny_runs
    scores = []
    for run in runs[:2]:  # the finished ones, scored as avgs eval scores them
        report = evaluate({f"ckpt:{run.checkpoint}": CheckpointMethod(run.checkpoint)}, [quick_scene], progress=False)
        write_json(eval_path(run, "val"), report)
        scores.append(report["methods"][f"ckpt:{run.checkpoint}"]["scenes"][quick_scene.name])
        assert run_state(run, "val").scored
    records = {runs[0].name: {"status": "trained", "seconds": 3.0}, runs[2].name: {"status": "failed", "reason": "exit code 2: boom"}}
    report = results.collect(runs, records, "val")
    entry = report["results"]["avgs"]
    scene = entry["scenes"][quick_scene.name]
    for metric in ("MAG", "ENV", "ILD", "MAGp"):
        values = np.array([s[metric] for s in scores])
        assert scene[metric]["n"] == 2
        assert math.isclose(scene[metric]["mean"], values.mean(), rel_tol=1e-12)
        assert math.isclose(scene[metric]["std"], values.std(ddof=1), rel_tol=1e-9)
    assert scores[0]["MAG"] != scores[1]["MAG"]  # two seeds, two models
    # Overall is RWAVS's (mean of environment means) per seed, then over seeds: one scene here.
    overall = [aggregate({quick_scene.name: s}, report["environments"])["overall"]["MAG"] for s in scores]
    assert math.isclose(entry["overall"]["MAG"]["mean"], float(np.mean(overall)), rel_tol=1e-12)
    assert [r["status"] for r in report["runs"]] == ["trained", "not run", "failed", "not run"]
    assert report["runs"][2]["scores"] is None
    json.dumps(report, allow_nan=False)

    table = results.format_results(report)
    mag = scene["MAG"]
    assert f"{mag['mean']:.4f} ± {mag['std']:.4f}" in table
    assert table.splitlines()[-1].startswith("overall")
    md = results.format_markdown(report)
    assert f"| scene {quick_scene.name} | avgs | {mag['mean']:.4f} ± {mag['std']:.4f} |" in md
    assert "exit code 2: boom" in results.format_runs(report)
    # One seed: a mean and no spread.
    one = results.collect(runs[:1], {}, "val")["results"]["avgs"]["scenes"][quick_scene.name]["MAG"]
    assert one["std"] is None and one["n"] == 1 and results.cell(one, ".4f") == f"{scores[0]['MAG']:.4f}"


def test_a_failing_run_on_ray(quick_scene, tmp_path):
    """Ray in the default suite, cheaply: one run that fails at once is reported with its exit
    code and the line that says why, and the sweep goes on to its report."""
    pytest.importorskip("ray")
    from avgs.sweep.driver import sweep

    missing = tmp_path / "missing.stage1.pt"
    spec = SweepSpec(data=str(quick_scene.parent), out=str(tmp_path / "runs"), seeds=[0], num_cpus=1, retries=0,
                     settings={"broken": f"{TINY} --init gs --stage1 {missing}"}, eval_split="none").validate()
    runs = expand(spec, [quick_scene])
    report = sweep(spec, runs, progress=False, echo=lambda line: None)
    (row,) = report["runs"]
    assert row["status"] == "failed" and not report["interrupted"]
    assert row["reason"].startswith("train: exit code 2: avgs train: error: ") and str(missing) in row["reason"]
    status = json.loads((runs[0].folder / "status.json").read_text())
    assert status["returncode"] == 2 and status["attempts"] == 1 and status["options"] == list(runs[0].options)
    assert json.loads((tmp_path / "runs" / "results.json").read_text())["runs"][0]["status"] == "failed"


def _sweep_processes(out: Path) -> list[int]:
    """Pids of avgs processes still writing under ``out`` (Linux /proc)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if "avgs.cli" in cmd and str(out) in cmd:
                pids.append(int(entry.name))
    return pids


@pytest.mark.slow
def test_sweep_on_ray_interrupted_resumed_and_failed(quick_scene, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "runs"
    argv = [sys.executable, "-m", "avgs.cli", "sweep", "--data", str(quick_scene.parent), "--out", str(out),
            "--setting", "avgs=", "--setting", "no-context=--no-context",
            "--setting", f"broken=--init gs --stage1 {tmp_path / 'missing.stage1.pt'}",
            f"--common={TINY} --iterations 80 --checkpoint-every 10", "--seeds", "0",
            "--num-cpus", "2", "--retries", "0", "--no-progress"]
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    first = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ckpts = [out / quick_scene.name / s / "seed0" / "scene.ckpt" for s in ("avgs", "no-context")]
    deadline = time.monotonic() + 240
    while not any(c.is_file() for c in ckpts) and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    first.send_signal(signal.SIGINT)  # Ctrl+C: the runs going on stop, their checkpoints stay
    output = first.communicate(timeout=120)[0]
    assert first.returncode == 130, output
    assert "interrupted: start the same sweep again to resume" in output
    if Path("/proc").is_dir():
        time.sleep(1.0)
        assert _sweep_processes(out) == [], "avgs train outlived the interrupted sweep"
    stopped = {c.parent.parent.name: run_state_of(c) for c in ckpts if c.is_file()}
    assert stopped and all(not finished for _, finished in stopped.values()), stopped

    second = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=400)
    assert second.returncode == 1, second.stdout + second.stderr  # one run failed
    report = json.loads((out / "results.json").read_text())
    status = {r["setting"]: r for r in report["runs"]}
    assert status["broken"]["status"] == "failed"
    assert "exit code 2" in status["broken"]["reason"] and "missing.stage1.pt" in status["broken"]["reason"]
    for setting, (iteration, _) in stopped.items():
        if iteration > 0:  # stopped after its first checkpoint: resumed from it
            assert status[setting]["status"] == "resumed", status[setting]
            log = (ckpts[0].parent.parent.parent / setting / "seed0" / "scene.ckpt.log.jsonl").read_text().splitlines()
            assert {"stage": "resume", "iteration": iteration} == {k: v for k, v in json.loads(
                next(l for l in log if '"resume"' in l)).items() if k != "file"}
    for c in ckpts:
        assert run_state_of(c) == (80, True)
    assert set(report["results"]) == {"avgs", "no-context"}
    assert report["results"]["avgs"]["overall"]["MAG"]["n"] == 1
    assert "overall" in second.stdout and "no-context" in second.stdout

    # Again: the finished runs are skipped; only the failed one is tried again.
    mtimes = [c.stat().st_mtime_ns for c in ckpts]
    third = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=400)
    assert third.returncode == 1
    assert "3 runs, 1 to run, 2 finished before" in third.stdout
    assert [c.stat().st_mtime_ns for c in ckpts] == mtimes
    shutil.rmtree(out / quick_scene.name / "broken")


def run_state_of(ckpt: Path) -> tuple[int, bool]:
    from avgs.sweep.state import checkpoint_progress

    return checkpoint_progress(ckpt)
