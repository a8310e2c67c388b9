//! Trust, then verify: the diagnosis's final emulated fit run through the
//! real simulator. The fit the verdict ends on (the named candidate's with
//! MD on top, `repaired_md`; the model's with MD, `base_md`, when nothing is
//! named) is an emulator's: its posterior median and a few of its draws are
//! run through the simulator by the study's executor, as any design is, and
//! the simulator's χ² against the data is reported beside the emulator
//! mean's at the same θ (`diagnose/verify.json`). A fit the simulator
//! contradicts is flagged, and parameters piled at the design box's edge
//! are reported with the advice to widen it.
//!
//! The simulator's χ² counts each run's own statistical error with the
//! data's (σ² = σ_data² + σ_run²); the emulator mean's, the data's alone.
//! Both are diagonal: a data covariance between points is not used here,
//! so the check compares the two at the same θ, not either with the
//! likelihood's own χ².
//! The fit is contradicted when, at the median, the simulator's χ² exceeds
//! the emulator's by more than three standard deviations of a χ² over
//! those points, 3 √(2n).

use crate::base::artifacts::{self, Measurement, Provenance};
use crate::engine::design::DesignSpec;
use crate::engine::diagnose::Diagnosis;
use crate::engine::execute::SimulatorSpec;
use crate::engine::model::Simulator;
use crate::pipeline::points::{self, ChosenPoints};
use crate::pipeline::study::Study;
use crate::pipeline::variants::Variant;
use anyhow::{anyhow, Context, Result};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

/// The outcome when `[run] verify = false`.
const SWITCHED_OFF: &str = "not run: [run] verify = false";

/// Draws run beside the posterior median.
const DRAWS: usize = 4;

/// One θ run through the simulator.
#[derive(Clone, Debug, serde::Serialize)]
pub(super) struct CheckedPoint {
    /// "posterior median" or "draw k" (a row of the fit's posterior).
    pub label: String,
    pub theta: BTreeMap<String, f64>,
    pub chi2_simulator: f64,
    pub chi2_emulator: f64,
    /// Data points compared (those at which the run has an output).
    pub points: usize,
}

/// `diagnose/verify.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub(super) struct Verification {
    /// The fit checked (`repaired_md` or `base_md`) and its model.
    pub fit: String,
    pub model: String,
    /// Whether the simulator could be run: not for a correction of the emulated output.
    pub checked: bool,
    pub points: Vec<CheckedPoint>,
    /// "consistent", "contradicted by the simulator" or why nothing was run.
    pub outcome: String,
    /// The simulator's parameters whose posterior piles at a bound of the design box.
    pub piled_at_bounds: Vec<String>,
    pub advice: Vec<String>,
    pub provenance: Provenance,
}

/// What is run: the model's emulator for the fit, and the simulator it stands for.
struct Checked {
    fit: &'static str,
    model: String,
    emulator: Arc<dyn Simulator>,
    simulator: SimulatorSpec,
    spec: DesignSpec,
}

/// Runs the check and writes `diagnose/verify.json`.
pub(super) fn against_simulator(
    study: &Study<'_>,
    analysis: &crate::engine::calibrate::Analysis,
    diagnosis: &Diagnosis,
) -> Result<()> {
    let out = study.paths.diagnose();
    let wanted = if study.run.verify { what_to_check(study, analysis, diagnosis)? } else { Err(SWITCHED_OFF.into()) };
    let report = match wanted {
        Err(why) => unchecked(study, diagnosis, why)?,
        // The diagnosis stands without its check: a simulator that fails
        // at every point is reported, not a reason to redo the diagnosis.
        Ok(checked) => match check(study, &checked, &out) {
            Ok(report) => report,
            Err(e) => unchecked(study, diagnosis, format!("not checked: {e:#}"))?,
        },
    };
    crate::base::messages::say!("  checked against the simulator: {}", report.outcome);
    for advice in &report.advice {
        crate::base::messages::say!("  {advice}");
    }
    artifacts::write_json_atomic(&out.join("verify.json"), &report)
}

/// The fit and model to check, or why there is none.
fn what_to_check(
    study: &Study<'_>,
    analysis: &crate::engine::calibrate::Analysis,
    diagnosis: &Diagnosis,
) -> Result<Result<Checked, String>> {
    let base_spec = DesignSpec::load(&study.config.resolve(&study.run.design))?;
    if diagnosis.improvement.is_none() {
        return Ok(Ok(Checked {
            fit: "base_md",
            model: "the model".into(),
            emulator: analysis.simulator.clone(),
            simulator: study.simulator(false)?,
            spec: base_spec,
        }));
    }
    let Some(name) = diagnosis.verdict.named().map(String::from) else {
        return Ok(Err(format!("not run: the verdict ({}) names no candidate", diagnosis.verdict.best)));
    };
    let name = &name;
    let variants: Vec<Variant> = crate::pipeline::stage::candidates::variants(study)?;
    let Some(variant) = variants.into_iter().find(|v| &v.name == name) else {
        return Ok(Err(format!(
            "not run: {name} is not one variant of the simulator (a correction of the emulated output, or a combination of candidates), which no simulator run includes"
        )));
    };
    let candidate = analysis
        .candidates()?
        .into_iter()
        .find(|c| &c.name == name)
        .ok_or_else(|| anyhow!("the verdict names {name}, which the analysis does not declare"))?;
    Ok(Ok(Checked {
        fit: "repaired_md",
        model: format!("the model with {name}"),
        emulator: candidate.simulator,
        spec: variant.design_spec(&base_spec),
        simulator: variant.simulator,
    }))
}

