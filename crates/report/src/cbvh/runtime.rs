//! The runtime part of `arbor report cbvh`: the analogue of \[P3\] Table 2 (§5.3), LBVH
//! build time with four kinds of output, simulated on the MergeTree model:
//! - `BVH`: single-precision 64-byte nodes (preset `p3`: the \[P1\] unit with a 256 KB
//!   scratchpad, M = 8192, B = 8, leaves of any size for equal Morton codes, 1 GHz);
//! - `TD`: the same build followed by the top-down compression pass (optimistic: every
//!   node read offered at once, see `sim::mergetree::cbvh_unit`);
//! - `R`: the streaming bottom-up encoder with relative coordinates and no treelets, its
//!   backtracking steps sequential DRAM reads and writes (pessimistic);
//! - `M4`: streaming with modulo coordinates and depth-4 treelets.
//!
//! All on `lpddr3-1600-2x32` (DRAMsim3's timing, from Arbor's model of its controller) by
//! default, \[P3\] §5.3's dual-channel 32-bit LPDDR3-1600. `BVH` is not run separately: it
//! is the build phase of the `TD` run, which ends exactly when a plain build ends (the pass
//! starts once every write is done; a test in `sim` checks the cycle counts are equal).
//!
//! Two what-ifs explain the backtracking cost: `R` with `cbvh_flush_before_backtrack =
//! false` (a backtracking read goes to DRAM even while its line waits in the unit's write
//! buffer, so the controller's write queue cannot answer it), and all four on the simple
//! memory model with the same peak bandwidth (no write queue: every read pays its 40 ns).
//! Every run's BVH is checked against the software builder and its CBVH against the
//! software encoder, bit for bit.

use crate::progress::Progress;
use anyhow::Context;
use geom::Aabb;
use rayon::prelude::*;
use sim::mergetree::{self, MergeTreeConfig, MergeTreeReport, OutputMode};
use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::fs::write_file as write;
use crate::svg::bar_svg;
use crate::table::Table;

/// \[P3\] §5.3's memory: "a dual-channel, 32-bit LPDDR3-1600 memory interface".
pub const DEFAULT_DRAM: &str = "lpddr3-1600-2x32";

/// One row of \[P3\] Table 2 for a scene we share.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct P3Table2Row {
    /// Our scene name.
    pub name: &'static str,
    /// The thesis's name.
    pub thesis_name: &'static str,
    /// Build time in ms: BVH (float), TD (relative), BU relative, BU modulo with depth-4
    /// treelets.
    pub ms: [f64; 4],
    /// Primitives per leaf.
    pub leaf_size: f64,
    /// Line of the thesis text.
    pub line: u32,
}

/// \[P3\] Table 2 (thesis text lines 2287-2303) for the scenes we share. The table is read
/// by column: BVH "Float", CBVH "TD Rel.", "BU Rel.", "BU Mod. 4", "Leaf size".
pub const P3_TABLE2: [P3Table2Row; 5] = [
    P3Table2Row {
        name: "bunny",
        thesis_name: "Bunny",
        ms: [1.1, 1.6, 1.9, 0.8],
        leaf_size: 1.1,
        line: 2288,
    },
    P3Table2Row {
        name: "cloth",
        thesis_name: "Cloth",
        ms: [1.5, 2.1, 2.4, 1.1],
        leaf_size: 1.0,
        line: 2290,
    },
    P3Table2Row {
        name: "crytek-sponza",
        thesis_name: "Crytek",
        ms: [3.6, 4.8, 5.4, 3.0],
        leaf_size: 2.0,
        line: 2293,
    },
    P3Table2Row {
        name: "conference",
        thesis_name: "Conference",
        ms: [3.2, 3.5, 3.4, 2.9],
        leaf_size: 8.7,
        line: 2294,
    },
    P3Table2Row {
        name: "dragon",
        thesis_name: "Dragon",
        ms: [13.4, 19.0, 21.5, 10.3],
        leaf_size: 1.3,
        line: 2299,
    },
];

