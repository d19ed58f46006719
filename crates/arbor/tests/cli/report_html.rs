//! Integration tests of `arbor report html`: the quick site's pages, that every link and
//! image resolves to a file of the site (nothing external), and, where Debian's
//! `chromium` is installed, that every page renders in headless Chromium with no broken
//! image and no console error; a screenshot of the index is kept.

use crate::common::{arbor, error};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The pages the site must have.
const PAGES: [&str; 9] = [
    "index.html",
    "builders.html",
    "mergetree.html",
    "cbvh.html",
    "tracing.html",
    "accelerator.html",
    "system.html",
    "sensitivity.html",
    "beyond.html",
];

/// The values of every `href="..."` and `src="..."` attribute in `html`.
fn references(html: &str) -> Vec<String> {
    let mut out = Vec::new();
    for attr in ["href=\"", "src=\""] {
        let mut rest = html;
        while let Some(i) = rest.find(attr) {
            rest = &rest[i + attr.len()..];
            if let Some(end) = rest.find('"') {
                out.push(rest[..end].replace("&amp;", "&"));
                rest = &rest[end..];
            }
        }
    }
    out
}

/// A headless Chromium to drive: `ARBOR_CHROMIUM`, else `chromium` or `chromium-browser`
/// on the PATH.
fn chromium() -> Option<String> {
    let candidates: Vec<String> = match std::env::var("ARBOR_CHROMIUM") {
        Ok(c) if !c.is_empty() => vec![c],
        _ => vec!["chromium".into(), "chromium-browser".into()],
    };
    candidates.into_iter().find(|c| {
        Command::new(c)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

fn chromium_cmd(bin: &str) -> Command {
    let mut c = Command::new(bin);
    c.args([
        "--headless",
        "--disable-gpu",
        "--no-sandbox",
        "--hide-scrollbars",
        "--enable-logging=stderr",
        "--v=0",
    ]);
    c
}

/// Says why a check was skipped, on the real stderr (the test harness captures
/// `eprintln!` of passing tests, and a skip must not pass silently).
fn skip(why: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr(), "{why}");
}

/// A script for the test's copy of a page (the site has none): it records resource load
/// failures and console errors, and after the load the images that did not decode, into
/// an attribute that `--dump-dom` shows.
const PROBE: &str = "<script>var E=[];addEventListener('error',function(e){var t=e.target;\
E.push(t&&(t.src||t.href)?'load failed: '+(t.src||t.href):'error: '+e.message)},true);\
var ce=console.error;console.error=function(){E.push('console.error: '+\
Array.prototype.join.call(arguments,' '));ce.apply(console,arguments)};\
addEventListener('load',function(){var b=[];for(var i of document.images){\
if(!i.complete||i.naturalWidth==0)b.push(i.getAttribute('src'))}\
document.documentElement.setAttribute('data-check',JSON.stringify({broken:b,errors:E}))});\
</script>";

/// Opens `page` of the site in headless Chromium through a probed copy beside it and
/// returns (images that did not load, errors), failing if the probe did not run.
fn render_check(bin: &str, site: &Path, page: &str) -> (Vec<String>, Vec<String>) {
    let html = std::fs::read_to_string(site.join(page)).unwrap();
    let probed = html.replacen("<head>", &format!("<head>\n{PROBE}"), 1);
    let copy = site.join(format!(".probe-{page}"));
    std::fs::write(&copy, probed).unwrap();
    let out = chromium_cmd(bin)
        .arg("--virtual-time-budget=5000")
        .arg("--dump-dom")
        .arg(format!("file://{}", copy.display()))
        .output()
        .expect("run chromium");
    std::fs::remove_file(&copy).unwrap();
    let dom = String::from_utf8_lossy(&out.stdout);
    let start = dom.find("data-check=\"").unwrap_or_else(|| {
        panic!(
            "{page}: the probe did not report; chromium said: {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let rest = &dom[start + "data-check=\"".len()..];
    let json = rest[..rest.find('"').unwrap()]
        .replace("&quot;", "\"")
        .replace("&amp;", "&");
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let list = |k: &str| -> Vec<String> {
        v[k].as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_str().unwrap_or_default().to_string())
            .collect()
    };
    let mut errors = list("errors");
    // Console messages Chromium logs at error level.
    errors.extend(
        String::from_utf8_lossy(&out.stderr)
            .lines()
            .filter(|l| l.contains(":CONSOLE") && l.contains(":ERROR:"))
            .map(String::from),
    );
    (list("broken"), errors)
}

#[test]
fn quick_site_is_complete_self_contained_and_renders() {
    let dir = tempfile::tempdir().unwrap();
    let site = dir.path().join("site");
    let out = arbor(&["report", "html", "--quick", "--out", site.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The reports' own text is not printed (the pages show it); progress on stderr, one
    // line per step, and the closing line.
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("report html: [1/9] arbor bench build"),
        "{err}"
    );
    assert!(err.contains("wrote") && err.contains("index.html"), "{err}");

    let mut pages: Vec<PathBuf> = std::fs::read_dir(&site)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "html"))
        .collect();
    pages.sort();
    for p in PAGES {
        assert!(site.join(p).is_file(), "{p} missing");
    }
    let mut images = 0;
    for page in &pages {
        let html = std::fs::read_to_string(page).unwrap();
        let name = page.file_name().unwrap().to_string_lossy().to_string();
        assert!(
            html.starts_with("<!DOCTYPE html>") && html.ends_with("</html>\n"),
            "{name}"
        );
        // How the numbers were produced.
        assert!(
            html.contains("Produced by arbor ") && html.contains(" threads), 20"),
            "{name}"
        );
        if name != "index.html" {
            assert!(html.contains("Command: <code>arbor "), "{name}");
            assert!(html.contains("href=\"index.html\""), "{name}");
        }
        assert!(
            !html.contains("<script"),
            "{name}: the site needs no scripts"
        );
        for r in references(&html) {
            assert!(
                !r.contains("://") && !r.starts_with('/') && !r.starts_with("data:"),
                "{name}: external or absolute reference {r}"
            );
            let target = site.join(&r);
            assert!(target.is_file(), "{name}: broken reference {r}");
            if r.ends_with(".png") || r.ends_with(".svg") {
                images += 1;
                assert!(
                    std::fs::metadata(&target).unwrap().len() > 0,
                    "{r} is empty"
                );
            }
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(page).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode & 0o644, 0o644, "{name}: mode {mode:o}");
        }
    }
    // Renders, heatmaps and plots of the demo and the reports.
    assert!(images >= 8, "only {images} images");
    let tracing = std::fs::read_to_string(site.join("tracing.html")).unwrap();
    assert!(tracing.contains("render-primary.png") && tracing.contains("heatmap-primary.png"));
    // The CBVH page compares with [P3] Table 1 whatever the scene: coloured differences.
    let cbvh = std::fs::read_to_string(site.join("cbvh.html")).unwrap();
    assert!(
        cbvh.contains("[P3] Table 1") && cbvh.contains("<td class=\"num ok\">"),
        "{cbvh}"
    );
    assert!(cbvh.contains("tolerance of 25% of the thesis's value"));
    let system = std::fs::read_to_string(site.join("system.html")).unwrap();
    assert!(system.contains("Table VIII") && system.contains("fig7-primary.svg"));

    let Some(bin) = chromium() else {
        skip(
            "SKIPPED the rendering check of `arbor report html`: no headless Chromium found \
             (install Debian's `chromium`: `apt-get install -y chromium`, or run scripts/setup \
             as root; or set ARBOR_CHROMIUM); links and images were checked without it",
        );
        return;
    };
    for page in PAGES {
        let (broken, errors) = render_check(&bin, &site, page);
        assert!(broken.is_empty(), "{page}: broken images {broken:?}");
        assert!(errors.is_empty(), "{page}: errors {errors:?}");
    }
    // A screenshot of the index, kept beside the test binary's temporary files.
    let shot_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("report-html");
    std::fs::create_dir_all(&shot_dir).unwrap();
    let shot = shot_dir.join("index.png");
    let _ = std::fs::remove_file(&shot);
    let out = chromium_cmd(&bin)
        .arg("--window-size=1280,1000")
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", site.join("index.html").display()))
        .output()
        .unwrap();
    assert!(
        shot.is_file(),
        "no screenshot: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&shot).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (1280, 1000));
    // Text on a white page: some dark pixels, mostly light ones.
    let px = &buf[..info.buffer_size()];
    let dark = px.iter().filter(|&&v| v < 100).count();
    assert!(
        dark > 1000 && dark < px.len() / 2,
        "{dark} dark of {}",
        px.len()
    );
    eprintln!("screenshot of the index: {}", shot.display());
}

#[test]
fn out_that_is_a_file_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("file");
    std::fs::write(&f, "x").unwrap();
    let e = error(&["report", "html", "--quick", "--out", f.to_str().unwrap()]);
    assert!(e.contains("is a file, not a folder"), "{e}");
    assert_eq!(std::fs::read_to_string(&f).unwrap(), "x");
}

#[test]
fn the_rendering_check_sees_broken_images_and_console_errors() {
    let Some(bin) = chromium() else {
        skip(
            "SKIPPED the check of the rendering check: no headless Chromium found (install \
             Debian's `chromium`, or set ARBOR_CHROMIUM)",
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("bad.html"),
        "<!DOCTYPE html>\n<html><head><title>x</title></head><body><img src=\"gone.png\">\
         <script>console.error('boom')</script></body></html>\n",
    )
    .unwrap();
    let (broken, errors) = render_check(&bin, dir.path(), "bad.html");
    assert_eq!(broken, vec!["gone.png".to_string()]);
    assert!(errors.iter().any(|e| e.contains("boom")), "{errors:?}");
    assert!(errors.iter().any(|e| e.contains("gone.png")), "{errors:?}");
}

#[test]
fn a_failing_command_is_shown_on_its_page_and_the_others_still_run() {
    // A scene folder whose Bunny is not a PLY file: the MergeTree page's command fails.
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    std::fs::create_dir(&scenes).unwrap();
    std::fs::write(scenes.join("bunny.ply"), "not a mesh\n").unwrap();
    let site = dir.path().join("site");
    let e = error(&[
        "report",
        "html",
        "--quick",
        "--quiet",
        "--scene-dir",
        scenes.to_str().unwrap(),
        "--out",
        site.to_str().unwrap(),
    ]);
    assert!(
        e.contains("1 of 9 commands failed (arbor report mergetree"),
        "{e}"
    );
    let page = std::fs::read_to_string(site.join("mergetree.html")).unwrap();
    assert!(page.contains("This command failed: cannot open"), "{page}");
    let index = std::fs::read_to_string(site.join("index.html")).unwrap();
    assert!(index.contains("1 command(s) failed"), "{index}");
    // The other pages were built.
    let cbvh = std::fs::read_to_string(site.join("cbvh.html")).unwrap();
    assert!(cbvh.contains("<td class=\"num ok\">"));
}
