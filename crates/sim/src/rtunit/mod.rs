//! The ray-tracing accelerator of \[P4\] §3 (Fig. 2 and Fig. 3), cycle by cycle on the
//! simulation kernel, with the binary BVH of the baseline and the 4-wide MBVH of the
//! proposal.
//!
//! # Architecture
//! - A **ray scheduler** holds the ray slots (one per stack of a TRV unit, so 4 x 32 = 128
//!   rays in flight by default). It admits one ray per cycle: the next bounce of a
//!   finished diffuse ray first (\[P4\] §3.2: "secondary rays are fed to the processor
//!   when the preceding ray is complete"), else the next camera ray; and it retires one
//!   finished ray per cycle.
//! - **TRV units** (4 per IST unit): an in-order pipeline taking one ray per cycle. Stage
//!   one reads the ray's node from the unit's 16 KB L1 node cache; the ray's children are
//!   tested (2 slab tests for BVH, 4 for MBVH4), the hit children are ordered by entry
//!   distance (a compare-and-swap for BVH; for MBVH4 the five-comparator network with one
//!   stage per layer, [`RtConfig::sort_stages`] = 2 extra cycles), the nearest is
//!   continued with and the others pushed (up to three per visit for MBVH4, through banked
//!   stack memory, so one pass). A ray that reaches a leaf leaves for the IST unit; back
//!   from it, it passes the pipeline once more to pop its stack (\[P4\] §3). The MBVH4
//!   unit keeps entry distances with the stack entries and drops those beyond the closest
//!   hit when popping (\[P4\] §3.1); the BVH unit does not.
//! - The **IST unit** buffers rays from the TRV units and starts one triangle test per
//!   cycle on 48-byte triangles read from the 128 KB two-bank primitive cache (64-byte
//!   lines; a triangle across two lines reads both banks in the same cycle). Its pipeline
//!   is [`RtConfig::ist_stages`] deep. The function is the software tracer's watertight
//!   test (so hits are bit-equal to `trace`'s); the data layout (48 B) and the FLOP count
//!   of the energy model (Wald 2004 with a Markstein division of 11 FLOPs) are \[P4\]'s.
//! - The **caches** are the kernel's non-blocking set-associative [`Cache`]: a 16 KB L1
//!   per TRV, the shared 128 KB node cache (lines of one node: 64 B for BVH, 128 B for
//!   MBVH4, at the same capacity), and the primitive cache; 4-way, LRU.
//! - **Looping for next chance** (Ray-Core, Nah et al. 2014): a ray whose node or
//!   triangle misses goes on through the pipeline with its results discarded and enters
//!   again when it comes out; the miss's fetch proceeds meanwhile.
//! - **FIFOs** between the units start at [`RtConfig::fifo_entries`] = 32; [`size_fifos`]
//!   runs once, shrinks each class to the power of two above its highest occupancy (\[P4\]
//!   §3) and runs again.
//! - 500 MHz, DRAM `lpddr3-1600-2x32` through the memory port.
//!
//! Trees: [`TreeKind::Bvh2`] from the binned SAH builder, [`TreeKind::Mbvh4`] from Wald's
//! top-down builder (\[P4\] §3.2). Every run checks each ray's hit against the software
//! tracer on the same tree ([`RtReport::hits_match_software`]).
//!
//! `docs/rtunit.md` describes the model, its parameters and what it leaves out.

mod config;
pub mod energy;
mod model;
pub mod report;
pub mod sampling;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_limits;
mod tree;

pub use config::{sized_fifo, ConfigError, RtConfig, TreeKind, FIFO_CLASSES, KEYS};
pub use model::{RayResult, TrafficSplit};
pub use tree::TreeImage;

use std::time::Instant;

use geom::Triangle;
use serde::Serialize;
use trace::{KernelOptions, PinholeCamera, TraversalStack, Traverse};

use crate::dram::MemStats;
use crate::kernel::{
    Cache, CacheConfig, CacheStats, LatencyFifo, Memory, Options, UnitId, WritePolicy,
};
use model::{RaySource, RtWorld, Slot};

/// Rays of a run: camera rays only, or diffuse paths.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RayMode {
    /// One camera ray per pixel.
    Primary,
    /// A camera ray per pixel and up to `bounces` cosine-weighted diffuse bounces.
    Diffuse,
}

