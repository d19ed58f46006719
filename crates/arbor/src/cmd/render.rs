//! `arbor render`: builds a tree over a scene at one time (and, for `--format cbvh`,
//! compresses it as `arbor cbvh` does, \[P3\]), traces an image through it (primary rays,
//! diffuse path tracing or shadow rays) and writes the shaded image, the
//! depth buffer, a traversal-cost heatmap, the statistics and the traversal log
//! (`trace` crate). The statistics JSON (`arbor.render.v1`) is documented in
//! `docs/cli-json.md`, the log format in `docs/trace-log.md`.

use super::build::{builder, mesh_aabbs, timed_build, BuildConfig, MAX_THREADS};
use super::cbvh::{CbvhChoice, CbvhOptions};
use super::{ms, open_scene, thousands, SceneArgs};
use crate::progress::{Ui, Unit};
use anyhow::{bail, Context};
use geom::{Aabb, Triangle, Vec3};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;
use trace::log::{LogHeader, LogWriter};
use trace::{Accel, KernelOptions, RayKind, RayStats, RenderSettings, Traverse};

/// Largest `--width`/`--height`.
pub const MAX_SIDE: u32 = 16_384;

/// Averages `spp - 1` more samples per pixel (seeds `settings.seed + 1`, ...) into the
/// colours of `img`, a diffuse render of `settings` with `accel`; its depth buffer,
/// counters and statistics stay those of the first sample.
pub fn add_samples<T: trace::Traverse>(
    accel: &T,
    shading: trace::Shading<'_>,
    settings: &RenderSettings,
    img: &mut trace::Render,
    spp: u32,
) -> anyhow::Result<()> {
    if spp <= 1 {
        return Ok(());
    }
    let mut sum: Vec<[f64; 3]> = img.color.iter().map(|c| c.map(|x| x as f64)).collect();
    for k in 1..spp {
        let s = RenderSettings {
            seed: settings.seed.wrapping_add(k as u64),
            ..settings.clone()
        };
        let more = trace::render(accel, shading, &s, None, None).context("rendering failed")?;
        for (acc, c) in sum.iter_mut().zip(&more.color) {
            for i in 0..3 {
                acc[i] += c[i] as f64;
            }
        }
    }
    for (c, acc) in img.color.iter_mut().zip(&sum) {
        *c = acc.map(|x| (x / spp as f64) as f32);
    }
    Ok(())
}

/// Smooths a diffuse render's noise: each pixel that hit the scene becomes the mean of the
/// pixels within 2 of it (a 5x5 window) whose primary hit lies at a depth within 3% of
/// its own, so that edges between surfaces at different depths stay sharp. The backdrop
/// is left alone.
pub fn denoise(img: &mut trace::Render) {
    let (w, h) = (img.width as usize, img.height as usize);
    let src = img.color.clone();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let d = img.depth[i];
            if !d.is_finite() {
                continue;
            }
            let (mut acc, mut n) = ([0.0f32; 3], 0u32);
            for yy in y.saturating_sub(2)..(y + 3).min(h) {
                for xx in x.saturating_sub(2)..(x + 3).min(w) {
                    let j = yy * w + xx;
                    if (img.depth[j] - d).abs() <= 0.03 * d {
                        for c in 0..3 {
                            acc[c] += src[j][c];
                        }
                        n += 1;
                    }
                }
            }
            img.color[i] = acc.map(|a| a / n as f32);
        }
    }
}

/// Mean luminance of the pixels a diffuse picture is exposed to ([`expose`]).
pub const EXPOSURE_TARGET: f32 = 0.3;

