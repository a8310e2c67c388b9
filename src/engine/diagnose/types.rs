//! What a diagnosis is: its settings, the mismatch located, each candidate's
//! result, the verdict and the repair, as `diagnosis.json` stores them.

use super::*;

#[derive(Clone, Debug)]
pub struct DiagnoseSettings {
    pub kernel: DiscrepancyKernel,
    pub strong_log_bf: f64,
    pub min_p_value: f64,
    /// Refit the winner with MD on top (step 3); blind tests skip it.
    pub repair: bool,
    /// When to search the model's grammar for a term nobody declared.
    pub discover: Discover,
    /// Every fit first as a scout, and again in full only where the verdict
    /// turns on it (`precision`); false samples every fit in full, the
    /// check that a scout left behind could not have changed the verdict.
    pub scouts: bool,
    /// Stop a candidate's tempering once an upper estimate of its final log
    /// evidence trails the leader by more than any verdict could turn on
    /// (`calibrate::smc::Abandon`); false tempers every fit to β = 1, the
    /// check that no stopped fit could have changed the verdict.
    pub stop_hopeless: bool,
    /// Calibrate the declared candidates most promising first (`promise`),
    /// so the leader is known before the candidates far behind it; false
    /// keeps the declared order. Either way each keeps its seed.
    pub order_by_promise: bool,
}

/// When `diagnose` searches for a term nobody declared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Discover {
    /// When the verdict would be "unexplained".
    WhenUnexplained,
    Always,
    Never,
}