/// What to trace.
#[derive(Clone, Copy)]
pub struct Workload<'a> {
    /// The scene's triangles.
    pub triangles: &'a [Triangle],
    /// The camera (its size is the image size).
    pub camera: &'a PinholeCamera,
    /// Ray kind.
    pub rays: RayMode,
    /// Diffuse bounces after the primary hit (diffuse only; \[P4\] §3.2: 4).
    pub bounces: u32,
    /// Sampling seed of the diffuse bounces (the renderer's: rays are the same).
    pub seed: u64,
    /// Time one in `sample` chunks of the image's 8x8 pixel tiles (1: every pixel);
    /// the other pixels warm the caches functionally ([`sampled_pixels`]).
    pub sample: u32,
    /// Called now and then with (camera rays issued, camera rays in all).
    pub progress: Option<&'a dyn Fn(u64, u64)>,
}

/// Errors of a run.
#[derive(Debug, thiserror::Error)]
pub enum RtError {
    /// A parameter cannot be used.
    #[error("{0}")]
    Config(#[from] ConfigError),
    /// The tree could not be built or traced.
    #[error("{0}")]
    Tree(String),
    /// The memory system could not be opened.
    #[error(transparent)]
    Dram(#[from] crate::dram::DramError),
    /// The model stopped making progress or ran past its cycle limit.
    #[error("accelerator model: {0}")]
    Kernel(String),
    /// A ray's stack outgrew the stack storage.
    #[error("stack overflow: ray of pixel {pixel} (bounce {bounce}) needed {depth} stack entries, the TRV stacks hold {entries} (raise stack_entries)")]
    StackOverflow {
        /// The ray's pixel.
        pixel: u32,
        /// Its bounce.
        bounce: u8,
        /// Depth it reached.
        depth: usize,
        /// Entries per stack.
        entries: u32,
    },
}

/// The schema name of [`RtReport`] documents.
pub const SCHEMA: &str = "arbor.sim.rtunit.v1";

/// A cache's figures.
#[derive(Clone, Debug, Serialize)]
pub struct CacheReport {
    /// Its name (`l1` sums the TRV units' L1 caches).
    pub name: String,
    /// Hits per line access.
    pub hit_rate: f64,
    /// Its counts.
    pub stats: CacheStats,
}

/// A unit's figures (fractions of the run's cycles).
#[derive(Clone, Debug, Serialize)]
pub struct UnitFigures {
    /// Its name.
    pub name: String,
    /// Busy fraction.
    pub busy: f64,
    /// Idle fraction.
    pub idle: f64,
    /// Stall fraction per reason.
    pub stalls: Vec<(String, f64)>,
    /// Its counters.
    pub counters: Vec<(String, u64)>,
}

/// A FIFO class's figures: its capacity and the highest occupancy of any of its FIFOs.
#[derive(Clone, Debug, Serialize)]
pub struct FifoFigures {
    /// The class (`sched->trv`, ...).
    pub name: String,
    /// Capacity of each FIFO of the class.
    pub capacity: usize,
    /// Highest occupancy over the class's FIFOs.
    pub high_water: usize,
    /// FIFOs in the class.
    pub count: usize,
    /// Items pushed into the class's FIFOs.
    pub pushes: u64,
}

/// The result of [`run`] (`arbor.sim.rtunit.v1`; `docs/cli-json.md`).
#[derive(Clone, Debug, Serialize)]
pub struct RtReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The tree.
    pub tree: TreeKind,
    /// The ray kind.
    pub ray_kind: RayMode,
    /// Bounces (diffuse).
    pub bounces: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// One in `sample` tiles traced.
    pub sample: u32,
    /// Pixels traced.
    pub pixels: u64,
    /// The configuration.
    pub config: RtConfig,
    /// Cycles of the run.
    pub cycles: u64,
    /// Simulated time in seconds.
    pub seconds: f64,
    /// Rays traced (sampled runs: the rays of the timed tiles).
    pub rays: u64,
    /// Rays simulated in detail (sampled runs add the lead and gap tiles' rays).
    pub detailed_rays: u64,
    /// Million rays per second of simulated time (sampled runs: rays retired per cycle
    /// within the measurement windows, from the first to the last retired ray of each
    /// timed chunk, at the clock).
    pub mrps: f64,
    /// Bytes read from DRAM.
    pub dram_bytes_read: u64,
    /// Bytes written to DRAM.
    pub dram_bytes_written: u64,
    /// Bytes fetched for misses of rays of timed tiles (all of them with `sample` = 1).
    pub counted_dram_bytes: u64,
    /// DRAM traffic of the whole frame in MB (1e6 bytes): exact with `sample` = 1; for a
    /// sampled run the counted bytes per timed pixel times the frame's pixels.
    pub frame_dram_mb: f64,
    /// `counted_dram_bytes` split into first touches (a line's first fetch in the run) and
    /// re-fetches (after eviction), of node lines and triangle lines.
    pub traffic_split: TrafficSplit,
    /// Sampled runs: the relative standard errors of the frame estimates (`sampling`;
    /// `None` for a whole frame or a run of fewer than two measurement windows).
    pub sampling: Option<sampling::SamplingError>,
    /// Sampled runs: the measurement windows behind `sampling`.
    #[serde(skip)]
    pub sampling_windows: Vec<sampling::Window>,
    /// Fraction of the data bus's peak used.
    pub bus_utilization: f64,
    /// Deepest stack of any ray (entries).
    pub max_stack_depth: usize,
    /// Every ray's closest hit (primitive and distance) equals the software tracer's.
    pub hits_match_software: bool,
    /// Rays whose hit differed from the software tracer's.
    pub mismatches: u64,
    /// Node visits, box tests, triangle tests, TRV and IST loop passes.
    pub node_visits: u64,
    /// Ray/box tests.
    pub box_tests: u64,
    /// Ray/triangle tests.
    pub triangle_tests: u64,
    /// Passes of rays through a TRV pipeline that were discarded after a miss.
    pub trv_loops: u64,
    /// Passes of rays through the IST pipeline discarded after a miss.
    pub ist_loops: u64,
    /// Caches.
    pub caches: Vec<CacheReport>,
    /// Units.
    pub units: Vec<UnitFigures>,
    /// FIFO classes.
    pub fifos: Vec<FifoFigures>,
    /// Nodes of the tree.
    pub tree_nodes: usize,
    /// Leaves of the tree (leaf child slots).
    pub tree_leaves: u64,
    /// Bytes of the tree's memory image (nodes and triangles).
    pub tree_bytes: u64,
    /// The memory system's counts.
    pub memory: MemStats,
    /// The memory system.
    pub memory_name: String,
    /// Energy and area of the accelerator ([`energy`]).
    pub energy: Option<energy::AcceleratorEnergy>,
    /// Wall-clock seconds the simulation took (not a result: varies with the machine).
    pub wall_seconds: f64,
}

/// A tree built for the accelerator, with the software tracer over the same tree.
pub struct BuiltTree {
    /// Its kind.
    pub kind: TreeKind,
    /// The memory image.
    pub image: TreeImage,
    /// The software tracer over the same nodes.
    pub accel: trace::Accel,
}

/// How the MBVH4 is built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mbvh4Build {
    /// Wald's top-down builder (\[P4\] §3.2), with the 4-wide node cost in its leaf
    /// decision (`bvh::Mbvh4TopDownBuilder`'s default).
    Topdown,
    /// The binned SAH binary tree collapsed to 4 wide (same leaves as the BVH2): a what-if
    /// that separates the node layout from the builder.
    Collapse,
    /// Wald's top-down builder with the earlier leaf decision, which priced the node it
    /// creates as a binary one ([`bvh::Mbvh4TopDownBuilder::wide_node_cost`] off).
    #[serde(rename = "topdown-binary-leaf")]
    TopdownBinaryLeaf,
    /// The binned SAH tree collapsed SAH-optimally (same leaves, [`bvh::collapse_sah_optimal`]).
    CollapseSah,
    /// The binned SAH tree collapsed into the fewest nodes its leaves allow
    /// ([`bvh::CollapseGoal::FewestNodes`]).
    CollapseFill,
}

