//! A partial explanation: the best candidate removes most of a mismatch but
//! not all of it. A real candidate is itself an approximation (a simulator's
//! electrolyte transport, a drag law fitted over a narrow range), so its
//! fit alone can fail the χ² test, or lose to the discrepancy fit, while
//! still being the physics the data ask for. The verdict "unexplained" then
//! throws the answer away; "partial" keeps it: the candidate with δ on top
//! for the rest, compared with the other models as one of them.
//!
//! The rule. When the verdict would be "unexplained", the leader c beats the
//! model as it is strongly, is not resting on its emulator, stands alone
//! (no rival within a decisive lead) and removes at least
//! `MIN_PARTIAL_SHARE` of the model's excess χ², the model + c + δ is
//! fitted. Its evidence joins the compared models (base, δ, each candidate).
//! c is named as a partial explanation when c + δ beats δ alone decisively
//! (`strong_log_bf` plus twice the Monte Carlo error of the difference) and
//! the models holding c (c, its pairs, c + δ) are more probable than not
//! (`MIN_NAMED_PROBABILITY`). Otherwise the verdict stays "unexplained".

use super::*;

/// The least share of the model's excess χ² a candidate must remove to be
/// weighed as a partial explanation: "most of the mismatch".
pub const MIN_PARTIAL_SHARE: f64 = 0.5;

/// The name under which the model + c + δ is fitted (the repair's fit of
/// the same model, so a partial verdict's repair reuses it).
pub(super) const FIT_NAME: &str = "repaired_md";

/// Whether the verdict's leader is worth a fit with δ on top (see the module docs).
pub(super) fn worth_trying(
    candidates: &[CandidateResult],
    verdict: &Verdict,
    base: &Summary,
    settings: &DiagnoseSettings,
) -> bool {
    let Some(c) = candidates.first() else { return false };
    verdict.best == "unexplained"
        && verdict.confidence.is_finite()
        && c.log_bayes_factor > settings.strong_log_bf
        && !rests_on_emulator(c)
        && rivals(c, candidates, settings).is_empty()
        && explained_share(c, base).is_some_and(|s| s >= MIN_PARTIAL_SHARE)
}

/// What the partial verdict weighs: the fits it compares c + δ with.
pub(super) struct Weighed<'a> {
    pub candidates: &'a [CandidateResult],
    /// The leader's share of the model's excess χ² (`explained_share`).
    pub share: Option<f64>,
    /// χ²/dof of the model as it is.
    pub base_chi2_per_dof: f64,
    pub mismatch: &'a [ObservableMismatch],
    /// Log evidence and its error of the model as it is and of the model + δ.
    pub z_base: f64,
    pub z_md: (f64, f64),
    /// Largest |δ|/σ over the observables, with δ alone.
    pub delta_md: f64,
}

/// The partial verdict on the leader, given the fit of model + leader + δ;
/// None when that fit does not earn it.
pub(super) fn verdict(w: &Weighed<'_>, with_delta: &FitFigures, settings: &DiagnoseSettings) -> Option<Verdict> {
    let c = w.candidates.first()?;
    let (z_cd, e_cd) = (with_delta.log_evidence, with_delta.log_evidence_err);
    let (z_md, e_md) = w.z_md;
    let err = e_cd.hypot(e_md);
    let margin = settings.strong_log_bf + 2.0 * if err.is_finite() { err } else { 0.0 };
    if z_cd - z_md <= margin {
        return None;
    }
    let mut all_z = vec![w.z_base, z_md, z_cd];
    all_z.extend(w.candidates.iter().map(|k| k.log_evidence));
    let lse = crate::engine::calibrate::sampler::smc::log_sum_exp(&all_z);
    let prob = |z: f64| (z - lse).exp();
    let mine = members(&c.name);
    let holding_c: f64 = w
        .candidates
        .iter()
        .filter(|k| mine.is_subset(&members(&k.name)) || c.same_fit_as.contains(&k.name))
        .map(|k| prob(k.log_evidence))
        .sum::<f64>()
        + prob(z_cd);
    if holding_c < MIN_NAMED_PROBABILITY {
        return None;
    }
    let share = w.share;
    let delta_after = with_delta.delta_max_sigma.values().copied().fold(0.0, f64::max);
    let statement = statement(w, c, share, (z_cd - z_md, holding_c), (w.delta_md, delta_after), settings);
    Some(Verdict {
        best: "partial".into(),
        standing: vec![c.name.clone()],
        suggestion: None,
        refine: Vec::new(),
        statement,
        confidence: holding_c,
        explained_share: share,
    })
}

