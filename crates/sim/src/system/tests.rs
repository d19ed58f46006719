//! Tests of the system energy model: hand-counted operation counts, breakdowns that add
//! up, energy growing with the scene, the Table VIII averaging, the animation policies,
//! and hostile inputs.

use super::report::*;
use super::*;
use scene::LoadOptions;

fn scene_at(spec: &str, t: f32, w: u32, h: u32) -> (Vec<Triangle>, PinholeCamera) {
    let s = scene::open(spec, &LoadOptions::default()).expect("procedural scene");
    let mesh = s.mesh_at(t).expect("mesh");
    let tris: Vec<Triangle> = mesh.triangles_iter().collect();
    let cam = PinholeCamera::new(&s.info().camera, w, h).expect("camera");
    (tris, cam)
}

#[test]
fn treelet_flops_by_hand() {
    // n = 3: forming 2 compares + 1 add; matrix 3 pairs x (6 + 5 adds, 3 muls); merge with
    // 3 active: 3 compares + 1 add + 2 x (11, 3); with 2 active: 1 + 1 + (11, 3); gain 1, 1.
    let f = treelet_flops(3);
    assert_eq!((f.adds, f.muls), (76.0, 19.0));
    // Grows about as n^3.
    assert!(treelet_flops(8).total() > 8.0 * treelet_flops(4).total() / 2.0);
    let mut work = bvh::AtrbvhWork {
        treelets_by_leaves: vec![0; 9],
        ..Default::default()
    };
    work.treelets_by_leaves[3] = 2;
    work.treelets_by_leaves[8] = 5;
    let w = atrbvh_flops(&work);
    let want = treelet_flops(3)
        .times(2.0)
        .plus(treelet_flops(8).times(5.0));
    assert_eq!(w, want);
}

#[test]
fn refit_flops_by_hand() {
    let (tris, _) = scene_at("proc:cloth?n=2000", 0.0, 8, 8);
    let aabbs = bvh::triangle_aabbs(&tris);
    let t = bvh::BinnedSahBuilder::default().build(&aabbs).unwrap();
    let leaves = t
        .nodes
        .iter()
        .flat_map(|n| n.children)
        .filter(|c| c.is_leaf())
        .count() as f64;
    let p = t.prim_indices.len() as f64;
    let f = refit_flops(&t);
    assert_eq!(f.adds, 6.0 * (p - leaves) + 6.0 * t.nodes.len() as f64);
    let e = refit_energy(&t, &SystemConfig::default()).unwrap();
    assert_eq!(e.len(), 2);
    assert!(e.iter().all(|u| u.total_mj > 0.0));
}

#[test]
fn every_build_adds_up_and_mergetree_spends_less_than_binned_sah() {
    // The full DRAM energy, so that the above-idle and DRAM-wait accountings differ from it.
    let full = Conventions {
        dram: crate::energy::DramConvention::Full,
        ..Conventions::default()
    };
    let cfg = SystemConfig::default().with(Node::Nm28, full, "lpddr3-1600-2x64");
    let thesis = SystemConfig::default();
    let mut last: Option<Vec<f64>> = None;
    for n in [60_000, 240_000] {
        let (tris, _) = scene_at(&format!("proc:forest?n={n}"), 0.0, 8, 8);
        let aabbs = bvh::triangle_aabbs(&tris);
        let mut mj = Vec::new();
        for b in Builder::ALL {
            let (e, tree) = build_energy(b, &aabbs, &cfg).unwrap();
            bvh::validate(&tree, &aabbs, u32::MAX).unwrap();
            let sum: f64 = e.units.iter().map(|u| u.total_mj).sum();
            assert!((sum - e.mj).abs() <= 1e-12 * e.mj, "{b:?}");
            assert_eq!(e.units.last().unwrap().unit, "DRAM");
            if b == Builder::BinnedSah {
                // Galal's FLOPs: binned SAH "performs significant floating-point
                // computation" ([P2] §6.4).
                assert!(e.units[0].total_mj > 0.2 * e.mj, "{e:?}");
            } else {
                assert!(e.dram_mj > 0.5 * e.mj, "{b:?}: DRAM dominates ({e:?})");
            }
            assert!(e
                .units
                .iter()
                .all(|u| u.dynamic_mj >= 0.0 && u.static_mj >= 0.0));
            assert!((e.sah - tree.sah()).abs() < 1e-9 * e.sah);
            assert!(e.dram_above_idle_mj > 0.0 && e.dram_above_idle_mj < e.dram_mj);
            assert!(e.mj_above_idle() < e.mj);
            // Only the streamed units wait on FPUs: MergeTree's memory runs the whole build.
            match b {
                Builder::Hlbvh | Builder::HlbvhSah => assert_eq!(e.dram_wait_mj, 0.0),
                _ => assert!(e.dram_wait_mj >= 0.0),
            }
            // The thesis's convention: the DRAM row is already above idle, nothing waits.
            let (t, _) = build_energy(b, &aabbs, &thesis).unwrap();
            assert!((t.mj - e.mj_above_idle()).abs() <= 1e-9 * t.mj, "{b:?}");
            assert!((t.mj - t.mj_above_idle()).abs() <= 1e-9 * t.mj, "{b:?}");
            assert_eq!(t.dram_wait_mj, 0.0);
            if b == Builder::BinnedSah {
                // 37 FPUs at 500 MHz are slower than the 25.6 GB/s stream: the idle
                // memory's energy over the difference, at the stream's own idle power.
                let t = binned_sah_hw::model(&tree, &cfg.binned);
                let (mem, dram_s) = dram::stream::streaming(
                    &cfg.dram,
                    t.sweep_read_bytes,
                    t.sweep_write_bytes + t.bvh_bytes,
                )
                .unwrap();
                let idle_w = mem.energy_pj.as_ref().unwrap().idle_pj * 1e-12 / dram_s;
                assert!(e.ms * 1e-3 > dram_s, "FPU-bound: {} ms", e.ms);
                let want = idle_w * (e.ms * 1e-3 - dram_s) * 1e3;
                assert!((e.dram_wait_mj - want).abs() < 1e-9 * want, "{e:?}");
                assert!(e.mj_with_dram_wait() > e.mj);
            }
            mj.push(e.mj);
        }
        // MergeTree's traffic is a fraction of binned SAH's at this size ([P2] Table VI).
        assert!(mj[1] < mj[0], "{n}: {mj:?}");
        // The toplevel units add energy; they never make the build cheaper.
        assert!(mj[2] >= mj[1] * 0.999 && mj[3] >= mj[1] * 0.999, "{mj:?}");
        if let Some(l) = &last {
            assert!(mj.iter().zip(l).all(|(a, b)| a > b), "{mj:?} vs {l:?}");
        }
        last = Some(mj);
    }
}

