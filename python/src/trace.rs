//! Tracing: rays as numpy arrays through any of the crate's kernels (`trace::Accel`), with
//! per-ray counters (`trace::RayStats`), the brute-force reference, and the ray sets of a
//! camera (primary rays, and the diffuse paths of `arbor render --rays diffuse`).

use crate::arrays::{err, n3_array, per_ray, points, resolve, PerRay, Points};
use crate::bvh::Bvh;
use crate::detached;
use crate::scene::Camera;
use ::trace::{Accel, KernelOptions, Query, RayStats, TraversalStack, Traverse};
use bvh::Tree;
use geom::{Aabb, Ray, Triangle, Vec3};
use numpy::{PyArray1, PyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use rayon::prelude::*;

/// Primitive id of a ray that hit nothing (`u32::MAX`, as in `trace::Render::prim`).
pub const NO_HIT: u32 = u32::MAX;

/// Rays per parallel work item.
pub(crate) const CHUNK: usize = 1024;

/// What one ray gave.
#[derive(Clone, Copy)]
struct RayOut {
    t: f32,
    prim: u32,
    u: f32,
    v: f32,
    stats: RayStats,
}

/// Hits of a batch of rays, with per-ray counters.
#[pyclass(module = "arbor._arbor", frozen)]
pub struct Hits {
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
    #[pyo3(get)]
    node_visits: Py<PyArray1<u32>>,
    #[pyo3(get)]
    box_tests: Py<PyArray1<u32>>,
    #[pyo3(get)]
    tri_tests: Py<PyArray1<u32>>,
    #[pyo3(get)]
    leaf_visits: Py<PyArray1<u32>>,
    #[pyo3(get)]
    pops: Py<PyArray1<u32>>,
    #[pyo3(get)]
    culled_pops: Py<PyArray1<u32>>,
    #[pyo3(get)]
    max_stack_depth: Py<PyArray1<u32>>,
    #[pyo3(get)]
    kernel: String,
    total: RayStats,
}

/// A counter as u32 (saturating; a single ray never comes near).
fn c32(x: u64) -> u32 {
    x.min(u32::MAX as u64) as u32
}

impl Hits {
    fn from_outs(py: Python<'_>, outs: Vec<RayOut>, kernel: &str) -> Self {
        let mut total = RayStats::default();
        for o in &outs {
            total.add(&o.stats);
        }
        let col_f = |f: &dyn Fn(&RayOut) -> f32| {
            PyArray1::from_vec(py, outs.iter().map(f).collect()).unbind()
        };
        let col_u = |f: &dyn Fn(&RayOut) -> u32| {
            PyArray1::from_vec(py, outs.iter().map(f).collect()).unbind()
        };
        Hits {
            t: col_f(&|o| o.t),
            u: col_f(&|o| o.u),
            v: col_f(&|o| o.v),
            primitive: col_u(&|o| o.prim),
            hit: PyArray1::from_vec(py, outs.iter().map(|o| o.prim != NO_HIT).collect()).unbind(),
            node_visits: col_u(&|o| c32(o.stats.node_visits)),
            box_tests: col_u(&|o| c32(o.stats.box_tests)),
            tri_tests: col_u(&|o| c32(o.stats.tri_tests)),
            leaf_visits: col_u(&|o| c32(o.stats.leaf_visits)),
            pops: col_u(&|o| c32(o.stats.pops)),
            culled_pops: col_u(&|o| c32(o.stats.culled_pops)),
            max_stack_depth: col_u(&|o| c32(o.stats.max_stack_depth)),
            kernel: kernel.to_string(),
            total,
        }
    }
}

#[pymethods]
impl Hits {
    /// Counters summed over all rays (`trace::RayStats`; the stack depth is a maximum).
    #[getter]
    fn totals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        stats_dict(py, &self.total)
    }

    fn __len__(&self) -> usize {
        self.total.rays as usize
    }

    /// Pickling: the arrays, the kernel and the totals.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let restore = py
            .import("arbor._arbor")?
            .getattr("Hits")?
            .getattr("_restore")?;
        let arrays = PyList::new(
            py,
            [
                self.t.bind(py).clone().into_any(),
                self.primitive.bind(py).clone().into_any(),
                self.u.bind(py).clone().into_any(),
                self.v.bind(py).clone().into_any(),
                self.hit.bind(py).clone().into_any(),
                self.node_visits.bind(py).clone().into_any(),
                self.box_tests.bind(py).clone().into_any(),
                self.tri_tests.bind(py).clone().into_any(),
                self.leaf_visits.bind(py).clone().into_any(),
                self.pops.bind(py).clone().into_any(),
                self.culled_pops.bind(py).clone().into_any(),
                self.max_stack_depth.bind(py).clone().into_any(),
            ],
        )?;
        let args = (arrays, self.kernel.clone(), stats_dict(py, &self.total)?);
        PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds pickled hits (see `__reduce__`).
    #[staticmethod]
    fn _restore(
        arrays: Vec<Bound<'_, PyAny>>,
        kernel: String,
        totals: std::collections::HashMap<String, u64>,
    ) -> PyResult<Self> {
        let [t, primitive, u, v, hit, nv, bt, tt, lv, pops, cp, msd] =
            <[Bound<'_, PyAny>; 12]>::try_from(arrays)
                .map_err(|_| err("pickled hits: 12 arrays expected"))?;
        let f = |a: Bound<'_, PyAny>| -> PyResult<Py<PyArray1<f32>>> {
            Ok(a.cast_into::<PyArray1<f32>>()
                .map_err(|_| err("pickled hits: a float32 array expected"))?
                .unbind())
        };
        let c = |a: Bound<'_, PyAny>| -> PyResult<Py<PyArray1<u32>>> {
            Ok(a.cast_into::<PyArray1<u32>>()
                .map_err(|_| err("pickled hits: a uint32 array expected"))?
                .unbind())
        };
        let g = |k: &str| totals.get(k).copied().unwrap_or(0);
        Ok(Hits {
            t: f(t)?,
            primitive: c(primitive)?,
            u: f(u)?,
            v: f(v)?,
            hit: hit
                .cast_into::<PyArray1<bool>>()
                .map_err(|_| err("pickled hits: a bool array expected"))?
                .unbind(),
            node_visits: c(nv)?,
            box_tests: c(bt)?,
            tri_tests: c(tt)?,
            leaf_visits: c(lv)?,
            pops: c(pops)?,
            culled_pops: c(cp)?,
            max_stack_depth: c(msd)?,
            kernel,
            total: RayStats {
                rays: g("rays"),
                hits: g("hits"),
                node_visits: g("node_visits"),
                box_tests: g("box_tests"),
                tri_tests: g("tri_tests"),
                leaf_visits: g("leaf_visits"),
                pushes: g("pushes"),
                pops: g("pops"),
                culled_pops: g("culled_pops"),
                max_stack_depth: g("max_stack_depth"),
            },
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "Hits({} rays, {} hits, kernel {:?})",
            self.total.rays, self.total.hits, self.kernel
        )
    }
}

