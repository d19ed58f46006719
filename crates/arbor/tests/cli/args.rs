//! The command line itself: every subcommand's `--help` page, and argument errors.

use crate::common::{arbor, error};

/// Every subcommand's path (`["sim", "rtunit"]`), parents before children.
fn paths(cmd: &clap::Command, prefix: &[String], out: &mut Vec<Vec<String>>) {
    for sub in cmd.get_subcommands() {
        let mut p = prefix.to_vec();
        p.push(sub.get_name().to_string());
        out.push(p.clone());
        paths(sub, &p, out);
    }
}

/// `arbor PATH... --help`'s text, which must succeed.
fn help(path: &[String]) -> String {
    let mut args: Vec<&str> = path.iter().map(String::as_str).collect();
    args.push("--help");
    let out = arbor(&args);
    assert!(out.status.success(), "arbor {args:?} failed");
    assert!(out.stderr.is_empty(), "arbor {args:?} wrote to stderr");
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn every_help_page_lists_its_subcommands_without_markdown_escapes() {
    let root = arbor::Cli::command();
    let mut all = vec![vec![]];
    paths(&root, &[], &mut all);
    assert!(all.len() > 20, "only {} commands", all.len());
    for path in &all {
        let text = help(path);
        assert!(
            !text.contains("\\[") && !text.contains("\\]"),
            "arbor {path:?} --help shows a Markdown escape:\n{text}"
        );
        let mut cmd = &root;
        for name in path {
            cmd = cmd.find_subcommand(name).unwrap();
        }
        for sub in cmd.get_subcommands().filter(|s| s.get_name() != "help") {
            let name = sub.get_name();
            assert!(
                text.lines()
                    .any(|l| l.trim_start().starts_with(&format!("{name} "))),
                "arbor {path:?} --help does not list {name}:\n{text}"
            );
            // A group's one-line summary in its parent's list that names its members
            // names them all (`arbor sim mergetree`, `arbor sim rtunit`, `arbor sim
            // dram`).
            let grand: Vec<&str> = sub
                .get_subcommands()
                .map(|s| s.get_name())
                .filter(|&n| n != "help")
                .collect();
            let about = sub.get_about().map(|a| a.to_string()).unwrap_or_default();
            if about.contains(&format!("`arbor {name} ")) {
                for g in grand {
                    assert!(
                        about.contains(g),
                        "the summary of arbor {path:?} {name} does not name {g}: {about}"
                    );
                }
            }
        }
    }
}

#[test]
fn argument_errors_are_one_line_with_status_1() {
    let e = error(&["info", "--no-such-option"]);
    assert!(
        e.starts_with("arbor: error: ") && e.contains("--no-such-option"),
        "{e}"
    );
    let e = error(&["sim"]);
    assert!(
        e.contains("requires a subcommand") && e.contains("rtunit"),
        "{e}"
    );
    error(&[]);
    error(&["render"]);
    error(&["sim", "dram", "--bytes", "many"]);
    // --help and --version still print on stdout with status 0.
    let out = arbor(&["--version"]);
    assert!(out.status.success() && !out.stdout.is_empty());
}

#[test]
fn times_out_of_range_are_errors() {
    // A negative number is a value, not an option; then the range check refuses it.
    let cloth = "proc:cloth?n=100";
    let e = error(&["info", cloth, "--time", "-5"]);
    assert!(e.contains("--time -5 is out of range"), "{e}");
    let e = error(&["info", cloth, "--time=100"]);
    assert!(e.contains("--time 100 is out of range"), "{e}");
    // A static scene has time 0 only.
    let dir = tempfile::tempdir().unwrap();
    let tri = dir.path().join("tri.obj");
    std::fs::write(&tri, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let tri = tri.to_str().unwrap();
    let e = error(&["build", tri, "--builder", "lbvh", "--time", "1"]);
    assert!(
        e.contains("--time 1 is out of range: the scene is static"),
        "{e}"
    );
    crate::common::json("info", &[tri, "--time", "0"]);
    // The ends of the timeline are in range.
    let info = crate::common::json("info", &[cloth]);
    let d = info["duration_s"].as_f64().unwrap();
    assert!(d > 0.0);
    crate::common::json("info", &[cloth, "--time", &d.to_string()]);
    crate::common::json("info", &[cloth, "--time", "0"]);
}

/// Images, logs and statistics are ordinary files: mode 0644 under umask 022 (not the
/// 0600 of a temporary file).
#[cfg(unix)]
#[test]
fn outputs_have_ordinary_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let files = ["a.png", "a.log", "a.json", "h.png", "d.pfm"];
    let p = |f: &str| dir.path().join(f).to_str().unwrap().to_string();
    let script = format!(
        "umask 022; exec \"$0\" render 'proc:soup?n=50' --width 8 --height 8 --quiet \
         --out {} --log {} --stats {} --heatmap {} --depth {}",
        p(files[0]),
        p(files[1]),
        p(files[2]),
        p(files[3]),
        p(files[4])
    );
    let out = std::process::Command::new("sh")
        .args(["-c", &script, env!("CARGO_BIN_EXE_arbor")])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in files {
        let mode = std::fs::metadata(dir.path().join(f))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o644, "{f}: mode {:o}", mode & 0o777);
    }
}

