//! The search for physics nobody declared, shared by every model family:
//! terms built by composition from primitives over the symbols each place
//! offers (`library`), screened where the data are (`along`, with the
//! rates of observed states read off the data by `smooth`), the same
//! explanation kept once (`distinct`), and a prior over forms learned from
//! a corpus of physics equations (`prior`). A family supplies its places
//! and symbols, how a term is compiled into its model, and how a found
//! term is declared.

pub mod along;
pub mod distinct;
pub mod library;
pub mod prior;
pub mod smooth;
