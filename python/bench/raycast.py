"""Ray casting from Python: :class:`arbor.RayCaster` next to Embree (through embreex, as
trimesh uses it) and next to the function API :func:`arbor.trace`, in one process, on one
scene, with a fixed number of worker threads.

    python python/bench/raycast.py [--scene PATH] [--rays 1000000] [--threads 1]
        [--rounds 3] [--trimesh-rays 100] [--extras] [--bench-trace]
        [--record python/bench/records.jsonl]

Measured (best of ``--rounds``, wall time):

- the cost of one call with one ray on the prepared structure (``one_ray_us``), against
  embreex's ``scene.run`` and the function API (which prepares the tree on every call);
- throughput on ``--rays`` random rays (from a sphere around the scene towards random
  points in its box; incoherent) in Mrays/s, closest hit (``intersect``: t, primitive,
  barycentrics, normal and location) and any hit (``occluded``), per kernel, against
  embreex with ``output=1`` (t, primitive, barycentrics, normal) and without (primitive
  ids only);
- trimesh's own intersector (``trimesh.ray.ray_triangle``, float64 numpy over an R-tree,
  what trimesh uses without embreex) on the first ``--trimesh-rays`` of the random rays,
  one ray per call (its memory grows with the rays of a call);
- with ``--extras``: an animation traced frame by frame from Python (``refit`` then
  ``intersect`` in a loop) against :meth:`arbor.RayCaster.trace_frames` (the same frames
  in one call), on the scene and on a small cloth; instances (:class:`arbor.InstanceCaster`,
  16 instances of Bunny) against one flat ``RayCaster`` over their world-space triangles
  (build, a transform update against a flat rebuild, random rays); and
  ``contains_points`` on a closed icosphere against trimesh's ``contains`` (which uses
  Embree when embreex is installed);
- with ``--bench-trace``: the ray sets of ``arbor bench trace`` (a 640x360 render's
  primary rays and its diffuse bounce rays, in tile order) through the same kernels from
  Python (``intersect``, all its columns, and ``closest_primitives``, the primitive
  alone, as the benchmark keeps little more than that), next to ``arbor bench trace --threads N`` run in the same process on the same
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


Report = Callable[..., None]


def trimesh_row(
    v: np.ndarray,
    ix: np.ndarray,
    o: np.ndarray,
    d: np.ndarray,
    ref: Any,
    rec: dict[str, Any],
    report: Report,
) -> None:
    """trimesh's float64 numpy intersector (R-tree candidates) on the first rays."""
    try:
        import trimesh
    except ImportError:
        rec["trimesh"] = None
        print("trimesh not installed: no trimesh row", file=sys.stderr)
        return
    rec["trimesh"] = trimesh.__version__
    t0 = time.perf_counter()
    m = trimesh.Trimesh(np.asarray(v, np.float64), np.asarray(ix, np.int64), process=False)
    tri = trimesh.ray.ray_triangle.RayMeshIntersector(m)
    tri.intersects_first(o[:1], d[:1])  # builds its R-tree
    build_ms = (time.perf_counter() - t0) * 1e3
    # One ray per call: its candidate triangles (those whose boxes overlap the ray's box)
    # are arrays of float64 triangles, about 60 MB per ray on Dragon; 500 rays at once
    # took 23 GB.
    first = np.empty(len(o), np.int64)

    def run() -> None:
        for i in range(len(o)):
            first[i] = tri.intersects_first(o[i : i + 1], d[i : i + 1])[0]

    t = best(run, 1)
    n = len(o)
    ours = np.where(ref.hit[:n], ref.primitive[:n].astype(np.int64), -1)
    report(
        "trimesh random",
        rays=float(n),
        build_ms=build_ms,
        first_krays=n / t / 1e3,
        first_krays_cpu=n / LAST_CPU[0] / 1e3,
        agreement_with_arbor=float(np.mean(first == ours)),
    )


