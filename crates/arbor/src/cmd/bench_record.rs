//! Benchmark records (issue 33): the timings of one `arbor bench build` or `arbor bench
//! trace` run in a small versioned JSON document (`arbor.bench.record.v1`) that is committed
//! under `bench/records/<cpu-slug>/` and compared with a later run by `arbor bench compare`.
//!
//! A record says where and when it was measured (CPU model, hardware threads, date, commit,
//! command) and, per (scene, subject, threads), the fastest and median run in milliseconds
//! and the run-to-run spread, `(slowest - fastest) / fastest`. A subject is a builder id
//! (`binned-sah`) or a tracer on a ray set (`arbor bvh2 binned-sah / diffuse`). Every value
//! is a time, so lower is better everywhere.

use anyhow::{bail, Context};
use report::fs::write_atomic;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The schema name of a record.
pub const SCHEMA: &str = "arbor.bench.record.v1";

/// One benchmark run's timings and circumstances.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Record {
    /// [`SCHEMA`].
    pub schema: String,
    /// `build` or `trace`: the benchmark that measured it.
    pub bench: String,
    /// `/proc/cpuinfo`'s first `model name` (`unknown` where there is none).
    pub cpu_model: String,
    /// Hardware threads available to the process.
    pub cpus: usize,
    /// When the run started (UTC, ISO 8601).
    pub date_utc: String,
    /// `git rev-parse HEAD` of the working directory, `+dirty` when it had changes (null
    /// outside a git checkout).
    pub commit: Option<String>,
    /// The command line.
    pub command: String,
    /// `/proc/loadavg` at the start and the end of the run (null where unknown).
    pub load_average_start: Option<[f64; 3]>,
    /// At the end.
    pub load_average_end: Option<[f64; 3]>,
    /// The measurements.
    pub entries: Vec<RecordEntry>,
}

/// The runs of one subject on one scene at one thread count.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RecordEntry {
    /// Scene (file name or procedural spec).
    pub scene: String,
    /// Builder id, or `tracer / ray set`.
    pub subject: String,
    /// Worker threads.
    pub threads: usize,
    /// Runs measured.
    pub runs: usize,
    /// Fastest run, milliseconds.
    pub best_ms: f64,
    /// Median run, milliseconds.
    pub median_ms: f64,
    /// `(slowest - fastest) / fastest` over the runs (0 for one run).
    pub spread: f64,
}

impl RecordEntry {
    /// The entry of `times_ms` (at least one run, milliseconds).
    pub fn from_times(scene: &str, subject: &str, threads: usize, times_ms: &[f64]) -> Self {
        let mut t = times_ms.to_vec();
        t.sort_by(f64::total_cmp);
        let (best, worst) = (t.first().copied(), t.last().copied());
        let (best, worst) = (best.unwrap_or(0.0), worst.unwrap_or(0.0));
        Self {
            scene: scene.to_string(),
            subject: subject.to_string(),
            threads,
            runs: t.len(),
            best_ms: best,
            median_ms: t.get(t.len() / 2).copied().unwrap_or(0.0),
            spread: if best > 0.0 {
                (worst - best) / best
            } else {
                0.0
            },
        }
    }

    /// What identifies the entry across records.
    pub fn key(&self) -> (&str, &str, usize) {
        (&self.scene, &self.subject, self.threads)
    }
}

impl Record {
    /// A record of `bench` (`build` or `trace`) for a run described by `run`.
    pub fn new(bench: &str, run: &super::bench::RunInfo, entries: Vec<RecordEntry>) -> Self {
        Self {
            schema: SCHEMA.to_string(),
            bench: bench.to_string(),
            cpu_model: cpu_model(),
            cpus: run.cpus,
            date_utc: run.started_utc.clone(),
            commit: git_commit(),
            command: run.command.clone(),
            load_average_start: run.load_average_start,
            load_average_end: run.load_average_end,
            entries,
        }
    }

