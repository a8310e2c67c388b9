//! iEBE-MUSIC's per-event output files: names, text form, and the in-memory
//! [`Event`] that both the text and the HDF5 readers produce.
//!
//! Differential files `particle_<pid>_vndata_diff_{eta|y}_<lo>_<hi>.dat`
//! (compact layout): `pT, dN/(2π pT dpT dy), Re v_1, Im v_1, …, Re v_{k}, Im v_{k}, N`
//! with k = order_max − 1 (order_max 10 for charged hadrons, pid 9999, and 6 for
//! identified particles). Integrated files `particle_<pid>_vndata_{eta|y}_<lo>_<hi>.dat`:
//! a row `0, dN/dy, err, <pT>, err`, rows `n, Re v_n, err, Im v_n, err`, and a
//! last row `99, total_N, N_events, 0, 0`.

use anyhow::{anyhow, bail, Context, Result};
use std::path::Path;

/// pid iEBE-MUSIC uses for all charged hadrons.
pub const CHARGED_PID: i32 = 9999;

/// Rapidity variable of a file's acceptance window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Window {
    /// Pseudorapidity (charged hadrons).
    Eta,
    /// Rapidity (identified particles).
    Y,
}

impl Window {
    fn tag(self) -> &'static str {
        match self {
            Window::Eta => "eta",
            Window::Y => "y",
        }
    }
}

/// What a file name says: particle, window, and whether it is pT-differential.
#[derive(Clone, Debug, PartialEq)]
pub struct FileKind {
    pub pid: i32,
    pub differential: bool,
    pub window: Window,
    pub lo: f64,
    pub hi: f64,
}

impl FileKind {
    pub fn diff(pid: i32, window: Window, lo: f64, hi: f64) -> FileKind {
        FileKind { pid, differential: true, window, lo, hi }
    }

    /// The file name, with bounds printed C-style (`-0.5_0.5`).
    pub fn file_name(&self) -> String {
        let diff = if self.differential { "diff_" } else { "" };
        format!("particle_{}_vndata_{diff}{}_{}_{}.dat", self.pid, self.window.tag(), self.lo, self.hi)
    }

    /// Parses a name like `particle_211_vndata_diff_y_-0.5_0.5.dat`.
    pub fn parse(name: &str) -> Option<FileKind> {
        let rest = name.strip_prefix("particle_")?.strip_suffix(".dat")?;
        let (pid, rest) = rest.split_once("_vndata_")?;
        let (differential, rest) = match rest.strip_prefix("diff_") {
            Some(r) => (true, r),
            None => (false, rest),
        };
        let (window, rest) = if let Some(r) = rest.strip_prefix("eta_") {
            (Window::Eta, r)
        } else {
            (Window::Y, rest.strip_prefix("y_")?)
        };
        // Bounds may be negative: split at the '_' that follows the first number.
        let split = rest.char_indices().skip(1).find(|&(_, c)| c == '_')?.0;
        let (lo, hi) = (rest[..split].parse().ok()?, rest[split + 1..].parse().ok()?);
        Some(FileKind { pid: pid.parse().ok()?, differential, window, lo, hi })
    }
}

/// One output file of one event: a rectangular table of numbers.
#[derive(Clone, Debug, PartialEq)]
pub struct EventFile {
    pub name: String,
    /// The file's first `#` line (without the newline).
    pub header: String,
    pub columns: usize,
    /// Row-major values.
    pub values: Vec<f64>,
    /// Where the table came from, for error messages: a path, or `file.h5:/group/dataset`.
    pub origin: String,
}

impl EventFile {
    pub fn rows(&self) -> usize {
        self.values.len().checked_div(self.columns).unwrap_or(0)
    }

    pub fn row(&self, i: usize) -> &[f64] {
        &self.values[i * self.columns..(i + 1) * self.columns]
    }

    /// The text form iEBE-MUSIC writes: the header line, then one row per line.
    pub fn to_text(&self) -> String {
        let mut s = String::with_capacity(self.values.len() * 14 + self.header.len() + 2);
        s.push_str(&self.header);
        s.push('\n');
        for i in 0..self.rows() {
            let line: Vec<String> = self.row(i).iter().map(|v| format!("{v:.6e}")).collect();
            s.push_str(&line.join("  "));
            s.push('\n');
        }
        s
    }
}

