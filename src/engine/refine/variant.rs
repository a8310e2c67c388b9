//! Refining a diagnose candidate's variant emulator, so that a verdict rests
//! on the data and not on a coarse emulator (`diagnose`'s "emulator_limited").
//!
//! A round: calibrate the variant without MD on the diagnosis' data (as a
//! scout, `SamplerConfig::scout`: a round needs where the posterior lies,
//! and the fit diagnose reports is its own), measure
//! its emulator's error over the data error at the posterior draws
//! (`ratios`), stop when the latent ratio is below 1 in every observable
//! and the emulator's share of the fit's predictive variance is at most one
//! half (the rule `diagnose` names a candidate by: a latent sd below the
//! data error can still leave a predictive floor, the dropped components'
//! run noise, that keeps the verdict "emulator_limited"),
//! else choose `points_per_round` runs among the draws (`select`), run them
//! with the variant's physics (a `PointRunner`, which the system that owns
//! the simulator gives), and retrain on every run so far with the settings
//! the emulator was trained with. The variant's own posterior decides where
//! runs go: that is where its evidence is earned.
//!
//! Writes `OUT/round_<r>/pilot/` (the variant's calibration),
//! `OUT/round_<r>/emulator/` (retrained) and `OUT/rounds.json`.

use super::{ratios, read_draws, select, targets, ObservableRatio};
use crate::base::artifacts::{self, Measurement};
use crate::base::progress::Observer;
use crate::engine::calibrate::{self, Analysis, Overrides, Problem};
use crate::engine::emulator::{store, train, EmulatedModel, TrainingTable};
use crate::engine::model::CandidateModel;
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Runs the simulator, with a variant's physics switched on, at new points.
pub trait PointRunner {
    /// The outputs at `points` (each in the order of `names`, the emulator's
    /// parameters) as a training table with design ids from `first_id`;
    /// `dir` is the round's folder, for whatever the runs leave behind.
    fn run(&self, names: &[String], points: &[Vec<f64>], first_id: i64, dir: &Path) -> Result<TrainingTable>;
}

/// How much refinement may do.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RoundSettings {
    /// New runs per round.
    pub points_per_round: usize,
    /// The most new runs in all rounds together.
    pub budget: usize,
    /// Posterior draws weighed per round.
    pub draws: usize,
}

/// One round as reported.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct VariantRound {
    pub round: usize,
    pub training_runs: usize,
    pub ratios: Vec<ObservableRatio>,
    /// The variant's posterior this round: parameter → [median, q025, q975].
    pub parameters: BTreeMap<String, [f64; 3]>,
    /// The emulator's share of the fit's predictive variance at the data.
    pub emulator_share: f64,
    pub new_runs: usize,
}

/// What refinement did to one variant emulator.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RefinedVariant {
    pub candidate: String,
    pub rounds: Vec<VariantRound>,
    /// "below the data error" or "budget spent (…)".
    pub stopped: String,
    /// The last emulator (the one to declare).
    pub emulator: PathBuf,
    pub provenance: artifacts::Provenance,
}