/// \[P3\] Table 2's "Average" row (line 2303) over its 16 scenes, relative to BVH: TD +36%,
/// R +52%, M4 -20%.
pub const P3_TABLE2_AVERAGE: [f64; 3] = [1.36, 1.52, 0.80];

/// \[P3\] Table 2's row for our scene `name`.
pub fn p3_row(name: &str) -> Option<&'static P3Table2Row> {
    P3_TABLE2.iter().find(|r| r.name == name)
}

/// The four alternatives.
pub const LABELS: [&str; 4] = ["BVH", "TD", "R", "M4"];

/// What one simulation contributes to the table.
#[derive(Clone, Debug, Default)]
pub struct RunRow {
    /// Whole run, ms.
    pub ms: f64,
    /// Build phase, ms (the BVH column for a TD run).
    pub build_ms: f64,
    /// Bytes through the port (whole bursts).
    pub bytes: u64,
    /// Bytes of the build phases (all but the top-down pass).
    pub build_bytes: u64,
    /// Bytes of DRAM RD/WR commands (DRAMsim3 timing; reads answered from the controller's write
    /// queue move no data on the bus).
    pub dram_command_bytes: u64,
    /// Backtracking steps.
    pub backtrack_steps: u64,
    /// Mean latency of a backtracking read, cycles.
    pub backtrack_latency: f64,
    /// Backtracking reads answered within 3 cycles (from the controller's write queue).
    pub backtrack_fast: u64,
    /// Backtracking reads that first flushed the write buffer.
    pub backtrack_flushes: u64,
    /// Node pairs.
    pub node_pairs: u64,
}

impl RunRow {
    fn of(r: &MergeTreeReport) -> Self {
        let c = r.cbvh.as_ref();
        let st = c.and_then(|c| c.stream.as_ref());
        let burst = r.memory.read_bursts + r.memory.write_bursts;
        let burst_bytes = (r.memory.bytes_read + r.memory.bytes_written)
            .checked_div(burst)
            .unwrap_or(0);
        Self {
            ms: r.ms,
            build_ms: c.map_or(r.ms, |c| c.build_ms),
            bytes: r.bytes_read + r.bytes_written,
            build_bytes: r
                .phases
                .iter()
                .filter(|p| p.name != "topdown_compress")
                .map(|p| p.bytes_read + p.bytes_written)
                .sum(),
            dram_command_bytes: (r.memory.read_commands + r.memory.write_commands) * burst_bytes,
            backtrack_steps: c.map_or(0, |c| c.backtrack_steps),
            backtrack_latency: st.map_or(0.0, |s| s.mean_backtrack_read_latency()),
            // Buckets 0 and 1 of the log2 histogram: latencies below 4 cycles.
            backtrack_fast: st.map_or(0, |s| {
                s.backtrack_read_latency_log2.iter().take(2).sum::<u64>()
            }),
            backtrack_flushes: st.map_or(0, |s| s.backtrack_flushes),
            node_pairs: c.map_or(r.nodes, |c| c.node_pairs),
        }
    }
}

/// The runs of one scene: `[TD, R, M4]` on the report's memory (BVH is TD's build), R
/// without the flush, and `[TD, R, M4]` on the simple model.
#[derive(Clone, Debug, Default)]
pub struct RuntimeRow {
    /// TD, R, M4 on the report's memory.
    pub main: [RunRow; 3],
    /// R with `cbvh_flush_before_backtrack = false`.
    pub no_flush: Option<RunRow>,
    /// TD, R, M4 on the simple memory model of the same peak bandwidth.
    pub simple: Option<[RunRow; 3]>,
}

impl RuntimeRow {
    /// Milliseconds of BVH, TD, R, M4 on the report's memory.
    pub fn ms(&self) -> [f64; 4] {
        let [td, r, m4] = &self.main;
        [td.build_ms, td.ms, r.ms, m4.ms]
    }

