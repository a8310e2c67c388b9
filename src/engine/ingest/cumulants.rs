//! From per-event pT-differential files to the analysis observables:
//! spectra, and v_n{2}(pT) as two-particle cumulants of per-event Q-vectors
//! with self-correlations removed, with jackknife errors over events.
//!
//! Conventions (written down because they change the numbers):
//! - **Spectra** come from each row's own `dN/(2π pT dpT dy)` column (so
//!   oversampled events, whose count column sums all samples, are normalised
//!   as the producer normalised them). Rows are assigned to analysis bins by
//!   their count-weighted mean pT L_r (bins should be unions of the file's
//!   equal-width bins), and the bin value is `Σ_r ȳ_r L_r / Σ_r L_r`: for
//!   rows printed at bin centres this is exactly the histogram yield
//!   `N_bin / (2π x Δp_T Δy)` at the bin midpoint x.
//! - **v_n{2}(pT)**: the reference is charged hadrons in the charged file's
//!   window with `ref_pt.0 ≤ pT < ref_pt.1`; particles of interest are the
//!   rows whose pT falls in the analysis bin. Per event
//!   `c = |Q|² − M` (weight M(M−1)) and `d = Re(p Q*) − m_q` (weight m M − m_q),
//!   `v_n{2}(bin) = (Σd / Σw_d) / sqrt(Σc / Σw_c)`. `m_q` counts particles
//!   that are both: every charged POI inside the reference range; for an
//!   identified species measured in a y window, the boost-invariant fraction
//!   of its particles that also fall in the charged η window.

use super::layout::{EventFile, FileKind};
use anyhow::{bail, Result};

/// One species' differential file for one event: per row pT, the yield
/// column, the count, and Q_n = count·(Re v_n + i Im v_n) for n = 2, 3.
#[derive(Clone, Debug)]
pub struct BinnedEvent {
    pub pt: Vec<f64>,
    pub yield_: Vec<f64>,
    pub count: Vec<f64>,
    /// q[n-2][row] = (Re, Im)
    pub q: [Vec<(f64, f64)>; 2],
}

/// Reads one differential file into per-row sums. Every problem names the
/// file (or HDF5 dataset), row and column.
pub fn binned_from_file(f: &EventFile) -> Result<BinnedEvent> {
    let origin = &f.origin;
    let c = f.columns;
    // pT, yield, at least (Re, Im) for n = 1..3, count.
    if c < 2 + 2 * 3 + 1 || !(c - 3).is_multiple_of(2) {
        bail!("{origin}: {c} columns; a differential file has pT, dN/(2pi pT dpT dy), (Re, Im) pairs for n = 1..order_max-1 (at least 3), and the count");
    }
    let rows = f.rows();
    let mut b = BinnedEvent {
        pt: Vec::with_capacity(rows),
        yield_: Vec::with_capacity(rows),
        count: Vec::with_capacity(rows),
        q: [Vec::with_capacity(rows), Vec::with_capacity(rows)],
    };
    for i in 0..rows {
        let r = f.row(i);
        for (k, v) in r.iter().enumerate() {
            if !v.is_finite() {
                bail!("{origin}: row {}, column {} ({}): value is {v}", i + 1, k + 1, column_name(k, c));
            }
        }
        let n = r[c - 1];
        if n < 0.0 || n.fract() != 0.0 {
            bail!("{origin}: row {}, column {c} (count): {n} is not a non-negative whole number", i + 1);
        }
        if r[1] < 0.0 {
            bail!("{origin}: row {}, column 2 (dN/(2pi pT dpT dy)): negative yield {}", i + 1, r[1]);
        }
        b.pt.push(r[0]);
        b.yield_.push(r[1]);
        b.count.push(n);
        for (slot, order) in [2usize, 3].iter().enumerate() {
            let re = r[2 + 2 * (order - 1)];
            let im = r[3 + 2 * (order - 1)];
            b.q[slot].push((n * re, n * im));
        }
    }
    Ok(b)
}

fn column_name(k: usize, columns: usize) -> String {
    match k {
        0 => "pT".into(),
        1 => "dN/(2pi pT dpT dy)".into(),
        _ if k == columns - 1 => "count".into(),
        _ => format!("{} v{}", if k.is_multiple_of(2) { "Re" } else { "Im" }, (k - 2) / 2 + 1),
    }
}

/// A species to analyse: its differential file, and how its particles
/// overlap the charged reference.
#[derive(Clone, Debug)]
pub struct Species {
    pub kind: FileKind,
    /// GeV; used for the y → η acceptance of identified particles.
    pub mass: f64,
}

impl Species {
    /// The fraction of this species' particles at `pt` that also lie in the
    /// charged file's window (1 for the charged file itself). Boost
    /// invariance: dN/dy is flat, and η = asinh(mT sinh y / pT).
    pub fn overlap(&self, charged: &FileKind, pt: f64) -> f64 {
        if self.kind == *charged {
            return 1.0;
        }
        if self.kind.window == charged.window {
            let lo = self.kind.lo.max(charged.lo);
            let hi = self.kind.hi.min(charged.hi);
            return ((hi - lo) / (self.kind.hi - self.kind.lo)).max(0.0);
        }
        let mt = (pt * pt + self.mass * self.mass).sqrt();
        let y_of_eta = |eta: f64| ((pt / mt) * f64::sinh(eta)).asinh();
        let (lo, hi) = (self.kind.lo.max(y_of_eta(charged.lo)), self.kind.hi.min(y_of_eta(charged.hi)));
        ((hi - lo) / (self.kind.hi - self.kind.lo)).max(0.0)
    }
}

