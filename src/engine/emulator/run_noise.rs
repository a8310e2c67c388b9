//! The training runs' own statistical noise, separated from what the
//! emulator does not know about the simulator's mean.
//!
//! A calibration compares measurements with the simulator's *mean* output
//! (an infinite-statistics run); a training run of a few hundred events
//! scatters around it by its jackknife error. Fitted on such runs, each
//! component's GP puts that scatter into its white-noise term, and the
//! dropped components are mostly that scatter too. Left in the likelihood,
//! it would count one run's noise as model uncertainty, which no number of
//! design points reduces.
//!
//! What the runs report is removed, and only that. Per component k, the
//! runs' noise covariance projected on its loading is `ν_k = v_kᵀ N v_k / σ_k²`
//! (standardized, whitened units). N has the runs' mean squared errors on
//! its diagonal (in the transformed scale) and, when the table carries the
//! runs' pooled error correlation R, `N_ab = R_ab √(N_aa N_bb)` off it. Bins
//! of one run share its events: in the bundled heavy-ion study the spectrum
//! bins' errors are correlated by 0.6–0.95, and the leading component (the
//! spectra's common normalization) carries three times the noise that
//! independent errors would project on it (0.0084 against 0.0027, with a GP
//! nugget of 0.0074). Taken as independent, that nugget stayed in every
//! prediction as model uncertainty.
//! * A kept component loses `ν_k`, capped at its GP's noise variance.
//! * The dropped components lose one common fraction: the projected noise
//!   summed over all of them over their summed variance, capped at 1. Their
//!   directions come from the sample PCA, which orders pure noise by its
//!   sampled variance (Marchenko–Pastur spread; with 70 outputs and 217 runs
//!   a noise eigenvalue ranges from 0.2 to 2.5 times its mean). Per
//!   direction, `ν_k` is therefore biased low exactly where the sample
//!   variance came out high, and a per-direction cap left up to 3.9 times
//!   the data error of pure noise in the bundled study's truncation
//!   covariance. The trace over the dropped subspace has no such selection,
//!   so the signal left there is estimated from it.
//!
//! The PCA itself is estimated from the noisy runs: the training mean it is
//! centred on, and the kept directions, whose tilt leaks the mean's signal
//! into the dropped subspace. Both are added to every prediction of the
//! simulator's mean (`pca_noise_cov`).
//! Any scatter beyond the reported errors (roughness the GP cannot follow)
//! stays; the caps keep the removal from exceeding what was fitted. Runs
//! without errors (deterministic simulators) remove nothing.

/// Per output, the runs' mean squared statistical error in standardized,
/// transformed units (`e/y` for log outputs, first order).
pub fn output_noise_var(parts: &super::EmulatorParts) -> Vec<f64> {
    let (n, m) = (parts.design_ids.len(), parts.outputs.len());
    if n == 0 || parts.train_errors.len() != n * m {
        return vec![0.0; m];
    }
    (0..m)
        .map(|j| {
            // A constant output (std 0) is emulated exactly: no noise to remove.
            if parts.output_std[j] <= 0.0 {
                return 0.0;
            }
            let scale = |i: usize| if parts.log_transform[j] { 1.0 / parts.train_values[i * m + j].abs() } else { 1.0 };
            let mean_sq: f64 =
                (0..n).map(|i| (parts.train_errors[i * m + j] * scale(i)).powi(2)).sum::<f64>() / n as f64;
            let v = mean_sq / (parts.output_std[j] * parts.output_std[j]);
            // An error whose square overflows says nothing usable about this
            // output's noise: remove none here rather than poison every
            // component's projection (and so every output) with an infinity.
            if v.is_finite() {
                v
            } else {
                0.0
            }
        })
        .collect()
}

/// The runs' noise covariance N (m × m, standardized transformed units): the
/// mean squared errors on the diagonal, and with the table's pooled error
/// correlation R, `R_ab √(N_aa N_bb)` off it.
pub fn output_noise_cov(parts: &super::EmulatorParts) -> Vec<f64> {
    let var = output_noise_var(parts);
    let m = var.len();
    let correlated = parts.noise_correlation.len() == m * m;
    let mut cov = vec![0.0; m * m];
    for a in 0..m {
        for b in 0..m {
            cov[a * m + b] = if a == b {
                var[a]
            } else if correlated {
                parts.noise_correlation[a * m + b] * (var[a] * var[b]).sqrt()
            } else {
                0.0
            };
        }
    }
    cov
}

