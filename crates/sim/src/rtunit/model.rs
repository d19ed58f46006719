//! The units of the accelerator and the world they share (see the module documentation
//! of [`super`] for the architecture).
//!
//! Unit ids: the ray scheduler is 0, TRV unit `i` is `1 + i`, then the IST unit, then the
//! shared node cache.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashSet, VecDeque};

use bvh::ChildRef;
use geom::{intersect_triangle_watertight, ray_aabb, Ray, RayPrecomp, Triangle};
use serde::Serialize;
use trace::sampling::Pcg32;
use trace::{cull_distance, enters_own_box, Hit};

use super::config::{RtConfig, TRIANGLE_BYTES};
use super::tree::TreeImage;
use crate::dram::{AccessKind, MemRequest};
use crate::kernel::{
    Access, Cache, Ctx, Cycle, LatencyFifo, Memory, Offer, RoundRobin, State, Unit, UnitId, Wake,
    World,
};

/// What a ray does at its next pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Next {
    /// Fetch and test inner node `n` (TRV).
    Fetch(u32),
    /// Pop the stack (TRV, after the IST unit returned the ray).
    Pop,
    /// Test the triangles of a leaf (IST).
    Ist { first: u32, count: u32 },
    /// Traversal has ended.
    Done,
}

/// A ray slot: the ray, its stack (held by its TRV unit) and its progress.
#[derive(Clone, Debug)]
pub(crate) struct Slot {
    pub ray: Ray,
    pub pre: RayPrecomp,
    pub best: Option<Hit>,
    pub best_t: f32,
    /// The stack: children still to visit with their entry distances.
    pub stack: Vec<(ChildRef, f32)>,
    pub next: Next,
    /// Triangles of the current leaf already tested.
    pub ist_pos: u32,
    pub pixel: u32,
    pub bounce: u8,
    pub rng: Pcg32,
    /// The ray belongs to a timed tile (its misses and its path are counted).
    pub counted: bool,
}

/// One finished ray: which pixel and bounce, and its closest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayResult {
    /// Pixel index (`y * width + x`).
    pub pixel: u32,
    /// 0 for the primary ray, `k` for bounce `k`.
    pub bounce: u8,
    /// The closest hit.
    pub hit: Option<Hit>,
}

/// Where rays come from: the camera pixels to trace and how paths continue.
pub(crate) struct RaySource<'a> {
    pub camera: &'a trace::PinholeCamera,
    /// The tiles in issue order and what to do with each (sampled runs).
    pub plan: super::Plan,
    pub bounces: u32,
    pub seed: u64,
    pub triangles: &'a [Triangle],
    /// The tree's root node.
    pub root: u32,
}

impl<'a> RaySource<'a> {
    /// The rays of `work` over a tree whose root is `root`, issued as `plan` says.
    pub fn new(work: &super::Workload<'a>, root: u32, plan: super::Plan) -> Self {
        Self {
            camera: work.camera,
            plan,
            bounces: match work.rays {
                super::RayMode::Primary => 0,
                super::RayMode::Diffuse => work.bounces,
            },
            seed: work.seed,
            triangles: work.triangles,
            root,
        }
    }

    pub fn primary(&self, pixel: u32) -> Slot {
        let w = self.camera.width();
        let ray = self.camera.pixel_ray(pixel % w, pixel / w);
        Slot::new(
            ray,
            pixel,
            0,
            Pcg32::new(self.seed, pixel as u64),
            self.root,
        )
    }

    /// The next ray of the path of `s` after its closest hit, as the renderer makes it.
    pub fn bounce(&self, s: &Slot) -> Option<Slot> {
        let h = s.best?;
        if (s.bounce as u32) >= self.bounces {
            return None;
        }
        let tri = &self.triangles[h.prim as usize];
        let n = trace::facing_normal(tri, s.ray.dir);
        if n == geom::Vec3::ZERO {
            return None;
        }
        let mut rng = s.rng.clone();
        let ray = trace::bounce_ray(tri, n, &h, &mut rng);
        let mut next = Slot::new(ray, s.pixel, s.bounce + 1, rng, self.root);
        next.counted = s.counted;
        Some(next)
    }
}

impl Slot {
    /// An unused slot.
    pub fn placeholder() -> Self {
        Self::new(
            Ray::new(geom::Vec3::ZERO, geom::Vec3::Z),
            0,
            0,
            Pcg32::new(0, 0),
            0,
        )
    }

    fn new(ray: Ray, pixel: u32, bounce: u8, rng: Pcg32, root: u32) -> Self {
        let finite = geom::is_finite3(ray.origin) && geom::is_finite3(ray.dir);
        Self {
            pre: RayPrecomp::new(&ray),
            best: None,
            best_t: ray.t_max,
            stack: Vec::new(),
            next: if finite {
                Next::Fetch(root)
            } else {
                Next::Done
            },
            ist_pos: 0,
            ray,
            pixel,
            bounce,
            rng,
            counted: true,
        }
    }

    fn continue_with(c: ChildRef) -> Next {
        if c.is_leaf() {
            Next::Ist {
                first: c.index,
                count: c.count,
            }
        } else {
            Next::Fetch(c.index)
        }
    }

    /// Pops the stack: with the distance stack, entries beyond the closest hit are
    /// dropped in the same pass. Returns the entries dropped (the pass's extra cycles are
    /// [`RtConfig::cull_cycles_per_entry`] each, charged by the TRV unit).
    fn pop(&mut self, distance_stack: bool) -> u64 {
        let cull = cull_distance(self.best_t);
        let mut culled = 0;
        self.next = loop {
            match self.stack.pop() {
                None => break Next::Done,
                Some((_, t)) if distance_stack && t > cull => culled += 1,
                Some((c, _)) => break Self::continue_with(c),
            }
        };
        culled
    }
}

/// A stack that outgrew its storage.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Overflow {
    pub pixel: u32,
    pub bounce: u8,
    pub depth: usize,
}

