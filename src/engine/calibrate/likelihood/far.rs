//! The likelihood below a floor. A sampler that gives no weight to points
//! whose log-likelihood is below a floor (`smc`'s) needs to know only that
//! they are below it; the fit without MD, whose log-likelihood is a
//! constant minus half the data's χ² when the errors are independent, tells
//! the model the χ² that puts a θ below the floor, and a model that builds
//! its predictions step by step (an ODE) stops there.

use super::form::Form;
use super::md::MdLikelihood;
use crate::engine::model::{ObservedData, ObservedSeries};
use std::f64::consts::PI;

impl MdLikelihood {
    /// `log L(params)`, or −∞ when the model shows it is below `floor`
    /// (values below the floor may be returned either way).
    pub fn log_likelihood_above(&self, params: &[f64], floor: f64) -> f64 {
        if let Some((data, top)) = self.watched_data().filter(|_| floor.is_finite()) {
            // log L = top − χ²/2, so log L < floor exactly when χ² > 2 (top − floor).
            let limit = 2.0 * (top - floor);
            if limit < 0.0 || self.simulator.chi_square_exceeds(&params[..self.n_theta], data, limit) {
                return f64::NEG_INFINITY;
            }
        }
        self.log_likelihood(params)
    }

    /// The data as the model may watch them, and the log-likelihood at a
    /// χ² of zero; None unless the likelihood is that constant minus half
    /// the χ² of independent errors (no MD, no model covariance, no data
    /// covariance beyond the errors, no joint form).
    fn watched_data(&self) -> Option<(&ObservedData, f64)> {
        self.observed.get_or_init(|| self.observed_data()).as_ref().map(|(data, top)| (data, *top))
    }

    fn observed_data(&self) -> Option<(ObservedData, f64)> {
        let independent = self.kernel.is_none()
            && !self.has_model_covariance()
            && matches!(self.form, Form::Blocks(_))
            && self.blocks.iter().all(|b| b.diagonal_data() && b.error.iter().all(|e| *e > 0.0));
        independent.then(|| {
            let series = self
                .blocks
                .iter()
                .map(|b| ObservedSeries {
                    observable: b.model_index,
                    x: b.x.clone(),
                    y: b.y.clone(),
                    inv_error: b.error.iter().map(|e| 1.0 / e).collect(),
                })
                .collect();
            let top = self.blocks.iter().flat_map(|b| &b.error).map(|e| -e.ln() - 0.5 * (2.0 * PI).ln()).sum();
            (ObservedData::new(series), top)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::data_covariance::test_support::{blocks, data, Line};
    use super::*;
    use crate::engine::model::Simulator;
    use std::sync::Arc;

    /// The line, telling exactly whether the χ² exceeds a limit.
    struct ExactLine;
    impl Simulator for ExactLine {
        fn parameter_names(&self) -> Vec<String> {
            Line.parameter_names()
        }
        fn observable_names(&self) -> Vec<String> {
            Line.observable_names()
        }
        fn predict(&self, o: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
            Line.predict(o, x, theta, out)
        }
        fn chi_square_exceeds(&self, theta: &[f64], data: &ObservedData, limit: f64) -> bool {
            data.chi_square_at(self, theta) > limit
        }
    }

    /// Without MD the log-likelihood is the watched constant minus χ²/2, so
    /// a model that answers exactly puts a θ at −∞ just where its
    /// log-likelihood is below the floor, and leaves it exact above.
    #[test]
    fn below_the_floor_is_where_the_log_likelihood_is() {
        let lik = MdLikelihood::new(Arc::new(ExactLine), blocks(&data()), None);
        for theta in [[1.0, 1.0], [1.05, 0.95], [0.0, 3.0], [5.0, -2.0]] {
            let exact = lik.log_likelihood(&theta);
            for floor in [exact - 10.0, exact - 1e-9, exact + 1e-9, exact + 5.0, f64::NEG_INFINITY] {
                let above = lik.log_likelihood_above(&theta, floor);
                if exact < floor {
                    assert_eq!(above, f64::NEG_INFINITY, "θ = {theta:?}, floor {floor}: log L = {exact}");
                } else {
                    assert_eq!(above, exact, "θ = {theta:?}, floor {floor}");
                }
            }
        }
    }

    /// With MD the likelihood is no χ²: nothing is watched, every value exact.
    #[test]
    fn with_md_nothing_is_watched() {
        let kernel = Some(crate::engine::gp::DiscrepancyKernel::KernelI);
        let lik = MdLikelihood::new(Arc::new(ExactLine), blocks(&data()), kernel);
        let params = [1.0, 1.0, 0.5, 0.3, 0.5, 0.1, 0.5, 0.3, 0.5, 0.1];
        let exact = lik.log_likelihood(&params);
        assert_eq!(lik.log_likelihood_above(&params, exact + 100.0), exact);
    }
}
