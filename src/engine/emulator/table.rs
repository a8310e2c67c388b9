//! Training and validation tables: design parameters and simulator outputs
//! per design point, long or wide, CSV or Parquet.
//!
//! Long (what `mdpipe ingest` writes): `design_id, observable, x, value`,
//! optionally `error` (the run's own statistical error of that value, the
//! jackknife error of its event average), plus one column per design
//! parameter (repeated on every row of a point).
//! Wide: one row per design point, `design_id`, the parameter columns, and
//! one column per output named `observable[x]` (or just `observable`, x = 0).

use crate::base::error::FieldError;
use crate::base::table::RawTable;
use anyhow::{anyhow, bail, Result};
use polars::prelude::*;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// One emulated output: an observable at one x (pT bin midpoint, time…).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OutputKey {
    pub observable: String,
    pub x: f64,
}

impl std::fmt::Display for OutputKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}[{}]", self.observable, self.x)
    }
}

/// Design points × outputs, dense.
#[derive(Clone, Debug)]
pub struct TrainingTable {
    pub path: PathBuf,
    pub parameter_names: Vec<String>,
    pub design_ids: Vec<i64>,
    /// Raw parameter values, row-major `n × d`.
    pub inputs: Vec<f64>,
    pub outputs: Vec<OutputKey>,
    /// Row-major `n × m`.
    pub values: Vec<f64>,
    /// Each value's statistical error from its own run (row-major `n × m`;
    /// 0 where the table has none, as for deterministic simulators).
    pub errors: Vec<f64>,
    /// The errors' correlation between outputs (m × m, pooled over the runs),
    /// from `TABLE.noise_correlation.csv`; `None`: independent.
    pub noise_correlation: Option<Vec<f64>>,
}

impl TrainingTable {
    pub fn n_points(&self) -> usize {
        self.design_ids.len()
    }
    pub fn n_outputs(&self) -> usize {
        self.outputs.len()
    }
    pub fn input(&self, i: usize) -> &[f64] {
        let d = self.parameter_names.len();
        &self.inputs[i * d..(i + 1) * d]
    }
    pub fn row(&self, i: usize) -> &[f64] {
        let m = self.outputs.len();
        &self.values[i * m..(i + 1) * m]
    }
    pub fn row_errors(&self, i: usize) -> &[f64] {
        let m = self.outputs.len();
        &self.errors[i * m..(i + 1) * m]
    }

    /// The sub-table of the given rows (for cross-validation folds).
    pub fn subset(&self, rows: &[usize]) -> TrainingTable {
        TrainingTable {
            path: self.path.clone(),
            parameter_names: self.parameter_names.clone(),
            design_ids: rows.iter().map(|&i| self.design_ids[i]).collect(),
            inputs: rows.iter().flat_map(|&i| self.input(i).to_vec()).collect(),
            outputs: self.outputs.clone(),
            values: rows.iter().flat_map(|&i| self.row(i).to_vec()).collect(),
            errors: rows.iter().flat_map(|&i| self.row_errors(i).to_vec()).collect(),
            noise_correlation: self.noise_correlation.clone(),
        }
    }

    /// Adds the rows of `other`, which must have the same parameters and
    /// outputs (new runs of the same simulator).
    pub fn append(&mut self, other: &TrainingTable) -> Result<()> {
        if other.parameter_names != self.parameter_names || other.outputs != self.outputs {
            bail!(
                "{}: its parameters or outputs differ from those of {} (new runs must be of the same simulator)",
                other.path.display(),
                self.path.display()
            );
        }
        if let Some(id) = other.design_ids.iter().find(|id| self.design_ids.contains(id)) {
            bail!("{}: design id {id} is already in {}", other.path.display(), self.path.display());
        }
        // Pooled over the runs that carry one, weighted by their number.
        self.noise_correlation = match (self.noise_correlation.take(), &other.noise_correlation) {
            (Some(a), Some(b)) => {
                let (na, nb) = (self.n_points() as f64, other.n_points() as f64);
                Some(a.iter().zip(b).map(|(x, y)| (na * x + nb * y) / (na + nb)).collect())
            }
            (a, b) => a.or_else(|| b.clone()),
        };
        self.design_ids.extend_from_slice(&other.design_ids);
        self.inputs.extend_from_slice(&other.inputs);
        self.values.extend_from_slice(&other.values);
        self.errors.extend_from_slice(&other.errors);
        Ok(())
    }

