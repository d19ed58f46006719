//! Traversal logs: per ray, what traversal touched, in a compact binary file that streams
//! to disk. This is the input of the traversal hardware model, as in [P4] §3.2 ("a
//! software ray tracer draws scenes and generates, for each ray, logs of node visits and
//! stack operations in a compact binary format, which are then fed to an architecture
//! simulator").
//!
//! The format is documented in `docs/trace-log.md`. In short: a 64-byte header, then
//! chunks (`CHNK`, payload length, ray count, CRC-32 of the payload, payload), then a
//! trailer (`TEND`, chunk count, ray count, payload bytes). A payload is a sequence of
//! records, each a tag byte and fields; integers are LEB128 varints, node and leaf indices
//! are zigzag deltas. A ray's records are: `RAY`, its events in order (`NODE`, `PUSH_NODE`,
//! `PUSH_LEAF`, `POP`, `POP_CULLED`, `LEAF`), then `END`.
//!
//! [`LogEncoder`] is an [`Observer`] that encodes one tile's rays into memory;
//! [`LogWriter`] appends encoded chunks to a temporary file and renames it into place on
//! [`LogWriter::finish`], so a crash never leaves a truncated log under the final name.
//! [`LogReader`] decodes a file ray by ray, and [`summarize`] recomputes every counter of
//! [`RayStats`] from the events alone.
//!
//! Reading a damaged or hostile file (truncated anywhere, any bytes changed, chunk CRCs
//! forged to match) gives an error or data, never a panic: every length, count and index
//! is checked before use, index deltas that leave 32 bits are errors, a chunk is read only
//! as far as the file holds it, and [`summarize`]'s distinct-node count uses a bitmap over
//! the header's node count only when that bitmap is no larger than the file (plus 1 MiB),
//! a set of the nodes met otherwise, so no allocation grows with a corrupted count beyond
//! what the file's size justifies. Property tests (`tests_log.rs`) check this on logs
//! written by [`LogWriter`] for trees of width 2, 4 and 8.

use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{Hit, TraceError};
use bvh::ChildRef;
use geom::{Ray, Vec3};
use serde::Serialize;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// File magic.
pub const LOG_MAGIC: [u8; 8] = *b"ARBTRLOG";
/// Format version written and read.
pub const LOG_VERSION: u32 = 1;
/// Header size in bytes.
pub const HEADER_BYTES: usize = 64;
/// Largest chunk payload accepted when reading (a writer's chunk is one batch of tiles;
/// a larger length in a file is corruption, not data).
pub const MAX_CHUNK_BYTES: u32 = 1 << 30;

const CHUNK_TAG: [u8; 4] = *b"CHNK";
const END_TAG: [u8; 4] = *b"TEND";

const T_RAY: u8 = 0x01;
const T_NODE: u8 = 0x02;
const T_PUSH_NODE: u8 = 0x03;
const T_PUSH_LEAF: u8 = 0x04;
const T_POP: u8 = 0x05;
const T_POP_CULLED: u8 = 0x06;
const T_LEAF: u8 = 0x07;
const T_END: u8 = 0x08;
/// A node record whose child slots are all valid (no mask byte follows).
const T_NODE_FULL: u8 = 0x09;
/// A node record of a tree wider than four (the hit mask does not fit the tag's high
/// nibble): hit mask byte, valid mask byte, node delta.
const T_NODE_WIDE: u8 = 0x0A;

/// What kind of render produced a log.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LogRays {
    /// One primary ray per pixel.
    Primary,
    /// Diffuse path tracing (primary rays and bounces).
    Diffuse,
    /// Primary rays plus one occlusion ray per hit.
    Shadow,
}

impl LogRays {
    fn code(self) -> u8 {
        match self {
            LogRays::Primary => 0,
            LogRays::Diffuse => 1,
            LogRays::Shadow => 2,
        }
    }
    fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(LogRays::Primary),
            1 => Some(LogRays::Diffuse),
            2 => Some(LogRays::Shadow),
            _ => None,
        }
    }
}

