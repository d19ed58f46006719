//! Raw data access for the glTF loader: the GLB container, buffer resolution (GLB binary
//! chunk, `data:` URIs, sibling `.bin` files) and bounds-checked accessor decoding.
//!
//! The `gltf` crate's own readers index buffers without checking that a buffer holds its
//! declared `byteLength` or that an accessor fits its view, so every byte range here is
//! checked (with overflow-safe arithmetic) *before* it is read, and no allocation is sized
//! by a count that the actual data does not back.

use crate::SceneError;
use base64::Engine as _;
use gltf::accessor::{DataType, Dimensions};
use gltf::Accessor;
use std::cell::Cell;
use std::io::Read as _;
use std::path::{Component, Path, PathBuf};

/// Most elements an accessor without a buffer view (implicitly all zeros, usually the
/// base of a sparse accessor) may have: such a count is backed by no data, so it is capped.
const MAX_ZERO_ACCESSOR_ELEMENTS: usize = 1 << 24;

/// How many times over the buffers' bytes may be decoded in total (see [`Reader::new`]).
const DECODE_BUDGET_FACTOR: u64 = 64;
/// Decode allowance independent of the buffer size (covers accessors without views).
const DECODE_BUDGET_SLACK: u64 = 1 << 28;

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// The two parts of a GLB file.
#[derive(Debug)]
pub(super) struct Glb<'a> {
    /// The JSON chunk.
    pub json: &'a [u8],
    /// The binary chunk, when present.
    pub bin: Option<&'a [u8]>,
}

fn le_u32(b: &[u8], at: usize) -> Option<u32> {
    let s = b.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// True when `bytes` starts like a GLB file (otherwise it is treated as JSON).
pub(super) fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(GLB_MAGIC)
}

/// Splits a GLB file into its chunks. Our own parser: the `gltf` crate's one underflows
/// on a header length below 12.
pub(super) fn parse_glb(bytes: &[u8]) -> Result<Glb<'_>, String> {
    let version = le_u32(bytes, 4).ok_or("truncated GLB header (need 12 bytes)")?;
    let length = le_u32(bytes, 8).ok_or("truncated GLB header (need 12 bytes)")? as usize;
    if version != 2 {
        return Err(format!("unsupported GLB version {version} (expected 2)"));
    }
    if length < 12 || length > bytes.len() {
        return Err(format!(
            "GLB header declares {length} bytes but the file has {}",
            bytes.len()
        ));
    }
    let body = &bytes[..length];
    let mut at = 12usize;
    let mut json = None;
    let mut bin = None;
    while at < body.len() {
        let (Some(len), Some(ty)) = (le_u32(body, at), le_u32(body, at + 4)) else {
            return Err(format!("truncated GLB chunk header at byte {at}"));
        };
        let start = at + 8;
        let end = start
            .checked_add(len as usize)
            .filter(|&e| e <= body.len())
            .ok_or_else(|| {
                format!(
                    "GLB chunk at byte {at} declares {len} bytes but only {} remain",
                    body.len().saturating_sub(start)
                )
            })?;
        let data = &body[start..end];
        match ty {
            CHUNK_JSON if json.is_none() && at == 12 => json = Some(data),
            CHUNK_BIN if bin.is_none() && json.is_some() => bin = Some(data),
            _ if at == 12 => return Err("GLB first chunk is not JSON".into()),
            // The spec says readers ignore chunks of unknown type.
            _ => {}
        }
        // Chunks are 4-byte aligned; a missing pad at the very end is tolerated.
        at = end.saturating_add(3) & !3;
    }
    let json = json.ok_or("GLB has no JSON chunk")?;
    Ok(Glb { json, bin })
}

/// Decodes `%XX` escapes of a URI reference.
fn percent_decode(s: &str) -> Result<String, String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| format!("bad percent escape in uri '{s}'"))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| format!("uri '{s}' is not UTF-8 after decoding"))
}

/// The bytes of every buffer, indexed like `document.buffers()`, each at least as long as
/// its declared `byteLength`.
pub(super) fn resolve_buffers(
    doc: &gltf::Document,
    bin: Option<&[u8]>,
    base_dir: Option<&Path>,
    path: &Path,
) -> Result<Vec<Vec<u8>>, SceneError> {
    let mut out = Vec::new();
    for buf in doc.buffers() {
        let i = buf.index();
        let want = buf.length();
        let data = match buf.source() {
            gltf::buffer::Source::Bin => {
                if i != 0 {
                    return Err(SceneError::malformed(
                        path,
                        format!(
                            "buffer {i} has no uri (only buffer 0 may use the GLB binary chunk)"
                        ),
                    ));
                }
                bin.ok_or_else(|| {
                    SceneError::malformed(
                        path,
                        "buffer 0 has no uri and there is no GLB binary chunk",
                    )
                })?
                .to_vec()
            }
            gltf::buffer::Source::Uri(uri) => load_uri(uri, want, base_dir, path, i)?,
        };
        if data.len() < want {
            return Err(SceneError::malformed(
                path,
                format!(
                    "buffer {i} declares byteLength {want} but holds only {} bytes",
                    data.len()
                ),
            ));
        }
        out.push(data);
    }
    Ok(out)
}

