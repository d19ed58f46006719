//! Issue 34: why HLBVH's SAH on Crytek Sponza is above Embree LOW's (Embree 3's Morton
//! builder), by experiment. For each scene it builds HLBVH variants, Embree LOW, and an
//! emulation of the Morton-prefix tree that both are (a split at the highest differing
//! code bit), whose code mapping and treatment of equal codes can be set to either
//! builder's: `emu arbor chunks8` is HLBVH's tree and `emu x0.99 zyx round recode` Embree
//! LOW's, node for node in SAH, so every difference between the two can be switched on
//! alone. Results and their reading: docs/builders.md, "HLBVH's SAH on Crytek Sponza".
//!
//! `cargo run --release -p peers --features embree --example hlbvh_sah -- SCENE...`
//!
//! `HL_MODE` picks what is printed per scene: `table` (the default: SAH over the sweep
//! SAH tree, its inner-node and leaf parts, leaf sizes), `grid` (the SAH of HLBVH's tree
//! on grids scaled or shifted by less than a cell, and with large primitives apart at
//! several thresholds), `depth` (the SAH parts by node depth on the exact and the 0.99
//! grid), `root` (the top two levels' boxes on both grids and the primitives spanning
//! over 30% of the scene), `time` (best of 7 single builds on the current pool, for
//! orientation: `arbor bench build` gives the timings that count).

use bvh::{
    optimize, validate, AtrbvhConfig, Bvh2, ChildRef, HlbvhBuilder, LbvhBuilder, MortonBits,
    MortonGrid, Node, SahParams, SweepSahBuilder,
};
use geom::Aabb;
use peers::{EmbreeBuilder, EmbreeDevice};

/// (inner part, leaf part) of the normalized SAH, and leaf counts by size 1, 2, 3-4, 5-8, 9+.
fn parts(t: &Bvh2) -> (f64, f64, [usize; 5]) {
    let ra = t.bounds.half_area() as f64;
    let ci = SahParams::THESIS.c_inner as f64;
    let mut inner = ci * t.bounds.half_area() as f64 / ra;
    let mut leaf = 0.0;
    let mut hist = [0usize; 5];
    for n in &t.nodes {
        for s in 0..2 {
            let c = n.children[s];
            let a = n.child_aabb(s).half_area() as f64 / ra;
            if c.is_leaf() {
                leaf += a * c.count as f64;
                let k = match c.count {
                    1 => 0,
                    2 => 1,
                    3..=4 => 2,
                    5..=8 => 3,
                    _ => 4,
                };
                hist[k] += 1;
            } else if c.is_inner() {
                inner += ci * a;
            }
        }
    }
    (inner, leaf, hist)
}

/// The box of the primitives' centroids.
fn centroid_bounds(prims: &[Aabb]) -> Aabb {
    prims.iter().fold(Aabb::EMPTY, |a, b| {
        let c = (b.min + b.max) * 0.5;
        a.union(Aabb::new(c, c))
    })
}

/// The inner-node and leaf parts of the normalized SAH by depth of the node (root 0), the
/// last entry summing depths 24 and below.
fn by_depth(t: &Bvh2) -> (Vec<f64>, Vec<f64>) {
    let ra = t.bounds.half_area() as f64;
    let mut inner = vec![0.0; 25];
    let mut leaf = vec![0.0; 25];
    let ci = SahParams::THESIS.c_inner as f64;
    inner[0] = ci;
    let mut st = vec![(0usize, 0usize)];
    while let Some((i, d)) = st.pop() {
        for s in 0..2 {
            let c = t.nodes[i].children[s];
            let a = t.nodes[i].child_aabb(s).half_area() as f64 / ra;
            let k = (d + 1).min(24);
            if c.is_leaf() {
                leaf[k] += a * c.count as f64;
            } else if c.is_inner() {
                inner[k] += ci * a;
                st.push((c.index as usize, d + 1));
            }
        }
    }
    (inner, leaf)
}

/// ATRBVH's SAH leaf collapse alone (no restructuring pass), leaves up to `max`.
fn collapsed(t: &Bvh2, prims: &[Aabb], max: u32) -> Bvh2 {
    let mut o = t.clone();
    optimize(
        &mut o,
        prims,
        &AtrbvhConfig {
            iterations: 0,
            max_leaf_size: max,
            sah: SahParams::THESIS,
            ..Default::default()
        },
    )
    .unwrap();
    o
}

