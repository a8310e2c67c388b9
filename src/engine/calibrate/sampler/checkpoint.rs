//! Checkpoints of long runs: a sampler saves its whole state as one
//! serializable value, so a run that is killed, or stopped at a time limit (a
//! SLURM job's wall time), resumes from there and ends with exactly the result
//! an uninterrupted run would have given (same seed, same draws).
//!
//! Each state is one JSON file `<name>.json` in the checkpoint folder, holding
//! `{key, state}`. Floats are stored as their bit patterns ([`f64_bits`]), so
//! nothing is rounded. A file whose key differs (other data, settings or
//! seed) is ignored with a message, never resumed. This module knows no
//! sampler: it stores whatever state it is given.

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
    /// Save at most this often (0: after every step).
    pub min_interval: Duration,
    pub started: Instant,
}

/// What one checkpoint file holds.
#[derive(serde::Serialize, serde::Deserialize)]
struct Saved<S> {
    key: String,
    state: S,
}

impl Checkpointing {
    pub fn new(dir: &Path, key: String, time_limit: Option<Duration>) -> Self {
        Checkpointing {
            dir: dir.to_path_buf(),
            key,
            time_limit,
            min_interval: Duration::from_secs(10),
            started: Instant::now(),
        }
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(format!("{name}.json"))
    }

    pub fn out_of_time(&self) -> bool {
        self.time_limit.is_some_and(|t| self.started.elapsed() >= t)
    }

    /// The state saved under `name`, if it belongs to this run.
    pub fn load<S: serde::de::DeserializeOwned>(&self, name: &str) -> Option<S> {
        let path = self.path(name);
        let text = std::fs::read_to_string(&path).ok()?;
        match serde_json::from_str::<Saved<S>>(&text) {
            Ok(v) if v.key == self.key => Some(v.state),
            Ok(_) => {
                crate::base::messages::note!(
                    "note: ignoring checkpoint {} (made by another run: data, settings or seed differ)",
                    path.display()
                );
                None
            }
            Err(e) => {
                crate::base::messages::note!("note: ignoring unreadable checkpoint {}: {e}", path.display());
                None
            }
        }
    }

    /// Saves `state` under `name`. A failed save only costs the resume, never
    /// the run, so it is reported and not returned.
    pub fn save<S: serde::Serialize>(&self, name: &str, state: &S) {
        let path = self.path(name);
        if let Err(e) = crate::base::artifacts::write_json_atomic(&path, &Saved { key: self.key.clone(), state }) {
            crate::base::messages::note!("warning: could not save checkpoint {}: {e:#}", path.display());
        }
    }

    /// Removes the folder once the run has finished.
    pub fn clear(&self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// `#[serde(with = "f64_bits")]`: a `Vec<f64>` stored as its bit patterns.
pub mod f64_bits {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(v.iter().map(|x| x.to_bits()))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        Ok(Vec::<u64>::deserialize(d)?.into_iter().map(f64::from_bits).collect())
    }
}

/// `#[serde(with = "f64_bits_rows")]`: a `Vec<Vec<f64>>` stored as bit patterns.
pub mod f64_bits_rows {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &[Vec<f64>], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(v.iter().map(|row| row.iter().map(|x| x.to_bits()).collect::<Vec<u64>>()))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<f64>>, D::Error> {
        let rows = Vec::<Vec<u64>>::deserialize(d)?;
        Ok(rows.into_iter().map(|row| row.into_iter().map(f64::from_bits).collect()).collect())
    }
}

/// `#[serde(with = "f64_bit")]`: one `f64` stored as its bit pattern.
pub mod f64_bit {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u64(v.to_bits())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(f64::from_bits(u64::deserialize(d)?))
    }
}
