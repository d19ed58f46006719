//! `arbor report <name>`: regenerates one of the thesis's tables or figures as CSV,
//! Markdown and SVG in an output folder. Each report lives in its own file
//! (`report_*.rs`); the helpers they share (scene names and loading, atomic file writes,
//! bar charts) are here.

use crate::progress::Ui;
use anyhow::Context;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

/// Arguments of `arbor report`.
#[derive(clap::Args, Debug)]
pub struct ReportArgs {
    #[command(subcommand)]
    kind: ReportKind,
}

/// The reports.
#[derive(clap::Subcommand, Debug)]
enum ReportKind {
    /// \[P3\] §5: CBVH backtracking, traffic, quality and minimum-scale tables.
    Cbvh(super::report_cbvh::ReportCbvhArgs),
    /// \[P2\] Tables III and VI: MergeTree build time, bus utilization and traffic on the
    /// three memory systems, SAH of the HLBVH family and binned SAH, and the traffic of
    /// the comparison models.
    Mergetree(super::report_mergetree::ReportMergetreeArgs),
    /// \[P4\] Table 2: the ray-tracing accelerator with BVH and MBVH4, primary and
    /// diffuse rays, performance and DRAM traffic beside the thesis's.
    Rtunit(super::report_rtunit::ReportRtunitArgs),
    /// Energy and area: the component models' figures, \[P2\] Tables IV and VII (MergeTree)
    /// and \[P4\] Tables 1 and 2 (the accelerator).
    Energy(super::report_energy::ReportEnergyArgs),
    /// \[P2\] §6.4, Table VIII and Fig. 7: system energy per frame (build plus trace) with
    /// four builders, and tree-update policies over animations.
    System(super::report_system::ReportSystemArgs),
    /// Every open assumption of the models swept over its documented range: the default,
    /// low, high and driving assumption of each figure of \[P2\] Tables III, IV, VI, VII
    /// and VIII and \[P4\] Tables 1 and 2.
    Sensitivity(super::report_sensitivity::ReportSensitivityArgs),
    /// Every report above as one self-contained static HTML site (index and one page per
    /// area), each reproduced table beside the thesis's numbers; `--quick` for small runs.
    Html(super::report_html::ReportHtmlArgs),
}

/// Runs `arbor report`.
pub fn run(a: &ReportArgs, ui: &Ui) -> anyhow::Result<()> {
    match &a.kind {
        ReportKind::Cbvh(r) => super::report_cbvh::run(r, ui),
        ReportKind::Mergetree(r) => super::report_mergetree::run(r, ui),
        ReportKind::Rtunit(r) => super::report_rtunit::run(r, ui).map(|_| ()),
        ReportKind::Energy(r) => super::report_energy::run(r, ui),
        ReportKind::System(r) => super::report_system::run(r, ui),
        ReportKind::Sensitivity(r) => super::report_sensitivity::run(r, ui),
        ReportKind::Html(r) => super::report_html::run(r, ui),
    }
}

/// The default of every report's `--scene-dir` (`default_value = SHARED_SCENES`): the
/// folder [`shared_scenes`] finds when the command line is parsed.
pub const SHARED_SCENES: SharedScenes = SharedScenes;

/// See [`SHARED_SCENES`].
#[derive(Clone, Copy, Debug)]
pub struct SharedScenes;

impl clap::builder::IntoResettable<clap::builder::OsStr> for SharedScenes {
    fn into_resettable(self) -> clap::builder::Resettable<clap::builder::OsStr> {
        static DIR: std::sync::OnceLock<&'static str> = std::sync::OnceLock::new();
        let dir = DIR.get_or_init(|| {
            let s = shared_scenes().display().to_string();
            Box::leak(s.into_boxed_str())
        });
        clap::builder::Resettable::Value((*dir).into())
    }
}

