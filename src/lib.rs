//! mdpipe: Bayesian calibration of simulators with a Kennedy–O'Hagan
//! model-discrepancy term (Jaiswal, Shen, Furnstahl, Heinz & Pratola 2025).
//!
//! Stages: `design` → `ingest` → `emulator` → `calibrate` → `diagnose`,
//! each reading and writing Parquet artifacts (see ARCHITECTURE.md).

pub mod artifacts;
pub mod bench;
pub mod calibrate;
pub mod config;
pub mod demo;
pub mod design;
pub mod diagnose;
pub mod emulator;
pub mod gp;
pub mod ingest;
pub mod models;
pub mod pipeline;
pub mod report;
pub mod study;

use indicatif::{ProgressBar, ProgressStyle};

/// A progress bar on stderr; indicatif hides it when stderr is not a terminal
/// (batch jobs), so logs stay clean.
pub fn progress_bar(len: u64, message: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg:48} [{elapsed_precise}] {wide_bar} {percent:>3}%")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_message(message.to_string());
    pb
}
