//! `mdpipe run`: a study end to end, as a sequence of stages that each write
//! their artifacts under one output folder and are skipped when their inputs
//! have not changed. The simulate stage runs `[run.simulator]` (any
//! simulator) or, without it, the heavy-ion stand-in, through
//! `engine::execute` (local processes or a Slurm array). The mock, candidates
//! and diagnose stages, and the study's assessment, belong to the stand-in's
//! study (`mock_delta_f`); with a user's simulator the calibrations use the
//! config's measurements and are tabulated in calibrate/cases.md.
//!
//! | stage       | writes (under OUT/)                                             |
//! |-------------|-----------------------------------------------------------------|
//! | design      | design/, validation_design/ (design.parquet, parameter files, submit.slurm) |
//! | simulate    | design/runs/, validation_design/runs/ (one folder per point, execution.json) |
//! | ingest      | training.parquet, validation.parquet (+ .report.json)           |
//! | emulator    | emulator/ (trained, then validated: validation.json)            |
//! | mock        | mock/runs/, mock/measurements.parquet                           |
//! | refine      | refine/round_<r>/ (pilots, design with runs, tables, emulator), refine/rounds.json, rounds.md (only with `[run.refine]`; the stages after it use its emulator) |
//! | calibrate   | calibrate/<observables>__<kernel>/ per case, study.md, study.json (or calibrate/cases.md, cases.json) |
//! | report      | report.html                                                     |
//! | candidates  | candidates/<name>/ (design, runs, training.parquet, emulator with validation.json) per `[run] candidates` entry |
//! | diagnose    | diagnose/ (diagnosis.json, report.html and every calibration; refine/<candidate>/ and refine/diagnosis_before.json when variants were refined) |
//!
//! The last two run only when `[run] candidates` names physics from the
//! stand-in's library (`heavy_ion::CANDIDATES`): each gets a variant
//! emulator trained on runs with that physics switched on, and `diagnose`
//! weighs the variants against the model on the mock data.
//! A stage's key hashes its settings and its upstream stages' keys (the
//! simulate stage's, and so ingest's, also the run folders' contents); a stage
//! whose stamp (`OUT/stages/<stage>.json`) holds the same key, and whose
//! outputs exist, is skipped. Within the calibrate stage each case is stamped
//! too (`OUT/stages/calibrate/<case>.json`), so an interrupted stage resumes
//! with the cases it had not finished.

use super::family::HeavyIonFamily;
use super::figures::HeavyIonFigures;
use crate::base::artifacts::{self, Measurement, Provenance};
use crate::base::config::Config;
use crate::base::progress::observer;
use crate::engine::calibrate::{self, Analysis, Overrides, Problem};
use crate::engine::compare;
use crate::engine::emulator::{EmulatorFamily, EmulatorSettings};
use crate::engine::execute::{self, Executor, OutputKind, SimulatorSpec};
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::{ModelFamily, Registry};
use crate::systems::heavy_ion::{self, events::Layout, DeltaF, HeavyIonParams};
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod refine_rounds;
mod variant_runs;
pub use refine_rounds::{RefineConfig, Rounds};

/// The `[run]` table of an analysis config.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Parameter-space spec (`design/*.toml`), relative to the config.
    pub design: PathBuf,
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
    /// Discrepancy kernels: "none", "I", "II".
    #[serde(default = "default_kernels")]
    pub kernels: Vec<String>,
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
fn default_kernels() -> Vec<String> {
    vec!["none".into(), "I".into(), "II".into()]
}

