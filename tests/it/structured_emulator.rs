//! The structured likelihood with an emulator's covariance across
//! observables (its kept components, its truncation and the noise the runs
//! leave in its PCA, as blocks plus a low-rank term with indefinite weights)
//! equals the dense factorization of the same joint covariance: emulators
//! trained on noisy and on noise-free runs, one observable on a log scale,
//! data with a systematic across every table, Kernels I and II and no MD.

use mdpipe::base::artifacts::Measurement;
use mdpipe::calibrate::likelihood::block::ObservableBlock;
use mdpipe::calibrate::likelihood::joint::CrossEntry;
use mdpipe::calibrate::MdLikelihood;
use mdpipe::emulator::model::EmulatedModel;
use mdpipe::emulator::{train, EmulatorSettings, OutputKey, TrainingTable};
use mdpipe::gp::DiscrepancyKernel;
use mdpipe::model::Simulator;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::sync::Arc;

const OBSERVABLES: usize = 5;
const BINS: usize = 12;

fn x_of(k: usize) -> f64 {
    0.5 + k as f64
}

/// Five observables of twelve bins from `runs` runs of a smooth
/// two-parameter model, `noise` their runs' relative error; the first on a
/// log scale.
fn emulated(noise: f64, seed: u64, runs: usize) -> Arc<EmulatedModel> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let inputs: Vec<f64> = (0..2 * runs).map(|_| rng.random_range(0.0..1.0)).collect();
    let (mut values, mut errors, mut outputs) = (Vec::new(), Vec::new(), Vec::new());
    for o in 0..OBSERVABLES {
        for k in 0..BINS {
            outputs.push(OutputKey { observable: format!("o{o}"), x: x_of(k) });
        }
    }
    for u in inputs.chunks(2) {
        for o in 0..OBSERVABLES {
            for k in 0..BINS {
                let x = x_of(k);
                let mean = (1.0 + u[0] * (-(x / (2.0 + 3.0 * u[1]))).exp() + 0.2 * o as f64 * u[1] * x.sqrt()).exp();
                let e = noise * mean;
                values.push(mean + e * rng.random_range(-1.7..1.7));
                errors.push(e);
            }
        }
    }
    let table = TrainingTable {
        path: "synthetic".into(),
        parameter_names: vec!["a".into(), "b".into()],
        design_ids: (0..runs as i64).collect(),
        inputs,
        outputs,
        errors,
        noise_correlation: None,
        values,
    };
    let settings: EmulatorSettings =
        toml::from_str("parameters = [\"a\", \"b\"]\ncomponents = 4\nrestarts = 1\nlog_observables = [\"o0\"]")
            .unwrap();
    Arc::new(EmulatedModel::new(train(&table, &settings, 1).unwrap().0))
}

/// Measurements at every bin with a 3% systematic shared by every table.
fn data(model: &EmulatedModel) -> (Vec<ObservableBlock>, Vec<CrossEntry>) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
    let names = model.observable_names();
    let mut blocks = Vec::new();
    for (o, name) in names.iter().enumerate() {
        let x: Vec<f64> = (0..BINS).map(x_of).collect();
        let mut eta = vec![0.0; BINS];
        model.predict(o, &x, &[0.4, 0.6], &mut eta);
        let rows: Vec<Measurement> = x
            .iter()
            .zip(&eta)
            .map(|(x, y)| Measurement::new(name, *x, y * rng.random_range(0.95..1.05), 0.02 * y))
            .collect();
        let refs: Vec<&Measurement> = rows.iter().collect();
        let mut block = ObservableBlock::new(name, o, &refs).unwrap();
        let own: Vec<f64> = (0..BINS * BINS).map(|e| (0.03 * eta[e % BINS]) * (0.03 * eta[e / BINS])).collect();
        block.covariance = Some(own);
        blocks.push((block, eta));
    }
    let mut across = Vec::new();
    for b in 0..blocks.len() {
        for a in 0..b {
            for j in 0..BINS {
                for i in 0..BINS {
                    let covariance = 0.03 * blocks[a].1[i] * 0.03 * blocks[b].1[j];
                    across.push(CrossEntry {
                        block_a: a,
                        index_a: i,
                        block_b: b,
                        index_b: j,
                        covariance,
                        rounding: 0.0,
                    });
                }
            }
        }
    }
    (blocks.into_iter().map(|(b, _)| b).collect(), across)
}

