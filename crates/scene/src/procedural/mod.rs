//! Procedural animated scenes (in progress).

use crate::{spec::ProcSpec, LoadOptions, Scene, SceneError};

/// Opens the procedural scene named by `ps`.
pub fn open(spec: &str, ps: &ProcSpec, _opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    Err(SceneError::spec(
        spec,
        format!("unknown procedural scene '{}'", ps.name),
    ))
}
