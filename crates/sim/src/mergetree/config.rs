//! Configuration of the MergeTree model: the architecture parameters of \[P1\] §4 and
//! \[P2\] §5-6.2, FIFO capacities, and the HLBVH options that select the tree.
//!
//! Three presets follow the thesis: `p1` (\[P1\] §4: M = 4096, B = 8, a 128 KB scratchpad,
//! 4 presorters), `p2` (\[P2\] §6.2: M = 8192, B = 16, 256 KB, 8 presorters) and `p3`
//! (\[P3\] §5.3: the \[P1\] unit with a 256 KB scratchpad, M = 8192, B = 8), all at 1 GHz.
//!
//! All three quantize centroids on a cube grid (cells of equal size on every axis) and put
//! every run of equal Morton codes into one leaf of any size. The papers state the second
//! (\[P2\] Algorithm 1 lines 4..8 concatenate equal codes with no bound, \[P3\] §5.2 "large
//! leafs") but not the first; the cube grid is what the published figures imply: with it,
//! the model's traffic reproduces \[P2\] Table VI to 0.1% on Bunny, Crytek Sponza and Dragon
//! and \[P3\] Table 2's leaf sizes, where the box grid misses both
//! (`docs/mergetree-vs-thesis.md`). The box grid and a leaf-size limit stay options
//! (`morton_grid = box`, `max_leaf_size = 8`).
//!
//! The output mode ([`OutputMode`]) chooses what becomes of the emitted hierarchy: 64-byte
//! single-precision nodes, a CBVH written by the streaming bottom-up encoder attached to
//! the emitter, or 64-byte nodes followed by a separate top-down compression pass (the
//! four alternatives of \[P3\] §5.3 and Table 2); or 128-byte MBVH4 nodes (\[P4\] §3.1),
//! written by the streaming collapse unit behind the emitter (`mbvh4`) or by a collapse pass
//! after the build (`mbvh4-collapse`, see [`super::mbvh4_unit`]). Every field can be overridden by name with [`MergeTreeConfig::set`], or from a
//! file of `key = value` lines (flat TOML) or a flat JSON object
//! ([`MergeTreeConfig::apply_file`]).

use cbvh::bottomup::{StreamConfig, MAX_TREELET_DEPTH};
use cbvh::{Coords, Params};
use geom::MortonGrid;
use serde::Serialize;

/// Bytes of one sort element in DRAM and in the scratchpad: an AABB (24 B), a primitive
/// reference (4 B) and the 4-byte Morton code, 256 bits (\[P2\] §5.1). In DRAM the code slot
/// is padding (\[P1\] §4.1: codes are omitted when writing out).
pub const ELEM_BYTES: u64 = 32;

/// Bytes of one sort element of the point modes (`point_element = 16`, the default there):
/// the 12-byte point and the 4-byte reference. The Morton code is not stored: the reader
/// computes it from the point as the element streams in, as it does for the 32-byte
/// element (whose code slot is padding in DRAM), and it travels beside the element on
/// chip (heap keys, FIFOs); see [`MergeTreeConfig::elem_bytes`].
pub const POINT_ELEM_BYTES: u64 = 16;

/// Bytes of one BVH node (\[P2\] §4.1: two child AABBs, two references).
pub const NODE_BYTES: u64 = 64;

/// Bytes of one MBVH4 node (\[P4\] §3.1: four child AABBs, four references).
pub const MBVH4_NODE_BYTES: u64 = std::mem::size_of::<bvh::Node4>() as u64;

/// Deepest window of the MBVH4 collapse's windowed rule (`mbvh4_window`): it holds up to
/// `2^(window + 1)` unresolved nodes per open subtree.
pub const MAX_MBVH4_WINDOW: u32 = 8;

/// Bytes of one leaf-table entry (\[P2\] §4.1: a pointer to primitive data).
pub const LEAF_ENTRY_BYTES: u64 = 4;

/// Bytes of one high-level output record: the cell root's AABB and reference.
pub const HIGHLEVEL_BYTES: u64 = 32;

/// Largest leaf of the point k-d tree (`output = kdtree-points`).
pub const MAX_POINT_LEAF: u32 = 1024;

/// What the unit does with the hierarchy it emits (\[P3\] §5.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OutputMode {
    /// 64-byte single-precision nodes (\[P2\] §4.1): the plain builder.
    Bvh,
    /// A CBVH written by the streaming bottom-up encoder (\[P3\] Algorithm 1) that consumes
    /// the emitter's nodes, with its backtracking steps as DRAM reads and writes.
    CbvhStream,
    /// 64-byte nodes, then a separate top-down compression pass that reads them back and
    /// writes the CBVH (the postprocessing baseline of \[P3\] Fig. 2a).
    CbvhTopdown,
    /// 128-byte MBVH4 nodes (\[P4\] §3.1) written by the streaming collapse unit behind the
    /// emitter ([`bvh::StreamCollapse`], issue 18 part 2).
    Mbvh4,
    /// 64-byte nodes, then a collapse pass that reads them back and writes the offline
    /// greedy collapse ([`bvh::collapse`]) as 128-byte MBVH4 nodes: the baseline of
    /// `mbvh4`.
    Mbvh4Collapse,
    /// Compressed 4-wide nodes (issue 18 part 2): the streaming collapse unit of `mbvh4`
    /// and behind it, in the place of its node writes, the streaming CBVH encoder of
    /// `cbvh-stream` carried over to 4-wide nodes ([`cbvh::WideStreamEncoder`]: \[P3\]
    /// Algorithm 1, its backtracking steps as DRAM reads and writes), which writes
    /// `cbvh::wide::QuadNode`s (32 bytes at 6 bits). The collapse rule is `mbvh4_window`'s,
    /// the quantization `cbvh_coords`, `cbvh_bits`, `cbvh_min_scale_exp` and
    /// `cbvh_treelet_depth`.
    Cbvh4,
    /// A k-d tree of points (issue 18, part 3): the primitives are points (degenerate
    /// boxes), and a point writer ([`bvh::PointStream`]) behind the emitter collapses
    /// subtrees of at most `max_leaf_size` points into leaves and writes the other nodes
    /// as 64-byte k-d nodes (two child boxes, two references, the split plane and axis).
    /// The tree equals `bvh::PointTree::build` of the points.
    KdtreePoints,
    /// An octree of points: the emitter's joins go to an octree writer
    /// ([`bvh::OctreeStream`]) that writes a node of k children as
    /// [`OCT_NODE_HEADER_BYTES`] + k [`OCT_CHILD_BYTES`] bytes (a variable number of bytes
    /// per join, queued in front of the node write buffer). The tree equals
    /// `bvh::Octree::build` of the points.
    OctreePoints,
}