/// Builds `kind` over `triangles` as \[P4\] §3.2 does: binned SAH for BVH, Wald's top-down
/// builder for MBVH4 (both with Arbor's defaults: 16 bins, leaves of up to 8).
pub fn build_tree(kind: TreeKind, triangles: &[Triangle]) -> Result<BuiltTree, RtError> {
    build_tree_with(kind, triangles, Mbvh4Build::Topdown)
}

/// [`build_tree`] with the MBVH4 built by `mbvh4`.
pub fn build_tree_with(
    kind: TreeKind,
    triangles: &[Triangle],
    mbvh4: Mbvh4Build,
) -> Result<BuiltTree, RtError> {
    if triangles.is_empty() {
        return Err(RtError::Tree("the scene has no triangles".into()));
    }
    let aabbs = bvh::triangle_aabbs(triangles);
    let tree_err = |e: &dyn std::fmt::Display| RtError::Tree(e.to_string());
    let binned = || {
        bvh::BinnedSahBuilder::default()
            .build(&aabbs)
            .map_err(|e| tree_err(&e))
    };
    let tree = match (kind, mbvh4) {
        (TreeKind::Bvh2 | TreeKind::Cbvh, _) => bvh::Tree::Bvh2(binned()?),
        (TreeKind::Mbvh4, Mbvh4Build::Topdown) => bvh::Tree::Mbvh4(
            bvh::Mbvh4TopDownBuilder::default()
                .build(&aabbs)
                .map_err(|e| tree_err(&e))?,
        ),
        (TreeKind::Mbvh4, Mbvh4Build::Collapse) => {
            bvh::Tree::Mbvh4(bvh::collapse(&binned()?).map_err(|e| tree_err(&e))?)
        }
        (TreeKind::Mbvh4, Mbvh4Build::TopdownBinaryLeaf) => bvh::Tree::Mbvh4(
            bvh::Mbvh4TopDownBuilder {
                wide_node_cost: false,
                ..Default::default()
            }
            .build(&aabbs)
            .map_err(|e| tree_err(&e))?,
        ),
        (TreeKind::Mbvh4, Mbvh4Build::CollapseSah) => bvh::Tree::Mbvh4(
            bvh::collapse_sah_optimal(&binned()?, &bvh::SahParams::THESIS)
                .map_err(|e| tree_err(&e))?,
        ),
        (TreeKind::Mbvh4, Mbvh4Build::CollapseFill) => bvh::Tree::Mbvh4(
            bvh::collapse_optimal(
                &binned()?,
                &bvh::SahParams::THESIS,
                bvh::CollapseGoal::FewestNodes,
            )
            .map_err(|e| tree_err(&e))?,
        ),
    };
    tree_from(kind, tree, triangles)
}

