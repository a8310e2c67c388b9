//! A candidate of an emulated model that corrects the emulator's output by
//! a formula (`correction = { rate = "rate/(1 + tau*rate)" }`): the physics
//! of the measurement, declared without running the simulator again.

use mdpipe::diagnose::{self, DiagnoseSettings};
use mdpipe::progress::Silent;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::PathBuf;

fn tmpdir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mdpipe-correction-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A counter's rate against source strength x, emulated from the
/// simulator's runs r = 12 A x (no dead time in the simulator); the
/// measured rate loses counts to a dead time tau, r / (1 + tau r).
const COUNTER: &str = "name = \"counter\"\n[model]\nkind = \"emulator\"\nartifact = \"emu\"\n\
    [data]\nmeasurements = \"data.csv\"\n[parameters.A]\nmin = 0.5\nmax = 2.0\n\
    [emulator]\nparameters = [\"A\"]\n\
    [[candidates]]\nname = \"dead_time\"\ndescription = \"non-paralysable dead time: each count blinds the counter for tau\"\n\
    correction = { rate = \"rate/(1 + tau*rate)\" }\nparameters.tau = { min = 0.0, max = 0.01 }\n\
    [[candidates]]\nname = \"background\"\ndescription = \"a constant background rate b\"\n\
    correction = { rate = \"rate + b\" }\nparameters.b = { min = -20.0, max = 20.0 }\n";

/// The simulator's runs (r = 12 A x, no dead time) and data in closed form
/// with a dead time `tau` at efficiency `a`.
fn write_counter(dir: &std::path::Path, a: f64, tau: f64) {
    let xs: Vec<f64> = (1..=12).map(f64::from).collect();
    let mut runs = String::from("design_id,observable,x,value,A\n");
    for i in 0..12 {
        let a = 0.45 + 1.6 * i as f64 / 11.0;
        for x in &xs {
            runs.push_str(&format!("{i},rate,{x},{},{a}\n", 12.0 * a * x));
        }
    }
    std::fs::write(dir.join("runs.csv"), runs).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
    let mut data = String::from("observable,x,value,error\n");
    for x in &xs {
        let r = 12.0 * a * x;
        let sigma = 0.01 * r + 0.2;
        let z: f64 = rng.sample(rand_distr::StandardNormal);
        data.push_str(&format!("rate,{x},{},{sigma}\n", r / (1.0 + tau * r) + sigma * z));
    }
    std::fs::write(dir.join("data.csv"), data).unwrap();
}

/// First tier: runs of the simulator train the emulator; data (written in
/// closed form here) carry a dead time of 2 ms at A = 1.2. `diagnose` names
/// the dead-time correction, its tau covering 0.002 and A covering 1.2,
/// over a background offset; and a correction with an emulator is refused.
/// `config` written as `name` in `dir`, its emulator trained on `runs.csv`,
/// loaded with a small sampler for speed.
fn trained(dir: &std::path::Path, name: &str, config: &str) -> mdpipe::calibrate::Analysis {
    std::fs::write(dir.join(name), config).unwrap();
    mdpipe::emulator::train_and_save(&dir.join(name), &dir.join("runs.csv"), None, &dir.join("emu"), 1).unwrap();
    let mut analysis = mdpipe::systems::load(&dir.join(name)).unwrap();
    analysis.sampler.smc.particles = 600;
    analysis.sampler.smc.replicates = 2;
    analysis
}

/// A simulator A·shape(observable, x) and data at A = `amp` carrying a
/// relative `effect`, written in closed form: 12 runs over A in 0.45–2.05
/// (runs.csv) and the data with a relative error (data.csv), seeded.
struct Truth<'a> {
    observables: &'a [&'a str],
    xs: &'a [f64],
    shape: &'a dyn Fn(&str, f64) -> f64,
    effect: &'a dyn Fn(&str, f64) -> f64,
    amp: f64,
    relative: f64,
}

