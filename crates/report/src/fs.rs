//! Atomic file writes of user files (reports, SVG, CSV, JSON, HTML): the workspace's one
//! writer, [`outfile`], with errors as `anyhow` errors that name the file. A temporary file
//! in the target's folder is written, synced and renamed over the target, with an ordinary
//! file's permissions (0666 less the umask: 0644 with umask 022, not `tempfile`'s 0600).

use anyhow::Context;
use std::path::Path;

pub use outfile::{temp_file_beside, write_with};

/// Writes `bytes` to `path` atomically; an existing file is replaced whole or kept whole.
pub fn write_atomic(path: &Path, bytes: impl AsRef<[u8]>) -> anyhow::Result<()> {
    outfile::write_with(
        path,
        |w| Ok(w.write_all(bytes.as_ref())?),
        anyhow::Error::new,
    )
    .with_context(|| format!("cannot write {}", path.display()))
}

/// Writes `text` to `dir/name` atomically (see [`write_atomic`]).
pub fn write_file(dir: &Path, name: &str, text: &str) -> anyhow::Result<()> {
    write_atomic(&dir.join(name), text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_replace_whole_and_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        write_file(dir.path(), "x.csv", "a\n").unwrap();
        write_file(dir.path(), "x.csv", "b\n").unwrap();
        let p = dir.path().join("x.csv");
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "b\n");
        // Only the file itself is left (no temporary files).
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let e = write_file(&dir.path().join("missing"), "x.csv", "").unwrap_err();
        assert!(format!("{e:#}").contains("cannot write"), "{e:#}");
        assert!(format!("{e:#}").contains("missing"), "{e:#}");
        // A folder as the target fails and leaves nothing behind.
        assert!(write_atomic(dir.path(), "x").is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "b\n");
    }

    #[cfg(unix)]
    #[test]
    fn reports_are_readable_by_others() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let plain = dir.path().join("plain");
        std::fs::File::create(&plain).unwrap();
        let ordinary = std::fs::metadata(&plain).unwrap().permissions().mode() & 0o777;
        write_file(dir.path(), "index.html", "<p>").unwrap();
        let m = std::fs::metadata(dir.path().join("index.html")).unwrap();
        assert_eq!(m.permissions().mode() & 0o777, ordinary);
    }
}