/// The accelerator's `kind` of tree from a tree built by any builder over `triangles`:
/// a binary tree for `bvh2` (as is) and `cbvh` (compressed top-down, 6-bit relative
/// coordinates), a 4-wide tree for `mbvh4`. The software tracer over it checks its links.
pub fn tree_from(
    kind: TreeKind,
    tree: bvh::Tree,
    triangles: &[Triangle],
) -> Result<BuiltTree, RtError> {
    let tree_err = |e: &dyn std::fmt::Display| RtError::Tree(e.to_string());
    let options = KernelOptions::thesis(kind.width() as u32);
    Ok(match (kind, tree) {
        (TreeKind::Bvh2, bvh::Tree::Bvh2(t)) => {
            let image = TreeImage::bvh2(&t, triangles);
            let accel = trace::Bvh2Accel::new(t, triangles, options).map_err(|e| tree_err(&e))?;
            BuiltTree {
                kind,
                image,
                accel: trace::Accel::Bvh2(accel),
            }
        }
        (TreeKind::Cbvh, bvh::Tree::Bvh2(t)) => {
            let (c, _) =
                cbvh::compress_topdown(&t, &cbvh::Params::default()).map_err(|e| tree_err(&e))?;
            let image = TreeImage::cbvh(&c, triangles).map_err(|e| tree_err(&e))?;
            let accel = trace::CbvhAccel::new(&c, triangles, options).map_err(|e| tree_err(&e))?;
            BuiltTree {
                kind,
                image,
                accel: trace::Accel::Cbvh(accel),
            }
        }
        (TreeKind::Mbvh4, bvh::Tree::Mbvh4(t)) => {
            let image = TreeImage::mbvh4(&t, triangles);
            let accel = trace::Mbvh4Accel::new(t, triangles, options).map_err(|e| tree_err(&e))?;
            BuiltTree {
                kind,
                image,
                accel: trace::Accel::Mbvh4(accel),
            }
        }
        (kind, t) => {
            return Err(RtError::Tree(format!(
                "the {} accelerator needs a {} tree, not a {}-wide one",
                kind.name(),
                if kind == TreeKind::Mbvh4 {
                    "4-wide"
                } else {
                    "binary"
                },
                match t {
                    bvh::Tree::Bvh2(_) => 2,
                    bvh::Tree::Mbvh4(_) => 4,
                }
            )))
        }
    })
}

/// Most pixels one run traces (a 16384 x 16384 image).
pub const MAX_PIXELS: u64 = 1 << 28;

/// Side of the pixel tiles rays are issued in (and sampled by).
pub const TILE: u32 = 8;

/// Tiles per sampling chunk: a sampled run times one in `sample` chunks of this many
/// consecutive tiles (in issue order).
pub const SAMPLE_CHUNK_TILES: u32 = 16;

/// Tiles simulated in detail, uncounted, before each timed chunk (they fill the pipeline,
/// so the chunk starts in steady state): two pipeline-fulls of 128 rays.
pub const SAMPLE_LEAD_TILES: u32 = 4;

/// The pixels timed, in issue order: 8x8 tiles in rows, pixels in rows within a tile;
/// with `sample` = k, one chunk ([`SAMPLE_CHUNK_TILES`] consecutive tiles) of each run of
/// k chunks, at a position drawn from a hash of the run's index (stratified random
/// sampling: a fixed position would sample the same image columns in every row, and the
/// traffic of a chunk depends on where it lies: measured on Crytek Sponza, the even and
/// the odd chunks of k = 2 gave traffic 13% below and above the whole frame's).
pub fn sampled_pixels(width: u32, height: u32, sample: u32) -> Vec<u32> {
    let p = plan(width, height, sample);
    p.tiles
        .iter()
        .enumerate()
        .filter(|(_, t)| t.1 == TileMode::Timed)
        .flat_map(|(i, _)| p.tile_pixels(i).iter().copied())
        .collect()
}

