//! `mdpipe design`: maximin Latin-hypercube designs for expensive simulators,
//! with one iEBE-MUSIC parameter file per point and a SLURM job-array script.
//!
//! Optimization: a Latin hypercube is improved by swapping two entries of one
//! column at a time, minimizing the Morris–Mitchell criterion
//! φ_p = (Σ_{i<j} d_ij^-p)^(1/p) (p = 50, a smooth stand-in for the minimum
//! distance), with the threshold-accepting outer loop of the enhanced
//! stochastic evolutionary algorithm (Jin, Chen & Sudjianto 2005). A swap
//! changes only the distances of two rows, so each trial costs O(n d).

use crate::base::artifacts::{self, Provenance};
use anyhow::{anyhow, bail, Context, Result};
use polars::prelude::*;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignSpec {
    pub name: String,
    #[serde(rename = "parameter")]
    pub parameters: Vec<DesignParameter>,
    /// Keys written unchanged into every parameter file.
    #[serde(default)]
    pub fixed: BTreeMap<String, toml::Value>,
    #[serde(default)]
    pub slurm: SlurmSpec,
}

#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct DesignParameter {
    pub name: String,
    pub min: f64,
    pub max: f64,
    /// Sample uniformly in log(value) (needs min > 0).
    #[serde(default)]
    pub log: bool,
    /// The simulator's key for this parameter in the `key value` files; the
    /// parameter's name when not given (a simulator that reads its
    /// parameters from the command line needs none).
    #[serde(default)]
    pub key: String,
    #[serde(default)]
    pub units: String,
}

impl DesignParameter {
    /// The key written into the point's parameter file.
    pub fn file_key(&self) -> &str {
        if self.key.is_empty() {
            &self.name
        } else {
            &self.key
        }
    }
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlurmSpec {
    /// Command run for one design point; `{param_file}` (its iEBE-MUSIC parameter
    /// file), `{point}` (the id as %04d, the run folder's name) and `{id}` are substituted.
    pub command: String,
    pub time: String,
    pub cpus_per_task: u32,
    pub mem: String,
}

impl Default for SlurmSpec {
    fn default() -> Self {
        SlurmSpec {
            // No simulator is assumed: a design spec for `mdpipe design` names its
            // own; `mdpipe run` writes its `[run.simulator]` command here.
            command: "echo 'no [slurm] command in the design spec: give the command that runs one point' >&2; exit 1"
                .into(),
            time: "04:00:00".into(),
            cpus_per_task: 1,
            mem: "4G".into(),
        }
    }
}

impl DesignSpec {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading design spec {}", path.display()))?;
        let spec: DesignSpec = toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        for p in &spec.parameters {
            if !(p.min.is_finite() && p.max.is_finite() && p.min < p.max) {
                bail!(
                    "{}: [[parameter]] {}: bounds must satisfy min < max, got ({}, {})",
                    path.display(),
                    p.name,
                    p.min,
                    p.max
                );
            }
            if p.log && p.min <= 0.0 {
                bail!("{}: [[parameter]] {}: log scale needs min > 0", path.display(), p.name);
            }
        }
        if spec.parameters.is_empty() {
            bail!("{}: no [[parameter]] entries", path.display());
        }
        Ok(spec)
    }

    /// Maps a unit-cube point to parameter values.
    pub fn scale(&self, u: &[f64]) -> Vec<f64> {
        self.parameters
            .iter()
            .zip(u)
            .map(
                |(p, &v)| {
                    if p.log {
                        (p.min.ln() + v * (p.max.ln() - p.min.ln())).exp()
                    } else {
                        p.min + v * (p.max - p.min)
                    }
                },
            )
            .collect()
    }
}

/// Quality figures of a design in the unit cube.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DesignQuality {
    pub points: usize,
    pub dimensions: usize,
    pub min_distance: f64,
    pub centered_l2_discrepancy: f64,
}

