//! The `[run.simulator]` table: how to run the user's simulator at one design
//! point, and what it must leave behind.

use anyhow::{anyhow, bail, Result};
use std::collections::BTreeMap;
use std::path::Path;

/// What a successful point leaves in its folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OutputKind {
    /// iEBE-MUSIC's layout, read by `ingest`: `spvn_results.h5` and/or
    /// `spvn_results_<i>/` event folders.
    IebeMusic,
    /// One table of outputs, `outputs.csv` or `outputs.parquet`, with columns
    /// `observable, x, value` (and optionally `error`).
    Table,
    /// Success is exit code 0; the command writes its results elsewhere
    /// (mdpipe's own calibration cases as array tasks).
    Exit,
}

/// `[run.simulator]`.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SimulatorSpec {
    /// Shell command for one point, run from the design folder. Substituted:
    /// `{point}` (the folder the point's outputs go to), `{param_file}` (its
    /// iEBE-MUSIC parameter file), `{id}`, `{design}` (design.parquet),
    /// `{mdpipe}` (this executable), `{seed}` (a seed of the point's own),
    /// `{config_dir}` (the config's folder, in `mdpipe run`),
    /// `{<parameter>}` for each design parameter and `{<name>}` for each of
    /// `placeholders`.
    pub command: String,
    /// Values of the command's own placeholders, e.g. `{ radiation = "off" }`
    /// for `--radiation {radiation}`: a diagnose candidate switches its
    /// physics on by giving one another value.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub placeholders: BTreeMap<String, String>,
    pub output: OutputKind,
    /// Wall-time limit of one attempt: "90s", "20m", "2h", "HH:MM:SS" or "D-HH:MM:SS".
    #[serde(default = "default_time_limit")]
    pub time_limit: String,
    /// Attempts after the first for a point that fails or times out.
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// Points run at once by the local executor (default: the number of cores);
    /// array tasks at once under Slurm (default: no limit).
    #[serde(default)]
    pub parallel: Option<usize>,
    /// Settings of `--executor slurm`.
    #[serde(default)]
    pub slurm: SlurmSettings,
}

/// `[run.simulator.slurm]`: the `sbatch` options of each array task.
#[derive(Clone, Debug, Default, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SlurmSettings {
    pub partition: Option<String>,
    pub account: Option<String>,
    pub cpus_per_task: Option<u32>,
    pub mem: Option<String>,
    /// Further `sbatch` arguments, e.g. ["--qos=short"].
    #[serde(default)]
    pub extra: Vec<String>,
    /// Seconds between `squeue` polls (default 10).
    pub poll_seconds: Option<f64>,
}

fn default_time_limit() -> String {
    "1h".into()
}
fn default_retries() -> u32 {
    1
}

impl SimulatorSpec {
    /// Checks the spec against the design's parameter names, naming the field at fault.
    pub fn validate(&self, parameters: &[String]) -> Result<()> {
        if self.command.trim().is_empty() {
            bail!("command is empty");
        }
        seconds_of(&self.time_limit).map_err(|e| anyhow!("time_limit: {e}"))?;
        if self.parallel == Some(0) {
            bail!("parallel must be at least 1");
        }
        if self.slurm.poll_seconds.is_some_and(|p| !(p > 0.0)) {
            bail!("slurm.poll_seconds must be positive");
        }
        if let Some(name) = self.placeholders.keys().find(|k| BUILT_IN.contains(&k.as_str()) || parameters.contains(k))
        {
            bail!(
                "placeholders: {{{name}}} is already the point's own (a design parameter or one of {})",
                BUILT_IN.join(", ")
            );
        }
        let known: Vec<&str> = BUILT_IN
            .into_iter()
            .chain(parameters.iter().map(String::as_str))
            .chain(self.placeholders.keys().map(String::as_str))
            .collect();
        for name in placeholders(&self.command) {
            if !known.contains(&name.as_str()) {
                bail!(
                    "command: unknown placeholder {{{name}}} (known: {})",
                    known.iter().map(|k| format!("{{{k}}}")).collect::<Vec<_>>().join(", ")
                );
            }
        }
        Ok(())
    }

    pub fn time_limit_seconds(&self) -> u64 {
        seconds_of(&self.time_limit).unwrap_or(3600)
    }

    /// The command for one point, every placeholder replaced.
    pub fn render(&self, point: &PointPaths, values: &BTreeMap<String, f64>) -> String {
        let mut cmd = self.command.clone();
        let quoted = |p: &Path| shell_quote(&p.display().to_string());
        for (name, value) in &self.placeholders {
            cmd = cmd.replace(&format!("{{{name}}}"), value);
        }
        for (name, value) in [
            ("seed", point.seed.to_string()),
            ("point", quoted(&point.folder)),
            ("param_file", quoted(&point.param_file)),
            ("id", point.id.to_string()),
            ("design", quoted(&point.design)),
            ("mdpipe", quoted(&point.mdpipe)),
        ] {
            cmd = cmd.replace(&format!("{{{name}}}"), &value);
        }
        for (name, v) in values {
            cmd = cmd.replace(&format!("{{{name}}}"), &format!("{v}"));
        }
        cmd
    }
}

