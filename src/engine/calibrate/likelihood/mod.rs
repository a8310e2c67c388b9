//! The Kennedy–O'Hagan likelihood, in the order its parts are built: each
//! observable's measurements as a block (`block`), the data's covariance
//! put into the blocks (`data_covariance`), the joint layout over all points
//! (`joint`), the likelihood below a floor a sampler ignores (`far`), the low-rank part linking blocks (`across`, `structured`,
//! `structured_model`), the form an evaluation takes (`form`), the
//! likelihood itself (`md`), and the per-block statistics a sampler may keep
//! (`block_stats`).

pub mod across;
pub mod block;
pub mod block_stats;
pub mod data_covariance;
pub mod factored;
mod far;
pub mod form;
pub mod joint;
pub mod md;
pub mod structured;
pub mod structured_model;
mod target_impls;

pub use block::ObservableBlock;
pub use form::Form;
pub use md::MdLikelihood;
