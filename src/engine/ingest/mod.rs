//! `mdpipe ingest`: iEBE-MUSIC runs (one folder per design point, named by its
//! design id, e.g. `runs/0007`) → one long Parquet table
//! `design_id, observable, x, value, error, n_events, <design parameters>`.
//!
//! Each design point folder holds its events either as a combined HDF5 file
//! (`*.h5`) or as per-event folders of text files ([`layout`]). Events that are
//! missing a file or hold a corrupt value are listed and skipped; a design point
//! with fewer than `min_events` good events is flagged and left out of the
//! table, never averaged in.

pub mod cumulants;
pub mod hdf5;
pub mod layout;
mod report;
pub mod tables;

pub use report::print_report;

use crate::base::artifacts::{self, Provenance};
use anyhow::{anyhow, bail, Context, Result};
use cumulants::{BinnedEvent, Species};
use layout::{Event, FileKind, Window, CHARGED_PID};
use polars::prelude::*;
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// How one simulator's output format is read into the long table: a folder
/// of point folders (`RUNS/<design id>/`) in, the rows, each point's report
/// and the design joined in, out. iEBE-MUSIC's layout ([`IebeMusicRuns`]) and
/// a table per point ([`tables::TableRuns`]) are two; another simulator's
/// format is one more implementation.
pub trait RunsReader {
    fn read(&self, runs_dir: &Path, design: Option<&Path>) -> Result<(Ingested, Option<DataFrame>)>;
}

/// iEBE-MUSIC's layout (`spvn_results.h5` or event folders), with its settings.
pub struct IebeMusicRuns(pub IngestSettings);

impl RunsReader for IebeMusicRuns {
    fn read(&self, runs_dir: &Path, design: Option<&Path>) -> Result<(Ingested, Option<DataFrame>)> {
        ingest_runs(runs_dir, design, &self.0)
    }
}

/// Which on-disk form to read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunFormat {
    /// HDF5 if the point folder has a `*.h5` file, else text folders.
    Auto,
    Hdf5,
    Text,
}

impl std::str::FromStr for RunFormat {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(RunFormat::Auto),
            "hdf5" => Ok(RunFormat::Hdf5),
            "text" => Ok(RunFormat::Text),
            _ => bail!("unknown run format '{s}' (use auto, hdf5 or text)"),
        }
    }
}

#[derive(Clone, Debug)]
pub struct IngestSettings {
    /// Analysis bin edges in GeV; each bin is represented by its midpoint.
    pub pt_edges: Vec<f64>,
    /// pT range of the charged reference particles for v_n{2}, GeV.
    pub reference_pt: (f64, f64),
    pub min_events: usize,
    pub format: RunFormat,
}

impl Default for IngestSettings {
    fn default() -> Self {
        IngestSettings {
            pt_edges: (0..=10).map(|k| 0.2 * k as f64).collect(),
            reference_pt: (0.2, 3.0),
            min_events: 10,
            format: RunFormat::Auto,
        }
    }
}