    /// Writes the record to `DIR/<cpu-slug>/<bench>.json` (atomically); returns the path.
    pub fn write_under(&self, dir: &Path) -> anyhow::Result<PathBuf> {
        let sub = dir.join(slug(&self.cpu_model));
        std::fs::create_dir_all(&sub)
            .with_context(|| format!("cannot create {}", sub.display()))?;
        let path = sub.join(format!("{}.json", self.bench));
        write_atomic(&path, &(serde_json::to_string_pretty(self)? + "\n"))?;
        Ok(path)
    }

    /// Reads and checks a record: a one-line error for a missing or empty file, another
    /// schema, or a record without entries or with a time that is not a positive number.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let name = path.display();
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {name}"))?;
        if text.trim().is_empty() {
            bail!("{name}: empty file, expected a benchmark record ({SCHEMA})");
        }
        let v: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{name}: not valid JSON"))?;
        match v.get("schema").and_then(|s| s.as_str()) {
            Some(SCHEMA) => {}
            Some(other) => bail!(
                "{name}: schema '{other}' is not a benchmark record ({SCHEMA}; write one with \
                 `arbor bench build --record DIR`)"
            ),
            None => bail!("{name}: no \"schema\" field, expected a benchmark record ({SCHEMA})"),
        }
        let r: Record = serde_json::from_value(v)
            .with_context(|| format!("{name}: not a valid {SCHEMA} record"))?;
        if r.entries.is_empty() {
            bail!("{name}: the record has no entries");
        }
        for e in &r.entries {
            let ok = |x: f64| x.is_finite() && x >= 0.0;
            if !(e.best_ms > 0.0 && ok(e.best_ms) && ok(e.median_ms) && ok(e.spread)) {
                bail!(
                    "{name}: entry {} / {} / {} threads: times must be positive and the \
                     spread non-negative",
                    e.scene,
                    e.subject,
                    e.threads
                );
            }
        }
        Ok(r)
    }
}

/// The CPU model from `/proc/cpuinfo` (`unknown` where it cannot be read).
pub fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.split_whitespace().collect::<Vec<_>>().join(" "))
        })
        .filter(|m| !m.is_empty())
        .unwrap_or_else(|| "unknown".to_string())
}

/// A file or folder name for any text (a CPU model, a scene): lowercase ASCII letters and
/// digits, runs of anything else one `-` (`Intel(R) Xeon(R) Gold 6230` ->
/// `intel-r-xeon-r-gold-6230`).
pub fn slug(model: &str) -> String {
    let mut s = String::new();
    for c in model.chars() {
        if c.is_ascii_alphanumeric() {
            s.push(c.to_ascii_lowercase());
        } else if !s.is_empty() && !s.ends_with('-') {
            s.push('-');
        }
    }
    let s = s.trim_end_matches('-').to_string();
    if s.is_empty() {
        "unknown".to_string()
    } else {
        s
    }
}

/// The checked-out commit, with `+dirty` when the tree has changes (None outside git).
fn git_commit() -> Option<String> {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let head = git(&["rev-parse", "HEAD"]).filter(|h| !h.is_empty())?;
    let dirty =
        git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
    Some(if dirty { head + "+dirty" } else { head })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slugs_and_entries() {
        assert_eq!(
            slug("Intel(R) Xeon(R) Gold 6230 CPU @ 2.10GHz"),
            "intel-r-xeon-r-gold-6230-cpu-2-10ghz"
        );
        assert_eq!(slug("  ()"), "unknown");
        let e = RecordEntry::from_times("s", "hlbvh", 2, &[12.0, 10.0, 11.0]);
        assert_eq!((e.runs, e.best_ms, e.median_ms), (3, 10.0, 11.0));
        assert!((e.spread - 0.2).abs() < 1e-12);
        assert_eq!(RecordEntry::from_times("s", "x", 1, &[5.0]).spread, 0.0);
    }
}