impl Truth<'_> {
    fn write(&self, dir: &std::path::Path, seed: u64) {
        let mut runs = String::from("design_id,observable,x,value,A\n");
        for i in 0..12 {
            let amp = 0.45 + 1.6 * i as f64 / 11.0;
            for o in self.observables {
                for x in self.xs {
                    runs.push_str(&format!("{i},{o},{x},{},{amp}\n", amp * (self.shape)(o, *x)));
                }
            }
        }
        std::fs::write(dir.join("runs.csv"), runs).unwrap();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut data = String::from("observable,x,value,error\n");
        for o in self.observables {
            for x in self.xs {
                let y = self.amp * (self.shape)(o, *x) * (self.effect)(o, *x);
                let sigma = self.relative * y;
                let z: f64 = rng.sample(rand_distr::StandardNormal);
                data.push_str(&format!("{o},{x},{},{sigma}\n", y + sigma * z));
            }
        }
        std::fs::write(dir.join("data.csv"), data).unwrap();
    }
}

#[test]
fn a_dead_time_correction_of_an_emulated_model_is_named() {
    let dir = tmpdir("counter");
    let (a, tau) = (1.2, 0.002);
    write_counter(&dir, a, tau);
    let analysis = trained(&dir, "counter.toml", COUNTER);
    let settings = DiagnoseSettings { repair: false, ..Default::default() };
    let d = diagnose::run(&analysis, &Default::default(), 5, &settings, None, &Silent).unwrap().diagnosis;
    assert_eq!(d.verdict.best, "dead_time", "{}", d.verdict.statement);
    let c = &d.candidates[0];
    assert!(c.parameters["tau"].covers(tau) && c.parameters["A"].covers(a), "{:?}", c.parameters);
    // A correction is its own candidate: an emulator beside it is refused by name.
    let both = COUNTER
        .replace("correction = { rate = \"rate + b\" }", "correction = { rate = \"rate + b\" }\nemulator = \"emu\"");
    std::fs::write(dir.join("both.toml"), both).unwrap();
    let analysis = mdpipe::systems::load(&dir.join("both.toml")).unwrap();
    let e = format!("{:#}", analysis.setup.candidates().err().expect("a correction with an emulator"));
    assert!(e.contains("both.toml") && e.contains("background") && e.contains("needs no variant"), "{e}");
}

/// First tier: the same counter with no candidate declared; `diagnose`,
/// unasked, searches corrections of the emulated output and a counting
/// loss leads (rate/(1 + c*rate), or rate + c*rate^2 to second order), c
/// covering the dead time, with the `[[candidates]]` block that declares
/// it. With `--no-discover` the verdict is `unexplained`.
#[test]
fn a_counting_loss_is_discovered_for_an_emulated_model() {
    let dir = tmpdir("discover");
    let (a, tau) = (1.2, 0.002);
    write_counter(&dir, a, tau);
    let bare = COUNTER.split("[[candidates]]").next().unwrap();
    let analysis = trained(&dir, "counter.toml", bare);
    let settings = DiagnoseSettings { repair: false, ..Default::default() };
    let d = diagnose::run(&analysis, &Default::default(), 5, &settings, None, &Silent).unwrap().diagnosis;
    // A counting loss leads: y/(1 + c y) or y + c y², the same dead time to
    // second order, 1.1 apart on these data and one explanation read two
    // ways. It is named, or, where that explanation is less probable than
    // the MD fit (its search's prior odds paid), the verdict is
    // `unexplained` and says so of it.
    let loss = ["saturation_of_rate", "square_loss_of_rate"];
    let first = &d.candidates[0];
    assert!(loss.contains(&first.name.as_str()), "{}", d.verdict.statement);
    let dead_time = if first.name == loss[0] { tau } else { -tau };
    assert!(first.parameters["c"].covers(dead_time) && first.parameters["A"].covers(a), "{:?}", first.parameters);
    let standing_are_losses = d.verdict.standing.iter().all(|s| loss.contains(&s.as_str()));
    let less_probable_than_md = d.verdict.best == "unexplained"
        && d.verdict.confidence > 0.5
        && d.verdict.statement.contains(&format!("the best candidate, {}", first.name));
    assert!(
        loss.contains(&d.verdict.best.as_str())
            || (d.verdict.best == "ambiguous" && standing_are_losses)
            || less_probable_than_md,
        "{}",
        d.verdict.statement
    );
    let report = d.discovery.as_ref().expect("the search ran");
    let found = report.screened.iter().find(|t| t.name == "saturation_of_rate").unwrap();
    assert!(found.toml.contains("correction = { rate = \"rate/(1 + c*rate)\" }"), "{}", found.toml);
    let settings = DiagnoseSettings { repair: false, discover: diagnose::Discover::Never, ..Default::default() };
    let d = diagnose::run(&analysis, &Default::default(), 5, &settings, None, &Silent).unwrap().diagnosis;
    assert!(d.discovery.is_none() && d.verdict.best == "unexplained", "{}", d.verdict.statement);
}

