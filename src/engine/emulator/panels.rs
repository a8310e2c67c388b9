//! `|L⁻¹ k|²`, the quadratic form in a GP's predictive variance
//! `k** − kᵀ K⁻¹ k`, for one θ at a time.
//!
//! With an emulator in the likelihood this is the largest single cost of a
//! θ move: n²/2 multiply-adds per component, over an `L⁻¹` too large for L1.
//! `L⁻¹` is stored as panels of four rows: panel g holds, for each column
//! t < 4g + 4, the four entries `L⁻¹[4g..4g+4][t]` side by side (zero above
//! the diagonal and past the last row). Then four entries of `L⁻¹ k` are one
//! AVX register, built by multiply-adds of a contiguous load with one
//! broadcast `k[t]`: no horizontal sums per row and no ragged row ends, which
//! is what held a row-by-row dot product to a third of the machine's speed.

/// `L⁻¹` of an n × n lower-triangular factor, in panels of four rows.
#[derive(Clone, Debug)]
pub struct InversePanels {
    n: usize,
    data: Vec<f64>,
}

const ROWS: usize = 4;

impl InversePanels {
    /// From `L⁻¹` column-major n × n (its upper triangle is ignored).
    pub fn new(linv: &[f64], n: usize) -> Self {
        let mut data = Vec::with_capacity(Self::stored_len(n));
        for r0 in (0..n).step_by(ROWS) {
            for t in 0..Self::columns(r0, n) {
                for q in 0..ROWS {
                    let row = r0 + q;
                    data.push(if row < n && t <= row { linv[row + t * n] } else { 0.0 });
                }
            }
        }
        InversePanels { n, data }
    }

    /// Columns of the panel starting at row r0: up to its last row's diagonal.
    fn columns(r0: usize, n: usize) -> usize {
        (r0 + ROWS).min(n)
    }

    fn stored_len(n: usize) -> usize {
        (0..n).step_by(ROWS).map(|r0| ROWS * Self::columns(r0, n)).sum()
    }

    /// `|L⁻¹ k|²` for `k` of length n.
    pub fn quadratic(&self, k: &[f64]) -> f64 {
        assert_eq!(k.len(), self.n, "k has the wrong length for these panels");
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
                // SAFETY: the CPU has the features the function is compiled
                // for, and `k.len() == n` with `data` built for n (checked above).
                return unsafe { self.quadratic_avx2(k) };
            }
        }
        self.quadratic_portable(k)
    }

    fn quadratic_portable(&self, k: &[f64]) -> f64 {
        let (mut total, mut off) = (0.0, 0);
        for r0 in (0..self.n).step_by(ROWS) {
            let cols = Self::columns(r0, self.n);
            let mut w = [0.0; ROWS];
            for (t, &kt) in k[..cols].iter().enumerate() {
                for q in 0..ROWS {
                    w[q] += self.data[off + ROWS * t + q] * kt;
                }
            }
            total += w.iter().map(|v| v * v).sum::<f64>();
            off += ROWS * cols;
        }
        total
    }

    /// Four independent accumulators per panel, so that consecutive
    /// multiply-adds do not wait on each other's latency.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn quadratic_avx2(&self, k: &[f64]) -> f64 {
        use std::arch::x86_64::*;
        let n = self.n;
        let (kp, mut p) = (k.as_ptr(), self.data.as_ptr());
        let mut total = _mm256_setzero_pd();
        for r0 in (0..n).step_by(ROWS) {
            let cols = Self::columns(r0, n);
            let (mut a0, mut a1, mut a2, mut a3) =
                (_mm256_setzero_pd(), _mm256_setzero_pd(), _mm256_setzero_pd(), _mm256_setzero_pd());
            let mut t = 0;
            while t + 4 <= cols {
                a0 = _mm256_fmadd_pd(_mm256_loadu_pd(p), _mm256_broadcast_sd(&*kp.add(t)), a0);
                a1 = _mm256_fmadd_pd(_mm256_loadu_pd(p.add(4)), _mm256_broadcast_sd(&*kp.add(t + 1)), a1);
                a2 = _mm256_fmadd_pd(_mm256_loadu_pd(p.add(8)), _mm256_broadcast_sd(&*kp.add(t + 2)), a2);
                a3 = _mm256_fmadd_pd(_mm256_loadu_pd(p.add(12)), _mm256_broadcast_sd(&*kp.add(t + 3)), a3);
                p = p.add(16);
                t += 4;
            }
            while t < cols {
                a0 = _mm256_fmadd_pd(_mm256_loadu_pd(p), _mm256_broadcast_sd(&*kp.add(t)), a0);
                p = p.add(4);
                t += 1;
            }
            let w = _mm256_add_pd(_mm256_add_pd(a0, a1), _mm256_add_pd(a2, a3));
            total = _mm256_fmadd_pd(w, w, total);
        }
        let mut lanes = [0.0; 4];
        _mm256_storeu_pd(lanes.as_mut_ptr(), total);
        (lanes[0] + lanes[1]) + (lanes[2] + lanes[3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `|L⁻¹ k|²` the plain way, for n not a multiple of four and for one.
    #[test]
    fn panels_give_the_plain_quadratic_form() {
        for n in [1usize, 3, 4, 7, 13, 160] {
            let mut linv = vec![0.0; n * n];
            for j in 0..n {
                for i in j..n {
                    linv[i + j * n] = ((i * 7 + j * 3) % 11) as f64 / 11.0 - 0.4 + if i == j { 1.0 } else { 0.0 };
                }
            }
            let k: Vec<f64> = (0..n).map(|i| ((i * 5) % 9) as f64 / 9.0 - 0.3).collect();
            let plain: f64 = (0..n).map(|i| (0..=i).map(|t| linv[i + t * n] * k[t]).sum::<f64>().powi(2)).sum();
            let panels = InversePanels::new(&linv, n);
            assert_eq!(panels.data.len(), InversePanels::stored_len(n));
            // Only the summation order differs: a few ulps of the largest partial sums.
            let tol = 1e-12 * plain.abs().max(1.0);
            assert!((panels.quadratic(&k) - plain).abs() < tol, "n = {n}: {} vs {plain}", panels.quadratic(&k));
            assert!(
                (panels.quadratic_portable(&k) - plain).abs() < tol,
                "n = {n}: portable {} vs {plain}",
                panels.quadratic_portable(&k)
            );
        }
    }
}
