//! The calibration cases of the calibrate stage: every observable set ×
//! kernel as one case, stamped on its own so an interrupted stage resumes
//! case by case, and run here or as a Slurm array.

use crate::base::artifacts::{self, Provenance};
use crate::base::progress::observer;
use crate::engine::calibrate::{self, Analysis, Overrides, Problem};
use crate::engine::compare;
use crate::engine::execute::{self, Executor, OutputKind, SimulatorSpec};
use crate::engine::gp::DiscrepancyKernel;
use crate::pipeline::stage::{read_stamp, Keys, Stamp};
use crate::pipeline::study::{absolute, Study};
use anyhow::Result;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// One calibration case of the calibrate stage.
pub(super) struct Case {
    index: usize,
    pub(super) name: String,
    set: Vec<String>,
    kernel: Option<DiscrepancyKernel>,
    pub(super) dir: PathBuf,
    seed: u64,
    key: String,
    stamp: PathBuf,
}

/// The calibration cases: every observable set × kernel, with its seed and key.
pub(super) fn cases(study: &Study<'_>, keys: &Keys) -> Result<Vec<Case>> {
    let mut cases = Vec::new();
    for (i, set) in study.run.observable_sets.iter().enumerate() {
        for (j, k) in study.run.kernels.iter().enumerate() {
            let kernel = DiscrepancyKernel::of(*k);
            let name = compare::case_dir_name(set, kernel);
            let seed = study.opts.seed.wrapping_add((i * 3 + j) as u64 * 1_000_003);
            let material = serde_json::json!({"config": study.analysis_hash()?, "data": study.data_hash()?, "set": set, "kernel": k, "seed": seed, "reads": keys.reads});
            let key = artifacts::sha256_hex(material.to_string().as_bytes());
            cases.push(Case {
                index: cases.len(),
                dir: study.paths.calibrate().join(&name),
                stamp: study.paths.stamp(&format!("calibrate/{name}")),
                name,
                set: set.clone(),
                kernel,
                seed,
                key,
            });
        }
    }
    Ok(cases)
}

/// Whether a case finished earlier with the same key (so an interrupted stage resumes case by case).
pub(super) fn case_done(study: &Study<'_>, c: &Case) -> bool {
    !study.opts.force && read_stamp(&c.stamp).is_some_and(|s| s.key == c.key) && c.dir.join("summary.json").exists()
}

pub(super) fn calibrate_case(study: &Study<'_>, analysis: &Analysis, c: &Case) -> Result<()> {
    let ov = Overrides {
        kernel: Some(DiscrepancyKernel::choice(c.kernel)),
        observables: Some(c.set.clone()),
        ..Default::default()
    };
    let problem = Problem::new(analysis, &ov)?;
    // Killed mid-case, the case resumes from its last saved tempering step.
    let checkpoint = calibrate::sampler::checkpoint::Checkpointing::new(
        &c.dir.join(".checkpoint"),
        calibrate::checkpoint_key(&problem, c.seed),
        None,
    );
    // The last refinement round fitted the same problem with the same emulator.
    let (cal, whence) = match calibrate::results::stored::find(
        &study.stored_fits(&crate::pipeline::stage::refine::report::refine_dir(study)),
        &problem,
    ) {
        Some((dir, cal)) => {
            calibrate::write_outputs(&c.dir, &problem, &cal)?;
            checkpoint.clear();
            (cal, format!(" when sampled in {}, the same problem; taken from there", dir.display()))
        }
        None => (
            calibrate::run_and_write(&problem, c.seed, observer(study.opts.show_progress), &checkpoint, &c.dir)?,
            String::new(),
        ),
    };
    let seconds = cal.summary.diagnostics.wall_seconds;
    let prov = Provenance::new(
        study.config.hash.clone(),
        String::new(),
        c.seed,
        &format!("run {} --stage calibrate ({})", study.config.path.display(), c.name),
    );
    artifacts::write_json_atomic(
        &c.stamp,
        &Stamp {
            stage: format!("calibrate/{}", c.name),
            key: c.key.clone(),
            output_key: String::new(),
            seconds,
            provenance: prov,
        },
    )?;
    crate::base::messages::say!("  {:<60} {seconds:>6.1} s{whence}", c.name);
    Ok(())
}

/// Under `--executor slurm`, the cases not yet done go out as one job
/// array, each task `mdpipe run … --stage calibrate --case <index>`; a case
/// whose task failed is then calibrated here, with the others kept.
pub(super) fn calibrate_as_array(study: &Study<'_>, cases: &[Case]) -> Result<()> {
    let todo: Vec<&Case> = cases.iter().filter(|c| !case_done(study, c)).collect();
    if todo.is_empty() {
        return Ok(());
    }
    let out = absolute(&study.paths.out);
    let command = format!(
        "{{mdpipe}} run {} --out {} --seed {} --stage calibrate --case {{id}}",
        execute::spec::shell_quote(&absolute(&study.config.path).display().to_string()),
        execute::spec::shell_quote(&out.display().to_string()),
        study.opts.seed
    );
    let template = study.run.simulator.clone();
    let spec = SimulatorSpec {
        command,
        placeholders: BTreeMap::new(),
        output: OutputKind::Exit,
        time_limit: study.run.calibration_time_limit.clone(),
        retries: template.as_ref().map_or(1, |t| t.retries),
        parallel: None,
        slurm: template.map(|t| t.slurm).unwrap_or_default(),
    };
    let runs = study.paths.calibrate().join(".array");
    let points = todo
        .iter()
        .map(|c| execute::Point { id: c.index as i64, values: BTreeMap::new(), param_file: runs.join("none") })
        .collect();
    let job = execute::Job {
        spec: &spec,
        workdir: out.clone(),
        design: runs.join("none"),
        runs: runs.clone(),
        points,
        label: "calibrations".into(),
        mdpipe: study.opts.mdpipe.clone(),
        seed: 0,
    };
    std::fs::create_dir_all(&runs)?;
    match execute::run(&job, Executor::Slurm, study.opts.show_progress) {
        Ok(report) if report.failed.is_empty() => {}
        Ok(report) => {
            report.print_failures();
            crate::base::messages::say!(
                "  warning: {} calibration task(s) failed under Slurm; those cases run here",
                report.failed.len()
            );
        }
        Err(e) => crate::base::messages::say!("  warning: {e:#}; the cases run here"),
    }
    Ok(())
}
