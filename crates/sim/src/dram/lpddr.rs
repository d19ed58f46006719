//! Arbor's own model of DRAMsim3's JEDEC channel controller: the same commands at the same
//! DRAM cycles as DRAMsim3 for the configurations Arbor ships, but event-driven and with
//! compact state, so a run skips the DRAM cycles in which nothing can happen.
//!
//! The behaviour modelled is DRAMsim3's (umd-memsys DRAMsim3 1.0 as vendored by the
//! `dramsim3` crate 0.2.2, `Controller`, `CommandQueue`, `ChannelState`, `BankState`,
//! `Refresh`, `Timing` and `Config::AddressMapping`), for the options Arbor's
//! configurations use: separate read and write transaction queues, `PER_BANK` command
//! queues, `OPEN_PAGE`, `RANK_LEVEL_STAGGERED` refresh, one rank per channel, no
//! self-refresh. [`LpddrSystem::new`] refuses a configuration outside that set. What one
//! channel does in one DRAM cycle `c`, in order:
//! 1. transactions whose completion cycle is `c` are returned, in the order they were
//!    scheduled for return;
//! 2. at every `c > 0` that is a multiple of tREFI a refresh becomes due (they accumulate
//!    if one is still waiting);
//! 3. one command issues, if any is legal: while a refresh is due, only the refresh's
//!    own commands (a PRE to the first open bank, in bank order, whose PRE is legal;
//!    the REF once every bank is closed and may take it); otherwise the command queues
//!    are visited round robin starting after the one that issued last, and in each, the
//!    first entry whose next command (ACT on a closed bank; the RD/WR itself on its open
//!    row; PRE otherwise) is legal now, where a PRE is only for the queue's first entry
//!    and only when no entry of the queue hits the open row or the row has had 4 hits
//!    since its ACT, an ACT also needs the four-activation window, and a WR waits for an
//!    older RD of the same column in its queue. A RD returns every read of its address
//!    waiting, at `c + RL + BL/2`;
//! 4. the rank counts as active when a bank is open after the command, else as
//!    precharged (the cycle split of the energy model);
//! 5. at most one transaction moves into its bank's command queue (room for 8): from the
//!    write buffer while draining, else from the read queue, the oldest that fits.
//!    Draining starts when the write buffer is full or holds more than 8 writes while
//!    every command queue is empty, and lasts for as many writes as the buffer held; a
//!    write whose address has a read waiting stops it for this cycle and the next one
//!    that moves a read.
//!
//! A transaction arrives before the cycle's tick. A write is buffered (merged with a
//! waiting write of the same address) and returns at the next cycle; a read of an
//! address with a write waiting is served from the buffer and returns at the next cycle;
//! a read of an address with a read waiting joins it. The completions of reads of one
//! address are handed to the waiting requests in arrival order, as the DRAMsim3 port
//! matches them.
//!
//! Speed. Per bank the model keeps the open row, its hit count and the earliest cycle of
//! each command kind; per channel small vectors for the queues and waiting addresses
//! (scanned linearly: they hold at most a few dozen entries). After each tick it computes
//! the next cycle at which anything can happen: a completion, a refresh, a command that
//! becomes legal by the timing alone (the other conditions cannot change without an
//! event) or a transaction that can move (the draining state, which may alternate with
//! period 2 while a write waits for a read, is carried over the skipped cycles). The
//! cycles in between only add to the active or precharged count.

use super::dramsim3::SystemConfig;
use super::energy::CommandCounts;
use super::port::{Backend, BurstPort};
use super::{DramError, MemStats};
use crate::clock::PeriodFs;

/// The memory port over this model.
pub type LpddrPort = BurstPort<LpddrSystem>;

const RD: usize = 0;
const WR: usize = 1;
const ACT: usize = 2;
const PRE: usize = 3;
const REF: usize = 4;
const KINDS: usize = 5;

/// Delay scopes relative to the bank a command goes to.
const SAME_BANK: usize = 0;
const SAME_GROUP: usize = 1;
const OTHER_GROUP: usize = 2;

/// Everything a channel needs from the configuration.
#[derive(Clone, Debug)]
struct Params {
    banks: usize,
    banks_per_group: usize,
    cmd_queue_size: usize,
    trans_queue_size: usize,
    read_delay: u64,
    t_refi: u64,
    t_rfc: u64,
    t_faw: u64,
    /// `delay[issued][scope][target]`: cycles after an issued RD/WR/ACT/PRE before a
    /// target command may go to a bank of that scope; 0 means no constraint.
    delay: [[[u64; KINDS]; 3]; 4],
    map: AddressMap,
    /// When the transaction scheduler moves writes instead of reads.
    drain: Drain,
    /// RD/WR to an open row after which a PRE may close it while hits still wait
    /// (`row_hit_cap`; DRAMsim3: 4).
    row_hit_cap: u32,
}

/// The write-drain policy of the transaction scheduler (`write_drain`, a what-if key that
/// only this model reads; DRAMsim3's policy is the default).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Drain {
    /// DRAMsim3: drain as many writes as the buffer holds once it is full, or once it
    /// holds more than 8 while every command queue is empty (`write_drain = dramsim3`).
    Dramsim3,
    /// Ramulator-like (`write_drain = watermark`): enter write mode when more than
    /// `high` writes wait for their WR, or when no read waits for its RD; leave it when
    /// fewer than `low` writes wait and a read does. `high` and `low` are
    /// `write_high_watermark` and `write_low_watermark` percent of the write buffer
    /// (Ramulator: 80 and 20), rounded down (`low` at least 1). Only writes move in write mode, only reads
    /// otherwise; a write whose address has a read waiting is passed over.
    Watermark { high: usize, low: usize },
}

