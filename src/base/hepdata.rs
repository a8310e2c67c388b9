//! Published measurements in HEPData's YAML format, as measurements and
//! their covariance.
//!
//! A table file holds `independent_variables` (the bins: `low`/`high` edges,
//! or a `value`) and `dependent_variables` (one per centrality class or
//! species, named by `qualifiers`), each with `values` carrying `errors`:
//! `symerror` or `asymerror` (`plus`/`minus`, signed), absolute or as a
//! percentage of the value (`'5%'`), each with a `label`. A record's
//! `submission.yaml` indexes its tables (`name`, `data_file`), one YAML
//! document each.
//!
//! What the likelihood gets: one observable per dependent variable (named
//! from its qualifiers unless `[data.hepdata] observables` maps it), x the
//! bin centre (or the value of another independent variable, `x = "<name>"`,
//! such as ⟨pT⟩); errors labelled `stat…` (or unlabelled) are independent
//! between bins and make the measurement's error; every other label is a
//! systematic source, correlated across the bins of its dependent variable,
//! fully by default or as `exp(−|x − x'| / correlation_length)`, and
//! `correlation_length = 0` makes it independent too; `[data] systematics`
//! gives one label a scope of its own (`"all"`: shared by every table, as
//! a luminosity is; `base::systematics`). An asymmetric error
//! enters with the mean of its two magnitudes. Bins whose value is `null`
//! or `-` are skipped and counted (`Record::skipped`).

use super::measurement::{CovarianceEntry, Measurement};
use super::systematics::{self, Scope, SourcedPoint};
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use yaml_serde::Value;

/// `[data.hepdata]`: which tables, and how they become observables.
#[derive(Clone, Debug, Default, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct HepdataOptions {
    /// With a record's `submission.yaml`: the tables to read, by `name`
    /// (all of them when empty).
    #[serde(default)]
    pub tables: Vec<String>,
    /// The independent variable whose value is x (by header name); the
    /// first independent variable's bin centre by default.
    pub x: Option<String>,
    /// Correlation length of the systematics across bins, in x's units;
    /// fully correlated when absent, independent at 0.
    pub correlation_length: Option<f64>,
    /// Observable names for dependent variables, keyed by the name mdpipe
    /// would give them (their qualifiers' values) or by that label as written.
    #[serde(default)]
    pub observables: BTreeMap<String, String>,
}

/// One measured bin as published.
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    pub observable: String,
    pub x: f64,
    /// Bin edges of x's independent variable, where the table gives them.
    pub x_low: Option<f64>,
    pub x_high: Option<f64>,
    pub value: f64,
    /// Independent errors (statistical), added in quadrature.
    pub stat: f64,
    /// Each systematic source's error at this bin, by label.
    pub systematics: Vec<(String, f64)>,
}

/// What a record gives the likelihood.
#[derive(Clone, Debug, Default)]
pub struct Record {
    pub points: Vec<Point>,
    /// Bins skipped for a `null` or missing value: (table, observable, bin index).
    pub skipped: Vec<(String, String, usize)>,
}

impl Record {
    /// The measurements: each point's value and its independent error.
    pub fn measurements(&self) -> Vec<Measurement> {
        self.points.iter().map(|p| Measurement::new(&p.observable, p.x, p.value, p.stat)).collect()
    }

    /// The systematics' covariance between every two bins (both orders, in
    /// `base::covariance`'s format): each label over the scope `scopes`
    /// gives it, else within its observable as `options` says.
    pub fn covariance(&self, options: &HepdataOptions, scopes: &BTreeMap<String, Scope>) -> Vec<CovarianceEntry> {
        let default = match options.correlation_length {
            None => Scope::Table,
            Some(l) => Scope::Length(l),
        };
        let points: Vec<SourcedPoint> = self
            .points
            .iter()
            .map(|p| SourcedPoint { observable: p.observable.clone(), x: p.x, systematics: p.systematics.clone() })
            .collect();
        systematics::covariance(&points, |label| scopes.get(label).copied().unwrap_or(default))
    }
}

