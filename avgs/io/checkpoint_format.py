"""The layout of ``scene.ckpt`` and its validation: every key checked before anything uses it.

The shape contract: a position is a tensor of exactly ``[3]`` (``source``; ``frame.center``
may also be a list of 3 numbers), a set of positions ``[N, 3]`` (``audio_points.X``,
``gaussians.means``, ``rir.*``), ``scene.bounds`` ``[2, 3]``, ``scene.outline`` ``[K, 2, 3]``.
Nothing is reshaped on reading: a ``[3, 1]`` or ``[1, 3]`` source is refused by name, shape
and the expected one, so the loader, the renderer and every command agree on what they read.

:func:`validate_checkpoint` refuses a malformed checkpoint dict with one ``ValueError`` that
names the file and the first problem: a missing key, a wrong type, a tensor of the wrong shape
for the stored configuration (the network weights are compared with the task's networks built
from it on the ``meta`` device: no memory spent), NaN or Inf, STFT settings out of range, a
malformed training state. Reading and writing are :mod:`avgs.io.checkpoint`'s.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
import typing
from pathlib import Path

import torch

from avgs.config import STFT, STFTConfig, TrainConfig
from avgs.data.frame import SceneFrame
from avgs.tasks import DEFAULT, TASKS, task_named

FORMAT_VERSION = 1
"Bumped whenever the layout of the checkpoint dict changes incompatibly."
REQUIRED_KEYS = ("format_version", "frame", "source", "stft", "audio_points", "field", "binauralizer", "config", "history", "scene")
"Top-level keys every checkpoint carries (``gaussians`` is optional)."
IDENTITY_PATTERN = re.compile(r"sha256:[0-9a-f]{64}")
"scene.identity (optional; absent in older files): the training scene's :func:`avgs.data.identity.scene_identity`."
CHECKSUM_KEY = "checksum"
"Top-level key of the integrity checksum that :func:`avgs.io.checkpoint.save_checkpoint` adds."


MAX_SAMPLE_RATE = 1_000_000
"Largest sample rate (Hz) a checkpoint may store."
MAX_N_FFT = 1 << 16
"Largest FFT size a checkpoint may store."
MIN_N_FFT = 4
"Smallest FFT size a checkpoint may store."
MAX_WIDTH = 1 << 16
"Largest network width (F, B, the context) a stored configuration may ask for."
MAX_LAYERS = 256
"Most layers of F a stored configuration may ask for."
MAX_FREQUENCIES = 64
"Most positional-encoding frequencies (2^63 is far beyond float32's resolution already)."
MAX_HARMONICS = 4096
"Most direction harmonics a stored configuration may ask for."
MAX_RIR_FRAMES = 1 << 14
"Most STFT frames of a response of the impulse-response task (about 95 s at AV-NeRF's hop)."


class _Invalid(Exception):
    """A validation failure; :func:`validate_checkpoint` turns it into ValueError naming the file."""


def kind_of(value) -> str:
    if isinstance(value, torch.Tensor):
        return f"a tensor {tuple(value.shape)} of {str(value.dtype).replace('torch.', '')}"
    if value is None:
        return "None"
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def _name(key) -> str:
    """A key from the file as it may appear in a one-line message."""
    if isinstance(key, str) and key.isprintable() and len(key) <= 60:
        return key
    text = repr(key)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_number(value) -> bool:
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer beyond float's range
        return False


def _dict(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise _Invalid(f"'{where}' must be a dict, got {kind_of(value)}")
    return value


def _tensor(value, where: str, shape: tuple | None = None, *, floating: bool = True, finite: bool = True) -> torch.Tensor:
    """``value`` as a dense tensor of ``shape`` (None entries: any size), floating point and finite."""
    if not isinstance(value, torch.Tensor):
        raise _Invalid(f"{where} must be a tensor{_shape_text(shape)}, got {kind_of(value)}")
    if value.layout != torch.strided:
        raise _Invalid(f"{where} must be a dense tensor, got a {value.layout} one")
    if floating and not (value.is_floating_point() and not value.is_complex()):
        raise _Invalid(f"{where} must hold real floating-point numbers, got {str(value.dtype).replace('torch.', '')}")
    if shape is not None and (
        value.dim() != len(shape) or any(s is not None and value.shape[i] != s for i, s in enumerate(shape))
    ):
        raise _Invalid(f"{where} must be a tensor{_shape_text(shape)}, got shape {tuple(value.shape)}")
    if finite and value.is_floating_point() and value.numel() and not bool(torch.isfinite(value).all()):
        raise _Invalid(f"{where} holds NaN or Inf")
    return value


def _shape_text(shape) -> str:
    if shape is None:
        return ""
    return " [" + ", ".join("*" if s is None else str(s) for s in shape) + "]"


def _plain(value, where: str, depth: int = 0) -> None:
    """JSON-like plain values only (what the log and ``avgs info --json`` write)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return
    if depth < 8 and isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _plain(item, f"{where}[{i}]", depth + 1)
        return
    if depth < 8 and isinstance(value, dict):
        for k, item in value.items():
            if not isinstance(k, str):
                raise _Invalid(f"{where} has a key {kind_of(k)}; expected strings")
            _plain(item, f"{where}.{_name(k)}", depth + 1)
        return
    raise _Invalid(f"{where} must hold plain values (numbers, strings, lists), got {kind_of(value)}")


