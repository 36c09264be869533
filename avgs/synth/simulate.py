"""Binaural room impulse responses of a scene spec, with pyroomacoustics and the KEMAR head.

Hybrid simulation: image sources up to ``max_order`` (shoebox rooms, pyroomacoustics' fast
path) or ``max_order_polygon`` (any other room: the image count grows as walls^order),
plus ray tracing for the late tail (``time_thres``) and air absorption. Every surface is
a quad or polygon, never triangles (a box of 12 triangles took 61 s per pose instead of
0.2 s). The head: both ears at the head centre, each a KEMAR measured directivity built
once per process (~1 s) and then copied and turned per pose (``copy.copy`` +
``set_orientation``), so a pose costs about the room simulation alone.

Public contract (the benchmarks call it)::

    spec = load_spec(scene_dir)                                     # from scene.json
    rirs = binaural_rirs(spec, listener, yaw_deg, SimSettings())   # [2, L] float32, 22050 Hz, ch0 = left

``binaural_rirs`` is a pure function of its arguments: pyroomacoustics' random generator
(ray tracing, tail synthesis) is seeded from them, so a pose gives the same response in
any process and in any order. That generator is global to the process: call it from one
thread at a time (use processes for parallelism, as ``avgs synth`` does).
"""

from __future__ import annotations

import copy
import json
import math
import threading
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from avgs.config import STFT
from avgs.synth.materials import pra_material
from avgs.synth.presets import SceneSpec

SAMPLE_RATE = STFT.sample_rate
RT60_BANDS_HZ = (125, 250, 500, 1000, 2000, 4000)


@dataclass
class SimSettings:
    """Acoustic simulation settings (pyroomacoustics)."""

    max_order: int = 10
    "Image-source order in shoebox rooms."
    ray_tracing: bool = True
    "Add a ray-traced late tail (hybrid simulation)."
    air_absorption: bool = True
    "Frequency-dependent air absorption."
    max_order_polygon: int = 3
    "Image-source order in non-shoebox rooms (the image count grows as walls^order); ray tracing does the rest."
    time_thres: float = 1.5
    "Length of the ray-traced tail in seconds."
    max_rays: int = 10000
    "Cap on the number of rays (pyroomacoustics picks a number from the room volume)."
    receiver_radius: float = 0.5
    "Radius of the ray-tracing receiver sphere in metres."
    hist_bin_size: float = 0.004
    "Ray-tracing energy histogram bin in seconds."
    sample_rate: int = SAMPLE_RATE
    "Output sample rate in Hz."
    seed: int = 0
    "Base seed of the simulator's random generator (mixed with the pose)."
    hrtf_equalised: bool = True
    "Diffuse-field equalise the KEMAR head, as binaural renderers do; False keeps the dummy head's own ear and pinna colouration, as a binaural recording has it."

    @classmethod
    def quick(cls) -> "SimSettings":
        """Cheap settings for tests and smoke runs: low-order image sources, no ray tracing
        (the reverberation time is then far too short: use the defaults for physics)."""
        return cls(max_order=4, max_order_polygon=2, ray_tracing=False)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "SimSettings":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown simulation settings {sorted(unknown)}; expected some of {sorted(known)}")
        return cls(**d)


# -- the head --------------------------------------------------------------------------

_HEAD: dict[int, tuple] = {}
_HEAD_LOCK = threading.Lock()


def ear_directivities(sample_rate: int = SAMPLE_RATE, equalised: bool = True) -> tuple:
    """The (left, right) KEMAR ``MeasuredDirectivity`` facing +x, built once per process
    (diffuse-field equalised unless ``equalised=False``)."""
    key = (int(sample_rate), bool(equalised))
    with _HEAD_LOCK:
        if key not in _HEAD:
            from pyroomacoustics.directivities import MeasuredDirectivityFile, Rotation3D

            from avgs.synth.hrtf import pra_file_reader

            reader = pra_file_reader(sample_rate, equalised)
            hrtf = MeasuredDirectivityFile("mit_kemar_normal_pinna", fs=sample_rate, file_reader_callback=reader)
            facing = Rotation3D([0.0], "z", degrees=True)
            _HEAD[key] = (hrtf.get_mic_directivity("left", facing), hrtf.get_mic_directivity("right", facing))
        return _HEAD[key]