/// What the scheduler does with a tile of a sampled run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum TileMode {
    /// Simulated and counted.
    Timed,
    /// Simulated in detail, not counted: one of the [`SAMPLE_LEAD_TILES`] before a timed
    /// chunk.
    Lead,
    /// Between chunks: simulated in detail (not counted) while rays of the previous timed
    /// chunk are in flight, then warmed functionally up to the next lead tiles.
    Gap,
}

/// The tiles of an image in issue order with their modes.
#[derive(Clone, Debug)]
pub(crate) struct Plan {
    /// Every pixel in issue order.
    pub pixels: Vec<u32>,
    /// Per tile: its first index in `pixels` and its mode.
    pub tiles: Vec<(usize, TileMode)>,
}

impl Plan {
    /// The pixels of tile `i`.
    pub fn tile_pixels(&self, i: usize) -> &[u32] {
        let end = self.tiles.get(i + 1).map_or(self.pixels.len(), |t| t.0);
        &self.pixels[self.tiles[i].0..end]
    }
}

/// The plan of a run timing one in `sample` chunks.
pub(crate) fn plan(width: u32, height: u32, sample: u32) -> Plan {
    let k = sample.max(1) as u64;
    let (tw, th) = (width.div_ceil(TILE), height.div_ceil(TILE));
    let chunks = ((tw * th) as u64).div_ceil(SAMPLE_CHUNK_TILES as u64);
    let mut pixels = Vec::with_capacity(width as usize * height as usize);
    let mut tiles = Vec::with_capacity(tw as usize * th as usize);
    for ty in 0..th {
        for tx in 0..tw {
            let c = ((ty * tw + tx) / SAMPLE_CHUNK_TILES) as u64;
            let g = c / k;
            // The last run of chunks may be short: its chunk is drawn among those it has.
            let run_len = k.min(chunks - g * k);
            let timed = c % k == trace::sampling::mix64(g) % run_len;
            tiles.push((
                pixels.len(),
                if timed {
                    TileMode::Timed
                } else {
                    TileMode::Gap
                },
            ));
            for y in ty * TILE..((ty + 1) * TILE).min(height) {
                for x in tx * TILE..((tx + 1) * TILE).min(width) {
                    pixels.push(y * width + x);
                }
            }
        }
    }
    mark_lead_tiles(&mut tiles);
    Plan { pixels, tiles }
}

/// Marks the [`SAMPLE_LEAD_TILES`] untimed tiles just before each timed chunk as leading
/// into it.
fn mark_lead_tiles(tiles: &mut [(usize, TileMode)]) {
    let mut lead = 0;
    for t in tiles.iter_mut().rev() {
        match t.1 {
            TileMode::Timed => lead = SAMPLE_LEAD_TILES,
            _ if lead > 0 => {
                t.1 = TileMode::Lead;
                lead -= 1;
            }
            _ => {}
        }
    }
}

/// [`plan`] with the camera rays in scanline order: row-major pixels in groups of
/// `TILE * TILE` consecutive pixels, which the sampling plan treats as its tiles.
pub(crate) fn plan_scanline(width: u32, height: u32, sample: u32) -> Plan {
    let k = sample.max(1) as u64;
    let n = width as usize * height as usize;
    let group = (TILE * TILE) as usize;
    let groups = n.div_ceil(group);
    let chunks = (groups as u64).div_ceil(SAMPLE_CHUNK_TILES as u64);
    let pixels: Vec<u32> = (0..n as u32).collect();
    let mut tiles = Vec::with_capacity(groups);
    for t in 0..groups {
        let c = (t as u64) / SAMPLE_CHUNK_TILES as u64;
        let g = c / k;
        let run_len = k.min(chunks - g * k);
        let timed = c % k == trace::sampling::mix64(g) % run_len;
        let mode = if timed {
            TileMode::Timed
        } else {
            TileMode::Gap
        };
        tiles.push((t * group, mode));
    }
    mark_lead_tiles(&mut tiles);
    Plan { pixels, tiles }
}

fn cache(
    name: &str,
    size: u64,
    line: u32,
    banks: u32,
    latency: u64,
    cfg: &RtConfig,
) -> Result<Cache<u32>, RtError> {
    Cache::new(CacheConfig {
        name: name.to_string(),
        size_bytes: size,
        ways: cfg.ways,
        line_bytes: line,
        banks,
        mshrs: cfg.mshrs,
        targets_per_mshr: cfg.trv_units.max(1),
        hit_latency: latency,
        write_policy: WritePolicy::WriteThroughNoAllocate,
    })
    .map_err(|e| RtError::Config(ConfigError(e.to_string())))
}

