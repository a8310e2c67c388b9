//! The part of a covariance that links observable blocks, as a low-rank term.
//!
//! Given the data's covariance beyond the errors, `S` (N × N, blocks of
//! points per observable), find `V` (N × k, k small) such that `V Vᵀ` equals
//! `S` in every entry between two blocks; what `V Vᵀ` adds inside a block is
//! taken back out of that block, so `S = blockdiag(S_b − (V Vᵀ)_b) + V Vᵀ`
//! exactly. A systematic shared by several tables (a normalization) is then
//! one column, however many tables share it, while each table's own
//! systematics and jackknife covariance stay inside its block.
//!
//! How: each block's entries towards the other blocks span a few directions
//! of its own points (an orthonormal basis `Q_a` from the eigenvectors of
//! that panel's Gram matrix). In those coordinates the entries between
//! blocks are a small matrix `C` whose diagonal blocks are free; the
//! smallest k for which some choice of them makes `C + D` positive
//! semi-definite of rank k is found by alternating projections (the rank-k
//! part of `C + D`, then its diagonal blocks as the new `D`, from D = 0), as
//! in principal-axis factor analysis. When no small rank reaches the entries to rounding,
//! `D = Qᵀ S Q` (the projection of each block's own covariance) gives an
//! exact factor of rank Σ rank(Q_a). The caller checks the remainder inside
//! each block and keeps the dense factorization when anything fails.

use faer::{MatRef, Side};

/// Largest rank tried by alternating projections before the exact fallback.
const SMALLEST_RANKS: usize = 12;
/// Rounds of projections in all, over every rank tried: each is an
/// eigendecomposition of the r × r matrix, so this bounds the setup's cost
/// (about 6 s at r = 256) when no small rank fits.
const PROJECTION_ROUNDS: usize = 300;

