"""Design-space sweeps: one ``arbor`` command over scenes x a parameter grid, each point an
independent, deterministic job, run by a local process pool or as Ray tasks.

A sweep file (TOML)::

    command = "sim mergetree"            # sim mergetree | sim rtunit | sim dram | build | cbvh
    scenes = ["../../scenes/CesiumMan.glb", "proc:cloth?n=20000&seed=1"]

    [options]                            # the same for every point
    no_check = true

    [grid]                               # crossed: every combination
    "set.m" = [1024, 2048, 4096, 8192]   # --set m=...; or {start, stop, step} / {start, stop, factor}
    dram = ["simple:lpddr3-1600-1x64", "simple:lpddr3-1333-4x64"]

    [zip]                                # zipped: the i-th values go together (equal lengths)

Scene paths are relative to the sweep file. A parameter named ``set.KEY`` is ``--set
KEY=VALUE``; any other name is a long option (:mod:`arbor.cli`). Everything is checked
before anything runs: unknown keys, empty grids, missing scenes and every point's options
(through the command's own parser and configuration), each error naming the file and key.

Each point's record (its parameters, the result document, the Arbor version, status and
error, wall time and host) is appended to ``OUT/records.jsonl`` as it finishes, so a sweep
can be interrupted and resumed: points whose records exist are skipped. After the run
``OUT/results.parquet`` and ``OUT/results.csv`` hold the sweep's records as a table (see
:func:`table`).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import hashlib
import json
import math
import multiprocessing
import os
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python < 3.11 only
    import tomli as tomllib

from . import cli
from .cli import Scalar

#: The commands a sweep can run, and whether each takes a scene.
COMMANDS: dict[str, bool] = {
    "sim mergetree": True,
    "sim rtunit": True,
    "sim dram": False,
    "build": True,
    "cbvh": True,
}

#: The top-level keys of a sweep file.
FILE_KEYS = ("command", "scenes", "options", "grid", "zip", "description")

#: Most points one sweep file may expand to.
MAX_POINTS = 1_000_000

#: Fields of a record that depend on the host and the moment, not on the point: two runs
#: of a point agree on everything else (see :func:`deterministic`).
HOST_FIELDS = ("wall_s", "host")


class SweepError(ValueError):
    """A sweep file that cannot run; the message names the file and the key."""


@dataclass(frozen=True)
class Point:
    """One job of a sweep: the command, the scene (as the sweep file names it, and as a
    path this machine opens) and the parameter values."""

    command: tuple[str, ...]
    scene: str | None
    scene_path: str | None
    params: tuple[tuple[str, Scalar], ...]

    @property
    def id(self) -> str:
        """A stable name of the point: a hash of the command, the scene as written and the
        parameters (not of where the scene lies on this machine)."""
        canon = json.dumps(
            {"command": list(self.command), "scene": self.scene, "params": dict(self.params)},
            sort_keys=True,
            separators=(",", ":"),
        )
        return hashlib.sha1(canon.encode()).hexdigest()[:16]

    def argv(self) -> list[str]:
        """The command line that runs the point (without the program name)."""
        return cli.command_line(self.command, self.scene_path, dict(self.params))


@dataclass
class Sweep:
    """A checked sweep file."""

    path: Path
    command: tuple[str, ...]
    scenes: list[tuple[str, str]]  # (as written, path on this machine)
    options: dict[str, Scalar]
    grid: dict[str, list[Scalar]]
    zipped: dict[str, list[Scalar]]
    description: str = ""
    parameters: list[str] = field(default_factory=list)

    def points(self) -> list[Point]:
        """Every point, scenes outermost, then the grid (first key slowest), then the zip."""
        grid_keys = list(self.grid)
        zip_len = len(next(iter(self.zipped.values()))) if self.zipped else 1
        out: list[Point] = []
        scenes: list[tuple[str | None, str | None]] = (
            [(s, p) for s, p in self.scenes] if self.scenes else [(None, None)]
        )
        for scene, scene_path in scenes:
            for combo in _product([self.grid[k] for k in grid_keys]):
                for i in range(zip_len):
                    params: dict[str, Scalar] = dict(self.options)
                    params.update(zip(grid_keys, combo))
                    params.update({k: v[i] for k, v in self.zipped.items()})
                    out.append(Point(self.command, scene, scene_path, tuple(params.items())))
        return out


def _product(lists: list[list[Scalar]]) -> Iterator[tuple[Scalar, ...]]:
    if not lists:
        yield ()
        return
    for head in lists[0]:
        for rest in _product(lists[1:]):
            yield (head, *rest)


# --- Reading and checking a sweep file --------------------------------------------------


def load(path: str | os.PathLike[str]) -> Sweep:
    """Reads and checks a sweep file; raises :class:`SweepError` naming the file and key.
    Every point's command line is checked by the command's own parser (options, ``--set``
    keys and values, memory systems) without loading a scene."""
    p = Path(path)
    where = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise SweepError(f"{where}: cannot read the sweep file: {e.strerror or e}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SweepError(f"{where}: not a TOML file: {e}") from None

    def err(key: str, msg: str) -> SweepError:
        return SweepError(f"{where}: {key}: {msg}")

    for k in doc:
        if k not in FILE_KEYS:
            raise err(k, f"unknown key (known: {', '.join(FILE_KEYS)})")
    if "command" not in doc:
        raise err("command", f"missing (one of: {', '.join(COMMANDS)})")
    command_raw = doc["command"]
    if isinstance(command_raw, list) and all(isinstance(w, str) for w in command_raw):
        command_name = " ".join(command_raw)
    elif isinstance(command_raw, str):
        command_name = " ".join(command_raw.split())
    else:
        raise err("command", 'must be a string such as "sim mergetree"')
    if command_name not in COMMANDS:
        raise err("command", f"'{command_name}' cannot be swept (one of: {', '.join(COMMANDS)})")
    command = tuple(command_name.split())
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise err("description", "must be a string")

    scenes: list[tuple[str, str]] = []
    if COMMANDS[command_name]:
        raw = doc.get("scenes")
        if raw is None:
            raise err("scenes", f"missing: '{command_name}' needs at least one scene")
        if isinstance(raw, str):
            raw = [raw]
        if not isinstance(raw, list) or not raw:
            raise err("scenes", "must be a non-empty list of scene specs")
        for i, s in enumerate(raw):
            if not isinstance(s, str) or not s:
                raise err(f"scenes[{i}]", "must be a scene spec (a path or proc:NAME?...)")
            scenes.append((s, _resolve_scene(s, p.parent, lambda m: err(f"scenes[{i}]", m))))
        dup = _first_duplicate([s for s, _ in scenes])
        if dup is not None:
            raise err("scenes", f"'{dup}' is listed twice")
    elif "scenes" in doc:
        raise err("scenes", f"'{command_name}' takes no scene")

    def at(key: str) -> Callable[[str], SweepError]:
        return lambda m: err(key, m)

    options = {
        k: _scalar(v, at(f"options.{k}"))
        for k, v in _params(doc.get("options", {}), "options", err).items()
    }
    grid = {
        k: _values(v, at(f"grid.{k}")) for k, v in _params(doc.get("grid", {}), "grid", err).items()
    }
    zipped = {
        k: _values(v, at(f"zip.{k}")) for k, v in _params(doc.get("zip", {}), "zip", err).items()
    }
    if zipped:
        lengths = {k: len(v) for k, v in zipped.items()}
        first = next(iter(lengths))
        for k, n in lengths.items():
            if n != lengths[first]:
                raise err(
                    f"zip.{k}",
                    f"has {n} values but zip.{first} has {lengths[first]} "
                    "(zipped parameters go together and need equal lengths)",
                )
    seen: dict[str, str] = {}
    for table, names in (("options", options), ("grid", grid), ("zip", zipped)):
        for k in names:
            if k in seen:
                raise err(f"{table}.{k}", f"is also given in {seen[k]}")
            seen[k] = table
            if k == "json":
                raise err(f"{table}.{k}", "is always on: a sweep reads the --json document")

    sweep = Sweep(
        path=p,
        command=command,
        scenes=scenes,
        options=options,
        grid=grid,
        zipped=zipped,
        description=description,
        parameters=list(seen),
    )
    count = max(len(scenes), 1) * math.prod(len(v) for v in grid.values())
    count *= len(next(iter(zipped.values()))) if zipped else 1
    if count > MAX_POINTS:
        raise err("grid", f"expands to {count} points, more than {MAX_POINTS}")
    _check_points(sweep, err)
    return sweep


def _first_duplicate(items: Iterable[str]) -> str | None:
    seen: set[str] = set()
    for s in items:
        if s in seen:
            return s
        seen.add(s)
    return None


def _resolve_scene(spec: str, base: Path, err: Callable[[str], SweepError]) -> str:
    """The spec this machine opens: ``proc:`` specs as they are, paths relative to the
    sweep file; a path (or the directory or glob's parent of a frame sequence) must exist."""
    if spec.startswith("proc:"):
        return spec
    path = Path(spec).expanduser()
    if not path.is_absolute():
        path = base / path
    probe = path
    if any(c in spec for c in "*?["):
        probe = path.parent  # a glob of frames: its folder must exist
    if not probe.exists():
        raise err(f"'{spec}' does not exist (looked for {probe})")
    return str(path)


def _params(table: Any, name: str, err: Callable[[str, str], SweepError]) -> dict[str, Any]:
    """A parameter table with ``set = {...}`` (or ``[grid.set]``) flattened to ``set.KEY``."""
    if not isinstance(table, dict):
        raise err(name, "must be a table of parameter = value")
    out: dict[str, Any] = {}
    for k, v in table.items():
        if k == "set" and isinstance(v, dict):
            for sk, sv in v.items():
                out[f"set.{sk}"] = sv
        else:
            out[k] = v
    for k in out:
        try:
            cli.option_args(k, "x")
        except ValueError as e:
            raise err(f"{name}.{k}", str(e)) from None
    return out


def _scalar(v: Any, err: Callable[[str], SweepError]) -> Scalar:
    if isinstance(v, (bool, int, str)):
        return v
    if isinstance(v, float):
        if not math.isfinite(v):
            raise err(f"{v} is not a finite number")
        return v
    raise err(f"{v!r} is not a number, a string or a boolean")


def _values(v: Any, err: Callable[[str], SweepError]) -> list[Scalar]:
    """A grid entry's values: a list, or a range table ``{start, stop, step}`` (inclusive)
    or ``{start, stop, factor}`` (geometric, inclusive)."""
    if isinstance(v, list):
        if not v:
            raise err("empty list: a grid parameter needs at least one value")
        vals = [_scalar(x, err) for x in v]
    elif isinstance(v, dict):
        vals = _range(v, err)
    else:
        raise err("must be a list of values or a range {start, stop, step | factor}")
    dup = _first_duplicate(json.dumps(x) for x in vals)
    if dup is not None:
        raise err(f"the value {dup} is listed twice")
    return vals


def _range(v: dict[str, Any], err: Callable[[str], SweepError]) -> list[Scalar]:
    keys = set(v)
    if keys not in ({"start", "stop", "step"}, {"start", "stop", "factor"}):
        raise err(
            f"a range has keys start, stop and step (or factor); got {', '.join(sorted(keys))}"
        )
    nums: dict[str, float] = {}
    for k, num in v.items():
        if isinstance(num, bool) or not isinstance(num, (int, float)) or not math.isfinite(num):
            raise err(f"range {k} must be a finite number, got {num!r}")
        nums[k] = num
    start, stop = nums["start"], nums["stop"]
    integral = all(isinstance(x, int) for x in nums.values())
    out: list[Scalar] = []
    if "step" in nums:
        step = nums["step"]
        if step == 0 or (stop - start) * step < 0:
            raise err(f"a step of {step} never goes from {start} to {stop}")
        n = int(math.floor((stop - start) / step + 1e-9)) + 1
        if n > MAX_POINTS:
            raise err(f"the range has {n} values, more than {MAX_POINTS}")
        out = [start + i * step if integral else float(start + i * step) for i in range(n)]
    else:
        factor = nums["factor"]
        if start == 0 or (stop / start) <= 0 or factor <= 0 or factor == 1:
            raise err(f"a factor of {factor} never goes from {start} to {stop}")
        if (stop > start) != (factor > 1) and stop != start:
            raise err(f"a factor of {factor} never goes from {start} to {stop}")
        x: float = start
        while (x <= stop * (1 + 1e-12)) if factor > 1 else (x >= stop * (1 - 1e-12)):
            out.append(int(round(x)) if integral else float(x))
            if len(out) > MAX_POINTS:
                raise err(f"the range has more than {MAX_POINTS} values")
            x *= factor
    if not out:
        raise err("the range is empty")
    return out


def _check_points(sweep: Sweep, err: Callable[[str, str], SweepError]) -> None:
    """Runs the command's own checks over the options, so that an error names the key: the
    first value of every parameter together (if that fails, each parameter alone finds the
    culprit), then each value of each parameter with the others at their first, then every
    distinct command line."""
    from . import check
    from ._arbor import ArborError

    first: dict[str, tuple[str, Scalar]] = {k: ("options", v) for k, v in sweep.options.items()}
    first.update({k: ("grid", v[0]) for k, v in sweep.grid.items()})
    first.update({k: ("zip", v[0]) for k, v in sweep.zipped.items()})
    base = {k: v for k, (_, v) in first.items()}
    scene = sweep.scenes[0][1] if sweep.scenes else None

    def problem(params: dict[str, Scalar]) -> str | None:
        try:
            check(*cli.command_line(sweep.command, scene, params))
        except (ArborError, ValueError) as e:
            return str(e)
        return None

    msg = problem(base)
    if msg is not None:
        for k, (table, v) in first.items():
            alone = problem({k: v})
            if alone is not None:
                raise err(f"{table}.{k}", f"value {json.dumps(v)}: {alone}")
        raise err("grid", f"the first values together: {msg}")
    for table, values in (("grid", sweep.grid), ("zip", sweep.zipped)):
        for k, vals in values.items():
            for v in vals[1:]:
                msg = problem({**base, k: v})
                if msg is not None:
                    raise err(f"{table}.{k}", f"value {json.dumps(v)}: {msg}")
    seen: set[tuple[tuple[str, Scalar], ...]] = set()
    for pt in sweep.points():
        if pt.params in seen:
            continue
        seen.add(pt.params)
        msg = problem(dict(pt.params))
        if msg is not None:
            combo = ", ".join(f"{k}={json.dumps(v)}" for k, v in pt.params)
            raise err("grid", f"the point {combo}: {msg}")


# --- Running points ---------------------------------------------------------------------


def run_point(point: Point) -> dict[str, Any]:
    """Runs one point and returns its record; a failure is a record with status
    ``failed`` and the error, never an exception. What pool workers and Ray tasks call."""
    from . import run
    from ._arbor import ArborError

    record = _record_head(point)
    record["host"] = socket.gethostname()
    start = time.perf_counter()
    try:
        docs = run(*point.argv())
        if len(docs) != 1:
            raise ArborError(f"the command gave {len(docs)} documents, expected 1")
        record.update(status="ok", error=None, document=docs[0])
    except ArborError as e:
        record.update(status="failed", error=str(e), document=None)
    except Exception as e:  # noqa: BLE001 - a point's failure must not stop the sweep
        record.update(status="failed", error=f"{type(e).__name__}: {e}", document=None)
    record["wall_s"] = time.perf_counter() - start
    return record


def deterministic(record: Mapping[str, Any]) -> dict[str, Any]:
    """A record without the fields that depend on the host and the moment (wall times, the
    host name, the simulator's own speed): two runs of one point give equal results."""
    out = {k: v for k, v in record.items() if k not in HOST_FIELDS}
    if isinstance(out.get("document"), dict):
        out["document"] = _drop_host_timing(out["document"])
    return out


def _is_host_timing(key: str) -> bool:
    # The documents' host timings: sim_wall_ms, sim_cycles_per_s, load/build wall times.
    return "wall" in key or key.endswith("cycles_per_s")


def _drop_host_timing(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {k: _drop_host_timing(v) for k, v in doc.items() if not _is_host_timing(k)}
    if isinstance(doc, list):
        return [_drop_host_timing(v) for v in doc]
    return doc


def _init_worker(threads: int) -> None:
    # Each point runs on `threads` cores; the pool runs one point per worker.
    os.environ["RAYON_NUM_THREADS"] = str(threads)


def _run_pool(
    points: list[Point], jobs: int, threads: int, on_record: Callable[[dict[str, Any]], None]
) -> None:
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(
        max_workers=jobs, mp_context=ctx, initializer=_init_worker, initargs=(threads,)
    ) as pool:
        futures = {pool.submit(run_point, p): p for p in points}
        try:
            for fut in cf.as_completed(futures):
                try:
                    rec = fut.result()
                except Exception as e:  # a worker that died (killed, out of memory)
                    rec = _crashed(futures[fut], e)
                on_record(rec)
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _record_head(point: Point) -> dict[str, Any]:
    """The fields of a record that name the point and the tool."""
    from ._arbor import __version__

    return {
        "id": point.id,
        "command": " ".join(point.command),
        "scene": point.scene,
        "params": dict(point.params),
        "arbor_version": __version__,
    }


def _crashed(point: Point, e: BaseException) -> dict[str, Any]:
    return {
        **_record_head(point),
        "host": None,
        "status": "failed",
        "error": f"the worker running the point died: {type(e).__name__}: {e}",
        "document": None,
        "wall_s": None,
    }


def _run_ray(
    points: list[Point],
    address: str,
    jobs: int,
    task_cpus: float,
    task_memory: int | None,
    on_record: Callable[[dict[str, Any]], None],
) -> None:
    try:
        import ray
    except ImportError:
        raise SweepError("--ray needs the ray package: pip install './python[ray]'") from None
    threads = max(1, int(task_cpus))
    started = not ray.is_initialized()
    if started:
        if address == "local":
            ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        opts: dict[str, Any] = {
            "num_cpus": task_cpus,
            "max_retries": 0,
            "runtime_env": {"env_vars": {"RAYON_NUM_THREADS": str(threads)}},
        }
        if task_memory:
            opts["memory"] = task_memory
        task = ray.remote(run_point).options(**opts)
        pending = {task.remote(p): p for p in points}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                p = pending.pop(ref)
                try:
                    rec = ray.get(ref)
                except Exception as e:  # the task's worker died
                    rec = _crashed(p, e)
                on_record(rec)
    finally:
        if started:
            ray.shutdown()


# --- Records and results ----------------------------------------------------------------


def read_records(out: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """The records in ``OUT/records.jsonl`` by point id (the last record of an id wins). A
    line cut short by an interrupted write is skipped."""
    path = Path(out) / "records.jsonl"
    recs: dict[str, dict[str, Any]] = {}
    if not path.exists():
        return recs
    with path.open(encoding="utf-8") as f:
        for line in f:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict) and isinstance(rec.get("id"), str):
                recs[rec["id"]] = rec
    return recs


class _Appender:
    """Appends records to ``records.jsonl``, each flushed to disk before the next."""

    def __init__(self, path: Path) -> None:
        self.f = path.open("a+b")
        self.f.seek(0, os.SEEK_END)
        if self.f.tell() > 0:
            self.f.seek(-1, os.SEEK_END)
            if self.f.read(1) != b"\n":  # a line cut short: end it, it is skipped on read
                self.f.write(b"\n")

    def write(self, rec: dict[str, Any]) -> None:
        self.f.write(json.dumps(rec, sort_keys=True).encode() + b"\n")
        self.f.flush()
        os.fsync(self.f.fileno())

    def close(self) -> None:
        self.f.close()


def _flatten(prefix: str, v: Any, out: dict[str, Any]) -> None:
    if isinstance(v, dict):
        for k, x in v.items():
            _flatten(f"{prefix}.{k}", x, out)
    elif isinstance(v, list):
        out[prefix] = json.dumps(v)
    else:
        out[prefix] = v


def rows(records: Iterable[Mapping[str, Any]], parameters: Sequence[str]) -> list[dict[str, Any]]:
    """Flat rows of records: ``id``, ``scene``, ``param.NAME`` for every parameter,
    ``status``, ``error``, ``arbor_version``, ``host``, ``wall_s``, the result document
    flattened as ``result.KEY.SUBKEY`` (lists as JSON text) and the whole ``document`` as
    JSON text."""
    out = []
    for rec in records:
        row: dict[str, Any] = {"id": rec["id"], "scene": rec.get("scene")}
        params = rec.get("params") or {}
        for name in parameters:
            row[f"param.{name}"] = params.get(name)
        for k in ("status", "error", "arbor_version", "host", "wall_s"):
            row[k] = rec.get(k)
        doc = rec.get("document")
        if isinstance(doc, dict):
            _flatten("result", doc, row)
        row["document"] = json.dumps(doc) if doc is not None else None
        out.append(row)
    return out


def table(records: Iterable[Mapping[str, Any]], parameters: Sequence[str]) -> Any:
    """The records as a ``pyarrow.Table`` (columns as :func:`rows`; a column whose values
    mix types is stored as text)."""
    import pyarrow as pa

    rs = rows(records, parameters)
    names: list[str] = []
    for r in rs:
        for k in r:
            if k not in names:
                names.append(k)
    cols = {}
    for k in names:
        vals = [r.get(k) for r in rs]
        kinds = {type(v) for v in vals if v is not None}
        if kinds == {int, float}:
            vals = [float(v) if v is not None else None for v in vals]
        elif len(kinds) > 1:
            vals = [json.dumps(v) if not isinstance(v, str) and v is not None else v for v in vals]
        try:
            cols[k] = pa.array(vals)
        except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError):
            cols[k] = pa.array([None if v is None else str(v) for v in vals], pa.string())
    return pa.table(cols)


def write_results(out: Path, tbl: Any) -> tuple[Path, Path]:
    """Writes ``results.parquet`` and ``results.csv`` in ``out``, each through a temporary
    file renamed into place, so that a reader never sees half a file."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    paths = (out / "results.parquet", out / "results.csv")
    tmp = [p.with_name(p.name + ".tmp") for p in paths]
    pq.write_table(tbl, tmp[0])
    pacsv.write_csv(tbl, tmp[1])
    for t, p in zip(tmp, paths):
        os.replace(t, p)
    return paths


@dataclass
class Summary:
    """What a sweep run did."""

    points: int
    skipped: int
    ran: int
    failed: int
    results: Path
    csv: Path

    def __str__(self) -> str:
        return (
            f"{self.points} points: {self.ran} run, {self.skipped} already done, "
            f"{self.failed} failed; results in {self.results} and {self.csv}"
        )


def run(
    sweep: str | os.PathLike[str] | Sweep,
    out: str | os.PathLike[str],
    *,
    jobs: int | None = None,
    ray: str | None = None,
    task_cpus: float = 1,
    task_memory: int | None = 2 << 30,
    retry_failed: bool = False,
    progress: bool = True,
) -> Summary:
    """Runs a sweep (a file or a loaded :class:`Sweep`) into directory ``out``.

    ``jobs`` points run at once (default: the machine's cores) in a local process pool, or,
    with ``ray`` (a cluster address, or ``"local"`` for a Ray instance started for the run),
    as Ray tasks requesting ``task_cpus`` CPUs and ``task_memory`` bytes each. Points whose
    records are in ``out`` are skipped (with ``retry_failed``, failed ones run again).
    Returns a :class:`Summary`; failed points are recorded, not raised."""
    sw = sweep if isinstance(sweep, Sweep) else load(sweep)
    if jobs is not None and jobs < 1:
        raise SweepError(f"jobs must be at least 1, got {jobs}")
    if task_cpus <= 0:
        raise SweepError(f"task_cpus must be positive, got {task_cpus}")
    outdir = Path(out)
    if outdir.exists() and not outdir.is_dir():
        raise SweepError(f"{outdir}: exists and is not a directory")
    outdir.mkdir(parents=True, exist_ok=True)
    points = sw.points()
    done = read_records(outdir)
    todo = [
        p for p in points if p.id not in done or (retry_failed and done[p.id].get("status") != "ok")
    ]
    n_jobs = jobs or os.cpu_count() or 1
    appender = _Appender(outdir / "records.jsonl")
    failed = 0
    bar = _progress(len(points), len(points) - len(todo), sw.path.name, progress)

    def on_record(rec: dict[str, Any]) -> None:
        nonlocal failed
        appender.write(rec)
        done[rec["id"]] = rec
        if rec.get("status") != "ok":
            failed += 1
        bar.update(failed)

    try:
        if todo:
            if ray is None:
                _run_pool(todo, min(n_jobs, len(todo)), max(1, int(task_cpus)), on_record)
            else:
                _run_ray(todo, ray, n_jobs, task_cpus, task_memory, on_record)
    finally:
        bar.close()
        appender.close()
        ids = [p.id for p in points]
        recs = [done[i] for i in ids if i in done]
        res, csv = write_results(outdir, table(recs, sw.parameters))
    return Summary(
        points=len(points),
        skipped=len(points) - len(todo),
        ran=len(todo),
        failed=failed,
        results=res,
        csv=csv,
    )


class _progress:
    """A progress bar of points done, failed and remaining (tqdm, on stderr)."""

    def __init__(self, total: int, skipped: int, name: str, show: bool) -> None:
        from tqdm import tqdm

        self.bar = tqdm(
            total=total,
            initial=skipped,
            desc=f"sweep {name}",
            unit="pt",
            disable=not show,
            file=sys.stderr,
        )
        self._post(0)

    def _post(self, failed: int) -> None:
        remaining = self.bar.total - self.bar.n
        self.bar.set_postfix(failed=failed, remaining=remaining, refresh=False)

    def update(self, failed: int) -> None:
        self.bar.update(1)
        self._post(failed)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


# --- Command line -----------------------------------------------------------------------


def _bytes(text: str) -> int:
    units = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}
    t = text.strip().lower().removesuffix("b").removesuffix("i")
    num, unit = (t[:-1], t[-1]) if t and t[-1] in units else (t, "")
    try:
        value = float(num) * units[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a size such as 2GiB") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"'{text}' is not a size such as 2GiB")
    return int(value)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``python -m arbor sweep``."""
    ap.add_argument("sweep", help="the sweep file (TOML)")
    ap.add_argument(
        "--out", required=True, help="results directory (created; resumed if it holds records)"
    )
    ap.add_argument("--jobs", "-j", type=int, help="points at once (default: the cores)")
    ap.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run the points as Ray tasks on the cluster at ADDRESS ('auto' for the one this "
        "machine belongs to), or 'local' to start a Ray instance for the run",
    )
    ap.add_argument("--task-cpus", type=float, default=1, help="CPUs per point (default 1)")
    ap.add_argument(
        "--task-memory",
        type=_bytes,
        default=2 << 30,
        help="memory each Ray task requests, e.g. 2GiB (default; 0: none)",
    )
    ap.add_argument("--retry-failed", action="store_true", help="run failed points again")
    ap.add_argument(
        "--check", action="store_true", help="check the sweep file and list its points, run nothing"
    )
    ap.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def main_args(a: argparse.Namespace) -> int:
    """Runs ``python -m arbor sweep`` with parsed arguments; returns the exit status."""
    try:
        if a.check:
            sw = load(a.sweep)
            pts = sw.points()
            print(
                f"{a.sweep}: {len(pts)} points, parameters {', '.join(sw.parameters) or '(none)'}"
            )
            for p in pts:
                print(f"  {p.id}  arbor {' '.join(p.argv())}")
            return 0
        s = run(
            a.sweep,
            a.out,
            jobs=a.jobs,
            ray=a.ray,
            task_cpus=a.task_cpus,
            task_memory=a.task_memory or None,
            retry_failed=a.retry_failed,
            progress=not a.quiet,
        )
    except SweepError as e:
        print(f"arbor: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("arbor: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    print(s)
    return 1 if s.failed else 0


def main(argv: Sequence[str] | None = None) -> int:
    """``arbor-sweep SWEEP.toml --out DIR ...`` (the same as ``python -m arbor sweep``)."""
    ap = argparse.ArgumentParser(
        prog="arbor-sweep", description=__doc__.split("\n\n")[0] if __doc__ else None
    )
    add_arguments(ap)
    return main_args(ap.parse_args(argv))
