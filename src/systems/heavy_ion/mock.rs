//! What `mdpipe simulate heavy-ion` makes: event-by-event runs at design
//! points or at one named point, and smooth mock measurements.

use super::{analysis_pt, observables, DeltaF, HeavyIonParams};
use crate::base::artifacts::{self, Measurement};
use anyhow::{anyhow, Context, Result};
use std::path::Path;

/// The points of `design` (or only `only`) to run, with the design copied
/// into `out` so that `ingest` finds the parameters beside the runs.
pub fn design_points(design: &Path, only: Option<i64>, out: &Path) -> Result<Vec<(i64, HeavyIonParams)>> {
    let d = super::read_design_points(design)?;
    std::fs::create_dir_all(out)?;
    // Array tasks may write this copy at once: each renames a complete file into place.
    let bytes = std::fs::read(design).with_context(|| format!("reading {}", design.display()))?;
    artifacts::write_atomic(&out.join("design.parquet"), |f| {
        use std::io::Write;
        Ok(f.write_all(&bytes)?)
    })?;
    let all: Vec<(i64, HeavyIonParams)> = d.ids.into_iter().zip(d.points).collect();
    match only {
        Some(id) => Ok(vec![*all.iter().find(|(i, _)| *i == id).ok_or_else(|| anyhow!("--only {id}: no design point {id} in {}", design.display()))?]),
        None => Ok(all),
    }
}

/// One named point (`eta_s=0.1,e_sw=0.2`) as design point 0, with a
/// one-row `design.parquet` written into `out`.
pub fn named_point(point: &str, seed: u64, out: &Path) -> Result<Vec<(i64, HeavyIonParams)>> {
    let params = HeavyIonParams::parse(point)?;
    let named: Vec<(String, f64)> = point.split(',').filter_map(|kv| kv.split_once('=')).map(|(k, v)| (k.trim().to_string(), v.trim().parse().unwrap_or(f64::NAN))).collect();
    let mut cols = vec![("design_id".to_string(), vec![0.0])];
    cols.extend(named.into_iter().map(|(k, v)| (k, vec![v])));
    let mut frame = artifacts::f64_frame(cols)?;
    let prov = artifacts::Provenance::new(String::new(), String::new(), seed, &format!("simulate heavy-ion --point {point}"));
    std::fs::create_dir_all(out)?;
    artifacts::write_parquet_atomic(&out.join("design.parquet"), &mut frame, Some(&prov))?;
    Ok(vec![(0, params)])
}

/// The stand-in's smooth observables at `params` in the analysis bins, each
/// with a relative 1σ error; flow coefficients near zero get an absolute
/// floor of 1e-4 so that errors stay positive.
pub fn smooth_measurements(params: &HeavyIonParams, delta_f: DeltaF, relative_error: f64) -> Vec<Measurement> {
    let pts = analysis_pt();
    let mut data = Vec::new();
    for (name, values) in observables(params, delta_f, &pts) {
        for (&x, &v) in pts.iter().zip(&values) {
            let err = if name.ends_with("spectrum") { relative_error * v.abs() } else { (relative_error * v.abs()).max(1e-4) };
            data.push(Measurement::new(name, x, v, err));
        }
    }
    data
}
