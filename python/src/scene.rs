//! Scenes: `Scene` (any spec `scene::open` takes), `Mesh` (one sampled time as numpy
//! arrays) and `Camera` (the pinhole camera of a scene or of a render).

use crate::arrays::{bounds_array, bounds_from, err, flatten_u32x3, flatten_vec3, n3_array};
use crate::detached;
use geom::{Aabb, Vec3};
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use std::sync::OnceLock;

/// A pinhole camera: eye, target, up and vertical field of view in degrees.
#[pyclass(module = "arbor._arbor", frozen)]
#[derive(Clone, Copy)]
pub struct Camera {
    pub(crate) inner: scene::Camera,
}

fn tuple(v: Vec3) -> (f32, f32, f32) {
    (v.x, v.y, v.z)
}

#[pymethods]
impl Camera {
    #[new]
    #[pyo3(signature = (eye, target, up = [0.0, 1.0, 0.0], vfov_deg = 45.0))]
    fn new(eye: [f32; 3], target: [f32; 3], up: [f32; 3], vfov_deg: f32) -> Self {
        Camera {
            inner: scene::Camera {
                eye: Vec3::from(eye),
                target: Vec3::from(target),
                up: Vec3::from(up),
                vfov_deg,
            },
        }
    }

    /// The camera that frames `bounds` (a (2, 3) array: min row, max row), as every scene's
    /// default camera does.
    #[staticmethod]
    fn framing(bounds: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(Camera {
            inner: scene::Camera::framing(&bounds_from(bounds)?),
        })
    }

    #[getter]
    fn eye(&self) -> (f32, f32, f32) {
        tuple(self.inner.eye)
    }

    #[getter]
    fn target(&self) -> (f32, f32, f32) {
        tuple(self.inner.target)
    }

    #[getter]
    fn up(&self) -> (f32, f32, f32) {
        tuple(self.inner.up)
    }

    #[getter]
    fn vfov_deg(&self) -> f32 {
        self.inner.vfov_deg
    }

    /// Pickling: the constructor's arguments.
    #[allow(clippy::type_complexity)]
    fn __getnewargs__(&self) -> ([f32; 3], [f32; 3], [f32; 3], f32) {
        let c = &self.inner;
        (
            c.eye.to_array(),
            c.target.to_array(),
            c.up.to_array(),
            c.vfov_deg,
        )
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "Camera(eye={:?}, target={:?}, up={:?}, vfov_deg={})",
            tuple(c.eye),
            tuple(c.target),
            tuple(c.up),
            c.vfov_deg
        )
    }
}

/// A triangle mesh at one time: vertices, indices, material ids and bounds.
#[pyclass(module = "arbor._arbor", frozen)]
pub struct Mesh {
    #[pyo3(get)]
    vertices: Py<PyArray2<f32>>,
    #[pyo3(get)]
    indices: Py<PyArray2<u32>>,
    #[pyo3(get)]
    material_ids: Py<PyArray1<u32>>,
    #[pyo3(get)]
    material_names: Vec<String>,
    #[pyo3(get)]
    time: f32,
    box_: Aabb,
    triangles: usize,
}

impl Mesh {
    /// Moves a sampled mesh into numpy arrays (no copy of the vertex or index buffers).
    fn from_mesh(py: Python<'_>, m: scene::Mesh, time: f32) -> PyResult<Self> {
        let box_ = m.bounds();
        let triangles = m.triangle_count();
        let scene::Mesh {
            positions,
            triangles: tris,
            material_ids,
            material_names,
        } = m;
        Ok(Mesh {
            vertices: n3_array(py, flatten_vec3(positions))?.unbind(),
            indices: n3_array(py, flatten_u32x3(tris))?.unbind(),
            material_ids: PyArray1::from_vec(py, material_ids).unbind(),
            material_names,
            time,
            box_,
            triangles,
        })
    }
}

#[pymethods]
impl Mesh {
    /// Bounds of the referenced vertices as a (2, 3) float32 array (min row, max row).
    #[getter]
    fn bounds<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        bounds_array(py, &self.box_)
    }

    #[getter]
    fn triangle_count(&self) -> usize {
        self.triangles
    }

    #[getter]
    fn vertex_count(&self, py: Python<'_>) -> usize {
        use numpy::PyUntypedArrayMethods;
        self.vertices.bind(py).shape()[0]
    }

    fn __len__(&self) -> usize {
        self.triangles
    }

    /// Pickling: the arrays, material names, time and bounds.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
        let restore = py
            .import("arbor._arbor")?
            .getattr("Mesh")?
            .getattr("_restore")?;
        let args = (
            self.vertices.bind(py).clone(),
            self.indices.bind(py).clone(),
            self.material_ids.bind(py).clone(),
            self.material_names.clone(),
            self.time,
            self.bounds(py)?,
            self.triangles,
        );
        pyo3::types::PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds a pickled mesh (see `__reduce__`).
    #[staticmethod]
    fn _restore(
        vertices: Bound<'_, PyArray2<f32>>,
        indices: Bound<'_, PyArray2<u32>>,
        material_ids: Bound<'_, PyArray1<u32>>,
        material_names: Vec<String>,
        time: f32,
        bounds: &Bound<'_, PyAny>,
        triangles: usize,
    ) -> PyResult<Self> {
        Ok(Mesh {
            vertices: vertices.unbind(),
            indices: indices.unbind(),
            material_ids: material_ids.unbind(),
            material_names,
            time,
            box_: bounds_from(bounds)?,
            triangles,
        })
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Mesh({} triangles, {} vertices, t = {} s)",
            self.triangles,
            self.vertex_count(py),
            self.time
        )
    }
}