impl SimulatorSpec {
    /// The command as one task of a design's Slurm array script, run from the
    /// design folder: the point's folder is `runs/NNNN`, each parameter's
    /// value is read from the point's parameter file (`parameters` gives
    /// each name's file key) and `{seed}` is `seed_base` + the task id, as the
    /// executors give it. `{param_file}` and `{id}` are left for the script
    /// writer (`engine::design::write_points`).
    pub fn array_command(&self, parameters: &[(String, String)], seed_base: u64, mdpipe: &Path) -> String {
        let point = "runs/$(printf '%04d' $SLURM_ARRAY_TASK_ID)";
        let mut cmd = self.command.clone();
        for (name, value) in &self.placeholders {
            cmd = cmd.replace(&format!("{{{name}}}"), value);
        }
        for (name, key) in parameters {
            let read = format!("$(awk -v k={} '$1 == k {{ print $2 }}' {{param_file}})", shell_quote(key));
            cmd = cmd.replace(&format!("{{{name}}}"), &read);
        }
        for (name, value) in [
            ("point", format!("\"{point}\"")),
            ("design", "design.parquet".to_string()),
            ("mdpipe", shell_quote(&mdpipe.display().to_string())),
            ("seed", format!("$(({seed_base} + SLURM_ARRAY_TASK_ID))")),
        ] {
            cmd = cmd.replace(&format!("{{{name}}}"), &value);
        }
        format!("mkdir -p \"{point}\"\n{cmd}")
    }
}

/// The placeholders every command may use.
pub const BUILT_IN: [&str; 6] = ["point", "param_file", "id", "design", "mdpipe", "seed"];

/// The placeholders a command uses, in order.
pub fn placeholders_of(command: &str) -> Vec<String> {
    placeholders(command)
}

/// The paths substituted into one point's command.
pub struct PointPaths {
    pub id: i64,
    /// The point's own seed, for a stochastic simulator.
    pub seed: u64,
    pub folder: std::path::PathBuf,
    pub param_file: std::path::PathBuf,
    pub design: std::path::PathBuf,
    pub mdpipe: std::path::PathBuf,
}

fn placeholders(command: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = command;
    while let Some(open) = rest.find('{') {
        let Some(close) = rest[open..].find('}') else { break };
        let name = &rest[open + 1..open + close];
        // Shell braces such as ${HOME} or {a,b} are not ours.
        let is_ours =
            !name.is_empty() && name.chars().all(|c| c.is_alphanumeric() || c == '_') && !rest[..open].ends_with('$');
        if is_ours {
            out.push(name.to_string());
        }
        rest = &rest[open + close + 1..];
    }
    out
}

/// Single-quotes a string for bash.
pub fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// Seconds in a time limit: "90s", "20m", "2h", "MM:SS", "HH:MM:SS", "D-HH:MM:SS" or plain seconds.
pub fn seconds_of(text: &str) -> Result<u64> {
    let t = text.trim();
    let bad = || anyhow!("{text:?} is not a time limit (use e.g. \"90s\", \"20m\", \"2h\" or \"HH:MM:SS\")");
    let seconds = if let Some(n) = t.strip_suffix('s') {
        n.trim().parse::<f64>().map_err(|_| bad())?
    } else if let Some(n) = t.strip_suffix('m') {
        60.0 * n.trim().parse::<f64>().map_err(|_| bad())?
    } else if let Some(n) = t.strip_suffix('h') {
        3600.0 * n.trim().parse::<f64>().map_err(|_| bad())?
    } else {
        let (days, clock) = match t.split_once('-') {
            Some((d, c)) => (d.parse::<f64>().map_err(|_| bad())?, c),
            None => (0.0, t),
        };
        let parts: Vec<f64> = clock.split(':').map(|p| p.parse::<f64>().map_err(|_| bad())).collect::<Result<_>>()?;
        let clock_seconds = match parts.as_slice() {
            [s] => *s,
            [m, s] => m * 60.0 + s,
            [h, m, s] => h * 3600.0 + m * 60.0 + s,
            _ => return Err(bad()),
        };
        days * 86_400.0 + clock_seconds
    };
    if !(seconds >= 1.0 && seconds.is_finite()) {
        return Err(bad());
    }
    Ok(seconds.ceil() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_limits_in_the_forms_slurm_users_write() {
        assert_eq!(seconds_of("90s").unwrap(), 90);
        assert_eq!(seconds_of("20m").unwrap(), 1200);
        assert_eq!(seconds_of("2h").unwrap(), 7200);
        assert_eq!(seconds_of("01:30").unwrap(), 90);
        assert_eq!(seconds_of("12:00:00").unwrap(), 43_200);
        assert_eq!(seconds_of("1-00:00:10").unwrap(), 86_410);
        assert!(seconds_of("soon").is_err() && seconds_of("0s").is_err() && seconds_of("1:2:3:4").is_err());
    }

    #[test]
    fn placeholders_are_checked_and_shell_braces_left_alone() {
        let spec: SimulatorSpec =
            toml::from_str("command = \"run.sh {param_file} {point} {eta_s} ${HOME} {a,b}\"\noutput = \"table\"")
                .unwrap();
        spec.validate(&["eta_s".into()]).unwrap();
        let err = spec.validate(&[]).unwrap_err().to_string();
        assert!(err.contains("{eta_s}"), "{err}");
        let paths = PointPaths {
            id: 7,
            seed: 3,
            folder: "/r/.attempts/0007.a1".into(),
            param_file: "/d/parameters/parameter_007".into(),
            design: "/d/design.parquet".into(),
            mdpipe: "/bin/mdpipe".into(),
        };
        let values = BTreeMap::from([("eta_s".to_string(), 0.125)]);
        assert_eq!(
            spec.render(&paths, &values),
            "run.sh '/d/parameters/parameter_007' '/r/.attempts/0007.a1' 0.125 ${HOME} {a,b}"
        );
    }
}
