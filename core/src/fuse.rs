//! Stage 5: semantic-constrained Gaussian fusion (paper §IV-A, equation 7).
//!
//! Two Gaussians fuse when ψ = ψ_g ∧ ψ_s holds: their AABB gap is at most `d_connect`, their unsigned normal
//! angle at most `theta_min_deg`, min(l_ij, l_ji) at most `l_min` (ψ_g); and, with semantic fusion, their
//! instance ids are equal (ψ_s; two unannotated Gaussians may fuse, an object and a plane may not) and neither
//! is an uncertain object fragment ([`is_uncertain`]).
//! Connected components of that graph are the fused clusters. The fusion map Γ is kept in every Gaussian's
//! `cluster` field (fused cluster → original Gaussians is "all Gaussians with that cluster id").
//!
//! Candidate pairs come from a sweep over the Gaussians sorted by the low x of their boxes: only pairs whose x
//! intervals are within `d_connect` are tested, instead of all n² pairs. Union-find runs in the `cluster`
//! fields (lowest index becomes the root), so the result does not depend on the order of tests.

use crate::gmm::Gaussian;
use crate::linalg::{self, Eigen3, Moments};
use crate::params::Params;
use crate::union_find;

/// Counts of the fusion stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FuseStats {
    /// Fused clusters.
    pub clusters: u32,
    /// Candidate pairs tested (after the sweep's x-interval filter).
    pub pair_tests: u32,
    /// Pairs that passed ψ.
    pub links: u32,
}

/// The AABB gap d_box between two Gaussians (equation 6), metres.
pub fn box_gap(a: &Gaussian, b: &Gaussian) -> f32 {
    let low_gap = linalg::sub(b.bbox_min, a.bbox_max);
    let high_gap = linalg::sub(a.bbox_min, b.bbox_max);
    let gap = linalg::max_elem(linalg::max_elem(low_gap, high_gap), [0.0; 3]);
    linalg::norm(gap)
}

/// An unannotated Gaussian with a real part of its support inside a mask — at least
/// max(`gmm_min_points`, `mask_split_min_share` · N) points, the same test that makes a Gaussian a candidate
/// for the mask cut, or most of its points however few — that was neither annotated nor cut apart (too small,
/// or mixed below voxel resolution). With semantic fusion it fuses with nothing, so object points are never
/// glued to the background through it (an m2smap extension of ψ_s, off in [`crate::Variant::Paper`]).
pub fn is_uncertain(g: &Gaussian, params: &Params) -> bool {
    let inside = g.support_ratio * g.count as f32;
    let share = g.support_ratio >= params.mask_split_min_share && inside >= params.gmm_min_points as f32;
    params.variant.extensions() && g.instance == 0 && (share || g.support_ratio > 0.5)
}

/// The geometric predicate ψ_g of two Gaussians.
pub fn geometric_link(a: &Gaussian, b: &Gaussian, cos_theta_min: f32, params: &Params) -> bool {
    let (na, nb) = (a.axes[2], b.axes[2]);
    if libm::fabsf(linalg::dot(na, nb)) < cos_theta_min {
        return false;
    }
    let d = linalg::sub(b.mean, a.mean);
    let l_ab = libm::fabsf(linalg::dot(d, na));
    let l_ba = libm::fabsf(linalg::dot(d, nb));
    l_ab.min(l_ba) <= params.l_min && box_gap(a, b) <= params.d_connect
}

/// Fusion's union-find lives in the Gaussians' `cluster` field.
impl union_find::Parents for [Gaussian] {
    fn count(&self) -> usize {
        self.len()
    }

    fn parent(&self, i: usize) -> usize {
        self.get(i).map_or(i, |g| g.cluster as usize)
    }

    fn set_parent(&mut self, i: usize, parent: usize) {
        if let Some(g) = self.get_mut(i) {
            g.cluster = parent as u16;
        }
    }
}

/// Fuses the Gaussians; afterwards `cluster` holds compact cluster ids 0..C, numbered by their lowest Gaussian,
/// and `order[..n]` lists the Gaussians grouped by cluster (within a cluster by index).
pub fn fuse(gaussians: &mut [Gaussian], order: &mut [u16], params: &Params) -> FuseStats {
    let cos_theta_min = libm::cosf(params.theta_min_deg.to_radians());
    let semantic = params.variant.semantic_fusion();
    connect(gaussians, order, params.d_connect, |a, b| {
        if semantic && (a.instance != b.instance || is_uncertain(a, params) || is_uncertain(b, params)) {
            return false;
        }
        geometric_link(a, b, cos_theta_min, params)
    })
}

