//! The systems mdpipe knows: model families that plug into the engine
//! through `engine::model::ModelFamily`, and what is particular to each
//! (the heavy-ion study runner, its tables and figures).
//!
//! A new family is its own module here plus one line in [`registry`].

pub mod ball_drop;
pub mod declared;
pub mod heavy_ion;

use crate::base::config::Config;
use crate::engine::calibrate::Analysis;
use crate::engine::model::Registry;
use anyhow::Result;
use std::path::Path;
use std::sync::Arc;

/// Every built-in model family, by the `kind` configs name it with.
pub fn registry() -> Registry {
    let mut r = Registry::new();
    r.register(Arc::new(heavy_ion::family::HeavyIonFamily));
    r.register(Arc::new(crate::engine::emulator::EmulatorFamily));
    r.register(Arc::new(declared::DeclaredFamily::EXPRESSION));
    r.register(Arc::new(declared::DeclaredFamily::ODE));
    r
}

/// Resolves a config with the built-in families.
pub fn resolve(config: &Config) -> Result<Analysis> {
    Analysis::resolve(config, &registry())
}

/// Reads a config and resolves it with the built-in families.
pub fn load(path: &Path) -> Result<Analysis> {
    resolve(&Config::load(path)?)
}
