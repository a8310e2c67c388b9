//! Analysis configuration (`pipeline/*.toml`) as plain data.
//!
//! This module only parses TOML: tables that belong to one stage or one model
//! family stay raw ([`toml::Table`]) and are decoded by their owner (`[model]`,
//! `[truth]` and `[[candidates]]` by the model family, `[sampler]` by
//! `calibrate`, `[emulator]` by `emulator`, `[run]` by the study runner), each
//! with errors that name this file and the table.

use super::error::ConfigError;
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub name: String,
    /// `kind = "<family>"` and that family's settings.
    pub model: toml::Table,
    pub data: DataConfig,
    /// Calibration parameters θ with uniform prior bounds; a model with
    /// none (every constant known) is calibrated in its discrepancy alone.
    #[serde(default)]
    pub parameters: BTreeMap<String, ParamSpec>,
    #[serde(default)]
    pub discrepancy: DiscrepancyConfig,
    /// Sampler choice and settings, decoded by `calibrate`.
    #[serde(default)]
    pub sampler: toml::Table,
    #[serde(default)]
    pub predictions: PredictionConfig,
    /// Emulator training settings, when this config also drives `train-emulator`.
    pub emulator: Option<toml::Table>,
    /// The process that made mock data (`kind = "<family>"` and its settings).
    pub truth: Option<toml::Table>,
    /// The whole study for `mdpipe run`, decoded by the study runner.
    pub run: Option<toml::Table>,
    /// Model variants `mdpipe diagnose` weighs, decoded by the model family.
    #[serde(default)]
    pub candidates: Vec<toml::Table>,
    /// Where the file was read from; relative paths resolve against its folder.
    #[serde(skip)]
    pub path: PathBuf,
    /// SHA-256 of the file's bytes, for provenance.
    #[serde(skip)]
    pub hash: String,
    /// SHA-256 of what a fit can depend on: the file less `[run]` (how a
    /// study is run; the observables, kernels and data it picks enter a
    /// fit's key by themselves) and `[[candidates]]` (each candidate's
    /// fits key on its own model and prior). A candidate added, or
    /// `[run] verify` switched, leaves the other fits' keys as they were.
    #[serde(skip)]
    pub fit_hash: String,
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// Measurements file (CSV, Parquet, or HEPData YAML: a table file or a
    /// record's submission.yaml), relative to the config file.
    pub measurements: PathBuf,
    /// Observables to calibrate on; all of the model's by default.
    pub observables: Option<Vec<String>>,
    /// Covariance of the measurements beyond their errors (`base::covariance`), relative to the config.
    #[serde(default)]
    pub covariance: Option<PathBuf>,
    /// Whether the likelihood carries correlations between observables.
    #[serde(default)]
    pub between_observables: BetweenObservables,
    /// With HEPData YAML measurements: which tables, x, how the systematics
    /// correlate, observable names (`base::hepdata`).
    #[serde(default)]
    pub hepdata: super::hepdata::HepdataOptions,
    /// How far each systematic source is correlated, by name: a table's
    /// `sys:<name>` column or a HEPData error label (`base::systematics`):
    /// "table" (the default), "all", or a correlation length in x's units.
    #[serde(default)]
    pub systematics: BTreeMap<String, super::systematics::Scope>,
}

/// How the likelihood treats correlations between observables.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BetweenObservables {
    /// Joint when something links them: covariance entries between two
    /// observables, or a model whose own covariance spans them (an emulator).
    #[default]
    Auto,
    /// One Gaussian over every point, always.
    Joint,
    /// One independent block per observable: faster (a move of one
    /// observable's δ costs one block), and blind to such correlations.
    Independent,
}

#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ParamSpec {
    pub min: f64,
    pub max: f64,
    /// True value, when known (mock data); drawn in plots, never used in fits.
    pub truth: Option<f64>,
    /// Units for tables and plots.
    #[serde(default)]
    pub units: String,
}

