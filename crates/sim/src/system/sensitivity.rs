//! How much each assumption moves the \[P2\] §6.4 reproduction: every open choice of the
//! system model (the energy conventions, the accelerator's unstated timing parameters, the
//! sampling rate) set to each value of a documented range, one at a time from the
//! defaults, and for every reproduced figure of Table VIII the default, the lowest and
//! highest value any variant gave, and the assumption that moves it most
//! (`arbor report sensitivity`; `arbor.report.sensitivity.v1`).
//!
//! Variants that differ only in what is computed from the cycle-level runs (the energy
//! conventions, the IST division's FLOPs) reuse the runs ([`SimMemo`]), so those cost
//! almost nothing; the timing parameters and the sampling rate simulate again.

use std::fmt::Write as _;

use rayon::prelude::*;
use serde::Serialize;

use super::report::{scene_result_memo, table8, SceneResult, SystemScene};
use super::{SimMemo, SystemConfig, SystemError};

/// Schema of the JSON document.
pub const SCHEMA: &str = "arbor.report.sensitivity.v1";

/// The key of [`Assumption`] that sets the scenes' sampling rate rather than a
/// configuration key.
pub const SAMPLE_KEY: &str = "sample";

/// One assumption and the values it is swept over.
#[derive(Clone, Debug, Serialize)]
pub struct Assumption {
    /// A `SystemConfig::set` key, or [`SAMPLE_KEY`].
    pub key: &'static str,
    /// Its value in the default model (as documented; the runs use the configuration's).
    pub default: &'static str,
    /// The other values tried.
    pub values: Vec<&'static str>,
    /// What it is and where its default comes from.
    pub what: &'static str,
}

/// The documented assumptions and ranges of the system model.
pub fn assumptions() -> Vec<Assumption> {
    let a = |key, default, values: &[&'static str], what| Assumption {
        key,
        default,
        values: values.to_vec(),
        what,
    };
    vec![
        a(
            "sram_cell",
            "lop",
            &["hp"],
            "SRAM cell type (thesis: 28 nm FDSOI with multi-threshold optimizations)",
        ),
        a(
            "fpu_energy",
            "galal",
            &["horowitz"],
            "FPU energy per operation (thesis: Galal et al., linear scaling)",
        ),
        a(
            "ram_figures",
            "scratchpad",
            &["cache-table"],
            "figures of FIFOs, stacks, heap and scratchpad (hardware.md §3.1)",
        ),
        a(
            "wide_port",
            "banked",
            &["p4-ratio"],
            "cost of a wide cache port (none in the BVH2 system)",
        ),
        a(
            "dram_energy",
            "above-idle",
            &["full"],
            "DRAM energy in the totals (thesis: above an idle memory)",
        ),
        a(
            "ist_div_flops",
            "3",
            &["11"],
            "FLOPs of the IST division ([P2] §6.4: 3; [P4] §3.2: 11)",
        ),
        a(
            "stacks_per_trv",
            "32",
            &["8"],
            "ray slots per TRV ([P4] §3: 32)",
        ),
        a(
            "l2_latency",
            "4",
            &["2", "8"],
            "node cache hit latency, cycles (Arbor's assumption)",
        ),
        a(
            "prim_latency",
            "2",
            &["1", "4"],
            "primitive cache hit latency, cycles (Arbor's assumption)",
        ),
        a(
            "mshrs",
            "16",
            &["8", "32"],
            "misses in flight per cache (Arbor's assumption)",
        ),
        a(
            "trv_stages",
            "6",
            &["4", "8"],
            "TRV pipeline depth (Arbor's reading of [P4] Fig. 3)",
        ),
        a(
            "ist_stages",
            "20",
            &["10", "30"],
            "IST pipeline depth (Arbor's assumption)",
        ),
        a(
            "cull_cycles_per_entry",
            "1",
            &["0", "2"],
            "cycles per culled stack entry (Arbor's assumption)",
        ),
        a(
            "l2_ports",
            "1",
            &["0"],
            "lines the node cache returns per cycle (0: unlimited, the earlier model)",
        ),
        a(
            SAMPLE_KEY,
            "the scenes'",
            &["8", "64"],
            "one in N tile chunks timed (sampling error)",
        ),
    ]
}