/// An opened scene: a function of time that gives meshes, plus a default camera.
#[pyclass(module = "arbor._arbor", frozen)]
pub struct Scene {
    inner: Box<dyn scene::Scene>,
    triangles: OnceLock<usize>,
}

impl Scene {
    /// The time `time` / `frame` select: the command line's `--time` / `--frame`
    /// (`arbor::cmd::resolve_time`, the one place they are interpreted), with the Python
    /// argument names in its errors. A time outside the timeline is an error, as there.
    fn resolve_time(&self, time: Option<f64>, frame: Option<i64>) -> PyResult<f32> {
        if time.is_some() && frame.is_some() {
            return Err(err("give time or frame, not both"));
        }
        let frame = match frame {
            Some(f) => Some(u32::try_from(f).map_err(|_| {
                err(format!(
                    "frame {f} is out of range: the scene has {} frame(s)",
                    self.inner.info().timeline.frame_count()
                ))
            })?),
            None => None,
        };
        if let Some(t) = time {
            // An f64 beyond f32's range would become infinite, not out of range.
            if t.is_finite() && t.abs() > f32::MAX as f64 {
                return Err(err(format!("time {t} is out of range")));
            }
        }
        arbor::cmd::resolve_time(self.inner.info(), time.map(|t| t as f32), frame).map_err(|e| {
            err(e
                .to_string()
                .replace("--time", "time")
                .replace("--frame", "frame"))
        })
    }
}

#[pymethods]
impl Scene {
    #[new]
    #[pyo3(signature = (spec, *, fps = None, animation = None))]
    fn new(
        py: Python<'_>,
        spec: String,
        fps: Option<f32>,
        animation: Option<String>,
    ) -> PyResult<Self> {
        if let Some(f) = fps {
            if !(f.is_finite() && f > 0.0) {
                return Err(err(format!("fps must be a positive number, got {f}")));
            }
        }
        let opts = scene::LoadOptions {
            progress: None,
            fps,
            animation,
        };
        let inner = detached(py, || {
            scene::open(&spec, &opts).map_err(|e| format!("cannot open scene: {e}"))
        })?;
        Ok(Scene {
            inner,
            triangles: OnceLock::new(),
        })
    }

    /// The mesh at `time` seconds or of frame `frame` (outside the timeline: an error);
    /// time 0 when neither is given.
    #[pyo3(signature = (time = None, frame = None))]
    fn mesh(&self, py: Python<'_>, time: Option<f64>, frame: Option<i64>) -> PyResult<Mesh> {
        let t = self.resolve_time(time, frame)?;
        let scene = &self.inner;
        let m = detached(py, || {
            scene
                .mesh_at(t)
                .map_err(|e| format!("cannot sample the scene at t = {t} s: {e}"))
        })?;
        Mesh::from_mesh(py, m, t)
    }

    /// Time in seconds of frame `frame`.
    fn time_of_frame(&self, frame: i64) -> PyResult<f32> {
        self.resolve_time(None, Some(frame))
    }

    #[getter]
    fn name(&self) -> String {
        self.inner.info().name.clone()
    }

    #[getter]
    fn spec(&self) -> String {
        self.inner.info().source.clone()
    }

    #[getter]
    fn format(&self) -> String {
        self.inner.info().format.clone()
    }

    #[getter]
    fn frame_count(&self) -> u32 {
        self.inner.info().timeline.frame_count()
    }

    #[getter]
    fn duration(&self) -> f32 {
        self.inner.info().timeline.duration_s
    }

    #[getter]
    fn fps(&self) -> f32 {
        self.inner.info().timeline.fps
    }

    #[getter]
    fn stable_topology(&self) -> bool {
        self.inner.info().stable_topology
    }

    #[getter]
    fn dropped_triangles(&self) -> usize {
        self.inner.info().dropped_triangles
    }

    #[getter]
    fn camera(&self) -> Camera {
        Camera {
            inner: self.inner.info().camera,
        }
    }

    /// Triangles at time 0 (sampled once, on first use).
    #[getter]
    fn triangle_count(&self, py: Python<'_>) -> PyResult<usize> {
        if let Some(n) = self.triangles.get() {
            return Ok(*n);
        }
        let scene = &self.inner;
        let n = detached(py, || {
            scene
                .mesh_at(0.0)
                .map(|m| m.triangle_count())
                .map_err(|e| format!("cannot sample the scene at t = 0 s: {e}"))
        })?;
        Ok(*self.triangles.get_or_init(|| n))
    }

    fn __repr__(&self) -> String {
        let i = self.inner.info();
        format!(
            "Scene({:?}, format={:?}, frames={}, duration={} s)",
            i.source,
            i.format,
            i.timeline.frame_count(),
            i.timeline.duration_s
        )
    }
}

/// Registers the scene classes.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Camera>()?;
    m.add_class::<Mesh>()?;
    m.add_class::<Scene>()?;
    Ok(())
}
