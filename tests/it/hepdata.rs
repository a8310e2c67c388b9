//! The HEPData reader on real STAR records (`../shared/hepdata/`, copied
//! into `tests/fixtures/hepdata/` so that a clone carries them): every value,
//! error and bin edge as published (read here by a plain line scan of the
//! file, not by the reader's YAML parser), the covariance equal to one built
//! here from the errors, null bins skipped; a record's submission.yaml with
//! a table chosen by name; a calibration straight from a table; and
//! malformed records refused with the file, table and entry named.

use mdpipe::base::hepdata::{self, HepdataOptions};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/hepdata").join(name)
}

/// A table file as (value or None, stat, sys) per dependent value, in file
/// order, scanned line by line: `value: X` lines and the `symerror` of the
/// errors before them (the STAR spectra write errors first, then the value).
fn scan(path: &Path) -> Vec<(Option<f64>, f64, f64)> {
    let text = std::fs::read_to_string(path).unwrap();
    let number = |line: &str, key: &str| -> Option<f64> {
        let rest = &line[line.find(key)? + key.len()..];
        let end = rest.find(['}', ',']).unwrap_or(rest.len());
        rest[..end].trim().trim_matches('\'').parse().ok()
    };
    let (mut out, mut stat, mut sys) = (Vec::new(), 0.0, 0.0);
    let mut in_dependent = false;
    for line in text.lines() {
        in_dependent |= line.starts_with("dependent_variables");
        if line.starts_with("independent_variables") {
            in_dependent = false;
        }
        if !in_dependent {
            continue;
        }
        if line.contains("label: stat") {
            stat = number(line, "symerror:").unwrap_or(f64::NAN);
        } else if line.contains("label: sys") {
            sys = number(line, "symerror:").unwrap_or(f64::NAN);
        } else if line.trim_start().starts_with("value:") || line.trim_start().starts_with("- {value:") {
            out.push((number(line, "value:"), stat, sys));
            (stat, sys) = (0.0, 0.0);
        }
    }
    out
}

/// Every bin's edges in the file, scanned (only independent variables have `low:`).
fn scan_edges(path: &Path) -> Vec<(f64, f64)> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| l.contains("low:") && l.contains("high:"))
        .map(|l| {
            let grab = |key: &str| {
                let rest = &l[l.find(key).unwrap() + key.len()..];
                rest[..rest.find([',', '}']).unwrap()].trim().parse::<f64>().unwrap()
            };
            (grab("low:"), grab("high:"))
        })
        .collect()
}

#[test]
fn star_spectra_are_read_as_published() {
    for file in ["star_bes_fig12_piplus.yaml", "star_bes_fig12_kplus.yaml", "star_bes_fig12_proton.yaml"] {
        let path = fixture(file);
        let record = hepdata::read(&path, &HepdataOptions::default()).unwrap();
        let scanned = scan(&path);
        let edges = scan_edges(&path);
        let published: Vec<&(Option<f64>, f64, f64)> = scanned.iter().filter(|v| v.0.is_some()).collect();
        let nulls = scanned.len() - published.len();
        assert_eq!(record.skipped.len(), nulls, "{file}: null bins skipped");
        assert_eq!(record.points.len(), published.len(), "{file}");
        assert!(nulls > 0, "{file}: the record has null bins to skip");
        // Nine centrality classes, named from their qualifiers.
        let mut names: Vec<&str> = record.points.iter().map(|p| p.observable.as_str()).collect();
        names.dedup();
        assert_eq!(names.len(), 9, "{file}: {names:?}");
        for (p, (value, stat, sys)) in record.points.iter().zip(&published) {
            assert_eq!(Some(p.value), *value, "{file}");
            assert_eq!(p.stat, *stat, "{file}: stat error at {}", p.x);
            assert_eq!(p.systematics, vec![("sys".to_string(), *sys)], "{file}");
            let (lo, hi) = (p.x_low.unwrap(), p.x_high.unwrap());
            assert!(edges.contains(&(lo, hi)), "{file}: edges ({lo}, {hi}) not published");
            assert_eq!(p.x, 0.5 * (lo + hi));
        }
    }
}

/// The covariance: within each centrality class, sys_i sys_j for every pair
/// (fully correlated), or sys_i sys_j exp(-|x_i - x_j| / l); nothing between classes.
#[test]
fn the_covariance_is_the_systematics_correlated_within_each_class() {
    let path = fixture("star_bes_fig12_piplus.yaml");
    for length in [None, Some(0.5), Some(0.0)] {
        let options = HepdataOptions { correlation_length: length, ..Default::default() };
        let record = hepdata::read(&path, &options).unwrap();
        let entries = record.covariance(&options, &Default::default());
        let mut expected = std::collections::HashMap::new();
        for a in &record.points {
            for b in &record.points {
                if a.observable != b.observable {
                    continue;
                }
                let rho = match length {
                    None => 1.0,
                    Some(l) if a.x == b.x => 1.0 + 0.0 * l,
                    Some(0.0) => 0.0,
                    Some(l) => (-(a.x - b.x).abs() / l).exp(),
                };
                let c = rho * a.systematics[0].1 * b.systematics[0].1;
                if c != 0.0 {
                    expected.insert((a.observable.clone(), a.x.to_bits(), b.x.to_bits()), c);
                }
            }
        }
        assert_eq!(entries.len(), expected.len(), "correlation length {length:?}");
        for e in &entries {
            assert_eq!(e.observable_a, e.observable_b);
            let c = expected[&(e.observable_a.clone(), e.x_a.to_bits(), e.x_b.to_bits())];
            assert!((e.covariance - c).abs() <= 1e-15 * c.abs(), "{e:?} vs {c}");
        }
    }
}

