//! The grammar of terms (`grammar.toml`, extendable by a config) and its
//! instances: each form with the model's own symbols put in, ready to be
//! declared as a `[[candidates]]` table.

use super::super::declaration::Declared;
use crate::engine::formula::{Formula, Scope};
use anyhow::{anyhow, bail, Context, Result};
use std::collections::{BTreeMap, BTreeSet};

/// Most starting points of one parameter: the screening fits from each,
/// so a grammar cannot make it run for hours.
const MAX_STARTS: usize = 64;

/// The bundled grammar.
const DEFAULT: &str = include_str!("grammar.toml");

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct GrammarFile {
    terms: Vec<TermForm>,
}

/// Where a form's terms go (`to` in grammar.toml).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum To {
    /// Added to each state's rate of an ODE (not to a kinematic identity).
    Rates,
    /// Added to each observable of an expression model, built from the input.
    Observables,
    /// Added to each observable of any model, built from the observable
    /// itself: the physics of the measurement (offset, gain, dead time).
    Measured,
    /// Replacing a parameter everywhere the model uses it: a parameter that
    /// varies with the input or a state.
    Parameters,
}

/// One form of the grammar, as written.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TermForm {
    pub name: String,
    pub form: String,
    pub to: To,
    /// What the form means to a physicist, for the verdict.
    #[serde(default)]
    pub meaning: String,
    pub parameters: BTreeMap<String, ParameterForm>,
    /// The power of its symbol the form is, when all its symbols are one:
    /// a number (`c*v*abs(v)`: 2) or the parameter that is the exponent
    /// (`c*abs(v)^p`: "p"). A fixed power is then the free one at that
    /// exponent where the symbol keeps one sign over the data.
    #[serde(default)]
    pub power: Option<Power>,
    /// The form's size, for the prior over forms (set when read).
    #[serde(skip)]
    pub operations: usize,
}

#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(untagged)]
pub enum Power {
    Fixed(f64),
    Free(String),
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(untagged)]
pub enum ParameterForm {
    /// "coefficient".
    Kind(String),
    Range {
        min: String,
        max: String,
        #[serde(default = "one")]
        starts: usize,
    },
}

fn one() -> usize {
    1
}

/// The bundled forms, then those of `extra` (a grammar file a config names).
pub fn forms(extra: Option<&std::path::Path>) -> Result<Vec<TermForm>> {
    let mut forms = parse(DEFAULT, "the bundled grammar")?;
    if let Some(path) = extra {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        forms.extend(parse(&text, &path.display().to_string())?);
    }
    Ok(forms)
}

fn parse(text: &str, what: &str) -> Result<Vec<TermForm>> {
    let mut file: GrammarFile = toml::from_str(text).map_err(|e| anyhow!("{what}: {e}"))?;
    for f in &mut file.terms {
        // The form's syntax, with every placeholder standing for a name.
        let mut plain = f.form.clone();
        while let (Some(a), Some(b)) = (plain.find('{'), plain.find('}')) {
            if b < a {
                break;
            }
            plain.replace_range(a..=b, "q");
        }
        match crate::engine::formula::notation::parse(&plain) {
            Ok(tree) => f.operations = tree.operations(),
            Err(e) => bail!("{what}: [[terms]] {}: form = {:?} is not a formula ({e})", f.name, f.form),
        }
        if f.to == To::Parameters && !(f.form.contains("{theta}") && f.form.contains("{u}")) {
            bail!("{what}: [[terms]] {}: a form with to = \"parameters\" uses {{theta}} (the parameter) and {{u}} (what it varies with)", f.name);
        }
        for (p, spec) in &f.parameters {
            check_parameter(what, f, p, spec)?;
        }
        if let Some(Power::Free(p)) = &f.power {
            if !f.parameters.contains_key(p) {
                bail!("{what}: [[terms]] {}: power = {p:?} is not one of the form's parameters", f.name);
            }
        }
    }
    Ok(file.terms)
}

