//! The Cooper–Frye integral over the blast wave's freeze-out surface: the
//! invariant yield and v2, v3 of one species at one pT, with the shear and
//! bulk δf, on fixed Gauss–Legendre and uniform azimuthal grids.

use super::{DeltaF, FreezeOut, Species, HBARC, KINETIC_T_FRACTION, PROFILE_EXPONENT, PROTON, SOUND_SPEED2};

/// Invariant yield and flow of one species at one pT, mid-rapidity (y = 0).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct YieldAndFlow {
    /// dN/(2π pT dpT dy), GeV⁻², particle only (not antiparticle).
    pub yield_: f64,
    pub v2: f64,
    pub v3: f64,
}

/// ∫ p² e^{−E/T} dp (GeV³): the Boltzmann number density up to g/(2π²).
pub(super) fn boltzmann_density(m: f64, t: f64) -> f64 {
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

/// One momentum azimuth's factors in one surface cell: what does not
/// depend on η_s, computed once per cell.
#[derive(Clone, Copy, Default)]
struct Azimuthal {
    transverse: f64,
    b_along: f64,
    p_r: f64,
    phi_term: f64,
    c2p: f64,
    c3p: f64,
}

/// One cell (u, φ) of the freeze-out surface: its measure, flow rapidity
/// and the shear of its expansion rates.
struct Cell {
    /// w_u r R(φ)², the cell's share of the measure before η_s.
    measure: f64,
    cosh_rho: f64,
    sinh_rho: f64,
    cos_phi: f64,
    sin_phi: f64,
    /// θ_i − θ/3 along the longitudinal, normal and tangential axes (GeV).
    sigma: [f64; 3],
}

fn cell(fo: &FreezeOut, (u, wu): (f64, f64), phi: f64, delta_f: DeltaF, tau_gev: f64) -> Cell {
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
        let local_radius = shape.radius * (fo.radius / HBARC);
        let drho_dr = fo.rho_max * PROFILE_EXPONENT * u.powf(PROFILE_EXPONENT - 1.0) * anisotropy / local_radius;
        (ch / tau_gev, ch * drho_dr, sh / (u * local_radius))
    } else {
        (1.0 / tau_gev, 0.0, 0.0)
    };
    let third = (theta_z + theta_r + theta_phi) / 3.0;
    Cell {
        measure: wu * (u * fo.radius) * shape.radius * shape.radius,
        cosh_rho: ch,
        sinh_rho: sh,
        cos_phi,
        sin_phi,
        sigma: [theta_z - third, theta_r - third, theta_phi - third],
    }
}

/// The δf coefficients: shear (Grad) and bulk (14-moment, relaxation time).
fn viscous_coefficients(fo: &FreezeOut, delta_f: DeltaF, tau_gev: f64) -> (f64, f64) {
    let t = fo.t_sw;
    // Navier–Stokes π_ii = −2η(θ_i − θ/3) in the fluid rest frame, so
    // δf/f0 = p^μ p^ν π_μν / (2(e+P)T²) = −(η/s)/T³ Σ_i (θ_i − θ/3) p_i*².
    let shear = match delta_f {
        DeltaF::None => 0.0,
        DeltaF::Grad | DeltaF::GradTransverse => -fo.eta_s_sw / (t * t * t),
    };
    // Bulk δf (14-moment, relaxation-time form): Π = −ζ/τ from the Bjorken
    // expansion, β_Π = 15 (1/3 − c_s²)² (e+P), s T = e + P, so
    // δf/f0 = −(ζ/s) (p*²/(3E*) − c_s² E*) / (15 (1/3 − c_s²)² τ T²): fewer
    // fast particles, more slow heavy ones (Π < 0 lowers the pressure).
    let bulk = if fo.zeta_s > 0.0 {
        let gap = 1.0 / 3.0 - SOUND_SPEED2;
        -fo.zeta_s / (15.0 * gap * gap * tau_gev * t * t)
    } else {
        0.0
    };
    (shear, bulk)
}

