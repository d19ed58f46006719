//! `RayCaster`: a prepared acceleration structure bound to its geometry. It owns a copy of
//! the vertices and triangles, the tree and the kernel's traceable form (`trace::Accel`; for
//! `kernel="cbvh"` the encoded CBVH), all made once, so that a query costs only its rays.
//! `refit` moves the vertices (same triangles) and updates the tree and the kernel in
//! place; since the object holds the only copy of the geometry it traces, it can never
//! answer for vertices other than those it was last given.
//!
//! Queries run with the interpreter released, in parallel for more than a few hundred rays,
//! and write straight into numpy arrays allocated before the work starts. The state sits
//! behind a read-write lock taken with the interpreter released: any number of threads
//! trace at once, and a `refit` waits for them (and they for it) instead of failing.

use crate::arrays::{err, points};
use crate::bvh::{aabbs, config, in_pool, Bvh};
use crate::detached;
use crate::query::{cached_normals, query_runs, ray_column, HitArrays, Sink};
use crate::trace::{
    accel_of, check_current, default_distance_stack, tree_kernel, RayArrays, RaySlices, CHUNK,
    KERNELS, NO_HIT, SERIAL_RAYS,
};
use ::trace::instance::InstanceHit;
use ::trace::{Accel, KernelOptions, Query, RayStats, TraversalStack, Traverse};
use bvh::Tree;
use geom::{Aabb, Ray, Triangle, Vec3};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PySlice, PyTuple};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock, RwLock};

/// Names of the per-ray counters, in the column order of `RayHits.counters`.
pub(crate) const COUNTERS: [&str; 7] = [
    "node_visits",
    "box_tests",
    "tri_tests",
    "leaf_visits",
    "pops",
    "culled_pops",
    "max_stack_depth",
];

/// What a `RayCaster` traces: the geometry it owns, its tree and the kernel's form of it.
pub(crate) struct State {
    pub(crate) vertices: Vec<Vec3>,
    pub(crate) indices: Vec<[u32; 3]>,
    /// Shared with the results traced over them (their normals are computed on demand).
    pub(crate) triangles: Arc<Vec<Triangle>>,
    pub(crate) tree: Tree,
    pub(crate) accel: Accel,
    /// Set while a refit changes the state; left set if it failed half way.
    broken: bool,
}

/// A prepared ray caster (see the module header).
#[pyclass(module = "arbor._arbor", frozen)]
pub struct RayCaster {
    pub(crate) state: RwLock<State>,
    /// Refits so far: part of every result, so that results of different geometry are
    /// told apart.
    generation: AtomicU64,
    pub(crate) kernel: &'static str,
    pub(crate) distance_stack: bool,
    pub(crate) builder: String,
    pub(crate) max_leaf: u32,
    vertex_count: usize,
    triangle_count: usize,
    /// The meshes it was built over (one unless `from_meshes`): the first triangle and
    /// the first vertex of each, and the totals at the end.
    geometry_first: Arc<Vec<u32>>,
    vertex_first: Vec<u32>,
}

/// The kernel name `kernel` (or the tree's own), checked.
pub(crate) fn kernel_name(tree: &Tree, kernel: Option<&str>) -> Result<&'static str, String> {
    match kernel {
        None => Ok(tree_kernel(tree)),
        Some(k) => ["bvh2", "mbvh4", "mbvh8", "cbvh"]
            .into_iter()
            .find(|&n| n == k)
            .ok_or_else(|| format!("unknown kernel '{k}'; valid: {KERNELS}")),
    }
}

/// An optional non-negative integer argument as `T`, or an `ArborError` naming it (a plain
/// `u32` argument would raise `OverflowError` for -1).
pub(crate) fn count_arg<T: TryFrom<i64>>(what: &str, x: Option<i64>) -> PyResult<Option<T>> {
    x.map(|v| {
        T::try_from(v).map_err(|_| {
            err(format!(
                "{what} must be a non-negative integer in range, got {v}"
            ))
        })
    })
    .transpose()
}

/// The build arguments of the constructor and `from_meshes`.
pub(crate) struct BuildOptions<'a> {
    pub(crate) builder: &'a str,
    pub(crate) kernel: Option<&'a str>,
    pub(crate) distance_stack: Option<bool>,
    pub(crate) max_leaf: Option<i64>,
    pub(crate) bins: Option<i64>,
    pub(crate) collapse_from: Option<String>,
    pub(crate) threads: Option<i64>,
}

/// A state that an update failing half way leaves marked.
pub(crate) trait Healthy {
    /// Whether an update failed half way.
    fn broken(&self) -> bool;
}

impl Healthy for State {
    fn broken(&self) -> bool {
        self.broken
    }
}

/// Locks for reading, or fails if a panic left the state inconsistent.
pub(crate) fn read<S: Healthy>(l: &RwLock<S>) -> Result<std::sync::RwLockReadGuard<'_, S>, String> {
    let broken = || "the ray caster was left inconsistent by an internal error".to_string();
    let s = l.read().map_err(|_| broken())?;
    if s.broken() {
        return Err(broken());
    }
    Ok(s)
}

/// Moves `s` to the vertices `vs` (same count, same triangles): the tree refitted and the
/// kernel's form updated in place (a CBVH encoded again).
/// `finite_checked`: the caller has checked that the vertices the triangles use are finite.
fn refit_state(
    s: &mut State,
    vs: &[Vec3],
    kernel: &'static str,
    ds: bool,
    finite_checked: bool,
) -> Result<(), String> {
    let triangles = if finite_checked {
        crate::arrays::gather(vs, &s.indices)?
    } else {
        crate::arrays::resolve(vs, &s.indices)?
    };
    let prims = bvh::triangle_aabbs(&triangles);
    // The triangles were checked above (finite, same count), so nothing below can fail
    // short of an internal error; if it does, the state is half moved and is marked
    // broken, so that queries fail instead of answering for it.
    s.broken = true;
    s.tree
        .refit(&prims)
        .map_err(|e| format!("cannot refit the tree: {e}"))?;
    if !s.accel.refit(&triangles).unwrap_or(false) {
        let options = KernelOptions { distance_stack: ds };
        s.accel = accel_of(&s.tree, Some(kernel), &triangles, options)?;
    }
    s.triangles = Arc::new(triangles);
    s.vertices.copy_from_slice(vs);
    s.broken = false;
    Ok(())
}