fn check_parameter(what: &str, f: &TermForm, p: &str, spec: &ParameterForm) -> Result<()> {
    if !f.form.contains(&format!("{{{p}}}")) {
        bail!("{what}: [[terms]] {}: parameter '{p}' is not in the form {:?} (write it {{{p}}})", f.name, f.form);
    }
    match spec {
        ParameterForm::Kind(k) if k != "coefficient" => {
            bail!("{what}: [[terms]] {}: parameter '{p}' = {k:?}; use \"coefficient\" or {{ min, max }}", f.name)
        }
        ParameterForm::Kind(_) => {}
        ParameterForm::Range { starts, .. } if !(1..=MAX_STARTS).contains(starts) => bail!(
            "{what}: [[terms]] {}: parameters.{p}.starts = {starts}; use 1 to {MAX_STARTS} (each start is a fit)",
            f.name
        ),
        ParameterForm::Range { min, max, .. } => {
            for (key, text) in [("min", min), ("max", max)] {
                let place = format!("{what}: [[terms]] {}: parameters.{p}.{key}", f.name);
                Formula::parse(text, &bound_scope(), &place)?;
            }
        }
    }
    Ok(())
}

/// The names a parameter's bounds may use (`span`, `n`, `smax`, `ymax`; see grammar.toml).
pub fn bound_scope() -> Scope {
    Scope::new(["span", "n", "smax", "ymax"].map(String::from))
}

/// A form with the model's symbols put in; its parameters still in braces.
#[derive(Clone, Debug)]
pub struct Instance {
    /// e.g. `signed_square_v_on_v`.
    pub name: String,
    pub form: String,
    /// The state (rates), observable (observables, measured) or parameter
    /// (parameters) the term joins.
    pub target: String,
    pub to: To,
    /// The form's place in the grammar: earlier forms are simpler.
    pub rank: usize,
    /// The symbols the form's placeholders took, for `smax`.
    pub symbols: Vec<String>,
    pub parameters: Vec<(String, ParameterForm)>,
    pub meaning: String,
    /// The form's size (operations), for the prior over forms.
    pub operations: usize,
    /// The form's power of its one symbol (`TermForm::power`); None when
    /// it takes several symbols.
    pub power: Option<Power>,
}

impl Instance {
    /// The term with parameter names given `suffix` (pairs keep theirs apart).
    pub fn render(&self, suffix: &str) -> String {
        let mut text = self.form.clone();
        for (p, _) in &self.parameters {
            text = text.replace(&format!("{{{p}}}"), &format!("{p}{suffix}"));
        }
        text
    }

    pub fn place(&self) -> String {
        match self.to {
            To::Rates => format!("d{}/dt", self.target),
            _ => self.target.clone(),
        }
    }
}

/// Every instance of `forms` for the model `d`: rate forms for an ODE,
/// observable forms for an expression model, measured and parameter forms
/// for both.
pub fn instances(forms: &[TermForm], d: &Declared) -> Vec<Instance> {
    let ode = !d.states.is_empty();
    let mut out = Vec::new();
    for (rank, f) in forms.iter().enumerate() {
        let (symbols, targets) = match f.to {
            To::Rates if ode => (state_names(d), laws(d)),
            To::Observables if !ode => (vec![d.input.clone()], observables(d)),
            To::Measured => (Vec::new(), observables(d)),
            // A law's coefficient depends on the state of the system (its
            // temperature, speed), not on the clock: in an ODE it varies
            // with a state; a drift in time is the transient forms' business.
            To::Parameters if ode => (state_names(d), varying(d)),
            To::Parameters => (vec![d.input.clone()], varying(d)),
            _ => continue,
        };
        for (target, own) in &targets {
            for combo in combinations(&symbols, arity(f)) {
                for ((origin, from), flux) in pairs(origins(f, d, combo.first()), fluxes(f, d, target)) {
                    let mut form = f.form.replace("{rate}", &format!("({own})")).replace("{y}", &format!("({own})"));
                    form = form.replace("{t}", &d.input).replace("{theta}", target).replace("{s0}", &from);
                    form = form.replace("{flux}", &format!("({})", flux.text));
                    for (k, s) in combo.iter().enumerate() {
                        form = form.replace(["{s}", "{s2}", "{s3}", "{s4}"][k], s).replace("{u}", s);
                    }
                    let mut name = f.name.clone();
                    for s in combo.iter().chain(&origin).chain(&flux.name) {
                        name.push('_');
                        name.push_str(s);
                    }
                    let joint = if f.to == To::Parameters { "of" } else { "on" };
                    out.push(Instance {
                        name: format!("{name}_{joint}_{target}"),
                        form,
                        target: target.clone(),
                        to: f.to,
                        rank,
                        symbols: combo.clone(),
                        parameters: f.parameters.iter().map(|(k, v)| (k.clone(), v.clone())).collect(),
                        meaning: combo
                            .first()
                            .map_or(f.meaning.clone(), |s| f.meaning.replace("{s}", s).replace("{u}", s))
                            .replace("{flux}", &flux.text)
                            .replace("{from}", &flux.from)
                            .replace("{target}", target),
                        operations: f.operations,
                        power: f.power.clone().filter(|_| combo.iter().all(|s| Some(s) == combo.first())),
                    });
                }
            }
        }
    }
    out
}

