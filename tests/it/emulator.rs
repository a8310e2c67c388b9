//! The emulator stage: accuracy and calibrated uncertainty on an analytic
//! vector-valued function, analytic gradients against finite differences,
//! bit-identical reload, clear errors on bad tables, and calibration through
//! an emulator reproducing calibration with the exact model.

use mdpipe::calibrate::{self, Overrides, Problem};
use mdpipe::emulator::{self, read_training_table, store, train, validate, EmulatorSettings};
use mdpipe::gp::{ard_log_marginal_likelihood, ArdHyper, ArdKernel};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::{Path, PathBuf};

fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mdpipe-it-emulator-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

const BINS: usize = 10;

/// A smooth 3-input, 60-output stand-in for binned observables: two
/// exponential "spectra" (emulated in log space) and four "flow" curves.
fn analytic(theta: &[f64]) -> Vec<(String, f64, f64)> {
    let (a, b, c) = (theta[0], theta[1], theta[2]);
    let mut out = Vec::new();
    for bin in 0..BINS {
        let x = 0.1 + 0.2 * bin as f64;
        for k in 0..2 {
            let slope = 0.2 + 0.3 * a + 0.1 * k as f64 + 0.05 * b * c;
            out.push((format!("spectrum{k}"), x, (1.0 + 0.5 * b) * (-x / slope).exp()));
        }
        for k in 0..4 {
            let damp = (-(k as f64 + 1.0) * (0.5 + 1.5 * b) * 0.3 * x).exp();
            out.push((
                format!("flow{k}"),
                x,
                (0.12 - 0.02 * k as f64) * x * damp * (1.0 - 0.4 * a + 0.2 * c) + 0.01 * (2.0 * c).cos() * x,
            ));
        }
    }
    out
}

/// Writes a long CSV table of `points` random designs, with multiplicative
/// noise of relative size `noise` (finite-event statistics).
fn write_table(path: &Path, points: usize, noise: f64, seed: u64) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut text = String::from("design_id,observable,x,value,a,b,c\n");
    for i in 0..points {
        let theta: Vec<f64> = (0..3).map(|_| rng.random::<f64>()).collect();
        for (obs, x, v) in analytic(&theta) {
            let z: f64 = rng.sample(StandardNormal);
            text.push_str(&format!("{i},{obs},{x},{},{},{},{}\n", v * (1.0 + noise * z), theta[0], theta[1], theta[2]));
        }
    }
    std::fs::write(path, text).unwrap();
}

fn settings(components: Option<usize>) -> EmulatorSettings {
    EmulatorSettings {
        parameters: vec!["a".into(), "b".into(), "c".into()],
        kernel: "matern52".into(),
        components,
        variance_fraction: 0.999,
        restarts: 4,
        max_iters: 200,
        log_observables: vec!["spectrum0".into(), "spectrum1".into()],
        observables: Vec::new(),
    }
}

fn params() -> Vec<String> {
    settings(None).parameters
}

#[test]
fn held_out_error_is_small_and_intervals_are_calibrated() {
    let dir = tmpdir("accuracy");
    write_table(&dir.join("train.csv"), 100, 0.01, 1);
    write_table(&dir.join("val.csv"), 200, 0.01, 2);
    let table = read_training_table(&dir.join("train.csv"), &params()).unwrap();
    assert_eq!((table.n_points(), table.n_outputs()), (100, 60));
    let (emu, report) = train(&table, &settings(None), 1).unwrap();
    assert_eq!(report.failures, 0, "{:?}", report.runs);
    let val = read_training_table(&dir.join("val.csv"), &params()).unwrap();
    let rows = validate::parity(&emu, &val, "holdout").unwrap();
    let summary = validate::summarize(&rows);
    // Coverage is counted over points × bins, but bins of one point are
    // correlated, so the Monte Carlo error uses the number of points.
    let n_val = val.n_points() as f64;
    let tol95 = 3.0 * (0.95f64 * 0.05 / n_val).sqrt();
    let tol68 = 3.0 * (0.68f64 * 0.32 / n_val).sqrt();
    for s in &summary {
        println!(
            "{:<10} RMSE/spread {:.4}  cov68 {:.3}  cov95 {:.3}",
            s.observable, s.relative_rmse, s.coverage_68, s.coverage_95
        );
        // The 1% noise alone puts a floor of about 0.01 × value / spread on this.
        assert!(s.relative_rmse < 0.1, "{}: relative RMSE {}", s.observable, s.relative_rmse);
        assert!(
            (s.coverage_95 - 0.95).abs() < tol95,
            "{}: 95% coverage {} (tolerance {tol95:.3})",
            s.observable,
            s.coverage_95
        );
        assert!(
            (s.coverage_68 - 0.68).abs() < tol68,
            "{}: 68% coverage {} (tolerance {tol68:.3})",
            s.observable,
            s.coverage_68
        );
    }
}

