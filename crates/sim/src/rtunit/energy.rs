//! Energy and area of the accelerator, counted as \[P4\] §3.2 counts them: the
//! floating-point units and memory blocks (caches, stacks, FIFOs) of each unit, SRAM
//! figures from CACTI, FPU figures per operation, DRAM from DRAMPower's formulas; a unit
//! spends dynamic energy only for the work it does (idle units are clock gated) and every
//! SRAM leaks for the whole run. Control logic, clock trees and pipeline registers are not
//! counted (\[P4\] §3.2: "they add a similar margin to both configurations"), nor FPU
//! leakage (no source gives it). The component figures are `crate::energy`'s.
//!
//! Datapaths (FLOPs per operation, Arbor's count of the textbook forms):
//! - slab test of one box: 6 subtractions and 6 multiplies (the plane distances), 6
//!   compares to order each axis's pair, 6 for the max of the entries and min of the exits
//!   with the ray's range, 1 for the final test: 19 adds, 6 multiplies;
//! - the MBVH4 unit's sorting network: 5 compares per visit (\[P4\] Fig. 4);
//! - the CBVH unit's decoder: 6 integer-to-float conversions and adds per box, counted
//!   as 6 adds;
//! - Wald's (2004) triangle test on 48-byte triangles: distance numerator and denominator
//!   (4 multiplies, 5 adds), the division (`RtConfig::ist_div_flops`, counted as
//!   multiplies: 11 by Markstein's method as \[P4\] §3.2 says, 3 for a reciprocal as
//!   \[P2\] §6.4 says), the hit point's two coordinates (2 multiplies, 2 adds), the two
//!   barycentrics (4 multiplies, 4 adds), and 6 compares (distance range, both
//!   barycentrics, their sum): 10 multiplies and 17 adds besides the division.
//!
//! Memory blocks: the caches are `crate::energy::cache`s (a 128-byte MBVH4 line read
//! through a port of two 512-bit widths), the stacks and FIFOs plain `crate::energy::ram`s.
//! Memory entries: a stack entry holds a child reference (8 bytes), plus its distance (4)
//! with a distance stack; a FIFO entry holds a ray record of 48 bytes (origin, direction,
//! range, closest hit and its primitive, node pointer and slot). An access reads or writes
//! one entry: its energy is CACTI's 64-byte access scaled by the entry's share of 64 bytes.

use serde::Serialize;

use super::{RtReport, TreeKind};
use crate::energy::{cache, ram, Conventions, EnergyError, Flops, Fpu, Node, UnitEnergy};

/// Bytes of a ray record in a FIFO.
pub const RAY_RECORD_BYTES: f64 = 48.0;

/// FLOPs of one slab test.
pub const BOX_TEST: Flops = Flops {
    adds: 19.0,
    muls: 6.0,
};
/// FLOPs of the MBVH4 sorting network per visit.
pub const SORT_NETWORK: Flops = Flops {
    adds: 5.0,
    muls: 0.0,
};
/// FLOPs of the CBVH decoder per box.
pub const DECODE_BOX: Flops = Flops {
    adds: 6.0,
    muls: 0.0,
};
/// FLOPs of Wald's triangle test besides its division.
pub const TRIANGLE_TEST_NO_DIV: Flops = Flops {
    adds: 17.0,
    muls: 10.0,
};

/// FLOPs of Wald's triangle test with a division of `div_flops`.
pub fn triangle_test(div_flops: u32) -> Flops {
    TRIANGLE_TEST_NO_DIV.plus(Flops {
        adds: 0.0,
        muls: div_flops as f64,
    })
}

/// Where energy and area are counted: \[P4\] Table 1's columns.
pub const UNITS: [&str; 6] = ["TRV", "IST", "stack", "cache", "FIFO", "DRAM"];

