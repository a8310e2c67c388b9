//! Command-line entry point: parses the arguments and hands them to the library.

use clap::Parser;

fn main() {
    if let Err(e) = mdpipe::app::run(mdpipe::app::cli::Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
