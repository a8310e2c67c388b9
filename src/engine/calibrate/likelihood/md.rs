//! The Kennedy–O'Hagan likelihood with one block per observable:
//!
//! `y_b - η_b(x, θ) ~ N(0, K_φb(x, x) + C_data,b [+ C_emu,b(θ)])`, "no MD"
//! being `K = 0`, `C_data,b` the errors² and any covariance given beyond them,
//! `C_emu,b` an emulator's predictive covariance. The blocks are independent
//! unless something links them (covariance entries between observables, an
//! emulator's covariance across its outputs); then the likelihood is one
//! Gaussian over all points (`joint`), with δ still one GP per observable.
//!
//! Scaling follows the paper: each observable is standardized by the mean and
//! population standard deviation of its measured values (so the discrepancy
//! hyperparameters are comparable across observables), while x is used as is
//! (x = t/1 s, or pT/1 GeV). The returned log-likelihood includes the Jacobian
//! of that standardization, so it is the density of the data in their own
//! units and evidences are comparable with any other analysis of the same data.

use super::block::ObservableBlock;
use super::form::{BlockForm, Form};
use super::joint::{add_lower_block, CrossEntry, JointLayout};
use super::structured::{self, Moving, Structure, LN_2PI};
use crate::base::config::BetweenObservables;
use crate::engine::gp::{copy_lower, gaussian_logpdf_factored, CholeskyWorkspace, DiscrepancyKernel};
use crate::engine::model::{ObservedData, Simulator};
use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

/// Per-thread scratch so that evaluations allocate nothing.
pub(super) struct Workspace {
    pub(super) chol: Vec<CholeskyWorkspace>,
    pub(super) eta: Vec<f64>,
    pub(super) resid: Vec<f64>,
    pub(super) xr: Vec<f64>,
    pub(super) corr: Vec<f64>,
    /// The joint covariance's factor and residuals (joint likelihoods only).
    joint_chol: Option<CholeskyWorkspace>,
    joint_resid: Vec<f64>,
    /// The θ-dependent part of the joint covariance at the last θs seen.
    joint_bases: Vec<JointBase>,
    clock: u64,
    /// Scratch of the structured joint evaluation (`structured`).
    pub(super) structured: Option<structured::Scratch>,
}

/// The joint covariance without δ (the data's and the model's parts) and the
/// residuals at one θ. A move of one observable's φ leaves θ unchanged, so
/// it reuses this and pays only for δ and the factorization: with an
/// emulator, its covariance across all points is most of an evaluation.
struct JointBase {
    theta: Vec<f64>,
    lower: Vec<f64>,
    resid: Vec<f64>,
    last_used: u64,
}

/// The current θ and a rejected proposal's: after a rejected θ move, the
/// next φ move is back at the current θ.
const JOINT_BASES: usize = 2;

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

thread_local! {
    static WORKSPACES: RefCell<Vec<(u64, Workspace)>> = const { RefCell::new(Vec::new()) };
}

/// Log-likelihood of the calibration parameters `[θ, φ_1, φ_2, …]`.
pub struct MdLikelihood {
    id: u64,
    pub simulator: Arc<dyn Simulator>,
    pub blocks: Vec<ObservableBlock>,
    pub kernel: Option<DiscrepancyKernel>,
    pub n_theta: usize,
    pub(super) log_jacobian: f64,
    /// The model adds its own predictive covariance (an emulator).
    model_covariance: bool,
    /// How an evaluation is done (`form`).
    pub form: Form,
    /// Factorizations of this likelihood's covariances that needed jitter.
    jitter_events: AtomicUsize,
    /// The data as a model may watch its χ², and the log-likelihood at
    /// χ² = 0 (`far`), made at first use.
    pub(super) observed: OnceLock<Option<(ObservedData, f64)>>,
}

impl MdLikelihood {
    /// How many of this likelihood's covariance matrices needed jitter to
    /// factorize: reported in the run's summary, so regularisation is never silent.
    pub fn jitter_events(&self) -> usize {
        self.jitter_events.load(Ordering::Relaxed)
    }

    pub(super) fn note_jitter(&self, jitter: f64, n: usize) {
        if jitter > 0.0 && self.jitter_events.fetch_add(1, Ordering::Relaxed) == 0 {
            crate::base::messages::note!(
                "warning: a covariance matrix ({n}x{n}) of the likelihood was not numerically positive definite; \
                 added jitter {jitter:.1e} (further events are counted in the run summary)"
            );
        }
    }

