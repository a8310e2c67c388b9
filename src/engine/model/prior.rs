//! The prior over forms the search charges each discovered term, by each
//! form's number of operations.

/// The prior over forms: a term's prior weight falls by a factor e^λ with
/// each operation of its form (a whole power x^k counting k − 1), as in the
/// Bayesian machine scientist's prior learned from published equations
/// (Guimerà et al. 2020), where each further operation is rarer. Weights
/// are normalized over every term searched, so the search as a whole still
/// pays its look-elsewhere odds (the singles' odds sum to one against the
/// model as it is, as under the uniform 1 : N), and where the data cannot
/// tell two forms apart the simpler leads.
pub struct FormPrior {
    total: f64,
    squares: f64,
}

/// Nats of prior odds per operation: e^0.5 ≈ 1.65 times rarer each. Mild on
/// purpose: a periodic drive (7 operations) against a constant (none) pays
/// 3.5 nats, less than the 5σ effects the campaigns are built on carry.
const NATS_PER_OPERATION: f64 = 0.5;

impl FormPrior {
    fn weight(operations: usize) -> f64 {
        (-NATS_PER_OPERATION * operations as f64).exp()
    }

    /// The prior over every term searched, each given by its operations.
    pub fn over(operations: &[usize]) -> FormPrior {
        let w = operations.iter().map(|k| FormPrior::weight(*k));
        FormPrior { total: w.clone().sum(), squares: w.map(|w| w * w).sum() }
    }

    /// Prior log odds of a term (or a pair) against the model as it is. The
    /// pairs were chosen after the data ranked the singles, so a pair pays
    /// for every pair the grammar could make, not only the ten fitted.
    pub fn log_odds(&self, terms: &[usize]) -> f64 {
        let own: f64 = terms.iter().map(|k| FormPrior::weight(*k).ln()).sum();
        match terms.len() {
            1 => own - self.total.ln(),
            _ => own - (0.5 * (self.total * self.total - self.squares)).max(f64::MIN_POSITIVE).ln(),
        }
    }

    /// Prior log odds of corrections of several observables at once (of
    /// each of `observables`, all offered the same forms, none or one):
    /// normalized over every such choice of two or more, so that these too
    /// pay for every combination the grammar could make, as pairs do.
    pub fn log_odds_one_per_observable(&self, terms: &[usize], observables: usize) -> f64 {
        let own: f64 = terms.iter().map(|k| FormPrior::weight(*k).ln()).sum();
        let m = observables.max(2) as f64;
        let w = self.total / m;
        let choices = (m * w.ln_1p()).exp_m1() - m * w;
        own - choices.max(f64::MIN_POSITIVE).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_search_pays_its_look_elsewhere_odds_and_simpler_forms_lead() {
        let all = [0, 1, 1, 3, 3, 4, 7, 7];
        let prior = FormPrior::over(&all);
        // Singles' odds sum to one against the model as it is; so do pairs'.
        let singles: f64 = all.iter().map(|k| prior.log_odds(&[*k]).exp()).sum();
        assert!((singles - 1.0).abs() < 1e-12, "{singles}");
        let mut pairs = 0.0;
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                pairs += prior.log_odds(&[*a, *b]).exp();
            }
        }
        assert!((pairs - 1.0).abs() < 1e-12, "{pairs}");
        // Each operation costs NATS_PER_OPERATION.
        assert!((prior.log_odds(&[1]) - prior.log_odds(&[3]) - 2.0 * NATS_PER_OPERATION).abs() < 1e-12);
        // With every form the same size it is the uniform 1 : N.
        assert!((FormPrior::over(&[2; 38]).log_odds(&[2]) + 38f64.ln()).abs() < 1e-12);
    }

    /// Corrections of two or more observables at once: their odds sum to one.
    #[test]
    fn corrections_of_several_observables_pay_for_every_combination() {
        let forms = [1, 2, 3, 3];
        let observables = 3;
        let all: Vec<usize> = (0..observables).flat_map(|_| forms).collect();
        let prior = FormPrior::over(&all);
        // Each observable: no correction (None) or one of the forms.
        let choices: Vec<Option<usize>> = std::iter::once(None).chain(forms.iter().copied().map(Some)).collect();
        let mut sum = 0.0;
        for a in &choices {
            for b in &choices {
                for c in &choices {
                    let terms: Vec<usize> = [a, b, c].iter().filter_map(|t| **t).collect();
                    if terms.len() >= 2 {
                        sum += prior.log_odds_one_per_observable(&terms, observables).exp();
                    }
                }
            }
        }
        assert!((sum - 1.0).abs() < 1e-12, "{sum}");
    }
}
