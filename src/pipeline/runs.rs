//! The design, simulate, ingest and emulator stages: a design over θ, the
//! simulator run at each point through `engine::execute`, the runs read into
//! a training table, and the emulator trained and validated on them.

use super::stages::*;
use crate::base::artifacts::{self};
use crate::engine::design::DesignSpec;
use crate::engine::execute::{self, OutputKind, SimulatorSpec};
use crate::engine::ingest::{tables::TableRuns, IebeMusicRuns, IngestSettings, RunsReader};
use anyhow::{bail, Context, Result};
use std::path::Path;

impl Study<'_> {
    pub(super) fn design(&self, _keys: &Keys) -> Result<()> {
        let spec_path = self.config.resolve(&self.run.design);
        let bytes = std::fs::read(&spec_path).with_context(|| format!("reading {}", spec_path.display()))?;
        let spec = DesignSpec::load(&spec_path)?;
        let hash = artifacts::sha256_hex(&bytes);
        for (dir, n, seed, label) in [
            (self.paths.design(), self.run.points, self.opts.seed, "design"),
            (
                self.paths.validation_design(),
                self.run.validation_points,
                self.opts.seed.wrapping_add(7919),
                "validation design",
            ),
        ] {
            let simulator = self.simulator(label == "validation design")?;
            self.write_design_for(&spec, &simulator, label, &hash, n, seed, &dir)?;
        }
        Ok(())
    }

    /// Writes a design of `n` points into `dir` whose Slurm array script
    /// (`submit.slurm`) runs `simulator` at each point as the simulate stage
    /// would, with the same `{seed}`s.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn write_design_for(
        &self,
        spec: &DesignSpec,
        simulator: &SimulatorSpec,
        label: &str,
        spec_hash: &str,
        n: usize,
        seed: u64,
        dir: &Path,
    ) -> Result<()> {
        let spec = self.with_array_command(spec, simulator, label);
        // Runs of an earlier design belong to other points: the simulate stage
        // keeps unstamped point folders (SLURM's), so they must not survive here.
        let runs = dir.join("runs");
        if runs.exists() {
            std::fs::remove_dir_all(&runs)
                .with_context(|| format!("removing runs of the previous design {}", runs.display()))?;
            println!("  removed {} (runs of the previous design)", runs.display());
        }
        let q = crate::engine::design::write_design(&spec, spec_hash, n, seed, dir)?;
        println!("  {}: {} points, minimum distance {:.4}", dir.display(), q.points, q.min_distance);
        Ok(())
    }

    pub(super) fn simulate(&self, keys: &Keys) -> Result<()> {
        // Settings changed since the last run: its runs are not these. Forced
        // with the same settings, finished points are kept and only the
        // failed ones run again, with fresh attempts.
        let previous = read_stamp(&self.paths.stamp("simulate"));
        let stale = previous.as_ref().is_some_and(|s| s.key != keys.this);
        let forced = previous.is_some() && !stale;
        for (dir, label) in [(self.paths.design(), "design"), (self.paths.validation_design(), "validation design")] {
            let runs = dir.join("runs");
            if stale && runs.exists() {
                std::fs::remove_dir_all(&runs).with_context(|| format!("removing outdated runs {}", runs.display()))?;
            }
            let attempts = runs.join(".attempts");
            if forced && attempts.exists() {
                std::fs::remove_dir_all(&attempts)
                    .with_context(|| format!("removing the previous attempts {}", attempts.display()))?;
            }
            let simulator = self.simulator(label == "validation design")?;
            self.run_design(&dir, &simulator, label)?;
        }
        Ok(())
    }

    /// Runs `simulator` at every point of the design in `dir` that has no run
    /// yet (an earlier attempt's or the design's Slurm array's are kept),
    /// through the run's executor; failed points are listed and left out.
    pub(super) fn run_design(
        &self,
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
            mdpipe: self.opts.mdpipe.clone(),
            seed: self.point_seeds(label),
        };
        let report = execute::run(&job, self.opts.executor, self.opts.show_progress)?;
        println!(
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
            println!(
                "  warning: {} of {} points of the {label} failed and are left out (never averaged in): {ids:?}; see {}",
                ids.len(),
                report.points,
                execute::ExecutionReport::path(&runs).display()
            );
        }
        Ok(report)
    }

    /// `spec` whose Slurm array script runs `simulator` as the executors do.
    pub(super) fn with_array_command(&self, spec: &DesignSpec, simulator: &SimulatorSpec, label: &str) -> DesignSpec {
        let mut spec = spec.clone();
        let keys: Vec<(String, String)> =
            spec.parameters.iter().map(|p| (p.name.clone(), p.file_key().to_string())).collect();
        spec.slurm.command = simulator.array_command(&keys, self.point_seeds(label), &absolute(&self.opts.mdpipe));
        spec
    }

    /// The base of the `{seed}` of a design's points: the study's seed and the design's label.
    pub(super) fn point_seeds(&self, label: &str) -> u64 {
        execute::point_seed_base(self.opts.seed, label)
    }

    /// What the simulate stage runs: `[run.simulator]`, or the stand-in as one
    /// instance of it (the same command line as the design's SLURM array).
    pub(super) fn simulator(&self, validation: bool) -> Result<SimulatorSpec> {
        if let Some(s) = &self.run.simulator {
            return Ok(s.clone());
        }
        self.stand_in_simulator(&self.run.model_delta_f, self.runs_seed(validation))
    }

    pub(super) fn ingest(&self, _keys: &Keys) -> Result<()> {
        for (dir, out) in
            [(self.paths.design(), self.paths.training()), (self.paths.validation_design(), self.paths.validation())]
        {
            self.ingest_design(&dir, &out)?;
        }
        Ok(())
    }

    /// Ingests one design's runs into a training table of the study's observables.
    pub(super) fn ingest_design(&self, dir: &Path, out: &Path) -> Result<()> {
        let keep = self.all_observables();
        let (mut ingested, design_df) =
            reader(self.run.output()).read(&dir.join("runs"), Some(&dir.join("design.parquet")))?;
        ingested.rows.retain(|r| keep.contains(&r.observable));
        let dropped = drop_incomplete_points(&mut ingested.rows);
        for (id, what) in &dropped {
            println!("  design point {id} left out: {what} undefined (a failed v_n{{2}} measurement, listed in the ingest report)");
        }
        let flagged: Vec<i64> =
            ingested.report.points.iter().filter(|p| p.flagged.is_some()).map(|p| p.design_id).collect();
        if !flagged.is_empty() {
            println!("  design points flagged by ingest and left out: {flagged:?}");
        }
        if !ingested.report.missing_points.is_empty() {
            println!(
                "  warning: design points without a run (failed, see runs/execution.json) left out of {}: {:?}",
                out.display(),
                ingested.report.missing_points
            );
        }
        let report = crate::engine::ingest::write(&ingested, design_df.as_ref(), out)?;
        let points: std::collections::BTreeSet<i64> = ingested.rows.iter().map(|r| r.design_id).collect();
        println!(
            "  {}: {} points ({} left out); report {}",
            out.display(),
            points.len(),
            dropped.len() + flagged.len(),
            report.display()
        );
        Ok(())
    }

    pub(super) fn emulator(&self, _keys: &Keys) -> Result<()> {
        if self.config.emulator.is_none() {
            bail!("{}: the emulator stage needs an [emulator] table", self.config.path.display());
        }
        let (_, r) = crate::engine::emulator::train_and_save(
            &self.config.path,
            &self.paths.training(),
            None,
            &self.paths.emulator(),
            self.opts.seed,
        )?;
        println!(
            "  {} points x {} outputs -> {} components in {:.1} s",
            r.n_points, r.n_outputs, r.n_components, r.training_seconds
        );
        let v = crate::engine::emulator::validate::run(
            &self.paths.emulator(),
            Some(&self.paths.validation()),
            5,
            self.opts.seed,
        )?;
        if let Some(h) = &v.holdout {
            crate::engine::emulator::validate::print("held-out design", h);
        }
        Ok(())
    }
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
pub(super) fn drop_incomplete_points(rows: &mut Vec<crate::engine::ingest::IngestedRow>) -> Vec<(i64, String)> {
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
