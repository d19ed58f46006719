//! The Arbor tree file: a little-endian binary format for a [`Bvh2`] or an [`Mbvh4`] that
//! `arbor build --out` writes and that `arbor render` and the hardware models read back.
//! The nodes are stored in exactly their in-memory layout — the 64-byte [`Node`] of \[P2\]
//! §4.1 Fig. 2, or the 128-byte [`Node4`] of \[P4\] §3.1 — so a hardware model can map the
//! node section and fetch one node per 64- or 128-byte line.
//!
//! Loading, for a ray tracer: [`read_tree_file`] returns a [`Tree`] of either kind (match on
//! it, or use [`Tree::kind`]); [`read_bvh2_file`] and [`read_mbvh4_file`] return one kind
//! and fail with [`IoError::WrongKind`] on the other.
//!
//! Layout (all integers and floats little-endian; `docs/tree-format.md` has the same table):
//!
//! | offset      | size | field                                                         |
//! |-------------|------|---------------------------------------------------------------|
//! | 0           | 8    | magic `ARBORBVH`                                              |
//! | 8           | 4    | format version `u32` (= [`FORMAT_VERSION`]; 1 is still read)  |
//! | 12          | 4    | tree kind `u32`: 1 = `Bvh2`; 2 = `Mbvh4` (version 2 only)     |
//! | 16          | 4    | node count `u32` (>= 1: the root always exists)               |
//! | 20          | 4    | leaf-table length `u32`                                       |
//! | 24          | 4    | primitive count `u32` (= leaf-table length)                   |
//! | 28          | 4    | builder name length `u32` in bytes (<= [`MAX_BUILDER_NAME_BYTES`]) |
//! | 32          | 24   | scene bounds: min x, y, z, max x, y, z (`f32`)                |
//! | 56          | 8    | SAH cost (`f64`, informational; [`Tree::normalized_sah`])     |
//! | 64          | L    | builder name, UTF-8, then zero bytes up to a multiple of 16   |
//! | H           | S N  | nodes, each in the S-byte layout of [`Node`] (64) or [`Node4`] (128) |
//! | H + S N     | 4 T  | leaf table (`u32` primitive indices)                          |
//! | end - 4     | 4    | CRC-32 (IEEE, as zlib/PNG) of every byte before it            |
//!
//! `H = 64 + L` rounded up to 16, so the node section is 16-byte aligned in the file.
//! Version 2 added kind 2; a version-1 file is a version-2 file of kind 1, byte for byte
//! apart from the version field, and is read the same way.
//!
//! Reading trusts nothing: bad magic, an unknown version or kind, counts above the format's
//! limits, non-zero padding, a truncated file, trailing bytes and a checksum mismatch are
//! each a typed [`IoError`]. Arrays grow as their bytes actually arrive (never preallocated
//! from a header count), so a header that claims 2^32 nodes on a 100-byte file costs
//! nothing. A tree that passes the checksum is then validated structurally with
//! [`crate::validate`] or [`crate::validate_mbvh4`] (every index in range, preorder, each
//! primitive once, child boxes inside parents, slot rules), so a reader can walk it without
//! bounds checks going wrong.
//!
//! The writers are atomic: [`write_tree_file`] (and [`write_bvh2_file`],
//! [`write_mbvh4_file`]) write to a temporary file in the destination's directory, flush it
//! to disk, then rename it over the destination, so a crash or a full disk never leaves a
//! half-written file or clobbers an existing one.

use crate::bvh2::Bvh2;
use crate::error::MAX_PRIMITIVES;
use crate::mbvh4::{validate_mbvh4, Mbvh4, Node4};
use crate::node::{ChildRef, Node, TreeNode};
use crate::validate::{validate, ValidationError};
use geom::{Aabb, Vec3};
use std::io::{Read, Write};
use std::path::Path;
use thiserror::Error;

pub use crate::tree::{Tree, TreeKind};