/// Header bytes of an octree node (`output = octree-points`): octant mask, depth, child
/// count, point range.
pub const OCT_NODE_HEADER_BYTES: u64 = 16;

/// Bytes per child of an octree node: its box (24 B), its reference (4 B), 4 spare.
pub const OCT_CHILD_BYTES: u64 = 32;

impl OutputMode {
    /// The name `--set output=...` takes.
    pub fn name(self) -> &'static str {
        match self {
            OutputMode::Bvh => "bvh",
            OutputMode::CbvhStream => "cbvh-stream",
            OutputMode::CbvhTopdown => "cbvh-topdown",
            OutputMode::Mbvh4 => "mbvh4",
            OutputMode::Mbvh4Collapse => "mbvh4-collapse",
            OutputMode::Cbvh4 => "cbvh4",
            OutputMode::KdtreePoints => "kdtree-points",
            OutputMode::OctreePoints => "octree-points",
        }
    }

    /// True for the two point modes.
    pub fn is_points(self) -> bool {
        matches!(self, OutputMode::KdtreePoints | OutputMode::OctreePoints)
    }

    /// True for the two CBVH modes.
    pub fn is_cbvh(self) -> bool {
        matches!(self, OutputMode::CbvhStream | OutputMode::CbvhTopdown)
    }

    /// True for the two MBVH4 modes.
    pub fn is_mbvh4(self) -> bool {
        matches!(self, OutputMode::Mbvh4 | OutputMode::Mbvh4Collapse)
    }

    /// True for the modes with the streaming MBVH4 collapse unit behind the emitter
    /// (`mbvh4`, and `cbvh4` with the wide encoder behind it).
    pub fn collapses_stream(self) -> bool {
        matches!(self, OutputMode::Mbvh4 | OutputMode::Cbvh4)
    }
}

/// The k-d node the point writer writes (`output = kdtree-points`, `point_node`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum KdNode {
    /// The \[P2\] §4.1 BVH node with the plane and axis: two child boxes, two references,
    /// 64 bytes ([`NODE_BYTES`]); queries prune by box ([`bvh::PointTree::knn`]).
    Box,
    /// Plane, axis and two references in one 16-byte slot ([`bvh::PlaneNode`]); queries
    /// prune by plane distance ([`bvh::PlaneKdTree`]).
    Plane,
}

/// How the multi-merge unit schedules the reads that refill its scratchpad buffers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReadSchedule {
    /// Double buffering (\[P1\] §4.2, \[P2\] §5.3): two buffers of B per run; a consumed
    /// buffer is refilled from its own run at once. Merge width M / (2B).
    Double,
    /// Forecasting (\[P1\] §4.2, \[P2\] §7; Knuth's forecasting for external merge sort):
    /// one buffer of B per run plus a pool of `forecast_spares` spare buffers; a second
    /// heap keyed by the last key of each run's newest buffer picks the run whose buffer
    /// empties first as the next to fetch into a free buffer. Merge width
    /// M / B - `forecast_spares`.
    Forecast,
}

impl ReadSchedule {
    /// The name `--set read_schedule=...` takes.
    pub fn name(self) -> &'static str {
        match self {
            ReadSchedule::Double => "double",
            ReadSchedule::Forecast => "forecast",
        }
    }
}

/// Errors of configuration.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConfigError {
    /// No preset of that name.
    #[error("unknown MergeTree preset '{0}' (known: p1, p2, p3)")]
    UnknownPreset(String),
    /// No parameter of that name.
    #[error("unknown MergeTree parameter '{key}' (known: {known})")]
    UnknownKey {
        /// The key given.
        key: String,
        /// The keys that exist.
        known: String,
    },
    /// The value does not parse or is out of range for the key.
    #[error("bad value '{value}' for MergeTree parameter '{key}': {why}")]
    BadValue {
        /// The key.
        key: String,
        /// The value given.
        value: String,
        /// What is wrong.
        why: String,
    },
    /// The parameters are inconsistent with each other.
    #[error("inconsistent MergeTree configuration: {0}")]
    Inconsistent(String),
    /// A configuration file could not be read or parsed.
    #[error("MergeTree configuration file {path}: {why}")]
    File {
        /// The file.
        path: String,
        /// What went wrong.
        why: String,
    },
}

