"""The prepared ray caster (`arbor.RayCaster`): closest and any hits against a float64
numpy brute force and the crate's own brute force, refit in place, stale trees, pickling,
`out=` buffers and threads."""

from __future__ import annotations

import pickle
import threading
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest

import arbor
from arbor import ArborError, RayCaster, RayHits

ROOT = Path(__file__).resolve().parents[2]
BUNNY = ROOT.parent / "shared" / "scenes" / "bunny.ply"
CLOTH = "proc:cloth?n=2000&seed=1"
Kernel = Literal["bvh2", "mbvh4", "mbvh8", "cbvh"]
KERNELS: tuple[Kernel, ...] = ("bvh2", "mbvh4", "mbvh8", "cbvh")


@pytest.fixture(scope="module")
def mesh() -> arbor.Mesh:
    return arbor.open_scene(CLOTH).mesh(frame=5)


def brute_force64(
    o: np.ndarray, d: np.ndarray, v: np.ndarray, ix: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Closest hit of each ray among all triangles, Moller-Trumbore in float64: (t, prim);
    t = inf and prim = -1 for a miss."""
    tri = np.asarray(v, np.float64)[np.asarray(ix, np.int64)]
    o64 = o.astype(np.float64)[:, None, :]
    d64 = d.astype(np.float64)[:, None, :]
    p0, e1, e2 = (
        tri[None, :, 0],
        tri[None, :, 1] - tri[None, :, 0],
        tri[None, :, 2] - tri[None, :, 0],
    )
    pv = np.cross(d64, e2)
    det = np.sum(e1 * pv, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tv = o64 - p0
        u = np.sum(tv * pv, axis=-1) * inv
        qv = np.cross(tv, e1)
        w = np.sum(d64 * qv, axis=-1) * inv
        t = np.sum(e2 * qv, axis=-1) * inv
    ok = (np.abs(det) > 1e-12) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t >= 0)
    t = np.where(ok, t, np.inf)
    prim = np.argmin(t, axis=1)
    best = t[np.arange(len(prim)), prim]
    return best, np.where(np.isfinite(best), prim, -1)


def rays_at(v: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rays from a sphere around the vertices towards random points in their box."""
    rng = np.random.default_rng(seed)
    lo, hi = v.min(axis=0), v.max(axis=0)
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo)
    dirs = rng.normal(size=(n, 3))
    origins = c + r * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    targets = lo + rng.random((n, 3)) * (hi - lo)
    return origins.astype(np.float32), (targets - origins).astype(np.float32)


def moved(v: np.ndarray, k: int) -> np.ndarray:
    """The vertices warped (non-rigidly) by an amount that depends on `k`."""
    v = np.asarray(v, np.float64)
    s = 0.1 * k
    out = v + s * np.stack([np.sin(v[:, 1] * 3), np.cos(v[:, 2] * 2), np.sin(v[:, 0] * 4)], 1)
    return out.astype(np.float32)


def check_hits(h: RayHits, o: np.ndarray, d: np.ndarray, v: np.ndarray, ix: np.ndarray) -> None:
    """`h` against the float64 brute force and against itself (normal, location, u, v)."""
    t, prim = brute_force64(o, d, v, ix)
    assert (prim >= 0).sum() > len(o) // 10  # there are hits to compare
    agree = h.hit == (prim >= 0)
    assert agree.mean() > 0.98  # the rest graze an edge within rounding
    both = agree & h.hit
    np.testing.assert_allclose(h.t[both], t[both], rtol=1e-4)
    same = both & (h.primitive == prim)
    assert same.sum() >= 0.97 * both.sum()  # the rest are ties at shared edges
    assert np.isinf(h.t[~h.hit]).all() and (h.primitive[~h.hit] == arbor.NO_HIT).all()
    assert np.isnan(h.normal[~h.hit]).all() and np.isnan(h.location[~h.hit]).all()
    # Location: on the ray at t, and the barycentric point of the triangle.
    tri = np.asarray(v, np.float64)[np.asarray(ix, np.int64)[h.primitive[h.hit]]]
    u, w = h.u[h.hit, None], h.v[h.hit, None]
    bary = (1 - u - w) * tri[:, 0] + u * tri[:, 1] + w * tri[:, 2]
    scale = float(np.abs(v).max())
    np.testing.assert_allclose(h.location[h.hit], bary, atol=1e-4 * scale)
    np.testing.assert_allclose(
        h.location[h.hit], o[h.hit] + h.t[h.hit, None] * d[h.hit], atol=1e-4 * scale
    )
    # Geometric normal: the unit normal of the triangle's winding.
    g = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    np.testing.assert_allclose(h.normal[h.hit], g, atol=1e-4)


# ------------------------------------------------------------------------------ queries


