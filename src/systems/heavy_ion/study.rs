//! What a set of calibrations of one study shows: bias in units of the
//! posterior width, the paper's consistency checks, η/s(T) coverage of the
//! truth, and whether the emulator is more precise than the data.

use super::figures as heavy_ion;
use crate::base::artifacts::Measurement;
use crate::base::config::Config;
use crate::engine::calibrate::results::summary::Summary;
use crate::engine::report::RunArtifacts;
use anyhow::Result;
use std::collections::BTreeMap;
use std::path::Path;

/// Two posteriors are called consistent when their means differ by less than
/// this many combined standard deviations.
pub const CONSISTENT_Z: f64 = 2.0;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Study {
    pub name: String,
    pub truth: BTreeMap<String, f64>,
    pub cases: Vec<CaseResult>,
    pub consistency: Vec<ConsistencyCheck>,
    pub emulator_vs_data: Vec<EmulatorVsData>,
    pub eta_s_coverage: Vec<EtaSCoverage>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CaseResult {
    pub case: String,
    pub observables: Vec<String>,
    pub kernel: String,
    pub parameters: BTreeMap<String, ParamResult>,
    pub log_evidence: Option<f64>,
    pub converged: bool,
    pub seconds: f64,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ParamResult {
    pub median: f64,
    pub mean: f64,
    pub sd: f64,
    pub q025: f64,
    pub q975: f64,
    /// Whether the 95% interval covers the truth (when known).
    pub covers: Option<bool>,
    /// (median − truth) / posterior sd.
    pub bias_in_sd: Option<f64>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ConsistencyCheck {
    /// "observables added" or "Kernel II vs Kernel I".
    pub check: String,
    pub parameter: String,
    pub from: String,
    pub to: String,
    /// |mean_to − mean_from| / sqrt(sd_from² + sd_to²).
    pub z: f64,
    /// 95% width of `to` over that of `from`.
    pub width_ratio: f64,
    pub consistent: bool,
    /// For "Kernel II vs Kernel I": Kernel II is the tighter.
    pub tighter: Option<bool>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EmulatorVsData {
    pub observable: String,
    /// Held-out RMSE over the validation design, per bin, over the data error in that bin.
    pub median_ratio: f64,
    pub max_ratio: f64,
    pub bins_above_error: usize,
    pub bins: usize,
    /// The same after removing the validation runs' own statistical noise:
    /// sqrt(max(0, MSE − mean σ_run²)) over the data error, median over bins.
    pub median_ratio_noise_removed: f64,
    pub bins_above_error_noise_removed: usize,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EtaSCoverage {
    pub case: String,
    /// Fraction of the temperature grid (0.10–0.35 GeV) where the 95% band covers the truth.
    pub fraction_covered: f64,
    /// Temperature ranges (GeV) where the band misses the truth.
    pub missed: Vec<[f64; 2]>,
}

fn param_result(p: &crate::engine::calibrate::results::summary::ParamSummary, truth: Option<f64>) -> ParamResult {
    ParamResult {
        median: p.median,
        mean: p.mean,
        sd: p.sd,
        q025: p.q025,
        q975: p.q975,
        covers: truth.map(|t| p.covers(t)),
        bias_in_sd: truth.map(|t| (p.median - t) / p.sd.max(f64::MIN_POSITIVE)),
    }
}

fn z_between(a: &ParamResult, b: &ParamResult) -> f64 {
    (a.mean - b.mean).abs() / (a.sd * a.sd + b.sd * b.sd).sqrt().max(f64::MIN_POSITIVE)
}

/// Assesses the calibrations in `case_dirs` (each a `calibrate` output);
/// `truth_point` names the stand-in parameters the mock data were made at.
/// `validation_runs` is the ingested validation table (its `error` column is
/// each run's statistical error).
pub fn assess(
    config: &Config,
    case_dirs: &[std::path::PathBuf],
    truth_point: &BTreeMap<String, f64>,
    emulator_dir: &Path,
    validation_runs: &Path,
    measurements: &Path,
) -> Result<Study> {
    let truth: BTreeMap<String, f64> =
        config.parameters.iter().filter_map(|(k, p)| p.truth.map(|t| (k.clone(), t))).collect();
    let theta: Vec<String> = config.parameters.keys().cloned().collect();
    let runs: Vec<RunArtifacts> = case_dirs.iter().map(|d| RunArtifacts::load(d)).collect::<Result<_>>()?;
    let cases: Vec<CaseResult> = runs.iter().map(|r| case_result(&r.summary, &r.dir, &theta, &truth)).collect();

    let mut consistency = Vec::new();
    let kernels: Vec<String> = {
        let mut k: Vec<String> = cases.iter().map(|c| c.kernel.clone()).collect();
        k.dedup();
        k.sort();
        k.dedup();
        k
    };
    // 1. As observables are added, within each method.
    for k in &kernels {
        let seq: Vec<&CaseResult> = cases.iter().filter(|c| &c.kernel == k).collect();
        for pair in seq.windows(2) {
            for p in &theta {
                let (a, b) = (&pair[0].parameters[p], &pair[1].parameters[p]);
                let z = z_between(a, b);
                consistency.push(ConsistencyCheck {
                    check: "observables added".into(),
                    parameter: p.clone(),
                    from: pair[0].case.clone(),
                    to: pair[1].case.clone(),
                    z,
                    width_ratio: (b.q975 - b.q025) / (a.q975 - a.q025),
                    consistent: z < CONSISTENT_Z,
                    tighter: None,
                });
            }
        }
    }
    // 2. Kernel II against Kernel I on the same observables.
    for c2 in cases.iter().filter(|c| c.kernel == "II") {
        let Some(c1) = cases.iter().find(|c| c.kernel == "I" && c.observables == c2.observables) else { continue };
        for p in &theta {
            let (a, b) = (&c1.parameters[p], &c2.parameters[p]);
            let z = z_between(a, b);
            let ratio = (b.q975 - b.q025) / (a.q975 - a.q025);
            consistency.push(ConsistencyCheck {
                check: "Kernel II vs Kernel I".into(),
                parameter: p.clone(),
                from: c1.case.clone(),
                to: c2.case.clone(),
                z,
                width_ratio: ratio,
                consistent: z < CONSISTENT_Z,
                tighter: Some(ratio < 1.0),
            });
        }
    }

    let emulator_vs_data = emulator_against_data(emulator_dir, validation_runs, measurements)?;
    let mut eta_s_coverage = Vec::new();
    let get = |p: &str| truth_point.get(p).copied();
    if let Some(true_curve) = heavy_ion::eta_s_from(&get) {
        for (run, case) in runs.iter().zip(&cases) {
            let Some(band) = heavy_ion::eta_s_band(run) else { continue };
            let covered: Vec<(f64, bool)> =
                band.iter().map(|&(t, lo, _, hi)| (t, (lo..=hi).contains(&true_curve.at(t)))).collect();
            let fraction = covered.iter().filter(|c| c.1).count() as f64 / covered.len().max(1) as f64;
            eta_s_coverage.push(EtaSCoverage {
                case: case.case.clone(),
                fraction_covered: fraction,
                missed: missed_ranges(&covered),
            });
        }
    }
    Ok(Study { name: config.name.clone(), truth, cases, consistency, emulator_vs_data, eta_s_coverage })
}

fn case_result(s: &Summary, dir: &Path, theta: &[String], truth: &BTreeMap<String, f64>) -> CaseResult {
    CaseResult {
        case: dir.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default(),
        observables: s.observables.clone(),
        kernel: s.kernel.clone(),
        parameters: theta
            .iter()
            .filter_map(|p| s.parameters.get(p).map(|ps| (p.clone(), param_result(ps, truth.get(p).copied()))))
            .collect(),
        log_evidence: s.log_evidence,
        converged: s.diagnostics.converged,
        seconds: s.diagnostics.wall_seconds,
    }
}

/// Contiguous runs of grid temperatures where the band misses the truth.
fn missed_ranges(covered: &[(f64, bool)]) -> Vec<[f64; 2]> {
    let mut out: Vec<[f64; 2]> = Vec::new();
    let mut open: Option<f64> = None;
    for (i, &(t, ok)) in covered.iter().enumerate() {
        match (ok, open) {
            (false, None) => open = Some(t),
            (true, Some(start)) => {
                out.push([start, covered[i - 1].0]);
                open = None;
            }
            _ => {}
        }
    }
    if let (Some(start), Some(last)) = (open, covered.last()) {
        out.push([start, last.0]);
    }
    out
}

/// Held-out emulator error per bin against the data's error in that bin.
fn emulator_against_data(
    emulator_dir: &Path,
    validation_runs: &Path,
    measurements: &Path,
) -> Result<Vec<EmulatorVsData>> {
    let parity_path = emulator_dir.join("validation_parity.parquet");
    if !parity_path.exists() {
        return Ok(Vec::new());
    }
    let bin = |o: &str, x: f64| (o.to_string(), (x * 1e6).round() as i64);
    let rows = crate::engine::report::emulator::load_parity(&parity_path)?;
    let data: Vec<Measurement> = crate::base::artifacts::read_measurements(measurements)?;
    // Mean squared statistical error of the validation runs, per bin.
    let mut run_var: BTreeMap<(String, i64), (f64, usize)> = BTreeMap::new();
    if validation_runs.exists() {
        let df = crate::base::artifacts::read_parquet(validation_runs)?;
        let obs: Vec<String> = df.column("observable")?.str()?.iter().map(|v| v.unwrap_or("").to_string()).collect();
        let xs: Vec<f64> = df.column("x")?.f64()?.iter().map(|v| v.unwrap_or(f64::NAN)).collect();
        let errs: Vec<f64> = df.column("error")?.f64()?.iter().map(|v| v.unwrap_or(f64::NAN)).collect();
        for ((o, x), e) in obs.iter().zip(&xs).zip(&errs) {
            let v = run_var.entry(bin(o, *x)).or_insert((0.0, 0));
            v.0 += e * e;
            v.1 += 1;
        }
    }
    let mut per_bin: BTreeMap<(String, i64), (f64, usize)> = BTreeMap::new();
    for r in rows.iter().filter(|r| r.set == "holdout") {
        let e = per_bin.entry(bin(&r.observable, r.x)).or_insert((0.0, 0));
        e.0 += (r.emulated - r.simulated).powi(2);
        e.1 += 1;
    }
    let mut by_obs: BTreeMap<String, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
    for (key, (ss, n)) in &per_bin {
        let Some(m) = data.iter().find(|m| bin(&m.observable, m.x) == *key) else { continue };
        let mse = ss / *n as f64;
        let noise = run_var.get(key).map(|(s, k)| s / *k as f64).unwrap_or(0.0);
        let entry = by_obs.entry(key.0.clone()).or_default();
        entry.0.push(mse.sqrt() / m.error);
        entry.1.push((mse - noise).max(0.0).sqrt() / m.error);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    Ok(by_obs
        .into_iter()
        .map(|(observable, (mut raw, mut denoised))| EmulatorVsData {
            observable,
            max_ratio: raw.iter().cloned().fold(f64::NAN, f64::max),
            bins_above_error: raw.iter().filter(|r| **r > 1.0).count(),
            bins: raw.len(),
            median_ratio: median(&mut raw),
            bins_above_error_noise_removed: denoised.iter().filter(|r| **r > 1.0).count(),
            median_ratio_noise_removed: median(&mut denoised),
        })
        .collect())
}

impl Study {
    pub fn markdown(&self) -> String {
        let theta: Vec<String> = self.cases.first().map(|c| c.parameters.keys().cloned().collect()).unwrap_or_default();
        let mut md = format!("# {}: the study\n\n", self.name);
        md.push_str("Posterior medians with 95% intervals; bias = (median − truth) / posterior sd; ✓ = the 95% interval covers the truth.\n\n| case | kernel |");
        for p in &theta {
            md.push_str(&format!(
                " {p} (truth {}) | bias/sd |",
                self.truth.get(p).map(|t| t.to_string()).unwrap_or("?".into())
            ));
        }
        md.push_str(" log Z | converged | s |\n|---|---|");
        md.push_str(&"---|---|".repeat(theta.len()));
        md.push_str("---|---|---|\n");
        for c in &self.cases {
            md.push_str(&format!("| {} | {} |", c.observables.join(", "), c.kernel));
            for p in &theta {
                let r = &c.parameters[p];
                let mark = match r.covers {
                    Some(true) => " ✓",
                    Some(false) => " ✗",
                    None => "",
                };
                md.push_str(&format!(
                    " {:.4} [{:.4}, {:.4}]{mark} | {} |",
                    r.median,
                    r.q025,
                    r.q975,
                    r.bias_in_sd.map(|b| format!("{b:+.2}")).unwrap_or_default()
                ));
            }
            md.push_str(&format!(
                " {} | {} | {:.1} |\n",
                c.log_evidence.map(|z| format!("{z:.2}")).unwrap_or_default(),
                if c.converged { "yes" } else { "NO" },
                c.seconds
            ));
        }
        md.push_str(&format!("\n## Consistency checks (consistent: means within {CONSISTENT_Z} combined sd)\n\n| check | parameter | from | to | z | width ratio | consistent | tighter |\n|---|---|---|---|---|---|---|---|\n"));
        for c in &self.consistency {
            md.push_str(&format!(
                "| {} | {} | {} | {} | {:.2} | {:.2} | {} | {} |\n",
                c.check,
                c.parameter,
                c.from,
                c.to,
                c.z,
                c.width_ratio,
                if c.consistent { "yes" } else { "NO" },
                c.tighter.map(|t| if t { "yes" } else { "NO" }).unwrap_or("")
            ));
        }
        if !self.emulator_vs_data.is_empty() {
            md.push_str("\n## Emulator against the data's precision\n\nHeld-out RMSE per bin over the mock data's error in that bin, then the same with the validation runs' own statistical noise removed. Where a ratio exceeds 1 the emulator is less precise than the data there; its predictive variance (including the discarded principal components) is part of the likelihood in every case.\n\n| observable | median ratio | max ratio | bins above the error | median ratio, run noise removed | bins above, run noise removed |\n|---|---|---|---|---|---|\n");
            for e in &self.emulator_vs_data {
                md.push_str(&format!(
                    "| {} | {:.2} | {:.2} | {} of {} | {:.2} | {} of {} |\n",
                    e.observable,
                    e.median_ratio,
                    e.max_ratio,
                    e.bins_above_error,
                    e.bins,
                    e.median_ratio_noise_removed,
                    e.bins_above_error_noise_removed,
                    e.bins
                ));
            }
        }
        if !self.eta_s_coverage.is_empty() {
            md.push_str("\n## η/s(T): where the 95% band covers the true curve (T grid 0.10–0.35 GeV)\n\n| case | fraction covered | missed at T (GeV) |\n|---|---|---|\n");
            for e in &self.eta_s_coverage {
                let missed: Vec<String> = e.missed.iter().map(|r| format!("{:.3}–{:.3}", r[0], r[1])).collect();
                md.push_str(&format!(
                    "| {} | {:.2} | {} |\n",
                    e.case,
                    e.fraction_covered,
                    if missed.is_empty() { "nowhere".to_string() } else { missed.join(", ") }
                ));
            }
        }
        md
    }

    /// The Markdown tables as HTML, for the report.
    pub fn html(&self) -> String {
        let mut html = String::new();
        let mut in_table = false;
        for line in self.markdown().lines() {
            let esc = crate::engine::report::html_escape(line);
            if let Some(cells) = line.strip_prefix('|') {
                if line.starts_with("|---") {
                    continue;
                }
                if !in_table {
                    html.push_str("<table>\n");
                    in_table = true;
                }
                let tds: Vec<String> = cells
                    .trim_end_matches('|')
                    .split('|')
                    .map(|c| format!("<td>{}</td>", crate::engine::report::html_escape(c.trim())))
                    .collect();
                html.push_str(&format!("<tr>{}</tr>\n", tds.join("")));
                continue;
            }
            if in_table {
                html.push_str("</table>\n");
                in_table = false;
            }
            if let Some(h) = line.strip_prefix("## ") {
                html.push_str(&format!("<h3>{}</h3>\n", crate::engine::report::html_escape(h)));
            } else if let Some(h) = line.strip_prefix("# ") {
                html.push_str(&format!("<h2>{}</h2>\n", crate::engine::report::html_escape(h)));
            } else if !line.is_empty() {
                html.push_str(&format!("<p>{esc}</p>\n"));
            }
        }
        if in_table {
            html.push_str("</table>\n");
        }
        html
    }
}
