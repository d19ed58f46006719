//! Image outputs: the shaded image as PNG, the depth buffer as PFM or NPY, and a heatmap
//! of traversal cost in the style of the thesis's Fig. 2.2 (red: inner-node visits per
//! pixel, blue: ray/triangle tests per pixel), with a legend giving the scale.
//!
//! Every file is written to a temporary file beside the target and renamed into place, so
//! an existing file is never left half-written.

use crate::render::Render;
use crate::TraceError;
use std::io::Write;
use std::path::Path;

fn io_err(path: &Path, source: std::io::Error) -> TraceError {
    TraceError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// A new temporary file beside `path`, with an ordinary file's permissions: the
/// workspace's one atomic writer, [`outfile`], which every output here goes through.
pub use outfile::temp_file_beside;

/// Writes `path` atomically: `fill` writes the content to a temporary file in the same
/// folder, which then replaces `path` ([`outfile::write_with`]).
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> Result<(), TraceError>,
) -> Result<(), TraceError> {
    outfile::write_with(path, fill, |e| io_err(path, e))
}

/// Linear to sRGB-encoded 8-bit, clamped.
fn srgb8(x: f32) -> u8 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// Writes 8-bit RGB pixels (`width * height * 3` bytes, row 0 at the top) as a PNG.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<(), TraceError> {
    debug_assert_eq!(rgb.len(), width as usize * height as usize * 3);
    write_atomic(path, |w| {
        let mut enc = png::Encoder::new(w, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let png_err = |e: png::EncodingError| TraceError::Png {
            path: path.display().to_string(),
            message: e.to_string(),
        };
        let mut wr = enc.write_header().map_err(png_err)?;
        wr.write_image_data(rgb).map_err(png_err)?;
        wr.finish().map_err(png_err)
    })
}

/// The shaded image as sRGB bytes.
pub fn color_bytes(r: &Render) -> Vec<u8> {
    r.color
        .iter()
        .flat_map(|c| [srgb8(c[0]), srgb8(c[1]), srgb8(c[2])])
        .collect()
}

/// Writes the shaded image as a PNG.
pub fn write_color_png(path: &Path, r: &Render) -> Result<(), TraceError> {
    write_png(path, r.width, r.height, &color_bytes(r))
}

/// Writes the depth buffer (primary hit distance, +inf for a miss) as little-endian 32-bit
/// floats: `.pfm` (Portable Float Map, grey, rows bottom to top as the format defines) or
/// `.npy` (NumPy, shape `(height, width)`, row 0 at the top).
pub fn write_depth(path: &Path, r: &Render) -> Result<(), TraceError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let (w, h) = (r.width as usize, r.height as usize);
    let err = |e: std::io::Error| io_err(path, e);
    match ext.as_deref() {
        Some("pfm") => write_atomic(path, |out| {
            write!(out, "Pf\n{w} {h}\n-1.0\n").map_err(err)?;
            for row in (0..h).rev() {
                for &d in &r.depth[row * w..(row + 1) * w] {
                    out.write_all(&d.to_le_bytes()).map_err(err)?;
                }
            }
            Ok(())
        }),
        Some("npy") => write_atomic(path, |out| {
            let dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({h}, {w}), }}");
            // Magic (6) + version (2) + header length (2) + dict + padding + '\n' is a
            // multiple of 64 bytes (NPY format 1.0).
            let unpadded = 10 + dict.len() + 1;
            let pad = unpadded.div_ceil(64) * 64 - unpadded;
            let hlen = (dict.len() + pad + 1) as u16;
            out.write_all(b"\x93NUMPY\x01\x00").map_err(err)?;
            out.write_all(&hlen.to_le_bytes()).map_err(err)?;
            out.write_all(dict.as_bytes()).map_err(err)?;
            out.write_all(&vec![b' '; pad]).map_err(err)?;
            out.write_all(b"\n").map_err(err)?;
            for &d in &r.depth {
                out.write_all(&d.to_le_bytes()).map_err(err)?;
            }
            Ok(())
        }),
        _ => Err(TraceError::Config(format!(
            "{}: depth buffers are written as .pfm or .npy",
            path.display()
        ))),
    }
}

