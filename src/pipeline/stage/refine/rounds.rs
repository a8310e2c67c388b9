//! The refine stage's rounds: rounds of
//! adaptive design until the emulator's error where the posterior lives is
//! below the data error, or the run budget is spent.
//!
//! A round: calibrate pilots (the largest observable set, without MD and
//! with the last MD kernel: the emulator must be good wherever either fit
//! puts its mass) as scouts (`SamplerConfig::scout`: where the posterior
//! lies is all a round needs; the reported calibrations are the calibrate
//! stage's, in full), pool their draws, measure the emulator's error there
//! (`engine::refine::ratios`), stop if every observable's predictive ratio
//! is below 1, else choose `points_per_round` runs (`engine::refine::select`),
//! write them as a design (parameter files and a SLURM array script, like the
//! design stage's), run them with the simulate stage's simulator and
//! executor, ingest, and retrain on every run so far.
//!
//! Writes `OUT/refine/round_<r>/` (pilots, design with runs, tables,
//! emulator) and `OUT/refine/rounds.json` / `rounds.md`; `rounds.json` names
//! the emulator the calibrations use.

use super::report::{refine_dir, Round, Rounds};
use crate::base::artifacts::{self, Provenance};
use crate::base::progress::observer;
use crate::engine::calibrate::{self, Overrides, Problem};
use crate::engine::design::DesignSpec;
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::refine::{self, ObservableRatio};
use crate::pipeline::points;
use crate::pipeline::study::{absolute, Study};
use anyhow::{anyhow, Context, Result};
use polars::prelude::*;
use std::path::{Path, PathBuf};

/// The rounds of refinement, until the emulator is good enough where the posterior lives or the budget is spent.
pub(super) fn refine_rounds(study: &Study<'_>) -> Result<()> {
    let settings = study
        .run
        .refine
        .clone()
        .ok_or_else(|| anyhow!("{}: the refine stage needs a [run.refine] table", study.config.path.display()))?;
    let dir = refine_dir(study);
    crate::engine::execute::attempt::remove_after_attempts(&dir)
        .with_context(|| format!("removing the previous refinement {}", dir.display()))?;
    let mut emulator_dir = study.paths.emulator();
    let mut tables = vec![study.paths.training()];
    let mut rounds: Vec<Round> = Vec::new();
    let mut spent = 0;
    // New ids follow the training design's (whose failed points keep theirs).
    let base_ids: Vec<i64> = crate::engine::design::read_points(&study.paths.design().join("design.parquet"))?
        .into_iter()
        .map(|(id, _)| id)
        .collect();
    let mut next_id = crate::engine::design::span_of(&base_ids) as i64;
    let stopped = loop {
        let r = rounds.len();
        let round_dir = dir.join(format!("round_{r}"));
        let emu = crate::engine::emulator::store::load(&emulator_dir)?;
        let (draws, pilots) =
            pilot_draws(study, &emulator_dir, &round_dir, &emu.parts.parameter_names, settings.draws, r)?;
        let targets = refine::targets(&emu, &pilot_data(study)?)?;
        let ratios = refine::ratios(&emu, &draws, &targets);
        let training_runs = emu.parts.design_ids.len();
        print_round(r, training_runs, &ratios);
        let verdict = stop_reason(&ratios);
        let worst = ratios.iter().map(|o| o.predictive).fold(0.0, f64::max);
        let mut round = Round {
            round: r,
            training_runs,
            emulator: relative(&emulator_dir, &dir),
            ratios,
            pilots,
            new_runs: 0,
            forecast_worst_latent: None,
        };
        if let Some(reason) = verdict {
            rounds.push(round);
            break reason;
        }
        let k = settings.points_per_round.min(settings.budget.saturating_sub(spent));
        if k == 0 {
            rounds.push(round);
            break format!(
                "budget spent ({} new runs), predictive ratio still {worst:.2} in the worst observable",
                settings.budget
            );
        }
        let sel = refine::select(&emu, &draws, &targets, k);
        round.new_runs = sel.points.len();
        round.forecast_worst_latent = Some(sel.forecast.iter().map(|o| o.latent).fold(0.0, f64::max));
        let ids: Vec<i64> = (next_id..next_id + sel.points.len() as i64).collect();
        next_id += ids.len() as i64;
        let table = run_new_points(study, &round_dir, &ids, &sel.points, &emu.parts.parameter_names)?;
        tables.push(table);
        spent += sel.points.len();
        rounds.push(round);
        emulator_dir = retrain(study, &round_dir, &tables, r)?;
    };
    let prov = Provenance::new(
        study.config.hash.clone(),
        String::new(),
        study.opts.seed,
        &format!("run {} --stage refine", study.config.path.display()),
    );
    let result = Rounds { rounds, stopped, emulator: relative(&emulator_dir, &dir), provenance: prov };
    let mut staged = artifacts::StagedWrites::new();
    staged.json(&dir.join("rounds.json"), &result)?;
    staged.text(&dir.join("rounds.md"), &result.markdown())?;
    staged.commit()?;
    crate::base::messages::say!(
        "  stopped: {}; the calibrations use {}",
        result.stopped,
        dir.join(&result.emulator).display()
    );
    Ok(())
}