/// x at another independent variable (⟨pT⟩ in each bin), edges from the bins;
/// labels 'Stat error' and 'Sys error'.
#[test]
fn x_may_be_another_independent_variable() {
    let options = HepdataOptions { x: Some("$\\langle p_T \\rangle$".into()), ..Default::default() };
    let record = hepdata::read(&fixture("star_auau200_d0_spectra.yaml"), &options).unwrap();
    let first = &record.points[0];
    assert_eq!((first.x, first.x_low, first.x_high), (0.242, Some(0.001), Some(0.485)));
    assert_eq!((first.value, first.stat), (0.125, 2.79e-02));
    assert_eq!(first.systematics, vec![("Sys error".to_string(), 3.26e-02)]);
    let msg = format!(
        "{:#}",
        hepdata::read(
            &fixture("star_auau200_d0_spectra.yaml"),
            &HepdataOptions { x: Some("pT".into()), ..Default::default() }
        )
        .unwrap_err()
    );
    assert!(msg.contains("no independent variable named 'pT'"), "{msg}");
}

/// Asymmetric errors with signed plus/minus, two labelled systematics.
#[test]
fn asymmetric_errors_enter_with_their_mean_magnitude() {
    let record = hepdata::read(&fixture("star_dihadron_mean_pt.yaml"), &HepdataOptions::default()).unwrap();
    // Third value: stat 0.026, v2min and v2max each {minus: -0.001, plus: -0.001}.
    let p = &record.points[2];
    assert_eq!((p.value, p.stat), (0.841, 0.026));
    assert_eq!(p.systematics, vec![("v2min".to_string(), 0.001), ("v2max".to_string(), 0.001)]);
    // Fourth: v2min {minus: -0.003, plus: -0.004}.
    assert_eq!(record.points[3].systematics[0], ("v2min".to_string(), 0.0035));
}

