//! Rendering: every tree gives the same image and depth buffer, the log's totals equal the
//! tracer's counters, and results do not depend on the thread count.

use crate::log::{summarize, LogHeader, LogReader, LogWriter, LoggedRay};
use crate::testutil::*;
use crate::{render, RayKind, Render, RenderSettings, Shading, Traverse};
use geom::{Triangle, Vec3};

fn scene_tris() -> (Vec<Triangle>, Vec<u32>) {
    // A closed bumpy sphere over a flat grid floor, with a few materials.
    let (p, t) = bumpy_sphere(3, 0.25, 3);
    let mut tris = resolve(&p, &t);
    for tri in flat_grid(8) {
        let v = tri
            .v
            .map(|v| Vec3::new(v.x * 1.5 - 6.0, -4.0, v.y * 1.5 - 6.0));
        tris.push(Triangle::new(v[0], v[1], v[2]));
    }
    let mats = (0..tris.len() as u32).map(|i| (i / 97) % 5).collect();
    (tris, mats)
}

fn settings(rays: RayKind) -> RenderSettings {
    let mut s = RenderSettings::new(scene::Camera {
        eye: Vec3::new(2.0, 3.0, 12.0),
        target: Vec3::new(0.5, -1.0, 0.0),
        up: Vec3::Y,
        vfov_deg: 50.0,
    });
    s.width = 72;
    s.height = 40;
    s.rays = rays;
    s.bounces = 3;
    s
}

fn same_image(a: &Render, b: &Render) -> bool {
    let bits = |r: &Render| {
        (
            r.color
                .iter()
                .flat_map(|c| c.map(f32::to_bits))
                .collect::<Vec<_>>(),
            r.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            r.prim.clone(),
        )
    };
    bits(a) == bits(b)
}

/// Bvh2 and Mbvh4, every builder and both kernels, and every CBVH encoder variant: the same
/// image and depth buffer, for primary, diffuse and shadow rays.
#[test]
fn every_tree_renders_the_same_image() {
    let (tris, mats) = scene_tris();
    let shading = Shading {
        triangles: &tris,
        material_ids: &mats,
    };
    let (b2, b4) = all_accels(&tris);
    let cb = all_cbvh(&tris);
    for kind in [RayKind::Primary, RayKind::Diffuse, RayKind::Shadow] {
        let s = settings(kind);
        let reference = render(&b2[0].1, shading, &s, None, None).unwrap();
        let hits = reference.prim.iter().filter(|&&p| p != u32::MAX).count();
        assert!(
            hits > 100 && hits < reference.prim.len(),
            "{kind:?}: {hits} hits"
        );
        for (name, a) in &b2 {
            let r = render(a, shading, &s, None, None).unwrap();
            assert!(same_image(&r, &reference), "{kind:?} {name}");
        }
        for (name, a) in &b4 {
            let r = render(a, shading, &s, None, None).unwrap();
            assert!(same_image(&r, &reference), "{kind:?} {name}");
        }
        for (name, a) in &all_mbvh8(&tris) {
            let r = render(a, shading, &s, None, None).unwrap();
            assert!(same_image(&r, &reference), "{kind:?} {name}");
        }
        for (name, a) in &cb {
            let r = render(a, shading, &s, None, None).unwrap();
            assert!(same_image(&r, &reference), "{kind:?} {name}");
        }
        // Ray counts: one primary ray per pixel; diffuse adds bounces, shadow one per lit hit.
        let st = &reference.stats;
        assert_eq!(st.per_bounce[0].rays, (s.width * s.height) as u64);
        match kind {
            RayKind::Primary => assert_eq!(st.per_bounce.len(), 1),
            RayKind::Shadow => {
                assert!(st.per_bounce[1].rays > 0 && st.per_bounce[1].rays <= hits as u64)
            }
            RayKind::Diffuse => {
                assert_eq!(st.per_bounce.len(), 4);
                assert_eq!(st.per_bounce[1].rays, hits as u64);
                assert!(
                    st.per_bounce[3].rays > 0 && st.per_bounce[3].rays <= st.per_bounce[2].rays
                );
            }
        }
        assert_eq!(
            st.total.rays,
            st.per_bounce.iter().map(|b| b.rays).sum::<u64>()
        );
        // The per-pixel heat sums to the counters.
        assert_eq!(
            reference.node_visits.iter().map(|&v| v as u64).sum::<u64>(),
            st.total.node_visits
        );
        assert_eq!(
            reference.tri_tests.iter().map(|&v| v as u64).sum::<u64>(),
            st.total.tri_tests
        );
    }
}

