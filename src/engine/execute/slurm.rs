//! The Slurm executor: the points go out as one job array (`sbatch --array`),
//! followed with `squeue` and the attempts' exit records. Failed, timed-out or
//! vanished tasks go out again as a new array, up to the retry count. The
//! arrays submitted are kept in `RUNS/.attempts/slurm.json`, so a restarted
//! mdpipe (the login-node case) follows the same array instead of submitting again.

use super::attempt;
use super::spec::shell_quote;
use super::{Job, Tracker};
use crate::base::artifacts;
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

#[derive(Default, serde::Serialize, serde::Deserialize)]
struct State {
    submissions: Vec<Submission>,
}

#[derive(Clone, serde::Serialize, serde::Deserialize)]
struct Submission {
    job_id: String,
    ids: Vec<i64>,
}

fn state_path(runs: &Path) -> PathBuf {
    attempt::attempts_dir(runs).join("slurm.json")
}

pub fn run(job: &Job, todo: &[i64], tracker: &mut Tracker) -> Result<()> {
    if Command::new("sbatch").arg("--version").output().is_err() {
        bail!("sbatch not found: --executor slurm runs where Slurm's commands are (a login node), or use --executor local");
    }
    let poll = Duration::from_secs_f64(job.spec.slurm.poll_seconds.unwrap_or(10.0));
    let path = state_path(&job.runs);
    let mut state: State = match std::fs::read_to_string(&path) {
        Ok(text) => {
            serde_json::from_str(&text).with_context(|| format!("{}: not mdpipe's Slurm state", path.display()))?
        }
        Err(_) => State::default(),
    };
    let done = |id: i64| job.runs.join(attempt::point_name(id)).exists();
    let mut seen: BTreeSet<(i64, String)> = BTreeSet::new();
    let ended = attempt::ended_by_point(&job.runs);
    for &id in todo {
        for tag in ended.get(&id).cloned().unwrap_or_default() {
            seen.insert((id, tag.clone()));
            if tracker.replay(id, attempt::settle(&job.runs, id, &tag, job.spec.output)?) {
                break;
            }
        }
    }
    if let Some(last) = state.submissions.last() {
        crate::base::messages::say!("  {}: following array job {} from an earlier mdpipe", job.label, last.job_id);
    }
    loop {
        // squeue first: a task that has left the queue has written its record.
        let live = match state.submissions.last() {
            Some(s) => queued_tasks(&s.job_id)?,
            None => Vec::new(),
        };
        let ended = attempt::ended_by_point(&job.runs);
        for &id in todo {
            for tag in ended.get(&id).cloned().unwrap_or_default() {
                if seen.insert((id, tag.clone())) {
                    tracker.ended(id, attempt::settle(&job.runs, id, &tag, job.spec.output)?);
                }
            }
        }
        let mut never_started = Vec::new();
        if let Some(last) = state.submissions.last() {
            let tag = format!("j{}", last.job_id);
            for &id in &last.ids {
                let still_queued = live.iter().any(|(t, _)| *t == id);
                if still_queued || done(id) || attempt::has_ended(&job.runs, id, &tag) {
                    continue;
                }
                if !attempt::started(&job.runs, id, &tag) {
                    // Cancelled while pending (scancel): no attempt was made.
                    never_started.push(id);
                    continue;
                }
                attempt::mark_lost(&job.runs, id, &tag)?;
                seen.insert((id, tag.clone()));
                tracker.ended(id, attempt::settle(&job.runs, id, &tag, job.spec.output)?);
            }
        }
        if !never_started.is_empty() && live.is_empty() {
            return stop_cancelled(&mut state, &path, &never_started);
        }
        if !live.is_empty() {
            let job_id = state.submissions.last().map(|s| s.job_id.clone()).unwrap_or_default();
            stuck(&job_id, &live)?;
            let running = live.iter().filter(|(_, s)| s == "R" || s == "CG").count();
            tracker.set_running(running, live.len() - running);
            std::thread::sleep(poll);
            continue;
        }
        let again: Vec<i64> = todo.iter().copied().filter(|&id| !done(id) && tracker.may_retry(id)).collect();
        if again.is_empty() {
            return Ok(());
        }
        let job_id = submit(job, &again)?;
        crate::base::messages::say!("  {}: submitted array job {job_id} ({} points)", job.label, again.len());
        state.submissions.push(Submission { job_id, ids: again });
        artifacts::write_json_atomic(&path, &state)?;
    }
}

