//! The samplers against posteriors and evidences known in closed form.
//!
//! Linear model η = a + b x with a Kernel II discrepancy whose hyperparameters
//! are pinned: y ~ N(Aθ, C) exactly, so under a wide uniform prior the θ
//! posterior is Gaussian and the evidence is analytic. Tolerances are 4×
//! the Monte Carlo standard error reported by the samplers' own ESS.



use super::common::*;
use mdpipe::calibrate::ensemble::{Ensemble, EnsembleSettings};
use mdpipe::calibrate::smc::{Smc, SmcSettings};
use mdpipe::calibrate::summary::ParamSummary;
use mdpipe::calibrate::{diagnostics, Chains};
use mdpipe::gp::DiscrepancyKernel;
use mdpipe::progress::Silent;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

const HYPER: [f64; 3] = [0.5, 0.3, 1.0];
const THETA_BOX: [(f64, f64); 2] = [(-20.0, 20.0), (-20.0, 20.0)];

fn data(seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let x: Vec<f64> = (1..=10).map(|i| i as f64 / 10.0).collect();
    let err = vec![0.1; 10];
    let noise = Normal::new(0.0, 0.1).unwrap();
    // Any y will do: the analytic answer is exact for the data at hand.
    let y = x.iter().map(|xi| 1.0 + 2.0 * xi + 0.3 * xi * xi + noise.sample(&mut rng)).collect();
    (x, y, err)
}

fn check_theta(chains: &Chains, exact: &Analytic, label: &str) {
    for p in 0..2 {
        let draws = chains.param(p);
        let s = ParamSummary::from_draws(&draws);
        let ess = diagnostics::ess_bulk(&chains.param_chains(p));
        let mc_err_mean = exact.sd[p] / ess.sqrt();
        assert!(
            (s.mean - exact.mean[p]).abs() < 4.0 * mc_err_mean,
            "{label} θ{p}: mean {} vs exact {} (MC error {mc_err_mean:.2e}, ESS {ess:.0})",
            s.mean,
            exact.mean[p]
        );
        // sd of a sample sd ≈ sd / sqrt(2 ESS) for near-Gaussian draws.
        let rel = s.sd / exact.sd[p] - 1.0;
        assert!(rel.abs() < 4.0 / (2.0 * ess).sqrt(), "{label} θ{p}: sd {} vs exact {} (ESS {ess:.0})", s.sd, exact.sd[p]);
    }
}

#[test]
fn smc_matches_closed_form_posterior_and_evidence() {
    let (x, y, err) = data(11);
    let kernel = DiscrepancyKernel::KernelII;
    let lik = linear_likelihood(&measurements(&x, &y, &err), Some(kernel));
    let exact = analytic_linear(&x, &y, &md_covariance(&lik, kernel, &HYPER));
    let prior = pinned_prior(THETA_BOX, &HYPER, lik.parameter_names());
    let out = Smc::new(SmcSettings { particles: 2000, replicates: 4, ..Default::default() }).run(&prior, &lik, 3, &Silent).unwrap();
    check_theta(&out.chains, &exact, "SMC");
    let log_z_exact = exact.log_integral - (40.0f64 * 40.0).ln();
    assert!(out.log_evidence_err > 0.0 && out.log_evidence_err < 0.5);
    assert!(
        (out.log_evidence - log_z_exact).abs() < 4.0 * out.log_evidence_err,
        "log Z {} ± {} vs exact {log_z_exact}",
        out.log_evidence,
        out.log_evidence_err
    );
}

#[test]
fn ensemble_matches_closed_form_posterior() {
    let (x, y, err) = data(12);
    let kernel = DiscrepancyKernel::KernelII;
    let lik = linear_likelihood(&measurements(&x, &y, &err), Some(kernel));
    let exact = analytic_linear(&x, &y, &md_covariance(&lik, kernel, &HYPER));
    let prior = pinned_prior(THETA_BOX, &HYPER, lik.parameter_names());
    let settings = EnsembleSettings { walkers: 32, steps: 20000, burn: 5000, thin: 5, stretch: 2.0 };
    let out = Ensemble::new(settings).run(&prior, &lik, 4, &Silent);
    check_theta(&out.chains, &exact, "ensemble");
    for p in 0..2 {
        let rhat = diagnostics::rhat(&out.chains.param_chains(p));
        assert!(rhat < 1.01, "R-hat {rhat}");
    }
}

/// The Lee–Whiteley evidence error must describe the actual scatter of log Ẑ
/// over independent runs: mean z² over 16 runs lies in the central 99.8% of
/// χ²₁₆/16, i.e. (0.29, 2.5), when the error estimate is right.
#[test]
fn smc_evidence_error_is_calibrated() {
    let (x, y, err) = data(13);
    let lik = linear_likelihood(&measurements(&x, &y, &err), None);
    let n = x.len();
    let mut cov = vec![0.0; n * n];
    for i in 0..n {
        cov[i + i * n] = err[i] * err[i];
    }
    let exact = analytic_linear(&x, &y, &cov);
    let log_z_exact = exact.log_integral - (40.0f64 * 40.0).ln();
    let prior = mdpipe::calibrate::UniformPrior::new(lik.parameter_names(), vec![-20.0, -20.0], vec![20.0, 20.0]).unwrap();
    let runs = 16;
    let mut z2 = 0.0;
    for seed in 0..runs {
        let out = Smc::new(SmcSettings { particles: 300, replicates: 1, ..Default::default() }).run(&prior, &lik, 100 + seed, &Silent).unwrap();
        let z = (out.log_evidence - log_z_exact) / out.log_evidence_err;
        z2 += z * z / runs as f64;
    }
    assert!(z2 > 0.29 && z2 < 2.5, "mean squared z-score {z2}");
}

#[test]
fn cramer_rao_sd_equals_the_linear_models_posterior_sd() {
    // For a linear model with Gaussian errors the posterior covariance under a
    // flat prior is exactly F⁻¹, at any θ; finite differences are exact too.
    let (x, y, err) = data(5);
    let lik = linear_likelihood(&measurements(&x, &y, &err), None);
    let diag: Vec<f64> = (0..x.len() * x.len()).map(|k| if k % (x.len() + 1) == 0 { err[k / (x.len() + 1)].powi(2) } else { 0.0 }).collect();
    let exact = analytic_linear(&x, &y, &diag);
    let sd = lik.cramer_rao_sd(&[0.7, -3.0], &[1e-3, 1e-3]).expect("identified parameters");
    for p in 0..2 {
        assert!((sd[p] / exact.sd[p] - 1.0).abs() < 1e-9, "θ{p}: Cramér–Rao sd {} vs posterior sd {}", sd[p], exact.sd[p]);
    }
    // One x value cannot separate intercept and slope: F is singular, and no bound is claimed.
    let same_x = vec![0.5; 10];
    let lik = linear_likelihood(&measurements(&same_x, &y, &err), None);
    assert!(lik.cramer_rao_sd(&[0.7, -3.0], &[1e-3, 1e-3]).is_none());
}
