"""Type stubs of ``arbor._arbor``, the native module (PyO3, ``python/src``).

Every function raises :class:`ArborError` with a one-line message on bad input (a bad spec,
option, array shape, dtype, NaN or out-of-range index) or a failed run; none crashes the
interpreter. Long work (scene loads, builds, refits, traces, encodes) runs with the GIL
released.

Arrays in: any array-like that numpy converts to the documented dtype and shape; an array
that already is C-contiguous, aligned and of that dtype is used without a copy. Arrays
out: fresh arrays that own (or view) memory moved from Rust, no extra copy.
"""

from __future__ import annotations

import os
from typing import Any, Final, Literal, Sequence, final

import numpy as np
import numpy.typing as npt

__version__: str

__all__ = [
    "ArborError",
    "__version__",
    "run_json",
    "check_args",
    "Camera",
    "Mesh",
    "Scene",
    "Bvh",
    "builders",
    "DEFAULT_BUILDER",
    "Hits",
    "InstanceCaster",
    "InstanceHits",
    "RayCaster",
    "RayHits",
    "Rays",
    "trace",
    "trace_brute_force",
    "camera_rays",
    "NO_HIT",
    "encode_cbvh",
]

#: Primitive id of a ray that hit nothing (``2**32 - 1``).
NO_HIT: Final[int]
#: The builder :meth:`Bvh.build` uses when none is named.
DEFAULT_BUILDER: Final[str]

_F32 = npt.NDArray[np.float32]
_U32 = npt.NDArray[np.uint32]

class ArborError(Exception):
    """An Arbor error: bad input, a bad option or a failed run; the message is the one line
    the ``arbor`` command prints."""

def run_json(args: list[str]) -> str:
    """Runs one ``arbor`` command line (without the program name) quietly and returns the
    JSON documents it produced, as a JSON array (text)."""

def check_args(args: list[str]) -> None:
    """Checks a command line without running it (raises :class:`ArborError`)."""

# ---------------------------------------------------------------------------- scenes

@final
class Camera:
    """A pinhole camera: eye, target, up and vertical field of view in degrees."""

    def __new__(
        cls,
        eye: tuple[float, float, float] | list[float],
        target: tuple[float, float, float] | list[float],
        up: tuple[float, float, float] | list[float] = (0.0, 1.0, 0.0),
        vfov_deg: float = 45.0,
    ) -> Camera: ...
    @staticmethod
    def framing(bounds: npt.ArrayLike) -> Camera:
        """The camera that frames ``bounds`` ((2, 3): min row, max row), as a scene's
        default camera does."""
    @property
    def eye(self) -> tuple[float, float, float]: ...
    @property
    def target(self) -> tuple[float, float, float]: ...
    @property
    def up(self) -> tuple[float, float, float]: ...
    @property
    def vfov_deg(self) -> float: ...

@final
class Mesh:
    """A triangle mesh at one time. Triangle ``i`` is ``indices[i]``; in a scene with
    stable topology, ``i`` is the same primitive in every frame."""

    @property
    def vertices(self) -> _F32:
        """Vertex positions, float32 (N, 3)."""
    @property
    def indices(self) -> _U32:
        """Vertex indices of each triangle, uint32 (M, 3)."""
    @property
    def material_ids(self) -> _U32:
        """Material id of each triangle, uint32 (M,) (index into ``material_names``)."""
    @property
    def material_names(self) -> list[str]: ...
    @property
    def time(self) -> float:
        """The time sampled, in seconds."""
    @property
    def bounds(self) -> _F32:
        """Bounds of the referenced vertices, float32 (2, 3): min row, max row (``+inf``
        over ``-inf`` for an empty mesh)."""
    @property
    def triangle_count(self) -> int: ...
    @property
    def vertex_count(self) -> int: ...
    def __len__(self) -> int: ...