/// Exposes a diffuse render's picture from its own luminance: scales the colours of the
/// pixels whose primary ray hit the scene (not the backdrop) so that their mean luminance
/// is [`EXPOSURE_TARGET`], brightening by at most 16 times and never darkening (a scene
/// lit through a window is mostly dark at first). Returns the factor.
pub fn expose(img: &mut trace::Render) -> f32 {
    let lum = |c: &[f32; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    let (mut sum, mut n) = (0.0f64, 0u64);
    for (c, d) in img.color.iter().zip(&img.depth) {
        if d.is_finite() {
            sum += lum(c) as f64;
            n += 1;
        }
    }
    if n == 0 || sum <= 0.0 {
        return 1.0;
    }
    let k = (EXPOSURE_TARGET / (sum / n as f64) as f32).clamp(1.0, 16.0);
    for (c, d) in img.color.iter_mut().zip(&img.depth) {
        if d.is_finite() {
            *c = c.map(|x| x * k);
        }
    }
    k
}

/// Arguments of `arbor render`.
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Builder of the tree (see `arbor build`); `mbvh4-topdown` builds the 4-wide tree
    /// natively, any other builder's tree is collapsed for `--format mbvh4`.
    #[arg(long, value_name = "NAME", default_value = "binned-sah")]
    builder: String,
    /// Tree format to trace: bvh2, mbvh4, mbvh8 (8-wide, beyond the thesis), or cbvh (the
    /// binary tree compressed into 16-byte
    /// node pairs of the thesis's P3; --encoder, --coords, --treelet, --bits and
    /// --min-scale-exp as for `arbor cbvh`).
    #[arg(long, value_name = "FORMAT", default_value = "bvh2")]
    format: String,
    /// Compression of `--format cbvh`.
    #[command(flatten)]
    cbvh: CbvhOptions,
    /// Rays: primary, diffuse (path tracing, --spp samples per pixel) or shadow (primary plus
    /// one occlusion ray per hit).
    #[arg(long, value_name = "KIND", default_value = "primary")]
    rays: String,
    /// Diffuse bounces after the primary hit (--rays diffuse; [P4] uses 4, [P2] 3).
    #[arg(long, value_name = "N", default_value_t = 4)]
    bounces: u32,
    /// Time in seconds at which to sample the scene.
    #[arg(long, value_name = "SECONDS", conflicts_with = "frame")]
    time: Option<f32>,
    /// Frame number at which to sample the scene.
    #[arg(long, value_name = "N")]
    frame: Option<u32>,
    /// Image width in pixels.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 720)]
    height: u32,
    /// Camera position as X,Y,Z (default: the scene's camera).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    eye: Option<String>,
    /// Point the camera looks at as X,Y,Z.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    target: Option<String>,
    /// Camera up direction as X,Y,Z.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    up: Option<String>,
    /// Vertical field of view in degrees.
    #[arg(long, value_name = "DEGREES")]
    fov: Option<f32>,
    /// Samples per pixel of the diffuse image (seeds SEED, SEED+1, ...); the statistics,
    /// depth buffer, heatmap and log are those of the first sample.
    #[arg(long, value_name = "N", default_value_t = 1)]
    spp: u32,
    /// Write the diffuse image as traced: no smoothing of the noise across pixels of
    /// similar depth and no exposure from the image's luminance.
    #[arg(long)]
    raw: bool,
    /// Sampling seed (diffuse rays).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Distance stack on or off (default: off for bvh2 and cbvh, on for mbvh4 and mbvh8, as
    /// in [P4] §3).
    #[arg(long, value_name = "on|off")]
    distance_stack: Option<String>,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Shaded image (PNG). Default: arbor-out/render/SCENE.png.
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Depth buffer of the primary hit distance (+inf for a miss): .pfm or .npy.
    #[arg(long, value_name = "FILE")]
    depth: Option<PathBuf>,
    /// Heatmap PNG: red = inner-node visits, blue = triangle tests per pixel.
    #[arg(long, value_name = "FILE")]
    heatmap: Option<PathBuf>,
    /// Heatmap scale as NODES,TRIS (counts shown at full intensity; default: the image's
    /// maxima). Give several renders the same scale to compare them.
    #[arg(long, value_name = "NODES,TRIS")]
    heatmap_scale: Option<String>,
    /// Statistics JSON (schema arbor.render.v1).
    #[arg(long, value_name = "FILE")]
    stats: Option<PathBuf>,
    /// Traversal log (docs/trace-log.md), streamed to disk.
    #[arg(long, value_name = "FILE")]
    log: Option<PathBuf>,
    /// Print the statistics JSON instead of text.
    #[arg(long)]
    json: bool,
}

