//! A study of the second system end to end, with the systems list the test
//! gives: its table is refused by the command line's list (which does not
//! hold it), claimed by a list with it; its simulator, stage, data and keys
//! are used by the generic stages; its own stages, with their own ids, run
//! where it placed them.

use super::FreeFall;
use crate::base::choices::Executor;
use crate::base::config::Config;
use crate::pipeline::plan::{assert_reads_only_earlier, names};
use crate::pipeline::stage::StageId;
use crate::pipeline::{run, RunOptions, Systems};
use crate::run_systems::StandIn;
use std::path::{Path, PathBuf};

/// A candidate that corrects the output: nothing to run.
const DRAG: &str =
    "[[candidates]]\nname = \"drag\"\ncorrection = { v = \"v*(1 - k*x)\" }\nparameters.k = { min = 0.0, max = 0.2 }\n";

fn study(dir: &Path, samples: usize) -> Config {
    std::fs::write(
        dir.join("design.toml"),
        "name = \"free_fall\"\n[[parameter]]\nname = \"g\"\nmin = 5.0\nmax = 15.0\n",
    )
    .unwrap();
    let text = format!(
        r#"
name = "free_fall"
[model]
kind = "emulator"
[data]
measurements = "unused.csv"
[parameters.g]
min = 5.0
max = 15.0
truth = 9.81
[sampler.smc]
particles = 300
replicates = 2
[emulator]
parameters = ["g"]
kernel = "matern52"
components = 2
restarts = 2
[run]
design = "design.toml"
points = 8
validation_points = 3
observable_sets = [["v"]]
kernels = ["none"]
[run.free_fall]
samples = {samples}
t_max = 2.0
mock_error = 0.05
"#
    );
    std::fs::write(dir.join("study.toml"), text).unwrap();
    Config::load(&dir.join("study.toml")).unwrap()
}

fn options(out: PathBuf) -> RunOptions {
    RunOptions {
        out,
        seed: 7,
        stage: None,
        force: false,
        show_progress: false,
        executor: Executor::Local,
        mdpipe: PathBuf::from("unused"),
        case: None,
    }
}

fn ran(outcomes: &[crate::pipeline::StageOutcome]) -> Vec<&str> {
    outcomes.iter().filter(|o| o.ran).map(|o| o.stage.as_str()).collect()
}

/// Its stages sit where it says, each with an id of its own and reading
/// only stages before it; the stages that read its mock data read it, and
/// a stage that does not read it does not.
#[test]
fn its_stages_sit_where_it_says_and_their_readers_read_them() {
    let with_system = crate::pipeline::plan::stages(&Systems::new(vec![&FreeFall]));
    assert_reads_only_earlier(&with_system);
    let placed = [
        "design",
        "simulate",
        "ingest",
        "emulator",
        "fall_mock",
        "refine",
        "calibrate",
        "fall_probe",
        "report",
        "candidates",
        "diagnose",
    ];
    assert_eq!(names(&with_system), placed);
    let calibrate = with_system.iter().find(|p| p.stage.id() == StageId::CALIBRATE).unwrap();
    assert!(calibrate.upstream.contains(&StageId::new("fall_mock")), "a reader reads the system's stage");
    let report = with_system.iter().find(|p| p.stage.id() == StageId::REPORT).unwrap();
    assert!(!report.upstream.contains(&StageId::new("fall_mock")), "a stage that does not read it does not");
}