@final
class Scene:
    """A scene opened from a spec, as every ``arbor`` command takes it: a mesh file (OBJ,
    PLY), a glTF 2.0 file (``.gltf``/``.glb``, skins and animation), a directory or glob of
    frame files, or ``proc:NAME?key=value&...``."""

    def __new__(cls, spec: str, *, fps: float | None = None, animation: str | None = None) -> Scene:
        """Opens ``spec``; ``fps`` numbers the frames of a frame sequence, ``animation``
        picks a glTF animation by index or name."""
    def mesh(self, time: float | None = None, frame: int | None = None) -> Mesh:
        """The mesh at ``time`` seconds or of frame ``frame``; time 0 when neither is
        given. A time outside the timeline (0 to ``duration``) or a frame past the last
        raises ``ArborError``, as ``--time`` / ``--frame`` do on the command line."""
    def time_of_frame(self, frame: int) -> float: ...
    @property
    def name(self) -> str: ...
    @property
    def spec(self) -> str: ...
    @property
    def format(self) -> str:
        """``ply``, ``obj``, ``gltf``, ``keyframes`` or ``procedural``."""
    @property
    def frame_count(self) -> int: ...
    @property
    def duration(self) -> float:
        """Length of the animation in seconds (0 for a static scene)."""
    @property
    def fps(self) -> float: ...
    @property
    def stable_topology(self) -> bool:
        """True when every frame has the same triangles in the same order (refittable)."""
    @property
    def dropped_triangles(self) -> int:
        """Triangles dropped at load for NaN or infinite coordinates (static files)."""
    @property
    def camera(self) -> Camera:
        """The scene's default camera."""
    @property
    def triangle_count(self) -> int:
        """Triangles at time 0 (sampled once, on first use)."""

# ------------------------------------------------------------------------------ BVHs

_BuilderName = Literal[
    "lbvh",
    "hlbvh",
    "hlbvh-large",
    "hlbvh+sah",
    "hlbvh+atrbvh",
    "hlbvh+atrbvh-cells",
    "binned-sah",
    "sweep-sah",
    "atrbvh",
    "ploc",
    "ploc+reinsert",
    "hlbvh+reinsert",
    "mbvh4-collapse",
    "mbvh4-stream",
    "mbvh4-stream-w4",
    "mbvh4-topdown",
]

def builders() -> list[str]:
    """Names of every builder, in ``arbor build``'s order."""

@final
class Bvh:
    """A built tree: the binary ``Bvh2`` (64-byte nodes of [P2] §4.1) or the 4-wide
    ``Mbvh4`` (128-byte nodes of [P4] §3.1), with its leaf table.

    ``nodes`` is a structured array in the exact memory and tree-file layout. ``Bvh2``:
    ``bounds`` float32 (2, 2, 3) = [child][min, max][x, y, z] and ``children`` (2,) of
    (``index``, ``count``) uint32. ``Mbvh4``: ``min_x`` ... ``max_z`` float32 (4,) and
    ``children`` (4,). A child with ``count > 0`` is a leaf of
    ``leaf_order[index:index + count]``; ``count == 0`` is inner node ``index``, or no
    child when ``index == 2**32 - 1``.
    """

    @staticmethod
    def build(
        vertices: npt.ArrayLike,
        indices: npt.ArrayLike,
        builder: _BuilderName | str = "binned-sah",
        *,
        max_leaf: int | None = None,
        bins: int | None = None,
        collapse_from: str | None = None,
        threads: int | None = None,
    ) -> Bvh:
        """Builds a tree over triangles with a builder of ``arbor build`` and its options
        (``max_leaf`` 1..1024, default 8; ``bins`` 8, 16 or 32 for the binned builders;
        ``collapse_from`` for ``mbvh4-collapse``; ``threads``: default all cores)."""
    @staticmethod
    def load(path: str | os.PathLike[str]) -> Bvh:
        """Reads a tree file (``arbor build --out``); it is checksummed and validated."""
    def save(self, path: str | os.PathLike[str]) -> None:
        """Writes the tree file atomically."""
    def refit(self, vertices: npt.ArrayLike, indices: npt.ArrayLike | None = None) -> None:
        """Refits the boxes to moved vertices (same triangles; ``indices`` default to those
        the tree was built over)."""
    def validate(
        self,
        vertices: npt.ArrayLike | None = None,
        indices: npt.ArrayLike | None = None,
        *,
        max_leaf: int | None = None,
    ) -> None:
        """Checks every invariant over the triangles (default: those last built or refitted
        over); raises :class:`ArborError` naming the first violation."""
    def sah(self, c_inner: float = 1.2, c_leaf: float = 0.0, c_tri: float = 1.0) -> float:
        """SAH cost normalized by the scene box, in binary units (a 4-wide node costs
        ``2 c_inner``); the defaults are the thesis weights."""
    def collapse(self) -> Bvh:
        """The 4-wide tree collapsed from this binary one."""
    def stats(self) -> dict[str, Any]: ...
    @property
    def nodes(self) -> npt.NDArray[np.void]:
        """The nodes as a structured array (a copy)."""
    @property
    def node_dtype(self) -> np.dtype[np.void]: ...
    @property
    def leaf_order(self) -> _U32:
        """The leaf table: triangle indices in leaf order, uint32 (a copy)."""
    @property
    def primitive_indices(self) -> _U32:
        """Same as ``leaf_order``."""
    @property
    def bounds(self) -> _F32:
        """Scene box, float32 (2, 3)."""
    @property
    def kind(self) -> Literal["Bvh2", "Mbvh4"]: ...
    @property
    def width(self) -> int: ...
    @property
    def builder(self) -> str: ...
    @property
    def max_leaf(self) -> int:
        """The leaf size limit the tree was built with (``validate``'s default)."""
    @property
    def node_count(self) -> int: ...
    @property
    def leaf_count(self) -> int: ...
    @property
    def primitive_count(self) -> int: ...
    @property
    def depth(self) -> int:
        """Longest root-to-leaf path, in nodes."""
    @property
    def max_leaf_size(self) -> int: ...
    @property
    def mean_children(self) -> float: ...
    @property
    def node_bytes(self) -> int: ...
    @property
    def bytes(self) -> int:
        """Bytes of the nodes plus the leaf table."""
    def __eq__(self, other: object, /) -> bool: ...

