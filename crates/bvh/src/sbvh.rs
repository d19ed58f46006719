//! Spatial-split BVH (SBVH; Stich, Friedrich and Dietrich 2009, "Spatial Splits in Bounding
//! Volume Hierarchies"): a top-down SAH builder that may, besides partitioning its
//! primitives by centroid (an *object* split), cut the node's box with a plane and send a
//! triangle that straddles it to both children, each with the box of its part on that
//! side (a *spatial* split). Long or large triangles then stop inflating every node they
//! pass through, which is what object partitioning cannot avoid in architectural scenes.
//! Beyond the thesis: [P2] and [P4] build without reference splitting (issues 33 and 34
//! ask for spatial splits as a quality option).
//!
//! The tree is a [`Bvh2`] whose leaf table may name a triangle more than once (once per
//! part); [`validate_spatial`](crate::validate_spatial) checks it (every triangle named at
//! least once, each leaf box meeting the boxes of the triangles it names). It traces
//! exactly like any other tree: a part's box is made conservative (below), so every point
//! of a triangle lies in the box of at least one leaf that names it.
//!
//! Per node, as in the paper:
//! 1. the best object split, by the binned SAH builder's own search over the references'
//!    boxes (`bins` bins per axis with its refinement of large nodes; exact over sorted
//!    centroids in nodes of at most `bins` references);
//! 2. if the two sides of that split overlap by more than `alpha` times the scene box's
//!    area (the paper's λ / SA(root) test), the best spatial split: `spatial_bins` equal
//!    slabs of the node box per axis (at most one per reference, at least 4: in small
//!    nodes every triangle spans most slabs, and cutting it into each took 80% of the
//!    build time; on Crytek Sponza and Bunny the SAH was the same to 0.1%); each reference is clipped into every slab it spans
//!    (its box in a slab is the box of the triangle's part there, within the reference's
//!    box), counting an *entry* in its first slab and an *exit* in its last; the plane
//!    before slab `i` has the entries of slabs `..i` on the left and the exits of `i..`
//!    on the right;
//! 3. the cheaper of the two (a leaf if it is cheaper still and the node fits in
//!    `max_leaf_size`); a spatial split moves a straddling reference wholly to one side
//!    instead of cutting it when that is cheaper ("reference unsplitting", §4.3 of the
//!    paper).
//!
//! **Reference budget** (a parameter the paper leaves open: it bounds growth only through
//! α): the tree holds at most about `(1 + max_growth)` references per triangle. Each node
//! gets a budget, the references its subtree may hold; a spatial split is taken only if
//! its two sides fit in it, and the slack is shared between the children in proportion to
//! their references, so the tree does not depend on the thread count.
//!
//! **Conservative parts.** Cutting a triangle at plane `x = p` takes its vertices on each
//! side and the points where its edges cross the plane. A crossing point's other two
//! coordinates are computed in `f32` (`a + (b - a) t`) and widened by a bound on that
//! rounding (`16 u (|a| + |b|)`: five roundings of at most `u` relative to a value of at
//! most `|a| + |b|`), its coordinate on the split axis set to `p` exactly; the part's box
//! is then cut to the reference's box and to its side of the plane. So a part's box
//! contains every point of the triangle on that side within the reference's box.

use crate::binned_sah::{self, sah, BinnedSahBuilder, MAX_BINS};
use crate::bvh2::Bvh2;
use crate::error::{in_pool, BuildError};
use crate::layout::preorder;
use crate::node::{ChildRef, Node};
use crate::sah::SahParams;
use crate::split::{left_pass, right_pass, Counted};
use crate::{MAX_SAH_DEPTH, PARALLEL_MIN_PRIMS};
use geom::{Aabb, Triangle, Vec3};
use rayon::prelude::*;

/// Configuration of the spatial-split builder.
#[derive(Clone, Debug, PartialEq)]
pub struct SbvhBuilder {
    /// Bins per axis of the object split search (2..=64).
    pub bins: usize,
    /// Slabs per axis of the spatial split search (2..=64; a node of `n < spatial_bins`
    /// references uses `max(n, 4)`).
    pub spatial_bins: usize,
    /// Spatial splits are tried only where the object split's two sides overlap by more
    /// than `alpha` times the scene box's half area (the paper's α; 1e-5 there), and in
    /// nodes whose centroids all coincide (no object split exists). 0 tries them
    /// everywhere; values >= 1 only in those nodes (`max_growth` 0 turns them off).
    pub alpha: f32,
    /// At most about `(1 + max_growth)` references per triangle in the whole tree.
    pub max_growth: f32,
    /// Largest leaf; nodes above it are always split (>= 1).
    pub max_leaf_size: u32,
    /// SAH weights used to choose splits (the thesis's by default).
    pub sah: SahParams,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
}

