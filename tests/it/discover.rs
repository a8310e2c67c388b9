//! Discovery: with no candidate declared (or none that fits), `diagnose`
//! names the missing term from a grammar built of the model's own symbols.
//! Blind data come from implementations other than the declared ODE under
//! test: the ball drop's own integrator (`systems::ball_drop`) and the
//! kinetics test's RK4 (`declared::Effect`).

use crate::declared::{kinetics_data_set, root, Effect};
use crate::diagnose::{clopper_pearson, effect_size};
use mdpipe::calibrate::{Analysis, Overrides};
use mdpipe::config::Config;
use mdpipe::diagnose::{self, DiagnoseSettings, Diagnosis, Discover};
use mdpipe::progress::Silent;
use mdpipe::systems::ball_drop::{self, ExtraForces, MockOptions};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::{Path, PathBuf};

/// A declared example with its `[[candidates]]` and `[truth]` taken away,
/// sampled lighter (evidence errors ~0.1, far below the margins of 3).
fn without_candidates(config: &str) -> Analysis {
    let mut c = Config::load(&root().join(config)).unwrap();
    c.candidates.clear();
    c.truth = None;
    let mut a = Analysis::resolve(&c, &mdpipe::systems::registry()).unwrap();
    a.sampler.smc.particles = 600;
    a.sampler.adapt = false;
    a.sampler.smc.replicates = 2;
    a.predictions.draws = 200;
    a
}

