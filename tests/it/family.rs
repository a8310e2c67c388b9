//! A model family defined here, outside the crate, plugs into the engine
//! with one registration line: the whole path (calibrate, compare, diagnose
//! and the report) works on it, and the engine never names it.

use mdpipe::calibrate::{self, Analysis, Overrides, Problem};
use mdpipe::config::{Config, ParamSpec};
use mdpipe::diagnose::{self, DiagnoseSettings};
use mdpipe::model::{CandidateModel, ModelFamily, ModelSetup, PlainSetup, Simulator, Units};
use mdpipe::progress::Silent;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::path::PathBuf;
use std::sync::Arc;

/// A straight line y = a + b x, with one candidate correction, a curvature
/// c x², and a `[truth]` table giving the curvature of the true process.
struct LineFamily;

/// y = a + b x + c x²; `curvature = None` makes c a parameter.
struct Line {
    curvature: Option<f64>,
}

impl Simulator for Line {
    fn parameter_names(&self) -> Vec<String> {
        let mut names = vec!["a".to_string(), "b".to_string()];
        if self.curvature.is_none() {
            names.push("c".into());
        }
        names
    }
    fn observable_names(&self) -> Vec<String> {
        vec!["y".into()]
    }
    fn predict(&self, _observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let c = self.curvature.unwrap_or_else(|| theta[2]);
        for (o, &xi) in out.iter_mut().zip(x) {
            *o = theta[0] + theta[1] * xi + c * xi * xi;
        }
    }
}

impl ModelFamily for LineFamily {
    fn kind(&self) -> &'static str {
        "line"
    }
    fn open(&self, _config: &Config) -> anyhow::Result<Arc<dyn ModelSetup>> {
        let curvature = CandidateModel {
            name: "curvature".into(),
            description: "a quadratic term c x²".into(),
            extra_parameters: vec![(
                "c".into(),
                ParamSpec { min: -2.0, max: 2.0, truth: Some(CURVATURE), units: "V/m²".into() },
            )],
            simulator: Arc::new(Line { curvature: None }),
            special_case_of: Vec::new(),
            own_emulator: false,
        };
        Ok(Arc::new(PlainSetup {
            simulator: Arc::new(Line { curvature: Some(0.0) }),
            units: line_units(),
            candidates: vec![curvature],
        }))
    }
    fn open_truth(&self, _config: &Config, truth: &toml::Table) -> anyhow::Result<Arc<dyn ModelSetup>> {
        let curvature = truth["curvature"].as_float().unwrap_or(0.0);
        Ok(PlainSetup::shared(Arc::new(Line { curvature: Some(curvature) }), line_units()))
    }
}

fn line_units() -> Units {
    Units { x: "m".into(), observables: [("y".to_string(), "V".to_string())].into(), parameters: Default::default() }
}

const CURVATURE: f64 = 0.5;

/// A config of kind "line" and mock data from the true process (a = 1, b = 2,
/// c = 0.5) at 15 points over [0, 2] with σ = 0.05.
fn setup(tag: &str) -> (PathBuf, Analysis) {
    let dir = std::env::temp_dir().join(format!("mdpipe-family-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
    let mut csv = String::from("observable,x,value,error\n");
    for i in 0..15 {
        let x = 2.0 * i as f64 / 14.0;
        let y = 1.0 + 2.0 * x + CURVATURE * x * x + Normal::new(0.0, 0.05).unwrap().sample(&mut rng);
        csv.push_str(&format!("y,{x},{y},0.05\n"));
    }
    std::fs::write(dir.join("data.csv"), csv).unwrap();
    let config = r#"
name = "line"
[model]
kind = "line"
[data]
measurements = "data.csv"
[parameters.a]
min = -5.0
max = 5.0
truth = 1.0
[parameters.b]
min = -5.0
max = 5.0
truth = 2.0
[sampler]
adapt = false
[sampler.smc]
particles = 600
replicates = 2
[truth]
kind = "line"
curvature = 0.5
"#;
    std::fs::write(dir.join("line.toml"), config).unwrap();
    let mut registry = mdpipe::systems::registry();
    registry.register(Arc::new(LineFamily)); // the one registration line
    let analysis = Analysis::resolve(&Config::load(&dir.join("line.toml")).unwrap(), &registry).unwrap();
    (dir, analysis)
}

#[test]
fn a_family_defined_outside_the_crate_runs_the_whole_pipeline() {
    let (dir, analysis) = setup("pipeline");
    // Calibrate: the truth curve and the family's units reach the artifacts.
    let problem =
        Problem::new(&analysis, &Overrides { kernel: Some(mdpipe::base::choices::Kernel::None), ..Default::default() })
            .unwrap();
    let cal = calibrate::run(&problem, 1, &Silent).unwrap();
    calibrate::write_outputs(&dir.join("calibrate"), &problem, &cal).unwrap();
    assert_eq!(cal.summary.units.x, "m");
    assert!(cal.predictions.iter().all(|r| r.truth.is_finite()), "the [truth] process gives the true curve everywhere");
    // A straight line through a parabola is a confident, wrong fit: the
    // noise-free χ² of the best line is 172 on 13 dof, so with noise χ²/dof is
    // 14.2 ± 2.1, and 5 lies 4.4 sd below it.
    assert!(cal.summary.fit.chi2_per_dof > 5.0, "χ²/dof = {}", cal.summary.fit.chi2_per_dof);

    // Compare runs its grid (one observable: one set × three kernels).
    let cases = mdpipe::compare::run_grid(&analysis, &Overrides::default(), 1, &dir.join("compare"), &Silent).unwrap();
    assert_eq!(cases.len(), 3);

    // Diagnose names the family's own candidate and recovers its parameter.
    let run = diagnose::run(
        &analysis,
        &Overrides::default(),
        1,
        &DiagnoseSettings::default(),
        Some(&dir.join("diagnose")),
        &Silent,
    )
    .unwrap();
    let d = &run.diagnosis;
    assert_eq!(d.verdict.best, "curvature", "{}", d.verdict.statement);
    let c = &d.candidates[0].parameters["c"];
    // Within 4 posterior sd of the truth: a calibrated posterior misses this once in 16 000.
    assert!((c.median - CURVATURE).abs() < 4.0 * c.sd, "c = {} ± {}", c.median, c.sd);

    // The report draws it with the family's units, knowing nothing of the family.
    let html = mdpipe::report::build(&[dir.join("diagnose")], "line", &mdpipe::app::systems().figures()).unwrap();
    assert!(html.contains("x [m]") && html.contains("y [V]"), "units missing from the report");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_unregistered_kind_is_refused_naming_the_file_and_the_known_kinds() {
    let (dir, _) = setup("unknown");
    let msg =
        format!("{:#}", mdpipe::systems::load(&dir.join("line.toml")).err().expect("an unknown kind was accepted"));
    assert!(msg.contains("line.toml") && msg.contains("[model] kind = \"line\"") && msg.contains("ode"), "{msg}");
    let _ = std::fs::remove_dir_all(&dir);
}
