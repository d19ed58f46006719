//! Pinned figures (issue 31 part 5): default reproductions on the shared scenes that fail
//! when they drift beyond the tolerance their documentation states, whether the figure
//! meets the thesis's or is a documented miss (then pinned to a band around the measured
//! value, so that a change that moves it is noticed and re-explained).
//!
//! Each test skips, saying so, when `shared/scenes` is absent.

use crate::mergetree::{self, MergeTreeConfig};
use crate::rtunit::{self, RayMode, RtConfig, TreeKind, Workload};
use crate::thesis::{p2_scene, P2_SYSTEMS, P4_TABLE1};

/// The triangles of a shared scene and its report camera (the interior view where it has
/// one) at 640x360, or `None` (with a message)
/// when it is absent.
fn shared(file: &str) -> Option<(Vec<geom::Triangle>, trace::PinholeCamera)> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/scenes")
        .join(file);
    if !path.is_file() {
        println!(
            "skipping the pinned figures of {file}: {} not found",
            path.display()
        );
        return None;
    }
    let s = scene::open(path.to_str()?, &Default::default()).expect("scene");
    // The interior view the reports use (`scene::camera::INTERIOR_VIEWS`).
    let stem = file.trim_end_matches(".ply");
    let view = scene::camera::view_camera(stem, s.info().camera);
    let cam = trace::PinholeCamera::new(&view, 640, 360).expect("camera");
    Some((
        s.mesh_at(0.0).expect("mesh").triangles_iter().collect(),
        cam,
    ))
}

/// `ours` relative to `thesis`, minus one.
fn rel(ours: f64, thesis: f64) -> f64 {
    ours / thesis - 1.0
}

/// MergeTree (preset `p2`) on \[P2\]'s three systems against Table III's times and
/// speed-ups and Table VI's traffic, with `docs/mergetree-vs-thesis.md`'s targets: the
/// slow-system time and the slow-to-medium speed-up within 15%, the traffic within 10%;
/// the slow-to-fast speed-up is a documented miss on Bunny (-16%), pinned to -20..-10%,
/// and met on Crytek Sponza (-15%, pinned to -18..-10%).
#[test]
fn mergetree_on_p2_systems_stays_where_documented() {
    for (file, name, fast_band) in [
        ("bunny.ply", "bunny", (-0.20, -0.10)),
        ("crytek-sponza.ply", "crytek-sponza", (-0.18, -0.10)),
    ] {
        let Some((tris, _)) = shared(file) else {
            continue;
        };
        let aabbs = bvh::triangle_aabbs(&tris);
        let cfg = MergeTreeConfig::p2();
        let t = p2_scene(name).expect("a Table III scene");
        let mut ms = [0.0; 3];
        let mut mb = 0.0;
        for (k, system) in P2_SYSTEMS.iter().enumerate() {
            let port = crate::dram::open(system, cfg.period_fs()).unwrap();
            let r = mergetree::simulate(&aabbs, &cfg, port).unwrap();
            assert!(mergetree::tree_matches_software(&r, &aabbs).unwrap());
            ms[k] = r.ms;
            if k == 0 {
                mb = (r.bytes_read + r.bytes_written) as f64 / 1e6;
            }
        }
        let speedups = [ms[0] / ms[1], ms[0] / ms[2]];
        let th = t.speedups();
        let report = format!(
            "{name}: ms {ms:?} (thesis {:?}), speed-ups {speedups:?} (thesis {th:?}), {mb:.2} MB (thesis {})",
            t.mergetree_ms, t.traffic_mb[0]
        );
        println!("{report}");
        assert!(rel(ms[0], t.mergetree_ms[0]).abs() <= 0.15, "{report}");
        assert!(rel(speedups[0], th[0]).abs() <= 0.15, "{report}");
        let fast = rel(speedups[1], th[1]);
        assert!(
            fast >= fast_band.0 && fast <= fast_band.1,
            "{report}: fast speed-up {fast:+.3} left its band {fast_band:?}"
        );
        assert!(rel(mb, t.traffic_mb[0]).abs() <= 0.10, "{report}");
    }
}

/// The \[P4\] accelerator on Crytek Sponza's primary rays (one in 16 tile chunks timed, at
/// \[P4\]'s 45 nm and IST division): the areas within 10% of \[P4\] Table 1's BVH total
/// (3.51 mm^2) and within 25% of its MBVH4 total (5.47 mm^2, a printed total 0.75 mm^2
/// above its units' sum, `crate::thesis` tests); MBVH4's speed-up over BVH2 in
/// `docs/rtunit-vs-thesis.md`'s measured range (+65..+100%, against \[P4\]'s +87%) and its
/// traffic change between -20% and +2% (\[P4\]: -42%, a documented miss); hits equal to
/// the software tracer's.
#[test]
fn p4_accelerator_on_crytek_sponza_stays_where_documented() {
    let Some((tris, cam)) = shared("crytek-sponza.ply") else {
        return;
    };
    let cfg = RtConfig {
        dram: "lpddr3-1600-2x32".into(),
        ..RtConfig::default()
    };
    let mut runs = Vec::new();
    for kind in [TreeKind::Bvh2, TreeKind::Mbvh4] {
        let tree = rtunit::build_tree(kind, &tris).unwrap();
        let work = Workload {
            triangles: &tris,
            camera: &cam,
            rays: RayMode::Primary,
            bounces: 0,
            seed: 1,
            sample: 16,
            progress: None,
        };
        let r = rtunit::run(&tree, &work, &cfg).unwrap();
        assert!(r.hits_match_software);
        runs.push(r);
    }
    let area = |r: &rtunit::RtReport| r.energy.as_ref().unwrap().area_mm2;
    let (b, m) = (&runs[0], &runs[1]);
    let speed = m.mrps / b.mrps - 1.0;
    let traffic = m.frame_dram_mb / b.frame_dram_mb - 1.0;
    let report = format!(
        "areas {:.2} / {:.2} mm^2 (thesis {} / {}), MBVH4 speed {speed:+.3}, traffic {traffic:+.3}",
        area(b),
        area(m),
        P4_TABLE1[0][0][6],
        P4_TABLE1[1][0][6]
    );
    println!("{report}");
    assert!(rel(area(b), P4_TABLE1[0][0][6]).abs() <= 0.10, "{report}");
    assert!(rel(area(m), P4_TABLE1[1][0][6]).abs() <= 0.25, "{report}");
    assert!((0.65..=1.00).contains(&speed), "{report}");
    assert!((-0.20..=0.02).contains(&traffic), "{report}");
}
