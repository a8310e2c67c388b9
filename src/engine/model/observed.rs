//! The data a fit compares a model with, as a model may read them while it
//! computes: a model that builds its predictions step by step (an ODE
//! integrated over the data's times) can tell that a θ misses the data by
//! more than a given χ² before it has finished, and stop there
//! (`Simulator::chi_square_exceeds`).

use super::Simulator;
use std::sync::atomic::{AtomicU64, Ordering};

/// One observable's measurements: times or inputs `x`, values `y` and the
/// inverse of their errors, in the same order.
#[derive(Clone, Debug)]
pub struct ObservedSeries {
    /// Index into the model's `observable_names`.
    pub observable: usize,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub inv_error: Vec<f64>,
}

/// Every observable's measurements of one fit, under an id that tells
/// different data apart (a model may keep what it derived from them).
#[derive(Clone, Debug)]
pub struct ObservedData {
    pub id: u64,
    pub series: Vec<ObservedSeries>,
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

impl ObservedData {
    pub fn new(series: Vec<ObservedSeries>) -> ObservedData {
        ObservedData { id: NEXT_ID.fetch_add(1, Ordering::Relaxed), series }
    }

    /// Σ ((y − η(θ))/σ)² over every series, η from `model.predict`
    /// (allocates: for tests and checks, not a sampler's loop).
    pub fn chi_square_at(&self, model: &dyn Simulator, theta: &[f64]) -> f64 {
        self.series
            .iter()
            .map(|s| {
                let mut eta = vec![0.0; s.x.len()];
                model.predict(s.observable, &s.x, theta, &mut eta);
                s.y.iter().zip(&s.inv_error).zip(&eta).map(|((y, w), e)| ((y - e) * w).powi(2)).sum::<f64>()
            })
            .sum()
    }
}
