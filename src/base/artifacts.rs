//! On-disk formats: the measurements table, Parquet/JSON artifacts with
//! provenance, and atomic writes (temporary file, then rename).
//!
//! Measurements schema (CSV or Parquet): `observable: str, x: f64, value: f64,
//! error: f64` with `error` the 1σ measurement uncertainty. The paper's
//! 15-column heavy-ion tables (`.dat`, `base::paper_table`) are read as
//! measurements too.

use super::measurement::validate_row_with;
pub use super::measurement::Measurement;
use anyhow::{anyhow, bail, Context, Result};
use polars::prelude::*;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// Where a run came from: written into every artifact.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct Provenance {
    pub mdpipe_version: String,
    pub config_hash: String,
    pub data_hash: String,
    pub seed: u64,
    pub command: String,
}

impl Provenance {
    pub fn new(config_hash: String, data_hash: String, seed: u64, command: &str) -> Self {
        Provenance {
            mdpipe_version: env!("CARGO_PKG_VERSION").to_string(),
            config_hash,
            data_hash,
            seed,
            command: command.to_string(),
        }
    }

    pub fn key_values(&self) -> Vec<(String, String)> {
        vec![
            ("mdpipe_version".into(), self.mdpipe_version.clone()),
            ("config_hash".into(), self.config_hash.clone()),
            ("data_hash".into(), self.data_hash.clone()),
            ("seed".into(), self.seed.to_string()),
            ("command".into(), self.command.clone()),
        ]
    }
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// Hash of the measurements themselves (not of the file's formatting).
pub fn measurements_hash(data: &[Measurement]) -> String {
    let mut h = Sha256::new();
    for m in data {
        h.update(m.observable.as_bytes());
        for v in [m.x, m.value, m.error] {
            h.update(v.to_le_bytes());
        }
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// This machine's host name ("" where none can be read).
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::env::var("HOSTNAME"))
        .map(|h| h.trim().to_string())
        .unwrap_or_default()
}

/// A sibling name no other writer uses: SLURM array tasks on different nodes
/// of a shared file system can have the same PID, so the name also carries
/// the host, the time and a per-process counter.
fn temp_path(path: &Path) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().map(|s| s.to_string_lossy().to_string()).unwrap_or_default();
    let host = host_name();
    let nanos =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.subsec_nanos()).unwrap_or(0);
    path.with_file_name(format!(
        ".{name}.tmp-{}-{}-{nanos}-{}",
        host,
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ))
}

/// The files of one result, each written to a temporary sibling and all
/// renamed into place only once every one is written. A failure part way (a
/// full disk, a read-only folder) removes the temporary files and leaves the
/// previous set whole: old and new artifacts are never mixed. Renames need no
/// space, so a full disk cannot stop the commit half done.
#[derive(Default)]
pub struct StagedWrites {
    /// (temporary sibling, final path), in the order written.
    pending: Vec<(PathBuf, PathBuf)>,
}

impl StagedWrites {
    pub fn new() -> Self {
        StagedWrites::default()
    }

