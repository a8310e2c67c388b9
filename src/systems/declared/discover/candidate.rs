//! A term ready to fit through the model (`Candidate`: from the library,
//! found along the data or not, or from the grammar), and the fit itself
//! (`Context::fit`): θ and the term's parameters by least squares, with a
//! coefficient's prior scaled to the size of the mismatch it must explain.

use super::super::declaration::{CandidateTable, Declared};
use super::grammar::{self, Instance, ParameterForm, Power, TermForm, To};
use super::{round_up, with_states_observed, DeclaredDiscoverer};
use crate::base::config::ParamSpec;
use crate::engine::discover::along::Found;
use crate::engine::discover::library::{fitted_value, seven_digits, Scale, Symbol, Term, Unary};
use crate::engine::discover::prior::{self, FormPrior};
use crate::engine::formula;
use crate::engine::model::fit::{Fitted, LeastSquares};
use crate::engine::model::{CandidateModel, Proposal, ScreeningData, Simulator};
use anyhow::Result;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

/// A coefficient's prior reaches this many times the larger of the
/// mismatch it must explain and its own best-fit size: wide enough that
/// the data, not the prior, place it, and tied to the mismatch the model
/// shows rather than to the observable's own magnitude.
const COEFFICIENT_REACH: f64 = 10.0;

/// A parameter's prior as the screening knows it.
#[derive(Clone, Debug)]
pub enum Range {
    /// A linear coefficient whose half-width the fit measures (`coefficient_reach`).
    Coefficient,
    /// A linear coefficient of known half-width.
    Reach(f64),
    /// min, max and how many starting points.
    Span(f64, f64, usize),
}

/// A term ready to fit through the model.
#[derive(Clone, Debug)]
pub struct Candidate {
    pub name: String,
    pub to: To,
    /// The state (rates), observable (observables, measured) or parameter it joins.
    pub target: String,
    /// The term with its parameters as `{name}`.
    pub template: String,
    /// Each parameter's prior and, from the screening along the data, its start.
    pub parameters: Vec<(String, Range, Option<f64>)>,
    /// Its prior cost in nats.
    pub nats: f64,
    pub meaning: String,
    /// Library terms first (0), then the grammar's in its order.
    pub rank: usize,
    pub power: Option<Power>,
    pub symbols: Vec<String>,
    /// A library term of one factor: its primitive.
    pub library_unary: Option<Unary>,
    /// θ where the screening along the data left it, with this term.
    pub theta: Option<Vec<f64>>,
}

impl Candidate {
    fn library(term: &Term, symbols: &[Symbol], to: To, target: &str) -> Candidate {
        let power = match term.factors.as_slice() {
            [f] => match f.unary {
                Unary::Id => Some(Power::Fixed(1.0)),
                Unary::Square | Unary::SignedSquare => Some(Power::Fixed(2.0)),
                Unary::Cube => Some(Power::Fixed(3.0)),
                Unary::Power => Some(Power::Free("p".into())),
                _ => None,
            },
            _ => None,
        };
        let place = if to == To::Rates { format!("d{target}/dt") } else { target.to_string() };
        Candidate {
            name: format!("{}_on_{target}", term.name(symbols)),
            to,
            target: target.into(),
            template: term.render(symbols, &|p| format!("{{{p}}}")),
            parameters: std::iter::once(("c".to_string(), Range::Coefficient, None))
                .chain(term.nonlinear.iter().map(|p| (p.name.clone(), Range::Span(p.min, p.max, 1), None)))
                .collect(),
            nats: term.nats,
            meaning: format!("{} in {place}", term.meaning(symbols)),
            rank: 0,
            power,
            symbols: term.factors.iter().map(|f| symbols[f.symbol].name.clone()).collect(),
            library_unary: match term.factors.as_slice() {
                [f] => Some(f.unary),
                _ => None,
            },
            theta: None,
        }
    }

