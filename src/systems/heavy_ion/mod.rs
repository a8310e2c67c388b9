//! A fast stand-in for iEBE-MUSIC: a boost-invariant viscous blast wave with
//! Cooper–Frye particlization of π, K, p (and antiparticles), optionally with
//! the Grad 14-moment shear δf. It is **not** hydrodynamics; it is built so
//! that observables have realistic size, shape and parameter dependence, and
//! so that switching δf on changes them the way hydro does.
//!
//! Ingredients (all in GeV, fm, GeV/fm³):
//! - **Equation of state.** Near the switching region a hadron resonance gas
//!   is well described by `ε(T) = 0.5 GeV/fm³ (T / 0.155 GeV)^9`, so
//!   `T_sw = 0.155 (ε_sw / 0.5)^(1/9)` GeV; thermodynamic consistency then gives
//!   `P = ε/8` and `s = 9ε/(8T)`.
//! - **Temperature history and η/s.** Bjorken cooling `T ∝ τ^(-1/3)` from
//!   `T_0 = 0.35` GeV spends time `dτ ∝ T^-4 dT` at each T; the damping uses
//!   `(η/s)_eff`, the η/s(T) average with that weight over [T_sw, T_0]. δf uses
//!   η/s at T_sw.
//! - **Freeze-out surface.** τ_f = 7.5 fm (0.2/ε_sw)^0.45; the volume per unit
//!   rapidity is fixed by entropy, `π R² τ_f = (dS/dy) / s(T_sw)`, with dS/dy
//!   growing with viscous entropy production, `S_0 (1 + 0.6 (η/s)_eff)`.
//! - **Freeze-out shape and flow (Retière–Lisa blast wave).** The boundary
//!   is `R(φ) = R [1 − 2 s_2 cos 2φ − 2 s_3 cos 3φ]` (s_2 > 0: longer out of
//!   plane), cells sit at `r = u R(φ)`, and the flow points along the
//!   boundary's normal φ_b, so it bunches towards the short axes. Flow
//!   rapidity `ρ = ρ_max u^0.754 [1 + 2 Σ_n ρ_n cos nφ_b]`, with
//!   `ρ_max = 0.936 + 0.2 ln(τ_f / 7.5 fm) + 0.3 (η/s)_eff`.
//! - **Anisotropic flow.** Both anisotropies follow the eccentricity with
//!   acoustic damping: `ρ_n = k_n ε_n exp(-β n² (η/s)_eff)` and
//!   `s_n = σ_n ε_n exp(-β n² (η/s)_eff)`, with rms eccentricities
//!   ε_2 = 0.30, ε_3 = 0.20 for 20–30% Au+Au. The shape term is what makes
//!   v2(pT) rise fast and then level off as in hydro: each cell beams its
//!   particles along its flow, and more cells flow in plane.
//! - **Kinetic freeze-out.** The hadronic phase cools momenta to
//!   T_kin = 0.886 T_sw but keeps each species' number from T_sw (partial
//!   chemical equilibrium): yields are scaled by n(T_sw)/n(T_kin).
//! - **Grad shear δf.** `δf = f0 p^μ p^ν π_μν / (2 (e+P) T²)` with
//!   Navier–Stokes `π^μν = 2η σ^μν` from the Bjorken expansion rate: in the
//!   fluid rest frame `p^μ p^ν π_μν = (2η / 3τ)(p_T*² − 2 p_z*²)`, so
//!   `δf/f0 = (η/s)(p_T*² − 2 p_z*²) / (3 τ_f T³)` (Teaney, PRC 68, 034913).
//!   `DeltaF::GradTransverse` adds the blast wave's radial (cosh ρ ∂_r ρ) and
//!   azimuthal (sinh ρ / r) expansion rates to the longitudinal one
//!   (cosh ρ / τ), keeping the diagonal rest-frame shear and neglecting ∂_τ u.
//!   Measured at η/s = 0.1, ε_sw = 0.2: those rates nearly equal the
//!   longitudinal one at this freeze-out, so the shear largely cancels: at
//!   1.9 GeV the charged spectrum rises by 2.6% (Bjorken only: 8.9%) and
//!   v2 (0.206 with f_eq) falls by 0.0076 (Bjorken only: 0.0096). Hydro's Israel–Stewart shear at
//!   freeze-out is dominated by the longitudinal component, so `Grad`
//!   (longitudinal) is the default and the mock truth.
//! - **Diagnose candidates** (off in the model and in the paper's truth):
//!   a bulk viscous δf from ζ/s at T_sw (`zeta_s`, 14-moment relaxation-time
//!   form, see `yield_and_flow`) and (anti)proton annihilation in the
//!   hadronic phase (`p_survival`); `CANDIDATES` lists them with the Grad δf.
//! - **What was fitted.** Resonance decays are not simulated; per-species
//!   yield factors (π 1.44, K 1.31, p 1.82) stand in for their feed-down.
//!   Ten constants (ρ_max's offset, the profile exponent 0.754, k_2, k_3,
//!   σ_2, σ_3, T_kin/T_sw and the three yield factors; dS/dy kept at 1925)
//!   were fitted once, by least squares, to
//!   `pipeline/reference/iebe_music_grad_shear0p1_esw0p2.dat` at its truth
//!   (η/s = 0.1, ε_sw = 0.2, Grad δf). Everything else, including every
//!   dependence on η/s, ε_sw and δf, is fixed by the formulas above.
//!   At that point every spectrum bin is within 12% of iEBE-MUSIC and every
//!   v_n bin within 21%, apart from the proton v2 below 0.4 GeV, which
//!   iEBE-MUSIC itself measures only to ±20–100% (printed by
//!   `cargo test --release --test it stand_in -- --nocapture`).
//! - **Why decays are not simulated.** Two-body decays (ρ, ω, K*, Δ fed by
//!   the blast wave's own parents) were tried in a numpy prototype, not in
//!   this crate: a ρ → ππ daughter at 0.3 GeV leaves mostly sideways to a
//!   0.2–0.8 GeV parent (⟨cos 2Δφ⟩ from −0.13 to −0.39), so feed-down
//!   lowered the low-pT pion v2 instead of raising it, and worsened the fit.