# --------------------------------------------------------------------------- tracing

_KernelName = Literal["bvh2", "mbvh4", "mbvh8", "cbvh"]

@final
class Hits:
    """Results of :func:`trace`, one entry per ray. ``t`` is ``inf`` and ``primitive`` is
    :data:`NO_HIT` on a miss. ``u`` and ``v`` are the barycentric weights of the
    triangle's vertices 1 and 2 (the hit is ``(1-u-v) p0 + u p1 + v p2``)."""

    @property
    def t(self) -> _F32: ...
    @property
    def primitive(self) -> _U32: ...
    @property
    def u(self) -> _F32: ...
    @property
    def v(self) -> _F32: ...
    @property
    def hit(self) -> npt.NDArray[np.bool_]: ...
    @property
    def node_visits(self) -> _U32: ...
    @property
    def box_tests(self) -> _U32: ...
    @property
    def tri_tests(self) -> _U32: ...
    @property
    def leaf_visits(self) -> _U32: ...
    @property
    def pops(self) -> _U32: ...
    @property
    def culled_pops(self) -> _U32: ...
    @property
    def max_stack_depth(self) -> _U32: ...
    @property
    def kernel(self) -> str: ...
    @property
    def totals(self) -> dict[str, int]:
        """Counters summed over all rays (``max_stack_depth``: the maximum)."""
    def __len__(self) -> int: ...

def trace(
    bvh: Bvh,
    vertices: npt.ArrayLike,
    indices: npt.ArrayLike,
    origins: npt.ArrayLike,
    directions: npt.ArrayLike,
    tmin: float | npt.ArrayLike | None = None,
    tmax: float | npt.ArrayLike | None = None,
    *,
    kernel: _KernelName | None = None,
    distance_stack: bool | None = None,
    any_hit: bool = False,
) -> Hits:
    """Traces rays (origins and directions float32 (N, 3); ``tmin``/``tmax`` a number or
    (N,), default 0 and ``inf``; ``tmin`` not negative) through ``bvh``, built over
    ``indices`` into ``vertices``. ``kernel`` defaults to the tree's own format; a binary
    tree can also be traced as ``mbvh4``, ``mbvh8`` or ``cbvh`` (collapsed or compressed
    first, on every call: see :class:`RayCaster` to prepare once). ``distance_stack``
    defaults as in ``arbor render`` (on for ``mbvh4`` and ``mbvh8``). ``any_hit``: stop at
    the first hit found. Vertices that moved since the tree was built or refitted are an
    error (a stale tree), not silent misses."""