/// The accelerator's energy over a run, and per frame.
#[derive(Clone, Debug, Serialize)]
pub struct AcceleratorEnergy {
    /// Process node of the on-chip figures.
    pub node: Node,
    /// The conventions of the figures.
    pub conventions: Conventions,
    /// Per unit, in [`UNITS`] order.
    pub units: Vec<UnitEnergy>,
    /// Area of the on-chip units in mm^2.
    pub area_mm2: f64,
    /// Energy of the run in mJ (the breakdown's sum).
    pub run_mj: f64,
    /// Mean power in mW.
    pub power_mw: f64,
    /// Energy of one frame in mJ: the run's (whole frames) or the run's per simulated ray
    /// times the frame's estimated rays (sampled runs).
    pub frame_mj: f64,
    /// Sampled runs: the relative standard error of `frame_mj` from sampling
    /// (`super::sampling::frame_energy_rel_se`); 0 for a whole frame.
    pub frame_mj_rel_se: f64,
    /// Sampled runs: each measurement window's pixels and share of the run's energy in
    /// mJ (`super::sampling::window_energy`), for errors of ratios between runs.
    #[serde(skip)]
    pub window_mj: Vec<(u64, f64)>,
    /// DRAM energy of the run above an idle memory's, in mJ (\[P2\] §6.2's convention).
    pub dram_above_idle_mj: f64,
    /// Million rays per second per mm^2.
    pub mrps_per_mm2: f64,
}

