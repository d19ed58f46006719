//! System energy per frame, \[P2\] §6.4: a BVH built for every frame by one of four
//! builders, then a frame rendered by the \[P4\] BVH accelerator, on one mobile SoC
//! (28 nm, the 25.6 GB/s LPDDR3 system, 500 MHz for every unit but MergeTree).
//!
//! The builders and how their energy is found:
//! - `binned-sah`: the hardware binned SAH builder of Doyle et al. as \[P2\] §6.4 bounds
//!   it: the DRAM traffic and floating-point operations of `analytic::binned_sah_hw` over
//!   the tree `bvh::BinnedSahBuilder` makes (16 bins, leaves of up to 8, the tree the
//!   accelerator's BVH uses too), FPUs fully used and the traffic as long consecutive
//!   bursts (`dram::stream`); on-chip buffers are not charged (a lower bound, as \[P2\]'s);
//! - `hlbvh`: the MergeTree cycle model (`mergetree`, preset `p2`, on the system's
//!   memory) with its energy model (`mergetree::energy`);
//! - `hlbvh+sah`: MergeTree with the toplevel binned SAH unit (`toplevel_sah`, cells of
//!   the top [`SystemConfig::toplevel_bits`] code bits), plus that unit's sweeps'
//!   floating-point work;
//! - `hlbvh+atrbvh`: MergeTree emitting the same cells, then a serial ATRBVH unit over
//!   the cell roots (treelets of 8, two passes, \[P2\] §6.2): its floating-point
//!   operations counted from Arbor's ATRBVH code ([`atrbvh_flops`], one per cycle at
//!   500 MHz), and its DRAM traffic as streams (the cell boxes read, each pass reading and
//!   writing every top node, the top tree written).
//!
//! Every MergeTree tree is checked against the software builder's (the run fails
//! otherwise), and every tree is traced by the accelerator model (`rtunit`, BVH2 nodes)
//! with its energy at the same node (`rtunit::energy`); the trace's functional result is
//! the software tracer's (checked in every run).

pub mod report;
pub mod sensitivity;

use geom::{Aabb, Triangle};
use serde::Serialize;
use trace::PinholeCamera;

use crate::analytic::binned_sah_hw::{self, BinnedSahHwParams};
use crate::dram::{self, MemStats};
use crate::energy::{Conventions, DramConvention, EnergyError, Flops, Fpu, Node, UnitEnergy};
use crate::mergetree::{self, energy::mergetree_energy, MergeTreeConfig};
use crate::rtunit::{self, RayMode, RtConfig, TreeKind, Workload};

/// Prefix of the [`SystemConfig::set`] keys that set a MergeTree parameter
/// (`mergetree.presort_slots`).
pub const MERGETREE_PREFIX: &str = "mergetree.";

/// Schema of the system report's JSON document.
pub const SCHEMA: &str = "arbor.report.system.v1";

/// The builders of \[P2\] §6.4.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Builder {
    /// Doyle et al.'s hardware binned SAH builder (lower bound).
    #[serde(rename = "binned-sah")]
    BinnedSah,
    /// MergeTree's HLBVH.
    #[serde(rename = "hlbvh")]
    Hlbvh,
    /// MergeTree with the toplevel binned SAH unit.
    #[serde(rename = "hlbvh+sah")]
    HlbvhSah,
    /// MergeTree with a toplevel ATRBVH unit.
    #[serde(rename = "hlbvh+atrbvh")]
    HlbvhAtrbvh,
}

impl Builder {
    /// All four, binned SAH (the reference) first.
    pub const ALL: [Builder; 4] = [
        Builder::BinnedSah,
        Builder::Hlbvh,
        Builder::HlbvhSah,
        Builder::HlbvhAtrbvh,
    ];

    /// Name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Builder::BinnedSah => "binned-sah",
            Builder::Hlbvh => "hlbvh",
            Builder::HlbvhSah => "hlbvh+sah",
            Builder::HlbvhAtrbvh => "hlbvh+atrbvh",
        }
    }
}