/// The fixed header of a log.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct LogHeader {
    /// Tree width: 2 (`Bvh2`, CBVH), 4 (`Mbvh4`) or 8 (`Mbvh8`).
    pub width: u32,
    /// Bytes per node in memory (64 or 128): what a node fetch reads.
    pub node_bytes: u32,
    /// Nodes in the tree.
    pub node_count: u64,
    /// Leaf-table entries in the tree.
    pub leaf_entries: u64,
    /// Image width in pixels.
    pub image_width: u32,
    /// Image height in pixels.
    pub image_height: u32,
    /// The kind of rays.
    pub rays: LogRays,
    /// Bounce limit of the render.
    pub bounces: u8,
    /// The distance stack was on.
    pub distance_stack: bool,
    /// Sampling seed of the render.
    pub seed: u64,
}

impl LogHeader {
    fn encode(&self) -> [u8; HEADER_BYTES] {
        let mut h = [0u8; HEADER_BYTES];
        h[0..8].copy_from_slice(&LOG_MAGIC);
        h[8..12].copy_from_slice(&LOG_VERSION.to_le_bytes());
        h[12..16].copy_from_slice(&self.width.to_le_bytes());
        h[16..20].copy_from_slice(&self.node_bytes.to_le_bytes());
        h[20..28].copy_from_slice(&self.node_count.to_le_bytes());
        h[28..36].copy_from_slice(&self.leaf_entries.to_le_bytes());
        h[36..40].copy_from_slice(&self.image_width.to_le_bytes());
        h[40..44].copy_from_slice(&self.image_height.to_le_bytes());
        h[44] = self.rays.code();
        h[45] = self.bounces;
        h[46] = self.distance_stack as u8;
        h[48..56].copy_from_slice(&self.seed.to_le_bytes());
        h
    }

    fn decode(h: &[u8; HEADER_BYTES]) -> Result<Self, String> {
        if h[0..8] != LOG_MAGIC {
            return Err("bad magic (not an Arbor traversal log)".into());
        }
        let u32_at = |i: usize| u32::from_le_bytes(h[i..i + 4].try_into().unwrap());
        let u64_at = |i: usize| u64::from_le_bytes(h[i..i + 8].try_into().unwrap());
        let version = u32_at(8);
        if version != LOG_VERSION {
            return Err(format!(
                "version {version} (this reader reads {LOG_VERSION})"
            ));
        }
        let width = u32_at(12);
        if ![2, 4, 8].contains(&width) {
            return Err(format!("tree width {width} (expected 2, 4 or 8)"));
        }
        let rays = LogRays::from_code(h[44]).ok_or(format!("unknown ray kind {}", h[44]))?;
        if h[46] > 1 {
            return Err(format!("bad distance-stack flag {}", h[46]));
        }
        Ok(Self {
            width,
            node_bytes: u32_at(16),
            node_count: u64_at(20),
            leaf_entries: u64_at(28),
            image_width: u32_at(36),
            image_height: u32_at(40),
            rays,
            bounces: h[45],
            distance_stack: h[46] == 1,
            seed: u64_at(48),
        })
    }
}

#[inline]
fn put_varint(buf: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        buf.push((v as u8) | 0x80);
        v >>= 7;
    }
    buf.push(v as u8);
}

#[inline]
fn zigzag(d: i64) -> u64 {
    ((d << 1) ^ (d >> 63)) as u64
}

#[inline]
fn unzigzag(v: u64) -> i64 {
    ((v >> 1) as i64) ^ -((v & 1) as i64)
}

/// An [`Observer`] that encodes rays into an in-memory buffer (one tile's worth, then
/// handed to a [`LogWriter`] as a chunk). Set the ray's identity with
/// [`LogEncoder::set_ray`] before tracing it.
#[derive(Clone, Debug, Default)]
pub struct LogEncoder {
    buf: Vec<u8>,
    /// The mask of all child slots of the tree's width (0b11 or 0b1111).
    full: u8,
    rays: u32,
    pixel: u32,
    bounce: u8,
    last_node: u32,
    last_leaf: u32,
}

impl LogEncoder {
    /// An empty encoder for a tree of `width` children per node (2 or 4).
    pub fn new(width: u32) -> Self {
        Self {
            full: ((1u32 << width.min(8)) - 1) as u8,
            ..Self::default()
        }
    }

    /// The next ray traced is bounce `bounce` of the path of pixel `pixel` (row-major).
    pub fn set_ray(&mut self, pixel: u32, bounce: u8) {
        self.pixel = pixel;
        self.bounce = bounce;
    }

    /// The encoded bytes so far.
    pub fn bytes(&self) -> &[u8] {
        &self.buf
    }

    /// Rays encoded so far.
    pub fn rays(&self) -> u32 {
        self.rays
    }

