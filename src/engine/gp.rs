//! Gaussian-process building blocks shared by the model-discrepancy term and
//! the emulators: covariance kernels, a jittered Cholesky on top of faer, and
//! the Gaussian log-density.
//!
//! Matrices are dense, column-major `&[f64]` of size `n*n`; everything that
//! runs inside a sampler works in caller-provided buffers so that a likelihood
//! evaluation does not allocate.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch, LltParams};
use faer::{MatMut, MatRef, Par, Spec};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The paper's two discrepancy kernels (Jaiswal et al. 2025, eqs. for Kernel I/II).
///
/// Kernel I:  `s² + c̄² (x x')^r exp(-|x-x'|²/2ℓ²)`;
/// Kernel II: the same without `s²`.
/// The `(x x')^r` factor lets the discrepancy grow (r > 0) away from x = 0,
/// where for the ball drop model and truth coincide by construction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum DiscrepancyKernel {
    #[serde(rename = "I")]
    KernelI,
    #[serde(rename = "II")]
    KernelII,
}

impl DiscrepancyKernel {
    /// Hyperparameter names in the order they appear in parameter vectors.
    pub fn hyper_names(self) -> &'static [&'static str] {
        match self {
            DiscrepancyKernel::KernelI => &["cbar", "ell", "r", "s"],
            DiscrepancyKernel::KernelII => &["cbar", "ell", "r"],
        }
    }

    pub fn n_hyper(self) -> usize {
        self.hyper_names().len()
    }

    pub fn parse(s: &str) -> Option<Option<DiscrepancyKernel>> {
        match s.trim() {
            "none" | "None" | "no-md" | "nomd" => Some(None),
            "I" | "1" | "i" => Some(Some(DiscrepancyKernel::KernelI)),
            "II" | "2" | "ii" => Some(Some(DiscrepancyKernel::KernelII)),
            _ => None,
        }
    }

    pub fn label(kernel: Option<DiscrepancyKernel>) -> &'static str {
        match kernel {
            None => "none",
            Some(DiscrepancyKernel::KernelI) => "I",
            Some(DiscrepancyKernel::KernelII) => "II",
        }
    }
}

/// `x^r` with the convention `0^r = 0` for r > 0 and `0^0 = 1`.
#[inline]
pub fn pow_r(x: f64, r: f64) -> f64 {
    if x == 0.0 {
        if r == 0.0 {
            1.0
        } else {
            0.0
        }
    } else {
        x.powf(r)
    }
}

/// Kernel evaluation between two sets of inputs, written into `out`
/// (column-major, `xa.len()` rows by `xb.len()` columns).
pub fn discrepancy_cross_cov(kernel: DiscrepancyKernel, hyper: &[f64], xa: &[f64], xb: &[f64], out: &mut [f64]) {
    let (cbar, ell, r) = (hyper[0], hyper[1], hyper[2]);
    let s2 = match kernel {
        DiscrepancyKernel::KernelI => hyper[3] * hyper[3],
        DiscrepancyKernel::KernelII => 0.0,
    };
    let c2 = cbar * cbar;
    let inv_two_ell2 = 0.5 / (ell * ell);
    let n = xa.len();
    for (j, &xj) in xb.iter().enumerate() {
        let pj = pow_r(xj, r);
        for (i, &xi) in xa.iter().enumerate() {
            let d = xi - xj;
            out[i + j * n] = s2 + c2 * pow_r(xi, r) * pj * (-d * d * inv_two_ell2).exp();
        }
    }
}

/// Precomputed inputs for filling `K(x, x)` fast inside a sampler: squared
/// distances are fixed, only the hyperparameters change.
#[derive(Clone, Debug)]
pub struct DiscrepancyGram {
    pub x: Vec<f64>,
    ln_x: Vec<f64>,
    /// Distinct squared distances (equally spaced inputs have only n of them).
    unique_sq_dist: Vec<f64>,
    /// For the packed lower triangle (by column), the index into `unique_sq_dist`.
    pair_index: Vec<u32>,
    /// `Some(h²)` when `unique_sq_dist[k] = (k h)²` (an equally spaced grid):
    /// then `exp(-k²h²/2ℓ²) = q^(k²)` follows from one exp by recurrence.
    equal_lag_sq: Option<f64>,
}

