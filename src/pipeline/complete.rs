//! One config for `mdpipe run` and the standalone commands: what the study
//! builds (its emulator, its candidates' variant emulators) is what
//! `calibrate`, `diagnose` and `compare` use when the config leaves it out.

use super::run_config::RunConfig;
use super::stage::refine::report::Rounds;
use super::study::{absolute, RunPaths};
use super::system::Systems;
use crate::base::config::Config;
use crate::engine::calibrate::Analysis;
use crate::systems;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Where `mdpipe run` writes: `--out`, else `[run] out` (relative to the
/// config), else `outputs/<name>` in the current folder.
pub fn study_out(config: &Config, run: &RunConfig, cli: Option<&Path>) -> PathBuf {
    match (cli, &run.out) {
        (Some(out), _) => out.to_path_buf(),
        (None, Some(out)) => config.resolve(out),
        (None, None) => PathBuf::from("outputs").join(&config.name),
    }
}

/// Reads a config and resolves it with the built-in families, with what its
/// `[run]` study built filled in where the config leaves it out.
pub fn load(path: &Path, systems: &Systems) -> Result<Analysis> {
    let mut config = Config::load(path)?;
    fill_in_from_study(&mut config, systems)?;
    systems::resolve(&config)
}

/// Fills in, for a config with a `[run]` table: `[model] artifact` (the
/// study's emulator, refined when `[run.refine]` ran) and each
/// `[[candidates]]` `emulator` (its variant), when not given; and the
/// library candidates a system's table names (`[run.<system>]`).
pub fn fill_in_from_study(config: &mut Config, systems: &Systems) -> Result<()> {
    let Some(table) = &config.run else { return Ok(()) };
    let run = RunConfig::decode(config, table)?;
    let paths = RunPaths { out: study_out(config, &run, None) };
    let model_is_emulator = config.model.get("kind").and_then(|k| k.as_str()) == Some("emulator");
    if model_is_emulator && !config.model.contains_key("artifact") {
        let rounds = paths.out.join("refine").join("rounds.json");
        let emulator = match std::fs::read_to_string(&rounds) {
            Ok(text) if run.refine.is_some() => {
                let r: Rounds = serde_json::from_str(&text).with_context(|| format!("reading {}", rounds.display()))?;
                paths.out.join("refine").join(r.emulator)
            }
            _ => paths.emulator(),
        };
        if !emulator.join("emulator.json").exists() {
            anyhow::bail!(
                "{}: [model] gives no `artifact` and the study's emulator is not in {}: run `mdpipe run {}` first (it writes there), or set [run] out to where it ran",
                config.path.display(),
                emulator.display(),
                config.path.display()
            );
        }
        config.model.insert("artifact".into(), absolute(&emulator).display().to_string().into());
    }
    for c in config.candidates.iter_mut() {
        let name = c.get("name").and_then(|n| n.as_str()).unwrap_or_default().to_string();
        if !c.contains_key("emulator") && !name.is_empty() {
            let emulator = absolute(&paths.candidate(&name).join("emulator"));
            c.insert("emulator".into(), emulator.display().to_string().into());
        }
    }
    for system in systems.iter() {
        config.candidates.extend(system.library_declarations(&run, &paths)?);
    }
    Ok(())
}
