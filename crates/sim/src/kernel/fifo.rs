//! The bounded FIFO with a latency that connects units.
//!
//! Visibility rules (what makes results independent of the step order within a cycle):
//! - an item pushed at cycle `t` can be popped from cycle `t + latency` on (latency >= 1,
//!   so never in the cycle it was pushed);
//! - a slot freed by a pop at cycle `t` can be pushed into from cycle `t + 1` on: within a
//!   cycle, the producer sees the occupancy the FIFO had at the start of the cycle plus its
//!   own pushes, whether the consumer stepped before it or not.
//!
//! Wake-ups: a push into an empty FIFO notifies the consumer for the cycle the item becomes
//! visible; a pop that leaves items notifies the consumer for the next head's visible cycle
//! (or the next cycle); a pop from a FIFO the producer saw full notifies the producer for
//! the next cycle. So a unit waiting on a FIFO may return [`super::Wake::OnEvent`].

use std::collections::VecDeque;

use serde::Serialize;

use super::{ConfigError, Ctx, Cycle, UnitId};

/// A bounded FIFO of capacity `capacity` whose items become visible `latency` cycles after
/// their push. See the module documentation for the visibility and wake-up rules.
#[derive(Clone, Debug)]
pub struct LatencyFifo<T> {
    name: &'static str,
    /// Items with the cycle each becomes visible.
    items: VecDeque<(Cycle, T)>,
    capacity: usize,
    latency: Cycle,
    producer: UnitId,
    consumer: UnitId,
    /// Pops made in cycle `credit_cycle`: their slots are free from the next cycle on.
    credit_cycle: Cycle,
    credits: usize,
    pushes: u64,
    pops: u64,
    refused: u64,
    /// The last push was refused (a refusal episode is open).
    refusing: bool,
    peak: usize,
    /// Sum over cycles of the occupancy, up to `area_since`.
    area: u128,
    area_since: Cycle,
}

impl<T> LatencyFifo<T> {
    /// An empty FIFO from unit `producer` to unit `consumer` (either may be
    /// [`UnitId::EXTERNAL`]).
    ///
    /// # Errors
    /// A capacity of zero, or a latency of zero (same-cycle visibility would make results
    /// depend on the step order).
    pub fn new(
        name: &'static str,
        capacity: usize,
        latency: Cycle,
        producer: UnitId,
        consumer: UnitId,
    ) -> Result<Self, ConfigError> {
        if capacity == 0 {
            return Err(ConfigError::new(name, "FIFO capacity must be at least 1"));
        }
        if latency == 0 {
            return Err(ConfigError::new(
                name,
                "FIFO latency must be at least 1 cycle",
            ));
        }
        Ok(Self {
            name,
            items: VecDeque::with_capacity(capacity),
            capacity,
            latency,
            producer,
            consumer,
            credit_cycle: 0,
            credits: 0,
            pushes: 0,
            pops: 0,
            refused: 0,
            refusing: false,
            peak: 0,
            area: 0,
            area_since: 0,
        })
    }

    /// Occupancy as the producer sees it at `now` (items held plus slots freed this cycle).
    #[inline]
    fn occupancy(&self, now: Cycle) -> usize {
        self.items.len()
            + if self.credit_cycle == now {
                self.credits
            } else {
                0
            }
    }

    #[inline]
    fn account(&mut self, now: Cycle) {
        self.area += self.items.len() as u128 * (now - self.area_since) as u128;
        self.area_since = now;
    }

    /// True when a push at this cycle would be refused.
    #[inline]
    pub fn is_full(&self, cx: &Ctx) -> bool {
        self.occupancy(cx.now) >= self.capacity
    }

    /// Appends `item`, visible from `now + latency`; gives it back when the FIFO is full.
    #[inline]
    pub fn push(&mut self, cx: &mut Ctx, item: T) -> Result<(), T> {
        let now = cx.now;
        if self.occupancy(now) >= self.capacity {
            self.refused += !self.refusing as u64;
            self.refusing = true;
            return Err(item);
        }
        self.refusing = false;
        self.account(now);
        let at = now + self.latency;
        if self.items.is_empty() {
            cx.notify(self.consumer, at);
        }
        self.items.push_back((at, item));
        self.pushes += 1;
        // The occupancy the producer sees (slots popped this cycle are not yet free): the
        // start-of-cycle occupancy plus this cycle's pushes, whatever the step order.
        self.peak = self.peak.max(self.occupancy(now));
        Ok(())
    }

    /// The oldest item if it is visible at this cycle.
    #[inline]
    pub fn peek(&self, cx: &Ctx) -> Option<&T> {
        match self.items.front() {
            Some((at, item)) if *at <= cx.now => Some(item),
            _ => None,
        }
    }

    /// True when an item is visible at this cycle.
    #[inline]
    pub fn can_pop(&self, cx: &Ctx) -> bool {
        self.peek(cx).is_some()
    }

    /// Removes and returns the oldest item if it is visible at this cycle.
    #[inline]
    pub fn pop(&mut self, cx: &mut Ctx) -> Option<T> {
        let now = cx.now;
        match self.items.front() {
            Some((at, _)) if *at <= now => {}
            _ => return None,
        }
        let was_full = self.occupancy(now) >= self.capacity;
        self.account(now);
        let (_, item) = self.items.pop_front().expect("checked");
        if self.credit_cycle != now {
            self.credit_cycle = now;
            self.credits = 0;
        }
        self.credits += 1;
        self.pops += 1;
        if was_full {
            cx.notify(self.producer, now + 1);
        }
        if let Some(&(at, _)) = self.items.front() {
            cx.notify(self.consumer, at);
        }
        Some(item)
    }