/// A `RayStats` as a dict.
pub(crate) fn stats_dict<'py>(py: Python<'py>, s: &RayStats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("rays", s.rays)?;
    d.set_item("hits", s.hits)?;
    d.set_item("node_visits", s.node_visits)?;
    d.set_item("box_tests", s.box_tests)?;
    d.set_item("tri_tests", s.tri_tests)?;
    d.set_item("leaf_visits", s.leaf_visits)?;
    d.set_item("pushes", s.pushes)?;
    d.set_item("pops", s.pops)?;
    d.set_item("culled_pops", s.culled_pops)?;
    d.set_item("max_stack_depth", s.max_stack_depth)?;
    Ok(d)
}

/// The kernel names `trace` accepts.
pub(crate) const KERNELS: &str = "bvh2, mbvh4, mbvh8, cbvh";

/// The kernel of `tree`'s own format.
pub(crate) fn tree_kernel(tree: &Tree) -> &'static str {
    match tree {
        Tree::Bvh2(_) => "bvh2",
        Tree::Mbvh4(_) => "mbvh4",
    }
}

/// The distance stack's default for `kernel`, as in `arbor render`: on for the wide
/// kernels, off for the binary ones (the BVH unit of [P4] §3 has none).
pub(crate) fn default_distance_stack(kernel: &str) -> bool {
    matches!(kernel, "mbvh4" | "mbvh8")
}

