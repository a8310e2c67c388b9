//! Systematics as columns of the measurement file (`stat`, `sys:<name>`),
//! each scoped by `[data] systematics`: the likelihood of a calibration
//! read from such a file equals the multivariate normal whose covariance
//! this test builds from the same numbers by hand and factorizes with its
//! own Cholesky; a source shared by every observable (`"all"`) is found as
//! the rank-one structure across them; bad columns and scopes are refused
//! naming the file, row and field.

use mdpipe::calibrate::Problem;
use std::path::{Path, PathBuf};

/// Two observables, 6 points each: value, stat, lumi (shared by all), tpc (within each).
const ROWS: usize = 6;

fn row(o: usize, i: usize) -> (f64, f64, f64, f64, f64) {
    let x = i as f64;
    let value = 1.0 + 0.5 * x + 0.03 * ((o * ROWS + i) as f64).sin();
    (x, value, 0.05 + 0.01 * i as f64, 0.02 * (1.0 + 0.1 * x), 0.03)
}

fn write_study(dir: &Path, table: &str, systematics: &str) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("data.csv"), table).unwrap();
    let config = format!(
        r#"name = "columns"
[model]
kind = "expression"
[model.observables]
a = "c + m*x"
b = "c + m*x"
[data]
measurements = "data.csv"
{systematics}
[parameters.c]
min = 0.0
max = 2.0
[parameters.m]
min = 0.0
max = 1.0
[discrepancy]
kernel = "none"
"#
    );
    std::fs::write(dir.join("study.toml"), config).unwrap();
    dir.join("study.toml")
}

fn table() -> String {
    let mut text = String::from("observable,x,value,stat,sys:lumi,sys:tpc\n");
    for (o, name) in ["a", "b"].iter().enumerate() {
        for i in 0..ROWS {
            let (x, v, stat, lumi, tpc) = row(o, i);
            text.push_str(&format!("{name},{x},{v},{stat},{lumi},{tpc}\n"));
        }
    }
    text
}

/// log N(y; η(θ), Σ) with Σ built here: stat² on the diagonal, lumi fully
/// correlated across all 12 points, tpc fully within each observable.
fn by_hand(c: f64, m: f64) -> f64 {
    let points: Vec<(usize, (f64, f64, f64, f64, f64))> =
        (0..2).flat_map(|o| (0..ROWS).map(move |i| (o, row(o, i)))).collect();
    let n = points.len();
    let mut cov = vec![0.0; n * n];
    for (i, (oi, (_, _, si, li, ti))) in points.iter().enumerate() {
        for (j, (oj, (_, _, _, lj, tj))) in points.iter().enumerate() {
            let mut v = li * lj + if oi == oj { ti * tj } else { 0.0 };
            if i == j {
                v += si * si;
            }
            cov[i * n + j] = v;
        }
    }
    // Cholesky, L L^T = Σ, row-major lower.
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s: f64 = cov[i * n + j] - (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum::<f64>();
            l[i * n + j] = if i == j { s.sqrt() } else { s / l[j * n + j] };
        }
    }
    let r: Vec<f64> = points.iter().map(|(_, (x, v, ..))| v - (c + m * x)).collect();
    let mut z = vec![0.0; n];
    for i in 0..n {
        z[i] = (r[i] - (0..i).map(|k| l[i * n + k] * z[k]).sum::<f64>()) / l[i * n + i];
    }
    let log_det: f64 = (0..n).map(|i| 2.0 * l[i * n + i].ln()).sum();
    -0.5 * (z.iter().map(|v| v * v).sum::<f64>() + log_det + n as f64 * (2.0 * std::f64::consts::PI).ln())
}

