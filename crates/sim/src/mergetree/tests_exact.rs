//! Whole-machine runs whose cycle counts are derived by hand from the documented unit
//! rules (`machine.rs` module docs, `docs/sim-kernel.md`), step by step, and asserted
//! exactly: the project standard "timing models get exact hand-derived cycle counts for
//! small cases, not only bounds" (the bounds are `tests::timing_bounds`).
//!
//! | test | case | cycles (L = 10) |
//! |---|---|---|
//! | `one_element_one_block` | n = 1, M = 4, B = 1 | 37 = 2L + 17 |
//! | `reversed_four_elements_one_block` | n = 4 reversed, M = 8, B = 2 (insertions 1 + 2 + 3 + 4) | 60 = 2L + 40 |
//! | `one_entry_emit_fifo_loses_nothing_when_the_emitter_keeps_up` | the same, `emit_fifo` = 1 | 60 |
//! | `one_ring_slot_delays_by_a_read_round_trip` | the same, `presort_slots` = 1: the reader stalls on the ring | 72 (+ L + 2) |
//! | `one_merge_pass_two_blocks` | n = 5, M = 4, B = 1: two partial sorts, fence, one merge pass with refills | 130 |
//! | `full_emit_fifo_adds_the_cycle_the_emitter_pops_late` | n = 6, M = 12, B = 3, `emit_fifo` 64 vs 1 | 71 vs 72 |
//!
//! The DRAM-level case (a read meeting a refresh) is in `dram::lpddr::tests`.
//!
//! The memory is [`SimpleDram`] at 64 GB/s with 64-byte bursts at 1 GHz, so one burst
//! holds the bus exactly one cycle, and a fixed latency of `L = 10` ns. The rules the
//! derivations use, with where they are stated:
//!
//! - **Kernel** (`docs/sim-kernel.md`): cycle 0 steps every unit; within a cycle units step
//!   in id order (control 0, emitter 1, merger 2, reader 3, run writer 4, arbiter 5,
//!   presorter bank 6); a FIFO push at `t` is visible at `t + 1` (every MergeTree FIFO has
//!   latency 1), a slot popped at `t` is free for pushes from `t + 1`; registers
//!   (`Reg`, the control's `scratch_open`, `emit_active`, flush flags, the arbiter's
//!   `inflight`) are read from the cycle after they are set. `cycles` is one past the last
//!   cycle stepped.
//! - **Memory** (`dram/simple.rs`): a request accepted at cycle `s` (the port is at the
//!   cycle being stepped) holds the bus from `max(s, bus free)` for one cycle per 64-byte
//!   burst and completes `L` cycles after its last burst; a response completing at `c` is
//!   popped by the arbiter at `c`.
//! - **Reader**: one request per cycle into `req_read` (capacity 2), B elements each, two
//!   per sub-block, round robin over presorters; stalls while the presorter's ring
//!   (`presort_slots` buffers) has no free slot; a slot is credited back (`ps_credit`,
//!   latency 1) when its last element is taken.
//! - **Arbiter**: one grant per cycle, round robin over (run writer, node, leaf,
//!   high-level buffers, reader, CBVH) from the last winner + 1; read data goes to the
//!   presorter's `ps_data` (latency 1).
//! - **Presorter** (`presort.rs`, \[P2\] §5.5): inserting an element into a sorted prefix
//!   takes compares + 1 cycles (the first element: 1; an element smaller than all `i`
//!   before it: `i + 1`); once sorted, one element per cycle is copied to the scratchpad,
//!   and the last copy pushes `sub_ready`.
//! - **Control** (\[P1\] Fig. 2): on `sub_ready` for every sub-block of the block, it pushes
//!   the `Partial` command; on `merge_done` of the last block with no merge pass it enters
//!   the emit phase; on `emit_done` it sets the write buffers' flush flags; then it polls
//!   until every buffer was empty and nothing was in flight at the start of a cycle, and
//!   finishes in that cycle.
//! - **Merger** (`merge.rs`, \[P2\] Fig. 4): the command is taken in the cycle it is
//!   visible, and the queue heads are inserted, one per two cycles, from that cycle; then
//!   one output per two cycles.
//! - **Emitter** (`emitter.rs`, \[P2\] Algorithm 1): one step per cycle (load, push, pop with
//!   a node, the high-level root, and a last step that reports `Done`, which pushes
//!   `emit_done`); a step that needs an input waits for the FIFO; once every primitive is
//!   read the end of the stream needs no input. Each primitive adds a 4-byte leaf entry,
//!   each node 64 bytes, the root a 32-byte high-level record, to write buffers whose
//!   512-byte chunks are written out only when full or flushed.

