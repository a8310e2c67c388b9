//! Discovery for declared models: the physics nobody declared, searched
//! among terms built by composition from the model's own symbols
//! (`engine::discover::library`) and among the forms of the grammar
//! (`grammar`: the physics of the measurement, parameters that vary,
//! drives and transients in t, and a user's own forms).
//!
//! Screening comes in two steps. Where the data show what a law must
//! supply (a state observed, its rate read off the data; an expression's
//! observable), every library term is regressed on it at once
//! (`engine::discover::along`), and the best few go on. Then those, the
//! grammar's forms, and for a law nobody observes the library's cheapest
//! terms, are fitted to the data through the model (`fit`: least squares
//! with θ, an ODE integrated), ranked by the Bayesian information
//! criterion ΔBIC = Δχ² − k ln N; a pair stays only if it beats every term
//! alone (forward selection). Terms that fit the data the same way are one
//! explanation, and the simpler stands for both (`discover::distinct`).
//! The best few are handed back as candidates; `diagnose` then judges them
//! by full calibration and evidence, with prior odds that pay for the
//! number searched (`discover::prior`).

mod along;
mod candidate;
pub mod grammar;
mod identities;
mod shoot;

use super::declaration::{Declared, Written};
use super::DeclaredFamily;
use crate::engine::discover::along::{fit as along_fit, screen as screen_along};
use crate::engine::discover::distinct::{distinct, Explanation};
use crate::engine::discover::library::{self, Unary};
use crate::engine::discover::prior::FormPrior;
use crate::engine::model::fit::{Fitted, LeastSquares};
use crate::engine::model::{Discoverer, Screening, ScreeningData, SpecialCase};
use anyhow::Result;
use candidate::{Candidate, Screened};
use grammar::{Power, TermForm, To};
use rayon::prelude::*;
use shoot::Best;

/// How many screened terms (or pairs) go on to full calibration.
const PROPOSALS: usize = 3;
/// How far below the best a term's score (ΔBIC/2 plus its prior log odds,
/// about a log posterior odds) may be and still be calibrated: a term 10
/// below trails beyond any decisive lead (3), and its calibration could not
/// change the verdict unless BIC misjudged the evidence by more than that.
const SCORE_REACH: f64 = 10.0;
/// Singles whose pairs are screened. Flexible single terms (a logistic
/// step, a squared cosine of a state) each absorb part of two concealed
/// terms and crowd the top of the ranking, so the window is wider than the
/// few proposals: 8 singles, 28 pairs.
const PAIRED: usize = 8;
/// Pairs among the proposals: the best pair, the other slots to singles. A
/// second pair mostly shares a term with the first and pays the same
/// look-elsewhere odds over every pair, and it took the slot of a single
/// the data favoured.
const PAIRS_PROPOSED: usize = 1;
/// Library terms that the screening along the data hands on to the fit
/// through the model.
const ALONG_KEPT: usize = 10;
/// Library terms fitted through the model for a law whose rate the data do
/// not show (no state observed): the cheapest by the prior over forms.
const UNOBSERVED_BUDGET: usize = 24;
/// The prior cost up to which a library term of an observed place is
/// fitted through the model whatever the screening along the data found:
/// a constant, a state, a product of two states or a square (0, 0.30,
/// 0.60 and 0.93 nats), the forms a quadratic polynomial holds; the next
/// cheapest (a saturation, 1.69) is already a guess at the physics.
const CHEAPEST_NATS: f64 = 1.0;
/// At most this many of them, cheapest first: their number grows steeply
/// with the states (products of two and of three states and reciprocals,
/// in every law), and each is a fit through the model. 64 holds every one
/// of a 3-state system's; a 10-state system would have thousands.
const CHEAPEST_BUDGET: usize = 64;
/// The grammar's forms that change a law, fitted along the data, that go
/// on to the fit through the model.
const PRESCREEN_KEPT: usize = 6;
/// A grammar coefficient's bound in a fit along the data, in units of the
/// largest rate there: wide enough never to bind.
const ALONG_COEFFICIENT: f64 = 1e3;

