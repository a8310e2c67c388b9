//! A Gaussian mixture fitted to the particle cloud by expectation–
//! maximisation: the proposal of the independent Metropolis–Hastings moves
//! (South, Pettitt & Drovandi 2019, "Sequential Monte Carlo samplers with
//! independent Markov chain Monte Carlo proposals").
//!
//! Random-walk moves with one covariance for the whole cloud crawl along a
//! thin curved ridge (parameters that trade against each other, as a
//! misfitting model's do), and the mass that resampling put unevenly along it
//! stays where it is. A proposal shaped like the whole cloud jumps along the
//! ridge in one move, and its Metropolis–Hastings ratio evens that mass out.
//!
//! The fit is made in coordinates whitened by the cloud's own mean and
//! covariance, where every scale is one, so that one regularisation suits
//! every problem. A fixed wide component, the cloud's Gaussian itself, keeps
//! the proposal from vanishing where the mixture's components miss (a
//! defensive mixture), so that a particle stranded there is not stuck by a
//! tiny q(u) in its acceptance ratio.

use super::*;

/// Weight of the cloud's own Gaussian in the proposal.
const DEFENSIVE_WEIGHT: f64 = 0.1;
/// Added to each component's covariance, in whitened units: a floor on its
/// width that resampled copies of one particle cannot collapse.
const REGULARISATION: f64 = 1e-3;
/// Particles per free parameter of a component: fewer components for more
/// dimensions, as a component's covariance grows with the square of them.
const PARTICLES_PER_PARAMETER: usize = 4;
const MAX_COMPONENTS: usize = 8;
/// A proposal needs the cloud's shape, not the likelihood's optimum: EM stops
/// after this many rounds, or once a round raises the mean log-density per
/// particle by less than `EM_TOLERANCE`.
const EM_ITERATIONS: usize = 25;
const EM_TOLERANCE: f64 = 1e-3;

struct Component {
    /// log weight − log det factor − (dim/2) ln 2π.
    log_norm: f64,
    weight: f64,
    /// Mean and lower Cholesky factor (column-major), whitened coordinates.
    mean: Vec<f64>,
    factor: Vec<f64>,
}

pub(super) struct Mixture {
    dim: usize,
    /// The cloud's mean and the lower Cholesky factor of its covariance.
    centre: Vec<f64>,
    whiten: Vec<f64>,
    log_det_whiten: f64,
    components: Vec<Component>,
}

/// Rows the mixture is fitted to at most (a random subset of a larger cloud):
/// EM's cost is proportional to rows × components × dim².
const MAX_ROWS: usize = 1000;

/// How many components a cloud of `n` particles in `dim` dimensions supports.
fn component_count(n: usize, dim: usize) -> usize {
    let parameters = 1 + dim + dim * (dim + 1) / 2;
    (n / (PARTICLES_PER_PARAMETER * parameters)).clamp(1, MAX_COMPONENTS)
}

/// Solves L y = b in place for a lower, column-major L of size `dim`.
fn forward_substitute(l: &[f64], b: &mut [f64], dim: usize) {
    for j in 0..dim {
        b[j] /= l[j + j * dim];
        let bj = b[j];
        for i in j + 1..dim {
            b[i] -= l[i + j * dim] * bj;
        }
    }
}

/// Lower Cholesky factor of the lower triangle in `cov`, or `None`.
fn cholesky(cov: &[f64], dim: usize) -> Option<Vec<f64>> {
    let mut ws = CholeskyWorkspace::new(dim);
    ws.factor.copy_from_slice(cov);
    if !ws.factorize_exact() {
        return None;
    }
    for j in 0..dim {
        for i in 0..j {
            ws.factor[i + j * dim] = 0.0;
        }
    }
    Some(ws.factor)
}

fn log_det(factor: &[f64], dim: usize) -> f64 {
    (0..dim).map(|i| factor[i + i * dim].ln()).sum()
}