def validate_checkpoint(ckpt, path: str | Path = "<checkpoint>") -> None:
    """Raise ValueError naming ``path`` and the first problem unless ``ckpt`` has the expected layout,
    types, shapes (for its stored configuration) and finite values."""
    if not isinstance(ckpt, dict) or "format_version" not in ckpt:
        what = "a dict without 'format_version'" if isinstance(ckpt, dict) else kind_of(ckpt)
        raise ValueError(f"{path}: not an AV-GS checkpoint (expected a dict with 'format_version', got {what})")
    version = ckpt["format_version"]
    if not _is_int(version):
        raise ValueError(f"{path}: not an AV-GS checkpoint ('format_version' is {kind_of(version)}, expected an integer)")
    if version > FORMAT_VERSION:
        raise ValueError(
            f"{path}: checkpoint format version {version}, written by a newer avgs; this avgs reads version "
            f"{FORMAT_VERSION} (update avgs to read it)"
        )
    if version != FORMAT_VERSION:
        raise ValueError(f"{path}: checkpoint format version {version!r}, this avgs reads version {FORMAT_VERSION}")
    missing = [k for k in REQUIRED_KEYS if k not in ckpt]
    if missing:
        raise ValueError(f"{path}: checkpoint is missing {', '.join(missing)} (expected keys: {', '.join(REQUIRED_KEYS)})")
    try:
        _validate(ckpt)
    except _Invalid as exc:
        raise ValueError(f"{path}: {exc}") from None


def _validate(ckpt: dict) -> None:
    cfg = _validate_config(ckpt["config"])
    stft = _validate_stft(ckpt["stft"], "stft")
    frame = ckpt["frame"]
    if not isinstance(frame, dict):
        raise _Invalid(f"bad 'frame': expected a dict of 'center' and 'scale', got {kind_of(frame)}")
    center = frame.get("center")
    if isinstance(center, torch.Tensor):
        _tensor(center, "bad 'frame': frame.center", (3,))
    elif not (isinstance(center, (list, tuple)) and len(center) == 3 and all(_is_number(v) for v in center)):
        raise _Invalid(f"bad 'frame': frame.center must be 3 numbers (a list or a tensor [3]), got {kind_of(center)}")
    try:
        SceneFrame.from_dict(frame)
    except (TypeError, ValueError, AttributeError, OverflowError, RuntimeError, IndexError) as exc:
        raise _Invalid(f"bad 'frame': {exc}") from None
    _tensor(ckpt["source"], "source", (3,))  # exactly [3]: what build_checkpoint writes and every reader indexes
    pts = _dict(ckpt["audio_points"], "audio_points")
    for key in ("X", "alpha"):
        if key not in pts:
            raise _Invalid(f"'audio_points' must hold 'X' [N,3] and 'alpha' [N,D]; '{key}' is missing")
    X = _tensor(pts["X"], "audio_points.X", (None, 3))
    if len(X) < 1:
        raise _Invalid("audio_points.X must hold at least one point, got none")
    alpha = _tensor(pts["alpha"], "audio_points.alpha", (len(X), None))
    if alpha.shape[1] < 1:
        raise _Invalid(f"audio_points.alpha must be a tensor [{len(X)}, D >= 1], got shape {tuple(alpha.shape)}")
    task = ckpt.get("task", DEFAULT)
    if not (isinstance(task, str) and task in TASKS):
        raise _Invalid(f"'task' must be one of {', '.join(map(repr, TASKS))}, got {kind_of(task)}")
    model = task_named(task).part("model")
    problem = model.config_problem(cfg, stft)
    if problem is not None:
        raise _Invalid(f"bad 'config': {problem}")
    positions = ckpt.get("rir")
    if positions is not None:  # the training positions of a source-aware model
        for key, value in _dict(positions, "rir").items():
            _tensor(value, f"rir.{_name(key)}", (None, 3))
    _validate_networks(ckpt, cfg, stft, alpha.shape[1], model)
    _validate_scene(ckpt["scene"])
    history = ckpt["history"]
    if not isinstance(history, list):
        raise _Invalid(f"'history' must be a list of log records, got {kind_of(history)}")
    for i, record in enumerate(history):
        if not isinstance(record, dict):
            raise _Invalid(f"history[{i}] must be a dict, got {kind_of(record)}")
        _plain(record, f"history[{i}]")
    g = ckpt.get("gaussians")
    if g is not None:
        _validate_gaussians(g)
    k = ckpt.get("vicinity_k")
    if k is not None and not (_is_int(k) and k >= 1):
        raise _Invalid(f"'vicinity_k' must be a positive integer, got {kind_of(k)}")
    metrics = ckpt.get("metrics")
    if metrics is not None:
        for name, value in _dict(metrics, "metrics").items():
            if not isinstance(name, str) or not (value is None or isinstance(value, (bool, int, float, str))):
                raise _Invalid(f"'metrics' must map names to numbers, got {_name(name)}: {kind_of(value)}")
    state = ckpt.get("train_state")
    if state is not None:
        _validate_train_state(state, len(X), cfg)


