//! The grammar of corrections an emulated model's output is searched over
//! (`corrections.toml`): each form, its parameters' ranges as formulas of
//! the data's scales, and its size for the prior over forms.

use crate::base::config::ParamSpec;
use crate::engine::formula::{notation, Formula, Scope};
use anyhow::{anyhow, bail, Result};
use std::collections::BTreeMap;

const BUNDLED: &str = include_str!("corrections.toml");

/// Most starting points of one parameter: the screening fits from each.
const MAX_STARTS: usize = 32;

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct FormsFile {
    corrections: Vec<Form>,
}

/// A correction as written: `{y}` stands for the observable, `{x}` for the
/// input, `{name}` for each of its parameters.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Form {
    pub name: String,
    pub form: String,
    pub meaning: String,
    pub parameters: BTreeMap<String, Bound>,
    /// The form's size (operations), which orders forms of as many parameters.
    #[serde(skip)]
    pub operations: usize,
    /// The form's prior cost in nats (`discover::prior`, set when read).
    #[serde(skip)]
    pub nats: f64,
}

/// A parameter's range, formulas of `ymax`, `xmax`, `span` and `n`
/// (`Scales`), and how many starting points the screening spreads over it
/// (absent: three, at a tenth, half and nine tenths of the range).
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bound {
    pub min: String,
    pub max: String,
    #[serde(default)]
    pub starts: Option<usize>,
}

/// One observable's data as a correction's bounds see them.
#[derive(Clone, Copy, Debug)]
pub struct Scales {
    /// The largest |y| and |x|.
    pub ymax: f64,
    pub xmax: f64,
    /// The range of x, and how many points.
    pub span: f64,
    pub n: f64,
}

impl Scales {
    pub fn of(x: &[f64], y: &[f64]) -> Scales {
        let largest = |v: &[f64]| v.iter().fold(0.0f64, |m, z| m.max(z.abs())).max(f64::MIN_POSITIVE);
        let (lo, hi) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
        let span = if hi > lo { hi - lo } else { f64::MIN_POSITIVE };
        Scales { ymax: largest(y), xmax: largest(x), span, n: x.len() as f64 }
    }
}

/// One parameter of a form on one observable: its range and starting values.
#[derive(Clone, Debug)]
pub struct Range {
    pub spec: ParamSpec,
    pub starts: Vec<f64>,
}

fn bound_scope() -> Scope {
    Scope::new(["ymax", "xmax", "span", "n"].map(String::from))
}

/// The bundled grammar, checked.
pub fn bundled() -> Result<Vec<Form>> {
    let file: FormsFile = toml::from_str(BUNDLED).map_err(|e| anyhow!("the bundled corrections: {e}"))?;
    file.corrections.into_iter().map(checked).collect()
}

fn checked(mut f: Form) -> Result<Form> {
    let place = format!("corrections.toml: [[corrections]] {}", f.name);
    for (p, b) in &f.parameters {
        if !f.form.contains(&format!("{{{p}}}")) {
            bail!("{place}: parameter '{p}' is not in the form");
        }
        if matches!(b.starts, Some(k) if !(1..=MAX_STARTS).contains(&k)) {
            bail!("{place}: parameters.{p}.starts: use 1 to {MAX_STARTS}");
        }
        for text in [&b.min, &b.max] {
            Formula::parse(text, &bound_scope(), &format!("{place}: parameters.{p}"))?;
        }
    }
    let text = f.render("y", &|p| p.to_string());
    f.operations = notation::parse(&text).map_err(|e| anyhow!("{place}: {e}"))?.operations();
    f.nats = crate::engine::discover::prior::nats(&text);
    Ok(f)
}

impl Form {
    /// The form with the observable's name and the parameters' names put in.
    pub fn render(&self, observable: &str, name: &dyn Fn(&str) -> String) -> String {
        let mut text = self.form.replace("{y}", observable).replace("{x}", "x");
        for p in self.parameters.keys() {
            text = text.replace(&format!("{{{p}}}"), &name(p));
        }
        text
    }

