//! Toplevel builds over the HLBVH cell roots (\[P2\] §5.6, §6.2): HLBVH+SAH, and the hooks
//! for HLBVH+ATRBVH.
//!
//! The streaming emitter with a `highlevel_threshold` ([`HlbvhBuilder::build_highlevel`])
//! outputs one subtree per grid cell of the top Morton bits. A toplevel build makes a tree
//! whose primitives are the cell roots' boxes (a few hundred to a few thousand, so a
//! high-quality builder is cheap), and [`stitch`] replaces each top leaf by the cell
//! subtrees it references. Any builder can make the top tree: [`HlbvhSahBuilder`] uses the
//! binned SAH of Wald (2007), as the thesis uses the builder of Doyle et al.; [`morton_top`]
//! gives the Morton-prefix top that the uncut HLBVH would have, the starting point that
//! ATRBVH optimizes for HLBVH+ATRBVH.

use crate::atrbvh::{optimize, optimize_checked, AtrbvhConfig, AtrbvhWork};
use crate::binned_sah::BinnedSahBuilder;
use crate::bvh2::Bvh2;
use crate::error::{in_pool, BuildError};
use crate::hlbvh::{EmitRef, Emitter, Highlevel, HlbvhBuilder, Prim, Step};
use crate::lbvh::MortonBits;
use crate::node::{ChildRef, Node};
use crate::validate::validate;
use geom::Aabb;
use rayon::prelude::*;

/// The top code bits whose cells the toplevel builds take as primitives by default: 12
/// (4 octree levels, at most 4096 cells; the thesis's toplevel trees have "ca. 500–2,000
/// nodes").
pub const DEFAULT_TOPLEVEL_BITS: u32 = 12;

/// The default cell level of the toplevel builds: the top [`DEFAULT_TOPLEVEL_BITS`] code
/// bits.
pub fn default_threshold(bits: MortonBits) -> u32 {
    match bits {
        MortonBits::Bits30 => 30 - DEFAULT_TOPLEVEL_BITS,
        MortonBits::Bits63 => 63 - DEFAULT_TOPLEVEL_BITS,
    }
}

/// The boxes of the cell roots, in Morton order: the primitives of a toplevel build.
pub fn root_boxes(hl: &Highlevel) -> Vec<Aabb> {
    hl.roots.iter().map(|r| r.aabb).collect()
}

/// The top tree over the cell roots that joins them by their Morton prefixes (one root per
/// leaf): stitched with the cells, it is exactly the uncut HLBVH tree.
pub fn morton_top(hl: &Highlevel) -> Bvh2 {
    let mut em = Emitter::new(None);
    let mut nodes = Vec::with_capacity(hl.roots.len().saturating_sub(1));
    let mut roots = Vec::new();
    // The tie is the root's index, so no two roots ever share a leaf.
    let mut input = hl.roots.iter().enumerate().map(|(i, r)| Prim {
        code: r.key.0,
        tie: i as u32,
        aabb: r.aabb,
    });
    loop {
        let inp = if em.needs_input() { input.next() } else { None };
        match em.step(inp) {
            Step::Emitted(n) => nodes.push(n),
            Step::Highlevel(r) => roots.push(r),
            Step::Done => break,
            Step::Loaded | Step::Combined | Step::Pushed => {}
        }
    }
    Highlevel {
        nodes,
        roots,
        order: (0..hl.roots.len() as u32).collect(),
    }
    .to_bvh2()
}

/// A subtree still to lay out while stitching.
#[derive(Clone, Copy, Debug)]
enum Item {
    /// No child.
    Empty,
    /// A node of the top tree.
    Top(u32),
    /// A (part of a) cell subtree.
    Sub(EmitRef),
    /// Several cell roots in one top leaf: `top.prim_indices[first..first + count]`.
    Group(u32, u32),
}

/// Lays out a top tree and the cell subtrees as one depth-first [`Bvh2`].
struct Stitcher<'a> {
    top: &'a Bvh2,
    hl: &'a Highlevel,
}