use super::*;
use crate::dram::simple::{SimpleDram, SimpleDramConfig};
use geom::{MortonGrid, MortonQuantizer, Vec3};

/// Memory latency in cycles (ns at 1 GHz).
const L: u64 = 10;

/// SimpleDram with one 64-byte burst per cycle and latency `L`.
fn mem() -> Box<dyn MemoryPort> {
    Box::new(SimpleDram::new(SimpleDramConfig {
        peak_bytes_per_s: 64_000_000_000,
        latency_ns: L,
        ..SimpleDramConfig::lpddr3_1600_1x64_like()
    }))
}

/// A configuration with scratchpad `m`, buffers `b`, one presorter with `slots` ring
/// slots, and a trace row per cycle.
fn cfg(m: u32, b: u32, slots: u32) -> MergeTreeConfig {
    let mut c = MergeTreeConfig::p2();
    c.m = m;
    c.b = b;
    c.presorters = 1;
    c.presort_slots = slots;
    c.trace_window_cycles = 1;
    c
}

/// The cycles in which `f` of the trace row is nonzero, with its value.
fn events(r: &MergeTreeReport, f: fn(&TraceRow) -> u64) -> Vec<(u64, u64)> {
    r.trace
        .iter()
        .filter(|t| f(t) > 0)
        .map(|t| (t.cycle_start, f(t)))
        .collect()
}

/// The cycle the trace's phase first reads `name`.
fn phase_from(r: &MergeTreeReport, name: &str) -> Option<u64> {
    r.trace
        .iter()
        .find(|t| t.phase == name)
        .map(|t| t.cycle_start)
}

/// Case 1: one primitive, one block (M = 4, B = 1), no merge pass.
///
/// | cycle | what happens |
/// |---|---|
/// | 0 | the reader pushes the read of element 0 (32 bytes, one burst) |
/// | 1 | the arbiter sees it and issues it: the first read; bus 1..2, completes 2 + L = 12 |
/// | 12 | the arbiter pops the response (32 bytes on the trace) and pushes `ps_data` |
/// | 13 | the presorter inserts element 0: 0 compares + 1 = 1 cycle (busy until 14) |
/// | 14 | sorted: copies it to the scratchpad (1 element), pushes `sub_ready`: the partial sort ends |
/// | 15 | the control pops `sub_ready` and pushes `Partial` |
/// | 16 | the merger takes it and inserts the queue head (next operation at 18) |
/// | 18 | the merger outputs element 0 into `emit_fifo`, its merge is done, pushes `merge_done` |
/// | 19 | the control pops `merge_done`: phase `sort_and_emit`; the emitter loads element 0 (leaf entry, 4 bytes) |
/// | 20 | emitter: end of stream, the root to the high-level output (32 bytes) |
/// | 21 | emitter: `Done`, pushes `emit_done` |
/// | 22 | the control pops it and sets the flush flags |
/// | 23 | the arbiter sees the flush: leaf buffer first (after the reader, the last winner): 4 bytes, bus 23..24, completes 24 + L = 34 |
/// | 24 | the high-level buffer: 32 bytes, bus 24..25, completes 35 |
/// | 34, 35 | the arbiter pops the two write responses; `inflight` is 0 from the end of 35 |
/// | 36 | the control sees every buffer empty and nothing in flight: done; `cycles` = 37 = 2L + 17 |
#[test]
fn one_element_one_block() {
    let a = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
    let r = simulate(&a, &cfg(4, 1, 4), mem()).unwrap();
    assert_eq!((r.partial_sort_blocks, r.merge_passes), (1, 0));
    assert_eq!(
        events(&r, |t| t.bus_bytes),
        [(L + 2, 32), (2 * L + 14, 4), (2 * L + 15, 32)]
    );
    // Issued at 1, completed at 12.
    assert_eq!(r.phases[0].read_latency_mean_cycles, (L + 1) as f64);
    assert_eq!(
        events(&r, |t| t.presort_busy),
        [(L + 3, 1), (L + 4, 1)],
        "insertion, then the copy that ends the partial sort"
    );
    assert_eq!(events(&r, |t| t.merge_outputs), [(L + 8, 1)]);
    assert_eq!(
        events(&r, |t| t.emitter_steps),
        [(L + 9, 1), (L + 10, 1), (L + 11, 1)]
    );
    assert_eq!(phase_from(&r, "sort_and_emit"), Some(L + 9));
    assert_eq!(r.phases.len(), 1);
    assert_eq!(
        (r.phases[0].start_cycle, r.phases[0].end_cycle),
        (0, 2 * L + 16)
    );
    assert_eq!(r.cycles, 2 * L + 17);
    assert_eq!(r.cycles, 37);
}

