"""A checkpoint's plain values, read without torch (:func:`peek_checkpoint`).

The sweep's workers ask every run's checkpoint how far it trained. Importing torch for that took
2-3 s on an idle machine and 40-45 s in a Ray worker on a busy one: Ray runs its workers at a low
priority (``RAY_worker_niceness``), so the import waits behind every other process; a sweep's run
stood that long between its training and its status.

``torch.save`` writes a zip archive whose ``<name>/data.pkl`` pickles the object, each tensor's
storage a persistent id of a record beside it. This unpickles that one member with every tensor,
storage and other torch object left out (:data:`OMITTED`): the dicts, lists, strings and numbers
around them come back as they are. Like ``torch.load(weights_only=True)``, it allows no global but
torch's own rebuild functions (which it does not call) and a few plain containers, so a file cannot
run code here; anything else is refused with :class:`pickle.UnpicklingError`.
"""

from __future__ import annotations

import collections
import pickle
import zipfile
from pathlib import Path


class _Omitted:
    """What stands in for a tensor, a storage or any other torch object: nothing of it is read."""

    def __repr__(self) -> str:
        return "OMITTED"

    def __setstate__(self, state) -> None:
        pass


OMITTED = _Omitted()
"The value of every tensor (and other torch object) in a peeked checkpoint."

_PLAIN = {("collections", "OrderedDict"): collections.OrderedDict, ("builtins", "set"): set,
          ("builtins", "frozenset"): frozenset, ("builtins", "complex"): complex}
"The globals other than torch's that a checkpoint's pickle may name (what weights-only loading allows of them)."


def _omit(*args, **kwargs) -> _Omitted:
    return OMITTED


class _PlainUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if module == "torch" or module.startswith("torch."):
            return _omit  # a rebuild function, a storage or dtype class: called, it gives OMITTED
        try:
            return _PLAIN[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(f"{module}.{name} is not a global a checkpoint holds") from None

    def persistent_load(self, pid):
        return OMITTED  # a storage: its bytes are a member of the archive that is not read


def peek_checkpoint(path: str | Path):
    """The object a ``torch.save`` file at ``path`` holds, its tensors :data:`OMITTED`.

    Raises OSError when the file cannot be read, :class:`zipfile.BadZipFile` when it is not a zip
    archive (torch's legacy format included), KeyError when it has no pickle, and
    :class:`pickle.UnpicklingError` (or another unpickling error) when the pickle is damaged or names
    a global a checkpoint does not hold."""
    with zipfile.ZipFile(path) as archive:
        names = [n for n in archive.namelist() if n.endswith("/data.pkl") and n.count("/") == 1]
        if len(names) != 1:
            raise KeyError(f"{path}: no data.pkl in the archive (a torch.save file has one)")
        with archive.open(names[0]) as member:
            return _PlainUnpickler(member).load()
