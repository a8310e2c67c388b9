//! The decision rule (see the module above): which candidate is named, who
//! still stands against it, and when the verdict rests on an emulator.

use super::*;

/// The single candidates a candidate combines: `a+b` → {a, b}.
pub(super) fn members(name: &str) -> std::collections::BTreeSet<&str> {
    name.split('+').collect()
}

/// Whether `inner` is `outer` made simpler: fewer of its members (a of
/// a+b), or one of its parameters fixed at a value the data leave inside
/// that parameter's 95% interval (`c*v*abs(v)` of `c*abs(v)^p` with p
/// covering 2). Either way the two are one explanation, not rivals.
pub(super) fn within(inner: &CandidateResult, outer: &CandidateResult) -> bool {
    let (i, o) = (members(&inner.name), members(&outer.name));
    (i.len() < o.len() && i.is_subset(&o))
        || simpler_reading(inner, outer)
        || inner
            .special_case_of
            .iter()
            .any(|s| s.of == outer.name && outer.parameters.get(&s.parameter).is_some_and(|p| p.covers(s.value)))
}

/// Index of the candidate to name among `ranked` (best evidence first): the
/// best, unless a candidate within it comes within `strong` of it; then
/// that one (the best such), and so on down.
pub(super) fn occam(ranked: &[&CandidateResult], strong: f64) -> usize {
    let mut chosen = 0;
    while let Some((i, _)) = ranked
        .iter()
        .enumerate()
        .filter(|(_, r)| within(r, ranked[chosen]) && ranked[chosen].log_evidence - r.log_evidence <= strong)
        .max_by(|a, b| a.1.log_evidence.total_cmp(&b.1.log_evidence))
    {
        chosen = i;
    }
    chosen
}

/// The best alternative to `winner` among `ranked`: a candidate that does not
/// contain it (a+b is the winner a with more, not another explanation) and
/// is not another reading of its fit (those are read beside it).
pub(super) fn runner_up<'c>(winner: &CandidateResult, ranked: &'c [CandidateResult]) -> Option<&'c CandidateResult> {
    let mine = members(&winner.name);
    ranked
        .iter()
        .find(|c| c.name != winner.name && !mine.is_subset(&members(&c.name)) && !winner.same_fit_as.contains(&c.name))
}

/// The best candidate, when it beats the base model by more than
/// `strong_log_bf`, fits adequately and is not itself beaten by the MD fit
/// by more than `strong_log_bf`. A discovered term's evidence carries the
/// search's prior odds against the base model (the look-elsewhere price
/// that keeps nulls clean); against the MD fit it is weighed without them:
/// that check asks whether the term captures what δ captured (fit and
/// Occam factor), not how many terms were tried, and a flexible δ that fits
/// as well is no reason to withhold the term that says what δ was. With the
/// price charged there too, a term fitting at χ²/dof 0.55 lost to δ by 3.1
/// (a T⁴ radiation term at 20σ; docs/diagnose.md).
pub(super) fn named_candidate<'c>(
    candidates: &'c [CandidateResult],
    settings: &DiagnoseSettings,
    z_md: f64,
) -> Option<&'c CandidateResult> {
    candidates.first().filter(|c| {
        c.log_bayes_factor > settings.strong_log_bf
            && c.p_value >= settings.min_p_value
            && c.log_evidence - c.prior_log_odds > z_md - settings.strong_log_bf
    })
}

/// The other explanations `best` does not beat decisively: candidates that
/// neither contain it nor are within it (Occam's rule settled those),
/// fit adequately, and trail it by no more than `strong_log_bf` plus twice
/// the Monte Carlo error of the difference.
pub(super) fn rivals<'c>(
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
            !mine.is_subset(&theirs) && !theirs.is_subset(&mine) && !within(c, best) && !within(best, c)
        })
        .filter(|c| best.log_evidence - c.log_evidence <= decisive_lead(best, c, settings))
        .collect()
}

/// The lead in log evidence of `a` over `b` that names `a` alone:
/// `strong_log_bf` plus twice the Monte Carlo error of the difference.
pub(super) fn decisive_lead(a: &CandidateResult, b: &CandidateResult, settings: &DiagnoseSettings) -> f64 {
    let err = (a.log_evidence_err.powi(2) + b.log_evidence_err.powi(2)).sqrt();
    settings.strong_log_bf + 2.0 * if err.is_finite() { err } else { 0.0 }
}