/// One event's files, as found in a text folder or an HDF5 group.
#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    /// Event folder or HDF5 group name, e.g. `spvn_results_7`.
    pub label: String,
    pub files: Vec<EventFile>,
}

impl Event {
    pub fn file(&self, name: &str) -> Option<&EventFile> {
        self.files.iter().find(|f| f.name == name)
    }
}

/// Parses one whitespace-separated text table; every error names the file,
/// line and column.
pub fn parse_text_table(path: &Path, text: &str) -> Result<EventFile> {
    let file = path.display();
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
    let mut header = String::new();
    let mut columns = 0;
    let mut values = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line_no = k + 1;
        let trimmed = line.trim();
        if trimmed.starts_with('#') {
            if header.is_empty() {
                header = trimmed.to_string();
            }
            continue;
        }
        if trimmed.is_empty() {
            continue;
        }
        let before = values.len();
        for (c, field) in trimmed.split_whitespace().enumerate() {
            let v: f64 = field
                .parse()
                .map_err(|_| anyhow!("{file}: line {line_no}, column {}: cannot parse {field:?} as a number", c + 1))?;
            values.push(v);
        }
        let n = values.len() - before;
        if columns == 0 {
            columns = n;
        } else if n != columns {
            bail!("{file}: line {line_no}: {n} columns, but earlier rows have {columns}");
        }
    }
    if values.is_empty() {
        bail!("{file}: no data rows");
    }
    Ok(EventFile { name, header, columns, values, origin: path.display().to_string() })
}

/// Reads every `particle_*_vndata_*.dat` file in one event folder.
pub fn read_text_event(dir: &Path) -> Result<Event> {
    let label = dir.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let path = entry?.path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else { continue };
        if FileKind::parse(name).is_none() {
            continue;
        }
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        files.push(parse_text_table(&path, &text)?);
    }
    files.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(Event { label, files })
}

/// Whether a folder holds an event's text files.
pub fn is_text_event_dir(dir: &Path) -> bool {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok()).any(|e| e.file_name().to_str().is_some_and(|n| FileKind::parse(n).is_some()))
        })
        .unwrap_or(false)
}

/// Writes one event as a folder of text files (atomically per file).
pub fn write_text_event(dir: &Path, event: &Event) -> Result<()> {
    let folder = dir.join(&event.label);
    std::fs::create_dir_all(&folder).with_context(|| format!("creating {}", folder.display()))?;
    for f in &event.files {
        crate::base::artifacts::write_text_atomic(&folder.join(&f.name), &f.to_text())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_round_trip_with_c_style_bounds() {
        let k = FileKind::diff(CHARGED_PID, Window::Eta, -0.5, 0.5);
        assert_eq!(k.file_name(), "particle_9999_vndata_diff_eta_-0.5_0.5.dat");
        assert_eq!(FileKind::parse(&k.file_name()), Some(k));
        let i = FileKind::parse("particle_2212_vndata_y_-1_2.5.dat").unwrap();
        assert_eq!((i.pid, i.differential, i.window, i.lo, i.hi), (2212, false, Window::Y, -1.0, 2.5));
        assert_eq!(FileKind::parse("particle_211_vndata_diff_y_-0.5.dat"), None);
    }

    #[test]
    fn text_tables_name_line_and_column_on_error() {
        let p = Path::new("ev/particle_211_vndata_diff_y_-0.5_0.5.dat");
        let ok = parse_text_table(p, "# pT dN\n0.05 1.0\n0.15 2.0\n").unwrap();
        assert_eq!((ok.rows(), ok.columns, ok.header.as_str()), (2, 2, "# pT dN"));
        let e = parse_text_table(p, "# h\n0.05 1.0\n0.15 x\n").unwrap_err().to_string();
        assert!(e.contains("line 3, column 2") && e.contains("ev/particle_211"), "{e}");
        let e = parse_text_table(p, "0.05 1.0\n0.15\n").unwrap_err().to_string();
        assert!(e.contains("line 2: 1 columns"), "{e}");
    }
}
