//! Adaptive design (`mdpipe refine`): where the simulator should run next so
//! that the emulator's uncertainty stops mattering to the posterior.
//!
//! **What is measured.** At posterior draws θ_b and data points j (an output
//! of the emulator with data error σ_j), the emulator's *latent* variance
//! var_j(θ_b): its uncertainty about the simulator's mean output, the part
//! well-placed runs reduce. Beside it, the *predictive* variance the
//! likelihood uses adds the PCA's own estimation noise (its mean and
//! directions come from noisy runs; it falls as 1/n with any new run) and a
//! *floor* that placing runs does not lower: white noise beyond the runs'
//! reported noise and the dropped components' signal
//! (`Emulator::variance_budget`; retraining on more runs may lower the
//! fitted white noise). Per observable the ratio
//! `sqrt(mean_{b,j} var_j(θ_b)/σ_j²)` says how the emulator's error compares
//! with the data's where the posterior lives. Refinement stops when the
//! *predictive* ratio is below 1 in every observable: what the likelihood
//! sees, so what decides whether the data or the emulator drives the
//! posterior.
//!
//! **Where to run.** Candidates are the posterior draws themselves. A run at
//! `a` lowers `U = Σ_b Σ_j var_j(θ_b)/σ_j²` by
//! `Σ_c Σ_b w_c(b) Σ_c(b,a)² / (Σ_c(a,a) + σ_n,c²)` (active learning Cohn,
//! ALC: Cohn 1996; Seo et al. 2000), where Σ_c is component c's latent
//! posterior covariance among the draws and `w_c(b) = Σ_j (s_c V_cj J_j(b))²/σ_j²`
//! maps it to data units (J: the log outputs' Jacobian). A batch is chosen
//! greedily: take the best draw, condition every component on a run there
//! (`LatentPosterior::condition_on_run_at`; exact, as GP variances do not
//! depend on what the run returns), repeat. Hyperparameters stay fixed
//! within a batch and are refitted when the emulator is retrained.

pub mod variant;

use crate::base::artifacts::{self, Measurement};
use crate::engine::emulator::latent::LatentPosterior;
use crate::engine::emulator::Emulator;
use anyhow::{anyhow, bail, Result};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use std::path::Path;

/// One data point as refinement sees it: an emulator output and its error.
#[derive(Clone, Debug)]
pub struct Target {
    pub output: usize,
    pub observable: String,
    pub error: f64,
}

/// Maps every data point to the emulator output it is compared with.
pub fn targets(emulator: &Emulator, data: &[Measurement]) -> Result<Vec<Target>> {
    data.iter()
        .map(|m| {
            let output = emulator.output_index(&m.observable, m.x).ok_or_else(|| {
                anyhow!("data point {} at x = {}: the emulator has no such output", m.observable, m.x)
            })?;
            if !(m.error > 0.0) {
                bail!("data point {} at x = {}: error {} is not positive", m.observable, m.x, m.error);
            }
            Ok(Target { output, observable: m.observable.clone(), error: m.error })
        })
        .collect()
}

/// How the emulator's error compares with the data error in one observable,
/// over the posterior draws (root mean square of sd/σ over draws and bins).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ObservableRatio {
    pub observable: String,
    /// The latent sd (what design points reduce).
    pub latent: f64,
    /// The largest bin's latent ratio.
    pub latent_max_bin: f64,
    /// The whole predictive sd the likelihood uses: latent, the PCA's
    /// estimation noise, scatter beyond the runs' reported noise, dropped
    /// components less their run noise.
    pub predictive: f64,
    /// The part of it placing runs does not reduce: white noise beyond the
    /// runs' reported noise and the dropped components' signal.
    #[serde(default)]
    pub floor: f64,
}

/// Per observable, the emulator's error over the data error at the draws.
pub fn ratios(emulator: &Emulator, draws: &[f64], targets: &[Target]) -> Vec<ObservableRatio> {
    let post = emulator.latent_posterior(draws);
    let latent = latent_ratio_terms(emulator, &post, targets);
    let predictive = predictive_ratio_terms(emulator, draws, targets);
    let floor = floor_ratio_terms(emulator, draws, targets);
    summarize(targets, post.points, &latent, &predictive, &floor)
}

