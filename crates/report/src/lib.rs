//! Arbor's reports as a library: the writers every report (and every other user file of
//! the workspace) goes through, and the reports themselves as plain functions of typed
//! option structs, which the command line (`arbor report ...`, whose clap arguments
//! convert into these options), the HTML site and the Python package call alike.
//!
//! Modules, each using only those listed before it (no import cycles):
//!
//! - [`fs`]: the atomic file writer (temporary file beside the target, renamed over it,
//!   ordinary permissions), re-exported from the leaf crate `outfile` that `bvh` and
//!   `trace` use too;
//! - [`table`]: the one table type and its Markdown, CSV and JSON writers;
//! - [`svg`]: the bar-chart writer;
//! - [`progress`]: the [`Progress`](progress::Progress) trait through which a report
//!   shows progress and warnings (the command line implements it with its progress bars);
//! - [`scenes`]: the shared scenes folder, scene names and loading;
//! - one module per area, each a `run` function of its options: [`mergetree`] (\[P2\]
//!   Tables III, VI), [`cbvh`] (\[P3\] §5), [`rtunit`] (\[P4\] Tables 1, 2), [`energy`]
//!   (components, \[P2\] IV and VII, \[P4\] 1 and 2; uses `mergetree` and `rtunit`),
//!   [`system`] (\[P2\] §6.4), [`sensitivity`] (uses `system`), [`beyond`] (issue 18:
//!   the thesis's open problems against their baselines);
//! - [`html`]: the static site of every report.
//!
//! See `crates/report/README.md` for where each report lives.

pub mod fs;
pub mod progress;
pub mod svg;
pub mod table;

pub mod scenes;

pub mod cbvh;
pub mod mergetree;
pub mod rtunit;

pub mod energy;
pub mod system;

pub mod sensitivity;

pub mod beyond;

pub mod html;
