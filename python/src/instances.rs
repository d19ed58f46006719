//! `InstanceCaster`: two-level instancing from Python (`trace::instance`). Bottom levels
//! are prepared ray casters (given as `RayCaster`s, whose trees and kernel forms are
//! copied, or as meshes built here); instances place them in the world with affine
//! transforms; a top-level tree over the instances' world boxes is refitted in place when
//! the transforms change (`set_transforms`) or a mesh deforms (`refit`).
//!
//! As with `RayCaster`, queries run with the interpreter released, in parallel for more
//! than a few hundred rays, under a read lock that updates wait for.

use crate::arrays::{err, points};
use crate::bvh::aabbs;
use crate::detached;
use crate::query::{cached_normals, one_by_one, ray_column, HitArrays};
use crate::raycaster::{count_arg, mesh_arrays, read, BuildOptions, Healthy, Part, RayCaster};
use crate::trace::{accel_of, NO_HIT};
use ::trace::instance::{BottomLevel, Instance, InstanceAccel, InstanceStack, Transform};
use ::trace::{KernelOptions, RayStats};
use geom::{Triangle, Vec3};
use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock, RwLock};

/// What an `InstanceCaster` traces.
/// A bottom level's geometry, tree and settings (its traceable form is in the
/// `InstanceAccel`).
struct Mesh {
    vertices: Vec<Vec3>,
    indices: Vec<[u32; 3]>,
    triangles: Arc<Vec<Triangle>>,
    tree: bvh::Tree,
    kernel: &'static str,
    distance_stack: bool,
    builder: String,
    max_leaf: u32,
}

struct IState {
    /// The bottom levels' geometry and trees (kept for refits and pickling).
    parts: Vec<Mesh>,
    /// Each mesh's triangles, shared with the results traced over them (for normals).
    triangles: Arc<Vec<Arc<Vec<Triangle>>>>,
    /// Each instance's transform, shared with the results traced over them.
    transforms: Arc<Vec<Transform>>,
    accel: InstanceAccel,
    /// Set while an update changes the state; left set if it failed half way.
    broken: bool,
}

impl Healthy for IState {
    fn broken(&self) -> bool {
        self.broken
    }
}

/// Instances of meshes under a top-level tree (see the module header).
#[pyclass(module = "arbor._arbor", frozen)]
pub struct InstanceCaster {
    state: RwLock<IState>,
    /// Updates so far (`set_transforms` and `refit`).
    generation: AtomicU64,
    /// The mesh of each instance.
    mesh_index: Arc<Vec<u32>>,
    /// Vertex count of each mesh (refits keep it).
    vertex_counts: Vec<usize>,
}