mod candidates;
mod cooper_frye;
pub mod events;
pub mod family;
pub mod figures;
pub mod mock;
mod runs;
pub mod study;

pub use candidates::*;
pub use cooper_frye::{yield_and_flow, Quadrature, YieldAndFlow};
pub use runs::*;

/// GeV·fm.
const HBARC: f64 = 0.197_326_98;

/// η/s as a function of temperature.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EtaOverS {
    Constant(f64),
    /// `(η/s)_kink + a_low (T − T_kink)` below the kink, `… + a_high (T − T_kink)`
    /// above, floored at 0 (T in GeV, slopes in GeV⁻¹).
    Kink {
        t_kink: f64,
        a_low: f64,
        a_high: f64,
        eta_s_kink: f64,
    },
}

impl EtaOverS {
    pub fn at(&self, t: f64) -> f64 {
        match *self {
            EtaOverS::Constant(v) => v,
            EtaOverS::Kink { t_kink, a_low, a_high, eta_s_kink } => {
                let slope = if t < t_kink { a_low } else { a_high };
                (eta_s_kink + slope * (t - t_kink)).max(0.0)
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeavyIonParams {
    pub eta_s: EtaOverS,
    /// Switching energy density, GeV/fm³.
    pub e_sw: f64,
    /// Bulk viscosity ζ/s at particlization; > 0 adds the bulk δf (0 in the
    /// model and in the paper's truth; a diagnose candidate).
    pub zeta_s: f64,
    /// Fraction of (anti)protons that survive annihilation in the hadronic
    /// phase (1 = none annihilate; a diagnose candidate).
    pub p_survival: f64,
}

impl HeavyIonParams {
    /// Constant η/s, no bulk δf, no annihilation: the paper's 2-parameter model.
    pub fn constant(eta_s: f64, e_sw: f64) -> HeavyIonParams {
        HeavyIonParams { eta_s: EtaOverS::Constant(eta_s), e_sw, zeta_s: 0.0, p_survival: 1.0 }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeltaF {
    None,
    /// Grad shear δf with the Bjorken (longitudinal) Navier–Stokes shear.
    Grad,
    /// The same plus the blast wave's radial and azimuthal expansion rates.
    GradTransverse,
}

impl std::str::FromStr for DeltaF {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> anyhow::Result<Self> {
        match s {
            "none" => Ok(DeltaF::None),
            "grad" => Ok(DeltaF::Grad),
            "grad-transverse" => Ok(DeltaF::GradTransverse),
            _ => anyhow::bail!("--delta-f: unknown value {s:?} (use none, grad or grad-transverse)"),
        }
    }
}

/// A hadron species (particle; its antiparticle is identical at μ_B = 0).
#[derive(Clone, Copy, Debug)]
pub struct Species {
    pub name: &'static str,
    /// PDG Monte Carlo id of the particle.
    pub pid: i32,
    pub mass: f64,
    pub degeneracy: f64,
    pub feed_down: f64,
}

pub const PION: Species = Species { name: "pi", pid: 211, mass: 0.139_570, degeneracy: 1.0, feed_down: 1.44 };
pub const KAON: Species = Species { name: "K", pid: 321, mass: 0.493_677, degeneracy: 1.0, feed_down: 1.31 };
pub const PROTON: Species = Species { name: "p", pid: 2212, mass: 0.938_272, degeneracy: 2.0, feed_down: 1.82 };
pub const SPECIES: [Species; 3] = [PION, KAON, PROTON];

pub const T0: f64 = 0.35;
pub const ECCENTRICITY: [f64; 2] = [0.30, 0.20];
/// Flow-anisotropy response k_n (ρ_n = k_n ε_n e^{−β n² η/s}) and acoustic damping β.
const FLOW_RESPONSE: [f64; 2] = [0.155, 0.224];
/// Shape response σ_n of the freeze-out boundary (s_n = σ_n ε_n e^{−β n² η/s}).
const SHAPE_RESPONSE: [f64; 2] = [0.221, 0.0446];
const ACOUSTIC_BETA: f64 = 0.8;
/// Flow profile ρ ∝ (r/R)^n.
const PROFILE_EXPONENT: f64 = 0.754;
/// The hadronic afterburner keeps cooling after particlization: momenta
/// are thermal at T_kin = this × T_sw (δf keeps T_sw, where it is created),
/// while each species keeps the number it had at T_sw (partial chemical
/// equilibrium: elastic scatterings cool, they do not change yields).
const KINETIC_T_FRACTION: f64 = 0.886;
/// Entropy per unit rapidity (dimensionless), 20–30% Au+Au at 200 GeV.
const ENTROPY_PER_RAPIDITY: f64 = 1925.0;

/// c_s² = dP/dε of the equation of state below (P = ε/8).
const SOUND_SPEED2: f64 = 1.0 / 8.0;

/// The equation of state: T (GeV) at energy density ε (GeV/fm³).
pub fn temperature(e: f64) -> f64 {
    0.155 * (e / 0.5).powf(1.0 / 9.0)
}

/// Entropy density s = 9ε/(8T), fm⁻³.
pub fn entropy_density(t: f64) -> f64 {
    let e = 0.5 * (t / 0.155).powi(9);
    9.0 * e / (8.0 * t)
}

/// `(η/s)_eff`: η/s(T) averaged over the Bjorken temperature history, weight T⁻⁴.
pub fn effective_eta_s(eta_s: &EtaOverS, t_sw: f64) -> f64 {
    let n = 200;
    let (mut num, mut den) = (0.0, 0.0);
    for k in 0..n {
        let t = t_sw + (T0 - t_sw) * (k as f64 + 0.5) / n as f64;
        let w = t.powi(-4);
        num += w * eta_s.at(t);
        den += w;
    }
    num / den
}

/// Freeze-out hypersurface and flow field for one parameter point.
#[derive(Clone, Copy, Debug)]
pub struct FreezeOut {
    pub t_sw: f64,
    /// fm
    pub tau: f64,
    /// fm
    pub radius: f64,
    pub rho_max: f64,
    /// ρ_2, ρ_3
    pub rho_n: [f64; 2],
    /// s_2, s_3: the boundary is `R(φ) = R (1 − 2 s_2 cos 2φ − 2 s_3 cos 3φ)`.
    pub shape_n: [f64; 2],
    pub eta_s_eff: f64,
    pub eta_s_sw: f64,
    pub zeta_s: f64,
    pub p_survival: f64,
}

impl FreezeOut {
    pub fn new(p: &HeavyIonParams) -> FreezeOut {
        let t_sw = temperature(p.e_sw);
        let eta_s_eff = effective_eta_s(&p.eta_s, t_sw);
        let tau = 7.5 * (0.2 / p.e_sw).powf(0.45);
        let ds_dy = ENTROPY_PER_RAPIDITY * (1.0 + 0.6 * eta_s_eff);
        let radius = (ds_dy / entropy_density(t_sw) / (std::f64::consts::PI * tau)).sqrt();
        let rho_max = 0.936 + 0.2 * (tau / 7.5).ln() + 0.3 * eta_s_eff;
        let damped = |k: usize, response: &[f64; 2]| {
            let n = (k + 2) as f64;
            response[k] * ECCENTRICITY[k] * (-ACOUSTIC_BETA * n * n * eta_s_eff).exp()
        };
        let rho_n = [0, 1].map(|k| damped(k, &FLOW_RESPONSE));
        let shape_n = [0, 1].map(|k| damped(k, &SHAPE_RESPONSE));
        FreezeOut {
            t_sw,
            tau,
            radius,
            rho_max,
            rho_n,
            shape_n,
            eta_s_eff,
            eta_s_sw: p.eta_s.at(t_sw),
            zeta_s: p.zeta_s,
            p_survival: p.p_survival,
        }
    }
}

/// Where the boundary ray at azimuth φ ends, and which way the flow there points.
#[derive(Clone, Copy, Debug)]
pub struct BoundaryPoint {
    /// R(φ)/R.
    pub radius: f64,
    /// φ_b, the azimuth of the boundary's outward normal.
    pub flow_azimuth: f64,
}

impl FreezeOut {
    /// The freeze-out boundary at azimuth φ. Cells on the ray share its
    /// normal direction (the level curves r/R(φ) = const are similar), so
    /// the flow is normal to every level curve, as in Retière and Lisa.
    pub fn boundary(&self, phi: f64) -> BoundaryPoint {
        let [s2, s3] = self.shape_n;
        let radius = 1.0 - 2.0 * s2 * (2.0 * phi).cos() - 2.0 * s3 * (3.0 * phi).cos();
        let slope = 4.0 * s2 * (2.0 * phi).sin() + 6.0 * s3 * (3.0 * phi).sin();
        // Normal of r = u R(φ): r̂ − (R'/R) φ̂.
        BoundaryPoint { radius, flow_azimuth: phi - (slope / radius).atan() }
    }
}

/// Smooth (infinite-statistics) observables in the analysis bins: for each
/// name in [`crate::base::paper_table::PAPER_TABLE_OBSERVABLES`], one value per pT.
pub fn observables(p: &HeavyIonParams, delta_f: DeltaF, pts: &[f64]) -> Vec<(&'static str, Vec<f64>)> {
    let fo = FreezeOut::new(p);
    let q = Quadrature::default();
    let mut ch = (vec![0.0; pts.len()], vec![0.0; pts.len()], vec![0.0; pts.len()]);
    let mut pi = (vec![0.0; pts.len()], vec![0.0; pts.len()]);
    let mut pr = (vec![0.0; pts.len()], vec![0.0; pts.len()]);
    for (k, &pt) in pts.iter().enumerate() {
        let (mut n, mut v2, mut v3) = (0.0, 0.0, 0.0);
        for s in SPECIES {
            let yf = yield_and_flow(&fo, &s, pt, delta_f, &q);
            // Charged hadrons are measured in η: dy/dη = p/E = pT/mT at mid-rapidity;
            // particle + antiparticle.
            let jac = pt / (pt * pt + s.mass * s.mass).sqrt();
            let y = 2.0 * yf.yield_ * jac;
            n += y;
            v2 += y * yf.v2;
            v3 += y * yf.v3;
            if s.pid == PION.pid {
                pi.0[k] = yf.yield_;
                pi.1[k] = yf.v2;
            } else if s.pid == PROTON.pid {
                pr.0[k] = yf.yield_;
                pr.1[k] = yf.v2;
            }
        }
        ch.0[k] = n;
        ch.1[k] = v2 / n;
        ch.2[k] = v3 / n;
    }
    vec![
        ("ch_spectrum", ch.0),
        ("ch_v2", ch.1),
        ("ch_v3", ch.2),
        ("pi_spectrum", pi.0),
        ("pi_v2", pi.1),
        ("p_spectrum", pr.0),
        ("p_v2", pr.1),
    ]
}

/// The paper's analysis bins: 10 bins over 0–2 GeV, represented by midpoints.
pub fn analysis_pt() -> Vec<f64> {
    (0..10).map(|k| 0.1 + 0.2 * k as f64).collect()
}

impl HeavyIonParams {
    /// From `name=value` pairs with the names of `design/*.toml`: either
    /// `eta_s, e_sw` or `T_kink, a_low, a_high, eta_s_kink, e_sw`.
    pub fn from_named(values: &[(String, f64)]) -> anyhow::Result<HeavyIonParams> {
        let get = |n: &str| values.iter().find(|(k, _)| k == n).map(|(_, v)| *v);
        let known = ["eta_s", "e_sw", "T_kink", "a_low", "a_high", "eta_s_kink", "zeta_s", "p_survival"];
        if let Some((k, _)) = values.iter().find(|(k, _)| !known.contains(&k.as_str())) {
            anyhow::bail!("unknown heavy-ion parameter '{k}' (use eta_s, e_sw, or T_kink, a_low, a_high, eta_s_kink, e_sw; candidates add zeta_s, p_survival)");
        }
        let e_sw = get("e_sw").ok_or_else(|| anyhow::anyhow!("missing parameter e_sw (GeV/fm^3)"))?;
        if !(e_sw > 0.0 && e_sw.is_finite()) {
            anyhow::bail!("e_sw = {e_sw}: the switching energy density must be positive and finite");
        }
        let eta_s = match (get("eta_s"), get("T_kink"), get("a_low"), get("a_high"), get("eta_s_kink")) {
            (Some(v), None, None, None, None) => EtaOverS::Constant(v),
            (None, Some(t_kink), Some(a_low), Some(a_high), Some(eta_s_kink)) => {
                EtaOverS::Kink { t_kink, a_low, a_high, eta_s_kink }
            }
            _ => anyhow::bail!("give either eta_s, or all four of T_kink, a_low, a_high, eta_s_kink"),
        };
        // A negative shear viscosity breaks the second law; NaN would pass every
        // later comparison and yield meaningless events.
        match eta_s {
            EtaOverS::Constant(v) if !(v >= 0.0 && v.is_finite()) => {
                anyhow::bail!("eta_s = {v}: the shear viscosity to entropy ratio must be finite and >= 0")
            }
            EtaOverS::Kink { t_kink, a_low, a_high, eta_s_kink }
                if ![t_kink, a_low, a_high, eta_s_kink].iter().all(|v| v.is_finite()) || !(eta_s_kink >= 0.0) =>
            {
                anyhow::bail!(
                    "T_kink = {t_kink}, a_low = {a_low}, a_high = {a_high}, eta_s_kink = {eta_s_kink}: need finite values and eta_s_kink >= 0"
                )
            }
            _ => {}
        }
        let zeta_s = get("zeta_s").unwrap_or(0.0);
        let p_survival = get("p_survival").unwrap_or(1.0);
        if !(zeta_s >= 0.0) || !(p_survival > 0.0) {
            anyhow::bail!("zeta_s = {zeta_s}, p_survival = {p_survival}: need zeta_s >= 0 and p_survival > 0");
        }
        Ok(HeavyIonParams { eta_s, e_sw, zeta_s, p_survival })
    }

    /// Parses `eta_s=0.1,e_sw=0.2`.
    pub fn parse(point: &str) -> anyhow::Result<HeavyIonParams> {
        let mut values = Vec::new();
        for part in point.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (k, v) =
                part.split_once('=').ok_or_else(|| anyhow::anyhow!("--point: expected name=value, got {part:?}"))?;
            let v: f64 = v.trim().parse().map_err(|_| anyhow::anyhow!("--point: {k} = {v:?} is not a number"))?;
            values.push((k.trim().to_string(), v));
        }
        Self::from_named(&values)
    }
}

/// Mean transverse momentum of a species over 0–3 GeV (GeV).
pub fn mean_pt(p: &HeavyIonParams, species: &Species, delta_f: DeltaF) -> f64 {
    let fo = FreezeOut::new(p);
    let q = Quadrature::default();
    let (mut num, mut den) = (0.0, 0.0);
    for k in 0..30 {
        let pt = 0.05 + 0.1 * k as f64;
        let y = yield_and_flow(&fo, species, pt, delta_f, &q).yield_ * pt;
        num += y * pt;
        den += y;
    }
    num / den
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ∫ p² e^{−E/T} dp = m² T K₂(m/T); the massive values are scipy's
    /// `m*m*T*scipy.special.kn(2, m/T)`.
    #[test]
    fn boltzmann_density_matches_the_bessel_function_form() {
        use super::cooper_frye::boltzmann_density;
        let t: f64 = 0.15;
        assert!((boltzmann_density(0.0, t) / (2.0 * t.powi(3)) - 1.0).abs() < 1e-12);
        for (m, t, expected) in [(0.938272, 0.124, 3.246313236662567e-05), (0.13957, 0.140, 0.004463628462056469)] {
            let got = boltzmann_density(m, t);
            assert!((got / expected - 1.0).abs() < 1e-10, "m = {m}, T = {t}: {got} vs {expected}");
        }
    }

    /// A circular boundary keeps radial flow; an elongated one turns the flow
    /// towards the short (in-plane) axis and is shortest in plane.
    #[test]
    fn boundary_normals_bunch_towards_the_short_axis() {
        let mut fo = FreezeOut::new(&HeavyIonParams::constant(0.1, 0.2));
        fo.shape_n = [0.0, 0.0];
        let b = fo.boundary(0.7);
        assert_eq!((b.radius, b.flow_azimuth), (1.0, 0.7));
        fo.shape_n = [0.05, 0.0];
        assert!(fo.boundary(0.0).radius < fo.boundary(std::f64::consts::FRAC_PI_2).radius);
        let phi = std::f64::consts::FRAC_PI_4;
        let b = fo.boundary(phi);
        assert!(b.flow_azimuth < phi && b.flow_azimuth > 0.0);
        // Numerical normal of the curve (R(φ) cos φ, R(φ) sin φ).
        let h = 1e-6;
        let point = |p: f64| {
            let r = fo.boundary(p).radius;
            (r * p.cos(), r * p.sin())
        };
        let (a, c) = (point(phi - h), point(phi + h));
        let (tx, ty) = (c.0 - a.0, c.1 - a.1);
        let normal = (-tx).atan2(ty);
        assert!((normal - b.flow_azimuth).abs() < 1e-8, "{normal} vs {}", b.flow_azimuth);
    }
}