/// Analysis result for one observable in one bin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    pub value: f64,
    pub error: f64,
}

/// Delete-one-event jackknife of `estimate`, a function of the per-event sums
/// summed over events (so leaving an event out is a subtraction). Returns
/// the estimate, its errors and the leave-one-out replicates (one per event),
/// from which [`jackknife_covariance`] gives the covariance between outputs.
fn jackknife(per_event: &[Vec<f64>], estimate: impl Fn(&[f64]) -> Vec<f64>) -> (Vec<f64>, Vec<f64>, Vec<Vec<f64>>) {
    let n = per_event.len();
    let width = per_event[0].len();
    let mut total = vec![0.0; width];
    for ev in per_event {
        for (t, v) in total.iter_mut().zip(ev) {
            *t += v;
        }
    }
    let full = estimate(&total);
    let mut mean = vec![0.0; full.len()];
    let mut reps = Vec::with_capacity(n);
    let mut leave = vec![0.0; width];
    for ev in per_event {
        for k in 0..width {
            leave[k] = total[k] - ev[k];
        }
        let r = estimate(&leave);
        for (m, v) in mean.iter_mut().zip(&r) {
            *m += v / n as f64;
        }
        reps.push(r);
    }
    let mut var = vec![0.0; full.len()];
    for r in &reps {
        for k in 0..full.len() {
            var[k] += (r[k] - mean[k]).powi(2);
        }
    }
    let scale = (n as f64 - 1.0) / n as f64;
    (full, var.into_iter().map(|v| (scale * v).sqrt()).collect(), reps)
}

/// Jackknife covariance `(n−1)/n Σ_k (r_k − r̄)(r_k − r̄)ᵀ` of replicates
/// `reps` (one vector per left-out event), row-major m × m. Outputs measured
/// on the same events are correlated (a multiplicity fluctuation moves every
/// bin of a spectrum), and this is that correlation.
pub fn jackknife_covariance(reps: &[Vec<f64>]) -> Vec<f64> {
    let n = reps.len();
    let m = reps.first().map_or(0, Vec::len);
    let mut mean = vec![0.0; m];
    for r in reps {
        for (a, v) in mean.iter_mut().zip(r) {
            *a += v / n as f64;
        }
    }
    let mut cov = vec![0.0; m * m];
    for r in reps {
        for i in 0..m {
            let di = r[i] - mean[i];
            for j in 0..=i {
                cov[i * m + j] += di * (r[j] - mean[j]);
            }
        }
    }
    let scale = (n as f64 - 1.0) / n as f64;
    for i in 0..m {
        for j in 0..=i {
            cov[i * m + j] *= scale;
            cov[j * m + i] = cov[i * m + j];
        }
    }
    cov
}

/// The observables of one species in the analysis bins `edges`.
pub struct SpeciesResult {
    pub spectrum: Vec<Estimate>,
    /// v_2{2}, v_3{2}
    pub vn: [Vec<Estimate>; 2],
    /// Leave-one-event-out replicates of [spectrum bins, v2 bins, v3 bins].
    pub replicates: Vec<Vec<f64>>,
}

/// Rows of the file that fall into analysis bin [lo, hi), by the row's pT.
fn rows_in(pt: &[f64], lo: f64, hi: f64) -> Vec<usize> {
    (0..pt.len()).filter(|&i| pt[i] >= lo && pt[i] < hi).collect()
}

/// Each row's location: its count-weighted mean pT over events (rows may
/// print the bin centre or the mean pT of the event's particles).
fn row_locations(events: &[BinnedEvent]) -> Vec<f64> {
    (0..events[0].pt.len())
        .map(|i| {
            let (num, den) = events.iter().fold((0.0, 0.0), |(a, b), e| (a + e.count[i] * e.pt[i], b + e.count[i]));
            if den > 0.0 {
                num / den
            } else {
                events.iter().map(|e| e.pt[i]).sum::<f64>() / events.len() as f64
            }
        })
        .collect()
}