    /// Writes `path`'s content through `write` into its temporary sibling.
    pub fn write(&mut self, path: &Path, write: impl FnOnce(&mut std::fs::File) -> Result<()>) -> Result<()> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating directory {}", dir.display()))?;
        }
        let tmp = temp_path(path);
        let result: Result<()> = (|| {
            let mut f = std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
            write(&mut f)?;
            // A full disk on a network file system may only show at sync.
            f.sync_all().with_context(|| format!("syncing {}", tmp.display()))?;
            Ok(())
        })();
        if let Err(e) = result {
            let _ = std::fs::remove_file(&tmp);
            self.abandon();
            return Err(e.context(format!(
                "writing {} failed; nothing of this result was put in place, the previous artifacts are as they were",
                path.display()
            )));
        }
        self.pending.push((tmp, path.to_path_buf()));
        Ok(())
    }

    pub fn text(&mut self, path: &Path, text: &str) -> Result<()> {
        use std::io::Write;
        self.write(path, |f| Ok(f.write_all(text.as_bytes())?))
    }

    pub fn json<T: serde::Serialize>(&mut self, path: &Path, value: &T) -> Result<()> {
        self.text(path, &serde_json::to_string_pretty(value)?)
    }

    /// A DataFrame as Parquet, with provenance in the file's key-value metadata.
    pub fn parquet(&mut self, path: &Path, df: &mut DataFrame, provenance: Option<&Provenance>) -> Result<()> {
        // Encoded in memory, then written: the Parquet writer reports a
        // failed write as a malformed file ("Invalid thrift"), which would
        // hide a full disk from the user; `write_all` keeps the OS's reason.
        let kv = provenance.map(|p| KeyValueMetadata::from_static(p.key_values()));
        let mut bytes = Vec::new();
        ParquetWriter::new(&mut bytes).with_key_value_metadata(kv).finish(df)?;
        self.write(path, |f| {
            use std::io::Write;
            Ok(f.write_all(&bytes)?)
        })
    }

    /// Renames every file into place, in the order written.
    pub fn commit(mut self) -> Result<()> {
        let pending = std::mem::take(&mut self.pending);
        for (k, (tmp, path)) in pending.iter().enumerate() {
            if let Err(e) = std::fs::rename(tmp, path) {
                // The ones not renamed, this one included, leave no temporary files.
                pending[k..].iter().for_each(|(t, _)| {
                    let _ = std::fs::remove_file(t);
                });
                return Err(e).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()));
            }
        }
        Ok(())
    }

    fn abandon(&mut self) {
        for (tmp, _) in self.pending.drain(..) {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

impl Drop for StagedWrites {
    /// A result dropped before its commit (an error elsewhere) leaves no temporary files.
    fn drop(&mut self) {
        self.abandon();
    }
}

/// Fails at once, before hours of work, when `dir` (or, if it does not exist
/// yet, its nearest existing ancestor) cannot take a new file: a read-only
/// mount, missing permissions. A full disk only shows when writing.
pub fn check_writable(dir: &Path) -> Result<()> {
    let existing = dir.ancestors().find(|a| a.as_os_str().is_empty() || a.is_dir()).unwrap_or(Path::new("."));
    let existing = if existing.as_os_str().is_empty() { Path::new(".") } else { existing };
    let probe = temp_path(&existing.join("write-probe"));
    std::fs::File::create(&probe).map_err(|e| {
        anyhow!(
            "{}: the output folder is not writable ({e}); nothing was run, and what it holds is as it was",
            dir.display()
        )
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Writes through `write` into a temporary sibling, then renames it into place,
/// so readers never see a half-written artifact.
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut std::fs::File) -> Result<()>) -> Result<()> {
    let mut staged = StagedWrites::new();
    staged.write(path, write)?;
    staged.commit()
}

pub fn write_text_atomic(path: &Path, text: &str) -> Result<()> {
    let mut staged = StagedWrites::new();
    staged.text(path, text)?;
    staged.commit()
}

pub fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let mut staged = StagedWrites::new();
    staged.json(path, value)?;
    staged.commit()
}

/// Writes a DataFrame as Parquet with provenance in the file's key-value metadata.
pub fn write_parquet_atomic(path: &Path, df: &mut DataFrame, provenance: Option<&Provenance>) -> Result<()> {
    let mut staged = StagedWrites::new();
    staged.parquet(path, df, provenance)?;
    staged.commit()
}

pub use super::table::{read_parquet, without_panics};

/// Builds a DataFrame from named f64 columns (all the same length).
pub fn f64_frame(columns: Vec<(String, Vec<f64>)>) -> Result<DataFrame> {
    let height = columns.first().map(|c| c.1.len()).unwrap_or(0);
    let cols: Vec<Column> = columns.into_iter().map(|(name, v)| Column::new(name.into(), v)).collect();
    Ok(DataFrame::new(height, cols)?)
}

/// Reads a measurements table, CSV or Parquet by extension, validating every row.
pub fn read_measurements(path: &Path) -> Result<Vec<Measurement>> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let rows = match ext.as_str() {
        "dat" => super::paper_table::read(path)?,
        "yaml" | "yml" => super::hepdata::read(path, &Default::default())?.measurements(),
        _ => read_measurements_table(path)?,
    };
    if rows.is_empty() {
        bail!("{}: no measurements in file", path.display());
    }
    Ok(rows)
}

/// Measurements from a CSV or Parquet long table, each row checked.
fn read_measurements_table(path: &Path) -> Result<Vec<Measurement>> {
    measurements_of(path, &super::table::RawTable::read(path)?)
}

/// Measurements and their systematic sources (`base::systematics`: a CSV or
/// Parquet table's `sys:<name>` columns, each scoped as `scopes` says); no
/// sources for the other formats.
pub fn read_measurements_with_sources(
    path: &Path,
    scopes: &std::collections::BTreeMap<String, super::systematics::Scope>,
) -> Result<(Vec<Measurement>, Vec<super::systematics::SourcedPoint>)> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    if matches!(ext.as_str(), "dat" | "yaml" | "yml") {
        if let Some(name) = scopes.keys().next() {
            bail!(
                "[data] systematics: {name:?}: {} has no sys:<name> columns (a .dat or HEPData file)",
                path.display()
            );
        }
        return Ok((read_measurements(path)?, Vec::new()));
    }
    let raw = super::table::RawTable::read(path)?;
    let rows = measurements_of(path, &raw)?;
    if rows.is_empty() {
        bail!("{}: no measurements in file", path.display());
    }
    let sources = super::systematics::read_sources(path, &raw, &rows, scopes)?;
    Ok((rows, sources))
}

