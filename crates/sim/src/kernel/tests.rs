//! Kernel-level tests: a run with skipping equals one that steps every unit every cycle
//! (randomized pipelines with back-pressure, an arbiter, a memory-like unit and a stalling
//! consumer; and units reading DRAM through the kernel), results do not depend on the
//! registration order, deadlocks are reported, and the activity fractions sum to one.

use proptest::prelude::*;

use super::*;
use crate::dram::{self, AccessKind, MemRequest};

/// SplitMix64: a small deterministic generator for the test units.
#[derive(Clone, Debug)]
pub(super) struct Rng(u64);

impl Rng {
    pub(super) fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub(super) fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n` > 0).
    pub(super) fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Item {
    src: u32,
    seq: u32,
}

/// The pipeline's world: producers -> arbiter -> memory-like unit -> consumer.
struct Pipe {
    inputs: Vec<LatencyFifo<Item>>,
    to_mem: LatencyFifo<Item>,
    to_sink: LatencyFifo<Item>,
    /// (cycle, item) per item consumed.
    log: Vec<(Cycle, Item)>,
}

impl World for Pipe {
    fn describe(&self) -> String {
        let mut s = String::new();
        for f in self.inputs.iter().chain([&self.to_mem, &self.to_sink]) {
            s += &format!("{}; ", f.stats(0));
        }
        s
    }
}

/// Makes `left` items, each after a random service time, and pushes them into its input
/// FIFO; stalls when the FIFO is full.
struct Producer {
    p: usize,
    rng: Rng,
    left: u32,
    seq: u32,
    ready_at: Cycle,
    max_service: u64,
}

impl Unit<Pipe> for Producer {
    fn name(&self) -> &str {
        "producer"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["output full"]
    }

    fn step(&mut self, w: &mut Pipe, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if self.left == 0 {
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        if now < self.ready_at {
            cx.set_state(State::Busy);
            return Wake::At(self.ready_at);
        }
        let item = Item {
            src: self.p as u32,
            seq: self.seq,
        };
        match w.inputs[self.p].push(cx, item) {
            Ok(()) => {
                self.seq += 1;
                self.left -= 1;
                if self.left == 0 {
                    cx.set_state(State::Idle);
                    return Wake::Done;
                }
                self.ready_at = now + 1 + self.rng.below(self.max_service);
                cx.set_state(State::Busy);
                Wake::At(self.ready_at)
            }
            Err(_) => {
                cx.set_state(State::Stalled(0));
                Wake::OnEvent
            }
        }
    }

    fn describe(&self, _: &Pipe) -> String {
        format!("{} items left", self.left)
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("made", self.seq as u64)]
    }
}

/// Moves up to K items per cycle from the inputs to the memory FIFO, round robin.
struct Arbiter {
    rr: RoundRobin,
}

impl Unit<Pipe> for Arbiter {
    fn name(&self) -> &str {
        "arbiter"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["output full"]
    }

    fn step(&mut self, w: &mut Pipe, cx: &mut Ctx) -> Wake {
        let Pipe { inputs, to_mem, .. } = w;
        let granted = self.rr.arbitrate(|i| {
            if !inputs[i].can_pop(cx) {
                return Offer::Nothing;
            }
            if to_mem.is_full(cx) {
                return Offer::Refused;
            }
            let item = inputs[i].pop(cx).expect("visible");
            to_mem.push(cx, item).expect("not full");
            Offer::Granted
        });
        if granted > 0 {
            cx.set_state(State::Busy);
            return Wake::Next;
        }
        if inputs.iter().any(|f| f.can_pop(cx)) {
            cx.set_state(State::Stalled(0));
            Wake::OnEvent
        } else {
            cx.set_state(State::Idle);
            Wake::Done
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        let s = self.rr.stats();
        let mut v = vec![("refusals", s.total_refusals())];
        v.extend(s.grants.iter().map(|&g| ("grants", g)));
        v
    }
}

/// A memory-like unit: each item takes a fixed latency; at most `slots` in service.
struct MemLike {
    latency: Cycle,
    slots: usize,
    q: std::collections::VecDeque<(Cycle, Item)>,
    served: u64,
}

impl Unit<Pipe> for MemLike {
    fn name(&self) -> &str {
        "memory-like"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["output full"]
    }

    fn step(&mut self, w: &mut Pipe, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        let mut did = false;
        let mut blocked = false;
        if let Some(&(r, item)) = self.q.front() {
            if r <= now {
                if w.to_sink.push(cx, item).is_ok() {
                    self.q.pop_front();
                    self.served += 1;
                    did = true;
                } else {
                    blocked = true;
                }
            }
        }
        if self.q.len() < self.slots {
            if let Some(item) = w.to_mem.pop(cx) {
                self.q.push_back((now + self.latency, item));
                did = true;
            }
        }
        cx.set_state(if blocked {
            State::Stalled(0)
        } else if did || !self.q.is_empty() {
            State::Busy
        } else {
            State::Idle
        });
        if did {
            return Wake::Next;
        }
        match self.q.front() {
            Some(&(r, _)) if r > now => Wake::At(r),
            Some(_) => Wake::OnEvent,
            None => Wake::Done,
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("served", self.served)]
    }
}

/// Takes `expect` items; after each, stalls for a random time with some probability.
struct Consumer {
    rng: Rng,
    expect: u32,
    got: u32,
    stall_until: Cycle,
    stall_percent: u64,
    max_stall: u64,
}

impl Unit<Pipe> for Consumer {
    fn name(&self) -> &str {
        "consumer"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["random stall"]
    }

    fn step(&mut self, w: &mut Pipe, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if now < self.stall_until {
            cx.set_state(State::Stalled(0));
            return Wake::At(self.stall_until);
        }
        if self.got == self.expect {
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        match w.to_sink.pop(cx) {
            Some(item) => {
                w.log.push((now, item));
                self.got += 1;
                if self.rng.below(100) < self.stall_percent {
                    self.stall_until = now + 1 + self.rng.below(self.max_stall);
                    cx.set_state(State::Stalled(0));
                    return Wake::At(self.stall_until);
                }
                cx.set_state(State::Busy);
                Wake::Next
            }
            None => {
                cx.set_state(State::Idle);
                Wake::OnEvent
            }
        }
    }

    fn describe(&self, _: &Pipe) -> String {
        format!("{}/{} items received", self.got, self.expect)
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("received", self.got as u64)]
    }
}

#[derive(Clone, Debug)]
struct PipeConfig {
    seed: u64,
    producers: usize,
    items: u32,
    max_service: u64,
    input_capacity: usize,
    input_latency: Cycle,
    grants: usize,
    mem_capacity: usize,
    mem_fifo_latency: Cycle,
    mem_latency: Cycle,
    mem_slots: usize,
    sink_capacity: usize,
    sink_latency: Cycle,
    stall_percent: u64,
    max_stall: u64,
    /// Items the consumer waits for beyond those made (a deadlock when > 0).
    extra_expected: u32,
    /// Register the units in reverse order (consumer first).
    reversed: bool,
}

fn pipe_configs() -> impl Strategy<Value = PipeConfig> {
    (
        any::<u64>(),
        1usize..5,
        1u32..40,
        1u64..12,
        (1usize..4, 1u64..4),
        1usize..3,
        (1usize..4, 1u64..4, 1u64..20, 1usize..5),
        (1usize..4, 1u64..4),
        (0u64..60, 1u64..30),
    )
        .prop_map(
            |(seed, producers, items, max_service, inp, grants, mem, sink, stall)| PipeConfig {
                seed,
                producers,
                items,
                max_service,
                input_capacity: inp.0,
                input_latency: inp.1,
                grants,
                mem_capacity: mem.0,
                mem_fifo_latency: mem.1,
                mem_latency: mem.2,
                mem_slots: mem.3,
                sink_capacity: sink.0,
                sink_latency: sink.1,
                stall_percent: stall.0,
                max_stall: stall.1,
                extra_expected: 0,
                reversed: false,
            },
        )
}

struct PipeRun {
    result: Result<RunReport, KernelError>,
    log: Vec<(Cycle, Item)>,
    fifos: Vec<LatencyFifoStats>,
}

fn run_pipe(c: &PipeConfig, skip: bool) -> PipeRun {
    let mut s: Scheduler<Pipe> = Scheduler::new(Options {
        skip,
        max_cycles: 10_000_000,
        ..Options::default()
    });
    let n = c.producers;
    // Ids in registration order: producers 0..n, arbiter n, memory n+1, consumer n+2;
    // reversed: consumer 0, memory 1, arbiter 2, producers 3.. .
    let (prod, arb, mem, cons) = if c.reversed {
        let p: Vec<UnitId> = (0..n).map(|i| UnitId(3 + (n - 1 - i) as u32)).collect();
        (p, UnitId(2), UnitId(1), UnitId(0))
    } else {
        let p: Vec<UnitId> = (0..n).map(|i| UnitId(i as u32)).collect();
        (
            p,
            UnitId(n as u32),
            UnitId(n as u32 + 1),
            UnitId(n as u32 + 2),
        )
    };
    let mut producers: Vec<Box<dyn Unit<Pipe>>> = (0..n)
        .map(|p| {
            let mut rng = Rng::new(c.seed ^ ((p as u64 + 1) * 0x1234_5678_9abc));
            let first = rng.below(c.max_service);
            Box::new(Producer {
                p,
                rng,
                left: c.items,
                seq: 0,
                ready_at: first,
                max_service: c.max_service,
            }) as Box<dyn Unit<Pipe>>
        })
        .collect();
    let arbiter = Box::new(Arbiter {
        rr: RoundRobin::new(n, c.grants).unwrap(),
    });
    let memory = Box::new(MemLike {
        latency: c.mem_latency,
        slots: c.mem_slots,
        q: Default::default(),
        served: 0,
    });
    let consumer = Box::new(Consumer {
        rng: Rng::new(c.seed.rotate_left(17) ^ 0xdead_beef),
        expect: c.items * n as u32 + c.extra_expected,
        got: 0,
        stall_until: 0,
        stall_percent: c.stall_percent,
        max_stall: c.max_stall,
    });
    if c.reversed {
        s.add(consumer);
        s.add(memory);
        s.add(arbiter);
        for p in producers.drain(..).rev() {
            s.add(p);
        }
    } else {
        for p in producers.drain(..) {
            s.add(p);
        }
        s.add(arbiter);
        s.add(memory);
        s.add(consumer);
    }
    let mut w = Pipe {
        inputs: (0..n)
            .map(|p| {
                LatencyFifo::new("input", c.input_capacity, c.input_latency, prod[p], arb).unwrap()
            })
            .collect(),
        to_mem: LatencyFifo::new("to memory", c.mem_capacity, c.mem_fifo_latency, arb, mem)
            .unwrap(),
        to_sink: LatencyFifo::new("to sink", c.sink_capacity, c.sink_latency, mem, cons).unwrap(),
        log: Vec::new(),
    };
    let result = s.run(&mut w);
    let end = result.as_ref().map_or(0, |r| r.cycles);
    let fifos = w
        .inputs
        .iter()
        .chain([&w.to_mem, &w.to_sink])
        .map(|f| f.stats(end))
        .collect();
    PipeRun {
        result,
        log: w.log,
        fifos,
    }
}

/// Per-unit reports keyed by position in the data flow (producers, arbiter, memory,
/// consumer), whatever the registration order.
fn in_flow_order(r: &RunReport, c: &PipeConfig) -> Vec<UnitReport> {
    let mut u = r.units.clone();
    if c.reversed {
        u.reverse();
    }
    u
}

fn check_fractions(r: &RunReport) -> Result<(), TestCaseError> {
    for u in &r.units {
        let a = &u.activity;
        prop_assert_eq!(a.accounted_cycles(), r.cycles, "{}", u.name);
        let sum: f64 = a.busy_fraction()
            + a.idle_fraction()
            + a.stalled
                .iter()
                .map(|s| s.cycles as f64 / a.cycles as f64)
                .sum::<f64>();
        prop_assert!((sum - 1.0).abs() < 1e-9, "{}: {}", u.name, sum);
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    /// Skipping idle cycles gives the same cycle count, per-unit activity and counters,
    /// FIFO statistics and output sequence as stepping every unit every cycle.
    #[test]
    fn skipping_equals_stepping_every_cycle(c in pipe_configs()) {
        let a = run_pipe(&c, true);
        let b = run_pipe(&c, false);
        let (ra, rb) = (a.result.unwrap(), b.result.unwrap());
        prop_assert!(ra.same_results(&rb), "{:?}\n{:?}", ra, rb);
        prop_assert_eq!(&a.log, &b.log);
        prop_assert_eq!(&a.fifos, &b.fifos);
        prop_assert!(ra.stepped_cycles <= rb.stepped_cycles);
        prop_assert_eq!(rb.stepped_cycles, rb.cycles);
        check_fractions(&ra)?;
        check_fractions(&rb)?;
        // Every item arrives exactly once, each producer's in order.
        prop_assert_eq!(a.log.len() as u32, c.items * c.producers as u32);
        for p in 0..c.producers as u32 {
            let seqs: Vec<u32> = a.log.iter().filter(|x| x.1.src == p).map(|x| x.1.seq).collect();
            prop_assert_eq!(seqs, (0..c.items).collect::<Vec<_>>());
        }
    }

    /// Registering the units in the opposite order (so they step in the opposite order
    /// within each cycle) changes nothing, with or without skipping: the channels'
    /// visibility rules hide the order. (Without skipping, every unit sees every cycle, so
    /// a slot freed by a pop being usable in the same cycle would show here.)
    #[test]
    fn step_order_does_not_change_results(c in pipe_configs()) {
        let r = PipeConfig { reversed: true, ..c.clone() };
        for skip in [true, false] {
            let a = run_pipe(&c, skip);
            let b = run_pipe(&r, skip);
            let (ra, rb) = (a.result.unwrap(), b.result.unwrap());
            prop_assert_eq!(ra.cycles, rb.cycles);
            prop_assert_eq!(in_flow_order(&ra, &c), in_flow_order(&rb, &r));
            prop_assert_eq!(&a.log, &b.log);
            prop_assert_eq!(&a.fifos, &b.fifos);
        }
    }
}

#[test]
fn deadlock_is_an_error_with_every_units_state() {
    let c = PipeConfig {
        seed: 7,
        producers: 2,
        items: 5,
        max_service: 3,
        input_capacity: 2,
        input_latency: 1,
        grants: 1,
        mem_capacity: 2,
        mem_fifo_latency: 1,
        mem_latency: 4,
        mem_slots: 2,
        sink_capacity: 1,
        sink_latency: 2,
        stall_percent: 20,
        max_stall: 5,
        extra_expected: 1,
        reversed: false,
    };
    for skip in [true, false] {
        let r = run_pipe(&c, skip);
        let err = r.result.unwrap_err();
        let KernelError::Deadlock { cycle, units, .. } = &err else {
            panic!("{err}");
        };
        assert_eq!(units.len(), 5);
        assert_eq!(units[4].last_wake, Wake::OnEvent);
        assert!(*cycle > 0);
        let text = err.to_string();
        assert!(
            text.contains("consumer") && text.contains("10/11 items received"),
            "{text}"
        );
        assert!(text.contains("to sink: 0/1"), "{text}");
    }
}

#[test]
fn a_run_that_never_settles_hits_the_cycle_limit() {
    struct Spin;
    impl Unit<Pipe> for Spin {
        fn name(&self) -> &str {
            "spin"
        }
        fn step(&mut self, _: &mut Pipe, _: &mut Ctx) -> Wake {
            Wake::At(Cycle::MAX / 2)
        }
    }
    let mut s: Scheduler<Pipe> = Scheduler::new(Options {
        max_cycles: 1000,
        ..Options::default()
    });
    s.add(Box::new(Spin));
    let mut w = Pipe {
        inputs: vec![],
        to_mem: LatencyFifo::new("m", 1, 1, UnitId::EXTERNAL, UnitId::EXTERNAL).unwrap(),
        to_sink: LatencyFifo::new("s", 1, 1, UnitId::EXTERNAL, UnitId::EXTERNAL).unwrap(),
        log: vec![],
    };
    // The jump goes straight past the limit: reported, not simulated cycle by cycle.
    assert!(matches!(s.run(&mut w), Err(KernelError::CycleLimit(_))));
}

// ---- Memory through the kernel ----

/// (unit, tag, completed cycle, cycle the unit saw it) per response.
type ResponseLog = Vec<(u32, u64, Cycle, Cycle)>;

struct MemWorld {
    mem: Memory,
    log: ResponseLog,
}

impl World for MemWorld {
    fn memory(&mut self) -> Option<&mut Memory> {
        Some(&mut self.mem)
    }
}

/// Issues `n` reads with random gaps (bursts of back-to-back reads fill the port's queue)
/// and records when each response comes back.
struct Reader {
    id: u32,
    rng: Rng,
    n: u64,
    sent: u64,
    received: u64,
    next_at: Cycle,
}

impl Unit<MemWorld> for Reader {
    fn name(&self) -> &str {
        "reader"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["port full", "waiting for data"]
    }

    fn step(&mut self, w: &mut MemWorld, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        while let Some(r) = w.mem.pop(cx) {
            assert_eq!(r.tag >> 32, self.id as u64, "response routed to its sender");
            w.log.push((self.id, r.tag, r.completed_cycle, now));
            self.received += 1;
        }
        let mut refused = false;
        if self.sent < self.n && now >= self.next_at {
            let req = MemRequest {
                tag: (self.id as u64) << 32 | self.sent,
                addr: self.rng.below(1 << 24) & !63,
                bytes: 64 * (1 + self.rng.below(3) as u32),
                kind: AccessKind::Read,
            };
            match w.mem.send(cx, req) {
                Ok(()) => {
                    self.sent += 1;
                    // Bursts of 20 back-to-back reads from all readers at once overfill the
                    // port's 32-entry queue.
                    let burst = self.sent % 50 < 20;
                    self.next_at = now + if burst { 1 } else { 1 + self.rng.below(300) };
                }
                Err(_) => refused = true,
            }
        }
        if refused {
            cx.set_state(State::Stalled(0));
            return Wake::Next;
        }
        if self.sent < self.n {
            cx.set_state(State::Busy);
            return Wake::At(self.next_at);
        }
        if self.received < self.n {
            cx.set_state(State::Stalled(1));
            return Wake::OnEvent;
        }
        cx.set_state(State::Idle);
        Wake::Done
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("sent", self.sent), ("received", self.received)]
    }
}

fn run_readers(seed: u64, n: u64, skip: bool) -> (RunReport, ResponseLog, u64) {
    let port = dram::open("simple:lpddr3-1600-1x64", 1_000_000).unwrap();
    let mut w = MemWorld {
        mem: Memory::new(port),
        log: Vec::new(),
    };
    let mut s = Scheduler::new(Options {
        skip,
        ..Options::default()
    });
    for id in 0..3 {
        s.add(Box::new(Reader {
            id,
            rng: Rng::new(seed + id as u64),
            n,
            sent: 0,
            received: 0,
            next_at: 0,
        }));
    }
    let r = s.run(&mut w).unwrap();
    let stats = w.mem.port().stats();
    assert_eq!(
        stats.unit_cycles, r.cycles,
        "port ticked exactly to the end"
    );
    (r, w.log, stats.bytes_read)
}

#[test]
fn memory_responses_arrive_at_the_same_cycles_with_and_without_skipping() {
    for seed in [1u64, 99, 12345] {
        let (ra, la, ba) = run_readers(seed, 200, true);
        let (rb, lb, bb) = run_readers(seed, 200, false);
        assert!(ra.same_results(&rb));
        assert_eq!(la, lb);
        assert_eq!(ba, bb);
        assert_eq!(la.len(), 600);
        // Each response is seen in the cycle it completes.
        assert!(la.iter().all(|&(_, _, done, seen)| done == seen));
        assert!(
            ra.stepped_cycles < rb.stepped_cycles / 4,
            "{}",
            ra.stepped_cycles
        );
        // Bursts filled the port's queue at least once.
        let refused: u64 = ra.units.iter().map(|u| u.activity.stalled[0].cycles).sum();
        assert!(refused > 0);
    }
}

// ---- The example of docs/sim-kernel.md ----

mod docs_example {
    use crate::kernel::{Ctx, LatencyFifo, Options, Scheduler, State, Unit, Wake, World};

    /// The world: one channel.
    struct Sys {
        q: LatencyFifo<u32>,
        sum: u64,
    }
    impl World for Sys {}

    /// Sends 0..n, one every `period` cycles.
    struct Source {
        next: u32,
        n: u32,
        period: u64,
    }

    impl Unit<Sys> for Source {
        fn name(&self) -> &str {
            "source"
        }
        fn stall_reasons(&self) -> &'static [&'static str] {
            &["queue full"]
        }
        fn step(&mut self, w: &mut Sys, cx: &mut Ctx) -> Wake {
            if self.next == self.n {
                cx.set_state(State::Idle);
                return Wake::Done;
            }
            if cx.now() < self.next as u64 * self.period {
                return Wake::At(self.next as u64 * self.period);
            }
            match w.q.push(cx, self.next) {
                Ok(()) => {
                    self.next += 1;
                    cx.set_state(State::Busy);
                    Wake::Next
                }
                Err(_) => {
                    cx.set_state(State::Stalled(0));
                    Wake::OnEvent // a pop from the full queue wakes us
                }
            }
        }
    }

    /// Adds up what arrives, taking 3 cycles per item.
    struct Sink {
        busy_until: u64,
        left: u32,
    }

    impl Unit<Sys> for Sink {
        fn name(&self) -> &str {
            "sink"
        }
        fn step(&mut self, w: &mut Sys, cx: &mut Ctx) -> Wake {
            if cx.now() < self.busy_until {
                return Wake::At(self.busy_until);
            }
            if self.left == 0 {
                cx.set_state(State::Idle);
                return Wake::Done;
            }
            match w.q.pop(cx) {
                Some(x) => {
                    w.sum += x as u64;
                    self.left -= 1;
                    self.busy_until = cx.now() + 3;
                    cx.set_state(State::Busy);
                    Wake::At(self.busy_until)
                }
                None => {
                    cx.set_state(State::Idle);
                    Wake::OnEvent // a push wakes us when the item becomes visible
                }
            }
        }
    }

    #[test]
    fn docs_example_runs_the_same_with_and_without_skipping() {
        let mut reports = Vec::new();
        for skip in [true, false] {
            let mut s = Scheduler::new(Options {
                skip,
                ..Options::default()
            });
            let src = s.add(Box::new(Source {
                next: 0,
                n: 10,
                period: 1,
            }));
            let snk = s.add(Box::new(Sink {
                busy_until: 0,
                left: 10,
            }));
            let mut w = Sys {
                q: LatencyFifo::new("q", 2, 2, src, snk).unwrap(),
                sum: 0,
            };
            let r = s.run(&mut w).unwrap();
            assert_eq!(w.sum, 45);
            assert_eq!(w.q.stats(r.cycles).peak, 2);
            reports.push(r);
        }
        assert!(reports[0].same_results(&reports[1]));
        // Items visible at 2, 3, ...; the sink takes one every 3 cycles: the tenth at 29,
        // its busy period ends at 32, and its Done step is at 32.
        assert_eq!(reports[0].cycles, 33);
        let sink = &reports[0].units[1].activity;
        assert_eq!(sink.busy_cycles, 30);
    }
}

/// Throughput of the kernel on an always-busy pipeline (a measurement, not a test of
/// speed: run with `cargo test --release -p sim --lib kernel_throughput -- --ignored
/// --nocapture`).
#[test]
#[ignore]
fn kernel_throughput() {
    let c = PipeConfig {
        seed: 3,
        producers: 4,
        items: 250_000,
        max_service: 1,
        input_capacity: 4,
        input_latency: 1,
        grants: 1,
        mem_capacity: 4,
        mem_fifo_latency: 1,
        mem_latency: 4,
        mem_slots: 8,
        sink_capacity: 4,
        sink_latency: 1,
        stall_percent: 0,
        max_stall: 1,
        extra_expected: 0,
        reversed: false,
    };
    // The scheduler alone: units that only count and ask for the next cycle.
    struct Tick(u64);
    impl Unit<Pipe> for Tick {
        fn name(&self) -> &str {
            "tick"
        }
        fn step(&mut self, _: &mut Pipe, cx: &mut Ctx) -> Wake {
            self.0 += 1;
            if self.0 == 2_000_000 {
                return Wake::Done;
            }
            cx.set_state(State::Busy);
            Wake::Next
        }
    }
    let mut s: Scheduler<Pipe> = Scheduler::new(Options::default());
    for _ in 0..8 {
        s.add(Box::new(Tick(0)));
    }
    let mut w = Pipe {
        inputs: vec![],
        to_mem: LatencyFifo::new("m", 1, 1, UnitId::EXTERNAL, UnitId::EXTERNAL).unwrap(),
        to_sink: LatencyFifo::new("s", 1, 1, UnitId::EXTERNAL, UnitId::EXTERNAL).unwrap(),
        log: vec![],
    };
    let t = std::time::Instant::now();
    let r = s.run(&mut w).unwrap();
    let secs = t.elapsed().as_secs_f64();
    println!(
        "empty units: {} cycles x {} units in {:.3} s: {:.1} M unit cycles/s",
        r.cycles,
        r.units.len(),
        secs,
        (r.cycles * r.units.len() as u64) as f64 / secs / 1e6
    );
    let t = std::time::Instant::now();
    let r = run_pipe(&c, true).result.unwrap();
    let secs = t.elapsed().as_secs_f64();
    let unit_cycles = r.cycles * r.units.len() as u64;
    let steps: u64 = r.steps.iter().sum();
    println!(
        "{} cycles, {} units, {} steps in {:.3} s: {:.1} M unit cycles/s, {:.1} M steps/s",
        r.cycles,
        r.units.len(),
        steps,
        secs,
        unit_cycles as f64 / secs / 1e6,
        steps as f64 / secs / 1e6
    );
}

/// A memory that accepts requests and never answers.
struct BlackHole {
    cycle: u64,
    held: usize,
}

impl dram::MemoryPort for BlackHole {
    fn name(&self) -> String {
        "black hole".into()
    }
    fn burst_bytes(&self) -> u32 {
        64
    }
    fn peak_bytes_per_unit_cycle(&self) -> f64 {
        1.0
    }
    fn send(&mut self, _: MemRequest) -> Result<(), MemRequest> {
        self.held += 1;
        Ok(())
    }
    fn tick(&mut self) {
        self.cycle += 1;
    }
    fn pop_response(&mut self) -> Option<dram::MemResponse> {
        None
    }
    fn cycle(&self) -> u64 {
        self.cycle
    }
    fn outstanding(&self) -> usize {
        self.held
    }
    fn stats(&self) -> dram::MemStats {
        dram::MemStats::default()
    }
    fn completed_waiting(&self) -> usize {
        0
    }
}

#[test]
fn a_memory_that_never_answers_is_a_deadlock_not_a_hang() {
    let mut w = MemWorld {
        mem: Memory::new(Box::new(BlackHole { cycle: 0, held: 0 })),
        log: Vec::new(),
    };
    let mut s = Scheduler::new(Options {
        memory_timeout_cycles: 5_000,
        ..Options::default()
    });
    s.add(Box::new(Reader {
        id: 0,
        rng: Rng::new(1),
        n: 1,
        sent: 0,
        received: 0,
        next_at: 0,
    }));
    let err = s.run(&mut w).unwrap_err();
    let KernelError::Deadlock {
        cycle,
        units,
        world,
    } = &err
    else {
        panic!("{err}");
    };
    assert!(*cycle > 5_000 && *cycle < 5_010, "{cycle}");
    assert_eq!(units[0].state, "stalled on waiting for data");
    assert!(
        world.contains("black hole") && world.contains("1 in flight"),
        "{world}"
    );
}
