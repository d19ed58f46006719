//! numpy in and out: array-likes checked and converted to the library's slices (without a
//! copy when the input already is a contiguous, aligned array of the right dtype), and
//! `Vec`s moved into numpy arrays (the `Vec`'s buffer becomes the array's memory).

use crate::ArborError;
use geom::{Aabb, Vec3};
use numpy::{
    PyArray1, PyArray2, PyArrayDescrMethods, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

// `Vec3` is `#[repr(C)] { x, y, z: f32 }` (glam): three packed floats, so a contiguous
// `(N, 3)` float32 array is a `[Vec3]` and a `Vec<Vec3>` is a `Vec<f32>` of 3N floats.
const _: () = assert!(std::mem::size_of::<Vec3>() == 12 && std::mem::align_of::<Vec3>() == 4);
const _: () = assert!(std::mem::size_of::<[u32; 3]>() == 12);

/// An `ArborError` with `msg`.
pub(crate) fn err(msg: impl Into<String>) -> PyErr {
    ArborError::new_err(msg.into())
}

/// `shape` as Python prints it: `(5,)`, `(4, 2)`.
pub(crate) fn shape_str(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// `numpy.asarray(obj)` as an ndarray, or an `ArborError` naming `what`.
fn as_ndarray<'py>(what: &str, obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyUntypedArray>> {
    let np = obj.py().import("numpy")?;
    let a = np
        .call_method1("asarray", (obj,))
        .map_err(|e| err(format!("{what}: cannot convert to an array: {e}")))?;
    a.cast_into::<PyUntypedArray>()
        .map_err(|_| err(format!("{what}: cannot convert to an array")))
}

/// `numpy.require(a, dtype, ["C", "A"])`: `a` itself when it already is C-contiguous,
/// aligned and of `dtype`, else a converted copy.
fn require<'py>(
    what: &str,
    a: &Bound<'py, PyUntypedArray>,
    dtype: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let py = a.py();
    let np = py.import("numpy")?;
    let kw = PyDict::new(py);
    kw.set_item("dtype", dtype)?;
    kw.set_item("requirements", PyList::new(py, ["C", "A"])?)?;
    np.call_method("require", (a,), Some(&kw))
        .map_err(|e| err(format!("{what}: cannot convert to {dtype}: {e}")))
}

/// The dtype kind character of `a` (`f`, `i`, `u`, `b`, `O`, ...).
fn kind(a: &Bound<'_, PyUntypedArray>) -> char {
    a.dtype().kind() as char
}

/// Checks that `a` is `(N, 3)` with a numeric dtype (`allowed` kinds).
fn check_n3(what: &str, a: &Bound<'_, PyUntypedArray>, allowed: &str) -> PyResult<usize> {
    let shape = a.shape();
    if shape.len() != 2 || shape[1] != 3 {
        return Err(err(format!(
            "{what} must have shape (N, 3), got {}",
            shape_str(shape)
        )));
    }
    let k = kind(a);
    if shape[0] > 0 && !allowed.contains(k) {
        return Err(err(format!(
            "{what} must be numbers ({}), got dtype {}",
            if allowed.contains('f') {
                "floats or integers"
            } else {
                "integers"
            },
            a.dtype().str()?
        )));
    }
    Ok(shape[0])
}

/// A checked `(N, 3)` float32 array: vertices, ray origins or directions.
pub(crate) struct Points<'py>(PyReadonlyArray2<'py, f32>);

impl Points<'_> {
    /// The points as `Vec3`s (a view of the array's memory).
    pub(crate) fn as_vec3(&self) -> PyResult<&[Vec3]> {
        let s = self
            .0
            .as_slice()
            .map_err(|_| err("internal error: array not contiguous"))?;
        if !(s.as_ptr() as usize).is_multiple_of(std::mem::align_of::<Vec3>()) {
            return Err(err("internal error: array not aligned"));
        }
        // SAFETY: `s` is 3N contiguous, 4-aligned f32s (checked above; `require` asked
        // numpy for C order and alignment), and `Vec3` is three f32s with no padding
        // (asserted at the top of this file). The borrow keeps the array alive and locked
        // against writes from Rust for the returned lifetime.
        Ok(unsafe { std::slice::from_raw_parts(s.as_ptr().cast::<Vec3>(), s.len() / 3) })
    }
}

