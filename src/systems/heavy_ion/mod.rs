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
pub mod events;
pub mod family;
pub mod figures;
pub mod mock;
mod runs;
pub mod study;

pub use candidates::*;
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

/// Invariant yield and flow of one species at one pT, mid-rapidity (y = 0).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct YieldAndFlow {
    /// dN/(2π pT dpT dy), GeV⁻², particle only (not antiparticle).
    pub yield_: f64,
    pub v2: f64,
    pub v3: f64,
}

/// ∫ p² e^{−E/T} dp (GeV³): the Boltzmann number density up to g/(2π²).
fn boltzmann_density(m: f64, t: f64) -> f64 {
    static NODES: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    // e^{−p/T} is below 1e-17 beyond 40 T.
    let p_max = 40.0 * t;
    NODES
        .get_or_init(|| gauss_legendre_unit(64))
        .iter()
        .map(|&(x, w)| {
            let p = p_max * x;
            p_max * w * p * p * (-(p * p + m * m).sqrt() / t).exp()
        })
        .sum()
}

/// Gauss–Legendre nodes and weights on [0, 1].
fn gauss_legendre_unit(n: usize) -> Vec<(f64, f64)> {
    // Newton iteration on P_n; fine for the small n used here.
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
            let dx = p1 / dp;
            x -= dx;
            if dx.abs() < 1e-15 {
                break;
            }
        }
        let w = 2.0 / ((1.0 - x * x) * dp * dp);
        out.push(((1.0 - x) / 2.0, w / 2.0));
    }
    out
}

/// Quadrature grids for the Cooper–Frye integral.
pub struct Quadrature {
    radial: Vec<(f64, f64)>,
    rapidity: Vec<(f64, f64)>,
    azimuth: usize,
    momentum_azimuth: usize,
}

impl Default for Quadrature {
    fn default() -> Self {
        // η_s ∈ [0, 3.5] covers the thermal smearing of every species at y = 0.
        Quadrature {
            radial: gauss_legendre_unit(12),
            rapidity: gauss_legendre_unit(16).into_iter().map(|(x, w)| (3.5 * x, 3.5 * w)).collect(),
            azimuth: 24,
            momentum_azimuth: 24,
        }
    }
}