/// One reproduced figure across the variants.
#[derive(Clone, Debug, Serialize)]
pub struct FigureRow {
    /// The figure, e.g. `VIII primary all hlbvh total`.
    pub figure: String,
    /// The thesis's value, where it gives one.
    pub thesis: Option<f64>,
    /// The default model's value.
    pub default: f64,
    /// The lowest value of any variant (the default included).
    pub low: f64,
    /// The highest.
    pub high: f64,
    /// The assumption whose values spread the figure most (empty when none moves it).
    pub driver: String,
    /// That assumption's spread (highest less lowest of its values and the default).
    pub driver_spread: f64,
    /// Whether the thesis's value lies in `[low, high]`.
    pub thesis_inside: Option<bool>,
}

/// One variant's figures.
#[derive(Clone, Debug, Serialize)]
pub struct Variant {
    /// The assumption (`default` for the default model).
    pub key: String,
    /// Its value.
    pub value: String,
    /// Figure name and value, in [`SensitivityReport::rows`] order.
    pub figures: Vec<(String, f64)>,
}

/// The whole study.
#[derive(Clone, Debug, Serialize)]
pub struct SensitivityReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// Scenes (name, triangles).
    pub scenes: Vec<(String, usize)>,
    /// The assumptions swept.
    pub assumptions: Vec<Assumption>,
    /// Per figure.
    pub rows: Vec<FigureRow>,
    /// Per variant.
    pub variants: Vec<Variant>,
    /// Cycle-level runs simulated.
    pub simulated: u64,
    /// Cycle-level runs reused from an earlier variant.
    pub reused: u64,
}

/// The Table VIII figures of one variant: every builder but the reference, per ray kind,
/// scene set and column, with the thesis's value.
fn figures(results: &[SceneResult]) -> Vec<(String, f64, Option<f64>)> {
    let mut v = Vec::new();
    for r in table8(results) {
        if r.builder == super::Builder::BinnedSah.name() {
            continue;
        }
        for (i, col) in ["build", "trace", "total"].into_iter().enumerate() {
            v.push((
                format!("VIII {} {} {} {col}", r.rays, r.scenes, r.builder),
                [r.build, r.trace, r.total][i],
                r.thesis.map(|t| t[i]),
            ));
        }
    }
    v
}