/// `vᵀ N v` for a loading v (m) and N (m × m).
fn projected(v: &[f64], noise: &[f64]) -> f64 {
    let m = v.len();
    (0..m).map(|a| v[a] * (0..m).map(|b| noise[a * m + b] * v[b]).sum::<f64>()).sum()
}

/// The covariance (m × m, standardized transformed units) that the runs'
/// noise leaves in the PCA itself, to first order in the noise:
/// `(1 + w) · P N P / n`, with N the runs' noise covariance
/// ([`output_noise_cov`]), n runs, P the projector onto the dropped subspace
/// and `w = Σ_kept (1 − ν_k)₊` the kept components' signal fractions.
/// * The training mean, on which the PCA is centred, is an average of n
///   noisy runs, with error `N/n`. Along a kept direction that error is an
///   unknown level of the component's scores, which its GP learns from the
///   same noisy scores and so already counts (about its nugget / n); the
///   dropped part, `P N P/n`, no GP carries. (Adding all of `N/n` counted
///   the kept part twice: with errors correlated along the leading
///   component, the mean prediction came out twice too wide, z² 0.49.)
/// * Each kept direction is estimated from the same runs. Perturbation
///   theory gives its tilt into the dropped subspace a covariance of
///   `P N P/(n λ_k)` (λ_k the component's variance), and the simulator
///   mean's score along it, whose variance over θ is only the signal's part
///   of λ_k, `S_k = λ_k(1 − ν_k)`, leaks `(1 − ν_k) P N P/n` into outputs
///   that the dropped components, and no GP, carry. A kept component of
///   pure noise (ν_k ≥ 1) has no mean to leak; counting every kept one as
///   signal overstated this by K/w (8 against about 2 in the bundled study).
///
/// With many outputs each output's share of the kept GPs' uncertainty is
/// smaller than these, and leaving them out made the mean prediction
/// overconfident (z² 3.8 with 40 outputs; see the tests).
pub fn pca_noise_cov(parts: &super::EmulatorParts) -> Vec<f64> {
    let (n, m, kept) = (parts.design_ids.len().max(1) as f64, parts.outputs.len(), parts.n_components);
    let noise = output_noise_cov(parts);
    let mut cov = vec![0.0; m * m];
    if noise.iter().all(|v| *v == 0.0) {
        return cov;
    }
    let signal_weight = pca_noise_signal_weight(parts, &noise);
    // P = I − Σ_kept v vᵀ, then P N P.
    let mut p = vec![0.0; m * m];
    for a in 0..m {
        p[a * m + a] = 1.0;
    }
    for v in parts.basis.chunks(m).take(kept) {
        for a in 0..m {
            for b in 0..m {
                p[a * m + b] -= v[a] * v[b];
            }
        }
    }
    let mut np = vec![0.0; m * m];
    for a in 0..m {
        for b in 0..m {
            np[a * m + b] = (0..m).map(|c| noise[a * m + c] * p[c * m + b]).sum();
        }
    }
    for a in 0..m {
        for b in 0..m {
            let pnp: f64 = (0..m).map(|c| p[a * m + c] * np[c * m + b]).sum();
            cov[a * m + b] = (1.0 + signal_weight) * pnp / n;
        }
    }
    cov
}

/// `w = Σ_kept (1 − ν_k)₊` of [`pca_noise_cov`], for the runs' noise
/// covariance `noise`: the kept components' signal fractions.
pub fn pca_noise_signal_weight(parts: &super::EmulatorParts, noise: &[f64]) -> f64 {
    let (n, m, kept) = (parts.design_ids.len().max(1) as f64, parts.outputs.len(), parts.n_components);
    parts
        .basis
        .chunks(m)
        .zip(&parts.singular_values)
        .take(kept)
        .map(|(v, s)| {
            let var = s * s / n;
            if var > 0.0 {
                (1.0 - finite_or_zero(projected(v, noise) / var)).max(0.0)
            } else {
                0.0
            }
        })
        .sum()
}

