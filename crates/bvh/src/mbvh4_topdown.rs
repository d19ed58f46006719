//! Native top-down 4-wide builder of Wald, Benthin and Boulos (2008), the MBVH builder
//! that \[P4\] used ("MBVHs with Wald's topdown recursive splitting algorithm").
//!
//! Thesis §4.2: "When processing a node, the algorithm finds the best axis-aligned split for
//! each child, and applies the split that gives the best SAH improvement, until the node is
//! full." A node starts as one candidate child holding all of its primitives. Each
//! candidate gets its best binned SAH split (Wald 2007 binning over the centroid bounds);
//! the split with the largest SAH gain `A(C)·N(C) − A(L)·N(L) − A(R)·N(R)` replaces its
//! candidate by two, until there are four candidates or no split improves the SAH.
//! Candidates above the maximum leaf size are always split first. Splitting a candidate
//! inside the node costs no extra node (the node's `C_i` is paid anyway), so the gain has
//! no `C_i` term. Each final candidate becomes a leaf when it fits and its leaf cost is not
//! above the 4-wide SAH (`2 C_i` per node) of the node the candidate would become (built
//! tentatively), otherwise that 4-wide node ([`Mbvh4TopDownBuilder::wide_node_cost`]; off,
//! the earlier leaf decision compares the leaf with a binary node over the best binary
//! split, at half the price the tree is judged by).
//!
//! Candidates of at most 16 primitives get an exact split instead (per axis, sort by
//! centroid and sweep every position), which is cheaper than clearing and sweeping bins
//! for the many tiny candidates near the leaves and never worse in SAH.
//!
//! Robustness is as in the binned binary builder: areas are computed in `f64` (no overflow
//! for huge coordinates), coincident centroids are split at the middle of the range, and
//! beyond [`MAX_SAH_DEPTH`](crate::MAX_SAH_DEPTH) levels every split is a median split so the
//! depth stays logarithmic. Subtrees of at least
//! [`PARALLEL_MIN_PRIMS`](crate::PARALLEL_MIN_PRIMS) primitives are built in parallel into
//! separate node arrays that are appended in child order, so the tree is the same for any
//! thread count.

use crate::bins::{Binner, Bins};
use crate::error::{check_input, in_pool, BuildError};
use crate::mbvh4::{Mbvh4, Node4, MBVH_WIDTH};
use crate::node::ChildRef;
use crate::sah::SahParams;
use crate::split::{sweep, Box4, Counted, PrimRef as Ref, SweepBox, Unit, Wide};
use crate::{MAX_BINS, MAX_SAH_DEPTH, PARALLEL_MIN_PRIMS};
use geom::{Aabb, Vec4};
use rayon::prelude::*;

/// Configuration of the native top-down MBVH4 builder.
#[derive(Clone, Debug, PartialEq)]
pub struct Mbvh4TopDownBuilder {
    /// Bins per axis for the SAH split search (2..=64).
    pub bins: usize,
    /// Largest leaf (>= 1).
    pub max_leaf_size: u32,
    /// SAH weights used to choose splits and leaves.
    pub sah: SahParams,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
    /// The leaf decision with the cost of the 4-wide SAH that [`Mbvh4::normalized_sah`]
    /// reports (the default; issue 31 part 4): a candidate that fits in a leaf becomes one
    /// unless the node it would become (built tentatively as it would be) costs less, each
    /// node at `2 C_i` ([`SahParams::for_width`]). `false` is the builder as it was before
    /// 2026-12-06, a defect kept as an option: the node is estimated as a binary node
    /// (`C_i` = 1.2) over the best binary split, half the 4-wide node's price, which gives
    /// leaves of 1.5 triangles and a 4-wide SAH about 9% above the collapse's on Crytek
    /// Sponza (`docs/rtunit-vs-thesis.md`).
    pub wide_node_cost: bool,
}

impl Default for Mbvh4TopDownBuilder {
    fn default() -> Self {
        Self {
            bins: 16,
            max_leaf_size: 8,
            sah: SahParams::THESIS,
            threads: 0,
            wide_node_cost: true,
        }
    }
}

/// Half surface area of a box in `f64`, so huge finite boxes do not overflow.
#[inline]
fn area(b: &Aabb) -> f64 {
    if b.is_empty() {
        return 0.0;
    }
    let e = |i: usize| b.max[i] as f64 - b.min[i] as f64;
    let (x, y, z) = (e(0), e(1), e(2));
    x * y + y * z + z * x
}

