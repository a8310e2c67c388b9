//! The application: one function per command of the command line, the demo
//! and the benchmarks. It wires the engine to the built-in model families
//! (`crate::systems::registry`) and `mdpipe run` to the systems of
//! [`systems`]; `main.rs` only parses the arguments.

pub mod bench;
pub mod bench_scaling;
pub mod cli;
pub mod commands;
pub mod demo;
pub mod export;
pub mod simulate;

use anyhow::Result;
use cli::Cli;

/// Every system `mdpipe run` knows, the one list: a study's `[run.<table>]`
/// is the system's that claims it, and reports take their figures. A new
/// system is its own folder and one line here.
pub fn systems() -> crate::pipeline::Systems {
    crate::pipeline::Systems::new(vec![&crate::run_systems::StandIn])
}

/// Runs one parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    cli.command.run()
}