#[test]
fn marginal_likelihood_gradient_matches_finite_differences() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let (n, d) = (30, 3);
    let x: Vec<f64> = (0..n * d).map(|_| rng.random::<f64>()).collect();
    let y: Vec<f64> = (0..n)
        .map(|i| (3.0 * x[i * d]).sin() + x[i * d + 1] * x[i * d + 2] + 0.05 * rng.sample::<f64, _>(StandardNormal))
        .collect();
    for kernel in [ArdKernel::SquaredExponential, ArdKernel::Matern52] {
        let hyper = ArdHyper { log_params: vec![0.3, -0.9, -0.4, 0.2, -2.0, -4.0] };
        let mut grad = vec![0.0; 6];
        ard_log_marginal_likelihood(kernel, &hyper, &x, &y, Some(&mut grad)).unwrap();
        for k in 0..6 {
            let h = 1e-5;
            let mut up = hyper.clone();
            up.log_params[k] += h;
            let mut dn = hyper.clone();
            dn.log_params[k] -= h;
            let fd = (ard_log_marginal_likelihood(kernel, &up, &x, &y, None).unwrap()
                - ard_log_marginal_likelihood(kernel, &dn, &x, &y, None).unwrap())
                / (2.0 * h);
            // Central differences are accurate to O(h²) ≈ 1e-10 relative; rounding adds ~1e-8.
            assert!(
                (grad[k] - fd).abs() < 1e-6 * fd.abs().max(1.0),
                "{kernel:?} parameter {k}: analytic {} vs finite difference {fd}",
                grad[k]
            );
        }
    }
}

#[test]
fn mean_gradient_matches_finite_differences_and_reload_is_bit_identical() {
    let dir = tmpdir("reload");
    write_table(&dir.join("train.csv"), 60, 0.01, 3);
    let table = read_training_table(&dir.join("train.csv"), &params()).unwrap();
    let set = settings(Some(4));
    let (emu, report) = train(&table, &set, 2).unwrap();
    let theta = [0.37, 0.52, 0.71];
    let (mean, jac) = emu.mean_gradient(&theta);
    let d = 3;
    // Central differences at two steps: their disagreement measures the
    // finite-difference error, which sets the tolerance. The steps balance
    // truncation against rounding: the mean αᵀk cancels between large terms
    // and carries ~5e-12 of rounding noise here, 1e-7 of the slope at a step
    // of 5e-5 (measured with libm's exp and the vector one alike), which the
    // two steps' disagreement does not see; at 5e-4 it is 1e-8.
    let central = |p: usize, h: f64| -> Vec<f64> {
        let (mut up, mut dn) = (theta, theta);
        up[p] += h;
        dn[p] -= h;
        let (mu, md) = (emu.predict(&up).mean, emu.predict(&dn).mean);
        mu.iter().zip(&md).map(|(a, b)| (a - b) / (2.0 * h)).collect()
    };
    for p in 0..d {
        let (coarse, fine) = (central(p, 1e-3), central(p, 5e-4));
        for j in 0..emu.n_outputs() {
            let fd_error = (coarse[j] - fine[j]).abs();
            let tol = 1e-7 * mean[j].abs().max(1e-3) + 2.0 * fd_error;
            assert!(
                (jac[j * d + p] - fine[j]).abs() < tol,
                "output {j}, parameter {p}: analytic {} vs finite difference {} (tolerance {tol:e})",
                jac[j * d + p],
                fine[j]
            );
        }
    }
    let prov = mdpipe::artifacts::Provenance::new("cfg".into(), "data".into(), 2, "test");
    store::save(&dir.join("emu"), &emu, &set, &report, &prov).unwrap();
    let back = store::load(&dir.join("emu")).unwrap();
    for t in [[0.1, 0.2, 0.3], theta, [0.9, 0.05, 0.5]] {
        let (a, b) = (emu.predict(&t), back.predict(&t));
        assert!(a.mean.iter().zip(&b.mean).all(|(u, v)| u.to_bits() == v.to_bits()), "means differ after reload");
        assert!(a.cov.iter().zip(&b.cov).all(|(u, v)| u.to_bits() == v.to_bits()), "covariances differ after reload");
    }
    // Batched predictions (one triangular matrix solve) agree with one-at-a-time ones.
    let k = emu.n_components();
    let thetas = [0.1, 0.2, 0.3, 0.37, 0.52, 0.71, 0.9, 0.05, 0.5];
    let (mut bm, mut bv) = (vec![0.0; 3 * k], vec![0.0; 3 * k]);
    emu.predict_components_batch(&thetas, &mut bm, &mut bv);
    let mut scratch = emu.scratch();
    let (mut m1, mut v1) = (vec![0.0; k], vec![0.0; k]);
    for q in 0..3 {
        emu.predict_components(&thetas[q * 3..q * 3 + 3], &mut m1, &mut v1, &mut scratch);
        for c in 0..k {
            assert!((bm[q * k + c] - m1[c]).abs() <= 1e-10 * m1[c].abs().max(1.0), "batched mean differs");
            assert!(
                (bv[q * k + c] - v1[c]).abs() <= 1e-8 * v1[c].abs() + 1e-11,
                "batched variance differs: {} vs {}",
                bv[q * k + c],
                v1[c]
            );
        }
    }
    // The covariance is a covariance: symmetric with a positive diagonal.
    let p = emu.predict(&theta);
    let m = emu.n_outputs();
    for i in 0..m {
        assert!(p.cov[i * m + i] > 0.0);
        for j in 0..m {
            assert_eq!(p.cov[i * m + j], p.cov[j * m + i]);
        }
    }
}