impl Default for SbvhBuilder {
    fn default() -> Self {
        Self {
            bins: 16,
            spatial_bins: 32,
            alpha: 1e-5,
            max_growth: 1.0,
            max_leaf_size: 8,
            sah: SahParams::THESIS,
            threads: 0,
        }
    }
}

/// A reference: a triangle (by index) and the box of its part in this node.
#[derive(Clone, Copy, Debug)]
struct Ref {
    bbox: Aabb,
    prim: u32,
}

impl Ref {
    #[inline(always)]
    fn centroid(&self) -> Vec3 {
        (self.bbox.min + self.bbox.max) * 0.5
    }
}

/// A built subtree, before layout.
enum Sub {
    Leaf(Vec<u32>),
    Inner(Box<[(Aabb, Sub); 2]>),
}

struct Ctx<'a> {
    cfg: &'a SbvhBuilder,
    /// The binned builder whose object split search the object splits use.
    binned: BinnedSahBuilder,
    tris: &'a [Triangle],
    /// `alpha` times the scene box's half area.
    overlap_limit: f32,
}

/// How a chosen split partitions the node.
#[derive(Clone, Copy, Debug)]
enum Kind {
    /// The binned builder's object split: the references of its mask go left.
    Object,
    /// References wholly below `plane` go left, wholly above it right; the others are cut
    /// or moved (unsplitting). `bin`: the first slab on the right.
    Spatial { plane: f32, bin: usize },
}

#[derive(Clone, Copy, Debug)]
struct Split {
    cost: f32,
    axis: usize,
    kind: Kind,
    left: Aabb,
    right: Aabb,
    left_count: u32,
    right_count: u32,
}

impl SbvhBuilder {
    /// Builds a tree over `tris`. Errors on a bad configuration, on more than
    /// [`crate::MAX_PRIMITIVES`] triangles and on non-finite vertices.
    pub fn build(&self, tris: &[Triangle]) -> Result<Bvh2, BuildError> {
        let bad = |m: String| Err(BuildError::InvalidConfig(m));
        if self.max_leaf_size == 0 {
            return bad("SBVH needs max_leaf_size >= 1".into());
        }
        for (what, n) in [("bins", self.bins), ("spatial_bins", self.spatial_bins)] {
            if !(2..=MAX_BINS).contains(&n) {
                return bad(format!("SBVH needs 2..={MAX_BINS} {what}, got {n}"));
            }
        }
        if !(self.alpha.is_finite() && self.alpha >= 0.0) {
            return bad(format!(
                "SBVH alpha must be finite and >= 0, got {}",
                self.alpha
            ));
        }
        if !(self.max_growth.is_finite() && self.max_growth >= 0.0) {
            return bad(format!(
                "SBVH max_growth must be finite and >= 0, got {}",
                self.max_growth
            ));
        }
        self.sah.check("SBVH")?;
        // A NaN vertex can vanish from a box (`min`/`max` skip NaN), so check the vertices.
        if let Some(index) = tris.iter().position(|t| !t.v.iter().all(|v| v.is_finite())) {
            return Err(BuildError::NonFinite { index });
        }
        let boxes = crate::triangle_aabbs(tris);
        crate::error::check_input(&boxes)?;
        if tris.is_empty() {
            return Ok(Bvh2::empty());
        }
        in_pool(self.threads, || self.build_checked(tris, boxes))
    }

