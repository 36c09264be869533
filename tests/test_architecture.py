"""The model library never imports the viewer or Qt (import-linter contract in pyproject.toml)."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_hold():
    exe = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    proc = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "KEPT" in proc.stdout


def test_import_avgs_is_light():
    code = "import sys, avgs; bad = [m for m in ('PySide6', 'pyvista', 'open3d', 'pyroomacoustics') if m in sys.modules]; print(bad)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


# -- the task seam (avgs.tasks) ------------------------------------------------------------

import ast  # noqa: E402
import inspect  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from avgs.tasks import TASKS, Task, task_named  # noqa: E402

PARTS = ("model", "renderer", "training", "evaluation", "data", "synth")
EVALUATION_API = ("DEFAULT_METHODS", "DEFAULT_SPLIT", "SPLITS", "check_request", "checkpoint_paths", "scenes",
                  "load_method", "evaluate", "format_report")


def _members(protocol) -> set[str]:
    own = set(vars(protocol)) | set(getattr(protocol, "__annotations__", {}))
    return {m for m in own if not m.startswith("_")}


@pytest.mark.parametrize("name", sorted(TASKS))
def test_every_part_of_every_task_resolves_and_keeps_its_layers_contract(name):
    from avgs.render.tasks import TaskModel
    from avgs.train.tasks import TaskTraining

    from avgs.io.checkpoint import untrained_checkpoint
    from avgs.render.renderer import SceneRenderer

    task = TASKS[name]
    assert task_named(name) is task and task.name == name
    parts = {field: task.part(field) for field in PARTS}
    renderer = (SceneRenderer.load(ROOT / "assets" / "demo" / "scene.ckpt") if task.source_aware
                else SceneRenderer(untrained_checkpoint(np.random.default_rng(0).uniform(-1, 1, (80, 3)), np.zeros(3), seed=0)))
    assert renderer.kind is task and isinstance(renderer.task_model, parts["renderer"])
    for member in ("build", "build_binauralizer", "config_problem"):
        assert callable(getattr(parts["model"], member)), f"{task.model} lacks {member}"
    for member in _members(TaskModel):
        assert hasattr(renderer.task_model, member), f"{task.renderer} lacks TaskModel.{member}"
        if callable(getattr(TaskModel, member, None)):
            want = list(inspect.signature(getattr(TaskModel, member)).parameters)
            have = list(inspect.signature(getattr(parts["renderer"], member)).parameters)
            assert have[: len(want)] == want, f"{task.renderer}.{member}{have} does not take TaskModel's {want}"
    assert parts["renderer"].source_aware is task.source_aware
    source = inspect.getsource(parts["training"])  # made from a scene folder: its attributes set in __init__
    for member in _members(TaskTraining):
        assert hasattr(parts["training"], member) or f"self.{member} = " in source, f"{task.training} lacks TaskTraining.{member}"
    for member in EVALUATION_API:
        assert hasattr(parts["evaluation"], member), f"{task.evaluation} lacks {member}"
    assert callable(parts["data"]) and callable(parts["synth"])


def test_an_unknown_task_is_refused_by_name():
    with pytest.raises(ValueError, match=r"--task must be one of 'binaural', 'rir', got 'nerf'"):
        task_named("nerf", "--task")
    with pytest.raises(ModuleNotFoundError, match="avgs.nowhere"):
        Task("x", "", False, "avgs.nowhere:X", "", "", "", "", "").part("model")


def _task_name_comparisons(path: Path) -> list[str]:
    """Places in ``path`` that compare something with a task's name (``x == "rir"``, ``t in ("binaural", "rir")``)."""
    names = set(TASKS)
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            for op in operands:
                values = op.elts if isinstance(op, (ast.Tuple, ast.List, ast.Set)) else [op]
                if any(isinstance(v, ast.Constant) and v.value in names for v in values):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return found


def test_nothing_outside_the_registry_branches_on_a_tasks_name():
    files = [p for pkg in ("avgs", "avgs_viewer") for p in sorted((ROOT / pkg).rglob("*.py")) if p.name != "tasks.py"
             or p.parent.name != "avgs"]
    found = [hit for p in files for hit in _task_name_comparisons(p)]
    assert found == [], "compare with the task's parts (avgs.tasks) instead: " + ", ".join(found)


def test_the_branch_finder_finds_branches(tmp_path):
    """The check above can fail: it sees the ways a task's name gets compared."""
    f = tmp_path / "x.py"
    f.write_text('if task == "rir":\n    pass\nok = kind in ("binaural", "rir")\nfine = {"rir": 1}\n')
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        assert _task_name_comparisons(f) == ["x.py:1", "x.py:3"]
    finally:
        ROOT = saved


def test_every_package_says_what_it_holds_and_modules_stay_small():
    for pkg in ("avgs", "avgs_viewer"):
        for init in (ROOT / pkg).rglob("__init__.py"):
            doc = ast.get_docstring(ast.parse(init.read_text()))
            assert doc and len(doc) > 40, f"{init.relative_to(ROOT)} does not say what its package holds"
        for module in (ROOT / pkg).rglob("*.py"):
            lines = len(module.read_text().splitlines())
            assert lines <= 650, f"{module.relative_to(ROOT)} has {lines} lines: split it by concept"