/// Every parameter of the model. See the module documentation for the presets.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MergeTreeConfig {
    /// Name of the preset this started from (informational).
    pub preset: String,
    /// Unit clock in MHz (\[P2\] §6.2: 1 GHz).
    pub clock_mhz: u32,
    /// Scratchpad capacity M in elements (\[P2\] §6.2: 8192).
    pub m: u32,
    /// Buffer length B in elements: the DRAM read length of the multi-merge (\[P2\] §6.2: 16).
    pub b: u32,
    /// Number of insertion presorters (\[P2\] §6.2: 8).
    pub presorters: u32,
    /// Read buffers of B elements in front of each presorter (read-ahead depth).
    pub presort_slots: u32,
    /// Elements in the FIFO from the multi-merge unit to the hierarchy emitter.
    pub emit_fifo: u32,
    /// Elements in the FIFO from the multi-merge unit to the run writer (>= B).
    pub run_write_fifo: u32,
    /// Bytes of the node write buffer of the hierarchy emitter (>= write_chunk_bytes).
    pub node_buffer_bytes: u32,
    /// Bytes of the leaf-table write buffer (>= write_chunk_bytes).
    pub leaf_buffer_bytes: u32,
    /// Size of one node, leaf-table or high-level write request in bytes.
    pub write_chunk_bytes: u32,
    /// Morton code length: 30 or 63 bits.
    pub morton_bits: u32,
    /// Grid of the Morton codes over the centroid bounds: `cube` (cubic cells, the presets'
    /// choice; see `docs/mergetree-vs-thesis.md`) or `box` (cells stretched to the box, as
    /// the software HLBVH builder does by default).
    pub morton_grid: MortonGrid,
    /// Identical Morton codes share a leaf (\[P2\] §5.4) rather than being split (\[P1\]).
    pub combine_identical: bool,
    /// Largest leaf when combining identical codes (the presets: no limit, `u32::MAX`).
    pub max_leaf_size: u32,
    /// Code-bit level above which subtrees go to the high-level output (\[P2\] Alg. 1
    /// lines 15..19); `None` emits one tree.
    pub highlevel_threshold: Option<u32>,
    /// Run the toplevel binned SAH unit over the high-level output (\[P2\] §6.1); needs a
    /// threshold.
    pub toplevel_sah: bool,
    /// Bins per axis of the toplevel binned SAH build.
    pub toplevel_bins: u32,
    /// Cycles of SAH evaluation at the end of each toplevel sweep (\[P2\] §6.1: 32).
    pub sah_cycles_per_sweep: u32,
    /// Cycles per row of the busy-fraction time series.
    pub trace_window_cycles: u64,
    /// Let the simulation kernel skip cycles in which no unit is due (exact; off: every unit
    /// steps in every cycle, the kernel's reference mode, only to test that).
    pub fast_forward: bool,
    /// What the emitted hierarchy becomes (\[P3\] §5.3).
    pub output: OutputMode,
    /// CBVH coordinates (\[P3\] §3, §4.2).
    pub cbvh_coords: Coords,
    /// Treelet depth of the streaming encoder (\[P3\] §4.3; 1 = none).
    pub cbvh_treelet_depth: u32,
    /// Bits per CBVH coordinate (\[P3\] §5: 6).
    pub cbvh_bits: u32,
    /// Minimum scale exponent of the CBVH grids (\[P3\] §4.4, §5.1: -30).
    pub cbvh_min_scale_exp: i32,
    /// Nodes in the FIFO from the hierarchy emitter to the unit behind it: the streaming
    /// CBVH encoder (`cbvh-stream`) or the streaming MBVH4 collapse (`mbvh4`).
    pub cbvh_fifo: u32,
    /// A backtracking read of a line that still has bytes in the node-pair write buffer
    /// first writes them out (coherent, the default); `false` is a timing what-if that reads
    /// DRAM at once (see `cbvh_unit`).
    pub cbvh_flush_before_backtrack: bool,
    /// With `output = mbvh4`: `None` for the streaming collapse's greedy rule, or the
    /// binary levels below the newest node that the windowed rule keeps unresolved
    /// ([`bvh::StreamCollapse::with_window`]; at most [`MAX_MBVH4_WINDOW`]).
    pub mbvh4_window: Option<u32>,
    /// Bytes of unused space after every M-element run in the run regions (a layout
    /// what-if; the presets: 0, runs back to back). With runs a power-of-two span apart,
    /// refills of runs at equal offsets go to one DRAM bank (`docs/mergetree-vs-thesis.md`,
    /// "Fast system: what the gap is made of"); a gap shifts each run's banks.
    pub run_gap_bytes: u32,
    /// Read scheduling of the multi-merge passes: `double` (the papers' double buffering,
    /// the presets) or `forecast` (the what-if of \[P2\] §7). The partial sorts are the
    /// same in both.
    pub read_schedule: ReadSchedule,
    /// Spare scratchpad buffers of B elements with `read_schedule = forecast` (the reads
    /// ahead that hide the memory latency); ignored with `double`.
    pub forecast_spares: u32,
    /// Bytes of the sort element in the point modes: 16 ([`POINT_ELEM_BYTES`], a point and
    /// a reference) or 32 (the \[P2\] §5.1 element, the earlier model and the baseline).
    /// The scratchpad (`m` x 32 bytes) and its buffers (`b` x 32 bytes) keep their bytes,
    /// so they hold 32 / `point_element` times as many elements. Ignored by the other
    /// modes, which sort boxes.
    pub point_element: u32,
    /// The k-d node of `output = kdtree-points`: `box` (64 bytes with the child boxes, the
    /// default) or `plane` (16 bytes, plane-only).
    pub point_node: KdNode,
}

