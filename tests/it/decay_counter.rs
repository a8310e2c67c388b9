//! The diagnose loop for a user's own simulator: the bundled example
//! (`examples/decay_counter`, a Python Monte Carlo outside mdpipe) run by
//! `mdpipe run` from an empty folder, locally and through a real Slurm, and
//! blind tests whose data are the simulator's own noisy runs.
//!
//! The blind data sets hide one effect at a time (or none) at seeded truths;
//! the emulators `diagnose` judges them with are trained on other runs of
//! the simulator. An effect's size is computed by the test's own integrator
//! from closed forms (Bateman for the daughter, n/(1+nτ) for the dead time):
//! the largest |truth − best ideal-detector fit| / σ over the bins.
//!
//! libtest starts tests in name order; this module's name puts the first
//! tier's longest test near the start, so that the shorter ones fill the
//! other test thread while it runs (last in the list, it ran its final two
//! minutes alone).

use crate::diagnose::{clopper_pearson, confusion_matrix_meets_targets, each_verdict_is_right, first_of_each_class};
use crate::pipeline::tmpdir;
use mdpipe::calibrate::Overrides;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: f64 = 0.5;
const BINS: usize = 24;

/// A copy of the bundled example in a fresh folder, writing into `out/` there.
fn example_copy(tag: &str, simulator_extra: &str) -> PathBuf {
    let dir = tmpdir(tag);
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/decay_counter");
    for f in ["simulator.py", "design.toml", "measurements.csv"] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let study = std::fs::read_to_string(src.join("study.toml")).unwrap();
    let study = study.replace("[run]\n", "[run]\nout = \"out\"\n").replace(
        "placeholders = { background = \"off\" }\n",
        &format!("placeholders = {{ background = \"off\" }}\n{simulator_extra}"),
    );
    std::fs::write(dir.join("study.toml"), study).unwrap();
    dir
}

fn mdpipe_run(dir: &Path, extra: &[&str]) {
    let out =
        Command::new(env!("CARGO_BIN_EXE_mdpipe")).arg("run").arg(dir.join("study.toml")).args(extra).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{text}");
    assert!(out.status.success(), "mdpipe run failed:\n{text}");
}

pub(crate) fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// The bundled example from an empty folder: the verdict names the dead
/// time, the repaired fit's 95% intervals cover every true value, and the
/// report shows δ before and after the repair.
fn check_bundled_verdict(out: &Path) {
    let d = json(&out.join("diagnose/diagnosis.json"));
    assert_eq!(d["verdict"]["best"], "dead_time", "{:#}", d["verdict"]);
    let repaired = &d["improvement"]["after"][0]["parameters"];
    for (name, truth) in [("activity", 50_000.0), ("half_life", 2.0), ("dead_time_us", 2.5)] {
        let p = &repaired[name];
        let (lo, hi) = (p["q025"].as_f64().unwrap(), p["q975"].as_f64().unwrap());
        assert!(lo <= truth && truth <= hi, "{name}: repaired 95% interval [{lo}, {hi}] misses the truth {truth}");
    }
    let report = std::fs::read_to_string(out.join("diagnose/report.html")).unwrap();
    for caption in ["before: model + δ", "after: repaired model + δ"] {
        assert!(report.contains(caption), "the diagnose report lacks the figure '{caption}'");
    }
}

fn tables_equal(a: &Path, b: &Path) {
    let (a, b) = (mdpipe::artifacts::read_parquet(a).unwrap(), mdpipe::artifacts::read_parquet(b).unwrap());
    assert_eq!(a.shape(), b.shape());
    for name in a.get_column_names() {
        let values = |df: &polars::prelude::DataFrame| -> Vec<Option<f64>> {
            let c = df.column(name).unwrap().cast(&polars::prelude::DataType::Float64).unwrap();
            c.f64().unwrap().iter().collect()
        };
        assert_eq!(values(&a), values(&b), "column {name} differs");
    }
}

