//! A jittered Cholesky factorization on top of faer (unblocked below
//! n = 24), solves with its factor, and the Gaussian log-density.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch, LltParams};
use faer::{MatMut, MatRef, Par, Spec};

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

/// Cholesky with the size known at compile time, so the short loops unroll
/// and lose their bounds checks; the discrepancy blocks (n ≈ 10) spend most
/// of their time here. Left-looking: column j takes every earlier column's
/// update just before its own square root. The products and their order
/// are `cholesky_unblocked`'s (L_ik L_jk subtracted for k = 0, 1, …), so the
/// factor is the same to the bit, but only one column's update waits on
/// each square root and division, which run one after another (measured
/// at n = 10: 171 ns against 190 ns for the right-looking order).
fn cholesky_fixed<const N: usize>(a: &mut [f64]) -> bool {
    let a = &mut a[..N * N];
    for j in 0..N {
        for k in 0..j {
            let l_jk = a[j + k * N];
            for i in j..N {
                a[i + j * N] -= a[i + k * N] * l_jk;
            }
        }
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

/// Forward substitution `L z = b` in place with the size known at compile
/// time (the short loops unroll and lose their bounds checks): the same
/// column-oriented order, products and divisions as the general loop, so the
/// same bits. Three of these per evaluation were an eighth of the ball
/// drop's Kernel II likelihood.
fn solve_lower_fixed<const N: usize>(l: &[f64], b: &mut [f64]) {
    let (l, b) = (&l[..N * N], &mut b[..N]);
    for k in 0..N {
        let z = b[k] / l[k + k * N];
        b[k] = z;
        for i in k + 1..N {
            b[i] -= l[i + k * N] * z;
        }
    }
}

/// Column-oriented forward substitution for any small n: contiguous inner loop.
fn solve_lower_unblocked(l: &[f64], b: &mut [f64], n: usize) {
    for (k, col) in l.chunks_exact(n).enumerate() {
        let z = b[k] / col[k];
        b[k] = z;
        for (bi, l) in b[k + 1..n].iter_mut().zip(&col[k + 1..n]) {
            *bi -= l * z;
        }
    }
}

/// Picks the fixed-size forward substitution for the sizes met in practice.
fn solve_lower_small(l: &[f64], b: &mut [f64], n: usize) {
    macro_rules! by_size {
        ($($k:literal)*) => {
            match n {
                $($k => solve_lower_fixed::<$k>(l, b),)*
                _ => solve_lower_unblocked(l, b, n),
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
    /// jitter; it returns the jitter used (0 when none was needed), which the
    /// caller counts where its results are reported (`MdLikelihood`).
    pub fn factorize(&mut self) -> Result<f64, NotPositiveDefinite> {
        let n = self.n;
        // Only the lower triangle is read, so only it is kept for a retry:
        // for the joint likelihood's N × N matrix this copy is per evaluation.
        // Small blocks are copied whole: one memcpy beats n short ones.
        let mut backup = std::mem::take(&mut self.backup);
        if n <= SMALL_N {
            backup.copy_from_slice(&self.factor);
        } else {
            copy_lower(&self.factor, &mut backup, n);
        }
        let result = self.factorize_refilling(|a| copy_lower(&backup, a, n));
        self.backup = backup;
        result
    }

    /// `factorize` of the matrix `fill` writes (its lower triangle) into
    /// the factor, which already holds it: a retry with jitter fills it
    /// again instead of copying a backup on every call.
    pub fn factorize_refilling(&mut self, mut fill: impl FnMut(&mut [f64])) -> Result<f64, NotPositiveDefinite> {
        let n = self.n;
        let mut mean_diag = f64::NAN;
        for (attempt, &rel) in JITTER_LADDER.iter().enumerate() {
            if attempt > 0 {
                fill(&mut self.factor);
                if attempt == 1 {
                    mean_diag = (0..n).map(|i| self.factor[i * n + i]).sum::<f64>() / n.max(1) as f64;
                }
                for i in 0..n {
                    self.factor[i * n + i] += rel * mean_diag.abs().max(f64::MIN_POSITIVE);
                }
            }
            if self.factorize_exact() && (0..n).all(|i| self.factor[i * n + i].is_finite()) {
                return Ok(if attempt == 0 { 0.0 } else { rel * mean_diag.abs().max(f64::MIN_POSITIVE) });
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
            solve_lower_small(&self.factor, b, n);
            return;
        }
        let l = MatRef::from_column_major_slice(&self.factor, self.n, self.n);
        let rhs = MatMut::from_column_major_slice_mut(b, self.n, 1);
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(l, rhs, Par::Seq);
    }

    /// Solves `L Z = B` in place for the `cols` columns of `b` (column-major n × cols).
    pub fn solve_lower_columns_in_place(&self, b: &mut [f64], cols: usize) {
        let l = MatRef::from_column_major_slice(&self.factor, self.n, self.n);
        let rhs = MatMut::from_column_major_slice_mut(b, self.n, cols);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// `log N(r | 0, A)` for a dense covariance (convenience, allocates).
    fn gaussian_logpdf(r: &[f64], cov: &[f64]) -> Result<f64, NotPositiveDefinite> {
        let n = r.len();
        let mut ws = CholeskyWorkspace::new(n);
        ws.factor.copy_from_slice(cov);
        ws.factorize()?;
        let mut z = r.to_vec();
        Ok(gaussian_logpdf_factored(&ws, &mut z))
    }
    use crate::engine::gp::discrepancy::{discrepancy_cross_cov, DiscrepancyKernel};

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
    fn singular_matrix_gets_jitter_and_says_how_much() {
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
    }

    /// The likelihood's path: the matrix refilled for each retry, not backed
    /// up. A singular block (rank one, n = 10) needs jitter; the refilling
    /// factorization gives `factorize`'s jitter and factor to the bit, and
    /// fills once per retry.
    #[test]
    fn refilling_matches_the_backed_up_factorization() {
        let n = 10;
        let fill = |a: &mut [f64]| {
            for j in 0..n {
                for i in j..n {
                    a[i + n * j] = (1.0 + i as f64) * (1.0 + j as f64);
                }
            }
        };
        let mut backed_up = CholeskyWorkspace::new(n);
        fill(&mut backed_up.factor);
        let jitter = backed_up.factorize().expect("jitter rescues a PSD matrix");
        assert!(jitter > 0.0);
        let mut refilled = CholeskyWorkspace::new(n);
        fill(&mut refilled.factor);
        let mut fills = 0;
        let got = refilled.factorize_refilling(|a| {
            fills += 1;
            fill(a)
        });
        assert_eq!(got.unwrap().to_bits(), jitter.to_bits());
        // The jitter is a rung of the ladder times the mean diagonal, Σ(1 + i)²/n = 38.5.
        let rung = JITTER_LADDER.iter().position(|r| *r > 0.0 && r * 38.5 == jitter).unwrap();
        assert_eq!(fills, rung, "one fill per retry");
        for j in 0..n {
            for i in j..n {
                assert_eq!(refilled.factor[i + n * j].to_bits(), backed_up.factor[i + n * j].to_bits());
            }
        }
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