/// Converts `obj` to `(N, 3)` float32 points; `what` names it in errors.
pub(crate) fn points<'py>(what: &str, obj: &Bound<'py, PyAny>) -> PyResult<Points<'py>> {
    // Fast path, no call into numpy: already a C-contiguous, aligned float32 (N, 3) array.
    if let Ok(a) = obj.cast::<PyArray2<f32>>() {
        if a.shape()[1] == 3
            && a.is_c_contiguous()
            && (a.data() as usize).is_multiple_of(std::mem::align_of::<f32>())
        {
            return Ok(Points(a.readonly()));
        }
    }
    let a = as_ndarray(what, obj)?;
    check_n3(what, &a, "fiu")?;
    let a = require(what, &a, "float32")?;
    let a = a
        .cast_into::<PyArray2<f32>>()
        .map_err(|_| err(format!("{what}: not a float32 array")))?;
    Ok(Points(a.readonly()))
}

/// Triangle vertex indices: a view of a uint32 array, or converted from another integer
/// dtype.
pub(crate) enum Indices<'py> {
    /// A contiguous uint32 `(M, 3)` array.
    View(PyReadonlyArray2<'py, u32>),
    /// Converted (and range-checked) from another integer dtype.
    Owned(Vec<[u32; 3]>),
}

impl Indices<'_> {
    /// The triangles.
    pub(crate) fn get(&self) -> PyResult<&[[u32; 3]]> {
        match self {
            Indices::Owned(v) => Ok(v),
            Indices::View(a) => {
                let s = a
                    .as_slice()
                    .map_err(|_| err("internal error: array not contiguous"))?;
                if !(s.as_ptr() as usize).is_multiple_of(4) {
                    return Err(err("internal error: array not aligned"));
                }
                // SAFETY: 3M contiguous, aligned u32s; `[u32; 3]` is three u32s.
                Ok(unsafe {
                    std::slice::from_raw_parts(s.as_ptr().cast::<[u32; 3]>(), s.len() / 3)
                })
            }
        }
    }
}

/// Wide integer indices as `u32` triangles; an index outside `u32` is an error naming it.
fn narrow<T: numpy::Element + Copy + std::fmt::Display>(
    a: &PyReadonlyArray2<'_, T>,
    vertices: usize,
) -> PyResult<Vec<[u32; 3]>>
where
    u32: TryFrom<T>,
{
    let s = a
        .as_slice()
        .map_err(|_| err("internal error: array not contiguous"))?;
    let mut out = Vec::with_capacity(s.len() / 3);
    for (t, tri) in s.chunks_exact(3).enumerate() {
        let mut v = [0u32; 3];
        for k in 0..3 {
            v[k] = u32::try_from(tri[k]).map_err(|_| {
                err(format!(
                    "triangle {t} refers to vertex {}, but there are only {vertices} vertices",
                    tri[k]
                ))
            })?;
        }
        out.push(v);
    }
    Ok(out)
}

/// Converts `obj` to `(M, 3)` vertex indices, each below `vertices`.
pub(crate) fn indices<'py>(obj: &Bound<'py, PyAny>, vertices: usize) -> PyResult<Indices<'py>> {
    let what = "indices";
    let a = as_ndarray(what, obj)?;
    check_n3(what, &a, "iu")?;
    let ix = if a.dtype().is_equiv_to(&numpy::dtype::<u32>(a.py())) {
        let a = require(what, &a, "uint32")?
            .cast_into::<PyArray2<u32>>()
            .map_err(|_| err("indices: not a uint32 array"))?;
        Indices::View(a.readonly())
    } else if kind(&a) == 'u' {
        // Unsigned: read as uint64, so that a huge index is not read back as negative.
        let wide = require(what, &a, "uint64")?
            .cast_into::<PyArray2<u64>>()
            .map_err(|_| err("indices: not a uint64 array"))?;
        Indices::Owned(narrow(&wide.readonly(), vertices)?)
    } else {
        let wide = require(what, &a, "int64")?
            .cast_into::<PyArray2<i64>>()
            .map_err(|_| err("indices: not an int64 array"))?;
        Indices::Owned(narrow(&wide.readonly(), vertices)?)
    };
    if let Some((t, tri)) = ix
        .get()?
        .iter()
        .enumerate()
        .find(|(_, tri)| tri.iter().any(|&v| v as usize >= vertices))
    {
        let v = tri
            .iter()
            .find(|&&v| v as usize >= vertices)
            .copied()
            .unwrap_or(0);
        return Err(err(format!(
            "triangle {t} refers to vertex {v}, but there are only {vertices} vertices"
        )));
    }
    Ok(ix)
}

