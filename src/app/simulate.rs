//! `mdpipe simulate`: mock data and runs from the built-in systems.

use crate::base::artifacts::{self, Provenance};
use crate::systems::ball_drop;
use crate::systems::heavy_ion::{self, mock};
use anyhow::{bail, Result};
use rand::SeedableRng;
use std::path::{Path, PathBuf};

/// The arguments of `simulate heavy-ion` (see `cli::SimulateSystem`).
#[derive(clap::Args)]
pub struct HeavyIonArgs {
    /// Parameter point, e.g. eta_s=0.1,e_sw=0.2 or T_kink=0.18,a_low=-1,a_high=1,eta_s_kink=0.1,e_sw=0.2
    #[arg(long, conflicts_with = "design", required_unless_present = "design")]
    pub point: Option<String>,
    /// Run every point of a design.parquet
    #[arg(long)]
    pub design: Option<PathBuf>,
    /// With --design: run only this design id (one SLURM array task)
    #[arg(long, requires = "design")]
    pub only: Option<i64>,
    /// With --only: --out is the point's own folder (what `mdpipe run` gives each attempt),
    /// written directly, without a copy of the design
    #[arg(long, requires = "only")]
    pub point_folder: bool,
    /// Particlization: none (f_eq), grad (Grad 14-moment shear δf, Bjorken shear) or grad-transverse
    /// (adds the blast wave's transverse expansion rates)
    #[arg(long, default_value = "grad")]
    pub delta_f: String,
    /// Events per design point (default 100 when writing runs)
    #[arg(long)]
    pub events: Option<usize>,
    /// Cooper–Frye samples per event (the count and v_n columns sum them; yields are per sample)
    #[arg(long, default_value_t = crate::systems::heavy_ion::events::DEFAULT_OVERSAMPLE)]
    pub oversample: usize,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run layout: text, hdf5 or both
    #[arg(long, default_value = "both")]
    pub layout: String,
    /// Smooth --point output only: relative 1σ error attached to every value
    #[arg(long, default_value_t = 0.01)]
    pub relative_error: f64,
    /// Smooth --point output only: take each value's 1σ error from this measurements file
    /// (matched by observable and x), e.g. a study's mock/measurements.parquet. The result is
    /// the Asimov data set: the expected data, no fluctuation, with the real errors
    #[arg(long, conflicts_with_all = ["design", "events", "relative_error"])]
    pub errors_from: Option<PathBuf>,
    /// Runs folder, or a .csv/.parquet file for smooth values
    #[arg(long)]
    pub out: PathBuf,
}

pub fn heavy_ion(a: HeavyIonArgs) -> Result<()> {
    let df: heavy_ion::DeltaF = a.delta_f.parse()?;
    let smooth = a.events.is_none() && a.out.extension().is_some_and(|e| e == "csv" || e == "parquet");
    if a.errors_from.is_some() && !smooth {
        bail!(
            "--errors-from gives smooth values their errors: --out must be a .csv or .parquet file (got {})",
            a.out.display()
        );
    }
    if let (true, Some(design), Some(id)) = (a.point_folder, &a.design, a.only) {
        let n_events = a.events.unwrap_or(100);
        let params = heavy_ion::design_point(design, id)?;
        heavy_ion::simulate_point(id, &params, df, n_events, a.oversample, a.seed, a.layout.parse()?, &a.out)?;
        println!("wrote {n_events} events of design point {id} (delta-f {}) to {}", a.delta_f, a.out.display());
        return Ok(());
    }
    if !smooth {
        let n_events = a.events.unwrap_or(100);
        let start = std::time::Instant::now();
        let points = match &a.design {
            Some(design) => mock::design_points(design, a.only, &a.out)?,
            None => mock::named_point(a.point.as_deref().unwrap_or_default(), a.seed, &a.out)?,
        };
        let n = heavy_ion::simulate_runs(&points, df, n_events, a.oversample, a.seed, a.layout.parse()?, &a.out)?;
        let (out, delta_f) = (a.out.display(), &a.delta_f);
        println!("wrote {n} events ({} design points x {n_events}, delta-f {delta_f}) to {out} in {:.1} s; next: mdpipe ingest {out} --out TABLE.parquet", points.len(), start.elapsed().as_secs_f64());
        return Ok(());
    }
    if let Some(design) = &a.design {
        let table = heavy_ion::simulate_design(design, df)?;
        let data_hash = artifacts::sha256_hex(&std::fs::read(design)?);
        let prov = Provenance::new(
            String::new(),
            data_hash,
            0,
            &format!("simulate heavy-ion --design {} --delta-f {}", design.display(), a.delta_f),
        );
        table.write(&a.out, Some(&prov))?;
        println!("wrote {} design points x {} outputs to {}", table.n_points(), table.n_outputs(), a.out.display());
        return Ok(());
    }
    let point = a.point.unwrap_or_default();
    let mut data = mock::smooth_measurements(&heavy_ion::HeavyIonParams::parse(&point)?, df, a.relative_error);
    if let Some(source) = &a.errors_from {
        mock::take_errors_from(&mut data, source)?;
    }
    let errors = a.errors_from.as_ref().map(|p| format!(" --errors-from {}", p.display())).unwrap_or_default();
    let prov = Provenance::new(
        String::new(),
        artifacts::measurements_hash(&data),
        0,
        &format!("simulate heavy-ion --point {point} --delta-f {}{errors}", a.delta_f),
    );
    artifacts::write_measurements(&a.out, &data, Some(&prov))?;
    let bins = heavy_ion::analysis_pt().len();
    println!("wrote {} values ({} observables x {bins} pT bins) to {}", data.len(), data.len() / bins, a.out.display());
    Ok(())
}

#[allow(clippy::too_many_arguments)]
pub fn ball_drop(
    seed: u64,
    out: &Path,
    k: f64,
    g: f64,
    v0: f64,
    h0: f64,
    points: usize,
    t_max: f64,
    sigma: &[f64],
) -> Result<()> {
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
    let prov = Provenance::new(String::new(), artifacts::measurements_hash(&data), seed, &cmd);
    artifacts::write_measurements(out, &data, Some(&prov))?;
    println!("wrote {} measurements to {}", data.len(), out.display());
    Ok(())
}
