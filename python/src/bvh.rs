//! `Bvh`: a tree of either width (`bvh::Tree`) built with any builder of `arbor build`
//! (`arbor::cmd::build::BUILDERS`, the same names and options), refitted, inspected as
//! structured numpy arrays, validated and saved to / loaded from tree files (`bvh::io`).

use crate::arrays::{bounds_array, err, indices, points};
use crate::detached;
use crate::raycaster::count_arg;
use arbor::cmd::build::{self as cli, BuildConfig};
use bvh::{SahParams, Tree};
use geom::{Aabb, Vec3};
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

/// Triangle vertex indices.
pub(crate) type Triangles = Vec<[u32; 3]>;

/// A built tree, with the triangle indices and primitive boxes it was last built or
/// refitted over (absent for a tree loaded from a file).
///
/// Threads share one `Bvh`: its state is an immutable snapshot behind a lock that is held
/// only to copy or swap the pointer. Readers work on the snapshot they took (with the
/// interpreter released); `refit` refits a copy and swaps it in. Nothing waits on the
/// lock for longer than a pointer copy, so there is no `Already borrowed` and no deadlock
/// with the interpreter lock.
#[pyclass(module = "arbor._arbor", frozen)]
pub struct Bvh {
    state: RwLock<Arc<BvhState>>,
    pub(crate) builder: String,
    pub(crate) max_leaf: u32,
}

/// What a `Bvh` holds at one moment.
pub(crate) struct BvhState {
    pub(crate) tree: Tree,
    pub(crate) indices: Option<Vec<[u32; 3]>>,
    pub(crate) prims: Option<Vec<Aabb>>,
}

/// Primitive boxes of triangles, with the command line's error context.
pub(crate) fn aabbs(v: &[Vec3], ix: &[[u32; 3]]) -> Result<Vec<Aabb>, String> {
    crate::arrays::check_finite(v, ix)?;
    bvh::indexed_triangle_aabbs(v, ix).map_err(|e| format!("cannot compute triangle bounds: {e}"))
}

/// How `Bvh.build` spells the options in messages.
const PY_NAMES: cli::OptionNames = cli::OptionNames {
    builder: "builder",
    threads: "threads",
    max_leaf: "max_leaf",
    collapse_from: "collapse_from",
    bins: "bins",
};

/// The build configuration of `arbor build`'s options, checked by its own rules
/// (`cmd::build::build_config`), the messages naming the Python arguments.
pub(crate) fn config(
    builder: &str,
    max_leaf: Option<u32>,
    bins: Option<usize>,
    collapse_from: Option<&str>,
    threads: Option<usize>,
) -> Result<(cli::BuildFn, BuildConfig), String> {
    cli::build_config(&PY_NAMES, builder, threads, max_leaf, collapse_from, bins)
        .map_err(|e| arbor::one_line(&e))
}

/// Runs `f` in a pool of `threads` workers, or in the global pool.
pub(crate) fn in_pool<T: Send>(
    threads: Option<usize>,
    f: impl FnOnce() -> Result<T, String> + Send,
) -> Result<T, String> {
    match threads {
        None => f(),
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| format!("cannot create the worker thread pool: {e}"))?
            .install(f),
    }
}

/// Little-endian bytes of the nodes, exactly their in-memory (and tree file) layout.
fn node_bytes(tree: &Tree) -> Vec<u8> {
    let mut out = Vec::with_capacity(tree.node_count() * tree.kind().node_bytes());
    match tree {
        Tree::Bvh2(t) => {
            for n in &t.nodes {
                for x in n.bounds.iter().flatten() {
                    out.extend_from_slice(&x.to_le_bytes());
                }
                for c in &n.children {
                    out.extend_from_slice(&c.index.to_le_bytes());
                    out.extend_from_slice(&c.count.to_le_bytes());
                }
            }
        }
        Tree::Mbvh4(t) => {
            for n in &t.nodes {
                for row in [n.min_x, n.min_y, n.min_z, n.max_x, n.max_y, n.max_z] {
                    for x in row {
                        out.extend_from_slice(&x.to_le_bytes());
                    }
                }
                for c in &n.children {
                    out.extend_from_slice(&c.index.to_le_bytes());
                    out.extend_from_slice(&c.count.to_le_bytes());
                }
            }
        }
    }
    out
}

