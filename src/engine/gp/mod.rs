//! Gaussian-process building blocks shared by the model-discrepancy term and
//! the emulators, one module per piece of the mathematics: the paper's
//! discrepancy kernels (`discrepancy`), the emulators' ARD kernels and their
//! marginal likelihood (`ard`), and a jittered Cholesky with the Gaussian
//! log-density (`cholesky`).
//!
//! Matrices are dense, column-major `&[f64]` of size `n*n`; everything that
//! runs inside a sampler works in caller-provided buffers so that a likelihood
//! evaluation does not allocate.

pub mod ard;
pub mod cholesky;
pub mod discrepancy;

pub use ard::*;
pub use cholesky::*;
pub use discrepancy::*;
