//! Issue 34's ATRBVH experiments: SAH against the sweep SAH tree (as `arbor build --json`'s
//! `sah_vs_sweep`) of ATRBVH configurations, on any scenes.
//!
//! `ATR_CONFIGS='t=8,i=2;t=9,i=2,d=1' cargo run --release -p bvh --example atrbvh_quality --
//! ../shared/scenes/bunny.ply 'proc:soup?n=100000'`
//!
//! A configuration is a comma-separated list of `key=value` over the defaults of
//! `AtrbvhConfig`: `t` treelet size, `i` iterations, `g` γ (0: the treelet size), `d` double
//! γ per pass (0/1), `l` largest collapsed leaf (`max` for no bound), `s` the start tree
//! (`lbvh`, the default, `lbvh63` with 63-bit codes, `hlbvh`: plain HLBVH, `hlbvh+atrbvh`: the thesis's toplevel
//! ATRBVH, `hlbvh+sah`: the binned SAH top over the cells, both then restructured as a whole through `optimize`; `cells`: the same as
//! `hlbvh+atrbvh`, through `HlbvhAtrbvhBuilder::cells`, without `optimize`'s validation of
//! its input, so its time is the builder's). Every tree is validated; times are of one
//! build on the current rayon pool, for orientation only (`arbor bench build` gives the
//! timings that count).

use bvh::{
    optimize, validate, AtrbvhConfig, Bvh2, HlbvhAtrbvhBuilder, HlbvhBuilder, HlbvhSahBuilder,
    LbvhBuilder, MortonBits, SweepSahBuilder,
};
use std::time::Instant;

fn parse(spec: &str) -> Result<(AtrbvhConfig, String), String> {
    let mut c = AtrbvhConfig::default();
    let mut start = "lbvh".to_string();
    for kv in spec.split(',').filter(|s| !s.is_empty()) {
        let (k, v) = kv.split_once('=').ok_or(format!("bad item {kv:?}"))?;
        let num = || v.parse::<usize>().map_err(|e| format!("{kv}: {e}"));
        match k {
            "t" => c.treelet_size = num()?,
            "i" => c.iterations = num()?,
            "g" => c.gamma = num()?,
            "d" => c.double_gamma = num()? != 0,
            "l" if v == "max" => c.max_leaf_size = u32::MAX,
            "l" => c.max_leaf_size = num()? as u32,
            "s" => start = v.to_string(),
            _ => return Err(format!("unknown key {k:?}")),
        }
    }
    Ok((c, start))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let configs = std::env::var("ATR_CONFIGS").unwrap_or_else(|_| "t=8,i=2".into());
    let configs: Vec<(String, AtrbvhConfig, String)> = configs
        .split(';')
        .map(|s| parse(s).map(|(c, st)| (s.to_string(), c, st)))
        .collect::<Result<_, _>>()?;
    for spec in std::env::args().skip(1) {
        let scene = scene::open(&spec, &Default::default())?;
        let mesh = scene.mesh_at(0.0)?;
        let prims = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
        let sweep = SweepSahBuilder::default().build(&prims)?;
        // Diagnostic: the sweep with one primitive per leaf, the reference for `l=1` trees.
        let sweep1 = SweepSahBuilder {
            max_leaf_size: 1,
            ..Default::default()
        }
        .build(&prims)?;
        let name = spec.rsplit('/').next().unwrap_or(&spec);
        let timed = |f: &dyn Fn() -> Result<Bvh2, bvh::BuildError>| {
            let s = Instant::now();
            let t = f();
            (t, s.elapsed().as_secs_f64() * 1e3)
        };
        let (hl, hl_ms) = timed(&|| HlbvhBuilder::default().build(&prims));
        println!(
            "{name}: {} tris, hlbvh {hl_ms:.0} ms, SAH {:.4} x sweep",
            prims.len(),
            hl?.sah_vs(&sweep)
        );
        for (label, cfg, start) in &configs {
            let (t, ms) = timed(&|| {
                if start == "cells" {
                    return HlbvhAtrbvhBuilder {
                        cells: Some(cfg.clone()),
                        ..Default::default()
                    }
                    .build(&prims);
                }
                let mut t = match start.as_str() {
                    "lbvh" => LbvhBuilder::default().build(&prims)?,
                    "lbvh63" => LbvhBuilder {
                        bits: MortonBits::Bits63,
                        ..Default::default()
                    }
                    .build(&prims)?,
                    "hlbvh" => HlbvhBuilder::default().build(&prims)?,
                    "hlbvh+atrbvh" => HlbvhAtrbvhBuilder::default().build(&prims)?,
                    "hlbvh+sah" => HlbvhSahBuilder::default().build(&prims)?,
                    s => panic!("unknown start tree {s}"),
                };
                optimize(&mut t, &prims, cfg)?;
                Ok(t)
            });
            let t = t?;
            validate(&t, &prims, cfg.max_leaf_size.max(8))?;
            let st = t.stats();
            println!(
                "{name}\t{label}\tsah_vs_sweep {:.4}\tvs 1-leaf sweep {:.4}\t{ms:.0} ms ({:.2}x hlbvh)\tmax leaf {}",
                t.sah_vs(&sweep),
                t.sah_vs(&sweep1),
                ms / hl_ms,
                st.max_leaf_size
            );
        }
    }
    Ok(())
}
