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

mod decide;
mod discover;
mod fits;
mod locate;
mod partial;
mod precision;
mod promise;
mod readings;
mod reuse;
mod suggest;
mod types;
mod uncomputable;
mod wording;

use crate::base::artifacts::{self, Provenance};
use crate::base::progress::Observer;
use crate::engine::calibrate::results::summary::{ParamSummary, PredictionRow, Summary, EMULATOR_DOMINATES};
use crate::engine::calibrate::{self, Analysis, Calibration, Overrides, Problem};
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::{CandidateModel, SpecialCase};
use anyhow::Result;
use decide::*;
use fits::*;
use locate::{locate, mismatch_phrase};
use readings::{mark_same_as_md, rank};
pub use reuse::Reuse;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::BTreeMap;
use std::path::Path;
pub use suggest::{Suggestion, MAX_REPEATS};
pub use types::*;
use wording::*;
pub use wording::{print, print_profile};

fn p_value(chi2: f64, dof: usize) -> f64 {
    ChiSquared::new(dof.max(1) as f64).map(|d| 1.0 - d.cdf(chi2)).unwrap_or(f64::NAN)
}

/// The verdict on ranked candidate runs, and whether one is named alone.
fn judge(
    runs: &[CandidateRun],
    mismatch: &[ObservableMismatch],
    base: &Summary,
    md: (&Problem, &Calibration),
    settings: &DiagnoseSettings,
    (z_base, z_md): (f64, f64),
) -> (Vec<CandidateResult>, Verdict, bool) {
    let mut candidates: Vec<CandidateResult> = runs.iter().map(|r| r.result.clone()).collect();
    mark_same_as_md(&mut candidates, runs, md, settings.strong_log_bf);
    let named = named_candidate(&candidates, settings, z_md);
    let mut rivals = named.map(|c| rivals(c, &candidates, settings)).unwrap_or_default();
    let separating = |name: &str| {
        let other = runs.iter().find(|run| run.result.name == name)?;
        let goal = suggest::Goal {
            lead: runs[0].result.log_evidence - other.result.log_evidence,
            decisive: decisive_lead(&runs[0].result, &other.result, settings),
        };
        suggest::suggest(&runs[0].fit(), &other.fit(), goal)
    };
    if let Some(c) = named {
        rivals.retain(|r| !decide::one_explanation(c, r, || separating(&r.name)));
    }
    let suggestion = rivals.first().and_then(|r| separating(&r.name));
    let verdict = decide(&candidates, named, (&rivals, suggestion), runs, mismatch, base, settings, (z_base, z_md));
    // Only a named candidate is repaired: not one that is ambiguous or rests on its emulator.
    let named_alone = named.is_some_and(|c| rivals.is_empty() && !rests_on_emulator(c));
    (candidates.clone(), verdict, named_alone)
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
    run_reusing(analysis, overrides, seed, settings, out, observer, &Reuse::none())
}

