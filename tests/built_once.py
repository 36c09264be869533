"""Fixtures built once for a whole pytest-xdist run, not once per worker."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """A folder ``build(folder)`` filled, made once for the whole run and copied to each worker.

    Under pytest-xdist every worker would otherwise build the session's fixtures anew (tens of
    seconds of the suite). The first worker to ask builds into a folder of the run, under a
    file lock; every worker gets a copy of its own, so that a test which writes into its
    fixture disturbs no other worker. Without xdist it builds straight into a folder of its own.
    """
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        folder = tmp_path_factory.mktemp(name)
        build(folder)
        return folder
    from filelock import FileLock

    shared = tmp_path_factory.getbasetemp().parent / f"built-once-{name}"  # the run's, above the workers'
    done = shared.with_name(shared.name + ".done")
    with FileLock(str(shared) + ".lock"):
        if not done.exists():
            shutil.rmtree(shared, ignore_errors=True)
            shared.mkdir()
            build(shared)
            done.touch()
    folder = tmp_path_factory.mktemp(name)
    shutil.copytree(shared, folder, dirs_exist_ok=True)
    return folder
