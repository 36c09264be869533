"""Score methods on impulse-response scenes (the RIR task): T60 %, C50 dB, EDT s and the spatial cues.

A *method* of the RIR task is a callable ``(train: RIRSet, query: RIRSet) -> [N, 2, L]``
(numpy or torch): the responses it predicts for the query's (source, receiver, yaw), given
the scene's training responses. The baselines of :mod:`avgs.evaluation.interpolation` interpolate
the training responses; :class:`ResponseCheckpointMethod` wraps a checkpoint trained on
the RIR task (``SceneRenderer.predict_responses``, which ignores ``train``). A method may
define ``applies_to(scene) -> bool`` (a checkpoint applies to the scene it was trained on)
and ``for_scene(scene)`` (a folder of checkpoints: the one for that scene).

Per response, each metric is that of :mod:`avgs.evaluation.metrics` (docs/design.md, "Metrics and baselines"), averaged
over the two ears: ``t60_pct`` (``|T60_pred - T60_gt| / T60_gt x 100``, a failed
measurement counting 100 %), ``c50_db`` (``|C50_pred - C50_gt|``), ``edt_s``
(``|EDT_pred - EDT_gt|``). A scene's score of these is the mean over its responses of the split.
The spatial cues (:mod:`avgs.evaluation.spatial`, docs/design.md "Spatial cues"), on both
ears together: ``onset_ms`` (``|onset_pred - onset_true|`` ms), ``itd_us`` (``|ITD_pred -
ITD_true|`` of the direct sound, the 5 ms after the onset, us), ``ild_db`` (``|ILD_pred -
ILD_true|`` of those 5 ms, dB), each a scene's MEDIAN over its responses, and ``lat_pct``, the
lateralisation agreement over the scene's responses in % (``None``, JSON ``null``, when no
response's true |ITD| reaches 150 us). An environment's score is the mean over its scenes;
overall the mean of the environment means, as the binaural task
(:func:`avgs.evaluation.binaural.aggregate`; a None is skipped).

The report has the binaural task's shape, plus ``"task": "rir"``:
``{"task", "split", "environments": {scene: env}, "clips": {scene: responses scored},
"methods": {name: {"scenes": {scene: {t60_pct, c50_db, edt_s, onset_ms, itd_us, ild_db, lat_pct}},
"environments": {...}, "overall": {...}}}}``. ``split="both"`` scores val and heldout and returns
``{"task": "rir", "split": "both", "splits": {"val": report, "heldout": report}}``.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from tqdm.auto import tqdm

from avgs.evaluation import metrics, spatial
from avgs.evaluation.binaural import CKPT_PREFIX, CheckpointMethod, CheckpointSetMethod, aggregate
from avgs.evaluation.binaural import format_report as format_table
from avgs.evaluation.interpolation import RIR_BASELINES, CodecMethod

if TYPE_CHECKING:
    from avgs.data.rir import RIRScene, RIRSet

MEAN_METRICS = ("t60_pct", "c50_db", "edt_s")
"The metrics whose scene value is the mean over the responses."
MEDIAN_METRICS = spatial.RESPONSE_METRICS
"The spatial errors whose scene value is the median over the responses: onset_ms, itd_us, ild_db."
RIR_METRICS = (*MEAN_METRICS, *MEDIAN_METRICS, "lat_pct")
"A scene's metrics, in the report's order."
COLUMNS = (("t60_pct", 9, ".2f"), ("c50_db", 8, ".3f"), ("edt_s", 8, ".4f"), ("onset_ms", 9, ".3f"),
           ("itd_us", 8, ".1f"), ("ild_db", 8, ".2f"), ("lat_pct", 8, ".1f"))
"The table's columns: (metric, least width, format)."
SPLITS = ("val", "heldout", "train", "both")
"What ``split`` accepts: a split of the scene's index, or ``both`` (val and heldout)."
MODEL_PREFIXES = (CKPT_PREFIX, "avgs:")
"A checkpoint on the command line: ``ckpt:PATH`` (as the binaural task) or ``avgs:PATH``; PATH a file or a folder of them."
CHUNK = 128
"Responses predicted and scored at a time (bounds the memory: N x 2 x L floats)."


class ResponseCheckpointMethod(CheckpointMethod):
    """A checkpoint of the RIR task as a method: ``SceneRenderer.predict_responses`` of the
    query's normalised source, receiver and yaw (the training responses are not read)."""

    def __init__(self, path: str | Path, device: str = "cpu", synthesis=None, batch: int = 64):
        super().__init__(path, device=device, synthesis=synthesis)
        if not self.renderer.source_aware:
            raise ValueError(f"{self.path}: a checkpoint of the {self.renderer.task} task; the RIR task scores "
                             "checkpoints trained on impulse responses ('avgs train --task rir')")
        self.batch = batch

    def __call__(self, train: "RIRSet", query: "RIRSet") -> np.ndarray:
        out = []
        for start in range(0, len(query), self.batch):
            rows = slice(start, start + self.batch)
            pred = self.renderer.predict_responses(query.source[rows], query.receiver[rows], query.yaw[rows])
            out.append(_float32(pred))
        return np.concatenate(out) if out else np.zeros((0, *query.rir.shape[1:]), np.float32)


