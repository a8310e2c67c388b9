//! Discovery's reach on physics the grammar was not built around: a power
//! above the cube, a parameter that varies with the input (shared by two
//! observables), and two near-equivalent forms of which the simpler is
//! true. Each system is declared as a new user would, with no candidates;
//! the truths are written here in closed form or integrated by this file's
//! own RK4, never by the code under test.

use crate::diagnose::clopper_pearson;
use crate::discover::{diagnose_file, discovered, tmp};
use mdpipe::calibrate::Analysis;
use mdpipe::diagnose::{Diagnosis, Discover};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::{Path, PathBuf};

/// A declared config written to `dir`, loaded and sampled as the discovery
/// campaigns sample (evidence errors ~0.1, far below the margins of 3).
fn load(dir: &Path, config: &str) -> Analysis {
    let path = dir.join("model.toml");
    std::fs::write(&path, config).unwrap();
    let mut a = mdpipe::systems::load(&path).unwrap();
    a.sampler.smc.particles = 600;
    a.sampler.adapt = false;
    a.sampler.smc.replicates = 2;
    a.predictions.draws = 200;
    a
}

fn write_data(dir: &Path, k: usize, rows: &[(&str, f64, f64, f64)]) -> PathBuf {
    let mut csv = String::from("observable,x,value,error\n");
    for (o, x, y, e) in rows {
        csv.push_str(&format!("{o},{x},{y},{e}\n"));
    }
    let path = dir.join(format!("set_{k}.csv"));
    std::fs::write(&path, csv).unwrap();
    path
}

/// How a campaign's data set ended: the right form leading (with its
/// parameters covered), `ambiguous` with the right form standing, or wrong.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Outcome {
    Right,
    AmbiguousStanding,
    Wrong,
}

fn outcome(d: &Diagnosis, right_name: impl Fn(&str) -> bool, covered: impl Fn(&Diagnosis) -> bool) -> Outcome {
    if discovered(d).is_some_and(|c| right_name(&c.name)) && covered(d) {
        Outcome::Right
    } else if d.verdict.best == "ambiguous" && d.verdict.standing.iter().any(|s| right_name(s)) {
        Outcome::AmbiguousStanding
    } else {
        Outcome::Wrong
    }
}

/// The campaign's rates with their 95% Clopper–Pearson intervals; asserts
/// the right form in ≥ 80%.
fn report(what: &str, outcomes: &[Outcome]) {
    let n = outcomes.len();
    let count = |o: Outcome| outcomes.iter().filter(|x| **x == o).count();
    for (o, label) in [
        (Outcome::Right, "right form leading, parameters covered"),
        (Outcome::AmbiguousStanding, "ambiguous, the right form standing"),
        (Outcome::Wrong, "wrong"),
    ] {
        let (lo, hi) = clopper_pearson(count(o), n);
        println!(
            "discovery reach: {what}: {label}: {} of {n}, 95% interval [{:.0}%, {:.0}%]",
            count(o),
            100.0 * lo,
            100.0 * hi
        );
    }
    assert!(count(Outcome::Right) * 5 >= n * 4, "{what}: right in {} of {n}", count(Outcome::Right));
}

/// Classical fourth-order Runge–Kutta for one state, fine steps, sampled at `times`.
fn rk4(rate: impl Fn(f64, f64) -> f64, y0: f64, times: &[f64]) -> Vec<f64> {
    let (mut t, mut y, h) = (0.0, y0, 1e-3_f64);
    times
        .iter()
        .map(|&stop| {
            while t < stop - 1e-12 {
                let dt = h.min(stop - t);
                let k1 = rate(t, y);
                let k2 = rate(t + dt / 2.0, y + dt / 2.0 * k1);
                let k3 = rate(t + dt / 2.0, y + dt / 2.0 * k2);
                let k4 = rate(t + dt, y + dt * k3);
                y += dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
                t += dt;
            }
            y
        })
        .collect()
}

/// Newton cooling declared, dT/dt = −k (T − Ta), T in units of 100 K from
/// T0 = 6 toward Ta = 3; the truth also radiates, −e (T⁴ − Ta⁴)
/// (Stefan–Boltzmann exchange with the surroundings).
const COOLING: &str = "name = \"cooling\"\n[model]\nkind = \"ode\"\nt0 = 0.0\nconstants = { Ta = 3.0 }\n\
    [model.initial]\nT = \"6\"\n[model.rates]\nT = \"-k*(T - Ta)\"\n[model.observables]\ntemperature = \"T\"\n\
    [data]\nmeasurements = \"set.csv\"\n[parameters.k]\nmin = 0.0\nmax = 1.0\n";