impl Stitcher<'_> {
    /// The box of the roots in a top leaf.
    fn group_box(&self, first: u32, count: u32) -> Aabb {
        self.top.prim_indices[first as usize..(first + count) as usize]
            .iter()
            .fold(Aabb::EMPTY, |b, &r| b.union(self.hl.roots[r as usize].aabb))
    }

    /// A top child as an item (a group of one root becomes that root's subtree).
    fn top_child(&self, c: ChildRef, b: Aabb) -> (Item, Aabb) {
        if c.is_inner() {
            (Item::Top(c.index), b)
        } else if c.is_leaf() {
            self.group(c.index, c.count)
        } else {
            (Item::Empty, Aabb::EMPTY)
        }
    }

    /// The item and box of the roots `top.prim_indices[first..first + count]`.
    fn group(&self, first: u32, count: u32) -> (Item, Aabb) {
        if count == 1 {
            let r = &self.hl.roots[self.top.prim_indices[first as usize] as usize];
            (Item::Sub(r.root), r.aabb)
        } else {
            (Item::Group(first, count), self.group_box(first, count))
        }
    }

    /// The two children of a node item, with their boxes.
    fn children(&self, item: Item) -> [(Item, Aabb); 2] {
        match item {
            Item::Top(n) => {
                let node = &self.top.nodes[n as usize];
                [0, 1].map(|s| self.top_child(node.children[s], node.child_aabb(s)))
            }
            Item::Sub(EmitRef::Node(id)) => {
                let e = &self.hl.nodes[id as usize];
                [0, 1].map(|s| (Item::Sub(e.children[s]), e.aabbs[s]))
            }
            Item::Group(first, count) => {
                // Several roots in one leaf: a balanced join in their leaf order.
                let half = count / 2;
                [
                    self.group(first, half),
                    self.group(first + half, count - half),
                ]
            }
            Item::Empty | Item::Sub(EmitRef::Leaf { .. }) => unreachable!("not a node"),
        }
    }

    /// The child reference of an item: final for leaves and empties, a placeholder for
    /// nodes (patched when the node is laid out).
    fn child_ref(item: Item) -> ChildRef {
        match item {
            Item::Empty => ChildRef::EMPTY,
            Item::Sub(EmitRef::Leaf { first, count }) => ChildRef::leaf(first, count),
            _ => ChildRef::inner(0),
        }
    }

    /// Lays out the node item `root` and everything below it in preorder.
    ///
    /// The top part is laid out serially; each cell subtree only reserves its range (its
    /// size is known from the emission order), and the cells are then written in parallel
    /// into their disjoint ranges.
    fn layout(&self, root: Item) -> Vec<Node> {
        let mut out = Vec::with_capacity(self.hl.nodes.len() + self.top.nodes.len());
        // (first emitted node, root emitted node, position in `out`) of each cell subtree.
        let mut cells: Vec<(u32, u32, usize)> = Vec::new();
        crate::layout::preorder(root, &mut out, |item, out, kids| {
            let at = out.len();
            if let Item::Sub(EmitRef::Node(r)) = item {
                let first = self.hl.subtree_first(r);
                cells.push((first, r, at));
                out.resize(at + (r - first) as usize + 1, Node::EMPTY);
            } else {
                let ch = self.children(item);
                let refs = [Self::child_ref(ch[0].0), Self::child_ref(ch[1].0)];
                out.push(Node::new(&ch[0].1, refs[0], &ch[1].1, refs[1]));
                for (slot, (r, c)) in refs.iter().zip(ch).enumerate() {
                    if r.is_inner() {
                        kids.push((slot, c.0));
                    }
                }
            }
        });
        // Disjoint slices of the reserved ranges, in increasing position order.
        let mut slices = Vec::with_capacity(cells.len());
        let mut rest = out.as_mut_slice();
        let mut taken = 0usize;
        for &(first, r, at) in &cells {
            let (_, tail) = rest.split_at_mut(at - taken);
            let (mine, tail) = tail.split_at_mut((r - first) as usize + 1);
            taken = at + mine.len();
            slices.push(mine);
            rest = tail;
        }
        slices
            .into_par_iter()
            .zip(cells.par_iter())
            .with_min_len(4)
            .for_each(|(sl, &(first, r, at))| self.hl.write_subtree(first, r, at as u32, sl));
        out
    }
}

