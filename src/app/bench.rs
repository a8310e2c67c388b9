//! `mdpipe bench`: throughput of the likelihood and of the full comparison grid.
//! Benchmarks, not tests: numbers vary with the machine, so they are printed,
//! never asserted.

use crate::base::progress::Silent;
use crate::engine::calibrate::{Analysis, Overrides, Problem};
use crate::engine::compare;
use crate::engine::diagnose::Discover;
use crate::engine::gp::DiscrepancyKernel;
use anyhow::Result;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Debug, serde::Serialize)]
pub struct LikelihoodBench {
    pub kernel: String,
    pub dim: usize,
    pub n_points: usize,
    pub evaluations: usize,
    pub seconds: f64,
    pub evaluations_per_second_one_core: f64,
}

/// Single-threaded evaluations per second at prior draws (all observables).
pub fn likelihood_throughput(
    analysis: &Analysis,
    kernel: Option<DiscrepancyKernel>,
    evaluations: usize,
) -> Result<LikelihoodBench> {
    let problem =
        Problem::new(analysis, &Overrides { kernel: Some(DiscrepancyKernel::choice(kernel)), ..Default::default() })?;
    let dim = problem.prior.dim();
    let points = problem.prior.draws(&mut Xoshiro256PlusPlus::seed_from_u64(7), 1024);
    let mut sink = 0.0;
    for p in points.iter().take(100) {
        sink += problem.likelihood.log_likelihood(p);
    }
    let start = Instant::now();
    for i in 0..evaluations {
        sink += problem.likelihood.log_likelihood(&points[i % points.len()]);
    }
    let seconds = start.elapsed().as_secs_f64();
    std::hint::black_box(sink);
    Ok(LikelihoodBench {
        kernel: DiscrepancyKernel::label(kernel).into(),
        dim,
        n_points: problem.likelihood.blocks.iter().map(|b| b.len()).sum(),
        evaluations,
        seconds,
        evaluations_per_second_one_core: evaluations as f64 / seconds,
    })
}

#[derive(Debug, serde::Serialize)]
pub struct GridBench {
    pub case: String,
    pub sampler: String,
    pub seconds: f64,
    pub min_ess: f64,
    pub min_ess_per_second: f64,
    pub converged: bool,
}

/// Times the full 9-case comparison grid.
pub fn compare_grid(
    analysis: &Analysis,
    overrides: &Overrides,
    seed: u64,
    out: &Path,
) -> Result<(f64, Vec<GridBench>)> {
    let start = Instant::now();
    let cases = compare::run_grid(analysis, overrides, seed, out, &Silent)?;
    let total = start.elapsed().as_secs_f64();
    let rows = cases
        .iter()
        .map(|c| {
            let d = &c.calibration.summary.diagnostics;
            let min_ess = d.parameters.iter().map(|p| p.ess_bulk.min(p.ess_tail)).fold(f64::INFINITY, f64::min);
            GridBench {
                case: c.dir_name.clone(),
                sampler: c.calibration.summary.sampler.clone(),
                seconds: d.wall_seconds,
                min_ess,
                min_ess_per_second: d.min_ess_per_second,
                converged: d.converged,
            }
        })
        .collect();
    Ok((total, rows))
}

#[derive(Debug, serde::Serialize)]
pub struct EmulatorBench {
    pub n_points: usize,
    pub n_components: usize,
    pub n_outputs: usize,
    /// Marginal likelihood with gradient, component 0 at its optimum, one core.
    pub marginal_likelihood_evals_per_second: f64,
    /// One component's mean and variance, one core.
    pub component_predictions_per_second_one_core: f64,
    /// Every component's mean and variance (one θ), all cores.
    pub emulator_predictions_per_second: f64,
    /// Every component's mean and variance, batches of 256 θ, all cores.
    pub batched_predictions_per_second: f64,
    /// Mean plus full observable-space covariance, all cores.
    pub full_covariance_predictions_per_second: f64,
}

