//! The results as one self-contained static site (`arbor report html`; no scripts, no
//! external resources; works offline). Each page runs existing commands in-process
//! through the caller's [`Runner`] (the command line hands it its own parser and code, the
//! same as `arbor report mergetree` and the others run), writing their files
//! into a folder of the site, and then shows them: the thesis comparisons read from their
//! CSV files with the difference coloured against a stated tolerance, the Markdown
//! reports as HTML, and the SVG plots and PNG renders beside them, with how each number
//! was produced (command line, version, commit, date, CPU).

use crate::fs::write_atomic;
use crate::progress::Progress;
use crate::svg::xml;
use anyhow::Context;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of the site.
#[derive(Clone, Debug)]
pub struct HtmlOptions {
    /// Folder of the site (created if missing; the files it names are replaced).
    pub out: PathBuf,
    /// Small runs (procedural and small shared scenes, tiny images, one run each): the
    /// whole site in a few minutes. Without it every report runs at its defaults, which
    /// takes hours.
    pub quick: bool,
    /// Folder of the shared real scenes.
    pub scene_dir: PathBuf,
    /// No progress lines on stderr.
    pub quiet: bool,
}

/// Runs one `arbor` command line (the arguments after `arbor`) without printing its text
/// results; a failure is its one-line message.
pub type Runner<'a> = &'a dyn Fn(&[String]) -> Result<(), String>;

/// How far ours may lie from the thesis's value and still count as reproduced.
#[derive(Clone, Copy, Debug)]
enum Tolerance {
    /// Relative difference, percent: |ours / thesis - 1| <= t.
    Relative(f64),
    /// Values that are fractions (1.0 = 100%): |ours - thesis| <= t percentage points.
    Points(f64),
}

impl Tolerance {
    /// The difference as text and how it stands: 0 within the tolerance, 1 within twice
    /// it, 2 beyond; `None` where a relative difference is undefined (the thesis's value
    /// is 0 and ours is not).
    fn judge(self, ours: f64, thesis: f64) -> (String, Option<u8>) {
        let (d, t, text) = match self {
            Tolerance::Relative(_) if thesis == 0.0 && ours != 0.0 => {
                return ("undefined (thesis 0)".to_string(), None);
            }
            Tolerance::Relative(t) => {
                let d = if thesis == 0.0 {
                    0.0
                } else {
                    (ours / thesis - 1.0) * 100.0
                };
                (d, t, format!("{d:+.1}%"))
            }
            Tolerance::Points(t) => {
                let d = (ours - thesis) * 100.0;
                (d, t, format!("{d:+.1} pp"))
            }
        };
        let grade = if d.abs() <= t {
            0
        } else if d.abs() <= 2.0 * t {
            1
        } else {
            2
        };
        (text, Some(grade))
    }

    fn describe(self) -> String {
        match self {
            Tolerance::Relative(t) => format!("{t}% of the thesis's value"),
            Tolerance::Points(t) => format!("{t} percentage points"),
        }
    }
}

/// One reproduced table: columns of a CSV file that a report wrote, ours beside the
/// thesis's.
struct Compare {
    title: &'static str,
    /// The CSV file, relative to the step's folder.
    csv: &'static str,
    /// Columns that name a row.
    keys: &'static [&'static str],
    /// (our column, the thesis's column, heading).
    pairs: &'static [(&'static str, &'static str, &'static str)],
    tolerance: Tolerance,
}

/// One command the page runs, writing into `dir` (relative to the site).
struct Step {
    dir: &'static str,
    /// The command line after `arbor`, without `--out`.
    args: Vec<String>,
    /// Comparisons read from this step's CSV files.
    compares: Vec<Compare>,
}

/// One page of the site.
struct Page {
    file: &'static str,
    title: &'static str,
    about: &'static str,
    steps: Vec<Step>,
}

/// The tally of a page's comparisons: values within, near (within twice) and beyond
/// tolerance; and the page's commands that failed.
#[derive(Clone, Copy, Default)]
struct Tally([usize; 3], usize);

fn strings(a: &[&str]) -> Vec<String> {
    a.iter().map(|s| s.to_string()).collect()
}

