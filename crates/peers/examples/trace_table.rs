//! Traversal throughput of Arbor's kernels against Embree 3 and obvhs on the same rays.
//! `cargo run --release -p peers --features embree --example trace_table -- SCENE
//! [EYE TARGET FOV]` (EYE and TARGET as x,y,z). Prints a Markdown table.

fn parse(s: &str) -> geom::Vec3 {
    let v: Vec<f32> = s
        .split(',')
        .map(|p| p.trim().parse().expect("a number"))
        .collect();
    geom::Vec3::new(v[0], v[1], v[2])
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args
        .first()
        .ok_or("usage: trace_table SCENE [EYE TARGET FOV]")?;
    let sc = scene::open(spec, &scene::LoadOptions::default())?;
    let mesh = sc.mesh_at(0.0)?;
    let mut camera = sc.info().camera;
    if args.len() >= 4 {
        camera.eye = parse(&args[1]);
        camera.target = parse(&args[2]);
        camera.vfov_deg = args[3].parse()?;
    }
    let (w, h) = match std::env::var("TRACE_SIZE").ok() {
        Some(s) => {
            let v: Vec<u32> = s.split('x').map(|p| p.parse().unwrap()).collect();
            (v[0], v[1])
        }
        None => (640, 360),
    };
    let bench = peers::trace_bench::BenchScene {
        name: sc.info().name.clone(),
        positions: &mesh.positions,
        indices: &mesh.triangles,
        camera,
        width: w,
        height: h,
        bounces: 4,
    };
    let threads: Vec<usize> = std::env::var("TRACE_THREADS")
        .unwrap_or_else(|_| "1,2".into())
        .split(',')
        .map(|t| t.parse().expect("a thread count"))
        .collect();
    let repeats = std::env::var("TRACE_REPEATS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(5);
    if std::env::var("TRACE_STATS").is_ok() {
        peers::trace_bench::print_kernel_stats(&bench)?;
    }
    let rows = peers::trace_bench::run(&bench, &threads, repeats, &|m| eprintln!("{m}"))?;
    println!("| scene | rays | tracer | threads | Mrays/s | vs Embree | Mrays/CPU-s | vs Embree (CPU) | agreement |");
    println!("|---|---|---|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        println!(
            "| {} | {} ({}) | {} | {} | {:.2} | {} | {:.2} | {} | {:.4} |",
            r.scene,
            r.rays,
            r.ray_count,
            r.tracer,
            r.threads,
            r.mrays_per_s,
            r.vs_embree.map_or("-".into(), |v| format!("{v:.2}x")),
            r.mrays_per_cpu_s,
            r.vs_embree_cpu.map_or("-".into(), |v| format!("{v:.2}x")),
            r.agreement
        );
    }
    Ok(())
}
