//! The particle cloud and its moves: the cloud drawn from the prior, move
//! groups with their proposal factors, and Metropolis-within-Gibbs sweeps
//! (a joint likelihood's φ moves screened by the block's marginal).

use super::*;

/// Lower Cholesky factor of the particles' covariance (in the unbounded space).
pub(super) fn proposal_factor(x: &[f64], dim: usize) -> Vec<f64> {
    let n = x.len() / dim;
    let mut mean = vec![0.0; dim];
    for row in x.chunks(dim) {
        for k in 0..dim {
            mean[k] += row[k] / n as f64;
        }
    }
    let mut ws = CholeskyWorkspace::new(dim);
    ws.factor.iter_mut().for_each(|v| *v = 0.0);
    for row in x.chunks(dim) {
        for j in 0..dim {
            let dj = row[j] - mean[j];
            for i in j..dim {
                ws.factor[i + j * dim] += (row[i] - mean[i]) * dj / (n as f64 - 1.0).max(1.0);
            }
        }
    }
    // A small floor keeps a collapsed cloud movable (u is O(1) under the prior).
    for k in 0..dim {
        ws.factor[k + k * dim] += 1e-18;
    }
    if ws.factorize().is_err() {
        let mut diag = vec![0.0; dim * dim];
        for k in 0..dim {
            diag[k + k * dim] = 0.1;
        }
        return diag;
    }
    for j in 0..dim {
        for i in 0..j {
            ws.factor[i + j * dim] = 0.0;
        }
    }
    ws.factor
}

/// Coordinates moved together by one random-walk Metropolis proposal.
#[derive(Clone, serde::Serialize, serde::Deserialize)]
pub(super) struct MoveGroup {
    pub(super) coords: Vec<usize>,
    /// Lower Cholesky factor of the cloud's covariance of `coords` (recomputed
    /// from the cloud before every use, so not stored).
    #[serde(skip)]
    pub(super) factor: Vec<f64>,
    #[serde(with = "f64_bit")]
    pub(super) scale: f64,
    /// The likelihood term whose own parameters these are; `None` means the
    /// move can change every term (a full evaluation).
    pub(super) term: Option<usize>,
}

/// Above this many coordinates the joint move is left out when the groups
/// cover every coordinate: a random walk of all d coordinates at once moves
/// each by about 2.38/√d of its spread for a whole evaluation, while the
/// shared parameters' move and each term's move shift theirs by 2.38/√k
/// (k ≤ a few) for a whole evaluation or less. At 124 coordinates the
/// joint move was half of the whole evaluations for a fortieth of the
/// movement; the mixture's independent proposals still move every
/// coordinate at once.
pub(super) const JOINT_MOVE_MAX_DIM: usize = 64;

/// The move groups: one joint move of everything, and when the likelihood is a
/// sum of terms, a move of the shared parameters and one move per term of its
/// own parameters (Metropolis within Gibbs). A term's move costs one term (or
/// its statistics), not the whole likelihood, which is what makes many
/// observables with their own discrepancy hyperparameters affordable. Without
/// the joint move above [`JOINT_MOVE_MAX_DIM`] coordinates.
pub(super) fn move_groups(dim: usize, structure: Option<&TermStructure>) -> Vec<MoveGroup> {
    let group = |coords: Vec<usize>, term| MoveGroup {
        scale: 2.38 / (coords.len() as f64).sqrt(),
        factor: Vec::new(),
        coords,
        term,
    };
    let joint = structure.is_none() || dim <= JOINT_MOVE_MAX_DIM;
    let mut groups = if joint { vec![group((0..dim).collect(), None)] } else { Vec::new() };
    if let Some(st) = structure {
        if !st.shared.is_empty() {
            groups.push(group(st.shared.clone(), None));
        }
        for (t, own) in st.own.iter().enumerate() {
            if !own.is_empty() {
                groups.push(group(own.clone(), Some(t)));
            }
        }
    }
    groups
}

pub(super) fn update_factors(groups: &mut [MoveGroup], x: &[f64], dim: usize) {
    for g in groups.iter_mut() {
        if g.coords.len() == dim {
            g.factor = proposal_factor(x, dim);
        } else {
            let sub: Vec<f64> = x.chunks(dim).flat_map(|row| g.coords.iter().map(move |&c| row[c])).collect();
            g.factor = proposal_factor(&sub, g.coords.len());
        }
    }
}