/// `var_j(θ_b)/σ_j²` (row-major draws × targets) from a latent posterior.
fn latent_ratio_terms(emulator: &Emulator, post: &LatentPosterior, targets: &[Target]) -> Vec<f64> {
    let kc = emulator.n_components();
    let mut out = vec![0.0; post.points * targets.len()];
    let mut vars = vec![0.0; kc];
    for b in 0..post.points {
        let means = &post.means[b * kc..(b + 1) * kc];
        for (c, v) in vars.iter_mut().enumerate() {
            *v = post.var(c, b);
        }
        for (t, target) in targets.iter().enumerate() {
            let (_, jac) = emulator.output_mean_from_components(means, target.output);
            out[b * targets.len() + t] =
                emulator.output_var_from_component_vars(&vars, target.output, jac) / (target.error * target.error);
        }
    }
    out
}

/// The same with the whole predictive variance.
fn predictive_ratio_terms(emulator: &Emulator, draws: &[f64], targets: &[Target]) -> Vec<f64> {
    let kc = emulator.n_components();
    let b = draws.len() / emulator.n_parameters();
    let (mut means, mut vars) = (vec![0.0; b * kc], vec![0.0; b * kc]);
    emulator.predict_components_batch(draws, &mut means, &mut vars);
    let mut out = vec![0.0; b * targets.len()];
    for q in 0..b {
        for (t, target) in targets.iter().enumerate() {
            let (_, jac) = emulator.output_mean_from_components(&means[q * kc..(q + 1) * kc], target.output);
            out[q * targets.len() + t] = emulator.output_cov_from_components(
                &vars[q * kc..(q + 1) * kc],
                target.output,
                target.output,
                jac,
                jac,
            ) / (target.error * target.error);
        }
    }
    out
}

/// The same with the floor alone (scatter and dropped signal).
fn floor_ratio_terms(emulator: &Emulator, draws: &[f64], targets: &[Target]) -> Vec<f64> {
    emulator
        .variance_budgets(draws)
        .into_iter()
        .flat_map(|budget| {
            targets.iter().map(move |t| budget[t.output].floor() / (t.error * t.error)).collect::<Vec<_>>()
        })
        .collect()
}

fn summarize(
    targets: &[Target],
    draws: usize,
    latent: &[f64],
    predictive: &[f64],
    floor: &[f64],
) -> Vec<ObservableRatio> {
    let mut names: Vec<String> = Vec::new();
    for t in targets {
        if !names.contains(&t.observable) {
            names.push(t.observable.clone());
        }
    }
    let nt = targets.len();
    names
        .into_iter()
        .map(|name| {
            let cols: Vec<usize> = (0..nt).filter(|&t| targets[t].observable == name).collect();
            let rms = |terms: &[f64], cols: &[usize]| {
                (cols.iter().map(|&t| (0..draws).map(|b| terms[b * nt + t]).sum::<f64>()).sum::<f64>()
                    / (draws * cols.len()) as f64)
                    .sqrt()
            };
            let latent_max_bin = cols.iter().map(|&t| rms(latent, &[t])).fold(0.0, f64::max);
            ObservableRatio {
                latent: rms(latent, &cols),
                latent_max_bin,
                predictive: rms(predictive, &cols),
                floor: rms(floor, &cols),
                observable: name,
            }
        })
        .collect()
}

/// A batch of new design points.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Selection {
    /// The chosen θ, in the emulator's parameter order.
    pub points: Vec<Vec<f64>>,
    /// `U/(draws × data points)` before and, as forecast with the chosen runs, after.
    pub mean_ratio2_before: f64,
    pub mean_ratio2_after: f64,
    /// Per observable, the forecast ratios once the batch has run.
    pub forecast: Vec<ObservableRatio>,
}

/// Chooses `k` runs among the draws (row-major B × d) by greedy batch ALC.
pub fn select(emulator: &Emulator, draws: &[f64], targets: &[Target], k: usize) -> Selection {
    let mut post = emulator.latent_posterior(draws);
    let b = post.points;
    let weights = component_weights(emulator, &post, targets);
    let before = latent_ratio_terms(emulator, &post, targets);
    let d = emulator.n_parameters();
    let mut points = Vec::with_capacity(k);
    for _ in 0..k.min(b) {
        let best = (0..b)
            .map(|a| (a, reduction(&post, &weights, a)))
            .max_by(|x, y| x.1.total_cmp(&y.1))
            .map(|(a, _)| a)
            .unwrap_or(0);
        post.condition_on_run_at(best);
        points.push(draws[best * d..(best + 1) * d].to_vec());
    }
    let after = latent_ratio_terms(emulator, &post, targets);
    // The predictive and floor columns of the forecast are today's: the
    // forecast is of the latent part only.
    let predictive = predictive_ratio_terms(emulator, draws, targets);
    let floor = floor_ratio_terms(emulator, draws, targets);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    Selection {
        points,
        mean_ratio2_before: mean(&before),
        mean_ratio2_after: mean(&after),
        forecast: summarize(targets, b, &after, &predictive, &floor),
    }
}

