"""CPU time of :meth:`arbor.RayCaster.intersect` and of
:meth:`arbor.RayCaster.closest_primitives` on the ray sets of ``arbor bench trace`` (a
640x360 render's primary rays and its diffuse bounce rays, in tile order), alone: the
quick measure for comparing two builds of the extension module (install one, run, install
the other, run, and alternate).

    RAYON_NUM_THREADS=1 python python/bench/intersect_rays.py [--scene PATH]
        [--kernel mbvh8] [--calls 7]

Prints, per ray set, the best CPU time of ``--calls`` calls of ``intersect`` and of
``closest_primitives`` (``out=`` buffers, so no allocation) in ns a ray, with the CPU
model. ``python/bench/raycast.py --bench-trace``
times the same calls next to ``arbor bench trace`` in one process.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("RAYON_NUM_THREADS", "1")

import arbor
from raycast import cpu_model  # the benchmark next to this one (same directory)

SCENES = Path(__file__).resolve().parents[2].parent / "shared" / "scenes"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=str(SCENES / "dragon.ply"))
    p.add_argument("--kernel", default="mbvh8")
    p.add_argument("--calls", type=int, default=7)
    a = p.parse_args(argv)
    if a.calls < 1:
        p.error("--calls must be at least 1")
    scene = arbor.open_scene(a.scene)
    mesh = scene.mesh()
    v, ix = mesh.vertices, mesh.indices
    rc = arbor.RayCaster(v, ix, kernel=a.kernel)
    rs = arbor.camera_rays(scene.camera, 640, 360, "diffuse", bvh=rc.bvh, vertices=v, indices=ix)
    print(f"{cpu_model()}; {a.scene}; kernel {a.kernel}; best of {a.calls} calls (CPU time)")
    for kind, sel in (("primary", rs.bounce == 0), ("diffuse", rs.bounce > 0)):
        args = (rs.origins[sel], rs.directions[sel], rs.tmin[sel], rs.tmax[sel])
        hits = rc.intersect(*args)
        ids = rc.closest_primitives(*args)
        n = int(sel.sum())
        best = [float("inf"), float("inf")]
        for _ in range(a.calls):
            for k, call in enumerate(
                (
                    lambda: rc.intersect(*args, out=hits),
                    lambda: rc.closest_primitives(*args, out=ids),
                )
            ):
                t0 = time.process_time()
                call()
                best[k] = min(best[k], time.process_time() - t0)
        for name, b in zip(("intersect", "closest_primitives"), best):
            print(
                f"{kind} {name}: {n} rays, {b / n * 1e9:.1f} ns a ray ({n / b / 1e6:.3f} Mrays/s)"
            )


if __name__ == "__main__":
    main()
