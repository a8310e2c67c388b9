//! `mdpipe bench --scaling`: how the likelihood's cost grows with the data.
//!
//! A synthetic analysis in files, as a user would bring it: observables of
//! 25 points each (an expression model with four parameters), each table with
//! its own correlated systematic (5% of the value, fully correlated across
//! its bins) and one normalization systematic (2%) across every table, all
//! of it written as the full covariance file `[data] covariance` reads
//! (N² rows). For each N it times the setup (reading the measurements and the
//! covariance, attaching it, finding its structure) and Kernel II
//! evaluations per second on one core, structured and dense, and fits the
//! exponent of the cost per evaluation against N.
//!
//! The same data then meet an emulated model: an emulator of 20 principal
//! components trained on 24 noise-free runs of a model nonlinear in its four
//! parameters at every one of the N points, so the likelihood carries the
//! emulator's predictive covariance across all observables (the kept
//! components with θ-dependent weights, the 4 dropped ones as its
//! truncation: rank 24) besides the systematics.

use crate::engine::calibrate::{Overrides, Problem};
use crate::engine::emulator::{train, EmulatedModel, EmulatorSettings, OutputKey, TrainingTable};
use anyhow::{Context, Result};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Points per observable (per table).
const TABLE: usize = 25;
/// The sizes measured, from 100 to 3 000 points.
pub const SIZES: [usize; 6] = [100, 200, 400, 1000, 2000, 3000];
/// Dense evaluations stop at this size (one at 3 000 points takes seconds).
const DENSE_UP_TO: usize = 3000;
/// The emulated model's training runs and kept components.
const RUNS: usize = 24;
const COMPONENTS: usize = 20;

/// One size's measurements.
#[derive(Debug, serde::Serialize)]
pub struct ScalingRow {
    pub points: usize,
    pub observables: usize,
    pub covariance_rows: usize,
    /// Reading the data and covariance, attaching it, and the likelihood's setup.
    pub setup_seconds: f64,
    /// Rank of the low-rank term across tables (`None`: the dense form).
    pub rank: Option<usize>,
    pub structured_per_second: f64,
    pub dense_per_second: Option<f64>,
    /// The same data with the emulated model: its covariance's rank in the
    /// structured form (`None`: dense), and the two rates.
    pub emulator_rank: Option<usize>,
    pub emulated_structured_per_second: f64,
    pub emulated_dense_per_second: Option<f64>,
}

/// Writes the synthetic analysis of `n` points under `dir`, its covariance
/// to `digits` significant digits (None: the double's shortest exact form);
/// returns its config.
pub fn write_problem(dir: &Path, n: usize, digits: Option<usize>) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let observables = n.div_ceil(TABLE);
    let value = |o: usize, x: f64| 2.0 + 0.5 * x + 0.3 * x * x + 0.2 * (o as f64 + x).sin();
    let mut data = std::io::BufWriter::new(std::fs::File::create(dir.join("data.csv"))?);
    writeln!(data, "observable,x,value,error")?;
    let mut points = Vec::with_capacity(n);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(n as u64);
    for o in 0..observables {
        for k in 0..TABLE.min(n - o * TABLE) {
            let x = (k as f64 + 0.5) / TABLE as f64;
            let y = value(o, x)
                * (1.0 + 0.01 * rand_distr::Distribution::<f64>::sample(&rand_distr::StandardNormal, &mut rng));
            writeln!(data, "o{o:04},{x},{y},{}", 0.01 * y)?;
            points.push((o, x, y));
        }
    }
    data.flush()?;
    let mut cov = std::io::BufWriter::new(std::fs::File::create(dir.join("covariance.csv"))?);
    writeln!(cov, "observable_a,x_a,observable_b,x_b,covariance")?;
    for &(oa, xa, ya) in &points {
        for &(ob, xb, yb) in &points {
            let table = if oa == ob { 0.05 * ya * 0.05 * yb } else { 0.0 };
            let c = table + 0.02 * ya * 0.02 * yb;
            match digits {
                Some(d) => writeln!(cov, "o{oa:04},{xa},o{ob:04},{xb},{c:.*e}", d - 1)?,
                None => writeln!(cov, "o{oa:04},{xa},o{ob:04},{xb},{c:e}")?,
            }
        }
    }
    cov.flush()?;
    let formulas: Vec<String> =
        (0..observables).map(|o| format!("o{o:04} = \"a + b*x + c*x^2 + d*sin({o} + x)\"")).collect();
    let config = format!(
        "name = \"scaling_{n}\"\n[model]\nkind = \"expression\"\n[model.observables]\n{}\n[data]\nmeasurements = \"data.csv\"\ncovariance = \"covariance.csv\"\n\
         [parameters.a]\nmin = 0.0\nmax = 4.0\n[parameters.b]\nmin = 0.0\nmax = 1.0\n[parameters.c]\nmin = 0.0\nmax = 1.0\n[parameters.d]\nmin = 0.0\nmax = 0.5\n\
         [discrepancy]\nkernel = \"II\"\n",
        formulas.join("\n")
    );
    let path = dir.join("analysis.toml");
    std::fs::write(&path, config)?;
    Ok(path)
}