fn error_of(table: &str, components: Option<usize>) -> String {
    let dir = tmpdir("bad");
    let path = dir.join("bad.csv");
    std::fs::write(&path, table).unwrap();
    let result = read_training_table(&path, &params()).and_then(|t| train(&t, &settings(components), 1).map(|_| ()));
    format!("{:#}", result.expect_err("bad input must be an error"))
}

#[test]
fn bad_tables_get_errors_naming_file_row_and_field() {
    let header = "design_id,observable,x,value,a,b,c\n";
    let good = |i: usize, v: f64| {
        format!("{i},flow0,0.5,{v},{},{},{}\n", 0.1 * i as f64, 0.3 + 0.2 * (i % 2) as f64, 0.2 + 0.1 * i as f64)
    };
    // NaN value.
    let t = format!("{header}{}{}0,flow0,0.7,NaN,0.0,0.3,0.2\n", good(0, 0.1), good(1, 0.2));
    let e = error_of(&t, None);
    assert!(e.contains("bad.csv") && e.contains("line 4") && e.contains("'value'"), "{e}");
    // A design point missing an output.
    let t = format!("{header}{}{}0,flow0,0.7,0.3,0.0,0.3,0.2\n{}", good(0, 0.1), good(1, 0.2), good(2, 0.4));
    let e = error_of(&t, None);
    assert!(e.contains("design point 1") && e.contains("flow0[0.7]"), "{e}");
    // Every output constant: nothing to emulate (one constant output among others is emulated exactly).
    let t = format!("{header}{}{}{}", good(0, 0.5), good(1, 0.5), good(2, 0.5));
    let e = error_of(&t, None);
    assert!(e.contains("every output is constant"), "{e}");
    // More components than design points allow.
    let t = format!("{header}{}{}{}", good(0, 0.1), good(1, 0.5), good(2, 0.2));
    let e = error_of(&t, Some(5));
    assert!(e.contains("components = 5"), "{e}");
    // A design point of the design that never made it into the table.
    let dir = tmpdir("design");
    let table_path = dir.join("runs.csv");
    std::fs::write(&table_path, format!("{header}{}{}{}", good(0, 0.1), good(1, 0.5), good(3, 0.2))).unwrap();
    let design = dir.join("design.csv");
    let rows: String = (0..4)
        .map(|i| format!("{i},{},{},{}\n", 0.1 * i as f64, 0.3 + 0.2 * (i % 2) as f64, 0.2 + 0.1 * i as f64))
        .collect();
    std::fs::write(&design, format!("design_id,a,b,c\n{rows}")).unwrap();
    let table = read_training_table(&table_path, &params()).unwrap();
    let e = format!("{:#}", emulator::check_against_design(&table, &design).unwrap_err());
    assert!(e.contains("1 of the 4 design points") && e.contains("(2)"), "{e}");
    // A negative run error.
    let t = "design_id,observable,x,value,error,a,b,c\n0,flow0,0.5,0.1,0.01,0.0,0.3,0.2\n1,flow0,0.5,0.2,-0.01,0.1,0.5,0.3\n";
    let e = error_of(t, None);
    assert!(e.contains("bad.csv") && e.contains("line 3") && e.contains("'error'"), "{e}");
    // A parameter column that is not there.
    let t = "design_id,observable,x,value,a,b\n0,flow0,0.5,0.1,0.1,0.2\n";
    let e = error_of(t, None);
    assert!(e.contains("missing column 'c'"), "{e}");
}

