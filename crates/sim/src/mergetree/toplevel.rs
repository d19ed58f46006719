//! The small toplevel binned SAH unit of \[P2\] §6.1 (HLBVH+SAH, \[P2\] §5.6).
//!
//! Its input is the high-level output of the emitter: one AABB per grid cell. The tree it
//! builds is the software binned SAH build over those boxes ([`bvh::BinnedSahBuilder`],
//! one cell per leaf), so the result is exactly the software HLBVH+SAH tree; the unit adds
//! the timing of \[P2\] §6.1's simplified serial builder: every sweep partitions and bins
//! its input at one AABB per cycle, then spends `sah_cycles_per_sweep` (32) cycles on the
//! SAH evaluation, and writes one 64-byte node.

use bvh::{BinnedSahBuilder, Bvh2, HighlevelRoot};

use super::config::{MergeTreeConfig, NODE_BYTES};
use super::machine::WriteBuffer;

/// The toplevel unit: the sweeps of the top build, in preorder, and their timing.
#[derive(Clone, Debug)]
pub struct TopUnit {
    /// The top tree over the cell roots.
    pub tree: Bvh2,
    /// Input AABBs of each sweep (one sweep per inner node), in build order.
    pub sweeps: Vec<u32>,
    sah_cycles: u32,
    cur: usize,
    left: u64,
    /// Busy this cycle.
    pub busy: bool,
    /// Cycles the unit has worked.
    pub busy_cycles: u64,
}

impl TopUnit {
    /// The unit for the cell roots `roots`.
    pub fn new(roots: &[HighlevelRoot], cfg: &MergeTreeConfig) -> Self {
        let boxes: Vec<_> = roots.iter().map(|r| r.aabb).collect();
        let tree = BinnedSahBuilder {
            bins: cfg.toplevel_bins as usize,
            max_leaf_size: 1,
            min_leaf_size: 1,
            threads: 1,
            ..Default::default()
        }
        .build(&boxes)
        .expect("cell root boxes are finite and non-empty");
        let sweeps = sweep_sizes(&tree);
        let left = sweeps
            .first()
            .map_or(0, |&s| s as u64 + cfg.sah_cycles_per_sweep as u64);
        Self {
            tree,
            sweeps,
            sah_cycles: cfg.sah_cycles_per_sweep,
            cur: 0,
            left,
            busy: false,
            busy_cycles: 0,
        }
    }

    /// True when every sweep has finished.
    pub fn done(&self) -> bool {
        self.cur == self.sweeps.len()
    }

    /// Cycles of the current sweep still to work before its node is written.
    pub fn left(&self) -> u64 {
        self.left
    }

    /// Works `k` cycles of the current sweep at once (`k` at most [`Self::left`]).
    pub fn spend(&mut self, k: u64) {
        debug_assert!(k <= self.left);
        self.left -= k;
        self.busy_cycles += k;
    }

    /// Ends the current sweep (its node was written): the next sweep starts.
    pub fn finish_sweep(&mut self) {
        debug_assert!(self.left == 0 && !self.done());
        self.cur += 1;
        if let Some(&s) = self.sweeps.get(self.cur) {
            self.left = s as u64 + self.sah_cycles as u64;
        }
    }

    /// One cycle; a finished sweep writes its node to `out`. Returns true on progress.
    pub fn tick(&mut self, out: &mut WriteBuffer) -> bool {
        self.busy = false;
        if self.done() {
            return false;
        }
        if self.left > 0 {
            self.left -= 1;
            self.busy = true;
            self.busy_cycles += 1;
            return true;
        }
        if !out.has_room(NODE_BYTES) {
            return false;
        }
        out.add(NODE_BYTES);
        self.cur += 1;
        if let Some(&s) = self.sweeps.get(self.cur) {
            self.left = s as u64 + self.sah_cycles as u64;
        }
        true
    }
}

/// Number of primitives under each inner node of `tree`, in preorder (node order).
fn sweep_sizes(tree: &Bvh2) -> Vec<u32> {
    let n = tree.nodes.len();
    let mut size = vec![0u32; n];
    // Children follow their parent in preorder: a backward pass sees children first.
    for i in (0..n).rev() {
        let node = &tree.nodes[i];
        size[i] = node
            .children
            .iter()
            .map(|c| {
                if c.is_leaf() {
                    c.count
                } else if c.is_inner() {
                    size[c.index as usize]
                } else {
                    0
                }
            })
            .sum();
    }
    size
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{Aabb, Vec3};

    #[test]
    fn sweeps_cover_the_tree() {
        let roots: Vec<HighlevelRoot> = (0..10)
            .map(|i| HighlevelRoot {
                aabb: Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 0.5)),
                root: bvh::EmitRef::Leaf { first: i, count: 1 },
                key: (i as u64, 0),
            })
            .collect();
        let cfg = MergeTreeConfig::p2();
        let mut t = TopUnit::new(&roots, &cfg);
        assert_eq!(t.sweeps.len(), t.tree.nodes.len());
        assert_eq!(t.sweeps[0], 10);
        let mut out = WriteBuffer::new_for_test(1 << 20);
        let mut cycles = 0u64;
        while !t.done() {
            t.tick(&mut out);
            cycles += 1;
        }
        let expect: u64 = t.sweeps.iter().map(|&s| s as u64 + 32 + 1).sum();
        assert_eq!(cycles, expect);
        assert_eq!(out.pending(), t.sweeps.len() as u64 * NODE_BYTES);
    }
}