fn unchecked(study: &Study<'_>, diagnosis: &Diagnosis, why: String) -> Result<Verification> {
    Ok(Verification {
        fit: "repaired_md".into(),
        model: diagnosis.verdict.best.clone(),
        checked: false,
        points: Vec::new(),
        outcome: why,
        piled_at_bounds: Vec::new(),
        advice: Vec::new(),
        provenance: provenance(study)?,
    })
}

fn provenance(study: &Study<'_>) -> Result<Provenance> {
    Ok(Provenance::new(study.config.hash.clone(), study.data_hash()?, study.opts.seed, "run --stage diagnose (verify)"))
}

fn check(study: &Study<'_>, c: &Checked, out: &Path) -> Result<Verification> {
    let fit = out.join(c.fit);
    let names = c.emulator.parameter_names();
    let (labels, thetas) = posterior_points(&fit.join("posterior.parquet"), &names)?;
    let dir = out.join("verify");
    // Runs of an earlier diagnosis are at other θ under the same ids: a
    // point's run is kept when its folder holds one, so they must go.
    if dir.exists() {
        crate::engine::execute::attempt::remove_after_attempts(&dir)
            .with_context(|| format!("removing the previous check {}", dir.display()))?;
    }
    let ids: Vec<i64> = (0..thetas.len() as i64).collect();
    let prov = provenance(study)?;
    let chosen = ChosenPoints {
        spec: &c.spec,
        simulator: &c.simulator,
        label: "verify",
        ids: &ids,
        points: &thetas,
        names: &names,
        prov: &prov,
    };
    points::run_chosen_points(study, &chosen, &dir.join("design"), &dir.join("runs.parquet"))?;
    let data = artifacts::read_measurements(&fit.join("measurements.parquet"))?;
    let runs = read_runs(&dir.join("runs.parquet"))?;
    let observables = c.emulator.observable_names();
    let mut checked = Vec::new();
    for (k, (label, theta)) in labels.into_iter().zip(&thetas).enumerate() {
        let Some(run) = runs.get(&(k as i64)) else { continue };
        let (chi2_simulator, n) = chi2_of_run(&data, run);
        let chi2_emulator = chi2_of_emulator(&data, c.emulator.as_ref(), &observables, theta);
        let theta = names.iter().cloned().zip(theta.iter().copied()).collect();
        checked.push(CheckedPoint { label, theta, chi2_simulator, chi2_emulator, points: n });
    }
    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(fit.join("summary.json"))?)?;
    // Only the simulator's parameters have a design box; a discrepancy
    // amplitude piled at 0 is δ found negligible.
    let piled: Vec<String> = summary["piled_at_bounds"]
        .as_array()
        .map(|a| a.iter().filter_map(|p| p["parameter"].as_str().map(String::from)).collect::<Vec<_>>())
        .unwrap_or_default()
        .into_iter()
        .filter(|p| names.contains(p))
        .collect();
    Ok(Verification {
        fit: c.fit.into(),
        model: c.model.clone(),
        checked: true,
        outcome: outcome(&checked),
        advice: advice(&checked, &piled),
        piled_at_bounds: piled,
        points: checked,
        provenance: prov,
    })
}

/// The posterior median (each parameter's) and `DRAWS` rows spread over the posterior.
fn posterior_points(path: &Path, names: &[String]) -> Result<(Vec<String>, Vec<Vec<f64>>)> {
    let df = artifacts::read_parquet(path)?;
    let columns: Vec<Vec<f64>> = names
        .iter()
        .map(|n| crate::base::columns::f64_column(&df, path, n))
        .collect::<Result<_>>()
        .with_context(|| format!("{}: the fit's parameters", path.display()))?;
    let rows = df.height();
    if rows == 0 {
        return Err(anyhow!("{}: an empty posterior", path.display()));
    }
    let median = columns.iter().map(|c| median_of(c)).collect();
    let (mut labels, mut thetas) = (vec!["posterior median".to_string()], vec![median]);
    for k in 0..DRAWS.min(rows) {
        let row = (2 * k + 1) * rows / (2 * DRAWS);
        labels.push(format!("draw {}", k + 1));
        thetas.push(columns.iter().map(|c| c[row]).collect());
    }
    Ok((labels, thetas))
}

fn median_of(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    if n % 2 == 1 {
        sorted[n / 2]
    } else {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    }
}

/// A run's outputs by (observable, x): value and its own error, per design point.
type Run = Vec<(String, f64, f64, f64)>;