/// Every pair of an origin and a flux (each list has one empty entry
/// when the form does not use it).
fn pairs<A: Clone, B: Clone>(a: Vec<A>, b: Vec<B>) -> Vec<(A, B)> {
    a.iter().flat_map(|x| b.iter().map(move |y| (x.clone(), y.clone()))).collect()
}

/// A term of another law that `{flux}` takes: its text, the law it is
/// taken from, and the name's suffix (`x_2_3`: the third term of dx_2/dt).
#[derive(Clone, Default)]
struct Flux {
    text: String,
    from: String,
    name: Option<String>,
}

/// Most terms one law is read as: a product of long sums multiplies out
/// into more than a physicist reads as separate processes.
const FLUX_TERMS: usize = 16;

/// The values `{flux}` may take in the law of `target`: each term of every
/// other law with its sign there (multiplied out, as `engine::formula::terms` reads a law)
/// that reads a state and one of the model's constants, and is not already
/// a term of `target`'s own law. In a model of exchanges (kinetics,
/// compartments, populations) what one state loses another gains, so a
/// process written in one law and left out of another is the first
/// suspect; its constants are the model's own, already calibrated. A term
/// of states alone is the library's (a product of states), not taken here.
/// One empty flux when the form has no `{flux}`.
fn fluxes(f: &TermForm, d: &Declared, target: &str) -> Vec<Flux> {
    use crate::engine::formula::notation::{parse, Expr};
    use crate::engine::formula::terms::{additive, render};
    if !f.form.contains("{flux}") {
        return vec![Flux::default()];
    }
    // Each term unsigned (to tell terms apart) and as the law has it, sign
    // and all: c = −1 then means a conserved exchange whichever side is written.
    let terms_of = |rate: &str| -> Vec<(String, String)> {
        let Ok(e) = parse(rate) else { return Vec::new() };
        let terms = additive(&e, FLUX_TERMS).unwrap_or_default();
        let signed = |s: f64, t: &Expr| if s < 0.0 { render(&Expr::Neg(Box::new(t.clone()))) } else { render(t) };
        terms.iter().map(|(s, t)| (render(t), signed(*s, t))).collect()
    };
    let states = state_names(d);
    let reads = |text: &str| {
        let mut names = Vec::new();
        if let Ok(e) = parse(text) {
            e.names(&mut names);
        }
        let state = names.iter().any(|n| states.contains(n));
        let constant = names.iter().any(|n| !states.contains(n) && *n != d.input);
        state && constant
    };
    let own: Vec<String> =
        laws(d).iter().filter(|(s, _)| s == target).flat_map(|(_, r)| terms_of(r)).map(|(u, _)| u).collect();
    let mut seen: Vec<String> = Vec::new();
    let mut out: Vec<Flux> = Vec::new();
    for (from, rate) in laws(d).iter().filter(|(s, _)| s != target) {
        for (k, (unsigned, text)) in terms_of(rate).into_iter().enumerate() {
            if reads(&unsigned) && !own.contains(&unsigned) && !seen.contains(&unsigned) {
                seen.push(unsigned);
                out.push(Flux { text, from: from.clone(), name: Some(format!("{from}_{}", k + 1)) });
            }
        }
    }
    out
}