/// Counters of one bounce (or all) in the statistics JSON.
#[derive(Serialize, Debug)]
pub struct BounceJson {
    /// Bounce number (0 = primary rays), or null for the total.
    pub bounce: Option<usize>,
    /// The tracer's counters (flattened: `rays`, `hits`, `node_visits`, ...).
    #[serde(flatten)]
    pub counters: RayStats,
    /// Node visits per ray.
    pub node_visits_per_ray: f64,
    /// Box tests per ray.
    pub box_tests_per_ray: f64,
    /// Triangle tests per ray.
    pub tri_tests_per_ray: f64,
}

impl BounceJson {
    fn new(bounce: Option<usize>, s: &RayStats) -> Self {
        Self {
            bounce,
            counters: *s,
            node_visits_per_ray: s.per_ray(s.node_visits),
            box_tests_per_ray: s.per_ray(s.box_tests),
            tri_tests_per_ray: s.per_ray(s.tri_tests),
        }
    }
}

/// What `--format cbvh` compressed (the `cbvh` object of `arbor.render.v1`).
#[derive(Serialize, Debug)]
pub struct RenderCbvhJson {
    /// `topdown` or `bottomup`.
    pub encoder: cbvh::study::Encoder,
    /// `relative` or `modulo`.
    pub coords: cbvh::Coords,
    /// Treelet depth (1 = none).
    pub treelet_depth: u32,
    /// Bits per coordinate.
    pub bits: u32,
    /// Minimum scale exponent.
    pub min_scale_exp: i32,
    /// Backtracking steps of the encoder (0 for top-down).
    pub backtrack_steps: u64,
    /// Compression time (included in `build_ms`).
    pub encode_ms: f64,
}

/// The statistics document (`arbor.render.v1`).
#[derive(Serialize, Debug)]
pub struct RenderJson {
    /// `"arbor.render.v1"`.
    pub schema: &'static str,
    /// Scene spec.
    pub scene: String,
    /// Time sampled.
    pub time_s: f32,
    /// Builder name.
    pub builder: String,
    /// `bvh2`, `mbvh4` or `cbvh`.
    pub format: String,
    /// The compression, for `cbvh` (null otherwise).
    pub cbvh: Option<RenderCbvhJson>,
    /// Distance stack on.
    pub distance_stack: bool,
    /// `primary`, `diffuse` or `shadow`.
    pub ray_kind: RayKind,
    /// Bounce limit (diffuse).
    pub bounces: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Triangles.
    pub triangles: usize,
    /// Nodes in the tree.
    pub nodes: usize,
    /// Tree bytes (nodes and leaf table).
    pub tree_bytes: usize,
    /// Tree build time (and collapse, for mbvh4 from a binary builder).
    pub build_ms: f64,
    /// Worker threads.
    pub threads: usize,
    /// Total rays.
    pub rays: u64,
    /// Total hits.
    pub hits: u64,
    /// Total inner-node visits.
    pub node_visits: u64,
    /// Total box tests.
    pub box_tests: u64,
    /// Total triangle tests.
    pub tri_tests: u64,
    /// Tracing wall time in seconds.
    pub seconds: f64,
    /// Millions of rays per second.
    pub mrays_per_s: f64,
    /// Counters per bounce.
    pub per_bounce: Vec<BounceJson>,
    /// Counters over all rays.
    pub total: BounceJson,
    /// Heatmap scale used (null without --heatmap).
    pub heatmap_scale: Option<trace::image::HeatScale>,
    /// Files written.
    pub outputs: Vec<String>,
    /// Log size in bytes (null without --log).
    pub log_bytes: Option<u64>,
}

/// Parses `X,Y,Z`.
fn parse_vec3(flag: &str, s: &str) -> anyhow::Result<Vec3> {
    let v: Vec<f32> = s
        .split(',')
        .map(|p| p.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("{flag} must be three numbers X,Y,Z, got '{s}'"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Vec3::new(x, y, z)),
        _ => bail!("{flag} must be three finite numbers X,Y,Z, got '{s}'"),
    }
}