pub struct DeclaredDiscoverer {
    pub(super) family: DeclaredFamily,
    pub(super) file: String,
    pub(super) base: Declared,
    pub(super) forms: Vec<TermForm>,
}

impl Discoverer for DeclaredDiscoverer {
    /// Screens the model as declared, with every rate that reads as a
    /// kinematic identity but that the data contradict read as a law
    /// (`identities`), and says so.
    fn screen(&self, data: &ScreeningData) -> Result<Screening> {
        let contradicted = identities::contradicted(&self.base, data);
        if contradicted.is_empty() {
            return self.screen_or_shoot(data);
        }
        let mut base = self.base.clone();
        let mut notes = Vec::new();
        for c in &contradicted {
            let state = &mut base.states[c.state];
            state.law_by_data = true;
            notes.push(format!(
                "d{}/dt = {} reads as a definition, but the rate of {} read off the data departs from it by {:+.1}σ on average: it was searched as a law written short",
                state.name, state.rate.text, state.name, c.bias_sigma
            ));
        }
        let as_laws = DeclaredDiscoverer {
            family: self.family.clone(),
            file: self.file.clone(),
            base,
            forms: self.forms.clone(),
        };
        let mut screening = as_laws.screen_or_shoot(data)?;
        screening.notes.extend(notes);
        Ok(screening)
    }
}

