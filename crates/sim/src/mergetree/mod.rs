//! MergeTree, the hardware HLBVH builder of \[P1\] and \[P2\] §4-6, as a cycle-level model
//! whose speed is set by its DRAM traffic.
//!
//! The unit sorts the primitives' AABBs by the Morton codes of their centroids with an
//! external multi-merge sort and streams the sorted AABBs into the hierarchy emitter:
//! - [`config`]: parameters and the presets `p1` and `p2`;
//! - [`machine`]: the units on the simulation kernel ([`crate::kernel`]): the control FSM,
//!   the reader (32-byte AABBs read in bursts of B, Morton codes computed as they stream in,
//!   \[P2\] §5.1, or in the point modes 16-byte points and references,
//!   [`MergeTreeConfig::elem_bytes`]; refills of the merge queues), the run writer, the write buffers and the
//!   round-robin memory arbiter, each a kernel unit or channel, plus the DRAM layout;
//! - [`presort`]: the insertion presorters of the partial-sort mode (\[P2\] §5.5);
//! - [`heap`]: the pipelined merge heap (\[P2\] §5.2);
//! - [`merge`]: the multi-merge unit, its double-buffered scratchpad and the even/odd
//!   schedule of \[P2\] Fig. 4 (§5.3), with as many merge passes as the scene needs;
//! - [`emitter`]: the hierarchy emitter (\[P2\] §5.4, Algorithm 1), which drives the same
//!   [`bvh::Emitter`] as the software builder, so the tree is the software tree;
//! - [`toplevel`]: the optional toplevel binned SAH unit (\[P2\] §6.1);
//! - [`cbvh_unit`]: the CBVH output of \[P3\] §5.3: the streaming bottom-up encoder behind
//!   the emitter (backtracking steps as DRAM reads and writes), or a top-down compression
//!   pass after the build;
//! - [`mbvh4_unit`]: the MBVH4 output (issue 18 part 2): the streaming collapse behind the
//!   emitter, or a collapse pass after the build (the baseline);
//! - [`report`]: cycles, traffic, utilization, stalls, time series (CSV and SVG).
//!
//! The centroid bounds that scale the Morton codes are an input of the unit (a
//! configuration register written by the host, as the scene bounds are known to the
//! application); computing them would take one more streaming read of the AABBs.
//!
//! Padding: the scene is padded to a multiple of B with elements whose code lies above
//! every real code (\[P2\] §5.3), so they sort last and end the emitter's stream.

pub mod cbvh_unit;
pub mod config;
pub mod emitter;
pub mod energy;
pub mod heap;
pub mod machine;
pub mod mbvh4_unit;
pub mod merge;
pub mod presort;
pub mod report;
pub mod toplevel;

pub use config::{ConfigError, KdNode, MergeTreeConfig, OutputMode, ReadSchedule};
pub use machine::MemoryLayout;
pub use mbvh4_unit::{Cbvh4RunReport, CollapseUnitStats, Mbvh4RunReport};
pub use report::{
    CbvhRunReport, MergeTreeReport, PhaseReport, PointRunReport, StallReport, TraceRow,
};

use bvh::{Bvh2, HlbvhBuilder, HlbvhSahBuilder, MortonBits};
use geom::Aabb;

use crate::dram::MemoryPort;

/// Morton code of the padding elements: above every 63-bit code.
const PAD_CODE: u64 = 1 << 63;

/// One sort element (\[P2\] §5.1): the AABB and the sort key (Morton code, then primitive
/// reference, so the order is the software builder's stable (code, index) order).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Elem {
    /// Morton code (padding: above every code).
    pub code: u64,
    /// Primitive reference.
    pub index: u32,
    /// The primitive's box.
    pub aabb: Aabb,
}

impl Elem {
    /// Placeholder contents of empty storage.
    pub const PAD: Elem = Elem {
        code: PAD_CODE,
        index: 0,
        aabb: Aabb::EMPTY,
    };

    /// The element of primitive `index` with Morton code `code`.
    pub fn new(code: u64, index: u32, aabb: Aabb) -> Self {
        Self { code, index, aabb }
    }

    /// A padding element at position `i` past the end of the scene.
    pub fn pad(i: u64) -> Self {
        Self {
            code: PAD_CODE,
            index: i as u32,
            aabb: Aabb::EMPTY,
        }
    }

