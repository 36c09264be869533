"""Write one synthetic scene in the RWAVS layout (docs/design.md, "Data layout (RWAVS)"), atomically.

::

    OUT_ROOT/position.json                   merged: {"<scene>": {"source_position": [normalised]}}
    OUT_ROOT/<scene>/binaural_syn_re.wav     2 ch, 22050 Hz, peak-normalised (32-bit float)
    OUT_ROOT/<scene>/source_syn_re.wav       1 ch, 22050 Hz, peak-normalised (32-bit float)
    OUT_ROOT/<scene>/frames/00001.png ...    RGB key frame at t = 1 s, ...
    OUT_ROOT/<scene>/transforms_{train,val}.json        camera paths, world metres
    OUT_ROOT/<scene>/transforms_scale_{train,val}.json  the same poses, normalised
    OUT_ROOT/<scene>/transforms.json         nerfstudio intrinsics + all frames (world metres)
    OUT_ROOT/<scene>/scene.json              geometry, materials, frame map, settings, RT60, seed

Timing: frame ``t`` (seconds) is the 1 s clip centred on ``t``. The listener stands at
the pose of frame ``t`` for ``[t - 0.5, t + 0.5)`` (the first pose also covers the first
half second); what it hears then is that slice of (the whole source convolved with that
pose's binaural RIR), so reverberant tails of earlier sound are present, as in a
recording. Train frames come first (1..N_train), then val frames.

The scene is built in a temporary folder beside the target and renamed into place at the
end; position.json is rewritten through a temporary file and a rename, under a lock.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing as mp
import os
import re
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from avgs.io.atomic import write_text
from avgs.synth import GENERATOR_VERSION
from avgs.synth.materials import material_record
from avgs.synth.poses import Pose, sample_poses
from avgs.synth.presets import ALL_PRESETS, SceneSpec, make_spec
from avgs.synth.simulate import SimSettings, binaural_rirs, ear_directivities, rt60_summary

BINAURAL_FILE = "binaural_syn_re.wav"
SOURCE_FILE = "source_syn_re.wav"
POSITION_FILE = "position.json"
RT60_MAX_POSES = 24
_SCENE_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass
class SynthConfig:
    """What ``avgs synth`` makes: one scene of a preset."""

    preset: str = "office"
    "Scene preset: office, house, apartment or outdoor (or an impulse-response preset's room)."
    poses: int = 100
    "Listener poses (= frames = seconds of audio), train and val together."
    seed: int = 0
    "Seed of everything random (room size, source, poses, signals, simulator)."
    val_fraction: float = 0.2
    "Share of the poses kept for validation (the last frames)."
    width: int = 256
    "Key frame width in pixels."
    height: int = 192
    "Key frame height in pixels."
    fov_deg: float = 70.0
    "Vertical field of view of the key frames in degrees."
    workers: int = 2
    "Processes simulating poses in parallel (the result does not depend on it)."
    quick: bool = False
    "Cheap preset for tests (low order, no ray tracing, 64x48 frames)."
    sim: SimSettings = field(default_factory=SimSettings)
    "Acoustic simulation settings."

    @classmethod
    def quick_config(cls, preset: str = "office", seed: int = 0, poses: int = 20, **kw) -> "SynthConfig":
        """The ``--quick`` preset: ~20 poses, 64x48 frames, image sources only (a few seconds)."""
        return cls(preset=preset, seed=seed, poses=poses, width=64, height=48, quick=True, sim=SimSettings.quick(), **kw)

    def split_sizes(self) -> tuple[int, int]:
        """(train, val) pose counts."""
        if self.poses < 2:
            raise ValueError(f"--poses must be >= 2 (at least one train and one val pose), got {self.poses}")
        if not 0 < self.val_fraction < 1:
            raise ValueError(f"--val-fraction must be in (0, 1), got {self.val_fraction}")
        n_val = min(self.poses - 1, max(1, int(round(self.poses * self.val_fraction))))
        return self.poses - n_val, n_val


@dataclass
class SynthResult:
    """What :func:`write_scene` made, and how long it took."""

    scene_dir: Path
    spec: SceneSpec
    n_train: int
    n_val: int
    rt60: dict
    seconds_total: float
    seconds_simulation: float
    seconds_per_pose: float  # wall time of the simulation / poses
    cpu_seconds_per_pose: float  # mean single-process time of one pose


# -- the per-pose simulation (possibly in worker processes) -----------------------------

_JOB: dict = {}


def _init_worker(spec: SceneSpec, poses: list[Pose], settings: SimSettings) -> None:
    _JOB.update(spec=spec, poses=poses, settings=settings)
    ear_directivities(settings.sample_rate, settings.hrtf_equalised)  # built once per process (inherited when forked)


def _simulate_pose(i: int) -> tuple[int, np.ndarray, float]:
    t0 = time.perf_counter()
    pose = _JOB["poses"][i]
    rir = binaural_rirs(_JOB["spec"], pose.position, pose.yaw_deg, _JOB["settings"])  # [2, L]
    return i, rir, time.perf_counter() - t0


def run_jobs(job, n: int, init, initargs: tuple, workers: int = 2, progress: bool = True, desc: str = "", unit: str = "job"):
    """Yield ``job(i)`` for ``i < n`` (in any order) from ``workers`` processes, each set up
    once by ``init(*initargs)`` (forked where the platform can, so that what the parent
    built, e.g. the KEMAR head, is inherited), with a progress bar. ``job`` and ``init``
    must be module-level functions; the results must not depend on the worker count."""
    from tqdm.auto import tqdm

    bar = tqdm(total=n, desc=desc, unit=unit, disable=not progress)
    workers = max(1, min(int(workers), n))
    if workers == 1:
        init(*initargs)
        try:
            for result in map(job, range(n)):
                yield result
                bar.update(1)
        finally:
            bar.close()
        return
    method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
    pool = mp.get_context(method).Pool(workers, initializer=init, initargs=initargs)
    try:
        for result in pool.imap_unordered(job, range(n)):
            yield result
            bar.update(1)
        # Done: the workers are told to stop and exit on their own. Pool.terminate (the with
        # block's exit) SIGTERMs them instead, and a worker that the signal finds waiting for the
        # task queue's lock could be left waiting, the parent joining it for ever (seen once in a run
        # of the test suite, the parent a multi-threaded test process).
        pool.close()
        pool.join()
    finally:
        pool.terminate()  # stopped early (an error, Ctrl+C, the caller gone): no wait for the jobs left
        bar.close()


def simulate_poses(spec: SceneSpec, poses: list[Pose], settings: SimSettings, workers: int = 2, progress: bool = True):
    """Binaural RIRs of every pose, in pose order, and each pose's compute time in seconds."""
    rirs: list = [None] * len(poses)
    times = [0.0] * len(poses)
    ear_directivities(settings.sample_rate, settings.hrtf_equalised)  # before forking, so that workers inherit the head
    jobs = run_jobs(_simulate_pose, len(poses), _init_worker, (spec, poses, settings), workers, progress, f"simulating {spec.preset}", "pose")
    for i, rir, seconds in jobs:
        rirs[i], times[i] = rir, seconds
    return rirs, times