/// Parses `on`/`off`.
fn parse_on_off(flag: &str, s: &str) -> anyhow::Result<bool> {
    match s {
        "on" | "true" | "yes" => Ok(true),
        "off" | "false" | "no" => Ok(false),
        _ => bail!("{flag} must be on or off, got '{s}'"),
    }
}

/// Parses a ray kind name.
pub fn parse_ray_kind(s: &str) -> anyhow::Result<RayKind> {
    match s {
        "primary" => Ok(RayKind::Primary),
        "diffuse" => Ok(RayKind::Diffuse),
        "shadow" => Ok(RayKind::Shadow),
        _ => bail!("unknown ray kind '{s}'; valid: primary, diffuse, shadow"),
    }
}

/// Tree format of a traversal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Binary nodes.
    Bvh2,
    /// 4-wide nodes.
    Mbvh4,
    /// Compressed binary nodes (\[P3\]).
    Cbvh,
    /// 8-wide nodes (beyond the thesis: the SAH-guided collapse to eight children).
    Mbvh8,
}

/// Parses a format name.
pub fn parse_format(s: &str) -> anyhow::Result<Format> {
    match s {
        "bvh2" => Ok(Format::Bvh2),
        "mbvh4" => Ok(Format::Mbvh4),
        "cbvh" => Ok(Format::Cbvh),
        "mbvh8" => Ok(Format::Mbvh8),
        _ => bail!("unknown format '{s}'; valid: bvh2, mbvh4, mbvh8, cbvh"),
    }
}

/// Builds the tree `builder` in `format` over `aabbs` (in the current rayon pool) and
/// prepares it for tracing `triangles`. Returns it with the build time in ms. A `cbvh`
/// gets the default compression of `arbor cbvh` (see [`build_accel_with`]).
pub fn build_accel(
    ui: &Ui,
    builder_name: &str,
    format: Format,
    aabbs: &[Aabb],
    triangles: &[Triangle],
    options: KernelOptions,
) -> anyhow::Result<(Accel, f64)> {
    let (accel, build_ms, _) = build_accel_with(
        ui,
        builder_name,
        format,
        &CbvhChoice::default(),
        aabbs,
        triangles,
        options,
    )?;
    Ok((accel, build_ms))
}

