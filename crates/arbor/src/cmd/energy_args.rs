//! The energy-convention options every energy-reporting command shares (one parser:
//! `sim::energy::Conventions::set`).

use sim::energy::Conventions;

/// `--energy KEY=VALUE,...` and its `--cell` shorthand.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct EnergyArgs {
    /// Energy conventions, comma separated KEY=VALUE (default: the thesis's):
    /// energy=thesis|earlier (all at once), sram_cell=lop|hp, fpu_energy=galal|horowitz,
    /// ram_figures=scratchpad|cache-table, wide_port=banked|p4-ratio,
    /// dram_energy=above-idle|full. docs/energy-model.md cites each.
    #[arg(long = "energy", value_name = "KEY=VALUE", value_delimiter = ',')]
    pub energy: Vec<String>,
    /// SRAM cell type, lop or hp (the same as --energy sram_cell=...).
    #[arg(long, value_name = "CELL")]
    pub cell: Option<String>,
}

impl EnergyArgs {
    /// The conventions the options give, in order (`--cell` last).
    pub fn conventions(&self) -> anyhow::Result<Conventions> {
        let mut c = Conventions::default();
        let cell = self.cell.as_ref().map(|v| format!("sram_cell={v}"));
        for kv in self.energy.iter().chain(cell.as_ref()) {
            let (k, v) = kv
                .split_once('=')
                .ok_or_else(|| anyhow::anyhow!("--energy takes KEY=VALUE pairs, got '{kv}'"))?;
            anyhow::ensure!(
                c.set(k, v)?,
                "unknown energy convention '{k}' (known: energy, {})",
                Conventions::KEYS.join(", ")
            );
        }
        Ok(c)
    }

    /// The options as `--set KEY=VALUE` pairs of the accelerator's configuration, which
    /// reads the same keys.
    pub fn as_set(&self) -> Vec<String> {
        let mut v = self.energy.clone();
        v.extend(self.cell.iter().map(|c| format!("sram_cell={c}")));
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::energy::{Cell, FpuSource};

    #[test]
    fn pairs_apply_in_order_and_errors_are_one_line() {
        let a = EnergyArgs {
            energy: vec!["energy=earlier".into(), "fpu_energy=galal".into()],
            cell: Some("lop".into()),
        };
        let c = a.conventions().unwrap();
        assert_eq!(c.fpu, FpuSource::Galal);
        assert_eq!(c.cell, Cell::Lop);
        assert_eq!(c.ram, Conventions::earlier().ram);
        assert_eq!(
            EnergyArgs::default().conventions().unwrap(),
            Conventions::default()
        );
        for bad in ["fpu_energy", "nope=1", "sram_cell=xx"] {
            let e = EnergyArgs {
                energy: vec![bad.into()],
                cell: None,
            }
            .conventions()
            .unwrap_err()
            .to_string();
            assert!(!e.contains('\n') && !e.is_empty(), "{e}");
        }
        let mut rt = sim::rtunit::RtConfig::default();
        for kv in a.as_set() {
            let (k, v) = kv.split_once('=').unwrap();
            rt.set(k, v).unwrap();
        }
        assert_eq!(rt.energy, c);
    }
}
