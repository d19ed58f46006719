//! Regression guard for refactors that must not change any tree (issue 34, "one engine per
//! concept"): a structural fingerprint (FNV-1a of the `Debug` text of the whole tree: every
//! node's boxes and child references, the leaf table and the bounds, plus the SAH bits) of
//! every builder's output on fixed inputs. The expected values were recorded from the code
//! before the shared split engine and layout routine (base 7f4edb0); they are not fitted
//! results, only "the same bits as before". A builder change that is meant to change trees
//! updates them (run `print_fingerprints` with `--ignored --nocapture`).

use crate::testutil::{adversarial, proc_scene, soup};
use crate::*;
use geom::Aabb;

/// FNV-1a (64 bit) of a string: stable across Rust releases, unlike `DefaultHasher`.
fn fnv(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The default configuration of builder type `$t` on `$th` worker threads.
macro_rules! on_threads {
    ($t:ident, $th:expr) => {
        $t {
            threads: $th,
            ..Default::default()
        }
    };
}

/// Fingerprint of a binary tree: its `Debug` text and its SAH bits.
fn fp2(t: &Bvh2) -> u64 {
    fnv(&format!("{t:?} {}", sah_cost(t).to_bits()))
}

/// Fingerprint of a 4-wide tree.
fn fp4(t: &Mbvh4) -> u64 {
    fnv(&format!("{t:?} {}", t.normalized_sah().to_bits()))
}

/// The inputs: random soups (one above the parallel thresholds), a procedural cloth, the
/// adversarial sets.
fn inputs() -> Vec<(String, Vec<Aabb>)> {
    let mut v = vec![
        ("soup 40K".to_string(), soup(40_000, 2.0, 5)),
        ("soup 3K".to_string(), soup(3_000, 10.0, 9)),
        ("cloth".to_string(), proc_scene("proc:cloth?n=5000")),
    ];
    v.extend(adversarial().into_iter().map(|(n, p)| (n.to_string(), p)));
    let bunny = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/scenes/bunny.ply"
    );
    if std::path::Path::new(bunny).exists() {
        let s = scene::open(bunny, &Default::default()).unwrap();
        let m = s.mesh_at(0.0).unwrap();
        let b = indexed_triangle_aabbs(&m.positions, &m.triangles).unwrap();
        v.push(("bunny".to_string(), b));
    } else {
        println!("skipping bunny: {bunny} not found");
    }
    v
}

/// Every builder's fingerprint on every input, as `(label, hash)`, 2 worker threads.
fn fingerprints() -> Vec<(String, u64)> {
    let mut out = Vec::new();
    for (name, prims) in inputs() {
        let mut add2 = |b: &str, t: &Bvh2| out.push((format!("{name} / {b}"), fp2(t)));
        let th = 2;
        for bins in [8, 16, 32] {
            for max_leaf_size in [1, 4, 8] {
                let base = on_threads!(BinnedSahBuilder, th);
                let b = BinnedSahBuilder {
                    bins,
                    max_leaf_size,
                    ..base
                };
                add2(
                    &format!("binned {bins}/{max_leaf_size}"),
                    &b.build(&prims).unwrap(),
                );
            }
        }
        for max_leaf_size in [1, 8] {
            let b = SweepSahBuilder {
                max_leaf_size,
                ..on_threads!(SweepSahBuilder, th)
            };
            add2(&format!("sweep {max_leaf_size}"), &b.build(&prims).unwrap());
        }
        let lbvh = on_threads!(LbvhBuilder, th).build(&prims).unwrap();
        add2("lbvh", &lbvh);
        let hl = on_threads!(HlbvhBuilder, th);
        add2("hlbvh", &hl.build(&prims).unwrap());
        let cut = HlbvhBuilder {
            highlevel_threshold: Some(toplevel::default_threshold(hl.bits)),
            ..hl.clone()
        };
        add2(
            "hlbvh cells",
            &cut.build_highlevel(&prims).unwrap().to_bvh2(),
        );
        add2(
            "hlbvh+sah",
            &on_threads!(HlbvhSahBuilder, th).build(&prims).unwrap(),
        );
        let t = on_threads!(HlbvhAtrbvhBuilder, th).build(&prims).unwrap();
        add2("hlbvh+atrbvh", &t);
        let config = on_threads!(AtrbvhConfig, th);
        let t = AtrbvhBuilder {
            bits: Default::default(),
            config,
        }
        .build(&prims)
        .unwrap();
        add2("atrbvh", &t);
        // Issue 34's whole-tree pass over HLBVH+ATRBVH (one pass, leaves collapsed), and a
        // multi-pass ATRBVH with γ doubling and a larger treelet (re-layout between passes).
        let t = HlbvhAtrbvhBuilder {
            cells: Some(AtrbvhConfig {
                threads: th,
                ..AtrbvhConfig::one_pass()
            }),
            ..on_threads!(HlbvhAtrbvhBuilder, th)
        }
        .build(&prims)
        .unwrap();
        add2("hlbvh+atrbvh-cells", &t);
        let t = AtrbvhBuilder {
            bits: Default::default(),
            config: AtrbvhConfig {
                treelet_size: 9,
                iterations: 3,
                double_gamma: true,
                ..on_threads!(AtrbvhConfig, th)
            },
        }
        .build(&prims)
        .unwrap();
        add2("atrbvh t9 i3 doubling", &t);
        add2("ploc", &on_threads!(PlocBuilder, th).build(&prims).unwrap());
        let mut t = lbvh.clone();
        reinsert(&mut t, &prims, &on_threads!(ReinsertConfig, th)).unwrap();
        add2("lbvh+reinsert", &t);
        for wide in [true, false] {
            let t = Mbvh4TopDownBuilder {
                threads: th,
                wide_node_cost: wide,
                ..Default::default()
            }
            .build(&prims)
            .unwrap();
            out.push((format!("{name} / mbvh4 topdown {wide}"), fp4(&t)));
        }
        // The streaming collapse of HLBVH's emission (its own renumbering into preorder).
        let hl = on_threads!(HlbvhBuilder, th)
            .build_highlevel(&prims)
            .unwrap();
        out.push((
            format!("{name} / stream collapse"),
            fp4(&stream_collapse(&hl).unwrap().0),
        ));
        let sweep = SweepSahBuilder::default().build(&prims).unwrap();
        out.push((
            format!("{name} / collapse(sweep)"),
            fp4(&collapse(&sweep).unwrap()),
        ));
    }
    out
}

