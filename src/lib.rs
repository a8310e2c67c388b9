//! mdpipe: Bayesian calibration of simulators with a Kennedy–O'Hagan
//! model-discrepancy term (Jaiswal, Shen, Furnstahl, Heinz & Pratola 2025).
//!
//! Six layers, each importing only from the layers below it (ARCHITECTURE.md;
//! `tests/it/layers.rs` checks it):
//! - [`base`]: artifacts I/O, the TOML config as plain data, measurement and
//!   covariance readers (HEPData's YAML among them), progress observers;
//! - [`engine`]: GP, calibration, emulator, design, execute, ingest, compare,
//!   diagnose, refine, report; it knows no particular system, only the
//!   [`model::ModelFamily`] trait;
//! - [`systems`]: the model families (declared formulas and ODEs, the
//!   heavy-ion stand-in, the Rust ball drop) and the registry that names them;
//! - [`pipeline`]: `mdpipe run`, the staged study for any simulator, with the
//!   hook through which a system adds what it brings;
//! - [`run_systems`]: what each system brings to `mdpipe run` (the heavy-ion
//!   stand-in's table, mock stage and assessment), one folder each;
//! - [`app`]: the command line's commands, the demo and the benchmarks.

pub mod app;
pub mod base;
pub mod engine;
pub mod pipeline;
pub mod run_systems;
pub mod systems;

// Short paths for the library's users (and the tests).
pub use base::{artifacts, config, paper_table, progress};
pub use engine::{calibrate, compare, design, diagnose, emulator, execute, gp, ingest, model, refine, report};
