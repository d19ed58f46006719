//! `arbor sim rtunit` runs the ray-tracing accelerator model of \[P4\] (`sim::rtunit`) over
//! a scene: the TRV and IST pipelines, the node and primitive caches and DRAM, with the
//! binary BVH or the 4-wide MBVH, for primary rays or diffuse paths. Every ray's hit is
//! checked against the software tracer. The JSON form (`arbor.sim.rtunit.v1`) is
//! documented in `docs/cli-json.md`.

use super::{open_scene, thousands, SceneArgs};
use crate::progress::{Ui, Unit};
use anyhow::Context;
use geom::Triangle;
use sim::rtunit::{self, RayMode, RtConfig, RtReport, TreeKind, Workload};

/// Arguments of `arbor sim rtunit`.
#[derive(clap::Args, Debug)]
pub struct RtunitArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Tree: bvh2 (binary BVH from binned SAH, the thesis's baseline) or mbvh4 (4-wide MBVH
    /// from Wald's top-down builder, the thesis's proposal).
    #[arg(long, default_value = "bvh2")]
    tree: String,
    /// Build the tree with this builder instead (any `arbor build` builder: a binary one
    /// for bvh2 and cbvh, a 4-wide one for mbvh4), e.g. hlbvh for MergeTree's trees.
    #[arg(long, value_name = "NAME")]
    builder: Option<String>,
    /// With --builder mbvh4-collapse: the binary builder whose tree is collapsed (default
    /// binned-sah), e.g. hlbvh for MergeTree's tree collapsed after the build (against
    /// --builder mbvh4-stream, the tree collapsed as it is emitted).
    #[arg(long, value_name = "NAME")]
    collapse_from: Option<String>,
    /// How the mbvh4 tree is built: topdown (Wald's top-down builder, thesis P4 3.2, with
    /// the 4-wide node cost in its leaf decision), topdown-binary-leaf (the same with the
    /// earlier leaf decision, which priced the node as a binary one), collapse
    /// (the binned SAH tree collapsed greedily to 4 wide: the same leaves as bvh2),
    /// collapse-sah (collapsed SAH-optimally) or collapse-fill (collapsed into the fewest
    /// nodes).
    #[arg(long, default_value = "topdown", value_name = "NAME")]
    mbvh4_builder: String,
    /// Rays: primary or diffuse (1 sample per pixel, --bounces diffuse bounces).
    #[arg(long, default_value = "primary", value_name = "KIND")]
    rays: String,
    /// Diffuse bounces after the primary hit (thesis P4 3.2: 4).
    #[arg(long, default_value_t = 4, value_name = "N")]
    bounces: u32,
    /// Image width.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 720)]
    height: u32,
    /// Trace one in N of the image's 8x8 pixel tiles (1: the whole frame); frame traffic
    /// is then estimated as N times the traffic measured.
    #[arg(long, default_value_t = 1, value_name = "N")]
    sample: u32,
    /// Sampling seed of the diffuse bounces.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Vertical field of view in degrees, replacing the view's (e.g. a narrower view).
    #[arg(long, value_name = "DEGREES")]
    fov: Option<f32>,
    /// Time at which to sample the scene, in seconds.
    #[arg(long, value_name = "SECONDS")]
    time: Option<f32>,
    /// Size the FIFOs as the thesis does: run with 32-entry FIFOs, shrink each to the power
    /// of two above its highest occupancy, run again; print the sizes.
    #[arg(long)]
    size_fifos: bool,
    /// Override one parameter, e.g. --set l2_bytes=262144 (repeatable; `--set help=1`
    /// lists the keys).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Print the report as JSON (arbor.sim.rtunit.v1).
    #[arg(long)]
    json: bool,
}

fn config_of(a: &RtunitArgs) -> anyhow::Result<RtConfig> {
    let mut cfg = RtConfig::default();
    for s in &a.set {
        if s.starts_with("help") {
            anyhow::bail!("accelerator parameters: {}", rtunit::KEYS.join(", "));
        }
        cfg.set_pair(s)?;
    }
    Ok(cfg)
}

/// The settings of `--builder`: the defaults, with `--collapse-from` (which only
/// `--builder mbvh4-collapse` takes).
fn build_config_of(a: &RtunitArgs) -> anyhow::Result<super::build::BuildConfig> {
    let mut bc = super::build::BuildConfig::default();
    if let Some(from) = &a.collapse_from {
        anyhow::ensure!(
            a.builder.as_deref() == Some(super::build::COLLAPSE),
            "--collapse-from needs --builder {}",
            super::build::COLLAPSE
        );
        bc.collapse_from = super::build::available_builders()
            .find(|n| n == from)
            .with_context(|| format!("unknown --collapse-from builder '{from}'"))?;
    }
    Ok(bc)
}