# -- audio -----------------------------------------------------------------------------


def pose_windows(n_poses: int, total: int, sample_rate: int) -> list[tuple[int, int]]:
    """Sample range ``[start, stop)`` during which the listener stands at pose ``i``
    (frame ``i + 1``): ``[(t - 0.5) sr, (t + 0.5) sr)``; the first starts at 0, the last ends at ``total``."""
    out = []
    for i in range(n_poses):
        t = i + 1
        start = 0 if i == 0 else int(round((t - 0.5) * sample_rate))
        stop = total if i == n_poses - 1 else int(round((t + 0.5) * sample_rate))
        out.append((start, stop))
    return out


def binaural_track(mono: np.ndarray, rirs: list[np.ndarray], sample_rate: int) -> np.ndarray:
    """``[2, T]``: for each pose's window, the slice of ``mono [T]`` convolved with that pose's RIR ``[2, L]``."""
    from scipy.signal import fftconvolve

    out = np.zeros((2, len(mono)))
    for (start, stop), rir in zip(pose_windows(len(rirs), len(mono), sample_rate), rirs):
        lo = max(0, start - rir.shape[-1] + 1)  # earliest sample still ringing at `start`
        y = fftconvolve(mono[None, lo:stop], rir.astype(np.float64), axes=-1)  # [2, stop - lo + L - 1]
        out[:, start:stop] = y[:, start - lo : stop - lo]
    return out


def _peak_normalised(x: np.ndarray) -> np.ndarray:
    peak = float(np.max(np.abs(x)))
    return (x / peak if peak > 0 else x).astype(np.float32)


# -- files -----------------------------------------------------------------------------


def normalisation(spec: SceneSpec, poses: list[Pose]) -> dict:
    """``{"center": [3], "scale": s}`` mapping the scene's visible surfaces, source and
    poses into [-1, 1]^3 (``normalised = (world - center) * scale``)."""
    pts = [np.asarray(spec.source, dtype=np.float64)[None], np.stack([p.position for p in poses])]
    pts += [s.corners for s in spec.visible_surfaces()]
    allp = np.concatenate(pts)
    lo, hi = allp.min(0), allp.max(0)
    center = (lo + hi) / 2
    scale = 1.0 / max(float(np.max(hi - lo)) / 2, 1e-6)
    return {"center": [round(float(v), 9) for v in center], "scale": float(scale)}


