//! The form an evaluation of the likelihood takes, chosen once when the
//! likelihood is built ([`Form::choose`]) and evaluated in one `match`
//! (`MdLikelihood::log_likelihood`). Every form is exact: they differ in
//! cost only, and in which moves a sampler may make cheaply.

use super::block::ObservableBlock;
use super::joint::{CrossEntry, JointLayout};
use super::structured::{Moving, Structure};
use crate::base::config::BetweenObservables;
use crate::engine::gp::{CholeskyWorkspace, DiscrepancyKernel};
use crate::engine::model::Simulator;

/// How the likelihood's Gaussian is evaluated.
pub enum Form {
    /// The observables independent: one Gaussian per observable block, each
    /// in its own form.
    Blocks(Vec<BlockForm>),
    /// One Gaussian over all N points, its covariance filled and factorized
    /// whole (N × N) at every evaluation.
    Dense(JointLayout),
    /// One Gaussian over all N points by its covariance's structure: each
    /// block's own part plus a low-rank term across blocks (`structured`),
    /// what moves with the parameters said by the structure's [`Moving`].
    Structured(JointLayout, Box<Structure>),
}

/// How one independent observable block is evaluated.
pub enum BlockForm {
    /// Nothing moves with the parameters (no δ, no model covariance) and
    /// the data's covariance has entries beyond the errors: factorized once.
    Fixed(CholeskyWorkspace),
    /// Nothing moves and the data are errors alone: a product of normals.
    Diagonal,
    /// δ or the model's own covariance moves: filled and factorized at every
    /// evaluation (as is a fixed covariance that needs jitter).
    Moving,
}

impl Form {
    /// The cheapest exact form, and why:
    /// - the blocks stay independent unless asked to be joint, or `auto`
    ///   finds something linking two observables (covariance entries
    ///   between them, a model covariance across its outputs);
    /// - a joint covariance is structured when its part across blocks is
    ///   low-rank (a systematic shared by many points), and dense otherwise;
    /// - with an emulator's covariance across observables, structured only
    ///   where that costs fewer operations than the dense factorization
    ///   (an emulator trained on many runs that predicts few points is
    ///   cheaper dense), and dense where the model gives no low-rank form.
    pub fn choose(
        blocks: &[ObservableBlock],
        across: &[CrossEntry],
        mode: BetweenObservables,
        simulator: &dyn Simulator,
        kernel: Option<DiscrepancyKernel>,
    ) -> Form {
        let model_covariance = simulator.has_model_covariance();
        let spans = model_covariance && simulator.model_covariance_spans_observables();
        let joint = match mode {
            BetweenObservables::Joint => true,
            BetweenObservables::Independent => false,
            BetweenObservables::Auto => blocks.len() > 1 && (!across.is_empty() || spans),
        };
        let fixed = kernel.is_none() && !model_covariance;
        if !joint {
            return Form::Blocks(blocks.iter().map(|b| BlockForm::choose(b, fixed)).collect());
        }
        let layout = JointLayout::new(blocks, across, spans);
        let structure = match spans.then(|| simulator.joint_model_low_rank(&layout.points, &layout.offsets)) {
            Some(None) => None,
            Some(model) => Structure::find(&layout, blocks, fixed, model).filter(|s| s.cheaper_than_dense()),
            None => Structure::find(&layout, blocks, fixed, None),
        };
        match structure {
            Some(structure) => Form::Structured(layout, Box::new(structure)),
            None => Form::Dense(layout),
        }
    }

    /// The same likelihood factorized whole: the reference a structured
    /// evaluation is tested and benchmarked against.
    pub fn dense(self) -> Form {
        match self {
            Form::Structured(layout, _) => Form::Dense(layout),
            other => other,
        }
    }

    /// The layout over all points, for the joint forms.
    pub fn layout(&self) -> Option<&JointLayout> {
        match self {
            Form::Blocks(_) => None,
            Form::Dense(layout) | Form::Structured(layout, _) => Some(layout),
        }
    }

    pub fn structure(&self) -> Option<&Structure> {
        match self {
            Form::Structured(_, structure) => Some(structure),
            _ => None,
        }
    }

    /// A short name for summaries and benchmarks.
    pub fn label(&self) -> String {
        match self {
            Form::Blocks(_) => "independent blocks".into(),
            Form::Dense(layout) => format!("joint, dense ({} points)", layout.len()),
            Form::Structured(layout, s) => {
                let moving = match &s.moving {
                    Moving::Nothing(_) => "factorized once".to_string(),
                    Moving::Blocks => "blocks move".to_string(),
                    Moving::BlocksAndModel(m) => format!("blocks and a rank-{} model term move", m.rank),
                };
                format!("joint, structured ({} points, rank {}, {moving})", layout.len(), s.rank)
            }
        }
    }
}

