//! What the refine stage reports (`rounds.json`, `rounds.md`, its section
//! of study.md) and, from it, which emulator the stages after it use.

use crate::base::artifacts::Provenance;
use crate::engine::refine::ObservableRatio;
use crate::pipeline::study::Study;
use anyhow::{Context, Result};
use std::path::PathBuf;

/// One round as reported.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Round {
    pub round: usize,
    /// Training runs of the emulator this round measured.
    pub training_runs: usize,
    pub emulator: String,
    pub ratios: Vec<ObservableRatio>,
    /// Pilot posteriors: case → parameter → [median, q025, q975].
    pub pilots: std::collections::BTreeMap<String, std::collections::BTreeMap<String, [f64; 3]>>,
    /// Runs chosen in this round (none in the last).
    pub new_runs: usize,
    /// The forecast worst latent ratio once they have run.
    pub forecast_worst_latent: Option<f64>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Rounds {
    pub rounds: Vec<Round>,
    /// Why refinement stopped: "below the data error" or "budget spent".
    pub stopped: String,
    /// The emulator the calibrations use, relative to `OUT/refine/`.
    pub emulator: String,
    pub provenance: Provenance,
}

/// What the columns of the ratio tables mean.
const SD_PARTS: &str = "Latent: the emulator's uncertainty about the simulator's mean, what well-placed runs reduce. Floor: white noise beyond the runs' reported noise (structure the GPs cannot follow on these runs, or noise the runs do not report) and the dropped PCA components' signal, which placing runs does not reduce (retraining on more runs may). Predictive: everything the likelihood adds, latent and floor with the PCA's own estimation noise (its mean and directions come from noisy runs; that part falls as 1/runs); the runs' own noise is not part of it.";

impl Rounds {
    pub fn markdown(&self) -> String {
        let mut md = format!(
            "# Adaptive design\n\nStopped: {}. The calibrations use `refine/{}`.\n\n",
            self.stopped, self.emulator
        );
        md.push_str(&format!("Emulator sd over data error where the pilot posteriors live (root mean square over draws and bins; the pilots are scouts, a quarter of the particles). {SD_PARTS} Refinement stops when the predictive ratio is below 1 in every observable.\n\n"));
        md.push_str("| round | training runs | observable | latent | latent, worst bin | floor | predictive |\n|---|---|---|---|---|---|---|\n");
        for r in &self.rounds {
            for o in &r.ratios {
                md.push_str(&format!(
                    "| {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.2} |\n",
                    r.round, r.training_runs, o.observable, o.latent, o.latent_max_bin, o.floor, o.predictive
                ));
            }
        }
        md.push_str("\n| round | pilot | parameter | median | 95% interval |\n|---|---|---|---|---|\n");
        for r in &self.rounds {
            for (case, params) in &r.pilots {
                for (name, [m, lo, hi]) in params {
                    md.push_str(&format!("| {} | {case} | {name} | {m:.4} | [{lo:.4}, {hi:.4}] |\n", r.round));
                }
            }
        }
        md
    }
}

impl Rounds {
    /// The first and last rounds side by side, for study.md.
    pub fn study_section(&self) -> String {
        let (Some(first), Some(last)) = (self.rounds.first(), self.rounds.last()) else { return String::new() };
        let mut md = format!(
            "\n## Emulator error where the posterior lives (adaptive design)\n\n{} training runs, then {} after {} round(s) of refinement (stopped: {}). Emulator sd over data error at the pilot posteriors' draws (root mean square over draws and bins). {SD_PARTS}\n\n| observable | latent before | latent after | worst bin after | floor after | predictive before | predictive after |\n|---|---|---|---|---|---|---|\n",
            first.training_runs,
            last.training_runs,
            self.rounds.len() - 1,
            self.stopped
        );
        for (a, b) in first.ratios.iter().zip(&last.ratios) {
            md.push_str(&format!(
                "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |\n",
                a.observable, a.latent, b.latent, b.latent_max_bin, b.floor, a.predictive, b.predictive
            ));
        }
        md
    }
}

/// Where the refine stage writes: `OUT/refine/`.
pub(crate) fn refine_dir(study: &Study<'_>) -> PathBuf {
    study.paths.out.join("refine")
}

/// The refine stage's report, when `[run.refine]` is set.
pub(crate) fn rounds(study: &Study<'_>) -> Result<Option<Rounds>> {
    if study.run.refine.is_none() {
        return Ok(None);
    }
    let path = refine_dir(study).join("rounds.json");
    Ok(Some(serde_json::from_str(
        &std::fs::read_to_string(&path)
            .with_context(|| format!("reading {} (run the refine stage first)", path.display()))?,
    )?))
}

/// The emulator the calibrations use: refine's last, when `[run.refine]` is set.
pub(crate) fn emulator_in_use(study: &Study<'_>) -> Result<PathBuf> {
    Ok(match rounds(study)? {
        Some(rounds) => refine_dir(study).join(rounds.emulator),
        None => study.paths.emulator(),
    })
}
