//! Configuration of the ray-tracing accelerator model: the [P4] §3 defaults and the
//! `--set KEY=VALUE` keys that change them.

use serde::Serialize;

/// The tree the accelerator traverses ([P4] §3.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TreeKind {
    /// Binary BVH, 64-byte nodes, from the binned SAH builder (the baseline).
    Bvh2,
    /// 4-wide MBVH, 128-byte nodes, from Wald's top-down builder (the proposal).
    Mbvh4,
    /// Beyond the thesis: the \[P3\] compressed BVH (16-byte node pairs of 6-bit
    /// coordinates, relative encoding) of the binned SAH tree, decoded in the TRV pipeline.
    Cbvh,
}

impl TreeKind {
    /// Name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            TreeKind::Bvh2 => "bvh2",
            TreeKind::Mbvh4 => "mbvh4",
            TreeKind::Cbvh => "cbvh",
        }
    }

    /// Parses a command-line name.
    pub fn parse(s: &str) -> Result<Self, ConfigError> {
        match s {
            "bvh2" | "bvh" => Ok(TreeKind::Bvh2),
            "mbvh4" => Ok(TreeKind::Mbvh4),
            "cbvh" => Ok(TreeKind::Cbvh),
            _ => Err(ConfigError(format!(
                "unknown tree '{s}' (known: bvh2, mbvh4, cbvh)"
            ))),
        }
    }

    /// Bytes of one node in memory (a CBVH node is a node pair at 6 bits).
    pub fn node_bytes(self) -> u32 {
        match self {
            TreeKind::Bvh2 => 64,
            TreeKind::Mbvh4 => 128,
            TreeKind::Cbvh => 16,
        }
    }

    /// Node cache line at the thesis's capacity: one node for BVH and MBVH4 ([P4] §3),
    /// four 16-byte pairs for the CBVH (the 64-byte DRAM granularity of [P3] §5.2).
    pub fn default_line(self) -> u32 {
        self.node_bytes().max(64)
    }

    /// Children per node.
    pub fn width(self) -> usize {
        match self {
            TreeKind::Bvh2 | TreeKind::Cbvh => 2,
            TreeKind::Mbvh4 => 4,
        }
    }
}

/// A configuration the model cannot run.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ConfigError(pub String);

