//! The report stage: report.html over the calibrations and the emulator,
//! with the section and figures of a system that assessed the study against
//! its truth.

use super::{Keys, Stage, StageId};
use crate::base::artifacts;
use crate::pipeline::study::Study;
use anyhow::Result;
use std::path::PathBuf;

pub(crate) struct Report;

#[derive(serde::Serialize)]
pub(crate) struct Settings {
    config: String,
}

impl Stage for Report {
    type Settings = Settings;
    const ID: StageId = StageId::REPORT;
    const UPSTREAM: &'static [StageId] = &[StageId::CALIBRATE];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![study.paths.out.join("report.html")])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        Ok(Settings { config: study.analysis_hash()? })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        let dirs = [study.paths.calibrate(), super::refine::report::emulator_in_use(study)?];
        // A system that assessed the study adds its section and its figures.
        let mut figures = Vec::new();
        let mut sections = String::new();
        for system in study.systems {
            if let Some(section) = system.report_section(study)? {
                sections.push_str(&section);
                figures.extend(system.figures());
            }
        }
        let html = crate::engine::report::build(&dirs, &format!("mdpipe run: {}", study.config.name), &figures)?;
        let html = html.replacen("</h1>\n", &format!("</h1>\n{sections}"), 1);
        artifacts::write_text_atomic(&study.paths.out.join("report.html"), &html)?;
        crate::base::messages::say!("  {}", study.paths.out.join("report.html").display());
        Ok(())
    }
}