impl DiscrepancyGram {
    pub fn new(x: &[f64]) -> Self {
        let n = x.len();
        let mut unique_sq_dist: Vec<f64> = Vec::new();
        let mut pair_index = Vec::with_capacity(n * (n + 1) / 2);
        for j in 0..n {
            for i in j..n {
                let d = x[i] - x[j];
                let d2 = d * d;
                // Lags of an equally spaced grid agree to rounding; merging them
                // changes K by ~1e-13 relative and saves most of the exp calls.
                let tol = 1e-13 * d2.max(1e-300);
                let k = match unique_sq_dist.iter().position(|u| (u - d2).abs() <= tol) {
                    Some(k) => k,
                    None => {
                        unique_sq_dist.push(d2);
                        unique_sq_dist.len() - 1
                    }
                };
                pair_index.push(k as u32);
            }
        }
        let equal_lag_sq = unique_sq_dist.get(1).copied().filter(|&h2| {
            h2 > 0.0
                && unique_sq_dist
                    .iter()
                    .enumerate()
                    .all(|(k, &d2)| (d2 - (k * k) as f64 * h2).abs() <= 1e-12 * d2.max(h2))
        });
        DiscrepancyGram {
            x: x.to_vec(),
            ln_x: x.iter().map(|v| v.ln()).collect(),
            unique_sq_dist,
            pair_index,
            equal_lag_sq,
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Writes the lower triangle of `K(x,x)` (column-major `n*n`).
    /// `xr` is scratch of length n for `x_i^r`; `corr` of length `n_unique()`.
    #[inline]
    pub fn fill_lower(
        &self,
        kernel: DiscrepancyKernel,
        hyper: &[f64],
        out: &mut [f64],
        xr: &mut [f64],
        corr: &mut [f64],
    ) {
        let n = self.x.len();
        let (cbar, ell, r) = (hyper[0], hyper[1], hyper[2]);
        let s2 = match kernel {
            DiscrepancyKernel::KernelI => hyper[3] * hyper[3],
            DiscrepancyKernel::KernelII => 0.0,
        };
        let c2 = cbar * cbar;
        for i in 0..n {
            // x^r = exp(r ln x): one exp per point instead of one powf per pair.
            xr[i] = if self.x[i] == 0.0 { pow_r(0.0, r) } else { (r * self.ln_x[i]).exp() };
        }
        let neg_inv_two_ell2 = -0.5 / (ell * ell);
        match self.equal_lag_sq {
            // q^(k²) = q^((k-1)²) · q^(2k-1): one exp instead of one per lag,
            // with a relative error of a few ulp over a grid of tens of points.
            // Past ~1e-280 the products would turn subnormal (slow, inexact);
            // exp is exact there, so the recurrence stops.
            Some(h2) => {
                let q = (h2 * neg_inv_two_ell2).exp();
                let q2 = q * q;
                let (mut value, mut step) = (1.0, q);
                for (k, c) in corr.iter_mut().enumerate() {
                    if value < 1e-280 {
                        *c = (self.unique_sq_dist[k] * neg_inv_two_ell2).exp();
                        continue;
                    }
                    *c = value;
                    value *= step;
                    step *= q2;
                }
            }
            None => {
                for (c, d2) in corr.iter_mut().zip(&self.unique_sq_dist) {
                    *c = (d2 * neg_inv_two_ell2).exp();
                }
            }
        }
        let mut k = 0;
        for j in 0..n {
            let cj = c2 * xr[j];
            for i in j..n {
                out[i + j * n] = s2 + cj * xr[i] * corr[self.pair_index[k] as usize];
                k += 1;
            }
        }
    }

    pub fn n_unique(&self) -> usize {
        self.unique_sq_dist.len()
    }
}

/// Stationary ARD correlation functions used by the emulators, written in
/// terms of the scaled squared distance `r² = Σ_k (a_k-b_k)²/ℓ_k²`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ArdKernel {
    /// `exp(-r²/2)`
    SquaredExponential,
    /// `(1 + √5 r + 5r²/3) exp(-√5 r)`
    Matern52,
}

impl ArdKernel {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "se" | "squared_exponential" | "rbf" => Some(ArdKernel::SquaredExponential),
            "matern52" | "matern_5_2" => Some(ArdKernel::Matern52),
            _ => None,
        }
    }

    #[inline]
    pub fn corr(self, r2: f64) -> f64 {
        match self {
            ArdKernel::SquaredExponential => (-0.5 * r2).exp(),
            ArdKernel::Matern52 => {
                let r = (5.0 * r2).sqrt();
                (1.0 + r + r * r / 3.0) * (-r).exp()
            }
        }
    }

    /// `d corr / d r²`, finite at r = 0 for both kernels.
    #[inline]
    pub fn dcorr_dr2(self, r2: f64) -> f64 {
        match self {
            ArdKernel::SquaredExponential => -0.5 * (-0.5 * r2).exp(),
            ArdKernel::Matern52 => {
                let r = (5.0 * r2).sqrt();
                -(5.0 / 6.0) * (1.0 + r) * (-r).exp()
            }
        }
    }

    /// `corr` and `d corr / d r²` together (one exponential).
    #[inline]
    pub fn corr_and_derivative(self, r2: f64) -> (f64, f64) {
        match self {
            ArdKernel::SquaredExponential => {
                let e = (-0.5 * r2).exp();
                (e, -0.5 * e)
            }
            ArdKernel::Matern52 => {
                let r = (5.0 * r2).sqrt();
                let e = (-r).exp();
                ((1.0 + r + r * r / 3.0) * e, -(5.0 / 6.0) * (1.0 + r) * e)
            }
        }
    }
}