/// A chosen split of a candidate.
#[derive(Clone, Copy, Debug)]
struct Split {
    /// Axis (0..3); ignored for a median split.
    axis: usize,
    /// Primitives in bins `< pos` go left.
    pos: usize,
    /// `A(L)·N(L) + A(R)·N(R)`.
    cost: f64,
    /// Split at the middle of the range instead of binning.
    median: bool,
    /// Exact split of a small candidate: the first `pos` references in centroid order
    /// along `axis` go left ([`Ctx::sorted_split`]).
    sorted: bool,
}

impl Split {
    /// Makes the boundary before position `pos` on `axis` (`sorted`: a position in centroid
    /// order, else a bin boundary) at `cost` the best split if it is cheaper.
    #[inline(always)]
    fn offer(best: &mut Option<Split>, cost: f64, axis: usize, pos: usize, sorted: bool) {
        if best.is_none_or(|b| cost < b.cost) {
            *best = Some(Split {
                axis,
                pos,
                cost,
                median: false,
                sorted,
            });
        }
    }
}

/// Both halves of a split as ((box, centroid box), (box, centroid box), left count).
type Halves = ((Aabb, Aabb), (Aabb, Aabb), usize);

/// A candidate child of the node under construction.
#[derive(Clone, Copy)]
struct Cand {
    /// Absolute range in the reference array (= leaf-table positions).
    start: usize,
    end: usize,
    bounds: Aabb,
    cbounds: Aabb,
    /// Best split, once computed (`Some(None)`: cannot be split).
    split: Option<Option<Split>>,
}

impl Cand {
    fn len(&self) -> usize {
        self.end - self.start
    }
}

/// Box and centroid box of a run of references.
fn bounds_of(refs: &[Ref]) -> (Aabb, Aabb) {
    type B = [Vec4; 4];
    let empty = || -> B {
        let (lo, hi) = (Vec4::splat(f32::INFINITY), Vec4::splat(f32::NEG_INFINITY));
        [lo, hi, lo, hi]
    };
    let add = |b: B, r: &Ref| {
        let m = r.centroid4();
        [b[0].min(r.min), b[1].max(r.max), b[2].min(m), b[3].max(m)]
    };
    let b = if refs.len() >= PAR_BIN_MIN {
        refs.par_chunks(PAR_BIN_MIN / 4)
            .map(|c| c.iter().fold(empty(), add))
            .reduce(empty, |a, b| {
                [
                    a[0].min(b[0]),
                    a[1].max(b[1]),
                    a[2].min(b[2]),
                    a[3].max(b[3]),
                ]
            })
    } else {
        refs.iter().fold(empty(), add)
    };
    (
        Aabb::new(b[0].truncate(), b[1].truncate()),
        Aabb::new(b[2].truncate(), b[3].truncate()),
    )
}

/// Candidates of at most this many primitives get an exact sorted split, not bins.
const SMALL: usize = 16;

/// Candidates of at least this many primitives are binned and bounded in parallel chunks.
const PAR_BIN_MIN: usize = 1 << 16;

/// Unnormalized SAH cost of the 4-wide subtree `nodes` (root at 0, box area `root_area`):
/// `C_i` for the root and every inner child, `C_l + C_t n` for every leaf, each times its
/// area.
fn subtree_cost(nodes: &[Node4], root_area: f64, p: &SahParams) -> f64 {
    let (ci, cl, ct) = (p.c_inner as f64, p.c_leaf as f64, p.c_tri as f64);
    let mut cost = ci * root_area;
    for node in nodes {
        for (slot, ch) in node.children.iter().enumerate() {
            let a = area(&node.child_aabb(slot));
            if ch.is_leaf() {
                cost += a * (cl + ct * ch.count as f64);
            } else if ch.is_inner() {
                cost += a * ci;
            }
        }
    }
    cost
}

struct Ctx<'a> {
    cfg: &'a Mbvh4TopDownBuilder,
}

