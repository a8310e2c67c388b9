//! The `[run]` table of an analysis config, checked before any stage runs.

use crate::base::choices::Kernel;
use crate::base::config::Config;
use crate::engine::execute::{OutputKind, SimulatorSpec};
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
    /// The simulator run at each design point. Without it, a system's own
    /// (with its table, `[run.<system>]`).
    #[serde(default)]
    pub simulator: Option<SimulatorSpec>,
    /// Observable sets to calibrate on, in order (each should extend the last).
    pub observable_sets: Vec<Vec<String>>,
    /// Discrepancy kernels: none, I, II.
    #[serde(default = "default_kernels")]
    pub kernels: Vec<Kernel>,
    /// Wall-time limit of one calibration case when cases go out as Slurm array tasks.
    #[serde(default = "default_calibration_time_limit")]
    pub calibration_time_limit: String,
    /// Design points of each candidate's variant runs (default: `points`).
    #[serde(default)]
    pub candidate_points: Option<usize>,
    /// Adaptive design after the emulator stage (`[run.refine]`).
    #[serde(default)]
    pub refine: Option<RefineConfig>,
    /// The diagnose stage's search for physics nobody declared: true
    /// searches always (as `diagnose --discover`), false never (and a study
    /// with no candidates then has no diagnose stage); unset, `diagnose`'s
    /// default, which searches when no candidate explains a mismatch.
    #[serde(default)]
    pub discover: Option<bool>,
    /// Whether the diagnose stage runs the final emulated fit's posterior
    /// median and a few draws through the simulator (`diagnose/verify.json`).
    /// Off for a simulator too costly for five more runs per study.
    #[serde(default = "default_verify")]
    pub verify: bool,
    /// The systems' own tables (`[run.<system>]`), by name: each is decoded
    /// and checked by its system, never here.
    #[serde(skip)]
    pub systems: BTreeMap<String, toml::Table>,
}

/// The tables of `[run]` that are its own; any other table is a system's.
const OWN_TABLES: [&str; 2] = ["simulator", "refine"];

fn default_calibration_time_limit() -> String {
    "12h".into()
}
fn default_verify() -> bool {
    true
}
fn default_kernels() -> Vec<Kernel> {
    vec![Kernel::None, Kernel::I, Kernel::II]
}

impl RunConfig {
    /// Checks everything a later stage would trip on, before any stage runs.
    pub(super) fn validate(&self, design_parameters: &[String]) -> Result<()> {
        for (field, n) in [("points", Some(self.points)), ("validation_points", Some(self.validation_points))] {
            if n == Some(0) {
                bail!("{field} must be at least 1");
            }
        }
        match &self.simulator {
            Some(spec) if spec.output == OutputKind::Exit => bail!(
                "[run.simulator] output: the simulate stage reads what points leave: use \"iebe-music\" or \"table\""
            ),
            Some(spec) => spec.validate(design_parameters).context("[run.simulator]")?,
            None => {}
        }
        if self.observable_sets.is_empty() || self.observable_sets.iter().any(|s| s.is_empty()) {
            bail!("observable_sets: give one or more non-empty sets");
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
    /// The `[run]` table of `config`: its own keys decoded (an unknown one is
    /// refused), its other tables kept for their systems.
    pub fn decode(config: &Config, table: &toml::Table) -> Result<RunConfig> {
        let mut own = table.clone();
        let mut systems = BTreeMap::new();
        for (key, value) in table {
            if let (toml::Value::Table(t), false) = (value, OWN_TABLES.contains(&key.as_str())) {
                own.remove(key);
                systems.insert(key.clone(), t.clone());
            }
        }
        let mut run: RunConfig = config.decode(&own, "run")?;
        run.systems = systems;
        Ok(run)
    }

    /// The `[run]` table of `config`, its commands' `{config_dir}` filled in.
    pub(super) fn of(config: &Config, table: &toml::Table) -> Result<RunConfig> {
        let mut run = RunConfig::decode(config, table)?;
        if let Some(s) = run.simulator.as_mut() {
            s.command = with_config_dir(&s.command, config);
        }
        Ok(run)
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
