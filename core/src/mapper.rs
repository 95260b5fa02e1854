//! The mapper: runs the stages over borrowed pools and reports what each frame used.

use crate::error::FrameError;
use crate::error::ParamError;
use crate::frame::Frame;
use crate::gmm::{self, Gaussian, GmmPools, SplitTask};
use crate::masks::MaskSet;
use crate::params::Params;
use crate::points::{self, Point};
use crate::pool::{Bounded, PoolId, PoolUsage};
use crate::profile::Profile;
use crate::supervoxel::{self, SeedCell, Supervoxel, SupervoxelPools, Voxel};

/// A frame (and its masks) that passed validation for this mapper's parameters and profile.
#[derive(Debug, Clone, Copy)]
pub struct CheckedFrame<'a> {
    frame: Frame<'a>,
    masks: Option<MaskSet<'a>>,
}

impl<'a> CheckedFrame<'a> {
    /// The frame.
    pub fn frame(&self) -> &Frame<'a> {
        &self.frame
    }

    /// Its instance masks, if any.
    pub fn masks(&self) -> Option<&MaskSet<'a>> {
        self.masks.as_ref()
    }
}

/// What one frame produced and used.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FrameReport {
    /// Frames processed so far, this one included.
    pub frame: u32,
    /// Sampled in-range points |P|.
    pub points: u32,
    /// Occupied voxels.
    pub voxels: u32,
    /// Seeds placed.
    pub seeds: u32,
    /// Supervoxels (seeded and orphan).
    pub supervoxels: u32,
    /// Supervoxels grown from unseeded components.
    pub orphan_supervoxels: u32,
    /// Growth rounds run.
    pub growth_rounds: u32,
    /// Binary splits of the refinement.
    pub splits: u32,
    /// Gaussians |C_g|.
    pub gaussians: u32,
    /// Points in outlier clusters (too small to map).
    pub outlier_points: u32,
    /// Points lost to a full pool.
    pub dropped_points: u32,
    /// Use of every pool, in [`PoolId::ALL`] order.
    pub pools: [PoolUsage; PoolId::COUNT],
    /// Sum of the pools' overflow events.
    pub overflow_events: u32,
}

impl FrameReport {
    /// Use of one pool.
    pub fn pool(&self, id: PoolId) -> PoolUsage {
        let i = PoolId::ALL.iter().position(|&p| p == id).unwrap_or(0);
        self.pools.get(i).copied().unwrap_or_default()
    }
}

/// The M2-SMap mapper over caller-owned storage.
pub struct Mapper<'s> {
    params: Params,
    max_pixels: usize,
    voxels: Bounded<'s, Voxel>,
    slots: &'s mut [u16],
    scratch: &'s mut [u16],
    seeds: Bounded<'s, SeedCell>,
    supervoxels: Bounded<'s, Supervoxel>,
    stack: Bounded<'s, SplitTask>,
    gaussians: Bounded<'s, Gaussian>,
    report: FrameReport,
    frames: u32,
}