/// The measurements of the largest observable set.
fn pilot_data(study: &Study<'_>) -> Result<Vec<artifacts::Measurement>> {
    let config = study.study_config_with(&study.paths.emulator());
    let set = study.diagnose_observables();
    let data = artifacts::read_measurements(&config.resolve(&config.data.measurements))?;
    Ok(data.into_iter().filter(|m| set.contains(&m.observable)).collect())
}

/// Calibrates the pilots, as scouts, with this round's emulator; their
/// pooled draws (half from each) and their parameter summaries.
fn pilot_draws(
    study: &Study<'_>,
    emulator: &Path,
    round_dir: &Path,
    parameters: &[String],
    max: usize,
    round: usize,
) -> Result<(Vec<f64>, std::collections::BTreeMap<String, std::collections::BTreeMap<String, [f64; 3]>>)> {
    let config = study.study_config_with(emulator);
    let mut analysis = study.analysis(&config)?;
    if let Some(sampler) = analysis.sampler.scout() {
        analysis.sampler = sampler;
    }
    let md_kernel = study.run.kernels.iter().rev().find_map(|k| DiscrepancyKernel::of(*k));
    let mut kernels = vec![None];
    kernels.extend(md_kernel.map(Some));
    let mut draws = Vec::new();
    let mut pilots = std::collections::BTreeMap::new();
    for (i, kernel) in kernels.iter().enumerate() {
        let name = crate::engine::compare::case_dir_name(&study.diagnose_observables(), *kernel);
        let out = round_dir.join("pilots").join(&name);
        let problem = Problem::new(
            &analysis,
            &Overrides {
                kernel: Some(DiscrepancyKernel::choice(*kernel)),
                observables: Some(study.diagnose_observables()),
                ..Default::default()
            },
        )?;
        let seed = study.opts.seed.wrapping_add(5_000 + 10 * round as u64 + i as u64);
        let checkpoint = calibrate::sampler::checkpoint::Checkpointing::new(
            &out.join(".checkpoint"),
            calibrate::checkpoint_key(&problem, seed),
            None,
        );
        let cal = calibrate::run_and_write(&problem, seed, observer(study.opts.show_progress), &checkpoint, &out)?;
        let summary = &cal.summary.parameters;
        pilots.insert(
            name.clone(),
            parameters.iter().filter_map(|p| summary.get(p).map(|s| (p.clone(), [s.median, s.q025, s.q975]))).collect(),
        );
        draws.extend(refine::read_draws(&out, parameters, max / kernels.len(), seed)?);
    }
    Ok((draws, pilots))
}

