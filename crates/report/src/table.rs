//! The one table type of the reports and its writers (Markdown, CSV, JSON, aligned text):
//! [`outfile::table`], re-exported here so that report code says `report::table`. It lives
//! in the leaf crate `outfile` so that the simulator's own report tables (`sim::system`,
//! `sim::rtunit`) use it too.

pub use outfile::table::*;
