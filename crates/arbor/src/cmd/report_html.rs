//! `arbor report html`: the results as one self-contained static site. The site is
//! library code (`report::html`); this is its command line, which hands the library a
//! runner of `arbor` command lines (this process's parser and code) and the provenance.

use super::report::SHARED_SCENES;
use crate::progress::Ui;
use report::html::{HtmlOptions, Provenance};
use std::path::PathBuf;

/// Arguments of `arbor report html`.
#[derive(clap::Args, Debug)]
pub struct ReportHtmlArgs {
    /// Folder of the site (created if missing; the files it names are replaced).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-html")]
    out: PathBuf,
    /// Small runs (procedural and small shared scenes, tiny images, one run each): the
    /// whole site in a few minutes. Without it every report runs at its defaults, which
    /// takes hours.
    #[arg(long)]
    quick: bool,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
}

/// Where the numbers come from: this build, now, on this CPU.
pub fn provenance() -> Provenance {
    Provenance::gather(super::bench::utc_now(), super::bench_record::cpu_model())
}

/// Runs `arbor ARGS` in this process without printing its text results (its progress
/// bars and warnings unless `quiet`).
fn run_arbor(args: &[String], quiet: bool) -> anyhow::Result<()> {
    let argv = std::iter::once("arbor".to_string()).chain(args.iter().cloned());
    let cli =
        crate::Cli::try_parse_from(argv).map_err(|e| anyhow::anyhow!(crate::arg_error_line(&e)))?;
    cli.run(&Ui {
        quiet,
        json: None,
        silent: true,
    })
}

/// Runs `arbor report html`.
pub fn run(a: &ReportHtmlArgs, ui: &Ui) -> anyhow::Result<()> {
    let opts = HtmlOptions {
        out: a.out.clone(),
        quick: a.quick,
        scene_dir: a.scene_dir.clone(),
        quiet: ui.quiet,
    };
    let runner = |args: &[String]| run_arbor(args, ui.quiet).map_err(|e| crate::one_line(&e));
    report::html::run(&opts, &provenance(), &runner, ui)
}
