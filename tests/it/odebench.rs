//! Discovery on an outside benchmark: the protocol "a term left out" of
//! `../shared/odebench/README.md` on the 32 odd-id ODEBench systems
//! (d'Ascoli et al., ICLR 2024), as `bench/odebench/make_cases.py` wrote
//! them into `tests/fixtures/odebench/cases.json`: every removable term of
//! every rate one case, the user's model the system without it (remaining
//! constants with priors [c/2, 2c], initial values known), the data the
//! full system integrated by SciPy (never by mdpipe) with 1% noise, and the
//! trajectory from the second initial condition, which no fit sees, where
//! the repaired law is judged. Each case is declared as a new user would,
//! with no candidates, and diagnosed once: first verdicts.
//!
//! Right: a decisive verdict whose repaired rates (the model's terms and
//! the discovered term at their posterior medians) are within 10% relative
//! rms of the true rates on every rate along that trajectory. The repaired
//! rates are evaluated by exmex, not by mdpipe's formulas.

use crate::diagnose::clopper_pearson;
use mdpipe::calibrate::Overrides;
use mdpipe::diagnose::{self, DiagnoseSettings, Diagnosis, Discover};
use mdpipe::progress::Silent;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Deserialize)]
struct Fixture {
    cases: Vec<Case>,
    nulls: Vec<Case>,
}

#[derive(Deserialize, Clone)]
struct Case {
    id: u32,
    removed: Option<String>,
    class: Option<String>,
    states: Vec<String>,
    initial: Vec<f64>,
    model_rates: Vec<String>,
    parameters: BTreeMap<String, Prior>,
    data: Data,
    judge: Judge,
}

#[derive(Deserialize, Clone)]
struct Prior {
    min: f64,
    max: f64,
}

#[derive(Deserialize, Clone)]
struct Data {
    t: Vec<f64>,
    values: Vec<Vec<f64>>,
    errors: Vec<f64>,
}

#[derive(Deserialize, Clone)]
struct Judge {
    t: Vec<f64>,
    states: Vec<Vec<f64>>,
    rates: Vec<Vec<f64>>,
}

