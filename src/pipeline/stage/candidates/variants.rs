//! Which candidates of a study are variants of its simulator, and so
//! whether the candidates stage runs: the systems' library names, then the
//! declared `[[candidates]]` (the corrections of the emulated output need
//! no runs).

use crate::engine::design::DesignSpec;
use crate::engine::emulator::family::CandidateDeclaration;
use crate::pipeline::run_config::with_config_dir;
use crate::pipeline::setup;
use crate::pipeline::stage::Presence;
use crate::pipeline::study::{absolute, Study};
use crate::pipeline::variants::{check_declaration, design_parameter, Variant};
use anyhow::{bail, Context, Result};

/// The candidates stage's presence: a variant to build for some candidate.
pub(crate) fn presence(study: &Study<'_>) -> Result<Presence> {
    Ok(if variants(study)?.is_empty() {
        Presence::Absent(format!(
            "{} declares no candidates that run the simulator ([[candidates]], or a system's library: {})",
            study.config.path.display(),
            setup::tables(&study.systems.iter().filter_map(|s| s.run_table()).collect::<Vec<_>>())
        ))
    } else {
        Presence::Runs
    })
}

/// Every candidate of the study that is a variant of the simulator: the
/// systems' library names, then the declared `[[candidates]]` (not the
/// corrections of the emulated output, which need no runs).
pub(crate) fn variants(study: &Study<'_>) -> Result<Vec<Variant>> {
    let mut variants = Vec::new();
    for system in study.systems {
        variants.extend(system.library_variants(study)?);
    }
    if study.config.candidates.is_empty() {
        return Ok(variants);
    }
    let library = variants.len();
    let spec = DesignSpec::load(&study.config.resolve(&study.run.design))?;
    let base = study.simulator(false)?;
    for (k, table) in study.config.candidates.iter().enumerate() {
        let mut c: CandidateDeclaration = study.config.decode(table, "[candidates]")?;
        if c.is_correction() {
            // A correction of the emulated output: nothing to run.
            continue;
        }
        c.command = c.command.map(|command| with_config_dir(&command, study.config));
        let where_ = format!("{}: [[candidates]] {}", study.config.path.display(), c.name);
        let simulator = check_declaration(&c, &spec, &base).context(where_.clone())?;
        if variants.iter().any(|v| v.name == c.name) {
            bail!("{where_}: a second candidate of that name");
        }
        let mut declaration = table.clone();
        let emulator = absolute(&study.paths.candidate(&c.name).join("emulator"));
        declaration.insert("emulator".into(), emulator.display().to_string().into());
        variants.push(Variant {
            name: c.name.clone(),
            declaration,
            parameters: c.parameters.iter().map(|(n, p)| design_parameter(n, p)).collect(),
            parameter_file: c.parameter_file.clone(),
            simulator,
            // After the systems' library variants' seeds (1_000 apart each).
            design_seed: study.opts.seed.wrapping_add(1_000 * (library + k + 1) as u64),
        });
    }
    Ok(variants)
}