/// Runs the accelerator over `work` with the tree `tree`.
pub fn run(tree: &BuiltTree, work: &Workload<'_>, cfg: &RtConfig) -> Result<RtReport, RtError> {
    run_with(tree, work, cfg, true)
}

/// [`run`], with the kernel skipping idle cycles (`skip`) or stepping every unit in every
/// cycle (the reference a skipping run must equal).
pub(crate) fn run_with(
    tree: &BuiltTree,
    work: &Workload<'_>,
    cfg: &RtConfig,
    skip: bool,
) -> Result<RtReport, RtError> {
    let start = Instant::now();
    cfg.validate(tree.kind)?;
    if work.sample == 0 {
        return Err(ConfigError("sample must be at least 1".into()).into());
    }
    if work.rays == RayMode::Diffuse && work.bounces > trace::render::MAX_BOUNCES {
        return Err(ConfigError(format!(
            "{} bounces: at most {} are supported",
            work.bounces,
            trace::render::MAX_BOUNCES
        ))
        .into());
    }
    let (width, height) = (work.camera.width(), work.camera.height());
    if width as u64 * height as u64 > MAX_PIXELS {
        return Err(ConfigError(format!(
            "a {width}x{height} image has more than {MAX_PIXELS} pixels, the most one run traces"
        ))
        .into());
    }
    let kind = tree.kind;
    let n = cfg.trv_units as usize;
    let spt = cfg.stacks_per_trv;
    let period_fs = 1_000_000_000 / cfg.clock_mhz as u64;
    let port = crate::dram::open(&cfg.dram, period_fs)?;
    let node_line = cfg.node_line(kind);
    let (sched_id, trv_ids, ist_id, l2_id) = model::unit_ids(n);
    fn fifo<T>(
        cfg: &RtConfig,
        class: usize,
        from: UnitId,
        to: UnitId,
    ) -> Result<LatencyFifo<T>, RtError> {
        LatencyFifo::new(FIFO_CLASSES[class], cfg.fifo_capacity(class), 1, from, to)
            .map_err(|e| RtError::Config(ConfigError(e.to_string())))
    }
    let mut new_ray = Vec::new();
    let mut to_ist = Vec::new();
    let mut from_ist = Vec::new();
    let mut done = Vec::new();
    let mut miss = Vec::new();
    let mut fill = Vec::new();
    for &t in &trv_ids {
        new_ray.push(fifo(cfg, 0, sched_id, t)?);
        to_ist.push(fifo(cfg, 1, t, ist_id)?);
        from_ist.push(fifo(cfg, 2, ist_id, t)?);
        done.push(fifo(cfg, 3, t, sched_id)?);
        miss.push(fifo(cfg, 4, t, l2_id)?);
        fill.push(fifo(cfg, 5, l2_id, t)?);
    }
    let slots_n = (n as u32 * spt) as usize;
    let l1s = (0..n)
        .map(|_| cache("l1", cfg.l1_bytes, node_line, 1, 1, cfg))
        .collect::<Result<Vec<_>, _>>()?;
    let order = if cfg.scanline { plan_scanline } else { plan };
    let source = RaySource::new(work, tree.image.root(), order(width, height, work.sample));
    let scheduler = model::Scheduler::new(cfg, &source.plan);
    let mut world = RtWorld {
        mem: Memory::new(port),
        tree: &tree.image,
        accel: &tree.accel,
        source,
        progress: work.progress,
        slots: vec![Slot::placeholder(); slots_n],
        new_ray,
        to_ist,
        from_ist,
        done,
        miss,
        fill,
        l1: l1s,
        l2: cache("node", cfg.l2_bytes, node_line, 1, cfg.l2_latency, cfg)?,
        prim: cache(
            "primitive",
            cfg.prim_bytes,
            cfg.prim_line_bytes,
            cfg.prim_banks,
            cfg.prim_latency,
            cfg,
        )?,
        results: Vec::new(),
        issued: Vec::new(),
        counted_bytes: 0,
        fetched: Default::default(),
        split: TrafficSplit::default(),
        window_rays: 0,
        window_cycles: 0,
        windows: Vec::new(),
        counted_visits: 0,
        counted_tests: 0,
        window_base: [0; 5],
        counted_rays: 0,
        counted_pixels: 0,
        overflow: None,
        livelock: None,
        last_finish: 0,
        livelock_cycles: cfg.livelock_cycles,
        max_depth: 0,
        stack_entries: cfg.stack_entries as usize,
        distance_stack: cfg.uses_distance_stack(kind),
    };
    let mut sched = crate::kernel::Scheduler::new(Options {
        skip,
        max_cycles: cfg.max_cycles,
        ..Options::default()
    });
    sched.add(Box::new(scheduler));
    for i in 0..n {
        sched.add(Box::new(model::Trv::new(i, cfg.trv_depth(kind), cfg)));
    }
    sched.add(Box::new(model::Ist::new(cfg)));
    sched.add(Box::new(model::NodeL2::new(node_line, n, cfg)));
    let report = sched.run(&mut world);
    if let Some(at) = world.livelock {
        return Err(RtError::Kernel(format!(
            "no ray finished between cycles {} and {at} (livelock_cycles = {}): rays keep \
             looping because the caches cannot hold a line until its ray comes back; enlarge \
             the caches or give them more ways",
            world.last_finish, cfg.livelock_cycles
        )));
    }
    let report = report.map_err(|e| RtError::Kernel(e.to_string()))?;
    if let Some(o) = world.overflow.take() {
        return Err(RtError::StackOverflow {
            pixel: o.pixel,
            bounce: o.bounce,
            depth: o.depth,
            entries: cfg.stack_entries,
        });
    }
    let mut units = Vec::new();
    for u in &report.units {
        let a = &u.activity;
        units.push(UnitFigures {
            name: u.name.clone(),
            busy: a.busy_fraction(),
            idle: a.idle_fraction(),
            stalls: a
                .stalled
                .iter()
                .map(|st| (st.reason.to_string(), a.stall_fraction(st.reason)))
                .collect(),
            counters: u
                .counters
                .iter()
                .map(|&(k, v)| (k.to_string(), v))
                .collect(),
        });
    }
    let count = |k: &str| unit_counter(&units, "", k);
    let mut l1 = CacheStats::default();
    for c in &world.l1 {
        l1.add(c.stats());
    }
    let caches = [
        ("l1", l1),
        ("node", world.l2.stats().clone()),
        ("primitive", world.prim.stats().clone()),
    ]
    .into_iter()
    .map(|(name, stats)| CacheReport {
        name: name.into(),
        hit_rate: stats.hit_rate(),
        stats,
    })
    .collect();
    let fifo_groups: [&Vec<LatencyFifo<u32>>; 4] =
        [&world.new_ray, &world.to_ist, &world.from_ist, &world.done];
    let mut fifos = Vec::new();
    for (c, name) in FIFO_CLASSES.iter().enumerate() {
        let stats: Vec<crate::kernel::LatencyFifoStats> = match c {
            0..=3 => fifo_groups[c]
                .iter()
                .map(|f| f.stats(report.cycles))
                .collect(),
            4 => world.miss.iter().map(|f| f.stats(report.cycles)).collect(),
            _ => world.fill.iter().map(|f| f.stats(report.cycles)).collect(),
        };
        let peaks: Vec<usize> = stats.iter().map(|f| f.peak).collect();
        fifos.push(FifoFigures {
            name: name.to_string(),
            capacity: cfg.fifo_capacity(c),
            high_water: peaks.iter().copied().max().unwrap_or(0),
            count: peaks.len(),
            pushes: stats.iter().map(|f| f.pushes).sum(),
        });
    }
    let memory = world.mem.port().stats();
    let memory_name = world.mem.port().name();
    let peak = world.mem.port().peak_bytes_per_unit_cycle();
    let cycles = report.cycles;
    let seconds = cycles as f64 / (cfg.clock_mhz as f64 * 1e6);
    let mut results = std::mem::take(&mut world.results);
    let detailed_rays = results.len() as u64;
    let mut mismatches = check_against_software(tree, work, &mut results, &world.issued);
    if work.sample == 1 {
        // Every pixel once.
        mismatches += (width as u64 * height as u64).abs_diff(world.issued.len() as u64);
    }
    let bytes = memory.bytes_read + memory.bytes_written;
    let sampled = work.sample > 1;
    let clock_hz = cfg.clock_mhz as f64 * 1e6;
    let (rays, mrps, frame_bytes) = if sampled {
        let per_cycle = world.window_rays as f64 / world.window_cycles.max(1) as f64;
        let frame = world.counted_bytes as f64 * (width as f64 * height as f64)
            / world.counted_pixels.max(1) as f64;
        (world.counted_rays, per_cycle * clock_hz / 1e6, frame)
    } else {
        let mrps = if seconds > 0.0 {
            detailed_rays as f64 / seconds / 1e6
        } else {
            0.0
        };
        (detailed_rays, mrps, bytes as f64)
    };
    let mut out = RtReport {
        schema: SCHEMA,
        tree: kind,
        ray_kind: work.rays,
        bounces: if work.rays == RayMode::Diffuse {
            work.bounces
        } else {
            0
        },
        width,
        height,
        sample: work.sample,
        pixels: if sampled {
            world.counted_pixels
        } else {
            world.issued.len() as u64
        },
        config: cfg.clone(),
        cycles,
        seconds,
        rays,
        detailed_rays,
        mrps,
        dram_bytes_read: memory.bytes_read,
        dram_bytes_written: memory.bytes_written,
        counted_dram_bytes: world.counted_bytes,
        frame_dram_mb: frame_bytes / 1e6,
        traffic_split: world.split,
        sampling: sampling::sampling_error(&world.windows, work.sample),
        sampling_windows: if sampled {
            std::mem::take(&mut world.windows)
        } else {
            Vec::new()
        },
        bus_utilization: if cycles > 0 {
            bytes as f64 / (peak * cycles as f64)
        } else {
            0.0
        },
        max_stack_depth: world.max_depth,
        hits_match_software: mismatches == 0,
        mismatches,
        node_visits: count("node_visits"),
        box_tests: count("box_tests"),
        triangle_tests: count("triangle_tests"),
        trv_loops: unit_counter(&units, "trv", "loops"),
        ist_loops: unit_counter(&units, "ist", "loops"),
        caches,
        units,
        fifos,
        tree_nodes: tree.image.node_count(),
        tree_leaves: (0..tree.image.node_count() as u32)
            .map(|n| {
                let mut k = 0u64;
                tree.image.for_children(n, |_, c| k += c.is_leaf() as u64);
                k
            })
            .sum(),
        tree_bytes: tree.image.bytes(),
        memory,
        memory_name,
        energy: None,
        wall_seconds: 0.0,
    };
    out.energy = Some(
        energy::accelerator_energy(&out, cfg.energy_node, &cfg.energy)
            .map_err(|e| RtError::Config(ConfigError(e.to_string())))?,
    );
    out.wall_seconds = start.elapsed().as_secs_f64();
    Ok(out)
}