/// [`build_accel`] with the compression of `--format cbvh`: the binary tree is compressed
/// top-down, or streamed bottom-up through the encoder in depth-first postorder (the order
/// a streaming builder emits it, \[P3\] Algorithm 1). The build time includes the
/// compression; the third value describes it (`None` for the other formats).
pub fn build_accel_with(
    ui: &Ui,
    builder_name: &str,
    format: Format,
    choice: &CbvhChoice,
    aabbs: &[Aabb],
    triangles: &[Triangle],
    options: KernelOptions,
) -> anyhow::Result<(Accel, f64, Option<RenderCbvhJson>)> {
    let spatial = super::build::cuts_triangles(builder_name);
    anyhow::ensure!(
        !(spatial && format == Format::Cbvh),
        "builder {builder_name} cuts triangles, which the compressed formats cannot hold yet; use --format bvh2, mbvh4 or mbvh8"
    );
    let cfg = BuildConfig {
        triangles: spatial.then(|| triangles.into()),
        ..Default::default()
    };
    if builder_name == "mbvh4-topdown" {
        anyhow::ensure!(
            format == Format::Mbvh4,
            "builder mbvh4-topdown makes a 4-wide tree; use --format mbvh4"
        );
        let spinner = ui.spinner(&format!(
            "building mbvh4-topdown over {} triangles",
            thousands(aabbs.len() as u64)
        ));
        let s = Instant::now();
        let t = bvh::Mbvh4TopDownBuilder::default()
            .build(aabbs)
            .context("builder mbvh4-topdown failed")?;
        let build_ms = ms(s.elapsed());
        drop(spinner);
        bvh::validate_mbvh4(&t, aabbs, cfg.max_leaf)
            .context("builder mbvh4-topdown produced an invalid tree")?;
        return Ok((
            Accel::Mbvh4(trace::Mbvh4Accel::new(t, triangles, options)?),
            build_ms,
            None,
        ));
    }
    let f = builder(builder_name)?;
    let (tree, mut build_ms) = timed_build(ui, builder_name, f, &cfg, aabbs)?;
    let bvh::Tree::Bvh2(tree) = tree else {
        bail!("builder {builder_name} makes a 4-wide tree; use a binary builder (--format mbvh4 collapses its tree)")
    };
    let valid = if spatial {
        bvh::validate_spatial(&tree, aabbs, cfg.max_leaf)
    } else {
        bvh::validate(&tree, aabbs, cfg.max_leaf)
    };
    valid.with_context(|| format!("builder {builder_name} produced an invalid tree"))?;
    Ok(match format {
        Format::Bvh2 => (
            Accel::Bvh2(trace::Bvh2Accel::new(tree, triangles, options)?),
            build_ms,
            None,
        ),
        Format::Mbvh4 => {
            let s = Instant::now();
            let m = bvh::collapse(&tree).context("cannot collapse the tree to MBVH4")?;
            build_ms += ms(s.elapsed());
            (
                Accel::Mbvh4(trace::Mbvh4Accel::new(m, triangles, options)?),
                build_ms,
                None,
            )
        }
        Format::Mbvh8 => {
            let s = Instant::now();
            let wide =
                trace::Mbvh8Accel::collapse(&tree).context("cannot collapse the tree to 8 wide")?;
            build_ms += ms(s.elapsed());
            (
                Accel::Mbvh8(trace::Mbvh8Accel::new(wide, triangles, options)?),
                build_ms,
                None,
            )
        }
        Format::Cbvh => {
            let spinner = ui.spinner("compressing the tree");
            let s = Instant::now();
            let (c, stats) = match choice.encoder {
                cbvh::study::Encoder::Topdown => cbvh::compress_topdown(&tree, &choice.cfg.params),
                cbvh::study::Encoder::Bottomup => cbvh::compress_bottomup(&tree, &choice.cfg),
            }
            .context("cannot compress the tree")?;
            let encode_ms = ms(s.elapsed());
            drop(spinner);
            build_ms += encode_ms;
            let p = choice.cfg.params;
            let info = RenderCbvhJson {
                encoder: choice.encoder,
                coords: p.coords,
                treelet_depth: choice.cfg.treelet_depth,
                bits: p.bits,
                min_scale_exp: p.min_scale_exp,
                backtrack_steps: stats.backtrack_steps,
                encode_ms,
            };
            (
                Accel::Cbvh(trace::CbvhAccel::new(&c, triangles, options)?),
                build_ms,
                Some(info),
            )
        }
    })
}

/// Fails early when an output file cannot be written (a directory, or a missing folder).
fn check_output(flag: &str, p: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(!p.is_dir(), "{flag} {}: is a directory", p.display());
    let parent = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    anyhow::ensure!(
        parent.is_dir(),
        "{flag} {}: folder {} does not exist",
        p.display(),
        parent.display()
    );
    Ok(())
}