impl DeclaredDiscoverer {
    /// The screening, and the best fit of a form it made (the base's when none).
    fn screen_declared(&self, data: &ScreeningData) -> Result<(Screening, Best)> {
        let base_model = self.family.compile(&self.file, &self.base)?;
        if self.base.shooting.is_some() {
            // The anchors are the data's (`ode::shooting`).
            for b in &data.blocks {
                base_model.check_inputs(b.model_index, b.x)?;
                base_model.note_measurements(b.model_index, b.y, b.error);
            }
        }
        let base = LeastSquares { blocks: &data.blocks, model: base_model.as_ref(), bounds: data.bounds.clone() };
        // A model that cannot be computed over the data (an ODE that blows
        // up) has no fit: terms are then screened along the data and fitted
        // from there, and ranked by their own χ².
        // By shooting, θ's fit from the base's calibration (a model one
        // trajectory could not follow) may sit in a basin of its own: the
        // prior's middle is a second start.
        let base_fit = match self.base.shooting {
            Some(_) => {
                base.best_of(&[data.theta.clone(), data.bounds.iter().map(|(lo, hi)| 0.5 * (lo + hi)).collect()])
            }
            None => base.fit(&data.theta),
        };
        let base_fit = base_fit.unwrap_or_else(|| Fitted {
            phi: data.theta.clone(),
            chi2: f64::INFINITY,
            prediction: vec![f64::NAN; base.points()],
        });
        let context = candidate::Context::new(self, data, &base_fit)?;
        let grammar = context.grammar_candidates(&self.forms);
        let observed = along::Observed::read(&self.base, data);
        let trajectory = |state: &str| context.trajectory(state);
        let along_base = if self.base.states.is_empty() {
            along::expression(&self.base, data, base_model.clone())
        } else {
            along::ode(&self.file, &self.base, data, &observed, &trajectory)
        };
        let theta = &base_fit.phi[..data.theta.len()];
        let (library, library_nats) = self.library_candidates(data, theta, along_base.as_ref(), &context);
        let mut all = library;
        let searched = context.searched(&self.forms, &grammar, &library_nats);
        all.extend(match &along_base {
            Some(a) if !self.base.states.is_empty() => self.prescreen(grammar, a, data, &observed, &context, theta),
            _ => grammar,
        });
        let mut singles: Vec<Screened> = all.par_iter().filter_map(|c| context.fit(&[c], None)).collect();
        let points = base.points() as f64;
        let reference = if base_fit.chi2.is_finite() {
            base_fit.chi2
        } else {
            singles.iter().map(|s| s.fitted.chi2).fold(0.0, f64::max)
        };
        let bic = bic_of(reference, points, self.dispersion(&singles, points));
        let prior = FormPrior::over(&searched.nats);
        // Ranked by ΔBIC/2 (about a log Bayes factor) plus the prior's log
        // odds: about a log posterior odds, the order the calibrations will judge in.
        let score = |s: &Screened| 0.5 * bic(s) + prior.log_odds(&s.parts.iter().map(|p| p.nats).collect::<Vec<_>>());
        singles.sort_by(|a, b| score(b).total_cmp(&score(a)));
        let singles = distinct(singles, data);
        let top: Vec<&Screened> = singles.iter().take(PAIRED).collect();
        let pairs: Vec<(&Screened, &Screened)> =
            top.iter().enumerate().flat_map(|(i, a)| top[i + 1..].iter().map(move |b| (*a, *b))).collect();
        let best_single = singles.first().map_or(f64::NEG_INFINITY, &score);
        let mut ranked: Vec<Screened> = pairs
            .par_iter()
            .filter_map(|(a, b)| context.pair(a, b))
            // Forward selection: a second term is kept only when the pair
            // beats every single term (not only its own two). A pair below
            // some single is, by the screening's own criterion, a worse
            // explanation than one already proposed.
            .filter(|s| score(s) > best_single)
            .collect();
        ranked.extend(singles);
        ranked.sort_by(|a, b| score(b).total_cmp(&score(a)));
        let ranked = distinct(ranked, data);
        let best = ranked.first().map_or(f64::NEG_INFINITY, &score);
        let best_fit = ranked.iter().min_by(|a, b| a.fitted.chi2.total_cmp(&b.fitted.chi2));
        let best_fit = match best_fit {
            Some(s) if s.fitted.chi2 < base_fit.chi2 => {
                Best { chi2: s.fitted.chi2, table: Some(s.table.clone()), phi: s.fitted.phi.clone() }
            }
            _ => Best { chi2: base_fit.chi2, table: None, phi: base_fit.phi.clone() },
        };
        let unshot = self.without_shooting();
        let mut pairs = 0;
        let proposals = ranked
            .into_iter()
            .filter(|s| bic(s) > 0.0 && score(s) >= best - SCORE_REACH)
            .filter(|s| {
                pairs += usize::from(s.parts.len() > 1);
                s.parts.len() == 1 || pairs <= PAIRS_PROPOSED
            })
            .take(PROPOSALS)
            .filter_map(|mut s| {
                if let Some(unshot) = &unshot {
                    // Calibrated as every model is: one trajectory from t0.
                    s.simulator = unshot.compile(&s.table)?;
                }
                Some(s)
            })
            .map(|s| {
                let special = special_cases(&s.parts, &all, &context);
                let delta_bic = bic(&s);
                let mut p = s.proposal(reference, delta_bic, &prior, &self.base.parameters);
                p.candidate.special_case_of = special;
                p
            })
            .collect();
        let screening = Screening { searched: searched.count, forms: searched.forms, proposals, notes: Vec::new() };
        Ok((screening, best_fit))
    }

    /// How much wider than the data's errors the residuals are: 1, but
    /// for a screening by shooting, whose anchors' errors move every point
    /// predicted from them, the best single form's χ² per degree of freedom
    /// (at least 1). Unscaled, those inflated χ² made any flexible second
    /// term worth its parameters by BIC.
    fn dispersion(&self, singles: &[Screened], points: f64) -> f64 {
        if self.base.shooting.is_none() {
            return 1.0;
        }
        let per_dof = |s: &Screened| s.fitted.chi2 / (points - s.fitted.phi.len() as f64).max(1.0);
        singles.iter().map(per_dof).filter(|d| d.is_finite()).fold(f64::INFINITY, f64::min).clamp(1.0, f64::MAX)
    }

    /// This discoverer integrating from t0, when it shoots.
    fn without_shooting(&self) -> Option<DeclaredDiscoverer> {
        let mut base = self.base.clone();
        base.shooting.take()?;
        Some(DeclaredDiscoverer {
            family: self.family.clone(),
            file: self.file.clone(),
            base,
            forms: self.forms.clone(),
        })
    }
}

