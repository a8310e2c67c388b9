//! Systematic errors as a measurement table carries them, the way HEPData
//! tables do: a `stat` column (independent between points: the
//! measurement's own error) and one `sys:<name>` column per source, each
//! correlated over a scope the config gives (`[data] systematics`):
//!
//! - `"table"` (the default): fully correlated across the points of its
//!   own observable, as HEPData's systematics are;
//! - `"all"`: fully correlated across every point of every observable (a
//!   luminosity, a normalization shared by every table);
//! - a number ℓ: correlated as `exp(−|x − x'| / ℓ)` within its observable
//!   (0: independent, added to that point's variance only).
//!
//! Each source adds `ρ σ_a σ_b` to the covariance of points a and b; the
//! entries are exact to the file's numbers (no printed rounding), so the
//! likelihood's structure (a rank-one term per `"all"` source across the
//! observables, the rest in their blocks) is found exactly.

use super::measurement::{CovarianceEntry, Measurement};
use super::table::RawTable;
use anyhow::{bail, Result};
use std::collections::BTreeMap;
use std::path::Path;

/// The prefix of a systematic source's column.
pub const SYS_PREFIX: &str = "sys:";

/// How far one systematic source is correlated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scope {
    /// Fully, within its observable.
    Table,
    /// Fully, across every point of every observable.
    All,
    /// As exp(−|Δx| / ℓ) within its observable; ℓ = 0 is independent.
    Length(f64),
}

impl<'de> serde::Deserialize<'de> for Scope {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Written {
            Name(String),
            Length(f64),
        }
        match Written::deserialize(deserializer)? {
            Written::Name(n) if n == "table" => Ok(Scope::Table),
            Written::Name(n) if n == "all" => Ok(Scope::All),
            Written::Length(l) if l.is_finite() && l >= 0.0 => Ok(Scope::Length(l)),
            Written::Name(n) => Err(serde::de::Error::custom(format!(
                "unknown scope {n:?} (use \"table\", \"all\" or a correlation length ≥ 0)"
            ))),
            Written::Length(l) => {
                Err(serde::de::Error::custom(format!("correlation length {l} must be a finite number ≥ 0")))
            }
        }
    }
}

impl serde::Serialize for Scope {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            Scope::Table => serializer.serialize_str("table"),
            Scope::All => serializer.serialize_str("all"),
            Scope::Length(l) => serializer.serialize_f64(*l),
        }
    }
}

/// One measured point with its errors by source.
#[derive(Clone, Debug, PartialEq)]
pub struct SourcedPoint {
    pub observable: String,
    pub x: f64,
    /// Each systematic source's error at this point, by name (absent where
    /// the source does not touch the point).
    pub systematics: Vec<(String, f64)>,
}

/// The correlation of one source between points a and b.
fn correlation(scope: Scope, a: &SourcedPoint, b: &SourcedPoint) -> f64 {
    let same_observable = a.observable == b.observable;
    match scope {
        Scope::All => 1.0,
        _ if !same_observable => 0.0,
        _ if a.x == b.x => 1.0,
        Scope::Table => 1.0,
        Scope::Length(l) if l > 0.0 => (-(a.x - b.x).abs() / l).exp(),
        Scope::Length(_) => 0.0,
    }
}

/// The systematics' covariance between every two points (both orders, in
/// `base::covariance`'s format), each source over its scope.
pub fn covariance(points: &[SourcedPoint], scope_of: impl Fn(&str) -> Scope) -> Vec<CovarianceEntry> {
    let mut out = Vec::new();
    for a in points {
        for b in points {
            let c: f64 = a
                .systematics
                .iter()
                .filter_map(|(name, ea)| {
                    let eb = b.systematics.iter().find(|(n, _)| n == name)?.1;
                    Some(correlation(scope_of(name), a, b) * ea * eb)
                })
                .sum();
            if c != 0.0 {
                out.push(CovarianceEntry {
                    observable_a: a.observable.clone(),
                    x_a: a.x,
                    observable_b: b.observable.clone(),
                    x_b: b.x,
                    covariance: c,
                    line: 0,
                    rounding: 0.0,
                });
            }
        }
    }
    out
}

/// The names of a table's systematic sources (`sys:<name>` columns).
pub fn source_names(raw: &RawTable) -> Vec<String> {
    raw.columns().iter().filter_map(|c| c.strip_prefix(SYS_PREFIX).map(str::to_string)).collect()
}