/// `b` with its axes reordered: axis `k` of the result is axis `perm[k]` of `b`.
fn permuted(b: &Aabb, perm: [usize; 3]) -> Aabb {
    let f = |v: geom::Vec3| {
        let a = [v.x, v.y, v.z];
        geom::Vec3::new(a[perm[0]], a[perm[1]], a[perm[2]])
    };
    Aabb::new(f(b.min), f(b.max))
}

/// The inverse of [`permuted`].
fn permuted_back(b: &Aabb, perm: [usize; 3]) -> Aabb {
    let f = |v: geom::Vec3| {
        let a = [v.x, v.y, v.z];
        let mut o = [0.0; 3];
        for k in 0..3 {
            o[perm[k]] = a[k];
        }
        geom::Vec3::new(o[0], o[1], o[2])
    };
    Aabb::new(f(b.min), f(b.max))
}

/// How the emulated Morton builder codes a centroid.
#[derive(Clone, Copy, Debug)]
struct Mapping {
    /// Cells per axis as a float (HLBVH: 1024; Embree: 1024 * 0.99).
    cells: f32,
    /// Round to the nearest cell (Embree's `vint4(vfloat4)`) rather than truncate.
    round: bool,
    /// The axis of the top bit of each triple comes first: `[0, 1, 2]` is x, y, z (HLBVH);
    /// `[2, 1, 0]` is z, y, x.
    order: [usize; 3],
    /// Cells added before rounding: the grid's origin moved down by this many cells.
    offset: f32,
    /// Primitives whose box spans more than this fraction of the scene's centroid box on
    /// some axis get a key above every small primitive's (0: no size class).
    big: f32,
}

/// (code, index) of the primitives `ids` over their own centroid bounds.
fn codes(prims: &[Aabb], ids: &[u32], m: Mapping) -> Vec<(u32, u32)> {
    let c = |i: u32| {
        let b = &prims[i as usize];
        let v = b.min + b.max;
        [v.x, v.y, v.z]
    };
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in ids {
        let v = c(i);
        for k in 0..3 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    let mut out: Vec<(u32, u32)> = ids
        .iter()
        .map(|&i| {
            let v = c(i);
            let mut q = [0u32; 3];
            for k in 0..3 {
                let d = hi[k] - lo[k];
                let s = if d > 1e-19 { m.cells / d } else { 0.0 };
                let r = (v[k] - lo[k]) * s + if d > 1e-19 { m.offset } else { 0.0 };
                let r = if m.round {
                    r.round_ties_even()
                } else {
                    r.floor()
                };
                q[k] = (r.max(0.0) as u32).min(1023);
            }
            let mut code = geom::morton30([q[m.order[0]], q[m.order[1]], q[m.order[2]]]);
            if m.big > 0.0 {
                let b = &prims[i as usize];
                let e = b.max - b.min;
                let ex = [e.x, e.y, e.z];
                if (0..3).any(|k| 2.0 * ex[k] > m.big * (hi[k] - lo[k])) {
                    code |= 1 << 30;
                }
            }
            (code, i)
        })
        .collect();
    out.sort_unstable();
    out
}

/// What the emulated builder does with a range whose codes are all equal.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Runs {
    /// HLBVH: leaves of up to `max_leaf` in sorted order, a radix tree over the chunks.
    Chunks(u32),
    /// Embree's Morton builder: codes made again over the range's centroid bounds; a range
    /// still equal is split at its middle; leaves of one primitive.
    Recode,
}

/// A subtree written into the emulated tree: its reference and box.
type Sub = (ChildRef, Aabb);