/// The rows of a long table: `observable, x, value` and the measurement's
/// own error, as `error` or, where the systematics are columns of their
/// own, `stat`.
fn measurements_of(path: &Path, raw: &super::table::RawTable) -> Result<Vec<Measurement>> {
    if raw.has("error") && raw.has("stat") {
        bail!("{}: columns 'error' and 'stat' both: give the measurement's own error once ('stat' beside sys:<name> columns)", path.display());
    }
    let error_column = if raw.has("stat") { "stat" } else { "error" };
    let expected = |e: anyhow::Error| match e.downcast::<super::error::ColumnError>() {
        Ok(missing) => missing.expecting(&["observable", "x", "value", "error"]).into(),
        Err(other) => other,
    };
    let observables = raw.strings(path, "observable").map_err(expected)?;
    let num = |name: &str| raw.numbers(path, name).map_err(expected);
    let (x, value, error) = (num("x")?, num("value")?, num(error_column)?);
    let mut out = Vec::with_capacity(raw.height());
    for i in 0..raw.height() {
        let m = Measurement {
            observable: observables[i].clone(),
            x: x[i],
            value: value[i],
            error: error[i],
            line: raw.line(i),
        };
        validate_row_with(path, &raw.location(i), &m, error_column)?;
        out.push(m);
    }
    Ok(out)
}

/// Writes measurements as CSV or Parquet by extension.
pub fn write_measurements(path: &Path, data: &[Measurement], provenance: Option<&Provenance>) -> Result<()> {
    let mut staged = StagedWrites::new();
    stage_measurements(&mut staged, path, data, provenance)?;
    staged.commit()
}

/// Writes measurements as CSV or Parquet by extension, as part of a staged result.
pub fn stage_measurements(
    staged: &mut StagedWrites,
    path: &Path,
    data: &[Measurement],
    provenance: Option<&Provenance>,
) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    if ext == "parquet" || ext == "pq" {
        let obs: Vec<&str> = data.iter().map(|m| m.observable.as_str()).collect();
        let mut df = DataFrame::new(
            data.len(),
            vec![
                Column::new("observable".into(), obs),
                Column::new("x".into(), data.iter().map(|m| m.x).collect::<Vec<_>>()),
                Column::new("value".into(), data.iter().map(|m| m.value).collect::<Vec<_>>()),
                Column::new("error".into(), data.iter().map(|m| m.error).collect::<Vec<_>>()),
            ],
        )?;
        staged.parquet(path, &mut df, provenance)
    } else {
        let mut text = String::new();
        if let Some(p) = provenance {
            text.push_str(&format!("# mdpipe {} | {} | seed {}\n", p.mdpipe_version, p.command, p.seed));
        }
        text.push_str("observable,x,value,error\n");
        for m in data {
            text.push_str(&format!("{},{},{},{}\n", m.observable, m.x, m.value, m.error));
        }
        staged.text(path, &text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rename_that_fails_leaves_no_temporary_files() {
        let dir = tmpdir("rename-fails");
        std::fs::create_dir_all(dir.join("taken")).unwrap();
        let mut staged = StagedWrites::new();
        staged.text(&dir.join("first.txt"), "a").unwrap();
        staged.text(&dir.join("taken"), "b").unwrap();
        staged.text(&dir.join("third.txt"), "c").unwrap();
        let err = staged.commit().expect_err("a directory in the way").to_string();
        assert!(err.contains("taken"), "{err}");
        let left: Vec<String> =
            std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into()).collect();
        assert!(left.iter().all(|f| !f.contains(".tmp")), "{left:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn tmpdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("mdpipe-artifacts-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn measurements_round_trip_csv_and_parquet() {
        let data = vec![Measurement::new("height", 0.1, 59.9, 0.1), Measurement::new("velocity", 0.2, 1.9, 0.2)];
        let d = tmpdir("rt");
        for name in ["m.csv", "m.parquet"] {
            let p = d.join(name);
            write_measurements(&p, &data, None).unwrap();
            assert_eq!(read_measurements(&p).unwrap(), data);
        }
    }

    #[test]
    fn csv_errors_name_file_line_and_field() {
        let d = tmpdir("bad");
        let p = d.join("bad.csv");
        std::fs::write(&p, "observable,x,value,error\nheight,0.1,59.9,0.1\nheight,0.2,NaN,0.1\n").unwrap();
        let msg = format!("{:#}", read_measurements(&p).unwrap_err());
        assert!(msg.contains("bad.csv") && msg.contains("line 3") && msg.contains("'value'"), "{msg}");

        std::fs::write(&p, "observable,x,value,error\nheight,0.1,59.9,-0.1\n").unwrap();
        let msg = format!("{:#}", read_measurements(&p).unwrap_err());
        assert!(msg.contains("line 2") && msg.contains("'error'"), "{msg}");

        std::fs::write(&p, "observable,x,value\nheight,0.1,59.9\n").unwrap();
        let msg = format!("{:#}", read_measurements(&p).unwrap_err());
        assert!(msg.contains("missing column 'error'"), "{msg}");
    }
}