/// `w_c(b)`: how much a unit of component c's latent variance at draw b
/// weighs in `U` (row-major draws × K).
fn component_weights(emulator: &Emulator, post: &LatentPosterior, targets: &[Target]) -> Vec<f64> {
    let kc = emulator.n_components();
    let mut w = vec![0.0; post.points * kc];
    let mut unit = vec![0.0; kc];
    for b in 0..post.points {
        let means = &post.means[b * kc..(b + 1) * kc];
        for t in targets {
            let (_, jac) = emulator.output_mean_from_components(means, t.output);
            for c in 0..kc {
                unit.iter_mut().for_each(|u| *u = 0.0);
                unit[c] = 1.0;
                w[b * kc + c] += emulator.output_var_from_component_vars(&unit, t.output, jac) / (t.error * t.error);
            }
        }
    }
    w
}

/// How much a run at draw `a` lowers `U`.
fn reduction(post: &LatentPosterior, weights: &[f64], a: usize) -> f64 {
    let (n, kc) = (post.points, post.covs.len());
    let mut total = 0.0;
    for c in 0..kc {
        let col = &post.covs[c][a * n..(a + 1) * n];
        let denom = col[a].max(0.0) + post.noise[c];
        if denom <= 0.0 {
            continue;
        }
        total += (0..n).map(|b| weights[b * kc + c] * col[b] * col[b]).sum::<f64>() / denom;
    }
    total
}