/// Everything the units share.
pub(crate) struct RtWorld<'a> {
    pub mem: Memory,
    pub tree: &'a TreeImage,
    /// The software tracer over the same tree (functional warming of sampled runs).
    pub accel: &'a trace::Accel,
    pub source: RaySource<'a>,
    pub progress: Option<&'a dyn Fn(u64, u64)>,
    pub slots: Vec<Slot>,
    /// Per TRV: new rays from the scheduler, rays to the IST unit, rays back from it,
    /// finished rays, L1 misses to the shared node cache, fills from it.
    pub new_ray: Vec<LatencyFifo<u32>>,
    pub to_ist: Vec<LatencyFifo<u32>>,
    pub from_ist: Vec<LatencyFifo<u32>>,
    pub done: Vec<LatencyFifo<u32>>,
    pub miss: Vec<LatencyFifo<(u64, bool)>>,
    pub fill: Vec<LatencyFifo<u64>>,
    /// The L1 node cache of each TRV unit, the shared node cache, the primitive cache.
    pub l1: Vec<Cache<u32>>,
    pub l2: Cache<u32>,
    pub prim: Cache<u32>,
    /// Finished rays, in the order they finished (every ray simulated in detail).
    pub results: Vec<RayResult>,
    /// Camera pixels simulated in detail, in issue order.
    pub issued: Vec<u32>,
    /// DRAM bytes fetched for misses of counted rays.
    pub counted_bytes: u64,
    /// Line addresses fetched from DRAM (or read by functional warming) so far in the run.
    pub fetched: HashSet<u64>,
    /// `counted_bytes` split into first touches and re-fetches, nodes and triangles.
    pub split: TrafficSplit,
    /// Sampled runs: rays retired and cycles within the measurement windows (from the
    /// first retired counted ray of a timed chunk to its last).
    pub window_rays: u64,
    pub window_cycles: u64,
    /// Each window of a sampled run, in order, with the timed work since the previous
    /// one closed (`super::sampling`).
    pub windows: Vec<super::sampling::Window>,
    /// Node visits and triangle tests of counted rays.
    pub counted_visits: u64,
    pub counted_tests: u64,
    /// The counted pixels, rays, bytes, visits and tests when the last window closed.
    pub window_base: [u64; 5],
    /// Rays of counted paths retired.
    pub counted_rays: u64,
    /// Camera pixels of counted paths.
    pub counted_pixels: u64,
    pub overflow: Option<Overflow>,
    /// Set when no ray has finished for `livelock_cycles`: every unit stops.
    pub livelock: Option<Cycle>,
    pub last_finish: Cycle,
    pub livelock_cycles: Cycle,
    pub max_depth: usize,
    pub stack_entries: usize,
    pub distance_stack: bool,
}

/// DRAM bytes fetched for misses of counted rays, split by what the line holds (nodes or
/// triangles) and by whether the run fetched it before: a *first touch* is a line's first
/// fetch in the run (lines read by functional warming count as fetched), a *re-fetch* is a
/// later fetch of a line that was evicted meanwhile. The four sum to `counted_dram_bytes`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct TrafficSplit {
    /// Node lines fetched for the first time.
    pub node_first_bytes: u64,
    /// Node lines fetched again after eviction.
    pub node_refetch_bytes: u64,
    /// Triangle lines fetched for the first time.
    pub triangle_first_bytes: u64,
    /// Triangle lines fetched again after eviction.
    pub triangle_refetch_bytes: u64,
}

impl TrafficSplit {
    /// The sum of the four.
    pub fn total(&self) -> u64 {
        self.node_first_bytes
            + self.node_refetch_bytes
            + self.triangle_first_bytes
            + self.triangle_refetch_bytes
    }
}

/// Records the DRAM fetch of `lines` (line addresses of `line_bytes` each): marks them
/// fetched and, for a counted ray, adds their bytes to the first-touch or re-fetch count of
/// nodes (`node`) or triangles.
pub(crate) fn record_fetch(
    fetched: &mut HashSet<u64>,
    split: &mut TrafficSplit,
    lines: &[Option<u64>; 2],
    line_bytes: u32,
    node: bool,
    counted: bool,
) {
    for &line in lines.iter().flatten() {
        let first = fetched.insert(line);
        if !counted {
            continue;
        }
        let b = line_bytes as u64;
        match (node, first) {
            (true, true) => split.node_first_bytes += b,
            (true, false) => split.node_refetch_bytes += b,
            (false, true) => split.triangle_first_bytes += b,
            (false, false) => split.triangle_refetch_bytes += b,
        }
    }
}

/// Marks every line of `line_bytes` that `[addr, addr + bytes)` covers as fetched.
fn mark_lines(fetched: &mut HashSet<u64>, addr: u64, bytes: u32, line_bytes: u32) {
    let lb = line_bytes.max(1) as u64;
    let mut line = addr / lb * lb;
    while line < addr + bytes.max(1) as u64 {
        fetched.insert(line);
        line += lb;
    }
}

impl World for RtWorld<'_> {
    fn memory(&mut self) -> Option<&mut Memory> {
        Some(&mut self.mem)
    }

    fn describe(&self) -> String {
        let occ = |v: &[LatencyFifo<u32>]| {
            v.iter()
                .map(|f| f.len().to_string())
                .collect::<Vec<_>>()
                .join("/")
        };
        format!(
            "fifo occupancy sched->trv {}, trv->ist {}, ist->trv {}, trv->sched {}; {:?}",
            occ(&self.new_ray),
            occ(&self.to_ist),
            occ(&self.from_ist),
            occ(&self.done),
            self.mem
        )
    }
}

/// True when the run must stop because no ray has finished for the livelock limit
/// (rays looping without end: caches too small to keep a line until its ray returns).
fn stop_on_livelock(w: &mut RtWorld<'_>, now: Cycle) -> bool {
    if w.livelock.is_none() && now > w.last_finish + w.livelock_cycles {
        w.livelock = Some(now);
    }
    w.livelock.is_some()
}

