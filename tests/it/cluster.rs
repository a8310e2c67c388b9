//! `mdpipe run` driving a user's simulator: the local executor with points
//! that fail, time out or fail once (reported with exit codes and log tails,
//! left out of the emulator's training, retried), and the Slurm executor
//! against a real Slurm (`.ci/slurm-setup.sh`): a job array with one point
//! that fails once and is resubmitted, mdpipe killed while the array runs and
//! restarted, and the ingested tables equal to the local executor's; then the
//! calibration cases as array tasks, with posteriors equal to a local run's.

use crate::pipeline::tmpdir;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn mdpipe() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mdpipe"))
}

/// A toy simulator, y(x) = a + b x² (+ c x³, a candidate's term) at six x: it fails for the ids in
/// `$FAIL` while `$marks/down` exists, sleeps past any limit for `$HANG`, fails the first time for
/// `$FLAKY` (a marker file remembers), and otherwise naps `$NAP` seconds (or what `$marks/nap`
/// says, when a test shortens the nap between two runs) and writes outputs.csv.
const SIMULATOR: &str = r#"#!/bin/bash
id=$1; a=$2; b=$3; out=$4; marks=$5; c=${6:-0}
for f in $FAIL; do [ "$id" = "$f" ] && [ -e "$marks/down" ] && { echo "solver diverged at design point $id" >&2; exit 3; }; done
for h in $HANG; do [ "$id" = "$h" ] && sleep 60; done
if [ "$id" = "$FLAKY" ] && [ ! -e "$marks/flaky_$id" ]; then
  touch "$marks/flaky_$id"; echo "transient failure: scratch disk busy" >&2; exit 1
fi
sleep "$(cat "$marks/nap" 2>/dev/null || echo "$NAP")"
{
  echo "observable,x,value"
  for x in 0.1 0.3 0.5 0.7 0.9 1.1; do
    awk -v a="$a" -v b="$b" -v c="$c" -v x="$x" 'BEGIN { printf "y,%s,%.12g\n", x, a + b * x * x + c * x * x * x }'
  done
} > "$out/outputs.csv"
"#;

/// A candidate with a command of its own: the toy with a cubic term c x³.
const CUBIC: &str = r#"
[[candidates]]
name = "cubic"
description = "a cubic term c x^3"
command = "FAIL= HANG= FLAKY= NAP=0 bash {config_dir}/sim.sh {id} {a} {b} {point} {config_dir}/marks {c}"
[candidates.parameters.c]
min = 0.0
max = 1.0
"#;