/// The eight bytes every tree file starts with.
pub const MAGIC: [u8; 8] = *b"ARBORBVH";
/// The format version this module writes (it reads this and every earlier version).
pub const FORMAT_VERSION: u32 = 2;
/// Longest builder name a file may carry, in bytes.
pub const MAX_BUILDER_NAME_BYTES: u32 = 255;
/// Size of the fixed part of the header, in bytes.
pub const FIXED_HEADER_BYTES: usize = 64;
/// Size of one binary node in the file, in bytes (\[P2\] §4.1: 64-byte nodes).
pub const NODE_BYTES: usize = 64;
/// Size of one 4-wide node in the file, in bytes (\[P4\] §3.1: 128-byte nodes).
pub const NODE4_BYTES: usize = 128;
/// Largest node count a file may claim: a tree over [`MAX_PRIMITIVES`] primitives has
/// fewer inner nodes than primitives (plus the root of the empty tree).
pub const MAX_NODES: usize = MAX_PRIMITIVES;
/// Alignment of the node section in the file, in bytes.
const SECTION_ALIGN_BYTES: usize = 16;
/// Bytes decoded per read: bounds the read buffer, not the tree (64 KiB).
const CHUNK_BYTES: usize = 64 * 1024;

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
    /// SAH cost as computed by the writer ([`Tree::normalized_sah`]: the thesis weights,
    /// a 4-wide node costing `2 C_i`).
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
    #[error("unsupported tree file version {0} (this build reads versions 1 to {FORMAT_VERSION})")]
    UnsupportedVersion(u32),
    /// A tree kind this build (or this file's version) does not have.
    #[error("unsupported tree kind {kind} in a version {version} file (kinds: 1 = Bvh2, 2 = Mbvh4 from version 2)")]
    UnsupportedKind {
        /// The kind field.
        kind: u32,
        /// The file's version.
        version: u32,
    },
    /// The file holds the other kind of tree than the caller asked for.
    #[error(
        "the tree file holds a {found} tree, not a {expected} (read it with bvh::io::read_tree)"
    )]
    WrongKind {
        /// The kind asked for.
        expected: TreeKind,
        /// The kind in the file.
        found: TreeKind,
    },
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

    /// Reads `count` records of `size` bytes, decoding each with `decode`, in bounded
    /// chunks: memory grows only with bytes actually read.
    fn records<T>(
        &mut self,
        count: usize,
        size: usize,
        what: &'static str,
        decode: impl Fn(&[u8]) -> T,
    ) -> Result<Vec<T>, IoError> {
        let per_chunk = CHUNK_BYTES / size;
        let mut chunk = vec![0u8; per_chunk * size];
        let mut out = Vec::new();
        let mut left = count;
        while left > 0 {
            let k = left.min(per_chunk);
            let bytes = &mut chunk[..k * size];
            self.fill(bytes, what)?;
            out.extend(bytes.chunks_exact(size).map(&decode));
            left -= k;
        }
        Ok(out)
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

/// Writes `vals` as little-endian `u32`/`f32` words into `out` from byte `o`; returns the
/// offset after them.
fn put_words(out: &mut [u8], mut o: usize, vals: impl IntoIterator<Item = u32>) -> usize {
    for v in vals {
        out[o..o + 4].copy_from_slice(&v.to_le_bytes());
        o += 4;
    }
    o
}

/// `(index, count)` of child reference `k` stored at byte `off` of a node record.
fn child_at(b: &[u8], off: usize, k: usize) -> ChildRef {
    ChildRef {
        index: u32_at(b, off + 8 * k),
        count: u32_at(b, off + 8 * k + 4),
    }
}

/// A node type the file stores: its record size and its byte encoding (the in-memory
/// `#[repr(C)]` layout, little-endian).
trait FileNode: TreeNode {
    /// The kind of tree made of these nodes.
    const KIND: TreeKind;
    /// Bytes per record.
    const BYTES: usize;
    /// Writes the record into `out` (exactly `BYTES` long).
    fn encode(&self, out: &mut [u8]);
    /// Reads a record (exactly `BYTES` long).
    fn decode(b: &[u8]) -> Self;
}

impl FileNode for Node {
    const KIND: TreeKind = TreeKind::Bvh2;
    const BYTES: usize = NODE_BYTES;
    fn encode(&self, out: &mut [u8]) {
        let o = put_words(out, 0, self.bounds.iter().flatten().map(|v| v.to_bits()));
        put_words(
            out,
            o,
            self.children.iter().flat_map(|c| [c.index, c.count]),
        );
    }
    fn decode(b: &[u8]) -> Self {
        let mut bounds = [[0.0f32; 6]; 2];
        for (i, v) in bounds.iter_mut().flatten().enumerate() {
            *v = f32_at(b, i * 4);
        }
        Node {
            bounds,
            children: [0, 1].map(|k| child_at(b, 48, k)),
        }
    }
}

impl FileNode for Node4 {
    const KIND: TreeKind = TreeKind::Mbvh4;
    const BYTES: usize = NODE4_BYTES;
    fn encode(&self, out: &mut [u8]) {
        let planes = [
            &self.min_x,
            &self.min_y,
            &self.min_z,
            &self.max_x,
            &self.max_y,
            &self.max_z,
        ];
        let o = put_words(out, 0, planes.iter().flat_map(|p| p.map(f32::to_bits)));
        put_words(
            out,
            o,
            self.children.iter().flat_map(|c| [c.index, c.count]),
        );
    }
    fn decode(b: &[u8]) -> Self {
        let plane = |p: usize| [0, 1, 2, 3].map(|i| f32_at(b, 16 * p + 4 * i));
        Node4 {
            min_x: plane(0),
            min_y: plane(1),
            min_z: plane(2),
            max_x: plane(3),
            max_y: plane(4),
            max_z: plane(5),
            children: [0, 1, 2, 3].map(|k| child_at(b, 96, k)),
        }
    }
}

/// The parts of a tree that the file stores.
struct Parts<'a, N> {
    nodes: &'a [N],
    prim_indices: &'a [u32],
    bounds: Aabb,
    sah: f64,
}

