//! Puts a measurement covariance file (`base::covariance`) into the
//! likelihood's observable blocks.
//!
//! Entries within one observable go into its block; entries between two
//! observables are returned for the joint likelihood (`joint`). Entries of
//! observables not calibrated on are skipped; entries naming a point that is
//! not in the measurements are errors.

use super::block::ObservableBlock;
use super::joint::CrossEntry;
use crate::base::artifacts::Measurement;
use crate::base::covariance::{read_covariance, CovarianceEntry};
use crate::engine::gp::CholeskyWorkspace;
use anyhow::{bail, Result};
use std::collections::HashMap;
use std::path::Path;

pub fn read(path: &Path) -> Result<Vec<CovarianceEntry>> {
    read_covariance(path)
}

fn same_x(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

/// Where each measured point is: per observable, its x values sorted, and
/// for a calibrated observable its block. Lookups are a hash of the name and
/// a binary search of x (within `same_x`'s tolerance), so attaching a
/// covariance file takes time linear in its entries (times a log), not the
/// product of entries and measurements.
struct PointIndex<'a> {
    measured: HashMap<&'a str, Vec<f64>>,
    block_of: HashMap<String, usize>,
}

impl<'a> PointIndex<'a> {
    fn new(blocks: &[ObservableBlock], measurements: &'a [Measurement]) -> Self {
        let mut measured: HashMap<&str, Vec<f64>> = HashMap::new();
        for m in measurements {
            measured.entry(m.observable.as_str()).or_default().push(m.x);
        }
        measured.values_mut().for_each(|xs| xs.sort_by(f64::total_cmp));
        let block_of = blocks.iter().enumerate().map(|(b, block)| (block.name.clone(), b)).collect();
        PointIndex { measured, block_of }
    }

    fn is_measured(&self, observable: &str, x: f64) -> bool {
        self.measured.get(observable).is_some_and(|xs| position_of(xs, x).is_some())
    }
}

/// Index of `x` in `sorted` within `same_x`'s tolerance.
/// An entry that gives a pair a covariance other than an earlier entry did.
fn contradiction(path: &Path, e: &CovarianceEntry, earlier: f64) -> anyhow::Error {
    let problem = format!("{} contradicts the entry for the same pair given earlier ({earlier})", e.covariance);
    e.field_error(path, "covariance", problem)
}

fn position_of(sorted: &[f64], x: f64) -> Option<usize> {
    let i = sorted.partition_point(|&v| v < x);
    [i.checked_sub(1), Some(i)].into_iter().flatten().find(|&k| k < sorted.len() && same_x(sorted[k], x))
}

