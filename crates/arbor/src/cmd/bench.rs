//! `arbor bench`: benchmarks that run Arbor side by side with peer libraries in one process
//! and report ratios, one subcommand each (`bench_*.rs`).

use super::{bench_build, bench_compare, bench_refit, bench_trace};
use crate::progress::Ui;
use report::table::Table;

/// Arguments of `arbor bench`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub bench: BenchCommand,
}

/// The benchmarks `arbor bench` runs.
#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Build speed, SAH and peak memory of Arbor's builders next to Embree 3, obvhs and
    /// the bvh crate on the same meshes, on 1 and 2 threads.
    Build(bench_build::BenchBuildArgs),
    /// Traversal throughput of Arbor's kernels next to Embree 3's rtcIntersect1 and obvhs
    /// on the same primary and diffuse rays, on 1 and 2 threads.
    Trace(bench_trace::BenchTraceArgs),
    /// Per-frame update of an animated mesh: Arbor's in-place refit of each kernel next to
    /// Embree 3's RTC_BUILD_QUALITY_REFIT commit, on one thread.
    Refit(bench_refit::BenchRefitArgs),
    /// Two benchmark records (`--record`) side by side: new/old ratio per entry, with
    /// regressions beyond the runs' own noise flagged.
    Compare(bench_compare::BenchCompareArgs),
}

/// Runs `arbor bench ...`.
pub fn run(args: &BenchArgs, ui: &Ui) -> anyhow::Result<()> {
    match &args.bench {
        BenchCommand::Build(a) => bench_build::run(a, ui),
        BenchCommand::Trace(a) => bench_trace::run(a, ui),
        BenchCommand::Refit(a) => bench_refit::run(a, ui),
        BenchCommand::Compare(a) => bench_compare::run(a, ui),
    }
}

/// The circumstances of one benchmark run, at the head of every `arbor bench` document.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RunInfo {
    /// When the run started (UTC, ISO 8601).
    pub started_utc: String,
    /// `/proc/loadavg` (1, 5, 15 minutes) at the start (null where it does not exist).
    pub load_average_start: Option<[f64; 3]>,
    /// At the end.
    pub load_average_end: Option<[f64; 3]>,
    /// Hardware threads available to the process.
    pub cpus: usize,
    /// `/proc/cpuinfo`'s first model name (`unknown` without it).
    pub cpu_model: String,
    /// The command line.
    pub command: String,
}

impl RunInfo {
    /// Taken when a run starts (the end load average is left unknown).
    pub fn start() -> Self {
        Self {
            started_utc: utc_now(),
            load_average_start: load_average(),
            load_average_end: None,
            cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
            cpu_model: super::bench_record::cpu_model(),
            command: std::env::args().collect::<Vec<_>>().join(" "),
        }
    }

    /// The same, with the load average at the end of the run.
    pub fn finish(self) -> Self {
        Self {
            load_average_end: load_average(),
            ..self
        }
    }

    /// Two lines for a report's preamble: the command, and when, where and under what load.
    pub fn lines(&self) -> [String; 2] {
        let la = |l: Option<[f64; 3]>| {
            l.map_or("unknown".to_string(), |l| {
                format!("{:.2} {:.2} {:.2}", l[0], l[1], l[2])
            })
        };
        [
            format!("command: {}", self.command),
            format!(
                "started {} on {} hardware threads ({}); load average {} at the start, {} at \
                 the end",
                self.started_utc,
                self.cpus,
                self.cpu_model,
                la(self.load_average_start),
                la(self.load_average_end)
            ),
        ]
    }
}

/// The goal table of a benchmark report: one row per goal, its last column named `last`.
pub fn goal_table(last: &str) -> Table {
    Table::text(&["goal", "scene", "threads", "value", "target", "met", last]).right(&[2, 3, 4])
}

/// A benchmark report in Markdown: the preamble as a list, the measurement table and, when
/// it has rows, the goal table.
pub fn markdown_report(preamble: &[String], table: &Table, goals: Option<&Table>) -> String {
    let mut s = String::new();
    for l in preamble {
        s += &format!("- {l}\n");
    }
    s += "\n";
    s += &table.markdown();
    if let Some(g) = goals.filter(|g| !g.rows.is_empty()) {
        s += "\n";
        s += &g.markdown();
    }
    s
}

/// A benchmark report as terminal text: the preamble lines, the measurement table aligned
/// and, when it has rows, the goal table after a `goals:` line.
pub fn text_report(preamble: &[String], table: &Table, goals: Option<&Table>) -> String {
    let mut s = String::new();
    for l in preamble {
        s += &format!("{l}\n");
    }
    s += "\n";
    s += &table.aligned();
    if let Some(g) = goals.filter(|g| !g.rows.is_empty()) {
        s += "\ngoals:\n";
        s += &g.aligned();
    }
    s
}

/// `/proc/loadavg`'s three averages, where the file exists.
pub fn load_average() -> Option<[f64; 3]> {
    let s = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut it = s.split_whitespace().map(|v| v.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}

/// Now in UTC as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let (days, rem) = (secs / 86_400, secs % 86_400);
    let (y, m, d) = civil_from_days(days as i64);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

/// The proleptic Gregorian date of day `z` after 1970-01-01 (H. Hinnant's algorithm).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + (m <= 2) as i64, m, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_are_gregorian() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(59), (1970, 3, 1));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
        assert_eq!(civil_from_days(20_788), (2026, 12, 1));
        assert_eq!(utc_now().len(), 20);
    }
}