/// What each particle keeps of its likelihood's terms, so that a move of one
/// term's own parameters costs that term, with the likelihood's interface
/// that computes them.
#[derive(Clone, Copy)]
pub(super) enum TermCache<'a> {
    /// Nothing: a term's move is screened, then pays a whole evaluation.
    None,
    /// Each separable term's value (their sum is the log-likelihood).
    Terms(&'a dyn SeparableTerms),
    /// Each linked term's statistics (`TermStatistics::width` values each).
    Stats(&'a dyn TermStatistics),
}

impl<'a> TermCache<'a> {
    /// The cache a likelihood allows and how many values it keeps per particle.
    pub(super) fn of(structure: Option<&TermStructure>, likelihood: &'a dyn LogLikelihood) -> (TermCache<'a>, usize) {
        let Some(s) = structure else {
            return (TermCache::None, 0);
        };
        match (likelihood.separable_terms(), likelihood.term_statistics()) {
            (Some(terms), _) => (TermCache::Terms(terms), s.own.len()),
            (None, Some(stats)) => (TermCache::Stats(stats), s.own.len() * stats.width()),
            (None, None) => (TermCache::None, 0),
        }
    }

    /// A whole evaluation at `x`, refilling the cache's `values`; −∞ below
    /// `floor` (which only a target without a cache has).
    fn evaluate(self, likelihood: &dyn LogLikelihood, x: &[f64], values: &mut [f64], floor: f64) -> f64 {
        match self {
            TermCache::None => {
                let l = likelihood.log_likelihood_above(x, floor);
                if l < floor {
                    f64::NEG_INFINITY
                } else {
                    l
                }
            }
            TermCache::Terms(terms) => terms.log_likelihood_terms(x, values),
            TermCache::Stats(stats) => stats.log_likelihood_stats(x, values),
        }
    }
}

/// What the moves target: `L(x(u))^β π_u(u)` given the prior and the
/// likelihood, and what each particle keeps of the likelihood's terms.
#[derive(Clone, Copy)]
pub(super) struct Target<'a> {
    pub(super) prior: &'a UniformPrior,
    pub(super) likelihood: &'a dyn LogLikelihood,
    pub(super) cache: TermCache<'a>,
    /// Log-likelihoods below this are taken as −∞ (`tempering::floor_at`);
    /// −∞ where the target keeps terms.
    pub(super) floor: f64,
}

/// The particle cloud between tempering steps, in the unbounded coordinates u.
#[derive(Clone, serde::Serialize, serde::Deserialize)]
pub(super) struct Cloud {
    pub(super) dim: usize,
    #[serde(with = "f64_bits")]
    pub(super) x: Vec<f64>,
    #[serde(with = "f64_bits")]
    pub(super) loglik: Vec<f64>,
    #[serde(with = "f64_bits")]
    pub(super) logprior: Vec<f64>,
    /// Per particle, its `TermCache` values (empty without one).
    #[serde(with = "f64_bits")]
    pub(super) terms: Vec<f64>,
    /// Values per particle in `terms`.
    pub(super) n_terms: usize,
}

impl Cloud {
    pub(super) fn resample(&mut self, ancestors: &[usize]) {
        self.x = reindex(&self.x, self.dim, ancestors);
        self.loglik = ancestors.iter().map(|&a| self.loglik[a]).collect();
        self.logprior = ancestors.iter().map(|&a| self.logprior[a]).collect();
        if self.n_terms > 0 {
            self.terms = reindex(&self.terms, self.n_terms, ancestors);
        }
    }
}

#[derive(Default)]
pub(super) struct MoveCounts {
    pub(super) accepted: Vec<u64>,
    pub(super) proposed: Vec<u64>,
    pub(super) full_evaluations: u64,
    pub(super) term_evaluations: u64,
}

impl MoveCounts {
    pub(super) fn merge(mut self, other: MoveCounts) -> MoveCounts {
        if self.accepted.is_empty() {
            return other;
        }
        for (a, b) in self.accepted.iter_mut().zip(&other.accepted) {
            *a += b;
        }
        for (a, b) in self.proposed.iter_mut().zip(&other.proposed) {
            *a += b;
        }
        self.full_evaluations += other.full_evaluations;
        self.term_evaluations += other.term_evaluations;
        self
    }

