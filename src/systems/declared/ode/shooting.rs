//! Multiple shooting from the data: how discovery screens a flow that one
//! trajectory cannot follow by least squares.
//!
//! Along a chaotic flow sampled a few times a turn, the χ² of a trajectory
//! from t0 is a landscape of narrow basins: a fit started from the model
//! as declared ends in whichever it starts in, so every candidate term
//! looks alike and the screening names noise (measured on ODEBench's
//! Lorenz, Rössler and Chen–Lee cases: a right form among the first three
//! in 0 of 20). Restarted from the measured state at each anchor (a data
//! time at which every state was measured, about `every` after the last),
//! a model predicts each point from the trajectory of the last anchor
//! before it, the first stretch from t0 and the declared initial values:
//! the χ² then measures how well the law moves the measured state over one
//! stretch, smooth in θ, and a term's fit finds the basin it belongs in.
//!
//! This is a screening device only: the anchors are data, so such a model's
//! predictions depend on the measurements, and its χ² ignores the anchors'
//! errors. Every calibration, and so every verdict, integrates one
//! trajectory from t0. The anchors are those of the data the model was last
//! told of (`note_measurements`): one such model screens one data set.

use super::dense::Dense;
use super::OdeModel;
use crate::systems::declared::declaration::MAX_NAMES;
use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, RwLock};

/// Where the model restarts: a data time at which every state was
/// measured, and the measured states.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Anchor {
    pub t: f64,
    pub state: Vec<f64>,
}

/// The anchors of the data last noted, and which data they are.
#[derive(Default)]
pub(super) struct Anchors {
    generation: u64,
    pub list: Vec<Anchor>,
}

impl Anchors {
    /// The stretch a time belongs to: 0 from t0, k from anchor k − 1. A
    /// point at an anchor's time is predicted by the stretch before it.
    fn stretch_of(&self, t: f64) -> usize {
        self.list.partition_point(|a| a.t < t)
    }
}

static GENERATION: AtomicU64 = AtomicU64::new(1);

pub(super) struct Shooting {
    pub every: f64,
    n_states: usize,
    /// Per observable: the state it measures as itself.
    state_of: Vec<Option<usize>>,
    noted: RwLock<Noted>,
}

/// What the data said, per observable: its times (`check_inputs`), then
/// its values (`note_measurements`).
struct Noted {
    times: Vec<Option<Vec<f64>>>,
    values: Vec<Option<Vec<f64>>>,
    anchors: Arc<Anchors>,
}

impl Shooting {
    pub fn new(every: f64, state_of: Vec<Option<usize>>, n_states: usize) -> Shooting {
        let n = state_of.len();
        let noted = Noted { times: vec![None; n], values: vec![None; n], anchors: Arc::default() };
        Shooting { every, n_states, state_of, noted: RwLock::new(noted) }
    }

    pub fn note_times(&self, observable: usize, x: &[f64]) {
        let mut noted = self.noted.write().unwrap_or_else(|e| e.into_inner());
        if let Some(slot) = noted.times.get_mut(observable) {
            *slot = Some(x.to_vec());
        }
    }

    /// Stores an observable's values and rebuilds the anchors from every
    /// state's latest data.
    pub fn note_values(&self, observable: usize, values: &[f64], t0: f64) {
        let mut noted = self.noted.write().unwrap_or_else(|e| e.into_inner());
        if let Some(slot) = noted.values.get_mut(observable) {
            *slot = Some(values.to_vec());
        }
        let list = self.anchors_from(&noted, t0);
        if list != noted.anchors.list {
            noted.anchors = Arc::new(Anchors { generation: GENERATION.fetch_add(1, Ordering::Relaxed), list });
        }
    }

    pub fn anchors(&self) -> Arc<Anchors> {
        self.noted.read().unwrap_or_else(|e| e.into_inner()).anchors.clone()
    }