/// Two spectra of one emulated model, each raised as 1 + c x² (a shear δf
/// in each pT spectrum, concealed): no one observable's correction explains
/// both, so each one's best is fitted together and named, its c's covering
/// the truths. The data come from the closed form above, not from the
/// emulator being judged.
#[test]
fn a_change_in_every_observable_is_found_as_their_corrections_together() {
    let dir = tmpdir("together");
    let xs: Vec<f64> = (1..=12).map(|k| 0.25 * f64::from(k)).collect();
    let shapes = [("a", 10.0, 1.0), ("b", 5.0, 2.0)];
    let shape =
        |o: &str, x: f64| shapes.iter().find(|s| s.0 == o).map_or(0.0, |(_, scale, offset)| scale * (offset + x));
    let (amp, c) = (1.2, [0.05, 0.08]);
    let effect = |o: &str, x: f64| {
        let c = if o == "a" { c[0] } else { c[1] };
        1.0 + c * x * x
    };
    let truth = Truth { observables: &["a", "b"], xs: &xs, shape: &shape, effect: &effect, amp, relative: 0.01 };
    truth.write(&dir, 31);
    let config = "name = \"spectra\"\n[model]\nkind = \"emulator\"\nartifact = \"emu\"\n\
        [data]\nmeasurements = \"data.csv\"\n[parameters.A]\nmin = 0.5\nmax = 2.0\n\
        [emulator]\nparameters = [\"A\"]\n";
    let analysis = trained(&dir, "spectra.toml", config);
    let settings = DiagnoseSettings { repair: false, ..Default::default() };
    let d = diagnose::run(&analysis, &Default::default(), 7, &settings, None, &Silent).unwrap().diagnosis;
    assert_eq!(d.verdict.best, "x2_gain_of_b+x2_gain_of_a", "{}", d.verdict.statement);
    let named = &d.candidates[0];
    let covers = |p: &str, v: f64| named.parameters[p].covers(v);
    // The corrections' c cover their truths; A, held by 24 points at 1% to
    // ±0.35%, also carries the emulator's interpolation between 12 runs, so
    // it is asked to within 1% (this seed: 1.2087 [1.2006, 1.2168]).
    assert!(covers("c_a", c[0]) && covers("c_b", c[1]), "{:?}", named.parameters);
    assert!((named.parameters["A"].median / amp - 1.0).abs() < 0.01, "{:?}", named.parameters);
    let text = &d.discovery.as_ref().unwrap().screened[0].toml;
    assert!(text.contains("b = \"b*(1 + c_b*x^2)\"") && text.contains("parameters.c_a"), "{text}");
}

