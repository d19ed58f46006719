//! `arbor report <name>`: regenerates one of the thesis's tables or figures as CSV,
//! Markdown and SVG in an output folder. Each report lives in its own file.

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
}

/// Runs `arbor report`.
pub fn run(a: &ReportArgs, ui: &Ui) -> anyhow::Result<()> {
    match &a.kind {
        ReportKind::Cbvh(r) => super::report_cbvh::run(r, ui),
    }
}
