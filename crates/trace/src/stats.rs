//! Traversal counters: what one ray, one bounce of an image, or a whole image cost.
//!
//! The thesis measures trees by tracing them: inner-node visits, ray/box and ray/triangle
//! tests ([P2] §6.2, [P3] §5.4, [P4] §3.2). Every kernel of this crate counts them in a
//! [`RayStats`]; counters of many rays are summed with [`RayStats::add`] (the stack
//! depth is the maximum, not the sum).

use serde::Serialize;

/// Counters of one ray, or sums over many rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RayStats {
    /// Rays traced.
    pub rays: u64,
    /// Rays that hit something (closest-hit: found a hit; any-hit: occluded).
    pub hits: u64,
    /// Inner nodes fetched and visited.
    pub node_visits: u64,
    /// Ray/box slab tests (one per non-empty child slot of each visited node).
    pub box_tests: u64,
    /// Ray/triangle tests.
    pub tri_tests: u64,
    /// Leaves visited (each visit tests the leaf's triangles).
    pub leaf_visits: u64,
    /// Traversal stack pushes.
    pub pushes: u64,
    /// Stack entries popped and traversed.
    pub pops: u64,
    /// Stack entries popped and skipped because their entry distance lies beyond the
    /// closest hit found since they were pushed (the distance stack of [P4] §3.1).
    pub culled_pops: u64,
    /// Deepest traversal stack seen (entries), a maximum over the rays summed.
    pub max_stack_depth: u64,
}

impl RayStats {
    /// Adds `o`'s counters to these (taking the maximum stack depth).
    #[inline]
    pub fn add(&mut self, o: &RayStats) {
        self.rays += o.rays;
        self.hits += o.hits;
        self.node_visits += o.node_visits;
        self.box_tests += o.box_tests;
        self.tri_tests += o.tri_tests;
        self.leaf_visits += o.leaf_visits;
        self.pushes += o.pushes;
        self.pops += o.pops;
        self.culled_pops += o.culled_pops;
        self.max_stack_depth = self.max_stack_depth.max(o.max_stack_depth);
    }

    /// `count / rays`, or 0 for no rays.
    pub fn per_ray(&self, count: u64) -> f64 {
        if self.rays == 0 {
            0.0
        } else {
            count as f64 / self.rays as f64
        }
    }
}

impl std::ops::AddAssign<&RayStats> for RayStats {
    fn add_assign(&mut self, o: &RayStats) {
        self.add(o);
    }
}

/// CPU time consumed so far by the calling thread, in seconds (Linux; elsewhere 0).
///
/// On a machine shared with other work, a thread's CPU time excludes the time it waited
/// for a core, so throughput per CPU second is far steadier than per wall second (cache
/// sharing with the other work still shows).
pub fn thread_cpu_seconds() -> f64 {
    #[cfg(target_os = "linux")]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid timespec for clock_gettime to fill.
        if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
        }
    }
    0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn add_sums_counts_and_takes_the_deepest_stack() {
        let a = RayStats {
            rays: 1,
            hits: 1,
            node_visits: 5,
            box_tests: 10,
            tri_tests: 3,
            leaf_visits: 2,
            pushes: 2,
            pops: 1,
            culled_pops: 1,
            max_stack_depth: 2,
        };
        let mut s = RayStats::default();
        s += &a;
        s += &RayStats {
            max_stack_depth: 7,
            ..a
        };
        assert_eq!(s.rays, 2);
        assert_eq!(s.box_tests, 20);
        assert_eq!(s.culled_pops, 2);
        assert_eq!(s.max_stack_depth, 7);
        assert_eq!(s.per_ray(s.node_visits), 5.0);
        assert_eq!(RayStats::default().per_ray(3), 0.0);
    }
}
