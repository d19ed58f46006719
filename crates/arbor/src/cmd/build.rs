//! `arbor build`: builds a BVH over a scene at one time with a named builder, validates it,
//! reports its shape, SAH and the SAH relative to a full sweep SAH build (the thesis's
//! "SAH %" columns, \[P2\] §6.2), and optionally writes it as a tree file (`bvh::io`).
//! The JSON form (`arbor.build.v1`) is documented in `docs/cli-json.md`.
//!
//! Builders are looked up by name in [`BUILDERS`], so adding one is one line. The binary
//! builders make a `Bvh2`; `mbvh4-collapse` (a binary build, `--collapse-from`, collapsed
//! by `bvh::collapse`), `mbvh4-stream` and `mbvh4-stream-w4` (the HLBVH emitter's stream
//! collapsed as it is emitted, `bvh::stream_collapse`, by the greedy rule or the windowed
//! rule with 4 levels) and `mbvh4-topdown` make the 4-wide `Mbvh4` of \[P4\]. A 4-wide
//! tree's SAH is `Mbvh4::normalized_sah` (each node costs `2 C_i` for its four box tests),
//! so it divides by the binary sweep SAH like any other.

use super::{ms, open_scene, thousands, SceneArgs};

pub mod points;
use crate::progress::Ui;
use anyhow::{bail, Context};
use bvh::{LbvhBuilder, SweepSahBuilder, Tree};
use geom::Aabb;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Above this many triangles the sweep SAH reference build (O(n log n), single pass per
/// axis, several times slower than the fast builders) is skipped unless `--sah-reference`.
pub const SAH_REFERENCE_MAX_TRIANGLES: usize = 2_000_000;
/// Largest `--threads` accepted: more threads than this only adds scheduling overhead on
/// any machine we target, and a typo like `--threads 10000` would spawn them all.
pub const MAX_THREADS: usize = 1024;
/// Largest `--max-leaf` accepted: leaves are ranges of a `u32` leaf table, and beyond a few
/// hundred primitives per leaf a tree is no longer a useful acceleration structure.
pub const MAX_LEAF_LIMIT: u32 = 1024;
/// Leaf size limit of the SAH builders when `--max-leaf` is not given (the builders' own
/// default).
pub const DEFAULT_MAX_LEAF: u32 = 8;
/// Bin counts `--bins` accepts (\[P2\] §6.2 compares binned SAH with 8, 16 and 32 bins).
pub const BIN_CHOICES: [usize; 3] = [8, 16, 32];
/// Builders that take `--bins` (binned SAH over primitives, over HLBVH cells, the 4-wide
/// top-down split search, or the object splits of `sbvh`).
const BINNED: [&str; 4] = ["binned-sah", "hlbvh+sah", "mbvh4-topdown", "sbvh"];
/// The builder that collapses a binary tree into a 4-wide one.
pub const COLLAPSE: &str = "mbvh4-collapse";
/// Binary builder whose tree `mbvh4-collapse` collapses when `--collapse-from` is not
/// given (binned SAH, the best of the fast binary builders in SAH).
pub const DEFAULT_COLLAPSE_FROM: &str = "binned-sah";

/// Bins per axis of `binned-sah` when `--bins` is not given.
pub const DEFAULT_BINS: usize = 16;

/// Settings every builder gets.
#[derive(Clone, Debug)]
pub struct BuildConfig {
    /// Largest leaf (builders with a fixed leaf size, like LBVH's 1, stay below it).
    pub max_leaf: u32,
    /// Bins per axis for binned builders.
    pub bins: usize,
    /// The binary builder whose tree `mbvh4-collapse` collapses.
    pub collapse_from: &'static str,
    /// The triangles themselves, for a builder that cuts them ([`cuts_triangles`]);
    /// the others see only the boxes. Commands that have a mesh set it for those builders.
    pub triangles: Option<std::sync::Arc<[geom::Triangle]>>,
}

impl Default for BuildConfig {
    fn default() -> Self {
        Self {
            max_leaf: DEFAULT_MAX_LEAF,
            bins: DEFAULT_BINS,
            collapse_from: DEFAULT_COLLAPSE_FROM,
            triangles: None,
        }
    }
}

/// A builder entry point. It runs in the current rayon pool (`threads: 0`): the caller
/// installs the pool that sets the thread count, so pool creation is not timed.
pub type BuildFn = fn(&[Aabb], &BuildConfig) -> anyhow::Result<Tree>;

/// The whole-tree ATRBVH pass of `hlbvh+atrbvh-cells`: the thesis's treelet size (8) with
/// one pass instead of two (issue 34's measurements: one pass keeps SAH within 1.10x sweep
/// on the shared meshes at about 70% of the second pass's time), leaves up to --max-leaf.
pub fn atrbvh_cells(c: &BuildConfig) -> bvh::AtrbvhConfig {
    bvh::AtrbvhConfig {
        max_leaf_size: c.max_leaf,
        threads: 0,
        ..bvh::AtrbvhConfig::one_pass()
    }
}

/// A binary builder's tree as a [`Tree`].
fn binary(t: Result<bvh::Bvh2, bvh::BuildError>) -> anyhow::Result<Tree> {
    Ok(Tree::Bvh2(t?))
}

/// Every builder name of the issue, in its order.
pub static BUILDERS: &[(&str, BuildFn)] = &[
    ("lbvh", |p, _| binary(LbvhBuilder::default().build(p))),
    ("hlbvh", |p, c| binary(hlbvh(c).build(p))),
    // Issue 34: HLBVH with the large primitives apart (`HlbvhBuilder::large_prims`).
    ("hlbvh-large", |p, c| binary(hlbvh_large(c).build(p))),
    ("hlbvh+sah", |p, c| {
        binary(
            bvh::HlbvhSahBuilder {
                hlbvh: hlbvh(c),
                bins: c.bins,
                threads: 0,
            }
            .build(p),
        )
    }),
    ("hlbvh+atrbvh", |p, c| {
        binary(
            bvh::HlbvhAtrbvhBuilder {
                hlbvh: hlbvh(c),
                ..Default::default()
            }
            .build(p),
        )
    }),
    // Issue 34: the thesis's build, then ATRBVH over the whole tree (the cells' subtrees
    // too, in parallel) with one pass and the SAH leaf collapse up to --max-leaf.
    ("hlbvh+atrbvh-cells", |p, c| {
        binary(
            bvh::HlbvhAtrbvhBuilder {
                hlbvh: hlbvh(c),
                cells: Some(atrbvh_cells(c)),
                ..Default::default()
            }
            .build(p),
        )
    }),
    ("binned-sah", |p, c| {
        binary(
            bvh::BinnedSahBuilder {
                bins: c.bins,
                max_leaf_size: c.max_leaf,
                threads: 0,
                ..Default::default()
            }
            .build(p),
        )
    }),
    ("sweep-sah", |p, c| binary(sweep(c).build(p))),
    ("atrbvh", |p, c| {
        binary(
            bvh::AtrbvhBuilder {
                bits: Default::default(),
                config: bvh::AtrbvhConfig {
                    max_leaf_size: c.max_leaf,
                    threads: 0,
                    ..Default::default()
                },
            }
            .build(p),
        )
    }),
    ("ploc", |p, c| binary(ploc(c).build(p))),
    ("ploc+reinsert", |p, c| {
        let mut t = ploc(&BuildConfig {
            max_leaf: 1,
            ..c.clone()
        })
        .build(p)?;
        reinsert(&mut t, p, c)?;
        Ok(Tree::Bvh2(t))
    }),
    ("hlbvh+reinsert", |p, c| {
        let mut t = hlbvh(c).build(p)?;
        reinsert(&mut t, p, c)?;
        Ok(Tree::Bvh2(t))
    }),
    (COLLAPSE, |p, c| {
        // The binary build and the collapse together are the 4-wide build.
        let from = binary_builder_name(c.collapse_from, CLI_NAMES.collapse_from)?;
        let Tree::Bvh2(t) = builder(from)?(p, c)? else {
            anyhow::bail!("--collapse-from {from} did not build a binary tree")
        };
        Ok(Tree::Mbvh4(bvh::collapse(&t)?))
    }),
    ("mbvh4-stream", |p, c| {
        // The HLBVH emitter's stream collapsed as it is emitted (issue 18 part 2): the tree
        // MergeTree writes with `--set output=mbvh4`.
        let hl = hlbvh(c).build_highlevel(p)?;
        Ok(Tree::Mbvh4(bvh::stream_collapse(&hl)?.0))
    }),
    ("mbvh4-stream-w4", |p, c| {
        // The same stream with the windowed rule, 4 levels unresolved: the tree of
        // `--set output=mbvh4 --set mbvh4_window=4`.
        let hl = hlbvh(c).build_highlevel(p)?;
        let sc = bvh::StreamCollapse::with_window(4);
        Ok(Tree::Mbvh4(bvh::stream_collapse_with(&hl, sc)?.0))
    }),
    ("sbvh", |p, c| {
        // Spatial splits (Stich et al. 2009; issues 33 and 34): leaves name parts of
        // triangles, so the builder needs the triangles, not only their boxes.
        let Some(tris) = c.triangles.as_deref() else {
            bail!("the sbvh builder cuts triangles and needs them; this command gives builders only the triangles' boxes")
        };
        anyhow::ensure!(
            tris.len() == p.len(),
            "sbvh got {} triangles for {} boxes",
            tris.len(),
            p.len()
        );
        binary(
            bvh::SbvhBuilder {
                bins: c.bins,
                max_leaf_size: c.max_leaf,
                threads: 0,
                ..Default::default()
            }
            .build(tris),
        )
    }),
    ("mbvh4-topdown", |p, c| {
        Ok(Tree::Mbvh4(
            bvh::Mbvh4TopDownBuilder {
                bins: c.bins,
                max_leaf_size: c.max_leaf,
                threads: 0,
                ..Default::default()
            }
            .build(p)?,
        ))
    }),
];

/// Whether builder `name` cuts triangles (spatial splits): it needs
/// [`BuildConfig::triangles`], and its leaves may name a triangle more than once, each time
/// for a part of it ([`validate_built`] checks that with `bvh::validate_spatial`).
pub fn cuts_triangles(name: &str) -> bool {
    name == "sbvh"
}

/// The triangles of `mesh` for a builder that cuts them ([`cuts_triangles`]), else `None`.
pub fn triangles_for(name: &str, mesh: &scene::Mesh) -> Option<std::sync::Arc<[geom::Triangle]>> {
    cuts_triangles(name).then(|| mesh.triangles_iter().collect())
}

/// Validates the tree builder `name` made over `prims` (`bvh::validate_spatial` for a
/// builder that cuts triangles, the tree's own validator otherwise).
pub fn validate_built(
    tree: &Tree,
    name: &str,
    prims: &[Aabb],
    max_leaf: u32,
) -> Result<(), bvh::ValidationError> {
    match tree {
        Tree::Bvh2(t) if cuts_triangles(name) => bvh::validate_spatial(t, prims, max_leaf),
        t => t.validate(prims, max_leaf),
    }
}

/// Whether builder `name` makes a 4-wide tree.
pub fn is_wide(name: &str) -> bool {
    name.starts_with("mbvh4-")
}

/// The streaming HLBVH builder for a configuration (\[P2\] leaf combining of identical
/// Morton codes, leaves up to `max_leaf`).
fn hlbvh(c: &BuildConfig) -> bvh::HlbvhBuilder {
    bvh::HlbvhBuilder {
        max_leaf_size: c.max_leaf,
        threads: 0,
        ..Default::default()
    }
}

/// [`hlbvh`] with the large primitives apart ([`bvh::LARGE_PRIMS_FRACTION`]).
fn hlbvh_large(c: &BuildConfig) -> bvh::HlbvhBuilder {
    bvh::HlbvhBuilder {
        large_prims: Some(bvh::LARGE_PRIMS_FRACTION),
        ..hlbvh(c)
    }
}

/// The PLOC builder for a configuration (radius 16, leaves collapsed up to `max_leaf`).
fn ploc(c: &BuildConfig) -> bvh::PlocBuilder {
    bvh::PlocBuilder {
        max_leaf_size: c.max_leaf,
        threads: 0,
        ..Default::default()
    }
}

/// The reinsertion optimizer (`X+reinsert`) over the tree `t` built over `p`, then the SAH
/// leaf collapse up to `max_leaf`. `bvh::reinsert` validates its input tree first, so the
/// time of an `X+reinsert` build includes one validation pass.
fn reinsert(t: &mut bvh::Bvh2, p: &[Aabb], c: &BuildConfig) -> anyhow::Result<()> {
    bvh::reinsert(
        t,
        p,
        &bvh::ReinsertConfig {
            max_leaf_size: c.max_leaf,
            threads: 0,
            ..Default::default()
        },
    )?;
    Ok(())
}

/// The sweep SAH builder for a configuration (also the SAH normalization reference).
fn sweep(c: &BuildConfig) -> SweepSahBuilder {
    SweepSahBuilder {
        max_leaf_size: c.max_leaf,
        threads: 0,
        ..Default::default()
    }
}

/// Names of every builder, in the issue's order.
pub fn available_builders() -> impl Iterator<Item = &'static str> {
    BUILDERS.iter().map(|(n, _)| *n)
}