    /// Writes the long table, Parquet or CSV by extension, and its noise
    /// correlation beside it (both or neither; a correlation file left from
    /// an earlier table at `path` is removed, since it would be read as this
    /// table's).
    pub fn write(&self, path: &Path, provenance: Option<&crate::base::artifacts::Provenance>) -> Result<()> {
        let mut staged = crate::base::artifacts::StagedWrites::new();
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        if ext == "parquet" || ext == "pq" {
            staged.parquet(path, &mut self.to_long_frame()?, provenance)?;
        } else {
            staged.text(path, &self.long_csv(provenance))?;
        }
        self.stage_noise_correlation(path, &mut staged)?;
        staged.commit()?;
        self.remove_stale_noise_correlation(path)
    }

    fn long_csv(&self, provenance: Option<&crate::base::artifacts::Provenance>) -> String {
        let mut text = String::new();
        if let Some(p) = provenance {
            text.push_str(&format!("# mdpipe {} | {} | seed {}\n", p.mdpipe_version, p.command, p.seed));
        }
        text.push_str(&format!("design_id,observable,x,value,error,{}\n", self.parameter_names.join(",")));
        for i in 0..self.n_points() {
            let params: Vec<String> = self.input(i).iter().map(|v| v.to_string()).collect();
            for (j, o) in self.outputs.iter().enumerate() {
                text.push_str(&format!(
                    "{},{},{},{},{},{}\n",
                    self.design_ids[i],
                    o.observable,
                    o.x,
                    self.row(i)[j],
                    self.row_errors(i)[j],
                    params.join(",")
                ));
            }
        }
        text
    }

    /// Writes `TABLE.noise_correlation.csv` for the table at `path` (or
    /// removes a stale one when this table has none).
    pub fn write_noise_correlation(&self, path: &Path) -> Result<()> {
        let mut staged = crate::base::artifacts::StagedWrites::new();
        self.stage_noise_correlation(path, &mut staged)?;
        staged.commit()?;
        self.remove_stale_noise_correlation(path)
    }

    /// Without a correlation of its own, a table written at `path` must not
    /// pick up one left there by an earlier table (removed after the table
    /// is in place).
    fn remove_stale_noise_correlation(&self, path: &Path) -> Result<()> {
        if self.noise_correlation.is_some() {
            return Ok(());
        }
        let side = crate::base::covariance::noise_correlation_path(path);
        match std::fs::remove_file(&side) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Err(anyhow!("removing the stale {}: {e}", side.display()))
            }
            _ => Ok(()),
        }
    }

    fn stage_noise_correlation(&self, path: &Path, staged: &mut crate::base::artifacts::StagedWrites) -> Result<()> {
        let side = crate::base::covariance::noise_correlation_path(path);
        let Some(r) = &self.noise_correlation else { return Ok(()) };
        let m = self.n_outputs();
        let mut entries = Vec::new();
        for a in 0..m {
            for b in 0..a {
                if r[a * m + b] != 0.0 {
                    let (oa, ob) = (&self.outputs[a], &self.outputs[b]);
                    entries.push(crate::base::covariance::CovarianceEntry {
                        observable_a: oa.observable.clone(),
                        x_a: oa.x,
                        observable_b: ob.observable.clone(),
                        x_b: ob.x,
                        covariance: r[a * m + b],
                        line: 0,
                        rounding: 0.0,
                    });
                }
            }
        }
        staged.text(&side, &crate::base::covariance::noise_correlation_csv(&entries))
    }

    /// Long-format columns `design_id, observable, x, value`, for storing.
    pub fn to_long_frame(&self) -> Result<DataFrame> {
        let (n, m) = (self.n_points(), self.n_outputs());
        let mut ids = Vec::with_capacity(n * m);
        let mut obs = Vec::with_capacity(n * m);
        let mut xs = Vec::with_capacity(n * m);
        for i in 0..n {
            for o in &self.outputs {
                ids.push(self.design_ids[i]);
                obs.push(o.observable.as_str());
                xs.push(o.x);
            }
        }
        let mut cols = vec![
            Column::new("design_id".into(), ids),
            Column::new("observable".into(), obs),
            Column::new("x".into(), xs),
            Column::new("value".into(), self.values.clone()),
            Column::new("error".into(), self.errors.clone()),
        ];
        let d = self.parameter_names.len();
        for (k, name) in self.parameter_names.iter().enumerate() {
            let v: Vec<f64> = (0..n).flat_map(|i| std::iter::repeat_n(self.inputs[i * d + k], m)).collect();
            cols.push(Column::new(name.as_str().into(), v));
        }
        Ok(DataFrame::new(n * m, cols)?)
    }
}