/// Outputs constant over the design (flow at x = 0 is 0 for every θ; a
/// log-transformed one at a fixed value) are emulated exactly: their
/// prediction is that value with zero variance and zero covariance with the
/// rest, at any θ, and after a reload.
#[test]
fn constant_outputs_are_emulated_exactly() {
    let dir = tmpdir("constant");
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let mut text = String::from("design_id,observable,x,value,a,b,c\n");
    for i in 0..40 {
        let theta: Vec<f64> = (0..3).map(|_| rng.random::<f64>()).collect();
        let mut rows = analytic(&theta);
        rows.push(("flow0".into(), 0.0, 0.0));
        rows.push(("spectrum0".into(), 5.0, 0.1));
        for (obs, x, v) in rows {
            text.push_str(&format!("{i},{obs},{x},{v},{},{},{}\n", theta[0], theta[1], theta[2]));
        }
    }
    std::fs::write(dir.join("train.csv"), text).unwrap();
    let table = read_training_table(&dir.join("train.csv"), &params()).unwrap();
    let (emu, report) = train(&table, &settings(None), 1).unwrap();
    store::save(
        &dir.join("emu"),
        &emu,
        &settings(None),
        &report,
        &mdpipe::artifacts::Provenance::new(String::new(), String::new(), 1, "test"),
    )
    .unwrap();
    let reloaded = store::load(&dir.join("emu")).unwrap();
    let constant: Vec<(usize, f64)> = table
        .outputs
        .iter()
        .enumerate()
        .filter_map(|(j, o)| match (o.observable.as_str(), o.x) {
            ("flow0", 0.0) => Some((j, 0.0)),
            ("spectrum0", 5.0) => Some((j, 0.1)),
            _ => None,
        })
        .collect();
    assert_eq!(constant.len(), 2);
    let m = table.n_outputs();
    for _ in 0..20 {
        let theta: Vec<f64> = (0..3).map(|_| rng.random::<f64>()).collect();
        for e in [&emu, &reloaded] {
            let p = e.predict(&theta);
            for &(j, value) in &constant {
                assert_eq!(
                    p.mean[j], value,
                    "{}: emulated {} instead of its constant {value}",
                    table.outputs[j], p.mean[j]
                );
                assert!((0..m).all(|k| p.cov[j * m + k] == 0.0), "{}: nonzero covariance", table.outputs[j]);
            }
        }
    }
}

