//! Stage 3: IH-GMM-style hierarchical refinement of each supervoxel into compact Gaussians, the set C_g
//! (paper §III-A, after Gao and Dong's integrated hierarchical GMM, for which no public code exists).
//!
//! **Split rule (decided here; docs/pipeline.md, stage 3).** A cluster (a set of voxels of one supervoxel) is
//! split in two when all of these hold:
//! - it is not compact: its thickness σ2 exceeds max(`gmm_max_thickness`, `gmm_noise_sigmas`·σ(z)) (1 cm, or
//!   twice the sensor's depth noise at the cluster's mean depth z: it bends or spans two surfaces),
//!   its voxel normals spread more than `gmm_max_normal_spread` (a fold or a junction of two surfaces that is
//!   still thin, such as a narrow strip of wall above a floor), or its largest principal scale σ0 exceeds
//!   `gmm_max_extent` (0.15 m; it is too large to be local);
//! - it has at least `2 · gmm_min_points` points and at least two voxels;
//! - it is fewer than `gmm_max_depth` splits below its supervoxel.
//!
//! **How it splits.** 2-means on (voxel centroid, voxel normal) weighted by point counts, with the distance
//! d² = ‖Δp‖² + (`gmm_normal_weight`·‖Δn‖)² and `gmm_kmeans_iters` Lloyd iterations. A cluster split for its
//! normal spread is first seeded at the two voxels whose normals differ most (the one farthest from the mean
//! normal, then the one farthest from that); then at μ ± σ0·e0 along the principal axis; and a thick cluster
//! last at μ ± σ2·e2 across its thickness (two parallel layers, such as a slab on a floor). The first seeding
//! that gives two large enough halves is used. The split is kept only when both halves
//! have at least `gmm_min_points` points; otherwise the cluster is a leaf. Leaves are the Gaussians.
//!
//! Split decisions use voxel centroids (within-voxel spread is averaged out, so sensor noise does not force
//! splits). The stored Gaussian is exact at point level: the mean and count come from the voxels' counts and
//! means, and the covariance (denominator N − 1, as the paper) and support box from a second pass over the
//! sampled points.
//! The work list is an explicit stack of voxel-order ranges; there is no recursion.
//!
//! **When the Gaussian pool runs short (drop policy).** A cluster is split only while the pool keeps room for
//! both halves, for one Gaussian per range still on the stack and for one per supervoxel still to come; else it
//! stays whole (a coarser Gaussian, counted as an overflow event of the pool in [`GmmStats::splits_refused`]).
//! What a short pool loses is detail of the last supervoxels, not their points: each supervoxel keeps at least
//! one Gaussian as long as there are no more supervoxels than the pool holds.

use bytemuck::Zeroable;
use m2smap_fpu::SpreadSums;

use crate::frame::Frame;
use crate::linalg::{self, Moments, Sym3, Vec3};
use crate::masks::MaskSet;
use crate::params::Params;
use crate::pool::Bounded;
use crate::supervoxel::{self, Revisit, Supervoxel, Voxel, DROPPED};

/// One refined Gaussian component of C_g.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct Gaussian {
    /// Mean μ of its support points, metres.
    pub mean: Vec3,
    /// Covariance Σ (denominator N − 1), m², as `[xx, xy, xz, yy, yz, zz]`.
    pub covariance: Sym3,
    /// Eigenvalues λ0 ≥ λ1 ≥ λ2 of Σ, m².
    pub eigenvalues: Vec3,
    /// Unit eigenvectors (rows), `axes[k]` for λk, right-handed; `axes[2]` is the normal.
    pub axes: [Vec3; 3],
    /// Support points N.
    pub count: u32,
    /// Mean colour of the support, RGB.
    pub colour: [u8; 3],
    /// Minimum corner of the support's axis-aligned box, metres.
    pub bbox_min: Vec3,
    /// Maximum corner of the support's axis-aligned box, metres.
    pub bbox_max: Vec3,
    /// Projected support box B_i^2D `[u0, v0, u1, v1]`, inclusive pixels.
    pub pixel_bbox: [u16; 4],
    /// Detection confidence s of the matched mask (0 when unannotated).
    pub score: f32,
    /// Mask support ratio ρ of the matched mask (0 when unannotated).
    pub support_ratio: f32,
    /// Supervoxel it was refined from.
    pub supervoxel: u16,
    /// Fused cluster (the fusion map Γ, read backwards), after stage 5.
    pub cluster: u16,
    /// Instance id a of the matched mask; 0 means a = −1 (unannotated).
    pub instance: u16,
    /// Category label ℓ of the matched mask (index into the caller's label table).
    pub class: u16,
    /// Role after flat-plane separation: [`ROLE_NONE`], [`ROLE_PLANE`], [`ROLE_OBJECT`] or [`ROLE_RESIDUAL`].
    pub role: u8,
    /// Index of the plane (`ROLE_PLANE`) or object (`ROLE_OBJECT`) it belongs to; a stage-local mark before
    /// separation.
    pub owner: u8,
}