    /// The sort key `code << 32 | index`: the software builder's (code, index) order.
    #[inline]
    pub fn key(&self) -> u128 {
        ((self.code as u128) << 32) | self.index as u128
    }

    /// True for padding.
    pub fn is_pad(&self) -> bool {
        self.code >= PAD_CODE
    }
}

/// Errors of a simulation.
#[derive(Debug, thiserror::Error)]
pub enum MergeTreeError {
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The input cannot be built.
    #[error("invalid input: {0}")]
    Input(String),
    /// No unit could make progress while work remained.
    #[error("MergeTree deadlock: {0}")]
    Deadlock(String),
    /// The software reference builder failed.
    #[error(transparent)]
    Build(#[from] bvh::BuildError),
    /// The CBVH encoder refused the tree (for example, more node pairs than its pointers
    /// address).
    #[error("CBVH output: {0}")]
    Cbvh(#[from] cbvh::CbvhError),
    /// The MBVH4 collapse refused the emitted stream (cannot happen with a correct
    /// emitter).
    #[error("MBVH4 output: {0}")]
    Collapse(#[from] bvh::CollapseError),
    /// The point writer failed (`output = kdtree-points`).
    #[error("point k-d tree output: {0}")]
    Points(#[from] bvh::PointError),
}

/// The centroid bounds of `aabbs`, with the software builder's centroid expression.
pub fn centroid_bounds(aabbs: &[Aabb]) -> Aabb {
    aabbs
        .iter()
        .fold(Aabb::EMPTY, |b, a| b.grow(a.min * 0.5 + a.max * 0.5))
}

/// The primitives of the point mode (`output = kdtree-points`): each point as a
/// degenerate box, whose centroid the reader computes as the point itself. Errors on a
/// non-finite point, and on a subnormal coordinate, which the centroid expression
/// (`min * 0.5 + max * 0.5`) would round.
pub fn point_boxes(points: &[geom::Vec3]) -> Result<Vec<Aabb>, MergeTreeError> {
    points
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            if !p.is_finite() {
                return Err(MergeTreeError::Points(bvh::PointError::NonFinite {
                    index: i,
                    point: p,
                }));
            }
            let b = Aabb::new(p, p);
            let c = b.min * 0.5 + b.max * 0.5;
            if c.to_array().map(f32::to_bits) != p.to_array().map(f32::to_bits) {
                return Err(MergeTreeError::Input(format!(
                    "point {i} ({p:?}) has a subnormal coordinate, which the unit's centroid \
                     expression rounds"
                )));
            }
            Ok(b)
        })
        .collect()
}

/// Simulates MergeTree building a BVH over the primitive boxes `aabbs` with configuration
/// `cfg` and memory `port`.
pub fn simulate(
    aabbs: &[Aabb],
    cfg: &MergeTreeConfig,
    port: Box<dyn MemoryPort>,
) -> Result<MergeTreeReport, MergeTreeError> {
    simulate_with_progress(aabbs, cfg, port, None)
}

/// [`simulate`] with a callback `(elements done, total)`, called every 65536 elements of
/// work (merge outputs and emitter inputs).
pub fn simulate_with_progress<'a>(
    aabbs: &'a [Aabb],
    cfg: &MergeTreeConfig,
    port: Box<dyn MemoryPort>,
    progress: Option<&'a mut dyn FnMut(u64, u64)>,
) -> Result<MergeTreeReport, MergeTreeError> {
    run_machine(aabbs, cfg, port, progress)
}

/// Checks the input, runs the [`machine`] and assembles its report.
fn run_machine<'a>(
    aabbs: &'a [Aabb],
    cfg: &MergeTreeConfig,
    port: Box<dyn MemoryPort>,
    progress: Option<&'a mut dyn FnMut(u64, u64)>,
) -> Result<MergeTreeReport, MergeTreeError> {
    cfg.validate()?;
    if aabbs.len() >= u32::MAX as usize / 2 {
        return Err(MergeTreeError::Input(format!(
            "{} primitives exceed the 32-bit references",
            aabbs.len()
        )));
    }
    if let Some(i) = aabbs.iter().position(|a| !a.is_finite() || a.is_empty()) {
        return Err(MergeTreeError::Input(format!(
            "primitive {i} has a non-finite or inverted box"
        )));
    }
    let cb = centroid_bounds(aabbs);
    if cfg.output.is_cbvh() {
        cbvh::bottomup::check_stream(1, aabbs.len())?;
    }
    let mut k = machine::run(aabbs, &cb, cfg, port, progress)?;
    let mut collapse = k.collapse.take();
    let wide = k.wide.take();
    let out = KernelCbvh {
        stream: k.stream.take(),
        ids: k.cbvh_ids.take(),
        topdown: k.topdown.take(),
        build_cycles: k.build_cycles,
        cycles: k.cycles,
    };
    let cycles = k.cycles;
    let stalls = k.stalls;
    let partial_cycles: u64 = k
        .phases
        .iter()
        .filter(|p| p.name == "partial_sort" || p.name == "sort_and_emit")
        .map(|p| p.end_cycle - p.start_cycle)
        .sum();
    let (toplevel_sweeps, toplevel_cycles, top_tree) = match &k.top {
        Some(t) => (
            t.sweeps.len() as u64,
            k.phases
                .iter()
                .find(|p| p.name == "toplevel_sah")
                .map_or(0, |p| p.end_cycle - p.start_cycle),
            Some(t.tree.clone()),
        ),
        None => (0, 0, None),
    };
    let highlevel = bvh::Highlevel {
        nodes: std::mem::take(&mut k.nodes),
        roots: std::mem::take(&mut k.roots),
        order: std::mem::take(&mut k.order),
    };
    let cbvh4 = if cfg.output == OutputMode::Cbvh4 {
        Some(kernel_cbvh4_result(
            collapse.take(),
            wide,
            &highlevel,
            cfg,
            k.cycles,
        )?)
    } else {
        None
    };
    let mbvh4 = kernel_mbvh4_result(
        collapse,
        out.topdown.clone(),
        &highlevel,
        cfg,
        [out.build_cycles, out.cycles],
    )?;
    let cbvh = kernel_cbvh_result(out, &highlevel, cfg)?;
    let points = match k.points.take() {
        Some(w) => Some(point_result(w?, aabbs, cfg)?),
        None => match cfg.output {
            OutputMode::KdtreePoints => Some(point_result(
                emitter::PointWriter::Kd(bvh::PointStream::new(&cb, cfg.max_leaf_size)?),
                aabbs,
                cfg,
            )?),
            OutputMode::OctreePoints => Some(point_result(
                emitter::PointWriter::Oct(bvh::OctreeStream::new(cfg.max_leaf_size)?),
                aabbs,
                cfg,
            )?),
            _ => None,
        },
    };
    let mem = k.mem;
    Ok(MergeTreeReport {
        triangles: aabbs.len() as u64,
        config: cfg.clone(),
        dram: k.dram,
        cycles,
        ms: cycles as f64 / (cfg.clock_mhz as f64 * 1e3),
        bytes_read: mem.bytes_read,
        bytes_written: mem.bytes_written,
        bus_utilization: (mem.bytes_read + mem.bytes_written) as f64 / (k.peak * cycles as f64),
        peak_bytes_per_cycle: k.peak,
        partial_sort_blocks: (aabbs.len() as u64).div_ceil(cfg.m_elems()),
        merge_passes: k.passes_total,
        phases: k.phases,
        presort_busy_fraction: if partial_cycles == 0 {
            0.0
        } else {
            stalls.presort_busy_cycles as f64 / (cfg.presorters as f64 * partial_cycles as f64)
        },
        merge_elements_per_cycle: stalls.merge_outputs as f64 / cycles as f64,
        stalls,
        nodes: highlevel.nodes.len() as u64,
        leaf_entries: highlevel.order.len() as u64,
        highlevel_roots: highlevel.roots.len() as u64,
        max_stack_depth: k.max_stack_depth,
        toplevel_sweeps,
        toplevel_cycles,
        fast_forward_cycles: k.run.cycles - k.run.stepped_cycles,
        layout: k.layout,
        memory: mem,
        trace: k.trace,
        highlevel,
        top_tree,
        cbvh,
        mbvh4,
        cbvh4,
        points,
        units: k.run.units,
    })
}

