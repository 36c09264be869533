"""Both stages end to end: scene folder in, ``scene.ckpt`` (+ log + curves) out.

Stage 1 warms up the 3D-GS scene G on the RGB key frames (:mod:`avgs.gaussians`);
G_a is initialised from it (``init="gs"``) or straight from its initial points
(``init="sfm"``): the scene's surfaces from scene.json, or, on a scene without them, SfM
points triangulated from the frames with their known poses
(:func:`avgs.train.stage1.initial_points`). Stage 2 (:mod:`avgs.train.stage2`) trains G_a, F and B on the audio clips, saving the checkpoint atomically every
``checkpoint_every`` iterations; ``resume=True`` continues from the last one.

Resuming is exact: the checkpoint's ``train_state`` holds the whole training state
(:meth:`Stage2Trainer.state_dict <avgs.train.stage2.Stage2Trainer.state_dict>`: optimizer,
schedule position, the point manager's statistics and generator, every random generator),
so a run resumed from any saved checkpoint (a killed one, say) ends with the same points and
weights, bit for bit, as the run that was never interrupted (on the CPU, with the same
iterations and the same number of torch threads).
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

import torch

from avgs.acoustics.points import AudioPoints
from avgs.config import TrainConfig
from avgs.data.identity import check_scene_identity, scene_identity
from avgs.data.scene_geometry import outline_from_metadata
from avgs.io.checkpoint import build_checkpoint, config_of, load_checkpoint, save_checkpoint
from avgs.tasks import BINAURAL, DEFAULT, Task, task_named, task_of
from avgs.train.logging import JsonLinesLog, log_paths, plot_curves
from avgs.train.stage1 import (
    audio_points_from,
    cpu_stage1_budget,
    initial_points,
    load_stage1,
    needs_gaussians,
    reusable,
    save_stage1,
    stage1_init_source,
    stage1_path,
    train_stage1,
)
from avgs.train.tasks import TaskTraining, quick_config  # noqa: F401 (the --quick preset, imported from here too)


def _stage1(scene, cfg: TrainConfig, log: JsonLinesLog, progress: bool, cache: Path, given: tuple[Path, dict] | None):
    """(AudioPoints, gaussians dict or None): stage 1 as ``cfg.init`` and ``cfg.store_gaussians`` ask.

    G comes from ``given`` (a stage-1 file and its contents, :func:`_given_stage1`), else from ``cache`` when it was made for this
    scene and these settings, else it is trained and written to ``cache``. The initial points
    (scene.json's surfaces or SfM points) are made once, when G_a or a new G needs them.
    """
    source = stage1_init_source(scene.metadata, cfg)
    log.write({"stage": "stage1", "event": "init_source", "source": source, "init": cfg.init})
    made: list = []

    def init():
        if not made:
            made.append(initial_points(scene.root, scene.metadata, cfg, progress=progress,
                                       log_fn=lambda r: log.write({"stage": "stage1", **r})))
        return made[0]

    gaussians = None
    if needs_gaussians(cfg):
        data = given[1] if given is not None else (load_stage1(cache) if cache.is_file() else None)
        reuse = data is not None and (given is not None or reusable(data, scene.name, cfg, source))
        if not reuse and _apply_cpu_budget(scene.root, cfg, log.write, progress):
            reuse = data is not None and reusable(data, scene.name, cfg, source)
        if reuse:
            for record in data.get("history", []):
                log.write(record)
            log.write({"stage": "stage1", "event": "reused", "file": str(given[0] if given is not None else cache)})
            gaussians = data["gaussians"]
        else:
            gaussians, stats, history = _train_stage1_logged(scene.root, cfg, progress, log.write, init())
            save_stage1(cache, scene.name, cfg, gaussians, stats, history)
    points = audio_points_from(gaussians if cfg.init == "gs" else None, init() if cfg.init == "sfm" else None, cfg)
    return points, (gaussians if cfg.store_gaussians else None)


def _given_stage1(path: str | Path | None, scene_name: str, cfg: TrainConfig) -> tuple[Path, dict] | None:
    """``--stage1 FILE`` read and checked before any output is written (a foreign or malformed
    file is refused without leaving a log behind); None when no file is given or G is not needed."""
    if path is None or not needs_gaussians(cfg):
        return None
    data = load_stage1(path)
    if data.get("scene") != scene_name:
        raise ValueError(f"{path}: stage 1 of scene {data.get('scene')!r}, not of {scene_name!r}")
    return Path(path), data


def _apply_cpu_budget(scene_dir: Path, cfg: TrainConfig, sink, progress: bool) -> bool:
    """Set stage 1's CPU budget on ``cfg`` (in place, so that the stored configuration and the
    stage-1 key say what G was trained with) when it applies
    (:func:`avgs.train.stage1.cpu_stage1_budget`); True when it did, and says so."""
    budget = cpu_stage1_budget(scene_dir, cfg)
    if budget is None:
        return False
    cfg.gaussians.image_downscale, cfg.gaussians.max_gaussians = budget["image_downscale"], budget["max_gaussians"]
    if sink is not None:
        sink({"stage": "stage1", "event": "cpu_budget", **budget})
    if progress:
        from tqdm.auto import tqdm

        tqdm.write(f"stage 1 on the CPU: frames shrunk {budget['image_downscale']}x, at most {budget['max_gaussians']} "
                   "Gaussians (--stage1-image-downscale N > 1 sets the size; CUDA trains at full size)")
    return True


def run_stage1_only(scene_dir: str | Path, out: str | Path, cfg: TrainConfig | None = None, *, progress: bool = True) -> Path:
    """Stage 1 alone (frames and poses only, no audio read): writes ``<out>.stage1.pt``, which a
    later ``train_scene(scene_dir, out, ...)`` with the same settings picks up."""
    cfg = copy.deepcopy(cfg or TrainConfig())
    scene_dir = Path(scene_dir).resolve()
    if not scene_dir.is_dir():
        raise FileNotFoundError(f"{scene_dir}: scene folder missing")
    _apply_cpu_budget(scene_dir, cfg, None, progress)
    gaussians, stats, history = _train_stage1_logged(scene_dir, cfg, progress)
    return save_stage1(stage1_path(out), scene_dir.name, cfg, gaussians, stats, history)


def _train_stage1_logged(scene_dir: Path, cfg: TrainConfig, progress: bool, sink=None, init=None):
    """Train G (from ``init`` points when given); returns ``(gaussians, stats, history)``, each
    history record also sent to ``sink``."""
    history: list[dict] = []

    def record(r: dict) -> None:
        history.append({"stage": "stage1", **r})
        if sink is not None:
            sink(history[-1])

    gaussians, stats = train_stage1(scene_dir, cfg, progress=progress, log_fn=record, init=init)
    record({"event": "trained", **{k: v for k, v in stats.items() if k != "backend"}, "backend": str(stats.get("backend"))})
    return gaussians, stats, history


def resume_from(out: Path, cfg: TrainConfig, log_path: Path, task: Task = BINAURAL, scene_dir: Path | None = None):
    """What ``--resume`` continues from the checkpoint ``out`` of ``task``: (the checkpoint, its
    stored configuration with this run's iterations (a run whose task sized its schedule to the data,
    logged as a "schedule" event, :attr:`~avgs.config.RIRConfig.passes`, keeps that size unless ``cfg``
    sets passes to 0),
    intervals and device, its log continued,
    its audio points, its G or None). ValueError when ``out`` holds no training state of ``task``,
    or was trained on another scene than ``scene_dir`` (:mod:`avgs.data.identity`)."""
    resumed = load_checkpoint(out)
    if resumed.get("train_state") is None or task_of(resumed) is not task:
        raise ValueError(f"{out}: holds no training state of the {task.name} task to resume from")
    if scene_dir is not None:
        check_scene_identity(resumed["scene"].get("identity"), scene_dir, out, "resume")
    stored = config_of(resumed)
    sized = any(r.get("event") == "schedule" for r in resumed.get("history") or [])  # its task sized its schedule
    if not (sized and cfg.rir.passes > 0):
        stored.acoustic.iterations = cfg.acoustic.iterations
    stored.checkpoint_every, stored.eval_every, stored.log_every = cfg.checkpoint_every, cfg.eval_every, cfg.log_every
    stored.device = cfg.device
    pts = resumed["audio_points"]
    return (resumed, stored, JsonLinesLog(log_path, resumed["history"]), AudioPoints(pts["X"], pts["alpha"]),
            resumed.get("gaussians"))


def train_scene(
    scene_dir: str | Path,
    out: str | Path,
    cfg: TrainConfig | None = None,
    *,
    task: str = DEFAULT,
    resume: bool = False,
    progress: bool = True,
    initial_points: AudioPoints | None = None,
    stage1: str | Path | None = None,
) -> dict:
    """Train AV-GS for ``task`` (:mod:`avgs.tasks`) on one scene and write ``out``; returns the
    final log record (the task's validation scores and final metrics).

    The task's hooks (:class:`~avgs.train.tasks.TaskTraining`) open the scene's targets and
    make its trainer; everything else is this one loop. ``initial_points`` (normalised frame)
    skips stage 1: G_a starts from them and no G is stored (for experiments on given
    geometry, and for tests that exercise stage 2 alone). ``stage1`` names a stage-1 file
    (:mod:`avgs.train.stage1`) to take G from; without it, ``<out>.stage1.pt`` is reused when
    it matches the scene and settings, else written.

    With ``resume`` and an existing ``out``, the model, optimizer and random state come from
    it and training continues from its iteration up to ``cfg.acoustic.iterations``.

    A run that fails before its first checkpoint is saved removes the log it started; the
    stage-1 file it wrote (``<out>.stage1.pt``) stays, for the next run to reuse.
    """
    kind = task_named(task, "task")
    cfg = copy.deepcopy(cfg or TrainConfig())
    out = Path(out)
    log_path, _ = log_paths(out)
    hooks: TaskTraining = kind.part("training")(scene_dir, cfg)
    scene = hooks.scene
    torch.manual_seed(cfg.seed)

    identity = scene_identity(scene.root)
    if resume and out.is_file():
        resumed, cfg, log, points, gaussians = resume_from(out, cfg, log_path, kind, scene.root)
        return _train(kind, hooks, cfg, out, log, points, gaussians, resumed, identity, progress, [])
    given = _given_stage1(stage1, scene.name, cfg)  # refused before the log is started
    log = JsonLinesLog(log_path)
    saved: list[int] = []
    try:
        planned = cfg.acoustic.iterations
        hooks.configure(cfg, log)
        if progress and cfg.acoustic.iterations != planned:
            from tqdm.auto import tqdm

            tqdm.write(f"stage 2: {cfg.acoustic.iterations} iterations, sized to the scene's training data "
                       f"(at most {planned}; --iterations N sets the count)")
        t0 = time.perf_counter()
        if initial_points is not None:
            points, gaussians = initial_points, None
        else:
            points, gaussians = _stage1(scene, cfg, log, progress, stage1_path(out), given)
        log.write({"stage": "stage1", "event": "done", "seconds": time.perf_counter() - t0, "points": points.num_points})
        return _train(kind, hooks, cfg, out, log, points, gaussians, None, identity, progress, saved)
    except BaseException:
        if not saved:  # a run that failed (a full disk, an error, Ctrl-C) before its first checkpoint leaves no log
            log.path.unlink(missing_ok=True)
        raise


def _train(kind: Task, hooks: TaskTraining, cfg: TrainConfig, out: Path, log: JsonLinesLog, points, gaussians,
           resumed: dict | None, identity: str, progress: bool, saved: list[int]) -> dict:
    """Stage 2: the one loop, from ``points`` (and ``resumed``'s state), saving ``out`` (each save's
    iteration appended to ``saved``)."""
    from tqdm.auto import tqdm

    scene = hooks.scene
    _, png_path = log_paths(out)
    torch.manual_seed(cfg.seed)
    model = kind.part("model").build(points, cfg, cfg.stft)
    if resumed is not None:
        try:
            if model.field is not None:
                model.field.load_state_dict(resumed["field"])
            model.binauralizer.load_state_dict(resumed["binauralizer"])
        except RuntimeError as exc:  # load_checkpoint compared the shapes already; this is the last guard
            raise ValueError(f"{out}: its network weights do not fit its configuration ({str(exc).splitlines()[0]})") from None
    trainer = hooks.trainer(model, cfg, resumed is not None)
    if resumed is not None:
        try:
            trainer.load_state_dict(resumed["train_state"])
        except ValueError as exc:
            raise ValueError(f"{out}: cannot resume from its training state: {exc}") from None
        log.write({"stage": "resume", "iteration": trainer.iteration, "file": str(out)})
    outline = outline_from_metadata(scene.metadata)

    def save(metrics: dict | None = None) -> None:
        extra = hooks.checkpoint_extra(metrics)
        ckpt = build_checkpoint(
            model, scene.frame, scene.source, cfg, history=log.records, gaussians=gaussians, name=scene.name, identity=identity,
            bounds_world=hooks.bounds(model, gaussians), outline_world=outline, stft=cfg.stft,
            extra={"task": kind.name, **extra, "train_state": trainer.state_dict()},
        )
        save_checkpoint(ckpt, out)
        saved.append(trainer.iteration)

    total = cfg.acoustic.iterations
    final: dict = {}
    bar = tqdm(total=total, initial=trainer.iteration, desc=hooks.label, disable=not progress, dynamic_ncols=True)
    t0 = time.perf_counter()
    while trainer.iteration < total:
        rec = trainer.step()
        it = trainer.iteration
        bar.update(1)
        record = {"stage": "stage2", "iteration": it, **rec}
        scores = hooks.validate(trainer) if it % cfg.eval_every == 0 or it == total else {}
        if scores:
            record.update(scores)
            first = hooks.scores[0]
            bar.set_postfix({"loss": f"{rec['loss']:.4f}", first: f"{record[first]:.3f}", "points": rec["points"]})
        if it % cfg.log_every == 0 or it == total or rec["added"] or rec["removed"] or scores:
            log.write({**record, "seconds": time.perf_counter() - t0})
        if it == total:
            final = {k: record[k] for k in ("iteration", "loss", "points", *hooks.scores) if k in record}
        elif it % cfg.checkpoint_every == 0:
            save()
    bar.close()
    final = hooks.final(trainer, final)
    log.write({"stage": "final", **final})
    save(final)
    plot_curves(log.records, png_path)
    return final
