//! Tests of the accelerator model: functional equality with the software tracer for every
//! tree and ray kind, skipping equal to stepping every cycle, determinism, hand-derived
//! cycle counts, FIFO sizing, and hostile configurations.

use super::*;
use scene::LoadOptions;

/// A procedural scene's triangles and its camera at `w` x `h`.
fn scene(spec: &str, w: u32, h: u32) -> (Vec<Triangle>, PinholeCamera) {
    let s = scene::open(spec, &LoadOptions::default()).expect("procedural scene");
    let mesh = s.mesh_at(0.0).expect("mesh");
    let tris: Vec<Triangle> = mesh.triangles_iter().collect();
    let cam = PinholeCamera::new(&s.info().camera, w, h).expect("camera");
    (tris, cam)
}

fn work<'a>(tris: &'a [Triangle], cam: &'a PinholeCamera, rays: RayMode) -> Workload<'a> {
    Workload {
        triangles: tris,
        camera: cam,
        rays,
        bounces: 4,
        seed: 1,
        sample: 1,
        progress: None,
    }
}

#[test]
fn hits_equal_the_software_tracer_for_every_tree_and_ray_kind() {
    let (tris, cam) = scene("proc:hairball?n=2000&seed=3", 48, 32);
    for kind in [TreeKind::Bvh2, TreeKind::Mbvh4, TreeKind::Cbvh] {
        let tree = build_tree(kind, &tris).unwrap();
        for rays in [RayMode::Primary, RayMode::Diffuse] {
            let r = run(&tree, &work(&tris, &cam, rays), &RtConfig::default()).unwrap();
            assert!(
                r.hits_match_software,
                "{kind:?} {rays:?}: {} mismatches",
                r.mismatches
            );
            assert!(r.rays >= 48 * 32);
            assert!(r.cycles > 0 && r.dram_bytes_read > 0);
        }
    }
}

/// A scene for the stress cases: big enough for misses, small enough for every-cycle runs.
fn small() -> (Vec<Triangle>, PinholeCamera) {
    scene("proc:city?n=3000&seed=2", 32, 24)
}

#[test]
fn skipping_equals_stepping_every_cycle() {
    let (tris, cam) = small();
    for kind in [TreeKind::Bvh2, TreeKind::Mbvh4, TreeKind::Cbvh] {
        let tree = build_tree(kind, &tris).unwrap();
        let w = work(&tris, &cam, RayMode::Diffuse);
        let cfg = RtConfig {
            l1_bytes: 1024,
            l2_bytes: 4096,
            prim_bytes: 2048,
            ..RtConfig::default()
        };
        let a = run_with(&tree, &w, &cfg, true).unwrap();
        let b = run_with(&tree, &w, &cfg, false).unwrap();
        assert_eq!(a.cycles, b.cycles, "{kind:?}");
        assert_eq!(a.memory, b.memory);
        assert_eq!(
            serde_json::to_value(&a.units).unwrap(),
            serde_json::to_value(&b.units).unwrap()
        );
        assert_eq!(
            serde_json::to_value(&a.caches).unwrap(),
            serde_json::to_value(&b.caches).unwrap()
        );
        assert!(a.hits_match_software && b.hits_match_software);
        assert!(
            a.trv_loops > 0 && a.ist_loops > 0,
            "the small caches make rays loop"
        );
    }
}

#[test]
fn runs_are_deterministic() {
    let (tris, cam) = small();
    let tree = build_tree(TreeKind::Mbvh4, &tris).unwrap();
    let w = work(&tris, &cam, RayMode::Diffuse);
    let a = run(&tree, &w, &RtConfig::default()).unwrap();
    let b = run(&tree, &w, &RtConfig::default()).unwrap();
    let strip = |r: &RtReport| {
        let mut v = serde_json::to_value(r).unwrap();
        v.as_object_mut().unwrap().remove("wall_seconds");
        v
    };
    assert_eq!(strip(&a), strip(&b));
}