/// Role before separation has run.
pub const ROLE_NONE: u8 = 0;
/// Support of a bounded plane (removed from the Gaussian map).
pub const ROLE_PLANE: u8 = 1;
/// Part of a semantic object support set.
pub const ROLE_OBJECT: u8 = 2;
/// Residual structure, kept as a GMM primitive.
pub const ROLE_RESIDUAL: u8 = 3;

impl Gaussian {
    /// A zeroed Gaussian used to carry semantic attributes (a, ℓ, s, ρ) between stages.
    pub fn default_label() -> Gaussian {
        Gaussian::zeroed()
    }

    /// Principal scales σk = √λk, metres.
    pub fn sigmas(&self) -> Vec3 {
        [linalg::sqrt(self.eigenvalues[0]), linalg::sqrt(self.eigenvalues[1]), linalg::sqrt(self.eigenvalues[2])]
    }
}

/// A pending range `[start, end)` of the voxel order, `depth` splits below its supervoxel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Zeroable)]
#[repr(C)]
pub struct SplitTask {
    /// First position in the voxel order.
    pub start: u16,
    /// One past the last position.
    pub end: u16,
    /// Splits made above this range.
    pub depth: u8,
    /// Supervoxel of the range.
    pub supervoxel: u16,
}

/// Counts of the refinement stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GmmStats {
    /// Splits made.
    pub splits: u32,
    /// Points whose Gaussian did not fit the pool.
    pub dropped_points: u32,
    /// Splits not made because the pool had no room for their halves (see the module docs); each is an overflow
    /// event of the Gaussian pool.
    pub splits_refused: u32,
}

/// Storage the refinement stage works in.
pub struct GmmPools<'a, 'b> {
    /// The labelled voxels (their `gaussian` field is written).
    pub voxels: &'a mut [Voxel],
    /// The voxel hash slots.
    pub slots: &'a [u16],
    /// How the passes find the sampled points again ([`supervoxel::Revisit`]).
    pub revisit: Revisit<'a>,
    /// Voxel order scratch (at least as long as `voxels`).
    pub order: &'a mut [u16],
    /// Supervoxels of stage 2.
    pub supervoxels: &'a mut [Supervoxel],
    /// Split work stack.
    pub stack: &'a mut Bounded<'b, SplitTask>,
    /// Output Gaussians.
    pub gaussians: &'a mut Bounded<'b, Gaussian>,
}

/// Refines every supervoxel into Gaussians and computes their exact point statistics.
pub fn refine(
    pools: GmmPools<'_, '_>,
    frame: &Frame<'_>,
    voxel_masks: Option<&MaskSet<'_>>,
    params: &Params,
) -> GmmStats {
    let GmmPools { voxels, slots, revisit, order, supervoxels, stack, gaussians } = pools;
    let mut stats = GmmStats::default();
    gaussians.clear();
    stack.clear();

    // Counting sort of voxel indices by supervoxel.
    let mut next = 0u16;
    for sv in supervoxels.iter_mut() {
        sv.first = next;
        next = next.saturating_add(sv.voxels);
    }
    for (i, v) in voxels.iter().enumerate() {
        if let Some(sv) = supervoxels.get_mut(v.supervoxel as usize) {
            if let Some(slot) = order.get_mut(sv.first as usize) {
                *slot = i as u16;
            }
            sv.first = sv.first.saturating_add(1);
        }
    }
    let count = supervoxels.len();
    for (s, sv) in supervoxels.iter_mut().enumerate() {
        sv.first = sv.first.saturating_sub(sv.voxels);
        let end = sv.first.saturating_add(sv.voxels);
        let _ = stack.push(SplitTask { start: sv.first, end, depth: 0, supervoxel: s as u16 });
        // Depth-first, one supervoxel at a time, so the Gaussian order follows the supervoxel order.
        let later = count - s - 1;
        while let Some(task) = stack.pop() {
            process(task, voxels, order, stack, gaussians, later, params, &mut stats);
        }
    }
    gaussians.add_overflows(stats.splits_refused);

    point_statistics(frame, voxel_masks, voxels, slots, revisit, gaussians.as_mut_slice(), params);
    stats
}

