//! The paper's comparison grid: growing observable sets × {no MD, Kernel I,
//! Kernel II}, on the analysis' data or on replicate mock data sets.

use crate::base::artifacts::{self, Measurement};
use crate::base::choices::Kernel;
use crate::base::progress::{Observer, Silent};
use crate::engine::calibrate::{run, write_outputs, Analysis, Calibration, Overrides, Problem};
use crate::engine::gp::DiscrepancyKernel;
use anyhow::Result;
use polars::prelude::*;
use std::path::Path;

pub const KERNELS: [Option<DiscrepancyKernel>; 3] =
    [None, Some(DiscrepancyKernel::KernelI), Some(DiscrepancyKernel::KernelII)];

/// One calibration in the grid.
pub struct CompareCase {
    pub observables: Vec<String>,
    pub kernel: Option<DiscrepancyKernel>,
    pub dir_name: String,
    pub calibration: Calibration,
}

/// Observable sets {o1}, {o1, o2}, … in the config's order.
pub fn observable_sets(analysis: &Analysis, overrides: &Overrides) -> Result<Vec<Vec<String>>> {
    let all = match &overrides.observables {
        Some(o) => o.clone(),
        None => Problem::new(analysis, &Overrides { kernel: Some(Kernel::None), ..overrides.clone() })?.observables(),
    };
    Ok((1..=all.len()).map(|k| all[..k].to_vec()).collect())
}

pub fn case_dir_name(observables: &[String], kernel: Option<DiscrepancyKernel>) -> String {
    format!(
        "{}__{}",
        observables.join("+"),
        match kernel {
            None => "nomd",
            Some(DiscrepancyKernel::KernelI) => "kernel1",
            Some(DiscrepancyKernel::KernelII) => "kernel2",
        }
    )
}

/// Runs every case, writing each into `out/<case>/` and the tables into `out/`.
pub fn run_grid(
    analysis: &Analysis,
    overrides: &Overrides,
    seed: u64,
    out: &Path,
    observer: &dyn Observer,
) -> Result<Vec<CompareCase>> {
    let mut cases = Vec::new();
    for (i, obs) in observable_sets(analysis, overrides)?.into_iter().enumerate() {
        for (j, kernel) in KERNELS.iter().enumerate() {
            let ov = Overrides {
                kernel: Some(DiscrepancyKernel::choice(*kernel)),
                observables: Some(obs.clone()),
                ..overrides.clone()
            };
            let problem = Problem::new(analysis, &ov)?;
            let case_seed = seed.wrapping_add((i * 3 + j) as u64 * 1_000_003);
            let calibration = run(&problem, case_seed, observer)?;
            let dir_name = case_dir_name(&obs, *kernel);
            write_outputs(&out.join(&dir_name), &problem, &calibration)?;
            cases.push(CompareCase { observables: obs.clone(), kernel: *kernel, dir_name, calibration });
        }
    }
    write_tables(analysis, &cases, out)?;
    Ok(cases)
}