/// Analyses one species against the charged reference over all events.
/// `species` and `reference` hold one [`BinnedEvent`] per event, in the same
/// order; every event must have the same rows.
pub fn analyse(
    species: &Species,
    charged: &FileKind,
    events: &[BinnedEvent],
    reference: &[BinnedEvent],
    edges: &[f64],
    ref_pt: (f64, f64),
) -> Result<SpeciesResult> {
    let n_ev = events.len();
    if n_ev < 2 {
        bail!("need at least 2 events for jackknife errors, have {n_ev}");
    }
    let loc = row_locations(events);
    let mids: Vec<f64> = edges.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
    let nb = mids.len();
    let bins: Vec<Vec<usize>> = edges.windows(2).map(|w| rows_in(&loc, w[0], w[1])).collect();
    for (b, r) in bins.iter().enumerate() {
        if r.is_empty() {
            bail!(
                "analysis bin [{}, {}) GeV holds no row of {}: the analysis bins must be wider than the file's",
                edges[b],
                edges[b + 1],
                species.kind.file_name()
            );
        }
    }
    let ref_loc = row_locations(reference);
    let ref_rows: Vec<usize> =
        (0..ref_loc.len()).filter(|&i| ref_loc[i] >= ref_pt.0 && ref_loc[i] < ref_pt.1).collect();
    let in_ref = |pt: f64| pt >= ref_pt.0 && pt < ref_pt.1;

    // Per-event sums, laid out as: per bin the count; then for n in 2,3:
    // [c, w_c] and per bin [d, w_d].
    let spectra_width = nb;
    let flow_width = 2 + 2 * nb;
    let width = spectra_width + 2 * flow_width;
    let mut per_event = Vec::with_capacity(n_ev);
    for (ev, rf) in events.iter().zip(reference) {
        let mut s = vec![0.0; width];
        for (b, rows_b) in bins.iter().enumerate() {
            s[b] = rows_b.iter().map(|&i| ev.yield_[i] * loc[i]).sum();
        }
        let m_ref: f64 = ref_rows.iter().map(|&i| rf.count[i]).sum();
        for slot in 0..2 {
            let base = spectra_width + slot * flow_width;
            let (qr, qi) = ref_rows.iter().fold((0.0, 0.0), |(a, b), &i| (a + rf.q[slot][i].0, b + rf.q[slot][i].1));
            s[base] = qr * qr + qi * qi - m_ref;
            s[base + 1] = m_ref * (m_ref - 1.0);
            for (b, rows_b) in bins.iter().enumerate() {
                let (mut pr, mut pi, mut m, mut mq) = (0.0, 0.0, 0.0, 0.0);
                for &i in rows_b {
                    pr += ev.q[slot][i].0;
                    pi += ev.q[slot][i].1;
                    m += ev.count[i];
                    if in_ref(loc[i]) {
                        mq += ev.count[i] * species.overlap(charged, loc[i]);
                    }
                }
                s[base + 2 + 2 * b] = pr * qr + pi * qi - mq;
                s[base + 3 + 2 * b] = m * m_ref - mq;
            }
        }
        per_event.push(s);
    }
    let estimate = |sum: &[f64]| -> Vec<f64> {
        let mut out = Vec::with_capacity(3 * nb);
        for (b, rows_b) in bins.iter().enumerate() {
            out.push(sum[b] / (n_ev as f64 * rows_b.iter().map(|&i| loc[i]).sum::<f64>()));
        }
        for slot in 0..2 {
            let base = spectra_width + slot * flow_width;
            let c2 = sum[base] / sum[base + 1];
            let vref = if c2 > 0.0 { c2.sqrt() } else { f64::NAN };
            for b in 0..nb {
                out.push(sum[base + 2 + 2 * b] / sum[base + 3 + 2 * b] / vref);
            }
        }
        out
    };
    let (value, error, replicates) = jackknife(&per_event, estimate);
    // Values or errors are NaN where a bin holds a handful of particles, or
    // where <|Q|² − M> ≤ 0 (v_n{2} undefined); the caller leaves those out.
    let est = |k: usize| Estimate { value: value[k], error: error[k] };
    Ok(SpeciesResult {
        spectrum: (0..nb).map(est).collect(),
        vn: [(nb..2 * nb).map(est).collect(), (2 * nb..3 * nb).map(est).collect()],
        replicates,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_jackknife_covariance_of_means_is_the_sample_covariance_over_n() {
        // For a mean the jackknife is exact: cov = S_ab / n with S the sample
        // covariance (denominator n − 1). Two correlated columns and a count.
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        let n = 50;
        let per_event: Vec<Vec<f64>> = (0..n)
            .map(|_| {
                let common: f64 = rng.random();
                vec![common + 0.3 * rng.random::<f64>(), 2.0 * common - rng.random::<f64>(), 1.0]
            })
            .collect();
        let (_, err, reps) = jackknife(&per_event, |s| vec![s[0] / s[2], s[1] / s[2]]);
        let cov = jackknife_covariance(&reps);
        let mean = |k: usize| per_event.iter().map(|e| e[k]).sum::<f64>() / n as f64;
        let sample = |a: usize, b: usize| {
            per_event.iter().map(|e| (e[a] - mean(a)) * (e[b] - mean(b))).sum::<f64>() / (n as f64 - 1.0)
        };
        for a in 0..2 {
            for b in 0..2 {
                let expect = sample(a, b) / n as f64;
                assert!(
                    (cov[a * 2 + b] - expect).abs() < 1e-12 * expect.abs().max(1e-6),
                    "cov[{a},{b}] = {} vs {expect}",
                    cov[a * 2 + b]
                );
            }
            assert!((cov[a * 2 + a].sqrt() - err[a]).abs() < 1e-12);
        }
    }
}