/// The folder of the shared real scenes (`--scene-dir`'s default), found at run time: the
/// environment variable `ARBOR_SCENE_DIR` if it is set; else the nearest `shared/scenes`
/// folder in or above the current folder (`../shared/scenes` from the repository's root),
/// else in or above the folder of the `arbor` executable; else `../shared/scenes`.
pub fn shared_scenes() -> std::path::PathBuf {
    if let Some(d) = std::env::var_os("ARBOR_SCENE_DIR").filter(|d| !d.is_empty()) {
        return d.into();
    }
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf));
    for start in [std::env::current_dir().ok(), exe_dir]
        .into_iter()
        .flatten()
    {
        if let Some(d) = start
            .ancestors()
            .map(|a| a.join("shared").join("scenes"))
            .find(|d| d.is_dir())
        {
            return d;
        }
    }
    Path::new("..").join("shared").join("scenes")
}

pub use scene::camera::{view_camera, INTERIOR_VIEWS};

/// Short name of a scene spec (file stem, or procedural name).
pub fn short_name(spec: &str) -> String {
    if let Some(rest) = spec.strip_prefix("proc:") {
        return rest.split('?').next().unwrap_or(rest).to_string();
    }
    Path::new(spec)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| spec.to_string())
}

/// The primitive boxes of scene `spec` at time `t`, clamped to its timeline (the report
/// scenes are sampled once).
pub fn scene_prims(spec: &str, t: f32) -> anyhow::Result<Vec<geom::Aabb>> {
    anyhow::ensure!(t.is_finite(), "the sampling time must be finite, got {t}");
    let scene = scene::open(spec, &scene::LoadOptions::default())
        .with_context(|| format!("cannot open {spec}"))?;
    let t = scene.info().timeline.clamp(t);
    let mesh = scene
        .mesh_at(t)
        .with_context(|| format!("cannot sample {spec}"))?;
    Ok(super::build::mesh_aabbs(&mesh)?.0)
}

/// Writes `text` to `dir/name` atomically (see [`write_atomic`]).
pub fn write_file(dir: &Path, name: &str, text: &str) -> anyhow::Result<()> {
    write_atomic(&dir.join(name), text)
}

/// Writes `text` to `path` atomically: a temporary file in the same folder
/// ([`trace::image::temp_file_beside`], with ordinary permissions) is written, synced and
/// renamed over the destination, so an existing file is never left half-written.
pub fn write_atomic(path: &Path, text: &str) -> anyhow::Result<()> {
    let fail = || format!("cannot write {}", path.display());
    let mut tmp = trace::image::temp_file_beside(path, ".arbor-").with_context(fail)?;
    tmp.write_all(text.as_bytes()).with_context(fail)?;
    tmp.as_file().sync_all().with_context(fail)?;
    tmp.persist(path).map_err(|e| e.error).with_context(fail)?;
    Ok(())
}

/// A grouped bar chart: one group per label, one bar per series (missing values skipped).
pub fn bar_svg(title: &str, labels: &[String], series: &[(String, Vec<Option<f64>>)]) -> String {
    let stacked: Vec<(String, Vec<Option<Vec<f64>>>)> = series
        .iter()
        .map(|(n, v)| (n.clone(), v.iter().map(|x| x.map(|x| vec![x])).collect()))
        .collect();
    stacked_bar_svg(title, labels, &stacked, &[])
}

