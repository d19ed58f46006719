//! Bounded tag pools and the MSHR file of a non-blocking cache.

use serde::Serialize;

/// A bounded pool of tags `0..capacity`: allocate, free, in-use count and high-water mark.
/// Allocation takes the most recently freed tag (a stack, no search).
#[derive(Clone, Debug)]
pub struct TagPool {
    free: Vec<u32>,
    in_use: Vec<bool>,
    high_water: usize,
    allocations: u64,
    exhausted: u64,
}

/// Freeing a tag that is not allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("tag {0} freed but not allocated")]
pub struct TagNotAllocated(pub u32);

impl TagPool {
    /// A pool of `capacity` tags, all free.
    pub fn new(capacity: u32) -> Self {
        Self {
            free: (0..capacity).rev().collect(),
            in_use: vec![false; capacity as usize],
            high_water: 0,
            allocations: 0,
            exhausted: 0,
        }
    }

    /// A free tag, or `None` when all are in use (counted as an exhaustion).
    #[inline]
    pub fn allocate(&mut self) -> Option<u32> {
        let Some(t) = self.free.pop() else {
            self.exhausted += 1;
            return None;
        };
        self.in_use[t as usize] = true;
        self.allocations += 1;
        self.high_water = self.high_water.max(self.in_use());
        Some(t)
    }

    /// Returns `tag` to the pool.
    #[inline]
    pub fn free(&mut self, tag: u32) -> Result<(), TagNotAllocated> {
        match self.in_use.get_mut(tag as usize) {
            Some(u) if *u => {
                *u = false;
                self.free.push(tag);
                Ok(())
            }
            _ => Err(TagNotAllocated(tag)),
        }
    }

    /// Tags allocated now.
    #[inline]
    pub fn in_use(&self) -> usize {
        self.in_use.len() - self.free.len()
    }

    /// Number of tags.
    pub fn capacity(&self) -> usize {
        self.in_use.len()
    }

    /// True when `tag` is allocated.
    pub fn is_allocated(&self, tag: u32) -> bool {
        self.in_use.get(tag as usize).copied().unwrap_or(false)
    }

    /// Statistics so far.
    pub fn stats(&self) -> TagPoolStats {
        TagPoolStats {
            capacity: self.capacity(),
            in_use: self.in_use(),
            high_water: self.high_water,
            allocations: self.allocations,
            exhausted: self.exhausted,
        }
    }
}

/// Counts of a [`TagPool`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct TagPoolStats {
    /// Number of tags.
    pub capacity: usize,
    /// Allocated now.
    pub in_use: usize,
    /// Most allocated at once.
    pub high_water: usize,
    /// Successful allocations.
    pub allocations: u64,
    /// Allocations refused because every tag was in use.
    pub exhausted: u64,
}

/// Why the MSHR file could not take a miss.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum MshrRefusal {
    /// A new line needs an entry and all are in use.
    MshrFull,
    /// The line's entry already holds its maximum number of targets.
    TargetsFull,
}

/// Miss status holding registers: at most `entries` lines outstanding, each with at most
/// `targets` waiting requests (targets of type `T`). A miss to a line already outstanding
/// (a secondary miss) is merged into its entry instead of fetching the line again.
///
/// Lookup by line address is a linear scan of the valid entries (MSHR files are small,
/// 4 to 64 entries): no hashing, no allocation after construction.
#[derive(Clone, Debug)]
pub struct MshrFile<T> {
    lines: Vec<u64>,
    valid: Vec<bool>,
    counts: Vec<u32>,
    /// `targets` slots per entry.
    slots: Vec<Option<T>>,
    targets: u32,
    in_use: usize,
    high_water: usize,
    allocations: u64,
    merges: u64,
}

impl<T: Copy> MshrFile<T> {
    /// A file of `entries` entries of `targets` targets each (both at least 1; the cache
    /// validates its configuration before building one).
    pub fn new(entries: usize, targets: u32) -> Self {
        let entries = entries.max(1);
        let targets = targets.max(1);
        Self {
            lines: vec![0; entries],
            valid: vec![false; entries],
            counts: vec![0; entries],
            slots: vec![None; entries * targets as usize],
            targets,
            in_use: 0,
            high_water: 0,
            allocations: 0,
            merges: 0,
        }
    }

    /// The entry of `line`, if it is outstanding.
    #[inline]
    pub fn find(&self, line: u64) -> Option<usize> {
        (0..self.lines.len()).find(|&i| self.valid[i] && self.lines[i] == line)
    }

    /// True when a new line can be allocated.
    #[inline]
    pub fn has_free_entry(&self) -> bool {
        self.in_use < self.lines.len()
    }

    /// True when entry `e` can take one more target.
    #[inline]
    pub fn has_target_room(&self, e: usize) -> bool {
        self.counts[e] < self.targets
    }

