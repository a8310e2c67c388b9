//! `mdpipe run`: every stage runs and writes its artifacts, an unchanged rerun
//! skips everything, a changed setting reruns exactly the stages downstream of
//! it, an interrupted calibrate stage resumes case by case, `--stage` needs
//! its inputs, and runs made by the design's SLURM array
//! script are the runs the simulate stage would have made.

use mdpipe::config::Config;
use mdpipe::pipeline::{stages, RunOptions, StageOutcome};
use std::path::{Path, PathBuf};

pub(crate) fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mdpipe-run-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A small 2-parameter study: few points, few events, few particles.
pub(crate) fn write_config(dir: &Path, mock_events: usize, candidate_points: usize) -> PathBuf {
    let spec = Path::new(env!("CARGO_MANIFEST_DIR")).join("design/heavy_ion_2param.toml");
    let text = format!(
        r#"
name = "run_test"
[model]
kind = "emulator"
artifact = "unused"
[data]
measurements = "unused.csv"
[parameters.eta_s]
min = 0.0
max = 0.4
truth = 0.1
[parameters.e_sw]
min = 0.1
max = 0.5
truth = 0.2
[discrepancy]
kernel = "II"
bounds = {{ cbar = [0.0, 5.0], ell = [0.0, 10.0], r = [0.0, 3.0], s = [0.0, 5.0] }}
[sampler]
adapt = false
[sampler.smc]
particles = 200
replicates = 2
final_steps_per_dim = 5.0
[emulator]
parameters = ["eta_s", "e_sw"]
kernel = "matern52"
components = 4
restarts = 2
log_observables = ["ch_spectrum"]
[run]
design = "{}"
points = 16
validation_points = 6
observable_sets = [["ch_spectrum"], ["ch_spectrum", "ch_v2"]]
kernels = ["none", "II"]
candidate_points = {candidate_points}
[run.stand_in]
events = 60
oversample = 20
mock_delta_f = "grad"
mock_events = {mock_events}
candidates = ["grad_shear_delta_f", "proton_annihilation"]
[run.refine]
points_per_round = 4
budget = 8
draws = 60
variant_budget = 4
"#,
        spec.display()
    );
    let path = dir.join("study.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The diagnose stage refines the variant emulators exactly when the first
/// verdict rests on them (variant_budget is set), and diagnoses again.
fn check_variant_refinement(out: &Path, last: &serde_json::Value) {
    let before = out.join("diagnose/refine/diagnosis_before.json");
    println!("final verdict: {}", last["verdict"]["best"]);
    if !before.exists() {
        assert_ne!(last["verdict"]["best"], "emulator_limited", "an emulator-limited verdict was left unrefined");
        return;
    }
    let first: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&before).unwrap()).unwrap();
    println!("first verdict: {} (refine {})", first["verdict"]["best"], first["verdict"]["refine"]);
    assert_eq!(first["verdict"]["best"], "emulator_limited");
    for name in first["verdict"]["refine"].as_array().unwrap() {
        let rounds: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("diagnose/refine").join(name.as_str().unwrap()).join("rounds.json"))
                .unwrap(),
        )
        .unwrap();
        let list = rounds["rounds"].as_array().unwrap();
        let new_runs: u64 = list.iter().map(|r| r["new_runs"].as_u64().unwrap()).sum();
        println!("{name}: {} rounds, {new_runs} new runs, stopped: {}", list.len(), rounds["stopped"]);
        assert!(new_runs <= 4, "{name}: {new_runs} runs past the variant budget");
        // The diagnosis after refinement declares the refined emulator.
        let emulator = rounds["emulator"].as_str().unwrap();
        assert!(std::path::Path::new(emulator).join("emulator.json").exists(), "{emulator}");
        let fit = last["candidates"].as_array().unwrap().iter().find(|c| &c["name"] == name).unwrap();
        if new_runs > 0 {
            assert!(emulator.contains("round_"), "{emulator}");
        }
        println!(
            "{name}: emulator share {} → {}",
            first["candidates"].as_array().unwrap().iter().find(|c| &c["name"] == name).unwrap()["emulator_share"],
            fit["emulator_share"]
        );
    }
}

