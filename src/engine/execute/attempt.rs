//! One attempt at one design point, the same under every executor.
//!
//! mdpipe writes `RUNS/.attempts/NNNN.sh`, which takes a tag (`a1`, `a2`, … locally,
//! `j<array job id>` under Slurm). The script runs the rendered command in
//! `RUNS/.attempts/NNNN.TAG/` under `timeout`, holding a lock on
//! `NNNN.TAG.lock` while it runs, logging to `NNNN.TAG.log`, and at the end
//! writes `NNNN.TAG.exit` (`<exit code> <seconds>`). mdpipe then checks the
//! outputs and renames the folder to `RUNS/NNNN`: a point folder exists only
//! when complete, so a restart keeps it, and a failed attempt is never read.

use super::spec::{shell_quote, OutputKind, SimulatorSpec};
use crate::base::artifacts;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// The `.attempts` folder of a runs folder.
pub fn attempts_dir(runs: &Path) -> PathBuf {
    runs.join(".attempts")
}

pub fn point_name(id: i64) -> String {
    format!("{id:04}")
}

fn attempt_path(runs: &Path, id: i64, tag: &str, ext: &str) -> PathBuf {
    attempts_dir(runs).join(format!("{}.{tag}{ext}", point_name(id)))
}

/// Writes the attempt script of one point.
pub fn write_script(runs: &Path, id: i64, command: &str, workdir: &Path, spec: &SimulatorSpec) -> Result<PathBuf> {
    let dir = std::path::absolute(attempts_dir(runs))?;
    let name = point_name(id);
    let limit = spec.time_limit_seconds();
    let script = format!(
        r#"#!/bin/bash
# Made by mdpipe: one attempt at design point {id}. Usage: {name}.sh TAG
set -u
tag="$1"
base={dir}/{name}."$tag"
# Held while this attempt runs: a restarted mdpipe waits for it instead of
# starting another, and a second script with the same tag leaves at once.
exec 9>"$base.lock"
flock -n 9 || exit 0
rm -rf "$base" && mkdir -p "$base" || exit 1
export MDPIPE_POINT="$base" MDPIPE_ID={id}
cd {workdir} || {{ echo "cannot enter {workdir}" > "$base.log"; echo "1 0" > "$base.exit.tmp"; mv "$base.exit.tmp" "$base.exit"; exit 0; }}
start=$(date +%s%N)
timeout --kill-after=10 {limit} bash -c {command} > "$base.log" 2>&1 < /dev/null
code=$?
ms=$(( ($(date +%s%N) - start) / 1000000 ))
echo "$code $((ms / 1000)).$(printf '%03d' $((ms % 1000)))" > "$base.exit.tmp"
mv "$base.exit.tmp" "$base.exit"
"#,
        dir = shell_quote(&dir.display().to_string()),
        workdir = shell_quote(&workdir.display().to_string()),
        command = shell_quote(command),
    );
    let path = attempts_dir(runs).join(format!("{name}.sh"));
    artifacts::write_text_atomic(&path, &script)?;
    Ok(path)
}

/// How one attempt ended.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct AttemptRecord {
    pub tag: String,
    /// The command's exit code (124 and 137 after the time limit).
    pub exit_code: Option<i32>,
    pub timed_out: bool,
    /// The attempt vanished without an exit record (node failure, cancelled).
    pub lost: bool,
    pub seconds: f64,
    /// Why a zero exit was not a success (no outputs).
    pub problem: Option<String>,
    /// The last lines of its log (stdout and stderr).
    pub stderr_tail: String,
}

impl AttemptRecord {
    pub fn succeeded(&self) -> bool {
        self.exit_code == Some(0) && self.problem.is_none() && !self.lost
    }

    pub fn describe(&self) -> String {
        if self.lost {
            return "lost (no exit record: the task vanished)".into();
        }
        if self.timed_out {
            return format!("timed out after {:.0} s", self.seconds);
        }
        match (&self.problem, self.exit_code) {
            (Some(p), _) => p.clone(),
            (None, Some(c)) => format!("exit code {c}"),
            (None, None) => "no exit code".into(),
        }
    }
}

