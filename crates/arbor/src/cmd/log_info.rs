//! `arbor log-info`: reads a traversal log written by `arbor render --log`, checks it
//! (chunk checksums, trailer, stack consistency) and prints its totals, recomputed from the
//! events alone: rays, hits, node fetches, box and triangle tests, stack traffic, per
//! bounce, and the node working set.

use super::thousands;
use crate::progress::Ui;
use anyhow::Context;
use std::path::PathBuf;

/// Arguments of `arbor log-info`.
#[derive(clap::Args, Debug)]
pub struct LogInfoArgs {
    /// The log file.
    log: PathBuf,
    /// Print JSON (schema `arbor.log-info.v1`) instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(serde::Serialize)]
struct Json<'a> {
    schema: &'static str,
    log: String,
    #[serde(flatten)]
    summary: &'a trace::log::LogSummary,
}

/// Runs `arbor log-info`.
pub fn run(a: &LogInfoArgs, ui: &Ui) -> anyhow::Result<()> {
    let _spinner = ui.spinner(&format!("reading {}", a.log.display()));
    let s = trace::log::summarize(&a.log).context("cannot read the traversal log")?;
    drop(_spinner);
    if a.json {
        let j = Json {
            schema: "arbor.log-info.v1",
            log: a.log.display().to_string(),
            summary: &s,
        };
        ui.emit_json(&j)?;
        return Ok(());
    }
    let h = s.header.expect("summaries of files have headers");
    println!(
        "log           {} ({} bytes)",
        a.log.display(),
        thousands(s.file_bytes)
    );
    println!(
        "tree          {}-wide, {} nodes of {} bytes, {} leaf-table entries",
        h.width,
        thousands(h.node_count),
        h.node_bytes,
        thousands(h.leaf_entries)
    );
    println!(
        "render        {}x{} {:?} rays, {} bounces, seed {}, distance stack {}",
        h.image_width,
        h.image_height,
        h.rays,
        h.bounces,
        h.seed,
        if h.distance_stack { "on" } else { "off" }
    );
    println!("              bounce       rays      hits  nodes/ray  boxes/ray   tris/ray  pushes/ray  max stack");
    let rows = s
        .per_bounce
        .iter()
        .enumerate()
        .map(|(i, b)| (i.to_string(), b));
    for (label, b) in rows.chain(std::iter::once(("total".to_string(), &s.total))) {
        println!(
            "              {label:>6} {:>10} {:>9} {:>10.2} {:>10.2} {:>10.2} {:>11.2} {:>10}",
            b.rays,
            b.hits,
            b.per_ray(b.node_visits),
            b.per_ray(b.box_tests),
            b.per_ray(b.tri_tests),
            b.per_ray(b.pushes),
            b.max_stack_depth
        );
    }
    println!(
        "stack         {} pushes, {} pops, {} culled by the distance stack",
        thousands(s.total.pushes),
        thousands(s.total.pops),
        thousands(s.total.culled_pops)
    );
    println!(
        "nodes         {} fetches ({:.1} MiB of node data), {} distinct nodes ({:.1}% of the tree)",
        thousands(s.total.node_visits),
        s.node_bytes_fetched as f64 / (1024.0 * 1024.0),
        thousands(s.distinct_nodes),
        100.0 * s.distinct_nodes as f64 / h.node_count.max(1) as f64
    );
    println!(
        "size          {:.1} bytes per ray",
        s.file_bytes as f64 / s.total.rays.max(1) as f64
    );
    Ok(())
}