/// Parameters of the accelerator. Defaults are [P4] §3's; `docs/rtunit.md` lists where
/// each comes from and which are Arbor's assumptions (pipeline depths, MSHR counts).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RtConfig {
    /// Clock in MHz ([P4] §3.2: 500).
    pub clock_mhz: u32,
    /// Memory system (a name `sim::dram::open` accepts; [P4] §3.2: LPDDR3-1600, 2x32 bit).
    pub dram: String,
    /// TRV units sharing the IST unit ([P4] §3: 4).
    pub trv_units: u32,
    /// Ray stacks (ray slots) per TRV unit ([P4] §3: 32).
    pub stacks_per_trv: u32,
    /// Entries per stack ([P4] §3: 64).
    pub stack_entries: u32,
    /// Keep entry distances and drop stack entries beyond the closest hit ([P4] §3.1:
    /// the MBVH4 unit has the distance stack, the BVH unit not). `None`: as the thesis.
    pub distance_stack: Option<bool>,
    /// L1 node cache per TRV, bytes ([P4] §3: 16 KB).
    pub l1_bytes: u64,
    /// Shared node cache, bytes ([P4] §3: 128 KB).
    pub l2_bytes: u64,
    /// Primitive cache, bytes ([P4] §3: 128 KB).
    pub prim_bytes: u64,
    /// Associativity of every cache ([P4] §3: 4).
    pub ways: u32,
    /// Node cache line in bytes; 0 = one node (64 B BVH, 128 B MBVH4, [P4] §3; 64 B, four
    /// node pairs, for the CBVH).
    pub node_line_bytes: u32,
    /// Primitive cache line in bytes ([P4] §3: 64, two interleaved banks).
    pub prim_line_bytes: u32,
    /// Banks of the primitive cache ([P4] §3: 2).
    pub prim_banks: u32,
    /// Miss status registers per cache (Arbor's assumption: 16; at least 2, since a
    /// triangle across two lines misses both at once).
    pub mshrs: u32,
    /// Shared node cache hit latency in cycles (Arbor's assumption: 4).
    pub l2_latency: u64,
    /// Primitive cache hit latency in cycles (Arbor's assumption: 2).
    pub prim_latency: u64,
    /// TRV pipeline depth of the BVH unit in cycles: node fetch, slab tests, stack
    /// operations (Arbor's reading of [P4] Fig. 3: 6).
    pub trv_stages: u64,
    /// Extra TRV stages of the MBVH4 unit's sorting network ([P4] §3.1: 2).
    pub sort_stages: u64,
    /// Extra TRV stages of the CBVH unit's box decoder (Arbor's assumption: 2, one for the
    /// integer arithmetic of [P3] Eq. 3, one for the conversion to floats).
    pub decode_stages: u64,
    /// IST pipeline depth in cycles (Arbor's assumption for Wald's test with a Markstein
    /// division: 20).
    pub ist_stages: u64,
    /// Rays the IST unit holds at once (Arbor's assumption: 16).
    pub ist_rays: u32,
    /// Starting capacity of every FIFO between units ([P4] §3: 32).
    pub fifo_entries: u32,
    /// FLOPs charged for the IST unit's division ([P4] §3.2: 11, Markstein's algorithm;
    /// [P2] §6.4 charges a reciprocal as 3).
    pub ist_div_flops: u32,
    /// Per-class FIFO capacities after sizing (0: `fifo_entries`): new rays, TRV to IST,
    /// IST to TRV, finished rays, L1 misses, L1 fills.
    pub fifo_sizes: [u32; 6],
    /// Stop with an error after this many cycles.
    pub max_cycles: u64,
    /// Process node of the energy and area figures ([P4] §3.2: 45 nm).
    pub energy_node: crate::energy::Node,
    /// The conventions of the energy and area figures (the thesis's by default:
    /// `crate::energy::Conventions`; keys `energy`, `sram_cell`, `fpu_energy`,
    /// `ram_figures`, `wide_port`, `dram_energy`).
    pub energy: crate::energy::Conventions,
    /// Stop with an error when no ray has finished for this many cycles (rays that loop
    /// for ever because the caches cannot hold a line until its ray comes back).
    pub livelock_cycles: u64,
    /// A TRV pipeline whose head cannot leave (its FIFO to the IST unit or the scheduler
    /// is full) stalls as a whole: no ray enters and the rays behind the head do not
    /// advance (Arbor's reading of an in-order pipeline: true). `false` is the earlier
    /// model: rays keep entering a blocked pipeline and the ones behind the head age.
    pub trv_block_stalls: bool,
    /// Lines the shared node cache hands to the L1 fill FIFOs per cycle, over all TRV
    /// units (Arbor's assumption: 1, one read port; 0 = any number, the earlier model).
    pub l2_ports: u32,
    /// Lines a cache installs per cycle: each L1 from its fill FIFO, the shared node cache
    /// and the primitive cache from DRAM (Arbor's assumption: 1, one write port; 0 = any
    /// number, the earlier model).
    pub fill_ports: u32,
    /// TRV cycles per stack entry that a pop with the distance stack discards beyond the
    /// closest hit: the pop stage holds the pipeline's entrance (and the ray) that many
    /// cycles longer (Arbor's assumption: 1, one stack read per cycle; 0 = free culling,
    /// the earlier model).
    pub cull_cycles_per_entry: u64,
    /// Issue camera rays in scanline order (row by row, in groups of 64 pixels for the
    /// sampling plan) instead of 8x8 tiles (issue 31 part 4's what-if; default false).
    pub scanline: bool,
}

/// The FIFO classes of [`RtConfig::fifo_sizes`], in order.
pub const FIFO_CLASSES: [&str; 6] = [
    "sched->trv",
    "trv->ist",
    "ist->trv",
    "trv->sched",
    "l1->l2",
    "l2->l1",
];

/// The keys [`RtConfig::set`] accepts.
pub const KEYS: &[&str] = &[
    "clock_mhz",
    "dram",
    "trv_units",
    "stacks_per_trv",
    "stack_entries",
    "distance_stack",
    "l1_bytes",
    "l2_bytes",
    "prim_bytes",
    "ways",
    "node_line_bytes",
    "prim_line_bytes",
    "prim_banks",
    "mshrs",
    "l2_latency",
    "prim_latency",
    "trv_stages",
    "sort_stages",
    "decode_stages",
    "ist_stages",
    "ist_rays",
    "ist_div_flops",
    "energy",
    "fpu_energy",
    "ram_figures",
    "wide_port",
    "dram_energy",
    "fifo_entries",
    "fifo_sched_trv",
    "fifo_trv_ist",
    "fifo_ist_trv",
    "fifo_trv_sched",
    "fifo_l1_l2",
    "fifo_l2_l1",
    "max_cycles",
    "livelock_cycles",
    "energy_node",
    "sram_cell",
    "trv_block_stalls",
    "l2_ports",
    "fill_ports",
    "cull_cycles_per_entry",
    "scanline",
];