/// The MBVH4 the machine wrote, with its counts, in the MBVH4 output modes: the streaming
/// unit's collapse, or the offline collapse of the built tree (the pass's result).
fn kernel_mbvh4_result(
    collapse: Option<(bvh::StreamCollapse, CollapseUnitStats)>,
    pass: Option<cbvh_unit::TopdownStats>,
    hl: &bvh::Highlevel,
    cfg: &MergeTreeConfig,
    [build_cycles, cycles]: [u64; 2],
) -> Result<Option<Mbvh4RunReport>, MergeTreeError> {
    let build_cycles = if hl.order.is_empty() { 0 } else { build_cycles };
    let (tree, stream, pass) = match cfg.output {
        OutputMode::Mbvh4 => match collapse {
            Some((sc, st)) => (sc.tree(hl.order.clone())?, Some(st), None),
            // An empty scene: the unit did not start.
            None => (
                bvh::stream_collapse_with(hl, cfg.stream_collapse())?.0,
                None,
                None,
            ),
        },
        OutputMode::Mbvh4Collapse => (bvh::collapse(&hl.to_bvh2())?, None, pass),
        _ => return Ok(None),
    };
    Ok(Some(Mbvh4RunReport {
        mode: cfg.output,
        wide_nodes: tree.nodes.len() as u64,
        node_bytes: config::MBVH4_NODE_BYTES,
        binary_nodes: hl.nodes.len() as u64,
        sah: tree.normalized_sah(),
        mean_children: tree.stats().mean_children,
        build_cycles,
        build_ms: build_cycles as f64 / (cfg.clock_mhz as f64 * 1e3),
        collapse_cycles: if cfg.output == OutputMode::Mbvh4Collapse {
            cycles - build_cycles
        } else {
            0
        },
        stream,
        pass,
        tree,
    }))
}