impl Component {
    fn new(weight: f64, mean: Vec<f64>, factor: Vec<f64>, dim: usize) -> Component {
        let log_norm = weight.ln() - log_det(&factor, dim) - 0.5 * dim as f64 * (2.0 * std::f64::consts::PI).ln();
        Component { log_norm, weight, mean, factor }
    }

    /// log(weight × density) at whitened `z`; `r` is scratch of length dim.
    fn log_weighted_density(&self, z: &[f64], r: &mut [f64], dim: usize) -> f64 {
        for k in 0..dim {
            r[k] = z[k] - self.mean[k];
        }
        forward_substitute(&self.factor, r, dim);
        self.log_norm - 0.5 * r.iter().map(|v| v * v).sum::<f64>()
    }
}

impl Mixture {
    /// The mixture fitted to the rows of `x` (`dim` columns); `None` when the
    /// cloud has no spread to whiten by (every particle a copy of one).
    pub(super) fn fit(x: &[f64], dim: usize, rng: &mut Xoshiro256PlusPlus) -> Option<Mixture> {
        let n = x.len() / dim;
        let mut z: Vec<f64> = if n > MAX_ROWS {
            let mut rows = rand::seq::index::sample(rng, n, MAX_ROWS).into_vec();
            rows.sort_unstable();
            rows.iter().flat_map(|&i| &x[i * dim..(i + 1) * dim]).copied().collect()
        } else {
            x.to_vec()
        };
        let rows = z.len() / dim;
        let (centre, cov) = mean_and_covariance(&z, dim, &vec![1.0; rows]);
        let whiten = cholesky(&cov, dim)?;
        for row in z.chunks_mut(dim) {
            for k in 0..dim {
                row[k] -= centre[k];
            }
            forward_substitute(&whiten, row, dim);
        }
        let mut fitted = expectation_maximisation(&z, dim, component_count(rows, dim), rng);
        for c in fitted.iter_mut() {
            *c = Component::new(
                (1.0 - DEFENSIVE_WEIGHT) * c.weight,
                std::mem::take(&mut c.mean),
                std::mem::take(&mut c.factor),
                dim,
            );
        }
        fitted.push(Component::new(DEFENSIVE_WEIGHT, vec![0.0; dim], identity(dim), dim));
        let log_det_whiten = log_det(&whiten, dim);
        Some(Mixture { dim, centre, whiten, log_det_whiten, components: fitted })
    }

    /// The proposal's log density at `u`; `scratch` holds 2 × dim.
    pub(super) fn log_density(&self, u: &[f64], scratch: &mut [f64]) -> f64 {
        let dim = self.dim;
        let (z, r) = scratch.split_at_mut(dim);
        for k in 0..dim {
            z[k] = u[k] - self.centre[k];
        }
        forward_substitute(&self.whiten, z, dim);
        let mut best = f64::NEG_INFINITY;
        let mut sum = 0.0;
        for c in &self.components {
            let l = c.log_weighted_density(z, r, dim);
            // Running log-sum-exp, without a buffer.
            if l == f64::NEG_INFINITY {
                continue;
            } else if l > best {
                sum = sum * (best - l).exp() + 1.0;
                best = l;
            } else {
                sum += (l - best).exp();
            }
        }
        best + sum.ln() - self.log_det_whiten
    }

    /// One draw into `u`; `scratch` holds 2 × dim.
    pub(super) fn sample(&self, rng: &mut Xoshiro256PlusPlus, u: &mut [f64], scratch: &mut [f64]) {
        let dim = self.dim;
        let mut pick: f64 = rng.random();
        let last = self.components.len() - 1;
        let c = self
            .components
            .iter()
            .position(|c| {
                pick -= c.weight;
                pick < 0.0
            })
            .map_or(&self.components[last], |i| &self.components[i]);
        let (e, z) = scratch.split_at_mut(dim);
        for v in e.iter_mut() {
            *v = rng.sample(StandardNormal);
        }
        lower_times(&c.factor, e, z, dim);
        for k in 0..dim {
            z[k] += c.mean[k];
        }
        lower_times(&self.whiten, z, u, dim);
        for k in 0..dim {
            u[k] += self.centre[k];
        }
    }
}

