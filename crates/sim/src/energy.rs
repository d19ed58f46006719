//! Energy and area of the on-chip components, in one place, from the data of
//! `shared/reference/hardware.md` (§3 SRAM, §4 FPUs). DRAM energy is the memory port's
//! own (`crate::dram::energy`, DRAMPower's formulas on the command counts).
//!
//! Every choice the thesis makes is the default ([`Conventions::default`], each cited
//! there), and every earlier or open choice is an option of [`Conventions`]:
//! - [`cache`]: a 4-way cache from the CACTI 7.0 table (64-byte line, 512-bit port;
//!   hardware.md §3.1), interpolated in size on log-log axes between the tabulated
//!   16-256 KB points and extrapolated the same way outside them, per process node and cell
//!   type (one cell type across nodes, as hardware.md advises); a wider port as banks
//!   ([`WidePort`]);
//! - [`ram`]: a plain RAM (FIFO, stack, heap, scratchpad) from the measured scratchpad
//!   figures of hardware.md §3.1 ([`RamFigures`]);
//! - [`Fpu`]: energy per FLOP from Galal and Horowitz with linear process scaling, as
//!   \[P2\] §6.4 and \[P4\] §3.2 say ([`FpuSource`]); area from a DesignWare synthesis;
//! - [`UnitEnergy::dram`]: DRAM energy above an idle memory's, \[P2\] §6.2's convention
//!   ([`DramConvention`]).
//!
//! Every figure here is a model input with its source; `docs/energy-model.md` lists them.

use outfile::table::Table;
use serde::Serialize;

/// A process node with CACTI data.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Node {
    /// 45 nm (\[P4\] §3.2).
    #[serde(rename = "45nm")]
    Nm45,
    /// 32 nm.
    #[serde(rename = "32nm")]
    Nm32,
    /// 28 nm (\[P2\] §6.4).
    #[serde(rename = "28nm")]
    Nm28,
    /// 22 nm.
    #[serde(rename = "22nm")]
    Nm22,
}

impl Cell {
    /// The name `parse` reads.
    pub fn name(self) -> &'static str {
        match self {
            Cell::Hp => "hp",
            Cell::Lop => "lop",
        }
    }

    /// Parses `hp` or `lop`.
    pub fn parse(s: &str) -> Result<Self, EnergyError> {
        match s.trim() {
            "hp" => Ok(Cell::Hp),
            "lop" => Ok(Cell::Lop),
            _ => Err(EnergyError(format!(
                "unknown SRAM cell type '{s}' (known: hp, lop)"
            ))),
        }
    }
}

impl Node {
    /// Parses `45nm`, `45`, ...
    pub fn parse(s: &str) -> Result<Self, EnergyError> {
        match s.trim().trim_end_matches("nm") {
            "45" => Ok(Node::Nm45),
            "32" => Ok(Node::Nm32),
            "28" => Ok(Node::Nm28),
            "22" => Ok(Node::Nm22),
            _ => Err(EnergyError(format!(
                "unknown process node '{s}' (known: 45nm, 32nm, 28nm, 22nm)"
            ))),
        }
    }

    /// The name `parse` reads (`45nm`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Node::Nm45 => "45nm",
            Node::Nm32 => "32nm",
            Node::Nm28 => "28nm",
            Node::Nm22 => "22nm",
        }
    }

    /// Feature size in nm.
    pub fn nm(self) -> f64 {
        match self {
            Node::Nm45 => 45.0,
            Node::Nm32 => 32.0,
            Node::Nm28 => 28.0,
            Node::Nm22 => 22.0,
        }
    }

    fn row(self) -> usize {
        match self {
            Node::Nm45 => 0,
            Node::Nm32 => 1,
            Node::Nm28 => 2,
            Node::Nm22 => 3,
        }
    }
}

/// SRAM cell type of the CACTI runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Cell {
    /// High-performance transistors.
    Hp,
    /// Low operating power transistors.
    Lop,
}

/// A model input out of range.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct EnergyError(pub String);

/// Sizes of the CACTI table in KB.
pub const CACTI_KB: [f64; 5] = [16.0, 32.0, 64.0, 128.0, 256.0];