impl ParamSpec {
    /// Checks `min < max`, both finite; `what` names the table for the message.
    pub fn check(&self, what: &str) -> Result<()> {
        if !(self.min.is_finite() && self.max.is_finite() && self.min < self.max) {
            bail!("{what}: bounds must satisfy min < max, got min = {}, max = {}", self.min, self.max);
        }
        Ok(())
    }
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiscrepancyConfig {
    /// none, I or II.
    pub kernel: crate::base::choices::Kernel,
    /// Uniform prior bounds per hyperparameter name (cbar, ell, r, s); the
    /// paper's (0, 10) for each when not given.
    #[serde(default = "paper_bounds")]
    pub bounds: BTreeMap<String, [f64; 2]>,
    /// Per observable, how x becomes the kernel's input (default: x over the
    /// largest |x| measured for that observable, `KernelInput::scaled_to`).
    #[serde(default)]
    pub inputs: BTreeMap<String, KernelInput>,
}

/// The paper's hyperparameter priors: (0, 10) for c̄, ℓ, r and s.
fn paper_bounds() -> BTreeMap<String, [f64; 2]> {
    let b = [0.0, 10.0];
    [("cbar", b), ("ell", b), ("r", b), ("s", b)].into_iter().map(|(k, v)| (k.to_string(), v)).collect()
}

impl Default for DiscrepancyConfig {
    fn default() -> Self {
        DiscrepancyConfig { kernel: crate::base::choices::Kernel::II, bounds: paper_bounds(), inputs: BTreeMap::new() }
    }
}

/// The discrepancy kernel's input for one observable, `(x + shift) / scale`.
/// The `(x·x')^r` factor needs it ≥ 0, so signed inputs (rapidity, a centred
/// variable) are shifted. Unless the config says otherwise each observable's
/// x is divided by the largest |x| measured (`scaled_to`), so the input lies
/// in [0, 1] whatever the units: `(x x')^r` stays at most 1 for any r of the
/// prior, and ℓ is in units of the measured range. The paper's convention,
/// x itself, is `{ scale = 1.0 }`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct KernelInput {
    #[serde(default)]
    pub shift: f64,
    #[serde(default = "one")]
    pub scale: f64,
}

fn one() -> f64 {
    1.0
}

impl Default for KernelInput {
    fn default() -> Self {
        KernelInput { shift: 0.0, scale: 1.0 }
    }
}

impl KernelInput {
    /// The default for an observable measured at `x`: x / max |x| (x itself
    /// when every x is 0 or none is finite).
    pub fn scaled_to(x: &[f64]) -> KernelInput {
        let largest = x.iter().filter(|v| v.is_finite()).fold(0.0f64, |m, v| m.max(v.abs()));
        KernelInput { shift: 0.0, scale: if largest > 0.0 { largest } else { 1.0 } }
    }

    pub fn apply(&self, x: f64) -> f64 {
        (x + self.shift) / self.scale
    }
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictionConfig {
    /// Grid for prediction bands; by default it runs from 0 (or the smallest
    /// x measured, when that is negative) to 1.5 × the largest x measured, to
    /// show extrapolation as the paper does.
    pub x_min: Option<f64>,
    pub x_max: Option<f64>,
    pub points: usize,
    /// Posterior draws used for the bands.
    pub draws: usize,
}

impl Default for PredictionConfig {
    fn default() -> Self {
        PredictionConfig { x_min: None, x_max: None, points: 41, draws: 1000 }
    }
}

/// The hash of `text` as a table, without the tables that cannot change a fit.
fn fit_hash(text: &str) -> std::result::Result<String, toml::de::Error> {
    let mut table: toml::Table = toml::from_str(text)?;
    table.remove("run");
    table.remove("candidates");
    Ok(crate::base::artifacts::sha256_hex(table.to_string().as_bytes()))
}

impl Config {
    pub fn load(path: &Path) -> Result<Config> {
        let bytes = std::fs::read(path).with_context(|| format!("reading config {}", path.display()))?;
        let text = String::from_utf8(bytes.clone()).with_context(|| format!("{}: not UTF-8", path.display()))?;
        let mut cfg: Config = toml::from_str(&text).map_err(|e| ConfigError::new(path, "", e))?;
        cfg.path = path.to_path_buf();
        cfg.hash = crate::base::artifacts::sha256_hex(&bytes);
        cfg.fit_hash = fit_hash(&text).map_err(|e| ConfigError::new(path, "", e))?;
        cfg.validate()?;
        Ok(cfg)
    }