impl Ctx<'_> {
    /// Bin index along `axis` for centroid coordinate `c` given the origin and scale.
    #[inline(always)]
    fn bin(&self, c: f32, lo: f32, k: f32) -> usize {
        (((c - lo) * k) as usize).min(self.cfg.bins - 1)
    }

    /// Best split of the references `refs` whose centroid box is `cbounds`.
    fn find_split(&self, refs: &[Ref], cbounds: &Aabb, depth: u32) -> Option<Split> {
        // Bin arrays sized to the bin count: clearing 64 bins per call dominated the
        // small candidates near the leaves.
        match self.cfg.bins {
            0..=8 => self.find_split_n::<8>(refs, cbounds, depth),
            9..=16 => self.find_split_n::<16>(refs, cbounds, depth),
            17..=32 => self.find_split_n::<32>(refs, cbounds, depth),
            _ => self.find_split_n::<MAX_BINS>(refs, cbounds, depth),
        }
    }

    /// [`Self::find_split`] with bin arrays of `N >= bins` entries.
    fn find_split_n<const N: usize>(
        &self,
        refs: &[Ref],
        cbounds: &Aabb,
        depth: u32,
    ) -> Option<Split> {
        let n = refs.len();
        if n < 2 {
            return None;
        }
        let median = || {
            let (l, _) = bounds_of(&refs[..n / 2]);
            let (r, _) = bounds_of(&refs[n / 2..]);
            Some(Split {
                axis: 0,
                pos: 0,
                cost: area(&l) * (n / 2) as f64 + area(&r) * (n - n / 2) as f64,
                median: true,
                sorted: false,
            })
        };
        if depth > MAX_SAH_DEPTH {
            return median();
        }
        if n <= SMALL {
            return Self::sorted_split(refs).or_else(median);
        }
        let bins = self.cfg.bins;
        let mut best: Option<Split> = None;
        // Zero, subnormal or overflowing extents give no usable planes on an axis (scale 0).
        let binner = Binner::new(cbounds, bins);
        let scale = binner.scale;
        if scale == Vec4::ZERO {
            return median();
        }
        // The binner's arithmetic equals `Ctx::bin`'s, so the partition agrees; unused axes
        // (scale 0) all land in bin 0 and are ignored. Min, max and counts are exact and
        // order-independent, so the parallel binning of large candidates gives the same bins
        // as the sequential one.
        let Bins {
            min: bmin,
            max: bmax,
            cnt,
        } = Bins::<N>::fill(refs, &binner);
        let (mut right_area, mut right_count) = ([0f64; N], [0u32; N]);
        for axis in 0..3 {
            if scale[axis] == 0.0 {
                continue;
            }
            let item = |i: usize| {
                let b = Box4 {
                    min: bmin[axis][i],
                    max: bmax[axis][i],
                };
                (Wide(b), cnt[axis][i])
            };
            let right = &mut Counted(&mut right_area, &mut right_count);
            sweep(bins, item, right, |i, left, k, ra, rk| {
                if k == 0 || rk == 0 {
                    return;
                }
                Split::offer(
                    &mut best,
                    left.area() * k as f64 + ra * rk as f64,
                    axis,
                    i,
                    false,
                );
            });
        }
        best.or_else(median)
    }

    /// Exact SAH split of at most [`SMALL`] references: per axis, sort by centroid and
    /// sweep every position (cheaper than clearing and sweeping the bins for tiny
    /// candidates, which are most of them, and never worse in SAH).
    fn sorted_split(refs: &[Ref]) -> Option<Split> {
        let n = refs.len();
        let mut best: Option<Split> = None;
        let mut ord = [(0u64, 0u8); SMALL];
        let mut right = [0f64; SMALL];
        for axis in 0..3 {
            for (k, r) in refs.iter().enumerate() {
                ord[k] = (r.key(axis), k as u8);
            }
            ord[..n].sort_unstable();
            let item = |i: usize| (Wide(refs[ord[i].1 as usize]), 1);
            sweep(n, item, &mut Unit(&mut right, n), |i, left, k, ra, rk| {
                Split::offer(
                    &mut best,
                    left.area() * k as f64 + ra * rk as f64,
                    axis,
                    i,
                    true,
                );
            });
        }
        best.filter(|b| b.cost.is_finite())
    }

    /// Median or sorted split: cuts the (sorted) references at a position, then bounds both.
    fn split_at(&self, refs: &mut [Ref], s: &Split) -> Halves {
        let mid = if s.median {
            refs.len() / 2
        } else {
            refs.sort_unstable_by_key(|r| r.key(s.axis));
            s.pos
        };
        (bounds_of(&refs[..mid]), bounds_of(&refs[mid..]), mid)
    }

    /// In-place partition by a binned split that also accumulates both sides' box and
    /// centroid box, so no second pass over the references is needed.
    fn partition(&self, refs: &mut [Ref], c: &Cand, s: &Split) -> Halves {
        let (axis, lo) = (s.axis, c.cbounds.min[s.axis]);
        let k = self.cfg.bins as f32 / (c.cbounds.max[axis] - lo);
        let inf = (Vec4::splat(f32::INFINITY), Vec4::splat(f32::NEG_INFINITY));
        let (mut l, mut lcb, mut r, mut rcb) = (inf, inf, inf, inf);
        let (mut i, mut j) = (0usize, refs.len());
        while i < j {
            let x = refs[i];
            let m = x.centroid4();
            if self.bin(m[axis], lo, k) < s.pos {
                l = (l.0.min(x.min), l.1.max(x.max));
                lcb = (lcb.0.min(m), lcb.1.max(m));
                i += 1;
            } else {
                r = (r.0.min(x.min), r.1.max(x.max));
                rcb = (rcb.0.min(m), rcb.1.max(m));
                j -= 1;
                refs.swap(i, j);
            }
        }
        let bx = |b: (Vec4, Vec4)| Aabb::new(b.0.truncate(), b.1.truncate());
        ((bx(l), bx(lcb)), (bx(r), bx(rcb)), i)
    }

    /// Partitions the candidate's references by `s`; returns the two halves as candidates.
    fn apply(&self, refs: &mut [Ref], c: &Cand, s: &Split) -> (Cand, Cand) {
        let ((lb, lc), (rb, rc), mid) = if s.median || s.sorted {
            self.split_at(refs, s)
        } else {
            let res = self.partition(refs, c, s);
            if res.2 == 0 || res.2 == refs.len() {
                // Cannot happen (binning and partition use the same arithmetic); never emit an
                // empty child if it did.
                self.split_at(refs, &Split { median: true, ..*s })
            } else {
                res
            }
        };
        let mk = |start, end, bounds, cbounds| Cand {
            start,
            end,
            bounds,
            cbounds,
            split: None,
        };
        (
            mk(c.start, c.start + mid, lb, lc),
            mk(c.start + mid, c.end, rb, rc),
        )
    }

    /// Whether a final candidate becomes a leaf (computing its split if needed).
    fn is_leaf(&self, refs: &[Ref], c: &mut Cand, depth: u32) -> bool {
        let n = c.len();
        if n > self.cfg.max_leaf_size as usize {
            return false;
        }
        if n <= 1 || depth > MAX_SAH_DEPTH {
            return true;
        }
        let split = match c.split {
            Some(s) => s,
            None => *c.split.insert(self.find_split(refs, &c.cbounds, depth)),
        };
        let Some(s) = split else { return true };
        let p = &self.cfg.sah;
        let a = area(&c.bounds);
        let leaf = a * (p.c_leaf as f64 + p.c_tri as f64 * n as f64);
        if self.cfg.wide_node_cost {
            // The node this candidate would become, built as it would be (at most
            // `max_leaf_size` references, so cheap), priced in the 4-wide SAH.
            let mut tmp = refs.to_vec();
            let mut nodes = Vec::new();
            let root = Cand {
                start: 0,
                end: n,
                ..*c
            };
            self.build_node(&mut tmp, root, depth, &mut nodes);
            return leaf <= subtree_cost(&nodes, a, &p.for_width(MBVH_WIDTH));
        }
        leaf <= a * p.c_inner as f64 + p.c_tri as f64 * s.cost
    }

    /// Builds the 4-wide node for candidate `root` (whose references are `refs`) into
    /// `out`, in depth-first order; returns its index in `out`.
    fn build_node(&self, refs: &mut [Ref], root: Cand, depth: u32, out: &mut Vec<Node4>) -> u32 {
        let base = root.start;
        let max_leaf = self.cfg.max_leaf_size as usize;
        // Fixed arrays, not vectors: two allocations per node showed in profiles.
        let mut cands = [root; MBVH_WIDTH];
        let mut len = 1;
        while len < MBVH_WIDTH {
            let mut best: Option<(usize, bool, f64)> = None;
            for (k, c) in cands[..len].iter_mut().enumerate() {
                let r = &refs[c.start - base..c.end - base];
                let split = match c.split {
                    Some(s) => s,
                    None => *c.split.insert(self.find_split(r, &c.cbounds, depth)),
                };
                let Some(s) = split else { continue };
                // The node's only candidate must be split: the parent made it an inner node.
                let must = c.len() > max_leaf || c.start == base && c.end == base + refs.len();
                let gain = area(&c.bounds) * c.len() as f64 - s.cost;
                if !(must || gain > 0.0) {
                    continue;
                }
                if best.is_none_or(|(_, bm, bg)| (must, gain) > (bm, bg)) {
                    best = Some((k, must, gain));
                }
            }
            let Some((k, _, _)) = best else { break };
            let c = cands[k];
            let Some(Some(s)) = c.split else { break }; // chosen candidates have a split
            let (l, r) = self.apply(&mut refs[c.start - base..c.end - base], &c, &s);
            cands.copy_within(k + 1..len, k + 2);
            cands[k] = l;
            cands[k + 1] = r;
            len += 1;
        }
        let at = out.len();
        out.push(Node4::EMPTY);
        let mut inner = [(0usize, root); MBVH_WIDTH];
        let mut n_inner = 0;
        for (slot, c) in cands[..len].iter_mut().enumerate() {
            let leaf = self.is_leaf(&refs[c.start - base..c.end - base], c, depth + 1);
            out[at].set_child_aabb(slot, &c.bounds);
            if leaf {
                out[at].children[slot] = ChildRef::leaf(c.start as u32, c.len() as u32);
            } else {
                inner[n_inner] = (slot, *c);
                n_inner += 1;
            }
        }
        let inner = &inner[..n_inner];
        if refs.len() >= PARALLEL_MIN_PRIMS && inner.len() > 1 {
            // Parallel: each inner child into its own array, appended in slot order.
            let mut jobs: Vec<(usize, Cand, &mut [Ref])> = Vec::with_capacity(inner.len());
            let mut rest = refs;
            let mut rest_start = base;
            for &(slot, c) in inner {
                let tail = std::mem::take(&mut rest);
                let (_, tail) = tail.split_at_mut(c.start - rest_start);
                let (mine, tail) = tail.split_at_mut(c.len());
                rest = tail;
                rest_start = c.end;
                jobs.push((slot, c, mine));
            }
            let subs: Vec<(usize, Vec<Node4>)> = jobs
                .into_par_iter()
                .map(|(slot, c, r)| {
                    let mut v = Vec::new();
                    self.build_node(r, c, depth + 1, &mut v);
                    (slot, v)
                })
                .collect();
            for (slot, v) in subs {
                let off = out.len() as u32;
                out[at].children[slot] = ChildRef::inner(off);
                out.extend(v.into_iter().map(|mut n| {
                    for ch in n.children.iter_mut().filter(|ch| ch.is_inner()) {
                        ch.index += off;
                    }
                    n
                }));
            }
        } else {
            for &(slot, c) in inner {
                let r = &mut refs[c.start - base..c.end - base];
                let idx = self.build_node(r, c, depth + 1, out);
                out[at].children[slot] = ChildRef::inner(idx);
            }
        }
        at as u32
    }
}

