//! Event-by-event sampling for the stand-in, written in iEBE-MUSIC's layout so
//! that `mdpipe ingest` reads it exactly as it reads real runs.
//!
//! Per event: a multiplicity factor λ ~ Gamma(mean 1, sd 0.1) (centrality-bin
//! width); eccentricity vectors ε_2 = ε_RP + Gaussian (σ = 0.10 per
//! component, ε_RP = 0.265) and ε_3 Gaussian (σ = 0.141), so that their rms
//! values are the smooth model's ε_2 = 0.30, ε_3 = 0.20. Flow responds linearly:
//! `v_n(pT) = v_n^smooth(pT) |ε_n| / ε_n,rms` about the event plane arg(ε_n)/n,
//! so v_n{2} of many events is the smooth v_n. Particles of π±, K±, p, p̄
//! are drawn per 0.1 GeV pT bin (Poisson), with pT inside the bin from the
//! local exponential slope, y uniform in |y| < 0.5, and φ by rejection.
//! Like iEBE-MUSIC's Cooper–Frye sampler, each event (one fluid evolution) is
//! sampled `oversample` times: the count and v_n columns sum every sample
//! (so Q-vectors have the statistics of all of them), while the yield
//! columns are per sample. Since only the sums are written, a bin's count
//! over all samples is drawn at once: `oversample` independent
//! Poisson(μ) counts sum to one Poisson(`oversample`·μ), and the particles
//! are independent given the event, so the written tables have the same law.

use super::{yield_and_flow, DeltaF, FreezeOut, HeavyIonParams, Quadrature, Species, ECCENTRICITY, SPECIES};
use crate::engine::ingest::layout::{Event, EventFile, FileKind, Window, CHARGED_PID};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Gamma, Normal, Poisson};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

/// Default samples per event: enough that v_3{2} is measurable from 100
/// events at dN_ch/dη ≈ 150.
pub const DEFAULT_OVERSAMPLE: usize = 50;
/// Fine pT bins of the written files: 0–3 GeV in steps of 0.1 GeV.
pub const FINE_PT_WIDTH: f64 = 0.1;
pub const FINE_PT_BINS: usize = 30;
/// Half-width of the |y| and |η| windows.
pub const WINDOW: f64 = 0.5;
const ORDER_MAX_CHARGED: usize = 10;
const ORDER_MAX_IDENTIFIED: usize = 6;
const MULTIPLICITY_SD: f64 = 0.10;
const EPS2_FLUCTUATION: f64 = 0.10;

/// The smooth model at two Gauss–Legendre nodes per fine bin, per species.
#[derive(Clone, Debug)]
pub struct SpeciesTable {
    pub species: Species,
    /// Per fine bin, per node: (pT, weight, dN/dpT per unit y (one charge), v2, v3).
    pub nodes: Vec<[(f64, f64, f64, f64, f64); 2]>,
}

/// What the sampler draws from at one parameter point.
#[derive(Clone, Debug)]
pub struct SmoothTables {
    pub species: Vec<SpeciesTable>,
}

impl SmoothTables {
    pub fn new(p: &HeavyIonParams, delta_f: DeltaF) -> SmoothTables {
        let fo = FreezeOut::new(p);
        let q = Quadrature::default();
        let g = 0.5 / 3f64.sqrt();
        let species = SPECIES
            .iter()
            .map(|s| {
                let nodes = (0..FINE_PT_BINS)
                    .into_par_iter()
                    .map(|b| {
                        let c = (b as f64 + 0.5) * FINE_PT_WIDTH;
                        [c - g * FINE_PT_WIDTH, c + g * FINE_PT_WIDTH].map(|pt| {
                            let yf = yield_and_flow(&fo, s, pt, delta_f, &q);
                            (pt, 0.5 * FINE_PT_WIDTH, 2.0 * std::f64::consts::PI * pt * yf.yield_, yf.v2, yf.v3)
                        })
                    })
                    .collect();
                SpeciesTable { species: *s, nodes }
            })
            .collect();
        SmoothTables { species }
    }

