//! Custom primitives: closest-hit and any-hit queries over a [`bvh::Bvh2`] whose leaves are
//! the caller's own primitives (spheres, curves, instances, ...), each tested by a callback.
//!
//! The tree is any `Bvh2` of the `bvh` crate, built over the primitives' boxes
//! (`bvh::SweepSahBuilder::default().build(&boxes)`); a leaf-table entry is a primitive
//! index into that box list, and that index is what the callback receives. The loop has
//! the shape of the triangle kernels' (nearer child first, the farther one pushed with its
//! entry distance, entries beyond the closest hit dropped when popped) and shares their
//! stack and culling distance, but it is its own loop: the shared `accel::traverse` is tied
//! to packed triangle leaves and hit records. It walks the tree's own nodes with `geom`'s
//! slab test ([`geom::ray_aabb`]) instead of a packed node copy, since what the packed
//! copies buy (4-wide triangle blocks in leaf order) does not apply to primitives the
//! library cannot see; per node visit it costs about what the `Bvh2` triangle kernel does
//! (both are bound by fetching nodes).
//!
//! # The callback's contract
//!
//! `intersect(prim, ray, t_max)` returns `Some((t, data))` when primitive `prim` is hit at a
//! distance `t` in `[ray.t_min, t_max]` (both ends included), `None` otherwise. `t_max` is
//! the closest hit so far (`ray.t_max` at first), so a callback may stop early beyond it.
//! A returned `t` outside that range, or NaN, is ignored. The closest hit follows the rule
//! of the triangle kernels ([`crate::Hit::beats`]): the smallest `t`, ties going to the
//! smaller primitive index; so, for a callback whose answer depends only on `prim` and
//! the ray, the result equals testing every primitive (brute force), whatever the tree.
//! An any-hit query stops at the first hit it accepts.
//!
//! # Example
//!
//! ```
//! use geom::{Aabb, Ray, Vec3};
//! use trace::custom::CustomAccel;
//! use trace::{RayStats, TraversalStack};
//!
//! // Unit spheres along the x axis.
//! let centers: Vec<Vec3> = (0..8).map(|i| Vec3::new(3.0 * i as f32, 0.0, 0.0)).collect();
//! let boxes: Vec<Aabb> = centers.iter().map(|&c| Aabb::new(c - Vec3::ONE, c + Vec3::ONE)).collect();
//! let accel = CustomAccel::new(bvh::SweepSahBuilder::default().build(&boxes)?)?;
//!
//! // The callback: a ray/sphere test returning the distance and the hit point.
//! let sphere = |prim: u32, ray: &Ray, t_max: f32| {
//!     let oc = ray.origin - centers[prim as usize];
//!     let (a, b, c) = (ray.dir.dot(ray.dir), oc.dot(ray.dir), oc.dot(oc) - 1.0);
//!     let disc = b * b - a * c;
//!     if disc < 0.0 {
//!         return None;
//!     }
//!     let t = (-b - disc.sqrt()) / a;
//!     (t >= ray.t_min && t <= t_max).then(|| (t, ray.at(t)))
//! };
//! let (mut stack, mut stats) = (TraversalStack::new(), RayStats::default());
//! let ray = Ray::new(Vec3::new(7.5, 0.0, 0.0), Vec3::X);
//! let hit = accel.closest_hit(&ray, &mut stack, &mut stats, sphere).unwrap();
//! assert_eq!((hit.prim, hit.t), (3, 0.5)); // the sphere at x = 9, entered at x = 8
//! assert_eq!(hit.data, Vec3::new(8.0, 0.0, 0.0));
//! assert!(accel.any_hit(&ray, &mut stack, &mut stats, sphere).is_some());
//! assert!(accel.any_hit(&Ray::new(ray.origin, Vec3::Y), &mut stack, &mut stats, sphere).is_none());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::accel::{cull_distance, StackEntry, TraversalStack};
use crate::bvh2_kernel::check_links;
use crate::observer::Query;
use crate::stats::RayStats;
use crate::TraceError;
use bvh::{Bvh2, ChildRef};
use geom::{Aabb, Ray, RayPrecomp};

/// Tests one primitive against a ray (see the module header for the contract). Every
/// closure `FnMut(u32, &Ray, f32) -> Option<(f32, D)>` is one.
pub trait Intersect {
    /// What a hit carries besides its distance (normal, uv, a nested hit, ...).
    type Data;

    /// The hit of primitive `prim` with `ray` at a distance in `[ray.t_min, t_max]`.
    fn intersect(&mut self, prim: u32, ray: &Ray, t_max: f32) -> Option<(f32, Self::Data)>;
}

impl<D, F> Intersect for F
where
    F: FnMut(u32, &Ray, f32) -> Option<(f32, D)>,
{
    type Data = D;

    #[inline(always)]
    fn intersect(&mut self, prim: u32, ray: &Ray, t_max: f32) -> Option<(f32, D)> {
        self(prim, ray, t_max)
    }
}

/// A hit on a custom primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CustomHit<D> {
    /// Distance along the ray, as the callback returned it.
    pub t: f32,
    /// The primitive index (an index into the box list the tree was built over).
    pub prim: u32,
    /// What the callback returned with the distance.
    pub data: D,
}

impl<D> CustomHit<D> {
    /// True when a hit at `t` on `prim` replaces `best` under the closest-hit rule of
    /// [`crate::Hit::beats`]: smaller `t`, or the same `t` and a smaller primitive index.
    #[inline(always)]
    fn beaten_by(best: Option<&Self>, t: f32, prim: u32) -> bool {
        match best {
            None => true,
            Some(b) => t < b.t || (t == b.t && prim < b.prim),
        }
    }
}

