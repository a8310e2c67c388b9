//! `[model] observable_labels`: quantities that set an emulated model's
//! observables apart (a current, an energy), which shared corrections scale
//! with (`shared`). Read and checked here, apart from the search that uses
//! them, so that the discoverer and its shared corrections both depend on
//! this and not on each other.

use crate::engine::model::Simulator;
use anyhow::{bail, Result};
use std::collections::BTreeMap;

/// A quantity that sets the observables apart, and its value for each.
#[derive(Clone, Debug)]
pub struct Label {
    pub name: String,
    pub values: BTreeMap<String, f64>,
}

/// `[model] observable_labels`, checked against the model's observables:
/// each value finite, each quantity given for two or more observables and
/// not the same for all (a common factor is no law).
pub fn labels(table: &BTreeMap<String, BTreeMap<String, f64>>, model: &dyn Simulator) -> Result<Vec<Label>> {
    let names = model.observable_names();
    let mut out = Vec::new();
    for (label, values) in table {
        for (observable, v) in values {
            if !names.contains(observable) {
                bail!(
                    "[model] observable_labels.{label}: '{observable}' is not an observable of the model (it has {})",
                    names.join(", ")
                );
            }
            if !v.is_finite() {
                bail!("[model] observable_labels.{label}.{observable} = {v}: not a finite number");
            }
        }
        let first = values.values().next().copied();
        if values.len() < 2 || values.values().all(|v| Some(*v) == first) {
            bail!(
                "[model] observable_labels.{label}: give it for two or more observables, with values that differ (a correction it scales is searched across them)"
            );
        }
        out.push(Label { name: label.clone(), values: values.clone() });
    }
    Ok(out)
}
