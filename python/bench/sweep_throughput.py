"""Sweep throughput: points per second and per-point overhead of the local process pool
and of local Ray, side by side in one run, on this machine.

    python python/bench/sweep_throughput.py [--jobs 2] [--record python/bench/records.jsonl]

Two sweeps per executor: ``sim dram`` points that move 4 KiB (almost no work, so the time
is the executor's) at two sizes, N and 2N points. The per-point overhead is the slope,
(T(2N) - T(N)) / N x jobs, in worker-seconds per point; the start-up (spawning the pool's
workers, or starting Ray and its workers) is the intercept. Then the example MergeTree
sweep (36 points of real work) on each, as points per second. Each measurement runs in a
fresh output directory. The CPU model, core count and versions go with the record.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import arbor
from arbor import sweep

ROOT = Path(__file__).resolve().parents[2]


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def trivial_sweep(tmp: Path, n: int) -> Path:
    p = tmp / f"trivial-{n}.toml"
    p.write_text(
        'command = "sim dram"\n[options]\nbytes = 4096\n'
        f"[grid]\nseed = {{ start = 1, stop = {n}, step = 1 }}\n"
    )
    return p


def timed(path: Path, out: Path, jobs: int, ray: str | None) -> float:
    start = time.perf_counter()
    s = sweep.run(path, out, jobs=jobs, ray=ray, task_memory=256 << 20, progress=False)
    wall = time.perf_counter() - start
    if s.failed or s.ran != s.points:
        raise SystemExit(f"benchmark sweep {path} did not run cleanly: {s}")
    return wall


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--n", type=int, default=200, help="points of the smaller trivial sweep")
    ap.add_argument("--record", type=Path, help="append the result (JSON line) to this file")
    a = ap.parse_args()
    import ray as ray_mod

    result: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d"),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "jobs": a.jobs,
        "arbor": arbor.__version__,
        "python": platform.python_version(),
        "ray": ray_mod.__version__,
    }
    example = ROOT / "examples" / "sweeps" / "mergetree.toml"
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for name, ray in (("pool", None), ("ray_local", "local")):
            t1 = timed(trivial_sweep(tmp, a.n), tmp / f"{name}-1", a.jobs, ray)
            t2 = timed(trivial_sweep(tmp, 2 * a.n), tmp / f"{name}-2", a.jobs, ray)
            per_point = (t2 - t1) / a.n * a.jobs
            startup = t1 - a.n * per_point / a.jobs
            tex = timed(example, tmp / f"{name}-example", a.jobs, ray)
            recs = sweep.read_records(tmp / f"{name}-example").values()
            busy = sum(r["wall_s"] for r in recs)
            result[name] = {
                "trivial_points_per_s": round(2 * a.n / t2, 1),
                "overhead_ms_per_point": round(per_point * 1e3, 2),
                "startup_s": round(startup, 2),
                "example_wall_s": round(tex, 2),
                "example_points_per_s": round(36 / tex, 2),
                "example_busy_fraction": round(busy / (tex * a.jobs), 3),
            }
            print(name, json.dumps(result[name]))
    print(json.dumps(result))
    if a.record:
        with a.record.open("a") as f:
            f.write(json.dumps(result) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