/// Writes a tree's parts in the file format.
fn write_parts<N: FileNode>(t: &Parts<'_, N>, builder: &str, w: impl Write) -> Result<(), IoError> {
    if builder.len() > MAX_BUILDER_NAME_BYTES as usize {
        return Err(IoError::Unwritable(format!(
            "builder name is {} bytes, above the limit of {MAX_BUILDER_NAME_BYTES}",
            builder.len()
        )));
    }
    if t.nodes.is_empty() || t.nodes.len() > MAX_NODES {
        return Err(IoError::Unwritable(format!(
            "{} nodes (must be 1..={MAX_NODES})",
            t.nodes.len()
        )));
    }
    if t.prim_indices.len() > MAX_PRIMITIVES {
        return Err(IoError::Unwritable(format!(
            "{} leaf-table entries exceed {MAX_PRIMITIVES}",
            t.prim_indices.len()
        )));
    }
    let mut w = CrcWriter {
        inner: std::io::BufWriter::new(w),
        crc: crc32fast::Hasher::new(),
    };
    let mut head = vec![0u8; header_bytes(builder.len())];
    head[0..8].copy_from_slice(&MAGIC);
    let b = &t.bounds;
    let bounds = [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits);
    let words = [
        FORMAT_VERSION,
        N::KIND as u32,
        t.nodes.len() as u32,
        t.prim_indices.len() as u32,
        t.prim_indices.len() as u32,
        builder.len() as u32,
    ];
    put_words(&mut head, 8, words.into_iter().chain(bounds));
    head[56..64].copy_from_slice(&t.sah.to_le_bytes());
    head[64..64 + builder.len()].copy_from_slice(builder.as_bytes());
    w.write_all(&head)?;
    let mut buf = vec![0u8; N::BYTES];
    for n in t.nodes {
        n.encode(&mut buf);
        w.write_all(&buf)?;
    }
    for p in t.prim_indices {
        w.write_all(&p.to_le_bytes())?;
    }
    let crc = w.crc.clone().finalize();
    w.inner.write_all(&crc.to_le_bytes())?;
    w.inner.flush()?;
    Ok(())
}