/// `V` (column-major N × k), k and what `accept` made of them, from the
/// first split `accept` takes (the smallest rank found, then the projected
/// one); `None` when the entries between blocks are not of rank ≤
/// `max_rank` or no split is accepted (`accept` sees V and k, and checks
/// what stays inside the blocks). `s`: full symmetric column-major N × N;
/// block b holds points `offsets[b]..offsets[b + 1]`. `allowed`: how far
/// an entry between blocks may be from `V Vᵀ`'s, the rounding of the
/// digits it was written with (0: to double rounding).
pub fn low_rank_across<T>(
    s: &[f64],
    offsets: &[usize],
    max_rank: usize,
    allowed: f64,
    accept: impl Fn(&[f64], usize) -> Option<T>,
) -> Option<(Vec<f64>, usize, T)> {
    let n = *offsets.last()?;
    let blocks: Vec<std::ops::Range<usize>> = offsets.windows(2).map(|w| w[0]..w[1]).collect();
    let block_of: Vec<usize> = blocks.iter().enumerate().flat_map(|(b, r)| r.clone().map(move |_| b)).collect();
    let scale = s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let tol = (1e-12 * scale.max(f64::MIN_POSITIVE)).max(allowed);
    let mut largest_across = 0.0f64;
    for j in 0..n {
        for i in (0..n).filter(|&i| block_of[i] != block_of[j]) {
            largest_across = largest_across.max(s[i + j * n].abs());
        }
    }
    if largest_across <= tol {
        let kept = accept(&[], 0)?;
        return Some((Vec::new(), 0, kept));
    }
    let bases: Vec<Basis> = blocks.iter().map(|rows| Basis::of_panel(s, n, rows.clone(), &block_of, allowed)).collect();
    let r: usize = bases.iter().map(|q| q.rank).sum();
    if r == 0 || r > max_rank {
        return None;
    }
    let at: Vec<usize> = std::iter::once(0)
        .chain(bases.iter().scan(0, |acc, q| {
            *acc += q.rank;
            Some(*acc)
        }))
        .collect();
    // C: the entries between blocks in the bases' coordinates; D0: each block's own, projected.
    let mut c = vec![0.0; r * r];
    let mut d0 = vec![0.0; r * r];
    for (a, qa) in bases.iter().enumerate() {
        for (b, qb) in bases.iter().enumerate() {
            let target = if a == b { &mut d0 } else { &mut c };
            for p in 0..qa.rank {
                for q in 0..qb.rank {
                    let mut v = 0.0;
                    for (jj, j) in blocks[b].clone().enumerate() {
                        let sq = qb.vector(q)[jj];
                        let col = &s[j * n + blocks[a].start..j * n + blocks[a].end];
                        v += sq * col.iter().zip(qa.vector(p)).map(|(x, y)| x * y).sum::<f64>();
                    }
                    target[(at[a] + p) + (at[b] + q) * r] = v;
                }
            }
        }
    }
    let in_block = |i: usize, j: usize| at.partition_point(|&x| x <= i) == at.partition_point(|&x| x <= j);
    // In units of each direction's own variance: where the entries between
    // blocks leave the split open (a systematic shared by two tables only),
    // the projections then share it in proportion to what each block holds,
    // so what is taken back out of a block stays within it.
    let w: Vec<f64> = (0..r).map(|p| if d0[p + p * r] > 0.0 { 1.0 / d0[p + p * r].sqrt() } else { 1.0 }).collect();
    let scaled: Vec<f64> = (0..r * r).map(|e| c[e] * w[e % r] * w[e / r]).collect();
    let widest = w.iter().fold(0.0f64, |m, v| m.max(*v));
    let scaled_tol = (1e-12 * scaled.iter().fold(0.0f64, |m, v| m.max(v.abs()))).max(2.0 * allowed * widest * widest);
    let mut rounds = PROJECTION_ROUNDS;
    let smallest = (1..=SMALLEST_RANKS.min(r).min(max_rank))
        .find_map(|k| smallest_rank_factor(&scaled, r, k, &in_block, scaled_tol, &mut rounds))
        .map(|(f, k)| ((0..r * k).map(|e| f[e] / w[e % r]).collect::<Vec<f64>>(), k));
    let projected = || {
        let whole: Vec<f64> = c.iter().zip(&d0).map(|(x, y)| x + y).collect();
        let (f, k) = positive_part(&whole, r, r, tol)?;
        (k <= max_rank && off_block_residual(&f, k, &c, r, &in_block) <= tol).then_some((f, k))
    };
    let to_points = |(f, k): (Vec<f64>, usize)| {
        let mut v = vec![0.0; n * k];
        for (a, q) in bases.iter().enumerate() {
            for col in 0..k {
                for (ii, i) in blocks[a].clone().enumerate() {
                    v[i + col * n] = (0..q.rank).map(|p| q.vector(p)[ii] * f[(at[a] + p) + col * r]).sum();
                }
            }
        }
        // What the bases left out, or rounding, must not show between blocks.
        for j in 0..n {
            for i in (j + 1..n).filter(|&i| block_of[i] != block_of[j]) {
                let vv: f64 = (0..k).map(|col| v[i + col * n] * v[j + col * n]).sum();
                if (vv - s[i + j * n]).abs() > 10.0 * tol {
                    return None;
                }
            }
        }
        let kept = accept(&v, k)?;
        Some((v, k, kept))
    };
    smallest.and_then(to_points).or_else(|| projected().and_then(to_points))
}

/// The spectral norm of `s − V Vᵀ` over the entries between blocks (the
/// entries within a block are the blocks' own, exactly): what a split to
/// printed digits leaves. Adding it to the diagonal makes the covariance
/// used at least the one written, in the Loewner order.
pub fn residual_norm(s: &[f64], offsets: &[usize], v: &[f64], k: usize) -> f64 {
    let n = *offsets.last().unwrap_or(&0);
    let block_of: Vec<usize> =
        offsets.windows(2).enumerate().flat_map(|(b, w)| std::iter::repeat_n(b, w[1] - w[0])).collect();
    let mut e = vec![0.0; n * n];
    for j in 0..n {
        for i in (0..n).filter(|&i| block_of[i] != block_of[j]) {
            let vv: f64 = (0..k).map(|col| v[i + col * n] * v[j + col * n]).sum();
            e[i + j * n] = s[i + j * n] - vv;
        }
    }
    // Above a thousand points the eigendecomposition (O(N³), once per
    // likelihood built) would cost more than it saves; power iteration
    // (O(N²) a step) estimates the same norm, raised to a bound.
    if n > EIGEN_POINTS {
        return spectral_norm_bound(&e, n);
    }
    let Ok(eigen) = MatRef::from_column_major_slice(&e, n, n).self_adjoint_eigen(Side::Lower) else {
        return f64::INFINITY;
    };
    let values = eigen.S().column_vector();
    (0..n).map(|i| values[i].abs()).fold(0.0, f64::max)
}

