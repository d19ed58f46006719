//! `arbor bench build`: build speed, tree quality and peak memory of Arbor's builders next
//! to the peer libraries of issue 3 (Embree 3's Morton and binned SAH builders, obvhs
//! PLOC, the `bvh` crate), on the same meshes, in one process and one run, as ratios.
//!
//! For every scene the triangle boxes at t = 0 are built by every builder on each thread
//! count, `--runs` rounds of one build per builder in turn (so that load from other
//! processes falls on all builders alike); the fastest run is reported. Arbor's builders run in a rayon pool
//! of that size (created outside the timing) through the same registry as `arbor build`;
//! the peers through `crates/peers`, timed over the peer's build call alone (input copy
//! and conversion to `Bvh2` excluded), Embree on a device of that many threads. Every tree
//! is validated, and every SAH is Arbor's (the thesis weights, a 4-wide node costing
//! `2 C_i`), relative to Arbor's full sweep SAH tree (\[P2\] §6.2 "SAH %").
//!
//! Peak memory: the `arbor` binary's counting allocator ([`crate::alloc`]) gives the most
//! bytes allocated at once during the build call, above what was allocated before it (the
//! input boxes, already there, are not in it; the output tree, alive at the end, is). For
//! Embree the device's memory monitor adds Embree's own allocations. The reported ratio is
//! `(input + peak) / (input + output)`, where input is the 24-byte boxes Arbor builds from
//! and output the tree in Arbor's format; issue 3's goal is at most 2.
//!
//! The goals of issue 3 are evaluated from the same rows and printed after the table.

use super::bench::{goal_table, markdown_report, text_report, RunInfo};
use super::bench_record::{Record, RecordEntry};
use super::build::{
    builder, mesh_aabbs, reusing_builder, BuildConfig, Frame, SAH_REFERENCE_MAX_TRIANGLES,
};
use super::{open_scene, thousands, SceneArgs};
use crate::alloc::{peak_bytes, reset_peak, PeakMeter};
use crate::progress::{Ui, Unit};
use anyhow::{bail, Context};
use bvh::Tree;
use geom::Aabb;
use peers::{BuildProbe, BvhCrateBuilder, ObvhsBuilder, ObvhsPreset};
use report::table::{Align, Table};
use serde::Serialize;
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
use std::time::{Duration, Instant};

/// Scenes measured when none are given: procedural soups at the two ends of the issue's
/// 100K..4M range that run in about a minute.
pub const DEFAULT_SCENES: [&str; 2] = ["proc:soup?n=100000", "proc:soup?n=1000000"];
/// Largest `--runs`.
pub const MAX_RUNS: usize = 100;
/// Largest thread count accepted (as `arbor build --threads`).
pub const MAX_THREADS: usize = super::build::MAX_THREADS;
/// Bytes of one input primitive box (`geom::Aabb`: two `Vec3`).
pub const INPUT_BYTES_PER_PRIM: usize = std::mem::size_of::<Aabb>();

/// Issue 3's goal: HLBVH throughput over Embree's Morton (LOW) builder, at equal or
/// better SAH.
pub const GOAL_HLBVH_VS_LOW: f64 = 1.5;
/// Issue 3's goal: binned SAH throughput over Embree's binned SAH (MEDIUM) builder, at
/// equal or better SAH.
pub const GOAL_BINNED_VS_MEDIUM: f64 = 1.0;
/// Issue 3's goal: HLBVH+ATRBVH SAH at most this multiple of the sweep SAH...
pub const GOAL_ATRBVH_SAH: f64 = 1.10;
/// ... at less than this multiple of the HLBVH build time.
pub const GOAL_ATRBVH_TIME: f64 = 2.0;
/// Issue 3's goal: peak memory during a build at most this multiple of input plus output.
pub const GOAL_MEMORY: f64 = 2.0;

/// Output formats (of `arbor bench build` and `arbor bench trace`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Aligned text table and goal summary.
    Text,
    /// Markdown tables (for the README).
    Markdown,
    /// One CSV row per measurement.
    Csv,
    /// The versioned JSON document (`arbor.bench.build.v1`, `arbor.bench.trace.v1`,
    /// `arbor.bench.refit.v1`).
    Json,
}

/// A benchmark's document in every format: written to `out` as `<stem>.txt`, `.md`,
/// `.csv` and `.json` (atomically) when given, and printed in `format` unless `quiet`.
pub(crate) struct Rendered {
    pub text: String,
    pub markdown: String,
    pub csv: String,
    pub json: String,
}

impl Rendered {
    /// Writes and prints the renderings (see the type).
    pub(crate) fn emit(
        &self,
        out: Option<&std::path::Path>,
        stem: &str,
        format: Format,
        quiet: bool,
    ) -> anyhow::Result<()> {
        if let Some(dir) = out {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            for (ext, body) in [
                ("txt", &self.text),
                ("md", &self.markdown),
                ("csv", &self.csv),
                ("json", &self.json),
            ] {
                report::fs::write_atomic(&dir.join(format!("{stem}.{ext}")), body)?;
            }
        }
        if !quiet {
            print!(
                "{}",
                match format {
                    Format::Json => &self.json,
                    Format::Csv => &self.csv,
                    Format::Markdown => &self.markdown,
                    Format::Text => &self.text,
                }
            );
        }
        Ok(())
    }
}

