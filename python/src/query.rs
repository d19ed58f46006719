//! The plumbing that `RayCaster` and `InstanceCaster` queries share: an `out=` column
//! filled per ray (or per point) with the interpreter released, in parallel runs for many
//! rays, under the state's read lock ([`query_runs`], [`ray_column`]); and the arrays of
//! a closest-hit query, taken from an earlier result or allocated, borrowed for writing
//! and filled the same way ([`HitArrays`], [`Closest`]). The helpers are generic over the
//! per-ray work, so that it inlines into the loops.

use crate::arrays::err;
use crate::detached;
use crate::raycaster::{read, Healthy, COUNTERS};
use crate::trace::{RaySlices, CHUNK, NO_HIT, SERIAL_RAYS};
use ::trace::instance::InstanceHit;
use ::trace::RayStats;
use geom::{Ray, Triangle};
use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadwriteArray1, PyReadwriteArray2, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use rayon::prelude::*;
use std::sync::{OnceLock, RwLock};

/// A counter as u32 (saturating; one ray never comes near).
fn c32(x: u64) -> u32 {
    x.min(u32::MAX as u64) as u32
}

/// Runs `work(scratch, part, first, totals)` over the runs of rays `parts` (`first`: the
/// run's first ray): on this thread for one run, else in parallel, `scratch()` made once
/// for each worker's share rather than once a run (a traversal stack allocates); returns
/// the summed counters.
fn for_chunks<P: Send, X>(
    parts: Vec<P>,
    scratch: impl Fn() -> X + Sync,
    work: impl Fn(&mut X, P, usize, &mut RayStats) + Sync,
) -> RayStats {
    if parts.len() <= 1 {
        let mut total = RayStats::default();
        if let Some(p) = parts.into_iter().next() {
            work(&mut scratch(), p, 0, &mut total);
        }
        return total;
    }
    parts
        .into_par_iter()
        .enumerate()
        .map_init(&scratch, |x, (i, p)| {
            let mut s = RayStats::default();
            work(x, p, i * CHUNK, &mut s);
            s
        })
        .reduce(RayStats::default, |mut a, b| {
            a.add(&b);
            a
        })
}

/// The run length for `n` rays: everything at once when few.
fn chunk_for(n: usize) -> usize {
    if n <= SERIAL_RAYS {
        n.max(1)
    } else {
        CHUNK
    }
}

/// `out` as a writable `(n,)` array of `T` (for `out=` arguments), or a fresh one.
fn out_array<'py, T: numpy::Element>(
    py: Python<'py>,
    out: Option<&Bound<'py, PyAny>>,
    n: usize,
    what: &str,
) -> PyResult<Bound<'py, PyArray1<T>>> {
    match out {
        None => Ok(PyArray1::zeros(py, n, false)),
        Some(o) => {
            let a = o.cast::<PyArray1<T>>().map_err(|_| {
                err(format!(
                    "{what}: out must be a numpy array of dtype {} and shape ({n},)",
                    std::any::type_name::<T>()
                ))
            })?;
            if a.len() != n || !a.is_contiguous() {
                return Err(err(format!(
                    "{what}: out must be a contiguous array of shape ({n},), got shape {:?}",
                    a.shape()
                )));
            }
            Ok(a.clone())
        }
    }
}