/// A per-ray float: one value for every ray, or a `(N,)` array.
pub(crate) enum PerRay<'py> {
    /// The same value for all rays.
    Scalar(f32),
    /// One value per ray.
    Array(PyReadonlyArray1<'py, f32>),
}

impl PerRay<'_> {
    /// The value of ray `i` (`i` below the checked length).
    #[inline]
    pub(crate) fn at(s: &Option<&[f32]>, scalar: f32, i: usize) -> f32 {
        match s {
            Some(v) => v[i],
            None => scalar,
        }
    }

    /// The scalar, or the array's values.
    pub(crate) fn parts(&self) -> PyResult<(f32, Option<&[f32]>)> {
        match self {
            PerRay::Scalar(x) => Ok((*x, None)),
            PerRay::Array(a) => Ok((
                0.0,
                Some(
                    a.as_slice()
                        .map_err(|_| err("internal error: array not contiguous"))?,
                ),
            )),
        }
    }
}

/// The index of the first NaN of `s`, if any: a branch-free pass over the whole slice
/// (which the compiler vectorizes) answers for the common case of none; only a slice with
/// a NaN is searched.
fn first_nan(s: &[f32]) -> Option<usize> {
    if s.iter().fold(false, |a, x| a | x.is_nan()) {
        s.iter().position(|x| x.is_nan())
    } else {
        None
    }
}

/// `obj` (None: `default`) as a number or a `(n,)` array of non-NaN floats.
pub(crate) fn per_ray<'py>(
    what: &str,
    obj: Option<&Bound<'py, PyAny>>,
    default: f32,
    n: usize,
) -> PyResult<PerRay<'py>> {
    let Some(obj) = obj else {
        return Ok(PerRay::Scalar(default));
    };
    if obj.is_none() {
        return Ok(PerRay::Scalar(default));
    }
    // Fast paths, no call into numpy: a Python float, or a contiguous float32 (n,) array.
    if let Ok(x) = obj.cast::<pyo3::types::PyFloat>() {
        let x = x.value() as f32;
        if x.is_nan() {
            return Err(err(format!("{what} is NaN")));
        }
        return Ok(PerRay::Scalar(x));
    }
    if let Ok(a) = obj.cast::<PyArray1<f32>>() {
        if a.len() == n
            && a.is_c_contiguous()
            && (a.data() as usize).is_multiple_of(std::mem::align_of::<f32>())
        {
            let a = a.readonly();
            if let Some(i) = first_nan(
                a.as_slice()
                    .map_err(|_| err("internal error: array not contiguous"))?,
            ) {
                return Err(err(format!("{what}[{i}] is NaN")));
            }
            return Ok(PerRay::Array(a));
        }
    }
    let a = as_ndarray(what, obj)?;
    if a.ndim() == 0 {
        let x: f32 = obj.extract::<f64>().map_err(|_| {
            err(format!(
                "{what} must be a number or an array of {n} numbers"
            ))
        })? as f32;
        if x.is_nan() {
            return Err(err(format!("{what} is NaN")));
        }
        return Ok(PerRay::Scalar(x));
    }
    if a.shape() != [n] {
        return Err(err(format!(
            "{what} must be a number or have shape ({n},), got {}",
            shape_str(a.shape())
        )));
    }
    if n > 0 && !"fiu".contains(kind(&a)) {
        return Err(err(format!(
            "{what} must be numbers, got dtype {}",
            a.dtype().str()?
        )));
    }
    let a = require(what, &a, "float32")?
        .cast_into::<PyArray1<f32>>()
        .map_err(|_| err(format!("{what}: not a float32 array")))?
        .readonly();
    if let Some(i) = first_nan(
        a.as_slice()
            .map_err(|_| err("internal error: array not contiguous"))?,
    ) {
        return Err(err(format!("{what}[{i}] is NaN")));
    }
    Ok(PerRay::Array(a))
}