#[test]
fn a_scene_result_and_table8() {
    let (tris, cam) = scene_at("proc:hairball?n=3000&seed=2", 0.0, 32, 24);
    let cfg = SystemConfig::default();
    let s = SystemScene {
        name: "hairball".into(),
        triangles: &tris,
        camera: cam,
        sample: 1,
    };
    let mut steps = 0;
    let r = scene_result(&s, &cfg, |_| steps += 1).unwrap();
    assert_eq!(steps, 12);
    assert_eq!(r.builds.len(), 4);
    assert_eq!(r.traces.len(), 8);
    for t in &r.traces {
        assert!(t.frame_mj > 0.0 && t.dram_fraction > 0.0 && t.dram_fraction < 1.0);
        // The thesis's convention: the frame's DRAM is counted above idle already.
        assert!((t.frame_mj_above_idle - t.frame_mj).abs() <= 1e-9 * t.frame_mj);
    }
    // Diffuse paths cost more than camera rays.
    for b in Builder::ALL {
        assert!(r.trace(b, RayMode::Diffuse).frame_mj > r.trace(b, RayMode::Primary).frame_mj);
    }
    // Table VIII over two copies of the scene with the second's energies doubled: the
    // ratios are those of one scene (mean of equal ratios), binned SAH is exactly 1.
    let mut r2 = r.clone();
    r2.scene = "copy".into();
    for b in &mut r2.builds {
        b.mj *= 2.0;
    }
    for t in &mut r2.traces {
        t.frame_mj *= 2.0;
    }
    let rows = table8(&[r.clone(), r2]);
    // Only "all": no scene is large.
    assert_eq!(rows.len(), 8);
    for row in &rows {
        assert_eq!(row.count, 2);
        let rays = if row.rays == "primary" {
            RayMode::Primary
        } else {
            RayMode::Diffuse
        };
        let b = Builder::ALL
            .into_iter()
            .find(|b| b.name() == row.builder)
            .unwrap();
        let want = r.total_mj(b, rays) / r.total_mj(Builder::BinnedSah, rays);
        assert!((row.total - want).abs() < 1e-12, "{row:?}");
        let want = r.build(b).mj / r.build(Builder::BinnedSah).mj;
        assert!((row.build - want).abs() < 1e-12);
        if b == Builder::BinnedSah {
            assert_eq!((row.build, row.trace, row.total), (1.0, 1.0, 1.0));
            assert_eq!(row.above_idle, [1.0; 3]);
            assert_eq!(row.with_dram_wait, [1.0; 3]);
        }
        assert_eq!(row.with_dram_wait[1], row.trace);
        assert!(row.thesis.is_some());
        // The balance: binned SAH's build share is the mean of its per-scene shares
        // (equal here), and the thesis's is defined for every builder but binned SAH.
        let share = r.build(Builder::BinnedSah).mj / r.total_mj(Builder::BinnedSah, rays);
        assert!((row.sah_build_share - share).abs() < 1e-12);
        assert_eq!(row.thesis_build_share.is_some(), b != Builder::BinnedSah);
        if let Some(s) = row.thesis_build_share {
            let want = s * row.build + (1.0 - s) * row.trace;
            assert!((row.total_at_thesis_share.unwrap() - want).abs() < 1e-12);
        }
    }
    // Sampling errors: none for whole frames; by hand for given trace errors, the
    // builder's and binned SAH's taken as independent, and over two equal scenes the
    // error of a mean of two.
    assert!(rows.iter().all(|row| row.sampling_se == [0.0; 3]));
    let mut rs = r.clone();
    for t in &mut rs.traces {
        t.frame_mj_rel_se = match t.builder {
            Builder::BinnedSah => 0.05,
            _ => 0.1,
        };
    }
    let (p, sah) = (RayMode::Primary, Builder::BinnedSah);
    let hl = Builder::Hlbvh;
    let trace = rs.trace(hl, p).frame_mj / rs.trace(sah, p).frame_mj;
    let total = rs.total_mj(hl, p) / rs.total_mj(sah, p);
    let want_trace = trace * (0.1f64.powi(2) + 0.05f64.powi(2)).sqrt();
    let want_total = total
        * ((0.1 * rs.trace(hl, p).frame_mj / rs.total_mj(hl, p)).powi(2)
            + (0.05 * rs.trace(sah, p).frame_mj / rs.total_mj(sah, p)).powi(2))
        .sqrt();
    for (scenes, n) in [
        (vec![rs.clone()], 1.0f64),
        (vec![rs.clone(), rs.clone()], 2.0),
    ] {
        let rows = table8(&scenes);
        let row = rows
            .iter()
            .find(|x| x.rays == "primary" && x.builder == "hlbvh")
            .unwrap();
        let se = row.sampling_se;
        assert_eq!(se[0], 0.0);
        assert!((se[1] - want_trace / n.sqrt()).abs() < 1e-12, "{se:?}");
        assert!((se[2] - want_total / n.sqrt()).abs() < 1e-12, "{se:?}");
        let reference = rows.iter().find(|x| x.builder == "binned-sah").unwrap();
        assert_eq!(reference.sampling_se, [0.0; 3]);
    }
    // Paired windows (the same timed chunks): the builder's trace heavy where binned
    // SAH's is, so its trace ratio has no sampling error at all.
    let mut paired = rs.clone();
    for t in &mut paired.traces {
        let k = if t.builder == Builder::BinnedSah {
            1.0
        } else {
            2.0
        };
        t.window_mj = vec![(64, k), (64, 3.0 * k), (64, 2.0 * k)];
        t.sample = 4;
    }
    let rows = table8(&[paired]);
    let row = rows
        .iter()
        .find(|x| x.rays == "primary" && x.builder == "hlbvh")
        .unwrap();
    assert!(row.sampling_se[1].abs() < 1e-12, "{:?}", row.sampling_se);
    assert!(
        row.sampling_se[2] > 0.0,
        "the builds do not scale with the chunks"
    );
    let rep = SystemReport::new(&cfg, 32, 24, vec![rs], Vec::new());
    assert!(rep.table8_markdown().contains(" ± "));
    let rep = SystemReport::new(&cfg, 32, 24, vec![r], Vec::new());
    assert!(!rep.table8_markdown().contains(" ± "));
    assert_eq!(rep.schema, SCHEMA);
    assert!(rep.table8_markdown().contains("hlbvh+atrbvh"));
    assert_eq!(rep.scenes_csv().lines().count(), 5);
    let (labels, series) = rep.fig7(RayMode::Primary);
    assert_eq!(labels, vec!["hairball".to_string()]);
    assert_eq!(series.len(), 4);
    assert!((series[0].1[0][0] - rep.scenes[0].builds[0].mj * FPS).abs() < 1e-12);
}

