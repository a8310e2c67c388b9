//! Checkpoint and resume of SMC runs: a run stopped after every tempering step
//! and resumed each time ends with exactly the draws and evidence of an
//! uninterrupted run; a saved state from another run is never resumed; and
//! `mdpipe calibrate --time-limit` stops cleanly and resumes from the CLI.

use mdpipe::calibrate::sampler::checkpoint::Checkpointing;
use mdpipe::calibrate::sampler::smc::Smc;
use mdpipe::calibrate::{Overrides, Problem};
use mdpipe::progress::Silent;
use std::path::Path;
use std::time::Duration;

fn problem() -> Problem {
    let mut cfg =
        mdpipe::systems::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("pipeline/ball_drop.toml")).unwrap();
    cfg.sampler.smc.particles = 300;
    cfg.sampler.adapt = false;
    cfg.sampler.smc.replicates = 2;
    Problem::new(&cfg, &Overrides { kernel: Some(mdpipe::base::choices::Kernel::II), ..Default::default() }).unwrap()
}

/// A checkpoint that saves after every step and stops at once.
fn stop_every_step(dir: &Path, key: &str) -> Checkpointing {
    Checkpointing { min_interval: Duration::ZERO, ..Checkpointing::new(dir, key.into(), Some(Duration::ZERO)) }
}