impl BlockForm {
    fn choose(block: &ObservableBlock, fixed: bool) -> BlockForm {
        if !fixed {
            return BlockForm::Moving;
        }
        if block.diagonal_data() {
            return BlockForm::Diagonal;
        }
        // A covariance that needs jitter to factorize is refactorized with it
        // at every evaluation, and the jitter reported.
        block.fixed_factor().map_or(BlockForm::Moving, BlockForm::Fixed)
    }
}

/// One test per form: what `Form::choose` picks, and why.
#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::artifacts::Measurement;
    use crate::engine::calibrate::likelihood::data_covariance::{attach, test_support::*};
    use std::path::Path;

    /// `a` and `b` at `m` points each, errors 0.1, and the covariance
    /// `entries` gives (lines numbered from 2).
    fn with_entries(
        m: usize,
        entries: &[(usize, usize, usize, usize, f64)],
    ) -> (Vec<ObservableBlock>, Vec<CrossEntry>) {
        let names = ["a", "b"];
        let data: Vec<Measurement> =
            names.iter().flat_map(|o| (0..m).map(move |i| Measurement::new(o, i as f64, 1.0, 0.1))).collect();
        let rows: Vec<_> = entries
            .iter()
            .enumerate()
            .map(|(k, &(oa, xa, ob, xb, c))| entry(names[oa], xa as f64, names[ob], xb as f64, c, k + 2))
            .collect();
        let mut b = blocks(&data);
        let across = attach(&mut b, &rows, &data, Path::new("cov.csv"), Path::new("data.csv")).unwrap();
        (b, across)
    }

    /// A systematic of sd 0.05 shared by every point of both observables.
    fn shared_systematic(m: usize) -> Vec<(usize, usize, usize, usize, f64)> {
        let points: Vec<(usize, usize)> = (0..2).flat_map(|o| (0..m).map(move |i| (o, i))).collect();
        let mut entries = Vec::new();
        for (k, &(oa, xa)) in points.iter().enumerate() {
            for &(ob, xb) in &points[..=k] {
                entries.push((oa, xa, ob, xb, 0.0025));
            }
        }
        entries
    }

    #[test]
    fn unlinked_observables_are_independent_blocks_each_in_its_cheapest_form() {
        // A covariance within a, none within b, nothing between them.
        let (blocks, across) = with_entries(2, &[(0, 0, 0, 1, 0.004)]);
        assert!(across.is_empty());
        let form = Form::choose(&blocks, &across, BetweenObservables::Auto, &Line, None);
        let Form::Blocks(each) = &form else { panic!("{}", form.label()) };
        assert!(matches!(each[..], [BlockForm::Fixed(_), BlockForm::Diagonal]));
        // With δ the covariance moves with the parameters in every block.
        let form = Form::choose(&blocks, &across, BetweenObservables::Auto, &Line, Some(DiscrepancyKernel::KernelII));
        let Form::Blocks(each) = &form else { panic!("{}", form.label()) };
        assert!(matches!(each[..], [BlockForm::Moving, BlockForm::Moving]));
        // Asked to be joint, they are one Gaussian.
        let form = Form::choose(&blocks, &across, BetweenObservables::Joint, &Line, None);
        assert!(form.layout().is_some(), "{}", form.label());
    }

    #[test]
    fn a_few_points_linked_across_observables_are_one_dense_gaussian() {
        // Below eight points a structure saves nothing: the whole covariance is factorized.
        let (blocks, across) = with_entries(2, &[(0, 0, 1, 0, 0.003)]);
        assert_eq!(across.len(), 1);
        let form = Form::choose(&blocks, &across, BetweenObservables::Auto, &Line, None);
        assert!(matches!(form, Form::Dense(_)), "{}", form.label());
        // Told to keep them independent, the entry between them is left out.
        let form = Form::choose(&blocks, &across, BetweenObservables::Independent, &Line, None);
        assert!(matches!(form, Form::Blocks(_)), "{}", form.label());
    }

    #[test]
    fn a_systematic_shared_across_observables_is_structured_at_rank_one() {
        let (blocks, across) = with_entries(6, &shared_systematic(6));
        let form = Form::choose(&blocks, &across, BetweenObservables::Auto, &Line, None);
        let Form::Structured(layout, structure) = &form else { panic!("{}", form.label()) };
        assert_eq!((layout.len(), structure.rank), (12, 1));
        // Nothing moves without δ: factorized once. With δ, the blocks move.
        assert!(matches!(structure.moving, Moving::Nothing(_)));
        let form = Form::choose(&blocks, &across, BetweenObservables::Auto, &Line, Some(DiscrepancyKernel::KernelI));
        let Some(structure) = form.structure() else { panic!("{}", form.label()) };
        assert!(matches!(structure.moving, Moving::Blocks));
        // The dense form of the same likelihood is its reference.
        assert!(matches!(form.dense(), Form::Dense(_)));
    }
}