/// Joins a top tree built over the cell roots ([`root_boxes`]: its leaf table holds root
/// indices) with the cell subtrees of `hl`: each top leaf is replaced by its roots'
/// subtrees (several roots in one leaf are joined by a balanced subtree). Works with a top
/// tree from any builder. Errors when `top` is not a valid tree over the roots.
pub fn stitch(top: &Bvh2, hl: &Highlevel) -> Result<Bvh2, BuildError> {
    let boxes = root_boxes(hl);
    validate(top, &boxes, u32::MAX)
        .map_err(|e| BuildError::InvalidConfig(format!("top tree over the cell roots: {e}")))?;
    if hl.roots.is_empty() {
        return Ok(Bvh2::empty());
    }
    let s = Stitcher { top, hl };
    let root = &top.nodes[0];
    // A top root with one child (a single top leaf) is replaced by that child, so the
    // result has no pass-through root level.
    let (item, bounds) = if root.children[1].is_empty() {
        s.top_child(root.children[0], root.child_aabb(0))
    } else {
        (Item::Top(0), top.bounds)
    };
    let item = match item {
        Item::Sub(EmitRef::Leaf { first, count }) => {
            return Ok(Bvh2::from_root(
                ChildRef::leaf(first, count),
                bounds,
                Vec::new(),
                hl.order.clone(),
            ));
        }
        other => other,
    };
    Ok(Bvh2 {
        nodes: s.layout(item),
        prim_indices: hl.order.clone(),
        bounds,
    })
}

/// Configuration of HLBVH+SAH (\[P2\] §5.6): streaming HLBVH cells, binned SAH over them.
#[derive(Clone, Debug, PartialEq)]
pub struct HlbvhSahBuilder {
    /// The HLBVH configuration; its `highlevel_threshold` selects the cells (`None` uses
    /// [`default_threshold`]) and its `threads` is overridden by `threads`.
    pub hlbvh: HlbvhBuilder,
    /// Bins per axis of the toplevel binned SAH build.
    pub bins: usize,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
}

impl Default for HlbvhSahBuilder {
    fn default() -> Self {
        Self {
            hlbvh: HlbvhBuilder::default(),
            bins: 16,
            threads: 0,
        }
    }
}

/// A toplevel build with any top builder: emits the HLBVH cells of `hlbvh`'s threshold
/// (`None` uses [`default_threshold`]), builds the top tree with `top(&cells, &root_boxes)`
/// (a valid tree over the root boxes, e.g. [`morton_top`] or any builder's output,
/// optionally optimized), and joins the cells under it as [`stitch`] does.
///
/// `cells` holds the cell roots only — each root's box and key; its `root` is a
/// placeholder, and `nodes` and `order` are empty — because the cells are emitted after
/// the top tree is built, straight into their places in the result
/// (`HlbvhBuilder::build_cells`); the tree is node for node
/// `stitch(&top, &hlbvh.build_highlevel(aabbs))`.
///
/// HLBVH+ATRBVH is this with `top = |hl, boxes| { let mut t = morton_top(hl);
/// atrbvh::optimize(&mut t, boxes, cfg); Ok(t) }` (treelet size 8, two iterations).
/// [`HlbvhAtrbvhBuilder`] is exactly that.
pub fn build_toplevel(
    hlbvh: &HlbvhBuilder,
    aabbs: &[Aabb],
    top: impl FnOnce(&Highlevel, &[Aabb]) -> Result<Bvh2, BuildError> + Send,
) -> Result<Bvh2, BuildError> {
    crate::error::check_input(aabbs)?;
    let shift = hlbvh
        .highlevel_threshold
        .unwrap_or_else(|| default_threshold(hlbvh.bits));
    let cfg = HlbvhBuilder {
        highlevel_threshold: Some(shift),
        ..hlbvh.clone()
    };
    cfg.check()?;
    // The cells are emitted and laid out in parallel: in the configured pool.
    let mut out = Bvh2::empty();
    in_pool(hlbvh.threads, || {
        cfg.build_cells(
            aabbs,
            shift,
            true,
            &mut crate::hlbvh::HlbvhArena::default(),
            &mut out,
            |hl| top(hl, &root_boxes(hl)),
        )
    })??;
    Ok(out)
}

impl HlbvhSahBuilder {
    /// The HLBVH configuration with this builder's thread count.
    fn hlbvh(&self) -> HlbvhBuilder {
        HlbvhBuilder {
            threads: self.threads,
            ..self.hlbvh.clone()
        }
    }