/// The builder called `name`, or a one-line error listing the valid names.
pub fn builder(name: &str) -> anyhow::Result<BuildFn> {
    match BUILDERS.iter().find(|(n, _)| *n == name) {
        Some((_, f)) => Ok(*f),
        None => bail!(
            "unknown builder '{name}'; valid names: {}",
            available_builders().collect::<Vec<_>>().join(", ")
        ),
    }
}

/// The buffers a builder keeps from one build to the next, as a renderer keeps them from
/// frame to frame: the previous tree, and the builder's scratch arena. Only the builders of
/// [`REUSING`] use them.
#[derive(Debug, Default)]
pub struct Frame {
    /// The previous build's tree, whose buffers the next build writes into.
    tree: Option<bvh::Bvh2>,
    /// HLBVH's sort, code and cell buffers.
    hlbvh: bvh::HlbvhArena,
}

impl Frame {
    /// Keeps the buffers of `t`, a tree this frame built, for the next build.
    pub fn recycle(&mut self, t: Tree) {
        if let Tree::Bvh2(b) = t {
            self.tree = Some(b);
        }
    }

    /// Bytes the frame holds between builds (its buffers' capacity).
    pub fn held_bytes(&self) -> usize {
        let tree = self.tree.as_ref().map_or(0, |t| {
            t.nodes.capacity() * std::mem::size_of::<bvh::Node>()
                + t.prim_indices.capacity() * std::mem::size_of::<u32>()
        });
        tree + self.hlbvh.capacity_bytes()
    }
}