/// Arguments of `arbor bench build`.
#[derive(clap::Args, Debug)]
pub struct BenchBuildArgs {
    /// Scenes, as for `arbor build` (default: proc:soup?n=100000 and proc:soup?n=1000000).
    pub scenes: Vec<String>,
    /// Thread counts, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2], value_name = "N,...")]
    pub threads: Vec<usize>,
    /// Runs per measurement; the fastest is reported.
    #[arg(long, default_value_t = 3, value_name = "N")]
    pub runs: usize,
    /// Builders, comma-separated (default all): Arbor's names as in `arbor build`, and the
    /// peers embree-low, embree-medium, obvhs-ploc-fastest, obvhs-ploc-fast, bvh-crate.
    #[arg(long, value_delimiter = ',', value_name = "NAME,...")]
    pub builders: Vec<String>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,
    /// Same as `--format json`.
    #[arg(long)]
    pub json: bool,
    /// Build the sweep SAH reference (and run sweep-sah) above 2M triangles too (slow).
    #[arg(long)]
    pub sah_reference: bool,
    /// Also write every format to DIR (bench-build.txt, .md, .csv, .json), atomically.
    #[arg(long, value_name = "DIR")]
    pub out: Option<std::path::PathBuf>,
    /// Also write the timings as a benchmark record to DIR/<cpu-slug>/build.json (for
    /// `arbor bench compare`; the committed ones are under bench/records).
    #[arg(long, value_name = "DIR")]
    pub record: Option<std::path::PathBuf>,
    /// Every Arbor build starts from new buffers. By default the builders that can (hlbvh)
    /// build into the buffers of their previous run, as a renderer rebuilding every frame
    /// does; their first run at each thread count is a fresh build either way.
    #[arg(long)]
    pub fresh: bool,
}

/// A peer library's builder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Peer {
    EmbreeLow,
    EmbreeMedium,
    ObvhsFastest,
    ObvhsFast,
    BvhCrate,
}

/// Peers by command-line name, with their table label.
const PEERS: [(&str, &str, Peer); 5] = [
    ("embree-low", "embree LOW", Peer::EmbreeLow),
    ("embree-medium", "embree MEDIUM", Peer::EmbreeMedium),
    (
        "obvhs-ploc-fastest",
        "obvhs PLOC fastest",
        Peer::ObvhsFastest,
    ),
    ("obvhs-ploc-fast", "obvhs PLOC fast", Peer::ObvhsFast),
    ("bvh-crate", "bvh crate", Peer::BvhCrate),
];

impl Peer {
    fn library(self) -> &'static str {
        match self {
            Peer::EmbreeLow | Peer::EmbreeMedium => "embree",
            Peer::ObvhsFastest | Peer::ObvhsFast => "obvhs",
            Peer::BvhCrate => "bvh crate",
        }
    }

    fn is_embree(self) -> bool {
        self.library() == "embree"
    }

    /// The largest leaf the peer makes (for the validator).
    fn max_leaf(self) -> u32 {
        match self {
            Peer::EmbreeLow | Peer::EmbreeMedium => 8,
            Peer::ObvhsFastest => ObvhsPreset::FastestBuild.max_leaf_size(),
            Peer::ObvhsFast => ObvhsPreset::FastBuild.max_leaf_size(),
            Peer::BvhCrate => 1,
        }
    }
}

/// One builder of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Entry {
    /// An Arbor builder of `arbor build`, by name.
    Arbor(&'static str),
    /// A peer's builder.
    Peer(Peer),
}

impl Entry {
    /// The command-line name.
    fn id(self) -> &'static str {
        match self {
            Entry::Arbor(n) => n,
            Entry::Peer(p) => PEERS.iter().find(|e| e.2 == p).expect("listed").0,
        }
    }

    /// The table label.
    fn label(self) -> String {
        match self {
            Entry::Arbor(n) => format!("arbor {n}"),
            Entry::Peer(p) => PEERS
                .iter()
                .find(|e| e.2 == p)
                .expect("listed")
                .1
                .to_string(),
        }
    }
}

/// True when this binary was built with Embree (`--features embree`).
pub const EMBREE: bool = cfg!(feature = "embree");

/// Every builder the benchmark knows, in table order (Embree's only with the feature).
fn all_entries() -> Vec<Entry> {
    let mut v: Vec<Entry> = super::build::available_builders()
        .map(Entry::Arbor)
        .collect();
    v.extend(
        PEERS
            .iter()
            .filter(|p| EMBREE || !p.2.is_embree())
            .map(|p| Entry::Peer(p.2)),
    );
    v
}

/// The builders named by `--builders` (all when empty), or a one-line error.
fn select(names: &[String]) -> anyhow::Result<Vec<Entry>> {
    let all = all_entries();
    if names.is_empty() {
        return Ok(all);
    }
    let mut out = Vec::new();
    for n in names {
        match all.iter().find(|e| e.id() == n) {
            Some(e) if !out.contains(e) => out.push(*e),
            Some(_) => {}
            None if !EMBREE && n.starts_with("embree-") => bail!(
                "builder {n} needs Embree: build arbor with `--features embree` (libembree-dev)"
            ),
            None => bail!(
                "unknown builder '{n}'; valid names: {}",
                all.iter().map(|e| e.id()).collect::<Vec<_>>().join(", ")
            ),
        }
    }
    Ok(out)
}

