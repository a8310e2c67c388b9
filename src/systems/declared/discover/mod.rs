//! Discovery for declared models: the physics nobody declared, searched in a
//! grammar of terms built from the model's own symbols (`grammar`).
//!
//! Screening (here) is cheap: every term, and every pair of the best five,
//! is fitted by least squares with θ (`fit`), and ranked by the Bayesian
//! information criterion ΔBIC = Δχ² − k ln N; a pair stays only if it beats
//! every term alone (forward selection). Terms that fit the data the
//! same way (`v*abs(v)` and `v^2` for a ball that only falls, or `h*v*v`
//! while h barely changes) are one explanation, and the simpler stands for
//! both (`model::distinct`). The best few are handed back as
//! candidates; `diagnose` then judges them by full calibration and evidence,
//! with prior odds that pay for the number searched (`proposal`).

pub mod grammar;

use super::declaration::{CandidateTable, Declared, Written};
use super::DeclaredFamily;
use crate::base::config::ParamSpec;
use crate::engine::formula;
use crate::engine::model::distinct::{distinct, Explanation};
use crate::engine::model::fit::{Fitted, LeastSquares};
use crate::engine::model::prior::FormPrior;
use crate::engine::model::{CandidateModel, Discoverer, Proposal, Screening, ScreeningData, Simulator, SpecialCase};
use anyhow::Result;
use grammar::{Instance, ParameterForm, Power, TermForm, To};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

/// How many screened terms (or pairs) go on to full calibration.
const PROPOSALS: usize = 3;
/// How far below the best a term's ΔBIC may be and still be calibrated.
/// ΔBIC/2 approximates a log Bayes factor, so a term 20 below trails by
/// about 10 in log evidence, beyond any decisive lead (3) and the prior
/// odds between forms (a periodic term pays 3.5 more than a constant): its
/// calibration could not change the verdict unless BIC misjudged the
/// evidence by more than that, and it may be the costliest of all (a free
/// power in the kinetics example's ODE, 50 below the constant source, took
/// 21 s of its 23 s search).
const BIC_REACH: f64 = 20.0;
/// Singles whose pairs are screened.
const PAIRED: usize = 5;
/// Pairs among the proposals: the best pair, the other slots to singles. A
/// second pair mostly shares a term with the first and pays the same
/// look-elsewhere odds over every pair, and it took the slot of a single
/// the data favoured: in a rubber band softening as F², two pairs ranked
/// above the square and `k*exp(c*F)` was named with the square never
/// calibrated.
const PAIRS_PROPOSED: usize = 1;
/// A coefficient's prior lets its term change an observable by this many
/// times the observable's own largest size.
const COEFFICIENT_REACH: f64 = 10.0;

pub struct DeclaredDiscoverer {
    pub(super) family: DeclaredFamily,
    pub(super) file: String,
    pub(super) base: Declared,
    pub(super) forms: Vec<TermForm>,
}

/// A screened term: its instance, its parameters' priors and its best fit.
struct Screened {
    instances: Vec<Instance>,
    table: CandidateTable,
    simulator: Arc<dyn Simulator>,
    fitted: Fitted,
}