/// Reads a depth buffer written by [`write_depth`] back (row 0 at the top): `(width,
/// height, values)`. For tests and tools; rejects anything else.
pub fn read_depth(path: &Path) -> Result<(u32, u32, Vec<f32>), TraceError> {
    let bytes = std::fs::read(path).map_err(|e| io_err(path, e))?;
    let bad = |m: &str| TraceError::Config(format!("{}: {m}", path.display()));
    let floats = |b: &[u8]| -> Vec<f32> {
        b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    if bytes.starts_with(b"Pf\n") {
        let mut lines = bytes.splitn(4, |&b| b == b'\n');
        lines.next();
        let dims =
            std::str::from_utf8(lines.next().ok_or(bad("no size"))?).map_err(|_| bad("size"))?;
        let mut it = dims.split_whitespace().map(|s| s.parse::<u32>());
        let (w, h) = match (it.next(), it.next()) {
            (Some(Ok(w)), Some(Ok(h))) => (w, h),
            _ => return Err(bad("bad size line")),
        };
        lines.next();
        let data = lines.next().ok_or(bad("no data"))?;
        if data.len() != w as usize * h as usize * 4 {
            return Err(bad("data size does not match"));
        }
        let rows = floats(data);
        let mut v = Vec::with_capacity(rows.len());
        for row in (0..h as usize).rev() {
            v.extend_from_slice(&rows[row * w as usize..(row + 1) * w as usize]);
        }
        Ok((w, h, v))
    } else if bytes.starts_with(b"\x93NUMPY\x01\x00") && bytes.len() >= 10 {
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        let header = std::str::from_utf8(bytes.get(10..10 + hlen).ok_or(bad("header"))?)
            .map_err(|_| bad("header"))?;
        let shape = header
            .split("'shape': (")
            .nth(1)
            .and_then(|s| s.split(')').next())
            .ok_or(bad("no shape"))?;
        let dims: Vec<u32> = shape
            .split(',')
            .filter_map(|s| s.trim().parse().ok())
            .collect();
        let [h, w] = dims[..] else {
            return Err(bad("shape is not 2-D"));
        };
        let data = &bytes[10 + hlen..];
        if data.len() != w as usize * h as usize * 4 {
            return Err(bad("data size does not match"));
        }
        Ok((w, h, floats(data)))
    } else {
        Err(bad("not a PFM or NPY depth buffer"))
    }
}

/// The scale of a heatmap: the counts shown at full red and full blue.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct HeatScale {
    /// Inner-node visits per pixel shown at full red.
    pub node_visits: u32,
    /// Triangle tests per pixel shown at full blue.
    pub tri_tests: u32,
}

/// The fraction of pixels at or below the default heatmap scale: the hottest 0.5% of
/// pixels saturate instead of washing out the rest of the image.
pub const HEAT_PERCENTILE: f64 = 0.995;

