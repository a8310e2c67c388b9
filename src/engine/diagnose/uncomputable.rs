//! When the model as declared cannot be computed over the data at any θ
//! its prior allows (an ODE that blows up before the data's last time), it
//! has no fit, with or without MD, to locate a mismatch against. What is
//! left is still worth saying: the candidates, declared or discovered along
//! the data (where no integration of the model is needed), are judged
//! against each other, and one that makes the model computable and fits
//! the data, decisively ahead of the rest, is named.

use super::*;
use crate::base::messages::note;

pub(super) fn run(
    d: &Diagnoser,
    analysis: &Analysis,
    seed: u64,
    settings: &DiagnoseSettings,
    why: &anyhow::Error,
) -> Result<DiagnoseRun> {
    note!("  the model as declared cannot be computed over the data, with or without MD: {why}");
    let strong = settings.strong_log_bf;
    let none = (f64::NEG_INFINITY, f64::NAN);
    let overrides = Overrides { kernel: Some(DiscrepancyKernel::choice(None)), ..d.overrides.clone() };
    let problem = Problem::new(analysis, &overrides)?;
    let declared = analysis.candidates()?.into_iter().map(|c| (c, 0.0)).collect();
    let mut runs = d.explain(analysis, declared, seed, none, (f64::NEG_INFINITY, strong))?;
    let mut discovery = None;
    if let Some(discoverer) = analysis.setup.discoverer().filter(|_| settings.discover != Discover::Never) {
        // The search starts from the prior's centre: there is no fit of the model to start from.
        let n = problem.simulator.parameter_names().len();
        let centre = (0..n).map(|k| 0.5 * (problem.prior.lower[k] + problem.prior.upper[k])).collect();
        let (report, proposals) = discover::screen(discoverer, &problem, centre)?;
        let leader = runs.iter().map(|r| r.result.log_evidence).fold(f64::NEG_INFINITY, f64::max);
        runs.extend(d.explain(analysis, proposals, seed.wrapping_add(500), none, (leader, strong))?);
        discovery = Some(report);
    }
    let runs = rank(runs, strong);
    let candidates: Vec<CandidateResult> = runs.iter().map(|r| r.result.clone()).collect();
    let mut verdict = verdict(&candidates, &runs, settings);
    if let Some(report) = &discovery {
        discover::word(&mut verdict, report);
    }
    let diagnosis = Diagnosis {
        mismatch: Vec::new(),
        candidates,
        verdict,
        improvement: None,
        base_log_evidence: f64::NEG_INFINITY,
        md_log_evidence: f64::NEG_INFINITY,
        discovery,
        profile: d.profile(),
        provenance: problem.provenance(seed, "diagnose"),
    };
    if let Some(dir) = d.out {
        artifacts::write_json_atomic(&dir.join("diagnosis.json"), &diagnosis)?;
    }
    let candidates = runs.into_iter().map(|r| (r.candidate.name, r.calibration)).collect();
    Ok(DiagnoseRun { diagnosis, base: None, md: None, candidates, repaired_md: None })
}

/// The verdict among the candidates alone: one that fits adequately and
/// leads every other explanation decisively is named; several within
/// reach of each other are `ambiguous`; none that fits leaves the model
/// `unexplained`. Probabilities are over the candidates: the model as
/// declared has none.
fn verdict(candidates: &[CandidateResult], runs: &[CandidateRun], settings: &DiagnoseSettings) -> Verdict {
    let lse = crate::engine::calibrate::sampler::smc::log_sum_exp(
        &candidates.iter().map(|c| c.log_evidence).collect::<Vec<_>>(),
    );
    let prob = |z: f64| (z - lse).exp();
    let cannot = "the model as declared cannot be computed over the data at any value its prior allows (its solution does not reach the data's last point); ";
    let named = named_candidate(candidates, settings, f64::NEG_INFINITY);
    let mut rivals = named.map(|c| rivals(c, candidates, settings)).unwrap_or_default();
    if let Some(c) = named {
        // No measurement is proposed here: readings of one fit are one explanation.
        rivals.retain(|r| !super::decide::one_explanation(c, r, || None));
    }
    let mut v = Verdict::uncomputable();
    match named {
        Some(c) if rivals.is_empty() => {
            let mine = members(&c.name);
            v.best = c.name.clone();
            v.confidence =
                candidates.iter().filter(|k| mine.is_subset(&members(&k.name))).map(|k| prob(k.log_evidence)).sum();
            let runner = runner_up(c, candidates);
            v.statement = format!(
                "{cannot}with {} it can, and fits with χ²/dof = {:.2}: {}",
                c.name.replace('_', " "),
                c.chi2_per_dof,
                named_statement(c, &runs[0].candidate, runner, &[])
            );
        }
        Some(c) => {
            let standing: Vec<&CandidateResult> = std::iter::once(c).chain(rivals.iter().copied()).collect();
            v.best = "ambiguous".into();
            v.confidence = standing.iter().map(|s| prob(s.log_evidence)).sum();
            v.standing = standing.iter().map(|s| s.name.clone()).collect();
            v.statement = format!("{cannot}{}", ambiguous_statement(&standing, None, &[], settings.strong_log_bf));
        }
        None => {
            let best = candidates.first().map(|c| {
                format!(
                    "the best candidate, {}, reaches χ²/dof = {:.2} (p = {:.1e})",
                    c.name, c.chi2_per_dof, c.p_value
                )
            });
            v.statement = format!(
                "{cannot}no candidate makes it fit the data{}.",
                best.map(|b| format!(": {b}")).unwrap_or_default()
            );
        }
    }
    v
}
