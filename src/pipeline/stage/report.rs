//! The report stage: report.html over the calibrations and the emulator,
//! with the stand-in's study and figures when the study is the stand-in's.

use super::{Keys, StageDef};
use crate::base::artifacts;
use crate::pipeline::study::Study;
use crate::systems::heavy_ion::figures::HeavyIonFigures;
use anyhow::Result;
use std::path::PathBuf;

pub(super) const STAGE: StageDef = StageDef {
    name: "report",
    rank: 80,
    upstream: &["calibrate"],
    present: super::always,
    outputs,
    settings,
    body: report,
};

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    Ok(vec![study.paths.out.join("report.html")])
}

fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    Ok(serde_json::json!({"config": study.analysis_hash()?}))
}

fn report(study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
    if !study.run.stand_in_study() {
        let html = crate::engine::report::build(
            &[study.paths.calibrate(), study.study_emulator()?],
            &format!("mdpipe run: {}", study.config.name),
            &[],
        )?;
        artifacts::write_text_atomic(&study.paths.out.join("report.html"), &html)?;
        println!("  {}", study.paths.out.join("report.html").display());
        return Ok(());
    }
    let assessed: crate::systems::heavy_ion::study::Study =
        serde_json::from_str(&std::fs::read_to_string(study.paths.out.join("study.json"))?)?;
    let mut dirs = vec![study.paths.calibrate(), study.study_emulator()?];
    dirs.dedup();
    let html = crate::engine::report::build(&dirs, &format!("mdpipe run: {}", study.config.name), &[&HeavyIonFigures])?;
    let html = html.replacen("</h1>\n", &format!("</h1>\n{}", assessed.html()), 1);
    artifacts::write_text_atomic(&study.paths.out.join("report.html"), &html)?;
    println!("  {}", study.paths.out.join("report.html").display());
    Ok(())
}
