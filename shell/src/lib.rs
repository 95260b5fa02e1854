//! # m2smap (shell)
//!
//! The std side of m2smap: reading datasets, making synthetic scenes with ground truth, replaying frames
//! through the `no_std` core ([`m2smap_core`]) and writing results. The binary `m2smap` is a thin CLI over
//! these modules.

pub mod budget;
pub mod dataset;
pub mod eval;
pub mod export;
pub mod faults;
pub mod firmware;
pub mod fuzzing;
pub mod masks;
pub mod raycast;
pub mod render;
pub mod report;
pub mod run;
pub mod sweep;
pub mod synth;
pub mod world;