/// Names of the parameters [`MergeTreeConfig::set`] accepts.
pub const KEYS: &[&str] = &[
    "clock_mhz",
    "m",
    "b",
    "presorters",
    "presort_slots",
    "emit_fifo",
    "run_write_fifo",
    "node_buffer_bytes",
    "leaf_buffer_bytes",
    "write_chunk_bytes",
    "morton_bits",
    "morton_grid",
    "combine_identical",
    "max_leaf_size",
    "highlevel_threshold",
    "toplevel_sah",
    "toplevel_bins",
    "sah_cycles_per_sweep",
    "trace_window_cycles",
    "fast_forward",
    "output",
    "cbvh_coords",
    "cbvh_treelet_depth",
    "cbvh_bits",
    "cbvh_min_scale_exp",
    "cbvh_fifo",
    "cbvh_flush_before_backtrack",
    "mbvh4_window",
    "run_gap_bytes",
    "read_schedule",
    "forecast_spares",
    "point_element",
    "point_node",
];

impl MergeTreeConfig {
    /// \[P1\] §4: M = 4096, B = 8 (128 KB scratchpad), 4 presorters, 1 GHz.
    pub fn p1() -> Self {
        Self {
            preset: "p1".into(),
            m: 4096,
            b: 8,
            presorters: 4,
            presort_slots: 4,
            run_write_fifo: 32,
            ..Self::p2()
        }
    }

    /// \[P2\] §6.2: M = 8192, B = 16 (256 KB scratchpad), 8 presorters, 1 GHz.
    pub fn p2() -> Self {
        Self {
            preset: "p2".into(),
            clock_mhz: 1000,
            m: 8192,
            b: 16,
            presorters: 8,
            presort_slots: 4,
            emit_fifo: 64,
            run_write_fifo: 64,
            node_buffer_bytes: 2048,
            leaf_buffer_bytes: 1024,
            write_chunk_bytes: 512,
            morton_bits: 30,
            morton_grid: MortonGrid::Cube,
            combine_identical: true,
            max_leaf_size: u32::MAX,
            highlevel_threshold: None,
            toplevel_sah: false,
            toplevel_bins: 16,
            sah_cycles_per_sweep: 32,
            trace_window_cycles: 10_000,
            fast_forward: true,
            output: OutputMode::Bvh,
            cbvh_coords: Coords::Relative,
            cbvh_treelet_depth: 1,
            cbvh_bits: cbvh::grid::DEFAULT_BITS,
            cbvh_min_scale_exp: cbvh::grid::DEFAULT_MIN_SCALE_EXP,
            cbvh_fifo: 16,
            cbvh_flush_before_backtrack: true,
            mbvh4_window: None,
            run_gap_bytes: 0,
            read_schedule: ReadSchedule::Double,
            forecast_spares: 16,
            point_element: POINT_ELEM_BYTES as u32,
            point_node: KdNode::Box,
        }
    }

    /// \[P3\] §5.3: "a 256KB scratchpad memory and a buffer size of 8 AABBs, such that it can
    /// handle scenes of up to 4M triangles" (M = 8192, B = 8: M^2 / (2B) = 4M), on the
    /// \[P1\] unit (\[VKJ*15\], 4 presorters) "modified to output large leafs when multiple
    /// primitives share the same Morton code" (\[P3\] §5.2: no leaf-size limit), 1 GHz.
    pub fn p3() -> Self {
        Self {
            preset: "p3".into(),
            m: 8192,
            ..Self::p1()
        }
    }

    /// The preset called `name` (`p1`, `p2` or `p3`).
    pub fn preset(name: &str) -> Result<Self, ConfigError> {
        match name {
            "p1" => Ok(Self::p1()),
            "p2" => Ok(Self::p2()),
            "p3" => Ok(Self::p3()),
            _ => Err(ConfigError::UnknownPreset(name.to_string())),
        }
    }

    /// Bytes of one sort element in DRAM and in the scratchpad: [`ELEM_BYTES`] (32, the
    /// \[P2\] §5.1 element), or `point_element` in the point modes.
    pub fn elem_bytes(&self) -> u64 {
        if self.output.is_points() {
            self.point_element as u64
        } else {
            ELEM_BYTES
        }
    }

    /// Bytes of one written k-d node (`output = kdtree-points`): [`NODE_BYTES`] for
    /// `point_node = box`, [`bvh::PLANE_NODE_BYTES`] for `plane`.
    pub fn kd_node_bytes(&self) -> u64 {
        match self.point_node {
            KdNode::Box => NODE_BYTES,
            KdNode::Plane => bvh::PLANE_NODE_BYTES as u64,
        }
    }

    /// Sort elements per 32-byte slot of the scratchpad: 1, or 2 with 16-byte elements.
    fn per_slot(&self) -> u64 {
        ELEM_BYTES / self.elem_bytes()
    }

    /// Elements the scratchpad holds, the run length of the partial sorts: M x 32 bytes
    /// over the element size (M for 32-byte elements).
    pub fn m_elems(&self) -> u64 {
        self.m as u64 * self.per_slot()
    }

    /// Elements one scratchpad buffer (a DRAM read of B x 32 bytes) holds.
    pub fn b_elems(&self) -> u64 {
        self.b as u64 * self.per_slot()
    }