/// DRAMsim3's address map (`Config::AddressMapping`): the burst offset is dropped, then
/// the six fields, named most significant first in `address_mapping`, are packed from bit
/// 0 upwards.
#[derive(Clone, Copy, Debug)]
pub(crate) struct AddressMap {
    banks_per_group: usize,
    shift: u32,
    ch: (u32, u64),
    bg: (u32, u64),
    ba: (u32, u64),
    ro: (u32, u64),
    co: (u32, u64),
    /// XOR the bank field with the low bits of the row (`bank_xor = 1`, a what-if only
    /// this model reads; DRAMsim3 and the default: 0): permutation-based interleaving, so
    /// that addresses a multiple of a row's span apart fall in different banks.
    bank_xor: bool,
}

impl AddressMap {
    /// The map of `cfg` (one rank per channel).
    pub(crate) fn from_config(cfg: &SystemConfig) -> Result<Self, DramError> {
        let bad = |what: String| DramError::Config(format!("{}: {what}", cfg.name));
        let int_or = |key: &str, default: u64| -> Result<u64, DramError> {
            match cfg.value(key) {
                None => Ok(default),
                Some(v) => v
                    .parse()
                    .map_err(|_| bad(format!("'{key}' is not an integer"))),
            }
        };
        let bankgroups = int_or("bankgroups", 2)?;
        let banks_per_group = int_or("banks_per_group", 2)?;
        let rows = int_or("rows", 1 << 16)?;
        let columns = int_or("columns", 1 << 10)?;
        let bl = int_or("BL", 8)?;
        let channels = int_or("channels", 1)?;
        let bus_width = int_or("bus_width", 64)?;
        let map = cfg.value("address_mapping").unwrap_or("chrobabgraco");
        let widths = |f: &str| -> Option<u32> {
            Some(match f {
                "ch" => log2(channels),
                "ra" => 0,
                "bg" => log2(bankgroups),
                "ba" => log2(banks_per_group),
                "ro" => log2(rows),
                "co" => log2(columns).checked_sub(log2(bl))?,
                _ => return None,
            })
        };
        if map.len() != 12 || !map.is_ascii() {
            return Err(bad(format!("address mapping '{map}'")));
        }
        let mut pos = std::collections::HashMap::new();
        let mut at = 0;
        for i in (0..6).rev() {
            let f = &map[2 * i..2 * i + 2];
            let w = widths(f).ok_or_else(|| bad(format!("address mapping field '{f}'")))?;
            pos.insert(f, (at, (1u64 << w) - 1));
            at += w;
        }
        let field = |f: &str| pos.get(f).copied().ok_or_else(|| bad(format!("no '{f}'")));
        field("ra")?;
        let bank_xor = match int_or("bank_xor", 0)? {
            0 => false,
            1 => true,
            _ => return Err(bad("bank_xor must be 0 or 1".into())),
        };
        Ok(Self {
            bank_xor,
            banks_per_group: banks_per_group.max(1) as usize,
            shift: log2(bus_width / 8 * bl),
            ch: field("ch")?,
            bg: field("bg")?,
            ba: field("ba")?,
            ro: field("ro")?,
            co: field("co")?,
        })
    }

    #[inline]
    fn get(a: u64, (pos, mask): (u32, u64)) -> u64 {
        (a >> pos) & mask
    }

    /// Position and mask of the channel field.
    pub(crate) fn ch_field(&self) -> (u32, u64) {
        self.ch
    }

    /// Bits of the burst offset below the fields.
    pub(crate) fn shift(&self) -> u32 {
        self.shift
    }

    /// Channel of a byte address.
    #[inline]
    pub(crate) fn channel(&self, addr: u64) -> usize {
        Self::get(addr >> self.shift, self.ch) as usize
    }

    /// (flat bank, row, column) of a byte address.
    #[inline]
    fn decode(&self, addr: u64) -> (u16, u32, u32) {
        let a = addr >> self.shift;
        let mut ba = Self::get(a, self.ba);
        if self.bank_xor {
            ba ^= Self::get(a, self.ro) & self.ba.1;
        }
        let bank = Self::get(a, self.bg) as usize * self.banks_per_group + ba as usize;
        (
            bank as u16,
            Self::get(a, self.ro) as u32,
            Self::get(a, self.co) as u32,
        )
    }
}

fn log2(x: u64) -> u32 {
    if x <= 1 {
        0
    } else {
        63 - x.leading_zeros()
    }
}

