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