/// Fails when `triangles` are not those the tree was last built or refitted over
/// (`stored`, its primitive boxes; None for a tree loaded from a file): a stale tree would
/// miss triangles silently. Costs one pass over the triangles.
pub(crate) fn check_current(stored: Option<&[Aabb]>, triangles: &[Triangle]) -> Result<(), String> {
    let Some(stored) = stored else {
        return Ok(());
    };
    let moved = if stored.len() != triangles.len() {
        Some(0)
    } else {
        triangles
            .par_iter()
            .zip(stored.par_iter())
            .with_min_len(CHUNK)
            .position_first(|(t, b)| t.aabb() != *b)
    };
    match moved {
        None => Ok(()),
        Some(i) => Err(format!(
            "the tree is stale: triangle {i} is not where it was when the tree was built or \
             last refitted; call refit(vertices) first"
        )),
    }
}

/// The traceable form of `tree` for `kernel` (None: the tree's own format).
pub(crate) fn accel_of(
    tree: &Tree,
    kernel: Option<&str>,
    triangles: &[Triangle],
    options: KernelOptions,
) -> Result<Accel, String> {
    let te = |e: ::trace::TraceError| format!("cannot prepare the tree for tracing: {e}");
    let binary = |k: &str| match tree {
        Tree::Bvh2(t) => Ok(t),
        Tree::Mbvh4(_) => Err(format!(
            "kernel {k} needs a binary tree; this tree is 4-wide (Mbvh4)"
        )),
    };
    let k = kernel.unwrap_or(match tree {
        Tree::Bvh2(_) => "bvh2",
        Tree::Mbvh4(_) => "mbvh4",
    });
    Ok(match k {
        "bvh2" => Accel::Bvh2(
            ::trace::Bvh2Accel::new(binary(k)?.clone(), triangles, options).map_err(te)?,
        ),
        "mbvh4" => {
            let m = match tree {
                Tree::Mbvh4(m) => m.clone(),
                Tree::Bvh2(t) => bvh::collapse(t)
                    .map_err(|e| format!("cannot collapse the tree to MBVH4: {e}"))?,
            };
            Accel::Mbvh4(::trace::Mbvh4Accel::new(m, triangles, options).map_err(te)?)
        }
        "mbvh8" => Accel::Mbvh8(
            ::trace::Mbvh8Accel::from_bvh2(binary(k)?, triangles, options).map_err(te)?,
        ),
        "cbvh" => {
            let choice = arbor::cmd::cbvh::CbvhChoice::default();
            let (c, _) = cbvh::compress_bottomup(binary(k)?, &choice.cfg)
                .map_err(|e| format!("cannot compress the tree: {e}"))?;
            Accel::Cbvh(::trace::CbvhAccel::new(&c, triangles, options).map_err(te)?)
        }
        other => return Err(format!("unknown kernel '{other}'; valid: {KERNELS}")),
    })
}

/// The ray arguments of a trace call, read from Python: origins, directions and ranges.
pub(crate) struct RayArrays<'py> {
    origins: Points<'py>,
    directions: Points<'py>,
    tmin: PerRay<'py>,
    tmax: PerRay<'py>,
}

impl<'py> RayArrays<'py> {
    pub(crate) fn new(
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Self> {
        let origins = points("origins", origins)?;
        let n = origins.as_vec3()?.len();
        Ok(Self {
            origins,
            directions: points("directions", directions)?,
            tmin: per_ray("tmin", tmin, 0.0, n)?,
            tmax: per_ray("tmax", tmax, f32::INFINITY, n)?,
        })
    }

    /// The arrays' contents, which can cross into a detached closure; as many directions
    /// as origins (else an error).
    pub(crate) fn slices(&self) -> PyResult<RaySlices<'_>> {
        let (o, d) = (self.origins.as_vec3()?, self.directions.as_vec3()?);
        if o.len() != d.len() {
            return Err(err(format!(
                "origins and directions differ in length: {} and {}",
                o.len(),
                d.len()
            )));
        }
        Ok(RaySlices {
            o,
            d,
            tmin: self.tmin.parts()?,
            tmax: self.tmax.parts()?,
        })
    }
}