/// The TRV unit owning slot `s`.
#[inline]
pub(crate) fn trv_of(s: u32, stacks_per_trv: u32) -> usize {
    (s / stacks_per_trv) as usize
}

// ---------------------------------------------------------------------------------------
// Ray scheduler
// ---------------------------------------------------------------------------------------

/// Hands free ray slots to new rays (camera rays, and the next bounce of a finished
/// diffuse ray, which has priority) and collects finished rays: one ray in and one out
/// per cycle.
pub(crate) struct Scheduler {
    next_pixel: usize,
    /// Tile of `next_pixel`.
    tile: usize,
    /// Paths of timed tiles in flight.
    counted_in_flight: usize,
    /// Cycle the open measurement window started (sampled runs).
    window: Option<(Cycle, u64)>,
    /// Index in `plan.pixels` after the last timed tile.
    timed_end: usize,
    free: Vec<Vec<u32>>,
    reissue: VecDeque<u32>,
    stacks_per_trv: u32,
    issue_rr: usize,
    done_rr: RoundRobin,
    in_flight: usize,
    rays: u64,
    warm_rr: usize,
    warm_rays: u64,
    stack: trace::TraversalStack,
}

impl Scheduler {
    pub fn new(cfg: &RtConfig, plan: &super::Plan) -> Self {
        let n = cfg.trv_units as usize;
        let timed_end = (0..plan.tiles.len())
            .rev()
            .find(|&i| plan.tiles[i].1 == super::TileMode::Timed)
            .map_or(0, |i| {
                plan.tiles.get(i + 1).map_or(plan.pixels.len(), |t| t.0)
            });
        let free = (0..n as u32)
            .map(|t| {
                (0..cfg.stacks_per_trv)
                    .rev()
                    .map(|k| t * cfg.stacks_per_trv + k)
                    .collect()
            })
            .collect();
        Self {
            next_pixel: 0,
            tile: 0,
            counted_in_flight: 0,
            window: None,
            timed_end,
            free,
            reissue: VecDeque::new(),
            stacks_per_trv: cfg.stacks_per_trv,
            issue_rr: 0,
            done_rr: RoundRobin::new(n, 1).expect("at least one TRV"),
            in_flight: 0,
            rays: 0,
            warm_rr: 0,
            warm_rays: 0,
            stack: trace::TraversalStack::new(),
        }
    }
}

impl Scheduler {
    /// Moves the cursor over what need not be simulated in detail: with no ray of a timed
    /// chunk in flight, the gap tiles up to the next lead tiles are warmed functionally
    /// (now, so no counted ray sees lines warmed by pixels after it), and after the last
    /// timed tile nothing more is issued.
    fn advance(&mut self, w: &mut RtWorld<'_>) {
        let plan_len = w.source.plan.pixels.len();
        while let Some(&(start, _)) = w.source.plan.tiles.get(self.tile + 1) {
            if self.next_pixel < start {
                break;
            }
            self.tile += 1;
        }
        if self.counted_in_flight > 0 || self.next_pixel >= plan_len {
            return;
        }
        if self.next_pixel >= self.timed_end {
            self.next_pixel = plan_len;
            return;
        }
        let first = self.next_pixel;
        while w.source.plan.tiles.get(self.tile).map(|t| t.1) == Some(super::TileMode::Gap) {
            self.tile += 1;
            self.next_pixel = w.source.plan.tiles.get(self.tile).map_or(plan_len, |t| t.0);
        }
        if self.next_pixel > first {
            let pixels = w.source.plan.pixels[first..self.next_pixel].to_vec();
            self.warm_rays += warm(w, &pixels, &mut self.warm_rr, &mut self.stack);
        }
    }
}

const SCHED_STALLS: &[&str] = &["trv_full"];

impl<'a> Unit<RtWorld<'a>> for Scheduler {
    fn name(&self) -> &str {
        "scheduler"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        SCHED_STALLS
    }