/// out = L v for a lower, column-major L.
fn lower_times(l: &[f64], v: &[f64], out: &mut [f64], dim: usize) {
    for i in 0..dim {
        out[i] = (0..=i).map(|j| l[i + j * dim] * v[j]).sum();
    }
}

fn identity(dim: usize) -> Vec<f64> {
    let mut m = vec![0.0; dim * dim];
    for k in 0..dim {
        m[k + k * dim] = 1.0;
    }
    m
}

/// Weighted mean and covariance (lower triangle, column-major) of the rows.
/// Rows of negligible weight (a responsibility below `NEGLIGIBLE`) are
/// skipped: they would change a proposal's shape by less than that.
fn mean_and_covariance(x: &[f64], dim: usize, w: &[f64]) -> (Vec<f64>, Vec<f64>) {
    const NEGLIGIBLE: f64 = 1e-8;
    let total: f64 = w.iter().sum();
    let mut mean = vec![0.0; dim];
    for (row, &wi) in x.chunks(dim).zip(w).filter(|(_, &wi)| wi >= NEGLIGIBLE) {
        for k in 0..dim {
            mean[k] += wi * row[k];
        }
    }
    mean.iter_mut().for_each(|m| *m /= total);
    let mut cov = vec![0.0; dim * dim];
    for (row, &wi) in x.chunks(dim).zip(w).filter(|(_, &wi)| wi >= NEGLIGIBLE) {
        for j in 0..dim {
            let dj = wi * (row[j] - mean[j]);
            for i in j..dim {
                cov[i + j * dim] += (row[i] - mean[i]) * dj;
            }
        }
    }
    cov.iter_mut().for_each(|c| *c /= total);
    (mean, cov)
}

/// The components fitted to whitened rows `z`, started from k-means++ seeds
/// (Arthur & Vassilvitskii 2007) with each row given to its nearest seed.
/// A component left with too little weight to estimate its covariance is
/// dropped; the fit stops when the mean log-likelihood stops rising.
fn expectation_maximisation(z: &[f64], dim: usize, k: usize, rng: &mut Xoshiro256PlusPlus) -> Vec<Component> {
    let n = z.len() / dim;
    let seeds = kmeans_plus_plus(z, dim, k, rng);
    let mut resp = vec![0.0; n * seeds.len()];
    for (i, row) in z.chunks(dim).enumerate() {
        let nearest = (0..seeds.len())
            .min_by(|&a, &b| {
                squared_distance(row, &z[seeds[a] * dim..][..dim])
                    .total_cmp(&squared_distance(row, &z[seeds[b] * dim..][..dim]))
            })
            .unwrap_or(0);
        resp[i * seeds.len() + nearest] = 1.0;
    }
    let mut components = maximisation(z, dim, &resp, seeds.len());
    let mut previous = f64::NEG_INFINITY;
    let mut r = vec![0.0; dim];
    for _ in 0..EM_ITERATIONS {
        let kc = components.len();
        resp.resize(n * kc, 0.0);
        let mut total = 0.0;
        for (i, row) in z.chunks(dim).enumerate() {
            let out = &mut resp[i * kc..(i + 1) * kc];
            for (o, c) in out.iter_mut().zip(&components) {
                *o = c.log_weighted_density(row, &mut r, dim);
            }
            let lse = log_sum_exp(out);
            total += lse;
            out.iter_mut().for_each(|o| *o = (*o - lse).exp());
        }
        let mean_loglik = total / n as f64;
        if mean_loglik - previous < EM_TOLERANCE {
            break;
        }
        previous = mean_loglik;
        components = maximisation(z, dim, &resp, kc);
    }
    components
}

