//! `arbor bench compare OLD NEW`: every (scene, subject, threads) of two benchmark records
//! (see [`super::bench_record`]) side by side, with the ratio of the fastest runs, new / old.
//!
//! A ratio is a regression when it exceeds `1 + noise`, and faster when below
//! `1 / (1 + noise)`, where an entry's noise is the larger of the two runs' own spreads
//! (`(slowest - fastest) / fastest`) and the `--noise` floor: a benchmark that varied by 12%
//! between its own runs cannot show a 5% change. Records from different CPU models are
//! compared with a warning, since their ratios measure the machines, not the code.

use super::bench_record::{Record, RecordEntry};
use crate::progress::Ui;
use anyhow::bail;
use report::table::Table;
use serde::Serialize;
use std::path::PathBuf;

/// Default noise floor, percent.
pub const DEFAULT_NOISE_PCT: f64 = 5.0;

/// Arguments of `arbor bench compare`.
#[derive(clap::Args, Debug)]
pub struct BenchCompareArgs {
    /// The earlier record (`arbor.bench.record.v1`, written by `--record`).
    pub old: PathBuf,
    /// The later record.
    pub new: PathBuf,
    /// Noise floor in percent: ratios within it are never flagged, even when both runs
    /// were steadier.
    #[arg(long, default_value_t = DEFAULT_NOISE_PCT, value_name = "PCT")]
    pub noise: f64,
    /// Exit with status 1 when an entry regressed beyond its noise.
    #[arg(long)]
    pub fail_on_regression: bool,
    /// Print the comparison as JSON (`arbor.bench.compare.v1`).
    #[arg(long)]
    pub json: bool,
}

/// How one shared entry moved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    /// Slower beyond the noise.
    Regression,
    /// Faster beyond the noise.
    Faster,
    /// Within the noise.
    Same,
}

/// One entry present in both records.
#[derive(Clone, Debug, Serialize)]
pub struct Compared {
    /// Scene.
    pub scene: String,
    /// Builder id or tracer / ray set.
    pub subject: String,
    /// Threads.
    pub threads: usize,
    /// Old fastest run, ms.
    pub old_ms: f64,
    /// New fastest run, ms.
    pub new_ms: f64,
    /// `new_ms / old_ms`.
    pub ratio: f64,
    /// The noise the ratio is judged against (fraction).
    pub noise: f64,
    /// The judgement.
    pub verdict: Verdict,
}

/// The comparison (`arbor.bench.compare.v1`).
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    /// `"arbor.bench.compare.v1"`.
    pub schema: &'static str,
    /// Old record's CPU model.
    pub old_cpu: String,
    /// New record's CPU model.
    pub new_cpu: String,
    /// True when the CPU models differ (the ratios are then not comparable).
    pub cpu_mismatch: bool,
    /// Warnings (CPU, threads, benchmark kind).
    pub warnings: Vec<String>,
    /// Entries of both records, in the new record's order.
    pub entries: Vec<Compared>,
    /// Entries only in the old record (`scene / subject / threads`).
    pub only_old: Vec<String>,
    /// Entries only in the new record.
    pub only_new: Vec<String>,
    /// Shared entries that regressed beyond their noise.
    pub regressions: usize,
}

/// Compares two records with a noise floor (a fraction, 0.05 = 5%).
pub fn compare(old: &Record, new: &Record, floor: f64) -> Comparison {
    let name = |e: &RecordEntry| format!("{} / {} / {} threads", e.scene, e.subject, e.threads);
    let mut entries = Vec::new();
    let mut only_new = Vec::new();
    for n in &new.entries {
        let Some(o) = old.entries.iter().find(|o| o.key() == n.key()) else {
            only_new.push(name(n));
            continue;
        };
        let ratio = n.best_ms / o.best_ms;
        let noise = floor.max(o.spread).max(n.spread);
        let verdict = if ratio > 1.0 + noise {
            Verdict::Regression
        } else if ratio < 1.0 / (1.0 + noise) {
            Verdict::Faster
        } else {
            Verdict::Same
        };
        entries.push(Compared {
            scene: n.scene.clone(),
            subject: n.subject.clone(),
            threads: n.threads,
            old_ms: o.best_ms,
            new_ms: n.best_ms,
            ratio,
            noise,
            verdict,
        });
    }
    let only_old = old
        .entries
        .iter()
        .filter(|o| !new.entries.iter().any(|n| n.key() == o.key()))
        .map(name)
        .collect();
    let cpu_mismatch = old.cpu_model != new.cpu_model;
    let mut warnings = Vec::new();
    if cpu_mismatch {
        warnings.push(format!(
            "CPU models differ ('{}' vs '{}'): the ratios compare machines, not code, and are \
             not comparable",
            old.cpu_model, new.cpu_model
        ));
    }
    if old.cpus != new.cpus {
        warnings.push(format!(
            "hardware threads differ ({} vs {})",
            old.cpus, new.cpus
        ));
    }
    if old.bench != new.bench {
        warnings.push(format!(
            "benchmarks differ ({} vs {})",
            old.bench, new.bench
        ));
    }
    let regressions = entries
        .iter()
        .filter(|e| e.verdict == Verdict::Regression)
        .count();
    Comparison {
        schema: "arbor.bench.compare.v1",
        old_cpu: old.cpu_model.clone(),
        new_cpu: new.cpu_model.clone(),
        cpu_mismatch,
        warnings,
        entries,
        only_old,
        only_new,
        regressions,
    }
}