    /// Anchors about `every` apart, at times where every state was
    /// measured: the first such time at least `every` after the last
    /// anchor (t0 first). None while some state has no data.
    fn anchors_from(&self, noted: &Noted, t0: f64) -> Vec<Anchor> {
        let mut series: Vec<Option<Vec<(f64, f64)>>> = vec![None; self.n_states];
        for (o, state) in self.state_of.iter().enumerate() {
            let (Some(m), Some(t), Some(y)) = (state, &noted.times[o], &noted.values[o]) else { continue };
            if t.len() == y.len() && series[*m].is_none() {
                let mut points: Vec<(f64, f64)> = t.iter().copied().zip(y.iter().copied()).collect();
                points.sort_by(|a, b| a.0.total_cmp(&b.0));
                series[*m] = Some(points);
            }
        }
        let Some(series) = series.into_iter().collect::<Option<Vec<_>>>() else { return Vec::new() };
        let Some(first) = series.first() else { return Vec::new() };
        let mut anchors = Vec::new();
        let mut last = t0;
        for &(t, _) in first {
            // A relative slack: data times written as decimals (0.1·k) miss
            // an exact multiple of `every` by an ulp.
            if t < last + self.every * (1.0 - 1e-9) {
                continue;
            }
            let state: Option<Vec<f64>> = series
                .iter()
                .map(|s| s.binary_search_by(|p| p.0.total_cmp(&t)).ok().map(|i| s[i].1).filter(|y| y.is_finite()))
                .collect();
            if let Some(state) = state {
                anchors.push(Anchor { t, state });
                last = t;
            }
        }
        anchors
    }
}

/// The stretches integrated at one θ, kept per thread: the likelihood asks
/// for each observable in turn at one θ.
struct Shot {
    model: u64,
    generation: u64,
    rtol: f64,
    theta: Vec<f64>,
    t_end: f64,
    y0: Vec<f64>,
    /// One solution per stretch (None where the integration failed).
    stretches: Vec<Option<Dense>>,
    values: [f64; MAX_NAMES],
}

const KEPT: usize = 3;

thread_local! {
    static SHOTS: RefCell<Vec<Shot>> = const { RefCell::new(Vec::new()) };
}

/// How far past its end a stretch is integrated: the solver's continuous
/// output is least trusted at the very end of an integration.
const MARGIN: f64 = 0.01;

impl OdeModel {
    /// The observable at each t of `x`, each from its stretch.
    pub(super) fn predict_shot(
        &self,
        shooting: &Shooting,
        observable: usize,
        x: &[f64],
        theta: &[f64],
        out: &mut [f64],
    ) {
        let anchors = shooting.anchors();
        let t_end = x.iter().copied().fold(self.horizon(), f64::max);
        SHOTS.with(|cell| {
            let mut kept = cell.borrow_mut();
            let shot = self.shot_at(&mut kept, &anchors, theta, t_end);
            let (at, n) = (self.variables.state_at, self.states.len());
            for (o, &t) in out.iter_mut().zip(x) {
                let Shot { y0, stretches, values: v, .. } = &mut *shot;
                let s = anchors.stretch_of(t);
                let found = if s == 0 && t <= self.t0 {
                    v[at..at + n].copy_from_slice(y0);
                    t == self.t0
                } else {
                    stretches[s].as_ref().is_some_and(|d| d.state_at(t, &mut v[at..at + n]))
                };
                if !found {
                    *o = f64::NAN;
                    continue;
                }
                v[0] = t;
                if self.uses_rates[observable] {
                    for (k, rate) in self.rates.iter().enumerate() {
                        v[self.variables.rate_at + k] = rate.eval(&v[..]);
                    }
                }
                *o = self.formulas[observable].eval(&v[..]);
            }
        })
    }