impl Mbvh4TopDownBuilder {
    /// Builds a 4-wide tree over `aabbs`; errors on invalid input or configuration.
    pub fn build(&self, aabbs: &[Aabb]) -> Result<Mbvh4, BuildError> {
        if !(2..=MAX_BINS).contains(&self.bins) {
            return Err(BuildError::InvalidConfig(format!(
                "bins = {} is outside 2..={MAX_BINS}",
                self.bins
            )));
        }
        if self.max_leaf_size == 0 {
            return Err(BuildError::InvalidConfig(
                "max_leaf_size must be >= 1".into(),
            ));
        }
        check_input(aabbs)?;
        if aabbs.is_empty() {
            return Ok(Mbvh4::empty());
        }
        in_pool(self.threads, || self.build_checked(aabbs))
    }

    fn build_checked(&self, aabbs: &[Aabb]) -> Mbvh4 {
        let mut refs: Vec<Ref> = aabbs
            .par_iter()
            .enumerate()
            .map(|(i, b)| Ref::new(b, i as u32))
            .collect();
        let (bounds, cbounds) = bounds_of(&refs);
        let mut root = Cand {
            start: 0,
            end: refs.len(),
            bounds,
            cbounds,
            split: None,
        };
        let ctx = Ctx { cfg: self };
        let mut nodes = Vec::with_capacity(refs.len() / 4 + 1);
        if ctx.is_leaf(&refs, &mut root, 0) {
            nodes.push(Node4::from_children(&[(
                bounds,
                ChildRef::leaf(0, refs.len() as u32),
            )]));
        } else {
            ctx.build_node(&mut refs, root, 0, &mut nodes);
        }
        Mbvh4 {
            nodes,
            prim_indices: refs.iter().map(Ref::index).collect(),
            bounds,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mbvh4::validate_mbvh4;
    use crate::testutil::{adversarial, proc_scene, soup, subnormal_simd_lane};
    use crate::{collapse, BinnedSahBuilder, SweepSahBuilder};
    use geom::Vec3;

    fn assert_valid(name: &str, t: &Mbvh4, prims: &[Aabb], max: u32) {
        if let Err(e) = validate_mbvh4(t, prims, max) {
            panic!("{name}: invalid 4-wide tree: {e}");
        }
    }

    /// Issue 17: for small input indices, no lane of a reference, of its SIMD extent, area
    /// products or centroid, or of the binning arithmetic `(centroid - lo) * k` is
    /// subnormal.
    #[test]
    fn simd_lanes_of_refs_are_never_subnormal() {
        let boxes = soup(4096, 2.0, 5);
        let (lo4, k4) = (Vec4::new(1.0, 2.0, 3.0, 0.0), Vec4::new(0.1, 0.2, 0.3, 0.0));
        for (i, b) in boxes.iter().enumerate() {
            let r = Ref::new(b, i as u32);
            assert_eq!(r.index(), i as u32);
            let bad = subnormal_simd_lane(r.min, r.max);
            assert!(bad.is_none(), "index {i}: {}", bad.unwrap());
            let f = (r.centroid4() - lo4) * k4;
            assert!(!f.to_array().iter().any(|x| x.is_subnormal()), "{i}: {f:?}");
        }
    }

    #[test]
    fn adversarial_inputs_give_valid_trees() {
        for (name, prims) in adversarial() {
            for (bins, max) in [(8, 1), (16, 4), (32, 8)] {
                let b = Mbvh4TopDownBuilder {
                    bins,
                    max_leaf_size: max,
                    ..Default::default()
                };
                let t = b.build(&prims).unwrap();
                assert_valid(name, &t, &prims, max);
            }
        }
    }

    #[test]
    fn small_inputs() {
        let t = Mbvh4TopDownBuilder::default().build(&[]).unwrap();
        assert_eq!(t, Mbvh4::empty());
        let one = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
        let t = Mbvh4TopDownBuilder::default().build(&one).unwrap();
        assert_valid("one", &t, &one, 8);
        assert_eq!(t.nodes.len(), 1);
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 1));
        // Five far-apart cubes with leaves of one: a root with four slots, one of them a
        // node of two.
        let five = crate::testutil::cubes_at(&[0.0, 10.0, 20.0, 30.0, 40.0]);
        let b = Mbvh4TopDownBuilder {
            max_leaf_size: 1,
            ..Default::default()
        };
        let t = b.build(&five).unwrap();
        assert_valid("five", &t, &five, 1);
        assert_eq!(t.nodes.len(), 2);
        assert_eq!(t.nodes[0].child_count(), 4);
    }

