"""Instances from Python (`arbor.InstanceCaster`): closest and any hits against a brute
force in world space (each instance's triangles moved into the world with numpy, traced by
a flat `RayCaster` over their union), after `set_transforms` and mesh refits, pickling,
`out=` buffers and clean errors for bad transforms."""

from __future__ import annotations

import pickle
import threading
from typing import Literal

import numpy as np
import pytest

import arbor
from arbor import ArborError, InstanceCaster, InstanceHits, RayCaster
from shapes import icosphere

CLOTH = "proc:cloth?n=2000&seed=1"
Kernel = Literal["bvh2", "mbvh4", "mbvh8", "cbvh"]
KERNELS: tuple[Kernel, ...] = ("bvh2", "mbvh4", "mbvh8", "cbvh")


@pytest.fixture(scope="module")
def meshes() -> list[tuple[np.ndarray, np.ndarray]]:
    cloth = arbor.open_scene(CLOTH).mesh(frame=5)
    cv = np.asarray(cloth.vertices, np.float32)
    cv = (cv - cv.mean(axis=0)) / np.abs(cv - cv.mean(axis=0)).max()  # about unit size
    return [(cv.astype(np.float32), np.asarray(cloth.indices, np.int64)), icosphere(3)]


def random_transforms(k: int, seed: int, homogeneous: bool = False) -> np.ndarray:
    """`k` affine transforms: rotation, non-uniform scale (one mirrored), a little shear,
    and translations on a line with some overlap between neighbours."""
    rng = np.random.default_rng(seed)
    out = np.zeros((k, 4, 4))
    for i in range(k):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        s = np.diag(rng.uniform(0.5, 1.6, 3) * (-1 if i == 1 else 1))
        shear = np.eye(3) + 0.2 * np.triu(rng.normal(size=(3, 3)), 1)
        out[i, :3, :3] = q @ s @ shear
        out[i, :3, 3] = [1.8 * i, rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)]
        out[i, 3, 3] = 1
    return out if homogeneous else out[:, :3, :]


def world_meshes(
    meshes: list[tuple[np.ndarray, np.ndarray]], xf: np.ndarray, mesh_index: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each instance's triangles moved into world space (float64, then float32)."""
    out = []
    for m, x in zip(mesh_index, xf):
        v, f = meshes[m]
        w = np.asarray(v, np.float64) @ x[:3, :3].T + x[:3, 3]
        out.append((w.astype(np.float32), f))
    return out


def rays_through(lo: np.ndarray, hi: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, ...]:
    """Rays from a sphere around the box [lo, hi] towards random points in it."""
    rng = np.random.default_rng(seed)
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo)
    dirs = rng.normal(size=(n, 3))
    origins = c + r * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    targets = lo + rng.random((n, 3)) * (hi - lo)
    return origins.astype(np.float32), (targets - origins).astype(np.float32)


def check_against_flat(
    ic: InstanceCaster,
    meshes: list[tuple[np.ndarray, np.ndarray]],
    xf: np.ndarray,
    mesh_index: np.ndarray,
    seed: int,
) -> None:
    """`ic`'s hits equal those of a flat ray caster over the world-space triangles."""
    world = world_meshes(meshes, xf, mesh_index)
    flat = RayCaster.from_meshes(world)
    allv = np.concatenate([w[0] for w in world])
    o, d = rays_through(allv.min(axis=0), allv.max(axis=0), 3000, seed)
    h, ref = ic.intersect(o, d), flat.intersect(o, d)
    assert isinstance(h, InstanceHits) and len(h) == len(o)
    assert ref.hit.sum() > len(o) // 4  # there are hits to compare
    np.testing.assert_array_equal(h.hit, ref.hit)
    np.testing.assert_array_equal(h.instance, ref.geometry)
    np.testing.assert_array_equal(h.primitive, ref.geometry_primitive)
    np.testing.assert_array_equal(h.geometry[h.hit], mesh_index[h.instance[h.hit]])
    assert (h.instance[~h.hit] == arbor.NO_HIT).all() and np.isinf(h.t[~h.hit]).all()
    np.testing.assert_allclose(h.t[h.hit], ref.t[h.hit], rtol=1e-4)
    scale = float(np.abs(allv).max())
    np.testing.assert_allclose(h.location[h.hit], ref.location[h.hit], atol=1e-4 * scale)
    np.testing.assert_allclose(h.normal[h.hit], ref.normal[h.hit], atol=2e-3)
    assert np.isnan(h.normal[~h.hit]).all() and np.isnan(h.location[~h.hit]).all()
    # Barycentrics: the world location is the weighted world triangle.
    tri = np.stack(
        [world[i][0][world[i][1][p]] for i, p in zip(h.instance[h.hit], h.primitive[h.hit])]
    )
    u, w = h.u[h.hit, None], h.v[h.hit, None]
    bary = (1 - u - w) * tri[:, 0] + u * tri[:, 1] + w * tri[:, 2]
    np.testing.assert_allclose(h.location[h.hit], bary, atol=1e-4 * scale)
    np.testing.assert_array_equal(ic.occluded(o, d), ref.hit)


