//! `arbor report cbvh`: the \[P3\] §5 tables for our scenes. The report is library code
//! (`report::cbvh`: the tables, the runtime simulations and the ray-traced measurement);
//! this is its command line.

use super::report::SHARED_SCENES;
use crate::progress::Ui;
use report::cbvh::{parse_size, CbvhOptions};
use std::path::PathBuf;

/// Arguments of `arbor report cbvh`.
#[derive(clap::Args, Debug)]
pub struct ReportCbvhArgs {
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-cbvh")]
    out: PathBuf,
    /// Scenes to use, comma separated: files, procedural specs, or `cloth` (the report's
    /// half-flat cloth). Default: the shared real scenes and `cloth`.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    /// Skip the minimum-scale sweep (Fig. 10).
    #[arg(long)]
    no_sweep: bool,
    /// Skip the runtime simulations (Table 2).
    #[arg(long)]
    no_runtime: bool,
    /// Memory system of the runtime simulations (Table 2); `simple:NAME` for the quick
    /// model.
    #[arg(long, value_name = "NAME", default_value = report::cbvh::runtime::DEFAULT_DRAM)]
    runtime_dram: String,
    /// Image size of the ray-traced quality and watertightness measurement (\[P3\] §5.4-5.5).
    #[arg(long, value_name = "WxH", default_value = "640x360")]
    trace_size: String,
    /// Skip the ray-traced measurement.
    #[arg(long)]
    no_trace: bool,
}

impl ReportCbvhArgs {
    /// The options of the library's report (a bad `--trace-size` is an error here).
    pub fn options(&self) -> anyhow::Result<CbvhOptions> {
        Ok(CbvhOptions {
            out: self.out.clone(),
            scenes: self.scenes.clone(),
            scene_dir: self.scene_dir.clone(),
            no_sweep: self.no_sweep,
            no_runtime: self.no_runtime,
            runtime_dram: self.runtime_dram.clone(),
            trace_size: parse_size(&self.trace_size)?,
            no_trace: self.no_trace,
        })
    }
}

/// Runs `arbor report cbvh`.
pub fn run(a: &ReportCbvhArgs, ui: &Ui) -> anyhow::Result<()> {
    let md = report::cbvh::run(&a.options()?, ui)?;
    crate::say!(ui, "{md}");
    crate::say!(ui, "wrote {}", a.out.display());
    Ok(())
}