#[test]
fn systematics_as_columns_make_the_covariance_with_a_shared_source_structured() {
    let dir = std::env::temp_dir().join(format!("mdpipe-sys-columns-{}", std::process::id()));
    let config = write_study(&dir, &table(), "systematics = { lumi = \"all\" }");
    let analysis = mdpipe::systems::load(&config).unwrap();
    let problem = Problem::new(&analysis, &Default::default()).unwrap();
    // The shared source is the one column across observables: rank one.
    let label = problem.likelihood.form.label();
    assert!(label.contains("structured") && label.contains("rank 1"), "{label}");
    for (c, m) in [(1.0, 0.5), (0.9, 0.55), (1.2, 0.4)] {
        let (got, want) = (problem.likelihood.log_likelihood(&[c, m]), by_hand(c, m));
        assert!((got - want).abs() < 1e-9 * want.abs().max(1.0), "θ = ({c}, {m}): {got} vs {want}");
    }
    // Scoped to its table (the default), lumi stays inside each block: nothing links them.
    let config = write_study(&dir, &table(), "");
    let problem = Problem::new(&mdpipe::systems::load(&config).unwrap(), &Default::default()).unwrap();
    assert!(problem.likelihood.layout().is_none(), "{}", problem.likelihood.form.label());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_systematic_columns_and_scopes_are_refused_naming_the_field() {
    let dir = std::env::temp_dir().join(format!("mdpipe-sys-columns-bad-{}", std::process::id()));
    let refused = |table: &str, systematics: &str| {
        let config = write_study(&dir, table, systematics);
        let analysis = mdpipe::systems::load(&config);
        let err = match analysis {
            Err(e) => e,
            Ok(a) => Problem::new(&a, &Default::default()).err().expect("refused"),
        };
        format!("{err:#}")
    };
    let negative = table().replacen(",0.03\n", ",-0.03\n", 1);
    let msg = refused(&negative, "");
    assert!(msg.contains("data.csv: line 2, field 'sys:tpc'") && msg.contains("not an error ≥ 0"), "{msg}");
    let msg = refused(&table(), "systematics = { jes = \"all\" }");
    assert!(msg.contains("\"jes\" is not a source of") && msg.contains("lumi, tpc"), "{msg}");
    let msg = refused(&table(), "systematics = { lumi = \"some\" }");
    assert!(msg.contains("unknown scope \"some\""), "{msg}");
    let both =
        table().replace("observable,x,value,stat,", "observable,x,value,stat,error,").replace(",0.02", ",0.05,0.02");
    let msg = refused(&both, "");
    assert!(msg.contains("columns 'error' and 'stat' both"), "{msg}");
    let zero_stat = table().replacen(",0.05,", ",0,", 1);
    let msg = refused(&zero_stat, "");
    assert!(msg.contains("field 'stat'") && msg.contains("not a positive 1-sigma error"), "{msg}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The same table as Parquet, a source absent from one point (a null): that
/// point's covariance loses the source's terms, and the likelihood is the
/// CSV's with an empty cell there.
#[test]
fn parquet_nulls_are_points_a_source_does_not_touch() {
    use polars::prelude::*;
    let dir = std::env::temp_dir().join(format!("mdpipe-sys-columns-pq-{}", std::process::id()));
    let csv = table().replacen(",0.03\n", ",\n", 1);
    let config = write_study(&dir, &csv, "systematics = { lumi = \"all\" }");
    let from_csv = Problem::new(&mdpipe::systems::load(&config).unwrap(), &Default::default()).unwrap();
    let rows: Vec<Vec<String>> = csv.lines().skip(1).map(|l| l.split(',').map(String::from).collect()).collect();
    let number = |k: usize| rows.iter().map(|r| r[k].parse::<f64>().ok()).collect::<Vec<Option<f64>>>();
    let mut df = DataFrame::new(
        rows.len(),
        vec![
            Column::new("observable".into(), rows.iter().map(|r| r[0].clone()).collect::<Vec<_>>()),
            Column::new("x".into(), number(1)),
            Column::new("value".into(), number(2)),
            Column::new("stat".into(), number(3)),
            Column::new("sys:lumi".into(), number(4)),
            Column::new("sys:tpc".into(), number(5)),
        ],
    )
    .unwrap();
    mdpipe::artifacts::write_parquet_atomic(&dir.join("data.parquet"), &mut df, None).unwrap();
    let text = std::fs::read_to_string(&config).unwrap().replace("data.csv", "data.parquet");
    std::fs::write(&config, text).unwrap();
    let from_parquet = Problem::new(&mdpipe::systems::load(&config).unwrap(), &Default::default()).unwrap();
    for theta in [[1.0, 0.5], [0.9, 0.55]] {
        let (a, b) = (from_csv.likelihood.log_likelihood(&theta), from_parquet.likelihood.log_likelihood(&theta));
        assert!((a - b).abs() < 1e-12 * a.abs().max(1.0), "{a} vs {b}");
    }
    // Without the source at that point the likelihood differs from the full table's.
    let full = write_study(&dir, &table(), "systematics = { lumi = \"all\" }");
    let whole = Problem::new(&mdpipe::systems::load(&full).unwrap(), &Default::default()).unwrap();
    assert!(
        (whole.likelihood.log_likelihood(&[1.0, 0.5]) - from_csv.likelihood.log_likelihood(&[1.0, 0.5])).abs() > 1e-6
    );
    let _ = std::fs::remove_dir_all(&dir);
}