/// A cooling data set: temperatures at 30 times over 60 s (σ = 0.01, 1 K),
/// and the effect's noise-free size: the largest |truth − best Newton fit| / σ.
fn cooling_set(k: f64, e: f64, rng: &mut Xoshiro256PlusPlus) -> (Vec<(f64, f64)>, f64) {
    let (ta, t0, sigma) = (3.0, 6.0, 0.01);
    let times: Vec<f64> = (1..=30).map(|i| 2.0 * i as f64).collect();
    let truth = rk4(|_, y| -k * (y - ta) - e * (y.powi(4) - ta.powi(4)), t0, &times);
    // The Newton law in closed form, its k by golden-section least squares.
    let newton = |kk: f64| times.iter().map(|t| ta + (t0 - ta) * (-kk * t).exp()).collect::<Vec<_>>();
    let misfit = |kk: f64| newton(kk).iter().zip(&truth).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..200 {
        let (a, b) = (lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo));
        if misfit(a) < misfit(b) {
            hi = b
        } else {
            lo = a
        }
    }
    let fit = newton(0.5 * (lo + hi));
    let size = fit.iter().zip(&truth).map(|(a, b)| (a - b).abs() / sigma).fold(0.0, f64::max);
    let noisy =
        times.iter().zip(&truth).map(|(t, y)| (*t, y + sigma * rng.sample::<f64, _>(rand_distr::StandardNormal)));
    (noisy.collect(), size)
}

/// Second tier: a fourth power (radiative loss) in a cooling law declared
/// as Newton's, 20 data sets at ≥ 5σ with e from 1e-4 to 1e-3 (k from 0.02
/// to 0.05). Right: c*(abs(T)^p − abs(Ta)^p) in dT/dt with p covering 4 and
/// c covering −e.
#[test]
#[ignore = "second tier: 20 diagnoses with discovery; cargo test --release -- --ignored"]
fn a_fourth_power_is_discovered_in_a_cooling_law() {
    let dir = tmp("cooling");
    let analysis = load(&dir, COOLING);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4040);
    let mut outcomes = Vec::new();
    for k in 1..200 {
        if outcomes.len() == 20 {
            break;
        }
        let (kk, e) = (0.02 + 0.03 * rng.random::<f64>(), 10f64.powf(-4.0 + rng.random::<f64>()));
        let (rows, size) = cooling_set(kk, e, &mut rng);
        if size < 5.0 {
            continue;
        }
        let rows: Vec<_> = rows.iter().map(|(t, y)| ("temperature", *t, *y, 0.01)).collect();
        let path = write_data(&dir, k, &rows);
        let d = diagnose_file(&analysis, &path, 900 + k as u64, Discover::WhenUnexplained);
        let right = |name: &str| name == "offset_power_T_Ta_on_T";
        let covered = |d: &Diagnosis| {
            let c = discovered(d).unwrap();
            c.parameters["p"].covers(4.0) && c.parameters["c"].covers(-e)
        };
        let o = outcome(&d, right, covered);
        println!("  set {k}: k = {kk:.3}, e = {e:.2e}, {size:.1}σ → {} {o:?}", d.verdict.best);
        outcomes.push(o);
    }
    report("cooling, a radiative loss e (T^4 - Ta^4) ≥ 5σ", &outcomes);
}

/// Ohm's law declared for a resistor, V = R I and P = R I² over I = 0.2–3 A;
/// the truth heats, R(I) = R0 (1 + a I²): one parameter, shared by both
/// observables, varies with the input.
const RESISTOR: &str = "name = \"resistor\"\n[model]\nkind = \"expression\"\ninput = \"I\"\n\
    observables = { voltage = \"R*I\", power = \"R*I^2\" }\n[data]\nmeasurements = \"set.csv\"\n\
    [parameters.R]\nmin = 1.0\nmax = 50.0\n";