impl Discoverer for DeclaredDiscoverer {
    fn screen(&self, data: &ScreeningData) -> Result<Screening> {
        let base_model = self.family.compile(&self.file, &self.base)?;
        let base = LeastSquares { blocks: &data.blocks, model: base_model.as_ref(), bounds: data.bounds.clone() };
        let Some(base_fit) = base.fit(&data.theta) else {
            anyhow::bail!("discover: the base model cannot be computed at its posterior median");
        };
        let scales = self.scales(data, &base_fit.phi)?;
        let instances = grammar::instances(&self.forms, &self.base);
        // Each term's fit is independent of the others': the cores share them.
        let mut singles: Vec<Screened> = instances
            .par_iter()
            .filter_map(|i| self.screen_one(std::slice::from_ref(i), data, &base_fit, &scales, None))
            .collect();
        let points = base.points() as f64;
        let bic = bic_of(base_fit.chi2, points);
        singles.sort_by(|a, b| bic(b).total_cmp(&bic(a)));
        let singles = distinct(singles, data);
        let searched = instances.len();
        let top: Vec<&Screened> = singles.iter().take(PAIRED).collect();
        let pairs: Vec<(&Screened, &Screened)> =
            top.iter().enumerate().flat_map(|(i, a)| top[i + 1..].iter().map(move |b| (*a, *b))).collect();
        let best_single = singles.first().map_or(f64::NEG_INFINITY, &bic);
        let mut all: Vec<Screened> = pairs
            .par_iter()
            .filter_map(|(a, b)| {
                let pair = [a.instances[0].clone(), b.instances[0].clone()];
                // Also from where each term fitted alone (θ from the better of the two).
                let mut joint: BTreeMap<String, f64> = a.fitted_terms("1");
                joint.extend(b.fitted_terms("2"));
                let theta = &a.fitted.phi[..data.theta.len()];
                self.screen_one(&pair, data, &base_fit, &scales, Some((theta, joint)))
            })
            // Forward selection: a second term is kept only when the pair
            // beats every single term (not only its own two). A pair below
            // some single is, by the screening's own criterion, a worse
            // explanation than one already proposed: its calibration could
            // not change the verdict unless BIC misjudged the evidence by
            // more than the gap, and it would cost an integration of every
            // parameter it adds.
            .filter(|s| bic(s) > best_single)
            .collect();
        all.extend(singles);
        all.sort_by(|a, b| bic(b).total_cmp(&bic(a)));
        let all = distinct(all, data);
        let prior = FormPrior::over(&instances.iter().map(|i| i.operations).collect::<Vec<_>>());
        let best = all.first().map_or(f64::NEG_INFINITY, &bic);
        let mut pairs = 0;
        let proposals = all
            .into_iter()
            .filter(|s| bic(s) > 0.0 && bic(s) >= best - BIC_REACH)
            .filter(|s| {
                pairs += usize::from(s.instances.len() > 1);
                s.instances.len() == 1 || pairs <= PAIRS_PROPOSED
            })
            .take(PROPOSALS)
            .map(|s| {
                let special = special_cases(&s.instances, &instances, &scales);
                let mut p = proposal(s, base_fit.chi2, &bic, &prior);
                p.candidate.special_case_of = special;
                p
            })
            .collect();
        let mut forms: Vec<String> = Vec::new();
        for i in &instances {
            let form = &self.forms[i.rank].form;
            if !forms.contains(form) {
                forms.push(form.clone());
            }
        }
        Ok(Screening { searched, forms, proposals })
    }
}

/// The free powers a single fixed-power term is a special case of: the same
/// symbol joining the same place (`c*v*abs(v)` in dv/dt is `c*abs(v)^p` in
/// dv/dt at p = 2), where the symbol keeps one sign over the data.
fn special_cases(terms: &[Instance], all: &[Instance], scales: &Scales) -> Vec<SpecialCase> {
    let [term] = terms else { return Vec::new() };
    let (Some(Power::Fixed(k)), Some(symbol)) = (&term.power, term.symbols.first()) else {
        return Vec::new();
    };
    if !scales.one_signed.contains(symbol) {
        return Vec::new();
    }
    let free = all.iter().filter(|f| f.to == term.to && f.target == term.target && f.symbols.first() == Some(symbol));
    free.filter_map(|f| match &f.power {
        Some(Power::Free(p)) => Some(SpecialCase { of: f.name.clone(), parameter: p.clone(), value: *k }),
        _ => None,
    })
    .collect()
}

fn bic_of(base_chi2: f64, points: f64) -> impl Fn(&Screened) -> f64 {
    move |s| base_chi2 - s.fitted.chi2 - (s.table.parameters.len() as f64) * points.ln()
}

/// A screened term as a candidate, with its prior odds.
fn proposal(s: Screened, base_chi2: f64, bic: impl Fn(&Screened) -> f64, prior: &FormPrior) -> Proposal {
    let delta_bic = bic(&s);
    let prior_log_odds = prior.log_odds(&s.instances.iter().map(|i| i.operations).collect::<Vec<_>>());
    let formula = describe(&s.table);
    let meaning = s.instances.iter().map(|i| i.meaning.as_str()).collect::<Vec<_>>().join("; and ");
    Proposal {
        meaning,
        toml: candidate_toml(&s.table),
        formula: formula.clone(),
        delta_chi2: base_chi2 - s.fitted.chi2,
        delta_bic,
        prior_log_odds,
        candidate: CandidateModel {
            name: s.table.name.clone(),
            description: format!("discovered: {formula}"),
            extra_parameters: s.table.parameters.iter().map(|(n, p)| (n.clone(), p.clone())).collect(),
            simulator: s.simulator,
            special_case_of: Vec::new(),
            own_emulator: false,
        },
    }
}