fn load_uri(
    uri: &str,
    want: usize,
    base_dir: Option<&Path>,
    path: &Path,
    i: usize,
) -> Result<Vec<u8>, SceneError> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) = rest.split_once(";base64,").ok_or_else(|| {
            SceneError::unsupported(path, format!("buffer {i}: data uri is not base64"))
        })?;
        let engine = base64::engine::GeneralPurpose::new(
            &base64::alphabet::STANDARD,
            base64::engine::GeneralPurposeConfig::new()
                .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent)
                .with_decode_allow_trailing_bits(true),
        );
        return engine.decode(payload.trim()).map_err(|e| {
            SceneError::malformed(path, format!("buffer {i}: bad base64 data uri: {e}"))
        });
    }
    let rel =
        percent_decode(uri).map_err(|m| SceneError::malformed(path, format!("buffer {i}: {m}")))?;
    let rel_path = PathBuf::from(&rel);
    let escapes = rel.contains("://")
        || rel.contains(':')
        || rel.starts_with('\\')
        || rel_path
            .components()
            .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir));
    if rel.is_empty() || escapes {
        return Err(SceneError::unsupported(
            path,
            format!("buffer {i}: uri '{uri}' is not a relative path inside the file's directory"),
        ));
    }
    let dir = base_dir.ok_or_else(|| {
        SceneError::unsupported(
            path,
            format!("buffer {i}: external uri '{uri}' but no base directory to resolve it"),
        )
    })?;
    let file = dir.join(&rel_path);
    let f = std::fs::File::open(&file).map_err(|e| {
        SceneError::malformed(
            path,
            format!("buffer {i}: cannot open '{}': {e}", file.display()),
        )
    })?;
    // Read no more than declared: a huge unrelated file costs nothing.
    let mut data = Vec::new();
    f.take(want as u64).read_to_end(&mut data).map_err(|e| {
        SceneError::malformed(
            path,
            format!("buffer {i}: cannot read '{}': {e}", file.display()),
        )
    })?;
    Ok(data)
}

/// Decodes accessors from resolved buffers, naming the file in every error.
pub(super) struct Reader<'a> {
    /// The file, for error messages.
    path: &'a Path,
    /// Resolved buffers.
    buffers: &'a [Vec<u8>],
    /// Bytes of element data still allowed to be decoded (see [`Reader::new`]).
    budget: Cell<u64>,
}

/// How a component of an accessor becomes a float.
fn to_f32(b: &[u8], dt: DataType, normalized: bool) -> f32 {
    match dt {
        DataType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        DataType::U8 if normalized => b[0] as f32 / 255.0,
        DataType::U8 => b[0] as f32,
        DataType::I8 if normalized => (b[0] as i8 as f32 / 127.0).max(-1.0),
        DataType::I8 => b[0] as i8 as f32,
        DataType::U16 if normalized => u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0,
        DataType::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
        DataType::I16 if normalized => {
            (i16::from_le_bytes([b[0], b[1]]) as f32 / 32767.0).max(-1.0)
        }
        DataType::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
        DataType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
    }
}

fn to_u32(b: &[u8], dt: DataType) -> u32 {
    match dt {
        DataType::U8 => b[0] as u32,
        DataType::U16 => u16::from_le_bytes([b[0], b[1]]) as u32,
        _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
    }
}

fn dims_name(d: Dimensions) -> &'static str {
    match d {
        Dimensions::Scalar => "SCALAR",
        Dimensions::Vec2 => "VEC2",
        Dimensions::Vec3 => "VEC3",
        Dimensions::Vec4 => "VEC4",
        Dimensions::Mat2 => "MAT2",
        Dimensions::Mat3 => "MAT3",
        Dimensions::Mat4 => "MAT4",
    }
}

impl<'a> Reader<'a> {
    /// A reader over `buffers`. Many accessors may reference the same bytes, so a small
    /// JSON could make the loader decode one large buffer millions of times; the total
    /// decoded is capped at [`DECODE_BUDGET_FACTOR`] times the buffer bytes (plus
    /// [`DECODE_BUDGET_SLACK`]), far above what any real file needs.
    pub fn new(path: &'a Path, buffers: &'a [Vec<u8>]) -> Self {
        let total: u64 = buffers.iter().map(|b| b.len() as u64).sum();
        Reader {
            path,
            buffers,
            budget: Cell::new(total.saturating_mul(DECODE_BUDGET_FACTOR) + DECODE_BUDGET_SLACK),
        }
    }

