//! Traces a scene's diffuse bounce rays through the MBVH4 and BVH2 kernels many times, for
//! profiling one kernel in isolation (e.g. under `valgrind --tool=callgrind
//! --toggle-collect='*Mbvh4Accel*run*'`). `cargo run --release -p trace --example
//! kernel_cost -- SCENE [REPEATS [EYE TARGET FOV [KERNEL]]]` (EYE and TARGET as `x,y,z`,
//! or `- - -` for the scene's own camera; KERNEL one of `mbvh4`, `mbvh8`, `bvh2`, or
//! `mbvh8xN` for the 8-wide kernel's batch path interleaving N rays, to trace only that
//! one; a name with `-batch` appended traces runs of 1,024 rays through `closest_hits`
//! instead of one `closest_hit` call a ray; the `mbvh8xN` and `-batch` rows run only when
//! named). A seventh argument `primary` traces the render's primary rays instead of its
//! diffuse bounce rays. The 8-wide tree is collapsed from binned SAH, or from spatial
//! splits with `KC_TREE=sbvh` (see below); `KC_HOT=N` traces each ray N times in a row;
//! `KC_ROUNDS=N` times each kernel N times over (default 1), and a last line gives the
//! fastest round's CPU time.

use trace::{RayKind, RenderSettings, Shading, Traverse};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args.first().ok_or("usage: kernel_cost SCENE [REPEATS]")?;
    let repeats: usize = args.get(1).map(|r| r.parse()).transpose()?.unwrap_or(10);
    let sc = scene::open(spec, &scene::LoadOptions::default())?;
    let mesh = sc.mesh_at(0.0)?;
    let tris: Vec<geom::Triangle> = mesh.triangles_iter().collect();
    let aabbs = bvh::triangle_aabbs(&tris);
    let binned = bvh::BinnedSahBuilder::default().build(&aabbs)?;
    let b2 = trace::Bvh2Accel::new(binned.clone(), &tris, Default::default())?;
    let b4 = trace::Mbvh4Accel::new(bvh::collapse(&binned)?, &tris, Default::default())?;
    // `KC_TREE=sbvh`: the 8-wide tree collapsed from spatial splits (`bvh::SbvhBuilder`)
    // instead of binned SAH, with its options from `SBVH_GROWTH`, `SBVH_ALPHA`,
    // `SBVH_CINNER`, `SBVH_LEAF` and `SBVH_SBINS` where set.
    let b8 = if std::env::var("KC_TREE").as_deref() == Ok("sbvh") {
        let mut b = bvh::SbvhBuilder::default();
        b.max_growth = env_num("SBVH_GROWTH")?.unwrap_or(b.max_growth);
        b.alpha = env_num("SBVH_ALPHA")?.unwrap_or(b.alpha);
        b.sah.c_inner = env_num("SBVH_CINNER")?.unwrap_or(b.sah.c_inner);
        b.max_leaf_size = env_num("SBVH_LEAF")?.unwrap_or(b.max_leaf_size);
        b.spatial_bins = env_num("SBVH_SBINS")?.unwrap_or(b.spatial_bins);
        let t = b.build(&tris)?;
        println!(
            "sbvh (max_growth {}, alpha {}, c_inner {}, max_leaf_size {}, spatial_bins {}): {} nodes",
            b.max_growth,
            b.alpha,
            b.sah.c_inner,
            b.max_leaf_size,
            b.spatial_bins,
            t.nodes.len()
        );
        trace::Mbvh8Accel::from_bvh2(&t, &tris, Default::default())?
    } else {
        trace::Mbvh8Accel::from_bvh2(&binned, &tris, Default::default())?
    };
    let mut cam = sc.info().camera;
    let v3 = |a: &str| -> Result<geom::Vec3, Box<dyn std::error::Error>> {
        let c: Vec<f32> = a.split(',').map(str::parse).collect::<Result<_, _>>()?;
        match c[..] {
            [x, y, z] => Ok(geom::Vec3::new(x, y, z)),
            _ => Err(format!("{a}: expected x,y,z").into()),
        }
    };
    // `-` for EYE keeps the scene's own camera (so that KERNEL can still be named).
    if let [eye, target, fov, ..] = &args[2.min(args.len())..] {
        if eye != "-" {
            (cam.eye, cam.target, cam.vfov_deg) = (v3(eye)?, v3(target)?, fov.parse()?);
        }
    }
    let only = args.get(5);
    // The render's primary rays instead of its bounce rays.
    let primary = match args.get(6).map(String::as_str) {
        None | Some("diffuse") => false,
        Some("primary") => true,
        Some(other) => return Err(format!("{other}: expected primary or diffuse").into()),
    };
    let mut s = RenderSettings::new(cam);
    s.width = 320;
    s.height = 180;
    s.rays = RayKind::Diffuse;
    let shading = Shading {
        triangles: &tris,
        material_ids: &[],
    };
    let mut rays = Vec::new();
    trace::render::render_observed(
        &b2,
        shading,
        &s,
        trace::render::RayRecorder::default,
        |r| {
            rays.extend(
                r.rays
                    .into_iter()
                    .filter(|r| (r.1 > 0) != primary)
                    .map(|r| r.0),
            );
            Ok(())
        },
        None,
    )?;
    println!(
        "mbvh8 tree: {:.1} MB, {}, interleaves {:?} (last-level cache {:?} bytes)",
        b8.memory_bytes() as f64 / 1e6,
        b8.isa(),
        b8.interleave(),
        trace::last_level_cache_bytes()
    );
    // `KC_HOT=N`: each ray N times in a row, so that all but its first trace find its
    // nodes and triangles in the L1 cache (the kernel's cost without memory waits).
    if let Some(h) = env_num::<usize>("KC_HOT")? {
        if h == 0 {
            return Err("KC_HOT: expected at least 1".into());
        }
        rays = rays
            .iter()
            .flat_map(|r| std::iter::repeat_n(*r, h))
            .collect();
    }
    let mut stack = trace::TraversalStack::new();
    let mut kernels = vec![
        ("mbvh4".to_string(), trace::Accel::Mbvh4(b4)),
        ("mbvh8".to_string(), trace::Accel::Mbvh8(b8.clone())),
        ("bvh2".to_string(), trace::Accel::Bvh2(b2)),
    ];
    // The batch path, interleaving N rays, as a kernel of its own.
    if let Some(n) = only.and_then(|o| o.strip_prefix("mbvh8x")) {
        let b = b8.with_interleave(trace::Interleave::Rays(n.parse()?));
        kernels.push((format!("mbvh8x{n}"), trace::Accel::Mbvh8(b)));
    }
    let batch = only.is_some_and(|o| o.ends_with("-batch"));
    // `KC_ROUNDS=N`: the timed loop N times over (each round's counters alike), each
    // round printed, then the fastest; on a host whose speed drifts between runs the
    // fastest of several rounds compares binaries better than one round.
    let rounds = env_num::<usize>("KC_ROUNDS")?.unwrap_or(1);
    if rounds == 0 {
        return Err("KC_ROUNDS: expected at least 1".into());
    }
    let per_ray = |s: f64| s * 1e9 / (rays.len() * repeats) as f64;
    let mut out = vec![None; 1024];
    for (name, t) in &kernels {
        if only.is_some_and(|o| o.trim_end_matches("-batch") != name) {
            continue;
        }
        let mut fastest = f64::INFINITY;
        for _ in 0..rounds {
            let mut st = trace::RayStats::default();
            let start = std::time::Instant::now();
            let cpu_start = trace::thread_cpu_seconds();
            let mut hits = 0u64;
            for _ in 0..repeats {
                if batch || name.starts_with("mbvh8x") {
                    for chunk in rays.chunks(1024) {
                        let out = &mut out[..chunk.len()];
                        t.closest_hits(chunk, &mut stack, out, &mut st);
                        hits += out.iter().filter(|h| h.is_some()).count() as u64;
                    }
                    continue;
                }
                for r in &rays {
                    hits += t.closest_hit(r, &mut stack, &mut st).is_some() as u64;
                }
            }
            let secs = start.elapsed().as_secs_f64();
            let cpu = trace::thread_cpu_seconds() - cpu_start;
            println!(
                "{name}: {} rays x {repeats}: {:.1} ns/ray (CPU {:.1}), nodes/ray {:.2}, \
                 leaves/ray {:.2}, tris/ray {:.2}, hits {hits}",
                rays.len(),
                per_ray(secs),
                per_ray(cpu),
                st.per_ray(st.node_visits),
                st.per_ray(st.leaf_visits),
                st.per_ray(st.tri_tests)
            );
            fastest = fastest.min(per_ray(cpu));
        }
        println!("{name}: fastest of {rounds} rounds: CPU {fastest:.1} ns/ray");
    }
    Ok(())
}

/// The number in environment variable `name`, if it is set; an error names a value that
/// does not parse.
fn env_num<T: std::str::FromStr>(name: &str) -> Result<Option<T>, Box<dyn std::error::Error>> {
    match std::env::var(name) {
        Ok(v) => v
            .parse()
            .map(Some)
            .map_err(|_| format!("{name}: expected a number, got {v:?}").into()),
        Err(_) => Ok(None),
    }
}