/// Four primitives whose centroids are the corners of a square in z = 0 (distinct Morton
/// codes forming a balanced tree: the first two and the last two share their top bit),
/// in descending Morton order, so insertion sort shifts every element.
fn reversed_square() -> Vec<Aabb> {
    let e = Vec3::splat(0.01);
    let mut a: Vec<Aabb> = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
        .iter()
        .map(|&(x, y)| {
            let c = Vec3::new(x, y, 0.0);
            Aabb::new(c - e, c + e)
        })
        .collect();
    let q = MortonQuantizer::with_grid(&centroid_bounds(&a), MortonGrid::Cube);
    let code = |b: &Aabb| q.code30(b.min * 0.5 + b.max * 0.5);
    a.sort_by_key(|b| std::cmp::Reverse(code(b)));
    let codes: Vec<u32> = a.iter().map(code).collect();
    assert!(codes.windows(2).all(|w| w[0] > w[1]), "distinct: {codes:?}");
    // Balanced: the middle pair differs in a higher bit than the outer pairs.
    let lvl = |i: usize| 32 - (codes[i] ^ codes[i + 1]).leading_zeros();
    assert!(lvl(1) > lvl(0) && lvl(1) > lvl(2), "{codes:?}");
    a
}

/// Case 2: four elements in reversed Morton order, one block (M = 8, B = 2: one sub-block
/// of 4, one queue), one presorter with 4 ring slots.
///
/// | cycle | what happens |
/// |---|---|
/// | 0 | the reader pushes read 0 (elements 0, 1: 64 bytes, one burst) |
/// | 1 | the arbiter issues read 0 (the first read; bus 1..2, completes 2 + L = 12); the reader pushes read 1 (elements 2, 3) |
/// | 2 | the arbiter issues read 1 (bus 2..3, completes 13) |
/// | 12, 13 | the arbiter pops the two responses into `ps_data` (visible 13, 14) |
/// | 13 | insert e0: 0 compares + 1 = 1 cycle |
/// | 14 | insert e1 (smaller than 1 element): 1 + 1 = 2 cycles, to 16 |
/// | 16 | insert e2: 2 + 1 = 3 cycles, to 19 |
/// | 19 | insert e3: 3 + 1 = 4 cycles, to 23 (1 + 2 + 3 + 4 = 10 cycles of insertion) |
/// | 23..26 | copy 4 elements to the scratchpad; at 26 `sub_ready`: the partial sort ends |
/// | 27 | the control pushes `Partial` |
/// | 28 | the merger inserts the one queue head (next operation at 30) |
/// | 30, 32, 34, 36 | the merger outputs the four elements (one per two cycles); `merge_done` at 36 |
/// | 37 | the control enters `sort_and_emit` |
/// | 31 | emitter: load e0 |
/// | 32 | emitter: needs e1, not visible until 33: starved |
/// | 33 | push leaf 0, e1 becomes the input |
/// | 35 | reads e2 (visible 35): pop, node (e0, e1) |
/// | 36 | push node, e2 becomes the input |
/// | 37 | reads e3 (visible 37): push leaf 2 |
/// | 38, 39 | end of stream: pop, node (e2, e3); pop, the root node |
/// | 40 | the root to the high-level output |
/// | 41 | `Done`: pushes `emit_done` (9 steps) |
/// | 42 | the control sets the flush flags |
/// | 43 | nodes: 3 x 64 = 192 bytes, 3 bursts, bus 43..46, completes 46 + L = 56 |
/// | 44 | leaves: 16 bytes, bus 46..47 (behind the nodes), completes 57 |
/// | 45 | high-level: 32 bytes, bus 47..48, completes 58 |
/// | 59 | the control sees nothing in flight (the last pop at 58): done; `cycles` = 60 = 2L + 40 |
#[test]
fn reversed_four_elements_one_block() {
    let a = reversed_square();
    let r = simulate(&a, &cfg(8, 2, 4), mem()).unwrap();
    check_reversed_four(&r, L + 3, 0);
    // Starved from cycle 0 until the first data at 13.
    assert_eq!(r.stalls.presort_starved_cycles, L + 3);
    assert_eq!(r.cycles, 60);
    // The kernel's reference mode (every unit stepped every cycle) agrees.
    let mut c = cfg(8, 2, 4);
    c.fast_forward = false;
    let slow = simulate(&a, &c, mem()).unwrap();
    assert_eq!((slow.cycles, &slow.trace), (r.cycles, &r.trace));
}

