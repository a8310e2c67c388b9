//! `mdpipe diagnose`: locate a model-data mismatch, name the physics that was
//! left out, model it, and show the fit improve.
//!
//! 1. Locate: calibrate with and without MD; read δ(x) off the MD posterior.
//! 2. Explain: calibrate the model augmented by each candidate correction from
//!    the model's library and rank them by SMC log-evidence against the base.
//! 3. Repair: refit with the winner, with and without MD, and compare.
//!
//! Nested candidates: a candidate named `a+b` combines candidates `a` and `b`
//! (declared models offer every pair). By Occam's rule the best candidate
//! gives way to a candidate it contains unless it beats it by more than
//! `strong_log_bf`: a second effect must earn its place as decisively as the
//! first did against the base model.
//!
//! Decision rule (log Bayes factors, Kass & Raftery's "strong" = 3):
//! * a candidate is named when it beats the base model by more than
//!   `strong_log_bf`, fits adequately (χ² p-value ≥ `min_p_value` at its
//!   posterior median) and is not itself beaten by the MD fit by more than
//!   `strong_log_bf`;
//! * it is named alone only when it beats every other explanation (each
//!   candidate that neither contains it nor is contained in it, and fits
//!   adequately) decisively: by more than `strong_log_bf` plus twice the
//!   Monte Carlo error of the difference of log evidences. log BF 3 is
//!   posterior odds of 20:1 with equal prior odds (Kass & Raftery's
//!   "strong"), and the 2σ margin keeps sampler noise from making a verdict.
//!   Otherwise the verdict is "ambiguous": it names the candidates still
//!   standing and the measurement that would separate the first two
//!   (`suggest`);
//! * a named candidate whose fit rests on its emulator (the emulator's share
//!   of the predictive variance at the data above one half in some
//!   observable, see `FitQuality::model_variance_share`,
//!   `EMULATOR_DOMINATES`) is not named: the verdict is "emulator_limited".
//!   There the emulator's uncertainty, not the data, decides how well the
//!   variant fits, and a coarse variant emulator can win on its variance
//!   alone. The verdict lists the variant emulators to refine (the standing
//!   candidates whose share is above one half) and is decided again after
//!   refinement (`engine::refine::variant`). The same holds for a leader
//!   that beats the base model strongly but is not named (its χ² test fails
//!   or the MD fit beats it) while resting on its emulator: its χ² and
//!   evidence are then the emulator's, so it is refined, not rejected;
//! * otherwise the verdict is "unexplained" when the mismatch is significant
//!   (MD beats the base by more than `strong_log_bf`, or the base χ² has
//!   p < `min_p_value`), and "none" when it is not.

mod locate;
mod suggest;

use crate::base::artifacts::{self, Provenance};
use crate::base::progress::Observer;
use crate::engine::calibrate::summary::{ParamSummary, PredictionRow, Summary, EMULATOR_DOMINATES};
use crate::engine::calibrate::{self, Analysis, Calibration, Overrides, Problem};
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::CandidateModel;
use anyhow::Result;
use locate::{locate, mismatch_phrase};
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::BTreeMap;
use std::path::Path;
pub use suggest::Suggestion;

#[derive(Clone, Debug)]
pub struct DiagnoseSettings {
    pub kernel: DiscrepancyKernel,
    pub strong_log_bf: f64,
    pub min_p_value: f64,
    /// Refit the winner with MD on top (step 3); blind tests skip it.
    pub repair: bool,
}