    /// Takes the encoded bytes and ray count, leaving the encoder empty.
    pub fn take(&mut self) -> (Vec<u8>, u32) {
        let rays = std::mem::take(&mut self.rays);
        (std::mem::take(&mut self.buf), rays)
    }

    fn delta(&mut self, v: u32, base: u32) {
        put_varint(&mut self.buf, zigzag(v as i64 - base as i64));
    }
}

impl Observer for LogEncoder {
    fn begin(&mut self, ray: &Ray, query: Query) {
        self.rays += 1;
        self.last_node = 0;
        self.last_leaf = 0;
        self.buf.push(T_RAY);
        put_varint(&mut self.buf, self.pixel as u64);
        self.buf.push(self.bounce);
        self.buf.push(match query {
            Query::Closest => 0,
            Query::Any => 1,
        });
        for f in [
            ray.origin.x,
            ray.origin.y,
            ray.origin.z,
            ray.dir.x,
            ray.dir.y,
            ray.dir.z,
            ray.t_min,
            ray.t_max,
        ] {
            self.buf.extend_from_slice(&f.to_le_bytes());
        }
    }

    fn node(&mut self, node: u32, valid: u8, hit: u8) {
        if self.full > 0x0F {
            self.buf.push(T_NODE_WIDE);
            self.buf.push(hit);
            self.buf.push(valid);
        } else if valid == self.full {
            self.buf.push(T_NODE_FULL | (hit & 0x0F) << 4);
        } else {
            self.buf.push(T_NODE | (hit & 0x0F) << 4);
            self.buf.push(valid);
        }
        self.delta(node, self.last_node);
        self.last_node = node;
    }

    fn push(&mut self, child: ChildRef) {
        if child.is_leaf() {
            self.buf.push(T_PUSH_LEAF);
            self.delta(child.index, self.last_leaf);
            put_varint(&mut self.buf, child.count as u64);
        } else {
            self.buf.push(T_PUSH_NODE);
            self.delta(child.index, self.last_node);
        }
    }

    fn pop(&mut self, culled: bool) {
        self.buf.push(if culled { T_POP_CULLED } else { T_POP });
    }

    fn leaf(&mut self, first: u32, count: u32) {
        self.buf.push(T_LEAF);
        self.delta(first, self.last_leaf);
        put_varint(&mut self.buf, count as u64);
        self.last_leaf = first;
    }

    fn end(&mut self, hit: Option<&Hit>) {
        self.buf.push(T_END);
        match hit {
            None => self.buf.push(0),
            Some(h) => {
                self.buf.push(1);
                put_varint(&mut self.buf, h.leaf_entry as u64);
                put_varint(&mut self.buf, h.prim as u64);
                self.buf.extend_from_slice(&h.t.to_le_bytes());
            }
        }
    }
}

/// Writes a log file: the header at creation, chunks as they come, the trailer at
/// [`LogWriter::finish`]. Data goes to a temporary file beside the target, renamed into
/// place by `finish`; dropping the writer without finishing removes it.
pub struct LogWriter {
    file: Option<BufWriter<tempfile::NamedTempFile>>,
    path: PathBuf,
    chunks: u32,
    rays: u64,
    payload_bytes: u64,
}

fn io_err(path: &Path, source: std::io::Error) -> TraceError {
    TraceError::Io {
        path: path.display().to_string(),
        source,
    }
}

impl LogWriter {
    /// Starts a log at `path` (written in full only by [`LogWriter::finish`]).
    pub fn create(path: &Path, header: &LogHeader) -> Result<Self, TraceError> {
        let tmp =
            crate::image::temp_file_beside(path, ".arbor-log-").map_err(|e| io_err(path, e))?;
        let mut file = BufWriter::with_capacity(1 << 20, tmp);
        file.write_all(&header.encode())
            .map_err(|e| io_err(path, e))?;
        Ok(Self {
            file: Some(file),
            path: path.to_path_buf(),
            chunks: 0,
            rays: 0,
            payload_bytes: 0,
        })
    }

