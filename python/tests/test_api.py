"""The typed API (`arbor.core`, native `arbor._arbor`): scenes, BVHs, tracing and CBVHs over
numpy arrays, checked against independent numpy computations."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

import arbor
from arbor import core
from arbor.core import ArborError, Bvh

ROOT = Path(__file__).resolve().parents[2]
CESIUM = ROOT / "scenes" / "CesiumMan.glb"
CLOTH = "proc:cloth?n=2000&seed=1"


@pytest.fixture(scope="module")
def scene() -> core.Scene:
    return core.open_scene(CLOTH)


@pytest.fixture(scope="module")
def mesh(scene: core.Scene) -> core.Mesh:
    return scene.mesh(frame=5)


# ----------------------------------------------------------------------------- helpers


def triangles(v: np.ndarray, ix: np.ndarray) -> np.ndarray:
    """(M, 3, 3) vertex positions of each triangle."""
    return np.asarray(v, dtype=np.float64)[np.asarray(ix, dtype=np.int64)]


def leaves(bvh: Bvh) -> list[tuple[np.ndarray, np.ndarray, int, int]]:
    """(box min, box max, first, count) of every leaf child of a binary tree."""
    out = []
    for n in bvh.nodes:
        for c in range(2):
            first, count = int(n["children"][c]["index"]), int(n["children"][c]["count"])
            if count > 0:
                out.append((n["bounds"][c, 0], n["bounds"][c, 1], first, count))
    return out


def assert_leaves_enclose(bvh: Bvh, v: np.ndarray, ix: np.ndarray) -> None:
    """Every leaf box of a binary tree holds the vertices of its triangles."""
    tri = triangles(v, ix)
    order = bvh.leaf_order
    seen = 0
    for lo, hi, first, count in leaves(bvh):
        prims = order[first : first + count]
        pts = tri[prims].reshape(-1, 3)
        assert (pts >= lo - 1e-6).all() and (pts <= hi + 1e-6).all()
        seen += count
    assert seen == bvh.primitive_count


def moller_trumbore(
    o: np.ndarray, d: np.ndarray, tri: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest hit of each ray among all triangles, in float64: (t, prim, u, v); t = inf
    and prim = -1 for a miss."""
    o = o.astype(np.float64)[:, None, :]
    d = d.astype(np.float64)[:, None, :]
    p0, e1, e2 = (
        tri[None, :, 0],
        tri[None, :, 1] - tri[None, :, 0],
        tri[None, :, 2] - tri[None, :, 0],
    )
    pv = np.cross(d, e2)
    det = np.sum(e1 * pv, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tv = o - p0
        u = np.sum(tv * pv, axis=-1) * inv
        qv = np.cross(tv, e1)
        v = np.sum(d * qv, axis=-1) * inv
        t = np.sum(e2 * qv, axis=-1) * inv
    ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0)
    t = np.where(ok, t, np.inf)
    prim = np.argmin(t, axis=1)
    rows = np.arange(len(prim))
    best = t[rows, prim]
    hit = np.isfinite(best)
    return best, np.where(hit, prim, -1), u[rows, prim], v[rows, prim]


