//! The calibration engine. It knows no particular system: a model reaches it
//! through [`model::ModelFamily`] and [`model::Simulator`].
//!
//! Inside the engine, from the bottom up: `gp`, `formula`, `model`, `execute`
//! → `design`, `ingest`, `discover` → `emulator` → `calibrate` → `compare`,
//! `diagnose`, `refine` → `report`.

pub mod calibrate;
pub mod compare;
pub mod design;
pub mod diagnose;
pub mod discover;
pub mod emulator;
pub mod execute;
pub mod formula;
pub mod gp;
pub mod ingest;
pub mod maximin;
pub mod model;
pub mod refine;
pub mod report;