/// The most points for which `residual_norm` takes the exact spectral norm.
const EIGEN_POINTS: usize = 1000;

/// Power iterations of `spectral_norm_bound`, and the share of the norm its
/// estimate is taken to reach. From a Gaussian start, k steps fall short of
/// (1 − ε)‖E‖ with probability at most 0.824 √n (1 − ε)^(2k−1)
/// (Kuczyński & Woźniakowski 1992): at ε = 0.1 and k = 100 below 1e-7 for
/// n up to 10⁴.
const POWER_ITERATIONS: usize = 100;
const POWER_REACH: f64 = 0.9;

/// An upper bound on the spectral norm of the symmetric `e` (column-major
/// n × n), with the probability above: power iteration's ‖E x‖ on a unit x
/// from a fixed-seed Gaussian start, over `POWER_REACH`. The Frobenius norm
/// it replaces bounds it surely but grows as N where rounding's grows as
/// √N: at 3 printed digits it exceeded the errors² themselves.
fn spectral_norm_bound(e: &[f64], n: usize) -> f64 {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(0x5eed);
    let mut x: Vec<f64> = (0..n).map(|_| StandardNormal.sample(&mut rng)).collect();
    let mut y = vec![0.0; n];
    let mut estimate = 0.0;
    for _ in 0..POWER_ITERATIONS {
        let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm == 0.0 {
            return 0.0;
        }
        x.iter_mut().for_each(|v| *v /= norm);
        y.fill(0.0);
        for (j, &xj) in x.iter().enumerate() {
            for (yi, eij) in y.iter_mut().zip(&e[j * n..(j + 1) * n]) {
                *yi += eij * xj;
            }
        }
        estimate = y.iter().map(|v| v * v).sum::<f64>().sqrt();
        std::mem::swap(&mut x, &mut y);
    }
    estimate / POWER_REACH
}

/// An orthonormal basis of the directions a block's entries towards the
/// other blocks take among its own points.
struct Basis {
    rows: usize,
    rank: usize,
    /// Column-major rows × rank.
    vectors: Vec<f64>,
}

impl Basis {
    /// From the singular vectors of the panel (the block's rows, the other
    /// blocks' columns) whose singular values are above rounding: the
    /// double's, or that of entries written to fewer digits (`allowed`
    /// each, whose largest singular value over an n × m panel is about
    /// `allowed (√n + √m) / √3`).
    fn of_panel(s: &[f64], n: usize, rows: std::ops::Range<usize>, block_of: &[usize], allowed: f64) -> Basis {
        let nb = rows.len();
        let own = block_of[rows.start];
        let others: Vec<usize> = (0..n).filter(|&j| block_of[j] != own).collect();
        let panel: Vec<f64> =
            others.iter().flat_map(|&j| s[j * n + rows.start..j * n + rows.end].iter().copied()).collect();
        let empty = Basis { rows: nb, rank: 0, vectors: Vec::new() };
        let Ok(svd) = MatRef::from_column_major_slice(&panel, nb, others.len()).thin_svd() else { return empty };
        let (u, sigma) = (svd.U(), svd.S().column_vector());
        let count = sigma.nrows();
        let largest = (0..count).map(|i| sigma[i]).fold(0.0f64, f64::max);
        let noise = 1.5 * allowed * ((nb as f64).sqrt() + (others.len() as f64).sqrt());
        let floor = (1e-13 * largest).max(noise);
        let kept: Vec<usize> = (0..count).filter(|&i| largest > 0.0 && sigma[i] > floor).collect();
        let vectors = kept.iter().flat_map(|&e| (0..nb).map(move |i| u[(i, e)])).collect();
        Basis { rows: nb, rank: kept.len(), vectors }
    }

    fn vector(&self, p: usize) -> &[f64] {
        &self.vectors[p * self.rows..(p + 1) * self.rows]
    }
}

