//! Sampling a posterior given a [`target::LogLikelihood`] and a uniform
//! prior box: the interface every algorithm implements (`algorithm`), the
//! draws they return (`chains`), sequential Monte Carlo (`smc`), the
//! affine-invariant ensemble (`ensemble`), adaptation until converged
//! (`adapt`) judged by convergence diagnostics (`diagnostics`), checkpoints
//! (`checkpoint`), the prior box (`uniform_prior`) and the `[sampler]` settings.

pub mod adapt;
pub mod algorithm;
pub mod chains;
pub mod checkpoint;
pub mod diagnostics;
pub mod ensemble;
pub mod settings;
pub mod smc;
pub mod target;
pub mod uniform_prior;