/// The site's pages and the commands behind them.
fn plan(quick: bool, scene_dir: &Path) -> Vec<Page> {
    let shared = |name: &str| {
        let p = scene_dir.join(name);
        p.is_file().then(|| p.display().to_string())
    };
    let hairball = "proc:hairball?n=3000&seed=2";
    // In quick mode, a shared scene where the thesis has values, else a procedural one.
    let mergetree_scene = shared("bunny.ply").unwrap_or_else(|| "proc:soup?n=20000".into());
    let p4_scene = shared("crytek-sponza.ply").unwrap_or_else(|| hairball.into());
    let q = |small: &[&str], full: &[&str]| strings(if quick { small } else { full });
    let dir_arg = |mut v: Vec<String>| {
        v.push("--scene-dir".into());
        v.push(scene_dir.display().to_string());
        v
    };
    vec![
        Page {
            file: "builders.html",
            title: "BVH builders and peers",
            about: "Build speed, tree quality (SAH) and peak memory of Arbor's builders beside \
                    the peer libraries on the same meshes (`arbor bench build`).",
            steps: vec![Step {
                dir: "builders/bench",
                args: q(
                    &[
                        "bench",
                        "build",
                        "--threads",
                        "1",
                        "--runs",
                        "1",
                        "proc:soup?n=20000",
                    ],
                    &["bench", "build"],
                ),
                compares: vec![],
            }],
        },
        Page {
            file: "mergetree.html",
            title: "MergeTree hardware builder ([P2])",
            about: "The MergeTree streaming HLBVH builder simulated cycle by cycle on the three \
                    memory systems of [P2] §6.2: build time and bus utilization (Table III), \
                    tree quality, memory traffic (Table VI), area and power (Tables IV and VII).",
            steps: vec![Step {
                dir: "mergetree/report",
                args: dir_arg(if quick {
                    vec![
                        "report".into(),
                        "mergetree".into(),
                        "--scenes".into(),
                        mergetree_scene,
                    ]
                } else {
                    strings(&["report", "mergetree"])
                }),
                compares: vec![
                    Compare {
                        title: "[P2] Table III: build time and speed-up",
                        csv: "table3.csv",
                        keys: &["scene", "system"],
                        pairs: &[
                            ("ms", "thesis_ms", "build ms"),
                            ("speedup", "thesis_speedup", "speed-up"),
                            (
                                "bus_utilization",
                                "thesis_implied_utilization",
                                "bus utilization",
                            ),
                        ],
                        tolerance: Tolerance::Relative(25.0),
                    },
                    Compare {
                        title: "[P2] Table III: SAH in % of a sweep SAH build",
                        csv: "sah.csv",
                        keys: &["scene", "builder"],
                        pairs: &[("sah_vs_sweep_pct", "thesis_pct", "SAH %")],
                        tolerance: Tolerance::Relative(5.0),
                    },
                    Compare {
                        title: "[P2] Table VI: memory traffic (MB)",
                        csv: "table6.csv",
                        keys: &["scene"],
                        pairs: &[
                            ("mergetree_mb", "thesis_mergetree_mb", "MergeTree"),
                            (
                                "binned_sah_hw_mb",
                                "thesis_binned_sah_hw_mb",
                                "binned SAH HW",
                            ),
                            ("gpu_hlbvh_mb", "thesis_gpu_hlbvh_mb", "GPU HLBVH"),
                        ],
                        tolerance: Tolerance::Relative(25.0),
                    },
                    Compare {
                        title: "[P2] Table IV: area and power per unit",
                        csv: "table4.csv",
                        keys: &["unit"],
                        pairs: &[
                            ("area_mm2", "thesis_area_mm2", "area mm2"),
                            ("power_mw", "thesis_power_mw", "power mW"),
                        ],
                        tolerance: Tolerance::Relative(25.0),
                    },
                    Compare {
                        title: "[P2] Table VII: power per memory system",
                        csv: "table7.csv",
                        keys: &["system"],
                        pairs: &[
                            ("traffic_gbs", "thesis_traffic_gbs", "traffic GB/s"),
                            ("logic_mw", "thesis_logic_mw", "logic mW"),
                            ("dram_above_idle_mw", "thesis_dram_mw", "DRAM mW"),
                            ("total_mw", "thesis_total_mw", "total mW"),
                        ],
                        tolerance: Tolerance::Relative(25.0),
                    },
                ],
            }],
        },
        Page {
            file: "cbvh.html",
            title: "Compressed BVHs ([P3])",
            about: "Streaming bottom-up compression into 16-byte node pairs with backtracking: \
                    backtracking and traffic (Table 1), runtime on the simulated memory \
                    (Table 2), tree and trace quality.",
            steps: vec![Step {
                dir: "cbvh/report",
                args: dir_arg(q(
                    &[
                        "report",
                        "cbvh",
                        "--scenes",
                        "cloth",
                        "--no-sweep",
                        "--runtime-dram",
                        "simple:lpddr3-1600-1x64",
                        "--trace-size",
                        "64x36",
                    ],
                    &["report", "cbvh"],
                )),
                compares: vec![
                    Compare {
                        title: "[P3] Table 1: backtracking and traffic",
                        csv: "table1.csv",
                        keys: &["metric", "stat", "variant"],
                        pairs: &[("ours", "thesis", "value")],
                        tolerance: Tolerance::Relative(25.0),
                    },
                    Compare {
                        title: "[P3] Table 2: runtime against the uncompressed BVH",
                        csv: "table2.csv",
                        keys: &["scene", "variant"],
                        pairs: &[("vs_bvh", "thesis_vs_bvh", "time / BVH's")],
                        tolerance: Tolerance::Relative(25.0),
                    },
                    Compare {
                        title: "[P3] §5.4: extra box and triangle tests of the compressed tree",
                        csv: "trace_quality.csv",
                        keys: &["scene", "rays"],
                        pairs: &[
                            ("box_increase", "thesis_box_increase", "box tests"),
                            ("tri_increase", "thesis_tri_increase", "triangle tests"),
                        ],
                        tolerance: Tolerance::Points(5.0),
                    },
                ],
            }],
        },
        Page {
            file: "tracing.html",
            title: "Ray tracing",
            about: "The demo on the bundled animated character: builds, refits, MergeTree, CBVH \
                    traffic, primary and diffuse renders through binary and 4-wide trees with \
                    their heatmaps, and the accelerator model (`arbor demo`).",
            steps: vec![Step {
                dir: "tracing/demo",
                args: q(&["demo", "--frames", "4"], &["demo"]),
                compares: vec![],
            }],
        },
        Page {
            file: "accelerator.html",
            title: "Ray-tracing accelerator ([P4])",
            about: "The [P4] traversal accelerator simulated cycle by cycle with BVH and MBVH4, \
                    primary and diffuse rays: performance, DRAM traffic, energy and area \
                    (Tables 1 and 2).",
            steps: vec![Step {
                dir: "accelerator/rtunit",
                args: dir_arg(if quick {
                    vec![
                        "report".into(),
                        "rtunit".into(),
                        "--scenes".into(),
                        p4_scene,
                        "--width".into(),
                        "64".into(),
                        "--height".into(),
                        "36".into(),
                        "--check-sample".into(),
                        "0".into(),
                    ]
                } else {
                    strings(&["report", "rtunit"])
                }),
                compares: vec![Compare {
                    title: "[P4] Table 2: performance and performance per area",
                    csv: "table2.csv",
                    keys: &["scene", "rays", "tree"],
                    // Rates only: the thesis's traffic and energy are per 1280x720 frame
                    // (the report below has them beside ours at this run's size).
                    pairs: &[
                        ("mrps", "thesis_mrps", "MRPS"),
                        ("mrps_per_mm2", "thesis_mrps_per_mm2", "MRPS / mm2"),
                    ],
                    tolerance: Tolerance::Relative(25.0),
                }],
            }],
        },
        Page {
            file: "system.html",
            title: "System energy ([P2] §6.4)",
            about: "Energy per frame of build plus trace with four builders (Table VIII, \
                    Fig. 7), tree-update policies over an animation, and the component models \
                    (SRAM, FPU, DRAM) behind every energy figure.",
            steps: vec![
                Step {
                    dir: "system/report",
                    args: dir_arg(q(
                        &[
                            "report",
                            "system",
                            "--scenes",
                            hairball,
                            "--animated",
                            "proc:cloth?n=20000",
                            "--frames",
                            "3",
                            "--width",
                            "32",
                            "--height",
                            "24",
                            "--sample",
                            "1",
                        ],
                        &["report", "system"],
                    )),
                    compares: vec![Compare {
                        title: "[P2] Table VIII: energy relative to binned SAH",
                        csv: "table8.csv",
                        keys: &["rays", "scenes", "builder"],
                        pairs: &[
                            ("build", "thesis_build", "build"),
                            ("trace", "thesis_trace", "trace"),
                            ("total", "thesis_total", "total"),
                        ],
                        tolerance: Tolerance::Points(8.0),
                    }],
                },
                Step {
                    dir: "system/energy",
                    args: dir_arg(q(
                        &[
                            "report",
                            "energy",
                            "--scenes",
                            "proc:cloth?n=20000",
                            "--p4-scenes",
                            hairball,
                        ],
                        &["report", "energy"],
                    )),
                    compares: vec![],
                },
            ],
        },
        Page {
            file: "sensitivity.html",
            title: "Sensitivity of the system model",
            about: "Every open assumption of the [P2] §6.4 system model swept over its \
                    documented range: each Table VIII figure's default, low and high value and \
                    the assumption that moves it most.",
            steps: vec![Step {
                dir: "sensitivity/report",
                args: dir_arg(q(
                    &[
                        "report",
                        "sensitivity",
                        "--scenes",
                        hairball,
                        "--p4-scene",
                        "none",
                        "--width",
                        "32",
                        "--height",
                        "24",
                        "--sample",
                        "1",
                    ],
                    &["report", "sensitivity"],
                )),
                compares: vec![Compare {
                    title: "Table VIII figures at the default assumptions",
                    csv: "sensitivity.csv",
                    keys: &["figure"],
                    pairs: &[("default", "thesis", "default")],
                    tolerance: Tolerance::Points(8.0),
                }],
            }],
        },
        Page {
            file: "beyond.html",
            title: "Beyond the thesis (issue 18)",
            about: "The open problems the thesis names, each a mode of the MergeTree model \
                    beside the thesis's baseline: forecasting read scheduling, MBVH4 and \
                    compressed 4-wide nodes out of the stream, point k-d trees and octrees, \
                    and plane-sharing CBVH update (no thesis numbers to compare: the thesis \
                    leaves them open; docs/beyond-thesis.md).",
            steps: vec![Step {
                dir: "beyond/report",
                args: dir_arg(q(&["report", "beyond", "--quick"], &["report", "beyond"])),
                compares: Vec::new(),
            }],
        },
    ]
}