/// The contents of [`RayArrays`], read by the batch queries in place
/// ([`::trace::RaySource`]).
pub(crate) struct RaySlices<'a> {
    o: &'a [Vec3],
    d: &'a [Vec3],
    tmin: (f32, Option<&'a [f32]>),
    tmax: (f32, Option<&'a [f32]>),
}

/// Rays at or below this count are traced on the calling thread (the prepared queries of
/// `RayCaster`): waking the worker pool costs more than they do.
pub(crate) const SERIAL_RAYS: usize = 512;

impl<'a> RaySlices<'a> {
    /// Rays `first..first + len` (in range).
    pub(crate) fn window(&self, first: usize, len: usize) -> RaySlices<'a> {
        let part = |(x, a): (f32, Option<&'a [f32]>)| (x, a.map(|a| &a[first..first + len]));
        RaySlices {
            o: &self.o[first..first + len],
            d: &self.d[first..first + len],
            tmin: part(self.tmin),
            tmax: part(self.tmax),
        }
    }

    /// Number of rays.
    pub(crate) fn len(&self) -> usize {
        self.o.len()
    }

    /// Ray `i` (below the checked length).
    #[inline(always)]
    pub(crate) fn ray(&self, i: usize) -> Ray {
        Ray::with_range(
            self.o[i],
            self.d[i],
            PerRay::at(&self.tmin.1, self.tmin.0, i),
            PerRay::at(&self.tmax.1, self.tmax.0, i),
        )
    }

    /// What is wrong with ray `i`, if anything.
    #[inline(always)]
    fn fault(&self, i: usize) -> Option<String> {
        let (o, d) = (self.o[i], self.d[i]);
        let t0 = PerRay::at(&self.tmin.1, self.tmin.0, i);
        if !o.is_finite() {
            Some(format!("origins[{i}] is not finite: {o}"))
        } else if !d.is_finite() || d == Vec3::ZERO {
            Some(format!(
                "directions[{i}] must be finite and not zero, got {d}"
            ))
        } else if t0 < 0.0 {
            Some(match self.tmin.1 {
                Some(_) => format!("tmin[{i}] is negative ({t0}); ranges start at 0 or later"),
                None => format!("tmin is negative ({t0}); ranges start at 0 or later"),
            })
        } else {
            None
        }
    }

    /// Whether every ray is valid (finite origin and direction, a direction not zero, a
    /// range that starts at 0 or later; NaN ranges were refused when the arrays were
    /// read): a branch-free pass over the flat coordinates, which the compiler vectorizes.
    fn valid(&self) -> bool {
        let finite = |v: &[Vec3]| {
            v.iter().fold(true, |a, p| {
                a & p.x.is_finite() & p.y.is_finite() & p.z.is_finite()
            })
        };
        let ranges = match self.tmin {
            (x, None) => x >= 0.0,
            (_, Some(t)) => t.iter().fold(true, |a, x| a & (*x >= 0.0)),
        };
        ranges
            && finite(self.o)
            && finite(self.d)
            && self.d.iter().fold(true, |a, p| a & (*p != Vec3::ZERO))
    }

    /// Checks every ray ([`RaySlices::valid`], in parallel runs for many rays); the error
    /// names the first bad ray (searched ray by ray only when there is one).
    pub(crate) fn check(&self) -> Result<(), String> {
        let n = self.len();
        let ok = if n <= 16 * CHUNK {
            self.valid()
        } else {
            (0..n.div_ceil(CHUNK))
                .into_par_iter()
                .all(|c| self.window(c * CHUNK, CHUNK.min(n - c * CHUNK)).valid())
        };
        if ok {
            return Ok(());
        }
        match (0..n).find_map(|i| self.fault(i)) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Checked rays from the arrays.
    fn rays(&self) -> Result<Vec<Ray>, String> {
        self.check()?;
        Ok((0..self.len())
            .into_par_iter()
            .map(|i| self.ray(i))
            .collect())
    }
}

impl ::trace::RaySource for RaySlices<'_> {
    #[inline(always)]
    fn len(&self) -> usize {
        RaySlices::len(self)
    }

    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        RaySlices::ray(self, i)
    }
}

