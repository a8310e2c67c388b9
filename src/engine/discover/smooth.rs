//! A measured series smoothed by a Gaussian process, with its first and
//! second derivatives and their uncertainties: where a state is observed,
//! the rate its law must supply along the data is read off the data
//! themselves, not off a model that may be far from them.
//!
//! The process is y(t) = a + b t + f(t) + ε: a line with a broad prior
//! (the series' level and trend), a squared-exponential f with amplitude σ
//! and length ℓ, and the measurement errors ε as given. σ and ℓ maximize
//! the marginal likelihood over a grid (Rasmussen & Williams 2006, §5.4);
//! the derivatives are those of the posterior mean, their variances those
//! of the posterior of f′ and f″ (R&W §9.4), so a rate the data cannot
//! resolve (a fast oscillation sampled coarsely) comes with a large error.

use crate::engine::gp::CholeskyWorkspace;

/// A series and its derivatives at the times it was measured.
#[derive(Clone, Debug)]
pub struct Smoothed {
    pub value: Vec<f64>,
    pub rate: Vec<f64>,
    pub rate_sd: Vec<f64>,
    pub second: Vec<f64>,
    pub second_sd: Vec<f64>,
}

/// Lengths tried, as fractions of the span, from a little under the
/// spacing of the points to twice the span.
const LENGTHS: usize = 24;
/// Amplitudes tried, as multiples of the series' scatter about its line.
const AMPLITUDES: [f64; 9] = [0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0];

/// The line's prior sd, in units of the series' own size: broad enough
/// that the level and the trend are the data's, not the prior's.
const LINE_PRIOR: f64 = 10.0;

struct Kernel {
    amplitude2: f64,
    length: f64,
    line2: f64,
    centre: f64,
    scale: f64,
}

impl Kernel {
    /// k(s, t) and its derivatives: ∂k/∂s, ∂²k/∂s∂t, ∂²k/∂s², ∂⁴k/∂s²∂t².
    fn at(&self, s: f64, t: f64) -> [f64; 5] {
        let r = s - t;
        let l2 = self.length * self.length;
        let e = self.amplitude2 * (-0.5 * r * r / l2).exp();
        let (us, ut) = ((s - self.centre) / self.scale, (t - self.centre) / self.scale);
        let line = self.line2 * (1.0 + us * ut);
        let ds_line = self.line2 * ut / self.scale;
        let dsdt_line = self.line2 / (self.scale * self.scale);
        [
            e + line,
            -e * r / l2 + ds_line,
            e * (1.0 / l2 - r * r / (l2 * l2)) + dsdt_line,
            e * (r * r / (l2 * l2) - 1.0 / l2),
            e * (3.0 / (l2 * l2) - 6.0 * r * r / (l2 * l2 * l2) + r.powi(4) / (l2 * l2 * l2 * l2)),
        ]
    }
}

/// The series `y` measured at `t` with 1σ errors `sd` (times increasing),
/// smoothed; None for fewer than four points or non-finite input.
pub fn smooth(t: &[f64], y: &[f64], sd: &[f64]) -> Option<Smoothed> {
    let n = t.len();
    if n < 4 || y.len() != n || sd.len() != n {
        return None;
    }
    if t.iter().chain(y).chain(sd).any(|v| !v.is_finite()) || sd.iter().any(|s| *s <= 0.0) {
        return None;
    }
    let (lo, hi) = (t[0].min(t[n - 1]), t[0].max(t[n - 1]));
    let span = hi - lo;
    if span <= 0.0 {
        return None;
    }
    let size = y.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(sd.iter().fold(0.0f64, |m, v| m.max(*v)));
    let scatter = scatter_about_line(t, y).max(sd.iter().sum::<f64>() / n as f64);
    let spacing = span / (n - 1) as f64;
    let mut best: Option<(f64, Kernel)> = None;
    for i in 0..LENGTHS {
        let length = 0.7 * spacing * (2.0 * span / (0.7 * spacing)).powf(i as f64 / (LENGTHS - 1) as f64);
        for a in AMPLITUDES {
            let kernel = Kernel {
                amplitude2: (a * scatter).powi(2),
                length,
                line2: (LINE_PRIOR * size).powi(2),
                centre: 0.5 * (lo + hi),
                scale: 0.5 * span,
            };
            let Some(evidence) = log_marginal(&kernel, t, y, sd) else { continue };
            if best.as_ref().is_none_or(|(b, _)| evidence > *b) {
                best = Some((evidence, kernel));
            }
        }
    }
    let (_, kernel) = best?;
    posterior(&kernel, t, y, sd)
}

