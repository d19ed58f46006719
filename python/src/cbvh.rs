//! CBVH encoding ([P3]): a binary tree compressed top-down or streamed bottom-up, with the
//! statistics of `arbor cbvh --json` that do not depend on how the tree was built.

use crate::arrays::err;
use crate::bvh::Bvh;
use crate::detached;
use bvh::Tree;
use cbvh::bottomup::{StreamConfig, MAX_TREELET_DEPTH};
use cbvh::{Coords, EncodeStats, Params};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::time::Instant;

/// The encoder configuration, checked with the rules of `arbor cbvh`'s options.
fn choice(
    encoder: &str,
    coords: &str,
    treelet: u32,
    bits: u32,
    min_scale_exp: i32,
) -> Result<(bool, StreamConfig), String> {
    let topdown = match encoder {
        "topdown" => true,
        "bottomup" => false,
        other => {
            return Err(format!(
                "unknown encoder '{other}' (known: topdown, bottomup)"
            ))
        }
    };
    let coords = match coords {
        "relative" => Coords::Relative,
        "modulo" => Coords::Modulo,
        other => {
            return Err(format!(
                "unknown coords '{other}' (known: relative, modulo)"
            ))
        }
    };
    if treelet == 0 || treelet > MAX_TREELET_DEPTH {
        return Err(format!(
            "treelet must be 1..={MAX_TREELET_DEPTH}, got {treelet}"
        ));
    }
    if topdown && treelet != 1 {
        return Err("treelet applies to the bottom-up encoder only".into());
    }
    let params = Params {
        bits,
        min_scale_exp,
        coords,
    };
    params.check().map_err(|e| e.to_string())?;
    Ok((
        topdown,
        StreamConfig {
            params,
            treelet_depth: treelet,
            ..StreamConfig::default()
        },
    ))
}

/// What one encode gave.
struct Encoded {
    pairs: u64,
    node_bytes: u64,
    prim_ids: usize,
    stats: EncodeStats,
    violations: u64,
    sah: f64,
    sah_uncompressed: f64,
    encode_ms: f64,
}

/// Compresses the binary tree `bvh` into a CBVH and returns its statistics as a dict (the
/// compressed tree itself is not kept).
#[pyfunction]
#[pyo3(signature = (bvh, vertices = None, indices = None, *, encoder = "bottomup", coords = "modulo", treelet = 1, bits = 6, min_scale_exp = -30))]
#[allow(clippy::too_many_arguments)]
fn encode_cbvh<'py>(
    py: Python<'py>,
    bvh: PyRef<'py, Bvh>,
    vertices: Option<&Bound<'py, PyAny>>,
    indices: Option<&Bound<'py, PyAny>>,
    encoder: &str,
    coords: &str,
    treelet: u32,
    bits: u32,
    min_scale_exp: i32,
) -> PyResult<Bound<'py, PyDict>> {
    let (topdown, cfg) = choice(encoder, coords, treelet, bits, min_scale_exp).map_err(err)?;
    let snap = bvh.snapshot();
    let Tree::Bvh2(tree) = &snap.tree else {
        return Err(err(
            "a CBVH compresses a binary tree; this tree is 4-wide (Mbvh4)",
        ));
    };
    let (prims, _) = bvh.prims_for(py, vertices, indices)?;
    if prims.len() != tree.prim_count() {
        return Err(err(format!(
            "the tree holds {} primitives but {} triangles were given",
            tree.prim_count(),
            prims.len()
        )));
    }
    let e = detached(py, || {
        let s = Instant::now();
        let (c, stats) = if topdown {
            cbvh::compress_topdown(tree, &cfg.params)
        } else {
            cbvh::compress_bottomup(tree, &cfg)
        }
        .map_err(|e| format!("cannot compress the tree: {e}"))?;
        let encode_ms = s.elapsed().as_secs_f64() * 1e3;
        let decoded = c
            .decode_to_bvh2()
            .map_err(|e| format!("cannot decode the CBVH: {e}"))?;
        let violations = cbvh::enclosure_violations(&decoded, &prims)
            .map_err(|e| format!("cannot check the decoded boxes: {e}"))?;
        Ok::<_, String>(Encoded {
            pairs: c.pairs.len() as u64,
            node_bytes: c.node_bytes(),
            prim_ids: c.prim_ids.len(),
            stats,
            violations,
            sah: bvh::sah_cost(&decoded),
            sah_uncompressed: bvh::sah_cost(tree),
            encode_ms,
        })
    })?;
    let st = tree.stats();
    let unc = (tree.nodes.len() * std::mem::size_of::<bvh::Node>()) as u64;
    let d = PyDict::new(py);
    d.set_item("encoder", encoder)?;
    d.set_item("coords", coords)?;
    d.set_item("treelet_depth", treelet)?;
    d.set_item("bits", bits)?;
    d.set_item("min_scale_exp", min_scale_exp)?;
    d.set_item("triangles", tree.prim_count())?;
    d.set_item("nodes", e.pairs)?;
    d.set_item("leaves", st.leaves)?;
    d.set_item(
        "avg_leaf_size",
        tree.prim_count() as f64 / st.leaves.max(1) as f64,
    )?;
    d.set_item("node_bytes", e.node_bytes)?;
    d.set_item("uncompressed_node_bytes", unc)?;
    d.set_item("compression_ratio", e.node_bytes as f64 / unc.max(1) as f64)?;
    d.set_item("prim_id_bytes", e.prim_ids * 4)?;
    d.set_item("nodes_written", e.stats.nodes_written)?;
    d.set_item("backtrack_steps", e.stats.backtrack_steps)?;
    d.set_item("backtrack_depth_hist", e.stats.backtrack_depth_hist.clone())?;
    d.set_item("max_stack", e.stats.max_stack)?;
    d.set_item("decoded_encloses_original", e.violations == 0)?;
    d.set_item("enclosure_violations", e.violations)?;
    d.set_item("sah", e.sah)?;
    d.set_item("sah_uncompressed", e.sah_uncompressed)?;
    d.set_item(
        "sah_vs_uncompressed",
        bvh::sah_ratio(e.sah, e.sah_uncompressed),
    )?;
    d.set_item("encode_ms", e.encode_ms)?;
    Ok(d)
}

/// Registers the CBVH functions.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(encode_cbvh, m)?)?;
    Ok(())
}