/// Tasks that left the queue without starting were cancelled (scancel), not
/// failed: they use no attempt. mdpipe stops, saying so, and forgets them
/// in its state, so that running it again submits them afresh.
fn stop_cancelled(state: &mut State, path: &Path, ids: &[i64]) -> Result<()> {
    let job_id = state.submissions.last().map(|s| s.job_id.clone()).unwrap_or_default();
    if let Some(last) = state.submissions.last_mut() {
        last.ids.retain(|id| !ids.contains(id));
    }
    artifacts::write_json_atomic(path, state)?;
    bail!(
        "{} task(s) of array job {job_id} left the queue without starting (cancelled, e.g. by scancel): points {ids:?} did not run and used none of their attempts; run the same command again to submit them",
        ids.len()
    )
}

/// Submits `ids` as one array; returns the array's job id.
fn submit(job: &Job, ids: &[i64]) -> Result<String> {
    let dir = std::path::absolute(attempt::attempts_dir(&job.runs))?;
    let s = &job.spec.slurm;
    let minutes = job.spec.time_limit_seconds().div_ceil(60) + 2;
    let name: String =
        job.label.chars().map(|c| if c.is_alphanumeric() || c == '_' || c == '-' { c } else { '_' }).collect();
    let mut script = format!("#!/bin/bash\n# Made by mdpipe: one design point per array task (the task id is the design id).\n#SBATCH --job-name=mdpipe-{name}\n#SBATCH --output={}/slurm-%A_%a.out\n#SBATCH --time={minutes}\n", dir.display());
    for (key, value) in [
        ("partition", s.partition.clone()),
        ("account", s.account.clone()),
        ("cpus-per-task", s.cpus_per_task.map(|c| c.to_string())),
        ("mem", s.mem.clone()),
    ] {
        if let Some(v) = value {
            script.push_str(&format!("#SBATCH --{key}={v}\n"));
        }
    }
    for extra in &s.extra {
        script.push_str(&format!("#SBATCH {extra}\n"));
    }
    script.push_str(&format!(
        "exec bash {}/\"$(printf '%04d' \"$SLURM_ARRAY_TASK_ID\")\".sh \"j$SLURM_ARRAY_JOB_ID\"\n",
        shell_quote(&dir.display().to_string())
    ));
    let path = dir.join("array.sbatch");
    artifacts::write_text_atomic(&path, &script)?;
    let mut array = ids.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(",");
    if let Some(p) = job.spec.parallel {
        array.push_str(&format!("%{p}"));
    }
    let out = Command::new("sbatch")
        .arg("--parsable")
        .arg(format!("--array={array}"))
        .arg(format!("--chdir={}", std::path::absolute(&job.workdir)?.display()))
        .arg(&path)
        .output()
        .context("running sbatch")?;
    if !out.status.success() {
        bail!("sbatch {} failed: {}", path.display(), String::from_utf8_lossy(&out.stderr).trim());
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let id = text.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        bail!("sbatch printed {:?}, not a job id", text.trim());
    }
    Ok(id)
}

/// The array's tasks still in the queue (pending, running or completing), as (design id, state).
fn queued_tasks(job_id: &str) -> Result<Vec<(i64, String)>> {
    let mut last_error = String::new();
    // The controller can be briefly unreachable; a restart would follow the same array anyway.
    for _ in 0..10 {
        let out = Command::new("squeue")
            .args(["-h", "-r", "-j", job_id, "-o", "%i %t %r"])
            .output()
            .context("running squeue")?;
        let stderr = String::from_utf8_lossy(&out.stderr);
        if out.status.success() {
            return Ok(String::from_utf8_lossy(&out.stdout).lines().flat_map(parse_task_line).collect());
        }
        // A finished job is forgotten by the controller after a while.
        if stderr.contains("Invalid job id") {
            return Ok(Vec::new());
        }
        last_error = stderr.trim().to_string();
        std::thread::sleep(Duration::from_secs(3));
    }
    Err(anyhow!("squeue -j {job_id} failed 10 times: {last_error}; the array keeps running, and mdpipe started again follows it"))
}

