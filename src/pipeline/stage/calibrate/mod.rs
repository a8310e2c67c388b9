//! The calibrate stage: every observable set × kernel as one case
//! (`cases`), each stamped on its own so an interrupted stage
//! resumes case by case; then a system that made the data assesses the
//! calibrations against its truth (its own study.json, study.md) or,
//! without a truth, each case's parameters and evidence are tabled
//! (calibrate/cases.json, cases.md).

mod cases;

use super::{Keys, Stage, StageId};
use crate::base::artifacts::{self, Provenance};
use crate::base::choices::Kernel;
use crate::engine::execute::Executor;
use crate::pipeline::study::Study;
use anyhow::{anyhow, Result};
use std::path::PathBuf;

pub(crate) struct Calibrate;

#[derive(serde::Serialize)]
pub(crate) struct Settings {
    config: String,
    data: String,
    sets: Vec<Vec<String>>,
    kernels: Vec<Kernel>,
    seed: u64,
}

impl Stage for Calibrate {
    type Settings = Settings;
    const ID: StageId = StageId::CALIBRATE;
    const UPSTREAM: &'static [StageId] = &[StageId::EMULATOR, StageId::REFINE];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        let assessment = study.systems.iter().find_map(|s| s.assessment(study));
        Ok(vec![assessment.unwrap_or_else(|| study.paths.calibrate().join("cases.json"))])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        let run = study.run;
        Ok(Settings {
            config: study.analysis_hash()?,
            data: study.data_hash()?,
            sets: run.observable_sets.clone(),
            kernels: run.kernels.clone(),
            seed: study.opts.seed,
        })
    }
    fn run(&self, study: &Study<'_>, keys: &Keys<'_>) -> Result<()> {
        let config = study.study_config()?;
        let analysis = study.analysis(&config)?;
        let cases = cases::cases(study, keys)?;
        if let Some(index) = study.opts.case {
            // One array task: this case only; the stage is assessed and stamped by the mdpipe that submitted it.
            let c = cases
                .get(index)
                .ok_or_else(|| anyhow!("--case {index}: the study has {} calibration cases", cases.len()))?;
            return if cases::case_done(study, c) { Ok(()) } else { cases::calibrate_case(study, &analysis, c) };
        }
        if study.opts.executor == Executor::Slurm {
            cases::calibrate_as_array(study, &cases)?;
        }
        let mut dirs = Vec::new();
        for c in &cases {
            if cases::case_done(study, c) {
                crate::base::messages::say!("  {:<60} done earlier, kept", c.name);
            } else {
                cases::calibrate_case(study, &analysis, c)?;
            }
            dirs.push(c.dir.clone());
        }
        match study.systems.iter().find(|s| s.assessment(study).is_some()) {
            Some(system) => system.assess(study, &config, &dirs),
            None => write_cases(study, &dirs),
        }
    }
}

/// Without mock data there is no truth to assess: each case's parameters
/// and evidence, as `calibrate/cases.json` and `cases.md`.
fn write_cases(study: &Study<'_>, dirs: &[PathBuf]) -> Result<()> {
    let mut cases = Vec::new();
    let mut md = String::from(
        "| case | parameter | median | 95% interval | log evidence | converged |\n|---|---|---|---|---|---|\n",
    );
    for dir in dirs {
        let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json"))?)?;
        let case = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        for name in study.config.parameters.keys() {
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
        study.config.hash.clone(),
        study.data_hash()?,
        study.opts.seed,
        &format!("run {} --stage calibrate", study.config.path.display()),
    );
    let mut staged = artifacts::StagedWrites::new();
    staged
        .json(&study.paths.calibrate().join("cases.json"), &serde_json::json!({"cases": cases, "provenance": prov}))?;
    staged.text(&study.paths.calibrate().join("cases.md"), &md)?;
    staged.commit()?;
    crate::base::messages::say!("{md}");
    Ok(())
}