    /// Appends one chunk of `rays` encoded rays.
    pub fn write_chunk(&mut self, payload: &[u8], rays: u32) -> Result<(), TraceError> {
        if payload.is_empty() {
            return Ok(());
        }
        let len = u32::try_from(payload.len())
            .ok()
            .filter(|&l| l <= MAX_CHUNK_BYTES)
            .ok_or_else(|| {
                TraceError::Config(format!("log chunk of {} bytes is too large", payload.len()))
            })?;
        let f = self.file.as_mut().expect("writer used after finish");
        let mut head = [0u8; 16];
        head[0..4].copy_from_slice(&CHUNK_TAG);
        head[4..8].copy_from_slice(&len.to_le_bytes());
        head[8..12].copy_from_slice(&rays.to_le_bytes());
        head[12..16].copy_from_slice(&crc32fast::hash(payload).to_le_bytes());
        f.write_all(&head).map_err(|e| io_err(&self.path, e))?;
        f.write_all(payload).map_err(|e| io_err(&self.path, e))?;
        self.chunks += 1;
        self.rays += rays as u64;
        self.payload_bytes += payload.len() as u64;
        Ok(())
    }

    /// Writes the trailer and renames the file into place. Returns the file's size.
    pub fn finish(mut self) -> Result<u64, TraceError> {
        let mut f = self.file.take().expect("finish called once");
        let mut end = [0u8; 24];
        end[0..4].copy_from_slice(&END_TAG);
        end[4..8].copy_from_slice(&self.chunks.to_le_bytes());
        end[8..16].copy_from_slice(&self.rays.to_le_bytes());
        end[16..24].copy_from_slice(&self.payload_bytes.to_le_bytes());
        f.write_all(&end).map_err(|e| io_err(&self.path, e))?;
        let tmp = f
            .into_inner()
            .map_err(|e| io_err(&self.path, e.into_error()))?;
        tmp.as_file()
            .sync_all()
            .map_err(|e| io_err(&self.path, e))?;
        tmp.persist(&self.path)
            .map_err(|e| io_err(&self.path, e.error))?;
        Ok(HEADER_BYTES as u64 + self.chunks as u64 * 16 + self.payload_bytes + 24)
    }
}

/// One event of a logged ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogEvent {
    /// Inner node fetched; `valid` and `hit` are child-slot masks.
    Node {
        /// Node index.
        node: u32,
        /// Non-empty slots.
        valid: u8,
        /// Slots whose boxes were hit.
        hit: u8,
    },
    /// A child pushed onto the stack.
    Push(ChildRef),
    /// The top entry popped (`culled`: skipped by the distance test).
    Pop {
        /// Skipped by the distance stack.
        culled: bool,
    },
    /// A leaf visited: leaf-table entries `first .. first + count`.
    Leaf {
        /// First entry.
        first: u32,
        /// Entries.
        count: u32,
    },
}

/// The final hit of a logged ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoggedHit {
    /// Leaf-table entry of the hit.
    pub leaf_entry: u32,
    /// Primitive id.
    pub prim: u32,
    /// Distance.
    pub t: f32,
}

/// One ray of a log.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LoggedRay {
    /// Pixel index (row-major) of the path the ray belongs to.
    pub pixel: u32,
    /// Bounce number (0 = primary).
    pub bounce: u8,
    /// Any-hit (occlusion) rather than closest-hit.
    pub any_hit: bool,
    /// The ray.
    pub ray: Option<Ray>,
    /// Its events in order.
    pub events: Vec<LogEvent>,
    /// Its final hit.
    pub hit: Option<LoggedHit>,
}

/// Reads a log ray by ray, checking every chunk's CRC and the trailer.
pub struct LogReader {
    input: BufReader<std::fs::File>,
    path: String,
    header: LogHeader,
    chunk: Vec<u8>,
    pos: usize,
    chunk_rays_left: u32,
    chunks: u32,
    rays: u64,
    payload_bytes: u64,
    done: bool,
}

impl LogReader {
    /// Opens `path` and reads its header.
    pub fn open(path: &Path) -> Result<Self, TraceError> {
        let f = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
        let mut input = BufReader::with_capacity(1 << 20, f);
        let mut h = [0u8; HEADER_BYTES];
        let name = path.display().to_string();
        input.read_exact(&mut h).map_err(|e| TraceError::BadLog {
            path: name.clone(),
            message: format!("cannot read the header: {e}"),
        })?;
        let header = LogHeader::decode(&h).map_err(|message| TraceError::BadLog {
            path: name.clone(),
            message,
        })?;
        Ok(Self {
            input,
            path: name,
            header,
            chunk: Vec::new(),
            pos: 0,
            chunk_rays_left: 0,
            chunks: 0,
            rays: 0,
            payload_bytes: 0,
            done: false,
        })
    }

