//! Where an emulator's predictive variance comes from, per output: what
//! well-placed design points reduce (the kept components' latent variance),
//! what any new run reduces as 1/n (the PCA's own estimation noise), and
//! what placing runs does not (white noise beyond the runs' reported errors,
//! which a refit on more runs may lower, and the dropped components'
//! signal). When adaptive design stalls above the data error, this says why.

use super::Emulator;

/// One output's predictive variance in observable units, split by source.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VarianceBudget {
    /// The kept components' uncertainty about the simulator's mean.
    pub latent: f64,
    /// The kept components' white noise left after the runs' reported noise
    /// is removed: scatter the runs do not report.
    pub excess_scatter: f64,
    /// The dropped components' signal (run noise removed).
    pub dropped: f64,
    /// The PCA's mean and directions, estimated from noisy runs.
    pub pca_noise: f64,
}

impl VarianceBudget {
    pub fn total(&self) -> f64 {
        self.latent + self.excess_scatter + self.dropped + self.pca_noise
    }
    /// What placing runs does not reduce at the fitted hyperparameters (the
    /// PCA's noise falls as 1/n with any run, so it is not part of it).
    pub fn floor(&self) -> f64 {
        self.excess_scatter + self.dropped.max(0.0)
    }
}

impl Emulator {
    /// Every output's predictive variance at θ, split by source; the parts
    /// sum to the diagonal of [`Emulator::predict`]'s covariance.
    pub fn variance_budget(&self, theta: &[f64]) -> Vec<VarianceBudget> {
        self.variance_budgets(theta).pop().unwrap_or_default()
    }

    /// The same at many θ (row-major B × d): the PCA's noise covariance,
    /// O(m³), is computed once rather than per point.
    pub fn variance_budgets(&self, thetas: &[f64]) -> Vec<Vec<VarianceBudget>> {
        let pca = super::run_noise::pca_noise_cov(&self.parts);
        thetas.chunks(self.n_parameters().max(1)).map(|theta| self.budget_with(theta, &pca)).collect()
    }

    fn budget_with(&self, theta: &[f64], pca: &[f64]) -> Vec<VarianceBudget> {
        let (kc, m) = (self.n_components(), self.n_outputs());
        let mut scratch = self.scratch();
        let (mut means, mut vars) = (vec![0.0; kc], vec![0.0; kc]);
        self.predict_components(theta, &mut means, &mut vars, &mut scratch);
        let excess: Vec<f64> = self.gps.iter().zip(&self.run_noise).map(|(g, r)| (g.noise_var - r).max(0.0)).collect();
        let latent: Vec<f64> = vars.iter().zip(&excess).map(|(v, e)| (v - e).max(0.0)).collect();
        (0..m)
            .map(|j| {
                let jac = self.output_mean_from_components(&means, j).1;
                let pca_noise = pca[j * m + j] * jac * jac;
                VarianceBudget {
                    latent: self.output_var_from_component_vars(&latent, j, jac),
                    excess_scatter: self.output_var_from_component_vars(&excess, j, jac),
                    dropped: self.truncation_cov[j * m + j] * jac * jac - pca_noise,
                    pca_noise,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use crate::engine::emulator::{train, EmulatorSettings, OutputKey, TrainingTable};
    use rand::SeedableRng;
    use rand_distr::Distribution;

    /// Six outputs of a full-rank function of two inputs, two components
    /// kept, 40 runs that report their noise (sd `error`).
    fn emulator(error: f64) -> crate::engine::emulator::Emulator {
        let (n, m) = (40, 6);
        // Uniform random inputs: the emulator's tests may not use the design
        // unit, a sibling of the same layer.
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let uniform = rand_distr::Uniform::new(0.0, 1.0).unwrap();
        let unit: Vec<f64> = (0..2 * n).map(|_| uniform.sample(&mut rng)).collect();
        let noise = rand_distr::Normal::new(0.0, 1.0).unwrap();
        let values: Vec<f64> = unit
            .chunks(2)
            .flat_map(|u| {
                (0..m)
                    .map(|j| ((1.0 + j as f64) * u[0]).sin() + u[1] * j as f64 * 0.3 + error * noise.sample(&mut rng))
                    .collect::<Vec<_>>()
            })
            .collect();
        let table = TrainingTable {
            path: "synthetic".into(),
            parameter_names: vec!["a".into(), "b".into()],
            design_ids: (0..n as i64).collect(),
            inputs: unit,
            outputs: (0..m).map(|j| OutputKey { observable: "y".into(), x: j as f64 }).collect(),
            errors: vec![error; values.len()],
            noise_correlation: None,
            values,
        };
        let settings: EmulatorSettings =
            toml::from_str("parameters = [\"a\", \"b\"]\ncomponents = 2\nrestarts = 2").unwrap();
        train(&table, &settings, 1).unwrap().0
    }

    /// The parts add up to the prediction's variance, none is negative, and
    /// runs without reported noise leave no PCA noise.
    #[test]
    fn the_parts_sum_to_the_predictive_variance() {
        for error in [0.0, 0.05] {
            let emu = emulator(error);
            for theta in [[0.2, 0.7], [0.5, 0.5], [0.9, 0.1]] {
                let prediction = emu.predict(&theta);
                let m = emu.n_outputs();
                for (j, b) in emu.variance_budget(&theta).iter().enumerate() {
                    let want = prediction.cov[j * m + j];
                    assert!(
                        (b.total() - want).abs() <= 1e-10 * want.abs().max(1e-12),
                        "output {j}: {} vs {want}",
                        b.total()
                    );
                    assert!(
                        b.latent >= 0.0 && b.excess_scatter >= 0.0 && b.dropped >= -1e-12 * want && b.pca_noise >= 0.0,
                        "{b:?}"
                    );
                    assert!(b.floor() <= b.total());
                    if error == 0.0 {
                        assert_eq!(b.pca_noise, 0.0);
                    }
                }
            }
            // With a full-rank truth and two of six components kept, the dropped ones carry signal somewhere.
            assert!(emu.variance_budget(&[0.5, 0.5]).iter().any(|b| b.dropped > 0.0));
        }
    }
}