impl Default for DiagnoseSettings {
    fn default() -> Self {
        DiagnoseSettings { kernel: DiscrepancyKernel::KernelII, strong_log_bf: 3.0, min_p_value: 1e-3, repair: true }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Region {
    pub x_from: f64,
    pub x_to: f64,
    /// "above": data above the model (δ > 0); "below": δ < 0.
    pub sign: String,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ObservableMismatch {
    pub observable: String,
    /// x ranges (within the data) where the 95% band of δ excludes zero.
    pub regions: Vec<Region>,
    /// Largest |posterior-mean δ| at a data point, in units of its 1σ error.
    pub max_sigma: f64,
    pub x_at_max: f64,
    /// "above", "below", "mixed" or "none".
    pub sign: String,
    /// Whether |δ| grows with x over the data.
    pub grows_with_x: bool,
    /// Posterior of the growth exponent r of the discrepancy kernel.
    pub r: ParamSummary,
    /// Posterior-predictive check of the no-MD fit: residuals (y − η̂)
    /// standardized by the whole predictive sd (measurement error, posterior
    /// spread of η and, for an emulator, its own uncertainty), and χ².
    pub no_md_residuals: Vec<(f64, f64)>,
    /// Runs of consecutive data points whose no-MD residual exceeds 2 in
    /// size with one sign (kept if two or more points, or one beyond 3): where
    /// the model alone misses. Where an emulator's uncertainty leaves the δ
    /// band wide (`regions` empty), this still locates the mismatch.
    #[serde(default)]
    pub residual_regions: Vec<Region>,
    pub no_md_chi2: f64,
    pub no_md_dof: usize,
    /// Posterior-mean δ/σ at each data point: one row of the mismatch map.
    pub map: Vec<(f64, f64)>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CandidateResult {
    pub name: String,
    pub description: String,
    pub log_evidence: f64,
    pub log_evidence_err: f64,
    /// Against the base model without MD.
    pub log_bayes_factor: f64,
    pub log_bayes_factor_err: f64,
    pub parameters: BTreeMap<String, ParamSummary>,
    pub chi2_per_dof: f64,
    pub p_value: f64,
    pub converged: bool,
    /// The model's (an emulator's) share of the fit's predictive variance at
    /// the data, in the observable where it is largest (`FitQuality`).
    #[serde(default)]
    pub emulator_share: f64,
    /// That observable ("" for an exact model).
    #[serde(default)]
    pub emulator_share_observable: String,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Verdict {
    /// A candidate name, "ambiguous", "emulator_limited", "none" or "unexplained".
    pub best: String,
    /// For "ambiguous": the candidates still standing, best evidence first.
    #[serde(default)]
    pub standing: Vec<String>,
    /// For "ambiguous": the measurement that would best separate the first two.
    #[serde(default)]
    pub suggestion: Option<Suggestion>,
    /// For "emulator_limited": the candidates whose variant emulators must be
    /// refined (more runs where their posteriors lie) before a verdict.
    #[serde(default)]
    pub refine: Vec<String>,
    pub statement: String,
    /// Posterior probability, with equal prior odds among the base, MD and
    /// candidate models: for a named candidate, of every model that contains
    /// it (the probability that the data need it); for `none`, of the base
    /// model; for `unexplained`, of the MD model; otherwise of the models
    /// still standing.
    pub confidence: f64,
}

impl Verdict {
    /// The verdict's probability in words: what it is the probability of.
    pub fn confidence_phrase(&self) -> String {
        let v = self;
        let p = v.confidence;
        let what = match v.best.as_str() {
            "none" => "that nothing is missing".to_string(),
            "unexplained" => "of the model-discrepancy fit".to_string(),
            "ambiguous" | "emulator_limited" => "of the models still standing".to_string(),
            name => format!("that the data need {name}, over every model that contains it"),
        };
        let shown = if p > 0.999 { "> 0.999".to_string() } else { format!("{p:.3}") };
        format!("posterior probability {shown} {what}")
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FitFigures {
    pub label: String,
    pub chi2_per_dof: f64,
    pub log_evidence: f64,
    pub log_evidence_err: f64,
    pub parameters: BTreeMap<String, ParamSummary>,
    /// Largest |posterior-mean δ|/σ per observable (0 without MD).
    pub delta_max_sigma: BTreeMap<String, f64>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Improvement {
    pub before: Vec<FitFigures>,
    pub after: Vec<FitFigures>,
    /// Width of the 95% interval of each model parameter, before (MD) / after (repaired).
    pub interval_narrowing: BTreeMap<String, f64>,
    /// The largest narrowing these data allow: the MD width over the repaired
    /// model's Cramér–Rao 95% width (2 × 1.96 × sd) at its posterior median.
    /// Empty for emulated models and for parameters the data cannot identify.
    #[serde(default)]
    pub information_limit: BTreeMap<String, f64>,
    /// The parameters' true values, when the config knows them (mock data).
    #[serde(default)]
    pub truth: BTreeMap<String, f64>,
}

impl Improvement {
    /// Whether the repaired fit's and the MD fit's 95% intervals of `name`
    /// cover its true value, when the config knows it: a narrower interval
    /// that misses the truth is no repair, a wider one that covers it may be.
    pub fn truth_coverage(&self, name: &str) -> String {
        let Some(&t) = self.truth.get(name) else { return String::new() };
        let covers =
            |f: Option<&FitFigures>| f.and_then(|f| f.parameters.get(name)).map(|p| p.q025 <= t && t <= p.q975);
        match (covers(self.after.first()), covers(self.before.get(1))) {
            (Some(true), Some(false)) => format!("; it covers the truth {t}, which MD alone missed"),
            (Some(true), Some(true)) => format!("; both cover the truth {t}"),
            (Some(false), Some(true)) => format!("; it misses the truth {t}, which MD alone covered"),
            (Some(false), Some(false)) => format!("; both miss the truth {t}"),
            _ => String::new(),
        }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Diagnosis {
    pub mismatch: Vec<ObservableMismatch>,
    pub candidates: Vec<CandidateResult>,
    pub verdict: Verdict,
    pub improvement: Option<Improvement>,
    pub base_log_evidence: f64,
    pub md_log_evidence: f64,
    pub provenance: Provenance,
}

/// Everything `diagnose` computed, for the report.
pub struct DiagnoseRun {
    pub diagnosis: Diagnosis,
    pub base: Calibration,
    pub md: Calibration,
    pub candidates: Vec<(String, Calibration)>,
    pub repaired_md: Option<Calibration>,
}

fn p_value(chi2: f64, dof: usize) -> f64 {
    ChiSquared::new(dof.max(1) as f64).map(|d| 1.0 - d.cdf(chi2)).unwrap_or(f64::NAN)
}

fn evidence(s: &Summary) -> (f64, f64) {
    (s.log_evidence.unwrap_or(f64::NEG_INFINITY), s.log_evidence_err.unwrap_or(f64::NAN))
}

fn delta_max_sigma(problem: &Problem, preds: &[PredictionRow]) -> BTreeMap<String, f64> {
    let mut out = BTreeMap::new();
    for b in &problem.likelihood.blocks {
        let m = preds
            .iter()
            .filter(|r| r.observable == b.name && r.kind == "data")
            .filter_map(|r| b.x.iter().position(|x| *x == r.x).map(|i| (r.delta_mean / b.error[i]).abs()))
            .fold(0.0, f64::max);
        out.insert(b.name.clone(), m);
    }
    out
}

fn figures(label: &str, problem: &Problem, cal: &Calibration) -> FitFigures {
    let (z, e) = evidence(&cal.summary);
    let theta: Vec<String> = problem.simulator.parameter_names();
    FitFigures {
        label: label.to_string(),
        chi2_per_dof: cal.summary.fit.chi2_per_dof,
        log_evidence: z,
        log_evidence_err: e,
        parameters: theta.iter().map(|n| (n.clone(), cal.summary.parameters[n].clone())).collect(),
        delta_max_sigma: delta_max_sigma(problem, &cal.predictions),
    }
}

/// One candidate's fit, kept with what made it.
struct CandidateRun {
    result: CandidateResult,
    candidate: CandidateModel,
    problem: Problem,
    calibration: Calibration,
}

impl CandidateRun {
    fn fit(&self) -> suggest::Fit<'_> {
        suggest::Fit { name: &self.result.name, problem: &self.problem, calibration: &self.calibration }
    }
}

/// What every calibration of one diagnosis shares.
struct Diagnoser<'a> {
    overrides: &'a Overrides,
    strong_log_bf: f64,
    out: Option<&'a Path>,
    observer: &'a dyn Observer,
}

impl Diagnoser<'_> {
    /// Calibrates `analysis` with `kernel` (None: no MD) and writes it to `out/name`.
    fn calibrate(
        &self,
        analysis: &Analysis,
        kernel: Option<DiscrepancyKernel>,
        seed: u64,
        name: &str,
    ) -> Result<(Problem, Calibration)> {
        let problem = Problem::new(analysis, &Overrides { kernel: Some(kernel), ..self.overrides.clone() })?;
        let cal = calibrate::run(&problem, seed, self.observer)?;
        if let Some(dir) = self.out {
            calibrate::write_outputs(&dir.join(name), &problem, &cal)?;
        }
        Ok((problem, cal))
    }

    /// Explain: every candidate fitted without MD, best evidence first.
    fn explain(&self, analysis: &Analysis, seed: u64, (z_base, e_base): (f64, f64)) -> Result<Vec<CandidateRun>> {
        let mut runs = Vec::new();
        for (k, candidate) in analysis.candidates()?.into_iter().enumerate() {
            let (problem, calibration) = self.calibrate(
                &analysis.with_candidate(&candidate),
                None,
                seed.wrapping_add(10 + k as u64),
                &format!("candidate_{}", candidate.name),
            )?;
            let (z, e) = evidence(&calibration.summary);
            let result = CandidateResult {
                name: candidate.name.clone(),
                description: candidate.description.clone(),
                log_evidence: z,
                log_evidence_err: e,
                log_bayes_factor: z - z_base,
                log_bayes_factor_err: (e * e + e_base * e_base).sqrt(),
                parameters: problem
                    .simulator
                    .parameter_names()
                    .iter()
                    .map(|n| (n.clone(), calibration.summary.parameters[n].clone()))
                    .collect(),
                chi2_per_dof: calibration.summary.fit.chi2_per_dof,
                p_value: p_value(calibration.summary.fit.chi2, calibration.summary.fit.dof),
                converged: calibration.summary.diagnostics.converged,
                emulator_share: calibration.summary.fit.model_variance_share,
                emulator_share_observable: worst_share_observable(&calibration.summary.fit),
            };
            runs.push(CandidateRun { result, candidate, problem, calibration });
        }
        // A stable sort keeps the library's order among equal evidences.
        runs.sort_by(|a, b| b.result.log_evidence.total_cmp(&a.result.log_evidence));
        let preferred = occam(&runs.iter().map(|r| &r.result).collect::<Vec<_>>(), self.strong_log_bf);
        let first = runs.remove(preferred);
        runs.insert(0, first);
        Ok(runs)
    }
}

/// The single candidates a candidate combines: `a+b` → {a, b}.
fn members(name: &str) -> std::collections::BTreeSet<&str> {
    name.split('+').collect()
}

/// Index of the candidate to name among `ranked` (best evidence first): the
/// best, unless a candidate it contains comes within `strong` of it; then
/// that one (the best such), and so on down.
fn occam(ranked: &[&CandidateResult], strong: f64) -> usize {
    let mut chosen = 0;
    while let Some((i, _)) = ranked
        .iter()
        .enumerate()
        .filter(|(_, r)| {
            let (inner, outer) = (members(&r.name), members(&ranked[chosen].name));
            inner.len() < outer.len()
                && inner.is_subset(&outer)
                && ranked[chosen].log_evidence - r.log_evidence <= strong
        })
        .max_by(|a, b| a.1.log_evidence.total_cmp(&b.1.log_evidence))
    {
        chosen = i;
    }
    chosen
}

/// The best alternative to `winner` among `ranked`: a candidate that does not
/// contain it (a+b is the winner a with more, not another explanation).
fn runner_up<'c>(winner: &CandidateResult, ranked: &'c [CandidateResult]) -> Option<&'c CandidateResult> {
    let mine = members(&winner.name);
    ranked.iter().find(|c| c.name != winner.name && !mine.is_subset(&members(&c.name)))
}

/// Runs the whole diagnosis. `out`, when given, receives every calibration.
pub fn run(
    analysis: &Analysis,
    overrides: &Overrides,
    seed: u64,
    settings: &DiagnoseSettings,
    out: Option<&Path>,
    observer: &dyn Observer,
) -> Result<DiagnoseRun> {
    let d = Diagnoser { overrides, strong_log_bf: settings.strong_log_bf, out, observer };
    let (base_problem, base) = d.calibrate(analysis, None, seed, "base_no_md")?;
    let (md_problem, md) = d.calibrate(analysis, Some(settings.kernel), seed.wrapping_add(1), "base_md")?;
    let (z_base, e_base) = evidence(&base.summary);
    let (z_md, _) = evidence(&md.summary);
    let mismatch = locate(&md_problem, &md, &base_problem, &base);
    let runs = d.explain(analysis, seed, (z_base, e_base))?;
    let candidates: Vec<CandidateResult> = runs.iter().map(|r| r.result.clone()).collect();
    let named = named_candidate(&candidates, settings, z_md);
    let rivals = named.map(|c| rivals(c, &candidates, settings)).unwrap_or_default();
    let suggestion = rivals.first().and_then(|r| {
        let other = runs.iter().find(|run| run.result.name == r.name)?;
        let goal = suggest::Goal {
            lead: runs[0].result.log_evidence - other.result.log_evidence,
            decisive: decisive_lead(&runs[0].result, &other.result, settings),
        };
        suggest::suggest(&runs[0].fit(), &other.fit(), goal)
    });
    let verdict =
        decide(&candidates, named, (&rivals, suggestion), &runs, &mismatch, &base.summary, settings, (z_base, z_md));

    // Repair: refit the winner with MD on top, to show δ shrink.
    let mut improvement = None;
    let mut repaired_md = None;
    // Only a named candidate is repaired: not one that is ambiguous or rests on its emulator.
    let named_alone = named.is_some_and(|c| rivals.is_empty() && !rests_on_emulator(c));
    if named_alone && settings.repair {
        let winner = &runs[0];
        let (rep_md_problem, rep_md) = d.calibrate(
            &analysis.with_candidate(&winner.candidate),
            Some(settings.kernel),
            seed.wrapping_add(99),
            "repaired_md",
        )?;
        let before = vec![figures("model, no MD", &base_problem, &base), figures("model + MD", &md_problem, &md)];
        let after = vec![
            figures(&format!("model + {}", winner.candidate.name), &winner.problem, &winner.calibration),
            figures(&format!("model + {} + MD", winner.candidate.name), &rep_md_problem, &rep_md),
        ];
        let interval_narrowing = base_problem
            .simulator
            .parameter_names()
            .iter()
            .map(|n| {
                (n.clone(), md.summary.parameters[n].width95() / winner.calibration.summary.parameters[n].width95())
            })
            .collect();
        let information_limit = information_limit(&winner.problem, &winner.calibration, &md);
        let truth = winner.problem.analysis.truth_values();
        improvement = Some(Improvement { before, after, interval_narrowing, information_limit, truth });
        repaired_md = Some(rep_md);
    }
    let diagnosis = Diagnosis {
        mismatch,
        candidates,
        verdict,
        improvement,
        base_log_evidence: z_base,
        md_log_evidence: z_md,
        provenance: base_problem.provenance(seed, "diagnose"),
    };
    if let Some(dir) = out {
        artifacts::write_json_atomic(&dir.join("diagnosis.json"), &diagnosis)?;
    }
    let candidates = runs.into_iter().map(|r| (r.candidate.name, r.calibration)).collect();
    Ok(DiagnoseRun { diagnosis, base, md, candidates, repaired_md })
}

/// The best candidate, when it beats the base model by more than
/// `strong_log_bf`, fits adequately and is not itself beaten by the MD fit.
fn named_candidate<'c>(
    candidates: &'c [CandidateResult],
    settings: &DiagnoseSettings,
    z_md: f64,
) -> Option<&'c CandidateResult> {
    candidates.first().filter(|c| {
        c.log_bayes_factor > settings.strong_log_bf
            && c.p_value >= settings.min_p_value
            && c.log_evidence > z_md - settings.strong_log_bf
    })
}

/// The other explanations `best` does not beat decisively: candidates that
/// neither contain it nor are contained in it (Occam's rule settled those),
/// fit adequately, and trail it by no more than `strong_log_bf` plus twice
/// the Monte Carlo error of the difference.
fn rivals<'c>(
    best: &CandidateResult,
    candidates: &'c [CandidateResult],
    settings: &DiagnoseSettings,
) -> Vec<&'c CandidateResult> {
    let mine = members(&best.name);
    candidates
        .iter()
        .filter(|c| c.name != best.name && c.p_value >= settings.min_p_value)
        .filter(|c| {
            let theirs = members(&c.name);
            !mine.is_subset(&theirs) && !theirs.is_subset(&mine)
        })
        .filter(|c| best.log_evidence - c.log_evidence <= decisive_lead(best, c, settings))
        .collect()
}

/// The lead in log evidence of `a` over `b` that names `a` alone:
/// `strong_log_bf` plus twice the Monte Carlo error of the difference.
fn decisive_lead(a: &CandidateResult, b: &CandidateResult, settings: &DiagnoseSettings) -> f64 {
    let err = (a.log_evidence_err.powi(2) + b.log_evidence_err.powi(2)).sqrt();
    settings.strong_log_bf + 2.0 * if err.is_finite() { err } else { 0.0 }
}

/// The verdict: a named candidate, "ambiguous", "unexplained" or "none" (see
/// the module docs).
#[allow(clippy::too_many_arguments)]
fn decide(
    candidates: &[CandidateResult],
    named: Option<&CandidateResult>,
    (rivals, suggestion): (&[&CandidateResult], Option<Suggestion>),
    runs: &[CandidateRun],
    mismatch: &[ObservableMismatch],
    base: &Summary,
    settings: &DiagnoseSettings,
    (z_base, z_md): (f64, f64),
) -> Verdict {
    let base_p = p_value(base.fit.chi2, base.fit.dof);
    let significant = z_md - z_base > settings.strong_log_bf || base_p < settings.min_p_value;
    let best = candidates.first();
    // Posterior model probabilities with equal prior odds.
    let mut all_z = vec![z_base, z_md];
    all_z.extend(candidates.iter().map(|c| c.log_evidence));
    let lse = crate::engine::calibrate::smc::log_sum_exp(&all_z);
    let prob = |z: f64| (z - lse).exp();
    let worst = mismatch.iter().max_by(|a, b| a.max_sigma.total_cmp(&b.max_sigma));
    let verdict = |best: &str, statement: String, confidence: f64| Verdict {
        best: best.into(),
        standing: Vec::new(),
        suggestion: None,
        refine: Vec::new(),
        statement,
        confidence,
    };
    let emulator_limited = |standing: Vec<&CandidateResult>| {
        let refine = to_refine(&standing);
        Verdict {
            best: "emulator_limited".into(),
            statement: emulator_limited_statement(standing[0], &refine, mismatch, settings.min_p_value),
            confidence: standing.iter().map(|s| prob(s.log_evidence)).sum(),
            standing: standing.iter().map(|s| s.name.clone()).collect(),
            suggestion: None,
            refine,
        }
    };
    if let (None, true, Some(standing)) = (named, significant, unnamed_on_emulator(candidates, settings)) {
        return emulator_limited(standing);
    }
    match named {
        Some(c) if rests_on_emulator(c) => emulator_limited(std::iter::once(c).chain(rivals.iter().copied()).collect()),
        Some(c) if !rivals.is_empty() => {
            let standing: Vec<&CandidateResult> = std::iter::once(c).chain(rivals.iter().copied()).collect();
            Verdict {
                best: "ambiguous".into(),
                statement: ambiguous_statement(&standing, suggestion.as_ref(), mismatch, settings.strong_log_bf),
                confidence: standing.iter().map(|s| prob(s.log_evidence)).sum(),
                standing: standing.iter().map(|s| s.name.clone()).collect(),
                suggestion,
                refine: Vec::new(),
            }
        }
        Some(c) => {
            // What a reader means by confidence in "the data need c": the
            // probability of every model that contains c, pairs included.
            let mine = members(&c.name);
            let needed = candidates.iter().filter(|k| mine.is_subset(&members(&k.name))).map(|k| prob(k.log_evidence)).sum();
            verdict(&c.name, named_statement(c, &runs[0].candidate, runner_up(c, candidates), mismatch), needed)
        }
        None if significant => {
            let w = worst.map(|w| format!("{} deviates by up to {:.1}σ (at x = {:.3}); ", w.observable, w.max_sigma, w.x_at_max)).unwrap_or_default();
            let b = best.map(|c| format!("the best candidate, {}, reaches χ²/dof = {:.2} (p = {:.1e}) and log BF = {:.1} against the model; ", c.name, c.chi2_per_dof, c.p_value, c.log_bayes_factor)).unwrap_or_default();
            verdict("unexplained", format!("a mismatch that no candidate explains: {w}{b}the model-discrepancy fit (log BF = {:.1} against no MD) stays the honest answer.", z_md - z_base), prob(z_md))
        }
        None => verdict(
            "none",
            format!(
                "no significant mismatch: δ is consistent with zero (largest posterior-mean |δ| = {:.1}σ), the model alone fits with χ²/dof = {:.2}, and no candidate is favoured (best log BF = {:.1}).",
                worst.map(|w| w.max_sigma).unwrap_or(0.0),
                base.fit.chi2_per_dof,
                best.map(|c| c.log_bayes_factor).unwrap_or(f64::NAN)
            ),
            prob(z_base),
        ),
    }
}

/// "…the data cannot yet choose between A (…) and B (…): …; to separate them, measure …".
fn ambiguous_statement(
    standing: &[&CandidateResult],
    suggestion: Option<&Suggestion>,
    mismatch: &[ObservableMismatch],
    strong: f64,
) -> String {
    let who: Vec<String> = standing
        .iter()
        .map(|c| {
            let fitted: Vec<String> = c
                .parameters
                .iter()
                .map(|(n, p)| format!("{n} = {:.3} [{:.3}, {:.3}]", p.median, p.q025, p.q975))
                .collect();
            format!(
                "{} ({}; log BF {:.1} ± {:.1} against the model as it is; {})",
                c.name,
                c.description,
                c.log_bayes_factor,
                c.log_bayes_factor_err,
                fitted.join(", ")
            )
        })
        .collect();
    let (a, b) = (standing[0], standing[1]);
    let gap = a.log_evidence - b.log_evidence;
    let err = (a.log_evidence_err.powi(2) + b.log_evidence_err.powi(2)).sqrt();
    let next = suggestion.map(|s| format!("; {}", suggest::phrase(s))).unwrap_or_default();
    format!(
        "{}the data cannot yet choose between {}: {} leads {} by log BF {gap:.1} ± {err:.1}, short of the decisive {strong} (plus twice its error){next}.",
        mismatch_phrase(mismatch),
        who.join(" and "),
        a.name,
        b.name
    )
}

/// Whether a fit rests on its emulator: the emulator's share of the
/// predictive variance at the data is above one half.
fn rests_on_emulator(c: &CandidateResult) -> bool {
    c.emulator_share > EMULATOR_DOMINATES
}

/// When the leader beats the base model strongly but was not named (its fit
/// fails the χ² test or the MD fit beats it) while resting on its emulator:
/// the leader and every other such candidate within a decisive lead of it.
/// Their χ² and evidence are then set by the emulator's error, not the data,
/// so rejecting them would be as unfounded as naming them; only refinement
/// can decide (a coarse emulator's mean can miss by more than its sd, and a
/// χ²/dof of 2 at 98% emulator share says exactly that).
fn unnamed_on_emulator<'c>(
    candidates: &'c [CandidateResult],
    settings: &DiagnoseSettings,
) -> Option<Vec<&'c CandidateResult>> {
    let leader = candidates.first().filter(|c| c.log_bayes_factor > settings.strong_log_bf && rests_on_emulator(c))?;
    let trailing = candidates[1..].iter().filter(|c| {
        rests_on_emulator(c)
            && c.log_bayes_factor > settings.strong_log_bf
            && leader.log_evidence - c.log_evidence <= decisive_lead(leader, c, settings)
    });
    Some(std::iter::once(leader).chain(trailing).collect())
}

