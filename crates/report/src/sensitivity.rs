//! Every open assumption of the models swept over its documented range, one at a time,
//! with the default, lowest and highest value of every reproduced figure (\[P2\] Tables
//! III, IV, VI, VII and VIII, \[P4\] Tables 1 and 2) and the assumption that moves it
//! most, beside the thesis's value. The study is `sim::system::sensitivity`; [`run`] loads
//! the scenes and writes to [`SensitivityOptions::out`]:
//! - `sensitivity.md` / `sensitivity.csv`: a row per figure;
//! - `sensitivity.json`: the document (`arbor.report.sensitivity.v1`).

use crate::fs::write_file;
use crate::progress::Progress;
use crate::system::{load_static, static_scene_specs, SocOptions};
use anyhow::Context;
use sim::system::report::SystemScene;
use sim::system::sensitivity::{assumptions, run as sweep, Assumption, P4Scene, SensitivityReport};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

/// Options of the sensitivity report.
#[derive(Clone, Debug)]
pub struct SensitivityOptions {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Scenes (mesh files or procedural specs). Default: those of the system report.
    pub scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    pub scene_dir: PathBuf,
    /// Scene of the [P4] Table 2 part, or `none`. Default: Crytek Sponza under
    /// `scene_dir`, [P4]'s scene, when it exists.
    pub p4_scene: Option<String>,
    /// Only these assumptions' keys (default: all).
    pub only: Option<Vec<String>>,
    /// A small study in about a minute: a 50K-triangle procedural scene at 320x180.
    pub quick: bool,
    /// The SoC and frame.
    pub soc: SocOptions,
    /// Time one in N chunks of 16 pixel tiles of each frame.
    pub sample: u32,
}

impl Default for SensitivityOptions {
    fn default() -> Self {
        SensitivityOptions {
            out: "arbor-out/report-sensitivity".into(),
            scenes: None,
            scene_dir: crate::scenes::shared_scenes(),
            p4_scene: None,
            only: None,
            quick: false,
            soc: SocOptions::default(),
            sample: 16,
        }
    }
}

/// \[P4\] Table 2's name of a scene of ours (`Crytek` for Crytek Sponza), or "" when the
/// thesis has no row for it.
fn thesis_p4_name(name: &str) -> &'static str {
    let n = name.to_ascii_lowercase();
    ["Crytek", "Fairy", "Hairball", "Rungholt"]
        .into_iter()
        .find(|t| n.contains(&t.to_ascii_lowercase()))
        .unwrap_or("")
}

/// The assumptions `--only` keeps, or an error naming the unknown key.
pub fn chosen(only: Option<&[String]>) -> anyhow::Result<Vec<Assumption>> {
    let all = assumptions();
    let Some(keys) = only else {
        return Ok(all);
    };
    let known: Vec<&str> = all.iter().map(|a| a.key).collect();
    for k in keys {
        anyhow::ensure!(
            known.contains(&k.as_str()),
            "unknown assumption '{k}' (known: {})",
            known.join(", ")
        );
    }
    Ok(all
        .into_iter()
        .filter(|a| keys.iter().any(|k| k == a.key))
        .collect())
}

/// Runs the sensitivity study: writes its files and returns the document.
pub fn run(a: &SensitivityOptions, ui: &dyn Progress) -> anyhow::Result<SensitivityReport> {
    let picked = chosen(a.only.as_deref())?;
    anyhow::ensure!(a.sample >= 1, "--sample must be at least 1");
    let cfg = a.soc.config()?;
    let (specs, width, height, sample) = if a.quick {
        (
            vec!["proc:hairball?n=50000".to_string()],
            320,
            180,
            a.sample.min(4),
        )
    } else {
        (
            static_scene_specs(a.scenes.as_deref(), &a.scene_dir, ui),
            a.soc.width,
            a.soc.height,
            a.sample,
        )
    };
    let p4_spec = match (&a.p4_scene, a.quick) {
        (_, true) => None,
        (Some(s), _) if s == "none" => None,
        (Some(s), _) => Some(s.clone()),
        (None, _) => {
            let p = a.scene_dir.join("crytek-sponza.ply");
            if p.is_file() {
                Some(p.display().to_string())
            } else {
                ui.warn(&format!("{} not found: no [P4] part", p.display()));
                None
            }
        }
    };
    anyhow::ensure!(!specs.is_empty() || p4_spec.is_some(), "no scenes to study");
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut loaded = Vec::new();
    for spec in &specs {
        loaded.push(load_static(spec, width, height, ui)?);
    }
    let scenes: Vec<SystemScene> = loaded
        .iter()
        .map(|(name, tris, camera)| SystemScene {
            name: name.clone(),
            triangles: tris,
            camera: *camera,
            sample,
        })
        .collect();
    let p4_loaded = match &p4_spec {
        Some(spec) => Some(load_static(spec, width, height, ui)?),
        None => None,
    };
    let p4 = p4_loaded.as_ref().map(|(name, tris, camera)| P4Scene {
        thesis_scene: thesis_p4_name(name),
        name: name.clone(),
        triangles: tris,
        camera: *camera,
        sample,
    });
    // One step per build and trace of every variant and scene, one per MergeTree on
    // [P2]'s systems, and one per variant of the [P4] part.
    let variants = 1 + picked.iter().map(|x| x.values.len()).sum::<usize>();
    let total = ((13 * scenes.len() + usize::from(p4.is_some())) * variants) as u64;
    let bar = ui.bar("sensitivity runs");
    let done = AtomicU64::new(0);
    let rep = sweep(&scenes, p4.as_ref(), &cfg, &picked, |_| {
        let d = done.fetch_add(1, Ordering::Relaxed) + 1;
        bar.update(d.min(total), total);
    })?;
    bar.finish();
    let mut md = String::from("# Sensitivity of the reproduced figures to their assumptions\n\n");
    md += &format!(
        "{}x{}, {} ({}) on {}, one in {} tile chunks timed; scenes: {}. Each assumption is \
         set to each of its values with the others at their defaults; low and high are \
         the extremes over all variants, the driver the assumption whose values spread the \
         figure most. [P2] Tables III, IV, VI and VII are MergeTree's (preset p2) on \
         [P2]'s three memory systems (slow, medium, fast; Table IV on the fast one for the \
         largest scene, Table VII means over the scenes, the thesis's over its 14); Table \
         VIII's figures are energies relative to binned SAH; [P4] Table 2's are MBVH4's \
         changes over BVH2 at [P4]'s settings (45 nm, 4 bounces), and Table 1's the area \
         and power of their units (the thesis's are Fairy's). {} cycle-level runs \
         simulated, {} reused between variants.\n\n",
        width,
        height,
        cfg.node.name(),
        cfg.energy.describe(),
        cfg.dram,
        sample,
        rep.scenes
            .iter()
            .map(|(n, t)| format!("{n} ({t})"))
            .collect::<Vec<_>>()
            .join(", "),
        rep.simulated,
        rep.reused
    );
    md += "## Assumptions\n\n";
    md += &rep.assumptions_markdown();
    md += "\n## Figures\n\n";
    md += &rep.markdown();
    write_file(&a.out, "sensitivity.md", &md)?;
    write_file(&a.out, "sensitivity.csv", &rep.csv())?;
    write_file(
        &a.out,
        "sensitivity.json",
        &serde_json::to_string_pretty(&rep)?,
    )?;
    Ok(rep)
}