impl DeclaredDiscoverer {
    /// The library's terms for each law (or, for an expression model, each
    /// observable): those the screening along the data finds, or, for a law
    /// whose rate the data do not show, the cheapest; and the prior cost of
    /// every library term tried.
    fn library_candidates(
        &self,
        data: &ScreeningData,
        theta: &[f64],
        found: Option<&along::DeclaredAlong>,
        context: &candidate::Context,
    ) -> (Vec<Candidate>, Vec<f64>) {
        let to = if self.base.states.is_empty() { To::Observables } else { To::Rates };
        let (mut out, mut nats) = (Vec::new(), Vec::new());
        let mut covered = Vec::new();
        if let Some(a) = found {
            let library = |p: &crate::engine::discover::along::Place| library::terms(&p.symbols);
            let kept = screen_along(&a.along, a.model.as_ref(), &library, theta, &data.bounds, ALONG_KEPT);
            for f in kept.map(|(_, k)| k).unwrap_or_default() {
                let place = &a.along.places[f.place];
                out.push(Candidate::from_found(&f, &place.symbols, to, &a.targets[f.place]));
            }
            for place in &a.along.places {
                nats.extend(library::terms(&place.symbols).iter().map(|t| t.nats));
            }
            let cheapest = cheapest_unscreened(a, &out, to);
            out.extend(cheapest);
            covered = a.targets.clone();
        }
        for (target, symbols) in context.unobserved_places(to, &covered) {
            let mut terms = library::terms(&symbols);
            terms.sort_by(|a, b| a.nats.total_cmp(&b.nats));
            for term in terms.into_iter().filter(|t| t.nonlinear.is_empty()).take(UNOBSERVED_BUDGET) {
                nats.push(term.nats);
                out.push(Candidate::from_term(&term, &symbols, to, &target));
            }
        }
        (out, nats)
    }

    /// The grammar's forms that change a law (a term in it, a parameter
    /// that varies) fitted along the data first, where no integration is
    /// needed; the best `PRESCREEN_KEPT` of them, and every form that acts
    /// on the measurement, go on to the fit through the model.
    fn prescreen(
        &self,
        grammar: Vec<Candidate>,
        base: &along::DeclaredAlong,
        data: &ScreeningData,
        observed: &along::Observed,
        context: &candidate::Context,
        theta: &[f64],
    ) -> Vec<Candidate> {
        let Some(base_fit) = along_fit(&base.along, base.model.as_ref(), &[theta.to_vec()], &data.bounds) else {
            return grammar;
        };
        let trajectory = |state: &str| context.trajectory(state);
        let rows = base.along.target.len() as f64;
        let (laws, measured): (Vec<Candidate>, Vec<Candidate>) =
            grammar.into_iter().partition(|c| matches!(c.to, To::Rates | To::Parameters));
        let size = base.along.target.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(f64::MIN_POSITIVE);
        let mut scored: Vec<(f64, Candidate)> = laws
            .into_par_iter()
            .filter_map(|c| {
                let (table, starts) = context.along_table(&c, ALONG_COEFFICIENT * size, theta);
                let declared = self.base.with_candidate(&self.file, &table).ok()?;
                let a = along::ode(&self.file, &declared, data, observed, &trajectory)?;
                let mut bounds = data.bounds.clone();
                bounds.extend(table.parameters.values().map(|p| (p.min, p.max)));
                let fit = along_fit(&a.along, a.model.as_ref(), &starts, &bounds)?;
                let score = base_fit.chi2 - fit.chi2 - table.parameters.len() as f64 * rows.ln();
                (score > 0.0).then_some((score, c))
            })
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        scored.into_iter().take(PRESCREEN_KEPT).map(|(_, c)| c).chain(measured).collect()
    }
}