/// The machine and build the numbers come from.
#[derive(Clone, Debug)]
pub struct Provenance {
    /// Arbor's version.
    pub version: &'static str,
    /// The source's commit (see [`git_commit`]).
    pub commit: String,
    /// When, `YYYY-MM-DDTHH:MM:SSZ`.
    pub date: String,
    /// The CPU model.
    pub cpu: String,
    /// Threads available.
    pub threads: usize,
}

impl Provenance {
    /// This build and machine now; `date` and `cpu` from the caller (the command line's
    /// benchmark records use the same).
    pub fn gather(date: String, cpu: String) -> Self {
        Provenance {
            version: env!("CARGO_PKG_VERSION"),
            commit: git_commit().unwrap_or_else(|| "unknown (no git checkout found)".into()),
            date,
            cpu,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }
}

/// The commit of the source tree the binary was built from, with `+changes` when it has
/// uncommitted changes; `None` without git or outside a checkout.
pub fn git_commit() -> Option<String> {
    let src = env!("CARGO_MANIFEST_DIR");
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .arg("-C")
            .arg(src)
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let head = git(&["rev-parse", "--short=12", "HEAD"]).filter(|h| !h.is_empty())?;
    let dirty =
        git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
    Some(if dirty {
        format!("{head}+changes")
    } else {
        head
    })
}

/// A command line as a shell would need it typed (arguments with special characters
/// quoted).
pub fn shell_line(args: &[String]) -> String {
    args.iter()
        .map(|a| {
            if !a.is_empty()
                && a.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_./,:=+".contains(c))
            {
                a.clone()
            } else {
                format!("'{}'", a.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Checks `--out` and creates it.
fn prepare_out(out: &Path) -> anyhow::Result<()> {
    if out.exists() && !out.is_dir() {
        anyhow::bail!("--out {} is a file, not a folder", out.display());
    }
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create the site folder {}", out.display()))
}

/// Builds the site: runs every page's commands with `run_arbor` and writes the pages.
pub fn run(
    a: &HtmlOptions,
    prov: &Provenance,
    run_arbor: Runner,
    ui: &dyn Progress,
) -> anyhow::Result<()> {
    prepare_out(&a.out)?;
    let pages = plan(a.quick, &a.scene_dir);
    let total: usize = pages.iter().map(|p| p.steps.len()).sum();
    let start = Instant::now();
    let mut done = 0;
    let mut summaries = Vec::new();
    let mut failed = Vec::new();
    for page in &pages {
        let mut body = String::new();
        let mut tally = Tally::default();
        for step in &page.steps {
            done += 1;
            let dir = a.out.join(step.dir);
            let mut args = step.args.clone();
            args.push("--out".into());
            args.push(dir.display().to_string());
            // The command as the page shows it: the output folder relative to the site.
            let mut shown = args.clone();
            if let Some(last) = shown.last_mut() {
                *last = step.dir.to_string();
            }
            let shown = format!("arbor {}", shell_line(&shown));
            if !a.quiet {
                eprintln!("report html: [{done}/{total}] {shown}");
            }
            let t = Instant::now();
            // A command that fails is shown failed on its page; the others still run.
            match run_arbor(&args) {
                Ok(()) => {
                    let secs = t.elapsed().as_secs_f64();
                    step_html(&mut body, &mut tally, &a.out, step, &shown, secs)?;
                }
                Err(why) => {
                    ui.warn(&format!("{shown} failed: {why}"));
                    let _ = writeln!(
                        body,
                        "<h2>{}</h2>\n<p class=\"prov\">Command: <code>{}</code></p>\n\
                         <p class=\"off\">This command failed: {}</p>",
                        xml(&step_title(&step.args)),
                        xml(&shown),
                        xml(&why)
                    );
                    failed.push(shown);
                    tally.1 += 1;
                }
            }
        }
        let html = page_html(page.title, page.about, &body, prov, Some(page.file));
        write_atomic(&a.out.join(page.file), &html)?;
        summaries.push((page, tally));
    }
    write_atomic(&a.out.join("style.css"), STYLE)?;
    let index = index_html(&summaries, prov, a.quick);
    write_atomic(&a.out.join("index.html"), &index)?;
    if !a.quiet {
        eprintln!(
            "report html: wrote {} ({} pages) in {:.0} s",
            a.out.join("index.html").display(),
            pages.len() + 1,
            start.elapsed().as_secs_f64()
        );
    }
    anyhow::ensure!(
        failed.is_empty(),
        "{} of {total} commands failed ({}); the site in {} shows which and why",
        failed.len(),
        failed.join("; "),
        a.out.display()
    );
    Ok(())
}

/// The site's style sheet (one file, linked by every page).
const STYLE: &str = "body{font-family:sans-serif;max-width:72rem;margin:1rem auto;padding:0 1rem;color:#222;line-height:1.4}
nav{border-bottom:1px solid #ccc;padding-bottom:.5rem;margin-bottom:1rem}
nav a{margin-right:1rem}
table{border-collapse:collapse;margin:.5rem 0 1rem;font-size:.85rem}
th,td{border:1px solid #ccc;padding:.15rem .4rem;text-align:left;vertical-align:top}
th{background:#f3f3f3}
td.num{text-align:right;font-variant-numeric:tabular-nums}
.ok{background:#d9f2d9}.near{background:#fff0c2}.off{background:#f8d0d0}
.prov{background:#f6f6f6;border:1px solid #ddd;padding:.5rem;font-size:.85rem}
.prov code{word-break:break-all}
figure{display:inline-block;margin:.5rem;vertical-align:top}
figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.8rem;color:#555}
.scroll{overflow-x:auto}
";

/// A full page: `body` with the navigation and the provenance.
fn page_html(
    title: &str,
    about: &str,
    body: &str,
    p: &Provenance,
    current: Option<&str>,
) -> String {
    let mut s = format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <title>{t} - Arbor</title>\n<link rel=\"stylesheet\" href=\"style.css\">\n</head>\n<body>\n<nav>",
        t = xml(title)
    );
    if current.is_some() {
        s += "<a href=\"index.html\">Arbor results</a>";
    }
    s += "</nav>\n";
    let _ = writeln!(s, "<h1>{}</h1>\n<p>{}</p>", xml(title), inline(about));
    let _ = writeln!(
        s,
        "<div class=\"prov\">Produced by arbor {} (commit {}) on {} ({} threads), {}.</div>",
        p.version,
        xml(&p.commit),
        xml(&p.cpu),
        p.threads,
        p.date
    );
    s += body;
    s += "</body>\n</html>\n";
    s
}

/// The index: one line per page, with its comparisons' tally.
fn index_html(pages: &[(&Page, Tally)], p: &Provenance, quick: bool) -> String {
    let mut b = String::new();
    let _ = writeln!(
        b,
        "<p>{}</p>",
        if quick {
            "Built with <code>--quick</code>: small scenes and images, so most thesis \
             comparisons are on stand-in scenes or missing; run <code>arbor report html</code> \
             without it for the thesis's settings (hours)."
        } else {
            "Built at every report's default settings."
        }
    );
    b += "<table>\n<tr><th>page</th><th>what</th><th>compared with the thesis: within / near / beyond tolerance</th></tr>\n";
    for (page, t) in pages {
        let [ok, near, off] = t.0;
        let tally = if t.1 > 0 {
            format!("<span class=\"off\">{} command(s) failed</span>", t.1)
        } else if ok + near + off == 0 {
            "no thesis values".to_string()
        } else {
            format!("{ok} / {near} / {off}")
        };
        let _ = writeln!(
            b,
            "<tr><td><a href=\"{}\">{}</a></td><td>{}</td><td class=\"num\">{tally}</td></tr>",
            page.file,
            xml(page.title),
            inline(page.about)
        );
    }
    b += "</table>\n<p>Near: within twice the tolerance. Each page states its tolerances and the command lines that produced its numbers.</p>\n";
    page_html(
        "Arbor: Hardware Accelerators for Animated Ray Tracing, reproduced",
        "The thesis's tables and figures (Viitanen 2018) regenerated by Arbor's models, beside \
         the thesis's numbers.",
        &b,
        p,
        None,
    )
}

/// One step's part of a page: its command, comparisons, report, figures and files.
fn step_html(
    b: &mut String,
    tally: &mut Tally,
    site: &Path,
    step: &Step,
    shown: &str,
    secs: f64,
) -> anyhow::Result<()> {
    let dir = site.join(step.dir);
    let _ = writeln!(
        b,
        "<h2>{}</h2>\n<p class=\"prov\">Command: <code>{}</code> ({secs:.1} s). Files in <code>{}/</code>.</p>",
        xml(&step_title(&step.args)),
        xml(shown),
        xml(step.dir)
    );
    folder_html(b, tally, &dir, step.dir, &step.compares)
}

/// `rel/name` (`name` where `rel` is empty), escaped for an attribute.
fn href(rel: &str, name: &str) -> String {
    if rel.is_empty() {
        xml(name)
    } else {
        format!("{}/{}", xml(rel), xml(name))
    }
}

/// What a folder of results holds, as HTML: the comparisons, its Markdown reports (or the
/// tables of a demo's `summary.json`), the figures they do not show, and links to the data
/// files. `rel` is the folder relative to the page.
fn folder_html(
    b: &mut String,
    tally: &mut Tally,
    dir: &Path,
    rel: &str,
    compares: &[Compare],
) -> anyhow::Result<()> {
    for c in compares {
        compare_html(b, tally, &dir.join(c.csv), c)?;
    }
    let mut shown_images = Vec::new();
    let md = dir.join("report.md");
    let mds: Vec<PathBuf> = if md.is_file() {
        vec![md]
    } else {
        files_with(dir, &["md"])
    };
    for m in mds {
        let text =
            std::fs::read_to_string(&m).with_context(|| format!("cannot read {}", m.display()))?;
        b.push_str("<div class=\"scroll\">\n");
        b.push_str(&markdown(&text, rel, dir, &mut shown_images));
        b.push_str("</div>\n");
    }
    let images: Vec<PathBuf> = files_with(dir, &["svg", "png"])
        .into_iter()
        .filter(|p| !shown_images.contains(p))
        .collect();
    if !images.is_empty() {
        b.push_str("<h3>Figures</h3>\n");
        for p in images {
            let name = file_name(&p);
            let _ = writeln!(
                b,
                "<figure><img src=\"{}\" alt=\"{n}\"><figcaption>{n}</figcaption></figure>",
                href(rel, &name),
                n = xml(&name)
            );
        }
    }
    let summary = dir.join("summary.json");
    if summary.is_file() {
        json_tables(b, &summary, DEMO_TABLES)?;
    }
    let data = files_with(dir, &["csv", "json", "md", "txt"]);
    if !data.is_empty() {
        b.push_str("<p>Data files: ");
        let links: Vec<String> = data
            .iter()
            .map(|p| {
                let n = file_name(p);
                format!("<a href=\"{}\">{}</a>", href(rel, &n), xml(&n))
            })
            .collect();
        b.push_str(&links.join(", "));
        b.push_str("</p>\n");
    }
    Ok(())
}

/// The tables of `arbor demo`'s `summary.json` a page shows: (key, heading).
const DEMO_TABLES: &[(&str, &str)] = &[
    ("builds", "Builds: every builder at a few frames"),
    ("refits", "Refit against rebuild over the animation"),
    ("mergetree", "MergeTree on the three memory systems"),
    ("cbvh", "CBVH traffic: top-down against streaming bottom-up"),
    (
        "renders",
        "Renders: primary and diffuse rays through both tree formats",
    ),
    ("accelerator", "The accelerator model with each tree"),
];

/// Arrays of objects in a JSON document as tables (the scalar fields of each object).
fn json_tables(b: &mut String, path: &Path, keys: &[(&str, &str)]) -> anyhow::Result<()> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let doc: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    for (key, title) in keys {
        let Some(rows) = doc.get(key).and_then(|v| v.as_array()) else {
            continue;
        };
        let Some(first) = rows.first().and_then(|r| r.as_object()) else {
            continue;
        };
        // The columns that name a row first, then the rest by name.
        const LEAD: [&str; 6] = ["frame", "builder", "format", "rays", "tree", "dram"];
        let mut cols: Vec<&String> = first
            .iter()
            .filter(|(_, v)| !v.is_array() && !v.is_object())
            .map(|(k, _)| k)
            .collect();
        cols.sort_by_key(|c| LEAD.iter().position(|l| l == c).unwrap_or(LEAD.len()));
        let _ = writeln!(
            b,
            "<h3>{}</h3>\n<div class=\"scroll\"><table>\n<tr>",
            xml(title)
        );
        for c in &cols {
            let _ = write!(b, "<th>{}</th>", xml(c));
        }
        b.push_str("</tr>\n");
        for r in rows {
            b.push_str("<tr>");
            for c in &cols {
                match r.get(c.as_str()) {
                    Some(serde_json::Value::Number(n)) => {
                        let v = n.as_f64().unwrap_or(0.0);
                        let text = if n.is_f64() { short(v) } else { n.to_string() };
                        let _ = write!(b, "<td class=\"num\">{text}</td>");
                    }
                    Some(serde_json::Value::String(t)) => {
                        let _ = write!(b, "<td>{}</td>", xml(t));
                    }
                    Some(v) if !v.is_null() => {
                        let _ = write!(b, "<td>{}</td>", xml(&v.to_string()));
                    }
                    _ => b.push_str("<td></td>"),
                }
            }
            b.push_str("</tr>\n");
        }
        b.push_str("</table></div>\n");
    }
    Ok(())
}

/// Writes `dir/index.html` (and its `style.css`): a page of what the folder holds, made by
/// `command` (as the user would type it), with provenance `prov`. `arbor demo` ends with
/// this.
pub fn write_folder_page(
    dir: &Path,
    title: &str,
    about: &str,
    command: &str,
    prov: &Provenance,
) -> anyhow::Result<()> {
    let mut b = String::new();
    let _ = writeln!(
        b,
        "<p class=\"prov\">Command: <code>{}</code>.</p>",
        xml(command)
    );
    folder_html(&mut b, &mut Tally::default(), dir, "", &[])?;
    write_atomic(&dir.join("style.css"), STYLE)?;
    write_atomic(
        &dir.join("index.html"),
        page_html(title, about, &b, prov, None),
    )
}

/// `arbor` and the subcommand words of a step's command line.
fn step_title(args: &[String]) -> String {
    let words: Vec<&str> = args
        .iter()
        .take(2)
        .map(String::as_str)
        .take_while(|a| !a.starts_with('-'))
        .collect();
    format!("arbor {}", words.join(" "))
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The files directly in `dir` with one of the extensions, sorted by name.
fn files_with(dir: &Path, exts: &[&str]) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| {
                    p.is_file()
                        && p.extension()
                            .and_then(|e| e.to_str())
                            .is_some_and(|e| exts.contains(&e))
                })
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Splits a CSV line with optional double-quoted cells.
fn csv_cells(line: &str) -> Vec<String> {
    let mut cells = vec![String::new()];
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                chars.next();
                if let Some(s) = cells.last_mut() {
                    s.push('"');
                }
            }
            '"' => quoted = !quoted,
            ',' if !quoted => cells.push(String::new()),
            c => {
                if let Some(s) = cells.last_mut() {
                    s.push(c);
                }
            }
        }
    }
    cells
}

/// A comparison table from a report's CSV file: the rows where the thesis has a value.
fn compare_html(b: &mut String, tally: &mut Tally, csv: &Path, c: &Compare) -> anyhow::Result<()> {
    let _ = writeln!(b, "<h3>{}</h3>", xml(c.title));
    let Ok(text) = std::fs::read_to_string(csv) else {
        let _ = writeln!(
            b,
            "<p>Not produced by this run ({} is missing).</p>",
            xml(&file_name(csv))
        );
        return Ok(());
    };
    let mut lines = text.lines();
    let head = csv_cells(lines.next().unwrap_or(""));
    let col = |name: &str| head.iter().position(|h| h == name);
    let keys: Vec<Option<usize>> = c.keys.iter().map(|k| col(k)).collect();
    let pairs: Vec<(Option<usize>, Option<usize>, &str)> = c
        .pairs
        .iter()
        .map(|(o, t, h)| (col(o), col(t), *h))
        .collect();
    let num = |row: &[String], i: Option<usize>| {
        i.and_then(|i| row.get(i))
            .and_then(|s| s.trim().parse::<f64>().ok())
            .filter(|v| v.is_finite())
    };
    let mut rows = String::new();
    let mut shown = 0;
    for line in lines.filter(|l| !l.trim().is_empty()) {
        let row = csv_cells(line);
        if pairs.iter().all(|&(_, t, _)| num(&row, t).is_none()) {
            continue;
        }
        shown += 1;
        rows += "<tr>";
        for k in &keys {
            let cell = k.and_then(|i| row.get(i)).map_or("", |s| s.as_str());
            let _ = write!(rows, "<td>{}</td>", xml(cell));
        }
        for &(o, t, _) in &pairs {
            match (num(&row, o), num(&row, t)) {
                (Some(ours), Some(thesis)) => {
                    let (d, grade) = c.tolerance.judge(ours, thesis);
                    if let Some(g) = grade {
                        tally.0[g as usize] += 1;
                    }
                    let class = grade.map_or("", |g| ["ok", "near", "off"][g as usize]);
                    let _ = write!(
                        rows,
                        "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num {class}\">{d}</td>",
                        short(ours),
                        short(thesis)
                    );
                }
                (ours, _) => {
                    let _ = write!(
                        rows,
                        "<td class=\"num\">{}</td><td></td><td></td>",
                        ours.map_or(String::new(), short)
                    );
                }
            }
        }
        rows += "</tr>\n";
    }
    if shown == 0 {
        let _ = writeln!(
            b,
            "<p>No thesis values for these scenes (the thesis's scenes were not in this run).</p>"
        );
        return Ok(());
    }
    let _ = writeln!(
        b,
        "<p>Difference coloured against a tolerance of {}: <span class=\"ok\">within</span>, \
         <span class=\"near\">near (within twice)</span>, <span class=\"off\">beyond</span>. From <code>{}</code>.</p>",
        c.tolerance.describe(),
        xml(&file_name(csv))
    );
    b.push_str("<div class=\"scroll\"><table>\n<tr>");
    for k in c.keys {
        let _ = write!(b, "<th>{}</th>", xml(k));
    }
    for (_, _, h) in &pairs {
        let _ = write!(
            b,
            "<th>{h} (ours)</th><th>thesis</th><th>difference</th>",
            h = xml(h)
        );
    }
    b.push_str("</tr>\n");
    b.push_str(&rows);
    b.push_str("</table></div>\n");
    Ok(())
}

/// A number in at most four significant digits.
fn short(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    format!("{v:.digits$}")
}

/// Inline Markdown as HTML: escaped text, `code`, **bold**, `\[` escapes; links keep
/// their text and show their target in brackets (they point into the source tree).
fn inline(t: &str) -> String {
    let t = t.replace("\\[", "[").replace("\\]", "]");
    let mut out = String::new();
    let mut rest = t.as_str();
    let mut code = false;
    while let Some(i) = rest.find('`') {
        let part = &rest[..i];
        if code {
            let _ = write!(out, "<code>{}</code>", xml(part));
        } else {
            out += &plain_inline(part);
        }
        code = !code;
        rest = &rest[i + 1..];
    }
    if code {
        out.push('`');
    }
    out += &plain_inline(rest);
    out
}

fn plain_inline(t: &str) -> String {
    let mut s = xml(t);
    while let (Some(a), true) = (s.find("**"), s.matches("**").count() >= 2) {
        s.replace_range(a..a + 2, "<strong>");
        if let Some(b) = s.find("**") {
            s.replace_range(b..b + 2, "</strong>");
        }
    }
    s
}

/// Markdown of the reports as HTML: headings, paragraphs, lists, tables, fenced code and
/// images (`![alt](file)`, resolved in `dir` and linked as `rel/file`; recorded in
/// `images`).
fn markdown(text: &str, rel: &str, dir: &Path, images: &mut Vec<PathBuf>) -> String {
    let mut out = String::new();
    let lines: Vec<&str> = text.lines().collect();
    let mut i = 0;
    let mut para: Vec<&str> = Vec::new();
    let flush = |out: &mut String, para: &mut Vec<&str>| {
        if !para.is_empty() {
            let _ = writeln!(out, "<p>{}</p>", inline(&para.join(" ")));
            para.clear();
        }
    };
    while i < lines.len() {
        let l = lines[i].trim_end();
        if l.trim().is_empty() {
            flush(&mut out, &mut para);
            i += 1;
        } else if l.starts_with("```") {
            flush(&mut out, &mut para);
            out += "<pre>";
            i += 1;
            while i < lines.len() && !lines[i].starts_with("```") {
                out += &xml(lines[i]);
                out.push('\n');
                i += 1;
            }
            out += "</pre>\n";
            i += 1;
        } else if let Some(h) = heading(l) {
            flush(&mut out, &mut para);
            // The page has the h1; a report's headings go one level down.
            let level = (h.0 + 1).min(6);
            let _ = writeln!(out, "<h{level}>{}</h{level}>", inline(h.1));
            i += 1;
        } else if l.starts_with('|') {
            flush(&mut out, &mut para);
            let start = i;
            while i < lines.len() && lines[i].trim_start().starts_with('|') {
                i += 1;
            }
            out += &table(&lines[start..i]);
        } else if let Some(item) = l.strip_prefix("- ").or_else(|| l.strip_prefix("* ")) {
            flush(&mut out, &mut para);
            out += "<ul>\n";
            let mut item = item.to_string();
            i += 1;
            loop {
                // Continuation lines of an item are indented.
                while i < lines.len() && lines[i].starts_with("  ") && !lines[i].trim().is_empty() {
                    item.push(' ');
                    item += lines[i].trim();
                    i += 1;
                }
                let _ = writeln!(out, "<li>{}</li>", inline(&item));
                match lines
                    .get(i)
                    .and_then(|l| l.strip_prefix("- ").or_else(|| l.strip_prefix("* ")))
                {
                    Some(next) => {
                        item = next.to_string();
                        i += 1;
                    }
                    None => break,
                }
            }
            out += "</ul>\n";
        } else if let Some((alt, src)) = image(l) {
            flush(&mut out, &mut para);
            let p = dir.join(src);
            if p.is_file() && !src.contains("..") {
                let _ = writeln!(
                    out,
                    "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
                    href(rel, src),
                    xml(alt),
                    xml(alt)
                );
                images.push(p);
            } else {
                let _ = writeln!(out, "<p>(figure {} not produced)</p>", xml(src));
            }
            i += 1;
        } else {
            para.push(l.trim());
            i += 1;
        }
    }
    flush(&mut out, &mut para);
    out
}

/// `# text` as (level, text).
fn heading(l: &str) -> Option<(usize, &str)> {
    let level = l.chars().take_while(|&c| c == '#').count();
    (1..=6)
        .contains(&level)
        .then(|| l[level..].strip_prefix(' '))
        .flatten()
        .map(|t| (level, t))
}

/// `![alt](src)` alone on a line as (alt, src).
fn image(l: &str) -> Option<(&str, &str)> {
    let rest = l.trim().strip_prefix("![")?;
    let (alt, rest) = rest.split_once("](")?;
    let src = rest.strip_suffix(')')?;
    Some((alt, src))
}

/// The cells of a Markdown table row.
fn row_cells(l: &str) -> Vec<&str> {
    let l = l.trim();
    let l = l.strip_prefix('|').unwrap_or(l);
    let l = l.strip_suffix('|').unwrap_or(l);
    l.split('|').map(str::trim).collect()
}

/// A Markdown table (header, alignment row, body) as HTML.
fn table(rows: &[&str]) -> String {
    let mut s = String::from("<table>\n");
    let is_rule = |l: &str| {
        row_cells(l)
            .iter()
            .all(|c| !c.is_empty() && c.chars().all(|ch| "-:".contains(ch)))
    };
    let right: Vec<bool> = rows
        .get(1)
        .filter(|l| is_rule(l))
        .map(|l| row_cells(l).iter().map(|c| c.ends_with(':')).collect())
        .unwrap_or_default();
    for (k, l) in rows.iter().enumerate() {
        if k == 1 && is_rule(l) {
            continue;
        }
        s += "<tr>";
        for (j, c) in row_cells(l).iter().enumerate() {
            let tag = if k == 0 { "th" } else { "td" };
            let class = if k > 0 && right.get(j) == Some(&true) {
                " class=\"num\""
            } else {
                ""
            };
            let _ = write!(s, "<{tag}{class}>{}</{tag}>", inline(c));
        }
        s += "</tr>\n";
    }
    s += "</table>\n";
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tolerance_grades() {
        let t = Tolerance::Relative(25.0);
        assert_eq!(t.judge(1.1, 1.0), ("+10.0%".to_string(), Some(0)));
        assert_eq!(t.judge(1.4, 1.0).1, Some(1));
        assert_eq!(t.judge(0.4, 1.0).1, Some(2));
        // Against a thesis value of 0 a relative difference is undefined, not graded.
        assert_eq!(
            t.judge(1.0, 0.0),
            ("undefined (thesis 0)".to_string(), None)
        );
        assert_eq!(t.judge(0.0, 0.0).1, Some(0));
        let p = Tolerance::Points(8.0);
        assert_eq!(p.judge(0.73, 0.71), ("+2.0 pp".to_string(), Some(0)));
        assert_eq!(p.judge(0.5, 0.32).1, Some(2));
    }

    #[test]
    fn markdown_tables_lists_images() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("a.svg"), "<svg/>").unwrap();
        let md = "# T \\[P2\\]\n\npara `x<y` **b**\nmore\n\n- one\n  cont\n- two\n\n\
                  | a | b |\n|---|---:|\n| 1 | 2 |\n\n![fig](a.svg)\n\n![gone](b.svg)\n";
        let mut imgs = Vec::new();
        let h = markdown(md, "d", dir.path(), &mut imgs);
        assert!(h.contains("<h2>T [P2]</h2>"), "{h}");
        assert!(
            h.contains("<p>para <code>x&lt;y</code> <strong>b</strong> more</p>"),
            "{h}"
        );
        assert!(h.contains("<li>one cont</li>\n<li>two</li>"), "{h}");
        assert!(
            h.contains(
                "<tr><th>a</th><th>b</th></tr>\n<tr><td>1</td><td class=\"num\">2</td></tr>"
            ),
            "{h}"
        );
        assert!(h.contains("<img src=\"d/a.svg\" alt=\"fig\">"), "{h}");
        assert!(h.contains("(figure b.svg not produced)"), "{h}");
        assert_eq!(imgs, vec![dir.path().join("a.svg")]);
    }

    #[test]
    fn csv_and_comparison() {
        assert_eq!(csv_cells("a,\"b,\"\"c\"\"\",d"), vec!["a", "b,\"c\"", "d"]);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.csv");
        std::fs::write(&p, "scene,ms,thesis_ms\nx,1.0,\ny,1.1,1.0\nz,3,1\n").unwrap();
        let c = Compare {
            title: "T",
            csv: "t.csv",
            keys: &["scene"],
            pairs: &[("ms", "thesis_ms", "ms")],
            tolerance: Tolerance::Relative(25.0),
        };
        let (mut b, mut t) = (String::new(), Tally::default());
        compare_html(&mut b, &mut t, &p, &c).unwrap();
        // Row x has no thesis value and is left out.
        assert!(!b.contains("<td>x</td>") && b.contains("<td>y</td>"), "{b}");
        assert_eq!(t.0, [1, 0, 1]);
        assert!(
            b.contains("num ok\">+10.0%") && b.contains("num off\">+200.0%"),
            "{b}"
        );
        let mut b = String::new();
        compare_html(&mut b, &mut t, &dir.path().join("none.csv"), &c).unwrap();
        assert!(b.contains("missing"));
    }

    #[test]
    fn out_that_is_a_file_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("f");
        std::fs::write(&f, "x").unwrap();
        let e = prepare_out(&f).unwrap_err().to_string();
        assert!(e.contains("is a file, not a folder"), "{e}");
        assert!(prepare_out(&dir.path().join("a/b")).is_ok());
    }

    #[test]
    fn shell_quoting() {
        let l = shell_line(&strings(&["report", "proc:hairball?n=3&seed=2", "a b"]));
        assert_eq!(l, "report 'proc:hairball?n=3&seed=2' 'a b'");
    }
}