#[test]
fn resumed_smc_equals_uninterrupted_smc_bit_for_bit() {
    let p = problem();
    let smc = Smc::new(p.analysis.sampler.smc.clone());
    let whole = smc.run(&p.prior, &p.likelihood, 5, &Silent).unwrap();
    let dir = std::env::temp_dir().join(format!("mdpipe-checkpoint-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut stops = 0;
    let resumed = loop {
        match smc.run_checkpointed(&p.prior, &p.likelihood, 5, &Silent, Some(&stop_every_step(&dir, "run-a"))) {
            Ok(out) => break out,
            Err(stopped) => {
                stops += 1;
                assert!(
                    stopped.dir.join("replicate_0.json").exists() || stopped.dir.join("replicate_0.done.json").exists()
                );
                assert!(stops < 500, "no progress across resumes");
            }
        }
    };
    // One stop per tempering step before β = 1 (the longer replicate's count).
    let steps = whole.replicates.iter().map(|r| r.steps.len() - 1).max().unwrap();
    assert_eq!(stops, steps, "stops vs tempering steps");
    assert_eq!(resumed.log_evidence.to_bits(), whole.log_evidence.to_bits());
    assert_eq!(resumed.log_evidence_err.to_bits(), whole.log_evidence_err.to_bits());
    for (a, b) in resumed.chains.chains.iter().zip(&whole.chains.chains) {
        assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "draws differ after resuming");
    }
    assert_eq!(resumed.likelihood_evaluations(), whole.likelihood_evaluations());

    // A state saved by another run (here: another key) is ignored, not resumed.
    let _ = std::fs::remove_dir_all(&dir);
    assert!(smc.run_checkpointed(&p.prior, &p.likelihood, 5, &Silent, Some(&stop_every_step(&dir, "run-a"))).is_err());
    let other = Checkpointing::new(&dir, "run-b".into(), None);
    let fresh = smc.run_checkpointed(&p.prior, &p.likelihood, 5, &Silent, Some(&other)).unwrap();
    assert_eq!(fresh.log_evidence.to_bits(), whole.log_evidence.to_bits());
    let _ = std::fs::remove_dir_all(&dir);
}

/// The ensemble sampler runs through the same driver: stopped after every
/// step and resumed each time, it ends with the draws of an uninterrupted run.
#[test]
fn resumed_ensemble_equals_uninterrupted_ensemble_bit_for_bit() {
    use mdpipe::calibrate::sampler::ensemble::{Ensemble, EnsembleSettings};
    let p = problem();
    let ensemble = Ensemble::new(EnsembleSettings { walkers: 16, steps: 30, burn: 10, thin: 1, stretch: 2.0 });
    let whole = ensemble.run(&p.prior, &p.likelihood, 9, &Silent);
    let dir = std::env::temp_dir().join(format!("mdpipe-checkpoint-ensemble-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut stops = 0;
    let resumed = loop {
        match ensemble.run_checkpointed(&p.prior, &p.likelihood, 9, &Silent, Some(&stop_every_step(&dir, "e"))) {
            Ok(out) => break out,
            Err(stopped) => {
                stops += 1;
                assert!(stopped.dir.join("ensemble.json").exists());
                assert!(stops < 100, "no progress across resumes");
            }
        }
    };
    assert_eq!(stops, 39, "one stop per step before the last");
    for (a, b) in resumed.chains.chains.iter().zip(&whole.chains.chains) {
        assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "draws differ after resuming");
    }
    assert_eq!(resumed.acceptance.to_bits(), whole.acceptance.to_bits());
    assert_eq!(resumed.likelihood_evaluations, whole.likelihood_evaluations);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn calibrate_time_limit_stops_and_the_same_command_resumes() {
    time_limit_stops_and_resumes(&[]);
}

#[test]
fn calibrate_ensemble_time_limit_stops_and_the_same_command_resumes() {
    time_limit_stops_and_resumes(&["--sampler", "ensemble"]);
}

/// `mdpipe calibrate --time-limit 0` (with `sampler`'s options) stops after
/// its first step with the state saved; the same command without the limit
/// resumes and ends with the draws of a run never stopped.
fn time_limit_stops_and_resumes(sampler: &[&str]) {
    let tag = sampler.last().unwrap_or(&"smc").to_string();
    let out = std::env::temp_dir().join(format!("mdpipe-time-limit-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let config_dir = out.with_extension("config");
    std::fs::create_dir_all(&config_dir).unwrap();
    let config = crate::common::small_ball_drop(&config_dir);
    let cmd = |extra: &[&str], dir: &Path| {
        let c = config.display().to_string();
        let mut args = vec!["calibrate", c.as_str(), "--kernel", "II", "--seed", "4", "--out"];
        let d = dir.display().to_string();
        args.push(&d);
        args.extend_from_slice(sampler);
        args.extend_from_slice(extra);
        std::process::Command::new(env!("CARGO_BIN_EXE_mdpipe")).args(&args).output().unwrap()
    };
    let stopped = cmd(&["--time-limit", "0"], &out);
    assert!(!stopped.status.success());
    assert!(
        String::from_utf8_lossy(&stopped.stderr).contains("stopped at the time limit"),
        "{}",
        String::from_utf8_lossy(&stopped.stderr)
    );
    assert!(out.join(".checkpoint").exists() && !out.join("summary.json").exists());
    let resumed = cmd(&[], &out);
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    assert!(!out.join(".checkpoint").exists(), "the checkpoint outlived the finished run");
    // Same draws as a run that was never stopped.
    let plain_dir = out.with_extension("plain");
    assert!(cmd(&[], &plain_dir).status.success());
    let read = |d: &Path| mdpipe::artifacts::read_parquet(&d.join("posterior.parquet")).unwrap();
    let (a, b) = (read(&out), read(&plain_dir));
    assert_eq!(a.get_column_names(), b.get_column_names());
    for name in a.get_column_names() {
        let (ca, cb) =
            (a.column(name.as_str()).unwrap().f64().unwrap(), b.column(name.as_str()).unwrap().f64().unwrap());
        assert!(
            ca.iter().zip(cb.iter()).all(|(x, y)| x == y),
            "resumed posterior differs from an uninterrupted one in {name}"
        );
    }
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&plain_dir);
    let _ = std::fs::remove_dir_all(out.with_extension("config"));
}

/// A fit written to disk reads back as the same calibration, bit for bit, and
/// is found for its own problem only: not for the same data with another
/// kernel, nor for the same problem after its model changed.
#[test]
fn a_stored_fit_reads_back_whole_and_is_found_only_for_its_own_problem() {
    use mdpipe::calibrate::results::stored;
    let p = problem();
    let fit = mdpipe::calibrate::run(&p, 11, &Silent).unwrap();
    let dir = std::env::temp_dir().join(format!("mdpipe-stored-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    mdpipe::calibrate::write_outputs(&dir, &p, &fit).unwrap();
    let (found, back) = stored::find(std::slice::from_ref(&dir), &p).expect("its own problem");
    assert_eq!(found, dir);
    assert_eq!(back.chains.chains, fit.chains.chains);
    assert_eq!(back.predictions, fit.predictions);
    assert_eq!(serde_json::to_string(&back.summary).unwrap(), serde_json::to_string(&fit.summary).unwrap());
    let mut cfg =
        mdpipe::systems::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("pipeline/ball_drop.toml")).unwrap();
    cfg.sampler.smc.particles = 300;
    cfg.sampler.adapt = false;
    cfg.sampler.smc.replicates = 2;
    let kernel_i =
        Problem::new(&cfg, &Overrides { kernel: Some(mdpipe::base::choices::Kernel::I), ..Default::default() });
    assert!(stored::find(std::slice::from_ref(&dir), &kernel_i.unwrap()).is_none());
    // Another model under the same config: only its answers tell it apart.
    let mut other = problem();
    assert_eq!(stored::problem_key(&other), stored::problem_key(&p));
    other.simulator =
        std::sync::Arc::new(crate::common::Perturbed { inner: other.simulator.clone(), change: |v| v + 1e-12 });
    assert!(stored::find(std::slice::from_ref(&dir), &other).is_none());
    // A stored fit whose draws were removed since is passed over, not an error.
    std::fs::remove_file(dir.join("posterior.parquet")).unwrap();
    assert!(stored::find(std::slice::from_ref(&dir), &p).is_none());
    let _ = std::fs::remove_dir_all(&dir);
}