impl Explanation for Screened {
    fn fitted(&self) -> &Fitted {
        &self.fitted
    }

    fn added_parameters(&self) -> usize {
        self.table.parameters.len()
    }

    fn complexity(&self) -> (usize, usize, usize, usize) {
        let operations = self.instances.iter().map(|i| i.operations).sum();
        (self.table.parameters.len(), self.instances.len(), operations, self.instances.iter().map(|i| i.rank).sum())
    }
}

impl Screened {
    /// The term parameters' best-fit values, named with `suffix` as in a pair.
    fn fitted_terms(&self, suffix: &str) -> BTreeMap<String, f64> {
        let theta = self.fitted.phi.len() - self.table.parameters.len();
        self.table.parameters.keys().zip(&self.fitted.phi[theta..]).map(|(n, v)| (format!("{n}{suffix}"), *v)).collect()
    }
}

/// Numbers the grammar's bounds may use: the input's span over the data,
/// the most points of one observable, and each symbol's largest size at the
/// base fit (a state along its trajectory, or the input).
struct Scales {
    span: f64,
    n: f64,
    smax: BTreeMap<String, f64>,
    /// Each observable's largest |y| over the data.
    ymax: BTreeMap<String, f64>,
    /// The symbols that keep one sign over the data (values of the other
    /// sign within 1% of their largest size count as zero).
    one_signed: BTreeSet<String>,
}

