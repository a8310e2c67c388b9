//! The likelihood as a sampler's target: its terms (one per observable,
//! with that observable's φ as their own parameters), separable in the
//! block form, kept as statistics in the structured form where only the
//! blocks move.

use super::block_stats;
use super::form::Form;
use super::md::MdLikelihood;
use crate::engine::calibrate::sampler::target::{LogLikelihood, SeparableTerms, TermStatistics, TermStructure};

impl LogLikelihood for MdLikelihood {
    fn log_likelihood(&self, x: &[f64]) -> f64 {
        MdLikelihood::log_likelihood(self, x)
    }
    fn log_likelihood_above(&self, x: &[f64], floor: f64) -> f64 {
        MdLikelihood::log_likelihood_above(self, x, floor)
    }
    fn term_structure(&self) -> Option<TermStructure> {
        let nh = self.n_hyper();
        if nh == 0 {
            return None;
        }
        let own =
            (0..self.blocks.len()).map(|b| (self.n_theta + b * nh..self.n_theta + (b + 1) * nh).collect()).collect();
        Some(TermStructure { shared: (0..self.n_theta).collect(), own })
    }
    fn screening_term(&self, x: &[f64], term: usize) -> Option<f64> {
        MdLikelihood::screening_term(self, x, term)
    }
    fn separable_terms(&self) -> Option<&dyn SeparableTerms> {
        (self.n_hyper() > 0 && matches!(self.form, Form::Blocks(_))).then_some(self as &dyn SeparableTerms)
    }
    fn term_statistics(&self) -> Option<&dyn TermStatistics> {
        (block_stats::width_of(self) > 0).then_some(self as &dyn TermStatistics)
    }
}

impl SeparableTerms for MdLikelihood {
    fn log_likelihood_terms(&self, x: &[f64], terms: &mut [f64]) -> f64 {
        MdLikelihood::log_likelihood_terms(self, x, terms)
    }
    fn log_likelihood_term(&self, x: &[f64], term: usize) -> f64 {
        MdLikelihood::log_likelihood_term(self, x, term)
    }
}
