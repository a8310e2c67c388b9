//! The heavy-ion and emulator figures of the report: a small emulated
//! 2-parameter calibration (stand-in, smooth), its report in a browser, and
//! PNG copies of every figure.

use mdpipe::calibrate::{self, Overrides, Problem};
use mdpipe::systems::heavy_ion::{analysis_pt, observables, DeltaF, HeavyIonParams};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::PathBuf;

const OBSERVABLES: [&str; 2] = ["ch_spectrum", "ch_v2"];

fn tmpdir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("mdpipe-report-hi-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn heavy_ion_report_has_eta_s_bands_boxes_and_emulator_checks() {
    let dir = tmpdir();
    let pts = analysis_pt();
    // Training runs of the f_eq stand-in over the prior box.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let mut text = String::from("design_id,observable,x,value,eta_s,e_sw\n");
    for i in 0..40 {
        let (eta_s, e_sw) = (0.4 * rng.random::<f64>(), 0.1 + 0.4 * rng.random::<f64>());
        for (name, values) in
            observables(&HeavyIonParams::parse(&format!("eta_s={eta_s},e_sw={e_sw}")).unwrap(), DeltaF::None, &pts)
        {
            if OBSERVABLES.contains(&name) {
                for (x, v) in pts.iter().zip(values) {
                    text.push_str(&format!("{i},{name},{x},{v},{eta_s},{e_sw}\n"));
                }
            }
        }
    }
    std::fs::write(dir.join("runs.csv"), text).unwrap();
    // Mock data: the Grad-δf stand-in at the truth, 3% errors.
    let truth = HeavyIonParams::parse("eta_s=0.1,e_sw=0.2").unwrap();
    let data: Vec<_> = observables(&truth, DeltaF::Grad, &pts)
        .into_iter()
        .filter(|(n, _)| OBSERVABLES.contains(n))
        .flat_map(|(n, v)| {
            pts.iter()
                .zip(v)
                .map(move |(&x, y)| mdpipe::artifacts::Measurement::new(n, x, y, 0.03 * y.abs() + 1e-3))
                .collect::<Vec<_>>()
        })
        .collect();
    mdpipe::artifacts::write_measurements(&dir.join("data.csv"), &data, None).unwrap();
    let config = r#"
name = "hi_report_test"
[model]
kind = "emulator"
artifact = "emu"
[data]
measurements = "data.csv"
observables = ["ch_spectrum", "ch_v2"]
[parameters.eta_s]
min = 0.0
max = 0.4
truth = 0.1
[parameters.e_sw]
min = 0.1
max = 0.5
truth = 0.2
[discrepancy]
kernel = "II"
bounds = { cbar = [0.0, 5.0], ell = [0.0, 10.0], r = [0.0, 3.0], s = [0.0, 5.0] }
[truth]
kind = "heavy_ion"
delta_f = "grad"
[sampler]
adapt = false
[sampler.smc]
particles = 400
replicates = 2
[emulator]
parameters = ["eta_s", "e_sw"]
restarts = 4
log_observables = ["ch_spectrum"]
"#;
    std::fs::write(dir.join("hi.toml"), config).unwrap();
    mdpipe::emulator::train_and_save(&dir.join("hi.toml"), &dir.join("runs.csv"), None, &dir.join("emu"), 1).unwrap();
    mdpipe::emulator::validate::run(&dir.join("emu"), None, 4, 1).unwrap();
    let cfg = mdpipe::systems::load(&dir.join("hi.toml")).unwrap();
    for (kernel, name) in [(mdpipe::base::choices::Kernel::None, "none"), (mdpipe::base::choices::Kernel::II, "II")] {
        let problem = Problem::new(&cfg, &Overrides { kernel: Some(kernel), ..Default::default() }).unwrap();
        let cal = calibrate::run(&problem, 2, &mdpipe::progress::Silent).unwrap();
        calibrate::write_outputs(&dir.join(name), &problem, &cal).unwrap();
    }

    // The true curve (config `[truth]`) is stored with the predictions.
    let pred = mdpipe::artifacts::read_parquet(&dir.join("II/predictions.parquet")).unwrap();
    let truth = pred.column("truth").unwrap().f64().unwrap().clone();
    assert!(truth.iter().all(|t| t.is_some_and(f64::is_finite)), "truth column: {truth:?}");
    let html =
        mdpipe::report::build(std::slice::from_ref(&dir), "heavy-ion test", &mdpipe::app::systems().figures()).unwrap();
    let figures = html.matches("<svg").count();
    // 2 corner plots... one per observable set: corner, η/s(T) + inset, 2 runs × 2 observables of boxes;
    // emulator: one z-score histogram (cv4) and a parity plot per observable.
    assert!(figures >= 2 + 4 + 1 + 2, "{figures} figures");
    for label in [
        "T [GeV]",
        "η/s",
        "ε_sw [GeV/fm³]",
        "pT [GeV]",
        "ch_spectrum / data",
        "emulator parity: ch_v2",
        "emulator z-scores",
        "N(0, 1)",
        "model + δ, 68%",
        "truth",
    ] {
        assert!(html.contains(label), "report lacks {label}");
    }
    let report = dir.join("report.html");
    std::fs::write(&report, &html).unwrap();
    crate::diagnose::check_in_browser(&report, figures);

    // PNG copies: one per figure, each a real PNG of twice its SVG's size.
    let pngs = mdpipe::report::png::write_figures(&html, &dir.join("png")).unwrap();
    assert_eq!(pngs.len(), figures);
    let attr = |tag: &str, name: &str| -> u32 {
        tag.split(&format!("{name}=\"")).nth(1).unwrap().split('"').next().unwrap().parse().unwrap()
    };
    let svg_tags: Vec<&str> = html.split("<svg").skip(1).map(|t| t.split('>').next().unwrap()).collect();
    for (p, tag) in pngs.iter().zip(&svg_tags) {
        let bytes = std::fs::read(p).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{}", p.display());
        let (w, h) = (
            u32::from_be_bytes(bytes[16..20].try_into().unwrap()),
            u32::from_be_bytes(bytes[20..24].try_into().unwrap()),
        );
        assert_eq!((w, h), (2 * attr(tag, "width"), 2 * attr(tag, "height")), "{}", p.display());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
