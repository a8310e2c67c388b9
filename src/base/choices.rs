//! The choices a user names in a config or on the command line, each parsed
//! in one place: an enum whose variants and aliases (clap's `ValueEnum`)
//! serve the command line, `FromStr` and serde alike, so a config's
//! `kernel = "II"`, `--kernel II` and a study's `kernels = ["II"]` meet the
//! same code and the same message. (The stages of `mdpipe run` are named by
//! `pipeline::StageId`: a system adds its own, so they are not a closed list.)

use clap::ValueEnum;

/// The discrepancy kernel of a calibration: none (the fit without model
/// discrepancy), or the paper's Kernel I or II.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, ValueEnum)]
pub enum Kernel {
    /// No model discrepancy.
    #[value(name = "none", alias = "None", alias = "no-md", alias = "nomd")]
    None,
    /// Kernel I: s² + c̄² (x x')^r exp(−|x − x'|²/2ℓ²).
    #[value(name = "I", alias = "1", alias = "i")]
    I,
    /// Kernel II: Kernel I without s².
    #[value(name = "II", alias = "2", alias = "ii")]
    II,
}

/// Where `mdpipe run` runs the design points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, ValueEnum)]
pub enum Executor {
    /// Parallel processes on this machine.
    #[value(name = "local")]
    Local,
    /// One Slurm array job per design.
    #[value(name = "slurm")]
    Slurm,
}

/// A choice written as none of its names.
#[derive(Debug, Clone, PartialEq)]
pub struct UnknownChoice {
    pub what: &'static str,
    pub got: String,
    pub options: Vec<String>,
}

impl std::fmt::Display for UnknownChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let options = match self.options.split_last() {
            Some((last, [])) => last.to_string(),
            Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
            None => String::new(),
        };
        write!(f, "unknown {} {:?} (use {options})", self.what, self.got)
    }
}

impl std::error::Error for UnknownChoice {}

/// `FromStr`, `Display` and serde for a `ValueEnum`, by its names.
macro_rules! choice_by_name {
    ($t:ty, $what:literal) => {
        impl std::str::FromStr for $t {
            type Err = $crate::base::choices::UnknownChoice;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                <$t as clap::ValueEnum>::from_str(s.trim(), false).map_err(|_| $crate::base::choices::UnknownChoice {
                    what: $what,
                    got: s.to_string(),
                    options: <$t as clap::ValueEnum>::value_variants()
                        .iter()
                        .filter_map(|v| clap::ValueEnum::to_possible_value(v))
                        .map(|p| p.get_name().to_string())
                        .collect(),
                })
            }
        }
        impl std::fmt::Display for $t {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                match clap::ValueEnum::to_possible_value(self) {
                    Some(p) => f.write_str(p.get_name()),
                    None => write!(f, "{self:?}"),
                }
            }
        }
        impl serde::Serialize for $t {
            fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
                serializer.collect_str(self)
            }
        }
        impl<'de> serde::Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
                let text = String::deserialize(deserializer)?;
                text.parse().map_err(serde::de::Error::custom)
            }
        }
    };
}

pub(crate) use choice_by_name;

choice_by_name!(Kernel, "kernel");
choice_by_name!(Executor, "executor");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_aliases_and_the_message_for_anything_else() {
        for (text, kernel) in [("none", Kernel::None), ("nomd", Kernel::None), ("I", Kernel::I), ("2", Kernel::II)] {
            assert_eq!(text.parse::<Kernel>().unwrap(), kernel);
        }
        assert_eq!(Kernel::II.to_string(), "II");
        assert_eq!(serde_json::to_string(&Kernel::None).unwrap(), "\"none\"");
        assert_eq!(serde_json::from_str::<Kernel>("\"ii\"").unwrap(), Kernel::II);
        let err = "III".parse::<Kernel>().unwrap_err().to_string();
        assert_eq!(err, "unknown kernel \"III\" (use none, I or II)");
        let err = "pbs".parse::<Executor>().unwrap_err().to_string();
        assert_eq!(err, "unknown executor \"pbs\" (use local or slurm)");
    }
}
