//! `arbor._arbor`, the native half of Arbor's Python package (`python/arbor/`).
//!
//! Two layers. [`run_json`] runs any `arbor` command line through the same parser and code
//! as the binary (`arbor::run_capture`), so Python takes the same options and `--set` keys
//! and gets the same `--json` documents (one schema, documented in `docs/cli-json.md`).
//! The typed classes (scenes, BVHs, tracing, CBVHs) wrap the library crates directly and
//! pass geometry as numpy arrays. Long work runs with the interpreter released
//! (`Python::detach`); every error, and any panic, becomes an `arbor.ArborError` carrying
//! the command line's one-line message.

use pyo3::prelude::*;

mod arrays;
mod bvh;
mod cbvh;
mod instances;
mod query;
mod raycaster;
mod scene;
mod trace;

pyo3::create_exception!(
    _arbor,
    ArborError,
    pyo3::exceptions::PyException,
    "An Arbor error: bad input, a bad option or a failed run; the message is the one line \
     the `arbor` command prints."
);

/// The message of a caught panic.
pub(crate) fn panic_message(p: Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic".to_string()
    }
}

/// Runs `f` with the interpreter released, turning an error or a panic into `ArborError`.
pub(crate) fn detached<T: Send, E: std::fmt::Display + Send>(
    py: Python<'_>,
    f: impl FnOnce() -> Result<T, E> + Send,
) -> PyResult<T> {
    let r = py.detach(|| std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)));
    match r {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(ArborError::new_err(e.to_string())),
        Err(p) => Err(ArborError::new_err(format!(
            "internal error (please report): {}",
            panic_message(p)
        ))),
    }
}

/// Runs one `arbor` command line (without the program name) quietly and returns the JSON
/// documents it produced, as a JSON array (text). Raises `ArborError` with the command's
/// one-line message on a bad option or a failure.
#[pyfunction]
fn run_json(py: Python<'_>, args: Vec<String>) -> PyResult<String> {
    let docs = detached(py, || arbor::run_capture(&args))?;
    serde_json::to_string(&docs).map_err(|e| ArborError::new_err(e.to_string()))
}

/// Checks one `arbor` command line without running it (the parser, and for `sim` commands
/// the preset, `--set` keys and values and memory system, with no scene loaded). Raises
/// `ArborError` with the command's one-line message.
#[pyfunction]
fn check_args(py: Python<'_>, args: Vec<String>) -> PyResult<()> {
    detached(py, || arbor::check_args(&args))
}

#[pymodule]
fn _arbor(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("ArborError", m.py().get_type::<ArborError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run_json, m)?)?;
    scene::register(m)?;
    bvh::register(m)?;
    trace::register(m)?;
    cbvh::register(m)?;
    raycaster::register(m)?;
    instances::register(m)?;
    m.add_function(wrap_pyfunction!(check_args, m)?)?;
    Ok(())
}