    fn step(&mut self, w: &mut RtWorld<'a>, cx: &mut Ctx) -> Wake {
        if w.livelock.is_some() {
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        let mut worked = false;
        // One finished ray per cycle.
        let (source, reissue, free, spt) = (
            &w.source,
            &mut self.reissue,
            &mut self.free,
            self.stacks_per_trv,
        );
        let mut finished = 0;
        let mut retired: Option<(bool, bool)> = None;
        let (done, slots, results) = (&mut w.done, &mut w.slots, &mut w.results);
        self.done_rr.arbitrate(|t| {
            let Some(s) = done[t].pop(cx) else {
                return Offer::Nothing;
            };
            let slot = &slots[s as usize];
            results.push(RayResult {
                pixel: slot.pixel,
                bounce: slot.bounce,
                hit: slot.best,
            });
            let counted = slot.counted;
            finished += 1;
            match source.bounce(slot) {
                Some(next) => {
                    slots[s as usize] = next;
                    reissue.push_back(s);
                    retired = Some((counted, false));
                }
                None => {
                    free[trv_of(s, spt)].push(s);
                    retired = Some((counted, true));
                }
            }
            Offer::Granted
        });
        if let Some((counted, path_ended)) = retired {
            worked = true;
            self.in_flight -= finished;
            w.last_finish = cx.now();
            let now = cx.now();
            if counted {
                w.counted_rays += 1;
                if path_ended {
                    self.counted_in_flight -= 1;
                }
                if self.window.is_none() {
                    self.window = Some((now, 0));
                }
            }
            if let Some((start, rays)) = self.window.as_mut() {
                *rays += 1;
                // The chunk is over when no timed ray is in flight and the cursor is not
                // inside a timed tile (looked up only then, not on every retire).
                let in_timed = || {
                    if self.next_pixel >= w.source.plan.pixels.len() {
                        return false; // every pixel issued
                    }
                    let tiles = &w.source.plan.tiles;
                    let at = tiles
                        .partition_point(|t| t.0 <= self.next_pixel)
                        .saturating_sub(1);
                    tiles
                        .get(at)
                        .is_some_and(|t| t.1 == super::TileMode::Timed && self.next_pixel > t.0)
                };
                if self.counted_in_flight == 0 && !in_timed() {
                    w.window_rays += *rays;
                    w.window_cycles += now + 1 - *start;
                    // The timed work since the previous window closed.
                    let totals = [
                        w.counted_pixels,
                        w.counted_rays,
                        w.counted_bytes,
                        w.counted_visits,
                        w.counted_tests,
                    ];
                    let before = std::mem::replace(&mut w.window_base, totals);
                    w.windows.push(super::sampling::Window {
                        pixels: totals[0] - before[0],
                        rays: totals[1] - before[1],
                        window_rays: *rays,
                        cycles: now + 1 - *start,
                        bytes: totals[2] - before[2],
                        visits: totals[3] - before[3],
                        tests: totals[4] - before[4],
                    });
                    self.window = None;
                }
            }
        }
        // One new ray per cycle: a next bounce first, else a camera ray.
        let mut blocked = false;
        if let Some(&s) = self.reissue.front() {
            let t = trv_of(s, spt);
            if w.new_ray[t].push(cx, s).is_ok() {
                self.reissue.pop_front();
                self.in_flight += 1;
                self.rays += 1;
                worked = true;
            } else {
                blocked = true;
            }
        } else {
            self.advance(w);
            let n = if self.next_pixel < w.source.plan.pixels.len() {
                self.free.len()
            } else {
                0
            };
            let mut any_free = false;
            for k in 0..n {
                let t = (self.issue_rr + k) % n;
                if self.free[t].is_empty() {
                    continue;
                }
                any_free = true;
                if w.new_ray[t].is_full(cx) {
                    continue;
                }
                let s = self.free[t].pop().expect("checked");
                let pixel = w.source.plan.pixels[self.next_pixel];
                let mut slot = w.source.primary(pixel);
                slot.counted = w.source.plan.tiles[self.tile].1 == super::TileMode::Timed;
                if slot.counted {
                    self.counted_in_flight += 1;
                    w.counted_pixels += 1;
                }
                w.slots[s as usize] = slot;
                w.issued.push(pixel);
                w.new_ray[t].push(cx, s).expect("checked not full");
                self.next_pixel += 1;
                if let Some(p) = w.progress {
                    let total = w.source.plan.pixels.len();
                    if self.next_pixel.is_multiple_of(4096) || self.next_pixel == total {
                        p(self.next_pixel as u64, total as u64);
                    }
                }
                self.in_flight += 1;
                self.rays += 1;
                self.issue_rr = (t + 1) % n;
                worked = true;
                break;
            }
            blocked = any_free && !worked;
        }
        cx.set_state(if worked {
            State::Busy
        } else if blocked {
            State::Stalled(0)
        } else {
            State::Idle
        });
        self.advance(w);
        let pixels_left = self.next_pixel < w.source.plan.pixels.len();
        let more_in =
            !self.reissue.is_empty() || (pixels_left && self.free.iter().any(|f| !f.is_empty()));
        let done_visible = w.done.iter().any(|f| f.can_pop(cx));
        let all_done = !more_in && self.in_flight == 0 && !pixels_left;
        if all_done {
            Wake::Done
        } else if worked || done_visible || (more_in && !blocked) {
            Wake::Next
        } else {
            Wake::OnEvent
        }
    }

    fn describe(&self, w: &RtWorld<'a>) -> String {
        format!(
            "{} rays in flight, {} of {} camera rays issued, {} bounces waiting",
            self.in_flight,
            self.next_pixel,
            w.source.plan.pixels.len(),
            self.reissue.len()
        )
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("rays", self.rays), ("warming_rays", self.warm_rays)]
    }
}

/// Functional warming: traces the paths of `pixels` with the software tracer and reads
/// every node and triangle they touch into the caches ([`Cache::warm`]: no time, no
/// counts), each path through the L1 of the next TRV unit in turn. A node found in the L1
/// does not reach the shared node cache, as in the timed model. Returns the rays traced.
fn warm(
    w: &mut RtWorld<'_>,
    pixels: &[u32],
    rr: &mut usize,
    stack: &mut trace::TraversalStack,
) -> u64 {
    struct Toucher<'c> {
        l1: &'c mut Cache<u32>,
        l2: &'c mut Cache<u32>,
        prim: &'c mut Cache<u32>,
        tree: &'c TreeImage,
        node_bytes: u32,
        fetched: &'c mut HashSet<u64>,
    }
    impl trace::Observer for Toucher<'_> {
        fn node(&mut self, node: u32, _valid: u8, _hit: u8) {
            let a = self.tree.node_addr(node);
            if !self.l1.warm(a, self.node_bytes) {
                self.l2.warm(a, self.node_bytes);
            }
            let lb = self.l2.config().line_bytes;
            mark_lines(self.fetched, a, self.node_bytes, lb);
        }
        fn leaf(&mut self, first: u32, count: u32) {
            let lb = self.prim.config().line_bytes;
            for e in first..first + count {
                let a = self.tree.triangle_addr(e);
                self.prim.warm(a, TRIANGLE_BYTES);
                mark_lines(self.fetched, a, TRIANGLE_BYTES, lb);
            }
        }
    }
    let mut stats = trace::RayStats::default();
    let mut rays = 0;
    let n = w.l1.len();
    for &p in pixels {
        let trv = *rr % n;
        *rr += 1;
        let mut t = Toucher {
            l1: &mut w.l1[trv],
            l2: &mut w.l2,
            prim: &mut w.prim,
            tree: w.tree,
            node_bytes: w.tree.node_bytes(),
            fetched: &mut w.fetched,
        };
        let mut slot = Some(w.source.primary(p));
        while let Some(mut s) = slot.take() {
            s.best = trace::Traverse::trace_observed(
                w.accel,
                &s.ray,
                trace::Query::Closest,
                stack,
                &mut stats,
                &mut t,
            );
            rays += 1;
            slot = w.source.bounce(&s);
        }
    }
    rays
}