class ResponseCheckpointSetMethod(CheckpointSetMethod):
    """A folder of RIR checkpoints, one per scene (``ckpt:DIR``)."""

    member = ResponseCheckpointMethod

    def __call__(self, train, query):  # pragma: no cover - the evaluator calls for_scene(scene)
        raise TypeError("a folder of checkpoints predicts through for_scene(scene)")


def method_names() -> list[str]:
    """What ``--methods`` accepts for the RIR task."""
    return [*RIR_BASELINES, f"{CKPT_PREFIX}PATH", "avgs:PATH", f"{CKPT_PREFIX}DIR"]


# -- what ``avgs eval`` asks of a task's evaluation (avgs.tasks: Task.evaluation) -------------

DEFAULT_METHODS = ("nearest", "linear", "opus-nearest", "opus-linear", "aac-nearest", "aac-linear")
"The baselines (:data:`~avgs.evaluation.interpolation.RIR_BASELINES`), scored when no method is named."
DEFAULT_SPLIT = "val"


def check_request(data_roots: list[str], specs: list[str], split: str) -> None:
    """ValueError, before any scene is read, for a method name or split this task does not know."""
    for spec in specs:
        if not spec.startswith(MODEL_PREFIXES) and spec not in RIR_BASELINES:
            raise ValueError(f"unknown RIR method {spec!r}; expected one of {', '.join(method_names())}")
    if split not in SPLITS:
        raise ValueError(f"--split {split}: expected one of {', '.join(SPLITS)}")


def checkpoint_paths(specs: list[str]) -> list[str]:
    """The checkpoint (or folder) paths that ``specs`` name."""
    return [s[len(p) :] for s in specs for p in MODEL_PREFIXES if s.startswith(p)]


def scenes(data_roots: list[str], ids: Iterable[str] | None = None) -> list[Path]:
    """The impulse-response scenes to score (:func:`find_scenes`)."""
    return find_scenes(data_roots, ids)


def load_method(spec: str, device: str = "cpu", synthesis=None, progress: bool = False):
    """A method of the RIR task from its command-line name (``synthesis`` does not apply: a
    checkpoint's render is the convolution with its predicted response)."""
    for prefix in MODEL_PREFIXES:
        if spec.startswith(prefix):
            path = Path(spec[len(prefix) :])
            if path.is_dir():
                return ResponseCheckpointSetMethod(path, device=device)
            return ResponseCheckpointMethod(path, device=device)
    if spec in RIR_BASELINES:
        method = RIR_BASELINES[spec]
        if isinstance(method, CodecMethod):  # a fresh one, with the caller's progress bars
            method = CodecMethod(method.codec, method.interpolation, progress=progress)
        return method
    raise ValueError(f"unknown RIR method {spec!r}; expected one of {', '.join(method_names())}")


def find_scenes(paths: str | Path | Iterable[str | Path], ids: Iterable[str] | None = None) -> list[Path]:
    """Impulse-response scenes: each path is a scene (``rir/index.json``) or a folder of them;
    ``ids`` keeps only the scenes of those names (each must be found)."""
    from avgs.data.rir import is_rir_scene

    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    found: list[Path] = []
    for p in map(Path, paths):
        if is_rir_scene(p):
            found.append(p)
        elif p.is_dir():
            found.extend(sorted((c for c in p.iterdir() if is_rir_scene(c)), key=lambda c: _natural_key(c.name)))
        else:
            raise FileNotFoundError(f"{p}: no such scene or data root")
    found = list(dict.fromkeys(found))
    if not found:
        raise ValueError(f"{', '.join(map(str, paths))}: no impulse-response scenes (folders with rir/index.json)")
    if ids:
        by_name = {p.name: p for p in found}
        missing = [i for i in ids if i not in by_name]
        if missing:
            raise FileNotFoundError(f"{', '.join(map(str, paths))}: no RIR scene named {', '.join(missing)} "
                                    f"(have {', '.join(by_name)})")
        found = [by_name[i] for i in dict.fromkeys(ids)]
    return found


def _natural_key(name: str) -> list:
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", name)]


def environment_of(scene: "RIRScene") -> str:
    """The scene's ``environment`` (scene.json); when unknown, the binaural task's rule on its
    name (the prefix before the first ``_`` or ``-``)."""
    env = getattr(scene, "environment", "unknown")
    if isinstance(env, str) and env and env != "unknown":
        return env
    return re.split(r"[_-]", scene.name, maxsplit=1)[0] or scene.name


def _float32(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float32)


def _rows(s: "RIRSet", rows: slice) -> "RIRSet":
    """The rows ``rows`` of a response set (every field is indexed by response)."""
    return dataclasses.replace(s, **{f.name: getattr(s, f.name)[rows] for f in dataclasses.fields(s)})