/// `(K, 3, 4)` or `(K, 4, 4)` affine matrices (rows `[M | t]`, a 4x4's last row
/// `0 0 0 1`) as checked transforms; `what` names the argument in errors.
fn transforms_arg(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Transform>> {
    let np = obj.py().import("numpy")?;
    let a = np
        .call_method1("ascontiguousarray", (obj, "float64"))
        .map_err(|e| err(format!("{what}: cannot convert to a float64 array: {e}")))?;
    let u = a
        .cast::<PyUntypedArray>()
        .map_err(|_| err(format!("{what}: cannot convert to an array")))?;
    let shape = u.shape().to_vec();
    if shape.len() != 3 || shape[2] != 4 || !(shape[1] == 3 || shape[1] == 4) {
        return Err(err(format!(
            "{what} must have shape (K, 3, 4) or (K, 4, 4), got ({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    let a = a
        .cast_into::<PyArray3<f64>>()
        .map_err(|_| err(format!("{what}: not a float64 array")))?;
    let ro = a.readonly();
    let flat = ro
        .as_slice()
        .map_err(|_| err("internal error: array not contiguous"))?;
    let rows = shape[1];
    flat.chunks_exact(4 * rows)
        .enumerate()
        .map(|(i, m)| {
            if rows == 4 && m[12..16] != [0.0, 0.0, 0.0, 1.0] {
                return Err(err(format!(
                    "{what}[{i}] is not affine: its last row is {:?}, not [0, 0, 0, 1]",
                    &m[12..16]
                )));
            }
            let r: [[f32; 4]; 3] =
                std::array::from_fn(|r| std::array::from_fn(|c| m[4 * r + c] as f32));
            Transform::new(r).map_err(|e| err(format!("{what}[{i}]: {e}")))
        })
        .collect()
}

/// `(K,)` mesh indices, each below `meshes`.
fn mesh_index_arg(obj: &Bound<'_, PyAny>, meshes: usize) -> PyResult<Vec<u32>> {
    let np = obj.py().import("numpy")?;
    let a = np
        .call_method1("asarray", (obj,))
        .map_err(|e| err(format!("mesh_index: cannot convert to an array: {e}")))?;
    let u = a
        .cast::<PyUntypedArray>()
        .map_err(|_| err("mesh_index: cannot convert to an array"))?;
    if u.ndim() != 1 {
        return Err(err(format!(
            "mesh_index must have shape (K,), got {} dimensions",
            u.ndim()
        )));
    }
    let kind = u.dtype().kind() as char;
    if u.len() > 0 && kind != 'i' && kind != 'u' {
        return Err(err(format!(
            "mesh_index must be integers, got dtype kind '{kind}'"
        )));
    }
    let v: Vec<i128> = np
        .call_method1("asarray", (&a, "int64"))?
        .call_method0("tolist")?
        .extract()?;
    v.into_iter()
        .enumerate()
        .map(|(i, m)| {
            u32::try_from(m)
                .ok()
                .filter(|&m| (m as usize) < meshes)
                .ok_or_else(|| {
                    err(format!(
                        "mesh_index[{i}] is {m}, but there are {meshes} meshes"
                    ))
                })
        })
        .collect()
}

/// The state over `parts` and their instances.
fn assemble(
    parts: Vec<Part>,
    mesh_index: &[u32],
    transforms: Vec<Transform>,
) -> Result<IState, String> {
    if transforms.len() != mesh_index.len() {
        return Err(format!(
            "{} transforms given for {} instances (mesh_index)",
            transforms.len(),
            mesh_index.len()
        ));
    }
    if transforms.is_empty() {
        return Err("an InstanceCaster needs at least one instance".into());
    }
    let mut bottoms = Vec::with_capacity(parts.len());
    let mut meshes = Vec::with_capacity(parts.len());
    for p in parts {
        bottoms.push(BottomLevel::new(p.accel, &p.triangles).map_err(|e| e.to_string())?);
        meshes.push(Mesh {
            vertices: p.vertices,
            indices: p.indices,
            triangles: p.triangles,
            tree: p.tree,
            kernel: p.kernel,
            distance_stack: p.distance_stack,
            builder: p.builder,
            max_leaf: p.max_leaf,
        });
    }
    let parts = meshes;
    let instances = mesh_index
        .iter()
        .zip(&transforms)
        .map(|(&bottom, &transform)| Instance { bottom, transform })
        .collect();
    let accel = InstanceAccel::new(bottoms, instances).map_err(|e| e.to_string())?;
    Ok(IState {
        triangles: Arc::new(parts.iter().map(|p| p.triangles.clone()).collect()),
        parts,
        transforms: Arc::new(transforms),
        accel,
        broken: false,
    })
}

/// Closest hits of a batch of rays from [`InstanceCaster::intersect`]: per ray `t` (world
/// distance in units of the ray direction, `inf` on a miss), the `instance`, the
/// `primitive` (triangle within the instance's mesh), barycentrics `u`, `v`, `hit`, the
/// world `location`, and on access the instance's `geometry` (mesh) and the world-space
/// unit geometric `normal`.
#[pyclass(module = "arbor._arbor", frozen)]
pub struct InstanceHits {
    #[pyo3(get)]
    t: Py<PyArray1<f32>>,
    #[pyo3(get)]
    instance: Py<PyArray1<u32>>,
    #[pyo3(get)]
    primitive: Py<PyArray1<u32>>,
    #[pyo3(get)]
    u: Py<PyArray1<f32>>,
    #[pyo3(get)]
    v: Py<PyArray1<f32>>,
    #[pyo3(get)]
    hit: Py<PyArray1<bool>>,
    #[pyo3(get)]
    location: Py<PyArray2<f32>>,
    /// What the normals are computed from: the meshes' triangles and the transforms of
    /// the generation traced.
    triangles: Arc<Vec<Arc<Vec<Triangle>>>>,
    transforms: Arc<Vec<Transform>>,
    mesh_index: Arc<Vec<u32>>,
    normal: OnceLock<Py<PyArray2<f32>>>,
    #[pyo3(get)]
    generation: u64,
    total: RayStats,
}

impl InstanceHits {
    /// Its arrays, to be overwritten by a query given it as `out`.
    fn arrays<'py>(&self, py: Python<'py>) -> HitArrays<'py> {
        HitArrays {
            t: self.t.bind(py).clone(),
            instance: Some(self.instance.bind(py).clone()),
            prim: self.primitive.bind(py).clone(),
            u: self.u.bind(py).clone(),
            v: self.v.bind(py).clone(),
            hit: self.hit.bind(py).clone(),
            location: self.location.bind(py).clone(),
            counters: None,
        }
    }
}

#[pymethods]
impl InstanceHits {
    /// The mesh of each hit instance (`mesh_index[instance]`), `NO_HIT` on a miss.
    #[getter]
    fn geometry<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let inst = self.instance.bind(py).readonly();
        let s = inst
            .as_slice()
            .map_err(|_| err("internal error: array not contiguous"))?;
        let mi = &self.mesh_index;
        let out: Vec<u32> = s
            .iter()
            .map(|&i| mi.get(i as usize).copied().unwrap_or(NO_HIT))
            .collect();
        Ok(PyArray1::from_vec(py, out))
    }

    /// The unit geometric normal of each hit triangle in world space (the normalized
    /// `cross(p1 - p0, p2 - p0)` of the triangle moved into the world; NaN on a miss),
    /// computed on first access.
    #[getter]
    fn normal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let (tris, xf, mi) = (&self.triangles, &self.transforms, &self.mesh_index);
        let (prim, inst) = (self.primitive.bind(py), self.instance.bind(py));
        cached_normals(py, &self.normal, prim, Some(inst), |p, i| {
            let tri = mi
                .get(i as usize)
                .and_then(|&m| tris.get(m as usize))
                .and_then(|t| t.get(p as usize))?;
            Some(xf.get(i as usize)?.triangle_to_world(tri))
        })
    }

    /// Counters summed over all rays (top and bottom levels).
    #[getter]
    fn totals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        crate::trace::stats_dict(py, &self.total)
    }

    fn __len__(&self, py: Python<'_>) -> usize {
        self.t.bind(py).len()
    }

    /// Pickling: the arrays, with the normals computed, and the instances' meshes.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let restore = py
            .import("arbor._arbor")?
            .getattr("InstanceHits")?
            .getattr("_restore")?;
        let args = (
            self.t.bind(py).clone(),
            self.instance.bind(py).clone(),
            self.primitive.bind(py).clone(),
            self.u.bind(py).clone(),
            self.v.bind(py).clone(),
            self.hit.bind(py).clone(),
            self.location.bind(py).clone(),
            self.normal(py)?,
            self.mesh_index.to_vec(),
            self.generation,
        );
        PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds a pickled result (see `__reduce__`).
    #[staticmethod]
    #[allow(clippy::too_many_arguments)]
    fn _restore(
        t: Bound<'_, PyArray1<f32>>,
        instance: Bound<'_, PyArray1<u32>>,
        primitive: Bound<'_, PyArray1<u32>>,
        u: Bound<'_, PyArray1<f32>>,
        v: Bound<'_, PyArray1<f32>>,
        hit: Bound<'_, PyArray1<bool>>,
        location: Bound<'_, PyArray2<f32>>,
        normal: Bound<'_, PyArray2<f32>>,
        mesh_index: Vec<u32>,
        generation: u64,
    ) -> PyResult<Self> {
        let n = t.len();
        let lens = [
            instance.len(),
            primitive.len(),
            u.len(),
            v.len(),
            hit.len(),
            location.shape()[0],
            normal.shape()[0],
        ];
        if lens.iter().any(|&l| l != n) {
            return Err(err("pickled result: arrays of different lengths"));
        }
        let cached = OnceLock::new();
        let _ = cached.set(normal.unbind());
        let total = RayStats {
            rays: n as u64,
            ..Default::default()
        };
        Ok(InstanceHits {
            t: t.unbind(),
            instance: instance.unbind(),
            primitive: primitive.unbind(),
            u: u.unbind(),
            v: v.unbind(),
            hit: hit.unbind(),
            location: location.unbind(),
            triangles: Arc::new(Vec::new()),
            transforms: Arc::new(Vec::new()),
            mesh_index: Arc::new(mesh_index),
            normal: cached,
            generation,
            total,
        })
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "InstanceHits({} rays, generation {})",
            self.t.bind(py).len(),
            self.generation
        )
    }
}

