//! The diagnose stage (when the study declares candidates): `diagnose` on
//! the study's data with every candidate's variant emulator declared.

use super::{Keys, StageDef};
use crate::base::artifacts;
use crate::base::progress::observer;
use crate::engine::calibrate::Overrides;
use crate::pipeline::setup;
use crate::pipeline::study::Study;
use anyhow::{Context, Result};
use std::path::PathBuf;

pub(super) const STAGE: StageDef = StageDef {
    name: "diagnose",
    rank: 100,
    upstream: &["emulator", "mock", "refine", "candidates"],
    present: super::candidates::with_candidates,
    outputs,
    settings,
    body: diagnose,
};

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    Ok(vec![study.paths.diagnose().join("diagnosis.json"), study.paths.diagnose().join("report.html")])
}

fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    Ok(
        serde_json::json!({"config": study.config.hash, "conventions": crate::engine::calibrate::analysis::CONVENTIONS, "data": study.data_hash()?, "observables": study.diagnose_observables(), "seed": study.opts.seed}),
    )
}

/// `mdpipe diagnose` on the study's data (the mock's, or the config's
/// measurements) with every candidate's variant emulator declared;
/// when the verdict rests on variant emulators and `[run.refine]
/// variant_budget` allows, they are refined and the diagnosis made again.
fn diagnose(study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
    let mut config = study.study_config()?;
    config.candidates = study.variants()?.into_iter().map(|v| v.declaration).collect();
    let out = study.paths.diagnose();
    // A previous run's refined variants are of other settings (its runs would mix with new ones).
    crate::engine::execute::attempt::remove_after_attempts(&out.join("refine"))
        .with_context(|| format!("removing the previous variant refinement {}", out.join("refine").display()))?;
    let overrides = Overrides { observables: Some(study.diagnose_observables()), ..Default::default() };
    let settings = crate::engine::diagnose::DiagnoseSettings::default();
    let seed = study.opts.seed.wrapping_add(77);
    // The base fits are two of the calibrate stage's cases; the diagnosis
    // after refinement takes the fits whose problems did not change.
    let stored = [study.paths.calibrate(), study.refine_dir()].iter().flat_map(|d| study.stored_fits(d)).collect();
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
    let analysis = study.analysis(&config)?;
    let mut d = diagnose(&analysis)?;
    if study.refine_variants(&mut config, &analysis, &overrides, &d.diagnosis)? {
        crate::engine::diagnose::print(&d.diagnosis);
        artifacts::write_json_atomic(&out.join("refine").join("diagnosis_before.json"), &d.diagnosis)?;
        crate::base::messages::say!("  refined the variant emulators the verdict listed; diagnosing again");
        d = diagnose(&study.analysis(&config)?)?;
    }
    crate::engine::diagnose::print(&d.diagnosis);
    crate::engine::report::write(
        std::slice::from_ref(&out),
        &out.join("report.html"),
        &format!("mdpipe run: {} (diagnose)", study.config.name),
        &setup::systems().into_iter().filter_map(|s| s.figures()).collect::<Vec<_>>(),
    )?;
    crate::base::messages::say!("  {}", out.join("report.html").display());
    Ok(())
}
