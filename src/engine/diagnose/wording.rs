//! The verdict in words, and the diagnosis as the terminal shows it.

use super::*;

/// "…the data cannot yet choose between A (…) and B (…): …; to separate them, measure …".
pub(super) fn ambiguous_statement(
    standing: &[&CandidateResult],
    suggestion: Option<&Suggestion>,
    mismatch: &[ObservableMismatch],
    strong: f64,
) -> String {
    let who: Vec<String> = standing
        .iter()
        .map(|c| {
            let fitted: Vec<String> = c.parameters.iter().map(|(n, p)| format!("{n} = {}", p.interval())).collect();
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

/// The observable where the emulator carries the largest share ("" when none does).
pub(super) fn worst_share_observable(fit: &crate::engine::calibrate::results::summary::FitQuality) -> String {
    fit.per_observable_share
        .iter()
        .filter(|(_, v)| **v > 0.0)
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map(|(k, _)| k.clone())
        .unwrap_or_default()
}

/// "…the data lead to X, but its emulator carries N% of the variance: refine …".
pub(super) fn emulator_limited_statement(
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
    // Corrections of the output share the model's emulator: that is the one to refine.
    let advice = if refine.is_empty() {
        "Refine the model's emulator with runs where the posterior lies (`mdpipe run` with `[run.refine]`, or `mdpipe refine`), then diagnose again.".to_string()
    } else {
        format!(
            "Refine the variant emulator{} of {} with runs where {} posterior{} lie{} (`mdpipe run` with `[run.refine] variant_budget`, or `refine::variant`), then diagnose again.",
            if refine.len() > 1 { "s" } else { "" },
            refine.join(" and "),
            if refine.len() > 1 { "their" } else { "its" },
            if refine.len() > 1 { "s" } else { "" },
            if refine.len() > 1 { "" } else { "s" },
        )
    };
    format!(
        "{}the data lead to {} (log BF {:.1} ± {:.1} against the model as it is), but the emulator's uncertainty is {:.0}% of that fit's predictive variance at the data{}, so the emulator, not the data, decides how well it fits{poor}: no candidate is named. {advice}",
        mismatch_phrase(mismatch),
        c.name,
        c.log_bayes_factor,
        c.log_bayes_factor_err,
        100.0 * c.emulator_share,
        if c.emulator_share_observable.is_empty() { String::new() } else { format!(" in {}", c.emulator_share_observable) },
    )
}

/// "…the data favour X (what it is), k = … over the runner-up by log BF = …".
pub(super) fn named_statement(
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
                "{n} = {}{}",
                p.interval(),
                if spec.units.is_empty() { String::new() } else { format!(" {}", spec.units) }
            )
        })
        .collect();
    let fitted = if fitted.is_empty() { "with no free parameter of its own".to_string() } else { fitted.join(", ") };
    let trend = mismatch_phrase(mismatch);
    let runner = runner_up
        .map(|r| {
            // A runner-up stopped early carries an upper estimate of its evidence.
            let relation = if r.stopped_at_beta.is_some() { "≥" } else { "=" };
            format!(" over {} by log BF {relation} {:.1}", r.name, c.log_evidence - r.log_evidence)
        })
        .unwrap_or_default();
    format!(
        "{trend}the data favour {} ({}), {fitted}{runner}; against the model as it is, log BF = {:.1}.",
        c.name.replace('_', " "),
        c.description,
        c.log_bayes_factor
    )
}