/// The refine stage: rounds reported, new runs under fresh ids with their
/// parameter files and array script, the error where the posterior lives
/// lower at the end, and the refined emulator trained on every run.
fn check_refinement(out: &Path, config: &Config) {
    let rounds: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("refine/rounds.json")).unwrap()).unwrap();
    let list = rounds["rounds"].as_array().unwrap();
    let new_runs: u64 = list.iter().map(|r| r["new_runs"].as_u64().unwrap()).sum();
    assert!(new_runs <= 8 && list.len() >= 2, "{rounds}");
    let worst = |r: &serde_json::Value, sd: &str| {
        r["ratios"].as_array().unwrap().iter().map(|o| o[sd].as_f64().unwrap()).fold(0.0, f64::max)
    };
    let (first, last) = (worst(&list[0], "latent"), worst(list.last().unwrap(), "latent"));
    // The stop reads the predictive sd (what the likelihood sees).
    let (first_predictive, last_predictive) =
        (worst(&list[0], "predictive"), worst(list.last().unwrap(), "predictive"));
    let stopped = rounds["stopped"].as_str().unwrap();
    assert!(
        if stopped.starts_with("below") { last_predictive < 1.0 } else { new_runs == 8 && first_predictive >= 1.0 },
        "{stopped}: {first_predictive} -> {last_predictive}"
    );
    if new_runs > 0 {
        assert!(
            last < first,
            "refinement did not lower the emulator's error where the posterior lives: {first} -> {last}"
        );
        let design = mdpipe::design::read_points(&out.join("refine/round_0/design/design.parquet")).unwrap();
        let ids: Vec<i64> = design.iter().map(|(id, _)| *id).collect();
        assert_eq!(ids, vec![16, 17, 18, 19]);
        // Inside the prior box, where the pilot posteriors live.
        for (_, values) in &design {
            for (name, p) in &config.parameters {
                assert!(values[name] >= p.min && values[name] <= p.max, "{name} = {}", values[name]);
            }
        }
        let script = std::fs::read_to_string(out.join("refine/round_0/design/submit.slurm")).unwrap();
        assert!(script.contains("#SBATCH --array=16-19") && script.contains("--seed"), "{script}");
        assert!(out.join("refine/round_0/design/parameters/parameter_016").exists());
        let emulator =
            mdpipe::emulator::store::load(&out.join("refine").join(rounds["emulator"].as_str().unwrap())).unwrap();
        assert!(emulator.parts.design_ids.contains(&19) && emulator.parts.design_ids.contains(&0));
    }
    assert!(std::fs::read_to_string(out.join("refine/rounds.md")).unwrap().contains("| 0 | "));
}

/// The mock data's jackknife covariance: a correlation matrix within
/// [-1, 1], used by a calibration that names it in `[data] covariance`.
fn check_mock_covariance(out: &Path, config: &Config) {
    let path = out.join("mock/covariance.csv");
    let entries = mdpipe::base::covariance::read_covariance(&path).unwrap();
    let data = mdpipe::artifacts::read_measurements(&out.join("mock/measurements.parquet")).unwrap();
    let n = data.len();
    assert_eq!(entries.len(), n * (n - 1) / 2, "every pair of the {n} points, once");
    let error = |o: &str, x: f64| data.iter().find(|m| m.observable == o && m.x == x).unwrap().error;
    for e in &entries {
        let r = e.covariance / (error(&e.observable_a, e.x_a) * error(&e.observable_b, e.x_b));
        assert!(r.abs() <= 1.0 + 1e-9, "correlation {r} of {e:?}");
    }
    let mut c = config.clone();
    c.model = mdpipe::emulator::EmulatorFamily::model_table(&out.join("emulator"));
    c.data.measurements = out.join("mock/measurements.parquet");
    c.data.covariance = Some(path);
    let analysis = mdpipe::systems::resolve(&c).unwrap();
    let problem = mdpipe::calibrate::Problem::new(&analysis, &Default::default()).unwrap();
    assert!(problem.likelihood.blocks.iter().all(|b| b.covariance.is_some()));
}

/// `path` (an absolute, existing folder) as a path relative to the working folder, through `..`.
fn relative_to_cwd(path: &Path) -> PathBuf {
    let cwd = std::env::current_dir().unwrap();
    let mut rel = PathBuf::new();
    for _ in cwd.components().skip(1) {
        rel.push("..");
    }
    rel.push(path.strip_prefix("/").unwrap());
    assert!(rel.is_relative() && rel.canonicalize().unwrap() == path.canonicalize().unwrap());
    rel
}

/// `mdpipe run` with the systems the command line has.
fn run(config: &Config, opts: &RunOptions) -> anyhow::Result<Vec<StageOutcome>> {
    mdpipe::pipeline::run(config, opts, &mdpipe::app::systems())
}

fn opts(out: &Path, stage: Option<&str>, force: bool) -> RunOptions {
    RunOptions {
        out: out.to_path_buf(),
        seed: 3,
        stage: stage.map(String::from),
        force,
        show_progress: false,
        executor: mdpipe::execute::Executor::Local,
        mdpipe: env!("CARGO_BIN_EXE_mdpipe").into(),
        case: None,
    }
}

