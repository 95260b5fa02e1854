//! A geometric instance segmenter: class-agnostic instance masks from depth alone, for robots without a
//! neural front end. It reuses the pipeline's own stages and produces the same [`MaskSet`](crate::MaskSet) as
//! file masks, into caller-owned buffers (an id image and an instance list).
//!
//! 1. **Supporting planes**: the Gaussians are fused geometrically (ψ_g only) and the flat-plane test of
//!    equation 8 picks the planes, of which those with σ0 ≥ `seg_support_sigma` (floors, walls, table tops;
//!    not the face of a cabinet) are support; any other thin Gaussian lying on one of them (within 2 cm, normals within
//!    θ_min) is plane support too.
//! 2. **Objects**: the remaining Gaussians are joined when their boxes are within `seg_gap` (a depth or normal
//!    discontinuity wider than that separates objects); a component with at least `seg_min_points` points and a
//!    box diagonal of at most `seg_max_extent` is an instance (label `class`, score `seg_score`).
//! 3. **Masks**: every pixel with a valid depth takes the instance of the voxel its point falls into.
//!
//! Objects that touch each other become one instance; that is what masks from a detector are for.

use crate::frame::Frame;
use crate::fuse;
use crate::gmm::{Gaussian, ROLE_NONE, ROLE_OBJECT, ROLE_PLANE};
use crate::linalg::{self, Vec3};
use crate::masks::Instance;
use crate::params::Params;
use crate::plane;
use crate::supervoxel::{self, Voxel};

/// Most supporting planes the segmenter keeps.
const MAX_SUPPORT_PLANES: usize = 16;
/// Largest distance of a thin Gaussian from a supporting plane for it to count as that plane's support, metres.
const PLANE_ATTACH_M: f32 = 0.02;

/// Counts of one segmentation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SegmentStats {
    /// Supporting planes found.
    pub planes: u32,
    /// Candidate components (before the size limits).
    pub components: u32,
    /// Instances written.
    pub instances: u32,
    /// Components that qualified but found no room in the instance buffer.
    pub truncated: u32,
}

/// Segments the frame whose Gaussians (stage 3) are in `gaussians`; writes the id image `ids` (one u16 per
/// pixel, 0 = none) and `instances`; returns how many instances it wrote. Leaves every Gaussian's stage-5
/// fields (`cluster`, `role`, `owner`) to be recomputed by the pipeline.
#[allow(clippy::too_many_arguments)]
pub fn segment(
    frame: &Frame<'_>,
    voxels: &[Voxel],
    slots: &[u16],
    gaussians: &mut [Gaussian],
    order: &mut [u16],
    params: &Params,
    ids: &mut [u16],
    instances: &mut [Instance],
    class: u16,
) -> SegmentStats {
    let mut stats = SegmentStats::default();
    // 1. Supporting planes from purely geometric fusion.
    let cos_theta = libm::cosf(params.theta_min_deg.to_radians());
    fuse::connect(gaussians, order, params.d_connect, |a, b| fuse::geometric_link(a, b, cos_theta, params));
    // (centre, normal) of at most MAX_SUPPORT_PLANES supports; beyond them a plane's Gaussians are still
    // planes, only the attachment of thin Gaussians does not look at it.
    let mut planes: heapless::Vec<(Vec3, Vec3), MAX_SUPPORT_PLANES> = heapless::Vec::new();
    fuse::for_each_cluster(gaussians, order, |gaussians, _, members| {
        let (m, e) = fuse::cluster_shape(gaussians, members);
        // Supporting structure is large: a cabinet's front is plane-shaped too, but not this long.
        let flat = plane::is_flat_plane(m.weight as u32, &e, 0, params) && e.sigmas()[0] >= params.seg_support_sigma;
        for &i in members {
            if let Some(g) = gaussians.get_mut(i as usize) {
                g.role = if flat { ROLE_PLANE } else { ROLE_NONE };
            }
        }
        if flat {
            let _ = planes.push((m.mean(), e.normal()));
        }
    });
    stats.planes = planes.len() as u32;
    for g in gaussians.iter_mut().filter(|g| g.role != ROLE_PLANE) {
        let n = g.axes[2];
        let thin = g.sigmas()[2] <= params.tau_t;
        let on_plane = planes.iter().any(|(c, pn)| {
            libm::fabsf(linalg::dot(*pn, linalg::sub(g.mean, *c))) <= PLANE_ATTACH_M
                && libm::fabsf(linalg::dot(n, *pn)) >= cos_theta
        });
        if thin && on_plane {
            g.role = ROLE_PLANE;
        }
    }
    // 2. Object components among the rest.
    let gap = params.seg_gap;
    fuse::connect(gaussians, order, gap, |a, b| {
        a.role != ROLE_PLANE && b.role != ROLE_PLANE && fuse::box_gap(a, b) <= gap
    });
    let mut written = 0usize;
    fuse::for_each_cluster(gaussians, order, |gaussians, _, members| {
        let first = members.first().and_then(|&i| gaussians.get(i as usize)).map_or(ROLE_PLANE, |g| g.role);
        if first == ROLE_PLANE {
            return;
        }
        stats.components += 1;
        let (mut lo, mut hi, mut points) = ([f32::MAX; 3], [f32::MIN; 3], 0u32);
        for g in members.iter().filter_map(|&i| gaussians.get(i as usize)) {
            lo = linalg::min_elem(lo, g.bbox_min);
            hi = linalg::max_elem(hi, g.bbox_max);
            points += g.count;
        }
        let extent = linalg::norm(linalg::sub(hi, lo));
        if points < params.seg_min_points || extent > params.seg_max_extent {
            return;
        }
        let Some(slot) = instances.get_mut(written) else {
            stats.truncated += 1;
            return;
        };
        *slot = Instance { id: written as u16 + 1, class, score: params.seg_score, bbox: [u16::MAX, u16::MAX, 0, 0] };
        for &i in members {
            if let Some(g) = gaussians.get_mut(i as usize) {
                g.role = ROLE_OBJECT;
                g.owner = written as u8;
            }
        }
        written += 1;
    });
    // 3. Masks: every valid pixel takes its voxel's instance.
    ids.fill(0);
    let (lo, hi) = frame.raw_range(params);
    let w = frame.width as usize;
    let r = params.voxel_resolution;
    for (i, (&raw, id)) in frame.depth.iter().zip(ids.iter_mut()).enumerate() {
        if raw < lo || raw > hi {
            continue;
        }
        let (u, v) = ((i % w) as u16, (i / w) as u16);
        let p = frame.intrinsics.unproject(u as f32, v as f32, frame.metres(raw));
        let Some(g) =
            supervoxel::voxel_at(voxels, slots, p, r, 0).and_then(|(_, vx)| gaussians.get(vx.gaussian as usize))
        else {
            continue;
        };
        if g.role != ROLE_OBJECT {
            continue;
        }
        if let Some(inst) = instances.get_mut(g.owner as usize) {
            *id = inst.id;
            let b = &mut inst.bbox;
            *b = [b[0].min(u), b[1].min(v), b[2].max(u), b[3].max(v)];
        }
    }
    // An instance whose voxels received no pixel keeps an empty box: drop it by giving it a one-pixel box at 0
    // with no pixels (still valid, never matched).
    for inst in instances.iter_mut().take(written) {
        if inst.bbox[0] > inst.bbox[2] {
            inst.bbox = [0, 0, 0, 0];
        }
    }
    for g in gaussians.iter_mut() {
        g.role = ROLE_NONE;
        g.owner = 0;
    }
    stats.instances = written as u32;
    stats
}
