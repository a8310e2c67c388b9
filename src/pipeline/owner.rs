//! Which config an output folder belongs to. Two configs that share a
//! `name` (a copy edited in another folder, a colleague's variant) default
//! to the same `outputs/<name>`; run one after the other from the same
//! folder, the second would quietly redo the stages whose inputs differ and
//! move the first's diagnosis into `previous/`. The folder therefore keeps
//! the path of the config that last ran into it, and a run of another
//! config says so before it writes anything.

use crate::base::artifacts;
use anyhow::Result;
use std::path::Path;

/// The record's file name in the output folder.
const OWNER_FILE: &str = ".mdpipe-config";

/// The config that last ran into `out`, when it is not `config`; then
/// records `config` as the folder's. Both paths are compared canonical.
pub(super) fn claim(out: &Path, config: &Path) -> Result<Option<String>> {
    let mine = std::fs::canonicalize(config).unwrap_or_else(|_| config.to_path_buf()).display().to_string();
    let record = out.join(OWNER_FILE);
    let last = std::fs::read_to_string(&record).ok().map(|t| t.trim().to_string()).filter(|t| !t.is_empty());
    artifacts::write_text_atomic(&record, &format!("{mine}\n"))?;
    Ok(last.filter(|l| *l != mine))
}

/// The warning for a folder last written by `other`.
pub(super) fn shared_warning(out: &Path, config: &Path, other: &str) -> String {
    format!(
        "warning: {} was last written by another config, {other}; this run of {} shares it (the two share a name or an `out`). \
         Stages whose inputs differ are made again and the last diagnosis is moved to previous/; \
         give one of them its own `--out` (or `[run] out`) to keep both.",
        out.display(),
        config.display()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_config_into_the_same_folder_is_told_and_the_same_config_is_not() {
        let dir = std::env::temp_dir().join(format!("mdpipe-owner-{}", std::process::id()));
        let (out, a, b) = (dir.join("out"), dir.join("a.toml"), dir.join("b.toml"));
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(&a, "").unwrap();
        std::fs::write(&b, "").unwrap();
        assert_eq!(claim(&out, &a).unwrap(), None, "a new folder belongs to nobody yet");
        assert_eq!(claim(&out, &a).unwrap(), None, "the same config again");
        let other = claim(&out, &b).unwrap().expect("another config must be told");
        assert!(other.ends_with("a.toml"), "{other}");
        assert!(shared_warning(&out, &b, &other).contains("a.toml"));
        assert_eq!(claim(&out, &b).unwrap(), None, "the folder is now b's");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