/// The options of `a` that need no scene, checked: tree kind, ray set, MBVH4 builder and
/// the configuration.
fn options_of(a: &RtunitArgs) -> anyhow::Result<(TreeKind, RayMode, rtunit::Mbvh4Build, RtConfig)> {
    let kind = TreeKind::parse(&a.tree)?;
    let rays = match a.rays.as_str() {
        "primary" => RayMode::Primary,
        "diffuse" => RayMode::Diffuse,
        other => anyhow::bail!("unknown --rays '{other}' (known: primary, diffuse)"),
    };
    if let Some(name) = &a.builder {
        super::build::builder(name)?;
    }
    build_config_of(a)?;
    let mbvh4 = match a.mbvh4_builder.as_str() {
        "topdown" => rtunit::Mbvh4Build::Topdown,
        "collapse" => rtunit::Mbvh4Build::Collapse,
        "topdown-binary-leaf" => rtunit::Mbvh4Build::TopdownBinaryLeaf,
        "collapse-sah" => rtunit::Mbvh4Build::CollapseSah,
        "collapse-fill" => rtunit::Mbvh4Build::CollapseFill,
        other => anyhow::bail!(
            "unknown --mbvh4-builder '{other}' (known: topdown, topdown-binary-leaf, collapse, collapse-sah, collapse-fill)"
        ),
    };
    let cfg = config_of(a)?;
    cfg.validate(kind)?;
    anyhow::ensure!(
        a.width as u64 * a.height as u64 <= rtunit::MAX_PIXELS,
        "a {}x{} image has more than {} pixels, the most one run traces",
        a.width,
        a.height,
        rtunit::MAX_PIXELS
    );
    anyhow::ensure!(a.sample >= 1, "--sample must be at least 1");
    super::check_seconds("--time", a.time)?;
    Ok((kind, rays, mbvh4, cfg))
}

/// Checks the options of `a` without loading the scene or simulating: what a sweep checks
/// before it runs.
pub fn check_rtunit(a: &RtunitArgs) -> anyhow::Result<()> {
    options_of(a).map(|_| ())
}

/// Runs `arbor sim rtunit`.
pub fn run_rtunit(a: &RtunitArgs, ui: &Ui) -> anyhow::Result<()> {
    let (kind, rays, mbvh4, cfg) = options_of(a)?;
    let (scene, _) = open_scene(&a.scene, ui)?;
    let info = scene.info();
    let t = super::resolve_time(info, a.time, None)?;
    let mesh = scene
        .mesh_at(t)
        .with_context(|| format!("cannot sample the scene at t = {t} s"))?;
    let triangles: Vec<Triangle> = mesh.triangles_iter().collect();
    // The interior view reports use for the scenes that have one (crytek-sponza, ...).
    let mut view =
        super::report::view_camera(&super::report::short_name(&a.scene.scene), info.camera);
    if let Some(fov) = a.fov {
        anyhow::ensure!(
            fov.is_finite() && fov > 0.0 && fov < 180.0,
            "--fov must lie between 0 and 180 degrees, got {fov}"
        );
        view.vfov_deg = fov;
    }
    let camera = trace::PinholeCamera::new(&view, a.width, a.height)?;
    let tree = {
        let _s = ui.spinner(&format!(
            "building the {} tree over {} triangles",
            kind.name(),
            thousands(triangles.len() as u64)
        ));
        match &a.builder {
            None => rtunit::build_tree_with(kind, &triangles, mbvh4)?,
            Some(name) => {
                let (aabbs, _) = super::build::mesh_aabbs(&mesh)?;
                let tree = super::build::builder(name)?(&aabbs, &build_config_of(a)?)?;
                rtunit::tree_from(kind, tree, &triangles)?
            }
        }
    };
    let bar = ui.progress(
        &format!(
            "simulating the {} accelerator, {} rays",
            kind.name(),
            a.rays
        ),
        Unit::Items,
    );
    let hook = |done: u64, total: u64| bar.update(done, total);
    let work = Workload {
        triangles: &triangles,
        camera: &camera,
        rays,
        bounces: a.bounces,
        seed: a.seed,
        sample: a.sample,
        progress: Some(&hook),
    };
    let result = if a.size_fifos {
        rtunit::size_fifos(&tree, &work, &cfg).map(|(_, first, r)| (Some(first), r))
    } else {
        rtunit::run(&tree, &work, &cfg).map(|r| (None, r))
    };
    bar.finish();
    let (first, r) = result.context("accelerator simulation failed")?;
    if a.json {
        ui.emit_json(&r)?;
    } else {
        print_report(&r, first.as_ref());
    }
    anyhow::ensure!(
        r.hits_match_software,
        "{} of {} rays differ from the software tracer (a model bug)",
        r.mismatches,
        r.rays
    );
    Ok(())
}