/// The standing candidates whose variant emulators must be refined.
fn to_refine(standing: &[&CandidateResult]) -> Vec<String> {
    standing.iter().filter(|s| rests_on_emulator(s)).map(|s| s.name.clone()).collect()
}

/// The observable where the emulator carries the largest share ("" when none does).
fn worst_share_observable(fit: &crate::engine::calibrate::summary::FitQuality) -> String {
    fit.per_observable_share
        .iter()
        .filter(|(_, v)| **v > 0.0)
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map(|(k, _)| k.clone())
        .unwrap_or_default()
}

/// "…the data lead to X, but its emulator carries N% of the variance: refine …".
fn emulator_limited_statement(
    c: &CandidateResult,
    refine: &[String],
    mismatch: &[ObservableMismatch],
    min_p_value: f64,
) -> String {
    let poor = if c.p_value < min_p_value {
        format!(" (its χ²/dof of {:.2} cannot yet tell a wrong candidate from a coarse emulator)", c.chi2_per_dof)
    } else {
        String::new()
    };
    format!(
        "{}the data lead to {} (log BF {:.1} ± {:.1} against the model as it is), but the emulator's uncertainty is {:.0}% of that fit's predictive variance at the data{}, so the emulator, not the data, decides how well it fits{poor}: no candidate is named. Refine the variant emulator{} of {} with runs where {} posterior{} lie{} (`mdpipe run` with `[run.refine] variant_budget`, or `refine::variant`), then diagnose again.",
        mismatch_phrase(mismatch),
        c.name,
        c.log_bayes_factor,
        c.log_bayes_factor_err,
        100.0 * c.emulator_share,
        if c.emulator_share_observable.is_empty() { String::new() } else { format!(" in {}", c.emulator_share_observable) },
        if refine.len() > 1 { "s" } else { "" },
        refine.join(" and "),
        if refine.len() > 1 { "their" } else { "its" },
        if refine.len() > 1 { "s" } else { "" },
        if refine.len() > 1 { "" } else { "s" },
    )
}

