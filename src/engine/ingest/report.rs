//! What an ingest read, skipped and flagged, said through the message sink.

use super::IngestReport;

/// Prints what was read, skipped and flagged.
pub fn print_report(report: &IngestReport) {
    for p in &report.points {
        match &p.flagged {
            None => crate::base::messages::note!(
                "design point {:>4}: {} good events ({})",
                p.design_id,
                p.good_events,
                p.source
            ),
            Some(why) => {
                crate::base::messages::note!("design point {:>4}: FLAGGED, left out of the table: {why}", p.design_id)
            }
        }
        for s in &p.skipped {
            crate::base::messages::note!("    skipped event {}: {}", s.event, s.reason);
        }
        if !p.undefined_bins.is_empty() {
            crate::base::messages::note!(
                "    left out (value or jackknife error undefined; more events or --oversample would measure them): {}",
                p.undefined_bins.join(", ")
            );
        }
    }
    if !report.missing_points.is_empty() {
        crate::base::messages::note!(
            "design points with no run folder (not in the table): {:?}",
            report.missing_points
        );
    }
}