def trace_brute_force(
    vertices: npt.ArrayLike,
    indices: npt.ArrayLike,
    origins: npt.ArrayLike,
    directions: npt.ArrayLike,
    tmin: float | npt.ArrayLike | None = None,
    tmax: float | npt.ArrayLike | None = None,
) -> Hits:
    """The closest hits by testing every triangle (the crate's reference); ``tmin`` and
    ``tmax`` as in :func:`trace`. Counters: ``tri_tests`` is the triangle count."""

@final
class Rays:
    """A ray set: origins and directions float32 (N, 3), ``tmin``/``tmax`` (N,), and the
    ``pixel`` (``y * width + x``) and ``bounce`` (0 = primary) of each ray."""

    @property
    def origins(self) -> _F32: ...
    @property
    def directions(self) -> _F32: ...
    @property
    def tmin(self) -> _F32: ...
    @property
    def tmax(self) -> _F32: ...
    @property
    def pixel(self) -> _U32: ...
    @property
    def bounce(self) -> npt.NDArray[np.uint8]: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def kind(self) -> str: ...
    def __len__(self) -> int: ...

def camera_rays(
    camera: Camera,
    width: int,
    height: int,
    kind: Literal["primary", "diffuse"] = "primary",
    *,
    bvh: Bvh | None = None,
    vertices: npt.ArrayLike | None = None,
    indices: npt.ArrayLike | None = None,
    bounces: int = 4,
    seed: int = 1,
) -> Rays:
    """The rays of a ``width`` x ``height`` image: ``primary`` (one per pixel centre,
    row-major, unit directions), or ``diffuse`` (the paths of ``arbor render --rays
    diffuse``, found by tracing through ``bvh``: each pixel's primary ray and up to
    ``bounces`` cosine-weighted bounces, in the renderer's tile order)."""

# ------------------------------------------------------------------------ ray caster

@final
class RayHits:
    """Closest hits of :meth:`RayCaster.intersect`, one entry per ray: ``t`` (``inf`` on a
    miss), ``primitive`` (:data:`NO_HIT` on a miss), ``u`` and ``v`` (the barycentric
    weights of the triangle's vertices 1 and 2), ``normal`` (the unit geometric normal
    ``cross(p1 - p0, p2 - p0)``, NaN on a miss; computed on first access, so a query that
    never reads it does not pay for it) and ``location`` (``origin + t * direction``,
    NaN on a miss), float32 (N, 3). Pickles (the normals computed, so a Ray task can
    return it)."""

    @property
    def t(self) -> _F32: ...
    @property
    def primitive(self) -> _U32: ...
    @property
    def u(self) -> _F32: ...
    @property
    def v(self) -> _F32: ...
    @property
    def hit(self) -> npt.NDArray[np.bool_]: ...
    @property
    def normal(self) -> _F32: ...
    @property
    def location(self) -> _F32: ...
    @property
    def geometry(self) -> _U32:
        """The mesh of each hit (its index in :meth:`RayCaster.from_meshes`; 0 for one
        mesh), :data:`NO_HIT` on a miss."""
    @property
    def geometry_primitive(self) -> _U32:
        """The triangle of each hit within its mesh, :data:`NO_HIT` on a miss."""
    @property
    def counters(self) -> dict[str, _U32] | None:
        """Per-ray traversal counters (``node_visits``, ``box_tests``, ``tri_tests``,
        ``leaf_visits``, ``pops``, ``culled_pops``, ``max_stack_depth``), or None unless
        the query passed ``counters=True``."""
    @property
    def totals(self) -> dict[str, int]:
        """Counters summed over all rays (always kept)."""
    @property
    def generation(self) -> int:
        """The :attr:`RayCaster.generation` the rays were traced against."""
    @property
    def kernel(self) -> str: ...
    def __len__(self) -> int: ...