def _validate_config(raw) -> TrainConfig:
    if not isinstance(raw, dict):
        raise _Invalid(f"bad 'config': expected a dict (TrainConfig.to_dict()), got {kind_of(raw)}")
    try:
        cfg = TrainConfig.from_dict(raw)
    except (TypeError, ValueError) as exc:
        raise _Invalid(f"bad 'config': {exc}") from None
    for section in (cfg, cfg.gaussians, cfg.acoustic, cfg.points, cfg.stft, cfg.rir):
        hints = typing.get_type_hints(type(section))
        prefix = "" if section is cfg else next(
            f"{f.name}." for f in dataclasses.fields(cfg) if getattr(cfg, f.name) is section
        )
        for f in dataclasses.fields(section):
            value = getattr(section, f.name)
            if dataclasses.is_dataclass(value):
                continue
            if not _matches(value, hints[f.name]):
                raise _Invalid(f"bad 'config': {prefix}{f.name} is {kind_of(value)}, expected {_hint_text(hints[f.name])}")
    try:
        cfg.validate()
    except ValueError as exc:
        raise _Invalid(f"bad 'config': {exc}") from None
    p = cfg.points
    for name, value in (("points.densify_every", p.densify_every), ("points.prune_every", p.prune_every),
                        ("points.max_points", p.max_points), ("log_every", cfg.log_every)):
        if value < 1:
            raise _Invalid(f"bad 'config': {name} must be >= 1, got {_name(value)}")
    a = cfg.acoustic
    for name, value, most in (
        ("acoustic.field_width", a.field_width, MAX_WIDTH), ("acoustic.context_dim", a.context_dim, MAX_WIDTH),
        ("acoustic.binauralizer_width", a.binauralizer_width, MAX_WIDTH), ("acoustic.field_layers", a.field_layers, MAX_LAYERS),
        ("acoustic.pe_frequencies", a.pe_frequencies, MAX_FREQUENCIES),
        ("acoustic.position_frequencies", a.position_frequencies, MAX_FREQUENCIES),
        ("acoustic.direction_harmonics", a.direction_harmonics, MAX_HARMONICS),
        ("rir.width", cfg.rir.width, MAX_WIDTH), ("rir.position_frequencies", cfg.rir.position_frequencies, MAX_FREQUENCIES),
        ("rir.time_frequencies", cfg.rir.time_frequencies, MAX_FREQUENCIES),
        ("rir.arrival_frequencies", cfg.rir.arrival_frequencies, MAX_FREQUENCIES),
        ("rir.direction_harmonics", cfg.rir.direction_harmonics, MAX_HARMONICS),
        ("rir.frames", cfg.rir.frames, MAX_RIR_FRAMES),
    ):
        if value > most:  # the networks are built (on the meta device) before their weights are compared
            raise _Invalid(f"bad 'config': {name} must be at most {most}, got {_name(value)}")
    _validate_stft(dataclasses.asdict(cfg.stft), "config.stft")
    return cfg