/// The energy and area of the accelerator of run `r` at `node` under `conv`.
pub fn accelerator_energy(
    r: &RtReport,
    node: Node,
    conv: &Conventions,
) -> Result<AcceleratorEnergy, EnergyError> {
    let c = &r.config;
    let fpu = Fpu::at(node, conv.fpu);
    let ist_path = triangle_test(c.ist_div_flops);
    let trvs = c.trv_units as f64;
    let seconds = r.seconds;
    // Datapaths: one pipelined unit per operation.
    let width = r.tree.width() as f64;
    let mut trv_path = BOX_TEST.times(width);
    match r.tree {
        TreeKind::Mbvh4 => trv_path = trv_path.plus(SORT_NETWORK),
        TreeKind::Cbvh => trv_path = trv_path.plus(DECODE_BOX.times(width)),
        TreeKind::Bvh2 => {}
    }
    let visits = r.node_visits as f64;
    let trv_dyn = BOX_TEST.times(r.box_tests as f64).energy_pj(&fpu)
        + match r.tree {
            TreeKind::Mbvh4 => SORT_NETWORK.times(visits).energy_pj(&fpu),
            TreeKind::Cbvh => DECODE_BOX.times(r.box_tests as f64).energy_pj(&fpu),
            TreeKind::Bvh2 => 0.0,
        };
    let ist_dyn = ist_path.times(r.triangle_tests as f64).energy_pj(&fpu);
    // Stacks: one SRAM per TRV unit.
    let distance = c.uses_distance_stack(r.tree);
    let entry = 8.0 + if distance { 4.0 } else { 0.0 };
    let stack_bytes = c.stacks_per_trv as f64 * c.stack_entries as f64 * entry;
    let stack = ram(stack_bytes, node, conv)?;
    let stack_ops = (super::unit_counter(&r.units, "trv", "pushes")
        + super::unit_counter(&r.units, "trv", "pops")) as f64;
    let stack_dyn = stack_ops * stack.access_pj * entry / 64.0;
    // Caches: the port reads a line (64 or 128 bytes).
    let line = c.node_line(r.tree) as f64;
    let port = ((line / 64.0).ceil() as u32).max(1);
    let l1 = cache(c.l1_bytes as f64, port, node, conv)?;
    let l2 = cache(c.l2_bytes as f64, port, node, conv)?;
    let banks = c.prim_banks.max(1) as f64;
    let bank = cache(c.prim_bytes as f64 / banks, 1, node, conv)?;
    let stats = |name: &str| r.caches.iter().find(|x| x.name == name).map(|x| &x.stats);
    let touches = |name: &str| stats(name).map_or(0.0, |s| (s.line_accesses + s.fills) as f64);
    let cache_dyn = touches("l1") * l1.access_pj
        + touches("node") * l2.access_pj
        + touches("primitive") * bank.access_pj;
    // FIFOs: each push writes and each pop reads a ray record.
    let mut fifo_area = 0.0;
    let mut fifo_leak = 0.0;
    let mut fifo_dyn = 0.0;
    for f in &r.fifos {
        let m = ram(f.capacity.max(1) as f64 * RAY_RECORD_BYTES, node, conv)?;
        fifo_area += m.area_mm2 * f.count as f64;
        fifo_leak += m.leak_mw * f.count as f64;
        fifo_dyn += 2.0 * f.pushes as f64 * m.access_pj * RAY_RECORD_BYTES / 64.0;
    }
    let leak_mj = |mw: f64| mw * seconds; // mW x s = mJ
    let unit = |name, area, dynamic_mj, static_mj| {
        UnitEnergy::new(name, area, dynamic_mj, static_mj, seconds)
    };
    let dram = r.memory.energy_pj.as_ref();
    let units = vec![
        unit("TRV", trv_path.area_mm2(&fpu) * trvs, trv_dyn * 1e-9, 0.0),
        unit("IST", ist_path.area_mm2(&fpu), ist_dyn * 1e-9, 0.0),
        unit(
            "stack",
            stack.area_mm2 * trvs,
            stack_dyn * 1e-9,
            leak_mj(stack.leak_mw * trvs),
        ),
        unit(
            "cache",
            l1.area_mm2 * trvs + l2.area_mm2 + bank.area_mm2 * banks,
            cache_dyn * 1e-9,
            leak_mj(l1.leak_mw * trvs + l2.leak_mw + bank.leak_mw * banks),
        ),
        unit("FIFO", fifo_area, fifo_dyn * 1e-9, leak_mj(fifo_leak)),
        UnitEnergy::dram(&r.memory, seconds, conv.dram),
    ];
    let run_mj: f64 = units.iter().map(|u| u.total_mj).sum();
    let area_mm2: f64 = units.iter().map(|u| u.area_mm2).sum();
    let frame_mj = if r.sample > 1 {
        let frame_rays =
            r.rays as f64 * (r.width as f64 * r.height as f64) / r.pixels.max(1) as f64;
        run_mj / r.detailed_rays.max(1) as f64 * frame_rays
    } else {
        run_mj
    };
    // What drives each unit's energy, for the frame energy's sampling error.
    let dynamic = |name: &str| -> f64 {
        units
            .iter()
            .filter(|u| u.unit == name)
            .map(|u| u.dynamic_mj)
            .sum()
    };
    let drivers = super::sampling::EnergyDrivers {
        visits_mj: dynamic("TRV") + dynamic("stack") + dynamic("cache") + dynamic("FIFO"),
        tests_mj: dynamic("IST"),
        bytes_mj: dynamic("DRAM"),
        time_mj: units.iter().map(|u| u.static_mj).sum(),
    };
    let window_mj = super::sampling::window_energy(&r.sampling_windows, &drivers);
    let frame_mj_rel_se = super::sampling::frame_energy_rel_se(&window_mj, r.sample).unwrap_or(0.0);
    Ok(AcceleratorEnergy {
        node,
        conventions: *conv,
        frame_mj_rel_se,
        window_mj,
        area_mm2,
        power_mw: if seconds > 0.0 { run_mj / seconds } else { 0.0 },
        run_mj,
        frame_mj,
        dram_above_idle_mj: dram.map_or(0.0, |e| e.above_idle_pj()) * 1e-9,
        mrps_per_mm2: if area_mm2 > 0.0 {
            r.mrps / area_mm2
        } else {
            0.0
        },
        units,
    })
}

