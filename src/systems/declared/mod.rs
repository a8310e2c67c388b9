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
pub mod discover;
pub mod expression;
pub mod ode;

use crate::base::config::Config;
use crate::engine::model::{CandidateModel, Discoverer, ModelFamily, ModelSetup, PlainSetup, Simulator, Units};
use anyhow::{Context, Result};
use declaration::{CandidateTable, Declared, ModelTable, TruthTable};
use std::sync::Arc;

/// The two declarative kinds, one family type: they differ only in how a
/// declaration compiles.
#[derive(Clone)]
pub struct DeclaredFamily {
    ode: bool,
}

impl DeclaredFamily {
    pub const EXPRESSION: DeclaredFamily = DeclaredFamily { ode: false };
    pub const ODE: DeclaredFamily = DeclaredFamily { ode: true };

    fn compile(&self, file: &str, declared: &Declared) -> Result<Arc<dyn Simulator>> {
        Ok(if self.ode {
            Arc::new(ode::OdeModel::compile(file, declared)?)
        } else {
            Arc::new(expression::ExpressionModel::compile(file, declared)?)
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
}

/// A declaration read once: the compiled model, and each single candidate
/// compiled (so a bad one fails before any sampling); pairs are compiled
/// when `diagnose` asks for them.
struct DeclaredSetup {
    family: DeclaredFamily,
    file: String,
    base: Declared,
    library: Vec<CandidateTable>,
    pairs: bool,
    units: Units,
    model: Arc<dyn Simulator>,
    singles: Vec<CandidateModel>,
    discoverer: discover::DeclaredDiscoverer,
}

impl DeclaredSetup {
    fn candidate(&self, chosen: &[&CandidateTable]) -> Result<CandidateModel> {
        let mut declared = self.base.clone();
        for c in chosen {
            declared = declared.with_candidate(&self.file, c)?;
        }
        let extra_parameters =
            chosen.iter().flat_map(|c| c.parameters.iter().map(|(n, s)| (n.clone(), s.clone()))).collect();
        Ok(CandidateModel {
            name: chosen.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join("+"),
            description: chosen.iter().map(|c| c.description.as_str()).collect::<Vec<_>>().join("; and "),
            extra_parameters,
            simulator: self.family.compile(&self.file, &declared)?,
            special_case_of: Vec::new(),
            own_emulator: false,
        })
    }
}

impl ModelSetup for DeclaredSetup {
    fn simulator(&self) -> Arc<dyn Simulator> {
        self.model.clone()
    }

    fn units(&self) -> Units {
        self.units.clone()
    }

    /// Each declared candidate, then (unless `candidate_pairs = false`) each
    /// pair of them, whose evidence pays for both sets of parameters.
    fn discoverer(&self) -> Option<&dyn Discoverer> {
        Some(&self.discoverer)
    }

    fn candidates(&self) -> Result<Vec<CandidateModel>> {
        let mut out = self.singles.clone();
        if self.pairs {
            for (i, a) in self.library.iter().enumerate() {
                for b in &self.library[i + 1..] {
                    out.push(self.candidate(&[a, b])?);
                }
            }
        }
        Ok(out)
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

    fn open(&self, config: &Config) -> Result<Arc<dyn ModelSetup>> {
        let table: ModelTable = config.decode_family_table(&config.model, "model")?;
        let file = config.path.display().to_string();
        let base = Declared::base(config, &table, self.ode)?;
        let grammar = table.discover.grammar.as_ref().map(|g| config.resolve(g));
        let discoverer = discover::DeclaredDiscoverer {
            family: DeclaredFamily { ode: self.ode },
            file: file.clone(),
            base: base.clone(),
            forms: discover::grammar::forms(grammar.as_deref())
                .with_context(|| format!("{file}: [model.discover] grammar"))?,
        };
        let mut setup = DeclaredSetup {
            discoverer,
            family: DeclaredFamily { ode: self.ode },
            model: self.compile(&file, &base)?,
            file,
            base,
            library: self.library(config)?,
            pairs: table.candidate_pairs,
            units: Units { x: table.units.x, observables: table.units.observables, parameters: Default::default() },
            singles: Vec::new(),
        };
        setup.singles = setup.library.iter().map(|c| setup.candidate(&[c])).collect::<Result<_>>()?;
        Ok(Arc::new(setup))
    }

    fn open_truth(&self, config: &Config, truth: &toml::Table) -> Result<Arc<dyn ModelSetup>> {
        let table: ModelTable = config.decode_family_table(&config.model, "model")?;
        let truth_table: TruthTable = config.decode_family_table(truth, "truth")?;
        let file = config.path.display().to_string();
        let declared =
            Declared::base(config, &table, self.ode)?.with_truth(&file, &truth_table, &self.library(config)?)?;
        let units = Units { x: table.units.x, observables: table.units.observables, parameters: Default::default() };
        Ok(PlainSetup::shared(self.compile(&file, &declared)?, units))
    }
}
