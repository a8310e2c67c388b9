//! Analysis configuration (`pipeline/*.toml`).

use crate::calibrate::ensemble::EnsembleSettings;
use crate::calibrate::smc::SmcSettings;
use crate::gp::DiscrepancyKernel;
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub name: String,
    pub model: ModelConfig,
    pub data: DataConfig,
    /// Calibration parameters θ with uniform prior bounds.
    pub parameters: BTreeMap<String, ParamSpec>,
    #[serde(default)]
    pub discrepancy: DiscrepancyConfig,
    #[serde(default)]
    pub sampler: SamplerConfig,
    #[serde(default)]
    pub predictions: PredictionConfig,
    /// Emulator training settings, when this config also drives `train-emulator`.
    pub emulator: Option<crate::emulator::EmulatorSettings>,
    /// The process that made mock data, drawn as the true curve in predictions.
    pub truth: Option<TruthConfig>,
    /// The whole study for `mdpipe run`: design, runs, emulator, mock data, calibrations.
    pub run: Option<crate::pipeline::RunConfig>,
    /// Model variants `mdpipe diagnose` weighs against an emulated model.
    #[serde(default)]
    pub candidates: Vec<CandidateConfig>,
    /// Where the file was read from; relative paths resolve against its folder.
    #[serde(skip)]
    pub path: PathBuf,
    /// SHA-256 of the file's bytes, for provenance.
    #[serde(skip)]
    pub hash: String,
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ModelConfig {
    /// The drag-free ball drop with parameters (g, v0).
    BallDrop {
        /// Known initial height, m.
        #[serde(default = "default_h0")]
        h0: f64,
    },
    /// A trained emulator (folder written by `mdpipe train-emulator`), relative to the config.
    Emulator { artifact: PathBuf },
}

/// A model variant declared as a diagnose candidate: an emulator (folder
/// from `mdpipe train-emulator`, relative to the config) trained on runs with
/// extra physics switched on, e.g. the Grad shear δf.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CandidateConfig {
    pub name: String,
    /// What physics the variant adds, in a phrase.
    pub description: String,
    pub emulator: PathBuf,
    /// Uniform priors of the variant's own parameters (beyond the model's θ).
    #[serde(default)]
    pub parameters: BTreeMap<String, ParamSpec>,
}

/// The data-generating process of mock data, evaluated at the parameters'
/// `truth` values (ball drop: g, v0; heavy ion: the stand-in's parameters).
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TruthConfig {
    /// The ball drop with extra forces (h0 from `[model]`).
    BallDrop {
        /// k in `-k v|v|`, 1/m.
        #[serde(default)]
        quadratic_drag: f64,
        /// b in `-b v`, 1/s.
        #[serde(default)]
        linear_drag: f64,
    },
    /// The heavy-ion stand-in's smooth observables.
    HeavyIon {
        /// none, grad or grad-transverse.
        delta_f: String,
    },
}

fn default_h0() -> f64 {
    60.0
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// Measurements file (CSV or Parquet), relative to the config file.
    pub measurements: PathBuf,
    /// Observables to calibrate on; all of the model's by default.
    pub observables: Option<Vec<String>>,
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

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiscrepancyConfig {
    /// "none", "I" or "II".
    pub kernel: String,
    /// Uniform prior bounds per hyperparameter name (cbar, ell, r, s).
    pub bounds: BTreeMap<String, [f64; 2]>,
}

impl Default for DiscrepancyConfig {
    fn default() -> Self {
        let b = [0.0, 10.0];
        DiscrepancyConfig {
            kernel: "II".into(),
            bounds: [("cbar", b), ("ell", b), ("r", b), ("s", b)].into_iter().map(|(k, v)| (k.to_string(), v)).collect(),
        }
    }
}

impl DiscrepancyConfig {
    pub fn kernel(&self) -> Result<Option<DiscrepancyKernel>> {
        DiscrepancyKernel::parse(&self.kernel).ok_or_else(|| anyhow!("discrepancy.kernel: unknown kernel {:?} (use none, I or II)", self.kernel))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SamplerKind {
    Smc,
    Ensemble,
}

impl SamplerKind {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "smc" => Some(SamplerKind::Smc),
            "ensemble" | "emcee" => Some(SamplerKind::Ensemble),
            _ => None,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            SamplerKind::Smc => "smc",
            SamplerKind::Ensemble => "ensemble",
        }
    }
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SamplerConfig {
    pub kind: SamplerKind,
    pub smc: SmcSettings,
    pub ensemble: EnsembleSettings,
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig { kind: SamplerKind::Smc, smc: SmcSettings::default(), ensemble: EnsembleSettings::default() }
    }
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictionConfig {
    /// Grid for prediction bands; by default it runs from 0 to 1.5 × the largest x measured,
    /// to show extrapolation as the paper does.
    pub x_min: f64,
    pub x_max: Option<f64>,
    pub points: usize,
    /// Posterior draws used for the bands.
    pub draws: usize,
}

impl Default for PredictionConfig {
    fn default() -> Self {
        PredictionConfig { x_min: 0.0, x_max: None, points: 41, draws: 1000 }
    }
}

impl Config {
    pub fn load(path: &Path) -> Result<Config> {
        let bytes = std::fs::read(path).with_context(|| format!("reading config {}", path.display()))?;
        let text = String::from_utf8(bytes.clone()).with_context(|| format!("{}: not UTF-8", path.display()))?;
        let mut cfg: Config = toml::from_str(&text).map_err(|e| anyhow!("{}: {}", path.display(), e))?;
        cfg.path = path.to_path_buf();
        cfg.hash = crate::artifacts::sha256_hex(&bytes);
        cfg.validate()?;
        Ok(cfg)
    }

    fn validate(&self) -> Result<()> {
        let file = self.path.display();
        for (name, p) in &self.parameters {
            if !(p.min.is_finite() && p.max.is_finite() && p.min < p.max) {
                bail!("{file}: [parameters.{name}]: bounds must satisfy min < max, got min = {}, max = {}", p.min, p.max);
            }
        }
        for (name, b) in &self.discrepancy.bounds {
            if !(b[0].is_finite() && b[1].is_finite() && b[0] < b[1]) {
                bail!("{file}: [discrepancy.bounds] {name}: bounds must satisfy min < max, got [{}, {}]", b[0], b[1]);
            }
        }
        self.discrepancy.kernel().with_context(|| format!("{file}"))?;
        Ok(())
    }

    /// Resolves a path from the config against the config's folder.
    pub fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.path.parent().unwrap_or(Path::new(".")).join(p)
        }
    }

    /// Bounds for a discrepancy hyperparameter.
    pub fn hyper_bounds(&self, hyper: &str) -> Result<[f64; 2]> {
        self.discrepancy
            .bounds
            .get(hyper)
            .copied()
            .ok_or_else(|| anyhow!("{}: [discrepancy.bounds] has no bounds for hyperparameter '{hyper}'", self.path.display()))
    }
}