/// The CACTI 7.0 table of hardware.md §3.1: per node (45, 32, 28, 22 nm) and cell type
/// (hp, lop), per size of [`CACTI_KB`]: access time ns, energy of one 64-byte read
/// including the tag in pJ, leakage mW, area mm^2.
pub const CACTI: [[[[f64; 4]; 5]; 2]; 4] = [
    [
        [
            [0.61, 92.0, 19.8, 0.16],
            [0.63, 97.0, 37.0, 0.20],
            [0.69, 107.0, 71.0, 0.29],
            [0.80, 129.0, 139.0, 0.50],
            [1.00, 166.0, 275.0, 0.87],
        ],
        [
            [1.09, 52.0, 0.3, 0.16],
            [1.14, 55.0, 0.5, 0.20],
            [1.18, 63.0, 1.0, 0.31],
            [1.39, 75.0, 1.9, 0.50],
            [1.73, 95.0, 3.8, 1.27],
        ],
    ],
    [
        [
            [0.47, 50.0, 10.6, 0.08],
            [0.49, 53.0, 19.7, 0.10],
            [0.55, 59.0, 38.0, 0.15],
            [0.64, 72.0, 74.0, 0.25],
            [0.80, 91.0, 148.0, 0.59],
        ],
        [
            [0.74, 25.0, 2.2, 0.08],
            [0.79, 27.0, 4.1, 0.10],
            [0.84, 31.0, 7.8, 0.16],
            [1.02, 39.0, 15.0, 0.25],
            [1.23, 48.0, 30.0, 0.64],
        ],
    ],
    [
        [
            [0.42, 41.0, 8.3, 0.06],
            [0.45, 43.0, 15.3, 0.08],
            [0.51, 48.0, 29.0, 0.11],
            [0.60, 58.0, 57.0, 0.19],
            [0.74, 75.0, 113.0, 0.49],
        ],
        [
            [0.69, 21.0, 4.8, 0.06],
            [0.73, 23.0, 8.9, 0.08],
            [0.80, 27.0, 17.0, 0.12],
            [0.99, 32.0, 34.0, 0.28],
            [1.16, 42.0, 67.0, 0.49],
        ],
    ],
    [
        [
            [0.36, 26.0, 5.4, 0.04],
            [0.39, 28.0, 9.8, 0.05],
            [0.45, 32.0, 19.0, 0.08],
            [0.48, 40.0, 38.0, 0.17],
            [0.63, 49.0, 74.0, 0.29],
        ],
        [
            [0.62, 17.0, 7.2, 0.04],
            [0.66, 18.0, 13.4, 0.05],
            [0.75, 21.0, 26.0, 0.08],
            [0.90, 26.0, 51.0, 0.17],
            [1.08, 33.0, 100.0, 0.30],
        ],
    ],
];

/// Area factor of a read port twice as wide at the same capacity under
/// [`WidePort::P4Ratio`]: \[P4\] Table 1's own result (MBVH4 cache area 2.35 mm^2 against
/// 1.57 for BVH), kept only as the earlier convention.
pub const WIDE_PORT_AREA: f64 = 2.35 / 1.57;

/// Figures of one SRAM block.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SramFigures {
    /// Energy of one access (a read of the port's width, or a write of it) in pJ.
    pub access_pj: f64,
    /// Leakage power in mW.
    pub leak_mw: f64,
    /// Area in mm^2.
    pub area_mm2: f64,
}

impl SramFigures {
    fn scaled(self, e: f64, l: f64, a: f64) -> Self {
        Self {
            access_pj: self.access_pj * e,
            leak_mw: self.leak_mw * l,
            area_mm2: self.area_mm2 * a,
        }
    }
}

/// Interpolates `ys` over `xs` at `x` on log-log axes (extrapolating the nearest segment
/// outside the table).
fn loglog<const N: usize>(x: f64, xs: [f64; N], ys: [f64; N]) -> f64 {
    let k = (1..N - 1).find(|&k| x < xs[k]).unwrap_or(N - 1);
    let (x0, x1) = (xs[k - 1].ln(), xs[k].ln());
    let (y0, y1) = (ys[k - 1].ln(), ys[k].ln());
    (y0 + (y1 - y0) * (x.ln() - x0) / (x1 - x0)).exp()
}

fn check_size(bytes: f64) -> Result<(), EnergyError> {
    if bytes.is_finite() && bytes > 0.0 {
        Ok(())
    } else {
        Err(EnergyError(format!(
            "SRAM size must be a positive number of bytes, got {bytes}"
        )))
    }
}

/// The CACTI cache table at `bytes` (one 512-bit port), interpolated and extrapolated on
/// log-log axes.
fn cache_table(bytes: f64, node: Node, cell: Cell) -> SramFigures {
    let t = &CACTI[node.row()][match cell {
        Cell::Hp => 0,
        Cell::Lop => 1,
    }];
    let kb = bytes / 1024.0;
    let col = |c: usize| loglog(kb, CACTI_KB, [0, 1, 2, 3, 4].map(|i| t[i][c]));
    SramFigures {
        access_pj: col(1),
        leak_mw: col(2),
        area_mm2: col(3),
    }
}

/// A 4-way cache of `bytes` bytes (tags included) whose port reads `width` x 64 bytes per
/// access, from the CACTI table of hardware.md §3.1. A port wider than the table's 512 bits
/// follows `conv.wide_port`: [`WidePort::Banked`] builds it from `width` banks of
/// `bytes / width` with a 512-bit port each, all read at once (energy, leakage and area
/// `width` times a bank's); [`WidePort::P4Ratio`] takes the whole array's figures, the
/// access energy times `width` and the area times [`WIDE_PORT_AREA`] per doubling.
pub fn cache(
    bytes: f64,
    width: u32,
    node: Node,
    conv: &Conventions,
) -> Result<SramFigures, EnergyError> {
    check_size(bytes)?;
    if width == 0 || width > 64 {
        return Err(EnergyError(format!(
            "SRAM port width must be 1..=64 times 512 bits, got {width}"
        )));
    }
    let w = width as f64;
    Ok(match conv.wide_port {
        WidePort::Banked => cache_table(bytes / w, node, conv.cell).scaled(w, w, w),
        WidePort::P4Ratio => {
            let area = if width > 1 {
                WIDE_PORT_AREA.powf(w.log2())
            } else {
                1.0
            };
            cache_table(bytes, node, conv.cell).scaled(w, 1.0, area)
        }
    })
}

/// Sizes of the measured scratchpad figures in KB (hardware.md §3.1, 28 nm hp, CACTI "ram"
/// type, 64-bit word).
pub const SCRATCH_KB: [f64; 3] = [1.0, 4.0, 16.0];

