//! Energy and area of the MergeTree unit from the cycle model's counts, in the units of
//! \[P2\] Table IV (insertion sorters, multi-merge unit, hierarchy emitter, FIFOs), plus
//! the DRAM, with the component models of `crate::energy`.
//!
//! \[P2\]'s figures come from post-synthesis power analysis of the RTL; Arbor has no RTL,
//! so the logic is counted from its memory blocks and operations (issue 13: "the
//! comparison is to the same order of magnitude"):
//! - **insertion sorters**: per presorter an SRAM of `presort_slots` elements (32 bytes, or
//!   `point_element` in the point modes);
//!   each busy presorter cycle compares its new element with every slot (32-bit integer
//!   compares of Morton codes) and writes one slot;
//! - **multi-merge unit**: the scratchpad (M elements of 32 bytes: 256 KB for `p2`), each
//!   element written once when its run's burst arrives and read once when merged out; the
//!   heap of the fan-in's keys (8 bytes each: code and queue), each heap operation touching
//!   one entry per level (log2 fan-in levels, \[P2\] §5.2);
//! - **hierarchy emitter**: per step a node's box union (6 floating-point compares) and
//!   per node one 64-byte write into the node buffer (`node_buffer_bytes`);
//! - **FIFOs**: every FIFO of the model an SRAM of its capacity in elements, each
//!   push a write and a read;
//! - **MBVH4 collapse unit** (only with `output = mbvh4`, issue 18 part 2; see
//!   [`collapse_unit`]): the streaming collapse behind the emitter, its storage sized
//!   from the run's measured peak, the emitter-to-unit FIFO and its datapath;
//! - static: every SRAM leaks for the whole build; comparators, muxes, control and clock
//!   trees are not counted (no component data gives them).

use serde::Serialize;

use super::config::{OutputMode, MBVH4_NODE_BYTES, NODE_BYTES};
use super::MergeTreeReport;
use crate::energy::{int_add_pj, ram, Conventions, EnergyError, Flops, Fpu, Node, UnitEnergy};

/// \[P2\] Table IV's units, then the DRAM.
pub const UNITS: [&str; 5] = [
    "Insertion sorters",
    "Multi-merge unit",
    "Hierarchy emitter",
    "FIFOs and muxes",
    "DRAM",
];

/// The row of the streaming MBVH4 collapse unit (`output = mbvh4` only), between
/// [`UNITS`]' on-chip units and the DRAM.
pub const COLLAPSE_UNIT: &str = "MBVH4 collapse unit";

/// Bytes of one entry of the FIFO from the emitter to the collapse unit: an emitted binary
/// node (two child boxes, 48 B; two references, 8 B) in a 64-byte entry.
pub const COLLAPSE_FIFO_ENTRY_BYTES: u64 = NODE_BYTES;

/// One box-area unit of the greedy rule: half the surface area `dx dy + dy dz + dz dx`,
/// three subtractions, three multiplies and two adds.
pub const AREA_UNIT: Flops = Flops {
    adds: 5.0,
    muls: 3.0,
};

/// One least-cost row of the windowed rule (`bvh::StreamCollapse::with_window`) per
/// cycle: for budgets 2..4 the six splits, each a sum and a compare with the best so far
/// (12 adds); budget 1, the node's own area and its sum with the 4-slot cost (an area
/// unit and an add); the compares of each budget with the one below (3).
pub const COST_ROW: Flops = Flops {
    adds: 12.0 + 5.0 + 1.0 + 3.0,
    muls: 3.0,
};

