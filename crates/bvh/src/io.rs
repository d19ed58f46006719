//! The Arbor tree file: a little-endian binary format for [`Bvh2`] that `arbor build --out`
//! writes and that `arbor render` and the hardware models read back. The nodes are stored in
//! exactly their 64-byte in-memory layout ([`Node`], \[P2\] §4.1 Fig. 2), so a
//! hardware model can map the node section and fetch one node per 64-byte line.
//!
//! Layout (all integers and floats little-endian; `docs/tree-format.md` has the same table):
//!
//! | offset      | size | field                                                         |
//! |-------------|------|---------------------------------------------------------------|
//! | 0           | 8    | magic `ARBORBVH`                                              |
//! | 8           | 4    | format version `u32` (= [`FORMAT_VERSION`])                   |
//! | 12          | 4    | tree kind `u32`: 1 = `Bvh2`; 2 = `Mbvh4` (reserved)           |
//! | 16          | 4    | node count `u32` (>= 1: the root always exists)               |
//! | 20          | 4    | leaf-table length `u32`                                       |
//! | 24          | 4    | primitive count `u32` (= leaf-table length for `Bvh2`)        |
//! | 28          | 4    | builder name length `u32` in bytes (<= [`MAX_BUILDER_NAME_BYTES`]) |
//! | 32          | 24   | scene bounds: min x, y, z, max x, y, z (`f32`)                |
//! | 56          | 8    | SAH cost with the thesis parameters (`f64`, informational)    |
//! | 64          | L    | builder name, UTF-8, then zero bytes up to a multiple of 16   |
//! | H           | 64 N | nodes, each in the 64-byte layout of [`Node`]          |
//! | H + 64 N    | 4 T  | leaf table (`u32` primitive indices)                          |
//! | end - 4     | 4    | CRC-32 (IEEE, as zlib/PNG) of every byte before it            |
//!
//! `H = 64 + L` rounded up to 16, so the node section is 16-byte aligned in the file.
//!
//! Reading trusts nothing: bad magic, an unknown version or kind, counts above the format's
//! limits, non-zero padding, a truncated file, trailing bytes and a checksum mismatch are
//! each a typed [`IoError`]. Arrays grow as their bytes actually arrive (never preallocated
//! from a header count), so a header that claims 2^32 nodes on a 100-byte file costs
//! nothing. A tree that passes the checksum is then validated structurally with
//! [`crate::validate`] (every index in range, preorder, each primitive once, child boxes
//! inside parents), so a reader can walk it without bounds checks going wrong.
//!
//! [`write_bvh2_file`] writes atomically: to a temporary file in the destination's
//! directory, flushed to disk, then renamed over the destination, so a crash or a full disk
//! never leaves a half-written file or clobbers an existing one.

use crate::bvh2::Bvh2;
use crate::error::MAX_PRIMITIVES;
use crate::node::{ChildRef, Node};
use crate::validate::{validate, ValidationError};
use geom::{Aabb, Vec3};
use std::io::{Read, Write};
use std::path::Path;
use thiserror::Error;

/// The eight bytes every tree file starts with.
pub const MAGIC: [u8; 8] = *b"ARBORBVH";
/// The format version this module writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Longest builder name a file may carry, in bytes.
pub const MAX_BUILDER_NAME_BYTES: u32 = 255;
/// Size of the fixed part of the header, in bytes.
pub const FIXED_HEADER_BYTES: usize = 64;
/// Size of one node in the file, in bytes (\[P2\] §4.1: 64-byte nodes).
pub const NODE_BYTES: usize = 64;
/// Largest node count a file may claim: a binary tree over [`MAX_PRIMITIVES`] primitives
/// has fewer inner nodes than primitives (plus the root of the empty tree).
pub const MAX_NODES: usize = MAX_PRIMITIVES;
/// Alignment of the node section in the file, in bytes.
const SECTION_ALIGN_BYTES: usize = 16;
/// Nodes decoded per read: bounds the read buffer, not the tree (64 KiB).
const NODES_PER_CHUNK: usize = 1024;