// ---------------------------------------------------------------------------------------
// TRV unit
// ---------------------------------------------------------------------------------------

/// A traversal unit: an in-order pipeline of `depth` stages that takes one ray per cycle
/// (a recirculating ray first, then a ray back from the IST unit, then a new ray), reads
/// its node from the L1 node cache in the first stage, tests the node's children, sorts
/// the hits and performs the stack operations. A ray whose node misses loops through the
/// pipeline with its results invalidated and tries again ("looping for next chance").
///
/// Time inside the pipeline runs on a clock that stops while the pipeline stalls
/// (`vt = now - stalled`): a head that cannot leave for its FIFO freezes every stage and
/// the entrance ([`RtConfig::trv_block_stalls`]). A pop that culls `k` distance-stack
/// entries holds the first stage for `k * cull_cycles_per_entry` more cycles: nothing
/// enters meanwhile and the ray leaves that much later.
pub(crate) struct Trv {
    pub index: usize,
    name: String,
    /// Rays in the pipeline, with the pipeline-clock cycle they leave it.
    pipe: VecDeque<(Cycle, u32)>,
    depth: Cycle,
    /// Cycles the pipeline has stood still (blocked head).
    stalled: Cycle,
    /// The cycle the head was last found blocked (its stall is counted at the next step).
    blocked_at: Option<Cycle>,
    /// Pipeline-clock cycle from which the first stage takes a ray again.
    entry_free: Cycle,
    block_stalls: bool,
    fill_ports: u32,
    cull_cost: Cycle,
    scratch: Vec<crate::kernel::cache::Ready<u32>>,
    visits: u64,
    pops: u64,
    loops: u64,
    box_tests: u64,
    pushes: u64,
    culled: u64,
}

impl Trv {
    pub fn new(index: usize, depth: Cycle, cfg: &RtConfig) -> Self {
        Self {
            index,
            name: format!("trv{index}"),
            pipe: VecDeque::new(),
            depth,
            stalled: 0,
            blocked_at: None,
            entry_free: 0,
            block_stalls: cfg.trv_block_stalls,
            fill_ports: cfg.fill_ports,
            cull_cost: cfg.cull_cycles_per_entry,
            scratch: Vec::new(),
            visits: 0,
            pops: 0,
            loops: 0,
            box_tests: 0,
            pushes: 0,
            culled: 0,
        }
    }
}

const TRV_STALLS: &[&str] = &["loop", "ist_full", "done_full", "miss_fifo_full"];

/// The node visit: tests the children of `node` against the ray within the cull distance,
/// continues with the nearest hit child and pushes the others, farthest first (the
/// compare-and-swap of the BVH unit, the sorting network of the MBVH4 unit).
/// Returns the box tests, the stack pushes and the entries a pop culled (a node with no
/// hit child pops in the same pass).
fn visit(w: &mut RtWorld<'_>, s: u32, node: u32) -> (u64, u64, u64) {
    let (tree, dist, cap) = (w.tree, w.distance_stack, w.stack_entries);
    let slot = &mut w.slots[s as usize];
    let cull = cull_distance(slot.best_t);
    let mut hits: [(f32, ChildRef); 4] = [(0.0, ChildRef::EMPTY); 4];
    let mut n = 0;
    let tests = tree.for_children(node, |b, c| {
        if let Some(t) = ray_aabb(&slot.pre, b, slot.ray.t_min, cull) {
            hits[n] = (t, c);
            n += 1;
        }
    });
    // Stable by distance: equal distances keep the child order.
    hits[..n].sort_by(|a, b| a.0.total_cmp(&b.0));
    let pushes = n.saturating_sub(1) as u64;
    let mut culled = 0;
    if n == 0 {
        culled = slot.pop(dist);
    } else {
        for &(t, c) in hits[1..n].iter().rev() {
            slot.stack.push((c, t));
        }
        slot.next = Slot::continue_with(hits[0].1);
        let depth = slot.stack.len();
        w.max_depth = w.max_depth.max(depth);
        if depth > cap && w.overflow.is_none() {
            w.overflow = Some(Overflow {
                pixel: slot.pixel,
                bounce: slot.bounce,
                depth,
            });
        }
    }
    (tests, pushes, culled)
}

impl<'a> Unit<RtWorld<'a>> for Trv {
    fn name(&self) -> &str {
        &self.name
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        TRV_STALLS
    }

