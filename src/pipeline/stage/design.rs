//! The design stage: a design over θ for the training runs and another for
//! the validation runs, each with its parameter files and the Slurm array
//! script that runs the simulator at each point as the simulate stage would.

use super::{always, Keys, StageDef};
use crate::engine::design::DesignSpec;
use crate::engine::execute::{self, SimulatorSpec};
use crate::pipeline::study::{absolute, Study};
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

pub(super) const STAGE: StageDef =
    StageDef { name: "design", rank: 10, upstream: &[], present: always, outputs, settings, body: design };

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    Ok(vec![study.paths.design().join("design.parquet"), study.paths.validation_design().join("design.parquet")])
}

/// The design stage also writes the array script, which carries the simulate settings.
fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    let run = study.run;
    Ok(
        serde_json::json!({"spec": study.design_spec_hash()?, "points": run.points, "validation_points": run.validation_points, "seed": study.opts.seed,
        "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f}),
    )
}

fn design(study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
    let spec_path = study.config.resolve(&study.run.design);
    let spec = DesignSpec::load(&spec_path)?;
    let hash = study.design_spec_hash()?;
    for (dir, n, seed, label) in [
        (study.paths.design(), study.run.points, study.opts.seed, "design"),
        (
            study.paths.validation_design(),
            study.run.validation_points,
            study.opts.seed.wrapping_add(7919),
            "validation design",
        ),
    ] {
        let simulator = study.simulator(label == "validation design")?;
        study.write_design_for(&spec, &simulator, label, &hash, n, seed, &dir)?;
    }
    Ok(())
}

impl Study<'_> {
    /// Writes a design of `n` points into `dir` whose Slurm array script
    /// (`submit.slurm`) runs `simulator` at each point as the simulate stage
    /// would, with the same `{seed}`s.
    #[allow(clippy::too_many_arguments)]
    pub(in crate::pipeline) fn write_design_for(
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
            crate::engine::execute::attempt::remove_after_attempts(&runs)
                .with_context(|| format!("removing runs of the previous design {}", runs.display()))?;
            crate::base::messages::say!("  removed {} (runs of the previous design)", runs.display());
        }
        let q = crate::engine::design::write_design(&spec, spec_hash, n, seed, dir)?;
        crate::base::messages::say!("  {}: {} points, minimum distance {:.4}", dir.display(), q.points, q.min_distance);
        Ok(())
    }

    /// `spec` whose Slurm array script runs `simulator` as the executors do.
    pub(in crate::pipeline) fn with_array_command(
        &self,
        spec: &DesignSpec,
        simulator: &SimulatorSpec,
        label: &str,
    ) -> DesignSpec {
        let mut spec = spec.clone();
        let keys: Vec<(String, String)> =
            spec.parameters.iter().map(|p| (p.name.clone(), p.file_key().to_string())).collect();
        spec.slurm.command = simulator.array_command(&keys, self.point_seeds(label), &absolute(&self.opts.mdpipe));
        spec
    }

    /// The base of the `{seed}` of a design's points: the study's seed and the design's label.
    pub(in crate::pipeline) fn point_seeds(&self, label: &str) -> u64 {
        execute::point_seed_base(self.opts.seed, label)
    }
}