/// Connected components of the graph whose edges are the pairs within `reach` metres along x (the sweep) for
/// which `link` holds; ids, `cluster` fields and `order` as [`fuse`] documents.
pub fn connect(
    gaussians: &mut [Gaussian],
    order: &mut [u16],
    reach_m: f32,
    mut link: impl FnMut(&Gaussian, &Gaussian) -> bool,
) -> FuseStats {
    let mut stats = FuseStats::default();
    let n = gaussians.len().min(order.len());
    let Some(order) = order.get_mut(..n) else { return stats };
    for (i, g) in gaussians.iter_mut().enumerate() {
        g.cluster = i as u16;
    }
    for (i, o) in order.iter_mut().enumerate() {
        *o = i as u16;
    }
    let low_x = |g: &[Gaussian], i: u16| g.get(i as usize).map_or(0.0, |x| x.bbox_min[0]);
    order.sort_unstable_by(|&a, &b| low_x(gaussians, a).total_cmp(&low_x(gaussians, b)).then(a.cmp(&b)));
    for s in 0..n {
        let Some(&i) = order.get(s) else { continue };
        let Some(a) = gaussians.get(i as usize).copied() else { continue };
        let reach = a.bbox_max[0] + reach_m;
        for &j in order.get(s + 1..).unwrap_or(&[]) {
            let Some(b) = gaussians.get(j as usize).copied() else { continue };
            if b.bbox_min[0] > reach {
                break;
            }
            stats.pair_tests += 1;
            if link(&a, &b) {
                stats.links += 1;
                union_find::union(gaussians, i as usize, j as usize);
            }
        }
    }
    // Point every Gaussian straight at its root, then number the roots in index order (`order` serves as the
    // root → id map meanwhile) and replace roots by ids.
    for i in 0..n {
        let r = union_find::find(gaussians, i);
        if let Some(g) = gaussians.get_mut(i) {
            g.cluster = r as u16;
        }
    }
    let mut clusters = 0u16;
    for (i, g) in gaussians.iter().enumerate().take(n) {
        if g.cluster as usize == i {
            if let Some(o) = order.get_mut(i) {
                *o = clusters;
            }
            clusters += 1;
        }
    }
    for g in gaussians.iter_mut().take(n) {
        g.cluster = order.get(g.cluster as usize).copied().unwrap_or(0);
    }
    for (i, o) in order.iter_mut().enumerate() {
        *o = i as u16;
    }
    let cluster_of = |g: &[Gaussian], i: u16| g.get(i as usize).map_or(0, |x| x.cluster);
    order.sort_unstable_by(|&a, &b| cluster_of(gaussians, a).cmp(&cluster_of(gaussians, b)).then(a.cmp(&b)));
    stats.clusters = clusters as u32;
    stats
}

/// Calls `f(gaussians, cluster id, member indices)` for each fused cluster, given the `order` produced by
/// [`fuse`]; `f` may change the members.
pub fn for_each_cluster(gaussians: &mut [Gaussian], order: &[u16], mut f: impl FnMut(&mut [Gaussian], u16, &[u16])) {
    let n = gaussians.len().min(order.len());
    let order = order.get(..n).unwrap_or(&[]);
    let cluster_at = |g: &[Gaussian], s: usize| order.get(s).and_then(|&i| g.get(i as usize)).map(|x| x.cluster);
    let mut start = 0;
    while start < n {
        let id = cluster_at(gaussians, start);
        let mut end = start + 1;
        while end < n && cluster_at(gaussians, end) == id {
            end += 1;
        }
        f(gaussians, id.unwrap_or(0), order.get(start..end).unwrap_or(&[]));
        start = end;
    }
}

/// Moments and eigen-decomposition of a fused cluster from its member Gaussians (exact union of their points).
pub fn cluster_shape(gaussians: &[Gaussian], members: &[u16]) -> (Moments, Eigen3) {
    let reference = members.first().and_then(|&i| gaussians.get(i as usize)).map_or([0.0; 3], |g| g.mean);
    let mut m = Moments::about(reference);
    for g in members.iter().filter_map(|&i| gaussians.get(i as usize)) {
        m.add_gaussian(g.mean, g.covariance, g.count as f32);
    }
    let e = linalg::sym_eigen(m.covariance());
    (m, e)
}