/// "…the data favour X (what it is), k = … over the runner-up by log BF = …".
fn named_statement(
    c: &CandidateResult,
    model: &CandidateModel,
    runner_up: Option<&CandidateResult>,
    mismatch: &[ObservableMismatch],
) -> String {
    let fitted: Vec<String> = model
        .extra_parameters
        .iter()
        .map(|(n, spec)| {
            let p = &c.parameters[n];
            format!(
                "{n} = {:.3} [{:.3}, {:.3}]{}",
                p.median,
                p.q025,
                p.q975,
                if spec.units.is_empty() { String::new() } else { format!(" {}", spec.units) }
            )
        })
        .collect();
    let fitted = if fitted.is_empty() { "with no free parameter of its own".to_string() } else { fitted.join(", ") };
    let trend = mismatch_phrase(mismatch);
    let runner = runner_up
        .map(|r| format!(" over {} by log BF = {:.1}", r.name, c.log_evidence - r.log_evidence))
        .unwrap_or_default();
    format!(
        "{trend}the data favour {} ({}), {fitted}{runner}; against the model as it is, log BF = {:.1}.",
        c.name.replace('_', " "),
        c.description,
        c.log_bayes_factor
    )
}

/// MD 95% width over the repaired model's Cramér–Rao 95% width, per
/// parameter of the base model, at the repaired posterior median.
fn information_limit(rep_problem: &Problem, rep: &Calibration, md: &Calibration) -> BTreeMap<String, f64> {
    let lik = &rep_problem.likelihood;
    let names = rep_problem.simulator.parameter_names();
    let theta: Vec<f64> = names.iter().map(|n| rep.summary.parameters[n].median).collect();
    // Central differences at 1e-5 of the prior range: truncation ~1e-10 relative.
    let steps: Vec<f64> =
        (0..lik.n_theta).map(|k| 1e-5 * (rep_problem.prior.upper[k] - rep_problem.prior.lower[k])).collect();
    let Some(sd) = lik.cramer_rao_sd(&theta, &steps) else {
        return BTreeMap::new();
    };
    names
        .iter()
        .zip(&sd)
        .filter_map(|(n, s)| md.summary.parameters.get(n).map(|p| (n.clone(), p.width95() / (2.0 * 1.959964 * s))))
        .collect()
}