/// Sets each block's `covariance` from `entries`, and returns the entries
/// between two blocks.
pub fn attach(
    blocks: &mut [ObservableBlock],
    entries: &[CovarianceEntry],
    measurements: &[Measurement],
    path: &Path,
    data_path: &Path,
) -> Result<Vec<CrossEntry>> {
    let xs: Vec<Vec<f64>> = blocks.iter().map(|b| b.x.clone()).collect();
    let index = PointIndex::new(blocks, measurements);
    // Cross entries by their pair (lower point first), for duplicates.
    let mut across: HashMap<(usize, usize, usize, usize), (CrossEntry, usize)> = HashMap::new();
    let mut set: Vec<Vec<bool>> = blocks.iter().map(|b| vec![false; b.len() * b.len()]).collect();
    for (k, e) in entries.iter().enumerate() {
        for (obs, x, field) in [(&e.observable_a, e.x_a, "a"), (&e.observable_b, e.x_b, "b")] {
            if !index.is_measured(obs, x) {
                bail!(
                    "{}, fields 'observable_{field}', 'x_{field}': {} has no measurement of '{obs}' at x = {x}",
                    e.location(path),
                    data_path.display()
                );
            }
        }
        let (Some(&ba), Some(&bb)) = (index.block_of.get(&e.observable_a), index.block_of.get(&e.observable_b)) else {
            continue;
        };
        let at = |b: usize, x: f64| position_of(&xs[b], x).expect("checked against the measurements");
        let (i, j) = (at(ba, e.x_a), at(bb, e.x_b));
        if ba != bb {
            let cross = CrossEntry {
                block_a: ba,
                index_a: i,
                block_b: bb,
                index_b: j,
                covariance: e.covariance,
                rounding: e.rounding,
            };
            let key = if (ba, i) <= (bb, j) { (ba, i, bb, j) } else { (bb, j, ba, i) };
            match across.get(&key) {
                Some((c, _)) if !same_x(c.covariance, e.covariance) => {
                    return Err(contradiction(path, e, c.covariance))
                }
                Some(_) => {}
                None => {
                    across.insert(key, (cross, k));
                }
            }
            continue;
        }
        let block = &mut blocks[ba];
        let n = block.len();
        let c = block.covariance.get_or_insert_with(|| vec![0.0; n * n]);
        if set[ba][j * n + i] && !same_x(c[j * n + i], e.covariance) {
            return Err(contradiction(path, e, c[j * n + i]));
        }
        c[j * n + i] = e.covariance;
        c[i * n + j] = e.covariance;
        set[ba][j * n + i] = true;
        set[ba][i * n + j] = true;
    }
    for block in blocks.iter().filter(|b| !b.diagonal_data()) {
        let mut chol = CholeskyWorkspace::new(block.len());
        chol.factor.fill(0.0);
        block.add_data_covariance(1.0, &mut chol.factor);
        if !chol.factorize_exact() {
            bail!(
                "{}: the covariance of '{}' with its errors² on the diagonal is not positive definite",
                path.display(),
                block.name
            );
        }
    }
    // In the file's order, so the joint covariance is built the same way whatever the hashing.
    let mut across: Vec<(CrossEntry, usize)> = across.into_values().collect();
    across.sort_by_key(|(_, k)| *k);
    let across: Vec<CrossEntry> = across.into_iter().map(|(c, _)| c).collect();
    if !across.is_empty() {
        let whole = super::joint::JointLayout::new(blocks, &across, false);
        let mut chol = CholeskyWorkspace::new(whole.len());
        chol.factor.copy_from_slice(&whole.data);
        if !chol.factorize_exact() {
            // A file written to few digits can be indefinite by its rounding
            // alone once it is large: say so, and what mends it.
            let rounded = across.iter().any(|c| c.rounding > 0.0 && c.rounding > 1e-12 * c.covariance.abs());
            let why = if rounded {
                format!(
                    "; its {} entries between observables are rounded to their printed digits, and at this size that rounding alone can make it so: write the file with more significant digits",
                    across.len()
                )
            } else {
                String::new()
            };
            bail!("{}: the covariance of all observables together, with the errors² on the diagonal, is not positive definite{why}", path.display());
        }
    }
    Ok(across)
}

/// A line model, its measurements and covariance entries, for the tests
/// of this module and of what is computed from its likelihoods.
#[cfg(test)]
pub(crate) mod test_support {
    use super::*;
    use crate::engine::model::Simulator;

    /// η(x, θ) = θ₀ + θ₁ x for observables "a" and "b".
    pub struct Line;
    impl Simulator for Line {
        fn parameter_names(&self) -> Vec<String> {
            vec!["c".into(), "m".into()]
        }
        fn observable_names(&self) -> Vec<String> {
            vec!["a".into(), "b".into()]
        }
        fn predict(&self, _o: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
            for (o, x) in out.iter_mut().zip(x) {
                *o = theta[0] + theta[1] * x;
            }
        }
    }

    pub fn data() -> Vec<Measurement> {
        vec![
            Measurement::new("a", 0.0, 1.1, 0.1),
            Measurement::new("a", 1.0, 1.9, 0.2),
            Measurement::new("b", 0.0, 1.0, 0.1),
            Measurement::new("b", 2.0, 3.2, 0.1),
        ]
    }

    pub fn entry(oa: &str, xa: f64, ob: &str, xb: f64, c: f64, line: usize) -> CovarianceEntry {
        CovarianceEntry {
            observable_a: oa.into(),
            x_a: xa,
            observable_b: ob.into(),
            x_b: xb,
            covariance: c,
            line,
            rounding: 0.0,
        }
    }

    pub fn blocks(m: &[Measurement]) -> Vec<ObservableBlock> {
        ["a", "b"]
            .iter()
            .enumerate()
            .map(|(k, o)| {
                ObservableBlock::new(o, k, &m.iter().filter(|r| r.observable == *o).collect::<Vec<_>>()).unwrap()
            })
            .collect()
    }