#[test]
fn hostile_but_valid_configurations_still_give_the_software_hits() {
    let (tris, cam) = small();
    let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
    let w = work(&tris, &cam, RayMode::Diffuse);
    let mut one_slot = RtConfig::default();
    one_slot.set("stacks_per_trv", "1").unwrap();
    one_slot.set("trv_units", "1").unwrap();
    let mut tiny = RtConfig::default();
    for (k, v) in [
        ("fifo_entries", "1"),
        ("mshrs", "2"),
        ("stacks_per_trv", "4"),
        ("l1_bytes", "1024"),
        ("l2_bytes", "1024"),
        ("prim_bytes", "1024"),
        ("ist_rays", "1"),
        ("dram", "simple:bw=1e9,lat=200,queue=1"),
    ] {
        tiny.set(k, v).unwrap();
    }
    for cfg in [one_slot, tiny] {
        let r = run(&tree, &w, &cfg).unwrap();
        assert!(r.hits_match_software, "{cfg:?}");
        assert_eq!(r.pixels, 32 * 24);
    }
}

#[test]
fn bad_options_are_one_line_errors() {
    let mut c = RtConfig::default();
    let e = c.set("l1_bytes", "0").unwrap_err().to_string();
    assert!(e.contains("l1_bytes") && e.contains("1..="), "{e}");
    assert!(c
        .set("no_such_key", "1")
        .unwrap_err()
        .to_string()
        .contains("known:"));
    assert!(c
        .set_pair("l2_bytes")
        .unwrap_err()
        .to_string()
        .contains("KEY=VALUE"));
    c.set("l1_bytes", "1000").unwrap();
    let e = c.validate(TreeKind::Bvh2).unwrap_err().to_string();
    assert!(e.contains("l1_bytes = 1000"), "{e}");
    let mut c = RtConfig::default();
    c.set("node_line_bytes", "64").unwrap();
    assert!(c
        .validate(TreeKind::Mbvh4)
        .unwrap_err()
        .to_string()
        .contains("128-byte"));
    let (tris, cam) = scene("proc:city?n=200&seed=2", 4, 4);
    let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
    let mut w = work(&tris, &cam, RayMode::Diffuse);
    w.sample = 0;
    assert!(run(&tree, &w, &RtConfig::default())
        .unwrap_err()
        .to_string()
        .contains("sample"));
    w.sample = 1;
    w.bounces = 1000;
    assert!(run(&tree, &w, &RtConfig::default())
        .unwrap_err()
        .to_string()
        .contains("bounces"));
    let huge = PinholeCamera::new(
        &scene::Camera {
            eye: geom::Vec3::new(0.0, 0.0, 5.0),
            target: geom::Vec3::ZERO,
            up: geom::Vec3::Y,
            vfov_deg: 45.0,
        },
        65_536,
        65_536,
    )
    .unwrap();
    let w = work(&tris, &huge, RayMode::Primary);
    let e = run(&tree, &w, &RtConfig::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("65536x65536") && !e.contains('\n'), "{e}");
    assert!(build_tree(TreeKind::Bvh2, &[]).is_err());
    let mut c = RtConfig::default();
    c.set("dram", "no-such-memory").unwrap();
    let w = work(&tris, &cam, RayMode::Primary);
    assert!(run(&tree, &w, &c)
        .unwrap_err()
        .to_string()
        .contains("unknown memory system"));
}

#[test]
fn a_stack_too_small_is_reported_not_overrun() {
    let (tris, cam) = small();
    let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
    let w = work(&tris, &cam, RayMode::Primary);
    let ok = run(&tree, &w, &RtConfig::default()).unwrap();
    assert!(ok.max_stack_depth >= 2 && ok.max_stack_depth <= 64);
    let mut c = RtConfig::default();
    c.set("stack_entries", &(ok.max_stack_depth - 1).to_string())
        .unwrap();
    match run(&tree, &w, &c) {
        Err(RtError::StackOverflow { depth, entries, .. }) => {
            assert_eq!(depth, ok.max_stack_depth);
            assert_eq!(entries as usize, ok.max_stack_depth - 1);
        }
        other => panic!("expected a stack overflow, got {other:?}"),
    }
}

#[test]
fn a_run_past_its_cycle_limit_stops_with_an_error() {
    let (tris, cam) = small();
    let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
    let w = work(&tris, &cam, RayMode::Primary);
    let mut c = RtConfig::default();
    c.set("max_cycles", "500").unwrap();
    let e = run(&tree, &w, &c).unwrap_err();
    assert!(matches!(e, RtError::Kernel(_)), "{e}");
}