/// Sets a Gaussian's voxel-level statistics from the voxels in `range`: point count, exact mean and mean colour
/// (from the voxels' counts, means and colour sums); resets the point-level ones that [`point_statistics`] accumulates.
pub fn voxel_statistics(g: &mut Gaussian, range: &[u16], voxels: &[Voxel]) {
    let (m, points) = range_moments(range, voxels);
    let mut colour = [0u64; 3];
    for v in range.iter().filter_map(|&i| voxels.get(i as usize)) {
        for (c, s) in colour.iter_mut().zip(v.colour_sums()) {
            *c += s as u64;
        }
    }
    let n = points.max(1) as u64;
    g.mean = m.mean();
    g.count = points;
    g.colour = [(colour[0] / n) as u8, (colour[1] / n) as u8, (colour[2] / n) as u8];
    g.covariance = [0.0; 6];
    g.bbox_min = [f32::MAX; 3];
    g.bbox_max = [f32::MIN; 3];
    g.pixel_bbox = [u16::MAX, u16::MAX, 0, 0];
}

/// Second pass over the points: the exact covariance (denominator N − 1), eigen frame, 3-D support box and
/// projected support box of every Gaussian, given its mean from [`voxel_statistics`].
pub fn point_statistics(
    frame: &Frame<'_>,
    voxel_masks: Option<&MaskSet<'_>>,
    voxels: &[Voxel],
    slots: &[u16],
    revisit: Revisit<'_>,
    gaussians: &mut [Gaussian],
    params: &Params,
) {
    supervoxel::for_each_voxel_point(frame, params, voxel_masks, voxels, slots, revisit, |p, v| {
        let Some(g) = v.and_then(|(_, v)| gaussians.get_mut(v.gaussian as usize)) else { return };
        // Covariance sums about the mean, support box and pixel box (on the Cortex-M7 by load/store multiple:
        // m2smap-fpu, feature `vldm`).
        let sums = SpreadSums {
            covariance: &mut g.covariance,
            bbox_min: &mut g.bbox_min,
            bbox_max: &mut g.bbox_max,
            pixel_bbox: &mut g.pixel_bbox,
        };
        m2smap_fpu::add_to_spread(sums, &g.mean, p.xyz, p.u, p.v);
    });
    for g in gaussians.iter_mut() {
        let k = if g.count > 1 { 1.0 / (g.count - 1) as f32 } else { 0.0 };
        for c in g.covariance.iter_mut() {
            *c *= k;
        }
        let e = linalg::sym_eigen(g.covariance);
        g.eigenvalues = e.values;
        g.axes = e.vectors;
    }
}

/// Recomputes every Gaussian's statistics after voxels changed Gaussian: groups the voxel indices by Gaussian in
/// `order`, then [`voxel_statistics`] per Gaussian and one [`point_statistics`] pass.
#[allow(clippy::too_many_arguments)]
pub fn recompute_statistics(
    frame: &Frame<'_>,
    voxel_masks: Option<&MaskSet<'_>>,
    voxels: &[Voxel],
    slots: &[u16],
    revisit: Revisit<'_>,
    order: &mut [u16],
    gaussians: &mut [Gaussian],
    params: &Params,
) {
    let n = voxels.len().min(order.len());
    let Some(order) = order.get_mut(..n) else { return };
    for (i, o) in order.iter_mut().enumerate() {
        *o = i as u16;
    }
    let label = |i: u16| voxels.get(i as usize).map_or(u16::MAX, |v| v.gaussian);
    order.sort_unstable_by(|&a, &b| label(a).cmp(&label(b)).then(a.cmp(&b)));
    let mut start = 0;
    while start < n {
        let g = order.get(start).map_or(u16::MAX, |&i| label(i));
        let mut end = start + 1;
        while end < n && order.get(end).map_or(u16::MAX, |&i| label(i)) == g {
            end += 1;
        }
        if let (Some(gauss), Some(range)) = (gaussians.get_mut(g as usize), order.get(start..end)) {
            voxel_statistics(gauss, range, voxels);
        }
        start = end;
    }
    point_statistics(frame, voxel_masks, voxels, slots, revisit, gaussians, params);
}

