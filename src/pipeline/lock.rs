//! One `mdpipe run` writes an output folder at a time. Two runs into one
//! folder (a second terminal, a batch job resubmitted while the first still
//! runs) would interleave their stamps and overwrite each other's stages, so
//! the second stops at once and names the first.
//!
//! The lock is the operating system's advisory lock (`flock`) on
//! `OUT/.mdpipe-run.lock`: the kernel drops it with the process, so a run
//! that is killed leaves no stale lock and the next run resumes as before.
//! The file's text says who holds it. A calibrate array task (`--case`)
//! writes only its own case and takes no lock: the run that submitted the
//! array holds it. On a file system without locks the run goes on unlocked,
//! as it did before there were locks, rather than refusing to run at all.

use anyhow::{bail, Context, Result};
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::Path;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The lock's file name in the output folder.
pub(super) const LOCK_FILE: &str = ".mdpipe-run.lock";

/// Held while a run writes its output folder; released when dropped.
pub(super) struct RunLock {
    _file: Option<File>,
}

/// Takes the lock on `out`, or says which run holds it.
pub(super) fn take(out: &Path) -> Result<RunLock> {
    let path = out.join(LOCK_FILE);
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    match try_lock_patiently(&file) {
        Ok(()) => {
            // Who holds it, then when it started (unix seconds, for its age).
            let holder = format!("pid {} on {}: {}\n{}\n", std::process::id(), host(), command(), now());
            file.set_len(0)
                .and_then(|()| file.rewind())
                .and_then(|()| file.write_all(holder.as_bytes()))
                .with_context(|| format!("writing {}", path.display()))?;
            Ok(RunLock { _file: Some(file) })
        }
        Err(TryLockError::WouldBlock) => {
            let mut text = String::new();
            let _ = file.read_to_string(&mut text);
            bail!(
                "{}: another `mdpipe run` is writing this folder ({}); wait for it to end, or give this run another --out",
                out.display(),
                describe(&text)
            )
        }
        // No advisory locks here (some network file systems): run unlocked.
        Err(TryLockError::Error(_)) => Ok(RunLock { _file: None }),
    }
}

/// How long a held lock is retried before the run stops and names its holder.
const PATIENCE: Duration = Duration::from_secs(2);

/// `try_lock`, retried for [`PATIENCE`] while the lock is held.
///
/// A process that spawns a child copies every open file into it until the
/// child's `exec` closes them, and a copy keeps an `flock` held: a lock just
/// released by one run can be held for a moment by a child another thread of
/// the same program is starting (the test harness runs pipelines side by side).
/// A real second run holds the folder for far longer than the wait.
fn try_lock_patiently(file: &File) -> std::result::Result<(), TryLockError> {
    let deadline = Instant::now() + PATIENCE;
    loop {
        match file.try_lock() {
            Err(TryLockError::WouldBlock) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            other => return other,
        }
    }
}

/// The holder with its age in seconds, as a person reads it.
fn describe(holder: &str) -> String {
    let mut lines = holder.lines();
    let who = lines.next().unwrap_or("").trim();
    match (who, lines.next().and_then(|t| t.trim().parse::<u64>().ok())) {
        ("", _) => "its holder is still starting".to_string(),
        (who, Some(t)) => format!("{who}; running for {} s", now().saturating_sub(t)),
        (who, None) => who.to_string(),
    }
}

fn host() -> String {
    Some(crate::base::artifacts::host_name()).filter(|h| !h.is_empty()).unwrap_or_else(|| "an unknown host".into())
}

fn now() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0)
}

fn command() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_run_into_a_held_folder_stops_naming_the_first_and_may_go_once_it_ends() {
        let dir = std::env::temp_dir().join(format!("mdpipe-lock-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = take(&dir).unwrap();
        // A lock is held per open file, so a second open in this process stands for a second run.
        let err = take(&dir).err().expect("a second run into a held folder must stop").to_string();
        assert!(err.contains("another `mdpipe run` is writing this folder"), "{err}");
        assert!(err.contains(&format!("pid {}", std::process::id())) && err.contains("running for"), "{err}");
        drop(first);
        let again = take(&dir);
        assert!(again.is_ok(), "the folder stays locked after its run ended");
        drop(again);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_lock_held_a_moment_by_a_copy_of_the_released_file_is_waited_for() {
        let dir = std::env::temp_dir().join(format!("mdpipe-lock-copy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = take(&dir).unwrap();
        // A spawned child holds a copy of the open file until its exec: a dup stands for it.
        let copy = first._file.as_ref().unwrap().try_clone().unwrap();
        drop(first);
        let child = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(300));
            drop(copy);
        });
        assert!(take(&dir).is_ok(), "a lock released a moment later stopped the run");
        child.join().unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