pub(crate) fn tmp(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mdpipe-discover-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

pub(crate) fn diagnose_file(analysis: &Analysis, path: &Path, seed: u64, discover: Discover) -> Diagnosis {
    let settings = DiagnoseSettings { repair: false, discover, ..Default::default() };
    let overrides = Overrides { data: Some(path.to_path_buf()), ..Default::default() };
    diagnose::run(analysis, &overrides, seed, &settings, None, &Silent).unwrap().diagnosis
}

/// The named candidate, when the verdict names a discovered term.
pub(crate) fn discovered(d: &Diagnosis) -> Option<&mdpipe::diagnose::CandidateResult> {
    d.candidates.iter().find(|c| c.name == d.verdict.best && c.prior_log_odds < 0.0)
}

/// The names of quadratic drag: `c*v*abs(v)`, `c*v*v` or `c*v^2` (the same
/// for a falling ball).
const DRAG: [&str; 3] = ["signed_square_v_on_v", "product_v_v_on_v", "square_v_on_v"];

/// Quadratic drag found: named, with c's 95% interval covering −k.
fn drag_found(d: &Diagnosis, k: f64) -> bool {
    discovered(d).is_some_and(|c| DRAG.contains(&c.name.as_str()) && c.parameters["c"].covers(-k))
}

/// Quadratic drag named, or leading an `ambiguous` verdict that proposes
/// the measurement to settle it, with c's 95% interval covering −k.
fn drag_leads(d: &Diagnosis, k: f64) -> bool {
    let leader = d.verdict.standing.first().and_then(|n| d.candidates.iter().find(|c| &c.name == n));
    let ambiguous_right = d.verdict.best == "ambiguous"
        && d.verdict.suggestion.is_some()
        && leader.is_some_and(|c| DRAG.contains(&c.name.as_str()) && c.parameters["c"].covers(-k));
    drag_found(d, k) || ambiguous_right
}

/// The verdict, whether it is right, and a found sine's ω, to see where a
/// miss lands (in kinetics, the alias on the data's spacing of 0.3 s is
/// 2π/0.3 − 2π/0.7 = 11.97 rad/s).
fn outcome(d: &Diagnosis, right: bool) -> String {
    crate::diagnose::named_at_even_odds_or_better("discovery", &d.verdict);
    let omega = discovered(d).and_then(|c| c.parameters.get("w")).map(|w| format!(" ω {w:?}"));
    format!("{} ({}){}", d.verdict.best, if right { "right" } else { "WRONG" }, omega.unwrap_or_default())
}

/// A periodic force found, its angular frequency's interval covering `w`.
fn periodic_found(d: &Diagnosis, state: &str, w: f64) -> bool {
    discovered(d).is_some_and(|c| c.name == format!("periodic_on_{state}") && c.parameters["w"].covers(w))
}

/// The ball drop with one concealed force, drawn by the ball drop's own
/// integrator: the data file and the effect's noise-free size in σ.
fn ball_drop_set(dir: &Path, k: usize, forces: ExtraForces, rng: &mut Xoshiro256PlusPlus) -> (PathBuf, f64) {
    let opts = MockOptions { forces, ..MockOptions::default() };
    let data = ball_drop::mock_measurements(&opts, rng);
    let path = dir.join(format!("set_{k}.csv"));
    mdpipe::artifacts::write_measurements(&path, &data, None).unwrap();
    (path, effect_size(&opts))
}

/// First tier: the bundled ball drop's library taken away. Its data (made
/// by the ball drop's own integrator, `mdpipe simulate ball-drop --seed 1`,
/// quadratic drag k = 0.4) are discovered to need c*v*abs(v), c covering −k,
/// and the [[candidates]] block is printed. The campaign below measures how
/// often over seeded data sets.
#[test]
fn quadratic_drag_is_discovered_when_no_candidate_is_declared() {
    let analysis = without_candidates("pipeline/ball_drop.toml");
    let path = root().join("pipeline/ball_drop_data.csv");
    let d = diagnose_file(&analysis, &path, 11, Discover::WhenUnexplained);
    assert!(drag_leads(&d, 0.4), "{}", d.verdict.statement);
    let report = d.discovery.as_ref().expect("discovery ran: nothing was declared");
    // Terms join the rate of v only: dh/dt = -v is a kinematic identity, a
    // definition. Built by composition, the search reaches beyond the 46
    // forms the grammar once listed (among them products such as h^2*v^2,
    // which on these ten points is as good a fit as v^2).
    assert!(report.searched > 46, "{}", report.searched);
    assert!(report.screened.iter().all(|t| !t.formula.contains("in dh/dt")), "{:?}", report.screened);
    assert!(d.verdict.statement.contains("[[candidates]]") && d.verdict.statement.contains("v^2"));
    assert!(d.verdict.statement.contains("square of v"), "the meaning is said: {}", d.verdict.statement);
    // The search paid for its size: the drag's prior odds against the model
    // are below one (their sum over the terms is one; a unit test shows it).
    let drag = d.candidates.iter().find(|c| DRAG.contains(&c.name.as_str())).expect("drag calibrated");
    assert!(drag.prior_log_odds < -1.0, "{}", drag.prior_log_odds);
}

/// First tier: a periodic force (3 m/s², period 0.4 s) on the ball drop,
/// drawn by the ball drop's own integrator, with the library taken away.
/// The force acts on v's law, which the acceleration measures directly:
/// the sine is named in dv/dt with ω's interval covering 2π/0.4, and no
/// term joins dh/dt = −v, a definition. (The campaign below measures the
/// rate over seeded sets.)
#[test]
fn a_periodic_force_is_discovered_in_the_law_not_in_the_definition() {
    let analysis = without_candidates("pipeline/ball_drop.toml");
    let dir = tmp("ball-periodic");
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let forces = ExtraForces { oscillation_amplitude: 3.0, oscillation_period: 0.4, ..ExtraForces::NONE };
    let (path, size) = ball_drop_set(&dir, 0, forces, &mut rng);
    assert!(size > 5.0, "{size}");
    let d = diagnose_file(&analysis, &path, 21, Discover::WhenUnexplained);
    assert!(periodic_found(&d, "v", 2.0 * std::f64::consts::PI / 0.4), "{}", d.verdict.statement);
    let report = d.discovery.as_ref().expect("discovery ran: nothing was declared");
    assert!(report.screened.iter().all(|t| !t.formula.contains("in dh/dt")), "{:?}", report.screened);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The campaigns' rates, printed with their 95% Clopper–Pearson intervals.
fn rate(what: &str, k: usize, n: usize) -> (f64, f64) {
    let (lo, hi) = clopper_pearson(k, n);
    println!("discovery: {what}: {k} of {n}, 95% interval [{:.0}%, {:.0}%]", 100.0 * lo, 100.0 * hi);
    (lo, hi)
}

/// Second tier: quadratic drag (k from 0.05 to 0.6) and a periodic force
/// (amplitude 1 to 4 m/s², period 0.4 s) on the ball drop, 20 data sets each
/// at 5σ or more, and 20 nulls diagnosed with `--discover` (the search forced
/// on). Targets: the right form in ≥ 80% of each, a discovery in ≤ 5% of nulls.
#[test]
#[ignore = "second tier: 60 diagnoses with discovery; cargo test --release -- --ignored"]
fn ball_drop_discovery_campaign() {
    let analysis = without_candidates("pipeline/ball_drop.toml");
    let dir = tmp("ball-campaign");
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2028);
    let (mut drag, mut periodic, mut nulls) = (Vec::new(), Vec::new(), Vec::new());
    let mut k = 0;
    while drag.len() < 20 || periodic.len() < 20 || nulls.len() < 20 {
        k += 1;
        assert!(k < 300, "too few data sets of 5σ or more in {k} draws");
        let u: f64 = rng.random();
        let (forces, kind) = match k % 3 {
            0 => (ExtraForces { quadratic_drag: 0.05 + 0.55 * u, ..ExtraForces::NONE }, 0),
            1 => {
                (ExtraForces { oscillation_amplitude: 1.0 + 3.0 * u, oscillation_period: 0.4, ..ExtraForces::NONE }, 1)
            }
            _ => (ExtraForces::NONE, 2),
        };
        let (path, size) = ball_drop_set(&dir, k, forces, &mut rng);
        let list = [&mut drag, &mut periodic, &mut nulls][kind].len();
        if list >= 20 || (kind < 2 && size < 5.0) {
            continue;
        }
        let mode = if kind == 2 { Discover::Always } else { Discover::WhenUnexplained };
        let d = diagnose_file(&analysis, &path, 300 + k as u64, mode);
        let right = match kind {
            0 => drag_found(&d, forces.quadratic_drag),
            1 => periodic_found(&d, "v", 2.0 * std::f64::consts::PI / 0.4),
            _ => discovered(&d).is_none(),
        };
        println!("  set {k}: {forces:?} {size:.1}σ → {}", outcome(&d, right));
        [&mut drag, &mut periodic, &mut nulls][kind].push(right);
    }
    let count = |v: &[bool]| v.iter().filter(|r| **r).count();
    rate("ball drop, quadratic drag ≥ 5σ, discovered as v*abs(v) with k covered", count(&drag), drag.len());
    rate("ball drop, periodic force ≥ 5σ, a sine whose ω covers 2π/0.4", count(&periodic), periodic.len());
    let false_found = nulls.len() - count(&nulls);
    let (_, upper) = rate("ball drop nulls with a term discovered", false_found, nulls.len());
    assert!(count(&drag) * 5 >= drag.len() * 4 && count(&periodic) * 5 >= periodic.len() * 4);
    assert!(
        false_found * 20 <= nulls.len(),
        "{false_found} discoveries in {} nulls (upper bound {upper:.2})",
        nulls.len()
    );
}

/// Second tier: the kinetics example (no candidates) with its periodic
/// source A sin(2π t / 0.7) (A from 2 to 6) at 5σ or more, 20 data sets,
/// and 20 nulls with the search forced on; data from the test's own RK4.
#[test]
#[ignore = "second tier: 40 diagnoses with discovery; cargo test --release -- --ignored"]
fn kinetics_discovery_campaign() {
    let analysis = without_candidates("pipeline/examples/kinetics.toml");
    let dir = tmp("kinetics-campaign");
    let times: Vec<f64> = (0..10).map(|i| 0.1 + 0.3 * i as f64).collect();
    let sigma = 0.05;
    let mut rng = rand::rngs::StdRng::seed_from_u64(2029);
    let (mut periodic, mut nulls) = (Vec::new(), Vec::new());
    let mut k = 0;
    while periodic.len() < 20 || nulls.len() < 20 {
        k += 1;
        assert!(k < 200, "{} periodic sets of 5σ or more in {k} draws", periodic.len());
        let size: f64 = rng.random();
        // Amplitudes of 2 to 6 give 5σ to 17σ over these times (the blind test's 0.2 to 1.7 stay below 5σ).
        let effect = if k % 2 == 0 { Effect::Periodic(2.0 + 4.0 * size) } else { Effect::None };
        let (u, csv, s) = kinetics_data_set(effect, &times, sigma, &mut rng);
        let null = matches!(effect, Effect::None);
        if (null && nulls.len() >= 20) || (!null && (periodic.len() >= 20 || s < 5.0)) {
            continue;
        }
        let path = dir.join(format!("set_{k}.csv"));
        std::fs::write(&path, csv).unwrap();
        let mode = if null { Discover::Always } else { Discover::WhenUnexplained };
        let d = diagnose_file(&analysis, &path, 700 + k as u64, mode);
        let right =
            if null { discovered(&d).is_none() } else { periodic_found(&d, "y", 2.0 * std::f64::consts::PI / 0.7) };
        println!("  set {k}: {effect:?} u = {u:.2} {s:.1}σ → {}", outcome(&d, right));
        if null { &mut nulls } else { &mut periodic }.push(right);
    }
    let count = |v: &[bool]| v.iter().filter(|r| **r).count();
    rate("kinetics, periodic source ≥ 5σ, a sine whose ω covers 2π/0.7", count(&periodic), periodic.len());
    let false_found = nulls.len() - count(&nulls);
    rate("kinetics nulls with a term discovered", false_found, nulls.len());
    assert!(count(&periodic) * 5 >= periodic.len() * 4);
    assert!(false_found * 20 <= nulls.len(), "{false_found} discoveries in {} nulls", nulls.len());
}

/// First tier: an expression model, y = a + b x, measured where the truth
/// (written here in closed form) curves as 0.5 x² over x in [0, 3]: the
/// discovered term is a square of x (x*abs(x) or x^2, the same for x ≥ 0)
/// with its coefficient covering 0.5. Over [0, 2] alone a cube fitted
/// nearly as well (log BF 3.3 ± 0.1 for the square, at the decisive
/// threshold); the point at x = 3 that diagnose proposed to separate them
/// is expected to add about 9 to it. Over [0, 3] the slope b growing as
/// b·exp(c x) fits nearly as well again once parameters may vary (log BF
/// 0.5 ± 0.1, `ambiguous`), and diagnose proposed one point at x = 4.5,
/// expected to move log BF by 9.0 toward the square: the data hold it.
#[test]
fn a_missing_square_is_discovered_in_an_expression_model() {
    let dir = tmp("line");
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
    let mut csv = String::from("observable,x,value,error\n");
    for i in 0..16 {
        let x = if i < 15 { 3.0 * i as f64 / 14.0 } else { 4.5 };
        let z: f64 = rng.sample(rand_distr::StandardNormal);
        csv.push_str(&format!("y,{x},{},0.05\n", 1.0 + 2.0 * x + 0.5 * x * x + 0.05 * z));
    }
    std::fs::write(dir.join("data.csv"), csv).unwrap();
    let config = "name = \"line\"\n[model]\nkind = \"expression\"\nobservables = { y = \"a + b*x\" }\n[data]\nmeasurements = \"data.csv\"\n[parameters.a]\nmin = -5.0\nmax = 5.0\n[parameters.b]\nmin = -5.0\nmax = 5.0\n[sampler]\nadapt = false\n[sampler.smc]\nparticles = 600\nreplicates = 2\n";
    std::fs::write(dir.join("line.toml"), config).unwrap();
    let analysis = mdpipe::systems::load(&dir.join("line.toml")).unwrap();
    let d = diagnose_file(&analysis, &dir.join("data.csv"), 3, Discover::WhenUnexplained);
    let c = discovered(&d).unwrap_or_else(|| panic!("{}", d.verdict.statement));
    assert!(["signed_square_x_on_y", "square_x_on_y"].contains(&c.name.as_str()), "{}", d.verdict.statement);
    assert!(c.parameters["c"].covers(0.5), "{:?}", c.parameters["c"]);
    // For an expression model with one observable: 14 terms composed of x
    // (x's range on the data decides which are defined), 2 forms of the
    // observable itself, 4 corrections of the measurement, a and b each
    // varying 3 ways with x.
    assert_eq!(d.discovery.as_ref().unwrap().searched, 26);
}

/// A decay declared as y' = −u y (u = 0.5 from y = 2), measured 40 times
/// over 10 s (σ = 0.01) where the truth, in closed form here, is
/// y' = −u y + c + a sin(w t) (a = 0.4, w = 2: 19σ); screened from u.
fn screen_decay(tag: &str, c: f64) -> mdpipe::model::Screening {
    use mdpipe::model::{ScreeningBlock, ScreeningData};
    let dir = tmp(tag);
    let (u, y0, a, w) = (0.5, 2.0, 0.4, 2.0);
    let periodic = |t: f64| a * (u * (w * t).sin() - w * (w * t).cos()) / (u * u + w * w);
    let truth = |t: f64| c / u + periodic(t) + (y0 - c / u - periodic(0.0)) * (-u * t).exp();
    let sigma = 0.01;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(31);
    let x: Vec<f64> = (1..=40).map(|k| 0.25 * k as f64).collect();
    let y: Vec<f64> = x.iter().map(|t| truth(*t) + sigma * rng.sample::<f64, _>(rand_distr::StandardNormal)).collect();
    let rows: String = x.iter().zip(&y).map(|(t, v)| format!("y,{t},{v},{sigma}\n")).collect();
    std::fs::write(dir.join("data.csv"), format!("observable,x,value,error\n{rows}")).unwrap();
    let config = "name = \"decay\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\ny = \"2\"\n[model.rates]\ny = \"-u*y\"\n\
                  [model.observables]\ny = \"y\"\n[data]\nmeasurements = \"data.csv\"\n[parameters.u]\nmin = 0.05\nmax = 3.0\n";
    std::fs::write(dir.join("decay.toml"), config).unwrap();
    let analysis = mdpipe::systems::load(&dir.join("decay.toml")).unwrap();
    let error = vec![sigma; x.len()];
    let block = ScreeningBlock { model_index: 0, x: &x, y: &y, error: &error, covariance_factor: None };
    let data = ScreeningData { blocks: vec![block], theta: vec![u], bounds: vec![(0.05, 3.0)] };
    analysis.setup.discoverer().expect("a declared model searches").screen(&data).unwrap()
}

/// First tier: forward selection both ways. With two concealed terms (a
/// constant source c = 0.3, 60σ, and the periodic one) screening's first
/// proposal is their pair, with the prior odds of one of every pair paid;
/// with the periodic term alone (c = 0) it is the single term, and no pair
/// is proposed.
#[test]
fn screening_proposes_a_pair_only_when_both_terms_are_there() {
    let two = screen_decay("pair", 0.3);
    let names: Vec<&str> = two.proposals.iter().map(|p| p.candidate.name.as_str()).collect();
    let mut first: Vec<&str> = names[0].split('+').collect();
    first.sort();
    assert_eq!(first, ["constant_on_y", "periodic_on_y"], "proposals: {names:?}");
    // The other slots go to singles: one pair at most is calibrated.
    assert_eq!(names.iter().filter(|n| n.contains('+')).count(), 1, "proposals: {names:?}");
    // A pair pays for every pair: less prior odds than either of its terms alone.
    let single = |name: &str| two.proposals.iter().find(|p| p.candidate.name == name).map(|p| p.prior_log_odds);
    for name in ["constant_on_y", "periodic_on_y"] {
        assert!(single(name).is_none_or(|odds| two.proposals[0].prior_log_odds < odds), "{name}");
    }
    assert!(two.proposals[0].prior_log_odds < -(two.searched as f64).ln(), "a pair pays more than a single's 1 : N");
    let one = screen_decay("single", 0.0);
    let names: Vec<&str> = one.proposals.iter().map(|p| p.candidate.name.as_str()).collect();
    assert_eq!(names[0], "periodic_on_y", "proposals: {names:?}");
    // A pair is proposed only above the best single: here, none at all
    // (before the rule, pairs below it that beat their own two were kept).
    assert!(names.iter().all(|n| !n.contains('+')), "proposals: {names:?}");
    assert!(one.proposals[0].prior_log_odds < 0.0, "a single pays for the search");
}
