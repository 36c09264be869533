"""Write one impulse-response scene (``avgs synth --task rir``): binaural room impulse
responses straight from the simulator, for every (source, receiver, orientation) of a grid.

The scene folder is first an ordinary RWAVS scene for source 0 (:func:`writer.write_scene`:
frames, camera poses, binaural track, scene.json, position.json), so that stage 1 and the
binaural loader read it unchanged; then ``rir/`` is added to it before the folder is renamed
into place (nothing half-written is ever at the target). Layout (docs/rir-layout.md, read by
:mod:`avgs.data.rir`)::

    <scene>/rir/index.json                 format, sample rate, orientations, sources and
                                           receivers (normalised), splits of (source, receiver) pairs
    <scene>/rir/s{S:03d}_r{R:04d}_y{Y:03d}.wav   [L, 2] float32, channel 0 = left ear

Time 0 of every response is the emission: pyroomacoustics' fractional-delay offset and the
head's own delay (:func:`simulate.emission_delay`) are cut off the front, so the direct
sound of a source straight ahead peaks at ``distance / c``. No normalisation: level falls
with distance as simulated. Every response of a scene has the same length ``L``: the
decay (``decay_factor`` x the scene's measured broadband RT60) after the farthest pair's
direct sound, rounded up to whole STFT hops, within ``min_seconds`` .. ``max_seconds``.
Cost: one room per receiver holds its sources (up to :data:`SOURCES_PER_ROOM` at a time) and
the O x 2 ears as microphones.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from avgs.config import STFT
from avgs.data.rir import FORMAT, INDEX_FILE, MAX_RESPONSE_SECONDS, RIR_DIR, rir_file_name
from avgs.synth.grid import SPLITS, GridConfig, RIRGrid, make_grid
from avgs.synth.presets import PRESETS, RIR_PRESETS, SceneSpec, make_spec
from avgs.synth.simulate import SimSettings, ear_directivities, emission_delay, receiver_rirs, speed_of_sound
from avgs.synth.writer import SynthConfig, SynthResult, run_jobs, write_scene

ORIENTATIONS_DEG = (0, 90, 180, 270)

DEFAULT_GRIDS = {
    # spacings (metres) and caps sized so that one preset takes about 5 minutes on 2 cores
    # (docs/rir-layout.md): a pair of 4 orientations costs about 1.5 (rect_small) to 6 (three_rooms) s of one core
    "rect_small": GridConfig(receiver_spacing=0.6, source_spacing=1.2),
    "rect_large": GridConfig(receiver_spacing=1.25, source_spacing=2.5, max_receivers=24),
    "l_room": GridConfig(receiver_spacing=1.0, source_spacing=2.0),
    "u_room": GridConfig(receiver_spacing=1.25, source_spacing=2.5),
    "two_rooms": GridConfig(receiver_spacing=1.0, source_spacing=2.0),
    "three_rooms": GridConfig(receiver_spacing=1.25, source_spacing=2.0, max_receivers=12),
}
QUICK_GRID = GridConfig(receiver_spacing=0.75, source_spacing=1.5, max_sources=3, max_receivers=4)
SOURCES_PER_ROOM = 3
"""Sources simulated together in one room: pyroomacoustics' ray tracing with 8 directive
microphones takes ~1.1 GB plus ~0.4 GB per source, so rooms of at most 3 sources keep a
worker near 2.3 GB."""


def hybrid_settings() -> SimSettings:
    """The simulation of impulse-response scenes: image sources to order 4 (3 in non-shoebox
    rooms) and a ray-traced tail; cheaper than the binaural presets' order 10 at the same tail."""
    return SimSettings(max_order=4, max_order_polygon=3, ray_tracing=True)


