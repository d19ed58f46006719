//! Arbor's one atomic file writer, used by every crate that writes a file a user reads
//! (images, depth buffers, traversal logs, tree files, reports, benchmark records, the
//! demo's summary): the content goes to a temporary file in the target's folder, is synced
//! and then renamed over the target, so an existing file is either kept whole or replaced
//! whole, never left half-written; on failure the temporary file is removed.
//!
//! On Unix the temporary file (and so the result) is created with mode 0666 less the
//! umask, the permissions of any file the user creates (0644 with the usual umask 022).
//! `tempfile`'s default, 0600, would make every result private.
//!
//! The crate also holds the one table type of every report, [`table::Table`], with its
//! Markdown, CSV, JSON and aligned-text writers.
//!
//! The crate is a leaf (it depends on `tempfile` and `serde_json` only) so that the lowest
//! crates (`bvh`, `trace`, `sim`) can use it as well as `report` (which re-exports it as
//! `report::fs` and `report::table`) and the command line.

pub mod table;

use std::io::{self, Write};
use std::path::Path;

/// A new temporary file in the folder of `path` (the current folder for a bare file name),
/// named `prefix...tmp`, to be renamed over `path` once written (see the crate doc for its
/// permissions).
pub fn temp_file_beside(path: &Path, prefix: &str) -> io::Result<tempfile::NamedTempFile> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut b = tempfile::Builder::new();
    b.prefix(prefix).suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o666));
    }
    b.tempfile_in(dir)
}

/// Writes `path` atomically: `fill` writes the content (through a buffer) to a temporary
/// file beside `path`, which is synced and renamed over `path`. An error of `fill` is
/// returned as is; an I/O error of the writer itself goes through `io_err`. On any error
/// `path` is untouched and the temporary file is removed.
pub fn write_with<E>(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> Result<(), E>,
    io_err: impl Fn(io::Error) -> E,
) -> Result<(), E> {
    let tmp = temp_file_beside(path, ".arbor-").map_err(&io_err)?;
    let mut w = io::BufWriter::new(tmp);
    fill(&mut w)?;
    let tmp = w.into_inner().map_err(|e| io_err(e.into_error()))?;
    tmp.as_file().sync_all().map_err(&io_err)?;
    tmp.persist(path).map_err(|e| io_err(e.error))?;
    Ok(())
}

/// Writes `bytes` to `path` atomically (see [`write_with`]); an error names the path.
pub fn write(path: &Path, bytes: impl AsRef<[u8]>) -> io::Result<()> {
    write_with(
        path,
        |w| w.write_all(bytes.as_ref()),
        |e| io::Error::new(e.kind(), format!("cannot write {}: {e}", path.display())),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn success_replaces_the_file_and_leaves_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.csv");
        write(&p, "a\n").unwrap();
        write(&p, "b\n").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "b\n");
        assert_eq!(names(dir.path()), ["x.csv"]);
    }

    #[test]
    fn failure_keeps_the_old_file_and_removes_the_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.png");
        write(&p, "old").unwrap();
        let r: Result<(), String> = write_with(
            &p,
            |w| {
                w.write_all(b"half of the new").map_err(|e| e.to_string())?;
                Err("the encoder failed".to_string())
            },
            |e| e.to_string(),
        );
        assert_eq!(r.unwrap_err(), "the encoder failed");
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "old");
        assert_eq!(names(dir.path()), ["x.png"]);
        // A missing folder or a folder as the target is an error naming the path.
        let e = write(&dir.path().join("missing").join("x"), "x").unwrap_err();
        assert!(e.to_string().contains("missing"), "{e}");
        assert!(write(dir.path(), "x").is_err());
        assert_eq!(names(dir.path()), ["x.png"]);
    }

    #[cfg(unix)]
    #[test]
    fn results_get_an_ordinary_files_permissions() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        // The mode the user's umask gives a new file (0644 with umask 022).
        let plain = dir.path().join("plain");
        std::fs::File::create(&plain).unwrap();
        let ordinary = std::fs::metadata(&plain).unwrap().permissions().mode() & 0o777;
        let p = dir.path().join("render.png");
        write(&p, "x").unwrap();
        let mode = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, ordinary);
        // With the usual umask, 0644, not tempfile's private default (0600).
        if ordinary == 0o644 {
            assert_eq!(mode, 0o644);
        }
    }
}