impl DeclaredDiscoverer {
    fn scales(&self, data: &ScreeningData, theta: &[f64]) -> Result<Scales> {
        let xs: Vec<f64> = data.blocks.iter().flat_map(|b| b.x.iter().copied()).collect();
        let (lo, hi) = xs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| (l.min(*x), h.max(*x)));
        let n = data.blocks.iter().map(|b| b.x.len()).max().unwrap_or(1) as f64;
        let mut smax = BTreeMap::new();
        let mut one_signed = BTreeSet::new();
        let mut record = |name: &str, values: &[f64]| {
            let (lo, hi) = values.iter().fold((0.0f64, 0.0f64), |(l, h), v| (l.min(*v), h.max(*v)));
            let size = hi.max(-lo);
            if lo >= -0.01 * size || hi <= 0.01 * size {
                one_signed.insert(name.to_string());
            }
            smax.insert(name.to_string(), size);
        };
        record(&self.base.input, &xs);
        if !self.base.states.is_empty() {
            // The states as observables of the same model, read off along the data's times.
            let mut d = self.base.clone();
            for s in &self.base.states {
                let place = format!("{}: discover", self.file);
                d.observables.push((format!("state {}", s.name), Written { text: s.name.clone(), place }));
            }
            let model = self.family.compile(&self.file, &d)?;
            let first = self.base.observables.len();
            for (k, s) in self.base.states.iter().enumerate() {
                let mut out = vec![0.0; xs.len()];
                model.predict(first + k, &xs, theta, &mut out);
                record(&s.name, &out);
            }
        }
        let mut ymax: BTreeMap<String, f64> = BTreeMap::new();
        for b in &data.blocks {
            let name = self.base.observables.get(b.model_index).map_or(String::new(), |(o, _)| o.clone());
            let size = b.y.iter().fold(0.0f64, |m, y| m.max(y.abs()));
            ymax.entry(name).and_modify(|m| *m = m.max(size)).or_insert(size);
        }
        Ok(Scales { span: (hi - lo).max(f64::MIN_POSITIVE), n, smax, ymax, one_signed })
    }

    /// Fits the model with `terms` added; None when the term cannot be
    /// declared or computed (a form undefined on these data).
    fn screen_one(
        &self,
        terms: &[Instance],
        data: &ScreeningData,
        base: &Fitted,
        scales: &Scales,
        also_from: Option<(&[f64], BTreeMap<String, f64>)>,
    ) -> Option<Screened> {
        if let [a, b] = terms {
            // One parameter cannot vary two ways at once.
            if a.to == To::Parameters && b.to == To::Parameters && a.target == b.target {
                return None;
            }
        }
        let suffixes: Vec<String> = if terms.len() > 1 {
            vec!["1".into(), "2".into()]
        } else if terms[0].parameters.iter().any(|(p, _)| self.base.knows(p)) {
            vec!["_new".into()]
        } else {
            vec![String::new()]
        };
        let mut ranges = Vec::new();
        for (term, suffix) in terms.iter().zip(&suffixes) {
            for (p, form) in &term.parameters {
                ranges.push((format!("{p}{suffix}"), self.range(term, form, scales)?));
            }
        }
        // In the order the compiled model takes them: a candidate's parameters by name.
        ranges.sort_by(|a, b| a.0.cmp(&b.0));
        // Coefficients at ±1 first, to measure how far one unit moves the model.
        let provisional = self.table(terms, &suffixes, &ranges, |_| (-1.0, 1.0));
        let model = self.compile(&provisional)?;
        let mid: Vec<f64> = base.phi.iter().copied().chain(ranges.iter().map(|(_, r)| r.start())).collect();
        let reach = self.coefficient_reach(model.as_ref(), data, &mid)?;
        let table = self.table(terms, &suffixes, &ranges, |_| (-reach, reach));
        let simulator = self.compile(&table)?;
        // The calibration refuses a model that cannot be computed at its
        // prior box's corners or centre (`check_inputs`): such a term is no
        // candidate on these data (`F/(k*(1 + c*F))` at c = -1/smax).
        if data.blocks.iter().any(|b| simulator.check_inputs(b.model_index, b.x).is_err()) {
            return None;
        }
        let mut bounds = data.bounds.clone();
        bounds.extend(table.parameters.values().map(|p| (p.min, p.max)));
        let ls = LeastSquares { blocks: &data.blocks, model: simulator.as_ref(), bounds };
        let mut starts = starts(&base.phi, &ranges);
        if let Some((theta, terms)) = also_from {
            starts.push(
                theta
                    .iter()
                    .copied()
                    .chain(ranges.iter().map(|(n, r)| terms.get(n).copied().unwrap_or(r.start())))
                    .collect(),
            );
        }
        let fitted = ls.best_of(&starts)?;
        Some(Screened { instances: terms.to_vec(), table, simulator, fitted })
    }

    fn range(&self, term: &Instance, form: &ParameterForm, scales: &Scales) -> Option<Range> {
        match form {
            ParameterForm::Kind(_) => Some(Range::Coefficient),
            ParameterForm::Range { min, max, starts } => {
                let smax = term.symbols.iter().filter_map(|s| scales.smax.get(s)).fold(0.0f64, |m, v| m.max(*v));
                let scope = grammar::bound_scope();
                let all = scales.ymax.values().fold(0.0f64, |m, v| m.max(*v));
                let ymax = match term.to {
                    To::Observables | To::Measured => scales.ymax.get(&term.target).copied().unwrap_or(all),
                    To::Rates | To::Parameters => all,
                };
                let values = [scales.span, scales.n, smax.max(f64::MIN_POSITIVE), ymax.max(f64::MIN_POSITIVE)];
                let eval = |text: &str| formula::Formula::parse(text, &scope, "grammar").ok().map(|f| f.eval(&values));
                let (lo, hi) = (eval(min)?, eval(max)?);
                (lo.is_finite() && hi.is_finite() && hi > lo).then_some(Range::Span(lo, hi, (*starts).max(1)))
            }
        }
    }

    /// Half-width of a coefficient's prior: `COEFFICIENT_REACH` times the
    /// coefficient that changes some observable by its own largest size.
    fn coefficient_reach(&self, model: &dyn Simulator, data: &ScreeningData, phi: &[f64]) -> Option<f64> {
        let ls =
            LeastSquares { blocks: &data.blocks, model, bounds: vec![(f64::NEG_INFINITY, f64::INFINITY); phi.len()] };
        let at = ls.predict(phi)?;
        let n_theta = data.theta.len();
        let mut reach = f64::INFINITY;
        for k in n_theta..phi.len() {
            let mut moved = phi.to_vec();
            moved[k] += 1e-3;
            let p = ls.predict(&moved)?;
            let mut offset = 0;
            for b in data.blocks.iter() {
                let size = b.y.iter().fold(0.0f64, |m, y| m.max(y.abs()));
                let slope = (offset..offset + b.x.len()).map(|i| ((p[i] - at[i]) / 1e-3).abs()).fold(0.0, f64::max);
                if slope > 0.0 && size > 0.0 {
                    reach = reach.min(size / slope);
                }
                offset += b.x.len();
            }
        }
        let r = COEFFICIENT_REACH * reach;
        (r.is_finite() && r > 0.0).then(|| round_up(r))
    }

    fn table(
        &self,
        terms: &[Instance],
        suffixes: &[String],
        ranges: &[(String, Range)],
        coefficient: impl Fn(&str) -> (f64, f64),
    ) -> CandidateTable {
        let mut rates: BTreeMap<String, String> = BTreeMap::new();
        let mut observables: BTreeMap<String, String> = BTreeMap::new();
        let mut vary: BTreeMap<String, String> = BTreeMap::new();
        for (term, suffix) in terms.iter().zip(suffixes) {
            let to = match term.to {
                To::Rates => &mut rates,
                To::Observables | To::Measured => &mut observables,
                To::Parameters => &mut vary,
            };
            let text = term.render(suffix);
            let joined = match to.get(&term.target) {
                Some(before) => format!("{before} + {text}"),
                None => text,
            };
            to.insert(term.target.clone(), joined);
        }
        let parameters = ranges
            .iter()
            .map(|(name, r)| {
                let (min, max) = match r {
                    Range::Coefficient => coefficient(name),
                    Range::Span(lo, hi, _) => (*lo, *hi),
                };
                (name.clone(), ParamSpec { min, max, truth: None, units: String::new() })
            })
            .collect();
        let name = terms.iter().map(|t| t.name.as_str()).collect::<Vec<_>>().join("+");
        CandidateTable { description: String::new(), name, observables, rates, vary, parameters }
    }

    fn compile(&self, table: &CandidateTable) -> Option<Arc<dyn Simulator>> {
        let declared = self.base.with_candidate(&self.file, table).ok()?;
        self.family.compile(&self.file, &declared).ok()
    }
}