/// The files the analysis needs, and the observables they give.
pub fn analysis_species() -> [(&'static str, Species); 3] {
    [
        ("ch", Species { kind: FileKind::diff(CHARGED_PID, Window::Eta, -0.5, 0.5), mass: 0.0 }),
        ("pi", Species { kind: FileKind::diff(211, Window::Y, -0.5, 0.5), mass: 0.139_570 }),
        ("p", Species { kind: FileKind::diff(2212, Window::Y, -0.5, 0.5), mass: 0.938_272 }),
    ]
}

/// One skipped event and why.
#[derive(Clone, Debug, Serialize)]
pub struct SkippedEvent {
    pub event: String,
    pub reason: String,
}

/// What happened at one design point.
#[derive(Clone, Debug, Serialize)]
pub struct PointReport {
    pub design_id: i64,
    pub folder: String,
    pub source: String,
    pub good_events: usize,
    pub skipped: Vec<SkippedEvent>,
    /// Why the point is left out of the table, if it is.
    pub flagged: Option<String>,
    /// Bins left out because their value or jackknife error is undefined:
    /// too few particles in some event subsets, or a v_n{2} whose reference
    /// <|Q|² − M> is not positive (more events or samples are needed).
    pub undefined_bins: Vec<String>,
}

/// One row of the output table.
#[derive(Clone, Debug)]
pub struct IngestedRow {
    pub design_id: i64,
    pub observable: String,
    pub x: f64,
    pub value: f64,
    pub error: f64,
    pub n_events: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct IngestReport {
    pub runs_dir: String,
    pub points: Vec<PointReport>,
    /// Design ids in the design with no run folder.
    pub missing_points: Vec<i64>,
    pub provenance: Provenance,
}

pub struct Ingested {
    pub rows: Vec<IngestedRow>,
    pub report: IngestReport,
    /// Per design point, the jackknife covariance between its rows (off the
    /// diagonal: the diagonal is the rows' errors²), over the same events.
    pub covariance: std::collections::BTreeMap<i64, Vec<crate::base::covariance::CovarianceEntry>>,
}

/// Trailing integer of a folder name (`0007`, `point_12`) = its design id.
fn design_id_of(name: &str) -> Option<i64> {
    let digits: String =
        name.chars().rev().take_while(|c| c.is_ascii_digit()).collect::<Vec<_>>().into_iter().rev().collect();
    digits.parse().ok()
}

/// Reads a design point's events, in either form.
fn read_point_events(dir: &Path, format: RunFormat) -> Result<(String, Vec<Event>, Vec<SkippedEvent>)> {
    let mut h5_files: Vec<PathBuf> = Vec::new();
    let mut text_dirs: Vec<PathBuf> = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let path = entry?.path();
        if path.is_file() && path.extension().is_some_and(|e| e == "h5") {
            h5_files.push(path);
        } else if path.is_dir() && layout::is_text_event_dir(&path) {
            text_dirs.push(path);
        }
    }
    h5_files.sort();
    text_dirs.sort();
    let use_h5 = match format {
        RunFormat::Hdf5 => true,
        RunFormat::Text => false,
        RunFormat::Auto => !h5_files.is_empty(),
    };
    let (mut events, mut skipped) = (Vec::new(), Vec::new());
    if use_h5 {
        if h5_files.is_empty() {
            bail!("{}: no *.h5 file", dir.display());
        }
        for f in &h5_files {
            let (good, bad) = hdf5::read_events(f)?;
            let prefix = if h5_files.len() > 1 { format!("{}:", file_name(f)) } else { String::new() };
            events.extend(good.into_iter().map(|mut e| {
                e.label = format!("{prefix}{}", e.label);
                e
            }));
            skipped.extend(
                bad.into_iter().map(|b| SkippedEvent { event: format!("{prefix}{}", b.label), reason: b.reason }),
            );
        }
        let names: Vec<String> = h5_files.iter().map(|f| file_name(f)).collect();
        Ok((format!("hdf5: {}", names.join(", ")), events, skipped))
    } else {
        if text_dirs.is_empty() {
            bail!("{}: no event folders with particle_*_vndata_*.dat files", dir.display());
        }
        for d in &text_dirs {
            match layout::read_text_event(d) {
                Ok(e) => events.push(e),
                Err(e) => skipped.push(SkippedEvent { event: file_name(d), reason: format!("{e:#}") }),
            }
        }
        Ok((format!("text: {} event folders", text_dirs.len()), events, skipped))
    }
}

/// Analyses the events of one design point: the observables (or why not),
/// with the jackknife covariance between the rows that are defined (every
/// pair of them, off the diagonal).
pub fn analyse_events_with_covariance(
    design_id: i64,
    events: &[Event],
    settings: &IngestSettings,
    skipped: &mut Vec<SkippedEvent>,
) -> Result<(Vec<IngestedRow>, Vec<crate::base::covariance::CovarianceEntry>)> {
    let species = analysis_species();
    // Per good event: one BinnedEvent per species (index 0 is charged, the reference).
    let mut binned: Vec<Vec<BinnedEvent>> = Vec::new();
    for ev in events {
        let parsed: Result<Vec<BinnedEvent>> = species
            .iter()
            .map(|(_, s)| {
                let name = s.kind.file_name();
                let f = ev.file(&name).ok_or_else(|| anyhow!("missing file {name}"))?;
                cumulants::binned_from_file(f)
            })
            .collect();
        match parsed {
            Ok(b) => {
                if let Some(first) = binned.first() {
                    if let Some(k) = (0..b.len()).find(|&k| first[k].pt.len() != b[k].pt.len()) {
                        skipped.push(SkippedEvent {
                            event: ev.label.clone(),
                            reason: format!(
                                "{} has {} rows, earlier events have {}",
                                species[k].1.kind.file_name(),
                                b[k].pt.len(),
                                first[k].pt.len()
                            ),
                        });
                        continue;
                    }
                }
                binned.push(b);
            }
            Err(e) => skipped.push(SkippedEvent { event: ev.label.clone(), reason: format!("{e:#}") }),
        }
    }
    if binned.len() < settings.min_events.max(2) {
        bail!("only {} good events (at least {} needed)", binned.len(), settings.min_events.max(2));
    }
    let n_ev = binned.len();
    let reference: Vec<BinnedEvent> = binned.iter().map(|b| b[0].clone()).collect();
    let mids: Vec<f64> = settings.pt_edges.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
    let mut rows = Vec::new();
    // Each row's leave-one-event-out replicates, per event: the events are
    // the same for every species, so rows of different species correlate too.
    let mut replicates: Vec<Vec<f64>> = vec![Vec::new(); n_ev];
    let nb = mids.len();
    for (k, (tag, s)) in species.iter().enumerate() {
        let evs: Vec<BinnedEvent> = binned.iter().map(|b| b[k].clone()).collect();
        let r = cumulants::analyse(s, &species[0].1.kind, &evs, &reference, &settings.pt_edges, settings.reference_pt)
            .with_context(|| tag.to_string())?;
        let kinds: &[(&str, usize)] =
            if *tag == "ch" { &[("spectrum", 0), ("v2", 1), ("v3", 2)] } else { &[("spectrum", 0), ("v2", 1)] };
        for &(kind, slot) in kinds {
            let est = if slot == 0 { &r.spectrum } else { &r.vn[slot - 1] };
            for (b, (x, e)) in mids.iter().zip(est).enumerate() {
                rows.push(IngestedRow {
                    design_id,
                    observable: format!("{tag}_{kind}"),
                    x: *x,
                    value: e.value,
                    error: e.error,
                    n_events: n_ev,
                });
                for (reps, r_ev) in replicates.iter_mut().zip(&r.replicates) {
                    reps.push(r_ev[slot * nb + b]);
                }
            }
        }
    }
    let cov = cumulants::jackknife_covariance(&replicates);
    let m = rows.len();
    let defined = |r: &IngestedRow| r.value.is_finite() && r.error.is_finite();
    let mut entries = Vec::new();
    for i in 0..m {
        for j in 0..i {
            let c = cov[i * m + j];
            if defined(&rows[i]) && defined(&rows[j]) && c.is_finite() {
                entries.push(crate::base::covariance::CovarianceEntry {
                    observable_a: rows[i].observable.clone(),
                    x_a: rows[i].x,
                    observable_b: rows[j].observable.clone(),
                    x_b: rows[j].x,
                    covariance: c,
                    line: 0,
                    rounding: 0.0,
                });
            }
        }
    }
    Ok((rows, entries))
}

/// Reads every design point folder under `runs_dir` (in parallel) and
/// analyses it. `design` (default: `runs_dir/design.parquet` if present) names
/// the expected points; points without a folder are reported.
pub fn ingest_runs(
    runs_dir: &Path,
    design: Option<&Path>,
    settings: &IngestSettings,
) -> Result<(Ingested, Option<DataFrame>)> {
    if settings.pt_edges.len() < 2 || settings.pt_edges.windows(2).any(|w| !(w[1] > w[0])) {
        bail!("--pt-bins: edges must be increasing, at least two (got {:?})", settings.pt_edges);
    }
    let folders = point_folders(runs_dir)?;
    let default_design = runs_dir.join("design.parquet");
    let design_path = design.map(Path::to_path_buf).or_else(|| default_design.exists().then_some(default_design));
    let design_df = design_path.as_deref().map(artifacts::read_parquet).transpose()?;
    let bar = crate::base::progress::bar(folders.len() as u64, "ingesting design points");
    type Cov = Vec<crate::base::covariance::CovarianceEntry>;
    let results: Vec<(PointReport, (Vec<IngestedRow>, Cov))> = folders
        .par_iter()
        .map(|(id, dir)| {
            let mut report = PointReport {
                design_id: *id,
                folder: dir.display().to_string(),
                source: String::new(),
                good_events: 0,
                skipped: Vec::new(),
                flagged: None,
                undefined_bins: Vec::new(),
            };
            let rows = match read_point_events(dir, settings.format) {
                Ok((source, events, mut skipped)) => {
                    report.source = source;
                    let before = skipped.len();
                    let r = analyse_events_with_covariance(*id, &events, settings, &mut skipped);
                    report.good_events = events.len() - (skipped.len() - before);
                    report.skipped = skipped;
                    r
                }
                Err(e) => Err(e),
            };
            bar.inc(1);
            match rows {
                Ok((rows, cov)) => {
                    let (good, bad): (Vec<IngestedRow>, Vec<IngestedRow>) =
                        rows.into_iter().partition(|r| r.value.is_finite() && r.error.is_finite());
                    report.undefined_bins = bad.iter().map(|r| format!("{}[{:.2}]", r.observable, r.x)).collect();
                    (report, (good, cov))
                }
                Err(e) => {
                    report.flagged = Some(format!("{e:#}"));
                    (report, (Vec::new(), Vec::new()))
                }
            }
        })
        .collect();
    bar.finish_and_clear();
    let missing_points = missing_points(&folders, design_df.as_ref(), design_path.as_deref())?;
    let (points, analysed): (Vec<PointReport>, Vec<(Vec<IngestedRow>, Cov)>) = results.into_iter().unzip();
    let covariance = points
        .iter()
        .zip(&analysed)
        .filter(|(_, (_, c))| !c.is_empty())
        .map(|(p, (_, c))| (p.design_id, c.clone()))
        .collect();
    let rows: Vec<Vec<IngestedRow>> = analysed.into_iter().map(|(r, _)| r).collect();
    // No config here: the analysis settings stand in for its hash.
    let settings_hash = artifacts::sha256_hex(format!("{settings:?}").as_bytes());
    let prov = Provenance::new(settings_hash, String::new(), 0, &format!("ingest {}", runs_dir.display()));
    Ok((
        Ingested {
            rows: rows.into_iter().flatten().collect(),
            covariance,
            report: IngestReport { runs_dir: runs_dir.display().to_string(), points, missing_points, provenance: prov },
        },
        design_df,
    ))
}

/// The design point folders of a runs folder (named by design id, e.g. `0007`), sorted.
/// A path's last component as text; the whole path where it has none (`..`).
fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

pub(crate) fn point_folders(runs_dir: &Path) -> Result<Vec<(i64, PathBuf)>> {
    let mut folders: Vec<(i64, PathBuf)> = Vec::new();
    for entry in std::fs::read_dir(runs_dir).with_context(|| format!("listing runs folder {}", runs_dir.display()))? {
        let path = entry?.path();
        if !path.is_dir() {
            continue;
        }
        let name = file_name(&path);
        // Hidden folders are staging areas of writes in progress (or interrupted).
        if name.starts_with('.') {
            continue;
        }
        if let Some(id) = design_id_of(&name) {
            folders.push((id, path));
        }
    }
    folders.sort();
    if folders.is_empty() {
        bail!(
            "{}: no design point folders (expected one folder per point, named by its design id, e.g. 0007)",
            runs_dir.display()
        );
    }
    for w in folders.windows(2) {
        if w[0].0 == w[1].0 {
            bail!("{} and {} both name design point {}", w[0].1.display(), w[1].1.display(), w[0].0);
        }
    }
    Ok(folders)
}

/// Design points without a folder; an error if a folder names a point the design lacks.
pub(crate) fn missing_points(
    folders: &[(i64, PathBuf)],
    design_df: Option<&DataFrame>,
    design_path: Option<&Path>,
) -> Result<Vec<i64>> {
    let (Some(df), Some(path)) = (design_df, design_path) else { return Ok(Vec::new()) };
    let ids = design_ids(df, path)?;
    if let Some((id, dir)) = folders.iter().find(|(f, _)| !ids.contains(f)) {
        bail!("{}: design point {id} is not in the design {}", dir.display(), path.display());
    }
    Ok(ids.iter().copied().filter(|id| !folders.iter().any(|(f, _)| f == id)).collect())
}

fn design_ids(df: &DataFrame, path: &Path) -> Result<Vec<i64>> {
    let c = df
        .column("design_id")
        .map_err(|_| anyhow!("{}: missing column 'design_id'", path.display()))?
        .cast(&DataType::Int64)?;
    let ca = c.i64()?;
    Ok((0..ca.len()).map(|i| ca.get(i).unwrap_or(-1)).collect())
}

/// The long table, with the design's parameter columns joined by design id.
pub fn to_frame(ingested: &Ingested, design: Option<&DataFrame>) -> Result<DataFrame> {
    let rows = &ingested.rows;
    let mut columns = vec![
        Column::new("design_id".into(), rows.iter().map(|r| r.design_id).collect::<Vec<_>>()),
        Column::new("observable".into(), rows.iter().map(|r| r.observable.clone()).collect::<Vec<_>>()),
        Column::new("x".into(), rows.iter().map(|r| r.x).collect::<Vec<_>>()),
        Column::new("value".into(), rows.iter().map(|r| r.value).collect::<Vec<_>>()),
        Column::new("error".into(), rows.iter().map(|r| r.error).collect::<Vec<_>>()),
        Column::new("n_events".into(), rows.iter().map(|r| r.n_events as i64).collect::<Vec<_>>()),
    ];
    if let Some(df) = design {
        let ids = design_ids(df, Path::new("design"))?;
        for name in df.get_column_names() {
            if name.as_str() == "design_id" {
                continue;
            }
            let c = df.column(name.as_str())?.cast(&DataType::Float64)?;
            let vals = c.f64()?;
            let joined: Vec<f64> = rows
                .iter()
                .map(|r| ids.iter().position(|&d| d == r.design_id).and_then(|i| vals.get(i)).unwrap_or(f64::NAN))
                .collect();
            columns.push(Column::new(name.clone(), joined));
        }
    }
    Ok(DataFrame::new(rows.len(), columns)?)
}

/// Writes the table (atomically) and `<table stem>.report.json` beside it.
pub fn write(ingested: &Ingested, design: Option<&DataFrame>, out: &Path) -> Result<PathBuf> {
    let mut df = to_frame(ingested, design)?;
    let report_path = out.with_extension("report.json");
    let mut staged = artifacts::StagedWrites::new();
    staged.parquet(out, &mut df, Some(&ingested.report.provenance))?;
    staged.json(&report_path, &ingested.report)?;
    // One point is a measurement: its bins' covariance goes beside it, for `[data] covariance`.
    if let Some(entries) = single_point_covariance(ingested) {
        staged.text(&covariance_path(out), &crate::base::covariance::covariance_csv(&entries))?;
    }
    // Several points are training runs: their errors' correlation goes beside
    // them, for the emulator to tell run noise from what it does not know.
    if let Some(entries) = pooled_noise_correlation(ingested) {
        staged.text(
            &crate::base::covariance::noise_correlation_path(out),
            &crate::base::covariance::noise_correlation_csv(&entries),
        )?;
    }
    staged.commit()?;
    Ok(report_path)
}

/// Where `write` puts a single point's covariance: `TABLE.covariance.csv`.
pub fn covariance_path(table: &Path) -> PathBuf {
    table.with_extension("covariance.csv")
}

/// The covariance of the only design point in the table, if it has one.
pub fn single_point_covariance(ingested: &Ingested) -> Option<Vec<crate::base::covariance::CovarianceEntry>> {
    let ids: std::collections::BTreeSet<i64> = ingested.rows.iter().map(|r| r.design_id).collect();
    let id = (ids.len() == 1).then(|| *ids.iter().next().unwrap())?;
    let kept = |o: &str, x: f64| ingested.rows.iter().any(|r| r.observable == o && r.x == x);
    Some(
        ingested
            .covariance
            .get(&id)?
            .iter()
            .filter(|e| kept(&e.observable_a, e.x_a) && kept(&e.observable_b, e.x_b))
            .cloned()
            .collect(),
    )
}

/// The runs' error correlation between two outputs, pooled over the design
/// points of the table: per pair, the mean over the points that measured
/// both of `C_ab / (e_a e_b)`, their jackknife covariance over their errors.
/// Bins of one run share its events (a multiplicity fluctuation moves every
/// bin of a spectrum), so a run's errors are far from independent. `None`
/// for fewer than two points or without covariances (tables from files).
pub fn pooled_noise_correlation(ingested: &Ingested) -> Option<Vec<crate::base::covariance::CovarianceEntry>> {
    type Pair = (String, u64, String, u64);
    let error: std::collections::HashMap<(i64, &str, u64), f64> =
        ingested.rows.iter().map(|r| ((r.design_id, r.observable.as_str(), r.x.to_bits()), r.error)).collect();
    let points = ingested.rows.iter().map(|r| r.design_id).collect::<std::collections::BTreeSet<i64>>();
    if points.len() < 2 {
        return None;
    }
    let mut sums: std::collections::BTreeMap<Pair, (f64, usize)> = std::collections::BTreeMap::new();
    for (id, entries) in &ingested.covariance {
        for e in entries {
            let ea = error.get(&(*id, e.observable_a.as_str(), e.x_a.to_bits()));
            let eb = error.get(&(*id, e.observable_b.as_str(), e.x_b.to_bits()));
            let (Some(&ea), Some(&eb)) = (ea, eb) else { continue };
            let r = e.covariance / (ea * eb);
            if r.is_finite() {
                let s = sums
                    .entry((e.observable_a.clone(), e.x_a.to_bits(), e.observable_b.clone(), e.x_b.to_bits()))
                    .or_insert((0.0, 0));
                s.0 += r;
                s.1 += 1;
            }
        }
    }
    if sums.is_empty() {
        return None;
    }
    let entries = sums
        .into_iter()
        .map(|((oa, xa, ob, xb), (sum, count))| crate::base::covariance::CovarianceEntry {
            observable_a: oa,
            x_a: f64::from_bits(xa),
            observable_b: ob,
            x_b: f64::from_bits(xb),
            covariance: (sum / count as f64).clamp(-1.0, 1.0),
            line: 0,
            rounding: 0.0,
        })
        .collect();
    Some(entries)
}
