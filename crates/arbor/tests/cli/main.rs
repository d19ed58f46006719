//! Integration tests of the `arbor` command, run as a user would run it: one test binary
//! with a module per area (one link of the large `arbor` library instead of one per file,
//! which made most of the test command's compile time).

mod common;

mod args;
mod bench;
mod bench_compare;
mod bench_refit;
mod bench_trace;
mod build;
mod cbvh;
mod info;
mod render;
mod report_energy;
mod report_html;
mod report_mergetree;
mod sim_dram;
mod sim_mergetree;
mod sim_rtunit;