/// Plain-text summary for the terminal.
pub fn print(d: &Diagnosis) {
    crate::base::messages::say!("Locate (model + MD; δ in units of the measurement error):");
    for m in &d.mismatch {
        let show = |rs: &[Region]| -> String {
            if rs.is_empty() {
                "no region".into()
            } else {
                rs.iter().map(|r| format!("[{:.2}, {:.2}] {}", r.x_from, r.x_to, r.sign)).collect::<Vec<_>>().join(", ")
            }
        };
        let largest = if m.max_sigma.is_nan() {
            "not computed (the MD fit's posterior-mean δ)".to_string()
        } else {
            format!("{:>5.1}σ at x = {:.2}", m.max_sigma, m.x_at_max)
        };
        crate::base::messages::say!(
            "  {:<14} max |δ| = {largest}; δ ≠ 0 in {}; r = {:.2} [{:.2}, {:.2}]; no-MD χ²/n = {:.1}, misses in {}",
            m.observable,
            show(&m.regions),
            m.r.median,
            m.r.q025,
            m.r.q975,
            m.no_md_chi2 / m.no_md_dof as f64,
            show(&m.residual_regions)
        );
    }
    if d.base_log_evidence.is_finite() {
        crate::base::messages::say!(
            "Explain (log Bayes factor against the model without MD; log BF of the MD fit: {:.1}):",
            d.md_log_evidence - d.base_log_evidence
        );
    } else {
        crate::base::messages::say!(
            "Explain (the model as declared cannot be computed over the data: no fit of it, with or without MD; each candidate's log evidence):"
        );
    }
    if d.candidates.is_empty() && d.discovery.is_none() {
        crate::base::messages::say!(
            "  no candidates declared; the search for undeclared physics runs when a mismatch is unexplained (--discover, or [run] discover = true, asks for it always)"
        );
    }
    let width = d.candidates.iter().map(|c| c.name.chars().count()).max().unwrap_or(0).clamp(16, NAME_COLUMN);
    for c in &d.candidates {
        let share = if c.emulator_share > 0.0 {
            format!("   emulator share {:.0}% ({})", 100.0 * c.emulator_share, c.emulator_share_observable)
        } else {
            String::new()
        };
        let flag = match (c.stopped_at_beta, c.converged, c.scout) {
            (Some(beta), ..) => format!("   (stopped at β = {beta:.1e}: behind any decision)"),
            (None, false, _) => "   not converged".to_string(),
            (None, true, true) => "   (scout: far from any decision)".to_string(),
            _ => String::new(),
        };
        let (what, z, e) = if d.base_log_evidence.is_finite() {
            ("log BF", c.log_bayes_factor, c.log_bayes_factor_err)
        } else {
            ("log Z ", c.log_evidence, c.log_evidence_err)
        };
        // A stopped fit's evidence is an upper estimate: at most, not about.
        let (relation, error) = match c.stopped_at_beta {
            Some(_) => ("≤", "     ".to_string()),
            None => ("=", format!("± {e:.1}")),
        };
        crate::base::messages::say!(
            "  {} {what} {relation} {z:>8.1} {error}   χ²/dof = {:>6.2}{share}{flag}",
            name_column(&c.name, width),
            c.chi2_per_dof
        );
    }
    if d.candidates.iter().any(|c| !c.converged && c.stopped_at_beta.is_none()) {
        crate::base::messages::say!("  (not converged: its ESS or R̂ failed the check in its summary.json, so its log BF is less certain than the ± says;");
        crate::base::messages::say!("   parameters the data cannot tell apart keep a fit from converging; otherwise more particles or more final");
        crate::base::messages::say!(
            "   moves ([sampler.smc] particles, final_mixture_proposals, final_steps_per_dim) help)"
        );
    }
    if let Some(r) = &d.discovery {
        crate::base::messages::say!("Discover ({} terms from the model's own symbols screened in {:.1} s; the best calibrated, log BF above includes their prior odds):", r.searched, r.screening_seconds);
        for t in &r.screened {
            crate::base::messages::say!(
                "  {} {}   screening Δχ² = {:.1}, ΔBIC = {:.1}, prior odds 1:{:.0}",
                name_column(&t.name, width),
                t.formula,
                t.delta_chi2,
                t.delta_bic,
                (-t.prior_log_odds).exp()
            );
        }
    }
    crate::base::messages::say!("Verdict: {} ({})", d.verdict.best, d.verdict.confidence_phrase());
    crate::base::messages::say!("  {}", d.verdict.statement);
    if let Some(imp) = &d.improvement {
        // With MD the χ² is of η alone: what δ had to absorb, not the MD fit's misfit.
        crate::base::messages::say!("Repair (before → after; χ²/dof of the model part η alone, δ left out):");
        for f in imp.before.iter().chain(&imp.after) {
            let g: Vec<String> = f.parameters.iter().map(|(n, p)| format!("{n} = {}", p.interval())).collect();
            let dmax = f.delta_max_sigma.values().cloned().fold(0.0, f64::max);
            crate::base::messages::say!(
                "  {:<34} χ²/dof {:>6.2}  log Z {:>8.2}  max|δ| {:>4.1}σ  {}",
                f.label,
                f.chi2_per_dof,
                f.log_evidence,
                dmax,
                g.join(", ")
            );
            for piled in &f.piled_at_bounds {
                crate::base::messages::say!("    warning ({}): {piled}", f.label);
            }
        }
        for (n, r) in &imp.interval_narrowing {
            let limit = imp
                .information_limit
                .get(n)
                .map(|l| format!(" (the data's Cramér–Rao limit: {l:.1}x)"))
                .unwrap_or_default();
            let change = if *r >= 1.0 { format!("{r:.1}x narrower") } else { format!("{:.1}x wider", 1.0 / r) };
            crate::base::messages::say!(
                "  95% interval of {n}: {change} than with MD alone{limit}{}",
                imp.truth_coverage(n)
            );
        }
    }
}

/// The widest the name column of the candidate tables grows.
const NAME_COLUMN: usize = 40;

/// `name` padded to `width`; a longer one (each observable's correction
/// together) on a line of its own, the row going on beneath it.
fn name_column(name: &str, width: usize) -> String {
    if name.chars().count() <= width {
        format!("{name:<width$}")
    } else {
        format!("{name}\n  {:<width$}", "")
    }
}

/// Where the time went (`mdpipe diagnose --profile`): each fit, the
/// screening, and what the fits took together.
pub fn print_profile(d: &Diagnosis) {
    let fits: f64 = d.profile.iter().map(|f| f.seconds).sum();
    crate::base::messages::say!("Profile (wall seconds; {} fits, {fits:.1} s in all):", d.profile.len());
    if let Some(r) = &d.discovery {
        crate::base::messages::say!("  {:<40} {:>8.1} s", "screening of discovered terms", r.screening_seconds);
    }
    for f in &d.profile {
        crate::base::messages::say!(
            "  {:<40} {:>8.1} s  {:>6} particles  {:>10} evaluations",
            f.fit,
            f.seconds,
            f.particles,
            f.evaluations
        );
    }
}
