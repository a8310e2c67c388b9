//! Simulation-based calibration (Talts et al. 2018): draw (θ, φ) from the
//! prior, simulate y = η(θ) + δ + ε with δ ~ GP(0, K_φ), fit with SMC, and
//! count how often the central credible intervals contain the truth.
//!
//! The discrepancy scale is fixed to 1 (no data-dependent standardization),
//! so the likelihood is exactly the generative model.



use super::common::*;
use mdpipe::calibrate::smc::{Smc, SmcSettings};
use mdpipe::calibrate::{MdLikelihood, ObservableBlock, UniformPrior};
use mdpipe::gp::{discrepancy_cross_cov, CholeskyWorkspace, DiscrepancyKernel};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::sync::Arc;

#[test]
fn credible_intervals_have_nominal_coverage() {
    let kernel = DiscrepancyKernel::KernelII;
    let names: Vec<String> = ["a", "b", "y.cbar", "y.ell", "y.r"].iter().map(|s| s.to_string()).collect();
    let prior = UniformPrior::new(names, vec![-2.0, -2.0, 0.0, 0.05, 0.0], vec![2.0, 2.0, 1.0, 1.0, 2.0]).unwrap();
    let x: Vec<f64> = (1..=8).map(|i| i as f64 / 8.0).collect();
    let err = vec![0.2; 8];
    let datasets = 200;
    let levels = [0.5, 0.9];
    // covered[param][level]
    let results: Vec<[[bool; 2]; 5]> = (0..datasets)
        .into_par_iter()
        .map(|k| {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(1000 + k as u64);
            let mut truth = vec![0.0; 5];
            prior.sample(&mut rng, &mut truth);
            // δ ~ GP(0, K_φ) on the data points.
            let n = x.len();
            let mut ws = CholeskyWorkspace::new(n);
            discrepancy_cross_cov(kernel, &truth[2..], &x, &x, &mut ws.factor);
            ws.factorize().unwrap();
            let z: Vec<f64> = (0..n).map(|_| StandardNormal.sample(&mut rng)).collect();
            let y: Vec<f64> = (0..n)
                .map(|i| {
                    let delta: f64 = (0..=i).map(|j| ws.factor[i + j * n] * z[j]).sum();
                    let e: f64 = StandardNormal.sample(&mut rng);
                    truth[0] + truth[1] * x[i] + delta + err[i] * e
                })
                .collect();
            let data = measurements(&x, &y, &err);
            let rows: Vec<_> = data.iter().collect();
            let mut block = ObservableBlock::new("y", 0, &rows).unwrap();
            block.mean = 0.0;
            block.scale = 1.0;
            let lik = MdLikelihood::new(Arc::new(LinearModel), vec![block], Some(kernel));
            let out = Smc::new(SmcSettings { particles: 500, replicates: 2, ..Default::default() }).run(&prior, &lik, 77 + k as u64, &mdpipe::progress::Silent).unwrap();
            let mut covered = [[false; 2]; 5];
            for p in 0..5 {
                let mut d = out.chains.param(p);
                d.sort_by(|a, b| a.total_cmp(b));
                for (l, level) in levels.iter().enumerate() {
                    let lo = mdpipe::calibrate::diagnostics::quantile_sorted(&d, (1.0 - level) / 2.0);
                    let hi = mdpipe::calibrate::diagnostics::quantile_sorted(&d, (1.0 + level) / 2.0);
                    covered[p][l] = lo <= truth[p] && truth[p] <= hi;
                }
            }
            covered
        })
        .collect();
    let mut report = String::new();
    let mut failures = Vec::new();
    for p in 0..5 {
        for (l, level) in levels.iter().enumerate() {
            let count = results.iter().filter(|c| c[p][l]).count() as f64;
            let expected = level * datasets as f64;
            // Binomial standard deviation; 3.5σ keeps the false-failure rate
            // across the 10 checks below 0.5%.
            let sd = (datasets as f64 * level * (1.0 - level)).sqrt();
            report.push_str(&format!("param {p} level {level}: {count}/{datasets} (expected {expected} ± {sd:.1})\n"));
            if (count - expected).abs() > 3.5 * sd {
                failures.push(format!("param {p} level {level}: {count}"));
            }
        }
    }
    println!("{report}");
    assert!(failures.is_empty(), "coverage off:\n{report}");
}