impl Params {
    fn from_config(cfg: &SystemConfig) -> Result<(Self, usize), DramError> {
        let bad = |what: String| DramError::Config(format!("{}: {what}", cfg.name));
        let int_or = |key: &str, default: u64| -> Result<u64, DramError> {
            match cfg.value(key) {
                None => Ok(default),
                Some(v) => v
                    .parse()
                    .map_err(|_| bad(format!("'{key}' is not an integer"))),
            }
        };
        let str_or = |key: &str, default: &'static str| cfg.value(key).unwrap_or(default);
        let protocol = str_or("protocol", "DDR3");
        if !matches!(protocol, "DDR3" | "DDR4" | "LPDDR" | "LPDDR3" | "LPDDR4") {
            return Err(bad(format!("protocol {protocol} is not modelled")));
        }
        for (key, want, default) in [
            ("queue_structure", "PER_BANK", "PER_BANK"),
            ("row_buf_policy", "OPEN_PAGE", "OPEN_PAGE"),
            (
                "refresh_policy",
                "RANK_LEVEL_STAGGERED",
                "RANK_LEVEL_STAGGERED",
            ),
            ("unified_queue", "false", "false"),
            ("enable_self_refresh", "false", "false"),
            ("bankgroup_enable", "true", "true"),
        ] {
            let got = str_or(key, default);
            if !got.eq_ignore_ascii_case(want) {
                return Err(bad(format!("{key} = {got} is not modelled (only {want})")));
            }
        }
        let bankgroups = int_or("bankgroups", 2)?;
        let banks_per_group = int_or("banks_per_group", 2)?;
        let banks = bankgroups * banks_per_group;
        let rows = int_or("rows", 1 << 16)?;
        let columns = int_or("columns", 1 << 10)?;
        let device_width = int_or("device_width", 8)?;
        let bl = int_or("BL", 8)?;
        let channels = int_or("channels", 1)?;
        let bus_width = int_or("bus_width", 64)?;
        let channel_size = int_or("channel_size", 1024)?;
        let pow2 = [bankgroups, banks_per_group, rows, columns, bl, channels];
        if pow2.iter().any(|&x| x == 0 || !x.is_power_of_two())
            || device_width == 0
            || bus_width % device_width != 0
        {
            return Err(bad("bad organisation".into()));
        }
        // Ranks as DRAMsim3 derives them from the channel size.
        let devices = bus_width / device_width;
        let page = columns * device_width / 8;
        let megs_per_rank = page * (rows / 1024) / 1024 * banks * devices;
        let ranks = if megs_per_rank > channel_size {
            1
        } else {
            channel_size / megs_per_rank
        };
        if banks > 32 {
            return Err(bad(format!("{banks} banks (at most 32 are modelled)")));
        }
        if ranks != 1 {
            return Err(bad(format!(
                "{ranks} ranks per channel (only 1 is modelled)"
            )));
        }
        let t = |key: &str, default: u64| int_or(key, default);
        let al = t("AL", 0)?;
        let cl = t("CL", 12)?;
        let cwl = t("CWL", 12)?;
        let t_ccd_l = t("tCCD_L", 6)?;
        let t_ccd_s = t("tCCD_S", 4)?;
        let t_rtrs = t("tRTRS", 2)?;
        let t_rtp = t("tRTP", 5)?;
        let t_wtr_l = t("tWTR_L", 5)?;
        let t_wtr_s = t("tWTR_S", 5)?;
        let t_wr = t("tWR", 10)?;
        let t_rp = t("tRP", 10)?;
        let t_rrd_l = t("tRRD_L", 4)?;
        let t_rrd_s = t("tRRD_S", 4)?;
        let t_ras = t("tRAS", 24)?;
        let t_rcd = t("tRCD", 10)?;
        let t_rfc = t("tRFC", 74)?;
        let t_refi = t("tREFI", 7800)?;
        let t_faw = t("tFAW", 50)?;
        let t_ppd = t("tPPD", 0)?;
        if t_refi == 0 || t_rcd < al {
            return Err(bad("bad timing".into()));
        }
        let burst = bl / 2;
        let rl = al + cl;
        let wl = al + cwl;
        let read_delay = rl + burst;
        let write_delay = wl + burst;
        let one_group = bankgroups == 1;
        let rr_s = burst.max(t_ccd_s);
        let rr_l = if one_group { rr_s } else { burst.max(t_ccd_l) };
        let ww_s = rr_s;
        let ww_l = rr_l;
        // RD to WR may be negative in principle; DRAMsim3 adds it to the clock as an int.
        let r2w = (rl + burst + t_rtrs).saturating_sub(wl);
        let r2p = al + t_rtp;
        let w2r_s = write_delay + t_wtr_s;
        let w2r_l = if one_group {
            w2r_s
        } else {
            write_delay + t_wtr_l
        };
        let w2p = wl + burst + t_wr;
        let rrd_s = t_rrd_s;
        let rrd_l = if one_group { t_rrd_s } else { t_rrd_l };
        let t_rc = t_ras + t_rp;
        let a2rw = t_rcd - al;
        let mut delay = [[[0u64; KINDS]; 3]; 4];
        // Issued RD.
        delay[RD][SAME_BANK][RD] = rr_l;
        delay[RD][SAME_BANK][WR] = r2w;
        delay[RD][SAME_BANK][PRE] = r2p;
        delay[RD][SAME_GROUP][RD] = rr_l;
        delay[RD][SAME_GROUP][WR] = r2w;
        delay[RD][OTHER_GROUP][RD] = rr_s;
        delay[RD][OTHER_GROUP][WR] = r2w;
        // Issued WR.
        delay[WR][SAME_BANK][RD] = w2r_l;
        delay[WR][SAME_BANK][WR] = ww_l;
        delay[WR][SAME_BANK][PRE] = w2p;
        delay[WR][SAME_GROUP][RD] = w2r_l;
        delay[WR][SAME_GROUP][WR] = ww_l;
        delay[WR][OTHER_GROUP][RD] = w2r_s;
        delay[WR][OTHER_GROUP][WR] = ww_s;
        // Issued ACT.
        delay[ACT][SAME_BANK][ACT] = t_rc;
        delay[ACT][SAME_BANK][RD] = a2rw;
        delay[ACT][SAME_BANK][WR] = a2rw;
        delay[ACT][SAME_BANK][PRE] = t_ras;
        delay[ACT][SAME_GROUP][ACT] = rrd_l;
        delay[ACT][OTHER_GROUP][ACT] = rrd_s;
        // Issued PRE.
        delay[PRE][SAME_BANK][ACT] = t_rp;
        delay[PRE][SAME_BANK][REF] = t_rp;
        if protocol == "LPDDR4" {
            delay[PRE][SAME_GROUP][PRE] = t_ppd;
            delay[PRE][OTHER_GROUP][PRE] = t_ppd;
        }
        let map = AddressMap::from_config(cfg)?;
        let trans_queue_size = int_or("trans_queue_size", 32)? as usize;
        let cmd_queue_size = int_or("cmd_queue_size", 16)? as usize;
        // Empty queues would accept nothing (a run that never ends); absurd ones only
        // allocate.
        for (key, v) in [
            ("trans_queue_size", trans_queue_size),
            ("cmd_queue_size", cmd_queue_size),
        ] {
            if !(1..=4096).contains(&v) {
                return Err(bad(format!("{key} = {v} (1 to 4096)")));
            }
        }
        let drain = match str_or("write_drain", "dramsim3") {
            "dramsim3" => Drain::Dramsim3,
            "watermark" => {
                let high = int_or("write_high_watermark", 80)?;
                let low = int_or("write_low_watermark", 20)?;
                if low > high || high > 100 {
                    return Err(bad(format!("write watermarks {low}% / {high}%")));
                }
                Drain::Watermark {
                    high: trans_queue_size * high as usize / 100,
                    // At least 1, so that write mode ends once the buffer is empty.
                    low: (trans_queue_size * low as usize / 100).max(1),
                }
            }
            other => {
                return Err(bad(format!(
                    "write_drain = {other} (dramsim3 or watermark)"
                )))
            }
        };
        let row_hit_cap = int_or("row_hit_cap", 4)?;
        let params = Self {
            banks: banks as usize,
            banks_per_group: banks_per_group as usize,
            cmd_queue_size,
            trans_queue_size,
            read_delay,
            t_refi,
            t_rfc,
            t_faw,
            delay,
            map,
            drain,
            row_hit_cap: u32::try_from(row_hit_cap).map_err(|_| bad("row_hit_cap".into()))?,
        };
        Ok((params, channels as usize))
    }
}

