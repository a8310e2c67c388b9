//! The grammar of terms (`grammar.toml`, extendable by a config) and its
//! instances: each form with the model's own symbols put in, ready to be
//! declared as a `[[candidates]]` table.

use super::super::declaration::Declared;
use super::super::formula::{Formula, Scope};
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeMap;

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

/// One form of the grammar, as written.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TermForm {
    pub name: String,
    pub form: String,
    /// "rates" or "observables".
    pub to: String,
    pub parameters: BTreeMap<String, ParameterForm>,
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
    let file: GrammarFile = toml::from_str(text).map_err(|e| anyhow!("{what}: {e}"))?;
    for f in &file.terms {
        if f.to != "rates" && f.to != "observables" {
            bail!("{what}: [[terms]] {}: to = {:?}; use \"rates\" or \"observables\"", f.name, f.to);
        }
        // The form's syntax, with every placeholder standing for a name.
        let mut plain = f.form.clone();
        while let (Some(a), Some(b)) = (plain.find('{'), plain.find('}')) {
            if b < a {
                break;
            }
            plain.replace_range(a..=b, "q");
        }
        if let Err(e) = super::super::notation::parse(&plain) {
            bail!("{what}: [[terms]] {}: form = {:?} is not a formula ({e})", f.name, f.form);
        }
        for (p, spec) in &f.parameters {
            if !f.form.contains(&format!("{{{p}}}")) {
                bail!(
                    "{what}: [[terms]] {}: parameter '{p}' is not in the form {:?} (write it {{{p}}})",
                    f.name,
                    f.form
                );
            }
            match spec {
                ParameterForm::Kind(k) if k != "coefficient" => bail!(
                    "{what}: [[terms]] {}: parameter '{p}' = {k:?}; use \"coefficient\" or {{ min, max }}",
                    f.name
                ),
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
        }
    }
    Ok(file.terms)
}

/// The names a parameter's bounds may use (`span`, `n`, `smax`; see grammar.toml).
pub fn bound_scope() -> Scope {
    Scope::new(["span", "n", "smax"].map(String::from))
}

/// A form with the model's symbols put in; its parameters still in braces.
#[derive(Clone, Debug)]
pub struct Instance {
    /// e.g. `signed_square_v_on_v`.
    pub name: String,
    pub form: String,
    /// The state (rates) or observable (observables) the term joins.
    pub target: String,
    pub on_rate: bool,
    /// The form's place in the grammar: earlier forms are simpler.
    pub rank: usize,
    /// The symbols the form's placeholders took, for `smax`.
    pub symbols: Vec<String>,
    pub parameters: Vec<(String, ParameterForm)>,
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
        if self.on_rate {
            format!("d{}/dt", self.target)
        } else {
            self.target.clone()
        }
    }
}

/// Every instance of `forms` for the model `d`: rate forms for an ODE,
/// observable forms for an expression model.
pub fn instances(forms: &[TermForm], d: &Declared) -> Vec<Instance> {
    let ode = !d.states.is_empty();
    let symbols: Vec<String> =
        if ode { d.states.iter().map(|s| s.name.clone()).collect() } else { vec![d.input.clone()] };
    let mut out = Vec::new();
    for (rank, f) in forms.iter().enumerate().filter(|(_, f)| (f.to == "rates") == ode) {
        let targets: Vec<(String, String)> = if ode {
            d.states.iter().map(|s| (s.name.clone(), s.rate.text.clone())).collect()
        } else {
            d.observables.iter().map(|(n, w)| (n.clone(), w.text.clone())).collect()
        };
        let arity = ["{s3}", "{s2}", "{s}"].iter().position(|p| f.form.contains(p)).map(|i| 3 - i).unwrap_or(0);
        for (target, own) in &targets {
            for combo in combinations(&symbols, arity) {
                let mut form = f.form.replace("{rate}", &format!("({own})")).replace("{y}", &format!("({own})"));
                form = form.replace("{t}", &d.input);
                for (k, s) in combo.iter().enumerate() {
                    form = form.replace(["{s}", "{s2}", "{s3}"][k], s);
                }
                let mut name = f.name.clone();
                for s in &combo {
                    name.push('_');
                    name.push_str(s);
                }
                out.push(Instance {
                    name: format!("{name}_on_{target}"),
                    form,
                    target: target.clone(),
                    on_rate: ode,
                    rank,
                    symbols: combo,
                    parameters: f.parameters.iter().map(|(k, v)| (k.clone(), v.clone())).collect(),
                });
            }
        }
    }
    out
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
        assert!(forms.iter().any(|f| f.name == "periodic" && f.to == "rates"));
        assert!(forms.iter().any(|f| f.name == "signed_square" && f.to == "observables"));
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
