//! The application: one function per command of the command line, the demo
//! and the benchmarks. It wires the engine to the built-in systems
//! (`crate::systems::registry`); `main.rs` only parses the arguments.

pub mod bench;
pub mod bench_scaling;
pub mod cli;
pub mod commands;
pub mod demo;
pub mod export;
pub mod simulate;

use anyhow::Result;
use cli::Cli;

/// Runs one parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    cli.command.run()
}
