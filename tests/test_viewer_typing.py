"""The explorer's view of a trained scene is typed (avgs_viewer.trained_scene.TrainedScene).

Three things are checked: the library's renderer (``avgs.SceneRenderer``, loaded from the bundled
demo) has every member the protocol declares, with values of the declared types and methods
callable as the protocol says; every parameter of avgs_viewer named ``renderer`` or ``scene`` is
annotated with the protocol (not ``Any``, not nothing); and the protocol lists exactly the
members that avgs_viewer reads or calls on the scene, no fewer and no more.
"""

from __future__ import annotations

import ast
import inspect
import typing
from pathlib import Path

import numpy as np
import pytest

import avgs
import avgs_viewer.state as viewer_state
import avgs_viewer.trained_scene as trained_scene
from avgs.config import STFTConfig, SynthesisConfig
from avgs.render.renderer import GaussianCloud, RenderResult, SceneRenderer
from avgs_viewer.trained_scene import BlockStream, TrainedScene

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "assets" / "demo" / "scene.ckpt"
VIEWER = ROOT / "avgs_viewer"
PROTOCOL = TrainedScene.__name__
SCENE_NAMES = ("renderer", "scene")

NOT_THE_SCENE = {
    # (module, function, parameter): its annotation, for parameters so named that are not the trained scene
    ("scene_view.py", "VtkProjector.__init__", "renderer"): "vtkRenderer",  # VTK's renderer of a plotter
    ("app.py", "resolve_scene", "scene"): "Path | None",  # the checkpoint's path
    ("app.py", "run_headless", "scene"): "Path",
    ("app.py", "run_window", "scene"): "Path",
    ("flythrough.py", "run_flythrough", "scene"): "Path",
    ("trained_scene.py", "_provided", "renderer"): "SceneRenderer",  # the library's, checked against the protocol
}
NOT_THE_SCENE_CLASSES = {("scene_view.py", "VtkProjector")}  # its self.renderer is VTK's

# The names the protocol module imports only for type checkers (the renderer imports torch).
LIBRARY_TYPES = {"GaussianCloud": GaussianCloud, "RenderResult": RenderResult, "STFTConfig": STFTConfig,
                 "SynthesisConfig": SynthesisConfig, "SceneRenderer": SceneRenderer}


def members(protocol: type) -> dict[str, object]:
    """The members a protocol class declares: its public attributes, properties and methods."""
    out = {name: value for name, value in vars(protocol).items() if not name.startswith("_")}
    out.update({name: None for name in vars(protocol).get("__annotations__", {}) if not name.startswith("_")})
    return out


def hints(fn) -> dict[str, object]:
    return typing.get_type_hints(fn, globalns=vars(trained_scene), localns=LIBRARY_TYPES)


def callable_as(protocol_fn, real_fn, where: str) -> None:
    """Every call the protocol's signature allows is one the real signature accepts."""
    P = inspect.Parameter
    declared = [p for p in inspect.signature(protocol_fn).parameters.values() if p.name != "self"]
    real = [p for p in inspect.signature(real_fn).parameters.values() if p.name != "self"]
    by_name = {p.name: p for p in real}
    positional = [p for p in real if p.kind in (P.POSITIONAL_ONLY, P.POSITIONAL_OR_KEYWORD)]
    for i, p in enumerate(declared):
        assert p.kind not in (P.VAR_POSITIONAL, P.VAR_KEYWORD), f"{where}: declare {p} by name"
        if p.kind in (P.POSITIONAL_ONLY, P.POSITIONAL_OR_KEYWORD):  # may be passed as argument i
            assert i < len(positional), f"{where}: {p.name!r} is positional argument {i}, which the renderer lacks"
            if p.kind is P.POSITIONAL_OR_KEYWORD:
                assert positional[i].name == p.name, \
                    f"{where}: positional argument {i} is {positional[i].name!r}, not {p.name!r}"
            real_p = positional[i]
        if p.kind in (P.POSITIONAL_OR_KEYWORD, P.KEYWORD_ONLY):  # may be passed by name
            assert p.name in by_name and by_name[p.name].kind in (P.POSITIONAL_OR_KEYWORD, P.KEYWORD_ONLY), \
                f"{where}: the renderer takes no argument {p.name!r}"
            real_p = by_name[p.name]
        if p.default is not P.empty:
            assert real_p.default is not P.empty, f"{where}: {p.name!r} may be left out, but the renderer needs it"
    used = {i for i, p in enumerate(declared) if p.kind in (P.POSITIONAL_ONLY, P.POSITIONAL_OR_KEYWORD)}
    named = {p.name for p in declared if p.kind in (P.POSITIONAL_OR_KEYWORD, P.KEYWORD_ONLY)}
    for i, p in enumerate(real):
        if p.kind in (P.VAR_POSITIONAL, P.VAR_KEYWORD) or p.default is not P.empty:
            continue
        assert i in used or p.name in named, f"{where}: the renderer needs {p.name!r}, which the protocol never passes"