    /// Merge width of one multi-merge pass: M / (2B) double-buffered queues, or with
    /// forecasting one buffer per run after the spares, M / B - `forecast_spares` (the
    /// same for any element size: the buffers keep their bytes).
    pub fn fan_in(&self) -> u64 {
        match self.read_schedule {
            ReadSchedule::Double => self.m as u64 / (2 * self.b as u64),
            ReadSchedule::Forecast => self.buffers().saturating_sub(self.forecast_spares as u64),
        }
    }

    /// Buffers of B elements in the scratchpad: M / B.
    pub fn buffers(&self) -> u64 {
        self.m as u64 / self.b as u64
    }

    /// Largest scene sorted with one multi-merge pass: M x fan-in, M^2 / (2B) with double
    /// buffering (\[P1\] §6), in elements ([`MergeTreeConfig::m_elems`]).
    pub fn single_pass_limit(&self) -> u64 {
        self.m_elems() * self.fan_in()
    }

    /// Clock period in femtoseconds.
    pub fn period_fs(&self) -> u64 {
        1_000_000_000 / self.clock_mhz as u64
    }

    /// Sets parameter `key` from its text `value`.
    pub fn set(&mut self, key: &str, value: &str) -> Result<(), ConfigError> {
        let value = value.trim().trim_matches('"');
        let bad = |why: &str| ConfigError::BadValue {
            key: key.to_string(),
            value: value.to_string(),
            why: why.to_string(),
        };
        let num = |min: u64| -> Result<u64, ConfigError> {
            let v: u64 = value
                .replace('_', "")
                .parse()
                .map_err(|_| bad("expected a non-negative integer"))?;
            if v < min {
                return Err(bad(&format!("must be at least {min}")));
            }
            Ok(v)
        };
        let num32 = |min: u64| -> Result<u32, ConfigError> {
            u32::try_from(num(min)?).map_err(|_| bad("too large"))
        };
        let boolean = || match value {
            "true" | "1" | "yes" | "on" => Ok(true),
            "false" | "0" | "no" | "off" => Ok(false),
            _ => Err(bad("expected true or false")),
        };
        match key {
            "clock_mhz" => self.clock_mhz = num32(1)?,
            "m" => self.m = num32(2)?,
            "b" => self.b = num32(1)?,
            "presorters" => self.presorters = num32(1)?,
            "presort_slots" => self.presort_slots = num32(2)?,
            "emit_fifo" => self.emit_fifo = num32(1)?,
            "run_write_fifo" => self.run_write_fifo = num32(1)?,
            "node_buffer_bytes" => self.node_buffer_bytes = num32(64)?,
            "leaf_buffer_bytes" => self.leaf_buffer_bytes = num32(4)?,
            "write_chunk_bytes" => self.write_chunk_bytes = num32(64)?,
            "morton_bits" => {
                self.morton_bits = match num(0)? {
                    30 => 30,
                    63 => 63,
                    _ => return Err(bad("must be 30 or 63")),
                }
            }
            "morton_grid" => {
                self.morton_grid = match value {
                    "box" => MortonGrid::Box,
                    "cube" => MortonGrid::Cube,
                    _ => return Err(bad("expected box or cube")),
                }
            }
            "combine_identical" => self.combine_identical = boolean()?,
            "max_leaf_size" => self.max_leaf_size = num32(1)?,
            "highlevel_threshold" => {
                self.highlevel_threshold = if value == "none" {
                    None
                } else {
                    Some(num32(0)?)
                }
            }
            "toplevel_sah" => self.toplevel_sah = boolean()?,
            "toplevel_bins" => self.toplevel_bins = num32(2)?,
            "sah_cycles_per_sweep" => self.sah_cycles_per_sweep = num32(0)?,
            "trace_window_cycles" => self.trace_window_cycles = num(1)?,
            "fast_forward" => self.fast_forward = boolean()?,
            "output" => {
                self.output = match value {
                    "bvh" => OutputMode::Bvh,
                    "cbvh-stream" => OutputMode::CbvhStream,
                    "cbvh-topdown" => OutputMode::CbvhTopdown,
                    "mbvh4" => OutputMode::Mbvh4,
                    "mbvh4-collapse" => OutputMode::Mbvh4Collapse,
                    "cbvh4" => OutputMode::Cbvh4,
                    "kdtree-points" => OutputMode::KdtreePoints,
                    "octree-points" => OutputMode::OctreePoints,
                    _ => return Err(bad(
                        "expected bvh, cbvh-stream, cbvh-topdown, mbvh4, mbvh4-collapse, cbvh4, \
                             kdtree-points or octree-points",
                    )),
                }
            }
            "cbvh_coords" => {
                self.cbvh_coords = match value {
                    "relative" => Coords::Relative,
                    "modulo" => Coords::Modulo,
                    "plane-sharing" => Coords::PlaneSharing,
                    _ => return Err(bad("expected relative, modulo or plane-sharing")),
                }
            }
            "cbvh_treelet_depth" => self.cbvh_treelet_depth = num32(1)?,
            "cbvh_bits" => self.cbvh_bits = num32(1)?,
            "cbvh_min_scale_exp" => {
                self.cbvh_min_scale_exp = value.parse().map_err(|_| bad("expected an integer"))?
            }
            "cbvh_fifo" => self.cbvh_fifo = num32(1)?,
            "cbvh_flush_before_backtrack" => self.cbvh_flush_before_backtrack = boolean()?,
            "mbvh4_window" => {
                self.mbvh4_window = if value == "none" {
                    None
                } else {
                    Some(num32(0)?)
                }
            }
            "run_gap_bytes" => self.run_gap_bytes = num32(0)?,
            "read_schedule" => {
                self.read_schedule = match value {
                    "double" => ReadSchedule::Double,
                    "forecast" => ReadSchedule::Forecast,
                    _ => return Err(bad("expected double or forecast")),
                }
            }
            "forecast_spares" => self.forecast_spares = num32(1)?,
            "point_element" => {
                self.point_element = match num(0)? {
                    16 => 16,
                    32 => 32,
                    _ => return Err(bad("must be 16 or 32")),
                }
            }
            "point_node" => {
                self.point_node = match value {
                    "box" => KdNode::Box,
                    "plane" => KdNode::Plane,
                    _ => return Err(bad("expected box or plane")),
                }
            }
            _ => {
                return Err(ConfigError::UnknownKey {
                    key: key.to_string(),
                    known: KEYS.join(", "),
                })
            }
        }
        Ok(())
    }