/// Writes `bvh`, built by `builder`, in the tree file format to `w`.
pub fn write_bvh2(bvh: &Bvh2, builder: &str, w: impl Write) -> Result<(), IoError> {
    let parts = Parts {
        nodes: &bvh.nodes,
        prim_indices: &bvh.prim_indices,
        bounds: bvh.bounds,
        sah: bvh.sah(),
    };
    write_parts(&parts, builder, w)
}

/// Writes the 4-wide `tree`, built by `builder`, in the tree file format to `w`.
pub fn write_mbvh4(tree: &Mbvh4, builder: &str, w: impl Write) -> Result<(), IoError> {
    let parts = Parts {
        nodes: &tree.nodes,
        prim_indices: &tree.prim_indices,
        bounds: tree.bounds,
        sah: tree.normalized_sah(),
    };
    write_parts(&parts, builder, w)
}

/// Writes a tree of either kind in the tree file format to `w`.
pub fn write_tree(tree: &Tree, builder: &str, w: impl Write) -> Result<(), IoError> {
    match tree {
        Tree::Bvh2(t) => write_bvh2(t, builder, w),
        Tree::Mbvh4(t) => write_mbvh4(t, builder, w),
    }
}

/// Runs `write` on a temporary file in `path`'s folder, syncs it and renames it over
/// `path`, so `path` is either untouched or complete.
fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut std::fs::File) -> Result<(), IoError>,
) -> Result<(), IoError> {
    // The workspace's one atomic writer's temporary file: an ordinary file's permissions
    // (0666 less the umask), not tempfile's private 0600.
    let mut tmp = outfile::temp_file_beside(path, ".arbor-tree-")?;
    write(tmp.as_file_mut())?;
    tmp.as_file().sync_all()?;
    // On failure the temporary file is removed when `tmp` (inside the error) is dropped.
    tmp.persist(path).map_err(|e| IoError::Io(e.error))?;
    Ok(())
}

/// Writes `bvh` to the file `path` atomically (see the module doc).
pub fn write_bvh2_file(bvh: &Bvh2, builder: &str, path: &Path) -> Result<(), IoError> {
    write_atomically(path, |f| write_bvh2(bvh, builder, f))
}

/// Writes the 4-wide `tree` to the file `path` atomically (see the module doc).
pub fn write_mbvh4_file(tree: &Mbvh4, builder: &str, path: &Path) -> Result<(), IoError> {
    write_atomically(path, |f| write_mbvh4(tree, builder, f))
}

/// Writes a tree of either kind to the file `path` atomically (see the module doc).
pub fn write_tree_file(tree: &Tree, builder: &str, path: &Path) -> Result<(), IoError> {
    write_atomically(path, |f| write_tree(tree, builder, f))
}

/// Reads a tree file of either kind from `r`, checking everything (see the module doc),
/// and returns the tree with its header. The tree is validated structurally before it is
/// returned.
pub fn read_tree(r: impl Read) -> Result<(Tree, Header), IoError> {
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
    if !(1..=FORMAT_VERSION).contains(&version) {
        return Err(IoError::UnsupportedVersion(version));
    }
    let kind = match (u32_at(&fixed, 12), version) {
        (1, _) => TreeKind::Bvh2,
        (2, 2..) => TreeKind::Mbvh4,
        (kind, version) => return Err(IoError::UnsupportedKind { kind, version }),
    };
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

    let tree = match kind {
        TreeKind::Bvh2 => {
            let nodes = r.records(node_count as usize, NODE_BYTES, "node array", Node::decode)?;
            let prim_indices = read_leaf_table(&mut r, leaf_table_len)?;
            Tree::Bvh2(Bvh2 {
                nodes,
                prim_indices,
                bounds,
            })
        }
        TreeKind::Mbvh4 => {
            let nodes = r.records(
                node_count as usize,
                NODE4_BYTES,
                "node array",
                Node4::decode,
            )?;
            let prim_indices = read_leaf_table(&mut r, leaf_table_len)?;
            Tree::Mbvh4(Mbvh4 {
                nodes,
                prim_indices,
                bounds,
            })
        }
    };
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
    check_structure(&tree)?;
    let header = Header {
        version,
        kind,
        node_count,
        leaf_table_len,
        prim_count,
        bounds,
        builder,
        sah,
    };
    Ok((tree, header))
}