/// Voltage and power at 15 currents (σ 0.05 V and 0.1 W), and the effect's
/// size: the largest |truth − best constant-R fit| / σ.
fn resistor_set(r0: f64, a: f64, rng: &mut Xoshiro256PlusPlus) -> (Vec<(&'static str, f64, f64, f64)>, f64) {
    let currents: Vec<f64> = (0..15).map(|i| 0.2 + 2.8 * i as f64 / 14.0).collect();
    let mut rows = Vec::new();
    for &i in &currents {
        let r = r0 * (1.0 + a * i * i);
        rows.push(("voltage", i, r * i, 0.05, i));
        rows.push(("power", i, r * i * i, 0.1, i * i));
    }
    // Constant R by weighted least squares: each row is R times its factor.
    let (num, den) = rows.iter().fold((0.0, 0.0), |(n, d), (_, _, y, s, f)| (n + f * y / (s * s), d + f * f / (s * s)));
    let r_fit = num / den;
    let size = rows.iter().map(|(_, _, y, s, f)| (y - r_fit * f).abs() / s).fold(0.0, f64::max);
    let noisy =
        rows.iter().map(|(o, i, y, s, _)| (*o, *i, y + s * rng.sample::<f64, _>(rand_distr::StandardNormal), *s));
    (noisy.collect(), size)
}

/// Second tier: a resistance that grows with current (Joule heating),
/// R0 from 5 to 15 Ω and a from 0.002 to 0.03 per A², 20 data sets at ≥ 5σ.
/// Right: R replaced by R*(1 + c*I^2) in both observables, c covering a.
#[test]
#[ignore = "second tier: 20 diagnoses with discovery; cargo test --release -- --ignored"]
fn a_parameter_varying_with_the_input_is_discovered_in_both_observables() {
    let dir = tmp("resistor");
    let analysis = load(&dir, RESISTOR);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4141);
    let mut outcomes = Vec::new();
    for k in 1..200 {
        if outcomes.len() == 20 {
            break;
        }
        let (r0, a) = (5.0 + 10.0 * rng.random::<f64>(), 0.002 + 0.028 * rng.random::<f64>());
        let (rows, size) = resistor_set(r0, a, &mut rng);
        if size < 5.0 {
            continue;
        }
        let path = write_data(&dir, k, &rows);
        let d = diagnose_file(&analysis, &path, 1100 + k as u64, Discover::WhenUnexplained);
        let right = |name: &str| name == "quadratic_I_of_R";
        let covered = |d: &Diagnosis| discovered(d).unwrap().parameters["c"].covers(a);
        let o = outcome(&d, right, covered);
        println!("  set {k}: R0 = {r0:.2}, a = {a:.4}, {size:.1}σ → {} {o:?}", d.verdict.best);
        outcomes.push(o);
    }
    report("resistor, R(I) = R0 (1 + a I^2) ≥ 5σ", &outcomes);
}

/// Hooke's law declared for a rubber band, extension x = F/k over F = 2–4 N;
/// the truth softens as b F², which a cube fits nearly as well over so
/// narrow a range.
const BAND: &str = "name = \"band\"\n[model]\nkind = \"expression\"\ninput = \"F\"\n\
    observables = { extension = \"F/k\" }\n[data]\nmeasurements = \"set.csv\"\n\
    [parameters.k]\nmin = 10.0\nmax = 500.0\n";

fn band_set(kk: f64, b: f64, rng: &mut Xoshiro256PlusPlus) -> (Vec<(&'static str, f64, f64, f64)>, f64) {
    let sigma = 0.0005;
    let forces: Vec<f64> = (0..12).map(|i| 2.0 + 2.0 * i as f64 / 11.0).collect();
    let truth: Vec<f64> = forces.iter().map(|f| f / kk + b * f * f).collect();
    // The linear law's 1/k by least squares: x = s F.
    let s = forces.iter().zip(&truth).map(|(f, x)| f * x).sum::<f64>() / forces.iter().map(|f| f * f).sum::<f64>();
    let size = forces.iter().zip(&truth).map(|(f, x)| (x - s * f).abs() / sigma).fold(0.0, f64::max);
    let rows = forces
        .iter()
        .zip(&truth)
        .map(|(f, x)| ("extension", *f, x + sigma * rng.sample::<f64, _>(rand_distr::StandardNormal), sigma));
    (rows.collect(), size)
}

/// Second tier: two near-equivalent forms, the simpler true: a softening
/// b F² (b from 2e-4 to 1e-3 m/N², k from 50 to 200 N/m) at ≥ 5σ over a
/// range where a cube fits nearly as well. Right: the square (F^2 or
/// F*abs(F), the same for F > 0) leading with c covering b.
#[test]
#[ignore = "second tier: 20 diagnoses with discovery; cargo test --release -- --ignored"]
fn the_simpler_of_two_near_equivalent_forms_leads() {
    let dir = tmp("band");
    let analysis = load(&dir, BAND);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4242);
    let mut outcomes = Vec::new();
    for k in 1..200 {
        if outcomes.len() == 20 {
            break;
        }
        let (kk, b) = (50.0 + 150.0 * rng.random::<f64>(), 2e-4 + 8e-4 * rng.random::<f64>());
        let (rows, size) = band_set(kk, b, &mut rng);
        if size < 5.0 {
            continue;
        }
        let path = write_data(&dir, k, &rows);
        let d = diagnose_file(&analysis, &path, 1300 + k as u64, Discover::WhenUnexplained);
        let right = |name: &str| ["square_F_on_extension", "signed_square_F_on_extension"].contains(&name);
        let covered = |d: &Diagnosis| discovered(d).unwrap().parameters["c"].covers(b);
        let o = outcome(&d, right, covered);
        println!("  set {k}: k = {kk:.1}, b = {b:.2e}, {size:.1}σ → {} {o:?}", d.verdict.best);
        outcomes.push(o);
    }
    report("rubber band, a softening b F^2 ≥ 5σ with a cube nearly as good", &outcomes);
}
