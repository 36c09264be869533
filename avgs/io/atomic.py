"""Safe file writes: nothing half-written is left at the destination, nothing a user
passed in is destroyed.

Every file ``avgs`` and ``avgs-viewer`` write (checkpoints, logs, plots, WAVs, JSON,
screenshots) goes through :func:`atomic_path`: the content is written to a temporary
file in the destination's folder and moved onto the destination with ``os.replace``
only when the writer finished. The file gets the permissions a plain ``open`` would
give it (0666 less the umask), not ``mkstemp``'s private 0600. The temporary file's name
carries the writer's process id; a later save to the same destination removes the
temporary files that writers no longer alive left behind (a save killed midway).

Outputs named by the user are checked first, before any work, by :func:`check_output`:
an output may not be one of the command's inputs (the same file after resolving links),
an existing folder, a name ending in a separator, anything that is not a regular file
(a device, FIFO or socket), or sit in a folder that does not exist. :func:`atomic_path`
refuses to replace anything but a regular file.

A write that fails (a full disk, a file size limit, an I/O error) is an ``OSError`` naming
the destination, whichever writer failed: libsndfile and torch's zip writer, which hide the
operating system's error behind their own, write through :class:`_GuardedFile`, which keeps
it. The temporary file is removed, and the destination is left as it was.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class OutputError(ValueError):
    """An output path that must not be written (names the path and why)."""


TEMP_MARK = ".avgs-tmp-"
"Part of every temporary file's name: ``.{name}.avgs-tmp-{pid}-{random}{suffix}``."


def check_output(path: str | Path, inputs=(), what: str = "output", exist_ok: bool = True) -> Path:
    """Refuse, before any work, an output that must not be written; returns it resolved.

    ``inputs``: the paths the command reads (files or folders). An output may not be one
    of them (after resolving links), nor an existing file inside an input folder (a scene's
    own files), nor an existing folder, nor a path ending in a separator, nor anything but a
    regular file (a device, FIFO or socket), and its folder must exist. ``exist_ok=False``
    also refuses an existing file.
    """
    text = os.fspath(path)
    if not text or text.endswith((os.sep, "/")):
        raise OutputError(f"{what} {text!r}: expected a file name, got a folder path")
    p = Path(text)
    try:
        resolved = p.resolve(strict=False)
    except (OSError, RuntimeError) as exc:  # a symlink loop
        raise OutputError(f"{what} {p}: cannot be resolved ({exc})") from None
    if resolved.exists() or p.is_symlink():
        try:
            mode = resolved.stat().st_mode
        except OSError as exc:
            raise OutputError(f"{what} {p}: cannot be checked ({exc.strerror or exc})") from None
        if stat.S_ISDIR(mode):
            raise OutputError(f"{what} {p}: is an existing folder; expected a file name")
        if not stat.S_ISREG(mode):
            raise OutputError(f"{what} {p}: is not a regular file (a device, FIFO or socket); refusing to replace it")
        if not exist_ok:
            raise OutputError(f"{what} {p}: exists already")
    if not resolved.parent.is_dir():
        raise OutputError(f"{what} {p}: folder {p.parent} does not exist")
    for given in inputs:
        if given is None:
            continue
        try:
            src = Path(given).resolve(strict=False)
        except (OSError, RuntimeError):
            continue
        if src == resolved:
            raise OutputError(f"{what} {p} is also an input of this command; write somewhere else")
        if src.is_dir() and resolved.exists() and src in resolved.parents:
            raise OutputError(f"{what} {p} would replace a file inside the input folder {given}; write somewhere else")
    return resolved


def _remove_stale_temporaries(path: Path) -> None:
    """Remove ``path``'s temporary files whose writers are no longer running."""
    try:
        candidates = list(path.parent.glob(f".{path.name}{TEMP_MARK}*"))
    except OSError:
        return
    for tmp in candidates:
        try:
            pid = int(tmp.name[len(f".{path.name}{TEMP_MARK}") :].split("-", 1)[0])
        except ValueError:
            continue
        if pid != os.getpid() and not _alive(pid):
            tmp.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


