"""Checked reading of a scene's files: what exists is a regular file, JSON is parsed strictly.

Every function raises ValueError (or FileNotFoundError) naming the file and, for JSON,
where in it the problem is: a folder or link loop where a file belongs, a JSON file too
large or nested too deeply, not UTF-8, with NaN/Infinity, a repeated key, a boolean or a
string where a number belongs, a number too large to represent. The RWAVS loader
(:mod:`avgs.data.rwavs`) and the camera views (:mod:`avgs.data.views`) read through here.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from pathlib import Path

import numpy as np

MAX_JSON_BYTES = 16 * 2**20
"""Largest JSON file read (16 MiB). The biggest legitimate one is a transforms file: ~400
bytes a frame, and a frame a second for an hour is ~1.5 MB."""
MAX_JSON_DEPTH = 64
"Deepest nesting of JSON arrays / objects accepted (our files nest at most 6 levels)."


def describe_json(value) -> str:
    """A short description of a parsed JSON value, for error messages (never a long repr)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, str):
        return f"a string ({value[:40]!r}{'...' if len(value) > 40 else ''})"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return f"an object with {len(value)} key(s)"
    if isinstance(value, int) and abs(value) > 10**15:
        return f"an integer of about {int(value.bit_length() * 0.30103) + 1} digits"
    return repr(value)


def finite_number(value, what: str) -> float:
    """``value`` as a float when it is a finite JSON number (not a boolean), else ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{what} must be a number, got {describe_json(value)}")
    try:
        x = float(value)
    except OverflowError:
        raise ValueError(f"{what} is too large ({describe_json(value)})") from None
    if not math.isfinite(x):
        raise ValueError(f"{what} must be finite, got {x!r}")
    return x


def require_file(path: Path, what: str) -> os.stat_result:
    """``os.stat`` of a file that must exist and be a regular file (symbolic links followed)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            raise FileNotFoundError(f"{path}: a symbolic link to nothing; expected {what}") from None
        raise FileNotFoundError(f"{path}: missing; expected {what}") from None
    except NotADirectoryError:
        raise FileNotFoundError(f"{path}: missing (a folder on its path is a file); expected {what}") from None
    except OSError as exc:  # ELOOP (a symbolic-link loop), EACCES, ENAMETOOLONG, ...
        raise ValueError(f"{path}: cannot be opened ({exc.strerror or exc}); expected {what}") from None
    except ValueError as exc:  # an embedded NUL
        raise ValueError(f"{str(path)[:200]!r}: not a usable path ({exc}); expected {what}") from None
    if stat.S_ISDIR(st.st_mode):
        raise ValueError(f"{path}: is a folder; expected {what}")
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{path}: not a regular file; expected {what}")
    return st


def file_present(path: Path, what: str) -> bool:
    """True for a regular file at ``path``, False when nothing is there; an error for anything
    else there (a folder, a symbolic-link loop, a link to nothing, a device)."""
    try:
        os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        return False
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot be opened ({exc}); expected {what}") from None
    require_file(path, what)
    return True


def is_regular_file(path: Path) -> bool:
    """``path.is_file()`` that is False, not an error, for any path the OS refuses
    (a name too long, a symbolic-link loop, an embedded NUL)."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):
        return False


class _DuplicateKey(ValueError):
    pass


def _object_without_duplicates(pairs):
    out = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def _json_child(where: str, key) -> str:
    if isinstance(key, int):
        return f"{where}[{key}]"
    text = key if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,60}", key) else repr(key[:60])
    return f"{where}.{text}" if where else text


def _json_problem(value) -> str | None:
    """The first non-finite number or too deep nesting in parsed JSON, as ``where: what``."""
    stack = [(value, "", 0)]
    while stack:
        v, where, depth = stack.pop()
        if isinstance(v, float) and not math.isfinite(v):
            spelled = "NaN" if math.isnan(v) else ("Infinity" if v > 0 else "-Infinity")
            return f"{where or 'the value'} is {spelled}; numbers must be finite (no NaN or Infinity)"
        if isinstance(v, (dict, list)):
            if depth >= MAX_JSON_DEPTH:
                return f"{where or 'the value'} nests deeper than {MAX_JSON_DEPTH} levels"
            items = list(v.items()) if isinstance(v, dict) else list(enumerate(v))
            stack.extend((child, _json_child(where, key), depth + 1) for key, child in reversed(items))
    return None


def read_json(path: Path, what: str):
    """Parsed JSON of ``path``, validated: a regular file of at most :data:`MAX_JSON_BYTES`,
    strict UTF-8, valid JSON nested at most :data:`MAX_JSON_DEPTH` levels, no NaN or
    Infinity (nor numbers that overflow to it), no key twice in one object. Errors name the
    file (and the place in it) and say what was ``what``-expected."""
    path = Path(path)
    st = require_file(path, what)
    if st.st_size > MAX_JSON_BYTES:
        raise ValueError(f"{path}: {st.st_size} bytes, more than the {MAX_JSON_BYTES} a scene's JSON may have; expected {what}")
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_JSON_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or exc}); expected {what}") from None
    if len(data) > MAX_JSON_BYTES:
        raise ValueError(f"{path}: more than the {MAX_JSON_BYTES} bytes a scene's JSON may have; expected {what}")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason}); expected {what}") from None
    try:
        value = json.loads(text, object_pairs_hook=_object_without_duplicates)
    except RecursionError:
        raise ValueError(f"{path}: JSON nested too deeply (more than {MAX_JSON_DEPTH} levels); expected {what}") from None
    except _DuplicateKey as exc:
        raise ValueError(f"{path}: key {str(exc.args[0])[:60]!r} appears twice in one object; expected {what}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc}); expected {what}") from None
    except ValueError as exc:  # e.g. an integer of more than sys.get_int_max_str_digits() digits
        raise ValueError(f"{path}: not valid JSON ({str(exc)[:200]}); expected {what}") from None
    problem = _json_problem(value)
    if problem is not None:
        raise ValueError(f"{path}: {problem}")
    return value


_read_json = read_json  # the name the readers used before


def json_vector(value, n: int, where: str) -> np.ndarray:
    """``[n]`` float64 from a JSON list of ``n`` finite numbers (not booleans or strings)."""
    if not isinstance(value, list) or len(value) != n:
        raise ValueError(f"{where} must be a list of {n} numbers, got {describe_json(value)}")
    return np.array([finite_number(v, f"{where}[{i}]") for i, v in enumerate(value)], dtype=np.float64)


def json_matrix4(value, where: str) -> np.ndarray:
    """``[4, 4]`` float64 from 16 numbers row-major, or 4 rows of 4 numbers."""
    if isinstance(value, list) and len(value) == 4 and all(isinstance(row, list) for row in value):
        rows = [json_vector(row, 4, f"{where}[{i}]") for i, row in enumerate(value)]
        return np.stack(rows)
    if not isinstance(value, list) or len(value) != 16:
        raise ValueError(f"{where} must be 16 numbers (row-major 4x4), got {describe_json(value)}")
    return json_vector(value, 16, where).reshape(4, 4)
