//! The calibrate stage: every observable set × kernel as one case
//! (`pipeline::cases`), each stamped on its own so an interrupted stage
//! resumes case by case; then a system that made the data assesses the
//! calibrations against its truth (the stand-in: study.json, study.md) or,
//! without a truth, each case's parameters and evidence are tabled
//! (calibrate/cases.json, cases.md).

use super::{Keys, StageDef};
use crate::base::artifacts::{self, Provenance};
use crate::engine::execute::Executor;
use crate::pipeline::setup;
use crate::pipeline::study::Study;
use anyhow::{anyhow, Result};
use std::path::PathBuf;

pub(super) const STAGE: StageDef = StageDef {
    name: "calibrate",
    rank: 70,
    upstream: &["emulator", "mock", "refine"],
    present: super::always,
    outputs,
    settings,
    body: calibrate,
};

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    Ok(vec![setup::first(|s| s.assessment(study)).unwrap_or_else(|| study.paths.calibrate().join("cases.json"))])
}

fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    let run = study.run;
    Ok(
        serde_json::json!({"config": study.analysis_hash()?, "data": study.data_hash()?, "sets": run.observable_sets, "kernels": run.kernels, "seed": study.opts.seed}),
    )
}

fn calibrate(study: &Study<'_>, keys: &Keys<'_>) -> Result<()> {
    let config = study.study_config()?;
    let analysis = study.analysis(&config)?;
    let cases = study.cases(keys)?;
    if let Some(index) = study.opts.case {
        // One array task: this case only; the stage is assessed and stamped by the mdpipe that submitted it.
        let c = cases
            .get(index)
            .ok_or_else(|| anyhow!("--case {index}: the study has {} calibration cases", cases.len()))?;
        return if study.case_done(c) { Ok(()) } else { study.calibrate_case(&analysis, c) };
    }
    if study.opts.executor == Executor::Slurm {
        study.calibrate_as_array(&cases)?;
    }
    let mut dirs = Vec::new();
    for c in &cases {
        if study.case_done(c) {
            crate::base::messages::say!("  {:<60} done earlier, kept", c.name);
        } else {
            study.calibrate_case(&analysis, c)?;
        }
        dirs.push(c.dir.clone());
    }
    match setup::systems().into_iter().find(|s| s.assessment(study).is_some()) {
        Some(system) => system.assess(study, &config, &dirs),
        None => study.write_cases(&dirs),
    }
}

impl Study<'_> {
    /// Without mock data there is no truth to assess: each case's parameters
    /// and evidence, as `calibrate/cases.json` and `cases.md`.
    pub(super) fn write_cases(&self, dirs: &[PathBuf]) -> Result<()> {
        let mut cases = Vec::new();
        let mut md = String::from(
            "| case | parameter | median | 95% interval | log evidence | converged |\n|---|---|---|---|---|---|\n",
        );
        for dir in dirs {
            let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json"))?)?;
            let case = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            for name in self.config.parameters.keys() {
                let p = &summary["parameters"][name];
                md.push_str(&format!(
                    "| {case} | {name} | {:.4} | [{:.4}, {:.4}] | {:.2} | {} |\n",
                    p["median"].as_f64().unwrap_or(f64::NAN),
                    p["q025"].as_f64().unwrap_or(f64::NAN),
                    p["q975"].as_f64().unwrap_or(f64::NAN),
                    summary["log_evidence"].as_f64().unwrap_or(f64::NAN),
                    summary["diagnostics"]["converged"]
                ));
            }
            cases.push(serde_json::json!({"case": case, "parameters": summary["parameters"], "log_evidence": summary["log_evidence"], "converged": summary["diagnostics"]["converged"]}));
        }
        let prov = Provenance::new(
            self.config.hash.clone(),
            self.data_hash()?,
            self.opts.seed,
            &format!("run {} --stage calibrate", self.config.path.display()),
        );
        let mut staged = artifacts::StagedWrites::new();
        staged.json(
            &self.paths.calibrate().join("cases.json"),
            &serde_json::json!({"cases": cases, "provenance": prov}),
        )?;
        staged.text(&self.paths.calibrate().join("cases.md"), &md)?;
        staged.commit()?;
        crate::base::messages::say!("{md}");
        Ok(())
    }
}