/// Per component (kept, then dropped), the run-noise variance removed from
/// it in whitened units: `min(ν_k, noise_var_k)` for a kept one, and for
/// every dropped one the same `min(Σ_d ν_d σ_d² / Σ_d σ_d², 1)` (see the
/// module docs).
pub fn removed_per_component(parts: &super::EmulatorParts, component_sd: &[f64], kept_noise_var: &[f64]) -> Vec<f64> {
    let noise = output_noise_cov(parts);
    let m = parts.outputs.len();
    // The run noise projected on component k, in the component's (unwhitened) units.
    let projected = |k: usize| -> f64 { projected(&parts.basis[k * m..(k + 1) * m], &noise) };
    let kept = kept_noise_var.len().min(component_sd.len());
    let removed_kept = (0..kept).map(|k| {
        let var = component_sd[k] * component_sd[k];
        // Remove nothing rather than a NaN (which `min` would turn into the cap).
        if var > 0.0 {
            finite_or_zero(projected(k) / var).min(kept_noise_var[k])
        } else {
            0.0
        }
    });
    let dropped_var: f64 = component_sd[kept..].iter().map(|s| s * s).sum();
    let dropped_noise: f64 = (kept..component_sd.len()).map(projected).sum();
    let fraction = if dropped_var > 0.0 { finite_or_zero(dropped_noise / dropped_var).min(1.0) } else { 0.0 };
    removed_kept.chain(component_sd[kept..].iter().map(|s| if *s > 0.0 { fraction } else { 0.0 })).collect()
}

