//! The systems of a run: what each brings to a study (`study::StudySystem`,
//! the queries the study holds) and the stages it adds (`System::stages`).
//! The runner knows no system: `app::systems()` is the one list, passed to
//! `pipeline::run`; each built-in system is a folder of its own here.
//! A new system is its own folder and one line in that list.

use super::stage::{AnyStage, StageId};
use super::study::StudySystem;

/// A system as `mdpipe run` takes it: its queries and its own stages.
pub(crate) trait System: StudySystem {
    /// The stages it adds to the generic ones, each with an id of its own.
    fn stages(&self) -> &'static [SystemStage] {
        &[]
    }
}

/// A stage a system adds: where it runs and which later stages read what
/// it leaves (their keys then hold its key, so they rerun when it does).
pub(crate) struct SystemStage {
    pub(crate) stage: &'static dyn AnyStage,
    /// The stage it runs right after (a generic one or one of its system's).
    pub(crate) after: StageId,
    pub(crate) read_by: &'static [StageId],
}

/// The systems a run may use, in the order they are asked (the first
/// answer wins where one answer is taken: the simulator, the data).
#[derive(Clone)]
pub struct Systems {
    list: Vec<&'static dyn System>,
}

impl Systems {
    pub(crate) fn new(list: Vec<&'static dyn System>) -> Systems {
        Systems { list }
    }

    pub(crate) fn iter(&self) -> impl Iterator<Item = &'static dyn System> + '_ {
        self.list.iter().copied()
    }

    /// Their queries, as the study holds them.
    pub(crate) fn queries(&self) -> Vec<&'static dyn StudySystem> {
        self.iter().map(|s| s as &dyn StudySystem).collect()
    }

    /// The figures they add to reports of their own runs.
    pub fn figures(&self) -> Vec<&'static dyn crate::engine::report::SystemFigures> {
        self.iter().filter_map(|s| s.figures()).collect()
    }
}