/// The compressed 4-wide tree the machine wrote (`output = cbvh4`), with its counts: the
/// wide encoder's tree over the collapse's leaves.
fn kernel_cbvh4_result(
    collapse: Option<(bvh::StreamCollapse, CollapseUnitStats)>,
    wide: Option<(cbvh::WideStreamEncoder, cbvh_unit::StreamUnitStats)>,
    hl: &bvh::Highlevel,
    cfg: &MergeTreeConfig,
    cycles: u64,
) -> Result<Cbvh4RunReport, MergeTreeError> {
    let (tree, encode, exact, col, stream) = match (collapse, wide) {
        (Some((sc, cst)), Some((enc, est))) => {
            let ids = cbvh::wide::prim_ids_of_nodes(hl.order.clone(), sc.written())?;
            let (tree, encode) = enc.finish(ids)?;
            (
                tree,
                encode,
                sc.tree(hl.order.clone())?,
                Some(cst),
                Some(est),
            )
        }
        // An empty scene: the units did not start.
        _ => {
            let (tree, encode, exact) = software_cbvh4_of(hl, cfg)?;
            (tree, encode, exact, None, None)
        }
    };
    let decoded = tree.decode_to_mbvh4()?;
    let cycles = if hl.order.is_empty() { 0 } else { cycles };
    Ok(Cbvh4RunReport {
        params: cfg.cbvh_params(),
        treelet_depth: cfg.cbvh_treelet_depth,
        mbvh4_window: cfg.mbvh4_window,
        wide_nodes: tree.nodes.len() as u64,
        node_bytes: cbvh::wide::quad_bytes(cfg.cbvh_bits) as u64,
        binary_nodes: hl.nodes.len() as u64,
        backtrack_steps: encode.backtrack_steps,
        backtrack_depth_hist: encode.backtrack_depth_hist.clone(),
        max_held: encode.max_stack as u64,
        sah: exact.normalized_sah(),
        sah_decoded: decoded.normalized_sah(),
        mean_children: exact.stats().mean_children,
        build_cycles: cycles,
        build_ms: cycles as f64 / (cfg.clock_mhz as f64 * 1e3),
        collapse: col,
        stream,
        encode,
        tree,
        exact,
    })
}