    fn step(&mut self, w: &mut RtWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        let i = self.index;
        if stop_on_livelock(w, now) {
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        // The cycles since the head was found blocked stood still (the head was blocked
        // in each: nothing it waits on changed, or this unit would have been stepped).
        if let Some(b) = self.blocked_at.take() {
            self.stalled += now - b;
        }
        let vt = now - self.stalled;
        let mut installed = 0;
        while self.fill_ports == 0 || installed < self.fill_ports {
            let Some(line) = w.fill[i].pop(cx) else {
                break;
            };
            self.scratch.clear();
            w.l1[i]
                .fill(line, now, &mut self.scratch)
                .expect("the L1 fetched this line");
            installed += 1;
        }
        let mut state = State::Idle;
        // The pipeline's exit: a ray for the IST unit or a finished one leaves.
        let mut blocked_exit = false;
        if let Some(&(t, s)) = self.pipe.front() {
            if t <= vt {
                let out = match w.slots[s as usize].next {
                    Next::Ist { .. } => Some((&mut w.to_ist[i], 1u8)),
                    Next::Done => Some((&mut w.done[i], 2u8)),
                    _ => None,
                };
                if let Some((fifo, reason)) = out {
                    if fifo.push(cx, s).is_ok() {
                        self.pipe.pop_front();
                    } else {
                        blocked_exit = true;
                        state = State::Stalled(reason);
                    }
                }
            }
        }
        let frozen = blocked_exit && self.block_stalls;
        if frozen {
            self.blocked_at = Some(now);
        }
        // The pipeline's entrance: closed while the pipeline stands still or the first
        // stage is still culling.
        let entry_busy = vt < self.entry_free;
        let entering = if frozen || entry_busy {
            None
        } else if matches!(self.pipe.front(), Some(&(t, s)) if t <= vt
            && matches!(w.slots[s as usize].next, Next::Fetch(_) | Next::Pop))
        {
            self.pipe.pop_front().map(|(_, s)| s)
        } else if let Some(s) = w.from_ist[i].pop(cx) {
            w.slots[s as usize].next = Next::Pop;
            Some(s)
        } else {
            w.new_ray[i].pop(cx)
        };
        if entry_busy && !frozen && state == State::Idle {
            state = State::Busy;
        }
        if let Some(s) = entering {
            let mut culled = 0;
            match w.slots[s as usize].next {
                Next::Pop => {
                    culled = w.slots[s as usize].pop(w.distance_stack);
                    self.pops += 1;
                    state = State::Busy;
                }
                Next::Fetch(node) => {
                    let addr = w.tree.node_addr(node);
                    let present = w.l1[i].contains(addr);
                    if !present && w.miss[i].is_full(cx) {
                        self.loops += 1;
                        state = State::Stalled(3);
                    } else {
                        match w.l1[i].access(addr, w.tree.node_bytes(), AccessKind::Read, None, now)
                        {
                            Access::Hit { .. } => {
                                let (tests, pushes, c) = visit(w, s, node);
                                self.box_tests += tests;
                                self.pushes += pushes;
                                self.visits += 1;
                                w.counted_visits += w.slots[s as usize].counted as u64;
                                culled = c;
                                state = State::Busy;
                            }
                            Access::Miss { fetch } => {
                                let counted = w.slots[s as usize].counted;
                                for line in fetch.into_iter().flatten() {
                                    w.miss[i]
                                        .push(cx, (line, counted))
                                        .expect("checked not full");
                                }
                                self.loops += 1;
                                state = State::Stalled(0);
                            }
                            _ => {
                                self.loops += 1;
                                state = State::Stalled(0);
                            }
                        }
                    }
                }
                Next::Ist { .. } | Next::Done => unreachable!("rays enter to fetch or pop"),
            }
            self.culled += culled;
            let extra = culled * self.cull_cost;
            self.entry_free = vt + 1 + extra;
            self.pipe.push_back((vt + extra + self.depth, s));
        }
        cx.set_state(state);
        let more_fills = w.fill[i].can_pop(cx);
        let rays_in = w.from_ist[i].can_pop(cx) || w.new_ray[i].can_pop(cx);
        // A pass this cycle: step next cycle too, to report the state of that cycle.
        let passed = entering.is_some();
        if passed || more_fills || (rays_in && !frozen && self.entry_free <= vt + 1) {
            return Wake::Next;
        }
        if frozen {
            // Until the FIFO the head waits on is popped (or a ray arrives, above).
            return Wake::OnEvent;
        }
        // In real cycles (the pipeline runs until something blocks it again).
        let entry_at = (self.entry_free > vt).then(|| self.entry_free + self.stalled);
        match self.pipe.front() {
            Some(&(t, s)) if t <= vt => {
                if blocked_exit {
                    Wake::OnEvent
                } else if matches!(w.slots[s as usize].next, Next::Fetch(_) | Next::Pop) {
                    // A head waiting for the first stage to finish culling.
                    Wake::At(entry_at.unwrap_or(now + 1).max(now + 1))
                } else {
                    Wake::Next
                }
            }
            Some(&(t, _)) => {
                let head = t + self.stalled;
                Wake::At(entry_at.map_or(head, |e| e.min(head)).max(now + 1))
            }
            None => match entry_at {
                Some(e) => Wake::At(e.max(now + 1)),
                None => Wake::Done,
            },
        }
    }

    fn describe(&self, w: &RtWorld<'a>) -> String {
        format!(
            "{} rays in the pipeline, head {:?}, stalled {} cycles",
            self.pipe.len(),
            self.pipe
                .front()
                .map(|&(t, s)| (t + self.stalled, w.slots[s as usize].next)),
            self.stalled
        )
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![
            ("node_visits", self.visits),
            ("box_tests", self.box_tests),
            ("pushes", self.pushes),
            ("pops", self.pops),
            ("loops", self.loops),
            ("culled", self.culled),
            ("stalled_cycles", self.stalled),
        ]
    }
}

// ---------------------------------------------------------------------------------------
// IST unit
// ---------------------------------------------------------------------------------------

/// The intersection unit: takes rays from the TRV units (round robin, one per cycle) into
/// its ray buffer, starts one triangle test per cycle (the buffer's head ray, triangle by
/// triangle) reading 48-byte triangles from the two-bank primitive cache, and returns a
/// ray to its TRV unit `depth` cycles after its last test. A triangle that misses sends
/// its ray around the pipeline again.
pub(crate) struct Ist {
    ready: VecDeque<u32>,
    looping: VecDeque<(Cycle, u32)>,
    out: VecDeque<(Cycle, u32)>,
    mem_q: VecDeque<u64>,
    rr: RoundRobin,
    capacity: usize,
    depth: Cycle,
    line: u32,
    fill_ports: u32,
    stacks_per_trv: u32,
    scratch: Vec<crate::kernel::cache::Ready<u32>>,
    tests: u64,
    loops: u64,
}

impl Ist {
    pub fn new(cfg: &RtConfig) -> Self {
        Self {
            line: cfg.prim_line_bytes,
            fill_ports: cfg.fill_ports,
            ready: VecDeque::new(),
            looping: VecDeque::new(),
            out: VecDeque::new(),
            mem_q: VecDeque::new(),
            rr: RoundRobin::new(cfg.trv_units as usize, 1).expect("at least one TRV"),
            capacity: cfg.ist_rays as usize,
            depth: cfg.ist_stages,
            stacks_per_trv: cfg.stacks_per_trv,
            scratch: Vec::new(),
            tests: 0,
            loops: 0,
        }
    }