/// The rms of the series about its least-squares line.
fn scatter_about_line(t: &[f64], y: &[f64]) -> f64 {
    let n = t.len() as f64;
    let (mt, my) = (t.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let stt: f64 = t.iter().map(|t| (t - mt).powi(2)).sum();
    let sty: f64 = t.iter().zip(y).map(|(t, y)| (t - mt) * (y - my)).sum();
    let b = if stt > 0.0 { sty / stt } else { 0.0 };
    (t.iter().zip(y).map(|(t, y)| (y - my - b * (t - mt)).powi(2)).sum::<f64>() / n).sqrt()
}

fn covariance(kernel: &Kernel, t: &[f64], sd: &[f64]) -> CholeskyWorkspace {
    let n = t.len();
    let mut chol = CholeskyWorkspace::new(n);
    for j in 0..n {
        for i in j..n {
            chol.factor[j * n + i] = kernel.at(t[i], t[j])[0] + if i == j { sd[i] * sd[i] } else { 0.0 };
        }
    }
    chol
}

fn log_marginal(kernel: &Kernel, t: &[f64], y: &[f64], sd: &[f64]) -> Option<f64> {
    let mut chol = covariance(kernel, t, sd);
    if !chol.factorize_exact() {
        return None;
    }
    let mut z = y.to_vec();
    chol.solve_lower_in_place(&mut z);
    let fit: f64 = z.iter().map(|v| v * v).sum();
    let value = -0.5 * fit - 0.5 * chol.log_det();
    value.is_finite().then_some(value)
}

fn posterior(kernel: &Kernel, t: &[f64], y: &[f64], sd: &[f64]) -> Option<Smoothed> {
    let n = t.len();
    let mut chol = covariance(kernel, t, sd);
    if !chol.factorize_exact() {
        return None;
    }
    let mut alpha = y.to_vec();
    chol.solve_in_place(&mut alpha);
    let mut out = Smoothed {
        value: vec![0.0; n],
        rate: vec![0.0; n],
        rate_sd: vec![0.0; n],
        second: vec![0.0; n],
        second_sd: vec![0.0; n],
    };
    let (mut d1, mut d2) = (vec![0.0; n], vec![0.0; n]);
    for (i, &s) in t.iter().enumerate() {
        let mut value = 0.0;
        for j in 0..n {
            let k = kernel.at(s, t[j]);
            value += k[0] * alpha[j];
            d1[j] = k[1];
            d2[j] = k[3];
        }
        let at = kernel.at(s, s);
        out.value[i] = value;
        out.rate[i] = d1.iter().zip(&alpha).map(|(a, b)| a * b).sum();
        out.second[i] = d2.iter().zip(&alpha).map(|(a, b)| a * b).sum();
        // Var f′(s) = ∂²k(s,s)/∂s∂t − d1ᵀ K⁻¹ d1, and so for f″.
        chol.solve_lower_in_place(&mut d1);
        chol.solve_lower_in_place(&mut d2);
        let v1 = at[2] - d1.iter().map(|v| v * v).sum::<f64>();
        let v2 = at[4] - d2.iter().map(|v| v * v).sum::<f64>();
        out.rate_sd[i] = v1.max(0.0).sqrt();
        out.second_sd[i] = v2.max(0.0).sqrt();
    }
    let finite = out.value.iter().chain(&out.rate).chain(&out.second).all(|v| v.is_finite());
    finite.then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A damped cosine measured at 40 times with 1% noise: the smoothed
    /// rate and its second derivative against the closed form, within a
    /// few of their own standard errors at most points.
    #[test]
    fn derivatives_of_a_noisy_damped_cosine_match_the_closed_form() {
        let f = |t: f64| (-0.2 * t).exp() * (1.3 * t).cos();
        let df = |t: f64| (-0.2 * t).exp() * (-0.2 * (1.3 * t).cos() - 1.3 * (1.3 * t).sin());
        let d2f = |t: f64| (-0.2 * t).exp() * ((0.04 - 1.69) * (1.3 * t).cos() + 2.0 * 0.2 * 1.3 * (1.3 * t).sin());
        let t: Vec<f64> = (1..=40).map(|i| 0.25 * i as f64).collect();
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.01).unwrap();
        let y: Vec<f64> = t.iter().map(|t| f(*t) + noise.sample(&mut rng)).collect();
        let sd = vec![0.01; t.len()];
        let s = smooth(&t, &y, &sd).unwrap();
        // Pulls of the rate: most within 3 sd, the ends (one-sided) aside.
        let inner = 2..t.len() - 2;
        let pulls: Vec<f64> = inner.clone().map(|i| (s.rate[i] - df(t[i])) / s.rate_sd[i]).collect();
        let within = pulls.iter().filter(|p| p.abs() < 3.0).count();
        assert!(within * 10 >= pulls.len() * 9, "rate pulls {pulls:?}");
        // And the rate is accurate in absolute terms: a few percent of its size.
        let worst = inner.clone().map(|i| (s.rate[i] - df(t[i])).abs()).fold(0.0, f64::max);
        assert!(worst < 0.06, "worst rate error {worst}");
        let worst2 = inner.map(|i| (s.second[i] - d2f(t[i])).abs()).fold(0.0, f64::max);
        assert!(worst2 < 0.25, "worst second-derivative error {worst2}");
    }

    #[test]
    fn too_few_points_or_bad_input_give_none() {
        assert!(smooth(&[0.0, 1.0, 2.0], &[1.0, 2.0, 3.0], &[0.1; 3]).is_none());
        assert!(smooth(&[0.0, 1.0, 2.0, 3.0], &[1.0, f64::NAN, 3.0, 4.0], &[0.1; 4]).is_none());
        assert!(smooth(&[0.0, 1.0, 2.0, 3.0], &[1.0, 2.0, 3.0, 4.0], &[0.1, 0.0, 0.1, 0.1]).is_none());
        assert!(smooth(&[1.0; 4], &[1.0, 2.0, 3.0, 4.0], &[0.1; 4]).is_none());
    }

    /// A straight line is exactly a line: its rate is the slope, with a small error.
    #[test]
    fn a_line_has_its_slope_as_rate() {
        let t: Vec<f64> = (0..20).map(|i| i as f64).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 - 0.5 * t).collect();
        let s = smooth(&t, &y, &[0.01; 20]).unwrap();
        for (r, sd) in s.rate.iter().zip(&s.rate_sd) {
            assert!((r + 0.5).abs() < 1e-3 && *sd < 0.01, "{r} ± {sd}");
        }
    }
}
