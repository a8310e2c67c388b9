//! Discovery for an emulated model: the simulator cannot be changed here,
//! so the search is over corrections of its output, the physics of the
//! measurement (`corrections.toml`, data: an offset, a gain, a loss growing
//! as the square of the signal, a saturating counting loss, a gain growing
//! as x²). Each is fitted with θ by least squares through the emulator's
//! mean, its residuals weighed by the data's covariance plus the emulator's
//! predictive covariance at the model's best fit (`model::fit`), and ranked
//! by ΔBIC; fits the data cannot tell apart are one (`model::distinct`),
//! and corrections of several observables are chosen by forward selection. The best
//! are proposed as `correction` candidates and judged, with the emulator's
//! covariance at every θ, by full calibration.

use super::correction::CorrectedModel;
use super::forms::{self, start_grid, Form, Range, Scales};
use super::labels::Label;
use crate::engine::discover::distinct::{distinct, Explanation};
use crate::engine::discover::library::fitted_value;
use crate::engine::discover::prior::FormPrior;
use crate::engine::gp::CholeskyWorkspace;
use crate::engine::model::fit::{Fitted, LeastSquares};
use crate::engine::model::{CandidateModel, Discoverer, Proposal, Screening, ScreeningBlock, ScreeningData, Simulator};
use anyhow::{anyhow, Result};
use std::collections::BTreeMap;
use std::sync::Arc;

/// How many screened corrections go on to full calibration.
const PROPOSALS: usize = 3;

pub struct EmulatedDiscoverer {
    pub model: Arc<dyn Simulator>,
    /// Quantities that set the observables apart, for shared corrections.
    pub labels: Vec<Label>,
}

/// One observable's correction: its form, its parameters' ranges on that
/// observable's data, and the form written out with the observable's and
/// the parameters' names.
#[derive(Clone)]
pub(super) struct Part {
    pub form: Form,
    /// The form's place in the grammar.
    pub rank: usize,
    pub observable: String,
    pub ranges: Vec<Range>,
    /// The parameters' names, in the form's order.
    pub parameters: Vec<String>,
    pub correction: String,
}

impl Part {
    fn new(form: &Form, rank: usize, observable: &str, ranges: Vec<Range>, name: &dyn Fn(&str) -> String) -> Part {
        let parameters = form.parameters.keys().map(|p| name(p)).collect();
        let correction = form.render(observable, name);
        Part { form: form.clone(), rank, observable: observable.into(), ranges, parameters, correction }
    }

    fn name(&self) -> String {
        format!("{}_of_{}", self.form.name, self.observable)
    }
}

/// A screened correction (of one observable, or of several at once) and
/// its least-squares fit with θ.
pub(super) struct Screened {
    parts: Vec<Part>,
    simulator: Arc<dyn Simulator>,
    fitted: Fitted,
    /// The label whose values scale one coefficient shared by every part.
    pub shared_by: Option<String>,
    /// Corrections the data could not tell from this one, merged into it (`distinct`).
    readings: Vec<String>,
}

impl Screened {
    /// Each parameter once, with its range, in the parts' order (a shared
    /// coefficient is a parameter of every part).
    fn parameters(&self) -> Vec<(&String, &Range)> {
        unique_parameters(&self.parts)
    }

    fn name(&self) -> String {
        match &self.shared_by {
            Some(label) => format!("{}_per_{label}", self.parts[0].form.name),
            None => self.parts.iter().map(Part::name).collect::<Vec<_>>().join("+"),
        }
    }
}

fn unique_parameters(parts: &[Part]) -> Vec<(&String, &Range)> {
    let mut seen: Vec<(&String, &Range)> = Vec::new();
    for (name, range) in parts.iter().flat_map(|p| p.parameters.iter().zip(&p.ranges)) {
        if !seen.iter().any(|(n, _)| *n == name) {
            seen.push((name, range));
        }
    }
    seen
}

impl Explanation for Screened {
    fn fitted(&self) -> &Fitted {
        &self.fitted
    }

    fn added_parameters(&self) -> usize {
        self.parameters().len()
    }

    fn complexity(&self) -> (usize, usize, usize, usize) {
        let operations = self.parts.iter().map(|p| p.form.operations).sum();
        (self.added_parameters(), self.parts.len(), operations, self.parts.iter().map(|p| p.rank).sum())
    }

    fn reading(&self) -> String {
        let theta = self.fitted.phi.len() - self.added_parameters();
        let fitted: Vec<String> = self
            .parameters()
            .iter()
            .zip(&self.fitted.phi[theta..])
            .map(|((n, _), v)| format!("{n} = {}", fitted_value(*v)))
            .collect();
        format!("{} ({}; at the screening's fit {})", formula_of(&self.parts), meaning_of(self), fitted.join(", "))
    }

    fn readings_mut(&mut self) -> &mut Vec<String> {
        &mut self.readings
    }
}