/// The events of [`reversed_four_elements_one_block`] with the second read completing at
/// `read1` and everything from e2's insertion on `d` cycles later.
fn check_reversed_four(r: &MergeTreeReport, read1: u64, d: u64) {
    assert_eq!((r.partial_sort_blocks, r.merge_passes), (1, 0));
    assert_eq!(
        r.highlevel.order,
        [3, 2, 1, 0],
        "input was in reversed order"
    );
    assert_eq!(r.nodes, 3);
    assert_eq!(
        events(r, |t| t.bus_bytes),
        [
            (L + 2, 64),
            (read1, 64),
            (2 * L + 36 + d, 192),
            (2 * L + 37 + d, 16),
            (2 * L + 38 + d, 32)
        ]
    );
    // Insertion of e0 at 13, e1 at 14-15, then (d later) e2 and e3, then the copy.
    let mut busy: Vec<(u64, u64)> = vec![(L + 3, 1), (L + 4, 1), (L + 5, 1)];
    busy.extend((L + 6 + d..=L + 16 + d).map(|c| (c, 1)));
    assert_eq!(events(r, |t| t.presort_busy), busy);
    let o = L + 20 + d; // the first merge output
    assert_eq!(
        events(r, |t| t.merge_outputs),
        [(o, 1), (o + 2, 1), (o + 4, 1), (o + 6, 1)]
    );
    let steps: Vec<(u64, u64)> = [1, 3, 5, 6, 7, 8, 9, 10, 11]
        .iter()
        .map(|&k| (o + k, 1))
        .collect();
    assert_eq!(events(r, |t| t.emitter_steps), steps);
    assert_eq!(phase_from(r, "sort_and_emit"), Some(o + 7));
    assert_eq!(r.stalls.merge.output_full_cycles, 0);
    assert_eq!(
        (r.phases[0].start_cycle, r.phases[0].end_cycle),
        (0, o + 19 + L)
    );
    assert_eq!(r.cycles, o + 20 + L);
    assert_eq!(r.cycles, 2 * L + 40 + d);
}

/// Case 2 with `emit_fifo` = 1: the emitter pops each output in the cycle after it is
/// pushed (31, 33, 35, 37 for pushes at 30, 32, 34, 36), and a slot popped at t is free
/// from t + 1, so every push finds the FIFO empty: no cycle is lost, 60 cycles again.
#[test]
fn one_entry_emit_fifo_loses_nothing_when_the_emitter_keeps_up() {
    let a = reversed_square();
    let mut c = cfg(8, 2, 4);
    c.emit_fifo = 1;
    let r = simulate(&a, &c, mem()).unwrap();
    check_reversed_four(&r, L + 3, 0);
    assert_eq!(r.cycles, 60);
}

