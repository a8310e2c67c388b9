//! Models declared in a config, with no Rust to write:
//!
//! - `[model] kind = "expression"`: each observable a formula of x and θ;
//! - `[model] kind = "ode"`: state variables, their initial values and
//!   equations of motion, and each observable a formula of the state;
//!
//! with the physics they may be missing declared beside them as
//! `[[candidates]]` (terms added to observables or to equations of motion,
//! each with its own parameters and uniform priors), and the process that
//! made mock data as `[truth]` (candidates switched on at fixed values, and
//! terms from outside the library). `diagnose` weighs each candidate and,
//! unless `[model] candidate_pairs = false`, each pair of them.
//!
//! Formulas are parsed once (`notation`: mathematical precedence) and
//! compiled (`tape`) to evaluate without allocation; `formula` binds them to names, `declaration` reads the tables, and
//! `expression` and `ode` compile a declaration into a `Simulator`.

mod declaration;
pub mod expression;
pub mod formula;
mod notation;
pub mod ode;
mod tape;

use crate::base::config::Config;
use crate::engine::model::{CandidateModel, ModelFamily, Simulator, Units};
use anyhow::Result;
use declaration::{CandidateTable, Declared, ModelTable, TruthTable};
use std::sync::Arc;

/// The two declarative kinds, one family type: they differ only in how a
/// declaration compiles.
pub struct DeclaredFamily {
    ode: bool,
}

impl DeclaredFamily {
    pub const EXPRESSION: DeclaredFamily = DeclaredFamily { ode: false };
    pub const ODE: DeclaredFamily = DeclaredFamily { ode: true };

    fn table(&self, config: &Config) -> Result<ModelTable> {
        config.decode_family_table(&config.model, "model")
    }

    fn base(&self, config: &Config) -> Result<Declared> {
        Declared::base(config, &self.table(config)?, self.ode)
    }

    fn compile(&self, config: &Config, declared: &Declared) -> Result<Arc<dyn Simulator>> {
        let file = config.path.display().to_string();
        Ok(if self.ode {
            Arc::new(ode::OdeModel::compile(&file, declared)?)
        } else {
            Arc::new(expression::ExpressionModel::compile(&file, declared)?)
        })
    }

    /// The `[[candidates]]` tables, decoded.
    fn library(&self, config: &Config) -> Result<Vec<CandidateTable>> {
        let file = config.path.display();
        let library: Vec<CandidateTable> = config
            .candidates
            .iter()
            .enumerate()
            .map(|(i, t)| t.clone().try_into().map_err(|e| anyhow::anyhow!("{file}: [[candidates]] #{}: {e}", i + 1)))
            .collect::<Result<_>>()?;
        for (i, c) in library.iter().enumerate() {
            if library[..i].iter().any(|o| o.name == c.name) {
                anyhow::bail!("{file}: [[candidates]]: two candidates are named '{}'", c.name);
            }
        }
        Ok(library)
    }

    fn candidate(&self, config: &Config, base: &Declared, chosen: &[&CandidateTable]) -> Result<CandidateModel> {
        let file = config.path.display().to_string();
        let mut declared = base.clone();
        for c in chosen {
            declared = declared.with_candidate(&file, c)?;
        }
        let extra_parameters =
            chosen.iter().flat_map(|c| c.parameters.iter().map(|(n, s)| (n.clone(), s.clone()))).collect();
        Ok(CandidateModel {
            name: chosen.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join("+"),
            description: chosen.iter().map(|c| c.description.as_str()).collect::<Vec<_>>().join("; and "),
            extra_parameters,
            simulator: self.compile(config, &declared)?,
        })
    }
}

impl ModelFamily for DeclaredFamily {
    fn kind(&self) -> &'static str {
        if self.ode {
            "ode"
        } else {
            "expression"
        }
    }

    fn simulator(&self, config: &Config) -> Result<Arc<dyn Simulator>> {
        let base = self.base(config)?;
        let model = self.compile(config, &base)?;
        // Candidates are compiled here too, so a bad one fails before any sampling.
        for c in self.library(config)? {
            self.candidate(config, &base, &[&c])?;
        }
        Ok(model)
    }

    fn units(&self, config: &Config) -> Units {
        match self.table(config) {
            Ok(t) => Units { x: t.units.x, observables: t.units.observables, parameters: Default::default() },
            Err(_) => Units::default(),
        }
    }

    /// Each declared candidate, then (unless `candidate_pairs = false`) each
    /// pair of them, whose evidence pays for both sets of parameters.
    fn candidates(&self, config: &Config) -> Result<Vec<CandidateModel>> {
        let base = self.base(config)?;
        let library = self.library(config)?;
        let mut out = Vec::new();
        for c in &library {
            out.push(self.candidate(config, &base, &[c])?);
        }
        if self.table(config)?.candidate_pairs {
            for (i, a) in library.iter().enumerate() {
                for b in &library[i + 1..] {
                    out.push(self.candidate(config, &base, &[a, b])?);
                }
            }
        }
        Ok(out)
    }

    fn true_process(&self, config: &Config, truth: &toml::Table) -> Result<Arc<dyn Simulator>> {
        let table: TruthTable = config.decode_family_table(truth, "truth")?;
        let declared =
            self.base(config)?.with_truth(&config.path.display().to_string(), &table, &self.library(config)?)?;
        self.compile(config, &declared)
    }
}
