//! The paper's ball-drop findings on the bundled mock data
//! (`pipeline/ball_drop_data.csv`, made by `mdpipe simulate ball-drop --seed 1`),
//! agreement of the two samplers, and clear errors on bad input.

use mdpipe::calibrate::results::summary::{ParamSummary, Summary};
use mdpipe::calibrate::sampler::diagnostics;
use mdpipe::calibrate::{self, Analysis, Overrides, Problem, SamplerKind};
use mdpipe::compare;
use mdpipe::config::Config;
use mdpipe::gp::DiscrepancyKernel;
use mdpipe::progress::Silent;
use std::path::{Path, PathBuf};

fn config() -> Analysis {
    mdpipe::systems::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("pipeline/ball_drop.toml").as_path()).unwrap()
}

fn tmp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mdpipe-test-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn all_obs() -> Vec<String> {
    ["height", "velocity", "acceleration"].iter().map(|s| s.to_string()).collect()
}

#[test]
fn paper_findings_hold_on_bundled_data() {
    // Two of the config's four replicates, each of its 2000 particles: every
    // finding below is many Monte Carlo errors clear, and R-hat still
    // compares independent replicates (`mdpipe compare` runs all four).
    let mut cfg = config();
    assert_eq!(cfg.sampler.smc.replicates, 4, "the bundled config's replicates moved");
    cfg.sampler.smc.replicates = 2;
    let out = tmp("grid");
    let cases = compare::run_grid(&cfg, &Overrides::default(), 1, &out, &Silent).unwrap();
    assert_eq!(cases.len(), 9);
    let find = |n: usize, k: Option<DiscrepancyKernel>| -> &Summary {
        &cases.iter().find(|c| c.observables.len() == n && c.kernel == k).unwrap().calibration.summary
    };
    for c in &cases {
        let d = &c.calibration.summary.diagnostics;
        let max_rhat = d.parameters.iter().map(|p| p.rhat).fold(0.0, f64::max);
        assert!(max_rhat < 1.05, "{}: R-hat {max_rhat}", c.dir_name);
    }
    // No MD, all observables: narrow and biased.
    let nomd = &find(3, None).parameters["g"];
    let k2 = &find(3, Some(DiscrepancyKernel::KernelII)).parameters;
    assert!(!nomd.covers(9.8), "no-MD g interval [{}, {}] should exclude 9.8", nomd.q025, nomd.q975);
    assert!(nomd.width95() < k2["g"].width95());
    // Kernel II, all observables: covers the truth.
    assert!(k2["g"].covers(9.8), "Kernel II g [{}, {}]", k2["g"].q025, k2["g"].q975);
    assert!(k2["v0"].covers(0.0), "Kernel II v0 [{}, {}]", k2["v0"].q025, k2["v0"].q975);
    // Kernel I is wider than Kernel II wherever the data constrain g: with
    // height alone both intervals span most of the prior (0, 20) and their
    // order is Monte Carlo noise.
    for n in 2..=3 {
        let k1 = &find(n, Some(DiscrepancyKernel::KernelI)).parameters;
        let k2 = &find(n, Some(DiscrepancyKernel::KernelII)).parameters;
        assert!(
            k1["g"].width95() > k2["g"].width95(),
            "set {n}: Kernel I g width {} vs II {}",
            k1["g"].width95(),
            k2["g"].width95()
        );
    }
    let (k1, k2) = (
        &find(1, Some(DiscrepancyKernel::KernelI)).parameters["g"],
        &find(1, Some(DiscrepancyKernel::KernelII)).parameters["g"],
    );
    assert!(k1.width95() > 10.0 && k2.width95() > 10.0, "height alone: widths {} and {}", k1.width95(), k2.width95());
    // The tables exist and name every case.
    let md = std::fs::read_to_string(out.join("compare.md")).unwrap();
    assert_eq!(md.lines().filter(|l| l.starts_with("| height")).count(), 9);
    assert!(out.join("compare.parquet").exists());
}

