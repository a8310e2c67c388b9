//! The systems of `mdpipe run`: what each system adds to a study (its
//! `[run.<system>]` table, default simulator, stages with ids of their own,
//! data with a known truth, assessment and figures), through the hooks of
//! `pipeline::system::System`. Each is one folder here and one line in
//! `app::systems()`; the generic pipeline below names none of them.

#[cfg(test)]
mod free_fall;
mod stand_in;

pub(crate) use stand_in::StandIn;
