//! Mock data from the heavy-ion stand-in's own events (not from an
//! emulator): what the diagnose tests calibrate against.

use mdpipe::config::Config;
use std::path::Path;

/// Mock data as the bundled study makes them: 3000 events of the stand-in
/// with the Grad δf at η/s = 0.1, ε_sw = 0.2 GeV/fm³ (event seed `seed`),
/// through ingest, with the bins' jackknife covariance (within and across
/// observables, since the bins are counted from the same events). Points
/// `cfg` at them; the files go into `dir`.
pub(crate) fn grad_event_mock(cfg: &mut Config, dir: &Path, seed: u64) {
    use mdpipe::systems::heavy_ion::{self, DeltaF, HeavyIonParams};
    let runs = dir.join("mock");
    heavy_ion::simulate_runs(
        &[(0, HeavyIonParams::constant(0.1, 0.2))],
        DeltaF::Grad,
        3000,
        50,
        seed,
        heavy_ion::events::Layout::Hdf5,
        &runs,
    )
    .unwrap();
    let (ingested, _) = mdpipe::ingest::ingest_runs(&runs, None, &mdpipe::ingest::IngestSettings::default()).unwrap();
    let data: Vec<mdpipe::artifacts::Measurement> = ingested
        .rows
        .iter()
        .map(|r| mdpipe::artifacts::Measurement::new(&r.observable, r.x, r.value, r.error))
        .collect();
    let measurements = dir.join("measurements.parquet");
    mdpipe::artifacts::write_measurements(&measurements, &data, None).unwrap();
    cfg.data.measurements = measurements;
    let covariance = dir.join("covariance.csv");
    mdpipe::base::covariance::write_covariance_csv(
        &covariance,
        &mdpipe::ingest::single_point_covariance(&ingested).unwrap(),
    )
    .unwrap();
    cfg.data.covariance = Some(covariance);
}