/// The scratch of [`closest`]: the traversal stack, and a run's hits and (when kept)
/// per-ray counters as the kernel hands them over.
pub(crate) struct ClosestScratch {
    stack: TraversalStack,
    hits: Vec<Option<::trace::Hit>>,
    stats: Vec<RayStats>,
}

impl ClosestScratch {
    pub(crate) fn new() -> Self {
        Self {
            stack: TraversalStack::new(),
            hits: Vec::new(),
            stats: Vec::new(),
        }
    }
}

/// The closest hits of `rays` in `accel` (one batch, [`Traverse::trace_batch`], which the
/// 8-wide kernel interleaves over trees larger than the cache), as the columns of
/// [`HitArrays`] take them. The kernel's `done` only keeps each hit (and the counters when
/// they are written out) in the scratch and sums the counters; the columns are written
/// from there after the batch. A `done` that wrote the eight columns itself was too large
/// to inline into the kernel's loop, and the call a ray with its hit passed through memory
/// cost about 4% of a primary ray's time (Dragon).
#[inline(always)]
fn closest(accel: &Accel, rays: &RaySlices<'_>, x: &mut ClosestScratch, sink: &mut Sink) {
    let n = rays.len();
    x.hits.clear();
    x.hits.resize(n, None);
    x.stats.clear();
    if sink.keeps_counters() {
        x.stats.resize(n, RayStats::default());
    }
    let (hits, stats) = (&mut x.hits, &mut x.stats);
    let mut total = RayStats::default();
    accel.trace_batch(rays, Query::Closest, &mut x.stack, |i, h, st| {
        hits[i] = h;
        if let Some(s) = stats.get_mut(i) {
            *s = *st;
        }
        total.add(st);
    });
    let none = RayStats::default();
    for (i, h) in hits.iter().enumerate() {
        let h = h.map(|h| InstanceHit {
            t: h.t,
            instance: 0,
            prim: h.prim,
            bary: h.bary,
        });
        sink.put(i, h, stats.get(i).unwrap_or(&none));
    }
    sink.total(&total);
}

/// Directions of the rays of `contains_points` (normalized when used): the first is
/// trimesh's, the others are far from it, from each other and from the axes, so that a
/// mesh on a grid rarely has an edge along them.
const CONTAINS_DIRECTIONS: [[f32; 3]; 3] = [
    [0.439_506_45, 0.617_598_6, 0.652_231_6],
    [-0.719_407_3, 0.190_125_8, -0.668_043_1],
    [0.283_617_6, -0.908_335_2, -0.307_554_9],
];

/// Walks `ray` through every hit, nearest first, up to `max_hits`, calling `each` on
/// each, and returns how many. After a hit the ray restarts just past it (the next float
/// above its `t`), so two triangles hit at exactly the same distance count once.
fn crossings(
    accel: &Accel,
    ray: &Ray,
    max_hits: u32,
    stack: &mut TraversalStack,
    mut each: impl FnMut(&::trace::Hit),
) -> u32 {
    let mut r = *ray;
    let mut n = 0;
    while n < max_hits {
        let mut st = RayStats::default();
        let Some(h) = accel.trace_observed(&r, Query::Closest, stack, &mut st, &mut ()) else {
            break;
        };
        each(&h);
        n += 1;
        // The next float above the hit (hits lie at t >= 0).
        r.t_min = if h.t <= 0.0 {
            f32::from_bits(1)
        } else {
            f32::from_bits(h.t.to_bits() + 1)
        };
        if r.t_min > r.t_max {
            break;
        }
    }
    n
}

/// Closest hits of a batch of rays from [`RayCaster::intersect`]: per ray the distance `t`
/// (`inf` on a miss), the triangle (`NO_HIT` on a miss), the barycentric weights `u`, `v`
/// of its vertices 1 and 2, the unit geometric normal (NaN on a miss; computed when first
/// read, from the triangles of the generation traced, which the result shares), the hit
/// location (NaN on a miss), and optionally the traversal counters.
#[pyclass(module = "arbor._arbor", frozen)]
pub struct RayHits {
    #[pyo3(get)]
    t: Py<PyArray1<f32>>,
    #[pyo3(get)]
    primitive: Py<PyArray1<u32>>,
    #[pyo3(get)]
    u: Py<PyArray1<f32>>,
    #[pyo3(get)]
    v: Py<PyArray1<f32>>,
    #[pyo3(get)]
    hit: Py<PyArray1<bool>>,
    /// The triangles traced (for `normal`), and the normals once computed.
    triangles: Arc<Vec<Triangle>>,
    normal: OnceLock<Py<PyArray2<f32>>>,
    /// The first triangle of each mesh of the ray caster, and the total.
    geometry_first: Arc<Vec<u32>>,
    #[pyo3(get)]
    location: Py<PyArray2<f32>>,
    counter_array: Option<Py<PyArray2<u32>>>,
    #[pyo3(get)]
    generation: u64,
    #[pyo3(get)]
    kernel: &'static str,
    total: RayStats,
}

impl RayHits {
    /// Its arrays, to be overwritten by a query given it as `out`.
    fn arrays<'py>(&self, py: Python<'py>) -> HitArrays<'py> {
        HitArrays {
            t: self.t.bind(py).clone(),
            instance: None,
            prim: self.primitive.bind(py).clone(),
            u: self.u.bind(py).clone(),
            v: self.v.bind(py).clone(),
            hit: self.hit.bind(py).clone(),
            location: self.location.bind(py).clone(),
            counters: self.counter_array.as_ref().map(|c| c.bind(py).clone()),
        }
    }

    /// `f(mesh, triangle within the mesh)` of every hit, `NO_HIT` on a miss.
    fn per_mesh<'py>(
        &self,
        py: Python<'py>,
        f: impl Fn(u32, u32) -> u32 + Sync + Send,
    ) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let prim = self.primitive.bind(py).readonly();
        let prims = prim
            .as_slice()
            .map_err(|_| err("internal error: array not contiguous"))?;
        let first = &self.geometry_first;
        let out: Vec<u32> = py.detach(|| {
            prims
                .par_iter()
                .with_min_len(CHUNK)
                .map(|&p| {
                    // The last mesh whose first triangle is at or before `p`.
                    let g = first.partition_point(|&x| x <= p);
                    if p == NO_HIT || g == 0 || g >= first.len() {
                        NO_HIT
                    } else {
                        f(g as u32 - 1, p - first[g - 1])
                    }
                })
                .collect()
        });
        Ok(PyArray1::from_vec(py, out))
    }
}

