//! One interface for every sampling algorithm, after BlackJAX's sampling
//! algorithms and argmin's
//! executor: a sampler says how to make its state (`init`), how one step
//! moves it (`step`) and what the final state yields (`finish`); [`drive`]
//! owns the loop around them, so checkpoints, time limits and progress work
//! the same for every sampler. A state is one serializable value: saved
//! whole, it resumes to exactly the draws of an uninterrupted run.

use super::checkpoint::Checkpointing;
use crate::base::progress::Observer;
use std::path::PathBuf;

/// Why a sampler cannot go on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SamplerError {
    /// Every particle's likelihood is −∞ or NaN: the weights are undefined.
    #[error("tempering made no progress at β = {beta:.3e}: no particle has a finite likelihood")]
    NoFiniteLikelihood { beta: f64 },
    /// β has not reached 1 in the sampler's limit of tempering steps.
    #[error("tempering made no progress: β = {beta:.3e} after {steps} steps; the likelihood is too sharp or nearly nowhere finite under this prior")]
    TemperingStalled { beta: f64, steps: usize },
}

pub trait SamplingAlgorithm {
    type State: serde::Serialize + serde::de::DeserializeOwned;
    type Output: serde::Serialize + serde::de::DeserializeOwned;

    /// The state before the first step.
    fn init(&self, seed: u64) -> Self::State;
    /// Moves the state one step; `Ok(true)` once it is finished, an error
    /// when it cannot go on.
    fn step(&self, state: &mut Self::State, observer: &dyn Observer) -> Result<bool, SamplerError>;
    /// The result of a finished state.
    fn finish(&self, state: Self::State) -> Self::Output;
    /// The progress units a whole run reports (given at once for a run whose
    /// finished output is loaded from a checkpoint).
    fn progress_units(&self) -> u64;
}

/// The run stopped before its end: at its time limit, or because it could
/// not go on (`cause`), with its state saved in `dir` when it had one.
#[derive(Debug)]
pub struct Stopped {
    pub dir: PathBuf,
    pub seconds: f64,
    /// The chain that stopped, as the message names it ("replicate 2: "), or "".
    pub chain: String,
    /// Why it could not go on; `None` for the time limit.
    pub cause: Option<SamplerError>,
}

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (secs, chain) = (self.seconds, &self.chain);
        match &self.cause {
            None => write!(f, "stopped at the time limit after {secs:.0} s with its state saved in {}; run the same command again to resume", self.dir.display()),
            Some(why) if self.dir.as_os_str().is_empty() => write!(f, "stopped after {secs:.0} s: {chain}{why}"),
            Some(why) => write!(f, "stopped after {secs:.0} s: {chain}{why} (the last state is kept in {})", self.dir.display()),
        }
    }
}
impl std::error::Error for Stopped {}

/// How a driven run ended.
pub enum End<O> {
    Done(O),
    /// Stopped at the checkpoint's time limit, the state saved.
    OutOfTime,
    /// Could not go on (the reason); the last state is saved when checkpointing.
    Stuck(SamplerError),
}

impl<O> End<O> {
    /// The output, or why the run stopped: at the time limit, or stuck
    /// (`chain` names the chain in the reason, e.g. "replicate 2: ").
    pub fn into_result(
        self,
        ck: Option<&Checkpointing>,
        started: std::time::Instant,
        chain: &str,
    ) -> Result<O, Stopped> {
        let stopped = |cause| Stopped {
            dir: ck.map(|c| c.dir.clone()).unwrap_or_default(),
            seconds: started.elapsed().as_secs_f64(),
            chain: chain.to_string(),
            cause,
        };
        match self {
            End::Done(out) => Ok(out),
            End::OutOfTime => Err(stopped(None)),
            End::Stuck(why) => Err(stopped(Some(why))),
        }
    }
}

/// Runs `algorithm` from its saved state under `name` in `ck` (or from `init`)
/// to its end, saving the state at the checkpoint's interval, when stuck and
/// at the time limit, and the finished output under `<name>.done`.
pub fn drive<K: SamplingAlgorithm>(
    algorithm: &K,
    seed: u64,
    observer: &dyn Observer,
    ck: Option<(&Checkpointing, &str)>,
) -> End<K::Output> {
    let done_name = ck.map(|(_, name)| format!("{name}.done"));
    if let (Some((c, _)), Some(done)) = (ck, &done_name) {
        if let Some(out) = c.load::<K::Output>(done) {
            observer.advance(algorithm.progress_units());
            return End::Done(out);
        }
    }
    let mut state = ck.and_then(|(c, name)| c.load::<K::State>(name)).unwrap_or_else(|| algorithm.init(seed));
    let mut last_save = std::time::Instant::now();
    loop {
        let stuck = match algorithm.step(&mut state, observer) {
            Ok(true) => break,
            Ok(false) => None,
            Err(why) => Some(why),
        };
        if let Some((c, name)) = ck {
            let out_of_time = c.out_of_time();
            if out_of_time || stuck.is_some() || last_save.elapsed() >= c.min_interval {
                c.save(name, &state);
                last_save = std::time::Instant::now();
            }
            if out_of_time && stuck.is_none() {
                return End::OutOfTime;
            }
        }
        if let Some(why) = stuck {
            return End::Stuck(why);
        }
    }
    let out = algorithm.finish(state);
    if let (Some((c, _)), Some(done)) = (ck, &done_name) {
        c.save(done, &out);
    }
    End::Done(out)
}
