//! Running a simulator at every point of a design, on this machine or as a
//! Slurm job array, with time limits, retries and a failure report.
//!
//! Both executors run the same per-point attempt script (`attempt`); they
//! differ only in how attempts are started and followed. A point's folder
//! `RUNS/NNNN` appears only when an attempt succeeded, so a restarted run keeps
//! finished points, and a failed point is reported and left out, never averaged in.

pub mod attempt;
pub mod local;
pub mod slurm;
pub mod spec;

pub use attempt::AttemptRecord;
pub use spec::{OutputKind, SimulatorSpec, SlurmSettings};

use crate::base::artifacts;
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

/// Where the design points run (parsed once, in `base::choices`).
pub use crate::base::choices::Executor;

/// One design point: its id, parameter values and iEBE-MUSIC parameter file.
pub struct Point {
    pub id: i64,
    pub values: BTreeMap<String, f64>,
    pub param_file: PathBuf,
}

/// A design to run.
pub struct Job<'a> {
    pub spec: &'a SimulatorSpec,
    /// The command's working folder (the design folder, holding design.parquet).
    pub workdir: PathBuf,
    pub design: PathBuf,
    pub runs: PathBuf,
    pub points: Vec<Point>,
    /// Name in progress lines and job names.
    pub label: String,
    /// The mdpipe executable, for `{mdpipe}` (a library caller's own binary is not it).
    pub mdpipe: PathBuf,
    /// The point with id `i` gets `{seed}` = `seed + i`: distinct designs
    /// need seeds far apart (`point_seed_base`).
    pub seed: u64,
}

/// A base of points' seeds for one design, from the study's seed and the
/// design's label: far apart for different labels, and below 2^52 so that
/// any language's arithmetic (a bash array script's too) adds ids exactly.
pub fn point_seed_base(study_seed: u64, label: &str) -> u64 {
    let digest = crate::base::artifacts::sha256_hex(format!("{study_seed}:{label}").as_bytes());
    u64::from_str_radix(&digest[..10], 16).unwrap_or(0) << 12
}

/// A point that failed every attempt.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FailedPoint {
    pub id: i64,
    pub attempts: Vec<AttemptRecord>,
}

/// `RUNS/execution.json`: what happened to every point.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ExecutionReport {
    pub executor: String,
    pub runs: String,
    pub command: String,
    pub points: usize,
    /// Points that had their run before this execution (printed, not stored:
    /// the report of a resumed run equals an uninterrupted one's).
    #[serde(skip)]
    pub already_done: usize,
    /// Points with a run, now.
    pub succeeded: usize,
    /// Points that succeeded only after a failed attempt.
    pub retried: Vec<i64>,
    pub failed: Vec<FailedPoint>,
    pub seconds: f64,
}

impl ExecutionReport {
    pub fn path(runs: &Path) -> PathBuf {
        runs.join("execution.json")
    }

    /// Prints the failures with their exit codes and log tails.
    pub fn print_failures(&self) {
        for f in &self.failed {
            crate::base::messages::say!("  point {:04} failed {} attempt(s):", f.id, f.attempts.len());
            for a in &f.attempts {
                crate::base::messages::say!("    {}: {}", a.tag, a.describe());
                for line in a.stderr_tail.lines() {
                    crate::base::messages::say!("      | {line}");
                }
            }
        }
    }
}