#[test]
fn dram_wait_by_hand() {
    // 64 MB on the medium system: 2.5 ms of transfer; a unit running 3x as long waits
    // 5 ms at the stream's idle power.
    let (mem, s) = dram::stream::streaming("lpddr3-1600-2x64", 64_000_000, 0).unwrap();
    assert!((s - 2.5e-3).abs() < 1e-12, "{s}");
    let idle_mj = mem.energy_pj.as_ref().unwrap().idle_pj * 1e-9;
    assert!((dram_wait_mj(&mem, s, 3.0 * s) - 2.0 * idle_mj).abs() < 1e-12 * idle_mj);
    // No wait when the memory is the bottleneck.
    assert_eq!(dram_wait_mj(&mem, s, s), 0.0);
    assert_eq!(dram_wait_mj(&mem, s, 0.5 * s), 0.0);
}

#[test]
fn implied_build_share_by_hand() {
    // [P2] Table VIII, primary rays, all scenes, HLBVH: build 32%, trace 143%, total 71%:
    // s = (1.43 - 0.71) / (1.43 - 0.32) = 0.72 / 1.11.
    let s = implied_build_share([0.32, 1.43, 0.71]).unwrap();
    assert!((s - 0.72 / 1.11).abs() < 1e-12);
    // Re-weighting the thesis's own ratios with that share gives back its total.
    assert!((s * 0.32 + (1.0 - s) * 1.43 - 0.71).abs() < 1e-12);
    // A system whose total is its build ratio spends everything on the build.
    assert_eq!(implied_build_share([0.5, 2.0, 0.5]), Some(1.0));
    // Equal build and trace ratios leave the share undefined.
    assert_eq!(implied_build_share([1.0, 1.0, 1.0]), None);
}