@final
class RayCaster:
    """A prepared ray caster: built once over triangles, it owns a copy of the geometry,
    the tree and the kernel's traceable form of it (for ``kernel="cbvh"`` the encoded
    CBVH), so a query costs only its rays. ``refit`` moves the vertices in place; the
    object never answers for other vertices than those it holds. Queries release the GIL
    and run in parallel; threads may share one object (a refit waits for queries in
    flight). Pickles (the tree travels in the tree-file format)."""

    def __init__(
        self,
        vertices: npt.ArrayLike,
        indices: npt.ArrayLike,
        builder: _BuilderName | str = "binned-sah",
        *,
        kernel: _KernelName | None = None,
        distance_stack: bool | None = None,
        max_leaf: int | None = None,
        bins: int | None = None,
        collapse_from: str | None = None,
        threads: int | None = None,
    ) -> None:
        """Builds the tree with a builder of ``arbor build`` (options as in
        :meth:`Bvh.build`) and prepares it for ``kernel`` (default: the tree's own format).
        ``distance_stack`` defaults as in ``arbor render``: on for ``mbvh4`` and ``mbvh8``."""
    @staticmethod
    def from_meshes(
        meshes: Sequence[tuple[npt.ArrayLike, npt.ArrayLike] | Any],
        builder: _BuilderName | str = "binned-sah",
        *,
        kernel: _KernelName | None = None,
        distance_stack: bool | None = None,
        max_leaf: int | None = None,
        bins: int | None = None,
        collapse_from: str | None = None,
        threads: int | None = None,
    ) -> RayCaster:
        """One structure over several meshes, each ``(vertices, indices)`` or an object with
        ``vertices`` and ``faces`` (a ``trimesh.Trimesh``) or ``indices``; results name the
        mesh of each hit (:attr:`RayHits.geometry`). ``refit`` then also takes a list of
        the meshes' vertex arrays."""
    @staticmethod
    def from_bvh(
        bvh: Bvh,
        vertices: npt.ArrayLike,
        indices: npt.ArrayLike | None = None,
        *,
        kernel: _KernelName | None = None,
        distance_stack: bool | None = None,
    ) -> RayCaster:
        """A ray caster over a built tree and the vertices it was built or last refitted
        over (``indices`` default to the tree's); a stale tree is refused."""
    def refit(self, vertices: npt.ArrayLike | Sequence[npt.ArrayLike]) -> None:
        """Moves the vertices (same count, same triangles; for :meth:`from_meshes`, also a
        list with each mesh's vertices); increments ``generation``."""
    def intersect(
        self,
        origins: npt.ArrayLike,
        directions: npt.ArrayLike,
        tmin: float | npt.ArrayLike | None = None,
        tmax: float | npt.ArrayLike | None = None,
        *,
        counters: bool = False,
        out: RayHits | None = None,
    ) -> RayHits:
        """Closest hits (origins and directions (N, 3); ``tmin``/``tmax`` a number or (N,),
        default 0 and ``inf``). ``out``: a result of the same length whose arrays are
        overwritten and shared with the returned result (treat ``out`` itself as spent)."""
    def trace_frames(
        self,
        frames: npt.ArrayLike,
        origins: npt.ArrayLike,
        directions: npt.ArrayLike,
        tmin: float | npt.ArrayLike | None = None,
        tmax: float | npt.ArrayLike | None = None,
    ) -> list[RayHits]:
        """An animation in one call: for each ``frames[k]`` ((T, N, 3) vertices of the same
        triangles) a refit and then :meth:`intersect`, with the GIL released throughout.
        ``origins``/``directions``: (R, 3) for every frame or (T, R, 3) per frame;
        ``tmin``/``tmax``: a number, (R,) or (T, R). One result per frame, equal to
        ``refit(frames[k]); intersect(...)``; the caster is left at the last frame
        (``generation`` up by T). Every frame is checked before any is applied."""
    def intersect_all(
        self,
        origins: npt.ArrayLike,
        directions: npt.ArrayLike,
        tmin: float | npt.ArrayLike | None = None,
        tmax: float | npt.ArrayLike | None = None,
        *,
        max_hits: int = 100,
    ) -> tuple[_U32, _U32, _F32]:
        """Every hit along each ray, nearest first, at most ``max_hits`` per ray:
        ``(ray, primitive, t)``, ray by ray. Each ray restarts just past its last hit, so
        two triangles hit at exactly the same distance count once."""
    def closest_primitives(
        self,
        origins: npt.ArrayLike,
        directions: npt.ArrayLike,
        tmin: float | npt.ArrayLike | None = None,
        tmax: float | npt.ArrayLike | None = None,
        *,
        out: _U32 | None = None,
    ) -> _U32:
        """The ``primitive`` column of :meth:`intersect` alone (:data:`NO_HIT` on a miss),
        without the other columns. ``out``: a uint32 (N,) array to fill."""
    def occluded(
        self,
        origins: npt.ArrayLike,
        directions: npt.ArrayLike,
        tmin: float | npt.ArrayLike | None = None,
        tmax: float | npt.ArrayLike | None = None,
        *,
        out: npt.NDArray[np.bool_] | None = None,
    ) -> npt.NDArray[np.bool_]:
        """Any hit within each ray's range, as booleans. ``out``: a bool (N,) array to fill."""
    def contains_points(
        self, points: npt.ArrayLike, *, out: npt.NDArray[np.bool_] | None = None
    ) -> npt.NDArray[np.bool_]:
        """Whether each point ((N, 3)) lies inside the closed mesh: the parity of the
        surface crossings along rays from the point in three fixed directions, by majority
        (a ray through an edge or a vertex is outvoted; two triangles hit at exactly the
        same distance count once). Undefined on the surface; for a mesh that is not
        closed, the parity of a majority of three rays. ``out``: a bool (N,) array."""

    @property
    def vertices(self) -> _F32:
        """A copy of the vertices traced (those of the last build or refit)."""
    @property
    def indices(self) -> _U32:
        """A copy of the triangles' vertex indices."""
    @property
    def bvh(self) -> Bvh:
        """A copy of the tree, over the current vertices."""
    @property
    def generation(self) -> int:
        """Refits so far (0 after building)."""
    @property
    def kernel(self) -> _KernelName: ...
    @property
    def distance_stack(self) -> bool: ...
    @property
    def builder(self) -> str: ...
    @property
    def triangle_count(self) -> int: ...
    @property
    def vertex_count(self) -> int: ...
    @property
    def geometry_count(self) -> int:
        """Meshes it was built over (1 unless :meth:`from_meshes`)."""
    def __len__(self) -> int: ...