impl Default for RtConfig {
    fn default() -> Self {
        Self {
            clock_mhz: 500,
            dram: "lpddr3-1600-2x32".into(),
            trv_units: 4,
            stacks_per_trv: 32,
            stack_entries: 64,
            distance_stack: None,
            l1_bytes: 16 << 10,
            l2_bytes: 128 << 10,
            prim_bytes: 128 << 10,
            ways: 4,
            node_line_bytes: 0,
            prim_line_bytes: 64,
            prim_banks: 2,
            mshrs: 16,
            l2_latency: 4,
            prim_latency: 2,
            trv_stages: 6,
            sort_stages: 2,
            decode_stages: 2,
            ist_stages: 20,
            ist_rays: 16,
            ist_div_flops: 11,
            fifo_entries: 32,
            fifo_sizes: [0; 6],
            max_cycles: 50_000_000_000,
            livelock_cycles: 10_000_000,
            energy_node: crate::energy::Node::Nm45,
            energy: crate::energy::Conventions::default(),
            trv_block_stalls: true,
            l2_ports: 1,
            fill_ports: 1,
            cull_cycles_per_entry: 1,
            scanline: false,
        }
    }
}

impl RtConfig {
    /// Sets `key` from its text `value` (the `--set KEY=VALUE` syntax).
    pub fn set(&mut self, key: &str, value: &str) -> Result<(), ConfigError> {
        let value = value.trim().trim_matches('"');
        let bad = |why: &str| {
            ConfigError(format!(
                "bad value '{value}' for accelerator parameter '{key}': {why}"
            ))
        };
        let num = |min: u64, max: u64| -> Result<u64, ConfigError> {
            let v: u64 = value
                .replace('_', "")
                .parse()
                .map_err(|_| bad("expected a non-negative integer"))?;
            if v < min || v > max {
                return Err(bad(&format!("must be in {min}..={max}")));
            }
            Ok(v)
        };
        let num32 = |min: u64, max: u64| num(min, max).map(|v| v as u32);
        const MIB: u64 = 1 << 20;
        if self
            .energy
            .set(key, value)
            .map_err(|e| bad(&e.to_string()))?
        {
            return Ok(());
        }
        match key {
            "clock_mhz" => self.clock_mhz = num32(1, 100_000)?,
            "dram" => self.dram = value.to_string(),
            "address_mapping" | "write_drain" => {
                self.dram = crate::dram::with_option(&self.dram, key, value)
                    .map_err(|e| bad(&e.to_string()))?
            }
            "trv_units" => self.trv_units = num32(1, 64)?,
            "stacks_per_trv" => self.stacks_per_trv = num32(1, 1024)?,
            "stack_entries" => self.stack_entries = num32(1, 4096)?,
            "distance_stack" => {
                self.distance_stack = match value {
                    "true" | "1" | "yes" | "on" => Some(true),
                    "false" | "0" | "no" | "off" => Some(false),
                    "thesis" | "auto" => None,
                    _ => return Err(bad("expected true, false or thesis")),
                }
            }
            "l1_bytes" => self.l1_bytes = num(1, 64 * MIB)?,
            "l2_bytes" => self.l2_bytes = num(1, 256 * MIB)?,
            "prim_bytes" => self.prim_bytes = num(1, 256 * MIB)?,
            "ways" => self.ways = num32(1, 64)?,
            "node_line_bytes" => self.node_line_bytes = num32(0, 4096)?,
            "prim_line_bytes" => self.prim_line_bytes = num32(1, 4096)?,
            "prim_banks" => self.prim_banks = num32(1, 64)?,
            "mshrs" => self.mshrs = num32(2, 1024)?,
            "l2_latency" => self.l2_latency = num(1, 1000)?,
            "prim_latency" => self.prim_latency = num(1, 1000)?,
            "trv_stages" => self.trv_stages = num(1, 1000)?,
            "sort_stages" => self.sort_stages = num(0, 1000)?,
            "decode_stages" => self.decode_stages = num(0, 1000)?,
            "ist_stages" => self.ist_stages = num(1, 1000)?,
            "ist_rays" => self.ist_rays = num32(1, 4096)?,
            "ist_div_flops" => self.ist_div_flops = num32(0, 1000)?,
            "fifo_entries" => self.fifo_entries = num32(1, 1 << 16)?,
            "max_cycles" => self.max_cycles = num(1, u64::MAX / 2)?,
            "livelock_cycles" => self.livelock_cycles = num(1, u64::MAX / 2)?,
            "energy_node" => {
                self.energy_node =
                    crate::energy::Node::parse(value).map_err(|e| bad(&e.to_string()))?
            }
            "trv_block_stalls" => {
                self.trv_block_stalls = match value {
                    "true" | "1" | "yes" | "on" => true,
                    "false" | "0" | "no" | "off" => false,
                    _ => return Err(bad("expected true or false")),
                }
            }
            "scanline" => {
                self.scanline = match value {
                    "true" | "1" | "yes" | "on" => true,
                    "false" | "0" | "no" | "off" => false,
                    _ => return Err(bad("expected true or false")),
                }
            }
            "l2_ports" => self.l2_ports = num32(0, 1024)?,
            "fill_ports" => self.fill_ports = num32(0, 1024)?,
            "cull_cycles_per_entry" => self.cull_cycles_per_entry = num(0, 1000)?,
            k => match k
                .strip_prefix("fifo_")
                .and_then(|c| FIFO_KEYS.iter().position(|&f| f == c))
            {
                Some(i) => self.fifo_sizes[i] = num32(1, 1 << 16)?,
                None => {
                    return Err(ConfigError(format!(
                        "unknown accelerator parameter '{key}' (known: {})",
                        KEYS.join(", ")
                    )))
                }
            },
        }
        Ok(())
    }

