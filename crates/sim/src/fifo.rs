//! The bounded FIFO between units.
//!
//! Capacities are configuration (`shared/DESIGN.md`: never hidden constants). A full FIFO
//! refuses a push and gives the item back, which is how back-pressure stalls the producer.
//! The FIFO keeps the statistics a report needs: peak occupancy, pushes, and refused
//! pushes.

use std::collections::VecDeque;

/// A bounded first-in first-out queue with occupancy statistics.
#[derive(Clone, Debug)]
pub struct Fifo<T> {
    name: &'static str,
    items: VecDeque<T>,
    capacity: usize,
    pushes: u64,
    refused: u64,
    peak: usize,
}

impl<T> Fifo<T> {
    /// An empty FIFO holding at most `capacity` items; `name` identifies it in reports and
    /// deadlock messages.
    ///
    /// # Panics
    /// If `capacity` is zero.
    pub fn new(name: &'static str, capacity: usize) -> Self {
        assert!(capacity > 0, "FIFO {name}: capacity must be at least 1");
        Self {
            name,
            items: VecDeque::with_capacity(capacity),
            capacity,
            pushes: 0,
            refused: 0,
            peak: 0,
        }
    }

    /// Appends `item`, or gives it back when the FIFO is full.
    pub fn push(&mut self, item: T) -> Result<(), T> {
        if self.items.len() >= self.capacity {
            self.refused += 1;
            return Err(item);
        }
        self.items.push_back(item);
        self.pushes += 1;
        self.peak = self.peak.max(self.items.len());
        Ok(())
    }

    /// Removes and returns the oldest item.
    pub fn pop(&mut self) -> Option<T> {
        self.items.pop_front()
    }

    /// The oldest item, without removing it.
    pub fn front(&self) -> Option<&T> {
        self.items.front()
    }

    /// Number of items held.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when no item is held.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// True when a push would be refused.
    pub fn is_full(&self) -> bool {
        self.items.len() >= self.capacity
    }

    /// Free slots.
    pub fn free(&self) -> usize {
        self.capacity - self.items.len()
    }

    /// Maximum number of items.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Name given at construction.
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Occupancy statistics so far.
    pub fn stats(&self) -> FifoStats {
        FifoStats {
            name: self.name,
            capacity: self.capacity,
            len: self.items.len(),
            pushes: self.pushes,
            refused_pushes: self.refused,
            peak: self.peak,
        }
    }
}

/// A snapshot of a FIFO's state and statistics (for reports and deadlock messages).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct FifoStats {
    /// The FIFO's name.
    pub name: &'static str,
    /// Its capacity.
    pub capacity: usize,
    /// Items held now.
    pub len: usize,
    /// Accepted pushes so far.
    pub pushes: u64,
    /// Pushes refused because the FIFO was full.
    pub refused_pushes: u64,
    /// Highest occupancy seen.
    pub peak: usize,
}

impl std::fmt::Display for FifoStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {}/{} (peak {}, {} pushes, {} refused)",
            self.name, self.len, self.capacity, self.peak, self.pushes, self.refused_pushes
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_fifo_gives_the_item_back_and_counts_it() {
        let mut f = Fifo::new("q", 2);
        assert!(f.push(1).is_ok());
        assert!(f.push(2).is_ok());
        assert_eq!(f.push(3), Err(3));
        assert!(f.is_full());
        assert_eq!(f.pop(), Some(1));
        assert!(f.push(4).is_ok());
        assert_eq!(f.pop(), Some(2));
        assert_eq!(f.pop(), Some(4));
        assert_eq!(f.pop(), None);
        let s = f.stats();
        assert_eq!((s.pushes, s.refused_pushes, s.peak, s.len), (3, 1, 2, 0));
    }
}