    /// The streaming HLBVH pass with the cell threshold applied.
    pub fn highlevel(&self, aabbs: &[Aabb]) -> Result<Highlevel, BuildError> {
        HlbvhBuilder {
            highlevel_threshold: Some(
                self.hlbvh
                    .highlevel_threshold
                    .unwrap_or_else(|| default_threshold(self.hlbvh.bits)),
            ),
            ..self.hlbvh()
        }
        .build_highlevel(aabbs)
    }

    /// Builds a tree over the primitive boxes `aabbs`.
    pub fn build(&self, aabbs: &[Aabb]) -> Result<Bvh2, BuildError> {
        build_toplevel(&self.hlbvh(), aabbs, |_, boxes| {
            BinnedSahBuilder {
                bins: self.bins,
                max_leaf_size: 1,
                min_leaf_size: 1,
                threads: self.threads,
                ..Default::default()
            }
            .build(boxes)
        })
    }
}

/// Configuration of HLBVH+ATRBVH (\[P2\] §5.6, §6.2): streaming HLBVH cells; the top tree
/// over the cell roots starts as the Morton-prefix top ([`morton_top`]) and is optimized by
/// ATRBVH (treelet size 8, two iterations by default).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct HlbvhAtrbvhBuilder {
    /// The HLBVH configuration; its `highlevel_threshold` selects the cells (`None` uses
    /// [`default_threshold`]) and its `threads` is overridden by `threads`.
    pub hlbvh: HlbvhBuilder,
    /// The ATRBVH pass over the top tree. Its leaf collapsing is not used: the top tree's
    /// leaves are whole cells, which stay separate subtrees.
    pub atrbvh: AtrbvhConfig,
    /// Issue 34's extension (not the thesis's build): after the toplevel build, ATRBVH
    /// over the whole tree with this configuration, so the cells' own subtrees are
    /// restructured too (independent subtrees, in parallel) and leaves collapse by the
    /// SAH up to its `max_leaf_size`. `None` (the default) is \[P2\] §6.2's toplevel-only
    /// HLBVH+ATRBVH, which `sim` and `arbor report mergetree` reproduce.
    pub cells: Option<AtrbvhConfig>,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
}

impl HlbvhAtrbvhBuilder {
    /// Builds a tree over the primitive boxes `aabbs`.
    pub fn build(&self, aabbs: &[Aabb]) -> Result<Bvh2, BuildError> {
        Ok(self.build_with_work(aabbs)?.0)
    }

