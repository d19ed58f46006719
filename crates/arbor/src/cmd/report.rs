//! `arbor report <name>`: regenerates one of the thesis's tables or figures as CSV,
//! Markdown and SVG in an output folder. Each report lives in its own file
//! (`report_*.rs`); the helpers they share (scene names and loading) are here, and the
//! writers (atomic files, tables, bar charts) in the `report` crate.

use crate::progress::Ui;
use anyhow::Context;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_names() {
        assert_eq!(short_name("/a/b/bunny.ply"), "bunny");
        assert_eq!(short_name("proc:cloth?n=5"), "cloth");
    }
}