impl<'s> Mapper<'s> {
    /// A mapper over `storage` with `params` (checked by [`Params::validate`]).
    pub fn new<P: Profile>(storage: &'s mut P, params: Params) -> Result<Self, ParamError> {
        params.validate()?;
        let parts = storage.parts();
        Ok(Mapper {
            params,
            max_pixels: P::MAX_PIXELS,
            voxels: Bounded::new(parts.voxels),
            slots: parts.slots,
            scratch: parts.scratch,
            seeds: Bounded::new(parts.seeds),
            supervoxels: Bounded::new(parts.supervoxels),
            stack: Bounded::new(parts.stack),
            gaussians: Bounded::new(parts.gaussians),
            report: FrameReport::default(),
            frames: 0,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Validates a frame and its masks without touching any state.
    pub fn check<'a>(&self, frame: Frame<'a>, masks: Option<MaskSet<'a>>) -> Result<CheckedFrame<'a>, FrameError> {
        frame.validate(&self.params, self.max_pixels)?;
        if let Some(m) = &masks {
            m.validate(frame.width, frame.height)?;
        }
        Ok(CheckedFrame { frame, masks })
    }

    /// Runs the whole pipeline on one frame. On error nothing changes: the previous frame's results stay.
    pub fn process(&mut self, frame: Frame<'_>, masks: Option<MaskSet<'_>>) -> Result<&FrameReport, FrameError> {
        let checked = self.check(frame, masks)?;
        self.stage_voxels(&checked);
        self.stage_supervoxels();
        self.stage_gaussians(&checked);
        Ok(self.finish_frame())
    }

    /// Stage 1 + voxel sums (first step of [`Mapper::process`]; public for benchmarks).
    pub fn stage_voxels(&mut self, checked: &CheckedFrame<'_>) {
        self.report = FrameReport { frame: self.frames + 1, ..FrameReport::default() };
        let stats = supervoxel::voxelize(&checked.frame, &self.params, &mut self.voxels, self.slots);
        supervoxel::compute_normals(self.voxels.as_mut_slice(), self.slots, self.params.voxel_resolution);
        self.report.points = stats.points;
        self.report.dropped_points += stats.dropped_points;
        self.report.voxels = self.voxels.len() as u32;
        self.report.pools[1] = PoolUsage {
            peak: self.voxels.len(),
            capacity: self.slots.len(),
            overflow_events: stats.slot_overflows,
        };
    }

    /// Stage 2: supervoxels (second step of [`Mapper::process`]).
    pub fn stage_supervoxels(&mut self) {
        let stats = supervoxel::build_supervoxels(
            SupervoxelPools {
                voxels: self.voxels.as_mut_slice(),
                slots: self.slots,
                scratch: self.scratch,
                seeds: &mut self.seeds,
                supervoxels: &mut self.supervoxels,
            },
            &self.params,
        );
        self.report.seeds = stats.seeds;
        self.report.growth_rounds = stats.rounds;
        self.report.orphan_supervoxels = stats.orphan_supervoxels;
        self.report.outlier_points = stats.outlier_points;
        self.report.dropped_points += stats.dropped_points;
        self.report.supervoxels = self.supervoxels.len() as u32;
    }

    /// Stage 3: IH-GMM refinement (third step of [`Mapper::process`]).
    pub fn stage_gaussians(&mut self, checked: &CheckedFrame<'_>) {
        let stats = gmm::refine(
            GmmPools {
                voxels: self.voxels.as_mut_slice(),
                slots: self.slots,
                order: self.scratch,
                supervoxels: self.supervoxels.as_mut_slice(),
                stack: &mut self.stack,
                gaussians: &mut self.gaussians,
            },
            &checked.frame,
            &self.params,
        );
        self.report.splits = stats.splits;
        self.report.dropped_points += stats.dropped_points;
        self.report.gaussians = self.gaussians.len() as u32;
    }

    /// Closes the frame's accounting and returns its report.
    pub fn finish_frame(&mut self) -> &FrameReport {
        self.frames += 1;
        let n = self.voxels.len();
        let slots = self.report.pools[1];
        self.report.pools = [
            self.voxels.usage(),
            slots,
            PoolUsage { peak: n, capacity: self.scratch.len(), overflow_events: 0 },
            self.seeds.usage(),
            self.supervoxels.usage(),
            self.stack.usage(),
            self.gaussians.usage(),
        ];
        self.report.overflow_events = self.report.pools.iter().map(|p| p.overflow_events).sum();
        &self.report
    }

    /// The last frame's report.
    pub fn report(&self) -> &FrameReport {
        &self.report
    }

    /// Voxels of the last frame.
    pub fn voxels(&self) -> &[Voxel] {
        self.voxels.as_slice()
    }

    /// Supervoxels of the last frame.
    pub fn supervoxels(&self) -> &[Supervoxel] {
        self.supervoxels.as_slice()
    }

    /// Gaussians C_g of the last frame.
    pub fn gaussians(&self) -> &[Gaussian] {
        self.gaussians.as_slice()
    }

    /// Calls `f(point, voxel)` for every sampled point of `checked` with the voxel it fell into (labels tell
    /// its supervoxel and Gaussian). `checked` must be the frame last processed for the labels to mean anything.
    pub fn for_each_labelled_point(&self, checked: &CheckedFrame<'_>, mut f: impl FnMut(&Point, Option<&Voxel>)) {
        let voxels = self.voxels.as_slice();
        let r = self.params.voxel_resolution;
        points::for_each_point(&checked.frame, &self.params, |p| {
            let v = supervoxel::voxel_key(p.xyz, r)
                .and_then(|k| supervoxel::find_voxel(voxels, self.slots, k))
                .and_then(|i| voxels.get(i));
            f(p, v);
        });
    }
}