    /// Applies a `KEY=VALUE` override (the `--set` syntax).
    pub fn set_pair(&mut self, pair: &str) -> Result<(), ConfigError> {
        let Some((k, v)) = pair.split_once('=') else {
            return Err(ConfigError::BadValue {
                key: pair.to_string(),
                value: String::new(),
                why: "expected KEY=VALUE".into(),
            });
        };
        self.set(k.trim(), v)
    }

    /// Applies the overrides in the text of a configuration file: a flat JSON object
    /// (`{"m": 4096, "b": 8}`) or `key = value` lines (flat TOML; `#` starts a comment).
    /// A `preset` key, if present, must come first and resets every field.
    pub fn apply_text(&mut self, text: &str, path: &str) -> Result<(), ConfigError> {
        let file_err = |why: String| ConfigError::File {
            path: path.to_string(),
            why,
        };
        let mut pairs: Vec<(String, String)> = Vec::new();
        if text.trim_start().starts_with('{') {
            let v: serde_json::Value =
                serde_json::from_str(text).map_err(|e| file_err(e.to_string()))?;
            let obj = v
                .as_object()
                .ok_or_else(|| file_err("expected a JSON object".into()))?;
            for (k, v) in obj {
                let s = match v {
                    serde_json::Value::String(s) => s.clone(),
                    serde_json::Value::Null => "none".into(),
                    other => other.to_string(),
                };
                pairs.push((k.clone(), s));
            }
        } else {
            for (n, line) in text.lines().enumerate() {
                let line = line.split('#').next().unwrap_or("").trim();
                if line.is_empty() {
                    continue;
                }
                let (k, v) = line
                    .split_once('=')
                    .ok_or_else(|| file_err(format!("line {}: expected key = value", n + 1)))?;
                pairs.push((k.trim().to_string(), v.trim().to_string()));
            }
        }
        for (k, v) in pairs {
            if k == "preset" {
                *self = Self::preset(v.trim_matches('"'))?;
            } else {
                self.set(&k, &v)?;
            }
        }
        Ok(())
    }