def test_closest_and_any_hits_match_brute_force(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    o, d = rays_at(v, 400, seed=1)
    ref = arbor.trace_brute_force(v, ix, o, d)
    for kernel in KERNELS:
        rc = RayCaster(v, ix, kernel=kernel)
        assert rc.kernel == kernel and rc.generation == 0 and len(rc) == len(ix)
        h = rc.intersect(o, d)
        assert isinstance(h, RayHits) and len(h) == 400 and h.kernel == kernel
        assert h.t.dtype == np.float32 and h.primitive.dtype == np.uint32
        assert h.normal.shape == (400, 3) and h.location.shape == (400, 3)
        check_hits(h, o, d, v, ix)
        # Every kernel gives the crate's brute-force hits, bit for bit.
        np.testing.assert_array_equal(h.primitive, ref.primitive)
        np.testing.assert_array_equal(h.t, ref.t)
        # The primitive column alone: the same answer.
        prim = rc.closest_primitives(o, d)
        assert prim.dtype == np.uint32 and prim.shape == (400,)
        np.testing.assert_array_equal(prim, ref.primitive)
        assert ((prim == arbor.NO_HIT) == ~h.hit).all() and h.hit.any() and not h.hit.all()
        # Any hit: exactly the rays with a closest hit; a tmax short of each hit clears it.
        np.testing.assert_array_equal(rc.occluded(o, d), h.hit)
        short = np.where(h.hit, h.t * 0.999, np.inf).astype(np.float32)
        clipped = rc.intersect(o, d, tmax=short)
        assert not (clipped.hit & (clipped.primitive == h.primitive)).any()
        assert not rc.occluded(o, d, tmin=1e9).any()


def test_many_rays_run_in_parallel_and_agree(mesh: arbor.Mesh) -> None:
    """More rays than one work item: the parallel path gives the serial path's hits."""
    v, ix = mesh.vertices, mesh.indices
    o, d = rays_at(v, 5000, seed=2)
    rc = RayCaster(v, ix, kernel="mbvh8")
    h = rc.intersect(o, d)
    for i in range(0, 5000, 499):
        one = rc.intersect(o[i : i + 1], d[i : i + 1])
        assert one.primitive[0] == h.primitive[i] and one.t[0] == h.t[i]
    np.testing.assert_array_equal(rc.occluded(o, d), h.hit)
    ref = arbor.trace_brute_force(v, ix, o, d)
    np.testing.assert_array_equal(h.primitive, ref.primitive)
    np.testing.assert_array_equal(rc.closest_primitives(o, d), ref.primitive)


@pytest.mark.skipif(not BUNNY.exists(), reason="shared scenes not present")
def test_shared_bunny_matches_brute_force() -> None:
    m = arbor.open_scene(str(BUNNY)).mesh()
    v, ix = m.vertices, m.indices
    o, d = rays_at(v, 300, seed=3)
    rc = RayCaster(v, ix)
    h = rc.intersect(o, d)
    check_hits(h, o, d, v, ix)
    ref = arbor.trace_brute_force(v, ix, o, d)
    np.testing.assert_array_equal(h.primitive, ref.primitive)
    np.testing.assert_array_equal(h.t, ref.t)


def test_counters_are_optional(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    o, d = rays_at(v, 100, seed=4)
    rc = RayCaster(v, ix)
    assert rc.intersect(o, d).counters is None
    h = rc.intersect(o, d, counters=True)
    c = h.counters
    assert c is not None and set(c) >= {"node_visits", "tri_tests", "max_stack_depth"}
    assert (c["node_visits"] >= 1).all() and (c["tri_tests"][h.hit] >= 1).all()
    assert h.totals["node_visits"] == int(c["node_visits"].sum())
    assert h.totals["rays"] == 100 and h.totals["hits"] == int(h.hit.sum())
    # The same counters as the function API (same kernel, same distance stack).
    old = arbor.trace(rc.bvh, v, ix, o, d)
    np.testing.assert_array_equal(old.node_visits, c["node_visits"])


def test_defaults_follow_the_command_line(mesh: arbor.Mesh) -> None:
    """`arbor render`: distance stack off for bvh2 and cbvh, on for the wide kernels."""
    v, ix = mesh.vertices, mesh.indices
    cases: list[tuple[Kernel, bool]] = [
        ("bvh2", False),
        ("cbvh", False),
        ("mbvh4", True),
        ("mbvh8", True),
    ]
    for kernel, on in cases:
        assert RayCaster(v, ix, kernel=kernel).distance_stack is on
    assert RayCaster(v, ix, builder="mbvh4-topdown").kernel == "mbvh4"
    assert RayCaster(v, ix, kernel="bvh2", distance_stack=True).distance_stack is True


def test_out_buffers_are_filled_in_place(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    o, d = rays_at(v, 50, seed=5)
    rc = RayCaster(v, ix)
    first = rc.intersect(o, d)
    again = rc.intersect(o[::-1].copy(), d[::-1].copy(), out=first)
    assert again.t is first.t and again.location is first.location
    ref = rc.intersect(o[::-1].copy(), d[::-1].copy())
    np.testing.assert_array_equal(first.t, ref.t)
    np.testing.assert_array_equal(first.primitive, ref.primitive)
    buf = np.zeros(50, dtype=bool)
    assert rc.occluded(o, d, out=buf) is buf
    np.testing.assert_array_equal(buf, ref.hit[::-1])
    with pytest.raises(ArborError, match="out holds 50 rays, 10 given"):
        rc.intersect(o[:10], d[:10], out=first)
    with pytest.raises(ArborError, match="counters"):
        rc.intersect(o, d, counters=True, out=first)
    with pytest.raises(ArborError, match="out"):
        rc.occluded(o, d, out=np.zeros(50, dtype=np.float32))
    with pytest.raises(ArborError, match="out"):
        rc.occluded(o, d, out=np.zeros(49, dtype=bool))
    ids = np.zeros(50, dtype=np.uint32)
    assert rc.closest_primitives(o, d, out=ids) is ids
    np.testing.assert_array_equal(ids, ref.primitive[::-1])
    with pytest.raises(ArborError, match="closest_primitives: out"):
        rc.closest_primitives(o, d, out=np.zeros(50, dtype=np.int64))
    with pytest.raises(ArborError, match="closest_primitives: out"):
        rc.closest_primitives(o, d, out=np.zeros(51, dtype=np.uint32))


def test_errors_name_the_problem(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    o, d = rays_at(v, 10, seed=6)
    rc = RayCaster(v, ix)
    with pytest.raises(ArborError, match="differ in length"):
        rc.intersect(o, d[:5])
    with pytest.raises(ArborError, match=r"directions\[2\]"):
        z = d.copy()
        z[2] = 0
        rc.occluded(o, z)
    with pytest.raises(ArborError, match=r"origins\[7\]"):
        n = o.copy()
        n[7, 1] = np.inf
        rc.intersect(n, d)
    with pytest.raises(ArborError, match="tmin is negative"):
        rc.intersect(o, d, tmin=-1.0)
    with pytest.raises(ArborError, match=r"tmin\[3\] is negative"):
        rc.intersect(o, d, tmin=np.where(np.arange(10) == 3, -1, 0))
    with pytest.raises(ArborError, match=r"tmax\[4\] is NaN"):
        rc.intersect(o, d, tmax=np.where(np.arange(10) == 4, np.nan, 1).astype(np.float32))
    with pytest.raises(ArborError, match="tmin is NaN"):
        rc.occluded(o, d, tmin=float("nan"))
    with pytest.raises(ArborError, match=r"directions\[2\]"):
        rc.closest_primitives(o, z)
    # The first NaN of a long range array is named, on the float32 path read in place and
    # on the converted one (the scan is one vectorized pass, then a search).
    o1k, d1k = rays_at(v, 1000, seed=6)
    far = np.ones(1000, dtype=np.float32)
    far[[517, 999]] = np.nan
    with pytest.raises(ArborError, match=r"tmax\[517\] is NaN"):
        rc.intersect(o1k, d1k, tmax=far)
    with pytest.raises(ArborError, match=r"tmin\[517\] is NaN"):
        rc.occluded(o1k, d1k, tmin=np.where(np.isnan(far), np.nan, 0.0))
    with pytest.raises(ArborError, match="max_leaf"):
        RayCaster(v, ix, max_leaf=-1)
    with pytest.raises(ArborError, match="threads"):
        RayCaster(v, ix, threads=-2)
    with pytest.raises(ArborError, match="unknown kernel"):
        RayCaster(v, ix, kernel="gpu")  # type: ignore[arg-type]
    with pytest.raises(ArborError, match="unknown builder|builder"):
        RayCaster(v, ix, builder="nope")
    with pytest.raises(ArborError, match="4-wide"):
        RayCaster(v, ix, builder="mbvh4-topdown", kernel="bvh2")


# -------------------------------------------------------------------- refit and staleness


@pytest.mark.parametrize("kernel", KERNELS)
def test_refit_moves_the_geometry_in_place(mesh: arbor.Mesh, kernel: str) -> None:
    v, ix = mesh.vertices, mesh.indices
    rc = RayCaster(v, ix, kernel=kernel)  # type: ignore[arg-type]
    v1 = moved(v, 1)
    o, d = rays_at(v1, 300, seed=7)
    rc.refit(v1)
    assert rc.generation == 1
    np.testing.assert_array_equal(rc.vertices, v1)
    h = rc.intersect(o, d)
    assert h.generation == 1
    ref = arbor.trace_brute_force(v1, ix, o, d)
    np.testing.assert_array_equal(h.primitive, ref.primitive)
    np.testing.assert_array_equal(h.t, ref.t)
    check_hits(h, o, d, v1, ix)
    # Back to the first positions: a fresh structure's hits.
    rc.refit(v)
    assert rc.generation == 2
    fresh = RayCaster(v, ix, kernel=kernel)  # type: ignore[arg-type]
    np.testing.assert_array_equal(rc.intersect(o, d).t, fresh.intersect(o, d).t)
    with pytest.raises(ArborError, match="topology"):
        rc.refit(v[:-1])
    with pytest.raises(ArborError, match="non-finite"):
        bad = v.copy()
        bad[int(ix[0, 0])] = np.nan
        rc.refit(bad)
    assert rc.generation == 2  # a failed refit changes nothing
    np.testing.assert_array_equal(rc.intersect(o, d).t, fresh.intersect(o, d).t)


def test_a_stale_tree_is_an_error_not_a_miss(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    bvh = arbor.build_bvh(mesh)
    v1 = moved(v, 1)
    o, d = rays_at(v1, 20, seed=8)
    with pytest.raises(ArborError, match="stale"):
        arbor.trace(bvh, v1, ix, o, d)
    with pytest.raises(ArborError, match="stale"):
        RayCaster.from_bvh(bvh, v1)
    bvh.refit(v1)
    h = arbor.trace(bvh, v1, ix, o, d)
    rc = RayCaster.from_bvh(bvh, v1, kernel="mbvh8")
    np.testing.assert_array_equal(rc.intersect(o, d).t, h.t)
    assert rc.builder == bvh.builder


# ----------------------------------------------------------------- pickling and threads


@pytest.mark.parametrize("kernel", ("bvh2", "cbvh"))
def test_pickle_round_trip(mesh: arbor.Mesh, kernel: str) -> None:
    v, ix = mesh.vertices, mesh.indices
    rc = RayCaster(v, ix, builder="sweep-sah", kernel=kernel)  # type: ignore[arg-type]
    rc.refit(moved(v, 1))
    back = pickle.loads(pickle.dumps(rc))
    assert isinstance(back, RayCaster)
    assert (back.kernel, back.builder, back.generation) == (kernel, "sweep-sah", 1)
    assert back.distance_stack == rc.distance_stack
    np.testing.assert_array_equal(back.vertices, rc.vertices)
    np.testing.assert_array_equal(back.indices, rc.indices)
    assert back.bvh == rc.bvh
    o, d = rays_at(rc.vertices, 200, seed=9)
    a, b = rc.intersect(o, d), back.intersect(o, d)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.primitive, b.primitive)


def test_threads_trace_while_another_refits(mesh: arbor.Mesh) -> None:
    """Queries and refits from several threads wait for each other: no error, and every
    result is the one of the geometry of the generation it reports."""
    v, ix = mesh.vertices, mesh.indices
    poses = [v, moved(v, 1)]
    o, d = rays_at(v, 2000, seed=10)
    want = [arbor.trace_brute_force(p, ix, o, d).t for p in poses]
    rc = RayCaster(v, ix)
    errors: list[BaseException] = []
    stop = threading.Event()

    def refit() -> None:
        try:
            for k in range(1, 21):
                rc.refit(poses[k % 2])
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)
        finally:
            stop.set()

    def query() -> None:
        try:
            while not stop.is_set():
                h = rc.intersect(o, d)
                np.testing.assert_array_equal(h.t, want[h.generation % 2])
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=refit)] + [threading.Thread(target=query) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert rc.generation == 20


def test_integer_arguments_and_indices_give_arbor_errors(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    for kw in ("max_leaf", "bins", "threads"):
        with pytest.raises(ArborError, match=kw):
            arbor.Bvh.build(v, ix, **{kw: -1})  # type: ignore[arg-type]
    huge = ix.astype(np.uint64)
    huge[3, 1] = 2**64 - 5
    with pytest.raises(ArborError, match=f"triangle 3 refers to vertex {2**64 - 5}"):
        arbor.Bvh.build(v, huge)
    with pytest.raises(ArborError, match="triangle 3 refers to vertex -2"):
        neg = ix.astype(np.int64)
        neg[3, 1] = -2
        RayCaster(v, neg)
    # Other integer dtypes are read exactly.
    a = RayCaster(v, ix.astype(np.uint16) if len(v) < 2**16 else ix)
    b = RayCaster(v, ix.astype(np.int64))
    np.testing.assert_array_equal(a.indices, b.indices)


def test_threads_share_one_bvh(mesh: arbor.Mesh) -> None:
    """`Bvh.refit` in one thread while others trace and read it: no `Already borrowed`."""
    v, ix = mesh.vertices, mesh.indices
    bvh = arbor.build_bvh(mesh)
    o, d = rays_at(v, 500, seed=11)
    want = arbor.trace(bvh, v, ix, o, d).t
    errors: list[BaseException] = []
    stop = threading.Event()

    def refit() -> None:
        try:
            for _ in range(30):
                bvh.refit(v)
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)
        finally:
            stop.set()

    def read() -> None:
        try:
            while not stop.is_set():
                np.testing.assert_array_equal(arbor.trace(bvh, v, ix, o, d).t, want)
                assert bvh.node_count > 0 and len(bvh.nodes) == bvh.node_count
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=refit)] + [threading.Thread(target=read) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    bvh.validate()


def test_a_ray_task_receives_the_structure(mesh: arbor.Mesh) -> None:
    ray = pytest.importorskip("ray")
    v, ix = mesh.vertices, mesh.indices
    rc = RayCaster(v, ix, kernel="mbvh8")
    o, d = rays_at(v, 200, seed=12)
    want = rc.intersect(o, d).t
    # And instances of it (the second one moved and turned half a turn about z).
    xf = np.array([np.eye(4)[:3], [[-1, 0, 0, 0.3], [0, -1, 0, 0], [0, 0, 1, 0.1]]])
    ic = arbor.InstanceCaster([rc], xf)
    ic_want = ic.intersect(o, d)
    assert ic_want.hit.any()
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:

        @ray.remote  # type: ignore[untyped-decorator]
        def cast(caster: RayCaster | arbor.InstanceCaster, o: np.ndarray, d: np.ndarray) -> Any:
            return caster.intersect(o, d)

        got = ray.get(cast.remote(ray.put(rc), o, d))
        ic_got = ray.get(cast.remote(ray.put(ic), o, d))
    finally:
        ray.shutdown()
    np.testing.assert_array_equal(got.t, want)
    np.testing.assert_array_equal(ic_got.t, ic_want.t)
    np.testing.assert_array_equal(ic_got.instance, ic_want.instance)


def test_bvh_pickles(mesh: arbor.Mesh, tmp_path: Path) -> None:
    v, ix = mesh.vertices, mesh.indices
    for bvh in (arbor.build_bvh(mesh, builder="sweep-sah"), arbor.build_bvh(mesh).collapse()):
        back = pickle.loads(pickle.dumps(bvh))
        assert back == bvh and (back.builder, back.max_leaf) == (bvh.builder, bvh.max_leaf)
        np.testing.assert_array_equal(back.nodes, bvh.nodes)
        back.validate()  # the stored triangles and boxes travel too
        back.refit(moved(v, 1))  # and the stored indices
        back.validate(moved(v, 1), ix)
    # A tree loaded from a file (no triangles stored) pickles too.
    path = tmp_path / "t.bvh"
    arbor.build_bvh(mesh).save(path)
    loaded = pickle.loads(pickle.dumps(arbor.load_bvh(path)))
    assert loaded == arbor.load_bvh(path)
    with pytest.raises(ArborError, match="loaded from a file"):
        loaded.validate()


def test_native_wide_trees_and_from_bvh(mesh: arbor.Mesh) -> None:
    """A 4-wide tree from its own builder: prepared, refitted, pickled and wrapped."""
    v, ix = mesh.vertices, mesh.indices
    rc = RayCaster(v, ix, builder="mbvh4-topdown")
    assert rc.kernel == "mbvh4" and rc.bvh.kind == "Mbvh4"
    v1 = moved(v, 2)
    rc.refit(v1)
    o, d = rays_at(v1, 300, seed=13)
    ref = arbor.trace_brute_force(v1, ix, o, d)
    np.testing.assert_array_equal(rc.intersect(o, d).t, ref.t)
    back = pickle.loads(pickle.dumps(rc))
    np.testing.assert_array_equal(back.intersect(o, d).primitive, ref.primitive)
    wrapped = RayCaster.from_bvh(rc.bvh, v1, ix)
    np.testing.assert_array_equal(wrapped.occluded(o, d), ref.hit)


def test_several_meshes_name_the_mesh_of_each_hit(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    other = arbor.open_scene("proc:cloth?n=500&seed=2").mesh()
    v2 = (other.vertices + np.float32(0.3)).astype(np.float32)
    rc = RayCaster.from_meshes([(v, ix), (v2, other.indices)], kernel="mbvh8")
    assert rc.geometry_count == 2 and len(rc) == len(ix) + len(other.indices)
    # The same hits as one mesh of both.
    allv = np.concatenate([v, v2])
    allix = np.concatenate([ix, other.indices + len(v)])
    o, d = rays_at(allv, 400, seed=14)
    h = rc.intersect(o, d)
    ref = arbor.trace_brute_force(allv, allix, o, d)
    np.testing.assert_array_equal(h.primitive, ref.primitive)
    first = np.array([0, len(ix), len(allix)])
    g = np.searchsorted(first, h.primitive[h.hit], side="right") - 1
    assert set(np.unique(g)) == {0, 1}
    np.testing.assert_array_equal(h.geometry[h.hit], g)
    np.testing.assert_array_equal(h.geometry_primitive[h.hit], h.primitive[h.hit] - first[g])
    assert (h.geometry[~h.hit] == arbor.NO_HIT).all()
    # One mesh: geometry 0 throughout.
    single = RayCaster(v, ix).intersect(o, d)
    assert (single.geometry[single.hit] == 0).all()
    # Refit with the vertices of each mesh; pickling keeps the meshes.
    rc.refit([moved(v, 1), v2])
    h1 = rc.intersect(o, d)
    ref1 = arbor.trace_brute_force(np.concatenate([moved(v, 1), v2]), allix, o, d)
    np.testing.assert_array_equal(h1.t, ref1.t)
    back = pickle.loads(pickle.dumps(rc))
    assert back.geometry_count == 2
    np.testing.assert_array_equal(back.intersect(o, d).geometry, h1.geometry)
    with pytest.raises(ArborError, match="2 meshes expected, 1 given"):
        rc.refit([v])
    with pytest.raises(ArborError, match="mesh 1 has"):
        rc.refit([v, v2[:-1]])
    with pytest.raises(ArborError, match="at least one mesh"):
        RayCaster.from_meshes([])
    with pytest.raises(ArborError, match=r"meshes\[0\]"):
        RayCaster.from_meshes([42])


def test_results_pickle(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    o, d = rays_at(v, 100, seed=15)
    rc = RayCaster.from_meshes([(v, ix)], kernel="cbvh")
    for counters in (False, True):
        h = rc.intersect(o, d, counters=counters)
        back = pickle.loads(pickle.dumps(h))
        assert isinstance(back, RayHits) and len(back) == 100
        assert (back.kernel, back.generation) == ("cbvh", 0) and back.totals == h.totals
        for name in ("t", "primitive", "u", "v", "hit", "normal", "location", "geometry"):
            np.testing.assert_array_equal(getattr(back, name), getattr(h, name))
        if counters:
            assert back.counters is not None and h.counters is not None
            np.testing.assert_array_equal(back.counters["tri_tests"], h.counters["tri_tests"])
        else:
            assert back.counters is None


def test_every_typed_object_pickles(mesh: arbor.Mesh) -> None:
    """Scenes aside (a scene is its spec: open it again), every object pickles."""
    scene = arbor.open_scene(CLOTH)
    cam = pickle.loads(pickle.dumps(scene.camera))
    assert (cam.eye, cam.target, cam.up, cam.vfov_deg) == (
        scene.camera.eye,
        scene.camera.target,
        scene.camera.up,
        scene.camera.vfov_deg,
    )
    m = pickle.loads(pickle.dumps(mesh))
    np.testing.assert_array_equal(m.vertices, mesh.vertices)
    np.testing.assert_array_equal(m.indices, mesh.indices)
    np.testing.assert_array_equal(m.bounds, mesh.bounds)
    assert (m.time, m.material_names, len(m)) == (mesh.time, mesh.material_names, len(mesh))
    rays = arbor.camera_rays(scene.camera, 16, 8)
    r = pickle.loads(pickle.dumps(rays))
    assert (len(r), r.width, r.height, r.kind) == (len(rays), 16, 8, "primary")
    np.testing.assert_array_equal(r.directions, rays.directions)
    np.testing.assert_array_equal(r.pixel, rays.pixel)
    hits = arbor.trace(arbor.build_bvh(mesh), mesh.vertices, mesh.indices, r.origins, r.directions)
    h = pickle.loads(pickle.dumps(hits))
    assert h.totals == hits.totals and h.kernel == hits.kernel
    np.testing.assert_array_equal(h.t, hits.t)
    np.testing.assert_array_equal(h.node_visits, hits.node_visits)


def test_all_hits_along_each_ray(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    o, d = rays_at(v, 300, seed=16)
    # A second, shifted layer of the cloth: rays cross several surfaces.
    v2 = np.concatenate([v, v + np.float32(0.05)])
    ix2 = np.concatenate([ix, ix + len(v)])
    rc = RayCaster(v2, ix2)
    ray, prim, t = rc.intersect_all(o, d)
    assert ray.dtype == np.uint32 and prim.dtype == np.uint32 and t.dtype == np.float32
    # Ray by ray, nearest first; the first of each ray is its closest hit.
    assert (np.diff(ray.astype(np.int64)) >= 0).all()
    same = ray[1:] == ray[:-1]
    assert (t[1:][same] > t[:-1][same]).all()
    h = rc.intersect(o, d)
    firsts = np.flatnonzero(np.r_[True, ~same])
    np.testing.assert_array_equal(ray[firsts], np.flatnonzero(h.hit))
    np.testing.assert_array_equal(prim[firsts], h.primitive[h.hit])
    # Against float64 brute force: the same number of hits per ray (but grazing edges).
    tri = np.asarray(v2, np.float64)[np.asarray(ix2, np.int64)]
    counts = np.bincount(ray, minlength=300)
    want = np.zeros(300, np.int64)
    for i in range(300):
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        dd = np.broadcast_to(d[i].astype(np.float64), e1.shape)
        pv = np.cross(dd, e2)
        det = np.sum(e1 * pv, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            tv = o[i].astype(np.float64) - tri[:, 0]
            u = np.sum(tv * pv, axis=1) / det
            qv = np.cross(tv, e1)
            w = np.sum(dd * qv, axis=1) / det
            tt = np.sum(e2 * qv, axis=1) / det
        want[i] = int(
            np.sum((np.abs(det) > 1e-12) & (u >= 0) & (w >= 0) & (u + w <= 1) & (tt >= 0))
        )
    assert (counts == want).mean() > 0.95 and counts.max() >= 2
    # max_hits caps each ray; tmax clips.
    capped = rc.intersect_all(o, d, max_hits=1)[0]
    np.testing.assert_array_equal(capped, np.flatnonzero(h.hit))
    assert len(rc.intersect_all(o, d, tmax=0.0)[0]) == 0
    with pytest.raises(ArborError, match="max_hits"):
        rc.intersect_all(o, d, max_hits=-1)


# ------------------------------------------------------------------- animation frames


@pytest.mark.parametrize("kernel", KERNELS)
def test_trace_frames_equals_refit_and_intersect_frame_by_frame(
    mesh: arbor.Mesh, kernel: Kernel
) -> None:
    v, ix = mesh.vertices, mesh.indices
    frames = np.stack([moved(v, k) for k in range(5)])
    o, d = rays_at(v, 700, seed=21)  # above the serial limit: the parallel path
    batched, stepped = RayCaster(v, ix, kernel=kernel), RayCaster(v, ix, kernel=kernel)
    hits = batched.trace_frames(frames, o, d)
    assert len(hits) == 5 and batched.generation == 5
    for k, h in enumerate(hits):
        stepped.refit(frames[k])
        ref = stepped.intersect(o, d)
        assert h.generation == ref.generation == k + 1 and h.kernel == kernel
        for name in ("t", "primitive", "u", "v", "hit", "location", "normal"):
            np.testing.assert_array_equal(getattr(h, name), getattr(ref, name), err_msg=name)
        assert h.totals == ref.totals
        check_hits(h, o, d, frames[k], ix)
    np.testing.assert_array_equal(batched.vertices, frames[-1])


def test_trace_frames_with_rays_per_frame_and_ranges(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    frames = np.stack([moved(v, k) for k in range(3)])
    rays = [rays_at(v, 50, seed=30 + k) for k in range(3)]
    o, d = np.stack([r[0] for r in rays]), np.stack([r[1] for r in rays])
    tmin = np.linspace(0.0, 0.3, 50, dtype=np.float32)  # (R,): the same for every frame
    tmax = np.tile(np.linspace(0.5, 1.5, 50, dtype=np.float32), (3, 1))  # (T, R)
    tmax[1] = np.inf
    rc, ref = RayCaster(v, ix, kernel="mbvh8"), RayCaster(v, ix, kernel="mbvh8")
    hits = rc.trace_frames(frames, o, d, tmin, tmax)
    for k, h in enumerate(hits):
        ref.refit(frames[k])
        r = ref.intersect(o[k], d[k], tmin, tmax[k])
        np.testing.assert_array_equal(h.t, r.t)
        np.testing.assert_array_equal(h.primitive, r.primitive)
    assert hits[1].hit.sum() > hits[0].hit.sum() // 2  # some rays do hit


def test_trace_frames_bad_input_changes_nothing(mesh: arbor.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    rc = RayCaster(v, ix)
    o, d = rays_at(v, 10, seed=40)
    frames = np.stack([moved(v, k) for k in range(4)])
    frames[2, 7] = np.nan
    with pytest.raises(ArborError, match=r"frames\[2\]: .*non-finite"):
        rc.trace_frames(frames, o, d)
    with pytest.raises(ArborError, match=r"frames must have shape \(T, \d+, 3\)"):
        rc.trace_frames(frames[:, :-1], o, d)
    with pytest.raises(ArborError, match=r"frames must have shape"):
        rc.trace_frames(frames[0], o, d)
    good = frames[[0, 1]]
    with pytest.raises(ArborError, match=r"per-frame rays"):
        rc.trace_frames(good, np.stack([o] * 3), np.stack([d] * 3))
    with pytest.raises(ArborError, match=r"tmin and tmax"):
        rc.trace_frames(good, np.stack([o] * 2), np.stack([d] * 2), np.zeros(3))
    with pytest.raises(ArborError, match=r"directions\[0\]"):
        rc.trace_frames(good, o, np.zeros_like(d))
    assert rc.generation == 0
    np.testing.assert_array_equal(rc.vertices, v)
    assert rc.trace_frames(good[:0], o, d) == []


# ------------------------------------------------------------------------ inside test

# The directions of `RayCaster.contains_points` (python/src/raycaster.rs).
CONTAINS_DIRECTIONS = np.array(
    [
        [0.43950645, 0.6175986, 0.6522316],
        [-0.7194073, 0.1901258, -0.6680431],
        [0.2836176, -0.9083352, -0.3075549],
    ]
)


def convex_depth(p: np.ndarray, v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Signed distance of each point to a convex polytope's boundary planes, float64:
    the largest distance above a face plane (negative inside)."""
    tri = np.asarray(v, np.float64)[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.max(np.einsum("pfk,fk->pf", p[:, None, :] - tri[None, :, 0], n), axis=1)


def hard_points(v: np.ndarray, f: np.ndarray, seed: int) -> np.ndarray:
    """Points whose rays in the directions of `contains_points` pass through an edge's
    midpoint or a vertex: each such point, moved back and forth along that direction."""
    rng = np.random.default_rng(seed)
    v = np.asarray(v, np.float64)
    edges = v[f[:, [0, 1, 2]]] + v[f[:, [1, 2, 0]]]
    targets = np.concatenate([edges.reshape(-1, 3) / 2, v])
    targets = targets[rng.choice(len(targets), 400, replace=False)]
    out = []
    for d in CONTAINS_DIRECTIONS:
        s = rng.uniform(-1.0, 1.0, size=(len(targets), 1))
        out.append(targets - s * d)
    return np.concatenate(out)


@pytest.mark.parametrize("kernel", KERNELS)
def test_contains_points_on_a_convex_mesh_matches_the_planes(kernel: Kernel) -> None:
    from shapes import icosphere

    v, f = icosphere(3)
    v = v * 2.0
    rc = RayCaster(v, f, kernel=kernel)
    rng = np.random.default_rng(50)
    tri = np.asarray(v, np.float64)[f]
    centroid = tri.mean(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    pts = np.concatenate(
        [
            rng.uniform(-2.6, 2.6, size=(3000, 3)),  # in and around the box
            centroid + 1e-3 * normal,  # just outside each face
            centroid - 1e-3 * normal,  # just inside
            hard_points(v, f, seed=51),  # rays through edges and vertices
        ]
    )
    depth = convex_depth(pts, v, f)
    clear = np.abs(depth) > 1e-4  # off the surface by more than float32 rounding
    assert clear.mean() > 0.98
    got = rc.contains_points(pts)
    assert got.dtype == bool and got.shape == (len(pts),)
    np.testing.assert_array_equal(got[clear], depth[clear] < 0)
    # The adapter uses it.
    adapter = arbor.RayMeshIntersector(types_mesh(v, f), kernel=kernel)
    np.testing.assert_array_equal(adapter.contains_points(pts), got)


class types_mesh:  # noqa: N801 (a plain record with the attributes of a mesh)
    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.vertices, self.faces = vertices, faces


def test_contains_points_on_a_torus_matches_its_equation() -> None:
    """A non-convex closed mesh: points off the surface against the torus equation
    (the polygon lies within 0.01 of the smooth torus), hard points included."""
    from shapes import torus

    big, small = 1.0, 0.35
    v, f = torus(big, small, 64, 32)
    rc = RayCaster(v, f)
    rng = np.random.default_rng(52)
    pts = np.concatenate([rng.uniform(-1.5, 1.5, size=(6000, 3)), hard_points(v, f, seed=53)])
    q = np.hypot(pts[:, 0], pts[:, 1]) - big
    dist = np.hypot(q, pts[:, 2]) - small  # signed distance to the smooth torus
    clear = np.abs(dist) > 0.01
    assert clear.mean() > 0.9 and (dist[clear] < 0).sum() > 300
    got = rc.contains_points(pts)
    np.testing.assert_array_equal(got[clear], dist[clear] < 0)
    # Moved: the refitted tree answers for the new place.
    rc.refit(v + np.float32([5.0, 0.0, 0.0]))
    np.testing.assert_array_equal(rc.contains_points(pts + [5.0, 0.0, 0.0])[clear], dist[clear] < 0)


def test_contains_points_of_several_meshes_and_bad_input() -> None:
    from shapes import icosphere

    v, f = icosphere(2)
    rc = RayCaster.from_meshes([(v, f), (v + np.float32([3, 0, 0]), f)])
    pts = np.array([[0, 0, 0], [3, 0, 0], [1.5, 0, 0], [3, 0, 2], [0.2, 0.1, -0.3]])
    np.testing.assert_array_equal(rc.contains_points(pts), [True, True, False, False, True])
    buf = np.zeros(5, bool)
    assert rc.contains_points(pts, out=buf) is buf and buf.sum() == 3
    assert rc.contains_points(np.zeros((0, 3))).shape == (0,)
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ArborError, match=r"points\[3\] is not finite"):
        rc.contains_points(bad)
    with pytest.raises(ArborError, match=r"points must have shape \(N, 3\)"):
        rc.contains_points(np.zeros((4, 2)))
    with pytest.raises(ArborError, match="out"):
        rc.contains_points(pts, out=np.zeros(4, bool))