/// Whether `path` names a HEPData YAML file.
pub fn is_hepdata(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("yaml") || e.eq_ignore_ascii_case("yml"))
}

/// Reads a table file, or the chosen tables of a record's `submission.yaml`.
pub fn read(path: &Path, options: &HepdataOptions) -> Result<Record> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let documents = documents(&text, path)?;
    let is_submission = documents.iter().any(|d| d.get("data_file").is_some());
    let mut record = Record::default();
    if !is_submission {
        if !options.tables.is_empty() {
            bail!(
                "{}: a table file, not a record's submission.yaml: `tables` has nothing to choose from",
                path.display()
            );
        }
        let table = documents.into_iter().next().ok_or_else(|| anyhow!("{}: empty file", path.display()))?;
        read_table(&table, &table_label(path, None), options, &mut record)?;
    } else {
        read_submission(&documents, path, options, &mut record)?;
    }
    if record.points.is_empty() {
        bail!("{}: no measured values in the tables read", path.display());
    }
    Ok(record)
}

fn documents(text: &str, path: &Path) -> Result<Vec<Value>> {
    use serde::Deserialize;
    let mut out = Vec::new();
    for doc in yaml_serde::Deserializer::from_str(text) {
        let value = Value::deserialize(doc).map_err(|e| anyhow!("{}: not valid YAML: {e}", path.display()))?;
        if !value.is_null() {
            out.push(value);
        }
    }
    Ok(out)
}

fn table_label(path: &Path, name: Option<&str>) -> String {
    match name {
        Some(n) => format!("{}, table '{n}'", path.display()),
        None => path.display().to_string(),
    }
}

