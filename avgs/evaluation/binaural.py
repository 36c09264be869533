"""Score methods on RWAVS-layout scenes: per scene, per environment and overall.

A *method* is any callable ``(clip: AudioClip, scene: RWAVSScene) -> binaural [2, T]``
(numpy or torch, T = the clip's length), or a :class:`Prediction` when the method made
its waveform from predicted magnitudes. The baselines of :mod:`avgs.evaluation.baselines` are
methods; :class:`CheckpointMethod` turns a trained ``scene.ckpt`` into one. A method may
also define ``applies_to(scene) -> bool``; scenes it does not apply to are left out of
its scores (a checkpoint applies to the scene it was trained on).

Columns: MAG of the waveform (:func:`avgs.evaluation.metrics.mag`, what a listener hears), ENV,
the ILD error, and MAGp, MAG of the predicted magnitudes
(:func:`avgs.evaluation.metrics.mag_spectrogram`), AV-NeRF's own evaluation convention and the one
its published numbers use. For a method that returns only a waveform, MAGp is its MAG.

Spatial cues (:mod:`avgs.evaluation.spatial`, docs/design.md "Spatial cues"): ITD, the MEDIAN
over the scene's clips of ``|ITD_pred - ITD_true|`` in microseconds (GCC-PHAT over the whole
clip), and LAT, the lateralisation agreement in percent over the scene's clips (``None`` --
JSON ``null``, the table's ``n/a`` -- when no clip's true ``|ITD|`` reaches 150 us).

Aggregation follows RWAVS: a scene's score is the mean over its val clips (ITD: the median;
LAT: the share); an environment's is the mean over its scenes; overall is the mean of the
environment means, each mean skipping ``None`` (``None`` when every value is). A scene's
environment is, in order: scene.json's ``"environment"``; else the
scene name's prefix before the first ``_`` or ``-`` (``office_2`` -> ``office``); else the
scene name itself (real RWAVS scenes are numbered, so each is its own environment).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from avgs import dsp
from avgs.evaluation import metrics, spatial
from avgs.evaluation.baselines import BASELINES
from avgs.config import STFT, SynthesisConfig
from avgs.data.identity import check_scene_identity
from avgs.data.rwavs import AudioClip, RWAVSScene, is_scene_dir
from avgs.evaluation.methods import Method, Prediction


MEAN_METRICS = ("MAG", "ENV", "ILD", "MAGp")
"The metrics whose scene value is the mean over the clips."
METRICS = (*MEAN_METRICS, "ITD", "LAT")
"A scene's metrics: the means, ITD (median error, us) and LAT (agreement, %, or None)."
CKPT_PREFIX = "ckpt:"


class CheckpointMethod:
    """A trained checkpoint as a method, through :class:`avgs.render.renderer.SceneRenderer`.

    The clip's normalised listener goes to world coordinates with the scene's frame and
    its yaw to degrees, the renderer's public convention (ARCHITECTURE.md). It applies to the
    scene of its name, and refuses (ValueError) one of that name with another identity
    (:mod:`avgs.data.identity`: other poses, source or normalisation); a checkpoint without one
    (older) is matched by name, with a warning.
    """

    def __init__(self, path: str | Path, device: str = "cpu", synthesis: SynthesisConfig | None = None):
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: checkpoint missing")
        from avgs.io.checkpoint import load_checkpoint
        from avgs.render.renderer import SceneRenderer  # heavy, and only needed here

        ckpt = load_checkpoint(self.path)
        self.scene_identity: str | None = ckpt["scene"].get("identity")
        "The training scene's :func:`~avgs.data.identity.scene_identity` (None in older checkpoints)."
        self.renderer = SceneRenderer(ckpt, device=device, path=self.path, synthesis=synthesis)
        self._checked: set[Path] = set()

    @property
    def scene_name(self) -> str | None:
        """The scene the checkpoint was trained on, when the renderer says."""
        for attr in ("scene_name", "name"):
            value = getattr(self.renderer, attr, None)
            if isinstance(value, str) and value:
                return value
        return None

    def applies_to(self, scene: RWAVSScene) -> bool:
        if self.scene_name is not None and self.scene_name != scene.name:
            return False
        folder = Path(getattr(scene, "root", None) or scene.scene_dir).resolve()  # RWAVSScene, RIRScene
        if folder not in self._checked and (self.scene_identity is not None or not self._checked):
            check_scene_identity(self.scene_identity, folder, self.path)  # a mismatch: ValueError; none: a warning, once
        self._checked.add(folder)
        return True

    def __call__(self, clip: AudioClip, scene: RWAVSScene) -> Prediction:
        listener = scene.frame.to_world(clip.listener)  # [3] world
        out = self.renderer.render(
            listener=tuple(float(v) for v in listener), yaw=math.degrees(clip.yaw), mono=clip.mono, magnitudes=True
        )
        return Prediction(out.binaural, out.magnitudes)


class CheckpointSetMethod:
    """A folder of checkpoints, one per scene, as one method: each scores the scene it was
    trained on (``ckpt:DIR`` on the command line, e.g. one run of ``avgs train`` per scene).
    ``member`` is the class each checkpoint becomes (the RIR task's evaluation uses its own)."""

    member = CheckpointMethod

    def __init__(self, folder: str | Path, device: str = "cpu", synthesis: SynthesisConfig | None = None):
        self.folder = Path(folder)
        paths = sorted(self.folder.glob("*.ckpt"))
        if not paths:
            raise FileNotFoundError(f"{self.folder}: no *.ckpt files in this folder")
        self.by_scene: dict[str, CheckpointMethod] = {}  # of type self.member
        for path in paths:
            method = self.member(path, device=device, synthesis=synthesis)
            name = method.scene_name or path.stem
            if name in self.by_scene:
                raise ValueError(f"{self.folder}: two checkpoints for scene {name!r} ({self.by_scene[name].path.name}, {path.name})")
            self.by_scene[name] = method

    def applies_to(self, scene: RWAVSScene) -> bool:
        return scene.name in self.by_scene and self.by_scene[scene.name].applies_to(scene)

    def __call__(self, clip: AudioClip, scene: RWAVSScene) -> Prediction:
        return self.by_scene[scene.name](clip, scene)

    def for_scene(self, scene) -> CheckpointMethod:
        """The checkpoint trained on ``scene`` (see :meth:`applies_to`)."""
        return self.by_scene[scene.name]


def method_names() -> list[str]:
    """What ``--method`` accepts: the baselines' names, ``ckpt:PATH`` and ``ckpt:DIR`` (one checkpoint per scene)."""
    return [*BASELINES, f"{CKPT_PREFIX}PATH", f"{CKPT_PREFIX}DIR"]


def load_method(spec: str, device: str = "cpu", synthesis: SynthesisConfig | None = None, progress: bool = False) -> Method:
    """A method from its command-line name: a baseline, ``ckpt:PATH`` or ``ckpt:DIR``
    (``synthesis``: how checkpoints make their waveforms, default :class:`SynthesisConfig`;
    ``progress``: unused, the baselines here show none)."""
    if spec.startswith(CKPT_PREFIX):
        path = Path(spec[len(CKPT_PREFIX) :])
        if path.is_dir():
            return CheckpointSetMethod(path, device=device, synthesis=synthesis)
        return CheckpointMethod(path, device=device, synthesis=synthesis)
    if spec in BASELINES:
        return BASELINES[spec]
    raise ValueError(f"unknown method {spec!r}; expected one of {', '.join(method_names())}")


# -- what ``avgs eval`` asks of a task's evaluation (avgs.tasks: Task.evaluation) -------------

DEFAULT_METHODS = tuple(BASELINES)
"Scored when no method is named."
SPLITS = ("val", "train")
"The clips this task scores."
DEFAULT_SPLIT = "val"


def check_request(data_roots: list[str], specs: list[str], split: str) -> None:
    """ValueError, before any scene is read, for what this task cannot score."""
    if len(data_roots) != 1:
        raise ValueError(f"the binaural task takes one DATA_ROOT, got {len(data_roots)}: {' '.join(map(str, data_roots))}")
    if split not in SPLITS:
        raise ValueError(f"--split {split}: the binaural task scores val or train clips (heldout and both are --task rir)")


def checkpoint_paths(specs: list[str]) -> list[str]:
    """The checkpoint (or folder) paths that ``specs`` name."""
    return [s[len(CKPT_PREFIX) :] for s in specs if s.startswith(CKPT_PREFIX)]


def scenes(data_roots: list[str], ids: Iterable[str] | None = None) -> list[Path]:
    """The scene folders to score (:func:`find_scenes` of the one data root)."""
    return find_scenes(data_roots[0], ids)


def find_scenes(data_root: str | Path, ids: Iterable[str] | None = None) -> list[Path]:
    """Scene folders under ``data_root`` (those holding transforms files), or the named ones."""
    root = Path(data_root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: data root missing")
    if ids:
        dirs = []
        for scene_id in ids:
            path = root / scene_id
            if not is_scene_dir(path):
                raise FileNotFoundError(f"{path}: no RWAVS scene there (expected transforms_*.json files)")
            dirs.append(path)
        return dirs
    dirs = sorted((p for p in root.iterdir() if is_scene_dir(p)), key=lambda p: _natural_key(p.name))
    if not dirs:
        raise ValueError(f"{root}: no scene folders with transforms_*.json files found")
    return dirs


def _natural_key(name: str) -> list:
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", name)]


def environment_of(scene: RWAVSScene) -> str:
    """The scene's environment (see the module docstring for the rule)."""
    if scene.metadata and isinstance(scene.metadata.get("environment"), str) and scene.metadata["environment"]:
        return scene.metadata["environment"]
    prefix = re.split(r"[_-]", scene.name, maxsplit=1)[0]
    return prefix or scene.name


def predict(method: Method, clip: AudioClip, scene: RWAVSScene, name: str = "method") -> Prediction:
    """Run ``method`` on one clip and check its waveform is ``[2, T]``.

    The magnitudes of a method that returns only a waveform are its waveform's STFT
    magnitudes; a method's own magnitudes must have the shape of the clip's STFT.
    """
    out = method(clip, scene)
    mags = None
    if isinstance(out, Prediction):
        out, mags = out
    wave = _float32(out)
    if wave.shape != clip.binaural.shape:
        raise ValueError(f"{name} returned {wave.shape} for {scene.name} t={clip.time:g}s; expected {clip.binaural.shape}")
    if mags is None:
        mags = dsp.magnitude(torch.from_numpy(wave.astype(np.float64))).numpy()  # as metrics.mag computes it
    mags = mags.detach().cpu().numpy() if isinstance(mags, torch.Tensor) else np.asarray(mags, dtype=np.float64)
    expected = (2, STFT.n_freq, dsp.n_frames(wave.shape[-1]))
    if mags.shape != expected:
        raise ValueError(f"{name} returned magnitudes {mags.shape} for {scene.name} t={clip.time:g}s; expected {expected}")
    return Prediction(wave, mags)


def _float32(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float32)


def score_scene(
    method: Method, scene: RWAVSScene, name: str = "method", split: str = "val", progress: bool = True
) -> dict[str, float | None]:
    """Mean MAG, ENV, ILD error and MAGp, median ITD error (us) and lateralisation agreement
    (%, None when no clip is eligible) of ``method`` over the scene's ``split`` clips."""
    clips = scene.clips(split)
    if not clips:
        raise ValueError(f"{scene.root}: no {split} clips to evaluate")
    fs = getattr(scene, "sample_rate", STFT.sample_rate)
    totals = dict.fromkeys(MEAN_METRICS, 0.0)
    itd_pred, itd_true, itd_errors = [], [], []
    for clip in tqdm(clips, desc=f"{name} / {scene.name}", unit="clip", leave=False, disable=not progress):
        pred, mags = predict(method, clip, scene, name)
        totals["MAG"] += metrics.mag(pred, clip.binaural)
        totals["ENV"] += metrics.env(pred, clip.binaural)
        totals["ILD"] += metrics.ild_error(pred, clip.binaural)
        totals["MAGp"] += metrics.mag_spectrogram(mags, clip.binaural)
        p, t, error = spatial.clip_itds(pred, clip.binaural, fs)
        itd_pred.append(p)
        itd_true.append(t)
        itd_errors.append(error)
    scores: dict[str, float | None] = {k: v / len(clips) for k, v in totals.items()}
    scores["ITD"] = spatial.median(itd_errors)
    scores["LAT"] = spatial.lateralisation(itd_true, itd_pred)
    return scores


def _mean(scores: Iterable[dict[str, float | None]]) -> dict[str, float | None]:
    """Per metric, the mean over ``scores`` of the values that are not None (None if none is)."""
    scores = list(scores)
    out: dict[str, float | None] = {}
    for k in scores[0]:
        values = [s[k] for s in scores if s.get(k) is not None]
        out[k] = float(np.mean(values)) if values else None
    return out


def aggregate(scene_scores: dict[str, dict[str, float]], environments: dict[str, str]) -> dict:
    """``{"scenes", "environments", "overall"}``: overall is the mean of the environment means."""
    by_env: dict[str, list[dict[str, float]]] = {}
    for scene_id, score in scene_scores.items():
        by_env.setdefault(environments[scene_id], []).append(score)
    env_scores = {env: _mean(scores) for env, scores in by_env.items()}
    return {"scenes": dict(scene_scores), "environments": env_scores, "overall": _mean(env_scores.values())}


def evaluate(
    methods: dict[str, Method],
    scene_dirs: Iterable[str | Path],
    split: str = "val",
    progress: bool = True,
) -> dict:
    """Score every method on every scene it applies to.

    Scenes are loaded one at a time (a real scene's recordings are minutes long).
    Returns ``{"split", "environments": {scene: env}, "clips": {scene: n},
    "methods": {name: {"scenes": {scene: {MAG, ENV, ILD, MAGp, ITD, LAT}}, "environments": {...},
    "overall": {...}}}}`` (LAT may be None: JSON null).
    """
    per_method: dict[str, dict[str, dict[str, float]]] = {name: {} for name in methods}
    environments: dict[str, str] = {}
    clips: dict[str, int] = {}
    for scene_dir in scene_dirs:
        scene = RWAVSScene(scene_dir)
        environments[scene.name] = environment_of(scene)
        clips[scene.name] = len(scene.clips(split))
        for name, method in methods.items():
            applies = getattr(method, "applies_to", None)
            if applies is not None and not applies(scene):
                continue
            per_method[name][scene.name] = score_scene(method, scene, name, split, progress)
    report = {"split": split, "environments": environments, "clips": clips, "methods": {}}
    for name, scene_scores in per_method.items():
        if not scene_scores:
            raise ValueError(f"method {name} applies to none of the scenes {sorted(environments)}")
        report["methods"][name] = aggregate(scene_scores, environments)
    return report


COLUMNS = (("MAG", 9, ".3f"), ("ENV", 8, ".4f"), ("ILD", 6, ".2f"), ("MAGp", 8, ".3f"), ("ITD", 8, ".1f"),
           ("LAT", 7, ".1f"))
"The binaural task's table columns: (metric, least width, format); ITD in us, LAT in %."


def format_report(report: dict, columns=COLUMNS, unit: str = "clips") -> str:
    """Plain-text table: one row per scene, per environment and overall; per method the
    ``columns`` (default: MAG, ENV, ILD error (dB), MAGp, ITD error (us) and LAT (%)), each
    ``(metric, least width, format)``; a value that is None (no eligible clip) shows ``n/a``."""
    names = list(report["methods"])
    label_w = max([len("overall")] + [len(s) + 6 for s in report["environments"]] + [len(e) + 6 for e in report["environments"].values()])
    col_w = max(sum(w for _, w, _ in columns), *(len(n) + 2 for n in names))
    first = col_w - sum(w for _, w, _ in columns[1:])  # the first column takes the rest of a long method name
    cols = ((columns[0][0], first, columns[0][2]), *columns[1:])
    head1 = " " * label_w + "".join(f"{n:>{col_w}}" for n in names)
    head2 = " " * label_w + "".join(f"{c:>{w}}" for c, w, _ in cols) * len(names)
    lines = [f"{report['split']} {unit}: {sum(report['clips'].values())} in {len(report['clips'])} scene(s)", head1, head2]

    def cell(s: dict | None, c: str, w: int, fmt: str) -> str:
        if not s:
            return f"{'-':>{w}}"
        value = s.get(c)
        return f"{'n/a':>{w}}" if value is None else f"{value:>{w}{fmt}}"

    def row(label: str, pick) -> str:
        cells = []
        for n in names:
            s = pick(report["methods"][n])
            cells.append("".join(cell(s, c, w, fmt) for c, w, fmt in cols))
        return f"{label:<{label_w}}" + "".join(cells)

    for scene_id in report["environments"]:
        lines.append(row(f"scene {scene_id}", lambda m, s=scene_id: m["scenes"].get(s)))
    for env in dict.fromkeys(report["environments"].values()):
        lines.append(row(f"env   {env}", lambda m, e=env: m["environments"].get(e)))
    lines.append(row("overall", lambda m: m["overall"]))
    return "\n".join(lines)