def c2w_matrix(position, yaw_deg: float) -> np.ndarray:
    """OpenGL camera-to-world ``[4, 4]``: looks along its -Z = the facing, +Y = world +z."""
    from avgs.data.frame import c2w_from_yaw

    return c2w_from_yaw(position, np.radians(yaw_deg))


def _camera_path(entries: list[tuple[int, np.ndarray]], cfg: SynthConfig) -> dict:
    return {
        "camera_type": "perspective",
        "render_height": cfg.height,
        "render_width": cfg.width,
        "camera_path": [
            {
                "camera_to_world": [float(v) for v in c2w.reshape(-1)],
                "file_path": f"frames/{t:05d}.png",
                "fov": cfg.fov_deg,
                "aspect": cfg.width / cfg.height,
            }
            for t, c2w in entries
        ],
    }


def _write_json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=1) + "\n")


@contextlib.contextmanager
def _locked(path: Path):
    """An exclusive advisory lock on ``path`` (a no-op where fcntl is unavailable)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    with open(path, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def merge_position(out_root: Path, scene_id: str, source_normalised) -> None:
    """Add or replace ``scene_id``'s source in ``out_root/position.json``, keeping other scenes."""
    path = out_root / POSITION_FILE
    with _locked(out_root / f".{POSITION_FILE}.lock"):
        table = {}
        if path.is_file():
            try:
                table = json.loads(path.read_text())
            except json.JSONDecodeError as exc:
                raise ValueError(f"{path}: not valid JSON ({exc}); fix or remove it before adding scenes") from None
            if not isinstance(table, dict):
                raise ValueError(f"{path}: expected a JSON object of scenes")
        table[scene_id] = {"source_position": [float(v) for v in source_normalised]}
        write_text(path, json.dumps(table, indent=1, sort_keys=True) + "\n")


