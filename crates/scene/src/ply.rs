//! PLY (Stanford polygon file) loader and writer: ASCII, binary little-endian and binary
//! big-endian.
//!
//! Scanned models and converted scenes arrive as PLY, often large (millions of faces), so the
//! binary path is built for speed: when `vertex` holds only scalar properties its records
//! have a fixed size and x, y, z are read at fixed offsets in one tight loop, and the common
//! `list uchar int vertex_indices` face layout has its own loop. Any other layout (extra
//! properties, lists in odd places, other scalar types) goes through a general per-property
//! walk. Only `x, y, z` of `vertex` and `vertex_indices` (or `vertex_index`) of `face` are
//! kept; every other element and property is skipped.
//!
//! Hostile input: every element count is checked against the bytes left before anything is
//! allocated (binary: `count * minimum record size`; ASCII: every value needs at least two
//! bytes), every index is range-checked, and truncation is reported with the element name
//! and record number. ASCII data is read as a stream of whitespace-separated tokens (the
//! line breaks between records are not required).
//!
//! Faces with more than three vertices are fan-triangulated; faces with fewer are an error.
//! Triangles referencing non-finite vertices are dropped (see the crate's NaN policy).

use crate::{LoadOptions, LoadedMesh, Mesh, SceneError};
use geom::Vec3;
use std::io::Write;
use std::path::Path;

/// Loads a PLY file.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<LoadedMesh, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    parse(&bytes, path, opts)
}

/// Parses PLY file contents; `path` only names the file in errors.
pub fn parse(bytes: &[u8], path: &Path, opts: &LoadOptions) -> Result<LoadedMesh, SceneError> {
    let header = parse_header(bytes).map_err(|m| SceneError::malformed(path, m))?;
    let mut progress = Progress::new(opts, bytes.len() as u64);
    let raw = match header.format {
        Format::Ascii => read_body_ascii(bytes, &header, &mut progress),
        Format::BinaryLe => read_body_binary::<false>(bytes, &header, &mut progress),
        Format::BinaryBe => read_body_binary::<true>(bytes, &header, &mut progress),
    }
    .map_err(|m| SceneError::malformed(path, m))?;
    progress.done();
    Ok(finish_mesh(
        raw.positions,
        raw.triangles,
        Vec::new(),
        Vec::new(),
        raw.polygons,
    ))
}

/// Writes `mesh` (positions and triangles only) as binary little-endian PLY with the common
/// `float x, y, z` / `list uchar int vertex_indices` layout.
pub fn write_binary_le(mesh: &Mesh, w: &mut impl Write) -> std::io::Result<()> {
    write_header(mesh, "binary_little_endian", w)?;
    let mut buf = Vec::with_capacity(1 << 16);
    for p in &mesh.positions {
        for c in [p.x, p.y, p.z] {
            buf.extend_from_slice(&c.to_le_bytes());
        }
        if buf.len() >= 1 << 16 {
            w.write_all(&buf)?;
            buf.clear();
        }
    }
    for t in &mesh.triangles {
        buf.push(3);
        for &i in t {
            buf.extend_from_slice(&i.to_le_bytes());
        }
        if buf.len() >= 1 << 16 {
            w.write_all(&buf)?;
            buf.clear();
        }
    }
    w.write_all(&buf)
}

/// Writes `mesh` (positions and triangles only) as ASCII PLY, one record per line.
pub fn write_ascii(mesh: &Mesh, w: &mut impl Write) -> std::io::Result<()> {
    write_header(mesh, "ascii", w)?;
    for p in &mesh.positions {
        writeln!(w, "{} {} {}", p.x, p.y, p.z)?;
    }
    for t in &mesh.triangles {
        writeln!(w, "3 {} {} {}", t[0], t[1], t[2])?;
    }
    Ok(())
}

fn write_header(mesh: &Mesh, format: &str, w: &mut impl Write) -> std::io::Result<()> {
    write!(
        w,
        "ply\nformat {format} 1.0\ncomment written by arbor\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    )
}

/// Builds a [`LoadedMesh`], dropping (and counting) triangles that reference a vertex with a
/// non-finite coordinate, per the crate's NaN policy. `material_ids` may be empty (all 0).
pub(crate) fn finish_mesh(
    positions: Vec<Vec3>,
    mut triangles: Vec<[u32; 3]>,
    mut material_ids: Vec<u32>,
    material_names: Vec<String>,
    polygons_triangulated: usize,
) -> LoadedMesh {
    if material_ids.len() != triangles.len() {
        material_ids = vec![0; triangles.len()];
    }
    let mut dropped = 0;
    if !positions.iter().all(|&p| geom::is_finite3(p)) {
        let ok = |t: &[u32; 3]| t.iter().all(|&i| geom::is_finite3(positions[i as usize]));
        let mut keep = 0;
        for i in 0..triangles.len() {
            if ok(&triangles[i]) {
                triangles[keep] = triangles[i];
                material_ids[keep] = material_ids[i];
                keep += 1;
            }
        }
        dropped = triangles.len() - keep;
        triangles.truncate(keep);
        material_ids.truncate(keep);
    }
    LoadedMesh {
        mesh: Mesh {
            positions,
            triangles,
            material_ids,
            material_names,
        },
        dropped_triangles: dropped,
        polygons_triangulated,
    }
}

/// Reports progress about once per megabyte of input.
pub(crate) struct Progress<'a> {
    opts: &'a LoadOptions,
    total: u64,
    next: u64,
}