    /// TD, R, M4 relative to BVH.
    pub fn rel(&self) -> [f64; 3] {
        let m = self.ms();
        [m[1] / m[0], m[2] / m[0], m[3] / m[0]]
    }
}

/// The configuration of variant `k` of [`LABELS`] (1 = TD, 2 = R, 3 = M4).
fn config(k: usize, flush: bool) -> MergeTreeConfig {
    let mut c = MergeTreeConfig::p3();
    match k {
        1 => c.output = OutputMode::CbvhTopdown,
        2 => c.output = OutputMode::CbvhStream,
        _ => {
            c.output = OutputMode::CbvhStream;
            c.cbvh_coords = cbvh::Coords::Modulo;
            c.cbvh_treelet_depth = 4;
        }
    }
    c.cbvh_flush_before_backtrack = flush;
    c
}

/// One simulation, checked against the software builder and encoder.
fn run_one(
    name: &str,
    prims: &[Aabb],
    k: usize,
    flush: bool,
    dram: &str,
) -> anyhow::Result<RunRow> {
    let cfg = config(k, flush);
    let port = sim::dram::open(dram, cfg.period_fs())?;
    let r = mergetree::simulate(prims, &cfg, port)
        .with_context(|| format!("{name}: {} on {dram}", LABELS[k]))?;
    anyhow::ensure!(
        mergetree::tree_matches_software(&r, prims)?,
        "{name} {} on {dram}: the simulated BVH differs from the software builder's",
        LABELS[k]
    );
    anyhow::ensure!(
        mergetree::cbvh_matches_software(&r, prims)? == Some(true),
        "{name} {} on {dram}: the simulated CBVH differs from the software encoder's",
        LABELS[k]
    );
    Ok(RunRow::of(&r))
}

