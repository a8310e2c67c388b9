//! `diagnose` on the heavy-ion stand-in through emulators: the Grad shear δf
//! located and named, the repaired fit's coverage over seeds, the blind
//! campaign with data from event-by-event runs, and a coarse variant emulator
//! that must be refined before it is named.

use crate::diagnose::{
    clopper_pearson, confusion_matrix_meets_targets, each_verdict_is_right, first_of_each_class, EXTRA_NULLS,
};
use crate::heavy_ion_mock::grad_event_mock;
use mdpipe::calibrate::Overrides;
use mdpipe::config::Config;
use mdpipe::diagnose::{self, DiagnoseSettings};
use mdpipe::progress::Silent;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;

/// Trains an emulator on the smooth stand-in (the infinite-statistics limit
/// of simulate + ingest) over a fresh design of `spec`, saved under `dir`.
fn smooth_emulator(
    spec: &mdpipe::design::DesignSpec,
    settings: &mdpipe::emulator::EmulatorSettings,
    delta_f: mdpipe::systems::heavy_ion::DeltaF,
    points: usize,
    seed: u64,
    dir: &Path,
) {
    noisy_emulator(spec, settings, delta_f, points, 0.0, seed, dir)
}

/// As `smooth_emulator`, from runs with `run_noise` × the data's error of
/// Gaussian noise in every bin (runs of fewer events than the measurement).
fn noisy_emulator(
    spec: &mdpipe::design::DesignSpec,
    settings: &mdpipe::emulator::EmulatorSettings,
    delta_f: mdpipe::systems::heavy_ion::DeltaF,
    points: usize,
    run_noise: f64,
    seed: u64,
    dir: &Path,
) {
    let design = dir.join("design");
    mdpipe::design::write_design(spec, "test", points, seed, &design).unwrap();
    let mut table = mdpipe::systems::heavy_ion::simulate_design(&design.join("design.parquet"), delta_f).unwrap();
    if run_noise > 0.0 {
        add_run_noise(&mut table, run_noise, seed);
    }
    let training = dir.join("training.parquet");
    table.write(&training, None).unwrap();
    mdpipe::emulator::train_with_settings(settings, "test", "test", &training, None, &dir.join("emulator"), seed)
        .unwrap();
}

/// The data's error at one bin: the real iEBE-MUSIC table's, relative for
/// spectra (so it follows the value) and absolute for flow.
fn data_error(obs: &str, x: f64, value: f64) -> f64 {
    static REFERENCE: std::sync::OnceLock<Vec<mdpipe::artifacts::Measurement>> = std::sync::OnceLock::new();
    let reference = REFERENCE.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        mdpipe::paper_table::read(&root.join("pipeline/reference/iebe_music_grad_shear0p1_esw0p2.dat")).unwrap()
    });
    let r = reference.iter().find(|m| m.observable == obs && (m.x - x).abs() < 1e-6).unwrap();
    if obs.ends_with("spectrum") {
        r.error / r.value * value
    } else {
        r.error
    }
}

/// Gives every run Gaussian noise of `factor` × the data's error in each bin,
/// and records that error in the table (as ingest does for real runs).
fn add_run_noise(table: &mut mdpipe::emulator::TrainingTable, factor: f64, seed: u64) {
    use rand_distr::{Distribution, StandardNormal};
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x5e_ed0f_2025);
    let n_out = table.outputs.len();
    for (k, v) in table.values.iter_mut().enumerate() {
        let o = &table.outputs[k % n_out];
        let e = factor * data_error(&o.observable, o.x, *v);
        let z: f64 = StandardNormal.sample(&mut rng);
        *v += e * z;
        table.errors[k] = e;
    }
}

/// New variant runs for refinement with the same run noise as the variant's first runs.
struct NoisyStandIn {
    smooth: mdpipe::systems::heavy_ion::SmoothStandIn,
    run_noise: f64,
    seed: u64,
}

impl mdpipe::refine::variant::PointRunner for NoisyStandIn {
    fn run(
        &self,
        names: &[String],
        points: &[Vec<f64>],
        first_id: i64,
        dir: &Path,
    ) -> anyhow::Result<mdpipe::emulator::TrainingTable> {
        let mut table = self.smooth.run(names, points, first_id, dir)?;
        add_run_noise(&mut table, self.run_noise, self.seed.wrapping_add(first_id as u64));
        Ok(table)
    }
}