/// One measurement: a builder on a scene at a thread count.
#[derive(Serialize, Debug, Clone)]
pub struct Row {
    /// Scene spec as given.
    pub scene: String,
    /// Primitives.
    pub triangles: usize,
    /// Builder name (`arbor NAME` or the peer's label).
    pub builder: String,
    /// Builder id for `--builders`.
    pub id: &'static str,
    /// `arbor`, `embree`, `obvhs` or `bvh crate`.
    pub library: &'static str,
    /// Children per node of the tree (2 or 4).
    pub width: usize,
    /// Threads.
    pub threads: usize,
    /// Fastest run, milliseconds.
    pub best_ms: f64,
    /// Median run, milliseconds.
    pub median_ms: f64,
    /// Every run, milliseconds, fastest first.
    pub runs_ms: Vec<f64>,
    /// Millions of primitives per second of the fastest run.
    pub mtris_per_s: f64,
    /// SAH with the thesis weights (a 4-wide node costs `2 C_i`).
    pub sah: f64,
    /// SAH over the sweep SAH tree's (null when the reference was skipped).
    pub sah_vs_sweep: Option<f64>,
    /// Throughput over Embree LOW's at the same thread count (null without it).
    pub vs_embree_low: Option<f64>,
    /// Throughput over Embree MEDIUM's at the same thread count (null without it).
    pub vs_embree_medium: Option<f64>,
    /// Most bytes allocated at once during the build, above what was allocated before it
    /// (largest over the runs).
    pub peak_bytes: usize,
    /// Input bytes: the primitive boxes.
    pub input_bytes: usize,
    /// Output bytes: the tree in Arbor's format (nodes plus leaf table).
    pub output_bytes: usize,
    /// `(input + peak) / (input + output)`.
    pub memory_ratio: f64,
}

/// One goal of issue 3 on one scene and thread count.
#[derive(Serialize, Debug, Clone)]
pub struct Goal {
    /// What the goal says.
    pub goal: &'static str,
    /// Scene spec.
    pub scene: String,
    /// Threads.
    pub threads: usize,
    /// The measured ratio the goal bounds.
    pub value: f64,
    /// The bound.
    pub target: f64,
    /// Whether the goal is met (the ratio and its SAH or time condition).
    pub met: bool,
    /// The numbers behind it.
    pub detail: String,
}

/// The JSON document (`arbor.bench.build.v1`).
#[derive(Serialize, Debug)]
pub struct BenchJson {
    /// `"arbor.bench.build.v1"`.
    pub schema: &'static str,
    /// When, where and how it ran (flattened into the document).
    #[serde(flatten)]
    pub run: RunInfo,
    /// Runs per measurement.
    pub runs: usize,
    /// Whether every Arbor build started from new buffers (`--fresh`); otherwise the
    /// builders that can reuse them built into those of their previous run.
    pub fresh: bool,
    /// Whether the Embree rows could run (feature `embree`).
    pub embree: bool,
    /// Notes on skipped rows.
    pub notes: Vec<String>,
    /// Measurements.
    pub rows: Vec<Row>,
    /// Goals of issue 3, per scene and thread count.
    pub goals: Vec<Goal>,
}

/// A probe that reads the counting allocator's peak over a peer's build call.
#[derive(Default)]
struct AllocProbe {
    base: AtomicUsize,
    extra: AtomicUsize,
}

impl BuildProbe for AllocProbe {
    fn before_build(&self) {
        self.base.store(reset_peak(), Relaxed);
    }
    fn after_build(&self) {
        let base = self.base.load(Relaxed);
        self.extra.store(peak_bytes().saturating_sub(base), Relaxed);
    }
}

/// What the thread-count-specific resources of a run are: the pool, and Embree's device.
struct Workers {
    pool: rayon::ThreadPool,
    #[cfg(feature = "embree")]
    embree: Option<peers::EmbreeDevice>,
}

impl Workers {
    fn new(threads: usize, entries: &[Entry]) -> anyhow::Result<Self> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .context("cannot create the worker thread pool")?;
        #[cfg(not(feature = "embree"))]
        let _ = entries;
        Ok(Self {
            pool,
            #[cfg(feature = "embree")]
            embree: if entries
                .iter()
                .any(|e| matches!(e, Entry::Peer(p) if p.is_embree()))
            {
                Some(peers::EmbreeDevice::new(threads)?)
            } else {
                None
            },
        })
    }
}

/// One build: the tree, its timed part and its peak extra bytes. An Arbor builder of
/// [`super::build::REUSING`] builds into `frame`'s buffers when one is given; the bytes
/// they held before the build count in its peak.
fn build_once(
    e: Entry,
    aabbs: &[Aabb],
    tris: &Option<std::sync::Arc<[geom::Triangle]>>,
    threads: usize,
    w: &Workers,
    frame: Option<&mut Frame>,
) -> anyhow::Result<(Tree, Duration, usize)> {
    let cfg = BuildConfig {
        triangles: match e {
            Entry::Arbor(name) if super::build::cuts_triangles(name) => tris.clone(),
            _ => None,
        },
        ..BuildConfig::default()
    };
    let probe = AllocProbe::default();
    let peer = |r: Result<peers::PeerBuild, peers::PeerError>| -> anyhow::Result<_> {
        let b = r?;
        Ok((Tree::Bvh2(b.bvh), b.build_time, probe.extra.load(Relaxed)))
    };
    match e {
        Entry::Arbor(name) => {
            if let (Some(frame), Some(f)) = (frame, reusing_builder(name)) {
                let held = frame.held_bytes();
                return w.pool.install(|| {
                    let m = PeakMeter::start();
                    let s = Instant::now();
                    let t = f(aabbs, &cfg, frame)?;
                    let d = s.elapsed();
                    Ok((t, d, held + m.extra_peak()))
                });
            }
            let f = builder(name)?;
            w.pool.install(|| {
                let m = PeakMeter::start();
                let s = Instant::now();
                let t = f(aabbs, &cfg)?;
                let d = s.elapsed();
                Ok((t, d, m.extra_peak()))
            })
        }
        Entry::Peer(Peer::ObvhsFastest | Peer::ObvhsFast) => {
            let preset = if e == Entry::Peer(Peer::ObvhsFast) {
                ObvhsPreset::FastBuild
            } else {
                ObvhsPreset::FastestBuild
            };
            // threads 0: the pool installed here.
            w.pool
                .install(|| peer(ObvhsBuilder { preset, threads: 0 }.build_probed(aabbs, &probe)))
        }
        Entry::Peer(Peer::BvhCrate) => {
            // Its serial build on 1 thread, its rayon executor in the installed pool else.
            let t = if threads == 1 { 1 } else { 0 };
            w.pool
                .install(|| peer(BvhCrateBuilder { threads: t }.build_probed(aabbs, &probe)))
        }
        Entry::Peer(p @ (Peer::EmbreeLow | Peer::EmbreeMedium)) => embree(p, aabbs, w, &probe),
    }
}