    fn validate(&self) -> Result<()> {
        let bad = |place: String, problem: String| Err(ConfigError::new(&self.path, place, problem).into());
        for (name, p) in &self.parameters {
            if !(p.min.is_finite() && p.max.is_finite() && p.min < p.max) {
                let problem = format!("bounds must satisfy min < max, got min = {}, max = {}", p.min, p.max);
                return bad(format!("[parameters.{name}]"), problem);
            }
        }
        for (name, b) in &self.discrepancy.bounds {
            if !(b[0].is_finite() && b[1].is_finite() && b[0] < b[1]) {
                let problem = format!("bounds must satisfy min < max, got [{}, {}]", b[0], b[1]);
                return bad(format!("[discrepancy.bounds] {name}"), problem);
            }
        }
        for (name, t) in &self.discrepancy.inputs {
            if !(t.shift.is_finite() && t.scale.is_finite() && t.scale > 0.0) {
                let problem =
                    format!("need a finite shift and a positive scale, got shift = {}, scale = {}", t.shift, t.scale);
                return bad(format!("[discrepancy.inputs.{name}]"), problem);
            }
        }
        let p = &self.predictions;
        let x_min = p.x_min.unwrap_or(f64::NEG_INFINITY);
        if p.points < 2
            || p.draws == 0
            || p.x_min.is_some_and(|m| !m.is_finite())
            || p.x_max.is_some_and(|m| !(m.is_finite() && m > x_min))
        {
            let problem = format!("need points >= 2, draws >= 1 and finite x_min < x_max, got points = {}, draws = {}, x_min = {:?}, x_max = {:?}", p.points, p.draws, p.x_min, p.x_max);
            return bad("[predictions]".into(), problem);
        }
        self.model_kind()?;
        Ok(())
    }

    /// The `kind` of a raw table (`[model]`, `[truth]`), named in errors by `table`.
    pub fn kind_of<'a>(&self, table: &'a toml::Table, name: &str) -> Result<&'a str> {
        table.get("kind").and_then(|k| k.as_str()).ok_or_else(|| {
            ConfigError::new(&self.path, format_args!("[{name}]"), "needs a `kind` (a model family's name)").into()
        })
    }

    /// `[model] kind`.
    pub fn model_kind(&self) -> Result<&str> {
        self.kind_of(&self.model, "model")
    }

    /// Decodes a raw table into `T`, naming this file and the table in errors.
    pub fn decode<T: serde::de::DeserializeOwned>(&self, table: &toml::Table, name: &str) -> Result<T> {
        table.clone().try_into().map_err(|e| ConfigError::new(&self.path, format_args!("[{name}]"), e).into())
    }

    /// As `decode`, for a family's table (`[model]`, `[truth]`): its `kind`,
    /// which chose the family, is dropped first so `T` may deny unknown fields.
    pub fn decode_family_table<T: serde::de::DeserializeOwned>(&self, table: &toml::Table, name: &str) -> Result<T> {
        let mut t = table.clone();
        t.remove("kind");
        self.decode(&t, name)
    }

    /// Resolves a path from the config against the config's folder.
    pub fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.path.parent().unwrap_or(Path::new(".")).join(p)
        }
    }
}
