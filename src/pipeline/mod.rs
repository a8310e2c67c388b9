//! `mdpipe run`: a study end to end for any simulator, as a sequence of
//! stages that each write their artifacts under one output folder and are
//! skipped when their inputs have not changed. The simulate stage runs
//! `[run.simulator]` (or, without it, the heavy-ion stand-in as one instance
//! of a simulator) through `engine::execute`, locally or as a Slurm array.
//! The calibrations use the config's measurements, or the stand-in's mock
//! data (`mock_delta_f`), whose truth is known and assessed in study.md.
//!
//! | stage       | writes (under OUT/)                                             |
//! |-------------|-----------------------------------------------------------------|
//! | design      | design/, validation_design/ (design.parquet, parameter files, submit.slurm) |
//! | simulate    | design/runs/, validation_design/runs/ (one folder per point, execution.json) |
//! | ingest      | training.parquet, validation.parquet (+ .report.json)           |
//! | emulator    | emulator/ (trained, then validated: validation.json)            |
//! | mock        | mock/runs/, mock/measurements.parquet (the stand-in's mock data only) |
//! | refine      | refine/round_<r>/ (pilots, design with runs, tables, emulator), refine/rounds.json, rounds.md (only with `[run.refine]`; the stages after it use its emulator) |
//! | calibrate   | calibrate/<observables>__<kernel>/ per case, study.md, study.json (or calibrate/cases.md, cases.json) |
//! | report      | report.html                                                     |
//! | candidates  | candidates/<name>/ (design, runs, training.parquet, emulator with its cross-validation) per candidate |
//! | diagnose    | diagnose/ (diagnosis.json, report.html and every calibration; refine/<candidate>/ and refine/diagnosis_before.json when variants were refined) |
//!
//! The last two run when the study declares candidates: `[[candidates]]`
//! tables that say how the simulator turns each piece of physics on
//! (`variants`), or the stand-in's library names in `[run] candidates`.
//! A stage's key hashes its settings (`settings_of`, below) and its upstream
//! stages' keys (the simulate stage's, and so ingest's, also the run folders'
//! contents); a stage whose stamp (`OUT/stages/<stage>.json`) holds the same
//! key, and whose outputs exist, is skipped. Within the calibrate stage each
//! case is stamped too (`OUT/stages/calibrate/<case>.json`), so an
//! interrupted stage resumes with the cases it had not finished. A new stage
//! is a name in `STAGES`, an entry in `plan`, its settings in `settings_of`
//! (all in this file) and its body, a `Study` method that reads the study
//! and writes only its outputs; `stages::StageLoop` owns the keys and stamps.

mod cases;
mod complete;
mod diagnose;
mod refine_rounds;
mod run_config;
mod runs;
mod stages;
mod stand_in;
mod variant_refine;
mod variants;

use crate::base::artifacts::{self};
use crate::base::config::Config;
use crate::engine::emulator::EmulatorSettings;
use crate::engine::execute::{self};
use anyhow::{anyhow, bail, Context, Result};
pub use complete::{fill_in_from_study, load, study_out};
pub use refine_rounds::Rounds;
pub use run_config::{RefineConfig, RunConfig};
use stages::*;
pub use stages::{RunOptions, RunPaths, StageOutcome};
use std::path::PathBuf;

/// Every stage a study may have, in order (`--stage` takes these names).
pub const STAGES: [&str; 10] =
    ["design", "simulate", "ingest", "emulator", "mock", "refine", "calibrate", "report", "candidates", "diagnose"];

/// Runs the study (or one stage of it). Returns what ran and what was skipped.
pub fn run(config: &Config, opts: &RunOptions) -> Result<Vec<StageOutcome>> {
    let table = config.run.as_ref().ok_or_else(|| {
        anyhow!(
            "{}: no [run] table; `mdpipe run` needs one (see pipeline/heavy_ion_2param.toml)",
            config.path.display()
        )
    })?;
    let run: &RunConfig = &RunConfig::of(config, table)?;
    if let Some(s) = &opts.stage {
        if !STAGES.contains(&s.as_str()) {
            bail!("--stage {s}: unknown stage (use one of {})", STAGES.join(", "));
        }
    }
    let spec = crate::engine::design::DesignSpec::load(&config.resolve(&run.design))?;
    let design_parameters: Vec<String> = spec.parameters.iter().map(|p| p.name.clone()).collect();
    if opts.case.is_some() && opts.stage.as_deref() != Some("calibrate") {
        bail!("--case needs --stage calibrate");
    }
    execute::spec::seconds_of(&run.calibration_time_limit).context("[run] calibration_time_limit")?;
    run.validate(&design_parameters).with_context(|| format!("{}: [run]", config.path.display()))?;
    variants::check_priors_inside_design(config, &spec).with_context(|| format!("{}", config.path.display()))?;
    artifacts::check_writable(&opts.out)?;
    std::fs::create_dir_all(&opts.out).with_context(|| format!("creating {}", opts.out.display()))?;
    let emulator = config.emulator.is_some().then(|| EmulatorSettings::load(&config.path)).transpose()?;
    let study = Study { config, run, emulator, paths: RunPaths { out: opts.out.clone() }, opts };
    // Every candidate's declaration is checked before anything runs.
    let variants = study.variants()?;
    let mut stages = StageLoop::default();
    for stage in plan(&study, &variants)? {
        stages.run(&study, &stage)?;
    }
    Ok(stages.outcomes)
}

