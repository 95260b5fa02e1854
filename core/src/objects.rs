//! Stage 8: semantic object support sets and the residual set (paper §IV-C).
//!
//! After the plane-related Gaussians are removed through Γ, the remaining Gaussians with a valid instance form
//! one object per instance id: O_j = ⋃ C_i over a_i = j. Each object records its label, confidence, mask
//! statistics, 3-D and 2-D boxes and its Gaussians (those whose `instance` is its id and whose role is
//! object). The rest (a = −1) is the residual set, kept as GMM primitives.

use bytemuck::Zeroable;

use crate::fuse;
use crate::gmm::{Gaussian, ROLE_OBJECT, ROLE_RESIDUAL};
use crate::linalg::{self, Vec3};
use crate::params::Params;
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
    /// With [`SQ_ACCEPTED`]: part of its superquadric's camera-facing surface projects outside the image
    /// ([`crate::superquadric::reaches_outside_image`]), so the camera saw only part of the object and the rest
    /// of the shape is the fit's guess ([`crate::map::MapSq::partial`]).
    pub sq_partial: bool,
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

/// Largest gap (metres) between the point boxes of two Gaussians of one object that still joins them in
/// [`detach_stray_parts`]: one voxel edge (neighbouring supervoxels meet within a voxel) plus the depth
/// tolerance at the farther of the two (their boxes may stand apart along the ray by the depth noise).
pub fn part_gap(a: &Gaussian, b: &Gaussian, params: &Params) -> f32 {
    part_gap_at(a.mean[2].max(b.mean[2]), params)
}

/// [`part_gap`] at depth `z`, metres (it grows with depth, as the depth tolerance does).
fn part_gap_at(z: f32, params: &Params) -> f32 {
    params.voxel_resolution + params.depth_tolerance(z)
}