    pub(super) fn acceptance(&self, g: usize) -> f64 {
        self.accepted[g] as f64 / self.proposed[g].max(1) as f64
    }
}

/// `move_one` applied to every particle in parallel (its point u, log-
/// likelihood, log prior density, likelihood terms and own random stream),
/// adding to a running count. Counts and `scratch_len` values of scratch
/// are made once per parallel task, not per particle: the final sweeps
/// call this once per sweep.
fn each_particle<T: Send>(
    cloud: &mut Cloud,
    rngs: &mut [Xoshiro256PlusPlus],
    scratch_len: usize,
    move_one: impl Fn(&mut T, &mut [f64], &mut [f64], &mut f64, &mut f64, &mut [f64], &mut Xoshiro256PlusPlus) + Sync + Send,
    identity: impl Fn() -> T + Sync + Send,
    merge: impl Fn(T, T) -> T + Sync + Send,
) -> T {
    let (dim, nt) = (cloud.dim, cloud.n_terms);
    let mut term_chunks: Vec<&mut [f64]> = if nt > 0 {
        cloud.terms.chunks_mut(nt).collect()
    } else {
        (0..cloud.loglik.len()).map(|_| &mut [][..]).collect()
    };
    cloud
        .x
        .par_chunks_mut(dim)
        .zip(cloud.loglik.par_iter_mut())
        .zip(cloud.logprior.par_iter_mut())
        .zip(term_chunks.par_iter_mut())
        .zip(rngs.par_iter_mut())
        .fold(
            || (identity(), vec![0.0; scratch_len]),
            |(mut counts, mut scratch), ((((u, l), p), t), rng)| {
                move_one(&mut counts, &mut scratch, u, l, p, t, rng);
                (counts, scratch)
            },
        )
        .map(|(counts, _)| counts)
        .reduce(&identity, merge)
}

/// `sweeps` rounds of random-walk Metropolis moves, one per group in turn, of
/// every particle at inverse temperature β (target `L(x(u))^β π_u(u)`).
pub(super) fn mutate(
    cloud: &mut Cloud,
    rngs: &mut [Xoshiro256PlusPlus],
    groups: &[MoveGroup],
    beta: f64,
    sweeps: usize,
    Target { prior, likelihood, cache, floor }: Target,
) -> MoveCounts {
    let (dim, nt) = (cloud.dim, cloud.n_terms);
    // A cloud resumed from a checkpoint written without values keeps none.
    let cache = if nt == 0 { TermCache::None } else { cache };
    let n_screens = groups.iter().filter_map(|g| g.term).max().map_or(0, |t| t + 1);
    each_particle(
        cloud,
        rngs,
        4 * dim + nt + n_screens,
        |counts: &mut MoveCounts, scratch, xi, li, pi, ti, rng| {
            let (z, rest) = scratch.split_at_mut(dim);
            let (prop, rest) = rest.split_at_mut(dim);
            let (prop_x, rest) = rest.split_at_mut(dim);
            let (cur_x, rest) = rest.split_at_mut(dim);
            let (prop_terms, screens) = rest.split_at_mut(nt);
            // Each term's screen at the current point, NaN until computed;
            // reset whenever a move changes the shared parameters.
            screens.fill(f64::NAN);
            for _ in 0..sweeps {
                for (gi, g) in groups.iter().enumerate() {
                    if g.term.is_some() && !li.is_finite() {
                        continue; // a term move cannot repair an impossible point
                    }
                    let k = g.coords.len();
                    for zk in z[..k].iter_mut() {
                        *zk = rng.sample(StandardNormal);
                    }
                    prop.copy_from_slice(xi);
                    for a in 0..k {
                        let mut s = 0.0;
                        for b in 0..=a {
                            s += g.factor[a + b * k] * z[b];
                        }
                        prop[g.coords[a]] += g.scale * s;
                    }
                    counts.proposed[gi] += 1;
                    let lpi = prior.from_unbounded_with_log_density(prop, prop_x);
                    // Far out in u the logistic rounds onto a bound: outside the open box.
                    if !prior.contains(prop_x) {
                        continue;
                    }
                    // Terms linked without kept statistics (no cache) move at the cost
                    // of a whole evaluation, paid only for moves their screen lets through.
                    let screened = match g.term {
                        Some(t) if matches!(cache, TermCache::None) => {
                            screen_change(likelihood, prior, xi, prop_x, cur_x, &mut screens[t], t)
                        }
                        None | Some(_) => None,
                    };
                    if let Some((ds, _)) = screened {
                        counts.term_evaluations += 1;
                        let u: f64 = rng.random();
                        if u.ln() >= beta * ds + lpi - *pi {
                            continue;
                        }
                    }
                    let (lp, new_term) = match (g.term, cache) {
                        (Some(t), TermCache::Terms(terms)) => {
                            counts.term_evaluations += 1;
                            let lt = terms.log_likelihood_term(prop_x, t);
                            (*li - ti[t] + lt, lt)
                        }
                        (Some(t), TermCache::Stats(stats)) => {
                            counts.term_evaluations += 1;
                            prop_terms.copy_from_slice(ti);
                            (stats.update_term_stats(prop_x, t, prop_terms), f64::NAN)
                        }
                        _ => {
                            counts.full_evaluations += 1;
                            (cache.evaluate(likelihood, prop_x, prop_terms, floor), f64::NAN)
                        }
                    };
                    let lp = if lp.is_nan() { f64::NEG_INFINITY } else { lp };
                    // After a screen, the second stage corrects for the screen's
                    // error; the prior's ratio was exact in the first.
                    let second = match screened {
                        Some((ds, _)) => -beta * ds,
                        None => lpi - *pi,
                    };
                    let log_ratio = if li.is_finite() {
                        beta * (lp - *li) + second
                    } else if lp.is_finite() {
                        f64::INFINITY
                    } else {
                        f64::NEG_INFINITY
                    };
                    let u: f64 = rng.random();
                    if u.ln() < log_ratio {
                        xi.copy_from_slice(prop);
                        *li = lp;
                        *pi = lpi;
                        match (g.term, cache) {
                            (Some(t), TermCache::Terms(_)) => ti[t] = new_term,
                            _ => ti.copy_from_slice(prop_terms),
                        }
                        match (g.term, screened) {
                            (Some(t), Some((_, at_prop))) => screens[t] = at_prop,
                            (Some(t), None) => screens[t] = f64::NAN,
                            (None, _) => screens.iter_mut().for_each(|s| *s = f64::NAN),
                        }
                        counts.accepted[gi] += 1;
                    }
                }
            }
        },
        || MoveCounts { accepted: vec![0; groups.len()], proposed: vec![0; groups.len()], ..Default::default() },
        MoveCounts::merge,
    )
}