    /// Applies a `KEY=VALUE` override.
    pub fn set_pair(&mut self, pair: &str) -> Result<(), ConfigError> {
        let Some((k, v)) = pair.split_once('=') else {
            return Err(ConfigError(format!(
                "bad --set '{pair}': expected KEY=VALUE"
            )));
        };
        self.set(k.trim(), v)
    }

    /// Capacity of FIFO class `c` (an index into [`FIFO_CLASSES`]).
    pub fn fifo_capacity(&self, c: usize) -> usize {
        match self.fifo_sizes[c] {
            0 => self.fifo_entries as usize,
            n => n as usize,
        }
    }

    /// Whether the TRV keeps a distance stack for `tree`.
    pub fn uses_distance_stack(&self, tree: TreeKind) -> bool {
        self.distance_stack.unwrap_or(tree == TreeKind::Mbvh4)
    }

    /// Node cache line for `tree`.
    pub fn node_line(&self, tree: TreeKind) -> u32 {
        match self.node_line_bytes {
            0 => tree.default_line(),
            n => n,
        }
    }

    /// TRV pipeline depth for `tree`.
    pub fn trv_depth(&self, tree: TreeKind) -> u64 {
        self.trv_stages
            + match tree {
                TreeKind::Bvh2 => 0,
                TreeKind::Mbvh4 => self.sort_stages,
                TreeKind::Cbvh => self.decode_stages,
            }
    }

    /// Checks that the parameters fit together: cache geometries, a node line that holds
    /// a node, a primitive line that holds a triangle across at most two lines.
    pub fn validate(&self, tree: TreeKind) -> Result<(), ConfigError> {
        let nl = self.node_line(tree);
        if !nl.is_power_of_two() || nl < tree.node_bytes() {
            return Err(ConfigError(format!(
                "node_line_bytes {nl} must be a power of two of at least one {}-byte {} node",
                tree.node_bytes(),
                tree.name()
            )));
        }
        if !self.prim_line_bytes.is_power_of_two() || self.prim_line_bytes < TRIANGLE_BYTES {
            return Err(ConfigError(format!(
                "prim_line_bytes {} must be a power of two of at least {TRIANGLE_BYTES} (one triangle)",
                self.prim_line_bytes
            )));
        }
        for (name, bytes, line) in [
            ("l1_bytes", self.l1_bytes, nl),
            ("l2_bytes", self.l2_bytes, nl),
            ("prim_bytes", self.prim_bytes, self.prim_line_bytes),
        ] {
            let set = self.ways as u64 * line as u64;
            if bytes < set || !bytes.is_multiple_of(set) || !(bytes / set).is_power_of_two() {
                return Err(ConfigError(format!(
                    "{name} = {bytes} must be a power-of-two number of sets of {} ways x {line}-byte lines",
                    self.ways
                )));
            }
        }
        if !self.prim_banks.is_power_of_two() {
            return Err(ConfigError(format!(
                "prim_banks = {} must be a power of two",
                self.prim_banks
            )));
        }
        Ok(())
    }
}

/// Short names of the FIFO classes in `fifo_*` keys, in [`FIFO_CLASSES`] order.
pub const FIFO_KEYS: [&str; 6] = [
    "sched_trv",
    "trv_ist",
    "ist_trv",
    "trv_sched",
    "l1_l2",
    "l2_l1",
];

/// Bytes of one precomputed triangle (Wald 2004, [P4] §3).
pub const TRIANGLE_BYTES: u32 = 48;

/// The capacity a FIFO is shrunk to after a run in which it held at most `peak` items
/// ([P4] §3: "the first power-of-two above the maximum population"): the smallest power
/// of two that holds `peak`, at least 1, never more than `start`.
pub fn sized_fifo(peak: usize, start: usize) -> usize {
    peak.max(1).next_power_of_two().min(start.max(1))
}