    /// [`Self::build`], with the work of the ATRBVH pass over the top tree (a `cells` pass
    /// is not counted).
    pub fn build_with_work(&self, aabbs: &[Aabb]) -> Result<(Bvh2, AtrbvhWork), BuildError> {
        let hlbvh = HlbvhBuilder {
            threads: self.threads,
            ..self.hlbvh.clone()
        };
        let cfg = AtrbvhConfig {
            max_leaf_size: 1,
            threads: self.threads,
            ..self.atrbvh.clone()
        };
        if let Some(c) = &self.cells {
            c.check()?;
        }
        let mut work = AtrbvhWork::default();
        let mut tree = build_toplevel(&hlbvh, aabbs, |hl, boxes| {
            let mut top = morton_top(hl);
            work = optimize(&mut top, boxes, &cfg)?;
            Ok(top)
        })?;
        if let Some(c) = &self.cells {
            // The stitched tree is valid by construction (the tests validate it), so the
            // whole-tree pass skips `optimize`'s validation.
            in_pool(self.threads, || optimize_checked(&mut tree, c))?;
        }
        Ok((tree, work))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use crate::SweepSahBuilder;

    #[test]
    fn hlbvh_sah_beats_plain_hlbvh_on_structured_scenes() {
        for spec in ["proc:forest?n=30000", "proc:cloth?n=20000"] {
            let prims = proc_scene(spec);
            let plain = HlbvhBuilder::default().build(&prims).unwrap();
            let top = HlbvhSahBuilder::default().build(&prims).unwrap();
            assert_valid(spec, &plain, &prims, 8);
            assert_valid(spec, &top, &prims, 8);
            let sweep = SweepSahBuilder::default().build(&prims).unwrap();
            let (rp, rt) = (plain.sah_vs(&sweep), top.sah_vs(&sweep));
            println!("{spec}: hlbvh {rp:.3}, hlbvh+sah {rt:.3} x sweep");
            assert!(rt <= rp, "{spec}: hlbvh+sah {rt} > hlbvh {rp}");
        }
    }

    #[test]
    fn hlbvh_atrbvh_is_valid_deterministic_and_not_worse_than_hlbvh() {
        for spec in ["proc:forest?n=30000", "proc:cloth?n=20000"] {
            let prims = proc_scene(spec);
            let plain = HlbvhBuilder::default().build(&prims).unwrap();
            let opt = HlbvhAtrbvhBuilder::default().build(&prims).unwrap();
            assert_valid(spec, &opt, &prims, 8);
            let sweep = SweepSahBuilder::default().build(&prims).unwrap();
            let (rp, ro) = (plain.sah_vs(&sweep), opt.sah_vs(&sweep));
            println!("{spec}: hlbvh {rp:.3}, hlbvh+atrbvh {ro:.3} x sweep");
            // ATRBVH never raises the top tree's SAH, and the cells are unchanged.
            assert!(
                ro <= rp * (1.0 + 1e-6),
                "{spec}: hlbvh+atrbvh {ro} > hlbvh {rp}"
            );
            for threads in [1, 2] {
                let again = HlbvhAtrbvhBuilder {
                    threads,
                    ..Default::default()
                }
                .build(&prims)
                .unwrap();
                assert_eq!(again, opt, "{spec}: {threads} threads");
            }
        }
        for (name, prims) in adversarial() {
            let t = HlbvhAtrbvhBuilder::default().build(&prims).unwrap();
            assert_valid(name, &t, &prims, HlbvhBuilder::default().leaf_limit());
        }
    }

    /// Issue 34: with `cells`, the whole tree is restructured and its leaves collapsed:
    /// valid (every primitive once, leaves within the bound), never worse than the
    /// toplevel-only build, the same for any thread count.
    #[test]
    fn hlbvh_atrbvh_cells_restructures_the_whole_tree() {
        let cells = AtrbvhConfig::one_pass();
        for spec in [
            "proc:forest?n=30000",
            "proc:cloth?n=20000",
            "proc:soup?n=20000",
        ] {
            let prims = proc_scene(spec);
            let top = HlbvhAtrbvhBuilder::default().build(&prims).unwrap();
            let b = |threads| HlbvhAtrbvhBuilder {
                cells: Some(cells.clone()),
                threads,
                ..Default::default()
            };
            let t = b(0).build(&prims).unwrap();
            assert_valid(spec, &t, &prims, 8);
            let sweep = SweepSahBuilder::default().build(&prims).unwrap();
            let (rt, rc) = (top.sah_vs(&sweep), t.sah_vs(&sweep));
            println!("{spec}: hlbvh+atrbvh {rt:.3}, with cells {rc:.3} x sweep");
            assert!(rc < rt, "{spec}: cells {rc} >= toplevel only {rt}");
            for threads in [1, 2, 3] {
                assert_eq!(b(threads).build(&prims).unwrap(), t, "{spec}: {threads}");
            }
            // The top pass's work is the toplevel-only build's.
            assert_eq!(
                b(0).build_with_work(&prims).unwrap().1,
                HlbvhAtrbvhBuilder::default()
                    .build_with_work(&prims)
                    .unwrap()
                    .1
            );
        }
        for (name, prims) in adversarial() {
            let t = HlbvhAtrbvhBuilder {
                cells: Some(cells.clone()),
                ..Default::default()
            }
            .build(&prims)
            .unwrap();
            assert_valid(name, &t, &prims, 8);
        }
        let bad = HlbvhAtrbvhBuilder {
            cells: Some(AtrbvhConfig {
                treelet_size: 2,
                ..Default::default()
            }),
            ..Default::default()
        };
        assert!(matches!(
            bad.build(&soup(100, 1.0, 1)),
            Err(BuildError::InvalidConfig(_))
        ));
    }

    #[test]
    fn stitching_the_morton_top_gives_the_uncut_tree() {
        let prims = soup(10_000, 2.0, 3);
        let plain = HlbvhBuilder::default().build(&prims).unwrap();
        for t in [0, 5, 18, 25] {
            let hl = HlbvhBuilder {
                highlevel_threshold: Some(t),
                ..Default::default()
            }
            .build_highlevel(&prims)
            .unwrap();
            let top = morton_top(&hl);
            assert_valid("top", &top, &root_boxes(&hl), 1);
            assert_eq!(stitch(&top, &hl).unwrap(), plain, "threshold {t}");
        }
    }

    /// The direct layout of the toplevel builds equals stitching the full emission output,
    /// for SAH and ATRBVH tops, thresholds from few to many cells, and tops whose leaves
    /// group several roots (stitched by the general path).
    #[test]
    fn toplevel_builds_equal_stitching_the_emission() {
        let mut forest = proc_scene("proc:forest?n=20000");
        forest.truncate(30_000);
        for prims in [soup(25_000, 1.0, 5), forest] {
            for threshold in [None, Some(12), Some(24), Some(29)] {
                let hlbvh = HlbvhBuilder {
                    highlevel_threshold: threshold,
                    ..Default::default()
                };
                let sah = HlbvhSahBuilder {
                    hlbvh: hlbvh.clone(),
                    ..Default::default()
                };
                let hl = sah.highlevel(&prims).unwrap();
                let boxes = root_boxes(&hl);
                let top = BinnedSahBuilder {
                    bins: 16,
                    max_leaf_size: 1,
                    min_leaf_size: 1,
                    ..Default::default()
                }
                .build(&boxes)
                .unwrap();
                let want = stitch(&top, &hl).unwrap();
                assert_eq!(sah.build(&prims).unwrap(), want, "sah {threshold:?}");
                let atr = HlbvhAtrbvhBuilder {
                    hlbvh: hlbvh.clone(),
                    ..Default::default()
                };
                let mut top = morton_top(&hl);
                let cfg = AtrbvhConfig {
                    max_leaf_size: 1,
                    ..Default::default()
                };
                optimize(&mut top, &boxes, &cfg).unwrap();
                assert_eq!(
                    atr.build(&prims).unwrap(),
                    stitch(&top, &hl).unwrap(),
                    "atrbvh {threshold:?}"
                );
                // Leaves of up to 4 roots: the general stitch.
                let grouped = |b: &[Aabb]| {
                    BinnedSahBuilder {
                        max_leaf_size: 4,
                        ..Default::default()
                    }
                    .build(b)
                };
                if boxes.len() > 8 {
                    assert!(grouped(&boxes).unwrap().stats().max_leaf_size > 1);
                }
                let t = build_toplevel(&hlbvh, &prims, |_, b| grouped(b)).unwrap();
                assert_eq!(t, stitch(&grouped(&boxes).unwrap(), &hl).unwrap());
                assert_eq!(validate(&t, &prims, 8), Ok(()));
            }
        }
    }

    #[test]
    fn build_toplevel_with_the_morton_top_is_plain_hlbvh() {
        let prims = proc_scene("proc:forest?n=10000");
        let cfg = HlbvhBuilder::default();
        let t = build_toplevel(&cfg, &prims, |hl, _| Ok(morton_top(hl))).unwrap();
        assert_eq!(t, cfg.build(&prims).unwrap());
        // A top tree over the wrong boxes is refused, not stitched.
        let bad = build_toplevel(&cfg, &prims, |_, b| {
            BinnedSahBuilder::default().build(&b[..b.len() / 2])
        });
        assert!(matches!(bad, Err(BuildError::InvalidConfig(_))));
    }

    #[test]
    fn stitch_accepts_top_leaves_with_several_roots() {
        let prims = proc_scene("proc:forest?n=10000");
        let hl = HlbvhSahBuilder::default().highlevel(&prims).unwrap();
        let boxes = root_boxes(&hl);
        assert!(boxes.len() > 8);
        for max_leaf_size in [1, 4, 8] {
            let top = BinnedSahBuilder {
                max_leaf_size,
                ..Default::default()
            }
            .build(&boxes)
            .unwrap();
            let t = stitch(&top, &hl).unwrap();
            assert_valid("forest", &t, &prims, 8);
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        /// A top tree from any builder, over cells of any level, stitches to a valid tree.
        #[test]
        fn any_top_over_any_cells_stitches_to_a_valid_tree(
            n in 0usize..1500,
            seed: u64,
            t in 0u32..31,
            which in 0usize..4,
            max_leaf in 1u32..5,
        ) {
            let prims = soup(n, 3.0, seed);
            let hl = HlbvhBuilder {
                highlevel_threshold: Some(t),
                ..Default::default()
            }
            .build_highlevel(&prims)
            .unwrap();
            let boxes = root_boxes(&hl);
            let top = match which {
                0 => morton_top(&hl),
                1 => BinnedSahBuilder { max_leaf_size: max_leaf, ..Default::default() }
                    .build(&boxes)
                    .unwrap(),
                2 => SweepSahBuilder { max_leaf_size: max_leaf, ..Default::default() }
                    .build(&boxes)
                    .unwrap(),
                _ => crate::LbvhBuilder::default().build(&boxes).unwrap(),
            };
            let st = stitch(&top, &hl).unwrap();
            proptest::prop_assert_eq!(crate::validate(&st, &prims, 8), Ok(()));
            if which == 0 {
                proptest::prop_assert_eq!(st, HlbvhBuilder::default().build(&prims).unwrap());
            }
        }
    }

    #[test]
    fn stitch_rejects_a_top_tree_over_other_boxes() {
        let prims = soup(1000, 1.0, 1);
        let hl = HlbvhSahBuilder::default().highlevel(&prims).unwrap();
        let wrong = BinnedSahBuilder::default().build(&prims[..3]).unwrap();
        assert!(matches!(
            stitch(&wrong, &hl),
            Err(BuildError::InvalidConfig(_))
        ));
    }

    #[test]
    fn adversarial_inputs_give_valid_trees() {
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for combine_identical in [true, false] {
                let cfg = HlbvhSahBuilder {
                    hlbvh: HlbvhBuilder {
                        bits,
                        combine_identical,
                        ..Default::default()
                    },
                    ..Default::default()
                };
                for (name, prims) in adversarial() {
                    let t = cfg.build(&prims).unwrap();
                    assert_valid(name, &t, &prims, cfg.hlbvh.leaf_limit());
                }
            }
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let prims = proc_scene("proc:forest?n=30000");
        let b = |threads| HlbvhSahBuilder {
            threads,
            ..Default::default()
        };
        let t1 = b(1).build(&prims).unwrap();
        assert_valid("forest", &t1, &prims, 8);
        assert_eq!(t1, b(2).build(&prims).unwrap());
        assert_eq!(t1, b(0).build(&prims).unwrap());
    }

    #[test]
    fn real_scenes_give_valid_trees() {
        let Some(scenes) = real_scenes() else {
            return;
        };
        for (name, prims) in &scenes {
            let t = HlbvhSahBuilder::default().build(prims).unwrap();
            assert_valid(name, &t, prims, 8);
            let plain = HlbvhBuilder::default().build(prims).unwrap();
            assert!(t.sah() <= plain.sah(), "{name}: hlbvh+sah worse than hlbvh");
        }
    }

    /// Cell count and SAH (relative to the sweep build) of HLBVH+SAH per cell level on the
    /// real scenes, to choose [`default_threshold`]. Run by hand:
    /// `cargo test -p bvh --lib -- --ignored --nocapture hlbvh_sah_threshold_table`
    #[test]
    #[ignore]
    fn hlbvh_sah_threshold_table() {
        let Some(scenes) = real_scenes() else {
            return;
        };
        println!("| scene | hlbvh | top bits: cells / SAH ... |");
        for (name, prims) in &scenes {
            let sweep = SweepSahBuilder::default().build(prims).unwrap();
            let plain = HlbvhBuilder::default().build(prims).unwrap();
            let mut row = format!("| {name} | {:.3} |", plain.sah_vs(&sweep));
            for top_bits in [6, 9, 12, 15, 18] {
                let cfg = HlbvhSahBuilder {
                    hlbvh: HlbvhBuilder {
                        highlevel_threshold: Some(30 - top_bits),
                        ..Default::default()
                    },
                    ..Default::default()
                };
                let cells = cfg.highlevel(prims).unwrap().roots.len();
                let t = cfg.build(prims).unwrap();
                assert_valid(name, &t, prims, 8);
                row += &format!(" {top_bits}: {cells} / {:.3} |", t.sah_vs(&sweep));
            }
            println!("{row}");
        }
    }
}