/// The prior's cheapest forms of each observed place, fitted through the
/// model whatever the screening along the data made of them: there the
/// rate is read off smoothed states, whose bias can bury the simplest law
/// under flexible forms (a Gray–Scott loss -0.02·x_1 ranked 87th along the
/// data, behind sines and saturations of the same states, and was never
/// fitted; the model's own rate rescaled was named in its place). These
/// terms were counted among those searched already, so fitting them costs
/// no prior odds, only a few fits.
fn cheapest_unscreened(a: &along::DeclaredAlong, kept: &[Candidate], to: To) -> Vec<Candidate> {
    let mut cheapest: Vec<Candidate> = a
        .along
        .places
        .iter()
        .zip(&a.targets)
        .flat_map(|(place, target)| {
            library::terms(&place.symbols)
                .into_iter()
                .filter(|t| t.nonlinear.is_empty() && t.nats <= CHEAPEST_NATS)
                .map(move |t| Candidate::from_term(&t, &place.symbols, to, target))
        })
        .filter(|c| !kept.iter().any(|k| k.name == c.name))
        .collect();
    // Cheapest first across places (a stable sort keeps the library's order
    // among equals), within a budget.
    cheapest.sort_by(|x, y| x.nats.total_cmp(&y.nats));
    cheapest.truncate(CHEAPEST_BUDGET);
    cheapest
}

/// The free powers a single fixed-power term is a special case of: the
/// same symbol joining the same place (`c*v*abs(v)` in dv/dt is
/// `c*abs(v/S)^p` in dv/dt at p = 2), where the symbol keeps one sign.
fn special_cases(parts: &[Candidate], all: &[Candidate], context: &candidate::Context) -> Vec<SpecialCase> {
    let [term] = parts else { return Vec::new() };
    let mut out = saturation_limits(term, all);
    out.extend(whole_power_cases(term, all, context));
    out
}

/// Where a saturating form s/(K + |s|), or a Hill form s²/(K² + s²), has
/// its scale K this share of the way up its range (27 times the largest |s|
/// on the data: the range ends at 30), it is s/K within 4% over the data,
/// or s²/K² within 0.2%: the linear term or the square it holds. Where the
/// data leave K's 95% interval reaching that far, the two are one
/// explanation and the simpler is named (Occam): along a Rössler flow,
/// c*x_1 and c*x_1/(K + |x_1|) with K = 52 [38, 59] were rivals 2.0 nats
/// apart, the saturation never reached on the data.
const SATURATION_OUT_OF_REACH: f64 = 0.9;

fn saturation_limits(term: &Candidate, all: &[Candidate]) -> Vec<SpecialCase> {
    let held = match term.library_unary {
        Some(Unary::Id) => Unary::Saturating,
        Some(Unary::Square) => Unary::Hill,
        _ => return Vec::new(),
    };
    let same_place = |f: &&Candidate| f.to == term.to && f.target == term.target && f.symbols == term.symbols;
    all.iter()
        .filter(same_place)
        .filter(|f| f.library_unary == Some(held))
        .filter_map(|f| {
            f.parameters.iter().find_map(|(name, range, _)| match range {
                candidate::Range::Span(_, hi, _) if name.starts_with('K') => Some(SpecialCase {
                    of: f.name.clone(),
                    parameter: name.clone(),
                    value: SATURATION_OUT_OF_REACH * hi,
                }),
                _ => None,
            })
        })
        .collect()
}

/// A whole power of a one-signed symbol is the free power |s/S|^p at that p.
fn whole_power_cases(term: &Candidate, all: &[Candidate], context: &candidate::Context) -> Vec<SpecialCase> {
    let (Some(Power::Fixed(k)), Some(symbol)) = (&term.power, term.symbols.first()) else {
        return Vec::new();
    };
    if !context.one_signed(symbol) {
        return Vec::new();
    }
    let free = all.iter().filter(|f| f.to == term.to && f.target == term.target && f.symbols.first() == Some(symbol));
    let mut out: Vec<SpecialCase> = free
        .filter_map(|f| match &f.power {
            Some(Power::Free(p)) => Some(SpecialCase { of: f.name.clone(), parameter: p.clone(), value: *k }),
            _ => None,
        })
        .collect();
    // The library's free power of the same symbol, whether or not it was screened.
    let library_power = format!("{}_{}_on_{}", "power", symbol, term.target);
    if !out.iter().any(|s| s.of == library_power) && term.library_unary.is_some_and(|u| u != Unary::Power) {
        out.push(SpecialCase { of: library_power, parameter: "p".into(), value: *k });
    }
    out
}

