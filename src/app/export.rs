//! `mdpipe export RUN_DIR --format netcdf|zarr`: a calibration as one file
//! that ArviZ reopens (`from_netcdf`, `from_zarr`).
//!
//! The file is written by ArviZ itself, through the Python package that
//! `pip install .` installs beside this binary (`python -m mdpipe export`):
//! ArviZ's own writer is what keeps the file's groups, dimensions and
//! attributes exactly ArviZ's schema, and NetCDF-4 needs HDF5 dimension
//! scales (variable-length object references) that no pure-Rust HDF5 writer
//! produces; linking libnetcdf and libhdf5 would add a C build to every
//! install for one command.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// What `--format` takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    Netcdf,
    Zarr,
}

impl ExportFormat {
    fn name(self) -> &'static str {
        match self {
            ExportFormat::Netcdf => "netcdf",
            ExportFormat::Zarr => "zarr",
        }
    }
}

/// The Python that has the mdpipe package: `$MDPIPE_PYTHON`, else the
/// interpreter of the environment this binary was installed into, else
/// `python3` on PATH.
fn python() -> PathBuf {
    if let Some(explicit) = std::env::var_os("MDPIPE_PYTHON") {
        return PathBuf::from(explicit);
    }
    let beside = std::env::current_exe().ok().and_then(|exe| {
        let dir = exe.parent()?.to_path_buf();
        ["python", "python3", "python.exe"].iter().map(|n| dir.join(n)).find(|p| p.is_file())
    });
    beside.unwrap_or_else(|| PathBuf::from("python3"))
}

pub fn run(run_dir: &Path, format: ExportFormat, out: Option<&Path>) -> Result<()> {
    if !run_dir.join("posterior.parquet").is_file() {
        bail!("{}: no posterior.parquet (export takes a calibration's folder)", run_dir.display());
    }
    let python = python();
    let probe = Command::new(&python).args(["-c", "import mdpipe.export, arviz"]).output();
    match probe {
        Ok(done) if done.status.success() => {}
        _ => bail!(
            "export writes through ArviZ and needs the mdpipe Python package, which {} cannot import: \
             install it with `pip install .` from the repository (or set MDPIPE_PYTHON to a Python that has it)",
            python.display()
        ),
    }
    let mut command = Command::new(&python);
    command.args(["-m", "mdpipe", "export"]).arg(run_dir).args(["--format", format.name()]);
    if let Some(out) = out {
        command.arg("--out").arg(out);
    }
    let status = command.status().with_context(|| format!("running {}", python.display()))?;
    if !status.success() {
        bail!("export of {} failed (see the message above)", run_dir.display());
    }
    Ok(())
}