/// Random Latin hypercube in [0,1]^d (row-major n × d), cell-centred jitter.
pub fn random_lhs(n: usize, d: usize, rng: &mut impl Rng) -> Vec<f64> {
    let mut x = vec![0.0; n * d];
    for k in 0..d {
        let mut perm: Vec<usize> = (0..n).collect();
        perm.shuffle(rng);
        for i in 0..n {
            x[i * d + k] = (perm[i] as f64 + rng.random::<f64>()) / n as f64;
        }
    }
    x
}

fn sq_dist(x: &[f64], d: usize, i: usize, j: usize) -> f64 {
    (0..d).map(|k| (x[i * d + k] - x[j * d + k]).powi(2)).sum()
}

pub fn min_distance(x: &[f64], d: usize) -> f64 {
    let n = x.len() / d;
    let mut m = f64::INFINITY;
    for i in 0..n {
        for j in i + 1..n {
            m = m.min(sq_dist(x, d, i, j));
        }
    }
    m.sqrt()
}

/// Centered L2 discrepancy (Hickernell 1998).
pub fn centered_l2_discrepancy(x: &[f64], d: usize) -> f64 {
    let n = x.len() / d;
    let nf = n as f64;
    let mut a = 0.0;
    for i in 0..n {
        let mut p = 1.0;
        for k in 0..d {
            let z = (x[i * d + k] - 0.5).abs();
            p *= 1.0 + 0.5 * z - 0.5 * z * z;
        }
        a += p;
    }
    let mut b = 0.0;
    for i in 0..n {
        for j in 0..n {
            let mut p = 1.0;
            for k in 0..d {
                let (zi, zj) = ((x[i * d + k] - 0.5).abs(), (x[j * d + k] - 0.5).abs());
                p *= 1.0 + 0.5 * zi + 0.5 * zj - 0.5 * (x[i * d + k] - x[j * d + k]).abs();
            }
            b += p;
        }
    }
    ((13.0f64 / 12.0).powi(d as i32) - 2.0 / nf * a + b / (nf * nf)).sqrt()
}

pub fn quality(x: &[f64], d: usize) -> DesignQuality {
    DesignQuality {
        points: x.len() / d,
        dimensions: d,
        min_distance: min_distance(x, d),
        centered_l2_discrepancy: centered_l2_discrepancy(x, d),
    }
}

/// Maximin-optimized Latin hypercube: column swaps by the enhanced
/// stochastic evolutionary algorithm on φ_p (Jin, Chen & Sudjianto 2005),
/// then swaps at the closest pair until the minimum distance stops rising
/// (`maximin::refine_closest_pairs`).
pub fn maximin_lhs(n: usize, d: usize, seed: u64) -> Vec<f64> {
    const P: i32 = 50;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut x = random_lhs(n, d, &mut rng);
    if n < 3 {
        return x;
    }
    // Work with distances scaled by the typical spacing to keep d^-p in range.
    let scale = (n as f64).powf(1.0 / d as f64);
    let inv_pow = |d2: f64| (d2.sqrt() * scale).max(1e-12).powi(-P);
    let mut terms = vec![0.0; n * n];
    let mut total = 0.0;
    for i in 0..n {
        for j in i + 1..n {
            let t = inv_pow(sq_dist(&x, d, i, j));
            terms[i * n + j] = t;
            terms[j * n + i] = t;
            total += t;
        }
    }
    let mut best = x.clone();
    let mut best_total = total;
    let mut threshold = 0.005 * total;
    let outer = 60;
    let inner = (200 * n * d).min(300_000) / outer + 50;
    let mut new_i = vec![0.0; n];
    let mut new_j = vec![0.0; n];
    for _ in 0..outer {
        let mut improved = false;
        for _ in 0..inner {
            let k = rng.random_range(0..d);
            let i = rng.random_range(0..n);
            let mut j = rng.random_range(0..n - 1);
            if j >= i {
                j += 1;
            }
            x.swap(i * d + k, j * d + k);
            let mut delta = 0.0;
            for m in 0..n {
                if m == i || m == j {
                    continue;
                }
                new_i[m] = inv_pow(sq_dist(&x, d, i, m));
                new_j[m] = inv_pow(sq_dist(&x, d, j, m));
                delta += new_i[m] - terms[i * n + m] + new_j[m] - terms[j * n + m];
            }
            // The i–j distance does not change under a swap in one column.
            if delta < threshold * rng.random::<f64>() {
                for m in 0..n {
                    if m == i || m == j {
                        continue;
                    }
                    terms[i * n + m] = new_i[m];
                    terms[m * n + i] = new_i[m];
                    terms[j * n + m] = new_j[m];
                    terms[m * n + j] = new_j[m];
                }
                total += delta;
                if total < best_total * (1.0 - 1e-12) {
                    best_total = total;
                    best.copy_from_slice(&x);
                    improved = true;
                }
            } else {
                x.swap(i * d + k, j * d + k);
            }
        }
        // Cool steadily; restart from the best design after an unproductive round.
        threshold *= 0.7;
        if !improved {
            x.copy_from_slice(&best);
            total = best_total;
            for i in 0..n {
                for j in i + 1..n {
                    let t = inv_pow(sq_dist(&x, d, i, j));
                    terms[i * n + j] = t;
                    terms[j * n + i] = t;
                }
            }
        }
    }
    let proposals = (200 * n * d).min(200_000);
    super::maximin::refine_closest_pairs(&mut best, d, proposals, &mut rng);
    best
}