fn check_finite(path: &Path, raw: &RawTable, field: &str, values: &[f64]) -> Result<()> {
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(FieldError::new(
            path,
            raw.location(i),
            field,
            format_args!("value is {}, must be a finite number", values[i]),
        )
        .into());
    }
    Ok(())
}

/// Parses `name[x]` into (name, x); a plain name has x = 0.
fn parse_wide_column(name: &str) -> Option<OutputKey> {
    match name.strip_suffix(']').and_then(|s| s.split_once('[')) {
        Some((obs, x)) => x.trim().parse::<f64>().ok().map(|x| OutputKey { observable: obs.to_string(), x }),
        None => Some(OutputKey { observable: name.to_string(), x: 0.0 }),
    }
}

/// Reads a long or wide table of simulator runs. Every design point must have
/// every output exactly once, and every value must be finite.
pub fn read_training_table(path: &Path, parameter_names: &[String]) -> Result<TrainingTable> {
    read_training_table_selected(path, parameter_names, &[])
}

/// Training values as they are read: cells keyed by (design point, output),
/// both numbered in order of first appearance.
#[derive(Default)]
struct Cells {
    point_order: Vec<i64>,
    point_row: HashMap<i64, usize>,
    outputs: Vec<OutputKey>,
    /// Value, its run's statistical error and the row it came from.
    cells: BTreeMap<(usize, usize), (f64, f64, usize)>,
}

impl Cells {
    fn point(&mut self, id: i64) -> usize {
        *self.point_row.entry(id).or_insert_with(|| {
            self.point_order.push(id);
            self.point_order.len() - 1
        })
    }

    fn output(&mut self, key: OutputKey) -> usize {
        match self.outputs.iter().position(|o| *o == key) {
            Some(k) => k,
            None => {
                self.outputs.push(key);
                self.outputs.len() - 1
            }
        }
    }

    /// Records one value; a second value for the same cell is an error naming both rows.
    fn add(
        &mut self,
        raw: &RawTable,
        path: &Path,
        id: i64,
        key: OutputKey,
        (value, error): (f64, f64),
        row: usize,
    ) -> Result<()> {
        let (point, out) = (self.point(id), self.output(key));
        if let Some((_, _, first)) = self.cells.insert((point, out), (value, error, row)) {
            bail!(
                "{}: {}: design point {id} has a second value for {} (first at {})",
                path.display(),
                raw.location(row),
                self.outputs[out],
                raw.location(first)
            );
        }
        Ok(())
    }
}

