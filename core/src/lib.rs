//! # m2smap-core
//!
//! The allocation-free core of m2smap, an implementation of M2-SMap (memory-efficient semantic mapping with a
//! hierarchical multi-model representation). Each RGB-D frame, with optional instance masks, becomes a compact map
//! of bounded planes, object-level superquadrics and Gaussian primitives.
//!
//! ## Design goals
//! - **Firmware first.** `#![no_std]`, no allocator, no recursion, no panicking paths on input. Every buffer is
//!   caller-owned storage with a compile-time capacity (a [`profile`]); the mapper borrows it, the way smoltcp
//!   borrows socket buffers.
//! - **Bounded and honest.** When a pool is full, the work that does not fit is dropped, counted per pool and
//!   reported in the [`mapper::FrameReport`]; nothing panics and nothing is lost silently.
//! - **Bad input is an error, and costs nothing.** A frame is validated completely before any state changes, so
//!   a rejected frame leaves the previous map as it was.
//! - **Deterministic.** The 15 % sample is a hash of the pixel index, supervoxels grow in index order and every
//!   floating-point operation goes through `libm`: the same input gives the same bytes on a PC and on a Cortex-M7.
//! - **Points need not be stored.** The sampled points are a pure function of the caller's depth buffer, so the
//!   core keeps 3 cm voxel sums and re-derives points when a stage needs them ([`points::for_each_point`]). This
//!   is what lets a 640×480 frame fit the 512 KiB `mcu` profile. A profile with room (`host`) lists them once
//!   with their voxels and links each voxel to its neighbours, which spares the later passes the re-sampling
//!   and hashing; the maps are the same bits either way ([`supervoxel::for_each_voxel_point`]).
//!
//! ## Pipeline (one module per stage of the paper)
//! 1. [`points`]: depth range filter and the seeded 15 % sample (paper §VI).
//! 2. [`supervoxel`]: 3 cm voxels and VCCS-style flow-constrained supervoxels (paper §III-A); with masks in the
//!    semantic-fusion variants, each instance's points get their own voxels (mask slots), so nothing downstream
//!    mixes an object with what it touches.
//! 3. [`gmm`]: IH-GMM-style hierarchical refinement into compact Gaussians, the set `C_g` (paper §III-A).
//! 4. [`annotate`]: projection-guided mask matching (paper §III-B).
//! 5. [`fuse`]: semantic-constrained fusion Γ (paper §IV-A); [`plane`]: flat planes and bounded planes (§IV-B);
//!    [`objects`]: object support sets and the residual set (§IV-C).
//! 6. [`superquadric`]: object superquadrics by Levenberg–Marquardt (§V-A); [`track`]: association,
//!    equivalence alignment and smoothing (§V-B).
//! 7. [`map`]: the primitives and their reconstruction samples (§V-C); [`wire`]: the postcard wire format, with
//!    [`cells`] coding plane cells as run lengths or row edges.
//!
//! [`segment`] makes instance masks from depth alone for datasets without them; [`snapshot`] carries the tracks
//! across a reset; [`mapper`] runs the stages over the borrowed pools.
//!
//! Units: metres in the camera frame (x right, y down, z forward), pixels for image coordinates, radians unless a
//! name ends in `_deg`.
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic))]

pub mod annotate;
pub mod cells;
pub mod error;
pub mod fastmath;
pub mod frame;
pub mod fuse;
pub mod gmm;
pub mod linalg;
pub mod map;
pub mod mapper;
pub mod masks;
pub mod objects;
pub mod params;
pub mod plane;
pub mod points;
pub mod pool;
pub mod profile;
pub mod segment;
pub mod snapshot;
pub mod superquadric;
pub mod supervoxel;
pub mod track;
pub mod union_find;
pub mod wire;
pub mod world;

pub use error::{FrameError, MaskError, ParamError};
pub use frame::{Frame, Intrinsics, Pose};
pub use gmm::Gaussian;
pub use mapper::{FrameReport, Mapper};
pub use masks::{Instance, MaskPixels, MaskSet};
pub use params::{Params, Variant};
pub use pool::{PoolId, PoolUsage};
pub use profile::{HostStorage, McuStorage, Profile, Storage, TinyStorage};