/// Refines `candidate`'s variant emulator (stored in `emulator_dir`) against
/// the data of `analysis` (as `overrides` select it), writing under `out`.
#[allow(clippy::too_many_arguments)]
pub fn refine_variant(
    analysis: &Analysis,
    overrides: &Overrides,
    candidate: &CandidateModel,
    emulator_dir: &Path,
    runner: &dyn PointRunner,
    settings: &RoundSettings,
    out: &Path,
    seed: u64,
    observer: &dyn Observer,
) -> Result<RefinedVariant> {
    if settings.points_per_round == 0 || settings.draws < 10 {
        bail!("refining {}: points_per_round must be at least 1 and draws at least 10", candidate.name);
    }
    let train_settings = store::load_settings(emulator_dir)?;
    let mut dir = emulator_dir.to_path_buf();
    let mut rounds = Vec::new();
    let mut spent = 0;
    let mut provenance = None;
    let stopped = loop {
        let r = rounds.len();
        let round_dir = out.join(format!("round_{r}"));
        let model = Arc::new(EmulatedModel::load(&dir).with_context(|| format!("refining {}", candidate.name))?);
        let variant = CandidateModel { simulator: model.clone(), ..candidate.clone() };
        let mut pilot = analysis.with_candidate(&variant);
        if let Some(sampler) = pilot.sampler.scout() {
            pilot.sampler = sampler;
        }
        let problem =
            Problem::new(&pilot, &Overrides { kernel: Some(crate::base::choices::Kernel::None), ..overrides.clone() })?;
        let round_seed = seed.wrapping_add(r as u64);
        let cal = calibrate::run(&problem, round_seed, observer)?;
        calibrate::write_outputs(&round_dir.join("pilot"), &problem, &cal)?;
        provenance.get_or_insert_with(|| problem.provenance(seed, &format!("refine variant {}", candidate.name)));
        let emu = &model.emulator;
        let names = emu.parts.parameter_names.clone();
        let draws = read_draws(&round_dir.join("pilot"), &names, settings.draws, round_seed)?;
        let targets = targets(emu, &data_points(&problem))?;
        let mut round = VariantRound {
            round: r,
            training_runs: emu.parts.design_ids.len(),
            ratios: ratios(emu, &draws, &targets),
            parameters: cal.summary.parameters.iter().map(|(n, p)| (n.clone(), [p.median, p.q025, p.q975])).collect(),
            emulator_share: cal.summary.fit.model_variance_share,
            new_runs: 0,
        };
        let worst = round.ratios.iter().map(|o| o.latent).fold(0.0, f64::max);
        crate::base::messages::say!(
            "  {} round {r} ({} runs): worst latent sd / data error {worst:.2}, emulator share {:.0}%",
            candidate.name,
            round.training_runs,
            100.0 * round.emulator_share
        );
        let k = settings.points_per_round.min(settings.budget.saturating_sub(spent));
        let done = worst < 1.0 && !cal.summary.fit.emulator_dominates();
        if done || k == 0 {
            let share = 100.0 * round.emulator_share;
            rounds.push(round);
            break if done {
                "below the data error".to_string()
            } else {
                format!("budget spent ({} new runs), latent ratio {worst:.2} in the worst observable and emulator share {share:.0}%", settings.budget)
            };
        }
        let chosen = select(emu, &draws, &targets, k).points;
        let first_id = emu.parts.design_ids.iter().max().map_or(0, |m| m + 1);
        let mut table = emu.training_table();
        table.append(&runner.run(&names, &chosen, first_id, &round_dir)?)?;
        let (retrained, report) = train(&table, &train_settings, round_seed)
            .with_context(|| format!("retraining the variant emulator of {}", candidate.name))?;
        dir = round_dir.join("emulator");
        store::save(
            &dir,
            &retrained,
            &train_settings,
            &report,
            &problem.provenance(round_seed, &format!("refine variant {} (round {r})", candidate.name)),
        )?;
        round.new_runs = chosen.len();
        spent += chosen.len();
        rounds.push(round);
    };
    let refined = RefinedVariant {
        candidate: candidate.name.clone(),
        rounds,
        stopped,
        emulator: dir,
        provenance: provenance.expect("at least one round ran"),
    };
    artifacts::write_json_atomic(&out.join("rounds.json"), &refined)?;
    Ok(refined)
}

/// The likelihood's data points as measurements (value unused by refinement).
fn data_points(problem: &Problem) -> Vec<Measurement> {
    problem
        .likelihood
        .blocks
        .iter()
        .flat_map(|b| b.x.iter().zip(&b.error).map(|(&x, &e)| Measurement::new(&b.name, x, f64::NAN, e)))
        .collect()
}
