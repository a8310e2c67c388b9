//! The commands of the command line, each reading its inputs, calling the
//! engine and saying what it wrote.

use crate::base::artifacts;
use crate::base::choices::{Executor, Kernel};
use crate::base::config::Config;
use crate::base::progress::Bars;
use crate::engine::calibrate::{self, results::summary::Summary, Overrides, Problem, SamplerKind};
use crate::engine::{compare, diagnose, report};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// The arguments every calibrating command takes.
#[derive(clap::Args, Clone)]
pub struct CalibrationArgs {
    /// Analysis config (TOML), e.g. pipeline/ball_drop.toml
    pub config: PathBuf,
    /// Measurements file (CSV or Parquet: observable,x,value,error); replaces the config's
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Random seed
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output directory
    #[arg(long)]
    pub out: PathBuf,
}

pub fn parse_overrides(
    data: Option<PathBuf>,
    kernel: Option<Kernel>,
    observables: Option<Vec<String>>,
    sampler: Option<SamplerKind>,
) -> Result<Overrides> {
    Ok(Overrides { data, kernel, observables, sampler })
}

pub fn calibrate(
    args: CalibrationArgs,
    kernel: Option<Kernel>,
    observables: Option<Vec<String>>,
    sampler: Option<SamplerKind>,
    time_limit: Option<f64>,
) -> Result<()> {
    let analysis = crate::pipeline::load(&args.config, &super::systems())?;
    let overrides = parse_overrides(args.data, kernel, observables, sampler)?;
    let problem = Problem::new(&analysis, &overrides)?;
    if let Some(t) = time_limit.filter(|t| !(t.is_finite() && *t >= 0.0)) {
        bail!("--time-limit {t}: give a number of seconds, 0 or more");
    }
    artifacts::check_writable(&args.out)?;
    let limit = time_limit.map(std::time::Duration::from_secs_f64);
    let checkpoint = calibrate::sampler::checkpoint::Checkpointing::new(
        &args.out.join(".checkpoint"),
        calibrate::checkpoint_key(&problem, args.seed),
        limit,
    );
    let cal = calibrate::run_and_write(&problem, args.seed, &Bars::default(), &checkpoint, &args.out)?;
    print_summary(&cal.summary);
    println!(
        "wrote {}/{{posterior.parquet, summary.json, predictions.parquet, posterior_predictive.parquet}}",
        args.out.display()
    );
    Ok(())
}

pub fn compare(args: CalibrationArgs, sampler: Option<SamplerKind>, replicates: Option<usize>) -> Result<()> {
    let analysis = crate::pipeline::load(&args.config, &super::systems())?;
    artifacts::check_writable(&args.out)?;
    if let Some(n) = replicates {
        if args.data.is_some() {
            bail!("--replicates draws its own data from the config's [truth]; drop --data");
        }
        let overrides = parse_overrides(None, None, None, sampler)?;
        compare::run_replicates(&analysis, &overrides, n, args.seed, &args.out)?;
        println!("{}", std::fs::read_to_string(args.out.join("replicates.md"))?);
        println!("wrote {0}/replicates.md, {0}/replicates.parquet and {0}/replicate_*/", args.out.display());
        return Ok(());
    }
    let overrides = parse_overrides(args.data, None, None, sampler)?;
    compare::run_grid(&analysis, &overrides, args.seed, &args.out, &Bars::default())?;
    println!("{}", std::fs::read_to_string(args.out.join("compare.md"))?);
    println!("wrote {}/compare.md and compare.parquet", args.out.display());
    Ok(())
}

pub fn diagnose(
    args: CalibrationArgs,
    discover: bool,
    no_discover: bool,
    no_repair: bool,
    profile: bool,
) -> Result<()> {
    let analysis = crate::pipeline::load(&args.config, &super::systems())?;
    let overrides = parse_overrides(args.data, None, None, None)?;
    artifacts::check_writable(&args.out)?;
    let discover = match (discover, no_discover) {
        (true, _) => diagnose::Discover::Always,
        (_, true) => diagnose::Discover::Never,
        _ => diagnose::Discover::WhenUnexplained,
    };
    let run = diagnose::run(
        &analysis,
        &overrides,
        args.seed,
        &diagnose::DiagnoseSettings { discover, repair: !no_repair, ..Default::default() },
        Some(&args.out),
        &Bars::default(),
    )?;
    diagnose::print(&run.diagnosis);
    if profile {
        diagnose::print_profile(&run.diagnosis);
    }
    report::write(
        std::slice::from_ref(&args.out),
        &args.out.join("report.html"),
        "mdpipe diagnose",
        &super::systems().figures(),
    )?;
    println!("wrote {0}/diagnosis.json and {0}/report.html", args.out.display());
    Ok(())
}

pub fn design(spec: &Path, points: usize, seed: u64, out: &Path) -> Result<()> {
    let bytes = std::fs::read(spec).with_context(|| format!("reading {}", spec.display()))?;
    let design_spec = crate::engine::design::DesignSpec::load(spec)?;
    let q = crate::engine::design::write_design(&design_spec, &artifacts::sha256_hex(&bytes), points, seed, out)?;
    println!(
        "{} points in {} dimensions: minimum distance {:.4}, centered L2 discrepancy {:.5} (unit cube)",
        q.points, q.dimensions, q.min_distance, q.centered_l2_discrepancy
    );
    println!("wrote {0}/design.parquet, {0}/parameters/parameter_*, {0}/submit.slurm, {0}/quality.json", out.display());
    Ok(())
}

