//! The emulator artifact, a folder of Parquet tables plus `emulator.json`:
//!
//! - `training.parquet`: long table `design_id, observable, x, value, error, <parameters…>`
//!   (the raw training data and each value's run error, kept for
//!   cross-validation and for separating run noise; older folders without
//!   `error` load with errors 0, as before);
//! - `scalings.parquet`: `output, observable, x, transform, mean, std`;
//! - `pca.parquet`: `component, singular_value, output, loading`
//!   (every component, kept or not, so the truncation error is known);
//! - `scores.parquet`: `component, design_id, score` (whitened, kept components);
//! - `hyperparameters.parquet`: `component, name, value` (log scale);
//! - `inputs.parquet`: `parameter, lo, hi` (unit-cube scaling);
//! - `emulator.json`: kernel, component count, training report, provenance.
//!
//! Reloading rebuilds the emulator through the same [`Emulator::from_parts`]
//! as training, from the same f64 values, so predictions are bit-identical.

use super::{Emulator, EmulatorParts, EmulatorSettings, OutputKey, TrainingReport};
use crate::base::artifacts::{self, Provenance};
use crate::engine::gp::{ArdHyper, ArdKernel};
use anyhow::{anyhow, bail, Context, Result};
use polars::prelude::*;
use std::path::Path;

#[derive(serde::Serialize, serde::Deserialize)]
struct Metadata {
    format: u32,
    kernel: ArdKernel,
    n_components: usize,
    parameters: Vec<String>,
    settings: EmulatorSettings,
    provenance: Provenance,
    report: serde_json::Value,
}

const FORMAT: u32 = 1;

/// Writes the artifact folder as a whole: everything goes into a staging
/// sibling that replaces `dir` only once complete, so an interrupted save
/// never leaves old and new tables mixed.
pub fn save(
    dir: &Path,
    emu: &Emulator,
    settings: &EmulatorSettings,
    report: &TrainingReport,
    provenance: &Provenance,
) -> Result<()> {
    let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("emulator");
    let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&staging);
    if let Err(e) = write_folder(&staging, emu, settings, report, provenance) {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e.context(format!("the emulator was not saved; {} is as it was", dir.display())));
    }
    if dir.exists() {
        let old = parent.join(format!(".{name}.old-{}", std::process::id()));
        std::fs::rename(dir, &old).with_context(|| format!("moving the previous {} aside", dir.display()))?;
        std::fs::rename(&staging, dir).with_context(|| format!("moving the new emulator into {}", dir.display()))?;
        let _ = std::fs::remove_dir_all(&old);
    } else {
        std::fs::rename(&staging, dir).with_context(|| format!("moving the new emulator into {}", dir.display()))?;
    }
    Ok(())
}

fn write_folder(
    dir: &Path,
    emu: &Emulator,
    settings: &EmulatorSettings,
    report: &TrainingReport,
    provenance: &Provenance,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let p = &emu.parts;
    let (n, m, d, r) = (p.design_ids.len(), p.outputs.len(), p.parameter_names.len(), p.singular_values.len());
    let prov = Some(provenance);

    let table = super::TrainingTable {
        path: dir.join("training.parquet"),
        parameter_names: p.parameter_names.clone(),
        design_ids: p.design_ids.clone(),
        inputs: p.train_inputs.clone(),
        outputs: p.outputs.clone(),
        values: p.train_values.clone(),
        errors: p.train_errors.clone(),
        noise_correlation: (!p.noise_correlation.is_empty()).then(|| p.noise_correlation.clone()),
    };
    artifacts::write_parquet_atomic(&dir.join("training.parquet"), &mut table.to_long_frame()?, prov)?;
    table.write_noise_correlation(&dir.join("training.parquet"))?;

    let mut df = DataFrame::new(
        m,
        vec![
            Column::new("output".into(), (0..m as i64).collect::<Vec<_>>()),
            Column::new("observable".into(), p.outputs.iter().map(|o| o.observable.as_str()).collect::<Vec<_>>()),
            Column::new("x".into(), p.outputs.iter().map(|o| o.x).collect::<Vec<_>>()),
            Column::new(
                "transform".into(),
                p.log_transform.iter().map(|&l| if l { "log" } else { "none" }).collect::<Vec<_>>(),
            ),
            Column::new("mean".into(), p.output_mean.clone()),
            Column::new("std".into(), p.output_std.clone()),
        ],
    )?;
    artifacts::write_parquet_atomic(&dir.join("scalings.parquet"), &mut df, prov)?;

    let mut df = DataFrame::new(
        m * r,
        vec![
            Column::new("component".into(), (0..r as i64).flat_map(|k| std::iter::repeat_n(k, m)).collect::<Vec<_>>()),
            Column::new(
                "singular_value".into(),
                p.singular_values.iter().flat_map(|&s| std::iter::repeat_n(s, m)).collect::<Vec<_>>(),
            ),
            Column::new("output".into(), (0..r).flat_map(|_| 0..m as i64).collect::<Vec<_>>()),
            Column::new("loading".into(), p.basis.clone()),
        ],
    )?;
    artifacts::write_parquet_atomic(&dir.join("pca.parquet"), &mut df, prov)?;

    let k = p.n_components;
    let mut df = DataFrame::new(
        k * n,
        vec![
            Column::new("component".into(), (0..k as i64).flat_map(|c| std::iter::repeat_n(c, n)).collect::<Vec<_>>()),
            Column::new("design_id".into(), (0..k).flat_map(|_| p.design_ids.iter().copied()).collect::<Vec<_>>()),
            Column::new("score".into(), p.scores.clone()),
        ],
    )?;
    artifacts::write_parquet_atomic(&dir.join("scores.parquet"), &mut df, prov)?;

    let names = ArdHyper::names(d);
    let np = names.len();
    let mut df = DataFrame::new(
        k * np,
        vec![
            Column::new("component".into(), (0..k as i64).flat_map(|c| std::iter::repeat_n(c, np)).collect::<Vec<_>>()),
            Column::new("name".into(), (0..k).flat_map(|_| names.iter().map(String::as_str)).collect::<Vec<_>>()),
            Column::new("value".into(), p.hypers.iter().flat_map(|h| h.log_params.iter().copied()).collect::<Vec<_>>()),
        ],
    )?;
    artifacts::write_parquet_atomic(&dir.join("hyperparameters.parquet"), &mut df, prov)?;

    let mut df = DataFrame::new(
        d,
        vec![
            Column::new("parameter".into(), p.parameter_names.iter().map(String::as_str).collect::<Vec<_>>()),
            Column::new("lo".into(), p.input_lo.clone()),
            Column::new("hi".into(), p.input_hi.clone()),
        ],
    )?;
    artifacts::write_parquet_atomic(&dir.join("inputs.parquet"), &mut df, prov)?;

    let meta = Metadata {
        format: FORMAT,
        kernel: p.kernel,
        n_components: k,
        parameters: p.parameter_names.clone(),
        settings: settings.clone(),
        provenance: provenance.clone(),
        report: serde_json::to_value(report)?,
    };
    artifacts::write_json_atomic(&dir.join("emulator.json"), &meta)
}