def _matches(value, hint) -> bool:
    if typing.get_origin(hint) is typing.Literal:
        return isinstance(value, str) and value in typing.get_args(hint)
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return _is_int(value)
    if hint is float:
        return _is_number(value)
    if hint is str:
        return isinstance(value, str)
    return True


def _hint_text(hint) -> str:
    if typing.get_origin(hint) is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(hint))
    return {bool: "true or false", int: "an integer", float: "a finite number", str: "a string"}.get(hint, str(hint))


def _validate_stft(raw, where: str) -> STFTConfig:
    """The STFT settings as :func:`stft_of` reads them, each a positive integer in range."""
    if not isinstance(raw, dict):
        raise _Invalid(f"'{where}' must be a dict of sample_rate, n_fft, hop_length, win_length, got {kind_of(raw)}")
    known = {f.name for f in dataclasses.fields(STFTConfig)}
    values = {**dataclasses.asdict(STFT), **{k: v for k, v in raw.items() if k in known}}
    for name, value in values.items():
        if not _is_int(value):
            raise _Invalid(f"{where}.{name} must be a positive integer, got {kind_of(value)}")
    sr, n_fft, hop, win = (int(values[k]) for k in ("sample_rate", "n_fft", "hop_length", "win_length"))
    if not 1 <= sr <= MAX_SAMPLE_RATE:
        raise _Invalid(f"{where}.sample_rate must be in [1, {MAX_SAMPLE_RATE}] Hz, got {_name(sr)}")
    if not MIN_N_FFT <= n_fft <= MAX_N_FFT:
        raise _Invalid(f"{where}.n_fft must be in [{MIN_N_FFT}, {MAX_N_FFT}], got {_name(n_fft)}")
    if not 1 <= hop <= n_fft:
        raise _Invalid(f"{where}.hop_length must be in [1, n_fft = {n_fft}], got {_name(hop)}")
    if not 1 <= win <= n_fft:
        raise _Invalid(f"{where}.win_length must be in [1, n_fft = {n_fft}], got {_name(win)}")
    return STFTConfig(sample_rate=sr, n_fft=n_fft, hop_length=hop, win_length=win)


def _expected_state_dicts(cfg: TrainConfig, stft: STFTConfig, alpha_dim: int, model) -> dict[str, dict[str, torch.Tensor]]:
    """``{"field": ..., "binauralizer": ...}``: the state dicts (meta tensors: shapes and dtypes, no
    memory) of the networks the task's ``model`` class (:mod:`avgs.tasks`) builds from this configuration."""
    from avgs.acoustics.field import AcousticField

    a = cfg.acoustic
    context = 2 * a.context_dim if a.use_context else None
    try:
        with torch.device("meta"):
            field = AcousticField(alpha_dim, a.field_width, a.field_layers, a.context_dim) if a.use_context else None
            binauralizer = model.build_binauralizer(cfg, stft, context)
    except (ValueError, TypeError, RuntimeError) as exc:
        raise _Invalid(f"bad 'config': no model can be built from it ({exc})") from None
    return {"field": {} if field is None else field.state_dict(), "binauralizer": binauralizer.state_dict()}


def _validate_networks(ckpt: dict, cfg: TrainConfig, stft: STFTConfig, alpha_dim: int, model) -> None:
    expected = _expected_state_dicts(cfg, stft, alpha_dim, model)
    for name in ("field", "binauralizer"):
        state = _dict(ckpt[name], name)
        want = expected[name]
        missing = [k for k in want if k not in state]
        extra = [k for k in state if k not in want]
        if missing or extra:
            parts = []
            if missing:
                parts.append(f"lacks {', '.join(map(str, missing[:4]))}{' ...' if len(missing) > 4 else ''}")
            if extra:
                parts.append(f"has unexpected {', '.join(map(_name, extra[:4]))}{' ...' if len(extra) > 4 else ''}")
            raise _Invalid(
                f"'{name}' does not fit the stored configuration (it {' and '.join(parts)}; "
                f"audio points with alpha of {alpha_dim} dims, context {'on' if cfg.acoustic.use_context else 'off'})"
            )
        for key, ref in want.items():
            value = state[key]
            where = f"{name}.{key}"
            _tensor(value, where, floating=ref.is_floating_point(), finite=True)
            if tuple(value.shape) != tuple(ref.shape):
                raise _Invalid(
                    f"{where} has shape {tuple(value.shape)}, but the stored configuration builds "
                    f"{tuple(ref.shape)} (wrong tensor for this config)"
                )