/// A factor F (r × k) with F Fᵀ equal to `c` between blocks, by alternating
/// projections; `None` when rank k does not reach `tol` (or stalls).
fn smallest_rank_factor(
    c: &[f64],
    r: usize,
    k: usize,
    in_block: &impl Fn(usize, usize) -> bool,
    tol: f64,
    rounds_left: &mut usize,
) -> Option<(Vec<f64>, usize)> {
    // From empty diagonal blocks: started from each block's own covariance
    // the projections stall far from the answer when a table's own
    // systematics outweigh what it shares (seen in the test below).
    let mut whole = c.to_vec();
    let mut last = f64::INFINITY;
    for round in 0..*rounds_left {
        *rounds_left -= 1;
        let (f, got) = positive_part(&whole, r, k, 0.0)?;
        if got < k {
            return None;
        }
        let residual = off_block_residual(&f, k, c, r, in_block);
        if residual <= tol {
            return Some((f, k));
        }
        // Linear convergence at a useless rate means the rank is too small.
        if round % 25 == 24 {
            if residual > 0.5 * last {
                return None;
            }
            last = residual;
        }
        for j in 0..r {
            for i in 0..r {
                whole[i + j * r] =
                    if in_block(i, j) { (0..k).map(|col| f[i + col * r] * f[j + col * r]).sum() } else { c[i + j * r] };
            }
        }
    }
    None
}

/// The largest `k` eigenpairs of the symmetric `m` (r × r) that are above
/// `floor`, as `U Λ^½` (r × k'), and k'.
fn positive_part(m: &[f64], r: usize, k: usize, floor: f64) -> Option<(Vec<f64>, usize)> {
    let eigen = MatRef::from_column_major_slice(m, r, r).self_adjoint_eigen(Side::Lower).ok()?;
    let (u, values) = (eigen.U(), eigen.S().column_vector());
    // Eigenvalues come in increasing order.
    let kept: Vec<usize> = (0..r).rev().take(k).filter(|&e| values[e] > floor).collect();
    let f = kept.iter().flat_map(|&e| (0..r).map(move |i| u[(i, e)] * values[e].sqrt())).collect();
    Some((f, kept.len()))
}

/// Largest |F Fᵀ − C| over entries between two blocks.
fn off_block_residual(f: &[f64], k: usize, c: &[f64], r: usize, in_block: &impl Fn(usize, usize) -> bool) -> f64 {
    let mut largest = 0.0f64;
    for j in 0..r {
        for i in j + 1..r {
            if !in_block(i, j) {
                let v: f64 = (0..k).map(|col| f[i + col * r] * f[j + col * r]).sum();
                largest = largest.max((v - c[i + j * r]).abs());
            }
        }
    }
    largest
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rounding of a printed file, as a symmetric matrix of entries uniform
    /// in ±half a unit: power iteration's bound is at or above the exact
    /// spectral norm and within the 1/0.9 it is raised by, where the
    /// Frobenius norm it replaces is some √N/2 times larger.
    #[test]
    fn the_power_bound_holds_the_spectral_norm_closely() {
        use rand::{Rng, SeedableRng};
        let n = 300;
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(9);
        let mut e = vec![0.0; n * n];
        for j in 0..n {
            for i in j..n {
                let v = rng.random_range(-0.5e-3..0.5e-3);
                e[i + j * n] = v;
                e[j + i * n] = v;
            }
        }
        let exact = {
            let eigen = MatRef::from_column_major_slice(&e, n, n).self_adjoint_eigen(Side::Lower).unwrap();
            let values = eigen.S().column_vector();
            (0..n).map(|i| -> f64 { values[i] }).map(f64::abs).fold(0.0, f64::max)
        };
        let bound = spectral_norm_bound(&e, n);
        let frobenius = e.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(bound >= exact && bound <= exact / POWER_REACH * (1.0 + 1e-12), "{bound} against {exact}");
        assert!(frobenius > 5.0 * bound, "{frobenius} against {bound}");
    }

    /// Tables with their own systematics and one normalization across all:
    /// the normalization is found as one column.
    #[test]
    fn a_normalization_across_tables_is_one_column() {
        let (tables, per) = (12, 5);
        let n = tables * per;
        let offsets: Vec<usize> = (0..=tables).map(|t| t * per).collect();
        let value = |i: usize| 1.0 + 0.1 * i as f64;
        let mut s = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let same = i / per == j / per;
                let own = if same { 0.05 * value(i) * 0.05 * value(j) * (1.0 + (i / per) as f64) } else { 0.0 };
                s[i + j * n] = own + 0.02 * value(i) * 0.02 * value(j);
            }
        }
        let (v, k, ()) = low_rank_across(&s, &offsets, 64, 0.0, |_, _| Some(())).unwrap();
        assert_eq!(k, 1);
        let tol = 1e-11 * s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for j in 0..n {
            for i in 0..n {
                if i / per != j / per {
                    assert!((v[i] * v[j] - s[i + j * n]).abs() < tol, "({i}, {j})");
                }
            }
        }
    }
}
