//! `mdpipe demo`: the bundled ball-drop story on a fresh machine.

use crate::base::artifacts::{self, Provenance};
use crate::base::progress::Bars;
use crate::engine::calibrate::Overrides;
use crate::engine::compare;
use crate::engine::gp::DiscrepancyKernel;
use crate::systems;
use anyhow::Result;
use rand::SeedableRng;
use std::path::{Path, PathBuf};

/// The bundled config, found from the working directory or the crate folder.
pub fn bundled_config(name: &str) -> PathBuf {
    let local = Path::new("pipeline").join(name);
    if local.exists() {
        local
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("pipeline").join(name)
    }
}

/// The demo's sampling: a quarter of the config's particles, unless `--full`.
/// Its verdict and intervals agree with the full settings' within Monte
/// Carlo error (docs/performance.md has both runs).
const DEMO_PARTICLES: usize = 1000;
const DEMO_REPLICATES: usize = 2;

pub fn run(seed: u64, full: bool, out: &Path) -> Result<()> {
    let mut analysis = systems::load(&bundled_config("ball_drop.toml"))?;
    let (full_particles, full_replicates) = (analysis.sampler.smc.particles, analysis.sampler.smc.replicates);
    if !full {
        analysis.sampler.smc.particles = DEMO_PARTICLES.min(full_particles);
        analysis.sampler.smc.replicates = DEMO_REPLICATES.min(full_replicates);
        println!(
            "Sampling: {} replicates x {} particles per calibration, a quarter of the config's {full_replicates} x {full_particles}, for speed;\non the default seed the verdict and intervals agree with the full run's (mdpipe demo --full) within Monte Carlo error.\n",
            analysis.sampler.smc.replicates, analysis.sampler.smc.particles
        );
    }
    std::fs::create_dir_all(out)?;

    println!("1. Simulating a ball dropped from 60 m with concealed quadratic drag (k = 0.4 /m) ...");
    // The config's [truth] (its declared model with quadratic drag on) at the
    // bundled data's times and errors, with fresh noise.
    let template = artifacts::read_measurements(&analysis.data)?;
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
    let data = compare::mock_measurements(&analysis, &template, &mut rng)?;
    let data_path = out.join("data.csv");
    let prov = Provenance::new(
        analysis.config_hash.clone(),
        artifacts::measurements_hash(&data),
        seed,
        "demo: simulate ball-drop k=0.4",
    );
    artifacts::write_measurements(&data_path, &data, Some(&prov))?;
    println!("   {} measurements of height, velocity, acceleration -> {}", data.len(), data_path.display());

    println!("2. Calibrating the drag-free model: 3 observable sets x {{no MD, Kernel I, Kernel II}} ...");
    // The demo's data follow the config's `[truth]` recipe, so they replace its
    // measurements file (a --data override would drop the true curve).
    let analysis = analysis.with_data(&std::fs::canonicalize(&data_path)?);
    let overrides = Overrides::default();
    let grid_dir = out.join("compare");
    let cases = compare::run_grid(&analysis, &overrides, seed, &grid_dir, &Bars::default())?;
    println!();
    println!("{}", std::fs::read_to_string(grid_dir.join("compare.md"))?);

    let all = |k| cases.iter().find(|c| c.observables.len() == 3 && c.kernel == k).map(|c| &c.calibration.summary);
    if let (Some(nomd), Some(k2)) = (all(None), all(Some(DiscrepancyKernel::KernelII))) {
        let (a, b) = (&nomd.parameters["g"], &k2.parameters["g"]);
        println!("Result (all observables, truth g = 9.8 m/s^2):");
        println!(
            "  without MD  g = {:.2} [{:.2}, {:.2}]  chi2/dof {:.1}  -> {}",
            a.median,
            a.q025,
            a.q975,
            nomd.fit.chi2_per_dof,
            if a.covers(9.8) { "covers the truth" } else { "narrow and biased: misses the truth" }
        );
        println!(
            "  Kernel II   g = {:.2} [{:.2}, {:.2}]  -> {}",
            b.median,
            b.q025,
            b.q975,
            if b.covers(9.8) { "covers the truth" } else { "misses the truth" }
        );
        if let (Some(z0), Some(z2)) = (nomd.log_evidence, k2.log_evidence) {
            println!("  log Bayes factor, Kernel II vs no MD: {:.1}", z2 - z0);
        }
    }

    println!("\n3. Diagnosing: locate the mismatch, try the candidate physics, repair ...");
    let diag_dir = out.join("diagnose");
    let settings = crate::engine::diagnose::DiagnoseSettings::default();
    let run = crate::engine::diagnose::run(&analysis, &overrides, seed, &settings, Some(&diag_dir), &Bars::default())?;
    crate::engine::diagnose::print(&run.diagnosis);

    println!("\n4. Writing the report ...");
    let report = out.join("report.html");
    crate::engine::report::write(
        &[diag_dir.clone(), grid_dir.clone()],
        &report,
        "mdpipe demo: a ball drop with concealed drag",
        &super::systems().figures(),
    )?;
    println!("\nVerdict: {}", run.diagnosis.verdict.statement);
    println!("Artifacts: {}/ and {}/", grid_dir.display(), diag_dir.display());
    println!("Report: {}", report.display());
    Ok(())
}