pub fn train_emulator(config: &Path, training: &Path, design: Option<&Path>, seed: u64, out: &Path) -> Result<()> {
    // The folder is saved beside itself and swapped in, so its parent must take files.
    artifacts::check_writable(out.parent().unwrap_or(Path::new(".")))?;
    let (_, r) = crate::engine::emulator::train_and_save(config, training, design, out, seed)?;
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
    Ok(())
}

pub fn validate_emulator(emulator: &Path, validation: Option<&Path>, folds: usize, seed: u64) -> Result<()> {
    use crate::engine::emulator::validate;
    let s = validate::run(emulator, validation, folds, seed)?;
    if let Some(h) = &s.holdout {
        validate::print("held-out design", h);
    }
    if let Some(c) = &s.cross_validation {
        validate::print(&format!("{folds}-fold cross-validation"), c);
    }
    println!("wrote {0}/validation.json and {0}/validation_parity.parquet", emulator.display());
    Ok(())
}

pub fn report(dirs: &[PathBuf], out: &Path, png: Option<&Path>) -> Result<()> {
    let html = report::build(dirs, "mdpipe report", &super::systems().figures())?;
    artifacts::write_text_atomic(out, &html)?;
    println!("wrote {}", out.display());
    if let Some(dir) = png {
        let files = report::png::write_figures(&html, dir)?;
        println!("wrote {} PNG figures to {}", files.len(), dir.display());
    }
    Ok(())
}

pub fn run_study(
    config: &Path,
    stage: Option<String>,
    force: bool,
    seed: u64,
    out: Option<PathBuf>,
    executor: Executor,
    case: Option<usize>,
) -> Result<()> {
    let config = Config::load(config)?;
    let run: crate::pipeline::RunConfig = match &config.run {
        Some(table) => crate::pipeline::RunConfig::decode(&config, table)?,
        None => return Err(crate::pipeline::no_run_table(&config.path)),
    };
    let out = crate::pipeline::study_out(&config, &run, out.as_deref());
    let start = std::time::Instant::now();
    let opts = crate::pipeline::RunOptions {
        out: out.clone(),
        seed,
        stage,
        force,
        show_progress: true,
        executor,
        mdpipe: std::env::current_exe()?,
        case,
    };
    let outcomes = crate::pipeline::run(&config, &opts, &super::systems())?;
    let ran: Vec<&str> = outcomes.iter().filter(|o| o.ran).map(|o| o.stage.as_str()).collect();
    println!(
        "ran {} stage(s) [{}] in {:.1} s; outputs in {}",
        ran.len(),
        ran.join(", "),
        start.elapsed().as_secs_f64(),
        out.display()
    );
    if out.join("report.html").exists() {
        let table =
            if out.join("study.md").exists() { out.join("study.md") } else { out.join("calibrate").join("cases.md") };
        println!("results: {}; report: {}", table.display(), out.join("report.html").display());
    }
    Ok(())
}

pub fn ingest(
    runs: &Path,
    pt_bins: Option<Vec<f64>>,
    design: Option<&Path>,
    min_events: usize,
    format: &str,
    out: &Path,
) -> Result<()> {
    use crate::engine::ingest;
    if runs.is_file() && runs.extension().is_some_and(|e| e == "dat") {
        let data = crate::base::paper_table::read(runs)?;
        let prov = artifacts::Provenance::new(
            String::new(),
            artifacts::measurements_hash(&data),
            0,
            &format!("ingest {}", runs.display()),
        );
        artifacts::write_measurements(out, &data, Some(&prov))?;
        println!("converted {} values from {} to {}", data.len(), runs.display(), out.display());
        return Ok(());
    }
    let mut settings = ingest::IngestSettings { min_events, format: format.parse()?, ..Default::default() };
    if let Some(edges) = pt_bins {
        settings.pt_edges = edges;
    }
    let (ingested, design_df) = ingest::ingest_runs(runs, design, &settings)?;
    ingest::print_report(&ingested.report);
    let report = ingest::write(&ingested, design_df.as_ref(), out)?;
    let good = ingested.report.points.iter().filter(|p| p.flagged.is_none()).count();
    println!(
        "wrote {} rows from {good} of {} design points to {} (report: {})",
        ingested.rows.len(),
        ingested.report.points.len(),
        out.display(),
        report.display()
    );
    Ok(())
}

pub fn print_summary(s: &Summary) {
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
    if let Some(numerics) = &s.numerics {
        println!("  {numerics}");
    }
    if s.fit.emulator_dominates() {
        eprintln!(
            "  WARNING: the emulator's uncertainty is {:.1}% of the predictive variance at the data in its worst observable: it, not the physics, absorbs the mismatch there; add design points where the posterior lies (mdpipe refine)",
            100.0 * s.fit.model_variance_share
        );
    }
    for piled in &s.piled_at_bounds {
        eprintln!("  WARNING: {piled}");
    }
    if d.converged {
        println!("  converged: R-hat <= 1.01 and ESS >= 400 for every parameter");
    } else {
        eprintln!("  WARNING: NOT CONVERGED:");
        for w in &d.warnings {
            eprintln!("    - {w}");
        }
    }
}