/// The numpy dtype of one node of `kind` (see `_arbor.pyi`).
fn node_dtype<'py>(py: Python<'py>, kind: bvh::TreeKind) -> PyResult<Bound<'py, PyAny>> {
    let dtype = py.import("numpy")?.getattr("dtype")?;
    let child = dtype.call1((vec![("index", "<u4"), ("count", "<u4")],))?;
    let field =
        |name: &str, ty: Bound<'py, PyAny>, shape: Vec<usize>| -> PyResult<Bound<'py, PyAny>> {
            Ok(PyTuple::new(
                py,
                [
                    name.into_pyobject(py)?.into_any(),
                    ty,
                    PyTuple::new(py, shape)?.into_any(),
                ],
            )?
            .into_any())
        };
    let f4 = || "<f4".into_pyobject(py).map(|s| s.into_any());
    let fields = match kind {
        bvh::TreeKind::Bvh2 => vec![
            field("bounds", f4()?, vec![2, 2, 3])?,
            field("children", child, vec![2])?,
        ],
        bvh::TreeKind::Mbvh4 => {
            let mut v = Vec::new();
            for n in ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z"] {
                v.push(field(n, f4()?, vec![4])?);
            }
            v.push(field("children", child, vec![4])?);
            v
        }
    };
    dtype.call1((PyList::new(py, fields)?,))
}

impl Bvh {
    /// Wraps a tree with the triangles it was built over, if known.
    pub(crate) fn new(
        tree: Tree,
        builder: String,
        max_leaf: u32,
        indices: Option<Vec<[u32; 3]>>,
        prims: Option<Vec<Aabb>>,
    ) -> Self {
        Bvh {
            state: RwLock::new(Arc::new(BvhState {
                tree,
                indices,
                prims,
            })),
            builder,
            max_leaf,
        }
    }

