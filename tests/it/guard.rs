//! Runs that cannot work stop at once with an error that says what to do,
//! instead of running at full CPU with no output (issue: "never hang").

use mdpipe::calibrate::sampler::smc::{Smc, SmcSettings};
use mdpipe::calibrate::{LogLikelihood, UniformPrior};
use mdpipe::progress::Silent;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn tmp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mdpipe-guard-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The bundled ball-drop config and data with every time shifted by `shift`
/// seconds, 500 particles per replicate, and `extra` appended to the config.
/// The bundled ball drop's config without its `[discrepancy] inputs` line
/// (the paper's convention, x itself), so a test can give its own table.
pub fn without_bundled_inputs(text: &str) -> String {
    text.lines().filter(|l| !l.starts_with("inputs = ")).collect::<Vec<_>>().join("\n")
}

fn shifted_ball_drop(dir: &Path, shift: f64, extra: &str) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let data = mdpipe::artifacts::read_measurements(&root.join("pipeline/ball_drop_data.csv")).unwrap();
    let shifted: Vec<_> = data
        .into_iter()
        .map(|m| mdpipe::artifacts::Measurement::new(&m.observable, m.x + shift, m.value, m.error))
        .collect();
    mdpipe::artifacts::write_measurements(&dir.join("data.csv"), &shifted, None).unwrap();
    // The ODE starts where the shifted data do.
    let text = std::fs::read_to_string(root.join("pipeline/ball_drop.toml"))
        .unwrap()
        .replace("ball_drop_data.csv", "data.csv")
        .replace("particles = 2000", "particles = 500")
        .replace("kind = \"smc\"", "kind = \"smc\"\nadapt = false")
        .replace("t0 = 0.0", &format!("t0 = {shift:?}"));
    let text = without_bundled_inputs(&text);
    let cfg = dir.join("shifted.toml");
    std::fs::write(&cfg, format!("{text}\n{extra}")).unwrap();
    cfg
}

fn calibrate(cfg: &Path, out: &Path) -> (std::process::Output, Duration) {
    let start = Instant::now();
    let args = ["calibrate", cfg.to_str().unwrap(), "--kernel", "II", "--out", out.to_str().unwrap()];
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_mdpipe")).args(args).output().unwrap();
    (output, start.elapsed())
}

#[test]
fn negative_kernel_inputs_stop_at_once_and_a_shift_fixes_them() {
    let dir = tmp("shift");
    // Times from −0.5 s: the (x·x')^r factor is NaN below zero everywhere.
    let cfg = shifted_ball_drop(&dir, -0.5, "");
    let (out, took) = calibrate(&cfg, &dir.join("bad"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && took < Duration::from_secs(30), "took {took:?}: {stderr}");
    assert!(
        stderr.contains("x ≥ 0") && stderr.contains("[discrepancy.inputs.height]") && stderr.contains("shift = 0.5"),
        "{stderr}"
    );
    assert!(!dir.join("bad/summary.json").exists(), "an artifact was written for a refused run");

    // With the shift the message suggests, the kernel sees t again: it runs.
    let fixed = shifted_ball_drop(
        &dir,
        -0.5,
        "[discrepancy.inputs]\nheight = { shift = 0.5 }\nvelocity = { shift = 0.5 }\nacceleration = { shift = 0.5 }\n",
    );
    let (out, _) = calibrate(&fixed, &dir.join("good"));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("good/summary.json")).unwrap()).unwrap();
    assert!(summary["log_evidence"].as_f64().unwrap().is_finite());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn impossible_settings_are_refused_naming_file_and_field() {
    let dir = tmp("settings");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = without_bundled_inputs(&std::fs::read_to_string(root.join("pipeline/ball_drop.toml")).unwrap());
    let cases = [
        (text.replace("replicates = 4", "replicates = 4\ness_fraction = 1.0"), "smc.ess_fraction"),
        (text.replace("replicates = 4", "replicates = 0"), "smc.replicates"),
        (text.replace("points = 41", "points = 1"), "[predictions]"),
        (format!("{text}\n[discrepancy.inputs]\nheight = {{ scale = 0.0 }}\n"), "[discrepancy.inputs.height]"),
        (format!("{text}\n[discrepancy.inputs]\nspeed = {{ shift = 1.0 }}\n"), "[discrepancy.inputs.speed]"),
    ];
    for (k, (config, field)) in cases.iter().enumerate() {
        let p = dir.join(format!("case{k}.toml"));
        std::fs::write(
            &p,
            config.replace("ball_drop_data.csv", &root.join("pipeline/ball_drop_data.csv").display().to_string()),
        )
        .unwrap();
        let msg =
            format!("{:#}", mdpipe::systems::load(&p).err().unwrap_or_else(|| panic!("case {k} ({field}) accepted")));
        assert!(msg.contains(&format!("case{k}.toml")) && msg.contains(field), "case {k}: {msg}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A likelihood that is −∞ everywhere: tempering cannot weigh the particles.
struct Nowhere;

impl LogLikelihood for Nowhere {
    fn log_likelihood(&self, _x: &[f64]) -> f64 {
        f64::NEG_INFINITY
    }
}

#[test]
fn smc_on_a_likelihood_that_is_nowhere_finite_stops_with_an_error() {
    let prior = UniformPrior::new(vec!["a".into(), "b".into()], vec![0.0, 0.0], vec![1.0, 1.0]).unwrap();
    // Its own threads: in the shared pool another test's long parallel work
    // can hold every thread, and the time measured would be the wait.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let start = Instant::now();
    let err = pool
        .install(|| {
            Smc::new(SmcSettings { particles: 200, replicates: 2, ..Default::default() })
                .run(&prior, &Nowhere, 1, &Silent)
        })
        .expect_err("a run on an impossible likelihood succeeded");
    assert!(start.elapsed() < Duration::from_secs(30));
    assert!(err.to_string().contains("no particle has a finite likelihood"), "{err}");
    // Typed, for a caller that acts on it rather than prints it.
    assert!(
        matches!(err.cause, Some(mdpipe::calibrate::sampler::algorithm::SamplerError::NoFiniteLikelihood { beta }) if beta == 0.0),
        "{err:?}"
    );
}
