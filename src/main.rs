//! Command-line entry point: argument parsing only; the work is in the library.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use mdpipe::artifacts;
use mdpipe::calibrate::{self, compare, Overrides, Problem};
use mdpipe::config::{Config, SamplerKind};
use mdpipe::gp::DiscrepancyKernel;
use mdpipe::models::ball_drop;
use rand::SeedableRng;
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "mdpipe", version, about = "Locate, explain and model simulator-data mismatch with Bayesian model discrepancy")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args, Clone)]
struct CalibrationArgs {
    /// Analysis config (TOML), e.g. pipeline/ball_drop.toml
    config: PathBuf,
    /// Measurements file (CSV or Parquet: observable,x,value,error); replaces the config's
    #[arg(long)]
    data: Option<PathBuf>,
    /// Random seed
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output directory
    #[arg(long)]
    out: PathBuf,
}

#[derive(Subcommand)]
enum Command {
    /// Calibrate a model against measurements, with or without model discrepancy
    Calibrate {
        #[command(flatten)]
        args: CalibrationArgs,
        /// Discrepancy kernel: none, I or II (default: the config's)
        #[arg(long)]
        kernel: Option<String>,
        /// Comma-separated observables to use (default: the config's)
        #[arg(long, value_delimiter = ',')]
        observables: Option<Vec<String>>,
        /// Sampler: smc or ensemble (default: the config's)
        #[arg(long)]
        sampler: Option<String>,
        /// Stop cleanly after this many seconds with the sampler's state saved
        /// in OUT/.checkpoint (e.g. before a SLURM time limit); the same command
        /// resumes it. The state is saved as the run goes either way.
        #[arg(long)]
        time_limit: Option<f64>,
    },
    /// Run the paper's grid: growing observable sets × {no MD, Kernel I, Kernel II}
    Compare {
        #[command(flatten)]
        args: CalibrationArgs,
        #[arg(long)]
        sampler: Option<String>,
        /// Run the grid on this many independent mock data sets drawn from the config's
        /// [truth] (ball drop) and tabulate how often each case covers the truth
        #[arg(long)]
        replicates: Option<usize>,
    },
    /// The bundled ball-drop example end to end: mock data with concealed drag, then the 3x3 grid
    Demo {
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value = "outputs/demo")]
        out: PathBuf,
    },
    /// Benchmarks: likelihood throughput (one core) and the full comparison grid
    Bench {
        #[arg(default_value = "pipeline/ball_drop.toml")]
        config: PathBuf,
        /// Likelihood evaluations per kernel
        #[arg(long, default_value_t = 2_000_000)]
        evaluations: usize,
        /// Skip the comparison grid
        #[arg(long)]
        likelihood_only: bool,
        #[arg(long)]
        sampler: Option<String>,
        #[arg(long, default_value = "outputs/bench")]
        out: PathBuf,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Benchmark this emulator folder (training and prediction throughput) instead
        #[arg(long)]
        emulator: Option<PathBuf>,
        /// Benchmark one heavy-ion stand-in design point of this many events instead
        #[arg(long)]
        heavy_ion_events: Option<usize>,
        /// Time one full `diagnose` of the config's data instead
        #[arg(long)]
        diagnose: bool,
    },
    /// Locate the mismatch, name the missing physics, repair the model, show the fit improve
    Diagnose {
        #[command(flatten)]
        args: CalibrationArgs,
    },
    /// Build a self-contained HTML report from run folders (calibrate, compare or diagnose outputs)
    Report {
        /// Run folders
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        #[arg(long, default_value = "report.html")]
        out: PathBuf,
        /// Also write every figure as a PNG into this folder
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// Maximin Latin-hypercube design with iEBE-MUSIC parameter files and a SLURM array script
    Design {
        /// Parameter-space spec, e.g. design/heavy_ion_2param.toml
        spec: PathBuf,
        #[arg(long)]
        points: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long)]
        out: PathBuf,
    },
    /// Read iEBE-MUSIC runs (one folder per design point; combined HDF5 or per-event text files)
    /// into a long table of spectra and v_n{2}; or convert a paper .dat table to measurements
    Ingest {
        /// Runs folder (RUNS_DIR/<design id>/...), or a 15-column paper table (.dat)
        runs: PathBuf,
        /// Analysis pT bin edges in GeV, comma-separated (default: 10 bins over 0-2 GeV)
        #[arg(long, value_delimiter = ',')]
        pt_bins: Option<Vec<f64>>,
        /// Design (design.parquet) whose parameters are joined in; default RUNS_DIR/design.parquet if present
        #[arg(long)]
        design: Option<PathBuf>,
        /// Design points with fewer good events are flagged and left out
        #[arg(long, default_value_t = 10)]
        min_events: usize,
        /// auto (HDF5 if present), hdf5 or text
        #[arg(long, default_value = "auto")]
        format: String,
        /// Output table (.parquet); for a .dat input, a measurements file (.csv or .parquet)
        #[arg(long)]
        out: PathBuf,
    },
    /// PCA + per-component GP emulator from simulator runs (long or wide table)
    TrainEmulator {
        /// Config with an [emulator] table (parameters, kernel, components, …)
        config: PathBuf,
        /// Training table (Parquet or CSV): design_id, observable, x, value, <parameters>
        #[arg(long)]
        training: PathBuf,
        /// The design the runs came from: every point must be in the table
        #[arg(long)]
        design: Option<PathBuf>,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long)]
        out: PathBuf,
    },
    /// Check an emulator on a held-out design and by k-fold cross-validation
    ValidateEmulator {
        /// Emulator folder written by train-emulator
        emulator: PathBuf,
        /// Held-out validation table (same layout as the training table)
        #[arg(long)]
        validation: Option<PathBuf>,
        /// Cross-validation folds (0 to skip)
        #[arg(long, default_value_t = 5)]
        folds: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// The whole heavy-ion study from a config's [run] table: design, simulate, ingest, emulator,
    /// mock data, the calibration grid and the report; stages whose inputs are unchanged are skipped
    Run {
        /// Analysis config with a [run] table, e.g. pipeline/heavy_ion_2param.toml
        config: PathBuf,
        /// Run only this stage: design, simulate, ingest, emulator, mock, calibrate or report
        #[arg(long)]
        stage: Option<String>,
        /// Run the selected stages even if their inputs are unchanged
        #[arg(long)]
        force: bool,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder (default: outputs/<config name>)
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Generate mock measurements from a built-in truth
    Simulate {
        #[command(subcommand)]
        system: SimulateSystem,
    },
}

#[derive(Subcommand)]
enum SimulateSystem {
    /// Heavy-ion blast-wave stand-in for iEBE-MUSIC. Writes event-by-event runs in iEBE-MUSIC's
    /// layout (OUT/<design id>/: per-event text files and spvn_results.h5) for `mdpipe ingest`;
    /// with an --out ending in .csv or .parquet and no --events, writes smooth expectation values
    /// instead (a measurements file for --point, a training table for --design)
    HeavyIon {
        /// Parameter point, e.g. eta_s=0.1,e_sw=0.2 or T_kink=0.18,a_low=-1,a_high=1,eta_s_kink=0.1,e_sw=0.2
        #[arg(long, conflicts_with = "design", required_unless_present = "design")]
        point: Option<String>,
        /// Run every point of a design.parquet
        #[arg(long)]
        design: Option<PathBuf>,
        /// With --design: run only this design id (one SLURM array task)
        #[arg(long, requires = "design")]
        only: Option<i64>,
        /// Particlization: none (f_eq), grad (Grad 14-moment shear δf, Bjorken shear) or grad-transverse
        /// (adds the blast wave's transverse expansion rates)
        #[arg(long, default_value = "grad")]
        delta_f: String,
        /// Events per design point (default 100 when writing runs)
        #[arg(long)]
        events: Option<usize>,
        /// Cooper–Frye samples per event (the count and v_n columns sum them; yields are per sample)
        #[arg(long, default_value_t = mdpipe::models::heavy_ion::events::DEFAULT_OVERSAMPLE)]
        oversample: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Run layout: text, hdf5 or both
        #[arg(long, default_value = "both")]
        layout: String,
        /// Smooth --point output only: relative 1σ error attached to every value
        #[arg(long, default_value_t = 0.01)]
        relative_error: f64,
        /// Runs folder, or a .csv/.parquet file for smooth values
        #[arg(long)]
        out: PathBuf,
    },
    /// Ball drop with quadratic drag: dv/dt = g - k v|v|, dh/dt = -v
    BallDrop {
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output file (.csv or .parquet)
        #[arg(long)]
        out: PathBuf,
        /// Quadratic drag coefficient k (1/m)
        #[arg(long, default_value_t = 0.4)]
        k: f64,
        #[arg(long, default_value_t = 9.8)]
        g: f64,
        #[arg(long, default_value_t = 0.0)]
        v0: f64,
        #[arg(long, default_value_t = 60.0)]
        h0: f64,
        /// Number of measurement times, equally spaced over [0, t-max]
        #[arg(long, default_value_t = 10)]
        points: usize,
        #[arg(long, default_value_t = 1.0)]
        t_max: f64,
        /// 1-sigma errors of height, velocity, acceleration
        #[arg(long, value_delimiter = ',', default_values_t = [0.1, 0.2, 0.3])]
        sigma: Vec<f64>,
    },
}

fn parse_overrides(data: Option<PathBuf>, kernel: Option<String>, observables: Option<Vec<String>>, sampler: Option<String>) -> Result<Overrides> {
    let kernel = match kernel {
        None => None,
        Some(k) => Some(DiscrepancyKernel::parse(&k).with_context(|| format!("--kernel: unknown kernel {k:?} (use none, I or II)"))?),
    };
    let sampler = match sampler {
        None => None,
        Some(s) => Some(SamplerKind::parse(&s).with_context(|| format!("--sampler: unknown sampler {s:?} (use smc or ensemble)"))?),
    };
    Ok(Overrides { data, kernel, observables, sampler })
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Calibrate { args, kernel, observables, sampler, time_limit } => {
            let config = Config::load(&args.config)?;
            let overrides = parse_overrides(args.data, kernel, observables, sampler)?;
            let problem = Problem::new(&config, &overrides)?;
            if let Some(t) = time_limit.filter(|t| !(t.is_finite() && *t >= 0.0)) {
                bail!("--time-limit {t}: give a number of seconds, 0 or more");
            }
            let limit = time_limit.map(std::time::Duration::from_secs_f64);
            let checkpoint = calibrate::checkpoint::Checkpointing::new(&args.out.join(".checkpoint"), calibrate::checkpoint_key(&problem, args.seed), limit);
            let cal = calibrate::run_checkpointed(&problem, args.seed, true, Some(&checkpoint))?;
            calibrate::write_outputs(&args.out, &problem, &cal)?;
            print_summary(&cal.summary);
            println!("wrote {}/{{posterior.parquet, summary.json, predictions.parquet}}", args.out.display());
        }
        Command::Compare { args, sampler, replicates: Some(n) } => {
            let config = Config::load(&args.config)?;
            if args.data.is_some() {
                bail!("--replicates draws its own data from the config's [truth]; drop --data");
            }
            let overrides = parse_overrides(None, None, None, sampler)?;
            compare::run_replicates(&config, &overrides, n, args.seed, &args.out)?;
            println!("{}", std::fs::read_to_string(args.out.join("replicates.md"))?);
            println!("wrote {0}/replicates.md, {0}/replicates.parquet and {0}/replicate_*/", args.out.display());
        }
        Command::Compare { args, sampler, replicates: None } => {
            let config = Config::load(&args.config)?;
            let overrides = parse_overrides(args.data, None, None, sampler)?;
            compare::run_grid(&config, &overrides, args.seed, &args.out, true)?;
            let table = std::fs::read_to_string(args.out.join("compare.md"))?;
            println!("{table}");
            println!("wrote {}/compare.md and compare.parquet", args.out.display());
        }
        Command::Diagnose { args } => {
            let config = Config::load(&args.config)?;
            let overrides = parse_overrides(args.data, None, None, None)?;
            let settings = mdpipe::diagnose::DiagnoseSettings { show_progress: true, ..Default::default() };
            let run = mdpipe::diagnose::run(&config, &overrides, args.seed, &settings, Some(&args.out))?;
            mdpipe::diagnose::print(&run.diagnosis);
            mdpipe::report::write(&[args.out.clone()], &args.out.join("report.html"), "mdpipe diagnose")?;
            println!("wrote {0}/diagnosis.json and {0}/report.html", args.out.display());
        }
        Command::Design { spec, points, seed, out } => {
            let bytes = std::fs::read(&spec).with_context(|| format!("reading {}", spec.display()))?;
            let design_spec = mdpipe::design::DesignSpec::load(&spec)?;
            let q = mdpipe::design::write_design(&design_spec, &artifacts::sha256_hex(&bytes), points, seed, &out)?;
            println!(
                "{} points in {} dimensions: minimum distance {:.4}, centered L2 discrepancy {:.5} (unit cube)",
                q.points, q.dimensions, q.min_distance, q.centered_l2_discrepancy
            );
            println!("wrote {0}/design.parquet, {0}/parameters/parameter_*, {0}/submit.slurm, {0}/quality.json", out.display());
        }
        Command::TrainEmulator { config, training, design, seed, out } => {
            let (_, r) = mdpipe::emulator::train_and_save(&config, &training, design.as_deref(), &out, seed)?;
            println!(
                "{} design points x {} outputs -> {} principal components ({:.2}% of the variance); {} kernel, {} restarts each, {} failed",
                r.n_points,
                r.n_outputs,
                r.n_components,
                100.0 * r.explained_variance.iter().sum::<f64>(),
                serde_json::to_value(r.kernel)?.as_str().unwrap_or(""),
                r.restarts,
                r.failures
            );
            println!("trained in {:.2} s; wrote {}/ (Parquet tables + emulator.json)", r.training_seconds, out.display());
        }
        Command::ValidateEmulator { emulator, validation, folds, seed } => {
            let s = mdpipe::emulator::validate::run(&emulator, validation.as_deref(), folds, seed)?;
            if let Some(h) = &s.holdout {
                mdpipe::emulator::validate::print("held-out design", h);
            }
            if let Some(c) = &s.cross_validation {
                mdpipe::emulator::validate::print(&format!("{folds}-fold cross-validation"), c);
            }
            println!("wrote {0}/validation.json and {0}/validation_parity.parquet", emulator.display());
        }
        Command::Report { dirs, out, png } => {
            let html = mdpipe::report::build(&dirs, "mdpipe report")?;
            artifacts::write_text_atomic(&out, &html)?;
            println!("wrote {}", out.display());
            if let Some(dir) = png {
                let files = mdpipe::report::png::write_figures(&html, &dir)?;
                println!("wrote {} PNG figures to {}", files.len(), dir.display());
            }
        }
        Command::Run { config, stage, force, seed, out } => {
            let config = Config::load(&config)?;
            let out = out.unwrap_or_else(|| PathBuf::from("outputs").join(&config.name));
            let start = std::time::Instant::now();
            let opts = mdpipe::pipeline::RunOptions { out: out.clone(), seed, stage, force, show_progress: true };
            let outcomes = mdpipe::pipeline::run(&config, &opts)?;
            let ran: Vec<&str> = outcomes.iter().filter(|o| o.ran).map(|o| o.stage.as_str()).collect();
            println!("ran {} stage(s) [{}] in {:.1} s; outputs in {}", ran.len(), ran.join(", "), start.elapsed().as_secs_f64(), out.display());
            if out.join("report.html").exists() {
                println!("study table: {}; report: {}", out.join("study.md").display(), out.join("report.html").display());
            }
        }
        Command::Demo { seed, out } => mdpipe::demo::run(seed, &out)?,
        Command::Bench { heavy_ion_events: Some(events), out, .. } => {
            let b = mdpipe::bench::heavy_ion_point(events, mdpipe::models::heavy_ion::events::DEFAULT_OVERSAMPLE, &out.join("heavy_ion"))?;
            println!("heavy-ion stand-in, one design point: {} events x {} samples, {} particles in the files ({} threads)", b.events, b.oversample, b.particles, rayon::current_num_threads());
            println!("  smooth Cooper-Frye tables {:>7.3} s", b.smooth_tables_s);
            println!("  event sampling            {:>7.3} s", b.sampling_s);
            println!("  write HDF5                {:>7.3} s", b.write_hdf5_s);
            println!("  write text files          {:>7.3} s", b.write_text_s);
            println!("  ingest (HDF5)             {:>7.3} s", b.ingest_s);
            println!("  simulate, HDF5 layout     {:>7.3} s total", b.smooth_tables_s + b.sampling_s + b.write_hdf5_s);
        }
        Command::Bench { diagnose: true, config, seed, .. } => {
            let config = Config::load(&config)?;
            let b = mdpipe::bench::diagnose_time(&config, seed)?;
            println!("diagnose {}: {} calibrations in {:.1} s on {} threads; verdict {}", config.path.display(), b.calibrations, b.seconds, rayon::current_num_threads(), b.verdict);
        }
        Command::Bench { emulator: Some(dir), .. } => {
            let b = mdpipe::bench::emulator_throughput(&dir, 200_000)?;
            println!("emulator: {} design points, {} components, {} outputs", b.n_points, b.n_components, b.n_outputs);
            println!("  marginal likelihood + gradient: {:>10.0} evaluations/s (one core)", b.marginal_likelihood_evals_per_second);
            println!("  one component, mean + variance: {:>10.0} predictions/s (one core)", b.component_predictions_per_second_one_core);
            println!("  all components, mean + variance: {:>9.0} predictions/s ({} threads)", b.emulator_predictions_per_second, rayon::current_num_threads());
            println!("  all components, batches of 256: {:>9.0} predictions/s ({} threads)", b.batched_predictions_per_second, rayon::current_num_threads());
            println!("  mean + full {}x{} covariance:  {:>10.0} predictions/s ({} threads)", b.n_outputs, b.n_outputs, b.full_covariance_predictions_per_second, rayon::current_num_threads());
        }
        Command::Bench { config, evaluations, likelihood_only, sampler, out, seed, emulator: None, heavy_ion_events: None, diagnose: false } => {
            let config = Config::load(&config)?;
            for kernel in compare::KERNELS {
                let b = mdpipe::bench::likelihood_throughput(&config, kernel, evaluations)?;
                println!(
                    "likelihood kernel={:<4} dim={:>2} points={}: {:>10.0} evaluations/s on one core ({:.1} ns each)",
                    b.kernel, b.dim, b.n_points, b.evaluations_per_second_one_core, 1e9 / b.evaluations_per_second_one_core
                );
            }
            if !likelihood_only {
                let overrides = parse_overrides(None, None, None, sampler)?;
                let (total, rows) = mdpipe::bench::compare_grid(&config, &overrides, seed, &out)?;
                for r in &rows {
                    println!(
                        "{:<40} {:<8} {:>6.2} s  min ESS {:>6.0}  min ESS/s {:>8.0}  {}",
                        r.case, r.sampler, r.seconds, r.min_ess, r.min_ess_per_second, if r.converged { "converged" } else { "NOT CONVERGED" }
                    );
                }
                println!("full 9-case grid: {total:.2} s on {} threads", rayon::current_num_threads());
            }
        }
        Command::Ingest { runs, pt_bins, design, min_events, format, out } => {
            if runs.is_file() && runs.extension().is_some_and(|e| e == "dat") {
                let data = artifacts::read_paper_table(&runs)?;
                let prov = artifacts::Provenance::new(String::new(), artifacts::measurements_hash(&data), 0, &format!("ingest {}", runs.display()));
                artifacts::write_measurements(&out, &data, Some(&prov))?;
                println!("converted {} values from {} to {}", data.len(), runs.display(), out.display());
                return Ok(());
            }
            let mut settings = mdpipe::ingest::IngestSettings { min_events, format: format.parse()?, ..Default::default() };
            if let Some(edges) = pt_bins {
                settings.pt_edges = edges;
            }
            let (ingested, design_df) = mdpipe::ingest::ingest_runs(&runs, design.as_deref(), &settings)?;
            mdpipe::ingest::print_report(&ingested.report);
            let report = mdpipe::ingest::write(&ingested, design_df.as_ref(), &out)?;
            let good = ingested.report.points.iter().filter(|p| p.flagged.is_none()).count();
            println!("wrote {} rows from {good} of {} design points to {} (report: {})", ingested.rows.len(), ingested.report.points.len(), out.display(), report.display());
        }
        Command::Simulate { system: SimulateSystem::HeavyIon { point, design, only, delta_f, events, oversample, seed, layout, relative_error, out } } => {
            use mdpipe::models::heavy_ion;
let df: heavy_ion::DeltaF = delta_f.parse()?;
            let smooth = events.is_none() && out.extension().is_some_and(|e| e == "csv" || e == "parquet");
            if !smooth {
                let n_events = events.unwrap_or(100);
                let start = std::time::Instant::now();
                let points: Vec<(i64, heavy_ion::HeavyIonParams)> = if let Some(design) = &design {
                    let d = heavy_ion::read_design_points(design)?;
                    std::fs::create_dir_all(&out)?;
                    // Array tasks may write this copy at once: each renames a complete file into place.
                    let bytes = std::fs::read(design).with_context(|| format!("reading {}", design.display()))?;
                    artifacts::write_atomic(&out.join("design.parquet"), |f| {
                        use std::io::Write;
                        Ok(f.write_all(&bytes)?)
                    })?;
                    let all: Vec<(i64, heavy_ion::HeavyIonParams)> = d.ids.into_iter().zip(d.points).collect();
                    match only {
                        Some(id) => vec![*all.iter().find(|(i, _)| *i == id).ok_or_else(|| anyhow::anyhow!("--only {id}: no design point {id} in {}", design.display()))?],
                        None => all,
                    }
                } else {
                    let point = point.clone().unwrap_or_default();
                    let params = heavy_ion::HeavyIonParams::parse(&point)?;
                    let named: Vec<(String, f64)> = point.split(',').filter_map(|kv| kv.split_once('=')).map(|(k, v)| (k.trim().to_string(), v.trim().parse().unwrap_or(f64::NAN))).collect();
                    let mut cols = vec![("design_id".to_string(), vec![0.0])];
                    cols.extend(named.into_iter().map(|(k, v)| (k, vec![v])));
                    let mut frame = artifacts::f64_frame(cols)?;
                    let prov = artifacts::Provenance::new(String::new(), String::new(), seed, &format!("simulate heavy-ion --point {point}"));
                    std::fs::create_dir_all(&out)?;
                    artifacts::write_parquet_atomic(&out.join("design.parquet"), &mut frame, Some(&prov))?;
                    vec![(0, params)]
                };
                let n = heavy_ion::simulate_runs(&points, df, n_events, oversample, seed, layout.parse()?, &out)?;
                println!("wrote {n} events ({} design points x {n_events}, delta-f {delta_f}) to {} in {:.1} s; next: mdpipe ingest {} --out TABLE.parquet", points.len(), out.display(), start.elapsed().as_secs_f64(), out.display());
                return Ok(());
            }
            if let Some(design) = design {
                let table = heavy_ion::simulate_design(&design, df)?;
                let data_hash = artifacts::sha256_hex(&std::fs::read(&design)?);
                let prov = artifacts::Provenance::new(String::new(), data_hash, 0, &format!("simulate heavy-ion --design {} --delta-f {delta_f}", design.display()));
                table.write(&out, Some(&prov))?;
                println!("wrote {} design points x {} outputs to {}", table.n_points(), table.n_outputs(), out.display());
                return Ok(());
            }
            let point = point.unwrap_or_default();
            let params = heavy_ion::HeavyIonParams::parse(&point)?;
            let pts = heavy_ion::analysis_pt();
            let mut data = Vec::new();
            for (name, values) in heavy_ion::observables(&params, df, &pts) {
                for (&x, &v) in pts.iter().zip(&values) {
                    // Flow coefficients near zero get an absolute floor so errors stay positive.
                    let err = if name.ends_with("spectrum") { relative_error * v.abs() } else { (relative_error * v.abs()).max(1e-4) };
                    data.push(artifacts::Measurement::new(name, x, v, err));
                }
            }
            let prov = artifacts::Provenance::new(String::new(), artifacts::measurements_hash(&data), 0, &format!("simulate heavy-ion --point {point} --delta-f {delta_f}"));
            artifacts::write_measurements(&out, &data, Some(&prov))?;
            println!("wrote {} values ({} observables x {} pT bins) to {}", data.len(), data.len() / pts.len(), pts.len(), out.display());
        }
        Command::Simulate { system: SimulateSystem::BallDrop { seed, out, k, g, v0, h0, points, t_max, sigma } } => {
            if sigma.len() != 3 || sigma.iter().any(|s| !(*s > 0.0)) {
                bail!("--sigma needs three positive errors (height, velocity, acceleration)");
            }
            let opts = ball_drop::MockOptions {
                setup: ball_drop::BallDropSetup { h0, g, v0 },
                forces: ball_drop::ExtraForces { quadratic_drag: k, ..ball_drop::ExtraForces::NONE },
                times: ball_drop::equally_spaced_times(points, t_max),
                sigma: [sigma[0], sigma[1], sigma[2]],
            };
            let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
            let data = ball_drop::mock_measurements(&opts, &mut rng);
            let cmd = format!("simulate ball-drop k={k} g={g} v0={v0} h0={h0}");
            let prov = artifacts::Provenance::new(String::new(), artifacts::measurements_hash(&data), seed, &cmd);
            artifacts::write_measurements(&out, &data, Some(&prov))?;
            println!("wrote {} measurements to {}", data.len(), out.display());
        }
    }
    Ok(())
}

