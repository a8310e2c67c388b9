//! The simulate stage: the simulator run at every point of both designs
//! through `engine::execute`, locally or as a Slurm array.

use super::{always, read_stamp, Keys, StageDef};
use crate::engine::execute::{self, SimulatorSpec};
use crate::pipeline::study::Study;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

pub(super) const STAGE: StageDef =
    StageDef { name: "simulate", rank: 20, upstream: &["design"], present: always, outputs, settings, body: simulate };

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    Ok(vec![study.paths.design().join("runs"), study.paths.validation_design().join("runs")])
}

fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    let run = study.run;
    Ok(
        serde_json::json!({"simulator": serde_json::to_value(&run.simulator)?, "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f, "seed": study.opts.seed}),
    )
}

fn simulate(study: &Study<'_>, keys: &Keys<'_>) -> Result<()> {
    // Settings changed since the last run: its runs are not these. Forced
    // with the same settings, finished points are kept and only the
    // failed ones run again, with fresh attempts.
    let previous = read_stamp(&study.paths.stamp("simulate"));
    let stale = previous.as_ref().is_some_and(|s| s.key != keys.this);
    let forced = previous.is_some() && !stale;
    for (dir, label) in [(study.paths.design(), "design"), (study.paths.validation_design(), "validation design")] {
        let runs = dir.join("runs");
        if stale {
            execute::attempt::remove_after_attempts(&runs)
                .with_context(|| format!("removing outdated runs {}", runs.display()))?;
        }
        let attempts = runs.join(".attempts");
        if forced {
            execute::attempt::remove_after_attempts(&attempts)
                .with_context(|| format!("removing the previous attempts {}", attempts.display()))?;
        }
        let simulator = study.simulator(label == "validation design")?;
        study.run_design(&dir, &simulator, label)?;
    }
    Ok(())
}

impl Study<'_> {
    /// Runs `simulator` at every point of the design in `dir` that has no run
    /// yet (an earlier attempt's or the design's Slurm array's are kept),
    /// through the run's executor; failed points are listed and left out.
    pub(in crate::pipeline) fn run_design(
        &self,
        dir: &Path,
        simulator: &SimulatorSpec,
        label: &str,
    ) -> Result<execute::ExecutionReport> {
        let runs = dir.join("runs");
        std::fs::create_dir_all(&runs)?;
        std::fs::copy(dir.join("design.parquet"), runs.join("design.parquet"))?;
        let design = dir.join("design.parquet");
        let rows = crate::engine::design::read_points(&design)?;
        let ids: Vec<i64> = rows.iter().map(|(id, _)| *id).collect();
        let span = crate::engine::design::span_of(&ids);
        let points = rows
            .into_iter()
            .map(|(id, values)| execute::Point {
                id,
                param_file: crate::engine::design::parameter_file(dir, id, span),
                values,
            })
            .collect();
        let job = execute::Job {
            spec: simulator,
            workdir: dir.to_path_buf(),
            design,
            runs: runs.clone(),
            points,
            label: label.into(),
            mdpipe: self.opts.mdpipe.clone(),
            seed: self.point_seeds(label),
        };
        let report = execute::run(&job, self.opts.executor, self.opts.show_progress)?;
        crate::base::messages::say!(
            "  {}: {} points ({} had their run, {} ran, {} after a retry, {} failed) in {:.1} s",
            runs.display(),
            report.points,
            report.already_done,
            report.succeeded - report.already_done,
            report.retried.len(),
            report.failed.len(),
            report.seconds
        );
        if !report.failed.is_empty() {
            report.print_failures();
            let ids: Vec<i64> = report.failed.iter().map(|f| f.id).collect();
            if ids.len() == report.points {
                bail!(
                    "every one of the {} points of the {label} failed; see {}",
                    ids.len(),
                    execute::ExecutionReport::path(&runs).display()
                );
            }
            crate::base::messages::say!(
                "  warning: {} of {} points of the {label} failed and are left out (never averaged in): {ids:?}; see {}",
                ids.len(),
                report.points,
                execute::ExecutionReport::path(&runs).display()
            );
        }
        Ok(report)
    }
}