/// A builder entry point that builds into the buffers of a [`Frame`] (the returned tree
/// goes back to the frame by [`Frame::recycle`]). Runs in the current rayon pool.
pub type BuildIntoFn = fn(&[Aabb], &BuildConfig, &mut Frame) -> anyhow::Result<Tree>;

/// The builders that can build into the buffers of their previous build, with the same
/// trees as their [`BUILDERS`] entry.
pub static REUSING: &[(&str, BuildIntoFn)] = &[
    ("hlbvh", |p, c, f| hlbvh_into(hlbvh(c), p, f)),
    ("hlbvh-large", |p, c, f| hlbvh_into(hlbvh_large(c), p, f)),
];

/// An HLBVH build into the frame's previous tree and arena.
fn hlbvh_into(b: bvh::HlbvhBuilder, p: &[Aabb], f: &mut Frame) -> anyhow::Result<Tree> {
    let mut t = f.tree.take().unwrap_or_else(bvh::Bvh2::empty);
    b.build_into(p, &mut f.hlbvh, &mut t)?;
    Ok(Tree::Bvh2(t))
}

/// The [`REUSING`] entry point of builder `name`, if it has one.
pub fn reusing_builder(name: &str) -> Option<BuildIntoFn> {
    REUSING.iter().find(|(n, _)| *n == name).map(|(_, f)| *f)
}