fn write_tables(analysis: &Analysis, cases: &[CompareCase], out: &Path) -> Result<()> {
    let theta_names: Vec<String> = analysis.parameters.keys().cloned().collect();
    let mut md = String::new();
    md.push_str(&format!("# {}: observable sets × discrepancy kernels\n\n", analysis.name));
    md.push_str("Posterior medians with 95% intervals [68% in parentheses]; log-evidence ± its standard error.\n\n");
    md.push_str("| observables | kernel |");
    for n in &theta_names {
        let truth = analysis.parameters[n].truth.map(|t| format!(" (truth {t})")).unwrap_or_default();
        md.push_str(&format!(" {n}{truth} |"));
    }
    md.push_str(" log Z | max R̂ | min ESS | s |\n|---|---|");
    for _ in &theta_names {
        md.push_str("---|");
    }
    md.push_str("---|---|---|---|\n");
    let (mut c_obs, mut c_kernel, mut c_param, mut c_truth) = (vec![], vec![], vec![], vec![]);
    let (
        mut c_med,
        mut c_q025,
        mut c_q975,
        mut c_q16,
        mut c_q84,
        mut c_logz,
        mut c_logz_err,
        mut c_rhat,
        mut c_ess,
        mut c_wall,
    ) = (vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![]);
    for case in cases {
        let s = &case.calibration.summary;
        let rhat = s.diagnostics.parameters.iter().map(|d| d.rhat).fold(f64::NEG_INFINITY, f64::max);
        let ess = s.diagnostics.parameters.iter().map(|d| d.ess_bulk.min(d.ess_tail)).fold(f64::INFINITY, f64::min);
        md.push_str(&format!("| {} | {} |", case.observables.join(", "), s.kernel));
        for n in &theta_names {
            let p = &s.parameters[n];
            md.push_str(&format!(
                " {} ({}, {}) |",
                p.interval(),
                crate::engine::calibrate::results::summary::readable(p.q16),
                crate::engine::calibrate::results::summary::readable(p.q84)
            ));
            c_obs.push(case.observables.join("+"));
            c_kernel.push(s.kernel.clone());
            c_param.push(n.clone());
            c_truth.push(analysis.parameters[n].truth.unwrap_or(f64::NAN));
            c_med.push(p.median);
            c_q025.push(p.q025);
            c_q975.push(p.q975);
            c_q16.push(p.q16);
            c_q84.push(p.q84);
            c_logz.push(s.log_evidence.unwrap_or(f64::NAN));
            c_logz_err.push(s.log_evidence_err.unwrap_or(f64::NAN));
            c_rhat.push(rhat);
            c_ess.push(ess);
            c_wall.push(s.diagnostics.wall_seconds);
        }
        let logz = match (s.log_evidence, s.log_evidence_err) {
            (Some(z), Some(e)) => format!("{z:.2} ± {e:.2}"),
            _ => "–".into(),
        };
        md.push_str(&format!(" {logz} | {rhat:.3} | {ess:.0} | {:.1} |\n", s.diagnostics.wall_seconds));
    }
    artifacts::write_text_atomic(&out.join("compare.md"), &md)?;
    let n = c_obs.len();
    let mut df = DataFrame::new(
        n,
        vec![
            Column::new("observables".into(), c_obs),
            Column::new("kernel".into(), c_kernel),
            Column::new("parameter".into(), c_param),
            Column::new("truth".into(), c_truth),
            Column::new("median".into(), c_med),
            Column::new("q025".into(), c_q025),
            Column::new("q975".into(), c_q975),
            Column::new("q16".into(), c_q16),
            Column::new("q84".into(), c_q84),
            Column::new("log_evidence".into(), c_logz),
            Column::new("log_evidence_err".into(), c_logz_err),
            Column::new("max_rhat".into(), c_rhat),
            Column::new("min_ess".into(), c_ess),
            Column::new("wall_seconds".into(), c_wall),
        ],
    )?;
    let prov = cases.first().map(|c| c.calibration.summary.provenance.clone());
    artifacts::write_parquet_atomic(&out.join("compare.parquet"), &mut df, prov.as_ref())?;
    Ok(())
}

/// How often each case of the grid covers the truth over independent mock
/// data sets, and how wide it is: a single data set decides a coverage claim
/// by luck as much as by method.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReplicateRow {
    pub observables: String,
    pub kernel: String,
    pub parameter: String,
    pub replicates: usize,
    pub covered: usize,
    pub mean_width95: f64,
    /// Replicates in which this case's 95% interval is wider than Kernel II's
    /// on the same data (Kernel I rows only).
    pub wider_than_kernel2: Option<usize>,
}

/// Mock measurements: the true process at θ's true values, at the x and with
/// the errors of `template` (the analysis' own data), plus Gaussian noise.
pub fn mock_measurements(
    analysis: &Analysis,
    template: &[Measurement],
    rng: &mut impl rand::Rng,
) -> Result<Vec<Measurement>> {
    use rand_distr::{Distribution, Normal};
    let mut out = Vec::with_capacity(template.len());
    for m in template {
        let truth = analysis.truth_curve(&m.observable, &[m.x]).map(|v| v[0]).filter(|v| v.is_finite());
        let truth = truth.ok_or_else(|| {
            anyhow::anyhow!(
                "{}: mock data need a [truth] process and a `truth` value for every parameter (none for {} at x = {})",
                analysis.config_path.display(),
                m.observable,
                m.x
            )
        })?;
        out.push(Measurement::new(&m.observable, m.x, truth + Normal::new(0.0, m.error)?.sample(rng), m.error));
    }
    Ok(out)
}

