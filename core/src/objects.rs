//! Stage 8: semantic object support sets and the residual set (paper §IV-C).
//!
//! After the plane-related Gaussians are removed through Γ, the remaining Gaussians with a valid instance form
//! one object per instance id: O_j = ⋃ C_i over a_i = j. Each object records its label, confidence, mask
//! statistics, 3-D and 2-D boxes and its Gaussians (those whose `instance` is its id and whose role is
//! object). The rest (a = −1) is the residual set, kept as GMM primitives.

use bytemuck::Zeroable;

use crate::gmm::{Gaussian, ROLE_OBJECT};
use crate::linalg::{self, Vec3};
use crate::pool::Bounded;
use crate::superquadric::Superquadric;

/// The object has too few points for a superquadric (or the variant fits none): it keeps its Gaussians.
pub const SQ_NONE: u8 = 0;
/// The fit was rejected (error or validity): the object falls back to its Gaussians.
pub const SQ_REJECTED: u8 = 1;
/// The object is represented by a superquadric.
pub const SQ_ACCEPTED: u8 = 2;

/// One semantic object support set O_j.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct Object {
    /// Instance id j (for objects allocated by geometry, MMQ: the id of its fused cluster).
    pub instance: u16,
    /// Category label ℓ.
    pub class: u16,
    /// Detection confidence s.
    pub score: f32,
    /// Point-weighted mean mask support ratio ρ of its Gaussians.
    pub support_ratio: f32,
    /// Its Gaussians.
    pub gaussians: u16,
    /// Its support points.
    pub points: u32,
    /// Minimum corner of its 3-D support box, metres.
    pub bbox_min: Vec3,
    /// Maximum corner of its 3-D support box, metres.
    pub bbox_max: Vec3,
    /// Its projected support box `[u0, v0, u1, v1]`, pixels.
    pub pixel_bbox: [u16; 4],
    /// Its superquadric (camera frame; the smoothed track state when tracked), valid when `sq_state` is
    /// [`SQ_ACCEPTED`].
    pub sq: Superquadric,
    /// E_sq of the fit (before smoothing).
    pub sq_error: f32,
    /// [`SQ_NONE`], [`SQ_REJECTED`] or [`SQ_ACCEPTED`].
    pub sq_state: u8,
    /// Id of its superquadric track.
    pub track: u16,
}

/// Groups the object-role Gaussians by `key` (the instance id; for objects allocated by geometry, the fused
/// cluster id), in order of first appearance, and marks each with its object index (`owner`).
pub fn group_objects(gaussians: &mut [Gaussian], objects: &mut Bounded<'_, Object>, key: impl Fn(&Gaussian) -> u16) {
    objects.clear();
    for g in gaussians.iter_mut().filter(|g| g.role == ROLE_OBJECT) {
        g.owner = u8::MAX;
        let id = key(g);
        let k = match objects.as_slice().iter().position(|o| o.instance == id) {
            Some(k) => k,
            None => {
                let mut o = Object::zeroed();
                o.instance = id;
                o.class = g.class;
                o.score = g.score;
                o.bbox_min = [f32::MAX; 3];
                o.bbox_max = [f32::MIN; 3];
                o.pixel_bbox = [u16::MAX, u16::MAX, 0, 0];
                match objects.push(o) {
                    Some(k) => k,
                    None => continue, // counted by the pool
                }
            }
        };
        let Some(o) = objects.get_mut(k) else { continue };
        g.owner = k as u8;
        let n = o.points as f32;
        o.support_ratio = (o.support_ratio * n + g.support_ratio * g.count as f32) / (n + g.count as f32);
        o.points += g.count;
        o.gaussians += 1;
        o.score = o.score.max(g.score);
        o.bbox_min = linalg::min_elem(o.bbox_min, g.bbox_min);
        o.bbox_max = linalg::max_elem(o.bbox_max, g.bbox_max);
        o.pixel_bbox = [
            o.pixel_bbox[0].min(g.pixel_bbox[0]),
            o.pixel_bbox[1].min(g.pixel_bbox[1]),
            o.pixel_bbox[2].max(g.pixel_bbox[2]),
            o.pixel_bbox[3].max(g.pixel_bbox[3]),
        ];
    }
}