#[derive(Clone, Copy, Debug)]
struct Bank {
    open: bool,
    row: u32,
    /// RD/WR to the open row since its ACT.
    hits: u32,
    /// Earliest cycle of each command kind.
    ready: [u64; KINDS],
}

/// A transaction in the read queue or write buffer, or a command-queue entry.
#[derive(Clone, Copy, Debug)]
struct Entry {
    addr: u64,
    row: u32,
    col: u32,
    bank: u16,
    is_write: bool,
}

/// A read waiting for its RD (DRAMsim3's pending-read map).
#[derive(Clone, Copy, Debug)]
struct Pending {
    addr: u64,
    token: u32,
    seq: u64,
}

/// A transaction scheduled to return at cycle `at`.
#[derive(Clone, Copy, Debug)]
struct Return {
    at: u64,
    addr: u64,
    token: u32,
    seq: u64,
    is_read: bool,
}

/// What the transaction scheduler would do in a cycle that starts with draining state
/// `d`: move entry `index` of the write buffer or read queue, and the state it leaves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Decision {
    moved: Option<(bool, usize)>,
    draining: i64,
}

/// One channel's controller.
#[derive(Clone, Debug)]
struct Channel {
    p: Params,
    /// The next cycle to tick.
    now: u64,
    /// No tick before this cycle can change anything.
    next_event: u64,
    /// Draining state at even and odd distances from `drain_base`, for skipped cycles.
    drain_cycle: [i64; 2],
    drain_base: u64,
    banks: Vec<Bank>,
    open_banks: u32,
    queues: Vec<Vec<Entry>>,
    queued: usize,
    rr: usize,
    read_q: Vec<Entry>,
    write_q: Vec<Entry>,
    /// Transactions per bank in the read queue and the write buffer, and bit `b` set when
    /// there are any (`[read, write]`).
    waiting_per_bank: [Vec<u16>; 2],
    waiting_mask: [u32; 2],
    /// Bit `b` set when bank `b`'s command queue is full.
    full_mask: u32,
    draining: i64,
    pending_rd: Vec<Pending>,
    pending_wr: Vec<u64>,
    returns: Vec<Return>,
    next_return: u64,
    refresh_due: u32,
    faw: std::collections::VecDeque<u64>,
    seq: u64,
    counts: CommandCounts,
    row_hits: u64,
}

impl Channel {
    fn new(p: Params) -> Self {
        let banks = p.banks;
        Self {
            now: 0,
            next_event: 0,
            drain_cycle: [0; 2],
            drain_base: 0,
            banks: vec![
                Bank {
                    open: false,
                    row: 0,
                    hits: 0,
                    ready: [0; KINDS],
                };
                banks
            ],
            open_banks: 0,
            queues: (0..banks)
                .map(|_| Vec::with_capacity(p.cmd_queue_size))
                .collect(),
            queued: 0,
            rr: 0,
            read_q: Vec::with_capacity(p.trans_queue_size),
            write_q: Vec::with_capacity(p.trans_queue_size),
            waiting_per_bank: [vec![0; banks], vec![0; banks]],
            waiting_mask: [0; 2],
            full_mask: 0,
            draining: 0,
            pending_rd: Vec::new(),
            pending_wr: Vec::new(),
            returns: Vec::new(),
            next_return: u64::MAX,
            refresh_due: 0,
            faw: std::collections::VecDeque::new(),
            seq: 0,
            counts: CommandCounts::default(),
            row_hits: 0,
            p,
        }
    }

    fn entry(&self, addr: u64, is_write: bool) -> Entry {
        let (bank, row, col) = self.p.map.decode(addr);
        Entry {
            addr,
            row,
            col,
            bank,
            is_write,
        }
    }

    fn can_add(&self, is_write: bool) -> bool {
        if is_write {
            self.write_q.len() < self.p.trans_queue_size
        } else {
            self.read_q.len() < self.p.trans_queue_size
        }
    }

    fn add(&mut self, addr: u64, is_write: bool, token: u32) {
        let seq = self.seq;
        self.seq += 1;
        let at = self.now + 1;
        let buffered = self.pending_wr.contains(&addr);
        if is_write {
            if !buffered {
                self.pending_wr.push(addr);
                let e = self.entry(addr, true);
                self.count_waiting(e.bank, true, true);
                self.write_q.push(e);
            }
            self.push_return(at, addr, token, seq, false);
        } else if buffered {
            self.push_return(at, addr, token, seq, true);
            self.keep_read_order(addr);
        } else {
            let joins = self.pending_rd.iter().any(|r| r.addr == addr);
            self.pending_rd.push(Pending { addr, token, seq });
            if !joins {
                let e = self.entry(addr, false);
                self.count_waiting(e.bank, false, true);
                self.read_q.push(e);
            }
        }
        self.next_event = self.now;
    }

    /// Keeps the per-bank counts of the read queue or write buffer.
    #[inline]
    fn count_waiting(&mut self, bank: u16, is_write: bool, added: bool) {
        let w = is_write as usize;
        let n = &mut self.waiting_per_bank[w][bank as usize];
        if added {
            *n += 1;
            self.waiting_mask[w] |= 1 << bank;
        } else {
            *n -= 1;
            if *n == 0 {
                self.waiting_mask[w] &= !(1 << bank);
            }
        }
    }