    /// A library term the screening along the data found, with its fit there as the start.
    pub fn from_found(f: &Found, symbols: &[Symbol], to: To, target: &str) -> Candidate {
        let mut c = Candidate::library(&f.term, symbols, to, target);
        let size = f.unit_size.max(f64::MIN_POSITIVE);
        let reach = COEFFICIENT_REACH * (f.coefficient.abs() * size).max(f.mismatch) / size;
        c.parameters[0] = ("c".into(), Range::Reach(round_up(reach)), Some(f.coefficient));
        for (p, v) in c.parameters[1..].iter_mut().zip(&f.nonlinear) {
            p.2 = Some(*v);
        }
        c.theta = Some(f.theta.clone());
        c
    }

    /// A library term fitted from the base fit alone.
    pub fn from_term(term: &Term, symbols: &[Symbol], to: To, target: &str) -> Candidate {
        Candidate::library(term, symbols, to, target)
    }

    /// The term with its parameters named with `suffix`.
    fn render(&self, suffix: &str) -> String {
        let mut text = self.template.clone();
        for (p, _, _) in &self.parameters {
            text = text.replace(&format!("{{{p}}}"), &format!("{p}{suffix}"));
        }
        text
    }
}

/// A candidate (or pair) and its least-squares fit through the model.
pub struct Screened {
    pub parts: Vec<Candidate>,
    pub table: CandidateTable,
    pub simulator: Arc<dyn Simulator>,
    pub fitted: Fitted,
    /// Terms the data could not tell from this one, merged into it (`distinct`).
    pub readings: Vec<String>,
}

impl Screened {
    /// The term parameters' best-fit values, named with `suffix` as in a pair.
    fn fitted_terms(&self, suffix: &str) -> BTreeMap<String, f64> {
        let theta = self.fitted.phi.len() - self.table.parameters.len();
        self.table.parameters.keys().zip(&self.fitted.phi[theta..]).map(|(n, v)| (format!("{n}{suffix}"), *v)).collect()
    }

    /// The term as a physicist reads it: where it enters, what it means,
    /// and its parameters at the screening's fit.
    pub fn reading(&self) -> String {
        let meaning = self.parts.iter().map(|i| i.meaning.as_str()).collect::<Vec<_>>().join("; and ");
        let fitted: Vec<String> =
            self.fitted_terms("").iter().map(|(n, v)| format!("{n} = {}", fitted_value(*v))).collect();
        format!("{} ({meaning}; at the screening's fit {})", describe(&self.table), fitted.join(", "))
    }

    /// The screened term as a candidate, with its prior odds.
    pub fn proposal(self, base_chi2: f64, delta_bic: f64, prior: &FormPrior, theta: &[String]) -> Proposal {
        let names = theta.iter().chain(self.table.parameters.keys());
        let best_fit = names.zip(&self.fitted.phi).map(|(n, v)| (n.clone(), *v)).collect();
        let prior_log_odds = prior.log_odds(&self.parts.iter().map(|p| p.nats).collect::<Vec<_>>());
        let formula = describe(&self.table);
        let meaning = self.parts.iter().map(|i| i.meaning.as_str()).collect::<Vec<_>>().join("; and ");
        Proposal {
            meaning,
            toml: candidate_toml(&self.table),
            formula: formula.clone(),
            delta_chi2: base_chi2 - self.fitted.chi2,
            delta_bic,
            prior_log_odds,
            best_fit,
            readings: self.readings,
            candidate: CandidateModel {
                name: self.table.name.clone(),
                description: format!("discovered: {formula}"),
                extra_parameters: self.table.parameters.iter().map(|(n, p)| (n.clone(), p.clone())).collect(),
                simulator: self.simulator,
                special_case_of: Vec::new(),
                own_emulator: false,
            },
        }
    }
}

/// What every fit of one screening shares: the model, the data's scales,
/// the states along the data at the base fit, and the mismatch there.
pub struct Context<'a> {
    discoverer: &'a DeclaredDiscoverer,
    data: &'a ScreeningData<'a>,
    base: &'a Fitted,
    span: f64,
    n: f64,
    /// Each symbol's largest size and scale on the data at the base fit.
    smax: BTreeMap<String, f64>,
    scales: BTreeMap<String, Scale>,
    ymax: BTreeMap<String, f64>,
    one_signed: BTreeSet<String>,
    /// Each state at every point of the data (blocks in a row), at the base fit.
    trajectories: BTreeMap<String, Vec<f64>>,
    /// Each block's largest |y − η| at the base fit, or its largest error if larger.
    mismatch: Vec<f64>,
}

