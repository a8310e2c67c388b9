//! What the heavy-ion stand-in adds to a study: its command as the default
//! simulator, its mock data with the truth known, and its library of
//! candidate physics as simulator variants.

use super::stages::*;
use super::variants::Variant;
use crate::base::artifacts::{self, Measurement, Provenance};
use crate::engine::execute::{OutputKind, SimulatorSpec};
use crate::systems::heavy_ion::{self, events::Layout, DeltaF, HeavyIonParams};
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

    pub(super) fn mock(&self, _keys: &Keys) -> Result<()> {
        let params = HeavyIonParams::from_named(&self.truth_named()?)?;
        let mock_delta_f = self.run.mock_delta_f.clone().unwrap_or_default();
        let mock_events = self.run.mock_events.unwrap_or_default();
        let delta_f: DeltaF = mock_delta_f.parse()?;
        let runs = self.paths.mock().join("runs");
        if runs.exists() {
            std::fs::remove_dir_all(&runs)?;
        }
        std::fs::create_dir_all(&runs)?;
        heavy_ion::simulate_runs(
            &[(0, params)],
            delta_f,
            mock_events,
            self.run.oversample,
            mock_seed(self.opts.seed),
            Layout::Hdf5,
            &runs,
        )?;
        let (ingested, _) =
            crate::engine::ingest::ingest_runs(&runs, None, &crate::engine::ingest::IngestSettings::default())?;
        let undefined: Vec<String> = ingested.report.points.iter().flat_map(|p| p.undefined_bins.clone()).collect();
        if !undefined.is_empty() {
            println!("  mock bins left out (undefined): {}", undefined.join(", "));
        }
        let keep = self.all_observables();
        let data: Vec<Measurement> = ingested
            .rows
            .iter()
            .filter(|r| keep.contains(&r.observable))
            .map(|r| Measurement::new(&r.observable, r.x, r.value, r.error))
            .collect();
        let prov = Provenance::new(
            self.config.hash.clone(),
            artifacts::measurements_hash(&data),
            self.opts.seed,
            &format!("run --stage mock: {mock_events} events, delta-f {mock_delta_f}"),
        );
        artifacts::write_measurements(&self.paths.measurements(), &data, Some(&prov))?;
        // The bins' jackknife covariance over the same events, for `[data] covariance`.
        let mut kept = ingested;
        kept.rows.retain(|r| keep.contains(&r.observable));
        if let Some(entries) = crate::engine::ingest::single_point_covariance(&kept) {
            crate::base::covariance::write_covariance_csv(&self.paths.mock().join("covariance.csv"), &entries)?;
        }
        println!(
            "  {} values from {mock_events} events (delta-f {mock_delta_f}) -> {}",
            data.len(),
            self.paths.measurements().display()
        );
        Ok(())
    }
}

pub(super) fn mock_seed(seed: u64) -> u64 {
    seed.wrapping_mul(31).wrapping_add(977)
}