#[pymethods]
impl RayHits {
    /// Per-ray counters (`node_visits`, `box_tests`, `tri_tests`, `leaf_visits`, `pops`,
    /// `culled_pops`, `max_stack_depth`) as a dict of uint32 arrays, or None when the query
    /// did not ask for them.
    #[getter]
    fn counters<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(a) = &self.counter_array else {
            return Ok(None);
        };
        let a = a.bind(py);
        let d = PyDict::new(py);
        for (j, name) in COUNTERS.iter().enumerate() {
            let col = a.get_item((PySlice::full(py), j))?;
            d.set_item(*name, col)?;
        }
        Ok(Some(d))
    }

    /// The unit geometric normal of each hit triangle, `cross(p1 - p0, p2 - p0)`
    /// normalized (NaN on a miss), computed on first access from `primitive` and the
    /// triangles traced: a query pays nothing for it unless it is read.
    #[getter]
    fn normal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let tris = &self.triangles;
        cached_normals(py, &self.normal, self.primitive.bind(py), None, |p, _| {
            tris.get(p as usize).copied()
        })
    }

    /// The mesh of each hit (its index in `RayCaster.from_meshes`; 0 for a ray caster of
    /// one mesh), `NO_HIT` on a miss. Computed on access from `primitive`.
    #[getter]
    fn geometry<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<u32>>> {
        self.per_mesh(py, |g, _| g)
    }

    /// The triangle of each hit within its mesh (`primitive` less the mesh's first
    /// triangle), `NO_HIT` on a miss. Computed on access from `primitive`.
    #[getter]
    fn geometry_primitive<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<u32>>> {
        self.per_mesh(py, |_, local| local)
    }

    /// Counters summed over all rays (always kept; `max_stack_depth` is a maximum).
    #[getter]
    fn totals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        crate::trace::stats_dict(py, &self.total)
    }

    fn __len__(&self) -> usize {
        self.total.rays as usize
    }

    /// Pickling (a Ray task can return a result): the arrays, with the normals computed
    /// (the triangles do not travel), the meshes' first triangles and the totals.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let restore = py
            .import("arbor._arbor")?
            .getattr("RayHits")?
            .getattr("_restore")?;
        let t = &self.total;
        let totals = [
            t.rays,
            t.hits,
            t.node_visits,
            t.box_tests,
            t.tri_tests,
            t.leaf_visits,
            t.pushes,
            t.pops,
            t.culled_pops,
            t.max_stack_depth,
        ];
        let args = (
            self.t.bind(py).clone(),
            self.primitive.bind(py).clone(),
            self.u.bind(py).clone(),
            self.v.bind(py).clone(),
            self.hit.bind(py).clone(),
            self.normal(py)?,
            self.location.bind(py).clone(),
            self.counter_array.as_ref().map(|c| c.bind(py).clone()),
            self.generation,
            self.kernel,
            self.geometry_first.to_vec(),
            totals.to_vec(),
        );
        PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds a pickled result (see `__reduce__`).
    #[staticmethod]
    #[allow(clippy::too_many_arguments)]
    fn _restore(
        t: Bound<'_, PyArray1<f32>>,
        primitive: Bound<'_, PyArray1<u32>>,
        u: Bound<'_, PyArray1<f32>>,
        v: Bound<'_, PyArray1<f32>>,
        hit: Bound<'_, PyArray1<bool>>,
        normal: Bound<'_, PyArray2<f32>>,
        location: Bound<'_, PyArray2<f32>>,
        counters: Option<Bound<'_, PyArray2<u32>>>,
        generation: u64,
        kernel: &str,
        geometry_first: Vec<u32>,
        totals: Vec<u64>,
    ) -> PyResult<Self> {
        let kernel = ["bvh2", "mbvh4", "mbvh8", "cbvh"]
            .into_iter()
            .find(|&k| k == kernel)
            .ok_or_else(|| err(format!("pickled result of unknown kernel '{kernel}'")))?;
        let [rays, hits, node_visits, box_tests, tri_tests, leaf_visits, pushes, pops, culled_pops, max_stack_depth] =
            <[u64; 10]>::try_from(totals)
                .map_err(|_| err("pickled totals: 10 counters expected"))?;
        let n = t.len();
        let lens = [
            primitive.len(),
            u.len(),
            v.len(),
            hit.len(),
            normal.shape()[0],
            location.shape()[0],
        ];
        if lens.iter().any(|&l| l != n) || rays as usize != n || geometry_first.is_empty() {
            return Err(err("pickled result: arrays of different lengths"));
        }
        let cached = OnceLock::new();
        let _ = cached.set(normal.unbind());
        Ok(RayHits {
            t: t.unbind(),
            primitive: primitive.unbind(),
            u: u.unbind(),
            v: v.unbind(),
            hit: hit.unbind(),
            triangles: Arc::new(Vec::new()),
            normal: cached,
            geometry_first: Arc::new(geometry_first),
            location: location.unbind(),
            counter_array: counters.map(|c| c.unbind()),
            generation,
            kernel,
            total: RayStats {
                rays,
                hits,
                node_visits,
                box_tests,
                tri_tests,
                leaf_visits,
                pushes,
                pops,
                culled_pops,
                max_stack_depth,
            },
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "RayHits({} rays, {} hits, kernel {:?}, generation {})",
            self.total.rays, self.total.hits, self.kernel, self.generation
        )
    }
}

impl RayCaster {
    /// The result of a closest-hit query into `a`, traced over `triangles` of `generation`.
    fn hits(
        &self,
        a: HitArrays<'_>,
        triangles: Arc<Vec<Triangle>>,
        generation: u64,
        total: RayStats,
    ) -> RayHits {
        RayHits {
            t: a.t.unbind(),
            primitive: a.prim.unbind(),
            u: a.u.unbind(),
            v: a.v.unbind(),
            hit: a.hit.unbind(),
            triangles,
            normal: OnceLock::new(),
            geometry_first: self.geometry_first.clone(),
            location: a.location.unbind(),
            counter_array: a.counters.map(|c| c.unbind()),
            generation,
            kernel: self.kernel,
            total,
        }
    }

