//! A non-blocking set-associative cache with MSHRs, banks and LRU replacement: the timing
//! and hit/miss model of a cache, driven by a unit (the data itself stays in the functional
//! model; the cache only says when it is there).
//!
//! # Semantics
//! - **Geometry**: `size_bytes / (ways * line_bytes)` sets (a power of two); a line
//!   address `a / line_bytes` maps to set `line % sets` and bank `line % banks`.
//! - **Banks**: each bank takes one access per cycle; a second access to a busy bank in the
//!   same cycle is refused ([`Refusal::BankBusy`]) and may retry the next cycle. Fills use a
//!   separate port and take no bank cycle.
//! - **Requests over two lines** (a 48-byte triangle crossing a 64-byte line boundary) are
//!   split into two line accesses, accepted or refused together. With the two lines in
//!   different banks both are read in the same cycle; in the same bank (one bank) the bank
//!   is held for two cycles and the data is ready one cycle later. The request completes
//!   when both lines are there. A request must be 1 to `line_bytes` bytes (so it touches at
//!   most two lines); others are refused with [`Refusal::TooWide`], a caller bug that a
//!   retry does not fix.
//! - **Hits** are ready `hit_latency` cycles after the access. A **primary miss** takes a
//!   free MSHR and asks the caller to fetch the line ([`Access::Miss`]); a **secondary
//!   miss** to a line already being fetched is merged into its MSHR
//!   ([`Access::MergedMiss`]) if the entry has a free target slot. With a tag, the request
//!   waits in the MSHR and [`Cache::fill`] returns it when its line (or last line) arrives,
//!   ready in the fill cycle (the fill forwards its data) or at its hit-part's ready cycle
//!   if later. Without a tag (a unit "looping for next chance", \[P4\]), the line is
//!   fetched but nothing waits: the caller retries later.
//! - **Replacement**: LRU within the set (an invalid way first); hits and fills make a line
//!   most recently used.
//! - **Writes**: [`WritePolicy::WriteBackAllocate`]: a write hit marks the line dirty; a
//!   write miss fetches the line like a read and the fill installs it dirty; a dirty victim
//!   is returned by `fill` as a write-back for the caller to send to memory.
//!   [`WritePolicy::WriteThroughNoAllocate`]: every write goes to memory (the caller sends
//!   it); a write hit refreshes LRU, a write miss allocates nothing and returns
//!   [`Access::Bypass`]; lines are never dirty.

use serde::Serialize;

use super::tags::MshrFile;
use super::{ConfigError, Cycle};
use crate::dram::AccessKind;

/// What a write does (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum WritePolicy {
    /// Write-back with write-allocate.
    WriteBackAllocate,
    /// Write-through with no write-allocate.
    WriteThroughNoAllocate,
}

/// Configuration of a [`Cache`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct CacheConfig {
    /// Name for reports.
    pub name: String,
    /// Capacity in bytes.
    pub size_bytes: u64,
    /// Associativity.
    pub ways: u32,
    /// Line size in bytes (a power of two).
    pub line_bytes: u32,
    /// Banks, interleaved by line (a power of two).
    pub banks: u32,
    /// Miss status holding registers: lines that can be outstanding at once.
    pub mshrs: u32,
    /// Requests that can wait on one outstanding line.
    pub targets_per_mshr: u32,
    /// Cycles from an accepted hit to its data.
    pub hit_latency: Cycle,
    /// What writes do.
    pub write_policy: WritePolicy,
}

impl CacheConfig {
    /// Number of sets, or why the configuration cannot be used.
    pub fn validate(&self) -> Result<u64, ConfigError> {
        let bad = |r: String| Err(ConfigError::new(format!("cache {}", self.name), r));
        if self.size_bytes == 0 {
            return bad("size of zero bytes".into());
        }
        if self.ways == 0 {
            return bad("zero ways".into());
        }
        if self.line_bytes == 0 || !self.line_bytes.is_power_of_two() {
            return bad(format!(
                "line of {} bytes is not a power of two",
                self.line_bytes
            ));
        }
        let set_bytes = self.ways as u64 * self.line_bytes as u64;
        if !self.size_bytes.is_multiple_of(set_bytes) {
            return bad(format!(
                "size {} is not a multiple of ways x line = {set_bytes} bytes",
                self.size_bytes
            ));
        }
        let sets = self.size_bytes / set_bytes;
        if !sets.is_power_of_two() {
            return bad(format!("{sets} sets is not a power of two"));
        }
        if self.banks == 0 || !self.banks.is_power_of_two() {
            return bad(format!("{} banks is not a power of two", self.banks));
        }
        if self.mshrs == 0 || self.targets_per_mshr == 0 {
            return bad("needs at least one MSHR with one target".into());
        }
        if self.mshrs > u16::MAX as u32 || self.targets_per_mshr > u16::MAX as u32 {
            return bad("more than 65535 MSHRs or targets".into());
        }
        Ok(sets)
    }
}

/// Why an access was not accepted (nothing changed in the cache).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Refusal {
    /// A primary miss needs an MSHR and none is free.
    MshrFull,
    /// A secondary miss's MSHR has no free target slot.
    TargetsFull,
    /// The bank already took an access this cycle.
    BankBusy,
    /// The request is 0 bytes or wider than a line (a caller bug; retrying does not help).
    TooWide,
}

