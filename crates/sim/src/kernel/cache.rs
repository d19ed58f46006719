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
        if self.size_bytes % set_bytes != 0 {
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
        // Victim: an invalid way first, else the least recently used.
        let base = (line & self.set_mask) as usize * self.ways;
        let slot = (base..base + self.ways)
            .find(|&s| !self.valid[s])
            .unwrap_or_else(|| {
                (base..base + self.ways)
                    .min_by_key(|&s| self.stamp[s])
                    .expect("ways >= 1")
            });
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