/// `Σ_k (a_k-b_k)² / ℓ_k²` given `inv_l2[k] = 1/ℓ_k²`.
#[inline]
pub fn scaled_sq_dist(a: &[f64], b: &[f64], inv_l2: &[f64]) -> f64 {
    let mut q = 0.0;
    for k in 0..a.len() {
        let d = a[k] - b[k];
        q += d * d * inv_l2[k];
    }
    q
}

/// Hyperparameters of an emulator GP, `k(a,b) = σ_f² corr(r²) + c + σ_n² [a=b]`,
/// stored as logs so that an unconstrained optimizer can move them:
/// `[ln σ_f², ln ℓ_1 … ln ℓ_d, ln c, ln σ_n²]`.
#[derive(Clone, Debug, PartialEq)]
pub struct ArdHyper {
    pub log_params: Vec<f64>,
}

impl ArdHyper {
    pub fn n_params(d: usize) -> usize {
        d + 3
    }
    pub fn names(d: usize) -> Vec<String> {
        let mut v = vec!["log_signal_var".to_string()];
        v.extend((0..d).map(|k| format!("log_length_{k}")));
        v.push("log_constant".into());
        v.push("log_noise_var".into());
        v
    }
    pub fn dim(&self) -> usize {
        self.log_params.len() - 3
    }
    pub fn signal_var(&self) -> f64 {
        self.log_params[0].exp()
    }
    pub fn inv_sq_lengths(&self) -> Vec<f64> {
        self.log_params[1..1 + self.dim()].iter().map(|l| (-2.0 * l).exp()).collect()
    }
    pub fn constant(&self) -> f64 {
        self.log_params[self.dim() + 1].exp()
    }
    pub fn noise_var(&self) -> f64 {
        self.log_params[self.dim() + 2].exp()
    }
}

/// Fills the lower triangle of `K` (column-major, n×n) for row-major inputs `x` (n×d).
pub fn ard_gram_lower(kernel: ArdKernel, hyper: &ArdHyper, x: &[f64], n: usize, out: &mut [f64]) {
    let d = hyper.dim();
    let (sf2, c, sn2) = (hyper.signal_var(), hyper.constant(), hyper.noise_var());
    let inv_l2 = hyper.inv_sq_lengths();
    for j in 0..n {
        let xj = &x[j * d..(j + 1) * d];
        out[j + j * n] = sf2 + c + sn2;
        for i in j + 1..n {
            let r2 = scaled_sq_dist(&x[i * d..(i + 1) * d], xj, &inv_l2);
            out[i + j * n] = sf2 * kernel.corr(r2) + c;
        }
    }
}