fn ran(outcomes: &[StageOutcome]) -> Vec<String> {
    outcomes.iter().filter(|o| o.ran).map(|o| o.stage.clone()).collect()
}

#[test]
fn run_executes_every_stage_then_skips_what_is_unchanged() {
    let dir = tmpdir("all");
    let out = dir.join("out");
    let config = Config::load(&write_config(&dir, 300, 12)).unwrap();

    // `--out` relative to the working folder, which is not the config's: the
    // study must find what it wrote (the variant emulators, at its diagnose
    // stage) where it wrote it, not relative to the config.
    let first = run(&config, &opts(&relative_to_cwd(&dir).join("out"), None, false)).unwrap();
    assert_eq!(ran(&first), stages(&mdpipe::app::systems()));
    for p in [
        "design/design.parquet",
        "validation_design/design.parquet",
        "design/submit.slurm",
        "training.parquet",
        "validation.parquet",
        "emulator/emulator.json",
        "emulator/validation.json",
        "mock/measurements.parquet",
        "study.json",
        "study.md",
        "report.html",
        "candidates/grad_shear_delta_f/emulator/emulator.json",
        "candidates/proton_annihilation/design/design.parquet",
        "diagnose/diagnosis.json",
        "diagnose/report.html",
        "diagnose/verify.json",
    ] {
        assert!(out.join(p).exists(), "{p} missing");
    }
    let study: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("study.json")).unwrap()).unwrap();
    let cases = study["cases"].as_array().unwrap();
    assert_eq!(cases.len(), 4, "2 observable sets x 2 kernels");
    for c in cases {
        let bias = c["parameters"]["eta_s"]["bias_in_sd"].as_f64().unwrap();
        let p = &c["parameters"]["eta_s"];
        // bias/sd is (median - truth)/sd, as the table says.
        let expect = (p["median"].as_f64().unwrap() - 0.1) / p["sd"].as_f64().unwrap();
        assert!((bias - expect).abs() < 1e-9);
    }
    // One "observables added" check per kernel and parameter; no Kernel I, so no II-vs-I check.
    let checks = study["consistency"].as_array().unwrap();
    assert_eq!(checks.len(), 4);
    assert!(checks.iter().all(|c| c["check"] == "observables added"));
    assert_eq!(study["emulator_vs_data"].as_array().unwrap().len(), 2);
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(report.contains("Consistency checks") && report.contains("bias"));
    // The proton-annihilation variant is emulated over θ and its own parameter.
    let variant = mdpipe::emulator::EmulatedModel::load(&out.join("candidates/proton_annihilation/emulator")).unwrap();
    assert_eq!(mdpipe::model::Simulator::parameter_names(&variant), vec!["eta_s", "e_sw", "p_survival"]);
    // Each variant is validated like the base emulator (5-fold cross-validation, every observable).
    for name in ["grad_shear_delta_f", "proton_annihilation"] {
        let v: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("candidates").join(name).join("emulator/validation.json")).unwrap(),
        )
        .unwrap();
        let cv = v["cross_validation"].as_array().unwrap();
        assert_eq!(v["folds"], 5);
        assert!(
            !cv.is_empty()
                && cv.iter().all(|o| o["rmse"].as_f64().unwrap().is_finite() && o["n"].as_u64().unwrap() > 0),
            "{name}: {cv:?}"
        );
    }
    check_refinement(&out, &config);
    check_mock_covariance(&out, &config);
    let diagnosis: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnose/diagnosis.json")).unwrap()).unwrap();
    let names: Vec<&str> =
        diagnosis["candidates"].as_array().unwrap().iter().map(|c| c["name"].as_str().unwrap()).collect();
    assert_eq!(names.len(), 2);
    assert!(names.contains(&"grad_shear_delta_f") && names.contains(&"proton_annihilation"));
    check_variant_refinement(&out, &diagnosis);
    // The diagnosis's final fit was run through the stand-in (its variant's
    // command when a variant is named): five θ, each compared at every data point.
    let verify: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnose/verify.json")).unwrap()).unwrap();
    let points = verify["points"].as_array().unwrap();
    assert!(verify["checked"] == true && points.len() == 5, "{verify}");
    assert!(
        points.iter().all(|p| p["chi2_simulator"].as_f64().unwrap().is_finite() && p["points"].as_u64() > Some(0)),
        "{verify}"
    );
    // A declared variant whose own parameter has no prior is refused, naming the config and the field.
    let mut declared = config.clone();
    declared.model = mdpipe::emulator::EmulatorFamily::model_table(&out.join("emulator"));
    let declaration = mdpipe::emulator::family::CandidateDeclaration::of_emulator(
        "annihilation",
        "p annihilation",
        out.join("candidates/proton_annihilation/emulator"),
        Default::default(),
    );
    declared.candidates = vec![declaration.to_table().unwrap()];
    let msg = format!(
        "{:#}",
        mdpipe::systems::resolve(&declared).unwrap().candidates().err().expect("missing prior accepted")
    );
    assert!(msg.contains("study.toml") && msg.contains("[candidates.parameters.p_survival]"), "{msg}");

    // Unchanged: nothing runs.
    let second = run(&config, &opts(&out, None, false)).unwrap();
    assert!(ran(&second).is_empty(), "reran {:?}", ran(&second));
    assert_eq!(second.len(), stages(&mdpipe::app::systems()).len());

    // --stage with --force reruns that stage only.
    let forced = run(&config, &opts(&out, Some("calibrate"), true)).unwrap();
    assert_eq!(ran(&forced), vec!["calibrate"]);

    // An interrupted calibrate stage (its stamp and one case's missing) redoes only the unfinished case.
    std::fs::remove_file(out.join("stages/calibrate.json")).unwrap();
    std::fs::remove_file(out.join("stages/calibrate/ch_spectrum+ch_v2__kernel2.json")).unwrap();
    let kept = out.join("calibrate/ch_spectrum__nomd/summary.json");
    let redone = out.join("calibrate/ch_spectrum+ch_v2__kernel2/summary.json");
    let (kept_time, redone_time) = (
        std::fs::metadata(&kept).unwrap().modified().unwrap(),
        std::fs::metadata(&redone).unwrap().modified().unwrap(),
    );
    let resumed = run(&config, &opts(&out, None, false)).unwrap();
    // A stage that ran hands its downstream stages a new key (it cannot tell
    // that the redone case came out as before), so the report is rebuilt.
    assert_eq!(ran(&resumed), vec!["calibrate", "report"]);
    assert_eq!(std::fs::metadata(&kept).unwrap().modified().unwrap(), kept_time, "a finished case was recomputed");
    assert_ne!(
        std::fs::metadata(&redone).unwrap().modified().unwrap(),
        redone_time,
        "the unfinished case was not recomputed"
    );

    // More mock events: the mock data and everything after them rerun; the runs and emulator do not.
    let config2 = Config::load(&write_config(&dir, 400, 12)).unwrap();
    let third = run(&config2, &opts(&out, None, false)).unwrap();
    assert_eq!(ran(&third), vec!["mock", "refine", "calibrate", "report", "diagnose"]);

    // A changed candidate setting redoes the variants and the diagnosis, not the calibrations.
    let config3 = Config::load(&write_config(&dir, 400, 10)).unwrap();
    let variants = run(&config3, &opts(&out, None, false)).unwrap();
    assert_eq!(ran(&variants), vec!["candidates", "diagnose"]);

    // Deleted runs are made again, and what was built on them is redone.
    std::fs::remove_dir_all(out.join("design/runs")).unwrap();
    let fourth = run(&config2, &opts(&out, None, false)).unwrap();
    assert_eq!(ran(&fourth).first().map(String::as_str), Some("simulate"));
    assert!(ran(&fourth).contains(&"ingest".to_string()));
    assert!(out.join("design/runs/0015").exists());

    // A stage whose inputs were never made says which stage to run.
    let err = run(&config, &opts(&dir.join("fresh"), Some("ingest"), false)).unwrap_err();
    let msg = format!("{err:#}");
    assert!(msg.contains("needs the outputs of stage simulate"), "{msg}");
    // An unknown stage is refused before anything runs, naming the stages there are.
    let err = format!("{:#}", run(&config, &opts(&dir.join("unknown"), Some("fit"), false)).unwrap_err());
    assert!(err.contains("unknown stage \"fit\" (use design, simulate,") && err.contains("mock"), "{err}");
    assert!(!dir.join("unknown").join("stages").exists(), "nothing runs for an unknown stage");
    // A bad [run] table is refused before any stage runs, naming the file and field.
    let text = std::fs::read_to_string(dir.join("study.toml"))
        .unwrap()
        .replace(r#"kernels = ["none", "II"]"#, r#"kernels = ["none", "III"]"#);
    std::fs::write(dir.join("bad.toml"), text).unwrap();
    let err = run(&Config::load(&dir.join("bad.toml")).unwrap(), &opts(&dir.join("bad"), None, false)).unwrap_err();
    let msg = format!("{err:#}");
    assert!(msg.contains("bad.toml: [run]") && msg.contains("unknown kernel \"III\""), "{msg}");
    assert!(!dir.join("bad").exists(), "nothing may be written for a refused config");
}