    #[test]
    fn quality_matches_collapse_and_nodes_are_full() {
        let prims = proc_scene("proc:soup?n=20000");
        let t = Mbvh4TopDownBuilder::default().build(&prims).unwrap();
        assert_valid("soup", &t, &prims, 8);
        let sweep = SweepSahBuilder::default().build(&prims).unwrap();
        let binned = BinnedSahBuilder::default().build(&prims).unwrap();
        let c = collapse(&binned).unwrap();
        let (st, sc) = (t.sah(), c.sah());
        println!(
            "topdown {st:.2} collapse(binned) {sc:.2} sweep(binary) {:.2}",
            sweep.sah()
        );
        // [WBB08] report similar quality for both methods.
        assert!(
            st < 1.15 * sc && st > 0.85 * sc,
            "topdown {st} vs collapse {sc}"
        );
        assert!(t.stats().mean_children > 3.0, "{:?}", t.stats());
    }

    /// Issue 31 part 4: the leaf decision with the 4-wide node cost lowers the 4-wide SAH
    /// ([`Mbvh4::normalized_sah`]) of the builder as it was, with fewer nodes and larger
    /// leaves. The greedy collapse of the binned SAH tree is printed beside them.
    #[test]
    fn the_wide_node_cost_brings_the_sah_to_the_collapse() {
        for spec in [
            "proc:soup?n=20000",
            "proc:city?n=20000&seed=2",
            "proc:hairball?n=20000&seed=3",
        ] {
            let prims = proc_scene(spec);
            let old = Mbvh4TopDownBuilder {
                wide_node_cost: false,
                ..Default::default()
            }
            .build(&prims)
            .unwrap();
            let new = Mbvh4TopDownBuilder::default().build(&prims).unwrap();
            assert_valid(spec, &old, &prims, 8);
            assert_valid(spec, &new, &prims, 8);
            let c = collapse(&BinnedSahBuilder::default().build(&prims).unwrap()).unwrap();
            let (so, sn, sc) = (
                old.normalized_sah(),
                new.normalized_sah(),
                c.normalized_sah(),
            );
            let leaf = |t: &Mbvh4| t.prim_count() as f64 / t.stats().leaves as f64;
            println!(
                "{spec}: as is {so:.3} ({} nodes, leaves {:.2}), wide cost {sn:.3} ({} nodes, leaves {:.2}), collapse {sc:.3} ({} nodes, leaves {:.2})",
                old.nodes.len(),
                leaf(&old),
                new.nodes.len(),
                leaf(&new),
                c.nodes.len(),
                leaf(&c)
            );
            assert!(sn < so, "{spec}: {sn} not below {so}");
            // Not asserted: below the collapse's. It is on soup, not on city (the split
            // choices, not only the leaf decision, keep the top-down tree above it there).
            let _ = sc;
            assert!(new.nodes.len() < old.nodes.len(), "{spec}");
            assert!(leaf(&new) > leaf(&old), "{spec}");
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let prims = soup(30_000, 2.0, 3);
        let t1 = Mbvh4TopDownBuilder {
            threads: 1,
            ..Default::default()
        }
        .build(&prims)
        .unwrap();
        let t2 = Mbvh4TopDownBuilder {
            threads: 2,
            ..Default::default()
        }
        .build(&prims)
        .unwrap();
        assert_valid("soup", &t1, &prims, 8);
        assert_eq!(t1, t2);
    }

    #[test]
    fn bad_inputs_and_configs_are_errors() {
        let ok = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
        for bins in [0, 1, 65] {
            let b = Mbvh4TopDownBuilder {
                bins,
                ..Default::default()
            };
            assert!(matches!(b.build(&ok), Err(BuildError::InvalidConfig(_))));
        }
        let b = Mbvh4TopDownBuilder {
            max_leaf_size: 0,
            ..Default::default()
        };
        assert!(matches!(b.build(&ok), Err(BuildError::InvalidConfig(_))));
        let nan = [Aabb::new(Vec3::ZERO, Vec3::new(f32::NAN, 1.0, 1.0))];
        assert_eq!(
            Mbvh4TopDownBuilder::default().build(&nan),
            Err(BuildError::NonFinite { index: 0 })
        );
        let inv = [ok[0], Aabb::new(Vec3::ONE, Vec3::ZERO)];
        assert_eq!(
            Mbvh4TopDownBuilder::default().build(&inv),
            Err(BuildError::InvertedBox { index: 1 })
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        #[test]
        fn random_soups_give_valid_trees(n in 0usize..1500, size in 0.0f32..20.0, seed: u64,
                                         max in 1u32..9) {
            let prims = soup(n, size, seed);
            let t = Mbvh4TopDownBuilder { max_leaf_size: max, ..Default::default() }
                .build(&prims).unwrap();
            proptest::prop_assert_eq!(validate_mbvh4(&t, &prims, max), Ok(()));
        }
    }
}