/// Log marginal likelihood `log N(y | 0, K)` of a GP with ARD kernel and, if
/// `gradient` is given, its gradient with respect to `hyper.log_params`:
/// `∂/∂θ_j = ½ tr((ααᵀ - K⁻¹) ∂K/∂θ_j)`, `α = K⁻¹y` (Rasmussen & Williams eq. 5.9).
pub fn ard_log_marginal_likelihood(
    kernel: ArdKernel,
    hyper: &ArdHyper,
    x: &[f64],
    y: &[f64],
    gradient: Option<&mut [f64]>,
) -> Result<f64, NotPositiveDefinite> {
    let n = y.len();
    let d = hyper.dim();
    let (sf2, c, sn2) = (hyper.signal_var(), hyper.constant(), hyper.noise_var());
    let inv_l2 = hyper.inv_sq_lengths();
    // One pass over pairs fills K and keeps d corr/d r² for the gradient.
    let mut chol = CholeskyWorkspace::new(n);
    let mut pair_corr = if gradient.is_some() { vec![(0.0, 0.0); n * n] } else { Vec::new() };
    for j in 0..n {
        let xj = &x[j * d..(j + 1) * d];
        chol.factor[j + j * n] = sf2 + c + sn2;
        for i in j + 1..n {
            let r2 = scaled_sq_dist(&x[i * d..(i + 1) * d], xj, &inv_l2);
            let (corr, dc) = kernel.corr_and_derivative(r2);
            chol.factor[i + j * n] = sf2 * corr + c;
            if !pair_corr.is_empty() {
                pair_corr[i + j * n] = (corr, dc);
            }
        }
    }
    chol.factorize()?;
    let mut alpha = y.to_vec();
    chol.solve_in_place(&mut alpha);
    let quad: f64 = alpha.iter().zip(y).map(|(a, b)| a * b).sum();
    let lml = -0.5 * (quad + chol.log_det() + n as f64 * (2.0 * std::f64::consts::PI).ln());
    let Some(grad) = gradient else {
        return Ok(lml);
    };
    // W = ααᵀ - K⁻¹, lower triangle used.
    let kinv = chol.inverse();
    grad.iter_mut().for_each(|g| *g = 0.0);
    let mut dl = vec![0.0; d];
    let (mut g_sf, mut g_c, mut g_n) = (0.0, 0.0, 0.0);
    for j in 0..n {
        let xj = &x[j * d..(j + 1) * d];
        // Diagonal: r = 0, so only σ_f², c and σ_n² contribute.
        let wjj = alpha[j] * alpha[j] - kinv[j + j * n];
        g_sf += 0.5 * wjj * sf2;
        g_c += 0.5 * wjj * c;
        g_n += 0.5 * wjj * sn2;
        for i in j + 1..n {
            let xi = &x[i * d..(i + 1) * d];
            // Off-diagonal pairs appear twice in the trace.
            let w = alpha[i] * alpha[j] - kinv[i + j * n];
            let (corr, dcorr) = pair_corr[i + j * n];
            g_sf += w * sf2 * corr;
            g_c += w * c;
            // ∂r²/∂ln ℓ_k = -2 Δ_k²/ℓ_k².
            let f = w * sf2 * dcorr * -2.0;
            for k in 0..d {
                let dk = xi[k] - xj[k];
                dl[k] += f * dk * dk * inv_l2[k];
            }
        }
    }
    grad[0] = g_sf;
    grad[1..1 + d].copy_from_slice(&dl);
    grad[1 + d] = g_c;
    grad[2 + d] = g_n;
    Ok(lml)
}

/// Number of times a matrix needed jitter to factorize, process-wide. Reported
/// in run summaries so that regularisation is never silent.
static JITTER_EVENTS: AtomicUsize = AtomicUsize::new(0);

pub fn jitter_events() -> usize {
    JITTER_EVENTS.load(Ordering::Relaxed)
}

pub fn reset_jitter_events() {
    JITTER_EVENTS.store(0, Ordering::Relaxed)
}

/// Relative jitters tried in turn, as multiples of the mean diagonal.
const JITTER_LADDER: [f64; 6] = [0.0, 1e-12, 1e-10, 1e-8, 1e-6, 1e-4];

/// Below this size a plain unblocked factorization beats faer's blocked
/// kernel, whose set-up cost dominates for the discrepancy blocks (n ≈ 10)
/// evaluated millions of times; `mdpipe bench` measures the difference.
const SMALL_N: usize = 24;

