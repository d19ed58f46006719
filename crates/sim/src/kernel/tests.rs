//! Kernel-level tests: skipping equals stepping every cycle.