/// Training and prediction throughput of a stored emulator.
pub fn emulator_throughput(dir: &Path, predictions: usize) -> Result<EmulatorBench> {
    use rand::Rng;
    use rayon::prelude::*;
    let emu = crate::engine::emulator::store::load(dir)?;
    let table = emu.training_table();
    let (n, d, k) = (table.n_points(), emu.n_parameters(), emu.n_components());
    let lo = &emu.parts.input_lo;
    let hi = &emu.parts.input_hi;
    let unit: Vec<f64> = (0..n * d).map(|i| (table.inputs[i] - lo[i % d]) / (hi[i % d] - lo[i % d])).collect();
    let scores = &emu.parts.scores[..n];
    let hyper = &emu.parts.hypers[0];
    let mut grad = vec![0.0; hyper.log_params.len()];
    let reps = (2e8 / (n as f64).powi(3)).clamp(10.0, 2000.0) as usize;
    let start = Instant::now();
    for _ in 0..reps {
        std::hint::black_box(
            crate::engine::gp::ard_log_marginal_likelihood(emu.parts.kernel, hyper, &unit, scores, Some(&mut grad))
                .ok(),
        );
    }
    let lml_rate = reps as f64 / start.elapsed().as_secs_f64();

    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let thetas: Vec<Vec<f64>> =
        (0..1024).map(|_| (0..d).map(|p| lo[p] + rng.random::<f64>() * (hi[p] - lo[p])).collect()).collect();
    let mut scratch = emu.scratch();
    let (mut m, mut v) = (vec![0.0; k], vec![0.0; k]);
    let start = Instant::now();
    for i in 0..predictions {
        emu.predict_components(&thetas[i % thetas.len()], &mut m, &mut v, &mut scratch);
        std::hint::black_box(&m);
    }
    let one_core = predictions as f64 * k as f64 / start.elapsed().as_secs_f64();

    let start = Instant::now();
    (0..predictions).into_par_iter().for_each_init(
        || (emu.scratch(), vec![0.0; k], vec![0.0; k]),
        |(s, m, v), i| {
            emu.predict_components(&thetas[i % thetas.len()], m, v, s);
            std::hint::black_box(&m);
        },
    );
    let all_cores = predictions as f64 / start.elapsed().as_secs_f64();

    let flat: Vec<f64> = thetas.iter().flatten().copied().collect();
    let batch = 256;
    let batches = (predictions / batch).max(4);
    let start = Instant::now();
    (0..batches).into_par_iter().for_each(|i| {
        let off = (i * batch) % (thetas.len() - batch + 1);
        let (mut m, mut v) = (vec![0.0; batch * k], vec![0.0; batch * k]);
        emu.predict_components_batch(&flat[off * d..(off + batch) * d], &mut m, &mut v);
        std::hint::black_box(&m);
    });
    let batched = (batches * batch) as f64 / start.elapsed().as_secs_f64();

    let full = (predictions / 20).max(100);
    let start = Instant::now();
    (0..full).into_par_iter().for_each(|i| {
        std::hint::black_box(emu.predict(&thetas[i % thetas.len()]));
    });
    let full_rate = full as f64 / start.elapsed().as_secs_f64();
    Ok(EmulatorBench {
        n_points: n,
        n_components: k,
        n_outputs: emu.n_outputs(),
        marginal_likelihood_evals_per_second: lml_rate,
        component_predictions_per_second_one_core: one_core,
        emulator_predictions_per_second: all_cores,
        batched_predictions_per_second: batched,
        full_covariance_predictions_per_second: full_rate,
    })
}

/// Wall times of one heavy-ion stand-in design point, stage by stage.
#[derive(Clone, Debug, serde::Serialize)]
pub struct HeavyIonBench {
    pub events: usize,
    pub oversample: usize,
    pub particles: usize,
    pub smooth_tables_s: f64,
    pub sampling_s: f64,
    pub write_hdf5_s: f64,
    pub write_text_s: f64,
    pub ingest_s: f64,
}