/// ΔBIC of a screened form against the base, its Δχ² divided by the
/// residuals' dispersion (1 but where the screening shoots).
fn bic_of(base_chi2: f64, points: f64, dispersion: f64) -> impl Fn(&Screened) -> f64 {
    move |s| (base_chi2 - s.fitted.chi2) / dispersion - (s.table.parameters.len() as f64) * points.ln()
}

impl Explanation for Screened {
    fn fitted(&self) -> &Fitted {
        &self.fitted
    }

    fn added_parameters(&self) -> usize {
        self.table.parameters.len()
    }

    fn complexity(&self) -> (usize, usize, usize, usize) {
        // Nats in thousandths: the prior's cost orders forms of as many parameters.
        let nats: f64 = self.parts.iter().map(|p| p.nats).sum();
        (
            self.table.parameters.len(),
            self.parts.len(),
            (1000.0 * nats) as usize,
            self.parts.iter().map(|p| p.rank).sum(),
        )
    }

    fn reading(&self) -> String {
        Screened::reading(self)
    }

    fn readings_mut(&mut self) -> &mut Vec<String> {
        &mut self.readings
    }
}

/// Two significant figures, rounded up: a prior bound a person can read.
fn round_up(x: f64) -> f64 {
    let scale = 10f64.powf(x.log10().floor() - 1.0);
    (x / scale).ceil() * scale
}

/// The states as observables of the same model, for reading them off along the data's times.
fn with_states_observed(base: &Declared, file: &str) -> Declared {
    let mut d = base.clone();
    for s in &base.states {
        let place = format!("{file}: discover");
        d.observables.push((format!("state {}", s.name), Written { text: s.name.clone(), place }));
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_whole_power_is_the_saturating_form_whose_scale_is_out_of_reach() {
        use crate::engine::discover::library::Symbol;
        let values: Vec<f64> = (0..20).map(|i| -1.0 + 0.15 * i as f64).collect();
        let symbols = vec![Symbol::of("x", &values, false).unwrap()];
        let terms = library::terms(&symbols);
        let pick = |u: Unary| {
            let term = terms.iter().find(|t| matches!(t.factors.as_slice(), [f] if f.unary == u)).unwrap();
            Candidate::from_term(term, &symbols, To::Rates, "y")
        };
        let all: Vec<Candidate> = [Unary::Id, Unary::Saturating, Unary::Square, Unary::Hill].map(pick).into();
        let linear = saturation_limits(&all[0], &all);
        assert_eq!(linear.len(), 1, "{linear:?}");
        assert_eq!((linear[0].of.as_str(), linear[0].parameter.as_str()), (all[1].name.as_str(), "K"));
        // K's range ends at 30 times the largest |x| (1.85).
        assert!((linear[0].value - 0.9 * 30.0 * 1.85).abs() < 1e-9, "{}", linear[0].value);
        assert_eq!(saturation_limits(&all[2], &all)[0].of, all[3].name);
        // The saturating form holds no saturating form; nor does the linear term of another place.
        assert!(saturation_limits(&all[1], &all).is_empty());
        let elsewhere = Candidate::from_term(&terms[1], &symbols, To::Rates, "z");
        assert!(saturation_limits(&elsewhere, &all).is_empty());
    }

    #[test]
    fn bounds_round_up_to_two_significant_figures() {
        assert!((round_up(0.01234) - 0.013).abs() < 1e-15);
        assert!((round_up(37.2) - 38.0).abs() < 1e-12);
    }
}