/// The registered name of binary builder `name` (what `--collapse-from` accepts; `option`
/// is how messages spell that option).
fn binary_builder_name(name: &str, option: &str) -> anyhow::Result<&'static str> {
    builder(name)?;
    // A tree with cut triangles cannot be collapsed yet: the 4-wide formats and their
    // validator hold each triangle once.
    let binary = |n: &&str| !is_wide(n) && !cuts_triangles(n);
    match available_builders().find(|n| *n == name && binary(n)) {
        Some(n) => Ok(n),
        None => bail!(
            "{option} needs a binary builder whose leaves hold each triangle once, not {name}; valid names: {}",
            available_builders()
                .filter(binary)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Arguments of `arbor build`.
#[derive(clap::Args, Debug)]
pub struct BuildArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Builder: lbvh, hlbvh, hlbvh-large (HLBVH with primitives wider than half the
    /// centroid box sorted apart), hlbvh+sah, hlbvh+atrbvh, hlbvh+atrbvh-cells, binned-sah,
    /// sweep-sah, atrbvh, ploc,
    /// ploc+reinsert, hlbvh+reinsert (binary trees), sbvh (binary, with spatial splits:
    /// leaves name parts of triangles; no --out yet), mbvh4-collapse, mbvh4-stream,
    /// mbvh4-stream-w4, mbvh4-topdown (4-wide trees); kdtree-points, octree-points (point
    /// trees over the triangles' centroids, checked against brute-force kNN).
    #[arg(long, value_name = "NAME")]
    builder: String,
    /// mbvh4-collapse: the binary builder whose tree is collapsed (default binned-sah).
    #[arg(long, value_name = "NAME")]
    collapse_from: Option<String>,
    /// Time in seconds at which to sample the scene (clamped to its timeline).
    #[arg(long, value_name = "SECONDS", conflicts_with = "frame")]
    time: Option<f32>,
    /// Frame number at which to sample the scene.
    #[arg(long, value_name = "N")]
    frame: Option<u32>,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Largest leaf, in primitives (default 8; LBVH leaves always hold 1).
    #[arg(long, value_name = "N")]
    max_leaf: Option<u32>,
    /// Bins per axis for binned-sah, hlbvh+sah and mbvh4-topdown: 8, 16 or 32 (default 16).
    #[arg(long, value_name = "N")]
    bins: Option<usize>,
    /// Print JSON (schema `arbor.build.v1`) instead of text.
    #[arg(long)]
    json: bool,
    /// Write the tree to FILE in the Arbor tree format (docs/tree-format.md), atomically.
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Build the tree at time T0 (seconds), then refit it to --time/--frame (the scene's
    /// topology must be stable); reports the refitted tree.
    #[arg(long, value_name = "T0")]
    refit_from: Option<f32>,
    /// Build the sweep SAH reference for `sah_vs_sweep` even above 2M triangles.
    #[arg(long)]
    sah_reference: bool,
}

/// The JSON document `arbor build --json` prints (`arbor.build.v1`).
#[derive(Serialize, Debug)]
pub struct BuildJson {
    /// `"arbor.build.v1"`.
    pub schema: &'static str,
    /// Scene spec as given.
    pub scene: String,
    /// Builder name.
    pub builder: String,
    /// Time sampled, after clamping.
    pub time_s: f32,
    /// `--frame` if given.
    pub frame: Option<u32>,
    /// Triangles (primitives) built over.
    pub triangles: usize,
    /// Tree format: `"Bvh2"` (binary) or `"Mbvh4"` (4-wide).
    pub tree_kind: &'static str,
    /// Children per node: 2 or 4.
    pub width: usize,
    /// Bytes per node: 64 or 128.
    pub node_bytes: usize,
    /// Mean number of used child slots per node.
    pub mean_children: f64,
    /// mbvh4-collapse: the binary builder whose tree was collapsed (null otherwise).
    pub collapse_from: Option<&'static str>,
    /// Nodes (64-byte binary or 128-byte 4-wide nodes).
    pub inner_nodes: usize,
    /// Leaves.
    pub leaves: usize,
    /// Largest leaf in the tree.
    pub max_leaf_size: u32,
    /// The leaf size limit the tree was built and validated with.
    pub max_leaf_limit: u32,
    /// Longest root-to-leaf path in nodes.
    pub max_depth: usize,
    /// SAH cost with the thesis parameters (a 4-wide node costs `2 C_i`).
    pub sah: f64,
    /// SAH relative to a sweep SAH build of the same primitives (null when skipped).
    pub sah_vs_sweep: Option<f64>,
    /// SAH of the sweep reference (null when skipped).
    pub sweep_sah: Option<f64>,
    /// Why `sah_vs_sweep` is null, else null.
    pub sah_reference_note: Option<String>,
    /// Builder wall time (excludes AABB computation, validation and the reference build).
    pub build_ms: f64,
    /// Time to compute the primitive boxes from the mesh.
    pub aabb_ms: f64,
    /// Time of the sweep reference build (null when skipped or when it is the tree itself).
    pub reference_ms: Option<f64>,
    /// Time to open the scene.
    pub open_ms: f64,
    /// Time to sample the mesh.
    pub sample_ms: f64,
    /// Worker threads of the pool the builder ran in.
    pub threads: usize,
    /// Bins per axis (binned builders only).
    pub bins: Option<usize>,
    /// The validator passed (always true in printed output: a failure is an error).
    pub valid: bool,
    /// Tree file written, if any.
    pub out: Option<String>,
    /// With `--refit-from`: the time the tree was built at (null otherwise).
    pub refit_from_s: Option<f32>,
    /// With `--refit-from`: SAH of the tree at its build time, over that frame's boxes.
    pub sah_at_build: Option<f64>,
    /// With `--refit-from`: wall time of the refit (`build_ms` is the build at T0).
    pub refit_ms: Option<f64>,
    /// Bytes of the node array plus leaf table in memory.
    pub tree_bytes: usize,
}

/// Computes the primitive boxes of a mesh; returns them with the time taken.
pub fn mesh_aabbs(mesh: &scene::Mesh) -> anyhow::Result<(Vec<Aabb>, f64)> {
    let s = Instant::now();
    let a = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)
        .context("cannot compute triangle bounds")?;
    Ok((a, ms(s.elapsed())))
}

/// Runs `f` on `aabbs` with a spinner; returns the tree and the builder's wall time.
pub fn timed_build(
    ui: &Ui,
    name: &str,
    f: BuildFn,
    cfg: &BuildConfig,
    aabbs: &[Aabb],
) -> anyhow::Result<(Tree, f64)> {
    let spinner = ui.spinner(&format!(
        "building {name} over {} triangles",
        thousands(aabbs.len() as u64)
    ));
    let s = Instant::now();
    let t = f(aabbs, cfg).with_context(|| format!("builder {name} failed"))?;
    let elapsed = ms(s.elapsed());
    drop(spinner);
    Ok((t, elapsed))
}

/// How the build options are spelled in messages: the command line's flags, or another
/// front end's argument names (the Python package's `max_leaf=`).
pub struct OptionNames {
    pub builder: &'static str,
    pub threads: &'static str,
    pub max_leaf: &'static str,
    pub collapse_from: &'static str,
    pub bins: &'static str,
}

/// The command line's spelling of the build options.
pub const CLI_NAMES: OptionNames = OptionNames {
    builder: "--builder",
    threads: "--threads",
    max_leaf: "--max-leaf",
    collapse_from: "--collapse-from",
    bins: "--bins",
};

/// The builder and configuration of `arbor build`'s options, checked with its rules (the
/// one place they live: the command line and the Python package both call it); `names`
/// spells the options in the messages.
pub fn build_config(
    names: &OptionNames,
    builder_name: &str,
    threads: Option<usize>,
    max_leaf: Option<u32>,
    collapse_from: Option<&str>,
    bins: Option<usize>,
) -> anyhow::Result<(BuildFn, BuildConfig)> {
    let f = builder(builder_name)?;
    if let Some(t) = threads {
        anyhow::ensure!(
            (1..=MAX_THREADS).contains(&t),
            "{} must be between 1 and {MAX_THREADS}, got {t}",
            names.threads
        );
    }
    let mut cfg = BuildConfig::default();
    if let Some(m) = max_leaf {
        anyhow::ensure!(
            (1..=MAX_LEAF_LIMIT).contains(&m),
            "{} must be between 1 and {MAX_LEAF_LIMIT}, got {m}",
            names.max_leaf
        );
        cfg.max_leaf = m;
    }
    if let Some(from) = collapse_from {
        anyhow::ensure!(
            builder_name == COLLAPSE,
            "{} applies only to {} {COLLAPSE}",
            names.collapse_from,
            names.builder
        );
        cfg.collapse_from = binary_builder_name(from, names.collapse_from)?;
    }
    if let Some(b) = bins {
        anyhow::ensure!(
            BINNED.contains(&builder_name),
            "{} applies only to {} {}",
            names.bins,
            names.builder,
            BINNED.join(", ")
        );
        anyhow::ensure!(
            BIN_CHOICES.contains(&b),
            "{} must be 8, 16 or 32, got {b}",
            names.bins
        );
        cfg.bins = b;
    }
    Ok((f, cfg))
}

/// Checks the arguments that need no scene, so bad input fails before a long load.
fn check_args(a: &BuildArgs) -> anyhow::Result<(BuildFn, BuildConfig)> {
    let checked = build_config(
        &CLI_NAMES,
        &a.builder,
        a.threads,
        a.max_leaf,
        a.collapse_from.as_deref(),
        a.bins,
    )?;
    super::check_seconds("--refit-from", a.refit_from)?;
    if let Some(out) = &a.out {
        anyhow::ensure!(
            !cuts_triangles(&a.builder),
            "--out: a {} tree cannot be written to a tree file yet (the format stores each triangle exactly once; its leaves name parts of triangles)",
            a.builder
        );
        check_out_path(out)?;
    }
    Ok(checked)
}

/// Fails early when `--out` cannot be written: a directory, or a missing parent folder.
fn check_out_path(out: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(
        !out.is_dir(),
        "cannot write tree file {}: it is a directory",
        out.display()
    );
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    anyhow::ensure!(
        parent.is_dir(),
        "cannot write tree file {}: folder {} does not exist",
        out.display(),
        parent.display()
    );
    Ok(())
}

/// How `sah_vs_sweep` is obtained.
#[derive(Debug, PartialEq)]
enum Reference {
    /// The tree is the sweep SAH build: the ratio is exactly 1.
    Itself,
    /// Build a sweep SAH tree of the same primitives.
    Build,
    /// Skip the reference, for this reason.
    Skip(String),
}

/// Whether to build the sweep SAH reference for `builder` over `triangles` primitives.
fn reference_plan(builder: &str, triangles: usize, force: bool) -> Reference {
    if builder == "sweep-sah" {
        Reference::Itself
    } else if triangles > SAH_REFERENCE_MAX_TRIANGLES && !force {
        Reference::Skip(format!(
            "sweep SAH reference skipped above {} triangles (use --sah-reference)",
            thousands(SAH_REFERENCE_MAX_TRIANGLES as u64)
        ))
    } else {
        Reference::Build
    }
}

/// Runs `arbor build`.
pub fn run(args: &BuildArgs, ui: &Ui) -> anyhow::Result<()> {
    if points::POINT_BUILDERS.contains(&args.builder.as_str()) {
        return points::run_points(args, ui);
    }
    let (build_fn, mut cfg) = check_args(args)?;
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = args.threads {
            b = b.num_threads(t);
        }
        b.build().context("cannot create the worker thread pool")?
    };
    let (scene, open) = open_scene(&args.scene, ui)?;
    let info = scene.info();
    let time_s = super::resolve_time(info, args.time, args.frame)?;
    let s = Instant::now();
    let mesh = {
        let _spinner = ui.spinner(&format!("sampling {} at t = {time_s} s", args.scene.scene));
        scene
            .mesh_at(time_s)
            .with_context(|| format!("cannot sample the scene at t = {time_s} s"))?
    };
    let sample_ms = ms(s.elapsed());
    let (aabbs, aabb_ms) = mesh_aabbs(&mesh)?;
    cfg.triangles = triangles_for(&args.builder, &mesh);
    drop(mesh);

    // With --refit-from, build over the boxes at T0, then refit to the boxes at time_s.
    let (tree, build_ms, refit) = match args.refit_from {
        None => {
            let (tree, build_ms) =
                pool.install(|| timed_build(ui, &args.builder, build_fn, &cfg, &aabbs))?;
            (tree, build_ms, None)
        }
        Some(t0) => {
            anyhow::ensure!(
                info.stable_topology,
                "--refit-from needs a scene with stable topology; {} changes its triangles over time",
                args.scene.scene
            );
            let t0 = info.timeline.clamp(t0);
            let mesh0 = scene
                .mesh_at(t0)
                .with_context(|| format!("cannot sample the scene at t = {t0} s"))?;
            let (aabbs0, _) = mesh_aabbs(&mesh0)?;
            let cfg0 = BuildConfig {
                triangles: triangles_for(&args.builder, &mesh0),
                ..cfg.clone()
            };
            drop(mesh0);
            let (mut tree, build_ms) =
                pool.install(|| timed_build(ui, &args.builder, build_fn, &cfg0, &aabbs0))?;
            let sah_at_build = tree.normalized_sah();
            let s = Instant::now();
            pool.install(|| tree.refit(&aabbs))
                .context("cannot refit the tree")?;
            (tree, build_ms, Some((t0, sah_at_build, ms(s.elapsed()))))
        }
    };
    validate_built(&tree, &args.builder, &aabbs, cfg.max_leaf)
        .with_context(|| format!("builder {} produced an invalid tree", args.builder))?;

    // The normalization reference: the tree itself for sweep-sah, else a sweep build.
    let sah = tree.normalized_sah();
    let (sweep_sah, reference_ms, note) =
        match reference_plan(&args.builder, aabbs.len(), args.sah_reference) {
            Reference::Itself => (Some(sah), None, None),
            Reference::Skip(note) => (None, None, Some(note)),
            Reference::Build => {
                let (r, r_ms) = pool.install(|| {
                    timed_build(
                        ui,
                        "sweep-sah (reference)",
                        |p, c| binary(sweep(c).build(p)),
                        &cfg,
                        &aabbs,
                    )
                })?;
                (Some(r.normalized_sah()), Some(r_ms), None)
            }
        };
    let sah_vs_sweep = sweep_sah.map(|r| bvh::sah_ratio(sah, r));

    if let Some(out) = &args.out {
        bvh::io::write_tree_file(&tree, &args.builder, out)
            .with_context(|| format!("cannot write tree file {}", out.display()))?;
    }
    let st = tree.stats();
    let j = BuildJson {
        schema: "arbor.build.v1",
        scene: args.scene.scene.clone(),
        builder: args.builder.clone(),
        time_s,
        frame: args.frame,
        triangles: aabbs.len(),
        tree_kind: tree.kind().name(),
        width: tree.kind().width(),
        node_bytes: tree.kind().node_bytes(),
        mean_children: tree.mean_children(),
        collapse_from: (args.builder == COLLAPSE).then_some(cfg.collapse_from),
        inner_nodes: st.inner_nodes,
        leaves: st.leaves,
        max_leaf_size: st.max_leaf_size,
        max_leaf_limit: cfg.max_leaf,
        max_depth: st.max_depth,
        sah,
        sah_vs_sweep,
        sweep_sah,
        sah_reference_note: note,
        build_ms,
        aabb_ms,
        reference_ms,
        open_ms: ms(open),
        sample_ms,
        threads: pool.current_num_threads(),
        bins: BINNED.contains(&args.builder.as_str()).then_some(cfg.bins),
        valid: true,
        out: args.out.as_ref().map(|p| p.display().to_string()),
        refit_from_s: refit.map(|r| r.0),
        sah_at_build: refit.map(|r| r.1),
        refit_ms: refit.map(|r| r.2),
        tree_bytes: tree.bytes(),
    };
    if args.json {
        ui.emit_json(&j)?;
    } else {
        print_text(&j);
    }
    Ok(())
}

fn print_text(j: &BuildJson) {
    let at = match j.frame {
        Some(f) => format!("t = {:.3} s, frame {f}", j.time_s),
        None => format!("t = {:.3} s", j.time_s),
    };
    println!("scene         {} ({at})", j.scene);
    let bins = j.bins.map(|b| format!(", {b} bins")).unwrap_or_default();
    let from = j
        .collapse_from
        .map(|f| format!(", collapsing {f}"))
        .unwrap_or_default();
    println!(
        "builder       {} ({} threads, max leaf {}{bins}{from})",
        j.builder, j.threads, j.max_leaf_limit
    );
    println!("triangles     {}", thousands(j.triangles as u64));
    println!(
        "tree          {} inner nodes ({}-wide, {} bytes, {:.2} children each), {} leaves, largest leaf {}, depth {}, {:.1} MiB",
        thousands(j.inner_nodes as u64),
        j.width,
        j.node_bytes,
        j.mean_children,
        thousands(j.leaves as u64),
        j.max_leaf_size,
        j.max_depth,
        j.tree_bytes as f64 / (1024.0 * 1024.0)
    );
    let units = if j.width > 2 {
        ", a 4-wide node costing 2 C_i"
    } else {
        ""
    };
    match (j.sah_vs_sweep, &j.sah_reference_note) {
        (Some(r), _) => println!(
            "SAH           {:.3} ({:.2}% of sweep SAH{units})",
            j.sah,
            r * 100.0
        ),
        (None, Some(n)) => println!("SAH           {:.3} ({n})", j.sah),
        (None, None) => println!("SAH           {:.3}", j.sah),
    }
    let mtris = if j.build_ms > 0.0 {
        format!(" ({:.1} Mtris/s)", j.triangles as f64 / j.build_ms / 1e3)
    } else {
        String::new()
    };
    println!(
        "time          build {:.2} ms{mtris}; boxes {:.2} ms; open {:.1} ms; sample {:.1} ms",
        j.build_ms, j.aabb_ms, j.open_ms, j.sample_ms
    );
    if let (Some(t0), Some(sah0), Some(r_ms)) = (j.refit_from_s, j.sah_at_build, j.refit_ms) {
        println!(
            "refit         built at t = {t0:.3} s (SAH {sah0:.3}), refitted in {r_ms:.2} ms; SAH now {:.2}x its build-time SAH",
            bvh::sah_ratio(j.sah, sah0)
        );
    }
    println!("valid         yes");
    if let Some(o) = &j.out {
        println!("written       {o}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_issue_builder_name_is_known() {
        for n in [
            "lbvh",
            "hlbvh",
            "hlbvh-large",
            "hlbvh+sah",
            "hlbvh+atrbvh",
            "hlbvh+atrbvh-cells",
            "binned-sah",
            "sweep-sah",
            "atrbvh",
            "ploc",
            "ploc+reinsert",
            "hlbvh+reinsert",
            "mbvh4-collapse",
            "mbvh4-stream",
            "mbvh4-stream-w4",
            "sbvh",
            "mbvh4-topdown",
        ] {
            assert!(BUILDERS.iter().any(|(b, _)| *b == n), "{n}");
        }
        let e = builder("nope").err().unwrap().to_string();
        assert!(e.contains("lbvh") && e.contains("mbvh4-topdown"), "{e}");
        assert_eq!(available_builders().count(), BUILDERS.len());
        assert_eq!(
            binary_builder_name("hlbvh", CLI_NAMES.collapse_from).unwrap(),
            "hlbvh"
        );
        let e = binary_builder_name("mbvh4-topdown", CLI_NAMES.collapse_from)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("binary builder") && e.contains("sweep-sah"),
            "{e}"
        );
        assert!(binary_builder_name("nope", CLI_NAMES.collapse_from).is_err());
    }

    #[test]
    fn sweep_reference_is_skipped_only_for_huge_scenes_unless_forced() {
        let big = SAH_REFERENCE_MAX_TRIANGLES + 1;
        assert_eq!(reference_plan("sweep-sah", big, false), Reference::Itself);
        assert_eq!(reference_plan("lbvh", 5000, false), Reference::Build);
        assert_eq!(
            reference_plan("lbvh", SAH_REFERENCE_MAX_TRIANGLES, false),
            Reference::Build
        );
        assert_eq!(reference_plan("lbvh", big, true), Reference::Build);
        match reference_plan("binned-sah", big, false) {
            Reference::Skip(n) => assert!(n.contains("--sah-reference"), "{n}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn available_builders_give_valid_trees() {
        let tris: Vec<geom::Triangle> = (0..300)
            .map(|i| {
                let p = geom::Vec3::new((i % 7) as f32, (i % 11) as f32, (i % 13) as f32);
                geom::Triangle::new(p, p + geom::Vec3::X * 0.5, p + 0.5)
            })
            .collect();
        let aabbs = bvh::triangle_aabbs(&tris);
        for name in available_builders() {
            let cfg = BuildConfig {
                max_leaf: 4,
                triangles: cuts_triangles(name).then(|| tris.clone().into()),
                ..Default::default()
            };
            let t = builder(name).unwrap()(&aabbs, &cfg).unwrap();
            assert_eq!(validate_built(&t, name, &aabbs, 4), Ok(()), "{name}");
            if !cuts_triangles(name) {
                assert_eq!(t.validate(&aabbs, 4), Ok(()), "{name}");
            }
            assert_eq!(
                t.kind().width(),
                if is_wide(name) { 4 } else { 2 },
                "{name}"
            );
        }
        // The collapse of a chosen binary builder is exactly that tree collapsed.
        let cfg = BuildConfig {
            collapse_from: "lbvh",
            ..Default::default()
        };
        let t = builder(COLLAPSE).unwrap()(&aabbs, &cfg).unwrap();
        let lbvh = LbvhBuilder::default().build(&aabbs).unwrap();
        assert_eq!(t, Tree::Mbvh4(bvh::collapse(&lbvh).unwrap()));
        let cfg = BuildConfig {
            collapse_from: COLLAPSE,
            ..Default::default()
        };
        assert!(builder(COLLAPSE).unwrap()(&aabbs, &cfg).is_err());
        // Without the triangles, sbvh says what it needs; it is no collapse source.
        let e = builder("sbvh").unwrap()(&aabbs, &BuildConfig::default()).unwrap_err();
        assert!(e.to_string().contains("needs them"), "{e}");
        let e = binary_builder_name("sbvh", CLI_NAMES.collapse_from).unwrap_err();
        assert!(e.to_string().contains("each triangle once"), "{e}");
    }
}