/// Evaluations per second on this thread, over at least `seconds` and 3 evaluations.
fn rate(problem: &Problem, seconds: f64) -> f64 {
    let draws = problem.prior.draws(&mut Xoshiro256PlusPlus::seed_from_u64(7), 64);
    let mut sink = problem.likelihood.log_likelihood(&draws[0]);
    let start = Instant::now();
    let mut done = 0;
    while done < 3 || start.elapsed().as_secs_f64() < seconds {
        sink += problem.likelihood.log_likelihood(&draws[done % draws.len()]);
        done += 1;
    }
    std::hint::black_box(sink);
    done as f64 / start.elapsed().as_secs_f64()
}

/// Measures every size in `sizes`, writing the problems under `out` with
/// covariances to `digits` significant digits. A size whose problem is
/// refused (a covariance written to few digits can be no longer positive
/// definite as written) is listed with the reason, and the rest measured.
pub fn measure(
    out: &Path,
    sizes: &[usize],
    seconds: f64,
    digits: Option<usize>,
) -> Result<(Vec<ScalingRow>, Vec<(usize, String)>)> {
    let (mut rows, mut refused) = (Vec::new(), Vec::new());
    for &n in sizes {
        let config = write_problem(&out.join(format!("n{n}")), n, digits)?;
        match measure_one(&config, n, seconds) {
            Ok(row) => rows.push(row),
            Err(e) => refused.push((n, format!("{e:#}"))),
        }
        let _ = std::fs::remove_file(out.join(format!("n{n}")).join("covariance.csv"));
    }
    Ok((rows, refused))
}

/// One size's setup time and rates, its problem written at `config`.
fn measure_one(config: &Path, n: usize, seconds: f64) -> Result<ScalingRow> {
    let start = Instant::now();
    let analysis = crate::systems::load(config)?;
    let overrides = Overrides { kernel: Some(crate::base::choices::Kernel::II), ..Default::default() };
    let mut problem = Problem::new(&analysis, &overrides)?;
    let setup_seconds = start.elapsed().as_secs_f64();
    let rank = problem.likelihood.form.structure().map(|s| s.rank);
    let mut emulated = analysis.clone();
    emulated.simulator = Arc::new(EmulatedModel::new(emulator_of(&problem)?));
    let structured_per_second = rate(&problem, seconds);
    let dense_per_second = (n <= DENSE_UP_TO).then(|| {
        problem.likelihood = problem.likelihood.dense();
        rate(&problem, seconds)
    });
    let mut problem = Problem::new(&emulated, &overrides)?;
    let emulator_rank = problem.likelihood.form.structure().and_then(|s| s.model()).map(|m| m.rank);
    let emulated_structured_per_second = rate(&problem, seconds);
    let emulated_dense_per_second = (n <= DENSE_UP_TO).then(|| {
        problem.likelihood = problem.likelihood.dense();
        rate(&problem, seconds)
    });
    Ok(ScalingRow {
        points: n,
        observables: n.div_ceil(TABLE),
        covariance_rows: n * n,
        setup_seconds,
        rank,
        structured_per_second,
        dense_per_second,
        emulator_rank,
        emulated_structured_per_second,
        emulated_dense_per_second,
    })
}