/// Fills a `(n,)` column of `T` (`out`, checked by [`out_array`] under the name `what`, or
/// a fresh array) run by run, `fill(state, scratch, first, run, totals)` writing the
/// entries `first..first + run.len()`, with the interpreter released and `lock`
/// read-locked, the runs in parallel when `n` is large (`scratch(state)` made once for
/// each worker's share). `check` runs first, released, before the lock.
#[allow(clippy::too_many_arguments)]
pub(crate) fn query_runs<'py, T, S, X>(
    py: Python<'py>,
    out: Option<&Bound<'py, PyAny>>,
    n: usize,
    what: &str,
    lock: &RwLock<S>,
    check: impl FnOnce() -> Result<(), String> + Send,
    scratch: impl Fn(&S) -> X + Sync,
    fill: impl Fn(&S, &mut X, usize, &mut [T], &mut RayStats) + Sync,
) -> PyResult<Bound<'py, PyArray1<T>>>
where
    T: numpy::Element + Send,
    S: Healthy + Send + Sync,
{
    let a = out_array::<T>(py, out, n, what)?;
    {
        let mut w = a.try_readwrite().map_err(|_| err("out is in use"))?;
        let col = w
            .as_slice_mut()
            .map_err(|_| err("internal error: array not contiguous"))?;
        let (scratch, fill) = (&scratch, &fill);
        detached(py, move || {
            check()?;
            let s = read(lock)?;
            let s = &*s;
            let parts: Vec<&mut [T]> = col.chunks_mut(chunk_for(n)).collect();
            for_chunks(
                parts,
                || scratch(s),
                |x, p, first, tot| fill(s, x, first, p, tot),
            );
            Ok::<_, String>(())
        })?;
    }
    Ok(a)
}

/// [`query_runs`] over `rays` (checked first): `batch(state, scratch, rays, out, totals)`
/// answers a run of rays into `out` (as long as the run).
pub(crate) fn ray_column<'py, T, S, X>(
    py: Python<'py>,
    rays: &RaySlices<'_>,
    out: Option<&Bound<'py, PyAny>>,
    what: &str,
    lock: &RwLock<S>,
    scratch: impl Fn(&S) -> X + Sync,
    batch: impl Fn(&S, &mut X, &RaySlices<'_>, &mut [T], &mut RayStats) + Sync,
) -> PyResult<Bound<'py, PyArray1<T>>>
where
    T: numpy::Element + Send,
    S: Healthy + Send + Sync,
{
    query_runs(
        py,
        out,
        rays.len(),
        what,
        lock,
        || rays.check(),
        scratch,
        |s, x, first, run, tot| batch(s, x, &rays.window(first, run.len()), run, tot),
    )
}

/// The output columns of a closest-hit query over a run of rays (one chunk of the
/// arrays): `instance` for instanced queries, `counters` when per-ray counters are kept.
pub(crate) struct Closest<'a> {
    pub(crate) t: &'a mut [f32],
    pub(crate) instance: Option<&'a mut [u32]>,
    pub(crate) prim: &'a mut [u32],
    pub(crate) u: &'a mut [f32],
    pub(crate) v: &'a mut [f32],
    pub(crate) hit: &'a mut [bool],
    pub(crate) location: &'a mut [f32],
    /// `(n, 7)` counters (the order of [`COUNTERS`]), when asked for.
    pub(crate) counters: Option<&'a mut [u32]>,
}

