"""Sweeps: checking sweep files, running points in the pool and on local Ray, resuming,
the results tables and the plot."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from arbor import plot, sweep

ROOT = Path(__file__).resolve().parents[2]

SMALL = """
command = "sim mergetree"
scenes = ["proc:cloth?n=3000&seed=1", "proc:skinned?n=2000&seed=3"]
[options]
dram = "simple:lpddr3-1600-1x64"
[grid]
"set.m" = [1024, 2048]
[zip]
"set.b" = [8, 16]
"set.presorters" = [4, 8]
"""


def write(tmp: Path, text: str, name: str = "sweep.toml") -> Path:
    p = tmp / name
    p.write_text(text)
    return p


def test_points_cross_the_grid_and_zip_the_zip(tmp_path: Path) -> None:
    sw = sweep.load(write(tmp_path, SMALL))
    pts = sw.points()
    assert len(pts) == 2 * 2 * 2
    assert sw.parameters == ["dram", "set.m", "set.b", "set.presorters"]
    combos = {(p.scene, dict(p.params)["set.m"], dict(p.params)["set.b"]) for p in pts}
    assert len(combos) == 8
    for p in pts:
        d = dict(p.params)
        assert (d["set.b"], d["set.presorters"]) in {(8, 4), (16, 8)}
    assert len({p.id for p in pts}) == 8
    assert pts[0].argv()[:3] == ["sim", "mergetree", "proc:cloth?n=3000&seed=1"]
    assert "--set" in pts[0].argv() and pts[0].argv()[-1] == "--json"


def test_ranges(tmp_path: Path) -> None:
    text = """
command = "sim dram"
[grid]
bytes = { start = 4096, stop = 32768, factor = 2 }
request_bytes = { start = 32, stop = 128, step = 32 }
unit_mhz = { start = 500.0, stop = 1000.0, step = 250.0 }
"""
    sw = sweep.load(write(tmp_path, text))
    assert sw.grid["bytes"] == [4096, 8192, 16384, 32768]
    assert sw.grid["request_bytes"] == [32, 64, 96, 128]
    assert sw.grid["unit_mhz"] == [500.0, 750.0, 1000.0]
    assert len(sw.points()) == 4 * 4 * 3


BAD = [
    ("bogus = 1\n" + SMALL, "bogus: unknown key"),
    (SMALL.replace('"set.m" = [1024, 2048]', '"set.m" = []'), "grid.set.m: empty list"),
    (
        SMALL.replace('"set.m" = [1024, 2048]', '"set.nosuchkey" = [1]'),
        "grid.set.nosuchkey: value 1:",
    ),
    (
        SMALL.replace('"set.m" = [1024, 2048]', "frobnicate = [1]"),
        "grid.frobnicate: value 1: unexpected argument '--frobnicate'",
    ),
    (
        SMALL.replace('"proc:cloth?n=3000&seed=1"', '"missing/scene.ply"'),
        "scenes[0]: 'missing/scene.ply' does not exist",
    ),
    (
        SMALL.replace('"set.presorters" = [4, 8]', '"set.presorters" = [4, 8, 2]'),
        "zip.set.presorters: has 3 values but zip.set.b has 2",
    ),
    (
        SMALL.replace('dram = "simple:lpddr3-1600-1x64"', 'dram = "ddr9"'),
        'options.dram: value "ddr9":',
    ),
    (
        SMALL.replace('"set.m" = [1024, 2048]', '"set.m" = { start = 1, stop = 8, step = -1 }'),
        "grid.set.m: a step of -1 never goes",
    ),
    (
        SMALL.replace('"set.m" = [1024, 2048]', '"set.m" = { start = 1, stop = 8 }'),
        "grid.set.m: a range has keys",
    ),
    (
        SMALL.replace("[options]\ndram", '[options]\n"set.m" = 4096\ndram'),
        "grid.set.m: is also given in options",
    ),
    (
        SMALL.replace('command = "sim mergetree"', 'command = "render"'),
        "command: 'render' cannot be swept",
    ),
    (SMALL.replace("scenes = [", "scenes = []\nx = ["), "x: unknown key"),
    ('command = "sim mergetree"\n', "scenes: missing"),
    ("command = [", "not a TOML file"),
]


@pytest.mark.parametrize("text,expected", BAD)
def test_bad_sweep_files_fail_before_anything_runs(
    tmp_path: Path, text: str, expected: str
) -> None:
    path = write(tmp_path, text)
    out = tmp_path / "out"
    with pytest.raises(sweep.SweepError) as ei:
        sweep.run(path, out, progress=False)
    msg = str(ei.value)
    assert msg.startswith(f"{path}: "), msg
    assert expected in msg, msg
    assert not out.exists(), "a bad sweep file must not start the run"


def test_command_line_reports_a_bad_file(tmp_path: Path) -> None:
    path = write(tmp_path, SMALL.replace('"set.m" = [1024, 2048]', '"set.m" = []'))
    r = subprocess.run(
        [sys.executable, "-m", "arbor", "sweep", str(path), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert (
        r.stderr.strip()
        == f"arbor: error: {path}: grid.set.m: empty list: a grid parameter needs at least one value"
    )


def by_id(out: Path) -> dict[str, dict[str, object]]:
    return {k: sweep.deterministic(v) for k, v in sweep.read_records(out).items()}


def test_pool_resume_and_results(tmp_path: Path) -> None:
    path = write(tmp_path, SMALL)
    out = tmp_path / "out"
    s = sweep.run(path, out, jobs=2, progress=False)
    assert (s.points, s.ran, s.skipped, s.failed) == (8, 8, 0, 0)
    first = by_id(out)
    assert len(first) == 8
    for rec in first.values():
        assert rec["status"] == "ok", rec
        doc = rec["document"]
        assert isinstance(doc, dict) and doc["tree_matches_software"] is True
        params = rec["params"]
        assert isinstance(params, dict) and doc["config"]["m"] == params["set.m"]
    # Run again: everything is there, nothing runs.
    s = sweep.run(path, out, jobs=2, progress=False)
    assert (s.ran, s.skipped) == (0, 8)
    # Interrupted mid-write: keep three records and half of the fourth line.
    lines = (out / "records.jsonl").read_bytes().splitlines(keepends=True)
    (out / "records.jsonl").write_bytes(b"".join(lines[:3]) + lines[3][:40])
    s = sweep.run(path, out, jobs=2, progress=False)
    assert (s.ran, s.skipped) == (5, 3)
    assert by_id(out) == first
    # The tables hold one row per point.
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    tbl = pq.read_table(out / "results.parquet")
    assert tbl.num_rows == 8
    cols = set(tbl.column_names)
    for c in (
        "scene",
        "param.set.m",
        "param.dram",
        "status",
        "arbor_version",
        "result.cycles",
        "result.ms",
        "document",
    ):
        assert c in cols, c
    assert str(tbl.schema.field("result.cycles").type) == "int64"
    assert str(tbl.schema.field("param.set.m").type) == "int64"
    assert pacsv.read_csv(out / "results.csv").num_rows == 8
    # The plot of the table.
    svg = plot.plot(
        out,
        "param.set.m",
        ["result.ms", "result.bytes_read"],
        tmp_path / "p.svg",
        facet="param.set.b",
    )
    text = svg.read_text()
    assert "<svg" in text and text.count("<path") > 4
    with pytest.raises(plot.PlotError, match="'result.dram' has no numeric values"):
        plot.plot(out, "param.set.m", "result.dram", tmp_path / "r.svg")
    with pytest.raises(plot.PlotError, match="no column 'result.nope'"):
        plot.plot(out, "param.set.m", "result.nope", tmp_path / "q.svg")


def test_a_failed_point_is_recorded_and_the_sweep_goes_on(tmp_path: Path) -> None:
    text = """
