//! What `mdpipe simulate heavy-ion` makes: event-by-event runs at design
//! points or at one named point, and smooth mock measurements.

use super::events::SmoothTables;
use super::{DeltaF, HeavyIonParams};
use crate::base::artifacts::{self, Measurement};
use anyhow::{anyhow, bail, Context, Result};
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
        Some(id) => Ok(vec![*all
            .iter()
            .find(|(i, _)| *i == id)
            .ok_or_else(|| anyhow!("--only {id}: no design point {id} in {}", design.display()))?]),
        None => Ok(all),
    }
}

/// One named point (`eta_s=0.1,e_sw=0.2`) as design point 0, with a
/// one-row `design.parquet` written into `out`.
pub fn named_point(point: &str, seed: u64, out: &Path) -> Result<Vec<(i64, HeavyIonParams)>> {
    let params = HeavyIonParams::parse(point)?;
    let named: Vec<(String, f64)> = point
        .split(',')
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.trim().to_string(), v.trim().parse().unwrap_or(f64::NAN)))
        .collect();
    let mut cols = vec![("design_id".to_string(), vec![0.0])];
    cols.extend(named.into_iter().map(|(k, v)| (k, vec![v])));
    let mut frame = artifacts::f64_frame(cols)?;
    let prov =
        artifacts::Provenance::new(String::new(), String::new(), seed, &format!("simulate heavy-ion --point {point}"));
    std::fs::create_dir_all(out)?;
    artifacts::write_parquet_atomic(&out.join("design.parquet"), &mut frame, Some(&prov))?;
    Ok(vec![(0, params)])
}

/// Replaces each value's error by the error of the same (observable, x) in the
/// measurements file `source`: smooth values with a real measurement's errors
/// are the Asimov data set, on which a fit lands where it would without noise.
pub fn take_errors_from(data: &mut [Measurement], source: &Path) -> Result<()> {
    let errors = artifacts::read_measurements(source)?;
    for m in data.iter_mut() {
        let same = |e: &&Measurement| e.observable == m.observable && (e.x - m.x).abs() <= 1e-9 * m.x.abs().max(1.0);
        let mut found = errors.iter().filter(same);
        let first = found.next().ok_or_else(|| {
            anyhow!("{}: no measurement of {} at x = {:.4} to take its error from", source.display(), m.observable, m.x)
        })?;
        // Two rows for one point leave its error ambiguous.
        if let Some(second) = found.next() {
            bail!(
                "{}: lines {} and {} both measure {} at x = {:.4}; which error to take is ambiguous",
                source.display(),
                first.line,
                second.line,
                m.observable,
                m.x
            );
        }
        m.error = first.error;
    }
    Ok(())
}

/// The stand-in's expected observables at `params` in the analysis bins, as
/// `mdpipe ingest` measures them from runs (histogram spectra, count-weighted
/// v_n, charged hadrons in their η window): the limit of `simulate` + `ingest`
/// for infinitely many events, like `simulate_design`'s training tables. Each
/// value gets a relative 1σ error; flow coefficients near zero get an
/// absolute floor of 1e-4 so that errors stay positive.
pub fn smooth_measurements(params: &HeavyIonParams, delta_f: DeltaF, relative_error: f64) -> Vec<Measurement> {
    let edges = crate::engine::ingest::IngestSettings::default().pt_edges;
    let mut data = Vec::new();
    for (name, values) in SmoothTables::new(params, delta_f).expected(&edges) {
        for (w, &v) in edges.windows(2).zip(&values) {
            let err = if name.ends_with("spectrum") {
                relative_error * v.abs()
            } else {
                (relative_error * v.abs()).max(1e-4)
            };
            data.push(Measurement::new(&name, 0.5 * (w[0] + w[1]), v, err));
        }
    }
    data
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_are_taken_by_observable_and_x_and_a_missing_point_is_named() {
        let params = HeavyIonParams::parse("eta_s=0.1,e_sw=0.2").unwrap();
        let smooth = smooth_measurements(&params, DeltaF::Grad, 0.01);
        // A source with every point's error set to a known function of its place.
        let source: Vec<Measurement> = smooth
            .iter()
            .enumerate()
            .map(|(i, m)| Measurement::new(&m.observable, m.x, -1.0, 0.5 + i as f64))
            .collect();
        let dir = std::env::temp_dir().join(format!("mdpipe_errors_from_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("source.csv");
        artifacts::write_measurements(&path, &source, None).unwrap();
        let mut data = smooth.clone();
        take_errors_from(&mut data, &path).unwrap();
        for (i, (d, s)) in data.iter().zip(&smooth).enumerate() {
            assert_eq!((d.value, d.error), (s.value, 0.5 + i as f64), "{} at {}", d.observable, d.x);
        }
        // A source that lacks one point (the last p_v2 bin): that point is named.
        artifacts::write_measurements(&path, &source[..source.len() - 1], None).unwrap();
        let err = take_errors_from(&mut data, &path).unwrap_err().to_string();
        assert!(err.contains("source.csv") && err.contains("p_v2"), "{err}");
        // A source that measures one point twice: both lines are named.
        let doubled: Vec<Measurement> = source.iter().chain(&source[..1]).cloned().collect();
        artifacts::write_measurements(&path, &doubled, None).unwrap();
        let err = take_errors_from(&mut data, &path).unwrap_err().to_string();
        assert!(err.contains("ambiguous") && err.contains("ch_spectrum"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