impl<'a> Closest<'a> {
    /// The columns split into runs of `chunk` rays.
    fn split(self, chunk: usize) -> Vec<Closest<'a>> {
        let mut t = self.t.chunks_mut(chunk);
        let mut instance = self.instance.map(|c| c.chunks_mut(chunk));
        let mut prim = self.prim.chunks_mut(chunk);
        let mut u = self.u.chunks_mut(chunk);
        let mut v = self.v.chunks_mut(chunk);
        let mut hit = self.hit.chunks_mut(chunk);
        let mut location = self.location.chunks_mut(3 * chunk);
        let mut counters = self.counters.map(|c| c.chunks_mut(COUNTERS.len() * chunk));
        let mut out = Vec::new();
        while let (Some(t), Some(prim), Some(u), Some(v), Some(hit), Some(location)) = (
            t.next(),
            prim.next(),
            u.next(),
            v.next(),
            hit.next(),
            location.next(),
        ) {
            out.push(Closest {
                t,
                instance: instance.as_mut().and_then(|c| c.next()),
                prim,
                u,
                v,
                hit,
                location,
                counters: counters.as_mut().and_then(|c| c.next()),
            });
        }
        out
    }

    /// Traces rays `first..first + self.t.len()` as one batch with `trace(rays, sink)`,
    /// which calls `sink.put(i, hit, counters)` once for each ray `i` of the batch (the
    /// closest hit; `instance` 0 where there are no instances), and writes their results.
    fn fill(
        self,
        rays: &RaySlices<'_>,
        first: usize,
        totals: &mut RayStats,
        mut trace: impl FnMut(&RaySlices<'_>, &mut Sink<'_, '_>),
    ) {
        let batch = rays.window(first, self.t.len());
        let mut sink = Sink {
            cols: self,
            batch: &batch,
            totals,
        };
        trace(&batch, &mut sink);
    }

    /// Traces `rays` (as many as the columns) into the columns, on this thread for few
    /// rays, else in parallel runs, with `trace(scratch, rays, done)` on each run (as
    /// [`Closest::fill`]; `scratch()` made once for each worker's share); returns the summed
    /// counters.
    pub(crate) fn run<X>(
        self,
        rays: &RaySlices<'_>,
        scratch: impl Fn() -> X + Sync,
        trace: impl Fn(&mut X, &RaySlices<'_>, &mut Sink<'_, '_>) + Sync,
    ) -> RayStats {
        let n = self.t.len();
        let parts = self.split(chunk_for(n));
        for_chunks(parts, scratch, |x, p, first, tot| {
            p.fill(rays, first, tot, |batch, sink| trace(x, batch, sink))
        })
    }
}

/// Where a batch query ([`Closest::fill`]) puts each ray's answer: the output columns of
/// the run, the run's rays (for the hit locations) and the summed counters.
pub(crate) struct Sink<'c, 'r> {
    cols: Closest<'c>,
    batch: &'r RaySlices<'r>,
    totals: &'r mut RayStats,
}

impl Sink<'_, '_> {
    /// Whether the per-ray counters are written out.
    pub(crate) fn keeps_counters(&self) -> bool {
        self.cols.counters.is_some()
    }

    /// Adds counters to the summed ones.
    pub(crate) fn total(&mut self, st: &RayStats) {
        self.totals.add(st);
    }

    /// Writes ray `k`'s closest hit (`None`: a miss) and counters (when they are kept;
    /// the summed counters are added with [`Sink::total`]).
    #[inline(always)]
    pub(crate) fn put(&mut self, k: usize, h: Option<InstanceHit>, st: &RayStats) {
        let c = &mut self.cols;
        let p = &mut c.location[3 * k..3 * k + 3];
        match h {
            Some(h) => {
                c.t[k] = h.t;
                if let Some(i) = c.instance.as_deref_mut() {
                    i[k] = h.instance;
                }
                c.prim[k] = h.prim;
                c.u[k] = h.bary[1];
                c.v[k] = h.bary[2];
                c.hit[k] = true;
                p.copy_from_slice(&self.batch.ray(k).at(h.t).to_array());
            }
            None => {
                c.t[k] = f32::INFINITY;
                if let Some(i) = c.instance.as_deref_mut() {
                    i[k] = NO_HIT;
                }
                c.prim[k] = NO_HIT;
                c.u[k] = 0.0;
                c.v[k] = 0.0;
                c.hit[k] = false;
                p.fill(f32::NAN);
            }
        }
        if let Some(counters) = c.counters.as_deref_mut() {
            let row = [
                st.node_visits,
                st.box_tests,
                st.tri_tests,
                st.leaf_visits,
                st.pops,
                st.culled_pops,
                st.max_stack_depth,
            ];
            for (j, x) in row.into_iter().enumerate() {
                counters[COUNTERS.len() * k + j] = c32(x);
            }
        }
    }
}

/// A batch query ([`Closest::run`]) from one that traces a ray at a time:
/// `one(scratch, ray, counters)` for each ray of `batch`.
pub(crate) fn one_by_one<X>(
    x: &mut X,
    batch: &RaySlices<'_>,
    sink: &mut Sink<'_, '_>,
    one: impl Fn(&mut X, &Ray, &mut RayStats) -> Option<InstanceHit>,
) {
    for i in 0..batch.len() {
        let mut st = RayStats::default();
        let h = one(x, &batch.ray(i), &mut st);
        sink.put(i, h, &st);
        sink.total(&st);
    }
}

/// The arrays of a closest-hit result (`RayHits`, `InstanceHits`).
pub(crate) struct HitArrays<'py> {
    pub(crate) t: Bound<'py, PyArray1<f32>>,
    pub(crate) instance: Option<Bound<'py, PyArray1<u32>>>,
    pub(crate) prim: Bound<'py, PyArray1<u32>>,
    pub(crate) u: Bound<'py, PyArray1<f32>>,
    pub(crate) v: Bound<'py, PyArray1<f32>>,
    pub(crate) hit: Bound<'py, PyArray1<bool>>,
    pub(crate) location: Bound<'py, PyArray2<f32>>,
    pub(crate) counters: Option<Bound<'py, PyArray2<u32>>>,
}