#[test]
fn a_second_system_plugs_in_with_its_folder_and_one_line() {
    let dir = std::env::temp_dir().join(format!("mdpipe-free-fall-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = study(&dir, 10);
    let out = dir.join("out");

    // The command line's list does not hold it: its table is refused by name.
    let without = Systems::new(vec![&StandIn]);
    let err = format!("{:#}", run(&config, &options(out.clone()), &without).unwrap_err());
    assert!(err.contains("[run.free_fall]: no system of that name") && err.contains("stand_in"), "{err}");
    assert!(!out.join("stages").exists(), "nothing runs when a table is refused");

    // One line: the list with it.
    let systems = Systems::new(vec![&StandIn, &FreeFall]);
    let first = run(&config, &options(out.clone()), &systems).unwrap();
    // The diagnose stage ends a study with no candidates too (its search on).
    let all =
        ["design", "simulate", "ingest", "emulator", "fall_mock", "calibrate", "fall_probe", "report", "diagnose"];
    assert_eq!(ran(&first), all);
    let diagnosis: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnose/diagnosis.json")).unwrap()).unwrap();
    assert_eq!(diagnosis["verdict"]["best"], "none", "mock data of the model itself: {}", diagnosis["verdict"]);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("calibrate/v__nomd/summary.json")).unwrap()).unwrap();
    let g = &summary["parameters"]["g"];
    let (lo, hi) = (g["q025"].as_f64().unwrap(), g["q975"].as_f64().unwrap());
    // Ten speeds of error 0.05 m/s up to 2 s: g is known to about 0.02 m/s².
    assert!(lo < 9.81 && 9.81 < hi && hi - lo < 0.2, "g in [{lo}, {hi}]");
    assert_eq!(summary["units"]["parameters"]["g"], "m/s²", "the system's units reach the fit");
    assert!(std::fs::read_to_string(out.join("mock/measurements.csv")).unwrap().lines().count() == 11);
    // The diagnosis's emulated fit, run through the simulator at its
    // posterior median and four draws: v = g t, which eight runs emulate
    // well, so the simulator agrees with the emulator there.
    let verify: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnose/verify.json")).unwrap()).unwrap();
    assert_eq!((verify["fit"].as_str(), verify["checked"].as_bool()), (Some("base_md"), Some(true)), "{verify}");
    let checked = verify["points"].as_array().unwrap();
    assert_eq!(checked.len(), 5, "{verify}");
    for p in checked {
        let (sim, emu) = (p["chi2_simulator"].as_f64().unwrap(), p["chi2_emulator"].as_f64().unwrap());
        assert!(p["points"] == 10 && sim.is_finite() && emu.is_finite(), "{p}");
    }
    assert!(verify["outcome"].as_str().unwrap().starts_with("consistent"), "{verify}");
    let report = std::fs::read_to_string(out.join("diagnose/report.html")).unwrap();
    assert!(report.contains("Checked against the simulator") && report.contains("posterior median"));
    assert!(report.contains("<td>g = "), "the θ each run was made at");
    // Its probe ran after the calibrations it reads.
    let probe: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("probe.json")).unwrap()).unwrap();
    assert_eq!(probe["cases"], 1);

    // Unchanged, nothing reruns; its own setting that shapes the runs
    // (what it adds to the design's key) reruns the design and what follows.
    assert!(ran(&run(&config, &options(out.clone()), &systems).unwrap()).is_empty());
    // A candidate declared (a correction of the output: nothing to run)
    // redoes the diagnosis, not the calibrations.
    let mut text = std::fs::read_to_string(dir.join("study.toml")).unwrap();
    text.push_str(DRAG);
    std::fs::write(dir.join("study.toml"), text).unwrap();
    let with_candidate = Config::load(&dir.join("study.toml")).unwrap();
    assert_eq!(ran(&run(&with_candidate, &options(out.clone()), &systems).unwrap()), ["diagnose"]);
    let config = study(&dir, 12);
    let again = run(&config, &options(out.clone()), &systems).unwrap();
    assert_eq!(ran(&again), all);
    // The check of the new diagnosis ran anew: no run of the old θ, with
    // the old times, is kept under the same ids.
    let verify: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnose/verify.json")).unwrap()).unwrap();
    assert!(verify["points"].as_array().unwrap().iter().all(|p| p["points"] == 12), "{verify}");
    // The check switched off: the diagnosis is made again (its key holds
    // the switch), and nothing is run through the simulator.
    let text = std::fs::read_to_string(dir.join("study.toml")).unwrap().replace("[run]\n", "[run]\nverify = false\n");
    std::fs::write(dir.join("study.toml"), text).unwrap();
    let unchecked = Config::load(&dir.join("study.toml")).unwrap();
    assert_eq!(ran(&run(&unchecked, &options(out.clone()), &systems).unwrap()), ["diagnose"]);
    let verify: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnose/verify.json")).unwrap()).unwrap();
    assert_eq!(verify["checked"], false, "{verify}");
    assert_eq!(verify["outcome"], "not run: [run] verify = false", "{verify}");
    assert!(verify["points"].as_array().unwrap().is_empty(), "{verify}");
    // The candidate declared again, then the check switched back on: two
    // more diagnoses, the second taking the first's fit of the candidate.
    let edits: [fn(String) -> String; 2] = [|t| t + DRAG, |t| t.replace("verify = false\n", "")];
    for edit in edits {
        let text = edit(std::fs::read_to_string(dir.join("study.toml")).unwrap());
        std::fs::write(dir.join("study.toml"), text).unwrap();
        let edited = Config::load(&dir.join("study.toml")).unwrap();
        assert_eq!(ran(&run(&edited, &options(out.clone()), &systems).unwrap()), ["diagnose"]);
    }
    kept_diagnoses_hold_their_fits(&out);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Each diagnosis a rerun under other settings replaced is kept in