/// The size of the collapse unit of a run (`output = mbvh4`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CollapseUnitSize {
    /// The windowed rule's levels (`mbvh4_window`; `None`: the greedy rule).
    pub window: Option<u32>,
    /// Bytes of its storage: the greedy rule's open subtrees, one 128-byte node of slots
    /// each, at the run's peak (`max_open` x 128); the windowed rule's treelets at the
    /// run's peak (`max_window_bytes`: 64-byte rows and their items).
    pub storage_bytes: u64,
    /// Bytes of the FIFO from the emitter (`cbvh_fifo` entries of 64 bytes).
    pub fifo_bytes: u64,
    /// The datapath, fully pipelined (one unit per operation): two box-area units and a
    /// compare (greedy), or one least-cost row and a box union (windowed).
    pub datapath: Flops,
    /// Operations over the run.
    pub ops: Flops,
    /// 64-byte accesses of the storage over the run.
    pub storage_accesses: u64,
}

/// The collapse unit of `r` (`output = mbvh4` only; `None` in the other modes).
///
/// - *Storage*: the greedy rule writes each open subtree's slots once (128 B, two 64-byte
///   accesses) and reads them once, when its parent consumes it (to open or to close it)
///   or, for the root, at the end: four accesses per binary node. The windowed rule
///   updates `L + 1` rows per node (its timing model), each reading the row and its two
///   children's and writing it back (four accesses), and reads each wide node's slots
///   when it closes it (two accesses).
/// - *Datapath*: per binary node the greedy rule computes both children's box areas and
///   compares them ([`AREA_UNIT`] twice and a compare; the decision itself compares slot
///   counts, not counted); the windowed rule forms the node's box (6 compares) and
///   updates `L + 1` [`COST_ROW`]s.
/// - *FIFO*: each binary node is pushed and popped once.
///
/// The storage is what the run needed (its measured peak), not a worst case: the greedy
/// rule's bound is the emitter's deepest stack + 1 nodes of slots, the windowed rule's
/// `2^(L + 1)` rows per open subtree.
pub fn collapse_unit(r: &MergeTreeReport) -> Option<CollapseUnitSize> {
    if r.config.output != OutputMode::Mbvh4 {
        return None;
    }
    let st = r
        .mbvh4
        .as_ref()
        .and_then(|m| m.stream.clone())
        .unwrap_or_default();
    let window = r.config.mbvh4_window;
    let n = st.nodes_in;
    let compares = |k: f64| Flops { adds: k, muls: 0.0 };
    // Storage bytes, datapath, operations per binary node, storage accesses.
    let (storage_bytes, datapath, per_node, storage_accesses) = match window {
        None => {
            let d = AREA_UNIT.times(2.0).plus(compares(1.0));
            (st.max_open * MBVH4_NODE_BYTES, d, d, 4 * n)
        }
        Some(l) => {
            let rows = l as u64 + 1;
            (
                st.max_window_bytes,
                COST_ROW.plus(compares(6.0)),
                COST_ROW.times(rows as f64).plus(compares(6.0)),
                4 * rows * n + 2 * st.nodes_written,
            )
        }
    };
    Some(CollapseUnitSize {
        window,
        storage_bytes: storage_bytes.max(MBVH4_NODE_BYTES),
        fifo_bytes: r.config.cbvh_fifo as u64 * COLLAPSE_FIFO_ENTRY_BYTES,
        datapath,
        ops: per_node.times(n as f64),
        storage_accesses,
    })
}

/// Bytes of a heap entry (Morton code and queue index).
pub const HEAP_ENTRY_BYTES: f64 = 8.0;

/// The unit's energy over one build.
#[derive(Clone, Debug, Serialize)]
pub struct MergeTreeEnergy {
    /// Process node.
    pub node: Node,
    /// The conventions of the figures.
    pub conventions: Conventions,
    /// Per unit, in [`UNITS`] order; with `output = mbvh4` the [`COLLAPSE_UNIT`] row
    /// comes before the DRAM, which is always last.
    pub units: Vec<UnitEnergy>,
    /// On-chip ("logic") power in mW: all units but the DRAM.
    pub logic_mw: f64,
    /// DRAM power in mW.
    pub dram_mw: f64,
    /// DRAM power above an idle memory's (\[P2\] §6.2's figure), mW.
    pub dram_above_idle_mw: f64,
    /// Energy of the build in mJ (the breakdown's sum).
    pub build_mj: f64,
    /// On-chip area in mm^2.
    pub area_mm2: f64,
    /// The MBVH4 collapse unit's size, work and area by part (`output = mbvh4`; its row
    /// is [`COLLAPSE_UNIT`]).
    pub collapse_unit: Option<CollapseUnitEnergy>,
}