@pytest.mark.parametrize("kernel", KERNELS)
def test_instances_match_a_flat_world_space_tree(
    meshes: list[tuple[np.ndarray, np.ndarray]], kernel: Kernel
) -> None:
    mesh_index = np.array([0, 1, 1, 0, 1, 0])
    xf = random_transforms(6, seed=1)
    ic = InstanceCaster(meshes, xf, mesh_index, kernel=kernel)
    assert ic.kernels == [kernel, kernel] and ic.instance_count == 6 and ic.mesh_count == 2
    assert ic.generation == 0 and len(ic) == 6
    np.testing.assert_array_equal(ic.mesh_index, mesh_index)
    np.testing.assert_allclose(ic.transforms, xf, rtol=1e-6, atol=1e-6)
    check_against_flat(ic, meshes, xf, mesh_index, seed=2)

    # Move every instance (4x4 matrices this time): refitted top level, then rebuilt.
    xf2 = random_transforms(6, seed=3, homogeneous=True)
    ic.set_transforms(xf2)
    assert ic.generation == 1
    check_against_flat(ic, meshes, xf2, mesh_index, seed=4)
    ic.set_transforms(xf2[:, :3], rebuild=True)
    check_against_flat(ic, meshes, xf2, mesh_index, seed=4)

    # Deform mesh 1 (the sphere, instanced three times) in place.
    v1, f1 = meshes[1]
    bumped = (v1 * (1 + 0.2 * np.sin(4 * v1[:, :1]))).astype(np.float32)
    ic.refit(1, bumped)
    assert ic.generation == 3
    check_against_flat(ic, [meshes[0], (bumped, f1)], xf2, mesh_index, seed=5)


