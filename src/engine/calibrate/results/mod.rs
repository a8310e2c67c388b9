//! What a calibration leaves: its summary (`summary`: posterior, evidence,
//! predictions, fit quality), the Cramér–Rao bounds of the fit without MD
//! (`fisher`) and finished fits on disk (`stored`).

pub mod fisher;
pub mod stored;
pub mod summary;

use crate::engine::calibrate::sampler::chains::Chains;

/// Output of one calibration run, in memory.
#[derive(Clone)]
pub struct Calibration {
    pub chains: Chains,
    pub summary: summary::Summary,
    pub predictions: Vec<summary::PredictionRow>,
}