/// Writes the chosen points as a design and runs them as the simulate
/// stage would; returns their ingested table.
fn run_new_points(
    study: &Study<'_>,
    round_dir: &Path,
    ids: &[i64],
    points: &[Vec<f64>],
    names: &[String],
) -> Result<PathBuf> {
    let design_dir = round_dir.join("design");
    let spec_path = study.config.resolve(&study.run.design);
    let simulator = study.simulator(false)?;
    let label = format!("refinement design {}", round_dir.file_name().unwrap_or_default().to_string_lossy());
    let prov = Provenance::new(
        artifacts::sha256_hex(&std::fs::read(&spec_path)?),
        String::new(),
        study.opts.seed,
        &format!("run {} --stage refine", study.config.path.display()),
    );
    let spec = DesignSpec::load(&spec_path)?;
    let chosen =
        points::ChosenPoints { spec: &spec, simulator: &simulator, label: &label, ids, points, names, prov: &prov };
    let table = round_dir.join("training.parquet");
    points::run_chosen_points(study, &chosen, &design_dir, &table)?;
    Ok(table)
}

/// Trains on every table so far; validates on the held-out design.
fn retrain(study: &Study<'_>, round_dir: &Path, tables: &[PathBuf], round: usize) -> Result<PathBuf> {
    let all = round_dir.join("training_all.parquet");
    concat_tables(tables, &all)?;
    let settings = study
        .emulator
        .clone()
        .ok_or_else(|| anyhow!("{}: refinement needs an [emulator] table", study.config.path.display()))?;
    let out = round_dir.join("emulator");
    let seed = study.opts.seed.wrapping_add(round as u64 + 1);
    let command = format!("run {} --stage refine (round {round})", study.config.path.display());
    let (_, r) =
        crate::engine::emulator::train_with_settings(&settings, &study.config.hash, &command, &all, None, &out, seed)?;
    crate::base::messages::say!(
        "  retrained: {} points x {} outputs -> {} components",
        r.n_points,
        r.n_outputs,
        r.n_components
    );
    let v = crate::engine::emulator::validate::run(&out, Some(&study.paths.validation()), 5, seed)?;
    if let Some(h) = &v.holdout {
        crate::engine::emulator::validate::print("  held-out design", h);
    }
    Ok(out)
}

fn print_round(r: usize, runs: usize, ratios: &[ObservableRatio]) {
    let parts: Vec<String> = ratios
        .iter()
        .map(|o| format!("{} {:.2} (latent {:.2}, floor {:.2})", o.observable, o.predictive, o.latent, o.floor))
        .collect();
    crate::base::messages::say!(
        "  round {r} ({runs} training runs): emulator predictive sd / data error: {}",
        parts.join(", ")
    );
}

/// Why refinement stops at these ratios, if it does: the predictive sd is
/// below the data error in every observable. (Not on the floor: its white
/// noise is fitted, and on more runs a GP can follow structure it had
/// to call noise. With 100 runs of 1000 events the bundled study read a
/// floor of 1.65 in the CH spectra.)
fn stop_reason(ratios: &[ObservableRatio]) -> Option<String> {
    ratios.iter().all(|o| o.predictive < 1.0).then(|| "below the data error".to_string())
}

fn relative(path: &Path, base: &Path) -> String {
    let abs = absolute(path);
    match abs.strip_prefix(absolute(base)) {
        Ok(rel) => rel.display().to_string(),
        Err(_) => abs.display().to_string(),
    }
}

/// Stacks ingested training tables (same schema) into one.
fn concat_tables(tables: &[PathBuf], out: &Path) -> Result<()> {
    let mut all: Option<DataFrame> = None;
    let mut points = Vec::new();
    for t in tables {
        let df = artifacts::read_parquet(t)?;
        points.push(
            df.column("design_id").map_err(|_| anyhow!("{}: missing column 'design_id'", t.display()))?.n_unique()?,
        );
        all = Some(match all {
            None => df,
            Some(mut a) => {
                a.vstack_mut(&df)
                    .map_err(|e| anyhow!("{}: its columns differ from the other training tables': {e}", t.display()))?;
                a
            }
        });
    }
    let mut all = all.ok_or_else(|| anyhow!("no training tables"))?;
    pool_noise_correlations(tables, &points, out)?;
    artifacts::write_parquet_atomic(out, &mut all, None)
}

