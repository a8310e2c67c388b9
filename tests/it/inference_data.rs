//! What a calibration writes for ArviZ beside its draws: each draw's
//! log-likelihood and log prior in `posterior.parquet`, and replicated data
//! in `posterior_predictive.parquet`, checked against a closed form written
//! here (a straight line and its mirror, independent Gaussian errors).

use mdpipe::artifacts::read_parquet;
use polars::prelude::*;
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use std::process::Command;

const ERROR: f64 = 0.2;

fn line(x: f64, a: f64, b: f64) -> f64 {
    a + b * x
}

fn mirror(x: f64, a: f64, b: f64) -> f64 {
    a - b * x
}

/// Two observables, y = a + b x and z = a − b x, 10 points each.
fn config(dir: &Path) -> PathBuf {
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    let mut csv = String::from("observable,x,value,error\n");
    for i in 0..10 {
        let x = i as f64 * 0.3;
        csv.push_str(&format!("y,{x},{},{ERROR}\n", line(x, 1.0, 2.0) + ERROR * (rng.random::<f64>() - 0.5)));
        csv.push_str(&format!("z,{x},{},{ERROR}\n", mirror(x, 1.0, 2.0) + ERROR * (rng.random::<f64>() - 0.5)));
    }
    std::fs::write(dir.join("line.csv"), csv).unwrap();
    let text = r#"name = "line"
[model]
kind = "expression"
observables = { y = "a + b*x", z = "a - b*x" }
[data]
measurements = "line.csv"
[parameters.a]
min = -10.0
max = 10.0
[parameters.b]
min = -10.0
max = 10.0
[discrepancy]
kernel = "none"
[sampler]
adapt = false
[sampler.smc]
particles = 400
replicates = 2
"#;
    std::fs::write(dir.join("line.toml"), text).unwrap();
    dir.join("line.toml")
}

fn column(df: &DataFrame, name: &str) -> Vec<f64> {
    df.column(name).unwrap().cast(&DataType::Float64).unwrap().f64().unwrap().into_no_null_iter().collect()
}

fn strings(df: &DataFrame, name: &str) -> Vec<String> {
    df.column(name).unwrap().str().unwrap().iter().map(|v| v.unwrap().to_string()).collect()
}

fn calibrated() -> (PathBuf, DataFrame, Vec<(String, f64, f64)>) {
    let dir = std::env::temp_dir().join(format!("mdpipe-inference-data-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = config(&dir);
    let out = dir.join("fit");
    let status = Command::new(env!("CARGO_BIN_EXE_mdpipe"))
        .args(["calibrate", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--seed", "3"])
        .status()
        .unwrap();
    assert!(status.success());
    let data = read_parquet(&out.join("measurements.parquet")).unwrap();
    let obs = strings(&data, "observable").into_iter();
    let points = obs.zip(column(&data, "x")).zip(column(&data, "value")).map(|((o, x), v)| (o, x, v)).collect();
    (out, data, points)
}

fn predict(observable: &str, x: f64, a: f64, b: f64) -> f64 {
    if observable == "y" {
        line(x, a, b)
    } else {
        mirror(x, a, b)
    }
}

#[test]
fn each_draw_carries_its_log_likelihood_and_log_prior_and_replicates_follow_the_errors() {
    let (out, _, points) = calibrated();
    let post = read_parquet(&out.join("posterior.parquet")).unwrap();
    let (a, b) = (column(&post, "a"), column(&post, "b"));
    let (total, prior) = (column(&post, "log_likelihood"), column(&post, "log_prior"));
    let (ly, lz) = (column(&post, "log_likelihood.y"), column(&post, "log_likelihood.z"));
    let gauss = |r: f64| -0.5 * (r / ERROR).powi(2) - ERROR.ln() - 0.5 * (2.0 * std::f64::consts::PI).ln();
    for k in 0..a.len() {
        let term = |name: &str| -> f64 {
            points.iter().filter(|p| p.0 == name).map(|(o, x, v)| gauss(v - predict(o, *x, a[k], b[k]))).sum()
        };
        let (ty, tz) = (term("y"), term("z"));
        let tol = 1e-9 * (1.0 + (ty + tz).abs());
        assert!(
            (ly[k] - ty).abs() < tol && (lz[k] - tz).abs() < tol,
            "draw {k}: terms {} {} vs {ty} {tz}",
            ly[k],
            lz[k]
        );
        assert!((total[k] - (ty + tz)).abs() < tol, "draw {k}: log-likelihood {} vs {}", total[k], ty + tz);
        assert!((prior[k] + (20.0f64 * 20.0).ln()).abs() < 1e-12, "draw {k}: log prior {}", prior[k]);
    }
    // Replicates: y_rep − η(θ of its draw) is the measurement noise, N(0, σ²)
    // here, so its standardized mean and variance are within 4 standard
    // errors of 0 and 1.
    let rep = read_parquet(&out.join("posterior_predictive.parquet")).unwrap();
    let chains = column(&post, "chain");
    let (rc, rd, rx, ry) = (column(&rep, "chain"), column(&rep, "draw"), column(&rep, "x"), column(&rep, "y"));
    let robs = strings(&rep, "observable");
    let per_chain = chains.iter().filter(|&&c| c == 0.0).count();
    let z: Vec<f64> = (0..ry.len())
        .map(|i| {
            let row = rc[i] as usize * per_chain + rd[i] as usize;
            assert_eq!(chains[row], rc[i], "replicate {i} names a draw of another chain");
            (ry[i] - predict(&robs[i], rx[i], a[row], b[row])) / ERROR
        })
        .collect();
    let n = z.len() as f64;
    let mean = z.iter().sum::<f64>() / n;
    let var = z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    println!("{} replicated points: standardized noise mean {mean:.4}, variance {var:.4}", z.len());
    assert!(n >= 2.0 * 200.0 * 10.0, "{n} replicated points");
    assert!(mean.abs() < 4.0 / n.sqrt(), "mean {mean}");
    assert!((var - 1.0).abs() < 4.0 * (2.0 / n).sqrt(), "variance {var}");
    // As many replicates from each chain (a chain × draw array for ArviZ).
    let from0 = rc.iter().filter(|&&c| c == 0.0).count();
    assert_eq!(2 * from0, rc.len());
}

/// `mdpipe export` without the Python package, or of a folder that holds no
/// calibration, stops with an error that says what to do.
#[test]
fn export_says_what_it_needs() {
    let dir = std::env::temp_dir().join(format!("mdpipe-export-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = |python: &str| {
        Command::new(env!("CARGO_BIN_EXE_mdpipe"))
            .args(["export", dir.to_str().unwrap(), "--format", "zarr"])
            .env("MDPIPE_PYTHON", python)
            .output()
            .unwrap()
    };
    let empty = run("python3");
    assert!(!empty.status.success());
    assert!(String::from_utf8_lossy(&empty.stderr).contains("no posterior.parquet"), "{empty:?}");
    std::fs::write(dir.join("posterior.parquet"), b"").unwrap();
    let no_python = run(dir.join("no-such-python").to_str().unwrap());
    assert!(!no_python.status.success());
    assert!(String::from_utf8_lossy(&no_python.stderr).contains("pip install ."), "{no_python:?}");
}
