//! What every stage of `mdpipe run` reads: the study (its config, `[run]`
//! table and options) and where it writes (`RunPaths`).

use super::run_config::RunConfig;
use super::system;
use crate::base::artifacts;
use crate::base::config::Config;
use crate::engine::calibrate::Analysis;
use crate::engine::emulator::{EmulatorFamily, EmulatorSettings};
use crate::engine::execute::Executor;
use crate::engine::model::Registry;
use anyhow::{anyhow, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Where and how to run.
pub struct RunOptions {
    pub out: PathBuf,
    pub seed: u64,
    /// Run only this stage (its inputs must exist).
    pub stage: Option<String>,
    /// Run stages even when their stamps match.
    pub force: bool,
    pub show_progress: bool,
    /// Where the simulate stage runs the design points.
    pub executor: Executor,
    /// The mdpipe executable, substituted for `{mdpipe}` (the stand-in's command).
    pub mdpipe: PathBuf,
    /// With `stage = calibrate`: only this case (by index), as one array task
    /// would; nothing is assessed or stamped but the case.
    pub case: Option<usize>,
}

/// Paths of a run's artifacts.
pub struct RunPaths {
    pub out: PathBuf,
}

impl RunPaths {
    pub fn design(&self) -> PathBuf {
        self.out.join("design")
    }
    pub fn validation_design(&self) -> PathBuf {
        self.out.join("validation_design")
    }
    pub fn training(&self) -> PathBuf {
        self.out.join("training.parquet")
    }
    pub fn validation(&self) -> PathBuf {
        self.out.join("validation.parquet")
    }
    pub fn emulator(&self) -> PathBuf {
        self.out.join("emulator")
    }
    pub fn calibrate(&self) -> PathBuf {
        self.out.join("calibrate")
    }
    pub fn candidate(&self, name: &str) -> PathBuf {
        self.out.join("candidates").join(name)
    }
    pub fn diagnose(&self) -> PathBuf {
        self.out.join("diagnose")
    }
    pub(super) fn stamp(&self, stage: &str) -> PathBuf {
        self.out.join("stages").join(format!("{stage}.json"))
    }
}

/// What every stage reads: the config, its `[run]` table, where the run
/// writes and how. Stage bodies are its methods; they change nothing in it.
pub(super) struct Study<'a> {
    pub(super) config: &'a Config,
    pub(super) run: &'a RunConfig,
    /// `[emulator]`, decoded once.
    pub(super) emulator: Option<EmulatorSettings>,
    pub(super) paths: RunPaths,
    pub(super) opts: &'a RunOptions,
}

impl Study<'_> {
    /// SHA-256 of the config without its `[run]` table: what the calibrations
    /// depend on beyond their stage settings and upstream keys (so declaring a
    /// diagnose candidate does not redo them).
    pub(super) fn analysis_hash(&self) -> Result<String> {
        let text = std::fs::read_to_string(&self.config.path)
            .with_context(|| format!("reading {}", self.config.path.display()))?;
        let mut table: toml::Table =
            toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", self.config.path.display()))?;
        table.remove("run");
        Ok(artifacts::sha256_hex(serde_json::to_string(&table)?.as_bytes()))
    }

    /// SHA-256 of the design spec `[run] design` names.
    pub(super) fn design_spec_hash(&self) -> Result<String> {
        let path = self.config.resolve(&self.run.design);
        let bytes = std::fs::read(&path).with_context(|| format!("reading design spec {}", path.display()))?;
        Ok(artifacts::sha256_hex(&bytes))
    }

    /// The analysis config pointed at the study's emulator (refined, with
    /// `[run.refine]`) and mock data.
    pub(super) fn study_config(&self) -> Result<Config> {
        Ok(self.study_config_with(&self.study_emulator()?))
    }

    /// The analysis config pointed at `emulator` and this run's mock data.
    pub(super) fn study_config_with(&self, emulator: &Path) -> Config {
        let mut c = self.config.clone();
        // The config's own [model] keys (its units) stay; the study's emulator is the artifact.
        let emulator_kind = c.model.get("kind").and_then(|k| k.as_str()) == Some("emulator");
        let mut model = if emulator_kind { c.model.clone() } else { toml::Table::new() };
        model.extend(EmulatorFamily::model_table(&absolute(emulator)));
        c.model = model;
        if let Some(data) = system::first(|s| s.data(self)) {
            c.data.measurements = data.measurements;
            c.data.covariance = data.covariance;
        }
        c
    }

    /// The study's analysis: the study's emulator as the model, a system's
    /// family (the stand-in itself) as the `[truth]` process.
    pub(super) fn analysis(&self, config: &Config) -> Result<Analysis> {
        let mut families = Registry::new();
        families.register(Arc::new(EmulatorFamily));
        for family in system::systems().into_iter().filter_map(|s| s.family()) {
            families.register(family);
        }
        let mut analysis = Analysis::resolve(config, &families)?;
        // The emulator knows no units; the system's come first, as in its figures.
        if let Some(units) = system::first(|s| s.units(self)) {
            analysis.units = units.or(&analysis.units);
        }
        Ok(analysis)
    }

    /// SHA-256 of the measurements the calibrations use (the config's, when
    /// no system made them: the key of the stage that did covers those).
    pub(super) fn data_hash(&self) -> Result<String> {
        if system::first(|s| s.data(self)).is_some() {
            return Ok(String::new());
        }
        let path = self.config.resolve(&self.config.data.measurements);
        Ok(artifacts::sha256_hex(
            &std::fs::read(&path).with_context(|| format!("reading the measurements {}", path.display()))?,
        ))
    }

    pub(super) fn all_observables(&self) -> Vec<String> {
        let mut all: Vec<String> = Vec::new();
        for set in &self.run.observable_sets {
            for o in set {
                if !all.contains(o) {
                    all.push(o.clone());
                }
            }
        }
        all
    }
}

pub(super) fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

/// A cheap content fingerprint of a runs folder: every file's path and size.
pub(super) fn runs_fingerprint(dir: &Path) -> Result<String> {
    let mut entries = Vec::new();
    if dir.exists() {
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).with_context(|| format!("listing {}", d.display()))? {
                let e = e?;
                let path = e.path();
                let meta = e.metadata()?;
                if meta.is_dir() {
                    stack.push(path);
                } else {
                    let modified = meta
                        .modified()
                        .ok()
                        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                        .map(|d| d.as_nanos())
                        .unwrap_or(0);
                    entries.push(format!(
                        "{}:{}:{}",
                        path.strip_prefix(dir).unwrap_or(&path).display(),
                        meta.len(),
                        modified
                    ));
                }
            }
        }
    }
    entries.sort();
    Ok(artifacts::sha256_hex(entries.join("\n").as_bytes()))
}
