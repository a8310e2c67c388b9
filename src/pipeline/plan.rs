//! The stages a study has, in the order it runs them: the generic stages
//! (one module each under `stage/`) and those its systems add.

#[cfg(test)]
use super::stage::probe;
use super::stage::{calibrate, candidates, design, diagnose, emulator, ingest, refine, report, simulate};
use super::stage::{AnyStage, Presence};
use super::study::Study;
use super::system::Systems;
use anyhow::{bail, Result};

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
        #[cfg(test)]
        &probe::Probe,
    ]
}

/// Every stage, the generic ones and those the systems add, in the order a study runs them.
pub(super) fn stages(systems: &Systems) -> Vec<&'static dyn AnyStage> {
    let mut stages = generic();
    for system in systems.iter() {
        stages.extend(system.stages());
    }
    stages.sort_by_key(|s| s.id());
    stages
}

/// The stages this study has, in order; `--stage` naming one it has not is refused.
pub(super) fn plan(study: &Study<'_>, systems: &Systems) -> Result<Vec<&'static dyn AnyStage>> {
    let mut planned = Vec::new();
    for stage in stages(systems) {
        match stage.present(study)? {
            Presence::Runs => planned.push(stage),
            Presence::Absent(why) if study.opts.stage == Some(stage.id()) => {
                bail!("--stage {}: {why}", stage.id())
            }
            Presence::Absent(_) => {}
        }
    }
    Ok(planned)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::choices::StageId;

    /// With the systems' stages, each stage has an id of its own and reads
    /// only stages that run before it; every id is some stage's.
    #[test]
    fn every_stage_reads_only_earlier_stages() {
        let stages = stages(&Systems::new(vec![&crate::pipeline::stand_in::StandIn]));
        for (i, stage) in stages.iter().enumerate() {
            assert!(stages[..i].iter().all(|s| s.id() < stage.id()), "{}", stage.id());
            for u in stage.upstream() {
                assert!(stages[..i].iter().any(|s| s.id() == *u), "{} reads {u}, which is not before it", stage.id());
            }
        }
        let ids: Vec<StageId> = stages.iter().map(|s| s.id()).collect();
        assert_eq!(ids, <StageId as clap::ValueEnum>::value_variants());
        for id in ids {
            assert_eq!(id.name(), id.to_string());
            assert_eq!(id.name().parse::<StageId>().unwrap(), id);
        }
    }
}