/// Up to `max` distinct posterior draws of the emulator's parameters from a
/// calibration's `posterior.parquet`, chosen at random (seeded), row-major.
pub fn read_draws(calibration: &Path, parameters: &[String], max: usize, seed: u64) -> Result<Vec<f64>> {
    let path = calibration.join("posterior.parquet");
    let df = artifacts::read_parquet(&path)?;
    let cols: Vec<Vec<f64>> = parameters
        .iter()
        .map(|p| -> Result<Vec<f64>> {
            let c =
                df.column(p).map_err(|_| anyhow!("{}: no column '{p}' (the emulator's parameter)", path.display()))?;
            Ok(c.f64()?.into_no_null_iter().collect())
        })
        .collect::<Result<_>>()?;
    let mut rows: Vec<Vec<f64>> = (0..df.height()).map(|i| cols.iter().map(|c| c[i]).collect()).collect();
    // SMC resampling repeats particles; a repeated draw adds nothing as a candidate.
    rows.sort_by(|a, b| {
        a.iter().zip(b).map(|(x, y)| x.total_cmp(y)).find(|o| o.is_ne()).unwrap_or(std::cmp::Ordering::Equal)
    });
    rows.dedup();
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
    rows.shuffle(&mut rng);
    rows.truncate(max);
    if rows.is_empty() {
        bail!("{}: no posterior draws", path.display());
    }
    Ok(rows.concat())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::emulator::{train, EmulatorParts, EmulatorSettings, OutputKey, TrainingTable};

    /// A noisy 2-parameter simulator with two outputs, emulated from 25 runs.
    fn small_emulator() -> Emulator {
        let n = 25;
        let unit = crate::engine::design::maximin_lhs(n, 2, 4);
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(8);
        let normal = rand_distr::Normal::new(0.0, 0.02).unwrap();
        let mut values = Vec::new();
        for u in unit.chunks(2) {
            use rand_distr::Distribution;
            values.push((3.0 * u[0]).sin() + u[1] * u[1] + normal.sample(&mut rng));
            values.push(u[0] * u[1] + 0.5 * u[0] + normal.sample(&mut rng));
        }
        let table = TrainingTable {
            path: "synthetic".into(),
            parameter_names: vec!["a".into(), "b".into()],
            design_ids: (0..n as i64).collect(),
            inputs: unit.clone(),
            outputs: vec![OutputKey { observable: "y".into(), x: 1.0 }, OutputKey { observable: "z".into(), x: 1.0 }],
            errors: vec![0.0; values.len()],
            noise_correlation: None,
            values,
        };
        let settings: EmulatorSettings =
            toml::from_str("parameters = [\"a\", \"b\"]\ncomponents = 2\nrestarts = 2").unwrap();
        train(&table, &settings, 1).unwrap().0
    }

    /// The emulator refitted with one more run at `theta`, hyperparameters fixed.
    fn with_run_at(emu: &Emulator, theta: &[f64]) -> Emulator {
        let mut parts: EmulatorParts = emu.parts.clone();
        let n = parts.design_ids.len();
        let kc = parts.n_components;
        parts.design_ids.push(n as i64);
        parts.train_inputs.extend_from_slice(theta);
        parts.train_values.extend(vec![0.0; emu.n_outputs()]);
        // The variances do not depend on the new run's output; any score will do.
        let mut scores = Vec::with_capacity(kc * (n + 1));
        for c in 0..kc {
            scores.extend_from_slice(&parts.scores[c * n..(c + 1) * n]);
            scores.push(0.3);
        }
        parts.scores = scores;
        // Keep each component's scale S_k/√n as it was (a retrain would redo the PCA).
        let grow = ((n + 1) as f64 / n as f64).sqrt();
        parts.singular_values.iter_mut().for_each(|s| *s *= grow);
        Emulator::from_parts(parts).unwrap()
    }

    fn grid_draws() -> Vec<f64> {
        (0..6).flat_map(|i| (0..5).flat_map(move |j| [0.3 + 0.05 * i as f64, 0.4 + 0.04 * j as f64])).collect()
    }

    #[test]
    fn latent_variance_is_the_predictive_variance_without_the_run_noise() {
        let emu = small_emulator();
        let draws = grid_draws();
        let post = emu.latent_posterior(&draws);
        let kc = emu.n_components();
        let mut scratch = emu.scratch();
        let (mut m, mut v) = (vec![0.0; kc], vec![0.0; kc]);
        for b in 0..post.points {
            emu.predict_components(&draws[2 * b..2 * b + 2], &mut m, &mut v, &mut scratch);
            for c in 0..kc {
                assert!((m[c] - post.means[b * kc + c]).abs() < 1e-10);
                let expect = v[c] - post.noise[c];
                assert!(
                    (post.var(c, b) - expect).abs() < 1e-9 * (1.0 + expect.abs()),
                    "c {c} b {b}: {} vs {expect}",
                    post.var(c, b)
                );
            }
        }
    }

    #[test]
    fn conditioning_on_a_run_matches_refitting_with_it() {
        // The rank-one downdate against an independent route: the GP rebuilt
        // from scratch (new Cholesky) with the run added.
        let emu = small_emulator();
        let draws = grid_draws();
        let mut post = emu.latent_posterior(&draws);
        let a = 7;
        post.condition_on_run_at(a);
        let refit = with_run_at(&emu, &draws[2 * a..2 * a + 2]).latent_posterior(&draws);
        for c in 0..emu.n_components() {
            for (x, y) in post.covs[c].iter().zip(&refit.covs[c]) {
                assert!((x - y).abs() < 1e-9, "component {c}: {x} vs {y}");
            }
        }
    }

    #[test]
    fn the_forecast_reduction_is_what_the_refitted_emulator_shows() {
        let emu = small_emulator();
        let draws = grid_draws();
        let targets = vec![
            Target { output: 0, observable: "y".into(), error: 0.01 },
            Target { output: 1, observable: "z".into(), error: 0.01 },
        ];
        let sel = select(&emu, &draws, &targets, 3);
        assert_eq!(sel.points.len(), 3);
        assert!(sel.mean_ratio2_after < sel.mean_ratio2_before);
        let mut refit = emu.clone();
        for p in &sel.points {
            refit = with_run_at(&refit, p);
        }
        let post = refit.latent_posterior(&draws);
        let measured: f64 =
            latent_ratio_terms(&refit, &post, &targets).iter().sum::<f64>() / (post.points * targets.len()) as f64;
        // Refitting leaves the means, and so the Jacobians, unchanged here (no log outputs).
        assert!(
            (measured - sel.mean_ratio2_after).abs() < 1e-9 * sel.mean_ratio2_before,
            "{measured} vs {}",
            sel.mean_ratio2_after
        );
        // Greedy ALC beats every one of 20 random batches of 3 prior-box points.
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        for _ in 0..20 {
            use rand::Rng;
            let mut r = emu.clone();
            for _ in 0..3 {
                r = with_run_at(&r, &[rng.random::<f64>(), rng.random::<f64>()]);
            }
            let post = r.latent_posterior(&draws);
            let random: f64 =
                latent_ratio_terms(&r, &post, &targets).iter().sum::<f64>() / (post.points * targets.len()) as f64;
            assert!(sel.mean_ratio2_after < random, "ALC {} vs random {random}", sel.mean_ratio2_after);
        }
    }
}