def random_rays(mesh: core.Mesh, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rays from a sphere around the mesh towards random points near it."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo)
    dirs = rng.normal(size=(n, 3))
    origins = c + r * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    targets = lo + rng.random((n, 3)) * (hi - lo)
    return origins.astype(np.float32), (targets - origins).astype(np.float32)


# ------------------------------------------------------------------------------ scenes


def test_package_exports_the_typed_api() -> None:
    for name in core.__all__:
        assert hasattr(core, name), name
    assert arbor.Bvh is core.Bvh and arbor.trace is core.trace


def test_procedural_scene(scene: core.Scene, mesh: core.Mesh) -> None:
    assert scene.format == "procedural" and scene.spec == CLOTH
    assert scene.frame_count > 1 and scene.duration > 0 and scene.fps > 0
    assert scene.stable_topology and scene.dropped_triangles == 0
    assert scene.triangle_count == mesh.triangle_count == len(mesh) > 1000
    assert mesh.vertices.dtype == np.float32 and mesh.vertices.shape == (mesh.vertex_count, 3)
    assert mesh.indices.dtype == np.uint32 and mesh.indices.shape == (mesh.triangle_count, 3)
    assert mesh.material_ids.shape == (mesh.triangle_count,)
    assert mesh.time == pytest.approx(scene.time_of_frame(5))
    used = mesh.vertices[np.unique(mesh.indices)]
    np.testing.assert_array_equal(mesh.bounds, np.stack([used.min(0), used.max(0)]))
    # Another frame: same triangles, moved vertices; times outside the span and frames
    # past the last are errors, as on the command line.
    other = scene.mesh(time=1.0)
    np.testing.assert_array_equal(other.indices, mesh.indices)
    assert not np.array_equal(other.vertices, mesh.vertices)
    last = scene.mesh(frame=scene.frame_count - 1)
    np.testing.assert_array_equal(scene.mesh(time=scene.duration).vertices, last.vertices)
    for bad in [{"time": 1e6}, {"time": -1.0}, {"time": 1e300}, {"frame": -1}]:
        with pytest.raises(ArborError, match="out of range"):
            scene.mesh(**bad)


def test_bundled_gltf_scene() -> None:
    s = core.Scene(str(CESIUM))
    assert s.format == "gltf" and s.name == "CesiumMan"
    assert s.frame_count > 10 and s.stable_topology
    a, b = s.mesh(frame=0), s.mesh(frame=s.frame_count // 2)
    assert a.triangle_count == s.triangle_count > 1000
    np.testing.assert_array_equal(a.indices, b.indices)
    assert np.abs(a.vertices - b.vertices).max() > 1e-3  # the skin moves
    cam = s.camera
    assert len(cam.eye) == 3 and 0 < cam.vfov_deg < 180


def test_scene_errors_name_the_problem(scene: core.Scene) -> None:
    with pytest.raises(ArborError, match="proc:nosuch") as e:
        core.Scene("proc:nosuch?n=10")
    assert str(e.value).startswith("cannot open scene: ")
    assert "\n" not in str(e.value)
    with pytest.raises(ArborError, match="no-such-file.obj"):
        core.Scene("/definitely/no-such-file.obj")
    with pytest.raises(ArborError, match="zzz"):
        core.Scene("proc:cloth?n=100&zzz=1")
    with pytest.raises(ArborError, match="out of range"):
        scene.mesh(frame=scene.frame_count)
    with pytest.raises(ArborError, match="not both"):
        scene.mesh(time=0.5, frame=1)
    with pytest.raises(ArborError, match="finite"):
        scene.mesh(time=float("nan"))
    with pytest.raises(ArborError, match="fps"):
        core.Scene(CLOTH, fps=0)


# -------------------------------------------------------------------------------- BVHs


def test_the_stub_names_every_builder() -> None:
    # The typed stub's builder names are `builders()`'s (`arbor build`'s, less those that
    # cut triangles), in its order: a name missing there is a type error for a valid call.
    stub = (ROOT / "python" / "arbor" / "_arbor.pyi").read_text()
    body = stub.split("_BuilderName = Literal[", 1)[1].split("]", 1)[0]
    names = [n.strip().strip('"') for n in body.split(",") if n.strip()]
    assert names == core.builders()


@pytest.mark.parametrize("name", core.builders())
def test_every_builder_gives_a_valid_tree(mesh: core.Mesh, name: str) -> None:
    bvh = core.build_bvh(mesh, builder=name, max_leaf=4)
    bvh.validate()
    assert bvh.builder == name and bvh.max_leaf == 4
    assert bvh.primitive_count == mesh.triangle_count
    order = bvh.leaf_order
    assert order.dtype == np.uint32
    np.testing.assert_array_equal(np.sort(order), np.arange(mesh.triangle_count))
    nodes = bvh.nodes
    assert len(nodes) == bvh.node_count
    assert bvh.max_leaf_size <= 4 and bvh.depth >= 1 and bvh.sah() > 0
    np.testing.assert_allclose(bvh.bounds, mesh.bounds)
    if name.startswith("mbvh4-"):
        assert bvh.kind == "Mbvh4" and bvh.width == 4
        assert nodes.dtype == core.MBVH4_NODE_DTYPE and nodes.dtype.itemsize == 128
        counts = nodes["children"]["count"]
    else:
        assert bvh.kind == "Bvh2" and bvh.width == 2
        assert nodes.dtype == core.BVH2_NODE_DTYPE and nodes.dtype.itemsize == 64
        counts = nodes["children"]["count"]
        assert_leaves_enclose(bvh, mesh.vertices, mesh.indices)
    assert counts.sum() == mesh.triangle_count
    assert (counts > 0).sum() == bvh.leaf_count


def test_builder_options_and_array_likes(mesh: core.Mesh) -> None:
    ref = Bvh.build(mesh.vertices, mesh.indices)
    assert ref.builder == core.DEFAULT_BUILDER == "binned-sah"
    # float64 vertices, int64 indices and nested lists give the same tree.
    same = Bvh.build(mesh.vertices.astype(np.float64), mesh.indices.astype(np.int64))
    assert same == ref
    small = 50
    sub_ix = mesh.indices[:small]
    assert Bvh.build(mesh.vertices.tolist(), sub_ix.tolist()) == Bvh.build(mesh.vertices, sub_ix)
    # Non-contiguous input works too.
    assert Bvh.build(np.asfortranarray(mesh.vertices), mesh.indices[:, :]) == ref
    assert Bvh.build(mesh.vertices, mesh.indices, "binned-sah", bins=8).sah() >= 0
    lbvh = Bvh.build(mesh.vertices, mesh.indices, "lbvh", threads=1)
    assert lbvh.max_leaf_size == 1
    c = Bvh.build(mesh.vertices, mesh.indices, "mbvh4-collapse", collapse_from="lbvh")
    assert c == lbvh.collapse()
    # The SAH with the default weights is the tree's normalized SAH.
    assert ref.sah() == pytest.approx(ref.stats()["sah"])
    assert ref.sah(c_inner=0.0) < ref.sah()
    empty = Bvh.build(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.uint32))
    empty.validate()
    assert empty.primitive_count == 0 and empty.node_count == 1


def test_build_errors(mesh: core.Mesh) -> None:
    v, ix = mesh.vertices, mesh.indices
    with pytest.raises(ArborError, match=r"unknown builder 'nope'; valid names: lbvh"):
        Bvh.build(v, ix, "nope")
    with pytest.raises(ArborError, match=r"indices must have shape \(N, 3\), got \(\d+, 2\)"):
        Bvh.build(v, ix[:, :2])
    with pytest.raises(ArborError, match=r"vertices must have shape \(N, 3\), got \(\d+,\)"):
        Bvh.build(v[:, 0], ix)
    with pytest.raises(ArborError, match=f"refers to vertex {len(v)}, but there are only"):
        bad = ix.copy()
        bad[7, 1] = len(v)
        Bvh.build(v, bad)
    with pytest.raises(ArborError, match="refers to vertex -1"):
        Bvh.build(v, ix.astype(np.int64) - 1)
    with pytest.raises(ArborError, match="integers"):
        Bvh.build(v, ix.astype(np.float32))
    with pytest.raises(ArborError, match="non-finite"):
        nan = v.copy()
        nan[ix[3, 0]] = np.nan
        Bvh.build(nan, ix)
    with pytest.raises(ArborError, match="max_leaf must be between 1 and 1024, got 0"):
        Bvh.build(v, ix, max_leaf=0)
    with pytest.raises(ArborError, match="bins must be 8, 16 or 32"):
        Bvh.build(v, ix, bins=12)
    with pytest.raises(ArborError, match="bins applies only"):
        Bvh.build(v, ix, "lbvh", bins=8)
    with pytest.raises(ArborError, match="binary builder"):
        Bvh.build(v, ix, "mbvh4-collapse", collapse_from="mbvh4-topdown")
    with pytest.raises(ArborError, match="threads"):
        Bvh.build(v, ix, threads=0)
    with pytest.raises(ArborError):
        Bvh.build("not an array", ix)
    with pytest.raises(ArborError):
        Bvh.build([[1.0, 2.0], [3.0]], ix)  # ragged


def test_refit_encloses_moved_triangles(scene: core.Scene) -> None:
    m0, m1 = scene.mesh(frame=0), scene.mesh(frame=scene.frame_count - 1)
    bvh = core.build_bvh(m0, builder="sweep-sah")
    before = bvh.nodes.copy()
    moved = m1.vertices + np.float32(0.25)
    bvh.refit(moved)
    bvh.validate()  # against the boxes it was refitted to
    bvh.validate(moved, m1.indices)
    assert_leaves_enclose(bvh, moved, m1.indices)
    used = moved[np.unique(m1.indices)]
    np.testing.assert_allclose(bvh.bounds, np.stack([used.min(0), used.max(0)]))
    # Same topology, new boxes.
    np.testing.assert_array_equal(bvh.nodes["children"], before["children"])
    assert not np.array_equal(bvh.nodes["bounds"], before["bounds"])
    # The old vertices no longer fit the refitted boxes.
    with pytest.raises(ArborError, match="invalid tree"):
        bvh.validate(m0.vertices, m0.indices)
    # 4-wide trees refit too.
    wide = core.build_bvh(m0, builder="mbvh4-topdown")
    wide.refit(moved)
    wide.validate()
    with pytest.raises(ArborError, match="primitives"):
        bvh.refit(moved, m1.indices[:10])


def test_save_and_load_round_trip(mesh: core.Mesh, tmp_path: Path) -> None:
    for name in ("hlbvh", "mbvh4-topdown"):
        bvh = core.build_bvh(mesh, builder=name)
        path = tmp_path / f"{name}.bvh"
        bvh.save(path)
        back = core.load_bvh(str(path))
        assert back == bvh and back.builder == name and back.kind == bvh.kind
        assert back.nodes.tobytes() == bvh.nodes.tobytes()
        np.testing.assert_array_equal(back.leaf_order, bvh.leaf_order)
        assert back.sah() == bvh.sah()
        back.validate(mesh.vertices, mesh.indices, max_leaf=8)
        with pytest.raises(ArborError, match="loaded from a file"):
            back.validate()
    bad = tmp_path / "garbage.bvh"
    bad.write_bytes(b"not a tree file at all, sorry" * 4)
    with pytest.raises(ArborError, match="garbage.bvh.*bad magic"):
        Bvh.load(bad)
    with pytest.raises(ArborError, match="cannot read tree file"):
        Bvh.load(tmp_path / "missing.bvh")
    with pytest.raises(ArborError, match="cannot write tree file"):
        core.build_bvh(mesh).save(tmp_path / "no-such-dir" / "t.bvh")


# ----------------------------------------------------------------------------- tracing


def test_trace_matches_brute_force_moller_trumbore(mesh: core.Mesh) -> None:
    o, d = random_rays(mesh, 300, seed=3)
    bvh = core.build_bvh(mesh, builder="binned-sah")
    hits = core.trace(bvh, mesh.vertices, mesh.indices, o, d)
    assert len(hits) == 300 and hits.t.dtype == np.float32 and hits.primitive.dtype == np.uint32
    t, prim, u, v = moller_trumbore(o, d, triangles(mesh.vertices, mesh.indices))
    assert (prim >= 0).sum() > 50  # the test has hits to compare
    # Hit or miss agrees, except for rays that graze an edge within rounding.
    agree = hits.hit == (prim >= 0)
    assert agree.mean() > 0.98
    both = agree & hits.hit
    np.testing.assert_allclose(hits.t[both], t[both], rtol=1e-4)
    same = both & (hits.primitive == prim)
    assert same.sum() >= 0.97 * both.sum()  # the rest are ties at shared edges
    np.testing.assert_allclose(hits.u[same], u[same], atol=1e-3)
    np.testing.assert_allclose(hits.v[same], v[same], atol=1e-3)
    # Misses.
    assert np.isinf(hits.t[~hits.hit]).all() and (hits.primitive[~hits.hit] == core.NO_HIT).all()
    # The crate's brute force gives the very same hits, bit for bit.
    ref = core.trace_brute_force(mesh.vertices, mesh.indices, o, d)
    np.testing.assert_array_equal(ref.primitive, hits.primitive)
    np.testing.assert_array_equal(ref.t, hits.t)
    # Counters: every hit ray tested a triangle and visited the root.
    assert (hits.node_visits >= 1).all() and (hits.tri_tests[hits.hit] >= 1).all()
    tot = hits.totals
    assert tot["rays"] == 300 and tot["hits"] == int(hits.hit.sum())
    assert tot["node_visits"] == int(hits.node_visits.sum())


def test_every_kernel_and_tree_gives_the_same_hits(mesh: core.Mesh) -> None:
    o, d = random_rays(mesh, 200, seed=4)
    v, ix = mesh.vertices, mesh.indices
    ref = core.trace(core.build_bvh(mesh, builder="sweep-sah"), v, ix, o, d)
    binary = core.build_bvh(mesh, builder="lbvh")
    for kernel in ("bvh2", "mbvh4", "mbvh8", "cbvh"):
        h = core.trace(binary, v, ix, o, d, kernel=kernel, distance_stack=kernel != "bvh2")
        assert h.kernel == kernel
        np.testing.assert_array_equal(h.primitive, ref.primitive)
        np.testing.assert_array_equal(h.t, ref.t)
    wide = core.build_bvh(mesh, builder="mbvh4-topdown")
    h = core.trace_mesh(wide, mesh, o, d)
    assert h.kernel == "mbvh4"
    np.testing.assert_array_equal(h.primitive, ref.primitive)
    # Ranges: a tmax just below each hit removes it; any-hit finds every occluded ray.
    tmax = np.where(ref.hit, ref.t * 0.999, np.inf).astype(np.float32)
    clipped = core.trace(binary, v, ix, o, d, tmax=tmax)
    assert not (clipped.hit & ref.hit & (clipped.primitive == ref.primitive)).any()
    occluded = core.trace(binary, v, ix, o, d, any_hit=True)
    np.testing.assert_array_equal(occluded.hit, ref.hit)
    far = core.trace(binary, v, ix, o, d, tmin=1e9)
    assert not far.hit.any()


def test_trace_errors(mesh: core.Mesh) -> None:
    o, d = random_rays(mesh, 10, seed=5)
    bvh = core.build_bvh(mesh)
    v, ix = mesh.vertices, mesh.indices
    with pytest.raises(ArborError, match="differ in length"):
        core.trace(bvh, v, ix, o, d[:5])
    with pytest.raises(ArborError, match=r"directions\[2\]"):
        z = d.copy()
        z[2] = 0
        core.trace(bvh, v, ix, o, z)
    with pytest.raises(ArborError, match=r"origins\[1\]"):
        n = o.copy()
        n[1, 0] = np.nan
        core.trace(bvh, v, ix, n, d)
    with pytest.raises(ArborError, match=r"tmax must be a number or have shape \(10,\)"):
        core.trace(bvh, v, ix, o, d, tmax=np.ones(3))
    with pytest.raises(ArborError, match="unknown kernel"):
        core.trace(bvh, v, ix, o, d, kernel="gpu")  # type: ignore[arg-type]
    with pytest.raises(ArborError, match="primitives but 100 triangles"):
        core.trace(bvh, v, ix[:100], o, d)
    with pytest.raises(ArborError, match="binary tree"):
        core.trace(bvh.collapse(), v, ix, o, d, kernel="bvh2")


def test_camera_rays(scene: core.Scene, mesh: core.Mesh) -> None:
    w, h = 24, 16
    rays = core.camera_rays(scene.camera, w, h)
    assert len(rays) == w * h and rays.kind == "primary"
    assert rays.origins.shape == rays.directions.shape == (w * h, 3)
    np.testing.assert_allclose(np.linalg.norm(rays.directions, axis=1), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(rays.pixel, np.arange(w * h))
    np.testing.assert_allclose(rays.origins, np.broadcast_to(scene.camera.eye, (w * h, 3)))
    # Row-major, row 0 at the top: x grows along a row, y falls down the image.
    grid = rays.directions.reshape(h, w, 3)
    fwd = np.subtract(scene.camera.target, scene.camera.eye)
    assert np.all(grid @ fwd > 0)
    # The centre ray looks at the target (even image: between the 4 central pixels).
    centre = grid[h // 2 - 1 : h // 2 + 1, w // 2 - 1 : w // 2 + 1].reshape(-1, 3).mean(0)
    np.testing.assert_allclose(
        centre / np.linalg.norm(centre), fwd / np.linalg.norm(fwd), atol=1e-4
    )
    # Diffuse paths: the primary ray of every pixel, then bounces from the surface.
    bvh = core.build_bvh(mesh)
    cam = core.Camera.framing(mesh.bounds)
    dr = core.camera_rays(
        cam,
        w,
        h,
        "diffuse",
        bvh=bvh,
        vertices=mesh.vertices,
        indices=mesh.indices,
        bounces=2,
        seed=7,
    )
    assert dr.kind == "diffuse" and (dr.bounce == 0).sum() == w * h
    assert (dr.bounce > 0).sum() > 0 and dr.bounce.max() <= 2
    np.testing.assert_allclose(np.linalg.norm(dr.directions, axis=1), 1.0, rtol=1e-4)
    primary = core.trace(
        bvh, mesh.vertices, mesh.indices, dr.origins[dr.bounce == 0], dr.directions[dr.bounce == 0]
    )
    assert (dr.bounce == 1).sum() == primary.hit.sum()  # one bounce per primary hit
    again = core.camera_rays(
        cam,
        w,
        h,
        "diffuse",
        bvh=bvh,
        vertices=mesh.vertices,
        indices=mesh.indices,
        bounces=2,
        seed=7,
    )
    np.testing.assert_array_equal(again.directions, dr.directions)  # deterministic
    with pytest.raises(ArborError, match="pass bvh"):
        core.camera_rays(cam, w, h, "diffuse")
    with pytest.raises(ArborError, match="unknown ray kind"):
        core.camera_rays(cam, w, h, "sideways")  # type: ignore[arg-type]
    with pytest.raises(ArborError, match="image size"):
        core.camera_rays(cam, 0, h)
    with pytest.raises(ArborError, match="same point"):
        core.camera_rays(core.Camera((1, 2, 3), (1, 2, 3)), w, h)


# -------------------------------------------------------------------------------- CBVH


def test_cbvh_statistics(mesh: core.Mesh) -> None:
    bvh = core.build_bvh(mesh, builder="lbvh")
    s = core.encode_cbvh(bvh)
    assert s["encoder"] == "bottomup" and s["bits"] == 6 and s["coords"] == "modulo"
    assert s["nodes"] == bvh.node_count and s["triangles"] == mesh.triangle_count
    assert s["node_bytes"] == 16 * s["nodes"] < s["uncompressed_node_bytes"] == 64 * bvh.node_count
    assert s["compression_ratio"] == pytest.approx(0.25)
    assert s["decoded_encloses_original"] and s["enclosure_violations"] == 0
    assert s["sah_uncompressed"] == pytest.approx(bvh.sah())
    assert 1.0 <= s["sah_vs_uncompressed"] < 1.5
    assert s["backtrack_steps"] == sum(s["backtrack_depth_hist"])
    td = core.encode_cbvh(
        bvh, mesh.vertices, mesh.indices, encoder="topdown", coords="relative", bits=8
    )
    assert td["encoder"] == "topdown" and td["backtrack_steps"] == 0
    assert td["node_bytes"] < td["uncompressed_node_bytes"] and td["decoded_encloses_original"]
    tl = core.encode_cbvh(bvh, treelet=3)
    assert tl["decoded_encloses_original"]
    with pytest.raises(ArborError, match="bits"):
        core.encode_cbvh(bvh, bits=2)
    with pytest.raises(ArborError, match="treelet"):
        core.encode_cbvh(bvh, encoder="topdown", treelet=2)
    with pytest.raises(ArborError, match="unknown encoder"):
        core.encode_cbvh(bvh, encoder="sideways")  # type: ignore[arg-type]
    with pytest.raises(ArborError, match="4-wide"):
        core.encode_cbvh(bvh.collapse())


# --------------------------------------------------------------------------- threading


def test_builds_run_in_parallel_threads(mesh: core.Mesh) -> None:
    """The GIL is released around builds: several Python threads build at once and get
    the same tree as a build on the main thread."""
    ref = core.build_bvh(mesh, builder="sweep-sah")
    out: list[Bvh] = []
    errors: list[BaseException] = []

    def work() -> None:
        try:
            out.append(core.build_bvh(mesh, builder="sweep-sah"))
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and len(out) == 4 and all(b == ref for b in out)