    /// The header.
    pub fn header(&self) -> &LogHeader {
        &self.header
    }

    fn bad(&self, message: impl Into<String>) -> TraceError {
        TraceError::BadLog {
            path: self.path.clone(),
            message: message.into(),
        }
    }

    /// Loads the next chunk; false at the trailer (after checking it).
    fn next_chunk(&mut self) -> Result<bool, TraceError> {
        let mut tag = [0u8; 4];
        self.input
            .read_exact(&mut tag)
            .map_err(|_| self.bad("truncated (no trailer)"))?;
        if tag == END_TAG {
            let mut end = [0u8; 20];
            self.input
                .read_exact(&mut end)
                .map_err(|_| self.bad("truncated trailer"))?;
            let chunks = u32::from_le_bytes(end[0..4].try_into().unwrap());
            let rays = u64::from_le_bytes(end[4..12].try_into().unwrap());
            let bytes = u64::from_le_bytes(end[12..20].try_into().unwrap());
            if (chunks, rays, bytes) != (self.chunks, self.rays, self.payload_bytes) {
                return Err(self.bad(format!(
                    "trailer says {chunks} chunks, {rays} rays, {bytes} bytes; read {}, {}, {}",
                    self.chunks, self.rays, self.payload_bytes
                )));
            }
            let mut extra = [0u8; 1];
            if self
                .input
                .read(&mut extra)
                .map_err(|e| self.bad(e.to_string()))?
                != 0
            {
                return Err(self.bad("data after the trailer"));
            }
            self.done = true;
            return Ok(false);
        }
        if tag != CHUNK_TAG {
            return Err(self.bad(format!("bad chunk tag {tag:?}")));
        }
        let mut head = [0u8; 12];
        self.input
            .read_exact(&mut head)
            .map_err(|_| self.bad("truncated chunk header"))?;
        let len = u32::from_le_bytes(head[0..4].try_into().unwrap());
        let rays = u32::from_le_bytes(head[4..8].try_into().unwrap());
        let crc = u32::from_le_bytes(head[8..12].try_into().unwrap());
        if len > MAX_CHUNK_BYTES {
            return Err(self.bad(format!("chunk of {len} bytes (limit {MAX_CHUNK_BYTES})")));
        }
        self.chunk.clear();
        (&mut self.input)
            .take(len as u64)
            .read_to_end(&mut self.chunk)
            .map_err(|e| self.bad(e.to_string()))?;
        if self.chunk.len() != len as usize {
            return Err(self.bad("truncated chunk"));
        }
        if crc32fast::hash(&self.chunk) != crc {
            return Err(self.bad(format!("chunk {} fails its CRC check", self.chunks)));
        }
        self.pos = 0;
        self.chunk_rays_left = rays;
        self.chunks += 1;
        self.rays += rays as u64;
        self.payload_bytes += len as u64;
        Ok(true)
    }

    fn byte(&mut self) -> Result<u8, TraceError> {
        let b = *self
            .chunk
            .get(self.pos)
            .ok_or_else(|| self.bad("record runs past its chunk"))?;
        self.pos += 1;
        Ok(b)
    }