#[test]
fn bundled_example_names_the_dead_time() {
    let dir = example_copy("decay-local", "");
    // Half the study's particles in its fits: the verdict and the intervals
    // asked of them need no more (the Slurm test and the campaign, in the
    // second tier, run the study as bundled).
    let study = std::fs::read_to_string(dir.join("study.toml")).unwrap();
    assert!(study.contains("particles = 2000\n"), "the bundled study's particles moved");
    // 30 runs per design, not 40 (the model's and each candidate's): the
    // emulators, of two or three parameters each and smooth in all, need no
    // more for this verdict (dead_time at 40 and at 30, every truth inside
    // the repaired intervals, 2026-11-30); the Slurm test and the campaign
    // run the bundled 40.
    assert!(study.contains("\npoints = 40\n"), "the bundled study's design size moved");
    let study = study.replace("particles = 2000\n", "particles = 1000\n").replace("\npoints = 40\n", "\npoints = 30\n");
    std::fs::write(dir.join("study.toml"), study).unwrap();
    // Runs of two experiments each, not four: the simulator's Python is
    // most of this test's CPU, and the route checked here (runs, emulators,
    // the verdict) does not need its runs' noise at half the data's; the
    // Slurm test and the campaign run the design as bundled.
    let design = std::fs::read_to_string(dir.join("design.toml")).unwrap();
    assert!(design.contains("\nreplicas = 4 "), "the bundled design's replicas moved");
    std::fs::write(dir.join("design.toml"), design.replace("\nreplicas = 4 ", "\nreplicas = 2 ")).unwrap();
    mdpipe_run(&dir, &[]);
    check_bundled_verdict(&dir.join("out"));
    // Blind data on this route with the study's emulators: a null, a
    // declared effect other than the example's, and a periodic efficiency
    // no candidate declares, which the search names (every class, and the
    // full campaign, in the second tier).
    let mut pick = first_of_each_class(3.0);
    // These three verdicts ask no more of the evidence than a quarter of
    // the study's particles give (the campaign, in the second tier,
    // samples as the study does).
    let rows = decay_blind(&dir, Some(500), &mut |label, size| {
        matches!(label, "none" | "background" | "periodic_gain_of_rate") && pick(label, size)
    });
    assert_eq!(rows.len(), 3, "{rows:?}");
    each_verdict_is_right("decay counter", &rows);
}

/// The bundled example through the Slurm that `.ci/run` starts: the same
/// tables and the same diagnosis as the local executor's.
#[test]
#[ignore = "second tier: cargo test --release -- --ignored"]
fn bundled_example_under_slurm_equals_the_local_run() {
    assert!(crate::cluster::slurm_answers(), "no Slurm cluster answers (as root: bash .ci/slurm-setup.sh)");
    let dir = example_copy("decay-local2", "");
    mdpipe_run(&dir, &[]);
    let local = dir.join("out");
    let slurm_dir = example_copy("decay-slurm", "parallel = 2\nslurm = { poll_seconds = 1.0 }\n");
    mdpipe_run(&slurm_dir, &["--executor", "slurm"]);
    let slurm = slurm_dir.join("out");
    for table in [
        "training.parquet",
        "validation.parquet",
        "candidates/dead_time/training.parquet",
        "candidates/background/training.parquet",
        "candidates/daughter/training.parquet",
    ] {
        tables_equal(&local.join(table), &slurm.join(table));
    }
    let (a, b) = (json(&local.join("diagnose/diagnosis.json")), json(&slurm.join("diagnose/diagnosis.json")));
    assert_eq!(a["verdict"], b["verdict"]);
    assert_eq!(a["candidates"], b["candidates"], "the same runs gave other candidate fits under Slurm");
}

/// One hidden effect and its truth.
#[derive(Clone, Copy, Debug)]
enum Effect {
    None,
    DeadTime(f64),
    Background(f64),
    Daughter(f64),
    /// Out of the study's declared candidates, in the grammar of discovered
    /// corrections: the detector's efficiency swings by this fraction with a
    /// 4 s period. (A steady drift, 1 − k t, was tried first: it is a shorter
    /// half-life to within 0.1–0.7σ, so no test of anything.)
    Modulation(f64),
}

