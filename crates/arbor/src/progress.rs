//! Progress bars that appear only when work takes more than a second, and only on a
//! terminal (indicatif draws nothing when stderr is not a TTY).

use indicatif::{ProgressBar, ProgressStyle};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// How long work may run before a progress bar appears.
const SHOW_AFTER: Duration = Duration::from_secs(1);

/// Where `--json` documents go: collected here instead of printed (Python's `arbor.run`).
pub type JsonSink = Arc<Mutex<Vec<serde_json::Value>>>;

/// User-interface settings shared by all subcommands.
pub struct Ui {
    /// No progress bars and no warnings.
    pub quiet: bool,
    /// Collect `--json` documents here instead of printing them (None: print to stdout).
    pub json: Option<JsonSink>,
    /// Print no result text on stdout (the caller reads the files the command writes;
    /// `arbor report html` runs the reports so). See [`say!`](crate::say).
    pub silent: bool,
}

/// `println!` unless `ui.silent`: the text results of the demo and the reports.
#[macro_export]
macro_rules! say {
    ($ui:expr, $($arg:tt)*) => {
        if !$ui.silent {
            println!($($arg)*);
        }
    };
}

impl Ui {
    /// Prints a command's `--json` document on stdout, or hands it to the caller that ran
    /// the command as a library ([`crate::run_capture`]).
    pub fn emit_json<T: serde::Serialize>(&self, doc: &T) -> anyhow::Result<()> {
        match &self.json {
            Some(sink) => {
                let v = serde_json::to_value(doc)?;
                sink.lock().unwrap_or_else(|p| p.into_inner()).push(v);
            }
            None => println!("{}", serde_json::to_string_pretty(doc)?),
        }
        Ok(())
    }

    /// Prints a warning to stderr unless quiet.
    pub fn warn(&self, msg: &str) {
        if !self.quiet {
            eprintln!("arbor: warning: {msg}");
        }
    }

    /// A progress reporter labelled `what`, counting in `unit` (`bytes` or a plain count).
    pub fn progress(&self, what: &str, unit: Unit) -> LazyBar {
        LazyBar(Arc::new(Inner {
            start: Instant::now(),
            bar: Mutex::new(None),
            what: what.to_string(),
            unit,
            hidden: self.quiet,
        }))
    }
}

/// What a progress bar counts.
#[derive(Clone, Copy)]
pub enum Unit {
    /// Bytes of input.
    Bytes,
    /// Items (frames, rays, ...).
    Items,
}

struct Inner {
    start: Instant,
    bar: Mutex<Option<ProgressBar>>,
    what: String,
    unit: Unit,
    hidden: bool,
}

/// A progress bar that is created on the first update after [`SHOW_AFTER`].
#[derive(Clone)]
pub struct LazyBar(Arc<Inner>);

impl LazyBar {
    /// Records that `done` of `total` are finished.
    pub fn update(&self, done: u64, total: u64) {
        let inner = &self.0;
        if inner.hidden || inner.start.elapsed() < SHOW_AFTER {
            return;
        }
        let mut slot = inner.bar.lock().unwrap_or_else(|p| p.into_inner());
        let bar = slot.get_or_insert_with(|| {
            let template = match inner.unit {
                Unit::Bytes => {
                    "{msg} [{bar:40}] {bytes}/{total_bytes} ({bytes_per_sec}, eta {eta})"
                }
                Unit::Items => "{msg} [{bar:40}] {pos}/{len} (eta {eta})",
            };
            let pb = ProgressBar::new(total);
            if let Ok(style) = ProgressStyle::with_template(template) {
                pb.set_style(style.progress_chars("=> "));
            }
            pb.set_message(inner.what.clone());
            pb
        });
        bar.set_length(total);
        bar.set_position(done);
    }

    /// A callback for the scene loaders.
    pub fn callback(&self) -> scene::ProgressFn {
        let me = self.clone();
        Arc::new(move |done, total| me.update(done, total))
    }

    /// Removes the bar, if one was shown.
    pub fn finish(&self) {
        if let Some(b) = self.0.bar.lock().unwrap_or_else(|p| p.into_inner()).take() {
            b.finish_and_clear();
        }
    }
}

/// A spinner for work that reports no progress of its own (sampling a frame, a build): it
/// appears if the work is still running after [`SHOW_AFTER`] and vanishes when dropped.
pub struct Spinner {
    done: Option<std::sync::mpsc::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Ui {
    /// Starts a delayed spinner labelled `what`.
    pub fn spinner(&self, what: &str) -> Spinner {
        if self.quiet {
            return Spinner {
                done: None,
                thread: None,
            };
        }
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let what = what.to_string();
        let thread = std::thread::spawn(move || {
            if rx.recv_timeout(SHOW_AFTER).is_ok() {
                return;
            }
            let pb = ProgressBar::new_spinner();
            if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
                pb.set_style(style);
            }
            pb.set_message(what);
            pb.enable_steady_tick(Duration::from_millis(120));
            // Returns on the message or when the sender is dropped.
            let _ = rx.recv();
            pb.finish_and_clear();
        });
        Spinner {
            done: Some(tx),
            thread: Some(thread),
        }
    }
}

impl Drop for Spinner {
    fn drop(&mut self) {
        if let Some(tx) = self.done.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The reports (the `report` crate) show progress and warnings through this.
impl report::progress::Progress for Ui {
    fn bar(&self, what: &str) -> Box<dyn report::progress::Bar> {
        Box::new(self.progress(what, Unit::Items))
    }
    fn spinner(&self, what: &str) -> Box<dyn Send> {
        Box::new(Ui::spinner(self, what))
    }
    fn warn(&self, msg: &str) {
        Ui::warn(self, msg)
    }
}

impl report::progress::Bar for LazyBar {
    fn update(&self, done: u64, total: u64) {
        LazyBar::update(self, done, total)
    }
    fn finish(&self) {
        LazyBar::finish(self)
    }
}
