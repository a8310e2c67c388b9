//! Discovery for an emulated model: the simulator cannot be changed here,
//! so the search is over corrections of its output, the physics of the
//! measurement (`corrections.toml`, data: an offset, a gain, a loss growing
//! as the square of the signal, a saturating counting loss). Each is fitted
//! with θ by least squares through the emulator's mean, its residuals
//! weighed by the data's covariance plus the emulator's predictive
//! covariance at the model's best fit (`model::fit`), and ranked by ΔBIC;
//! the best are proposed as `correction` candidates and judged, with the
//! emulator's covariance at every θ, by full calibration.

use super::correction::CorrectedModel;
use crate::base::config::ParamSpec;
use crate::engine::gp::CholeskyWorkspace;
use crate::engine::model::fit::{Fitted, LeastSquares};
use crate::engine::model::prior::FormPrior;
use crate::engine::model::{CandidateModel, Discoverer, Proposal, Screening, ScreeningBlock, ScreeningData, Simulator};
use anyhow::{anyhow, Result};
use std::collections::BTreeMap;
use std::sync::Arc;

const FORMS: &str = include_str!("corrections.toml");
/// How many screened corrections go on to full calibration.
const PROPOSALS: usize = 3;

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Forms {
    corrections: Vec<Form>,
}

/// A correction as written: `{y}` stands for the observable, `{c}` for its
/// one parameter, whose range is `min`..`max` times `ymax^power` (the
/// observable's largest |y| over the data).
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Form {
    name: String,
    form: String,
    meaning: String,
    min: f64,
    max: f64,
    #[serde(default)]
    power: i32,
    /// The form's size for the prior over forms.
    operations: usize,
}

pub struct EmulatedDiscoverer {
    pub model: Arc<dyn Simulator>,
}

struct Screened {
    form: Form,
    observable: String,
    /// The correction's parameter name, and the correction with it put in.
    parameter: String,
    correction: String,
    spec: ParamSpec,
    simulator: Arc<dyn Simulator>,
    fitted: Fitted,
}

impl Discoverer for EmulatedDiscoverer {
    fn screen(&self, data: &ScreeningData) -> Result<Screening> {
        let forms: Forms = toml::from_str(FORMS).map_err(|e| anyhow!("the bundled corrections: {e}"))?;
        let mean_only = LeastSquares { blocks: &data.blocks, model: self.model.as_ref(), bounds: data.bounds.clone() };
        let first = mean_only
            .fit(&data.theta)
            .ok_or_else(|| anyhow!("discover: the emulated model cannot be fitted at its median"))?;
        // Residuals are weighed by the data's covariance plus the emulator's
        // at that fit's θ: where the emulator is unsure, a correction's
        // gain counts for less (held fixed over the screening's fits).
        let theta = &first.phi[..data.theta.len()];
        let data = &ScreeningData {
            blocks: self.with_emulator_covariance(data, theta)?,
            theta: theta.to_vec(),
            bounds: data.bounds.clone(),
        };
        let base = LeastSquares { blocks: &data.blocks, model: self.model.as_ref(), bounds: data.bounds.clone() };
        let base_fit = base
            .fit(&data.theta)
            .ok_or_else(|| anyhow!("discover: the emulated model cannot be fitted at its median"))?;
        let names = self.model.observable_names();
        let mut screened = Vec::new();
        let mut operations = Vec::new();
        for b in &data.blocks {
            let observable = &names[b.model_index];
            // A correction names its observable in a formula; a name that
            // cannot stand in one (`ch-spectrum`) cannot be corrected.
            let identity = BTreeMap::from([(observable.clone(), observable.clone())]);
            if CorrectedModel::new(self.model.clone(), &identity, &[], "discover").is_err() {
                crate::base::messages::note!(
                    "discover: observable '{observable}' is not a name a formula can use (letters, digits and '_', not starting with a digit): its corrections are not searched"
                );
                continue;
            }
            let ymax = b.y.iter().fold(0.0f64, |m, y| m.max(y.abs())).max(f64::MIN_POSITIVE);
            for f in &forms.corrections {
                operations.push(f.operations);
                if let Some(s) = self.screen_one(f, observable, ymax, data, &base_fit) {
                    screened.push(s);
                }
            }
        }
        let points = base.points() as f64;
        let bic = |s: &Screened| base_fit.chi2 - s.fitted.chi2 - points.ln();
        screened.sort_by(|a, b| bic(b).total_cmp(&bic(a)));
        let prior = FormPrior::over(&operations);
        let proposals = screened
            .into_iter()
            .filter(|s| bic(s) > 0.0)
            .take(PROPOSALS)
            .map(|s| {
                let delta_bic = bic(&s);
                proposal(s, base_fit.chi2, delta_bic, &prior)
            })
            .collect();
        let forms_tried = forms.corrections.iter().map(|f| f.form.clone()).collect();
        Ok(Screening { searched: operations.len(), forms: forms_tried, proposals })
    }
}