/// Runs every scene's simulations in parallel (largest first) with a progress bar.
pub fn simulate_all(
    scenes: &[(String, Vec<Aabb>)],
    dram: &str,
    ui: &dyn Progress,
) -> anyhow::Result<Vec<RuntimeRow>> {
    let cfg = MergeTreeConfig::p3();
    sim::dram::open(dram, cfg.period_fs())?;
    // Sensitivity on the simple model, unless the report's memory is one already.
    let simple = (!dram.starts_with("simple:")).then(|| format!("simple:{dram}"));
    if let Some(s) = &simple {
        sim::dram::open(s, cfg.period_fs())?;
    }
    // (scene, variant of LABELS, flush before backtracking, memory)
    let mut jobs: Vec<(usize, usize, bool, &str)> = Vec::new();
    for s in 0..scenes.len() {
        for k in 1..=3 {
            jobs.push((s, k, true, dram));
            if let Some(m) = &simple {
                jobs.push((s, k, true, m.as_str()));
            }
        }
        jobs.push((s, 2, false, dram));
    }
    // Largest first (the simple model runs about 20 times as fast as DRAMsim3).
    jobs.sort_by_key(|&(s, _, _, m)| {
        let w = if m.starts_with("simple:") { 1 } else { 20 };
        std::cmp::Reverse(scenes[s].1.len() as u64 * w)
    });
    let bar = ui.bar("report cbvh: runtime simulations");
    let total = jobs.len() as u64;
    let done = AtomicU64::new(0);
    bar.update(0, total);
    /// (scene, variant, flush, on the simple model, result)
    type Done = (usize, usize, bool, bool, RunRow);
    let out: Vec<anyhow::Result<Done>> = jobs
        .par_iter()
        .map(|&(s, k, flush, m)| {
            let row = run_one(&scenes[s].0, &scenes[s].1, k, flush, m)?;
            bar.update(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            Ok((s, k, flush, m != dram, row))
        })
        .collect();
    bar.finish();
    let mut rows = vec![RuntimeRow::default(); scenes.len()];
    for r in out {
        let (s, k, flush, is_simple, row) = r?;
        let rr = &mut rows[s];
        if !flush {
            rr.no_flush = Some(row);
        } else if is_simple {
            rr.simple.get_or_insert_with(Default::default)[k - 1] = row;
        } else {
            rr.main[k - 1] = row;
        }
    }
    Ok(rows)
}

fn pct(ours: f64, thesis: f64) -> String {
    format!("{:+.0}%", (ours / thesis - 1.0) * 100.0)
}

/// Writes `table2.csv`, `table2-dram.csv`, `table2.svg` and the Markdown section.
pub fn write_table2(
    out: &Path,
    md: &mut String,
    names: &[String],
    leaf: &[f64],
    rows: &[RuntimeRow],
    dram: &str,
) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "avg_leaf_size",
        "thesis_leaf_size",
        "variant",
        "ms",
        "vs_bvh",
        "thesis_ms",
        "thesis_vs_bvh",
        "diff_vs_bvh_pct",
        "bytes",
        "backtrack_steps",
        "node_pairs",
    ]);
    writeln!(md, "## Table 2 analogue: LBVH runtime (\\[P3\\] §5.3)\n")?;
    writeln!(
        md,
        "MergeTree preset p3 (M = 8192, B = 8, 4 presorters, 1 GHz, leaves of any size for equal \
         30-bit Morton codes) on {dram}. BVH: single-precision nodes; TD: the same build, then the \
         top-down pass (optimistic); R: streaming, relative coordinates, sequential backtracking \
         (pessimistic); M4: streaming, modulo coordinates, depth-4 treelets. ms ours / [P3]; then \
         relative to BVH, ours / [P3] (difference of our ratio from [P3]'s). [P3] prints one or two \
         digits, so its small scenes' ratios are uncertain by several percent.\n"
    )?;
    let mut table = Table::text(&[
        "scene",
        "leaf size",
        "BVH ms",
        "TD ms",
        "R ms",
        "M4 ms",
        "TD / BVH",
        "R / BVH",
        "M4 / BVH",
    ]);
    let mut ours_sum = [0.0; 3];
    let (mut shared_ours, mut shared_p3, mut shared) = ([0.0; 3], [0.0; 3], 0usize);
    for (i, row) in rows.iter().enumerate() {
        let p3 = p3_row(&names[i]);
        let ms = row.ms();
        let rel = row.rel();
        let p3_rel = p3.map(|p| [p.ms[1] / p.ms[0], p.ms[2] / p.ms[0], p.ms[3] / p.ms[0]]);
        let bytes = [
            row.main[0].build_bytes,
            row.main[0].bytes,
            row.main[1].bytes,
            row.main[2].bytes,
        ];
        for k in 0..4 {
            let (v, tv) = if k == 0 {
                (1.0, p3.map(|_| 1.0))
            } else {
                (rel[k - 1], p3_rel.map(|r| r[k - 1]))
            };
            let steps = if k >= 2 {
                row.main[k - 1].backtrack_steps
            } else {
                0
            };
            let pairs = row.main[k.max(1) - 1].node_pairs;
            csv.push([
                names[i].clone(),
                format!("{:.3}", leaf[i]),
                p3.map_or(String::new(), |p| p.leaf_size.to_string()),
                LABELS[k].to_string(),
                format!("{:.4}", ms[k]),
                format!("{v:.4}"),
                p3.map_or(String::new(), |p| p.ms[k].to_string()),
                tv.map_or(String::new(), |t| format!("{t:.4}")),
                tv.map_or(String::new(), |t| format!("{:.1}", (v / t - 1.0) * 100.0)),
                bytes[k].to_string(),
                steps.to_string(),
                pairs.to_string(),
            ]);
        }
        for k in 0..3 {
            ours_sum[k] += rel[k];
        }
        if let (Some(_), Some(t)) = (p3, p3_rel) {
            shared += 1;
            for k in 0..3 {
                shared_ours[k] += rel[k];
                shared_p3[k] += t[k];
            }
        }
        let cell_ms = |k: usize| match p3 {
            Some(p) => format!("{:.2} / {}", ms[k], p.ms[k]),
            None => format!("{:.2}", ms[k]),
        };
        let cell_rel = |k: usize| match p3_rel {
            Some(t) => format!("{:.2} / {:.2} ({})", rel[k], t[k], pct(rel[k], t[k])),
            None => format!("{:.2}", rel[k]),
        };
        table.push([
            names[i].clone(),
            format!(
                "{:.2}{}",
                leaf[i],
                p3.map_or(String::new(), |p| format!(" / {}", p.leaf_size))
            ),
            cell_ms(0),
            cell_ms(1),
            cell_ms(2),
            cell_ms(3),
            cell_rel(0),
            cell_rel(1),
            cell_rel(2),
        ]);
    }
    // The averages: rows under the scenes, their middle cells empty.
    let n = rows.len().max(1) as f64;
    let average = |label: String, cells: [String; 3]| {
        std::iter::once(label)
            .chain(std::iter::repeat_n(String::new(), 5))
            .chain(cells)
            .collect::<Vec<String>>()
    };
    table.push(average(
        format!("average, our {} scenes", rows.len()),
        [0, 1, 2].map(|k| format!("{:.2}", ours_sum[k] / n)),
    ));
    if shared > 0 {
        let s = shared as f64;
        let cell = |k: usize| {
            format!(
                "{:.2} / {:.2} ({})",
                shared_ours[k] / s,
                shared_p3[k] / s,
                pct(shared_ours[k], shared_p3[k])
            )
        };
        table.push(average(
            format!("average, the {shared} shared scenes"),
            [cell(0), cell(1), cell(2)],
        ));
    }
    table.push(average(
        "[P3] average, its 16 scenes".to_string(),
        P3_TABLE2_AVERAGE.map(|v| format!("{v:.2}")),
    ));
    md.push_str(&table.markdown());
    md.push('\n');
    write(out, "table2.csv", &csv.csv())?;
    // SVG: the three ratios per scene, ours beside [P3]'s.
    let mut series = Vec::new();
    for (k, name) in ["TD", "R", "M4"].iter().enumerate() {
        series.push((
            format!("{name} ours"),
            rows.iter().map(|r| Some(r.rel()[k])).collect(),
        ));
        series.push((
            format!("{name} [P3]"),
            names
                .iter()
                .map(|n| p3_row(n).map(|p| p.ms[k + 1] / p.ms[0]))
                .collect(),
        ));
    }
    write(
        out,
        "table2.svg",
        &bar_svg(
            &format!("LBVH runtime relative to single-precision BVH on {dram} (cf. [P3] Table 2)"),
            names,
            &series,
        ),
    )?;
    write_dram(out, md, names, rows)
}

