"""Ray casting from Python: :class:`arbor.RayCaster` next to Embree (through embreex, as
trimesh uses it) and next to the function API :func:`arbor.trace`, in one process, on one
scene, with a fixed number of worker threads.

    python python/bench/raycast.py [--scene PATH] [--rays 1000000] [--threads 1]
        [--rounds 3] [--bench-trace] [--record python/bench/records.jsonl]

Measured (best of ``--rounds``, wall time):

- the cost of one call with one ray on the prepared structure (``one_ray_us``), against
  embreex's ``scene.run`` and the function API (which prepares the tree on every call);
- throughput on ``--rays`` random rays (from a sphere around the scene towards random
  points in its box; incoherent) in Mrays/s, closest hit (``intersect``: t, primitive,
  barycentrics, normal and location) and any hit (``occluded``), per kernel, against
  embreex with ``output=1`` (t, primitive, barycentrics, normal) and without (primitive
  ids only);
- with ``--bench-trace``: the ray sets of ``arbor bench trace`` (a 640x360 render's
  primary rays and its diffuse bounce rays, in tile order) through the same kernels from
  Python, next to ``arbor bench trace --threads N`` run in the same process on the same
  scene (the kernels with no Python layer; its CPU time counts worker threads only).

``--threads`` sets Arbor's worker pool (``RAYON_NUM_THREADS``, before arbor is imported);
embreex traces on the calling thread only, so compare at ``--threads 1``. The CPU model,
core count and versions go with the record.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

# numpy's BLAS threads spin after each call, taking a core from the tracers on a small
# machine and adding to the process CPU time measured; nothing here needs them.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402  (after the thread settings)

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_SCENE = ROOT.parent / "shared" / "scenes" / "dragon.ply"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


#: Process CPU seconds of the fastest round of the last `best` call: steadier than wall
#: time on a machine shared with other work (Arbor's work runs on its worker threads,
#: embreex's on the calling thread; process time counts both).
LAST_CPU = [0.0]


def best(f: Callable[[], Any], rounds: int) -> float:
    """Fastest of `rounds` timed calls, in wall seconds (its CPU time in LAST_CPU)."""
    times = []
    for _ in range(rounds):
        t0, c0 = time.perf_counter(), time.process_time()
        f()
        times.append((time.perf_counter() - t0, time.process_time() - c0))
    wall, LAST_CPU[0] = min(times)
    return wall


def per_call_us(f: Callable[[], Any], calls: int, rounds: int) -> float:
    """Mean time of one call over `calls` calls, best of `rounds`, in microseconds."""
    f()

    def many() -> None:
        for _ in range(calls):
            f()

    return best(many, rounds) / calls * 1e6


def random_rays(v: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = v.min(axis=0), v.max(axis=0)
    c, r = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    dirs = rng.normal(size=(n, 3))
    origins = c + r * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    targets = lo + rng.random((n, 3)) * (hi - lo)
    return origins.astype(np.float32), (targets - origins).astype(np.float32)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default=str(DEFAULT_SCENE))
    p.add_argument("--rays", type=int, default=1_000_000)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--bench-trace", action="store_true")
    p.add_argument("--record", type=Path, default=None)
    a = p.parse_args(argv)

    os.environ["RAYON_NUM_THREADS"] = str(a.threads)
    import arbor  # after RAYON_NUM_THREADS: the worker pool reads it once

    scene = arbor.open_scene(a.scene)
    mesh = scene.mesh()
    v, ix = mesh.vertices, mesh.indices
    rec: dict[str, Any] = {
        "bench": "raycast",
        "date": time.strftime("%Y-%m-%d"),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "threads": a.threads,
        "arbor": arbor.__version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scene": Path(a.scene).name,
        "triangles": len(ix),
        "rays": a.rays,
        "rounds": a.rounds,
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
    }
    out: dict[str, dict[str, float]] = {}

    def report(name: str, **fields: float) -> None:
        out[name] = {k: round(x, 3) for k, x in fields.items()}
        print(f"{name:<28}" + "  ".join(f"{k} {x:.3f}" for k, x in fields.items()), flush=True)

    o, d = random_rays(v, a.rays, seed=1)
    o1, d1 = o[:1].copy(), d[:1].copy()
    casters = {}
    for kernel in ("bvh2", "mbvh8"):
        t0 = time.perf_counter()
        casters[kernel] = arbor.RayCaster(v, ix, kernel=kernel)
        build_ms = (time.perf_counter() - t0) * 1e3
        rc = casters[kernel]
        report(
            f"arbor {kernel} one ray",
            build_ms=build_ms,
            intersect_us=per_call_us(lambda: rc.intersect(o1, d1), 2000, a.rounds),
            occluded_us=per_call_us(lambda: rc.occluded(o1, d1), 2000, a.rounds),
        )
    bvh = casters["bvh2"].bvh
    report(
        "arbor.trace one ray",
        us=per_call_us(lambda: arbor.trace(bvh, v, ix, o1, d1), 3, a.rounds),
    )

    ref = casters["bvh2"].intersect(o, d)
    for kernel, rc in casters.items():
        hits = rc.intersect(o, d)
        t_int = best(lambda: rc.intersect(o, d, out=hits), a.rounds)
        c_int = LAST_CPU[0]
        t_occ = best(lambda: rc.occluded(o, d), a.rounds)
        report(
            f"arbor {kernel} random",
            intersect_mrays=a.rays / t_int / 1e6,
            intersect_mrays_cpu=a.rays / c_int / 1e6,
            occluded_mrays=a.rays / t_occ / 1e6,
            occluded_mrays_cpu=a.rays / LAST_CPU[0] / 1e6,
            hit_fraction=float(ref.hit.mean()),
        )
    t_fn = best(lambda: arbor.trace(bvh, v, ix, o, d), 1)
    report("arbor.trace bvh2 random", mrays=a.rays / t_fn / 1e6)

    try:
        from embreex import rtcore_scene as rtcs  # type: ignore[import-untyped]
        from embreex.mesh_construction import TriangleMesh  # type: ignore[import-untyped]
    except ImportError:
        rec["embreex"] = None
        print("embreex not installed: no Embree rows", file=sys.stderr)
    else:
        import embreex

        rec["embreex"] = getattr(embreex, "__version__", "installed")
        t0 = time.perf_counter()
        es = rtcs.EmbreeScene()
        TriangleMesh(scene=es, vertices=np.ascontiguousarray(v[ix.astype(np.int64)]))
        es.run(o1, d1)  # Embree builds its tree on the first query
        build_ms = (time.perf_counter() - t0) * 1e3
        report(
            "embreex one ray",
            build_ms=build_ms,
            run_us=per_call_us(lambda: es.run(o1, d1), 2000, a.rounds),
            run_output_us=per_call_us(lambda: es.run(o1, d1, output=1), 2000, a.rounds),
        )
        ids = es.run(o, d)
        t_ids = best(lambda: es.run(o, d), a.rounds)
        c_ids = LAST_CPU[0]
        t_out = best(lambda: es.run(o, d, output=1), a.rounds)
        agree = float(np.mean(np.where(ref.hit, ref.primitive.astype(np.int64), -1) == ids))
        report(
            "embreex random",
            ids_mrays=a.rays / t_ids / 1e6,
            ids_mrays_cpu=a.rays / c_ids / 1e6,
            output_mrays=a.rays / t_out / 1e6,
            output_mrays_cpu=a.rays / LAST_CPU[0] / 1e6,
            agreement_with_arbor=agree,
        )

    if a.bench_trace:
        # The ray sets of `arbor bench trace`: a 640x360 render's primary rays and its
        # diffuse bounce rays (4 bounces, seed 1), in the renderer's tile order.
        rs = arbor.camera_rays(scene.camera, 640, 360, "diffuse", bvh=bvh, vertices=v, indices=ix)
        for kind, sel in (("primary", rs.bounce == 0), ("diffuse", rs.bounce > 0)):
            args = (rs.origins[sel], rs.directions[sel], rs.tmin[sel], rs.tmax[sel])
            for kernel, rc in casters.items():
                hits = rc.intersect(*args)
                t = best(lambda: rc.intersect(*args, out=hits), a.rounds)
                report(
                    f"arbor {kernel} {kind}",
                    rays=float(sel.sum()),
                    intersect_mrays=float(sel.sum()) / t / 1e6,
                    intersect_mrays_cpu=float(sel.sum()) / LAST_CPU[0] / 1e6,
                )
        with tempfile.TemporaryDirectory() as tmp:
            arbor.run(
                "bench",
                "trace",
                a.scene,
                "--threads",
                str(a.threads),
                "--runs",
                str(a.rounds),
                "--out",
                tmp,
            )
            doc = json.loads((Path(tmp) / "bench-trace.json").read_text())
        for row in doc["rows"]:
            report(
                f"bench trace {row['tracer']} {row['rays']}",
                rays=row["ray_count"],
                mrays=row["mrays_per_s"],
                mrays_cpu=row["mrays_per_cpu_s"],
            )

    rec["results"] = out
    if a.record:
        with a.record.open("a") as f:
            f.write(json.dumps(rec) + "\n")
        print(f"recorded in {a.record}")


if __name__ == "__main__":
    main()
