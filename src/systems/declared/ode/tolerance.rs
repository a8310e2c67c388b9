//! How precisely an integration must follow the solution: no more than the
//! data can tell apart.
//!
//! An integrator's error is a bias in every prediction; it is harmless once
//! it is a small share of the measurements' errors, and each tenfold in
//! precision costs DOP853 another third in steps (work ∝ tol^(−1/8)). So a
//! model whose `[model.solver]` leaves `rtol` unset integrates with a local
//! tolerance of a thousandth of the data's finest relative error (the
//! smallest error over the largest |value| of an observable), never looser
//! than 1e-6, the default of Stan's ODE solvers, nor tighter than 1e-12;
//! `atol` defaults to `rtol / 100`. Before any data are seen it is 1e-8, as
//! it always was. A declared tolerance is used as written.
//!
//! The rule reads an observable's relative error as its state's, which
//! holds only where the observable is a state itself: an observable that
//! is a formula of the state (a difference of large states, a rescaled
//! one) keeps the model at 1e-8. And `atol` is absolute, so it is scaled
//! down with the data where an observed state is smaller than 1: a state
//! of size 1e-9 is not followed to 1e-8 absolute.

use crate::systems::declared::declaration::SolverSettings;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The tolerance before any data are seen.
const UNSEEN_RTOL: f64 = 1e-8;
/// The loosest tolerance the data may ask for.
const LOOSEST_RTOL: f64 = 1e-6;
/// The tightest: near double precision's own rounding DOP853's step-size
/// control can fail, and a failed integration costs its θ its likelihood;
/// 1e-12 is tested to integrate (`ode::tests`).
const TIGHTEST_RTOL: f64 = 1e-12;
/// The integrator's local error as a share of the data's relative error.
const SHARE_OF_ERROR: f64 = 1e-3;
/// `atol` as a share of `rtol` when neither is declared.
const ATOL_PER_RTOL: f64 = 1e-2;

/// What the data a model has seen say of the precision it needs: their
/// finest relative error and the smallest scale of an observed state (both
/// only fall), and whether an observable other than a state was noted.
pub(super) struct Precision {
    relative: AtomicU64,
    scale: AtomicU64,
    indirect: AtomicBool,
}

/// Lowers the f64 held in `cell` to `value` when `value` is smaller.
fn lower(cell: &AtomicU64, value: f64) {
    let _ = cell.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |old| {
        (value < f64::from_bits(old)).then_some(value.to_bits())
    });
}

impl Precision {
    pub fn unseen() -> Precision {
        let inf = f64::INFINITY.to_bits();
        Precision { relative: AtomicU64::new(inf), scale: AtomicU64::new(inf), indirect: AtomicBool::new(false) }
    }

    /// Notes one observable's measurements: their smallest positive error
    /// over their largest |value|, when the observable is a state (`state`);
    /// nothing when either is missing.
    pub fn note(&self, values: &[f64], errors: &[f64], state: bool) {
        if !state {
            self.indirect.store(true, Ordering::Relaxed);
            return;
        }
        let largest = values.iter().fold(0.0_f64, |m, y| m.max(y.abs()));
        let smallest = errors.iter().copied().filter(|e| *e > 0.0).fold(f64::INFINITY, f64::min);
        let relative = smallest / largest;
        if !(relative.is_finite() && relative > 0.0) {
            return;
        }
        lower(&self.relative, relative);
        lower(&self.scale, largest);
    }

    /// The finest relative error, infinite when the data cannot say.
    fn get(&self) -> f64 {
        if self.indirect.load(Ordering::Relaxed) {
            return f64::INFINITY;
        }
        f64::from_bits(self.relative.load(Ordering::Relaxed))
    }

    /// (rtol, atol): the declared ones, else as precise as the data need.
    pub fn tolerances(&self, declared: &SolverSettings) -> (f64, f64) {
        let rtol = declared.rtol.unwrap_or_else(|| rtol_for(self.get()));
        let scale =
            if self.get().is_finite() { f64::from_bits(self.scale.load(Ordering::Relaxed)).min(1.0) } else { 1.0 };
        let atol = declared.atol.unwrap_or(rtol * ATOL_PER_RTOL * scale);
        (rtol, atol)
    }
}