/// Weights, means and covariances from responsibilities `resp` (n × k).
fn maximisation(z: &[f64], dim: usize, resp: &[f64], k: usize) -> Vec<Component> {
    let n = z.len() / dim;
    (0..k)
        .filter_map(|c| {
            let w: Vec<f64> = (0..n).map(|i| resp[i * k + c]).collect();
            let mass: f64 = w.iter().sum();
            if mass < (dim + 1) as f64 {
                return None;
            }
            let (mean, mut cov) = mean_and_covariance(z, dim, &w);
            for d in 0..dim {
                cov[d + d * dim] += REGULARISATION;
            }
            let factor = cholesky(&cov, dim)?;
            Some(Component::new(mass / n as f64, mean, factor, dim))
        })
        .collect()
}

fn squared_distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Row indices of `k` seeds, each drawn with probability proportional to its
/// squared distance from the nearest seed already drawn.
fn kmeans_plus_plus(z: &[f64], dim: usize, k: usize, rng: &mut Xoshiro256PlusPlus) -> Vec<usize> {
    let n = z.len() / dim;
    let mut seeds = vec![rng.random_range(0..n)];
    let mut nearest: Vec<f64> = z.chunks(dim).map(|row| squared_distance(row, &z[seeds[0] * dim..][..dim])).collect();
    while seeds.len() < k {
        let total: f64 = nearest.iter().sum();
        if total <= 0.0 {
            break; // every row is a copy of a seed
        }
        let mut pick = rng.random::<f64>() * total;
        let next = nearest.iter().position(|&d| {
            pick -= d;
            pick < 0.0
        });
        let next = next.unwrap_or(n - 1);
        seeds.push(next);
        for (d, row) in nearest.iter_mut().zip(z.chunks(dim)) {
            *d = d.min(squared_distance(row, &z[next * dim..][..dim]));
        }
    }
    seeds
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Draws from a fitted two-cluster mixture reproduce the cloud's
    /// clusters, and the density integrates to one (importance sampling
    /// from a wide Gaussian; the tolerance is four Monte Carlo errors).
    #[test]
    fn fitted_mixture_follows_the_cloud_and_is_normalised() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let dim = 2;
        let mut x = Vec::new();
        for i in 0..2000 {
            let centre = if i % 2 == 0 { -3.0 } else { 3.0 };
            let a: f64 = rng.sample(StandardNormal);
            let b: f64 = rng.sample(StandardNormal);
            x.extend_from_slice(&[centre + 0.3 * a, 0.1 * b]);
        }
        let m = Mixture::fit(&x, dim, &mut rng).unwrap();
        let mut u = vec![0.0; dim];
        let mut scratch = vec![0.0; 2 * dim];
        let draws = 20_000;
        let mut right = 0usize;
        for _ in 0..draws {
            m.sample(&mut rng, &mut u, &mut scratch);
            right += (u[0] > 0.0) as usize;
        }
        let p = right as f64 / draws as f64;
        assert!((p - 0.5).abs() < 4.0 * (0.25 / draws as f64).sqrt(), "right cluster {p}");
        // ∫ q = E_g[q / g] for g = N(0, 5² I).
        let (s, n) = (5.0, 200_000);
        let mut terms = Vec::with_capacity(n);
        for _ in 0..n {
            let e: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            let v = [s * e[0], s * e[1]];
            let log_g = -0.5 * (e[0] * e[0] + e[1] * e[1]) - (2.0 * std::f64::consts::PI * s * s).ln();
            terms.push((m.log_density(&v, &mut scratch) - log_g).exp());
        }
        let mean = terms.iter().sum::<f64>() / n as f64;
        let sd = (terms.iter().map(|t| (t - mean) * (t - mean)).sum::<f64>() / n as f64).sqrt();
        assert!((mean - 1.0).abs() < 4.0 * sd / (n as f64).sqrt(), "integral {mean} ± {}", sd / (n as f64).sqrt());
    }

    #[test]
    fn a_cloud_of_copies_has_no_mixture() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let x = vec![0.5; 3 * 100];
        assert!(Mixture::fit(&x, 3, &mut rng).is_none());
    }
}