/// Right-looking unblocked Cholesky of the lower triangle (column-major).
/// Every inner loop runs down a column, so memory access is contiguous and
/// vectorizes; the strided row dot products of the left-looking form cost
/// about twice as much at n ≈ 10.
fn cholesky_unblocked(a: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        let (done, rest) = a.split_at_mut((j + 1) * n);
        let col_j = &mut done[j * n..];
        let d = col_j[j];
        if !(d > 0.0) || !d.is_finite() {
            return false;
        }
        let d = d.sqrt();
        col_j[j] = d;
        let inv = 1.0 / d;
        for v in &mut col_j[j + 1..n] {
            *v *= inv;
        }
        let col_j = &col_j[..n];
        for (k, col_k) in rest.chunks_exact_mut(n).enumerate() {
            let k = j + 1 + k;
            let l_kj = col_j[k];
            for (t, s) in col_k[k..n].iter_mut().zip(&col_j[k..n]) {
                *t -= s * l_kj;
            }
        }
    }
    true
}

/// `cholesky_unblocked` with the size known at compile time, so the short
/// loops unroll and lose their bounds checks; the discrepancy blocks (n ≈ 10)
/// spend most of their time here.
fn cholesky_fixed<const N: usize>(a: &mut [f64]) -> bool {
    let a = &mut a[..N * N];
    for j in 0..N {
        let d = a[j + j * N];
        if !(d > 0.0) || !d.is_finite() {
            return false;
        }
        let d = d.sqrt();
        a[j + j * N] = d;
        let inv = 1.0 / d;
        for i in j + 1..N {
            a[i + j * N] *= inv;
        }
        for k in j + 1..N {
            let l_kj = a[k + j * N];
            for i in k..N {
                a[i + k * N] -= a[i + j * N] * l_kj;
            }
        }
    }
    true
}

/// Picks the fixed-size factorization for the small sizes met in practice.
fn cholesky_small(a: &mut [f64], n: usize) -> bool {
    macro_rules! by_size {
        ($($k:literal)*) => {
            match n {
                $($k => cholesky_fixed::<$k>(a),)*
                _ => cholesky_unblocked(a, n),
            }
        };
    }
    by_size!(1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16)
}

/// Reusable scratch for repeated Cholesky factorizations of one size.
pub struct CholeskyWorkspace {
    n: usize,
    /// Factor (lower triangle), column-major.
    pub factor: Vec<f64>,
    backup: Vec<f64>,
    stack: MemBuffer,
}

/// Why a factorization failed even with the largest jitter.
#[derive(Debug, Clone)]
pub struct NotPositiveDefinite {
    pub n: usize,
    pub max_jitter: f64,
}

impl std::fmt::Display for NotPositiveDefinite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{} matrix is not positive definite even with jitter {:.1e}", self.n, self.n, self.max_jitter)
    }
}
impl std::error::Error for NotPositiveDefinite {}

/// Copies the lower triangle (diagonal included) of a column-major n × n
/// matrix; the strictly upper triangle of `dst` is left as it is.
pub fn copy_lower(src: &[f64], dst: &mut [f64], n: usize) {
    for j in 0..n {
        dst[j * n + j..(j + 1) * n].copy_from_slice(&src[j * n + j..(j + 1) * n]);
    }
}

impl CholeskyWorkspace {
    pub fn new(n: usize) -> Self {
        let req = cholesky_in_place_scratch::<f64>(n, Par::Seq, Spec::<LltParams, f64>::default());
        CholeskyWorkspace { n, factor: vec![0.0; n * n], backup: vec![0.0; n * n], stack: MemBuffer::new(req) }
    }

    pub fn n(&self) -> usize {
        self.n
    }

    /// Factorizes the symmetric matrix whose lower triangle is in `self.factor`
    /// (column-major), in place. On failure it retries with growing diagonal
    /// jitter and counts the event; it returns the jitter used.
    pub fn factorize(&mut self) -> Result<f64, NotPositiveDefinite> {
        let n = self.n;
        // Only the lower triangle is read, so only it is kept for a retry:
        // for the joint likelihood's N × N matrix this copy is per evaluation.
        copy_lower(&self.factor, &mut self.backup, n);
        let mean_diag = (0..n).map(|i| self.backup[i * n + i]).sum::<f64>() / n.max(1) as f64;
        for (attempt, &rel) in JITTER_LADDER.iter().enumerate() {
            if attempt > 0 {
                copy_lower(&self.backup, &mut self.factor, n);
                for i in 0..n {
                    self.factor[i * n + i] += rel * mean_diag.abs().max(f64::MIN_POSITIVE);
                }
            }
            let ok = if n <= SMALL_N {
                cholesky_small(&mut self.factor, n)
            } else {
                let a = MatMut::from_column_major_slice_mut(&mut self.factor, n, n);
                cholesky_in_place(
                    a,
                    Default::default(),
                    Par::Seq,
                    MemStack::new(&mut self.stack),
                    Spec::<LltParams, f64>::default(),
                )
                .is_ok()
            };
            if ok && (0..n).all(|i| self.factor[i * n + i].is_finite()) {
                if attempt > 0 {
                    let count = JITTER_EVENTS.fetch_add(1, Ordering::Relaxed);
                    if count == 0 {
                        eprintln!(
                            "warning: covariance matrix ({n}x{n}) was not numerically positive definite; \
                             added jitter {:.1e} x mean diagonal (further events are counted in the run summary)",
                            rel
                        );
                    }
                }
                return Ok(rel * mean_diag);
            }
        }
        Err(NotPositiveDefinite { n, max_jitter: *JITTER_LADDER.last().unwrap() })
    }

