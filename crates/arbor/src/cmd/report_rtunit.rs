//! `arbor report rtunit`: \[P4\] Table 2 from the accelerator model. The report is
//! library code (`report::rtunit`); this is its command line.

use super::report::SHARED_SCENES;
use crate::progress::Ui;
use report::rtunit::RtunitOptions;
use std::path::PathBuf;

/// Arguments of `arbor report rtunit`.
#[derive(clap::Args, Debug)]
pub struct ReportRtunitArgs {
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-rtunit")]
    out: PathBuf,
    /// Scenes, comma separated: mesh files or procedural specs. Default: Crytek Sponza
    /// (the thesis's scene we have) and the procedural stand-ins for Hairball and Rungholt
    /// at their sizes, plus Conference and Sibenik where they exist.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    /// Image width.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 720)]
    height: u32,
    /// Diffuse bounces (thesis P4 3.2: 4).
    #[arg(long, default_value_t = 4, value_name = "N")]
    bounces: u32,
    /// Scenes of more than 1M triangles are timed one in N tile chunks (1: whole frames).
    #[arg(long, default_value_t = 16, value_name = "N")]
    large_sample: u32,
    /// Time every scene one in N tile chunks (default: whole frames below 1M triangles,
    /// `--large-sample` above).
    #[arg(long, value_name = "N")]
    sample: Option<u32>,
    /// The sampling factor of the sampling check (0: no check).
    #[arg(long, default_value_t = 16, value_name = "N")]
    check_sample: u32,
    /// Override an accelerator parameter (repeatable), as in `arbor sim rtunit`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
}

impl ReportRtunitArgs {
    /// The options of the library's report.
    pub fn options(&self) -> RtunitOptions {
        RtunitOptions {
            out: self.out.clone(),
            scenes: self.scenes.clone(),
            scene_dir: self.scene_dir.clone(),
            width: self.width,
            height: self.height,
            bounces: self.bounces,
            large_sample: self.large_sample,
            sample: self.sample,
            check_sample: self.check_sample,
            set: self.set.clone(),
            energy: None,
        }
    }
}

/// Runs `arbor report rtunit`.
pub fn run(a: &ReportRtunitArgs, ui: &Ui) -> anyhow::Result<()> {
    let rep = report::rtunit::run(&a.options(), ui)?;
    crate::say!(ui, "{}", rep.table.markdown());
    crate::say!(ui, "{}", rep.table.table1_markdown());
    if !rep.checks.is_empty() {
        crate::say!(ui, "{}", rep.sampling_markdown());
    }
    crate::say!(ui, "wrote {}", a.out.join("report.md").display());
    Ok(())
}