#[cfg(feature = "embree")]
fn embree(
    p: Peer,
    aabbs: &[Aabb],
    w: &Workers,
    probe: &AllocProbe,
) -> anyhow::Result<(Tree, Duration, usize)> {
    let device = w.embree.as_ref().context("no Embree device")?;
    let quality = if p == Peer::EmbreeLow {
        peers::EmbreeQuality::Low
    } else {
        peers::EmbreeQuality::Medium
    };
    device.reset_memory_peak();
    let b = peers::EmbreeBuilder {
        quality,
        ..Default::default()
    }
    .build_on_probed(device, aabbs, probe)?;
    // Rust's peak (the callbacks allocate nothing) plus Embree's own.
    let extra = probe.extra.load(Relaxed) + device.memory_peak_bytes();
    Ok((Tree::Bvh2(b.bvh), b.build_time, extra))
}

#[cfg(not(feature = "embree"))]
fn embree(
    _: Peer,
    _: &[Aabb],
    _: &Workers,
    _: &AllocProbe,
) -> anyhow::Result<(Tree, Duration, usize)> {
    bail!("this arbor was built without Embree (feature `embree`)")
}

/// Largest leaf a builder makes (for the validator).
fn max_leaf(e: Entry) -> u32 {
    match e {
        Entry::Arbor(_) => BuildConfig::default().max_leaf,
        Entry::Peer(p) => p.max_leaf(),
    }
}

/// The fastest and the median of `times`, in milliseconds.
fn best_and_median(times: &mut [f64]) -> (f64, f64) {
    times.sort_by(f64::total_cmp);
    (times[0], times[times.len() / 2])
}

/// What the runs of one builder measured.
struct Measured {
    /// Wall time of each run, milliseconds.
    times: Vec<f64>,
    /// Largest peak extra bytes over the runs.
    peak: usize,
    /// Tree width, SAH and bytes (of the first run's tree; every run builds the same).
    width: usize,
    sah: f64,
    bytes: usize,
}

/// Measures every builder in `entries` on `aabbs`, `runs` rounds, each round one build per
/// builder in turn, so that load from other processes, which comes and goes, falls on all
/// builders alike rather than on whichever ran during it. Each builder's first tree is
/// validated (untimed) and every tree is freed before the next build, or, unless `fresh`,
/// kept in its builder's [`Frame`] for the next build to reuse.
#[allow(clippy::too_many_arguments)]
fn measure_all(
    entries: &[Entry],
    aabbs: &[Aabb],
    tris: &Option<std::sync::Arc<[geom::Triangle]>>,
    threads: usize,
    runs: usize,
    fresh: bool,
    w: &Workers,
    tick: &mut dyn FnMut(),
) -> anyhow::Result<Vec<Measured>> {
    let mut out: Vec<Option<Measured>> = entries.iter().map(|_| None).collect();
    let mut frames: Vec<Frame> = entries.iter().map(|_| Frame::default()).collect();
    for _ in 0..runs {
        for ((e, m), frame) in entries.iter().zip(out.iter_mut()).zip(&mut frames) {
            let reuse = (!fresh).then_some(&mut *frame);
            let (t, d, p) = build_once(*e, aabbs, tris, threads, w, reuse)
                .with_context(|| format!("{} failed", e.label()))?;
            let ms = d.as_secs_f64() * 1e3;
            match m {
                Some(m) => {
                    m.times.push(ms);
                    m.peak = m.peak.max(p);
                }
                None => {
                    let valid = match e {
                        Entry::Arbor(name) => {
                            super::build::validate_built(&t, name, aabbs, max_leaf(*e))
                        }
                        Entry::Peer(_) => t.validate(aabbs, max_leaf(*e)),
                    };
                    valid.with_context(|| format!("{} built an invalid tree", e.label()))?;
                    *m = Some(Measured {
                        times: vec![ms],
                        peak: p,
                        width: t.kind().width(),
                        sah: t.normalized_sah(),
                        bytes: t.bytes(),
                    });
                }
            }
            if fresh {
                drop(t);
            } else {
                frame.recycle(t);
            }
            tick();
        }
    }
    out.into_iter().map(|m| m.context("no runs")).collect()
}

/// Checks the arguments that need no scene.
fn check_args(a: &BenchBuildArgs) -> anyhow::Result<Vec<Entry>> {
    anyhow::ensure!(
        (1..=MAX_RUNS).contains(&a.runs),
        "--runs must be between 1 and {MAX_RUNS}, got {}",
        a.runs
    );
    anyhow::ensure!(!a.threads.is_empty(), "--threads needs at least one count");
    for d in a.out.iter().chain(&a.record) {
        // Fail before the measurements, not after.
        anyhow::ensure!(
            !d.exists() || d.is_dir(),
            "cannot create {}: a file of that name exists",
            d.display()
        );
    }
    for &t in &a.threads {
        anyhow::ensure!(
            (1..=MAX_THREADS).contains(&t),
            "--threads must be between 1 and {MAX_THREADS}, got {t}"
        );
    }
    select(&a.builders)
}

