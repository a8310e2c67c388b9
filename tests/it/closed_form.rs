//! The samplers against posteriors and evidences known in closed form.
//!
//! Linear model η = a + b x with a Kernel II discrepancy whose hyperparameters
//! are pinned: y ~ N(Aθ, C) exactly, so under a wide uniform prior the θ
//! posterior is Gaussian and the evidence is analytic. Tolerances are 4×
//! the Monte Carlo standard error reported by the samplers' own ESS.

use super::common::*;
use mdpipe::artifacts::Measurement;
use mdpipe::calibrate::results::fisher;
use mdpipe::calibrate::results::summary::ParamSummary;
use mdpipe::calibrate::sampler::diagnostics;
use mdpipe::calibrate::sampler::ensemble::{Ensemble, EnsembleSettings};
use mdpipe::calibrate::sampler::smc::{Smc, SmcSettings};
use mdpipe::calibrate::Chains;
use mdpipe::calibrate::{MdLikelihood, ObservableBlock};
use mdpipe::gp::{discrepancy_cross_cov, DiscrepancyKernel};
use mdpipe::progress::Silent;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;
use std::sync::Arc;

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
        assert!(
            rel.abs() < 4.0 / (2.0 * ess).sqrt(),
            "{label} θ{p}: sd {} vs exact {} (ESS {ess:.0})",
            s.sd,
            exact.sd[p]
        );
    }
}