command = "sim mergetree"
scenes = ["proc:cloth?n=2000&seed=1", "proc:cloth?n=-4"]
[grid]
"set.m" = [1024]
"""
    path = write(tmp_path, text)
    s = sweep.run(path, tmp_path / "out", jobs=1, progress=False)
    assert (s.points, s.failed) == (2, 1)
    recs = list(sweep.read_records(tmp_path / "out").values())
    bad = [r for r in recs if r["status"] == "failed"]
    assert len(bad) == 1 and bad[0]["scene"] == "proc:cloth?n=-4"
    assert "n" in bad[0]["error"] and bad[0]["document"] is None
    # Failed points are skipped on resume unless asked to run again.
    assert sweep.run(path, tmp_path / "out", progress=False).ran == 0
    assert sweep.run(path, tmp_path / "out", retry_failed=True, progress=False).ran == 1


def test_local_ray_gives_the_pools_records(tmp_path: Path) -> None:
    ray = pytest.importorskip(
        "ray", reason="ray is part of the test set-up (pip install './python[test]')"
    )
    path = write(tmp_path, SMALL)
    sweep.run(path, tmp_path / "pool", jobs=2, progress=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        s = sweep.run(path, tmp_path / "ray", ray="local", task_memory=256 << 20, progress=False)
    finally:
        ray.shutdown()
    assert (s.ran, s.failed) == (8, 0)
    pool, on_ray = by_id(tmp_path / "pool"), by_id(tmp_path / "ray")
    assert len(pool) == 8
    assert on_ray == pool


def test_the_example_sweep_checks(tmp_path: Path) -> None:
    sw = sweep.load(ROOT / "examples" / "sweeps" / "mergetree.toml")
    pts = sw.points()
    assert len(pts) == 36
    assert {dict(p.params)["set.m"] for p in pts} == {1024, 2048, 4096, 8192}
    # Scene paths resolve relative to the sweep file, ids do not depend on where it lies.
    assert pts[0].scene == "../../scenes/CesiumMan.glb"
    assert pts[0].scene_path == str(ROOT / "examples" / "sweeps" / "../../scenes/CesiumMan.glb")
    assert json.loads(json.dumps(pts[0].id)) == pts[0].id