fn print_report(r: &RtReport, first: Option<&RtReport>) {
    println!(
        "{} accelerator, {} rays, {}x{} ({} pixels{}), {}",
        r.tree.name(),
        match r.ray_kind {
            RayMode::Primary => "primary".to_string(),
            RayMode::Diffuse => format!("diffuse ({} bounces)", r.bounces),
        },
        r.width,
        r.height,
        thousands(r.pixels),
        if r.sample > 1 {
            format!(" timed: 1 in {} tile chunks", r.sample)
        } else {
            String::new()
        },
        r.memory_name
    );
    // A sampled figure carries its standard error from sampling (`sim::rtunit::sampling`).
    let se = |rel: Option<f64>| rel.map_or(String::new(), |e| format!(" ± {:.1}%", 100.0 * e));
    println!(
        "  {} rays in {} cycles ({:.3} ms at {} MHz): {:.1} MRPS{}",
        thousands(r.rays),
        thousands(r.cycles),
        r.seconds * 1e3,
        r.config.clock_mhz,
        r.mrps,
        se(r.sampling.map(|e| e.mrps))
    );
    println!(
        "  DRAM: {:.2} MB read, {:.2} MB written, bus {:.1}% busy; frame traffic {:.2} MB{}{}",
        r.dram_bytes_read as f64 / 1e6,
        r.dram_bytes_written as f64 / 1e6,
        100.0 * r.bus_utilization,
        r.frame_dram_mb,
        se(r.sampling.map(|e| e.frame_traffic)),
        if r.sample > 1 {
            " (estimated from the sample)"
        } else {
            ""
        }
    );
    let ts = &r.traffic_split;
    println!(
        "  counted DRAM bytes: nodes {:.2} MB first touches + {:.2} MB re-fetches, triangles {:.2} MB + {:.2} MB",
        ts.node_first_bytes as f64 / 1e6,
        ts.node_refetch_bytes as f64 / 1e6,
        ts.triangle_first_bytes as f64 / 1e6,
        ts.triangle_refetch_bytes as f64 / 1e6
    );
    println!(
        "  {} node visits, {} box tests, {} triangle tests; loops after misses: TRV {}, IST {}",
        thousands(r.node_visits),
        thousands(r.box_tests),
        thousands(r.triangle_tests),
        thousands(r.trv_loops),
        thousands(r.ist_loops)
    );
    println!(
        "  deepest stack {} of {} entries; hits equal the software tracer's: {}",
        r.max_stack_depth,
        r.config.stack_entries,
        if r.hits_match_software { "yes" } else { "NO" }
    );
    if let Some(e) = &r.energy {
        println!(
            "  energy at {} ({}): {:.3} mJ per frame{}, {:.0} mW, {:.2} mm^2, {:.1} MRPS/mm^2",
            e.node.name(),
            e.conventions.describe(),
            e.frame_mj,
            se(r.sampling.map(|_| e.frame_mj_rel_se)),
            e.power_mw,
            e.area_mm2,
            e.mrps_per_mm2
        );
        let parts: Vec<String> = e
            .units
            .iter()
            .map(|u| format!("{} {:.0} mW", u.unit, u.power_mw))
            .collect();
        println!("    {}", parts.join(", "));
    }
    println!("  caches:");
    for c in &r.caches {
        println!(
            "    {:<10} {:>12} accesses, hit rate {:.1}%",
            c.name,
            thousands(c.stats.line_accesses),
            100.0 * c.hit_rate
        );
    }
    println!("  units (busy, stalls):");
    for u in &r.units {
        let stalls: Vec<String> = u
            .stalls
            .iter()
            .filter(|(_, f)| *f > 0.0005)
            .map(|(n, f)| format!("{n} {:.1}%", 100.0 * f))
            .collect();
        println!(
            "    {:<10} busy {:>5.1}%  {}",
            u.name,
            100.0 * u.busy,
            stalls.join(", ")
        );
    }
    println!("  FIFOs (capacity, high water):");
    for (k, f) in r.fifos.iter().enumerate() {
        let before = first.map(|p| {
            format!(
                " (sized from {}, high water {})",
                p.fifos[k].capacity, p.fifos[k].high_water
            )
        });
        println!(
            "    {:<11} x{}  {:>5} {:>5}{}",
            f.name,
            f.count,
            f.capacity,
            f.high_water,
            before.unwrap_or_default()
        );
    }
}