impl HeatScale {
    /// The default scale of an image: the [`HEAT_PERCENTILE`] quantile of each count over
    /// its pixels (at least 1).
    pub fn of(r: &Render) -> Self {
        let q = |v: &[u32]| -> u32 {
            if v.is_empty() {
                return 1;
            }
            let mut s = v.to_vec();
            let k = ((HEAT_PERCENTILE * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1;
            let (_, x, _) = s.select_nth_unstable(k);
            (*x).max(1)
        };
        Self {
            node_visits: q(&r.node_visits),
            tri_tests: q(&r.tri_tests),
        }
    }
}

/// Height of the legend strip below a heatmap, in pixels.
const LEGEND_H: u32 = 36;

/// Writes the heatmap of `r` as a PNG: red = inner-node visits / `scale.node_visits`,
/// blue = triangle tests / `scale.tri_tests` (clamped), summed over all of each pixel's
/// rays, with a legend strip below the image naming the scale (images at least 160
/// pixels wide; narrower ones get no legend). Give several renders the same scale to
/// compare them, as in the thesis's Fig. 2.2.
pub fn write_heatmap(path: &Path, r: &Render, scale: HeatScale) -> Result<(), TraceError> {
    let (w, h) = (r.width, r.height);
    let legend = w >= 160;
    let total_h = h + if legend { LEGEND_H } else { 0 };
    let mut px = vec![0u8; (w * total_h * 3) as usize];
    let level =
        |v: u32, max: u32| ((v.min(max) as u64 * 255 + max as u64 / 2) / max.max(1) as u64) as u8;
    for i in 0..(w * h) as usize {
        px[i * 3] = level(r.node_visits[i], scale.node_visits);
        px[i * 3 + 2] = level(r.tri_tests[i], scale.tri_tests);
    }
    if legend {
        let mut c = Canvas {
            px: &mut px,
            width: w,
        };
        let y0 = h;
        c.fill(0, y0, w, LEGEND_H, [24, 24, 24]);
        let bar_w = (w / 4).clamp(40, 256);
        for (row, (label, max, chan)) in [
            ("INNER NODE VISITS", scale.node_visits, 0usize),
            ("TRIANGLE TESTS", scale.tri_tests, 2usize),
        ]
        .into_iter()
        .enumerate()
        {
            let y = y0 + 4 + row as u32 * 16;
            let x = c.text(4, y, "0", [220, 220, 220]) + 4;
            for i in 0..bar_w {
                let mut col = [0u8; 3];
                col[chan] = ((i * 255) / (bar_w - 1)) as u8;
                c.fill(x + i, y, 1, 10, col);
            }
            let x = c.text(
                x + bar_w + 4,
                y,
                &format!("{max} {label} PER PIXEL"),
                [220, 220, 220],
            );
            let _ = x;
        }
    }
    write_png(path, w, total_h, &px)
}

/// A tiny raster for the legend.
struct Canvas<'a> {
    px: &'a mut [u8],
    width: u32,
}

impl Canvas<'_> {
    fn fill(&mut self, x: u32, y: u32, w: u32, h: u32, c: [u8; 3]) {
        let height = self.px.len() as u32 / (self.width * 3);
        for yy in y..(y + h).min(height) {
            for xx in x..(x + w).min(self.width) {
                let i = ((yy * self.width + xx) * 3) as usize;
                self.px[i..i + 3].copy_from_slice(&c);
            }
        }
    }

    /// Draws `s` at 2x scale with the 3x5 font; returns the x after the text.
    fn text(&mut self, mut x: u32, y: u32, s: &str, c: [u8; 3]) -> u32 {
        for ch in s.chars() {
            let g = glyph(ch.to_ascii_uppercase());
            for row in 0..5 {
                for col in 0..3 {
                    if g >> (14 - (row * 3 + col)) & 1 == 1 {
                        self.fill(x + col * 2, y + row * 2, 2, 2, c);
                    }
                }
            }
            x += 8;
        }
        x
    }
}