/// The ball drop through an emulator: a calibration with `model = "emulator"`
/// must reproduce the calibration with the exact model, up to emulator error
/// (small here) and Monte Carlo error.
#[test]
fn calibration_through_an_emulator_matches_the_exact_model() {
    let dir = tmpdir("ballemu");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exact_cfg = mdpipe::systems::load(&root.join("pipeline/ball_drop.toml")).unwrap();
    let obs = vec!["velocity".to_string(), "acceleration".to_string()];
    let overrides = Overrides {
        kernel: Some(mdpipe::base::choices::Kernel::None),
        observables: Some(obs.clone()),
        ..Default::default()
    };
    let exact = Problem::new(&exact_cfg, &overrides).unwrap();
    // Training runs of the drag-free model over the prior box, at the data times.
    let times: Vec<f64> = exact.likelihood.blocks[0].x.clone();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let mut text = String::from("design_id,observable,x,value,g,v0\n");
    for i in 0..80 {
        let (g, v0) = (20.0 * rng.random::<f64>(), -2.0 + 4.0 * rng.random::<f64>());
        for (k, name) in ["velocity", "acceleration"].iter().enumerate() {
            for &t in &times {
                let v = mdpipe::systems::ball_drop::model_value(k + 1, 60.0, g, v0, t);
                text.push_str(&format!("{i},{name},{t},{v},{g},{v0}\n"));
            }
        }
    }
    std::fs::write(dir.join("runs.csv"), text).unwrap();
    // The emulator predicts velocity and acceleration only, so its data file holds just those.
    let data: Vec<_> = mdpipe::artifacts::read_measurements(&root.join("pipeline/ball_drop_data.csv"))
        .unwrap()
        .into_iter()
        .filter(|m| obs.contains(&m.observable))
        .collect();
    mdpipe::artifacts::write_measurements(&dir.join("data.csv"), &data, None).unwrap();
    let cfg_text = format!(
        "{}\n[emulator]\nparameters = [\"g\", \"v0\"]\nkernel = \"se\"\nrestarts = 4\n",
        emulated_ball_drop_config(&std::fs::read_to_string(root.join("pipeline/ball_drop.toml")).unwrap())
            .replace("measurements = \"ball_drop_data.csv\"", "measurements = \"data.csv\"")
    );
    std::fs::write(dir.join("emulated.toml"), cfg_text).unwrap();
    emulator::train_and_save(&dir.join("emulated.toml"), &dir.join("runs.csv"), None, &dir.join("emu"), 1).unwrap();
    let emu_cfg = mdpipe::systems::load(&dir.join("emulated.toml")).unwrap();
    let emulated = Problem::new(&emu_cfg, &overrides).unwrap();
    let a = calibrate::run(&exact, 3, &mdpipe::progress::Silent).unwrap();
    let b = calibrate::run(&emulated, 4, &mdpipe::progress::Silent).unwrap();
    for p in ["g", "v0"] {
        let (x, y) = (&a.summary.parameters[p], &b.summary.parameters[p]);
        let width = x.q975 - x.q025;
        println!(
            "{p}: exact {:.4} [{:.4}, {:.4}], emulated {:.4} [{:.4}, {:.4}]",
            x.median, x.q025, x.q975, y.median, y.q025, y.q975
        );
        // SMC medians carry Monte Carlo error of a few % of the width; the emulator's own error adds less.
        assert!((x.median - y.median).abs() < 0.1 * width, "{p}: medians {} vs {}", x.median, y.median);
        assert!(((y.q975 - y.q025) / width - 1.0).abs() < 0.15, "{p}: widths {} vs {}", width, y.q975 - y.q025);
    }
}

/// An emulator asked outside its training box returns its mean, not the
/// model: a prior reaching there is refused before any sampling, naming the
/// config, the table and both ranges; the training box itself is accepted.
#[test]
fn a_prior_outside_the_training_box_is_refused() {
    let dir = tmpdir("box");
    write_table(&dir.join("t.csv"), 30, 0.0, 5);
    let config = |a_max: f64| {
        format!(
            "name = \"box\"\n[model]\nkind = \"emulator\"\nartifact = \"emu\"\n[data]\nmeasurements = \"m.csv\"\n[parameters.a]\nmin = 0.0\nmax = {a_max}\n[parameters.b]\nmin = 0.0\nmax = 1.0\n[parameters.c]\nmin = 0.0\nmax = 1.0\n[emulator]\nparameters = [\"a\", \"b\", \"c\"]\n"
        )
    };
    std::fs::write(dir.join("c.toml"), config(1.0)).unwrap();
    emulator::train_and_save(&dir.join("c.toml"), &dir.join("t.csv"), None, &dir.join("emu"), 1).unwrap();
    assert!(mdpipe::systems::load(&dir.join("c.toml")).is_ok(), "the training box itself must be accepted");
    std::fs::write(dir.join("wide.toml"), config(3.0)).unwrap();
    let msg = format!(
        "{:#}",
        mdpipe::systems::load(&dir.join("wide.toml")).err().expect("a prior three times the training box was accepted")
    );
    assert!(
        msg.contains("wide.toml")
            && msg.contains("[parameters.a]")
            && msg.contains("trained on a in")
            && msg.contains("Narrow the prior"),
        "{msg}"
    );
}