/// `previous/`, with the stamp of how it was made; the last one's fit of
/// the candidate (its problem unchanged by the switch) is taken, not
/// sampled again: the same fit, down to its wall time.
fn kept_diagnoses_hold_their_fits(out: &std::path::Path) {
    let kept: Vec<_> = std::fs::read_dir(out.join("previous")).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(kept.len(), 5, "one per diagnosis replaced: {kept:?}");
    for k in &kept {
        assert!(k.join("diagnosis.json").is_file() && k.join("stage.json").is_file(), "{}", k.display());
    }
    let wall = |fit: &std::path::Path| -> f64 {
        let s: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(fit.join("summary.json")).unwrap()).unwrap();
        s["diagnostics"]["wall_seconds"].as_f64().unwrap()
    };
    let now = wall(&out.join("diagnose/candidate_drag"));
    let before: Vec<f64> =
        kept.iter().map(|k| k.join("candidate_drag")).filter(|f| f.is_dir()).map(|f| wall(&f)).collect();
    assert!(before.contains(&now), "the candidate was sampled again ({now} s; kept fits {before:?})");
}

/// The simulator a study ran, changed since its runs (a user's fix, a new
/// build): the emulator still answers for the old one, and the diagnosis's
/// check against the simulator says the fit is contradicted. The free fall
/// runs through a script of the user's, `[run.simulator]`, whose factor on
/// v = g t lives in a file beside it; the command's text, and so every
/// stage's key, stays the same.
#[test]
fn a_simulator_changed_since_its_runs_contradicts_the_emulated_fit() {
    let dir = std::env::temp_dir().join(format!("mdpipe-free-fall-changed-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    study(&dir, 10);
    std::fs::write(
        dir.join("sim.sh"),
        "f=$(cat \"$(dirname \"$0\")/factor\")\nmkdir -p \"$2\" && awk -v g=\"$1\" -v f=\"$f\" 'BEGIN { print \"observable,x,value\"; for (i = 1; i <= 10; i++) { t = 2.0 * i / 10; printf \"v,%.17g,%.17g\\n\", t, f * g * t } }' > \"$2/outputs.csv\"\n",
    )
    .unwrap();
    std::fs::write(dir.join("factor"), "1\n").unwrap();
    let mut text = std::fs::read_to_string(dir.join("study.toml")).unwrap();
    text.push_str("[run.simulator]\ncommand = \"sh {config_dir}/sim.sh {g} {point}\"\noutput = \"table\"\n");
    std::fs::write(dir.join("study.toml"), text).unwrap();
    let config = Config::load(&dir.join("study.toml")).unwrap();
    let (out, systems) = (dir.join("out"), Systems::new(vec![&StandIn, &FreeFall]));
    let outcome = |opts: RunOptions| {
        run(&config, &opts, &systems).unwrap();
        let verify: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("diagnose/verify.json")).unwrap()).unwrap();
        verify["outcome"].as_str().unwrap().to_string()
    };
    assert!(outcome(options(out.clone())).starts_with("consistent"));
    // v 20% faster at every θ: the runs of the check disagree with the
    // emulator by some 40σ per point at the fit's median.
    std::fs::write(dir.join("factor"), "1.2\n").unwrap();
    let again = RunOptions { stage: Some("diagnose".into()), force: true, ..options(out.clone()) };
    let contradicted = outcome(again);
    assert!(contradicted.starts_with("contradicted by the simulator"), "{contradicted}");
    let report = std::fs::read_to_string(out.join("diagnose/report.html")).unwrap();
    assert!(report.contains("contradicted by the simulator"), "the report does not say so");
    let _ = std::fs::remove_dir_all(&dir);
}
