//! The application: one function per command of the command line, the demo
//! and the benchmarks. It wires the engine to the built-in systems
//! (`crate::systems::registry`); `main.rs` only parses the arguments.

pub mod bench;
pub mod cli;
pub mod commands;
pub mod demo;
pub mod simulate;

use anyhow::Result;
use cli::{Cli, Command, SimulateSystem};

/// Runs one parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Calibrate { args, kernel, observables, sampler, time_limit } => {
            commands::calibrate(args, kernel, observables, sampler, time_limit)
        }
        Command::Compare { args, sampler, replicates } => commands::compare(args, sampler, replicates),
        Command::Diagnose { args } => commands::diagnose(args),
        Command::Design { spec, points, seed, out } => commands::design(&spec, points, seed, &out),
        Command::TrainEmulator { config, training, design, seed, out } => {
            commands::train_emulator(&config, &training, design.as_deref(), seed, &out)
        }
        Command::ValidateEmulator { emulator, validation, folds, seed } => {
            commands::validate_emulator(&emulator, validation.as_deref(), folds, seed)
        }
        Command::Report { dirs, out, png } => commands::report(&dirs, &out, png.as_deref()),
        Command::Run { config, stage, force, seed, out, executor, case } => {
            commands::run_study(&config, stage, force, seed, out, &executor, case)
        }
        Command::Refine { config, seed, out, executor } => {
            commands::run_study(&config, Some("refine".into()), false, seed, out, &executor, None)
        }
        Command::Demo { seed, full, out } => demo::run(seed, full, &out),
        Command::Bench {
            config,
            evaluations,
            likelihood_only,
            sampler,
            out,
            seed,
            emulator,
            heavy_ion_events,
            diagnose,
        } => bench::command(bench::BenchArgs {
            config,
            evaluations,
            likelihood_only,
            sampler,
            out,
            seed,
            emulator,
            heavy_ion_events,
            diagnose,
        }),
        Command::Ingest { runs, pt_bins, design, min_events, format, out } => {
            commands::ingest(&runs, pt_bins, design.as_deref(), min_events, &format, &out)
        }
        Command::Simulate {
            system:
                SimulateSystem::HeavyIon {
                    point,
                    design,
                    only,
                    point_folder,
                    delta_f,
                    events,
                    oversample,
                    seed,
                    layout,
                    relative_error,
                    errors_from,
                    out,
                },
        } => simulate::heavy_ion(simulate::HeavyIonArgs {
            point,
            design,
            only,
            point_folder,
            delta_f,
            events,
            oversample,
            seed,
            layout,
            relative_error,
            errors_from,
            out,
        }),
        Command::Simulate { system: SimulateSystem::BallDrop { seed, out, k, g, v0, h0, points, t_max, sigma } } => {
            simulate::ball_drop(seed, &out, k, g, v0, h0, points, t_max, &sigma)
        }
    }
}
