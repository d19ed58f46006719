"""Arbor from Python: scenes, BVH builders, traversal, compressed BVHs and the cycle-level
hardware models (MergeTree, DRAM, the ray-tracing accelerator and its energy), and
design-space sweeps over them on one machine or a Ray cluster.

Two layers:

- :func:`run` runs any ``arbor`` command line in-process and returns its ``--json``
  documents as dictionaries: the same options, the same ``--set`` keys, the same schema
  (``docs/cli-json.md``). :func:`sim_mergetree`, :func:`sim_rtunit` and :func:`sim_dram`
  are keyword-argument front ends to it.
- The typed API (:mod:`arbor.core`): scenes, BVHs, tracing and CBVHs with numpy arrays.

Every failure raises :class:`ArborError` with the one-line message the ``arbor`` command
prints. Sweeps: :func:`arbor.sweep.run` and ``python -m arbor sweep``.
"""

from __future__ import annotations

import json
from typing import Any, Mapping

from . import cli
from ._arbor import ArborError as ArborError
from ._arbor import __version__ as __version__
from ._arbor import check_args as _check_args
from ._arbor import run_json as _run_json
from .cli import Scalar

from .core import *  # noqa: F401,F403  (the typed API; its __all__ lists it)
from .core import __all__ as _core_all

__all__ = [
    "ArborError",
    "__version__",
    "run",
    "check",
    "sim",
    "sim_mergetree",
    "sim_rtunit",
    "sim_dram",
] + list(_core_all)


def run(*args: str) -> list[dict[str, Any]]:
    """Runs one ``arbor`` command line (without the program name) quietly and returns the
    JSON documents it produced, in order. Pass ``--json`` yourself for commands that print
    text otherwise.

    >>> arbor.run("sim", "dram", "--bytes", "4096", "--json")[0]["schema"]
    'arbor.sim.dram.v1'
    """
    docs = json.loads(_run_json([str(a) for a in args]))
    if not isinstance(docs, list):
        raise ArborError("internal error: the command's documents are not a list")
    return docs


def check(*args: str) -> None:
    """Checks a command line without running it (options, and for ``sim`` commands the
    preset, ``--set`` keys and values and memory system, with no scene loaded); raises
    :class:`ArborError` with the command's message."""
    _check_args([str(a) for a in args])


def sim(
    model: str,
    scene: str | None = None,
    *,
    set: Mapping[str, Scalar] | None = None,
    **options: Scalar | None,
) -> dict[str, Any]:
    """Runs hardware model ``model`` (``mergetree``, ``rtunit`` or ``dram``) and returns
    its ``--json`` document. ``set`` holds configuration keys (``--set KEY=VALUE``); other
    keyword arguments are long options (see :mod:`arbor.cli`)."""
    return _sim(model, scene, options, set)


def _sim(
    model: str,
    scene: str | None,
    options: Mapping[str, Scalar | None],
    set: Mapping[str, Scalar] | None,
) -> dict[str, Any]:
    docs = run(*cli.command_line(["sim", model], scene, options, set))
    if len(docs) != 1:
        raise ArborError(f"internal error: sim {model} gave {len(docs)} documents")
    return docs[0]


def sim_mergetree(
    scene: str,
    *,
    preset: str | None = None,
    dram: str | None = None,
    time: float | None = None,
    check: bool = True,
    set: Mapping[str, Scalar] | None = None,
    **options: Scalar | None,
) -> dict[str, Any]:
    """Simulates the MergeTree builder over ``scene`` (any scene spec) and returns the
    ``arbor.sim.mergetree.v1`` document. ``check=False`` skips the comparison with the
    software HLBVH; ``set`` takes ``arbor sim mergetree --set help`` keys, e.g.
    ``set={"m": 4096}``; other options as the command line's (``cbvh="stream"``, ...)."""
    opts: dict[str, Scalar | None] = {
        "preset": preset,
        "dram": dram,
        "time": time,
        "no_check": not check,
    }
    opts.update(options)
    return _sim("mergetree", scene, opts, set)


def sim_rtunit(
    scene: str,
    *,
    tree: str | None = None,
    rays: str | None = None,
    width: int | None = None,
    height: int | None = None,
    set: Mapping[str, Scalar] | None = None,
    **options: Scalar | None,
) -> dict[str, Any]:
    """Simulates the ray-tracing accelerator over ``scene`` and returns the
    ``arbor.sim.rtunit.v1`` document (traffic, cycles, energy). ``tree`` is ``bvh2`` or
    ``mbvh4``, ``rays`` ``primary`` or ``diffuse``; ``set`` takes its configuration keys."""
    opts: dict[str, Scalar | None] = {
        "tree": tree,
        "rays": rays,
        "width": width,
        "height": height,
    }
    opts.update(options)
    return _sim("rtunit", scene, opts, set)


def sim_dram(system: str = "lpddr3-1600-1x64", **options: Scalar | None) -> dict[str, Any]:
    """Drives memory system ``system`` with a synthetic pattern (``pattern="random"``,
    ``bytes=1 << 20``, ...) and returns the ``arbor.sim.dram.v1`` document."""
    return _sim("dram", None, {"system": system, **options}, None)