/// Times one design point of `events` events at η/s = 0.1, ε_sw = 0.2 (Grad δf):
/// the smooth Cooper–Frye tables, event sampling, writing each layout, and ingest.
pub fn heavy_ion_point(events: usize, oversample: usize, dir: &Path) -> Result<HeavyIonBench> {
    use crate::systems::heavy_ion::{self, events as ev};
    let p = heavy_ion::HeavyIonParams::parse("eta_s=0.1,e_sw=0.2")?;
    let t = Instant::now();
    let tables = ev::SmoothTables::new(&p, heavy_ion::DeltaF::Grad);
    let smooth_tables_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let sampled = ev::sample_events(&tables, events, oversample, 1);
    let sampling_s = t.elapsed().as_secs_f64();
    let particles: f64 = sampled
        .iter()
        .flat_map(|e| e.files.iter().filter(|f| f.name.contains("_diff_")))
        .map(|f| (0..f.rows()).map(|r| f.row(r)[f.columns - 1]).sum::<f64>())
        .sum();
    let _ = std::fs::remove_dir_all(dir);
    let (h5_dir, text_dir) = (dir.join("hdf5/0000"), dir.join("text/0000"));
    let t = Instant::now();
    ev::write_point(&h5_dir, &sampled, ev::Layout::Hdf5)?;
    let write_hdf5_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    ev::write_point(&text_dir, &sampled, ev::Layout::Text)?;
    let write_text_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    crate::engine::ingest::ingest_runs(&dir.join("hdf5"), None, &crate::engine::ingest::IngestSettings::default())?;
    let ingest_s = t.elapsed().as_secs_f64();
    Ok(HeavyIonBench {
        events,
        oversample,
        particles: particles as usize,
        smooth_tables_s,
        sampling_s,
        write_hdf5_s,
        write_text_s,
        ingest_s,
    })
}

#[derive(Debug, serde::Serialize)]
pub struct DiagnoseBench {
    pub seconds: f64,
    pub calibrations: usize,
    pub verdict: String,
}

/// Wall time of one full `diagnose` (base ± MD, every candidate, the repair,
/// and the search for undeclared terms when `discover` asks) with the
/// config's settings, writing nothing.
pub fn diagnose_time(analysis: &Analysis, seed: u64, discover: Discover) -> Result<DiagnoseBench> {
    let settings = crate::engine::diagnose::DiagnoseSettings { discover, ..Default::default() };
    let start = Instant::now();
    let run = crate::engine::diagnose::run(analysis, &Overrides::default(), seed, &settings, None, &Silent)?;
    Ok(DiagnoseBench {
        seconds: start.elapsed().as_secs_f64(),
        calibrations: 2 + run.candidates.len() + usize::from(run.repaired_md.is_some()),
        verdict: run.diagnosis.verdict.best,
    })
}

/// The arguments of `mdpipe bench` (see `cli::Command::Bench`).
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[arg(default_value = "pipeline/ball_drop.toml")]
    pub config: PathBuf,
    /// Likelihood evaluations per kernel
    #[arg(long, default_value_t = 2_000_000)]
    pub evaluations: usize,
    /// Skip the comparison grid
    #[arg(long)]
    pub likelihood_only: bool,
    #[arg(long)]
    pub sampler: Option<crate::engine::calibrate::SamplerKind>,
    #[arg(long, default_value = "outputs/bench")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Benchmark this emulator folder (training and prediction throughput) instead
    #[arg(long)]
    pub emulator: Option<PathBuf>,
    /// Benchmark one heavy-ion stand-in design point of this many events instead
    #[arg(long)]
    pub heavy_ion_events: Option<usize>,
    /// Time one full `diagnose` of the config's data instead
    #[arg(long)]
    pub diagnose: bool,
    /// How the likelihood's cost grows with the data instead: a synthetic
    /// analysis of 100 to 3 000 points with correlated systematics, setup
    /// and evaluations per second, structured and dense (writes under --out)
    #[arg(long)]
    pub scaling: bool,
    /// With --scaling: write the covariance files to this many significant
    /// digits, as users and HEPData write them (default: every digit of the double)
    #[arg(long, requires = "scaling", value_parser = clap::value_parser!(u8).range(1..=17))]
    pub digits: Option<u8>,
    /// Likelihood rates of the bundled declared models instead: the ball
    /// drop, the kinetics and the oscillator (run from the checkout)
    #[arg(long)]
    pub declared: bool,
}

/// The bundled declared models `--declared` measures.
const DECLARED: [(&str, &str); 3] = [
    ("ball drop", "pipeline/ball_drop.toml"),
    ("kinetics", "pipeline/examples/kinetics.toml"),
    ("oscillator", "pipeline/examples/oscillator.toml"),
];

