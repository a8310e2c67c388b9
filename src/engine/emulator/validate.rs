//! `mdpipe validate-emulator`: held-out design and k-fold cross-validation.
//! Per observable: RMSE relative to the spread of the simulator outputs, and
//! the coverage of the 68% / 95% predictive intervals; plus a parity table.

use super::{train, Emulator, EmulatorSettings, TrainingTable};
use anyhow::{bail, Result};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

#[derive(Clone, Debug, serde::Serialize)]
pub struct ObservableValidation {
    pub observable: String,
    /// Design points × bins compared.
    pub n: usize,
    pub rmse: f64,
    /// RMS over bins of the standard deviation of the simulator outputs over the design.
    pub spread: f64,
    pub relative_rmse: f64,
    pub coverage_68: f64,
    pub coverage_95: f64,
}

/// One predicted output at one held-out design point.
#[derive(Clone, Debug)]
pub struct ParityRow {
    pub set: String,
    pub design_id: i64,
    pub observable: String,
    pub x: f64,
    pub simulated: f64,
    pub emulated: f64,
    pub sd: f64,
}

/// Predicts every row of `table` (same outputs as the emulator) into parity rows.
pub fn parity(emu: &Emulator, table: &TrainingTable, set: &str) -> Result<Vec<ParityRow>> {
    let cols: Vec<usize> = emu
        .outputs()
        .iter()
        .map(|o| {
            table
                .outputs
                .iter()
                .position(|t| t.observable == o.observable && (t.x - o.x).abs() <= 1e-9 * o.x.abs().max(1.0))
                .ok_or_else(|| anyhow::anyhow!("{}: no column for emulator output {o}", table.path.display()))
        })
        .collect::<Result<_>>()?;
    if table.parameter_names != emu.parts.parameter_names {
        bail!(
            "{}: parameters {:?} differ from the emulator's {:?}",
            table.path.display(),
            table.parameter_names,
            emu.parts.parameter_names
        );
    }
    let mut rows = Vec::new();
    for i in 0..table.n_points() {
        // A held-out run carries its own noise, as the training runs did.
        let pred = emu.predict_run(table.input(i));
        for (j, o) in emu.outputs().iter().enumerate() {
            rows.push(ParityRow {
                set: set.to_string(),
                design_id: table.design_ids[i],
                observable: o.observable.clone(),
                x: o.x,
                simulated: table.row(i)[cols[j]],
                emulated: pred.mean[j],
                sd: pred.sd(j),
            });
        }
    }
    Ok(rows)
}

/// Per-observable summary of parity rows.
pub fn summarize(rows: &[ParityRow]) -> Vec<ObservableValidation> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.observable.as_str()) {
            names.push(&r.observable);
        }
    }
    names
        .into_iter()
        .map(|name| {
            let sel: Vec<&ParityRow> = rows.iter().filter(|r| r.observable == name).collect();
            let n = sel.len() as f64;
            let rmse = (sel.iter().map(|r| (r.emulated - r.simulated).powi(2)).sum::<f64>() / n).sqrt();
            // Spread per bin, then RMS over bins.
            let mut xs: Vec<f64> = sel.iter().map(|r| r.x).collect();
            xs.sort_by(f64::total_cmp);
            xs.dedup();
            let var_mean = xs
                .iter()
                .map(|&x| {
                    let v: Vec<f64> = sel.iter().filter(|r| r.x == x).map(|r| r.simulated).collect();
                    let mu = v.iter().sum::<f64>() / v.len() as f64;
                    v.iter().map(|a| (a - mu).powi(2)).sum::<f64>() / v.len() as f64
                })
                .sum::<f64>()
                / xs.len() as f64;
            let spread = var_mean.sqrt();
            let covered =
                |z: f64| sel.iter().filter(|r| (r.emulated - r.simulated).abs() <= z * r.sd).count() as f64 / n;
            ObservableValidation {
                observable: name.to_string(),
                n: sel.len(),
                rmse,
                spread,
                relative_rmse: rmse / spread,
                coverage_68: covered(0.994_457_883_209_753),
                coverage_95: covered(1.959_963_984_540_054),
            }
        })
        .collect()
}