/// The tables' run-error correlations (`TABLE.noise_correlation.csv`),
/// averaged pair by pair with each table's number of design points as its
/// weight, beside `out`; nothing when no table has one.
fn pool_noise_correlations(tables: &[PathBuf], points: &[usize], out: &Path) -> Result<()> {
    use crate::base::covariance::{
        noise_correlation_csv, noise_correlation_path, read_noise_correlation, CovarianceEntry,
    };
    let mut sums: std::collections::BTreeMap<(String, u64, String, u64), (f64, f64)> =
        std::collections::BTreeMap::new();
    for (t, &n) in tables.iter().zip(points) {
        let side = noise_correlation_path(t);
        if !side.exists() {
            continue;
        }
        for e in read_noise_correlation(&side)? {
            let s =
                sums.entry((e.observable_a, e.x_a.to_bits(), e.observable_b, e.x_b.to_bits())).or_insert((0.0, 0.0));
            s.0 += n as f64 * e.covariance;
            s.1 += n as f64;
        }
    }
    if sums.is_empty() {
        return Ok(());
    }
    let entries: Vec<CovarianceEntry> = sums
        .into_iter()
        .map(|((oa, xa, ob, xb), (sum, weight))| CovarianceEntry {
            observable_a: oa,
            x_a: f64::from_bits(xa),
            observable_b: ob,
            x_b: f64::from_bits(xb),
            covariance: sum / weight,
            line: 0,
            rounding: 0.0,
        })
        .collect();
    artifacts::write_text_atomic(&noise_correlation_path(out), &noise_correlation_csv(&entries))
}

#[cfg(test)]
mod tests {
    use super::{stop_reason, ObservableRatio};
    use crate::engine::emulator::{read_training_table, OutputKey, TrainingTable};

    /// A round's training table joins every table so far, and the runs'
    /// error correlation with it, weighted by each table's number of points
    /// (one point with correlation 0.2 and three with 0.6 pool to 0.5).
    #[test]
    fn joined_tables_pool_their_noise_correlation_by_points() {
        let dir = std::env::temp_dir().join(format!("mdpipe-concat-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let table = |ids: Vec<i64>, rho: f64| TrainingTable {
            path: "t".into(),
            parameter_names: vec!["a".into()],
            inputs: ids.iter().map(|&i| i as f64).collect(),
            outputs: vec![OutputKey { observable: "y".into(), x: 0.1 }, OutputKey { observable: "y".into(), x: 0.3 }],
            values: ids.iter().flat_map(|&i| [i as f64, 2.0 * i as f64]).collect(),
            errors: vec![0.1; 2 * ids.len()],
            noise_correlation: Some(vec![1.0, rho, rho, 1.0]),
            design_ids: ids,
        };
        let (first, second, all) = (dir.join("a.parquet"), dir.join("b.parquet"), dir.join("all.parquet"));
        table(vec![1], 0.2).write(&first, None).unwrap();
        table(vec![2, 3, 4], 0.6).write(&second, None).unwrap();
        super::concat_tables(&[first, second], &all).unwrap();
        let joined = read_training_table(&all, &["a".to_string()]).unwrap();
        assert_eq!(joined.design_ids, vec![1, 2, 3, 4]);
        let r = joined.noise_correlation.expect("the pooled correlation");
        assert!((r[1] - 0.5).abs() < 1e-12 && r[1] == r[2], "{r:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn ratio(observable: &str, latent: f64, floor: f64, predictive: f64) -> ObservableRatio {
        ObservableRatio { observable: observable.into(), latent, latent_max_bin: latent, predictive, floor }
    }

    /// Refinement stops on the predictive ratio, not the latent one, and not
    /// on a high floor (the budget ends it).
    #[test]
    fn refinement_stops_on_the_predictive_sd() {
        assert_eq!(
            stop_reason(&[ratio("a", 0.5, 0.3, 0.9), ratio("b", 0.2, 0.1, 0.4)]).as_deref(),
            Some("below the data error")
        );
        // Latent below 1 but predictive above, with a floor below 1: go on.
        assert_eq!(stop_reason(&[ratio("a", 0.8, 0.5, 1.6), ratio("b", 0.2, 0.1, 0.4)]), None);
        assert_eq!(stop_reason(&[ratio("a", 0.8, 1.2, 1.6), ratio("b", 0.2, 1.05, 1.4)]), None);
    }
}