impl<'a> Progress<'a> {
    const STEP_BYTES: u64 = 1 << 20;

    pub(crate) fn new(opts: &'a LoadOptions, total: u64) -> Self {
        opts.report(0, total);
        Progress {
            opts,
            total,
            next: Self::STEP_BYTES,
        }
    }

    /// Called often with the bytes consumed so far; reports when a megabyte has passed.
    #[inline]
    pub(crate) fn at(&mut self, done: usize) {
        let done = done as u64;
        if done >= self.next {
            self.opts.report(done.min(self.total), self.total);
            self.next = done + Self::STEP_BYTES;
        }
    }

    pub(crate) fn done(&self) {
        self.opts.report(self.total, self.total);
    }
}

// ---------------------------------------------------------------------------------------
// Header

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
}

impl Element {
    /// Bytes of a binary record when every list is empty (the least a record can take).
    fn min_binary_size(&self) -> usize {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => s.size(),
                Kind::List { count, .. } => count.size(),
            })
            .sum()
    }

    /// Fixed record size when the element has no lists.
    fn fixed_size(&self) -> Option<usize> {
        self.props
            .iter()
            .all(|p| matches!(p.kind, Kind::Scalar(_)))
            .then(|| self.min_binary_size())
    }

    fn prop(&self, name: &str) -> Option<usize> {
        self.props.iter().position(|p| p.name == name)
    }
}

#[derive(Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    data_start: usize,
}

/// Headers of real files are a few hundred bytes; this bounds the work on a file that never
/// says `end_header`.
const MAX_HEADER_BYTES: usize = 1 << 20;

fn parse_header(bytes: &[u8]) -> Result<Header, String> {
    let mut pos = 0;
    let mut line_no = 0;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    // Duplicate checks by set: a hostile header may declare many thousands of names.
    let mut element_names = std::collections::HashSet::new();
    let mut prop_names = std::collections::HashSet::new();
    loop {
        if pos >= MAX_HEADER_BYTES.min(bytes.len()) {
            return Err(if bytes.is_empty() {
                "empty file (expected a PLY header)".into()
            } else {
                "header not terminated by 'end_header'".into()
            });
        }
        let end = match bytes[pos..].iter().position(|&b| b == b'\n') {
            Some(n) => pos + n,
            None => return Err("header not terminated by 'end_header'".into()),
        };
        let raw = &bytes[pos..end];
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        pos = end + 1;
        line_no += 1;
        let line = std::str::from_utf8(raw)
            .map_err(|_| format!("header line {line_no}: not valid text"))?;
        if line_no == 1 {
            if line.trim_end() != "ply" {
                return Err("not a PLY file (first line is not 'ply')".into());
            }
            continue;
        }
        let mut words = line.split_ascii_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let err = |m: &str| format!("header line {line_no}: {m}: '{line}'");
        match keyword {
            "comment" | "obj_info" => {}
            "format" => {
                let f = match words.next() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::BinaryLe,
                    Some("binary_big_endian") => Format::BinaryBe,
                    _ => return Err(err("unknown format")),
                };
                match words.next() {
                    Some("1.0") | Some("1") => {}
                    _ => return Err(err("unsupported format version (expected 1.0)")),
                }
                if format.replace(f).is_some() {
                    return Err(err("second 'format' line"));
                }
            }
            "element" => {
                let (Some(name), Some(count), None) = (words.next(), words.next(), words.next())
                else {
                    return Err(err("expected 'element NAME COUNT'"));
                };
                let count: u64 = count.parse().map_err(|_| err("bad element count"))?;
                if !element_names.insert(name.to_string()) {
                    return Err(err("element declared twice"));
                }
                prop_names.clear();
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            "property" => {
                let Some(el) = elements.last_mut() else {
                    return Err(err("property before any element"));
                };
                let words: Vec<&str> = words.collect();
                let (kind, name) = match words.as_slice() {
                    ["list", c, i, name] => {
                        let count =
                            Scalar::parse(c).ok_or_else(|| err("unknown list count type"))?;
                        let item = Scalar::parse(i).ok_or_else(|| err("unknown list item type"))?;
                        if !count.is_int() {
                            return Err(err("list count type must be an integer type"));
                        }
                        (Kind::List { count, item }, *name)
                    }
                    [t, name] => {
                        let s = Scalar::parse(t).ok_or_else(|| err("unknown property type"))?;
                        (Kind::Scalar(s), *name)
                    }
                    _ => {
                        return Err(err(
                            "expected 'property TYPE NAME' or 'property list COUNT ITEM NAME'",
                        ))
                    }
                };
                if !prop_names.insert(name.to_string()) {
                    return Err(err("property declared twice"));
                }
                el.props.push(Property {
                    name: name.to_string(),
                    kind,
                });
            }
            "end_header" => break,
            _ => return Err(err("unknown header keyword")),
        }
    }
    let format = format.ok_or("header has no 'format' line")?;
    Ok(Header {
        format,
        elements,
        data_start: pos,
    })
}

/// Where the wanted properties are, resolved from the header.
struct Layout {
    /// Index of the `vertex` element and of its x, y, z properties.
    vertex: usize,
    xyz: [usize; 3],
    vertex_count: u32,
    /// Index of the `face` element and of its index list, if there are faces.
    face: Option<(usize, usize)>,
}

