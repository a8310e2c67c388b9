//! A set of simulator points, as every stage that makes runs makes them:
//! written as a design (parameter files and the Slurm array script that
//! runs the simulator at each point as the executor would), run through the
//! study's executor, and ingested into a table of the study's observables.
//! The design, simulate, ingest, candidates and refine stages and the
//! diagnose stage's variant refinement all call it.

use super::study::{absolute, Study};
use crate::base::artifacts::Provenance;
use crate::engine::design::DesignSpec;
use crate::engine::execute::{self, OutputKind, SimulatorSpec};
use crate::engine::ingest::{tables::TableRuns, IebeMusicRuns, IngestSettings, RunsReader};
use anyhow::{anyhow, bail, Context, Result};
use std::path::{Path, PathBuf};

/// A design to write: where, how many points, from which seed, under which label.
pub(super) struct NewDesign<'d> {
    pub(super) spec: &'d DesignSpec,
    pub(super) spec_hash: &'d str,
    pub(super) simulator: &'d SimulatorSpec,
    pub(super) label: &'d str,
    pub(super) points: usize,
    pub(super) seed: u64,
    pub(super) dir: &'d Path,
}

/// Writes a design of `d.points` points into `d.dir` whose Slurm array
/// script (`submit.slurm`) runs the simulator at each point as the simulate
/// stage would, with the same `{seed}`s.
pub(super) fn write_design(study: &Study<'_>, d: &NewDesign<'_>) -> Result<()> {
    let spec = with_array_command(study, d.spec, d.simulator, d.label);
    // Runs of an earlier design belong to other points: the simulate stage
    // keeps unstamped point folders (SLURM's), so they must not survive here.
    let runs = d.dir.join("runs");
    if runs.exists() {
        execute::attempt::remove_after_attempts(&runs)
            .with_context(|| format!("removing runs of the previous design {}", runs.display()))?;
        crate::base::messages::say!("  removed {} (runs of the previous design)", runs.display());
    }
    let q = crate::engine::design::write_design(&spec, d.spec_hash, d.points, d.seed, d.dir)?;
    crate::base::messages::say!("  {}: {} points, minimum distance {:.4}", d.dir.display(), q.points, q.min_distance);
    Ok(())
}

/// Points chosen by a stage (emulator parameter order, `names`), to be run
/// as a design of their own: which simulator, under which label and ids,
/// with the provenance their design records.
pub(super) struct ChosenPoints<'a> {
    pub spec: &'a DesignSpec,
    pub simulator: &'a SimulatorSpec,
    pub label: &'a str,
    pub ids: &'a [i64],
    pub points: &'a [Vec<f64>],
    pub names: &'a [String],
    pub prov: &'a Provenance,
}

/// Writes the chosen points as a design in `design_dir`, runs them through
/// the run's executor and ingests their runs into the training table `table`.
pub(super) fn run_chosen_points(
    study: &Study<'_>,
    chosen: &ChosenPoints,
    design_dir: &Path,
    table: &Path,
) -> Result<()> {
    write_chosen_points(study, chosen, design_dir)?;
    run_design(study, design_dir, chosen.simulator, chosen.label)?;
    ingest_design(study, design_dir, table)
}

/// Writes chosen points as a design in `design_dir` (parameter files and a
/// Slurm array over their ids) whose array script runs their simulator
/// under their label, and makes its `runs/` folder ready.
fn write_chosen_points(study: &Study<'_>, c: &ChosenPoints, design_dir: &Path) -> Result<PathBuf> {
    let spec = with_array_command(study, c.spec, c.simulator, c.label);
    // The design's parameter order may differ from the emulator's.
    let rows: Vec<Vec<f64>> = c
        .points
        .iter()
        .map(|p| {
            spec.parameters
                .iter()
                .map(|sp| {
                    c.names
                        .iter()
                        .position(|n| *n == sp.name)
                        .map(|k| p[k])
                        .ok_or_else(|| anyhow!("design parameter {} is not an emulator parameter", sp.name))
                })
                .collect::<Result<Vec<f64>>>()
        })
        .collect::<Result<_>>()?;
    let made_by = format!("mdpipe {} ({} points)", c.label, c.ids.len());
    crate::engine::design::write_points(&spec, c.ids, &rows, c.prov, &made_by, design_dir)?;
    let runs = design_dir.join("runs");
    std::fs::create_dir_all(&runs)?;
    std::fs::copy(design_dir.join("design.parquet"), runs.join("design.parquet"))?;
    Ok(runs)
}

/// `spec` whose Slurm array script runs `simulator` as the executors do.
fn with_array_command(study: &Study<'_>, spec: &DesignSpec, simulator: &SimulatorSpec, label: &str) -> DesignSpec {
    let mut spec = spec.clone();
    let keys: Vec<(String, String)> =
        spec.parameters.iter().map(|p| (p.name.clone(), p.file_key().to_string())).collect();
    spec.slurm.command = simulator.array_command(&keys, point_seeds(study, label), &absolute(&study.opts.mdpipe));
    spec
}

/// The base of the `{seed}` of a design's points: the study's seed and the design's label.
fn point_seeds(study: &Study<'_>, label: &str) -> u64 {
    execute::point_seed_base(study.opts.seed, label)
}