impl Effect {
    fn label(self) -> &'static str {
        match self {
            Effect::None => "none",
            Effect::DeadTime(_) => "dead_time",
            Effect::Background(_) => "background",
            Effect::Daughter(_) => "daughter",
            Effect::Modulation(_) => "periodic_gain_of_rate",
        }
    }
}

/// Blind data sets: 20 null, 30 with a declared effect (10 each), 6 with a
/// periodic efficiency only discovery can name, then 4 more null (24 nulls bound a clean false-alarm rate
/// below 15%: the upper 95% limit of 0 in 24 is 14.2%).
const BLIND_SETS: usize = 60;

/// The k-th blind data set's effect and source (activity, half-life), seeded.
fn blind_case(k: usize) -> (Effect, f64, f64) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7_000 + k as u64);
    let (activity, half_life) = (rng.random_range(35_000.0..65_000.0), rng.random_range(1.5..3.0));
    let effect = match k {
        0..=19 => Effect::None,
        // Sizes mostly of 3σ or more: a dead time below ~3 µs is largely
        // absorbed by a shorter half-life and a lower activity.
        20..=49 => match k % 3 {
            0 => Effect::DeadTime(rng.random_range(3.5..5.0)),
            1 => Effect::Background(rng.random_range(300.0..1_500.0)),
            _ => Effect::Daughter(rng.random_range(6.0..30.0)),
        },
        50..=55 => Effect::Modulation(rng.random_range(0.04..0.12)),
        _ => Effect::None,
    };
    (effect, activity, half_life)
}

/// The expected count rate in each bin, by the test's own Simpson rule over
/// closed forms.
fn expected_rates(effect: Effect, activity: f64, half_life: f64) -> Vec<f64> {
    let lam = std::f64::consts::LN_2 / half_life;
    let rate = |t: f64| {
        let n = activity * (-lam * t).exp();
        match effect {
            Effect::None => n,
            Effect::DeadTime(us) => n / (1.0 + n * us * 1e-6),
            Effect::Background(b) => n + b,
            Effect::Daughter(hl) => {
                let ld = std::f64::consts::LN_2 / hl;
                n + activity * ld / (ld - lam) * ((-lam * t).exp() - (-ld * t).exp())
            }
            Effect::Modulation(a) => {
                let omega = 2.0 * std::f64::consts::PI / 4.0;
                n * (1.0 - 0.5 * a * (1.0 + (omega * t).sin()))
            }
        }
    };
    (0..BINS)
        .map(|i| {
            let (a, m) = (i as f64 * BIN, 64);
            let h = BIN / m as f64;
            let sum: f64 = (0..=m)
                .map(|j| {
                    let w = if j == 0 || j == m {
                        1.0
                    } else if j % 2 == 1 {
                        4.0
                    } else {
                        2.0
                    };
                    w * rate(a + j as f64 * h)
                })
                .sum();
            sum * h / 3.0 / BIN
        })
        .collect()
}

/// Noise-free size of an effect: the largest |truth − best ideal-detector
/// fit| / σ over the bins, the fit weighted least squares over the half-life
/// (a fine grid) with the activity in closed form.
fn effect_size(effect: Effect, activity: f64, half_life: f64) -> f64 {
    // The ideal detector's shapes on the half-life grid, the same for every data set.
    static SHAPES: std::sync::OnceLock<Vec<Vec<f64>>> = std::sync::OnceLock::new();
    let shapes = SHAPES
        .get_or_init(|| (0..=3000).map(|j| expected_rates(Effect::None, 1.0, 1.0 + 3.0 * j as f64 / 3000.0)).collect());
    let truth = expected_rates(effect, activity, half_life);
    let sigma: Vec<f64> = truth.iter().map(|r| (r * BIN).sqrt() / BIN).collect();
    shapes
        .iter()
        .map(|shape| {
            let (num, den) = (0..BINS).fold((0.0, 0.0), |(n, d), i| {
                let w = 1.0 / (sigma[i] * sigma[i]);
                (n + w * shape[i] * truth[i], d + w * shape[i] * shape[i])
            });
            let a = num / den;
            (0..BINS).map(|i| ((truth[i] - a * shape[i]) / sigma[i]).abs()).fold(0.0, f64::max)
        })
        .fold(f64::INFINITY, f64::min)
}

