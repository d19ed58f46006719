//! What a MergeTree run reports: cycles and time, traffic per phase, bus utilization,
//! stall causes, and the per-unit busy fraction over time as CSV and as an SVG plot in the
//! style of \[P2\] Fig. 6 (bus utilization and unit activity against time).

use std::fmt::Write as _;

use serde::Serialize;

use super::cbvh_unit::{StreamUnitStats, TopdownStats};
use super::config::{MergeTreeConfig, OutputMode};
use super::emitter::EmitterStalls;
use super::machine::MemoryLayout;
use super::merge::MergeStalls;
use crate::dram::MemStats;
use crate::fifo::FifoStats;

/// One phase of the run (\[P1\] Fig. 2 states).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PhaseReport {
    /// `partial_sort`, `merge_pass_N`, `merge_pass_N_and_emit` (or `sort_and_emit` when
    /// the scene fits one block), `toplevel_sah`.
    pub name: String,
    /// First cycle.
    pub start_cycle: u64,
    /// Cycle after the last.
    pub end_cycle: u64,
    /// Bytes of the read requests issued in the phase (whole bursts).
    pub bytes_read: u64,
    /// Bytes of the write requests issued in the phase (whole bursts).
    pub bytes_written: u64,
    /// Read requests completed in the phase.
    pub reads: u64,
    /// Their mean latency in unit cycles, from the port accepting a request to its last
    /// burst (queueing in the memory controller included).
    pub read_latency_mean_cycles: f64,
}

/// Busy and stall counters of every unit: sums of the units' activity intervals (see
/// `machine::stall_report` for each field's source). Every figure counts cycles of a unit's
/// state, so none depends on how often the kernel stepped the unit.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StallReport {
    /// Presorter-cycles spent inserting or copying to the scratchpad.
    pub presort_busy_cycles: u64,
    /// Presorter-cycles waiting for input data.
    pub presort_starved_cycles: u64,
    /// Presorter-cycles waiting for the scratchpad (previous block still merging).
    pub presort_wait_scratchpad_cycles: u64,
    /// Multi-merge stalls.
    pub merge: MergeStalls,
    /// Elements output by the multi-merge unit (all modes and passes).
    pub merge_outputs: u64,
    /// Heap operations.
    pub heap_ops: u64,
    /// Hierarchy emitter stalls.
    pub emitter: EmitterStalls,
    /// Emitter steps (stack operations and leaf enlargements).
    pub emitter_steps: u64,
    /// Cycles the input reader had data to fetch but no presorter buffer to put it in.
    pub reader_blocked_cycles: u64,
    /// Cycles the memory arbiter had a request refused by the controller (queue full) and
    /// granted none.
    pub port_refusals: u64,
    /// The FIFOs between units.
    pub fifos: Vec<FifoStats>,
}

/// Activity in one window of the time series.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TraceRow {
    /// First cycle of the window.
    pub cycle_start: u64,
    /// Cycles in the window.
    pub cycles: u64,
    /// Control phase at the end of the window.
    pub phase: String,
    /// Bytes whose requests completed in the window.
    pub bus_bytes: u64,
    /// Presorter-cycles busy.
    pub presort_busy: u64,
    /// Elements output by the multi-merge unit.
    pub merge_outputs: u64,
    /// Emitter steps.
    pub emitter_steps: u64,
    /// Toplevel unit busy cycles.
    pub toplevel_busy: u64,
}