#[cfg(test)]
mod tests {
    use super::super::{build_tree, run, RayMode, RtConfig, TreeKind, Workload};
    use geom::{Triangle, Vec3};
    use trace::PinholeCamera;

    /// One camera ray over one triangle through the BVH2 unit at 45 nm with the thesis's
    /// conventions, every figure computed by hand from the component tables (a unit slip
    /// of any power of ten fails):
    /// - a FLOP: 37.037 pJ x 45 / 90 = 18.519 pJ; a slab test (25 FLOPs) 462.96 pJ, the
    ///   triangle test (27 + 11 FLOPs) 703.70 pJ;
    /// - the stack RAM (32 x 64 x 8 B = 16 KB, 45 nm lop): the cache table's 52 pJ,
    ///   0.3 mW, 0.16 mm^2 times the 28 nm hp scratchpad-to-cache ratios at 16 KB
    ///   (35.04 / 41, 7.6 / 8.3, 0.0196 / 0.06): 44.44 pJ per 64 B, 0.2747 mW,
    ///   0.05227 mm^2 per TRV;
    /// - caches (45 nm lop): 4 L1s of 16 KB (0.16 mm^2, 0.3 mW), the 128 KB node cache
    ///   (0.50 mm^2, 1.9 mW), two 64 KB primitive banks (0.31 mm^2, 1.0 mW): 1.76 mm^2,
    ///   5.1 mW.
    #[test]
    fn one_ray_by_hand() {
        let tri = Triangle::new(
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        );
        let cam = PinholeCamera::new(
            &scene::Camera {
                eye: Vec3::new(0.0, 0.0, 5.0),
                target: Vec3::ZERO,
                up: Vec3::Y,
                vfov_deg: 30.0,
            },
            1,
            1,
        )
        .unwrap();
        let tris = [tri];
        let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
        let mut cfg = RtConfig::default();
        cfg.set("dram", "simple:bw=12.8e9,lat=100").unwrap();
        let work = Workload {
            triangles: &tris,
            camera: &cam,
            rays: RayMode::Primary,
            bounces: 0,
            seed: 1,
            sample: 1,
            progress: None,
        };
        let r = run(&tree, &work, &cfg).unwrap();
        assert!(r.hits_match_software);
        let e = r.energy.as_ref().unwrap();
        let unit = |name: &str| e.units.iter().find(|u| u.unit == name).unwrap();
        let close = |got: f64, want: f64| (got / want - 1.0).abs() < 1e-4;
        assert_eq!(r.triangle_tests, 1);
        assert!(r.box_tests >= 1);
        let trv = unit("TRV");
        assert!(
            close(trv.dynamic_mj, r.box_tests as f64 * 462.963e-9),
            "{trv:?}"
        );
        let ist = unit("IST");
        assert!(close(ist.dynamic_mj, 703.704e-9), "{ist:?}");
        let seconds = r.seconds;
        let stack = unit("stack");
        assert!(
            close(stack.static_mj, 4.0 * 0.274699 * seconds),
            "{stack:?}"
        );
        assert!(close(stack.area_mm2, 4.0 * 0.0522667), "{stack:?}");
        let ops = (super::super::unit_counter(&r.units, "trv", "pushes")
            + super::super::unit_counter(&r.units, "trv", "pops")) as f64;
        if ops > 0.0 {
            // An 8-byte entry: 44.441 pJ x 8 / 64.
            assert!(
                close(stack.dynamic_mj, ops * 5.555125e-9),
                "{stack:?} {ops}"
            );
        } else {
            assert_eq!(stack.dynamic_mj, 0.0);
        }
        let cache = unit("cache");
        assert!(close(cache.area_mm2, 1.76), "{cache:?}");
        assert!(close(cache.static_mj, 5.1 * seconds), "{cache:?}");
        // No DRAM energy model on the simple memory.
        assert_eq!(unit("DRAM").total_mj, 0.0);
    }
}