    fn build_checked(&self, tris: &[Triangle], boxes: Vec<Aabb>) -> Bvh2 {
        let refs: Vec<Ref> = boxes
            .into_iter()
            .enumerate()
            .map(|(i, bbox)| Ref {
                bbox,
                prim: i as u32,
            })
            .collect();
        let bounds = refs.iter().fold(Aabb::EMPTY, |b, r| b.union(r.bbox));
        let ctx = Ctx {
            cfg: self,
            binned: BinnedSahBuilder {
                bins: self.bins,
                max_leaf_size: self.max_leaf_size,
                sah: self.sah,
                ..Default::default()
            },
            tris,
            overlap_limit: self.alpha * bounds.half_area(),
        };
        let budget = ((1.0 + self.max_growth as f64) * refs.len() as f64) as usize;
        let root = build_rec(&ctx, refs, bounds, 0, budget.max(tris.len()));
        let mut prim_indices = Vec::new();
        let (root_ref, nodes) = match &root {
            Sub::Leaf(p) => {
                prim_indices.extend_from_slice(p);
                (ChildRef::leaf(0, p.len() as u32), Vec::new())
            }
            Sub::Inner(_) => {
                let mut nodes: Vec<Node> = Vec::new();
                preorder(&root, &mut nodes, |s, out, kids| {
                    let Sub::Inner(k) = s else {
                        unreachable!("only inner subtrees are laid out")
                    };
                    let mut c = [ChildRef::EMPTY; 2];
                    for (slot, (_, sub)) in k.iter().enumerate() {
                        match sub {
                            Sub::Leaf(p) => {
                                c[slot] = ChildRef::leaf(prim_indices.len() as u32, p.len() as u32);
                                prim_indices.extend_from_slice(p);
                            }
                            Sub::Inner(_) => kids.push((slot, sub)),
                        }
                    }
                    out.push(Node::new(&k[0].0, c[0], &k[1].0, c[1]));
                });
                (ChildRef::inner(0), nodes)
            }
        };
        Bvh2::from_root(root_ref, bounds, nodes, prim_indices)
    }
}

/// Builds the subtree over `refs` (box `bounds`), which may hold at most `budget`
/// references (at least `refs.len()`).
fn build_rec(ctx: &Ctx, refs: Vec<Ref>, bounds: Aabb, depth: u32, budget: usize) -> Sub {
    let n = refs.len();
    let cfg = ctx.cfg;
    let fits = n <= cfg.max_leaf_size as usize;
    if n <= 1 {
        return leaf(&refs);
    }
    let mut object_mask = None;
    let best = if depth >= MAX_SAH_DEPTH {
        None
    } else {
        let (object, mask) = object_split(ctx, &refs, &bounds).unzip();
        object_mask = mask;
        let try_spatial = budget > n
            && match &object {
                Some(o) => overlap_area(&o.left, &o.right) > ctx.overlap_limit,
                None => true,
            };
        let spatial = if try_spatial {
            spatial_split(ctx, &refs, &bounds)
                .filter(|s| (s.left_count + s.right_count) as usize <= budget)
        } else {
            None
        };
        match (object, spatial) {
            (Some(o), Some(s)) => Some(if s.cost < o.cost { s } else { o }),
            (o, s) => o.or(s),
        }
    };
    let p = &cfg.sah;
    let leaf_cost = bounds.half_area() * (p.c_leaf + p.c_tri * n as f32);
    match &best {
        Some(s) if fits && leaf_cost <= s.cost => return leaf(&refs),
        None if fits => return leaf(&refs),
        _ => {}
    }
    let (l, r) = match best.and_then(|s| partition(ctx, &refs, &s, object_mask.as_deref())) {
        Some(lr) => lr,
        None => median_split(refs),
    };
    let boxed = |v: &[Ref]| v.iter().fold(Aabb::EMPTY, |b, r| b.union(r.bbox));
    let (lb, rb) = (boxed(&l), boxed(&r));
    // The slack of the budget, shared in proportion to the children's references.
    let (nl, nr) = (l.len(), r.len());
    let slack = budget.saturating_sub(nl + nr);
    let lslack = (slack as u128 * nl as u128 / (nl + nr) as u128) as usize;
    let (lbud, rbud) = (nl + lslack, nr + (slack - lslack));
    let (ls, rs) = if n >= PARALLEL_MIN_PRIMS && rayon::current_num_threads() > 1 {
        rayon::join(
            || build_rec(ctx, l, lb, depth + 1, lbud),
            || build_rec(ctx, r, rb, depth + 1, rbud),
        )
    } else {
        (
            build_rec(ctx, l, lb, depth + 1, lbud),
            build_rec(ctx, r, rb, depth + 1, rbud),
        )
    };
    Sub::Inner(Box::new([(lb, ls), (rb, rs)]))
}

