//! Tracing speed of the CBVH kernel beside the uncompressed `Bvh2` kernel, in one run:
//! the same rays (a primary or diffuse render) through the LBVH of [P3] §5.2 and its CBVH
//! (top-down relative and bottom-up modulo, 6 bits), best of `REPS` renders on one thread.
//!
//! `cargo run --release -p trace --example cbvh_speed -- SCENE [primary|diffuse] [W H]`

use cbvh::bottomup::{compress_hlbvh, StreamConfig};
use cbvh::{compress_topdown, Coords, Params};
use trace::{render, Bvh2Accel, CbvhAccel, RayKind, RenderSettings, Shading, Traverse};

const REPS: usize = 3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args
        .first()
        .ok_or("usage: cbvh_speed SCENE [primary|diffuse] [W H]")?;
    let kind = match args.get(1).map(String::as_str) {
        None | Some("primary") => RayKind::Primary,
        Some("diffuse") => RayKind::Diffuse,
        Some(k) => return Err(format!("unknown ray kind {k}").into()),
    };
    let w: u32 = args.get(2).map_or(Ok(640), |s| s.parse())?;
    let h: u32 = args.get(3).map_or(Ok(360), |s| s.parse())?;
    let scene = scene::open(spec, &Default::default())?;
    let mesh = scene.mesh_at(0.0)?;
    let tris: Vec<geom::Triangle> = mesh.triangles_iter().collect();
    let prims = bvh::triangle_aabbs(&tris);
    let hl = cbvh::study::paper_lbvh().build_highlevel(&prims)?;
    let lbvh = hl.to_bvh2();
    let td = compress_topdown(&lbvh, &Params::default())?.0;
    let m = StreamConfig {
        params: Params {
            coords: Coords::Modulo,
            ..Params::default()
        },
        ..StreamConfig::default()
    };
    let bu = compress_hlbvh(&hl, &m)?.0;
    let mut s = RenderSettings::new(scene.info().camera);
    (s.width, s.height, s.rays) = (w, h, kind);
    let shading = Shading {
        triangles: &tris,
        material_ids: &mesh.material_ids,
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let time = |a: &dyn Fn() -> trace::Render| {
        (0..REPS)
            .map(|_| a())
            .min_by(|x, y| x.stats.seconds.total_cmp(&y.stats.seconds))
            .unwrap()
    };
    let b2 = Bvh2Accel::new(lbvh, &tris, Default::default())?;
    let c_td = CbvhAccel::new(&td, &tris, Default::default())?;
    let c_bu = CbvhAccel::new(&bu, &tris, Default::default())?;
    let base = pool.install(|| time(&|| render(&b2, shading, &s, None, None).unwrap()));
    println!(
        "{spec}: {} triangles, {w}x{h} {kind:?}, {} rays",
        tris.len(),
        base.stats.total.rays
    );
    let row = |name: &str, r: &trace::Render, nodes: usize, bytes: u32| {
        let st = &r.stats.total;
        println!(
            "{name:<24} {:>7.3} Mrays/s  {:>5.2}x time  {:>7.2} boxes/ray  {:>6.2} tris/ray  {:>6.1} MiB nodes",
            r.stats.mrays_per_s,
            r.stats.seconds / base.stats.seconds,
            st.per_ray(st.box_tests),
            st.per_ray(st.tri_tests),
            (nodes * bytes as usize) as f64 / (1 << 20) as f64
        );
    };
    row("bvh2 (LBVH)", &base, b2.node_count(), b2.node_bytes());
    for (name, a) in [
        ("cbvh top-down relative", &c_td),
        ("cbvh bottom-up modulo", &c_bu),
    ] {
        let r = pool.install(|| time(&|| render(a, shading, &s, None, None).unwrap()));
        assert_eq!(
            r.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            base.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            "{name}: not the same image"
        );
        row(name, &r, a.node_count(), a.node_bytes());
    }
    Ok(())
}