/// Prints the table below (for updating it deliberately).
#[test]
#[ignore]
fn print_fingerprints() {
    for (label, h) in fingerprints() {
        println!("    (\"{label}\", {h:#018x}),");
    }
}

/// Every builder's tree is bit for bit the one recorded before the refactor.
#[test]
fn trees_are_unchanged() {
    let got = fingerprints();
    let mut bad = Vec::new();
    for (label, h) in &got {
        match EXPECTED.iter().find(|(l, _)| l == label) {
            Some((_, e)) if e == h => {}
            Some((_, e)) => bad.push(format!("{label}: {h:#018x}, recorded {e:#018x}")),
            None => bad.push(format!("{label}: not recorded")),
        }
    }
    // Only the shared scene may be absent (outside the workspace).
    let missing = EXPECTED
        .iter()
        .filter(|(l, _)| !l.starts_with("bunny") && !got.iter().any(|(g, _)| g == l));
    bad.extend(missing.map(|(l, _)| format!("{l}: not built")));
    assert!(bad.is_empty(), "trees changed:\n{}", bad.join("\n"));
}

/// Recorded on base 7f4edb0 (the stream collapse rows on e66670b).
const EXPECTED: &[(&str, u64)] = &[
    ("soup 40K / binned 8/1", 0xc3155623356f4562),
    ("soup 40K / binned 8/4", 0xa4bb89d99c86d57c),
    ("soup 40K / binned 8/8", 0xa4bb89d99c86d57c),
    ("soup 40K / binned 16/1", 0xbf9a492d8f4e0136),
    ("soup 40K / binned 16/4", 0x534523cd97f3ee8c),
    ("soup 40K / binned 16/8", 0x534523cd97f3ee8c),
    ("soup 40K / binned 32/1", 0x968248a2c60054c8),
    ("soup 40K / binned 32/4", 0x63fa6f09467b741d),
    ("soup 40K / binned 32/8", 0x63fa6f09467b741d),
    ("soup 40K / sweep 1", 0x8850a2b0d4fdd3af),
    ("soup 40K / sweep 8", 0xe3e9479e7bbacd08),
    ("soup 40K / lbvh", 0x203158589f8666f8),
    ("soup 40K / hlbvh", 0xac00cbd1bdccf12e),
    ("soup 40K / hlbvh cells", 0xac00cbd1bdccf12e),
    ("soup 40K / hlbvh+sah", 0x46240047aafc5dc0),
    ("soup 40K / hlbvh+atrbvh", 0x72f2bf9012117332),
    ("soup 40K / atrbvh", 0x32bb531881cfae4f),
    ("soup 40K / ploc", 0x635c7432824dd7de),
    ("soup 40K / lbvh+reinsert", 0x94aa7c2c63f0e466),
    ("soup 40K / mbvh4 topdown true", 0x2c585e35c9766aee),
    ("soup 40K / mbvh4 topdown false", 0x7320efe7bee1fc96),
    ("soup 40K / collapse(sweep)", 0x90cf2cfb62f10840),
    ("soup 3K / binned 8/1", 0xe0bd27a38609f010),
    ("soup 3K / binned 8/4", 0x28bd4dfdd3ad0d13),
    ("soup 3K / binned 8/8", 0x28bd4dfdd3ad0d13),
    ("soup 3K / binned 16/1", 0x6db7250cf2cf5b41),
    ("soup 3K / binned 16/4", 0x69beb20f86887754),
    ("soup 3K / binned 16/8", 0x69beb20f86887754),
    ("soup 3K / binned 32/1", 0xe2ff6d9e4db0a0b4),
    ("soup 3K / binned 32/4", 0x2cbe6fe0a52c8d40),
    ("soup 3K / binned 32/8", 0x2cbe6fe0a52c8d40),
    ("soup 3K / sweep 1", 0x7d8c530aaa3eea4a),
    ("soup 3K / sweep 8", 0x3ea2f501bfe9a0e6),
    ("soup 3K / lbvh", 0x8feff678e7a3b20c),
    ("soup 3K / hlbvh", 0x8feff678e7a3b20c),
    ("soup 3K / hlbvh cells", 0x8feff678e7a3b20c),
    ("soup 3K / hlbvh+sah", 0x41bb6a92f0249cdb),
    ("soup 3K / hlbvh+atrbvh", 0x97c81141baa8afc8),
    ("soup 3K / atrbvh", 0x6fc54c8060c20daf),
    ("soup 3K / ploc", 0x43da766819ad252b),
    ("soup 3K / lbvh+reinsert", 0x4f7698b0df6b5ff5),
    ("soup 3K / mbvh4 topdown true", 0x715f549662370a17),
    ("soup 3K / mbvh4 topdown false", 0x79a976bb6832b662),
    ("soup 3K / collapse(sweep)", 0x3f96ad44cfcdf873),
    ("cloth / binned 8/1", 0x2b8943299ccaaebc),
    ("cloth / binned 8/4", 0x90cccdfce0b1ce58),
    ("cloth / binned 8/8", 0x90cccdfce0b1ce58),
    ("cloth / binned 16/1", 0x43677d19ff52f930),
    ("cloth / binned 16/4", 0x1972a9804ef03764),
    ("cloth / binned 16/8", 0x1972a9804ef03764),
    ("cloth / binned 32/1", 0x1417002b1ff48b99),
    ("cloth / binned 32/4", 0x8622644440cfe77c),
    ("cloth / binned 32/8", 0x8622644440cfe77c),
    ("cloth / sweep 1", 0x7f403d0e9e4fbd4a),
    ("cloth / sweep 8", 0x826a89dc3832de33),
    ("cloth / lbvh", 0x6823824da931e8df),
    ("cloth / hlbvh", 0x22c1ddb381f82d1e),
    ("cloth / hlbvh cells", 0x22c1ddb381f82d1e),
    ("cloth / hlbvh+sah", 0xab74c4b687202d3c),
    ("cloth / hlbvh+atrbvh", 0x22c1ddb381f82d1e),
    ("cloth / atrbvh", 0x83faacd6b6478692),
    ("cloth / ploc", 0x8b38fd44c5c3ef40),
    ("cloth / lbvh+reinsert", 0x83faacd6b6478692),
    ("cloth / mbvh4 topdown true", 0xf45cfa8291e29cb1),
    ("cloth / mbvh4 topdown false", 0x9b0157893a154f32),
    ("cloth / collapse(sweep)", 0x5c4c8e74b0f4c908),
    ("one / binned 8/1", 0x92d3f3bf05c65eaf),
    ("one / binned 8/4", 0x92d3f3bf05c65eaf),
    ("one / binned 8/8", 0x92d3f3bf05c65eaf),
    ("one / binned 16/1", 0x92d3f3bf05c65eaf),
    ("one / binned 16/4", 0x92d3f3bf05c65eaf),
    ("one / binned 16/8", 0x92d3f3bf05c65eaf),
    ("one / binned 32/1", 0x92d3f3bf05c65eaf),
    ("one / binned 32/4", 0x92d3f3bf05c65eaf),
    ("one / binned 32/8", 0x92d3f3bf05c65eaf),
    ("one / sweep 1", 0x92d3f3bf05c65eaf),
    ("one / sweep 8", 0x92d3f3bf05c65eaf),
    ("one / lbvh", 0x92d3f3bf05c65eaf),
    ("one / hlbvh", 0x92d3f3bf05c65eaf),
    ("one / hlbvh cells", 0x92d3f3bf05c65eaf),
    ("one / hlbvh+sah", 0x92d3f3bf05c65eaf),
    ("one / hlbvh+atrbvh", 0x92d3f3bf05c65eaf),
    ("one / atrbvh", 0x92d3f3bf05c65eaf),
    ("one / ploc", 0x92d3f3bf05c65eaf),
    ("one / lbvh+reinsert", 0x92d3f3bf05c65eaf),
    ("one / mbvh4 topdown true", 0xd21b4a064957bc05),
    ("one / mbvh4 topdown false", 0xd21b4a064957bc05),
    ("one / collapse(sweep)", 0xd21b4a064957bc05),
    ("two / binned 8/1", 0xab8a9db21c3a5660),
    ("two / binned 8/4", 0xab8a9db21c3a5660),
    ("two / binned 8/8", 0xab8a9db21c3a5660),
    ("two / binned 16/1", 0xab8a9db21c3a5660),
    ("two / binned 16/4", 0xab8a9db21c3a5660),
    ("two / binned 16/8", 0xab8a9db21c3a5660),
    ("two / binned 32/1", 0xab8a9db21c3a5660),
    ("two / binned 32/4", 0xab8a9db21c3a5660),
    ("two / binned 32/8", 0xab8a9db21c3a5660),
    ("two / sweep 1", 0xab8a9db21c3a5660),
    ("two / sweep 8", 0xab8a9db21c3a5660),
    ("two / lbvh", 0xab8a9db21c3a5660),
    ("two / hlbvh", 0xab8a9db21c3a5660),
    ("two / hlbvh cells", 0xab8a9db21c3a5660),
    ("two / hlbvh+sah", 0xab8a9db21c3a5660),
    ("two / hlbvh+atrbvh", 0xab8a9db21c3a5660),
    ("two / atrbvh", 0xab8a9db21c3a5660),
    ("two / ploc", 0xab8a9db21c3a5660),
    ("two / lbvh+reinsert", 0xab8a9db21c3a5660),
    ("two / mbvh4 topdown true", 0xa9a1141626297a28),
    ("two / mbvh4 topdown false", 0xd7d3ce367e815c86),
    ("two / collapse(sweep)", 0xd7d3ce367e815c86),
    ("two identical / binned 8/1", 0xc8df6ad4e6e20b8f),
    ("two identical / binned 8/4", 0xd2b5ff860c0d0bef),
    ("two identical / binned 8/8", 0xd2b5ff860c0d0bef),
    ("two identical / binned 16/1", 0xc8df6ad4e6e20b8f),
    ("two identical / binned 16/4", 0xd2b5ff860c0d0bef),
    ("two identical / binned 16/8", 0xd2b5ff860c0d0bef),
    ("two identical / binned 32/1", 0xc8df6ad4e6e20b8f),
    ("two identical / binned 32/4", 0xd2b5ff860c0d0bef),
    ("two identical / binned 32/8", 0xd2b5ff860c0d0bef),
    ("two identical / sweep 1", 0xc8df6ad4e6e20b8f),
    ("two identical / sweep 8", 0xd2b5ff860c0d0bef),
    ("two identical / lbvh", 0xc8df6ad4e6e20b8f),
    ("two identical / hlbvh", 0xd2b5ff860c0d0bef),
    ("two identical / hlbvh cells", 0xd2b5ff860c0d0bef),
    ("two identical / hlbvh+sah", 0xd2b5ff860c0d0bef),
    ("two identical / hlbvh+atrbvh", 0xd2b5ff860c0d0bef),
    ("two identical / atrbvh", 0xc8df6ad4e6e20b8f),
    ("two identical / ploc", 0xc8df6ad4e6e20b8f),
    ("two identical / lbvh+reinsert", 0xc8df6ad4e6e20b8f),
    ("two identical / mbvh4 topdown true", 0xe724e13bdf34d140),
    ("two identical / mbvh4 topdown false", 0xe724e13bdf34d140),
    ("two identical / collapse(sweep)", 0xe724e13bdf34d140),
    ("all centroids equal (9) / binned 8/1", 0x4f1b7f6d393174c0),
    ("all centroids equal (9) / binned 8/4", 0x86532237f0ec5e7f),
    ("all centroids equal (9) / binned 8/8", 0xef5774473fcec13c),
    ("all centroids equal (9) / binned 16/1", 0x4f1b7f6d393174c0),
    ("all centroids equal (9) / binned 16/4", 0x86532237f0ec5e7f),
    ("all centroids equal (9) / binned 16/8", 0xef5774473fcec13c),
    ("all centroids equal (9) / binned 32/1", 0x4f1b7f6d393174c0),
    ("all centroids equal (9) / binned 32/4", 0x86532237f0ec5e7f),
    ("all centroids equal (9) / binned 32/8", 0xef5774473fcec13c),
    ("all centroids equal (9) / sweep 1", 0x4f1b7f6d393174c0),
    ("all centroids equal (9) / sweep 8", 0xef5774473fcec13c),
    ("all centroids equal (9) / lbvh", 0x0857ce9a7edee28c),
    ("all centroids equal (9) / hlbvh", 0x3bee8805afba70c0),
    ("all centroids equal (9) / hlbvh cells", 0x3bee8805afba70c0),
    ("all centroids equal (9) / hlbvh+sah", 0x3bee8805afba70c0),
    ("all centroids equal (9) / hlbvh+atrbvh", 0x3bee8805afba70c0),
    ("all centroids equal (9) / atrbvh", 0x3bee8805afba70c0),
    ("all centroids equal (9) / ploc", 0x88b0b3f21bb36756),
    (
        "all centroids equal (9) / lbvh+reinsert",
        0x3bee8805afba70c0,
    ),
    (
        "all centroids equal (9) / mbvh4 topdown true",
        0x3d1519e84170d773,
    ),
    (
        "all centroids equal (9) / mbvh4 topdown false",
        0x3d1519e84170d773,
    ),
    (
        "all centroids equal (9) / collapse(sweep)",
        0xa03550a53150a56a,
    ),
    (
        "all centroids equal (5000) / binned 8/1",
        0xd218d47b7fdcf240,
    ),
    (
        "all centroids equal (5000) / binned 8/4",
        0x6b40bcc54c16255d,
    ),
    (
        "all centroids equal (5000) / binned 8/8",
        0x8f5c2a379421df28,
    ),
    (
        "all centroids equal (5000) / binned 16/1",
        0xd218d47b7fdcf240,
    ),
    (
        "all centroids equal (5000) / binned 16/4",
        0x6b40bcc54c16255d,
    ),
    (
        "all centroids equal (5000) / binned 16/8",
        0x8f5c2a379421df28,
    ),
    (
        "all centroids equal (5000) / binned 32/1",
        0xd218d47b7fdcf240,
    ),
    (
        "all centroids equal (5000) / binned 32/4",
        0x6b40bcc54c16255d,
    ),
    (
        "all centroids equal (5000) / binned 32/8",
        0x8f5c2a379421df28,
    ),
    ("all centroids equal (5000) / sweep 1", 0xd218d47b7fdcf240),
    ("all centroids equal (5000) / sweep 8", 0x8f5c2a379421df28),
    ("all centroids equal (5000) / lbvh", 0x91fcf3ca487c68a4),
    ("all centroids equal (5000) / hlbvh", 0xc064f7b661e0e928),
    (
        "all centroids equal (5000) / hlbvh cells",
        0xc064f7b661e0e928,
    ),
    ("all centroids equal (5000) / hlbvh+sah", 0xc064f7b661e0e928),
    (
        "all centroids equal (5000) / hlbvh+atrbvh",
        0xc064f7b661e0e928,
    ),
    ("all centroids equal (5000) / atrbvh", 0xdcd3bfdda74f6a6c),
    ("all centroids equal (5000) / ploc", 0x404fcd97d71afc7e),
    (
        "all centroids equal (5000) / lbvh+reinsert",
        0xdcd3bfdda74f6a6c,
    ),
    (
        "all centroids equal (5000) / mbvh4 topdown true",
        0xb49feb0d7437faee,
    ),
    (
        "all centroids equal (5000) / mbvh4 topdown false",
        0xb49feb0d7437faee,
    ),
    (
        "all centroids equal (5000) / collapse(sweep)",
        0x4cd141a53330b1df,
    ),
    (
        "nested boxes, one centroid / binned 8/1",
        0x8e1ffb22637694c6,
    ),
    (
        "nested boxes, one centroid / binned 8/4",
        0x47c1d645c85258a4,
    ),
    (
        "nested boxes, one centroid / binned 8/8",
        0x20f94b996a43a7b9,
    ),
    (
        "nested boxes, one centroid / binned 16/1",
        0x8e1ffb22637694c6,
    ),
    (
        "nested boxes, one centroid / binned 16/4",
        0x47c1d645c85258a4,
    ),
    (
        "nested boxes, one centroid / binned 16/8",
        0x20f94b996a43a7b9,
    ),
    (
        "nested boxes, one centroid / binned 32/1",
        0x8e1ffb22637694c6,
    ),
    (
        "nested boxes, one centroid / binned 32/4",
        0x47c1d645c85258a4,
    ),
    (
        "nested boxes, one centroid / binned 32/8",
        0x20f94b996a43a7b9,
    ),
    ("nested boxes, one centroid / sweep 1", 0xd2383498057fe8d9),
    ("nested boxes, one centroid / sweep 8", 0x923adb797ed9ce17),
    ("nested boxes, one centroid / lbvh", 0xf8344e9bff0d762d),
    ("nested boxes, one centroid / hlbvh", 0x764ba1dd55fda4ba),
    (
        "nested boxes, one centroid / hlbvh cells",
        0x764ba1dd55fda4ba,
    ),
    ("nested boxes, one centroid / hlbvh+sah", 0x764ba1dd55fda4ba),
    (
        "nested boxes, one centroid / hlbvh+atrbvh",
        0x764ba1dd55fda4ba,
    ),
    ("nested boxes, one centroid / atrbvh", 0xee18993db5c73c94),
    ("nested boxes, one centroid / ploc", 0xf928b5ca1812a831),
    (
        "nested boxes, one centroid / lbvh+reinsert",
        0x87db6658e311a35a,
    ),
    (
        "nested boxes, one centroid / mbvh4 topdown true",
        0x468c83010405fdbc,
    ),
    (
        "nested boxes, one centroid / mbvh4 topdown false",
        0x468c83010405fdbc,
    ),
    (
        "nested boxes, one centroid / collapse(sweep)",
        0x198cac54aed65424,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 8/1",
        0xfe53704ac6011f44,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 8/4",
        0x2a62385d1b3e4d7c,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 8/8",
        0x2a62385d1b3e4d7c,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 16/1",
        0xc24f8127749dcb37,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 16/4",
        0x78ca734fe41d59d2,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 16/8",
        0xcfab28035da0a6d5,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 32/1",
        0xec1b3e4e2bf67d3a,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 32/4",
        0xeb073e5f1eff85b0,
    ),
    (
        "coplanar axis-aligned (flat z) / binned 32/8",
        0xeb073e5f1eff85b0,
    ),
    (
        "coplanar axis-aligned (flat z) / sweep 1",
        0xcd2e8470018d4972,
    ),
    (
        "coplanar axis-aligned (flat z) / sweep 8",
        0x4ec729e0c01e4669,
    ),
    ("coplanar axis-aligned (flat z) / lbvh", 0x72dd0b65a3a2419b),
    ("coplanar axis-aligned (flat z) / hlbvh", 0xa0fc7cbc77c15d56),
    (
        "coplanar axis-aligned (flat z) / hlbvh cells",
        0xa0fc7cbc77c15d56,
    ),
    (
        "coplanar axis-aligned (flat z) / hlbvh+sah",
        0x3917e655c06617d1,
    ),
    (
        "coplanar axis-aligned (flat z) / hlbvh+atrbvh",
        0x133dcb8546257d9c,
    ),
    (
        "coplanar axis-aligned (flat z) / atrbvh",
        0x67d54e5395a343dc,
    ),
    ("coplanar axis-aligned (flat z) / ploc", 0x9ac62967b5d5acc9),
    (
        "coplanar axis-aligned (flat z) / lbvh+reinsert",
        0x77c0b80e3aa3d9fd,
    ),
    (
        "coplanar axis-aligned (flat z) / mbvh4 topdown true",
        0xcaef41db3ac8ee8f,
    ),
    (
        "coplanar axis-aligned (flat z) / mbvh4 topdown false",
        0x0ab4b629970eeda8,
    ),
    (
        "coplanar axis-aligned (flat z) / collapse(sweep)",
        0xdd61c32f955a9f76,
    ),
    ("one huge among tiny / binned 8/1", 0xa53b4e64bc503595),
    ("one huge among tiny / binned 8/4", 0xa53b4e64bc503595),
    ("one huge among tiny / binned 8/8", 0xa53b4e64bc503595),
    ("one huge among tiny / binned 16/1", 0xae4ef2bd2352fd65),
    ("one huge among tiny / binned 16/4", 0xae4ef2bd2352fd65),
    ("one huge among tiny / binned 16/8", 0xae4ef2bd2352fd65),
    ("one huge among tiny / binned 32/1", 0xa5dbeaa9d302278f),
    ("one huge among tiny / binned 32/4", 0xa5dbeaa9d302278f),
    ("one huge among tiny / binned 32/8", 0xa5dbeaa9d302278f),
    ("one huge among tiny / sweep 1", 0x13eed1bbc2fd9e6f),
    ("one huge among tiny / sweep 8", 0x13eed1bbc2fd9e6f),
    ("one huge among tiny / lbvh", 0x051dfd697b91d857),
    ("one huge among tiny / hlbvh", 0x051dfd697b91d857),
    ("one huge among tiny / hlbvh cells", 0x051dfd697b91d857),
    ("one huge among tiny / hlbvh+sah", 0x60d8a4b60604c62c),
    ("one huge among tiny / hlbvh+atrbvh", 0x66a3694b5db74989),
    ("one huge among tiny / atrbvh", 0xda177852a1751942),
    ("one huge among tiny / ploc", 0xe4d46437a36e821e),
    ("one huge among tiny / lbvh+reinsert", 0x9cb9b5464710523f),
    (
        "one huge among tiny / mbvh4 topdown true",
        0xa9e1038345847363,
    ),
    (
        "one huge among tiny / mbvh4 topdown false",
        0xa57d1deb9ca25266,
    ),
    ("one huge among tiny / collapse(sweep)", 0x0c6f81e676a74959),
    ("points on a line / binned 8/1", 0x31423333af0bd3b7),
    ("points on a line / binned 8/4", 0x691d198d0939159e),
    ("points on a line / binned 8/8", 0x4299c78271135ed6),
    ("points on a line / binned 16/1", 0xd644c9b4b3ca821b),
    ("points on a line / binned 16/4", 0xe25a2ddc5d1c83d1),
    ("points on a line / binned 16/8", 0xa147c3de64357d1e),
    ("points on a line / binned 32/1", 0xc1bbc16a16c4e6a6),
    ("points on a line / binned 32/4", 0x8472dee2d3823377),
    ("points on a line / binned 32/8", 0x413b6a0761abe20f),
    ("points on a line / sweep 1", 0x61964c9ecfefe7e7),
    ("points on a line / sweep 8", 0xfbeff22582bbae9f),
    ("points on a line / lbvh", 0xbb732f765c9e6309),
    ("points on a line / hlbvh", 0xbb732f765c9e6309),
    ("points on a line / hlbvh cells", 0xbb732f765c9e6309),
    ("points on a line / hlbvh+sah", 0x9ac0ee30975248c4),
    ("points on a line / hlbvh+atrbvh", 0xbb732f765c9e6309),
    ("points on a line / atrbvh", 0xc0b540d3ac986347),
    ("points on a line / ploc", 0x73f472de0851ff0b),
    ("points on a line / lbvh+reinsert", 0xc0b540d3ac986347),
    ("points on a line / mbvh4 topdown true", 0x0fbf4e8ae6152c49),
    ("points on a line / mbvh4 topdown false", 0x0fbf4e8ae6152c49),
    ("points on a line / collapse(sweep)", 0x35d5cc3c8540705a),
    (
        "exponentially spaced points / binned 8/1",
        0xef59716b02d37b83,
    ),
    (
        "exponentially spaced points / binned 8/4",
        0xef59716b02d37b83,
    ),
    (
        "exponentially spaced points / binned 8/8",
        0xef59716b02d37b83,
    ),
    (
        "exponentially spaced points / binned 16/1",
        0x3dd649e4f4978e1f,
    ),
    (
        "exponentially spaced points / binned 16/4",
        0x3dd649e4f4978e1f,
    ),
    (
        "exponentially spaced points / binned 16/8",
        0x3dd649e4f4978e1f,
    ),
    (
        "exponentially spaced points / binned 32/1",
        0xf54faf78fc1775e5,
    ),
    (
        "exponentially spaced points / binned 32/4",
        0xf54faf78fc1775e5,
    ),
    (
        "exponentially spaced points / binned 32/8",
        0xf54faf78fc1775e5,
    ),
    ("exponentially spaced points / sweep 1", 0x4ea2a79f0e0e6401),
    ("exponentially spaced points / sweep 8", 0x4ea2a79f0e0e6401),
    ("exponentially spaced points / lbvh", 0xa9c6986113125e0c),
    ("exponentially spaced points / hlbvh", 0xa1d202a20a971d32),
    (
        "exponentially spaced points / hlbvh cells",
        0xa1d202a20a971d32,
    ),
    (
        "exponentially spaced points / hlbvh+sah",
        0x7690ac15da9a317a,
    ),
    (
        "exponentially spaced points / hlbvh+atrbvh",
        0xa1d202a20a971d32,
    ),
    ("exponentially spaced points / atrbvh", 0xed88416d7958681c),
    ("exponentially spaced points / ploc", 0x5e501689bf363b19),
    (
        "exponentially spaced points / lbvh+reinsert",
        0xac6a9b315c0053da,
    ),
    (
        "exponentially spaced points / mbvh4 topdown true",
        0x9ba6545a17733624,
    ),
    (
        "exponentially spaced points / mbvh4 topdown false",
        0xc699b5c637545755,
    ),
    (
        "exponentially spaced points / collapse(sweep)",
        0x2f137629622261be,
    ),
    ("huge coordinates / binned 8/1", 0x73105c90b748c0a9),
    ("huge coordinates / binned 8/4", 0x86bf3477c797db6a),
    ("huge coordinates / binned 8/8", 0x86bf3477c797db6a),
    ("huge coordinates / binned 16/1", 0x73105c90b748c0a9),
    ("huge coordinates / binned 16/4", 0x86bf3477c797db6a),
    ("huge coordinates / binned 16/8", 0x86bf3477c797db6a),
    ("huge coordinates / binned 32/1", 0x73105c90b748c0a9),
    ("huge coordinates / binned 32/4", 0x86bf3477c797db6a),
    ("huge coordinates / binned 32/8", 0x86bf3477c797db6a),
    ("huge coordinates / sweep 1", 0x73105c90b748c0a9),
    ("huge coordinates / sweep 8", 0x74c23a2834ad6ebc),
    ("huge coordinates / lbvh", 0x4771df0fc0129f09),
    ("huge coordinates / hlbvh", 0x86bf3477c797db6a),
    ("huge coordinates / hlbvh cells", 0x86bf3477c797db6a),
    ("huge coordinates / hlbvh+sah", 0x86bf3477c797db6a),
    ("huge coordinates / hlbvh+atrbvh", 0x86bf3477c797db6a),
    ("huge coordinates / atrbvh", 0xecd61d2eccb654f5),
    ("huge coordinates / ploc", 0xecd61d2eccb654f5),
    ("huge coordinates / lbvh+reinsert", 0xecd61d2eccb654f5),
    ("huge coordinates / mbvh4 topdown true", 0x81f30894eeba9502),
    ("huge coordinates / mbvh4 topdown false", 0x81f30894eeba9502),
    ("huge coordinates / collapse(sweep)", 0x97105a4803a101d4),
    ("bunny / binned 8/1", 0x9485075e590ac929),
    ("bunny / binned 8/4", 0xb7cbd807e6ef3811),
    ("bunny / binned 8/8", 0x9ca5fd42efba83b4),
    ("bunny / binned 16/1", 0xcbec3027c7cb2c35),
    ("bunny / binned 16/4", 0x49e653de4272e4f0),
    ("bunny / binned 16/8", 0x0306f919fa1557a7),
    ("bunny / binned 32/1", 0xa944a70b35fc95ad),
    ("bunny / binned 32/4", 0x08a56afb33376293),
    ("bunny / binned 32/8", 0xdb7cdebc4ef9b37b),
    ("bunny / sweep 1", 0x8bdb8ebaff0d6a64),
    ("bunny / sweep 8", 0xc5e3c714172f4fcd),
    ("bunny / lbvh", 0x3efba41667ecb227),
    ("bunny / hlbvh", 0x392c2d527f37d560),
    ("bunny / hlbvh cells", 0x392c2d527f37d560),
    ("bunny / hlbvh+sah", 0xe54bd2a93593d6e9),
    ("bunny / hlbvh+atrbvh", 0xf8ec1be9ac84a82b),
    ("bunny / atrbvh", 0xfebf7befe7355231),
    ("bunny / ploc", 0xa6336e482217d453),
    ("bunny / lbvh+reinsert", 0x9042d74fc6b0b2e8),
    ("bunny / mbvh4 topdown true", 0x6b4c21081c2a6184),
    ("bunny / mbvh4 topdown false", 0x98ddf7606938c718),
    ("bunny / collapse(sweep)", 0x9bc98a251f4f18f1),
    // Recorded on e66670b, before the streaming collapse's renumbering moved to `layout`.
    ("soup 40K / stream collapse", 0xfafaa6e4d7c42721),
    ("soup 3K / stream collapse", 0x12654c55a4ba1194),
    ("cloth / stream collapse", 0x15ef2d2b50806f46),
    ("one / stream collapse", 0xd21b4a064957bc05),
    ("two / stream collapse", 0xd7d3ce367e815c86),
    ("two identical / stream collapse", 0xe724e13bdf34d140),
    (
        "all centroids equal (9) / stream collapse",
        0x563d5db738db215e,
    ),
    (
        "all centroids equal (5000) / stream collapse",
        0xd5ff91e8089987d1,
    ),
    (
        "nested boxes, one centroid / stream collapse",
        0xfccd780d28915996,
    ),
    (
        "coplanar axis-aligned (flat z) / stream collapse",
        0x02ca5ec0c4b1b338,
    ),
    ("one huge among tiny / stream collapse", 0x1ddefb4f79bf63b4),
    ("points on a line / stream collapse", 0x1ed08b72fc999de9),
    (
        "exponentially spaced points / stream collapse",
        0xa2a16b7aad6edfad,
    ),
    ("huge coordinates / stream collapse", 0x81f30894eeba9502),
    ("bunny / stream collapse", 0xf9e9bed39c2ea95f),
    // Recorded on 6e61715 (issue 34), before ATRBVH restructured `Bvh2` nodes in place.
    ("soup 40K / hlbvh+atrbvh-cells", 0x39de5302fb4eb211),
    ("soup 40K / atrbvh t9 i3 doubling", 0x4eb92947aca00318),
    ("soup 3K / hlbvh+atrbvh-cells", 0x3526e5a91c5e7526),
    ("soup 3K / atrbvh t9 i3 doubling", 0xc9dcfe36d57719b8),
    ("cloth / hlbvh+atrbvh-cells", 0x83faacd6b6478692),
    ("cloth / atrbvh t9 i3 doubling", 0x83faacd6b6478692),
    ("one / hlbvh+atrbvh-cells", 0x92d3f3bf05c65eaf),
    ("one / atrbvh t9 i3 doubling", 0x92d3f3bf05c65eaf),
    ("two / hlbvh+atrbvh-cells", 0xab8a9db21c3a5660),
    ("two / atrbvh t9 i3 doubling", 0xab8a9db21c3a5660),
    ("two identical / hlbvh+atrbvh-cells", 0xd2b5ff860c0d0bef),
    ("two identical / atrbvh t9 i3 doubling", 0xc8df6ad4e6e20b8f),
    (
        "all centroids equal (9) / hlbvh+atrbvh-cells",
        0x3bee8805afba70c0,
    ),
    (
        "all centroids equal (9) / atrbvh t9 i3 doubling",
        0x3bee8805afba70c0,
    ),
    (
        "all centroids equal (5000) / hlbvh+atrbvh-cells",
        0xdcd3bfdda74f6a6c,
    ),
    (
        "all centroids equal (5000) / atrbvh t9 i3 doubling",
        0xdcd3bfdda74f6a6c,
    ),
    (
        "nested boxes, one centroid / hlbvh+atrbvh-cells",
        0xa4c79d89059539cf,
    ),
    (
        "nested boxes, one centroid / atrbvh t9 i3 doubling",
        0x1f7a7aac0672e366,
    ),
    (
        "coplanar axis-aligned (flat z) / hlbvh+atrbvh-cells",
        0xd94e8c5011271a01,
    ),
    (
        "coplanar axis-aligned (flat z) / atrbvh t9 i3 doubling",
        0xd2077b066ff80458,
    ),
    (
        "one huge among tiny / hlbvh+atrbvh-cells",
        0xf61573c91a7e1af2,
    ),
    (
        "one huge among tiny / atrbvh t9 i3 doubling",
        0xdce0e70dba509187,
    ),
    ("points on a line / hlbvh+atrbvh-cells", 0xc0b540d3ac986347),
    (
        "points on a line / atrbvh t9 i3 doubling",
        0xc0b540d3ac986347,
    ),
    (
        "exponentially spaced points / hlbvh+atrbvh-cells",
        0xe6b0e8813a05324c,
    ),
    (
        "exponentially spaced points / atrbvh t9 i3 doubling",
        0x18d9fa13083506e9,
    ),
    ("huge coordinates / hlbvh+atrbvh-cells", 0x86bf3477c797db6a),
    (
        "huge coordinates / atrbvh t9 i3 doubling",
        0xecd61d2eccb654f5,
    ),
    ("bunny / hlbvh+atrbvh-cells", 0xb12089cb8b1f3a91),
    ("bunny / atrbvh t9 i3 doubling", 0x2e879edb47f8add3),
];
