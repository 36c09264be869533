"""``avgs sweep --address`` on a real multi-node Ray cluster, and a node lost mid-sweep.

The cluster is Ray's own ``cluster_utils.Cluster``: a head (no CPUs: only the driver's
services) and three worker nodes of one CPU each, every one a real raylet with its own
object store, on this machine. A node is lost by ``Cluster.remove_node`` (its raylet,
object store and workers SIGKILLed), and a fresh one joins. Everything on the cluster is in
the slow suite (``make test-all``; a minute of CPU, a tenth of the default suite's): a
one-run sweep whose node is lost, two runs scored with one lost (the other goes on, the report
holds every run once), a run lost beyond its retries, a local sweep beside a cluster. The run
folder's lock (:mod:`avgs.sweep.lock`) is tested without Ray in the default suite: it outlives
the worker while a subprocess it started still runs.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from avgs.sweep.lock import LOCK, FolderBusy, run_lock
from avgs.sweep.state import checkpoint_progress, read_status

TINY = "--quick --init sfm --no-gaussians --stage1-init-points 300"
ITERATIONS, EVERY = 120, 20
LEAN = dict(include_dashboard=False, object_store_memory=80 * 1024**2)
"Each node's Ray: no dashboard, an 80 MB object store (a run's arguments and record are a few kB)."
FAST_HEALTH_CHECK = {"health_check_initial_delay_ms": 0, "health_check_period_ms": 500, "health_check_failure_threshold": 4}
"How often the head asks its nodes whether they live: a lost node is known in 2 s, not Ray's default 15 s."


@pytest.fixture(scope="module")
def cluster():
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args=dict(num_cpus=0, _system_config=FAST_HEALTH_CHECK, **LEAN))
    for _ in range(3):
        cluster.add_node(num_cpus=1, **LEAN)
    cluster.wait_for_nodes()
    yield cluster
    cluster.shutdown()


def _train_processes(ckpt: Path) -> list[int]:
    """Pids of ``avgs train`` processes writing ``ckpt`` (Linux /proc)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                state = (entry / "stat").read_text().split(") ")[-1][:1]
            except OSError:
                continue
            if "avgs.cli" in cmd and " train " in cmd and str(ckpt) in cmd and state != "Z":
                pids.append(int(entry.name))
    return pids


def _stage2_iterations(log: Path) -> list[int]:
    """The stage-2 iterations a training log records (a line being appended is left out)."""
    try:
        lines = log.read_text().splitlines()
    except OSError:
        return []
    records = []
    for line in lines:
        try:
            records.append(json.loads(line))
        except ValueError:
            pass
    return [r["iteration"] for r in records if r.get("stage") == "stage2"]


@pytest.mark.slow  # the cluster: see the module's docstring
def test_a_local_sweep_never_joins_a_cluster_found_on_the_machine(cluster):
    """Without --address the sweep starts a Ray of its own, even with a cluster running here
    (Ray's default would join the newest one it finds, and refuse num_cpus)."""
    from avgs.sweep.cluster import connected

    with connected("", num_cpus=1) as resources:
        assert resources["CPU"] == 1
    assert len([n for n in cluster.list_all_nodes() if n.any_processes_alive()]) == 4