@final
class InstanceHits:
    """Closest hits of :meth:`InstanceCaster.intersect`, one entry per ray: ``t`` (world
    distance in units of the ray direction, ``inf`` on a miss), ``instance`` and
    ``primitive`` (the triangle within the instance's mesh; :data:`NO_HIT` on a miss),
    ``u`` and ``v`` (barycentric weights of the triangle's vertices 1 and 2), ``hit``,
    ``location`` (world space, NaN on a miss), and on access ``geometry`` (the instance's
    mesh) and ``normal`` (the world-space unit geometric normal). Pickles."""

    @property
    def t(self) -> _F32: ...
    @property
    def instance(self) -> _U32: ...
    @property
    def primitive(self) -> _U32: ...
    @property
    def u(self) -> _F32: ...
    @property
    def v(self) -> _F32: ...
    @property
    def hit(self) -> npt.NDArray[np.bool_]: ...
    @property
    def location(self) -> _F32: ...
    @property
    def geometry(self) -> _U32:
        """The mesh of each hit instance (``mesh_index[instance]``), :data:`NO_HIT` on a
        miss."""
    @property
    def normal(self) -> _F32:
        """The normalized ``cross(p1 - p0, p2 - p0)`` of each hit triangle moved into world
        space (NaN on a miss), computed on first access."""
    @property
    def totals(self) -> dict[str, int]:
        """Traversal counters summed over all rays, top and bottom levels."""
    @property
    def generation(self) -> int:
        """The :attr:`InstanceCaster.generation` the rays were traced against."""
    def __len__(self) -> int: ...

