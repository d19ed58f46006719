"""`arbor.run` and the `sim_*` helpers: the command line's documents and errors, in-process."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

import arbor
from arbor import cli, sweep

ROOT = Path(__file__).resolve().parents[2]
SCENE = "proc:cloth?n=3000&seed=2"


def arbor_binary() -> Path | None:
    for profile in ("release", "debug"):
        p = ROOT / "target" / profile / "arbor"
        if p.exists():
            return p
    return None


def test_run_returns_the_json_document() -> None:
    docs = arbor.run("sim", "dram", "--bytes", "8192", "--pattern", "random", "--json")
    assert len(docs) == 1
    d = docs[0]
    assert d["schema"] == "arbor.sim.dram.v1"
    assert d["requests"] == 8192 // 64 and d["request_bytes"] == 64


def test_sim_mergetree_builds_the_software_tree() -> None:
    d = arbor.sim_mergetree(SCENE, dram="simple:lpddr3-1600-1x64", set={"m": 2048})
    assert d["schema"] == "arbor.sim.mergetree.v1"
    assert d["config"]["m"] == 2048
    assert d["tree_matches_software"] is True
    assert d["triangles"] > 2900
    assert d["cycles"] > 0 and d["bytes_read"] > 0
    # The keyword form and the command-line form are one run.
    same = arbor.run(
        "sim", "mergetree", SCENE, "--dram", "simple:lpddr3-1600-1x64", "--set", "m=2048", "--json"
    )[0]
    assert sweep.deterministic({"document": d}) == sweep.deterministic({"document": same})


def test_documents_equal_the_binarys() -> None:
    exe = arbor_binary()
    if exe is None:
        pytest.skip("no target/*/arbor binary built (cargo build first); not compared")
    args = ["sim", "mergetree", SCENE, "--dram", "simple:lpddr3-1600-2x64", "--json"]
    out = subprocess.run([str(exe), *args], capture_output=True, text=True, check=True).stdout
    from_binary = json.loads(out)
    from_python = arbor.run(*args)[0]
    assert sweep.deterministic({"document": from_binary}) == sweep.deterministic(
        {"document": from_python}
    )


@pytest.mark.parametrize(
    "args",
    [
        ["info", "no-such-scene.ply"],
        ["sim", "mergetree", SCENE, "--set", "bogus=1"],
        ["sim", "mergetree", SCENE, "--dram", "ddr9-9999"],
        ["sim", "mergetree"],
        ["sim", "rtunit", SCENE, "--rays", "sideways"],
        ["build", "proc:nosuchscene"],
    ],
)
def test_errors_are_the_command_lines_one_line_message(args: list[str]) -> None:
    with pytest.raises(arbor.ArborError) as ei:
        arbor.run(*args)
    msg = str(ei.value)
    assert msg and "\n" not in msg
    exe = arbor_binary()
    if exe is None:
        return  # the message is checked for shape only; no binary to compare with
    err = subprocess.run([str(exe), *args], capture_output=True, text=True).stderr
    if err.startswith("arbor: error: "):
        # The binary adds where to look after an argument error; the message is the same.
        assert err.strip() in (
            f"arbor: error: {msg}",
            f"arbor: error: {msg} (see 'arbor --help')",
        )
    else:  # clap's own message: "error: ..." and usage lines
        assert " ".join(err.split()).startswith("error: " + msg)


def test_check_needs_no_scene() -> None:
    arbor.check("sim", "mergetree", "no-such-file.ply", "--set", "m=4096")
    with pytest.raises(arbor.ArborError, match="bogus"):
        arbor.check("sim", "mergetree", "no-such-file.ply", "--set", "bogus=1")
    with pytest.raises(arbor.ArborError, match="unexpected argument '--nope'"):
        arbor.check("build", "x.ply", "--nope")


def test_command_line_rules() -> None:
    args = cli.command_line(
        ["sim", "rtunit"],
        "s.ply",
        {"mbvh4_builder": "collapse", "no_check": True, "fifo_sizing": False, "time": 0.25},
        {"trv_pipelines": 2},
    )
    assert args == [
        "sim",
        "rtunit",
        "s.ply",
        "--mbvh4-builder",
        "collapse",
        "--no-check",
        "--time",
        "0.25",
        "--set",
        "trv_pipelines=2",
        "--json",
    ]
    assert cli.option_args("set.m", 4096) == ["--set", "m=4096"]
    assert cli.option_args("set.toplevel_sah", True) == ["--set", "toplevel_sah=true"]
    with pytest.raises(ValueError):
        cli.option_args("Bad Name", 1)
    with pytest.raises(ValueError):
        cli.value_text(float("nan"))


def test_report_sensitivity_from_python(tmp_path: Path) -> None:
    docs = arbor.run(
        "report",
        "sensitivity",
        "--scenes",
        "proc:hairball?n=3000&seed=2",
        "--p4-scene",
        "none",
        "--only",
        "fpu_energy",
        "--width",
        "32",
        "--height",
        "24",
        "--sample",
        "1",
        "--out",
        str(tmp_path),
        "--json",
    )
    assert len(docs) == 1
    d = docs[0]
    assert d["schema"] == "arbor.report.sensitivity.v1"
    assert [v["key"] for v in d["variants"]] == ["default", "fpu_energy"]
    # The default simulates 11 runs for Table VIII and 2 more for MergeTree on [P2]'s
    # slow and fast systems (the medium one is Table VIII's, reused); the FPU variant
    # reuses all 14.
    assert (d["simulated"], d["reused"]) == (13, 15)
    for r in d["rows"]:
        assert r["low"] <= r["default"] <= r["high"]
        # The thesis has every figure but those of scenes it does not have.
        per_scene = r["figure"].startswith(("III ", "VI "))
        assert (r["thesis"] is None) == per_scene, r
