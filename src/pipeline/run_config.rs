//! The `[run]` table of an analysis config, checked before any stage runs.

use crate::base::choices::Kernel;
use crate::base::config::Config;
use crate::engine::execute::{OutputKind, SimulatorSpec};
use crate::systems::heavy_ion::{self, DeltaF};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::Path;
use std::path::PathBuf;

/// The `[run]` table of an analysis config.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Parameter-space spec (`design/*.toml`), relative to the config.
    pub design: PathBuf,
    /// Where the study writes, relative to the config (default:
    /// `outputs/<name>` in the current folder; `--out` overrides it).
    #[serde(default)]
    pub out: Option<PathBuf>,
    /// Training design points and held-out validation points.
    pub points: usize,
    pub validation_points: usize,
    /// The simulator run at each design point. Without it, the heavy-ion
    /// stand-in (`mdpipe simulate heavy-ion`) with `events` and `model_delta_f`.
    #[serde(default)]
    pub simulator: Option<SimulatorSpec>,
    /// Events per design point of the stand-in's model runs, and Cooper–Frye samples per event.
    #[serde(default)]
    pub events: Option<usize>,
    #[serde(default = "default_oversample")]
    pub oversample: usize,
    /// Particlization of the model runs: none (f_eq), as in the paper.
    #[serde(default = "default_model_delta_f")]
    pub model_delta_f: String,
    /// Mock data: the stand-in at the parameters' `truth` values with this δf.
    /// Without it, the calibrations use the config's `[data] measurements`.
    #[serde(default)]
    pub mock_delta_f: Option<String>,
    /// Stand-in parameters of the mock data when they are not the calibration
    /// parameters' truth values (a constant η/s = 0.1 behind a kink model:
    /// `{ eta_s = 0.1, e_sw = 0.2 }`).
    #[serde(default)]
    pub mock_truth: Option<BTreeMap<String, f64>>,
    #[serde(default)]
    pub mock_events: Option<usize>,
    /// Observable sets to calibrate on, in order (each should extend the last).
    pub observable_sets: Vec<Vec<String>>,
    /// Discrepancy kernels: none, I, II.
    #[serde(default = "default_kernels")]
    pub kernels: Vec<Kernel>,
    /// Wall-time limit of one calibration case when cases go out as Slurm array tasks.
    #[serde(default = "default_calibration_time_limit")]
    pub calibration_time_limit: String,
    /// Diagnose candidates from the stand-in's library, by name.
    #[serde(default)]
    pub candidates: Vec<String>,
    /// Design points of each candidate's variant runs (default: `points`).
    #[serde(default)]
    pub candidate_points: Option<usize>,
    /// Adaptive design after the emulator stage (`[run.refine]`).
    #[serde(default)]
    pub refine: Option<RefineConfig>,
}

fn default_oversample() -> usize {
    heavy_ion::events::DEFAULT_OVERSAMPLE
}
fn default_model_delta_f() -> String {
    "none".into()
}
fn default_calibration_time_limit() -> String {
    "12h".into()
}
fn default_kernels() -> Vec<Kernel> {
    vec![Kernel::None, Kernel::I, Kernel::II]
}

impl RunConfig {
    /// Checks everything a later stage would trip on, before any stage runs.
    pub(super) fn validate(&self, design_parameters: &[String]) -> Result<()> {
        for (field, n) in [
            ("points", Some(self.points)),
            ("validation_points", Some(self.validation_points)),
            ("events", self.events),
            ("mock_events", self.mock_events),
            ("oversample", Some(self.oversample)),
        ] {
            if n == Some(0) {
                bail!("{field} must be at least 1");
            }
        }
        match &self.simulator {
            Some(spec) if spec.output == OutputKind::Exit => bail!(
                "[run.simulator] output: the simulate stage reads what points leave: use \"iebe-music\" or \"table\""
            ),
            Some(spec) => spec.validate(design_parameters).context("[run.simulator]")?,
            None if self.events.is_none() => {
                bail!("give `events` (the stand-in's events per point) or a [run.simulator] table")
            }
            None => {}
        }
        self.model_delta_f.parse::<DeltaF>().context("model_delta_f")?;
        if let Some(m) = &self.mock_delta_f {
            m.parse::<DeltaF>().context("mock_delta_f")?;
            if self.mock_events.is_none() {
                bail!("mock_delta_f needs mock_events (the events of the stand-in's mock data)");
            }
        }
        if self.observable_sets.is_empty() || self.observable_sets.iter().any(|s| s.is_empty()) {
            bail!("observable_sets: give one or more non-empty sets");
        }
        let known: Vec<String> =
            crate::base::paper_table::PAPER_TABLE_OBSERVABLES.iter().map(|(_, name)| name.to_string()).collect();
        for o in self.observable_sets.iter().flatten() {
            if self.simulator.is_none() && !known.contains(o) {
                bail!("observable_sets: unknown observable '{o}' (the stand-in gives {})", known.join(", "));
            }
        }
        if !self.candidates.is_empty() && self.simulator.is_some() {
            bail!("candidates: these name the heavy-ion stand-in's library; with your own simulator declare each candidate as a [[candidates]] table saying how the simulator turns it on (`parameter_file`, `placeholders` or `command`) and its `parameters` (see docs/cluster.md)");
        }
        for c in &self.candidates {
            heavy_ion::candidate(c).context("candidates")?;
        }
        if let Some(r) = &self.refine {
            r.validate()?;
        }
        if self.candidate_points == Some(0) {
            bail!("candidate_points must be at least 1");
        }
        Ok(())
    }
}

/// `command` with `{config_dir}` replaced by the config's folder (quoted,
/// absolute): a study's scripts can sit beside its config and be found from
/// any working folder.
pub(super) fn with_config_dir(command: &str, config: &Config) -> String {
    let dir = config.path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let dir = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    command.replace("{config_dir}", &crate::engine::execute::spec::shell_quote(&dir.display().to_string()))
}

impl RunConfig {
    /// The `[run]` table of `config`, its commands' `{config_dir}` filled in.
    pub(super) fn of(config: &Config, table: &toml::Table) -> Result<RunConfig> {
        let mut run: RunConfig = config.decode(table, "run")?;
        if let Some(s) = run.simulator.as_mut() {
            s.command = with_config_dir(&s.command, config);
        }
        Ok(run)
    }

    /// A study on the stand-in's mock data (with its truth known), rather than on measurements.
    pub fn stand_in_study(&self) -> bool {
        self.mock_delta_f.is_some()
    }

    pub(super) fn output(&self) -> OutputKind {
        self.simulator.as_ref().map_or(OutputKind::IebeMusic, |s| s.output)
    }
}

/// `[run.refine]`.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RefineConfig {
    /// New runs per round.
    pub points_per_round: usize,
    /// The most new runs in all rounds together.
    pub budget: usize,
    /// Posterior draws weighed per round (candidate points and where the error is measured).
    #[serde(default = "default_draws")]
    pub draws: usize,
    /// New runs the diagnose stage may spend on each variant emulator when
    /// the verdict rests on it ("emulator_limited"); 0: none (runs cost).
    #[serde(default)]
    pub variant_budget: usize,
}

fn default_draws() -> usize {
    300
}

impl RefineConfig {
    pub(super) fn validate(&self) -> Result<()> {
        if self.points_per_round == 0 || self.draws < 10 {
            bail!("[run.refine]: points_per_round must be at least 1 and draws at least 10");
        }
        Ok(())
    }
}
