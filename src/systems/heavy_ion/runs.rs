//! The stand-in run over a design: event-by-event runs in iEBE-MUSIC's
//! layout, one point or all, and its smooth (infinite-statistics) tables.

use super::*;

/// A design's points: ids, parameter names and per-parameter columns, and the
/// parsed parameter points.
pub struct DesignPoints {
    pub ids: Vec<i64>,
    pub names: Vec<String>,
    pub columns: Vec<Vec<f64>>,
    pub points: Vec<HeavyIonParams>,
}

/// Reads `design.parquet` (from `mdpipe design`: `design_id` plus one column per parameter).
pub fn read_design_points(design: &std::path::Path) -> anyhow::Result<DesignPoints> {
    use anyhow::Context;
    let crate::engine::design::DesignColumns { names, ids, columns } = crate::engine::design::read_columns(design)?;
    let points: Vec<HeavyIonParams> = (0..ids.len())
        .map(|i| {
            let named: Vec<(String, f64)> = names.iter().zip(&columns).map(|(n, c)| (n.clone(), c[i])).collect();
            HeavyIonParams::from_named(&named).with_context(|| format!("{}: row {}", design.display(), i + 1))
        })
        .collect::<anyhow::Result<_>>()?;
    if points.is_empty() {
        anyhow::bail!("{}: the design has no points", design.display());
    }
    Ok(DesignPoints { ids, names, columns, points })
}

/// Runs the stand-in event by event at each point, writing iEBE-MUSIC-layout
/// runs to `out/<design id as %04d>/` (points in parallel). Returns the
/// number of events written.
pub fn simulate_runs(
    points: &[(i64, HeavyIonParams)],
    delta_f: DeltaF,
    n_events: usize,
    oversample: usize,
    seed: u64,
    layout: events::Layout,
    out: &std::path::Path,
) -> anyhow::Result<usize> {
    use rayon::prelude::*;
    if n_events == 0 {
        anyhow::bail!("--events must be at least 1");
    }
    let bar = crate::base::progress::bar(points.len() as u64, "heavy-ion stand-in, event by event");
    points.par_iter().try_for_each(|(id, p)| -> anyhow::Result<()> {
        simulate_point(*id, p, delta_f, n_events, oversample, seed, layout, &out.join(format!("{id:04}")))?;
        bar.inc(1);
        Ok(())
    })?;
    bar.finish_and_clear();
    Ok(points.len() * n_events)
}

/// The events of one design point, written into `dir`. Its seed depends on
/// the point's id only, so a point run alone (one array task, one attempt of
/// `mdpipe run`) equals the same point run with the whole design.
#[allow(clippy::too_many_arguments)]
pub fn simulate_point(
    id: i64,
    p: &HeavyIonParams,
    delta_f: DeltaF,
    n_events: usize,
    oversample: usize,
    seed: u64,
    layout: events::Layout,
    dir: &std::path::Path,
) -> anyhow::Result<()> {
    if n_events == 0 {
        anyhow::bail!("--events must be at least 1");
    }
    let tables = events::SmoothTables::new(p, delta_f);
    let evs = events::sample_events(
        &tables,
        n_events,
        oversample.max(1),
        seed.wrapping_add((id as u64).wrapping_mul(1_000_003)),
    );
    events::write_point(dir, &evs, layout)
}

/// The parameters of design point `id` of a design.parquet.
pub fn design_point(design: &std::path::Path, id: i64) -> anyhow::Result<HeavyIonParams> {
    let d = read_design_points(design)?;
    d.ids
        .iter()
        .position(|&i| i == id)
        .map(|k| d.points[k])
        .ok_or_else(|| anyhow::anyhow!("--only {id}: no design point {id} in {}", design.display()))
}

/// Runs the smooth (infinite-statistics) stand-in at every point of a design,
/// in parallel, and returns the long training table. Values follow ingest's
/// definitions in the analysis bins (bin-averaged spectra, count-weighted
/// v_n), i.e. the limit of `simulate` + `ingest` for infinitely many events,
/// so that an emulator trained on them compares with ingested data.
pub fn simulate_design(
    design: &std::path::Path,
    delta_f: DeltaF,
) -> anyhow::Result<crate::engine::emulator::TrainingTable> {
    let DesignPoints { ids, names, columns, points } = read_design_points(design)?;
    let inputs = (0..points.len()).flat_map(|i| columns.iter().map(move |c| c[i])).collect();
    Ok(smooth_table(design, ids, names, inputs, &points, delta_f))
}

/// The smooth stand-in's outputs at `points` as a training table (inputs
/// row-major in the order of `names`).
pub(super) fn smooth_table(
    path: &std::path::Path,
    ids: Vec<i64>,
    names: Vec<String>,
    inputs: Vec<f64>,
    points: &[HeavyIonParams],
    delta_f: DeltaF,
) -> crate::engine::emulator::TrainingTable {
    use rayon::prelude::*;
    let pts = analysis_pt();
    let edges = crate::engine::ingest::IngestSettings::default().pt_edges;
    let bar = crate::base::progress::bar(points.len() as u64, "heavy-ion stand-in over the design");
    let results: Vec<Vec<(String, Vec<f64>)>> = points
        .par_iter()
        .map(|p| {
            let o = events::SmoothTables::new(p, delta_f).expected(&edges);
            bar.inc(1);
            o
        })
        .collect();
    bar.finish_and_clear();
    let outputs: Vec<crate::engine::emulator::OutputKey> = results[0]
        .iter()
        .flat_map(|(n, _)| pts.iter().map(move |&x| crate::engine::emulator::OutputKey { observable: n.clone(), x }))
        .collect();
    let values: Vec<f64> = results.iter().flat_map(|r| r.iter().flat_map(|(_, v)| v.iter().copied())).collect();
    // Expected values: no run noise.
    let errors = vec![0.0; values.len()];
    crate::engine::emulator::TrainingTable {
        path: path.to_path_buf(),
        parameter_names: names,
        design_ids: ids,
        inputs,
        outputs,
        values,
        errors,
        noise_correlation: None,
    }
}

/// New runs for refinement from the smooth stand-in with a fixed
/// particlization: the runner of a variant emulator trained on smooth runs.
pub struct SmoothStandIn {
    pub delta_f: DeltaF,
}

impl crate::engine::refine::variant::PointRunner for SmoothStandIn {
    fn run(
        &self,
        names: &[String],
        points: &[Vec<f64>],
        first_id: i64,
        dir: &std::path::Path,
    ) -> anyhow::Result<crate::engine::emulator::TrainingTable> {
        if points.is_empty() {
            anyhow::bail!("no points to run");
        }
        let params: Vec<HeavyIonParams> = points
            .iter()
            .map(|p| HeavyIonParams::from_named(&names.iter().cloned().zip(p.iter().copied()).collect::<Vec<_>>()))
            .collect::<anyhow::Result<_>>()?;
        let ids = (first_id..first_id + points.len() as i64).collect();
        Ok(smooth_table(&dir.join("smooth stand-in runs"), ids, names.to_vec(), points.concat(), &params, self.delta_f))
    }
}