/// The measured scratchpad figures at [`SCRATCH_KB`]: energy of one 64-bit read in pJ,
/// leakage mW, area mm^2 (hardware.md §3.1, 28 nm hp).
pub const SCRATCH_28NM_HP: [[f64; 3]; 3] = [
    [0.57, 0.50, 0.0014],
    [1.71, 2.1, 0.0057],
    [4.38, 7.6, 0.0196],
];

/// A plain RAM of `bytes` bytes without tags (a FIFO, stack, heap, scratchpad or buffer);
/// `access_pj` is for 64 bytes (eight 64-bit words), as [`cache`]'s, so callers charge
/// an entry of `e` bytes `access_pj * e / 64`.
///
/// [`RamFigures::Scratchpad`] (the default): the measured scratchpad figures of
/// hardware.md §3.1 (28 nm hp, 1-16 KB), interpolated on log-log axes; for other nodes and
/// cell types, and above 16 KB, the cache table's figures at the same size times the
/// scratchpad-to-cache ratio of 28 nm hp at that size (at 16 KB above it): the node's and
/// cell's effect is the cache table's, the RAM's saving over a cache the measured one.
/// Below 1 KB the scratchpad segment is extrapolated. [`RamFigures::CacheTable`]: the cache
/// table alone (the earlier convention).
pub fn ram(bytes: f64, node: Node, conv: &Conventions) -> Result<SramFigures, EnergyError> {
    check_size(bytes)?;
    let table = cache_table(bytes, node, conv.cell);
    match conv.ram {
        RamFigures::CacheTable => Ok(table),
        RamFigures::Scratchpad => {
            let at = (bytes / 1024.0).min(16.0) * 1024.0;
            let kb = at / 1024.0;
            let col = |c: usize| loglog(kb, SCRATCH_KB, SCRATCH_28NM_HP.map(|r| r[c]));
            let reference = cache_table(at, Node::Nm28, Cell::Hp);
            Ok(table.scaled(
                8.0 * col(0) / reference.access_pj,
                col(1) / reference.leak_mw,
                col(2) / reference.area_mm2,
            ))
        }
    }
}

/// Where the energy of a floating-point operation comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FpuSource {
    /// Galal and Horowitz (IEEE TC 2011), every FLOP alike, scaled linearly with the
    /// feature size as GPUSimPow does: the thesis's (\[P2\] §6.4, \[P4\] §3.2).
    Galal,
    /// Horowitz (ISSCC 2014) arithmetic-only adds and multiplies: the earlier convention.
    Horowitz,
}

/// Where the figures of plain RAMs (FIFOs, stacks, heaps, scratchpads) come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RamFigures {
    /// The measured scratchpad figures (see [`ram`]).
    Scratchpad,
    /// The 4-way cache table (the earlier convention).
    #[serde(rename = "cache-table")]
    CacheTable,
}

/// How a port wider than 512 bits is costed (see [`cache`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum WidePort {
    /// As banks of the table's port width read together.
    Banked,
    /// With \[P4\] Table 1's own area ratio (the earlier convention).
    #[serde(rename = "p4-ratio")]
    P4Ratio,
}

/// Which DRAM energy the headline figures carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DramConvention {
    /// The energy above an idle memory's over the same time: \[P2\] §6.2 ("We subtract
    /// from all memory power figures a static power term computed from an idle memory
    /// transaction trace"), and \[P4\] Table 1's DRAM (37 mW with primary rays, below the
    /// standby floor of its two LPDDR3 dies).
    AboveIdle,
    /// Everything the memory draws, standby and refresh included (the earlier convention).
    Full,
}

/// The conventions of every energy and area figure: the thesis's by default
/// (`docs/energy-model.md` cites each), the earlier ones as options. One place parses
/// them for every front end ([`Conventions::set`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Conventions {
    /// SRAM cell type: `lop` by default. The thesis synthesized on 28 nm FDSOI "with
    /// multi-threshold voltage optimizations" (\[P2\] §6.2), and \[P4\] Table 1's caches draw
    /// 90 mW in all with primary rays, below the 360 mW that CACTI's hp cells leak at 45 nm
    /// for the same arrays (four 16 KB L1s, the 128 KB node cache, two 64 KB primitive
    /// banks).
    pub cell: Cell,
    /// FPU energy per operation.
    pub fpu: FpuSource,
    /// Plain RAM figures.
    pub ram: RamFigures,
    /// Wide ports.
    pub wide_port: WidePort,
    /// DRAM energy in the headline figures.
    pub dram: DramConvention,
}

impl Default for Conventions {
    fn default() -> Self {
        Self {
            cell: Cell::Lop,
            fpu: FpuSource::Galal,
            ram: RamFigures::Scratchpad,
            wide_port: WidePort::Banked,
            dram: DramConvention::AboveIdle,
        }
    }
}

impl Conventions {
    /// The keys [`Conventions::set`] reads.
    pub const KEYS: [&'static str; 5] = [
        "sram_cell",
        "fpu_energy",
        "ram_figures",
        "wide_port",
        "dram_energy",
    ];

    /// The conventions Arbor used before it followed the thesis's: hp cells, Horowitz
    /// FPUs, RAMs from the cache table, \[P4\]'s wide-port ratio, full DRAM energy.
    pub fn earlier() -> Self {
        Self {
            cell: Cell::Hp,
            fpu: FpuSource::Horowitz,
            ram: RamFigures::CacheTable,
            wide_port: WidePort::P4Ratio,
            dram: DramConvention::Full,
        }
    }