/// The point tree the unit wrote (`output = kdtree-points` or `octree-points`).
#[derive(Clone, Debug, Serialize)]
pub struct PointRunReport {
    /// `kdtree` or `octree`.
    pub kind: &'static str,
    /// Points in the tree.
    pub points: u64,
    /// Largest leaf (`max_leaf_size`).
    pub max_leaf: u32,
    /// Nodes the emitter emitted (points minus one).
    pub emitted: u64,
    /// Inner nodes written (k-d: 64 bytes each; octree: single-child cells included).
    pub written: u64,
    /// Bytes of the written nodes.
    pub node_bytes: u64,
    /// k-d tree: emitted nodes the writer collapsed into leaves (not written); octree:
    /// emitted nodes that wrote no node.
    pub collapsed: u64,
    /// Nodes of the tree, leaves included (as `bvh::PointTree` and `bvh::Octree` count
    /// them).
    pub tree_nodes: u64,
    /// Levels of the tree (the root alone is 1).
    pub depth: u64,
    /// Deepest stack of the point writer.
    pub writer_max_stack: u64,
    /// The k-d tree, in `bvh::PointTree`'s layout.
    #[serde(skip)]
    pub tree: Option<bvh::PointTree>,
    /// The octree, in `bvh::Octree`'s layout.
    #[serde(skip)]
    pub octree: Option<bvh::Octree>,
}

/// The result of [`super::simulate`].
#[derive(Clone, Debug, Serialize)]
pub struct MergeTreeReport {
    /// Primitives in the scene.
    pub triangles: u64,
    /// The configuration that ran.
    pub config: MergeTreeConfig,
    /// The memory backend.
    pub dram: String,
    /// Unit clock cycles of the whole build.
    pub cycles: u64,
    /// Build time at the unit clock, in milliseconds.
    pub ms: f64,
    /// Bytes read from DRAM (whole bursts).
    pub bytes_read: u64,
    /// Bytes written to DRAM (whole bursts).
    pub bytes_written: u64,
    /// (read + written) / (peak bytes per cycle * cycles).
    pub bus_utilization: f64,
    /// Peak bytes per unit cycle of the memory.
    pub peak_bytes_per_cycle: f64,
    /// Partial-sort blocks (sorted runs of M elements): ceil(N / M).
    pub partial_sort_blocks: u64,
    /// Multi-merge passes (0 when the scene fits one block; 1 up to M^2 / (2B)).
    pub merge_passes: u32,
    /// Phases in order.
    pub phases: Vec<PhaseReport>,
    /// Busy and stall counters.
    pub stalls: StallReport,
    /// Mean busy fraction of the presorters over the partial-sort phase.
    pub presort_busy_fraction: f64,
    /// Elements per cycle out of the multi-merge unit over the whole run (at most 0.5).
    pub merge_elements_per_cycle: f64,
    /// Inner nodes emitted (BVH nodes written, toplevel excluded).
    pub nodes: u64,
    /// Leaf-table entries written.
    pub leaf_entries: u64,
    /// High-level roots (cells) output.
    pub highlevel_roots: u64,
    /// Deepest emitter stack.
    pub max_stack_depth: usize,
    /// Sweeps of the toplevel SAH unit (0 when it did not run).
    pub toplevel_sweeps: u64,
    /// Cycles of the toplevel SAH unit.
    pub toplevel_cycles: u64,
    /// Cycles in which the kernel stepped no unit (a simulator statistic; the results are
    /// the same without skipping).
    pub fast_forward_cycles: u64,
    /// DRAM addresses of the regions.
    pub layout: MemoryLayout,
    /// The memory's own statistics.
    pub memory: MemStats,
    /// Activity time series (`trace_window_cycles` per row).
    #[serde(skip)]
    pub trace: Vec<TraceRow>,
    /// The emitter's output (nodes, cell roots, leaf table).
    #[serde(skip)]
    pub highlevel: bvh::Highlevel,
    /// The toplevel unit's tree over the cell roots, when it ran.
    #[serde(skip)]
    pub top_tree: Option<bvh::Bvh2>,
    /// The CBVH output (\[P3\] §5.3), in the CBVH output modes.
    pub cbvh: Option<CbvhRunReport>,
    /// The MBVH4 output (issue 18 part 2), in the MBVH4 output modes.
    pub mbvh4: Option<super::mbvh4_unit::Mbvh4RunReport>,
    /// The compressed 4-wide output (`output = cbvh4`, issue 18 part 2).
    pub cbvh4: Option<super::mbvh4_unit::Cbvh4RunReport>,
    /// The point k-d tree (`output = kdtree-points`, issue 18 part 3).
    pub points: Option<PointRunReport>,
    /// Busy / stalled / idle cycles and counters of every unit (the kernel machine).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub units: Vec<crate::kernel::UnitReport>,
}

