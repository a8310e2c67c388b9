//! The fits one diagnosis makes: the model with and without MD, and each
//! candidate (`Diagnoser`), each written beside the others and reused
//! where the same problem was fitted before.

use super::*;

pub(super) fn evidence(s: &Summary) -> (f64, f64) {
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

pub(super) fn figures(label: &str, problem: &Problem, cal: &Calibration) -> FitFigures {
    let (z, e) = evidence(&cal.summary);
    let theta: Vec<String> = problem.simulator.parameter_names();
    FitFigures {
        label: label.to_string(),
        chi2_per_dof: cal.summary.fit.chi2_per_dof,
        log_evidence: z,
        log_evidence_err: e,
        parameters: theta.iter().map(|n| (n.clone(), cal.summary.parameters[n].clone())).collect(),
        delta_max_sigma: delta_max_sigma(problem, &cal.predictions),
        piled_at_bounds: cal.summary.piled_at_bounds.clone(),
    }
}

/// One candidate's fit, kept with what made it.
pub(super) struct CandidateRun {
    pub(super) result: CandidateResult,
    pub(super) candidate: CandidateModel,
    pub(super) problem: Problem,
    pub(super) calibration: Calibration,
    /// The seed its calibration used: a refit with more particles uses it again.
    pub(super) seed: u64,
}

impl CandidateRun {
    pub(super) fn fit(&self) -> suggest::Fit<'_> {
        suggest::Fit { name: &self.result.name, problem: &self.problem, calibration: &self.calibration }
    }
}

/// What every calibration of one diagnosis shares.
pub(super) struct Diagnoser<'a> {
    pub(super) overrides: &'a Overrides,
    pub(super) out: Option<&'a Path>,
    pub(super) observer: &'a dyn Observer,
    pub(super) reuse: &'a Reuse,
    /// Whether a candidate far behind stops tempering (`explain`).
    pub(super) stop_hopeless: bool,
    /// Each fit's wall time, for `Diagnosis::profile`.
    pub(super) times: std::sync::Mutex<Vec<FitTime>>,
}