/// The terms one screening searched: how many, the grammar's forms, and each one's prior cost.
pub struct Searched {
    pub count: usize,
    pub forms: Vec<String>,
    pub nats: Vec<f64>,
}

impl<'a> Context<'a> {
    pub fn new(
        discoverer: &'a DeclaredDiscoverer,
        data: &'a ScreeningData<'a>,
        base: &'a Fitted,
    ) -> Result<Context<'a>> {
        let xs: Vec<f64> = data.blocks.iter().flat_map(|b| b.x.iter().copied()).collect();
        let (lo, hi) = xs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| (l.min(*x), h.max(*x)));
        let n = data.blocks.iter().map(|b| b.x.len()).max().unwrap_or(1) as f64;
        let d = &discoverer.base;
        let mut context = Context {
            discoverer,
            data,
            base,
            span: (hi - lo).max(f64::MIN_POSITIVE),
            n,
            smax: BTreeMap::new(),
            scales: BTreeMap::new(),
            ymax: BTreeMap::new(),
            one_signed: BTreeSet::new(),
            trajectories: BTreeMap::new(),
            mismatch: Vec::new(),
        };
        context.record(&d.input, &xs);
        if !d.states.is_empty() {
            let model = discoverer.family.compile(&discoverer.file, &with_states_observed(d, &discoverer.file))?;
            let first = d.observables.len();
            for (k, s) in d.states.iter().enumerate() {
                let mut all = Vec::with_capacity(xs.len());
                for b in &data.blocks {
                    let mut out = vec![0.0; b.x.len()];
                    model.predict(first + k, b.x, &base.phi[..data.theta.len()], &mut out);
                    all.extend(out);
                }
                context.record(&s.name, &all);
                context.trajectories.insert(s.name.clone(), all);
            }
        }
        let mut offset = 0;
        for b in &data.blocks {
            let name = d.observables.get(b.model_index).map_or(String::new(), |(o, _)| o.clone());
            let size = b.y.iter().fold(0.0f64, |m, y| m.max(y.abs()));
            context.ymax.entry(name).and_modify(|m| *m = m.max(size)).or_insert(size);
            let residual = (0..b.x.len()).map(|i| (b.y[i] - base.prediction[offset + i]).abs()).fold(0.0, f64::max);
            context.mismatch.push(residual.max(b.error.iter().fold(0.0f64, |m, e| m.max(*e))));
            offset += b.x.len();
        }
        Ok(context)
    }

    fn record(&mut self, name: &str, values: &[f64]) {
        let (lo, hi) = values.iter().fold((0.0f64, 0.0f64), |(l, h), v| (l.min(*v), h.max(*v)));
        let size = hi.max(-lo);
        if lo >= -0.01 * size || hi <= 0.01 * size {
            self.one_signed.insert(name.to_string());
        }
        self.smax.insert(name.to_string(), size);
        if let Some(scale) = Scale::of(values) {
            self.scales.insert(name.to_string(), scale);
        }
    }

    pub fn one_signed(&self, symbol: &str) -> bool {
        self.one_signed.contains(symbol)
    }

    pub fn trajectory(&self, state: &str) -> Option<Vec<f64>> {
        self.trajectories.get(state).cloned()
    }

    /// The places no screening along the data covered, with their symbols
    /// along the base fit's trajectory: laws whose state nobody observes.
    pub fn unobserved_places(&self, to: To, covered: &[String]) -> Vec<(String, Vec<Symbol>)> {
        if to != To::Rates {
            return Vec::new();
        }
        let angles = grammar::angles(&self.discoverer.base);
        let symbols: Vec<Symbol> =
            self.trajectories.iter().filter_map(|(name, v)| Symbol::of(name, v, angles.contains(name))).collect();
        grammar::laws(&self.discoverer.base)
            .into_iter()
            .filter(|(state, _)| !covered.contains(state))
            .map(|(state, _)| (state, symbols.clone()))
            .collect()
    }

    /// The grammar's instances on this model, as candidates.
    pub fn grammar_candidates(&self, forms: &[TermForm]) -> Vec<Candidate> {
        grammar::instances(forms, &self.discoverer.base).into_iter().filter_map(|i| self.candidate_of(&i)).collect()
    }

    fn candidate_of(&self, i: &Instance) -> Option<Candidate> {
        let scale = i.symbols.first().and_then(|s| self.scales.get(s));
        let mut template = i.form.clone();
        if let Some(s) = scale {
            template =
                template.replace("{sref}", &seven_digits(s.reference)).replace("{sspan}", &seven_digits(s.span()));
        }
        let mut parameters = Vec::new();
        for (p, form) in &i.parameters {
            parameters.push((p.clone(), self.range(i, form)?, None));
        }
        let mut named = template.clone();
        for (p, _, _) in &parameters {
            named = named.replace(&format!("{{{p}}}"), p);
        }
        Some(Candidate {
            name: i.name.clone(),
            to: i.to,
            target: i.target.clone(),
            template,
            parameters,
            nats: prior::nats_given(&named, &grammar::angles(&self.discoverer.base)),
            meaning: i.meaning.clone(),
            rank: 1 + i.rank,
            power: i.power.clone(),
            symbols: i.symbols.clone(),
            library_unary: None,
            theta: None,
        })
    }

    fn range(&self, term: &Instance, form: &ParameterForm) -> Option<Range> {
        match form {
            ParameterForm::Kind(_) => Some(Range::Coefficient),
            ParameterForm::Range { min, max, starts } => {
                let smax = term.symbols.iter().filter_map(|s| self.smax.get(s)).fold(0.0f64, |m, v| m.max(*v));
                let scope = grammar::bound_scope();
                let all = self.ymax.values().fold(0.0f64, |m, v| m.max(*v));
                let ymax = match term.to {
                    To::Observables | To::Measured => self.ymax.get(&term.target).copied().unwrap_or(all),
                    To::Rates | To::Parameters => all,
                };
                let values = [self.span, self.n, smax.max(f64::MIN_POSITIVE), ymax.max(f64::MIN_POSITIVE)];
                let eval = |text: &str| formula::Formula::parse(text, &scope, "grammar").ok().map(|f| f.eval(&values));
                let (lo, hi) = (eval(min)?, eval(max)?);
                (lo.is_finite() && hi.is_finite() && hi > lo).then_some(Range::Span(lo, hi, (*starts).max(1)))
            }
        }
    }

    /// How many terms were searched, the grammar's forms, and each term's
    /// cost: the grammar's instances and every library term tried.
    pub fn searched(&self, forms: &[TermForm], grammar_and_library: &[Candidate], library_nats: &[f64]) -> Searched {
        let grammar: Vec<f64> = grammar_and_library.iter().filter(|c| c.rank > 0).map(|c| c.nats).collect();
        let mut names: Vec<String> = Vec::new();
        for i in grammar::instances(forms, &self.discoverer.base) {
            let form = &forms[i.rank].form;
            if !names.contains(form) {
                names.push(form.clone());
            }
        }
        if !library_nats.is_empty() {
            names.insert(0, "c times powers (whole, fractional or free), exp, log, sin, cos, saturating, Hill and logistic forms of each symbol, and their products across symbols".into());
        }
        let nats: Vec<f64> = grammar.into_iter().chain(library_nats.iter().copied()).collect();
        Searched { count: nats.len(), forms: names, nats }
    }

    /// Fits the model with `parts` added; None when the term cannot be
    /// declared or computed (a form undefined on these data).
    pub fn fit(&self, parts: &[&Candidate], also_from: Option<(&[f64], BTreeMap<String, f64>)>) -> Option<Screened> {
        if let [a, b] = parts {
            // One parameter cannot vary two ways at once.
            if a.to == To::Parameters && b.to == To::Parameters && a.target == b.target {
                return None;
            }
        }
        let (suffixes, ranges) = self.named(parts);
        let n_theta = self.data.theta.len();
        let measured = ranges.iter().any(|(_, r, _)| matches!(r, Range::Coefficient));
        let reach = if measured {
            // Coefficients at ±1 first, to measure how far one unit moves the model.
            let provisional = self.table(parts, &suffixes, &ranges, 1.0);
            let model = self.discoverer.compile(&provisional)?;
            let mid: Vec<f64> = self.base.phi.iter().copied().chain(ranges.iter().map(|(_, r, _)| start(r))).collect();
            self.coefficient_reach(model.as_ref(), &mid)?
        } else {
            1.0
        };
        let table = self.table(parts, &suffixes, &ranges, reach);
        let simulator = self.discoverer.compile(&table)?;
        // The calibration refuses a model that cannot be computed at its
        // prior box's corners or centre (`check_inputs`): such a term is no
        // candidate on these data.
        if self.data.blocks.iter().any(|b| simulator.check_inputs(b.model_index, b.x).is_err()) {
            return None;
        }
        for b in &self.data.blocks {
            simulator.note_measurements(b.model_index, b.y, b.error);
        }
        let mut bounds = self.data.bounds.clone();
        bounds.extend(table.parameters.values().map(|p| (p.min, p.max)));
        let ls = LeastSquares { blocks: &self.data.blocks, model: simulator.as_ref(), bounds };
        let mut all = starts(&self.base.phi[..n_theta], &ranges);
        if let [c] = parts {
            if let Some(theta) = &c.theta {
                let found = ranges.iter().map(|(_, r, v)| v.unwrap_or_else(|| start(r)));
                all.push(theta.iter().copied().chain(found).collect());
            }
        }
        if let Some((theta, terms)) = also_from {
            let found = ranges.iter().map(|(n, r, _)| terms.get(n).copied().unwrap_or_else(|| start(r)));
            all.push(theta.iter().copied().chain(found).collect());
        }
        let fitted = ls.best_of(&all)?;
        let parts = parts.iter().map(|c| (*c).clone()).collect();
        Some(Screened { parts, table, simulator, fitted, readings: Vec::new() })
    }

    /// Each part's suffix for its parameters' names (a pair keeps its two
    /// apart; a name the model has already gets `_new`), and every
    /// parameter so named, in the order the compiled model takes them: by name.
    fn named(&self, parts: &[&Candidate]) -> (Vec<String>, Vec<(String, Range, Option<f64>)>) {
        let d = &self.discoverer.base;
        let suffixes: Vec<String> = if parts.len() > 1 {
            vec!["1".into(), "2".into()]
        } else if parts[0].parameters.iter().any(|(p, _, _)| d.knows(p)) {
            vec!["_new".into()]
        } else {
            vec![String::new()]
        };
        let mut ranges: Vec<(String, Range, Option<f64>)> = parts
            .iter()
            .zip(&suffixes)
            .flat_map(|(c, s)| c.parameters.iter().map(move |(p, r, v)| (format!("{p}{s}"), r.clone(), *v)))
            .collect();
        ranges.sort_by(|a, b| a.0.cmp(&b.0));
        (suffixes, ranges)
    }

    /// The candidate's table with its coefficients within ±`coefficient`,
    /// and its starting points (θ from `theta`): for a fit along the data.
    pub fn along_table(&self, c: &Candidate, coefficient: f64, theta: &[f64]) -> (CandidateTable, Vec<Vec<f64>>) {
        let (suffixes, ranges) = self.named(&[c]);
        let table = self.table(&[c], &suffixes, &ranges, coefficient);
        (table, starts(theta, &ranges))
    }

    /// Two screened terms fitted together, also from where each fitted alone.
    pub fn pair(&self, a: &Screened, b: &Screened) -> Option<Screened> {
        let mut joint: BTreeMap<String, f64> = a.fitted_terms("1");
        joint.extend(b.fitted_terms("2"));
        let theta = &a.fitted.phi[..self.data.theta.len()];
        self.fit(&[&a.parts[0], &b.parts[0]], Some((theta, joint)))
    }

    /// Half-width of a measured coefficient's prior: `COEFFICIENT_REACH`
    /// times the coefficient that moves some observable by the mismatch
    /// the model shows there (its largest |y − η| at the base fit, or its
    /// largest error if that is larger): the prior follows the size of
    /// what is to be explained, not the observable's magnitude.
    fn coefficient_reach(&self, model: &dyn Simulator, phi: &[f64]) -> Option<f64> {
        let blocks = &self.data.blocks;
        let ls = LeastSquares { blocks, model, bounds: vec![(f64::NEG_INFINITY, f64::INFINITY); phi.len()] };
        let at = ls.predict(phi)?;
        let n_theta = self.data.theta.len();
        let mut reach = f64::INFINITY;
        for k in n_theta..phi.len() {
            let mut moved = phi.to_vec();
            moved[k] += 1e-3;
            let p = ls.predict(&moved)?;
            let mut offset = 0;
            for (b, size) in blocks.iter().zip(&self.mismatch) {
                let slope = (offset..offset + b.x.len()).map(|i| ((p[i] - at[i]) / 1e-3).abs()).fold(0.0, f64::max);
                if slope > 0.0 && *size > 0.0 {
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
        parts: &[&Candidate],
        suffixes: &[String],
        ranges: &[(String, Range, Option<f64>)],
        reach: f64,
    ) -> CandidateTable {
        let mut rates: BTreeMap<String, String> = BTreeMap::new();
        let mut observables: BTreeMap<String, String> = BTreeMap::new();
        let mut vary: BTreeMap<String, String> = BTreeMap::new();
        for (part, suffix) in parts.iter().zip(suffixes) {
            let to = match part.to {
                To::Rates => &mut rates,
                To::Observables | To::Measured => &mut observables,
                To::Parameters => &mut vary,
            };
            let text = part.render(suffix);
            let joined = match to.get(&part.target) {
                Some(before) => format!("{before} + {text}"),
                None => text,
            };
            to.insert(part.target.clone(), joined);
        }
        let parameters = ranges
            .iter()
            .map(|(name, r, _)| {
                let (min, max) = match r {
                    Range::Coefficient => (-reach, reach),
                    Range::Reach(h) => (-h, *h),
                    Range::Span(lo, hi, _) => (*lo, *hi),
                };
                (name.clone(), ParamSpec { min, max, truth: None, units: String::new() })
            })
            .collect();
        let name = parts.iter().map(|t| t.name.as_str()).collect::<Vec<_>>().join("+");
        CandidateTable { description: String::new(), name, observables, rates, vary, parameters }
    }
}

impl DeclaredDiscoverer {
    pub(super) fn compile(&self, table: &CandidateTable) -> Option<Arc<dyn Simulator>> {
        let declared: Declared = self.base.with_candidate(&self.file, table).ok()?;
        self.family.compile(&self.file, &declared).ok()
    }
}

fn start(r: &Range) -> f64 {
    match r {
        Range::Coefficient | Range::Reach(_) => 0.0,
        Range::Span(lo, hi, _) => 0.5 * (lo + hi),
    }
}

/// Starting points: θ at the base fit, coefficients at 0, and every
/// combination of each ranged parameter's starts (midpoints of equal cells).
fn starts(theta: &[f64], ranges: &[(String, Range, Option<f64>)]) -> Vec<Vec<f64>> {
    let mut out = vec![theta.to_vec()];
    for (_, r, _) in ranges {
        let values: Vec<f64> = match r {
            Range::Coefficient | Range::Reach(_) => vec![0.0],
            Range::Span(lo, hi, n) => (0..*n).map(|i| lo + (hi - lo) * (i as f64 + 0.5) / *n as f64).collect(),
        };
        out = out.into_iter().flat_map(|s| values.iter().map(move |v| [s.clone(), vec![*v]].concat())).collect();
    }
    out
}

/// `c*v*abs(v) in dv/dt` for each term of a candidate table.
pub fn describe(table: &CandidateTable) -> String {
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