/// Writes `design.parquet`, `parameter_NNN` files, `submit.slurm` and `quality.json` into `out`.
pub fn write_design(spec: &DesignSpec, spec_hash: &str, n: usize, seed: u64, out: &Path) -> Result<DesignQuality> {
    let d = spec.parameters.len();
    let unit = maximin_lhs(n, d, seed);
    let q = quality(&unit, d);
    let prov =
        Provenance::new(spec_hash.to_string(), String::new(), seed, &format!("design {} --points {n}", spec.name));
    let rows: Vec<Vec<f64>> = unit.chunks(d).map(|u| spec.scale(u)).collect();
    let ids: Vec<i64> = (0..n as i64).collect();
    write_points(spec, &ids, &rows, &prov, &format!("mdpipe design ({n} points, seed {seed})"), out)?;
    artifacts::write_json_atomic(&out.join("quality.json"), &serde_json::json!({"quality": q, "provenance": prov}))?;
    Ok(q)
}

/// Writes given points (physical units, in the spec's parameter order) with
/// their design ids: `design.parquet`, one parameter file per point and a
/// SLURM array script over those ids. `made_by` goes into the script's header.
pub fn write_points(
    spec: &DesignSpec,
    ids: &[i64],
    rows: &[Vec<f64>],
    prov: &Provenance,
    made_by: &str,
    out: &Path,
) -> Result<()> {
    let n = ids.len();
    if n == 0 || rows.len() != n {
        bail!(
            "{}: a design needs one or more points, each with its id ({} ids, {} points)",
            out.display(),
            n,
            rows.len()
        );
    }
    let span = span_of(ids);
    let mut cols = vec![Column::new("design_id".into(), ids.iter().map(|&i| i as u32).collect::<Vec<u32>>())];
    for (k, p) in spec.parameters.iter().enumerate() {
        cols.push(Column::new(p.name.as_str().into(), rows.iter().map(|r| r[k]).collect::<Vec<f64>>()));
    }
    let mut df = DataFrame::new(n, cols)?;
    artifacts::write_parquet_atomic(&out.join("design.parquet"), &mut df, Some(prov))?;
    for (&id, r) in ids.iter().zip(rows) {
        let mut text = String::new();
        for (key, value) in &spec.fixed {
            text.push_str(&format!("{key} {}\n", toml_scalar(value)));
        }
        for (p, v) in spec.parameters.iter().zip(r) {
            text.push_str(&format!("{} {v}\n", p.file_key()));
        }
        artifacts::write_text_atomic(&parameter_file(out, id, span), &text)?;
    }
    let width = parameter_file_width(span);
    let param_file = format!("parameters/parameter_$(printf '%0{width}d' $SLURM_ARRAY_TASK_ID)");
    let cmd = spec
        .slurm
        .command
        .replace("{param_file}", &param_file)
        .replace("{point}", "$(printf '%04d' $SLURM_ARRAY_TASK_ID)")
        .replace("{id}", "$SLURM_ARRAY_TASK_ID");
    let array = ids.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(",");
    let array = if ids.windows(2).all(|w| w[1] == w[0] + 1) { format!("{}-{}", ids[0], ids[n - 1]) } else { array };
    let script = format!(
        "#!/bin/bash\n# One design point per array task; made by {made_by}.\n#SBATCH --job-name={}\n#SBATCH --array={array}\n#SBATCH --time={}\n#SBATCH --cpus-per-task={}\n#SBATCH --mem={}\n#SBATCH --output=logs/%x_%A_%a.out\nset -euo pipefail\ncd \"$SLURM_SUBMIT_DIR\"\nmkdir -p logs runs\n# This task's iEBE-MUSIC parameter file: {param_file}\n{cmd}\n",
        spec.name,
        spec.slurm.time,
        spec.slurm.cpus_per_task,
        spec.slurm.mem
    );
    artifacts::write_text_atomic(&out.join("submit.slurm"), &script)?;
    Ok(())
}