/// The reports' `--scene-dir` default is found when `arbor` runs, not compiled in:
/// `$ARBOR_SCENE_DIR`, else the nearest `shared/scenes` above the current folder.
#[test]
fn scene_dir_default_is_found_at_run_time() {
    let default_of = |cmd: &mut std::process::Command| {
        let out = cmd.args(["report", "cbvh", "--help"]).output().unwrap();
        assert!(out.status.success());
        let text = String::from_utf8(out.stdout).unwrap();
        let line = text.lines().find(|l| l.contains("--scene-dir")).unwrap();
        let d = line.split("[default: ").nth(1).unwrap();
        d.trim_end().trim_end_matches(']').to_string()
    };
    let exe = env!("CARGO_BIN_EXE_arbor");
    let dir = tempfile::tempdir().unwrap();
    let d = default_of(
        std::process::Command::new(exe)
            .env("ARBOR_SCENE_DIR", "/no/such/scenes")
            .current_dir(dir.path()),
    );
    assert_eq!(d, "/no/such/scenes");
    // A checkout beside a shared folder: found from a folder inside the checkout.
    let inside = dir.path().join("repo").join("crates");
    let scenes = dir.path().join("shared").join("scenes");
    std::fs::create_dir_all(&inside).unwrap();
    std::fs::create_dir_all(&scenes).unwrap();
    let d = default_of(
        std::process::Command::new(exe)
            .env_remove("ARBOR_SCENE_DIR")
            .current_dir(&inside),
    );
    assert_eq!(std::path::Path::new(&d), scenes);
}

/// One spelling per concept: an option that several subcommands take has the same value
/// name in all of them (the two documented exceptions: `--out` names a file or a folder,
/// `--threads` is a list where a benchmark sweeps it), and no two subcommands spell one
/// concept two ways.
#[test]
fn every_option_is_spelled_one_way() {
    use std::collections::BTreeMap;
    fn walk(cmd: &clap::Command, path: &str, out: &mut BTreeMap<String, Vec<(String, String)>>) {
        for arg in cmd.get_arguments() {
            if let Some(long) = arg.get_long() {
                let value = arg
                    .get_value_names()
                    .map(|v| {
                        v.iter()
                            .map(|s| s.to_string())
                            .collect::<Vec<_>>()
                            .join(" ")
                    })
                    .unwrap_or_default();
                out.entry(long.to_string())
                    .or_default()
                    .push((path.to_string(), value));
            }
        }
        for sub in cmd.get_subcommands() {
            walk(sub, &format!("{path} {}", sub.get_name()), out);
        }
    }
    let mut opts = BTreeMap::new();
    walk(&arbor::Cli::command(), "arbor", &mut opts);
    assert!(opts.len() > 40, "only {} options", opts.len());
    for (long, uses) in &opts {
        let mut names: Vec<&str> = uses.iter().map(|(_, v)| v.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        let allowed: &[&str] = match long.as_str() {
            "out" => &["DIR", "FILE"],
            "threads" => &["N", "N,..."],
            _ => &[],
        };
        assert!(
            names.len() == 1 || names.iter().all(|n| allowed.contains(n)),
            "--{long} has value names {names:?} in {uses:?}"
        );
    }
    // Synonyms: at most one spelling of each of these concepts exists.
    for group in [
        &["out", "output", "out-dir"][..],
        &["scene-dir", "scenes-dir", "shared-scenes"],
        &["quiet", "silent"],
        &["sample", "sampling", "sample-rate"],
        &["fov", "field-of-view"],
        &["animated", "animated-scenes"],
        &["json", "format-json"],
        &["seed", "rng-seed"],
        &["runs", "rounds", "repeat"],
    ] {
        let present: Vec<&&str> = group.iter().filter(|g| opts.contains_key(**g)).collect();
        assert!(present.len() <= 1, "one concept, spellings {present:?}");
    }
    // `--animation` picks a glTF animation wherever it is spelled so.
    for (path, value) in &opts["animation"] {
        assert_eq!(value, "NAME|INDEX", "{path} --animation");
    }
}

/// The README stays short enough to read (issue 32: at most 12 KB).
#[test]
fn readme_is_at_most_12_kb() {
    let readme = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../README.md");
    let n = std::fs::metadata(&readme).unwrap().len();
    assert!(n <= 12_000, "README.md is {n} bytes");
}
