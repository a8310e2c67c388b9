//! The declared ODE model against closed forms, its kept solutions and
//! its watch of the data's χ².

use super::*;
use crate::engine::model::ObservedSeries;
use std::path::Path;

/// Whether the latest solution on this thread was made over the grid.
fn solved_on_grid() -> bool {
    SOLVED.with(|c| matches!(c.borrow().first().and_then(|s| s.dense.as_ref()), Some(Dense::OnGrid { .. })))
}

/// The bundled oscillator, told its data's 40 times (0.25 s apart).
fn bundled_oscillator() -> (std::sync::Arc<dyn Simulator>, Vec<f64>) {
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipeline/examples/oscillator.toml");
    let model = crate::systems::load(&config).expect("the bundled oscillator").simulator;
    let times: Vec<f64> = (1..=40).map(|k| 0.25 * k as f64).collect();
    model.check_inputs(0, &times).unwrap();
    (model, times)
}

/// The θ of the solutions kept on this thread, the most recent first.
fn kept_thetas() -> Vec<Vec<f64>> {
    SOLVED.with(|c| c.borrow().iter().map(|s| s.theta.clone()).collect())
}

/// Three solutions are kept, the least recently used one replaced: a
/// particle's θ, then two proposals, then the particle's θ again is
/// answered from what was kept (the same numbers), and a fourth θ
/// replaces the one unused longest.
#[test]
fn the_last_three_solutions_are_kept() {
    let (model, times) = bundled_oscillator();
    let [a, b, c, d] = [[1.0, 1.0], [2.0, 1.0], [3.0, 1.0], [4.0, 1.0]];
    let predict = |theta: &[f64]| {
        let mut out = vec![0.0; times.len()];
        model.predict(0, &times, theta, &mut out);
        out
    };
    let first = predict(&a);
    predict(&b);
    predict(&c);
    assert_eq!(predict(&a), first);
    assert_eq!(kept_thetas(), vec![a.to_vec(), c.to_vec(), b.to_vec()]);
    predict(&d);
    assert_eq!(kept_thetas(), vec![d.to_vec(), a.to_vec(), c.to_vec()]);
}

/// The bundled oscillator, x'' = −w²x from x0 at rest, against its closed
/// form x0·cos(wt): at the data's times (DOP853 over their grid) and off
/// them (Dormand–Prince 5(4)'s continuous output), within 1e-6 m, 2·10⁴
/// times below the data's error of 0.02 m.
#[test]
fn the_oscillator_matches_its_closed_form_on_and_off_the_data_grid() {
    let (model, data_times) = bundled_oscillator();
    let off_grid: Vec<f64> = (0..30).map(|k| 0.1 + 0.33 * k as f64).collect();
    for (w, x0) in [(0.5, 1.5), (2.0, 1.0), (4.0, 0.5), (3.3, 0.8)] {
        // The third request, at the same θ, is answered by the continuous
        // solution the second made.
        for (times, on_grid) in [(&data_times, true), (&off_grid, false), (&data_times, false)] {
            let mut got = vec![0.0; times.len()];
            model.predict(0, times, &[w, x0], &mut got);
            assert_eq!(solved_on_grid(), on_grid, "w = {w}, on the grid: {on_grid}");
            for (t, g) in times.iter().zip(&got) {
                let want = x0 * (w * t).cos();
                assert!((g - want).abs() < 1e-6, "w = {w}, t = {t}, on the grid: {on_grid}: {g} vs {want}");
            }
        }
    }
    assert_eq!(model.failures(), 0);
}