    /// Keeps `full_mask` for bank `bank`'s command queue.
    #[inline]
    fn note_queue(&mut self, bank: usize) {
        if self.queues[bank].len() >= self.p.cmd_queue_size {
            self.full_mask |= 1 << bank;
        } else {
            self.full_mask &= !(1 << bank);
        }
    }

    fn push_return(&mut self, at: u64, addr: u64, token: u32, seq: u64, is_read: bool) {
        self.returns.push(Return {
            at,
            addr,
            token,
            seq,
            is_read,
        });
        self.next_return = self.next_return.min(at);
    }

    /// After a read of `addr` was served from the write buffer: hands the completions of
    /// reads of `addr` to the requests in arrival order (the new completion may come
    /// before those of older reads still waiting).
    #[cold]
    fn keep_read_order(&mut self, addr: u64) {
        // Completion events in the order they will happen: scheduled returns by cycle
        // (ties in scheduling order), then the reads still waiting for their RD.
        let mut events: Vec<(u64, usize, bool)> = Vec::new();
        for (i, r) in self.returns.iter().enumerate() {
            if r.is_read && r.addr == addr {
                events.push((r.at, i, true));
            }
        }
        events.sort_by_key(|&(at, i, _)| (at, i));
        for (i, r) in self.pending_rd.iter().enumerate() {
            if r.addr == addr {
                events.push((u64::MAX, i, false));
            }
        }
        if events.len() < 2 {
            return;
        }
        let mut tokens: Vec<(u64, u32)> = events
            .iter()
            .map(|&(_, i, ret)| {
                if ret {
                    (self.returns[i].seq, self.returns[i].token)
                } else {
                    (self.pending_rd[i].seq, self.pending_rd[i].token)
                }
            })
            .collect();
        tokens.sort_unstable();
        for (&(_, i, ret), &(seq, token)) in events.iter().zip(&tokens) {
            if ret {
                self.returns[i].seq = seq;
                self.returns[i].token = token;
            } else {
                self.pending_rd[i].seq = seq;
                self.pending_rd[i].token = token;
            }
        }
    }

    /// The four-activation window allows an ACT at `c`.
    #[inline]
    fn faw_ok(&self, c: u64) -> bool {
        self.faw.len() < 4 || c >= self.faw[0]
    }

    /// The command the bank of queue `q` needs for `e`.
    #[inline]
    fn needed(b: &Bank, e: &Entry) -> usize {
        if !b.open {
            ACT
        } else if e.row == b.row {
            if e.is_write {
                WR
            } else {
                RD
            }
        } else {
            PRE
        }
    }

    /// Whether entry `j` of queue `q` may take its command, timing aside (conditions that
    /// change only with an event).
    #[inline]
    fn allowed(&self, q: usize, j: usize, kind: usize) -> bool {
        let queue = &self.queues[q];
        match kind {
            PRE => {
                let b = &self.banks[q];
                j == 0 && (b.hits >= self.p.row_hit_cap || !queue.iter().any(|x| x.row == b.row))
            }
            WR => {
                let e = &queue[j];
                !queue[..j]
                    .iter()
                    .any(|x| !x.is_write && x.row == e.row && x.col == e.col)
            }
            _ => true,
        }
    }

    /// The first entry of queue `q` whose command is legal at `c`.
    #[inline]
    fn first_ready(&self, q: usize, c: u64) -> Option<(usize, usize)> {
        let b = &self.banks[q];
        for (j, e) in self.queues[q].iter().enumerate() {
            let kind = Self::needed(b, e);
            if c < b.ready[kind] || (kind == ACT && !self.faw_ok(c)) {
                continue;
            }
            if self.allowed(q, j, kind) {
                return Some((j, kind));
            }
        }
        None
    }

    /// The refresh's next command at `c`: a PRE to bank `b`, or the REF.
    fn refresh_command(&self, c: u64) -> Option<(usize, usize)> {
        let mut closed_ready = 0;
        for (i, b) in self.banks.iter().enumerate() {
            let kind = if b.open { PRE } else { REF };
            if c < b.ready[kind] {
                continue;
            }
            if kind == PRE {
                return Some((i, PRE));
            }
            closed_ready += 1;
        }
        (closed_ready == self.banks.len()).then_some((0, REF))
    }

    /// Earliest cycle at or after `now` at which a command may become legal, or `bound`
    /// if that is earlier.
    fn next_command_time(&self, bound: u64) -> u64 {
        let mut t = bound;
        if self.refresh_due > 0 {
            if self.open_banks > 0 {
                for b in self.banks.iter().filter(|b| b.open) {
                    t = t.min(b.ready[PRE]);
                }
            } else {
                t = t.min(self.banks.iter().map(|b| b.ready[REF]).max().unwrap_or(0));
            }
        } else if self.queued > 0 {
            for (q, queue) in self.queues.iter().enumerate() {
                let b = &self.banks[q];
                for (j, e) in queue.iter().enumerate() {
                    let kind = Self::needed(b, e);
                    let mut at = b.ready[kind];
                    if at >= t {
                        continue;
                    }
                    if kind == ACT && self.faw.len() >= 4 {
                        at = at.max(self.faw[0]);
                    }
                    if at < t && self.allowed(q, j, kind) {
                        t = at;
                        if t <= self.now {
                            return self.now;
                        }
                    }
                }
            }
        }
        t.min(bound).max(self.now)
    }