/// The outcome of [`Cache::access`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Every line is present: the data is ready at this cycle.
    Hit {
        /// Cycle the data is ready.
        ready_at: Cycle,
    },
    /// At least one line must be fetched: send a read for each address given (line-aligned
    /// byte addresses, one or two), then call [`Cache::fill`] when each arrives.
    Miss {
        /// Lines to fetch.
        fetch: [Option<u64>; 2],
    },
    /// No new fetch is needed, but a line is already being fetched: the request waits for
    /// its fill.
    MergedMiss,
    /// A write-through write that missed: not allocated, nothing waits (the caller sends the
    /// write to memory).
    Bypass {
        /// Cycle the write has left the cache.
        ready_at: Cycle,
    },
    /// Not accepted; retry later.
    Refused(Refusal),
}

/// A waiting request whose data arrived, returned by [`Cache::fill`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ready<T> {
    /// The request's tag.
    pub tag: T,
    /// Cycle its data is ready.
    pub ready_at: Cycle,
}

/// Counts of a [`Cache`]. Line accesses: a request over two lines counts two.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CacheStats {
    /// Requests accepted.
    pub accesses: u64,
    /// Accepted requests that spanned two lines.
    pub split_accesses: u64,
    /// Line accesses of accepted requests (hits + misses + merges).
    pub line_accesses: u64,
    /// Line accesses that found the line present.
    pub hits: u64,
    /// Line accesses that found the line absent and not outstanding (primary misses,
    /// including write-through write misses, which fetch nothing).
    pub misses: u64,
    /// Line accesses merged into an outstanding MSHR (secondary misses).
    pub merges: u64,
    /// Requests refused because no MSHR was free.
    pub refused_mshr_full: u64,
    /// Requests refused because an MSHR's targets were full.
    pub refused_targets_full: u64,
    /// Requests refused by a bank conflict.
    pub refused_bank_busy: u64,
    /// Requests refused as wider than a line or empty.
    pub refused_too_wide: u64,
    /// Lines installed.
    pub fills: u64,
    /// Valid lines replaced by a fill.
    pub evictions: u64,
    /// Dirty lines replaced (each a write-back to memory).
    pub writebacks: u64,
    /// Writes passed to memory by the write-through policy.
    pub write_throughs: u64,
}

impl CacheStats {
    /// Adds `o`'s counts to these (the statistics of several caches as one).
    pub fn add(&mut self, o: &CacheStats) {
        self.accesses += o.accesses;
        self.split_accesses += o.split_accesses;
        self.line_accesses += o.line_accesses;
        self.hits += o.hits;
        self.misses += o.misses;
        self.merges += o.merges;
        self.refused_mshr_full += o.refused_mshr_full;
        self.refused_targets_full += o.refused_targets_full;
        self.refused_bank_busy += o.refused_bank_busy;
        self.refused_too_wide += o.refused_too_wide;
        self.fills += o.fills;
        self.evictions += o.evictions;
        self.writebacks += o.writebacks;
        self.write_throughs += o.write_throughs;
    }

    /// Hits per line access (0 with no accesses).
    pub fn hit_rate(&self) -> f64 {
        if self.line_accesses == 0 {
            0.0
        } else {
            self.hits as f64 / self.line_accesses as f64
        }
    }

    /// All refused requests.
    pub fn refusals(&self) -> u64 {
        self.refused_mshr_full
            + self.refused_targets_full
            + self.refused_bank_busy
            + self.refused_too_wide
    }
}

/// A request waiting in the MSHRs.
#[derive(Clone, Copy, Debug)]
struct Waiting<T> {
    tag: T,
    /// Lines still to arrive.
    remaining: u8,
    /// Ready no earlier than this (its hit part).
    floor: Cycle,
}

/// How one line of a request is served.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Part {
    Hit(usize),
    Bypass,
    Merge(usize),
    Miss,
}

/// The cache. See the module documentation; `T` is the caller's request tag.
#[derive(Clone, Debug)]
pub struct Cache<T> {
    cfg: CacheConfig,
    line_shift: u32,
    set_mask: u64,
    bank_mask: u64,
    ways: usize,
    /// Per line slot (set * ways + way): line address, valid, dirty, LRU stamp.
    tag: Vec<u64>,
    valid: Vec<bool>,
    dirty: Vec<bool>,
    stamp: Vec<u64>,
    clock: u64,
    /// Cycle from which each bank is free.
    bank_free: Vec<Cycle>,
    mshr: MshrFile<u32>,
    /// Per MSHR entry: install the line dirty (a write-allocate write waits on it).
    fill_dirty: Vec<bool>,
    waiting: Vec<Option<Waiting<T>>>,
    free_waiting: Vec<u32>,
    scratch: Vec<u32>,
    stats: CacheStats,
}