/// `mdpipe bench`: one of the benchmarks, printed.
pub fn command(a: BenchArgs) -> Result<()> {
    let threads = rayon::current_num_threads();
    if let Some(events) = a.heavy_ion_events {
        let b =
            heavy_ion_point(events, crate::systems::heavy_ion::events::DEFAULT_OVERSAMPLE, &a.out.join("heavy_ion"))?;
        println!("heavy-ion stand-in, one design point: {} events x {} samples, {} particles in the files ({threads} threads)", b.events, b.oversample, b.particles);
        println!("  smooth Cooper-Frye tables {:>7.3} s", b.smooth_tables_s);
        println!("  event sampling            {:>7.3} s", b.sampling_s);
        println!("  write HDF5                {:>7.3} s", b.write_hdf5_s);
        println!("  write text files          {:>7.3} s", b.write_text_s);
        println!("  ingest (HDF5)             {:>7.3} s", b.ingest_s);
        println!("  simulate, HDF5 layout     {:>7.3} s total", b.smooth_tables_s + b.sampling_s + b.write_hdf5_s);
        return Ok(());
    }
    if let Some(dir) = &a.emulator {
        let b = emulator_throughput(dir, 200_000)?;
        println!("emulator: {} design points, {} components, {} outputs", b.n_points, b.n_components, b.n_outputs);
        println!(
            "  marginal likelihood + gradient: {:>10.0} evaluations/s (one core)",
            b.marginal_likelihood_evals_per_second
        );
        println!(
            "  one component, mean + variance: {:>10.0} predictions/s (one core)",
            b.component_predictions_per_second_one_core
        );
        println!(
            "  all components, mean + variance: {:>9.0} predictions/s ({threads} threads)",
            b.emulator_predictions_per_second
        );
        println!(
            "  all components, batches of 256: {:>9.0} predictions/s ({threads} threads)",
            b.batched_predictions_per_second
        );
        println!(
            "  mean + full {}x{} covariance:  {:>10.0} predictions/s ({threads} threads)",
            b.n_outputs, b.n_outputs, b.full_covariance_predictions_per_second
        );
        return Ok(());
    }
    if a.scaling {
        return super::bench_scaling::print(&a.out.join("scaling"), 2.0, a.digits.map(usize::from));
    }
    if a.declared {
        for (name, config) in DECLARED {
            let analysis = crate::systems::load(Path::new(config))?;
            for kernel in compare::KERNELS {
                let b = likelihood_throughput(&analysis, kernel, a.evaluations)?;
                println!(
                    "{name:<10} ({config}) kernel={:<4} points={}: {:>10.0} evaluations/s on one core",
                    b.kernel, b.n_points, b.evaluations_per_second_one_core
                );
            }
        }
        return Ok(());
    }
    let analysis = crate::systems::load(&a.config)?;
    if a.diagnose {
        // Without the search, then with it forced on: what discovery costs.
        let plain = diagnose_time(&analysis, a.seed, Discover::Never)?;
        let found = diagnose_time(&analysis, a.seed, Discover::Always)?;
        for (what, b) in [("without discovery", &plain), ("with --discover", &found)] {
            println!(
                "diagnose {} {what}: {} calibrations in {:.1} s on {threads} threads; verdict {}",
                a.config.display(),
                b.calibrations,
                b.seconds,
                b.verdict
            );
        }
        println!(
            "  discovery adds {:.1} s, {:.0}% of the diagnosis without it",
            found.seconds - plain.seconds,
            100.0 * (found.seconds - plain.seconds) / plain.seconds
        );
        return Ok(());
    }
    for kernel in compare::KERNELS {
        let b = likelihood_throughput(&analysis, kernel, a.evaluations)?;
        println!(
            "likelihood kernel={:<4} dim={:>2} points={}: {:>10.0} evaluations/s on one core ({:.1} ns each)",
            b.kernel,
            b.dim,
            b.n_points,
            b.evaluations_per_second_one_core,
            1e9 / b.evaluations_per_second_one_core
        );
    }
    if !a.likelihood_only {
        let overrides = super::commands::parse_overrides(None, None, None, a.sampler)?;
        let (total, rows) = compare_grid(&analysis, &overrides, a.seed, &a.out)?;
        for r in &rows {
            println!(
                "{:<40} {:<8} {:>6.2} s  min ESS {:>6.0}  min ESS/s {:>8.0}  {}",
                r.case,
                r.sampler,
                r.seconds,
                r.min_ess,
                r.min_ess_per_second,
                if r.converged { "converged" } else { "NOT CONVERGED" }
            );
        }
        println!("full 9-case grid: {total:.2} s on {threads} threads");
    }
    Ok(())
}