@pytest.fixture(scope="module")
def demo() -> SceneRenderer:
    return avgs.SceneRenderer.load(DEMO)


def test_the_protocol_declares_the_explorers_members():
    declared = members(TrainedScene)
    assert {"sample_rate", "points", "bounds", "binaural_filter", "stream", "render"} <= set(declared)
    assert set(members(BlockStream)) == {"process"}


@pytest.mark.parametrize("name", sorted(members(TrainedScene)))
def test_scene_renderer_provides_each_member(demo, name):
    declared = members(TrainedScene)[name]
    assert hasattr(demo, name), f"SceneRenderer has no {name!r}, which TrainedScene declares"
    if isinstance(declared, property):
        expected = hints(declared.fget)["return"]
        value = getattr(demo, name)
        assert isinstance(value, expected), f"SceneRenderer.{name} is {type(value).__name__}, not {expected}"
    else:
        assert callable(declared) and callable(getattr(demo, name)), name
        callable_as(declared, getattr(SceneRenderer, name), f"SceneRenderer.{name}")
        hints(declared)  # every annotation names a type that exists


def test_the_protocols_methods_give_what_they_declare(demo):
    listener = np.asarray(demo.bounds, dtype=np.float64).mean(axis=0)
    result = demo.binaural_filter(listener, 30.0, source=demo.source)
    assert isinstance(result, RenderResult) and result.impulse is not None and result.impulse.shape[0] == 2
    assert isinstance(demo.reach_frames(), int)
    stream = demo.stream(tuple(listener), 30.0, source=None, block_frames=None)
    for name in members(BlockStream):
        callable_as(getattr(BlockStream, name), getattr(type(stream), name), f"{type(stream).__name__}.{name}")
    y = stream.process(np.zeros(4096, np.float32))
    assert isinstance(y, np.ndarray) and y.ndim == 2 and y.shape[0] == 2


def test_signature_check_fails_for_real():
    """The signature check above rejects what it should: an argument the renderer lacks, one in
    another place, one it needs that the protocol leaves out."""
    def real(self, listener, yaw: float, source=None, stop=None): ...
    def real_needs_source(self, listener, yaw: float, source): ...

    def lacks(self, listener, yaw: float, block_frames=None): ...
    def misplaced(self, yaw: float, listener): ...
    def too_few(self, listener): ...
    def optional(self, listener, yaw: float, source=None): ...
    def by_position(self, listener, yaw: float, /): ...

    for wrong, fn in ((lacks, real), (misplaced, real), (too_few, real), (optional, real_needs_source)):
        with pytest.raises(AssertionError):
            callable_as(wrong, fn, wrong.__name__)
    for right in (TrainedScene.binaural_filter, by_position):
        callable_as(right, real, right.__name__)


# -- the viewer's source ------------------------------------------------------------------
def viewer_modules() -> list[tuple[str, ast.Module]]:
    return [(p.name, ast.parse(p.read_text(), filename=str(p))) for p in sorted(VIEWER.glob("*.py"))]


