//! `arbor cbvh`: compresses the LBVH of a scene into a CBVH (\[P3\]) with a chosen encoder,
//! or refits a CBVH from an earlier time, and reports node writes, backtracking, memory
//! traffic (\[P3\] §5.2), the decoded tree's SAH and whether it encloses the geometry.
//! The JSON form (`arbor.cbvh.v1`) is documented in `docs/cli-json.md`.

use super::build::mesh_aabbs;
use super::{ms, open_scene, thousands, SceneArgs};
use crate::progress::Ui;
use anyhow::{bail, Context};
use cbvh::bottomup::{compress_hlbvh, StreamConfig};
use cbvh::study::{build_lbvh, Encoder};
use cbvh::traffic::{self, Counts, Traffic};
use cbvh::{compress_topdown, enclosure_violations, refit_streaming, Coords, EncodeStats, Params};
use serde::Serialize;
use std::time::Instant;

/// The compression options of `arbor cbvh`, shared with `arbor render --format cbvh`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct CbvhOptions {
    /// Encoder: `topdown` (postprocessing) or `bottomup` (streaming, Algorithm 1)
    /// [default: bottomup].
    #[arg(long, value_enum)]
    encoder: Option<EncoderArg>,
    /// Coordinates: `relative`, `modulo` or `plane-sharing` (modulo coordinates whose pairs
    /// reuse their node's planes, \[P3\] §4.5's open problem) [default: modulo].
    #[arg(long, value_enum)]
    coords: Option<CoordsArg>,
    /// Treelet depth (1 = none; 2..=8; bottom-up only) [default: 1].
    #[arg(long, value_name = "D")]
    treelet: Option<u32>,
    /// Bits per coordinate (3..=8) [default: 6].
    #[arg(long, value_name = "N")]
    bits: Option<u32>,
    /// Minimum scale exponent (\[P3\] §4.4) [default: -30].
    #[arg(long, value_name = "E", allow_hyphen_values = true)]
    min_scale_exp: Option<i32>,
}

/// The encoder and its configuration chosen by [`CbvhOptions`].
#[derive(Clone, Copy, Debug)]
pub struct CbvhChoice {
    /// Top-down or bottom-up.
    pub encoder: Encoder,
    /// Parameters and treelet depth (for bottom-up).
    pub cfg: StreamConfig,
}

impl Default for CbvhChoice {
    /// The defaults of `arbor cbvh`: bottom-up, modulo coordinates, no treelets, 6 bits,
    /// minimum scale 2^-30.
    fn default() -> Self {
        CbvhOptions::default()
            .resolve()
            .expect("the defaults are valid")
    }
}

impl CbvhOptions {
    /// True when any option was given.
    pub fn any_given(&self) -> bool {
        self.encoder.is_some()
            || self.coords.is_some()
            || self.treelet.is_some()
            || self.bits.is_some()
            || self.min_scale_exp.is_some()
    }

    /// The options with defaults filled in, checked.
    pub fn resolve(&self) -> anyhow::Result<CbvhChoice> {
        let treelet = self.treelet.unwrap_or(1);
        if treelet == 0 || treelet > cbvh::bottomup::MAX_TREELET_DEPTH {
            bail!(
                "--treelet must be 1..={}, got {treelet}",
                cbvh::bottomup::MAX_TREELET_DEPTH
            );
        }
        let encoder = match self.encoder.unwrap_or(EncoderArg::Bottomup) {
            EncoderArg::Topdown => Encoder::Topdown,
            EncoderArg::Bottomup => Encoder::Bottomup,
        };
        if encoder == Encoder::Topdown && treelet != 1 {
            bail!("--treelet applies to the bottom-up encoder only");
        }
        let params = Params {
            bits: self.bits.unwrap_or(cbvh::grid::DEFAULT_BITS),
            min_scale_exp: self
                .min_scale_exp
                .unwrap_or(cbvh::grid::DEFAULT_MIN_SCALE_EXP),
            coords: match self.coords.unwrap_or(CoordsArg::Modulo) {
                CoordsArg::Relative => Coords::Relative,
                CoordsArg::Modulo => Coords::Modulo,
                CoordsArg::PlaneSharing => Coords::PlaneSharing,
            },
        };
        params.check()?;
        Ok(CbvhChoice {
            encoder,
            cfg: StreamConfig {
                params,
                treelet_depth: treelet,
                ..StreamConfig::default()
            },
        })
    }
}