/// An emulator of `problem`'s observables at their points, trained on
/// `RUNS` noise-free runs of a model nonlinear in θ at uniform draws of
/// the prior (the data are the expression model's; only the cost matters).
fn emulator_of(problem: &Problem) -> Result<crate::engine::emulator::Emulator> {
    let names = problem.likelihood.simulator.parameter_names();
    let draws = problem.prior.draws(&mut Xoshiro256PlusPlus::seed_from_u64(11), RUNS);
    let blocks = &problem.likelihood.blocks;
    let outputs: Vec<OutputKey> =
        blocks.iter().flat_map(|b| b.x.iter().map(|&x| OutputKey { observable: b.name.clone(), x })).collect();
    let mut values = Vec::with_capacity(RUNS * outputs.len());
    for t in &draws {
        for (o, b) in blocks.iter().enumerate() {
            let tilt = 1.0 + 0.1 * (o % 7) as f64;
            values.extend(
                b.x.iter().map(|&x| {
                    t[0] * (-t[1] * x * tilt).exp() + t[2] * x * x + t[3] * (o as f64 + t[2] * x + t[1]).sin()
                }),
            );
        }
    }
    let table = TrainingTable {
        path: "synthetic runs".into(),
        parameter_names: names.clone(),
        design_ids: (0..RUNS as i64).collect(),
        inputs: draws.iter().flat_map(|t| t[..names.len()].iter().copied()).collect(),
        errors: vec![0.0; values.len()],
        outputs,
        noise_correlation: None,
        values,
    };
    let quoted: Vec<String> = names.iter().map(|n| format!("\"{n}\"")).collect();
    let settings: EmulatorSettings =
        toml::from_str(&format!("parameters = [{}]\ncomponents = {COMPONENTS}\nrestarts = 1", quoted.join(", ")))?;
    Ok(train(&table, &settings, 1)?.0)
}

/// The exponent p of cost ∝ N^p, least squares on logs.
pub fn exponent(points: &[(usize, f64)]) -> f64 {
    let xy: Vec<(f64, f64)> = points.iter().map(|&(n, rate)| ((n as f64).ln(), -rate.ln())).collect();
    let k = xy.len() as f64;
    let (mx, my) = (xy.iter().map(|p| p.0).sum::<f64>() / k, xy.iter().map(|p| p.1).sum::<f64>() / k);
    let sxy: f64 = xy.iter().map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xy.iter().map(|(x, _)| (x - mx) * (x - mx)).sum();
    sxy / sxx
}

/// `mdpipe bench --scaling`, printed.
pub fn print(out: &Path, seconds: f64, digits: Option<usize>) -> Result<()> {
    let written = digits.map_or("every digit".to_string(), |d| format!("{d} significant digits"));
    println!(
        "likelihood scaling: Kernel II, observables of {TABLE} points, a 5% systematic per table and a 2% one across all \
         (full covariance files of N² rows, written to {written}); then the same data with an emulator of {COMPONENTS} \
         components from {RUNS} runs; one core, {seconds} s per rate"
    );
    println!(
        "{:>6} {:>5} {:>10} {:>9} {:>5} {:>14} {:>10} {:>9} {:>14} {:>10}",
        "N", "obs", "cov rows", "setup s", "rank", "structured /s", "dense /s", "emu rank", "emulated /s", "dense /s"
    );
    let (rows, refused) = measure(out, &SIZES, seconds, digits)?;
    let rank = |r: Option<usize>| r.map_or("dense".into(), |k| k.to_string());
    let per_second = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.1}"));
    for r in &rows {
        println!(
            "{:>6} {:>5} {:>10} {:>9.2} {:>5} {:>14.0} {:>10} {:>9} {:>14.0} {:>10}",
            r.points,
            r.observables,
            r.covariance_rows,
            r.setup_seconds,
            rank(r.rank),
            r.structured_per_second,
            per_second(r.dense_per_second),
            rank(r.emulator_rank),
            r.emulated_structured_per_second,
            per_second(r.emulated_dense_per_second),
        );
    }
    for (n, why) in &refused {
        println!("{n:>6} refused: {why}");
    }
    if rows.len() < 2 {
        println!("fewer than two sizes measured: no growth of the cost to fit");
    } else {
        print_growth(&rows);
    }
    crate::base::artifacts::write_json_atomic(&out.join("scaling.json"), &rows)?;
    println!("{}", out.join("scaling.json").display());
    Ok(())
}

/// The cost's growth with N, least squares over the measured sizes.
fn print_growth(rows: &[ScalingRow]) {
    let fit = |rate: &dyn Fn(&ScalingRow) -> Option<f64>| {
        exponent(&rows.iter().filter_map(|r| rate(r).map(|v| (r.points, v))).collect::<Vec<_>>())
    };
    println!(
        "cost per evaluation ∝ N^{:.2} structured, N^{:.2} dense; with the emulator N^{:.2} structured, N^{:.2} dense \
         (least squares over the sizes above)",
        fit(&|r| Some(r.structured_per_second)),
        fit(&|r| r.dense_per_second),
        fit(&|r| Some(r.emulated_structured_per_second)),
        fit(&|r| r.emulated_dense_per_second),
    );
}