fn layout(h: &Header) -> Result<Layout, String> {
    let vertex = h
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or("no 'vertex' element")?;
    let v = &h.elements[vertex];
    let mut xyz = [0; 3];
    for (slot, name) in xyz.iter_mut().zip(["x", "y", "z"]) {
        let i = v
            .prop(name)
            .ok_or_else(|| format!("element 'vertex' has no property '{name}'"))?;
        if !matches!(v.props[i].kind, Kind::Scalar(_)) {
            return Err(format!("vertex property '{name}' is a list"));
        }
        *slot = i;
    }
    let vertex_count = u32::try_from(v.count)
        .map_err(|_| format!("{} vertices exceed the 32-bit index range", v.count))?;
    let face = match h.elements.iter().position(|e| e.name == "face") {
        None => None,
        Some(fi) => {
            let f = &h.elements[fi];
            let pi = f
                .prop("vertex_indices")
                .or_else(|| f.prop("vertex_index"))
                .ok_or("element 'face' has no 'vertex_indices' list")?;
            match f.props[pi].kind {
                Kind::List { item, .. } if item.is_int() => {}
                Kind::List { .. } => {
                    return Err("face vertex_indices must have an integer item type".into())
                }
                Kind::Scalar(_) => return Err("face vertex_indices is not a list".into()),
            }
            Some((fi, pi))
        }
    };
    Ok(Layout {
        vertex,
        xyz,
        vertex_count,
        face,
    })
}

/// What the body readers produce before the NaN pass.
struct Raw {
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    polygons: usize,
}

impl Raw {
    /// Checks and fan-triangulates one face's indices (already range-checked).
    #[inline]
    fn push_face(&mut self, poly: &[u32], face: u64) -> Result<(), String> {
        if poly.len() < 3 {
            return Err(format!(
                "face {face} has {} vertices (need at least 3)",
                poly.len()
            ));
        }
        if poly.len() > 3 {
            self.polygons += 1;
        }
        for i in 1..poly.len() - 1 {
            self.triangles.push([poly[0], poly[i], poly[i + 1]]);
        }
        Ok(())
    }
}

#[inline]
fn check_index(v: i64, nv: u32, face: u64) -> Result<u32, String> {
    if v < 0 || v >= nv as i64 {
        Err(format!(
            "face {face}: vertex index {v} out of range ({nv} vertices)"
        ))
    } else {
        Ok(v as u32)
    }
}

/// Capacity for `count` records, never more than the data could hold (already checked, but
/// the bound keeps the allocation honest on its own).
fn capacity(count: u64, remaining: usize, min_size: usize) -> usize {
    (count as usize).min(remaining / min_size.max(1))
}

// ---------------------------------------------------------------------------------------
// Binary body

#[inline(always)]
fn arr<const N: usize>(b: &[u8], at: usize) -> [u8; N] {
    let mut a = [0u8; N];
    a.copy_from_slice(&b[at..at + N]);
    a
}

#[inline(always)]
fn rd_f32<const BE: bool>(b: &[u8], at: usize) -> f32 {
    if BE {
        f32::from_be_bytes(arr(b, at))
    } else {
        f32::from_le_bytes(arr(b, at))
    }
}

#[inline(always)]
fn rd_u32<const BE: bool>(b: &[u8], at: usize) -> u32 {
    if BE {
        u32::from_be_bytes(arr(b, at))
    } else {
        u32::from_le_bytes(arr(b, at))
    }
}

/// Reads a scalar of type `t` at the start of `b` (which holds at least `t.size()` bytes).
#[inline]
fn rd_f64<const BE: bool>(t: Scalar, b: &[u8]) -> f64 {
    macro_rules! rd {
        ($ty:ty, $n:expr) => {
            if BE {
                <$ty>::from_be_bytes(arr::<$n>(b, 0))
            } else {
                <$ty>::from_le_bytes(arr::<$n>(b, 0))
            }
        };
    }
    match t {
        Scalar::I8 => b[0] as i8 as f64,
        Scalar::U8 => b[0] as f64,
        Scalar::I16 => rd!(i16, 2) as f64,
        Scalar::U16 => rd!(u16, 2) as f64,
        Scalar::I32 => rd!(i32, 4) as f64,
        Scalar::U32 => rd!(u32, 4) as f64,
        Scalar::F32 => rd!(f32, 4) as f64,
        Scalar::F64 => rd!(f64, 8),
    }
}

/// Reads an integer scalar (counts, indices); float types were rejected by the header.
#[inline]
fn rd_int<const BE: bool>(t: Scalar, b: &[u8]) -> i64 {
    macro_rules! rd {
        ($ty:ty, $n:expr) => {
            if BE {
                <$ty>::from_be_bytes(arr::<$n>(b, 0)) as i64
            } else {
                <$ty>::from_le_bytes(arr::<$n>(b, 0)) as i64
            }
        };
    }
    match t {
        Scalar::I8 => b[0] as i8 as i64,
        Scalar::U8 => b[0] as i64,
        Scalar::I16 => rd!(i16, 2),
        Scalar::U16 => rd!(u16, 2),
        Scalar::I32 => rd!(i32, 4),
        Scalar::U32 => rd!(u32, 4),
        // Unreachable for counts and indices (the header requires integer types); -1 makes
        // any such value an error rather than a panic.
        Scalar::F32 | Scalar::F64 => -1,
    }
}