    /// The likelihood with independent observable blocks.
    pub fn new(simulator: Arc<dyn Simulator>, blocks: Vec<ObservableBlock>, kernel: Option<DiscrepancyKernel>) -> Self {
        Self::linked(simulator, blocks, kernel, BetweenObservables::Independent, &[])
    }

    /// The likelihood in the form `Form::choose` finds for these blocks, the
    /// data's entries between them (`across`) and `mode`.
    pub fn linked(
        simulator: Arc<dyn Simulator>,
        blocks: Vec<ObservableBlock>,
        kernel: Option<DiscrepancyKernel>,
        mode: BetweenObservables,
        across: &[CrossEntry],
    ) -> Self {
        let n_theta = simulator.parameter_names().len();
        let log_jacobian = -blocks.iter().map(|b| b.len() as f64 * b.scale.ln()).sum::<f64>();
        let model_covariance = simulator.has_model_covariance();
        let form = Form::choose(&blocks, across, mode, simulator.as_ref(), kernel);
        MdLikelihood {
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            simulator,
            blocks,
            kernel,
            n_theta,
            log_jacobian,
            model_covariance,
            jitter_events: AtomicUsize::new(0),
            observed: OnceLock::new(),
            form,
        }
    }

    /// This likelihood as one Gaussian over all points, with the data's
    /// entries between blocks `across` (and the model's covariance across
    /// observables, when it has one), in its cheapest exact form.
    pub fn joint(self, across: &[CrossEntry]) -> Self {
        Self::linked(self.simulator, self.blocks, self.kernel, BetweenObservables::Joint, across)
    }

    /// This likelihood with the dense factorization of the whole
    /// covariance, whatever its structure: the reference the structured
    /// evaluation is tested and benchmarked against.
    pub fn dense(mut self) -> Self {
        self.form = self.form.dense();
        // A new id: workspaces of the structured form must not be reused.
        self.id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
        self
    }

    /// The model adds its own predictive covariance (an emulator).
    pub fn has_model_covariance(&self) -> bool {
        self.model_covariance
    }

    /// The layout over all points, for the joint forms.
    pub fn layout(&self) -> Option<&JointLayout> {
        self.form.layout()
    }

    pub fn n_hyper(&self) -> usize {
        self.kernel.map(|k| k.n_hyper()).unwrap_or(0)
    }

    pub fn dim(&self) -> usize {
        self.n_theta + self.blocks.len() * self.n_hyper()
    }

    /// Parameter names: θ names, then `<observable>.<hyper>` per block.
    pub fn parameter_names(&self) -> Vec<String> {
        let mut names = self.simulator.parameter_names();
        if let Some(k) = self.kernel {
            for b in &self.blocks {
                for h in k.hyper_names() {
                    names.push(format!("{}.{}", b.name, h));
                }
            }
        }
        names
    }