/// Arguments of `arbor cbvh`.
#[derive(clap::Args, Debug)]
pub struct CbvhArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    options: CbvhOptions,
    /// Time in seconds to sample the scene at.
    #[arg(long, value_name = "SECONDS", conflicts_with = "frame")]
    time: Option<f32>,
    /// Frame number to sample the scene at.
    #[arg(long, value_name = "N")]
    frame: Option<u32>,
    /// Build the CBVH at time T0 and refit it to --time/--frame (stable topology only).
    #[arg(long, value_name = "T0")]
    refit_from: Option<f32>,
    /// Print the `arbor.cbvh.v1` JSON document instead of text.
    #[arg(long)]
    json: bool,
}

/// `--encoder` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum EncoderArg {
    Topdown,
    Bottomup,
}

/// `--coords` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum CoordsArg {
    Relative,
    Modulo,
    PlaneSharing,
}

/// The JSON document of `arbor cbvh --json` (`arbor.cbvh.v1`).
#[derive(Serialize)]
pub struct CbvhJson {
    schema: &'static str,
    scene: String,
    time_s: f32,
    refit_from_s: Option<f32>,
    encoder: Encoder,
    coords: Coords,
    treelet_depth: u32,
    bits: u32,
    min_scale_exp: i32,
    triangles: usize,
    nodes: u64,
    leaves: u64,
    avg_leaf_size: f64,
    node_bytes: u64,
    backtrack_steps: u64,
    backtrack_depth_hist: Vec<u64>,
    backtrack_unchanged: u64,
    traffic_bytes: u64,
    traffic: Traffic,
    topdown_traffic_bytes: u64,
    traffic_vs_topdown: f64,
    decoded_encloses_original: bool,
    enclosure_violations: u64,
    sah: f64,
    sah_uncompressed: f64,
    sah_vs_uncompressed: f64,
    lbvh_ms: f64,
    encode_ms: f64,
}