#[derive(Default)]
pub(super) struct IndependentCounts {
    pub(super) accepted: u64,
    pub(super) proposed: u64,
    /// Whole evaluations: every proposal inside the prior's box.
    pub(super) evaluations: u64,
    /// Particles that accepted at least one proposal.
    pub(super) moved: u64,
}

impl IndependentCounts {
    fn merge(self, o: IndependentCounts) -> IndependentCounts {
        IndependentCounts {
            accepted: self.accepted + o.accepted,
            proposed: self.proposed + o.proposed,
            evaluations: self.evaluations + o.evaluations,
            moved: self.moved + o.moved,
        }
    }

    pub(super) fn acceptance(&self) -> f64 {
        self.accepted as f64 / self.proposed.max(1) as f64
    }
}

/// `proposals` independent Metropolis–Hastings moves of every particle at
/// inverse temperature β, each proposing a draw of `mixture` (fitted to the
/// cloud) in place of the whole point: accepted with probability
/// `min(1, [L(x')^β π_u(u') q(u)] / [L(x)^β π_u(u) q(u')])`. Returns the
/// counts.
pub(super) fn independent_moves(
    cloud: &mut Cloud,
    rngs: &mut [Xoshiro256PlusPlus],
    mixture: &Mixture,
    beta: f64,
    proposals: usize,
    Target { prior, likelihood, cache, floor }: Target,
) -> IndependentCounts {
    let (dim, nt) = (cloud.dim, cloud.n_terms);
    let cache = if nt == 0 { TermCache::None } else { cache };
    each_particle(
        cloud,
        rngs,
        4 * dim + nt,
        |counts: &mut IndependentCounts, buffers, ui, li, pi, ti, rng| {
            let (prop, rest) = buffers.split_at_mut(dim);
            let (prop_x, rest) = rest.split_at_mut(dim);
            let (scratch, prop_terms) = rest.split_at_mut(2 * dim);
            let mut log_q = mixture.log_density(ui, scratch);
            let (mut accepted, mut evaluated) = (0u64, 0u64);
            for _ in 0..proposals {
                mixture.sample(rng, prop, scratch);
                let lpi = prior.from_unbounded_with_log_density(prop, prop_x);
                let log_q_prop = mixture.log_density(prop, scratch);
                // Draw the uniform whatever happens, so that the streams do
                // not depend on which proposals fell outside the box.
                let uniform: f64 = rng.random();
                if !prior.contains(prop_x) {
                    continue;
                }
                evaluated += 1;
                let lp = cache.evaluate(likelihood, prop_x, prop_terms, floor);
                let lp = if lp.is_nan() { f64::NEG_INFINITY } else { lp };
                let log_ratio = if li.is_finite() {
                    beta * (lp - *li) + lpi - *pi + log_q - log_q_prop
                } else if lp.is_finite() {
                    f64::INFINITY
                } else {
                    f64::NEG_INFINITY
                };
                if uniform.ln() < log_ratio {
                    ui.copy_from_slice(prop);
                    (*li, *pi, log_q) = (lp, lpi, log_q_prop);
                    ti.copy_from_slice(prop_terms);
                    accepted += 1;
                }
            }
            counts.accepted += accepted;
            counts.proposed += proposals as u64;
            counts.evaluations += evaluated;
            counts.moved += (accepted > 0) as u64;
        },
        IndependentCounts::default,
        IndependentCounts::merge,
    )
}

