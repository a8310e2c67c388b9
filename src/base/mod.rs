//! The foundation: what every layer above may use and which imports nothing
//! of the crate beyond itself.

pub mod artifacts;
pub mod choices;
pub mod columns;
pub mod config;
pub mod covariance;
pub mod error;
pub mod hepdata;
pub mod measurement;
pub mod messages;
pub mod paper_table;
pub mod progress;
pub mod systematics;
pub mod table;