/// The study's stages in order, from its config: the mock stage for the
/// stand-in's mock data, refine with `[run.refine]`, candidates and diagnose
/// when the study declares candidates.
fn plan<'a>(r: &Study<'a>, variants: &[variants::Variant]) -> Result<Vec<Stage<'a>>> {
    let (run, paths) = (r.run, &r.paths);
    let stage = |name, upstream: &[&'static str], outputs: Vec<PathBuf>, body: fn(&Study<'a>, &Keys) -> Result<()>| {
        Stage { name, upstream: upstream.to_vec(), outputs, body }
    };
    let mut stages = vec![
        stage(
            "design",
            &[],
            vec![paths.design().join("design.parquet"), paths.validation_design().join("design.parquet")],
            Study::design,
        ),
        stage(
            "simulate",
            &["design"],
            vec![paths.design().join("runs"), paths.validation_design().join("runs")],
            Study::simulate,
        ),
        stage("ingest", &["simulate"], vec![paths.training(), paths.validation()], Study::ingest),
        stage(
            "emulator",
            &["ingest"],
            vec![paths.emulator().join("emulator.json"), paths.emulator().join("validation.json")],
            Study::emulator,
        ),
    ];
    let mut data: Vec<&'static str> = vec!["emulator"];
    if run.stand_in_study() {
        stages.push(stage("mock", &[], vec![paths.measurements()], Study::mock));
        data.push("mock");
    }
    let mut fitted = data.clone();
    let only = r.opts.stage.as_deref();
    if run.refine.is_some() {
        stages.push(stage("refine", &data, vec![r.refine_dir().join("rounds.json")], Study::refine));
        fitted.push("refine");
    } else if only == Some("refine") {
        bail!("--stage refine: {} has no [run.refine] table", r.config.path.display());
    }
    let assessed =
        if run.stand_in_study() { paths.out.join("study.json") } else { paths.calibrate().join("cases.json") };
    stages.push(stage("calibrate", &fitted, vec![assessed], Study::calibrate));
    stages.push(stage("report", &["calibrate"], vec![paths.out.join("report.html")], Study::report));
    if variants.is_empty() {
        if let Some(s) = only.filter(|s| *s == "candidates" || *s == "diagnose") {
            bail!(
                "--stage {s}: {} declares no candidates ([[candidates]] or [run] candidates)",
                r.config.path.display()
            );
        }
        return Ok(stages);
    }
    let emulators = variants.iter().map(|v| paths.candidate(&v.name).join("emulator").join("emulator.json")).collect();
    stages.push(stage("candidates", &["design"], emulators, Study::candidates));
    fitted.push("candidates");
    let outputs = vec![paths.diagnose().join("diagnosis.json"), paths.diagnose().join("report.html")];
    stages.push(stage("diagnose", &fitted, outputs, Study::diagnose));
    Ok(stages)
}

impl Study<'_> {
    /// The settings that define a stage's output, beyond its upstream keys.
    pub(super) fn settings_of(&self, stage: &str) -> Result<serde_json::Value> {
        let run = self.run;
        let spec_bytes = std::fs::read(self.config.resolve(&run.design))
            .with_context(|| format!("reading design spec {}", self.config.resolve(&run.design).display()))?;
        Ok(match stage {
            // The design stage also writes the array script, which carries the simulate settings.
            "design" => {
                serde_json::json!({"spec": artifacts::sha256_hex(&spec_bytes), "points": run.points, "validation_points": run.validation_points, "seed": self.opts.seed,
                "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f})
            }
            "simulate" => {
                serde_json::json!({"simulator": serde_json::to_value(&run.simulator)?, "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f, "seed": self.opts.seed})
            }
            "ingest" => {
                serde_json::json!({"runs": [runs_fingerprint(&self.paths.design().join("runs"))?, runs_fingerprint(&self.paths.validation_design().join("runs"))?], "observables": self.all_observables()})
            }
            "emulator" => {
                serde_json::json!({"emulator": serde_json::to_value(&self.emulator)?, "seed": self.opts.seed})
            }
            "mock" => {
                serde_json::json!({"truth": self.truth_named()?, "delta_f": run.mock_delta_f, "events": run.mock_events, "oversample": run.oversample, "seed": self.opts.seed, "observables": self.all_observables()})
            }
            "calibrate" => {
                serde_json::json!({"config": self.analysis_hash()?, "data": self.data_hash()?, "sets": run.observable_sets, "kernels": run.kernels, "seed": self.opts.seed})
            }
            "refine" => {
                serde_json::json!({"config": self.analysis_hash()?, "data": self.data_hash()?, "refine": serde_json::to_value(&run.refine)?, "simulator": serde_json::to_value(&run.simulator)?,
                "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f, "set": self.diagnose_observables(), "kernels": run.kernels, "seed": self.opts.seed})
            }
            "candidates" => {
                serde_json::json!({"spec": artifacts::sha256_hex(&spec_bytes), "variants": serde_json::to_value(self.variants()?)?, "points": run.candidate_points.unwrap_or(run.points), "events": run.events,
                "oversample": run.oversample, "delta_f": run.model_delta_f, "observables": self.all_observables(), "emulator": serde_json::to_value(&self.emulator)?, "seed": self.opts.seed})
            }
            "diagnose" => {
                serde_json::json!({"config": self.config.hash, "data": self.data_hash()?, "observables": self.diagnose_observables(), "seed": self.opts.seed})
            }
            _ => serde_json::json!({"config": self.analysis_hash()?}),
        })
    }
}
