//! `mdpipe ingest` on fixtures written by h5py and numpy
//! (tests/fixtures/iebe_music/make_fixtures.py): the known spectra and
//! v_n{2} must come back within their jackknife errors; text and HDF5 forms
//! of the same events must agree; bad events and thin points are reported.

use mdpipe::ingest::{self, IngestSettings, IngestedRow};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn fixture_runs() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/iebe_music/runs")
}

// Keep in sync with make_fixtures.py: pid, mass, dN/dy, T.
const SPECIES: [(i32, f64, f64, f64); 3] =
    [(211, 0.13957, 120.0, 0.22), (321, 0.493677, 20.0, 0.26), (2212, 0.938272, 8.0, 0.30)];

fn v2_of(pt: f64, m: f64) -> f64 {
    let k = (pt * pt + m * m).sqrt() - m;
    0.16 * k / (0.35 + k)
}

fn v3_of(pt: f64, m: f64) -> f64 {
    let k = (pt * pt + m * m).sqrt() - m;
    0.06 * k / (0.5 + k)
}

/// dN/dpT in the file's window: |y| < 0.5 for one identified species, or
/// |η| < 0.5 for all charged (both signs).
fn density(pt: f64, s: (i32, f64, f64, f64), charged: bool) -> f64 {
    let (_, m, dndy, t) = s;
    let a = dndy / (2.0 * std::f64::consts::PI * t * (m + t) * (-m / t).exp());
    let mt = (pt * pt + m * m).sqrt();
    let acceptance = if charged { 2.0 * ((pt / mt) * 0.5f64.sinh()).asinh() / 0.5 } else { 1.0 };
    2.0 * std::f64::consts::PI * a * pt * (-mt / t).exp() * acceptance
}

fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    let n = 200;
    let h = (b - a) / n as f64;
    (0..=n)
        .map(|i| {
            f(a + i as f64 * h)
                * if i == 0 || i == n {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                }
        })
        .sum::<f64>()
        * h
        / 3.0
}

fn truth(observable: &str, x: f64) -> f64 {
    let (tag, kind) = observable.split_once('_').unwrap();
    let species: Vec<_> = match tag {
        "ch" => SPECIES.to_vec(),
        "pi" => vec![SPECIES[0]],
        "p" => vec![SPECIES[2]],
        _ => unreachable!(),
    };
    let charged = tag == "ch";
    let (a, b) = (x - 0.1, x + 0.1);
    let count: f64 = species.iter().map(|&s| simpson(|p| density(p, s, charged), a, b)).sum();
    match kind {
        "spectrum" => count / (2.0 * std::f64::consts::PI * x * 0.2),
        "v2" => species.iter().map(|&s| simpson(|p| density(p, s, charged) * v2_of(p, s.1), a, b)).sum::<f64>() / count,
        "v3" => species.iter().map(|&s| simpson(|p| density(p, s, charged) * v3_of(p, s.1), a, b)).sum::<f64>() / count,
        _ => unreachable!(),
    }
}

fn by_point(rows: &[IngestedRow], id: i64) -> HashMap<(String, u64), &IngestedRow> {
    rows.iter().filter(|r| r.design_id == id).map(|r| ((r.observable.clone(), r.x.to_bits()), r)).collect()
}