fn print_summary(s: &calibrate::summary::Summary) {
    println!("{} | kernel {} | observables {} | sampler {}", s.name, s.kernel, s.observables.join(", "), s.sampler);
    for name in &s.parameter_order {
        let p = &s.parameters[name];
        let truth = s.truth.get(name).map(|t| format!("  (truth {t})")).unwrap_or_default();
        println!("  {name:>22} = {:>9.4}  95% [{:.4}, {:.4}]{truth}", p.median, p.q025, p.q975);
    }
    if let (Some(z), Some(e)) = (s.log_evidence, s.log_evidence_err) {
        println!("  log evidence = {z:.3} ± {e:.3}");
    }
    let d = &s.diagnostics;
    println!(
        "  {} draws, {:.1} s, {:.0} likelihood evals/s, min ESS/s {:.0}, chi2/dof (model alone) {:.2}",
        d.draws, d.wall_seconds, d.likelihood_evaluations_per_second, d.min_ess_per_second, s.fit.chi2_per_dof
    );
    if d.converged {
        println!("  converged: R-hat <= 1.01 and ESS >= 400 for every parameter");
    } else {
        eprintln!("  WARNING: NOT CONVERGED:");
        for w in &d.warnings {
            eprintln!("    - {w}");
        }
    }
}