fn truncated(el: &Element, i: u64) -> String {
    format!(
        "truncated data in element '{}' at record {i} of {}",
        el.name, el.count
    )
}

fn read_body_binary<const BE: bool>(
    data: &[u8],
    h: &Header,
    progress: &mut Progress,
) -> Result<Raw, String> {
    let lay = layout(h)?;
    let mut pos = h.data_start;
    let mut raw = Raw {
        positions: Vec::new(),
        triangles: Vec::new(),
        polygons: 0,
    };
    for (ei, el) in h.elements.iter().enumerate() {
        let remaining = data.len() - pos;
        let min = el.min_binary_size();
        if min == 0 {
            // No properties: the records take no bytes, whatever the count.
            continue;
        }
        if el
            .count
            .checked_mul(min as u64)
            .is_none_or(|n| n > remaining as u64)
        {
            return Err(format!(
                "element '{}' declares {} records of at least {min} bytes but only {remaining} bytes remain",
                el.name, el.count
            ));
        }
        if ei == lay.vertex {
            raw.positions = Vec::with_capacity(capacity(el.count, remaining, min));
            pos = read_vertices_binary::<BE>(data, pos, el, lay.xyz, &mut raw.positions, progress)?;
        } else if let Some((_, pi)) = lay.face.filter(|&(fi, _)| fi == ei) {
            raw.triangles = Vec::with_capacity(capacity(el.count, remaining, min));
            pos = read_faces_binary::<BE>(data, pos, el, pi, lay.vertex_count, &mut raw, progress)?;
        } else if let Some(size) = el.fixed_size() {
            pos += el.count as usize * size;
        } else {
            for i in 0..el.count {
                pos = skip_record_binary::<BE>(data, pos, el).ok_or_else(|| truncated(el, i))?;
            }
        }
    }
    Ok(raw)
}

/// Skips one record with lists; `None` when it runs past the data.
fn skip_record_binary<const BE: bool>(data: &[u8], mut pos: usize, el: &Element) -> Option<usize> {
    for p in &el.props {
        match p.kind {
            Kind::Scalar(s) => pos += s.size(),
            Kind::List { count, item } => {
                let n = rd_int::<BE>(count, data.get(pos..pos + count.size())?);
                pos += count.size();
                let n = usize::try_from(n).ok()?;
                pos = pos.checked_add(n.checked_mul(item.size())?)?;
            }
        }
        if pos > data.len() {
            return None;
        }
    }
    Some(pos)
}

fn read_vertices_binary<const BE: bool>(
    data: &[u8],
    mut pos: usize,
    el: &Element,
    xyz: [usize; 3],
    out: &mut Vec<Vec3>,
    progress: &mut Progress,
) -> Result<usize, String> {
    let ty = |i: usize| match el.props[i].kind {
        Kind::Scalar(s) => s,
        Kind::List { .. } => Scalar::U8, // excluded by layout()
    };
    let types = xyz.map(ty);
    if let Some(size) = el.fixed_size() {
        // Fixed-size records: x, y, z at fixed offsets.
        let offset = |i: usize| el.props[..i].iter().map(|p| ty_size(p.kind)).sum::<usize>();
        let [ox, oy, oz] = xyz.map(offset);
        let end = pos + el.count as usize * size;
        let body = &data[pos..end];
        const CHUNK: usize = 1 << 14;
        for (ci, chunk) in body.chunks(CHUNK * size).enumerate() {
            if types == [Scalar::F32; 3] {
                out.extend(chunk.chunks_exact(size).map(|r| {
                    Vec3::new(
                        rd_f32::<BE>(r, ox),
                        rd_f32::<BE>(r, oy),
                        rd_f32::<BE>(r, oz),
                    )
                }));
            } else {
                out.extend(chunk.chunks_exact(size).map(|r| {
                    Vec3::new(
                        rd_f64::<BE>(types[0], &r[ox..]) as f32,
                        rd_f64::<BE>(types[1], &r[oy..]) as f32,
                        rd_f64::<BE>(types[2], &r[oz..]) as f32,
                    )
                }));
            }
            progress.at(pos + (ci + 1) * CHUNK * size);
        }
        return Ok(end);
    }
    // Records with lists: walk property by property.
    for i in 0..el.count {
        let mut v = [0f32; 3];
        for (pi, p) in el.props.iter().enumerate() {
            match p.kind {
                Kind::Scalar(s) => {
                    let b = data
                        .get(pos..pos + s.size())
                        .ok_or_else(|| truncated(el, i))?;
                    if let Some(k) = xyz.iter().position(|&x| x == pi) {
                        v[k] = rd_f64::<BE>(s, b) as f32;
                    }
                    pos += s.size();
                }
                Kind::List { .. } => {
                    let one = Element {
                        name: String::new(),
                        count: 1,
                        props: vec![p.clone()],
                    };
                    pos = skip_record_binary::<BE>(data, pos, &one)
                        .ok_or_else(|| truncated(el, i))?;
                }
            }
        }
        out.push(Vec3::from(v));
        if i & 4095 == 0 {
            progress.at(pos);
        }
    }
    Ok(pos)
}

fn ty_size(k: Kind) -> usize {
    match k {
        Kind::Scalar(s) => s.size(),
        Kind::List { count, .. } => count.size(),
    }
}