    fn charge(&self, what: &str, bytes: u64) -> Result<(), SceneError> {
        let left = self.budget.get();
        if bytes > left {
            return Err(self.err(format!(
                "{what}: accessors reference the buffers more than {DECODE_BUDGET_FACTOR} times over"
            )));
        }
        self.budget.set(left - bytes);
        Ok(())
    }

    fn err(&self, msg: String) -> SceneError {
        SceneError::malformed(self.path, msg)
    }

    /// The checked byte range of `count` elements of `elem` bytes at `offset` in `view`:
    /// (buffer slice from the first element, stride).
    fn view_range(
        &self,
        what: &str,
        view: &gltf::buffer::View,
        offset: usize,
        count: usize,
        elem: usize,
    ) -> Result<(&[u8], usize), SceneError> {
        let buf = self.buffers.get(view.buffer().index()).ok_or_else(|| {
            self.err(format!(
                "{what}: buffer view {} has no buffer",
                view.index()
            ))
        })?;
        let stride = view.stride().unwrap_or(elem);
        if stride < elem {
            return Err(self.err(format!(
                "{what}: buffer view {} stride {stride} is less than the element size {elem}",
                view.index()
            )));
        }
        let view_end = (view.offset() as u64) + (view.length() as u64);
        if view_end > buf.len() as u64 {
            return Err(self.err(format!(
                "{what}: buffer view {} ends at byte {view_end} past its buffer ({} bytes)",
                view.index(),
                buf.len()
            )));
        }
        let start = view.offset() as u64 + offset as u64;
        let need = if count == 0 {
            0
        } else {
            (stride as u64)
                .checked_mul(count as u64 - 1)
                .and_then(|x| x.checked_add(elem as u64))
                .unwrap_or(u64::MAX)
        };
        if start.saturating_add(need) > view_end {
            return Err(self.err(format!(
                "{what}: {count} elements of {elem} bytes (stride {stride}) at offset {offset} \
                 do not fit buffer view {} ({} bytes)",
                view.index(),
                view.length()
            )));
        }
        Ok((&buf[start as usize..view_end as usize], stride))
    }

    /// Decodes an accessor element by element, `comps` components each, with `conv`.
    /// `dims` lists the accepted accessor types and `types` the component types.
    fn decode<T: Copy + Default>(
        &self,
        what: &str,
        acc: &Accessor,
        dims: &[Dimensions],
        types: &[DataType],
        conv: impl Fn(&[u8], DataType, bool) -> T,
    ) -> Result<(Vec<T>, usize), SceneError> {
        let what = format!("{what} (accessor {})", acc.index());
        let (d, dt) = (acc.dimensions(), acc.data_type());
        if !dims.contains(&d) {
            return Err(self.err(format!("{what}: unexpected accessor type {}", dims_name(d))));
        }
        if !types.contains(&dt) {
            return Err(self.err(format!("{what}: unexpected component type {dt:?}")));
        }
        let comps = d.multiplicity();
        let csize = dt.size();
        let elem = comps * csize;
        let count = acc.count();
        let normalized = acc.normalized();
        let charge = (count as u64).saturating_mul(elem as u64);
        let mut out: Vec<T> = match acc.view() {
            Some(view) => {
                let (bytes, stride) = self.view_range(&what, &view, acc.offset(), count, elem)?;
                self.charge(&what, charge)?;
                let mut v = Vec::with_capacity(count * comps);
                for e in 0..count {
                    let base = e * stride;
                    for c in 0..comps {
                        let at = base + c * csize;
                        v.push(conv(&bytes[at..at + csize], dt, normalized));
                    }
                }
                v
            }
            None => {
                if count > MAX_ZERO_ACCESSOR_ELEMENTS {
                    return Err(self.err(format!(
                        "{what}: {count} elements without a buffer view (limit {MAX_ZERO_ACCESSOR_ELEMENTS})"
                    )));
                }
                self.charge(&what, charge)?;
                vec![T::default(); count * comps]
            }
        };
        if let Some(sparse) = acc.sparse() {
            let n = sparse.count();
            if n > count {
                return Err(self.err(format!("{what}: sparse count {n} exceeds count {count}")));
            }
            let ind = sparse.indices();
            let it = match ind.index_type() {
                gltf::accessor::sparse::IndexType::U8 => DataType::U8,
                gltf::accessor::sparse::IndexType::U16 => DataType::U16,
                gltf::accessor::sparse::IndexType::U32 => DataType::U32,
            };
            let (ib, istride) = self.view_range(
                &format!("{what} sparse indices"),
                &ind.view(),
                ind.offset(),
                n,
                it.size(),
            )?;
            let vals = sparse.values();
            let (vb, vstride) = self.view_range(
                &format!("{what} sparse values"),
                &vals.view(),
                vals.offset(),
                n,
                elem,
            )?;
            for k in 0..n {
                let at = k * istride;
                let idx = to_u32(&ib[at..at + it.size()], it) as usize;
                if idx >= count {
                    return Err(
                        self.err(format!("{what}: sparse index {idx} out of range ({count})"))
                    );
                }
                for c in 0..comps {
                    let at = k * vstride + c * csize;
                    out[idx * comps + c] = conv(&vb[at..at + csize], dt, normalized);
                }
            }
        }
        Ok((out, comps))
    }