/// One measurement: a run of the simulator itself at the truth, with its own seed.
fn measure(dir: &Path, k: usize, effect: Effect, activity: f64, half_life: f64) -> PathBuf {
    let case = dir.join(format!("blind_{k:02}"));
    std::fs::create_dir_all(&case).unwrap();
    let mut params = format!("activity {activity}\nhalf_life {half_life}\n");
    let mut args: Vec<String> = vec!["--seed".into(), (90_000 + k).to_string()];
    match effect {
        Effect::None => {}
        Effect::DeadTime(us) => params.push_str(&format!("detector_model nonparalyzable\ndead_time_us {us}\n")),
        Effect::Background(b) => {
            params.push_str(&format!("background_rate {b}\n"));
            args.extend(["--background".into(), "on".into()]);
        }
        Effect::Daughter(hl) => {
            params.push_str(&format!("daughter_half_life {hl}\n"));
            args.push("--chain".into());
        }
        Effect::Modulation(a) => params.push_str(&format!("efficiency_modulation {a}\n")),
    }
    std::fs::write(case.join("params"), params).unwrap();
    let status = Command::new("python3")
        .arg(dir.join("simulator.py"))
        .arg(case.join("params"))
        .arg(&case)
        .args(&args)
        .status()
        .expect("python3 runs the bundled simulator");
    assert!(status.success());
    case.join("outputs.csv")
}

/// Diagnoses blind data sets made by the simulator's own runs with the
/// study's emulators (the study in `dir` must have run), with `particles`
/// per replicate (None: the study's); returns (hidden effect, verdict,
/// noise-free size) for the data sets `pick` keeps.
fn decay_blind(
    dir: &Path,
    particles: Option<usize>,
    pick: &mut dyn FnMut(&str, f64) -> bool,
) -> Vec<(&'static str, String, f64)> {
    let mut analysis = mdpipe::pipeline::load(&dir.join("study.toml"), &mdpipe::app::systems()).unwrap();
    if let Some(n) = particles {
        analysis.sampler.smc.particles = n;
    }
    let mut rows = Vec::new();
    for k in 0..BLIND_SETS {
        let (effect, activity, half_life) = blind_case(k);
        let size = effect_size(effect, activity, half_life);
        if !pick(effect.label(), size) {
            continue;
        }
        let data = measure(dir, k, effect, activity, half_life);
        let overrides = Overrides { data: Some(data), ..Default::default() };
        let settings = mdpipe::diagnose::DiagnoseSettings::default();
        let run =
            mdpipe::diagnose::run(&analysis, &overrides, 11 + k as u64, &settings, None, &mdpipe::progress::Silent)
                .unwrap();
        println!(
            "  data set {k:>2}: hidden {:<12} {effect:?}, activity {activity:.0}, half-life {half_life:.2} s: verdict {:<12} noise-free mismatch {size:.1}σ",
            effect.label(),
            run.diagnosis.verdict.best
        );
        crate::diagnose::named_at_even_odds_or_better("decay counter", &run.diagnosis.verdict);
        rows.push((effect.label(), run.diagnosis.verdict.best.clone(), size));
    }
    rows
}

