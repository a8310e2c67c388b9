//! What every stage of `mdpipe run` reads: the study (its config, `[run]`
//! table, options and systems) and where it writes (`RunPaths`); and what a
//! system brings to it (`StudySystem`), in the same file because each names
//! the other.

use super::run_config::RunConfig;
use super::stage_id::StageId;
use super::variants::Variant;

use crate::base::artifacts;
use crate::base::config::Config;
use crate::engine::calibrate;
use crate::engine::emulator::EmulatorSettings;
use crate::engine::execute::{Executor, SimulatorSpec};
use crate::engine::model::{ModelFamily, Units};
use crate::engine::report::SystemFigures;
use anyhow::{anyhow, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Where and how to run.
pub struct RunOptions {
    pub out: PathBuf,
    pub seed: u64,
    /// Run only the stage of this name (its inputs must exist).
    pub stage: Option<String>,
    /// Run stages even when their stamps match.
    pub force: bool,
    pub show_progress: bool,
    /// Where the simulate stage runs the design points.
    pub executor: Executor,
    /// The mdpipe executable, substituted for `{mdpipe}` (a built-in system's command).
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
    /// Results of earlier settings, kept when a stage ran again (`<stage>-<key>/`).
    pub fn previous(&self) -> PathBuf {
        self.out.join("previous")
    }
    pub(super) fn stamp(&self, stage: &str) -> PathBuf {
        self.out.join("stages").join(format!("{stage}.json"))
    }
}

/// What every stage reads: the config, its `[run]` table, where the run
/// writes and how. Read only: stages change
/// nothing in it.
pub(crate) struct Study<'a> {
    pub(crate) config: &'a Config,
    pub(crate) run: &'a RunConfig,
    /// `[emulator]`, decoded once.
    pub(crate) emulator: Option<EmulatorSettings>,
    pub(crate) paths: RunPaths,
    pub(crate) opts: &'a RunOptions,
    /// The systems of this run, which complete the study (`setup`).
    pub(crate) systems: &'a [&'a dyn StudySystem],
}

/// Data a system made for the study (mock data with a known truth).
pub(crate) struct StudyData {
    pub(crate) measurements: PathBuf,
    /// Their covariance (`[data] covariance`), when the system measured it.
    pub(crate) covariance: Option<PathBuf>,
}

/// What a simulator system brings to a study beyond its command line, as
/// `report::SystemFigures` brings figures to a report: the runner and its
/// stages know no system and ask the ones the study holds (`Study::systems`,
/// the list `app::systems()` passes in; the stages a system adds are
/// `system::System::stages`). Every method has a default that adds nothing,
/// so a system implements only what it brings.
pub(crate) trait StudySystem: Sync {
    /// The name of its own table in `[run]` (`[run.<name>]`), if it has one.
    fn run_table(&self) -> Option<&'static str> {
        None
    }
    /// Checks its table of `run` before any stage runs.
    fn validate(&self, _run: &RunConfig) -> Result<()> {
        Ok(())
    }
    /// The declarations of its library candidates that `run` names, each
    /// pointing at its variant emulator under `paths` (what the standalone
    /// commands take from a study, `complete::fill_in_from_study`).
    fn library_declarations(&self, _run: &RunConfig, _paths: &RunPaths) -> Result<Vec<toml::Table>> {
        Ok(Vec::new())
    }
    /// What it adds to a generic stage's key: its own `[run]` settings that
    /// shape that stage's output (the generic stages know only their own).
    fn key_settings(&self, _study: &Study<'_>, _stage: StageId) -> serde_json::Map<String, serde_json::Value> {
        serde_json::Map::new()
    }
    /// What the simulate stage runs when the study has no `[run.simulator]`.
    fn default_simulator(&self, _study: &Study<'_>, _validation: bool) -> Result<Option<SimulatorSpec>> {
        Ok(None)
    }
    /// Candidate physics from its own library (a table of its own in `[run]`), as variants of its simulator.
    fn library_variants(&self, _study: &Study<'_>) -> Result<Vec<Variant>> {
        Ok(Vec::new())
    }
    /// The data the study calibrates on, when the system made them.
    fn data(&self, _study: &Study<'_>) -> Option<StudyData> {
        None
    }
    /// A model family the study's configs may name (its `[truth]` process).
    fn family(&self) -> Option<Arc<dyn ModelFamily>> {
        None
    }
    /// Units of its parameters and observables, first in the study's figures.
    fn units(&self, _study: &Study<'_>) -> Option<Units> {
        None
    }
    /// Where its assessment of the calibrations against the truth goes,
    /// when it assesses this study (else the calibrate stage tables the cases).
    fn assessment(&self, _study: &Study<'_>) -> Option<PathBuf> {
        None
    }
    /// Writes that assessment from the calibrations in `dirs`.
    fn assess(&self, _study: &Study<'_>, _config: &Config, _dirs: &[PathBuf]) -> Result<()> {
        Ok(())
    }
    /// Its report figures, and the section its assessment puts above them.
    fn figures(&self) -> Option<&'static dyn SystemFigures> {
        None
    }
    fn report_section(&self, _study: &Study<'_>) -> Result<Option<String>> {
        Ok(None)
    }
}

impl Study<'_> {
    /// SHA-256 of the config without its `[run]` table and its
    /// `[[candidates]]`: what the calibrations depend on beyond their stage
    /// settings and upstream keys (so declaring a diagnose candidate does not
    /// redo them; the candidates and diagnose stages key on the candidates).
    pub(super) fn analysis_hash(&self) -> Result<String> {
        let text = std::fs::read_to_string(&self.config.path)
            .with_context(|| format!("reading {}", self.config.path.display()))?;
        let mut table: toml::Table =
            toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", self.config.path.display()))?;
        table.remove("run");
        table.remove("candidates");
        table.insert("conventions".into(), crate::engine::calibrate::analysis::CONVENTIONS.into());
        Ok(artifacts::sha256_hex(serde_json::to_string(&table)?.as_bytes()))
    }

    /// SHA-256 of the design spec `[run] design` names.
    pub(super) fn design_spec_hash(&self) -> Result<String> {
        let path = self.config.resolve(&self.run.design);
        let bytes = std::fs::read(&path).with_context(|| format!("reading design spec {}", path.display()))?;
        Ok(artifacts::sha256_hex(&bytes))
    }

    /// The calibrations written under `dir`, at most three folders down (the
    /// calibrate stage's cases, the refine rounds' pilots), in path order:
    /// fits a later stage may take for the same problem (`calibrate::results::stored`).
    pub(crate) fn stored_fits(&self, dir: &Path) -> Vec<PathBuf> {
        let mut found = Vec::new();
        let mut level = vec![dir.to_path_buf()];
        for _ in 0..3 {
            let mut next = Vec::new();
            for d in &level {
                let Ok(entries) = std::fs::read_dir(d) else { continue };
                next.extend(entries.flatten().map(|e| e.path()).filter(|p| p.is_dir()));
            }
            found.extend(next.iter().filter(|p| p.join(calibrate::results::stored::KEY_FILE).is_file()).cloned());
            level = next;
        }
        found.sort();
        found
    }

    /// Diagnose and the refine stage's pilots work on the last (largest) observable set.
    pub(super) fn diagnose_observables(&self) -> Vec<String> {
        self.run.observable_sets.last().cloned().unwrap_or_default()
    }

    pub(crate) fn all_observables(&self) -> Vec<String> {
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

pub(crate) fn absolute(p: &Path) -> PathBuf {
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