fn read_faces_binary<const BE: bool>(
    data: &[u8],
    mut pos: usize,
    el: &Element,
    list: usize,
    nv: u32,
    raw: &mut Raw,
    progress: &mut Progress,
) -> Result<usize, String> {
    let Kind::List { count: cty, item } = el.props[list].kind else {
        return Err("face vertex_indices is not a list".into()); // excluded by layout()
    };
    let mut poly: Vec<u32> = Vec::with_capacity(16);
    // Fast path: the face record is just `list uchar int|uint`, nearly always of triangles.
    if el.props.len() == 1 && cty == Scalar::U8 && matches!(item, Scalar::I32 | Scalar::U32) {
        for i in 0..el.count {
            let Some(&k) = data.get(pos) else {
                return Err(truncated(el, i));
            };
            let k = k as usize;
            let Some(rec) = data.get(pos + 1..pos + 1 + 4 * k) else {
                return Err(truncated(el, i));
            };
            pos += 1 + 4 * k;
            // Indices are compared as u32: a negative `int` becomes >= 2^31 and fails the
            // range check like any other out-of-range value.
            if k == 3 {
                let t = [
                    rd_u32::<BE>(rec, 0),
                    rd_u32::<BE>(rec, 4),
                    rd_u32::<BE>(rec, 8),
                ];
                if t.iter().all(|&v| v < nv) {
                    raw.triangles.push(t);
                    if i & 8191 == 0 {
                        progress.at(pos);
                    }
                    continue;
                }
            }
            poly.clear();
            for j in 0..k {
                let v = rd_u32::<BE>(rec, 4 * j);
                let v = if item == Scalar::I32 {
                    v as i32 as i64
                } else {
                    v as i64
                };
                poly.push(check_index(v, nv, i)?);
            }
            raw.push_face(&poly, i)?;
        }
        return Ok(pos);
    }
    // General layout.
    for i in 0..el.count {
        poly.clear();
        for (pi, p) in el.props.iter().enumerate() {
            match p.kind {
                Kind::Scalar(s) => pos += s.size(),
                Kind::List { count, item } => {
                    let b = data
                        .get(pos..pos + count.size())
                        .ok_or_else(|| truncated(el, i))?;
                    let n = rd_int::<BE>(count, b);
                    pos += count.size();
                    if n < 0 {
                        return Err(format!(
                            "element '{}' record {i}: negative list length {n}",
                            el.name
                        ));
                    }
                    let n = n as usize;
                    let bytes = data
                        .get(pos..pos + n * item.size())
                        .ok_or_else(|| truncated(el, i))?;
                    if pi == list {
                        for c in bytes.chunks_exact(item.size()) {
                            poly.push(check_index(rd_int::<BE>(item, c), nv, i)?);
                        }
                    }
                    pos += n * item.size();
                }
            }
            if pos > data.len() {
                return Err(truncated(el, i));
            }
        }
        raw.push_face(&poly, i)?;
        if i & 4095 == 0 {
            progress.at(pos);
        }
    }
    Ok(pos)
}

// ---------------------------------------------------------------------------------------
// ASCII body

struct Tokens<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Tokens<'a> {
    #[inline]
    fn next(&mut self) -> Option<&'a [u8]> {
        let d = self.data;
        let mut p = self.pos;
        while p < d.len() && d[p].is_ascii_whitespace() {
            p += 1;
        }
        let start = p;
        while p < d.len() && !d[p].is_ascii_whitespace() {
            p += 1;
        }
        self.pos = p;
        (p > start).then(|| &d[start..p])
    }

    /// 1-based line of the current position, for error messages.
    fn line(&self) -> usize {
        1 + self.data[..self.pos]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
    }
}

fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(&tok[..tok.len().min(32)]).into_owned();
    if tok.len() > 32 {
        s + "..."
    } else {
        s
    }
}

/// Parses a decimal integer (optional sign); `None` on anything else or overflow.
#[inline]
pub(crate) fn parse_int(tok: &[u8]) -> Option<i64> {
    let (neg, digits) = match tok.first()? {
        b'-' => (true, &tok[1..]),
        b'+' => (false, &tok[1..]),
        _ => (false, tok),
    };
    if digits.is_empty() || digits.len() > 18 {
        return None;
    }
    let mut v: i64 = 0;
    for &c in digits {
        if !c.is_ascii_digit() {
            return None;
        }
        v = v * 10 + (c - b'0') as i64;
    }
    Some(if neg { -v } else { v })
}

/// Parses a float token with the standard library's (correctly rounded) parser.
#[inline]
pub(crate) fn parse_f32(tok: &[u8]) -> Option<f32> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