#[test]
fn ingest_recovers_known_spectra_and_flow_from_h5py_fixtures() {
    let settings = IngestSettings { min_events: 5, ..Default::default() };
    let (got, design) = ingest::ingest_runs(&fixture_runs(), None, &settings).unwrap();
    assert!(design.is_none());
    let report = &got.report;
    // Point 0: 40 good events; the NaN event and the one missing a file are listed.
    let p0 = report.points.iter().find(|p| p.design_id == 0).unwrap();
    assert_eq!(p0.good_events, 40, "{p0:?}");
    assert_eq!(p0.skipped.len(), 2);
    let nan = p0.skipped.iter().find(|s| s.event == "spvn_results_40").unwrap();
    assert!(
        nan.reason
            .contains("spvn_results.h5:/spvn_results_40/particle_211_vndata_diff_y_-0.5_0.5.dat: row 4, column 2"),
        "{}",
        nan.reason
    );
    let missing = p0.skipped.iter().find(|s| s.event == "spvn_results_41").unwrap();
    assert!(missing.reason.contains("missing file particle_9999_vndata_diff_eta_-0.5_0.5.dat"), "{}", missing.reason);
    // Point 3 has 2 events: flagged, and absent from the table.
    let p3 = report.points.iter().find(|p| p.design_id == 3).unwrap();
    assert!(p3.flagged.as_deref().unwrap().contains("only 2 good events"), "{p3:?}");
    assert!(got.rows.iter().all(|r| r.design_id != 3));

    // Point 0 against the truth the fixture was drawn from: 70 values.
    let rows0 = by_point(&got.rows, 0);
    assert_eq!(rows0.len(), 70);
    let mut pulls = Vec::new();
    for r in rows0.values() {
        assert_eq!(r.n_events, 40);
        let pull = (r.value - truth(&r.observable, r.x)) / r.error;
        assert!(
            pull.abs() < 4.0,
            "{}[{}]: {} vs truth {} ± {} (pull {pull:.1})",
            r.observable,
            r.x,
            r.value,
            truth(&r.observable, r.x),
            r.error
        );
        pulls.push(pull);
    }
    // Jackknife errors are right on average: the rms pull of 70 unit normals
    // is 1 ± 0.085; allow ±3.5 of that.
    let rms = (pulls.iter().map(|p| p * p).sum::<f64>() / pulls.len() as f64).sqrt();
    eprintln!("point 0: rms pull {rms:.3} over {} values", pulls.len());
    assert!((0.7..1.3).contains(&rms), "rms pull {rms}");

    // Points 1 (text) and 2 (HDF5, float32) hold the same events.
    let (t, h) = (by_point(&got.rows, 1), by_point(&got.rows, 2));
    assert_eq!(t.len(), h.len());
    assert!(t.len() >= 68);
    for (k, a) in &t {
        let b = h[k];
        assert!(
            (a.value - b.value).abs() <= 1e-4 * a.value.abs().max(1e-3),
            "{k:?}: text {} vs hdf5 {}",
            a.value,
            b.value
        );
    }
}

