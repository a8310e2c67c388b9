//! The ingest stage: each design's runs read into a table of the study's
//! observables (training.parquet, validation.parquet), with points that
//! failed or lack an output left out and listed.

use super::{always, Keys, StageDef};
use crate::engine::execute::OutputKind;
use crate::engine::ingest::{tables::TableRuns, IebeMusicRuns, IngestSettings, RunsReader};
use crate::pipeline::study::{runs_fingerprint, Study};
use anyhow::Result;
use std::path::{Path, PathBuf};

pub(super) const STAGE: StageDef =
    StageDef { name: "ingest", rank: 30, upstream: &["simulate"], present: always, outputs, settings, body: ingest };

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    Ok(vec![study.paths.training(), study.paths.validation()])
}

/// The run folders' contents, which a rerun of the simulate stage may change.
fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    let paths = &study.paths;
    Ok(
        serde_json::json!({"runs": [runs_fingerprint(&paths.design().join("runs"))?, runs_fingerprint(&paths.validation_design().join("runs"))?], "observables": study.all_observables()}),
    )
}

fn ingest(study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
    for (dir, out) in
        [(study.paths.design(), study.paths.training()), (study.paths.validation_design(), study.paths.validation())]
    {
        study.ingest_design(&dir, &out)?;
    }
    Ok(())
}

impl Study<'_> {
    /// Ingests one design's runs into a training table of the study's observables.
    pub(in crate::pipeline) fn ingest_design(&self, dir: &Path, out: &Path) -> Result<()> {
        let keep = self.all_observables();
        let (mut ingested, design_df) =
            reader(self.run.output()).read(&dir.join("runs"), Some(&dir.join("design.parquet")))?;
        ingested.rows.retain(|r| keep.contains(&r.observable));
        let dropped = drop_incomplete_points(&mut ingested.rows);
        for (id, what) in &dropped {
            crate::base::messages::say!("  design point {id} left out: {what} undefined (a failed v_n{{2}} measurement, listed in the ingest report)");
        }
        let flagged: Vec<i64> =
            ingested.report.points.iter().filter(|p| p.flagged.is_some()).map(|p| p.design_id).collect();
        if !flagged.is_empty() {
            crate::base::messages::say!("  design points flagged by ingest and left out: {flagged:?}");
        }
        if !ingested.report.missing_points.is_empty() {
            crate::base::messages::say!(
                "  warning: design points without a run (failed, see runs/execution.json) left out of {}: {:?}",
                out.display(),
                ingested.report.missing_points
            );
        }
        let report = crate::engine::ingest::write(&ingested, design_df.as_ref(), out)?;
        let points: std::collections::BTreeSet<i64> = ingested.rows.iter().map(|r| r.design_id).collect();
        crate::base::messages::say!(
            "  {}: {} points ({} left out); report {}",
            out.display(),
            points.len(),
            dropped.len() + flagged.len(),
            report.display()
        );
        Ok(())
    }
}

/// The reader of a simulator's output format.
fn reader(output: OutputKind) -> Box<dyn RunsReader> {
    match output {
        OutputKind::IebeMusic => Box::new(IebeMusicRuns(IngestSettings::default())),
        OutputKind::Table | OutputKind::Exit => Box::new(TableRuns),
    }
}

/// Removes design points that lack any output another point has (an undefined
/// v_n{2} bin), since the emulator needs every output at every point. Returns
/// the points removed with what they lacked.
fn drop_incomplete_points(rows: &mut Vec<crate::engine::ingest::IngestedRow>) -> Vec<(i64, String)> {
    use std::collections::{BTreeMap, BTreeSet};
    let key = |r: &crate::engine::ingest::IngestedRow| format!("{}[{}]", r.observable, r.x);
    let all: BTreeSet<String> = rows.iter().map(key).collect();
    let mut have: BTreeMap<i64, BTreeSet<String>> = BTreeMap::new();
    for r in rows.iter() {
        have.entry(r.design_id).or_default().insert(key(r));
    }
    let dropped: Vec<(i64, String)> = have
        .iter()
        .filter(|(_, h)| h.len() < all.len())
        .map(|(id, h)| (*id, all.difference(h).cloned().collect::<Vec<_>>().join(", ")))
        .collect();
    rows.retain(|r| !dropped.iter().any(|(id, _)| *id == r.design_id));
    dropped
}