def test_ray_casters_as_meshes_and_defaults(meshes: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """RayCasters are reused as bottom levels (each with its own kernel); with one mesh
    every instance shows it, with K meshes instance i shows mesh i."""
    casters = [RayCaster(*meshes[0], kernel="mbvh8"), RayCaster(*meshes[1], kernel="cbvh")]
    xf = random_transforms(2, seed=6)
    ic = InstanceCaster(casters, xf)
    assert ic.kernels == ["mbvh8", "cbvh"]
    np.testing.assert_array_equal(ic.mesh_index, [0, 1])
    check_against_flat(ic, meshes, xf, np.array([0, 1]), seed=7)
    one = InstanceCaster([casters[1]], random_transforms(3, seed=8))
    np.testing.assert_array_equal(one.mesh_index, [0, 0, 0])
    # The caster given is copied: refitting it does not move the instances.
    casters[1].refit(meshes[1][0] * 2)
    check_against_flat(ic, meshes, xf, np.array([0, 1]), seed=7)


def test_pickle_out_buffers_and_few_rays(
    meshes: list[tuple[np.ndarray, np.ndarray]],
) -> None:
    mesh_index = np.array([1, 0, 1])
    xf = random_transforms(3, seed=9)
    ic = InstanceCaster(meshes, xf, mesh_index, kernel="mbvh4")
    ic.set_transforms(random_transforms(3, seed=10))
    back = pickle.loads(pickle.dumps(ic))
    assert back.generation == 1 and back.kernels == ["mbvh4", "mbvh4"]
    np.testing.assert_array_equal(back.transforms, ic.transforms)
    o, d = rays_through(np.array([-2.0, -2, -2]), np.array([6.0, 2, 2]), 2000, seed=11)
    h, hb = ic.intersect(o, d), back.intersect(o, d)
    for name in ("t", "instance", "primitive", "u", "v", "hit"):
        np.testing.assert_array_equal(getattr(h, name), getattr(hb, name))
    # A result pickles with its normals.
    hp = pickle.loads(pickle.dumps(h))
    np.testing.assert_array_equal(hp.normal, h.normal)
    np.testing.assert_array_equal(hp.geometry, h.geometry)
    # out=: the arrays are reused.
    again = ic.intersect(o[::-1].copy(), d[::-1].copy(), out=hb)
    assert again.t is hb.t
    np.testing.assert_array_equal(again.primitive, h.primitive[::-1])
    buf = np.zeros(len(o), bool)
    assert ic.occluded(o, d, out=buf) is buf
    np.testing.assert_array_equal(buf, h.hit)
    # Few rays (the serial path) agree with many (the parallel path).
    for i in range(0, 2000, 397):
        one = ic.intersect(o[i : i + 1], d[i : i + 1])
        assert one.instance[0] == h.instance[i] and one.t[0] == h.t[i]


def test_bad_input_is_a_clear_error(meshes: list[tuple[np.ndarray, np.ndarray]]) -> None:
    xf = random_transforms(2, seed=12)
    ic = InstanceCaster(meshes, xf)
    singular = xf.copy()
    singular[1, :, 2] = singular[1, :, 0]  # two equal columns
    nan = xf.copy()
    nan[0, 1, 1] = np.nan
    huge = xf.copy()
    huge[1, 0, 3] = 1e300  # not finite in float32
    projective = random_transforms(2, seed=12, homogeneous=True)
    projective[0, 3, 0] = 0.5
    cases = [
        (singular, r"transforms\[1\]: bad transform: singular"),
        (nan, r"transforms\[0\]: bad transform: non-finite"),
        (huge, r"transforms\[1\]: bad transform: non-finite"),
        (projective, r"transforms\[0\] is not affine"),
        (xf[0], r"shape \(K, 3, 4\) or \(K, 4, 4\), got \(3, 4\)"),
        (np.zeros((2, 3, 3)), r"got \(2, 3, 3\)"),
        (xf[:1], "1 transforms given for 2 instances"),
        ([["a"]], "transforms"),
    ]
    for bad, msg in cases:
        with pytest.raises(ArborError, match=msg):
            ic.set_transforms(bad)
        with pytest.raises(ArborError):
            InstanceCaster(meshes, bad)
    assert ic.generation == 0  # nothing changed
    with pytest.raises(ArborError, match="mesh_index\\[1\\] is 2, but there are 2 meshes"):
        InstanceCaster(meshes, xf, [0, 2])
    with pytest.raises(ArborError, match="mesh_index\\[0\\] is -1"):
        InstanceCaster(meshes, xf, [-1, 0])
    with pytest.raises(ArborError, match="mesh_index must be integers"):
        InstanceCaster(meshes, xf, [0.5, 1.0])
    with pytest.raises(ArborError, match="2 meshes and 3 transforms: pass mesh_index"):
        InstanceCaster(meshes, random_transforms(3, seed=1))
    with pytest.raises(ArborError, match="3 transforms given for 2 instances"):
        InstanceCaster(meshes, random_transforms(3, seed=1), [0, 1])
    with pytest.raises(ArborError, match="at least one instance"):
        InstanceCaster(meshes[:1], np.zeros((0, 3, 4)))
    with pytest.raises(ArborError, match="at least one mesh"):
        InstanceCaster([], xf)
    with pytest.raises(ArborError, match="meshes must be a sequence"):
        InstanceCaster(3, xf)  # type: ignore[arg-type]
    with pytest.raises(ArborError, match=r"meshes\[1\] is neither"):
        InstanceCaster([meshes[0], 5], xf)
    with pytest.raises(ArborError, match="no mesh 2"):
        ic.refit(2, meshes[0][0])
    with pytest.raises(ArborError, match="non-negative"):
        ic.refit(-1, meshes[0][0])
    with pytest.raises(ArborError, match="refit keeps the topology"):
        ic.refit(0, meshes[1][0])
    bad_v = meshes[0][0].copy()
    bad_v[3] = np.nan
    with pytest.raises(ArborError, match="non-finite"):
        ic.refit(0, bad_v)
    with pytest.raises(ArborError, match="directions"):
        ic.intersect(np.zeros((1, 3)), np.zeros((1, 3)))
    assert ic.generation == 0


def test_threads_trace_while_another_moves_the_instances(
    meshes: list[tuple[np.ndarray, np.ndarray]],
) -> None:
    """Queries and transform updates from several threads wait for each other: every
    result is the one of the transforms of the generation it reports."""
    mesh_index = np.array([0, 1, 0])
    poses = [random_transforms(3, seed=20), random_transforms(3, seed=21)]
    ic = InstanceCaster(meshes, poses[0], mesh_index)
    o, d = rays_through(np.array([-2.0, -2, -2]), np.array([6.0, 2, 2]), 2000, seed=22)
    want = []
    for p in poses:
        ic.set_transforms(p)
        want.append(ic.intersect(o, d).t)
    assert not np.array_equal(want[0], want[1])
    errors: list[BaseException] = []
    stop = threading.Event()

    def move() -> None:
        try:
            for k in range(200):
                ic.set_transforms(poses[k % 2])
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)
        finally:
            stop.set()

    def query() -> None:
        try:
            while not stop.is_set():
                h = ic.intersect(o, d)
                # Generation g >= 2 holds poses[(g + 1) % 2] (generation 1 held poses[0]).
                np.testing.assert_array_equal(h.t, want[(h.generation + 1) % 2])
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=move)] + [threading.Thread(target=query) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert ic.generation == 202