/// Case 4, a stalled queue: case 2 with one ring slot in front of the presorter
/// (`presort_slots` = 1). The reader pushes read 0 at 0 and then finds the ring full
/// (stalled). The slot is credited back when its last element is taken, by the insertion
/// of e1 at 14 (`ps_credit` visible 15); the reader pushes read 1 at 15, the arbiter issues
/// it at 16 (bus 16..17, completes 17 + L = 27), its data is visible at 28. Meanwhile e1's
/// insertion ends at 16 and the presorter starves 16..28. So everything from e2's
/// insertion on is 28 - 16 = 12 = L + 2 cycles later than in case 2: 72 cycles.
#[test]
fn one_ring_slot_delays_by_a_read_round_trip() {
    let a = reversed_square();
    let r = simulate(&a, &cfg(8, 2, 1), mem()).unwrap();
    let d = L + 2;
    check_reversed_four(&r, L + 17, d);
    // Starved 0..13 for read 0 and 16..28 for read 1.
    assert_eq!(r.stalls.presort_starved_cycles, L + 3 + d);
    assert_eq!(r.cycles, 72);
}

/// Small boxes centred at `xs` on the x axis, and their 30-bit Morton codes on the
/// presets' cube grid.
fn line_boxes(xs: &[f32]) -> (Vec<Aabb>, Vec<u32>) {
    let e = Vec3::splat(0.01);
    let a: Vec<Aabb> = xs
        .iter()
        .map(|&x| {
            let c = Vec3::new(x, 0.0, 0.0);
            Aabb::new(c - e, c + e)
        })
        .collect();
    let q = MortonQuantizer::with_grid(&centroid_bounds(&a), MortonGrid::Cube);
    let codes = a
        .iter()
        .map(|b| q.code30(b.min * 0.5 + b.max * 0.5))
        .collect();
    (a, codes)
}

/// Five primitives on the x axis (centroids x = 0, 1, 3, 7, 15), given in ascending Morton
/// order, whose consecutive codes differ in ever higher bits (a left-deep tree).
fn ascending_line() -> Vec<Aabb> {
    let (a, codes) = line_boxes(&[0.0, 1.0, 3.0, 7.0, 15.0]);
    let lvl = |i: usize| 32 - (codes[i] ^ codes[i + 1]).leading_zeros();
    assert!(
        codes.windows(2).all(|w| w[0] < w[1]) && (0..3).all(|i| lvl(i) < lvl(i + 1)),
        "{codes:?}"
    );
    a
}