/// Runs a design folder's SLURM array script by hand, as Slurm would: the
/// whole script under bash, once per task, with the task's id and the
/// folder as the submit directory.
fn run_slurm_array(design_dir: &Path, n: usize) {
    let script = design_dir.join("submit.slurm");
    for id in 0..n {
        let status = std::process::Command::new("bash")
            .arg(&script)
            .env("SLURM_ARRAY_TASK_ID", id.to_string())
            .env("SLURM_SUBMIT_DIR", design_dir)
            .current_dir(design_dir)
            .output()
            .unwrap();
        assert!(status.status.success(), "task {id}: {}", String::from_utf8_lossy(&status.stderr));
    }
}

#[test]
fn slurm_array_runs_are_the_simulate_stage_runs() {
    let dir = tmpdir("slurm");
    let config = Config::load(&write_config(&dir, 300, 12)).unwrap();
    // Reference: the pipeline simulates and ingests.
    let local = dir.join("local");
    run(&config, &opts(&local, Some("design"), false)).unwrap();
    run(&config, &opts(&local, Some("simulate"), false)).unwrap();
    run(&config, &opts(&local, Some("ingest"), false)).unwrap();
    // Batch: the design stage, then its array scripts, then ingest.
    let batch = dir.join("batch");
    // Runs left from an earlier design (an interrupted simulate leaves no stamp)
    // must not be taken for this design's: the design stage removes them.
    std::fs::create_dir_all(batch.join("design/runs/0003")).unwrap();
    run(&config, &opts(&batch, Some("design"), false)).unwrap();
    assert!(!batch.join("design/runs").exists(), "runs of a previous design survived a new design");
    run_slurm_array(&batch.join("design"), 16);
    run_slurm_array(&batch.join("validation_design"), 6);
    let sim = run(&config, &opts(&batch, Some("simulate"), false)).unwrap();
    assert_eq!(ran(&sim), vec!["simulate"]); // it finds every point already run and keeps them
    run(&config, &opts(&batch, Some("ingest"), false)).unwrap();
    for table in ["training.parquet", "validation.parquet"] {
        let a = mdpipe::artifacts::read_parquet(&local.join(table)).unwrap();
        let b = mdpipe::artifacts::read_parquet(&batch.join(table)).unwrap();
        assert_eq!(a.height(), b.height(), "{table}");
        for col in ["value", "error"] {
            let (va, vb) = (a.column(col).unwrap().f64().unwrap(), b.column(col).unwrap().f64().unwrap());
            assert!(
                va.iter().zip(vb.iter()).all(|(x, y)| x == y),
                "{table}: column {col} differs between the SLURM and local runs"
            );
        }
    }
}