/// The Morton-prefix tree (a split at the highest differing code bit) that HLBVH and
/// Embree's Morton builder both build, with `m`'s codes and `runs`' treatment of equal
/// codes.
fn emulate(prims: &[Aabb], m: Mapping, runs: Runs) -> Bvh2 {
    let ids: Vec<u32> = (0..prims.len() as u32).collect();
    let mut sorted = codes(prims, &ids, m);
    let mut nodes: Vec<Node> = Vec::new();
    let mut idx: Vec<u32> = Vec::new();
    fn leaf(prims: &[Aabb], s: &[(u32, u32)], idx: &mut Vec<u32>) -> (ChildRef, Aabb) {
        let first = idx.len() as u32;
        let mut b = Aabb::EMPTY;
        for &(_, i) in s {
            idx.push(i);
            b = b.union(prims[i as usize]);
        }
        (ChildRef::leaf(first, s.len() as u32), b)
    }
    fn node(
        nodes: &mut Vec<Node>,
        f: &mut dyn FnMut(&mut Vec<Node>, usize) -> Sub,
    ) -> (ChildRef, Aabb) {
        let me = nodes.len();
        nodes.push(Node::EMPTY);
        let (c0, b0) = f(nodes, 0);
        let (c1, b1) = f(nodes, 1);
        nodes[me] = Node::new(&b0, c0, &b1, c1);
        (ChildRef::inner(me as u32), b0.union(b1))
    }
    // A radix tree over `n` chunks of `max` (the last may be short) of `s`.
    fn chunks(
        prims: &[Aabb],
        s: &[(u32, u32)],
        max: usize,
        nodes: &mut Vec<Node>,
        idx: &mut Vec<u32>,
    ) -> (ChildRef, Aabb) {
        if s.len() <= max {
            return leaf(prims, s, idx);
        }
        let n = s.len().div_ceil(max) as u32;
        let bit = 31 - (n - 1).leading_zeros();
        let cut = (1usize << bit) * max;
        node(nodes, &mut |nodes, k| {
            let part = if k == 0 { &s[..cut] } else { &s[cut..] };
            chunks(prims, part, max, nodes, idx)
        })
    }
    fn rec(
        prims: &[Aabb],
        s: &mut [(u32, u32)],
        m: Mapping,
        runs: Runs,
        nodes: &mut Vec<Node>,
        idx: &mut Vec<u32>,
    ) -> (ChildRef, Aabb) {
        if s.len() == 1 {
            return leaf(prims, s, idx);
        }
        let (a, b) = (s[0].0, s[s.len() - 1].0);
        let cut = if a != b {
            let mask = 1u32 << (31 - (a ^ b).leading_zeros());
            s.partition_point(|e| e.0 & mask == 0)
        } else {
            match runs {
                Runs::Chunks(max) => return chunks(prims, s, max as usize, nodes, idx),
                Runs::Recode => {
                    let ids: Vec<u32> = s.iter().map(|e| e.1).collect();
                    let again = codes(prims, &ids, m);
                    s.copy_from_slice(&again);
                    let (a, b) = (s[0].0, s[s.len() - 1].0);
                    if a != b {
                        let mask = 1u32 << (31 - (a ^ b).leading_zeros());
                        s.partition_point(|e| e.0 & mask == 0)
                    } else {
                        s.len() / 2
                    }
                }
            }
        };
        let (l, r) = s.split_at_mut(cut);
        let mut parts = [Some(l), Some(r)];
        node(nodes, &mut |nodes, k| {
            rec(prims, parts[k].take().unwrap(), m, runs, nodes, idx)
        })
    }
    let (root, b) = rec(prims, &mut sorted, m, runs, &mut nodes, &mut idx);
    assert!(root.is_inner() && root.index == 0);
    Bvh2 {
        nodes,
        prim_indices: idx,
        bounds: b,
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let device = EmbreeDevice::new(0)?;
    let mode = std::env::var("HL_MODE").unwrap_or_else(|_| "table".into());
    if !["table", "grid", "depth", "root", "time"].contains(&mode.as_str()) {
        return Err(format!("HL_MODE {mode:?} is not table, grid, depth, root or time").into());
    }
    let arbor = Mapping {
        cells: 1024.0,
        round: false,
        order: [0, 1, 2],
        offset: 0.0,
        big: 0.0,
    };
    for spec in std::env::args().skip(1) {
        let scene = scene::open(&spec, &Default::default())?;
        let mesh = scene.mesh_at(0.0)?;
        let prims = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
        let sweep = SweepSahBuilder::default().build(&prims)?;
        let name = spec.rsplit('/').next().unwrap_or(&spec).to_string();
        println!(
            "{name}: {} triangles, sweep SAH {:.3}",
            prims.len(),
            sweep.sah()
        );
        let hl = |f: &dyn Fn(&mut HlbvhBuilder)| {
            let mut b = HlbvhBuilder::default();
            f(&mut b);
            b.build(&prims).unwrap()
        };
        let embree = |max: u32| {
            EmbreeBuilder {
                max_leaf_size: max,
                ..Default::default()
            }
            .build_on(&device, &prims)
            .unwrap()
            .bvh
        };
        // The emulated HLBVH tree on a grid of 1024 * scale cells per axis.
        let scaled = |scale: f32| {
            emulate(
                &prims,
                Mapping {
                    cells: 1024.0 * scale,
                    ..arbor
                },
                Runs::Chunks(8),
            )
        };
        if mode == "grid" {
            let mut line = String::new();
            for scale in [0.9, 0.95, 0.97, 0.98, 0.99, 0.995, 0.999, 0.9999, 1.0] {
                let t = scaled(scale);
                line += &format!(" s{scale}:{:.4}", t.sah_vs(&sweep));
            }
            for (cells, offset) in [
                (1023.0, 0.5),
                (1024.0, 0.0),
                (1022.0, 1.0),
                (1023.0, 0.25),
                (1023.0, 0.75),
                (1023.9, 0.05),
            ] {
                let t = emulate(
                    &prims,
                    Mapping {
                        cells,
                        offset,
                        ..arbor
                    },
                    Runs::Chunks(8),
                );
                line += &format!(" c{cells}+{offset}:{:.4}", t.sah_vs(&sweep));
            }
            for big in [0.5, 0.25, 0.125, 0.0625] {
                let t = emulate(&prims, Mapping { big, ..arbor }, Runs::Chunks(8));
                line += &format!(" big{big}:{:.4}", t.sah_vs(&sweep));
            }
            println!("  {line}");
            continue;
        }
        if mode == "depth" {
            for scale in [1.0, 0.99] {
                let t = scaled(scale);
                let (inner, leaf) = by_depth(&t);
                let f = |v: &[f64]| {
                    v.iter()
                        .map(|x| format!("{x:.1}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                };
                println!(
                    "  s{scale}: inner by depth {}\n         leaf by depth {}",
                    f(&inner),
                    f(&leaf)
                );
            }
            continue;
        }
        if mode == "root" {
            println!("  scene box {:?}", sweep.bounds);
            for scale in [1.0, 0.99] {
                let t = scaled(scale);
                // The two depth-2 levels: print every node's child boxes down to depth 2.
                let mut st = vec![(0usize, 0usize, String::from("root"))];
                while let Some((i, d, path)) = st.pop() {
                    let n = &t.nodes[i];
                    for s in 0..2 {
                        let b = n.child_aabb(s);
                        println!(
                            "  s{scale} {path}.{s}: area {:.3} of root, box {:?}..{:?}",
                            b.half_area() / t.bounds.half_area(),
                            b.min,
                            b.max
                        );
                        if d < 1 && n.children[s].is_inner() {
                            st.push((n.children[s].index as usize, d + 1, format!("{path}.{s}")));
                        }
                    }
                }
            }
            // The primitives `large_prims: Some(0.5)` names, and those of them whose
            // centroid is within 0.5% of the middle of the centroid box on x.
            let cb = centroid_bounds(&prims);
            let e = cb.max - cb.min;
            let large: Vec<usize> = (0..prims.len())
                .filter(|&i| {
                    let d = prims[i].max - prims[i].min;
                    d.x > 0.5 * e.x || d.y > 0.5 * e.y || d.z > 0.5 * e.z
                })
                .collect();
            let mid = large
                .iter()
                .filter(|&&i| {
                    let c = (prims[i].min.x + prims[i].max.x) * 0.5;
                    ((c - cb.min.x) / e.x - 0.5).abs() < 0.005
                })
                .count();
            let below = large
                .iter()
                .filter(|&&i| {
                    let c = (prims[i].min.x + prims[i].max.x) * 0.5;
                    let r = (c - cb.min.x) / e.x;
                    (0.495..0.5).contains(&r)
                })
                .count();
            println!(
                "  {} primitives wider than half the centroid box on an axis; {mid} of them centred within 0.5% of its middle on x, {below} of those below it",
                large.len()
            );
            // The primitives whose box spans more than 30% of the scene on some axis.
            let e = sweep.bounds.max - sweep.bounds.min;
            let big: Vec<usize> = (0..prims.len())
                .filter(|&i| {
                    let d = prims[i].max - prims[i].min;
                    d.x > 0.3 * e.x || d.y > 0.3 * e.y || d.z > 0.3 * e.z
                })
                .collect();
            println!(
                "  {} primitives span over 30% of the scene on an axis",
                big.len()
            );
            for &i in big.iter().take(20) {
                let b = prims[i];
                let c = (b.min + b.max) * 0.5;
                let cb = centroid_bounds(&prims);
                let r = (c - cb.min) / (cb.max - cb.min);
                println!(
                    "    {i}: {:?}..{:?} centroid at {:?} of the centroid box",
                    b.min, b.max, r
                );
            }
            continue;
        }
        if mode == "time" {
            let best = |f: &mut dyn FnMut()| {
                (0..7)
                    .map(|_| {
                        let t = std::time::Instant::now();
                        f();
                        t.elapsed().as_secs_f64() * 1e3
                    })
                    .fold(f64::INFINITY, f64::min)
            };
            let base = HlbvhBuilder::default().build(&prims)?;
            let h = best(&mut || {
                HlbvhBuilder::default().build(&prims).unwrap();
            });
            let large = HlbvhBuilder {
                large_prims: Some(0.5),
                ..Default::default()
            };
            let l = best(&mut || {
                large.build(&prims).unwrap();
            });
            let c = best(&mut || {
                collapsed(&base, &prims, 8);
            });
            let v = best(&mut || {
                validate(&base, &prims, 8).unwrap();
            });
            let e = best(&mut || {
                EmbreeBuilder::default().build_on(&device, &prims).unwrap();
            });
            println!("  ms (best of 7): hlbvh {h:.2}  hlbvh large 0.5 {l:.2}  optimize(i=0) {c:.2} of which validate {v:.2}  embree-low (with conversion) {e:.2}");
            continue;
        }
        let base = hl(&|_| {});
        let low = embree(8);
        let mut trees: Vec<(String, Bvh2)> = vec![
            ("hlbvh".into(), base.clone()),
            ("hlbvh large 0.5".into(), hl(&|b| b.large_prims = Some(0.5))),
            (
                "hlbvh large 0.25".into(),
                hl(&|b| b.large_prims = Some(0.25)),
            ),
            (
                "hlbvh bits63 large 0.5".into(),
                hl(&|b| {
                    b.bits = MortonBits::Bits63;
                    b.large_prims = Some(0.5);
                }),
            ),
            ("hlbvh bits63".into(), hl(&|b| b.bits = MortonBits::Bits63)),
            ("hlbvh leaf1".into(), hl(&|b| b.max_leaf_size = 1)),
            (
                "hlbvh no-combine".into(),
                hl(&|b| b.combine_identical = false),
            ),
            ("hlbvh cube".into(), hl(&|b| b.grid = MortonGrid::Cube)),
            ("hlbvh +collapse8".into(), collapsed(&base, &prims, 8)),
            ("lbvh".into(), LbvhBuilder::default().build(&prims)?),
        ];
        // Axis orders: which axis takes the top bit of each code triple (HLBVH: x, y, z).
        for perm in [[0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]] {
            let p: Vec<Aabb> = prims.iter().map(|b| permuted(b, perm)).collect();
            let mut t = HlbvhBuilder::default().build(&p)?;
            t.bounds = permuted_back(&t.bounds, perm);
            for n in &mut t.nodes {
                for s in 0..2 {
                    let b = permuted_back(&n.child_aabb(s), perm);
                    n.set_child_aabb(s, &b);
                }
            }
            trees.push((format!("hlbvh axes {perm:?}"), t));
        }
        trees.extend([
            ("embree-low".into(), low.clone()),
            ("embree-low leaf1".into(), embree(1)),
            ("embree-low +collapse8".into(), collapsed(&low, &prims, 8)),
        ]);
        // The emulation: HLBVH's mapping and Embree's (1024 * 0.99 cells, z's bit first in
        // each triple, rounding to the nearest cell), alone and together, with either
        // treatment of equal codes.
        for (m, mname) in [
            (arbor, "arbor"),
            (
                Mapping {
                    order: [2, 1, 0],
                    ..arbor
                },
                "zyx",
            ),
            (
                Mapping {
                    cells: 1024.0 * 0.99,
                    ..arbor
                },
                "x0.99",
            ),
            (
                Mapping {
                    cells: 1024.0 * 0.99,
                    order: [2, 1, 0],
                    ..arbor
                },
                "x0.99 zyx",
            ),
            (
                Mapping {
                    cells: 1024.0 * 0.99,
                    order: [2, 1, 0],
                    round: true,
                    ..arbor
                },
                "x0.99 zyx round",
            ),
            (
                Mapping {
                    cells: 1024.0 * 0.99,
                    round: true,
                    ..arbor
                },
                "x0.99 xyz round",
            ),
        ] {
            for (runs, rname) in [(Runs::Chunks(8), "chunks8"), (Runs::Recode, "recode")] {
                trees.push((format!("emu {mname} {rname}"), emulate(&prims, m, runs)));
            }
        }
        for (label, t) in trees.iter_mut() {
            validate(t, &prims, 8).map_err(|e| format!("{label}: {e}"))?;
            let (i, l, h) = parts(t);
            println!(
                "  {label:26} sah_vs_sweep {:.4}  inner {:.2} leaf {:.2}  leaves {:7}  sizes 1/2/3-4/5-8/9+ {:?}",
                t.sah_vs(&sweep),
                i,
                l,
                t.stats().leaves,
                h
            );
        }
    }
    Ok(())
}
