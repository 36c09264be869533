"""Command-line flags generated from the configuration dataclasses of :mod:`avgs.config`.

Every field of a section becomes one flag whose help is the field's docstring:
``--{prefix}{name}`` with underscores as dashes, or the field's ``metadata["flag"]`` where
set. Booleans get both forms (``--context`` / ``--no-context``); ``Literal`` fields list
their choices. A flag left out keeps the value of the configuration it is applied to
(the defaults, or the ``--quick`` preset).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import textwrap
import typing

DEST = "config:"
"Prefix of the argparse destinations of generated flags: ``config:SECTION.FIELD``."


@functools.lru_cache(maxsize=None)
def _docstrings(dc: type) -> dict[str, str]:
    body = ast.parse(textwrap.dedent(inspect.getsource(dc))).body[0].body
    out = {}
    for node, nxt in zip(body, body[1:]):
        if (
            isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
            and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str)
        ):
            out[node.target.id] = nxt.value.value
    return out


def field_help(dc: type, name: str) -> str:
    """The one-line docstring written under a dataclass field."""
    return _docstrings(dc).get(name, "")


def flag_name(f: dataclasses.Field, prefix: str) -> str:
    return f.metadata.get("flag") or prefix + f.name.replace("_", "-")


def add_config_flags(parser: argparse.ArgumentParser, sections: dict[str, tuple[object, str]], title: str) -> None:
    """One flag per field of each section. ``sections``: attribute path ("" for the top level,
    "acoustic", ...) -> (an instance whose values are the documented defaults, flag prefix)."""
    group = parser.add_argument_group(title)
    seen: set[str] = {a for action in parser._actions for a in action.option_strings}
    for path, (obj, prefix) in sections.items():
        hints = typing.get_type_hints(type(obj))
        for f in dataclasses.fields(obj):
            kind = hints[f.name]
            if dataclasses.is_dataclass(kind):
                continue  # a nested section has its own entry
            flag = "--" + flag_name(f, prefix)
            if flag in seen:
                raise RuntimeError(f"two configuration fields would share the flag {flag}")
            seen.add(flag)
            default = getattr(obj, f.name)
            kwargs: dict = {"dest": f"{DEST}{path}.{f.name}", "default": None,
                            "help": f"{field_help(type(obj), f.name)} (default: {default})".replace("%", "%%")}
            if kind is bool:
                kwargs["action"] = argparse.BooleanOptionalAction
            elif typing.get_origin(kind) is typing.Literal:
                kwargs["choices"] = typing.get_args(kind)
            else:
                kwargs["type"] = kind
                kwargs["metavar"] = {int: "N", float: "X", str: "S"}.get(kind, "V")
            group.add_argument(flag, **kwargs)


def apply_config_flags(args: argparse.Namespace, root: object) -> object:
    """Set every generated flag that was given on the command line on ``root`` (in place); returns it."""
    for dest, value in vars(args).items():
        if not dest.startswith(DEST) or value is None:
            continue
        path, name = dest[len(DEST) :].rsplit(".", 1)
        obj = root
        for part in filter(None, path.split(".")):
            obj = getattr(obj, part)
        setattr(obj, name, value)
    return root