impl EmulatedDiscoverer {
    /// The screening blocks with the emulator's predictive covariance at
    /// `theta` added to the data's, each as its lower Cholesky factor.
    fn with_emulator_covariance<'a>(&self, data: &ScreeningData<'a>, theta: &[f64]) -> Result<Vec<ScreeningBlock<'a>>> {
        let blocks = data.blocks.iter().map(|b| {
            let n = b.x.len();
            let mut chol = CholeskyWorkspace::new(n);
            match &b.covariance_factor {
                // L Lᵀ, lower triangle.
                Some(l) => {
                    for j in 0..n {
                        for i in j..n {
                            chol.factor[i + j * n] = (0..=j).map(|k| l[i + k * n] * l[j + k * n]).sum();
                        }
                    }
                }
                None => (0..n).for_each(|i| chol.factor[i + i * n] = b.error[i] * b.error[i]),
            }
            self.model.add_model_covariance(b.model_index, b.x, theta, 1.0, &mut chol.factor);
            chol.factorize().map_err(|e| {
                anyhow!("discover: the data and emulator covariance of observable {}: {e}", b.model_index)
            })?;
            Ok(ScreeningBlock {
                model_index: b.model_index,
                x: b.x,
                y: b.y,
                error: b.error,
                covariance_factor: Some(chol.factor),
            })
        });
        blocks.collect()
    }

    /// The correction's parameter: `c`, unless θ has a `c` already.
    fn parameter(&self) -> String {
        if self.model.parameter_names().iter().any(|p| p == "c") {
            "c_new".into()
        } else {
            "c".into()
        }
    }

    /// The correction `f` of `observable` fitted with θ; None where it
    /// cannot be computed on these data.
    fn screen_one(
        &self,
        f: &Form,
        observable: &str,
        ymax: f64,
        data: &ScreeningData,
        base: &Fitted,
    ) -> Option<Screened> {
        let scale = ymax.powi(f.power);
        let spec = ParamSpec { min: f.min * scale, max: f.max * scale, truth: None, units: String::new() };
        let c = self.parameter();
        let text = f.form.replace("{y}", observable).replace("{c}", &c);
        let corrections = BTreeMap::from([(observable.to_string(), text)]);
        let model = CorrectedModel::new(self.model.clone(), &corrections, std::slice::from_ref(&c), "discover").ok()?;
        let mut bounds = data.bounds.clone();
        bounds.push((spec.min, spec.max));
        let ls = LeastSquares { blocks: &data.blocks, model: &model, bounds };
        let starts: Vec<Vec<f64>> = [0.1, 0.5, 0.9]
            .iter()
            .map(|u| base.phi.iter().copied().chain([spec.min + u * (spec.max - spec.min)]).collect())
            .collect();
        let fitted = ls.best_of(&starts)?;
        let correction = f.form.replace("{y}", observable).replace("{c}", &c);
        Some(Screened {
            form: f.clone(),
            observable: observable.to_string(),
            parameter: c,
            correction,
            spec,
            simulator: Arc::new(model),
            fitted,
        })
    }
}

fn proposal(s: Screened, base_chi2: f64, delta_bic: f64, prior: &FormPrior) -> Proposal {
    let name = format!("{}_of_{}", s.form.name, s.observable);
    let correction = &s.correction;
    let formula = format!("{} → {correction}", s.observable);
    let toml = format!(
        "[[candidates]]\nname = {name:?}\ndescription = {:?}\ncorrection = {{ {} = {correction:?} }}\nparameters.{} = {{ min = {}, max = {} }}\n",
        s.form.meaning, s.observable, s.parameter, s.spec.min, s.spec.max
    );
    Proposal {
        meaning: s.form.meaning.clone(),
        toml,
        formula: formula.clone(),
        delta_chi2: base_chi2 - s.fitted.chi2,
        delta_bic,
        prior_log_odds: prior.log_odds(&[s.form.operations]),
        candidate: CandidateModel {
            name,
            description: format!("discovered: {formula}"),
            extra_parameters: vec![(s.parameter.clone(), s.spec)],
            simulator: s.simulator,
            special_case_of: Vec::new(),
            own_emulator: false,
        },
    }
}