/// Whether `rival` is another reading of `best`'s fit (`same_fit_as`)
/// rather than another explanation. Two discovered terms that fit alike are
/// one explanation: the prior over forms, which the data then leave as it
/// was, already ranks them, and the verdict names the more probable and
/// reads the other beside it ("here equal to ..."). A declared candidate is
/// the user's own alternative at even prior odds: fitting alike, it stays a
/// rival while a measurement in reach (`separating`: one within the
/// prediction range and `MAX_REPEATS`) would tell the two apart, so that the
/// verdict is `ambiguous` and proposes that measurement (the simple
/// machine's saturation and quadratic loss).
pub(super) fn one_explanation(
    best: &CandidateResult,
    rival: &CandidateResult,
    separating: impl FnOnce() -> Option<Suggestion>,
) -> bool {
    if !best.same_fit_as.contains(&rival.name) {
        return false;
    }
    (discovered(best) && discovered(rival)) || separating().is_none_or(|s| s.repeats.is_none())
}

/// Whether `inner` is a simpler reading of `outer`'s fit: both discovered,
/// the same fit on these data, `inner` with no more parameters and fewer
/// operations (higher prior odds over forms). Then `outer` must earn its
/// place by Occam's margin, as a form that contains `inner` must: on one
/// fall of a ball `c*h^2*v^2` is the same fit as the drag `c*v^2` (the
/// height is a function of the speed there), and leading it by less than
/// the margin it is the drag that is named, with the other read beside it.
fn simpler_reading(inner: &CandidateResult, outer: &CandidateResult) -> bool {
    discovered(inner)
        && discovered(outer)
        && inner.same_fit_as.contains(&outer.name)
        && inner.parameters.len() <= outer.parameters.len()
        && inner.prior_log_odds > outer.prior_log_odds
}

/// A discovered term pays the search's prior odds (`prior_log_odds` < 0);
/// a declared candidate pays none.
pub(super) fn discovered(c: &CandidateResult) -> bool {
    c.prior_log_odds < 0.0
}

/// The verdict: a named candidate, "ambiguous", "unexplained" or "none" (see
/// the module docs).
#[allow(clippy::too_many_arguments)]
pub(super) fn decide(
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
    let prob = probability(candidates, (z_base, z_md));
    // A δ not computed (NaN) is never the worst: total_cmp would rank it above every number.
    let size = |m: &ObservableMismatch| if m.max_sigma.is_nan() { f64::NEG_INFINITY } else { m.max_sigma };
    let worst = mismatch.iter().max_by(|a, b| size(a).total_cmp(&size(b)));
    let verdict = |best: &str, statement: String, confidence: f64| Verdict {
        best: best.into(),
        standing: Vec::new(),
        suggestion: None,
        refine: Vec::new(),
        statement,
        confidence,
        explained_share: None,
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
            explained_share: None,
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
                statement: ambiguous_statement(&standing, suggestion.as_ref(), mismatch, settings.strong_log_bf)
                    + &same_fit_phrase(c, candidates),
                confidence: standing.iter().map(|s| prob(s.log_evidence)).sum(),
                standing: standing.iter().map(|s| s.name.clone()).collect(),
                suggestion,
                refine: Vec::new(),
                explained_share: None,
            }
        }
        Some(c) => {
            // What a reader means by confidence in "the data need c": the
            // probability of every model that contains c, pairs included,
            // and of the other readings of the same fit, δ's among them
            // when the model-discrepancy fit draws c's curve.
            let needed = explanation_probability(c, candidates, (z_base, z_md));
            if needed < MIN_NAMED_PROBABILITY {
                // Ahead of every other candidate, but less probable than not:
                // the model-discrepancy fit stays the more probable account.
                let statement = format!(
                    "{}the best candidate, {} (log BF {:.1} against the model as it is, χ²/dof {:.2}), has posterior probability {:.3}, below one half, and the model-discrepancy fit {:.3}: it is not named; the model-discrepancy fit (log BF = {:.1} against no MD) stays the honest answer.",
                    mismatch_phrase(mismatch),
                    c.name,
                    c.log_bayes_factor,
                    c.chi2_per_dof,
                    needed,
                    prob(z_md),
                    z_md - z_base
                );
                let share = explained_share(c, base);
                let statement = statement + &share_phrase(share, c, base, " Its fit", ", the rest left to δ.");
                return Verdict { explained_share: share, ..verdict("unexplained", statement, prob(z_md)) };
            }
            let mut statement = named_statement(c, &runs[0].candidate, runner_up(c, candidates), mismatch);
            statement.push_str(&same_fit_phrase(c, candidates));
            statement.push_str(&same_as_md_phrase(c, z_md));
            let share = explained_share(c, base);
            statement.push_str(&share_phrase(share, c, base, " It", "."));
            Verdict { explained_share: share, ..verdict(&c.name, statement, needed) }
        }
        None if significant => {
            let w = worst
                .map(|w| format!("{} deviates by up to {:.1}σ (at x = {:.3}); ", w.observable, w.max_sigma, w.x_at_max))
                .unwrap_or_default();
            let b = best.map(|c| format!("the best candidate, {}, reaches χ²/dof = {:.2} (p = {:.1e}) and log BF = {:.1} against the model; ", c.name, c.chi2_per_dof, c.p_value, c.log_bayes_factor)).unwrap_or_default();
            let share = best.and_then(|c| explained_share(c, base));
            let partial =
                best.map(|c| share_phrase(share, c, base, " Its fit", ", the rest left to δ.")).unwrap_or_default();
            let statement = format!("a mismatch that no candidate explains: {w}{b}the model-discrepancy fit (log BF = {:.1} against no MD) stays the honest answer.{partial}", z_md - z_base);
            Verdict { explained_share: share, ..verdict("unexplained", statement, prob(z_md)) }
        }
        None => {
            let candidates = match best {
                Some(c) => format!("no candidate is favoured (best log BF = {:.1})", c.log_bayes_factor),
                None => "no candidate was weighed".to_string(),
            };
            let statement = format!(
                "no significant mismatch: δ is consistent with zero (largest posterior-mean |δ| = {:.1}σ), the model alone fits with χ²/dof = {:.2}, and {candidates}.",
                worst.map(|w| w.max_sigma).unwrap_or(0.0),
                base.fit.chi2_per_dof,
            );
            verdict("none", statement, prob(z_base))
        }
    }
}

