//! Finished fits on disk, and when one may stand in for a new fit.
//!
//! Every calibration's outputs carry `fit.key`: a hash of everything that
//! defines its posterior and how it is sampled (config, data, kernel,
//! observables, prior, sampler settings, the data's covariance) and of its
//! model's answers at probe points (every prediction and, for an emulator,
//! its covariance, bit for bit: a retrained emulator answers differently at
//! every θ). Not the seed, nor the config's `[run]` and `[[candidates]]`
//! tables (`Config::fit_hash`). A study fits some problems in more than one stage
//! (the last adaptive-design round's pilots are two of the calibrate stage's
//! cases; diagnose's base fits are two more): a stage may take a stored fit
//! with the same key instead of sampling the same posterior again with
//! another seed. The fit's provenance keeps the seed and command it was made with.

use super::summary::{PredictionRow, Summary};
use super::Calibration;
use crate::base::artifacts;
use crate::base::columns::{f64_column, str_column};
use crate::engine::calibrate::problem::{fit_key, Problem};
use crate::engine::calibrate::sampler::chains::Chains;
use crate::engine::model::Simulator;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

pub const KEY_FILE: &str = "fit.key";

/// The problem's key: its fit key (the checkpoint key without the seed, of
/// the config's tables a fit can depend on), and its model's digest.
pub fn problem_key(problem: &Problem) -> String {
    let material = format!("{}|{}", fit_key(problem), model_digest(problem));
    artifacts::sha256_hex(material.as_bytes())
}

/// The first stored fit among `dirs` of this very problem, read back. One
/// that cannot be read (a file removed or damaged since) is passed over with
/// a warning: the caller then samples the problem itself.
pub fn find(dirs: &[PathBuf], problem: &Problem) -> Option<(PathBuf, Calibration)> {
    let key = problem_key(problem);
    for dir in dirs {
        let stored = std::fs::read_to_string(dir.join(KEY_FILE)).unwrap_or_default();
        if stored.trim() == key {
            match read(dir, problem) {
                Ok(fit) => return Some((dir.clone(), fit)),
                Err(e) => crate::base::messages::note!(
                    "warning: the stored fit {} cannot be read ({e:#}); not taken",
                    dir.display()
                ),
            }
        }
    }
    None
}

/// A calibration as `write_outputs` wrote it.
pub fn read(dir: &Path, problem: &Problem) -> Result<Calibration> {
    let summary: Summary = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json"))?)
        .with_context(|| format!("{}: summary.json", dir.display()))?;
    let chains = read_chains(&dir.join("posterior.parquet"), &problem.prior.names)?;
    let predictions = read_predictions(&dir.join("predictions.parquet"))?;
    Ok(Calibration { chains, summary, predictions })
}

fn read_chains(path: &Path, names: &[String]) -> Result<Chains> {
    let df = artifacts::read_parquet(path)?;
    let columns = names.iter().map(|n| f64_column(&df, path, n)).collect::<Result<Vec<_>>>()?;
    let chain = f64_column(&df, path, "chain")?;
    let mut chains: Vec<Vec<f64>> = Vec::new();
    let mut points = 0;
    for (row, &c) in chain.iter().enumerate() {
        let c = c as usize;
        if c > chains.len() {
            let at = format!("row {}", row + 1);
            return Err(crate::base::error::FieldError::new(path, at, "chain", "chains must come in order").into());
        }
        if c == chains.len() {
            chains.push(Vec::new());
            points = 0;
        }
        points += 1;
        chains[c].extend(columns.iter().map(|col| col[row]));
    }
    if names.is_empty() {
        return Ok(Chains::of_a_point(chains.len(), points));
    }
    Ok(Chains::new(names.to_vec(), names.len(), chains))
}

fn read_predictions(path: &Path) -> Result<Vec<PredictionRow>> {
    let df = artifacts::read_parquet(path)?;
    let bands = |prefix: &str| -> Result<Vec<Vec<f64>>> {
        ["q025", "q16", "median", "q84", "q975"]
            .iter()
            .map(|q| f64_column(&df, path, &format!("{prefix}_{q}")))
            .collect()
    };
    let (model, model_md, delta) = (bands("model")?, bands("model_md")?, bands("delta")?);
    let observable = str_column(&df, path, "observable")?;
    let kind = str_column(&df, path, "kind")?;
    let (x, delta_mean, truth) =
        (f64_column(&df, path, "x")?, f64_column(&df, path, "delta_mean")?, f64_column(&df, path, "truth")?);
    let at = |b: &[Vec<f64>], i: usize| [b[0][i], b[1][i], b[2][i], b[3][i], b[4][i]];
    (0..df.height())
        .map(|i| {
            Ok(PredictionRow {
                observable: observable[i].clone(),
                kind: match kind[i].as_str() {
                    "grid" => "grid",
                    "data" => "data",
                    other => {
                        let problem = format!("'{other}' is neither grid nor data");
                        return Err(crate::base::error::FieldError::new(
                            path,
                            format!("row {}", i + 1),
                            "kind",
                            problem,
                        )
                        .into());
                    }
                },
                x: x[i],
                model: at(&model, i),
                model_md: at(&model_md, i),
                delta: at(&delta, i),
                delta_mean: delta_mean[i],
                truth: truth[i],
            })
        })
        .collect()
}

/// The model's predictions (and model covariance, when it has one) at the
/// data's x for three θ inside the prior box, as bit patterns.
pub fn model_digest(problem: &Problem) -> String {
    let sim: &dyn Simulator = problem.simulator.as_ref();
    let dim = sim.parameter_names().len();
    let (lo, hi) = (&problem.prior.lower[..dim], &problem.prior.upper[..dim]);
    let mut bits: Vec<u64> = Vec::new();
    for t in [0.5, 0.3, 0.7] {
        let theta: Vec<f64> = lo.iter().zip(hi).enumerate().map(|(i, (l, h))| probe(*l, *h, t, i)).collect();
        for b in &problem.likelihood.blocks {
            let mut out = vec![0.0; b.x.len()];
            sim.predict(b.model_index, &b.x, &theta, &mut out);
            bits.extend(out.iter().map(|v| v.to_bits()));
            if sim.has_model_covariance() {
                let mut lower = vec![0.0; b.x.len() * b.x.len()];
                sim.add_model_covariance(b.model_index, &b.x, &theta, 1.0, &mut lower);
                bits.extend(lower.iter().map(|v| v.to_bits()));
            }
        }
    }
    artifacts::sha256_hex(&bits.iter().flat_map(|b| b.to_le_bytes()).collect::<Vec<u8>>())
}

/// A point at fraction t of [lo, hi], mirrored in every other coordinate so
/// that the probes are not all on the box's diagonal.
fn probe(lo: f64, hi: f64, t: f64, i: usize) -> f64 {
    let t = if i.is_multiple_of(2) { t } else { 1.0 - t };
    lo + t * (hi - lo)
}