/// The full campaign: 60 seeded data sets (24 null, 30 in-library, 6 out of
/// the library), each the simulator's own run.
#[test]
#[ignore = "second tier: cargo test --release -- --ignored"]
fn decay_counter_blind_test_confusion_matrix() {
    let dir = example_copy("decay-blind", "");
    mdpipe_run(&dir, &["--stage", "design"]);
    for stage in ["simulate", "ingest", "emulator", "candidates"] {
        mdpipe_run(&dir, &["--stage", stage]);
    }
    let rows = decay_blind(&dir, None, &mut |_, _| true);
    let strong = rows.iter().filter(|r| !matches!(r.0, "none" | "unexplained") && r.2 >= 3.0).count();
    assert!(strong >= 20, "only {strong} in-library effects of 3σ or more");
    let labels = [
        "none",
        "dead_time",
        "background",
        "daughter",
        "periodic_gain_of_rate",
        "unexplained",
        "ambiguous",
        "emulator_limited",
    ];
    confusion_matrix_meets_targets("decay counter", &labels, &rows);
    let nulls = rows.iter().filter(|r| r.0 == "none").count();
    let alarms = rows.iter().filter(|r| r.0 == "none" && r.1 != "none").count();
    assert!(clopper_pearson(alarms, nulls).1 < 0.15, "false-alarm upper bound not below 15%");
}

/// Second tier: discovery on the emulated route. The decay-counter study
/// with its `[[candidates]]` taken out, diagnosed with `--discover` on data
/// sets from the simulator's own runs: 20 with a dead time of 5–20 µs and
/// 20 with a background of 300–2000 counts/s, each at 5σ or more, and 20
/// nulls. Right: for the dead time a counting loss, rate/(1 + c*rate) with
/// c covering τ or rate + c*rate^2 with c covering −τ (the same loss to
/// second order); for the background an offset rate + c with c covering it.
/// Then 20 sets at 5σ or more whose efficiency swings with a 4 s period:
/// right, a periodic gain with w covering 2π/4.
/// (Dead times of 3.5–6 µs, the blind test's, stay below 5σ here: the fit
/// absorbs them in a shorter half-life and a lower activity.)
#[test]
#[ignore = "second tier: 80 emulated diagnoses with discovery; cargo test --release -- --ignored"]
fn decay_counter_discovery_campaign() {
    let dir = example_copy("decay-discover", "");
    let study = std::fs::read_to_string(dir.join("study.toml")).unwrap();
    let bare = study.split("[[candidates]]").next().unwrap().replace("[run]\n", "[run]\ndiscover = true\n");
    std::fs::write(dir.join("study.toml"), bare).unwrap();
    for stage in ["design", "simulate", "ingest", "emulator", "diagnose"] {
        mdpipe_run(&dir, &["--stage", stage]);
    }
    // The study's own measurements (a 2.5 µs dead time) at the end of
    // `mdpipe run` with no candidates and `[run] discover = true`: a
    // counting loss is found, alone or standing first beside its twin.
    // (Unasked the search would not run: this 2.5 µs dead time leaves the
    // model alone at χ²/dof 1.75, a mismatch the verdict does not flag.)
    let text = std::fs::read_to_string(dir.join("out/diagnose/diagnosis.json")).unwrap();
    let d: mdpipe::diagnose::Diagnosis = serde_json::from_str(&text).unwrap();
    let losses = ["saturation_of_rate", "square_loss_of_rate"];
    let found = losses.contains(&d.verdict.best.as_str())
        || (d.verdict.best == "ambiguous" && losses.contains(&d.verdict.standing[0].as_str()));
    assert!(d.discovery.is_some() && found, "{}", d.verdict.statement);
    let analysis = mdpipe::pipeline::load(&dir.join("study.toml"), &mdpipe::app::systems()).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7_500);
    // right, ambiguous with a right form standing, total: dead time, background, nulls, modulation
    let mut tally = [[0usize; 3]; 4];
    for k in 0..600 {
        if tally[..3].iter().all(|t| t[2] >= 20) {
            break;
        }
        let (activity, half_life) = (rng.random_range(35_000.0..65_000.0), rng.random_range(1.5..3.0));
        let (effect, kind) = match k % 3 {
            0 => (Effect::DeadTime(rng.random_range(5.0..20.0)), 0),
            1 => (Effect::Background(rng.random_range(300.0..2_000.0)), 1),
            _ => (Effect::None, 2),
        };
        if tally[kind][2] < 20 {
            discovery_set(&analysis, &dir, k, effect, (activity, half_life), &mut tally[kind]);
        }
    }
    // The periodic efficiency, from seeds of its own so that the sets above
    // are the same as before it was added.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7_600);
    for k in 600..1200 {
        if tally[3][2] >= 20 {
            break;
        }
        let (activity, half_life) = (rng.random_range(35_000.0..65_000.0), rng.random_range(1.5..3.0));
        let effect = Effect::Modulation(rng.random_range(0.04..0.2));
        discovery_set(&analysis, &dir, k, effect, (activity, half_life), &mut tally[3]);
    }
    let classes = [
        "dead time ≥ 5σ, a counting loss",
        "background ≥ 5σ, an offset",
        "nulls, nothing discovered",
        "periodic efficiency ≥ 5σ, a periodic gain",
    ];
    for (what, t) in classes.iter().zip(&tally) {
        let (lo, hi) = clopper_pearson(t[0], t[2]);
        println!(
            "discovery, decay counter: {what}: {} of {} right, 95% interval [{:.0}%, {:.0}%]; {} ambiguous with a right form standing",
            t[0], t[2], 100.0 * lo, 100.0 * hi, t[1]
        );
    }
    assert!(tally[3][0] * 5 >= tally[3][2] * 4, "{tally:?}");
    assert!(tally[0][0] * 5 >= tally[0][2] * 4 && tally[1][0] * 5 >= tally[1][2] * 4, "{tally:?}");
    assert!((tally[2][2] - tally[2][0]) * 20 <= tally[2][2], "{tally:?}");
}

