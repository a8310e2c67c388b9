//! The diagnose stage.

use super::stages::*;
use crate::base::artifacts::{self};
use crate::base::progress::observer;
use crate::engine::calibrate::Overrides;
use crate::systems::heavy_ion::figures::HeavyIonFigures;
use anyhow::{Context, Result};

impl Study<'_> {
    /// `mdpipe diagnose` on the study's data (the mock's, or the config's
    /// measurements) with every candidate's variant emulator declared;
    /// when the verdict rests on variant emulators and `[run.refine]
    /// variant_budget` allows, they are refined and the diagnosis made again.
    pub(super) fn diagnose(&self, _keys: &Keys) -> Result<()> {
        let mut config = self.study_config()?;
        config.candidates = self.variants()?.into_iter().map(|v| v.declaration).collect();
        let out = self.paths.diagnose();
        // A previous run's refined variants are of other settings (its runs would mix with new ones).
        if out.join("refine").exists() {
            std::fs::remove_dir_all(out.join("refine")).with_context(|| {
                format!("removing the previous variant refinement {}", out.join("refine").display())
            })?;
        }
        let overrides = Overrides { observables: Some(self.diagnose_observables()), ..Default::default() };
        let settings = crate::engine::diagnose::DiagnoseSettings::default();
        let seed = self.opts.seed.wrapping_add(77);
        let diagnose = |analysis: &_| {
            crate::engine::diagnose::run(
                analysis,
                &overrides,
                seed,
                &settings,
                Some(&out),
                observer(self.opts.show_progress),
            )
        };
        let analysis = self.analysis(&config)?;
        let mut d = diagnose(&analysis)?;
        if self.refine_variants(&mut config, &analysis, &overrides, &d.diagnosis)? {
            crate::engine::diagnose::print(&d.diagnosis);
            artifacts::write_json_atomic(&out.join("refine").join("diagnosis_before.json"), &d.diagnosis)?;
            println!("  refined the variant emulators the verdict listed; diagnosing again");
            d = diagnose(&self.analysis(&config)?)?;
        }
        crate::engine::diagnose::print(&d.diagnosis);
        crate::engine::report::write(
            std::slice::from_ref(&out),
            &out.join("report.html"),
            &format!("mdpipe run: {} (diagnose)", self.config.name),
            &[&HeavyIonFigures],
        )?;
        println!("  {}", out.join("report.html").display());
        Ok(())
    }
}
