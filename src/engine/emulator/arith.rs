//! The emulator's inner arithmetic: the loops its predictions run per
//! evaluation of the likelihood, written so that the compiler vectorizes
//! them (and, for the covariance's rank-K update, compiled for AVX2 when
//! the CPU has it).

/// `acc += w · v vᵀ` for a square row-major `acc`.
pub(super) fn add_outer(acc: &mut [f64], v: &[f64], w: f64) {
    let m = v.len();
    for i in 0..m {
        for j in 0..m {
            acc[i * m + j] += w * v[i] * v[j];
        }
    }
}

/// Dot product with eight independent partial sums (two AVX registers'
/// worth), so the compiler can use SIMD (a plain float `sum()` must keep its
/// order and cannot) and consecutive additions do not wait on each other.
#[inline(always)]
pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f64 = ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7])) + tail
}

/// `lower += W Pᵀ` on the lower triangle (column-major n × n), for W and P
/// column-major n × K: column j gains `Σ_k W[j,k] P[j..,k]`.
pub(super) fn add_lower_product(plain: &[f64], weighted: &[f64], n: usize, kc: usize, lower: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU has the features the function is compiled for.
            return unsafe { add_lower_product_avx2(plain, weighted, n, kc, lower) };
        }
    }
    add_lower_product_portable(plain, weighted, n, kc, lower)
}

/// The same loops compiled for AVX2, picked at run time: the portable build
/// vectorizes only two doubles wide. (faer's triangular matrix product was
/// tried here and made the 7-observable heavy-ion calibration slower, 85 s
/// against 58 s, with libm's `exp` taking 45% of the run instead of 14%.)
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn add_lower_product_avx2(plain: &[f64], weighted: &[f64], n: usize, kc: usize, lower: &mut [f64]) {
    add_lower_product_portable(plain, weighted, n, kc, lower)
}

#[inline(always)]
fn add_lower_product_portable(plain: &[f64], weighted: &[f64], n: usize, kc: usize, lower: &mut [f64]) {
    for j in 0..n {
        let col = &mut lower[j * n + j..(j + 1) * n];
        for k in 0..kc {
            let c = weighted[j + k * n];
            for (t, p) in col.iter_mut().zip(&plain[j + k * n..(k + 1) * n]) {
                *t += c * p;
            }
        }
    }
}

pub(super) fn scale_to_unit(lo: &[f64], hi: &[f64], theta: &[f64], out: &mut [f64]) {
    for p in 0..theta.len() {
        out[p] = (theta[p] - lo[p]) / (hi[p] - lo[p]);
    }
}