    /// Reads `path` and applies it with [`MergeTreeConfig::apply_text`].
    pub fn apply_file(&mut self, path: &std::path::Path) -> Result<(), ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::File {
            path: path.display().to_string(),
            why: e.to_string(),
        })?;
        self.apply_text(&text, &path.display().to_string())
    }

    /// Checks that the parameters fit together and stay within what the model can
    /// allocate (the limits are far above any real design).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let err = |s: String| Err(ConfigError::Inconsistent(s));
        let limits: [(&str, u64, u64); 9] = [
            ("clock_mhz", self.clock_mhz as u64, 100_000),
            ("m", self.m as u64, 1 << 24),
            ("presorters", self.presorters as u64, 4096),
            ("presort_slots", self.presort_slots as u64, 1024),
            ("emit_fifo", self.emit_fifo as u64, 1 << 20),
            ("run_write_fifo", self.run_write_fifo as u64, 1 << 20),
            ("node_buffer_bytes", self.node_buffer_bytes as u64, 1 << 30),
            ("leaf_buffer_bytes", self.leaf_buffer_bytes as u64, 1 << 30),
            ("write_chunk_bytes", self.write_chunk_bytes as u64, 1 << 20),
        ];
        for (name, value, max) in limits {
            if value > max {
                return err(format!(
                    "{name} ({value}) exceeds the model's limit of {max}"
                ));
            }
        }
        let ring = self.presorters as u64 * self.presort_slots as u64 * self.b_elems();
        if ring > 1 << 24 {
            return err(format!(
                "presorters x presort_slots x B ({ring}) exceeds the model's limit of {}",
                1 << 24
            ));
        }
        let double_fan = self.m as u64 / (2 * self.b as u64);
        if !(self.m as u64).is_multiple_of(2 * self.b as u64) || double_fan < 2 {
            return err(format!(
                "M ({}) must be a multiple of 2B ({}) with at least two queues",
                self.m,
                2 * self.b
            ));
        }
        if self.read_schedule == ReadSchedule::Forecast
            && !(1..=double_fan).contains(&(self.forecast_spares as u64))
        {
            // At most M / (2B) spares: the forecast merge is at least as wide as the
            // double-buffered one (and the partial sorts' M / (2B) queues fit its heap).
            return err(format!(
                "forecast_spares ({}) must be 1..=M/(2B) ({double_fan})",
                self.forecast_spares
            ));
        }
        if (self.run_write_fifo as u64) < self.b_elems() {
            return err(format!(
                "run_write_fifo ({}) must hold at least a buffer's {} elements",
                self.run_write_fifo,
                self.b_elems()
            ));
        }
        if self.node_buffer_bytes < self.write_chunk_bytes
            || self.leaf_buffer_bytes < self.write_chunk_bytes
        {
            return err("node and leaf buffers must hold at least one write chunk".into());
        }
        if self.toplevel_sah && self.highlevel_threshold.is_none() {
            return err("toplevel_sah needs a highlevel_threshold".into());
        }
        if (self.output.is_cbvh() || self.output.is_mbvh4() || self.output == OutputMode::Cbvh4)
            && (self.highlevel_threshold.is_some() || self.toplevel_sah)
        {
            return err(format!(
                "output = {} builds one LBVH: it needs highlevel_threshold = none and \
                 toplevel_sah = false",
                self.output.name()
            ));
        }
        if let Some(w) = self.mbvh4_window {
            if w > MAX_MBVH4_WINDOW {
                return err(format!(
                    "mbvh4_window ({w}) must be none or 0..={MAX_MBVH4_WINDOW}"
                ));
            }
        }
        if (self.output.is_cbvh() || self.output.collapses_stream())
            && self.cbvh_fifo as u64 > 1 << 20
        {
            return err(format!(
                "cbvh_fifo ({}) exceeds the model's limit of {}",
                self.cbvh_fifo,
                1 << 20
            ));
        }
        if self.output.is_cbvh() || self.output == OutputMode::Cbvh4 {
            self.cbvh_params()
                .check()
                .map_err(|e| ConfigError::Inconsistent(e.to_string()))?;
            if !(1..=MAX_TREELET_DEPTH).contains(&self.cbvh_treelet_depth) {
                return err(format!(
                    "cbvh_treelet_depth ({}) must be 1..={MAX_TREELET_DEPTH}",
                    self.cbvh_treelet_depth
                ));
            }
            if self.output == OutputMode::CbvhTopdown && self.cbvh_treelet_depth != 1 {
                return err("treelets apply to output = cbvh-stream only".into());
            }
        }
        if self.output.is_points() {
            let name = self.output.name();
            if self.highlevel_threshold.is_some() || self.toplevel_sah {
                return err(format!(
                    "output = {name} builds one tree: it needs highlevel_threshold = none and \
                     toplevel_sah = false"
                ));
            }
            if self.morton_bits != 63 || self.morton_grid != MortonGrid::Box {
                return err(format!(
                    "output = {name} needs morton_bits = 63 and morton_grid = box (the grid \
                     of the software point trees, bvh::PointTree and bvh::Octree)"
                ));
            }
            if !(1..=MAX_POINT_LEAF).contains(&self.max_leaf_size) {
                return err(format!(
                    "output = {name} takes its leaf size from max_leaf_size ({}), which must \
                     be 1..={MAX_POINT_LEAF} (8 is usual)",
                    self.max_leaf_size
                ));
            }
        }
        if self.point_node == KdNode::Plane && self.output != OutputMode::KdtreePoints {
            return err("point_node = plane applies to output = kdtree-points".into());
        }
        if let Some(t) = self.highlevel_threshold {
            if t > self.morton_bits {
                return err(format!(
                    "highlevel_threshold ({t}) exceeds morton_bits ({})",
                    self.morton_bits
                ));
            }
        }
        Ok(())
    }
}

impl MergeTreeConfig {
    /// The streaming MBVH4 collapse of `output = mbvh4`: the greedy rule, or the windowed
    /// rule with `mbvh4_window` levels.
    pub fn stream_collapse(&self) -> bvh::StreamCollapse {
        match self.mbvh4_window {
            None => bvh::StreamCollapse::new(),
            Some(w) => bvh::StreamCollapse::with_window(w),
        }
    }

    /// The CBVH quantization parameters of the CBVH output modes.
    pub fn cbvh_params(&self) -> Params {
        Params {
            bits: self.cbvh_bits,
            min_scale_exp: self.cbvh_min_scale_exp,
            coords: self.cbvh_coords,
        }
    }

    /// The streaming encoder's configuration (`base_addr_bytes` is the CBVH region's
    /// address; accesses are recorded for the cycle model).
    pub fn stream_config(&self, base_addr_bytes: u64) -> StreamConfig {
        StreamConfig {
            params: self.cbvh_params(),
            treelet_depth: self.cbvh_treelet_depth,
            record_ops: true,
            base_addr_bytes,
        }
    }
}