/// Runs `arbor bench build`.
pub fn run(args: &BenchBuildArgs, ui: &Ui) -> anyhow::Result<()> {
    let entries = check_args(args)?;
    let format = if args.json { Format::Json } else { args.format };
    let scenes: Vec<String> = if args.scenes.is_empty() {
        DEFAULT_SCENES.iter().map(|s| s.to_string()).collect()
    } else {
        args.scenes.clone()
    };
    let run = RunInfo::start();
    let mut notes = Vec::new();
    if !EMBREE {
        notes.push(
            "Embree rows omitted: this arbor was built without the `embree` feature \
             (cargo build --release -p arbor --features embree, needs libembree-dev)"
                .to_string(),
        );
    }
    let mut rows = Vec::new();
    for spec in &scenes {
        let scene_args = SceneArgs {
            scene: spec.clone(),
            fps: None,
            animation: None,
        };
        let (scene, _) = open_scene(&scene_args, ui)?;
        let mesh = scene
            .mesh_at(0.0)
            .with_context(|| format!("cannot sample {spec} at t = 0"))?;
        let (aabbs, _) = mesh_aabbs(&mesh)?;
        // The triangles themselves, for the builders that cut them (sbvh).
        let tris = entries.iter().find_map(|e| match e {
            Entry::Arbor(name) => super::build::triangles_for(name, &mesh),
            Entry::Peer(_) => None,
        });
        drop(mesh);
        drop(scene);
        let n = aabbs.len();
        let big = n > SAH_REFERENCE_MAX_TRIANGLES && !args.sah_reference;
        let run: Vec<Entry> = entries
            .iter()
            .copied()
            .filter(|e| !(big && *e == Entry::Arbor("sweep-sah")))
            .collect();
        if big && entries.contains(&Entry::Arbor("sweep-sah")) {
            notes.push(format!(
                "{spec}: sweep-sah and the SAH reference skipped above {} triangles (--sah-reference builds them)",
                thousands(SAH_REFERENCE_MAX_TRIANGLES as u64)
            ));
        }
        let bar = ui.progress(
            &format!("benchmarking {} builders on {spec}", run.len()),
            Unit::Items,
        );
        let total = (run.len() * args.threads.len() * args.runs) as u64;
        let mut done = 0u64;
        let mut tick = || {
            done += 1;
            bar.update(done, total);
        };
        let mut scene_rows = Vec::new();
        for &threads in &args.threads {
            let workers = Workers::new(threads, &run)?;
            let measured = measure_all(
                &run, &aabbs, &tris, threads, args.runs, args.fresh, &workers, &mut tick,
            )?;
            for (&e, mut m) in run.iter().zip(measured) {
                let (best_ms, median_ms) = best_and_median(&mut m.times);
                let input_bytes = n * INPUT_BYTES_PER_PRIM;
                scene_rows.push(Row {
                    scene: spec.clone(),
                    triangles: n,
                    builder: e.label(),
                    id: e.id(),
                    library: match e {
                        Entry::Arbor(_) => "arbor",
                        Entry::Peer(p) => p.library(),
                    },
                    width: m.width,
                    threads,
                    best_ms,
                    median_ms,
                    runs_ms: m.times.clone(),
                    mtris_per_s: if best_ms > 0.0 {
                        n as f64 / best_ms / 1e3
                    } else {
                        0.0
                    },
                    sah: m.sah,
                    sah_vs_sweep: None,
                    vs_embree_low: None,
                    vs_embree_medium: None,
                    peak_bytes: m.peak,
                    input_bytes,
                    output_bytes: m.bytes,
                    memory_ratio: (input_bytes + m.peak) as f64
                        / (input_bytes + m.bytes).max(1) as f64,
                });
            }
        }
        bar.finish();
        // The sweep SAH reference: the sweep-sah rows' tree, or one untimed build.
        let sweep = match scene_rows.iter().find(|r| r.id == "sweep-sah") {
            Some(r) => Some(r.sah),
            None if !big => {
                let _s = ui.spinner(&format!("building the sweep SAH reference of {spec}"));
                let t = super::build::builder("sweep-sah")?(&aabbs, &BuildConfig::default())?;
                Some(t.normalized_sah())
            }
            None => None,
        };
        fill_ratios(&mut scene_rows, sweep);
        rows.extend(scene_rows);
    }
    let goals = goals(&rows);
    let doc = BenchJson {
        schema: "arbor.bench.build.v1",
        run: run.finish(),
        runs: args.runs,
        fresh: args.fresh,
        embree: EMBREE,
        notes,
        rows,
        goals,
    };
    let json = serde_json::to_string_pretty(&doc)? + "\n";
    if let Some(dir) = &args.record {
        let entries = doc
            .rows
            .iter()
            .map(|r| RecordEntry::from_times(short(&r.scene), r.id, r.threads, &r.runs_ms))
            .collect();
        Record::new("build", &doc.run, entries).write_under(dir)?;
    }
    Rendered {
        text: text(&doc),
        markdown: markdown(&doc),
        csv: csv(&doc),
        json,
    }
    .emit(args.out.as_deref(), "bench-build", format, ui.silent)?;
    if let Some(dir) = &args.out {
        for (scene, svg) in sah_time_plots(&doc.rows) {
            let name = format!("bench-build-sah-{}.svg", super::bench_record::slug(&scene));
            report::fs::write_atomic(&dir.join(name), &svg)?;
        }
    }
    Ok(())
}