/// Runs every point of `job` that has no run yet, and writes `RUNS/execution.json`.
pub fn run(job: &Job, executor: Executor, show_progress: bool) -> Result<ExecutionReport> {
    let start = std::time::Instant::now();
    // The attempt script needs coreutils' timeout and util-linux's flock.
    for tool in ["timeout", "flock"] {
        if std::process::Command::new(tool).arg("--version").output().is_err() {
            bail!("{tool} not found on PATH: the attempt scripts of `mdpipe run` need `timeout` (coreutils) and `flock` (util-linux)");
        }
    }
    std::fs::create_dir_all(attempt::attempts_dir(&job.runs))
        .with_context(|| format!("creating {}", job.runs.display()))?;
    let mut todo = Vec::new();
    for p in &job.points {
        if job.runs.join(attempt::point_name(p.id)).exists() {
            continue;
        }
        let paths = spec::PointPaths {
            id: p.id,
            seed: job.seed.wrapping_add(p.id.max(0) as u64),
            folder: PathBuf::from("$MDPIPE_POINT"),
            param_file: abs(&p.param_file),
            design: abs(&job.design),
            mdpipe: job.mdpipe.clone(),
        };
        // The folder differs per attempt: the script exports it; the quoted
        // placeholder must expand, so it is left outside single quotes.
        let command = job.spec.render(&paths, &p.values).replace("'$MDPIPE_POINT'", "\"$MDPIPE_POINT\"");
        attempt::write_script(&job.runs, p.id, &command, &abs(&job.workdir), job.spec)?;
        todo.push(p.id);
    }
    let already_done = job.points.len() - todo.len();
    let mut tracker = Tracker::new(job, todo.len(), show_progress);
    if !todo.is_empty() {
        match executor {
            Executor::Local => local::run(job, &todo, &mut tracker)?,
            Executor::Slurm => slurm::run(job, &todo, &mut tracker)?,
        }
    }
    tracker.finish();
    let failed: Vec<FailedPoint> = todo
        .iter()
        .filter(|id| !job.runs.join(attempt::point_name(**id)).exists())
        .map(|&id| FailedPoint { id, attempts: tracker.records.get(&id).cloned().unwrap_or_default() })
        .collect();
    let report = ExecutionReport {
        executor: format!("{executor:?}").to_lowercase(),
        runs: job.runs.display().to_string(),
        command: job.spec.command.clone(),
        points: job.points.len(),
        already_done,
        succeeded: job.points.len() - failed.len(),
        retried: tracker
            .records
            .iter()
            .filter(|(_, r)| r.len() > 1 && r.last().is_some_and(AttemptRecord::succeeded))
            .map(|(id, _)| *id)
            .collect(),
        failed,
        seconds: start.elapsed().as_secs_f64(),
    };
    artifacts::write_json_atomic(&ExecutionReport::path(&job.runs), &report)?;
    if report.succeeded == 0 {
        report.print_failures();
        bail!(
            "{}: every design point failed (see {} and the logs in {})",
            job.label,
            ExecutionReport::path(&job.runs).display(),
            attempt::attempts_dir(&job.runs).display()
        );
    }
    Ok(report)
}

fn abs(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

/// Counts what the executors report and shows it: points done, running,
/// failed and retried, with an estimate of the time left.
pub struct Tracker {
    total: usize,
    done: usize,
    failed: usize,
    running: usize,
    max_attempts: usize,
    records: BTreeMap<i64, Vec<AttemptRecord>>,
    bar: indicatif::ProgressBar,
    label: String,
    plain: bool,
    last_line: std::time::Instant,
}

impl Tracker {
    fn new(job: &Job, total: usize, show_progress: bool) -> Self {
        let bar = indicatif::ProgressBar::new(total as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} points, ~{eta} left",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        if !show_progress {
            bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
        }
        // In a batch log (no terminal) a plain line now and then replaces the bar.
        let plain = show_progress && !std::io::stderr().is_terminal();
        Tracker {
            total,
            done: 0,
            failed: 0,
            running: 0,
            max_attempts: 1 + job.spec.retries as usize,
            records: BTreeMap::new(),
            bar,
            label: job.label.clone(),
            plain,
            last_line: std::time::Instant::now(),
        }
    }

    /// Attempts of `id` that have ended so far.
    pub fn attempts(&self, id: i64) -> usize {
        self.records.get(&id).map_or(0, Vec::len)
    }

    /// Whether `id` may be tried again.
    pub fn may_retry(&self, id: i64) -> bool {
        self.attempts(id) < self.max_attempts
    }

    /// An attempt ended. Returns whether the point should be tried again.
    pub fn ended(&mut self, id: i64, record: AttemptRecord) -> bool {
        let ok = record.succeeded();
        if !ok {
            self.bar.suspend(|| {
                crate::base::messages::say!(
                    "  {}: point {:04} attempt {} {}",
                    self.label,
                    id,
                    record.tag,
                    record.describe()
                )
            });
        }
        self.records.entry(id).or_default().push(record);
        if ok {
            self.done += 1;
            self.bar.inc(1);
            return false;
        }
        if self.may_retry(id) {
            return true;
        }
        self.failed += 1;
        self.bar.inc(1);
        false
    }

    /// Counts an attempt that ended before this execution (a restart) without
    /// printing it. Returns whether it succeeded.
    pub fn replay(&mut self, id: i64, record: AttemptRecord) -> bool {
        let ok = record.succeeded();
        self.records.entry(id).or_default().push(record);
        if ok || !self.may_retry(id) {
            self.done += usize::from(ok);
            self.failed += usize::from(!ok);
            self.bar.inc(1);
        }
        ok
    }

    pub fn set_running(&mut self, running: usize, pending: usize) {
        self.running = running;
        let msg = format!(
            "{}: {} done, {running} running, {pending} queued, {} failed, {} retried",
            self.label,
            self.done,
            self.failed,
            self.records.values().filter(|r| r.len() > 1).count()
        );
        if self.plain && self.last_line.elapsed().as_secs() >= 30 {
            crate::base::messages::say!("  {msg} (of {})", self.total);
            self.last_line = std::time::Instant::now();
        }
        self.bar.set_message(msg);
    }

    fn finish(&mut self) {
        self.bar.finish_and_clear();
    }
}