def functions(tree: ast.AST, prefix: str = "", cls: str | None = None):
    """(qualified name, enclosing class or None, node) of every function and method, nested ones too."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.ClassDef):
            yield from functions(node, f"{prefix}{node.name}.", node.name)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield f"{prefix}{node.name}", cls, node
            yield from functions(node, f"{prefix}{node.name}.", cls)
        else:  # the bodies of if, with, try, ...
            yield from functions(node, prefix, cls)


def scene_parameters() -> list[tuple[str, str, str, str | None]]:
    """(module, function, parameter, annotation) of every parameter named renderer or scene."""
    out = []
    for module, tree in viewer_modules():
        for qual, _, fn in functions(tree):
            a = fn.args
            for arg in (*a.posonlyargs, *a.args, *a.kwonlyargs):
                if arg.arg in SCENE_NAMES:
                    out.append((module, qual, arg.arg, None if arg.annotation is None else ast.unparse(arg.annotation)))
    return out


def mentions_protocol(annotation: ast.expr) -> bool:
    return any(isinstance(n, ast.Name) and n.id == PROTOCOL for n in ast.walk(annotation))


def test_every_scene_parameter_is_the_protocol():
    found = scene_parameters()
    where = {(m, f) for m, f, _, _ in found}
    # the drag -> filter -> engine path and the other users are all seen (the scan is not vacuous)
    assert {("worker.py", "pose_filter"), ("worker.py", "LiveAudio.__init__"), ("refine.py", "render_loop"),
            ("refine.py", "LoopRefiner.__init__"), ("refine.py", "refines"), ("refine.py", "periods_before"),
            ("window.py", "MainWindow._install_scene"), ("scene_view.py", "SceneView.__init__"),
            ("propagation_view.py", "PropagationView.__init__"), ("export.py", "export_headless")} <= where
    wrong = []
    for module, function, name, annotation in found:
        expected = NOT_THE_SCENE.get((module, function, name), PROTOCOL)
        if annotation != expected:
            wrong.append(f"{module}: {function}({name}: {annotation}), expected {expected}")
    assert not wrong, "parameters named renderer or scene not typed as the scene protocol:\n" + "\n".join(wrong)


def test_every_annotated_scene_attribute_is_the_protocol():
    """``self.renderer: ... = ...`` and the like: the window's scene is the protocol (or None)."""
    wrong, seen = [], 0
    for module, tree in viewer_modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.AnnAssign):
                target = node.target
                name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", None)
                if name in SCENE_NAMES:
                    seen += 1
                    if not mentions_protocol(node.annotation):
                        wrong.append(f"{module}:{node.lineno}: {ast.unparse(node)}")
    assert seen >= 1 and not wrong, wrong


def accesses() -> dict[str, list[str]]:
    """member -> where avgs_viewer reads or calls it on the scene (``renderer.x``, ``self.scene.x``,
    ``getattr(scene, "x", ...)``), outside the code where such a name is not the scene."""
    out: dict[str, list[str]] = {}

    def is_scene(node: ast.expr, other: set[str]) -> bool:
        if isinstance(node, ast.Name):
            return node.id in SCENE_NAMES and node.id not in other
        return (isinstance(node, ast.Attribute) and node.attr in SCENE_NAMES
                and not ast.unparse(node.value).endswith("plotter"))  # a plotter's renderer is VTK's

    for module, tree in viewer_modules():
        for qual, cls, fn in functions(tree):
            if (module, cls) in NOT_THE_SCENE_CLASSES:
                continue
            other = {n for n in SCENE_NAMES if (module, qual, n) in NOT_THE_SCENE}  # e.g. a checkpoint's path
            for node in ast.walk(fn):
                member = None
                if isinstance(node, ast.Attribute) and is_scene(node.value, other):
                    member = node.attr
                elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr"
                      and len(node.args) >= 2 and is_scene(node.args[0], other)
                      and isinstance(node.args[1], ast.Constant)):
                    member = node.args[1].value
                if member is not None and f"{module}:{node.lineno}" not in out.get(member, []):
                    out.setdefault(member, []).append(f"{module}:{node.lineno}")
    return out


def test_the_protocol_lists_exactly_what_the_viewer_uses():
    used, declared = accesses(), set(members(TrainedScene))
    undeclared = {m: w for m, w in used.items() if m not in declared}
    assert not undeclared, f"avgs_viewer uses members of the scene that TrainedScene does not declare: {undeclared}"
    unused = declared - set(used)
    assert not unused, f"TrainedScene declares members that avgs_viewer never uses: {sorted(unused)}"


def test_the_state_events_are_typed():
    """Each of the state's events carries a declared type (the pose event: a Pose, for the audio path)."""
    events = viewer_state.ViewerEvents
    declared = typing.get_type_hints(events, globalns=vars(viewer_state))
    assert tuple(declared) == events.NAMES
    assert typing.get_args(declared["pose"]) == (viewer_state.Pose,)