impl Precision {
    /// The tolerances in words, with where they came from.
    pub fn describe(&self, declared: &SolverSettings) -> String {
        let (rtol, atol) = self.tolerances(declared);
        let source = match (declared.rtol, self.get()) {
            (Some(_), _) => "as declared".to_string(),
            (None, p) if p.is_finite() => format!("from the data's finest relative error, {p:.2e}"),
            (None, _) if self.indirect.load(Ordering::Relaxed) => "an observable is no state: the default".to_string(),
            (None, _) => "no data seen".to_string(),
        };
        format!("rtol {rtol:.0e}, atol {atol:.0e} ({source})")
    }
}

/// The relative tolerance for data of this finest relative error.
fn rtol_for(relative_error: f64) -> f64 {
    if !relative_error.is_finite() {
        return UNSEEN_RTOL;
    }
    (SHARE_OF_ERROR * relative_error).clamp(TIGHTEST_RTOL, LOOSEST_RTOL)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unset() -> SolverSettings {
        SolverSettings { rtol: None, atol: None, max_steps: 1 }
    }

    #[test]
    fn the_tolerance_follows_the_finest_data_and_a_declared_one_wins() {
        let p = Precision::unseen();
        assert_eq!(p.tolerances(&unset()), (1e-8, 1e-10), "before data: as before");
        // 1% data: a thousandth of it is 1e-5, looser than the loosest.
        p.note(&[2.0, -10.0], &[0.1, 0.3], true);
        assert_eq!(p.tolerances(&unset()), (1e-6, 1e-8));
        // Data ten thousand times finer tighten it; coarser data later do not loosen it.
        p.note(&[5.0, 1.0], &[5e-6, 0.0], true);
        let (rtol, atol) = p.tolerances(&unset());
        assert!((rtol - 1e-9).abs() < 1e-22 && (atol - 1e-11).abs() < 1e-24, "{rtol} {atol}");
        p.note(&[1.0], &[0.5], true);
        assert!((p.tolerances(&unset()).0 - 1e-9).abs() < 1e-22);
        // Values all zero or no positive error say nothing.
        p.note(&[0.0, 0.0], &[1e-30], true);
        p.note(&[1.0], &[0.0], true);
        assert!((p.tolerances(&unset()).0 - 1e-9).abs() < 1e-22);
        let declared = SolverSettings { rtol: Some(1e-4), atol: None, max_steps: 1 };
        let (rtol, atol) = p.tolerances(&declared);
        assert!(rtol == 1e-4 && (atol - 1e-6).abs() < 1e-19, "{rtol} {atol}");
        // Data finer than any integration can follow ask for the tightest it can.
        let fine = Precision::unseen();
        fine.note(&[1.0], &[1e-14], true);
        assert_eq!(fine.tolerances(&unset()).0, 1e-12);
        let both = SolverSettings { rtol: None, atol: Some(1e-3), max_steps: 1 };
        assert!((p.tolerances(&both).0 - 1e-9).abs() < 1e-22 && p.tolerances(&both).1 == 1e-3);
        // A state observed at the size of 1e-6 scales atol down with it.
        let small = Precision::unseen();
        small.note(&[2e-6, 1e-6], &[2e-8, 2e-8], true);
        let (rtol, atol) = small.tolerances(&unset());
        assert!(rtol == 1e-6 && (atol - 1e-8 * 2e-6).abs() < 1e-25, "{rtol} {atol}");
        // An observable that is a formula of the state says nothing of the
        // state's precision: the model stays at the default.
        small.note(&[300.0], &[1.0], false);
        assert_eq!(small.tolerances(&unset()), (1e-8, 1e-10));
        assert!(small.describe(&unset()).contains("an observable is no state"));
    }
}
