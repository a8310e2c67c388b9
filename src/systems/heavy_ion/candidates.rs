//! The stand-in's library of candidate physics: what each switches on in
//! the runs, its own parameter, and its `[[candidates]]` declaration.

use super::*;

/// A parameter a candidate correction adds, with its uniform prior.
#[derive(Clone, Copy, Debug)]
pub struct CandidateParameter {
    pub name: &'static str,
    pub min: f64,
    pub max: f64,
    /// The iEBE-MUSIC parameter-file key.
    pub key: &'static str,
    pub units: &'static str,
}

/// Physics the stand-in can switch on that the f_eq model leaves out: the
/// heavy-ion library of `mdpipe diagnose`. `mdpipe run` trains one variant
/// emulator per candidate on runs with it switched on, and declares it.
#[derive(Clone, Copy, Debug)]
pub struct StandInCandidate {
    pub name: &'static str,
    pub description: &'static str,
    /// The variant's runs use the Grad shear δf (otherwise the model's δf).
    pub shear_delta_f: bool,
    pub parameter: Option<CandidateParameter>,
}

pub const CANDIDATES: [StandInCandidate; 3] = [
    StandInCandidate {
        name: "grad_shear_delta_f",
        description: "the Grad 14-moment shear viscous δf at particlization, its size fixed by η/s at the switching temperature",
        shear_delta_f: true,
        parameter: None,
    },
    StandInCandidate {
        name: "bulk_delta_f",
        description: "a bulk viscous δf at particlization (14-moment, relaxation-time form) from ζ/s at the switching temperature",
        shear_delta_f: false,
        parameter: Some(CandidateParameter { name: "zeta_s", min: 0.0, max: 0.2, key: "Bulk_to_S_ratio", units: "" }),
    },
    StandInCandidate {
        name: "proton_annihilation",
        description: "baryon–antibaryon annihilation in the hadronic phase, leaving a fraction p_survival of the (anti)protons",
        shear_delta_f: false,
        parameter: Some(CandidateParameter { name: "p_survival", min: 0.5, max: 1.0, key: "proton_survival_fraction", units: "" }),
    },
];

impl StandInCandidate {
    /// The candidate's own parameter as a design dimension.
    pub fn design_parameter(&self) -> Option<crate::engine::design::DesignParameter> {
        self.parameter.map(|p| crate::engine::design::DesignParameter {
            name: p.name.into(),
            min: p.min,
            max: p.max,
            log: false,
            key: p.key.into(),
            units: p.units.into(),
        })
    }

    /// The particlization of the variant's runs, given the model's.
    pub fn delta_f(&self, model: DeltaF) -> DeltaF {
        if self.shear_delta_f {
            DeltaF::Grad
        } else {
            model
        }
    }

    /// Its `[[candidates]]` declaration, with its variant emulator at `emulator`.
    pub fn declaration(&self, emulator: std::path::PathBuf) -> crate::engine::emulator::family::CandidateDeclaration {
        let parameters = self
            .parameter
            .iter()
            .map(|p| {
                let spec =
                    crate::base::config::ParamSpec { min: p.min, max: p.max, truth: None, units: p.units.into() };
                (p.name.to_string(), spec)
            })
            .collect();
        crate::engine::emulator::family::CandidateDeclaration::of_emulator(
            self.name,
            self.description,
            emulator,
            parameters,
        )
    }
}

/// The library candidate called `name`.
pub fn candidate(name: &str) -> anyhow::Result<&'static StandInCandidate> {
    CANDIDATES.iter().find(|c| c.name == name).ok_or_else(|| {
        let names: Vec<&str> = CANDIDATES.iter().map(|c| c.name).collect();
        anyhow::anyhow!("unknown heavy-ion candidate '{name}' (the library has {})", names.join(", "))
    })
}