    /// Sets `key` (one of [`Conventions::KEYS`]) to `value`; `Ok(false)` for another key.
    /// `energy=thesis` and `energy=earlier` set all of them.
    pub fn set(&mut self, key: &str, value: &str) -> Result<bool, EnergyError> {
        let v = value.trim();
        let bad = |known: &str| {
            EnergyError(format!(
                "unknown value '{value}' for {key} (known: {known})"
            ))
        };
        match key.trim() {
            "energy" => {
                *self = match v {
                    "thesis" => Self::default(),
                    "earlier" => Self::earlier(),
                    _ => return Err(bad("thesis, earlier")),
                }
            }
            "sram_cell" => self.cell = Cell::parse(v)?,
            "fpu_energy" => {
                self.fpu = match v {
                    "galal" => FpuSource::Galal,
                    "horowitz" => FpuSource::Horowitz,
                    _ => return Err(bad("galal, horowitz")),
                }
            }
            "ram_figures" => {
                self.ram = match v {
                    "scratchpad" => RamFigures::Scratchpad,
                    "cache-table" => RamFigures::CacheTable,
                    _ => return Err(bad("scratchpad, cache-table")),
                }
            }
            "wide_port" => {
                self.wide_port = match v {
                    "banked" => WidePort::Banked,
                    "p4-ratio" => WidePort::P4Ratio,
                    _ => return Err(bad("banked, p4-ratio")),
                }
            }
            "dram_energy" => {
                self.dram = match v {
                    "above-idle" => DramConvention::AboveIdle,
                    "full" => DramConvention::Full,
                    _ => return Err(bad("above-idle, full")),
                }
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// One line for reports: `lop cells, galal FPUs, scratchpad RAMs, banked wide ports,
    /// DRAM above idle`.
    pub fn describe(&self) -> String {
        format!(
            "{} cells, {} FPUs, {} RAMs, {} wide ports, DRAM {}",
            self.cell.name(),
            match self.fpu {
                FpuSource::Galal => "galal",
                FpuSource::Horowitz => "horowitz",
            },
            match self.ram {
                RamFigures::Scratchpad => "scratchpad",
                RamFigures::CacheTable => "cache-table",
            },
            match self.wide_port {
                WidePort::Banked => "banked",
                WidePort::P4Ratio => "p4-ratio",
            },
            match self.dram {
                DramConvention::AboveIdle => "above idle",
                DramConvention::Full => "full",
            }
        )
    }
}

/// Floating-point units at a node.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Fpu {
    /// Energy of a 32-bit add, subtract or compare in pJ.
    pub add_pj: f64,
    /// Energy of a 32-bit multiply in pJ.
    pub mul_pj: f64,
    /// Area of an adder in mm^2.
    pub add_mm2: f64,
    /// Area of a multiplier in mm^2.
    pub mul_mm2: f64,
}

/// Galal and Horowitz (IEEE TC 60(7), 2011) at 90 nm: 1 W/mm^2 at 27 GFLOPS/mm^2, 37 pJ
/// per FLOP (hardware.md §4's derivation; the paper's per-design table could not be
/// retrieved).
pub const GALAL_90NM_PJ_PER_FLOP: f64 = 1000.0 / 27.0;
/// Horowitz (ISSCC 2014), 45 nm, 0.9 V: 32-bit FP add and multiply in pJ.
pub const HOROWITZ_45NM_PJ: [f64; 2] = [0.9, 3.7];
/// DesignWare 3-stage FP adder and multiplier areas at TSMC 40 nm, 1 ns clock, in um^2
/// (hardware.md §4, from ALADDIN's power_func.h).
pub const DESIGNWARE_40NM_UM2: [f64; 2] = [3142.0, 6460.0];

impl Fpu {
    /// The figures at `node` from `source`, energy scaled linearly with the feature size
    /// (as GPUSimPow scales per-operation figures, \[P2\] §6.4): [`FpuSource::Galal`]
    /// charges every FLOP (add, subtract, compare, multiply) [`GALAL_90NM_PJ_PER_FLOP`]
    /// x nm / 90 (11.5 pJ at 28 nm, 18.5 at 45 nm); [`FpuSource::Horowitz`] 0.9 pJ per
    /// add and 3.7 per multiply x nm / 45. The area per unit is the DesignWare synthesis
    /// (with its pipeline registers, as Galal's energy includes the whole unit's), scaled
    /// with the square of the feature size.
    pub fn at(node: Node, source: FpuSource) -> Self {
        let a = (node.nm() / 40.0).powi(2) * 1e-6;
        let (add_pj, mul_pj) = match source {
            FpuSource::Galal => {
                let e = GALAL_90NM_PJ_PER_FLOP * node.nm() / 90.0;
                (e, e)
            }
            FpuSource::Horowitz => {
                let e = node.nm() / 45.0;
                (HOROWITZ_45NM_PJ[0] * e, HOROWITZ_45NM_PJ[1] * e)
            }
        };
        Self {
            add_pj,
            mul_pj,
            add_mm2: DESIGNWARE_40NM_UM2[0] * a,
            mul_mm2: DESIGNWARE_40NM_UM2[1] * a,
        }
    }
}

/// Work of a pipelined datapath: its floating-point operations by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Flops {
    /// Adds, subtracts and compares.
    pub adds: f64,
    /// Multiplies (a Markstein division's 11 FLOPs count as 11 multiplies).
    pub muls: f64,
}

impl Flops {
    /// Energy of the operations in pJ.
    pub fn energy_pj(&self, f: &Fpu) -> f64 {
        self.adds * f.add_pj + self.muls * f.mul_pj
    }