    /// This thread's stretches at θ reaching `t_end`, integrated unless kept.
    fn shot_at<'a>(&self, kept: &'a mut Vec<Shot>, anchors: &Anchors, theta: &[f64], t_end: f64) -> &'a mut Shot {
        let rtol = self.precision.tolerances(&self.solver).0;
        let found = kept.iter().position(|s| {
            s.model == self.id
                && s.generation == anchors.generation
                && s.rtol == rtol
                && s.theta == theta
                && s.t_end >= t_end
        });
        let slot = found.unwrap_or_else(|| {
            if kept.len() < KEPT {
                kept.push(Shot::empty());
            }
            kept.len() - 1
        });
        kept[..=slot].rotate_right(1);
        if found.is_none() {
            self.shoot(&mut kept[0], anchors, theta, t_end, rtol);
        }
        &mut kept[0]
    }

    /// Integrates every stretch at θ: from t0 to the first anchor, from
    /// each anchor to the next, and from the last to `t_end`.
    fn shoot(&self, shot: &mut Shot, anchors: &Anchors, theta: &[f64], t_end: f64, rtol: f64) {
        shot.model = self.id;
        shot.generation = anchors.generation;
        shot.rtol = rtol;
        shot.theta.clear();
        shot.theta.extend_from_slice(theta);
        shot.t_end = t_end;
        shot.stretches.clear();
        let v = &mut shot.values;
        self.variables.set_theta(theta, v);
        v[0] = self.t0;
        shot.y0.clear();
        shot.y0.extend(self.initial.iter().map(|f| f.eval(&v[..])));
        let v = *v;
        let mut failed = !shot.y0.iter().all(|y| y.is_finite());
        for s in 0..=anchors.list.len() {
            let (start, y) = match s {
                0 => (self.t0, &shot.y0),
                _ => (anchors.list[s - 1].t, &anchors.list[s - 1].state),
            };
            let end = anchors.list.get(s).map_or(t_end, |a| a.t);
            let dense = if end <= start {
                Some(Dense::Empty)
            } else {
                self.integrate_from(v, start, y, end + MARGIN * (end - start))
            };
            failed |= dense.is_none();
            shot.stretches.push(dense);
        }
        if failed {
            self.failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl Shot {
    fn empty() -> Shot {
        Shot {
            model: 0,
            generation: 0,
            rtol: f64::NAN,
            theta: Vec::new(),
            t_end: f64::NAN,
            y0: Vec::new(),
            stretches: Vec::new(),
            values: [0.0; MAX_NAMES],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::declaration::{Declared, ModelTable};
    use super::super::OdeModel;
    use crate::base::config::Config;
    use crate::engine::model::Simulator;

    /// x' = v, v' = −w²x from (1, 0), both states observed, shooting every `every`.
    fn oscillator(tag: &str, every: Option<f64>) -> OdeModel {
        let dir = std::env::temp_dir().join(format!("mdpipe-shooting-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.toml");
        let text = "name = \"m\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n[model.initial]\nx = \"1\"\nv = \"0\"\n\
            [model.rates]\nx = \"v\"\nv = \"-w^2*x\"\n[model.observables]\nx = \"x\"\nv = \"v\"\n\
            [data]\nmeasurements = \"d.csv\"\n[parameters.w]\nmin = 0.5\nmax = 3.0\n";
        std::fs::write(&path, text).unwrap();
        let config = Config::load(&path).unwrap();
        let table: ModelTable = config.decode_family_table(&config.model, "model").unwrap();
        let mut d = Declared::base(&config, &table, true).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        d.shooting = every;
        OdeModel::compile("m", &d).unwrap()
    }

    /// The index of observable `name`.
    fn index(model: &OdeModel, name: &str) -> usize {
        model.observable_names().iter().position(|o| o == name).unwrap()
    }

    /// Each point is the closed form x_a cos(wτ) + (v_a/w) sin(wτ) from the
    /// state measured at the last anchor before it (τ = t − t_a), anchors a
    /// whole `every` apart; a point at an anchor's time comes from the
    /// anchor before; before the first anchor, from the declared start.
    #[test]
    fn each_point_is_the_flow_from_the_last_measured_state_before_it() {
        let (w, every) = (1.7, 1.0);
        let times: Vec<f64> = (1..=16).map(|k| 0.25 * k as f64).collect();
        // "Measurements" from another trajectory (amplitude 2, a phase), so
        // that restarting from them differs from one trajectory.
        let measured = |t: f64| (2.0 * (w * t + 0.4).cos(), -2.0 * w * (w * t + 0.4).sin());
        let model = oscillator("flow", Some(every));
        let x_at = index(&model, "x");
        for o in 0..2 {
            model.check_inputs(o, &times).unwrap();
            let values: Vec<f64> =
                times.iter().map(|t| if o == x_at { measured(*t).0 } else { measured(*t).1 }).collect();
            model.note_measurements(o, &values, &vec![0.01; times.len()]);
        }
        let mut x = vec![0.0; times.len()];
        model.predict(x_at, &times, &[w], &mut x);
        for (t, got) in times.iter().zip(&x) {
            // The anchors are t = 1, 2, 3: the last strictly before t.
            let anchor = ((t - 1e-12) / every).floor() * every;
            let (xa, va) = if anchor < 0.5 { (1.0, 0.0) } else { measured(anchor) };
            let tau = t - anchor;
            let expected = xa * (w * tau).cos() + va / w * (w * tau).sin();
            assert!((got - expected).abs() < 1e-5, "t = {t}: {got} against {expected}");
        }
        // Without shooting, the same model is one trajectory: cos(wt).
        let one = oscillator("one", None);
        one.check_inputs(x_at, &times).unwrap();
        let mut y = vec![0.0; times.len()];
        one.predict(x_at, &times, &[w], &mut y);
        assert!(times.iter().zip(&y).all(|(t, y)| (y - (w * t).cos()).abs() < 1e-5));
    }

    /// New measurements move the anchors, and the predictions with them
    /// (a kept solution of the old anchors is not reused).
    #[test]
    fn new_measurements_move_the_anchors() {
        let times: Vec<f64> = (1..=8).map(|k| 0.5 * k as f64).collect();
        let model = oscillator("moved", Some(1.0));
        let x_at = index(&model, "x");
        let note = |value: f64| {
            for o in 0..2 {
                model.check_inputs(o, &times).unwrap();
                model.note_measurements(o, &vec![value; times.len()], &vec![0.01; times.len()]);
            }
        };
        let predict = || {
            let mut x = vec![0.0; times.len()];
            model.predict(x_at, &times, &[1.0], &mut x);
            x
        };
        note(0.0);
        let at_rest = predict();
        assert!(at_rest[2..].iter().all(|x| x.abs() < 1e-12), "from rest at every anchor: {at_rest:?}");
        note(1.0);
        let moved = predict();
        // t = 1.5 from the anchor at t = 1, (x, v) = (1, 1), half a unit on.
        assert!((moved[2] - (0.5f64.cos() + 0.5f64.sin())).abs() < 1e-5, "{moved:?}");
        // Before the first anchor, the declared start (the tolerances
        // follow the data's errors relative to their values, which moved).
        for (a, b) in at_rest[..2].iter().zip(&moved[..2]) {
            assert!((a - b).abs() < 1e-5, "{at_rest:?} against {moved:?}");
        }
        assert!((moved[0] - 0.5f64.cos()).abs() < 1e-5);
    }

    /// States measured at different times (here v's values not even
    /// finite) share no anchor: the model is then one trajectory from t0,
    /// with no panic and no NaN start.
    #[test]
    fn without_a_time_every_state_was_measured_the_model_is_one_trajectory() {
        let model = oscillator("apart", Some(0.5));
        let x_at = index(&model, "x");
        let v_at = 1 - x_at;
        let (tx, tv): (Vec<f64>, Vec<f64>) =
            ((1..=8).map(|k| 0.5 * k as f64).collect(), (1..=8).map(|k| 0.5 * k as f64 - 0.25).collect());
        model.check_inputs(x_at, &tx).unwrap();
        model.note_measurements(x_at, &[5.0; 8], &[0.01; 8]);
        model.check_inputs(v_at, &tv).unwrap();
        model.note_measurements(v_at, &[f64::NAN; 8], &[0.01; 8]);
        let mut x = vec![0.0; 8];
        model.predict(x_at, &tx, &[1.0], &mut x);
        assert!(tx.iter().zip(&x).all(|(t, x)| (x - t.cos()).abs() < 1e-5), "{x:?}");
    }
}
