//! The command line: what each command and flag means (clap). `main.rs`
//! parses it and hands it to [`super::run`].

use super::commands::CalibrationArgs;
use super::{bench, commands, demo, simulate};
use crate::base::choices::{Executor, Kernel};
use crate::engine::calibrate::SamplerKind;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "mdpipe",
    version,
    about = "Locate, explain and model simulator-data mismatch with Bayesian model discrepancy"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Calibrate a model against measurements, with or without model discrepancy
    Calibrate {
        #[command(flatten)]
        args: CalibrationArgs,
        /// Discrepancy kernel: none, I or II (default: the config's)
        #[arg(long)]
        kernel: Option<Kernel>,
        /// Comma-separated observables to use (default: the config's)
        #[arg(long, value_delimiter = ',')]
        observables: Option<Vec<String>>,
        /// Sampler: smc or ensemble (default: the config's)
        #[arg(long)]
        sampler: Option<SamplerKind>,
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
        sampler: Option<SamplerKind>,
        /// Run the grid on this many independent mock data sets drawn from the config's
        /// [truth] (ball drop) and tabulate how often each case covers the truth
        #[arg(long)]
        replicates: Option<usize>,
    },
    /// The bundled ball-drop example end to end: mock data with concealed drag, then the 3x3 grid
    Demo {
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Sample with the config's full settings (4 x 2000 particles) instead of a quarter of them
        #[arg(long)]
        full: bool,
        #[arg(long, default_value = "outputs/demo")]
        out: PathBuf,
    },
    /// Benchmarks: likelihood throughput (one core) and the full comparison grid
    Bench(bench::BenchArgs),
    /// Locate the mismatch, name the missing physics, repair the model, show the fit improve
    Diagnose {
        #[command(flatten)]
        args: CalibrationArgs,
        /// Search the model's grammar for a term nobody declared even when a
        /// candidate explains the data (by default only when none does)
        #[arg(long, conflicts_with = "no_discover")]
        discover: bool,
        /// Never search for undeclared terms
        #[arg(long)]
        no_discover: bool,
        /// The verdict only: skip the repaired fit with MD on top (the before-and-after)
        #[arg(long)]
        no_repair: bool,
        /// Print where the time went: each fit's wall time, particles and model evaluations
        #[arg(long)]
        profile: bool,
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
    /// A calibration's folder as one NetCDF or Zarr file for ArviZ (`from_netcdf`, `from_zarr`); needs the
    /// Python package (`pip install .`)
    Export {
        /// Calibration folder (calibrate --out, a study's calibrate/<case>, a diagnosis's fit)
        run_dir: PathBuf,
        #[arg(long, value_enum, default_value = "netcdf")]
        format: super::export::ExportFormat,
        /// File to write (default: RUN_DIR/posterior.nc or RUN_DIR/posterior.zarr)
        #[arg(long)]
        out: Option<PathBuf>,
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
    /// A whole study from a config's [run] table, for any simulator: design, simulate (locally or as
    /// a Slurm array), ingest, emulator, the calibrations and the report, then each declared
    /// candidate as a variant of the simulator and diagnose; stages whose inputs are unchanged are
    /// skipped
    Run {
        /// Analysis config with a [run] table, e.g. examples/decay_counter/study.toml
        config: PathBuf,
        /// Run only this stage (a system may add its own, as the stand-in's mock)
        #[arg(long, value_parser = stage_names())]
        stage: Option<String>,
        /// Run the selected stages even if their inputs are unchanged
        #[arg(long)]
        force: bool,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder (default: [run] out, or outputs/<config name>)
        #[arg(long)]
        out: Option<PathBuf>,
        /// Where the simulate stage runs the design points: local (parallel processes) or
        /// slurm (a job array submitted with sbatch and followed with squeue)
        #[arg(long, default_value = "local")]
        executor: Executor,
        /// With --stage calibrate: only this calibration case, by index (what each
        /// array task runs when the cases go out to Slurm)
        #[arg(long)]
        case: Option<usize>,
    },
    /// Adaptive design: the refine stage of `mdpipe run` (its [run.refine] table). Rounds of
    /// pilot calibrations, new runs where the emulator's error matters most to the posterior,
    /// and retraining, until that error is below the data error or the run budget is spent
    Refine {
        /// Analysis config with [run] and [run.refine] tables
        config: PathBuf,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder of the run (default: outputs/<config name>)
        #[arg(long)]
        out: Option<PathBuf>,
        /// Where the new runs go: local or slurm
        #[arg(long, default_value = "local")]
        executor: Executor,
    },
    /// Generate mock measurements from a built-in truth
    Simulate {
        #[command(subcommand)]
        system: SimulateSystem,
    },
}

#[derive(Subcommand)]
pub enum SimulateSystem {
    /// Heavy-ion blast-wave stand-in for iEBE-MUSIC. Writes event-by-event runs in iEBE-MUSIC's
    /// layout (OUT/<design id>/: per-event text files and spvn_results.h5) for `mdpipe ingest`;
    /// with an --out ending in .csv or .parquet and no --events, writes smooth expectation values
    /// instead (a measurements file for --point, a training table for --design)
    HeavyIon(simulate::HeavyIonArgs),
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

impl Command {
    /// Runs the command: each variant hands its arguments to its function in
    /// `commands` (or `demo`, `bench`, `simulate`), so a new command is a
    /// variant here and a function there.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Command::Calibrate { args, kernel, observables, sampler, time_limit } => {
                commands::calibrate(args, kernel, observables, sampler, time_limit)
            }
            Command::Compare { args, sampler, replicates } => commands::compare(args, sampler, replicates),
            Command::Diagnose { args, discover, no_discover, no_repair, profile } => {
                commands::diagnose(args, discover, no_discover, no_repair, profile)
            }
            Command::Design { spec, points, seed, out } => commands::design(&spec, points, seed, &out),
            Command::TrainEmulator { config, training, design, seed, out } => {
                commands::train_emulator(&config, &training, design.as_deref(), seed, &out)
            }
            Command::ValidateEmulator { emulator, validation, folds, seed } => {
                commands::validate_emulator(&emulator, validation.as_deref(), folds, seed)
            }
            Command::Report { dirs, out, png } => commands::report(&dirs, &out, png.as_deref()),
            Command::Export { run_dir, format, out } => super::export::run(&run_dir, format, out.as_deref()),
            Command::Run { config, stage, force, seed, out, executor, case } => {
                commands::run_study(&config, stage, force, seed, out, executor, case)
            }
            Command::Refine { config, seed, out, executor } => commands::run_study(
                &config,
                Some(crate::pipeline::StageId::REFINE.name().to_string()),
                false,
                seed,
                out,
                executor,
                None,
            ),
            Command::Demo { seed, full, out } => demo::run(seed, full, &out),
            Command::Bench(args) => bench::command(args),
            Command::Ingest { runs, pt_bins, design, min_events, format, out } => {
                commands::ingest(&runs, pt_bins, design.as_deref(), min_events, &format, &out)
            }
            Command::Simulate { system: SimulateSystem::HeavyIon(args) } => simulate::heavy_ion(args),
            Command::Simulate {
                system: SimulateSystem::BallDrop { seed, out, k, g, v0, h0, points, t_max, sigma },
            } => simulate::ball_drop(seed, &out, k, g, v0, h0, points, t_max, &sigma),
        }
    }
}

/// `--stage`'s values: every stage a study with the command line's systems
/// may have, their own among them (an unknown name is a usage error).
fn stage_names() -> clap::builder::PossibleValuesParser {
    clap::builder::PossibleValuesParser::new(crate::pipeline::stages(&super::systems()))
}