#[test]
fn rays_that_never_finish_are_reported_as_a_livelock() {
    let (tris, cam) = small();
    let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
    let w = work(&tris, &cam, RayMode::Primary);
    let mut c = RtConfig::default();
    // The first ray needs two DRAM round trips, far more than 50 cycles.
    c.set("livelock_cycles", "50").unwrap();
    let e = run(&tree, &w, &c).unwrap_err().to_string();
    assert!(
        e.contains("no ray finished") && e.contains("livelock"),
        "{e}"
    );
    assert!(c
        .set("mshrs", "1")
        .unwrap_err()
        .to_string()
        .contains("2..="));
}

#[test]
fn fifo_sizing_shrinks_to_the_power_of_two_above_the_high_water() {
    assert_eq!(sized_fifo(0, 32), 1);
    assert_eq!(sized_fifo(1, 32), 1);
    assert_eq!(sized_fifo(5, 32), 8);
    assert_eq!(sized_fifo(8, 32), 8);
    assert_eq!(sized_fifo(32, 32), 32);
    let (tris, cam) = small();
    let tree = build_tree(TreeKind::Mbvh4, &tris).unwrap();
    let w = work(&tris, &cam, RayMode::Diffuse);
    let (sized, first, second) = size_fifos(&tree, &w, &RtConfig::default()).unwrap();
    for (c, f) in first.fifos.iter().enumerate() {
        assert_eq!(f.capacity, 32);
        let cap = sized.fifo_capacity(c);
        assert!(
            cap.is_power_of_two() && cap >= f.high_water.max(1) && cap < 2 * f.high_water.max(1)
        );
        assert_eq!(second.fifos[c].capacity, cap);
    }
    assert!(second.hits_match_software);
}

#[test]
fn the_sampling_plan_times_one_chunk_in_k_with_lead_tiles_before_each() {
    let p = plan(20, 10, 1);
    assert!(p.tiles.iter().all(|t| t.1 == TileMode::Timed));
    let mut sorted = p.pixels.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, (0..200).collect::<Vec<_>>(), "every pixel once");
    assert_eq!(sampled_pixels(20, 10, 1), p.pixels);
    // 40 x 3 tiles of 8x8 (the last tile row clipped to 4 pixels): 120 tiles, chunks 0..8
    // of 16 tiles (chunk 7 holds the last 8 tiles).
    let (w, h) = (320, 20);
    for k in [2, 3, 8, 16] {
        let p = plan(w, h, k);
        let mut sorted = p.pixels.clone();
        sorted.sort_unstable();
        assert_eq!(
            sorted,
            (0..w * h).collect::<Vec<_>>(),
            "k = {k}: every pixel once"
        );
        let timed: Vec<usize> = (0..p.tiles.len())
            .filter(|&i| p.tiles[i].1 == TileMode::Timed)
            .collect();
        let chunks: std::collections::BTreeSet<usize> = timed.iter().map(|t| t / 16).collect();
        // Exactly one chunk of each run of k chunks, the last (maybe short) run included,
        // and every tile of a timed chunk timed.
        let runs: Vec<usize> = chunks.iter().map(|c| c / k as usize).collect();
        assert_eq!(
            runs,
            (0..8usize.div_ceil(k as usize)).collect::<Vec<_>>(),
            "k = {k}"
        );
        for c in &chunks {
            let tiles = (c * 16..(c * 16 + 16).min(120)).collect::<Vec<_>>();
            assert!(
                tiles.iter().all(|t| timed.contains(t)),
                "k = {k}: chunk {c}"
            );
        }
        // The lead tiles are the SAMPLE_LEAD_TILES untimed tiles before each timed run.
        for i in 0..p.tiles.len() {
            let next_timed = (i + 1..p.tiles.len()).find(|&j| p.tiles[j].1 == TileMode::Timed);
            let lead = p.tiles[i].1 != TileMode::Timed
                && next_timed.is_some_and(|j| {
                    j - i <= SAMPLE_LEAD_TILES as usize
                        && (i + 1..j).all(|m| p.tiles[m].1 != TileMode::Timed)
                });
            assert_eq!(p.tiles[i].1 == TileMode::Lead, lead, "k = {k}, tile {i}");
        }
        assert_eq!(
            sampled_pixels(w, h, k).len(),
            timed.iter().map(|&t| p.tile_pixels(t).len()).sum::<usize>()
        );
    }
}