/// Weighted voxel-centroid moments of the range, and its point count.
fn range_moments(range: &[u16], voxels: &[Voxel]) -> (Moments, u32) {
    let first = range.first().and_then(|&i| voxels.get(i as usize).map(Voxel::centroid)).unwrap_or([0.0; 3]);
    let mut m = Moments::about(first);
    let mut points = 0u32;
    for v in range.iter().filter_map(|&i| voxels.get(i as usize)) {
        m.add(v.centroid(), v.count as f32);
        points += v.count as u32;
    }
    (m, points)
}

#[allow(clippy::too_many_arguments)]
fn process(
    task: SplitTask,
    voxels: &mut [Voxel],
    order: &mut [u16],
    stack: &mut Bounded<'_, SplitTask>,
    gaussians: &mut Bounded<'_, Gaussian>,
    later_supervoxels: usize,
    params: &Params,
    stats: &mut GmmStats,
) {
    let Some(range) = order.get_mut(task.start as usize..task.end as usize) else { return };
    let (m, points) = range_moments(range, voxels);
    let eig = linalg::sym_eigen(m.covariance());
    let sigma = eig.sigmas();
    let (mean_normal, spread) = normal_spread(range, voxels);
    let bent = spread > params.gmm_max_normal_spread;
    let max_thickness = params.gmm_max_thickness.max(params.gmm_noise_sigmas * params.depth_noise(m.mean()[2]));
    let compact = sigma[2] <= max_thickness && sigma[0] <= params.gmm_max_extent && !bent;
    let splittable = task.depth < params.gmm_max_depth && points >= 2 * params.gmm_min_points && range.len() >= 2;
    // Room for both halves, a Gaussian per range still on the stack and one per supervoxel still to come.
    let room = gaussians.len() + stack.len() + 2 + later_supervoxels <= gaussians.capacity();
    if !compact && splittable && !room {
        stats.splits_refused += 1;
    }
    if !compact && splittable && room {
        // Candidate seedings, tried in order until one gives two halves of at least `gmm_min_points`: the two
        // most different normals (a fold), the principal axis (too long), the thickness axis (two layers).
        let mean = m.mean();
        let along = |axis: Vec3, s: f32| {
            let offset = linalg::scale(axis, s);
            [
                Feature { p: linalg::add(mean, offset), n: mean_normal },
                Feature { p: linalg::sub(mean, offset), n: mean_normal },
            ]
        };
        let candidates = [
            bent.then(|| normal_seeds(range, voxels, mean_normal)),
            Some(along(eig.vectors[0], sigma[0])),
            (sigma[2] > max_thickness).then(|| along(eig.vectors[2], sigma[2])),
        ];
        let split =
            candidates.into_iter().flatten().find_map(|seeds| two_means_partition(range, voxels, seeds, params));
        if let Some(mid) = split {
            let mid = task.start + mid as u16;
            let right = SplitTask { start: mid, end: task.end, depth: task.depth + 1, supervoxel: task.supervoxel };
            let left = SplitTask { start: task.start, end: mid, depth: task.depth + 1, supervoxel: task.supervoxel };
            if stack.push(right).is_some() {
                if stack.push(left).is_some() {
                    stats.splits += 1;
                    return;
                }
                stack.pop();
            }
            // The stack is full (counted by the pool): the cluster stays whole.
        }
    }
    // Leaf: one Gaussian.
    let Some(range) = order.get(task.start as usize..task.end as usize) else { return };
    let mut g = Gaussian::zeroed();
    voxel_statistics(&mut g, range, voxels);
    g.supervoxel = task.supervoxel;
    let label = match gaussians.push(g) {
        Some(id) => id as u16,
        None => {
            stats.dropped_points += points;
            DROPPED
        }
    };
    for &i in range {
        if let Some(v) = voxels.get_mut(i as usize) {
            v.gaussian = label;
        }
    }
}

/// A point in the 2-means feature space: position (metres) and unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Feature {
    p: Vec3,
    n: Vec3,
}

impl Feature {
    #[inline(always)]
    fn of(v: &Voxel) -> Self {
        Feature { p: v.centroid(), n: v.unit_normal() }
    }