    /// The line with a covariance within block a (its 2 × 2 Σ is
    /// [[0.015, 0.012], [0.012, 0.04]]) and an a–b entry that the
    /// independent blocks leave out; block b keeps its errors alone.
    pub fn line_with_a_covariance() -> crate::engine::calibrate::likelihood::MdLikelihood {
        let m = data();
        let mut b = blocks(&m);
        let entries = [
            entry("a", 0.0, "a", 1.0, 0.012, 2),
            entry("a", 0.0, "a", 0.0, 0.005, 3),
            entry("a", 0.0, "b", 0.0, 0.003, 4),
        ];
        attach(&mut b, &entries, &m, Path::new("cov.csv"), Path::new("data.csv")).unwrap();
        crate::engine::calibrate::likelihood::MdLikelihood::new(std::sync::Arc::new(Line), b, None)
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::*;
    use super::*;

    #[test]
    fn the_likelihood_is_the_gaussian_density_with_the_whole_covariance() {
        let lik = line_with_a_covariance();
        let theta = [1.0, 0.95];
        // Closed form: block a is 2×2, Σ = [[0.01 + 0.005, 0.012], [0.012, 0.04]];
        // block b keeps its diagonal errors (the a–b entry is not used).
        let (s11, s12, s22): (f64, f64, f64) = (0.015, 0.012, 0.04);
        let det = s11 * s22 - s12 * s12;
        let (r1, r2) = (1.1 - 1.0, 1.9 - 1.95);
        let quad = (s22 * r1 * r1 - 2.0 * s12 * r1 * r2 + s11 * r2 * r2) / det;
        let ln2pi = (2.0 * std::f64::consts::PI).ln();
        let block_a = -0.5 * (quad + det.ln() + 2.0 * ln2pi);
        let normal = |r: f64, s: f64| -0.5 * ((r / s).powi(2) + 2.0 * s.ln() + ln2pi);
        let block_b = normal(1.0 - 1.0, 0.1) + normal(3.2 - 2.9, 0.1);
        let got = lik.log_likelihood(&theta);
        assert!((got - (block_a + block_b)).abs() < 1e-10, "{got} vs {}", block_a + block_b);
    }

    #[test]
    fn bad_covariance_files_are_refused_naming_the_row() {
        let m = data();
        let cases = [
            (
                vec![entry("a", 0.5, "a", 1.0, 0.01, 7)],
                "cov.csv: line 7, fields 'observable_a', 'x_a': data.csv has no measurement of 'a' at x = 0.5",
            ),
            (
                vec![entry("a", 0.0, "a", 1.0, 0.01, 2), entry("a", 1.0, "a", 0.0, 0.02, 3)],
                "cov.csv: line 3, field 'covariance': 0.02 contradicts",
            ),
            (
                vec![entry("a", 0.0, "a", 1.0, 0.5, 2)],
                "the covariance of 'a' with its errors² on the diagonal is not positive definite",
            ),
        ];
        for (entries, expect) in cases {
            let mut b = blocks(&m);
            let msg =
                format!("{:#}", attach(&mut b, &entries, &m, Path::new("cov.csv"), Path::new("data.csv")).unwrap_err());
            assert!(msg.contains(expect), "{msg}");
        }
        // Both orders of a pair, agreeing, are fine; an unselected observable's entries are skipped.
        let mut b = blocks(&m);
        b.truncate(1);
        attach(
            &mut b,
            &[
                entry("a", 0.0, "a", 1.0, 0.01, 2),
                entry("a", 1.0, "a", 0.0, 0.01, 3),
                entry("b", 0.0, "b", 2.0, 0.001, 4),
            ],
            &m,
            Path::new("cov.csv"),
            Path::new("data.csv"),
        )
        .unwrap();
        assert_eq!(b[0].covariance.as_ref().unwrap()[1], 0.01);
    }

    #[test]
    fn covariance_files_round_trip_through_csv() {
        let dir = std::env::temp_dir().join(format!("mdpipe-cov-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let entries = vec![entry("a", 0.0, "a", 1.0, 0.012, 2), entry("b", 2.0, "a", 0.0, -3.5e-4, 3)];
        crate::base::covariance::write_covariance_csv(&dir.join("c.csv"), &entries).unwrap();
        let mut back = read(&dir.join("c.csv")).unwrap();
        // Read back, each entry knows the digits it was written with.
        assert_eq!(back.iter().map(|e| e.rounding).collect::<Vec<_>>(), [0.5e-3, 0.5e-5]);
        back.iter_mut().for_each(|e| e.rounding = 0.0);
        assert_eq!(back, entries);
        std::fs::write(dir.join("bad.csv"), "observable_a,x_a,observable_b,x_b,covariance\na,0,a,one,0.1\n").unwrap();
        let msg = format!("{:#}", read(&dir.join("bad.csv")).unwrap_err());
        assert!(msg.contains("bad.csv: line 2, field 'x_b': cannot parse \"one\""), "{msg}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
