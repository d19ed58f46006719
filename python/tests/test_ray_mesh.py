"""The trimesh-shaped adapter (`arbor.RayMeshIntersector`) against trimesh's own ray
intersectors (the float64 numpy one, and Embree's where embreex is installed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import arbor

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("rtree")  # trimesh's own ray intersector needs it

BUNNY = Path(__file__).resolve().parents[3] / "shared" / "scenes" / "bunny.ply"


def rays_at(v: Any, n: int, seed: int) -> tuple[Any, Any]:
    rng = np.random.default_rng(seed)
    lo, hi = v.min(axis=0), v.max(axis=0)
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo)
    dirs = rng.normal(size=(n, 3))
    origins = c + r * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    targets = lo + rng.random((n, 3)) * (hi - lo)
    return origins, targets - origins


@pytest.fixture(scope="module")
def sphere() -> Any:
    return trimesh.creation.icosphere(subdivisions=3, radius=2.0)


def test_first_and_any_hits_match_trimesh(sphere: Any) -> None:
    ours = arbor.RayMeshIntersector(sphere)
    ref = trimesh.ray.ray_triangle.RayMeshIntersector(sphere)
    o, d = rays_at(sphere.vertices, 500, seed=1)
    first = ours.intersects_first(o, d)
    assert first.dtype == np.int64 and (first >= 0).sum() > 100
    want = ref.intersects_first(o, d)
    assert (first == want).mean() > 0.98  # the rest graze an edge within rounding
    np.testing.assert_array_equal(ours.intersects_any(o, d), first >= 0)


def test_multiple_hits_and_locations_match_trimesh(sphere: Any) -> None:
    ours = arbor.RayMeshIntersector(sphere)
    ref = trimesh.ray.ray_triangle.RayMeshIntersector(sphere)
    o, d = rays_at(sphere.vertices, 300, seed=2)
    loc, ray, tri = ours.intersects_location(o, d)
    rloc, rray, rtri = ref.intersects_location(o, d)
    # A ray through the sphere enters and leaves it: two hits each.
    n, rn = np.bincount(ray, minlength=300), np.bincount(rray, minlength=300)
    assert (n == rn).mean() > 0.98 and set(np.unique(n)) <= {0, 1, 2}
    assert (n == 2).sum() > 50
    # The same hits (triangle, ray) and locations.
    ours_set = {(int(r), int(t)) for r, t in zip(ray, tri)}
    ref_set = {(int(r), int(t)) for r, t in zip(rray, rtri)}
    assert len(ours_set & ref_set) >= 0.97 * len(ref_set)
    at = {(int(r), int(t)): p for r, t, p in zip(rray, rtri, rloc)}
    for r, t, p in zip(ray, tri, loc):
        if (int(r), int(t)) in at:
            np.testing.assert_allclose(p, at[(int(r), int(t))], atol=1e-4)
    # First hits only.
    tri1, ray1 = ours.intersects_id(o, d, multiple_hits=False)[:2]
    np.testing.assert_array_equal(ray1, np.flatnonzero(ours.intersects_any(o, d)))
    np.testing.assert_array_equal(tri1, ours.intersects_first(o, d)[ray1])


def test_contains_points_matches_trimesh(sphere: Any) -> None:
    ours = arbor.RayMeshIntersector(sphere)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-2.5, 2.5, size=(2000, 3))
    got = ours.contains_points(pts)
    want = sphere.contains(pts)
    assert got.dtype == bool and 200 < got.sum() < 1900
    assert (got == want).mean() > 0.995
    # Far from the surface, exactly the points inside the sphere.
    r = np.linalg.norm(pts, axis=1)
    clear = np.abs(r - 2.0) > 0.1
    np.testing.assert_array_equal(got[clear], r[clear] < 2.0)


def test_contains_points_on_a_torus_matches_trimesh() -> None:
    """A non-convex closed mesh: the native inside test against trimesh's `contains`
    on random points, and on points just off each face (inside by construction)."""
    from shapes import torus

    v, f = torus(1.0, 0.35, 48, 24)
    m = trimesh.Trimesh(v.astype(np.float64), f, process=False)
    assert m.is_watertight
    rng = np.random.default_rng(9)
    rand = rng.uniform(-1.5, 1.5, size=(3000, 3))
    ours = arbor.RayMeshIntersector(m)
    got = ours.contains_points(rand)
    # Away from the surface (the polygon lies within 0.02 of the smooth torus).
    dist = np.hypot(np.hypot(rand[:, 0], rand[:, 1]) - 1.0, rand[:, 2]) - 0.35
    clear = np.abs(dist) > 0.02
    np.testing.assert_array_equal(got[clear], dist[clear] < 0)
    np.testing.assert_array_equal(got[clear], m.contains(rand)[clear])
    assert (got == m.contains(rand)).mean() > 0.995
    # 1e-3 off each face's centroid, out and in.
    c, n = m.triangles_center, m.face_normals
    near = np.concatenate([c + 1e-3 * n, c - 1e-3 * n])
    want = np.repeat([False, True], len(c))
    np.testing.assert_array_equal(ours.contains_points(near), want)
    np.testing.assert_array_equal(m.contains(near), want)


def test_refit_and_arbor_meshes(sphere: Any) -> None:
    ours = arbor.RayMeshIntersector(sphere)
    moved = sphere.copy()
    moved.apply_translation([0.5, 0.0, 0.0])
    ours.refit(moved.vertices.astype(np.float32))
    o, d = rays_at(moved.vertices, 200, seed=4)
    ref = trimesh.ray.ray_triangle.RayMeshIntersector(moved)
    assert (ours.intersects_first(o, d) == ref.intersects_first(o, d)).mean() > 0.98
    m = arbor.open_scene("proc:cloth?n=500&seed=1").mesh()
    a = arbor.RayMeshIntersector(m)
    o, d = rays_at(m.vertices, 50, seed=5)
    assert a.intersects_any(o, d).any()


@pytest.mark.skipif(not BUNNY.exists(), reason="shared scenes not present")
def test_bunny_matches_embree() -> None:
    pytest.importorskip("embreex")
    from trimesh.ray.ray_pyembree import RayMeshIntersector as Embree

    m = trimesh.load(str(BUNNY), process=False)
    ours = arbor.RayMeshIntersector(m)
    o, d = rays_at(np.asarray(m.vertices), 2000, seed=6)
    got, want = ours.intersects_first(o, d), Embree(m).intersects_first(o, d)
    assert (got >= 0).sum() > 200
    assert (got == want).mean() > 0.99


def test_switches_trimesh_over_with_one_line(sphere: Any) -> None:
    """`mesh.ray = arbor.RayMeshIntersector(mesh)`: trimesh's own methods then use it."""
    m = sphere.copy()
    m.ray = arbor.RayMeshIntersector(m)
    assert isinstance(m.ray, arbor.RayMeshIntersector)
    rng = np.random.default_rng(7)
    pts = rng.uniform(-2.5, 2.5, size=(500, 3))
    r = np.linalg.norm(pts, axis=1)
    clear = np.abs(r - 2.0) > 0.1
    np.testing.assert_array_equal(m.contains(pts)[clear], r[clear] < 2.0)
    o, d = rays_at(np.asarray(m.vertices), 100, seed=8)
    loc, ray, tri = m.ray.intersects_location(o, d)
    assert len(loc) == len(ray) == len(tri) > 0


def test_from_meshes_takes_trimesh_objects(sphere: Any) -> None:
    a, b = sphere.copy(), sphere.copy()
    b.apply_translation([5.0, 0.0, 0.0])
    rc = arbor.RayCaster.from_meshes([a, b])
    o = np.array([[0.0, 0.0, 10.0], [5.0, 0.0, 10.0], [20.0, 0.0, 10.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0]] * 3, np.float32)
    h = rc.intersect(o, d)
    np.testing.assert_array_equal(h.geometry, [0, 1, arbor.NO_HIT])
    np.testing.assert_allclose(h.t[:2], [8.0, 8.0], atol=0.05)