def extras(
    arbor: Any, v: np.ndarray, ix: np.ndarray, rounds: int, rec: dict[str, Any], report: Report
) -> None:
    """Animation frames, instances and the inside test (see the module header)."""

    def wave(verts: np.ndarray, frames: int, amount: float) -> np.ndarray:
        """`frames` copies of `verts`, each warped a little more."""
        base = np.asarray(verts, np.float64)
        size = float(np.ptp(base, axis=0).max())
        out = []
        for k in range(frames):
            s = amount * size * k / max(frames - 1, 1)
            off = np.stack([np.sin(base[:, 1] * 7 / size), np.cos(base[:, 2] * 5 / size)], 1)
            moved = base.copy()
            moved[:, :2] += s * off
            out.append(moved.astype(np.float32))
        return np.stack(out)

    # Animation: a Python loop of refit + intersect against one trace_frames call.
    cloth = arbor.open_scene("proc:cloth?n=2000&seed=1").mesh()
    for name, (verts, faces, frames, nrays) in {
        "scene": (v, ix, 8, 10_000),
        "cloth": (cloth.vertices, cloth.indices, 200, 100),
    }.items():
        anim = wave(verts, frames, 0.02)
        ro, rd = random_rays(verts, nrays, seed=3)
        rc = arbor.RayCaster(verts, faces, kernel="bvh2")

        def loop() -> None:
            for k in range(frames):
                rc.refit(anim[k])
                rc.intersect(ro, rd)

        t_loop = best(loop, rounds)
        c_loop = LAST_CPU[0]
        t_batch = best(lambda: rc.trace_frames(anim, ro, rd), rounds)
        report(
            f"frames {name}",
            triangles=float(len(faces)),
            frames=float(frames),
            rays_per_frame=float(nrays),
            loop_ms_per_frame=t_loop / frames * 1e3,
            trace_frames_ms_per_frame=t_batch / frames * 1e3,
            speedup=t_loop / t_batch,
            speedup_cpu=c_loop / LAST_CPU[0],
        )

    # Instances: 16 bunnies on a grid, each turned; against one flat tree over them.
    bunny = arbor.open_scene(str(DEFAULT_SCENE.parent / "bunny.ply")).mesh()
    bv, bf = np.asarray(bunny.vertices), np.asarray(bunny.indices)
    size = float(np.ptp(bv, axis=0).max())

    def placements(turn: float) -> np.ndarray:
        xf = np.zeros((16, 3, 4))
        for i in range(16):
            a = turn + 0.4 * i
            c, s_ = np.cos(a), np.sin(a)
            xf[i, :3, :3] = [[c, 0, s_], [0, 1, 0], [-s_, 0, c]]
            xf[i, :3, 3] = [1.2 * size * (i % 4), 0, 1.2 * size * (i // 4)]
        return xf

    def world(xf: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        b64 = bv.astype(np.float64)
        return [((b64 @ x[:3, :3].T + x[:3, 3]).astype(np.float32), bf) for x in xf]

    xf0, xf1 = placements(0.0), placements(0.3)
    t0 = time.perf_counter()
    ic = arbor.InstanceCaster([(bv, bf)], xf0, kernel="bvh2")
    ic_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    flat = arbor.RayCaster.from_meshes(world(xf0), kernel="bvh2")
    flat_build = time.perf_counter() - t0
    t_update = best(lambda: ic.set_transforms(xf1), rounds)
    t_rebuild = best(lambda: arbor.RayCaster.from_meshes(world(xf1), kernel="bvh2"), 1)
    flat = arbor.RayCaster.from_meshes(world(xf1), kernel="bvh2")
    allv = np.concatenate([w[0] for w in world(xf1)])
    ro, rd = random_rays(allv, 200_000, seed=4)
    t_inst = best(lambda: ic.intersect(ro, rd), rounds)
    c_inst = LAST_CPU[0]
    t_flat = best(lambda: flat.intersect(ro, rd), rounds)
    hi, hf = ic.intersect(ro, rd), flat.intersect(ro, rd)
    same = float(np.mean((hi.hit == hf.hit) & (~hi.hit | (hi.instance == hf.geometry))))
    report(
        "instances 16 bunny",
        world_triangles=float(16 * len(bf)),
        build_ms=ic_build * 1e3,
        flat_build_ms=flat_build * 1e3,
        set_transforms_ms=t_update * 1e3,
        flat_rebuild_ms=t_rebuild * 1e3,
        intersect_mrays=len(ro) / t_inst / 1e6,
        intersect_mrays_cpu=len(ro) / c_inst / 1e6,
        flat_intersect_mrays=len(ro) / t_flat / 1e6,
        flat_intersect_mrays_cpu=len(ro) / LAST_CPU[0] / 1e6,
        same_hit_and_instance=same,
    )

    # Inside test on a closed mesh against trimesh's (Embree's rays when installed).
    try:
        import trimesh
    except ImportError:
        return
    sphere = trimesh.creation.icosphere(subdivisions=6)
    pts = np.random.default_rng(5).uniform(-1.2, 1.2, size=(100_000, 3))
    rc = arbor.RayCaster(sphere.vertices.astype(np.float32), sphere.faces)
    t_ours = best(lambda: rc.contains_points(pts), rounds)
    c_ours = LAST_CPU[0]
    sphere.contains(pts[:10])  # builds trimesh's intersector
    rec["trimesh_contains_intersector"] = type(sphere.ray).__module__
    t_tm = best(lambda: sphere.contains(pts), 1)
    agree = float(np.mean(rc.contains_points(pts) == sphere.contains(pts)))
    report(
        "contains icosphere",
        triangles=float(len(sphere.faces)),
        points=float(len(pts)),
        arbor_mpoints=len(pts) / t_ours / 1e6,
        arbor_mpoints_cpu=len(pts) / c_ours / 1e6,
        trimesh_mpoints=len(pts) / t_tm / 1e6,
        trimesh_mpoints_cpu=len(pts) / LAST_CPU[0] / 1e6,
        agreement=agree,
    )


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default=str(DEFAULT_SCENE))
    p.add_argument("--rays", type=int, default=1_000_000)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--trimesh-rays", type=int, default=100)
    p.add_argument("--extras", action="store_true")
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

    if a.trimesh_rays > 0:
        try:
            trimesh_row(v, ix, o[: a.trimesh_rays], d[: a.trimesh_rays], ref, rec, report)
        except MemoryError:
            rec["trimesh"] = "out of memory"
            print("trimesh ran out of memory: no trimesh row", file=sys.stderr)
    if a.extras:
        extras(arbor, v, ix, a.rounds, rec, report)

    if a.bench_trace:
        # The ray sets of `arbor bench trace`: a 640x360 render's primary rays and its
        # diffuse bounce rays (4 bounces, seed 1), in the renderer's tile order.
        rs = arbor.camera_rays(scene.camera, 640, 360, "diffuse", bvh=bvh, vertices=v, indices=ix)
        for kind, sel in (("primary", rs.bounce == 0), ("diffuse", rs.bounce > 0)):
            args = (rs.origins[sel], rs.directions[sel], rs.tmin[sel], rs.tmax[sel])
            for kernel, rc in casters.items():
                hits = rc.intersect(*args)
                t = best(lambda: rc.intersect(*args, out=hits), a.rounds)
                cpu = LAST_CPU[0]
                ids = rc.closest_primitives(*args)
                t_ids = best(lambda: rc.closest_primitives(*args, out=ids), a.rounds)
                report(
                    f"arbor {kernel} {kind}",
                    rays=float(sel.sum()),
                    intersect_mrays=float(sel.sum()) / t / 1e6,
                    intersect_mrays_cpu=float(sel.sum()) / cpu / 1e6,
                    closest_primitives_mrays=float(sel.sum()) / t_ids / 1e6,
                    closest_primitives_mrays_cpu=float(sel.sum()) / LAST_CPU[0] / 1e6,
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