@final
class InstanceCaster:
    """Two-level instancing: meshes (bottom levels) placed in the world by affine
    transforms under a top-level tree over the instances. ``set_transforms`` moves the
    instances and ``refit`` deforms a mesh, both refitting in place. Queries release the
    GIL and run in parallel; threads may share one object. Pickles."""

    def __init__(
        self,
        meshes: Sequence[RayCaster | tuple[npt.ArrayLike, npt.ArrayLike] | Any],
        transforms: npt.ArrayLike,
        mesh_index: npt.ArrayLike | None = None,
        builder: _BuilderName | str = "binned-sah",
        *,
        kernel: _KernelName | None = None,
        distance_stack: bool | None = None,
        max_leaf: int | None = None,
        bins: int | None = None,
        collapse_from: str | None = None,
        threads: int | None = None,
    ) -> None:
        """``meshes``: each a :class:`RayCaster` (its tree and kernel form are copied and
        reused; one made by :meth:`RayCaster.from_meshes` is one mesh here, its triangles
        numbered over all its parts), ``(vertices, indices)``, or an object with ``vertices`` and ``faces``
        (a ``trimesh.Trimesh``) or ``indices``, built here with the builder options of
        :class:`RayCaster`. ``transforms``: (K, 3, 4) or (K, 4, 4) object-to-world
        matrices (rows ``[M | t]``; a 4x4's last row ``0 0 0 1``); a singular or
        non-finite matrix is an error. ``mesh_index``: the mesh of each instance (default:
        mesh ``i`` for instance ``i`` when there are K meshes, mesh 0 when there is one)."""
    def set_transforms(self, transforms: npt.ArrayLike, *, rebuild: bool = False) -> None:
        """Replaces every instance's transform ((K, 3, 4) or (K, 4, 4)) and refits the top
        level in place (``rebuild=True``: builds it anew); increments ``generation``."""
    def refit(self, mesh: int, vertices: npt.ArrayLike) -> None:
        """Moves the vertices of mesh ``mesh`` (same count, same triangles): its tree and
        the top level are refitted in place; increments ``generation``."""
    def intersect(
        self,
        origins: npt.ArrayLike,
        directions: npt.ArrayLike,
        tmin: float | npt.ArrayLike | None = None,
        tmax: float | npt.ArrayLike | None = None,
        *,
        out: InstanceHits | None = None,
    ) -> InstanceHits:
        """Closest hits (arguments as in :meth:`RayCaster.intersect`)."""
    def occluded(
        self,
        origins: npt.ArrayLike,
        directions: npt.ArrayLike,
        tmin: float | npt.ArrayLike | None = None,
        tmax: float | npt.ArrayLike | None = None,
        *,
        out: npt.NDArray[np.bool_] | None = None,
    ) -> npt.NDArray[np.bool_]:
        """Any hit within each ray's range, as booleans."""
    @property
    def transforms(self) -> _F32:
        """The instances' object-to-world matrices, (K, 3, 4) float32."""
    @property
    def mesh_index(self) -> _U32:
        """The mesh of each instance."""
    @property
    def generation(self) -> int:
        """Updates so far (``set_transforms`` and ``refit``; 0 after building)."""
    @property
    def instance_count(self) -> int: ...
    @property
    def mesh_count(self) -> int: ...
    @property
    def kernels(self) -> list[_KernelName]:
        """The kernel of each mesh."""
    def __len__(self) -> int: ...

# ----------------------------------------------------------------------------- CBVH

def encode_cbvh(
    bvh: Bvh,
    vertices: npt.ArrayLike | None = None,
    indices: npt.ArrayLike | None = None,
    *,
    encoder: Literal["bottomup", "topdown"] = "bottomup",
    coords: Literal["modulo", "relative"] = "modulo",
    treelet: int = 1,
    bits: int = 6,
    min_scale_exp: int = -30,
) -> dict[str, Any]:
    """Compresses a binary tree into a CBVH ([P3]) and returns its statistics (fields of
    ``arbor cbvh --json`` plus sizes): nodes, node_bytes, uncompressed_node_bytes,
    compression_ratio, backtrack_steps, backtrack_depth_hist, nodes_written, max_stack,
    enclosure_violations, decoded_encloses_original, sah, sah_uncompressed,
    sah_vs_uncompressed, encode_ms, and the options. The decoded boxes are checked against
    the triangles (default: those the tree was last built or refitted over)."""