@contextmanager
def atomic_path(path: str | Path, make_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so writers that look at it pick the
    right format); it replaces ``path`` when the block ends without an exception, else it is removed.

    A destination that exists and is not a regular file is never replaced; a symbolic link
    is followed (its target is written). OS errors (read-only or full destination, no
    permission) come out as ``OSError`` naming the destination.
    """
    path = Path(path)
    if path.is_symlink():
        path = path.resolve()
    if path.exists() and not path.is_file():
        raise OutputError(f"{path}: is not a regular file; refusing to replace it")
    try:
        if make_parents:
            path.parent.mkdir(parents=True, exist_ok=True)
        elif not path.parent.is_dir():
            raise FileNotFoundError(f"cannot write {path}: folder {path.parent} does not exist")
        _remove_stale_temporaries(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TEMP_MARK}{os.getpid()}-", suffix=path.suffix or ".tmp",
                                   dir=path.parent)
        os.close(fd)
    except OSError as exc:
        if isinstance(exc, FileNotFoundError) and not exc.errno:
            raise
        raise OSError(exc.errno or errno.EIO, f"cannot write {path}: {exc.strerror or exc}") from None
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
            os.chmod(tmp_path, 0o666 & ~_umask())
            if path.exists() and not path.is_file():  # appeared while we were writing
                raise OutputError(f"{path}: is not a regular file; refusing to replace it")
            os.replace(tmp_path, path)
        except OSError as exc:
            if isinstance(exc, OutputError) or not exc.errno:
                raise
            raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        tmp_path.unlink(missing_ok=True)


def write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_json(path: str | Path, data, indent: int = 2) -> Path:
    return write_text(path, json.dumps(data, indent=indent) + "\n")


class _GuardedFile:
    """A binary file handed to a writer that does its own I/O (libsndfile, torch's zip writer):
    the first ``OSError`` of a write is kept and the writer is told nothing was written, so the
    real reason (ENOSPC, EFBIG, EIO) survives writers that report failures their own way
    (``LibsndfileError: System error``, ``RuntimeError: ... unexpected pos``). After the first
    failure nothing more is written. :meth:`check` raises the kept error."""

    def __init__(self, f):
        self._f = f
        self.error: OSError | None = None

    def _call(self, name: str, *args):
        if self.error is None:
            try:
                return getattr(self._f, name)(*args)
            except OSError as exc:  # a buffered file fails on write, seek, tell or flush
                self.error = exc
        return 0

    def write(self, data) -> int:
        return self._call("write", data)

    def seek(self, *args) -> int:
        return self._call("seek", *args)

    def tell(self) -> int:
        return self._call("tell")

    def flush(self) -> None:
        self._call("flush")

    def check(self) -> None:
        if self.error is not None:
            raise self.error

    def __getattr__(self, name):  # read, fileno, mode, ...: the file's own
        return getattr(self._f, name)


@contextmanager
def guarded_open(tmp: Path) -> Iterator[_GuardedFile]:
    """``tmp`` opened for binary writing as a :class:`_GuardedFile`; a failed write (kept by the
    guard) raises its ``OSError`` whatever exception the writer made of it, and so do flushing,
    syncing and closing; the data reach the disk (``fsync``) before the block ends."""
    with open(tmp, "wb") as f:
        guard = _GuardedFile(f)
        try:
            yield guard
        except Exception:
            guard.check()  # the writer's own exception hides an OS error: report that instead
            raise
        guard.check()
        f.flush()
        os.fsync(f.fileno())


AUDIO_FORMATS = {".wav": ("WAV", "FLOAT"), ".flac": ("FLAC", "PCM_24"), ".ogg": ("OGG", "VORBIS"),
                 ".mp3": ("MP3", "MPEG_LAYER_III")}
"Audio outputs by file name extension: (soundfile format, subtype). Only WAV holds samples beyond +-1."


def audio_format(path: str | Path, what: str = "output") -> tuple[str, str]:
    """``(format, subtype)`` that :func:`write_audio` writes ``path`` in, chosen by its extension;
    OutputError for an extension it cannot write as that format (before any work)."""
    suffix = Path(path).suffix.lower()
    known = AUDIO_FORMATS.get(suffix)
    if known is None:
        kind = f"{suffix!r} files" if suffix else "a name without an extension"
        raise OutputError(f"{what} {path}: audio is written as {', '.join(AUDIO_FORMATS)} (by the extension), not {kind}")
    import soundfile as sf

    if known[0] not in sf.available_formats():
        raise OutputError(f"{what} {path}: this libsndfile cannot write {known[0]}; name it .wav")
    return known


def write_audio(path: str | Path, audio, sample_rate: int, format: str = "WAV", subtype: str = "FLOAT",
                make_parents: bool = True) -> Path:
    """``audio [C, T]`` as a C-channel file of soundfile's ``format`` and ``subtype`` (channel 0 first)."""
    import numpy as np
    import soundfile as sf

    audio = np.asarray(audio, dtype=np.float32)  # [C, T]
    with atomic_path(path, make_parents=make_parents) as tmp, guarded_open(tmp) as out:
        with sf.SoundFile(out, "w", int(sample_rate), audio.shape[0], subtype=subtype, format=format) as f:
            for i in range(0, audio.shape[1], 1 << 18):  # in pieces: no interleaved copy of a long signal
                f.write(np.ascontiguousarray(audio[:, i : i + (1 << 18)].T))
                out.check()  # stop at the first failed write (a full disk), not at the end of a long clip
    return Path(path)


def write_wav(path: str | Path, audio, sample_rate: int, make_parents: bool = True) -> Path:
    """``audio [C, T]`` as a C-channel 32-bit float WAV (channel 0 first)."""
    return write_audio(path, audio, sample_rate, "WAV", "FLOAT", make_parents=make_parents)


def write_binaural_wav(path: str | Path, binaural, sample_rate: int, inputs=(), what: str = "binaural audio",
                       make_parents: bool = True) -> Path:
    """``binaural [2, T]`` (channel 0 = left) as a 2-channel 32-bit float WAV at ``path``, which must
    end in ``.wav`` and be none of ``inputs`` (:func:`check_output`); errors name ``what`` and the value."""
    import numpy as np

    binaural = np.asarray(binaural, dtype=np.float32)
    if binaural.ndim != 2 or binaural.shape[0] != 2:
        raise ValueError(f"{what} must be [2, T] (left, right), got shape {binaural.shape}")
    path = Path(path)
    if path.suffix.lower() != ".wav":
        raise ValueError(f"{what} must be written to a .wav file, got {path}")
    check_output(path, inputs=inputs, what=what)
    return write_wav(path, binaural, sample_rate, make_parents=make_parents)


def torch_save(obj, path: str | Path) -> Path:
    """``torch.save`` to ``path`` atomically (flushed to disk before the rename)."""
    import torch

    with atomic_path(path) as tmp, guarded_open(tmp) as out:
        torch.save(obj, out)
    return Path(path)