/// A 3x5 glyph: 15 bits, rows top to bottom, each row's three pixels left to right, most
/// significant first. Unknown characters are blank.
fn glyph(c: char) -> u16 {
    let rows: [u8; 5] = match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        'A' => [2, 5, 7, 5, 5],
        'B' => [6, 5, 6, 5, 6],
        'C' => [3, 4, 4, 4, 3],
        'D' => [6, 5, 5, 5, 6],
        'E' => [7, 4, 6, 4, 7],
        'F' => [7, 4, 6, 4, 4],
        'G' => [3, 4, 5, 5, 3],
        'H' => [5, 5, 7, 5, 5],
        'I' => [7, 2, 2, 2, 7],
        'J' => [1, 1, 1, 5, 2],
        'K' => [5, 5, 6, 5, 5],
        'L' => [4, 4, 4, 4, 7],
        'M' => [5, 7, 7, 5, 5],
        'N' => [6, 5, 5, 5, 5],
        'O' => [2, 5, 5, 5, 2],
        'P' => [6, 5, 6, 4, 4],
        'Q' => [2, 5, 5, 6, 3],
        'R' => [6, 5, 6, 5, 5],
        'S' => [3, 4, 2, 1, 6],
        'T' => [7, 2, 2, 2, 2],
        'U' => [5, 5, 5, 5, 7],
        'V' => [5, 5, 5, 5, 2],
        'W' => [5, 5, 7, 7, 5],
        'X' => [5, 5, 2, 5, 5],
        'Y' => [5, 5, 2, 2, 2],
        'Z' => [7, 1, 2, 4, 7],
        '.' => [0, 0, 0, 0, 2],
        ':' => [0, 2, 0, 2, 0],
        '/' => [1, 1, 2, 4, 4],
        '-' => [0, 0, 7, 0, 0],
        '=' => [0, 7, 0, 7, 0],
        '(' => [2, 4, 4, 4, 2],
        ')' => [2, 1, 1, 1, 2],
        _ => [0; 5],
    };
    rows.iter().fold(0u16, |g, &r| (g << 3) | r as u16)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::RenderStats;

    fn tiny() -> Render {
        let (w, h) = (200u32, 3u32);
        let n = (w * h) as usize;
        Render {
            width: w,
            height: h,
            color: (0..n).map(|i| [i as f32 / n as f32, 0.5, 2.0]).collect(),
            depth: (0..n)
                .map(|i| {
                    if i % 7 == 0 {
                        f32::INFINITY
                    } else {
                        i as f32 * 0.25
                    }
                })
                .collect(),
            prim: vec![0; n],
            node_visits: (0..n as u32).collect(),
            tri_tests: (0..n as u32).map(|i| i / 2).collect(),
            stats: RenderStats::default(),
        }
    }

    #[test]
    fn depth_round_trips_through_pfm_and_npy() {
        let dir = tempfile::tempdir().unwrap();
        let r = tiny();
        for ext in ["pfm", "npy"] {
            let p = dir.path().join(format!("d.{ext}"));
            write_depth(&p, &r).unwrap();
            let (w, h, v) = read_depth(&p).unwrap();
            assert_eq!((w, h), (r.width, r.height));
            assert_eq!(
                v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                r.depth.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
            );
        }
        let npy = std::fs::read(dir.path().join("d.npy")).unwrap();
        let hlen = u16::from_le_bytes([npy[8], npy[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        assert!(write_depth(&dir.path().join("d.exr"), &r).is_err());
    }

    #[test]
    fn pngs_decode_with_the_right_size_and_heat_levels() {
        let dir = tempfile::tempdir().unwrap();
        let r = tiny();
        let p = dir.path().join("c.png");
        write_color_png(&p, &r).unwrap();
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap()));
        let mut rd = dec.read_info().unwrap();
        let mut buf = vec![0; rd.output_buffer_size()];
        let info = rd.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (200, 3));
        // Radiance above 1 clamps to white; 0.5 encodes as sRGB 188.
        assert_eq!((buf[1], buf[2]), (188, 255));
        let hp = dir.path().join("h.png");
        let scale = HeatScale::of(&r);
        // 99.5% of the 600 pixels are at or below the scale (value 596 of 0..=599).
        assert_eq!(
            scale,
            HeatScale {
                node_visits: 596,
                tri_tests: 298
            }
        );

        write_heatmap(&hp, &r, scale).unwrap();
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&hp).unwrap()));
        let mut rd = dec.read_info().unwrap();
        let mut buf = vec![0; rd.output_buffer_size()];
        let info = rd.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (200, 3 + LEGEND_H));
        // The hottest pixel is full red and full blue, the first one black, green unused.
        let last = (200 * 3 - 1) * 3;
        assert_eq!(&buf[last..last + 3], &[255, 0, 255]);
        assert_eq!(&buf[0..3], &[0, 0, 0]);
        // The legend draws text (light pixels) below the image.
        let legend = &buf[(200 * 3 * 3)..];
        assert!(legend.chunks(3).any(|p| p == [220, 220, 220]));
    }

    #[test]
    fn glyphs_are_distinct() {
        let chars = "0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ.:/-=()";
        let mut seen = std::collections::HashSet::new();
        for c in chars.chars() {
            assert!(seen.insert(glyph(c)), "{c} repeats a glyph");
            assert_ne!(glyph(c), 0);
        }
        assert_eq!(glyph('~'), 0);
    }
}