/// The default of [`SystemConfig::toplevel_bits`]: the cell level of
/// `bvh::toplevel::default_threshold`.
pub const TOPLEVEL_BITS: u32 = bvh::toplevel::DEFAULT_TOPLEVEL_BITS;

/// Errors of the system model.
#[derive(Debug, thiserror::Error)]
pub enum SystemError {
    /// A parameter cannot be used.
    #[error("{0}")]
    Config(String),
    /// A component model rejected its input.
    #[error(transparent)]
    Energy(#[from] EnergyError),
    /// The memory system.
    #[error(transparent)]
    Dram(#[from] dram::DramError),
    /// The MergeTree model.
    #[error(transparent)]
    MergeTree(#[from] mergetree::MergeTreeError),
    /// The accelerator model.
    #[error(transparent)]
    Rt(#[from] rtunit::RtError),
    /// A software builder.
    #[error(transparent)]
    Build(#[from] bvh::BuildError),
}

/// The modelled system.
#[derive(Clone, Debug, Serialize)]
pub struct SystemConfig {
    /// Process node of every on-chip figure (\[P2\] §6.4: 28 nm).
    pub node: Node,
    /// The conventions of every energy figure (the thesis's by default).
    pub energy: Conventions,
    /// Memory system (\[P2\] §6.4: the 25.6 GB/s system, `lpddr3-1600-2x64`).
    pub dram: String,
    /// Clock of the binned SAH, ATRBVH and refit units and the accelerator, MHz (500).
    pub unit_clock_mhz: u32,
    /// MergeTree (preset `p2` on `dram`).
    pub mergetree: MergeTreeConfig,
    /// The accelerator (\[P4\] defaults, energy at `node`, on `dram`).
    pub rt: RtConfig,
    /// The binned SAH builder's traffic model.
    #[serde(skip)]
    pub binned: BinnedSahHwParams,
    /// Diffuse bounces (\[P2\] §6.4: three).
    pub bounces: u32,
    /// Sampling seed of the diffuse rays.
    pub seed: u64,
    /// Top Morton code bits whose grid cells are the primitives of the toplevel builds
    /// (`hlbvh+sah`, `hlbvh+atrbvh`): the emitter's `highlevel_threshold` is the code's bits
    /// less these. The thesis gives the toplevel trees' size ("ca. 500–2,000 nodes",
    /// \[P2\] §6.1), not the cell level; 12 bits (at most 4,096 cells) is Arbor's
    /// (`bvh::toplevel::default_threshold`).
    pub toplevel_bits: u32,
}

impl Default for SystemConfig {
    fn default() -> Self {
        let dram = "lpddr3-1600-2x64".to_string();
        let rt = RtConfig {
            energy_node: Node::Nm28,
            dram: dram.clone(),
            // [P2] §6.4: "Reciprocal calculation is estimated to take as much energy as 3
            // FLOPs".
            ist_div_flops: 3,
            ..RtConfig::default()
        };
        let mergetree = MergeTreeConfig::p2();
        Self {
            node: Node::Nm28,
            energy: Conventions::default(),
            dram,
            unit_clock_mhz: 500,
            mergetree,
            rt,
            binned: BinnedSahHwParams::default(),
            bounces: 3,
            seed: 1,
            toplevel_bits: TOPLEVEL_BITS,
        }
    }
}

impl SystemConfig {
    /// Sets `key` to `value`: `node`, `bounces`, `seed`, an energy convention
    /// (`crate::energy::Conventions::KEYS`, `energy`), a memory controller option
    /// (`address_mapping`, `write_drain`: `dram::with_option`), a MergeTree key prefixed
    /// [`MERGETREE_PREFIX`] (`MergeTreeConfig::set`) or any accelerator key
    /// (`RtConfig::set`), everywhere it appears.
    pub fn set(&mut self, key: &str, value: &str) -> Result<(), SystemError> {
        let bad = |why: &str| SystemError::Config(format!("bad value '{value}' for {key}: {why}"));
        match key {
            "node" => {
                let n = Node::parse(value)?;
                *self = self.clone().with(n, self.energy, &self.dram.clone());
            }
            "bounces" => {
                self.bounces = value
                    .trim()
                    .parse()
                    .ok()
                    .filter(|b| *b <= 64)
                    .ok_or_else(|| bad("expected 0 to 64"))?
            }
            "seed" => {
                self.seed = value
                    .trim()
                    .parse()
                    .map_err(|_| bad("expected a non-negative integer"))?
            }
            "toplevel_bits" => {
                let most = self.mergetree.morton_bits.saturating_sub(1);
                self.toplevel_bits = value
                    .trim()
                    .parse()
                    .ok()
                    .filter(|b| (1..=most).contains(b))
                    .ok_or_else(|| bad(&format!("expected 1 to {most}")))?
            }
            "dram" => return Err(bad("the memory system is set with --dram")),
            // What-if options of the memory controller, on every memory of the study.
            "address_mapping" | "write_drain" => {
                self.dram = dram::with_option(&self.dram, key, value)?;
                self.rt.dram = dram::with_option(&self.rt.dram, key, value)?;
            }
            _ if key.starts_with(MERGETREE_PREFIX) => {
                let mut mt = self.mergetree.clone();
                mt.set(&key[MERGETREE_PREFIX.len()..], value)
                    .and_then(|()| mt.validate())
                    .map_err(|e| SystemError::Config(format!("{key}={value}: {e}")))?;
                self.mergetree = mt;
            }
            _ => {
                let mut e = self.energy;
                if e.set(key, value)? {
                    self.energy = e;
                    self.rt.energy = e;
                } else {
                    self.rt
                        .set(key, value)
                        .map_err(|e| SystemError::Config(e.to_string()))?;
                }
            }
        }
        Ok(())
    }

    /// Sets the node, energy conventions and memory system everywhere they appear.
    pub fn with(mut self, node: Node, energy: Conventions, dram: &str) -> Self {
        self.node = node;
        self.energy = energy;
        self.dram = dram.to_string();
        self.rt.energy_node = node;
        self.rt.energy = energy;
        self.rt.dram = dram.to_string();
        self
    }
}

/// One build's energy.
#[derive(Clone, Debug, Serialize)]
pub struct BuildEnergy {
    /// Builder.
    pub builder: Builder,
    /// Build time in ms (binned SAH: the longer of its DRAM transfer and its FPU work at
    /// one operation per FPU per cycle; see [`binned_sah_energy`]).
    pub ms: f64,
    /// DRAM traffic in bytes.
    pub dram_bytes: u64,
    /// Floating-point operations outside MergeTree (binned SAH, the toplevel units).
    pub flops: f64,
    /// Energy per unit (the last one the DRAM); they sum to `mj`.
    pub units: Vec<UnitEnergy>,
    /// Energy of the build in mJ.
    pub mj: f64,
    /// DRAM energy in mJ.
    pub dram_mj: f64,
    /// The part of `dram_mj` above an idle memory's over the same time (\[P2\] §6.2's
    /// convention: an idle memory's background and refresh subtracted), mJ.
    pub dram_above_idle_mj: f64,
    /// The idle memory's energy (standby and refresh) over the part of the build time in
    /// which a streamed unit computes but its DRAM does not transfer, mJ: not in `mj`,
    /// whose streamed DRAM is the full-utilization lower bound (the memory charged only
    /// while it transfers). MergeTree's memory model runs for the whole build, so only
    /// binned SAH and the ATRBVH unit, whose FPUs are slower than their streams, have it.
    pub dram_wait_mj: f64,
    /// SAH of the tree (\[P2\]'s weights, `Bvh2::sah`).
    pub sah: f64,
}

/// The work of the toplevel ATRBVH unit: FLOPs and DRAM bytes.
fn atrbvh_traffic(roots: u64, top_inner: u64, passes: u32) -> (u64, u64) {
    let node = 64;
    let read = roots * 32 + passes as u64 * top_inner * node;
    let write = passes as u64 * top_inner * node + top_inner * node;
    (read, write)
}

/// Half area of a box: 3 subtracts, 3 multiplies, 2 adds.
const HALF_AREA: Flops = Flops {
    adds: 5.0,
    muls: 3.0,
};
/// Union of two boxes: 6 min/max.
const UNION: Flops = Flops {
    adds: 6.0,
    muls: 0.0,
};

/// Floating-point operations of rebuilding one treelet of `n` leaves, counted from
/// `bvh::atrbvh`'s `restructure`: forming it (`k` area compares while it has `k` leaves,
/// `k = 2 .. n-1`, and `n - 2` adds of the old area sum), the distance matrix
/// (`n (n-1) / 2` unions and half areas), then each of the `n - 1` merges with `m` active
/// leaves: `m (m-1) / 2` compares for the closest pair, one union and half area, one add
/// of the new sum, and `m - 2` new distances; finally the gain test (1 multiply, 1
/// compare).
pub fn treelet_flops(n: u64) -> Flops {
    let n = n as f64;
    let ua = UNION.plus(HALF_AREA);
    let form = Flops {
        adds: ((2..n as u64).sum::<u64>() as f64) + (n - 2.0),
        muls: 0.0,
    };
    let matrix = ua.times(n * (n - 1.0) / 2.0);
    let mut merges = Flops::default();
    let mut m = n;
    while m >= 2.0 {
        merges = merges
            .plus(Flops {
                adds: m * (m - 1.0) / 2.0 + 1.0,
                muls: 0.0,
            })
            .plus(ua)
            .plus(ua.times((m - 2.0).max(0.0)));
        m -= 1.0;
    }
    form.plus(matrix).plus(merges).plus(Flops {
        adds: 1.0,
        muls: 1.0,
    })
}

/// Floating-point operations of an ATRBVH post-process that did `work`.
pub fn atrbvh_flops(work: &bvh::AtrbvhWork) -> Flops {
    work.treelets_by_leaves
        .iter()
        .enumerate()
        .fold(Flops::default(), |f, (n, &count)| {
            if count == 0 {
                f
            } else {
                f.plus(treelet_flops(n as u64).times(count as f64))
            }
        })
}

/// A unit that streams `read` and `write` bytes and does `flops` (one FPU operation per
/// cycle per FPU of `fpus`, at `mhz`): its FPU energy and its DRAM bound, and the time
/// (the longer of the two).
fn streaming_unit(
    name: &'static str,
    flops: Flops,
    fpus: f64,
    read: u64,
    write: u64,
    cfg: &SystemConfig,
) -> Result<(Vec<UnitEnergy>, f64, MemStats, f64), SystemError> {
    let (mem, dram_s) = dram::stream::streaming(&cfg.dram, read, write)?;
    let fpu_s = flops.total() / (fpus * cfg.unit_clock_mhz as f64 * 1e6);
    let seconds = dram_s.max(fpu_s);
    let fpu_mj = flops.energy_pj(&Fpu::at(cfg.node, cfg.energy.fpu)) * 1e-9;
    let wait_mj = match cfg.energy.dram {
        DramConvention::Full => dram_wait_mj(&mem, dram_s, seconds),
        // The idle memory's energy is what this convention leaves out.
        DramConvention::AboveIdle => 0.0,
    };
    Ok((
        vec![
            UnitEnergy::new(name, 0.0, fpu_mj, 0.0, seconds),
            UnitEnergy::dram(&mem, seconds, cfg.energy.dram),
        ],
        seconds,
        mem,
        wait_mj,
    ))
}

/// The idle memory's energy over `seconds - dram_s` (the time a streamed unit computes
/// after its `dram_s` of transfers), at the idle power of `mem`'s own run (its idle
/// energy over its transfer time), mJ.
pub fn dram_wait_mj(mem: &MemStats, dram_s: f64, seconds: f64) -> f64 {
    match mem.energy_pj.as_ref() {
        Some(e) if dram_s > 0.0 && seconds > dram_s => {
            e.idle_pj * 1e-9 / dram_s * (seconds - dram_s)
        }
        _ => 0.0,
    }
}

/// FPUs of the binned SAH unit for its time estimate: \[P2\] does not give Doyle et al.'s
/// count, so the time is bounded by DRAM alone unless the FPUs would be slower with one
/// pipelined datapath per operation of a primitive's binning step (37,
/// `binned_sah_hw::SweepFlops::PER_PRIM`).
pub const BINNED_SAH_FPUS: f64 = 37.0;

/// The binned SAH builder's lower-bound energy over `aabbs`, and its tree.
pub fn binned_sah_energy(
    aabbs: &[Aabb],
    cfg: &SystemConfig,
) -> Result<(BuildEnergy, bvh::Bvh2), SystemError> {
    let tree = bvh::BinnedSahBuilder::default().build(aabbs)?;
    let t = binned_sah_hw::model(&tree, &cfg.binned);
    let flops = binned_sah_hw::energy_flops(&tree, cfg.binned.bins);
    let (units, seconds, mem, wait) = streaming_unit(
        "binned SAH FPUs",
        flops,
        BINNED_SAH_FPUS,
        t.sweep_read_bytes,
        t.sweep_write_bytes + t.bvh_bytes,
        cfg,
    )?;
    let dram = DramAccounting {
        above_idle_mj: above_idle_mj(&mem),
        wait_mj: wait,
    };
    Ok((
        finish(Builder::BinnedSah, units, seconds, dram, &mem, flops, &tree),
        tree,
    ))
}

impl BuildEnergy {
    /// The build's energy with the DRAM counted above idle.
    pub fn mj_above_idle(&self) -> f64 {
        self.mj - self.dram_mj + self.dram_above_idle_mj
    }

    /// The build's energy with the memory's idle energy charged while streamed units
    /// compute ([`BuildEnergy::dram_wait_mj`]).
    pub fn mj_with_dram_wait(&self) -> f64 {
        self.mj + self.dram_wait_mj
    }
}

/// DRAM energy above an idle memory's in mJ, from a run's counts.
fn above_idle_mj(mem: &MemStats) -> f64 {
    mem.energy_pj.as_ref().map_or(0.0, |e| e.above_idle_pj()) * 1e-9
}

/// A build's DRAM energy under the other accountings than `BuildEnergy::dram_mj`'s.
struct DramAccounting {
    /// `BuildEnergy::dram_above_idle_mj`.
    above_idle_mj: f64,
    /// `BuildEnergy::dram_wait_mj`.
    wait_mj: f64,
}

fn finish(
    builder: Builder,
    units: Vec<UnitEnergy>,
    seconds: f64,
    dram: DramAccounting,
    mem: &MemStats,
    flops: Flops,
    tree: &bvh::Bvh2,
) -> BuildEnergy {
    BuildEnergy {
        dram_above_idle_mj: dram.above_idle_mj,
        dram_wait_mj: dram.wait_mj,
        builder,
        ms: seconds * 1e3,
        dram_bytes: mem.bytes_read + mem.bytes_written,
        flops: flops.total(),
        mj: units.iter().map(|u| u.total_mj).sum(),
        dram_mj: units
            .iter()
            .filter(|u| u.unit == "DRAM")
            .map(|u| u.total_mj)
            .sum(),
        units,
        sah: tree.sah(),
    }
}

/// The cycle-level runs already done over one scene, keyed by everything that sets their
/// result, so that configurations differing only in what is computed from the runs (the
/// energy conventions, the IST division's FLOPs) reuse them. A memo belongs to one scene.
#[derive(Default)]
pub struct SimMemo {
    mergetree: std::collections::HashMap<String, mergetree::MergeTreeReport>,
    rt: std::collections::HashMap<String, rtunit::RtReport>,
    /// Runs simulated, and runs answered from the memo.
    pub simulated: u64,
    /// Runs answered from the memo.
    pub reused: u64,
}

impl SimMemo {
    fn key<T: Serialize>(parts: &T) -> String {
        serde_json::to_string(parts).expect("configurations serialize")
    }

    /// An accelerator run with `cfg`: from the memo when a run with the same `tag` (what
    /// else sets the run: tree, rays, sampling, camera) and the same timing configuration
    /// was done, with its energy recomputed under `cfg`'s node, conventions and IST
    /// division; else `run()`, remembered.
    pub fn rt_run<T: Serialize>(
        &mut self,
        tag: &T,
        cfg: &RtConfig,
        run: impl FnOnce() -> Result<rtunit::RtReport, SystemError>,
    ) -> Result<rtunit::RtReport, SystemError> {
        let mut timing = cfg.clone();
        timing.energy = Conventions::default();
        timing.ist_div_flops = 0;
        timing.energy_node = Node::Nm45;
        let key = Self::key(&(&timing, tag));
        if let Some(r) = self.rt.get(&key) {
            self.reused += 1;
            let mut r = r.clone();
            r.config = cfg.clone();
            r.energy = Some(rtunit::energy::accelerator_energy(
                &r,
                cfg.energy_node,
                &cfg.energy,
            )?);
            return Ok(r);
        }
        let r = run()?;
        self.simulated += 1;
        self.rt.insert(key, r.clone());
        Ok(r)
    }
}

/// A hash of every node and leaf-table entry of `tree`: equal trees give equal values.
fn tree_fingerprint(tree: &bvh::Bvh2) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    tree.nodes.len().hash(&mut h);
    for n in &tree.nodes {
        for b in n.bounds.iter().flatten() {
            b.to_bits().hash(&mut h);
        }
        n.children.hash(&mut h);
    }
    tree.prim_indices.hash(&mut h);
    h.finish()
}

/// One MergeTree run on `cfg`'s memory, checked against the software builder.
fn mergetree_run(
    aabbs: &[Aabb],
    mt: &MergeTreeConfig,
    cfg: &SystemConfig,
    memo: &mut SimMemo,
) -> Result<mergetree::MergeTreeReport, SystemError> {
    let key = SimMemo::key(&(mt, &cfg.dram));
    if let Some(r) = memo.mergetree.get(&key) {
        memo.reused += 1;
        return Ok(r.clone());
    }
    let r = mergetree_run_uncached(aabbs, mt, cfg)?;
    memo.simulated += 1;
    memo.mergetree.insert(key, r.clone());
    Ok(r)
}

fn mergetree_run_uncached(
    aabbs: &[Aabb],
    mt: &MergeTreeConfig,
    cfg: &SystemConfig,
) -> Result<mergetree::MergeTreeReport, SystemError> {
    let port = dram::open(&cfg.dram, mt.period_fs())?;
    let r = mergetree::simulate(aabbs, mt, port)?;
    if !mergetree::tree_matches_software(&r, aabbs)? {
        return Err(SystemError::Config(
            "MergeTree model's tree differs from the software builder's".into(),
        ));
    }
    Ok(r)
}

/// The energy of a MergeTree build `builder` over `aabbs` (`hlbvh`, `hlbvh+sah` or
/// `hlbvh+atrbvh`), and its tree.
pub fn mergetree_build_energy(
    builder: Builder,
    aabbs: &[Aabb],
    cfg: &SystemConfig,
) -> Result<(BuildEnergy, bvh::Bvh2), SystemError> {
    mergetree_build_energy_memo(builder, aabbs, cfg, &mut SimMemo::default())
}

fn mergetree_build_energy_memo(
    builder: Builder,
    aabbs: &[Aabb],
    cfg: &SystemConfig,
    memo: &mut SimMemo,
) -> Result<(BuildEnergy, bvh::Bvh2), SystemError> {
    let mut mt = cfg.mergetree.clone();
    if builder != Builder::Hlbvh {
        let code_bits = mt.morton_bits;
        if cfg.toplevel_bits == 0 || cfg.toplevel_bits >= code_bits {
            return Err(SystemError::Config(format!(
                "toplevel_bits {} outside 1 to {}",
                cfg.toplevel_bits,
                code_bits - 1
            )));
        }
        mt.highlevel_threshold = Some(code_bits - cfg.toplevel_bits);
        mt.toplevel_sah = builder == Builder::HlbvhSah;
    }
    let r = mergetree_run(aabbs, &mt, cfg, memo)?;
    let e = mergetree_energy(&r, cfg.node, &cfg.energy)?;
    let seconds = r.ms * 1e-3;
    let mut units = e.units.clone();
    let mut mem = r.memory.clone();
    let mut flops = Flops::default();
    let mut extra_s = 0.0;
    let mut above = above_idle_mj(&r.memory);
    let mut wait = 0.0;
    let tree = match builder {
        Builder::BinnedSah => {
            return Err(SystemError::Config(
                "binned SAH is not a MergeTree build".into(),
            ))
        }
        Builder::Hlbvh => r.tree()?,
        Builder::HlbvhSah => {
            // The toplevel unit's sweeps run inside the MergeTree run (its time and
            // node writes are there); its FPU work is added here.
            let top = r.top_tree.as_ref().ok_or_else(|| {
                SystemError::Config("MergeTree ran without its toplevel unit".into())
            })?;
            flops = binned_sah_hw::energy_flops(top, mt.toplevel_bins as u64);
            let fpu_mj = flops.energy_pj(&Fpu::at(cfg.node, cfg.energy.fpu)) * 1e-9;
            units.insert(
                units.len() - 1,
                UnitEnergy::new("toplevel SAH FPUs", 0.0, fpu_mj, 0.0, seconds),
            );
            r.tree()?
        }
        Builder::HlbvhAtrbvh => {
            let (tree, work) = bvh::HlbvhAtrbvhBuilder {
                hlbvh: mergetree::software_builder(&mt),
                ..Default::default()
            }
            .build_with_work(aabbs)?;
            flops = atrbvh_flops(&work);
            let (read, write) = atrbvh_traffic(r.highlevel_roots, work.inner_nodes, work.passes);
            let (top_units, s, top_mem, w) =
                streaming_unit("toplevel ATRBVH unit", flops, 1.0, read, write, cfg)?;
            extra_s = s;
            wait = w;
            let dram = units.pop().expect("a DRAM row");
            units.push(top_units[0].clone());
            units.push(UnitEnergy::new(
                "DRAM",
                0.0,
                dram.dynamic_mj + top_units[1].dynamic_mj,
                dram.static_mj + top_units[1].static_mj,
                seconds + s,
            ));
            above += above_idle_mj(&top_mem);
            mem.bytes_read += top_mem.bytes_read;
            mem.bytes_written += top_mem.bytes_written;
            tree
        }
    };
    let dram = DramAccounting {
        above_idle_mj: above,
        wait_mj: wait,
    };
    Ok((
        finish(builder, units, seconds + extra_s, dram, &mem, flops, &tree),
        tree,
    ))
}

/// The energy of `builder` over `aabbs`, and its tree.
pub fn build_energy(
    builder: Builder,
    aabbs: &[Aabb],
    cfg: &SystemConfig,
) -> Result<(BuildEnergy, bvh::Bvh2), SystemError> {
    build_energy_memo(builder, aabbs, cfg, &mut SimMemo::default())
}

/// [`build_energy`] reusing the runs of `memo` (one memo per scene).
pub fn build_energy_memo(
    builder: Builder,
    aabbs: &[Aabb],
    cfg: &SystemConfig,
    memo: &mut SimMemo,
) -> Result<(BuildEnergy, bvh::Bvh2), SystemError> {
    match builder {
        Builder::BinnedSah => binned_sah_energy(aabbs, cfg),
        b => mergetree_build_energy_memo(b, aabbs, cfg, memo),
    }
}

/// One frame's tracing energy.
#[derive(Clone, Debug, Serialize)]
pub struct TraceEnergy {
    /// Builder of the tree.
    pub builder: Builder,
    /// Ray kind.
    pub rays: RayMode,
    /// Energy of the frame in mJ (sampled runs: per traced ray times the frame's rays).
    pub frame_mj: f64,
    /// `frame_mj` with the DRAM counted above an idle memory's.
    pub frame_mj_above_idle: f64,
    /// DRAM part of the run's energy, as a fraction.
    pub dram_fraction: f64,
    /// Million rays per second.
    pub mrps: f64,
    /// DRAM traffic of the frame in MB.
    pub frame_dram_mb: f64,
    /// One in `sample` tile chunks timed.
    pub sample: u32,
    /// The relative standard error of `frame_mj` (and `frame_mj_above_idle`) from
    /// sampling (`rtunit::sampling`); 0 for whole frames.
    pub frame_mj_rel_se: f64,
    /// Sampled runs: each measurement window's pixels and energy share in mJ
    /// (`rtunit::energy::AcceleratorEnergy::window_mj`).
    #[serde(skip)]
    pub window_mj: Vec<(u64, f64)>,
}

/// Traces one frame of `rays` through `tree` (a binary tree over `triangles`) with the
/// accelerator.
pub fn trace_energy(
    builder: Builder,
    tree: bvh::Bvh2,
    triangles: &[Triangle],
    camera: &PinholeCamera,
    rays: RayMode,
    sample: u32,
    cfg: &SystemConfig,
) -> Result<TraceEnergy, SystemError> {
    let t = TraceJob {
        builder,
        triangles,
        camera,
        rays,
        sample,
    };
    trace_energy_memo(&t, tree, cfg, &mut SimMemo::default())
}

/// What [`trace_energy`] traces.
pub struct TraceJob<'a> {
    /// Builder of the tree.
    pub builder: Builder,
    /// The scene's triangles.
    pub triangles: &'a [Triangle],
    /// The camera.
    pub camera: &'a PinholeCamera,
    /// Ray kind.
    pub rays: RayMode,
    /// One in `sample` tile chunks timed.
    pub sample: u32,
}

/// [`trace_energy`] reusing the runs of `memo`: a run whose timing configuration, builder,
/// ray kind, sampling and seed match is not simulated again, only its energy recomputed
/// under `cfg`'s conventions (the tree of a builder is the same for the same scene and
/// MergeTree configuration, which [`build_energy_memo`]'s key holds).
pub fn trace_energy_memo(
    t: &TraceJob<'_>,
    tree: bvh::Bvh2,
    cfg: &SystemConfig,
    memo: &mut SimMemo,
) -> Result<TraceEnergy, SystemError> {
    let (builder, rays, sample) = (t.builder, t.rays, t.sample);
    // The tree itself, not the builder's configuration, sets the run: a MergeTree
    // parameter that changes only the build's timing reuses the traces.
    let tag = (
        builder,
        rays,
        sample,
        cfg.bounces,
        cfg.seed,
        tree_fingerprint(&tree),
        t.camera,
    );
    let r = memo.rt_run(&tag, &cfg.rt, || {
        let built = rtunit::tree_from(TreeKind::Bvh2, bvh::Tree::Bvh2(tree), t.triangles)?;
        let work = Workload {
            triangles: t.triangles,
            camera: t.camera,
            rays,
            bounces: cfg.bounces,
            seed: cfg.seed,
            sample,
            progress: None,
        };
        Ok(rtunit::run(&built, &work, &cfg.rt)?)
    })?;
    if !r.hits_match_software {
        return Err(SystemError::Config(
            "accelerator hits differ from the software tracer's".into(),
        ));
    }
    let e = r
        .energy
        .as_ref()
        .ok_or_else(|| SystemError::Config("the accelerator run has no energy".into()))?;
    let dram = e
        .units
        .iter()
        .find(|u| u.unit == "DRAM")
        .map_or(0.0, |u| u.total_mj);
    // The frame's share of the run (1 for whole frames).
    let scale = if e.run_mj > 0.0 {
        e.frame_mj / e.run_mj
    } else {
        0.0
    };
    Ok(TraceEnergy {
        builder,
        rays,
        frame_mj: e.frame_mj,
        frame_mj_above_idle: (e.run_mj - dram + e.dram_above_idle_mj) * scale,
        dram_fraction: if e.run_mj > 0.0 { dram / e.run_mj } else { 0.0 },
        mrps: r.mrps,
        frame_dram_mb: r.frame_dram_mb,
        sample,
        frame_mj_rel_se: e.frame_mj_rel_se,
        window_mj: e.window_mj.clone(),
    })
}

#[cfg(test)]
mod tests;
