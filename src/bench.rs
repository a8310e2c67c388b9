//! `mdpipe bench`: throughput of the likelihood and of the full comparison grid.
//! Benchmarks, not tests: numbers vary with the machine, so they are printed,
//! never asserted.

use crate::calibrate::{compare, Overrides, Problem};
use crate::config::Config;
use crate::gp::DiscrepancyKernel;
use anyhow::Result;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;
use std::time::Instant;

#[derive(Debug, serde::Serialize)]
pub struct LikelihoodBench {
    pub kernel: String,
    pub dim: usize,
    pub n_points: usize,
    pub evaluations: usize,
    pub seconds: f64,
    pub evaluations_per_second_one_core: f64,
}

/// Single-threaded evaluations per second at prior draws (all observables).
pub fn likelihood_throughput(config: &Config, kernel: Option<DiscrepancyKernel>, evaluations: usize) -> Result<LikelihoodBench> {
    let problem = Problem::new(config, &Overrides { kernel: Some(kernel), ..Default::default() })?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let dim = problem.prior.dim();
    let points: Vec<Vec<f64>> = (0..1024)
        .map(|_| {
            let mut x = vec![0.0; dim];
            problem.prior.sample(&mut rng, &mut x);
            x
        })
        .collect();
    let mut sink = 0.0;
    for p in points.iter().take(100) {
        sink += problem.likelihood.log_likelihood(p);
    }
    let start = Instant::now();
    for i in 0..evaluations {
        sink += problem.likelihood.log_likelihood(&points[i % points.len()]);
    }
    let seconds = start.elapsed().as_secs_f64();
    std::hint::black_box(sink);
    Ok(LikelihoodBench {
        kernel: DiscrepancyKernel::label(kernel).into(),
        dim,
        n_points: problem.likelihood.blocks.iter().map(|b| b.len()).sum(),
        evaluations,
        seconds,
        evaluations_per_second_one_core: evaluations as f64 / seconds,
    })
}

#[derive(Debug, serde::Serialize)]
pub struct GridBench {
    pub case: String,
    pub sampler: String,
    pub seconds: f64,
    pub min_ess: f64,
    pub min_ess_per_second: f64,
    pub converged: bool,
}

/// Times the full 9-case comparison grid.
pub fn compare_grid(config: &Config, overrides: &Overrides, seed: u64, out: &Path) -> Result<(f64, Vec<GridBench>)> {
    let start = Instant::now();
    let cases = compare::run_grid(config, overrides, seed, out, false)?;
    let total = start.elapsed().as_secs_f64();
    let rows = cases
        .iter()
        .map(|c| {
            let d = &c.calibration.summary.diagnostics;
            let min_ess = d.parameters.iter().map(|p| p.ess_bulk.min(p.ess_tail)).fold(f64::INFINITY, f64::min);
            GridBench {
                case: c.dir_name.clone(),
                sampler: c.calibration.summary.sampler.clone(),
                seconds: d.wall_seconds,
                min_ess,
                min_ess_per_second: d.min_ess_per_second,
                converged: d.converged,
            }
        })
        .collect();
    Ok((total, rows))
}