/// One ray's output from a hit.
fn out_of(hit: Option<::trace::Hit>, stats: RayStats) -> RayOut {
    match hit {
        Some(h) => RayOut {
            t: h.t,
            prim: h.prim,
            u: h.bary[1],
            v: h.bary[2],
            stats,
        },
        None => RayOut {
            t: f32::INFINITY,
            prim: NO_HIT,
            u: 0.0,
            v: 0.0,
            stats,
        },
    }
}

/// Traces `rays` through `accel` in parallel, in ray order.
fn trace_all(accel: &Accel, rays: &[Ray], query: Query) -> Vec<RayOut> {
    rays.par_chunks(CHUNK)
        .flat_map_iter(|chunk| {
            let mut stack = TraversalStack::new();
            chunk
                .iter()
                .map(|r| {
                    let mut s = RayStats::default();
                    let h = accel.trace_observed(r, query, &mut stack, &mut s, &mut ());
                    out_of(h, s)
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// Traces rays through `bvh` (built over `indices` into `vertices`).
#[pyfunction]
#[pyo3(name = "trace", signature = (bvh, vertices, indices, origins, directions, tmin = None, tmax = None, *, kernel = None, distance_stack = None, any_hit = false))]
#[allow(clippy::too_many_arguments)]
fn trace_rays<'py>(
    py: Python<'py>,
    bvh: PyRef<'py, Bvh>,
    vertices: &Bound<'py, PyAny>,
    indices: &Bound<'py, PyAny>,
    origins: &Bound<'py, PyAny>,
    directions: &Bound<'py, PyAny>,
    tmin: Option<&Bound<'py, PyAny>>,
    tmax: Option<&Bound<'py, PyAny>>,
    kernel: Option<&str>,
    distance_stack: Option<bool>,
    any_hit: bool,
) -> PyResult<Hits> {
    let v = points("vertices", vertices)?;
    let vs = v.as_vec3()?;
    let ix = crate::arrays::indices(indices, vs.len())?;
    let ixs = ix.get()?;
    let ray_arrays = RayArrays::new(origins, directions, tmin, tmax)?;
    let ray_slices = ray_arrays.slices()?;
    let snap = bvh.snapshot();
    let tree = &snap.tree;
    let stored = snap.prims.as_deref();
    let options = KernelOptions {
        distance_stack: distance_stack
            .unwrap_or_else(|| default_distance_stack(kernel.unwrap_or(tree_kernel(tree)))),
    };
    let query = if any_hit { Query::Any } else { Query::Closest };
    let (outs, name) = detached(py, || {
        if tree.prim_count() != ixs.len() {
            return Err(format!(
                "the tree holds {} primitives but {} triangles were given",
                tree.prim_count(),
                ixs.len()
            ));
        }
        let rays = ray_slices.rays()?;
        let tris = resolve(vs, ixs)?;
        check_current(stored, &tris)?;
        let accel = accel_of(tree, kernel, &tris, options)?;
        Ok((trace_all(&accel, &rays, query), accel.format_name()))
    })?;
    Ok(Hits::from_outs(py, outs, name))
}

/// The closest hit of every ray among all triangles (`::trace::brute_force`, the reference
/// every kernel is tested against). Counters: `tri_tests` is the triangle count.
#[pyfunction]
#[pyo3(signature = (vertices, indices, origins, directions, tmin = None, tmax = None))]
fn trace_brute_force<'py>(
    py: Python<'py>,
    vertices: &Bound<'py, PyAny>,
    indices: &Bound<'py, PyAny>,
    origins: &Bound<'py, PyAny>,
    directions: &Bound<'py, PyAny>,
    tmin: Option<&Bound<'py, PyAny>>,
    tmax: Option<&Bound<'py, PyAny>>,
) -> PyResult<Hits> {
    let v = points("vertices", vertices)?;
    let vs = v.as_vec3()?;
    let ix = crate::arrays::indices(indices, vs.len())?;
    let ixs = ix.get()?;
    let ray_arrays = RayArrays::new(origins, directions, tmin, tmax)?;
    let ray_slices = ray_arrays.slices()?;
    let outs = detached(py, || {
        let rays = ray_slices.rays()?;
        let tris = resolve(vs, ixs)?;
        Ok::<_, String>(
            rays.par_iter()
                .map(|r| {
                    let h = ::trace::brute_force(r, &tris);
                    let s = RayStats {
                        rays: 1,
                        hits: h.is_some() as u64,
                        tri_tests: tris.len() as u64,
                        ..Default::default()
                    };
                    out_of(h, s)
                })
                .collect(),
        )
    })?;
    Ok(Hits::from_outs(py, outs, "brute-force"))
}

/// A set of rays: origins, directions, ranges, and the pixel and bounce of each.
#[pyclass(module = "arbor._arbor", frozen)]
pub struct Rays {
    #[pyo3(get)]
    origins: Py<PyArray2<f32>>,
    #[pyo3(get)]
    directions: Py<PyArray2<f32>>,
    #[pyo3(get)]
    tmin: Py<PyArray1<f32>>,
    #[pyo3(get)]
    tmax: Py<PyArray1<f32>>,
    #[pyo3(get)]
    pixel: Py<PyArray1<u32>>,
    #[pyo3(get)]
    bounce: Py<PyArray1<u8>>,
    #[pyo3(get)]
    width: u32,
    #[pyo3(get)]
    height: u32,
    #[pyo3(get)]
    kind: String,
    count: usize,
}

#[pymethods]
impl Rays {
    fn __len__(&self) -> usize {
        self.count
    }

    /// Pickling: the arrays, the image size and the kind.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let restore = py
            .import("arbor._arbor")?
            .getattr("Rays")?
            .getattr("_restore")?;
        let args = (
            self.origins.bind(py).clone(),
            self.directions.bind(py).clone(),
            self.tmin.bind(py).clone(),
            self.tmax.bind(py).clone(),
            self.pixel.bind(py).clone(),
            self.bounce.bind(py).clone(),
            self.width,
            self.height,
            self.kind.clone(),
        );
        PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds pickled rays (see `__reduce__`).
    #[staticmethod]
    #[allow(clippy::too_many_arguments)]
    fn _restore(
        origins: Bound<'_, PyArray2<f32>>,
        directions: Bound<'_, PyArray2<f32>>,
        tmin: Bound<'_, PyArray1<f32>>,
        tmax: Bound<'_, PyArray1<f32>>,
        pixel: Bound<'_, PyArray1<u32>>,
        bounce: Bound<'_, PyArray1<u8>>,
        width: u32,
        height: u32,
        kind: String,
    ) -> PyResult<Self> {
        let count = tmin.len();
        Ok(Rays {
            origins: origins.unbind(),
            directions: directions.unbind(),
            tmin: tmin.unbind(),
            tmax: tmax.unbind(),
            pixel: pixel.unbind(),
            bounce: bounce.unbind(),
            width,
            height,
            kind,
            count,
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "Rays({} {} rays for {}x{} pixels)",
            self.count, self.kind, self.width, self.height
        )
    }
}

/// Records every ray a render traces, with its pixel and bounce.
#[derive(Default)]
struct Recorder {
    rays: Vec<(Ray, u32, u8)>,
    pixel: u32,
    bounce: u8,
}

impl ::trace::Observer for Recorder {
    fn begin(&mut self, ray: &Ray, _query: Query) {
        self.rays.push((*ray, self.pixel, self.bounce));
    }
}

impl ::trace::render::RayObserver for Recorder {
    fn set_ray(&mut self, pixel: u32, bounce: u8) {
        self.pixel = pixel;
        self.bounce = bounce;
    }
}

/// The rays of a camera image: `primary` (one through each pixel centre, row-major), or
/// `diffuse` (the paths of `arbor render --rays diffuse`: each pixel's primary ray and up
/// to `bounces` cosine-weighted bounces, traced through `bvh` to find them; in the
/// renderer's order, tile by tile).
#[pyfunction]
#[pyo3(signature = (camera, width, height, kind = "primary", *, bvh = None, vertices = None, indices = None, bounces = 4, seed = 1))]
#[allow(clippy::too_many_arguments)]
fn camera_rays<'py>(
    py: Python<'py>,
    camera: PyRef<'py, Camera>,
    width: u32,
    height: u32,
    kind: &str,
    bvh: Option<PyRef<'py, Bvh>>,
    vertices: Option<&Bound<'py, PyAny>>,
    indices: Option<&Bound<'py, PyAny>>,
    bounces: u32,
    seed: u64,
) -> PyResult<Rays> {
    let cam = camera.inner;
    let recorded: Vec<(Ray, u32, u8)> = match kind {
        "primary" => detached(py, || {
            let pc = ::trace::PinholeCamera::new(&cam, width, height).map_err(|e| e.to_string())?;
            let mut v = Vec::with_capacity(width as usize * height as usize);
            for y in 0..height {
                for x in 0..width {
                    v.push((pc.pixel_ray(x, y), y * width + x, 0u8));
                }
            }
            Ok::<_, String>(v)
        })?,
        "diffuse" => {
            let (Some(bvh), Some(vertices), Some(ix)) = (bvh, vertices, indices) else {
                return Err(err(
                    "diffuse rays are found by tracing: pass bvh, vertices and indices",
                ));
            };
            let v = points("vertices", vertices)?;
            let vs = v.as_vec3()?;
            let ix = crate::arrays::indices(ix, vs.len())?;
            let ixs = ix.get()?;
            let snap = bvh.snapshot();
            let tree = &snap.tree;
            let stored = snap.prims.as_deref();
            detached(py, || {
                if tree.prim_count() != ixs.len() {
                    return Err(format!(
                        "the tree holds {} primitives but {} triangles were given",
                        tree.prim_count(),
                        ixs.len()
                    ));
                }
                let tris = resolve(vs, ixs)?;
                check_current(stored, &tris)?;
                let accel = accel_of(tree, None, &tris, KernelOptions::default())?;
                let settings = ::trace::RenderSettings {
                    width,
                    height,
                    rays: ::trace::RayKind::Diffuse,
                    bounces,
                    seed,
                    camera: cam,
                };
                let shading = ::trace::Shading {
                    triangles: &tris,
                    material_ids: &[],
                };
                let mut all = Vec::new();
                ::trace::render::render_observed(
                    &accel,
                    shading,
                    &settings,
                    Recorder::default,
                    |r| {
                        all.extend(r.rays);
                        Ok(())
                    },
                    None,
                )
                .map_err(|e| e.to_string())?;
                Ok(all)
            })?
        }
        other => {
            return Err(err(format!(
                "unknown ray kind '{other}' (known: primary, diffuse)"
            )))
        }
    };
    let n = recorded.len();
    let mut o = Vec::with_capacity(3 * n);
    let mut d = Vec::with_capacity(3 * n);
    let (mut t0, mut t1, mut px, mut b) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for (r, p, bo) in &recorded {
        o.extend_from_slice(&r.origin.to_array());
        d.extend_from_slice(&r.dir.to_array());
        t0.push(r.t_min);
        t1.push(r.t_max);
        px.push(*p);
        b.push(*bo);
    }
    Ok(Rays {
        origins: n3_array(py, o)?.unbind(),
        directions: n3_array(py, d)?.unbind(),
        tmin: PyArray1::from_vec(py, t0).unbind(),
        tmax: PyArray1::from_vec(py, t1).unbind(),
        pixel: PyArray1::from_vec(py, px).unbind(),
        bounce: PyArray1::from_vec(py, b).unbind(),
        width,
        height,
        kind: kind.to_string(),
        count: n,
    })
}

/// Registers the tracing classes and functions.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Hits>()?;
    m.add_class::<Rays>()?;
    m.add_function(wrap_pyfunction!(trace_rays, m)?)?;
    m.add_function(wrap_pyfunction!(trace_brute_force, m)?)?;
    m.add_function(wrap_pyfunction!(camera_rays, m)?)?;
    m.add("NO_HIT", NO_HIT)?;
    Ok(())
}
