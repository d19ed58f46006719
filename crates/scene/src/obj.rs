//! obj loader (in progress).

use crate::{LoadOptions, LoadedMesh, SceneError};
use std::path::Path;

/// Loads a obj file.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<LoadedMesh, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    parse(&bytes, path, opts)
}

/// Parses obj file contents; `path` only names the file in errors.
pub fn parse(_bytes: &[u8], path: &Path, _opts: &LoadOptions) -> Result<LoadedMesh, SceneError> {
    Err(SceneError::unsupported(
        path,
        "obj loader not yet implemented",
    ))
}
