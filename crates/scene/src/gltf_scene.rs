//! glTF 2.0 scenes (in progress).

use crate::{LoadOptions, Scene, SceneError};
use std::path::Path;

/// Opens a `.gltf` or `.glb` file as an animated scene.
pub fn open(_spec: &str, path: &Path, _opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    Err(SceneError::unsupported(
        path,
        "glTF loader not yet implemented",
    ))
}
