//! The last phase of the maximin Latin hypercube: column swaps aimed at the
//! closest pair. The φ_p criterion the evolutionary phase minimizes
//! (`design::maximin_lhs`) is a smooth stand-in for the minimum distance
//! and stops improving it long before the design is locally maximin; here
//! each proposal swaps one coordinate of a point of the closest pair with
//! another point's, kept only when the distances of the two points moved do
//! not fall below what they were (then φ_p must drop) or rise above it. A
//! swap within a column keeps the Latin property, and the minimum distance
//! never decreases (Morris & Mitchell 1995 order designs the same way:
//! minimum distance first, then how many pairs are at it).

use rand::Rng;

const P: i32 = 50;

/// Squared distances of a row-major n × d design, kept with each point's
/// nearest-neighbour distance so the closest pair is found in O(n).
struct Distances {
    n: usize,
    d: usize,
    sq: Vec<f64>,
    nearest: Vec<f64>,
}

impl Distances {
    fn new(x: &[f64], d: usize) -> Self {
        let n = x.len() / d;
        let mut sq = vec![f64::INFINITY; n * n];
        for i in 0..n {
            for j in i + 1..n {
                let v = sq_dist(x, d, i, j);
                sq[i * n + j] = v;
                sq[j * n + i] = v;
            }
        }
        let mut this = Distances { n, d, sq, nearest: vec![0.0; n] };
        (0..n).for_each(|i| this.refresh(i));
        this
    }

    fn refresh(&mut self, i: usize) {
        self.nearest[i] = self.sq[i * self.n..(i + 1) * self.n].iter().copied().fold(f64::INFINITY, f64::min);
    }

    /// A point of the closest pair, chosen at random between the two.
    fn critical(&self, rng: &mut impl Rng) -> usize {
        let a = (0..self.n).min_by(|&p, &q| self.nearest[p].total_cmp(&self.nearest[q])).unwrap_or(0);
        let row = &self.sq[a * self.n..(a + 1) * self.n];
        let b = (0..self.n).min_by(|&p, &q| row[p].total_cmp(&row[q])).unwrap_or(0);
        if rng.random::<bool>() {
            a
        } else {
            b
        }
    }

    /// Replaces the distances of points i and j with `new_i`, `new_j`.
    fn accept(&mut self, i: usize, j: usize, new_i: &[f64], new_j: &[f64]) {
        let n = self.n;
        for m in (0..n).filter(|&m| m != i && m != j) {
            let (old_i, old_j) = (self.sq[m * n + i], self.sq[m * n + j]);
            for (p, v) in [(i, new_i[m]), (j, new_j[m])] {
                self.sq[p * n + m] = v;
                self.sq[m * n + p] = v;
            }
            let lost = old_i == self.nearest[m] || old_j == self.nearest[m];
            if lost {
                self.refresh(m);
            } else {
                self.nearest[m] = self.nearest[m].min(new_i[m]).min(new_j[m]);
            }
        }
        self.refresh(i);
        self.refresh(j);
    }
}

fn sq_dist(x: &[f64], d: usize, i: usize, j: usize) -> f64 {
    (0..d).map(|k| (x[i * d + k] - x[j * d + k]).powi(2)).sum()
}

/// Raises the design's minimum distance by up to `proposals` swaps at its
/// closest pair (see the module's comment); `x` stays a Latin hypercube.
pub fn refine_closest_pairs(x: &mut [f64], d: usize, proposals: usize, rng: &mut impl Rng) {
    let n = x.len() / d;
    if n < 3 || d == 0 {
        return;
    }
    let mut dist = Distances::new(x, d);
    // φ_p's terms at the typical spacing, so that d^-p stays in range.
    let scale = (n as f64).powf(1.0 / d as f64);
    let phi = |sq: f64| (sq.sqrt() * scale).max(1e-12).powi(-P);
    let (mut new_i, mut new_j) = (vec![f64::INFINITY; n], vec![f64::INFINITY; n]);
    for _ in 0..proposals {
        let i = dist.critical(rng);
        let mut j = rng.random_range(0..n - 1);
        if j >= i {
            j += 1;
        }
        let k = rng.random_range(0..dist.d);
        x.swap(i * d + k, j * d + k);
        let (mut local, mut change) = (dist.sq[i * n + j], 0.0);
        for m in (0..n).filter(|&m| m != i && m != j) {
            new_i[m] = sq_dist(x, d, i, m);
            new_j[m] = sq_dist(x, d, j, m);
            local = local.min(new_i[m]).min(new_j[m]);
            change += phi(new_i[m]) - phi(dist.sq[i * n + m]) + phi(new_j[m]) - phi(dist.sq[j * n + m]);
        }
        let before = dist.nearest[i].min(dist.nearest[j]);
        if local > before || (local >= before && change < 0.0) {
            dist.accept(i, j, &new_i, &new_j);
        } else {
            x.swap(i * d + k, j * d + k);
        }
    }
}