/// Case 3: one merge pass. M = 4, B = 1 (two queues), one presorter with 4 ring slots,
/// n = 5 in ascending order: block 0 = sub-blocks (e0, e1), (e2, e3); block 1 = (e4).
/// Inserting the second element of a sub-block costs 1 compare + 1 = 2 cycles.
///
/// Partial sorts:
/// - reads of one element (32 bytes) pushed at 0, 1, 2, 3, issued at 1, 2, 3, 4 (the
///   first read at 1), completed at 12, 13, 14, 15; the ring is then full (4 slots);
/// - 13: insert e0 (1 cycle), its slot is credited; 14: the reader pushes read 4 (e4),
///   issued at 15, completed at 26; 14: insert e1 (2 cycles, to 16);
/// - 16, 17: copy sub-block 0; 18: insert e2; 19: insert e3 (to 21); 21, 22: copy,
///   `sub_ready` at 22; 23: insert e4 starves (data visible 27);
/// - 23: the control has both sub-blocks of block 0: `Partial`, scratchpad closed;
///   24: the merger inserts queue 0's head, 26 queue 1's; outputs at 28, 30, 32, 34 to
///   the run writer, which stages each (29, 31, 33, 35) and whose writes are issued at 30,
///   32, 34, 36 and complete at 41, 43, 45, 47; `merge_done` at 34;
/// - 27: insert e4 (1 cycle); 28: sorted, but the scratchpad is closed until the control
///   opens it for block 1 at 35 (visible 36); 36: copy e4, `sub_ready`;
/// - 37: `Partial` for block 1; 38: head insert; 40: output e4, `merge_done`; its write
///   is issued at 42 and completes at 53;
/// - 41: the control ends the partial sort (phase `merge_pass_1`, the fence) and polls
///   the acknowledged run elements; 5 of them from the end of 53, so at 54 it starts the
///   pass, which is the last: phase `merge_pass_1_and_emit`, `Multi` command.
///
/// Merge pass (queue 0: run 0 = e0..e3, queue 1: run 1 = e4):
/// - 55: the merger queues the reads of queue 0 half 0 (e0), queue 1 half 0 (e4), queue
///   0 half 1 (e1); the reader takes one per cycle (56, 57, 58), the arbiter issues them at
///   57, 58, 59; they complete at 68, 69, 70 (data visible 69, 70, 71);
/// - 69: insert queue 0's head; 71: queue 1's; 73: output e0 (its half is refilled with
///   e2: refill 73, read 74, issued 75, completes 86, visible 87);
/// - 75: e1's successor e2 is in the refilling half: queue dry until 87; 87: output e1
///   (refill with e3: issued 89, completes 100, visible 101); 89: dry until 101;
/// - 101: output e2; 103: e3 (queue 0's last); 105: e4, the merge is done.
///
/// Emitter (each output visible a cycle later; with rising levels each input is one pop
/// and one push): 74 load e0; 88 push e0; 102 pop (e0, e1); 103 push; 104 pop; 105 push;
/// 106 pop; 107 push; 108 end of stream: pop, the root; 109 the root to the high-level
/// output; 110 `Done`. 111: the control flushes; 112: nodes (4 x 64 bytes, 4 bursts, bus
/// 112..116, completes 126); 113: leaves (20 bytes, bus 116..117, 127); 114: high-level (32
/// bytes, 128). 129: drained, done: 130 cycles.
#[test]
fn one_merge_pass_two_blocks() {
    let a = ascending_line();
    let r = simulate(&a, &cfg(4, 1, 4), mem()).unwrap();
    assert_eq!((r.partial_sort_blocks, r.merge_passes), (2, 1));
    assert_eq!(r.highlevel.order, [0, 1, 2, 3, 4]);
    let bus: Vec<(u64, u64)> = [12, 13, 14, 15, 26, 41, 43, 45, 47, 53, 68, 69, 70, 86, 100]
        .iter()
        .map(|&c| (c, 32))
        .chain([(126, 256), (127, 20), (128, 32)])
        .collect();
    assert_eq!(events(&r, |t| t.bus_bytes), bus);
    let outs: Vec<(u64, u64)> = [28, 30, 32, 34, 40, 73, 87, 101, 103, 105]
        .iter()
        .map(|&c| (c, 1))
        .collect();
    assert_eq!(events(&r, |t| t.merge_outputs), outs);
    let presort: Vec<(u64, u64)> = [13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 27, 36]
        .iter()
        .map(|&c| (c, 1))
        .collect();
    assert_eq!(events(&r, |t| t.presort_busy), presort);
    let steps: Vec<(u64, u64)> = [74, 88]
        .into_iter()
        .chain(102..=110)
        .map(|c| (c, 1))
        .collect();
    assert_eq!(events(&r, |t| t.emitter_steps), steps);
    assert_eq!(phase_from(&r, "merge_pass_1"), Some(41));
    assert_eq!(phase_from(&r, "merge_pass_1_and_emit"), Some(54));
    let ph: Vec<(&str, u64, u64)> = r
        .phases
        .iter()
        .map(|p| (p.name.as_str(), p.start_cycle, p.end_cycle))
        .collect();
    assert_eq!(
        ph,
        [("partial_sort", 0, 41), ("merge_pass_1_and_emit", 41, 129)]
    );
    // Queue dry 75..87 and 89..101.
    assert_eq!(r.stalls.merge.queue_dry_cycles, 24);
    assert_eq!(r.cycles, 130);
}