def _validate_scene(scene) -> None:
    scene = _dict(scene, "scene")
    if "bounds" not in scene:
        raise _Invalid("'scene' must hold 'bounds' [2,3]")
    if "name" in scene and not isinstance(scene["name"], str):
        raise _Invalid(f"scene.name must be a string, got {kind_of(scene['name'])}")
    identity = scene.get("identity")
    if identity is not None and not (isinstance(identity, str) and IDENTITY_PATTERN.fullmatch(identity)):
        raise _Invalid(f"scene.identity must be 'sha256:' and 64 hex digits (avgs.data.identity), got {kind_of(identity)}")
    bounds = _tensor(scene["bounds"], "scene.bounds", (2, 3))
    if not bool((bounds[0] <= bounds[1]).all()):
        raise _Invalid(f"scene.bounds must be (min corner, max corner), got {bounds.tolist()}")
    outline = scene.get("outline")
    if outline is not None:
        _tensor(outline, "scene.outline", (None, 2, 3))


def _validate_gaussians(g) -> None:
    g = _dict(g, "gaussians")
    if not g:
        return
    if "means" not in g:
        raise _Invalid("'gaussians' must hold at least 'means' [M,3]")
    means = _tensor(g["means"], "gaussians.means", (None, 3))
    m = len(means)
    if m < 1:
        raise _Invalid("gaussians.means holds no Gaussians; leave 'gaussians' out instead")
    shapes = {"quats": (m, 4), "log_scales": (m, 3), "sh": (m, None, 3)}
    for key, value in g.items():
        where = f"gaussians.{_name(key)}"
        if key == "means":
            continue
        if key == "opacity_logits":
            t = _tensor(value, where, finite=False)
            if t.shape not in ((m,), (m, 1)):
                raise _Invalid(f"{where} must be a tensor [{m}] or [{m}, 1], got shape {tuple(t.shape)}")
        elif key in shapes:
            t = _tensor(value, where, shapes[key], finite=key == "sh")
            if key == "sh" and t.shape[1] < 1:
                raise _Invalid(f"{where} must be a tensor [{m}, K >= 1, 3], got shape {tuple(t.shape)}")
        elif isinstance(value, torch.Tensor):
            _tensor(value, where, floating=False, finite=False)


def _generator_state(value, where: str) -> None:
    size = _GENERATOR_STATE_BYTES
    t = _tensor(value, where, (size,), floating=False, finite=False)
    if t.dtype != torch.uint8:
        raise _Invalid(f"{where} must be a uint8 tensor [{size}] (a torch.Generator state), got {t.dtype}")


_GENERATOR_STATE_BYTES = int(torch.Generator().get_state().numel())