fn leaf(refs: &[Ref]) -> Sub {
    Sub::Leaf(refs.iter().map(|r| r.prim).collect())
}

/// Half area of the overlap of two boxes (0 if they do not overlap).
fn overlap_area(a: &Aabb, b: &Aabb) -> f32 {
    let o = a.intersection(*b);
    if o.is_empty() {
        0.0
    } else {
        o.half_area()
    }
}

/// Keeps `cand` in `best` if it is cheaper (finite costs only; ties keep the first).
fn offer(best: &mut Option<Split>, cand: Split) {
    if cand.cost.is_finite() && best.as_ref().is_none_or(|b| cand.cost < b.cost) {
        *best = Some(cand);
    }
}

/// Per-axis bins of the spatial split search: a box per bin, the references entering in
/// it (`a`) and those leaving in it (`b`).
#[derive(Clone)]
struct AxisBins {
    boxes: [[Aabb; MAX_BINS]; 3],
    a: [[u32; MAX_BINS]; 3],
    b: [[u32; MAX_BINS]; 3],
}

impl AxisBins {
    fn new() -> Self {
        Self {
            boxes: [[Aabb::EMPTY; MAX_BINS]; 3],
            a: [[0; MAX_BINS]; 3],
            b: [[0; MAX_BINS]; 3],
        }
    }

    /// The union of two bin sets (exact, so the order of merging does not matter).
    fn merge(mut self, o: Self) -> Self {
        for axis in 0..3 {
            for k in 0..MAX_BINS {
                self.boxes[axis][k] = self.boxes[axis][k].union(o.boxes[axis][k]);
                self.a[axis][k] += o.a[axis][k];
                self.b[axis][k] += o.b[axis][k];
            }
        }
        self
    }

    /// The bins of `refs`, each added by `add`: in parallel chunks in large nodes (the
    /// top of the tree, which would otherwise run on one thread).
    fn fill(refs: &[Ref], add: impl Fn(&mut AxisBins, &Ref) + Sync) -> Box<AxisBins> {
        let chunk = |c: &[Ref]| {
            let mut bins = Box::new(AxisBins::new());
            for r in c {
                add(&mut bins, r);
            }
            bins
        };
        if refs.len() >= PARALLEL_MIN_PRIMS && rayon::current_num_threads() > 1 {
            refs.par_chunks(PARALLEL_MIN_PRIMS / 2)
                .map(chunk)
                .reduce(|| Box::new(AxisBins::new()), |x, y| Box::new(x.merge(*y)))
        } else {
            chunk(refs)
        }
    }

    /// Sweeps the `nb` bins of `axis` (left side counted by `a`, right side by `b`) and
    /// offers each boundary that leaves references on both sides to `best`, as `kind(k)`.
    #[allow(clippy::too_many_arguments)]
    fn sweep_axis(
        &self,
        axis: usize,
        nb: usize,
        p: &SahParams,
        base: f32,
        kind: impl Fn(usize) -> Kind,
        best: &mut Option<Split>,
    ) {
        let mut right_area = [0f32; MAX_BINS];
        let mut right_count = [0u32; MAX_BINS];
        let right = &mut Counted(&mut right_area, &mut right_count);
        let boxes = &self.boxes[axis];
        right_pass(nb, |k| (boxes[k], self.b[axis][k]), right);
        let before = best.as_ref().map(|s| s.cost);
        left_pass(
            nb,
            |k| (boxes[k], self.a[axis][k]),
            &*right,
            |k, left, lc, ra, rc| {
                if lc == 0 || rc == 0 {
                    return;
                }
                let cost = sah(p, base, left.half_area(), lc, ra, rc);
                offer(
                    best,
                    Split {
                        cost,
                        axis,
                        kind: kind(k),
                        left: *left,
                        right: Aabb::EMPTY,
                        left_count: lc,
                        right_count: rc,
                    },
                );
            },
        );
        // The right box of a boundary of this axis that became the best.
        if let Some(s) = best
            .as_mut()
            .filter(|s| s.axis == axis && Some(s.cost) != before)
        {
            let Kind::Spatial { bin: k, .. } = s.kind else {
                return;
            };
            s.right = boxes[k..nb].iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
        }
    }
}