/// Runs the default model and every value of every assumption over `scenes`. `progress`
/// is told what runs. An assumption with a key the configuration does not know is an
/// error before anything runs.
pub fn run(
    scenes: &[SystemScene<'_>],
    base: &SystemConfig,
    assumptions: &[Assumption],
    progress: impl Fn(&str) + Sync,
) -> Result<SensitivityReport, SystemError> {
    if scenes.is_empty() {
        return Err(SystemError::Config(
            "no scenes for the sensitivity study".into(),
        ));
    }
    // (key, value, config, sample override)
    let mut variants: Vec<(String, String, SystemConfig, Option<u32>)> =
        vec![("default".into(), String::new(), base.clone(), None)];
    for a in assumptions {
        for &v in &a.values {
            if a.key == SAMPLE_KEY {
                let k: u32 = v
                    .parse()
                    .ok()
                    .filter(|k| *k >= 1)
                    .ok_or_else(|| SystemError::Config(format!("bad sample '{v}'")))?;
                variants.push((a.key.into(), v.into(), base.clone(), Some(k)));
            } else {
                let mut c = base.clone();
                c.set(a.key, v)?;
                variants.push((a.key.into(), v.into(), c, None));
            }
        }
    }
    // Scenes in parallel, each with its own memo over all the variants.
    let per_scene: Vec<(Vec<SceneResult>, u64, u64)> = scenes
        .par_iter()
        .map(|s| {
            let mut memo = SimMemo::default();
            let mut out = Vec::with_capacity(variants.len());
            for (key, value, cfg, sample) in &variants {
                let scene = SystemScene {
                    name: s.name.clone(),
                    triangles: s.triangles,
                    camera: s.camera,
                    sample: sample.unwrap_or(s.sample),
                };
                let label = if key == "default" {
                    "default".to_string()
                } else {
                    format!("{key}={value}")
                };
                out.push(scene_result_memo(&scene, cfg, &mut memo, |what| {
                    progress(&format!("{label}: {what}"))
                })?);
            }
            Ok((out, memo.simulated, memo.reused))
        })
        .collect::<Result<_, SystemError>>()?;
    let (mut simulated, mut reused) = (0, 0);
    let mut results: Vec<Vec<SceneResult>> = vec![Vec::new(); variants.len()];
    for (out, sim, re) in per_scene {
        simulated += sim;
        reused += re;
        for (i, r) in out.into_iter().enumerate() {
            results[i].push(r);
        }
    }
    let per_variant: Vec<Vec<(String, f64, Option<f64>)>> =
        results.iter().map(|r| figures(r)).collect();
    let mut rows = Vec::new();
    for (f, (name, default, thesis)) in per_variant[0].iter().enumerate() {
        let values: Vec<f64> = per_variant.iter().map(|v| v[f].1).collect();
        let low = values.iter().copied().fold(f64::INFINITY, f64::min);
        let high = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut driver = String::new();
        let mut driver_spread = 0.0;
        for a in assumptions {
            let of: Vec<f64> = variants
                .iter()
                .zip(&values)
                .filter(|((k, ..), _)| k == a.key)
                .map(|(_, &x)| x)
                .chain([*default])
                .collect();
            let spread = of.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                - of.iter().copied().fold(f64::INFINITY, f64::min);
            if spread > driver_spread {
                driver_spread = spread;
                driver = a.key.to_string();
            }
        }
        rows.push(FigureRow {
            figure: name.clone(),
            thesis: *thesis,
            default: *default,
            low,
            high,
            driver,
            driver_spread,
            thesis_inside: thesis.map(|t| t >= low - 1e-12 && t <= high + 1e-12),
        });
    }
    let variants = variants
        .into_iter()
        .zip(&per_variant)
        .map(|((key, value, ..), figs)| Variant {
            key,
            value,
            figures: figs.iter().map(|(n, v, _)| (n.clone(), *v)).collect(),
        })
        .collect();
    Ok(SensitivityReport {
        schema: SCHEMA,
        scenes: scenes
            .iter()
            .map(|s| (s.name.clone(), s.triangles.len()))
            .collect(),
        assumptions: assumptions.to_vec(),
        rows,
        variants,
        simulated,
        reused,
    })
}

impl SensitivityReport {
    /// The figures as Markdown: value, range, driver, thesis, in percent of binned SAH.
    pub fn markdown(&self) -> String {
        let pct = |x: f64| format!("{:.0}%", x * 100.0);
        let mut m = String::from(
            "| figure | thesis | default | low | high | driver (spread) | thesis in range |\n|---|---:|---:|---:|---:|---|---|\n",
        );
        for r in &self.rows {
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} | {} | {} |",
                r.figure,
                r.thesis.map_or("-".into(), pct),
                pct(r.default),
                pct(r.low),
                pct(r.high),
                if r.driver.is_empty() {
                    "-".to_string()
                } else {
                    format!("{} ({:.1} pp)", r.driver, r.driver_spread * 100.0)
                },
                match r.thesis_inside {
                    Some(true) => "yes",
                    Some(false) => "no",
                    None => "-",
                }
            );
        }
        m
    }

    /// The assumptions as Markdown.
    pub fn assumptions_markdown(&self) -> String {
        let mut m = String::from("| key | default | tried | what |\n|---|---|---|---|\n");
        for a in &self.assumptions {
            let _ = writeln!(
                m,
                "| `{}` | {} | {} | {} |",
                a.key,
                a.default,
                a.values.join(", "),
                a.what
            );
        }
        m
    }

    /// One CSV row per figure.
    pub fn csv(&self) -> String {
        let mut c = String::from("figure,thesis,default,low,high,driver,driver_spread\n");
        for r in &self.rows {
            let _ = writeln!(
                c,
                "{},{},{},{},{},{},{}",
                r.figure,
                r.thesis.map_or(String::new(), |t| t.to_string()),
                r.default,
                r.low,
                r.high,
                r.driver,
                r.driver_spread
            );
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::energy::FpuSource;
    use scene::LoadOptions;

    fn scene(spec: &str) -> (Vec<geom::Triangle>, trace::PinholeCamera) {
        let s = scene::open(spec, &LoadOptions::default()).unwrap();
        let tris: Vec<geom::Triangle> = s.mesh_at(0.0).unwrap().triangles_iter().collect();
        let cam = trace::PinholeCamera::new(&s.info().camera, 16, 12).unwrap();
        (tris, cam)
    }

    /// Two assumptions over a tiny scene: the conventions reuse every cycle-level run,
    /// the figures of each variant equal a run of that configuration alone, and the rows
    /// hold the lowest and highest of the variants, with the driver the assumption that
    /// moves the figure most.
    #[test]
    fn variants_equal_single_runs_and_rows_span_them() {
        let (tris, cam) = scene("proc:hairball?n=2000&seed=3");
        let scenes = [SystemScene {
            name: "hairball".into(),
            triangles: &tris,
            camera: cam,
            sample: 1,
        }];
        let base = SystemConfig::default();
        let all = assumptions();
        let pick: Vec<Assumption> = all
            .into_iter()
            .filter(|a| a.key == "fpu_energy" || a.key == "l2_latency")
            .collect();
        let rep = run(&scenes, &base, &pick, |_| {}).unwrap();
        assert_eq!(rep.variants.len(), 1 + 1 + 2);
        // Per variant: 3 MergeTree runs and 8 traces; the FPU variant reuses all 11, the
        // latency variants reuse the MergeTree runs and trace again.
        assert_eq!(rep.simulated, 11 + 2 * 8);
        assert_eq!(rep.reused, 11 + 2 * 3);
        // The Horowitz variant equals a run of that configuration on its own.
        let mut horowitz = base.clone();
        horowitz.set("fpu_energy", "horowitz").unwrap();
        assert_eq!(horowitz.energy.fpu, FpuSource::Horowitz);
        let alone = super::super::report::scene_result(&scenes[0], &horowitz, |_| {}).unwrap();
        let want = figures(&[alone]);
        let got = &rep.variants[1];
        assert_eq!(got.key, "fpu_energy");
        for ((n, v), (wn, wv, _)) in got.figures.iter().zip(&want) {
            assert_eq!(n, wn);
            assert!(
                (v - wv).abs() <= 1e-12 * wv.abs().max(1.0),
                "{n}: {v} vs {wv}"
            );
        }
        // Rows span the variants; every row has a thesis value (Table VIII's builders).
        assert_eq!(rep.rows.len(), 2 * 3 * 3);
        for (f, r) in rep.rows.iter().enumerate() {
            let vals: Vec<f64> = rep.variants.iter().map(|v| v.figures[f].1).collect();
            assert_eq!(r.default, vals[0]);
            assert_eq!(r.low, vals.iter().copied().fold(f64::INFINITY, f64::min));
            assert_eq!(
                r.high,
                vals.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            );
            assert!(r.thesis.is_some());
            if r.high > r.low {
                assert!(
                    r.driver == "fpu_energy" || r.driver == "l2_latency",
                    "{r:?}"
                );
                assert!(r.driver_spread > 0.0 && r.driver_spread <= r.high - r.low + 1e-12);
            }
        }
        // The FPU source moves the binned SAH reference, so it moves the build ratios.
        let build = rep
            .rows
            .iter()
            .find(|r| r.figure == "VIII primary all hlbvh build")
            .unwrap();
        assert_eq!(build.driver, "fpu_energy", "{build:?}");
        assert!(rep.markdown().lines().count() == rep.rows.len() + 2);
        assert_eq!(rep.csv().lines().count(), rep.rows.len() + 1);
    }

    #[test]
    fn unknown_keys_and_bad_values_fail_before_running() {
        let (tris, cam) = scene("proc:hairball?n=500&seed=3");
        let scenes = [SystemScene {
            name: "h".into(),
            triangles: &tris,
            camera: cam,
            sample: 1,
        }];
        for (key, value) in [("warp_drive", "1"), ("sram_cell", "xx"), (SAMPLE_KEY, "0")] {
            let a = Assumption {
                key,
                default: "",
                values: vec![value],
                what: "",
            };
            let ran = std::sync::atomic::AtomicBool::new(false);
            let e = run(&scenes, &SystemConfig::default(), &[a], |_| {
                ran.store(true, std::sync::atomic::Ordering::Relaxed)
            })
            .unwrap_err()
            .to_string();
            assert!(!ran.into_inner() && !e.contains('\n'), "{key}: {e}");
        }
        assert!(run(&[], &SystemConfig::default(), &assumptions(), |_| {}).is_err());
    }
}