    fn held(&self) -> usize {
        self.ready.len() + self.looping.len() + self.out.len()
    }
}

const IST_STALLS: &[&str] = &["loop", "return_full"];

/// Sends queued line reads until the port refuses one.
fn send_lines(mem: &mut Memory, cx: &Ctx, q: &mut VecDeque<u64>, bytes: u32) {
    while let Some(&line) = q.front() {
        let r = MemRequest {
            tag: line,
            addr: line,
            bytes,
            kind: AccessKind::Read,
        };
        if mem.send(cx, r).is_err() {
            break;
        }
        q.pop_front();
    }
}

impl<'a> Unit<RtWorld<'a>> for Ist {
    fn name(&self) -> &str {
        "ist"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        IST_STALLS
    }

    fn step(&mut self, w: &mut RtWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if stop_on_livelock(w, now) {
            while w.mem.pop(cx).is_some() {}
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        let (prim, scratch) = (&mut w.prim, &mut self.scratch);
        pop_responses(&mut w.mem, cx, self.fill_ports, |r| {
            scratch.clear();
            prim.fill(r.tag, now, scratch)
                .expect("the primitive cache fetched this line");
        });
        send_lines(&mut w.mem, cx, &mut self.mem_q, self.line);
        let mut state = State::Idle;
        // Return finished rays.
        let mut return_blocked = false;
        if let Some(&(t, s)) = self.out.front() {
            if t <= now {
                let trv = trv_of(s, self.stacks_per_trv);
                if w.from_ist[trv].push(cx, s).is_ok() {
                    self.out.pop_front();
                } else {
                    return_blocked = true;
                    state = State::Stalled(1);
                }
            }
        }
        while matches!(self.looping.front(), Some(&(t, _)) if t <= now) {
            let (_, s) = self.looping.pop_front().expect("checked");
            self.ready.push_back(s);
        }
        // Take one ray from the TRV units.
        if self.held() < self.capacity {
            let (ready, to_ist) = (&mut self.ready, &mut w.to_ist);
            self.rr.arbitrate(|t| match to_ist[t].pop(cx) {
                Some(s) => {
                    ready.push_back(s);
                    Offer::Granted
                }
                None => Offer::Nothing,
            });
        }
        // One triangle test.
        if let Some(&s) = self.ready.front() {
            let Next::Ist { first, count } = w.slots[s as usize].next else {
                unreachable!("rays in the IST unit have a leaf")
            };
            let entry = first + w.slots[s as usize].ist_pos;
            let addr = w.tree.triangle_addr(entry);
            match w
                .prim
                .access(addr, TRIANGLE_BYTES, AccessKind::Read, None, now)
            {
                Access::Hit { .. } => {
                    let tri = w.tree.triangle(entry);
                    let slot = &mut w.slots[s as usize];
                    test_triangle(slot, tri, entry, w.tree.prim_of(entry));
                    slot.ist_pos += 1;
                    self.tests += 1;
                    w.counted_tests += slot.counted as u64;
                    if slot.ist_pos == count {
                        slot.ist_pos = 0;
                        self.ready.pop_front();
                        self.out.push_back((now + self.depth, s));
                    }
                    state = State::Busy;
                }
                a => {
                    if let Access::Miss { fetch } = a {
                        let counted = w.slots[s as usize].counted;
                        if counted {
                            let lines = fetch.iter().flatten().count() as u64;
                            w.counted_bytes += lines * self.line as u64;
                        }
                        record_fetch(
                            &mut w.fetched,
                            &mut w.split,
                            &fetch,
                            self.line,
                            false,
                            counted,
                        );
                        self.mem_q.extend(fetch.into_iter().flatten());
                        send_lines(&mut w.mem, cx, &mut self.mem_q, self.line);
                    }
                    self.ready.pop_front();
                    self.looping.push_back((now + self.depth, s));
                    self.loops += 1;
                    if state == State::Idle {
                        state = State::Stalled(0);
                    }
                }
            }
        }
        cx.set_state(state);
        let inputs = self.held() < self.capacity && w.to_ist.iter().any(|f| f.can_pop(cx));
        let mut wake = Cycle::MAX;
        if let Some(&(t, _)) = self.out.front() {
            if !return_blocked {
                wake = wake.min(t.max(now + 1));
            }
        }
        if let Some(&(t, _)) = self.looping.front() {
            wake = wake.min(t.max(now + 1));
        }
        let acted = matches!(state, State::Busy | State::Stalled(0));
        let responses = w.mem.has_response(cx.me());
        if acted || inputs || responses || !self.ready.is_empty() || !self.mem_q.is_empty() {
            Wake::Next
        } else if wake != Cycle::MAX {
            Wake::At(wake)
        } else if return_blocked || w.prim.mshrs_in_use() > 0 {
            Wake::OnEvent
        } else {
            Wake::Done
        }
    }

    fn describe(&self, _w: &RtWorld<'a>) -> String {
        format!(
            "{} rays ready, {} looping, {} returning, {} line reads queued",
            self.ready.len(),
            self.looping.len(),
            self.out.len(),
            self.mem_q.len()
        )
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("triangle_tests", self.tests), ("loops", self.loops)]
    }
}

/// The triangle test of the software tracer (`trace`'s leaf test): the watertight test
/// within `[t_min, closest hit]`, the hit's own box entered, the closest-hit rule.
fn test_triangle(slot: &mut Slot, tri: &Triangle, entry: u32, prim: u32) {
    let Some(h) = intersect_triangle_watertight(&slot.pre, tri, slot.ray.t_min, slot.best_t) else {
        return;
    };
    if !enters_own_box(&slot.pre, tri, slot.ray.t_min, h.t) {
        return;
    }
    let hit = Hit {
        t: h.t,
        prim,
        leaf_entry: entry,
        bary: h.bary,
    };
    if hit.beats(slot.best.as_ref()) {
        slot.best_t = hit.t;
        slot.best = Some(hit);
    }
}

// ---------------------------------------------------------------------------------------
// Shared node cache
// ---------------------------------------------------------------------------------------

/// The node cache shared by the TRV units: takes one L1 miss per cycle (round robin),
/// answers hits after its latency and misses when DRAM returns the line; requests for a
/// line already being fetched wait in its MSHR. It hands at most `l2_ports` lines per
/// cycle to the L1 fill FIFOs (the earliest ready first, ties by TRV index) and installs
/// at most `fill_ports` lines from DRAM per cycle; the others wait for later cycles.
pub(crate) struct NodeL2 {
    out: BinaryHeap<Reverse<(Cycle, u32, u64)>>,
    mem_q: VecDeque<u64>,
    rr: RoundRobin,
    line: u32,
    ports: u32,
    fill_ports: u32,
    ready: Vec<crate::kernel::cache::Ready<u32>>,
    fills: u64,
    peak_fills: u64,
}

impl NodeL2 {
    pub fn new(line: u32, trv_units: usize, cfg: &RtConfig) -> Self {
        Self {
            line,
            out: BinaryHeap::new(),
            mem_q: VecDeque::new(),
            rr: RoundRobin::new(trv_units, 1).expect("at least one TRV"),
            ports: cfg.l2_ports,
            fill_ports: cfg.fill_ports,
            ready: Vec::new(),
            fills: 0,
            peak_fills: 0,
        }
    }
}

/// Pops at most `ports` (0: any number) memory responses of the stepping unit.
fn pop_responses(
    mem: &mut Memory,
    cx: &Ctx,
    ports: u32,
    mut install: impl FnMut(crate::dram::MemResponse),
) {
    let mut n = 0;
    while ports == 0 || n < ports {
        let Some(r) = mem.pop(cx) else {
            break;
        };
        install(r);
        n += 1;
    }
}

const L2_STALLS: &[&str] = &["fill_full", "refused"];

impl<'a> Unit<RtWorld<'a>> for NodeL2 {
    fn name(&self) -> &str {
        "node_cache"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        L2_STALLS
    }

