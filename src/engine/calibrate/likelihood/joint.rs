//! The likelihood as one Gaussian over every measured point, for when the
//! observable blocks are not independent: measurements correlated across
//! observables (several spectra counted from the same events), or a model
//! whose own covariance links them (an emulator's principal components are
//! shared by all of its outputs).
//!
//! The discrepancies stay one GP per observable, so δ fills only the diagonal
//! blocks of the covariance; the data's and the model's covariances fill the
//! rest. The cost is one factorization of N × N (N points in all) per
//! evaluation instead of one per observable block, and a move of one
//! observable's hyperparameters costs a whole evaluation, paid only when the
//! block's own marginal does not already reject it (the sampler's delayed
//! acceptance, `MdLikelihood::screening_term`).

use super::block::ObservableBlock;

/// A covariance entry between points of two different observable blocks.
#[derive(Clone, Debug, PartialEq)]
pub struct CrossEntry {
    pub block_a: usize,
    pub index_a: usize,
    pub block_b: usize,
    pub index_b: usize,
    /// In the measurements' units squared.
    pub covariance: f64,
    /// Half a unit in its last printed digit (`CovarianceEntry::rounding`).
    pub rounding: f64,
}

/// Where each block's points sit in the joint covariance, and the data's part of it.
#[derive(Clone, Debug)]
pub struct JointLayout {
    /// Block b's points are rows `offsets[b]..offsets[b + 1]`.
    pub offsets: Vec<usize>,
    /// Per point: the model's observable index and x, for the model's covariance.
    pub points: Vec<(usize, f64)>,
    /// Per point: 1 / its block's standardization scale.
    pub inv_scales: Vec<f64>,
    /// The data's covariance over all points, standardized (errors², each
    /// block's own entries, the entries between blocks), lower triangle,
    /// column-major N × N.
    pub data: Vec<f64>,
    /// How many data entries link two observables.
    pub cross_entries: usize,
    /// Whether the model's own covariance links the observables (added per evaluation).
    pub model_spans: bool,
    /// The largest rounding of an entry between blocks, standardized: the
    /// structure across blocks need match the data only to it.
    pub rounding_across: f64,
}

impl JointLayout {
    pub fn new(blocks: &[ObservableBlock], across: &[CrossEntry], model_spans: bool) -> Self {
        let mut offsets = vec![0];
        for b in blocks {
            offsets.push(offsets.last().unwrap() + b.len());
        }
        let n = *offsets.last().unwrap();
        let points = blocks.iter().flat_map(|b| b.x.iter().map(move |&x| (b.model_index, x))).collect();
        let inv_scales: Vec<f64> = blocks.iter().flat_map(|b| std::iter::repeat_n(1.0 / b.scale, b.len())).collect();
        let mut data = vec![0.0; n * n];
        for (b, block) in blocks.iter().enumerate() {
            let nb = block.len();
            let mut own = vec![0.0; nb * nb];
            block.add_data_covariance(1.0 / (block.scale * block.scale), &mut own);
            add_lower_block(&own, nb, offsets[b], &mut data, n);
        }
        let mut rounding_across = 0.0f64;
        for e in across {
            let (i, j) = (offsets[e.block_a] + e.index_a, offsets[e.block_b] + e.index_b);
            let (row, col) = if i >= j { (i, j) } else { (j, i) };
            data[row + col * n] += e.covariance * inv_scales[i] * inv_scales[j];
            rounding_across = rounding_across.max(e.rounding * inv_scales[i] * inv_scales[j]);
        }
        JointLayout { offsets, points, inv_scales, data, cross_entries: across.len(), model_spans, rounding_across }
    }

    /// N, the number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Block b's rows.
    pub fn rows(&self, b: usize) -> std::ops::Range<usize> {
        self.offsets[b]..self.offsets[b + 1]
    }
}

/// Adds the lower triangle of `block` (column-major nb × nb) to `whole`
/// (column-major n × n) with its corner at (`at`, `at`).
pub fn add_lower_block(block: &[f64], nb: usize, at: usize, whole: &mut [f64], n: usize) {
    for j in 0..nb {
        for i in j..nb {
            whole[(at + i) + (at + j) * n] += block[i + j * nb];
        }
    }
}