/// Runs `arbor render`.
pub fn run(a: &RenderArgs, ui: &Ui) -> anyhow::Result<()> {
    // Everything that needs no scene is checked first.
    let kind = parse_ray_kind(&a.rays)?;
    let format = parse_format(&a.format)?;
    anyhow::ensure!(
        format == Format::Cbvh || !a.cbvh.any_given(),
        "--encoder, --coords, --treelet, --bits and --min-scale-exp apply to --format cbvh only"
    );
    let choice = a.cbvh.resolve()?;
    if a.builder != "mbvh4-topdown" {
        builder(&a.builder)?;
    } else {
        anyhow::ensure!(
            format == Format::Mbvh4,
            "builder mbvh4-topdown makes a 4-wide tree; use --format mbvh4"
        );
    }
    anyhow::ensure!(
        (1..=1024).contains(&a.spp),
        "--spp must be between 1 and 1024, got {}",
        a.spp
    );
    anyhow::ensure!(
        (1..=MAX_SIDE).contains(&a.width) && (1..=MAX_SIDE).contains(&a.height),
        "--width and --height must be between 1 and {MAX_SIDE}, got {}x{}",
        a.width,
        a.height
    );
    anyhow::ensure!(
        a.bounces <= trace::render::MAX_BOUNCES,
        "--bounces must be at most {}, got {}",
        trace::render::MAX_BOUNCES,
        a.bounces
    );
    if let Some(t) = a.threads {
        anyhow::ensure!(
            (1..=MAX_THREADS).contains(&t),
            "--threads must be between 1 and {MAX_THREADS}, got {t}"
        );
    }
    let distance_stack = match &a.distance_stack {
        Some(s) => parse_on_off("--distance-stack", s)?,
        None => matches!(format, Format::Mbvh4 | Format::Mbvh8),
    };
    let heat_scale = match &a.heatmap_scale {
        None => None,
        Some(s) => {
            let v: Vec<u32> = s
                .split(',')
                .map(|p| p.trim().parse::<u32>())
                .collect::<Result<_, _>>()
                .ok()
                .filter(|v: &Vec<u32>| v.len() == 2 && v.iter().all(|&x| x > 0))
                .ok_or_else(|| {
                    anyhow::anyhow!(
                        "--heatmap-scale must be two positive integers NODES,TRIS, got '{s}'"
                    )
                })?;
            Some(trace::image::HeatScale {
                node_visits: v[0],
                tri_tests: v[1],
            })
        }
    };
    let eye = a
        .eye
        .as_deref()
        .map(|s| parse_vec3("--eye", s))
        .transpose()?;
    let target = a
        .target
        .as_deref()
        .map(|s| parse_vec3("--target", s))
        .transpose()?;
    let up = a.up.as_deref().map(|s| parse_vec3("--up", s)).transpose()?;
    if let Some(f) = a.fov {
        anyhow::ensure!(
            f.is_finite() && f > 0.0 && f < 180.0,
            "--fov must be between 0 and 180 degrees, got {f}"
        );
    }
    let out = a.out.clone();
    for (flag, p) in [
        ("--out", &out),
        ("--depth", &a.depth),
        ("--heatmap", &a.heatmap),
        ("--stats", &a.stats),
        ("--log", &a.log),
    ] {
        if let Some(p) = p {
            check_output(flag, p)?;
        }
    }
    if let Some(d) = &a.depth {
        let ext = d.extension().and_then(|e| e.to_str()).unwrap_or("");
        anyhow::ensure!(
            ext.eq_ignore_ascii_case("pfm") || ext.eq_ignore_ascii_case("npy"),
            "--depth {}: write .pfm or .npy",
            d.display()
        );
    }
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = a.threads {
            b = b.num_threads(t);
        }
        b.build().context("cannot create the worker thread pool")?
    };

    let (scene, _) = open_scene(&a.scene, ui)?;
    let info = scene.info();
    let time_s = super::resolve_time(info, a.time, a.frame)?;
    let mesh = {
        let _s = ui.spinner(&format!("sampling {} at t = {time_s} s", a.scene.scene));
        scene
            .mesh_at(time_s)
            .with_context(|| format!("cannot sample the scene at t = {time_s} s"))?
    };
    let (aabbs, _) = mesh_aabbs(&mesh)?;
    let triangles: Vec<Triangle> = mesh.triangles_iter().collect();
    let options = KernelOptions { distance_stack };
    let (accel, build_ms, cbvh_info) = pool.install(|| {
        build_accel_with(ui, &a.builder, format, &choice, &aabbs, &triangles, options)
    })?;
    drop(aabbs);

    let mut camera = info.camera;
    if let Some(e) = eye {
        camera.eye = e;
    }
    if let Some(t) = target {
        camera.target = t;
    }
    if let Some(u) = up {
        camera.up = u;
    }
    if let Some(f) = a.fov {
        camera.vfov_deg = f;
    }
    let settings = RenderSettings {
        width: a.width,
        height: a.height,
        rays: kind,
        bounces: a.bounces,
        seed: a.seed,
        camera,
    };
    let mut log = match &a.log {
        None => None,
        Some(p) => Some(LogWriter::create(
            p,
            &LogHeader {
                width: accel.width(),
                node_bytes: accel.node_bytes(),
                node_count: accel.node_count() as u64,
                leaf_entries: accel.leaf_entries() as u64,
                image_width: a.width,
                image_height: a.height,
                rays: kind,
                bounces: a.bounces.min(255) as u8,
                distance_stack,
                seed: a.seed,
            },
        )?),
    };
    let bar = ui.progress(
        &format!("tracing {}x{} {} rays", a.width, a.height, a.rays),
        Unit::Items,
    );
    let progress = |done: u64, total: u64| bar.update(done, total);
    let shading = trace::Shading {
        triangles: &triangles,
        material_ids: &mesh.material_ids,
    };
    let img =
        pool.install(|| trace::render(&accel, shading, &settings, log.as_mut(), Some(&progress)));
    bar.finish();
    let mut img = img.context("rendering failed")?;
    if kind == RayKind::Diffuse {
        let _s = (a.spp > 1).then(|| ui.spinner(&format!("{} more samples per pixel", a.spp - 1)));
        pool.install(|| add_samples(&accel, shading, &settings, &mut img, a.spp))?;
        if !a.raw {
            denoise(&mut img);
            expose(&mut img);
        }
    }
    let log_bytes = match log {
        Some(w) => Some(w.finish().context("cannot finish the traversal log")?),
        None => None,
    };

    let mut outputs = Vec::new();
    let image_path = match out {
        Some(p) => p,
        None => {
            let dir = PathBuf::from("arbor-out/render");
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create folder {}", dir.display()))?;
            dir.join(format!("{}.png", sanitize(&info.name)))
        }
    };
    trace::image::write_color_png(&image_path, &img)?;
    outputs.push(image_path.display().to_string());
    if let Some(p) = &a.depth {
        trace::image::write_depth(p, &img)?;
        outputs.push(p.display().to_string());
    }
    let mut used_scale = None;
    if let Some(p) = &a.heatmap {
        let sc = heat_scale.unwrap_or_else(|| trace::image::HeatScale::of(&img));
        trace::image::write_heatmap(p, &img, sc)?;
        used_scale = Some(sc);
        outputs.push(p.display().to_string());
    }
    if let Some(p) = &a.log {
        outputs.push(p.display().to_string());
    }
    let st = &img.stats;
    let j = RenderJson {
        schema: "arbor.render.v1",
        scene: a.scene.scene.clone(),
        time_s,
        builder: a.builder.clone(),
        format: accel.format_name().to_string(),
        cbvh: cbvh_info,
        distance_stack,
        ray_kind: kind,
        bounces: a.bounces,
        width: a.width,
        height: a.height,
        triangles: triangles.len(),
        nodes: accel.node_count(),
        tree_bytes: accel.tree_bytes(),
        build_ms,
        threads: st.threads,
        rays: st.total.rays,
        hits: st.total.hits,
        node_visits: st.total.node_visits,
        box_tests: st.total.box_tests,
        tri_tests: st.total.tri_tests,
        seconds: st.seconds,
        mrays_per_s: st.mrays_per_s,
        per_bounce: st
            .per_bounce
            .iter()
            .enumerate()
            .map(|(i, b)| BounceJson::new(Some(i), b))
            .collect(),
        total: BounceJson::new(None, &st.total),
        heatmap_scale: used_scale,
        outputs,
        log_bytes,
    };
    let text = serde_json::to_string_pretty(&j)?;
    if let Some(p) = &a.stats {
        trace::image::write_atomic(p, |w| {
            w.write_all(text.as_bytes())
                .and_then(|_| w.write_all(b"\n"))
                .map_err(|e| trace::TraceError::Io {
                    path: p.display().to_string(),
                    source: e,
                })
        })?;
    }
    if a.json {
        ui.emit_json(&j)?;
    } else {
        print_text(&j);
    }
    Ok(())
}