/// "…c explains 85% of the mismatch; a residual remains (δ after)…" in words.
fn statement(
    w: &Weighed<'_>,
    c: &CandidateResult,
    share: Option<f64>,
    (lead_over_md, probability): (f64, f64),
    (delta_before, delta_after): (f64, f64),
    settings: &DiagnoseSettings,
) -> String {
    let why_not_all = if c.p_value < settings.min_p_value {
        format!("alone it fits with χ²/dof {:.2} (p = {:.1e})", c.chi2_per_dof, c.p_value)
    } else {
        format!("alone it loses to the model-discrepancy fit by log BF {:.1}", (w.z_md.0 - c.log_evidence).max(0.0))
    };
    format!(
        "{}a partial explanation: {} ({}) removes {:.0}% of the model's excess χ² (χ²/dof {:.2} → {:.2}; log BF {:.1} against the model as it is), but not all of it: {why_not_all}. With δ kept for the rest, model + {} + δ beats δ alone by log BF {:.1}, posterior probability {:.3}; the largest |δ| falls from {:.1}σ to {:.1}σ, the residual no candidate explains.",
        mismatch_phrase(w.mismatch),
        c.name.replace('_', " "),
        c.description,
        100.0 * share.unwrap_or(0.0),
        w.base_chi2_per_dof,
        c.chi2_per_dof,
        c.log_bayes_factor,
        c.name,
        lead_over_md,
        probability,
        delta_before,
        delta_after,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::diagnose::tests::ranked;

    /// The leader c at log evidence 40 (the model as it is at 0, δ alone at
    /// 50), removing 85% of the excess χ².
    fn weighed(candidates: &[CandidateResult]) -> Weighed<'_> {
        Weighed {
            candidates,
            share: Some(0.85),
            base_chi2_per_dof: 33.1,
            mismatch: &[],
            z_base: 0.0,
            z_md: (50.0, 0.1),
            delta_md: 11.0,
        }
    }

    fn with_delta(z: f64, err: f64, delta: f64) -> FitFigures {
        FitFigures {
            label: "model + c + MD".into(),
            chi2_per_dof: 1.0,
            log_evidence: z,
            log_evidence_err: err,
            parameters: BTreeMap::new(),
            delta_max_sigma: [("y".to_string(), delta)].into(),
            piled_at_bounds: Vec::new(),
        }
    }

    #[test]
    fn a_candidate_with_delta_on_top_that_beats_delta_alone_is_a_partial_explanation() {
        let mut c = ranked(&[("electrolyte", 40.0), ("heat", 10.0)]);
        c[0].p_value = 1e-9;
        c[0].chi2_per_dof = 10.2;
        let settings = DiagnoseSettings::default();
        let v = verdict(&weighed(&c), &with_delta(60.0, 0.1, 3.0), &settings).expect("named as partial");
        assert_eq!((v.best.as_str(), v.standing.as_slice()), ("partial", ["electrolyte".to_string()].as_slice()));
        // c + δ holds all but e^-10 of the probability; the statement gives the shares and δ before and after.
        assert!(v.confidence > 0.99, "{}", v.confidence);
        assert_eq!(v.explained_share, Some(0.85));
        for part in ["removes 85%", "33.10 → 10.20", "beats δ alone by log BF 10.0", "from 11.0σ to 3.0σ"] {
            assert!(v.statement.contains(part), "{part}: {}", v.statement);
        }
    }

    #[test]
    fn a_lead_over_delta_alone_short_of_decisive_leaves_the_mismatch_unexplained() {
        let c = ranked(&[("electrolyte", 40.0)]);
        let settings = DiagnoseSettings::default();
        // Ahead of δ alone by 2: not the strong margin of 3.
        assert!(verdict(&weighed(&c), &with_delta(52.0, 0.1, 3.0), &settings).is_none());
        // Ahead by 3.5 with errors 0.3 and 0.1: short of 3 + 2 × 0.32.
        assert!(verdict(&weighed(&c), &with_delta(53.5, 0.3, 3.0), &settings).is_none());
        assert!(verdict(&weighed(&c), &with_delta(53.7, 0.3, 3.0), &settings).is_some());
    }

    #[test]
    fn a_partial_explanation_less_probable_than_not_is_not_named() {
        // A rival model outside c (the other candidate at 60) holds most of the probability.
        let c = ranked(&[("electrolyte", 40.0), ("heat", 60.5)]);
        let settings = DiagnoseSettings::default();
        assert!(verdict(&weighed(&c), &with_delta(60.0, 0.1, 3.0), &settings).is_none());
    }
}