    /// Each parameter's range and starts on data of these scales, in the
    /// parameters' order; None where a bound is not finite (every x at 0
    /// leaves an x-form none).
    pub fn ranges(&self, scales: &Scales) -> Option<Vec<Range>> {
        let values = [scales.ymax, scales.xmax, scales.span, scales.n];
        let eval = |text: &str| Formula::parse(text, &bound_scope(), "corrections").ok().map(|f| f.eval(&values));
        self.parameters
            .values()
            .map(|b| {
                let (min, max) = (eval(&b.min)?, eval(&b.max)?);
                if !(min.is_finite() && max.is_finite() && max > min) {
                    return None;
                }
                let starts = match b.starts {
                    None => [0.1, 0.5, 0.9].iter().map(|u| min + u * (max - min)).collect(),
                    Some(k) => (0..k).map(|i| min + (max - min) * (i as f64 + 0.5) / k as f64).collect(),
                };
                Some(Range { spec: ParamSpec { min, max, truth: None, units: String::new() }, starts })
            })
            .collect()
    }
}

/// Every combination of each range's starts.
pub fn start_grid(ranges: &[Range]) -> Vec<Vec<f64>> {
    ranges.iter().fold(vec![Vec::new()], |grid, r| {
        grid.into_iter().flat_map(|s| r.starts.iter().map(move |v| [s.clone(), vec![*v]].concat())).collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bundled_grammar_reads_and_sizes_its_forms() {
        let forms = bundled().unwrap();
        let size = |name: &str| forms.iter().find(|f| f.name == name).unwrap().operations;
        assert_eq!(size("offset"), 1);
        assert_eq!(size("gain"), 2);
        assert_eq!(size("saturation"), 3);
        assert_eq!(size("x2_gain"), 4);
        // Twelve points: enough for two periods of a swing below their Nyquist rate.
        let x: Vec<f64> = (0..12).map(f64::from).collect();
        let scales = Scales::of(&x, &x.iter().map(|v| 2.0 - v).collect::<Vec<_>>());
        for f in &forms {
            let ranges = f.ranges(&scales).unwrap_or_else(|| panic!("{}: no finite range", f.name));
            assert!(!start_grid(&ranges).is_empty() && start_grid(&ranges).len() <= 64, "{}", f.name);
        }
    }

    #[test]
    fn ranges_scale_with_the_data_and_refuse_an_empty_input_range() {
        let forms = bundled().unwrap();
        let x2 = forms.iter().find(|f| f.name == "x2_gain").unwrap();
        let r = x2.ranges(&Scales::of(&[1.0, 2.0], &[5.0, 5.0])).unwrap();
        assert!((r[0].spec.max - 9.0 / 4.0).abs() < 1e-12 && (r[0].spec.min + 0.9 / 4.0).abs() < 1e-12);
        assert!(x2.ranges(&Scales::of(&[0.0], &[5.0])).is_none());
        // Three points cannot hold two periods below their Nyquist rate: no periodic gain.
        let periodic = forms.iter().find(|f| f.name == "periodic_gain").unwrap();
        assert!(periodic.ranges(&Scales::of(&[0.0, 3.0, 6.0], &[1.0, 2.0, 3.0])).is_none());
        let offset = forms.iter().find(|f| f.name == "offset").unwrap();
        assert_eq!(offset.ranges(&Scales::of(&[1.0, 2.0], &[-5.0, 3.0])).unwrap()[0].spec.max, 50.0);
    }

    #[test]
    fn a_form_with_a_parameter_it_does_not_use_is_refused() {
        let bad = Form {
            name: "bad".into(),
            form: "{y} + {c}".into(),
            meaning: String::new(),
            parameters: BTreeMap::from([("d".into(), Bound { min: "0".into(), max: "1".into(), starts: None })]),
            operations: 0,
            nats: 0.0,
        };
        let e = checked(bad).unwrap_err().to_string();
        assert!(e.contains("parameter 'd' is not in the form"), "{e}");
    }
}