    /// The transaction scheduler's choice for a cycle starting in draining state `d`.
    fn decide(&self, mut d: i64) -> Decision {
        if let Drain::Watermark { high, low } = self.p.drain {
            return self.decide_watermark(d > 0, high, low);
        }
        let wlen = self.write_q.len();
        if d == 0 && (wlen >= self.p.trans_queue_size || (wlen > 8 && self.queued == 0)) {
            d = wlen as i64;
        }
        let writes = d > 0;
        if self.waiting_mask[writes as usize] & !self.full_mask == 0 {
            // Every waiting transaction's command queue is full (or none waits).
            return Decision {
                moved: None,
                draining: d.max(0),
            };
        }
        let q = if writes { &self.write_q } else { &self.read_q };
        for (i, e) in q.iter().enumerate() {
            if self.queues[e.bank as usize].len() < self.p.cmd_queue_size {
                if writes {
                    if self.pending_rd.iter().any(|r| r.addr == e.addr) {
                        return Decision {
                            moved: None,
                            draining: -1,
                        };
                    }
                    d -= 1;
                }
                return Decision {
                    moved: Some((writes, i)),
                    draining: d,
                };
            }
        }
        Decision {
            moved: None,
            draining: d.max(0),
        }
    }

    /// [`Drain::Watermark`]'s choice in a cycle that starts in write mode or not.
    fn decide_watermark(&self, mut writes: bool, high: usize, low: usize) -> Decision {
        let wait_wr = self.pending_wr.len();
        let reads = !self.pending_rd.is_empty();
        if !writes && (wait_wr > high || !reads) {
            writes = true;
        } else if writes && wait_wr < low && reads {
            writes = false;
        }
        let draining = writes as i64;
        if self.waiting_mask[writes as usize] & !self.full_mask == 0 {
            return Decision {
                moved: None,
                draining,
            };
        }
        let q = if writes { &self.write_q } else { &self.read_q };
        let moved = q.iter().position(|e| {
            self.queues[e.bank as usize].len() < self.p.cmd_queue_size
                && !(writes && self.pending_rd.iter().any(|r| r.addr == e.addr))
        });
        Decision {
            moved: moved.map(|i| (writes, i)),
            draining,
        }
    }

    fn next_refresh(&self) -> u64 {
        let r = self.p.t_refi;
        if self.now == 0 {
            r
        } else {
            self.now.div_ceil(r) * r
        }
    }

    /// Issues command `kind` for bank `bank` (entry `j` of its queue for a RD/WR or ACT).
    fn issue(&mut self, c: u64, bank: usize, j: usize, kind: usize) {
        match kind {
            RD | WR => {
                let e = self.queues[bank].remove(j);
                self.note_queue(bank);
                self.queued -= 1;
                if kind == RD {
                    self.counts.read += 1;
                    let at = c + self.p.read_delay;
                    let mut i = 0;
                    while i < self.pending_rd.len() {
                        let r = self.pending_rd[i];
                        if r.addr == e.addr {
                            self.pending_rd.remove(i);
                            self.push_return(at, r.addr, r.token, r.seq, true);
                        } else {
                            i += 1;
                        }
                    }
                } else {
                    self.counts.write += 1;
                    let i = self
                        .pending_wr
                        .iter()
                        .position(|&a| a == e.addr)
                        .expect("a write command has its pending write");
                    self.pending_wr.swap_remove(i);
                }
                let b = &mut self.banks[bank];
                if b.hits != 0 {
                    self.row_hits += 1;
                }
                b.hits += 1;
            }
            ACT => {
                self.counts.act += 1;
                let row = self.queues[bank][j].row;
                let b = &mut self.banks[bank];
                b.open = true;
                b.row = row;
                self.open_banks += 1;
                if self.faw.front().is_some_and(|&f| c >= f) {
                    self.faw.pop_front();
                }
                self.faw.push_back(c + self.p.t_faw);
            }
            PRE => {
                self.counts.pre += 1;
                let b = &mut self.banks[bank];
                b.open = false;
                b.hits = 0;
                self.open_banks -= 1;
            }
            _ => {
                self.counts.refresh += 1;
                self.refresh_due -= 1;
                let t = c + self.p.t_rfc;
                for b in &mut self.banks {
                    b.ready[ACT] = b.ready[ACT].max(t);
                    b.ready[REF] = b.ready[REF].max(t);
                }
                return;
            }
        }
        let group = bank / self.p.banks_per_group;
        let table = &self.p.delay[kind];
        for (i, b) in self.banks.iter_mut().enumerate() {
            let scope = if i == bank {
                SAME_BANK
            } else if i / self.p.banks_per_group == group {
                SAME_GROUP
            } else {
                OTHER_GROUP
            };
            for (ready, &d) in b.ready.iter_mut().zip(&table[scope]) {
                if d > 0 {
                    *ready = (*ready).max(c + d);
                }
            }
        }
    }

    /// Ticks cycle `now`.
    fn tick(&mut self, done: &mut Vec<u32>) {
        let c = self.now;
        if self.next_return <= c {
            let mut next = u64::MAX;
            self.returns.retain(|r| {
                if r.at <= c {
                    done.push(r.token);
                    false
                } else {
                    next = next.min(r.at);
                    true
                }
            });
            self.next_return = next;
        }
        if c > 0 && c.is_multiple_of(self.p.t_refi) {
            self.refresh_due += 1;
        }
        let cmd = if self.refresh_due > 0 {
            self.refresh_command(c).map(|(b, k)| (b, 0, k))
        } else if self.queued > 0 {
            let n = self.queues.len();
            let mut found = None;
            let mut q = self.rr;
            for _ in 0..n {
                q += 1;
                if q == n {
                    q = 0;
                }
                if let Some((j, kind)) = self.first_ready(q, c) {
                    self.rr = q;
                    found = Some((q, j, kind));
                    break;
                }
            }
            found
        } else {
            None
        };
        if let Some((bank, j, kind)) = cmd {
            self.issue(c, bank, j, kind);
        }
        if self.open_banks == 0 {
            self.counts.precharged_rank_cycles += 1;
        } else {
            self.counts.active_rank_cycles += 1;
        }
        let decision = self.decide(self.draining);
        self.draining = decision.draining;
        if let Some((writes, i)) = decision.moved {
            let e = if writes {
                self.write_q.remove(i)
            } else {
                self.read_q.remove(i)
            };
            self.count_waiting(e.bank, writes, false);
            self.queues[e.bank as usize].push(e);
            self.note_queue(e.bank as usize);
            self.queued += 1;
        }
        self.now = c + 1;
        self.plan();
    }