#[test]
fn animation_policies() {
    let times = [0.0f32, 0.5, 1.0];
    let mut frames = Vec::new();
    let mut cam = None;
    for &t in &times {
        let (tris, c) = scene_at("proc:cloth?n=20000", t, 24, 16);
        frames.push(tris);
        cam = Some(c);
    }
    let sc = AnimationScene {
        name: "cloth".into(),
        frames,
        times: times.to_vec(),
        camera: cam.unwrap(),
        sample: 1,
    };
    let cfg = SystemConfig::default();
    for (threshold, always) in [(1e9, false), (1.0 + 1e-12, true)] {
        let a = animation_study(&sc, &cfg, threshold, |_| {}).unwrap();
        assert_eq!(a.rays.len(), 2);
        for rays in &a.rays {
            let [rebuild, refit, advised] = &rays.policies[..] else {
                panic!("three policies")
            };
            assert!(rebuild
                .frames
                .iter()
                .all(|f| f.rebuilt && f.refit_mj == 0.0));
            assert!(rebuild
                .frames
                .iter()
                .all(|f| (f.sah_ratio - 1.0).abs() < 1e-12));
            assert!(refit.frames[0].rebuilt);
            assert!(refit.frames[1..]
                .iter()
                .all(|f| !f.rebuilt && f.build_mj == 0.0 && f.refit_mj > 0.0));
            // A refit is cheaper than a rebuild (above one multi-merge block).
            assert!(refit.frames[1].refit_mj < rebuild.frames[1].build_mj);
            // Frame 0 is the same tree everywhere: one trace, shared.
            assert_eq!(rebuild.frames[0].trace_mj, refit.frames[0].trace_mj);
            if !always {
                // The tracker never advises: the advised policy is the refit policy.
                for (x, y) in advised.frames.iter().zip(&refit.frames) {
                    assert_eq!((x.rebuilt, x.trace_mj), (y.rebuilt, y.trace_mj));
                }
            } else {
                // A threshold of 1 advises a rebuild whenever the refitted SAH rose above
                // the last build's (the waving cloth's does): the advised frames are
                // fresh builds (ratio 1) that paid for the refit too.
                assert!(advised.frames[1..].iter().any(|f| f.rebuilt));
                for f in advised.frames[1..].iter().filter(|f| f.rebuilt) {
                    assert!(f.refit_mj > 0.0 && f.build_mj > 0.0);
                    assert!((f.sah_ratio - 1.0).abs() < 1e-12);
                }
            }
        }
    }
}

#[test]
fn hostile_inputs_are_one_line_errors() {
    let (tris, cam) = scene_at("proc:cloth?n=500", 0.0, 8, 8);
    let cam2 = cam;
    let aabbs = bvh::triangle_aabbs(&tris);
    let bad = SystemConfig::default().with(Node::Nm28, Conventions::default(), "ddr9");
    for b in Builder::ALL {
        let e = build_energy(b, &aabbs, &bad).unwrap_err().to_string();
        assert!(e.contains("ddr9") && !e.contains('\n'), "{b:?}: {e}");
    }
    let s = SystemScene {
        name: "empty".into(),
        triangles: &[],
        camera: cam,
        sample: 1,
    };
    let e = scene_result(&s, &SystemConfig::default(), |_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("no triangles"), "{e}");
    let sc = AnimationScene {
        name: "uneven".into(),
        frames: vec![tris.clone(), tris[1..].to_vec()],
        times: vec![0.0, 1.0],
        camera: cam2,
        sample: 1,
    };
    let e = animation_study(&sc, &SystemConfig::default(), 1.3, |_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("different triangle counts"), "{e}");
    let sc = AnimationScene {
        frames: vec![tris.clone(), tris.clone()],
        ..sc
    };
    let e = animation_study(&sc, &SystemConfig::default(), -1.0, |_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("threshold") && !e.contains('\n'), "{e}");
}