/// The best object split: the binned builder's own search
/// ([`binned_sah::object_split_of`]: exact over sorted centroids in small nodes, binned
/// with its refinement of large nodes), over the references' boxes; with the mask of
/// the references that go left. `None` when all centroids coincide.
fn object_split(ctx: &Ctx, refs: &[Ref], bounds: &Aabb) -> Option<(Split, Vec<bool>)> {
    let boxes: Vec<Aabb> = refs.iter().map(|r| r.bbox).collect();
    let (cost, [lb, rb], left) = binned_sah::object_split_of(&ctx.binned, &boxes, bounds)?;
    let lc = left.iter().filter(|&&l| l).count() as u32;
    let rc = left.len() as u32 - lc;
    let s = Split {
        cost,
        axis: 0,
        kind: Kind::Object,
        left: lb,
        right: rb,
        left_count: lc,
        right_count: rc,
    };
    Some((s, left))
}

/// The bin of coordinate `x` among `nb` bins starting at `min`, `scale` bins per unit.
#[inline(always)]
fn bin_of(x: f32, min: f32, scale: f32, nb: usize) -> usize {
    (((x - min) * scale) as usize).min(nb - 1)
}

/// The best spatial split of the node box `bounds`, or `None` if no plane leaves
/// references on both sides.
fn spatial_split(ctx: &Ctx, refs: &[Ref], bounds: &Aabb) -> Option<Split> {
    // Small nodes get fewer slabs: their triangles span most of the node box, so each
    // would be cut into every slab (most of the build's time), for no SAH gain measured
    // on the shared scenes (module notes).
    let nb = ctx.cfg.spatial_bins.min(refs.len().max(4));
    let extent = bounds.max - bounds.min;
    let scale: [f32; 3] = std::array::from_fn(|a| {
        if extent[a] > 0.0 {
            nb as f32 / extent[a]
        } else {
            0.0
        }
    });
    let plane = |axis: usize, i: usize| plane_at(bounds.min[axis], bounds.max[axis], i, nb);
    let bins = AxisBins::fill(refs, |bins, r| {
        let tri = &ctx.tris[r.prim as usize];
        for axis in (0..3).filter(|&a| scale[a] > 0.0) {
            let (min, sc) = (bounds.min[axis], scale[axis]);
            let lo = bin_of(r.bbox.min[axis], min, sc, nb);
            let hi = bin_of(r.bbox.max[axis], min, sc, nb).max(lo);
            bins.a[axis][lo] += 1;
            bins.b[axis][hi] += 1;
            let boxes = &mut bins.boxes[axis];
            let mut rest = r.bbox;
            for (k, bin_box) in boxes.iter_mut().enumerate().take(hi).skip(lo) {
                let (part, above) = cut(tri, &rest, axis, plane(axis, k + 1));
                *bin_box = bin_box.union(part);
                rest = above;
                if rest.is_empty() {
                    break;
                }
            }
            boxes[hi] = boxes[hi].union(rest);
        }
    });
    let p = &ctx.cfg.sah;
    let base = p.c_inner * bounds.half_area();
    let mut best = None;
    for axis in (0..3).filter(|&a| scale[a] > 0.0) {
        let kind = |bin| Kind::Spatial {
            plane: plane(axis, bin),
            bin,
        };
        bins.sweep_axis(axis, nb, p, base, kind, &mut best);
    }
    best
}

/// The plane before slab `i` of `nb` equal slabs of `[min, max]`.
#[inline(always)]
fn plane_at(min: f32, max: f32, i: usize, nb: usize) -> f32 {
    min + (max - min) * (i as f32 / nb as f32)
}