    /// Expected observables in the analysis bins `edges` for infinitely many
    /// events, with the same definitions as `mdpipe ingest` (histogram
    /// spectra at bin midpoints, count-weighted v_n{2}), for round-trip tests.
    pub fn expected(&self, edges: &[f64]) -> Vec<(String, Vec<f64>)> {
        let mut out = Vec::new();
        for (tag, pid) in [("ch", CHARGED_PID), ("pi", 211), ("p", 2212)] {
            let (mut spec, mut v2, mut v3) = (Vec::new(), Vec::new(), Vec::new());
            for w in edges.windows(2) {
                let (mut n, mut n2, mut n3) = (0.0, 0.0, 0.0);
                for t in self.species.iter().filter(|t| pid == CHARGED_PID || t.species.pid == pid) {
                    let m = t.species.mass;
                    let charges = if pid == CHARGED_PID { 2.0 } else { 1.0 };
                    for (b, nodes) in t.nodes.iter().enumerate() {
                        let c = (b as f64 + 0.5) * FINE_PT_WIDTH;
                        if c < w[0] || c >= w[1] {
                            continue;
                        }
                        for &(pt, wt, d, a2, a3) in nodes {
                            let acc = if pid == CHARGED_PID { eta_acceptance(pt, m) } else { 1.0 };
                            let k = charges * wt * d * acc * 2.0 * WINDOW;
                            n += k;
                            n2 += k * a2;
                            n3 += k * a3;
                        }
                    }
                }
                let x = 0.5 * (w[0] + w[1]);
                spec.push(n / (2.0 * std::f64::consts::PI * x * (w[1] - w[0]) * 2.0 * WINDOW));
                v2.push(n2 / n);
                v3.push(n3 / n);
            }
            out.push((format!("{tag}_spectrum"), spec));
            out.push((format!("{tag}_v2"), v2));
            if tag == "ch" {
                out.push((format!("{tag}_v3"), v3));
            }
        }
        out
    }
}

/// Fraction of particles uniform in |y| < WINDOW that have |η| < WINDOW.
fn eta_acceptance(pt: f64, m: f64) -> f64 {
    let mt = (pt * pt + m * m).sqrt();
    ((pt / mt) * WINDOW.sinh()).asinh() / WINDOW
}

/// Per-file accumulators for one event: per fine bin count, Σ pT and Σ e^{inφ}.
struct Accumulator {
    orders: usize,
    count: Vec<f64>,
    sum_pt: Vec<f64>,
    /// [bin][n-1] = (Σ cos nφ, Σ sin nφ)
    q: Vec<Vec<(f64, f64)>>,
}

impl Accumulator {
    fn new(order_max: usize) -> Accumulator {
        let orders = order_max - 1;
        Accumulator {
            orders,
            count: vec![0.0; FINE_PT_BINS],
            sum_pt: vec![0.0; FINE_PT_BINS],
            q: vec![vec![(0.0, 0.0); orders]; FINE_PT_BINS],
        }
    }

    /// Adds one particle whose e^{inφ} for n = 1, 2, … are `harmonics`
    /// (this accumulator reads the first `orders`).
    fn add(&mut self, bin: usize, pt: f64, harmonics: &Harmonics) {
        self.count[bin] += 1.0;
        self.sum_pt[bin] += pt;
        for (slot, &(c, s)) in self.q[bin].iter_mut().zip(&harmonics.0) {
            slot.0 += c;
            slot.1 += s;
        }
    }

    /// The compact differential table: pT, dN/(2π pT dpT dy), (Re, Im) v_n, N.
    fn diff_file(&self, kind: &FileKind, oversample: usize) -> EventFile {
        let dy = kind.hi - kind.lo;
        let columns = 2 + 2 * self.orders + 1;
        let mut values = Vec::with_capacity(FINE_PT_BINS * columns);
        for b in 0..FINE_PT_BINS {
            let centre = (b as f64 + 0.5) * FINE_PT_WIDTH;
            let n = self.count[b];
            values.push(centre);
            values.push(n / (oversample as f64 * 2.0 * std::f64::consts::PI * centre * FINE_PT_WIDTH * dy));
            for &(c, s) in &self.q[b] {
                values.push(if n > 0.0 { c / n } else { 0.0 });
                values.push(if n > 0.0 { s / n } else { 0.0 });
            }
            values.push(n);
        }
        let vn: Vec<String> = (1..=self.orders).map(|k| format!("Re{{v{k}}}  Im{{v{k}}}")).collect();
        let header = format!("# pT(GeV)  dN/(2pi dy pT dpT)(GeV^-2, pT = bin centre)  {}  dN", vn.join("  "));
        EventFile { name: kind.file_name(), header, columns, values, origin: String::new() }
    }