/// [`HitArrays`] borrowed for writing.
pub(crate) struct HitGuards<'py> {
    t: PyReadwriteArray1<'py, f32>,
    instance: Option<PyReadwriteArray1<'py, u32>>,
    prim: PyReadwriteArray1<'py, u32>,
    u: PyReadwriteArray1<'py, f32>,
    v: PyReadwriteArray1<'py, f32>,
    hit: PyReadwriteArray1<'py, bool>,
    location: PyReadwriteArray2<'py, f32>,
    counters: Option<PyReadwriteArray2<'py, u32>>,
}

impl<'py> HitArrays<'py> {
    /// Fresh arrays for `n` rays, with an instance column and per-ray counters when asked.
    pub(crate) fn new(py: Python<'py>, n: usize, instance: bool, counters: bool) -> Self {
        HitArrays {
            t: PyArray1::zeros(py, n, false),
            instance: instance.then(|| PyArray1::zeros(py, n, false)),
            prim: PyArray1::zeros(py, n, false),
            u: PyArray1::zeros(py, n, false),
            v: PyArray1::zeros(py, n, false),
            hit: PyArray1::zeros(py, n, false),
            location: PyArray2::zeros(py, [n, 3], false),
            counters: counters.then(|| PyArray2::zeros(py, [n, COUNTERS.len()], false)),
        }
    }

    /// The arrays of `out` (an earlier result, to be overwritten) checked to hold `n` rays
    /// and counters exactly when `counters`, or fresh ones.
    pub(crate) fn out_or_new(
        py: Python<'py>,
        out: Option<Self>,
        n: usize,
        instance: bool,
        counters: bool,
    ) -> PyResult<Self> {
        let Some(o) = out else {
            return Ok(Self::new(py, n, instance, counters));
        };
        let len = o.t.len();
        if len != n {
            return Err(err(format!("out holds {len} rays, {n} given")));
        }
        if counters != o.counters.is_some() {
            return Err(err("out must have counters exactly when counters=True"));
        }
        Ok(o)
    }

    /// The arrays borrowed for writing (`out.<name> is in use` if one is borrowed).
    pub(crate) fn borrow(&self) -> PyResult<HitGuards<'py>> {
        let in_use = |w: &str| err(format!("out.{w} is in use"));
        Ok(HitGuards {
            t: self.t.try_readwrite().map_err(|_| in_use("t"))?,
            instance: match &self.instance {
                Some(a) => Some(a.try_readwrite().map_err(|_| in_use("instance"))?),
                None => None,
            },
            prim: self.prim.try_readwrite().map_err(|_| in_use("primitive"))?,
            u: self.u.try_readwrite().map_err(|_| in_use("u"))?,
            v: self.v.try_readwrite().map_err(|_| in_use("v"))?,
            hit: self.hit.try_readwrite().map_err(|_| in_use("hit"))?,
            location: self
                .location
                .try_readwrite()
                .map_err(|_| in_use("location"))?,
            counters: match &self.counters {
                Some(a) => Some(a.try_readwrite().map_err(|_| in_use("counters"))?),
                None => None,
            },
        })
    }

    /// Closest hits of `rays` (as many as the arrays) written into the arrays with
    /// `trace(state, scratch, rays, done)` (as [`Closest::run`]), with the interpreter
    /// released and `lock` read-locked; returns the summed counters and `after(state)`,
    /// read under the same lock.
    pub(crate) fn trace<S, X, R>(
        &self,
        py: Python<'py>,
        rays: &RaySlices<'_>,
        lock: &RwLock<S>,
        scratch: impl Fn() -> X + Sync,
        trace: impl Fn(&S, &mut X, &RaySlices<'_>, &mut Sink<'_, '_>) + Sync,
        after: impl FnOnce(&S) -> R + Send,
    ) -> PyResult<(RayStats, R)>
    where
        S: Healthy + Send + Sync,
        R: Send,
    {
        let mut guards = self.borrow()?;
        let cols = guards.columns()?;
        let (scratch, trace) = (&scratch, &trace);
        detached(py, move || {
            rays.check()?;
            let s = read(lock)?;
            let s = &*s;
            let total = cols.run(rays, scratch, |x, batch, sink| trace(s, x, batch, sink));
            Ok::<_, String>((total, after(s)))
        })
    }
}