/// The 2-parameter heavy-ion config with the f_eq stand-in (60 smooth runs)
/// and every library candidate emulated from `variant_runs` smooth runs, under `dir`.
fn emulated_stand_in(dir: &Path, model_seed: u64, candidate_seed: u64, variant_runs: usize) -> Config {
    emulated_stand_in_with(dir, model_seed, candidate_seed, variant_runs, 0.0)
}

/// As `emulated_stand_in`, with the variants' runs carrying `variant_run_noise` × the data's error.
fn emulated_stand_in_with(
    dir: &Path,
    model_seed: u64,
    candidate_seed: u64,
    variant_runs: usize,
    variant_run_noise: f64,
) -> Config {
    use mdpipe::design::DesignSpec;
    use mdpipe::systems::heavy_ion::{self, DeltaF};
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut cfg = Config::load(&root.join("pipeline/heavy_ion_2param.toml")).unwrap();
    let settings = mdpipe::emulator::EmulatorSettings::load(&cfg.path).unwrap();
    let spec = DesignSpec::load(&root.join("design/heavy_ion_2param.toml")).unwrap();
    smooth_emulator(&spec, &settings, DeltaF::None, 60, model_seed, &dir.join("model"));
    for (k, cand) in heavy_ion::CANDIDATES.iter().enumerate() {
        let (mut s, mut e) = (spec.clone(), settings.clone());
        if let Some(p) = cand.design_parameter() {
            e.parameters.push(p.name.clone());
            s.parameters.push(p);
        }
        noisy_emulator(
            &s,
            &e,
            cand.delta_f(DeltaF::None),
            variant_runs,
            variant_run_noise,
            candidate_seed + k as u64,
            &dir.join(cand.name),
        );
        cfg.candidates.push(cand.declaration(dir.join(cand.name).join("emulator")).to_table().unwrap());
    }
    cfg.model = mdpipe::emulator::EmulatorFamily::model_table(&dir.join("model").join("emulator"));
    cfg
}

