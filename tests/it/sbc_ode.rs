//! Simulation-based calibration on the path a declared ODE's fit without MD
//! takes: SMC with its floor, the likelihood's χ² limit, and the ODE's
//! watch that stops an integration there. A pendulum, x₀' = x₁,
//! x₁' = c₀ − sin x₀ − c·x₁, whose prior reaches c < 0, where it is driven
//! off the data and the watch stops most proposals. The data come from the
//! test's own RK4 integrator, not from the code under test.

use super::common::central_interval_covers;
use mdpipe::artifacts::Measurement;
use mdpipe::calibrate::sampler::smc::{Smc, SmcSettings};
use mdpipe::calibrate::{MdLikelihood, ObservableBlock, UniformPrior};
use mdpipe::model::Simulator;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::sync::Arc;

const TIMES: usize = 16;
const SPACING: f64 = 0.25;
const ERROR: f64 = 0.05;
const INITIAL: [f64; 2] = [1.47, -0.2];

/// The pendulum as a user declares it, told the data's times.
fn pendulum() -> Arc<dyn Simulator> {
    let dir = std::env::temp_dir().join(format!("mdpipe-sbc-ode-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let times: Vec<f64> = (1..=TIMES).map(|k| SPACING * k as f64).collect();
    let rows: String =
        times.iter().flat_map(|t| [format!("x0,{t},0,{ERROR}\n"), format!("x1,{t},0,{ERROR}\n")]).collect();
    std::fs::write(dir.join("data.csv"), format!("observable,x,value,error\n{rows}")).unwrap();
    let config = format!(
        "name = \"pendulum\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\nx0 = \"{}\"\nx1 = \"{}\"\n\
         [model.rates]\nx0 = \"x1\"\nx1 = \"c0 - sin(x0) - c*x1\"\n[model.observables]\nx0 = \"x0\"\nx1 = \"x1\"\n\
         [data]\nmeasurements = \"data.csv\"\n[parameters.c0]\nmin = 0.5\nmax = 2.0\n[parameters.c]\nmin = -1.0\nmax = 1.5\n",
        INITIAL[0], INITIAL[1]
    );
    std::fs::write(dir.join("pendulum.toml"), config).unwrap();
    let model = mdpipe::systems::load(&dir.join("pendulum.toml")).unwrap().simulator;
    std::fs::remove_dir_all(&dir).ok();
    for o in 0..2 {
        model.check_inputs(o, &times).unwrap();
    }
    model
}

/// The states at the data's times by classical RK4 at step 1e-3.
fn rk4_states(c0: f64, c: f64) -> Vec<[f64; 2]> {
    let rate = |y: [f64; 2]| [y[1], c0 - y[0].sin() - c * y[1]];
    let (h, per_point) = (1e-3, (SPACING / 1e-3).round() as usize);
    let mut y = INITIAL;
    let mut out = Vec::new();
    for _ in 0..TIMES {
        for _ in 0..per_point {
            let k1 = rate(y);
            let k2 = rate([y[0] + 0.5 * h * k1[0], y[1] + 0.5 * h * k1[1]]);
            let k3 = rate([y[0] + 0.5 * h * k2[0], y[1] + 0.5 * h * k2[1]]);
            let k4 = rate([y[0] + h * k3[0], y[1] + h * k3[1]]);
            for i in 0..2 {
                y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        out.push(y);
    }
    out
}

/// Data set `k`: a truth from the prior, the states plus noise, and the
/// likelihood without MD that the fit of a declared model builds.
fn data_set(k: usize, prior: &UniformPrior, model: &Arc<dyn Simulator>) -> (Vec<f64>, MdLikelihood) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5000 + k as u64);
    let mut truth = vec![0.0; 2];
    prior.sample(&mut rng, &mut truth);
    let names = model.parameter_names();
    let value = |name: &str| truth[names.iter().position(|n| n == name).unwrap()];
    let states = rk4_states(value("c0"), value("c"));
    let mut rows = Vec::new();
    for (i, s) in states.iter().enumerate() {
        let t = SPACING * (i + 1) as f64;
        for (o, name) in ["x0", "x1"].iter().enumerate() {
            let e: f64 = StandardNormal.sample(&mut rng);
            rows.push(Measurement::new(name, t, s[o] + ERROR * e, ERROR));
        }
    }
    let blocks = ["x0", "x1"]
        .iter()
        .enumerate()
        .map(|(o, name)| {
            let own: Vec<&Measurement> = rows.iter().filter(|m| m.observable == *name).collect();
            ObservableBlock::new(name, o, &own).unwrap()
        })
        .collect();
    (truth, MdLikelihood::new(model.clone(), blocks, None))
}

#[test]
#[ignore = "second tier: SBC over 200 data sets of a declared ODE without MD; cargo test --release -- --ignored"]
fn a_declared_ode_fit_with_its_floor_has_nominal_coverage() {
    let model = pendulum();
    // The prior in the model's order of parameters (not the config's).
    let names = model.parameter_names();
    let bounds = |n: &String| if n == "c0" { (0.5, 2.0) } else { (-1.0, 1.5) };
    let prior = UniformPrior::new(
        names.clone(),
        names.iter().map(|n| bounds(n).0).collect(),
        names.iter().map(|n| bounds(n).1).collect(),
    )
    .unwrap();
    let (datasets, levels) = (200, [0.5, 0.9]);
    let covered: Vec<[[bool; 2]; 2]> = (0..datasets)
        .into_par_iter()
        .map(|k| {
            let (truth, lik) = data_set(k, &prior, &model);
            let out = Smc::new(SmcSettings { particles: 500, replicates: 2, ..Default::default() })
                .run(&prior, &lik, 91 + k as u64, &mdpipe::progress::Silent)
                .unwrap();
            let mut covered = [[false; 2]; 2];
            for p in 0..2 {
                for (l, level) in levels.iter().enumerate() {
                    covered[p][l] = central_interval_covers(out.chains.param(p), truth[p], *level);
                }
            }
            covered
        })
        .collect();
    let mut report = String::new();
    let mut off = Vec::new();
    for (p, name) in names.iter().enumerate() {
        for (l, level) in levels.iter().enumerate() {
            let count = covered.iter().filter(|c| c[p][l]).count() as f64;
            let (expected, sd) = (level * datasets as f64, (datasets as f64 * level * (1.0 - level)).sqrt());
            report.push_str(&format!("{name} level {level}: {count}/{datasets} (expected {expected} ± {sd:.1})\n"));
            // 3.5 binomial sds: a false failure among the four checks below 0.2%.
            if (count - expected).abs() > 3.5 * sd {
                off.push(format!("{name} level {level}: {count}"));
            }
        }
    }
    println!("{report}");
    assert!(off.is_empty(), "coverage off:\n{report}");
}
