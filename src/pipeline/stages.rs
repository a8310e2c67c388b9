//! The stage machinery of `mdpipe run`: where a run writes (`RunPaths`), what
//! a stage leaves as its stamp, and the loop that skips a stage whose key is
//! unchanged and whose outputs exist.

use super::run_config::RunConfig;
use crate::base::artifacts::{self, Provenance};
use crate::base::config::Config;
use crate::engine::emulator::EmulatorSettings;
use crate::engine::execute::Executor;
use anyhow::{anyhow, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

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
    pub fn mock(&self) -> PathBuf {
        self.out.join("mock")
    }
    pub fn measurements(&self) -> PathBuf {
        self.out.join("mock").join("measurements.parquet")
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

#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct Stamp {
    pub(super) stage: String,
    /// Hash of the stage's settings and upstream keys: unchanged, the stage is skipped.
    pub(super) key: String,
    /// What later stages key on: new each time the stage runs, so a stage
    /// run again with the same settings (`--force`) reruns what follows.
    /// (Keyed on `key`, a forced refine once left the calibrations of the
    /// previous emulator in place.) Empty in stamps from before it existed.
    #[serde(default)]
    pub(super) output_key: String,
    pub(super) seconds: f64,
    pub(super) provenance: Provenance,
}

impl Stamp {
    pub(super) fn downstream_key(&self) -> String {
        if self.output_key.is_empty() {
            self.key.clone()
        } else {
            self.output_key.clone()
        }
    }
}

/// What happened to each stage.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StageOutcome {
    pub stage: String,
    pub ran: bool,
    pub seconds: f64,
}

pub(super) struct Runner<'a> {
    pub(super) config: &'a Config,
    pub(super) run: &'a RunConfig,
    /// `[emulator]`, decoded once.
    pub(super) emulator: Option<EmulatorSettings>,
    pub(super) paths: RunPaths,
    pub(super) opts: &'a RunOptions,
    pub(super) keys: BTreeMap<String, String>,
    /// Key of the stage running now.
    pub(super) running_key: String,
    pub(super) outcomes: Vec<StageOutcome>,
}

impl Runner<'_> {
    pub(super) fn stage(
        &mut self,
        name: &str,
        upstream: &[&str],
        outputs: &[PathBuf],
        body: impl FnOnce(&mut Self) -> Result<()>,
    ) -> Result<()> {
        if self.opts.stage.as_deref().is_some_and(|s| s != name) {
            // Not this stage: later stages key on what it left on disk.
            if let Some(s) = read_stamp(&self.paths.stamp(name)) {
                self.keys.insert(name.into(), s.downstream_key());
            }
            return Ok(());
        }
        let mut material = serde_json::json!({"stage": name, "version": env!("CARGO_PKG_VERSION"), "settings": self.settings_of(name)?});
        for u in upstream {
            let key = self.keys.get(*u).cloned().ok_or_else(|| anyhow!("stage {name} needs the outputs of stage {u}, which has not run in {}; run `mdpipe run CONFIG --stage {u}` (or without --stage) first", self.paths.out.display()))?;
            material[format!("upstream_{u}")] = serde_json::Value::String(key);
        }
        let key = artifacts::sha256_hex(material.to_string().as_bytes());
        let done = read_stamp(&self.paths.stamp(name)).filter(|s| s.key == key && outputs.iter().all(|p| p.exists()));
        if let Some(done) = done.filter(|_| !self.opts.force) {
            println!("[{name}] up to date, skipped");
            self.outcomes.push(StageOutcome { stage: name.into(), ran: false, seconds: 0.0 });
            self.keys.insert(name.into(), done.downstream_key());
            return Ok(());
        }
        println!("[{name}] running");
        self.running_key = key.clone();
        let start = std::time::Instant::now();
        body(self).with_context(|| format!("{}: stage {name}", self.config.path.display()))?;
        if self.opts.case.is_some() {
            return Ok(());
        }
        let seconds = start.elapsed().as_secs_f64();
        let output_key = artifacts::sha256_hex(
            format!("{key} ran at {:?} in process {}", std::time::SystemTime::now(), std::process::id()).as_bytes(),
        );
        let stamp = Stamp {
            stage: name.into(),
            key,
            output_key: output_key.clone(),
            seconds,
            provenance: Provenance::new(
                self.config.hash.clone(),
                String::new(),
                self.opts.seed,
                &format!("run {} --stage {name}", self.config.path.display()),
            ),
        };
        artifacts::write_json_atomic(&self.paths.stamp(name), &stamp)?;
        println!("[{name}] done in {seconds:.1} s");
        self.keys.insert(name.into(), output_key);
        self.outcomes.push(StageOutcome { stage: name.into(), ran: true, seconds });
        Ok(())
    }

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

pub(super) fn read_stamp(path: &Path) -> Option<Stamp> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
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