    /// Area of a fully pipelined datapath with one unit per operation, in mm^2.
    pub fn area_mm2(&self, f: &Fpu) -> f64 {
        self.adds * f.add_mm2 + self.muls * f.mul_mm2
    }

    /// The sum of two datapaths.
    pub fn plus(self, o: Flops) -> Flops {
        Flops {
            adds: self.adds + o.adds,
            muls: self.muls + o.muls,
        }
    }

    /// `n` copies.
    pub fn times(self, n: f64) -> Flops {
        Flops {
            adds: self.adds * n,
            muls: self.muls * n,
        }
    }

    /// All operations.
    pub fn total(&self) -> f64 {
        self.adds + self.muls
    }
}

/// One unit's energy and area over a run (a row of \[P4\] Table 1 or \[P2\] Table IV).
#[derive(Clone, Debug, Serialize)]
pub struct UnitEnergy {
    /// The unit.
    pub unit: &'static str,
    /// Area in mm^2 (DRAM: 0, off chip).
    pub area_mm2: f64,
    /// Dynamic energy in mJ.
    pub dynamic_mj: f64,
    /// Static (leakage; DRAM: background and refresh) energy in mJ.
    pub static_mj: f64,
    /// Their sum.
    pub total_mj: f64,
    /// Mean power over the run in mW.
    pub power_mw: f64,
}

impl UnitEnergy {
    /// A unit that spent `dynamic_mj` and `static_mj` over `seconds`.
    pub fn new(
        unit: &'static str,
        area_mm2: f64,
        dynamic_mj: f64,
        static_mj: f64,
        seconds: f64,
    ) -> Self {
        let total_mj = dynamic_mj + static_mj;
        Self {
            unit,
            area_mm2,
            dynamic_mj,
            static_mj,
            total_mj,
            power_mw: if seconds > 0.0 {
                total_mj / seconds
            } else {
                0.0
            },
        }
    }