/// The sum of counter `name` over the units whose names start with `prefix` (all units
/// for "").
pub fn unit_counter(units: &[UnitFigures], prefix: &str, name: &str) -> u64 {
    units
        .iter()
        .filter(|u| u.name.starts_with(prefix))
        .flat_map(|u| u.counters.iter())
        .filter(|(k, _)| k == name)
        .map(|(_, v)| *v)
        .sum()
}

/// Traces the paths of `pixels` (the camera pixels the model simulated) with the software
/// tracer over the same tree and counts the rays whose closest hit (primitive and
/// distance) differs from the model's, or that one traced and the other did not. Sorts
/// `results` by pixel and bounce.
pub fn check_against_software(
    tree: &BuiltTree,
    work: &Workload<'_>,
    results: &mut [RayResult],
    pixels: &[u32],
) -> u64 {
    results.sort_by_key(|r| (r.pixel, r.bounce));
    let mut stack = TraversalStack::new();
    let mut stats = trace::RayStats::default();
    let mut mismatches = 0u64;
    let no_plan = Plan {
        pixels: Vec::new(),
        tiles: Vec::new(),
    };
    let source = RaySource::new(work, tree.image.root(), no_plan);
    let key = |h: &Option<trace::Hit>| h.map(|h| (h.prim, h.t.to_bits()));
    let mut i = 0;
    let mut sorted = pixels.to_vec();
    sorted.sort_unstable();
    for p in sorted {
        let mut slot = Some(source.primary(p));
        while let Some(mut s) = slot.take() {
            s.best = tree.accel.closest_hit(&s.ray, &mut stack, &mut stats);
            match results.get(i) {
                Some(r) if r.pixel == p && r.bounce == s.bounce => {
                    if key(&r.hit) != key(&s.best) {
                        mismatches += 1;
                    }
                    i += 1;
                }
                _ => mismatches += 1,
            }
            slot = source.bounce(&s);
        }
    }
    mismatches + (results.len() - i.min(results.len())) as u64
}

/// \[P4\] §3's FIFO sizing: runs with `cfg`, shrinks each FIFO class to the power of two
/// above its highest occupancy ([`sized_fifo`]), and runs again with the sized FIFOs.
/// Returns the sized configuration, the first run and the run with sized FIFOs.
pub fn size_fifos(
    tree: &BuiltTree,
    work: &Workload<'_>,
    cfg: &RtConfig,
) -> Result<(RtConfig, RtReport, RtReport), RtError> {
    let first = run(tree, work, cfg)?;
    let mut sized = cfg.clone();
    for (c, f) in first.fifos.iter().enumerate() {
        sized.fifo_sizes[c] = sized_fifo(f.high_water, f.capacity) as u32;
    }
    let second = run(tree, work, &sized)?;
    Ok((sized, first, second))
}
