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

/// What a stage body may know of the loop: the keys of the stages before it
/// (what their outputs were) and its own key.
pub(super) struct Keys<'k> {
    pub(super) upstream: &'k BTreeMap<String, String>,
    pub(super) this: &'k str,
}

/// One stage of a study: what it needs, what it leaves, what it does.
pub(super) struct Stage<'a> {
    pub(super) name: &'static str,
    pub(super) upstream: Vec<&'static str>,
    pub(super) outputs: Vec<PathBuf>,
    pub(super) body: fn(&Study<'a>, &Keys) -> Result<()>,
}

/// The loop over a study's stages: it owns the keys, skips a stage whose
/// stamp holds its key, runs the rest and stamps them.
#[derive(Default)]
pub(super) struct StageLoop {
    keys: BTreeMap<String, String>,
    pub(super) outcomes: Vec<StageOutcome>,
}

impl StageLoop {
    pub(super) fn run<'a>(&mut self, study: &Study<'a>, stage: &Stage<'a>) -> Result<()> {
        let (name, paths, opts) = (stage.name, &study.paths, study.opts);
        if opts.stage.as_deref().is_some_and(|s| s != name) {
            // Not this stage: later stages key on what it left on disk.
            if let Some(s) = read_stamp(&paths.stamp(name)) {
                self.keys.insert(name.into(), s.downstream_key());
            }
            return Ok(());
        }
        let key = self.key_of(study, stage)?;
        let done = read_stamp(&paths.stamp(name)).filter(|s| s.key == key && stage.outputs.iter().all(|p| p.exists()));
        if let Some(done) = done.filter(|_| !opts.force) {
            println!("[{name}] up to date, skipped");
            self.outcomes.push(StageOutcome { stage: name.into(), ran: false, seconds: 0.0 });
            self.keys.insert(name.into(), done.downstream_key());
            return Ok(());
        }
        println!("[{name}] running");
        let start = std::time::Instant::now();
        (stage.body)(study, &Keys { upstream: &self.keys, this: &key })
            .with_context(|| format!("{}: stage {name}", study.config.path.display()))?;
        if opts.case.is_some() {
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
                study.config.hash.clone(),
                String::new(),
                opts.seed,
                &format!("run {} --stage {name}", study.config.path.display()),
            ),
        };
        artifacts::write_json_atomic(&paths.stamp(name), &stamp)?;
        println!("[{name}] done in {seconds:.1} s");
        self.keys.insert(name.into(), output_key);
        self.outcomes.push(StageOutcome { stage: name.into(), ran: true, seconds });
        Ok(())
    }

    /// The stage's key: its settings and its upstream stages' keys.
    fn key_of(&self, study: &Study<'_>, stage: &Stage<'_>) -> Result<String> {
        let name = stage.name;
        let mut material = serde_json::json!({"stage": name, "version": env!("CARGO_PKG_VERSION"), "settings": study.settings_of(name)?});
        for u in &stage.upstream {
            let key = self.keys.get(*u).cloned().ok_or_else(|| anyhow!("stage {name} needs the outputs of stage {u}, which has not run in {}; run `mdpipe run CONFIG --stage {u}` (or without --stage) first", study.paths.out.display()))?;
            material[format!("upstream_{u}")] = serde_json::Value::String(key);
        }
        Ok(artifacts::sha256_hex(material.to_string().as_bytes()))
    }
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