/// A `Bvh2` over custom primitives, checked once so that queries never index outside it
/// and always terminate.
#[derive(Clone, Debug)]
pub struct CustomAccel {
    tree: Bvh2,
}

impl CustomAccel {
    /// Prepares `tree` for queries. Fails when a child link points outside the tree or a
    /// leaf outside the leaf table, an inner child does not follow its parent (Arbor's
    /// trees are depth-first, which also rules out cycles), a node is linked twice, or
    /// leaves overlap (see the crate's "Trees from anywhere" section). Primitive ids are
    /// not checked (the tree does not know the primitive count): the callback receives
    /// whatever the leaf table holds.
    pub fn new(tree: Bvh2) -> Result<Self, TraceError> {
        check_links(
            tree.nodes.iter().flat_map(|n| n.children.iter()),
            2,
            tree.nodes.len(),
            tree.prim_indices.len(),
        )?;
        Ok(Self { tree })
    }

    /// The tree.
    pub fn tree(&self) -> &Bvh2 {
        &self.tree
    }

    /// The box of everything in the tree (empty for an empty tree).
    pub fn bounds(&self) -> Aabb {
        self.tree.bounds
    }

    /// Refits in place to `boxes`, the primitives' boxes after they moved (same list
    /// length and order as the tree was built over); the topology is kept.
    pub fn refit(&mut self, boxes: &[Aabb]) -> Result<(), TraceError> {
        bvh::refit_bvh2(&mut self.tree, boxes).map_err(|e| TraceError::Config(e.to_string()))
    }

    /// The closest hit along `ray`, primitives tested by `prims`. Adds the ray's counters
    /// to `stats` (`tri_tests` counts callback calls).
    pub fn closest_hit<I: Intersect>(
        &self,
        ray: &Ray,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        mut prims: I,
    ) -> Option<CustomHit<I::Data>> {
        self.trace(ray, Query::Closest, stack, stats, &mut prims)
    }

    /// The first hit found along `ray` (occlusion), primitives tested by `prims`.
    pub fn any_hit<I: Intersect>(
        &self,
        ray: &Ray,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        mut prims: I,
    ) -> Option<CustomHit<I::Data>> {
        self.trace(ray, Query::Any, stack, stats, &mut prims)
    }

    /// Traces `ray` for `query` (the loop behind [`CustomAccel::closest_hit`] and
    /// [`CustomAccel::any_hit`]). A ray with a non-finite origin or direction hits
    /// nothing.
    pub fn trace<I: Intersect>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        total: &mut RayStats,
        prims: &mut I,
    ) -> Option<CustomHit<I::Data>> {
        let mut ray_stats = RayStats {
            rays: 1,
            ..RayStats::default()
        };
        let stats = &mut ray_stats;
        stack.entries.clear();
        let mut best: Option<CustomHit<I::Data>> = None;
        let mut best_t = ray.t_max;
        // The slab test assumes a finite ray (as in the triangle kernels). A NaN range
        // accepts nothing: every comparison of the acceptance test below is false.
        let finite = geom::is_finite3(ray.origin) && geom::is_finite3(ray.dir);
        let pre = RayPrecomp::new(ray);
        let (nodes, entries) = (&self.tree.nodes, &self.tree.prim_indices);
        let mut cur = finite.then_some(ChildRef::inner(0));
        'walk: while let Some(c) = cur {
            if c.is_leaf() {
                stats.leaf_visits += 1;
                let first = c.index as usize;
                for &prim in entries.get(first..first + c.count as usize).unwrap_or(&[]) {
                    stats.tri_tests += 1;
                    let Some((t, data)) = prims.intersect(prim, ray, best_t) else {
                        continue;
                    };
                    // In range (a NaN `t` fails every comparison) and closer.
                    let accept = t >= ray.t_min
                        && t <= best_t
                        && CustomHit::beaten_by(best.as_ref(), t, prim);
                    if !accept {
                        continue;
                    }
                    best_t = t;
                    best = Some(CustomHit { t, prim, data });
                    if query == Query::Any {
                        break 'walk;
                    }
                }
            } else if let Some(node) = nodes.get(c.index as usize) {
                stats.node_visits += 1;
                let limit = cull_distance(best_t);
                let mut hit = [None; 2];
                for (k, h) in hit.iter_mut().enumerate() {
                    if !node.children[k].is_empty() {
                        stats.box_tests += 1;
                        *h = geom::ray_aabb(&pre, &node.child_aabb(k), ray.t_min, limit);
                    }
                }
                let [c0, c1] = node.children;
                let next = match hit {
                    [Some(d0), Some(d1)] => {
                        // Front to back: continue with the nearer child, push the other.
                        let (near, far, far_d) = if d1 < d0 { (c1, c0, d0) } else { (c0, c1, d1) };
                        stack.entries.push(StackEntry {
                            child: far,
                            dist: far_d,
                        });
                        stats.pushes += 1;
                        stats.max_stack_depth =
                            stats.max_stack_depth.max(stack.entries.len() as u64);
                        Some(near)
                    }
                    [Some(_), None] => Some(c0),
                    [None, Some(_)] => Some(c1),
                    [None, None] => None,
                };
                if next.is_some() {
                    cur = next;
                    continue;
                }
            }
            cur = stack.pop(true, best_t, stats, &mut ());
        }
        stats.hits += best.is_some() as u64;
        total.add(stats);
        best
    }
}
