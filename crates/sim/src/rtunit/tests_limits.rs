//! The memory's throughput limit seen from the accelerator: a run that misses in every
//! cache is bound by DRAM row activations, which the four-activate window (tFAW) caps at
//! four per window per channel.

use super::*;
use scene::LoadOptions;

/// `key = value` of a DRAMsim3 configuration text, as an integer.
fn ini_value(ini: &str, key: &str) -> u64 {
    ini.lines()
        .filter_map(|l| l.split_once('='))
        .find(|(k, _)| k.trim() == key)
        .and_then(|(_, v)| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("{key} in the configuration"))
}

/// Diffuse paths through caches far too small for the scene, with many misses in flight:
/// the activations per DRAM cycle come near the tFAW ceiling (channels x 4 / tFAW: 2 x 4
/// / 40 = 0.2 on `lpddr3-1600-2x32`, whose channels interleave every burst), never pass
/// it, and do not rise with more misses in flight; with caches that hold the scene the
/// same rays activate less than half as often (first touches remain).
#[test]
fn a_thrashing_run_is_bound_at_the_four_activate_window() {
    let s = scene::open("proc:hairball?n=20000&seed=4", &LoadOptions::default()).unwrap();
    let tris: Vec<Triangle> = s.mesh_at(0.0).unwrap().triangles_iter().collect();
    let cam = PinholeCamera::new(&s.info().camera, 48, 32).unwrap();
    let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
    let sys = crate::dram::dramsim3::SYSTEMS
        .iter()
        .find(|c| c.name == "lpddr3-1600-2x32")
        .unwrap();
    let ceiling = ini_value(sys.ini, "channels") as f64 * 4.0 / ini_value(sys.ini, "tFAW") as f64;
    assert!((ceiling - 0.2).abs() < 1e-12);
    let work = Workload {
        triangles: &tris,
        camera: &cam,
        rays: RayMode::Diffuse,
        bounces: 4,
        seed: 1,
        sample: 1,
        progress: None,
    };
    let rate = |cfg: &RtConfig| {
        let r = run(&tree, &work, cfg).unwrap();
        assert!(r.hits_match_software);
        (
            r.memory.act_commands as f64 / r.memory.dram_cycles as f64,
            r.memory.act_commands,
        )
    };
    let mut thrash = RtConfig::default();
    for (k, v) in [
        ("l1_bytes", "1024"),
        ("l2_bytes", "2048"),
        ("prim_bytes", "2048"),
        ("mshrs", "64"),
    ] {
        thrash.set(k, v).unwrap();
    }
    let (bound, acts) = rate(&thrash);
    assert!(bound <= ceiling * (1.0 + 1e-9), "{bound} above {ceiling}");
    // Bound: within the ramp at the start and the tail at the end (and refreshes), the
    // run activates at 86% of the ceiling on average, and four times the misses in
    // flight do not raise it.
    assert!(bound >= 0.8 * ceiling, "{bound}: not DRAM bound");
    let mut more = thrash.clone();
    more.set("mshrs", "256").unwrap();
    let (more, _) = rate(&more);
    assert!(more <= bound * 1.02, "{more} against {bound}");
    let mut roomy = RtConfig::default();
    for (k, v) in [("l2_bytes", "4194304"), ("prim_bytes", "4194304")] {
        roomy.set(k, v).unwrap();
    }
    let (_, roomy_acts) = rate(&roomy);
    assert!(roomy_acts * 2 < acts, "{roomy_acts} against {acts}");
}
