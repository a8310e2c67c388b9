//! What the heavy-ion stand-in adds to a study: its command as the default
//! simulator, the truth of its mock data (made by the mock stage), and its
//! library of candidate physics as simulator variants.

use super::study::*;
use super::variants::Variant;
use crate::engine::execute::{OutputKind, SimulatorSpec};
use crate::systems::heavy_ion::{self, DeltaF};
use anyhow::{anyhow, Result};

impl Study<'_> {
    /// Seed of the stand-in's events, distinct for the training and validation designs.
    pub(super) fn runs_seed(&self, validation: bool) -> u64 {
        self.opts.seed.wrapping_mul(31).wrapping_add(if validation { 104_729 } else { 11 })
    }

    /// The mock truth: `mock_truth`, or every θ's `truth` value from the config.
    pub(super) fn truth_named(&self) -> Result<Vec<(String, f64)>> {
        if let Some(t) = &self.run.mock_truth {
            return Ok(t.iter().map(|(k, v)| (k.clone(), *v)).collect());
        }
        self.config
            .parameters
            .iter()
            .map(|(name, p)| {
                p.truth.map(|t| (name.clone(), t)).ok_or_else(|| {
                    anyhow!(
                        "{}: [parameters.{name}] needs a `truth` value: the mock data are made there",
                        self.config.path.display()
                    )
                })
            })
            .collect()
    }

    /// The stand-in as a simulator like any other: one point's events with
    /// the particlization `delta_f` (the design may add its candidates'
    /// parameters, which `simulate heavy-ion --design` reads).
    pub(super) fn stand_in_simulator(&self, delta_f: &str, seed: u64) -> Result<SimulatorSpec> {
        let events = self.run.events.ok_or_else(|| anyhow!("[run] events is needed to run the stand-in"))?;
        let command = format!(
            "{{mdpipe}} simulate heavy-ion --design {{design}} --only {{id}} --point-folder --delta-f {delta_f} --events {events} --oversample {} --layout hdf5 --seed {seed} --out {{point}}",
            self.run.oversample,
        );
        Ok(SimulatorSpec {
            command,
            placeholders: Default::default(),
            output: OutputKind::IebeMusic,
            time_limit: "1h".into(),
            retries: 1,
            parallel: None,
            slurm: Default::default(),
        })
    }

    /// The stand-in's library candidates `[run] candidates` names, as
    /// variants of its simulator: each a command of its own (the Grad δf
    /// switched on, or the model's δf) with its parameter added to the design.
    pub(super) fn library_variants(&self) -> Result<Vec<Variant>> {
        let model_delta_f: DeltaF = self.run.model_delta_f.parse()?;
        self.run
            .candidates
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let c = heavy_ion::candidate(name)?;
                let delta_f =
                    if c.delta_f(model_delta_f) == DeltaF::Grad { "grad" } else { self.run.model_delta_f.as_str() };
                let seed = self.opts.seed.wrapping_add(1_000 * (k as u64 + 1));
                let simulator = self.stand_in_simulator(delta_f, seed)?;
                Ok(Variant {
                    declaration: c.declaration(self.paths.candidate(name).join("emulator")).to_table()?,
                    name: c.name.into(),
                    parameters: c.design_parameter().into_iter().collect(),
                    parameter_file: Default::default(),
                    simulator,
                    design_seed: seed,
                })
            })
            .collect()
    }
}
