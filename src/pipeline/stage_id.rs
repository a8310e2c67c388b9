//! The names of the stages of `mdpipe run`, below both the study (whose
//! systems key on them) and the stages.

/// A stage's name: its `--stage` name and the name of its stamp. The
/// generic stages' are here; a system names its own stages in its folder
/// (`StageId::new`), so this is not a closed list.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct StageId(&'static str);

impl StageId {
    pub const DESIGN: StageId = StageId("design");
    pub const SIMULATE: StageId = StageId("simulate");
    pub const INGEST: StageId = StageId("ingest");
    pub const EMULATOR: StageId = StageId("emulator");
    pub const REFINE: StageId = StageId("refine");
    pub const CALIBRATE: StageId = StageId("calibrate");
    pub const REPORT: StageId = StageId("report");
    pub const CANDIDATES: StageId = StageId("candidates");
    pub const DIAGNOSE: StageId = StageId("diagnose");

    /// A system's own stage.
    pub const fn new(name: &'static str) -> StageId {
        StageId(name)
    }

    pub fn name(self) -> &'static str {
        self.0
    }
}

impl std::fmt::Display for StageId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.0)
    }
}