impl Default for MergeTreeConfig {
    fn default() -> Self {
        Self::p2()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_match_the_thesis() {
        let p1 = MergeTreeConfig::p1();
        assert_eq!((p1.m, p1.b, p1.presorters), (4096, 8, 4));
        assert_eq!(p1.m as u64 * ELEM_BYTES, 128 * 1024);
        assert_eq!(p1.single_pass_limit(), 1 << 20); // [P1] §6: 1M
        let p2 = MergeTreeConfig::p2();
        assert_eq!((p2.m, p2.b, p2.presorters), (8192, 16, 8));
        assert_eq!(p2.m as u64 * ELEM_BYTES, 256 * 1024);
        assert_eq!(p2.fan_in(), 256); // [P2] §6.2: 256-way merge
        assert_eq!(p2.single_pass_limit(), 2 << 20); // 2M triangles
        p1.validate().unwrap();
        p2.validate().unwrap();
        // [P3] §5.3: 256 KB, buffers of 8 AABBs, "scenes of up to 4M triangles".
        let p3 = MergeTreeConfig::p3();
        assert_eq!((p3.m, p3.b, p3.presorters), (8192, 8, 4));
        assert_eq!(p3.m as u64 * ELEM_BYTES, 256 * 1024);
        assert_eq!(p3.single_pass_limit(), 4 << 20);
        p3.validate().unwrap();
        // Every preset: cube grid, equal codes in one leaf of any size (module docs).
        for p in [&p1, &p2, &p3] {
            assert_eq!(p.morton_grid, MortonGrid::Cube, "{}", p.preset);
            assert!(
                p.combine_identical && p.max_leaf_size == u32::MAX,
                "{}",
                p.preset
            );
        }
    }

    #[test]
    fn cbvh_output_keys() {
        let mut c = MergeTreeConfig::p3();
        c.set("output", "cbvh-stream").unwrap();
        c.set("cbvh_coords", "modulo").unwrap();
        c.set("cbvh_treelet_depth", "4").unwrap();
        c.set("cbvh_min_scale_exp", "-126").unwrap();
        c.validate().unwrap();
        assert_eq!(c.output, OutputMode::CbvhStream);
        let s = c.stream_config(4096);
        assert_eq!((s.treelet_depth, s.base_addr_bytes), (4, 4096));
        assert_eq!(s.params.coords, Coords::Modulo);
        assert_eq!(s.params.min_scale_exp, -126);
        assert!(c.set("output", "cbvh").is_err());
        assert!(c.set("cbvh_coords", "absolute").is_err());
        let mut ps = c.clone();
        ps.set("cbvh_coords", "plane-sharing").unwrap();
        assert_eq!(ps.stream_config(0).params.coords, Coords::PlaneSharing);
        assert!(c.set("cbvh_min_scale_exp", "x").is_err());
        let mut t = c.clone();
        t.set("output", "cbvh-topdown").unwrap();
        assert!(t.validate().is_err(), "treelets with top-down");
        t.set("cbvh_treelet_depth", "1").unwrap();
        t.validate().unwrap();
        let mut bits = c.clone();
        bits.set("cbvh_bits", "9").unwrap();
        assert!(bits.validate().is_err());
        let mut deep = c.clone();
        deep.set("cbvh_treelet_depth", "9").unwrap();
        assert!(deep.validate().is_err());
        let mut hl = c.clone();
        hl.set("highlevel_threshold", "18").unwrap();
        assert!(hl.validate().unwrap_err().to_string().contains("none"));
        // The plain output ignores the CBVH keys.
        hl.set("output", "bvh").unwrap();
        hl.validate().unwrap();
    }

    #[test]
    fn set_parses_and_rejects() {
        let mut c = MergeTreeConfig::p2();
        c.set("m", "1024").unwrap();
        c.set_pair("b=4").unwrap();
        c.set("highlevel_threshold", "18").unwrap();
        c.set("combine_identical", "false").unwrap();
        assert_eq!((c.m, c.b, c.highlevel_threshold), (1024, 4, Some(18)));
        assert!(!c.combine_identical);
        c.set("highlevel_threshold", "none").unwrap();
        assert_eq!(c.highlevel_threshold, None);
        assert!(matches!(
            c.set("bogus", "1"),
            Err(ConfigError::UnknownKey { .. })
        ));
        assert!(matches!(c.set("m", "x"), Err(ConfigError::BadValue { .. })));
        assert!(matches!(c.set("b", "0"), Err(ConfigError::BadValue { .. })));
        assert!(matches!(
            c.set("morton_bits", "32"),
            Err(ConfigError::BadValue { .. })
        ));
        assert_eq!(c.morton_grid, MortonGrid::Cube);
        c.set("morton_grid", "box").unwrap();
        assert_eq!(c.morton_grid, MortonGrid::Box);
        c.set("morton_grid", "cube").unwrap();
        assert_eq!(c.morton_grid, MortonGrid::Cube);
        let e = c.set("morton_grid", "sphere").unwrap_err();
        assert!(e.to_string().contains("box or cube"), "{e}");
        assert!(c.set_pair("m").is_err());
        c.set("m", "1002").unwrap();
        assert!(c.validate().is_err());
        let mut big = MergeTreeConfig::p2();
        big.set("clock_mhz", "4000000000").unwrap();
        assert!(big
            .validate()
            .unwrap_err()
            .to_string()
            .contains("clock_mhz"));
        let mut big = MergeTreeConfig::p2();
        big.set("m", "4294967296").unwrap_err();
        big.set("m", "2147483648").unwrap();
        assert!(big.validate().is_err());
    }

    #[test]
    fn files_in_toml_and_json() {
        let mut c = MergeTreeConfig::p2();
        c.apply_text("preset = \"p1\"\n# comment\nm = 2048 # inline\n", "x.toml")
            .unwrap();
        assert_eq!((c.preset.as_str(), c.m, c.b), ("p1", 2048, 8));
        c.apply_text(r#"{"b": 4, "highlevel_threshold": null}"#, "x.json")
            .unwrap();
        assert_eq!((c.m, c.b), (2048, 4));
        assert!(c.apply_text("m 5", "bad.toml").is_err());
        assert!(c.apply_text("{", "bad.json").is_err());
        assert!(c.apply_text("zz = 1", "bad.toml").is_err());
    }
}
