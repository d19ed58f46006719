//! Arbor scenes: a scene is a function of time that gives world-space triangles plus a
//! default camera.
//!
//! Sources:
//! - static meshes: Wavefront OBJ ([`obj`]) and PLY, ASCII and binary ([`ply`]);
//! - glTF 2.0 (`.gltf` + `.bin`, `.glb`) with node hierarchies, skins and animations
//!   sampled at any time ([`gltf_scene`]);
//! - keyframe sequences: one mesh per frame with identical topology ([`keyframes`]);
//! - procedural animated scenes, deterministic from a seed and a size ([`procedural`]).
//!
//! [`open`] takes a spec string (a file, a directory of frames, a glob, or
//! `proc:NAME?key=value&...`) and returns the matching [`Scene`].
//!
//! # Non-finite coordinates (the NaN policy)
//!
//! A *static* file (OBJ, PLY) may contain vertices with NaN or infinite coordinates. Vertices
//! that no face references are ignored. A triangle that references such a vertex is
//! **dropped**, and the number dropped is reported in [`SceneInfo::dropped_triangles`] (the
//! `arbor` command prints a warning). Dropping keeps the rest of a large scan usable.
//! In *animated* sources (keyframe sequences, glTF) dropping would change the primitive ids
//! between frames, so there a non-finite position at any sampled time is an **error** naming
//! the file. Degenerate but finite triangles (zero area, collinear, repeated vertices) always
//! load and are counted.

#![warn(missing_docs)]

pub mod camera;
pub mod error;
pub mod gltf_scene;
pub mod keyframes;
pub mod mesh;
pub mod obj;
pub mod ply;
pub mod procedural;
mod source;
pub mod spec;

pub use camera::Camera;
pub use error::SceneError;
pub use mesh::{LoadedMesh, Mesh};
pub use source::{
    open, LoadOptions, ProgressFn, Scene, SceneInfo, StaticScene, Timeline, DEFAULT_FPS,
};