/// Cycles a fresh `dram` port takes to answer one read of `bytes` sent at cycle 0.
fn isolated_read_latency(dram: &str, period_fs: u64, addr: u64, bytes: u32) -> u64 {
    let mut p = crate::dram::open(dram, period_fs).unwrap();
    p.send(crate::dram::MemRequest {
        tag: 0,
        addr,
        bytes,
        kind: crate::dram::AccessKind::Read,
    })
    .unwrap();
    let mut n = 0;
    loop {
        p.tick();
        n += 1;
        if p.pop_response().is_some() {
            return n;
        }
    }
}

/// One ray, one triangle, cold caches: the cycle count derived by hand from the
/// pipeline depths and the memory's isolated read latency `m` (see the comments).
#[test]
fn one_ray_takes_the_hand_derived_number_of_cycles() {
    let tri = Triangle::new(
        geom::Vec3::new(-1.0, -1.0, 0.0),
        geom::Vec3::new(1.0, -1.0, 0.0),
        geom::Vec3::new(0.0, 1.0, 0.0),
    );
    let cam = PinholeCamera::new(
        &scene::Camera {
            eye: geom::Vec3::new(0.0, 0.0, 5.0),
            target: geom::Vec3::ZERO,
            up: geom::Vec3::Y,
            vfov_deg: 30.0,
        },
        1,
        1,
    )
    .unwrap();
    let tris = [tri];
    for (kind, dram) in [
        (TreeKind::Bvh2, "simple:bw=12.8e9,lat=100"),
        (TreeKind::Mbvh4, "simple:bw=12.8e9,lat=37"),
        (TreeKind::Cbvh, "simple:bw=12.8e9,lat=61"),
    ] {
        let tree = build_tree(kind, &tris).unwrap();
        let mut cfg = RtConfig::default();
        cfg.set("dram", dram).unwrap();
        let period = 1_000_000_000 / cfg.clock_mhz as u64;
        let d = cfg.trv_depth(kind);
        let i = cfg.ist_stages;
        // Node 0 is at address 0 (one line); the triangle at the page after the nodes.
        let m_node = isolated_read_latency(dram, period, 0, cfg.node_line(kind));
        let m_tri = isolated_read_latency(dram, period, 4096, cfg.prim_line_bytes);
        // Cycle 0: the scheduler sends the ray (FIFO latency 1). Cycle 1: the TRV misses
        // in L1 (the miss reaches the node cache at 2) and the ray loops, re-entering at
        // 1 + k d. Cycle 2: the node cache misses and reads DRAM; the line arrives at
        // 2 + m and reaches the L1 at 3 + m. The ray's first pass at or after 3 + m hits.
        let visit = 1 + d * (2 + m_node).div_ceil(d);
        // It leaves for the IST unit d cycles later; the IST takes it one cycle after
        // that, misses in the primitive cache and reads DRAM; the ray loops every i
        // cycles and tests at the first pass at or after the line's arrival.
        let ist_in = visit + d + 1;
        let test = ist_in + i * m_tri.div_ceil(i);
        // It returns i cycles after its test (seen by the TRV one cycle later), passes the
        // TRV pipeline once to pop its empty stack, and the scheduler retires it one cycle
        // after it leaves: the run ends one cycle after that.
        let retire = test + i + 1 + d + 1;
        let r = run(&tree, &work(&tris, &cam, RayMode::Primary), &cfg).unwrap();
        assert_eq!(r.rays, 1);
        assert!(r.hits_match_software);
        assert_eq!(
            r.cycles,
            retire + 1,
            "{kind:?}: m_node {m_node}, m_tri {m_tri}"
        );
        assert_eq!(r.node_visits, 1);
        assert_eq!(r.triangle_tests, 1);
    }
}