/// The leaf table of `len` entries.
fn read_leaf_table<R: Read>(r: &mut CrcReader<R>, len: u32) -> Result<Vec<u32>, IoError> {
    r.records(len as usize, 4, "leaf table", |b| u32_at(b, 0))
}

/// Reads a tree file of either kind from `path` (see [`read_tree`]).
pub fn read_tree_file(path: &Path) -> Result<(Tree, Header), IoError> {
    let f = std::fs::File::open(path)?;
    read_tree(std::io::BufReader::new(f))
}

/// Reads a [`Bvh2`] tree file from `r` (see [`read_tree`]); a file holding an [`Mbvh4`] is
/// [`IoError::WrongKind`].
pub fn read_bvh2(r: impl Read) -> Result<(Bvh2, Header), IoError> {
    match read_tree(r)? {
        (Tree::Bvh2(t), h) => Ok((t, h)),
        (t, _) => Err(IoError::WrongKind {
            expected: TreeKind::Bvh2,
            found: t.kind(),
        }),
    }
}

/// Reads an [`Mbvh4`] tree file from `r` (see [`read_tree`]); a file holding a [`Bvh2`] is
/// [`IoError::WrongKind`].
pub fn read_mbvh4(r: impl Read) -> Result<(Mbvh4, Header), IoError> {
    match read_tree(r)? {
        (Tree::Mbvh4(t), h) => Ok((t, h)),
        (t, _) => Err(IoError::WrongKind {
            expected: TreeKind::Mbvh4,
            found: t.kind(),
        }),
    }
}

/// Reads a [`Bvh2`] tree file from `path` (see [`read_bvh2`]).
pub fn read_bvh2_file(path: &Path) -> Result<(Bvh2, Header), IoError> {
    let f = std::fs::File::open(path)?;
    read_bvh2(std::io::BufReader::new(f))
}

/// Reads an [`Mbvh4`] tree file from `path` (see [`read_mbvh4`]).
pub fn read_mbvh4_file(path: &Path) -> Result<(Mbvh4, Header), IoError> {
    let f = std::fs::File::open(path)?;
    read_mbvh4(std::io::BufReader::new(f))
}

/// Boxes for the primitives of a tree read from a file, whose real boxes are unknown: each
/// primitive gets the box of the leaf that references it, so the validator checks
/// everything but primitive-in-leaf containment (indices, preorder, each primitive once,
/// child boxes inside parents, bounds, slot rules). Out-of-range leaves and primitives are
/// skipped here and reported by the validator; an unreferenced primitive keeps the empty
/// box and is reported unreferenced.
fn leaf_boxes<N: TreeNode>(nodes: &[N], prim_indices: &[u32]) -> Vec<Aabb> {
    // The leaf table was read from the file, so this allocation is bounded by its size.
    let mut prims = vec![Aabb::EMPTY; prim_indices.len()];
    for n in nodes {
        for (slot, c) in n.child_refs().iter().enumerate() {
            if !c.is_leaf() {
                continue;
            }
            let first = c.index as usize;
            let Some(range) = prim_indices.get(first..first.saturating_add(c.count as usize))
            else {
                continue;
            };
            for &p in range {
                if let Some(b) = prims.get_mut(p as usize) {
                    *b = n.slot_aabb(slot);
                }
            }
        }
    }
    prims
}