/// How many symbols a form takes: `{s}` … `{s4}`, or `{u}`.
fn arity(f: &TermForm) -> usize {
    if f.form.contains("{u}") {
        return 1;
    }
    ["{s4}", "{s3}", "{s2}", "{s}"].iter().position(|p| f.form.contains(p)).map_or(0, |i| 4 - i)
}

/// The values `{s0}` may take for the symbol `s`: zero (unnamed), each
/// constant of the model, and for a state its initial value (where it
/// rests before the law acts). Named by the constant, or `initial`. One
/// empty origin when the form has no `{s0}`.
fn origins(f: &TermForm, d: &Declared, s: Option<&String>) -> Vec<(Option<String>, String)> {
    if !f.form.contains("{s0}") {
        return vec![(None, String::new())];
    }
    // Zero, where a quantity rests (a current, a speed): named by nothing.
    let mut out: Vec<(Option<String>, String)> = vec![(None, "0".into())];
    out.extend(d.constants.iter().map(|(c, _)| (Some(c.clone()), c.clone())));
    if let Some(state) = s.and_then(|s| d.states.iter().find(|st| &st.name == s)) {
        out.push((Some("initial".into()), format!("({})", state.initial.text)));
    }
    out
}

fn state_names(d: &Declared) -> Vec<String> {
    d.states.iter().map(|s| s.name.clone()).collect()
}

fn observables(d: &Declared) -> Vec<(String, String)> {
    d.observables.iter().map(|(n, w)| (n.clone(), w.text.clone())).collect()
}

/// The variables (states, the input, t) the model uses inside a sine,
/// cosine or tangent, in its rates or its observables: its angles and
/// phases, which a new term should keep inside such functions
/// (`engine::discover::prior::nats_given`). A parameter inside one (a
/// frequency ω) is not counted: a term may vary it as it varies any other.
pub fn angles(d: &Declared) -> BTreeSet<String> {
    let mut inside = BTreeSet::new();
    let rates = d.states.iter().map(|s| &s.rate.text);
    for text in rates.chain(d.observables.iter().map(|(_, w)| &w.text)) {
        if let Ok(e) = crate::engine::formula::notation::parse(text) {
            crate::engine::discover::prior::inside_trig(&e, false, &mut inside);
        }
    }
    let variable = |n: &String| n == &d.input || n == "t" || d.states.iter().any(|s| &s.name == n);
    inside.into_iter().filter(variable).collect()
}

/// The states whose rate is a law, with the rate: not a kinematic identity
/// (`dh/dt = v`), which is a definition and exact.
pub fn laws(d: &Declared) -> Vec<(String, String)> {
    d.states
        .iter()
        .filter(|s| kinematic_identity(d, &s.name, &s.rate.text).is_none())
        .map(|s| (s.name.clone(), s.rate.text.clone()))
        .collect()
}

/// The state a rate is, and its sign, when the rate is a kinematic identity:
/// `dx/dt = v` (+1), or `dh/dt = -v` for a height that falls as the
/// downward speed v grows (−1). Such a rate is a definition: no term joins it.
/// A rate that is ± its own state (`dx/dt = -x`, a decay) is a law, and so
/// is one the data contradict (`State::law_by_data`).
pub fn kinematic_identity(d: &Declared, own: &str, rate: &str) -> Option<(usize, f64)> {
    use crate::engine::formula::notation::{parse, Expr};
    if d.states.iter().any(|s| s.name == own && s.law_by_data) {
        return None;
    }
    let state = |n: &str| d.states.iter().position(|s| s.name == n && s.name != own);
    match parse(rate).ok()? {
        Expr::Name(n) => Some((state(&n)?, 1.0)),
        Expr::Neg(a) => match *a {
            Expr::Name(n) => Some((state(&n)?, -1.0)),
            _ => None,
        },
        _ => None,
    }
}