/// A record's submission.yaml, one table chosen by its name.
#[test]
fn a_submission_chooses_tables_by_name() {
    let dir = std::env::temp_dir().join(format!("mdpipe-hepdata-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(fixture("star_record158_submission.yaml"), dir.join("submission.yaml")).unwrap();
    std::fs::copy(fixture("star_dihadron_mean_pt.yaml"), dir.join("Fig7_part1.yaml")).unwrap();
    let options = HepdataOptions { tables: vec!["Figure 7.1".into()], ..Default::default() };
    let record = hepdata::read(&dir.join("submission.yaml"), &options).unwrap();
    let direct = hepdata::read(&fixture("star_dihadron_mean_pt.yaml"), &HepdataOptions::default()).unwrap();
    assert_eq!(record.points, direct.points);
    let missing = HepdataOptions { tables: vec!["Figure 99".into()], ..Default::default() };
    let msg = format!("{:#}", hepdata::read(&dir.join("submission.yaml"), &missing).unwrap_err());
    assert!(msg.contains("no table named 'Figure 99'") && msg.contains("Figure 7.1"), "{msg}");
    // All tables: the other data files are not in the folder, and the error says which.
    let msg = format!("{:#}", hepdata::read(&dir.join("submission.yaml"), &HepdataOptions::default()).unwrap_err());
    assert!(msg.contains("table 'Figure 2 for") && msg.contains("Fig2_2.5-3_1.yaml"), "{msg}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Malformed records: each refused, naming the file and the entry.
#[test]
fn malformed_records_are_refused_with_the_entry_named() {
    let good = "independent_variables:\n- header: {name: PT}\n  values:\n  - {low: 0.0, high: 1.0}\n  - {low: 1.0, high: 2.0}\ndependent_variables:\n- header: {name: Y}\n  qualifiers:\n  - {name: CENT, value: 0-5%}\n  values:\n  - value: 1.0\n    errors:\n    - {symerror: 0.1, label: stat}\n    - {symerror: 0.2, label: sys}\n  - value: 2.0\n    errors:\n    - {symerror: 0.1, label: stat}\n";
    let cases: [(&str, String, &str); 14] = [
        ("not yaml", "independent_variables: [\n".into(), "not valid YAML"),
        ("no dependents", good.replace("\ndependent_variables", "\ndependents"), "no `dependent_variables` list"),
        ("no independents", good.replace("independent_variables", "independents"), "no `independent_variables` list"),
        ("value count", good.replace("  - {low: 1.0, high: 2.0}\n", ""), "has 2 values for 1 bins"),
        ("bad value", good.replace("value: 2.0", "value: two"), "value 2, field 'value': \"two\" is not a number"),
        ("bad edge", good.replace("low: 1.0", "low: one"), "bin 2, field 'low'"),
        ("edges reversed", good.replace("{low: 1.0, high: 2.0}", "{low: 2.0, high: 1.0}"), "low 2 is above high 1"),
        (
            "no errors",
            good.replace("  - value: 2.0\n    errors:\n    - {symerror: 0.1, label: stat}\n", "  - value: 2.0\n"),
            "value 2: no `errors`",
        ),
        (
            "bad percent",
            good.replace("symerror: 0.2", "symerror: 'ten%'"),
            "error 2, field 'symerror': \"ten%\" is not a percentage",
        ),
        (
            "asym half",
            good.replace("{symerror: 0.2, label: sys}", "{asymerror: {plus: 0.2}, label: sys}"),
            "error 2: `asymerror` without `minus`",
        ),
        (
            "no stat",
            good.replace("    - {symerror: 0.1, label: stat}\n    - {symerror: 0.2", "    - {symerror: 0.2"),
            "value 1: no statistical",
        ),
        (
            "infinite value",
            good.replace("value: 2.0", "value: .inf"),
            "value 2: value inf at x = 1.5 is not a finite number",
        ),
        ("infinite edge", good.replace("high: 2.0", "high: .inf"), "is not a finite number"),
        (
            "all null",
            good.replace("value: 1.0", "value: 'null'").replace("value: 2.0", "value: '-'"),
            "no measured values",
        ),
    ];
    let dir = std::env::temp_dir().join(format!("mdpipe-hepdata-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("table.yaml");
    std::fs::write(&path, good).unwrap();
    let record = hepdata::read(&path, &HepdataOptions::default()).unwrap();
    assert_eq!(record.points[0].observable, "0_5pct");
    for (what, text, expect) in cases {
        std::fs::write(&path, &text).unwrap();
        let msg = format!("{:#}", hepdata::read(&path, &HepdataOptions::default()).unwrap_err());
        assert!(msg.contains(expect) && msg.contains("table.yaml"), "{what}: {msg}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A calibration straight from a published table: `[data] measurements`
/// names the YAML file, the systematics become each observable's covariance.
#[test]
fn a_calibration_reads_a_table_as_its_data() {
    let dir = std::env::temp_dir().join(format!("mdpipe-hepdata-fit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(fixture("star_auau200_d0_spectra.yaml"), dir.join("d0.yaml")).unwrap();
    let config = r#"name = "d0"
[model]
kind = "expression"
[model.observables]
central = "a*exp(-x/t)"
[data]
measurements = "d0.yaml"
observables = ["central"]
[data.hepdata]
x = '$\langle p_T \rangle$'
observables = { "D_0_spectra_in_0_10_pct_AuplusAu_collisions" = "central" }
[parameters.a]
min = 0.0
max = 1.0
[parameters.t]
min = 0.1
max = 3.0
[discrepancy]
kernel = "II"
"#;
    std::fs::write(dir.join("d0.toml"), config).unwrap();
    let analysis = mdpipe::systems::load(&dir.join("d0.toml")).unwrap();
    let problem = mdpipe::calibrate::Problem::new(&analysis, &Default::default()).unwrap();
    let block = &problem.likelihood.blocks[0];
    assert_eq!((block.name.as_str(), block.len()), ("central", 11));
    let c = block.covariance.as_ref().unwrap();
    // Fully correlated systematics: c_01 = sys_0 sys_1.
    assert!((c[1] - 3.26e-02 * 1.42e-02).abs() < 1e-15);
    assert!(problem.likelihood.log_likelihood(&[0.1, 0.5, 0.1, 1.0, 0.5]).is_finite());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A record written by hepdata_lib and validated by hepdata_validator
/// (`tests/fixtures/hepdata/written/make.py`) reads back value for value:
/// binned x, two classes named from their qualifier, symmetric and
/// asymmetric errors, a bin written as '-' skipped.
#[test]
fn records_written_by_hepdata_lib_read_back_value_for_value() {
    let dir = fixture("written");
    let options = HepdataOptions { tables: vec!["Spectra".into()], ..Default::default() };
    let record = hepdata::read(&dir.join("record/submission.yaml"), &options).unwrap();
    let expected = std::fs::read_to_string(dir.join("expected.csv")).unwrap();
    let rows: Vec<Vec<&str>> = expected.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(record.points.len(), rows.len());
    assert_eq!(record.skipped.len(), 1);
    let close = |a: f64, b: &str| (a - b.parse::<f64>().unwrap()).abs() <= 1e-15 * a.abs();
    for (p, row) in record.points.iter().zip(&rows) {
        assert_eq!(p.observable, hepdata::identifier(row[0]));
        assert!(close(p.x_low.unwrap(), row[1]) && close(p.x_high.unwrap(), row[2]), "{p:?} {row:?}");
        assert!(close(p.value, row[3]) && close(p.stat, row[4]), "{p:?} {row:?}");
        assert_eq!(p.systematics.len(), 2);
        assert!(close(p.systematics[0].1, row[5]) && close(p.systematics[1].1, row[6]), "{p:?} {row:?}");
    }
}
