//! The diagnose stage, the end of every run (unless the study declares no
//! candidates and `[run] discover = false`): `diagnose` on the study's data
//! with every candidate's variant emulator and correction declared, and the
//! search for a correction when none explains a mismatch.

mod variant_refine;
mod verify;

use super::{Keys, Presence, Stage, StageId};
use crate::base::artifacts;
use crate::base::progress::observer;
use crate::engine::calibrate::Overrides;
use crate::pipeline::study::Study;
use anyhow::{Context, Result};
use std::path::PathBuf;

pub(crate) struct Diagnose;

#[derive(serde::Serialize)]
pub(crate) struct Settings {
    config: String,
    conventions: &'static str,
    data: String,
    observables: Vec<String>,
    seed: u64,
    /// When the search runs ("always", "never", "when unexplained").
    discover: &'static str,
    /// Whether the fit is run through the simulator (`[run] verify`); left
    /// out of the key when on, so studies run before the switch keep theirs.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    skip_verify: bool,
}

impl Stage for Diagnose {
    type Settings = Settings;
    const ID: StageId = StageId::DIAGNOSE;
    const UPSTREAM: &'static [StageId] = &[StageId::EMULATOR, StageId::REFINE, StageId::CANDIDATES];
    fn present(&self, study: &Study<'_>) -> Result<Presence> {
        presence(study)
    }
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        let dir = study.paths.diagnose();
        Ok(vec![dir.join("diagnosis.json"), dir.join("report.html"), dir.join("verify.json")])
    }
    fn kept_when_rerun(&self, study: &Study<'_>) -> Option<PathBuf> {
        Some(study.paths.diagnose())
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        Ok(Settings {
            config: study.config.hash.clone(),
            conventions: crate::engine::calibrate::analysis::CONVENTIONS,
            data: study.data_hash()?,
            observables: study.diagnose_observables(),
            seed: study.opts.seed,
            discover: match study.run.discover {
                Some(true) => "always",
                Some(false) => "never",
                None => "when unexplained",
            },
            skip_verify: !study.run.verify,
        })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        diagnose(study)
    }
}

/// `mdpipe diagnose` on the study's data (the mock's, or the config's
/// measurements) with every candidate's variant emulator declared;
/// when the verdict rests on variant emulators and `[run.refine]
/// variant_budget` allows, they are refined and the diagnosis made again.
fn diagnose(study: &Study<'_>) -> Result<()> {
    let mut config = study.study_config()?;
    let corrections: Vec<toml::Table> =
        config.candidates.iter().filter(|t| t.contains_key("correction")).cloned().collect();
    config.candidates =
        super::candidates::variants(study)?.into_iter().map(|v| v.declaration).chain(corrections).collect();
    let out = study.paths.diagnose();
    // A previous run's refined variants are of other settings (its runs would mix with new ones).
    crate::engine::execute::attempt::remove_after_attempts(&out.join("refine"))
        .with_context(|| format!("removing the previous variant refinement {}", out.join("refine").display()))?;
    let overrides = Overrides { observables: Some(study.diagnose_observables()), ..Default::default() };
    let mut settings = crate::engine::diagnose::DiagnoseSettings::default();
    settings.discover = match study.run.discover {
        Some(true) => crate::engine::diagnose::Discover::Always,
        Some(false) => crate::engine::diagnose::Discover::Never,
        None => settings.discover,
    };
    let seed = study.opts.seed.wrapping_add(77);
    // The base fits are two of the calibrate stage's cases; the diagnosis
    // after refinement takes the fits whose problems did not change, and so
    // does a diagnosis under new settings (a candidate added) from the last
    // one's, kept in previous/: each fit is taken only for its own problem.
    let stored = [study.paths.calibrate(), super::refine::report::refine_dir(study), study.paths.previous()]
        .iter()
        .flat_map(|d| study.stored_fits(d))
        .collect();
    let reuse = crate::engine::diagnose::Reuse::across_diagnoses(stored);
    let diagnose = |analysis: &_| {
        crate::engine::diagnose::run_reusing(
            analysis,
            &overrides,
            seed,
            &settings,
            Some(&out),
            observer(study.opts.show_progress),
            &reuse,
        )
    };
    let mut analysis = study.analysis(&config)?;
    let mut d = diagnose(&analysis)?;
    if variant_refine::refine_variants(study, &mut config, &analysis, &overrides, &d.diagnosis)? {
        crate::engine::diagnose::print(&d.diagnosis);
        artifacts::write_json_atomic(&out.join("refine").join("diagnosis_before.json"), &d.diagnosis)?;
        crate::base::messages::say!("  refined the variant emulators the verdict listed; diagnosing again");
        analysis = study.analysis(&config)?;
        d = diagnose(&analysis)?;
    }
    crate::engine::diagnose::print(&d.diagnosis);
    // Before the report, which shows it.
    verify::against_simulator(study, &analysis, &d.diagnosis)?;
    crate::engine::report::write(
        std::slice::from_ref(&out),
        &out.join("report.html"),
        &format!("mdpipe run: {} (diagnose)", study.config.name),
        &study.systems.iter().filter_map(|s| s.figures()).collect::<Vec<_>>(),
    )?;
    crate::base::messages::say!("  {}", out.join("report.html").display());
    Ok(())
}

/// The diagnose stage's presence: it ends every run, weighing the
/// candidates (variants or corrections of the emulator's output) and
/// searching when none explains a mismatch, unless the study declares none
/// and turns the search off (`[run] discover = false`).
fn presence(study: &Study<'_>) -> Result<Presence> {
    let corrections = study.config.candidates.iter().any(|t| t.contains_key("correction"));
    if corrections || study.run.discover != Some(false) {
        return Ok(Presence::Runs);
    }
    Ok(match super::candidates::presence(study)? {
        Presence::Absent(why) => {
            Presence::Absent(format!("{why}, no corrections, and the search is off ([run] discover = false)"))
        }
        runs => runs,
    })
}