/// Each part's correction, as "observable → correction".
fn formula_of(parts: &[Part]) -> String {
    parts.iter().map(|p| format!("{} → {}", p.observable, p.correction)).collect::<Vec<_>>().join("; ")
}

/// What the parts mean, each meaning once, and a shared coefficient's label.
fn meaning_of(s: &Screened) -> String {
    let mut meanings: Vec<&str> = Vec::new();
    for p in &s.parts {
        if !meanings.contains(&p.form.meaning.as_str()) {
            meanings.push(&p.form.meaning);
        }
    }
    let meaning = meanings.join("; ");
    match &s.shared_by {
        Some(label) => {
            format!("{meaning}; one coefficient for all the observables, in proportion to each one's {label}")
        }
        None => meaning,
    }
}

impl Discoverer for EmulatedDiscoverer {
    fn screen(&self, data: &ScreeningData) -> Result<Screening> {
        let forms = forms::bundled()?;
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
        let (mut screened, operations, observables) = self.screen_singles(&forms, data, &base_fit);
        let points = base.points() as f64;
        let bic = |s: &Screened| base_fit.chi2 - s.fitted.chi2 - s.added_parameters() as f64 * points.ln();
        screened.sort_by(|a, b| bic(b).total_cmp(&bic(a)));
        let mut screened = distinct(screened, data);
        // As pairs on declared models: corrections of several observables
        // are kept only when they beat every single one.
        let best_single = screened.first().map_or(f64::NEG_INFINITY, &bic);
        if let Some(all) = self.several_observables(&screened, &bic, data) {
            if bic(&all) > best_single {
                screened.insert(0, all);
            }
        }
        let (shared, shared_nats) = self.screen_shared(&forms, data, &base_fit);
        screened.extend(shared);
        screened.sort_by(|a, b| bic(b).total_cmp(&bic(a)));
        let priors = Priors { per_observable: FormPrior::over(&operations), shared: FormPrior::over(&shared_nats) };
        let proposals = screened
            .into_iter()
            .filter(|s| bic(s) > 0.0)
            .take(PROPOSALS)
            .map(|s| {
                let delta_bic = bic(&s);
                proposal(s, base_fit.chi2, delta_bic, &priors, observables)
            })
            .collect();
        let forms_tried = forms.iter().map(|f| f.form.clone()).collect();
        Ok(Screening {
            searched: operations.len() + shared_nats.len(),
            forms: forms_tried,
            proposals,
            notes: Vec::new(),
        })
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

    /// A correction's parameter `p` as named in the candidate: `p` (or
    /// `p_<observable>` when several observables are corrected at once),
    /// unless θ or an observable has that name already (a periodic gain's
    /// `b` on an observable named `b` would be the observable itself).
    pub(super) fn parameter(&self, p: &str, observable: Option<&str>) -> String {
        let name = observable.map_or(p.to_string(), |o| format!("{p}_{o}"));
        if self.model.parameter_names().contains(&name) || self.model.observable_names().contains(&name) {
            format!("{name}_new")
        } else {
            name
        }
    }

    /// Every form of the grammar on every observable a formula can name,
    /// each fitted with θ; with each term's size, and how many observables
    /// were searched.
    fn screen_singles(&self, forms: &[Form], data: &ScreeningData, base: &Fitted) -> (Vec<Screened>, Vec<f64>, usize) {
        let names = self.model.observable_names();
        let (mut screened, mut operations, mut observables) = (Vec::new(), Vec::new(), 0);
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
            observables += 1;
            let scales = Scales::of(b.x, b.y);
            for (rank, f) in forms.iter().enumerate() {
                operations.push(f.nats);
                // x all 0 (one point at the origin) leaves an x-form no finite prior: not searched.
                let Some(ranges) = f.ranges(&scales) else { continue };
                let starts: Vec<Vec<f64>> =
                    start_grid(&ranges).into_iter().map(|u| base.phi.iter().copied().chain(u).collect()).collect();
                let part = Part::new(f, rank, observable, ranges, &|p| self.parameter(p, None));
                if let Some(s) = self.fit_parts(vec![part], data, &starts) {
                    screened.push(s);
                }
            }
        }
        (screened, operations, observables)
    }

    /// The corrections `parts` fitted with θ from the best of `starts`;
    /// None where they cannot be computed on these data.
    pub(super) fn fit_parts(&self, parts: Vec<Part>, data: &ScreeningData, starts: &[Vec<f64>]) -> Option<Screened> {
        let corrections: BTreeMap<String, String> =
            parts.iter().map(|p| (p.observable.clone(), p.correction.clone())).collect();
        let unique = unique_parameters(&parts);
        let parameters: Vec<String> = unique.iter().map(|(n, _)| (*n).clone()).collect();
        let model = CorrectedModel::new(self.model.clone(), &corrections, &parameters, "discover").ok()?;
        let mut bounds = data.bounds.clone();
        bounds.extend(unique.iter().map(|(_, r)| (r.spec.min, r.spec.max)));
        let ls = LeastSquares { blocks: &data.blocks, model: &model, bounds };
        let fitted = ls.best_of(starts)?;
        Some(Screened { parts, simulator: Arc::new(model), fitted, shared_by: None, readings: Vec::new() })
    }

