//! Where a CBVH's extra triangle tests come from ([P3] §5.4): the leaves a ray enters only
//! because their decoded box is larger than the original, split by whether the original
//! leaf box is flat (zero extent on an axis, as for the faces of axis-aligned walls and
//! floors) and by bounce (primary rays against the diffuse bounces that start on a surface).
//!
//! The LBVH of [P3] §5.2 compressed top-down (6 bits, relative), the rays of a diffuse render
//! (4 bounces) through the uncompressed tree, no distance stack (so every hit leaf child is
//! visited and its triangles tested).
//!
//! `cargo run --release -p trace --example cbvh_extra_tests -- SCENE [EYE TARGET FOV] [W H]`
//! with EYE and TARGET as `x,y,z`.

use cbvh::codec::{slot_ptr, ChildPtr};
use cbvh::{compress_topdown, Params};
use geom::{ray_aabb, Aabb, RayPrecomp, Vec3};
use trace::render::record_rays;
use trace::{
    BoxObserver, Bvh2Accel, CbvhAccel, KernelOptions, RayKind, RayStats, RenderSettings, Shading,
    TraversalStack,
};

/// Triangle tests in leaves entered although the ray misses their original box.
#[derive(Default)]
struct Extra<'a> {
    cbvh: Option<&'a cbvh::Cbvh>,
    original: &'a [[Aabb; 2]],
    pre: Option<RayPrecomp>,
    /// [flat, not flat] extra triangle tests; all leaf triangle tests.
    extra: [u64; 2],
    all: u64,
}

impl BoxObserver for Extra<'_> {
    fn boxes(&mut self, pair: u32, _: &[Option<Aabb>; 2], t_min: f32, t_max: f32, hit: u8) {
        let (Some(c), Some(pre)) = (self.cbvh, &self.pre) else {
            return;
        };
        for k in 0..2 {
            if hit >> k & 1 == 0 {
                continue;
            }
            if let ChildPtr::Leaf(first) = slot_ptr(&c.pairs[pair as usize].slots[k]) {
                let n = c.leaf_range(first).unwrap().1 as u64;
                self.all += n;
                let o = &self.original[pair as usize][k];
                if ray_aabb(pre, o, t_min, t_max).is_none() {
                    let flat = (o.max - o.min).min_element() == 0.0;
                    self.extra[usize::from(!flat)] += n;
                }
            }
        }
    }
}

fn parse3(s: &str) -> Vec3 {
    let v: Vec<f32> = s.split(',').map(|x| x.parse().expect("x,y,z")).collect();
    Vec3::new(v[0], v[1], v[2])
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let spec = a
        .first()
        .ok_or("usage: cbvh_extra_tests SCENE [EYE TARGET FOV] [W H]")?;
    let scene = scene::open(spec, &Default::default())?;
    let mesh = scene.mesh_at(0.0)?;
    let tris: Vec<geom::Triangle> = mesh.triangles_iter().collect();
    let prims = bvh::triangle_aabbs(&tris);
    let (_, lbvh) = cbvh::study::build_lbvh(&prims)?;
    let td = compress_topdown(&lbvh, &Params::default())?.0;
    let original = td.original_child_boxes(&prims)?;
    let options = KernelOptions::thesis(2);
    let b2 = Bvh2Accel::new(lbvh, &tris, options)?;
    let c = CbvhAccel::new(&td, &tris, options)?;
    let mut cam = scene.info().camera;
    let mut rest = &a[1..];
    if rest.len() >= 3 {
        (cam.eye, cam.target, cam.vfov_deg) =
            (parse3(&rest[0]), parse3(&rest[1]), rest[2].parse()?);
        rest = &rest[3..];
    }
    let mut s = RenderSettings::new(cam);
    s.width = rest.first().map_or(Ok(320), |x| x.parse())?;
    s.height = rest.get(1).map_or(Ok(180), |x| x.parse())?;
    s.rays = RayKind::Diffuse;
    let sh = Shading {
        triangles: &tris,
        material_ids: &[],
    };
    let rays = record_rays(&b2, sh, &s)?;
    println!("{spec}: {} rays", rays.len());
    for (label, primary) in [("primary", true), ("bounces", false)] {
        let mut ex = Extra {
            cbvh: Some(&td),
            original: &original,
            ..Default::default()
        };
        let (mut st, mut s_c, mut s_b) = (
            TraversalStack::new(),
            RayStats::default(),
            RayStats::default(),
        );
        for (ray, bounce, q) in rays.iter().filter(|r| (r.1 == 0) == primary) {
            let _ = bounce;
            ex.pre = Some(RayPrecomp::new(ray));
            c.trace_boxes(ray, *q, &mut st, &mut s_c, &mut (), &mut ex);
            trace::Traverse::trace_observed(&b2, ray, *q, &mut st, &mut s_b, &mut ());
        }
        assert_eq!(ex.all, s_c.tri_tests, "every hit leaf is visited");
        let extra = s_c.tri_tests as f64 - s_b.tri_tests as f64;
        println!(
            "{label:<8} {:>8} rays  tri tests BVH {:.3}/ray, CBVH {:.3}/ray ({:+.1}%); tests in leaves whose original box is missed: {:.3}/ray flat, {:.3}/ray not flat (net extra {:.3}/ray)",
            s_c.rays,
            s_b.per_ray(s_b.tri_tests),
            s_c.per_ray(s_c.tri_tests),
            100.0 * extra / s_b.tri_tests.max(1) as f64,
            s_c.per_ray(ex.extra[0]),
            s_c.per_ray(ex.extra[1]),
            extra / s_c.rays.max(1) as f64
        );
    }
    Ok(())
}