/// Pending reasons that waiting does not resolve (Slurm's squeue %r codes).
const NEVER_STARTS: [&str; 12] = [
    "JobHeldUser",
    "JobHeldAdmin",
    "PartitionConfig",
    "PartitionNodeLimit",
    "PartitionTimeLimit",
    "BadConstraints",
    "InvalidAccount",
    "InvalidQOS",
    "AccountNotAllowed",
    "QOSMaxWallDurationPerJobLimit",
    "DependencyNeverSatisfied",
    "PartitionDown",
];

/// Stops, rather than waits for ever, when every task left in the queue is
/// pending for a reason that waiting will not resolve.
fn stuck(job_id: &str, live: &[(i64, String)]) -> Result<()> {
    if live.iter().any(|(_, s)| !s.starts_with("PD")) {
        return Ok(());
    }
    let reasons: BTreeSet<&str> = live.iter().filter_map(|(_, s)| s.split_once(' ').map(|(_, r)| r)).collect();
    if reasons.is_empty() || !reasons.iter().all(|r| NEVER_STARTS.iter().any(|n| r.contains(n))) {
        return Ok(());
    }
    let reasons: Vec<&str> = reasons.into_iter().collect();
    bail!("array job {job_id}: every task left is pending for {}, which waiting does not resolve; cancel it (scancel {job_id}), mend [run.simulator] slurm settings or the job's hold, and run mdpipe again", reasons.join(", "))
}

/// "57_3 R" → [(3, "R")]; "57_[4-6,9%2] PD" → [(4, "PD"), (5, "PD"), (6, "PD"), (9, "PD")].
fn parse_task_line(line: &str) -> Vec<(i64, String)> {
    let mut parts = line.split_whitespace();
    let (Some(id), Some(code)) = (parts.next(), parts.next()) else { return Vec::new() };
    // A pending task keeps its reason: "PD JobHeldUser".
    let state = match (code, parts.next()) {
        ("PD", Some(reason)) => format!("PD {reason}"),
        _ => code.to_string(),
    };
    let state = state.as_str();
    let Some((_, task)) = id.split_once('_') else { return Vec::new() };
    let task = task.trim_start_matches('[').trim_end_matches(']');
    let task = task.split('%').next().unwrap_or("");
    let mut out = Vec::new();
    for piece in task.split(',') {
        match piece.split_once('-') {
            Some((a, b)) => {
                if let (Ok(a), Ok(b)) = (a.parse::<i64>(), b.parse::<i64>()) {
                    out.extend((a..=b).map(|i| (i, state.to_string())));
                }
            }
            None => out.extend(piece.parse::<i64>().ok().map(|i| (i, state.to_string()))),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn squeue_task_lines_in_both_forms() {
        assert_eq!(super::parse_task_line("57_3 R"), vec![(3, "R".to_string())]);
        let ids: Vec<i64> = super::parse_task_line("57_[4-6,9%2] PD").into_iter().map(|(i, _)| i).collect();
        assert_eq!(ids, vec![4, 5, 6, 9]);
        assert!(super::parse_task_line("57 R").is_empty());
        assert_eq!(super::parse_task_line("57_2 PD JobHeldUser"), vec![(2, "PD JobHeldUser".to_string())]);
    }

    #[test]
    fn a_queue_that_waiting_will_not_move_is_an_error() {
        let held = vec![(1, "PD JobHeldUser".to_string()), (2, "PD JobHeldUser".to_string())];
        let e = super::stuck("57", &held).unwrap_err().to_string();
        assert!(e.contains("JobHeldUser") && e.contains("scancel 57"), "{e}");
        // Waiting for resources, or some task running: keep following.
        assert!(super::stuck("57", &[(1, "PD Resources".to_string())]).is_ok());
        assert!(super::stuck("57", &[(1, "PD JobHeldUser".to_string()), (2, "R".to_string())]).is_ok());
    }
}