/// Keeps, of every object grouped by [`group_objects`], only its largest part: its Gaussians are joined when
/// their point boxes are at most [`part_gap`] apart, and every part but the one with the most points becomes
/// residual Gaussians (unlabelled: role residual, owner, instance, class and score 0, as the residual set's).
/// A solid object is one connected part; a second part is what an instance mask lent it across a depth jump
/// (a mask that bleeds past the silhouette onto the wall or floor behind, or onto a neighbour in front). The
/// parts stay in the map as Gaussians. Returns the Gaussians detached; regroup the objects when it is not 0.
///
/// `scratch` must hold 2 × `gaussians.len()` entries (the profile guarantees it); with less nothing is done.
/// The Gaussians' `cluster` fields (the fused clusters) are kept.
pub fn detach_stray_parts(gaussians: &mut [Gaussian], n_objects: usize, scratch: &mut [u16], params: &Params) -> u32 {
    let n = gaussians.len();
    let Some((order, saved)) = scratch.get_mut(..2 * n).map(|s| s.split_at_mut(n)) else { return 0 };
    for (slot, g) in saved.iter_mut().zip(gaussians.iter()) {
        *slot = g.cluster;
    }
    // No Gaussian lies beyond `depth_max`: the largest gap there bounds the sweep.
    fuse::connect(gaussians, order, part_gap_at(params.depth_max, params), |a, b| {
        a.role == ROLE_OBJECT
            && b.role == ROLE_OBJECT
            && a.owner == b.owner
            && fuse::box_gap(a, b) <= part_gap(a, b, params)
    });
    // `cluster` now holds the parts, and `order` lists the Gaussians part by part.
    let mut detached = 0;
    for k in 0..n_objects.min(u8::MAX as usize) {
        let of_object = |g: &Gaussian| g.role == ROLE_OBJECT && g.owner as usize == k;
        let mut best: Option<(u32, u16)> = None;
        let mut parts = 0;
        fuse::for_each_cluster(gaussians, order, |gaussians, part, members| {
            let mine = members.first().and_then(|&i| gaussians.get(i as usize)).is_some_and(of_object);
            if mine {
                parts += 1;
                let points = members.iter().filter_map(|&i| gaussians.get(i as usize)).map(|g| g.count).sum();
                if best.is_none_or(|(p, _)| points > p) {
                    best = Some((points, part));
                }
            }
        });
        let Some((_, keep)) = best.filter(|_| parts > 1) else { continue };
        for g in gaussians.iter_mut().filter(|g| of_object(g) && g.cluster != keep) {
            (g.role, g.owner, g.instance, g.class, g.score) = (ROLE_RESIDUAL, 0, 0, 0, 0.0);
            detached += 1;
        }
    }
    for (g, &c) in gaussians.iter_mut().zip(saved.iter()) {
        g.cluster = c;
    }
    detached
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gmm::ROLE_PLANE;

    /// An object Gaussian of object `owner` (instance `owner + 1`) over the box `lo`..`hi`, metres.
    fn part(owner: u8, count: u32, lo: Vec3, hi: Vec3, cluster: u16) -> Gaussian {
        let mut g = Gaussian::zeroed();
        (g.role, g.owner, g.instance, g.class, g.score) = (ROLE_OBJECT, owner, owner as u16 + 1, 7, 0.9);
        (g.count, g.bbox_min, g.bbox_max, g.cluster) = (count, lo, hi, cluster);
        g.mean = linalg::scale(linalg::add(lo, hi), 0.5);
        g
    }

    #[test]
    fn only_the_largest_connected_part_of_an_object_stays_in_it() {
        let params = Params::default();
        let mut gaussians = [
            // Object 0: a stray 12-point part 40 cm behind (listed first), then two touching parts of a box.
            part(0, 12, [0.0, 0.0, 1.9], [0.1, 0.1, 2.0], 5),
            part(0, 300, [0.0, 0.0, 1.0], [0.2, 0.2, 1.2], 3),
            part(0, 200, [0.21, 0.0, 1.0], [0.4, 0.2, 1.2], 3),
            // A plane Gaussian between them joins nothing.
            part(0, 500, [0.0, 0.0, 1.2], [0.4, 0.2, 1.9], 4),
            // Object 1: one part, 4 cm from object 0 (other objects never join).
            part(1, 50, [0.44, 0.0, 1.0], [0.6, 0.2, 1.2], 6),
        ];
        if let Some(g) = gaussians.get_mut(3) {
            g.role = ROLE_PLANE;
        }
        let mut scratch = [0u16; 10];
        let detached = detach_stray_parts(&mut gaussians, 2, &mut scratch, &params);
        assert_eq!(detached, 1);
        let roles: [u8; 5] = core::array::from_fn(|i| gaussians[i].role);
        assert_eq!(roles, [ROLE_RESIDUAL, ROLE_OBJECT, ROLE_OBJECT, ROLE_PLANE, ROLE_OBJECT]);
        assert_eq!((gaussians[0].instance, gaussians[0].class, gaussians[0].score), (0, 0, 0.0));
        assert_eq!(gaussians[1].instance, 1);
        // The fused clusters are kept.
        let clusters: [u16; 5] = core::array::from_fn(|i| gaussians[i].cluster);
        assert_eq!(clusters, [5, 3, 3, 4, 6]);
        // Without room for two entries per Gaussian nothing changes.
        let mut again = gaussians;
        again[0] = part(0, 12, [0.0, 0.0, 1.9], [0.1, 0.1, 2.0], 5);
        assert_eq!(detach_stray_parts(&mut again, 2, &mut scratch[..9], &params), 0);
        assert_eq!(again[0].role, ROLE_OBJECT);
    }

    #[test]
    fn parts_within_a_voxel_and_the_depth_tolerance_stay_joined() {
        let params = Params::default();
        // Two parts 4 cm apart along the ray at 1 m (voxel 3 cm + tolerance 2 cm = 5 cm): one object.
        let mut gaussians =
            [part(0, 100, [0.0, 0.0, 1.0], [0.1, 0.1, 1.1], 0), part(0, 10, [0.0, 0.0, 1.14], [0.1, 0.1, 1.2], 1)];
        let mut scratch = [0u16; 4];
        assert!(part_gap(&gaussians[0], &gaussians[1], &params) >= 0.05 - 1e-6);
        assert_eq!(detach_stray_parts(&mut gaussians, 1, &mut scratch, &params), 0);
        // 7 cm apart: the small part is detached.
        gaussians[1] = part(0, 10, [0.0, 0.0, 1.17], [0.1, 0.1, 1.2], 1);
        assert_eq!(detach_stray_parts(&mut gaussians, 1, &mut scratch, &params), 1);
        assert_eq!(gaussians[1].role, ROLE_RESIDUAL);
    }
}