    fn distance2(&self, other: &Feature, normal_weight: f32) -> f32 {
        let (dp, dn) = (linalg::sub(self.p, other.p), linalg::sub(self.n, other.n));
        linalg::dot(dp, dp) + normal_weight * normal_weight * linalg::dot(dn, dn)
    }
}

/// Point-weighted mean normal (unit) of the range and the spread mean(1 − |n_v · n̄|).
fn normal_spread(range: &[u16], voxels: &[Voxel]) -> (Vec3, f32) {
    let mut sum = [0.0f32; 3];
    let mut weight = 0.0f32;
    for v in range.iter().filter_map(|&i| voxels.get(i as usize)) {
        sum = linalg::add(sum, linalg::scale(v.unit_normal(), v.count as f32));
        weight += v.count as f32;
    }
    let mean = linalg::normalize_or(sum, [0.0, 0.0, -1.0]);
    let mut spread = 0.0f32;
    for v in range.iter().filter_map(|&i| voxels.get(i as usize)) {
        spread += v.count as f32 * (1.0 - libm::fabsf(linalg::dot(v.unit_normal(), mean)));
    }
    (mean, if weight > 0.0 { spread / weight } else { 0.0 })
}

/// Seeds for a bent cluster: the voxel whose normal is farthest from the mean, then the one farthest from it.
fn normal_seeds(range: &[u16], voxels: &[Voxel], mean_normal: Vec3) -> [Feature; 2] {
    let farthest_from = |n: Vec3| {
        let mut best: Option<(f32, Feature)> = None;
        for v in range.iter().filter_map(|&i| voxels.get(i as usize)) {
            let d = linalg::dot(v.unit_normal(), n);
            if best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, Feature::of(v)));
            }
        }
        best.map(|(_, f)| f)
    };
    let a = farthest_from(mean_normal).unwrap_or(Feature { p: [0.0; 3], n: mean_normal });
    let b = farthest_from(a.n).unwrap_or(a);
    [a, b]
}