/// Posterior model probability of a log evidence, with equal prior odds
/// among the model as it is, the model + δ and the candidates.
fn probability(candidates: &[CandidateResult], (z_base, z_md): (f64, f64)) -> impl Fn(f64) -> f64 {
    let mut all_z = vec![z_base, z_md];
    all_z.extend(candidates.iter().map(|k| k.log_evidence));
    let lse = crate::engine::calibrate::sampler::smc::log_sum_exp(&all_z);
    move |z: f64| (z - lse).exp()
}

/// The posterior probability, with equal prior odds among the model as it
/// is, the model + δ and the candidates (a discovered term's prior odds in
/// its evidence), of the models that hold `c`'s explanation: every model
/// containing c, pairs included, the other readings of its fit, and the
/// model + δ when it draws c's curve (`same_fit_as_md`).
pub(super) fn explanation_probability(
    c: &CandidateResult,
    candidates: &[CandidateResult],
    (z_base, z_md): (f64, f64),
) -> f64 {
    let prob = probability(candidates, (z_base, z_md));
    let mine = members(&c.name);
    let holding: f64 = candidates
        .iter()
        .filter(|k| mine.is_subset(&members(&k.name)) || c.same_fit_as.contains(&k.name))
        .map(|k| prob(k.log_evidence))
        .sum();
    holding + if c.same_fit_as_md { prob(z_md) } else { 0.0 }
}

/// The share of the model's excess χ² (χ² over its degrees of freedom, at
/// the fit without MD) that `c`'s fit removes, in [0, 1]; `None` when the
/// model has no excess. The candidate's χ² is read off its χ²/dof with its
/// own degrees of freedom (the same data, its own parameters).
pub(super) fn explained_share(c: &CandidateResult, base: &Summary) -> Option<f64> {
    let model = (base.fit.chi2, base.fit.dof, base.parameters.len());
    share_of_excess(model, (c.chi2_per_dof, c.parameters.len()))
}

/// `explained_share` from the model's (χ², dof, parameters) and the
/// candidate's (χ²/dof, parameters) over the same points.
fn share_of_excess((chi2, dof, p): (f64, usize, usize), (chi2_per_dof, own_p): (f64, usize)) -> Option<f64> {
    let excess = chi2 - dof as f64;
    if !(excess > 0.0 && chi2_per_dof.is_finite()) {
        return None;
    }
    let own_dof = ((dof + p) as f64 - own_p as f64).max(1.0);
    Some(((chi2 - chi2_per_dof * own_dof) / excess).clamp(0.0, 1.0))
}

/// " It removes 85% of the model's excess χ² (χ²/dof 33.10 → 10.20)." in words.
fn share_phrase(share: Option<f64>, c: &CandidateResult, base: &Summary, subject: &str, end: &str) -> String {
    share.map_or_else(String::new, |s| {
        format!(
            "{subject} removes {:.0}% of the model's excess χ² (χ²/dof {:.2} → {:.2}){end}",
            100.0 * s,
            base.fit.chi2_per_dof,
            c.chi2_per_dof
        )
    })
}

/// No verdict names a candidate whose explanation (every model that
/// contains it, and the other readings of its fit) is less probable than not.
pub const MIN_NAMED_PROBABILITY: f64 = 0.5;

/// " On these data it is the same fit as X (what X is): one explanation, read two ways."
pub(super) fn same_fit_phrase(c: &CandidateResult, candidates: &[CandidateResult]) -> String {
    let others: Vec<String> = candidates
        .iter()
        .filter(|k| c.same_fit_as.contains(&k.name))
        .map(|k| format!("{} ({})", k.name, k.description))
        .collect();
    if others.is_empty() {
        return String::new();
    }
    format!(
        " On these data it is the same fit as {}: one explanation, read {} ways, which data over a wider range would tell apart.",
        others.join(" and "),
        others.len() + 1
    )
}

