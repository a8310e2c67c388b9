//! The `[sampler]` table: which sampler, and its settings.

use super::ensemble::EnsembleSettings;
use super::smc::SmcSettings;

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SamplerKind {
    Smc,
    Ensemble,
}

impl SamplerKind {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "smc" => Some(SamplerKind::Smc),
            "ensemble" | "emcee" => Some(SamplerKind::Ensemble),
            _ => None,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            SamplerKind::Smc => "smc",
            SamplerKind::Ensemble => "ensemble",
        }
    }
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SamplerConfig {
    pub kind: SamplerKind,
    pub smc: SmcSettings,
    pub ensemble: EnsembleSettings,
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig { kind: SamplerKind::Smc, smc: SmcSettings::default(), ensemble: EnsembleSettings::default() }
    }
}