@dataclass
class RIRConfig:
    """What ``avgs synth --task rir`` makes: one impulse-response scene of a preset."""

    preset: str = "rect_small"
    "Impulse-response preset: rect_small, rect_large, l_room, u_room, two_rooms or three_rooms."
    seed: int = 0
    "Seed of everything random (room, split, poses, simulator)."
    grid: GridConfig | None = None
    "Source and receiver grids and the split (None: the preset's default)."
    orientations_deg: tuple = ORIENTATIONS_DEG
    "Listener yaws in whole degrees, counter-clockwise from +x."
    decay_factor: float = 1.2
    "Response length after the farthest direct sound, in units of the scene's RT60."
    min_seconds: float = 0.1
    "Shortest response length in seconds."
    max_seconds: float = 1.5
    "Longest response length in seconds (the ray-traced tail is cut there)."
    workers: int = 2
    "Processes simulating receivers in parallel (the result does not depend on it)."
    quick: bool = False
    "Cheap scene for tests: 3 sources x 4 receivers, image sources only, short responses, 20 small frames."
    binaural: SynthConfig = field(default_factory=lambda: SynthConfig(sim=hybrid_settings()))
    "The RWAVS part: poses, frames, and the simulation settings of the whole scene (:func:`hybrid_settings`)."

    def __post_init__(self) -> None:
        self.binaural = dataclasses.replace(self.binaural, preset=self.preset, seed=self.seed, workers=self.workers)

    @classmethod
    def quick_config(cls, preset: str = "rect_small", seed: int = 0, **kw) -> "RIRConfig":
        """The ``--quick`` scene: :data:`QUICK_GRID`, image sources only, at most 0.25 s responses."""
        kw.setdefault("grid", QUICK_GRID)
        kw.setdefault("max_seconds", 0.25)
        return cls(preset=preset, seed=seed, quick=True, binaural=SynthConfig.quick_config(preset, seed), **kw)

    def grid_config(self) -> GridConfig:
        return self.grid if self.grid is not None else DEFAULT_GRIDS[self.preset]

    def validate(self) -> None:
        if self.preset not in RIR_PRESETS:
            hint = " (a binaural preset: use --task binaural)" if self.preset in PRESETS else ""
            raise ValueError(f"--task rir: unknown preset {self.preset!r}{hint}; expected one of {', '.join(RIR_PRESETS)}")
        o = list(self.orientations_deg)
        if not o or any(isinstance(y, bool) or not isinstance(y, int) or not 0 <= y < 360 for y in o) or len(set(o)) != len(o):
            raise ValueError(f"orientations must be distinct whole degrees in [0, 360), got {o}")
        if not (0 < self.min_seconds <= self.max_seconds <= MAX_RESPONSE_SECONDS):
            raise ValueError(f"need 0 < min_seconds <= max_seconds <= {MAX_RESPONSE_SECONDS} (the reader's cap), "
                             f"got {self.min_seconds} and {self.max_seconds}")
        if not self.decay_factor > 0:
            raise ValueError(f"decay_factor must be > 0, got {self.decay_factor}")
        if self.workers < 1:
            raise ValueError(f"--workers must be >= 1, got {self.workers}")
        self.grid_config().validate()


@dataclass
class RIRResult:
    """What :func:`write_rir_scene` made, and how long it took."""

    scene: SynthResult
    grid: RIRGrid
    length: int  # samples per response
    responses: int  # files written
    seconds_total: float
    seconds_responses: float  # wall time of the response simulation
    cpu_seconds_per_room: float  # mean single-process time of one room (a receiver and up to SOURCES_PER_ROOM sources)
    silent: int = 0  # responses with no sound at all (no image-source path, and ray tracing off)