impl RunConfig {
    /// Checks everything a later stage would trip on, before any stage runs.
    fn validate(&self, design_parameters: &[String]) -> Result<()> {
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
        for k in &self.kernels {
            DiscrepancyKernel::parse(k).ok_or_else(|| anyhow!("kernels: unknown kernel {k:?} (use none, I or II)"))?;
        }
        if self.observable_sets.is_empty() || self.observable_sets.iter().any(|s| s.is_empty()) {
            bail!("observable_sets: give one or more non-empty sets");
        }
        let known: Vec<String> = artifacts::PAPER_TABLE_OBSERVABLES.iter().map(|(_, name)| name.to_string()).collect();
        for o in self.observable_sets.iter().flatten() {
            if self.simulator.is_none() && !known.contains(o) {
                bail!("observable_sets: unknown observable '{o}' (the stand-in gives {})", known.join(", "));
            }
        }
        if !self.candidates.is_empty() && !self.stand_in_study() {
            bail!("candidates come from the stand-in's library: they need the stand-in's mock data (mock_delta_f)");
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

impl RunConfig {
    /// A study on the stand-in's mock data (with its truth known), rather than on measurements.
    pub fn stand_in_study(&self) -> bool {
        self.mock_delta_f.is_some()
    }

    fn output(&self) -> OutputKind {
        self.simulator.as_ref().map_or(OutputKind::IebeMusic, |s| s.output)
    }
}

pub const STAGES: [&str; 10] =
    ["design", "simulate", "ingest", "emulator", "mock", "refine", "calibrate", "report", "candidates", "diagnose"];

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

/// One calibration case of the calibrate stage.
struct Case {
    index: usize,
    name: String,
    set: Vec<String>,
    kernel: Option<DiscrepancyKernel>,
    dir: PathBuf,
    seed: u64,
    key: String,
    stamp: PathBuf,
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
    fn stamp(&self, stage: &str) -> PathBuf {
        self.out.join("stages").join(format!("{stage}.json"))
    }
}

#[derive(serde::Serialize, serde::Deserialize)]
struct Stamp {
    stage: String,
    /// Hash of the stage's settings and upstream keys: unchanged, the stage is skipped.
    key: String,
    /// What later stages key on: new each time the stage runs, so a stage
    /// run again with the same settings (`--force`) reruns what follows.
    /// (Keyed on `key`, a forced refine once left the calibrations of the
    /// previous emulator in place.) Empty in stamps from before it existed.
    #[serde(default)]
    output_key: String,
    seconds: f64,
    provenance: Provenance,
}

impl Stamp {
    fn downstream_key(&self) -> String {
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

struct Runner<'a> {
    config: &'a Config,
    run: &'a RunConfig,
    /// `[emulator]`, decoded once.
    emulator: Option<EmulatorSettings>,
    paths: RunPaths,
    opts: &'a RunOptions,
    keys: BTreeMap<String, String>,
    /// Key of the stage running now.
    running_key: String,
    outcomes: Vec<StageOutcome>,
}

/// Runs the study (or one stage of it). Returns what ran and what was skipped.
pub fn run(config: &Config, opts: &RunOptions) -> Result<Vec<StageOutcome>> {
    let table = config.run.as_ref().ok_or_else(|| {
        anyhow!(
            "{}: no [run] table; `mdpipe run` needs one (see pipeline/heavy_ion_2param.toml)",
            config.path.display()
        )
    })?;
    let run: &RunConfig = &config.decode(table, "run")?;
    if let Some(s) = &opts.stage {
        if !STAGES.contains(&s.as_str()) {
            bail!("--stage {s}: unknown stage (use one of {})", STAGES.join(", "));
        }
    }
    let spec = crate::engine::design::DesignSpec::load(&config.resolve(&run.design))?;
    let design_parameters: Vec<String> = spec.parameters.iter().map(|p| p.name.clone()).collect();
    if opts.case.is_some() && opts.stage.as_deref() != Some("calibrate") {
        bail!("--case needs --stage calibrate");
    }
    execute::spec::seconds_of(&run.calibration_time_limit).context("[run] calibration_time_limit")?;
    run.validate(&design_parameters).with_context(|| format!("{}: [run]", config.path.display()))?;
    artifacts::check_writable(&opts.out)?;
    std::fs::create_dir_all(&opts.out).with_context(|| format!("creating {}", opts.out.display()))?;
    let emulator = config.emulator.is_some().then(|| EmulatorSettings::load(&config.path)).transpose()?;
    let mut r = Runner {
        config,
        run,
        emulator,
        paths: RunPaths { out: opts.out.clone() },
        opts,
        keys: BTreeMap::new(),
        running_key: String::new(),
        outcomes: Vec::new(),
    };
    r.stage(
        "design",
        &[],
        &[r.paths.design().join("design.parquet"), r.paths.validation_design().join("design.parquet")],
        |r| r.design(),
    )?;
    r.stage(
        "simulate",
        &["design"],
        &[r.paths.design().join("runs"), r.paths.validation_design().join("runs")],
        |r| r.simulate(),
    )?;
    r.stage("ingest", &["simulate"], &[r.paths.training(), r.paths.validation()], |r| r.ingest())?;
    r.stage(
        "emulator",
        &["ingest"],
        &[r.paths.emulator().join("emulator.json"), r.paths.emulator().join("validation.json")],
        |r| r.emulator(),
    )?;
    let data_stage: &[&str] = if run.stand_in_study() { &["emulator", "mock"] } else { &["emulator"] };
    if run.stand_in_study() {
        r.stage("mock", &[], &[r.paths.measurements()], |r| r.mock())?;
    }
    let mut calibrate_upstream = data_stage.to_vec();
    if run.refine.is_some() {
        r.stage("refine", data_stage, &[r.refine_dir().join("rounds.json")], |r| r.refine())?;
        calibrate_upstream.push("refine");
    } else if opts.stage.as_deref() == Some("refine") {
        bail!("--stage refine: {} has no [run.refine] table", config.path.display());
    }
    let outputs =
        if run.stand_in_study() { r.paths.out.join("study.json") } else { r.paths.calibrate().join("cases.json") };
    r.stage("calibrate", &calibrate_upstream, &[outputs], |r| r.calibrate())?;
    r.stage("report", &["calibrate"], &[r.paths.out.join("report.html")], |r| r.report())?;
    if !run.candidates.is_empty() {
        let variants: Vec<PathBuf> =
            run.candidates.iter().map(|c| r.paths.candidate(c).join("emulator").join("emulator.json")).collect();
        r.stage("candidates", &["design"], &variants, |r| r.candidates())?;
        let diagnose_upstream: &[&str] = if run.refine.is_some() {
            &["emulator", "mock", "refine", "candidates"]
        } else {
            &["emulator", "mock", "candidates"]
        };
        r.stage(
            "diagnose",
            diagnose_upstream,
            &[r.paths.diagnose().join("diagnosis.json"), r.paths.diagnose().join("report.html")],
            |r| r.diagnose(),
        )?;
    } else if opts.stage.as_deref().is_some_and(|s| s == "candidates" || s == "diagnose") {
        bail!(
            "--stage {}: {} names no `candidates` in [run]",
            opts.stage.as_deref().unwrap_or_default(),
            config.path.display()
        );
    }
    Ok(r.outcomes)
}

impl Runner<'_> {
    /// The settings that define a stage's output, beyond its upstream keys.
    fn settings_of(&self, stage: &str) -> Result<serde_json::Value> {
        let run = self.run;
        let spec_bytes = std::fs::read(self.config.resolve(&run.design))
            .with_context(|| format!("reading design spec {}", self.config.resolve(&run.design).display()))?;
        Ok(match stage {
            // The design stage also writes the array script, which carries the simulate settings.
            "design" => {
                serde_json::json!({"spec": artifacts::sha256_hex(&spec_bytes), "points": run.points, "validation_points": run.validation_points, "seed": self.opts.seed,
                "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f})
            }
            "simulate" => {
                serde_json::json!({"simulator": serde_json::to_value(&run.simulator)?, "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f, "seed": self.opts.seed})
            }
            "ingest" => {
                serde_json::json!({"runs": [runs_fingerprint(&self.paths.design().join("runs"))?, runs_fingerprint(&self.paths.validation_design().join("runs"))?], "observables": self.all_observables()})
            }
            "emulator" => {
                serde_json::json!({"emulator": serde_json::to_value(&self.emulator)?, "seed": self.opts.seed})
            }
            "mock" => {
                serde_json::json!({"truth": self.truth_named()?, "delta_f": run.mock_delta_f, "events": run.mock_events, "oversample": run.oversample, "seed": self.opts.seed, "observables": self.all_observables()})
            }
            "calibrate" => {
                serde_json::json!({"config": self.analysis_hash()?, "data": self.data_hash()?, "sets": run.observable_sets, "kernels": run.kernels, "seed": self.opts.seed})
            }
            "refine" => {
                serde_json::json!({"config": self.analysis_hash()?, "data": self.data_hash()?, "refine": serde_json::to_value(&run.refine)?, "simulator": serde_json::to_value(&run.simulator)?,
                "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f, "set": self.diagnose_observables(), "kernels": run.kernels, "seed": self.opts.seed})
            }
            "candidates" => {
                serde_json::json!({"spec": artifacts::sha256_hex(&spec_bytes), "candidates": run.candidates, "points": run.candidate_points.unwrap_or(run.points), "events": run.events,
                "oversample": run.oversample, "delta_f": run.model_delta_f, "observables": self.all_observables(), "emulator": serde_json::to_value(&self.emulator)?, "seed": self.opts.seed})
            }
            "diagnose" => {
                serde_json::json!({"config": self.config.hash, "observables": self.diagnose_observables(), "seed": self.opts.seed})
            }
            _ => serde_json::json!({"config": self.analysis_hash()?}),
        })
    }

    fn stage(
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
    fn analysis_hash(&self) -> Result<String> {
        let text = std::fs::read_to_string(&self.config.path)
            .with_context(|| format!("reading {}", self.config.path.display()))?;
        let mut table: toml::Table =
            toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", self.config.path.display()))?;
        table.remove("run");
        Ok(artifacts::sha256_hex(serde_json::to_string(&table)?.as_bytes()))
    }

    fn all_observables(&self) -> Vec<String> {
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

    /// Seed of the stand-in's events, distinct for the training and validation designs.
    fn runs_seed(&self, validation: bool) -> u64 {
        self.opts.seed.wrapping_mul(31).wrapping_add(if validation { 104_729 } else { 11 })
    }

    /// The mock truth: `mock_truth`, or every θ's `truth` value from the config.
    fn truth_named(&self) -> Result<Vec<(String, f64)>> {
        if let Some(t) = &self.run.mock_truth {
            return Ok(t.iter().map(|(k, v)| (k.clone(), *v)).collect());
        }
        self.config
            .parameters
            .iter()
            .map(|(name, p)| {
                p.truth.map(|t| (name.clone(), t)).ok_or_else(|| {
                    anyhow!(
                        "{}: [parameters.{name}] needs a `truth` value: the mock data are made there",
                        self.config.path.display()
                    )
                })
            })
            .collect()
    }

    fn design(&mut self) -> Result<()> {
        let spec_path = self.config.resolve(&self.run.design);
        let bytes = std::fs::read(&spec_path).with_context(|| format!("reading {}", spec_path.display()))?;
        let mut spec = crate::engine::design::DesignSpec::load(&spec_path)?;
        let hash = artifacts::sha256_hex(&bytes);
        for (dir, n, seed) in [
            (self.paths.design(), self.run.points, self.opts.seed),
            (self.paths.validation_design(), self.run.validation_points, self.opts.seed.wrapping_add(7919)),
        ] {
            if let Some(command) = self.array_command(dir == self.paths.validation_design()) {
                spec.slurm.command = command;
            }
            // Runs of an earlier design belong to other points: the simulate stage
            // keeps unstamped point folders (SLURM's), so they must not survive here.
            let runs = dir.join("runs");
            if runs.exists() {
                std::fs::remove_dir_all(&runs)
                    .with_context(|| format!("removing runs of the previous design {}", runs.display()))?;
                println!("  removed {} (runs of the previous design)", runs.display());
            }
            let q = crate::engine::design::write_design(&spec, &hash, n, seed, &dir)?;
            println!("  {}: {} points, minimum distance {:.4}", dir.display(), q.points, q.min_distance);
        }
        Ok(())
    }

    /// The array script's command: the stand-in exactly as the simulate stage
    /// runs it (a user's simulator keeps the design spec's own [slurm] command).
    fn array_command(&self, validation: bool) -> Option<String> {
        let (None, Some(events)) = (&self.run.simulator, self.run.events) else { return None };
        Some(format!(
            "mdpipe simulate heavy-ion --design design.parquet --only {{id}} --delta-f {} --events {events} --oversample {} --layout hdf5 --seed {} --out runs",
            self.run.model_delta_f,
            self.run.oversample,
            self.runs_seed(validation)
        ))
    }

    fn simulate(&mut self) -> Result<()> {
        // Settings changed since the last run: its runs are not these. Forced
        // with the same settings, finished points are kept and only the
        // failed ones run again, with fresh attempts.
        let previous = read_stamp(&self.paths.stamp("simulate"));
        let stale = previous.as_ref().is_some_and(|s| s.key != self.running_key);
        let forced = previous.is_some() && !stale;
        for dir in [self.paths.design(), self.paths.validation_design()] {
            let runs = dir.join("runs");
            if stale && runs.exists() {
                std::fs::remove_dir_all(&runs).with_context(|| format!("removing outdated runs {}", runs.display()))?;
            }
            let attempts = runs.join(".attempts");
            if forced && attempts.exists() {
                std::fs::remove_dir_all(&attempts)
                    .with_context(|| format!("removing the previous attempts {}", attempts.display()))?;
            }
            std::fs::create_dir_all(&runs)?;
            std::fs::copy(dir.join("design.parquet"), runs.join("design.parquet"))?;
            let validation = dir == self.paths.validation_design();
            let spec = self.simulator(validation)?;
            let design = dir.join("design.parquet");
            let rows = crate::engine::design::read_points(&design)?;
            let n = rows.len();
            // Points already run (by an earlier attempt or the design's SLURM array) are kept.
            let points = rows
                .into_iter()
                .map(|(id, values)| execute::Point {
                    id,
                    param_file: crate::engine::design::parameter_file(&dir, id, n),
                    values,
                })
                .collect();
            let label = if validation { "validation design" } else { "design" };
            let job = execute::Job {
                spec: &spec,
                workdir: dir.clone(),
                design,
                runs: runs.clone(),
                points,
                label: label.into(),
                mdpipe: self.opts.mdpipe.clone(),
            };
            let report = execute::run(&job, self.opts.executor, self.opts.show_progress)?;
            println!(
                "  {}: {} points ({} had their run, {} ran, {} after a retry, {} failed) in {:.1} s",
                runs.display(),
                report.points,
                report.already_done,
                report.succeeded - report.already_done,
                report.retried.len(),
                report.failed.len(),
                report.seconds
            );
            if !report.failed.is_empty() {
                report.print_failures();
                let ids: Vec<i64> = report.failed.iter().map(|f| f.id).collect();
                println!("  warning: {} of {} points of the {label} failed and are left out (never averaged in): {ids:?}; see {}", ids.len(), n, execute::ExecutionReport::path(&runs).display());
            }
        }
        Ok(())
    }

    /// What the simulate stage runs: `[run.simulator]`, or the stand-in as one
    /// instance of it (the same command line as the design's SLURM array).
    fn simulator(&self, validation: bool) -> Result<SimulatorSpec> {
        if let Some(s) = &self.run.simulator {
            return Ok(s.clone());
        }
        let events = self.run.events.ok_or_else(|| anyhow!("[run] events is needed to run the stand-in"))?;
        let command = format!(
            "{{mdpipe}} simulate heavy-ion --design {{design}} --only {{id}} --point-folder --delta-f {} --events {events} --oversample {} --layout hdf5 --seed {} --out {{point}}",
            self.run.model_delta_f,
            self.run.oversample,
            self.runs_seed(validation)
        );
        Ok(SimulatorSpec {
            command,
            output: OutputKind::IebeMusic,
            time_limit: "1h".into(),
            retries: 1,
            parallel: None,
            slurm: Default::default(),
        })
    }

    fn ingest(&mut self) -> Result<()> {
        for (dir, out) in
            [(self.paths.design(), self.paths.training()), (self.paths.validation_design(), self.paths.validation())]
        {
            self.ingest_design(&dir, &out)?;
        }
        Ok(())
    }

    /// Ingests one design's runs into a training table of the study's observables.
    fn ingest_design(&self, dir: &Path, out: &Path) -> Result<()> {
        let keep = self.all_observables();
        let (mut ingested, design_df) = match self.run.output() {
            OutputKind::IebeMusic => crate::engine::ingest::ingest_runs(
                &dir.join("runs"),
                Some(&dir.join("design.parquet")),
                &crate::engine::ingest::IngestSettings::default(),
            )?,
            OutputKind::Table | OutputKind::Exit => {
                crate::engine::ingest::tables::ingest_tables(&dir.join("runs"), Some(&dir.join("design.parquet")))?
            }
        };
        ingested.rows.retain(|r| keep.contains(&r.observable));
        let dropped = drop_incomplete_points(&mut ingested.rows);
        for (id, what) in &dropped {
            println!("  design point {id} left out: {what} undefined (a failed v_n{{2}} measurement, listed in the ingest report)");
        }
        let flagged: Vec<i64> =
            ingested.report.points.iter().filter(|p| p.flagged.is_some()).map(|p| p.design_id).collect();
        if !flagged.is_empty() {
            println!("  design points flagged by ingest and left out: {flagged:?}");
        }
        if !ingested.report.missing_points.is_empty() {
            println!(
                "  warning: design points without a run (failed, see runs/execution.json) left out of {}: {:?}",
                out.display(),
                ingested.report.missing_points
            );
        }
        let report = crate::engine::ingest::write(&ingested, design_df.as_ref(), out)?;
        let points: std::collections::BTreeSet<i64> = ingested.rows.iter().map(|r| r.design_id).collect();
        println!(
            "  {}: {} points ({} left out); report {}",
            out.display(),
            points.len(),
            dropped.len() + flagged.len(),
            report.display()
        );
        Ok(())
    }

    fn emulator(&mut self) -> Result<()> {
        if self.config.emulator.is_none() {
            bail!("{}: the emulator stage needs an [emulator] table", self.config.path.display());
        }
        let (_, r) = crate::engine::emulator::train_and_save(
            &self.config.path,
            &self.paths.training(),
            None,
            &self.paths.emulator(),
            self.opts.seed,
        )?;
        println!(
            "  {} points x {} outputs -> {} components in {:.1} s",
            r.n_points, r.n_outputs, r.n_components, r.training_seconds
        );
        let v = crate::engine::emulator::validate::run(
            &self.paths.emulator(),
            Some(&self.paths.validation()),
            5,
            self.opts.seed,
        )?;
        if let Some(h) = &v.holdout {
            crate::engine::emulator::validate::print("held-out design", h);
        }
        Ok(())
    }

    fn mock(&mut self) -> Result<()> {
        let params = HeavyIonParams::from_named(&self.truth_named()?)?;
        let mock_delta_f = self.run.mock_delta_f.clone().unwrap_or_default();
        let mock_events = self.run.mock_events.unwrap_or_default();
        let delta_f: DeltaF = mock_delta_f.parse()?;
        let runs = self.paths.mock().join("runs");
        if runs.exists() {
            std::fs::remove_dir_all(&runs)?;
        }
        std::fs::create_dir_all(&runs)?;
        heavy_ion::simulate_runs(
            &[(0, params)],
            delta_f,
            mock_events,
            self.run.oversample,
            mock_seed(self.opts.seed),
            Layout::Hdf5,
            &runs,
        )?;
        let (ingested, _) =
            crate::engine::ingest::ingest_runs(&runs, None, &crate::engine::ingest::IngestSettings::default())?;
        let undefined: Vec<String> = ingested.report.points.iter().flat_map(|p| p.undefined_bins.clone()).collect();
        if !undefined.is_empty() {
            println!("  mock bins left out (undefined): {}", undefined.join(", "));
        }
        let keep = self.all_observables();
        let data: Vec<Measurement> = ingested
            .rows
            .iter()
            .filter(|r| keep.contains(&r.observable))
            .map(|r| Measurement::new(&r.observable, r.x, r.value, r.error))
            .collect();
        let prov = Provenance::new(
            self.config.hash.clone(),
            artifacts::measurements_hash(&data),
            self.opts.seed,
            &format!("run --stage mock: {mock_events} events, delta-f {mock_delta_f}"),
        );
        artifacts::write_measurements(&self.paths.measurements(), &data, Some(&prov))?;
        // The bins' jackknife covariance over the same events, for `[data] covariance`.
        let mut kept = ingested;
        kept.rows.retain(|r| keep.contains(&r.observable));
        if let Some(entries) = crate::engine::ingest::single_point_covariance(&kept) {
            crate::base::covariance::write_covariance_csv(&self.paths.mock().join("covariance.csv"), &entries)?;
        }
        println!(
            "  {} values from {mock_events} events (delta-f {mock_delta_f}) -> {}",
            data.len(),
            self.paths.measurements().display()
        );
        Ok(())
    }

    /// The analysis config pointed at the study's emulator (refined, with
    /// `[run.refine]`) and mock data.
    fn study_config(&self) -> Result<Config> {
        Ok(self.study_config_with(&self.study_emulator()?))
    }

    /// The analysis config pointed at `emulator` and this run's mock data.
    fn study_config_with(&self, emulator: &Path) -> Config {
        let mut c = self.config.clone();
        c.model = EmulatorFamily::model_table(&absolute(emulator));
        if self.run.stand_in_study() {
            c.data.measurements = absolute(&self.paths.measurements());
            // The mock's bins are counted from the same events (correlated by
            // 0.6-0.95 within a spectrum); with errors alone the likelihood
            // is overconfident and the MD fits excluded ε_sw by 2-3 sd.
            let covariance = self.paths.mock().join("covariance.csv");
            c.data.covariance = covariance.exists().then(|| absolute(&covariance));
        }
        c
    }

    /// The study's analysis: the stand-in's emulator as the model, the
    /// stand-in itself as the `[truth]` process.
    fn analysis(&self, config: &Config) -> Result<Analysis> {
        let mut families = Registry::new();
        families.register(Arc::new(EmulatorFamily)).register(Arc::new(HeavyIonFamily));
        let mut analysis = Analysis::resolve(config, &families)?;
        // The emulator knows no units; the stand-in's come first, as in its figures.
        if self.run.stand_in_study() {
            analysis.units = HeavyIonFamily.units(config).or(&analysis.units);
        }
        Ok(analysis)
    }

    /// The calibration cases: every observable set × kernel, with its seed and key.
    fn cases(&self) -> Result<Vec<Case>> {
        let mut cases = Vec::new();
        for (i, set) in self.run.observable_sets.iter().enumerate() {
            for (j, k) in self.run.kernels.iter().enumerate() {
                let kernel = DiscrepancyKernel::parse(k)
                    .ok_or_else(|| anyhow!("[run] kernels: unknown kernel {k:?} (use none, I or II)"))?;
                let name = compare::case_dir_name(set, kernel);
                let seed = self.opts.seed.wrapping_add((i * 3 + j) as u64 * 1_000_003);
                let material = serde_json::json!({"config": self.analysis_hash()?, "data": self.data_hash()?, "set": set, "kernel": k, "seed": seed, "emulator": self.keys.get("emulator"), "mock": self.keys.get("mock"), "refine": self.keys.get("refine")});
                let key = artifacts::sha256_hex(material.to_string().as_bytes());
                cases.push(Case {
                    index: cases.len(),
                    dir: self.paths.calibrate().join(&name),
                    stamp: self.paths.stamp(&format!("calibrate/{name}")),
                    name,
                    set: set.clone(),
                    kernel,
                    seed,
                    key,
                });
            }
        }
        Ok(cases)
    }

    /// Whether a case finished earlier with the same key (so an interrupted stage resumes case by case).
    fn case_done(&self, c: &Case) -> bool {
        !self.opts.force && read_stamp(&c.stamp).is_some_and(|s| s.key == c.key) && c.dir.join("summary.json").exists()
    }

    fn calibrate_case(&self, analysis: &Analysis, c: &Case) -> Result<()> {
        let ov = Overrides { kernel: Some(c.kernel), observables: Some(c.set.clone()), ..Default::default() };
        let problem = Problem::new(analysis, &ov)?;
        // Killed mid-case, the case resumes from its last saved tempering step.
        let checkpoint = calibrate::checkpoint::Checkpointing::new(
            &c.dir.join(".checkpoint"),
            calibrate::checkpoint_key(&problem, c.seed),
            None,
        );
        let cal = calibrate::run_and_write(&problem, c.seed, observer(self.opts.show_progress), &checkpoint, &c.dir)?;
        let seconds = cal.summary.diagnostics.wall_seconds;
        let prov = Provenance::new(
            self.config.hash.clone(),
            String::new(),
            c.seed,
            &format!("run {} --stage calibrate ({})", self.config.path.display(), c.name),
        );
        artifacts::write_json_atomic(
            &c.stamp,
            &Stamp {
                stage: format!("calibrate/{}", c.name),
                key: c.key.clone(),
                output_key: String::new(),
                seconds,
                provenance: prov,
            },
        )?;
        println!("  {:<60} {seconds:>6.1} s", c.name);
        Ok(())
    }

    /// Under `--executor slurm`, the cases not yet done go out as one job
    /// array, each task `mdpipe run … --stage calibrate --case <index>`; a case
    /// whose task failed is then calibrated here, with the others kept.
    fn calibrate_as_array(&self, cases: &[Case]) -> Result<()> {
        let todo: Vec<&Case> = cases.iter().filter(|c| !self.case_done(c)).collect();
        if todo.is_empty() {
            return Ok(());
        }
        let out = absolute(&self.paths.out);
        let command = format!(
            "{{mdpipe}} run {} --out {} --seed {} --stage calibrate --case {{id}}",
            execute::spec::shell_quote(&absolute(&self.config.path).display().to_string()),
            execute::spec::shell_quote(&out.display().to_string()),
            self.opts.seed
        );
        let template = self.run.simulator.clone();
        let spec = SimulatorSpec {
            command,
            output: OutputKind::Exit,
            time_limit: self.run.calibration_time_limit.clone(),
            retries: template.as_ref().map_or(1, |t| t.retries),
            parallel: None,
            slurm: template.map(|t| t.slurm).unwrap_or_default(),
        };
        let runs = self.paths.calibrate().join(".array");
        let points = todo
            .iter()
            .map(|c| execute::Point { id: c.index as i64, values: BTreeMap::new(), param_file: runs.join("none") })
            .collect();
        let job = execute::Job {
            spec: &spec,
            workdir: out.clone(),
            design: runs.join("none"),
            runs: runs.clone(),
            points,
            label: "calibrations".into(),
            mdpipe: self.opts.mdpipe.clone(),
        };
        std::fs::create_dir_all(&runs)?;
        match execute::run(&job, Executor::Slurm, self.opts.show_progress) {
            Ok(report) if report.failed.is_empty() => {}
            Ok(report) => {
                report.print_failures();
                println!(
                    "  warning: {} calibration task(s) failed under Slurm; those cases run here",
                    report.failed.len()
                );
            }
            Err(e) => println!("  warning: {e:#}; the cases run here"),
        }
        Ok(())
    }

    fn calibrate(&mut self) -> Result<()> {
        let config = self.study_config()?;
        let analysis = self.analysis(&config)?;
        let cases = self.cases()?;
        if let Some(index) = self.opts.case {
            // One array task: this case only; the stage is assessed and stamped by the mdpipe that submitted it.
            let c = cases
                .get(index)
                .ok_or_else(|| anyhow!("--case {index}: the study has {} calibration cases", cases.len()))?;
            return if self.case_done(c) { Ok(()) } else { self.calibrate_case(&analysis, c) };
        }
        if self.opts.executor == Executor::Slurm {
            self.calibrate_as_array(&cases)?;
        }
        let mut dirs = Vec::new();
        for c in &cases {
            if self.case_done(c) {
                println!("  {:<60} done earlier, kept", c.name);
            } else {
                self.calibrate_case(&analysis, c)?;
            }
            dirs.push(c.dir.clone());
        }
        if !self.run.stand_in_study() {
            return self.write_cases(&dirs);
        }
        let truth_curve: BTreeMap<String, f64> = self.truth_named()?.into_iter().collect();
        let study = crate::systems::heavy_ion::study::assess(
            &config,
            &dirs,
            &truth_curve,
            &self.study_emulator()?,
            &self.paths.validation(),
            &self.paths.measurements(),
        )?;
        artifacts::write_json_atomic(&self.paths.out.join("study.json"), &study)?;
        let mut md = study.markdown();
        if let Some(rounds) = self.rounds()? {
            md.push_str(&rounds.study_section());
        }
        artifacts::write_text_atomic(&self.paths.out.join("study.md"), &md)?;
        println!("{md}");
        Ok(())
    }

    /// Without mock data there is no truth to assess: each case's parameters
    /// and evidence, as `calibrate/cases.json` and `cases.md`.
    fn write_cases(&self, dirs: &[PathBuf]) -> Result<()> {
        let mut cases = Vec::new();
        let mut md = String::from(
            "| case | parameter | median | 95% interval | log evidence | converged |\n|---|---|---|---|---|---|\n",
        );
        for dir in dirs {
            let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json"))?)?;
            let case = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            for name in self.config.parameters.keys() {
                let p = &summary["parameters"][name];
                md.push_str(&format!(
                    "| {case} | {name} | {:.4} | [{:.4}, {:.4}] | {:.2} | {} |\n",
                    p["median"].as_f64().unwrap_or(f64::NAN),
                    p["q025"].as_f64().unwrap_or(f64::NAN),
                    p["q975"].as_f64().unwrap_or(f64::NAN),
                    summary["log_evidence"].as_f64().unwrap_or(f64::NAN),
                    summary["diagnostics"]["converged"]
                ));
            }
            cases.push(serde_json::json!({"case": case, "parameters": summary["parameters"], "log_evidence": summary["log_evidence"], "converged": summary["diagnostics"]["converged"]}));
        }
        let prov = Provenance::new(
            self.config.hash.clone(),
            self.data_hash()?,
            self.opts.seed,
            &format!("run {} --stage calibrate", self.config.path.display()),
        );
        let mut staged = artifacts::StagedWrites::new();
        staged.json(
            &self.paths.calibrate().join("cases.json"),
            &serde_json::json!({"cases": cases, "provenance": prov}),
        )?;
        staged.text(&self.paths.calibrate().join("cases.md"), &md)?;
        staged.commit()?;
        println!("{md}");
        Ok(())
    }

    /// SHA-256 of the measurements the calibrations use (the config's, when there is no mock stage).
    fn data_hash(&self) -> Result<String> {
        if self.run.stand_in_study() {
            return Ok(String::new());
        }
        let path = self.config.resolve(&self.config.data.measurements);
        Ok(artifacts::sha256_hex(
            &std::fs::read(&path).with_context(|| format!("reading the measurements {}", path.display()))?,
        ))
    }

    fn report(&mut self) -> Result<()> {
        if !self.run.stand_in_study() {
            let html = crate::engine::report::build(
                &[self.paths.calibrate(), self.study_emulator()?],
                &format!("mdpipe run: {}", self.config.name),
                &[],
            )?;
            artifacts::write_text_atomic(&self.paths.out.join("report.html"), &html)?;
            println!("  {}", self.paths.out.join("report.html").display());
            return Ok(());
        }
        let study: crate::systems::heavy_ion::study::Study =
            serde_json::from_str(&std::fs::read_to_string(self.paths.out.join("study.json"))?)?;
        let mut dirs = vec![self.paths.calibrate(), self.study_emulator()?];
        dirs.dedup();
        let html =
            crate::engine::report::build(&dirs, &format!("mdpipe run: {}", self.config.name), &[&HeavyIonFigures])?;
        let html = html.replacen("</h1>\n", &format!("</h1>\n{}", study.html()), 1);
        artifacts::write_text_atomic(&self.paths.out.join("report.html"), &html)?;
        println!("  {}", self.paths.out.join("report.html").display());
        Ok(())
    }
}

impl Runner<'_> {
    /// Diagnose works on the last (largest) observable set.
    fn diagnose_observables(&self) -> Vec<String> {
        self.run.observable_sets.last().cloned().unwrap_or_default()
    }

    /// One variant emulator per library candidate: a design over θ and the
    /// candidate's parameter, stand-in runs with the physics switched on
    /// (same events and seeds scheme as the model's), ingest, training.
    fn candidates(&mut self) -> Result<()> {
        let run = self.run;
        let spec_path = self.config.resolve(&run.design);
        let spec_hash = artifacts::sha256_hex(
            &std::fs::read(&spec_path).with_context(|| format!("reading {}", spec_path.display()))?,
        );
        let base_settings = self
            .emulator
            .clone()
            .ok_or_else(|| anyhow!("{}: the candidates stage needs an [emulator] table", self.config.path.display()))?;
        let model_delta_f: DeltaF = run.model_delta_f.parse()?;
        for (k, name) in run.candidates.iter().enumerate() {
            let cand = heavy_ion::candidate(name)?;
            let dir = self.paths.candidate(name);
            if dir.exists() {
                std::fs::remove_dir_all(&dir)
                    .with_context(|| format!("removing the previous variant {}", dir.display()))?;
            }
            let mut spec = crate::engine::design::DesignSpec::load(&spec_path)?;
            let mut settings = base_settings.clone();
            if let Some(p) = cand.design_parameter() {
                settings.parameters.push(p.name.clone());
                spec.parameters.push(p);
            }
            let seed = self.opts.seed.wrapping_add(1_000 * (k as u64 + 1));
            let delta_f = cand.delta_f(model_delta_f);
            let design_dir = dir.join("design");
            spec.slurm.command = format!(
                "mdpipe simulate heavy-ion --design design.parquet --only {{id}} --delta-f {} --events {} --oversample {} --layout hdf5 --seed {seed} --out runs",
                if cand.shear_delta_f { "grad" } else { run.model_delta_f.as_str() },
                run.events.unwrap_or_default(),
                run.oversample
            );
            crate::engine::design::write_design(
                &spec,
                &spec_hash,
                run.candidate_points.unwrap_or(run.points),
                seed,
                &design_dir,
            )?;
            let d = heavy_ion::read_design_points(&design_dir.join("design.parquet"))?;
            let runs = design_dir.join("runs");
            std::fs::create_dir_all(&runs)?;
            std::fs::copy(design_dir.join("design.parquet"), runs.join("design.parquet"))?;
            let points: Vec<(i64, HeavyIonParams)> = d.ids.into_iter().zip(d.points).collect();
            heavy_ion::simulate_runs(
                &points,
                delta_f,
                run.events.unwrap_or_default(),
                run.oversample,
                seed,
                Layout::Hdf5,
                &runs,
            )?;
            let training = dir.join("training.parquet");
            self.ingest_design(&design_dir, &training)?;
            let command = format!("run {} --stage candidates ({name})", self.config.path.display());
            let (_, r) = crate::engine::emulator::train_with_settings(
                &settings,
                &self.config.hash,
                &command,
                &training,
                None,
                &dir.join("emulator"),
                seed,
            )?;
            println!(
                "  {name}: {} points x {} outputs -> {} components ({})",
                r.n_points,
                r.n_outputs,
                r.n_components,
                settings.parameters.join(", ")
            );
            // A variant decides verdicts as much as the base emulator does: validate it too
            // (5-fold cross-validation, as no held-out design is run for it).
            let v = crate::engine::emulator::validate::run(&dir.join("emulator"), None, 5, seed)?;
            if let Some(cv) = &v.cross_validation {
                crate::engine::emulator::validate::print(&format!("  {name}: 5-fold cross-validation"), cv);
            }
        }
        Ok(())
    }

    /// `mdpipe diagnose` on the mock data with the library variants declared;
    /// when the verdict rests on variant emulators and `[run.refine]
    /// variant_budget` allows, they are refined and the diagnosis made again.
    fn diagnose(&mut self) -> Result<()> {
        let mut config = self.study_config()?;
        config.candidates = self
            .run
            .candidates
            .iter()
            .map(|name| {
                heavy_ion::candidate(name)?
                    .declaration(absolute(&self.paths.candidate(name).join("emulator")))
                    .to_table()
            })
            .collect::<Result<_>>()?;
        let out = self.paths.diagnose();
        // A previous run's refined variants are of other settings (its runs would mix with new ones).
        if out.join("refine").exists() {
            std::fs::remove_dir_all(out.join("refine")).with_context(|| {
                format!("removing the previous variant refinement {}", out.join("refine").display())
            })?;
        }
        let overrides = Overrides { observables: Some(self.diagnose_observables()), ..Default::default() };
        let settings = crate::engine::diagnose::DiagnoseSettings::default();
        let seed = self.opts.seed.wrapping_add(77);
        let analysis = self.analysis(&config)?;
        let mut d = crate::engine::diagnose::run(
            &analysis,
            &overrides,
            seed,
            &settings,
            Some(&out),
            observer(self.opts.show_progress),
        )?;
        if self.refine_variants(&mut config, &analysis, &overrides, &d.diagnosis)? {
            crate::engine::diagnose::print(&d.diagnosis);
            artifacts::write_json_atomic(&out.join("refine").join("diagnosis_before.json"), &d.diagnosis)?;
            println!("  refined the variant emulators the verdict listed; diagnosing again");
            d = crate::engine::diagnose::run(
                &self.analysis(&config)?,
                &overrides,
                seed,
                &settings,
                Some(&out),
                observer(self.opts.show_progress),
            )?;
        }
        crate::engine::diagnose::print(&d.diagnosis);
        crate::engine::report::write(
            std::slice::from_ref(&out),
            &out.join("report.html"),
            &format!("mdpipe run: {} (diagnose)", self.config.name),
            &[&HeavyIonFigures],
        )?;
        println!("  {}", out.join("report.html").display());
        Ok(())
    }
}

fn read_stamp(path: &Path) -> Option<Stamp> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

fn mock_seed(seed: u64) -> u64 {
    seed.wrapping_mul(31).wrapping_add(977)
}

/// A cheap content fingerprint of a runs folder: every file's path and size.
fn runs_fingerprint(dir: &Path) -> Result<String> {
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

/// Removes design points that lack any output another point has (an undefined
/// v_n{2} bin), since the emulator needs every output at every point. Returns
/// the points removed with what they lacked.
fn drop_incomplete_points(rows: &mut Vec<crate::engine::ingest::IngestedRow>) -> Vec<(i64, String)> {
    use std::collections::{BTreeMap, BTreeSet};
    let key = |r: &crate::engine::ingest::IngestedRow| format!("{}[{}]", r.observable, r.x);
    let all: BTreeSet<String> = rows.iter().map(key).collect();
    let mut have: BTreeMap<i64, BTreeSet<String>> = BTreeMap::new();
    for r in rows.iter() {
        have.entry(r.design_id).or_default().insert(key(r));
    }
    let dropped: Vec<(i64, String)> = have
        .iter()
        .filter(|(_, h)| h.len() < all.len())
        .map(|(id, h)| (*id, all.difference(h).cloned().collect::<Vec<_>>().join(", ")))
        .collect();
    rows.retain(|r| !dropped.iter().any(|(id, _)| *id == r.design_id));
    dropped
}