/// The ended attempts' tags of every point, oldest first, from one listing
/// of the attempts folder (a poll of a large array reads it once).
pub fn ended_by_point(runs: &Path) -> std::collections::BTreeMap<i64, Vec<String>> {
    let mut found: Vec<(i64, std::time::SystemTime, String)> = std::fs::read_dir(attempts_dir(runs))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let (id, tag) = name.strip_suffix(".exit")?.split_once('.')?;
            Some((id.parse().ok()?, e.metadata().and_then(|m| m.modified()).ok()?, tag.to_string()))
        })
        .collect();
    found.sort();
    let mut out: std::collections::BTreeMap<i64, Vec<String>> = std::collections::BTreeMap::new();
    for (id, _, tag) in found {
        out.entry(id).or_default().push(tag);
    }
    out
}

/// Whether an attempt has an exit record.
pub fn has_ended(runs: &Path, id: i64, tag: &str) -> bool {
    attempt_path(runs, id, tag, ".exit").exists()
}

/// Whether an attempt's script ever started (it takes its lock first thing).
pub fn started(runs: &Path, id: i64, tag: &str) -> bool {
    attempt_path(runs, id, tag, ".lock").exists()
}

/// Whether an attempt's script still holds its lock (it is running on this machine).
pub fn is_running_here(runs: &Path, id: i64, tag: &str) -> bool {
    lock_is_held(&attempt_path(runs, id, tag, ".lock"))
}

/// Tags of attempts that started (have a folder or lock) but have no exit record.
pub fn unfinished_tags(runs: &Path, id: i64) -> Vec<String> {
    let prefix = format!("{}.", point_name(id));
    let mut tags: Vec<String> = std::fs::read_dir(attempts_dir(runs))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let tag = name.strip_prefix(&prefix)?.strip_suffix(".lock")?.to_string();
            (!has_ended(runs, id, &tag)).then_some(tag)
        })
        .collect();
    tags.sort();
    tags
}

/// Records an attempt that left no exit record, so it counts and is not waited for.
pub fn mark_lost(runs: &Path, id: i64, tag: &str) -> Result<()> {
    artifacts::write_text_atomic(&attempt_path(runs, id, tag, ".exit"), "lost 0\n")?;
    let _ = std::fs::remove_dir_all(attempt_path(runs, id, tag, ""));
    Ok(())
}

/// Forgets an attempt interrupted with mdpipe itself (its script is gone and
/// wrote no exit record): not the point's failure, so it does not count.
pub fn forget(runs: &Path, id: i64, tag: &str) {
    let _ = std::fs::remove_dir_all(attempt_path(runs, id, tag, ""));
    let _ = std::fs::remove_file(attempt_path(runs, id, tag, ".lock"));
}

/// Reads an ended attempt; if it succeeded and its folder is still staged,
/// checks the outputs and moves the folder to `RUNS/NNNN`. Idempotent.
pub fn settle(runs: &Path, id: i64, tag: &str, output: OutputKind) -> Result<AttemptRecord> {
    let exit_path = attempt_path(runs, id, tag, ".exit");
    let text = std::fs::read_to_string(&exit_path).with_context(|| format!("reading {}", exit_path.display()))?;
    let mut fields = text.split_whitespace();
    let code_text = fields.next().unwrap_or("");
    let seconds = fields.next().and_then(|s| s.parse().ok()).unwrap_or(0.0);
    let lost = code_text == "lost";
    let exit_code = code_text.parse::<i32>().ok();
    let timed_out = matches!(exit_code, Some(124) | Some(137));
    let stderr_tail = tail(&attempt_path(runs, id, tag, ".log"), 5);
    let mut record =
        AttemptRecord { tag: tag.to_string(), exit_code, timed_out, lost, seconds, problem: None, stderr_tail };
    let staged = attempt_path(runs, id, tag, "");
    let done = runs.join(point_name(id));
    if record.exit_code == Some(0) && !lost {
        if done.exists() {
            return Ok(record);
        }
        record.problem = missing_outputs(&staged, output);
        if record.problem.is_none() {
            std::fs::rename(&staged, &done)
                .with_context(|| format!("moving {} to {}", staged.display(), done.display()))?;
            return Ok(record);
        }
    }
    // A failed attempt's outputs are never read; its log stays.
    let _ = std::fs::remove_dir_all(&staged);
    Ok(record)
}