impl HitGuards<'_> {
    /// The borrowed arrays as slices.
    pub(crate) fn columns(&mut self) -> PyResult<Closest<'_>> {
        let nc = || err("internal error: array not contiguous");
        Ok(Closest {
            t: self.t.as_slice_mut().map_err(|_| nc())?,
            instance: match self.instance.as_mut() {
                Some(c) => Some(c.as_slice_mut().map_err(|_| nc())?),
                None => None,
            },
            prim: self.prim.as_slice_mut().map_err(|_| nc())?,
            u: self.u.as_slice_mut().map_err(|_| nc())?,
            v: self.v.as_slice_mut().map_err(|_| nc())?,
            hit: self.hit.as_slice_mut().map_err(|_| nc())?,
            location: self.location.as_slice_mut().map_err(|_| nc())?,
            counters: match self.counters.as_mut() {
                Some(c) => Some(c.as_slice_mut().map_err(|_| nc())?),
                None => None,
            },
        })
    }
}

/// The normals of a closest-hit result, cached in `cell`: on the first call computed with
/// the interpreter released, in parallel, for each hit `k` as the unit geometric normal
/// (`cross(p1 - p0, p2 - p0)` normalized) of `triangle(prim[k], inst[k])` (`inst` 0 where
/// there are no instances), NaN where that gives none (a miss).
pub(crate) fn cached_normals<'py>(
    py: Python<'py>,
    cell: &OnceLock<Py<PyArray2<f32>>>,
    prim: &Bound<'py, PyArray1<u32>>,
    inst: Option<&Bound<'py, PyArray1<u32>>>,
    triangle: impl Fn(u32, u32) -> Option<Triangle> + Sync,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    if let Some(n) = cell.get() {
        return Ok(n.bind(py).clone());
    }
    let nc = "internal error: array not contiguous";
    let inst = inst.map(|a| a.readonly());
    let prim = prim.readonly();
    let insts = match &inst {
        Some(a) => Some(a.as_slice().map_err(|_| err(nc))?),
        None => None,
    };
    let prims = prim.as_slice().map_err(|_| err(nc))?;
    let flat = py.detach(|| {
        let mut out = vec![f32::NAN; 3 * prims.len()];
        out.par_chunks_mut(3 * CHUNK)
            .zip(prims.par_chunks(CHUNK))
            .enumerate()
            .for_each(|(c, (o, ps))| {
                let is = insts.map(|s| &s[(c * CHUNK).min(s.len())..]);
                for (k, (n, &p)) in o.chunks_exact_mut(3).zip(ps).enumerate() {
                    let i = match is {
                        Some(is) => match is.get(k) {
                            Some(&i) => i,
                            None => break,
                        },
                        None => 0,
                    };
                    if let Some(t) = triangle(p, i) {
                        let g = (t.v[1] - t.v[0]).cross(t.v[2] - t.v[0]).normalize_or_zero();
                        n.copy_from_slice(&g.to_array());
                    }
                }
            });
        out
    });
    let a = crate::arrays::n3_array(py, flat)?;
    let _ = cell.set(a.clone().unbind());
    Ok(cell.get().map_or(a, |n| n.bind(py).clone()))
}