/// The software reference of `output = cbvh4` for the emitter's stream `hl`:
/// [`cbvh::compress_stream_collapse`] with `cfg`'s collapse rule and quantization.
fn software_cbvh4_of(
    hl: &bvh::Highlevel,
    cfg: &MergeTreeConfig,
) -> Result<(cbvh::Cbvh4, cbvh::EncodeStats, bvh::Mbvh4), MergeTreeError> {
    let sc = cbvh::bottomup::StreamConfig {
        record_ops: false,
        ..cfg.stream_config(0)
    };
    Ok(cbvh::compress_stream_collapse(
        hl,
        cfg.stream_collapse(),
        &sc,
    )?)
}

/// The compressed 4-wide tree software makes for `cfg` (`output = cbvh4`): the software
/// emitter's stream through [`cbvh::compress_stream_collapse`]; `None` in the other modes.
pub fn software_cbvh4(
    aabbs: &[Aabb],
    cfg: &MergeTreeConfig,
) -> Result<Option<(cbvh::Cbvh4, cbvh::EncodeStats, bvh::Mbvh4)>, MergeTreeError> {
    if cfg.output != OutputMode::Cbvh4 {
        return Ok(None);
    }
    let hl = software_builder(cfg).build_highlevel(aabbs)?;
    Ok(Some(software_cbvh4_of(&hl, cfg)?))
}

/// With `output = cbvh4`, true when the compressed tree the unit wrote equals the software
/// encoder's bit for bit (nodes, root, root context, primitive ids) with the same counts,
/// over the same exact tree; `None` in the other modes.
pub fn cbvh4_matches_software(
    report: &MergeTreeReport,
    aabbs: &[Aabb],
) -> Result<Option<bool>, MergeTreeError> {
    let (Some(ours), Some((tree, stats, exact))) =
        (&report.cbvh4, software_cbvh4(aabbs, &report.config)?)
    else {
        return Ok(None);
    };
    Ok(Some(
        ours.tree == tree && ours.encode == stats && ours.exact == exact,
    ))
}

/// The point tree the writer made, with its counts.
fn point_result(
    w: emitter::PointWriter,
    aabbs: &[Aabb],
    cfg: &MergeTreeConfig,
) -> Result<PointRunReport, MergeTreeError> {
    let emitted = aabbs.len().saturating_sub(1) as u64;
    let r = match w {
        emitter::PointWriter::Kd(w) => {
            let (written, collapsed, stack) = (
                w.written().len() as u64,
                w.collapsed(),
                w.max_stack_depth() as u64,
            );
            let tree = w.finish()?;
            PointRunReport {
                kind: "kdtree",
                points: tree.len() as u64,
                max_leaf: tree.max_leaf(),
                emitted,
                written,
                node_bytes: written * cfg.kd_node_bytes(),
                collapsed,
                tree_nodes: tree.nodes().len() as u64,
                depth: tree.depth() as u64,
                writer_max_stack: stack,
                tree: Some(tree),
                octree: None,
            }
        }
        emitter::PointWriter::Oct(mut w) => {
            w.close_root()?;
            let stack = w.max_stack_depth() as u64;
            let (nodes, children) = (w.written() as u64, w.written_children() as u64);
            let (tree, _) = w.finish()?;
            let s = tree.stats();
            let single = s.single_child as u64;
            PointRunReport {
                kind: "octree",
                points: tree.len() as u64,
                max_leaf: tree.max_leaf(),
                emitted,
                written: nodes,
                node_bytes: nodes * config::OCT_NODE_HEADER_BYTES
                    + children * config::OCT_CHILD_BYTES,
                // Joins that started no node: the emitted joins less the nodes with two or
                // more children (single-child cells come with the node below them).
                collapsed: emitted.saturating_sub(nodes - single),
                tree_nodes: s.nodes as u64,
                depth: s.depth as u64,
                writer_max_stack: stack,
                tree: None,
                octree: Some(tree),
            }
        }
    };
    if r.points != aabbs.len() as u64 {
        return Err(MergeTreeError::Points(bvh::PointError::Stream(format!(
            "{} points in the tree for {} inputs",
            r.points,
            aabbs.len()
        ))));
    }
    Ok(r)
}