/// Partitions `refs` by split `s`; `None` if one side would be empty (the caller then
/// halves the node).
fn partition(
    ctx: &Ctx,
    refs: &[Ref],
    s: &Split,
    object_mask: Option<&[bool]>,
) -> Option<(Vec<Ref>, Vec<Ref>)> {
    let axis = s.axis;
    let (mut l, mut r) = (
        Vec::with_capacity(s.left_count as usize),
        Vec::with_capacity(s.right_count as usize),
    );
    match s.kind {
        Kind::Object => {
            let mask = object_mask?;
            for (x, &left) in refs.iter().zip(mask) {
                if left {
                    l.push(*x);
                } else {
                    r.push(*x);
                }
            }
        }
        Kind::Spatial { plane, .. } => {
            let p = &ctx.cfg.sah;
            let per = |a: f32, c: u32| a * (p.c_leaf + p.c_tri * c as f32);
            let (mut lb, mut rb) = (s.left, s.right);
            let (mut lc, mut rc) = (s.left_count, s.right_count);
            for x in refs {
                if x.bbox.max[axis] <= plane {
                    l.push(*x);
                } else if x.bbox.min[axis] >= plane {
                    r.push(*x);
                } else {
                    // Straddles: cut it, or move it whole to the cheaper side (unsplitting).
                    let split = per(lb.half_area(), lc) + per(rb.half_area(), rc);
                    let all_left = per(lb.union(x.bbox).half_area(), lc)
                        + per(rb.half_area(), rc.saturating_sub(1));
                    let all_right = per(lb.half_area(), lc.saturating_sub(1))
                        + per(rb.union(x.bbox).half_area(), rc);
                    if all_left < split && all_left <= all_right {
                        lb = lb.union(x.bbox);
                        rc = rc.saturating_sub(1);
                        l.push(*x);
                    } else if all_right < split {
                        rb = rb.union(x.bbox);
                        lc = lc.saturating_sub(1);
                        r.push(*x);
                    } else {
                        let (a, b) = cut(&ctx.tris[x.prim as usize], &x.bbox, axis, plane);
                        if !a.is_empty() {
                            l.push(Ref {
                                bbox: a,
                                prim: x.prim,
                            });
                        }
                        if !b.is_empty() {
                            r.push(Ref {
                                bbox: b,
                                prim: x.prim,
                            });
                        }
                    }
                }
            }
        }
    }
    (!l.is_empty() && !r.is_empty()).then_some((l, r))
}

/// Halves a node whose split search found nothing usable (or whose chosen split left one
/// side empty): the median of the centroids on the longest axis of their box.
fn median_split(mut refs: Vec<Ref>) -> (Vec<Ref>, Vec<Ref>) {
    let cb = refs.iter().fold(Aabb::EMPTY, |b, r| b.grow(r.centroid()));
    let axis = cb.largest_axis();
    let k = refs.len() / 2;
    refs.select_nth_unstable_by(k, |a, b| {
        a.centroid()[axis]
            .total_cmp(&b.centroid()[axis])
            .then(a.prim.cmp(&b.prim))
    });
    let r = refs.split_off(k);
    (refs, r)
}

/// Cuts triangle `tri`'s part inside `within` at the plane `x[axis] = plane`: the boxes
/// of its parts below and above the plane (each may be empty). Conservative: each box
/// contains every point of the triangle on its side of the plane that lies in `within`
/// (see the module notes for the rounding bound).
pub(crate) fn cut(tri: &Triangle, within: &Aabb, axis: usize, plane: f32) -> (Aabb, Aabb) {
    let (mut lo, mut hi) = (Aabb::EMPTY, Aabb::EMPTY);
    for i in 0..3 {
        let a = tri.v[i];
        let b = tri.v[(i + 1) % 3];
        if a[axis] <= plane {
            lo = lo.grow(a);
        }
        if a[axis] >= plane {
            hi = hi.grow(a);
        }
        if (a[axis] < plane && b[axis] > plane) || (a[axis] > plane && b[axis] < plane) {
            let t = (plane - a[axis]) / (b[axis] - a[axis]);
            let mut x = a + (b - a) * t;
            let mut err = Vec3::ZERO;
            for c in 0..3 {
                err[c] = 16.0 * f32::EPSILON * (a[c].abs() + b[c].abs()) + f32::MIN_POSITIVE;
            }
            x[axis] = plane;
            err[axis] = 0.0;
            let wide = Aabb::new(x - err, x + err);
            lo = lo.union(wide);
            hi = hi.union(wide);
        }
    }
    let mut below = *within;
    below.max[axis] = below.max[axis].min(plane);
    let mut above = *within;
    above.min[axis] = above.min[axis].max(plane);
    (lo.intersection(below), hi.intersection(above))
}

#[cfg(test)]
mod tests;
