//! mdpipe: Bayesian calibration of simulators with a Kennedy–O'Hagan
//! model-discrepancy term (Jaiswal, Shen, Furnstahl, Heinz & Pratola 2025).
//!
//! Four layers, each importing only from the layers below it (ARCHITECTURE.md):
//! - [`base`]: artifacts I/O, the TOML config as plain data, progress observers;
//! - [`engine`]: GP, calibration, emulator, design, ingest, compare, diagnose,
//!   report; it knows no particular system, only the [`model::ModelFamily`] trait;
//! - [`systems`]: the model families (ball drop, heavy-ion stand-in with its
//!   study runner) and the registry that names them;
//! - [`app`]: the command line's commands, the demo and the benchmarks.

pub mod app;
pub mod base;
pub mod engine;
pub mod pipeline;
pub mod systems;

// Short paths for the library's users (and the tests).
pub use base::{artifacts, config, paper_table, progress};
pub use engine::{calibrate, compare, design, diagnose, emulator, execute, gp, ingest, model, refine, report};