    /// Wraps prepared state.
    #[allow(clippy::too_many_arguments)]
    fn wrap(
        state: State,
        kernel: &'static str,
        distance_stack: bool,
        builder: String,
        max_leaf: u32,
        generation: u64,
        geometry_first: Option<Vec<u32>>,
        vertex_first: Option<Vec<u32>>,
    ) -> Self {
        let (nv, nt) = (state.vertices.len() as u32, state.indices.len() as u32);
        RayCaster {
            vertex_count: state.vertices.len(),
            triangle_count: state.indices.len(),
            geometry_first: Arc::new(geometry_first.unwrap_or_else(|| vec![0, nt])),
            vertex_first: vertex_first.unwrap_or_else(|| vec![0, nv]),
            state: RwLock::new(state),
            generation: AtomicU64::new(generation),
            kernel,
            distance_stack,
            builder,
            max_leaf,
        }
    }

    /// The state prepared over `tree` (built or refitted over these triangles).
    pub(crate) fn prepare(
        vertices: Vec<Vec3>,
        indices: Vec<[u32; 3]>,
        tree: Tree,
        kernel: &'static str,
        distance_stack: bool,
    ) -> Result<State, String> {
        if tree.prim_count() != indices.len() {
            return Err(format!(
                "the tree holds {} primitives but {} triangles were given",
                tree.prim_count(),
                indices.len()
            ));
        }
        let triangles = crate::arrays::resolve(&vertices, &indices)?;
        let options = KernelOptions { distance_stack };
        let accel = accel_of(&tree, Some(kernel), &triangles, options)?;
        Ok(State {
            vertices,
            indices,
            triangles: Arc::new(triangles),
            tree,
            accel,
            broken: false,
        })
    }

    /// Builds the tree with the options of the constructor and prepares it.
    pub(crate) fn build(
        py: Python<'_>,
        vs: &[Vec3],
        ixs: &[[u32; 3]],
        o: BuildOptions<'_>,
        meshes: Option<(Vec<u32>, Vec<u32>)>,
    ) -> PyResult<Self> {
        let max_leaf = count_arg::<u32>("max_leaf", o.max_leaf)?;
        let bins = count_arg::<usize>("bins", o.bins)?;
        let threads = count_arg::<usize>("threads", o.threads)?;
        let builder = o.builder;
        let (f, cfg) =
            config(builder, max_leaf, bins, o.collapse_from.as_deref(), threads).map_err(err)?;
        let leaf_limit = cfg.max_leaf;
        let (kernel, distance_stack) = (o.kernel, o.distance_stack);
        let (state, k, ds) = detached(py, || {
            let prims = aabbs(vs, ixs)?;
            let tree = in_pool(threads, || {
                f(&prims, &cfg)
                    .map_err(|e| format!("builder {builder} failed: {}", arbor::one_line(&e)))
            })?;
            let k = kernel_name(&tree, kernel)?;
            let ds = distance_stack.unwrap_or_else(|| default_distance_stack(k));
            let state = Self::prepare(vs.to_vec(), ixs.to_vec(), tree, k, ds)?;
            Ok::<_, String>((state, k, ds))
        })?;
        let (g, v) = meshes.unzip();
        Ok(Self::wrap(
            state,
            k,
            ds,
            builder.to_string(),
            leaf_limit,
            0,
            g,
            v,
        ))
    }

    /// Rays from Python, with the checks every query makes.
    /// A query answering each ray with one value, `answer(hit)` of its `query` hit, as a
    /// column (`what` names it in errors; `out` as for `occluded`).
    #[allow(clippy::too_many_arguments)]
    fn column<'py, T: numpy::Element + Send>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
        out: Option<&Bound<'py, PyAny>>,
        what: &str,
        query: Query,
        answer: impl Fn(Option<::trace::Hit>) -> T + Sync,
    ) -> PyResult<Bound<'py, PyArray1<T>>> {
        let arrays = Self::rays(origins, directions, tmin, tmax)?;
        let rays = arrays.slices()?;
        ray_column(
            py,
            &rays,
            out,
            what,
            &self.state,
            |_| TraversalStack::new(),
            |s, stack, batch, out, _| {
                s.accel
                    .trace_batch(batch, query, stack, |i, h, _| out[i] = answer(h))
            },
        )
    }

    pub(crate) fn rays<'py>(
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<RayArrays<'py>> {
        RayArrays::new(origins, directions, tmin, tmax)
    }
}

/// The vertices and indices of `meshes[g]`: a pair `(vertices, indices)`, or an object
/// with `vertices` and `faces` (trimesh) or `indices` (`arbor.Mesh`).
pub(crate) fn mesh_arrays<'py>(
    m: &Bound<'py, PyAny>,
    g: usize,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    if let Ok((v, ix)) = m.extract::<(Bound<'_, PyAny>, Bound<'_, PyAny>)>() {
        return Ok((v, ix));
    }
    let v = m.getattr("vertices").map_err(|_| {
        err(format!(
            "meshes[{g}] is neither (vertices, indices) nor a mesh with vertices"
        ))
    })?;
    let ix = m
        .getattr("faces")
        .or_else(|_| m.getattr("indices"))
        .map_err(|_| err(format!("meshes[{g}] has no faces or indices")))?;
    Ok((v, ix))
}