/// A study of the toy simulator: 16 training and 4 validation points over
/// a ∈ [0, 2], b ∈ [0, 3]; data at a = 1, b = 2.
fn write_study(dir: &Path, env: &str, simulator_extra: &str) -> PathBuf {
    let sim = dir.join("sim.sh");
    std::fs::write(&sim, SIMULATOR).unwrap();
    std::fs::create_dir_all(dir.join("marks")).unwrap();
    std::fs::write(dir.join("design.toml"), "name = \"toy\"\n[[parameter]]\nname = \"a\"\nmin = 0.0\nmax = 2.0\nkey = \"a\"\n[[parameter]]\nname = \"b\"\nmin = 0.0\nmax = 3.0\nkey = \"b\"\n").unwrap();
    let mut data = String::from("observable,x,value,error\n");
    for x in [0.1, 0.3, 0.5, 0.7, 0.9, 1.1] {
        data.push_str(&format!("y,{x},{},0.02\n", 1.0 + 2.0 * x * x));
    }
    std::fs::write(dir.join("data.csv"), data).unwrap();
    let text = format!(
        r#"
name = "toy_study"
[model]
kind = "emulator"
artifact = "unused"
[data]
measurements = "data.csv"
[parameters.a]
min = 0.0
max = 2.0
[parameters.b]
min = 0.0
max = 3.0
[discrepancy]
kernel = "II"
bounds = {{ cbar = [0.0, 5.0], ell = [0.0, 10.0], r = [0.0, 3.0], s = [0.0, 5.0] }}
[sampler]
adapt = false
[sampler.smc]
particles = 400
replicates = 2
[emulator]
parameters = ["a", "b"]
kernel = "matern52"
components = 3
restarts = 2
[run]
design = "design.toml"
points = 16
validation_points = 4
observable_sets = [["y"]]
kernels = ["none", "II"]
[run.simulator]
command = "{env} bash {sim} {{id}} {{a}} {{b}} {{point}} {marks}"
output = "table"
{simulator_extra}
"#,
        sim = sim.display(),
        marks = dir.join("marks").display(),
    );
    let path = dir.join("study.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn run(config: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    mdpipe().arg("run").arg(config).args(["--seed", "5", "--out"]).arg(out).args(extra).output().unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

fn design_ids(table: &Path) -> Vec<i64> {
    let df = mdpipe::artifacts::read_parquet(table).unwrap();
    let mut ids: Vec<i64> = df.column("design_id").unwrap().i64().unwrap().into_no_null_iter().collect();
    ids.dedup();
    ids
}

#[test]
fn local_executor_reports_failed_points_and_trains_on_the_rest() {
    let dir = tmpdir("local-failures");
    let config = write_study(&dir, "FAIL='2 5' HANG=7 FLAKY=4 NAP=0", "time_limit = \"3s\"\nretries = 1\nparallel = 2");
    std::fs::write(dir.join("marks/down"), "").unwrap();
    let out = dir.join("out");
    let o = run(&config, &out, &[]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "mdpipe run failed:\n{stdout}\n{}", String::from_utf8_lossy(&o.stderr));

    // The report lists each failed point with every attempt's exit code and log tail.
    let report = json(&out.join("design/runs/execution.json"));
    let failed: Vec<i64> = report["failed"].as_array().unwrap().iter().map(|f| f["id"].as_i64().unwrap()).collect();
    assert_eq!(failed, vec![2, 5, 7], "{report:#}");
    for f in report["failed"].as_array().unwrap() {
        let attempts = f["attempts"].as_array().unwrap();
        assert_eq!(attempts.len(), 2, "one retry: {f:#}");
        for a in attempts {
            if f["id"] == 7 {
                assert_eq!(a["timed_out"], true, "{a:#}");
                assert!(
                    a["seconds"].as_f64().unwrap() >= 3.0 && a["seconds"].as_f64().unwrap() < 20.0,
                    "the 3 s limit: {a:#}"
                );
            } else {
                assert_eq!(a["exit_code"], 3, "{a:#}");
                assert!(
                    a["stderr_tail"]
                        .as_str()
                        .unwrap()
                        .contains(&format!("solver diverged at design point {}", f["id"])),
                    "{a:#}"
                );
            }
        }
    }
    assert_eq!(report["retried"], serde_json::json!([4]), "point 4 failed once and succeeded on its retry: {report:#}");
    assert_eq!(report["succeeded"], 13);
    // stdout says so, with the exit codes and stderr tails.
    assert!(stdout.contains("warning: 3 of 16 points of the design failed and are left out"), "{stdout}");
    assert!(
        stdout.contains("exit code 3")
            && stdout.contains("| solver diverged at design point 5")
            && stdout.contains("timed out after"),
        "{stdout}"
    );

    // The emulator is trained on the rest, and the calibration finds the truth.
    assert_eq!(design_ids(&out.join("training.parquet")), vec![0, 1, 3, 4, 6, 8, 9, 10, 11, 12, 13, 14, 15]);
    assert_eq!(design_ids(&out.join("validation.parquet")), vec![0, 1, 3]);
    let emulator = json(&out.join("emulator/emulator.json"));
    assert_eq!(emulator["report"]["n_points"], 13, "emulator trained on the 13 good points");
    let cases = json(&out.join("calibrate/cases.json"));
    let p = &cases["cases"][0]["parameters"];
    for (name, truth) in [("a", 1.0), ("b", 2.0)] {
        let (lo, hi) = (p[name]["q025"].as_f64().unwrap(), p[name]["q975"].as_f64().unwrap());
        assert!(lo <= truth && truth <= hi, "{name}: 95% interval [{lo}, {hi}] misses {truth}");
    }
    assert!(out.join("report.html").exists());

    // Unchanged, a rerun skips every stage; failed points are not retried behind the user's back.
    let again = run(&config, &out, &[]);
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert!(
        again.status.success()
            && stdout.contains("[simulate] up to date, skipped")
            && stdout.contains("[calibrate] up to date, skipped"),
        "{stdout}"
    );
    // A stage forced to run again with the same settings reruns what follows
    // (the calibrations must not keep the previous emulator's results).
    assert!(run(&config, &out, &["--stage", "emulator", "--force"]).status.success());
    let after = run(&config, &out, &[]);
    let stdout = String::from_utf8_lossy(&after.stdout);
    assert!(
        after.status.success()
            && stdout.contains("[ingest] up to date, skipped")
            && stdout.contains("[calibrate] running"),
        "{stdout}"
    );

    // The cause mended, `--stage simulate --force` runs only the failed points
    // again (the finished ones are kept), and ingest takes them in.
    std::fs::remove_file(dir.join("marks/down")).unwrap();
    let kept = std::fs::metadata(out.join("design/runs/0000/outputs.csv")).unwrap().modified().unwrap();
    let o = run(&config, &out, &["--stage", "simulate", "--force"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && stdout.contains("16 points (13 had their run, 2 ran, 0 after a retry, 1 failed)"),
        "{stdout}"
    );
    assert_eq!(
        std::fs::metadata(out.join("design/runs/0000/outputs.csv")).unwrap().modified().unwrap(),
        kept,
        "a finished point was run again"
    );
    let report = json(&out.join("design/runs/execution.json"));
    assert_eq!(
        report["failed"].as_array().unwrap().iter().map(|f| f["id"].as_i64().unwrap()).collect::<Vec<_>>(),
        vec![7],
        "{report:#}"
    );
    assert!(run(&config, &out, &["--stage", "ingest"]).status.success());
    assert_eq!(design_ids(&out.join("training.parquet")), vec![0, 1, 2, 3, 4, 5, 6, 8, 9, 10, 11, 12, 13, 14, 15]);
}

/// Whether a Slurm cluster answers with a node that takes jobs: idle, or
/// busy with another test's (mixed, allocated, completing). Asked once per
/// test run: where `sinfo` is installed without a controller it waits about
/// half a minute before it fails, and every Slurm test would wait again.
pub(crate) fn slurm_answers() -> bool {
    static ANSWER: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ANSWER.get_or_init(ask_sinfo)
}

fn ask_sinfo() -> bool {
    Command::new("sinfo")
        .args(["-h", "-o", "%T"])
        .output()
        .map(|o| {
            let states = String::from_utf8_lossy(&o.stdout).to_string();
            o.status.success() && ["idle", "mix", "alloc", "completing"].iter().any(|s| states.contains(s))
        })
        .unwrap_or(false)
}

fn tables_equal(a: &Path, b: &Path) {
    let (a, b) = (mdpipe::artifacts::read_parquet(a).unwrap(), mdpipe::artifacts::read_parquet(b).unwrap());
    assert_eq!(a.height(), b.height());
    for col in ["design_id", "x", "value", "a", "b"] {
        let (va, vb) = (
            a.column(col).unwrap().cast(&polars::prelude::DataType::Float64).unwrap(),
            b.column(col).unwrap().cast(&polars::prelude::DataType::Float64).unwrap(),
        );
        assert!(
            va.f64().unwrap().iter().zip(vb.f64().unwrap().iter()).all(|(x, y)| x == y),
            "column {col} differs between the Slurm and local executors"
        );
    }
}

#[test]
fn slurm_executor_retries_resumes_and_matches_the_local_executor() {
    if !slurm_answers() {
        // CI starts a one-node cluster (.ci/slurm-setup.sh); there this test must run.
        crate::common::skip(
            "slurm_executor_retries_resumes_and_matches_the_local_executor",
            "no Slurm cluster answers here (as root: bash .ci/slurm-setup.sh)",
        );
        return;
    }
    let dir = tmpdir("slurm-executor");
    let config = write_study(
        &dir,
        "FAIL= HANG= FLAKY=5 NAP=1",
        &("time_limit = \"2m\"\nretries = 2\nparallel = 2\nslurm = { poll_seconds = 1.0 }\n\n".to_string() + CUBIC),
    );
    let slurm = dir.join("slurm");
    assert!(run(&config, &slurm, &["--stage", "design"]).status.success());

    // mdpipe submits the array and is killed while it runs.
    let mut child = mdpipe()
        .arg("run")
        .arg(&config)
        .args(["--seed", "5", "--out"])
        .arg(&slurm)
        .args(["--stage", "simulate", "--executor", "slurm"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let state = slurm.join("design/runs/.attempts/slurm.json");
    let start = Instant::now();
    while !(state.exists() && slurm.join("design/runs/0000").exists()) {
        assert!(start.elapsed() < Duration::from_secs(300), "no array submitted and no point done in 300 s");
        assert!(child.try_wait().unwrap().is_none(), "mdpipe ended before the kill");
        std::thread::sleep(Duration::from_millis(200));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let first_job = json(&state)["submissions"][0]["job_id"].as_str().unwrap().to_string();
    let queued = Command::new("squeue").args(["-h", "-j", &first_job]).output().unwrap();
    assert!(
        !String::from_utf8_lossy(&queued.stdout).trim().is_empty(),
        "the kill should land while array {first_job} still runs"
    );

    // Restarted, mdpipe follows the same array, then resubmits the point that failed once.
    let o = run(&config, &slurm, &["--stage", "simulate", "--executor", "slurm"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains(&format!("following array job {first_job} from an earlier mdpipe")), "{stdout}");
    let submissions = json(&state)["submissions"].as_array().unwrap().clone();
    assert_eq!(
        submissions[0]["job_id"].as_str().unwrap(),
        first_job,
        "the first array was followed, not submitted again"
    );
    assert_eq!(submissions.len(), 2, "one resubmission, of the failed point only: {submissions:?}");
    assert_eq!(submissions[1]["ids"], serde_json::json!([5]));
    let report = json(&slurm.join("design/runs/execution.json"));
    assert_eq!(report["executor"], "slurm");
    assert_eq!(report["retried"], serde_json::json!([5]), "{report:#}");
    assert!(report["failed"].as_array().unwrap().is_empty(), "{report:#}");
    let log = std::fs::read_to_string(slurm.join(format!("design/runs/.attempts/0005.j{first_job}.log"))).unwrap();
    assert!(log.contains("transient failure"), "the failed attempt's log is kept: {log}");
    assert!(run(&config, &slurm, &["--stage", "ingest"]).status.success());

    // The local executor makes the same tables.
    let local = dir.join("local");
    for stage in ["design", "simulate", "ingest"] {
        let o = run(&config, &local, &["--stage", stage]);
        assert!(o.status.success(), "local {stage}: {}", String::from_utf8_lossy(&o.stderr));
    }
    for table in ["training.parquet", "validation.parquet"] {
        tables_equal(&slurm.join(table), &local.join(table));
    }
    assert_eq!(design_ids(&slurm.join("training.parquet")), (0..16).collect::<Vec<i64>>());

    // The rest of the study, with the two calibration cases as one array, equals the local run's.
    let o = run(&config, &slurm, &["--executor", "slurm"]);
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    let cases = json(&slurm.join("calibrate/.array/.attempts/slurm.json"));
    assert_eq!(cases["submissions"].as_array().unwrap().len(), 1, "{cases:#}");
    assert_eq!(cases["submissions"][0]["ids"], serde_json::json!([0, 1]), "both cases as array tasks");
    let o = run(&config, &local, &[]);
    assert!(o.status.success(), "local: {}", String::from_utf8_lossy(&o.stderr));
    for case in ["y__nomd", "y__kernel2"] {
        let (a, b) = (
            mdpipe::artifacts::read_parquet(&slurm.join("calibrate").join(case).join("posterior.parquet")).unwrap(),
            mdpipe::artifacts::read_parquet(&local.join("calibrate").join(case).join("posterior.parquet")).unwrap(),
        );
        assert_eq!(a.get_column_names(), b.get_column_names());
        for col in a.get_column_names() {
            let (va, vb) = (
                a.column(col.as_str()).unwrap().cast(&polars::prelude::DataType::Float64).unwrap(),
                b.column(col.as_str()).unwrap().cast(&polars::prelude::DataType::Float64).unwrap(),
            );
            assert!(
                va.f64().unwrap().iter().zip(vb.f64().unwrap().iter()).all(|(x, y)| x == y),
                "{case}: posterior column {col} differs between the array task and the local run"
            );
        }
    }
    assert!(slurm.join("calibrate/cases.md").exists() && slurm.join("report.html").exists());
    // The candidate's variant: its runs through Slurm equal the local ones, and so does the diagnosis.
    tables_equal(&slurm.join("candidates/cubic/training.parquet"), &local.join("candidates/cubic/training.parquet"));
    let (a, b) = (json(&slurm.join("diagnose/diagnosis.json")), json(&local.join("diagnose/diagnosis.json")));
    assert_eq!(a["verdict"], b["verdict"]);
    assert_eq!(a["candidates"], b["candidates"]);
    assert_eq!(a["verdict"]["best"], "none", "no cubic term in the data: {:#}", a["verdict"]);
    // The fit the verdict ends on, run through the simulator: as an array
    // job under Slurm, with the same runs and so the same χ² as locally.
    let (a, b) = (json(&slurm.join("diagnose/verify.json")), json(&local.join("diagnose/verify.json")));
    assert!(a["outcome"].as_str().unwrap().starts_with("consistent"), "{a:#}");
    assert_eq!(a["points"].as_array().unwrap().len(), 5, "the median and four draws: {a:#}");
    assert_eq!(a["points"], b["points"], "the check's runs differ between Slurm and local");
    let check = json(&slurm.join("diagnose/verify/design/runs/.attempts/slurm.json"));
    assert_eq!(check["submissions"][0]["ids"], serde_json::json!([0, 1, 2, 3, 4]), "{check:#}");
    assert_eq!(json(&slurm.join("diagnose/verify/design/runs/execution.json"))["executor"], "slurm");
}

/// An array that can never start (held here; a partition limit it can never
/// meet elsewhere) stops mdpipe with the reason and the scancel to run, instead
/// of a wait without end.
#[test]
fn a_slurm_array_that_cannot_start_stops_with_the_reason() {
    if !slurm_answers() {
        crate::common::skip(
            "a_slurm_array_that_cannot_start_stops_with_the_reason",
            "no Slurm cluster answers here (as root: bash .ci/slurm-setup.sh)",
        );
        return;
    }
    let dir = tmpdir("slurm-held");
    let config = write_study(&dir, "FAIL= HANG= FLAKY= NAP=0", "slurm = { poll_seconds = 1.0, extra = [\"--hold\"] }");
    let out = dir.join("out");
    assert!(run(&config, &out, &["--stage", "design"]).status.success());
    let mut child = mdpipe()
        .arg("run")
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .args(["--stage", "simulate", "--executor", "slurm"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > Duration::from_secs(120) {
            child.kill().unwrap();
            panic!("mdpipe kept waiting on a held array for 120 s");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    let job =
        json(&out.join("design/runs/.attempts/slurm.json"))["submissions"][0]["job_id"].as_str().unwrap().to_string();
    let _ = Command::new("scancel").arg(&job).output();
    assert!(!status.success(), "a held array must stop the run");
    assert!(stderr.contains("JobHeldUser") && stderr.contains(&format!("scancel {job}")), "{stderr}");
}

/// `scancel` of a running array: the pending tasks never started, so they
/// use none of their attempts; mdpipe stops saying so, and run again it
/// submits them and every point ends with exactly the attempts it made.
#[test]
fn cancelled_pending_tasks_use_no_attempt() {
    if !slurm_answers() {
        crate::common::skip(
            "cancelled_pending_tasks_use_no_attempt",
            "no Slurm cluster answers here (as root: bash .ci/slurm-setup.sh)",
        );
        return;
    }
    let dir = tmpdir("slurm-cancel");
    let config = write_study(
        &dir,
        "FAIL= HANG= FLAKY= NAP=1",
        "time_limit = \"2m\"\nretries = 0\nparallel = 1\nslurm = { poll_seconds = 1.0 }",
    );
    let out = dir.join("out");
    assert!(run(&config, &out, &["--stage", "design"]).status.success());
    let child = mdpipe()
        .arg("run")
        .arg(&config)
        .args(["--seed", "5", "--out"])
        .arg(&out)
        .args(["--stage", "simulate", "--executor", "slurm"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let state = out.join("design/runs/.attempts/slurm.json");
    let start = Instant::now();
    while !state.exists() {
        assert!(start.elapsed() < Duration::from_secs(120), "no array submitted in 120 s");
        std::thread::sleep(Duration::from_millis(200));
    }
    std::thread::sleep(Duration::from_secs(2));
    let job = json(&state)["submissions"][0]["job_id"].as_str().unwrap().to_string();
    assert!(Command::new("scancel").arg(&job).status().unwrap().success());
    let o = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "mdpipe went on after the array was cancelled");
    assert!(stderr.contains("left the queue without starting"), "{stderr}");

    // Run again: with no retries allowed, every point that never started
    // still runs (without the nap, which only had to hold the array until
    // the scancel: the command and hence the points' keys are unchanged).
    std::fs::write(dir.join("marks/nap"), "0").unwrap();
    let o = run(&config, &out, &["--stage", "simulate", "--executor", "slurm"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = json(&out.join("design/runs/execution.json"));
    let failed = report["failed"].as_array().unwrap();
    // Tasks running at the scancel were killed: those count (at most one, parallel = 1).
    assert!(failed.len() <= 1, "more failures than tasks running at the scancel: {report:#}");
    assert_eq!(report["succeeded"].as_u64().unwrap() as usize + failed.len(), 16, "{report:#}");
}

/// Two configs that share a name, run from one folder into one output
/// folder: the second is told whose folder it is writing; run again, it is
/// not told twice.
#[test]
fn a_second_config_into_the_same_output_folder_is_told_whose_it_was() {
    let dir = std::env::temp_dir().join(format!("mdpipe-owner-it-{}", std::process::id()));
    let (a, b, out) = (dir.join("a"), dir.join("b"), dir.join("outputs/toy_study"));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let (config_a, config_b) = (write_study(&a, "NAP=0", ""), write_study(&b, "NAP=0", ""));
    let said = |o: &std::process::Output| String::from_utf8_lossy(&o.stderr).to_string();
    let first = run(&config_a, &out, &["--stage", "design"]);
    assert!(first.status.success(), "{}", said(&first));
    assert!(!said(&first).contains("last written by another config"), "{}", said(&first));
    let second = run(&config_b, &out, &["--stage", "design"]);
    assert!(second.status.success(), "{}", said(&second));
    let text = said(&second);
    assert!(text.contains("last written by another config") && text.contains("a/study.toml"), "{text}");
    let again = run(&config_b, &out, &["--stage", "design"]);
    assert!(!said(&again).contains("last written by another config"), "{}", said(&again));
    std::fs::remove_dir_all(&dir).unwrap();
}
