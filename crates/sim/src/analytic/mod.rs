//! Analytic models of the builders the thesis compares MergeTree with, each reproducing a
//! published table:
//! - [`sort_traffic`]: DRAM traffic of LBVH construction by sorting strategy, \[P1\] Table 1
//!   and \[P2\] Table I;
//! - [`binned_sah_hw`]: the binned SAH hardware builder of Doyle et al., traffic and
//!   floating-point operations, \[P2\] §6.1 and Tables II and VI;
//! - [`gpu_hlbvh`]: the GPU HLBVH build with a radix sort, \[P2\] §4.2 and Table VI.

pub mod binned_sah_hw;
pub mod gpu_hlbvh;
pub mod sort_traffic;