fn missing_outputs(dir: &Path, output: OutputKind) -> Option<String> {
    let names: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    match output {
        OutputKind::Table if !names.iter().any(|n| n == "outputs.csv" || n == "outputs.parquet") => {
            Some("exit code 0 but no outputs.csv or outputs.parquet in the point folder".into())
        }
        OutputKind::IebeMusic if !names.iter().any(|n| n == "spvn_results.h5" || n.starts_with("spvn_results_")) => {
            Some("exit code 0 but no spvn_results.h5 or spvn_results_<i>/ in the point folder".into())
        }
        _ => None,
    }
}

/// The last `n` non-empty lines of a file.
fn tail(path: &Path, n: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// Removes a folder that may hold runs, first waiting for every attempt
/// still running in it: a killed mdpipe leaves its attempts running (they
/// outlive it by design, so a restart can adopt them), and removing their
/// folder under them fails or lets them write into its successor. An attempt
/// ends within its time limit, so the wait is bounded.
pub fn remove_after_attempts(dir: &Path) -> Result<()> {
    if !dir.exists() {
        return Ok(());
    }
    let locks = attempt_locks(dir);
    let running: Vec<&PathBuf> = locks.iter().filter(|l| lock_is_held(l)).collect();
    if !running.is_empty() {
        crate::base::messages::say!(
            "  waiting for {} attempt(s) of an earlier run still running in {} (each ends within its \
             time limit; stop them to go on at once)",
            running.len(),
            dir.display()
        );
    }
    for lock in running {
        if let Ok(f) = std::fs::OpenOptions::new().write(true).open(lock) {
            f.lock().with_context(|| format!("waiting for the attempt holding {}", lock.display()))?;
        }
    }
    std::fs::remove_dir_all(dir).with_context(|| format!("removing {}", dir.display()))
}

fn lock_is_held(lock: &Path) -> bool {
    let Ok(f) = std::fs::OpenOptions::new().write(true).open(lock) else { return false };
    matches!(f.try_lock(), Err(std::fs::TryLockError::WouldBlock))
}

/// Every attempt lock file in the `.attempts` folders under `dir`. Locks
/// lie directly in a runs folder's `.attempts`, so a runs folder's point
/// folders (a study's event files) and the attempts' own folders are not read.
fn attempt_locks(dir: &Path) -> Vec<PathBuf> {
    let children =
        |d: &Path| -> Vec<std::fs::DirEntry> { std::fs::read_dir(d).into_iter().flatten().flatten().collect() };
    if dir.file_name().is_some_and(|n| n == ".attempts") {
        return children(dir)
            .into_iter()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "lock"))
            .collect();
    }
    let attempts = attempts_dir(dir);
    if attempts.is_dir() {
        return attempt_locks(&attempts);
    }
    children(dir)
        .into_iter()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .flat_map(|e| attempt_locks(&e.path()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An attempt left running by a killed mdpipe, which writes into its
    /// folder a moment later: removal waits for it, so nothing is written
    /// into the folder after it is gone.
    #[test]
    fn removal_waits_for_an_attempt_still_running_in_the_folder() {
        let dir = std::env::temp_dir().join(format!("mdpipe-remove-after-{}", std::process::id()));
        let attempts = dir.join("runs").join(".attempts");
        std::fs::create_dir_all(&attempts).unwrap();
        let lock = attempts.join("0001.a1.lock");
        let late = attempts.join("0001.a1").join("late.txt");
        let script = format!(
            "exec 9>'{}'; flock 9; sleep 1; mkdir -p '{}' && echo late > '{}'",
            lock.display(),
            late.parent().unwrap().display(),
            late.display()
        );
        let mut orphan = std::process::Command::new("bash").args(["-c", &script]).spawn().unwrap();
        let start = std::time::Instant::now();
        while !lock_is_held(&lock) {
            assert!(start.elapsed().as_secs() < 10, "the stand-in attempt never took its lock");
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        remove_after_attempts(&dir).unwrap();
        orphan.wait().unwrap();
        assert!(!dir.exists(), "the attempt wrote into the folder after it was removed");
    }

    #[test]
    fn removal_of_a_missing_folder_is_a_no_op() {
        remove_after_attempts(Path::new("/nonexistent/mdpipe/runs")).unwrap();
    }
}