/// Cooper–Frye on the τ = τ_f surface: `E dN/d³p = g/(2π)³ ∫ τ r dr dφ dη_s mT cosh η_s f`.
pub fn yield_and_flow(fo: &FreezeOut, species: &Species, pt: f64, delta_f: DeltaF, q: &Quadrature) -> YieldAndFlow {
    let m = species.mass;
    let mt = (pt * pt + m * m).sqrt();
    let t = fo.t_sw;
    let t_kin = KINETIC_T_FRACTION * t;
    let tau_gev = fo.tau / HBARC;
    let radius_gev = fo.radius / HBARC;
    // Navier–Stokes π_ii = −2η(θ_i − θ/3) in the fluid rest frame, so
    // δf/f0 = p^μ p^ν π_μν / (2(e+P)T²) = −(η/s)/T³ Σ_i (θ_i − θ/3) p_i*².
    let df_coeff = match delta_f {
        DeltaF::None => 0.0,
        DeltaF::Grad | DeltaF::GradTransverse => -fo.eta_s_sw / (t * t * t),
    };
    // Bulk δf (14-moment, relaxation-time form): Π = −ζ/τ from the Bjorken
    // expansion, β_Π = 15 (1/3 − c_s²)² (e+P), s T = e + P, so
    // δf/f0 = −(ζ/s) (p*²/(3E*) − c_s² E*) / (15 (1/3 − c_s²)² τ T²): fewer
    // fast particles, more slow heavy ones (Π < 0 lowers the pressure).
    let bulk_coeff = if fo.zeta_s > 0.0 {
        let gap = 1.0 / 3.0 - SOUND_SPEED2;
        -fo.zeta_s / (15.0 * gap * gap * tau_gev * t * t)
    } else {
        0.0
    };
    let (na, np) = (q.azimuth, q.momentum_azimuth);
    // Momentum-azimuth tables: the inner loop then needs no trigonometry.
    let tau = 2.0 * std::f64::consts::PI;
    let trig: Vec<(f64, f64, f64, f64)> = (0..np)
        .map(|ip| {
            let phip = tau * ip as f64 / np as f64;
            (phip.cos(), phip.sin(), (2.0 * phip).cos(), (3.0 * phip).cos())
        })
        .collect();
    let (mut n0, mut c2, mut c3) = (0.0, 0.0, 0.0);
    // With a = mT cosh ρ cosh η_s, b = pT sinh ρ and c = cos(φp − φb),
    // exp(−E*/T) = exp(−(a − b c)/T) = exp(−(a − |b|)/T) · exp(−(|b| − b c)/T):
    // the second factor, per momentum azimuth, is shared by every η_s. Both
    // exponents are ≤ 0 (a ≥ mT cosh ρ ≥ |b|, and |c| ≤ 1), whatever the
    // sign of ρ (a short τ_f makes ρ_max negative), so neither factor
    // overflows, and one underflows only where the whole does.
    let mut transverse = vec![0.0; np];
    for &(u, wu) in &q.radial {
        let r = u * fo.radius;
        for ia in 0..na {
            let phi = tau * ia as f64 / na as f64;
            let shape = fo.boundary(phi);
            // The flow points along the boundary's outward normal, φ_b.
            let (sin_phi, cos_phi) = shape.flow_azimuth.sin_cos();
            let anisotropy = 1.0
                + 2.0 * fo.rho_n[0] * (2.0 * shape.flow_azimuth).cos()
                + 2.0 * fo.rho_n[1] * (3.0 * shape.flow_azimuth).cos();
            let rho = fo.rho_max * u.powf(PROFILE_EXPONENT) * anisotropy;
            let (ch, sh) = (rho.cosh(), rho.sinh());
            // Expansion rates of u = (cosh ρ cosh η_s, sinh ρ n̂, cosh ρ sinh η_s) along
            // the longitudinal, normal and tangential rest-frame axes (GeV),
            // treating the boundary locally as a circle of radius R(φ).
            let (theta_z, theta_r, theta_phi) = if delta_f == DeltaF::GradTransverse {
                let local_radius = shape.radius * radius_gev;
                let drho_dr =
                    fo.rho_max * PROFILE_EXPONENT * u.powf(PROFILE_EXPONENT - 1.0) * anisotropy / local_radius;
                (ch / tau_gev, ch * drho_dr, sh / (u * local_radius))
            } else {
                (1.0 / tau_gev, 0.0, 0.0)
            };
            let third = (theta_z + theta_r + theta_phi) / 3.0;
            let (sig_z, sig_r, sig_phi) = (theta_z - third, theta_r - third, theta_phi - third);
            let b = pt * sh;
            for (g, &(cp, sp, _, _)) in transverse.iter_mut().zip(&trig) {
                *g = (-(b.abs() - b * (cp * cos_phi + sp * sin_phi)) / t_kin).exp();
            }
            for &(eta, we) in &q.rapidity {
                let (che, she) = (eta.cosh(), eta.sinh());
                let pz_star2 = (mt * she) * (mt * she);
                let a = mt * ch * che;
                let longitudinal = (-(a - b.abs()) / t_kin).exp();
                let w0 = wu * r * shape.radius * shape.radius * we * mt * che;
                for (&(cp, sp, c2p, c3p), &g) in trig.iter().zip(&transverse) {
                    let mut f = longitudinal * g;
                    if df_coeff != 0.0 {
                        let p_r = pt * (cp * cos_phi + sp * sin_phi);
                        let p_phi = pt * (sp * cos_phi - cp * sin_phi);
                        let p_r_star = ch * p_r - sh * mt * che;
                        f *=
                            1.0 + df_coeff * (sig_r * p_r_star * p_r_star + sig_phi * p_phi * p_phi + sig_z * pz_star2);
                    }
                    if bulk_coeff != 0.0 {
                        let e_star = a - b * (cp * cos_phi + sp * sin_phi);
                        // Floored at 0 like every regulated δf (only reached where f0 is negligible).
                        f *= (1.0 + bulk_coeff * ((e_star * e_star - m * m) / (3.0 * e_star) - SOUND_SPEED2 * e_star))
                            .max(0.0);
                    }
                    let w = w0 * f;
                    n0 += w;
                    c2 += w * c2p;
                    c3 += w * c3p;
                }
            }
        }
    }
    // Measure: r dr = R² u du; dφ, dφp = 2π/n each; η_s symmetric (×2); φp average = /np.
    let jac = fo.radius * 2.0 * std::f64::consts::PI / na as f64 * 2.0 / np as f64;
    let survival = if species.pid == PROTON.pid { fo.p_survival } else { 1.0 };
    let chemical = boltzmann_density(m, t) / boltzmann_density(m, t_kin);
    let norm = chemical * survival * species.feed_down * species.degeneracy / (2.0 * std::f64::consts::PI).powi(3)
        * tau_gev
        / (HBARC * HBARC);
    YieldAndFlow { yield_: norm * jac * n0, v2: c2 / n0, v3: c3 / n0 }
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
        if !(e_sw > 0.0) {
            anyhow::bail!("e_sw = {e_sw}: the switching energy density must be positive");
        }
        let eta_s = match (get("eta_s"), get("T_kink"), get("a_low"), get("a_high"), get("eta_s_kink")) {
            (Some(v), None, None, None, None) => EtaOverS::Constant(v),
            (None, Some(t_kink), Some(a_low), Some(a_high), Some(eta_s_kink)) => {
                EtaOverS::Kink { t_kink, a_low, a_high, eta_s_kink }
            }
            _ => anyhow::bail!("give either eta_s, or all four of T_kink, a_low, a_high, eta_s_kink"),
        };
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