#[test]
fn a_sampled_run_warms_the_caches_and_stays_exact() {
    let (tris, cam) = scene("proc:city?n=3000&seed=2", 128, 64);
    let tree = build_tree(TreeKind::Bvh2, &tris).unwrap();
    let mut w = work(&tris, &cam, RayMode::Diffuse);
    w.sample = 2;
    let cfg = RtConfig::default();
    let a = run_with(&tree, &w, &cfg, true).unwrap();
    let b = run_with(&tree, &w, &cfg, false).unwrap();
    assert_eq!((a.cycles, &a.memory), (b.cycles, &b.memory));
    assert!(a.hits_match_software);
    assert_eq!(a.pixels, sampled_pixels(128, 64, 2).len() as u64);
    assert!(a.pixels < 128 * 64);
    let sched = &a.units[0].counters;
    let warmed = sched.iter().find(|(k, _)| k == "warming_rays").unwrap().1;
    assert!(warmed > 0, "skipped chunks warm the caches");
    assert!(
        a.detailed_rays > a.rays,
        "lead and gap tiles are simulated uncounted"
    );
    assert!(a.counted_dram_bytes <= a.dram_bytes_read);
    // A sampling factor above the number of chunks times one chunk; its measurement
    // window closes at the end of the image.
    w.sample = 1_000_000;
    let one = run(&tree, &w, &cfg).unwrap();
    // One retire per cycle bounds the rate at the clock (500 MRPS).
    assert!(one.pixels > 0 && one.mrps > 0.0, "{}", one.mrps);
    assert!(one.mrps <= cfg.clock_mhz as f64 + 1e-9, "{}", one.mrps);
    assert!(one.hits_match_software);
    assert!(a.mrps > 0.0 && a.frame_dram_mb > 0.0);
}

#[test]
fn the_energy_breakdown_adds_up_and_grows_with_work_and_size() {
    let (tris, cam) = small();
    let tree = build_tree(TreeKind::Mbvh4, &tris).unwrap();
    let primary = run(
        &tree,
        &work(&tris, &cam, RayMode::Primary),
        &RtConfig::default(),
    )
    .unwrap();
    let diffuse = run(
        &tree,
        &work(&tris, &cam, RayMode::Diffuse),
        &RtConfig::default(),
    )
    .unwrap();
    for r in [&primary, &diffuse] {
        let e = r.energy.as_ref().unwrap();
        let names: Vec<&str> = e.units.iter().map(|u| u.unit).collect();
        assert_eq!(names, energy::UNITS);
        let sum: f64 = e.units.iter().map(|u| u.total_mj).sum();
        assert!((sum - e.run_mj).abs() <= 1e-12 * e.run_mj.max(1.0));
        let area: f64 = e.units.iter().map(|u| u.area_mm2).sum();
        assert!((area - e.area_mm2).abs() < 1e-12);
        for u in &e.units {
            assert!(u.dynamic_mj >= 0.0 && u.static_mj >= 0.0, "{u:?}");
            assert!((u.power_mw - u.total_mj / r.seconds).abs() <= 1e-9 * u.power_mw.max(1.0));
        }
        assert_eq!(e.frame_mj, e.run_mj, "a whole frame");
        assert!((e.mrps_per_mm2 - r.mrps / e.area_mm2).abs() < 1e-9);
    }
    // More rays, more dynamic energy in every unit that works per ray.
    let (p, d) = (primary.energy.unwrap(), diffuse.energy.unwrap());
    for k in 0..5 {
        assert!(
            d.units[k].dynamic_mj > p.units[k].dynamic_mj,
            "{}",
            energy::UNITS[k]
        );
    }
    assert_eq!(p.area_mm2, d.area_mm2, "same hardware");
    // Bigger caches: more area and leakage.
    let mut big = RtConfig::default();
    big.set("l2_bytes", "262144").unwrap();
    let rb = run(&tree, &work(&tris, &cam, RayMode::Primary), &big).unwrap();
    let b = rb.energy.unwrap();
    assert!(b.units[3].area_mm2 > p.units[3].area_mm2);
    // Leakage power (static energy over the run's time) grows with the size.
    assert!(b.units[3].static_mj / rb.seconds > p.units[3].static_mj / primary.seconds);
    // The node and cell are configuration; an unknown node is a one-line error.
    let mut c = RtConfig::default();
    assert!(c
        .set("energy_node", "7nm")
        .unwrap_err()
        .to_string()
        .contains("unknown process node"));
    c.set("energy_node", "28nm").unwrap();
    let e28 = run(&tree, &work(&tris, &cam, RayMode::Primary), &c)
        .unwrap()
        .energy
        .unwrap();
    assert!(e28.area_mm2 < p.area_mm2);
}