/// The bundled ball-drop config with its declared ODE model replaced by an
/// emulator in `emu`, and without the [truth] and [[candidates]] that belong
/// to the declared model.
fn emulated_ball_drop_config(text: &str) -> String {
    let (head, rest) = text.split_once("[model]").unwrap();
    let data = rest.find("[data]").unwrap();
    let body = &rest[data..];
    let body = body.split("# The process that made the bundled data").next().unwrap();
    // The paper's kernel inputs (x itself), as the exact model's, for the two observables emulated.
    let inputs = "inputs = { velocity = { scale = 1.0 }, acceleration = { scale = 1.0 } }";
    let body: Vec<&str> = body.lines().map(|l| if l.starts_with("inputs = ") { inputs } else { l }).collect();
    format!("{head}[model]\nkind = \"emulator\"\nartifact = \"emu\"\n\n{}\n", body.join("\n"))
}

/// One emulator trained on `runs` noisy runs of a smooth two-input function
/// with one output: the runs report an error sd of 0.05, and actually
/// scatter with sd `0.05 √(1 + excess)`. Whether the trained emulator kept
/// the white noise beyond the reported error.
fn excess_kept(runs: usize, excess: f64, seed: u64) -> bool {
    use mdpipe::emulator::{OutputKey, TrainingTable};
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let inputs: Vec<f64> = (0..2 * runs).map(|_| rng.random::<f64>()).collect();
    let error = 0.05;
    let values: Vec<f64> = inputs
        .chunks(2)
        .map(|u| {
            (3.0 * u[0]).sin() + u[1] * u[1] + error * (1.0 + excess).sqrt() * rng.sample::<f64, _>(StandardNormal)
        })
        .collect();
    let table = TrainingTable {
        path: "synthetic".into(),
        parameter_names: vec!["a".into(), "b".into()],
        design_ids: (0..runs as i64).collect(),
        inputs,
        outputs: vec![OutputKey { observable: "y".into(), x: 0.0 }],
        errors: vec![error; runs],
        noise_correlation: None,
        values,
    };
    let settings: EmulatorSettings =
        toml::from_str("parameters = [\"a\", \"b\"]\ncomponents = 1\nrestarts = 3").unwrap();
    let (_, report) = train(&table, &settings, seed).unwrap();
    report.excess_scatter.iter().any(|t| t.excess_kept)
}

/// White noise beyond the runs' reported errors is kept only when the runs
/// show it (`emulator::nugget`). 200 seeded data sets of 100 runs per case,
/// each rate printed with its 95% Clopper–Pearson interval:
/// * no excess: the interval must contain the test's nominal 5%;
/// * true noise variance 2x the reported: the interval must lie above 90%
///   (the design target: an excess as large as the reported noise is found);
/// * 1.5x is printed, not asserted (measured 150/200, [0.684, 0.808]); it
///   sits below the test's asymptotic Wald power (0.87) because the GP's
///   lengths, refitted under the null, absorb part of the excess.
#[test]
#[ignore = "second tier: the nugget study over 400 trainings; cargo test --release -- --ignored"]
fn excess_run_scatter_is_kept_at_the_tests_nominal_rate() {
    use crate::diagnose::clopper_pearson;
    let (sets, runs) = (200, 100);
    for (excess, label) in [
        (0.0, "size (no excess)"),
        (0.5, "power (noise variance 1.5x reported)"),
        (1.0, "power (noise variance 2x reported)"),
    ] {
        let kept = (0..sets as u64).filter(|&s| excess_kept(runs, excess, 1000 + s)).count();
        let (lo, hi) = clopper_pearson(kept, sets);
        println!("{label}: excess kept in {kept}/{sets} data sets of {runs} runs, 95% interval [{lo:.3}, {hi:.3}]");
        if excess == 0.0 {
            assert!(lo <= 0.05 && 0.05 <= hi, "size {kept}/{sets}: [{lo:.3}, {hi:.3}] excludes 5%");
        } else if excess == 1.0 {
            assert!(lo > 0.9, "power {kept}/{sets}: [{lo:.3}, {hi:.3}]");
        }
    }
}