/// Six primitives on the x axis at grid cells 0, 256, 384, 600, 610, 1023 (of 1024), in
/// ascending order: consecutive codes differ at cell bits 8, 7, 9, 5, 8, so e3 closes two
/// nodes at once and e5 one.
fn two_pop_line() -> Vec<Aabb> {
    let (a, codes) = line_boxes(&[0.0, 256.0, 384.0, 600.0, 610.0, 1023.0]);
    let lvl: Vec<u32> = codes
        .windows(2)
        .map(|w| 32 - (w[0] ^ w[1]).leading_zeros())
        .collect();
    // The pattern of the levels (cell bits 8, 7, 9, 5, 8 of x).
    assert!(
        lvl[1] < lvl[0] && lvl[0] < lvl[2] && lvl[3] < lvl[4] && lvl[4] == lvl[0],
        "{codes:?} {lvl:?}"
    );
    a
}

/// Case 4, a full `emit_fifo`: one block of six (M = 12, B = 3: one sub-block of 6), one
/// presorter, ascending input (insertions 1 + 5 x 2 = 11 cycles).
///
/// Common part: reads of 96 bytes (2 bursts) pushed at 0, 1, issued at 1 (bus 1..3) and
/// 2 (bus 3..5), complete at 13 and 15 (visible 14, 16); insertions 14..25 (e0 at 14, e1
/// 15-16, e2 17-18, e3 19-20, e4 21-22, e5 23-24), copies 25..30, `sub_ready` at 30;
/// `Partial` at 31; head insert at 32; outputs from o = 34 every two cycles.
///
/// Emitter steps by input (levels 8, 7, 9, 5, 8): e0 load; e1 push; e2 push; e3 pop, pop,
/// push; e4 push; e5 pop, push; end: pop, pop, high-level root, `Done` (13 steps).
///
/// With `emit_fifo` = 64: e0..e5 pushed at 34, 36, ..., 44; the emitter: 35 (e0), 37 (e1),
/// 39 (e2), 41, 42, 43 (e3), 44 (e4, visible 43), 45..50 (e5, visible 45): `emit_done` at
/// 50. `merge_done` at 44, emit phase from 45. Flush 51; nodes 5 x 64 = 320 bytes (5
/// bursts) issued 52, bus 52..57, complete 67; leaves (24 bytes) 53, bus 57..58, 68;
/// high-level 54, 69; drained at 70: 71 cycles.
///
/// With `emit_fifo` = 1: e4 is pushed at 42 (e3 was popped at 41); the emitter pops e4 at
/// 44, which frees the slot only from 45, so at 44 the merger finds the FIFO full (its
/// one output-full cycle) and pushes e5 at 45 (woken by the pop). The emitter, wanting e5
/// at 45, starves one cycle and does e5's and the end's six steps at 46..51: one cycle
/// more, 72 cycles; `merge_done` at 45, emit phase from 46.
#[test]
fn full_emit_fifo_adds_the_cycle_the_emitter_pops_late() {
    let a = two_pop_line();
    let ones = |v: &[u64]| v.iter().map(|&c| (c, 1)).collect::<Vec<_>>();
    for (fifo, late) in [(64, 0), (1, 1)] {
        let mut c = cfg(12, 3, 4);
        c.emit_fifo = fifo;
        let r = simulate(&a, &c, mem()).unwrap();
        assert_eq!(r.highlevel.order, [0, 1, 2, 3, 4, 5]);
        assert_eq!(r.nodes, 5);
        assert_eq!(
            events(&r, |t| t.bus_bytes),
            [
                (13, 96),
                (15, 96),
                (67 + late, 320),
                (68 + late, 24),
                (69 + late, 32)
            ]
        );
        assert_eq!(
            events(&r, |t| t.presort_busy),
            ones(&(14..=30).collect::<Vec<_>>())
        );
        assert_eq!(r.stalls.presort_starved_cycles, L + 4);
        assert_eq!(
            events(&r, |t| t.merge_outputs),
            ones(&[34, 36, 38, 40, 42, 44 + late])
        );
        let mut steps = vec![35, 37, 39, 41, 42, 43, 44];
        steps.extend(45 + late..=50 + late);
        assert_eq!(
            events(&r, |t| t.emitter_steps),
            ones(&steps),
            "emit_fifo {fifo}"
        );
        assert_eq!(r.stalls.merge.output_full_cycles, late);
        assert_eq!(phase_from(&r, "sort_and_emit"), Some(45 + late));
        assert_eq!(r.cycles, 71 + late, "emit_fifo {fifo}");
    }
}
