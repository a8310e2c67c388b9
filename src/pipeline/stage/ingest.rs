//! The ingest stage: each design's runs read into a table of the study's
//! observables (training.parquet, validation.parquet), with points that
//! failed or lack an output left out and listed.

use super::{Keys, Stage, StageId};
use crate::pipeline::points;
use crate::pipeline::study::{runs_fingerprint, Study};
use anyhow::Result;
use std::path::PathBuf;

pub(crate) struct Ingest;

/// The run folders' contents, which a rerun of the simulate stage may change.
#[derive(serde::Serialize)]
pub(crate) struct Settings {
    runs: [String; 2],
    observables: Vec<String>,
}

impl Stage for Ingest {
    type Settings = Settings;
    const ID: StageId = StageId::INGEST;
    const UPSTREAM: &'static [StageId] = &[StageId::SIMULATE];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![study.paths.training(), study.paths.validation()])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        let paths = &study.paths;
        Ok(Settings {
            runs: [
                runs_fingerprint(&paths.design().join("runs"))?,
                runs_fingerprint(&paths.validation_design().join("runs"))?,
            ],
            observables: study.all_observables(),
        })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        for (dir, out) in [
            (study.paths.design(), study.paths.training()),
            (study.paths.validation_design(), study.paths.validation()),
        ] {
            points::ingest_design(study, &dir, &out)?;
        }
        Ok(())
    }
}