impl Default for DiagnoseSettings {
    fn default() -> Self {
        DiagnoseSettings {
            kernel: DiscrepancyKernel::KernelII,
            strong_log_bf: 3.0,
            min_p_value: 1e-3,
            repair: true,
            discover: Discover::WhenUnexplained,
            scouts: true,
            stop_hopeless: true,
            order_by_promise: true,
        }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Region {
    pub x_from: f64,
    pub x_to: f64,
    /// "above": data above the model (δ > 0); "below": δ < 0.
    pub sign: String,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ObservableMismatch {
    pub observable: String,
    /// x ranges (within the data) where the 95% band of δ excludes zero.
    pub regions: Vec<Region>,
    /// Largest |posterior-mean δ| at a data point, in units of its 1σ error.
    #[serde(deserialize_with = "nan_if_null")]
    pub max_sigma: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub x_at_max: f64,
    /// "above", "below", "mixed" or "none".
    pub sign: String,
    /// Whether |δ| grows with x over the data.
    pub grows_with_x: bool,
    /// Posterior of the growth exponent r of the discrepancy kernel.
    pub r: ParamSummary,
    /// Posterior-predictive check of the no-MD fit: residuals (y − η̂)
    /// standardized by the whole predictive sd (measurement error, posterior
    /// spread of η and, for an emulator, its own uncertainty), and χ².
    #[serde(deserialize_with = "pairs_nan_if_null")]
    pub no_md_residuals: Vec<(f64, f64)>,
    /// Runs of consecutive data points whose no-MD residual exceeds 2 in
    /// size with one sign (kept if two or more points, or one beyond 3): where
    /// the model alone misses. Where an emulator's uncertainty leaves the δ
    /// band wide (`regions` empty), this still locates the mismatch.
    #[serde(default)]
    pub residual_regions: Vec<Region>,
    #[serde(deserialize_with = "nan_if_null")]
    pub no_md_chi2: f64,
    pub no_md_dof: usize,
    /// Posterior-mean δ/σ at each data point: one row of the mismatch map.
    #[serde(deserialize_with = "pairs_nan_if_null")]
    pub map: Vec<(f64, f64)>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CandidateResult {
    pub name: String,
    pub description: String,
    pub log_evidence: f64,
    pub log_evidence_err: f64,
    /// Against the base model without MD (+∞, null in JSON, when that
    /// model cannot be computed over the data).
    #[serde(deserialize_with = "infinity_if_null")]
    pub log_bayes_factor: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub log_bayes_factor_err: f64,
    pub parameters: BTreeMap<String, ParamSummary>,
    pub chi2_per_dof: f64,
    pub p_value: f64,
    pub converged: bool,
    /// The model's (an emulator's) share of the fit's predictive variance at
    /// the data, in the observable where it is largest (`FitQuality`).
    #[serde(default)]
    pub emulator_share: f64,
    /// That observable ("" for an exact model).
    #[serde(default)]
    pub emulator_share_observable: String,
    /// A discovered term's prior log odds against the base model, ln(1/N)
    /// for one of N terms searched, ln(2/(N(N−1))) for a pair (0 for a
    /// declared candidate). It is included in
    /// `log_evidence` and `log_bayes_factor`: the search pays for its size.
    #[serde(default)]
    pub prior_log_odds: f64,
    /// Candidates this one is a special case of (`SpecialCase`).
    #[serde(default)]
    pub special_case_of: Vec<SpecialCase>,
    /// A variant emulator of its own (`CandidateModel::own_emulator`).
    #[serde(default)]
    pub own_emulator: bool,
    /// Other candidates whose fits are the same on these data (their
    /// predictions at the measured points within a χ² of twice the decisive
    /// log BF of each other, in the data's errors): one explanation read
    /// two ways.
    #[serde(default)]
    pub same_fit_as: Vec<String>,
    /// Its model alone draws at the measured points the curve the
    /// model-discrepancy fit draws (model + δ, within the same χ²): δ is
    /// this term's effect read without a law, one explanation with it.
    #[serde(default)]
    pub same_fit_as_md: bool,
    /// Sampled only as a scout (a quarter of the particles): far enough
    /// from every decision that more precision could not change the verdict.
    #[serde(default)]
    pub scout: bool,
    /// The β at which its calibration stopped tempering, its final log
    /// evidence estimated at most `log_evidence` (an upper estimate, not an
    /// estimate), behind the leader by more than any verdict turns on
    /// (`smc::Abandon`); absent for a fit sampled to β = 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopped_at_beta: Option<f64>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Verdict {
    /// A candidate name, "partial" (a candidate that explains most of the
    /// mismatch, named in `standing`, with δ for the rest), "ambiguous",
    /// "emulator_limited", "none" or "unexplained".
    pub best: String,
    /// For "ambiguous": the candidates still standing, best evidence first;
    /// for "partial": the candidate that explains part of the mismatch.
    #[serde(default)]
    pub standing: Vec<String>,
    /// For "ambiguous": the measurement that would best separate the first two.
    #[serde(default)]
    pub suggestion: Option<Suggestion>,
    /// For "emulator_limited": the candidates whose variant emulators must be
    /// refined (more runs where their posteriors lie) before a verdict.
    #[serde(default)]
    pub refine: Vec<String>,
    pub statement: String,
    /// Posterior probability, with equal prior odds among the base, MD and
    /// candidate models: for a named candidate, of every model that contains
    /// it (the probability that the data need it); for `none`, of the base
    /// model; for `unexplained`, of the MD model; otherwise of the models
    /// still standing. NaN (null in JSON) for `unexplained` when the model
    /// as declared cannot be computed: there is no MD fit to weigh.
    #[serde(deserialize_with = "nan_if_null")]
    pub confidence: f64,
    /// For a named candidate, and for `unexplained` when some candidate was
    /// weighed: the share of the model's excess χ² (over its degrees of
    /// freedom) that the named, or best, candidate's fit removes, in [0, 1].
    /// A real candidate is itself an approximation: 0.85 says it explains
    /// most of the mismatch and leaves the rest to δ. Absent when the model
    /// has no excess χ².
    #[serde(default)]
    pub explained_share: Option<f64>,
}

impl Verdict {
    /// `unexplained` for a model that cannot be computed over the data:
    /// there is no MD fit to weigh, so no probability until a candidate is
    /// named or standing.
    pub(super) fn uncomputable() -> Verdict {
        Verdict {
            best: "unexplained".into(),
            standing: Vec::new(),
            suggestion: None,
            refine: Vec::new(),
            statement: String::new(),
            confidence: f64::NAN,
            explained_share: None,
        }
    }

    /// The candidate the verdict names: the winner, or for "partial" the
    /// candidate that explains part of the mismatch (`standing[0]`); None
    /// for "none", "unexplained", "ambiguous" and "emulator_limited".
    pub fn named(&self) -> Option<&str> {
        match self.best.as_str() {
            "none" | "unexplained" | "ambiguous" | "emulator_limited" => None,
            "partial" => self.standing.first().map(String::as_str),
            name => Some(name),
        }
    }

    /// The verdict's probability in words: what it is the probability of.
    pub fn confidence_phrase(&self) -> String {
        let v = self;
        let p = v.confidence;
        let what = match v.best.as_str() {
            "none" => "that nothing is missing".to_string(),
            "unexplained" if !p.is_finite() => {
                return "no posterior probability: the model as declared cannot be computed, so it has no model-discrepancy fit".to_string()
            }
            "unexplained" => "of the model-discrepancy fit".to_string(),
            "ambiguous" | "emulator_limited" => "of the models still standing".to_string(),
            "partial" => format!(
                "that the data need {}, with δ for the rest, over every model that contains it",
                v.named().unwrap_or("its candidate")
            ),
            name => format!("that the data need {name}, over every model that contains it"),
        };
        let shown = if p > 0.999 { "> 0.999".to_string() } else { format!("{p:.3}") };
        format!("posterior probability {shown} {what}")
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FitFigures {
    pub label: String,
    pub chi2_per_dof: f64,
    pub log_evidence: f64,
    pub log_evidence_err: f64,
    pub parameters: BTreeMap<String, ParamSummary>,
    /// Largest |posterior-mean δ|/σ per observable (0 without MD).
    pub delta_max_sigma: BTreeMap<String, f64>,
    /// Parameters piled against a bound of the prior box (for an emulator,
    /// its design box): the box, not the data, ends their posterior.
    #[serde(default)]
    pub piled_at_bounds: Vec<crate::engine::calibrate::results::summary::PiledAtBound>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Improvement {
    pub before: Vec<FitFigures>,
    pub after: Vec<FitFigures>,
    /// Width of the 95% interval of each model parameter, before (MD) / after (repaired).
    pub interval_narrowing: BTreeMap<String, f64>,
    /// The largest narrowing these data allow: the MD width over the repaired
    /// model's Cramér–Rao 95% width (2 × 1.96 × sd) at its posterior median.
    /// Empty for emulated models and for parameters the data cannot identify.
    #[serde(default)]
    pub information_limit: BTreeMap<String, f64>,
    /// The parameters' true values, when the config knows them (mock data).
    #[serde(default)]
    pub truth: BTreeMap<String, f64>,
    /// Which of `after` is the verdict's answer: 0, the model with the named
    /// candidate; 1, with δ on top, for a partial explanation (the
    /// candidate alone misfits, so its own intervals are not the answer).
    #[serde(default)]
    pub answer: usize,
}

impl Improvement {
    /// Whether the repaired fit's and the MD fit's 95% intervals of `name`
    /// cover its true value, when the config knows it: a narrower interval
    /// that misses the truth is no repair, a wider one that covers it may be.
    pub fn truth_coverage(&self, name: &str) -> String {
        let Some(&t) = self.truth.get(name) else { return String::new() };
        let covers =
            |f: Option<&FitFigures>| f.and_then(|f| f.parameters.get(name)).map(|p| p.q025 <= t && t <= p.q975);
        match (covers(self.after.get(self.answer)), covers(self.before.get(1))) {
            (Some(true), Some(false)) => format!("; it covers the truth {t}, which MD alone missed"),
            (Some(true), Some(true)) => format!("; both cover the truth {t}"),
            (Some(false), Some(true)) => format!("; it misses the truth {t}, which MD alone covered"),
            (Some(false), Some(false)) => format!("; both miss the truth {t}"),
            _ => String::new(),
        }
    }
}

/// JSON has no infinity: serde_json writes a non-finite number as null.
fn minus_infinity_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    use serde::Deserialize;
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NEG_INFINITY))
}

fn infinity_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    use serde::Deserialize;
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    use serde::Deserialize;
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// (x, value) pairs whose values JSON wrote as null (NaN: a δ that could not
/// be computed at a point) read back as NaN. Before, such a diagnosis was
/// written and then refused by its own report ("invalid type: null").
fn pairs_nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<(f64, f64)>, D::Error> {
    use serde::Deserialize;
    let pairs = Vec::<(Option<f64>, Option<f64>)>::deserialize(d)?;
    Ok(pairs.into_iter().map(|(x, v)| (x.unwrap_or(f64::NAN), v.unwrap_or(f64::NAN))).collect())
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Diagnosis {
    pub mismatch: Vec<ObservableMismatch>,
    pub candidates: Vec<CandidateResult>,
    pub verdict: Verdict,
    pub improvement: Option<Improvement>,
    /// −∞ (null in JSON) when the model as declared cannot be computed
    /// over the data, and so neither it nor its MD fit can be made.
    #[serde(deserialize_with = "minus_infinity_if_null")]
    pub base_log_evidence: f64,
    #[serde(deserialize_with = "minus_infinity_if_null")]
    pub md_log_evidence: f64,
    /// What the search for undeclared terms tried, when it ran.
    #[serde(default)]
    pub discovery: Option<DiscoveryReport>,
    /// Where the time went: every fit in the order it was made.
    #[serde(default)]
    pub profile: Vec<FitTime>,
    pub provenance: Provenance,
}

/// One fit of a diagnosis and its wall time (zero when a stored fit of the
/// same problem was taken).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FitTime {
    /// `base_no_md`, `base_md`, a candidate's name, `repaired`, `repaired_md`.
    pub fit: String,
    /// Particles per replicate: a scout's are a quarter of the configured.
    pub particles: usize,
    pub seconds: f64,
    /// Model evaluations, the sampler's own count.
    pub evaluations: u64,
}

/// The search for a term nobody declared.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DiscoveryReport {
    /// Single terms the grammar made for the model (the ten pairs of the
    /// best five were fitted too).
    pub searched: usize,
    /// The grammar's forms that were tried.
    pub forms: Vec<String>,
    /// Wall time of the screening (the full calibrations not included).
    #[serde(default)]
    pub screening_seconds: f64,
    /// What went on to full calibration, best screened first.
    pub screened: Vec<ScreenedTerm>,
    /// What the search decided about the model itself (`Screening::notes`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ScreenedTerm {
    pub name: String,
    pub formula: String,
    /// What the term is to a physicist, from the grammar.
    #[serde(default)]
    pub meaning: String,
    pub delta_chi2: f64,
    pub delta_bic: f64,
    #[serde(default)]
    pub prior_log_odds: f64,
    /// The `[[candidates]]` block that declares the term.
    pub toml: String,
    /// Terms screened as the same fit on these data, merged into this one:
    /// one explanation, read each of these ways too.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub readings: Vec<String>,
}

/// Everything `diagnose` computed, for the report.
pub struct DiagnoseRun {
    pub diagnosis: Diagnosis,
    /// The fits of the model as declared, without and with MD; None when it
    /// cannot be computed over the data.
    pub base: Option<Calibration>,
    pub md: Option<Calibration>,
    pub candidates: Vec<(String, Calibration)>,
    pub repaired_md: Option<Calibration>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model that cannot be computed has no MD fit: its `unexplained`
    /// carries no probability, says why, and survives JSON (null) intact.
    #[test]
    fn an_uncomputable_models_verdict_has_no_probability_and_round_trips() {
        let v = Verdict::uncomputable();
        assert!(v.confidence_phrase().contains("cannot be computed"), "{}", v.confidence_phrase());
        let text = serde_json::to_string(&v).unwrap();
        assert!(text.contains("\"confidence\":null"), "{text}");
        let back: Verdict = serde_json::from_str(&text).unwrap();
        assert!(back.confidence.is_nan());
        let fitted = Verdict { confidence: 0.25, ..v };
        assert_eq!(fitted.confidence_phrase(), "posterior probability 0.250 of the model-discrepancy fit");
    }

    /// A mismatch whose δ could not be computed at some points (NaN, null in
    /// JSON) reads back with NaN there (ODEBench case 48 wrote one and its
    /// report refused it).
    #[test]
    fn a_mismatch_with_values_that_could_not_be_computed_round_trips() {
        let m = ObservableMismatch {
            observable: "x_0".into(),
            regions: Vec::new(),
            max_sigma: f64::NAN,
            x_at_max: 0.25,
            sign: "none".into(),
            grows_with_x: false,
            r: serde_json::from_str(r#"{"median":0.1,"q025":0.0,"q975":0.3,"q16":0.05,"q84":0.2,"mean":0.1,"sd":0.1}"#)
                .unwrap(),
            no_md_residuals: vec![(0.25, 1.5), (0.5, f64::NAN)],
            residual_regions: Vec::new(),
            no_md_chi2: f64::NAN,
            no_md_dof: 40,
            map: vec![(0.25, f64::NAN), (0.5, 2.0)],
        };
        let text = serde_json::to_string(&m).unwrap();
        assert!(text.contains("[0.25,null]"), "{text}");
        let back: ObservableMismatch = serde_json::from_str(&text).unwrap();
        assert!(back.map[0].1.is_nan() && back.map[1] == (0.5, 2.0));
        assert!(back.no_md_residuals[1].1.is_nan() && back.max_sigma.is_nan() && back.no_md_chi2.is_nan());
    }
}