/// As [`read_training_table`], keeping only the named observables (all if
/// `observables` is empty); each named one must be in the table.
pub fn read_training_table_selected(
    path: &Path,
    parameter_names: &[String],
    observables: &[String],
) -> Result<TrainingTable> {
    let raw = RawTable::read(path)?;
    let file = path.display();
    if raw.height() == 0 {
        bail!("{file}: table has no rows");
    }
    let ids_f = raw.numbers(path, "design_id")?;
    for (i, v) in ids_f.iter().enumerate() {
        if v.fract() != 0.0 || !v.is_finite() {
            return Err(
                FieldError::new(path, raw.location(i), "design_id", format_args!("{v} is not an integer")).into()
            );
        }
    }
    let ids: Vec<i64> = ids_f.iter().map(|&v| v as i64).collect();
    let mut params = Vec::with_capacity(parameter_names.len());
    for name in parameter_names {
        let v = raw.numbers(path, name)?;
        check_finite(path, &raw, name, &v)?;
        params.push(v);
    }
    let keep = |o: &str| observables.is_empty() || observables.iter().any(|k| k == o);
    let cells = if raw.has("observable") {
        read_long(&raw, path, &ids, &keep)?
    } else {
        read_wide(&raw, path, &ids, parameter_names, &keep)?
    };
    let inputs = point_inputs(&raw, path, &ids, &cells, parameter_names, &params)?;
    let (outputs, values, errors) = ordered_values(path, &cells, observables)?;
    let noise_correlation = read_noise_correlation_beside(path, &outputs)?;
    Ok(TrainingTable {
        path: path.to_path_buf(),
        parameter_names: parameter_names.to_vec(),
        design_ids: cells.point_order,
        inputs,
        outputs,
        values,
        errors,
        noise_correlation,
    })
}

/// The correlation matrix (m × m, unit diagonal) of `TABLE.noise_correlation.csv`
/// over `outputs`, if the file is there; pairs it does not list are
/// uncorrelated, and entries for outputs not in the table are ignored.
fn read_noise_correlation_beside(path: &Path, outputs: &[OutputKey]) -> Result<Option<Vec<f64>>> {
    let side = crate::base::covariance::noise_correlation_path(path);
    if !side.exists() {
        return Ok(None);
    }
    let m = outputs.len();
    let find =
        |o: &str, x: f64| outputs.iter().position(|k| k.observable == o && (k.x - x).abs() <= 1e-9 * x.abs().max(1.0));
    let mut r = vec![0.0; m * m];
    for a in 0..m {
        r[a * m + a] = 1.0;
    }
    for e in crate::base::covariance::read_noise_correlation(&side)? {
        if let (Some(a), Some(b)) = (find(&e.observable_a, e.x_a), find(&e.observable_b, e.x_b)) {
            if a != b {
                r[a * m + b] = e.covariance;
                r[b * m + a] = e.covariance;
            }
        }
    }
    Ok(Some(positive_definite(r, m, &side)))
}

/// The correlation matrix itself if it is positive definite; otherwise
/// shrunk towards the identity, `(1 − λ) R + λ I`, by the smallest λ of a
/// ladder that makes it so, with a warning. A projected noise `vᵀ N v` below
/// zero would add variance where run noise is to be removed, and an
/// indefinite N could leave the emulator's covariance indefinite. Entries
/// missing from the file (bins undefined in some runs) or a hand-edited
/// file can break definiteness even though each run's matrix had it.
fn positive_definite(r: Vec<f64>, m: usize, file: &Path) -> Vec<f64> {
    for lambda in [0.0, 1e-6, 1e-4, 1e-3, 1e-2, 0.03, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 0.95, 0.99, 1.0] {
        let shrunk: Vec<f64> =
            r.iter().enumerate().map(|(ab, v)| if ab % (m + 1) == 0 { 1.0 } else { (1.0 - lambda) * v }).collect();
        let mut chol = crate::engine::gp::CholeskyWorkspace::new(m);
        chol.factor.copy_from_slice(&shrunk);
        if chol.factorize_exact() {
            if lambda > 0.0 {
                crate::base::messages::note!("warning: {}: the correlation matrix is not positive definite; shrunk towards the identity by λ = {lambda} ((1 − λ) R + λ I)", file.display());
            }
            return shrunk;
        }
    }
    (0..m * m).map(|ab| if ab % (m + 1) == 0 { 1.0 } else { 0.0 }).collect()
}