    /// The current state (a pointer copy; see the type's comment).
    pub(crate) fn snapshot(&self) -> Arc<BvhState> {
        // The lock guards a pointer copy or swap, which cannot panic: never poisoned in
        // a way that matters.
        self.state.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Primitive boxes from `vertices` (and `indices`, else the stored ones), or the stored
    /// boxes when neither is given.
    pub(crate) fn prims_for(
        &self,
        py: Python<'_>,
        vertices: Option<&Bound<'_, PyAny>>,
        ix: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<(Vec<Aabb>, Option<Triangles>)> {
        match (vertices, ix) {
            (None, None) => match &self.snapshot().prims {
                Some(p) => Ok((p.clone(), None)),
                None => Err(err(
                    "this tree was loaded from a file: pass the vertices and indices it was built over",
                )),
            },
            (None, Some(_)) => Err(err("indices given without vertices")),
            (Some(v), ix) => {
                let v = points("vertices", v)?;
                let vs = v.as_vec3()?;
                match ix {
                    Some(ix) => {
                        let ix = indices(ix, vs.len())?;
                        let ixs = ix.get()?;
                        let p = detached(py, || aabbs(vs, ixs))?;
                        Ok((p, Some(ixs.to_vec())))
                    }
                    None => {
                        let snap = self.snapshot();
                        let Some(stored) = &snap.indices else {
                            return Err(err(
                                "this tree was loaded from a file: pass the indices it was built over",
                            ));
                        };
                        let p = detached(py, || aabbs(vs, stored))?;
                        Ok((p, None))
                    }
                }
            }
        }
    }
}

#[pymethods]
impl Bvh {
    /// Builds a tree over triangles with a builder of `arbor build`.
    #[staticmethod]
    #[pyo3(signature = (vertices, indices, builder = "binned-sah", *, max_leaf = None, bins = None, collapse_from = None, threads = None))]
    #[allow(clippy::too_many_arguments)]
    fn build(
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        indices: &Bound<'_, PyAny>,
        builder: &str,
        max_leaf: Option<i64>,
        bins: Option<i64>,
        collapse_from: Option<String>,
        threads: Option<i64>,
    ) -> PyResult<Self> {
        let max_leaf = count_arg::<u32>("max_leaf", max_leaf)?;
        let bins = count_arg::<usize>("bins", bins)?;
        let threads = count_arg::<usize>("threads", threads)?;
        let (f, cfg) =
            config(builder, max_leaf, bins, collapse_from.as_deref(), threads).map_err(err)?;
        let v = points("vertices", vertices)?;
        let vs = v.as_vec3()?;
        let ix = crate::arrays::indices(indices, vs.len())?;
        let ixs = ix.get()?;
        let max_leaf = cfg.max_leaf;
        let (tree, prims) = detached(py, || {
            let prims = aabbs(vs, ixs)?;
            let tree = in_pool(threads, || {
                f(&prims, &cfg)
                    .map_err(|e| format!("builder {builder} failed: {}", arbor::one_line(&e)))
            })?;
            Ok::<_, String>((tree, prims))
        })?;
        Ok(Bvh::new(
            tree,
            builder.to_string(),
            max_leaf,
            Some(ixs.to_vec()),
            Some(prims),
        ))
    }

    /// Reads a tree file (the format of `arbor build --out`, `bvh::io`).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (tree, header) = detached(py, || {
            bvh::io::read_tree_file(&path)
                .map_err(|e| format!("cannot read tree file {}: {e}", path.display()))
        })?;
        let max_leaf = tree.stats().max_leaf_size.max(1);
        Ok(Bvh::new(tree, header.builder, max_leaf, None, None))
    }

    /// Writes the tree file atomically.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let snap = self.snapshot();
        let (tree, builder) = (&snap.tree, &self.builder);
        detached(py, || {
            bvh::io::write_tree_file(tree, builder, &path)
                .map_err(|e| format!("cannot write tree file {}: {e}", path.display()))
        })
    }

    /// Refits the boxes to moved vertices (same triangles; `indices` default to the ones
    /// the tree was built over). Refits a copy and swaps it in, so that threads tracing
    /// the tree meanwhile keep a consistent one.
    #[pyo3(signature = (vertices, indices = None))]
    fn refit(
        &self,
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        indices: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let (prims, ix) = self.prims_for(py, Some(vertices), indices)?;
        let old = self.snapshot();
        let state = detached(py, || {
            let mut tree = old.tree.clone();
            tree.refit(&prims)
                .map_err(|e| format!("cannot refit the tree: {e}"))?;
            Ok::<_, String>(BvhState {
                tree,
                indices: ix.or_else(|| old.indices.clone()),
                prims: Some(prims),
            })
        })?;
        *self.state.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(state);
        Ok(())
    }

    /// Checks every invariant of the tree over the triangles (default: those it was last
    /// built or refitted over) with leaves of at most `max_leaf` (default: the build's
    /// limit). Raises ArborError naming the first violation.
    #[pyo3(signature = (vertices = None, indices = None, *, max_leaf = None))]
    fn validate(
        &self,
        py: Python<'_>,
        vertices: Option<&Bound<'_, PyAny>>,
        indices: Option<&Bound<'_, PyAny>>,
        max_leaf: Option<u32>,
    ) -> PyResult<()> {
        let (prims, _) = self.prims_for(py, vertices, indices)?;
        let limit = max_leaf.unwrap_or(self.max_leaf);
        let snap = self.snapshot();
        let tree = &snap.tree;
        detached(py, || {
            tree.validate(&prims, limit)
                .map_err(|e| format!("invalid tree: {e}"))
        })
    }

    /// SAH cost normalized by the scene box, in the binary SAH's units (a 4-wide node costs
    /// `2 c_inner`); defaults are the thesis weights of [P2] §6.2.
    #[pyo3(signature = (c_inner = 1.2, c_leaf = 0.0, c_tri = 1.0))]
    fn sah(&self, c_inner: f32, c_leaf: f32, c_tri: f32) -> PyResult<f64> {
        if ![c_inner, c_leaf, c_tri]
            .iter()
            .all(|x| x.is_finite() && *x >= 0.0)
        {
            return Err(err("SAH weights must be finite and not negative"));
        }
        let p = SahParams {
            c_inner,
            c_leaf,
            c_tri,
        };
        Ok(match &self.snapshot().tree {
            Tree::Bvh2(t) => bvh::sah_cost_with(t, &p),
            Tree::Mbvh4(t) => bvh::mbvh4_sah_cost_with(t, &p.for_width(bvh::MBVH_WIDTH)),
        })
    }

    /// The 4-wide tree collapsed from this binary one ([P4], `bvh::collapse`).
    fn collapse(&self, py: Python<'_>) -> PyResult<Self> {
        let snap = self.snapshot();
        let Tree::Bvh2(t) = &snap.tree else {
            return Err(err("the tree is already 4-wide (Mbvh4)"));
        };
        let m = detached(py, || {
            bvh::collapse(t).map_err(|e| format!("cannot collapse the tree to MBVH4: {e}"))
        })?;
        Ok(Bvh::new(
            Tree::Mbvh4(m),
            cli::COLLAPSE.to_string(),
            self.max_leaf,
            snap.indices.clone(),
            snap.prims.clone(),
        ))
    }

    /// The nodes as a structured array (a copy), in their exact memory layout.
    #[getter]
    fn nodes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let snap = self.snapshot();
        let bytes = PyArray1::from_vec(py, node_bytes(&snap.tree));
        bytes.call_method1("view", (node_dtype(py, snap.tree.kind())?,))
    }

    /// The numpy dtype of `nodes`.
    #[getter]
    fn node_dtype<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        node_dtype(py, self.snapshot().tree.kind())
    }

    /// The leaf table: primitive (triangle) indices in leaf order (a copy).
    #[getter]
    fn leaf_order<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        PyArray1::from_slice(py, self.snapshot().tree.prim_indices())
    }

    #[getter]
    fn primitive_indices<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        self.leaf_order(py)
    }

    #[getter]
    fn bounds<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        bounds_array(py, &self.snapshot().tree.bounds())
    }

    #[getter]
    fn kind(&self) -> &'static str {
        self.snapshot().tree.kind().name()
    }

    #[getter]
    fn width(&self) -> usize {
        self.snapshot().tree.kind().width()
    }

    #[getter]
    fn builder(&self) -> String {
        self.builder.clone()
    }

    #[getter]
    fn max_leaf(&self) -> u32 {
        self.max_leaf
    }

    #[getter]
    fn node_count(&self) -> usize {
        self.snapshot().tree.node_count()
    }

    #[getter]
    fn leaf_count(&self) -> usize {
        self.snapshot().tree.stats().leaves
    }

    #[getter]
    fn primitive_count(&self) -> usize {
        self.snapshot().tree.prim_count()
    }

    #[getter]
    fn depth(&self) -> usize {
        self.snapshot().tree.stats().max_depth
    }

    #[getter]
    fn max_leaf_size(&self) -> u32 {
        self.snapshot().tree.stats().max_leaf_size
    }

    #[getter]
    fn mean_children(&self) -> f64 {
        self.snapshot().tree.mean_children()
    }

    #[getter]
    fn node_bytes(&self) -> usize {
        self.snapshot().tree.kind().node_bytes()
    }

    /// Bytes of the nodes plus the leaf table.
    #[getter]
    fn bytes(&self) -> usize {
        self.snapshot().tree.bytes()
    }

    /// Shape statistics as a dict.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let snap = self.snapshot();
        let tree = &snap.tree;
        let s = tree.stats();
        let d = PyDict::new(py);
        d.set_item("kind", self.kind())?;
        d.set_item("width", self.width())?;
        d.set_item("builder", &self.builder)?;
        d.set_item("triangles", tree.prim_count())?;
        d.set_item("inner_nodes", s.inner_nodes)?;
        d.set_item("leaves", s.leaves)?;
        d.set_item("max_leaf_size", s.max_leaf_size)?;
        d.set_item("max_leaf_limit", self.max_leaf)?;
        d.set_item("max_depth", s.max_depth)?;
        d.set_item("mean_children", tree.mean_children())?;
        d.set_item("sah", tree.normalized_sah())?;
        d.set_item("node_bytes", tree.kind().node_bytes())?;
        d.set_item("tree_bytes", tree.bytes())?;
        Ok(d)
    }

    /// Pickling: the tree in the tree-file format, with the triangles and primitive boxes
    /// it was last built or refitted over (when known).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let snap = self.snapshot();
        let builder = &self.builder;
        let bytes = detached(py, || {
            let mut buf = Vec::new();
            bvh::io::write_tree(&snap.tree, builder, &mut buf)
                .map_err(|e| format!("cannot serialize the tree: {e}"))?;
            Ok::<_, String>(buf)
        })?;
        let ix = match &snap.indices {
            Some(v) => Some(crate::arrays::n3_array(
                py,
                v.iter().flatten().copied().collect::<Vec<u32>>(),
            )?),
            None => None,
        };
        let prims = match &snap.prims {
            Some(p) => {
                let flat: Vec<f32> = p
                    .iter()
                    .flat_map(|b| [b.min.to_array(), b.max.to_array()])
                    .flatten()
                    .collect();
                let n = p.len();
                Some(PyArray1::from_vec(py, flat).reshape([n, 6])?)
            }
            None => None,
        };
        let restore = py
            .import("arbor._arbor")?
            .getattr("Bvh")?
            .getattr("_restore")?;
        let args = (PyBytes::new(py, &bytes), self.max_leaf, ix, prims);
        PyTuple::new(py, [restore.into_any(), args.into_pyobject(py)?.into_any()])
    }

    /// Rebuilds a pickled tree (see `__reduce__`).
    #[staticmethod]
    #[pyo3(signature = (tree, max_leaf, indices = None, prims = None))]
    fn _restore(
        py: Python<'_>,
        tree: &[u8],
        max_leaf: u32,
        indices: Option<&Bound<'_, PyAny>>,
        prims: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let (tree, header) = detached(py, || {
            bvh::io::read_tree(tree).map_err(|e| format!("cannot read the pickled tree: {e}"))
        })?;
        let ix = match indices {
            Some(ix) => Some(crate::arrays::indices(ix, usize::MAX)?.get()?.to_vec()),
            None => None,
        };
        let prims = match prims {
            Some(p) => {
                let a = p
                    .cast::<PyArray2<f32>>()
                    .map_err(|_| err("pickled primitive boxes: not a float32 array"))?
                    .readonly();
                let s = a
                    .as_slice()
                    .map_err(|_| err("internal error: array not contiguous"))?;
                Some(
                    s.chunks_exact(6)
                        .map(|b| {
                            Aabb::new(Vec3::new(b[0], b[1], b[2]), Vec3::new(b[3], b[4], b[5]))
                        })
                        .collect(),
                )
            }
            None => None,
        };
        Ok(Bvh::new(tree, header.builder, max_leaf, ix, prims))
    }

    fn __eq__(&self, other: PyRef<'_, Bvh>) -> bool {
        Arc::ptr_eq(&self.snapshot(), &other.snapshot())
            || self.snapshot().tree == other.snapshot().tree
    }

    fn __repr__(&self) -> String {
        let snap = self.snapshot();
        format!(
            "Bvh({}, builder={:?}, {} triangles, {} nodes)",
            self.kind(),
            self.builder,
            snap.tree.prim_count(),
            snap.tree.node_count()
        )
    }
}

/// Names of every builder, in `arbor build`'s order, but those that cut triangles
/// (`sbvh`: its trees name parts of triangles, which this package's arrays, validation
/// and files do not hold yet).
#[pyfunction]
fn builders() -> Vec<&'static str> {
    cli::available_builders()
        .filter(|n| !cli::cuts_triangles(n))
        .collect()
}

/// Registers the BVH class and functions.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Bvh>()?;
    m.add_function(wrap_pyfunction!(builders, m)?)?;
    m.add("DEFAULT_BUILDER", "binned-sah")?;
    Ok(())
}