    /// The discrepancy hyperparameters of block `b` within a parameter vector.
    pub fn hyper_of<'a>(&self, params: &'a [f64], b: usize) -> &'a [f64] {
        let nh = self.n_hyper();
        &params[self.n_theta + b * nh..self.n_theta + (b + 1) * nh]
    }

    fn new_workspace(&self) -> Workspace {
        let nmax = self.blocks.iter().map(|b| b.len()).max().unwrap_or(0);
        Workspace {
            chol: self.blocks.iter().map(|b| CholeskyWorkspace::new(b.len())).collect(),
            eta: vec![0.0; nmax],
            resid: vec![0.0; nmax],
            xr: vec![0.0; nmax],
            corr: vec![0.0; self.blocks.iter().map(|b| b.gram.n_unique()).max().unwrap_or(0)],
            joint_chol: match &self.form {
                Form::Dense(layout) => Some(CholeskyWorkspace::new(layout.len())),
                _ => None,
            },
            joint_resid: vec![0.0; self.layout().map_or(0, |j| j.len())],
            joint_bases: Vec::new(),
            clock: 0,
            structured: self.form.structure().map(structured::Scratch::new),
        }
    }

    /// Runs `f` with this thread's workspace for this likelihood.
    pub(super) fn with_workspace<R>(&self, f: impl FnOnce(&mut Workspace) -> R) -> R {
        WORKSPACES.with(|cell| {
            let mut list = cell.borrow_mut();
            let pos = match list.iter().position(|(id, _)| *id == self.id) {
                Some(p) => p,
                None => {
                    if list.len() >= 16 {
                        list.remove(0);
                    }
                    list.push((self.id, self.new_workspace()));
                    list.len() - 1
                }
            };
            f(&mut list[pos].1)
        })
    }

    pub fn log_likelihood(&self, params: &[f64]) -> f64 {
        self.with_workspace(|ws| {
            let value = match &self.form {
                Form::Blocks(_) => (0..self.blocks.len()).map(|b| self.block_log_likelihood(params, b, ws)).sum(),
                Form::Dense(layout) => self.dense_log_likelihood(layout, params, ws),
                Form::Structured(layout, structure) => self.structured_log_likelihood(structure, layout, params, ws),
            };
            self.log_jacobian + value
        })
    }

    /// The log-likelihood, with each observable block's term written to `terms`
    /// (the total is their sum plus the standardization's Jacobian).
    pub fn log_likelihood_terms(&self, params: &[f64], terms: &mut [f64]) -> f64 {
        self.with_workspace(|ws| {
            let mut total = self.log_jacobian;
            for (b, t) in terms.iter_mut().enumerate() {
                *t = self.block_log_likelihood(params, b, ws);
                total += *t;
            }
            total
        })
    }

    /// One observable block's term of the log-likelihood.
    pub fn log_likelihood_term(&self, params: &[f64], b: usize) -> f64 {
        self.with_workspace(|ws| self.block_log_likelihood(params, b, ws))
    }

    /// For the joint form: block `b`'s marginal, its points' Gaussian with
    /// their own covariance (δ_b, the data's and the model's within the
    /// block), which is the block form's term. A move of φ_b changes the
    /// joint likelihood mostly through it, at the cost of an n_b × n_b
    /// factorization instead of N × N. `None` for the block form (its terms
    /// are exact) and without δ.
    pub fn screening_term(&self, params: &[f64], b: usize) -> Option<f64> {
        (self.layout().is_some() && self.kernel.is_some())
            .then(|| self.with_workspace(|ws| self.block_log_likelihood(params, b, ws)))
    }

    /// The dense form's Gaussian over all points (without the Jacobian).
    fn dense_log_likelihood(&self, joint: &JointLayout, params: &[f64], ws: &mut Workspace) -> f64 {
        let mut chol = ws.joint_chol.take().expect("a joint likelihood's workspace has its factor");
        let mut resid = std::mem::take(&mut ws.joint_resid);
        self.fill_joint(joint, params, true, ws, &mut chol.factor, &mut resid);
        let total = match chol.factorize() {
            Ok(jitter) => {
                self.note_jitter(jitter, chol.n());
                gaussian_logpdf_factored(&chol, &mut resid)
            }
            Err(_) => f64::NEG_INFINITY,
        };
        ws.joint_chol = Some(chol);
        ws.joint_resid = resid;
        if total.is_nan() {
            f64::NEG_INFINITY
        } else {
            total
        }
    }

    /// The joint Gaussian by the covariance's structure (`structured`): per
    /// block, δ and the model's own covariance added to the block's data part.
    fn structured_log_likelihood(
        &self,
        structure: &Structure,
        joint: &JointLayout,
        params: &[f64],
        ws: &mut Workspace,
    ) -> f64 {
        let theta = &params[..self.n_theta];
        let Workspace { chol, eta, xr, corr, joint_resid: resid, structured: scratch, .. } = ws;
        let scratch = scratch.as_mut().expect("a structured likelihood's workspace has its scratch");
        self.fill_residuals(joint, theta, eta, resid);
        let fill = |b: usize, lower: &mut [f64]| self.fill_own(params, b, lower, xr, corr);
        let evaluated = match &structure.moving {
            Moving::Nothing(fixed) => return finite_or_neg_inf(structure.fixed_log_pdf(fixed, resid, scratch)),
            Moving::Blocks => structure.log_pdf(resid, scratch, chol, fill),
            Moving::BlocksAndModel(model) => {
                let ms = scratch.model.as_mut().expect("a structure with a model term has its scratch");
                let (points, inv_scales) = (&joint.points, &joint.inv_scales);
                self.simulator.joint_model_factors(points, inv_scales, theta, &mut ms.g, &mut ms.theta_weights);
                structure.log_pdf_with_model(model, resid, scratch, chol, fill)
            }
        };
        let total = match evaluated {
            Some((value, jitter)) => {
                self.note_jitter(jitter, joint.len());
                value
            }
            None => f64::NEG_INFINITY,
        };
        finite_or_neg_inf(total)
    }

    /// Standardized residuals of every point at θ, in the joint order.
    fn fill_residuals(&self, joint: &JointLayout, theta: &[f64], eta: &mut [f64], resid: &mut [f64]) {
        for (b, block) in self.blocks.iter().enumerate() {
            let n = block.len();
            self.simulator.predict(block.model_index, &block.x, theta, &mut eta[..n]);
            for (i, r) in resid[joint.rows(b)].iter_mut().enumerate() {
                *r = (block.y[i] - eta[i]) / block.scale;
            }
        }
    }

    /// Block b's covariance beyond the data (δ, the model's own) into `lower`.
    pub(super) fn fill_own(&self, params: &[f64], b: usize, lower: &mut [f64], xr: &mut [f64], corr: &mut [f64]) {
        let block = &self.blocks[b];
        let n = block.len();
        match self.kernel {
            Some(kernel) => block.gram.fill_lower(kernel, self.hyper_of(params, b), lower, &mut xr[..n], corr),
            None => lower.iter_mut().for_each(|v| *v = 0.0),
        }
        // A model covariance across observables is the structure's own term.
        if self.model_covariance && !self.layout().is_some_and(|j| j.model_spans) {
            let inv2 = 1.0 / (block.scale * block.scale);
            self.simulator.add_model_covariance(block.model_index, &block.x, &params[..self.n_theta], inv2, lower);
        }
    }

    /// The structured joint covariance factorized at `params` and the residuals,
    /// for summaries (allocates); `None` for the other forms or a failed factor.
    pub fn structured_system(&self, params: &[f64]) -> Option<(super::factored::Factored, Vec<f64>)> {
        let Form::Structured(joint, structure) = &self.form else { return None };
        let nmax = self.blocks.iter().map(|b| b.len()).max().unwrap_or(0);
        let (mut eta, mut resid) = (vec![0.0; nmax], vec![0.0; joint.len()]);
        self.fill_residuals(joint, &params[..self.n_theta], &mut eta, &mut resid);
        let mut xr = vec![0.0; nmax];
        let mut corr = vec![0.0; self.blocks.iter().map(|b| b.gram.n_unique()).max().unwrap_or(0)];
        let (mut g, mut theta_weights) = (vec![0.0; joint.len()], Vec::new());
        if let Some(model) = structure.model() {
            theta_weights.resize(model.weighted.len(), 0.0);
            let theta = &params[..self.n_theta];
            self.simulator.joint_model_factors(&joint.points, &joint.inv_scales, theta, &mut g, &mut theta_weights);
        }
        let factors = structure.model().map(|_| (g.as_slice(), theta_weights.as_slice()));
        let factored = structure.factor_at(factors, |b, lower| self.fill_own(params, b, lower, &mut xr, &mut corr))?;
        Some((factored, resid))
    }

    /// The joint covariance's lower triangle (column-major N × N) and the
    /// standardized residuals at `params`: the θ-dependent base (see
    /// `joint_base`) plus each block's δ (`with_delta`; then `params` holds φ
    /// after θ).
    fn fill_joint(
        &self,
        joint: &JointLayout,
        params: &[f64],
        with_delta: bool,
        ws: &mut Workspace,
        lower: &mut [f64],
        resid: &mut [f64],
    ) {
        let base = self.joint_base(joint, &params[..self.n_theta], ws);
        copy_lower(&ws.joint_bases[base].lower, lower, joint.len());
        resid.copy_from_slice(&ws.joint_bases[base].resid);
        let Some(kernel) = self.kernel.filter(|_| with_delta) else { return };
        for (b, block) in self.blocks.iter().enumerate() {
            let n = block.len();
            let factor = &mut ws.chol[b].factor;
            block.gram.fill_lower(kernel, self.hyper_of(params, b), factor, &mut ws.xr[..n], &mut ws.corr);
            add_lower_block(factor, n, joint.offsets[b], lower, joint.len());
        }
    }

    /// Index into `ws.joint_bases` of the base at θ, computed unless cached:
    /// the data's covariance, the model's own covariance (within each block,
    /// or across observables) and the standardized residuals.
    fn joint_base(&self, joint: &JointLayout, theta: &[f64], ws: &mut Workspace) -> usize {
        ws.clock += 1;
        if let Some(i) = ws.joint_bases.iter().position(|b| b.theta.as_slice() == theta) {
            ws.joint_bases[i].last_used = ws.clock;
            return i;
        }
        let n_all = joint.len();
        let slot = if ws.joint_bases.len() < JOINT_BASES {
            ws.joint_bases.push(JointBase {
                theta: Vec::new(),
                lower: vec![0.0; n_all * n_all],
                resid: vec![0.0; n_all],
                last_used: 0,
            });
            ws.joint_bases.len() - 1
        } else {
            (0..ws.joint_bases.len()).min_by_key(|&i| ws.joint_bases[i].last_used).unwrap_or(0)
        };
        let mut base = std::mem::replace(
            &mut ws.joint_bases[slot],
            JointBase { theta: Vec::new(), lower: Vec::new(), resid: Vec::new(), last_used: 0 },
        );
        base.theta.clear();
        base.theta.extend_from_slice(theta);
        base.last_used = ws.clock;
        base.lower.copy_from_slice(&joint.data);
        let own_model = self.model_covariance && !joint.model_spans;
        for (b, block) in self.blocks.iter().enumerate() {
            let n = block.len();
            let at = joint.offsets[b];
            self.simulator.predict(block.model_index, &block.x, theta, &mut ws.eta[..n]);
            for i in 0..n {
                base.resid[at + i] = (block.y[i] - ws.eta[i]) / block.scale;
            }
            if own_model {
                let factor = &mut ws.chol[b].factor;
                factor.iter_mut().for_each(|v| *v = 0.0);
                self.simulator.add_model_covariance(
                    block.model_index,
                    &block.x,
                    theta,
                    1.0 / (block.scale * block.scale),
                    factor,
                );
                add_lower_block(factor, n, at, &mut base.lower, n_all);
            }
        }
        if joint.model_spans {
            self.simulator.add_joint_model_covariance(&joint.points, &joint.inv_scales, theta, &mut base.lower);
        }
        ws.joint_bases[slot] = base;
        slot
    }

    /// The joint covariance (lower triangle, standardized) and residuals at
    /// `params`, for summaries (allocates); `None` for the block form.
    pub fn joint_system(&self, params: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
        self.joint_system_with(params, true)
    }

    /// As `joint_system` for the model alone (no δ) at θ.
    pub fn joint_model_system(&self, theta: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
        self.joint_system_with(theta, false)
    }

    fn joint_system_with(&self, params: &[f64], with_delta: bool) -> Option<(Vec<f64>, Vec<f64>)> {
        let joint = self.layout()?;
        let n = joint.len();
        let (mut lower, mut resid) = (vec![0.0; n * n], vec![0.0; n]);
        self.with_workspace(|ws| self.fill_joint(joint, params, with_delta, ws, &mut lower, &mut resid));
        Some((lower, resid))
    }

    fn block_log_likelihood(&self, params: &[f64], b: usize, ws: &mut Workspace) -> f64 {
        let theta = &params[..self.n_theta];
        let block = &self.blocks[b];
        let n = block.len();
        let eta = &mut ws.eta[..n];
        self.simulator.predict(block.model_index, &block.x, theta, eta);
        let resid = &mut ws.resid[..n];
        let inv_scale = 1.0 / block.scale;
        for i in 0..n {
            resid[i] = (block.y[i] - eta[i]) * inv_scale;
        }
        let mut total = 0.0;
        let own_form = match &self.form {
            Form::Blocks(forms) => &forms[b],
            // A joint form's block marginal (its screen): δ moves.
            _ => &BlockForm::Moving,
        };
        if let BlockForm::Fixed(chol) = own_form {
            total = gaussian_logpdf_factored(chol, resid);
        } else if let BlockForm::Diagonal = own_form {
            for i in 0..n {
                let s = block.error[i] * inv_scale;
                let z = resid[i] / s;
                total += -0.5 * (z * z + 2.0 * s.ln() + LN_2PI);
            }
        } else {
            // The covariance is filled in place, and filled again only for a
            // retry with jitter (no copy of it per evaluation).
            let hyper = self.hyper_of(params, b);
            let (xr, corr) = (&mut ws.xr[..n], &mut ws.corr);
            let mut fill = |a: &mut [f64]| {
                match self.kernel {
                    Some(kernel) => block.gram.fill_lower(kernel, hyper, a, xr, corr),
                    None => a.iter_mut().for_each(|v| *v = 0.0),
                }
                if self.model_covariance {
                    self.simulator.add_model_covariance(block.model_index, &block.x, theta, inv_scale * inv_scale, a);
                }
                block.add_data_covariance(inv_scale * inv_scale, a);
            };
            let chol = &mut ws.chol[b];
            fill(&mut chol.factor);
            match chol.factorize_refilling(fill) {
                Ok(jitter) => self.note_jitter(jitter, chol.n()),
                Err(_) => return f64::NEG_INFINITY,
            }
            total = gaussian_logpdf_factored(chol, resid);
        }
        if total.is_nan() {
            f64::NEG_INFINITY
        } else {
            total
        }
    }
}

/// NaN (an overflow in a factorization) as zero likelihood.
fn finite_or_neg_inf(total: f64) -> f64 {
    if total.is_nan() {
        f64::NEG_INFINITY
    } else {
        total
    }
}
