//! `[model] kind = "heavy_ion"` and `[truth] kind = "heavy_ion"`: the
//! blast-wave stand-in's smooth observables (no event noise) as a model, and
//! as the process that made mock data. Studies calibrate an emulator of the
//! stand-in instead (`kind = "emulator"`); this family gives them the truth
//! curve and the units, and lets a small calibration use the stand-in directly.
//! It evaluates the observables at the points x themselves, not averaged over
//! the analysis bins as runs, ingest and `simulate heavy-ion --out FILE` are
//! (`events::SmoothTables::expected`); the two differ most in the lowest bin
//! (v2 at 0.1 GeV by a factor 2, where v2 grows as pT²), so calibrate binned
//! data with an emulator of binned runs, not with this family.

use super::{observables, DeltaF, HeavyIonParams};
use crate::base::config::Config;
use crate::engine::model::{ModelFamily, ModelSetup, PlainSetup, Simulator, Units};
use anyhow::{anyhow, Context, Result};
use std::sync::Arc;

pub struct HeavyIonFamily;

/// `[model]` or `[truth]` of kind "heavy_ion".
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StandInTable {
    /// none, grad or grad-transverse.
    #[serde(default = "default_delta_f")]
    delta_f: String,
}

fn default_delta_f() -> String {
    "none".into()
}

/// The seven observables, in the stand-in's order.
pub const OBSERVABLES: [&str; 7] = ["ch_spectrum", "ch_v2", "ch_v3", "pi_spectrum", "pi_v2", "p_spectrum", "p_v2"];

fn stand_in(config: &Config, table: &toml::Table, name: &str) -> Result<Arc<dyn Simulator>> {
    let t: StandInTable = config.decode_family_table(table, name)?;
    let delta_f: DeltaF = t.delta_f.parse().with_context(|| format!("{}: [{name}] delta_f", config.path.display()))?;
    let names: Vec<String> = config.parameters.keys().cloned().collect();
    // The names must make a stand-in parameter set (checked once here, at mid-prior).
    let mid: Vec<(String, f64)> = config.parameters.iter().map(|(n, p)| (n.clone(), 0.5 * (p.min + p.max))).collect();
    HeavyIonParams::from_named(&mid).map_err(|e| anyhow!("{}: [parameters]: {e}", config.path.display()))?;
    Ok(Arc::new(StandIn { names, delta_f }))
}

impl HeavyIonFamily {
    /// The stand-in's units: pT in GeV, the switching density in GeV/fm³.
    pub fn units() -> Units {
        let pairs = |v: &[(&str, &str)]| v.iter().map(|(k, u)| (k.to_string(), u.to_string())).collect();
        Units {
            x: "GeV".into(),
            observables: Default::default(),
            parameters: pairs(&[("e_sw", "GeV/fm³"), ("T_kink", "GeV"), ("a_low", "1/GeV"), ("a_high", "1/GeV")]),
        }
    }
}

impl ModelFamily for HeavyIonFamily {
    fn kind(&self) -> &'static str {
        "heavy_ion"
    }

    fn open(&self, config: &Config) -> Result<Arc<dyn ModelSetup>> {
        Ok(PlainSetup::shared(stand_in(config, &config.model, "model")?, Self::units()))
    }

    fn open_truth(&self, config: &Config, truth: &toml::Table) -> Result<Arc<dyn ModelSetup>> {
        Ok(PlainSetup::shared(stand_in(config, truth, "truth")?, Self::units()))
    }
}

type StandInKey = (DeltaF, Vec<String>, Vec<f64>, Vec<f64>);

thread_local! {
    /// This thread's last stand-in evaluation: (δf, names, θ, x) and the observables.
    static LAST: std::cell::RefCell<Option<(StandInKey, Option<Vec<(&'static str, Vec<f64>)>>)>> = const { std::cell::RefCell::new(None) };
}

/// The smooth stand-in over named parameters (`eta_s, e_sw` or the kink set).
struct StandIn {
    names: Vec<String>,
    delta_f: DeltaF,
}

impl Simulator for StandIn {
    fn parameter_names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn observable_names(&self) -> Vec<String> {
        OBSERVABLES.iter().map(|s| s.to_string()).collect()
    }
    /// NaN where θ is no valid stand-in point (the likelihood then rejects it).
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        // The stand-in computes all seven observables at once and the
        // likelihood asks for them one by one at the same θ: keep the last.
        LAST.with(|cell| {
            let mut last = cell.borrow_mut();
            let hit = last
                .as_ref()
                .is_some_and(|((d, n, t, xs), _)| *d == self.delta_f && *n == self.names && t == theta && xs == x);
            if !hit {
                let key = (self.delta_f, self.names.clone(), theta.to_vec(), x.to_vec());
                let named: Vec<(String, f64)> = self.names.iter().cloned().zip(theta.iter().copied()).collect();
                let values = HeavyIonParams::from_named(&named).ok().map(|p| observables(&p, self.delta_f, x));
                *last = Some((key, values));
            }
            out.fill(f64::NAN);
            let values = last.as_ref().and_then(|(_, v)| v.as_ref());
            if let Some((_, v)) = values.and_then(|v| v.iter().find(|(n, _)| *n == OBSERVABLES[observable])) {
                out.copy_from_slice(v);
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stand_in_predictions_equal_the_observables_whatever_the_order_asked() {
        let model = StandIn { names: vec!["e_sw".into(), "eta_s".into()], delta_f: DeltaF::Grad };
        let x = [0.3, 0.9, 1.5];
        for theta in [[0.2, 0.1], [0.3, 0.05], [0.2, 0.1]] {
            let expected = observables(&HeavyIonParams::constant(theta[1], theta[0]), DeltaF::Grad, &x);
            for k in [3, 0, 6, 3] {
                let mut out = [0.0; 3];
                model.predict(k, &x, &theta, &mut out);
                assert_eq!(out.as_slice(), expected[k].1.as_slice(), "observable {k} at {theta:?}");
            }
        }
        // A θ that is no stand-in point gives NaN, not the previous θ's values.
        let mut out = [0.0; 3];
        model.predict(0, &x, &[-1.0, 0.1], &mut out);
        assert!(out.iter().all(|v| v.is_nan()));
    }
}
