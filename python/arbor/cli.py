"""Command lines: how Python values become `arbor` arguments.

One rule, shared by the `arbor.sim_*` helpers and by sweeps, so that a parameter means the
same thing everywhere:

- ``set.KEY`` (or a key of the ``set=`` mapping) becomes ``--set KEY=VALUE``: a
  configuration key of a hardware model, the same keys as the command line's ``--set``;
- any other name becomes a long option, underscores spelled as hyphens
  (``mbvh4_builder="collapse"`` is ``--mbvh4-builder collapse``);
- ``True`` is a bare flag (``no_check=True`` is ``--no-check``), ``False`` and ``None``
  leave the option out;
- numbers and strings are written as Python prints them (``repr`` for floats, so that
  nothing is rounded).
"""

from __future__ import annotations

import math
import re
from typing import Mapping, Sequence, Union

#: A value a parameter may take.
Scalar = Union[bool, int, float, str]

_NAME = re.compile(r"^[a-z][a-z0-9_-]*$")
_KEY = re.compile(r"^[a-z][a-z0-9_]*$")


def value_text(value: Scalar) -> str:
    """The text of one value on a command line."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{value} is not a finite number")
        return repr(value)
    if isinstance(value, str):
        return value
    raise TypeError(f"{value!r} is not a number, a string or a boolean")


def option_args(name: str, value: Scalar | None) -> list[str]:
    """The arguments that give option ``name`` (``set.KEY`` or a long option) ``value``."""
    if name.startswith("set."):
        key = name[4:]
        if not _KEY.match(key):
            raise ValueError(f"'{key}' is not a configuration key name")
        if value is None:
            return []
        return ["--set", f"{key}={value_text(value)}"]
    if not _NAME.match(name):
        raise ValueError(f"'{name}' is not an option name")
    flag = "--" + name.replace("_", "-")
    if value is None or value is False:
        return []
    if value is True:
        return [flag]
    return [flag, value_text(value)]


def command_line(
    command: Sequence[str],
    scene: str | None = None,
    options: Mapping[str, Scalar | None] | None = None,
    set: Mapping[str, Scalar] | None = None,
) -> list[str]:
    """The full argument list (without the program name): the command words, the scene,
    the options in order, then ``--set`` pairs, then ``--json``."""
    args = list(command)
    if scene is not None:
        args.append(scene)
    for name, value in (options or {}).items():
        args += option_args(name, value)
    for key, value in (set or {}).items():
        args += option_args("set." + key, value)
    args.append("--json")
    return args