    fn varint(&mut self) -> Result<u64, TraceError> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.byte()?;
            v |= ((b & 0x7F) as u64) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(self.bad("varint longer than 64 bits"))
    }

    fn u32_varint(&mut self) -> Result<u32, TraceError> {
        let v = self.varint()?;
        u32::try_from(v).map_err(|_| self.bad(format!("value {v} exceeds 32 bits")))
    }

    fn delta(&mut self, base: u32) -> Result<u32, TraceError> {
        let d = unzigzag(self.varint()?);
        (base as i64)
            .checked_add(d)
            .and_then(|v| u32::try_from(v).ok())
            .ok_or_else(|| self.bad("index delta out of range"))
    }

    fn f32(&mut self) -> Result<f32, TraceError> {
        let mut b = [0u8; 4];
        for x in b.iter_mut() {
            *x = self.byte()?;
        }
        Ok(f32::from_le_bytes(b))
    }

    /// Reads the next ray into `out`; false at the end of the log.
    pub fn next_ray(&mut self, out: &mut LoggedRay) -> Result<bool, TraceError> {
        while self.chunk_rays_left == 0 || self.pos >= self.chunk.len() {
            if self.done {
                return Ok(false);
            }
            if self.chunk_rays_left != 0 || self.pos < self.chunk.len() {
                return Err(self.bad("chunk ray count does not match its records"));
            }
            if !self.next_chunk()? {
                return Ok(false);
            }
        }
        if self.byte()? != T_RAY {
            return Err(self.bad("ray record expected"));
        }
        out.pixel = self.u32_varint()?;
        out.bounce = self.byte()?;
        out.any_hit = match self.byte()? {
            0 => false,
            1 => true,
            q => return Err(self.bad(format!("unknown query {q}"))),
        };
        let mut v = [0f32; 8];
        for x in v.iter_mut() {
            *x = self.f32()?;
        }
        out.ray = Some(Ray::with_range(
            Vec3::new(v[0], v[1], v[2]),
            Vec3::new(v[3], v[4], v[5]),
            v[6],
            v[7],
        ));
        out.events.clear();
        out.hit = None;
        let (mut last_node, mut last_leaf) = (0u32, 0u32);
        let full = ((1u32 << self.header.width) - 1) as u8;
        loop {
            let tag = self.byte()?;
            let ev = match tag & 0x0F {
                T_NODE_WIDE if tag == T_NODE_WIDE => {
                    let hit = self.byte()?;
                    let valid = self.byte()?;
                    let node = self.delta(last_node)?;
                    last_node = node;
                    LogEvent::Node { node, valid, hit }
                }
                kind @ (T_NODE | T_NODE_FULL) => {
                    let valid = if kind == T_NODE { self.byte()? } else { full };
                    let node = self.delta(last_node)?;
                    last_node = node;
                    LogEvent::Node {
                        node,
                        valid,
                        hit: tag >> 4,
                    }
                }
                T_PUSH_NODE if tag == T_PUSH_NODE => {
                    LogEvent::Push(ChildRef::inner(self.delta(last_node)?))
                }
                T_PUSH_LEAF if tag == T_PUSH_LEAF => {
                    let first = self.delta(last_leaf)?;
                    let count = self.u32_varint()?;
                    LogEvent::Push(ChildRef::leaf(first, count))
                }
                T_POP if tag == T_POP => LogEvent::Pop { culled: false },
                T_POP_CULLED if tag == T_POP_CULLED => LogEvent::Pop { culled: true },
                T_LEAF if tag == T_LEAF => {
                    let first = self.delta(last_leaf)?;
                    let count = self.u32_varint()?;
                    last_leaf = first;
                    LogEvent::Leaf { first, count }
                }
                T_END if tag == T_END => {
                    out.hit = match self.byte()? {
                        0 => None,
                        1 => Some(LoggedHit {
                            leaf_entry: self.u32_varint()?,
                            prim: self.u32_varint()?,
                            t: self.f32()?,
                        }),
                        b => return Err(self.bad(format!("bad hit flag {b}"))),
                    };
                    break;
                }
                _ => return Err(self.bad(format!("unknown record tag {tag:#04x}"))),
            };
            out.events.push(ev);
        }
        self.chunk_rays_left -= 1;
        Ok(true)
    }
}

/// Totals of a log, recomputed from its events alone.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LogSummary {
    /// The header.
    pub header: Option<LogHeader>,
    /// Counters over all rays (the same quantities the tracer counts).
    pub total: RayStats,
    /// Counters per bounce (index 0 = primary rays).
    pub per_bounce: Vec<RayStats>,
    /// Distinct nodes fetched at least once.
    pub distinct_nodes: u64,
    /// Bytes of node data fetched (node fetches times the node size).
    pub node_bytes_fetched: u64,
    /// File size in bytes.
    pub file_bytes: u64,
}