fn read_submission(index: &[Value], path: &Path, options: &HepdataOptions, record: &mut Record) -> Result<()> {
    let listed: Vec<(&str, &str)> =
        index.iter().filter_map(|d| Some((d.get("name")?.as_str()?, d.get("data_file")?.as_str()?))).collect();
    for wanted in &options.tables {
        if !listed.iter().any(|(name, _)| name == wanted) {
            let names: Vec<&str> = listed.iter().map(|(n, _)| *n).collect();
            bail!("{}: no table named '{wanted}' (the record has: {})", path.display(), names.join("; "));
        }
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    for (name, file) in
        listed.iter().filter(|(n, _)| options.tables.is_empty() || options.tables.iter().any(|t| t == n))
    {
        let table_path: PathBuf = dir.join(file);
        let text = std::fs::read_to_string(&table_path).with_context(|| {
            format!("{}, table '{name}': reading its data file {}", path.display(), table_path.display())
        })?;
        let table = documents(&text, &table_path)?
            .into_iter()
            .next()
            .ok_or_else(|| anyhow!("{}: empty data file of table '{name}'", table_path.display()))?;
        read_table(&table, &table_label(&table_path, Some(name)), options, record)?;
    }
    Ok(())
}

/// One dependent variable's name: the mapped one, else its qualifiers'
/// values (or its header's name) made into an identifier.
fn observable_name(variable: &Value, options: &HepdataOptions) -> String {
    let header = variable.get("header").and_then(|h| h.get("name")).and_then(scalar_text).unwrap_or_default();
    let qualifiers: Vec<String> = variable
        .get("qualifiers")
        .and_then(|q| q.as_sequence())
        .map(|q| q.iter().filter_map(|q| q.get("value").and_then(scalar_text)).collect())
        .unwrap_or_default();
    let label = if qualifiers.is_empty() { header } else { qualifiers.join(" ") };
    let name = identifier(&label);
    options.observables.get(&name).or_else(|| options.observables.get(&label)).cloned().unwrap_or(name)
}

/// `pi+ 0-5%` → `piplus_0_5pct`.
pub fn identifier(label: &str) -> String {
    let spelled = label.replace('+', "plus").replace('%', "pct");
    let mut out = String::new();
    for ch in spelled.chars() {
        if ch.is_ascii_alphanumeric() {
            out.push(ch);
        } else if !out.ends_with('_') && !out.is_empty() {
            out.push('_');
        }
    }
    out.trim_end_matches('_').to_string()
}

fn scalar_text(v: &Value) -> Option<String> {
    match v {
        Value::String(s) => Some(s.clone()),
        Value::Number(n) => Some(n.to_string()),
        Value::Bool(b) => Some(b.to_string()),
        _ => None,
    }
}

/// A number as HEPData writes one: a YAML number or a numeric string;
/// `Ok(None)` for `null`, `'null'`, `'-'` or an empty string.
fn number(v: &Value) -> Result<Option<f64>, String> {
    match v {
        Value::Null => Ok(None),
        Value::Number(n) => n.as_f64().map(Some).ok_or_else(|| format!("{n} is not a number")),
        Value::String(s) => match s.trim() {
            "" | "-" | "null" | "NULL" | "None" | "nan" | "NaN" => Ok(None),
            t => t.parse::<f64>().map(Some).map_err(|_| format!("{t:?} is not a number")),
        },
        other => Err(format!("{other:?} is not a number")),
    }
}

fn read_table(table: &Value, label: &str, options: &HepdataOptions, record: &mut Record) -> Result<()> {
    let independents = table
        .get("independent_variables")
        .and_then(|v| v.as_sequence())
        .ok_or_else(|| anyhow!("{label}: no `independent_variables` list"))?;
    let dependents = table
        .get("dependent_variables")
        .and_then(|v| v.as_sequence())
        .ok_or_else(|| anyhow!("{label}: no `dependent_variables` list"))?;
    let x_index = match &options.x {
        None => 0,
        Some(name) => independents
            .iter()
            .position(|v| v.get("header").and_then(|h| h.get("name")).and_then(scalar_text).as_deref() == Some(name))
            .ok_or_else(|| anyhow!("{label}: no independent variable named '{name}' (`[data.hepdata] x`)"))?,
    };
    let first = independents.first().ok_or_else(|| anyhow!("{label}: `independent_variables` is empty"))?;
    let mut bins = bins(&independents[x_index], label)?;
    // The edges are the binned variable's (the first), also when x is another's (⟨pT⟩ in each bin).
    if x_index != 0 {
        let edges = self::bins(first, label)?;
        if edges.len() != bins.len() {
            bail!("{label}: the independent variables have {} and {} bins", edges.len(), bins.len());
        }
        for (b, e) in bins.iter_mut().zip(edges) {
            if let (Some(b), Some(e)) = (b.as_mut(), e) {
                (b.1, b.2) = (e.1, e.2);
            }
        }
    }
    for (d, variable) in dependents.iter().enumerate() {
        let observable = observable_name(variable, options);
        let values = variable
            .get("values")
            .and_then(|v| v.as_sequence())
            .ok_or_else(|| anyhow!("{label}: dependent variable {} ('{observable}'): no `values` list", d + 1))?;
        if values.len() != bins.len() {
            bail!(
                "{label}: dependent variable {} ('{observable}') has {} values for {} bins of its independent variable",
                d + 1,
                values.len(),
                bins.len()
            );
        }
        if record.points.iter().any(|p| p.observable == observable) {
            bail!("{label}: dependent variable {} is named '{observable}' like one read before: map it to another name in [data.hepdata] observables", d + 1);
        }
        for (i, entry) in values.iter().enumerate() {
            let at = format!("{label}: dependent variable {} ('{observable}'), value {}", d + 1, i + 1);
            let value =
                number(entry.get("value").unwrap_or(&Value::Null)).map_err(|e| anyhow!("{at}, field 'value': {e}"))?;
            let (Some(value), Some((x, low, high))) = (value, bins[i]) else {
                record.skipped.push((label.to_string(), observable.clone(), i));
                continue;
            };
            // `.inf` or `.nan` in YAML would make a likelihood that is never finite.
            if !(value.is_finite() && x.is_finite()) {
                bail!("{at}: value {value} at x = {x} is not a finite number");
            }
            let (stat, systematics) = errors(entry, value, &at)?;
            record.points.push(Point {
                observable: observable.clone(),
                x,
                x_low: low,
                x_high: high,
                value,
                stat,
                systematics,
            });
        }
    }
    Ok(())
}

/// Each bin's x and edges; `None` for a bin with no usable x.
fn bins(variable: &Value, label: &str) -> Result<Vec<Option<(f64, Option<f64>, Option<f64>)>>> {
    let values = variable
        .get("values")
        .and_then(|v| v.as_sequence())
        .ok_or_else(|| anyhow!("{label}: an independent variable has no `values` list"))?;
    values
        .iter()
        .enumerate()
        .map(|(i, bin)| {
            let field = |name: &str| {
                number(bin.get(name).unwrap_or(&Value::Null))
                    .map_err(|e| anyhow!("{label}: independent variable, bin {}, field '{name}': {e}", i + 1))
            };
            let (low, high, value) = (field("low")?, field("high")?, field("value")?);
            if let (Some(l), Some(h)) = (low, high) {
                if !(l <= h) {
                    bail!("{label}: independent variable, bin {}: low {l} is above high {h}", i + 1);
                }
            }
            let x = value.or(match (low, high) {
                (Some(l), Some(h)) => Some(0.5 * (l + h)),
                _ => None,
            });
            Ok(x.map(|x| (x, low, high)))
        })
        .collect()
}

/// The bin's independent error (statistical, in quadrature) and its
/// systematics by label.
fn errors(entry: &Value, value: f64, at: &str) -> Result<(f64, Vec<(String, f64)>)> {
    let list = match entry.get("errors") {
        None => bail!("{at}: no `errors`: a measurement without its uncertainty cannot be weighed"),
        Some(e) => e.as_sequence().ok_or_else(|| anyhow!("{at}, field 'errors': not a list"))?,
    };
    let (mut stat2, mut systematics) = (0.0, Vec::<(String, f64)>::new());
    for (k, e) in list.iter().enumerate() {
        let where_ = format!("{at}, error {}", k + 1);
        let size = |v: &Value, field: &str| -> Result<f64> {
            let size = match v {
                Value::String(s) if s.trim().ends_with('%') => {
                    let pct: f64 = s
                        .trim()
                        .trim_end_matches('%')
                        .trim()
                        .parse()
                        .map_err(|_| anyhow!("{where_}, field '{field}': {s:?} is not a percentage"))?;
                    pct / 100.0 * value
                }
                other => number(other)
                    .map_err(|m| anyhow!("{where_}, field '{field}': {m}"))?
                    .ok_or_else(|| anyhow!("{where_}, field '{field}': no value"))?,
            };
            if !size.is_finite() {
                bail!("{where_}, field '{field}': {size} is not finite");
            }
            Ok(size.abs())
        };
        let sigma = match (e.get("symerror"), e.get("asymerror")) {
            (Some(s), None) => size(s, "symerror")?,
            (None, Some(a)) => {
                let plus = size(a.get("plus").ok_or_else(|| anyhow!("{where_}: `asymerror` without `plus`"))?, "plus")?;
                let minus =
                    size(a.get("minus").ok_or_else(|| anyhow!("{where_}: `asymerror` without `minus`"))?, "minus")?;
                0.5 * (plus + minus)
            }
            (Some(_), Some(_)) => bail!("{where_}: both `symerror` and `asymerror`"),
            (None, None) => bail!("{where_}: neither `symerror` nor `asymerror`"),
        };
        let label = e.get("label").and_then(scalar_text).unwrap_or_default();
        if label.is_empty() || label.to_ascii_lowercase().starts_with("stat") {
            stat2 += sigma * sigma;
        } else if let Some(s) = systematics.iter_mut().find(|(l, _)| *l == label) {
            s.1 = (s.1 * s.1 + sigma * sigma).sqrt();
        } else {
            systematics.push((label, sigma));
        }
    }
    if !(stat2 > 0.0) {
        bail!("{at}: no statistical (or unlabelled) error above zero: the measurement's own error must be positive");
    }
    Ok((stat2.sqrt(), systematics))
}
