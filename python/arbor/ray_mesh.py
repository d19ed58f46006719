"""A trimesh-shaped ray intersector over :class:`arbor.RayCaster`.

:class:`RayMeshIntersector` has the methods and return conventions of
``trimesh.ray.ray_pyembree.RayMeshIntersector`` (``intersects_first``, ``intersects_any``,
``intersects_id``, ``intersects_location``, ``contains_points``), so code written against
``mesh.ray`` switches with one line::

    mesh.ray = arbor.RayMeshIntersector(mesh)

Differences from trimesh: coordinates are traced in float32 (as Embree does); multiple hits
along a ray (:meth:`arbor.RayCaster.intersect_all`) restart each ray just past its last
hit, so two triangles hit at exactly the same distance (a ray through a shared edge) count
once, and come ray by ray rather than depth by depth; the structure is built once, and
``refit`` moves the vertices of the same triangles.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from ._arbor import NO_HIT, ArborError, RayCaster

__all__ = ["RayMeshIntersector"]

_I64 = npt.NDArray[np.int64]
_F64 = npt.NDArray[np.float64]
_B = npt.NDArray[np.bool_]


def _rays(origins: npt.ArrayLike, directions: npt.ArrayLike) -> tuple[Any, Any]:
    o = np.asarray(origins, dtype=np.float32)
    d = np.asarray(directions, dtype=np.float32)
    if o.shape != d.shape:
        raise ArborError("ray origins and directions differ in shape")
    return o.reshape(-1, 3), d.reshape(-1, 3)


class RayMeshIntersector:
    """Ray queries on a triangle mesh: ``mesh`` is anything with ``vertices`` (N, 3) and
    ``faces`` (M, 3) (a ``trimesh.Trimesh``) or ``indices`` (an :class:`arbor.Mesh`).
    ``builder`` and ``kernel`` are those of :class:`arbor.RayCaster`."""

    def __init__(
        self,
        mesh: Any,
        *,
        builder: str = "binned-sah",
        kernel: Any = None,
    ) -> None:
        faces = getattr(mesh, "faces", None)
        if faces is None:
            faces = getattr(mesh, "indices", None)
        if faces is None or getattr(mesh, "vertices", None) is None:
            raise ArborError("the mesh needs vertices and faces (or indices)")
        self.mesh = mesh
        v = np.asarray(mesh.vertices, dtype=np.float32)
        self.caster = RayCaster(v, faces, builder, kernel=kernel)

    def refit(self, vertices: npt.ArrayLike) -> None:
        """Moves the vertices (same triangles); see :meth:`arbor.RayCaster.refit`."""
        v = np.asarray(vertices, dtype=np.float32)
        self.caster.refit(v)

    def intersects_first(self, ray_origins: npt.ArrayLike, ray_directions: npt.ArrayLike) -> _I64:
        """Index of the first triangle each ray hits, -1 for a miss."""
        o, d = _rays(ray_origins, ray_directions)
        prim = self.caster.closest_primitives(o, d)
        return np.where(prim == NO_HIT, -1, prim.astype(np.int64))

    def intersects_any(self, ray_origins: npt.ArrayLike, ray_directions: npt.ArrayLike) -> _B:
        """Whether each ray hits the mesh."""
        o, d = _rays(ray_origins, ray_directions)
        return self.caster.occluded(o, d)

    def intersects_id(
        self,
        ray_origins: npt.ArrayLike,
        ray_directions: npt.ArrayLike,
        multiple_hits: bool = True,
        max_hits: int = 100,
        return_locations: bool = False,
    ) -> tuple[_I64, _I64] | tuple[_I64, _I64, _F64]:
        """``(index_tri, index_ray)`` of every hit (only the first per ray unless
        ``multiple_hits``, at most ``max_hits`` per ray), and their locations (m, 3) with
        ``return_locations``. Hits come ray by ray, nearest first (trimesh orders them by
        depth); each ray's first entry is its nearest hit either way."""
        o, d = _rays(ray_origins, ray_directions)
        if multiple_hits:
            ray, tri, t = self.caster.intersect_all(o, d, max_hits=max_hits)
            index_ray, index_tri = ray.astype(np.int64), tri.astype(np.int64)
            o64, d64 = o.astype(np.float64), d.astype(np.float64)
            locations = o64[index_ray] + t.astype(np.float64)[:, None] * d64[index_ray]
        else:
            h = self.caster.intersect(o, d)
            index_ray = np.flatnonzero(h.hit).astype(np.int64)
            index_tri = h.primitive[h.hit].astype(np.int64)
            locations = h.location[h.hit].astype(np.float64)
        if return_locations:
            return index_tri, index_ray, locations
        return index_tri, index_ray

    def intersects_location(
        self,
        ray_origins: npt.ArrayLike,
        ray_directions: npt.ArrayLike,
        multiple_hits: bool = True,
    ) -> tuple[_F64, _I64, _I64]:
        """``(locations, index_ray, index_tri)`` of every hit, as trimesh returns them."""
        index_tri, index_ray, locations = self.intersects_id(
            ray_origins, ray_directions, multiple_hits=multiple_hits, return_locations=True
        )  # type: ignore[misc]
        return locations, index_ray, index_tri

    def contains_points(self, points: npt.ArrayLike) -> _B:
        """Whether each point lies inside the (closed) mesh: the parity of the surface
        crossings along rays from the point in three fixed directions, by majority
        (:meth:`arbor.RayCaster.contains_points`; undefined on the surface)."""
        p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        return self.caster.contains_points(p)
