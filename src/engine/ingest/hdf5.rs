//! iEBE-MUSIC's combined HDF5 file: one group per event (`spvn_results_<evid>`,
//! random letters appended on a name clash), one float32 gzip dataset per text
//! file named after it, and the file's first `#` line in a `header` attribute.
//! Read and written with the pure-Rust `hdf5-pure` crate (no libhdf5).

use super::layout::{Event, EventFile};
use anyhow::{anyhow, Context, Result};
use hdf5_pure::AttrValue;
use std::path::Path;

/// An event group that could not be read, with the reason.
#[derive(Clone, Debug)]
pub struct UnreadableEvent {
    pub label: String,
    pub reason: String,
}

fn attr_text(value: &AttrValue) -> Option<String> {
    let s = match value {
        AttrValue::String(s)
        | AttrValue::AsciiString(s)
        | AttrValue::VarLenString(s)
        | AttrValue::VarLenAsciiString(s) => s.clone(),
        AttrValue::StringSized { value, .. } | AttrValue::AsciiStringSized { value, .. } => value.clone(),
        AttrValue::U8Array(bytes) => String::from_utf8_lossy(bytes).into_owned(),
        _ => return None,
    };
    Some(s.trim_end_matches(['\0', '\n', '\r']).to_string())
}

/// At most this many values in one dataset (800 MB as f64): an iEBE-MUSIC
/// event file holds a few hundred.
const MAX_VALUES: usize = 100_000_000;

fn read_group(file: &hdf5_pure::File, path: &Path, label: &str) -> Result<Event> {
    let group = file.group(label).map_err(|e| anyhow!("{}:/{label}: cannot open group: {e}", path.display()))?;
    let mut files = Vec::new();
    let names = group.datasets().map_err(|e| anyhow!("{}:/{label}: cannot list datasets: {e}", path.display()))?;
    for name in names {
        let origin = format!("{}:/{label}/{name}", path.display());
        let ds = group.dataset(&name).map_err(|e| anyhow!("{origin}: cannot open dataset: {e}"))?;
        let shape = ds.shape().map_err(|e| anyhow!("{origin}: cannot read shape: {e}"))?;
        let (rows, columns) = match shape.as_slice() {
            [r, c] => (*r as usize, *c as usize),
            [r] => (*r as usize, 1),
            _ => return Err(anyhow!("{origin}: expected a 2-D table, found shape {shape:?}")),
        };
        // A damaged shape must not make the decoder allocate without bound:
        // deflate expands at most ~1032×, so no dataset holds more values than that.
        let file_bytes = std::fs::metadata(path).map(|m| m.len() as usize).unwrap_or(0);
        let most = (1100 * file_bytes / 4).min(MAX_VALUES);
        if rows.checked_mul(columns).is_none_or(|n| n > most) {
            return Err(anyhow!(
                "{origin}: shape {rows}×{columns} is impossible for a file of {file_bytes} bytes (damaged file?)"
            ));
        }
        let values = ds.read_f64().map_err(|e| anyhow!("{origin}: cannot read data: {e}"))?;
        if values.len() != rows * columns {
            return Err(anyhow!("{origin}: {} values for shape {rows}×{columns}", values.len()));
        }
        let header = ds.attrs().ok().and_then(|a| a.get("header").and_then(attr_text)).unwrap_or_default();
        files.push(EventFile { name, header, columns, values, origin });
    }
    files.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(Event { label: label.to_string(), files })
}

/// Reads every event group of a combined file. A group that cannot be read is
/// returned separately (reported and skipped by the caller); a file that cannot
/// be opened is an error.
pub fn read_events(path: &Path) -> Result<(Vec<Event>, Vec<UnreadableEvent>)> {
    crate::base::artifacts::without_panics(path, "HDF5", || read_events_unguarded(path))?
}

fn read_events_unguarded(path: &Path) -> Result<(Vec<Event>, Vec<UnreadableEvent>)> {
    let file = hdf5_pure::File::open(path).map_err(|e| anyhow!("{}: not a readable HDF5 file: {e}", path.display()))?;
    let mut labels = file.root().groups().map_err(|e| anyhow!("{}: cannot list event groups: {e}", path.display()))?;
    labels.sort();
    let (mut good, mut bad) = (Vec::new(), Vec::new());
    for label in labels {
        match read_group(&file, path, &label) {
            Ok(ev) => good.push(ev),
            Err(e) => bad.push(UnreadableEvent { label, reason: e.to_string() }),
        }
    }
    Ok((good, bad))
}

/// Writes events in the layout of iEBE-MUSIC's combine script (one float32
/// dataset per table, `header` attribute), to a temporary file renamed into
/// place. The script gzips each dataset; these are stored uncompressed:
/// deflate gains nothing on a few hundred sampled float32 values behind
/// per-dataset metadata (a stand-in design point of 1000 events takes
/// 10 266 978 bytes stored against 10 276 146 at level 1) and cost most of
/// the writing (0.11 s against 0.29 s; `mdpipe bench --heavy-ion-events
/// 1000`, docs/performance.md). Reading gzip datasets is tested on h5py's
/// files (`tests/fixtures/iebe_music`).
pub fn write_events(path: &Path, events: &[Event]) -> Result<()> {
    let mut builder = hdf5_pure::FileBuilder::new();
    for ev in events {
        let mut group = builder.create_group(&ev.label);
        for f in &ev.files {
            let data: Vec<f32> = f.values.iter().map(|&v| v as f32).collect();
            let rows = f.rows() as u64;
            group
                .create_dataset(&f.name)
                .with_f32_data(&data)
                .with_shape(&[rows, f.columns as u64])
                .set_attr("header", AttrValue::AsciiString(format!("{}\n", f.header)));
        }
        builder.add_group(group.finish());
    }
    let bytes = builder.finish().map_err(|e| anyhow!("{}: encoding HDF5: {e}", path.display()))?;
    crate::base::artifacts::write_atomic(path, |out| {
        use std::io::Write;
        out.write_all(&bytes).with_context(|| format!("writing {}", path.display()))
    })
}