def _validate_train_state(state, n_points: int, cfg: TrainConfig) -> None:
    """The stage-2 training state (:meth:`avgs.train.stage2.Stage2Trainer.state_dict`): types and
    shapes; whether the optimizer's state fits the model is checked when it is loaded."""
    state = _dict(state, "train_state")
    if "iteration" not in state:
        raise _Invalid("train_state lacks 'iteration' (the stage-2 iteration it was saved at)")
    it = state["iteration"]
    if not (_is_int(it) and it >= 0):
        raise _Invalid(f"train_state.iteration must be an integer >= 0, got {kind_of(it)}")
    for key in ("optimizer", "generator", "torch_rng"):
        if key not in state:
            raise _Invalid(f"train_state lacks '{key}'")
    if "manager_generator" not in state:
        raise _Invalid("train_state lacks 'manager_generator'")
    for key in ("generator", "manager_generator", "torch_rng"):
        _generator_state(state[key], f"train_state.{key}")
    opt = _dict(state["optimizer"], "train_state.optimizer")
    if "state" not in opt or "param_groups" not in opt:
        raise _Invalid("train_state.optimizer must hold 'state' and 'param_groups' (an optimizer state dict)")
    groups = opt["param_groups"]
    if not isinstance(groups, list) or not groups:
        raise _Invalid(f"train_state.optimizer.param_groups must be a non-empty list, got {kind_of(groups)}")
    ids = []
    for i, group in enumerate(groups):
        if not isinstance(group, dict) or not isinstance(group.get("params"), list):
            raise _Invalid(f"train_state.optimizer.param_groups[{i}] must be a dict with a list 'params'")
        if not all(_is_int(p) for p in group["params"]):
            raise _Invalid(f"train_state.optimizer.param_groups[{i}].params must be integers")
        ids += group["params"]
    if len(set(ids)) != len(ids):
        raise _Invalid("train_state.optimizer.param_groups name a parameter twice")
    per_param = _dict(opt["state"], "train_state.optimizer.state")
    for pid, entry in per_param.items():
        where = f"train_state.optimizer.state[{_name(pid)}]"
        if pid not in ids:
            raise _Invalid(f"{where} belongs to no parameter group")
        for key, value in _dict(entry, where).items():
            if isinstance(value, torch.Tensor):
                _tensor(value, f"{where}.{_name(key)}", floating=False)
            elif not (value is None or _is_number(value) or isinstance(value, (bool, str))):
                raise _Invalid(f"{where}.{_name(key)} must be a tensor or a number, got {kind_of(value)}")
        step = entry.get("step")
        if isinstance(step, torch.Tensor):
            step = float(step.reshape(-1)[0]) if step.numel() == 1 else None
        elif step is None and "step" not in entry:
            continue
        if not (_is_number(step) and step >= 0):
            raise _Invalid(f"{where}.step must be a number >= 0, got {kind_of(entry.get('step'))}")
    manager = state.get("manager")
    if manager is not None:
        manager = _dict(manager, "train_state.manager")
        present = [manager.get(k) is not None for k in ("grad_sum", "count")]
        if any(present) and not all(present):
            raise _Invalid("train_state.manager must hold both 'grad_sum' and 'count', or neither")
        for key in ("grad_sum", "count"):
            if manager.get(key) is not None:
                t = _tensor(manager[key], f"train_state.manager.{key}", (n_points,))
                if bool((t < 0).any()):
                    raise _Invalid(f"train_state.manager.{key} must be >= 0")
    for key in ("numpy_rng", "python_rng"):
        if state.get(key) is not None:
            _validate_host_rng(state[key], key)
    cuda = state.get("cuda_rng")
    if cuda is not None:
        if not isinstance(cuda, list):
            raise _Invalid(f"train_state.cuda_rng must be a list of generator states, got {kind_of(cuda)}")
        for i, t in enumerate(cuda):
            t = _tensor(t, f"train_state.cuda_rng[{i}]", (None,), floating=False, finite=False)
            if t.dtype != torch.uint8:
                raise _Invalid(f"train_state.cuda_rng[{i}] must be a uint8 tensor")
    schedule = state.get("schedule")
    if schedule is not None:
        _plain(_dict(schedule, "train_state.schedule"), "train_state.schedule")


def _validate_host_rng(value, key: str) -> None:
    where = f"train_state.{key}"
    value = _dict(value, where)
    if key == "numpy_rng":
        keys = _tensor(value.get("keys"), f"{where}.keys", (624,), floating=False)
        if keys.dtype != torch.int64 or bool(((keys < 0) | (keys >= 2**32)).any()):
            raise _Invalid(f"{where}.keys must be int64 values in [0, 2^32)")
        if not (_is_int(value.get("pos")) and 0 <= value["pos"] <= 624 and _is_int(value.get("has_gauss"))
                and _is_number(value.get("cached_gaussian"))):
            raise _Invalid(f"{where} must hold integers 'pos' in [0, 624], 'has_gauss' and a number 'cached_gaussian'")
    else:
        words = _tensor(value.get("state"), f"{where}.state", (625,), floating=False)
        if words.dtype != torch.int64 or bool(((words < 0) | (words >= 2**32)).any()) or int(words[-1]) > 624:
            raise _Invalid(f"{where}.state must be 625 int64 words of a Mersenne Twister state")
        gauss = value.get("gauss_next")
        if not (_is_int(value.get("version")) and (gauss is None or _is_number(gauss))):
            raise _Invalid(f"{where} must hold an integer 'version' and 'gauss_next' (a number or None)")