def _turned(directivity, yaw_deg: float):
    from pyroomacoustics.directivities import Rotation3D

    d = copy.copy(directivity)
    d.set_orientation(Rotation3D([float(yaw_deg)], "z", degrees=True))
    return d


# -- the room --------------------------------------------------------------------------


def build_room(spec: SceneSpec, settings: SimSettings):
    """A pyroomacoustics room for ``spec`` without source or microphones (ray tracing off:
    it is switched on after the directive microphones are added)."""
    import pyroomacoustics as pra

    fs = settings.sample_rate
    if spec.is_shoebox:
        w, d = np.max(np.asarray(spec.footprint, dtype=np.float64), axis=0)
        south, east, north, west = spec.wall_materials
        materials = {
            "south": pra_material(south),
            "east": pra_material(east),
            "north": pra_material(north),
            "west": pra_material(west),
            "floor": pra_material(spec.floors[0].material),
            "ceiling": pra_material(spec.ceilings[0].material),
        }
        return pra.ShoeBox(
            [float(w), float(d), float(spec.height)],
            fs=fs,
            materials=materials,
            max_order=settings.max_order,
            air_absorption=settings.air_absorption,
        )
    from pyroomacoustics.acoustics import AntoniOctaveFilterBank
    from pyroomacoustics.parameters import constants
    from pyroomacoustics.room import wall_factory

    bands = AntoniOctaveFilterBank(
        fs=fs, n_fft=constants.get("octave_bands_n_fft"), base_frequency=constants.get("octave_bands_base_freq")
    )
    walls = []
    for s in spec.surfaces():
        mat = pra_material(s.material)
        mat.resample(bands)
        walls.append(wall_factory(np.ascontiguousarray(s.corners.T), mat.absorption_coeffs, mat.scattering_coeffs, s.name))
    return pra.Room(walls, fs=fs, max_order=settings.max_order_polygon, air_absorption=settings.air_absorption)


def _pose_seed(spec: SceneSpec, listener: np.ndarray, yaw_deg: float, settings: SimSettings) -> int:
    key = [int(settings.seed) & 0xFFFFFFFF, int(spec.seed) & 0xFFFFFFFF]
    key += [int(round(v * 1e4)) & 0xFFFFFFFF for v in (*listener, yaw_deg)]
    return int(np.random.SeedSequence(key).generate_state(1, np.uint64)[0])


def binaural_rirs(spec: SceneSpec, listener: np.ndarray, yaw_deg: float, settings: SimSettings) -> np.ndarray:
    """Binaural room impulse response ``[2, L]`` float32 at ``settings.sample_rate``
    (channel 0 = left ear) from ``spec``'s source to a KEMAR head at ``listener`` ([3],
    world metres) facing ``yaw_deg`` (degrees ccw from +x, level head)."""
    import pyroomacoustics as pra

    listener = np.asarray(listener, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(listener)) or not math.isfinite(float(yaw_deg)):
        raise ValueError(f"listener {listener.tolist()} and yaw {yaw_deg} must be finite")
    pra.random.seed(_pose_seed(spec, listener, float(yaw_deg), settings))
    room = build_room(spec, settings)
    if not room.is_inside(np.asarray(spec.source, dtype=np.float64)):
        raise ValueError(f"{spec.preset}: source {spec.source} is outside the room")
    if not room.is_inside(listener):
        raise ValueError(f"{spec.preset}: listener {listener.tolist()} is outside the room (or inside furniture)")
    room.add_source(np.asarray(spec.source, dtype=np.float64))
    left, right = ear_directivities(settings.sample_rate, settings.hrtf_equalised)
    mics = np.stack([listener, listener], axis=1)  # [3, 2] both ears at the head centre
    room.add_microphone_array(
        pra.MicrophoneArray(mics, settings.sample_rate, directivity=[_turned(left, yaw_deg), _turned(right, yaw_deg)])
    )
    _enable_ray_tracing(room, settings)
    compute_rir(room)
    ears = [np.asarray(room.rir[m][0], dtype=np.float64) for m in (0, 1)]
    out = np.zeros((2, max(len(e) for e in ears)), dtype=np.float32)
    for m, e in enumerate(ears):
        out[m, : len(e)] = e
    return out