/// What the CBVH output of a run did (\[P3\] §5.3).
#[derive(Clone, Debug, Serialize)]
pub struct CbvhRunReport {
    /// `cbvh-stream` or `cbvh-topdown`.
    pub mode: OutputMode,
    /// Quantization parameters.
    pub params: cbvh::Params,
    /// Treelet depth of the streaming encoder (1 = none).
    pub treelet_depth: u32,
    /// Node pairs of the CBVH.
    pub node_pairs: u64,
    /// Bytes of one node pair.
    pub pair_bytes: u64,
    /// Backtracking steps (streaming; 0 for top-down).
    pub backtrack_steps: u64,
    /// Backtracking steps by depth (\[P3\] Fig. 7).
    pub backtrack_depth_hist: Vec<u64>,
    /// Cycles until the build's output was complete in DRAM: for top-down, the
    /// single-precision build before the pass (\[P3\] Table 2's "BVH" column is this
    /// build alone); for streaming, the whole run.
    pub build_cycles: u64,
    /// `build_cycles` in milliseconds.
    pub build_ms: f64,
    /// Cycles of the top-down pass (0 for streaming).
    pub compress_cycles: u64,
    /// Streaming encoder unit counters.
    pub stream: Option<StreamUnitStats>,
    /// Top-down pass counters.
    pub topdown: Option<TopdownStats>,
    /// The encoder's own counts.
    #[serde(skip)]
    pub encode: cbvh::EncodeStats,
    /// The CBVH written.
    #[serde(skip)]
    pub tree: cbvh::Cbvh,
}

impl MergeTreeReport {
    /// The tree the unit built, as a [`bvh::Bvh2`]: the emitted nodes renumbered into
    /// preorder exactly as the software builder does; with the toplevel unit, its top tree
    /// stitched over the cells; with a threshold and no toplevel build, the Morton top.
    pub fn tree(&self) -> Result<bvh::Bvh2, bvh::BuildError> {
        match &self.top_tree {
            Some(top) => bvh::toplevel::stitch(top, &self.highlevel),
            None => Ok(self.highlevel.to_bvh2()),
        }
    }

    /// The time series as CSV: one row per window, fractions of the window's cycles.
    pub fn trace_csv(&self) -> String {
        let mut t = outfile::table::Table::text(&[
            "cycle_start",
            "cycles",
            "phase",
            "bus_utilization",
            "presort_busy",
            "merge_elements_per_cycle",
            "emitter_busy",
            "toplevel_busy",
        ]);
        let p = self.config.presorters.max(1) as f64;
        for r in &self.trace {
            let c = r.cycles.max(1) as f64;
            t.push([
                r.cycle_start.to_string(),
                r.cycles.to_string(),
                r.phase.to_string(),
                format!(
                    "{:.4}",
                    r.bus_bytes as f64 / (self.peak_bytes_per_cycle * c)
                ),
                format!("{:.4}", r.presort_busy as f64 / (p * c)),
                format!("{:.4}", r.merge_outputs as f64 / c),
                format!("{:.4}", r.emitter_steps as f64 / c),
                format!("{:.4}", r.toplevel_busy as f64 / c),
            ]);
        }
        t.csv()
    }

