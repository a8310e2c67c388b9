//! The local executor: attempts as child processes, a few at a time.
//!
//! An attempt is followed through its exit record, not its process, so an
//! attempt left running by a killed mdpipe (its script holds a lock) is
//! waited for after a restart instead of being started again.

use super::attempt;
use super::{Job, Tracker};
use anyhow::{Context, Result};
use std::collections::VecDeque;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// How often the running attempts are looked at. A slot stays empty for up
/// to this long after its attempt ends, which for a simulator of a fraction
/// of a second is a share of the stage (at 100 ms, 40 runs of a 10 ms
/// command took 2.3 s on two slots); a look is a stat and a `try_wait` per
/// attempt, nothing at this rate.
const POLL: Duration = Duration::from_millis(20);

struct Running {
    id: i64,
    tag: String,
    /// None for an attempt adopted from an earlier mdpipe.
    child: Option<Child>,
}

pub fn run(job: &Job, todo: &[i64], tracker: &mut Tracker) -> Result<()> {
    let parallel = job.spec.parallel.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let mut running: Vec<Running> = Vec::new();
    let mut queue: VecDeque<i64> = VecDeque::new();
    let ended = attempt::ended_by_point(&job.runs);
    for &id in todo {
        if replay_ended(job, id, ended.get(&id).map_or(&[], Vec::as_slice), tracker)? {
            continue;
        }
        let mut adopted = false;
        for tag in attempt::unfinished_tags(&job.runs, id) {
            if attempt::is_running_here(&job.runs, id, &tag) {
                running.push(Running { id, tag, child: None });
                adopted = true;
            } else {
                attempt::forget(&job.runs, id, &tag);
            }
        }
        if !adopted && tracker.may_retry(id) {
            queue.push_back(id);
        }
    }
    while !(running.is_empty() && queue.is_empty()) {
        let mut still = Vec::with_capacity(running.len());
        for mut r in running.drain(..) {
            match state_of(job, &mut r) {
                State::Running => still.push(r),
                State::Ended => {
                    let record = attempt::settle(&job.runs, r.id, &r.tag, job.spec.output)?;
                    if tracker.ended(r.id, record) {
                        queue.push_back(r.id);
                    }
                }
            }
        }
        running = still;
        while running.len() < parallel {
            let Some(id) = queue.pop_front() else { break };
            let tag = next_tag(job, id);
            running.push(Running { id, child: Some(spawn(job, id, &tag)?), tag });
        }
        tracker.set_running(running.len(), queue.len());
        std::thread::sleep(POLL);
    }
    Ok(())
}

/// Settles the attempts of `id` that ended before this execution (`tags`,
/// oldest first); true if the point is now done.
fn replay_ended(job: &Job, id: i64, tags: &[String], tracker: &mut Tracker) -> Result<bool> {
    for tag in tags {
        let record = attempt::settle(&job.runs, id, tag, job.spec.output)?;
        if tracker.replay(id, record) {
            return Ok(true);
        }
    }
    Ok(false)
}

enum State {
    Running,
    Ended,
}

fn state_of(job: &Job, r: &mut Running) -> State {
    if attempt::has_ended(&job.runs, r.id, &r.tag) {
        if let Some(c) = r.child.as_mut() {
            let _ = c.wait();
        }
        return State::Ended;
    }
    // Once the script process is gone, the attempt is followed through its
    // lock (a same-tag attempt from a killed mdpipe may be the one running).
    if r.child.as_mut().is_some_and(|c| matches!(c.try_wait(), Ok(Some(_)) | Err(_))) {
        r.child = None;
    }
    if r.child.is_some() || attempt::is_running_here(&job.runs, r.id, &r.tag) {
        return State::Running;
    }
    // The script may have written its record just before exiting.
    if !attempt::has_ended(&job.runs, r.id, &r.tag) {
        let _ = attempt::mark_lost(&job.runs, r.id, &r.tag);
    }
    State::Ended
}

/// `a<n>` after the highest attempt number used for `id` so far.
fn next_tag(job: &Job, id: i64) -> String {
    let prefix = format!("{}.a", attempt::point_name(id));
    let highest = std::fs::read_dir(attempt::attempts_dir(&job.runs))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.strip_prefix(&prefix)?.split('.').next()?.parse::<u32>().ok()
        })
        .max()
        .unwrap_or(0);
    format!("a{}", highest + 1)
}

fn spawn(job: &Job, id: i64, tag: &str) -> Result<Child> {
    let script = attempt::attempts_dir(&job.runs).join(format!("{}.sh", attempt::point_name(id)));
    // Output goes to the attempt's log; nothing is inherited, so an attempt
    // outliving mdpipe holds none of its pipes.
    Command::new("bash")
        .arg(&script)
        .arg(tag)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .with_context(|| format!("starting {}", script.display()))
}
