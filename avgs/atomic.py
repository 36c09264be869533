"""Atomic file writes: nothing half-written is ever left at the destination.

Every file ``avgs`` and ``avgs-viewer`` write (checkpoints, logs, plots, WAVs, JSON,
screenshots) goes through :func:`atomic_path`: the content is written to a temporary
file in the destination's folder and moved onto the destination with ``os.replace``
only when the writer finished. The file gets the permissions a plain ``open`` would
give it (0666 less the umask), not ``mkstemp``'s private 0600.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | Path, make_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so writers that look at it pick the
    right format); it replaces ``path`` when the block ends without an exception, else it is removed."""
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: folder {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    finally:
        tmp_path.unlink(missing_ok=True)


def write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_json(path: str | Path, data, indent: int = 2) -> Path:
    return write_text(path, json.dumps(data, indent=indent) + "\n")


def write_wav(path: str | Path, audio, sample_rate: int, make_parents: bool = True) -> Path:
    """``audio [C, T]`` as a C-channel 32-bit float WAV (channel 0 first)."""
    import numpy as np
    import soundfile as sf

    with atomic_path(path, make_parents=make_parents) as tmp:
        sf.write(str(tmp), np.asarray(audio, dtype=np.float32).T, int(sample_rate), subtype="FLOAT", format="WAV")
    return Path(path)


def torch_save(obj, path: str | Path) -> Path:
    """``torch.save`` to ``path`` atomically (flushed to disk before the rename)."""
    import torch

    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            torch.save(obj, f)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)