    /// The integrated table: `0, dN/dy, err, <pT>, err`; `n, Re v_n, err, Im v_n, err`;
    /// `99, N, samples, 0, 0`.
    fn integrated_file(&self, kind: &FileKind, sum_pt2: f64, oversample: usize) -> EventFile {
        let dy = kind.hi - kind.lo;
        let n: f64 = self.count.iter().sum();
        let mean_pt = if n > 0.0 { self.sum_pt.iter().sum::<f64>() / n } else { 0.0 };
        let sd_pt = if n > 1.0 { (sum_pt2 / n - mean_pt * mean_pt).max(0.0).sqrt() } else { 0.0 };
        let err_n = if n > 0.0 { (0.5 / n).sqrt() } else { 0.0 };
        let k_os = oversample as f64;
        let mut values =
            vec![0.0, n / (k_os * dy), n.sqrt() / (k_os * dy), mean_pt, if n > 0.0 { sd_pt / n.sqrt() } else { 0.0 }];
        for k in 0..self.orders {
            let (c, s) = self.q.iter().fold((0.0, 0.0), |(a, b), q| (a + q[k].0, b + q[k].1));
            let (c, s) = if n > 0.0 { (c / n, s / n) } else { (0.0, 0.0) };
            values.extend([(k + 1) as f64, c, err_n, s, err_n]);
        }
        values.extend([99.0, n, k_os, 0.0, 0.0]);
        let integrated = FileKind { differential: false, ..kind.clone() };
        EventFile {
            name: integrated.file_name(),
            header: "# n  vn_real  vn_real_err  vn_imag  vn_imag_err".into(),
            columns: 5,
            values,
            origin: String::new(),
        }
    }
}

/// Draws pT in one fine bin [lo, lo + w) from the exponential through the
/// bin's two nodes. The slope and its exponential are the bin's, worked out
/// once rather than once per particle (a log and an exp of the few each
/// particle costs), with the same arithmetic.
struct PtSampler {
    lo: f64,
    /// None: uniform in the bin (a node without density, or a flat bin).
    slope: Option<(f64, f64)>,
}

impl PtSampler {
    fn new(lo: f64, nodes: &[(f64, f64, f64, f64, f64); 2]) -> PtSampler {
        let (p1, d1, p2, d2) = (nodes[0].0, nodes[0].2, nodes[1].0, nodes[1].2);
        if d1 <= 0.0 || d2 <= 0.0 {
            return PtSampler { lo, slope: None };
        }
        let slope = (d2 / d1).ln() / (p2 - p1);
        let steep = slope.abs() * FINE_PT_WIDTH >= 1e-9;
        PtSampler { lo, slope: steep.then(|| (slope, (slope * FINE_PT_WIDTH).exp() - 1.0)) }
    }

    fn sample(&self, rng: &mut impl Rng) -> f64 {
        let u: f64 = rng.random();
        match self.slope {
            None => self.lo + u * FINE_PT_WIDTH,
            Some((slope, span)) => self.lo + (1.0 + u * span).ln() / slope,
        }
    }
}

fn interpolate(
    nodes: &[(f64, f64, f64, f64, f64); 2],
    pt: f64,
    pick: impl Fn(&(f64, f64, f64, f64, f64)) -> f64,
) -> f64 {
    let t = (pt - nodes[0].0) / (nodes[1].0 - nodes[0].0);
    pick(&nodes[0]) * (1.0 - t) + pick(&nodes[1]) * t
}

/// e^{inφ} of one particle for n = 1 … ORDER_MAX_CHARGED − 1, by rotation
/// from e^{iφ}; worked out once and added to both the identified and the
/// charged tables.
struct Harmonics([(f64, f64); ORDER_MAX_CHARGED - 1]);