    /// Floats of an accessor (normalized integers mapped per the spec, plain integers cast),
    /// flattened, with the number of components per element.
    pub fn floats(
        &self,
        what: &str,
        acc: &Accessor,
        dims: &[Dimensions],
    ) -> Result<(Vec<f32>, usize), SceneError> {
        use DataType::*;
        self.decode(what, acc, dims, &[F32, U8, I8, U16, I16, U32], to_f32)
    }

    /// Non-negative integers of an accessor (u8, u16 or u32 components), flattened.
    pub fn uints(
        &self,
        what: &str,
        acc: &Accessor,
        dims: &[Dimensions],
    ) -> Result<(Vec<u32>, usize), SceneError> {
        use DataType::*;
        self.decode(what, acc, dims, &[U8, U16, U32], |b, dt, _| to_u32(b, dt))
    }

    /// Float-only accessor (animation times, inverse bind matrices).
    pub fn f32s(
        &self,
        what: &str,
        acc: &Accessor,
        dims: &[Dimensions],
    ) -> Result<(Vec<f32>, usize), SceneError> {
        self.decode(what, acc, dims, &[DataType::F32], to_f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decode_budget_is_bounded_by_buffer_size() {
        let bufs = vec![vec![0u8; 1000]];
        let r = Reader::new(Path::new("x.glb"), &bufs);
        let total = 1000 * DECODE_BUDGET_FACTOR + DECODE_BUDGET_SLACK;
        assert!(r.charge("a", total - 10).is_ok());
        assert!(r.charge("a", 10).is_ok());
        let e = r.charge("accessor 3", 1).unwrap_err().to_string();
        assert!(e.contains("x.glb") && e.contains("accessor 3"), "{e}");
    }

    #[test]
    fn glb_chunks() {
        let mut g = b"glTF\x02\0\0\0\0\0\0\0".to_vec();
        g.extend_from_slice(&2u32.to_le_bytes());
        g.extend_from_slice(&CHUNK_JSON.to_le_bytes());
        g.extend_from_slice(b"{}");
        // An unknown chunk type is skipped (after 4-byte alignment), then the BIN chunk.
        g.extend_from_slice(&[0, 0]);
        g.extend_from_slice(&1u32.to_le_bytes());
        g.extend_from_slice(b"XTRA");
        g.extend_from_slice(&[9, 0, 0, 0]);
        g.extend_from_slice(&3u32.to_le_bytes());
        g.extend_from_slice(&CHUNK_BIN.to_le_bytes());
        g.extend_from_slice(&[1, 2, 3]);
        let n = g.len() as u32;
        g[8..12].copy_from_slice(&n.to_le_bytes());
        let glb = parse_glb(&g).unwrap();
        assert_eq!(glb.json, b"{}");
        assert_eq!(glb.bin, Some(&[1u8, 2, 3][..]));
        // Declared length larger than the data, smaller than the header, bad version.
        let mut long = g.clone();
        long[8..12].copy_from_slice(&(n + 1).to_le_bytes());
        assert!(parse_glb(&long).unwrap_err().contains("declares"));
        let mut short = g.clone();
        short[8..12].copy_from_slice(&4u32.to_le_bytes());
        assert!(parse_glb(&short).is_err());
        let mut v1 = g.clone();
        v1[4] = 1;
        assert!(parse_glb(&v1).unwrap_err().contains("version"));
        // First chunk not JSON.
        let mut bin_first = g.clone();
        bin_first[16..20].copy_from_slice(&CHUNK_BIN.to_le_bytes());
        assert!(parse_glb(&bin_first).is_err());
    }

    #[test]
    fn percent_decoding() {
        assert_eq!(percent_decode("a%20b.bin").unwrap(), "a b.bin");
        assert!(percent_decode("a%2").is_err());
        assert!(percent_decode("a%zz").is_err());
        assert!(percent_decode("%ff").is_err());
    }
}