    /// Records a miss of `target` on `line`: merged into the line's entry if outstanding
    /// (returns `Ok(false)`), else a new entry (`Ok(true)`: the line must be fetched).
    pub fn insert(&mut self, line: u64, target: T) -> Result<bool, MshrRefusal> {
        let (e, new) = match self.find(line) {
            Some(e) => {
                if !self.has_target_room(e) {
                    return Err(MshrRefusal::TargetsFull);
                }
                (e, false)
            }
            None => (self.allocate(line)?, true),
        };
        if !new {
            self.merges += 1;
        }
        let k = e * self.targets as usize + self.counts[e] as usize;
        self.slots[k] = Some(target);
        self.counts[e] += 1;
        Ok(new)
    }

    /// Opens an entry for `line` with no target (the requester will retry instead of
    /// waiting); `Ok(false)` if the line is already outstanding.
    pub fn open(&mut self, line: u64) -> Result<bool, MshrRefusal> {
        if self.find(line).is_some() {
            return Ok(false);
        }
        self.allocate(line)?;
        Ok(true)
    }

    /// A free entry made outstanding for `line`, with no targets yet.
    fn allocate(&mut self, line: u64) -> Result<usize, MshrRefusal> {
        let e = self
            .valid
            .iter()
            .position(|v| !v)
            .ok_or(MshrRefusal::MshrFull)?;
        self.valid[e] = true;
        self.lines[e] = line;
        self.counts[e] = 0;
        self.in_use += 1;
        self.high_water = self.high_water.max(self.in_use);
        self.allocations += 1;
        Ok(e)
    }

    /// The fill of `line` arrived: frees its entry and appends its targets, in arrival
    /// order, to `out`. Returns false (and changes nothing) if `line` is not outstanding.
    pub fn complete(&mut self, line: u64, out: &mut Vec<T>) -> bool {
        let Some(e) = self.find(line) else {
            return false;
        };
        let base = e * self.targets as usize;
        for k in base..base + self.counts[e] as usize {
            out.push(self.slots[k].take().expect("counted target"));
        }
        self.valid[e] = false;
        self.counts[e] = 0;
        self.in_use -= 1;
        true
    }

    /// Entries in use.
    pub fn in_use(&self) -> usize {
        self.in_use
    }

    /// Statistics so far.
    pub fn stats(&self) -> MshrStats {
        MshrStats {
            entries: self.lines.len(),
            targets_per_entry: self.targets,
            in_use: self.in_use,
            high_water: self.high_water,
            allocations: self.allocations,
            merges: self.merges,
        }
    }
}

/// Counts of an [`MshrFile`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct MshrStats {
    /// Number of entries.
    pub entries: usize,
    /// Targets each entry can hold.
    pub targets_per_entry: u32,
    /// Entries in use now.
    pub in_use: usize,
    /// Most entries in use at once.
    pub high_water: usize,
    /// Entries allocated (primary misses).
    pub allocations: u64,
    /// Targets merged into an outstanding entry (secondary misses).
    pub merges: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tag_pool_bounds_and_high_water() {
        let mut p = TagPool::new(3);
        let a = p.allocate().unwrap();
        let b = p.allocate().unwrap();
        let c = p.allocate().unwrap();
        assert_eq!(p.allocate(), None);
        assert_eq!(p.in_use(), 3);
        assert!(a != b && b != c && a != c);
        p.free(b).unwrap();
        assert_eq!(p.free(b), Err(TagNotAllocated(b)));
        assert_eq!(p.free(99), Err(TagNotAllocated(99)));
        assert_eq!(p.allocate(), Some(b));
        let s = p.stats();
        assert_eq!(
            (s.high_water, s.allocations, s.exhausted, s.in_use),
            (3, 4, 1, 3)
        );
    }

    #[test]
    fn mshr_merges_secondary_misses_and_returns_targets_in_order() {
        let mut m = MshrFile::new(2, 2);
        assert_eq!(m.insert(0x40, 'a'), Ok(true));
        assert_eq!(m.insert(0x40, 'b'), Ok(false));
        assert_eq!(m.insert(0x40, 'c'), Err(MshrRefusal::TargetsFull));
        assert_eq!(m.insert(0x80, 'd'), Ok(true));
        assert_eq!(m.insert(0xc0, 'e'), Err(MshrRefusal::MshrFull));
        let mut out = Vec::new();
        assert!(!m.complete(0xc0, &mut out));
        assert!(m.complete(0x40, &mut out));
        assert_eq!(out, vec!['a', 'b']);
        assert_eq!(m.insert(0xc0, 'e'), Ok(true));
        let s = m.stats();
        assert_eq!(
            (s.allocations, s.merges, s.high_water, s.in_use),
            (3, 1, 2, 2)
        );
    }
}