    /// Cycle at which the oldest item is (or was) visible, if any item is held.
    pub fn head_visible_at(&self) -> Option<Cycle> {
        self.items.front().map(|f| f.0)
    }

    /// Items held (in flight or visible).
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when no item is held.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Maximum number of items.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Cycles from push to visibility.
    pub fn latency(&self) -> Cycle {
        self.latency
    }

    /// Name given at construction.
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Statistics over `[0, end)` (`end` at or after the last push or pop).
    pub fn stats(&self, end: Cycle) -> LatencyFifoStats {
        let area =
            self.area + self.items.len() as u128 * end.saturating_sub(self.area_since) as u128;
        LatencyFifoStats {
            name: self.name,
            capacity: self.capacity,
            latency: self.latency,
            len: self.items.len(),
            pushes: self.pushes,
            pops: self.pops,
            refused_pushes: self.refused,
            peak: self.peak,
            occupancy_cycles: area as u64,
            cycles: end,
        }
    }
}

/// A snapshot of a [`LatencyFifo`]'s state and statistics.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct LatencyFifoStats {
    /// The FIFO's name.
    pub name: &'static str,
    /// Its capacity.
    pub capacity: usize,
    /// Its latency in cycles.
    pub latency: Cycle,
    /// Items held at the end.
    pub len: usize,
    /// Accepted pushes.
    pub pushes: u64,
    /// Pops.
    pub pops: u64,
    /// Refusal episodes: pushes refused because the FIFO was full, counting a run of
    /// refused pushes without an accepted one in between once (a producer retrying every
    /// cycle counts as often as one that sleeps until a slot frees, so the figure does not
    /// depend on how often the producer is stepped).
    pub refused_pushes: u64,
    /// Highest occupancy: the most slots in use in one cycle, counting a slot popped in a
    /// cycle as used until the cycle ends (it is free only from the next cycle). This is
    /// the storage FIFO sizing needs, and it does not depend on the step order.
    pub peak: usize,
    /// Occupancy-time integral: the sum over cycles of the items held (in flight included).
    pub occupancy_cycles: u64,
    /// Length of the period the integral covers.
    pub cycles: Cycle,
}

impl LatencyFifoStats {
    /// Mean number of items held over the period.
    pub fn mean_occupancy(&self) -> f64 {
        if self.cycles == 0 {
            0.0
        } else {
            self.occupancy_cycles as f64 / self.cycles as f64
        }
    }
}

impl std::fmt::Display for LatencyFifoStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {}/{} (latency {}, peak {}, {} pushes, {} pops, {} refused)",
            self.name,
            self.len,
            self.capacity,
            self.latency,
            self.peak,
            self.pushes,
            self.pops,
            self.refused_pushes
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: UnitId = UnitId(0);
    const C: UnitId = UnitId(1);

    #[test]
    fn items_become_visible_after_the_latency() {
        let mut cx = Ctx::new(2);
        let mut f = LatencyFifo::new("q", 4, 3, P, C).unwrap();
        cx.set_now(10, P);
        f.push(&mut cx, 'a').unwrap();
        assert_eq!(cx.pending_event(C), Some(13));
        cx.set_now(11, P);
        f.push(&mut cx, 'b').unwrap();
        for t in 10..13 {
            cx.set_now(t, C);
            assert_eq!(f.pop(&mut cx), None, "cycle {t}");
        }
        cx.set_now(13, C);
        assert_eq!(f.pop(&mut cx), Some('a'));
        assert_eq!(f.pop(&mut cx), None, "b visible at 14");
        cx.set_now(14, C);
        assert_eq!(f.pop(&mut cx), Some('b'));
        let s = f.stats(20);
        // 'a' held 10..13, 'b' held 11..14.
        assert_eq!(s.occupancy_cycles, 3 + 3);
        assert_eq!((s.pushes, s.pops, s.peak, s.len), (2, 2, 2, 0));
    }

    #[test]
    fn full_fifo_refuses_and_a_freed_slot_is_usable_next_cycle() {
        let mut cx = Ctx::new(2);
        let mut f = LatencyFifo::new("q", 2, 1, P, C).unwrap();
        cx.set_now(0, P);
        f.push(&mut cx, 1).unwrap();
        f.push(&mut cx, 2).unwrap();
        assert_eq!(f.push(&mut cx, 3), Err(3));
        cx.set_now(5, C);
        assert_eq!(f.pop(&mut cx), Some(1));
        assert_eq!(cx.pending_event(P), Some(6), "producer woken by the pop");
        // Same cycle: the freed slot is not yet usable, whatever the step order.
        cx.set_now(5, P);
        assert!(f.is_full(&cx));
        assert_eq!(f.push(&mut cx, 3), Err(3));
        cx.set_now(6, P);
        assert!(!f.is_full(&cx));
        f.push(&mut cx, 3).unwrap();
        let s = f.stats(6);
        // The refusals at cycles 0 and 5, with no accepted push between, are one episode.
        assert_eq!((s.pushes, s.refused_pushes, s.peak), (3, 1, 2));
    }

    #[test]
    fn zero_capacity_or_latency_is_an_error() {
        assert!(LatencyFifo::<u8>::new("q", 0, 1, P, C).is_err());
        let e = LatencyFifo::<u8>::new("q", 1, 0, P, C).err().unwrap();
        assert!(e.to_string().contains("latency"), "{e}");
    }
}
