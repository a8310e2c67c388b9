//! Corrections one coefficient shares across observables. Observables that
//! differ by a quantity the user names (the same cell discharged at several
//! currents, one spectrum at several energies or centralities) often carry
//! one missing effect whose size follows that quantity: a voltage drop R·I,
//! a gain growing with the energy. Fitted per observable, such an effect
//! costs one coefficient per observable and its law is never stated; shared,
//! it is one coefficient c and each observable's term is the grammar's form
//! with c·s_k in place of c, s_k the observable's value of the quantity
//! (`[model] observable_labels = { current = { v_low = 0.5, v_high = 1.0 } }`).
//! Only forms of one coefficient are shared (for several the scaling of each
//! is a choice of its own), and they form a class of their own in the prior
//! over forms, normalized over every (form, quantity) searched, as pairs
//! and singles are.

use super::discover::{EmulatedDiscoverer, Part, Screened};
use super::forms::{Form, Range, Scales};
use super::labels::Label;
use crate::base::config::ParamSpec;
use crate::engine::model::fit::Fitted;
use crate::engine::model::{ScreeningBlock, ScreeningData};

/// One shared correction before it is fitted: its parts and where its fit starts.
struct Draft {
    parts: Vec<Part>,
    starts: Vec<Vec<f64>>,
}

impl EmulatedDiscoverer {
    /// Every one-coefficient form of the grammar shared across the
    /// observables of each label, fitted with θ from `base`; with each
    /// searched term's size in nats (for their class of the prior).
    pub(super) fn screen_shared(
        &self,
        forms: &[Form],
        data: &ScreeningData,
        base: &Fitted,
    ) -> (Vec<Screened>, Vec<f64>) {
        let (mut screened, mut nats) = (Vec::new(), Vec::new());
        for label in &self.labels {
            let blocks = self.labelled_blocks(label, data);
            if blocks.len() < 2 {
                continue;
            }
            for (rank, form) in forms.iter().enumerate().filter(|(_, f)| f.parameters.len() == 1) {
                nats.push(form.nats);
                let Some(draft) = self.draft(form, rank, label, &blocks, base) else { continue };
                if let Some(mut s) = self.fit_parts(draft.parts, data, &draft.starts) {
                    s.shared_by = Some(label.name.clone());
                    screened.push(s);
                }
            }
        }
        (screened, nats)
    }

    /// The data's blocks of a label's observables, with each one's value.
    fn labelled_blocks<'d>(&self, label: &Label, data: &'d ScreeningData) -> Vec<(&'d ScreeningBlock<'d>, f64)> {
        let names = self.model.observable_names();
        data.blocks.iter().filter_map(|b| label.values.get(&names[b.model_index]).map(|s| (b, *s))).collect()
    }

    /// The form on every labelled observable with c·s_k for its coefficient.
    /// c's range is the form's on the observable of largest |s_k| divided by
    /// it: there the shared term is largest, and its size is the form's.
    fn draft(
        &self,
        form: &Form,
        rank: usize,
        label: &Label,
        blocks: &[(&ScreeningBlock, f64)],
        base: &Fitted,
    ) -> Option<Draft> {
        let (widest, s_max) = blocks.iter().max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))?;
        let range = form.ranges(&Scales::of(widest.x, widest.y))?.pop()?;
        let scaled = |v: f64| v / s_max;
        let (lo, hi) = (scaled(range.spec.min), scaled(range.spec.max));
        let range = Range {
            spec: ParamSpec { min: lo.min(hi), max: lo.max(hi), truth: None, units: String::new() },
            starts: range.starts.iter().map(|v| scaled(*v)).collect(),
        };
        let coefficient = form.parameters.keys().next()?;
        let shared = self.parameter(&format!("{coefficient}_per_{}", label.name), None);
        let names = self.model.observable_names();
        let parts = blocks
            .iter()
            .map(|(b, s)| {
                let observable = &names[b.model_index];
                let times = if *s < 0.0 { format!("({shared}*({s}))") } else { format!("({shared}*{s})") };
                Part {
                    form: form.clone(),
                    rank,
                    observable: observable.clone(),
                    ranges: vec![range.clone()],
                    parameters: vec![shared.clone()],
                    correction: form.render(observable, &|_| times.clone()),
                }
            })
            .collect();
        let starts = range.starts.iter().map(|u| base.phi.iter().copied().chain([*u]).collect()).collect();
        Some(Draft { parts, starts })
    }
}
