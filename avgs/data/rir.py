"""Reader of an impulse-response scene (``avgs synth --task rir``; docs/rir-layout.md).

Layout::

    DATA_ROOT/<scene>/...                          an RWAVS scene for source 0 (frames, poses, scene.json)
    DATA_ROOT/<scene>/rir/index.json               {"format": "avgs-rir/1", "sample_rate", "orientations_deg",
                                                    "sources": [[x, y, z]], "receivers": [[x, y, z]] (normalised),
                                                    "splits": {"train" | "val" | "heldout": [[s, r], ...]}}
    DATA_ROOT/<scene>/rir/s{S:03d}_r{R:04d}_y{Y:03d}.wav   2 channels (0 = left ear), float32, all of length L

The reader only reads and never unpickles. Everything is validated, and an invalid scene is
refused with a ValueError (a FileNotFoundError for a missing file) naming the file and the
field: index.json is read strictly (:func:`avgs.data.files.read_json`); ``format`` is
:data:`FORMAT`; ``sample_rate`` the one the model expects; orientations distinct whole
degrees in [0, 360); positions finite, within :data:`avgs.data.rwavs.MAX_COORDINATE`;
every pair two integer indices in range, listed once over all splits; ``train`` not empty;
no held-out pair's source in any train or val pair, and source 0 (the RWAVS part's) never
held out. scene.json's ``rir`` section, when there is one, must agree with the index: its
``length_samples``, ``counts`` per split, ``heldout_sources`` and the world positions
``sources_world`` / ``receivers_world`` (through the scene's frame). When the scene is opened
every listed file must be present: a WAV of 32-bit float samples at the sample rate, 2
channels, whole STFT hops (:data:`HOP`), at most :data:`MAX_RESPONSE_SECONDS`, and all of one
length, scene.json's ``rir.length_samples`` when it gives one; no response file in ``rir/``
may be left unlisted. Samples are checked
(finite, within :data:`avgs.data.rwavs.MAX_SAMPLE_MAGNITUDE`) when they are read.

:meth:`RIRScene.responses` reads a whole split (cached); :meth:`RIRScene.index` gives a
split's positions without reading a file and :meth:`RIRScene.read` the responses of a few of
its rows, so that training holds only a batch of responses at a time.

The world <-> normalised frame is found as the binaural loader finds it: scene.json's
``to_normalised``, else a fit of ``transforms_{split}.json`` to ``transforms_scale_{split}.json``,
else the identity.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf

from avgs.config import STFT
from avgs.data.files import describe_json, file_present, is_regular_file, json_vector, read_json, require_file
from avgs.data.frame import SceneFrame
from avgs.data.rwavs import (
    METADATA_FILE,
    POSE_TOLERANCE,
    SPLITS as POSE_SPLITS,
    check_coordinates,
    read_camera_path,
    read_scene_metadata,
    read_wav,
    scene_frame_from_json,
    transforms_path,
)

FORMAT = "avgs-rir/1"
RIR_DIR = "rir"
INDEX_FILE = "index.json"
METADATA_SECTION = "rir"
"scene.json's section about the responses (their length, positions in metres, held-out sources)."
SPLITS = ("train", "val", "heldout")
ENVIRONMENTS = ("rectangular", "non-rectangular", "multi-room")
MAX_RESPONSE_SECONDS = 1.5
"Longest response accepted (docs/rir-layout.md; the generator caps its lengths there)."
HOP = STFT.hop_length
"Every response is a whole number of STFT hops (128 samples)."
WAV_FORMATS = ("WAV", "WAVEX")
"Containers a response may be in (libsndfile's names); the samples are 32-bit float (``FLOAT``)."


def max_response_samples(sample_rate: int) -> int:
    """The longest response of whole hops within :data:`MAX_RESPONSE_SECONDS` (33024 at 22050 Hz)."""
    return int(MAX_RESPONSE_SECONDS * sample_rate) // HOP * HOP


RESPONSE_NAME = re.compile(r"s\d{3,}_r\d{4,}_y\d{3,}\.wav")
"A response's file name (:func:`rir_file_name`)."


def rir_file_name(source: int, receiver: int, yaw_deg: int) -> str:
    """``s{S:03d}_r{R:04d}_y{Y:03d}.wav``: the response of source ``S`` to receiver ``R`` facing ``Y`` degrees."""
    return f"s{int(source):03d}_r{int(receiver):04d}_y{int(yaw_deg):03d}.wav"


def is_rir_scene(path) -> bool:
    """True for a folder holding ``rir/index.json``."""
    return is_regular_file(Path(path) / RIR_DIR / INDEX_FILE)


@dataclass(frozen=True)
class RIRIndex:
    """The rows of one split without their responses: pair by pair (index.json's order), each pair's orientations in order."""

    source: np.ndarray  # [N, 3] float64, normalised
    receiver: np.ndarray  # [N, 3] float64, normalised
    yaw: np.ndarray  # [N] float64, degrees counter-clockwise from +x
    source_index: np.ndarray  # [N] int64
    receiver_index: np.ndarray  # [N] int64

    def __len__(self) -> int:
        return int(self.source.shape[0])


@dataclass(frozen=True)
class RIRSet:
    """The responses of one split: pair by pair (index.json's order), each pair's orientations in index order."""

    rir: np.ndarray  # [N, 2, L] float32, channel 0 = left ear
    source: np.ndarray  # [N, 3] float64, normalised
    receiver: np.ndarray  # [N, 3] float64, normalised
    yaw: np.ndarray  # [N] float64, degrees counter-clockwise from +x
    source_index: np.ndarray  # [N] int64
    receiver_index: np.ndarray  # [N] int64

    def __len__(self) -> int:
        return int(self.rir.shape[0])


def _integer(value, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where} must be an integer, got {describe_json(value)}")
    return value


class RIRScene:
    """One impulse-response scene folder; positions in the normalised frame.

    Attributes: ``scene_dir``, ``name``, ``sample_rate``, ``length`` (samples per response),
    ``frame`` (:class:`SceneFrame`), ``sources [S, 3]``, ``receivers [R, 3]`` (normalised),
    ``orientations [O]`` (degrees), ``environment`` (scene.json's when one of
    :data:`ENVIRONMENTS`, else "unknown"), ``metadata`` (scene.json or None), ``pairs``
    (``{split: [N, 2] int64}``).
    """

    def __init__(self, scene_dir, sample_rate: int = STFT.sample_rate):
        try:
            self.scene_dir = Path(scene_dir).resolve()
        except (OSError, RuntimeError, ValueError) as exc:
            raise ValueError(f"{str(scene_dir)[:200]}: cannot resolve the scene folder ({exc})") from None
        if not self.scene_dir.is_dir():
            raise FileNotFoundError(f"{self.scene_dir}: scene folder missing")
        self.name = self.scene_dir.name
        self.index_path = self.scene_dir / RIR_DIR / INDEX_FILE
        index = read_json(self.index_path, f"the impulse-response index ({FORMAT})")
        if not isinstance(index, dict):
            raise ValueError(f"{self.index_path}: expected a JSON object, got {describe_json(index)}")
        for key in ("format", "sample_rate", "orientations_deg", "sources", "receivers", "splits"):
            if key not in index:
                raise ValueError(f"{self.index_path}: '{key}' missing")
        if index["format"] != FORMAT:
            raise ValueError(f"{self.index_path}: format must be {FORMAT!r}, got {describe_json(index['format'])}")
        rate = _integer(index["sample_rate"], f"{self.index_path}: sample_rate")
        if rate != sample_rate:
            raise ValueError(f"{self.index_path}: sample_rate {rate} Hz, expected {sample_rate} Hz")
        self.sample_rate = rate
        self.orientations = self._read_orientations(index["orientations_deg"])
        self.sources = self._read_points(index["sources"], "sources")
        self.receivers = self._read_points(index["receivers"], "receivers")
        self.pairs = self._read_splits(index["splits"])
        self.metadata = read_scene_metadata(self.scene_dir)
        self.frame = self._read_frame()
        env = (self.metadata or {}).get("environment")
        self.environment = env if env in ENVIRONMENTS else "unknown"
        self.length = self._check_files(self._check_metadata())
        self._cache: dict[str, RIRSet] = {}

    def __repr__(self) -> str:
        counts = ", ".join(f"{len(self.pairs[k])} {k}" for k in SPLITS)
        return f"RIRScene({self.name!r}: {len(self.sources)} sources x {len(self.receivers)} receivers, pairs {counts}; {len(self.orientations)} orientations, {self.length} samples)"

    # -- reading index.json ----------------------------------------------------------------

    def _read_orientations(self, value) -> np.ndarray:
        where = f"{self.index_path}: orientations_deg"
        if not isinstance(value, list) or not value:
            raise ValueError(f"{where} must be a non-empty list of whole degrees, got {describe_json(value)}")
        out = [_integer(v, f"{where}[{i}]") for i, v in enumerate(value)]
        for i, v in enumerate(out):
            if not 0 <= v < 360:
                raise ValueError(f"{where}[{i}] is {v}; expected whole degrees in [0, 360)")
        if len(set(out)) != len(out):
            raise ValueError(f"{where} lists an orientation twice ({out})")
        return np.array(out, dtype=np.float64)

    def _read_points(self, value, key: str) -> np.ndarray:
        where = f"{self.index_path}: {key}"
        if not isinstance(value, list) or not value:
            raise ValueError(f"{where} must be a non-empty list of [x, y, z], got {describe_json(value)}")
        pts = np.stack([json_vector(p, 3, f"{where}[{i}]") for i, p in enumerate(value)])  # [K, 3]
        check_coordinates(pts, where)
        return pts

    def _read_splits(self, value) -> dict[str, np.ndarray]:
        where = f"{self.index_path}: splits"
        if not isinstance(value, dict):
            raise ValueError(f"{where} must be an object {{'train', 'val', 'heldout'}}, got {describe_json(value)}")
        unknown = sorted(set(value) - set(SPLITS))
        if unknown:
            raise ValueError(f"{where} has unknown split(s) {unknown}; expected {list(SPLITS)}")
        seen: dict[tuple[int, int], str] = {}
        out = {}
        for split in SPLITS:
            if split not in value:
                raise ValueError(f"{where}.{split} missing; expected a list of [source, receiver] pairs")
            listed = value[split]
            if not isinstance(listed, list):
                raise ValueError(f"{where}.{split} must be a list of [source, receiver] pairs, got {describe_json(listed)}")
            pairs = []
            for i, p in enumerate(listed):
                w = f"{where}.{split}[{i}]"
                if not isinstance(p, list) or len(p) != 2:
                    raise ValueError(f"{w} must be a [source, receiver] pair, got {describe_json(p)}")
                s, r = _integer(p[0], f"{w}[0]"), _integer(p[1], f"{w}[1]")
                if not 0 <= s < len(self.sources):
                    raise ValueError(f"{w}: source index {s} out of range (0..{len(self.sources) - 1})")
                if not 0 <= r < len(self.receivers):
                    raise ValueError(f"{w}: receiver index {r} out of range (0..{len(self.receivers) - 1})")
                if (s, r) in seen:
                    raise ValueError(f"{w}: pair [{s}, {r}] is listed again (already in {seen[(s, r)]}); the splits must be disjoint")
                seen[(s, r)] = split
                pairs.append((s, r))
            out[split] = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        if not len(out["train"]):
            raise ValueError(f"{where}.train is empty; expected at least one training pair")
        if 0 in out["heldout"][:, 0]:
            raise ValueError(f"{where}.heldout holds source 0, the RWAVS part's source; expected held-out sources other than 0")
        trained = set(out["train"][:, 0].tolist()) | set(out["val"][:, 0].tolist())
        leaked = sorted(set(out["heldout"][:, 0].tolist()) & trained)
        if leaked:
            raise ValueError(
                f"{where}.heldout: source {leaked[0]} also appears in a train or val pair"
                + (f" (as do {len(leaked) - 1} more)" if len(leaked) > 1 else "")
                + "; held-out sources must be in no training pair"
            )
        return out

    # -- the frame, as the binaural loader finds it ----------------------------------------------

    def _read_frame(self) -> SceneFrame:
        meta = self.metadata
        if meta is not None and "to_normalised" in meta:
            try:
                return scene_frame_from_json(meta["to_normalised"])
            except ValueError as exc:
                raise ValueError(f"{self.scene_dir / METADATA_FILE}: bad 'to_normalised' ({exc})") from None
        world, normalised = [], []
        for split in POSE_SPLITS:
            paths = [transforms_path(self.scene_dir, split, scaled) for scaled in (False, True)]
            if not all(file_present(p, f"the {split} camera poses") for p in paths):
                continue
            unscaled = {e.frame_number: e.c2w for e in read_camera_path(paths[0])}
            for e in read_camera_path(paths[1]):
                if e.frame_number in unscaled:
                    world.append(unscaled[e.frame_number][:3, 3])
                    normalised.append(e.c2w[:3, 3])
        if not world:
            return SceneFrame.identity()
        try:
            frame, _ = SceneFrame.fit(np.array(world), np.array(normalised))
        except ValueError as exc:
            raise ValueError(f"{self.scene_dir}: cannot relate transforms_*.json to transforms_scale_*.json: {exc}") from None
        off = float(np.max(np.linalg.norm(frame.to_normalised(np.array(world)) - np.array(normalised), axis=-1)))
        tol = POSE_TOLERANCE * max(1.0, float(np.max(np.abs(normalised))))
        if off > tol:
            raise ValueError(
                f"{self.scene_dir}: transforms_scale_*.json is no uniformly scaled and shifted copy of transforms_*.json "
                f"(a pose {off:.3g} normalised units off the best fit, tolerance {tol:.3g})"
            )
        return frame

    # -- the responses --------------------------------------------------------------------------

    def _entries(self, split: str) -> list[tuple[int, int, int]]:
        return [(int(s), int(r), int(y)) for s, r in self.pairs[split] for y in self.orientations]

    def _path(self, s: int, r: int, y: int) -> Path:
        return self.scene_dir / RIR_DIR / rir_file_name(s, r, y)

    def _check_metadata(self) -> int | None:
        """scene.json's ``rir`` section against the index (when there is one); its ``length_samples`` or None."""
        meta = self.metadata
        if meta is None or METADATA_SECTION not in meta:
            return None
        where = f"{self.scene_dir / METADATA_FILE}: rir"
        rir = meta[METADATA_SECTION]
        if not isinstance(rir, dict):
            raise ValueError(f"{where} must be an object, got {describe_json(rir)}")
        length = None
        if "length_samples" in rir:
            length = _integer(rir["length_samples"], f"{where}.length_samples")
            top = max_response_samples(self.sample_rate)
            if not 0 < length <= top or length % HOP:
                raise ValueError(f"{where}.length_samples is {length}; expected whole {HOP}-sample hops, {HOP} .. {top} "
                                 f"(at most {MAX_RESPONSE_SECONDS} s)")
        if "counts" in rir:
            counts = rir["counts"]
            for split in SPLITS:
                n = counts.get(split) if isinstance(counts, dict) else None
                if n is None or isinstance(n, bool) or n != len(self.pairs[split]):
                    raise ValueError(f"{where}.counts.{split} is {describe_json(n)}; {INDEX_FILE} lists {len(self.pairs[split])} {split} pairs")
        if "heldout_sources" in rir:
            held = sorted(set(self.pairs["heldout"][:, 0].tolist()))
            given = rir["heldout_sources"]
            ok = isinstance(given, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in given)
            if not ok or sorted(given) != held:
                raise ValueError(f"{where}.heldout_sources is {describe_json(given) if not ok else given}; {INDEX_FILE}'s held-out pairs have sources {held}")
        for key, points in (("sources_world", self.sources), ("receivers_world", self.receivers)):
            if key not in rir:
                continue
            listed = rir[key]
            if not isinstance(listed, list) or len(listed) != len(points):
                raise ValueError(f"{where}.{key} must list {len(points)} [x, y, z] like {INDEX_FILE}, got {describe_json(listed)}")
            world = np.stack([json_vector(p, 3, f"{where}.{key}[{i}]") for i, p in enumerate(listed)])  # [K, 3]
            check_coordinates(world, f"{where}.{key}")
            off = np.linalg.norm(self.frame.to_normalised(world) - points, axis=-1)  # [K]
            tol = POSE_TOLERANCE * max(1.0, float(np.max(np.abs(points))))
            if float(off.max()) > tol:
                i = int(off.argmax())
                raise ValueError(f"{where}.{key}[{i}] is {float(off[i]):.3g} normalised units from {INDEX_FILE}'s "
                                 f"(tolerance {tol:.3g}); the two files must give the same positions")
        return length

    def _check_files(self, expected: int | None) -> int:
        """Every listed file present: a 32-bit float WAV at the sample rate, 2 channels, whole hops,
        within the cap, all of one length (``expected``: scene.json's, when it gives one); returns it."""
        length, first = expected, None
        top = max_response_samples(self.sample_rate)
        listed = set()
        for split in SPLITS:
            for s, r, y in self._entries(split):
                path = self._path(s, r, y)
                listed.add(path.name)
                require_file(path, f"the response of source {s} to receiver {r} at yaw {y} (a 2-channel {self.sample_rate} Hz WAV)")
                try:
                    info = sf.info(str(path))
                except Exception as exc:  # libsndfile's errors, and whatever a malformed header provokes
                    raise ValueError(f"{path}: not a readable audio file ({type(exc).__name__}: {str(exc)[:200]})") from None
                if info.format not in WAV_FORMATS or info.subtype != "FLOAT":
                    raise ValueError(f"{path}: {info.format} of {info.subtype} samples, expected a WAV of 32-bit float samples (FLOAT)")
                if info.samplerate != self.sample_rate:
                    raise ValueError(f"{path}: sample rate {info.samplerate} Hz, expected {self.sample_rate} Hz ({INDEX_FILE}'s sample_rate)")
                if info.channels != 2:
                    raise ValueError(f"{path}: {info.channels} channel(s), expected 2 (left, right)")
                if not 0 < info.frames <= top or info.frames % HOP:
                    raise ValueError(f"{path}: {info.frames} samples; expected whole {HOP}-sample hops, {HOP} .. {top} (at most {MAX_RESPONSE_SECONDS} s)")
                if length is None:
                    length, first = info.frames, path.name
                elif info.frames != length:
                    like = first if first is not None else f"{METADATA_FILE}'s rir.length_samples"
                    raise ValueError(f"{path}: {info.frames} samples, expected {length} (as {like}); every response of a scene has the same length")
        try:
            names = sorted(e.name for e in os.scandir(self.scene_dir / RIR_DIR) if RESPONSE_NAME.fullmatch(e.name))
        except OSError as exc:
            raise ValueError(f"{self.scene_dir / RIR_DIR}: cannot be listed ({exc.strerror or exc})") from None
        unlisted = [n for n in names if n not in listed]
        if unlisted:
            raise ValueError(f"{self.scene_dir / RIR_DIR / unlisted[0]}: a response that {INDEX_FILE} does not list"
                             + (f" (and {len(unlisted) - 1} more)" if len(unlisted) > 1 else "")
                             + "; expected one file per listed pair and orientation (an orientation or a pair missing from the index?)")
        return int(length)

    def index(self, split: str) -> RIRIndex:
        """The positions of ``split``'s rows, without reading a response."""
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        idx = np.array(self._entries(split), dtype=np.int64).reshape(-1, 3)  # [N, 3] source, receiver, yaw
        return RIRIndex(source=self.sources[idx[:, 0]], receiver=self.receivers[idx[:, 1]], yaw=idx[:, 2].astype(np.float64),
                        source_index=idx[:, 0].copy(), receiver_index=idx[:, 1].copy())

    def read(self, split: str, rows) -> np.ndarray:
        """The responses [len(rows), 2, L] float32 of ``split``'s ``rows`` (indices of :meth:`index`), read now."""
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        entries = self._entries(split)
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        out = np.empty((len(rows), 2, self.length), dtype=np.float32)  # [B, 2, L]
        for i, row in enumerate(rows):
            s, r, y = entries[int(row)]
            path = self._path(s, r, y)
            audio = read_wav(path, 2, self.sample_rate)  # [2, T], finite, within the magnitude limit
            if audio.shape[-1] != self.length:
                raise ValueError(f"{path}: {audio.shape[-1]} samples, expected {self.length} like every response of the scene")
            out[i] = audio
        return out

    def responses(self, split: str) -> RIRSet:
        """The responses of ``split`` ("train", "val" or "heldout"), read once and cached."""
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        if split not in self._cache:
            rows = self.index(split)
            self._cache[split] = RIRSet(rir=self.read(split, np.arange(len(rows))), source=rows.source, receiver=rows.receiver,
                                        yaw=rows.yaw, source_index=rows.source_index, receiver_index=rows.receiver_index)
        return self._cache[split]
