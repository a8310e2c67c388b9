//! The foundation: what every layer above may use and which imports nothing
//! of the crate beyond itself.

pub mod artifacts;
pub mod config;
pub mod covariance;
pub mod progress;