/// Validates a tree read from a file (see [`leaf_boxes`]). Leaf sizes are not limited:
/// the file does not record the builder's maximum.
fn check_structure(tree: &Tree) -> Result<(), ValidationError> {
    match tree {
        Tree::Bvh2(t) => validate(t, &leaf_boxes(&t.nodes, &t.prim_indices), u32::MAX),
        Tree::Mbvh4(t) => validate_mbvh4(t, &leaf_boxes(&t.nodes, &t.prim_indices), u32::MAX),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::soup;
    use crate::{collapse, BinnedSahBuilder, LbvhBuilder, Mbvh4TopDownBuilder, SweepSahBuilder};

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

    fn sample4() -> Mbvh4 {
        Mbvh4TopDownBuilder::default()
            .build(&soup(500, 2.0, 7))
            .unwrap()
    }

    fn bytes4_of(t: &Mbvh4, name: &str) -> Vec<u8> {
        let mut v = Vec::new();
        write_mbvh4(t, name, &mut v).unwrap();
        v
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
        for bad in [0u8, 3, 255] {
            let mut v = bytes_of(&sample(), "b");
            v[8] = bad;
            assert!(matches!(
                read_bvh2(&v[..]),
                Err(IoError::UnsupportedVersion(x)) if x == bad as u32
            ));
        }
        for bad in [0u8, 3, 200] {
            let mut v = bytes_of(&sample(), "b");
            v[12] = bad;
            assert!(matches!(
                read_tree(&v[..]),
                Err(IoError::UnsupportedKind { kind, version: 2 }) if kind == bad as u32
            ));
        }
        // Version 1 knew only kind 1: a 4-wide tree in a version-1 file is rejected.
        let mut v = bytes4_of(&sample4(), "b");
        v[8] = 1;
        reseal(&mut v);
        assert!(matches!(
            read_tree(&v[..]),
            Err(IoError::UnsupportedKind {
                kind: 2,
                version: 1
            })
        ));
    }

    #[test]
    fn version_one_files_still_read() {
        // A version-1 file is a version-2 file of kind 1 with the old version number.
        let t = sample();
        let mut v = bytes_of(&t, "binned-sah");
        assert_eq!(u32_at(&v, 8), 2);
        v[8] = 1;
        reseal(&mut v);
        let (back, h) = read_bvh2(&v[..]).unwrap();
        assert_eq!(back, t);
        assert_eq!((h.version, h.kind), (1, TreeKind::Bvh2));
    }

    #[test]
    fn mbvh4_round_trips_and_either_kind_reads_as_a_tree() {
        let prims = soup(2000, 3.0, 1);
        let binned = BinnedSahBuilder::default().build(&prims).unwrap();
        let one = Mbvh4TopDownBuilder::default().build(&prims[..1]).unwrap();
        let trees = [
            (
                "mbvh4-topdown",
                Mbvh4TopDownBuilder::default().build(&prims).unwrap(),
            ),
            ("mbvh4-collapse", collapse(&binned).unwrap()),
            ("empty", Mbvh4::empty()),
            ("one", one),
        ];
        for (name, t) in trees {
            let v = bytes4_of(&t, name);
            assert_eq!(
                v.len(),
                header_bytes(name.len()) + 128 * t.nodes.len() + 4 * t.prim_indices.len() + 4
            );
            let (back, h) = read_mbvh4(&v[..]).unwrap();
            assert_eq!(back, t, "{name}");
            assert_eq!((h.kind, h.version), (TreeKind::Mbvh4, FORMAT_VERSION));
            assert_eq!(h.builder, name);
            assert_eq!(h.node_count as usize, t.nodes.len());
            assert!(h.sah == t.normalized_sah());
            let (any, _) = read_tree(&v[..]).unwrap();
            assert_eq!(any, Tree::Mbvh4(t.clone()));
            // Through `Tree`, byte for byte the same file.
            let mut w = Vec::new();
            write_tree(&any, name, &mut w).unwrap();
            assert_eq!(w, v);
            // Asking for the other kind names both.
            let e = read_bvh2(&v[..]).unwrap_err();
            assert!(matches!(
                e,
                IoError::WrongKind {
                    expected: TreeKind::Bvh2,
                    found: TreeKind::Mbvh4
                }
            ));
            assert!(e.to_string().contains("Mbvh4"), "{e}");
        }
        let v = bytes_of(&binned, "binned-sah");
        assert_eq!(read_tree(&v[..]).unwrap().0, Tree::Bvh2(binned));
        assert!(matches!(
            read_mbvh4(&v[..]),
            Err(IoError::WrongKind {
                expected: TreeKind::Mbvh4,
                found: TreeKind::Bvh2
            })
        ));
    }

    #[test]
    fn mbvh4_node_bytes_are_the_in_memory_layout() {
        let t = sample4();
        let v = bytes4_of(&t, "x");
        let h = header_bytes(1);
        let n = &t.nodes[0];
        // Structure of arrays: min x of the four children, ..., max z, then the refs.
        assert_eq!(f32_at(&v, h), n.min_x[0]);
        assert_eq!(f32_at(&v, h + 4), n.min_x[1]);
        assert_eq!(f32_at(&v, h + 16), n.min_y[0]);
        assert_eq!(f32_at(&v, h + 92), n.max_z[3]);
        assert_eq!(u32_at(&v, h + 96), n.children[0].index);
        assert_eq!(u32_at(&v, h + 124), n.children[3].count);
        assert_eq!(u32_at(&v, 12), 2);
        // The file's node bytes are the node's memory bytes (little-endian target).
        #[cfg(target_endian = "little")]
        {
            // SAFETY: `Node4` is `repr(C)` plain old data of 128 bytes without padding
            // (asserted in the mbvh4 module), so viewing it as bytes is sound.
            let mem = unsafe { std::slice::from_raw_parts(n as *const Node4 as *const u8, 128) };
            assert_eq!(&v[h..h + 128], mem);
        }
    }

    #[test]
    fn mbvh4_rejects_truncation_and_structural_corruption() {
        let t = sample4();
        let v = bytes4_of(&t, "mbvh4-topdown");
        for len in (0..v.len()).filter(|l| l % 11 == 0 || *l < 100 || v.len() - l < 100) {
            match read_tree(&v[..len]) {
                Err(IoError::Truncated(_)) | Err(IoError::BadMagic) => {}
                other => panic!("prefix {len}: {other:?}"),
            }
        }
        let h = header_bytes("mbvh4-topdown".len());
        let used = t.nodes[0].child_count();
        assert!(used >= 2);
        type Corrupt = Box<dyn Fn(&mut Vec<u8>)>;
        let cases: Vec<(&str, Corrupt)> = vec![
            (
                "child index out of range",
                Box::new(move |v| v[h + 96..h + 100].copy_from_slice(&999_999u32.to_le_bytes())),
            ),
            (
                "used slot after an empty one",
                Box::new(move |v| {
                    // Empty slot 0 (index u32::MAX, count 0): slots 1.. are still used.
                    v[h + 96..h + 104].copy_from_slice(&[255, 255, 255, 255, 0, 0, 0, 0]);
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
            let mut w = v.clone();
            corrupt(&mut w);
            reseal(&mut w);
            assert!(
                matches!(read_tree(&w[..]), Err(IoError::Invalid(_))),
                "{what}: {:?}",
                read_tree(&w[..])
            );
        }
        let mut w = v.clone();
        w[h + 7] ^= 1;
        assert!(matches!(read_tree(&w[..]), Err(IoError::Checksum { .. })));
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
        // Either kind through `Tree`, and the 4-wide writer, over the same path.
        let m = Tree::Mbvh4(sample4());
        write_tree_file(&m, "mbvh4-topdown", &path).unwrap();
        assert_eq!(read_tree_file(&path).unwrap().0, m);
        assert!(read_bvh2_file(&path).is_err());
        write_mbvh4_file(m.as_mbvh4().unwrap(), "x", &path).unwrap();
        assert_eq!(&read_mbvh4_file(&path).unwrap().0, m.as_mbvh4().unwrap());
        assert!(write_tree_file(&m, &long, &path).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
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

        /// The same for 4-wide files, read as either kind.
        #[test]
        fn corrupted_mbvh4_bytes_never_panic(pos in 0usize..4096, val in 0u8..=255, cut in 0usize..4096) {
            let t = Mbvh4TopDownBuilder::default().build(&soup(40, 2.0, 3)).unwrap();
            let mut v = bytes4_of(&t, "mbvh4-topdown");
            let p = pos % v.len();
            v[p] = val;
            if let Ok((back, _)) = read_tree(&v[..]) {
                proptest::prop_assert_eq!(back, Tree::Mbvh4(t.clone()));
            }
            reseal(&mut v);
            let _ = read_tree(&v[..]);
            let _ = read_mbvh4(&v[..cut % v.len()]);
        }
    }
}