fn f64s(df: &DataFrame, file: &Path, name: &str) -> Result<Vec<f64>> {
    crate::base::columns::f64_column(df, file, name)
}

fn strs(df: &DataFrame, file: &Path, name: &str) -> Result<Vec<String>> {
    crate::base::columns::str_column(df, file, name)
}

fn load_metadata(dir: &Path) -> Result<Metadata> {
    let meta_path = dir.join("emulator.json");
    let meta: Metadata = serde_json::from_str(&std::fs::read_to_string(&meta_path).with_context(|| {
        format!("reading {} (is this an emulator folder from `mdpipe train-emulator`?)", meta_path.display())
    })?)
    .map_err(|e| anyhow!("{}: {e}", meta_path.display()))?;
    if meta.format != FORMAT {
        bail!(
            "{}: emulator format {} is not supported (this mdpipe reads format {FORMAT})",
            meta_path.display(),
            meta.format
        );
    }
    Ok(meta)
}

/// The settings the stored emulator was trained with (for cross-validation).
pub fn load_settings(dir: &Path) -> Result<EmulatorSettings> {
    Ok(load_metadata(dir)?.settings)
}

/// Provenance of the stored emulator.
pub fn load_provenance(dir: &Path) -> Result<Provenance> {
    Ok(load_metadata(dir)?.provenance)
}

pub fn load(dir: &Path) -> Result<Emulator> {
    let meta = load_metadata(dir)?;
    let read = |name: &str| -> Result<(DataFrame, std::path::PathBuf)> {
        let p = dir.join(name);
        Ok((artifacts::read_parquet(&p)?, p))
    };
    let training = super::read_training_table(&dir.join("training.parquet"), &meta.parameters)?;

    let (df, f) = read("scalings.parquet")?;
    let obs = strs(&df, &f, "observable")?;
    let xs = f64s(&df, &f, "x")?;
    let outputs: Vec<OutputKey> = obs.into_iter().zip(xs).map(|(observable, x)| OutputKey { observable, x }).collect();
    if outputs != training.outputs {
        bail!("{}: outputs do not match training.parquet", f.display());
    }
    let log_transform: Vec<bool> = strs(&df, &f, "transform")?.iter().map(|t| t == "log").collect();
    let output_mean = f64s(&df, &f, "mean")?;
    let output_std = f64s(&df, &f, "std")?;

    let (df, f) = read("pca.parquet")?;
    let m = outputs.len();
    let loading = f64s(&df, &f, "loading")?;
    let sv_rows = f64s(&df, &f, "singular_value")?;
    if loading.len() % m != 0 {
        bail!("{}: {} rows is not a multiple of {m} outputs", f.display(), loading.len());
    }
    let singular_values: Vec<f64> = sv_rows.chunks(m).map(|c| c[0]).collect();

    let (df, f) = read("scores.parquet")?;
    let scores = f64s(&df, &f, "score")?;

    let (df, f) = read("hyperparameters.parquet")?;
    let values = f64s(&df, &f, "value")?;
    let np = ArdHyper::n_params(meta.parameters.len());
    let hypers: Vec<ArdHyper> = values.chunks(np).map(|c| ArdHyper { log_params: c.to_vec() }).collect();

    let (df, f) = read("inputs.parquet")?;
    let input_lo = f64s(&df, &f, "lo")?;
    let input_hi = f64s(&df, &f, "hi")?;

    let parts = EmulatorParts {
        parameter_names: meta.parameters.clone(),
        design_ids: training.design_ids.clone(),
        train_inputs: training.inputs.clone(),
        train_values: training.values.clone(),
        train_errors: training.errors.clone(),
        noise_correlation: training.noise_correlation.clone().unwrap_or_default(),
        input_lo,
        input_hi,
        kernel: meta.kernel,
        outputs,
        log_transform,
        output_mean,
        output_std,
        singular_values,
        basis: loading,
        n_components: meta.n_components,
        scores,
        hypers,
    };
    Emulator::from_parts(parts).with_context(|| format!("rebuilding the emulator in {}", dir.display()))
}
