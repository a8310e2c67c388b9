//! Integration tests, in one binary so that the release build links once.

mod bad_inputs;
mod ball_drop;
mod checkpoint;
mod closed_form;
mod cluster;
mod common;
mod declared;
mod diagnose;
mod diagnose_heavy_ion;
mod discover;
mod doc_commands;
mod emulator;
mod family;
mod faults;
mod guard;
mod heavy_ion;
mod hepdata;
mod ingest;
mod layers;
mod pipeline;
mod readers;
mod readme;
mod report;
mod sbc;
mod structured;
mod your_simulator;