    /// The DRAM of a run from the memory's counts (zero when the backend has no energy
    /// model): commands and bursts as dynamic; as static, background and refresh
    /// ([`DramConvention::Full`]) or what they add over an idle memory's
    /// ([`DramConvention::AboveIdle`]: active standby beyond precharged standby; the total
    /// is then `DramEnergy::above_idle_pj`).
    pub fn dram(mem: &crate::dram::MemStats, seconds: f64, convention: DramConvention) -> Self {
        let e = mem.energy_pj.as_ref();
        let total = e.map_or(0.0, |e| e.total_pj()) * 1e-9;
        let stat = e.map_or(0.0, |e| e.background_pj + e.refresh_pj) * 1e-9;
        let idle = match convention {
            DramConvention::Full => 0.0,
            DramConvention::AboveIdle => e.map_or(0.0, |e| e.idle_pj) * 1e-9,
        };
        let dynamic = total - stat;
        let stat = (stat - idle).max(0.0);
        Self::new("DRAM", 0.0, dynamic, stat, seconds)
    }
}

/// Energy of a 32-bit integer add or compare at 45 nm in pJ (Horowitz, ISSCC 2014;
/// hardware.md §4), scaled linearly with the feature size by [`int_add_pj`].
pub const HOROWITZ_45NM_INT_ADD_PJ: f64 = 0.1;

/// A 32-bit integer add or compare at `node`, in pJ.
pub fn int_add_pj(node: Node) -> f64 {
    HOROWITZ_45NM_INT_ADD_PJ * node.nm() / 45.0
}

/// Every process node with CACTI data.
pub const NODES: [Node; 4] = [Node::Nm45, Node::Nm32, Node::Nm28, Node::Nm22];

/// One row of the component tables: a block at a node.
#[derive(Clone, Debug, Serialize)]
pub struct ComponentRow {
    /// `sram`, `fpu-add`, `fpu-mul`, `int-add` or `dram`.
    pub kind: &'static str,
    /// What it is (size, or the DRAM command).
    pub what: String,
    /// Node (empty for DRAM, which is off chip).
    pub node: &'static str,
    /// Energy per access or operation, pJ.
    pub energy_pj: f64,
    /// Leakage mW (SRAM; DRAM: standby power of one die).
    pub static_mw: f64,
    /// Area mm^2.
    pub area_mm2: f64,
}

/// The component models' figures under `conv`: caches at the table's sizes and between them
/// (the model interpolates), plain RAMs, FPUs and integer adders at every node; and the
/// DRAM commands of the LPDDR3 die of the thesis's memory systems (per die).
pub fn component_rows(conv: &Conventions) -> Vec<ComponentRow> {
    let mut rows = Vec::new();
    let cell = conv.cell;
    for node in NODES {
        for kb in [8.0, 16.0, 24.0, 32.0, 64.0, 128.0, 256.0, 512.0] {
            let f = cache(kb * 1024.0, 1, node, conv).expect("positive size");
            rows.push(ComponentRow {
                kind: "sram",
                what: format!("{kb} KB {} cache (64-B access)", cell.name()),
                node: node.name(),
                energy_pj: f.access_pj,
                static_mw: f.leak_mw,
                area_mm2: f.area_mm2,
            });
        }
        for kb in [0.5, 1.0, 2.0, 4.0, 16.0, 256.0] {
            let f = ram(kb * 1024.0, node, conv).expect("positive size");
            rows.push(ComponentRow {
                kind: "ram",
                what: format!("{kb} KB {} RAM (64-B access)", cell.name()),
                node: node.name(),
                energy_pj: f.access_pj,
                static_mw: f.leak_mw,
                area_mm2: f.area_mm2,
            });
        }
        let fpu = Fpu::at(node, conv.fpu);
        for (kind, e, a) in [
            ("fpu-add", fpu.add_pj, fpu.add_mm2),
            ("fpu-mul", fpu.mul_pj, fpu.mul_mm2),
            ("int-add", int_add_pj(node), 0.0),
        ] {
            rows.push(ComponentRow {
                kind,
                what: "32-bit".into(),
                node: node.name(),
                energy_pj: e,
                static_mw: 0.0,
                area_mm2: a,
            });
        }
    }
    let d = &crate::dram::energy::MICRON_4GB_LPDDR3_1600_X32;
    for (what, e, st) in [
        ("ACT", d.act_pj(), 0.0),
        ("PRE", d.pre_pj(), 0.0),
        ("RD burst", d.read_burst_pj(), 0.0),
        ("WR burst", d.write_burst_pj(), 0.0),
        ("REF", d.refresh_pj(), 0.0),
        ("active standby", 0.0, d.active_standby_mw()),
        ("precharged standby", 0.0, d.precharged_standby_mw()),
    ] {
        rows.push(ComponentRow {
            kind: "dram",
            what: format!("LPDDR3-1600 x32 die: {what}"),
            node: "",
            energy_pj: e,
            static_mw: st,
            area_mm2: 0.0,
        });
    }
    rows
}

/// [`component_rows`] as Markdown.
pub fn component_markdown(rows: &[ComponentRow]) -> String {
    let mut t = Table::text(&["kind", "what", "node", "energy pJ", "static mW", "area mm2"])
        .right(&[3, 4, 5]);
    for r in rows {
        t.push([
            r.kind.to_string(),
            r.what.clone(),
            r.node.to_string(),
            format!("{:.3}", r.energy_pj),
            format!("{:.3}", r.static_mw),
            format!("{:.4}", r.area_mm2),
        ]);
    }
    t.markdown()
}

/// [`component_rows`] as CSV.
pub fn component_csv(rows: &[ComponentRow]) -> String {
    let mut t = Table::text(&["kind", "what", "node", "energy_pj", "static_mw", "area_mm2"]);
    for r in rows {
        t.push([
            r.kind.to_string(),
            r.what.clone(),
            r.node.to_string(),
            r.energy_pj.to_string(),
            r.static_mw.to_string(),
            r.area_mm2.to_string(),
        ]);
    }
    t.csv()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cache under the earlier conventions with `cell` cells (the cache table alone,
    /// [P4]'s wide-port ratio).
    fn sram(bytes: f64, width: u32, node: Node, cell: Cell) -> Result<SramFigures, EnergyError> {
        let c = Conventions {
            cell,
            ..Conventions::earlier()
        };
        cache(bytes, width, node, &c)
    }

    #[test]
    fn component_rows_cover_every_node_and_match_the_models() {
        let conv = Conventions::earlier();
        let rows = component_rows(&conv);
        for node in NODES {
            let at: Vec<&ComponentRow> = rows.iter().filter(|r| r.node == node.name()).collect();
            assert_eq!(at.len(), 8 + 6 + 3, "{node:?}");
            // The 16 KB row is CACTI's own point.
            let r16 = at.iter().find(|r| r.what.starts_with("16 KB")).unwrap();
            assert_eq!(
                r16.energy_pj,
                sram(16384.0, 1, node, Cell::Hp).unwrap().access_pj
            );
            // SRAM energy, leakage and area grow with size.
            let s: Vec<&&ComponentRow> = at.iter().filter(|r| r.kind == "sram").collect();
            assert_eq!(s.len(), 8);
            assert!(s.windows(2).all(|w| w[1].energy_pj > w[0].energy_pj
                && w[1].static_mw > w[0].static_mw
                && w[1].area_mm2 > w[0].area_mm2));
        }
        assert_eq!(rows.iter().filter(|r| r.kind == "dram").count(), 7);
        let md = component_markdown(&rows);
        assert_eq!(md.lines().count(), rows.len() + 2);
        assert_eq!(component_csv(&rows).lines().count(), rows.len() + 1);
    }

    #[test]
    fn sram_equals_the_cacti_table_at_its_points_and_interpolates_monotonically() {
        for (n, node) in [Node::Nm45, Node::Nm32, Node::Nm28, Node::Nm22]
            .into_iter()
            .enumerate()
        {
            for (c, cell) in [Cell::Hp, Cell::Lop].into_iter().enumerate() {
                for (i, kb) in CACTI_KB.iter().enumerate() {
                    let f = sram(kb * 1024.0, 1, node, cell).unwrap();
                    let t = CACTI[n][c][i];
                    assert!((f.access_pj - t[1]).abs() < 1e-9 * t[1]);
                    assert!((f.leak_mw - t[2]).abs() < 1e-9 * t[2]);
                    assert!((f.area_mm2 - t[3]).abs() < 1e-9 * t[3]);
                }
                // Monotone in size, within and outside the table.
                let mut last = sram(1024.0, 1, node, cell).unwrap();
                for kb in [2.0, 8.0, 16.0, 20.0, 48.0, 100.0, 200.0, 256.0, 512.0] {
                    let f = sram(kb * 1024.0, 1, node, cell).unwrap();
                    assert!(f.access_pj > last.access_pj && f.area_mm2 > last.area_mm2);
                    assert!(f.leak_mw > last.leak_mw);
                    last = f;
                }
            }
        }
        // Spot values: 45 nm hp 16 KB 92 pJ; 128 KB 129 pJ; 28 nm lop 64 KB 27 pJ.
        assert_eq!(
            sram(16384.0, 1, Node::Nm45, Cell::Hp)
                .unwrap()
                .access_pj
                .round(),
            92.0
        );
        assert_eq!(
            sram(131072.0, 1, Node::Nm45, Cell::Hp)
                .unwrap()
                .access_pj
                .round(),
            129.0
        );
        assert_eq!(
            sram(65536.0, 1, Node::Nm28, Cell::Lop)
                .unwrap()
                .access_pj
                .round(),
            27.0
        );
        // Between two points the value lies between them.
        let mid = sram(24.0 * 1024.0, 1, Node::Nm45, Cell::Hp).unwrap();
        assert!(mid.access_pj > 92.0 && mid.access_pj < 97.0);
        // A doubled port reads twice the data and takes [P4]'s area factor.
        let wide = sram(131072.0, 2, Node::Nm45, Cell::Hp).unwrap();
        assert!((wide.access_pj - 258.0).abs() < 1e-9);
        assert!((wide.area_mm2 - 0.50 * 2.35 / 1.57).abs() < 1e-9);
    }

    #[test]
    fn fpus_scale_with_the_node() {
        let f45 = Fpu::at(Node::Nm45, FpuSource::Horowitz);
        assert_eq!([f45.add_pj, f45.mul_pj], HOROWITZ_45NM_PJ);
        let f28 = Fpu::at(Node::Nm28, FpuSource::Horowitz);
        assert!((f28.mul_pj - 3.7 * 28.0 / 45.0).abs() < 1e-12);
        assert!((f28.add_mm2 - 3142e-6 * (28.0f64 / 40.0).powi(2)).abs() < 1e-15);
        let work = Flops {
            adds: 10.0,
            muls: 2.0,
        };
        assert!((work.energy_pj(&f45) - (9.0 + 7.4)).abs() < 1e-12);
        assert_eq!(work.plus(work).times(0.5), work);
        assert_eq!(work.total(), 12.0);
    }

    #[test]
    fn hostile_inputs_are_one_line_errors() {
        for bad in [0.0, -5.0, f64::NAN, f64::INFINITY] {
            let e = sram(bad, 1, Node::Nm45, Cell::Hp).unwrap_err().to_string();
            assert!(e.contains("positive") && !e.contains('\n'), "{e}");
        }
        assert!(sram(1024.0, 0, Node::Nm45, Cell::Hp).is_err());
        let e = Node::parse("7nm").unwrap_err().to_string();
        assert!(e.contains("unknown process node '7nm'"), "{e}");
        assert_eq!(Node::parse("28nm").unwrap(), Node::Nm28);
        assert_eq!(Node::parse("45").unwrap(), Node::Nm45);
        for n in [Node::Nm45, Node::Nm32, Node::Nm28, Node::Nm22] {
            assert_eq!(Node::parse(n.name()).unwrap(), n);
        }
        for c in [Cell::Hp, Cell::Lop] {
            assert_eq!(Cell::parse(c.name()).unwrap(), c);
        }
    }

    /// Galal's 90 nm figure, linearly scaled: 37.04 pJ x 28 / 90 = 11.52 pJ per FLOP at
    /// 28 nm, the same for adds and multiplies; 18.52 pJ at 45 nm.
    #[test]
    fn galal_fpus_by_hand() {
        let f28 = Fpu::at(Node::Nm28, FpuSource::Galal);
        assert!((f28.add_pj - 11.5226).abs() < 1e-3, "{}", f28.add_pj);
        assert_eq!(f28.add_pj, f28.mul_pj);
        let f45 = Fpu::at(Node::Nm45, FpuSource::Galal);
        assert!((f45.mul_pj - 18.5185).abs() < 1e-3, "{}", f45.mul_pj);
        // The area is the same under either source.
        let h28 = Fpu::at(Node::Nm28, FpuSource::Horowitz);
        assert_eq!(f28.add_mm2, h28.add_mm2);
        // A slab test's 19 adds and 6 multiplies at 28 nm: 25 x 11.52 = 288.1 pJ.
        let slab = Flops {
            adds: 19.0,
            muls: 6.0,
        };
        assert!((slab.energy_pj(&f28) - 288.07).abs() < 0.01);
    }

    /// The scratchpad figures at their own points (28 nm hp), scaled by the cache table's
    /// node and cell ratios elsewhere, continuous at 16 KB, and the cache table alone under
    /// the earlier convention.
    #[test]
    fn ram_figures_by_hand() {
        let hp = Conventions {
            cell: Cell::Hp,
            ..Conventions::default()
        };
        for (kb, want) in SCRATCH_KB.iter().zip(SCRATCH_28NM_HP) {
            let f = ram(kb * 1024.0, Node::Nm28, &hp).unwrap();
            assert!((f.access_pj - 8.0 * want[0]).abs() < 1e-9, "{kb} KB {f:?}");
            assert!((f.leak_mw - want[1]).abs() < 1e-9, "{kb} KB {f:?}");
            assert!((f.area_mm2 - want[2]).abs() < 1e-12, "{kb} KB {f:?}");
        }
        // 28 nm lop at 16 KB: the cache table's lop figures (21 pJ, 4.8 mW, 0.06 mm^2)
        // times the hp scratchpad-to-cache ratios (35.04 / 41, 7.6 / 8.3, 0.0196 / 0.06).
        let lop = ram(16384.0, Node::Nm28, &Conventions::default()).unwrap();
        assert!((lop.access_pj - 21.0 * 35.04 / 41.0).abs() < 1e-9);
        assert!((lop.leak_mw - 4.8 * 7.6 / 8.3).abs() < 1e-9);
        assert!((lop.area_mm2 - 0.06 * 0.0196 / 0.06).abs() < 1e-12);
        // Above 16 KB the ratio at 16 KB: the 256 KB MergeTree scratchpad, 28 nm lop.
        let pad = ram(262144.0, Node::Nm28, &Conventions::default()).unwrap();
        assert!((pad.leak_mw - 67.0 * 7.6 / 8.3).abs() < 1e-9);
        // Continuous across 16 KB, monotone in size.
        let below = ram(16383.0, Node::Nm28, &hp).unwrap();
        let above = ram(16385.0, Node::Nm28, &hp).unwrap();
        assert!((below.access_pj / above.access_pj - 1.0).abs() < 1e-3);
        let mut last = ram(256.0, Node::Nm45, &hp).unwrap();
        for kb in [0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 64.0, 256.0] {
            let f = ram(kb * 1024.0, Node::Nm45, &hp).unwrap();
            assert!(
                f.access_pj > last.access_pj && f.area_mm2 > last.area_mm2,
                "{kb}"
            );
            last = f;
        }
        // A 1 KB FIFO costs about a seventh of the cache table's energy at 28 nm hp.
        let earlier = ram(1024.0, Node::Nm28, &Conventions::earlier()).unwrap();
        let ratio = earlier.access_pj / ram(1024.0, Node::Nm28, &hp).unwrap().access_pj;
        assert!((5.0..9.0).contains(&ratio), "{ratio}");
        assert!(ram(0.0, Node::Nm28, &hp).is_err());
    }

    /// A port twice as wide: two banks of half the capacity (45 nm hp 128 KB: 2 x the
    /// 64 KB figures, 214 pJ, 142 mW, 0.58 mm^2), or [P4]'s ratio under the earlier
    /// convention.
    #[test]
    fn wide_ports_by_hand() {
        let banked = Conventions {
            cell: Cell::Hp,
            ..Conventions::default()
        };
        let w = cache(131072.0, 2, Node::Nm45, &banked).unwrap();
        assert!((w.access_pj - 214.0).abs() < 1e-9);
        assert!((w.leak_mw - 142.0).abs() < 1e-9);
        assert!((w.area_mm2 - 0.58).abs() < 1e-9);
        let one = cache(131072.0, 1, Node::Nm45, &banked).unwrap();
        assert_eq!(one, sram(131072.0, 1, Node::Nm45, Cell::Hp).unwrap());
    }

    /// Above idle: the DRAM row is the total less the idle memory's energy.
    #[test]
    fn dram_conventions_by_hand() {
        let mem = crate::dram::MemStats {
            energy_pj: Some(crate::dram::DramEnergy {
                act_pre_pj: 1e9,
                read_pj: 2e9,
                write_pj: 0.5e9,
                refresh_pj: 0.25e9,
                background_pj: 4e9,
                idle_pj: 3.5e9,
            }),
            ..Default::default()
        };
        let full = UnitEnergy::dram(&mem, 1.0, DramConvention::Full);
        assert!((full.total_mj - 7.75).abs() < 1e-12);
        assert!((full.static_mj - 4.25).abs() < 1e-12);
        let above = UnitEnergy::dram(&mem, 1.0, DramConvention::AboveIdle);
        assert!((above.total_mj - 4.25).abs() < 1e-12);
        assert!((above.dynamic_mj - 3.5).abs() < 1e-12);
        assert!((above.static_mj - 0.75).abs() < 1e-12);
    }

    #[test]
    fn conventions_parse_every_key_and_reject_bad_values() {
        let mut c = Conventions::default();
        assert_eq!(
            c.describe(),
            "lop cells, galal FPUs, scratchpad RAMs, banked wide ports, DRAM above idle"
        );
        for (k, v) in [
            ("sram_cell", "hp"),
            ("fpu_energy", "horowitz"),
            ("ram_figures", "cache-table"),
            ("wide_port", "p4-ratio"),
            ("dram_energy", "full"),
        ] {
            assert!(c.set(k, v).unwrap(), "{k}");
        }
        assert_eq!(c, Conventions::earlier());
        assert!(c.set("energy", "thesis").unwrap());
        assert_eq!(c, Conventions::default());
        assert!(!c.set("trv_stages", "3").unwrap());
        for k in Conventions::KEYS {
            let e = c.set(k, "bogus").unwrap_err().to_string();
            assert!(e.contains("bogus") && !e.contains('\n'), "{e}");
        }
    }
}