impl InstanceCaster {
    fn wrap(state: IState, mesh_index: Vec<u32>, generation: u64) -> Self {
        let vertex_counts = state.parts.iter().map(|p| p.vertices.len()).collect();
        InstanceCaster {
            state: RwLock::new(state),
            generation: AtomicU64::new(generation),
            mesh_index: Arc::new(mesh_index),
            vertex_counts,
        }
    }

    fn write(&self) -> Result<std::sync::RwLockWriteGuard<'_, IState>, String> {
        self.state
            .write()
            .map_err(|_| "the instance caster was left inconsistent by an internal error".into())
    }
}

#[pymethods]
impl InstanceCaster {
    /// Instances of `meshes` (each a `RayCaster`, whose tree and kernel are reused, or
    /// `(vertices, indices)`, or an object with `vertices` and `faces`/`indices`, built
    /// here with the builder options) placed by `transforms` ((K, 3, 4) or (K, 4, 4)
    /// object-to-world matrices); instance `i` shows mesh `mesh_index[i]` (default: mesh
    /// `i` when there are K meshes, mesh 0 when there is one).
    #[new]
    #[pyo3(signature = (meshes, transforms, mesh_index = None, builder = "binned-sah", *, kernel = None, distance_stack = None, max_leaf = None, bins = None, collapse_from = None, threads = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        meshes: &Bound<'_, PyAny>,
        transforms: &Bound<'_, PyAny>,
        mesh_index: Option<&Bound<'_, PyAny>>,
        builder: &str,
        kernel: Option<&str>,
        distance_stack: Option<bool>,
        max_leaf: Option<i64>,
        bins: Option<i64>,
        collapse_from: Option<String>,
        threads: Option<i64>,
    ) -> PyResult<Self> {
        let xf = transforms_arg(transforms, "transforms")?;
        let mut parts = Vec::new();
        let items = meshes
            .try_iter()
            .map_err(|_| err("meshes must be a sequence of meshes"))?;
        for (g, m) in items.enumerate() {
            let m = m?;
            if let Ok(rc) = m.cast::<RayCaster>() {
                let rc = rc.get();
                parts.push(detached(py, || rc.part())?);
                continue;
            }
            let (v, ix) = mesh_arrays(&m, g)?;
            let pv = points(&format!("meshes[{g}] vertices"), &v)?;
            let pvs = pv.as_vec3()?;
            let pix = crate::arrays::indices(&ix, pvs.len())?;
            let opts = BuildOptions {
                builder,
                kernel,
                distance_stack,
                max_leaf,
                bins,
                collapse_from: collapse_from.clone(),
                threads,
            };
            let rc = RayCaster::build(py, pvs, pix.get()?, opts, None)?;
            parts.push(rc.into_part().map_err(err)?);
        }
        if parts.is_empty() {
            return Err(err("an InstanceCaster needs at least one mesh"));
        }
        let mi = match mesh_index {
            Some(m) => mesh_index_arg(m, parts.len())?,
            None if parts.len() == 1 => vec![0; xf.len()],
            None if parts.len() == xf.len() => (0..xf.len() as u32).collect(),
            None => {
                return Err(err(format!(
                    "{} meshes and {} transforms: pass mesh_index (the mesh of each instance)",
                    parts.len(),
                    xf.len()
                )))
            }
        };
        let state = detached(py, || assemble(parts, &mi, xf))?;
        Ok(Self::wrap(state, mi, 0))
    }

    /// Replaces every instance's transform ((K, 3, 4) or (K, 4, 4)) and refits the top
    /// level in place (`rebuild=True`: builds it anew, better after large motion).
    #[pyo3(signature = (transforms, *, rebuild = false))]
    fn set_transforms(
        &self,
        py: Python<'_>,
        transforms: &Bound<'_, PyAny>,
        rebuild: bool,
    ) -> PyResult<()> {
        let xf = transforms_arg(transforms, "transforms")?;
        if xf.len() != self.mesh_index.len() {
            return Err(err(format!(
                "{} transforms given for {} instances",
                xf.len(),
                self.mesh_index.len()
            )));
        }
        detached(py, || {
            let mut s = self.write()?;
            s.broken = true;
            s.accel.set_transforms(&xf).map_err(|e| e.to_string())?;
            if rebuild {
                s.accel.rebuild().map_err(|e| e.to_string())?;
            }
            s.transforms = Arc::new(xf);
            s.broken = false;
            self.generation.fetch_add(1, Ordering::SeqCst);
            Ok::<_, String>(())
        })
    }

    /// Moves the vertices of mesh `mesh` (same count, same triangles): its tree and
    /// kernel form are refitted in place (a CBVH encoded again) and the top level too.
    fn refit(&self, py: Python<'_>, mesh: i64, vertices: &Bound<'_, PyAny>) -> PyResult<()> {
        let count = self.vertex_counts.len();
        let g = count_arg::<usize>("mesh", Some(mesh))?
            .filter(|&g| g < count)
            .ok_or_else(|| err(format!("no mesh {mesh} (there are {count})")))?;
        let v = points("vertices", vertices)?;
        let vs = v.as_vec3()?;
        if vs.len() != self.vertex_counts[g] {
            return Err(err(format!(
                "refit keeps the topology: mesh {g} has {} vertices, {} given",
                self.vertex_counts[g],
                vs.len()
            )));
        }
        detached(py, || {
            let mut guard = self.write()?;
            let s = &mut *guard;
            let part = &mut s.parts[g];
            let triangles = crate::arrays::resolve(vs, &part.indices)?;
            let prims = aabbs(vs, &part.indices)?;
            s.broken = true;
            part.tree
                .refit(&prims)
                .map_err(|e| format!("cannot refit the tree: {e}"))?;
            let refitted = s
                .accel
                .refit_bottom(g, &triangles)
                .map_err(|e| e.to_string())?;
            if !refitted {
                // A CBVH: encoded again, and the top level built over the new bottom.
                let options = KernelOptions {
                    distance_stack: part.distance_stack,
                };
                let accel = accel_of(&part.tree, Some(part.kernel), &triangles, options)?;
                let mut bottoms = s.accel.bottoms().to_vec();
                bottoms[g] = BottomLevel::new(accel, &triangles).map_err(|e| e.to_string())?;
                s.accel = InstanceAccel::new(bottoms, s.accel.instances().to_vec())
                    .map_err(|e| e.to_string())?;
            }
            part.vertices.copy_from_slice(vs);
            part.triangles = Arc::new(triangles);
            s.triangles = Arc::new(s.parts.iter().map(|p| p.triangles.clone()).collect());
            s.broken = false;
            self.generation.fetch_add(1, Ordering::SeqCst);
            Ok::<_, String>(())
        })
    }

    /// Closest hits (the arguments as in `RayCaster.intersect`). `out`: an earlier result
    /// of the same length whose arrays are overwritten and returned.
    #[pyo3(signature = (origins, directions, tmin = None, tmax = None, *, out = None))]
    fn intersect<'py>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmin: Option<&Bound<'py, PyAny>>,
        tmax: Option<&Bound<'py, PyAny>>,
        out: Option<PyRef<'py, InstanceHits>>,
    ) -> PyResult<InstanceHits> {
        let arrays = RayCaster::rays(origins, directions, tmin, tmax)?;
        let rays = arrays.slices()?;
        let out = out.as_deref().map(|o| o.arrays(py));
        let a = HitArrays::out_or_new(py, out, rays.len(), true, false)?;
        let (total, (generation, triangles, transforms)) = a.trace(
            py,
            &rays,
            &self.state,
            InstanceStack::new,
            |s, stack, batch, sink| {
                one_by_one(stack, batch, sink, |stack, ray, st| {
                    s.accel.closest_hit(ray, stack, st)
                })
            },
            |s| {
                (
                    self.generation.load(Ordering::SeqCst),
                    s.triangles.clone(),
                    s.transforms.clone(),
                )
            },
        )?;
        Ok(InstanceHits {
            t: a.t.unbind(),
            instance: a
                .instance
                .ok_or_else(|| err("internal error: no instance column"))?
                .unbind(),
            primitive: a.prim.unbind(),
            u: a.u.unbind(),
            v: a.v.unbind(),
            hit: a.hit.unbind(),
            location: a.location.unbind(),
            triangles,
            transforms,
            mesh_index: self.mesh_index.clone(),
            normal: OnceLock::new(),
            generation,
            total,
        })
    }

    /// Whether anything lies along each ray within its range, as booleans (the arguments
    /// as in `intersect`; `out`: a bool (N,) array to fill).
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
        let arrays = RayCaster::rays(origins, directions, tmin, tmax)?;
        let rays = arrays.slices()?;
        ray_column(
            py,
            &rays,
            out,
            "occluded",
            &self.state,
            |_| InstanceStack::new(),
            |s, stack, batch, out, tot| {
                for (i, o) in out.iter_mut().enumerate() {
                    *o = s.accel.any_hit(&batch.ray(i), stack, tot).is_some();
                }
            },
        )
    }

    /// The instances' object-to-world matrices, (K, 3, 4) float32.
    #[getter]
    fn transforms<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let flat: Vec<f32> = {
            let s = read(&self.state).map_err(err)?;
            s.transforms
                .iter()
                .flat_map(|t| t.matrix().into_iter().flatten())
                .collect()
        };
        let k = self.mesh_index.len();
        PyArray1::from_vec(py, flat).reshape([k, 3, 4])
    }

    /// The mesh of each instance, (K,) uint32.
    #[getter]
    fn mesh_index<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        PyArray1::from_slice(py, &self.mesh_index)
    }

    /// Updates so far (`set_transforms` and `refit`; 0 after building).
    #[getter]
    fn generation(&self) -> u64 {
        self.generation.load(Ordering::SeqCst)
    }

    #[getter]
    fn instance_count(&self) -> usize {
        self.mesh_index.len()
    }

    #[getter]
    fn mesh_count(&self) -> usize {
        self.vertex_counts.len()
    }

    /// The kernel of each mesh.
    #[getter]
    fn kernels(&self) -> PyResult<Vec<&'static str>> {
        let s = read(&self.state).map_err(err)?;
        Ok(s.parts.iter().map(|p| p.kernel).collect())
    }

    fn __len__(&self) -> usize {
        self.mesh_index.len()
    }

    /// Pickling: each mesh (geometry, tree in the tree-file format, settings), the
    /// transforms and the mesh of each instance; the kernels' forms and the top level are
    /// prepared again on loading.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        type Flat = (Vec<f32>, Vec<u32>, Vec<u8>, &'static str, bool, String, u32);
        let (meshes, xf) = detached(py, || {
            let s = read(&self.state)?;
            let mut meshes: Vec<Flat> = Vec::new();
            for p in &s.parts {
                let mut buf = Vec::new();
                bvh::io::write_tree(&p.tree, &p.builder, &mut buf)
                    .map_err(|e| format!("cannot serialize a tree: {e}"))?;
                meshes.push((
                    p.vertices.iter().flat_map(|q| q.to_array()).collect(),
                    p.indices.iter().flatten().copied().collect(),
                    buf,
                    p.kernel,
                    p.distance_stack,
                    p.builder.clone(),
                    p.max_leaf,
                ));
            }
            let xf: Vec<f32> = s
                .transforms
                .iter()
                .flat_map(|t| t.matrix().into_iter().flatten())
                .collect();
            Ok::<_, String>((meshes, xf))
        })?;
        let mut items = Vec::new();
        for (v, ix, tree, k, ds, b, ml) in meshes {
            let t = (
                crate::arrays::n3_array(py, v)?,
                crate::arrays::n3_array(py, ix)?,
                PyBytes::new(py, &tree),
                k,
                ds,
                b,
                ml,
            );
            items.push(t.into_pyobject(py)?.into_any());
        }
        let restore = py
            .import("arbor._arbor")?
            .getattr("InstanceCaster")?
            .getattr("_restore")?;
        let k = self.mesh_index.len();
        let args = (
            items,
            PyArray1::from_vec(py, xf).reshape([k, 3, 4])?,
            self.mesh_index.to_vec(),
            self.generation(),
        );
        PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds a pickled instance caster (see `__reduce__`).
    #[staticmethod]
    fn _restore(
        py: Python<'_>,
        meshes: Vec<Bound<'_, PyTuple>>,
        transforms: &Bound<'_, PyAny>,
        mesh_index: Vec<u32>,
        generation: u64,
    ) -> PyResult<Self> {
        let xf = transforms_arg(transforms, "transforms")?;
        let mut parts = Vec::new();
        for m in meshes {
            let (v, ix, tree, kernel, ds, builder, max_leaf): (
                Bound<'_, PyAny>,
                Bound<'_, PyAny>,
                Vec<u8>,
                String,
                bool,
                String,
                u32,
            ) = m.extract()?;
            let pv = points("vertices", &v)?;
            let vs = pv.as_vec3()?;
            let pix = crate::arrays::indices(&ix, vs.len())?;
            let ixs = pix.get()?;
            let part = detached(py, || {
                let (tree, _) = bvh::io::read_tree(&tree[..])
                    .map_err(|e| format!("cannot read a pickled tree: {e}"))?;
                let k = crate::raycaster::kernel_name(&tree, Some(&kernel))?;
                let s = RayCaster::prepare(vs.to_vec(), ixs.to_vec(), tree, k, ds)?;
                Ok::<_, String>(Part {
                    vertices: s.vertices,
                    indices: s.indices,
                    triangles: s.triangles,
                    tree: s.tree,
                    accel: s.accel,
                    kernel: k,
                    distance_stack: ds,
                    builder,
                    max_leaf,
                })
            })?;
            parts.push(part);
        }
        if mesh_index.iter().any(|&m| m as usize >= parts.len()) {
            return Err(err("pickled instance caster: a mesh index out of range"));
        }
        let state = detached(py, || assemble(parts, &mesh_index, xf))?;
        Ok(Self::wrap(state, mesh_index, generation))
    }

    fn __repr__(&self) -> String {
        format!(
            "InstanceCaster({} instances of {} meshes, generation {})",
            self.mesh_index.len(),
            self.vertex_counts.len(),
            self.generation()
        )
    }
}

/// Registers the instance caster.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<InstanceCaster>()?;
    m.add_class::<InstanceHits>()?;
    Ok(())
}