    /// Factorizes without jitter: false when the matrix is not numerically
    /// positive definite. For callers to whom singularity is the answer (a
    /// Fisher matrix of unidentified parameters), not a nuisance to regularize.
    pub fn factorize_exact(&mut self) -> bool {
        let n = self.n;
        if n <= SMALL_N {
            cholesky_small(&mut self.factor, n)
        } else {
            let a = MatMut::from_column_major_slice_mut(&mut self.factor, n, n);
            cholesky_in_place(
                a,
                Default::default(),
                Par::Seq,
                MemStack::new(&mut self.stack),
                Spec::<LltParams, f64>::default(),
            )
            .is_ok()
        }
    }

    /// `log det A` from the factor.
    pub fn log_det(&self) -> f64 {
        let n = self.n;
        // One log of the product instead of n logs, unless it could leave the normal range.
        let mut prod = 1.0;
        for i in 0..n {
            prod *= self.factor[i * n + i];
            if !(1e-150..=1e150).contains(&prod) {
                return 2.0 * (0..n).map(|i| self.factor[i * n + i].ln()).sum::<f64>();
            }
        }
        2.0 * prod.ln()
    }

    /// Solves `L z = b` in place (forward substitution).
    pub fn solve_lower_in_place(&self, b: &mut [f64]) {
        let n = self.n;
        if n <= SMALL_N {
            // Column-oriented forward substitution: contiguous inner loop.
            for (k, col) in self.factor.chunks_exact(n).enumerate() {
                let z = b[k] / col[k];
                b[k] = z;
                for (bi, l) in b[k + 1..n].iter_mut().zip(&col[k + 1..n]) {
                    *bi -= l * z;
                }
            }
            return;
        }
        let l = MatRef::from_column_major_slice(&self.factor, self.n, self.n);
        let rhs = MatMut::from_column_major_slice_mut(b, self.n, 1);
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(l, rhs, Par::Seq);
    }

    /// Solves `Lᵀ z = b` in place (backward substitution).
    pub fn solve_upper_in_place(&self, b: &mut [f64]) {
        let l = MatRef::from_column_major_slice(&self.factor, self.n, self.n);
        let rhs = MatMut::from_column_major_slice_mut(b, self.n, 1);
        faer::linalg::triangular_solve::solve_upper_triangular_in_place(l.transpose(), rhs, Par::Seq);
    }

    /// Solves `A z = b` in place using the factor.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        self.solve_lower_in_place(b);
        self.solve_upper_in_place(b);
    }

    /// `A⁻¹` (full, column-major) from the factor.
    pub fn inverse(&self) -> Vec<f64> {
        let n = self.n;
        let mut out = vec![0.0; n * n];
        let l = MatRef::from_column_major_slice(&self.factor, n, n);
        let req = faer::linalg::cholesky::llt::inverse::inverse_scratch::<f64>(n, Par::Seq);
        let mut mem = MemBuffer::new(req);
        faer::linalg::cholesky::llt::inverse::inverse(
            MatMut::from_column_major_slice_mut(&mut out, n, n),
            l,
            Par::Seq,
            MemStack::new(&mut mem),
        );
        // faer fills the lower triangle; mirror it.
        for j in 0..n {
            for i in j + 1..n {
                out[j + i * n] = out[i + j * n];
            }
        }
        out
    }

    /// `L⁻¹` (lower triangular, column-major) from the factor.
    pub fn lower_inverse(&self) -> Vec<f64> {
        let n = self.n;
        let mut out = vec![0.0; n * n];
        for i in 0..n {
            out[i + i * n] = 1.0;
        }
        let l = MatRef::from_column_major_slice(&self.factor, n, n);
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(
            l,
            MatMut::from_column_major_slice_mut(&mut out, n, n),
            Par::Seq,
        );
        out
    }
}

