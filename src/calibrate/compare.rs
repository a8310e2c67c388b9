//! The paper's comparison grid: growing observable sets × {no MD, Kernel I, Kernel II}.

use super::{run, write_outputs, Calibration, Overrides, Problem};
use crate::artifacts;
use crate::config::Config;
use crate::gp::DiscrepancyKernel;
use anyhow::Result;
use polars::prelude::*;
use std::path::Path;

pub const KERNELS: [Option<DiscrepancyKernel>; 3] = [None, Some(DiscrepancyKernel::KernelI), Some(DiscrepancyKernel::KernelII)];

/// One calibration in the grid.
pub struct CompareCase {
    pub observables: Vec<String>,
    pub kernel: Option<DiscrepancyKernel>,
    pub dir_name: String,
    pub calibration: Calibration,
}

/// Observable sets {o1}, {o1, o2}, … in the config's order.
pub fn observable_sets(config: &Config, overrides: &Overrides) -> Result<Vec<Vec<String>>> {
    let all = match &overrides.observables {
        Some(o) => o.clone(),
        None => Problem::new(config, &Overrides { kernel: Some(None), ..overrides.clone() })?.observables(),
    };
    Ok((1..=all.len()).map(|k| all[..k].to_vec()).collect())
}

pub fn case_dir_name(observables: &[String], kernel: Option<DiscrepancyKernel>) -> String {
    format!("{}__{}", observables.join("+"), match kernel {
        None => "nomd",
        Some(DiscrepancyKernel::KernelI) => "kernel1",
        Some(DiscrepancyKernel::KernelII) => "kernel2",
    })
}

/// Runs every case, writing each into `out/<case>/` and the tables into `out/`.
pub fn run_grid(config: &Config, overrides: &Overrides, seed: u64, out: &Path, show_progress: bool) -> Result<Vec<CompareCase>> {
    let mut cases = Vec::new();
    for (i, obs) in observable_sets(config, overrides)?.into_iter().enumerate() {
        for (j, kernel) in KERNELS.iter().enumerate() {
            let ov = Overrides { kernel: Some(*kernel), observables: Some(obs.clone()), ..overrides.clone() };
            let problem = Problem::new(config, &ov)?;
            let case_seed = seed.wrapping_add((i * 3 + j) as u64 * 1_000_003);
            let calibration = run(&problem, case_seed, show_progress)?;
            let dir_name = case_dir_name(&obs, *kernel);
            write_outputs(&out.join(&dir_name), &problem, &calibration)?;
            cases.push(CompareCase { observables: obs.clone(), kernel: *kernel, dir_name, calibration });
        }
    }
    write_tables(config, &cases, out)?;
    Ok(cases)
}

fn write_tables(config: &Config, cases: &[CompareCase], out: &Path) -> Result<()> {
    let theta_names: Vec<String> = config.parameters.keys().cloned().collect();
    let mut md = String::new();
    md.push_str(&format!("# {}: observable sets × discrepancy kernels\n\n", config.name));
    md.push_str("Posterior medians with 95% intervals [68% in parentheses]; log-evidence ± its standard error.\n\n");
    md.push_str("| observables | kernel |");
    for n in &theta_names {
        let truth = config.parameters[n].truth.map(|t| format!(" (truth {t})")).unwrap_or_default();
        md.push_str(&format!(" {n}{truth} |"));
    }
    md.push_str(" log Z | max R̂ | min ESS | s |\n|---|---|");
    for _ in &theta_names {
        md.push_str("---|");
    }
    md.push_str("---|---|---|---|\n");
    let (mut c_obs, mut c_kernel, mut c_param, mut c_truth) = (vec![], vec![], vec![], vec![]);
    let (mut c_med, mut c_q025, mut c_q975, mut c_q16, mut c_q84, mut c_logz, mut c_logz_err, mut c_rhat, mut c_ess, mut c_wall) =
        (vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![]);
    for case in cases {
        let s = &case.calibration.summary;
        let rhat = s.diagnostics.parameters.iter().map(|d| d.rhat).fold(f64::NEG_INFINITY, f64::max);
        let ess = s.diagnostics.parameters.iter().map(|d| d.ess_bulk.min(d.ess_tail)).fold(f64::INFINITY, f64::min);
        md.push_str(&format!("| {} | {} |", case.observables.join(", "), s.kernel));
        for n in &theta_names {
            let p = &s.parameters[n];
            md.push_str(&format!(" {:.3} [{:.3}, {:.3}] ({:.3}, {:.3}) |", p.median, p.q025, p.q975, p.q16, p.q84));
            c_obs.push(case.observables.join("+"));
            c_kernel.push(s.kernel.clone());
            c_param.push(n.clone());
            c_truth.push(config.parameters[n].truth.unwrap_or(f64::NAN));
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