/// Plain-text summary for the terminal.
pub fn print(d: &Diagnosis) {
    println!("Locate (model + MD; δ in units of the measurement error):");
    for m in &d.mismatch {
        let show = |rs: &[Region]| -> String {
            if rs.is_empty() {
                "no region".into()
            } else {
                rs.iter().map(|r| format!("[{:.2}, {:.2}] {}", r.x_from, r.x_to, r.sign)).collect::<Vec<_>>().join(", ")
            }
        };
        println!(
            "  {:<14} max |δ| = {:>5.1}σ at x = {:.2}; δ ≠ 0 in {}; r = {:.2} [{:.2}, {:.2}]; no-MD χ²/n = {:.1}, misses in {}",
            m.observable,
            m.max_sigma,
            m.x_at_max,
            show(&m.regions),
            m.r.median,
            m.r.q025,
            m.r.q975,
            m.no_md_chi2 / m.no_md_dof as f64,
            show(&m.residual_regions)
        );
    }
    println!(
        "Explain (log Bayes factor against the model without MD; log BF of the MD fit: {:.1}):",
        d.md_log_evidence - d.base_log_evidence
    );
    let width = d.candidates.iter().map(|c| c.name.chars().count()).max().unwrap_or(0).max(16);
    for c in &d.candidates {
        let share = if c.emulator_share > 0.0 {
            format!("   emulator share {:.0}% ({})", 100.0 * c.emulator_share, c.emulator_share_observable)
        } else {
            String::new()
        };
        println!(
            "  {:<width$} log BF = {:>8.1} ± {:.1}   χ²/dof = {:>6.2}{share}",
            c.name, c.log_bayes_factor, c.log_bayes_factor_err, c.chi2_per_dof
        );
    }
    println!("Verdict: {} ({})", d.verdict.best, d.verdict.confidence_phrase());
    println!("  {}", d.verdict.statement);
    if let Some(imp) = &d.improvement {
        // With MD the χ² is of η alone: what δ had to absorb, not the MD fit's misfit.
        println!("Repair (before → after; χ²/dof of the model part η alone, δ left out):");
        for f in imp.before.iter().chain(&imp.after) {
            let g: Vec<String> = f
                .parameters
                .iter()
                .map(|(n, p)| format!("{n} = {:.3} [{:.3}, {:.3}]", p.median, p.q025, p.q975))
                .collect();
            let dmax = f.delta_max_sigma.values().cloned().fold(0.0, f64::max);
            println!(
                "  {:<34} χ²/dof {:>6.2}  log Z {:>8.2}  max|δ| {:>4.1}σ  {}",
                f.label,
                f.chi2_per_dof,
                f.log_evidence,
                dmax,
                g.join(", ")
            );
        }
        for (n, r) in &imp.interval_narrowing {
            let limit = imp
                .information_limit
                .get(n)
                .map(|l| format!(" (the data's Cramér–Rao limit: {l:.1}x)"))
                .unwrap_or_default();
            let change = if *r >= 1.0 { format!("{r:.1}x narrower") } else { format!("{:.1}x wider", 1.0 / r) };
            println!("  95% interval of {n}: {change} than with MD alone{limit}{}", imp.truth_coverage(n));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ranked(evidences: &[(&str, f64)]) -> Vec<CandidateResult> {
        evidences
            .iter()
            .map(|(name, z)| CandidateResult {
                name: name.to_string(),
                description: String::new(),
                log_evidence: *z,
                log_evidence_err: 0.1,
                log_bayes_factor: *z,
                log_bayes_factor_err: 0.1,
                parameters: BTreeMap::new(),
                chi2_per_dof: 1.0,
                p_value: 0.5,
                converged: true,
                emulator_share: 0.0,
                emulator_share_observable: String::new(),
            })
            .collect()
    }

    fn named(evidences: &[(&str, f64)]) -> String {
        let r = ranked(evidences);
        r[occam(&r.iter().collect::<Vec<_>>(), 3.0)].name.clone()
    }

    #[test]
    fn a_pair_is_named_only_when_it_beats_what_it_contains_decisively() {
        // The ball drop's case: the pair leads its member by 0.6.
        assert_eq!(
            named(&[("quadratic_drag+field_gradient", -4.4), ("quadratic_drag", -5.0), ("field_gradient", -590.0)]),
            "quadratic_drag"
        );
        // Two effects that each need the other: the pair leads both by more than 3.
        assert_eq!(named(&[("a+b", 0.0), ("a", -5.0), ("b", -6.0)]), "a+b");
        // Of two members within 3, the better one.
        assert_eq!(named(&[("a+b", 0.0), ("b", -2.0), ("a", -2.5)]), "b");
        // Not nested: the best stands, however close.
        assert_eq!(named(&[("a", 0.0), ("b", -0.1)]), "a");
        // The runner-up of a named member is another explanation, not the pair that contains it.
        let r = ranked(&[("a", 0.0), ("a+b", -0.5), ("b+c", -8.0), ("c", -9.0)]);
        assert_eq!(runner_up(&r[0], &r).map(|c| c.name.as_str()), Some("b+c"));
    }

    #[test]
    fn a_winner_that_rests_on_its_emulator_is_not_named_and_its_emulator_is_to_be_refined() {
        let mut r = ranked(&[("a", 0.0), ("b", -1.0), ("c", -9.0)]);
        r[0].emulator_share = 0.8;
        r[1].emulator_share = 0.2;
        r[2].emulator_share = 0.9;
        assert!(rests_on_emulator(&r[0]) && !rests_on_emulator(&r[1]));
        // Exactly one half is the emulator and the data in equal parts: not yet resting on it.
        r[1].emulator_share = EMULATOR_DOMINATES;
        assert!(!rests_on_emulator(&r[1]));
        // Of the standing (a and its rival b), only a's emulator needs runs; c is out of the race.
        let standing: Vec<&CandidateResult> =
            std::iter::once(&r[0]).chain(rivals(&r[0], &r, &DiagnoseSettings::default())).collect();
        assert_eq!(to_refine(&standing), ["a"]);
        let text = emulator_limited_statement(&r[0], &to_refine(&standing), &[], 1e-3);
        assert!(
            text.contains("80%")
                && text.contains("no candidate is named")
                && text.contains("emulator of a with runs where its posterior lies"),
            "{text}"
        );
    }

    #[test]
    fn an_unnamed_leader_that_rests_on_its_emulator_is_refined_not_rejected() {
        let settings = DiagnoseSettings::default();
        // The bundled study's case: the leader beats the base by far but fails the χ² test at 98% emulator share.
        let mut r = ranked(&[("grad", 1340.0), ("bulk", 296.0), ("annihilation", 1337.5), ("weak", 2.0)]);
        r.sort_by(|a, b| b.log_evidence.total_cmp(&a.log_evidence));
        for c in r.iter_mut() {
            c.p_value = 1e-6;
            c.chi2_per_dof = 2.01;
            c.emulator_share = 0.98;
        }
        let standing: Vec<&str> = unnamed_on_emulator(&r, &settings).unwrap().iter().map(|c| c.name.as_str()).collect();
        // bulk trails decisively and weak does not beat the base strongly: neither stands.
        assert_eq!(standing, ["grad", "annihilation"]);
        let text = emulator_limited_statement(&r[0], &["grad".into()], &[], settings.min_p_value);
        assert!(text.contains("χ²/dof of 2.01 cannot yet tell"), "{text}");
        // Whose emulator is not the larger share of the variance, its failed χ² test is the data's: no refinement.
        r[0].emulator_share = 0.3;
        assert!(unnamed_on_emulator(&r, &settings).is_none());
        // Nor for a leader that does not beat the base model strongly.
        let mut weak = ranked(&[("a", 2.5)]);
        weak[0].emulator_share = 0.9;
        assert!(unnamed_on_emulator(&weak, &settings).is_none());
    }

    fn rival_names(r: &[CandidateResult]) -> Vec<&str> {
        rivals(&r[0], r, &DiagnoseSettings::default()).iter().map(|c| c.name.as_str()).collect()
    }

    #[test]
    fn a_candidate_stands_alone_only_when_it_leads_every_other_explanation_decisively() {
        // The simple machine's case: a lead of 1.7 is no verdict.
        assert_eq!(rival_names(&ranked(&[("saturation", 0.0), ("quadratic_loss", -1.7)])), ["quadratic_loss"]);
        // 3.5 with errors 0.1 each: 3.5 > 3 + 2 × 0.14, decisive.
        assert!(rival_names(&ranked(&[("a", 0.0), ("b", -3.5)])).is_empty());
        // The same lead with errors 0.3 each (3 + 2 × 0.42 = 3.85) is not.
        let mut r = ranked(&[("a", 0.0), ("b", -3.5)]);
        r.iter_mut().for_each(|c| c.log_evidence_err = 0.3);
        assert_eq!(rival_names(&r), ["b"]);
        // A pair holding the best, or a member of the best, is Occam's business, not a rival;
        // a candidate that does not fit is no explanation.
        let mut r = ranked(&[("a", 0.0), ("a+b", -0.2), ("c", -0.5), ("d", -1.0)]);
        r[3].p_value = 1e-5;
        assert_eq!(rival_names(&r), ["c"]);
        assert!(rival_names(&ranked(&[("a+b", 0.0), ("a", -3.2), ("b", -9.0)])).is_empty());
    }
}