fn finite_or_zero(v: f64) -> f64 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two outputs, one component along (1, 1)/√2: ν is the loading-weighted
    /// mean squared error over the component's variance, capped.
    #[test]
    fn removal_is_the_projected_error_capped_at_what_the_component_carries() {
        let s = 0.5_f64.sqrt();
        let parts = super::super::EmulatorParts {
            parameter_names: vec!["a".into()],
            design_ids: vec![0, 1],
            train_inputs: vec![0.0, 1.0],
            train_values: vec![1.0, 2.0, 3.0, 4.0],
            train_errors: vec![0.1, 0.3, 0.1, 0.3],
            noise_correlation: vec![],
            input_lo: vec![0.0],
            input_hi: vec![1.0],
            kernel: crate::engine::gp::ArdKernel::Matern52,
            outputs: vec![
                super::super::OutputKey { observable: "y".into(), x: 1.0 },
                super::super::OutputKey { observable: "y".into(), x: 2.0 },
            ],
            log_transform: vec![false, false],
            output_mean: vec![0.0, 0.0],
            output_std: vec![1.0, 2.0],
            singular_values: vec![1.0, 1.0],
            basis: vec![s, s, s, -s],
            n_components: 1,
            scores: vec![],
            hypers: vec![],
        };
        let noise = output_noise_var(&parts);
        assert!((noise[0] - 0.01).abs() < 1e-15 && (noise[1] - 0.09 / 4.0).abs() < 1e-15);
        // ν_0 = (½·0.01 + ½·0.0225)/0.2² = 0.40625; capped at the kept GP's 0.3.
        let removed = removed_per_component(&parts, &[0.2, 0.2], &[0.3]);
        assert!((removed[0] - 0.3).abs() < 1e-15);
        assert!((removed[1] - 0.40625).abs() < 1e-12);
        let constant = super::super::EmulatorParts { output_std: vec![0.0, 2.0], ..parts.clone() };
        assert_eq!(output_noise_var(&constant)[0], 0.0);
        assert!(removed_per_component(&constant, &[0.2, 0.2], &[0.3]).iter().all(|r| r.is_finite()));
        // Both dropped: one common fraction, the summed projected noise (0.01625
        // on each) over the summed variance (0.04 + 0.01), not 0.406 and 1.625 → 1.
        let all_dropped = removed_per_component(&parts, &[0.2, 0.1], &[]);
        assert!(all_dropped.iter().all(|r| (r - 0.65).abs() < 1e-12), "{all_dropped:?}");
        // An error whose square overflows makes its output's noise unknown
        // (none removed there), and leaves the other output's as it was.
        let huge = super::super::EmulatorParts { train_errors: vec![1e308, 0.3, 0.1, 0.3], ..parts.clone() };
        let huge_noise = output_noise_var(&huge);
        assert!(huge_noise[0] == 0.0 && huge_noise[1] == noise[1], "{huge_noise:?}");
        assert!(pca_noise_cov(&huge).iter().all(|v| v.is_finite()));
        assert!(removed_per_component(&huge, &[0.2, 0.2], &[0.3]).iter().all(|r| r.is_finite() && *r > 0.0));
        let none = super::super::EmulatorParts { train_errors: vec![0.0; 4], ..parts };
        assert_eq!(removed_per_component(&none, &[0.2, 0.2], &[0.3]), vec![0.0, 0.0]);
    }

    /// The runs' noise: each output's error is `σ(√ρ c + √(1−ρ) z_j)`, one
    /// common c per run, so equicorrelated by ρ; `told` says whether the
    /// table carries that correlation.
    #[derive(Clone, Copy)]
    struct Noise {
        rho: f64,
        told: bool,
    }
    const INDEPENDENT: Noise = Noise { rho: 0.0, told: false };

    /// Mean z² of three predictions, and the largest share of a kept
    /// component's GP nugget that was left in as uncertainty about the mean.
    struct Z2 {
        mean_vs_mean: f64,
        run_vs_mean: f64,
        run_vs_runs: f64,
        nugget_left: f64,
    }

    /// A stochastic simulator with a known mean whose runs report their noise
    /// (sd 0.1). Against the true mean, the predictive sd without the run
    /// noise gives z-scores of unit variance; the sd with it is too wide
    /// (z² near latent²/(latent² + noise²), far below 1). Against fresh
    /// noisy runs, the sd with the noise is the right one.
    ///
    /// Tolerances: 5 training sets × 200 test points × the outputs, z²
    /// averaged. For unit-variance z the mean of z² has sd √(2/4000) ≈ 0.02
    /// with independent terms; outputs and nearby points share each set's GP
    /// error, so an effective count of 100 (sd 0.14) is assumed and the band
    /// is ±3 of those around 1, [0.58, 1.42].
    fn z2_over_training_sets(outputs: usize, runs: usize, case: Noise) -> Z2 {
        use crate::engine::emulator::{train, EmulatorSettings, OutputKey, TrainingTable};
        use rand::SeedableRng;
        use rand_distr::Distribution;
        // Rank two: the two kept components carry all of the mean, the dropped
        // ones only noise. (With a full-rank truth and two components kept, z²
        // against the mean was 1.43: the dropped components' signal varies with
        // θ, which a constant truncation covariance cannot follow. That is not
        // what these tests are about.) With correlated noise, f moves every
        // output alike (a spectrum's normalization), so its component is the
        // common mode that the noise shares.
        let f_loading = |j: usize| if case.rho > 0.0 { 1.0 } else { (0.7 * j as f64).cos() };
        let truth = |u: &[f64]| -> Vec<f64> {
            let (f, g) = ((1.5 * u[0]).sin() + u[1], u[0] * u[1] + 0.5 * u[0]);
            (0..outputs).map(|j| f_loading(j) * f + (0.7 * j as f64).sin() * g + 0.1 * j as f64).collect()
        };
        let sigma = 0.1;
        let correlation: Vec<f64> =
            (0..outputs * outputs).map(|ab| if ab % (outputs + 1) == 0 { 1.0 } else { case.rho }).collect();
        let (mut mean_z2, mut run_z2_vs_mean, mut run_z2_vs_runs, mut count, mut nugget_left) =
            (0.0, 0.0, 0.0, 0.0, 0.0f64);
        for seed in 0..5 {
            let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
            let uniform = rand_distr::Uniform::new(0.0, 1.0).unwrap();
            let noise = rand_distr::Normal::new(0.0, sigma).unwrap();
            let run_noise = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus| -> Vec<f64> {
                let common = noise.sample(rng);
                (0..outputs).map(|_| case.rho.sqrt() * common + (1.0 - case.rho).sqrt() * noise.sample(rng)).collect()
            };
            let inputs: Vec<f64> = (0..2 * runs).map(|_| uniform.sample(&mut rng)).collect();
            let values: Vec<f64> = inputs
                .chunks(2)
                .flat_map(|u| truth(u).into_iter().zip(run_noise(&mut rng)).map(|(t, e)| t + e).collect::<Vec<_>>())
                .collect();
            let table = TrainingTable {
                path: "synthetic".into(),
                parameter_names: vec!["a".into(), "b".into()],
                design_ids: (0..runs as i64).collect(),
                inputs,
                outputs: (0..outputs).map(|j| OutputKey { observable: "y".into(), x: j as f64 }).collect(),
                errors: vec![sigma; values.len()],
                noise_correlation: case.told.then(|| correlation.clone()),
                values,
            };
            let settings: EmulatorSettings =
                toml::from_str("parameters = [\"a\", \"b\"]\ncomponents = 2\nrestarts = 3").unwrap();
            let emu = train(&table, &settings, seed).unwrap().0;
            for (gp, removed) in emu.gps.iter().zip(&emu.run_noise) {
                nugget_left = nugget_left.max(1.0 - removed / gp.noise_var);
            }
            for _ in 0..200 {
                let u = [uniform.sample(&mut rng), uniform.sample(&mut rng)];
                let (mean, run) = (emu.predict(&u), emu.predict_run(&u));
                let fresh_noise = run_noise(&mut rng);
                for (j, t) in truth(&u).iter().enumerate() {
                    let fresh_run = t + fresh_noise[j];
                    mean_z2 += ((mean.mean[j] - t) / mean.sd(j)).powi(2);
                    run_z2_vs_mean += ((run.mean[j] - t) / run.sd(j)).powi(2);
                    run_z2_vs_runs += ((run.mean[j] - fresh_run) / run.sd(j)).powi(2);
                    count += 1.0;
                }
            }
        }
        let z2 = Z2 {
            mean_vs_mean: mean_z2 / count,
            run_vs_mean: run_z2_vs_mean / count,
            run_vs_runs: run_z2_vs_runs / count,
            nugget_left,
        };
        crate::base::messages::say!(
            "{outputs} outputs, {runs} runs, noise correlation {} ({}): z² against the true mean: {:.3} (mean prediction), {:.3} (run prediction); against fresh runs: {:.3}; largest nugget share left: {:.3}",
            case.rho,
            if case.told { "in the table" } else { "not in the table" },
            z2.mean_vs_mean,
            z2.run_vs_mean,
            z2.run_vs_runs,
            z2.nugget_left
        );
        z2
    }

    fn assert_calibrated(z2: &Z2) {
        assert!(
            (0.58..=1.42).contains(&z2.mean_vs_mean),
            "mean prediction against the true mean: z² {:.3}",
            z2.mean_vs_mean
        );
        assert_run_prediction_calibrated(z2);
    }

    fn assert_run_prediction_calibrated(z2: &Z2) {
        assert!((0.58..=1.42).contains(&z2.run_vs_runs), "run prediction against fresh runs: z² {:.3}", z2.run_vs_runs);
        assert!(z2.run_vs_mean < 0.3, "with the run noise the sd is too wide for the mean: z² {:.3}", z2.run_vs_mean);
    }

    /// Four outputs, 80 runs, two of four components kept.
    #[test]
    fn the_mean_prediction_leaves_out_the_runs_noise_and_only_that() {
        assert_calibrated(&z2_over_training_sets(4, 80, INDEPENDENT));
    }

    /// 40 outputs and 100 runs, two components kept: 38 dropped directions of
    /// pure noise, ordered by their sampled variance. The summed removal must
    /// leave none of it in the truncation covariance.
    #[test]
    fn many_dropped_noise_directions_leave_no_noise_behind() {
        assert_calibrated(&z2_over_training_sets(40, 100, INDEPENDENT));
    }

    /// 40 outputs whose errors are correlated by 0.7 within a run, as the
    /// bins of one spectrum are, with the signal's leading component their
    /// common mode: 28 times the noise an independent-error projection sees
    /// lies along it.
    /// * With the correlation in the table, the kept GPs' nuggets are removed
    ///   (what is left is at most the scatter of a nugget fitted to 100 runs,
    ///   relative sd √(2/100); 3 of those is 0.42), and the run prediction
    ///   is calibrated against fresh runs.
    /// * Without it, nearly all of the leading component's nugget stays in as
    ///   uncertainty about the mean: the diagonal projection sees 1/28 of
    ///   it, so even a nugget 3 of its sd (0.42) low leaves over 1 − 1/16;
    ///   the bound is 0.9. The mean prediction is then far wider (its z²
    ///   falls at least by half; measured 0.072 against 0.561).
    ///
    /// The mean prediction's z² with the correlation (0.56, measured) is not
    /// held to the band: it is that of the kept GPs themselves, which fitted
    /// to noisy scores are wide here (their own z² 0.60 and 0.66, measured
    /// per component), and that no run-noise rule can change.
    #[test]
    fn correlated_run_noise_is_removed_when_the_table_carries_its_correlation() {
        let told = z2_over_training_sets(40, 100, Noise { rho: 0.7, told: true });
        assert!(told.nugget_left < 0.42, "with the correlation, {:.3} of a nugget was left", told.nugget_left);
        assert_run_prediction_calibrated(&told);
        let untold = z2_over_training_sets(40, 100, Noise { rho: 0.7, told: false });
        assert!(
            untold.nugget_left > 0.9,
            "without the correlation, only {:.3} of the leading nugget should be left out",
            untold.nugget_left
        );
        assert!(
            untold.mean_vs_mean < 0.5 * told.mean_vs_mean,
            "without the correlation the mean prediction should be far wider: z² {:.3} against {:.3}",
            untold.mean_vs_mean,
            told.mean_vs_mean
        );
    }
}