/// One data set of the discovery campaign, unless its effect is below 5σ:
/// measured by the simulator, diagnosed with discovery forced on, and
/// counted in `tally` (right, ambiguous with a right form standing, total).
fn discovery_set(
    analysis: &mdpipe::calibrate::Analysis,
    dir: &Path,
    k: usize,
    effect: Effect,
    (activity, half_life): (f64, f64),
    tally: &mut [usize; 3],
) {
    use mdpipe::diagnose::{self, DiagnoseSettings, Discover};
    let size = effect_size(effect, activity, half_life);
    if !matches!(effect, Effect::None) && size < 5.0 {
        return;
    }
    let data = measure(dir, 100 + k, effect, activity, half_life);
    let overrides = Overrides { data: Some(data), ..Default::default() };
    let settings = DiagnoseSettings { repair: false, discover: Discover::Always, ..Default::default() };
    let d = diagnose::run(analysis, &overrides, 11 + k as u64, &settings, None, &mdpipe::progress::Silent)
        .unwrap()
        .diagnosis;
    crate::diagnose::named_at_even_odds_or_better("decay counter discovery", &d.verdict);
    let named = d.candidates.iter().find(|c| c.name == d.verdict.best && c.prior_log_odds < 0.0);
    let covers = |name: &str, p: &str, value: f64| {
        named.is_some_and(|c| c.name == name && c.parameters.get(p).is_some_and(|s| s.covers(value)))
    };
    let standing = |names: &[&str]| {
        d.verdict.best == "ambiguous" && d.verdict.standing.iter().any(|s| names.contains(&s.as_str()))
    };
    let (right, ambiguous) = match effect {
        Effect::DeadTime(us) => (
            covers("saturation_of_rate", "c", us * 1e-6) || covers("square_loss_of_rate", "c", -us * 1e-6),
            standing(&["saturation_of_rate", "square_loss_of_rate"]),
        ),
        Effect::Background(b) => (covers("offset_of_rate", "c", b), standing(&["offset_of_rate"])),
        // The efficiency's 4 s period: w = 2π/4.
        Effect::Modulation(_) => {
            (covers("periodic_gain_of_rate", "w", std::f64::consts::FRAC_PI_2), standing(&["periodic_gain_of_rate"]))
        }
        _ => (named.is_none(), false),
    };
    println!("  set {k}: {effect:?} {size:.1}σ → {} {}", d.verdict.best, if right { "right" } else { "WRONG" });
    tally[0] += usize::from(right);
    tally[1] += usize::from(!right && ambiguous);
    tally[2] += 1;
}
