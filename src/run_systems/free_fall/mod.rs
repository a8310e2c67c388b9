//! A second system for `mdpipe run`, built only for the tests: a falling
//! body whose speed a shell command computes, v(t) = g t, and mock data from
//! its truth with an optional linear drag the model leaves out. It shows what
//! adding a system takes: this folder and one line in a list of systems
//! (`app::systems()` for the command line; the test below makes its own).
//! It uses every kind of hook: its own `[run.free_fall]` table, decoded and
//! checked here; its simulator; what it adds to the design's and simulate's
//! keys; stages of its own, with ids of its own (mock data before the
//! stages that read the data, and a probe after the calibrations); the
//! study's data; and its units.

use crate::base::artifacts;
use crate::engine::execute::{OutputKind, SimulatorSpec};
use crate::engine::model::Units;
use crate::pipeline::run_config::RunConfig;
use crate::pipeline::stage::{Keys, Presence, Stage, StageId};
use crate::pipeline::study::{Study, StudyData, StudySystem};
use crate::pipeline::system::{System, SystemStage};
use anyhow::{bail, Context, Result};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::path::PathBuf;

const TABLE: &str = "free_fall";

/// `[run.free_fall]`.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct FreeFallRun {
    /// Speeds sampled at t = t_max/samples, …, t_max.
    samples: usize,
    /// s.
    t_max: f64,
    /// Mock data's error on each speed (m/s); without it the config's measurements are used.
    mock_error: Option<f64>,
    /// The drag rate of the mock data (1/s): v = g/k (1 − e^{−k t}).
    #[serde(default)]
    mock_drag: f64,
}

impl FreeFallRun {
    fn of(run: &RunConfig) -> Result<Option<FreeFallRun>> {
        let Some(table) = run.systems.get(TABLE) else { return Ok(None) };
        toml::Value::Table(table.clone()).try_into().map(Some).map_err(|e| anyhow::anyhow!("[run.{TABLE}]: {e}"))
    }

    fn times(&self) -> Vec<f64> {
        (1..=self.samples).map(|i| self.t_max * i as f64 / self.samples as f64).collect()
    }
}

pub(super) struct FreeFall;

impl StudySystem for FreeFall {
    fn run_table(&self) -> Option<&'static str> {
        Some(TABLE)
    }
    fn validate(&self, run: &RunConfig) -> Result<()> {
        let Some(fall) = FreeFallRun::of(run)? else { return Ok(()) };
        if fall.samples < 2 || !(fall.t_max > 0.0) || fall.mock_error.is_some_and(|e| !(e > 0.0)) {
            bail!("[run.{TABLE}]: samples must be at least 2, and t_max and mock_error positive");
        }
        Ok(())
    }
    fn key_settings(&self, study: &Study<'_>, stage: StageId) -> serde_json::Map<String, serde_json::Value> {
        let mut settings = serde_json::Map::new();
        if let (Ok(Some(fall)), StageId::DESIGN | StageId::SIMULATE) = (FreeFallRun::of(study.run), stage) {
            settings.insert("free_fall_times".into(), fall.times().into());
        }
        settings
    }
    fn default_simulator(&self, study: &Study<'_>, _validation: bool) -> Result<Option<SimulatorSpec>> {
        let Some(fall) = FreeFallRun::of(study.run)? else { return Ok(None) };
        let command = format!(
            "mkdir -p {{point}} && awk -v g={{g}} -v n={} -v T={} 'BEGIN {{ print \"observable,x,value\"; for (i = 1; i <= n; i++) {{ t = T * i / n; printf \"v,%.17g,%.17g\\n\", t, g * t }} }}' > {{point}}/outputs.csv",
            fall.samples, fall.t_max
        );
        Ok(Some(SimulatorSpec {
            command,
            placeholders: Default::default(),
            output: OutputKind::Table,
            time_limit: "1m".into(),
            retries: 0,
            parallel: None,
            slurm: Default::default(),
        }))
    }
    fn data(&self, study: &Study<'_>) -> Option<StudyData> {
        mock_study(study).then(|| StudyData { measurements: mock_file(study), covariance: None })
    }
    fn units(&self, study: &Study<'_>) -> Option<Units> {
        let mut units = Units { x: "s".into(), ..Default::default() };
        units.observables.insert("v".into(), "m/s".into());
        units.parameters.insert("g".into(), "m/s²".into());
        FreeFallRun::of(study.run).ok().flatten().map(|_| units)
    }
}

impl System for FreeFall {
    fn stages(&self) -> &'static [SystemStage] {
        &[
            SystemStage {
                stage: &MockFall,
                after: StageId::EMULATOR,
                read_by: &[StageId::REFINE, StageId::CALIBRATE, StageId::DIAGNOSE],
            },
            SystemStage { stage: &Probe, after: StageId::CALIBRATE, read_by: &[] },
        ]
    }
}

fn mock_study(study: &Study<'_>) -> bool {
    FreeFallRun::of(study.run).ok().flatten().is_some_and(|f| f.mock_error.is_some())
}

fn mock_file(study: &Study<'_>) -> PathBuf {
    study.paths.out.join("mock").join("measurements.csv")
}

/// Mock data: the speeds at the truth of g, with drag, and Gaussian errors.
struct MockFall;

impl Stage for MockFall {
    type Settings = (FreeFallRun, f64, u64);
    const ID: StageId = StageId::new("fall_mock");
    const UPSTREAM: &'static [StageId] = &[];
    fn present(&self, study: &Study<'_>) -> Result<Presence> {
        Ok(if mock_study(study) { Presence::Runs } else { Presence::Absent("no mock_error".into()) })
    }
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![mock_file(study)])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Self::Settings> {
        let fall = FreeFallRun::of(study.run)?.context("[run.free_fall]")?;
        let g = study.config.parameters.get("g").and_then(|p| p.truth).context("[parameters.g] truth")?;
        Ok((fall, g, study.opts.seed))
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        let (fall, g, seed) = self.settings(study)?;
        let error = fall.mock_error.unwrap_or_default();
        let noise = Normal::new(0.0, error)?;
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut csv = String::from("observable,x,value,error\n");
        for t in fall.times() {
            let k = fall.mock_drag;
            let v = if k > 0.0 { g / k * (1.0 - (-k * t).exp()) } else { g * t };
            csv.push_str(&format!("v,{t},{},{error}\n", v + noise.sample(&mut rng)));
        }
        artifacts::write_text_atomic(&mock_file(study), &csv)
    }
}

/// A stage after the calibrations that it reads: it writes how many cases
/// ran (OUT/probe.json); the loop keys, skips and stamps it like any other.
struct Probe;

impl Stage for Probe {
    type Settings = Vec<Vec<String>>;
    const ID: StageId = StageId::new("fall_probe");
    const UPSTREAM: &'static [StageId] = &[StageId::CALIBRATE];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![study.paths.out.join("probe.json")])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Self::Settings> {
        Ok(study.run.observable_sets.clone())
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        let cases = study.stored_fits(&study.paths.calibrate()).len();
        artifacts::write_json_atomic(&study.paths.out.join("probe.json"), &serde_json::json!({ "cases": cases }))
    }
}

#[cfg(test)]
mod tests;
