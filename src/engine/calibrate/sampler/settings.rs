//! The `[sampler]` table: which sampler, and its settings.

use super::ensemble::EnsembleSettings;
use super::smc::SmcSettings;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SamplerKind {
    /// Sequential Monte Carlo (tempering), with the evidence.
    #[value(name = "smc")]
    Smc,
    /// The affine-invariant ensemble sampler (emcee's stretch move).
    #[value(name = "ensemble", alias = "emcee")]
    Ensemble,
}

crate::base::choices::choice_by_name!(SamplerKind, "sampler");

impl SamplerKind {
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
    /// Sample again with more where SMC has not converged (`adapt`); a
    /// config that chose small settings for speed can turn it off.
    pub adapt: bool,
    pub smc: SmcSettings,
    pub ensemble: EnsembleSettings,
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig {
            kind: SamplerKind::Smc,
            adapt: true,
            smc: SmcSettings::default(),
            ensemble: EnsembleSettings::default(),
        }
    }
}

/// A scout takes this fraction of the configured particles.
const SCOUT_SHARE: usize = 4;
/// A scout's final sweeps per dimension (the configured default is 15).
const SCOUT_FINAL_STEPS_PER_DIM: f64 = 2.0;
/// The fewest particles per replicate worth scouting with: below them a
/// scout's evidence is too rough to rule anything out.
const SCOUT_MIN_PARTICLES: usize = 200;

impl SamplerConfig {
    /// The settings of a scout, a fit that needs to know roughly where the
    /// posterior lies and what its evidence is, not a reported posterior: a
    /// quarter of the particles, few final sweeps, no reruns for
    /// convergence. None where scouting does not apply (the ensemble
    /// sampler, or too few particles to divide).
    pub fn scout(&self) -> Option<SamplerConfig> {
        if self.kind != SamplerKind::Smc || self.smc.particles / SCOUT_SHARE < SCOUT_MIN_PARTICLES {
            return None;
        }
        let mut s = self.clone();
        s.smc.particles /= SCOUT_SHARE;
        // The final sweeps decorrelate the draws a reported posterior needs;
        // a scout's evidence is made before them.
        s.smc.final_steps_per_dim = s.smc.final_steps_per_dim.min(SCOUT_FINAL_STEPS_PER_DIM);
        s.smc.final_mixture_proposals = s.smc.final_mixture_proposals.min(s.smc.mixture_proposals);
        s.adapt = false;
        Some(s)
    }

    /// Checks every setting a sampler would trip on; the message names the field.
    pub fn validate(&self) -> Result<(), BadSetting> {
        let s = &self.smc;
        let checks: [(bool, &str, String); 8] = [
            (s.particles >= 2, "smc.particles", format!("{} (need at least 2)", s.particles)),
            (s.replicates >= 1, "smc.replicates", format!("{} (need at least 1)", s.replicates)),
            (
                s.ess_fraction > 0.0 && s.ess_fraction < 1.0,
                "smc.ess_fraction",
                format!("{} (need 0 < ess_fraction < 1: at 1 no tempering step can keep the ESS)", s.ess_fraction),
            ),
            (
                s.steps_per_dim > 0.0
                    && s.steps_per_dim.is_finite()
                    && s.max_steps_per_dim >= s.steps_per_dim
                    && s.max_steps_per_dim.is_finite(),
                "smc.steps_per_dim",
                format!(
                    "{} with max_steps_per_dim {} (need 0 < steps_per_dim <= max_steps_per_dim, finite)",
                    s.steps_per_dim, s.max_steps_per_dim
                ),
            ),
            (
                s.final_steps_per_dim >= 0.0 && s.final_steps_per_dim.is_finite(),
                "smc.final_steps_per_dim",
                format!("{} (need a finite number >= 0)", s.final_steps_per_dim),
            ),
            (
                s.target_acceptance > 0.0 && s.target_acceptance < 1.0,
                "smc.target_acceptance",
                format!("{} (need 0 < target_acceptance < 1)", s.target_acceptance),
            ),
            (
                self.ensemble.steps >= 1 && self.ensemble.thin >= 1,
                "ensemble.steps/thin",
                format!("{} / {} (need at least 1 each)", self.ensemble.steps, self.ensemble.thin),
            ),
            (
                self.ensemble.stretch > 1.0 && self.ensemble.stretch.is_finite(),
                "ensemble.stretch",
                format!("{} (need a finite a > 1)", self.ensemble.stretch),
            ),
        ];
        match checks.into_iter().find(|(ok, _, _)| !ok) {
            Some((_, field, got)) => Err(BadSetting { field, got }),
            None => Ok(()),
        }
    }
}

/// A `[sampler]` setting a sampler would trip on: the field and what it holds.
#[derive(Debug, Clone, PartialEq)]
pub struct BadSetting {
    pub field: &'static str,
    pub got: String,
}

impl std::fmt::Display for BadSetting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} = {}", self.field, self.got)
    }
}

impl std::error::Error for BadSetting {}
