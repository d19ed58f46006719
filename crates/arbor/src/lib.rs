//! The `arbor` command as a library: the command line's parser and subcommands, so that
//! the binary and the Python package (`python/`) run the same code, take the same options
//! and print (or return) the same `--json` documents (see `docs/cli-json.md`). Every
//! subcommand is a thin layer over the library crates.

pub mod alloc;
pub mod cmd;
pub mod progress;

/// The binary installs the counting allocator (`main.rs`); the library's own tests do too,
/// so that `alloc`'s tests measure. Other users of the library keep their allocator.
#[cfg(test)]
#[global_allocator]
static TEST_ALLOC: alloc::Counting = alloc::Counting;

use clap::{CommandFactory, FromArgMatches, Subcommand};
use std::sync::{Arc, Mutex};

/// Arbor: BVH construction, compression and traversal for animated ray tracing, and
/// cycle-level models of the hardware that does it.
#[derive(clap::Parser)]
#[command(name = "arbor", version, about, long_about = None)]
pub struct Cli {
    /// Hide progress bars and warnings.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Print a scene's triangle count, bounds, frames and load time.
    Info(cmd::info::InfoArgs),
    /// Run the main job on the bundled default scene (or another) and summarize it.
    Demo(cmd::demo::DemoArgs),
    /// Build a BVH over a scene with a named builder, validate it, report SAH and timings.
    Build(cmd::build::BuildArgs),
    /// Run a cycle-level hardware model (`arbor sim mergetree`, `arbor sim rtunit`, `arbor
    /// sim dram`).
    Sim(cmd::sim::SimArgs),
    /// Compress a scene's LBVH into a CBVH (or refit one) and report backtracking, traffic
    /// and quality (\[P3\]).
    Cbvh(cmd::cbvh::CbvhArgs),
    /// Trace an image through a BVH (primary, diffuse or shadow rays); write the image,
    /// depth buffer, heatmap, statistics and traversal log.
    Render(Box<cmd::render::RenderArgs>),
    /// Check a traversal log and print its totals.
    LogInfo(cmd::log_info::LogInfoArgs),
    /// Regenerate a table or figure of the thesis (CSV, Markdown, SVG).
    Report(cmd::report::ReportArgs),
    /// Benchmark Arbor against peer libraries in one run (`arbor bench build`, `arbor bench
    /// trace`, `arbor bench refit`) and compare two recorded runs (`arbor bench compare`).
    Bench(cmd::bench::BenchArgs),
}

impl Cli {
    /// The command line's parser: the derived one with the doc comments' Markdown escapes
    /// (`\[P2\]`, which rustdoc needs) removed from every help text, and negative numbers
    /// accepted as option values (`--time -5`) in every subcommand.
    pub fn command() -> clap::Command {
        polish(<Cli as CommandFactory>::command())
    }

    /// Parses a command line (`argv` with the program name first) with [`Cli::command`].
    pub fn try_parse_from<I, T>(argv: I) -> Result<Cli, clap::Error>
    where
        I: IntoIterator<Item = T>,
        T: Into<std::ffi::OsString> + Clone,
    {
        let mut matches = Self::command().try_get_matches_from(argv)?;
        <Cli as FromArgMatches>::from_arg_matches_mut(&mut matches)
    }

    /// Runs the parsed command with `ui`.
    pub fn run(self, ui: &progress::Ui) -> anyhow::Result<()> {
        let ui = progress::Ui {
            quiet: ui.quiet || self.quiet,
            json: ui.json.clone(),
            silent: ui.silent,
        };
        let ui = &ui;
        match self.command {
            Command::Info(a) => cmd::info::run(&a, ui),
            Command::Demo(a) => cmd::demo::run(&a, ui),
            Command::Build(a) => cmd::build::run(&a, ui),
            Command::Sim(a) => cmd::sim::run(&a, ui),
            Command::Cbvh(a) => cmd::cbvh::run(&a, ui),
            Command::Report(a) => cmd::report::run(&a, ui),
            Command::Render(a) => cmd::render::run(&a, ui),
            Command::LogInfo(a) => cmd::log_info::run(&a, ui),
            Command::Bench(a) => cmd::bench::run(&a, ui),
        }
    }
}