#[test]
fn smc_matches_closed_form_posterior_and_evidence() {
    let (x, y, err) = data(11);
    let kernel = DiscrepancyKernel::KernelII;
    let lik = linear_likelihood(&measurements(&x, &y, &err), Some(kernel));
    let exact = analytic_linear(&x, &y, &md_covariance(&lik, kernel, &HYPER));
    let prior = pinned_prior(THETA_BOX, &HYPER, lik.parameter_names());
    let out = Smc::new(SmcSettings { particles: 2000, replicates: 4, ..Default::default() })
        .run(&prior, &lik, 3, &Silent)
        .unwrap();
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
    let prior =
        mdpipe::calibrate::UniformPrior::new(lik.parameter_names(), vec![-20.0, -20.0], vec![20.0, 20.0]).unwrap();
    let runs = 16;
    let mut z2 = 0.0;
    for seed in 0..runs {
        let out = Smc::new(SmcSettings { particles: 300, replicates: 1, ..Default::default() })
            .run(&prior, &lik, 100 + seed, &Silent)
            .unwrap();
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
    let diag: Vec<f64> = (0..x.len() * x.len())
        .map(|k| if k % (x.len() + 1) == 0 { err[k / (x.len() + 1)].powi(2) } else { 0.0 })
        .collect();
    let exact = analytic_linear(&x, &y, &diag);
    let sd = fisher::cramer_rao_sd(&lik, &[0.7, -3.0], &[1e-3, 1e-3]).expect("identified parameters");
    for p in 0..2 {
        assert!(
            (sd[p] / exact.sd[p] - 1.0).abs() < 1e-9,
            "θ{p}: Cramér–Rao sd {} vs posterior sd {}",
            sd[p],
            exact.sd[p]
        );
    }
    // One x value cannot separate intercept and slope: F is singular, and no bound is claimed.
    let same_x = vec![0.5; 10];
    let lik = linear_likelihood(&measurements(&same_x, &y, &err), None);
    assert!(fisher::cramer_rao_sd(&lik, &[0.7, -3.0], &[1e-3, 1e-3]).is_none());
}

/// Two observables of one line, every point sharing a normalization
/// uncertainty (covariance 0.05² between any two points, across observables
/// too), each with its own Kernel II δ pinned at `HYPER`: y ~ N(Aθ, C) with C
/// the full covariance, so the joint likelihood's θ posterior, evidence and
/// Fisher information are known exactly. This is also the sampler's path for
/// a joint likelihood: its Gibbs groups move one observable's φ at the cost
/// of a whole evaluation.
#[test]
fn joint_likelihood_matches_closed_form_with_covariance_between_observables() {
    use mdpipe::base::covariance::CovarianceEntry;
    let (x, y, err) = data(21);
    let half = x.len() / 2;
    let names = ["y1", "y2"];
    let rows: Vec<Measurement> = (0..x.len()).map(|i| Measurement::new(names[i / half], x[i], y[i], err[i])).collect();
    let norm = 0.05f64 * 0.05;
    let mut entries = Vec::new();
    for i in 0..x.len() {
        for j in 0..=i {
            entries.push(CovarianceEntry {
                observable_a: rows[i].observable.clone(),
                x_a: x[i],
                observable_b: rows[j].observable.clone(),
                x_b: x[j],
                covariance: norm,
                line: 0,
                rounding: 0.0,
            });
        }
    }
    let mut blocks: Vec<ObservableBlock> = names
        .iter()
        .map(|n| ObservableBlock::new(n, 0, &rows.iter().filter(|r| &r.observable == n).collect::<Vec<_>>()).unwrap())
        .collect();
    let across = mdpipe::calibrate::likelihood::data_covariance::attach(
        &mut blocks,
        &entries,
        &rows,
        Path::new("cov.csv"),
        Path::new("data.csv"),
    )
    .unwrap();
    assert_eq!(across.len(), half * half);
    let kernel = DiscrepancyKernel::KernelII;
    let lik = MdLikelihood::new(Arc::new(LinearModel), blocks, Some(kernel)).joint(&across);
    assert!(mdpipe::calibrate::LogLikelihood::term_structure(&lik).is_some());
    assert!(mdpipe::calibrate::LogLikelihood::separable_terms(&lik).is_none(), "joined blocks are not separable");
    // C = errors² + normalization + each block's δ (in data units), by hand.
    let n = x.len();
    let mut cov = vec![norm; n * n];
    for i in 0..n {
        cov[i + i * n] += err[i] * err[i];
    }
    for (b, block) in lik.blocks.iter().enumerate() {
        let mut k = vec![0.0; half * half];
        discrepancy_cross_cov(kernel, &HYPER, &block.x, &block.x, &mut k);
        for i in 0..half {
            for j in 0..half {
                cov[(b * half + i) + (b * half + j) * n] += k[i + j * half] * block.scale * block.scale;
            }
        }
    }
    let exact = analytic_linear(&x, &y, &cov);
    let prior = pinned_prior(THETA_BOX, &[HYPER, HYPER].concat(), lik.parameter_names());
    let out = Smc::new(SmcSettings { particles: 2000, replicates: 4, ..Default::default() })
        .run(&prior, &lik, 3, &Silent)
        .unwrap();
    check_theta(&out.chains, &exact, "SMC, joint");
    let log_z_exact = exact.log_integral - (40.0f64 * 40.0).ln();
    assert!(
        (out.log_evidence - log_z_exact).abs() < 4.0 * out.log_evidence_err,
        "log Z {} ± {} vs exact {log_z_exact}",
        out.log_evidence,
        out.log_evidence_err
    );
    // Without δ the Fisher information is AᵀC⁻¹A, whose inverse is the posterior covariance.
    let lik = MdLikelihood::new(Arc::new(LinearModel), lik.blocks.clone(), None).joint(&across);
    let mut data_cov = vec![norm; n * n];
    for i in 0..n {
        data_cov[i + i * n] += err[i] * err[i];
    }
    let exact = analytic_linear(&x, &y, &data_cov);
    let sd = fisher::cramer_rao_sd(&lik, &[0.7, -3.0], &[1e-3, 1e-3]).unwrap();
    for p in 0..2 {
        assert!(
            (sd[p] / exact.sd[p] - 1.0).abs() < 1e-9,
            "θ{p}: Cramér–Rao sd {} vs posterior sd {}",
            sd[p],
            exact.sd[p]
        );
    }
}

/// With nothing linking the observables, the joint form is the sum of the blocks.
#[test]
fn joint_likelihood_without_links_is_the_sum_of_the_blocks() {
    let (x, y, err) = data(22);
    let half = x.len() / 2;
    let rows: Vec<Measurement> =
        (0..x.len()).map(|i| Measurement::new(["y1", "y2"][i / half], x[i], y[i], err[i])).collect();
    let blocks: Vec<ObservableBlock> = ["y1", "y2"]
        .iter()
        .map(|n| ObservableBlock::new(n, 0, &rows.iter().filter(|r| &r.observable == n).collect::<Vec<_>>()).unwrap())
        .collect();
    for kernel in [None, Some(DiscrepancyKernel::KernelI), Some(DiscrepancyKernel::KernelII)] {
        let blockwise = MdLikelihood::new(Arc::new(LinearModel), blocks.clone(), kernel);
        let joint = MdLikelihood::new(Arc::new(LinearModel), blocks.clone(), kernel).joint(&[]);
        let hyper: Vec<f64> = [0.8, 0.4, 1.3, 0.2][..blockwise.n_hyper()].to_vec();
        let params: Vec<f64> = [vec![0.9, 2.1], hyper.clone(), hyper.iter().map(|h| h * 1.5).collect()].concat();
        let (a, b) = (blockwise.log_likelihood(&params), joint.log_likelihood(&params));
        assert!((a - b).abs() < 1e-9 * a.abs().max(1.0), "{kernel:?}: blocks {a} vs joint {b}");
    }
}

/// A thin curved ridge with a closed-form posterior, like a misfitting
/// model whose parameters trade against each other (the bundled
/// oscillator's hardening against its frequency): w | a ~ N(0.2 a², 0.004²)
/// under a uniform prior on a ∈ [0, 2], w ∈ [−1, 5], so that a is uniform
/// on [0, 2] and w follows it along the parabola.
struct CurvedRidge;

impl mdpipe::calibrate::LogLikelihood for CurvedRidge {
    fn log_likelihood(&self, x: &[f64]) -> f64 {
        let z = (x[1] - 0.2 * x[0] * x[0]) / 0.004;
        -0.5 * z * z
    }
}

/// Random-walk moves with one covariance for the whole cloud crawl along the
/// ridge and fail the convergence check's ESS; with independent proposals
/// from a mixture fitted to the cloud the draws pass it, and a has the
/// uniform's mean, spread and 5% tails within their Monte Carlo error.
#[test]
fn smc_mixture_proposals_cross_a_curved_ridge() {
    let prior =
        mdpipe::calibrate::UniformPrior::new(vec!["a".into(), "w".into()], vec![0.0, -1.0], vec![2.0, 5.0]).unwrap();
    let run = |mixture: bool| {
        let mut settings = SmcSettings { particles: 1000, replicates: 2, ..Default::default() };
        if !mixture {
            (settings.mixture_proposals, settings.final_mixture_proposals) = (0, 0);
        }
        Smc::new(settings).run(&prior, &CurvedRidge, 5, &Silent).unwrap()
    };
    let worst_ess = |out: &mdpipe::calibrate::sampler::smc::SmcOutput| {
        (0..2)
            .map(|p| {
                let chains = out.chains.param_chains(p);
                diagnostics::ess_bulk(&chains).min(diagnostics::ess_tail(&chains))
            })
            .fold(f64::INFINITY, f64::min)
    };
    let random_walk = run(false);
    let with_mixture = run(true);
    assert!(
        worst_ess(&random_walk) < diagnostics::ESS_MIN,
        "random walk alone passes: ESS {:.0}",
        worst_ess(&random_walk)
    );
    let ess = worst_ess(&with_mixture);
    eprintln!("worst ESS: random walk {:.0}, with the mixture {ess:.0}", worst_ess(&random_walk));
    assert!(ess >= diagnostics::ESS_MIN, "ESS {ess:.0}");

    let a = with_mixture.chains.param(0);
    let s = ParamSummary::from_draws(&a);
    let sd_uniform = 2.0 / 12f64.sqrt();
    assert!((s.mean - 1.0).abs() < 4.0 * sd_uniform / ess.sqrt(), "mean {} (ESS {ess:.0})", s.mean);
    assert!((s.sd / sd_uniform - 1.0).abs() < 4.0 / (2.0 * ess).sqrt(), "sd {} vs {sd_uniform}", s.sd);
    // Each tail holds 5% of a uniform: a binomial proportion over ESS draws.
    let tails =
        [("a < 0.1", a.iter().filter(|&&v| v < 0.1).count()), ("a > 1.9", a.iter().filter(|&&v| v > 1.9).count())];
    for (label, count) in tails {
        let p = count as f64 / a.len() as f64;
        let mc_error = (0.05 * 0.95 / ess).sqrt();
        assert!((p - 0.05).abs() < 4.0 * mc_error, "{label}: {p:.3} against 0.05 (MC error {mc_error:.3})");
    }
}