/// Runs `arbor cbvh`.
pub fn run(a: &CbvhArgs, ui: &Ui) -> anyhow::Result<()> {
    let CbvhChoice { encoder, cfg } = a.options.resolve()?;
    let params = cfg.params;
    let (scene, _) = open_scene(&a.scene, ui)?;
    let timeline = scene.info().timeline;
    super::check_seconds("--refit-from", a.refit_from)?;
    let time_s = super::resolve_time(scene.info(), a.time, a.frame)?;
    if a.refit_from.is_some() && !scene.info().stable_topology {
        bail!("--refit-from needs a scene whose topology does not change over time");
    }
    let build_time = a.refit_from.map_or(time_s, |t| timeline.clamp(t));
    let mesh = scene
        .mesh_at(build_time)
        .context("cannot sample the scene")?;
    let (prims0, _) = mesh_aabbs(&mesh)?;
    drop(mesh);
    let prims = if a.refit_from.is_some() {
        let mesh = scene.mesh_at(time_s).context("cannot sample the scene")?;
        let p = mesh_aabbs(&mesh)?.0;
        if p.len() != prims0.len() {
            bail!("the triangle count changes between the two times");
        }
        p
    } else {
        prims0.clone()
    };
    let spin = ui.spinner("LBVH build");
    let s = Instant::now();
    let (hl, mut bvh) = build_lbvh(&prims0)?;
    let lbvh_ms = ms(s.elapsed());
    drop(spin);
    let spin = ui.spinner("compressing");
    let s = Instant::now();
    let (tree, stats): (cbvh::Cbvh, EncodeStats) = match (encoder, a.refit_from) {
        (Encoder::Topdown, None) => compress_topdown(&bvh, &params)?,
        (Encoder::Bottomup, None) => compress_hlbvh(&hl, &cfg)?,
        (Encoder::Topdown, Some(_)) => {
            // Full-precision refit, then top-down compression (the baseline).
            bvh::refit_bvh2(&mut bvh, &prims).context("refit")?;
            compress_topdown(&bvh, &params)?
        }
        (Encoder::Bottomup, Some(_)) => {
            let (built, _) = compress_hlbvh(&hl, &cfg)?;
            refit_streaming(&built, &prims, &cfg)?
        }
    };
    let encode_ms = ms(s.elapsed());
    drop(spin);
    if a.refit_from.is_some() && encoder == Encoder::Bottomup {
        bvh::refit_bvh2(&mut bvh, &prims).context("refit")?;
    }
    let decoded = tree.decode_to_bvh2()?;
    let violations = enclosure_violations(&decoded, &prims)?;
    let st = bvh.stats();
    let counts = Counts {
        prims: prims.len() as u64,
        node_pairs: tree.pairs.len() as u64,
        backtrack_steps: stats.backtrack_steps,
    };
    let (t, td) = match a.refit_from {
        None => (
            match encoder {
                Encoder::Topdown => traffic::lbvh_topdown(&counts),
                Encoder::Bottomup => traffic::lbvh_bottomup(&counts),
            },
            traffic::lbvh_topdown(&counts),
        ),
        Some(_) => (
            match encoder {
                Encoder::Topdown => traffic::refit_topdown(&counts),
                Encoder::Bottomup => traffic::refit_bottomup(&counts),
            },
            traffic::refit_topdown(&counts),
        ),
    };
    let sah = bvh::sah_cost(&decoded);
    let sah_unc = bvh::sah_cost(&bvh);
    let out = CbvhJson {
        schema: "arbor.cbvh.v1",
        scene: a.scene.scene.clone(),
        time_s,
        refit_from_s: a.refit_from.map(|_| build_time),
        encoder,
        coords: params.coords,
        treelet_depth: cfg.treelet_depth,
        bits: params.bits,
        min_scale_exp: params.min_scale_exp,
        triangles: prims.len(),
        nodes: tree.pairs.len() as u64,
        leaves: st.leaves as u64,
        avg_leaf_size: prims.len() as f64 / st.leaves.max(1) as f64,
        node_bytes: tree.node_bytes(),
        backtrack_steps: stats.backtrack_steps,
        backtrack_depth_hist: stats.backtrack_depth_hist.clone(),
        backtrack_unchanged: stats.backtrack_unchanged,
        traffic_bytes: t.total_bytes(),
        traffic: t,
        topdown_traffic_bytes: td.total_bytes(),
        traffic_vs_topdown: t.total_bytes() as f64 / td.total_bytes().max(1) as f64,
        decoded_encloses_original: violations == 0,
        enclosure_violations: violations,
        sah,
        sah_uncompressed: sah_unc,
        sah_vs_uncompressed: bvh::sah_ratio(sah, sah_unc),
        lbvh_ms,
        encode_ms,
    };
    if a.json {
        ui.emit_json(&out)?;
    } else {
        print_text(&out);
    }
    if violations > 0 {
        bail!("{violations} decoded boxes do not enclose their geometry (a bug: please report)");
    }
    Ok(())
}

fn print_text(o: &CbvhJson) {
    let what = if o.refit_from_s.is_some() {
        "refit"
    } else {
        "LBVH"
    };
    println!(
        "{}: {} triangles, {} node pairs, {:.2} triangles per leaf",
        o.scene,
        thousands(o.triangles as u64),
        thousands(o.nodes),
        o.avg_leaf_size
    );
    println!(
        "encoder {:?} {} treelet {} ({} bits, min scale 2^{})",
        o.encoder,
        o.coords.name(),
        o.treelet_depth,
        o.bits,
        o.min_scale_exp
    );
    println!(
        "backtracking steps  {} ({:.4} per node, {} re-encoded unchanged); by depth {:?}",
        thousands(o.backtrack_steps),
        o.backtrack_steps as f64 / o.nodes.max(1) as f64,
        thousands(o.backtrack_unchanged),
        o.backtrack_depth_hist
    );
    println!(
        "{what} traffic  {:.1} MB ({:.1} B/triangle), {:.3} of top-down compression",
        o.traffic_bytes as f64 / 1e6,
        o.traffic_bytes as f64 / o.triangles.max(1) as f64,
        o.traffic_vs_topdown
    );
    println!(
        "SAH  {:.3} vs {:.3} uncompressed ({:+.2}%); decoded boxes enclose the geometry: {}",
        o.sah,
        o.sah_uncompressed,
        (o.sah_vs_uncompressed - 1.0) * 100.0,
        if o.decoded_encloses_original {
            "yes"
        } else {
            "NO"
        }
    );
    println!(
        "times  LBVH {:.1} ms, encode {:.1} ms",
        o.lbvh_ms, o.encode_ms
    );
}