    /// Corrections of several observables fitted together, chosen by
    /// forward selection: from the best single (`screened` best first), each
    /// other observable in turn gets the correction, of those that paid
    /// their parameters alone, that most lowers the joint χ² net of its
    /// price, ln N per parameter, if that is more than nothing. Chosen alone, one observable's best
    /// was fitted with θ bent toward another's mismatch. A change that
    /// reaches every observable (a shear δf in each spectrum of a heavy-ion
    /// model) is no one observable's. None unless two or more are chosen.
    fn several_observables(
        &self,
        screened: &[Screened],
        bic: &dyn Fn(&Screened) -> f64,
        data: &ScreeningData,
    ) -> Option<Screened> {
        let paying: Vec<&Screened> = screened.iter().filter(|s| bic(s) > 0.0).collect();
        let leader = paying.first()?;
        let renamed = |p: &Part| {
            Part::new(&p.form, p.rank, &p.observable, p.ranges.clone(), &|q| self.parameter(q, Some(&p.observable)))
        };
        let mut current =
            self.fit_parts(vec![renamed(&leader.parts[0])], data, std::slice::from_ref(&leader.fitted.phi))?;
        let price = (data.blocks.iter().map(|b| b.x.len()).sum::<usize>() as f64).ln();
        let mut observables: Vec<&str> = Vec::new();
        for s in &paying {
            let o = s.parts[0].observable.as_str();
            if o != leader.parts[0].observable && !observables.contains(&o) {
                observables.push(o);
            }
        }
        for o in observables {
            // θ and the corrections so far where they are, the new one where it fitted alone.
            let start = |s: &Screened| {
                let own = &s.fitted.phi[s.fitted.phi.len() - s.added_parameters()..];
                current.fitted.phi.iter().chain(own).copied().collect::<Vec<_>>()
            };
            // What a correction gains: the χ² it takes off, less ln N for each of its parameters.
            let gain = |b: &Screened| {
                current.fitted.chi2 - b.fitted.chi2 - (b.added_parameters() - current.added_parameters()) as f64 * price
            };
            let best = paying
                .iter()
                .filter(|s| s.parts[0].observable == o)
                .filter_map(|s| {
                    let parts = current.parts.iter().cloned().chain([renamed(&s.parts[0])]).collect();
                    self.fit_parts(parts, data, &[start(s)])
                })
                .max_by(|a, b| gain(a).total_cmp(&gain(b)));
            if let Some(b) = best.filter(|b| gain(b) > 0.0) {
                current = b;
            }
        }
        (current.parts.len() >= 2).then_some(current)
    }
}

/// The prior over forms of each class of correction: of one observable or
/// several each its own, and shared by the observables of a label.
struct Priors {
    per_observable: FormPrior,
    shared: FormPrior,
}

/// A screened correction as a `correction` candidate, with its prior odds
/// against the model as it is (`observables`: how many were searched).
fn proposal(s: Screened, base_chi2: f64, delta_bic: f64, priors: &Priors, observables: usize) -> Proposal {
    let name = s.name();
    let formula = formula_of(&s.parts);
    let meaning = meaning_of(&s);
    let corrections = s.parts.iter().map(|p| format!("{} = {:?}", p.observable, p.correction)).collect::<Vec<_>>();
    let mut toml = format!(
        "[[candidates]]\nname = {name:?}\ndescription = {meaning:?}\ncorrection = {{ {} }}\n",
        corrections.join(", ")
    );
    for (name, r) in s.parameters() {
        toml.push_str(&format!("parameters.{name} = {{ min = {}, max = {} }}\n", r.spec.min, r.spec.max));
    }
    let sizes: Vec<f64> = s.parts.iter().map(|p| p.form.nats).collect();
    let prior_log_odds = match (&s.shared_by, sizes.as_slice()) {
        (Some(_), [one, ..]) => priors.shared.log_odds(&[*one]),
        (_, [one]) => priors.per_observable.log_odds(&[*one]),
        (_, many) => priors.per_observable.log_odds_one_per_observable(many, observables),
    };
    let extra_parameters = s.parameters().into_iter().map(|(n, r)| (n.clone(), r.spec.clone())).collect();
    // The corrected model names θ and then the corrections' parameters.
    let best_fit = s.simulator.parameter_names().into_iter().zip(s.fitted.phi.iter().copied()).collect();
    Proposal {
        meaning,
        toml,
        best_fit,
        readings: s.readings,
        formula: formula.clone(),
        delta_chi2: base_chi2 - s.fitted.chi2,
        delta_bic,
        prior_log_odds,
        candidate: CandidateModel {
            name,
            description: format!("discovered: {formula}"),
            extra_parameters,
            simulator: s.simulator,
            special_case_of: Vec::new(),
            own_emulator: false,
        },
    }
}