/// A grouped bar chart whose bars are stacks of parts (e.g. build and trace energy): one
/// group per label, one bar per series, the parts of a bar drawn bottom-up, the first in
/// the series' colour and later ones lighter; `parts` names them in the legend.
pub fn stacked_bar_svg(
    title: &str,
    labels: &[String],
    series: &[(String, Vec<Option<Vec<f64>>>)],
    parts: &[&str],
) -> String {
    const COLORS: [&str; 6] = [
        "#1f77b4", "#aec7e8", "#d62728", "#ff9896", "#2ca02c", "#98df8a",
    ];
    const OPACITY: [f64; 3] = [1.0, 0.45, 0.25];
    // Wide enough for the labels (about 7 px per character) and the legend (150 px per
    // series and part), and at least 760 px.
    let longest = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    let w = (80.0 + labels.len() as f64 * (7.0 * longest as f64 + 8.0))
        .max(80.0 + 150.0 * (series.len() + parts.len()) as f64)
        .max(760.0);
    let (h, left, bottom, top) = (360.0, 60.0, 40.0, 40.0);
    let max = series
        .iter()
        .flat_map(|s| s.1.iter().flatten())
        .map(|v| v.iter().sum::<f64>())
        .fold(0.0f64, f64::max)
        .max(1e-9);
    let plot_h = h - bottom - top;
    let group_w = (w - left - 20.0) / labels.len().max(1) as f64;
    let bar_w = group_w * 0.8 / series.len().max(1) as f64;
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"11\">\n\
         <rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n<text x=\"{left}\" y=\"20\" font-size=\"13\">{}</text>\n",
        xml(title)
    );
    for k in 0..=4 {
        let v = max * k as f64 / 4.0;
        let y = h - bottom - plot_h * k as f64 / 4.0;
        let _ = writeln!(
            s,
            "<line x1=\"{left}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/><text x=\"4\" y=\"{:.1}\">{v:.3}</text>",
            w - 20.0,
            y + 4.0
        );
    }
    for (gi, l) in labels.iter().enumerate() {
        let gx = left + gi as f64 * group_w + group_w * 0.1;
        for (si, (name, vals)) in series.iter().enumerate() {
            let Some(Some(v)) = vals.get(gi) else {
                continue;
            };
            let mut base = h - bottom;
            for (pi, &part) in v.iter().enumerate() {
                let bh = plot_h * part / max;
                let what = parts.get(pi).map_or(String::new(), |p| format!(" {p}"));
                let _ = writeln!(
                    s,
                    "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{bh:.1}\" fill=\"{}\" fill-opacity=\"{}\"><title>{}{}: {part:.4}</title></rect>",
                    gx + si as f64 * bar_w,
                    base - bh,
                    bar_w.max(1.0),
                    COLORS[si % COLORS.len()],
                    OPACITY[pi.min(OPACITY.len() - 1)],
                    xml(name),
                    xml(&what)
                );
                base -= bh;
            }
        }
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            gx + group_w * 0.4,
            h - bottom + 14.0,
            xml(l)
        );
    }
    let legend = series
        .iter()
        .enumerate()
        .map(|(si, (name, _))| (COLORS[si % COLORS.len()], 1.0, name.as_str()))
        .chain(
            parts
                .iter()
                .enumerate()
                .map(|(pi, p)| ("#555", OPACITY[pi.min(OPACITY.len() - 1)], *p)),
        );
    for (i, (color, opacity, name)) in legend.enumerate() {
        let x = left + i as f64 * 150.0;
        let _ = writeln!(
            s,
            "<rect x=\"{x}\" y=\"{:.1}\" width=\"10\" height=\"10\" fill=\"{color}\" fill-opacity=\"{opacity}\"/><text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            h - 14.0,
            x + 14.0,
            h - 5.0,
            xml(name)
        );
    }
    s.push_str("</svg>\n");
    s
}

/// `t` with the XML special characters escaped.
pub fn xml(t: &str) -> String {
    t.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_svg_and_atomic_writes() {
        assert_eq!(short_name("/a/b/bunny.ply"), "bunny");
        assert_eq!(short_name("proc:cloth?n=5"), "cloth");
        let svg = bar_svg("t<", &["a".into()], &[("s".into(), vec![Some(1.0)])]);
        assert!(svg.contains("t&lt;") && svg.ends_with("</svg>\n"));
        // Stacked: two parts per bar, the second on top of the first.
        let svg = stacked_bar_svg(
            "s",
            &["a".into()],
            &[("x".into(), vec![Some(vec![1.0, 3.0])])],
            &["build", "trace"],
        );
        assert_eq!(svg.matches("<title>").count(), 2);
        assert!(svg.contains("x build: 1.0000") && svg.contains("x trace: 3.0000"));
        let dir = tempfile::tempdir().unwrap();
        write_file(dir.path(), "x.csv", "a\n").unwrap();
        write_file(dir.path(), "x.csv", "b\n").unwrap();
        assert_eq!(
            std::fs::read_to_string(dir.path().join("x.csv")).unwrap(),
            "b\n"
        );
        // Only the file itself is left (no temporary files).
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        assert!(write_file(&dir.path().join("missing"), "x.csv", "").is_err());
        // A bare file name goes to the current folder's temporary file; a folder fails.
        assert!(write_atomic(dir.path(), "x").is_err());
    }
}
