//! The stages a study has, in the order it runs them: the generic stages
//! (one module each under `stage/`) and those its systems add.

use super::stage::{calibrate, candidates, design, diagnose, emulator, ingest, refine, report, simulate};
use super::stage::{AnyStage, Planned, Presence, StageId};
use super::study::Study;
use super::system::Systems;
use anyhow::{anyhow, bail, Result};

/// The stages every study may have (a system adds its own).
fn generic() -> Vec<&'static dyn AnyStage> {
    vec![
        &design::Design,
        &simulate::Simulate,
        &ingest::Ingest,
        &emulator::Emulator,
        &refine::Refine,
        &calibrate::Calibrate,
        &report::Report,
        &candidates::Candidates,
        &diagnose::Diagnose,
    ]
}

/// Every stage, the generic ones and those the systems add, in the order a
/// study runs them, each with the stages it reads. A system's stage runs
/// right after the stage it names (after the others placed there before it).
pub(crate) fn stages(systems: &Systems) -> Vec<Planned> {
    let mut stages: Vec<Planned> =
        generic().into_iter().map(|stage| Planned { stage, upstream: stage.upstream().to_vec() }).collect();
    let mut placed_after: Vec<StageId> = Vec::new();
    for added in systems.iter().flat_map(|system| system.stages()) {
        let anchor = stages.iter().position(|p| p.stage.id() == added.after);
        let anchor = anchor
            .unwrap_or_else(|| panic!("stage {} runs after {}, which no stage is", added.stage.id(), added.after));
        let mut at = anchor + 1;
        while at < stages.len() && placed_after.contains(&stages[at].stage.id()) {
            at += 1;
        }
        placed_after.push(added.stage.id());
        for reader in stages.iter_mut().filter(|p| added.read_by.contains(&p.stage.id())) {
            reader.upstream.push(added.stage.id());
        }
        stages.insert(at, Planned { stage: added.stage, upstream: added.stage.upstream().to_vec() });
    }
    stages
}

/// The stages this study has, in order; `--stage` naming one it has not,
/// or no stage at all, is refused with the names there are.
pub(super) fn plan(study: &Study<'_>, systems: &Systems) -> Result<Vec<Planned>> {
    let all = stages(systems);
    if let Some(only) = study.opts.stage.as_deref() {
        if !all.iter().any(|p| p.stage.id().name() == only) {
            let names: Vec<&str> = all.iter().map(|p| p.stage.id().name()).collect();
            return Err(anyhow!("unknown stage {only:?} (use {})", names.join(", ")));
        }
    }
    let mut planned = Vec::new();
    for p in all {
        match p.stage.present(study)? {
            Presence::Runs => planned.push(p),
            Presence::Absent(why) if study.opts.stage.as_deref() == Some(p.stage.id().name()) => {
                bail!("--stage {}: {why}", p.stage.id())
            }
            Presence::Absent(_) => {}
        }
    }
    Ok(planned)
}

/// Asserts that each stage has an id of its own and reads only stages that
/// run before it (a system's own tests call it with its stages).
#[cfg(test)]
pub(crate) fn assert_reads_only_earlier(stages: &[Planned]) {
    for (i, p) in stages.iter().enumerate() {
        let id = p.stage.id();
        assert!(stages[..i].iter().all(|s| s.stage.id() != id), "{id} twice");
        for u in &p.upstream {
            assert!(stages[..i].iter().any(|s| s.stage.id() == *u), "{id} reads {u}, which is not before it");
        }
    }
}

/// The stage names in run order.
#[cfg(test)]
pub(crate) fn names(stages: &[Planned]) -> Vec<&'static str> {
    stages.iter().map(|p| p.stage.id().name()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The generic stages, with no system, in their order, each reading
    /// only stages before it (a system's own tests check its stages).
    #[test]
    fn every_generic_stage_reads_only_earlier_stages() {
        let generic = stages(&Systems::new(vec![]));
        assert_reads_only_earlier(&generic);
        let generic_names =
            ["design", "simulate", "ingest", "emulator", "refine", "calibrate", "report", "candidates", "diagnose"];
        assert_eq!(names(&generic), generic_names);
    }
}