fn fixture() -> Fixture {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/odebench/cases.json");
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The case as a user's config and measurements, in `dir`.
fn write_case(case: &Case, dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let s = &case.states;
    let mut config = format!("name = \"odebench_{}\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n", case.id);
    let pairs = |values: Vec<String>| s.iter().zip(values).map(|(s, v)| format!("{s} = \"{v}\"")).collect::<Vec<_>>();
    config +=
        &format!("initial = {{ {} }}\n", pairs(case.initial.iter().map(|v| format!("{v:?}")).collect()).join(", "));
    config += &format!("rates = {{ {} }}\n", pairs(case.model_rates.clone()).join(", "));
    config += &format!("observables = {{ {} }}\n", pairs(s.clone()).join(", "));
    config += "[data]\nmeasurements = \"data.csv\"\n";
    for (name, p) in &case.parameters {
        config += &format!("[parameters.{name}]\nmin = {:?}\nmax = {:?}\n", p.min, p.max);
    }
    config += "[discrepancy]\nkernel = \"II\"\n";
    let mut csv = String::from("observable,x,value,error\n");
    for (k, state) in s.iter().enumerate() {
        for (t, v) in case.data.t.iter().zip(&case.data.values[k]) {
            csv += &format!("{state},{t:?},{v:?},{:?}\n", case.data.errors[k]);
        }
    }
    std::fs::write(dir.join("data.csv"), csv).unwrap();
    let path = dir.join("model.toml");
    std::fs::write(&path, config).unwrap();
    path
}

fn diagnose_case(path: &Path, discover: Discover) -> Diagnosis {
    let analysis = mdpipe::systems::load(path).unwrap();
    let settings = DiagnoseSettings { repair: false, discover, ..Default::default() };
    diagnose::run(&analysis, &Overrides::default(), 1, &settings, None, &Silent).unwrap().diagnosis
}

/// A formula fully parenthesized for exmex, whose own precedence differs
/// (it reads `-x^2` as (−x)²): parsed by the conventions of mathematics.
fn explicit(text: &str) -> String {
    use mdpipe::engine::formula::notation::{parse, Expr};
    fn print(e: &Expr) -> String {
        match e {
            Expr::Number(v) => format!("{v:?}"),
            Expr::Name(n) => match n.as_str() {
                "PI" => format!("{:?}", std::f64::consts::PI),
                _ => n.clone(),
            },
            Expr::Neg(a) => format!("(0-{})", print(a)),
            Expr::Binary(op, a, b) => format!("({}{op}{})", print(a), print(b)),
            Expr::Call(f, args) => {
                let f = if f == "log" { "ln" } else { f.as_str() };
                format!("{f}({})", args.iter().map(print).collect::<Vec<_>>().join(","))
            }
        }
    }
    print(&parse(text).unwrap_or_else(|e| panic!("{text}: {e}")))
}

/// The worst relative rms of `rates` (states, then names with values) from
/// the true rates along the judging trajectory.
fn worst_rms(case: &Case, rates: &[String], values: &BTreeMap<String, f64>) -> f64 {
    use exmex::prelude::*;
    let mut worst = 0.0f64;
    for (k, text) in rates.iter().enumerate() {
        let flat = exmex::parse::<f64>(&explicit(text)).unwrap_or_else(|e| panic!("{text}: {e}"));
        let n = case.judge.rates[k].len();
        let (mut err, mut norm) = (0.0, 0.0);
        for i in 0..n {
            let args: Vec<f64> = flat
                .var_names()
                .iter()
                .map(|v| match case.states.iter().position(|s| s == v) {
                    Some(j) => case.judge.states[j][i],
                    None if v == "t" => case.judge.t[i],
                    None => *values.get(v).unwrap_or_else(|| panic!("{text}: no value of {v}")),
                })
                .collect();
            let got = flat.eval(&args).unwrap_or(f64::NAN);
            let want = case.judge.rates[k][i];
            err += (got - want).powi(2);
            norm += want * want;
        }
        let rms = (err / n as f64).sqrt() / (norm / n as f64).sqrt().max(1e-12);
        worst = worst.max(if rms.is_finite() { rms } else { f64::INFINITY });
    }
    worst
}

/// The model's rates with the candidate `name` in, and its posterior medians.
fn repaired(case: &Case, d: &Diagnosis, name: &str) -> Option<(Vec<String>, BTreeMap<String, f64>)> {
    let candidate = d.candidates.iter().find(|c| c.name == name)?;
    let screened = d.discovery.as_ref()?.screened.iter().find(|s| s.name == name)?;
    let table: toml::Table = toml::from_str(&screened.toml).ok()?;
    let entry = table["candidates"].as_array()?[0].as_table()?.clone();
    let mut rates = case.model_rates.clone();
    if let Some(extra) = entry.get("rates").and_then(|r| r.as_table()) {
        for (k, s) in case.states.iter().enumerate() {
            if let Some(t) = extra.get(s).and_then(|v| v.as_str()) {
                rates[k] = format!("({}) + ({t})", rates[k]);
            }
        }
    }
    if let Some(vary) = entry.get("vary").and_then(|r| r.as_table()) {
        for (p, t) in vary {
            let t = t.as_str()?;
            rates = rates.iter().map(|r| mdpipe::engine::formula::notation::rename(r, p, &format!("({t})"))).collect();
        }
    }
    let medians = candidate.parameters.iter().map(|(n, p)| (n.clone(), p.median)).collect();
    Some((rates, medians))
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Outcome {
    Right,
    AmbiguousLeading,
    /// A partial explanation naming the right form, δ kept for the rest.
    PartialRight,
    Unexplained,
    None,
    Wrong,
}

fn judge(case: &Case, d: &Diagnosis) -> (Outcome, String) {
    crate::diagnose::named_at_even_odds_or_better("ODEBench", &d.verdict);
    let best = d.verdict.best.as_str();
    let close = |name: &str| repaired(case, d, name).map(|(r, v)| worst_rms(case, &r, &v));
    match best {
        "unexplained" | "emulator_limited" => (Outcome::Unexplained, best.into()),
        "none" => (Outcome::None, best.into()),
        "partial" => {
            let named = d.verdict.named().unwrap_or_default().to_string();
            match close(&named) {
                Some(w) if w <= 0.1 => (Outcome::PartialRight, format!("partial, {named} ({w:.3})")),
                w => (Outcome::Wrong, format!("partial, {named} ({w:?})")),
            }
        }
        "ambiguous" => {
            let lead = d.verdict.standing.first().cloned().unwrap_or_default();
            match close(&lead) {
                Some(w) if w <= 0.1 => (Outcome::AmbiguousLeading, format!("{lead} ({w:.3})")),
                w => (Outcome::Wrong, format!("ambiguous, {lead} leading ({w:?})")),
            }
        }
        name => match close(name) {
            Some(w) if w <= 0.1 => (Outcome::Right, format!("{name} ({w:.3})")),
            w => (Outcome::Wrong, format!("{name} ({w:?})")),
        },
    }
}

fn rate(what: &str, k: usize, n: usize) -> String {
    let (lo, hi) = clopper_pearson(k, n);
    format!("{what}: {k} of {n}, 95% interval [{:.0}%, {:.0}%]", 100.0 * lo, 100.0 * hi)
}

/// Second tier: every case of the protocol, first verdicts. Targets: right
/// in ≥ 75%, wrong in ≤ 5%; by class; and each diagnosis's wall time.
#[test]
#[ignore = "second tier: the ODEBench protocol, 117 diagnoses with discovery; cargo test --release -- --ignored"]
fn odebench_a_term_left_out() {
    let cases = fixture().cases;
    let dir = std::env::temp_dir().join(format!("mdpipe-odebench-{}", std::process::id()));
    let mut outcomes = Vec::new();
    let mut seconds = Vec::new();
    for (i, case) in cases.iter().enumerate() {
        let path = write_case(case, &dir.join(format!("case_{i}")));
        let start = std::time::Instant::now();
        let d = diagnose_case(&path, Discover::WhenUnexplained);
        seconds.push(start.elapsed().as_secs_f64());
        let (o, what) = judge(case, &d);
        println!(
            "  case {i} (system {}, {} left out, {}): {o:?} {what} [{:.0} s]",
            case.id,
            case.removed.as_deref().unwrap_or(""),
            case.class.as_deref().unwrap_or(""),
            seconds[i]
        );
        outcomes.push((o, case.class.clone().unwrap_or_default()));
    }
    let n = outcomes.len();
    let count = |o: Outcome| outcomes.iter().filter(|(x, _)| *x == o).count();
    for (o, label) in [
        (Outcome::Right, "decisive and right"),
        (Outcome::AmbiguousLeading, "ambiguous, the right form leading"),
        (Outcome::PartialRight, "partial, the right form with δ for the rest"),
        (Outcome::Unexplained, "unexplained"),
        (Outcome::None, "none"),
        (Outcome::Wrong, "wrong (decisive, ambiguous or partial with a wrong form leading)"),
    ] {
        println!("odebench: {}", rate(label, count(o), n));
    }
    let mut classes: Vec<String> = outcomes.iter().map(|(_, c)| c.clone()).collect();
    classes.sort();
    classes.dedup();
    for class in classes {
        let of: Vec<&(Outcome, String)> = outcomes.iter().filter(|(_, c)| *c == class).collect();
        let right = of.iter().filter(|(o, _)| *o == Outcome::Right).count();
        println!("odebench:   {}", rate(&format!("{class}: right"), right, of.len()));
    }
    seconds.sort_by(f64::total_cmp);
    println!("odebench: diagnose wall time median {:.1} s, longest {:.1} s", seconds[n / 2], seconds[n - 1]);
    let (right, wrong) = (count(Outcome::Right), count(Outcome::Wrong));
    assert!(right * 4 >= n * 3, "right in {right} of {n}, below 75%");
    assert!(wrong * 20 <= n, "wrong in {wrong} of {n}, above 5%");
}

/// Second tier: each system as it is (nothing removed), the search forced
/// on. Target: a term discovered in ≤ 5%.
#[test]
#[ignore = "second tier: 32 diagnoses with discovery forced on; cargo test --release -- --ignored"]
fn odebench_nulls_discover_nothing() {
    let nulls = fixture().nulls;
    let dir = std::env::temp_dir().join(format!("mdpipe-odebench-nulls-{}", std::process::id()));
    let mut found = 0;
    for (i, case) in nulls.iter().enumerate() {
        let path = write_case(case, &dir.join(format!("null_{i}")));
        let d = diagnose_case(&path, Discover::Always);
        let term = d.candidates.iter().find(|c| c.name == d.verdict.best && c.prior_log_odds < 0.0);
        println!(
            "  null {i} (system {}): {} {}",
            case.id,
            d.verdict.best,
            if term.is_some() { "DISCOVERED" } else { "" }
        );
        found += usize::from(term.is_some());
    }
    println!("odebench: {}", rate("nulls with a term discovered", found, nulls.len()));
    assert!(found * 20 <= nulls.len(), "{found} discoveries in {} nulls", nulls.len());
}

/// First tier: one case of each kind the protocol judges, end to end: a
/// product across states left out of a Lotka–Volterra law is named and
/// repaired within the protocol's tolerance.
#[test]
fn a_product_left_out_of_lotka_volterra_is_found_and_repaired() {
    let cases = fixture().cases;
    let case = cases.iter().find(|c| c.id == 27 && c.removed.as_deref() == Some("-c_1*x_0*x_1")).unwrap();
    let dir = std::env::temp_dir().join(format!("mdpipe-odebench-lv-{}", std::process::id()));
    let path = write_case(case, &dir);
    // A quarter of the default particles (the size of diagnose's scouts)
    // and two replicates, not four: the protocol's campaign, in the second
    // tier, runs the defaults. This case end to end took 186 s with them,
    // 51 s with 500 particles (the same verdict, the coefficients' medians
    // and bounds within 0.002) and 25 s with two replicates as well (the
    // same verdict; c2 = -1.448 [-1.474, -1.424] with four, the median
    // within 0.001 with two).
    let mut config = std::fs::read_to_string(&path).unwrap();
    config += "[sampler.smc]\nparticles = 500\nreplicates = 2\n";
    std::fs::write(&path, config).unwrap();
    let d = diagnose_case(&path, Discover::WhenUnexplained);
    let (o, what) = judge(case, &d);
    assert_eq!(o, Outcome::Right, "{what}: {}", d.verdict.statement);
}

/// First tier: the screening alone on the Gray–Scott case whose missing
/// linear loss (-0.02·x_1 in dx_1/dt) the rates read off smoothed states
/// buried under flexible forms (87th along the data): it is among the
/// proposals, and at the screening's fit it reproduces the true rates
/// within the protocol's 10%.
#[test]
fn a_linear_loss_the_smoothed_rates_bury_is_still_proposed() {
    let cases = fixture().cases;
    let (case, screening) = screened(&cases, 45, "-c_1*x_1", "gray-scott");
    let (first_right, shown) = first_right(case, &screening);
    assert!(first_right.is_some(), "no right form among the proposals: {}", shown.join("; "));
}

/// The cell cycle's constant source left out of dx_1/dt (case 52, data
/// from the fixture's own integrator) leaves dx_1/dt = -x_0, which reads as
/// a kinematic identity; the data contradict it, so it is searched as a law
/// and the right constant is proposed. A true identity on the same protocol
/// (system 25's dx_0/dt = x_1, case 24) stays a definition.
#[test]
fn a_definition_the_data_contradict_is_searched_as_a_law() {
    let cases = fixture().cases;
    let (case, screening) = screened(&cases, 41, "c_2", "cell-cycle");
    assert!(
        screening.notes.iter().any(|n| n.starts_with("dx_1/dt = -x_0 reads as a definition")),
        "{:?}",
        screening.notes
    );
    let (first_right, shown) = first_right(case, &screening);
    assert_eq!(first_right, Some(1), "{}", shown.join("; "));
    let (_, screening) = screened(&cases, 25, "-c_0*x_0", "cell-cycle-kept");
    assert!(screening.notes.is_empty(), "{:?}", screening.notes);
}

/// A rotating body in a shear flow (system 35, cos(x₁)² sin(x₀) left out of
/// dx₁/dt, the fixture's own data): the model writes x₀ only inside sines
/// and cosines, so c·x₀, which matches c·sin(x₀) on the data's |x₀| < 1.4,
/// pays the learned price of an angle written bare and no longer leads it on
/// prior odds (a plain symbol pays nothing: `library::tests::an_angle_pays_…`).
#[test]
fn an_angle_written_bare_pays_the_corpus_price() {
    let cases = fixture().cases;
    let (_, screening) = screened(&cases, 35, "cos(x_1)^2*sin(x_0)", "angle");
    let odds = |name: &str| screening.proposals.iter().find(|p| p.candidate.name == name).map(|p| p.prior_log_odds);
    let (linear, sin) = (odds("linear_x_0_on_x_1"), odds("sin_x_0_on_x_1"));
    // operations.toml: "sin", the one operation c·sin(x) adds to c·x, and an angle written bare.
    let (sin_cost, bare) = (2.259, 2.375);
    let (linear, sin) = (linear.expect("c·x₀ proposed"), sin.expect("c·sin(x₀) proposed"));
    assert!(sin > linear, "an angle: sin {sin} against linear {linear}");
    assert!((linear - sin - (sin_cost - bare)).abs() < 0.01, "linear − sin = {}", linear - sin);
}

/// The case of system `id` with `removed` left out, and its screening (in a
/// folder of its own, named by `tag`).
fn screened<'c>(cases: &'c [Case], id: u32, removed: &str, tag: &str) -> (&'c Case, mdpipe::model::Screening) {
    let case = cases.iter().find(|c| c.id == id && c.removed.as_deref() == Some(removed)).unwrap();
    let dir = std::env::temp_dir().join(format!("mdpipe-odebench-{tag}-{}", std::process::id()));
    (case, screen_case(case, &dir).unwrap().0)
}

/// The screening of one case, as `diagnose` screens it (no MD, θ at the
/// prior's middle), and its wall time; Err when the case does not load.
fn screen_case(case: &Case, dir: &Path) -> anyhow::Result<(mdpipe::model::Screening, f64)> {
    use mdpipe::calibrate::Problem;
    use mdpipe::model::{ScreeningBlock, ScreeningData};
    let path = write_case(case, dir);
    let analysis = mdpipe::systems::load(&path)?;
    let overrides = Overrides { kernel: Some(mdpipe::base::choices::Kernel::None), ..Default::default() };
    let problem = Problem::new(&analysis, &overrides)?;
    let blocks = problem
        .likelihood
        .blocks
        .iter()
        .map(|b| ScreeningBlock {
            model_index: b.model_index,
            x: &b.x,
            y: &b.y,
            error: &b.error,
            covariance_factor: None,
        })
        .collect();
    let n = problem.simulator.parameter_names().len();
    let data = ScreeningData {
        blocks,
        theta: (0..n).map(|k| 0.5 * (problem.prior.lower[k] + problem.prior.upper[k])).collect(),
        bounds: (0..n).map(|k| (problem.prior.lower[k], problem.prior.upper[k])).collect(),
    };
    let start = std::time::Instant::now();
    let screening = analysis.setup.discoverer().expect("a declared model has a discoverer").screen(&data)?;
    Ok((screening, start.elapsed().as_secs_f64()))
}

/// Where among the proposals the first right one stands (its rates at the
/// screening's least-squares fit within the protocol's 10%), from 1, and
/// each proposal as printed.
fn first_right(case: &Case, screening: &mdpipe::model::Screening) -> (Option<usize>, Vec<String>) {
    let mut first_right = None;
    let mut shown = Vec::new();
    for (k, p) in screening.proposals.iter().enumerate() {
        let table: toml::Table = toml::from_str(&p.toml).unwrap();
        let entry = table["candidates"].as_array().unwrap()[0].as_table().unwrap().clone();
        let mut rates = case.model_rates.clone();
        if let Some(extra) = entry.get("rates").and_then(|r| r.as_table()) {
            for (j, s) in case.states.iter().enumerate() {
                if let Some(t) = extra.get(s).and_then(|v| v.as_str()) {
                    rates[j] = format!("({}) + ({t})", rates[j]);
                }
            }
        }
        let values: BTreeMap<String, f64> = p.best_fit.iter().cloned().collect();
        let worst = if entry.contains_key("observables") { f64::INFINITY } else { worst_rms(case, &rates, &values) };
        if worst <= 0.1 && first_right.is_none() {
            first_right = Some(k + 1);
        }
        shown.push(format!("{} ({:.3}, ΔBIC {:.0})", p.candidate.name, worst, p.delta_bic));
    }
    (first_right, shown)
}

/// The screening alone on every case, in seconds rather than hours: for
/// each case, where among the proposals the first right one stands, so
/// that misses of the campaign can be told apart: a form the search did
/// not reach or rank, against one the calibrations then judged otherwise.
/// Prints only; the campaign above is the measure.
#[test]
#[ignore = "a diagnostic of the screening alone (prints, asserts nothing): cargo test --release --test it odebench_screening -- --ignored --nocapture"]
fn odebench_screening() {
    let cases = fixture().cases;
    let only: Option<Vec<usize>> =
        std::env::var("ODEBENCH_CASES").ok().map(|s| s.split(',').filter_map(|k| k.trim().parse().ok()).collect());
    let dir = std::env::temp_dir().join(format!("mdpipe-odebench-screening-{}", std::process::id()));
    let mut ranks = Vec::new();
    for (i, case) in cases.iter().enumerate() {
        if only.as_ref().is_some_and(|o| !o.contains(&i)) {
            continue;
        }
        let (screening, seconds) = match screen_case(case, &dir.join(format!("case_{i}"))) {
            Ok(s) => s,
            Err(e) => {
                println!("  case {i} (system {}): not screened: {e:#}", case.id);
                ranks.push(None);
                continue;
            }
        };
        let (first_right, shown) = first_right(case, &screening);
        println!(
            "  case {i} (system {}, {} left out, {}): right at {:?} of [{}] [{seconds:.1} s]",
            case.id,
            case.removed.as_deref().unwrap_or(""),
            case.class.as_deref().unwrap_or(""),
            first_right,
            shown.join("; ")
        );
        ranks.push(first_right);
    }
    let n = ranks.len();
    for k in 1..=3 {
        let within = ranks.iter().filter(|r| r.is_some_and(|r| r <= k)).count();
        println!("odebench screening: {}", rate(&format!("a right form among the first {k}"), within, n));
    }
}

/// Along the Lorenz flow at ρ = 100, sampled a few times a turn over ten
/// time units, no form fitted through one trajectory from t0 comes near the
/// data (the best 580 per point). The screening then shoots from the
/// measured states: the removed coupling c·x₁ in dx₀/dt leads, its rates at
/// the screening's fit within the protocol's 10% of the truth on the
/// judge's trajectory, and the note says how it was screened. The proposal
/// is calibrated as every model is, integrated from t0.
#[test]
fn a_flow_one_trajectory_cannot_follow_is_screened_by_shooting() {
    let cases = fixture().cases;
    let (case, screening) = screened(&cases, 55, "c_0*x_1", "shooting");
    assert!(screening.notes.iter().any(|n| n.contains("multiple shooting")), "{:?}", screening.notes);
    let (first, shown) = first_right(case, &screening);
    assert_eq!(first, Some(1), "{shown:?}");
    let numerics = screening.proposals[0].candidate.simulator.numerics().unwrap_or_default();
    assert!(!numerics.contains("shooting"), "the proposal integrates from t0: {numerics}");
}