def _lose_a_node(cluster, scene: Path, out: Path, seeds: list[int], split: str) -> dict:
    """``avgs sweep --address`` of ``seeds`` runs; the node of the first run to train past a periodic
    checkpoint (between two of them) is killed, and a fresh node joins (as an autoscaler would
    bring one). What happened."""
    argv = [sys.executable, "-m", "avgs.cli", "sweep", "--address", cluster.address, "--data", str(scene.parent),
            "--out", str(out), "--setting", "avgs=", f"--common={TINY} --iterations {ITERATIONS} --checkpoint-every {EVERY}",
            "--seeds", *map(str, seeds), "--retries", "0", "--eval-split", split, "--no-progress"]
    folders = [out / scene.name / "avgs" / f"seed{k}" for k in seeds]
    sweep = subprocess.Popen(argv, env=dict(os.environ, OMP_NUM_THREADS="1"), stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    try:
        victim = None
        deadline = time.monotonic() + 180
        while victim is None and sweep.poll() is None and time.monotonic() < deadline:
            for folder in folders:
                progress = checkpoint_progress(folder / "scene.ckpt")
                status = read_status(folder) or {}
                if progress and 0 < progress[0] and not progress[1] and status.get("status") == "running":
                    reached = max(_stage2_iterations(folder / "scene.ckpt.log.jsonl"), default=0)
                    if reached > progress[0]:  # past its checkpoint: the iterations since are lost
                        victim, seen, node_id = folder, progress[0], status["node"]
                        break
            time.sleep(0.05)
        assert victim is not None, "no run wrote a periodic checkpoint"
        node = next(n for n in cluster.worker_nodes if n.node_id == node_id)
        cluster.remove_node(node, allow_graceful=False)  # raylet, object store and workers: SIGKILL
        output = sweep.communicate(timeout=240)[0]
    finally:
        if sweep.poll() is None:
            sweep.kill()
        cluster.add_node(num_cpus=1, **LEAN)
    assert sweep.returncode == 0, output
    return dict(output=output, folders=folders, victim=victim, seen=seen, node=node_id, reached=reached)


def _check_resumed(lost: dict) -> int:
    """The lost run was placed again on another node and resumed from the checkpoint it had
    written: trained once from scratch, no iteration twice; its resumed iteration."""
    victim, node_id = lost["victim"], lost["node"]
    status = read_status(victim)
    resumed = status["resumed_from"]
    assert status["status"] == "resumed" and status["node"] != node_id
    assert lost["seen"] <= resumed < ITERATIONS and resumed % EVERY == 0
    assert status["lost"] == [{"host": status["host"], "node": node_id, "iteration": resumed}]
    assert status["reason"] == f"from iteration {resumed}; after 1 lost attempt (node {node_id[:8]})"
    commands = [line for line in (victim / "train.out").read_text().splitlines() if line.startswith("$ ")]
    trains = [c for c in commands if " train " in c]
    assert len(trains) == 2 and not trains[0].endswith("--resume") and trains[1].endswith("--resume"), commands
    log = [json.loads(line) for line in (victim / "scene.ckpt.log.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in log if r.get("stage") == "resume"] == [resumed]
    assert sum(r.get("stage") == "stage1" and r.get("event") == "done" for r in log) == 1  # stage 1 ran once
    iterations = _stage2_iterations(victim / "scene.ckpt.log.jsonl")
    assert iterations == sorted(set(iterations)) and iterations[-1] == ITERATIONS  # no iteration trained twice
    assert checkpoint_progress(victim / "scene.ckpt") == (ITERATIONS, True)
    assert _train_processes(victim / "scene.ckpt") == []  # the lost node's avgs train stopped
    print(f"lost node: at iteration {lost['reached']} (logged), checkpoint {lost['seen']}; resumed from {resumed}")
    return resumed


@pytest.mark.slow  # the cluster: see the module's docstring
def test_a_lost_node_s_run_resumes_on_another(cluster, quick_scene, tmp_path):
    """One run; its node is killed after a periodic checkpoint (--retries 0: a lost node is not a
    failure of the run). The sweep finishes with the run resumed on another node, listed once."""
    lost = _lose_a_node(cluster, quick_scene, tmp_path / "runs", [0], "none")
    _check_resumed(lost)
    report = json.loads((tmp_path / "runs" / "results.json").read_text())
    assert [(r["run"], r["status"]) for r in report["runs"]] == [(f"{quick_scene.name}/avgs/seed0", "resumed")]


@pytest.mark.slow
def test_a_lost_node_mid_sweep_loses_nothing(cluster, quick_scene, tmp_path):
    """Two runs, scored; the node of the first to write a periodic checkpoint is killed. That run
    resumes elsewhere, the other goes on undisturbed, and the sweep ends with both runs scored,
    each exactly once in the report and the tables."""
    out = tmp_path / "runs"
    lost = _lose_a_node(cluster, quick_scene, out, [0, 1], "val")
    _check_resumed(lost)
    (other,) = [f for f in lost["folders"] if f != lost["victim"]]
    assert read_status(other)["status"] == "trained" and read_status(other)["lost"] == []
    for folder in lost["folders"]:
        assert checkpoint_progress(folder / "scene.ckpt") == (ITERATIONS, True)
        assert (folder / LOCK).is_file() and (folder / "eval-val.json").is_file()
    report = json.loads((out / "results.json").read_text())
    assert [r["run"] for r in report["runs"]] == [f"{quick_scene.name}/avgs/seed{k}" for k in (0, 1)]
    assert all(r["scores"] for r in report["runs"])
    assert report["results"]["avgs"]["scenes"][quick_scene.name]["MAG"]["n"] == 2
    assert lost["output"].count(f"{quick_scene.name}/avgs/seed") == 4  # a line as each ended, a row in the table


def test_the_lock_outlives_its_holder_while_a_subprocess_it_started_runs(tmp_path):
    """What keeps a lost node's ``avgs train`` and the run placed again from writing one folder:
    the lock passes to the subprocess, and the next taker waits until that has exited."""
    with run_lock(tmp_path) as fd:
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3)"], pass_fds=(fd,))
    # The holder is gone (its descriptor closed); the child still holds the folder.
    with pytest.raises(FolderBusy, match=f"{tmp_path}: in use by .* pid {os.getpid()} for 0 s"):
        with run_lock(tmp_path, wait=0.3):
            pass
    told = []
    with run_lock(tmp_path, wait=60, on_wait=told.append):
        assert child.poll() is not None  # taken only once the child had exited
    assert told == [f"{os.uname().nodename} pid {os.getpid()}"]
    child.wait()


@pytest.mark.slow
def test_a_run_lost_beyond_its_retries_is_failed_with_why_and_keeps_its_checkpoint(cluster, quick_scene, tmp_path,
                                                                                     monkeypatch):
    """The driver's side: a run whose node is lost once more than Ray may place it again ends
    as failed, saying it was lost and how to go on; its status.json says so too (not "running"
    for ever), its checkpoint is kept, and the next sweep would resume from it."""
    import threading

    from avgs.sweep import cluster as on_ray
    from avgs.sweep.spec import SweepSpec, expand
    from avgs.sweep.state import INTERRUPTED, run_state

    monkeypatch.setattr(on_ray, "LOST_RETRIES", 0)
    spec = SweepSpec(data=str(quick_scene.parent), out=str(tmp_path / "runs"), seeds=[0], eval_split="none",
                     settings={"avgs": f"{TINY} --iterations {ITERATIONS} --checkpoint-every {EVERY}"}).validate()
    (run,) = expand(spec, [quick_scene])
    killed = []

    def kill_at_first_checkpoint():
        while not (checkpoint_progress(run.checkpoint) or (0, False))[0]:
            time.sleep(0.05)
        node_id = read_status(run.folder)["node"]
        cluster.remove_node(next(n for n in cluster.worker_nodes if n.node_id == node_id), allow_graceful=False)
        killed.append(node_id)

    records = []
    killer = threading.Thread(target=kill_at_first_checkpoint, daemon=True)
    try:
        with on_ray.connected(cluster.address):
            killer.start()
            on_ray.run_all([run], 1, 0.0, 0, "none", lambda r, record: records.append(record))
        killer.join(timeout=30)
    finally:
        cluster.add_node(num_cpus=1, **LEAN)
    ((record,),) = [records]
    assert killed and record["status"] == "failed"
    reason = record["reason"]  # one line: Ray's first sentence, then what to do
    assert reason.startswith("lost: NodeDiedError: ") and "node" in reason[21:] and "\n" not in reason
    assert reason.endswith("; start the sweep again to resume from its checkpoint") and len(reason) < 200, reason
    status = read_status(run.folder)
    assert (status["status"], status["reason"], status["node"]) == ("failed", record["reason"], killed[0])
    state = run_state(run, "none")
    assert state.training == INTERRUPTED and state.iteration >= EVERY
