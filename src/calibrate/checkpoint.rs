//! Checkpoints of long SMC runs: each replicate saves its whole state after a
//! tempering step, so a run that is killed, or stopped at a time limit (a
//! SLURM job's wall time), resumes from there and ends with exactly the
//! result an uninterrupted run would have given (same seed, same draws).
//!
//! Files, in the checkpoint folder: `replicate_<k>.json` (a step's state) and
//! `replicate_<k>.done.json` (a finished replicate). Floats are stored as
//! their bit patterns, so nothing is rounded. A file whose key differs (other
//! data, settings or seed) is ignored with a message, never resumed.

use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where and how often a run saves its state.
#[derive(Clone, Debug)]
pub struct Checkpointing {
    pub dir: PathBuf,
    /// Identifies the run (problem, settings, seed).
    pub key: String,
    /// Stop cleanly, state saved, once this much wall time has passed.
    pub time_limit: Option<Duration>,
    /// Save at most this often (0: after every tempering step).
    pub min_interval: Duration,
    pub started: Instant,
}

impl Checkpointing {
    pub fn new(dir: &Path, key: String, time_limit: Option<Duration>) -> Self {
        Checkpointing { dir: dir.to_path_buf(), key, time_limit, min_interval: Duration::from_secs(10), started: Instant::now() }
    }

    pub(crate) fn state_path(&self, replicate: usize) -> PathBuf {
        self.dir.join(format!("replicate_{replicate}.json"))
    }

    pub(crate) fn done_path(&self, replicate: usize) -> PathBuf {
        self.dir.join(format!("replicate_{replicate}.done.json"))
    }

    pub(crate) fn out_of_time(&self) -> bool {
        self.time_limit.is_some_and(|t| self.started.elapsed() >= t)
    }

    /// Reads a saved file if it belongs to this run.
    pub(crate) fn load<T: serde::de::DeserializeOwned + Keyed>(&self, path: &Path) -> Option<T> {
        let text = std::fs::read_to_string(path).ok()?;
        match serde_json::from_str::<T>(&text) {
            Ok(v) if v.key() == self.key => Some(v),
            Ok(_) => {
                eprintln!("note: ignoring checkpoint {} (made by another run: data, settings or seed differ)", path.display());
                None
            }
            Err(e) => {
                eprintln!("note: ignoring unreadable checkpoint {}: {e}", path.display());
                None
            }
        }
    }

    pub(crate) fn save<T: serde::Serialize>(&self, path: &Path, value: &T) -> anyhow::Result<()> {
        crate::artifacts::write_json_atomic(path, value)
    }

    /// Removes the folder once the run has finished.
    pub fn clear(&self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

pub(crate) trait Keyed {
    fn key(&self) -> &str;
}

/// The run stopped at its time limit with every replicate's state saved.
#[derive(Debug)]
pub struct Stopped {
    pub dir: PathBuf,
    pub seconds: f64,
}

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "stopped at the time limit after {:.0} s with its state saved in {}; run the same command again to resume", self.seconds, self.dir.display())
    }
}
impl std::error::Error for Stopped {}

pub(crate) fn to_bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

pub(crate) fn from_bits(v: &[u64]) -> Vec<f64> {
    v.iter().map(|&b| f64::from_bits(b)).collect()
}

/// One replicate between tempering steps.
#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct ReplicateState {
    pub key: String,
    pub x: Vec<u64>,
    pub loglik: Vec<u64>,
    pub logprior: Vec<u64>,
    pub terms: Vec<u64>,
    pub rngs: Vec<Xoshiro256PlusPlus>,
    pub master: Xoshiro256PlusPlus,
    pub eve: Vec<usize>,
    pub scales: Vec<u64>,
    pub beta: u64,
    pub log_z: u64,
    pub stages: usize,
    pub last_acceptance: u64,
    pub steps: Vec<super::smc::SmcStep>,
    pub evaluations: u64,
    pub term_evaluations: u64,
}

impl Keyed for ReplicateState {
    fn key(&self) -> &str {
        &self.key
    }
}

/// A finished replicate.
#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct ReplicateDone {
    pub key: String,
    pub particles: Vec<u64>,
    pub log_evidence: u64,
    pub relative_variance: u64,
    pub steps: Vec<super::smc::SmcStep>,
    pub likelihood_evaluations: u64,
    pub term_evaluations: u64,
    pub unique_fraction: u64,
}

impl Keyed for ReplicateDone {
    fn key(&self) -> &str {
        &self.key
    }
}