/// A log's totals, recomputed from its events alone, equal the tracer's counters, bounce
/// by bounce; logging does not change the image; the rays in the log are the rays traced.
#[test]
fn log_totals_equal_the_tracer_counters() {
    let (tris, mats) = scene_tris();
    let shading = Shading {
        triangles: &tris,
        material_ids: &mats,
    };
    let (b2, b4) = all_accels(&tris);
    let cb = all_cbvh(&tris);
    let b8 = all_mbvh8(&tris);
    let dir = tempfile::tempdir().unwrap();
    for kind in [RayKind::Diffuse, RayKind::Shadow] {
        let s = settings(kind);
        for (name, accel) in [
            (&b2[1].0, &b2[1].1 as &dyn TraverseDyn),
            (&b4[1].0, &b4[1].1 as &dyn TraverseDyn),
            (&cb[7].0, &cb[7].1 as &dyn TraverseDyn),
            (&b8[1].0, &b8[1].1 as &dyn TraverseDyn),
        ] {
            let path = dir.path().join("t.bin");
            let header = LogHeader {
                width: accel.w(),
                node_bytes: accel.nb(),
                node_count: accel.nc() as u64,
                leaf_entries: accel.le() as u64,
                image_width: s.width,
                image_height: s.height,
                rays: kind,
                bounces: s.bounces as u8,
                distance_stack: true,
                seed: s.seed,
            };
            let mut w = LogWriter::create(&path, &header).unwrap();
            let logged = accel.render_logged(shading, &s, Some(&mut w));
            let size = w.finish().unwrap();
            assert_eq!(size, std::fs::metadata(&path).unwrap().len());
            let plain = accel.render_logged(shading, &s, None);
            assert!(same_image(&logged, &plain), "{name}");
            let sum = summarize(&path).unwrap();
            assert_eq!(sum.header, Some(header));
            assert_eq!(sum.total, logged.stats.total, "{kind:?} {name}");
            assert_eq!(sum.per_bounce, logged.stats.per_bounce, "{kind:?} {name}");
            assert!(sum.distinct_nodes > 0 && sum.distinct_nodes <= header.node_count);
            // Ray by ray: primary rays are the camera's, in tile order, and hits match.
            let mut rd = LogReader::open(&path).unwrap();
            let mut ray = LoggedRay::default();
            let mut primaries = 0;
            while rd.next_ray(&mut ray).unwrap() {
                if ray.bounce == 0 {
                    primaries += 1;
                    let p = ray.pixel as usize;
                    assert_eq!(ray.hit.map(|h| h.prim).unwrap_or(u32::MAX), logged.prim[p]);
                    if let Some(h) = ray.hit {
                        assert_eq!(h.t.to_bits(), logged.depth[p].to_bits());
                    }
                }
            }
            assert_eq!(primaries, s.width * s.height);
        }
    }
}

/// Helper so the log test can loop over both widths.
trait TraverseDyn {
    fn w(&self) -> u32;
    fn nb(&self) -> u32;
    fn nc(&self) -> usize;
    fn le(&self) -> usize;
    fn render_logged(
        &self,
        sh: Shading<'_>,
        s: &RenderSettings,
        log: Option<&mut LogWriter>,
    ) -> Render;
}

impl<T: Traverse> TraverseDyn for T {
    fn w(&self) -> u32 {
        self.width()
    }
    fn nb(&self) -> u32 {
        self.node_bytes()
    }
    fn nc(&self) -> usize {
        self.node_count()
    }
    fn le(&self) -> usize {
        self.leaf_entries()
    }
    fn render_logged(
        &self,
        sh: Shading<'_>,
        s: &RenderSettings,
        log: Option<&mut LogWriter>,
    ) -> Render {
        render(self, sh, s, log, None).unwrap()
    }
}

/// One thread or two: the same image, counters and log bytes.
#[test]
fn results_do_not_depend_on_the_thread_count() {
    let (tris, mats) = scene_tris();
    let shading = Shading {
        triangles: &tris,
        material_ids: &mats,
    };
    let (b2, _) = all_accels(&tris);
    let s = settings(RayKind::Diffuse);
    let dir = tempfile::tempdir().unwrap();
    let run = |threads: usize, name: &str| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let path = dir.path().join(name);
        let header = LogHeader {
            width: 2,
            node_bytes: 64,
            node_count: 1,
            leaf_entries: 1,
            image_width: s.width,
            image_height: s.height,
            rays: RayKind::Diffuse,
            bounces: 3,
            distance_stack: false,
            seed: 1,
        };
        let mut w = LogWriter::create(&path, &header).unwrap();
        let r = pool.install(|| render(&b2[0].1, shading, &s, Some(&mut w), None).unwrap());
        w.finish().unwrap();
        (r, std::fs::read(&path).unwrap())
    };
    let (a, la) = run(1, "a.bin");
    let (b, lb) = run(2, "b.bin");
    assert!(same_image(&a, &b));
    assert_eq!(a.stats.total, b.stats.total);
    assert_eq!(la, lb);
}

/// Damaged logs are errors, never panics: truncation, a flipped byte, a bad header.
#[test]
fn damaged_logs_are_reported() {
    let (tris, mats) = scene_tris();
    let shading = Shading {
        triangles: &tris,
        material_ids: &mats,
    };
    let (b2, _) = all_accels(&tris);
    let mut s = settings(RayKind::Primary);
    s.width = 20;
    s.height = 20;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ok.bin");
    let header = LogHeader {
        width: 2,
        node_bytes: 64,
        node_count: b2[0].1.node_count() as u64,
        leaf_entries: 1,
        image_width: 20,
        image_height: 20,
        rays: RayKind::Primary,
        bounces: 0,
        distance_stack: false,
        seed: 1,
    };
    let mut w = LogWriter::create(&path, &header).unwrap();
    render(&b2[0].1, shading, &s, Some(&mut w), None).unwrap();
    w.finish().unwrap();
    let good = std::fs::read(&path).unwrap();
    assert!(summarize(&path).is_ok());
    let bad = dir.path().join("bad.bin");
    let mut cases: Vec<Vec<u8>> = vec![
        good[..good.len() - 5].to_vec(),
        good[..40].to_vec(),
        Vec::new(),
        [good.clone(), vec![0]].concat(),
    ];
    for i in [0usize, 9, 12, 70, good.len() / 2, good.len() - 10] {
        let mut g = good.clone();
        g[i] ^= 0x5A;
        cases.push(g);
    }
    for (k, c) in cases.iter().enumerate() {
        std::fs::write(&bad, c).unwrap();
        assert!(summarize(&bad).is_err(), "case {k} was accepted");
    }
    // A writer dropped without finishing leaves no file.
    let never = dir.path().join("never.bin");
    let w = LogWriter::create(&never, &header).unwrap();
    drop(w);
    assert!(!never.exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}