/// `cmd` and its subcommands, recursively, with help texts free of Markdown escapes,
/// negative numbers accepted as values, and a missing subcommand an ordinary error (one
/// line, like every other) instead of a help page.
fn polish(cmd: clap::Command) -> clap::Command {
    fn plain(s: &clap::builder::StyledStr) -> String {
        s.to_string().replace("\\[", "[").replace("\\]", "]")
    }
    let mut cmd = cmd
        .allow_negative_numbers(true)
        .arg_required_else_help(false);
    if let Some(a) = cmd.get_about().map(plain) {
        cmd = cmd.about(a);
    }
    if let Some(a) = cmd.get_long_about().map(plain) {
        cmd = cmd.long_about(a);
    }
    cmd.mut_args(|mut arg| {
        if let Some(h) = arg.get_help().map(plain) {
            arg = arg.help(h);
        }
        if let Some(h) = arg.get_long_help().map(plain) {
            arg = arg.long_help(h);
        }
        arg
    })
    .mut_subcommands(polish)
}

/// A command-line parsing error as one line, without clap's `error: ` prefix: its message
/// and detail lines, without the usage and help hints that follow.
pub fn arg_error_line(e: &clap::Error) -> String {
    // clap's message: "error: ...", indented detail lines, a blank line, then usage.
    let text = e.to_string();
    let msg: Vec<&str> = text
        .lines()
        .map(str::trim)
        .take_while(|l| !l.is_empty() && !l.starts_with("Usage:"))
        .collect();
    let line = msg.join(" ");
    line.strip_prefix("error: ").unwrap_or(&line).to_string()
}

/// An error as the command line prints it: one line, the error and its causes, outermost
/// first, skipping a cause whose text the line already holds (library errors often include
/// their source).
pub fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain().map(|c| c.to_string()) {
        if line.contains(&cause) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&cause);
    }
    line.replace('\n', " ")
}

/// Runs one command line (`args` without the program name, e.g. `["sim", "mergetree",
/// "bunny.ply", "--json"]`) quietly and returns the JSON documents it printed, in order; a
/// bad option or a failure is the command line's one-line error message. What Python's
/// `arbor.run` calls.
pub fn run_capture<S: AsRef<str>>(args: &[S]) -> Result<Vec<serde_json::Value>, String> {
    let cli = parse(args)?;
    let sink = Arc::new(Mutex::new(Vec::new()));
    let ui = progress::Ui {
        quiet: true,
        json: Some(sink.clone()),
        silent: false,
    };
    cli.run(&ui).map_err(|e| one_line(&e))?;
    let docs = std::mem::take(&mut *sink.lock().unwrap_or_else(|p| p.into_inner()));
    Ok(docs)
}

/// Parses a command line (without the program name) the way the binary does; a bad option
/// is clap's message, first line, without its `error: ` prefix.
fn parse<S: AsRef<str>>(args: &[S]) -> Result<Cli, String> {
    let argv = std::iter::once("arbor").chain(args.iter().map(|s| s.as_ref()));
    Cli::try_parse_from(argv).map_err(|e| arg_error_line(&e))
}

/// Checks a command line without running it: the parser, and for `arbor sim ...` the
/// preset, `--set` keys and values and memory system, with no scene loaded. What a sweep
/// runs over every point before it starts, so that a bad option fails at once.
pub fn check_args<S: AsRef<str>>(args: &[S]) -> Result<(), String> {
    match parse(args)?.command {
        Command::Sim(a) => cmd::sim::check(&a).map_err(|e| one_line(&e)),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_args_rejects_bad_options_without_a_scene() {
        // The scene does not exist: check_args never opens it.
        let ok = ["sim", "mergetree", "no-such.ply", "--set", "m=2048"];
        assert_eq!(check_args(&ok), Ok(()));
        let e = check_args(&["sim", "mergetree", "x.ply", "--set", "bogus=1"]).unwrap_err();
        assert!(e.contains("bogus"), "{e}");
        let e = check_args(&["sim", "mergetree", "x.ply", "--dram", "ddr9"]).unwrap_err();
        assert!(e.contains("ddr9"), "{e}");
        let e = check_args(&["sim", "rtunit", "x.ply", "--rays", "sideways"]).unwrap_err();
        assert_eq!(e, "unknown --rays 'sideways' (known: primary, diffuse)");
        let e = check_args(&["sim", "dram", "--bytes", "0"]).unwrap_err();
        assert!(e.starts_with("--bytes must be"), "{e}");
        let e = check_args(&["sim", "mergetree"]).unwrap_err();
        assert!(e.contains("required") && e.contains("<SCENE>"), "{e}");
    }

    #[test]
    fn run_capture_returns_the_json_documents() {
        let docs = run_capture(&["sim", "dram", "--bytes", "4096", "--json"]).unwrap();
        assert_eq!(docs.len(), 1);
        assert_eq!(docs[0]["schema"], "arbor.sim.dram.v1");
        let e = run_capture(&["info", "no-such-file.ply"]).unwrap_err();
        assert!(e.contains("no-such-file.ply"), "{e}");
        assert!(!e.contains('\n'));
    }
}