    /// Sets `next_event` after a tick: the conditions for anything to happen at `now` or
    /// later are all known from the state, whether or not the tick was busy.
    fn plan(&mut self) {
        self.next_event = self.now;
        let bound = self.next_return.min(self.next_refresh());
        if bound <= self.now {
            return;
        }
        let d1 = self.draining;
        let first = self.decide(d1);
        if first.moved.is_some() {
            return;
        }
        let d2 = first.draining;
        if d2 != d1 {
            let second = self.decide(d2);
            if second.moved.is_some() || second.draining != d1 {
                return;
            }
        }
        self.drain_cycle = [d1, d2];
        self.drain_base = self.now;
        self.next_event = self.next_command_time(bound);
    }

    /// Advances quiet cycles up to `to` (no event before it).
    #[inline]
    fn skip_to(&mut self, to: u64) {
        let n = to - self.now;
        if self.open_banks == 0 {
            self.counts.precharged_rank_cycles += n;
        } else {
            self.counts.active_rank_cycles += n;
        }
        self.draining = self.drain_cycle[((to - self.drain_base) & 1) as usize];
        self.now = to;
    }
}

/// Arbor's controller model for every channel of one memory system: a [`Backend`] for the
/// shared memory port.
pub struct LpddrSystem {
    config: &'static SystemConfig,
    channels: Vec<Channel>,
    tck_ns: f64,
    dies_per_rank: u32,
}

impl LpddrSystem {
    /// The model of the system described by `config`.
    pub fn new(config: &'static SystemConfig) -> Result<Self, DramError> {
        let (p, n) = Params::from_config(config)?;
        let bus = config.int("bus_width")?;
        let dev = config.int("device_width")?;
        Ok(Self {
            config,
            channels: (0..n).map(|_| Channel::new(p.clone())).collect(),
            tck_ns: config.tck_ns()?,
            dies_per_rank: (bus / dev) as u32,
        })
    }

    /// Command counts and row hits so far, summed over channels.
    pub fn command_counts(&self) -> (CommandCounts, u64) {
        let mut c = CommandCounts::default();
        let mut hits = 0;
        for ch in &self.channels {
            let k = &ch.counts;
            c.act += k.act;
            c.pre += k.pre;
            c.read += k.read;
            c.write += k.write;
            c.refresh += k.refresh;
            c.active_rank_cycles += k.active_rank_cycles;
            c.precharged_rank_cycles += k.precharged_rank_cycles;
            hits += ch.row_hits;
        }
        (c, hits)
    }

    /// The configuration modelled.
    pub fn config(&self) -> &'static SystemConfig {
        self.config
    }
}

impl Backend for LpddrSystem {
    fn name(&self) -> String {
        format!("lpddr({})", self.config.name)
    }

    fn channels(&self) -> usize {
        self.channels.len()
    }

    #[inline]
    fn channel_of(&self, addr: u64) -> usize {
        self.channels[0].p.map.channel(addr)
    }

    #[inline]
    fn can_add(&self, channel: usize, is_write: bool) -> bool {
        self.channels[channel].can_add(is_write)
    }

    fn add(&mut self, channel: usize, addr: u64, is_write: bool, token: u32) {
        self.channels[channel].add(addr, is_write, token);
    }

    #[inline]
    fn now(&self) -> u64 {
        self.channels[0].now
    }

    #[inline]
    fn next_event(&self) -> u64 {
        self.channels
            .iter()
            .map(|c| c.next_event)
            .min()
            .unwrap_or(u64::MAX)
    }

    fn run_until(&mut self, to: u64, done: &mut Vec<u32>) {
        while self.now() < to {
            let ev = self.next_event();
            let now = self.now();
            if ev > now {
                let t = ev.min(to);
                for ch in &mut self.channels {
                    ch.skip_to(t);
                }
            } else {
                for ch in &mut self.channels {
                    if ch.next_event > now {
                        ch.skip_to(now + 1);
                    } else {
                        ch.tick(done);
                    }
                }
            }
        }
    }

    fn fill_stats(&self, s: &mut MemStats) {
        let (counts, row_hits) = self.command_counts();
        super::port::fill_command_stats(
            s,
            self.config,
            &counts,
            row_hits,
            self.dies_per_rank,
            self.tck_ns,
        );
    }
}

impl BurstPort<LpddrSystem> {
    /// Opens the shipped system `name` driven by a unit clock of period `unit_period_fs`.
    pub fn open(name: &str, unit_period_fs: PeriodFs) -> Result<Self, DramError> {
        let config = super::port::shipped_system(name)?;
        Self::with_config(config, unit_period_fs)
    }

