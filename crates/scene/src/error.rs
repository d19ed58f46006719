//! The error type of every loader.

use std::path::{Path, PathBuf};

/// Why a scene could not be opened or sampled. Every variant names the file (or spec) and
/// the problem in one line, so the CLI prints it as is.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file's contents are malformed, truncated or hostile.
    #[error("{}: {msg}", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong, with a line number or byte offset where known.
        msg: String,
    },
    /// The file is valid but uses a feature Arbor does not support.
    #[error("{}: unsupported: {msg}", path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The feature.
        msg: String,
    },
    /// A scene spec (path, glob or `proc:` string) could not be understood.
    #[error("scene '{spec}': {msg}")]
    Spec {
        /// The spec as given.
        spec: String,
        /// What is wrong.
        msg: String,
    },
}

impl SceneError {
    /// A [`SceneError::Malformed`] for `path`.
    pub fn malformed(path: &Path, msg: impl Into<String>) -> Self {
        SceneError::Malformed {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// A [`SceneError::Unsupported`] for `path`.
    pub fn unsupported(path: &Path, msg: impl Into<String>) -> Self {
        SceneError::Unsupported {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// A [`SceneError::Io`] for `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        SceneError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// A [`SceneError::Spec`].
    pub fn spec(spec: &str, msg: impl Into<String>) -> Self {
        SceneError::Spec {
            spec: spec.to_string(),
            msg: msg.into(),
        }
    }
}