/// A long table: one row per (design point, observable, x).
fn read_long(raw: &RawTable, path: &Path, ids: &[i64], keep: &dyn Fn(&str) -> bool) -> Result<Cells> {
    let obs = raw.strings(path, "observable")?;
    let xs = raw.numbers(path, "x")?;
    let values = raw.numbers(path, "value")?;
    check_finite(path, raw, "x", &xs)?;
    check_finite(path, raw, "value", &values)?;
    let errors = if raw.has("error") { raw.numbers(path, "error")? } else { vec![0.0; raw.height()] };
    check_run_errors(path, raw, &errors)?;
    let mut cells = Cells::default();
    for i in 0..raw.height() {
        if obs[i].trim().is_empty() {
            return Err(FieldError::new(path, raw.location(i), "observable", "empty observable name").into());
        }
        if keep(&obs[i]) {
            cells.add(
                raw,
                path,
                ids[i],
                OutputKey { observable: obs[i].clone(), x: xs[i] },
                (values[i], errors[i]),
                i,
            )?;
        }
    }
    Ok(cells)
}

/// A wide table: one row per design point, one column `observable[x]` per output.
fn read_wide(
    raw: &RawTable,
    path: &Path,
    ids: &[i64],
    parameter_names: &[String],
    keep: &dyn Fn(&str) -> bool,
) -> Result<Cells> {
    let file = path.display();
    let reserved: Vec<&str> = std::iter::once("design_id").chain(parameter_names.iter().map(String::as_str)).collect();
    let out_cols: Vec<String> = raw.columns().into_iter().filter(|c| !reserved.contains(&c.as_str())).collect();
    if out_cols.is_empty() {
        bail!("{file}: no output columns (a long table needs 'observable, x, value'; a wide one, columns named like 'ch_v2[0.3]')");
    }
    let mut cells = Cells::default();
    for c in &out_cols {
        let key = parse_wide_column(c)
            .ok_or_else(|| anyhow!("{file}: column '{c}': expected 'observable[x]' with a numeric x"))?;
        if !keep(&key.observable) {
            continue;
        }
        let values = raw.numbers(path, c)?;
        check_finite(path, raw, c, &values)?;
        for i in 0..raw.height() {
            cells.add(raw, path, ids[i], key.clone(), (values[i], 0.0), i)?;
        }
    }
    Ok(cells)
}

/// Each point's parameters, which must agree on every row of the point.
fn point_inputs(
    raw: &RawTable,
    path: &Path,
    ids: &[i64],
    cells: &Cells,
    parameter_names: &[String],
    params: &[Vec<f64>],
) -> Result<Vec<f64>> {
    let d = parameter_names.len();
    let mut inputs = vec![f64::NAN; cells.point_order.len() * d];
    for i in 0..raw.height() {
        // A point whose rows were all of unselected observables is not trained on.
        let Some(&p) = cells.point_row.get(&ids[i]) else { continue };
        for k in 0..d {
            let v = params[k][i];
            let slot = &mut inputs[p * d + k];
            if slot.is_nan() {
                *slot = v;
            } else if *slot != v {
                let problem = format!("design point {} has {} here but {} on an earlier row", ids[i], v, slot);
                return Err(FieldError::new(path, raw.location(i), &parameter_names[k], problem).into());
            }
        }
    }
    Ok(inputs)
}