fn read_body_ascii(data: &[u8], h: &Header, progress: &mut Progress) -> Result<Raw, String> {
    let lay = layout(h)?;
    let mut tk = Tokens {
        data,
        pos: h.data_start,
    };
    let mut raw = Raw {
        positions: Vec::new(),
        triangles: Vec::new(),
        polygons: 0,
    };
    let mut poly: Vec<u32> = Vec::with_capacity(16);
    for (ei, el) in h.elements.iter().enumerate() {
        let nvals = el.props.len();
        if nvals == 0 {
            continue;
        }
        let remaining = data.len() - tk.pos;
        // Every value is at least one character plus a separator (the last may lack one).
        let min = 2 * nvals;
        if el
            .count
            .checked_mul(min as u64)
            .is_none_or(|n| n > remaining as u64 + 1)
        {
            return Err(format!(
                "element '{}' declares {} records of {nvals} values but only {remaining} bytes remain",
                el.name, el.count
            ));
        }
        let is_vertex = ei == lay.vertex;
        let face_list = lay.face.filter(|&(fi, _)| fi == ei).map(|(_, pi)| pi);
        if is_vertex {
            raw.positions = Vec::with_capacity(capacity(el.count, remaining, min));
        } else if face_list.is_some() {
            raw.triangles = Vec::with_capacity(capacity(el.count, remaining, min));
        }
        let err = |tk: &Tokens, i: u64, m: String| {
            format!("line {}: element '{}' record {i}: {m}", tk.line(), el.name)
        };
        for i in 0..el.count {
            let mut v = [0f32; 3];
            poly.clear();
            for (pi, p) in el.props.iter().enumerate() {
                let tok = tk.next().ok_or_else(|| truncated(el, i))?;
                match p.kind {
                    Kind::Scalar(s) => {
                        if is_vertex {
                            if let Some(k) = lay.xyz.iter().position(|&x| x == pi) {
                                let x = if s.is_int() {
                                    parse_int(tok).map(|x| x as f32)
                                } else {
                                    parse_f32(tok)
                                };
                                v[k] = x.ok_or_else(|| {
                                    err(&tk, i, format!("bad number '{}'", show(tok)))
                                })?;
                            }
                        }
                    }
                    Kind::List { .. } => {
                        let n = parse_int(tok).filter(|&n| n >= 0).ok_or_else(|| {
                            err(&tk, i, format!("bad list length '{}'", show(tok)))
                        })?;
                        for _ in 0..n {
                            let t = tk.next().ok_or_else(|| truncated(el, i))?;
                            if face_list == Some(pi) {
                                let idx = parse_int(t).ok_or_else(|| {
                                    err(&tk, i, format!("bad vertex index '{}'", show(t)))
                                })?;
                                poly.push(check_index(idx, lay.vertex_count, i)?);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                raw.positions.push(Vec3::from(v));
            } else if face_list.is_some() {
                raw.push_face(&poly, i)?;
            }
            if i & 1023 == 0 {
                progress.at(tk.pos);
            }
        }
    }
    Ok(raw)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn p() -> &'static Path {
        Path::new("test.ply")
    }

    fn parse_ok(b: &[u8]) -> LoadedMesh {
        let m = parse(b, p(), &LoadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        m.mesh.check().unwrap();
        m
    }

    fn parse_err(b: &[u8]) -> String {
        match parse(b, p(), &LoadOptions::default()) {
            Ok(m) => panic!("parsed: {} triangles", m.mesh.triangle_count()),
            Err(e) => {
                let s = e.to_string();
                assert!(s.contains("test.ply"), "{s}");
                assert!(!s.contains('\n'), "{s}");
                s
            }
        }
    }

    fn quad_mesh() -> Mesh {
        Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            material_ids: vec![0, 0],
            material_names: vec![],
        }
    }

    fn scene_path(name: &str) -> Option<std::path::PathBuf> {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/scenes")
            .join(name);
        if p.exists() {
            Some(p)
        } else {
            eprintln!("skipping: {} not found", p.display());
            None
        }
    }

    #[test]
    fn roundtrip_binary_and_ascii() {
        let m = quad_mesh();
        let mut b = Vec::new();
        write_binary_le(&m, &mut b).unwrap();
        assert_eq!(parse_ok(&b).mesh, m);
        let mut a = Vec::new();
        write_ascii(&m, &mut a).unwrap();
        assert_eq!(parse_ok(&a).mesh, m);
    }

    const ASCII_EXTRA: &str = "ply\r\nformat ascii 1.0\r\ncomment hi\r\nobj_info x\r\n\
        element vertex 4\r\nproperty uchar red\r\nproperty double x\r\nproperty list uchar float junk\r\n\
        property int16 y\r\nproperty float32 z\r\nelement edge 1\r\nproperty int a\r\nproperty int b\r\n\
        element face 1\r\nproperty uchar flags\r\nproperty list int8 uint32 vertex_index\r\n\
        property list uchar float texcoord\r\nend_header\r\n\
        1 0.0 2 0.5 0.5 0 0\r\n2 1.0 0 0 1\r\n3 1 1 1.5 1 0\r\n4 0 0 1 0\r\n\
        0 1\r\n7 4 0 1 2 3 2 0.1 0.2\r\n";

    #[test]
    fn ascii_extra_properties_and_quads() {
        let m = parse_ok(ASCII_EXTRA.as_bytes());
        assert_eq!(m.mesh.positions[2], Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(m.mesh.positions[3], Vec3::new(0.0, 1.0, 0.0));
        assert_eq!(m.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.polygons_triangulated, 1);
    }

    /// Converts the ASCII_EXTRA layout to binary by hand, in either byte order.
    fn binary_extra(be: bool) -> Vec<u8> {
        let hdr = ASCII_EXTRA.split("end_header\r\n").next().unwrap().replace(
            "format ascii 1.0",
            if be {
                "format binary_big_endian 1.0"
            } else {
                "format binary_little_endian 1.0"
            },
        );
        let mut b = format!("{hdr}end_header\n").into_bytes();
        macro_rules! put {
            ($v:expr) => {
                if be {
                    b.extend_from_slice(&$v.to_be_bytes())
                } else {
                    b.extend_from_slice(&$v.to_le_bytes())
                }
            };
        }
        let verts = [
            (0.0f64, 0i16, 0.0f32),
            (1.0, 0, 0.0),
            (1.0, 1, 0.0),
            (0.0, 1, 0.0),
        ];
        for (k, (x, y, z)) in verts.into_iter().enumerate() {
            b.push(k as u8);
            put!(x);
            b.push(1);
            put!(0.25f32);
            put!(y);
            put!(z);
        }
        put!(0i32);
        put!(1i32);
        b.push(9);
        b.push(4);
        for i in [0u32, 1, 2, 3] {
            put!(i);
        }
        b.push(0);
        b
    }

    #[test]
    fn binary_both_endians_general_layout() {
        for be in [false, true] {
            let m = parse_ok(&binary_extra(be));
            assert_eq!(m.mesh.positions[2], Vec3::new(1.0, 1.0, 0.0), "be={be}");
            assert_eq!(m.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
            assert_eq!(m.polygons_triangulated, 1);
        }
    }

    #[test]
    fn truncated_binary_names_element() {
        let m = quad_mesh();
        let mut b = Vec::new();
        write_binary_le(&m, &mut b).unwrap();
        for cut in 1..b.len() {
            let r = parse(&b[..cut], p(), &LoadOptions::default());
            assert!(r.is_err(), "cut at {cut} parsed");
        }
        let e = parse_err(&b[..b.len() - 2]);
        assert!(e.contains("'face'"), "{e}");
        let be = binary_extra(true);
        for cut in 1..be.len() {
            assert!(
                parse(&be[..cut], p(), &LoadOptions::default()).is_err(),
                "cut {cut}"
            );
        }
    }

    #[test]
    fn truncated_ascii() {
        let e = parse_err(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0.000 0.000 0.000\n1.000 0.000 0.000\n0.000 1.000");
        assert!(e.contains("truncated") && e.contains("'vertex'"), "{e}");
    }

    #[test]
    fn absurd_counts_do_not_allocate() {
        let e = parse_err(b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n");
        assert!(e.contains("only 0 bytes remain"), "{e}");
        let e = parse_err(b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\nproperty float x\nproperty float y\nproperty float z\nend_header\n");
        assert!(e.contains("32-bit"), "{e}");
        let e = parse_err(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 99999999999\nproperty list uchar int vertex_indices\nend_header\n0 0 0 1 0 0 0 1 0\n3 0 1 2\n");
        assert!(e.contains("'face'"), "{e}");
        // Huge counts of elements without properties are skipped without looping.
        let m = parse_ok(b"ply\nformat binary_little_endian 1.0\nelement nothing 18446744073709551615\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n");
        assert_eq!(m.mesh.triangle_count(), 0);
        // A huge list length inside a record is bounded by the data.
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n".to_vec();
        b.extend_from_slice(&[0u8; 36]);
        b.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(parse_err(&b).contains("truncated"));
    }

    #[test]
    fn header_errors() {
        assert!(parse_err(b"").contains("empty"));
        assert!(parse_err(b"plx\n").contains("not a PLY"));
        assert!(parse_err(b"ply\nformat ascii 1.0\n").contains("end_header"));
        assert!(parse_err(b"ply\nformat ascii 2.0\nend_header\n").contains("version"));
        assert!(parse_err(b"ply\nformat utf8 1.0\nend_header\n").contains("unknown format"));
        assert!(parse_err(b"ply\nend_header\n").contains("format"));
        assert!(
            parse_err(b"ply\nformat ascii 1.0\nproperty float x\nend_header\n")
                .contains("before any element")
        );
        assert!(parse_err(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n"
        )
        .contains("unknown property type"));
        assert!(
            parse_err(b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n").contains("count")
        );
        assert!(parse_err(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n"
        )
        .contains("'y'"));
        assert!(parse_err(b"ply\nformat ascii 1.0\nfoo\nend_header\n")
            .contains("unknown header keyword"));
        assert!(
            parse_err(b"ply\nformat ascii 1.0\nelement a 0\nelement a 0\nend_header\n")
                .contains("element declared twice")
        );
        assert!(parse_err(
            b"ply\nformat ascii 1.0\nelement a 0\nproperty int b\nproperty float b\nend_header\n"
        )
        .contains("property declared twice"));
        // Many elements: the header check stays linear.
        let mut big = String::from("ply\nformat ascii 1.0\n");
        for i in 0..20_000 {
            big += &format!("element e{i} 0\nproperty int p\n");
        }
        big += "end_header\n";
        assert!(parse_err(big.as_bytes()).contains("no 'vertex'"));
        assert!(
            parse_err(b"ply\nformat ascii 1.0\n\xff\xfe\nend_header\n").contains("not valid text")
        );
        assert!(parse_err(b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n").contains("no 'vertex'"));
        let hdr = "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n";
        assert!(parse_err(
            format!("{hdr}element face 0\nproperty list float float vertex_indices\nend_header\n")
                .as_bytes()
        )
        .contains("integer"));
        assert!(parse_err(
            format!("{hdr}element face 0\nproperty list uchar float vertex_indices\nend_header\n")
                .as_bytes()
        )
        .contains("integer"));
        assert!(parse_err(
            format!("{hdr}element face 0\nproperty int vertex_indices\nend_header\n").as_bytes()
        )
        .contains("not a list"));
        assert!(parse_err(
            format!("{hdr}element face 0\nproperty int flags\nend_header\n").as_bytes()
        )
        .contains("vertex_indices"));
    }

    const HDR3: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n";

    #[test]
    fn bad_faces_and_numbers() {
        assert!(parse_err(format!("{HDR3}3 0 1 3\n").as_bytes()).contains("out of range"));
        assert!(parse_err(format!("{HDR3}3 0 1 -1\n").as_bytes()).contains("out of range"));
        assert!(parse_err(format!("{HDR3}2 0 1\n").as_bytes()).contains("2 vertices"));
        assert!(parse_err(format!("{HDR3}3 0 1 x\n").as_bytes()).contains("bad vertex index"));
        assert!(parse_err(format!("{HDR3}-3 0 1 2\n").as_bytes()).contains("list length"));
        let bad_num = HDR3.replace("1 0 0\n", "1 zz 0\n");
        let e = parse_err(format!("{bad_num}3 0 1 2\n").as_bytes());
        assert!(
            e.contains("bad number 'zz'") && e.contains("line 11"),
            "{e}"
        );
        // Binary: negative int index and degenerate face.
        let m = quad_mesh();
        let mut b = Vec::new();
        write_binary_le(&m, &mut b).unwrap();
        let n = b.len();
        b[n - 4..].copy_from_slice(&(-1i32).to_le_bytes());
        assert!(parse_err(&b).contains("index -1 out of range"));
        b[n - 13] = 2;
        assert!(parse_err(&b[..n - 4]).contains("2 vertices"));
    }

    #[test]
    fn nan_vertices_drop_their_triangles() {
        let mut m = quad_mesh();
        m.positions[3] = Vec3::new(f32::NAN, 0.0, 0.0);
        m.positions.push(Vec3::splat(f32::INFINITY)); // unreferenced: ignored
        let mut b = Vec::new();
        write_binary_le(&m, &mut b).unwrap();
        let l = parse_ok(&b);
        assert_eq!(l.dropped_triangles, 1);
        assert_eq!(l.mesh.triangles, vec![[0, 1, 2]]);
        let l = parse_ok(
            format!("{HDR3}3 0 1 2\n")
                .replace("1 0 0\n", "inf 0 0\n")
                .as_bytes(),
        );
        assert_eq!((l.dropped_triangles, l.mesh.triangle_count()), (1, 0));
    }

    #[test]
    fn progress_is_reported() {
        use std::sync::atomic::{AtomicU64, Ordering};
        use std::sync::Arc;
        let last = Arc::new(AtomicU64::new(0));
        let l2 = last.clone();
        let opts = LoadOptions {
            progress: Some(Arc::new(move |d, t| {
                assert!(d <= t);
                l2.store(d, Ordering::Relaxed);
            })),
            ..Default::default()
        };
        let mut b = Vec::new();
        write_binary_le(&quad_mesh(), &mut b).unwrap();
        parse(&b, p(), &opts).unwrap();
        assert_eq!(last.load(Ordering::Relaxed), b.len() as u64);
    }

    #[test]
    fn real_scenes() {
        for (name, tris) in [
            ("bunny.ply", 69_451),
            ("sibenik.ply", 75_284),
            ("dragon-res2.ply", 202_520),
        ] {
            let Some(path) = scene_path(name) else {
                continue;
            };
            let l = load(&path, &LoadOptions::default()).unwrap();
            l.mesh.check().unwrap();
            assert_eq!(
                l.mesh.triangle_count() + l.dropped_triangles,
                tris,
                "{name}"
            );
            assert_eq!(l.dropped_triangles, 0, "{name}");
            assert!(l.mesh.bounds().is_finite(), "{name}");
        }
    }

    fn arb_mesh() -> impl Strategy<Value = Mesh> {
        (1usize..40).prop_flat_map(|nv| {
            (
                proptest::collection::vec(proptest::array::uniform3(-1e6f32..1e6), nv),
                proptest::collection::vec(proptest::array::uniform3(0..nv as u32), 0..60),
            )
                .prop_map(|(p, t)| Mesh {
                    positions: p.into_iter().map(Vec3::from).collect(),
                    material_ids: vec![0; t.len()],
                    triangles: t,
                    material_names: vec![],
                })
        })
    }

    #[test]
    fn fuzz_seeds_parse() {
        // The fuzzers' seed files are valid and must stay so.
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/seeds/ply");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).unwrap() {
            let path = e.unwrap().path();
            let l = parse_ok(&std::fs::read(&path).unwrap());
            assert!(l.mesh.triangle_count() > 0, "{}", path.display());
            n += 1;
        }
        assert!(n >= 2);
    }

    proptest! {
        #[test]
        fn prop_roundtrip(m in arb_mesh()) {
            let mut b = Vec::new();
            write_binary_le(&m, &mut b).unwrap();
            prop_assert_eq!(&parse_ok(&b).mesh, &m);
            let mut a = Vec::new();
            write_ascii(&m, &mut a).unwrap();
            prop_assert_eq!(&parse_ok(&a).mesh, &m);
        }

        #[test]
        fn prop_garbage_never_panics(m in arb_mesh(), flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8), ascii in any::<bool>()) {
            let mut b = Vec::new();
            if ascii { write_ascii(&m, &mut b).unwrap() } else { write_binary_le(&m, &mut b).unwrap() }
            for (at, v) in flips {
                let n = b.len();
                b[at % n] = v;
            }
            if let Ok(l) = parse(&b, p(), &LoadOptions::default()) {
                prop_assert!(l.mesh.check().is_ok());
            }
        }
    }
}