    fn step(&mut self, w: &mut RtWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if w.livelock.is_some() {
            while w.mem.pop(cx).is_some() {}
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        let (l2, ready, out) = (&mut w.l2, &mut self.ready, &mut self.out);
        pop_responses(&mut w.mem, cx, self.fill_ports, |r| {
            ready.clear();
            l2.fill(r.tag, now, ready)
                .expect("the node cache fetched this line");
            for rd in ready.iter() {
                out.push(Reverse((rd.ready_at, rd.tag, r.tag)));
            }
        });
        send_lines(&mut w.mem, cx, &mut self.mem_q, self.line);
        let mut state = State::Idle;
        let mut fill_blocked = false;
        let mut handed = 0;
        while let Some(&Reverse((t, trv, line))) = self.out.peek() {
            if t > now || (self.ports > 0 && handed >= self.ports) {
                break;
            }
            if w.fill[trv as usize].push(cx, line).is_err() {
                fill_blocked = true;
                state = State::Stalled(0);
                break;
            }
            self.out.pop();
            handed += 1;
        }
        self.fills += handed as u64;
        self.peak_fills = self.peak_fills.max(handed as u64);
        let (cache, out, mem_q, miss) = (&mut w.l2, &mut self.out, &mut self.mem_q, &mut w.miss);
        let counted_bytes = &mut w.counted_bytes;
        let (fetched, split) = (&mut w.fetched, &mut w.split);
        let line_bytes = self.line;
        let mut refused = false;
        let granted = self.rr.arbitrate(|t| {
            let Some(&(line, counted)) = miss[t].peek(cx) else {
                return Offer::Nothing;
            };
            match cache.access(
                line,
                cache.config().line_bytes,
                AccessKind::Read,
                Some(t as u32),
                now,
            ) {
                Access::Hit { ready_at } => out.push(Reverse((ready_at, t as u32, line))),
                Access::Miss { fetch } => {
                    if counted {
                        *counted_bytes += fetch.iter().flatten().count() as u64 * line_bytes as u64;
                    }
                    record_fetch(fetched, split, &fetch, line_bytes, true, counted);
                    mem_q.extend(fetch.into_iter().flatten())
                }
                Access::MergedMiss => {}
                _ => {
                    refused = true;
                    return Offer::Refused;
                }
            }
            miss[t].pop(cx);
            Offer::Granted
        });
        if granted > 0 {
            send_lines(&mut w.mem, cx, &mut self.mem_q, self.line);
            state = State::Busy;
        } else if refused {
            state = State::Stalled(1);
        }
        cx.set_state(state);
        let inputs = w.miss.iter().any(|f| f.can_pop(cx)) || w.mem.has_response(cx.me());
        match self.out.peek() {
            _ if granted > 0 || inputs || !self.mem_q.is_empty() => Wake::Next,
            Some(&Reverse((t, _, _))) if !fill_blocked => Wake::At(t.max(now + 1)),
            Some(_) => Wake::OnEvent,
            None if w.l2.mshrs_in_use() > 0 => Wake::OnEvent,
            None => Wake::Done,
        }
    }

    fn describe(&self, w: &RtWorld<'a>) -> String {
        format!(
            "{} fills waiting, {} line reads queued, {} MSHRs in use",
            self.out.len(),
            self.mem_q.len(),
            w.l2.mshrs_in_use()
        )
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![
            ("fills", self.fills),
            ("peak_fills_per_cycle", self.peak_fills),
        ]
    }
}

/// The unit ids of a world with `trv_units` TRV units: the scheduler, the TRVs, the IST
/// unit and the shared node cache, in the order the scheduler adds them.
pub(crate) fn unit_ids(trv_units: usize) -> (UnitId, Vec<UnitId>, UnitId, UnitId) {
    let trvs = (0..trv_units).map(|i| UnitId(1 + i as u32)).collect();
    (
        UnitId(0),
        trvs,
        UnitId(1 + trv_units as u32),
        UnitId(2 + trv_units as u32),
    )
}
