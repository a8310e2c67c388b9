//! `mdpipe run`: a study end to end for any simulator, as a sequence of
//! stages that each write their artifacts under one output folder and are
//! skipped when their inputs have not changed. The simulate stage runs
//! `[run.simulator]` (or, without it, the simulator of a system named by its
//! own table, `[run.<system>]`) through `engine::execute`, locally or as a
//! Slurm array. The calibrations use the config's measurements, or data a
//! system's own stage made, whose truth is known and assessed in study.md.
//!
//! | stage       | writes (under OUT/)                                             |
//! |-------------|-----------------------------------------------------------------|
//! | design      | design/, validation_design/ (design.parquet, parameter files, submit.slurm) |
//! | simulate    | design/runs/, validation_design/runs/ (one folder per point, execution.json) |
//! | ingest      | training.parquet, validation.parquet (+ .report.json)           |
//! | emulator    | emulator/ (trained, then validated: validation.json)            |
//! | (a system's) | what its own stages write, placed where the system says (mock data with a known truth, before the stages that read the data) |
//! | refine      | refine/round_<r>/ (pilots, design with runs, tables, emulator), refine/rounds.json, rounds.md (only with `[run.refine]`; the stages after it use its emulator) |
//! | calibrate   | calibrate/<observables>__<kernel>/ per case, study.md, study.json (or calibrate/cases.md, cases.json) |
//! | report      | report.html                                                     |
//! | candidates  | candidates/<name>/ (design, runs, training.parquet, emulator with its cross-validation) per candidate |
//! | diagnose    | diagnose/ (diagnosis.json, report.html and every calibration; refine/<candidate>/ and refine/diagnosis_before.json when variants were refined) |
//!
//! The last two run when the study declares candidates: `[[candidates]]`
//! tables that say how the simulator turns each piece of physics on
//! (`variants`), or the library names a system's table gives.
//! Each stage is one module of `stage/` (a type implementing `stage::Stage`:
//! its `StageId`, upstream stages, outputs, typed settings and body), and a
//! system adds its own, with ids of its own, through `system::System::stages`
//! (with where each runs and which stages read it);
//! `stage::StageLoop` owns the keys and stamps:
//! a stage whose stamp (`OUT/stages/<stage>.json`) holds the key of its
//! settings and upstream keys, and whose outputs exist, is skipped. Within
//! the calibrate stage each case is stamped too
//! (`OUT/stages/calibrate/<case>.json`), so an interrupted stage resumes
//! with the cases it had not finished. One run writes a folder at a time
//! (`lock`): a second run into it stops and names the first.

mod complete;
mod lock;
mod owner;
pub(crate) mod plan;
mod points;
pub(crate) mod run_config;
mod setup;
pub(crate) mod stage;
mod stage_id;
pub(crate) mod study;
pub(crate) mod system;
pub(crate) mod variants;

use crate::base::artifacts::{self};
use crate::base::config::Config;
use crate::engine::emulator::EmulatorSettings;
use crate::engine::execute::{self};
use anyhow::{anyhow, bail, Context, Result};
pub use complete::{fill_in_from_study, load, study_out};
pub use run_config::{RefineConfig, RunConfig};
pub use stage::refine::report::Rounds;
use stage::StageLoop;
pub use stage::{StageId, StageOutcome};
use study::Study;
pub use study::{RunOptions, RunPaths};
pub use system::Systems;

/// Every stage a study with these systems may have, in order (`--stage` takes these names).
pub fn stages(systems: &Systems) -> Vec<&'static str> {
    plan::stages(systems).iter().map(|p| p.stage.id().name()).collect()
}

/// The error for a config without `[run]`, pointing at a generic example.
pub fn no_run_table(path: &std::path::Path) -> anyhow::Error {
    anyhow!(
        "{}: no [run] table; `mdpipe run` needs one (see examples/decay_counter/study.toml, your own simulator's run)",
        path.display()
    )
}

/// Runs the study (or one stage of it) with the systems `app::systems()`
/// lists. Returns what ran and what was skipped.
pub fn run(config: &Config, opts: &RunOptions, systems: &Systems) -> Result<Vec<StageOutcome>> {
    let table = config.run.as_ref().ok_or_else(|| no_run_table(&config.path))?;
    let run: &RunConfig = &RunConfig::of(config, table)?;
    let spec = crate::engine::design::DesignSpec::load(&config.resolve(&run.design))?;
    let design_parameters: Vec<String> = spec.parameters.iter().map(|p| p.name.clone()).collect();
    if opts.case.is_some() && opts.stage.as_deref() != Some(StageId::CALIBRATE.name()) {
        bail!("--case needs --stage calibrate");
    }
    execute::spec::seconds_of(&run.calibration_time_limit).context("[run] calibration_time_limit")?;
    run.validate(&design_parameters).with_context(|| format!("{}: [run]", config.path.display()))?;
    setup::check_system_tables(run, systems).with_context(|| format!("{}", config.path.display()))?;
    variants::check_priors_inside_design(config, &spec).with_context(|| format!("{}", config.path.display()))?;
    artifacts::check_writable(&opts.out)?;
    std::fs::create_dir_all(&opts.out).with_context(|| format!("creating {}", opts.out.display()))?;
    let emulator = config.emulator.is_some().then(|| EmulatorSettings::load(&config.path)).transpose()?;
    // Absolute from here on: declarations written for later stages (a variant's
    // emulator folder) are resolved against the config's folder, not the cwd.
    // Canonical, so that `--out ../x` and `--out /abs/x` key their stages alike.
    let out = std::fs::canonicalize(&opts.out).unwrap_or_else(|_| study::absolute(&opts.out));
    let paths = RunPaths { out };
    let queries = systems.queries();
    let study = Study { config, run, emulator, paths, opts, systems: &queries };
    // Every candidate's declaration is checked before anything runs.
    stage::candidates::variants(&study)?;
    let planned = plan::plan(&study, systems)?;
    // Taken once the study is checked (a refused config leaves no lock file)
    // and held to the end of the run; a calibrate array task is covered by
    // the run that submitted it.
    let _lock = opts.case.is_none().then(|| lock::take(&study.paths.out)).transpose()?;
    if opts.case.is_none() {
        if let Some(other) = owner::claim(&study.paths.out, &config.path)? {
            crate::base::messages::note!("{}", owner::shared_warning(&study.paths.out, &config.path, &other));
        }
    }
    let mut stages = StageLoop::new(&planned);
    for stage in &planned {
        stages.run(&study, stage)?;
    }
    Ok(stages.outcomes)
}
