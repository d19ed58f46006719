//! `arbor report <name>`: regenerates one of the thesis's tables or figures as CSV,
//! Markdown and SVG in an output folder. The reports are library code (the `report`
//! crate, one module per area); each `report_*.rs` here holds one report's command-line
//! options, which it converts into the library's option struct, and prints the result.

use crate::progress::Ui;

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
    /// Beyond the thesis (issue 18): forecasting read scheduling, MBVH4 and compressed
    /// 4-wide nodes out of the stream, point k-d trees and octrees, plane-sharing CBVH
    /// update, each against the thesis's baseline on the MergeTree model.
    Beyond(super::report_beyond::ReportBeyondArgs),
    /// Every report above as one self-contained static HTML site (index and one page per
    /// area), each reproduced table beside the thesis's numbers; `--quick` for small runs.
    Html(super::report_html::ReportHtmlArgs),
}

/// Runs `arbor report`.
pub fn run(a: &ReportArgs, ui: &Ui) -> anyhow::Result<()> {
    match &a.kind {
        ReportKind::Cbvh(r) => super::report_cbvh::run(r, ui),
        ReportKind::Mergetree(r) => super::report_mergetree::run(r, ui),
        ReportKind::Rtunit(r) => super::report_rtunit::run(r, ui),
        ReportKind::Energy(r) => super::report_energy::run(r, ui),
        ReportKind::System(r) => super::report_system::run(r, ui),
        ReportKind::Sensitivity(r) => super::report_sensitivity::run(r, ui),
        ReportKind::Beyond(r) => super::report_beyond::run(r, ui),
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

pub use report::scenes::{scene_prims, shared_scenes, short_name, view_camera, INTERIOR_VIEWS};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_names() {
        assert_eq!(short_name("/a/b/bunny.ply"), "bunny");
        assert_eq!(short_name("proc:cloth?n=5"), "cloth");
    }
}