/// The sources of a measurement table read with its `measurements` (in
/// the same rows), each value checked: finite and ≥ 0 (an empty cell in a
/// CSV is a source that does not touch that point). Every scope the config
/// gives must name a source of the file.
pub fn read_sources(
    path: &Path,
    raw: &RawTable,
    measurements: &[Measurement],
    scopes: &BTreeMap<String, Scope>,
) -> Result<Vec<SourcedPoint>> {
    let names = source_names(raw);
    if let Some(unknown) = scopes.keys().find(|n| !names.contains(n)) {
        bail!(
            "[data] systematics: {unknown:?} is not a source of {} (its sources: {})",
            path.display(),
            if names.is_empty() { "none: no sys:<name> column".to_string() } else { names.join(", ") }
        );
    }
    let mut points: Vec<SourcedPoint> = measurements
        .iter()
        .map(|m| SourcedPoint { observable: m.observable.clone(), x: m.x, systematics: Vec::new() })
        .collect();
    for name in &names {
        let column = format!("{SYS_PREFIX}{name}");
        for (i, sigma) in raw.optional_numbers(path, &column)?.into_iter().enumerate() {
            match sigma {
                None => {}
                Some(s) if s.is_finite() && s >= 0.0 => points[i].systematics.push((name.clone(), s)),
                Some(s) => {
                    return Err(measurements[i].field_error(path, &column, format!("{s} is not an error ≥ 0")));
                }
            }
        }
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(o: &str, x: f64, sys: &[(&str, f64)]) -> SourcedPoint {
        SourcedPoint { observable: o.into(), x, systematics: sys.iter().map(|(n, s)| (n.to_string(), *s)).collect() }
    }

    fn entry(entries: &[CovarianceEntry], oa: &str, xa: f64, ob: &str, xb: f64) -> f64 {
        entries
            .iter()
            .find(|e| e.observable_a == oa && e.x_a == xa && e.observable_b == ob && e.x_b == xb)
            .map_or(0.0, |e| e.covariance)
    }

    #[test]
    fn each_source_adds_its_errors_product_over_its_scope() {
        let points = [
            point("a", 0.0, &[("lumi", 0.1), ("tpc", 0.2)]),
            point("a", 1.0, &[("lumi", 0.3), ("tpc", 0.4)]),
            point("b", 0.0, &[("lumi", 0.5)]),
        ];
        let scopes = |name: &str| if name == "lumi" { Scope::All } else { Scope::Length(2.0) };
        let c = covariance(&points, scopes);
        // Within a: both sources, tpc damped by exp(−1/2) between x = 0 and 1.
        assert!((entry(&c, "a", 0.0, "a", 0.0) - (0.01 + 0.04)).abs() < 1e-15);
        let within = 0.1 * 0.3 + (-0.5f64).exp() * 0.2 * 0.4;
        assert!((entry(&c, "a", 0.0, "a", 1.0) - within).abs() < 1e-15);
        assert_eq!(entry(&c, "a", 1.0, "a", 0.0), entry(&c, "a", 0.0, "a", 1.0), "both orders");
        // Across observables only the source scoped "all".
        assert!((entry(&c, "a", 1.0, "b", 0.0) - 0.3 * 0.5).abs() < 1e-15);
        // Scoped to its table, a source does not cross to b; at length 0 it
        // touches each point's own variance only.
        let table = covariance(&points, |_| Scope::Table);
        assert_eq!(entry(&table, "a", 0.0, "b", 0.0), 0.0);
        assert!((entry(&table, "a", 0.0, "a", 1.0) - (0.03 + 0.08)).abs() < 1e-15);
        let independent = covariance(&points, |_| Scope::Length(0.0));
        assert_eq!(entry(&independent, "a", 0.0, "a", 1.0), 0.0);
        assert!((entry(&independent, "b", 0.0, "b", 0.0) - 0.25).abs() < 1e-15);
    }

    #[test]
    fn scopes_are_read_as_written_and_anything_else_is_refused() {
        #[derive(serde::Deserialize)]
        struct T {
            s: BTreeMap<String, Scope>,
        }
        let t: T = toml::from_str("s = { lumi = \"all\", tpc = \"table\", pid = 0.5 }").unwrap();
        assert_eq!(t.s["lumi"], Scope::All);
        assert_eq!(t.s["tpc"], Scope::Table);
        assert_eq!(t.s["pid"], Scope::Length(0.5));
        let err = toml::from_str::<T>("s = { lumi = \"everything\" }").err().unwrap().to_string();
        assert!(err.contains("unknown scope \"everything\""), "{err}");
        let err = toml::from_str::<T>("s = { lumi = -1.0 }").err().unwrap().to_string();
        assert!(err.contains("must be a finite number ≥ 0"), "{err}");
        let err = toml::from_str::<T>("s = { lumi = inf }").err().unwrap().to_string();
        assert!(err.contains("correlation length inf must be a finite number"), "{err}");
    }
}