#[test]
fn ingest_writes_a_training_table_and_reports_corrupt_text() {
    // A copy of the text point with one corrupted file and one empty event folder.
    let dir = std::env::temp_dir().join(format!("mdpipe-ingest-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let src = fixture_runs().join("0001");
    let dst = dir.join("0005");
    for ev in std::fs::read_dir(&src).unwrap() {
        let ev = ev.unwrap().path();
        let to = dst.join(ev.file_name().unwrap());
        std::fs::create_dir_all(&to).unwrap();
        for f in std::fs::read_dir(&ev).unwrap() {
            let f = f.unwrap().path();
            std::fs::copy(&f, to.join(f.file_name().unwrap())).unwrap();
        }
    }
    let bad = dst.join("spvn_results_3/particle_2212_vndata_diff_y_-0.5_0.5.dat");
    let text = std::fs::read_to_string(&bad).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    lines[5] = lines[5].replacen("e", "x", 1);
    std::fs::write(&bad, lines.join("\n")).unwrap();

    let settings = IngestSettings { min_events: 5, ..Default::default() };
    let (got, _) = ingest::ingest_runs(&dir, None, &settings).unwrap();
    let p = &got.report.points[0];
    assert_eq!((p.design_id, p.good_events), (5, 11), "{p:?}");
    assert!(
        p.skipped[0].reason.contains("particle_2212_vndata_diff_y_-0.5_0.5.dat: line 6, column 1"),
        "{}",
        p.skipped[0].reason
    );

    // The table is a valid training table for train-emulator (long format).
    let out = dir.join("table.parquet");
    ingest::write(&got, None, &out).unwrap();
    let table = mdpipe::emulator::read_training_table(&out, &[]).unwrap();
    assert_eq!(table.design_ids, vec![5]);
    // 7 observables × 10 bins, less any bin too thin to measure in 11 events.
    assert_eq!(table.n_outputs(), 70 - p.undefined_bins.len());
    // `[emulator] observables` keeps a subset; naming an absent one is an error.
    let only = mdpipe::emulator::table::read_training_table_selected(&out, &[], &["ch_v2".to_string()]).unwrap();
    assert!(
        only.n_outputs() == 10 - p.undefined_bins.iter().filter(|b| b.starts_with("ch_v2[")).count()
            && only.outputs.iter().all(|o| o.observable == "ch_v2")
    );
    let e = mdpipe::emulator::table::read_training_table_selected(&out, &[], &["ch_v4".to_string()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("no values for observable 'ch_v4'"), "{e}");
    assert!(dir.join("table.report.json").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The stand-in's event-by-event runs, read back by ingest in both layouts,
/// reproduce the distribution they were sampled from within the jackknife
/// errors; text and HDF5 agree.
#[test]
fn stand_in_runs_round_trip_through_ingest() {
    use mdpipe::systems::heavy_ion::{events, simulate_runs, DeltaF, HeavyIonParams};
    let dir = std::env::temp_dir().join(format!("mdpipe-standin-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let p = HeavyIonParams::parse("eta_s=0.1,e_sw=0.2").unwrap();
    let n = simulate_runs(&[(3, p)], DeltaF::Grad, 100, events::DEFAULT_OVERSAMPLE, 11, events::Layout::Both, &dir)
        .unwrap();
    assert_eq!(n, 100);
    // A rerun into the same folder is refused rather than mixing its events with these.
    let again = simulate_runs(&[(3, p)], DeltaF::Grad, 10, events::DEFAULT_OVERSAMPLE, 12, events::Layout::Both, &dir)
        .unwrap_err()
        .to_string();
    assert!(again.contains("already exists"), "{again}");
    let settings = IngestSettings::default();
    let (h5, _) =
        ingest::ingest_runs(&dir, None, &IngestSettings { format: ingest::RunFormat::Hdf5, ..settings.clone() })
            .unwrap();
    let (txt, _) =
        ingest::ingest_runs(&dir, None, &IngestSettings { format: ingest::RunFormat::Text, ..settings.clone() })
            .unwrap();
    assert_eq!(h5.report.points[0].good_events, 100);
    let expected = events::SmoothTables::new(&p, DeltaF::Grad).expected(&settings.pt_edges);
    let (a, b) = (by_point(&h5.rows, 3), by_point(&txt.rows, 3));
    assert_eq!(a.len(), 70, "undefined bins: {:?}", h5.report.points[0].undefined_bins);
    let mut pulls = Vec::new();
    for (name, values) in &expected {
        for (k, want) in values.iter().enumerate() {
            let x = 0.1 + 0.2 * k as f64;
            let key = a.keys().find(|(o, xb)| o == name && (f64::from_bits(*xb) - x).abs() < 1e-9).unwrap().clone();
            let (r, t) = (a[&key], b[&key]);
            assert!(
                (r.value - t.value).abs() <= 1e-4 * r.value.abs().max(1e-3),
                "{name}[{x}]: hdf5 {} vs text {}",
                r.value,
                t.value
            );
            let pull = (r.value - want) / r.error;
            assert!(pull.abs() < 4.0, "{name}[{x}]: {} ± {} vs sampled-from {want} (pull {pull:.1})", r.value, r.error);
            pulls.push(pull);
        }
    }
    let rms = (pulls.iter().map(|p| p * p).sum::<f64>() / pulls.len() as f64).sqrt();
    eprintln!("stand-in round trip: rms pull {rms:.3} over {} values", pulls.len());
    assert!((0.7..1.3).contains(&rms), "rms pull {rms}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Goodness of fit of the stand-in's events, through ingest, against their
/// infinite-statistics limit, under the jackknife covariance that ingest
/// writes (between bins and across observables). If that covariance is right,
/// `rᵀ C⁻¹ r` over the 70 rows is Hotelling's T² (C estimated from the same
/// 3000 events): about χ²₇₀ × (n−1)/(n−p). Four seeds, summed, are tested
/// two-sided at the 0.2% level (Wilson–Hilferty quantiles of χ²₂₈₀). The
/// heavy-ion diagnose test's mock data are seed 7.
#[test]
fn stand_in_events_fit_their_smooth_limit_under_the_jackknife_covariance() {
    use mdpipe::systems::heavy_ion::{events, simulate_runs, DeltaF, HeavyIonParams};
    let p = HeavyIonParams::constant(0.1, 0.2);
    let settings = IngestSettings::default();
    let expected = events::SmoothTables::new(&p, DeltaF::Grad).expected(&settings.pt_edges);
    let (n_events, seeds) = (3000usize, [7u64, 8, 9, 10]);
    let mut total = 0.0;
    let mut rows_per_seed = 0;
    for seed in seeds {
        let dir = std::env::temp_dir().join(format!("mdpipe-gof-{}-{seed}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        simulate_runs(&[(0, p)], DeltaF::Grad, n_events, 50, seed, events::Layout::Hdf5, &dir).unwrap();
        let (ingested, _) = ingest::ingest_runs(&dir, None, &settings).unwrap();
        let rows = by_point(&ingested.rows, 0);
        let keys: Vec<_> = rows.keys().cloned().collect();
        let index = |o: &str, x: f64| keys.iter().position(|k| k.0 == o && k.1 == x.to_bits());
        let n = keys.len();
        let mut residual = vec![0.0; n];
        for (name, values) in &expected {
            for (k, want) in values.iter().enumerate() {
                let x = 0.5 * (settings.pt_edges[k] + settings.pt_edges[k + 1]);
                let key = keys.iter().position(|(o, xb)| o == name && (f64::from_bits(*xb) - x).abs() < 1e-9).unwrap();
                residual[key] = rows[&keys[key]].value - want;
            }
        }
        let mut chol = mdpipe::gp::CholeskyWorkspace::new(n);
        for (i, k) in keys.iter().enumerate() {
            chol.factor[i + i * n] = rows[k].error * rows[k].error;
        }
        for e in mdpipe::ingest::single_point_covariance(&ingested).unwrap() {
            let (a, b) = (index(&e.observable_a, e.x_a).unwrap(), index(&e.observable_b, e.x_b).unwrap());
            if a != b {
                chol.factor[a.max(b) + a.min(b) * n] = e.covariance;
            }
        }
        assert_eq!(chol.factorize().unwrap(), 0.0, "seed {seed}: the jackknife covariance needed jitter");
        chol.solve_lower_in_place(&mut residual);
        let chi2: f64 = residual.iter().map(|z| z * z).sum();
        eprintln!("seed {seed}: rᵀC⁻¹r = {chi2:.1} over {n} rows");
        total += chi2;
        rows_per_seed = n;
        std::fs::remove_dir_all(&dir).unwrap();
    }
    let p_rows = rows_per_seed as f64;
    let hotelling = (n_events as f64 - 1.0) / (n_events as f64 - p_rows);
    let k = p_rows * seeds.len() as f64;
    let quantile = |z: f64| k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3) * hotelling;
    let (low, high) = (quantile(-3.09), quantile(3.09));
    eprintln!("sum {total:.1} for {k} rows; two-sided 0.2% acceptance [{low:.1}, {high:.1}]");
    assert!((low..high).contains(&total), "sum {total:.1} outside [{low:.1}, {high:.1}]");
}

/// Training runs carry their errors' correlation between bins (shared
/// events), pooled over the design points, beside the table; the training
/// table reads it, and a copy written elsewhere (an emulator's folder, a
/// refinement round) keeps it.
#[test]
fn a_training_table_carries_its_runs_pooled_error_correlation() {
    use mdpipe::systems::heavy_ion::{events, simulate_runs, DeltaF, HeavyIonParams};
    let dir = std::env::temp_dir().join(format!("mdpipe-noisecorr-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let at: Vec<(i64, HeavyIonParams)> =
        [(1, "eta_s=0.1,e_sw=0.2"), (2, "eta_s=0.2,e_sw=0.3"), (3, "eta_s=0.05,e_sw=0.15")]
            .iter()
            .map(|(id, p)| (*id, HeavyIonParams::parse(p).unwrap()))
            .collect();
    simulate_runs(&at, DeltaF::None, 200, events::DEFAULT_OVERSAMPLE, 5, events::Layout::Hdf5, &dir.join("runs"))
        .unwrap();
    let (got, _) = ingest::ingest_runs(&dir.join("runs"), None, &IngestSettings::default()).unwrap();
    let out = dir.join("training.parquet");
    ingest::write(&got, None, &out).unwrap();
    let side = mdpipe::base::covariance::noise_correlation_path(&out);
    assert!(side.exists(), "{} was not written", side.display());
    let table = mdpipe::emulator::read_training_table(&out, &[]).unwrap();
    let m = table.n_outputs();
    let r = table.noise_correlation.as_ref().expect("the table's noise correlation");
    let at_x =
        |o: &str, x: f64| table.outputs.iter().position(|k| k.observable == o && (k.x - x).abs() < 1e-9).unwrap();
    // A multiplicity fluctuation moves every bin of a spectrum: neighbouring
    // bins' errors are strongly correlated (0.9 in the 6000-event mock).
    let (a, b) = (at_x("ch_spectrum", 0.5), at_x("ch_spectrum", 0.7));
    assert!(r[a * m + b] > 0.5 && r[a * m + b] == r[b * m + a], "ch_spectrum 0.5/0.7: {}", r[a * m + b]);
    assert!((0..m).all(|i| r[i * m + i] == 1.0) && r.iter().all(|v| v.abs() <= 1.0));
    // Written elsewhere and read back, the correlation is the same.
    let copy = dir.join("copy").join("training.parquet");
    std::fs::create_dir_all(copy.parent().unwrap()).unwrap();
    table.write(&copy, None).unwrap();
    let again = mdpipe::emulator::read_training_table(&copy, &[]).unwrap();
    let (r2, r1) = (again.noise_correlation.unwrap(), r);
    assert!(
        r2.iter().zip(r1).all(|(x, y)| (x - y).abs() <= 1e-12 * y.abs().max(1e-300) || x == y),
        "the copy's correlation differs"
    );
    // A table without one, written over the copy, does not inherit its file.
    let plain = mdpipe::emulator::TrainingTable { noise_correlation: None, ..table.clone() };
    plain.write(&copy, None).unwrap();
    assert!(
        !mdpipe::base::covariance::noise_correlation_path(&copy).exists()
            && mdpipe::emulator::read_training_table(&copy, &[]).unwrap().noise_correlation.is_none()
    );
    // A hand-edited file that is not positive definite (ten bins pairwise
    // anti-correlated by 0.9) is shrunk towards the identity until it is.
    let mut text = String::from("observable_a,x_a,observable_b,x_b,correlation\n");
    for a in 0..10 {
        for b in 0..a {
            text.push_str(&format!(
                "ch_spectrum,{},ch_spectrum,{},-0.9\n",
                table.outputs[at_x("ch_spectrum", 0.1 + 0.2 * a as f64)].x,
                table.outputs[at_x("ch_spectrum", 0.1 + 0.2 * b as f64)].x
            ));
        }
    }
    std::fs::write(&side, text).unwrap();
    let shrunk = mdpipe::emulator::read_training_table(&out, &[]).unwrap().noise_correlation.unwrap();
    let mut chol = mdpipe::gp::CholeskyWorkspace::new(m);
    chol.factor.copy_from_slice(&shrunk);
    assert!(chol.factorize_exact(), "the shrunk correlation is not positive definite");
    let (a, b) = (at_x("ch_spectrum", 0.1), at_x("ch_spectrum", 0.3));
    assert!(shrunk[a * m + b] < 0.0 && shrunk[a * m + b] > -0.9, "{}", shrunk[a * m + b]);
    std::fs::remove_dir_all(&dir).unwrap();
}