/// The parameters some rate or observable uses: those that can vary.
fn varying(d: &Declared) -> Vec<(String, String)> {
    let formulas: Vec<&str> = d
        .observables
        .iter()
        .map(|(_, w)| w.text.as_str())
        .chain(d.states.iter().map(|s| s.rate.text.as_str()))
        .collect();
    let used = |p: &str| formulas.iter().any(|f| crate::engine::formula::notation::rename(f, p, "") != *f);
    d.parameters.iter().filter(|p| used(p)).map(|p| (p.clone(), String::new())).collect()
}

/// Every multiset of `k` of `symbols` (s ≤ s2 ≤ s3 in their order).
fn combinations(symbols: &[String], k: usize) -> Vec<Vec<String>> {
    if k == 0 {
        return vec![Vec::new()];
    }
    let mut out = Vec::new();
    for (i, s) in symbols.iter().enumerate() {
        for mut rest in combinations(&symbols[i..], k - 1) {
            rest.insert(0, s.clone());
            out.push(rest);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bundled_grammar_parses_and_every_form_names_its_parameters() {
        let forms = forms(None).unwrap();
        assert!(forms.iter().any(|f| f.name == "periodic" && f.to == To::Rates));
        assert!(forms.iter().any(|f| f.name == "gain" && f.to == To::Measured));
        // Every bundled form says what it means to a physicist.
        assert!(forms.iter().all(|f| !f.meaning.is_empty()), "a bundled form without its meaning");
        let bad = "[[terms]]\nname = \"x\"\nform = \"{c}\"\nto = \"state\"\nparameters = { c = \"coefficient\" }\n";
        let e = parse(bad, "my.toml").unwrap_err().to_string();
        assert!(e.contains("my.toml") && e.contains("measured"), "{e}");
        let bad = "[[terms]]\nname = \"x\"\nform = \"{theta}*{c}\"\nto = \"parameters\"\nparameters = { c = \"coefficient\" }\n";
        let e = parse(bad, "my.toml").unwrap_err().to_string();
        assert!(e.contains("{u}"), "{e}");
        let bad = "[[terms]]\nname = \"x\"\nform = \"c*t\"\nto = \"rates\"\nparameters = { c = \"coefficient\" }\n";
        let e = parse(bad, "my.toml").unwrap_err().to_string();
        assert!(e.contains("my.toml") && e.contains("write it {c}"), "{e}");
        let bad =
            "[[terms]]\nname = \"x\"\nform = \"{c}*{s}^\"\nto = \"rates\"\nparameters = { c = \"coefficient\" }\n";
        let e = parse(bad, "my.toml").unwrap_err().to_string();
        assert!(e.contains("my.toml") && e.contains("not a formula"), "{e}");
        // A bound in a name the bounds do not know is refused, not skipped.
        let bad = "[[terms]]\nname = \"x\"\nform = \"{c}*sin({w}*t)\"\nto = \"rates\"\nparameters = { c = \"coefficient\", w = { min = \"pi/span\", max = \"1\" } }\n";
        let e = format!("{:#}", parse(bad, "my.toml").unwrap_err());
        assert!(e.contains("parameters.w.min") && e.contains("unknown name 'pi'"), "{e}");
    }

    #[test]
    fn combinations_are_multisets_in_order() {
        let s: Vec<String> = vec!["h".into(), "v".into()];
        assert_eq!(combinations(&s, 2), [["h", "h"], ["h", "v"], ["v", "v"]]);
        assert_eq!(combinations(&s, 3).len(), 4);
    }
}

#[cfg(test)]
mod identity_tests {
    use super::super::super::declaration::{Declared, ModelTable};
    use super::kinematic_identity;
    use crate::base::config::Config;

    /// The declared model of a config's text.
    fn declared(tag: &str, text: &str) -> Declared {
        let dir = std::env::temp_dir().join(format!("mdpipe-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.toml");
        std::fs::write(&path, text).unwrap();
        let config = Config::load(&path).unwrap();
        let table: ModelTable = config.decode_family_table(&config.model, "model").unwrap();
        let d = Declared::base(&config, &table, true).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        d
    }

    /// dh/dt = -v is a definition (h falls as the downward speed grows);
    /// dv/dt = g is a law; dc/dt = -c, a decay, is a law, not an identity.
    #[test]
    fn a_rate_that_is_another_state_is_a_definition_and_its_own_is_a_law() {
        let text =
            "name = \"m\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\nh = \"1\"\nv = \"0\"\nc = \"1\"\n\
            [model.rates]\nh = \"-v\"\nv = \"g\"\nc = \"-c\"\n[model.observables]\nheight = \"h\"\n\
            [data]\nmeasurements = \"d.csv\"\n[parameters.g]\nmin = 0.0\nmax = 20.0\n";
        let d = declared("identity", text);
        let rate = |name: &str| d.states.iter().find(|s| s.name == name).unwrap().rate.text.clone();
        let v = d.states.iter().position(|s| s.name == "v").unwrap();
        assert_eq!(kinematic_identity(&d, "h", &rate("h")), Some((v, -1.0)));
        assert_eq!(kinematic_identity(&d, "v", &rate("v")), None);
        assert_eq!(kinematic_identity(&d, "c", &rate("c")), None);
        let mut laws: Vec<String> = super::laws(&d).into_iter().map(|(s, _)| s).collect();
        laws.sort();
        assert_eq!(laws, ["c", "v"]);
    }

    /// A driven pendulum: θ inside a sine and t inside a cosine are its
    /// angle and phase; ω, a parameter inside the cosine, and v, written
    /// bare, are not.
    #[test]
    fn the_angles_are_the_variables_written_inside_trig_functions() {
        let text = "name = \"m\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\ntheta = \"1\"\nv = \"0\"\n\
            [model.rates]\ntheta = \"v\"\nv = \"-g*sin(theta) + a*cos(w*t)\"\n[model.observables]\nangle = \"theta\"\n\
            [data]\nmeasurements = \"d.csv\"\n[parameters.g]\nmin = 0.0\nmax = 20.0\n\
            [parameters.a]\nmin = 0.0\nmax = 1.0\n[parameters.w]\nmin = 0.1\nmax = 5.0\n";
        let d = declared("angles", text);
        assert_eq!(super::angles(&d).into_iter().collect::<Vec<_>>(), ["t", "theta"]);
    }

    /// A process written in one law is offered to every other law that
    /// lacks it (what A loses, B may gain): each term of another law that
    /// reads a state and a constant, not a product of states alone (the
    /// library's), and not a term the law has already.
    #[test]
    fn a_term_of_one_law_is_offered_to_the_others_as_a_flux() {
        let text = "name = \"m\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\nA = \"1\"\nB = \"0\"\n\
            [model.rates]\nA = \"-d*A\"\nB = \"k*A/(K + A) - A*B - d*B\"\n[model.observables]\na = \"A\"\n\
            [data]\nmeasurements = \"d.csv\"\n[parameters.d]\nmin = 0.0\nmax = 1.0\n\
            [parameters.k]\nmin = 0.0\nmax = 1.0\n[parameters.K]\nmin = 0.1\nmax = 1.0\n";
        let d = declared("flux", text);
        let forms = super::forms(None).unwrap();
        let mut fluxes: Vec<(String, String)> = super::instances(&forms, &d)
            .into_iter()
            .filter(|i| i.name.starts_with("flux_"))
            .map(|i| (i.name, i.form))
            .collect();
        fluxes.sort();
        let expected =
            [("flux_A_1_on_B", "{c}*(-d*A)"), ("flux_B_1_on_A", "{c}*(k*A/(K + A))"), ("flux_B_3_on_A", "{c}*(-d*B)")];
        assert_eq!(fluxes, expected.map(|(n, f)| (n.to_string(), f.to_string())));
        let meaning = super::instances(&forms, &d).into_iter().find(|i| i.name == "flux_B_1_on_A").unwrap().meaning;
        assert!(meaning.contains("k*A/(K + A) of dB/dt acting on A"), "{meaning}");
    }
}