/// What the parameter files' numbering is sized for: one past the largest id.
pub fn span_of(ids: &[i64]) -> usize {
    ids.iter().copied().max().map_or(0, |m| m.max(0) as usize + 1)
}

fn parameter_file_width(n: usize) -> usize {
    (n.max(1) - 1).to_string().len().max(3)
}

/// The iEBE-MUSIC parameter file of point `id` in a design written into `dir`
/// whose ids are below `n` ([`span_of`]).
pub fn parameter_file(dir: &Path, id: i64, n: usize) -> std::path::PathBuf {
    dir.join("parameters").join(format!("parameter_{id:0width$}", width = parameter_file_width(n)))
}

/// A design.parquet's columns: the parameter names in the file's order, the
/// design ids, and each parameter's values.
pub struct DesignColumns {
    pub names: Vec<String>,
    pub ids: Vec<i64>,
    pub columns: Vec<Vec<f64>>,
}

/// Reads a design.parquet (from `mdpipe design`: `design_id` plus one column per parameter).
pub fn read_columns(design: &Path) -> Result<DesignColumns> {
    let df = artifacts::read_parquet(design)?;
    let column = |name: &str| crate::base::columns::f64_column(&df, design, name);
    let ids = column("design_id")?.into_iter().map(|v| v as i64).collect();
    let names: Vec<String> = df.get_column_names().iter().map(|s| s.to_string()).filter(|n| n != "design_id").collect();
    let columns = names.iter().map(|n| column(n)).collect::<Result<_>>()?;
    Ok(DesignColumns { names, ids, columns })
}

/// The points of a design.parquet: each design id with its parameter values by name.
pub fn read_points(design: &Path) -> Result<Vec<(i64, BTreeMap<String, f64>)>> {
    let d = read_columns(design)?;
    Ok((0..d.ids.len())
        .map(|i| (d.ids[i], d.names.iter().zip(&d.columns).map(|(n, c)| (n.clone(), c[i])).collect()))
        .collect())
}