/// Splits `range` in place into two groups by 2-means from `seeds`; returns the size of the first group, or
/// `None` when either group would have fewer than `gmm_min_points` points.
fn two_means_partition(range: &mut [u16], voxels: &[Voxel], seeds: [Feature; 2], params: &Params) -> Option<usize> {
    let w = params.gmm_normal_weight;
    let mut centres = seeds;
    let nearer_first = |f: &Feature, c: &[Feature; 2]| f.distance2(&c[0], w) <= f.distance2(&c[1], w);
    for _ in 0..params.gmm_kmeans_iters {
        let (mut a0, mut a1) = (Moments::about(centres[0].p), Moments::about(centres[1].p));
        let (mut n0, mut n1) = ([0.0f32; 3], [0.0f32; 3]);
        for v in range.iter().filter_map(|&i| voxels.get(i as usize)) {
            let f = Feature::of(v);
            let w = v.count as f32;
            // A branch per group, not an index into arrays of sums: each group's sums stay in registers.
            if nearer_first(&f, &centres) {
                a0.add(f.p, w);
                n0 = linalg::add(n0, linalg::scale(f.n, w));
            } else {
                a1.add(f.p, w);
                n1 = linalg::add(n1, linalg::scale(f.n, w));
            }
        }
        let (acc, normals) = ([a0, a1], [n0, n1]);
        if acc[0].weight == 0.0 || acc[1].weight == 0.0 {
            return None;
        }
        let updated = [
            Feature { p: acc[0].mean(), n: linalg::normalize_or(normals[0], centres[0].n) },
            Feature { p: acc[1].mean(), n: linalg::normalize_or(normals[1], centres[1].n) },
        ];
        if updated == centres {
            break;
        }
        centres = updated;
    }
    // Two-pointer partition: first-group voxels to the front.
    let (mut lo, mut hi) = (0usize, range.len());
    let mut first_points = 0u32;
    let mut second_points = 0u32;
    while lo < hi {
        let i = range.get(lo).copied()? as usize;
        let v = voxels.get(i)?;
        if nearer_first(&Feature::of(v), &centres) {
            first_points += v.count as u32;
            lo += 1;
        } else {
            second_points += v.count as u32;
            hi -= 1;
            range.swap(lo, hi);
        }
    }
    let ok = first_points >= params.gmm_min_points && second_points >= params.gmm_min_points;
    ok.then_some(lo).filter(|&m| m > 0 && m < range.len())
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use crate::frame::Intrinsics;

    /// `n` voxels, each of 10 points, 3 cm apart along x from `x0` at y = `y`, z = 1 m, facing the camera, in
    /// supervoxel `sv`: a strip 3·n cm long, which the extent rule splits while its σ0 (length/√12) exceeds
    /// 15 cm.
    fn strip(voxels: &mut [Voxel], first: usize, n: usize, x0: f32, y: f32, sv: u16) {
        for (k, v) in voxels.iter_mut().skip(first).take(n).enumerate() {
            *v = Voxel::zeroed();
            v.key = (first + k) as u32;
            v.count = 10;
            v.mean = [x0 + 0.03 * k as f32, y, 1.0];
            v.normal = [0, 0, -32767];
            v.supervoxel = sv;
        }
    }

    /// Refines two 1.2 m strips (two supervoxels) into at most `capacity` Gaussians; returns the Gaussians'
    /// supervoxels, the stats, the pool's overflow events and whether every voxel got a Gaussian.
    fn refine_strips(capacity: usize) -> (std::vec::Vec<u16>, GmmStats, u32, bool) {
        const N: usize = 40;
        let mut voxels = [Voxel::zeroed(); 2 * N];
        strip(&mut voxels, 0, N, -0.6, 0.0, 0);
        strip(&mut voxels, N, N, -0.6, 0.3, 1);
        let mut supervoxels = [Supervoxel::zeroed(); 2];
        for sv in &mut supervoxels {
            sv.voxels = N as u16;
        }
        let mut order = [0u16; 2 * N];
        let mut tasks = [SplitTask::zeroed(); 64];
        let mut stack = Bounded::new(&mut tasks);
        let mut store = std::vec![Gaussian::zeroed(); capacity];
        let mut gaussians = Bounded::new(&mut store);
        let frame = Frame {
            width: 1,
            height: 1,
            depth: &[0],
            depth_scale: 1000.0,
            colour: &[0, 0, 0],
            intrinsics: Intrinsics { fx: 500.0, fy: 500.0, cx: 0.5, cy: 0.5 },
            pose: None,
        };
        let stats = refine(
            GmmPools {
                voxels: &mut voxels,
                slots: &[],
                revisit: Revisit::Listed(&[]),
                order: &mut order,
                supervoxels: &mut supervoxels,
                stack: &mut stack,
                gaussians: &mut gaussians,
            },
            &frame,
            None,
            &Params::default(),
        );
        let owners = gaussians.as_slice().iter().map(|g| g.supervoxel).collect();
        let labelled = voxels.iter().all(|v| (v.gaussian as usize) < gaussians.len());
        (owners, stats, gaussians.usage().overflow_events, labelled)
    }

    /// With room, each strip splits into four 30 cm pieces (1.2 m → 0.6 m, σ0 17 cm → 0.3 m, σ0 8.7 cm); with
    /// a pool of 3, the first strip keeps room for the second: 2 + 1 Gaussians, no point dropped, every refused
    /// split an overflow event.
    #[test]
    fn a_short_gaussian_pool_coarsens_the_last_clusters_instead_of_dropping_them() {
        let (owners, stats, overflows, labelled) = refine_strips(64);
        let per_strip = owners.iter().filter(|&&s| s == 0).count();
        assert_eq!(per_strip, 4, "a 1.2 m strip in 30 cm pieces");
        assert_eq!(owners.iter().filter(|&&s| s == 1).count(), per_strip);
        assert_eq!((stats.dropped_points, stats.splits_refused, overflows), (0, 0, 0));
        assert!(labelled);

        let (owners, stats, overflows, labelled) = refine_strips(3);
        assert_eq!(owners, [0, 0, 1]);
        assert_eq!(stats.dropped_points, 0);
        assert_eq!(stats.splits_refused, 3, "both halves of the first strip and the whole second one");
        assert_eq!(overflows, stats.splits_refused);
        assert!(labelled, "every voxel has a Gaussian");

        // One Gaussian per supervoxel is the least: a pool of 1 drops the second strip's 400 points.
        let (owners, stats, _, _) = refine_strips(1);
        assert_eq!(owners, [0]);
        assert_eq!(stats.dropped_points, 400);
    }
}