/// Per scene (in the order of the rows), the plot of each builder's SAH over the sweep
/// SAH tree's against its build time at the scene's fewest threads: the picture of
/// quality against time the builders page of the HTML report shows. Scenes without the
/// sweep reference get no plot.
pub fn sah_time_plots(rows: &[Row]) -> Vec<(String, String)> {
    let mut scenes: Vec<&str> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
    }
    scenes
        .into_iter()
        .filter_map(|scene| {
            let of_scene = || rows.iter().filter(move |r| r.scene == scene);
            let threads = of_scene().map(|r| r.threads).min()?;
            let points: Vec<report::svg::Point> = of_scene()
                .filter(|r| r.threads == threads)
                .filter_map(|r| {
                    Some(report::svg::Point {
                        x: r.best_ms,
                        y: r.sah_vs_sweep?,
                        label: r.builder.clone(),
                    })
                })
                .collect();
            if points.is_empty() {
                return None;
            }
            let title = format!(
                "{}: SAH against build time ({threads} thread{}, fastest run)",
                short(scene),
                if threads == 1 { "" } else { "s" }
            );
            let svg = report::svg::scatter_svg(
                &title,
                "build time, ms (log scale)",
                "SAH / sweep SAH",
                true,
                &points,
            );
            Some((short(scene).to_string(), svg))
        })
        .collect()
}

/// Fills the SAH and throughput ratios of one scene's rows.
fn fill_ratios(rows: &mut [Row], sweep: Option<f64>) {
    let time_of = |rows: &[Row], id: &str, threads: usize| {
        rows.iter()
            .find(|r| r.id == id && r.threads == threads)
            .map(|r| r.best_ms)
    };
    let refs: Vec<(Option<f64>, Option<f64>)> = rows
        .iter()
        .map(|r| {
            (
                time_of(rows, "embree-low", r.threads),
                time_of(rows, "embree-medium", r.threads),
            )
        })
        .collect();
    for (r, (low, medium)) in rows.iter_mut().zip(refs) {
        r.sah_vs_sweep = sweep.map(|s| bvh::sah_ratio(r.sah, s));
        r.vs_embree_low = low.map(|l| l / r.best_ms);
        r.vs_embree_medium = medium.map(|m| m / r.best_ms);
    }
}

/// The goals of issue 3 evaluated on every (scene, threads) that has the rows they need.
fn goals(rows: &[Row]) -> Vec<Goal> {
    let mut out = Vec::new();
    let mut keys: Vec<(String, usize)> = Vec::new();
    for r in rows {
        if !keys.contains(&(r.scene.clone(), r.threads)) {
            keys.push((r.scene.clone(), r.threads));
        }
    }
    for (scene, threads) in keys {
        let find = |id: &str| {
            rows.iter()
                .find(|r| r.scene == scene && r.threads == threads && r.id == id)
        };
        let goal = |goal, value: f64, target, met, detail| Goal {
            goal,
            scene: scene.clone(),
            threads,
            value,
            target,
            met,
            detail,
        };
        // The thesis's HLBVH tree, and HLBVH with its large primitives apart (issue 34).
        for (id, name) in [
            (
                "hlbvh",
                "hlbvh throughput >= 1.5x Embree LOW, SAH <= Embree LOW's",
            ),
            (
                "hlbvh-large",
                "hlbvh-large throughput >= 1.5x Embree LOW, SAH <= Embree LOW's",
            ),
        ] {
            let (Some(h), Some(l)) = (find(id), find("embree-low")) else {
                continue;
            };
            let speed = l.best_ms / h.best_ms;
            out.push(goal(
                name,
                speed,
                GOAL_HLBVH_VS_LOW,
                speed >= GOAL_HLBVH_VS_LOW && h.sah <= l.sah,
                format!(
                    "{:.1} vs {:.1} ms; SAH {:.3} vs {:.3} ({:+.1}%)",
                    h.best_ms,
                    l.best_ms,
                    h.sah,
                    l.sah,
                    (h.sah / l.sah - 1.0) * 100.0
                ),
            ));
        }
        if let (Some(b), Some(m)) = (find("binned-sah"), find("embree-medium")) {
            let speed = m.best_ms / b.best_ms;
            out.push(goal(
                "binned-sah throughput >= Embree MEDIUM, SAH <= Embree MEDIUM's",
                speed,
                GOAL_BINNED_VS_MEDIUM,
                speed >= GOAL_BINNED_VS_MEDIUM && b.sah <= m.sah,
                format!(
                    "{:.1} vs {:.1} ms; SAH {:.3} vs {:.3} ({:+.1}%)",
                    b.best_ms,
                    m.best_ms,
                    b.sah,
                    m.sah,
                    (b.sah / m.sah - 1.0) * 100.0
                ),
            ));
        }
        for (name, label) in [
            (
                "hlbvh+atrbvh",
                "hlbvh+atrbvh SAH <= 1.10x sweep at < 2x hlbvh time",
            ),
            (
                "hlbvh+atrbvh-cells",
                "hlbvh+atrbvh-cells SAH <= 1.10x sweep at < 2x hlbvh time",
            ),
        ] {
            if let (Some(a), Some(h)) = (find(name), find("hlbvh")) {
                if let Some(q) = a.sah_vs_sweep {
                    let time = a.best_ms / h.best_ms;
                    out.push(goal(
                        label,
                        q,
                        GOAL_ATRBVH_SAH,
                        q <= GOAL_ATRBVH_SAH && time < GOAL_ATRBVH_TIME,
                        format!("{:.2}x hlbvh time", time),
                    ));
                }
            }
        }
        let worst = rows
            .iter()
            .filter(|r| r.scene == scene && r.threads == threads && r.library == "arbor")
            .max_by(|a, b| a.memory_ratio.total_cmp(&b.memory_ratio));
        if let Some(w) = worst {
            let over: Vec<&str> = rows
                .iter()
                .filter(|r| {
                    r.scene == scene
                        && r.threads == threads
                        && r.library == "arbor"
                        && r.memory_ratio > GOAL_MEMORY
                })
                .map(|r| r.id)
                .collect();
            out.push(goal(
                "peak memory <= 2x (input + output), every Arbor builder",
                w.memory_ratio,
                GOAL_MEMORY,
                over.is_empty(),
                if over.is_empty() {
                    format!("worst {}", w.id)
                } else {
                    format!("above 2: {}", over.join(", "))
                },
            ));
        }
    }
    out
}