/// Means and sds of θ from SMC and the ensemble sampler agree within 4×
/// their combined Monte Carlo error.
#[test]
fn smc_and_ensemble_agree_on_ball_drop() {
    let mut cfg = config();
    // Half the config's ensemble (20 000 kept steps after 5 000 of burn-in,
    // not 40 000 after 10 000): the bound is 4 Monte Carlo errors from each
    // run's own ESS, so a shorter chain widens it rather than weakening the
    // check's calibration; the burn-in stays a quarter of the kept steps.
    assert_eq!(
        (cfg.sampler.ensemble.steps, cfg.sampler.ensemble.burn),
        (40_000, 10_000),
        "the config's ensemble moved"
    );
    cfg.sampler.ensemble.steps = 20_000;
    cfg.sampler.ensemble.burn = 5_000;
    for kernel in [mdpipe::base::choices::Kernel::None, mdpipe::base::choices::Kernel::II] {
        let mut runs = Vec::new();
        for sampler in [SamplerKind::Smc, SamplerKind::Ensemble] {
            let ov = Overrides {
                kernel: Some(kernel),
                observables: Some(all_obs()),
                sampler: Some(sampler),
                ..Default::default()
            };
            let problem = Problem::new(&cfg, &ov).unwrap();
            let cal = calibrate::run(&problem, 21, &Silent).unwrap();
            runs.push(cal.chains);
        }
        for p in 0..2 {
            let s: Vec<ParamSummary> = runs.iter().map(|c| ParamSummary::from_draws(&c.param(p))).collect();
            let ess: Vec<f64> = runs.iter().map(|c| diagnostics::ess_bulk(&c.param_chains(p))).collect();
            let mc = (s[0].sd.powi(2) / ess[0] + s[1].sd.powi(2) / ess[1]).sqrt();
            assert!(
                (s[0].mean - s[1].mean).abs() < 4.0 * mc,
                "kernel {:?} param {p}: SMC mean {} vs ensemble {} (MC error {mc:.3e}; ESS {:?})",
                kernel,
                s[0].mean,
                s[1].mean,
                ess
            );
            let sd_err = 4.0 * (1.0 / (2.0 * ess[0]) + 1.0 / (2.0 * ess[1])).sqrt();
            assert!(
                (s[0].sd / s[1].sd - 1.0).abs() < sd_err,
                "kernel {:?} param {p}: sd {} vs {}",
                kernel,
                s[0].sd,
                s[1].sd
            );
        }
    }
}

#[test]
fn calibrate_writes_artifacts_with_provenance() {
    let cfg = config();
    let problem =
        Problem::new(&cfg, &Overrides { kernel: Some(mdpipe::base::choices::Kernel::II), ..Default::default() })
            .unwrap();
    let cal = calibrate::run(&problem, 5, &Silent).unwrap();
    let out = tmp("artifacts");
    calibrate::write_outputs(&out, &problem, &cal).unwrap();
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    for key in ["median", "q025", "q975", "q16", "q84", "mean", "sd"] {
        assert!(summary["parameters"]["g"][key].is_number(), "missing {key}");
        assert!(summary["parameters"]["acceleration.cbar"][key].is_number());
    }
    assert!(summary["log_evidence"].is_number() && summary["log_evidence_err"].is_number());
    assert_eq!(summary["provenance"]["config_hash"].as_str().unwrap(), cfg.config_hash);
    assert_eq!(summary["provenance"]["seed"].as_u64().unwrap(), 5);
    let post = mdpipe::artifacts::read_parquet(&out.join("posterior.parquet")).unwrap();
    assert!(post.column("height.ell").is_ok() && post.column("v0").is_ok());
    assert_eq!(post.height(), cal.chains.n_draws());
    let pred = mdpipe::artifacts::read_parquet(&out.join("predictions.parquet")).unwrap();
    let x = pred.column("x").unwrap().f64().unwrap().clone();
    // The grid extends beyond the data (extrapolation to 2 s).
    assert!(x.iter().flatten().fold(f64::NEG_INFINITY, f64::max) >= 2.0 - 1e-12);
    // No stray temporary files from the atomic writes.
    assert!(std::fs::read_dir(&out).unwrap().all(|e| !e.unwrap().file_name().to_string_lossy().starts_with('.')));
    // The model+δ band at the data should contain most measurements.
    let rows: Vec<_> = cal.predictions.iter().filter(|r| r.kind == "data").collect();
    let inside = rows
        .iter()
        .filter(|r| {
            let m = problem.measurements.iter().find(|m| m.observable == r.observable && m.x == r.x).unwrap();
            (m.value - r.model_md[2]).abs() < 3.0 * m.error + (r.model_md[4] - r.model_md[0])
        })
        .count();
    assert!(inside as f64 >= 0.9 * rows.len() as f64, "{inside}/{}", rows.len());
}