/// Runs `simulator` at every point of the design in `dir` that has no run
/// yet (an earlier attempt's or the design's Slurm array's are kept),
/// through the run's executor; failed points are listed and left out.
pub(super) fn run_design(
    study: &Study<'_>,
    dir: &Path,
    simulator: &SimulatorSpec,
    label: &str,
) -> Result<execute::ExecutionReport> {
    let runs = dir.join("runs");
    std::fs::create_dir_all(&runs)?;
    std::fs::copy(dir.join("design.parquet"), runs.join("design.parquet"))?;
    let design = dir.join("design.parquet");
    let rows = crate::engine::design::read_points(&design)?;
    let ids: Vec<i64> = rows.iter().map(|(id, _)| *id).collect();
    let span = crate::engine::design::span_of(&ids);
    let points = rows
        .into_iter()
        .map(|(id, values)| execute::Point {
            id,
            param_file: crate::engine::design::parameter_file(dir, id, span),
            values,
        })
        .collect();
    let job = execute::Job {
        spec: simulator,
        workdir: dir.to_path_buf(),
        design,
        runs: runs.clone(),
        points,
        label: label.into(),
        mdpipe: study.opts.mdpipe.clone(),
        seed: point_seeds(study, label),
    };
    let report = execute::run(&job, study.opts.executor, study.opts.show_progress)?;
    crate::base::messages::say!(
        "  {}: {} points ({} had their run, {} ran, {} after a retry, {} failed) in {:.1} s",
        runs.display(),
        report.points,
        report.already_done,
        report.succeeded - report.already_done,
        report.retried.len(),
        report.failed.len(),
        report.seconds
    );
    if !report.failed.is_empty() {
        report.print_failures();
        let ids: Vec<i64> = report.failed.iter().map(|f| f.id).collect();
        if ids.len() == report.points {
            bail!(
                "every one of the {} points of the {label} failed; see {}",
                ids.len(),
                execute::ExecutionReport::path(&runs).display()
            );
        }
        crate::base::messages::say!(
            "  warning: {} of {} points of the {label} failed and are left out (never averaged in): {ids:?}; see {}",
            ids.len(),
            report.points,
            execute::ExecutionReport::path(&runs).display()
        );
    }
    Ok(report)
}

/// Ingests one design's runs into a training table of the study's observables.
pub(super) fn ingest_design(study: &Study<'_>, dir: &Path, out: &Path) -> Result<()> {
    let keep = study.all_observables();
    let (mut ingested, design_df) =
        reader(study.simulator(false)?.output).read(&dir.join("runs"), Some(&dir.join("design.parquet")))?;
    ingested.rows.retain(|r| keep.contains(&r.observable));
    let dropped = drop_incomplete_points(&mut ingested.rows);
    for (id, what) in &dropped {
        crate::base::messages::say!("  design point {id} left out: {what} undefined (a failed v_n{{2}} measurement, listed in the ingest report)");
    }
    let flagged: Vec<i64> =
        ingested.report.points.iter().filter(|p| p.flagged.is_some()).map(|p| p.design_id).collect();
    if !flagged.is_empty() {
        crate::base::messages::say!("  design points flagged by ingest and left out: {flagged:?}");
    }
    if !ingested.report.missing_points.is_empty() {
        crate::base::messages::say!(
            "  warning: design points without a run (failed, see runs/execution.json) left out of {}: {:?}",
            out.display(),
            ingested.report.missing_points
        );
    }
    let report = crate::engine::ingest::write(&ingested, design_df.as_ref(), out)?;
    let points: std::collections::BTreeSet<i64> = ingested.rows.iter().map(|r| r.design_id).collect();
    crate::base::messages::say!(
        "  {}: {} points ({} left out); report {}",
        out.display(),
        points.len(),
        dropped.len() + flagged.len(),
        report.display()
    );
    Ok(())
}

/// The reader of a simulator's output format.
fn reader(output: OutputKind) -> Box<dyn RunsReader> {
    match output {
        OutputKind::IebeMusic => Box::new(IebeMusicRuns(IngestSettings::default())),
        OutputKind::Table | OutputKind::Exit => Box::new(TableRuns),
    }
}

/// Removes design points that lack any output another point has (an undefined
/// v_n{2} bin), since the emulator needs every output at every point. Returns
/// the points removed with what they lacked.
fn drop_incomplete_points(rows: &mut Vec<crate::engine::ingest::IngestedRow>) -> Vec<(i64, String)> {
    use std::collections::{BTreeMap, BTreeSet};
    let key = |r: &crate::engine::ingest::IngestedRow| format!("{}[{}]", r.observable, r.x);
    let all: BTreeSet<String> = rows.iter().map(key).collect();
    let mut have: BTreeMap<i64, BTreeSet<String>> = BTreeMap::new();
    for r in rows.iter() {
        have.entry(r.design_id).or_default().insert(key(r));
    }
    let dropped: Vec<(i64, String)> = have
        .iter()
        .filter(|(_, h)| h.len() < all.len())
        .map(|(id, h)| (*id, all.difference(h).cloned().collect::<Vec<_>>().join(", ")))
        .collect();
    rows.retain(|r| !dropped.iter().any(|(id, _)| *id == r.design_id));
    dropped
}