/// The scene's short name: the file name of a path, the spec of a procedural scene.
fn short(scene: &str) -> &str {
    if scene.starts_with("proc:") {
        scene
    } else {
        scene.rsplit(['/', '\\']).next().unwrap_or(scene)
    }
}

/// The cells of a row for the text and Markdown tables.
fn cells(r: &Row) -> [String; 12] {
    let opt = |v: Option<f64>, prec: usize, suffix: &str| {
        v.map_or("—".to_string(), |v| format!("{v:.prec$}{suffix}"))
    };
    [
        short(&r.scene).to_string(),
        r.triangles.to_string(),
        r.builder.clone(),
        r.threads.to_string(),
        format!("{:.1}", r.best_ms),
        format!("{:.2}", r.mtris_per_s),
        format!("{:.2}", r.sah),
        opt(r.sah_vs_sweep, 3, ""),
        opt(r.vs_embree_low, 2, "x"),
        opt(r.vs_embree_medium, 2, "x"),
        format!("{:.1}", r.peak_bytes as f64 / (1024.0 * 1024.0)),
        format!("{:.2}", r.memory_ratio),
    ]
}

const HEADERS: [&str; 12] = [
    "scene",
    "triangles",
    "builder",
    "threads",
    "best ms",
    "Mtris/s",
    "SAH",
    "SAH vs sweep",
    "vs Embree LOW",
    "vs Embree MEDIUM",
    "peak MiB",
    "memory ratio",
];

/// The run's circumstances, one line each.
fn preamble(d: &BenchJson) -> Vec<String> {
    let mut v = d.run.lines().to_vec();
    v.push(format!(
        "best of {} runs; SAH with the thesis weights (a 4-wide node costs 2 C_i), over \
             Arbor's sweep SAH tree; throughput ratios over Embree at the same thread count; \
             memory ratio = (input + peak) / (input + output)",
        d.runs
    ));
    v.push(if d.fresh {
        "every build from new buffers (--fresh)".to_string()
    } else {
        format!(
            "{} build into the buffers of their previous run (a renderer's frame loop; \
             --fresh for new buffers every run), which count in their peak memory",
            super::build::REUSING
                .iter()
                .map(|(n, _)| *n)
                .collect::<Vec<_>>()
                .join(", ")
        )
    });
    v.extend(d.notes.iter().cloned());
    v
}

/// The goals as a table.
fn goal_rows(d: &BenchJson) -> Table {
    let mut t = goal_table("detail");
    for g in &d.goals {
        t.push([
            g.goal.to_string(),
            short(&g.scene).to_string(),
            g.threads.to_string(),
            format!("{:.3}", g.value),
            g.target.to_string(),
            if g.met { "met" } else { "NOT met" }.to_string(),
            g.detail.clone(),
        ]);
    }
    t
}

/// The measurements as a table (text columns left, numbers right).
fn table(d: &BenchJson) -> Table {
    let mut t = Table::new(&HEADERS).with_align(2, Align::Left);
    for r in &d.rows {
        t.push(cells(r));
    }
    t
}

/// The aligned text tables.
fn text(d: &BenchJson) -> String {
    text_report(&preamble(d), &table(d), Some(&goal_rows(d)))
}

/// Markdown tables: the measurements and the goals.
fn markdown(d: &BenchJson) -> String {
    markdown_report(&preamble(d), &table(d), Some(&goal_rows(d)))
}