def response_length(rt60_s: float | None, max_distance: float, cfg: RIRConfig, sample_rate: int) -> int:
    """Samples per response: ``decay_factor x rt60 + max_distance / c``, rounded up to whole
    STFT hops, within ``min_seconds`` .. ``max_seconds`` (``max_seconds`` when the RT60 is unknown):
    the cap is rounded down to whole hops, so a response never exceeds ``max_seconds``."""
    hop = STFT.hop_length
    seconds = cfg.max_seconds if rt60_s is None else cfg.decay_factor * float(rt60_s) + max_distance / speed_of_sound()
    seconds = min(max(seconds, cfg.min_seconds), cfg.max_seconds)
    top = max(1, int(cfg.max_seconds * sample_rate) // hop)  # whole hops within the cap
    return min(int(math.ceil(seconds * sample_rate / hop)), top) * hop


# -- per-receiver simulation (possibly in worker processes) -----------------------------

_JOB: dict = {}


def _init_worker(spec: SceneSpec, grid: RIRGrid, jobs: list, yaws: list, settings: SimSettings) -> None:
    _JOB.update(spec=spec, grid=grid, jobs=jobs, yaws=yaws, settings=settings)
    ear_directivities(settings.sample_rate, settings.hrtf_equalised)


def _simulate_receiver(i: int):
    t0 = time.perf_counter()
    r, sources = _JOB["jobs"][i]
    grid = _JOB["grid"]
    rirs = receiver_rirs(_JOB["spec"], grid.sources[sources], grid.receivers[r], _JOB["yaws"], _JOB["settings"])  # [S', O, 2, n]
    return r, sources, rirs, time.perf_counter() - t0


def _to_length(h: np.ndarray, offset: int, length: int) -> np.ndarray:
    """``h [2, n]`` from sample ``offset`` on, cut or zero-padded to ``[2, length]``."""
    out = np.zeros((2, length), dtype=np.float32)
    part = h[:, offset : offset + length]
    out[:, : part.shape[-1]] = part
    return out


# -- the scene --------------------------------------------------------------------------


def write_rir_scene(out_root, scene_id: str, cfg: RIRConfig, *, overwrite: bool = False, progress: bool = True) -> RIRResult:
    """Generate one impulse-response scene of ``cfg.preset`` into ``out_root/scene_id``
    (see the module docstring)."""
    from scipy.io import wavfile

    t_start = time.perf_counter()
    cfg.validate()
    spec = make_spec(cfg.preset, cfg.seed)
    grid = make_grid(spec, cfg.grid_config(), cfg.seed)
    spec = dataclasses.replace(spec, source=[float(v) for v in grid.sources[0]])  # the binaural task's source
    yaws = [int(y) for y in cfg.orientations_deg]
    pairs = grid.pairs()  # [N, 2] sorted by receiver
    jobs = []  # (receiver, up to SOURCES_PER_ROOM of its sources)
    for r in np.unique(pairs[:, 1]):
        sources = pairs[pairs[:, 1] == r, 0].tolist()
        jobs += [(int(r), sources[i : i + SOURCES_PER_ROOM]) for i in range(0, len(sources), SOURCES_PER_ROOM)]
    max_distance = float(np.max(np.linalg.norm(grid.sources[pairs[:, 0]] - grid.receivers[pairs[:, 1]], axis=-1)))
    info: dict = {}

    def extend(folder: Path, spec: SceneSpec, frame, metadata: dict) -> None:
        sr = int(metadata["simulation"]["sample_rate"])
        length = response_length(metadata["rt60"].get("broadband_s"), max_distance, cfg, sr)
        base = SimSettings.from_dict(metadata["simulation"])
        settings = dataclasses.replace(base, time_thres=min(base.time_thres, length / sr + 0.05))
        offset = emission_delay(settings)
        (folder / RIR_DIR).mkdir()
        t_sim = time.perf_counter()
        seconds, peak, silent = [], 0.0, 0
        ear_directivities(settings.sample_rate, settings.hrtf_equalised)  # before forking: workers inherit the head
        for r, sources, rirs, sec in run_jobs(
            _simulate_receiver, len(jobs), _init_worker, (spec, grid, jobs, yaws, settings),
            cfg.workers, progress, f"responses of {cfg.preset}", "room",
        ):
            seconds.append(sec)
            for k, s in enumerate(sources):
                for o, y in enumerate(yaws):
                    h = _to_length(rirs[k, o], offset, length)  # [2, L]
                    peak = max(peak, float(np.max(np.abs(h))))
                    silent += not np.any(h)  # no image-source path and no ray tracing (simulate.compute_rir)
                    # scipy writes IEEE-float WAVs with no PEAK chunk: the same seed gives the same bytes
                    wavfile.write(folder / RIR_DIR / rir_file_name(s, r, y), sr, np.ascontiguousarray(h.T))
        info.update(length=length, seconds=time.perf_counter() - t_sim, cpu=float(np.mean(seconds)), silent=silent)
        index = {
            "format": FORMAT,
            "sample_rate": sr,
            "orientations_deg": yaws,
            "sources": [[float(v) for v in p] for p in frame.to_normalised(grid.sources)],
            "receivers": [[float(v) for v in p] for p in frame.to_normalised(grid.receivers)],
            "splits": {k: grid.splits[k].tolist() for k in SPLITS},
        }
        (folder / RIR_DIR / INDEX_FILE).write_text(json.dumps(index, indent=1) + "\n")
        metadata["rir"] = {
            "format": FORMAT,
            "index": f"{RIR_DIR}/{INDEX_FILE}",
            "environment": spec.environment,
            "length_samples": length,
            "length_s": length / sr,
            "length_rule": f"{cfg.decay_factor} x rt60.broadband_s + farthest pair distance / c, rounded up to "
            f"{STFT.hop_length}-sample hops, within {cfg.min_seconds}..{cfg.max_seconds} s",
            "removed_delay_samples": offset,
            "time_zero": "emission: pyroomacoustics' frac_delay_length // 2 and the KEMAR head's frontal peak delay "
            "are cut off the front; the direct sound of a source straight ahead peaks at distance / c",
            "speed_of_sound": speed_of_sound(),
            "scale": 1.0,
            "peak": peak,
            "silent": silent,  # responses with no sound at all: no path of up to max_order_polygon reflections, no ray tracing
            "sources_world": grid.sources.tolist(),
            "receivers_world": grid.receivers.tolist(),
            "heldout_sources": grid.heldout_sources,
            "counts": {k: int(len(grid.splits[k])) for k in SPLITS},
            "grid": dataclasses.asdict(cfg.grid_config()),
            "simulation": settings.to_dict(),
        }  # no timings: the same seed gives the same bytes

    scene = write_scene(out_root, scene_id, cfg.binaural, overwrite=overwrite, progress=progress, spec=spec, extend=extend)
    return RIRResult(
        scene=scene,
        grid=grid,
        length=info["length"],
        responses=len(pairs) * len(yaws),
        seconds_total=time.perf_counter() - t_start,
        seconds_responses=info["seconds"],
        cpu_seconds_per_room=info["cpu"],
        silent=info["silent"],
    )
