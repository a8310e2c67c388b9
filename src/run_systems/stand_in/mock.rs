//! The mock stage (the heavy-ion stand-in's studies only, `[run]
//! mock_delta_f`): the stand-in run at the truth with the concealed δf, its
//! events ingested as the measurements, with their jackknife covariance.

use super::settings::StandInRun;
use crate::base::artifacts::{self, Measurement, Provenance};
use crate::pipeline::stage::{Keys, Presence, Stage, StageId};
use crate::pipeline::study::Study;
use crate::systems::heavy_ion::{self, events::Layout, DeltaF, HeavyIonParams};
use anyhow::{anyhow, Result};
use std::path::PathBuf;

pub(super) struct Mock;

/// The mock stage's id: `--stage mock`, `OUT/stages/mock.json`.
pub(super) const MOCK: StageId = StageId::new("mock");

#[derive(serde::Serialize)]
pub(super) struct Settings {
    truth: Vec<(String, f64)>,
    delta_f: Option<String>,
    events: Option<usize>,
    oversample: usize,
    seed: u64,
    observables: Vec<String>,
}

impl Stage for Mock {
    type Settings = Settings;
    const ID: StageId = MOCK;
    const UPSTREAM: &'static [StageId] = &[];
    fn present(&self, study: &Study<'_>) -> Result<Presence> {
        Ok(if super::mock_study(study) {
            Presence::Runs
        } else {
            Presence::Absent(format!("{} has no mock data ([run.stand_in] mock_delta_f)", study.config.path.display()))
        })
    }
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![measurements(study)])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        let stand_in = stand_in(study)?;
        Ok(Settings {
            truth: truth_named(study)?,
            delta_f: stand_in.mock_delta_f,
            events: stand_in.mock_events,
            oversample: stand_in.oversample,
            seed: study.opts.seed,
            observables: study.all_observables(),
        })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        mock(study)
    }
}

/// Where the mock stage writes: mock/runs/, mock/measurements.parquet, mock/covariance.csv.
pub(super) fn folder(study: &Study<'_>) -> PathBuf {
    study.paths.out.join("mock")
}

pub(super) fn measurements(study: &Study<'_>) -> PathBuf {
    folder(study).join("measurements.parquet")
}

fn mock(study: &Study<'_>) -> Result<()> {
    let params = HeavyIonParams::from_named(&truth_named(study)?)?;
    let stand_in = stand_in(study)?;
    let mock_delta_f = stand_in.mock_delta_f.clone().unwrap_or_default();
    let mock_events = stand_in.mock_events.unwrap_or_default();
    let delta_f: DeltaF = mock_delta_f.parse()?;
    let runs = folder(study).join("runs");
    if runs.exists() {
        std::fs::remove_dir_all(&runs)?;
    }
    std::fs::create_dir_all(&runs)?;
    heavy_ion::simulate_runs(
        &[(0, params)],
        delta_f,
        mock_events,
        stand_in.oversample,
        mock_seed(study.opts.seed),
        Layout::Hdf5,
        &runs,
    )?;
    let (ingested, _) =
        crate::engine::ingest::ingest_runs(&runs, None, &crate::engine::ingest::IngestSettings::default())?;
    let undefined: Vec<String> = ingested.report.points.iter().flat_map(|p| p.undefined_bins.clone()).collect();
    if !undefined.is_empty() {
        crate::base::messages::say!("  mock bins left out (undefined): {}", undefined.join(", "));
    }
    let keep = study.all_observables();
    let data: Vec<Measurement> = ingested
        .rows
        .iter()
        .filter(|r| keep.contains(&r.observable))
        .map(|r| Measurement::new(&r.observable, r.x, r.value, r.error))
        .collect();
    let prov = Provenance::new(
        study.config.hash.clone(),
        artifacts::measurements_hash(&data),
        study.opts.seed,
        &format!("run --stage mock: {mock_events} events, delta-f {mock_delta_f}"),
    );
    artifacts::write_measurements(&measurements(study), &data, Some(&prov))?;
    // The bins' jackknife covariance over the same events, for `[data] covariance`.
    let mut kept = ingested;
    kept.rows.retain(|r| keep.contains(&r.observable));
    if let Some(entries) = crate::engine::ingest::single_point_covariance(&kept) {
        crate::base::covariance::write_covariance_csv(&folder(study).join("covariance.csv"), &entries)?;
    }
    crate::base::messages::say!(
        "  {} values from {mock_events} events (delta-f {mock_delta_f}) -> {}",
        data.len(),
        measurements(study).display()
    );
    Ok(())
}

/// The study's `[run.stand_in]` (the mock stage runs only with one).
fn stand_in(study: &Study<'_>) -> Result<StandInRun> {
    StandInRun::of(study.run)?.ok_or_else(|| anyhow!("the mock stage needs a [run.stand_in] table"))
}

fn mock_seed(seed: u64) -> u64 {
    seed.wrapping_mul(31).wrapping_add(977)
}

/// The mock truth: `mock_truth`, or every θ's `truth` value from the config.
pub(super) fn truth_named(study: &Study<'_>) -> Result<Vec<(String, f64)>> {
    if let Some(t) = &stand_in(study)?.mock_truth {
        return Ok(t.iter().map(|(k, v)| (k.clone(), *v)).collect());
    }
    study
        .config
        .parameters
        .iter()
        .map(|(name, p)| {
            p.truth.map(|t| (name.clone(), t)).ok_or_else(|| {
                anyhow!(
                    "{}: [parameters.{name}] needs a `truth` value: the mock data are made there",
                    study.config.path.display()
                )
            })
        })
        .collect()
}