/// A cell's voltage over its discharge at two currents, emulated from runs
/// of a model without the cell's internal resistance; the data (closed
/// form) lie below it by R·I at each current, R = 0.05 Ω. With the currents
/// given as the observables' labels, the drop is found as one offset
/// shared by both, proportional to the current, its coefficient covering
/// −R; an offset of each voltage on its own, two coefficients for one law,
/// is not what is named.
#[test]
fn a_drop_proportional_to_the_current_is_found_as_one_shared_correction() {
    let dir = tmpdir("shared");
    let xs: Vec<f64> = (0..12).map(|k| 0.05 + 0.08 * f64::from(k)).collect();
    let (resistance, currents) = (0.05, [("v_low", 0.5), ("v_high", 2.0)]);
    let current = |o: &str| currents.iter().find(|c| c.0 == o).map_or(0.0, |c| c.1);
    let shape = |o: &str, x: f64| 4.1 - 0.6 * x - 0.3 * x * x - 0.05 * current(o) * x;
    let amp = 1.1;
    let effect = |o: &str, x: f64| 1.0 - resistance * current(o) / (amp * shape(o, x));
    let truth =
        Truth { observables: &["v_low", "v_high"], xs: &xs, shape: &shape, effect: &effect, amp, relative: 0.001 };
    truth.write(&dir, 53);
    let config = "name = \"cell\"\n[model]\nkind = \"emulator\"\nartifact = \"emu\"\n\
        observable_labels = { current = { v_low = 0.5, v_high = 2.0 } }\n\
        [data]\nmeasurements = \"data.csv\"\n[parameters.A]\nmin = 0.5\nmax = 2.0\n\
        [emulator]\nparameters = [\"A\"]\n";
    let analysis = trained(&dir, "cell.toml", config);
    let settings = DiagnoseSettings { repair: false, ..Default::default() };
    let d = diagnose::run(&analysis, &Default::default(), 9, &settings, None, &Silent).unwrap().diagnosis;
    diagnose::print(&d);
    assert_eq!(d.verdict.best, "offset_per_current", "{}", d.verdict.statement);
    let named = &d.candidates[0];
    assert!(named.parameters["c_per_current"].covers(-resistance), "{:?}", named.parameters);
    let text = &d.discovery.as_ref().unwrap().screened[0].toml;
    assert!(
        text.contains("v_high = \"v_high + (c_per_current*2)\"") && text.matches("parameters.").count() == 1,
        "{text}"
    );
    // A label of an observable the model does not have is refused by name.
    std::fs::write(dir.join("bad.toml"), config.replace("v_low = 0.5", "v_mid = 0.5")).unwrap();
    let e = format!("{:#}", mdpipe::systems::load(&dir.join("bad.toml")).err().expect("refused"));
    assert!(e.contains("bad.toml") && e.contains("observable_labels.current: 'v_mid' is not an observable"), "{e}");
    // So are a value that is no number and one value for every observable.
    for (label, why) in [("v_low = nan", "not a finite number"), ("v_low = 2.0", "with values that differ")] {
        std::fs::write(dir.join("bad.toml"), config.replace("v_low = 0.5", label)).unwrap();
        let e = format!("{:#}", mdpipe::systems::load(&dir.join("bad.toml")).err().expect("refused"));
        assert!(e.contains("bad.toml") && e.contains("observable_labels.current") && e.contains(why), "{e}");
    }
}

/// A rate that falls as A e^{-x/4}, measured with an efficiency that swings
/// by 5% with a 4 s period (a detector whose temperature cycles; data in
/// closed form). With no candidate declared, the periodic gain is named,
/// its angular frequency covering π/2 and its sine amplitude 0.05.
#[test]
fn a_periodic_gain_is_discovered_with_its_frequency() {
    let dir = tmpdir("periodic");
    let xs: Vec<f64> = (0..24).map(|k| 0.25 + 0.5 * f64::from(k)).collect();
    let (amp, swing, omega) = (1.2, 0.05, std::f64::consts::FRAC_PI_2);
    let shape = |_: &str, x: f64| 100.0 * (-x / 4.0).exp();
    let effect = |_: &str, x: f64| 1.0 + swing * (omega * x).sin();
    let truth = Truth { observables: &["rate"], xs: &xs, shape: &shape, effect: &effect, amp, relative: 0.005 };
    truth.write(&dir, 41);
    let config = "name = \"cycling\"\n[model]\nkind = \"emulator\"\nartifact = \"emu\"\n\
        [data]\nmeasurements = \"data.csv\"\n[parameters.A]\nmin = 0.5\nmax = 2.0\n\
        [emulator]\nparameters = [\"A\"]\nlog_observables = [\"rate\"]\n";
    let analysis = trained(&dir, "cycling.toml", config);
    let settings = DiagnoseSettings { repair: false, ..Default::default() };
    let d = diagnose::run(&analysis, &Default::default(), 9, &settings, None, &Silent).unwrap().diagnosis;
    assert_eq!(d.verdict.best, "periodic_gain_of_rate", "{}", d.verdict.statement);
    let p = &d.candidates[0].parameters;
    assert!(p["w"].covers(omega) && p["a"].covers(swing) && p["b"].covers(0.0), "{p:?}");
}
