//! The stages of `mdpipe run` and the loop that runs them.
//!
//! A stage is a type implementing [`Stage`]: its [`StageId`], the stages
//! whose outputs it reads, whether the study has it, what it leaves, the
//! typed settings that define its output, and its body. Each stage is one
//! module here holding all of its own code (a folder when it has several
//! files); what two stages share (a design run through the executor and
//! ingested) is the service module `pipeline::points`. The generic stages
//! are listed in `pipeline::plan`; a system adds its own, with an id of its
//! own, through `system::System::stages`, which also says where it runs and
//! which later stages read it. The loop owns the keys: a stage's key
//! hashes its settings and its upstream stages' keys; a stage whose stamp
//! (`OUT/stages/<stage>.json`) holds the same key, and whose outputs exist,
//! is skipped.

pub(super) mod calibrate;
pub(super) mod candidates;
pub(super) mod design;
pub(super) mod diagnose;
pub(super) mod emulator;
pub(super) mod ingest;
pub(crate) mod refine;
pub(super) mod report;
pub(super) mod simulate;

use super::study::Study;
use crate::base::artifacts::{self, Provenance};
use anyhow::{anyhow, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use super::stage_id::StageId;

/// Whether a study has a stage, and if not, why (for `--stage`).
pub(crate) enum Presence {
    Runs,
    Absent(String),
}

/// One stage of a study: what it needs, what it leaves, what it does.
pub(crate) trait Stage: Sync {
    /// What defines its output beyond its upstream keys; serialized into its key.
    type Settings: serde::Serialize;
    const ID: StageId;
    /// The stages whose outputs it reads, when the study has them.
    const UPSTREAM: &'static [StageId];
    fn present(&self, _study: &Study<'_>) -> Result<Presence> {
        Ok(Presence::Runs)
    }
    /// What it leaves: the stage reruns when one of them is missing.
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>>;
    /// A folder of results a person reads and compares (a diagnosis): when
    /// the stage runs again with other settings, the folder the last
    /// settings made is kept under `OUT/previous/` rather than overwritten.
    fn kept_when_rerun(&self, _study: &Study<'_>) -> Option<PathBuf> {
        None
    }
    fn settings(&self, study: &Study<'_>) -> Result<Self::Settings>;
    fn run(&self, study: &Study<'_>, keys: &Keys<'_>) -> Result<()>;
}

/// A [`Stage`] as the loop holds it, its settings already serialized.
pub(crate) trait AnyStage: Sync {
    fn id(&self) -> StageId;
    fn upstream(&self) -> &'static [StageId];
    fn present(&self, study: &Study<'_>) -> Result<Presence>;
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>>;
    fn kept_when_rerun(&self, study: &Study<'_>) -> Option<PathBuf>;
    fn settings_value(&self, study: &Study<'_>) -> Result<serde_json::Value>;
    fn run(&self, study: &Study<'_>, keys: &Keys<'_>) -> Result<()>;
}

impl<S: Stage> AnyStage for S {
    fn id(&self) -> StageId {
        S::ID
    }
    fn upstream(&self) -> &'static [StageId] {
        S::UPSTREAM
    }
    fn present(&self, study: &Study<'_>) -> Result<Presence> {
        Stage::present(self, study)
    }
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Stage::outputs(self, study)
    }
    fn kept_when_rerun(&self, study: &Study<'_>) -> Option<PathBuf> {
        Stage::kept_when_rerun(self, study)
    }
    fn settings_value(&self, study: &Study<'_>) -> Result<serde_json::Value> {
        Ok(serde_json::to_value(Stage::settings(self, study)?)?)
    }
    fn run(&self, study: &Study<'_>, keys: &Keys<'_>) -> Result<()> {
        Stage::run(self, study, keys)
    }
}

/// What a stage body may know of the loop: the keys of the stages it reads
/// (what their outputs were) and its own key.
pub(crate) struct Keys<'k> {
    /// Stage name → key, for each stage it reads that the study has.
    pub(crate) reads: &'k BTreeMap<&'static str, String>,
    pub(crate) this: &'k str,
}

#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct Stamp {
    pub(crate) stage: String,
    /// Hash of the stage's settings and upstream keys: unchanged, the stage is skipped.
    pub(crate) key: String,
    /// What later stages key on: new each time the stage runs, so a stage
    /// run again with the same settings (`--force`) reruns what follows.
    /// (Keyed on `key`, a forced refine once left the calibrations of the
    /// previous emulator in place.) Empty in stamps from before it existed.
    #[serde(default)]
    pub(crate) output_key: String,
    pub(crate) seconds: f64,
    pub(crate) provenance: Provenance,
}

impl Stamp {
    pub(crate) fn downstream_key(&self) -> String {
        if self.output_key.is_empty() {
            self.key.clone()
        } else {
            self.output_key.clone()
        }
    }
}

/// A stage as a study runs it: the stages it reads are its own upstream
/// and the systems' stages that say they feed it.
pub(crate) struct Planned {
    pub(crate) stage: &'static dyn AnyStage,
    pub(crate) upstream: Vec<StageId>,
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
pub(crate) struct StageLoop {
    /// The study's stages.
    planned: Vec<StageId>,
    keys: BTreeMap<String, String>,
    pub(crate) outcomes: Vec<StageOutcome>,
}

impl StageLoop {
    pub(crate) fn new(planned: &[Planned]) -> StageLoop {
        StageLoop {
            planned: planned.iter().map(|p| p.stage.id()).collect(),
            keys: BTreeMap::new(),
            outcomes: Vec::new(),
        }
    }

    pub(crate) fn run(&mut self, study: &Study<'_>, planned: &Planned) -> Result<()> {
        let (stage, paths, opts) = (planned.stage, &study.paths, study.opts);
        let name = stage.id().name();
        if opts.stage.as_deref().is_some_and(|s| s != name) {
            // Not this stage: later stages key on what it left on disk.
            if let Some(s) = read_stamp(&paths.stamp(name)) {
                self.keys.insert(name.into(), s.downstream_key());
            }
            return Ok(());
        }
        let reads = self.reads(study, planned)?;
        let key = self.key_of(study, stage, &reads)?;
        let outputs = stage.outputs(study)?;
        let done = read_stamp(&paths.stamp(name)).filter(|s| s.key == key && outputs.iter().all(|p| p.exists()));
        if let Some(done) = done.filter(|_| !opts.force) {
            crate::base::messages::say!("[{name}] up to date, skipped");
            self.outcomes.push(StageOutcome { stage: name.into(), ran: false, seconds: 0.0 });
            self.keys.insert(name.into(), done.downstream_key());
            return Ok(());
        }
        if let Some(folder) = stage.kept_when_rerun(study) {
            keep_previous(paths, name, &key, &folder)?;
        }
        crate::base::messages::say!("[{name}] running");
        let start = std::time::Instant::now();
        stage
            .run(study, &Keys { reads: &reads, this: &key })
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

    /// The keys of the stages it reads; one the study does not have is left out.
    fn reads(&self, study: &Study<'_>, planned: &Planned) -> Result<BTreeMap<&'static str, String>> {
        let name = planned.stage.id();
        let mut reads = BTreeMap::new();
        for u in planned.upstream.iter().filter(|u| self.planned.contains(u)) {
            let key = self.keys.get(u.name()).cloned().ok_or_else(|| anyhow!("stage {name} needs the outputs of stage {u}, which has not run in {}; run `mdpipe run CONFIG --stage {u}` (or without --stage) first", study.paths.out.display()))?;
            reads.insert(u.name(), key);
        }
        Ok(reads)
    }

    /// The stage's key: its settings and the keys of the stages it reads.
    fn key_of(
        &self,
        study: &Study<'_>,
        stage: &dyn AnyStage,
        reads: &BTreeMap<&'static str, String>,
    ) -> Result<String> {
        let mut material = serde_json::json!({"stage": stage.id().name(), "version": env!("CARGO_PKG_VERSION"), "settings": stage.settings_value(study)?});
        for (u, key) in reads {
            material[format!("upstream_{u}")] = serde_json::Value::String(key.clone());
        }
        Ok(artifacts::sha256_hex(material.to_string().as_bytes()))
    }
}

/// Moves `folder`, made by the stage's last run under other settings than
/// `key`, to `OUT/previous/<stage>-<its key>/` with the stamp that says how
/// it was made. The stamp is removed with it: a run stopped part way then
/// leaves its partial folder unclaimed, never filed under the old settings.
fn keep_previous(paths: &super::RunPaths, name: &str, key: &str, folder: &Path) -> Result<()> {
    let stamp_path = paths.stamp(name);
    let Some(old) = read_stamp(&stamp_path).filter(|s| s.key != key) else { return Ok(()) };
    if !folder.is_dir() {
        return Ok(());
    }
    // The key is hex; a stamp edited by hand must not name a path elsewhere.
    let tag: String = old.key.chars().filter(char::is_ascii_alphanumeric).take(12).collect();
    let kept = paths.previous().join(format!("{name}-{tag}"));
    if kept.exists() {
        // The same settings' results again: the stage reproduces them.
        std::fs::remove_dir_all(&kept).with_context(|| format!("removing {}", kept.display()))?;
    }
    std::fs::create_dir_all(paths.previous()).with_context(|| format!("creating {}", paths.previous().display()))?;
    std::fs::rename(folder, &kept).with_context(|| format!("moving {} to {}", folder.display(), kept.display()))?;
    artifacts::write_json_atomic(&kept.join("stage.json"), &old)?;
    std::fs::remove_file(&stamp_path).with_context(|| format!("removing {}", stamp_path.display()))?;
    crate::base::messages::say!("[{name}] the last results, of other settings, are kept in {}", kept.display());
    Ok(())
}

pub(crate) fn read_stamp(path: &Path) -> Option<Stamp> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}
