//! Screening by multiple shooting from the data (`ode::shooting`), where
//! one trajectory from t0 is lost: along a chaotic flow sampled a few
//! times a turn, no form fitted through such a trajectory comes near the
//! data, and the screening names noise.
//!
//! Each point is then predicted from the states measured one step before
//! it. Those anchors are measurements: their errors move every point
//! predicted from them, by the flow's sensitivity, most where the flow
//! stretches fastest. Unweighted, those points rule the χ², and a flexible
//! term that damps the stretching beat the true law (Rössler, ODEBench
//! case 100: c·x₁·e^{x₂/s} at χ² 488 against the true c·x₁ at 614). So
//! the screening runs twice: once on the data's errors, then on errors
//! that add, point by point, the spread the anchors' errors give the best
//! form of the first pass (each state's anchors moved by one error in
//! turn, the predictions' changes added in quadrature).

use super::super::declaration::CandidateTable;
use super::DeclaredDiscoverer;
use crate::engine::model::{Screening, ScreeningBlock, ScreeningData, Simulator};
use anyhow::Result;
use std::sync::Arc;

/// The χ² per point beyond which the screening through one trajectory is
/// lost: residuals of 10σ on average under the best form it fitted. A
/// missing term that one trajectory can follow is found far below this
/// (the right form near 1 per point); along ODEBench's Rössler flow the
/// best form stays above 300 per point (case 100: 36 709 over 120 points).
const LOST_CHI2: f64 = 100.0;

/// The best fit a screening made: χ², the form (None: the base), its parameters.
pub struct Best {
    pub chi2: f64,
    pub table: Option<CandidateTable>,
    pub phi: Vec<f64>,
}

impl DeclaredDiscoverer {
    /// The screening through one trajectory from t0; where its best form
    /// stays beyond `LOST_CHI2` per point and every state is measured, the
    /// screening by shooting instead, which says so.
    pub(super) fn screen_or_shoot(&self, data: &ScreeningData) -> Result<Screening> {
        let (screening, best) = self.screen_declared(data)?;
        let points = data.blocks.iter().map(|b| b.y.len()).sum::<usize>().max(1) as f64;
        let Some(every) = self.shooting_step(data).filter(|_| best.chi2 / points > LOST_CHI2) else {
            return Ok(screening);
        };
        let mut base = self.base.clone();
        base.shooting = Some(every);
        let shot = DeclaredDiscoverer {
            family: self.family.clone(),
            file: self.file.clone(),
            base,
            forms: self.forms.clone(),
        };
        let (first, lead) = shot.screen_declared(data)?;
        let spread = shot.anchor_spread(data, &lead);
        let errors = spread.as_ref().map(|s| widened_errors(data, s));
        let mut screening = match &errors {
            Some(errors) => shot.screen_declared(&with_errors(data, errors))?.0,
            None => first,
        };
        screening.notes.push(format!(
            "no form fitted through one trajectory from t0 came near the data (best χ²/N = {:.0}): the terms were screened by multiple shooting, each point predicted from the states measured {every} before it{}; every fit below integrates from t0",
            best.chi2 / points,
            if spread.is_some() { ", its errors widened by the anchors' own" } else { "" }
        ));
        Ok(screening)
    }

    /// One step of the data, where every state is measured as itself (so
    /// the model can restart from the measurements): the smallest gap
    /// between two times of a state's series.
    fn shooting_step(&self, data: &ScreeningData) -> Option<f64> {
        let d = &self.base;
        if d.states.is_empty() {
            return None;
        }
        let mut step = f64::INFINITY;
        for s in &d.states {
            let observes =
                |b: &&ScreeningBlock| d.observables.get(b.model_index).is_some_and(|(_, w)| w.text.trim() == s.name);
            let block = data.blocks.iter().find(observes)?;
            let gap = block.x.windows(2).map(|w| w[1] - w[0]).filter(|g| *g > 0.0).fold(f64::INFINITY, f64::min);
            step = step.min(gap);
        }
        step.is_finite().then_some(step)
    }

    /// Per point (blocks in a row), the variance the anchors' errors give
    /// the prediction of the best form at its fit: each state's anchors
    /// moved by one error in turn, the changes squared and summed. None
    /// when the data carry a covariance (their errors are not all there
    /// is) or the form cannot be computed.
    fn anchor_spread(&self, data: &ScreeningData, best: &Best) -> Option<Vec<f64>> {
        if data.blocks.iter().any(|b| b.covariance_factor.is_some()) {
            return None;
        }
        let model: Arc<dyn Simulator> = match &best.table {
            Some(table) => self.compile(table)?,
            None => self.family.compile(&self.file, &self.base).ok()?,
        };
        for b in &data.blocks {
            model.check_inputs(b.model_index, b.x).ok()?;
        }
        let predict = |moved: Option<usize>| -> Vec<f64> {
            for b in &data.blocks {
                let observes = self.observed_state(b.model_index);
                let values: Vec<f64> = match moved.filter(|m| observes == Some(*m)) {
                    Some(_) => b.y.iter().zip(b.error).map(|(y, e)| y + e).collect(),
                    None => b.y.to_vec(),
                };
                model.note_measurements(b.model_index, &values, b.error);
            }
            let mut out = Vec::new();
            for b in &data.blocks {
                let mut p = vec![0.0; b.x.len()];
                model.predict(b.model_index, b.x, &best.phi, &mut p);
                out.extend(p);
            }
            out
        };
        let at = predict(None);
        let mut spread = vec![0.0; at.len()];
        for m in 0..self.base.states.len() {
            for ((s, moved), a) in spread.iter_mut().zip(predict(Some(m))).zip(&at) {
                *s += (moved - a).powi(2);
            }
        }
        spread.iter().all(|s| s.is_finite()).then_some(spread)
    }

    /// The state observable `o` measures as itself.
    fn observed_state(&self, o: usize) -> Option<usize> {
        let (_, w) = self.base.observables.get(o)?;
        self.base.states.iter().position(|s| s.name == w.text.trim())
    }
}

/// Each block's errors widened by the anchors' spread at its points.
fn widened_errors(data: &ScreeningData, spread: &[f64]) -> Vec<Vec<f64>> {
    let mut offset = 0;
    data.blocks
        .iter()
        .map(|b| {
            let at = &spread[offset..offset + b.error.len()];
            offset += b.error.len();
            b.error.iter().zip(at).map(|(e, s)| (e * e + s).sqrt()).collect()
        })
        .collect()
}

/// The data with these errors, block by block.
fn with_errors<'a>(data: &ScreeningData<'a>, errors: &'a [Vec<f64>]) -> ScreeningData<'a> {
    let blocks = data
        .blocks
        .iter()
        .zip(errors)
        .map(|(b, e)| ScreeningBlock { model_index: b.model_index, x: b.x, y: b.y, error: e, covariance_factor: None })
        .collect();
    ScreeningData { blocks, theta: data.theta.clone(), bounds: data.bounds.clone() }
}