/// " The model-discrepancy fit draws the same curve …" when it does.
fn same_as_md_phrase(c: &CandidateResult, z_md: f64) -> String {
    if !c.same_fit_as_md {
        return String::new();
    }
    let lead = c.log_evidence - z_md;
    let (by, side) = if lead < 0.0 { (-lead, "above") } else { (lead, "below") };
    format!(
        " The model-discrepancy fit draws the same curve at the data, log BF {by:.1} {side} this term: δ reads as this term's effect without a law, one explanation whose probability counts for it."
    )
}

/// Whether a fit rests on its emulator: the emulator's share of the
/// predictive variance at the data is above one half.
pub(super) fn rests_on_emulator(c: &CandidateResult) -> bool {
    c.emulator_share > EMULATOR_DOMINATES
}

/// When the leader beats the base model strongly but was not named (its fit
/// fails the χ² test or the MD fit beats it) while resting on its emulator:
/// the leader and every other such candidate within a decisive lead of it.
/// Their χ² and evidence are then set by the emulator's error, not the data,
/// so rejecting them would be as unfounded as naming them; only refinement
/// can decide (a coarse emulator's mean can miss by more than its sd, and a
/// χ²/dof of 2 at 98% emulator share says exactly that).
pub(super) fn unnamed_on_emulator<'c>(
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
pub(super) fn to_refine(standing: &[&CandidateResult]) -> Vec<String> {
    standing.iter().filter(|s| s.own_emulator && rests_on_emulator(s)).map(|s| s.name.clone()).collect()
}

#[cfg(test)]
mod tests {
    use super::{explanation_probability, same_as_md_phrase, share_of_excess};
    use crate::engine::diagnose::tests::ranked;

    #[test]
    fn delta_drawing_the_candidates_curve_counts_for_the_candidate() {
        // The decay counter's background set 4 (log evidences as measured):
        // the model as it is at -270.16, model + δ at -167.56, the
        // discovered offset at -168.89 (its prior log odds -1.04 included)
        // and the square loss at -176.44.
        let mut c = ranked(&[("offset_of_rate", -168.89), ("square_loss_of_rate", -176.44)]);
        let z = (-270.16, -167.56);
        // δ a rival: the offset holds 0.209 of the probability, below one half.
        let rival = explanation_probability(&c[0], &c, z);
        let expected = 1.0 / (1.0 + (1.33f64).exp() + (-7.55f64).exp());
        assert!((rival - expected).abs() < 1e-9 && rival < 0.5, "{rival} against {expected}");
        // δ draws the offset's curve: one explanation, all but the square loss's share.
        c[0].same_fit_as_md = true;
        let one = explanation_probability(&c[0], &c, z);
        let rest = (-7.55f64).exp() / (1.0 + (1.33f64).exp() + (-7.55f64).exp());
        assert!((one - (1.0 - rest)).abs() < 1e-9, "{one}");
        let phrase = same_as_md_phrase(&c[0], z.1);
        assert!(phrase.contains("same curve") && phrase.contains("log BF 1.3 above this term"), "{phrase}");
        assert_eq!(same_as_md_phrase(&c[1], z.1), "", "the square loss draws its own curve");
        // A pair holding the candidate counts for it, an unrelated candidate never.
        let with_pair = ranked(&[("a", 0.0), ("a+b", 0.0), ("b", 0.0)]);
        let p = explanation_probability(&with_pair[0], &with_pair, (f64::NEG_INFINITY, f64::NEG_INFINITY));
        assert!((p - 2.0 / 3.0).abs() < 1e-12, "{p}");
    }

    #[test]
    fn the_share_of_the_excess_chi2_a_candidate_removes() {
        // 52 points, 2 parameters: χ² 150 against 50 dof, an excess of 100.
        // A candidate with one more parameter at χ²/dof 1.4 (χ² 49 × 1.4 = 68.6) removes 81.4%.
        let share = share_of_excess((150.0, 50, 2), (1.4, 3)).unwrap();
        assert!((share - (150.0 - 68.6) / 100.0).abs() < 1e-12, "{share}");
        // As good as the data allow, or better by chance: all of it; worse than the model: none.
        assert_eq!(share_of_excess((150.0, 50, 2), (0.9, 3)), Some(1.0));
        assert_eq!(share_of_excess((150.0, 50, 2), (3.5, 3)), Some(0.0));
        // No excess to explain, or no fit: no share.
        assert_eq!(share_of_excess((45.0, 50, 2), (0.8, 3)), None);
        assert_eq!(share_of_excess((150.0, 50, 2), (f64::NAN, 3)), None);
    }
}