/// Outputs sorted by observable (first appearance) then x, so bins are in
/// order, and the `points × outputs` values; every point needs every output.
fn ordered_values(path: &Path, cells: &Cells, observables: &[String]) -> Result<(Vec<OutputKey>, Vec<f64>, Vec<f64>)> {
    let file = path.display();
    let outputs = &cells.outputs;
    let obs_order: Vec<String> = outputs.iter().fold(Vec::new(), |mut acc, o| {
        if !acc.contains(&o.observable) {
            acc.push(o.observable.clone());
        }
        acc
    });
    if let Some(missing) = observables.iter().find(|o| !obs_order.contains(o)) {
        bail!("{file}: no values for observable '{missing}' (found: {})", obs_order.join(", "));
    }
    let mut perm: Vec<usize> = (0..outputs.len()).collect();
    perm.sort_by(|&a, &b| {
        let oa = obs_order.iter().position(|o| *o == outputs[a].observable);
        let ob = obs_order.iter().position(|o| *o == outputs[b].observable);
        oa.cmp(&ob).then(outputs[a].x.total_cmp(&outputs[b].x))
    });
    let (n, m) = (cells.point_order.len(), outputs.len());
    let (mut values, mut errors) = (vec![0.0; n * m], vec![0.0; n * m]);
    for p in 0..n {
        for (new_k, &old_k) in perm.iter().enumerate() {
            match cells.cells.get(&(p, old_k)) {
                Some(&(v, e, _)) => (values[p * m + new_k], errors[p * m + new_k]) = (v, e),
                None => bail!(
                    "{file}: design point {} has no value for {} (every design point needs every output; drop or rerun failed points before training)",
                    cells.point_order[p],
                    outputs[old_k]
                ),
            }
        }
    }
    Ok((perm.iter().map(|&k| outputs[k].clone()).collect(), values, errors))
}

/// A run's statistical error must be a finite number ≥ 0 (an `error` column
/// left empty by a failed jackknife is caught here, not in the likelihood).
fn check_run_errors(path: &Path, raw: &RawTable, errors: &[f64]) -> Result<()> {
    match errors.iter().position(|e| !e.is_finite() || *e < 0.0) {
        Some(i) => Err(FieldError::new(
            path,
            raw.location(i),
            "error",
            format_args!("{} is not a statistical error (it must be finite and ≥ 0)", errors[i]),
        )
        .into()),
        None => Ok(()),
    }
}

/// Checks a training table against the design it was run from (`design.parquet`
/// from `mdpipe design`, or a CSV with the same columns): every design point
/// must be present, with the same parameter values. Missing points are named.
pub fn check_against_design(table: &TrainingTable, design: &Path) -> Result<()> {
    let raw = RawTable::read(design)?;
    let ids: Vec<i64> = raw.numbers(design, "design_id")?.into_iter().map(|v| v as i64).collect();
    let missing: Vec<i64> = ids.iter().copied().filter(|id| !table.design_ids.contains(id)).collect();
    if !missing.is_empty() {
        let shown: Vec<String> = missing.iter().take(20).map(|i| i.to_string()).collect();
        bail!(
            "{}: {} of the {} design points in {} have no runs ({}{}); rerun them, or train on the rest with a design that lists only the finished points",
            table.path.display(),
            missing.len(),
            ids.len(),
            design.display(),
            shown.join(", "),
            if missing.len() > 20 { ", …" } else { "" }
        );
    }
    for (k, name) in table.parameter_names.iter().enumerate() {
        let values = raw.numbers(design, name)?;
        for (row, (id, v)) in ids.iter().zip(&values).enumerate() {
            let i = table.design_ids.iter().position(|d| d == id).expect("checked above");
            let t = table.input(i)[k];
            if (t - v).abs() > 1e-9 * v.abs().max(1.0) {
                let problem = format!("design point {id} has {v} in the design but {t} in {}", table.path.display());
                return Err(FieldError::new(design, raw.location(row), name, problem).into());
            }
        }
    }
    Ok(())
}