impl Harmonics {
    /// From e^{iφ} = (c1, s1).
    fn of_direction(c1: f64, s1: f64) -> Harmonics {
        let mut h = [(0.0, 0.0); ORDER_MAX_CHARGED - 1];
        let (mut c, mut s) = (c1, s1);
        for slot in h.iter_mut() {
            *slot = (c, s);
            (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
        }
        Harmonics(h)
    }
}

/// One event's flow geometry: v_n scale factors |ε_n| / ε_n,rms and the
/// event planes as (cos nψ_n, sin nψ_n) for n = 2, 3.
struct Geometry {
    scale: [f64; 2],
    planes: [(f64, f64); 2],
}

/// A uniform direction e^{iφ} by the polar method: a point uniform in the
/// unit disc, scaled to the circle (one square root instead of a sin_cos).
fn draw_direction(rng: &mut impl Rng) -> (f64, f64) {
    loop {
        let (x, y) = (rng.random::<f64>() * 2.0 - 1.0, rng.random::<f64>() * 2.0 - 1.0);
        let r2 = x * x + y * y;
        if r2 > 1e-300 && r2 <= 1.0 {
            let r = r2.sqrt();
            return (x / r, y / r);
        }
    }
}

/// e^{inφ} of a φ drawn from `1 + 2 v2 cos 2(φ − ψ2) + 2 v3 cos 3(φ − ψ3)`
/// by rejection under `1 + 2(|v2| + |v3|)`. A draw below the density's
/// floor `1 − 2(|v2| + |v3|)` is accepted without evaluating it (a
/// squeeze); otherwise cos n(φ − ψ_n) = Re(e^{inφ} e^{−inψ_n}) from the
/// harmonics the accepted particle needs anyway, so no trigonometric call.
fn draw_harmonics(rng: &mut impl Rng, v2: f64, v3: f64, planes: &[(f64, f64); 2]) -> Harmonics {
    let reach = 2.0 * (v2.abs() + v3.abs());
    let bound = 1.0 + reach;
    let sure = 1.0 - reach;
    loop {
        let (c, s) = draw_direction(rng);
        let harmonics = Harmonics::of_direction(c, s);
        let u = rng.random::<f64>() * bound;
        if u < sure {
            return harmonics;
        }
        let [_, (c2, s2), (c3, s3), ..] = harmonics.0;
        let density =
            1.0 + 2.0 * v2 * (c2 * planes[0].0 + s2 * planes[0].1) + 2.0 * v3 * (c3 * planes[1].0 + s3 * planes[1].1);
        if u < density {
            return harmonics;
        }
    }
}

/// Whether a particle uniform in |y| < WINDOW falls in |η| < WINDOW: a
/// Bernoulli draw with the acceptance at its pT (y is used for nothing
/// else). Over one fine bin the acceptance rises with pT, so a uniform draw
/// below the bin's lowest acceptance or above its highest decides without
/// the asinh.
#[derive(Clone, Copy)]
struct EtaWindow {
    mass: f64,
    low: f64,
    high: f64,
}

impl EtaWindow {
    fn new(lo: f64, mass: f64) -> EtaWindow {
        EtaWindow { mass, low: eta_acceptance(lo, mass), high: eta_acceptance(lo + FINE_PT_WIDTH, mass) }
    }