/// k-fold cross-validation: retrain (hyperparameters included) without each
/// fold and predict it.
pub fn cross_validate(emu: &Emulator, settings: &EmulatorSettings, folds: usize, seed: u64) -> Result<Vec<ParityRow>> {
    let table = emu.training_table();
    let n = table.n_points();
    if folds < 2 || folds > n {
        bail!("--folds {folds}: need 2 ≤ folds ≤ {n} design points");
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.shuffle(&mut Xoshiro256PlusPlus::seed_from_u64(seed));
    let mut rows = Vec::new();
    let bar = crate::base::progress::bar(folds as u64, "cross-validation folds");
    for f in 0..folds {
        let test: Vec<usize> = order.iter().enumerate().filter(|(k, _)| k % folds == f).map(|(_, &i)| i).collect();
        let fit: Vec<usize> = order.iter().enumerate().filter(|(k, _)| k % folds != f).map(|(_, &i)| i).collect();
        let mut fold_settings = settings.clone();
        fold_settings.components = Some(emu.n_components().min(fit.len() - 1));
        let (fold_emu, _) = train(&table.subset(&fit), &fold_settings, seed.wrapping_add(f as u64 + 1))?;
        rows.extend(parity(&fold_emu, &table.subset(&test), &format!("cv{folds}"))?);
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(rows)
}

pub fn parity_frame(rows: &[ParityRow]) -> Result<polars::prelude::DataFrame> {
    use polars::prelude::*;
    Ok(DataFrame::new(
        rows.len(),
        vec![
            Column::new("set".into(), rows.iter().map(|r| r.set.as_str()).collect::<Vec<_>>()),
            Column::new("design_id".into(), rows.iter().map(|r| r.design_id).collect::<Vec<_>>()),
            Column::new("observable".into(), rows.iter().map(|r| r.observable.as_str()).collect::<Vec<_>>()),
            Column::new("x".into(), rows.iter().map(|r| r.x).collect::<Vec<_>>()),
            Column::new("simulated".into(), rows.iter().map(|r| r.simulated).collect::<Vec<_>>()),
            Column::new("emulated".into(), rows.iter().map(|r| r.emulated).collect::<Vec<_>>()),
            Column::new("sd".into(), rows.iter().map(|r| r.sd).collect::<Vec<_>>()),
        ],
    )?)
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ValidationSummary {
    /// Against the held-out validation design, if one was given.
    pub holdout: Option<Vec<ObservableValidation>>,
    /// k-fold cross-validation on the training design.
    pub cross_validation: Option<Vec<ObservableValidation>>,
    pub folds: usize,
    pub provenance: crate::base::artifacts::Provenance,
}

/// `mdpipe validate-emulator`: writes `validation.json` and `validation_parity.parquet` into the emulator folder.
pub fn run(
    dir: &std::path::Path,
    validation: Option<&std::path::Path>,
    folds: usize,
    seed: u64,
) -> Result<ValidationSummary> {
    let emu = super::store::load(dir)?;
    let mut rows = Vec::new();
    let holdout = match validation {
        Some(path) => {
            let mut observables: Vec<String> = Vec::new();
            for o in &emu.parts.outputs {
                if !observables.contains(&o.observable) {
                    observables.push(o.observable.clone());
                }
            }
            let table = super::table::read_training_table_selected(path, &emu.parts.parameter_names, &observables)?;
            let r = parity(&emu, &table, "holdout")?;
            let s = summarize(&r);
            rows.extend(r);
            Some(s)
        }
        None => None,
    };
    let cross_validation = if folds > 0 {
        let settings = super::store::load_settings(dir)?;
        let r = cross_validate(&emu, &settings, folds, seed)?;
        let s = summarize(&r);
        rows.extend(r);
        Some(s)
    } else {
        None
    };
    let mut provenance = super::store::load_provenance(dir)?;
    provenance.seed = seed;
    provenance.command = format!("validate-emulator {} --folds {folds}", dir.display());
    let summary = ValidationSummary { holdout, cross_validation, folds, provenance: provenance.clone() };
    let mut staged = crate::base::artifacts::StagedWrites::new();
    staged.parquet(&dir.join("validation_parity.parquet"), &mut parity_frame(&rows)?, Some(&provenance))?;
    staged.json(&dir.join("validation.json"), &summary)?;
    staged.commit()?;
    Ok(summary)
}

/// Console table of one validation set.
pub fn print(label: &str, rows: &[ObservableValidation]) {
    crate::base::messages::say!("{label}:");
    crate::base::messages::say!(
        "  {:<14} {:>6} {:>11} {:>11} {:>9} {:>8} {:>8}",
        "observable",
        "n",
        "RMSE",
        "spread",
        "RMSE/spr",
        "cov68",
        "cov95"
    );
    for r in rows {
        crate::base::messages::say!(
            "  {:<14} {:>6} {:>11.4e} {:>11.4e} {:>9.4} {:>8.3} {:>8.3}",
            r.observable,
            r.n,
            r.rmse,
            r.spread,
            r.relative_rmse,
            r.coverage_68,
            r.coverage_95
        );
    }
}