/// Reads the whole log at `path` and recomputes the tracer's counters from its events:
/// node visits and box tests from `NODE` records (one test per valid slot), triangle tests
/// from `LEAF` records (cut short at the hit for an any-hit ray), pushes and pops, and the
/// deepest stack by replaying pushes and pops. Checks that the events are consistent (a
/// pop never empties an empty stack, and after a pop the next fetch is the popped entry).
pub fn summarize(path: &Path) -> Result<LogSummary, TraceError> {
    let mut r = LogReader::open(path)?;
    let header = *r.header();
    let file_bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let mut seen = NodeSet::new(header.node_count, file_bytes);
    let mut s = LogSummary {
        header: Some(header),
        ..Default::default()
    };
    let mut ray = LoggedRay::default();
    let mut stack: Vec<ChildRef> = Vec::new();
    while r.next_ray(&mut ray)? {
        let mut st = RayStats {
            rays: 1,
            hits: ray.hit.is_some() as u64,
            ..Default::default()
        };
        stack.clear();
        // The entry just popped, which the next fetch must be.
        let mut expect: Option<ChildRef> = None;
        let mut last_leaf: Option<(u32, u32)> = None;
        for ev in &ray.events {
            match *ev {
                LogEvent::Node { node, valid, .. } => {
                    if let Some(e) = expect.take() {
                        if !(e.is_inner() && e.index == node) {
                            return Err(r.bad(format!(
                                "pixel {}: popped {e:?} but fetched node {node}",
                                ray.pixel
                            )));
                        }
                    }
                    st.node_visits += 1;
                    st.box_tests += valid.count_ones() as u64;
                    seen.insert(node);
                }
                LogEvent::Push(c) => {
                    st.pushes += 1;
                    stack.push(c);
                    st.max_stack_depth = st.max_stack_depth.max(stack.len() as u64);
                }
                LogEvent::Pop { culled } => {
                    let top = stack.pop().ok_or_else(|| {
                        r.bad(format!("pixel {}: pop from an empty stack", ray.pixel))
                    })?;
                    if culled {
                        st.culled_pops += 1;
                    } else {
                        st.pops += 1;
                        expect = Some(top);
                    }
                }
                LogEvent::Leaf { first, count } => {
                    if let Some(e) = expect.take() {
                        if !(e.is_leaf() && e.index == first && e.count == count) {
                            return Err(r.bad(format!(
                                "pixel {}: popped {e:?} but visited leaf {first}+{count}",
                                ray.pixel
                            )));
                        }
                    }
                    st.leaf_visits += 1;
                    st.tri_tests += count as u64;
                    last_leaf = Some((first, count));
                }
            }
        }
        if let (true, Some(h), Some((first, count))) = (ray.any_hit, ray.hit, last_leaf) {
            // An any-hit ray stops at its hit, inside the last leaf.
            let tested = (h.leaf_entry as u64 + 1).saturating_sub(first as u64);
            st.tri_tests -= count as u64 - tested.min(count as u64);
        }
        let b = ray.bounce as usize;
        if s.per_bounce.len() <= b {
            s.per_bounce.resize(b + 1, RayStats::default());
        }
        s.per_bounce[b].add(&st);
        s.total.add(&st);
    }
    s.distinct_nodes = seen.len();
    s.node_bytes_fetched = s.total.node_visits * header.node_bytes as u64;
    s.file_bytes = file_bytes;
    Ok(s)
}

/// The distinct node indices below a log's node count that its `NODE` records name, in
/// memory bounded by the file: a bitmap over the node count when it is no larger than the
/// file (plus 1 MiB), otherwise the set of the nodes actually met, which grows with the
/// records read. (The node count comes from the header: a corrupted one must not turn
/// into a huge allocation.)
#[derive(Debug)]
pub(crate) enum NodeSet {
    /// One bit per node.
    Bits(Vec<u64>, u64),
    /// The nodes met, when a bitmap would outgrow the file.
    Sparse(std::collections::HashSet<u32>, u64),
}

impl NodeSet {
    pub(crate) fn new(node_count: u64, file_bytes: u64) -> Self {
        // Node indices are 32-bit: no more nodes can be named.
        let node_count = node_count.min(1 << 32);
        let bitmap_bytes = node_count.div_ceil(64) * 8;
        if bitmap_bytes <= file_bytes.saturating_add(1 << 20) {
            NodeSet::Bits(vec![0; node_count.div_ceil(64) as usize], node_count)
        } else {
            NodeSet::Sparse(Default::default(), node_count)
        }
    }

    /// Records `node` (ignored at or beyond the node count).
    #[inline]
    pub(crate) fn insert(&mut self, node: u32) {
        match self {
            NodeSet::Bits(w, n) => {
                if (node as u64) < *n {
                    w[node as usize / 64] |= 1 << (node % 64);
                }
            }
            NodeSet::Sparse(set, n) => {
                if (node as u64) < *n {
                    set.insert(node);
                }
            }
        }
    }

    /// Distinct nodes recorded.
    pub(crate) fn len(&self) -> u64 {
        match self {
            NodeSet::Bits(w, _) => w.iter().map(|w| w.count_ones() as u64).sum(),
            NodeSet::Sparse(set, _) => set.len() as u64,
        }
    }
}