/// Which kind of tree a file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TreeKind {
    /// The binary 64-byte-node tree [`Bvh2`].
    Bvh2 = 1,
    /// The 4-wide tree of \[P4\] (reserved: not read or written yet).
    Mbvh4 = 2,
}

/// What a tree file's header says.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// Format version.
    pub version: u32,
    /// Tree kind.
    pub kind: TreeKind,
    /// Number of nodes.
    pub node_count: u32,
    /// Number of leaf-table entries.
    pub leaf_table_len: u32,
    /// Number of primitives the tree was built over.
    pub prim_count: u32,
    /// Scene bounds.
    pub bounds: Aabb,
    /// Name of the builder that made the tree (e.g. `binned-sah`).
    pub builder: String,
    /// SAH cost with the thesis parameters, as computed by the writer.
    pub sah: f64,
}

/// Why a tree file could not be written or read.
#[derive(Debug, Error)]
pub enum IoError {
    /// An operating-system read or write error.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The file does not start with `ARBORBVH`.
    #[error("not an Arbor tree file (bad magic)")]
    BadMagic,
    /// A format version this build does not know.
    #[error("unsupported tree file version {0} (this build reads version {FORMAT_VERSION})")]
    UnsupportedVersion(u32),
    /// A tree kind this build does not read.
    #[error("unsupported tree kind {0} (this build reads kind 1, Bvh2)")]
    UnsupportedKind(u32),
    /// The file ends before the data its header announces.
    #[error("truncated tree file: it ends inside the {0}")]
    Truncated(&'static str),
    /// A header count or length beyond the format's limits or inconsistent with the others.
    #[error("corrupt tree file header: {0}")]
    BadHeader(String),
    /// The stored checksum does not match the data.
    #[error("tree file checksum mismatch (stored {stored:#010x}, computed {computed:#010x})")]
    Checksum {
        /// Checksum in the file.
        stored: u32,
        /// Checksum of the bytes read.
        computed: u32,
    },
    /// Bytes follow the checksum.
    #[error("trailing bytes after the tree file's checksum")]
    TrailingData,
    /// The tree decoded but breaks a structural invariant.
    #[error("invalid tree in file: {0}")]
    Invalid(#[from] ValidationError),
    /// The tree or builder name cannot be represented in the format.
    #[error("cannot write tree: {0}")]
    Unwritable(String),
}

/// A writer that computes the CRC-32 of everything written through it.
struct CrcWriter<W> {
    inner: W,
    crc: crc32fast::Hasher,
}

impl<W: Write> Write for CrcWriter<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.crc.update(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// A reader that computes the CRC-32 of everything read through it and maps a short read
/// to [`IoError::Truncated`].
struct CrcReader<R> {
    inner: R,
    crc: crc32fast::Hasher,
}

impl<R: Read> CrcReader<R> {
    /// Fills `buf` exactly; `what` names the section for the truncation error.
    fn fill(&mut self, buf: &mut [u8], what: &'static str) -> Result<(), IoError> {
        match self.inner.read_exact(buf) {
            Ok(()) => {
                self.crc.update(buf);
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                Err(IoError::Truncated(what))
            }
            Err(e) => Err(IoError::Io(e)),
        }
    }
}

/// Length of the header including the padded builder name.
fn header_bytes(name_len: usize) -> usize {
    (FIXED_HEADER_BYTES + name_len).div_ceil(SECTION_ALIGN_BYTES) * SECTION_ALIGN_BYTES
}

fn u32_at(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

fn f32_at(b: &[u8], off: usize) -> f32 {
    f32::from_bits(u32_at(b, off))
}

/// The 64 file bytes of a node (the in-memory layout, little-endian).
fn encode_node(n: &Node, out: &mut [u8]) {
    let mut o = 0;
    for b in &n.bounds {
        for v in b {
            out[o..o + 4].copy_from_slice(&v.to_le_bytes());
            o += 4;
        }
    }
    for c in &n.children {
        out[o..o + 4].copy_from_slice(&c.index.to_le_bytes());
        out[o + 4..o + 8].copy_from_slice(&c.count.to_le_bytes());
        o += 8;
    }
}

/// A node from its 64 file bytes.
fn decode_node(b: &[u8]) -> Node {
    let mut bounds = [[0.0f32; 6]; 2];
    for (i, v) in bounds.iter_mut().flatten().enumerate() {
        *v = f32_at(b, i * 4);
    }
    let child = |k: usize| ChildRef {
        index: u32_at(b, 48 + 8 * k),
        count: u32_at(b, 52 + 8 * k),
    };
    Node {
        bounds,
        children: [child(0), child(1)],
    }
}

/// Writes `bvh`, built by `builder`, in the tree file format to `w`.
pub fn write_bvh2(bvh: &Bvh2, builder: &str, w: impl Write) -> Result<(), IoError> {
    if builder.len() > MAX_BUILDER_NAME_BYTES as usize {
        return Err(IoError::Unwritable(format!(
            "builder name is {} bytes, above the limit of {MAX_BUILDER_NAME_BYTES}",
            builder.len()
        )));
    }
    if bvh.nodes.is_empty() || bvh.nodes.len() > MAX_NODES {
        return Err(IoError::Unwritable(format!(
            "{} nodes (must be 1..={MAX_NODES})",
            bvh.nodes.len()
        )));
    }
    if bvh.prim_indices.len() > MAX_PRIMITIVES {
        return Err(IoError::Unwritable(format!(
            "{} leaf-table entries exceed {MAX_PRIMITIVES}",
            bvh.prim_indices.len()
        )));
    }
    let mut w = CrcWriter {
        inner: std::io::BufWriter::new(w),
        crc: crc32fast::Hasher::new(),
    };
    let mut head = vec![0u8; header_bytes(builder.len())];
    head[0..8].copy_from_slice(&MAGIC);
    let put = |h: &mut [u8], off: usize, v: u32| h[off..off + 4].copy_from_slice(&v.to_le_bytes());
    put(&mut head, 8, FORMAT_VERSION);
    put(&mut head, 12, TreeKind::Bvh2 as u32);
    put(&mut head, 16, bvh.nodes.len() as u32);
    put(&mut head, 20, bvh.prim_indices.len() as u32);
    put(&mut head, 24, bvh.prim_indices.len() as u32);
    put(&mut head, 28, builder.len() as u32);
    let b = &bvh.bounds;
    for (i, v) in [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z]
        .iter()
        .enumerate()
    {
        put(&mut head, 32 + 4 * i, v.to_bits());
    }
    head[56..64].copy_from_slice(&bvh.sah().to_le_bytes());
    head[64..64 + builder.len()].copy_from_slice(builder.as_bytes());
    w.write_all(&head)?;
    let mut buf = [0u8; NODE_BYTES];
    for n in &bvh.nodes {
        encode_node(n, &mut buf);
        w.write_all(&buf)?;
    }
    for p in &bvh.prim_indices {
        w.write_all(&p.to_le_bytes())?;
    }
    let crc = w.crc.clone().finalize();
    w.inner.write_all(&crc.to_le_bytes())?;
    w.inner.flush()?;
    Ok(())
}

/// Writes `bvh` to the file `path` atomically: a temporary file in the same directory is
/// written, synced and renamed over `path`, so `path` is either untouched or complete.
pub fn write_bvh2_file(bvh: &Bvh2, builder: &str, path: &Path) -> Result<(), IoError> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut tb = tempfile::Builder::new();
    tb.prefix(".arbor-tree-").suffix(".tmp");
    // Temporary files are private (0600) by default; the renamed result should get the
    // permissions of any file the user creates (0666 less the umask).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tb.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = tb.tempfile_in(dir)?;
    write_bvh2(bvh, builder, tmp.as_file_mut())?;
    tmp.as_file().sync_all()?;
    // On failure the temporary file is removed when `tmp` (inside the error) is dropped.
    tmp.persist(path).map_err(|e| IoError::Io(e.error))?;
    Ok(())
}

/// Reads a [`Bvh2`] tree file from `r`, checking everything (see the module doc), and
/// returns the tree with its header. The tree is validated structurally before it is
/// returned.
pub fn read_bvh2(r: impl Read) -> Result<(Bvh2, Header), IoError> {
    let mut r = CrcReader {
        inner: r,
        crc: crc32fast::Hasher::new(),
    };
    let mut fixed = [0u8; FIXED_HEADER_BYTES];
    // A file shorter than the magic is not a tree file at all; say so before "truncated".
    let mut magic = [0u8; 8];
    match r.fill(&mut magic, "header") {
        Ok(()) if magic == MAGIC => {}
        Ok(()) | Err(IoError::Truncated(_)) => return Err(IoError::BadMagic),
        Err(e) => return Err(e),
    }
    fixed[..8].copy_from_slice(&magic);
    r.fill(&mut fixed[8..], "header")?;
    let version = u32_at(&fixed, 8);
    if version != FORMAT_VERSION {
        return Err(IoError::UnsupportedVersion(version));
    }
    let kind = u32_at(&fixed, 12);
    if kind != TreeKind::Bvh2 as u32 {
        return Err(IoError::UnsupportedKind(kind));
    }
    let node_count = u32_at(&fixed, 16);
    let leaf_table_len = u32_at(&fixed, 20);
    let prim_count = u32_at(&fixed, 24);
    let name_len = u32_at(&fixed, 28);
    if node_count == 0 || node_count as usize > MAX_NODES {
        return Err(IoError::BadHeader(format!(
            "node count {node_count} outside 1..={MAX_NODES}"
        )));
    }
    if leaf_table_len as usize > MAX_PRIMITIVES {
        return Err(IoError::BadHeader(format!(
            "leaf-table length {leaf_table_len} above {MAX_PRIMITIVES}"
        )));
    }
    if prim_count != leaf_table_len {
        return Err(IoError::BadHeader(format!(
            "primitive count {prim_count} differs from leaf-table length {leaf_table_len}"
        )));
    }
    if name_len > MAX_BUILDER_NAME_BYTES {
        return Err(IoError::BadHeader(format!(
            "builder name length {name_len} above {MAX_BUILDER_NAME_BYTES}"
        )));
    }
    let v = |i: usize| f32_at(&fixed, 32 + 4 * i);
    let bounds = Aabb::new(Vec3::new(v(0), v(1), v(2)), Vec3::new(v(3), v(4), v(5)));
    let sah = f64::from_le_bytes(fixed[56..64].try_into().expect("8 bytes"));

    // Builder name and padding (bounded by MAX_BUILDER_NAME_BYTES).
    let mut name = vec![0u8; header_bytes(name_len as usize) - FIXED_HEADER_BYTES];
    r.fill(&mut name, "builder name")?;
    if name[name_len as usize..].iter().any(|&b| b != 0) {
        return Err(IoError::BadHeader("non-zero header padding".into()));
    }
    name.truncate(name_len as usize);
    let builder = String::from_utf8(name)
        .map_err(|_| IoError::BadHeader("builder name is not UTF-8".into()))?;

    // Nodes, in chunks: memory grows only with bytes actually read.
    let mut nodes = Vec::new();
    let mut chunk = vec![0u8; NODES_PER_CHUNK * NODE_BYTES];
    let mut left = node_count as usize;
    while left > 0 {
        let k = left.min(NODES_PER_CHUNK);
        let bytes = &mut chunk[..k * NODE_BYTES];
        r.fill(bytes, "node array")?;
        nodes.extend(bytes.chunks_exact(NODE_BYTES).map(decode_node));
        left -= k;
    }
    let mut prim_indices = Vec::new();
    let mut left = leaf_table_len as usize;
    while left > 0 {
        let k = left.min(NODES_PER_CHUNK * NODE_BYTES / 4);
        let bytes = &mut chunk[..k * 4];
        r.fill(bytes, "leaf table")?;
        prim_indices.extend(bytes.chunks_exact(4).map(|b| u32_at(b, 0)));
        left -= k;
    }
    let computed = r.crc.clone().finalize();
    let mut stored = [0u8; 4];
    r.fill(&mut stored, "checksum")?;
    let stored = u32::from_le_bytes(stored);
    if stored != computed {
        return Err(IoError::Checksum { stored, computed });
    }
    let mut extra = [0u8; 1];
    loop {
        match r.inner.read(&mut extra) {
            Ok(0) => break,
            Ok(_) => return Err(IoError::TrailingData),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(IoError::Io(e)),
        }
    }

    let bvh = Bvh2 {
        nodes,
        prim_indices,
        bounds,
    };
    check_structure(&bvh)?;
    let header = Header {
        version,
        kind: TreeKind::Bvh2,
        node_count,
        leaf_table_len,
        prim_count,
        bounds,
        builder,
        sah,
    };
    Ok((bvh, header))
}

/// Reads a tree file from `path` (see [`read_bvh2`]).
pub fn read_bvh2_file(path: &Path) -> Result<(Bvh2, Header), IoError> {
    let f = std::fs::File::open(path)?;
    read_bvh2(std::io::BufReader::new(f))
}

/// Validates a tree read from a file, whose primitive boxes are unknown: each primitive
/// gets the box of the leaf that references it, so [`validate`] checks everything but
/// primitive-in-leaf containment (indices, preorder, each primitive once, child boxes
/// inside parents, bounds). Leaf sizes are not limited: the file does not record the
/// builder's maximum.
fn check_structure(bvh: &Bvh2) -> Result<(), ValidationError> {
    // The leaf table was read from the file, so this allocation is bounded by its size.
    let mut prims = vec![Aabb::EMPTY; bvh.prim_indices.len()];
    for n in &bvh.nodes {
        for (slot, c) in n.children.iter().enumerate() {
            if !c.is_leaf() {
                continue;
            }
            let first = c.index as usize;
            let Some(range) = bvh
                .prim_indices
                .get(first..first.saturating_add(c.count as usize))
            else {
                continue; // out of range: `validate` reports it
            };
            for &p in range {
                if let Some(b) = prims.get_mut(p as usize) {
                    *b = n.child_aabb(slot);
                }
            }
        }
    }
    // An unreferenced primitive keeps the empty box; the validator reports it unreferenced.
    validate(bvh, &prims, u32::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::soup;
    use crate::{BinnedSahBuilder, LbvhBuilder, SweepSahBuilder};

    fn bytes_of(t: &Bvh2, name: &str) -> Vec<u8> {
        let mut v = Vec::new();
        write_bvh2(t, name, &mut v).unwrap();
        v
    }

    fn sample() -> Bvh2 {
        BinnedSahBuilder::default()
            .build(&soup(500, 2.0, 7))
            .unwrap()
    }

    /// Re-seals a modified file with a correct checksum, so the test reaches the check
    /// after the checksum.
    fn reseal(v: &mut [u8]) {
        let n = v.len() - 4;
        let crc = crc32fast::hash(&v[..n]);
        v[n..].copy_from_slice(&crc.to_le_bytes());
    }

    #[test]
    fn round_trips_every_builder_and_small_trees() {
        let prims = soup(2000, 3.0, 1);
        let trees = [
            (
                "binned-sah",
                BinnedSahBuilder::default().build(&prims).unwrap(),
            ),
            (
                "sweep-sah",
                SweepSahBuilder::default().build(&prims).unwrap(),
            ),
            ("lbvh", LbvhBuilder::default().build(&prims).unwrap()),
            ("empty", Bvh2::empty()),
            ("one", LbvhBuilder::default().build(&prims[..1]).unwrap()),
            ("", SweepSahBuilder::default().build(&prims[..2]).unwrap()),
        ];
        for (name, t) in trees {
            let v = bytes_of(&t, name);
            assert_eq!(
                v.len(),
                header_bytes(name.len()) + 64 * t.nodes.len() + 4 * t.prim_indices.len() + 4
            );
            let (back, h) = read_bvh2(&v[..]).unwrap();
            assert_eq!(back, t, "{name}");
            assert_eq!(h.builder, name);
            assert_eq!(h.node_count as usize, t.nodes.len());
            assert_eq!(h.prim_count as usize, t.prim_count());
            assert_eq!(h.kind, TreeKind::Bvh2);
            assert!(h.sah == t.sah() || (h.sah.is_nan() && t.sah().is_nan()));
        }
    }

    #[test]
    fn node_bytes_are_the_in_memory_layout() {
        let t = sample();
        let v = bytes_of(&t, "x");
        let h = header_bytes(1);
        assert_eq!(h % 16, 0);
        // Field by field, as the node module documents: bounds then (index, count) pairs.
        let n = &t.nodes[0];
        assert_eq!(f32_at(&v, h), n.bounds[0][0]);
        assert_eq!(f32_at(&v, h + 36), n.bounds[1][3]);
        assert_eq!(u32_at(&v, h + 48), n.children[0].index);
        assert_eq!(u32_at(&v, h + 60), n.children[1].count);
        assert_eq!(&v[..8], b"ARBORBVH");
        assert_eq!(u32_at(&v, 8), FORMAT_VERSION);
    }

    #[test]
    fn rejects_bad_magic_and_tiny_files() {
        let mut v = bytes_of(&sample(), "b");
        v[0] = b'X';
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadMagic)));
        assert!(matches!(read_bvh2(&[][..]), Err(IoError::BadMagic)));
        assert!(matches!(read_bvh2(&b"ARBOR"[..]), Err(IoError::BadMagic)));
    }

    #[test]
    fn rejects_unknown_version_and_kind() {
        let mut v = bytes_of(&sample(), "b");
        v[8] = 2;
        assert!(matches!(
            read_bvh2(&v[..]),
            Err(IoError::UnsupportedVersion(2))
        ));
        let mut v = bytes_of(&sample(), "b");
        v[12] = TreeKind::Mbvh4 as u8;
        assert!(matches!(
            read_bvh2(&v[..]),
            Err(IoError::UnsupportedKind(2))
        ));
    }

    #[test]
    fn rejects_every_truncation() {
        let v = bytes_of(&sample(), "binned-sah");
        // Every prefix, sampled densely at the section boundaries.
        for len in (0..v.len()).filter(|l| l % 7 == 0 || *l < 100 || v.len() - l < 100) {
            match read_bvh2(&v[..len]) {
                Err(IoError::Truncated(_)) | Err(IoError::BadMagic) => {}
                other => panic!("prefix {len}: {other:?}"),
            }
        }
    }

    #[test]
    fn absurd_counts_fail_fast_without_allocating() {
        // Claims u32::MAX - 1 nodes and 2^31 - 1 leaves on a small file: the count is within
        // the limits for the leaves, so the reader must stop at the truncation, having grown
        // its arrays only by what was read.
        let mut v = bytes_of(&sample(), "b");
        v[16..20].copy_from_slice(&(MAX_NODES as u32).to_le_bytes());
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::Truncated(_))));
        let mut v = bytes_of(&sample(), "b");
        v[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadHeader(_))));
        let mut v = bytes_of(&sample(), "b");
        v[16..20].copy_from_slice(&0u32.to_le_bytes());
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadHeader(_))));
        let mut v = bytes_of(&sample(), "b");
        v[20..24].copy_from_slice(&u32::MAX.to_le_bytes());
        v[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadHeader(_))));
        let mut v = bytes_of(&sample(), "b");
        v[24..28].copy_from_slice(&3u32.to_le_bytes());
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadHeader(_))));
        let mut v = bytes_of(&sample(), "b");
        v[28..32].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadHeader(_))));
    }

    #[test]
    fn rejects_bad_name_and_padding() {
        let mut v = bytes_of(&sample(), "abc");
        v[64] = 0xff;
        reseal(&mut v);
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadHeader(_))));
        let mut v = bytes_of(&sample(), "abc");
        v[70] = 1;
        reseal(&mut v);
        assert!(matches!(read_bvh2(&v[..]), Err(IoError::BadHeader(_))));
        let long = "x".repeat(MAX_BUILDER_NAME_BYTES as usize + 1);
        assert!(matches!(
            write_bvh2(&sample(), &long, Vec::new()),
            Err(IoError::Unwritable(_))
        ));
    }

    #[test]
    fn rejects_checksum_mismatch_and_trailing_bytes() {
        let v = bytes_of(&sample(), "b");
        for pos in [40, header_bytes(1) + 5, v.len() - 10, v.len() - 1] {
            let mut w = v.clone();
            w[pos] ^= 0x10;
            assert!(
                matches!(read_bvh2(&w[..]), Err(IoError::Checksum { .. })),
                "flip at {pos}"
            );
        }
        let mut w = v.clone();
        w.push(0);
        assert!(matches!(read_bvh2(&w[..]), Err(IoError::TrailingData)));
    }

    #[test]
    fn rejects_structurally_invalid_trees_with_valid_checksums() {
        let t = sample();
        let h = header_bytes(1);
        let leaf_at = h + 64 * t.nodes.len();
        type Corrupt = Box<dyn Fn(&mut Vec<u8>)>;
        let cases: Vec<(&str, Corrupt)> = vec![
            (
                "child index out of range",
                Box::new(move |v| v[h + 48..h + 52].copy_from_slice(&999_999u32.to_le_bytes())),
            ),
            (
                "child points to the root",
                Box::new(move |v| {
                    v[h + 48..h + 56].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0, 0]);
                }),
            ),
            (
                "leaf-table entry out of range",
                Box::new(move |v| v[leaf_at..leaf_at + 4].copy_from_slice(&u32::MAX.to_le_bytes())),
            ),
            (
                "duplicate primitive",
                Box::new(move |v| {
                    let second: [u8; 4] = v[leaf_at + 4..leaf_at + 8].try_into().unwrap();
                    v[leaf_at..leaf_at + 4].copy_from_slice(&second);
                }),
            ),
            (
                "NaN box",
                Box::new(move |v| v[h..h + 4].copy_from_slice(&f32::NAN.to_le_bytes())),
            ),
            (
                "wrong scene bounds",
                Box::new(|v| v[32..36].copy_from_slice(&(-1e30f32).to_le_bytes())),
            ),
        ];
        for (what, corrupt) in cases {
            let mut v = bytes_of(&t, "b");
            corrupt(&mut v);
            reseal(&mut v);
            assert!(
                matches!(read_bvh2(&v[..]), Err(IoError::Invalid(_))),
                "{what}: {:?}",
                read_bvh2(&v[..])
            );
        }
    }

    #[test]
    fn file_writes_are_atomic_and_never_clobber_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.bvh");
        let t = sample();
        write_bvh2_file(&t, "binned-sah", &path).unwrap();
        assert_eq!(read_bvh2_file(&path).unwrap().0, t);
        // A failing write (name too long) leaves the old file and no temporary behind.
        let long = "x".repeat(300);
        assert!(write_bvh2_file(&Bvh2::empty(), &long, &path).is_err());
        assert_eq!(read_bvh2_file(&path).unwrap().0, t);
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "temporary file left behind");
        // A directory that does not exist is an error, not a panic.
        assert!(write_bvh2_file(&t, "b", &dir.path().join("no/such/t.bvh")).is_err());
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]
        /// Any corruption of any byte is rejected or yields exactly the written tree (never
        /// a panic, never a different tree).
        #[test]
        fn corrupted_bytes_never_panic(pos in 0usize..4096, val in 0u8..=255, cut in 0usize..4096) {
            let t = LbvhBuilder::default().build(&soup(20, 2.0, 3)).unwrap();
            let mut v = bytes_of(&t, "lbvh");
            let p = pos % v.len();
            v[p] = val;
            if let Ok((back, _)) = read_bvh2(&v[..]) {
                proptest::prop_assert_eq!(back, t.clone());
            }
            reseal(&mut v);
            let _ = read_bvh2(&v[..]);
            let _ = read_bvh2(&v[..cut % v.len()]);
        }
    }
}