#[pymethods]
impl RayCaster {
    /// Builds the tree over `indices` into `vertices` with a builder of `arbor build` and
    /// prepares it for `kernel` (default: the tree's own format).
    #[new]
    #[pyo3(signature = (vertices, indices, builder = "binned-sah", *, kernel = None, distance_stack = None, max_leaf = None, bins = None, collapse_from = None, threads = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        indices: &Bound<'_, PyAny>,
        builder: &str,
        kernel: Option<&str>,
        distance_stack: Option<bool>,
        max_leaf: Option<i64>,
        bins: Option<i64>,
        collapse_from: Option<String>,
        threads: Option<i64>,
    ) -> PyResult<Self> {
        let v = points("vertices", vertices)?;
        let vs = v.as_vec3()?;
        let ix = crate::arrays::indices(indices, vs.len())?;
        let ixs = ix.get()?;
        let opts = BuildOptions {
            builder,
            kernel,
            distance_stack,
            max_leaf,
            bins,
            collapse_from,
            threads,
        };
        Self::build(py, vs, ixs, opts, None)
    }

    /// A ray caster over several meshes, each `(vertices, indices)` or an object with
    /// `vertices` and `faces` (or `indices`): results name the mesh of each hit
    /// (`RayHits.geometry`) and the triangle within it (`geometry_primitive`); the other
    /// arguments as for the constructor.
    #[staticmethod]
    #[pyo3(signature = (meshes, builder = "binned-sah", *, kernel = None, distance_stack = None, max_leaf = None, bins = None, collapse_from = None, threads = None))]
    #[allow(clippy::too_many_arguments)]
    fn from_meshes(
        py: Python<'_>,
        meshes: &Bound<'_, PyAny>,
        builder: &str,
        kernel: Option<&str>,
        distance_stack: Option<bool>,
        max_leaf: Option<i64>,
        bins: Option<i64>,
        collapse_from: Option<String>,
        threads: Option<i64>,
    ) -> PyResult<Self> {
        let (mut vs, mut ixs) = (Vec::new(), Vec::new());
        let (mut gfirst, mut vfirst) = (vec![0u32], vec![0u32]);
        for (g, m) in meshes.try_iter()?.enumerate() {
            let (v, ix) = mesh_arrays(&m?, g)?;
            let pv = points(&format!("meshes[{g}] vertices"), &v)?;
            let pvs = pv.as_vec3()?;
            let pix = crate::arrays::indices(&ix, pvs.len())?;
            let base = vs.len() as u32;
            ixs.extend(pix.get()?.iter().map(|t| t.map(|i| i + base)));
            vs.extend_from_slice(pvs);
            let too_many = || err("the meshes hold more than 2^32 vertices or triangles");
            vfirst.push(u32::try_from(vs.len()).map_err(|_| too_many())?);
            gfirst.push(u32::try_from(ixs.len()).map_err(|_| too_many())?);
        }
        if gfirst.len() == 1 {
            return Err(err("from_meshes needs at least one mesh"));
        }
        let opts = BuildOptions {
            builder,
            kernel,
            distance_stack,
            max_leaf,
            bins,
            collapse_from,
            threads,
        };
        Self::build(py, &vs, &ixs, opts, Some((gfirst, vfirst)))
    }

    /// A ray caster over a tree built before (`Bvh.build`, or loaded from a file), with
    /// the vertices and indices it was built or last refitted over (`indices` default to
    /// the tree's own). A tree that does not match the vertices is refused.
    #[staticmethod]
    #[pyo3(signature = (bvh, vertices, indices = None, *, kernel = None, distance_stack = None))]
    fn from_bvh(
        py: Python<'_>,
        bvh: PyRef<'_, Bvh>,
        vertices: &Bound<'_, PyAny>,
        indices: Option<&Bound<'_, PyAny>>,
        kernel: Option<&str>,
        distance_stack: Option<bool>,
    ) -> PyResult<Self> {
        let v = points("vertices", vertices)?;
        let vs = v.as_vec3()?;
        let given = match indices {
            Some(ix) => Some(crate::arrays::indices(ix, vs.len())?),
            None => None,
        };
        let snap = bvh.snapshot();
        let ixs: Vec<[u32; 3]> = match (&given, &snap.indices) {
            (Some(g), _) => g.get()?.to_vec(),
            (None, Some(stored)) => stored.clone(),
            (None, None) => {
                return Err(err(
                    "this tree was loaded from a file: pass the indices it was built over",
                ))
            }
        };
        if let Some((t, v)) = ixs.iter().enumerate().find_map(|(t, tri)| {
            tri.iter()
                .find(|&&v| v as usize >= vs.len())
                .map(|v| (t, *v))
        }) {
            return Err(err(format!(
                "triangle {t} refers to vertex {v}, but there are only {} vertices",
                vs.len()
            )));
        }
        let tree = snap.tree.clone();
        let stored = snap.prims.clone();
        let (builder, max_leaf) = (bvh.builder.clone(), bvh.max_leaf);
        let (state, k, ds) = detached(py, || {
            let k = kernel_name(&tree, kernel)?;
            let ds = distance_stack.unwrap_or_else(|| default_distance_stack(k));
            let state = Self::prepare(vs.to_vec(), ixs, tree, k, ds)?;
            check_current(stored.as_deref(), &state.triangles)?;
            Ok::<_, String>((state, k, ds))
        })?;
        Ok(Self::wrap(state, k, ds, builder, max_leaf, 0, None, None))
    }

    /// Moves the vertices (same count, same triangles) and updates the tree and the
    /// kernel in place (a CBVH is encoded again). Waits for queries in flight.
    fn refit(&self, py: Python<'_>, vertices: &Bound<'_, PyAny>) -> PyResult<()> {
        // From `from_meshes`: a list with the vertices of each mesh.
        let joined: Option<Vec<Vec3>> = if vertices.is_instance_of::<pyo3::types::PyList>()
            || vertices.is_instance_of::<pyo3::types::PyTuple>()
        {
            let parts: Vec<Bound<'_, PyAny>> = vertices.extract()?;
            let counts = self.vertex_first.windows(2).map(|w| (w[1] - w[0]) as usize);
            if parts.len() != counts.len() {
                return Err(err(format!(
                    "refit keeps the topology: {} meshes expected, {} given",
                    counts.len(),
                    parts.len()
                )));
            }
            let mut all = Vec::with_capacity(self.vertex_count);
            for (g, (part, want)) in parts.iter().zip(counts).enumerate() {
                let p = points(&format!("vertices[{g}]"), part)?;
                let ps = p.as_vec3()?;
                if ps.len() != want {
                    return Err(err(format!(
                        "refit keeps the topology: mesh {g} has {want} vertices, {} given",
                        ps.len()
                    )));
                }
                all.extend_from_slice(ps);
            }
            Some(all)
        } else {
            None
        };
        let v = match joined {
            Some(_) => None,
            None => Some(points("vertices", vertices)?),
        };
        let vs: &[Vec3] = match (&joined, &v) {
            (Some(all), _) => all,
            (None, Some(v)) => v.as_vec3()?,
            (None, None) => return Err(err("internal error: no vertices")),
        };
        if vs.len() != self.vertex_count {
            return Err(err(format!(
                "refit keeps the topology: {} vertices expected, {} given",
                self.vertex_count,
                vs.len()
            )));
        }
        let (lock, kernel, ds, generation) = (
            &self.state,
            self.kernel,
            self.distance_stack,
            &self.generation,
        );
        detached(py, || {
            let mut s = lock.write().map_err(|_| {
                "the ray caster was left inconsistent by an internal error".to_string()
            })?;
            refit_state(&mut s, vs, kernel, ds, false)?;
            generation.fetch_add(1, Ordering::SeqCst);
            Ok::<_, String>(())
        })
    }

    /// Traces the same rays through every frame of an animation: for each `frames[k]`
    /// ((T, N, 3) vertices of the same triangles), a refit and then `intersect`, all in
    /// one call with the GIL released. `origins`/`directions`: (R, 3) for every frame, or
    /// (T, R, 3) per frame; `tmin`/`tmax` a number, (R,) or (T, R). Returns one `RayHits`
    /// per frame; the caster is left at the last frame (`generation` up by T).
    #[pyo3(signature = (frames, origins, directions, tmin = None, tmax = None))]
    fn trace_frames<'py>(
        &self,
        py: Python<'py>,
        frames: &Bound<'py, PyAny>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Vec<RayHits>> {
        let np = py.import("numpy")?;
        let f = np
            .call_method1("ascontiguousarray", (frames, "float32"))
            .map_err(|e| err(format!("frames: cannot convert to a float32 array: {e}")))?;
        let shape: Vec<usize> = f.getattr("shape")?.extract()?;
        if shape.len() != 3 || shape[1] != self.vertex_count || shape[2] != 3 {
            return Err(err(format!(
                "frames must have shape (T, {}, 3) (the vertices of each frame), got {}",
                self.vertex_count,
                crate::arrays::shape_str(&shape)
            )));
        }
        let nf = shape[0];
        let flat = f.call_method1("reshape", ((nf * self.vertex_count, 3),))?;
        let fv = points("frames", &flat)?;
        let all = fv.as_vec3()?;
        // Rays: (R, 3) shared, or (T, R, 3) flattened to (T R, 3) with the ranges broadcast.
        let o = np.call_method1("asarray", (origins,))?;
        let per_frame = o.getattr("ndim")?.extract::<usize>()? == 3;
        let (o, d, lo, hi, r) = if per_frame {
            let d = np.call_method1("asarray", (directions,))?;
            let (os, ds): (Vec<usize>, Vec<usize>) = (
                o.getattr("shape")?.extract()?,
                d.getattr("shape")?.extract()?,
            );
            if os != ds || os[0] != nf || os[2] != 3 {
                return Err(err(format!(
                    "per-frame rays: origins and directions must both have shape ({nf}, R, 3), got {} and {}",
                    crate::arrays::shape_str(&os),
                    crate::arrays::shape_str(&ds)
                )));
            }
            let r = os[1];
            let range = |x: Option<&Bound<'py, PyAny>>| -> PyResult<Option<Bound<'py, PyAny>>> {
                let Some(x) = x else { return Ok(None) };
                let a = np.call_method1("asarray", (x, "float32"))?;
                if a.getattr("ndim")?.extract::<usize>()? == 0 {
                    return Ok(Some(a));
                }
                let b = np.call_method1("broadcast_to", (a, (nf, r))).map_err(|_| {
                    err(format!(
                        "tmin and tmax must be a number, ({r},) or ({nf}, {r})"
                    ))
                })?;
                Ok(Some(b.call_method1("reshape", (nf * r,))?))
            };
            let flat3 = |a: &Bound<'py, PyAny>| a.call_method1("reshape", ((nf * r, 3),));
            (flat3(&o)?, flat3(&d)?, range(tmin)?, range(tmax)?, r)
        } else {
            let r = o.len().unwrap_or(0);
            (o, directions.clone(), tmin.cloned(), tmax.cloned(), r)
        };
        let arrays = Self::rays(&o, &d, lo.as_ref(), hi.as_ref())?;
        let rays = arrays.slices()?;
        let n = if per_frame { r } else { rays.len() };
        // The output arrays of every frame, allocated before the work.
        let outs: Vec<HitArrays<'py>> = (0..nf)
            .map(|_| HitArrays::new(py, n, false, false))
            .collect();
        let mut guards = Vec::with_capacity(nf);
        for o in &outs {
            guards.push(o.borrow()?);
        }
        let mut cols = Vec::with_capacity(nf);
        for g in guards.iter_mut() {
            cols.push(g.columns()?);
        }
        let (vc, kernel, ds, generation) = (
            self.vertex_count,
            self.kernel,
            self.distance_stack,
            &self.generation,
        );
        let lock = &self.state;
        let rays = &rays;
        let done = detached(py, move || {
            rays.check()?;
            let mut s = lock.write().map_err(|_| {
                "the ray caster was left inconsistent by an internal error".to_string()
            })?;
            // Every frame is checked before the first moves anything: a sequential pass
            // over the vertices that triangles use (the message from the indexed check).
            let mut used = vec![false; vc];
            for &i in s.indices.iter().flatten() {
                if let Some(u) = used.get_mut(i as usize) {
                    *u = true;
                }
            }
            for (k, frame) in all.chunks_exact(vc.max(1)).enumerate() {
                let ok = frame
                    .iter()
                    .zip(&used)
                    .fold(true, |a, (p, &u)| a & (!u | p.is_finite()));
                if !ok {
                    crate::arrays::check_finite(frame, &s.indices)
                        .map_err(|e| format!("frames[{k}]: {e}"))?;
                }
            }
            let mut done = Vec::with_capacity(nf);
            for (k, c) in cols.into_iter().enumerate() {
                refit_state(&mut s, &all[k * vc..(k + 1) * vc], kernel, ds, true)?;
                let g = generation.fetch_add(1, Ordering::SeqCst) + 1;
                let window = if per_frame {
                    rays.window(k * n, n)
                } else {
                    rays.window(0, n)
                };
                let accel = &s.accel;
                let total = c.run(&window, ClosestScratch::new, |x, batch, sink| {
                    closest(accel, batch, x, sink)
                });
                done.push((total, g, s.triangles.clone()));
            }
            Ok::<_, String>(done)
        })?;
        drop(guards);
        Ok(outs
            .into_iter()
            .zip(done)
            .map(|(a, (total, g, triangles))| self.hits(a, triangles, g, total))
            .collect())
    }

    /// Closest hits of rays (origins and directions float32-convertible (N, 3); `tmin` and
    /// `tmax` a number or (N,), default 0 and inf). `counters`: keep the per-ray traversal
    /// counters too. `out`: a `RayHits` of the same length whose arrays are overwritten
    /// and returned (no allocation).
    #[pyo3(signature = (origins, directions, tmin = None, tmax = None, *, counters = false, out = None))]
    #[allow(clippy::too_many_arguments)]
    fn intersect<'py>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
        counters: bool,
        out: Option<PyRef<'py, RayHits>>,
    ) -> PyResult<RayHits> {
        let arrays = Self::rays(origins, directions, tmin, tmax)?;
        let rays = arrays.slices()?;
        let out = out.as_deref().map(|o| o.arrays(py));
        let a = HitArrays::out_or_new(py, out, rays.len(), false, counters)?;
        let (total, (generation, triangles)) = a.trace(
            py,
            &rays,
            &self.state,
            ClosestScratch::new,
            |s, x, batch, sink| closest(&s.accel, batch, x, sink),
            // Read under the lock: the generation of the geometry just traced.
            |s| (self.generation.load(Ordering::SeqCst), s.triangles.clone()),
        )?;
        Ok(self.hits(a, triangles, generation, total))
    }

    /// Every hit along each ray, nearest first, up to `max_hits` per ray (the arguments
    /// as in `intersect`): `(ray, primitive, t)` arrays, ray by ray. Each ray restarts just
    /// past its last hit, so two triangles hit at exactly the same distance (a ray through
    /// a shared edge) count once.
    #[pyo3(signature = (origins, directions, tmin = None, tmax = None, *, max_hits = 100))]
    #[allow(clippy::type_complexity)]
    fn intersect_all<'py>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
        max_hits: i64,
    ) -> PyResult<(
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<f32>>,
    )> {
        let max_hits = count_arg::<u32>("max_hits", Some(max_hits))?.unwrap_or(0);
        let arrays = Self::rays(origins, directions, tmin, tmax)?;
        let rays = arrays.slices()?;
        let n = rays.len();
        let lock = &self.state;
        let rays = &rays;
        let (ray, prim, t) = detached(py, move || {
            rays.check()?;
            let s = read(lock)?;
            let s = &*s;
            let run = |range: std::ops::Range<usize>| {
                let mut stack = TraversalStack::new();
                let (mut ray, mut prim, mut t) = (Vec::new(), Vec::new(), Vec::new());
                for i in range {
                    crossings(&s.accel, &rays.ray(i), max_hits, &mut stack, |h| {
                        ray.push(i as u32);
                        prim.push(h.prim);
                        t.push(h.t);
                    });
                }
                (ray, prim, t)
            };
            let parts: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)> = if n <= SERIAL_RAYS {
                vec![run(0..n)]
            } else {
                (0..n.div_ceil(CHUNK))
                    .into_par_iter()
                    .map(|c| run(c * CHUNK..((c + 1) * CHUNK).min(n)))
                    .collect()
            };
            let total: usize = parts.iter().map(|p| p.0.len()).sum();
            let (mut ray, mut prim, mut t) = (
                Vec::with_capacity(total),
                Vec::with_capacity(total),
                Vec::with_capacity(total),
            );
            for (a, b, c) in parts {
                ray.extend(a);
                prim.extend(b);
                t.extend(c);
            }
            Ok::<_, String>((ray, prim, t))
        })?;
        Ok((
            PyArray1::from_vec(py, ray),
            PyArray1::from_vec(py, prim),
            PyArray1::from_vec(py, t),
        ))
    }

    /// Whether each point ((N, 3)) lies inside the closed mesh: the parity of the surface
    /// crossings along a ray from the point, by majority over three fixed directions
    /// (`CONTAINS_DIRECTIONS`), so that a ray through an edge or a vertex, or grazing the
    /// surface, is outvoted. Crossings are counted as in `intersect_all` (a restart just
    /// past each hit, so two triangles at exactly the same distance count once). A point
    /// outside the tree's box is outside. On the surface the answer is undefined.
    /// `out`: a bool (N,) array to fill.
    #[pyo3(signature = (points, *, out = None))]
    fn contains_points<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<bool>>> {
        let p = crate::arrays::points("points", points)?;
        let ps = p.as_vec3()?;
        let n = ps.len();
        let dirs = CONTAINS_DIRECTIONS.map(|d| Vec3::from_array(d).normalize());
        let inside = |s: &State, stack: &mut TraversalStack, bounds: &Aabb, q: Vec3| {
            bounds.contains_point(q) && {
                let mut odd = |d: Vec3| {
                    crossings(&s.accel, &Ray::new(q, d), u32::MAX, stack, |_| {}) % 2 == 1
                };
                let (a, b) = (odd(dirs[0]), odd(dirs[1]));
                // Two that agree decide; else the third.
                if a == b {
                    a
                } else {
                    odd(dirs[2])
                }
            }
        };
        query_runs(
            py,
            out,
            n,
            "contains_points",
            &self.state,
            || match ps.iter().position(|q| !q.is_finite()) {
                Some(i) => Err(format!("points[{i}] is not finite: {}", ps[i])),
                None => Ok(()),
            },
            |s| (TraversalStack::new(), s.tree.bounds()),
            |s, (stack, bounds), first, run, _| {
                for (o, &q) in run.iter_mut().zip(&ps[first..]) {
                    *o = inside(s, stack, bounds, q);
                }
            },
        )
    }

    /// The primitive each ray hits first: the `primitive` column of `intersect` alone
    /// (`NO_HIT` on a miss), without the others (the arguments as in `intersect`), as a
    /// uint32 array. `out`: a uint32 array of shape (N,) to write into and return.
    #[pyo3(signature = (origins, directions, tmin = None, tmax = None, *, out = None))]
    fn closest_primitives<'py>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let (what, query) = ("closest_primitives", Query::Closest);
        self.column(py, origins, directions, tmin, tmax, out, what, query, |h| {
            h.map_or(NO_HIT, |h| h.prim)
        })
    }

    /// Whether anything lies along each ray within its range (an any-hit query; the
    /// arguments as in `intersect`), as a bool array. `out`: a bool array of shape (N,) to
    /// write into and return.
    #[pyo3(signature = (origins, directions, tmin = None, tmax = None, *, out = None))]
    fn occluded<'py>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<bool>>> {
        let (what, query) = ("occluded", Query::Any);
        self.column(py, origins, directions, tmin, tmax, out, what, query, |h| {
            h.is_some()
        })
    }

    /// A copy of the vertices the structure traces (those of the last build or refit).
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let flat = detached(py, || {
            let s = read(&self.state)?;
            Ok::<_, String>(
                s.vertices
                    .iter()
                    .flat_map(|p| p.to_array())
                    .collect::<Vec<_>>(),
            )
        })?;
        crate::arrays::n3_array(py, flat)
    }

    /// A copy of the triangles' vertex indices.
    #[getter]
    fn indices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u32>>> {
        let flat = detached(py, || {
            let s = read(&self.state)?;
            Ok::<_, String>(s.indices.iter().flatten().copied().collect::<Vec<_>>())
        })?;
        crate::arrays::n3_array(py, flat)
    }

    /// The tree (a copy), as a `Bvh` over the current vertices.
    #[getter]
    fn bvh(&self, py: Python<'_>) -> PyResult<Bvh> {
        let (tree, ix, prims) = detached(py, || {
            let s = read(&self.state)?;
            let prims = aabbs(&s.vertices, &s.indices)?;
            Ok::<_, String>((s.tree.clone(), s.indices.clone(), prims))
        })?;
        Ok(Bvh::new(
            tree,
            self.builder.clone(),
            self.max_leaf,
            Some(ix),
            Some(prims),
        ))
    }

    /// Refits so far (0 after building); every result carries the generation it was
    /// traced against.
    #[getter]
    fn generation(&self) -> u64 {
        self.generation.load(Ordering::SeqCst)
    }

    #[getter]
    fn kernel(&self) -> &'static str {
        self.kernel
    }

    #[getter]
    fn distance_stack(&self) -> bool {
        self.distance_stack
    }

    #[getter]
    fn builder(&self) -> String {
        self.builder.clone()
    }

    #[getter]
    fn triangle_count(&self) -> usize {
        self.triangle_count
    }

    /// Meshes it was built over (1 unless `from_meshes`).
    #[getter]
    fn geometry_count(&self) -> usize {
        self.geometry_first.len() - 1
    }

    #[getter]
    fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    fn __len__(&self) -> usize {
        self.triangle_count
    }

    /// Pickling: the geometry, the tree (in the tree file format) and the settings; the
    /// kernel's form is prepared again on loading (a CBVH encoded again).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let (tree_bytes, v, ix) = detached(py, || {
            let s = read(&self.state)?;
            let mut buf = Vec::new();
            bvh::io::write_tree(&s.tree, &self.builder, &mut buf)
                .map_err(|e| format!("cannot serialize the tree: {e}"))?;
            let v: Vec<f32> = s.vertices.iter().flat_map(|p| p.to_array()).collect();
            let ix: Vec<u32> = s.indices.iter().flatten().copied().collect();
            Ok::<_, String>((buf, v, ix))
        })?;
        let restore = py
            .import("arbor._arbor")?
            .getattr("RayCaster")?
            .getattr("_restore")?;
        let args = (
            crate::arrays::n3_array(py, v)?,
            crate::arrays::n3_array(py, ix)?,
            PyBytes::new(py, &tree_bytes),
            self.kernel,
            self.distance_stack,
            self.builder.clone(),
            self.max_leaf,
            self.generation(),
            self.geometry_first.to_vec(),
            self.vertex_first.clone(),
        );
        PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds a pickled ray caster (see `__reduce__`).
    #[staticmethod]
    #[pyo3(signature = (vertices, indices, tree, kernel, distance_stack, builder, max_leaf, generation, geometry_first = None, vertex_first = None))]
    #[allow(clippy::too_many_arguments)]
    fn _restore(
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        indices: &Bound<'_, PyAny>,
        tree: &[u8],
        kernel: &str,
        distance_stack: bool,
        builder: String,
        max_leaf: u32,
        generation: u64,
        geometry_first: Option<Vec<u32>>,
        vertex_first: Option<Vec<u32>>,
    ) -> PyResult<Self> {
        let v = points("vertices", vertices)?;
        let vs = v.as_vec3()?;
        let ix = crate::arrays::indices(indices, vs.len())?;
        let ixs = ix.get()?;
        let (state, k) = detached(py, || {
            let (tree, _) = bvh::io::read_tree(tree)
                .map_err(|e| format!("cannot read the pickled tree: {e}"))?;
            let k = kernel_name(&tree, Some(kernel))?;
            let state = Self::prepare(vs.to_vec(), ixs.to_vec(), tree, k, distance_stack)?;
            Ok::<_, String>((state, k))
        })?;
        Ok(Self::wrap(
            state,
            k,
            distance_stack,
            builder,
            max_leaf,
            generation,
            geometry_first,
            vertex_first,
        ))
    }

    fn __repr__(&self) -> String {
        format!(
            "RayCaster({} triangles, builder={:?}, kernel={:?}, generation {})",
            self.triangle_count,
            self.builder,
            self.kernel,
            self.generation()
        )
    }
}