#[derive(Clone, Copy, Debug)]
enum Range {
    Coefficient,
    /// min, max and how many starting points.
    Span(f64, f64, usize),
}

impl Range {
    fn start(&self) -> f64 {
        match self {
            Range::Coefficient => 0.0,
            Range::Span(lo, hi, _) => 0.5 * (lo + hi),
        }
    }
}

/// Starting points: θ at the base fit, coefficients at 0, and every
/// combination of each ranged parameter's starts (midpoints of equal cells).
fn starts(theta: &[f64], ranges: &[(String, Range)]) -> Vec<Vec<f64>> {
    let mut out = vec![theta.to_vec()];
    for (_, r) in ranges {
        let values: Vec<f64> = match r {
            Range::Coefficient => vec![0.0],
            Range::Span(lo, hi, n) => (0..*n).map(|i| lo + (hi - lo) * (i as f64 + 0.5) / *n as f64).collect(),
        };
        out = out.into_iter().flat_map(|s| values.iter().map(move |v| [s.clone(), vec![*v]].concat())).collect();
    }
    out
}

/// Two significant figures, rounded up: a prior bound a person can read.
fn round_up(x: f64) -> f64 {
    let scale = 10f64.powf(x.log10().floor() - 1.0);
    (x / scale).ceil() * scale
}

/// `c*v*abs(v) in dv/dt` for each term of a candidate table.
fn describe(table: &CandidateTable) -> String {
    let rates = table.rates.iter().map(|(s, t)| format!("{t} in d{s}/dt"));
    let observables = table.observables.iter().map(|(o, t)| format!("{t} in {o}"));
    let vary = table.vary.iter().map(|(p, t)| format!("{p} → {t} wherever {p} is used"));
    rates.chain(observables).chain(vary).collect::<Vec<_>>().join("; ")
}

/// The `[[candidates]]` block that declares `table`.
fn candidate_toml(table: &CandidateTable) -> String {
    let mut out = format!("[[candidates]]\nname = {:?}\ndescription = {:?}\n", table.name, describe(table));
    for (key, map) in [("rates", &table.rates), ("observables", &table.observables), ("vary", &table.vary)] {
        if !map.is_empty() {
            let items: Vec<String> = map.iter().map(|(k, v)| format!("{k} = {v:?}")).collect();
            out.push_str(&format!("{key} = {{ {} }}\n", items.join(", ")));
        }
    }
    for (name, p) in &table.parameters {
        out.push_str(&format!("parameters.{name} = {{ min = {}, max = {} }}\n", p.min, p.max));
    }
    out
}