fn toml_scalar(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maximin_is_a_latin_hypercube_and_beats_random() {
        for &(n, d) in &[(50usize, 2usize), (100, 5)] {
            let x = maximin_lhs(n, d, 3);
            // Latin: each column has exactly one point per cell.
            for k in 0..d {
                let mut cells: Vec<usize> = (0..n).map(|i| (x[i * d + k] * n as f64).floor() as usize).collect();
                cells.sort();
                assert_eq!(cells, (0..n).collect::<Vec<_>>());
            }
            // Better than every one of 20 random Latin hypercubes.
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
            let best_random = (0..20).map(|_| min_distance(&random_lhs(n, d, &mut rng), d)).fold(0.0, f64::max);
            assert!(min_distance(&x, d) > best_random, "n={n} d={d}: {} vs {best_random}", min_distance(&x, d));
        }
    }

    #[test]
    fn bundled_spec_writes_iebe_music_parameter_files_and_slurm_array() {
        let spec_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("design/heavy_ion_5param.toml");
        let spec = DesignSpec::load(&spec_path).unwrap();
        let out = std::env::temp_dir().join(format!("mdpipe-design-{}", std::process::id()));
        let q = write_design(&spec, "hash", 20, 4, &out).unwrap();
        assert_eq!((q.points, q.dimensions), (20, 5));
        let text = std::fs::read_to_string(out.join("parameters/parameter_013")).unwrap();
        let kv: BTreeMap<&str, f64> =
            text.lines().map(|l| l.split_once(' ').unwrap()).map(|(k, v)| (k, v.parse().unwrap())).collect();
        assert_eq!(kv["T_dependent_Shear_to_S_ratio"], 3.0);
        let t = kv["shear_viscosity_3_eta_over_s_T_kink_in_GeV"];
        assert!((0.13..0.3).contains(&t));
        assert!((0.1..0.5).contains(&kv["eps_switch"]));
        let design = artifacts::read_parquet(&out.join("design.parquet")).unwrap();
        assert_eq!(design.height(), 20);
        let t_col = design.column("T_kink").unwrap().f64().unwrap().get(13).unwrap();
        assert_eq!(t_col, t);
        let slurm = std::fs::read_to_string(out.join("submit.slurm")).unwrap();
        assert!(
            slurm.contains("#SBATCH --array=0-19") && slurm.contains("parameter_$(printf '%03d' $SLURM_ARRAY_TASK_ID)")
        );
    }

    /// A simulator that reads its parameters from the command line needs no
    /// parameter-file keys: the files then name each parameter by its name.
    #[test]
    fn a_spec_without_keys_names_parameters_by_their_names() {
        let dir = std::env::temp_dir().join(format!("mdpipe-design-nokey-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let spec_path = dir.join("spec.toml");
        std::fs::write(&spec_path, "name = \"cooling\"\n[[parameter]]\nname = \"k\"\nmin = 0.1\nmax = 2.0\n").unwrap();
        let spec = DesignSpec::load(&spec_path).unwrap();
        write_design(&spec, "hash", 4, 1, &dir.join("out")).unwrap();
        let text = std::fs::read_to_string(dir.join("out/parameters/parameter_002")).unwrap();
        let (key, value) = text.trim().split_once(' ').unwrap();
        assert_eq!(key, "k");
        assert!((0.1..2.0).contains(&value.parse::<f64>().unwrap()), "{text}");
    }

    #[test]
    fn centered_l2_discrepancy_matches_hand_value() {
        // One point at the centre in 1-d: CD² = 13/12 - 2 + 1 = 1/12.
        assert!((centered_l2_discrepancy(&[0.5], 1) - (1.0f64 / 12.0).sqrt()).abs() < 1e-12);
    }

    /// The closest-pair swaps of `maximin`, on designs from this module.
    mod closest_pair_swaps {
        use super::super::*;
        use crate::engine::maximin::*;

        fn is_latin(x: &[f64], d: usize) -> bool {
            let n = x.len() / d;
            (0..d).all(|k| {
                let mut cells: Vec<usize> = (0..n).map(|i| (x[i * d + k] * n as f64).floor() as usize).collect();
                cells.sort();
                cells == (0..n).collect::<Vec<_>>()
            })
        }

        #[test]
        fn swaps_at_the_closest_pair_keep_the_design_latin_and_never_lower_its_minimum_distance() {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
            for &(n, d) in &[(30usize, 2usize), (120, 5), (60, 8)] {
                let mut x = random_lhs(n, d, &mut rng);
                let start = min_distance(&x, d);
                let mut last = start;
                for _ in 0..20 {
                    refine_closest_pairs(&mut x, d, 500, &mut rng);
                    let now = min_distance(&x, d);
                    assert!(now >= last, "n={n} d={d}: {now} after {last}");
                    assert!(is_latin(&x, d), "n={n} d={d}: no longer Latin");
                    last = now;
                }
                assert!(last > 1.5 * start, "n={n} d={d}: {start} → {last}");
            }
        }
    }
}