/// Registers the ray caster.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<RayCaster>()?;
    m.add_class::<RayHits>()?;
    Ok(())
}

/// What a ray caster traces, copied or moved out of it: an instance's bottom level.
pub(crate) struct Part {
    pub(crate) vertices: Vec<Vec3>,
    pub(crate) indices: Vec<[u32; 3]>,
    pub(crate) triangles: Arc<Vec<Triangle>>,
    pub(crate) tree: Tree,
    pub(crate) accel: Accel,
    pub(crate) kernel: &'static str,
    pub(crate) distance_stack: bool,
    pub(crate) builder: String,
    pub(crate) max_leaf: u32,
}

impl RayCaster {
    /// A copy of its geometry, tree and kernel form.
    pub(crate) fn part(&self) -> Result<Part, String> {
        let s = read(&self.state)?;
        Ok(Part {
            vertices: s.vertices.clone(),
            indices: s.indices.clone(),
            triangles: s.triangles.clone(),
            tree: s.tree.clone(),
            accel: s.accel.clone(),
            kernel: self.kernel,
            distance_stack: self.distance_stack,
            builder: self.builder.clone(),
            max_leaf: self.max_leaf,
        })
    }

    /// Its geometry, tree and kernel form, moved out.
    pub(crate) fn into_part(self) -> Result<Part, String> {
        let s = self
            .state
            .into_inner()
            .map_err(|_| "the ray caster was left inconsistent by an internal error")?;
        Ok(Part {
            vertices: s.vertices,
            indices: s.indices,
            triangles: s.triangles,
            tree: s.tree,
            accel: s.accel,
            kernel: self.kernel,
            distance_stack: self.distance_stack,
            builder: self.builder,
            max_leaf: self.max_leaf,
        })
    }
}