impl Diagnoser<'_> {
    /// Calibrates `analysis` with `kernel` (None: no MD) and writes it to `out/name`.
    pub(super) fn calibrate(
        &self,
        analysis: &Analysis,
        kernel: Option<DiscrepancyKernel>,
        seed: u64,
        name: &str,
    ) -> Result<(Problem, Calibration)> {
        self.calibrate_judged(analysis, kernel, seed, name, calibrate::Judge::ALWAYS)
    }

    fn record(&self, name: &str, analysis: &Analysis, seconds: f64, cal: &Calibration) {
        let evaluations = cal.summary.diagnostics.likelihood_evaluations;
        let fit = FitTime { fit: name.to_string(), particles: analysis.sampler.smc.particles, seconds, evaluations };
        self.times.lock().unwrap_or_else(|e| e.into_inner()).push(fit);
    }

    /// The fits' times so far, in the order made.
    pub(super) fn profile(&self) -> Vec<FitTime> {
        self.times.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// As `calibrate`, as far as `judge` says the answer can matter. A fit
    /// that was abandoned while tempering is reused only where `judge` would
    /// abandon it too at the estimate it stopped at: what it was too far
    /// behind belonged to the diagnosis that made it.
    pub(super) fn calibrate_judged(
        &self,
        analysis: &Analysis,
        kernel: Option<DiscrepancyKernel>,
        seed: u64,
        name: &str,
        judge: calibrate::Judge,
    ) -> Result<(Problem, Calibration)> {
        let problem = Problem::new(
            analysis,
            &Overrides { kernel: Some(DiscrepancyKernel::choice(kernel)), ..self.overrides.clone() },
        )?;
        let still_behind = |cal: &Calibration| match cal.summary.diagnostics.sampler.abandoned_at() {
            None => true,
            Some(_) => judge.abandon.is_some_and(|stop| stop(evidence(&cal.summary).0)),
        };
        let cal = match self.reuse.get(name, &problem, seed).filter(|(cal, _)| still_behind(cal)) {
            Some((cal, whence)) => {
                crate::base::messages::say!("  {name}: the same problem was fitted in {whence}; that fit is used");
                cal
            }
            None => {
                let started = std::time::Instant::now();
                let cal = calibrate::run_judged(&problem, seed, self.observer, judge)?;
                self.reuse.keep(name, &problem, seed, &cal);
                self.record(name, analysis, started.elapsed().as_secs_f64(), &cal);
                cal
            }
        };
        if let Some(dir) = self.out {
            calibrate::write_outputs(&dir.join(name), &problem, &cal)?;
        }
        Ok((problem, cal))
    }

    /// Explain: each candidate fitted without MD. A discovered term's prior
    /// log odds (paying for the search) join its log evidence. A candidate
    /// that trails the best so far (`leader`, and each run here) by more
    /// than any verdict could turn on is not sampled again for convergence
    /// (`hopeless`), and stops tempering once an upper estimate of its
    /// final log evidence (`smc::Abandon`) is that far behind.
    pub(super) fn explain(
        &self,
        analysis: &Analysis,
        candidates: Vec<(CandidateModel, f64)>,
        seed: u64,
        (z_base, e_base): (f64, f64),
        (leader, strong_log_bf): (f64, f64),
    ) -> Result<Vec<CandidateRun>> {
        let order = (0..candidates.len()).collect();
        self.explain_in_order(analysis, candidates, order, seed, (z_base, e_base), (leader, strong_log_bf))
    }

    /// As `explain`, calibrating `candidates[order[0]]` first, and so on
    /// (`promise`); each keeps the seed of its position in `candidates`, so
    /// the order decides which fits stop early, not what a fit is.
    pub(super) fn explain_in_order(
        &self,
        analysis: &Analysis,
        candidates: Vec<(CandidateModel, f64)>,
        order: Vec<usize>,
        seed: u64,
        (z_base, e_base): (f64, f64),
        (leader, strong_log_bf): (f64, f64),
    ) -> Result<Vec<CandidateRun>> {
        let mut queue: Vec<Option<(CandidateModel, f64)>> = candidates.into_iter().map(Some).collect();
        let mut runs: Vec<CandidateRun> = Vec::new();
        for k in order {
            let Some((candidate, prior_log_odds)) = queue.get_mut(k).and_then(Option::take) else { continue };
            let best = runs.iter().map(|r| r.result.log_evidence).fold(leader, f64::max);
            let matters = |z: f64, e: f64| !hopeless(z + prior_log_odds, e, best, strong_log_bf);
            let abandon = |reach: f64| hopeless(reach + prior_log_odds, 0.0, best, strong_log_bf);
            let judge =
                calibrate::Judge { matters: &matters, abandon: Some(&abandon as _).filter(|_| self.stop_hopeless) };
            let seed = seed.wrapping_add(10 + k as u64);
            if let Some(run) = self.fit_candidate(analysis, candidate, prior_log_odds, seed, (z_base, e_base), judge)? {
                runs.push(run);
            }
        }
        Ok(runs)
    }

    /// One candidate fitted without MD (None when it cannot be computed
    /// over the data), its prior log odds joined to its log evidence.
    pub(super) fn fit_candidate(
        &self,
        analysis: &Analysis,
        candidate: CandidateModel,
        prior_log_odds: f64,
        seed: u64,
        (z_base, e_base): (f64, f64),
        judge: calibrate::Judge,
    ) -> Result<Option<CandidateRun>> {
        let fitted = self.calibrate_judged(
            &analysis.with_candidate(&candidate),
            None,
            seed,
            &format!("candidate_{}", candidate.name),
            judge,
        );
        let (problem, calibration) = match fitted {
            Err(e) if e.downcast_ref::<calibrate::guard::NotComputable>().is_some() => {
                crate::base::messages::note!("  candidate {} cannot be computed over the data: {e}", candidate.name);
                return Ok(None);
            }
            other => other?,
        };
        let (z, e) = evidence(&calibration.summary);
        let z = z + prior_log_odds;
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
            prior_log_odds,
            special_case_of: candidate.special_case_of.clone(),
            own_emulator: candidate.own_emulator,
            same_fit_as: Vec::new(),
            same_fit_as_md: false,
            scout: false,
            stopped_at_beta: calibration.summary.diagnostics.sampler.abandoned_at(),
        };
        Ok(Some(CandidateRun { result, candidate, problem, calibration, seed }))
    }
}

/// A scouted candidate made again with the configured settings and its own
/// seed. Only the verdict's named candidate, whose posterior is the
/// answer (the discovered term's parameters, the repair's "after"), is
/// sampled again for convergence; any other is weighed by its evidence,
/// whose error already counts the replicates' disagreement
/// (`calibrate::sampler::smc`), and its diagnostics say whether it converged.
pub(super) fn refit(
    d: &Diagnoser,
    analysis: &Analysis,
    run: &CandidateRun,
    verdict: &Verdict,
    base: (f64, f64),
) -> Result<Option<CandidateRun>> {
    let answer = verdict.named() == Some(run.result.name.as_str());
    let (candidate, odds) = (run.candidate.clone(), run.result.prior_log_odds);
    let matters = |_: f64, _: f64| answer;
    d.fit_candidate(analysis, candidate, odds, run.seed, base, calibrate::Judge { matters: &matters, abandon: None })
}

/// Whether a candidate of log evidence `z` (± `e`) trails `leader` by more
/// than a verdict could turn on: the decisive margin, plus room for its
/// estimate to move by ten of its errors (and at least 5 nats) as more
/// sampling converges it.
pub(super) fn hopeless(z: f64, e: f64, leader: f64, strong_log_bf: f64) -> bool {
    let room = 5.0f64.max(10.0 * if e.is_finite() { e } else { f64::INFINITY });
    z < leader - strong_log_bf - room
}