/// Cooper–Frye on the τ = τ_f surface: `E dN/d³p = g/(2π)³ ∫ τ r dr dφ dη_s mT cosh η_s f`.
///
/// With a = mT cosh ρ cosh η_s, b = pT sinh ρ and c = cos(φp − φb),
/// exp(−E*/T) = exp(−(a − b c)/T) = exp(−(a − |b|)/T) · exp(−(|b| − b c)/T):
/// the second factor, per momentum azimuth, is shared by every η_s. Both
/// exponents are ≤ 0 (a ≥ mT cosh ρ ≥ |b|, and |c| ≤ 1), whatever the
/// sign of ρ (a short τ_f makes ρ_max negative), so neither factor
/// overflows, and one underflows only where the whole does.
pub fn yield_and_flow(fo: &FreezeOut, species: &Species, pt: f64, delta_f: DeltaF, q: &Quadrature) -> YieldAndFlow {
    let m = species.mass;
    let mt = (pt * pt + m * m).sqrt();
    let t_kin = KINETIC_T_FRACTION * fo.t_sw;
    let tau_gev = fo.tau / HBARC;
    let (df_coeff, bulk_coeff) = viscous_coefficients(fo, delta_f, tau_gev);
    let (na, np) = (q.azimuth, q.momentum_azimuth);
    // Momentum-azimuth tables: the inner loop then needs no trigonometry.
    let tau = 2.0 * std::f64::consts::PI;
    let trig: Vec<(f64, f64, f64, f64)> = (0..np)
        .map(|ip| {
            let phip = tau * ip as f64 / np as f64;
            (phip.cos(), phip.sin(), (2.0 * phip).cos(), (3.0 * phip).cos())
        })
        .collect();
    // What depends on η_s alone, once per call: (cosh η_s, p_z*², weight).
    let rapidity: Vec<(f64, f64, f64)> = q
        .rapidity
        .iter()
        .map(|&(eta, we)| {
            let (che, she) = (eta.cosh(), eta.sinh());
            (che, (mt * she) * (mt * she), we)
        })
        .collect();
    let mut azimuthal = vec![Azimuthal::default(); np];
    let (mut n0, mut c2, mut c3) = (0.0, 0.0, 0.0);
    for &node in &q.radial {
        for ia in 0..na {
            let c = cell(fo, node, tau * ia as f64 / na as f64, delta_f, tau_gev);
            let (ch, sh) = (c.cosh_rho, c.sinh_rho);
            let [sig_z, sig_r, sig_phi] = c.sigma;
            let b = pt * sh;
            for (az, &(cp, sp, c2p, c3p)) in azimuthal.iter_mut().zip(&trig) {
                let along = cp * c.cos_phi + sp * c.sin_phi;
                let p_phi = pt * (sp * c.cos_phi - cp * c.sin_phi);
                *az = Azimuthal {
                    transverse: (-(b.abs() - b * along) / t_kin).exp(),
                    b_along: b * along,
                    p_r: pt * along,
                    phi_term: sig_phi * p_phi * p_phi,
                    c2p,
                    c3p,
                };
            }
            for &(che, pz_star2, we) in &rapidity {
                let a = mt * ch * che;
                let longitudinal = (-(a - b.abs()) / t_kin).exp();
                let w0 = c.measure * we * mt * che;
                let boost = sh * mt * che;
                for az in &azimuthal {
                    let mut f = longitudinal * az.transverse;
                    if df_coeff != 0.0 {
                        let p_r_star = ch * az.p_r - boost;
                        f *= 1.0 + df_coeff * (sig_r * p_r_star * p_r_star + az.phi_term + sig_z * pz_star2);
                    }
                    if bulk_coeff != 0.0 {
                        let e_star = a - az.b_along;
                        // Floored at 0 like every regulated δf (only reached where f0 is negligible).
                        f *= (1.0 + bulk_coeff * ((e_star * e_star - m * m) / (3.0 * e_star) - SOUND_SPEED2 * e_star))
                            .max(0.0);
                    }
                    let w = w0 * f;
                    n0 += w;
                    c2 += w * az.c2p;
                    c3 += w * az.c3p;
                }
            }
        }
    }
    // Measure: r dr = R² u du; dφ, dφp = 2π/n each; η_s symmetric (×2); φp average = /np.
    let jac = fo.radius * 2.0 * std::f64::consts::PI / na as f64 * 2.0 / np as f64;
    let survival = if species.pid == PROTON.pid { fo.p_survival } else { 1.0 };
    let chemical = boltzmann_density(m, fo.t_sw) / boltzmann_density(m, t_kin);
    let norm = chemical * survival * species.feed_down * species.degeneracy / (2.0 * std::f64::consts::PI).powi(3)
        * tau_gev
        / (HBARC * HBARC);
    YieldAndFlow { yield_: norm * jac * n0, v2: c2 / n0, v3: c3 / n0 }
}
