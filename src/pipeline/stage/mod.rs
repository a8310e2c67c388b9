//! The stages of `mdpipe run` and the loop that runs them.
//!
//! A stage is one file in this folder: a `STAGE` that gives its name, its
//! rank among the stages, the stages whose outputs it reads, what it leaves,
//! the settings that define its output, and its body. The build script
//! (`build.rs`) declares every file here as a module, so a new stage is one
//! new file. The loop owns the keys: a stage's key hashes its settings and
//! its upstream stages' keys; a stage whose stamp (`OUT/stages/<stage>.json`)
//! holds the same key, and whose outputs exist, is skipped.

use super::study::Study;
use crate::base::artifacts::{self, Provenance};
use anyhow::{anyhow, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

// `mod <file>;` for every stage file, and `FOUND`, their `STAGE`s
// (`setup::stages` adds the systems' stages and orders them).
include!(concat!(env!("OUT_DIR"), "/stages.rs"));

/// Whether a study has a stage, and if not, why (for `--stage`).
pub(in crate::pipeline) enum Presence {
    Runs,
    Absent(String),
}

/// One stage of a study: what it needs, what it leaves, what it does.
pub(in crate::pipeline) struct StageDef {
    /// Its `--stage` name and the name of its stamp.
    pub(in crate::pipeline) name: &'static str,
    /// Its place in the study: stages run in ascending rank.
    pub(in crate::pipeline) rank: u32,
    /// The stages whose outputs it reads, when the study has them.
    pub(in crate::pipeline) upstream: &'static [&'static str],
    pub(in crate::pipeline) present: fn(&Study<'_>) -> Result<Presence>,
    /// What it leaves: the stage reruns when one of them is missing.
    pub(in crate::pipeline) outputs: fn(&Study<'_>) -> Result<Vec<PathBuf>>,
    /// The settings that define its output, beyond its upstream keys.
    pub(in crate::pipeline) settings: fn(&Study<'_>) -> Result<serde_json::Value>,
    pub(in crate::pipeline) body: fn(&Study<'_>, &Keys<'_>) -> Result<()>,
}

/// For a stage every study has.
fn always(_: &Study<'_>) -> Result<Presence> {
    Ok(Presence::Runs)
}

/// What a stage body may know of the loop: the keys of the stages before it
/// (what their outputs were) and its own key.
pub(in crate::pipeline) struct Keys<'k> {
    pub(in crate::pipeline) upstream: &'k BTreeMap<String, String>,
    pub(in crate::pipeline) this: &'k str,
}

#[derive(serde::Serialize, serde::Deserialize)]
pub(in crate::pipeline) struct Stamp {
    pub(in crate::pipeline) stage: String,
    /// Hash of the stage's settings and upstream keys: unchanged, the stage is skipped.
    pub(in crate::pipeline) key: String,
    /// What later stages key on: new each time the stage runs, so a stage
    /// run again with the same settings (`--force`) reruns what follows.
    /// (Keyed on `key`, a forced refine once left the calibrations of the
    /// previous emulator in place.) Empty in stamps from before it existed.
    #[serde(default)]
    pub(in crate::pipeline) output_key: String,
    pub(in crate::pipeline) seconds: f64,
    pub(in crate::pipeline) provenance: Provenance,
}

impl Stamp {
    pub(in crate::pipeline) fn downstream_key(&self) -> String {
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

/// The loop over a study's stages: it owns the keys, skips a stage whose
/// stamp holds its key, runs the rest and stamps them.
pub(in crate::pipeline) struct StageLoop {
    /// The names of the study's stages.
    planned: Vec<&'static str>,
    keys: BTreeMap<String, String>,
    pub(in crate::pipeline) outcomes: Vec<StageOutcome>,
}

impl StageLoop {
    pub(in crate::pipeline) fn new(planned: &[&StageDef]) -> StageLoop {
        StageLoop { planned: planned.iter().map(|s| s.name).collect(), keys: BTreeMap::new(), outcomes: Vec::new() }
    }

    pub(in crate::pipeline) fn run(&mut self, study: &Study<'_>, stage: &StageDef) -> Result<()> {
        let (name, paths, opts) = (stage.name, &study.paths, study.opts);
        if opts.stage.as_deref().is_some_and(|s| s != name) {
            // Not this stage: later stages key on what it left on disk.
            if let Some(s) = read_stamp(&paths.stamp(name)) {
                self.keys.insert(name.into(), s.downstream_key());
            }
            return Ok(());
        }
        let key = self.key_of(study, stage)?;
        let outputs = (stage.outputs)(study)?;
        let done = read_stamp(&paths.stamp(name)).filter(|s| s.key == key && outputs.iter().all(|p| p.exists()));
        if let Some(done) = done.filter(|_| !opts.force) {
            crate::base::messages::say!("[{name}] up to date, skipped");
            self.outcomes.push(StageOutcome { stage: name.into(), ran: false, seconds: 0.0 });
            self.keys.insert(name.into(), done.downstream_key());
            return Ok(());
        }
        crate::base::messages::say!("[{name}] running");
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
        crate::base::messages::say!("[{name}] done in {seconds:.1} s");
        self.keys.insert(name.into(), output_key);
        self.outcomes.push(StageOutcome { stage: name.into(), ran: true, seconds });
        Ok(())
    }

    /// The stage's key: its settings and its upstream stages' keys.
    fn key_of(&self, study: &Study<'_>, stage: &StageDef) -> Result<String> {
        let name = stage.name;
        let mut material = serde_json::json!({"stage": name, "version": env!("CARGO_PKG_VERSION"), "settings": (stage.settings)(study)?});
        // An upstream stage the study does not have is left out.
        for u in stage.upstream.iter().filter(|u| self.planned.contains(u)) {
            let key = self.keys.get(*u).cloned().ok_or_else(|| anyhow!("stage {name} needs the outputs of stage {u}, which has not run in {}; run `mdpipe run CONFIG --stage {u}` (or without --stage) first", study.paths.out.display()))?;
            material[format!("upstream_{u}")] = serde_json::Value::String(key);
        }
        Ok(artifacts::sha256_hex(material.to_string().as_bytes()))
    }
}

pub(in crate::pipeline) fn read_stamp(path: &Path) -> Option<Stamp> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}
