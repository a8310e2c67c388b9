//! Evidence only as precise as the verdict needs. Every fit of a diagnosis
//! is first made as a scout (a quarter of the configured particles, few
//! final sweeps, no reruns for convergence), the verdict is decided on the scouts, and then
//! each fit the verdict turns on is made again with the configured
//! settings and the same seed, so that it is exactly the fit a full run
//! makes: every candidate whose lead or lag is within a few of its
//! standard errors of the decisive margin, the one it is compared with,
//! and the fits with and without MD where a comparison with them is
//! close. With the repair, the fits its before-and-after shows (the named
//! candidate, those it stands against, and the fits with and without MD)
//! are made in full too; without it (`--no-repair`, the blind tests) the
//! verdict is the whole answer. A candidate far behind keeps its scout,
//! and says so: its answer could not have changed the verdict.

use super::*;

/// A comparison within this many of its standard errors of a threshold
/// (and within `CLOSE_NATS` besides) is remade at full precision: a scout's
/// error of a few tenths leaves its side of the line uncertain.
const CLOSE_SIGMAS: f64 = 4.0;
const CLOSE_NATS: f64 = 2.0;
/// A base fit whose χ² p-value is below this share of `min_p_value` is a
/// significant mismatch however the scout's posterior median moves within
/// its error (a χ² of 2.0 per point over 80 points has p ≈ 1e-7).
const CLEAR_P_SHARE: f64 = 0.01;

/// The analysis as a scout samples it (`SamplerConfig::scout`); None where
/// scouting does not apply.
pub(super) fn scout(analysis: &Analysis) -> Option<Analysis> {
    let sampler = analysis.sampler.scout()?;
    Some(Analysis { sampler, ..analysis.clone() })
}

/// The fits a verdict turns on.
#[derive(Debug, Default, PartialEq)]
pub(super) struct Needed {
    /// Indices into the ranked runs.
    pub candidates: Vec<usize>,
    pub base: bool,
    pub md: bool,
}

/// Whether `a` and `b`, of standard errors `ea` and `eb`, sit within a
/// scout's reach of `threshold` apart.
fn close(a: f64, b: f64, threshold: f64, ea: f64, eb: f64) -> bool {
    let err = (ea * ea + eb * eb).sqrt();
    let err = if err.is_finite() { err } else { f64::INFINITY };
    ((a - b) - threshold).abs() <= CLOSE_SIGMAS * err + CLOSE_NATS
}

/// Which scouted fits the verdict turns on (`repair`: the winner will be
/// repaired, and its before-and-after shows the fits with and without MD).
pub(super) fn needed(
    runs: &[CandidateRun],
    verdict: &Verdict,
    settings: &DiagnoseSettings,
    (z_base, e_base): (f64, f64),
    (z_md, e_md): (f64, f64),
    base_p_value: f64,
    repair: bool,
) -> Needed {
    let strong = settings.strong_log_bf;
    let index = |name: &str| runs.iter().position(|r| r.result.name == name);
    let mut standing: Vec<usize> = match verdict.best.as_str() {
        "ambiguous" | "emulator_limited" => verdict.standing.iter().filter_map(|n| index(n)).collect(),
        name => index(name).into_iter().collect(),
    };
    // With nothing named, the leader's comparisons decide why.
    if standing.is_empty() && !runs.is_empty() {
        standing.push(0);
    }
    // With the repair, the standing fits' posteriors are shown (the
    // before-and-after), so they are made in full; without it the verdict
    // is the answer, and a fit is made again only where a comparison it
    // enters is close. A named candidate's intervals are the verdict's own
    // numbers: its fit is made in full either way.
    let named = index(&verdict.best);
    let first = if repair { standing.clone() } else { named.into_iter().collect() };
    let mut need = Needed { candidates: first, ..Default::default() };
    let (mut md, mut base) = (false, false);
    let mut add = |i: usize| {
        if !need.candidates.contains(&i) {
            need.candidates.push(i);
        }
    };
    // A standing candidate that cannot come within reach of the base
    // model's margin cannot be named, whatever its rivals or the MD fit
    // do: those comparisons then decide nothing.
    let nameable = |s: usize| {
        let c = &runs[s].result;
        c.log_evidence - z_base > strong || close(c.log_evidence, z_base, strong, c.log_evidence_err, e_base)
    };
    let standing: Vec<usize> = standing.into_iter().filter(|&s| nameable(s)).collect();
    for (i, r) in runs.iter().enumerate() {
        let c = &r.result;
        for &s in standing.iter().filter(|&&s| s != i) {
            let l = &runs[s].result;
            // Another reading of a standing fit that the verdict did not keep
            // as a rival is the same explanation: its precision decides at
            // most which reading is named first, never the verdict.
            if l.same_fit_as.contains(&c.name) && !verdict.standing.contains(&c.name) {
                continue;
            }
            let (el, ec) = (l.log_evidence_err, c.log_evidence_err);
            // A candidate that contains the leader, or is within it, is
            // weighed against it by Occam's margin, in one direction only:
            // an extension is named instead only if it leads by the margin
            // (behind, or ahead by less, the simpler leader stands either
            // way), and a simpler form instead if it comes within the
            // margin. Any other is a rival, and both sides of its lead count.
            let extends = members(&c.name).is_superset(&members(&l.name)) || within(l, c);
            let simpler = within(c, l);
            let rival = decisive_lead(l, c, settings);
            let ahead = close(c.log_evidence, l.log_evidence, if extends { strong } else { rival }, ec, el);
            let behind = close(l.log_evidence, c.log_evidence, if simpler { strong } else { rival }, el, ec);
            let turns = match (extends, simpler) {
                (true, _) => ahead,
                (_, true) => behind,
                _ => ahead || behind,
            };
            if turns {
                add(i);
                add(s);
            }
        }
    }
    for &s in &standing {
        let c = &runs[s].result;
        let (z, e) = (c.log_evidence, c.log_evidence_err);
        // Not beaten by MD by more than the margin (without the search's odds), and more probable than MD.
        let md_close = close(z - c.prior_log_odds, z_md, -strong, e, e_md) || close(z, z_md, 0.0, e, e_md);
        let base_close = close(z, z_base, strong, e, e_base);
        if md_close || base_close {
            add(s);
        }
        (md, base) = (md || md_close, base || base_close);
    }
    need.md |= repair || md;
    // Whether the mismatch is significant turns on MD against the base
    // only where the base fit's χ² test does not already say so by far.
    let significant_by_chi2 = base_p_value < CLEAR_P_SHARE * settings.min_p_value;
    let md_against_base = !significant_by_chi2 && close(z_md, z_base, strong, e_md, e_base);
    need.base |= repair || base || md_against_base;
    need.md |= md_against_base;
    need.candidates.sort_unstable();
    need
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_comparison_is_close_within_four_errors_and_two_nats_of_its_threshold() {
        // A lead of 9 against a margin of 3, errors 0.3 each: 6 from the line, beyond 4 × 0.42 + 2.
        assert!(!close(9.0, 0.0, 3.0, 0.3, 0.3));
        // A lead of 5.5: 2.5 from the line, within 3.7.
        assert!(close(5.5, 0.0, 3.0, 0.3, 0.3));
        // An unknown error is never far.
        assert!(close(100.0, 0.0, 3.0, f64::NAN, 0.1));
    }
}