fn err_of(data: &str) -> String {
    let d = tmp("bad");
    let p = d.join("bad.csv");
    std::fs::write(&p, data).unwrap();
    let ov = Overrides { data: Some(p), ..Default::default() };
    match Problem::new(&config(), &ov) {
        Ok(_) => panic!("bad input was accepted: {data}"),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn bad_input_names_file_line_and_field() {
    let head = "observable,x,value,error\n";
    let msg = err_of("observable,x,value\nheight,0,60,0.1\n");
    assert!(msg.contains("bad.csv") && msg.contains("missing column 'error'"), "{msg}");
    let msg = err_of(&format!("{head}height,0,60,0.1\nheight,0.1,nan,0.1\n"));
    assert!(msg.contains("line 3") && msg.contains("'value'"), "{msg}");
    let msg = err_of(&format!("{head}height,0,60,0.1\nheight,0.1,59,-0.1\n"));
    assert!(msg.contains("line 3") && msg.contains("'error'"), "{msg}");
    let msg = err_of(&format!("{head}height,0,60,0.1\nheight,0.1,59,0.1\nspeed,0.1,1,0.1\n"));
    assert!(msg.contains("line 4") && msg.contains("'observable'") && msg.contains("speed"), "{msg}");

    let cfg_text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("pipeline/ball_drop.toml")).unwrap();
    let d = tmp("badcfg");
    let p = d.join("cfg.toml");
    std::fs::write(&p, cfg_text.replace("min = 0.0\nmax = 20.0", "min = 20.0\nmax = 20.0")).unwrap();
    let msg = format!("{:#}", Config::load(&p).unwrap_err());
    assert!(msg.contains("cfg.toml") && msg.contains("parameters.g") && msg.contains("min < max"), "{msg}");
}

/// The replicate grid: its counts are exactly those of the per-replicate
/// tables, and the finding that holds in every draw of a 20-draw study (no MD
/// with all observables misses g = 9.8) holds here too.
#[test]
fn replicate_grid_tabulates_coverage_over_mock_data_sets() {
    let mut cfg = config();
    // The tabulation is checked against the replicate tables, whatever the
    // fits' precision: two SMC replicates of 500 particles are enough for the
    // one finding asserted (no MD misses g = 9.8 by some 20 sd).
    cfg.sampler.smc.particles = 500;
    cfg.sampler.smc.replicates = 2;
    cfg.sampler.adapt = false;
    let out = tmp("replicates");
    // Two data sets are enough to check the tabulation against the per-replicate tables.
    let n = 2;
    let rows = compare::run_replicates(&cfg, &Overrides::default(), n, 11, &out).unwrap();
    assert_eq!(rows.len(), 3 * 3 * 2, "3 observable sets x 3 kernels x (g, v0)");
    for r in &rows {
        assert_eq!(r.replicates, n);
        // Recount from the replicate folders' compare.parquet.
        let mut covered = 0;
        for k in 0..n {
            let df = mdpipe::artifacts::read_parquet(&out.join(format!("replicate_{k:03}/compare.parquet"))).unwrap();
            let col_s = |c: &str| {
                df.column(c).unwrap().str().unwrap().iter().map(|v| v.unwrap().to_string()).collect::<Vec<_>>()
            };
            let col_f = |c: &str| df.column(c).unwrap().f64().unwrap().iter().map(|v| v.unwrap()).collect::<Vec<_>>();
            let (obs, ker, par, lo, hi, truth) = (
                col_s("observables"),
                col_s("kernel"),
                col_s("parameter"),
                col_f("q025"),
                col_f("q975"),
                col_f("truth"),
            );
            let i = (0..obs.len())
                .find(|&i| obs[i] == r.observables && ker[i] == r.kernel && par[i] == r.parameter)
                .unwrap();
            covered += (lo[i] <= truth[i] && truth[i] <= hi[i]) as usize;
        }
        assert_eq!(r.covered, covered, "{} {} {}", r.observables, r.kernel, r.parameter);
        assert_eq!(r.wider_than_kernel2.is_some(), r.kernel == "I");
    }
    let nomd_all = rows
        .iter()
        .find(|r| r.observables == "height+velocity+acceleration" && r.kernel == "none" && r.parameter == "g")
        .unwrap();
    assert_eq!(nomd_all.covered, 0);
    assert!(out.join("replicates.md").exists() && out.join("replicates.parquet").exists());
}
