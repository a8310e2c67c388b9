//! A structured joint likelihood as a sum over observables plus a small
//! correction: what lets a sampler move one observable's φ at the cost of
//! that observable's block.
//!
//! With the covariance `blockdiag_b(B_b) + V Vᵀ` (`structured`), every
//! quantity of an evaluation is a sum over blocks of small statistics:
//! `log det B_b`, `‖z_b‖²`, `a_b = W_bᵀ z_b` (r values) and
//! `H_b = W_bᵀ W_b` (r × r), with `z_b = L_b⁻¹ r_b` and `W_b = L_b⁻¹ V_b`.
//! The log-likelihood is then
//! `−½(Σ‖z_b‖² − ‖L_M⁻¹ Σa_b‖² + Σ log det B_b + log det M + N ln 2π)`
//! with `M = I + Σ H_b`. A move of φ_b changes block
//! b's statistics only; keeping every block's, a sampler pays one n_b × n_b
//! factorization and an r × r one for it, instead of all blocks, and the
//! value is exact: the same operations in the same order as a whole
//! evaluation, so equal to it bit for bit.
//!
//! Only for a covariance whose low-rank term does not depend on θ (the
//! data's systematics); with a model term across observables (an
//! emulator's) the term's columns follow θ and the statistics would be as
//! large as the term, so those likelihoods keep the screened moves.

use super::form::Form;
use super::md::{MdLikelihood, Workspace};
use super::structured::{BlockPart, Moving, Structure};
use crate::engine::calibrate::sampler::target::TermStatistics;

/// At most this many values per particle (all blocks' statistics): the
/// sampler keeps them for every particle.
const MAX_VALUES: usize = 4096;

impl Structure {
    /// Values per block: `log det B_b`, `‖z_b‖²`, `a_b`, `H_b` (full r × r,
    /// lower triangle used).
    pub fn stats_width(&self) -> usize {
        2 + self.rank + self.rank * self.rank
    }
}

/// Values per observable that a sampler can keep to move one observable's
/// φ at one block's cost: the structured joint form where only the blocks
/// move (δ; nothing across observables that follows θ), and at most
/// `MAX_VALUES` in all; 0 otherwise.
pub(super) fn width_of(lik: &MdLikelihood) -> usize {
    match (&lik.form, lik.kernel) {
        (Form::Structured(_, s), Some(_))
            if matches!(s.moving, Moving::Blocks) && s.stats_width() * lik.blocks.len() <= MAX_VALUES =>
        {
            s.stats_width()
        }
        _ => 0,
    }
}

impl TermStatistics for MdLikelihood {
    fn width(&self) -> usize {
        width_of(self)
    }

    /// Every block's statistics at `params` into `stats` (blocks × `width`),
    /// and the log-likelihood from them (the whole evaluation, `stats`
    /// untouched, where there are none to keep).
    fn log_likelihood_stats(&self, params: &[f64], stats: &mut [f64]) -> f64 {
        let width = width_of(self);
        if width == 0 {
            return self.log_likelihood(params);
        }
        for (b, out) in stats.chunks_mut(width).enumerate() {
            block_stats(self, params, b, out);
        }
        combine_stats(self, stats)
    }

    /// Block `b`'s statistics recomputed at `params` in `stats` (every
    /// block's), and the log-likelihood from them (as
    /// `log_likelihood_stats` where there are none to keep).
    fn update_term_stats(&self, params: &[f64], b: usize, stats: &mut [f64]) -> f64 {
        let width = width_of(self);
        if width == 0 {
            return self.log_likelihood(params);
        }
        block_stats(self, params, b, &mut stats[b * width..(b + 1) * width]);
        combine_stats(self, stats)
    }
}

/// Block b's statistics into `out`; `log det B_b` is NaN when the block
/// is not positive definite even with jitter (the likelihood is then 0).
fn block_stats(lik: &MdLikelihood, params: &[f64], b: usize, out: &mut [f64]) {
    let structure = lik.form.structure().expect("statistics need the structured form");
    let (block, r) = (&lik.blocks[b], structure.rank);
    let n = block.len();
    lik.with_workspace(|ws| {
        let Workspace { chol, eta, resid, xr, corr, structured: scratch, .. } = ws;
        let scratch = scratch.as_mut().expect("a structured likelihood's workspace has its scratch");
        lik.simulator.predict(block.model_index, &block.x, &params[..lik.n_theta], &mut eta[..n]);
        for ((z, y), e) in resid[..n].iter_mut().zip(&block.y).zip(&eta[..n]) {
            *z = (y - e) / block.scale;
        }
        out.iter_mut().for_each(|v| *v = 0.0);
        let (head, rest) = out.split_at_mut(2);
        let (a, h) = rest.split_at_mut(r);
        let part = &mut BlockPart { chol: &mut chol[b], z: &mut resid[..n], w: &mut scratch.w[..n * r] };
        let mut fill = |b: usize, lower: &mut [f64]| lik.fill_own(params, b, lower, xr, corr);
        match structure.add_block(b, part, &mut fill, a, h) {
            Some(jitter) => {
                lik.note_jitter(jitter, n);
                head[0] = part.chol.log_det();
                head[1] = part.z.iter().map(|v| v * v).sum::<f64>();
            }
            None => head[0] = f64::NAN,
        }
    });
}

/// The log-likelihood from every block's statistics (summed in block
/// order, as a whole evaluation sums them).
fn combine_stats(lik: &MdLikelihood, stats: &[f64]) -> f64 {
    let structure = lik.form.structure().expect("statistics need the structured form");
    let (r, width) = (structure.rank, structure.stats_width());
    let n_points: usize = lik.blocks.iter().map(|b| b.len()).sum();
    lik.with_workspace(|ws| {
        let scratch = ws.structured.as_mut().expect("a structured likelihood's workspace has its scratch");
        scratch.capacitance.factor.iter_mut().for_each(|v| *v = 0.0);
        scratch.c.iter_mut().for_each(|v| *v = 0.0);
        let (mut log_det, mut quad) = (0.0, 0.0);
        for s in stats.chunks(width) {
            log_det += s[0];
            quad += s[1];
            scratch.c.iter_mut().zip(&s[2..2 + r]).for_each(|(c, a)| *c += a);
            scratch.capacitance.factor.iter_mut().zip(&s[2 + r..]).for_each(|(m, h)| *m += h);
        }
        if !log_det.is_finite() {
            return f64::NEG_INFINITY;
        }
        match structure.finish(log_det, quad, &mut scratch.c, &mut scratch.capacitance, n_points) {
            Some(v) if v.is_finite() => lik.log_jacobian + v,
            _ => f64::NEG_INFINITY,
        }
    })
}