/// The comparison as text: the two runs, warnings, the table and a summary line.
fn text(c: &Comparison, old: &Record, new: &Record) -> String {
    let about = |r: &Record| {
        format!(
            "{} ({}), commit {}, {} on {} threads",
            r.bench,
            r.date_utc,
            r.commit.as_deref().unwrap_or("unknown"),
            r.cpu_model,
            r.cpus
        )
    };
    let mut s = format!("old: {}\nnew: {}\n", about(old), about(new));
    for w in &c.warnings {
        s += &format!("warning: {w}\n");
    }
    s += "\n";
    let mut t = Table::text(&[
        "scene", "subject", "threads", "old ms", "new ms", "new/old", "noise", "verdict",
    ])
    .right(&[2, 3, 4, 5, 6]);
    for e in &c.entries {
        t.push([
            e.scene.clone(),
            e.subject.clone(),
            e.threads.to_string(),
            format!("{:.3}", e.old_ms),
            format!("{:.3}", e.new_ms),
            format!("{:.3}", e.ratio),
            format!("{:.1}%", e.noise * 100.0),
            match e.verdict {
                Verdict::Regression => "REGRESSION",
                Verdict::Faster => "faster",
                Verdict::Same => "within noise",
            }
            .to_string(),
        ]);
    }
    s += &t.aligned();
    let faster = c
        .entries
        .iter()
        .filter(|e| e.verdict == Verdict::Faster)
        .count();
    s += &format!(
        "\n{} shared entries: {} regressions, {} faster, {} within noise (ratios of the \
         fastest runs; noise = max(floor, each run's spread))\n",
        c.entries.len(),
        c.regressions,
        faster,
        c.entries.len() - c.regressions - faster
    );
    for (which, list) in [("old", &c.only_old), ("new", &c.only_new)] {
        if !list.is_empty() {
            s += &format!("only in {which}: {}\n", list.join("; "));
        }
    }
    s
}

/// Runs `arbor bench compare`.
pub fn run(a: &BenchCompareArgs, ui: &Ui) -> anyhow::Result<()> {
    if !(a.noise.is_finite() && (0.0..=1000.0).contains(&a.noise)) {
        bail!(
            "--noise must be a percentage between 0 and 1000, got {}",
            a.noise
        );
    }
    let old = Record::load(&a.old)?;
    let new = Record::load(&a.new)?;
    let c = compare(&old, &new, a.noise / 100.0);
    if c.entries.is_empty() {
        bail!(
            "{} and {} share no (scene, subject, threads) entry",
            a.old.display(),
            a.new.display()
        );
    }
    if !ui.silent {
        if a.json {
            print!("{}", serde_json::to_string_pretty(&c)? + "\n");
        } else {
            print!("{}", text(&c, &old, &new));
        }
    }
    if a.fail_on_regression && c.regressions > 0 {
        bail!(
            "{} entr{} regressed beyond the noise (--fail-on-regression)",
            c.regressions,
            if c.regressions == 1 { "y" } else { "ies" }
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(cpu: &str, entries: Vec<RecordEntry>) -> Record {
        Record {
            schema: super::super::bench_record::SCHEMA.into(),
            bench: "build".into(),
            cpu_model: cpu.into(),
            cpus: 2,
            date_utc: "2026-12-06T00:00:00Z".into(),
            commit: None,
            command: "arbor bench build".into(),
            load_average_start: None,
            load_average_end: None,
            entries,
        }
    }

    #[test]
    fn noise_is_the_larger_spread_or_the_floor() {
        let e = |s: &str, t: &[f64]| RecordEntry::from_times("x", s, 1, t);
        let old = record(
            "A",
            vec![e("a", &[100.0]), e("b", &[100.0, 120.0]), e("c", &[100.0])],
        );
        let new = record(
            "A",
            vec![
                e("a", &[106.0]),
                e("b", &[115.0]),
                e("c", &[90.0]),
                e("d", &[1.0]),
            ],
        );
        let c = compare(&old, &new, 0.05);
        let v: Vec<Verdict> = c.entries.iter().map(|e| e.verdict).collect();
        assert_eq!(v, [Verdict::Regression, Verdict::Same, Verdict::Faster]);
        assert!((c.entries[1].noise - 0.2).abs() < 1e-12);
        assert_eq!(
            (c.regressions, c.only_new.len(), c.cpu_mismatch),
            (1, 1, false)
        );
        assert!(compare(&old, &record("B", vec![]), 0.05).cpu_mismatch);
    }
}