/// The stand-in run point by point through the executor's command (`--only
/// ID --point-folder`, how `mdpipe run` now builds the model and each library
/// candidate's variant) writes byte for byte the runs of the in-process run
/// over the whole design that the candidates stage used before: the study's
/// tables, emulators and verdict are unchanged by the move.
#[test]
fn the_stand_in_point_by_point_equals_the_whole_design_in_process() {
    let dir = tmpdir("stand-in-points");
    let mdpipe = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_mdpipe")).args(args).output().unwrap();
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    };
    let spec = Path::new(env!("CARGO_MANIFEST_DIR")).join("design/heavy_ion_2param.toml");
    let d = dir.join("d");
    mdpipe(&["design", spec.to_str().unwrap(), "--points", "3", "--out", d.to_str().unwrap()]);
    let design = d.join("design.parquet");
    let common = ["--delta-f", "grad", "--events", "20", "--oversample", "5", "--layout", "hdf5", "--seed", "1001"];
    let whole = dir.join("whole");
    let mut args =
        vec!["simulate", "heavy-ion", "--design", design.to_str().unwrap(), "--out", whole.to_str().unwrap()];
    args.extend(common);
    mdpipe(&args);
    for id in ["0", "1", "2"] {
        let point = dir.join("points").join(format!("000{id}"));
        let mut args =
            vec!["simulate", "heavy-ion", "--design", design.to_str().unwrap(), "--only", id, "--point-folder"];
        args.extend(common);
        args.extend(["--out", point.to_str().unwrap()]);
        mdpipe(&args);
        let (a, b) = (
            std::fs::read(whole.join(format!("000{id}/spvn_results.h5"))).unwrap(),
            std::fs::read(point.join("spvn_results.h5")).unwrap(),
        );
        assert!(a == b, "point {id}: the runs differ");
    }
}