/// A `Vec<Vec3>` as the `Vec<f32>` of its coordinates, without copying.
pub(crate) fn flatten_vec3(v: Vec<Vec3>) -> Vec<f32> {
    let mut v = std::mem::ManuallyDrop::new(v);
    let (ptr, len, cap) = (v.as_mut_ptr(), v.len(), v.capacity());
    // SAFETY: `Vec3` is three f32s (size 12, align 4, asserted above), so the allocation of
    // `cap` Vec3s is exactly the allocation of `3 cap` f32s with the same alignment, and
    // the first `3 len` f32s are initialized. `v` is not dropped (ManuallyDrop).
    unsafe { Vec::from_raw_parts(ptr.cast::<f32>(), len * 3, cap * 3) }
}

/// A `Vec<[u32; 3]>` as the `Vec<u32>` of its entries, without copying.
pub(crate) fn flatten_u32x3(v: Vec<[u32; 3]>) -> Vec<u32> {
    let mut v = std::mem::ManuallyDrop::new(v);
    let (ptr, len, cap) = (v.as_mut_ptr(), v.len(), v.capacity());
    // SAFETY: as in `flatten_vec3`: `[u32; 3]` is three u32s with align 4.
    unsafe { Vec::from_raw_parts(ptr.cast::<u32>(), len * 3, cap * 3) }
}

/// A flat `Vec` of `3 n` values as an `(n, 3)` array (the `Vec` becomes its memory).
pub(crate) fn n3_array<'py, T: numpy::Element>(
    py: Python<'py>,
    flat: Vec<T>,
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let n = flat.len() / 3;
    PyArray1::from_vec(py, flat).reshape([n, 3])
}

/// A box as a `(2, 3)` float32 array: row 0 the minimum, row 1 the maximum (an empty box
/// is `+inf` over `-inf`).
pub(crate) fn bounds_array<'py>(py: Python<'py>, b: &Aabb) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let v = vec![b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z];
    PyArray1::from_vec(py, v).reshape([2, 3])
}

/// A `(2, 3)` array-like as a box.
pub(crate) fn bounds_from(obj: &Bound<'_, PyAny>) -> PyResult<Aabb> {
    let a = as_ndarray("bounds", obj)?;
    if a.shape() != [2, 3] {
        return Err(err(format!(
            "bounds must have shape (2, 3) (min row, max row), got {}",
            shape_str(a.shape())
        )));
    }
    let a = require("bounds", &a, "float32")?
        .cast_into::<PyArray2<f32>>()
        .map_err(|_| err("bounds: not a float32 array"))?;
    let ro = a.readonly();
    let s = ro
        .as_slice()
        .map_err(|_| err("internal error: array not contiguous"))?;
    Ok(Aabb::new(
        Vec3::new(s[0], s[1], s[2]),
        Vec3::new(s[3], s[4], s[5]),
    ))
}

/// Fails when a triangle uses a vertex with a NaN or infinite coordinate (a box grown
/// over such a vertex would silently ignore the NaN).
pub(crate) fn check_finite(vertices: &[Vec3], indices: &[[u32; 3]]) -> Result<(), String> {
    for (t, tri) in indices.iter().enumerate() {
        for &v in tri {
            if let Some(p) = vertices.get(v as usize) {
                if !p.is_finite() {
                    return Err(format!(
                        "triangle {t} uses vertex {v}, which has a non-finite coordinate: {p}"
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The triangles of `indices` over `vertices`; an index out of range or a non-finite
/// vertex is an error.
pub(crate) fn resolve(
    vertices: &[Vec3],
    indices: &[[u32; 3]],
) -> Result<Vec<geom::Triangle>, String> {
    check_finite(vertices, indices)?;
    gather(vertices, indices)
}

/// The triangles of `indices` over `vertices` whose finiteness was checked before; an
/// index out of range is an error.
pub(crate) fn gather(
    vertices: &[Vec3],
    indices: &[[u32; 3]],
) -> Result<Vec<geom::Triangle>, String> {
    let n = vertices.len();
    let at = |t: usize, v: u32| {
        vertices.get(v as usize).copied().ok_or_else(|| {
            format!("triangle {t} refers to vertex {v}, but there are only {n} vertices")
        })
    };
    indices
        .iter()
        .enumerate()
        .map(|(i, t)| {
            Ok(geom::Triangle::new(
                at(i, t[0])?,
                at(i, t[1])?,
                at(i, t[2])?,
            ))
        })
        .collect()
}