/// The heavy-ion half of the issue: Grad shear δf concealed in event-by-event
/// mock data, the f_eq model emulated, the stand-in's library declared as
/// variant emulators. Diagnose must locate the mismatch at high pT in the
/// spectra and v2, name the shear δf and recover η/s and ε_sw.
#[test]
#[ignore = "second tier (the first names the Grad δf in heavy_ion_blind_test_names_the_grad_delta_f); cargo test --release -- --ignored"]
fn heavy_ion_grad_delta_f_is_located_and_named() {
    let dir = std::env::temp_dir().join(format!("mdpipe-diagnose-hi-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut cfg = emulated_stand_in(&dir, 1, 10, 60);
    grad_event_mock(&mut cfg, &dir, 7);
    let cfg = mdpipe::systems::resolve(&cfg).unwrap();

    let run = diagnose::run(
        &cfg,
        &Overrides::default(),
        3,
        &DiagnoseSettings::default(),
        Some(&dir.join("diagnose")),
        &Silent,
    )
    .unwrap();
    let d = &run.diagnosis;
    diagnose::print(d);
    assert_eq!(d.verdict.best, "grad_shear_delta_f", "{}", d.verdict.statement);
    let winner = &d.candidates[0];
    // Every fit reports the emulator's share of its predictive variance (6%, 13%, 4% measured).
    for c in &d.candidates {
        println!("{}: emulator share of the predictive variance {:.3}", c.name, c.emulator_share);
        assert!(c.emulator_share > 0.0 && c.emulator_share < 1.0, "{}: {}", c.name, c.emulator_share);
    }
    // Named, so the fit rests on the data rather than on the emulator.
    assert!(winner.emulator_share <= 0.5, "{}", winner.emulator_share);
    assert!(winner.log_bayes_factor > 3.0 + 3.0 * winner.log_bayes_factor_err);
    // η/s and ε_sw are pinned to about ±0.5% by the spectra. The issue asks
    // for 95% coverage of both, which one seed cannot test: a calibrated 95%
    // interval misses on one seed in twenty, and this seed's η/s interval
    // does (0.1017 [0.1006, 0.1027]: its 3000 events give χ² 101.5 for 70
    // points against the smooth truth under their own jackknife covariance).
    // `heavy_ion_grad_fit_covers_the_truth_over_seeds` tests the coverage
    // rate over 20 seeds. Here each estimate must lie within 4 posterior sd
    // of the truth, which a calibrated posterior fails with probability
    // 6e-5: a gross bias, not bad luck.
    for (name, truth) in [("eta_s", 0.1), ("e_sw", 0.2)] {
        let p = &winner.parameters[name];
        let sd = (p.q975 - p.q025) / 3.92;
        println!(
            "{name}: {:.4} [{:.4}, {:.4}] (truth {truth}, {:.1} sd away)",
            p.median,
            p.q025,
            p.q975,
            (p.median - truth) / sd
        );
        assert!((p.median - truth).abs() < 4.0 * sd, "{name}: {p:?}");
    }
    // Without the correction η/s is biased: the reason to diagnose at all.
    let base_eta = &d.improvement.as_ref().unwrap().before[0].parameters["eta_s"];
    assert!(!base_eta.covers(0.1), "{base_eta:?}");
    // Located where the shear δf acts. The spectra rise above the model at
    // high pT, both in the no-MD residuals and in δ's posterior mean.
    let mismatch = |name: &str| d.mismatch.iter().find(|m| m.observable == name).unwrap();
    let ch = mismatch("ch_spectrum");
    assert!(ch.residual_regions.iter().any(|r| r.sign == "above" && r.x_from >= 0.5 && r.x_to >= 1.5), "{ch:?}");
    assert!(ch.x_at_max >= 1.5 && ch.map.last().unwrap().1 > 3.0, "{ch:?}");
    // δ's own regions, from its band at the data points (an emulated model has no grid).
    assert!(ch.regions.iter().any(|r| r.sign == "above" && r.x_to >= 1.5), "{ch:?}");
    // v2 falls below the model at the highest pT (δ's posterior mean beyond
    // 2σ there); the no-MD fit raises η/s to pull v2 down, which leaves it
    // above the data at low pT instead, so only δ shows the high-pT deficit.
    let v2 = mismatch("ch_v2");
    assert!(v2.map.last().unwrap().1 < -2.0, "{v2:?}");
    // Repaired: χ² falls to an adequate fit and δ shrinks.
    let imp = d.improvement.as_ref().unwrap();
    assert!(imp.after[0].chi2_per_dof < imp.before[0].chi2_per_dof);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Coverage of the 95% intervals of η/s and ε_sw from the Grad variant's fit
/// (the fit diagnose reports when it names grad_shear_delta_f), over seeded
/// 3000-event mock data sets: the same emulators and likelihood as
/// `heavy_ion_grad_delta_f_is_located_and_named`, one seed per data set.
/// Asks that the Clopper–Pearson 95% interval of each coverage rate contain
/// 0.95. Measured: η/s covered in 19 of 20 ([75%, 100%]), ε_sw in 20 of 20
/// ([83%, 100%]); 409 s on 2 shared cores.
#[test]
#[ignore = "second tier: 20 calibrations; cargo test --release -- --ignored"]
fn heavy_ion_grad_fit_covers_the_truth_over_seeds() {
    use mdpipe::calibrate::{self, Problem};
    let dir = std::env::temp_dir().join(format!("mdpipe-coverage-hi-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let base = emulated_stand_in(&dir, 1, 10, 60);
    let data_sets = 20;
    let mut covered = [0usize; 2];
    for s in 0..data_sets {
        let mut cfg = base.clone();
        let seed_dir = dir.join(format!("data_{s}"));
        grad_event_mock(&mut cfg, &seed_dir, 1000 + s as u64);
        let analysis = mdpipe::systems::resolve(&cfg).unwrap();
        let grad = analysis.candidates().unwrap().into_iter().find(|c| c.name == "grad_shear_delta_f").unwrap();
        let problem = Problem::new(
            &analysis.with_candidate(&grad),
            &Overrides { kernel: Some(mdpipe::base::choices::Kernel::None), ..Default::default() },
        )
        .unwrap();
        let cal = calibrate::run(&problem, s as u64, &Silent).unwrap();
        let mut line = format!("data set {s:2}:");
        for (k, (name, truth)) in [("eta_s", 0.1), ("e_sw", 0.2)].into_iter().enumerate() {
            let p = &cal.summary.parameters[name];
            covered[k] += p.covers(truth) as usize;
            line.push_str(&format!(
                "  {name} {:.4} [{:.4}, {:.4}]{}",
                p.median,
                p.q025,
                p.q975,
                if p.covers(truth) { "" } else { " MISS" }
            ));
        }
        println!("{line}");
        let _ = std::fs::remove_dir_all(&seed_dir);
    }
    for (k, name) in ["eta_s", "e_sw"].into_iter().enumerate() {
        let (lo, hi) = clopper_pearson(covered[k], data_sets);
        println!(
            "{name}: 95% intervals cover the truth in {} of {data_sets} data sets, rate 95% interval [{:.0}%, {:.0}%]",
            covered[k],
            100.0 * lo,
            100.0 * hi
        );
        assert!(lo <= 0.95 && 0.95 <= hi, "{name}: coverage {} of {data_sets}", covered[k]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// One heavy-ion blind data set: the concealed effect and the verdict it deserves.
struct HeavyIonBlind {
    params: mdpipe::systems::heavy_ion::HeavyIonParams,
    delta_f: mdpipe::systems::heavy_ion::DeltaF,
    /// Out-of-library: a hard-scattering tail `× (1 + a pT³)` on every spectrum, diluting v_n.
    hard_tail: f64,
    expected: &'static str,
}

fn heavy_ion_blind_effect(k: usize, rng: &mut Xoshiro256PlusPlus) -> HeavyIonBlind {
    use mdpipe::systems::heavy_ion::{DeltaF, HeavyIonParams};
    let base = HeavyIonParams::constant(0.05 + 0.25 * rng.random::<f64>(), 0.15 + 0.25 * rng.random::<f64>());
    let u: f64 = rng.random(); // magnitude, weak to strong
    let (params, delta_f, hard_tail, expected) = match k % 5 {
        0 => (base, DeltaF::None, 0.0, "none"),
        1 => (base, DeltaF::Grad, 0.0, "grad_shear_delta_f"),
        2 => (HeavyIonParams { zeta_s: 0.01 + 0.19 * u, ..base }, DeltaF::None, 0.0, "bulk_delta_f"),
        3 => (HeavyIonParams { p_survival: 0.97 - 0.4 * u, ..base }, DeltaF::None, 0.0, "proton_annihilation"),
        _ => (base, DeltaF::None, 0.002 + 0.02 * u, "unexplained"),
    };
    HeavyIonBlind { params, delta_f, hard_tail, expected }
}

/// The noise-free values of the smooth stand-in (with `b`'s effect) in the
/// analysis bins, with the real iEBE-MUSIC table's errors: what the size of
/// an effect is measured on.
fn smooth_truth(b: &HeavyIonBlind) -> Vec<mdpipe::artifacts::Measurement> {
    use mdpipe::systems::heavy_ion::events::SmoothTables;
    let edges = mdpipe::ingest::IngestSettings::default().pt_edges;
    let truth = SmoothTables::new(&b.params, b.delta_f).expected(&edges);
    let mut clean = Vec::new();
    for (obs, values) in &truth {
        for (i, &v) in values.iter().enumerate() {
            let x = 0.5 * (edges[i] + edges[i + 1]);
            let v = v * hard_tail_factor(b, obs, x);
            clean.push(mdpipe::artifacts::Measurement::new(obs, x, v, data_error(obs, x, v)));
        }
    }
    clean
}

/// `smooth_truth` with Gaussian noise of its errors: data whose only
/// randomness is the measurement's, and the noise-free values.
fn smooth_mock(
    b: &HeavyIonBlind,
    rng: &mut Xoshiro256PlusPlus,
) -> (Vec<mdpipe::artifacts::Measurement>, Vec<mdpipe::artifacts::Measurement>) {
    use rand_distr::{Distribution, StandardNormal};
    let clean = smooth_truth(b);
    let data = clean
        .iter()
        .map(|m| {
            let z: f64 = StandardNormal.sample(rng);
            mdpipe::artifacts::Measurement::new(&m.observable, m.x, m.value + m.error * z, m.error)
        })
        .collect();
    (data, clean)
}

/// The out-of-library hard tail: spectra × (1 + a pT³), v_n diluted by it.
fn hard_tail_factor(b: &HeavyIonBlind, obs: &str, x: f64) -> f64 {
    let tail = 1.0 + b.hard_tail * x.powi(3);
    if obs.ends_with("spectrum") {
        tail
    } else {
        1.0 / tail
    }
}

/// Events of the stand-in per blind data set: the study's mock statistics,
/// whose errors are 0.4–2.8× the reference tables'.
const BLIND_EVENTS: usize = 6000;

/// Blind data as real data are made: event-by-event runs of the stand-in
/// with `b`'s physics on (the hard tail applied to what was measured),
/// ingested with jackknife errors and the bins' covariance over the same
/// events. Returns the measurements and the covariance file.
fn event_mock(b: &HeavyIonBlind, names: &[String], seed: u64, dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    use mdpipe::systems::heavy_ion::{self, events::Layout};
    let runs = dir.join("runs");
    let _ = std::fs::remove_dir_all(&runs);
    std::fs::create_dir_all(&runs).unwrap();
    let oversample = heavy_ion::events::DEFAULT_OVERSAMPLE;
    heavy_ion::simulate_runs(&[(0, b.params)], b.delta_f, BLIND_EVENTS, oversample, seed, Layout::Hdf5, &runs).unwrap();
    let (mut ingested, _) =
        mdpipe::ingest::ingest_runs(&runs, None, &mdpipe::ingest::IngestSettings::default()).unwrap();
    ingested.rows.retain(|r| names.contains(&r.observable));
    let factor = |obs: &str, x: f64| hard_tail_factor(b, obs, x);
    let data: Vec<mdpipe::artifacts::Measurement> = ingested
        .rows
        .iter()
        .map(|r| {
            let f = factor(&r.observable, r.x);
            mdpipe::artifacts::Measurement::new(&r.observable, r.x, r.value * f, r.error * f)
        })
        .collect();
    let mut covariance = mdpipe::ingest::single_point_covariance(&ingested).unwrap();
    for e in covariance.iter_mut() {
        e.covariance *= factor(&e.observable_a, e.x_a) * factor(&e.observable_b, e.x_b);
    }
    let (data_path, cov_path) = (dir.join("data.csv"), dir.join("covariance.csv"));
    mdpipe::artifacts::write_measurements(&data_path, &data, None).unwrap();
    mdpipe::base::covariance::write_covariance_csv(&cov_path, &covariance).unwrap();
    (data_path, cov_path)
}

/// The heavy-ion blind campaign: 25 seeded data sets (5 each: no effect, the
/// three library candidates at weak to strong size, an out-of-library hard
/// tail) and 15 more null ones, each made as real data are, by event-by-event
/// runs of the stand-in with the physics on, ingested (`event_mock`), and
/// diagnosed against emulators of the stand-in. An effect's size is measured
/// on the noise-free smooth values with the real table's errors. `pick`
/// chooses which are diagnosed, as in `ball_drop_blind`.
/// At most `wanted` data sets are diagnosed: the search for them stops there.
/// Each fit samples `particles` per replicate.
fn heavy_ion_blind(
    tag: &str,
    wanted: usize,
    particles: usize,
    pick: &mut dyn FnMut(&str, f64) -> bool,
) -> Vec<(&'static str, String, f64)> {
    use mdpipe::model::Simulator;
    let dir = std::env::temp_dir().join(format!("mdpipe-blind-hi-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut cfg = mdpipe::systems::resolve(&emulated_stand_in(&dir, 21, 30, 60)).unwrap();
    cfg.sampler.smc.particles = particles;
    cfg.sampler.adapt = false;
    cfg.sampler.smc.replicates = 2;
    cfg.predictions.draws = 300;
    let model = mdpipe::emulator::EmulatedModel::load(&dir.join("model").join("emulator")).unwrap();
    let edges = mdpipe::ingest::IngestSettings::default().pt_edges;
    let names = model.observable_names();
    let settings = DiagnoseSettings { repair: false, ..Default::default() };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2027);
    let mut rows = Vec::new();
    for k in 0..25 + EXTRA_NULLS {
        if rows.len() == wanted {
            break;
        }
        let b = heavy_ion_blind_effect(if k < 25 { k } else { 0 }, &mut rng);
        let clean = smooth_truth(&b);
        // Noise-free size of the effect: the largest |truth − best f_eq fit|/σ,
        // the fit a χ² grid search over (η/s, ε_sw) on the model emulator.
        let xs: Vec<f64> = edges.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
        let mut best = (f64::INFINITY, 0.0);
        for i in 0..60 {
            for j in 0..60 {
                let theta = [0.4 * (i as f64 + 0.5) / 60.0, 0.1 + 0.4 * (j as f64 + 0.5) / 60.0];
                let (mut chi2, mut worst) = (0.0, 0.0f64);
                for (o, name) in names.iter().enumerate() {
                    let mut eta = vec![0.0; xs.len()];
                    model.predict(o, &xs, &theta, &mut eta);
                    for (q, m) in clean.iter().filter(|m| &m.observable == name).enumerate() {
                        let z = (m.value - eta[q]) / m.error;
                        chi2 += z * z;
                        worst = worst.max(z.abs());
                    }
                }
                if chi2 < best.0 {
                    best = (chi2, worst);
                }
            }
        }
        if !pick(b.expected, best.1) {
            continue;
        }
        let case = dir.join(format!("blind_{k}"));
        let (data, covariance) = event_mock(&b, &names, 5_000 + k as u64, &case);
        let analysis = cfg.with_data_and_covariance(&data, &covariance);
        let run = diagnose::run(&analysis, &Overrides::default(), 200 + k as u64, &settings, None, &Silent).unwrap();
        println!(
            "  data set {k:>2}: concealed {:<20} verdict {:<20} noise-free mismatch {:.1}σ",
            b.expected, run.diagnosis.verdict.best, best.1
        );
        crate::diagnose::named_at_even_odds_or_better("heavy ion", &run.diagnosis.verdict);
        rows.push((b.expected, run.diagnosis.verdict.best.clone(), best.1));
    }
    let _ = std::fs::remove_dir_all(&dir);
    rows
}

/// Second tier: the whole heavy-ion campaign, its confusion matrix and rates.
#[test]
#[ignore = "second tier: 40 diagnoses; cargo test --release -- --ignored"]
fn heavy_ion_blind_test_confusion_matrix() {
    let rows = heavy_ion_blind("all", usize::MAX, 600, &mut |_, _| true);
    let labels = ["none", "grad_shear_delta_f", "bulk_delta_f", "proton_annihilation", "unexplained", "ambiguous"];
    confusion_matrix_meets_targets("heavy ion", &labels, &rows);
}

/// First tier: the campaign's first event-by-event data set with the Grad
/// δf concealed is named. Its nulls and out-of-library tails are judged in
/// the second tier's campaign; on an emulated model the first tier judges
/// those classes on the decay counter's route
/// (`decay_counter::bundled_example_names_the_dead_time`).
#[test]
fn heavy_ion_blind_test_names_the_grad_delta_f() {
    let mut first = first_of_each_class(3.0);
    let mut pick = |label: &str, size: f64| label == "grad_shear_delta_f" && first(label, size);
    let rows = heavy_ion_blind("grad", 1, 400, &mut pick);
    assert_eq!(rows.len(), 1, "{rows:?}");
    each_verdict_is_right("heavy ion", &rows);
}

/// The coarse-variant case. Every variant emulator comes from only 24
/// runs with 3 times the data's error in each bin (a first pass at the
/// candidates with few events; smooth runs this few are already fine by the
/// unit-free share), the model's from 60 smooth runs; the
/// data are the smooth stand-in with the Grad shear δf at η/s = 0.1,
/// ε_sw = 0.2 and the real table's errors. The leading candidate's fit then
/// rests on its emulator's variance, so mdpipe must not name it; refining
/// the variant emulators the verdict lists, where each variant's posterior
/// lies, must lead to naming the Grad shear δf with η/s and ε_sw recovered.
#[test]
fn a_coarse_variant_emulator_is_not_named_until_refined() {
    use mdpipe::refine::variant::{refine_variant, RoundSettings};
    use mdpipe::systems::heavy_ion::{self, DeltaF, HeavyIonParams, SmoothStandIn};
    let dir = std::env::temp_dir().join(format!("mdpipe-coarse-variant-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    // Every variant is coarse: 24 runs, each with 3 times the data's error
    // in every bin (runs of about a ninth of the measurement's events).
    const RUN_NOISE: f64 = 3.0;
    let mut cfg = emulated_stand_in_with(&dir, 41, 50, 24, RUN_NOISE);
    let truth = HeavyIonBlind {
        params: HeavyIonParams::constant(0.1, 0.2),
        delta_f: DeltaF::Grad,
        hard_tail: 0.0,
        expected: "grad_shear_delta_f",
    };
    let (data, _) = smooth_mock(&truth, &mut Xoshiro256PlusPlus::seed_from_u64(4242));
    let path = dir.join("data.csv");
    mdpipe::artifacts::write_measurements(&path, &data, None).unwrap();
    let overrides = Overrides { data: Some(path), ..Default::default() };
    let settings = DiagnoseSettings { repair: false, ..Default::default() };
    let rounds = RoundSettings { points_per_round: 8, budget: 48, draws: 300 };
    // As the study's diagnose stage does: one seed for every diagnosis, so a
    // fit whose problem the refinement left alone (the base fits, the
    // candidates not refined) is taken from the diagnosis before.
    let reuse = diagnose::Reuse::across_diagnoses(Vec::new());
    let diagnose_with = |cfg: &Config| {
        let mut analysis = mdpipe::systems::resolve(cfg).unwrap();
        // 400 particles per replicate, as the blind test: with 600 the two
        // verdicts and the six rounds were the same, and the recovered
        // intervals' ends within 0.0001 (2026-11-30, one run each).
        analysis.sampler.smc.particles = 400;
        analysis.sampler.adapt = false;
        analysis.sampler.smc.replicates = 2;
        analysis.predictions.draws = 300;
        let run = diagnose::run_reusing(&analysis, &overrides, 300, &settings, None, &Silent, &reuse).unwrap();
        diagnose::print(&run.diagnosis);
        (analysis, run.diagnosis)
    };

    let (mut analysis, mut d) = diagnose_with(&cfg);
    // The leader's fit rests on its emulator: without the rule it would be named on variance.
    let leader = d.candidates[0].clone();
    assert!(leader.emulator_share > 0.5, "{}: share {}", leader.name, leader.emulator_share);
    assert_eq!(d.verdict.best, "emulator_limited", "{}", d.verdict.statement);
    assert!(d.verdict.refine.contains(&leader.name), "{:?}", d.verdict.refine);

    // Refine what the verdict asks for and decide again, as long as it asks.
    for pass in 0..3 {
        if d.verdict.best != "emulator_limited" {
            break;
        }
        for name in d.verdict.refine.clone() {
            let candidate = analysis.candidates().unwrap().into_iter().find(|c| c.name == name).unwrap();
            let table = cfg.candidates.iter_mut().find(|t| t["name"].as_str() == Some(name.as_str())).unwrap();
            let current = std::path::PathBuf::from(table["emulator"].as_str().unwrap());
            let runner = NoisyStandIn {
                smooth: SmoothStandIn { delta_f: heavy_ion::candidate(&name).unwrap().delta_f(DeltaF::None) },
                run_noise: RUN_NOISE,
                seed: 800 + pass,
            };
            let out = dir.join("refine").join(format!("pass_{pass}")).join(&name);
            let refined = refine_variant(
                &analysis,
                &overrides,
                &candidate,
                &current,
                &runner,
                &rounds,
                &out,
                700 + pass,
                &Silent,
            )
            .unwrap();
            println!("refined {name}: {} ({} rounds)", refined.stopped, refined.rounds.len());
            table.insert("emulator".into(), refined.emulator.display().to_string().into());
        }
        (analysis, d) = diagnose_with(&cfg);
    }
    assert_eq!(d.verdict.best, "grad_shear_delta_f", "{}", d.verdict.statement);
    let winner = &d.candidates[0];
    assert!(winner.emulator_share <= 0.5, "{}", winner.emulator_share);
    for (name, value) in [("eta_s", 0.1), ("e_sw", 0.2)] {
        let p = &winner.parameters[name];
        println!("{name}: {:.4} [{:.4}, {:.4}] (truth {value})", p.median, p.q025, p.q975);
        assert!(p.covers(value), "{name}: {p:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
