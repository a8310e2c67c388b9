//! The search for physics nobody declared, as `diagnose` runs it: the
//! model's discoverer screens its grammar against the data at the base fit,
//! and the terms it proposes are judged as declared candidates are, by full
//! calibration and evidence, each with its prior odds: its share of a prior
//! over every term searched.

use super::*;
use crate::engine::calibrate::ObservableBlock;
use crate::engine::gp::CholeskyWorkspace;
use crate::engine::model::{Discoverer, ScreeningBlock, ScreeningData};
use anyhow::anyhow;

/// Whether to search: always, never, or when no candidate explains a
/// mismatch.
pub(super) fn wanted(discover: Discover, verdict: &Verdict) -> bool {
    match discover {
        Discover::Always => true,
        Discover::Never => false,
        Discover::WhenUnexplained => verdict.best == "unexplained",
    }
}

/// Screens the grammar from `theta` (the base fit's posterior median, or
/// the prior's centre where the model cannot be fitted); the report and the
/// proposed terms as candidates.
pub(super) fn screen(
    discoverer: &dyn Discoverer,
    problem: &Problem,
    theta: Vec<f64>,
) -> Result<(DiscoveryReport, Vec<(CandidateModel, f64)>)> {
    let names = problem.simulator.parameter_names();
    let blocks = problem.likelihood.blocks.iter().map(|b| {
        Ok(ScreeningBlock {
            model_index: b.model_index,
            x: &b.x,
            y: &b.y,
            error: &b.error,
            covariance_factor: covariance_factor(b)?,
        })
    });
    let data = ScreeningData {
        blocks: blocks.collect::<Result<_>>()?,
        theta,
        bounds: (0..names.len()).map(|k| (problem.prior.lower[k], problem.prior.upper[k])).collect(),
    };
    let start = std::time::Instant::now();
    let screening = discoverer.screen(&data)?;
    let report = DiscoveryReport {
        searched: screening.searched,
        forms: screening.forms,
        screening_seconds: start.elapsed().as_secs_f64(),
        screened: screening
            .proposals
            .iter()
            .map(|p| ScreenedTerm {
                name: p.candidate.name.clone(),
                formula: p.formula.clone(),
                meaning: p.meaning.clone(),
                delta_chi2: p.delta_chi2,
                delta_bic: p.delta_bic,
                prior_log_odds: p.prior_log_odds,
                toml: p.toml.clone(),
                readings: p.readings.clone(),
            })
            .collect(),
        notes: screening.notes,
    };
    Ok((report, screening.proposals.into_iter().map(|p| (p.candidate, p.prior_log_odds)).collect()))
}

/// The other readings of a screened term: forms whose fits the data could
/// not tell from its own by the price of a parameter (`distinct`), so one
/// explanation that a measurement beyond the data may still split.
fn also_read(s: &ScreenedTerm) -> String {
    if s.readings.is_empty() {
        return String::new();
    }
    let shown = &s.readings[..s.readings.len().min(READINGS_SHOWN)];
    let more = match s.readings.len() - shown.len() {
        0 => String::new(),
        n => format!(", and {n} more (diagnosis.json lists them)"),
    };
    format!(
        "; on these data the same fit as {}{more}, which the screening merged into it as the simpler",
        shown.join("; or as ")
    )
}

/// Readings named in the verdict's words, in the order the screening ranked
/// them; the rest are in `diagnosis.json`. Several are often the same term
/// in another dress (a saturation whose scale fell to zero is a constant).
const READINGS_SHOWN: usize = 2;

/// The lower Cholesky factor of a block's measurement covariance (errors²
/// and `[data] covariance`), when it has more than the errors. Covariance
/// between observables is left to the confirming calibrations.
fn covariance_factor(block: &ObservableBlock) -> Result<Option<Vec<f64>>> {
    if block.diagonal_data() {
        return Ok(None);
    }
    let mut chol = CholeskyWorkspace::new(block.len());
    block.add_data_covariance(1.0, &mut chol.factor);
    chol.factorize().map_err(|e| anyhow!("discover: the covariance of '{}': {e}", block.name))?;
    Ok(Some(chol.factor))
}

/// What the verdict says of the search.
pub(super) fn word(verdict: &mut Verdict, report: &DiscoveryReport) {
    for note in &report.notes {
        verdict.statement.push_str(&format!(" The search: {note}."));
    }
    let partial = verdict.best == "partial";
    let found = report.screened.iter().find(|s| Some(s.name.as_str()) == verdict.named());
    let standing: Vec<_> =
        verdict.standing.iter().filter_map(|n| report.screened.iter().find(|s| &s.name == n)).collect();
    if found.is_none() && !standing.is_empty() && !partial {
        let read: Vec<String> =
            standing.iter().map(|s| format!("{} ({}){}", s.formula, s.meaning, also_read(s))).collect();
        verdict.statement.push_str(&format!(
            " Discovered in a search of {} terms, not declared: {}. Once a measurement settles it, declare the winner; the leader reads:\n{}",
            report.searched,
            read.join("; or "),
            standing[0].toml
        ));
        return;
    }
    verdict.statement.push_str(&match found {
        Some(s) => format!(
            " It was discovered, not declared: {} ({}; one of {} terms searched; prior odds 1:{:.0} paid){}. Declare it with:\n{}",
            s.formula,
            s.meaning,
            report.searched,
            (-s.prior_log_odds).exp(),
            also_read(s),
            s.toml
        ),
        None => format!(
            " A search of {} terms built from the model's own symbols (forms: {}) found none that explains the data decisively.",
            report.searched,
            // The grammar's forms without their placeholders' braces: `c*(y)^2`.
            report.forms.iter().map(|f| f.replace(['{', '}'], "")).collect::<Vec<_>>().join("; ")
        ),
    });
}