fn parameters(kernel: Option<DiscrepancyKernel>, rng: &mut impl Rng) -> Vec<f64> {
    let mut p = vec![rng.random_range(0.05..0.95), rng.random_range(0.05..0.95)];
    let hyper = kernel.map_or(0, |k| k.n_hyper());
    p.extend((0..OBSERVABLES * hyper).map(|_| rng.random_range(0.2..3.0)));
    p
}

#[test]
fn the_emulators_covariance_across_observables_is_exact_in_the_structured_form() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
    let mut compared = 0;
    for (noise, seed) in [(0.03, 1), (0.0, 2), (0.1, 3)] {
        // Few runs for many points: the low-rank term (rank about the runs'
        // count, twice the kept components more with run noise) pays.
        let model = emulated(noise, seed, 14);
        let (blocks, across) = data(&model);
        for kernel in [None, Some(DiscrepancyKernel::KernelI), Some(DiscrepancyKernel::KernelII)] {
            let fast = MdLikelihood::new(model.clone(), blocks.clone(), kernel).joint(&across);
            let structure = fast.form.structure().expect("an emulator's covariance has the structured form");
            let model_rank = structure.model().map(|m| m.rank).expect("with the model's term");
            assert!(model_rank >= 4, "noise {noise}: rank {model_rank}");
            let dense = MdLikelihood::new(model.clone(), blocks.clone(), kernel).joint(&across).dense();
            for _ in 0..20 {
                let params = parameters(kernel, &mut rng);
                let (a, b) = (fast.log_likelihood(&params), dense.log_likelihood(&params));
                assert!(b.is_finite(), "dense {b} at {params:?}");
                assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "noise {noise} {kernel:?}: {a} vs {b} at {params:?}");
                compared += 1;
            }
            let params = parameters(kernel, &mut rng);
            let (factored, mut alpha) = fast.structured_system(&params).unwrap();
            let (lower, mut dense_alpha) = fast.joint_system(&params).unwrap();
            let n = dense_alpha.len();
            let mut chol = mdpipe::gp::CholeskyWorkspace::new(n);
            chol.factor.copy_from_slice(&lower);
            chol.factorize().unwrap();
            chol.solve_in_place(&mut dense_alpha);
            factored.solve_in_place(&mut alpha);
            let scale = dense_alpha.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, d) in alpha.iter().zip(&dense_alpha) {
                assert!((a - d).abs() <= 1e-9 * scale, "Σ⁻¹r {a} vs {d}");
            }
            let k: Vec<f64> = (0..BINS).map(|i| 0.3 + 0.1 * i as f64).collect();
            let mut whole = vec![0.0; n];
            whole[n - BINS..].copy_from_slice(&k);
            chol.solve_lower_in_place(&mut whole);
            let dense_quad: f64 = whole.iter().map(|v| v * v).sum();
            let quad = factored.block_quadratic(OBSERVABLES - 1, &mut k.clone());
            assert!((quad - dense_quad).abs() <= 1e-9 * dense_quad.abs(), "kᵀΣ⁻¹k {quad} vs {dense_quad}");
        }
    }
    println!("{compared} evaluations equal to the dense factorization's");
}

/// Noise-free runs, more of them than points: every dropped component is
/// kept in the truncation, the low-rank term would cost more than the dense
/// factorization, and the dense form is kept. (With run noise, the dropped
/// components that are noise carry no weight and the rank stays small.)
#[test]
fn an_emulator_of_more_runs_than_points_stays_dense() {
    let model = emulated(0.0, 5, 80);
    let (blocks, across) = data(&model);
    let lik = MdLikelihood::new(model, blocks, Some(DiscrepancyKernel::KernelII)).joint(&across);
    assert!(lik.form.structure().is_none());
}