    /// The time series as an SVG line plot (\[P2\] Fig. 6 style): bus utilization,
    /// presorter busy fraction, merge elements per cycle and emitter busy fraction against
    /// time in microseconds, with the phase boundaries marked.
    pub fn trace_svg(&self, title: &str) -> String {
        let (w, h) = (900.0f64, 360.0f64);
        let (left, right, top, bottom) = (60.0, 170.0, 30.0, 45.0);
        let pw = w - left - right;
        let ph = h - top - bottom;
        let total = self.cycles.max(1) as f64;
        let us_per_cycle = 1.0 / self.config.clock_mhz as f64;
        let x = |c: f64| left + pw * c / total;
        let y = |f: f64| top + ph * (1.0 - f.clamp(0.0, 1.0));
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">"#
        );
        let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        let _ = writeln!(
            s,
            r#"<text x="{left}" y="18" font-size="14">{}</text>"#,
            xml_escape(title)
        );
        // Axes and grid.
        for i in 0..=4 {
            let f = i as f64 / 4.0;
            let _ = writeln!(
                s,
                r##"<line x1="{left}" x2="{}" y1="{:.1}" y2="{:.1}" stroke="#ddd"/><text x="{}" y="{:.1}" text-anchor="end">{}%</text>"##,
                left + pw,
                y(f),
                y(f),
                left - 6.0,
                y(f) + 4.0,
                (f * 100.0) as u32
            );
        }
        for i in 0..=5 {
            let c = total * i as f64 / 5.0;
            let _ = writeln!(
                s,
                r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{:.1}</text>"#,
                x(c),
                top + ph + 16.0,
                c * us_per_cycle
            );
        }
        let _ = writeln!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">time (µs)</text>"#,
            left + pw / 2.0,
            h - 8.0
        );
        for p in self.phases.iter().skip(1) {
            let _ = writeln!(
                s,
                r##"<line x1="{0:.1}" x2="{0:.1}" y1="{top}" y2="{1:.1}" stroke="#999" stroke-dasharray="4 3"/>"##,
                x(p.start_cycle as f64),
                top + ph
            );
        }
        let p = self.config.presorters.max(1) as f64;
        let peak = self.peak_bytes_per_cycle;
        type Series<'a> = (&'a str, &'a str, Box<dyn Fn(&TraceRow) -> f64>);
        let series: Vec<Series> = vec![
            (
                "memory bus",
                "#d62728",
                Box::new(move |r: &TraceRow| r.bus_bytes as f64 / (peak * r.cycles as f64)),
            ),
            (
                "presorters",
                "#2ca02c",
                Box::new(move |r: &TraceRow| r.presort_busy as f64 / (p * r.cycles as f64)),
            ),
            (
                "multi-merge",
                "#1f77b4",
                Box::new(|r: &TraceRow| r.merge_outputs as f64 / r.cycles as f64),
            ),
            (
                "emitter",
                "#ff7f0e",
                Box::new(|r: &TraceRow| r.emitter_steps as f64 / r.cycles as f64),
            ),
            (
                "toplevel SAH",
                "#9467bd",
                Box::new(|r: &TraceRow| r.toplevel_busy as f64 / r.cycles as f64),
            ),
        ];
        for (i, (name, color, f)) in series.iter().enumerate() {
            let mut pts = String::new();
            for r in self.trace.iter().filter(|r| r.cycles > 0) {
                let mid = r.cycle_start as f64 + r.cycles as f64 / 2.0;
                let _ = write!(pts, "{:.1},{:.1} ", x(mid), y(f(r)));
            }
            let _ = writeln!(
                s,
                r#"<polyline fill="none" stroke="{color}" stroke-width="1.5" points="{}"/>"#,
                pts.trim_end()
            );
            let ly = top + 14.0 + 18.0 * i as f64;
            let _ = writeln!(
                s,
                r#"<line x1="{0:.1}" x2="{1:.1}" y1="{2:.1}" y2="{2:.1}" stroke="{color}" stroke-width="2"/><text x="{3:.1}" y="{4:.1}">{name}</text>"#,
                w - right + 12.0,
                w - right + 32.0,
                ly,
                w - right + 38.0,
                ly + 4.0
            );
        }
        let _ = writeln!(s, "</svg>");
        s
    }
}

fn xml_escape(t: &str) -> String {
    t.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
