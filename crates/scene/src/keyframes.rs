//! Keyframe sequences (in progress).

use crate::{LoadOptions, Scene, SceneError};
use std::path::Path;

/// Opens the `.obj` / `.ply` files of a directory, in name order, as a keyframe sequence.
pub fn open_dir(
    spec: &str,
    _dir: &Path,
    _opts: &LoadOptions,
) -> Result<Box<dyn Scene>, SceneError> {
    Err(SceneError::spec(
        spec,
        "keyframe sequences not yet implemented",
    ))
}

/// Opens the files matching a glob pattern, in name order, as a keyframe sequence.
pub fn open_glob(spec: &str, _opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    Err(SceneError::spec(
        spec,
        "keyframe sequences not yet implemented",
    ))
}