fn read_runs(path: &Path) -> Result<BTreeMap<i64, Run>> {
    let df = artifacts::read_parquet(path)?;
    let col = |n: &str| crate::base::columns::f64_column(&df, path, n);
    let (ids, x, value, error) = (col("design_id")?, col("x")?, col("value")?, col("error")?);
    let observable = crate::base::columns::str_column(&df, path, "observable")?;
    let mut runs: BTreeMap<i64, Run> = BTreeMap::new();
    for i in 0..df.height() {
        runs.entry(ids[i] as i64).or_default().push((observable[i].clone(), x[i], value[i], error[i]));
    }
    Ok(runs)
}

fn same_x(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

/// χ² of one run against the data, over the data points the run has.
fn chi2_of_run(data: &[Measurement], run: &Run) -> (f64, usize) {
    let mut chi2 = 0.0;
    let mut n = 0;
    for m in data {
        if let Some((_, _, v, e)) = run.iter().find(|(o, x, ..)| *o == m.observable && same_x(*x, m.x)) {
            chi2 += (v - m.value).powi(2) / (m.error * m.error + e * e);
            n += 1;
        }
    }
    (chi2, n)
}

/// χ² of the emulator's mean at θ against the data.
fn chi2_of_emulator(data: &[Measurement], emulator: &dyn Simulator, observables: &[String], theta: &[f64]) -> f64 {
    let mut chi2 = 0.0;
    for (o, name) in observables.iter().enumerate() {
        let rows: Vec<&Measurement> = data.iter().filter(|m| &m.observable == name).collect();
        if rows.is_empty() {
            continue;
        }
        let x: Vec<f64> = rows.iter().map(|m| m.x).collect();
        let mut mean = vec![0.0; x.len()];
        emulator.predict(o, &x, theta, &mut mean);
        chi2 += rows.iter().zip(&mean).map(|(m, p)| ((p - m.value) / m.error).powi(2)).sum::<f64>();
    }
    chi2
}

fn outcome(points: &[CheckedPoint]) -> String {
    let Some(median) = points.first() else { return "no run of the simulator succeeded".into() };
    if median.points == 0 {
        return "not compared: the runs have no output at the data's x".into();
    }
    let n = median.points as f64;
    let (sim, emu) = (median.chi2_simulator / n, median.chi2_emulator / n);
    let verdict = if median.chi2_simulator > median.chi2_emulator + 3.0 * (2.0 * n).sqrt() {
        "contradicted by the simulator"
    } else {
        "consistent"
    };
    format!(
        "{verdict}: at the posterior median χ²/n {sim:.2} from the simulator, {emu:.2} from the emulator ({} points)",
        median.points
    )
}

fn advice(points: &[CheckedPoint], piled: &[String]) -> Vec<String> {
    let mut advice = Vec::new();
    if points.first().is_some_and(|m| m.chi2_simulator > m.chi2_emulator + 3.0 * (2.0 * m.points.max(1) as f64).sqrt())
    {
        advice.push(
            "the emulator is wrong where this fit lives: refine it there (`[run.refine]`) before trusting the fit"
                .into(),
        );
    }
    if !piled.is_empty() {
        advice.push(format!(
            "the posterior piles at the edge of the box in {}: widen the design's range there and run again",
            piled.join(", ")
        ));
    }
    advice
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at_median(chi2_simulator: f64, chi2_emulator: f64, points: usize) -> CheckedPoint {
        let label = "posterior median".into();
        CheckedPoint { label, theta: BTreeMap::new(), chi2_simulator, chi2_emulator, points }
    }

    /// Contradicted beyond 3 √(2n) above the emulator's χ², whatever the draws say.
    #[test]
    fn the_simulator_contradicts_the_fit_beyond_three_sd_of_its_chi2() {
        // n = 50: 3 √100 = 30.
        assert!(outcome(&[at_median(79.0, 50.0, 50)]).starts_with("consistent"));
        assert!(outcome(&[at_median(81.0, 50.0, 50)]).starts_with("contradicted"));
        assert!(advice(&[at_median(81.0, 50.0, 50)], &[])[0].contains("refine it there"));
        let piled = advice(&[at_median(50.0, 50.0, 50)], &["activity".into()]);
        assert_eq!(piled.len(), 1);
        assert!(piled[0].contains("edge of the box in activity"));
        assert_eq!(outcome(&[]), "no run of the simulator succeeded");
        assert!(outcome(&[at_median(0.0, 0.0, 0)]).starts_with("not compared"), "nothing compared is not consistent");
    }

    #[test]
    fn a_run_is_compared_at_the_data_it_has() {
        let data = vec![Measurement::new("rate", 0.25, 10.0, 1.0), Measurement::new("rate", 0.75, 8.0, 1.0)];
        // Only x = 0.25 in the run; its own error 1 doubles the variance there.
        let run = vec![("rate".to_string(), 0.25, 12.0, 1.0), ("other".to_string(), 0.75, 0.0, 1.0)];
        assert_eq!(chi2_of_run(&data, &run), (2.0, 1));
        assert_eq!(median_of(&[3.0, 1.0, 2.0, 10.0]), 2.5);
    }
}