/// A rate with t, y' = a·cos(wt) from y(0) = 1, against its closed form
/// 1 + (a/w)·sin(wt), on the data's grid (DOP853 with t as a state) and
/// off it.
#[test]
fn a_rate_with_time_matches_its_closed_form_on_and_off_the_grid() {
    let dir = std::env::temp_dir().join(format!("mdpipe-ode-time-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let times: Vec<f64> = (1..=20).map(|k| 0.5 * k as f64).collect();
    let rows: String = times.iter().map(|t| format!("y,{t},1.0,0.1\n")).collect();
    std::fs::write(dir.join("data.csv"), format!("observable,x,value,error\n{rows}")).unwrap();
    let config = "name = \"forced\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\ny = \"1\"\n\
        [model.rates]\ny = \"a*cos(w*t)\"\n[model.observables]\ny = \"y\"\n[data]\nmeasurements = \"data.csv\"\n\
        [parameters.a]\nmin = 0.0\nmax = 5.0\n[parameters.w]\nmin = 0.5\nmax = 6.0\n";
    std::fs::write(dir.join("forced.toml"), config).unwrap();
    let model = crate::systems::load(&dir.join("forced.toml")).expect("the forced model").simulator;
    model.check_inputs(0, &times).unwrap();
    let off_grid: Vec<f64> = (0..30).map(|k| 0.1 + 0.33 * k as f64).collect();
    for (a, w) in [(1.0, 0.5), (5.0, 6.0), (2.5, 3.3)] {
        for (x, on_grid) in [(&times, true), (&off_grid, false)] {
            let mut got = vec![0.0; x.len()];
            model.predict(0, x, &[a, w], &mut got);
            assert_eq!(solved_on_grid(), on_grid);
            for (t, g) in x.iter().zip(&got) {
                let want = 1.0 + a / w * (w * t).sin();
                assert!((g - want).abs() < 1e-6, "a = {a}, w = {w}, t = {t}, grid {on_grid}: {g} vs {want}");
            }
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A driven pendulum, x₀' = x₁, x₁' = c₀ − sin x₀ − c·x₁ (ODEBench's
/// Josephson junction), with `solver` as its `[model.solver]` table.
fn pendulum(solver: &str) -> std::sync::Arc<dyn Simulator> {
    let dir = std::env::temp_dir().join(format!("mdpipe-ode-pendulum-{}-{}", std::process::id(), solver.len()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = format!(
        "name = \"pendulum\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\nx0 = \"1.47\"\nx1 = \"-0.2\"\n\
        [model.rates]\nx0 = \"x1\"\nx1 = \"c0 - sin(x0) - c*x1\"\n[model.observables]\nx0 = \"x0\"\nx1 = \"x1\"\n\
        [model.solver]\n{solver}\n[data]\nmeasurements = \"data.csv\"\n[parameters.c0]\nmin = 0.8\nmax = 3.4\n\
        [parameters.c]\nmin = -6.6\nmax = 6.6\n"
    );
    std::fs::write(dir.join("pendulum.toml"), config).unwrap();
    let model = crate::systems::load(&dir.join("pendulum.toml")).expect("the pendulum").simulator;
    std::fs::remove_dir_all(&dir).ok();
    model
}

/// The pendulum with data at 40 times, their values the model's own at
/// c₀ = 1.67, c = 0.64 (this tests the watch, not a fit).
fn pendulum_and_data() -> (std::sync::Arc<dyn Simulator>, ObservedData) {
    let model = pendulum("");
    let times: Vec<f64> = (1..=40).map(|k| 0.25 * k as f64).collect();
    let series = (0..2)
        .map(|o| {
            model.check_inputs(o, &times).unwrap();
            let mut y = vec![0.0; times.len()];
            model.predict(o, &times, &[1.67, 0.64], &mut y);
            let error = [0.19, 0.03][o];
            ObservedSeries { observable: o, x: times.clone(), y, inv_error: vec![1.0 / error; times.len()] }
        })
        .collect();
    (model, ObservedData::new(series))
}

/// Told data of 1% errors, a model with no declared tolerance integrates at
/// rtol 1e-6, says so, and its predictions stay within a hundredth of the
/// data's errors of an integration at 1e-12 (the claim is a thousandth
/// locally; the margin is for the error's growth along the trajectory).
#[test]
fn an_integration_to_the_datas_precision_stays_far_inside_their_errors() {
    let times: Vec<f64> = (1..=40).map(|k| 0.25 * k as f64).collect();
    let (loose, tight) = (pendulum(""), pendulum("rtol = 1e-12\natol = 1e-14"));
    assert!(loose.numerics().unwrap().contains("rtol 1e-8, atol 1e-10 (no data seen)"), "{:?}", loose.numerics());
    let errors = [0.02, 0.03];
    for (o, e) in errors.iter().enumerate() {
        for model in [&loose, &tight] {
            model.check_inputs(o, &times).unwrap();
            model.note_measurements(o, &[2.0, -1.5], &[*e; 2]);
        }
    }
    let said = loose.numerics().unwrap();
    assert!(said.contains("rtol 1e-6, atol 1e-8 (from the data's finest relative error, 1.00e-2)"), "{said}");
    assert!(tight.numerics().unwrap().contains("rtol 1e-12, atol 1e-14 (as declared)"));
    let mut worst: f64 = 0.0;
    for theta in [[1.67, 0.64], [1.0, 0.0], [2.5, -0.5], [3.3, 1.5], [0.9, 0.05]] {
        for (o, e) in errors.iter().enumerate() {
            let (mut a, mut b) = (vec![0.0; times.len()], vec![0.0; times.len()]);
            loose.predict(o, &times, &theta, &mut a);
            tight.predict(o, &times, &theta, &mut b);
            worst = a.iter().zip(&b).map(|(a, b)| (a - b).abs() / e).fold(worst, f64::max);
        }
    }
    assert!(worst < 1e-2, "the integration's error reached {worst} of the data's errors");
}

/// The watch never claims a χ² above the limit that the predictions do not
/// have; below the true χ² by a factor it stops (a driven pendulum, c < 0,
/// spins off); a watched integration that ran through gives the same
/// predictions as an unwatched one, and a stop is no failure.
#[test]
fn the_watch_stops_only_where_the_chi_square_exceeds_its_limit() {
    let (model, data) = pendulum_and_data();
    let failures = model.failures();
    let mut stopped = 0;
    // A solution kept from `predict` answers "not known" at once: three
    // other θ push it out first.
    let forget = || {
        for k in 0..KEPT {
            data.chi_square_at(model.as_ref(), &[0.85, 0.1 + k as f64 * 0.1]);
        }
    };
    for theta in [[1.67, 0.64], [1.0, 0.0], [2.5, -0.5], [1.67, -3.0], [3.3, 1.5], [0.9, 6.0]] {
        let chi2 = data.chi_square_at(model.as_ref(), &theta);
        for factor in [1e-6, 0.5, 0.999, 1.001, 2.0] {
            let limit = (factor * chi2).max(1e-9);
            forget();
            let exceeds = model.chi_square_exceeds(&theta, &data, limit);
            assert!(!exceeds || chi2 > limit, "θ = {theta:?}: claimed χ² > {limit}, but it is {chi2}");
            if factor < 1e-3 && theta != [1.67, 0.64] {
                assert!(exceeds, "θ = {theta:?}: χ² = {chi2} is a million times the limit, and no stop");
            }
            stopped += exceeds as usize;
            // Whatever the watch did, predict answers with the full solution.
            assert_eq!(data.chi_square_at(model.as_ref(), &theta), chi2, "θ = {theta:?}, limit {limit}");
        }
    }
    assert!(stopped > 5, "only the million-fold limits stopped ({stopped})");
    forget();
    assert!(model.chi_square_exceeds(&[1.67, -3.0], &data, 1e4), "a pendulum driven off the data stops");
    assert_eq!(model.failures(), failures, "a stop is not a failure");
}

/// Logistic growth y' = r·y·(1 − y/K), a rate polynomial in the state and
/// so integrated through its expansion (`expanded`), against its closed
/// form K / (1 + (K/y₀ − 1)·e^{−rt}) on the data's grid, within 1e-6 of
/// K = 10 (the default tolerances with no data noted: 1e-8).
#[test]
fn a_polynomial_rate_expanded_matches_its_closed_form() {
    let dir = std::env::temp_dir().join(format!("mdpipe-ode-logistic-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = "name = \"logistic\"\n[model]\nkind = \"ode\"\nt0 = 0.0\nconstants = { K = 10.0 }\n\
        [model.initial]\ny = \"y0\"\n[model.rates]\ny = \"r*y*(1 - y/K)\"\n[model.observables]\ny = \"y\"\n\
        [data]\nmeasurements = \"data.csv\"\n[parameters.r]\nmin = 0.1\nmax = 3.0\n[parameters.y0]\nmin = 0.1\nmax = 5.0\n";
    std::fs::write(dir.join("logistic.toml"), config).unwrap();
    let declared = crate::systems::load(&dir.join("logistic.toml")).expect("the logistic model");
    std::fs::remove_dir_all(&dir).ok();
    let model = declared.simulator;
    let times: Vec<f64> = (1..=40).map(|k| 0.25 * k as f64).collect();
    model.check_inputs(0, &times).unwrap();
    for (r, y0) in [(0.1, 0.1), (1.3, 2.0), (3.0, 5.0), (2.2, 0.4)] {
        let mut got = vec![0.0; times.len()];
        model.predict(0, &times, &[r, y0], &mut got);
        assert!(solved_on_grid());
        for (t, g) in times.iter().zip(&got) {
            let want = 10.0 / (1.0 + (10.0 / y0 - 1.0) * (-r * t).exp());
            assert!((g - want).abs() < 1e-6, "r = {r}, y0 = {y0}, t = {t}: {g} vs {want}");
        }
    }
    assert_eq!(model.failures(), 0);
}

/// Which rates are expanded: polynomials in the state, not a sine of one
/// nor a rate that reads t.
#[test]
fn only_rates_polynomial_in_the_state_are_expanded() {
    let scope = crate::engine::formula::Scope::new(["t", "c", "x", "v"].map(String::from));
    let states: Vec<String> = ["x", "v"].map(String::from).to_vec();
    let rate = |text: &str| Formula::parse(text, &scope, "test").unwrap();
    let e = expanded::ExpandedRates::of(&[rate("v"), rate("c - sin(x) - c*v*x^2")], &states, &scope);
    let e = e.expect("the first rate expands");
    assert!(e.rates[0].is_some() && e.rates[1].is_none() && !e.all);
    assert!(expanded::ExpandedRates::of(&[rate("v*t"), rate("sin(x)")], &states, &scope).is_none());
    let e = expanded::ExpandedRates::of(&[rate("v"), rate("c*(1 - x^2)*v - x")], &states, &scope).unwrap();
    assert!(e.all && e.degree == 2);
    // The input under the name a config gives it is read as the input, not a constant.
    let named = crate::engine::formula::Scope::new(["time", "c", "x", "v"].map(String::from));
    let rate = |text: &str| Formula::parse(text, &named, "test").unwrap();
    assert!(expanded::ExpandedRates::of(&[rate("c*time*x"), rate("sin(x)")], &states, &named).is_none());
}