/// The collapse unit's row by part.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CollapseUnitEnergy {
    /// Its size and work.
    #[serde(flatten)]
    pub size: CollapseUnitSize,
    /// Area of the storage, mm^2.
    pub storage_mm2: f64,
    /// Area of the FIFO, mm^2.
    pub fifo_mm2: f64,
    /// Area of the datapath (one floating-point unit per operation), mm^2.
    pub datapath_mm2: f64,
    /// Dynamic energy of the datapath's operations, mJ.
    pub datapath_mj: f64,
}

impl MergeTreeEnergy {
    /// The on-chip units: every row but the DRAM, which is last.
    pub fn on_chip(&self) -> &[UnitEnergy] {
        &self.units[..self.units.len() - 1]
    }
}

/// The energy of the build `r` at `node` under `conv`. Every memory block is a plain RAM
/// (`crate::energy::ram`).
pub fn mergetree_energy(
    r: &MergeTreeReport,
    node: Node,
    conv: &Conventions,
) -> Result<MergeTreeEnergy, EnergyError> {
    let c = &r.config;
    let seconds = r.ms * 1e-3;
    let leak = |mw: f64| mw * seconds;
    // The sort element: 32 bytes, or `point_element` in the point modes.
    let elem = c.elem_bytes() as f64;
    let share = |bytes: f64| bytes / 64.0;
    // Insertion sorters.
    let slots = ram(c.presort_slots as f64 * elem, node, conv)?;
    let presorters = c.presorters as f64;
    let busy = r.stalls.presort_busy_cycles as f64;
    let sort_dyn =
        busy * (c.presort_slots as f64 * int_add_pj(node) + slots.access_pj * share(elem));
    // Multi-merge: scratchpad and heap.
    let pad = ram(c.m_elems() as f64 * elem, node, conv)?;
    let fan_in = c.fan_in().max(2) as f64;
    let heap = ram(fan_in * HEAP_ENTRY_BYTES, node, conv)?;
    let merged = r.stalls.merge_outputs as f64;
    let loaded = r.bytes_read as f64 / elem;
    let merge_dyn = (merged + loaded) * pad.access_pj * share(elem)
        + r.stalls.heap_ops as f64
            * fan_in.log2().ceil()
            * heap.access_pj
            * share(HEAP_ENTRY_BYTES);
    // Emitter.
    let fpu = Fpu::at(node, conv.fpu);
    let nbuf = ram(c.node_buffer_bytes.max(64) as f64, node, conv)?;
    // With `output = mbvh4` the emitter's binary nodes go to the collapse unit's FIFO,
    // not the node buffer; the unit writes the wide nodes into it.
    let buffered = if c.output == OutputMode::Mbvh4 {
        0
    } else {
        r.nodes
    };
    let emit_dyn =
        r.stalls.emitter_steps as f64 * 6.0 * fpu.add_pj + buffered as f64 * nbuf.access_pj;
    // FIFOs.
    let (mut fifo_area, mut fifo_leak, mut fifo_dyn) = (0.0, 0.0, 0.0);
    for f in &r.stalls.fifos {
        let m = ram(f.capacity.max(1) as f64 * elem, node, conv)?;
        fifo_area += m.area_mm2;
        fifo_leak += m.leak_mw;
        fifo_dyn += 2.0 * f.pushes as f64 * m.access_pj * share(elem);
    }
    let unit = |name, area, dynamic_pj: f64, leak_mw: f64| {
        UnitEnergy::new(name, area, dynamic_pj * 1e-9, leak(leak_mw), seconds)
    };
    let mut parts = None;
    let collapse = match collapse_unit(r) {
        None => None,
        Some(z) => {
            let store = ram(z.storage_bytes as f64, node, conv)?;
            let fifo = ram(z.fifo_bytes as f64, node, conv)?;
            let st = r
                .mbvh4
                .as_ref()
                .and_then(|m| m.stream.clone())
                .unwrap_or_default();
            let per_wide = MBVH4_NODE_BYTES as f64 / 64.0;
            let dynamic = z.storage_accesses as f64 * store.access_pj
                + 2.0
                    * st.nodes_in as f64
                    * fifo.access_pj
                    * share(COLLAPSE_FIFO_ENTRY_BYTES as f64)
                + z.ops.energy_pj(&fpu)
                + st.nodes_written as f64 * per_wide * nbuf.access_pj;
            let u = unit(
                COLLAPSE_UNIT,
                store.area_mm2 + fifo.area_mm2 + z.datapath.area_mm2(&fpu),
                dynamic,
                store.leak_mw + fifo.leak_mw,
            );
            parts = Some(CollapseUnitEnergy {
                storage_mm2: store.area_mm2,
                fifo_mm2: fifo.area_mm2,
                datapath_mm2: z.datapath.area_mm2(&fpu),
                datapath_mj: z.ops.energy_pj(&fpu) * 1e-9,
                size: z,
            });
            Some(u)
        }
    };
    let mut units = vec![
        unit(
            "Insertion sorters",
            slots.area_mm2 * presorters,
            sort_dyn,
            slots.leak_mw * presorters,
        ),
        unit(
            "Multi-merge unit",
            pad.area_mm2 + heap.area_mm2,
            merge_dyn,
            pad.leak_mw + heap.leak_mw,
        ),
        unit("Hierarchy emitter", nbuf.area_mm2, emit_dyn, nbuf.leak_mw),
        unit("FIFOs and muxes", fifo_area, fifo_dyn, fifo_leak),
    ];
    units.extend(collapse);
    units.push(UnitEnergy::dram(&r.memory, seconds, conv.dram));
    let build_mj: f64 = units.iter().map(|u| u.total_mj).sum();
    let logic_mw: f64 = units[..units.len() - 1].iter().map(|u| u.power_mw).sum();
    let above = r
        .memory
        .energy_pj
        .as_ref()
        .map_or(0.0, |e| e.above_idle_pj())
        * 1e-9;
    Ok(MergeTreeEnergy {
        node,
        conventions: *conv,
        logic_mw,
        dram_mw: units[units.len() - 1].power_mw,
        dram_above_idle_mw: if seconds > 0.0 { above / seconds } else { 0.0 },
        build_mj,
        area_mm2: units.iter().map(|u| u.area_mm2).sum(),
        units,
        collapse_unit: parts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mergetree::tests::random_boxes;
    use crate::mergetree::{simulate, MergeTreeConfig};

    fn build(n: usize) -> MergeTreeReport {
        let cfg = MergeTreeConfig::p2();
        let port = crate::dram::open("lpddr3-1600-2x64", cfg.period_fs()).unwrap();
        simulate(&random_boxes(n, 7), &cfg, port).unwrap()
    }

    /// The multi-merge unit of preset `p2` at 28 nm under the thesis's conventions, by
    /// hand from hardware.md §3.1: the 256 KB scratchpad is the lop cache table's 42 pJ,
    /// 67 mW, 0.49 mm^2 times the 28 nm hp scratchpad-to-cache ratios at 16 KB (35.04 / 41,
    /// 7.6 / 8.3, 0.0196 / 0.06): 35.895 pJ, 61.349 mW, 0.16007 mm^2; the 256-entry heap
    /// (2 KB) is the lop table extrapolated to 2 KB (21 x (23/21)^-3 = 15.983 pJ,
    /// 4.8 x (8.9/4.8)^-3 = 0.75307 mW, 0.06 x (0.08/0.06)^-3 = 0.025313 mm^2) times the
    /// ratios at 2 KB (scratchpad 0.98727 pJ per word x 8, 1.02470 mW, 0.0028249 mm^2
    /// over the hp table's 35.540 pJ, 1.32520 mW, 0.025313 mm^2): 3.5504 pJ, 0.58232 mW,
    /// 0.0028249 mm^2. Static power 61.931 mW, area 0.16290 mm^2 (a unit slip of any
    /// power of ten fails).
    #[test]
    fn the_multi_merge_unit_by_hand() {
        let r = build(20_000);
        assert_eq!(r.config.fan_in(), 256);
        let e = mergetree_energy(&r, Node::Nm28, &Conventions::default()).unwrap();
        let mm = &e.units[1];
        assert_eq!(mm.unit, "Multi-merge unit");
        let seconds = r.ms * 1e-3;
        let close = |got: f64, want: f64| (got / want - 1.0).abs() < 1e-4;
        assert!(close(mm.static_mj / seconds, 61.931), "{mm:?}");
        assert!(close(mm.area_mm2, 0.16290), "{mm:?}");
        // Dynamic: a 32-byte element is half a 64-byte access, written once when loaded
        // and read once when merged; a heap operation touches one 8-byte entry per level
        // (8 levels for 256 queues).
        let loaded = r.bytes_read as f64 / 32.0;
        let merged = r.stalls.merge_outputs as f64;
        let want_pj =
            (loaded + merged) * 35.895 * 0.5 + r.stalls.heap_ops as f64 * 8.0 * 3.5504 * 8.0 / 64.0;
        assert!(
            close(mm.dynamic_mj, want_pj * 1e-9),
            "{mm:?} want {want_pj} pJ"
        );
    }

    fn build_with(a: &[geom::Aabb], cfg: &MergeTreeConfig) -> MergeTreeReport {
        let port = crate::dram::open("lpddr3-1600-2x64", cfg.period_fs()).unwrap();
        simulate(a, cfg, port).unwrap()
    }

    fn mbvh4(window: Option<u32>) -> MergeTreeConfig {
        MergeTreeConfig {
            output: crate::mergetree::OutputMode::Mbvh4,
            mbvh4_window: window,
            ..MergeTreeConfig::p2()
        }
    }

    /// The greedy collapse unit on 16 unit cubes (`tests_mbvh4::sixteen_cubes_by_hand`:
    /// 15 binary nodes, 5 wide nodes, 4 open subtrees at most). Storage 4 x 128 = 512 B,
    /// FIFO 16 x 64 = 1 KB; two area units and a compare, 11 adds and 6 multiplies, whose
    /// area at 28 nm is (11 x 3142 + 6 x 6460) um^2 x (28 / 40)^2 = 0.035928 mm^2; per
    /// binary node 4 storage accesses of 64 B, a FIFO push and pop and 17 FLOPs (Galal at
    /// 28 nm: 37.037 x 28 / 90 = 11.523 pJ each); per wide node two 64-byte writes into
    /// the node buffer, where the emitter now writes none of its 15 binary nodes.
    #[test]
    fn the_greedy_collapse_unit_by_hand() {
        let cubes: Vec<geom::Aabb> = (0..16)
            .map(|i| {
                let x = 2.0 * i as f32;
                geom::Aabb::new(
                    geom::Vec3::new(x, 0.0, 0.0),
                    geom::Vec3::new(x + 1.0, 1.0, 1.0),
                )
            })
            .collect();
        let conv = Conventions::default();
        let r = build_with(&cubes, &mbvh4(None));
        let plain = build_with(&cubes, &MergeTreeConfig::p2());
        let e = mergetree_energy(&r, Node::Nm28, &conv).unwrap();
        let parts = e.collapse_unit.as_ref().unwrap();
        let z = &parts.size;
        assert_eq!((z.storage_bytes, z.fifo_bytes), (512, 1024));
        assert_eq!(
            z.datapath,
            Flops {
                adds: 11.0,
                muls: 6.0
            }
        );
        assert_eq!(
            z.ops,
            Flops {
                adds: 165.0,
                muls: 90.0
            }
        );
        assert_eq!(z.storage_accesses, 60);
        let close = |got: f64, want: f64| (got / want - 1.0).abs() < 1e-4;
        let u = &e.units[4];
        assert_eq!(u.unit, COLLAPSE_UNIT);
        let (store, fifo) = (
            ram(512.0, Node::Nm28, &conv).unwrap(),
            ram(1024.0, Node::Nm28, &conv).unwrap(),
        );
        let nbuf = ram(2048.0, Node::Nm28, &conv).unwrap();
        assert!(
            close(u.area_mm2, store.area_mm2 + fifo.area_mm2 + 0.035928),
            "{u:?}"
        );
        assert!(close(parts.datapath_mm2, 0.035928));
        assert_eq!(
            (parts.storage_mm2, parts.fifo_mm2),
            (store.area_mm2, fifo.area_mm2)
        );
        assert!(close(parts.datapath_mj, 255.0 * 11.523e-9));
        let want_pj =
            60.0 * store.access_pj + 30.0 * fifo.access_pj + 255.0 * 11.523 + 10.0 * nbuf.access_pj;
        assert!(
            close(u.dynamic_mj, want_pj * 1e-9),
            "{u:?} want {want_pj} pJ"
        );
        let seconds = r.ms * 1e-3;
        assert!(
            close(u.static_mj / seconds, store.leak_mw + fifo.leak_mw),
            "{u:?}"
        );
        // The emitter's row loses its 15 binary-node writes into the node buffer.
        let p = mergetree_energy(&plain, Node::Nm28, &conv).unwrap();
        assert_eq!(r.stalls.emitter_steps, plain.stalls.emitter_steps);
        assert!(close(
            p.units[2].dynamic_mj - e.units[2].dynamic_mj,
            15.0 * nbuf.access_pj * 1e-9
        ));
    }

    /// The collapse unit's row exists only with `output = mbvh4`, sits before the DRAM,
    /// counts in the on-chip totals, and grows with the window (storage, datapath work,
    /// area and energy), the greedy rule below every window.
    #[test]
    fn the_collapse_unit_only_in_mbvh4_and_growing_with_the_window() {
        use crate::mergetree::OutputMode;
        let a = random_boxes(12_000, 5);
        let conv = Conventions::default();
        for output in [
            OutputMode::Bvh,
            OutputMode::Mbvh4Collapse,
            OutputMode::CbvhStream,
            OutputMode::CbvhTopdown,
        ] {
            let r = build_with(
                &a,
                &MergeTreeConfig {
                    output,
                    mbvh4_window: Some(2),
                    ..MergeTreeConfig::p2()
                },
            );
            let e = mergetree_energy(&r, Node::Nm28, &conv).unwrap();
            let names: Vec<&str> = e.units.iter().map(|u| u.unit).collect();
            assert_eq!(names, UNITS, "{output:?}");
            assert!(e.collapse_unit.is_none() && collapse_unit(&r).is_none());
        }
        let mut last: Option<(MergeTreeEnergy, u64)> = None;
        for window in [None, Some(0), Some(2), Some(4)] {
            let r = build_with(&a, &mbvh4(window));
            let e = mergetree_energy(&r, Node::Nm28, &conv).unwrap();
            let names: Vec<&str> = e.units.iter().map(|u| u.unit).collect();
            assert_eq!(names[..4], UNITS[..4]);
            assert_eq!(names[4..], [COLLAPSE_UNIT, "DRAM"], "{window:?}");
            let logic: f64 = e.on_chip().iter().map(|u| u.power_mw).sum();
            assert!((logic - e.logic_mw).abs() < 1e-9 * logic);
            let sum: f64 = e.units.iter().map(|u| u.total_mj).sum();
            assert!((sum - e.build_mj).abs() <= 1e-12 * e.build_mj);
            assert_eq!(e.dram_mw, e.units[5].power_mw);
            let z = e.collapse_unit.clone().unwrap().size;
            let st = r.mbvh4.as_ref().unwrap().stream.clone().unwrap();
            match window {
                None => assert_eq!(z.storage_bytes, st.max_open * 128),
                Some(_) => {
                    assert_eq!(z.storage_bytes, st.max_window_bytes);
                    assert!(st.max_window_bytes >= st.max_treelet_nodes * 64);
                }
            }
            let u = &e.units[4];
            assert!(u.area_mm2 > 0.0 && u.dynamic_mj > 0.0 && u.static_mj > 0.0);
            if let Some((prev, prev_bytes)) = &last {
                let p = &prev.units[4];
                assert!(z.storage_bytes > *prev_bytes, "{window:?}");
                assert!(u.area_mm2 > p.area_mm2, "{window:?}: {u:?} {p:?}");
                assert!(u.dynamic_mj > p.dynamic_mj, "{window:?}");
                assert!(u.total_mj > p.total_mj, "{window:?}");
                assert!(e.area_mm2 > prev.area_mm2, "{window:?}");
            }
            last = Some((e, z.storage_bytes));
        }
    }

    #[test]
    fn the_breakdown_adds_up_dram_dominates_and_energy_grows_with_the_scene() {
        let full = Conventions {
            dram: crate::energy::DramConvention::Full,
            ..Conventions::default()
        };
        let small = mergetree_energy(&build(20_000), Node::Nm28, &full).unwrap();
        let big = mergetree_energy(&build(80_000), Node::Nm28, &full).unwrap();
        for e in [&small, &big] {
            let names: Vec<&str> = e.units.iter().map(|u| u.unit).collect();
            assert_eq!(names, UNITS);
            let sum: f64 = e.units.iter().map(|u| u.total_mj).sum();
            assert!((sum - e.build_mj).abs() <= 1e-12 * e.build_mj);
            let logic: f64 = e.units[..4].iter().map(|u| u.power_mw).sum();
            assert!((logic - e.logic_mw).abs() < 1e-9);
            assert!(e
                .units
                .iter()
                .all(|u| u.dynamic_mj >= 0.0 && u.static_mj >= 0.0));
            // [P2] §6.3.1's finding: the DRAM interface draws most of the power.
            assert!(e.dram_mw > 2.0 * e.logic_mw, "{e:?}");
            assert!(e.dram_above_idle_mw < e.dram_mw);
            // The 256 KB scratchpad is the largest block.
            assert!(e.units[1].area_mm2 > e.units[0].area_mm2);
        }
        assert!(big.build_mj > 3.0 * small.build_mj);
        assert_eq!(small.area_mm2, big.area_mm2, "same hardware");
        // A smaller node: less area and logic power.
        let r = build(20_000);
        // A larger node: more area, and more logic power with hp cells (CACTI's lop cells
        // leak anomalously little at 45 nm, hardware.md §3.1, so not with those).
        let hp = Conventions {
            cell: crate::energy::Cell::Hp,
            ..full
        };
        let e45 = mergetree_energy(&r, Node::Nm45, &hp).unwrap();
        let e28 = mergetree_energy(&r, Node::Nm28, &hp).unwrap();
        assert!(e45.area_mm2 > e28.area_mm2 && e45.logic_mw > e28.logic_mw);
        // The thesis's convention: the DRAM row is the energy above idle.
        let thesis = mergetree_energy(&r, Node::Nm28, &Conventions::default()).unwrap();
        assert!((thesis.dram_mw - thesis.dram_above_idle_mw).abs() < 1e-9 * thesis.dram_mw);
        assert!((thesis.dram_mw - small.dram_above_idle_mw).abs() < 1e-9 * thesis.dram_mw);
    }
}
