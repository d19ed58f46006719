"""Arbor's typed API: scenes, BVHs, tracing and CBVHs over numpy arrays.

The classes and functions are those of the native module :mod:`arbor._arbor` (its stubs,
``_arbor.pyi``, document every signature); this module re-exports them with a few
conveniences that take a :class:`Mesh` instead of separate arrays.

Example::

    import arbor
    scene = arbor.open_scene("proc:cloth?n=2000&seed=1")
    mesh = scene.mesh(frame=3)
    bvh = arbor.build_bvh(mesh, builder="sweep-sah")
    bvh.validate()
    rays = arbor.camera_rays(scene.camera, 64, 48)
    hits = arbor.trace(bvh, mesh.vertices, mesh.indices, rays.origins, rays.directions)
    print(hits.hit.mean(), hits.totals["node_visits"] / len(hits))

Every failure raises :class:`arbor.ArborError` with the one-line message the ``arbor``
command prints for the same problem (option errors name the Python argument).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Union

import numpy as np
import numpy.typing as npt

from ._arbor import (
    DEFAULT_BUILDER,
    NO_HIT,
    ArborError,
    Bvh,
    Camera,
    Hits,
    InstanceCaster,
    InstanceHits,
    Mesh,
    RayCaster,
    RayHits,
    Rays,
    Scene,
    builders,
    camera_rays,
    encode_cbvh,
    trace,
    trace_brute_force,
)

from .ray_mesh import RayMeshIntersector

if TYPE_CHECKING:
    from ._arbor import _KernelName

__all__ = [
    "ArborError",
    "BVH2_NODE_DTYPE",
    "Bvh",
    "Camera",
    "CHILD_DTYPE",
    "DEFAULT_BUILDER",
    "Hits",
    "InstanceCaster",
    "InstanceHits",
    "MBVH4_NODE_DTYPE",
    "Mesh",
    "NO_HIT",
    "RayCaster",
    "RayHits",
    "RayMeshIntersector",
    "Rays",
    "Scene",
    "build_bvh",
    "builders",
    "camera_rays",
    "encode_cbvh",
    "load_bvh",
    "open_scene",
    "trace",
    "trace_brute_force",
    "trace_mesh",
]

#: One child reference of a node: a node index or the first leaf-table entry, and a leaf
#: size (0 for an inner or absent child).
CHILD_DTYPE: np.dtype[np.void] = np.dtype([("index", "<u4"), ("count", "<u4")])

#: A ``Bvh2`` node (64 bytes, [P2] §4.1 Fig. 2): ``bounds[child, 0]`` is the min corner
#: of child 0 or 1, ``bounds[child, 1]`` its max corner; then both child references.
BVH2_NODE_DTYPE: np.dtype[np.void] = np.dtype(
    [("bounds", "<f4", (2, 2, 3)), ("children", CHILD_DTYPE, (2,))]
)

#: An ``Mbvh4`` node (128 bytes, [P4] §3.1): the four child boxes as structure of arrays,
#: then the four child references (empty slots last).
MBVH4_NODE_DTYPE: np.dtype[np.void] = np.dtype(
    [(name, "<f4", (4,)) for name in ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z")]
    + [("children", CHILD_DTYPE, (4,))]
)

_Geometry = Union[Mesh, npt.ArrayLike]


def open_scene(spec: str, *, fps: float | None = None, animation: str | None = None) -> Scene:
    """Opens a scene spec: a mesh file, a glTF file, a directory or glob of frames, or
    ``proc:NAME?key=value&...`` (the same specs as every ``arbor`` command)."""
    return Scene(spec, fps=fps, animation=animation)


def _arrays(geometry: _Geometry, indices: npt.ArrayLike | None) -> tuple[Any, Any]:
    """``(vertices, indices)`` of a mesh, or the arrays given."""
    if isinstance(geometry, Mesh):
        if indices is not None:
            raise ArborError("give a Mesh or vertices and indices, not both")
        return geometry.vertices, geometry.indices
    if indices is None:
        raise ArborError("indices are required with a vertex array")
    return geometry, indices


def build_bvh(
    geometry: _Geometry,
    indices: npt.ArrayLike | None = None,
    builder: str = DEFAULT_BUILDER,
    *,
    max_leaf: int | None = None,
    bins: int | None = None,
    collapse_from: str | None = None,
    threads: int | None = None,
) -> Bvh:
    """Builds a BVH over a :class:`Mesh`, or over ``vertices`` (float32 (N, 3)) and
    ``indices`` (uint32 (M, 3)), with a builder of ``arbor build`` (see :func:`builders`)
    and its options. See :meth:`Bvh.build`."""
    v, ix = _arrays(geometry, indices)
    return Bvh.build(
        v,
        ix,
        builder,
        max_leaf=max_leaf,
        bins=bins,
        collapse_from=collapse_from,
        threads=threads,
    )


def load_bvh(path: str | os.PathLike[str]) -> Bvh:
    """Reads a tree file written by :meth:`Bvh.save` or ``arbor build --out``."""
    return Bvh.load(path)


def trace_mesh(
    bvh: Bvh,
    mesh: Mesh,
    origins: npt.ArrayLike,
    directions: npt.ArrayLike,
    tmin: float | npt.ArrayLike = 0.0,
    tmax: float | npt.ArrayLike = float("inf"),
    *,
    kernel: _KernelName | None = None,
    distance_stack: bool | None = None,
    any_hit: bool = False,
) -> Hits:
    """:func:`trace` with the vertices and indices of ``mesh``."""
    return trace(
        bvh,
        mesh.vertices,
        mesh.indices,
        origins,
        directions,
        tmin,
        tmax,
        kernel=kernel,
        distance_stack=distance_stack,
        any_hit=any_hit,
    )
