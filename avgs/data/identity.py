"""A scene's identity: what a checkpoint must have been trained on to be scored on a scene or
resumed on it (``avgs eval``, ``avgs train --resume``), beyond the folder's name.

:func:`scene_identity` is ``"sha256:<hex>"`` over what sets the scene's coordinates and its
set of poses, each file parsed and written back canonically (sorted keys, no spaces: the same
scene reformatted keeps its identity):

- ``position.json``'s entry of the scene (the source, normalised; the data root's file, shared
  by its scenes, so only this scene's entry);
- ``transforms_{train,val}.json`` and ``transforms_scale_{train,val}.json`` (the poses and the
  split, plain and normalised: the map between world and normalised frame is fitted from them
  when scene.json has none);
- ``scene.json``'s ``to_normalised`` (the map, where the generator wrote it);
- ``rir/index.json`` of an impulse-response scene (docs/rir-layout.md: its sources, receivers,
  orientations, splits and sample rate).

Files a scene lacks are left out (a real RWAVS scene has no scene.json). Frames, audio,
materials and simulator settings are not part of it: they change what is heard, not where.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

from avgs.data.files import file_present, read_json

POSITION_FILE = "position.json"
POSE_FILES = ("transforms_train.json", "transforms_val.json", "transforms_scale_train.json", "transforms_scale_val.json")
METADATA_FILE = "scene.json"
RIR_INDEX = "rir/index.json"
PREFIX = "sha256:"


def _canonical(value) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def identity_parts(scene_dir: str | Path) -> dict[str, str]:
    """``{what: canonical JSON}``: the parts :func:`scene_identity` digests (module docstring)."""
    root = Path(scene_dir)
    parts: dict[str, str] = {}
    position = root.parent / POSITION_FILE
    if file_present(position, "position file"):
        entries = read_json(position, "position file")
        if isinstance(entries, dict) and root.name in entries:
            parts[f"{POSITION_FILE}[{root.name}]"] = _canonical(entries[root.name])
    for name in POSE_FILES:
        if file_present(root / name, "transforms file"):
            parts[name] = _canonical(read_json(root / name, "transforms file"))
    if file_present(root / METADATA_FILE, "scene metadata"):
        meta = read_json(root / METADATA_FILE, "scene metadata")
        if isinstance(meta, dict) and "to_normalised" in meta:
            parts[f"{METADATA_FILE}.to_normalised"] = _canonical(meta["to_normalised"])
    if file_present(root / RIR_INDEX, "impulse-response index"):
        parts[RIR_INDEX] = _canonical(read_json(root / RIR_INDEX, "impulse-response index"))
    return parts


def scene_identity(scene_dir: str | Path) -> str:
    """``"sha256:<64 hex>"`` of the scene folder's :func:`identity_parts`; ValueError naming a file
    that cannot be read (:func:`avgs.data.files.read_json`)."""
    h = hashlib.sha256()
    for key, text in sorted(identity_parts(scene_dir).items()):
        h.update(f"{len(key)}:{key}{len(text)}:{text}".encode())
    return PREFIX + h.hexdigest()


def short(identity: str) -> str:
    """An identity as messages print it: ``sha256:`` and its first 12 hex digits."""
    return identity[: len(PREFIX) + 12]


def check_scene_identity(stored: str | None, scene_dir: str | Path, checkpoint: str | Path, action: str = "score") -> bool:
    """Refuse (ValueError, one line naming both) a checkpoint whose stored identity is not that of
    ``scene_dir``; True when they match. A checkpoint without one (written before avgs stored it)
    gets a warning, and False: the caller goes on, matching by the folder's name alone."""
    if stored is None:
        warnings.warn(f"{checkpoint}: carries no scene identity (an older checkpoint); matched to {scene_dir} by "
                      "its folder name only", stacklevel=2)
        return False
    actual = scene_identity(scene_dir)
    if actual != stored:
        raise ValueError(
            f"{checkpoint}: trained on another scene than {scene_dir} (scene identity {short(stored)}, the folder's "
            f"{short(actual)}: its poses, source or normalisation differ); cannot {action} it there"
        )
    return True