def predict(method, train: "RIRSet", query: "RIRSet", name: str = "method", scene=None) -> np.ndarray:
    """Run ``method`` and check it returned ``[N, 2, L]`` finite responses; a shorter ``L'``
    is zero-padded (a response that ends early is silent after it), a longer one refused."""
    out = _float32(method(train, query))
    where = f" on {scene.name}" if scene is not None else ""
    n, channels, length = query.rir.shape
    if out.ndim != 3 or out.shape[:2] != (n, channels):
        raise ValueError(f"{name} returned {out.shape}{where}; expected {(n, channels, length)}")
    if out.shape[-1] > length:
        raise ValueError(f"{name} returned responses of {out.shape[-1]} samples{where}; the scene's are {length}")
    if out.shape[-1] < length:
        out = np.pad(out, ((0, 0), (0, 0), (0, length - out.shape[-1])))
    return out


def response_errors(pred: np.ndarray, gt: np.ndarray, fs: float) -> dict[str, float]:
    """The errors of one response ``[2, L]``: T60, C50 and EDT (each averaged over the ears),
    and the spatial ``onset_ms``, ``itd_us`` and ``ild_db`` (:func:`avgs.evaluation.spatial.response_errors`)."""
    return {
        "t60_pct": metrics.t60_error(pred, gt, fs),
        "c50_db": metrics.c50_error(pred, gt, fs),
        "edt_s": metrics.edt_error(pred, gt, fs),
        **spatial.response_errors(pred, gt, fs),
    }


def score_scene(method, scene: "RIRScene", split: str = "val", name: str = "method", progress: bool = True,
                chunk: int = CHUNK) -> dict[str, float | None]:
    """Mean T60 %, C50 dB and EDT s, median onset (ms), direct-sound ITD (us) and early-ILD (dB)
    errors and the lateralisation agreement (%, None when no response is eligible) of
    ``method`` over the scene's ``split`` responses."""
    method = method.for_scene(scene) if hasattr(method, "for_scene") else method
    train, query = scene.responses("train"), scene.responses(split)
    if len(query) == 0:
        raise ValueError(f"{scene.scene_dir}: no {split} responses to evaluate")
    totals = dict.fromkeys(MEAN_METRICS, 0.0)
    per_response: dict[str, list[float]] = {k: [] for k in MEDIAN_METRICS}
    itd_true: list[float] = []
    itd_pred: list[float] = []
    fs = scene.sample_rate
    with tqdm(total=len(query), desc=f"{name} / {scene.name} / {split}", unit="response", leave=False,
              disable=not progress) as bar:
        for start in range(0, len(query), chunk):
            part = _rows(query, slice(start, start + chunk))
            pred = predict(method, train, part, name, scene)
            for p, g in zip(pred, part.rir):
                errors = response_errors(p, g, fs)
                for k in MEAN_METRICS:
                    totals[k] += errors[k]
                for k in MEDIAN_METRICS:
                    per_response[k].append(errors[k])
                itd_true.append(spatial.response_itd(g, fs))
                itd_pred.append(spatial.response_itd(p, fs))
            bar.update(len(part))
    scores: dict[str, float | None] = {k: v / len(query) for k, v in totals.items()}
    scores.update({k: spatial.median(v) for k, v in per_response.items()})
    scores["lat_pct"] = spatial.lateralisation(itd_true, itd_pred)
    return scores


def evaluate(methods: dict, scene_dirs: Iterable[str | Path], split: str = "val", progress: bool = True) -> dict:
    """Score every method on every scene it applies to (module docstring: the report)."""
    from avgs.data.rir import RIRScene

    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    splits = ("val", "heldout") if split == "both" else (split,)
    per_split = {s: {name: {} for name in methods} for s in splits}
    environments: dict[str, str] = {}
    counts: dict[str, dict[str, int]] = {s: {} for s in splits}
    for scene_dir in scene_dirs:
        scene = RIRScene(scene_dir)  # one at a time; its responses are cached on it
        environments[scene.name] = environment_of(scene)
        for s in splits:
            counts[s][scene.name] = len(scene.responses(s))
            for name, method in methods.items():
                applies = getattr(method, "applies_to", None)
                if applies is not None and not applies(scene):
                    continue
                per_split[s][name][scene.name] = score_scene(method, scene, s, name, progress)
    reports = {}
    for s in splits:
        report = {"task": "rir", "split": s, "environments": dict(environments), "clips": counts[s], "methods": {}}
        for name, scene_scores in per_split[s].items():
            if not scene_scores:
                raise ValueError(f"method {name} applies to none of the scenes {sorted(environments)}")
            report["methods"][name] = aggregate(scene_scores, environments)
        reports[s] = report
    if split == "both":
        return {"task": "rir", "split": "both", "splits": reports}
    return reports[split]


def format_report(report: dict) -> str:
    """The table of :func:`avgs.evaluation.binaural.format_report` with T60 %, C50 dB, EDT s and the
    spatial cues (onset ms, ITD us, early ILD dB, lateralisation %); one per split."""
    if "splits" in report:
        return "\n\n".join(format_report(r) for r in report["splits"].values())
    return format_table(report, columns=COLUMNS, unit="responses")