/// The first stage of a delayed-acceptance move of term `t`'s own parameters
/// (Christen & Fox 2005): the change of the likelihood's screen from the
/// current point (`u`, unbounded) to the proposal `prop_x`. A move passes the
/// first stage with probability `min(1, exp(β Δs) × prior ratio)` and is then
/// accepted with probability `min(1, exp(β (Δlog L − Δs)))`, which keeps the
/// target exact for any screen that is a fixed function of the point; a good
/// screen only saves the whole evaluations of moves it would reject anyway.
/// `None` (plain Metropolis) without a screen or where either value is not
/// finite: the choice is symmetric in the two points, so each kind of move
/// keeps detailed balance on its own. `at_cur` is the screen at the current
/// point (NaN: not yet computed; then it is). Returns the change and the
/// screen at the proposal.
#[allow(clippy::too_many_arguments)]
pub(super) fn screen_change(
    likelihood: &dyn LogLikelihood,
    prior: &UniformPrior,
    u: &[f64],
    prop_x: &[f64],
    cur_x: &mut [f64],
    at_cur: &mut f64,
    t: usize,
) -> Option<(f64, f64)> {
    let at_prop = likelihood.screening_term(prop_x, t)?;
    if at_cur.is_nan() {
        prior.from_unbounded(u, cur_x);
        *at_cur = likelihood.screening_term(cur_x, t)?;
    }
    let change = at_prop - *at_cur;
    change.is_finite().then_some((change, at_prop))
}

/// Draws the particles from the prior, in the unbounded coordinates u (see
/// `UniformPrior::to_unbounded`), with their log-likelihoods (and terms).
pub(super) fn initial_cloud(
    prior: &UniformPrior,
    likelihood: &dyn LogLikelihood,
    rngs: &mut [Xoshiro256PlusPlus],
    n: usize,
    (cache, n_terms): (TermCache, usize),
) -> Cloud {
    let dim = prior.dim();
    let mut x = vec![0.0; n * dim];
    let mut terms = vec![0.0; n * n_terms];
    let mut term_chunks: Vec<&mut [f64]> =
        if n_terms > 0 { terms.chunks_mut(n_terms).collect() } else { (0..n).map(|_| &mut [][..]).collect() };
    let loglik: Vec<f64> = x
        .par_chunks_mut(dim)
        .zip(rngs.par_iter_mut())
        .zip(term_chunks.par_iter_mut())
        .map(|((row, rng), t)| {
            let mut draw = vec![0.0; dim];
            prior.sample(rng, &mut draw);
            prior.to_unbounded(&draw, row);
            cache.evaluate(likelihood, &draw, t, f64::NEG_INFINITY)
        })
        .collect();
    drop(term_chunks);
    let logprior: Vec<f64> = x.chunks(dim).map(|u| prior.log_density_unbounded(u)).collect();
    Cloud { dim, x, loglik, logprior, terms, n_terms }
}
