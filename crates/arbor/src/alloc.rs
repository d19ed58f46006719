//! A counting global allocator: the system allocator plus two counters, the bytes live now
//! and their peak, so that `arbor bench build` can report the peak memory of each build
//! (issue 3's goal: no more than twice the size of the input plus the output).
//!
//! Every allocation, reallocation and free of the process goes through it (it is the
//! `#[global_allocator]` of the `arbor` binary). The cost is two relaxed atomic operations
//! per call. It counts requested bytes, not the allocator's rounding or the pages the
//! operating system maps, and only Rust allocations: memory a C library allocates itself
//! (Embree) is invisible here, which is why the Embree adapter has its own monitor.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

/// Bytes allocated and not yet freed.
static LIVE: AtomicUsize = AtomicUsize::new(0);
/// Highest value of [`LIVE`] since the last [`reset_peak`].
static PEAK: AtomicUsize = AtomicUsize::new(0);

/// The system allocator with live and peak byte counters.
pub struct Counting;

impl Counting {
    #[inline]
    fn grew(by: usize) {
        let now = LIVE.fetch_add(by, Relaxed) + by;
        PEAK.fetch_max(now, Relaxed);
    }

    #[inline]
    fn shrank(by: usize) {
        LIVE.fetch_sub(by, Relaxed);
    }
}

// SAFETY: every method forwards to `System` with the caller's arguments unchanged and only
// updates counters besides, so `System`'s guarantees hold.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            Self::grew(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() {
            Self::grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        Self::shrank(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() {
            // Counted as the new block arriving before the old one leaves, as a moving
            // realloc needs both for a moment.
            Self::grew(new_size);
            Self::shrank(layout.size());
        }
        p
    }
}

/// Bytes allocated now (by this process's Rust code).
#[cfg(test)]
pub fn live_bytes() -> usize {
    LIVE.load(Relaxed)
}

/// Peak of the live bytes since the last [`reset_peak`].
pub fn peak_bytes() -> usize {
    PEAK.load(Relaxed)
}

/// Starts a new peak at the bytes live now, and returns them.
pub fn reset_peak() -> usize {
    let now = LIVE.load(Relaxed);
    PEAK.store(now, Relaxed);
    now
}

/// Measures the peak memory of one piece of work: the most bytes allocated at once while
/// it ran, above what was allocated when it started.
pub struct PeakMeter {
    base: usize,
}

impl PeakMeter {
    /// Starts measuring (resets the global peak).
    pub fn start() -> Self {
        Self { base: reset_peak() }
    }

    /// The peak so far, above the bytes live at the start.
    pub fn extra_peak(&self) -> usize {
        peak_bytes().saturating_sub(self.base)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `arbor` binary's unit tests run with this allocator installed, so a large
    /// vector shows up in the counters. Tests run on several threads and may allocate or
    /// free at the same time, so only bounds that hold whatever they do are checked.
    #[test]
    fn a_large_vector_raises_the_peak_by_its_size() {
        const N: usize = 64 << 20;
        let m = PeakMeter::start();
        let v = vec![1u8; N];
        assert!(live_bytes() >= N);
        assert!(peak_bytes() >= live_bytes().min(N));
        assert!(peak_bytes() >= N);
        drop(v);
        // The peak stays until the next reset; an unrelated free cannot lower it below N.
        assert!(peak_bytes() >= N);
        assert!(m.base + m.extra_peak() >= N);
        // Growing by reallocation counts the larger block.
        reset_peak();
        let mut w: Vec<u8> = Vec::with_capacity(1024);
        w.resize(N, 0);
        assert!(peak_bytes() >= N && live_bytes() >= N);
        drop(w);
    }
}