def compute_rir(room) -> None:
    """``room.compute_rir()`` without pyroomacoustics' phantom direct sound (0.10.1, rooms from polygons).

    Where no image source up to the room's order reaches the microphones (a listener behind a wall
    whom no path of up to that many reflections reaches through a door), pyroomacoustics marks "the
    direct path not visible" with an integer array ``[[0]]``, which its ``compute_ism_rir`` then uses as an index, not a mask: image 0,
    the source itself, is rendered at full level at distance / c, through every wall between. Here
    those images are given zero amplitude instead, so such a response holds only what the ray tracing
    brings (the sound that finds its way around). Upstream: LCAV/pyroomacoustics#441 (the same case)."""
    room.image_source_model()
    for source, unreached in zip(room.sources, unreached_sources(room)):
        if unreached:
            source.damping = np.zeros_like(source.damping)
    room.compute_rir()


def unreached_sources(room) -> list[bool]:
    """After ``room.image_source_model()``: per source, whether no image source reaches the microphones
    (pyroomacoustics' "nothing visible" stand-in, an integer ``[[0]]``, not a boolean mask: :func:`compute_rir`)."""
    return [np.asarray(v).dtype != np.bool_ and not np.asarray(v).any() for v in room.visibility]


def _enable_ray_tracing(room, settings: SimSettings) -> None:
    if settings.ray_tracing:
        k1 = room.get_volume() / (math.pi * settings.receiver_radius**2 * room.c * settings.hist_bin_size)
        n_rays = int(min(settings.max_rays, max(500, 20 * k1)))  # pyroomacoustics' own rule, capped
        room.set_ray_tracing(
            n_rays=n_rays,
            receiver_radius=settings.receiver_radius,
            time_thres=settings.time_thres,
            hist_bin_size=settings.hist_bin_size,
        )


def emission_delay(settings: SimSettings) -> int:
    """Samples between emission and time 0 of a :func:`binaural_rirs` response's frame: half
    pyroomacoustics' fractional-delay filter (``frac_delay_length // 2``) plus the KEMAR
    head's own delay (the peak of its frontal response, both ears summed). A response
    shifted left by this many samples has the direct sound of a source straight ahead at
    ``distance / c`` (the ears of a lateral source lead or lag by the interaural delay)."""
    from pyroomacoustics.parameters import constants

    from avgs.synth.hrtf import frontal_delay

    return int(constants.get("frac_delay_length")) // 2 + frontal_delay(settings.sample_rate, settings.hrtf_equalised)


def speed_of_sound() -> float:
    """pyroomacoustics' speed of sound in m/s (what its rooms use)."""
    from pyroomacoustics.parameters import constants

    return float(constants.get("c"))