/// True when the point tree the unit wrote (`output = kdtree-points`) equals
/// `bvh::PointTree::build` of the points (the boxes' minima) node for node: the same point
/// order, ranges, children, axes, boxes and planes; `None` in the other modes.
pub fn points_match_software(
    report: &MergeTreeReport,
    aabbs: &[Aabb],
) -> Result<Option<bool>, MergeTreeError> {
    let Some(p) = &report.points else {
        return Ok(None);
    };
    let pts: Vec<geom::Vec3> = aabbs.iter().map(|a| a.min).collect();
    let leaf = p.max_leaf as usize;
    Ok(Some(match (&p.tree, &p.octree) {
        (Some(t), _) => bvh::PointTree::build(&pts, leaf)?.same_as(t),
        (_, Some(t)) => {
            let sw = bvh::Octree::build(&pts, leaf)?;
            sw.ids() == t.ids() && sw.nodes() == t.nodes()
        }
        _ => false,
    }))
}

/// What the kernel machine's CBVH units left behind.
struct KernelCbvh {
    stream: Option<(cbvh::bottomup::StreamEncoder, cbvh_unit::StreamUnitStats)>,
    ids: Option<Vec<u32>>,
    topdown: Option<cbvh_unit::TopdownStats>,
    build_cycles: u64,
    cycles: u64,
}

/// The CBVH the kernel machine wrote, with its counts, in the CBVH output modes.
fn kernel_cbvh_result(
    mut k: KernelCbvh,
    hl: &bvh::Highlevel,
    cfg: &MergeTreeConfig,
) -> Result<Option<CbvhRunReport>, MergeTreeError> {
    let pair_bytes = cbvh::format::pair_bytes(cfg.cbvh_bits) as u64;
    let build_cycles = if hl.order.is_empty() {
        0
    } else {
        k.build_cycles
    };
    let (tree, encode, stream, topdown) = match cfg.output {
        OutputMode::Bvh
        | OutputMode::Mbvh4
        | OutputMode::Mbvh4Collapse
        | OutputMode::Cbvh4
        | OutputMode::KdtreePoints
        | OutputMode::OctreePoints => return Ok(None),
        OutputMode::CbvhStream => match k.stream.take() {
            Some((enc, stats)) if !hl.order.is_empty() => {
                let ids = k.ids.take().unwrap_or_default();
                let (tree, encode) = enc.finish(ids)?;
                (tree, encode, Some(stats), None)
            }
            _ => {
                let (tree, encode) = cbvh::compress_hlbvh(hl, &cfg.stream_config(0))?;
                (tree, encode, None, None)
            }
        },
        OutputMode::CbvhTopdown => {
            let (tree, encode) = cbvh::compress_topdown(&hl.to_bvh2(), &cfg.cbvh_params())?;
            (tree, encode, None, k.topdown.take())
        }
    };
    Ok(Some(CbvhRunReport {
        mode: cfg.output,
        params: cfg.cbvh_params(),
        treelet_depth: cfg.cbvh_treelet_depth,
        node_pairs: tree.pairs.len() as u64,
        pair_bytes,
        backtrack_steps: encode.backtrack_steps,
        backtrack_depth_hist: encode.backtrack_depth_hist.clone(),
        build_cycles,
        build_ms: build_cycles as f64 / (cfg.clock_mhz as f64 * 1e3),
        compress_cycles: k.cycles - build_cycles,
        stream,
        topdown,
        encode,
        tree,
    }))
}

/// The software HLBVH builder with the same tree options as `cfg`.
pub fn software_builder(cfg: &MergeTreeConfig) -> HlbvhBuilder {
    HlbvhBuilder {
        bits: if cfg.morton_bits == 30 {
            MortonBits::Bits30
        } else {
            MortonBits::Bits63
        },
        combine_identical: cfg.combine_identical,
        max_leaf_size: cfg.max_leaf_size,
        highlevel_threshold: cfg.highlevel_threshold,
        threads: 0,
        grid: cfg.morton_grid,
        // The unit codes centroids only: no large primitives apart (issue 34's option).
        large_prims: None,
    }
}

/// The tree the software builder makes for `cfg` (HLBVH, or HLBVH+SAH with the toplevel
/// unit).
pub fn software_tree(aabbs: &[Aabb], cfg: &MergeTreeConfig) -> Result<Bvh2, MergeTreeError> {
    let hl = software_builder(cfg);
    if cfg.toplevel_sah {
        return Ok(HlbvhSahBuilder {
            hlbvh: hl,
            bins: cfg.toplevel_bins as usize,
            threads: 0,
        }
        .build(aabbs)?);
    }
    Ok(hl.build(aabbs)?)
}