/// Runs the grid on `n` mock data sets drawn from the config's `[truth]`
/// process at the parameters' true values and at the analysis' data points,
/// into `out/replicate_<r>/`, and writes `replicates.md` and `replicates.parquet`.
pub fn run_replicates(
    analysis: &Analysis,
    overrides: &Overrides,
    n: usize,
    seed: u64,
    out: &Path,
) -> Result<Vec<ReplicateRow>> {
    use rand::SeedableRng;
    let template = artifacts::read_measurements(&analysis.data)?;
    // (observables, kernel, parameter) -> (covered, widths)
    let mut acc: std::collections::BTreeMap<(String, String, String), (usize, Vec<f64>)> = Default::default();
    let bar = crate::base::progress::bar(n as u64, "replicate grids");
    for r in 0..n {
        let dir = out.join(format!("replicate_{r:03}"));
        let rseed = seed.wrapping_add(r as u64);
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(rseed);
        let data = mock_measurements(analysis, &template, &mut rng)?;
        let data_path = dir.join("data.csv");
        let prov = artifacts::Provenance::new(
            analysis.config_hash.clone(),
            artifacts::measurements_hash(&data),
            rseed,
            "compare --replicates: mock data from [truth]",
        );
        artifacts::write_measurements(&data_path, &data, Some(&prov))?;
        let replicate = analysis.with_data(&std::path::absolute(&data_path)?);
        for case in run_grid(&replicate, overrides, rseed, &dir, &Silent)? {
            let s = &case.calibration.summary;
            for (name, p) in &analysis.parameters {
                let (Some(t), Some(ps)) = (p.truth, s.parameters.get(name)) else { continue };
                let e = acc.entry((case.observables.join("+"), s.kernel.clone(), name.clone())).or_default();
                e.0 += ps.covers(t) as usize;
                e.1.push(ps.width95());
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let rows: Vec<ReplicateRow> = acc
        .iter()
        .map(|((obs, kernel, param), (covered, widths))| {
            let wider = (kernel == "I").then(|| {
                acc.get(&(obs.clone(), "II".to_string(), param.clone()))
                    .map(|(_, w2)| widths.iter().zip(w2).filter(|(a, b)| a > b).count())
                    .unwrap_or(0)
            });
            ReplicateRow {
                observables: obs.clone(),
                kernel: kernel.clone(),
                parameter: param.clone(),
                replicates: widths.len(),
                covered: *covered,
                mean_width95: widths.iter().sum::<f64>() / widths.len().max(1) as f64,
                wider_than_kernel2: wider,
            }
        })
        .collect();
    let mut md = format!("# {}: the grid over {n} independent mock data sets\n\nCoverage = replicates whose 95% interval contains the truth; a calibrated 95% interval covers in 95% of them (binomial sd for {n}: {:.1}).\n\n| observables | kernel | parameter | covered | mean 95% width | Kernel I wider than II |\n|---|---|---|---|---|---|\n", analysis.name, (n as f64 * 0.95 * 0.05).sqrt());
    for r in &rows {
        md.push_str(&format!(
            "| {} | {} | {} | {} of {} | {:.3} | {} |\n",
            r.observables,
            r.kernel,
            r.parameter,
            r.covered,
            r.replicates,
            r.mean_width95,
            r.wider_than_kernel2.map(|w| format!("{w} of {}", r.replicates)).unwrap_or_default()
        ));
    }
    artifacts::write_text_atomic(&out.join("replicates.md"), &md)?;
    let col_s = |f: &dyn Fn(&ReplicateRow) -> String| rows.iter().map(f).collect::<Vec<String>>();
    let mut df = DataFrame::new(
        rows.len(),
        vec![
            Column::new("observables".into(), col_s(&|r| r.observables.clone())),
            Column::new("kernel".into(), col_s(&|r| r.kernel.clone())),
            Column::new("parameter".into(), col_s(&|r| r.parameter.clone())),
            Column::new("replicates".into(), rows.iter().map(|r| r.replicates as u32).collect::<Vec<u32>>()),
            Column::new("covered".into(), rows.iter().map(|r| r.covered as u32).collect::<Vec<u32>>()),
            Column::new("mean_width95".into(), rows.iter().map(|r| r.mean_width95).collect::<Vec<f64>>()),
            Column::new(
                "wider_than_kernel2".into(),
                rows.iter().map(|r| r.wider_than_kernel2.map(|w| w as u32)).collect::<Vec<Option<u32>>>(),
            ),
        ],
    )?;
    let prov = artifacts::Provenance::new(
        analysis.config_hash.clone(),
        String::new(),
        seed,
        &format!("compare --replicates {n}"),
    );
    artifacts::write_parquet_atomic(&out.join("replicates.parquet"), &mut df, Some(&prov))?;
    Ok(rows)
}