/// The backtracking and DRAM details behind the R column, and the what-ifs.
fn write_dram(
    out: &Path,
    md: &mut String,
    names: &[String],
    rows: &[RuntimeRow],
) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "backtrack_steps",
        "steps_per_node",
        "mean_read_latency_cycles",
        "reads_under_4_cycles",
        "flushes",
        "r_bytes",
        "r_dram_command_bytes",
        "ns_per_step",
        "thesis_ns_per_step",
        "r_no_flush_ms",
        "r_no_flush_vs_bvh",
        "r_no_flush_mean_latency",
        "simple_td_vs_bvh",
        "simple_r_vs_bvh",
        "simple_m4_vs_bvh",
    ]);
    writeln!(md, "### Backtracking in the R runs, and two what-ifs\n")?;
    writeln!(
        md,
        "Steps per node pair; mean latency of a backtracking read in cycles and the share \
         answered in under 4 cycles (by the controller from its write queue); reads that first \
         flushed the unit's write buffer; bytes the DRAM moved (RD/WR commands) over bytes through \
         the port; the cost of one step, (R - M4) / steps in ns, ours / [P3] (with our step count, \
         as [P3] prints none). What-ifs: R when a backtracking read does not wait for its line to \
         leave the write buffer (`cbvh_flush_before_backtrack = false`), and the four alternatives \
         on the simple memory model of the same peak bandwidth (no write queue, 40 ns per read), \
         relative to its own BVH time.\n"
    )?;
    let mut table = Table::text(&[
        "scene",
        "R steps",
        "per pair",
        "read latency",
        "under 4 cycles",
        "flushed",
        "DRAM / port bytes",
        "ns per step",
        "R / BVH, no flush",
        "simple: TD, R, M4 / BVH",
    ]);
    for (i, row) in rows.iter().enumerate() {
        let r = &row.main[1];
        let bvh = row.main[0].build_ms;
        let per = r.backtrack_steps as f64 / r.node_pairs.max(1) as f64;
        let fast = r.backtrack_fast as f64 / r.backtrack_steps.max(1) as f64;
        let nf = row.no_flush.as_ref();
        let steps = r.backtrack_steps.max(1) as f64;
        let ns = (r.ms - row.main[2].ms) * 1e6 / steps;
        let p3_ns = p3_row(&names[i]).map(|p| (p.ms[2] - p.ms[3]) * 1e6 / steps);
        let dram_share = r.dram_command_bytes as f64 / r.bytes.max(1) as f64;
        let simple_rel = row.simple.as_ref().map(|s| {
            let b = s[0].build_ms;
            [s[0].ms / b, s[1].ms / b, s[2].ms / b]
        });
        csv.push([
            names[i].clone(),
            r.backtrack_steps.to_string(),
            format!("{per:.4}"),
            format!("{:.2}", r.backtrack_latency),
            r.backtrack_fast.to_string(),
            r.backtrack_flushes.to_string(),
            r.bytes.to_string(),
            r.dram_command_bytes.to_string(),
            format!("{ns:.2}"),
            p3_ns.map_or(String::new(), |x| format!("{x:.2}")),
            nf.map_or(String::new(), |x| format!("{:.4}", x.ms)),
            nf.map_or(String::new(), |x| format!("{:.4}", x.ms / bvh)),
            nf.map_or(String::new(), |x| format!("{:.2}", x.backtrack_latency)),
            simple_rel.map_or(String::new(), |s| format!("{:.4}", s[0])),
            simple_rel.map_or(String::new(), |s| format!("{:.4}", s[1])),
            simple_rel.map_or(String::new(), |s| format!("{:.4}", s[2])),
        ]);
        table.push([
            names[i].clone(),
            r.backtrack_steps.to_string(),
            format!("{per:.2}"),
            format!("{:.1}", r.backtrack_latency),
            format!("{:.0}%", fast * 100.0),
            r.backtrack_flushes.to_string(),
            if r.dram_command_bytes > 0 {
                format!("{dram_share:.2}")
            } else {
                "-".into()
            },
            format!(
                "{ns:.1}{}",
                p3_ns.map_or(String::new(), |x| format!(" / {x:.1}"))
            ),
            nf.map_or("-".into(), |x| {
                format!("{:.2} (latency {:.1})", x.ms / bvh, x.backtrack_latency)
            }),
            simple_rel.map_or("-".into(), |s| {
                format!("{:.2}, {:.2}, {:.2}", s[0], s[1], s[2])
            }),
        ]);
    }
    writeln!(md, "{}", table.markdown())?;
    write(out, "table2-dram.csv", &csv.csv())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_rows_are_consistent() {
        // The printed averages are of the 16 scenes; ours of the five shared ones must be
        // in the same direction.
        let n = P3_TABLE2.len() as f64;
        let avg = |k: usize| P3_TABLE2.iter().map(|r| r.ms[k] / r.ms[0]).sum::<f64>() / n;
        assert!(avg(1) > 1.2 && avg(2) > avg(1) && avg(3) < 1.0);
        assert_eq!(p3_row("dragon").unwrap().ms, [13.4, 19.0, 21.5, 10.3]);
        assert!(p3_row("sibenik").is_none());
        assert_eq!(config(3, true).cbvh_treelet_depth, 4);
        assert_eq!(config(1, true).output, OutputMode::CbvhTopdown);
        config(2, false).validate().unwrap();
    }
}