/// `log N(r | 0, A)` where `ws` already holds the Cholesky factor of `A`.
/// `r` is overwritten with `L⁻¹ r`.
pub fn gaussian_logpdf_factored(ws: &CholeskyWorkspace, r: &mut [f64]) -> f64 {
    ws.solve_lower_in_place(r);
    let quad: f64 = r.iter().map(|z| z * z).sum();
    -0.5 * (quad + ws.log_det() + r.len() as f64 * (2.0 * std::f64::consts::PI).ln())
}

/// `log N(r | 0, A)` for a dense covariance (convenience, allocates).
pub fn gaussian_logpdf(r: &[f64], cov: &[f64]) -> Result<f64, NotPositiveDefinite> {
    let n = r.len();
    let mut ws = CholeskyWorkspace::new(n);
    ws.factor.copy_from_slice(cov);
    ws.factorize()?;
    let mut z = r.to_vec();
    Ok(gaussian_logpdf_factored(&ws, &mut z))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logpdf_matches_diagonal_closed_form() {
        let r = [0.3, -1.2, 0.7];
        let var: [f64; 3] = [0.5, 2.0, 1.5];
        let mut cov = vec![0.0; 9];
        for i in 0..3 {
            cov[i * 3 + i] = var[i];
        }
        let expected: f64 =
            (0..3).map(|i| -0.5 * (r[i] * r[i] / var[i] + var[i].ln() + (2.0 * std::f64::consts::PI).ln())).sum();
        let got = gaussian_logpdf(&r, &cov).unwrap();
        assert!((got - expected).abs() < 1e-12, "{got} vs {expected}");
    }

    #[test]
    fn logpdf_matches_2x2_closed_form() {
        // [[a, b],[b, c]] inverse and determinant by hand.
        let (a, b, c) = (2.0, 0.6, 1.0);
        let det: f64 = a * c - b * b;
        let r = [0.4, -0.9];
        let quad = (c * r[0] * r[0] - 2.0 * b * r[0] * r[1] + a * r[1] * r[1]) / det;
        let expected = -0.5 * (quad + det.ln() + 2.0 * (2.0 * std::f64::consts::PI).ln());
        let got = gaussian_logpdf(&r, &[a, b, b, c]).unwrap();
        assert!((got - expected).abs() < 1e-12);
    }

    #[test]
    fn singular_matrix_gets_jitter_and_is_counted() {
        let before = jitter_events();
        // Rank-one matrix: exactly singular.
        let v = [1.0, 2.0, 3.0];
        let mut ws = CholeskyWorkspace::new(3);
        for j in 0..3 {
            for i in 0..3 {
                ws.factor[i + 3 * j] = v[i] * v[j];
            }
        }
        let jitter = ws.factorize().expect("jitter should rescue a PSD matrix");
        assert!(jitter > 0.0);
        assert!(jitter_events() > before);
    }

    #[test]
    fn every_factorization_path_reproduces_the_matrix() {
        // n = 3, 10: fixed-size; 20: unblocked; 30, 70: faer. L Lᵀ must give A
        // back, from the lower triangle alone: the upper holds NaN (callers copy
        // only the lower triangle, and leave whatever the last factor left above).
        for (n, exact) in [3usize, 10, 20, 30, 70].into_iter().flat_map(|n| [(n, true), (n, false)]) {
            let x: Vec<f64> = (0..n).map(|i| 0.1 + 0.07 * i as f64 + 0.01 * (i as f64).sin()).collect();
            let mut a = vec![0.0; n * n];
            discrepancy_cross_cov(DiscrepancyKernel::KernelI, &[1.1, 0.3, 0.8, 0.4], &x, &x, &mut a);
            for i in 0..n {
                a[i + i * n] += 0.05;
            }
            let mut ws = CholeskyWorkspace::new(n);
            ws.factor.copy_from_slice(&a);
            for j in 0..n {
                for i in 0..j {
                    ws.factor[i + j * n] = f64::NAN;
                }
            }
            if exact {
                assert!(ws.factorize_exact(), "n = {n}");
            } else {
                assert_eq!(ws.factorize().ok(), Some(0.0), "n = {n}: no jitter needed");
            }
            for j in 0..n {
                for i in j..n {
                    let llt: f64 = (0..=j).map(|k| ws.factor[i + k * n] * ws.factor[j + k * n]).sum();
                    assert!((llt - a[i + j * n]).abs() < 1e-12, "n = {n}, ({i},{j}): {llt} vs {}", a[i + j * n]);
                }
            }
        }
    }

    #[test]
    fn indefinite_matrix_is_an_error_not_a_silent_answer() {
        let mut ws = CholeskyWorkspace::new(2);
        ws.factor.copy_from_slice(&[1.0, 3.0, 3.0, 1.0]);
        assert!(ws.factorize().is_err());
    }

    #[test]
    fn gram_fill_matches_cross_cov() {
        let x = [0.1, 0.35, 0.8, 1.0];
        let h = [1.3, 0.4, 1.7, 0.2];
        let g = DiscrepancyGram::new(&x);
        let mut lower = vec![0.0; 16];
        let mut xr = vec![0.0; 4];
        let mut corr = vec![0.0; g.n_unique()];
        g.fill_lower(DiscrepancyKernel::KernelI, &h, &mut lower, &mut xr, &mut corr);
        let mut full = vec![0.0; 16];
        discrepancy_cross_cov(DiscrepancyKernel::KernelI, &h, &x, &x, &mut full);
        for j in 0..4 {
            for i in j..4 {
                assert!((lower[i + 4 * j] - full[i + 4 * j]).abs() < 1e-14);
            }
        }
        // Kernel I at x = x' = 1: s² + c̄².
        assert!((full[15] - (0.04 + 1.69)).abs() < 1e-12);
    }

    #[test]
    fn equally_spaced_gram_recurrence_matches_direct_exp() {
        // The ball drop's times (0..1 s in 9 steps) and the heavy-ion pT bin
        // midpoints, at length scales from tiny (underflowing lags) to long.
        let grids: [Vec<f64>; 2] =
            [(0..10).map(|i| i as f64 / 9.0).collect(), (0..10).map(|i| 0.1 + 0.2 * i as f64).collect()];
        for x in &grids {
            let n = x.len();
            let g = DiscrepancyGram::new(x);
            assert!(g.equal_lag_sq.is_some(), "grid {x:?} should be recognised as equally spaced");
            for ell in [0.003, 0.05, 0.4, 2.0, 9.5] {
                let h = [1.3, ell, 1.7, 0.2];
                let (mut lower, mut full) = (vec![0.0; n * n], vec![0.0; n * n]);
                let (mut xr, mut corr) = (vec![0.0; n], vec![0.0; g.n_unique()]);
                g.fill_lower(DiscrepancyKernel::KernelII, &h, &mut lower, &mut xr, &mut corr);
                discrepancy_cross_cov(DiscrepancyKernel::KernelII, &h, x, x, &mut full);
                for j in 0..n {
                    for i in j..n {
                        let (a, b) = (lower[i + n * j], full[i + n * j]);
                        // exp(u) inherits u's rounding as |u|·ε relative error, whichever
                        // way it is computed; allow that plus a few ulp per recurrence step.
                        let cond = 1.0 + b.abs().max(1e-300).ln().abs();
                        assert!((a - b).abs() <= 1e-14 * cond * b.abs() + 1e-300, "ell {ell}, ({i},{j}): {a} vs {b}");
                    }
                }
            }
        }
        assert!(DiscrepancyGram::new(&[0.1, 0.35, 0.8, 1.0]).equal_lag_sq.is_none());
    }

    #[test]
    fn solve_recovers_rhs() {
        let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let mut ws = CholeskyWorkspace::new(3);
        ws.factor.copy_from_slice(&a);
        ws.factorize().unwrap();
        let x = [1.0, -2.0, 0.5];
        let mut b = [0.0; 3];
        for i in 0..3 {
            for j in 0..3 {
                b[i] += a[i + 3 * j] * x[j];
            }
        }
        ws.solve_in_place(&mut b);
        for i in 0..3 {
            assert!((b[i] - x[i]).abs() < 1e-12);
        }
    }
}