/// As `run`, taking from `reuse` the fits an earlier diagnosis made of the
/// same problems with the same seeds, and keeping its own there.
pub fn run_reusing(
    analysis: &Analysis,
    overrides: &Overrides,
    seed: u64,
    settings: &DiagnoseSettings,
    out: Option<&Path>,
    observer: &dyn Observer,
    reuse: &Reuse,
) -> Result<DiagnoseRun> {
    let d =
        Diagnoser { overrides, out, observer, reuse, stop_hopeless: settings.stop_hopeless, times: Default::default() };
    // Every fit first as a scout; those the verdict turns on again in full (`precision`).
    let scouting = precision::scout(analysis).filter(|_| settings.scouts);
    let first = scouting.as_ref().unwrap_or(analysis);
    let (mut base_problem, mut base) = match d.calibrate(first, None, seed, "base_no_md") {
        Err(e) if e.downcast_ref::<calibrate::guard::NotComputable>().is_some() => {
            return uncomputable::run(&d, analysis, seed, settings, &e);
        }
        other => other?,
    };
    let (mut md_problem, mut md) = d.calibrate(first, Some(settings.kernel), seed.wrapping_add(1), "base_md")?;
    let (mut z_base, mut e_base) = evidence(&base.summary);
    let (mut z_md, mut e_md) = evidence(&md.summary);
    let mut mismatch = locate(&md_problem, &md, &base_problem, &base);
    let declared: Vec<_> = analysis.candidates()?.into_iter().map(|c| (c, 0.0)).collect();
    let strong = settings.strong_log_bf;
    let order = if settings.order_by_promise {
        let medians = base.summary.parameters.iter().map(|(n, p)| (n.clone(), p.median)).collect();
        promise::order(first, overrides, &declared, &medians)
    } else {
        (0..declared.len()).collect()
    };
    let explained = d.explain_in_order(first, declared, order, seed, (z_base, e_base), (f64::NEG_INFINITY, strong))?;
    let mut runs = rank(explained, strong);
    let (mut candidates, mut verdict, mut named_alone) =
        judge(&runs, &mismatch, &base.summary, (&md_problem, &md), settings, (z_base, z_md));
    let mut discovery = None;
    if let Some(discoverer) = analysis.setup.discoverer().filter(|_| discover::wanted(settings.discover, &verdict)) {
        let names = base_problem.simulator.parameter_names();
        let theta = names.iter().map(|n| base.summary.parameters[n].median).collect();
        let (report, proposals) = discover::screen(discoverer, &base_problem, theta)?;
        let leader = runs.iter().map(|r| r.result.log_evidence).fold(f64::NEG_INFINITY, f64::max);
        let found = d.explain(first, proposals, seed.wrapping_add(500), (z_base, e_base), (leader, strong))?;
        runs.extend(found);
        runs = rank(runs, settings.strong_log_bf);
        (candidates, verdict, named_alone) =
            judge(&runs, &mismatch, &base.summary, (&md_problem, &md), settings, (z_base, z_md));
        discovery = Some(report);
    }
    if scouting.is_some() {
        let mut full = vec![false; runs.len()];
        let (mut base_full, mut md_full) = (false, false);
        // Twice at most: a first refinement may move the verdict onto fits still scouted.
        for _ in 0..2 {
            let base_p = p_value(base.summary.fit.chi2, base.summary.fit.dof);
            let need =
                precision::needed(&runs, &verdict, settings, (z_base, e_base), (z_md, e_md), base_p, settings.repair);
            let todo: Vec<usize> = need.candidates.iter().copied().filter(|i| !full[*i]).collect();
            if todo.is_empty() && (!need.base || base_full) && (!need.md || md_full) {
                break;
            }
            if need.base && !base_full {
                (base_problem, base) = d.calibrate(analysis, None, seed, "base_no_md")?;
                (z_base, e_base) = evidence(&base.summary);
                base_full = true;
            }
            if need.md && !md_full {
                (md_problem, md) = d.calibrate(analysis, Some(settings.kernel), seed.wrapping_add(1), "base_md")?;
                (z_md, e_md) = evidence(&md.summary);
                md_full = true;
            }
            for i in todo {
                if let Some(refit) = refit(&d, analysis, &runs[i], &verdict, (z_base, e_base))? {
                    runs[i] = refit;
                }
                full[i] = true;
            }
            for r in runs.iter_mut() {
                r.result.log_bayes_factor = r.result.log_evidence - z_base;
                r.result.log_bayes_factor_err = r.result.log_evidence_err.hypot(e_base);
            }
            mismatch = locate(&md_problem, &md, &base_problem, &base);
            let order: Vec<String> = runs.iter().map(|r| r.result.name.clone()).collect();
            runs = rank(runs, strong);
            full = runs.iter().map(|r| full[order.iter().position(|n| *n == r.result.name).unwrap_or(0)]).collect();
            (candidates, verdict, named_alone) =
                judge(&runs, &mismatch, &base.summary, (&md_problem, &md), settings, (z_base, z_md));
        }
        for (c, f) in candidates.iter_mut().zip(&full) {
            c.scout = !f;
        }
    }
    // A partial explanation: the leader with δ on top, as one of the compared models.
    let mut with_delta = None;
    if partial::worth_trying(&candidates, &verdict, &base.summary, settings) {
        let fit = d.calibrate(
            &analysis.with_candidate(&runs[0].candidate),
            Some(settings.kernel),
            seed.wrapping_add(99),
            partial::FIT_NAME,
        )?;
        let largest = |f: &FitFigures| f.delta_max_sigma.values().copied().fold(0.0, f64::max);
        let weighed = partial::Weighed {
            candidates: &candidates,
            share: explained_share(&candidates[0], &base.summary),
            base_chi2_per_dof: base.summary.fit.chi2_per_dof,
            mismatch: &mismatch,
            z_base,
            z_md: (z_md, e_md),
            delta_md: largest(&figures("model + MD", &md_problem, &md)),
        };
        let shown = figures(&format!("model + {} + MD", runs[0].candidate.name), &fit.0, &fit.1);
        if let Some(v) = partial::verdict(&weighed, &shown, settings) {
            verdict = v;
            named_alone = true;
        }
        with_delta = Some(fit);
    }
    if let Some(report) = &discovery {
        discover::word(&mut verdict, report);
    }

    // Repair: refit the winner with MD on top, to show δ shrink.
    let mut improvement = None;
    let mut repaired_md = None;
    if named_alone && settings.repair {
        let winner = &runs[0];
        let (rep_md_problem, rep_md) = match with_delta {
            Some(fit) => fit,
            None => d.calibrate(
                &analysis.with_candidate(&winner.candidate),
                Some(settings.kernel),
                seed.wrapping_add(99),
                partial::FIT_NAME,
            )?,
        };
        let before = vec![figures("model, no MD", &base_problem, &base), figures("model + MD", &md_problem, &md)];
        let after = vec![
            figures(&format!("model + {}", winner.candidate.name), &winner.problem, &winner.calibration),
            figures(&format!("model + {} + MD", winner.candidate.name), &rep_md_problem, &rep_md),
        ];
        // A partial explanation's answer is the fit with δ kept for the rest.
        let answer = usize::from(verdict.best == "partial");
        let (answer_problem, answer_fit) =
            if answer == 1 { (&rep_md_problem, &rep_md) } else { (&winner.problem, &winner.calibration) };
        let interval_narrowing = base_problem
            .simulator
            .parameter_names()
            .iter()
            .map(|n| (n.clone(), md.summary.parameters[n].width95() / answer_fit.summary.parameters[n].width95()))
            .collect();
        // The Cramér–Rao limit is of θ alone, without δ's hyperparameters.
        let information_limit =
            if answer == 0 { information_limit(answer_problem, answer_fit, &md) } else { BTreeMap::new() };
        let truth = winner.problem.analysis.truth_values();
        improvement = Some(Improvement { before, after, interval_narrowing, information_limit, truth, answer });
        repaired_md = Some(rep_md);
    }
    let diagnosis = Diagnosis {
        mismatch,
        candidates,
        verdict,
        improvement,
        base_log_evidence: z_base,
        md_log_evidence: z_md,
        discovery,
        profile: d.profile(),
        provenance: base_problem.provenance(seed, "diagnose"),
    };
    if let Some(dir) = out {
        artifacts::write_json_atomic(&dir.join("diagnosis.json"), &diagnosis)?;
    }
    let candidates = runs.into_iter().map(|r| (r.candidate.name, r.calibration)).collect();
    Ok(DiagnoseRun { diagnosis, base: Some(base), md: Some(md), candidates, repaired_md })
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
    let Some(sd) = calibrate::results::fisher::cramer_rao_sd(lik, &theta, &steps) else {
        return BTreeMap::new();
    };
    names
        .iter()
        .zip(&sd)
        .filter_map(|(n, s)| md.summary.parameters.get(n).map(|p| (n.clone(), p.width95() / (2.0 * 1.959964 * s))))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Candidates of these log evidences, each fitting adequately, errors 0.1.
    pub(super) fn ranked(evidences: &[(&str, f64)]) -> Vec<CandidateResult> {
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
                prior_log_odds: 0.0,
                special_case_of: Vec::new(),
                own_emulator: true,
                same_fit_as: Vec::new(),
                same_fit_as_md: false,
                scout: false,
                stopped_at_beta: None,
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
        // A correction of the output has no emulator of its own: the model's is the one to refine.
        r[0].own_emulator = false;
        let standing: Vec<&CandidateResult> =
            std::iter::once(&r[0]).chain(rivals(&r[0], &r, &DiagnoseSettings::default())).collect();
        assert!(to_refine(&standing).is_empty());
        let text = emulator_limited_statement(&r[0], &[], &[], 1e-3);
        assert!(text.contains("Refine the model's emulator") && !text.contains("variant"), "{text}");
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

    #[test]
    fn a_special_case_the_data_allow_is_named_for_the_form_it_is_within() {
        // The ball drop's case: c*abs(v)^p leads c*v*abs(v) by 0.2 with p = 1.76 [1.53, 2.06].
        let p = |lo: f64, hi: f64| ParamSummary::from_draws(&[lo, 0.5 * (lo + hi), hi]);
        let mut r = ranked(&[("power_v_on_v", 0.0), ("signed_square_v_on_v", -0.2), ("periodic_on_v", -22.0)]);
        r[0].parameters.insert("p".into(), p(1.53, 2.06));
        r[1].special_case_of = vec![SpecialCase { of: "power_v_on_v".into(), parameter: "p".into(), value: 2.0 }];
        let order = |r: &[CandidateResult]| occam(&r.iter().collect::<Vec<_>>(), 3.0);
        assert_eq!(order(&r), 1, "the square is named");
        assert!(rivals(&r[1], &r, &DiagnoseSettings::default()).is_empty(), "the free power is no rival of it");
        // Where the data put p away from 2, the two are rivals and the better leads.
        r[0].parameters.insert("p".into(), p(2.2, 2.9));
        assert_eq!(order(&r), 0);
        assert_eq!(rival_names(&r), ["signed_square_v_on_v"]);
    }

    #[test]
    fn readings_of_one_fit_are_one_explanation_unless_declared_and_separable() {
        let suggestion = |repeats: Option<usize>| Suggestion {
            observable: "y".into(),
            x: 5.0,
            error: 0.1,
            candidates: ["a".into(), "b".into()],
            predicted_mean: [1.0, 1.3],
            predicted_sd: [0.05, 0.05],
            repeats,
            expected_gain: [4.0, 4.0],
        };
        let mut r = ranked(&[("a", 0.0), ("b", -1.9)]);
        // Not the same fit: another explanation, whatever the measurements.
        assert!(!decide::one_explanation(&r[0], &r[1], || None));
        r[0].same_fit_as = vec!["b".into()];
        // Declared alternatives that fit alike: rivals while a measurement in reach separates them.
        assert!(!decide::one_explanation(&r[0], &r[1], || Some(suggestion(Some(12)))));
        assert!(decide::one_explanation(&r[0], &r[1], || Some(suggestion(None))));
        assert!(decide::one_explanation(&r[0], &r[1], || None));
        // Discovered readings: the prior over forms ranks them; one explanation either way.
        r[0].prior_log_odds = -4.4;
        r[1].prior_log_odds = -6.7;
        assert!(decide::one_explanation(&r[0], &r[1], || Some(suggestion(Some(12)))));
        // A declared candidate beside a discovered one is still the user's alternative.
        r[1].prior_log_odds = 0.0;
        assert!(!decide::one_explanation(&r[0], &r[1], || Some(suggestion(Some(12)))));
    }

    #[test]
    fn of_two_discovered_readings_of_one_fit_the_simpler_is_named_unless_the_other_leads_by_the_margin() {
        // The ball drop's case: c*h^2*v^2 leads the drag c*v^2 by 1.8 on one fall.
        let mut r = ranked(&[("square_h_square_v_on_v", 0.0), ("square_v_on_v", -1.8), ("periodic_on_v", -40.0)]);
        let odds = [-7.9, -5.2, -6.0];
        for (c, o) in r.iter_mut().zip(odds) {
            c.prior_log_odds = o;
            c.parameters.insert("c".into(), ParamSummary::from_draws(&[1.0, 2.0, 3.0]));
        }
        r[0].same_fit_as = vec!["square_v_on_v".into()];
        r[1].same_fit_as = vec!["square_h_square_v_on_v".into()];
        let order = |r: &[CandidateResult]| occam(&r.iter().collect::<Vec<_>>(), 3.0);
        assert_eq!(order(&r), 1, "the simpler reading is named");
        assert!(rivals(&r[1], &r, &DiagnoseSettings::default()).is_empty(), "the other reading is no rival");
        // Leading by more than the margin, the richer reading is named.
        r[1].log_evidence = -3.5;
        assert_eq!(order(&r), 0);
        // Not the same fit: two explanations, and the better leads.
        r[1].log_evidence = -1.8;
        r[0].same_fit_as.clear();
        r[1].same_fit_as.clear();
        assert_eq!(order(&r), 0);
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
