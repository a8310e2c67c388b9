//! The published data tables of Jaiswal et al. (2025): 15 whitespace-separated
//! columns, `pT` then (value, error) for each of seven heavy-ion observables.
//! A measurements format like CSV, read where measurements are read.

use super::measurement::{validate_row, Measurement};
use anyhow::{bail, Context, Result};
use std::path::Path;

/// Observable names of the paper's heavy-ion measurement tables, in column
/// order: `pT`, then (value, error) for each.
pub const PAPER_TABLE_OBSERVABLES: [(&str, &str); 7] = [
    ("CH:dN/d2pT", "ch_spectrum"),
    ("CH:v2", "ch_v2"),
    ("CH:v3", "ch_v3"),
    ("pi+:dN/d2pT", "pi_spectrum"),
    ("pi+:v2", "pi_v2"),
    ("p:dN/d2pT", "p_spectrum"),
    ("p:v2", "p_v2"),
];

/// Reads the 15-column tables of Jaiswal et al. (whitespace-separated, `#`
/// header): `pT` (GeV) then value/error pairs in the order of
/// [`PAPER_TABLE_OBSERVABLES`]. x = pT/(1 GeV).
pub fn read(path: &Path) -> Result<Vec<Measurement>> {
    let file = path.display();
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {file}"))?;
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line_no = k + 1;
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = t.split_whitespace().collect();
        if cells.len() != 15 {
            bail!(
                "{file}: line {line_no}: expected 15 columns (pT, then value and error for {}), found {}",
                PAPER_TABLE_OBSERVABLES.map(|o| o.0).join(", "),
                cells.len()
            );
        }
        let num = |c: usize, field: String| -> Result<f64> {
            cells[c].parse::<f64>().map_err(|_| {
                let problem = format!("cannot parse {:?} as a number", cells[c]);
                anyhow::Error::from(super::error::FieldError::new(path, format!("line {line_no}"), &field, problem))
            })
        };
        let pt = num(0, "pT".into())?;
        for (j, (column, name)) in PAPER_TABLE_OBSERVABLES.iter().enumerate() {
            let m = Measurement {
                observable: name.to_string(),
                x: pt,
                value: num(1 + 2 * j, column.to_string())?,
                error: num(2 + 2 * j, format!("{column}_err"))?,
                line: line_no,
            };
            validate_row(path, &format!("line {line_no}"), &m).with_context(|| format!("column {column}"))?;
            out.push(m);
        }
    }
    Ok(out)
}
