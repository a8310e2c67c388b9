//! The calibration cases of the calibrate stage: every observable set ×
//! kernel as one case, stamped on its own so an interrupted stage resumes
//! case by case, and run here or as a Slurm array.

use super::stage::{read_stamp, Keys, Stamp};
use super::study::{absolute, Study};
use crate::base::artifacts::{self, Provenance};
use crate::base::progress::observer;
use crate::engine::calibrate::{self, Analysis, Overrides, Problem};
use crate::engine::compare;
use crate::engine::execute::{self, Executor, OutputKind, SimulatorSpec};
use crate::engine::gp::DiscrepancyKernel;
use anyhow::Result;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// One calibration case of the calibrate stage.
pub(in crate::pipeline) struct Case {
    index: usize,
    pub(in crate::pipeline) name: String,
    set: Vec<String>,
    kernel: Option<DiscrepancyKernel>,
    pub(in crate::pipeline) dir: PathBuf,
    seed: u64,
    key: String,
    stamp: PathBuf,
}

impl Study<'_> {
    /// The calibration cases: every observable set × kernel, with its seed and key.
    pub(in crate::pipeline) fn cases(&self, keys: &Keys) -> Result<Vec<Case>> {
        let mut cases = Vec::new();
        for (i, set) in self.run.observable_sets.iter().enumerate() {
            for (j, k) in self.run.kernels.iter().enumerate() {
                let kernel = DiscrepancyKernel::of(*k);
                let name = compare::case_dir_name(set, kernel);
                let seed = self.opts.seed.wrapping_add((i * 3 + j) as u64 * 1_000_003);
                let material = serde_json::json!({"config": self.analysis_hash()?, "data": self.data_hash()?, "set": set, "kernel": k, "seed": seed, "emulator": keys.upstream.get("emulator"), "mock": keys.upstream.get("mock"), "refine": keys.upstream.get("refine")});
                let key = artifacts::sha256_hex(material.to_string().as_bytes());
                cases.push(Case {
                    index: cases.len(),
                    dir: self.paths.calibrate().join(&name),
                    stamp: self.paths.stamp(&format!("calibrate/{name}")),
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
    pub(in crate::pipeline) fn case_done(&self, c: &Case) -> bool {
        !self.opts.force && read_stamp(&c.stamp).is_some_and(|s| s.key == c.key) && c.dir.join("summary.json").exists()
    }

    pub(in crate::pipeline) fn calibrate_case(&self, analysis: &Analysis, c: &Case) -> Result<()> {
        let ov = Overrides { kernel: Some(c.kernel), observables: Some(c.set.clone()), ..Default::default() };
        let problem = Problem::new(analysis, &ov)?;
        // Killed mid-case, the case resumes from its last saved tempering step.
        let checkpoint = calibrate::checkpoint::Checkpointing::new(
            &c.dir.join(".checkpoint"),
            calibrate::checkpoint_key(&problem, c.seed),
            None,
        );
        // The last refinement round fitted the same problem with the same emulator.
        let (cal, whence) = match calibrate::stored::find(&self.stored_fits(&self.refine_dir()), &problem) {
            Some((dir, cal)) => {
                calibrate::write_outputs(&c.dir, &problem, &cal)?;
                checkpoint.clear();
                (cal, format!(" when sampled in {}, the same problem; taken from there", dir.display()))
            }
            None => (
                calibrate::run_and_write(&problem, c.seed, observer(self.opts.show_progress), &checkpoint, &c.dir)?,
                String::new(),
            ),
        };
        let seconds = cal.summary.diagnostics.wall_seconds;
        let prov = Provenance::new(
            self.config.hash.clone(),
            String::new(),
            c.seed,
            &format!("run {} --stage calibrate ({})", self.config.path.display(), c.name),
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
    pub(in crate::pipeline) fn calibrate_as_array(&self, cases: &[Case]) -> Result<()> {
        let todo: Vec<&Case> = cases.iter().filter(|c| !self.case_done(c)).collect();
        if todo.is_empty() {
            return Ok(());
        }
        let out = absolute(&self.paths.out);
        let command = format!(
            "{{mdpipe}} run {} --out {} --seed {} --stage calibrate --case {{id}}",
            execute::spec::shell_quote(&absolute(&self.config.path).display().to_string()),
            execute::spec::shell_quote(&out.display().to_string()),
            self.opts.seed
        );
        let template = self.run.simulator.clone();
        let spec = SimulatorSpec {
            command,
            placeholders: BTreeMap::new(),
            output: OutputKind::Exit,
            time_limit: self.run.calibration_time_limit.clone(),
            retries: template.as_ref().map_or(1, |t| t.retries),
            parallel: None,
            slurm: template.map(|t| t.slurm).unwrap_or_default(),
        };
        let runs = self.paths.calibrate().join(".array");
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
            mdpipe: self.opts.mdpipe.clone(),
            seed: 0,
        };
        std::fs::create_dir_all(&runs)?;
        match execute::run(&job, Executor::Slurm, self.opts.show_progress) {
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
}