    /// Opens a system from its configuration.
    pub fn with_config(
        config: &'static SystemConfig,
        unit_period_fs: PeriodFs,
    ) -> Result<Self, DramError> {
        if unit_period_fs == 0 {
            return Err(DramError::Config("unit clock period of zero".into()));
        }
        let system = LpddrSystem::new(config)?;
        let tck_ns = config.tck_ns()?;
        BurstPort::for_system(system, config, tck_ns, unit_period_fs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The map of `system` with what-if `options` (as `dram::open` builds it).
    fn map(system: &str, options: &str) -> AddressMap {
        let base = super::super::dramsim3::system(system).unwrap();
        let ini = format!("{options}\n{}", base.ini);
        let cfg = SystemConfig {
            name: base.name,
            ini: Box::leak(ini.into_boxed_str()),
            memspec: base.memspec,
        };
        AddressMap::from_config(&cfg).unwrap()
    }

    #[test]
    fn bank_xor_spreads_rows_over_banks_and_is_off_by_default() {
        let plain = map("lpddr3-1333-4x64", "");
        let off = map("lpddr3-1333-4x64", "bank_xor = 0");
        let on = map("lpddr3-1333-4x64", "bank_xor = 1");
        // 256 KiB = one row of every bank on this system: the same bank without the XOR.
        let addrs: Vec<u64> = (0..8).map(|k| 0x1_2340 + (k << 18)).collect();
        let banks = |m: &AddressMap| -> Vec<u16> { addrs.iter().map(|&a| m.decode(a).0).collect() };
        assert!(banks(&plain).iter().all(|&b| b == banks(&plain)[0]));
        assert_eq!(banks(&plain), banks(&off));
        let mut spread = banks(&on);
        spread.sort_unstable();
        assert_eq!(spread, (0..8).collect::<Vec<u16>>());
        for a in (0..1u64 << 24).step_by(4099 * 64) {
            let (p, o) = (plain.decode(a), on.decode(a));
            assert_eq!((p.1, p.2, plain.channel(a)), (o.1, o.2, on.channel(a)));
        }
    }
}

#[cfg(test)]
mod tests_refresh {
    //! Exact hand-derived completion cycles of single reads around a refresh, in DRAM
    //! cycles, from the per-cycle rules of the module documentation and the timing of
    //! `lpddr3-1600-1x64.ini`: tREFI = 3120, tRFC = 104, tRCD = 15, tRAS = 34, tRP = 15,
    //! CL = 12 (AL = 0, so RL = 12), BL = 8 (BL/2 = 4 cycles of data). (The DRAMsim3 tests
    //! bound these latencies and the refresh cost; these pin them, on Arbor's model and on
    //! DRAMsim3 itself.)

    use super::*;

    /// The DRAM cycle whose tick completes a read of `addr` added with the controller at
    /// cycle `a` (before that cycle's tick), and the refreshes issued by then, on Arbor's
    /// model and on DRAMsim3 itself (the same `Backend` interface), which must agree.
    fn read_done(a: u64, addr: u64) -> (u64, u64) {
        let cfg = super::super::dramsim3::system("lpddr3-1600-1x64").unwrap();
        let model = read_done_on(LpddrSystem::new(cfg).unwrap(), a, addr);
        let ds3 = read_done_on(
            super::super::dramsim3::Dramsim3System::new(cfg).unwrap(),
            a,
            addr,
        );
        assert_eq!(model, ds3, "the model and DRAMsim3 differ");
        model
    }

    fn read_done_on(mut m: impl Backend, a: u64, addr: u64) -> (u64, u64) {
        let mut done = Vec::new();
        m.run_until(a, &mut done);
        assert!(done.is_empty() && m.now() == a);
        m.add(m.channel_of(addr), addr, false, 7);
        while done.is_empty() {
            let t = m.now() + 1;
            m.run_until(t, &mut done);
        }
        assert_eq!(done, [7]);
        let mut s = MemStats::default();
        m.fill_stats(&mut s);
        // Tick c leaves the controller at c + 1.
        (m.now() - 1, s.refresh_commands)
    }

    const TREFI: u64 = 3120;
    const TRFC: u64 = 104;
    const TRCD: u64 = 15;
    const TRAS: u64 = 34;
    const TRP: u64 = 15;
    /// RL + BL/2: a RD at c returns at c + 16.
    const READ: u64 = 12 + 8 / 2;

    /// No refresh near: the read moves to its command queue in the tick of its arrival
    /// cycle a (step 5), ACT at a + 1 (every bank closed), RD at a + 1 + tRCD, data back
    /// at a + 1 + tRCD + RL + BL/2 = a + 32.
    #[test]
    fn read_to_a_closed_bank_completes_after_trcd_rl_and_the_burst() {
        assert_eq!(read_done(100, 0), (100 + 1 + TRCD + READ, 0));
        assert_eq!(read_done(100, 0).0, 132);
    }

    /// A read arriving at a = tREFI, the cycle the first refresh becomes due (step 2, before
    /// the command of step 3): every bank is closed, so the REF issues at a itself; it
    /// holds every bank's ACT until a + tRFC. The read moved to its queue at a (step 5);
    /// ACT at a + tRFC = 3224, RD at 3224 + tRCD = 3239, data at 3239 + 16 = 3255:
    /// the refresh costs tRFC - 1 = 103 cycles over the 32 of an undisturbed read.
    /// Arriving one cycle earlier (a = tREFI - 1) changes nothing: the read is in its
    /// queue at the end of tick a, but at tREFI the refresh has priority.
    #[test]
    fn read_arriving_as_the_refresh_becomes_due_waits_trfc() {
        let want = TREFI + TRFC + TRCD + READ;
        assert_eq!(want, 3255);
        assert_eq!(read_done(TREFI, 0), (want, 1));
        assert_eq!(read_done(TREFI - 1, 0), (want, 1));
    }

    /// A read arriving at a = tREFI - 2: ACT at tREFI - 1 = 3119, then at tREFI the refresh
    /// is due and only its commands may issue, so the RD (legal from 3119 + tRCD = 3134) is
    /// held. The refresh must close the bank: PRE when it becomes legal, tRAS after the ACT
    /// (3153); REF tRP later (3168); the read's row is closed by then, so ACT again at
    /// 3168 + tRFC = 3272, RD at 3287, data at 3303 = a + 1 + tRAS + tRP + tRFC + tRCD + 16.
    #[test]
    fn read_whose_act_just_precedes_the_refresh_is_closed_and_reopened() {
        let a = TREFI - 2;
        let want = a + 1 + TRAS + TRP + TRFC + TRCD + READ;
        assert_eq!(want, 3303);
        assert_eq!(read_done(a, 0), (want, 1));
        let cfg = super::super::dramsim3::system("lpddr3-1600-1x64").unwrap();
        let mut m = LpddrSystem::new(cfg).unwrap();
        let mut done = Vec::new();
        m.run_until(a, &mut done);
        m.add(0, 0, false, 1);
        m.run_until(want + 1, &mut done);
        let c = m.command_counts().0;
        assert_eq!((c.act, c.pre, c.read, c.refresh), (2, 1, 1, 1));
    }
}