def receiver_rirs(spec: SceneSpec, sources, listener, yaws_deg, settings: SimSettings) -> np.ndarray:
    """Binaural responses ``[S, O, 2, n]`` float32 (channel 0 = left ear) from every source
    ``sources [S, 3]`` to a KEMAR head at ``listener [3]`` facing each of ``yaws_deg [O]``,
    world metres: one room holding all sources and the O x 2 ears as microphones.

    Same time frame and scale as :func:`binaural_rirs` (each response starts
    :func:`emission_delay` samples before emission; no normalisation); with image sources
    only (no ray tracing) each response equals ``binaural_rirs`` of that source and yaw. A
    pure function of its arguments: the simulator's random generator is seeded from the
    listener (not the yaws or the sources), so the result does not depend on the process
    or the order of calls."""
    import pyroomacoustics as pra

    listener = np.asarray(listener, dtype=np.float64).reshape(3)
    sources = np.asarray(sources, dtype=np.float64).reshape(-1, 3)
    yaws = [float(y) for y in yaws_deg]
    if not (np.all(np.isfinite(listener)) and np.all(np.isfinite(sources)) and all(math.isfinite(y) for y in yaws)):
        raise ValueError("listener, sources and yaws must be finite")
    if not len(sources) or not yaws:
        raise ValueError(f"need at least one source and one yaw, got {len(sources)} and {len(yaws)}")
    pra.random.seed(_pose_seed(spec, listener, 0.0, settings))
    room = build_room(spec, settings)
    if not room.is_inside(listener):
        raise ValueError(f"{spec.preset}: listener {listener.tolist()} is outside the room (or inside furniture)")
    for s in sources:
        if not room.is_inside(s):
            raise ValueError(f"{spec.preset}: source {s.tolist()} is outside the room (or inside furniture)")
        room.add_source(s)
    left, right = ear_directivities(settings.sample_rate, settings.hrtf_equalised)
    directivity = [_turned(ear, y) for y in yaws for ear in (left, right)]  # mic 2 o + e: yaw o, ear e
    mics = np.repeat(listener[:, None], len(directivity), axis=1)  # [3, 2 O] every ear at the head centre
    room.add_microphone_array(pra.MicrophoneArray(mics, settings.sample_rate, directivity=directivity))
    _enable_ray_tracing(room, settings)
    compute_rir(room)
    n = max(len(room.rir[m][s]) for m in range(len(directivity)) for s in range(len(sources)))
    out = np.zeros((len(sources), len(yaws), 2, n), dtype=np.float32)
    for m in range(len(directivity)):
        for s in range(len(sources)):
            h = np.asarray(room.rir[m][s])
            out[s, m // 2, m % 2, : len(h)] = h
    return out


# -- reverberation time ----------------------------------------------------------------


def rt60(rir: np.ndarray, sample_rate: int = SAMPLE_RATE, band_hz: float | None = None) -> float:
    """T30-extrapolated RT60 in seconds of a mono impulse response ``[L]``, broadband or in
    the octave band centred on ``band_hz`` (``pra.experimental.measure_rt60``, decay 30 dB).
    NaN when the response is silent or never decays by 5 dB."""
    import pyroomacoustics as pra
    from scipy.signal import butter, sosfiltfilt

    h = np.asarray(rir, dtype=np.float64)
    if band_hz is not None:
        lo, hi = band_hz / math.sqrt(2), min(band_hz * math.sqrt(2), 0.95 * sample_rate / 2)
        h = sosfiltfilt(butter(4, [lo, hi], btype="bandpass", fs=sample_rate, output="sos"), h)
    if not np.any(h):
        return float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        value = float(pra.experimental.measure_rt60(h, fs=sample_rate, decay_db=30))
    return value if value > 0 and math.isfinite(value) else float("nan")


def rt60_summary(rirs: list[np.ndarray], sample_rate: int = SAMPLE_RATE, ray_tracing: bool = True) -> dict:
    """Median RT60 over poses and both ears: broadband and per octave band, seconds.

    ``rirs``: binaural responses, each ``[2, L]``. ``ray_tracing=False`` adds a note that
    the responses hold image sources only, whose truncated tail makes the RT60 too short."""

    def median(values):
        v = np.asarray([x for x in values if math.isfinite(x)])
        return round(float(np.median(v)), 4) if len(v) else None

    broadband = [rt60(ear, sample_rate) for r in rirs for ear in r]
    bands = {str(b): median(rt60(ear, sample_rate, b) for r in rirs for ear in r) for b in RT60_BANDS_HZ}
    out = {
        "broadband_s": median(broadband),
        "bands_s": bands,
        "method": "pyroomacoustics.experimental.measure_rt60(decay_db=30) on the binaural RIRs; "
        "median over poses and ears; octave bands by 4th-order Butterworth band-pass",
        "poses": len(rirs),
    }
    if not ray_tracing:
        out["note"] = "image sources only (no ray-traced tail): far shorter than the room's real RT60"
    return out


# -- scenes on disk --------------------------------------------------------------------


def _read_scene_json(scene_dir) -> tuple[Path, dict]:
    path = Path(scene_dir) / "scene.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing; expected the scene.json written by `avgs synth`")
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("spec"), dict):
        raise ValueError(f"{path}: no 'spec' object; expected a scene written by `avgs synth`")
    return path, meta


def load_spec(scene_dir) -> SceneSpec:
    """Rebuild the :class:`SceneSpec` of a scene written by ``avgs synth`` (world metres)."""
    path, meta = _read_scene_json(scene_dir)
    try:
        return SceneSpec.from_dict(meta["spec"])
    except ValueError as exc:
        raise ValueError(f"{path}: bad 'spec' ({exc})") from None


def load_settings(scene_dir) -> SimSettings:
    """The :class:`SimSettings` a written scene was simulated with."""
    path, meta = _read_scene_json(scene_dir)
    try:
        return SimSettings.from_dict(meta.get("simulation", {}))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: bad 'simulation' ({exc})") from None