def _save_png(path: Path, rgb: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(rgb).save(path, optimize=False)


def check_scene_id(scene_id: str) -> None:
    if not _SCENE_ID.match(scene_id or "") or scene_id == POSITION_FILE:
        raise ValueError(f"scene id {scene_id!r}: use letters, digits, '_', '-' or '.', starting with a letter or digit")


def write_scene(
    out_root,
    scene_id: str,
    cfg: SynthConfig,
    *,
    overwrite: bool = False,
    progress: bool = True,
    spec: SceneSpec | None = None,
    extend=None,
) -> SynthResult:
    """Generate one scene of ``cfg.preset`` into ``out_root/scene_id`` (see the module docstring).

    ``spec``: the scene to write instead of ``make_spec(cfg.preset, cfg.seed)`` (same preset).
    ``extend(folder, spec, frame, metadata)``: called once everything but scene.json is in the
    temporary scene folder; it may add files there and entries to ``metadata`` (scene.json's
    dict), and they are renamed into place with the rest (``avgs synth --task rir``)."""
    from scipy.io import wavfile

    from avgs.data.frame import SceneFrame
    from avgs.synth.render import FrameRenderer, focal_length_px
    from avgs.synth.signals import scene_source

    t_start = time.perf_counter()
    check_scene_id(scene_id)
    if cfg.preset not in ALL_PRESETS:
        raise ValueError(f"unknown preset {cfg.preset!r}; expected one of {', '.join(ALL_PRESETS)}")
    if spec is not None and spec.preset != cfg.preset:
        raise ValueError(f"the spec given is of preset {spec.preset!r}, the config's is {cfg.preset!r}")
    n_train, n_val = cfg.split_sizes()
    out_root = Path(out_root)
    target = out_root / scene_id
    if target.exists() and not overwrite:
        raise ValueError(f"{target}: already exists; pass --overwrite to replace it")
    out_root.mkdir(parents=True, exist_ok=True)
    sr = cfg.sim.sample_rate

    spec = make_spec(cfg.preset, cfg.seed) if spec is None else spec
    pose_rng = np.random.default_rng([cfg.seed, 1])
    train = sample_poses(spec, n_train, pose_rng)
    val = sample_poses(spec, n_val, pose_rng, avoid=train)
    poses = train + val  # pose i is frame i + 1

    settings = SimSettings.from_dict({**cfg.sim.to_dict(), "seed": cfg.seed})
    t_sim = time.perf_counter()
    rirs, pose_seconds = simulate_poses(spec, poses, settings, cfg.workers, progress)
    seconds_sim = time.perf_counter() - t_sim

    total = int(round((len(poses) + 0.5) * sr))
    mono = scene_source(n_train + 0.5, total / sr, cfg.seed, sr)  # [T] speech (train), music (val)
    binaural = binaural_track(mono, rirs, sr)  # [2, T]
    rt60 = rt60_summary(rirs[:RT60_MAX_POSES], sr, settings.ray_tracing)

    frame = SceneFrame.from_dict(normalisation(spec, poses))
    tmp = out_root / f".{scene_id}.tmp-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "frames").mkdir(parents=True)
    try:
        # scipy writes IEEE-float WAVs with no PEAK chunk (libsndfile's carries a timestamp),
        # so the same seed gives the same bytes
        wavfile.write(tmp / SOURCE_FILE, sr, _peak_normalised(mono))
        wavfile.write(tmp / BINAURAL_FILE, sr, np.ascontiguousarray(_peak_normalised(binaural).T))

        with FrameRenderer(spec, cfg.width, cfg.height, cfg.fov_deg, seed=cfg.seed) as renderer:
            for i, pose in enumerate(poses):
                _save_png(tmp / "frames" / f"{i + 1:05d}.png", renderer.render(pose.position, pose.yaw_deg))

        c2w = [c2w_matrix(p.position, p.yaw_deg) for p in poses]
        for split, idx in (("train", range(n_train)), ("val", range(n_train, len(poses)))):
            world = [(i + 1, c2w[i]) for i in idx]
            scaled = [(t, frame.pose_to_normalised(m)) for t, m in world]
            _write_json(tmp / f"transforms_{split}.json", _camera_path(world, cfg))
            _write_json(tmp / f"transforms_scale_{split}.json", _camera_path(scaled, cfg))
        fl = focal_length_px(cfg.height, cfg.fov_deg)
        _write_json(
            tmp / "transforms.json",
            {
                "camera_model": "OPENCV",
                "fl_x": fl,
                "fl_y": fl,
                "cx": cfg.width / 2,
                "cy": cfg.height / 2,
                "w": cfg.width,
                "h": cfg.height,
                "k1": 0.0,
                "k2": 0.0,
                "p1": 0.0,
                "p2": 0.0,
                "frames": [{"file_path": f"frames/{i + 1:05d}.png", "transform_matrix": m.tolist()} for i, m in enumerate(c2w)],
            },
        )
        metadata = _scene_json(spec, cfg, settings, frame, n_train, n_val, rt60, poses)
        if extend is not None:
            extend(tmp, spec, frame, metadata)
        _write_json(tmp / "scene.json", metadata)

        if target.exists():  # overwrite: swap, then delete the old one
            old = out_root / f".{scene_id}.old-{os.getpid()}"
            os.replace(target, old)
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    merge_position(out_root, scene_id, frame.to_normalised(spec.source))

    return SynthResult(
        scene_dir=target,
        spec=spec,
        n_train=n_train,
        n_val=n_val,
        rt60=rt60,
        seconds_total=time.perf_counter() - t_start,
        seconds_simulation=seconds_sim,
        seconds_per_pose=seconds_sim / len(poses),
        cpu_seconds_per_pose=float(np.mean(pose_seconds)),
    )


def _scene_json(spec, cfg, settings, frame, n_train, n_val, rt60, poses) -> dict:
    surfaces = spec.surfaces()
    materials = sorted({s.material for s in surfaces})
    return {
        "generator": {"name": "avgs.synth", "version": GENERATOR_VERSION},
        "preset": spec.preset,
        "environment": spec.environment,
        "seed": cfg.seed,
        "quick": cfg.quick,
        "units": "metres; z up; yaw degrees counter-clockwise from +x",
        "to_normalised": frame.to_dict(),
        "bounds": spec.bounds().tolist(),
        "source": {"position": [float(v) for v in spec.source], "normalised": [float(v) for v in frame.to_normalised(spec.source)]},
        "listener_height": spec.listener_height,
        "surfaces": [s.to_dict() for s in surfaces if s.visible],
        "materials": {m: material_record(m) for m in materials},
        "simulation": settings.to_dict(),
        "simulator": _simulator_versions(),
        "hrtf": "MIT KEMAR normal pinna (Gardner & Martin 1994), from the slab package, "
        + ("diffuse-field equalised" if settings.hrtf_equalised else "not equalised (the head's own response)")
        + "; both ears at the head centre",
        "rt60": rt60,
        "signals": {"train": "speech", "val": "music", "sample_rate": settings.sample_rate},
        "frames": {"train": [1, n_train], "val": [n_train + 1, n_train + n_val]},
        "camera": {"width": cfg.width, "height": cfg.height, "fov_deg": cfg.fov_deg},
        "poses": [{"frame": i + 1, "position": [round(float(v), 6) for v in p.position], "yaw_deg": round(p.yaw_deg, 6)} for i, p in enumerate(poses)],
        "spec": spec.to_dict(),
    }


def _simulator_versions() -> dict:
    import pyroomacoustics as pra

    return {"pyroomacoustics": pra.__version__}
