//! The design stage: a design over θ for the training runs and another for
//! the validation runs, each with its parameter files and the Slurm array
//! script that runs the simulator at each point as the simulate stage would.

use super::{Keys, Stage, StageId};
use crate::engine::design::DesignSpec;
use crate::pipeline::points::{self, NewDesign};
use crate::pipeline::setup;
use crate::pipeline::study::Study;
use anyhow::Result;
use std::path::PathBuf;

pub(crate) struct Design;

/// The design stage also writes the array script, which carries the
/// simulate settings (a system's among them).
#[derive(serde::Serialize)]
pub(crate) struct Settings {
    spec: String,
    points: usize,
    validation_points: usize,
    seed: u64,
    #[serde(flatten)]
    system: serde_json::Map<String, serde_json::Value>,
}

impl Stage for Design {
    type Settings = Settings;
    const ID: StageId = StageId::DESIGN;
    const UPSTREAM: &'static [StageId] = &[];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![study.paths.design().join("design.parquet"), study.paths.validation_design().join("design.parquet")])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        Ok(Settings {
            spec: study.design_spec_hash()?,
            points: study.run.points,
            validation_points: study.run.validation_points,
            seed: study.opts.seed,
            system: setup::system_settings(study, StageId::DESIGN),
        })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        let spec = DesignSpec::load(&study.config.resolve(&study.run.design))?;
        let spec_hash = study.design_spec_hash()?;
        for (dir, points, seed, label) in [
            (study.paths.design(), study.run.points, study.opts.seed, "design"),
            (
                study.paths.validation_design(),
                study.run.validation_points,
                study.opts.seed.wrapping_add(7919),
                "validation design",
            ),
        ] {
            let simulator = study.simulator(label == "validation design")?;
            let design =
                NewDesign { spec: &spec, spec_hash: &spec_hash, simulator: &simulator, label, points, seed, dir: &dir };
            points::write_design(study, &design)?;
        }
        Ok(())
    }
}