impl<T: Copy> Cache<T> {
    /// An empty cache.
    ///
    /// # Errors
    /// An unusable configuration ([`CacheConfig::validate`]).
    pub fn new(cfg: CacheConfig) -> Result<Self, ConfigError> {
        let sets = cfg.validate()?;
        let lines = (sets * cfg.ways as u64) as usize;
        let slots = (cfg.mshrs * cfg.targets_per_mshr) as usize;
        Ok(Self {
            line_shift: cfg.line_bytes.trailing_zeros(),
            set_mask: sets - 1,
            bank_mask: cfg.banks as u64 - 1,
            ways: cfg.ways as usize,
            tag: vec![0; lines],
            valid: vec![false; lines],
            dirty: vec![false; lines],
            stamp: vec![0; lines],
            clock: 0,
            bank_free: vec![0; cfg.banks as usize],
            mshr: MshrFile::new(cfg.mshrs as usize, cfg.targets_per_mshr),
            fill_dirty: vec![false; cfg.mshrs as usize],
            waiting: vec![None; slots],
            free_waiting: (0..slots as u32).rev().collect(),
            scratch: Vec::with_capacity(cfg.targets_per_mshr as usize),
            stats: CacheStats::default(),
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &CacheConfig {
        &self.cfg
    }

    /// Statistics so far.
    pub fn stats(&self) -> &CacheStats {
        &self.stats
    }

    /// MSHRs in use.
    pub fn mshrs_in_use(&self) -> usize {
        self.mshr.in_use()
    }

    /// The MSHR file's statistics (high-water mark, merges).
    pub fn mshr_stats(&self) -> super::MshrStats {
        self.mshr.stats()
    }

    /// Byte address of the line holding `addr`.
    #[inline]
    pub fn line_of(&self, addr: u64) -> u64 {
        addr >> self.line_shift << self.line_shift
    }

    /// The way holding line index `line`, if present.
    #[inline]
    fn lookup(&self, line: u64) -> Option<usize> {
        let base = (line & self.set_mask) as usize * self.ways;
        (base..base + self.ways).find(|&s| self.valid[s] && self.tag[s] == line)
    }

    /// True when the line holding `addr` is present.
    pub fn contains(&self, addr: u64) -> bool {
        self.lookup(addr >> self.line_shift).is_some()
    }

    #[inline]
    fn touch(&mut self, slot: usize) {
        self.clock += 1;
        self.stamp[slot] = self.clock;
    }

    /// Offers a request of `bytes` bytes at `addr` at cycle `now` (see the module
    /// documentation). `tag`: `Some` to wait in the MSHRs and be returned by
    /// [`Self::fill`]; `None` to retry later instead.
    pub fn access(
        &mut self,
        addr: u64,
        bytes: u32,
        kind: AccessKind,
        tag: Option<T>,
        now: Cycle,
    ) -> Access {
        if bytes == 0 || bytes > self.cfg.line_bytes {
            self.stats.refused_too_wide += 1;
            return Access::Refused(Refusal::TooWide);
        }
        let first = addr >> self.line_shift;
        let last = (addr + bytes as u64 - 1) >> self.line_shift;
        let n = (last - first + 1) as usize;
        let lines = [first, last];
        // Banks.
        let (b0, b1) = (
            (first & self.bank_mask) as usize,
            (last & self.bank_mask) as usize,
        );
        let same_bank = n == 2 && b0 == b1;
        if self.bank_free[b0] > now || (n == 2 && self.bank_free[b1] > now) {
            self.stats.refused_bank_busy += 1;
            return Access::Refused(Refusal::BankBusy);
        }
        // Classify every line before changing anything.
        let write = kind == AccessKind::Write;
        let wt = self.cfg.write_policy == WritePolicy::WriteThroughNoAllocate;
        let mut parts = [Part::Hit(0); 2];
        let mut new_entries = 0;
        for k in 0..n {
            parts[k] = match self.lookup(lines[k]) {
                Some(s) => Part::Hit(s),
                None if write && wt => Part::Bypass,
                None => match self.mshr.find(lines[k]) {
                    Some(e) => Part::Merge(e),
                    None => {
                        new_entries += 1;
                        Part::Miss
                    }
                },
            };
        }
        let waits = parts[..n]
            .iter()
            .any(|p| matches!(p, Part::Merge(_) | Part::Miss));
        let free_entries = self.cfg.mshrs as usize - self.mshr.in_use();
        if new_entries > free_entries {
            self.stats.refused_mshr_full += 1;
            return Access::Refused(Refusal::MshrFull);
        }
        let waiter = tag.is_some() && waits;
        if waiter {
            let full = parts[..n].iter().any(|p| match p {
                Part::Merge(e) => !self.mshr.has_target_room(*e),
                _ => false,
            });
            if full || self.free_waiting.is_empty() {
                self.stats.refused_targets_full += 1;
                return Access::Refused(Refusal::TargetsFull);
            }
        }
        // Accepted.
        self.bank_free[b0] = now + 1 + same_bank as Cycle;
        if n == 2 {
            self.bank_free[b1] = self.bank_free[b1].max(now + 1);
        }
        let ready_at = now + self.cfg.hit_latency + same_bank as Cycle;
        self.stats.accesses += 1;
        self.stats.split_accesses += (n == 2) as u64;
        self.stats.line_accesses += n as u64;
        if write && wt {
            self.stats.write_throughs += 1;
        }
        let slot = if waiter {
            let s = self.free_waiting.pop().expect("checked");
            let remaining = parts[..n]
                .iter()
                .filter(|p| matches!(p, Part::Merge(_) | Part::Miss))
                .count() as u8;
            self.waiting[s as usize] = Some(Waiting {
                tag: tag.expect("waiter has a tag"),
                remaining,
                floor: ready_at,
            });
            Some(s)
        } else {
            None
        };
        let mut fetch = [None; 2];
        let mut bypass = false;
        for k in 0..n {
            match parts[k] {
                Part::Hit(s) => {
                    self.stats.hits += 1;
                    self.touch(s);
                    if write && !wt {
                        self.dirty[s] = true;
                    }
                }
                Part::Bypass => {
                    self.stats.misses += 1;
                    bypass = true;
                }
                Part::Merge(e) => {
                    self.stats.merges += 1;
                    if let Some(s) = slot {
                        self.mshr.insert(lines[k], s).expect("target room checked");
                    }
                    self.fill_dirty[e] |= write;
                }
                Part::Miss => {
                    self.stats.misses += 1;
                    match slot {
                        Some(s) => {
                            self.mshr.insert(lines[k], s).expect("entry checked");
                        }
                        None => self.mshr_open(lines[k]),
                    }
                    let e = self.mshr.find(lines[k]).expect("just inserted");
                    self.fill_dirty[e] = write;
                    fetch[k] = Some(lines[k] << self.line_shift);
                }
            }
        }
        if fetch[0].is_some() || fetch[1].is_some() {
            Access::Miss { fetch }
        } else if waits {
            Access::MergedMiss
        } else if bypass {
            Access::Bypass { ready_at }
        } else {
            Access::Hit { ready_at }
        }
    }

    /// Opens an MSHR entry with no waiting target (a tagless primary miss).
    fn mshr_open(&mut self, line: u64) {
        self.mshr.open(line).expect("entry checked");
    }

    /// The line at byte address `line_addr` arrived at cycle `now`: installs it, appends
    /// the requests that can now proceed to `ready`, and returns the dirty victim's line
    /// address if one was replaced (a write-back for the caller to send).
    ///
    /// # Errors
    /// If the line was not being fetched (a caller bug; nothing changes).
    pub fn fill(
        &mut self,
        line_addr: u64,
        now: Cycle,
        ready: &mut Vec<Ready<T>>,
    ) -> Result<Option<u64>, ConfigError> {
        let line = line_addr >> self.line_shift;
        let Some(e) = self.mshr.find(line) else {
            return Err(ConfigError::new(
                format!("cache {}", self.cfg.name),
                format!("fill of line {line_addr:#x}, which is not being fetched"),
            ));
        };
        let dirty = self.fill_dirty[e];
        self.fill_dirty[e] = false;
        let mut targets = std::mem::take(&mut self.scratch);
        targets.clear();
        self.mshr.complete(line, &mut targets);
        let slot = self.victim(line);
        let mut writeback = None;
        if self.valid[slot] {
            self.stats.evictions += 1;
            if self.dirty[slot] {
                self.stats.writebacks += 1;
                writeback = Some(self.tag[slot] << self.line_shift);
            }
        }
        self.tag[slot] = line;
        self.valid[slot] = true;
        self.dirty[slot] = dirty;
        self.touch(slot);
        self.stats.fills += 1;
        for &t in &targets {
            let w = self.waiting[t as usize].as_mut().expect("live waiter");
            w.remaining -= 1;
            if w.remaining == 0 {
                let w = self.waiting[t as usize].take().expect("live waiter");
                self.free_waiting.push(t);
                ready.push(Ready {
                    tag: w.tag,
                    ready_at: w.floor.max(now),
                });
            }
        }
        self.scratch = targets;
        Ok(writeback)
    }

    /// The way a fill of line index `line` replaces: an invalid way of its set first, else
    /// the least recently used.
    #[inline]
    fn victim(&self, line: u64) -> usize {
        let base = (line & self.set_mask) as usize * self.ways;
        (base..base + self.ways)
            .find(|&s| !self.valid[s])
            .unwrap_or_else(|| {
                (base..base + self.ways)
                    .min_by_key(|&s| self.stamp[s])
                    .expect("ways >= 1")
            })
    }

    /// Functional warming (for sampled simulation): the lines of `bytes` bytes at `addr`
    /// are read as if their fetch completed at once: a present line becomes most recently
    /// used, an absent one is installed clean in its LRU way. Nothing is counted and no
    /// time passes. A line being fetched is left alone, and a dirty line is never replaced
    /// (a read-only warm-up must not lose a write). Returns true when every line was
    /// present.
    pub fn warm(&mut self, addr: u64, bytes: u32) -> bool {
        let first = addr >> self.line_shift;
        let last = (addr + bytes.max(1) as u64 - 1) >> self.line_shift;
        let mut all = true;
        for line in first..=last {
            if let Some(s) = self.lookup(line) {
                self.touch(s);
                continue;
            }
            all = false;
            if self.mshr.find(line).is_some() {
                continue;
            }
            let s = self.victim(line);
            if self.valid[s] && self.dirty[s] {
                continue;
            }
            self.tag[s] = line;
            self.valid[s] = true;
            self.dirty[s] = false;
            self.touch(s);
        }
        all
    }

    /// Checks the structural invariants (a debugging aid for tests): no line twice in a
    /// set, no line both present and outstanding, every waiting request counted.
    pub fn check_invariants(&self) -> Result<(), String> {
        let sets = (self.set_mask + 1) as usize;
        for set in 0..sets {
            let base = set * self.ways;
            for a in base..base + self.ways {
                if !self.valid[a] {
                    if self.dirty[a] {
                        return Err(format!("invalid dirty line in set {set}"));
                    }
                    continue;
                }
                if (self.tag[a] & self.set_mask) as usize != set {
                    return Err(format!("line {:#x} in the wrong set {set}", self.tag[a]));
                }
                for b in a + 1..base + self.ways {
                    if self.valid[b] && self.tag[a] == self.tag[b] {
                        return Err(format!("line {:#x} twice in set {set}", self.tag[a]));
                    }
                }
                if self.mshr.find(self.tag[a]).is_some() {
                    return Err(format!("line {:#x} present and outstanding", self.tag[a]));
                }
            }
        }
        let live = self.waiting.iter().filter(|w| w.is_some()).count();
        if live + self.free_waiting.len() != self.waiting.len() {
            return Err("waiting slots lost".into());
        }
        Ok(())
    }

    /// Valid lines held.
    pub fn lines_held(&self) -> usize {
        self.valid.iter().filter(|v| **v).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::tests::Rng;
    use proptest::prelude::*;

    fn cfg(size: u64, ways: u32, line: u32, banks: u32, policy: WritePolicy) -> CacheConfig {
        CacheConfig {
            name: "test".into(),
            size_bytes: size,
            ways,
            line_bytes: line,
            banks,
            mshrs: 4,
            targets_per_mshr: 2,
            hit_latency: 2,
            write_policy: policy,
        }
    }

    const WB: WritePolicy = WritePolicy::WriteBackAllocate;
    const WT: WritePolicy = WritePolicy::WriteThroughNoAllocate;

    #[test]
    fn warming_installs_and_refreshes_lines_without_counting() {
        // 2 sets x 2 ways of 64-byte lines: lines 0, 2, 4 share set 0.
        let mut c: Cache<u32> = Cache::new(cfg(256, 2, 64, 1, WB)).unwrap();
        assert!(!c.warm(0, 64));
        assert!(!c.warm(128, 64));
        assert!(c.warm(0, 64), "line 0 present, now most recent");
        assert!(!c.warm(256, 64), "replaces line 2, the least recent");
        assert!(c.contains(0) && c.contains(256) && !c.contains(128));
        // A warm read across two lines (1 in set 1, 2 in set 0) installs both; line 2
        // replaces line 0, now the least recent of set 0.
        assert!(!c.warm(64 + 40, 48));
        assert!(c.contains(64) && c.contains(128) && !c.contains(0));
        assert_eq!(c.stats(), &CacheStats::default(), "warming counts nothing");
        // A line being fetched is left to its fill; a dirty line is never replaced.
        assert!(matches!(
            c.access(512, 8, AccessKind::Read, None, 0),
            Access::Miss { .. }
        ));
        assert!(!c.warm(512, 8));
        assert!(!c.contains(512));
        assert!(matches!(
            c.access(128, 8, AccessKind::Write, None, 1),
            Access::Hit { .. }
        ));
        assert!(matches!(
            c.access(256, 8, AccessKind::Write, None, 2),
            Access::Hit { .. }
        ));
        assert!(!c.warm(768, 8), "set 0 holds two dirty lines");
        assert!(c.contains(128) && c.contains(256) && !c.contains(768));
        c.check_invariants().unwrap();
    }

    #[test]
    fn bad_configurations_are_errors_not_panics() {
        let good = cfg(4096, 4, 64, 2, WB);
        assert_eq!(good.validate(), Ok(16));
        let cases: Vec<(CacheConfig, &str)> = vec![
            (
                CacheConfig {
                    size_bytes: 0,
                    ..good.clone()
                },
                "size",
            ),
            (
                CacheConfig {
                    ways: 0,
                    ..good.clone()
                },
                "ways",
            ),
            (
                CacheConfig {
                    line_bytes: 48,
                    ..good.clone()
                },
                "power of two",
            ),
            (
                CacheConfig {
                    line_bytes: 0,
                    ..good.clone()
                },
                "power of two",
            ),
            (
                CacheConfig {
                    ways: 3,
                    ..good.clone()
                },
                "multiple",
            ),
            (
                CacheConfig {
                    size_bytes: 3 * 4 * 64,
                    ..good.clone()
                },
                "sets",
            ),
            (
                CacheConfig {
                    banks: 0,
                    ..good.clone()
                },
                "banks",
            ),
            (
                CacheConfig {
                    banks: 3,
                    ..good.clone()
                },
                "banks",
            ),
            (
                CacheConfig {
                    mshrs: 0,
                    ..good.clone()
                },
                "MSHR",
            ),
            (
                CacheConfig {
                    targets_per_mshr: 0,
                    ..good.clone()
                },
                "MSHR",
            ),
        ];
        for (c, word) in cases {
            let e = Cache::<u32>::new(c.clone()).err().unwrap().to_string();
            assert!(e.contains(word) && e.contains("cache test"), "{c:?}: {e}");
        }
    }

    #[test]
    fn miss_fill_hit_and_secondary_misses_merge() {
        let mut c = Cache::new(cfg(1024, 2, 64, 1, WB)).unwrap();
        assert_eq!(
            c.access(0x100, 8, AccessKind::Read, Some(1), 0),
            Access::Miss {
                fetch: [Some(0x100), None]
            }
        );
        assert_eq!(
            c.access(0x108, 8, AccessKind::Read, Some(2), 1),
            Access::MergedMiss
        );
        assert_eq!(
            c.access(0x110, 8, AccessKind::Read, Some(3), 2),
            Access::Refused(Refusal::TargetsFull)
        );
        let mut ready = Vec::new();
        assert!(c.fill(0x200, 5, &mut ready).is_err());
        assert_eq!(c.fill(0x100, 10, &mut ready), Ok(None));
        assert_eq!(
            ready,
            vec![
                Ready {
                    tag: 1,
                    ready_at: 10
                },
                Ready {
                    tag: 2,
                    ready_at: 10
                }
            ]
        );
        assert_eq!(
            c.access(0x110, 8, AccessKind::Read, Some(3), 11),
            Access::Hit { ready_at: 13 }
        );
        let s = c.stats();
        assert_eq!(
            (s.hits, s.misses, s.merges, s.refused_targets_full),
            (1, 1, 1, 1)
        );
        assert!((s.hit_rate() - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn split_requests_wait_for_both_lines_and_banks_conflict() {
        // Two banks: a 48-byte request at 0x30 covers lines 0x00 (bank 0) and 0x40 (bank 1).
        let mut c = Cache::new(cfg(2048, 2, 64, 2, WB)).unwrap();
        assert_eq!(
            c.access(0x30, 48, AccessKind::Read, Some(7), 0),
            Access::Miss {
                fetch: [Some(0x00), Some(0x40)]
            }
        );
        // Both banks taken in cycle 0.
        assert_eq!(
            c.access(0x80, 4, AccessKind::Read, Some(8), 0),
            Access::Refused(Refusal::BankBusy)
        );
        let mut ready = Vec::new();
        c.fill(0x40, 3, &mut ready).unwrap();
        assert!(ready.is_empty(), "one line still missing");
        c.fill(0x00, 6, &mut ready).unwrap();
        assert_eq!(
            ready,
            vec![Ready {
                tag: 7,
                ready_at: 6
            }]
        );
        assert_eq!(c.stats().split_accesses, 1);
        assert_eq!(c.stats().line_accesses, 2);
        // One bank: both lines in the same bank, read over two cycles.
        let mut c = Cache::new(cfg(2048, 2, 64, 1, WB)).unwrap();
        c.access(0x00, 4, AccessKind::Read, None, 0);
        c.access(0x40, 4, AccessKind::Read, None, 1);
        c.fill(0x00, 2, &mut ready).unwrap();
        c.fill(0x40, 2, &mut ready).unwrap();
        assert_eq!(
            c.access(0x30, 48, AccessKind::Read, Some(1), 5),
            Access::Hit {
                ready_at: 5 + 2 + 1
            }
        );
        assert_eq!(
            c.access(0x00, 4, AccessKind::Read, Some(2), 6),
            Access::Refused(Refusal::BankBusy)
        );
        assert!(matches!(
            c.access(0x00, 4, AccessKind::Read, Some(2), 7),
            Access::Hit { .. }
        ));
        assert_eq!(
            c.access(0x00, 65, AccessKind::Read, Some(2), 9),
            Access::Refused(Refusal::TooWide)
        );
    }

    #[test]
    fn tagless_misses_fetch_once_and_the_retry_hits() {
        let mut c = Cache::<u32>::new(cfg(1024, 2, 64, 1, WB)).unwrap();
        assert!(matches!(
            c.access(0, 4, AccessKind::Read, None, 0),
            Access::Miss { .. }
        ));
        // Retries while the line is on its way merge without taking target slots.
        for t in 1..5 {
            assert_eq!(
                c.access(0, 4, AccessKind::Read, None, t),
                Access::MergedMiss
            );
        }
        let mut ready = Vec::new();
        c.fill(0, 9, &mut ready).unwrap();
        assert!(ready.is_empty());
        assert!(matches!(
            c.access(0, 4, AccessKind::Read, None, 10),
            Access::Hit { .. }
        ));
        assert_eq!(c.mshr_stats().allocations, 1);
    }

    #[test]
    fn dirty_victims_are_written_back_and_write_through_never_allocates() {
        // Direct-mapped, 2 sets of 64 B: 0x000 and 0x080 share set 0.
        let mut c = Cache::new(cfg(128, 1, 64, 1, WB)).unwrap();
        let mut ready = Vec::new();
        assert!(matches!(
            c.access(0x000, 4, AccessKind::Write, Some(1), 0),
            Access::Miss { .. }
        ));
        assert_eq!(c.fill(0x000, 3, &mut ready), Ok(None));
        assert!(matches!(
            c.access(0x080, 4, AccessKind::Read, Some(2), 4),
            Access::Miss { .. }
        ));
        assert_eq!(c.fill(0x080, 8, &mut ready), Ok(Some(0x000)));
        let s = c.stats();
        assert_eq!((s.evictions, s.writebacks), (1, 1));

        let mut c = Cache::new(cfg(128, 1, 64, 1, WT)).unwrap();
        assert_eq!(
            c.access(0x000, 4, AccessKind::Write, Some(1), 0),
            Access::Bypass { ready_at: 2 }
        );
        assert!(!c.contains(0));
        assert!(matches!(
            c.access(0x000, 4, AccessKind::Read, Some(2), 1),
            Access::Miss { .. }
        ));
        c.fill(0x000, 3, &mut ready).unwrap();
        assert_eq!(
            c.access(0x000, 4, AccessKind::Write, Some(3), 4),
            Access::Hit { ready_at: 6 }
        );
        assert!(matches!(
            c.access(0x080, 4, AccessKind::Read, Some(4), 5),
            Access::Miss { .. }
        ));
        assert_eq!(
            c.fill(0x080, 8, &mut ready),
            Ok(None),
            "write-through lines are clean"
        );
        assert_eq!(c.stats().write_throughs, 2);
    }

    /// The reference: per-set LRU lists (front = least recent), a list of lines being
    /// fetched, and fills applied when the driver says. With fills applied at once it is
    /// the plain blocking cache.
    struct Reference {
        sets: u64,
        ways: usize,
        wt: bool,
        lru: Vec<Vec<(u64, bool)>>,
        pending: Vec<(u64, bool)>,
        stats: CacheStats,
    }

    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    enum RefOutcome {
        Hit,
        Miss,
        Merge,
        Bypass,
    }

    impl Reference {
        fn new(c: &CacheConfig) -> Self {
            let sets = c.validate().unwrap();
            Self {
                sets,
                ways: c.ways as usize,
                wt: c.write_policy == WT,
                lru: vec![Vec::new(); sets as usize],
                pending: Vec::new(),
                stats: CacheStats::default(),
            }
        }

        fn access(&mut self, line: u64, write: bool) -> RefOutcome {
            self.stats.line_accesses += 1;
            let set = &mut self.lru[(line % self.sets) as usize];
            if let Some(p) = set.iter().position(|e| e.0 == line) {
                let (l, d) = set.remove(p);
                set.push((l, d || (write && !self.wt)));
                self.stats.hits += 1;
                return RefOutcome::Hit;
            }
            if write && self.wt {
                self.stats.misses += 1;
                return RefOutcome::Bypass;
            }
            if let Some(p) = self.pending.iter_mut().find(|e| e.0 == line) {
                p.1 |= write;
                self.stats.merges += 1;
                return RefOutcome::Merge;
            }
            self.pending.push((line, write));
            self.stats.misses += 1;
            RefOutcome::Miss
        }

        fn fill(&mut self, line: u64) {
            let p = self
                .pending
                .iter()
                .position(|e| e.0 == line)
                .expect("pending");
            let (_, dirty) = self.pending.remove(p);
            let set = &mut self.lru[(line % self.sets) as usize];
            if set.len() == self.ways {
                let (_, d) = set.remove(0);
                self.stats.evictions += 1;
                self.stats.writebacks += d as u64;
            }
            set.push((line, dirty));
            self.stats.fills += 1;
        }
    }

    #[derive(Clone, Copy, Debug)]
    enum Dist {
        Uniform,
        Strided,
        HotSet,
        Sequential,
    }

    /// A stream of (address, bytes, is_write).
    fn stream(dist: Dist, seed: u64, len: usize, line: u32) -> Vec<(u64, u32, bool)> {
        let mut r = Rng::new(seed);
        let sizes: Vec<u32> = [4u32, 16, 32, 48, 64]
            .into_iter()
            .filter(|&b| b <= line)
            .collect();
        let stride = 4 * (1 + r.below(64));
        let mut seq = r.below(1 << 16) & !3;
        (0..len)
            .map(|i| {
                let bytes = sizes[r.below(sizes.len() as u64) as usize];
                let addr = match dist {
                    Dist::Uniform => r.below(1 << 16) & !3,
                    Dist::Strided => (i as u64 * stride) % (1 << 15),
                    Dist::HotSet => {
                        if r.below(10) < 9 {
                            r.below(2048) & !3
                        } else {
                            r.below(1 << 18) & !3
                        }
                    }
                    Dist::Sequential => {
                        let a = seq;
                        seq += bytes as u64;
                        a
                    }
                };
                (addr, bytes, r.below(10) < 3)
            })
            .collect()
    }

    fn configs() -> impl Strategy<Value = CacheConfig> {
        (
            prop::sample::select(vec![512u64, 1024, 2048, 4096, 16384]),
            prop::sample::select(vec![1u32, 2, 4, 8]),
            prop::sample::select(vec![16u32, 32, 64]),
            prop::sample::select(vec![1u32, 2, 4]),
            2u32..9,
            1u32..4,
            0u64..4,
            any::<bool>(),
        )
            .prop_map(
                |(size, ways, line, banks, mshrs, targets, lat, wt)| CacheConfig {
                    name: "prop".into(),
                    size_bytes: size,
                    ways,
                    line_bytes: line,
                    banks,
                    mshrs,
                    targets_per_mshr: targets,
                    hit_latency: lat,
                    write_policy: if wt { WT } else { WB },
                },
            )
            .prop_filter("valid", |c| c.validate().is_ok())
    }

    fn dists() -> impl Strategy<Value = Dist> {
        prop::sample::select(vec![
            Dist::Uniform,
            Dist::Strided,
            Dist::HotSet,
            Dist::Sequential,
        ])
    }

    /// Feeds an accepted access's lines to the reference, in ascending line order, and
    /// checks the cache's outcome agrees.
    fn feed(
        rf: &mut Reference,
        c: &CacheConfig,
        addr: u64,
        bytes: u32,
        write: bool,
        got: Access,
    ) -> Result<(), TestCaseError> {
        let shift = c.line_bytes.trailing_zeros();
        let (first, last) = (addr >> shift, (addr + bytes as u64 - 1) >> shift);
        let outs: Vec<RefOutcome> = (first..=last).map(|l| rf.access(l, write)).collect();
        let expect_fetch: Vec<u64> = (first..=last)
            .zip(&outs)
            .filter(|(_, o)| **o == RefOutcome::Miss)
            .map(|(l, _)| l << shift)
            .collect();
        match got {
            Access::Hit { .. } => prop_assert!(outs.iter().all(|o| *o == RefOutcome::Hit)),
            Access::Bypass { .. } => {
                prop_assert!(outs.contains(&RefOutcome::Bypass));
                prop_assert!(
                    !outs.contains(&RefOutcome::Miss) && !outs.contains(&RefOutcome::Merge)
                );
            }
            Access::MergedMiss => {
                prop_assert!(
                    outs.contains(&RefOutcome::Merge) && !outs.contains(&RefOutcome::Miss)
                );
            }
            Access::Miss { fetch } => {
                let f: Vec<u64> = fetch.iter().flatten().copied().collect();
                prop_assert_eq!(f, expect_fetch);
            }
            Access::Refused(r) => prop_assert!(false, "refused {:?}", r),
        }
        Ok(())
    }

    fn same_counts(a: &CacheStats, b: &CacheStats) -> Result<(), TestCaseError> {
        prop_assert_eq!(
            (
                a.line_accesses,
                a.hits,
                a.misses,
                a.merges,
                a.fills,
                a.evictions,
                a.writebacks
            ),
            (
                b.line_accesses,
                b.hits,
                b.misses,
                b.merges,
                b.fills,
                b.evictions,
                b.writebacks
            )
        );
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        /// Fills applied at once: the hit/miss sequence and every count equal the plain
        /// blocking LRU reference, access by access.
        #[test]
        fn immediate_fills_equal_the_reference(
            c in configs(), dist in dists(), seed in any::<u64>(),
        ) {
            let mut cache = Cache::new(c.clone()).unwrap();
            let mut rf = Reference::new(&c);
            let mut ready = Vec::new();
            let mut now = 0;
            for (i, &(addr, bytes, write)) in stream(dist, seed, 400, c.line_bytes).iter().enumerate() {
                let kind = if write { AccessKind::Write } else { AccessKind::Read };
                now += 2; // banks always free
                let got = cache.access(addr, bytes, kind, Some(i), now);
                feed(&mut rf, &c, addr, bytes, write, got)?;
                if let Access::Miss { fetch } = got {
                    for l in fetch.iter().flatten() {
                        let wb = cache.fill(*l, now, &mut ready).unwrap();
                        let before = rf.stats.writebacks;
                        rf.fill(l >> c.line_bytes.trailing_zeros());
                        prop_assert_eq!(wb.is_some(), rf.stats.writebacks > before);
                    }
                }
                prop_assert_eq!(cache.stats().merges, 0);
                same_counts(cache.stats(), &rf.stats)?;
            }
            cache.check_invariants().map_err(TestCaseError::fail)?;
        }

        /// Fills after random delays, several accesses per cycle (bank conflicts), refusals
        /// retried: the counts equal the reference fed the same accepted order and fill
        /// order; every access completes exactly once; the structure stays sound.
        #[test]
        fn delayed_fills_keep_the_invariants(
            c in configs(), dist in dists(), seed in any::<u64>(), max_delay in 1u64..60,
        ) {
            let mut cache = Cache::new(c.clone()).unwrap();
            let mut rf = Reference::new(&c);
            let mut rng = Rng::new(seed ^ 0x5555);
            let work = stream(dist, seed, 300, c.line_bytes);
            let capacity_lines = (c.size_bytes / c.line_bytes as u64) as usize;
            // (due cycle, line address), kept sorted by due cycle (stable).
            let mut fills: Vec<(Cycle, u64)> = Vec::new();
            let mut done: Vec<Option<Cycle>> = vec![None; work.len()];
            let mut issued_at = vec![0; work.len()];
            let mut ready: Vec<Ready<usize>> = Vec::new();
            let mut next = 0;
            let mut now: Cycle = 0;
            while next < work.len() || !fills.is_empty() {
                // Fills due now, in order.
                while fills.first().is_some_and(|f| f.0 <= now) {
                    let (_, l) = fills.remove(0);
                    ready.clear();
                    cache.fill(l, now, &mut ready).unwrap();
                    rf.fill(l >> c.line_bytes.trailing_zeros());
                    for r in &ready {
                        prop_assert!(done[r.tag].is_none(), "completed twice");
                        prop_assert!(r.ready_at >= now && r.ready_at >= issued_at[r.tag]);
                        done[r.tag] = Some(r.ready_at);
                    }
                    cache.check_invariants().map_err(TestCaseError::fail)?;
                }
                // Up to three accesses this cycle; stop at the first refusal (in order).
                for _ in 0..1 + rng.below(3) {
                    if next == work.len() {
                        break;
                    }
                    let (addr, bytes, write) = work[next];
                    let kind = if write { AccessKind::Write } else { AccessKind::Read };
                    let got = cache.access(addr, bytes, kind, Some(next), now);
                    if let Access::Refused(_) = got {
                        break;
                    }
                    feed(&mut rf, &c, addr, bytes, write, got)?;
                    issued_at[next] = now;
                    match got {
                        Access::Hit { ready_at } | Access::Bypass { ready_at } => {
                            done[next] = Some(ready_at);
                        }
                        Access::Miss { fetch } => {
                            for l in fetch.iter().flatten() {
                                let due = now + 1 + rng.below(max_delay);
                                let at = fills.partition_point(|f| f.0 <= due);
                                fills.insert(at, (due, *l));
                            }
                        }
                        _ => {}
                    }
                    next += 1;
                }
                same_counts(cache.stats(), &rf.stats)?;
                prop_assert!(cache.lines_held() <= capacity_lines);
                prop_assert!(cache.mshrs_in_use() <= c.mshrs as usize);
                now += 1;
            }
            prop_assert!(done.iter().all(|d| d.is_some()), "an access never completed");
            let s = cache.stats();
            prop_assert_eq!(s.accesses, work.len() as u64);
            prop_assert_eq!(s.hits + s.misses + s.merges, s.line_accesses);
            prop_assert_eq!(cache.mshrs_in_use(), 0);
            cache.check_invariants().map_err(TestCaseError::fail)?;
        }
    }
}