/// The CBVH software makes for `cfg`'s output mode: `cbvh::compress_hlbvh` of the software
/// emitter's stream (streaming), or `cbvh::compress_topdown` of the software tree
/// (top-down); `None` for the plain output.
pub fn software_cbvh(
    aabbs: &[Aabb],
    cfg: &MergeTreeConfig,
) -> Result<Option<(cbvh::Cbvh, cbvh::EncodeStats)>, MergeTreeError> {
    Ok(match cfg.output {
        OutputMode::Bvh
        | OutputMode::Mbvh4
        | OutputMode::Mbvh4Collapse
        | OutputMode::Cbvh4
        | OutputMode::KdtreePoints
        | OutputMode::OctreePoints => None,
        OutputMode::CbvhStream => {
            let hl = software_builder(cfg).build_highlevel(aabbs)?;
            Some(cbvh::compress_hlbvh(&hl, &cfg.stream_config(0))?)
        }
        OutputMode::CbvhTopdown => Some(cbvh::compress_topdown(
            &software_tree(aabbs, cfg)?,
            &cfg.cbvh_params(),
        )?),
    })
}

/// In the CBVH output modes, true when the CBVH the unit wrote equals the software
/// encoder's bit for bit (node pairs, root, root context, primitive ids) with the same
/// counts; `None` for the plain output.
pub fn cbvh_matches_software(
    report: &MergeTreeReport,
    aabbs: &[Aabb],
) -> Result<Option<bool>, MergeTreeError> {
    let (Some(ours), Some((tree, stats))) = (&report.cbvh, software_cbvh(aabbs, &report.config)?)
    else {
        return Ok(None);
    };
    Ok(Some(ours.tree == tree && ours.encode == stats))
}

/// The MBVH4 software makes for `cfg`'s output mode: [`bvh::stream_collapse_with`] of
/// the software emitter's stream (`mbvh4`, with the rule of `mbvh4_window`), or [`bvh::collapse`] of the software tree
/// (`mbvh4-collapse`); `None` in the other modes.
pub fn software_mbvh4(
    aabbs: &[Aabb],
    cfg: &MergeTreeConfig,
) -> Result<Option<bvh::Mbvh4>, MergeTreeError> {
    Ok(match cfg.output {
        OutputMode::Mbvh4 => {
            let hl = software_builder(cfg).build_highlevel(aabbs)?;
            Some(bvh::stream_collapse_with(&hl, cfg.stream_collapse())?.0)
        }
        OutputMode::Mbvh4Collapse => Some(bvh::collapse(&software_tree(aabbs, cfg)?)?),
        _ => None,
    })
}

/// In the MBVH4 output modes, true when the MBVH4 the unit wrote equals the software
/// collapse's node for node; `None` in the other modes.
pub fn mbvh4_matches_software(
    report: &MergeTreeReport,
    aabbs: &[Aabb],
) -> Result<Option<bool>, MergeTreeError> {
    let (Some(ours), Some(tree)) = (&report.mbvh4, software_mbvh4(aabbs, &report.config)?) else {
        return Ok(None);
    };
    Ok(Some(ours.tree == tree))
}

/// True when the simulated unit's tree equals the software builder's node for node (and,
/// with a threshold, its high-level output equals the software emitter's).
pub fn tree_matches_software(
    report: &MergeTreeReport,
    aabbs: &[Aabb],
) -> Result<bool, MergeTreeError> {
    let cfg = &report.config;
    if cfg.output.is_points() {
        // The point mode's keys tie by run index, not as the HLBVH builder's: its tree is
        // the point k-d tree.
        return Ok(points_match_software(report, aabbs)?.unwrap_or(false));
    }
    if cfg.highlevel_threshold.is_some() {
        let hl = software_builder(cfg).build_highlevel(aabbs)?;
        if hl != report.highlevel {
            return Ok(false);
        }
    }
    Ok(report.tree()? == software_tree(aabbs, cfg)?)
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_cbvh;
#[cfg(test)]
mod tests_cbvh4;
#[cfg(test)]
mod tests_exact;
#[cfg(test)]
mod tests_forecast;
#[cfg(test)]
mod tests_kernel;
#[cfg(test)]
mod tests_mbvh4;
#[cfg(test)]
mod tests_points;