/// A file-name-safe version of a scene name.
pub fn sanitize(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "scene".into()
    } else {
        s
    }
}

fn print_text(j: &RenderJson) {
    println!(
        "scene         {} (t = {:.3} s), {} triangles",
        j.scene,
        j.time_s,
        thousands(j.triangles as u64)
    );
    println!(
        "tree          {} {} ({} nodes, {:.1} MiB), built in {:.1} ms; distance stack {}",
        j.builder,
        j.format,
        thousands(j.nodes as u64),
        j.tree_bytes as f64 / (1024.0 * 1024.0),
        j.build_ms,
        if j.distance_stack { "on" } else { "off" }
    );
    if let Some(c) = &j.cbvh {
        println!(
            "compressed    {:?} {} treelet {}, {} bits, min scale 2^{}: {} backtracking steps, {:.1} ms",
            c.encoder,
            c.coords.name(),
            c.treelet_depth,
            c.bits,
            c.min_scale_exp,
            thousands(c.backtrack_steps),
            c.encode_ms
        );
    }
    println!(
        "image         {}x{} {:?} rays{}",
        j.width,
        j.height,
        j.ray_kind,
        if j.ray_kind == RayKind::Diffuse {
            format!(", {} bounces", j.bounces)
        } else {
            String::new()
        }
    );
    println!(
        "              bounce       rays      hits  nodes/ray  boxes/ray   tris/ray  max stack"
    );
    for b in j.per_bounce.iter().chain(std::iter::once(&j.total)) {
        let label = b.bounce.map_or("total".to_string(), |i| i.to_string());
        println!(
            "              {label:>6} {:>10} {:>9} {:>10.2} {:>10.2} {:>10.2} {:>10}",
            b.counters.rays,
            b.counters.hits,
            b.node_visits_per_ray,
            b.box_tests_per_ray,
            b.tri_tests_per_ray,
            b.counters.max_stack_depth
        );
    }
    println!(
        "speed         {:.2} Mrays/s ({} rays in {:.3} s, {} threads)",
        j.mrays_per_s,
        thousands(j.rays),
        j.seconds,
        j.threads
    );
    for o in &j.outputs {
        println!("written       {o}");
    }
    if let Some(b) = j.log_bytes {
        println!(
            "log           {:.1} MiB ({:.1} bytes per ray)",
            b as f64 / (1024.0 * 1024.0),
            b as f64 / j.rays.max(1) as f64
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4x1 render: two backdrop pixels, then two hits at different depths.
    fn strip(color: [[f32; 3]; 4], depth: [f32; 4]) -> trace::Render {
        trace::Render {
            width: 4,
            height: 1,
            color: color.to_vec(),
            depth: depth.to_vec(),
            prim: vec![0; 4],
            node_visits: vec![0; 4],
            tri_tests: vec![0; 4],
            stats: Default::default(),
        }
    }

    #[test]
    fn exposure_brightens_the_scene_not_the_backdrop() {
        let inf = f32::INFINITY;
        let mut img = strip(
            [[0.1; 3], [0.1; 3], [0.01; 3], [0.03; 3]],
            [inf, inf, 1.0, 1.0],
        );
        let k = expose(&mut img);
        assert!((k - 15.0).abs() < 1e-3, "{k}");
        assert_eq!(img.color[0], [0.1; 3]);
        assert!((img.color[2][0] - 0.15).abs() < 1e-4 && (img.color[3][0] - 0.45).abs() < 1e-4);
        // Never darker: a bright image stays as it is.
        let mut img = strip([[0.9; 3]; 4], [1.0; 4]);
        assert_eq!(expose(&mut img), 1.0);
        assert_eq!(img.color[0], [0.9; 3]);
    }

    #[test]
    fn denoise_averages_within_a_surface_only() {
        let inf = f32::INFINITY;
        let mut img = strip(
            [[0.5; 3], [0.0; 3], [1.0; 3], [9.0; 3]],
            [inf, 1.0, 1.0, 5.0],
        );
        denoise(&mut img);
        // The backdrop is untouched; the two pixels at depth 1 share their mean; the
        // pixel at depth 5 keeps its own colour.
        assert_eq!(img.color, vec![[0.5; 3], [0.5; 3], [0.5; 3], [9.0; 3]]);
    }
}