/// One CSV line per row, with a header; numbers unrounded.
fn csv(d: &BenchJson) -> String {
    let o = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
    let mut t = Table::text(&[
        "scene",
        "triangles",
        "builder",
        "library",
        "width",
        "threads",
        "best_ms",
        "median_ms",
        "mtris_per_s",
        "sah",
        "sah_vs_sweep",
        "vs_embree_low",
        "vs_embree_medium",
        "peak_bytes",
        "input_bytes",
        "output_bytes",
        "memory_ratio",
    ]);
    for r in &d.rows {
        t.push([
            r.scene.clone(),
            r.triangles.to_string(),
            r.builder.clone(),
            r.library.to_string(),
            r.width.to_string(),
            r.threads.to_string(),
            r.best_ms.to_string(),
            r.median_ms.to_string(),
            r.mtris_per_s.to_string(),
            r.sah.to_string(),
            o(r.sah_vs_sweep),
            o(r.vs_embree_low),
            o(r.vs_embree_medium),
            r.peak_bytes.to_string(),
            r.input_bytes.to_string(),
            r.output_bytes.to_string(),
            r.memory_ratio.to_string(),
        ]);
    }
    t.csv()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builder_selection() {
        let all = select(&[]).unwrap();
        assert!(all.contains(&Entry::Arbor("hlbvh")));
        assert!(all.contains(&Entry::Peer(Peer::ObvhsFastest)));
        assert_eq!(all.contains(&Entry::Peer(Peer::EmbreeLow)), EMBREE);
        let two = select(&["hlbvh".into(), "bvh-crate".into(), "hlbvh".into()]).unwrap();
        assert_eq!(
            two,
            vec![Entry::Arbor("hlbvh"), Entry::Peer(Peer::BvhCrate)]
        );
        let e = select(&["nope".into()]).unwrap_err().to_string();
        assert!(
            e.contains("obvhs-ploc-fast") && e.contains("mbvh4-topdown"),
            "{e}"
        );
        if !EMBREE {
            let e = select(&["embree-low".into()]).unwrap_err().to_string();
            assert!(e.contains("--features embree"), "{e}");
        }
        for e in all_entries() {
            assert_eq!(select(&[e.id().to_string()]).unwrap(), vec![e]);
            assert!(!e.label().is_empty());
        }
    }

    fn row(id: &'static str, library: &'static str, ms: f64, sah: f64, mem: f64) -> Row {
        Row {
            scene: "s".into(),
            triangles: 1000,
            builder: id.into(),
            id,
            library,
            width: 2,
            threads: 1,
            best_ms: ms,
            median_ms: ms,
            runs_ms: vec![ms],
            mtris_per_s: 1.0 / ms,
            sah,
            sah_vs_sweep: None,
            vs_embree_low: None,
            vs_embree_medium: None,
            peak_bytes: 0,
            input_bytes: 0,
            output_bytes: 0,
            memory_ratio: mem,
        }
    }

    #[test]
    fn goals_follow_the_issue_definitions() {
        let mut rows = vec![
            row("hlbvh", "arbor", 10.0, 99.0, 1.5),
            row("hlbvh+atrbvh", "arbor", 19.0, 90.0, 1.6),
            row("binned-sah", "arbor", 50.0, 81.0, 2.5),
            row("embree-low", "embree", 16.0, 100.0, 3.0),
            row("embree-medium", "embree", 49.0, 80.0, 3.0),
        ];
        fill_ratios(&mut rows, Some(82.0));
        assert_eq!(rows[0].vs_embree_low, Some(1.6));
        assert_eq!(rows[2].vs_embree_medium, Some(49.0 / 50.0));
        assert_eq!(rows[1].sah_vs_sweep, Some(90.0 / 82.0));
        let g = goals(&rows);
        assert_eq!(g.len(), 4);
        // 1.6x Embree LOW at lower SAH: met.
        assert!(g[0].met && (g[0].value - 1.6).abs() < 1e-12);
        // Slower than MEDIUM and worse SAH: not met.
        assert!(!g[1].met);
        // 1.098x sweep at 1.9x the HLBVH time: met.
        assert!(g[2].met);
        // binned-sah's 2.5 breaks the memory goal; Embree's 3.0 does not count.
        assert!(!g[3].met && g[3].detail.contains("binned-sah"));
        assert_eq!(g[3].value, 2.5);
        // Worse SAH than Embree LOW fails the first goal even when fast.
        rows[0].sah = 101.0;
        assert!(!goals(&rows)[0].met);
        // HLBVH with its large primitives apart is held to the same goal, after hlbvh:
        // met at lower SAH and 1.6x, not at 16 / 11 = 1.45x.
        rows.push(row("hlbvh-large", "arbor", 10.0, 95.0, 1.5));
        let g = goals(&rows);
        assert_eq!(g.len(), 5);
        assert!(!g[0].met && g[1].met && g[1].goal.starts_with("hlbvh-large"));
        rows[5].best_ms = 11.0;
        let g = goals(&rows);
        assert!(!g[1].met && (g[1].value - 16.0 / 11.0).abs() < 1e-12);
    }

    #[test]
    fn every_format_has_every_row() {
        let mut rows = vec![
            row("hlbvh", "arbor", 10.0, 99.0, 1.5),
            row("bvh-crate", "bvh crate", 30.0, 98.0, 1.2),
        ];
        rows[1].scene = "../x/dragon.ply".into();
        let d = BenchJson {
            schema: "arbor.bench.build.v1",
            run: RunInfo {
                started_utc: super::super::bench::utc_now(),
                load_average_start: Some([1.0, 2.0, 3.0]),
                load_average_end: None,
                cpus: 2,
                cpu_model: "AMD EPYC".into(),
                command: "arbor bench build".into(),
            },
            runs: 3,
            fresh: false,
            embree: false,
            notes: vec!["a note".into()],
            goals: goals(&rows),
            rows,
        };
        let t = text(&d);
        assert!(
            t.contains("load average 1.00 2.00 3.00") && t.contains("a note"),
            "{t}"
        );
        assert!(t.contains("dragon.ply") && !t.contains("../x"), "{t}");
        let m = markdown(&d);
        assert_eq!(
            m.lines().filter(|l| l.starts_with("| s |")).count(),
            1,
            "{m}"
        );
        assert!(m.contains("| dragon.ply |"), "{m}");
        let c = csv(&d);
        assert_eq!(c.lines().count(), 3);
        assert!(
            c.lines()
                .nth(1)
                .unwrap()
                .starts_with("s,1000,hlbvh,arbor,2,1,10,"),
            "{c}"
        );
        assert!(c.contains("bvh crate"));
    }
}