    fn admits(&self, u: f64, pt: f64) -> bool {
        if u < self.low {
            true
        } else if u >= self.high {
            false
        } else {
            u < eta_acceptance(pt, self.mass)
        }
    }
}

/// One event (`oversample` samples of one fluid evolution), reproducible
/// from (seed, index).
pub fn sample_event(tables: &SmoothTables, seed: u64, index: usize, oversample: usize) -> Event {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ (index as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let shape = 1.0 / (MULTIPLICITY_SD * MULTIPLICITY_SD);
    let lambda = Gamma::new(shape, 1.0 / shape).expect("valid gamma").sample(&mut rng);
    let geometry = draw_geometry(&mut rng);
    let charged_kind = FileKind::diff(CHARGED_PID, Window::Eta, -WINDOW, WINDOW);
    let mut charged = Accumulator::new(ORDER_MAX_CHARGED);
    let mut charged_pt2 = 0.0;
    let mut files = Vec::new();
    for table in &tables.species {
        let kind = FileKind::diff(table.species.pid, Window::Y, -WINDOW, WINDOW);
        let mut identified = Accumulator::new(ORDER_MAX_IDENTIFIED);
        let mut identified_pt2 = 0.0;
        let bins = species_bins(table, lambda, oversample);
        // Particles, then antiparticles, of all `oversample` samples of this event.
        for sign in [1, -1] {
            for (b, (nodes, bin)) in table.nodes.iter().zip(&bins).enumerate() {
                let Some(count) = &bin.count else { continue };
                for _ in 0..count.sample(&mut rng) as usize {
                    let pt = bin.pt.sample(&mut rng);
                    let in_eta = bin.eta.admits(rng.random(), pt);
                    if sign == -1 && !in_eta {
                        continue;
                    }
                    let v2 = geometry.scale[0] * interpolate(nodes, pt, |n| n.3);
                    let v3 = geometry.scale[1] * interpolate(nodes, pt, |n| n.4);
                    let harmonics = draw_harmonics(&mut rng, v2, v3, &geometry.planes);
                    if sign == 1 {
                        identified.add(b, pt, &harmonics);
                        identified_pt2 += pt * pt;
                    }
                    if in_eta {
                        charged.add(b, pt, &harmonics);
                        charged_pt2 += pt * pt;
                    }
                }
            }
        }
        files.push(identified.diff_file(&kind, oversample));
        files.push(identified.integrated_file(&kind, identified_pt2, oversample));
    }
    files.push(charged.diff_file(&charged_kind, oversample));
    files.push(charged.integrated_file(&charged_kind, charged_pt2, oversample));
    files.sort_by(|a, b| a.name.cmp(&b.name));
    Event { label: format!("spvn_results_{index}"), files }
}

/// The event's eccentricities, as v_n scales and event-plane angles.
fn draw_geometry(rng: &mut impl Rng) -> Geometry {
    let eps_rp = (ECCENTRICITY[0].powi(2) - 2.0 * EPS2_FLUCTUATION.powi(2)).sqrt();
    let sigma3 = ECCENTRICITY[1] / 2f64.sqrt();
    let normal = Normal::new(0.0, 1.0).expect("valid normal");
    let psi_rp = rng.random::<f64>() * std::f64::consts::TAU;
    let (ex, ey) = (eps_rp + EPS2_FLUCTUATION * normal.sample(rng), EPS2_FLUCTUATION * normal.sample(rng));
    let (e3x, e3y) = (sigma3 * normal.sample(rng), sigma3 * normal.sample(rng));
    let psi = [ey.atan2(ex) / 2.0 + psi_rp, e3y.atan2(e3x) / 3.0 + psi_rp];
    let plane = |angle: f64| (angle.cos(), angle.sin());
    Geometry {
        scale: [ex.hypot(ey) / ECCENTRICITY[0], e3x.hypot(e3y) / ECCENTRICITY[1]],
        planes: [plane(2.0 * psi[0]), plane(3.0 * psi[1])],
    }
}

/// One fine bin of one species in one event.
struct Bin {
    /// The law of its count over all samples (None when it holds no particles).
    count: Option<Poisson<f64>>,
    pt: PtSampler,
    eta: EtaWindow,
}

/// The species' fine bins in one event, made once per event.
fn species_bins(table: &SpeciesTable, lambda: f64, oversample: usize) -> Vec<Bin> {
    table
        .nodes
        .iter()
        .enumerate()
        .map(|(b, nodes)| {
            let weight = nodes.iter().map(|n| n.1 * n.2).sum::<f64>();
            let mean = oversample as f64 * lambda * 2.0 * WINDOW * weight;
            let lo = b as f64 * FINE_PT_WIDTH;
            Bin {
                count: (mean > 0.0).then(|| Poisson::new(mean).expect("positive mean")),
                pt: PtSampler::new(lo, nodes),
                eta: EtaWindow::new(lo, table.species.mass),
            }
        })
        .collect()
}

/// `n` events at one parameter point (in parallel; reproducible from `seed`).
pub fn sample_events(tables: &SmoothTables, n: usize, oversample: usize, seed: u64) -> Vec<Event> {
    (0..n).into_par_iter().map(|i| sample_event(tables, seed, i, oversample)).collect()
}

/// How a run is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    Text,
    Hdf5,
    Both,
}

impl std::str::FromStr for Layout {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> anyhow::Result<Self> {
        match s {
            "text" => Ok(Layout::Text),
            "hdf5" => Ok(Layout::Hdf5),
            "both" => Ok(Layout::Both),
            _ => anyhow::bail!("unknown layout '{s}' (use text, hdf5 or both)"),
        }
    }
}

/// Writes one design point's events into `dir`: per-event text folders
/// and/or the combined `spvn_results.h5`. They are written into a hidden
/// staging sibling that is renamed into place when complete, and an existing
/// `dir` is refused: a rerun must never mix its events with an earlier run's.
pub fn write_point(dir: &std::path::Path, events: &[Event], layout: Layout) -> anyhow::Result<()> {
    use anyhow::Context;
    // An empty folder is the one `mdpipe run` made for this attempt; rename replaces it.
    if dir.exists() && std::fs::read_dir(dir).map_or(true, |mut d| d.next().is_some()) {
        anyhow::bail!(
            "{} already exists: remove it to rerun this point (its old events would mix with the new ones)",
            dir.display()
        );
    }
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let staging = dir.with_file_name(format!(".{name}.partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&staging);
    std::fs::create_dir_all(&staging).with_context(|| format!("creating {}", staging.display()))?;
    if layout != Layout::Hdf5 {
        for ev in events {
            crate::engine::ingest::layout::write_text_event(&staging, ev)?;
        }
    }
    if layout != Layout::Text {
        crate::engine::ingest::hdf5::write_events(&staging.join("spvn_results.h5"), events)?;
    }
    std::fs::rename(&staging, dir).with_context(|| format!("moving {} to {}", staging.display(), dir.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// φ drawn about given event planes has ⟨cos n(φ − ψ_n)⟩ = v_n for
    /// n = 2, 3, no other harmonic, and no sine about the planes: the
    /// orientation, which v_n{2} (a correlation of pairs) cannot check.
    /// Tolerance: 5 standard errors of a mean of cosines (sd ≤ 1/√2).
    #[test]
    fn flow_harmonics_are_drawn_about_their_event_planes() {
        let (v2, v3, psi) = (0.15, 0.08, [0.7f64, -1.9f64]);
        let planes = [((2.0 * psi[0]).cos(), (2.0 * psi[0]).sin()), ((3.0 * psi[1]).cos(), (3.0 * psi[1]).sin())];
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let n = 400_000;
        let mut sums = [0.0; 5];
        for _ in 0..n {
            let h = draw_harmonics(&mut rng, v2, v3, &planes).0;
            let about = |k: usize, (c, s): (f64, f64)| (h[k].0 * c + h[k].1 * s, h[k].1 * c - h[k].0 * s);
            let (c2, s2) = about(1, planes[0]);
            let (c3, s3) = about(2, planes[1]);
            for (sum, v) in sums.iter_mut().zip([c2, s2, c3, s3, h[0].0]) {
                *sum += v;
            }
        }
        let tolerance = 5.0 * (0.5 / n as f64).sqrt();
        let wanted = [("cos2", v2), ("sin2", 0.0), ("cos3", v3), ("sin3", 0.0), ("cos1", 0.0)];
        for (sum, (what, want)) in sums.iter().zip(wanted) {
            let mean = sum / n as f64;
            assert!((mean - want).abs() < tolerance, "<{what}> = {mean}, want {want} ± {tolerance}");
        }
    }

    /// The |η| window admits a particle with the acceptance at its pT, the
    /// fraction of |y| < WINDOW inside |η| < WINDOW, whichever branch
    /// decides (5 binomial standard errors).
    #[test]
    fn the_eta_window_admits_at_the_acceptance() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        for (lo, mass) in [(0.0, 0.13957), (0.3, 0.938272), (2.0, 0.493677)] {
            let window = EtaWindow::new(lo, mass);
            let pt = lo + 0.37 * FINE_PT_WIDTH;
            let n = 200_000;
            let admitted = (0..n).filter(|_| window.admits(rng.random(), pt)).count() as f64 / n as f64;
            let p = eta_acceptance(pt, mass);
            let tolerance = 5.0 * (p * (1.0 - p) / n as f64).sqrt();
            assert!((admitted - p).abs() < tolerance, "pT {pt}, m {mass}: {admitted} against {p} ± {tolerance}");
        }
    }
}
