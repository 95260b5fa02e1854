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
//! splits). The stored Gaussian comes from its voxels alone, with no pass over the points: the mean, count and
//! colour are exact (the voxels' counts, means and colour sums); the covariance (denominator N − 1, as the
//! paper) is the voxels' exact between-voxel scatter plus a modelled within-voxel part, and the support boxes are
//! modelled from each voxel's mean and normal ([`voxel_support_statistics`]).
//! The work list is an explicit stack of voxel-order ranges; there is no recursion.
//!
//! **When the Gaussian pool runs short (drop policy).** A cluster is split only while the pool keeps room for
//! both halves, for one Gaussian per range still on the stack and for one per supervoxel still to come; else it
//! stays whole (a coarser Gaussian, counted as an overflow event of the pool in [`GmmStats::splits_refused`]).
//! What a short pool loses is detail of the last supervoxels, not their points: each supervoxel keeps at least
//! one Gaussian as long as there are no more supervoxels than the pool holds.

use bytemuck::Zeroable;

use crate::frame::Frame;
use crate::linalg::{self, Moments, Sym3, Vec3};
use crate::params::Params;
use crate::pool::Bounded;
use crate::supervoxel::{self, Supervoxel, Voxel, DROPPED};

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
    /// Voxel order scratch (at least as long as `voxels`).
    pub order: &'a mut [u16],
    /// Supervoxels of stage 2.
    pub supervoxels: &'a mut [Supervoxel],
    /// Split work stack.
    pub stack: &'a mut Bounded<'b, SplitTask>,
    /// Output Gaussians.
    pub gaussians: &'a mut Bounded<'b, Gaussian>,
}

/// Refines every supervoxel into Gaussians and computes their statistics from their voxels
/// ([`voxel_support_statistics`]); `frame` gives the camera the projected boxes are taken in.
pub fn refine(pools: GmmPools<'_, '_>, frame: &Frame<'_>, params: &Params) -> GmmStats {
    let GmmPools { voxels, order, supervoxels, stack, gaussians } = pools;
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

    voxel_support_statistics(frame, voxels, gaussians.as_mut_slice(), params);
    stats
}

/// Sets a Gaussian's voxel-level statistics from the voxels in `range`: point count, exact mean and mean colour
/// (from the voxels' counts, means and colour sums); resets those [`voxel_support_statistics`] accumulates.
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

/// The covariance (denominator N − 1), eigen frame, 3-D support box and projected support box of every
/// Gaussian from its voxels alone, given its mean and count from [`voxel_statistics`]: no pass over the points.
///
/// The scatter of a Gaussian's points about its mean μ is, exactly, the scatter of its voxels' means (each
/// weighted by its point count n) plus each voxel's scatter about its own mean. The voxels do not keep the
/// latter (six second moments cost 24 bytes a voxel, 204 KiB of the mcu profile, which it has not got), so it
/// is modelled from what a voxel keeps, its mean m and normal (`voxel_spread`): n − 1 times the covariance
/// of points spread over the voxel's surface, the expected scatter of n such points about their mean. The
/// support box is the union of the voxels' boxes of that surface about m; the projected box is the projection
/// of the surface's box over the whole cube, rounded outwards, so that it holds every pixel of the Gaussian's
/// points (the windows of the later passes and the mask-box tests rely on that).
pub fn voxel_support_statistics(frame: &Frame<'_>, voxels: &[Voxel], gaussians: &mut [Gaussian], params: &Params) {
    let r = params.voxel_resolution;
    let k = &frame.intrinsics;
    let (w, h) = (frame.width.saturating_sub(1) as f32, frame.height.saturating_sub(1) as f32);
    for v in voxels {
        let Some(g) = gaussians.get_mut(v.gaussian as usize) else { continue };
        let m = v.centroid();
        let corner = supervoxel::key_corner(v.key, r);
        let far = linalg::add(corner, [r; 3]);
        let spread = voxel_spread(m, v.unit_normal(), corner, r, params.depth_noise(m[2]));
        let d = linalg::sub(m, g.mean);
        let count = v.count as f32;
        let weight = (count - 1.0).max(0.0);
        let within = spread.covariance;
        let between = [d[0] * d[0], d[0] * d[1], d[0] * d[2], d[1] * d[1], d[1] * d[2], d[2] * d[2]];
        for ((c, b), s) in g.covariance.iter_mut().zip(between).zip(within) {
            *c += count * b + weight * s;
        }
        let lo = linalg::max_elem(linalg::sub(m, spread.half), corner);
        let hi = linalg::min_elem(linalg::add(m, spread.half), far);
        g.bbox_min = linalg::min_elem(g.bbox_min, lo);
        g.bbox_max = linalg::max_elem(g.bbox_max, hi);
        let lo = linalg::max_elem(linalg::sub(m, spread.reach), corner);
        let hi = linalg::min_elem(linalg::add(m, spread.reach), far);
        // x/z over the box is least at its least x over the farthest z when that x is ahead of the camera
        // (x ≥ 0), else over the nearest z; likewise the largest, and y/z.
        let (z_near, z_far) = (lo[2].max(MIN_PROJECTED_DEPTH), hi[2].max(MIN_PROJECTED_DEPTH));
        let least = |a: f32| if a >= 0.0 { a / z_far } else { a / z_near };
        let most = |a: f32| if a >= 0.0 { a / z_near } else { a / z_far };
        let px = |x: f32, top: f32| x.clamp(0.0, top) as u16;
        let b = &mut g.pixel_bbox;
        b[0] = b[0].min(px(libm::floorf(k.fx * least(lo[0]) + k.cx), w));
        b[1] = b[1].min(px(libm::floorf(k.fy * least(lo[1]) + k.cy), h));
        b[2] = b[2].max(px(libm::ceilf(k.fx * most(hi[0]) + k.cx), w));
        b[3] = b[3].max(px(libm::ceilf(k.fy * most(hi[1]) + k.cy), h));
    }
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

/// Nearest depth a voxel's box is projected at, metres (no sampled point is this near; it keeps the division
/// finite).
const MIN_PROJECTED_DEPTH: f32 = 1e-3;

/// The modelled spread of a voxel's points about their mean (see [`voxel_support_statistics`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct VoxelSpread {
    /// Covariance of the points about their mean, m², `[xx, xy, xz, yy, yz, zz]`.
    covariance: Sym3,
    /// Half-widths about the mean of the box of the points' modelled surface, metres per axis.
    half: Vec3,
    /// Half-widths about the mean of the box of the surface's whole extent in the cube, metres per axis.
    reach: Vec3,
}

/// The spread of the points of a voxel with mean `m`, unit normal `n`, cube corner `corner` and edge `r`
/// (metres). The points lie on the plane through m with normal n. Along the two axes a, b the normal is least
/// along, they are uniform over the widest interval about m inside the cube, half-width h = min(m − c, c + r − m)
/// (variance h²/3: r²/12 for a voxel its surface crosses whole, less for one it crosses in part); along the
/// third axis k they follow the plane, x_k moving by −(n_a Δx_a + n_b Δx_b)/n_k. The boxes: h along a and b,
/// |n_a| h_a + |n_b| h_b over |n_k| along k (`half`), or the same with the farthest faces H = max(m − c,
/// c + r − m) (`reach`), each widened by two sigmas of the depth noise `noise` (metres) across the plane. The
/// noise itself is left out of the covariance: with σ(z)·|ray · n| across the plane in it, λ2 came out 15–17 %
/// above the exact one (median over the Gaussians of the synthetic tabletop and desk) and those scenes' primitives
/// per frame rose by 11–13 % (thicker Gaussians fail the flatness tests); without it they stay within 2 %.
fn voxel_spread(m: Vec3, n: Vec3, corner: Vec3, r: f32, noise: f32) -> VoxelSpread {
    let [x, y, z] = n;
    let abs = [x.abs(), y.abs(), z.abs()];
    let [ax, ay, az] = abs;
    let near = |mi: f32, ci: f32| (mi - ci).min(ci + r - mi).clamp(0.0, 0.5 * r);
    let far = |mi: f32, ci: f32| (mi - ci).max(ci + r - mi).clamp(0.5 * r, r);
    let h = [near(m[0], corner[0]), near(m[1], corner[1]), near(m[2], corner[2])];
    let hf = [far(m[0], corner[0]), far(m[1], corner[1]), far(m[2], corner[2])];
    let ratio = |a: f32, b: f32| if b.abs() > 1e-6 { a / b } else { 0.0 };
    // Per dominant axis k: the plane's directions e_a − (n_a/n_k) e_k and e_b − (n_b/n_k) e_k with the
    // half-widths along a and b, and each box's lift along k.
    let lift = |h: &Vec3, a: usize, b: usize, k: usize| {
        let get = |v: &Vec3, i: usize| v.get(i).copied().unwrap_or(0.0);
        ratio(get(&abs, a) * get(h, a) + get(&abs, b) * get(h, b), get(&abs, k))
    };
    let (p, hp, q, hq, half, reach) = if ax >= ay && ax >= az {
        let (l, lf) = (lift(&h, 1, 2, 0), lift(&hf, 1, 2, 0));
        ([-ratio(y, x), 1.0, 0.0], h[1], [-ratio(z, x), 0.0, 1.0], h[2], [l, h[1], h[2]], [lf, hf[1], hf[2]])
    } else if ay >= az {
        let (l, lf) = (lift(&h, 2, 0, 1), lift(&hf, 2, 0, 1));
        ([0.0, -ratio(z, y), 1.0], h[2], [1.0, -ratio(x, y), 0.0], h[0], [h[0], l, h[2]], [hf[0], lf, hf[2]])
    } else {
        let (l, lf) = (lift(&h, 0, 1, 2), lift(&hf, 0, 1, 2));
        ([1.0, 0.0, -ratio(x, z)], h[0], [0.0, 1.0, -ratio(y, z)], h[1], [h[0], h[1], l], [hf[0], hf[1], lf])
    };
    let (up, uq) = (hp * hp / 3.0, hq * hq / 3.0);
    let e = |a: (f32, f32), b: (f32, f32)| up * a.0 * b.0 + uq * a.1 * b.1;
    let (cx, cy, cz) = ((p[0], q[0]), (p[1], q[1]), (p[2], q[2]));
    let covariance = [e(cx, cx), e(cx, cy), e(cx, cz), e(cy, cy), e(cy, cz), e(cz, cz)];
    let widen = [2.0 * noise * ax, 2.0 * noise * ay, 2.0 * noise * az];
    VoxelSpread { covariance, half: linalg::add(half, widen), reach: linalg::add(reach, widen) }
}

/// Recomputes every Gaussian's statistics after voxels changed Gaussian: groups the voxel indices by Gaussian in
/// `order`, then [`voxel_statistics`] per Gaussian and [`voxel_support_statistics`].
pub fn recompute_statistics(
    frame: &Frame<'_>,
    voxels: &[Voxel],
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
    voxel_support_statistics(frame, voxels, gaussians, params);
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
        let mut acc = [Moments::about(centres[0].p), Moments::about(centres[1].p)];
        let mut normals = [[0.0f32; 3]; 2];
        for v in range.iter().filter_map(|&i| voxels.get(i as usize)) {
            let f = Feature::of(v);
            let k = if nearer_first(&f, &centres) { 0 } else { 1 };
            if let (Some(a), Some(n)) = (acc.get_mut(k), normals.get_mut(k)) {
                a.add(f.p, v.count as f32);
                *n = linalg::add(*n, linalg::scale(f.n, v.count as f32));
            }
        }
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
                order: &mut order,
                supervoxels: &mut supervoxels,
                stack: &mut stack,
                gaussians: &mut gaussians,
            },
            &frame,
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

#[cfg(test)]
mod voxel_statistics_tests {
    extern crate std;

    use std::vec::Vec;

    use super::*;
    use crate::frame::Intrinsics;

    /// Points on a plane through (0.02, −0.03, 1.1) m with unit normal `n`, on a 1.5 mm grid over ±`extent`
    /// metres along two in-plane directions: a dense, evenly sampled surface, as a depth camera sees one.
    fn plane_points(n: Vec3, extent: f32) -> Vec<Vec3> {
        let centre = [0.02, -0.03, 1.1];
        let a = linalg::normalize_or(linalg::cross(n, [0.0, 1.0, 0.0]), [1.0, 0.0, 0.0]);
        let b = linalg::cross(n, a);
        let steps = (2.0 * extent / 0.0015) as i32;
        let mut points = Vec::new();
        for i in 0..=steps {
            for j in 0..=steps {
                let (s, t) = (-extent + i as f32 * 0.0015, -extent + j as f32 * 0.0015);
                points.push(linalg::add(centre, linalg::add(linalg::scale(a, s), linalg::scale(b, t))));
            }
        }
        points
    }

    /// Voxelises `points` as stage 1 does (count and mean per 3 cm cube, every voxel given the plane's normal),
    /// all in Gaussian 0, and returns the voxels with the Gaussian (mean and count exact).
    fn voxelised(points: &[Vec3], n: Vec3, r: f32) -> (Vec<Voxel>, Gaussian) {
        let mut voxels: Vec<Voxel> = Vec::new();
        for &p in points {
            let key = supervoxel::voxel_key(p, r, 0).unwrap();
            let i = match voxels.iter().position(|v| v.key == key) {
                Some(i) => i,
                None => {
                    let mut v = Voxel::zeroed();
                    v.key = key;
                    v.normal = n.map(supervoxel::quantise_unit);
                    voxels.push(v);
                    voxels.len() - 1
                }
            };
            let v = &mut voxels[i];
            v.count += 1;
            v.mean = linalg::add(v.mean, p);
        }
        for v in voxels.iter_mut() {
            v.mean = linalg::scale(v.mean, 1.0 / v.count as f32);
        }
        let mut g = Gaussian::zeroed();
        let order: Vec<u16> = (0..voxels.len() as u16).collect();
        voxel_statistics(&mut g, &order, &voxels);
        (voxels, g)
    }

    /// The exact covariance (denominator N − 1) and box of `points`.
    fn exact(points: &[Vec3]) -> (Eigen3Values, Vec3, Vec3) {
        let n = points.len() as f32;
        let mean = linalg::scale(points.iter().fold([0.0; 3], |s, &p| linalg::add(s, p)), 1.0 / n);
        let mut c = [0.0f32; 6];
        for &p in points {
            let d = linalg::sub(p, mean);
            for (ci, x) in
                c.iter_mut().zip([d[0] * d[0], d[0] * d[1], d[0] * d[2], d[1] * d[1], d[1] * d[2], d[2] * d[2]])
            {
                *ci += x / (n - 1.0);
            }
        }
        let lo = points.iter().fold([f32::MAX; 3], |m, &p| linalg::min_elem(m, p));
        let hi = points.iter().fold([f32::MIN; 3], |m, &p| linalg::max_elem(m, p));
        (linalg::sym_eigen(c).values, lo, hi)
    }

    type Eigen3Values = Vec3;

    /// Planes facing the camera, tilted about one axis and about two, over 6 × 6 cm to 30 × 30 cm: the
    /// voxel-level statistics give the in-plane variances within 6 % of the points' exact ones (within 1 % from
    /// 16 cm across; the modelled within-voxel part is a large share of a small patch's, a quarter for a patch
    /// two voxels across), the thickness below 1 mm, a support box within half a voxel of the exact one, and a
    /// projected box that holds every point's pixel.
    #[test]
    #[allow(clippy::needless_range_loop)] // the axes of several arrays at once
    fn voxel_level_statistics_match_the_points_of_planes() {
        let r = Params::default().voxel_resolution;
        let params = Params::default();
        let intrinsics = Intrinsics { fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 };
        let frame = Frame {
            width: 640,
            height: 480,
            depth: &[0],
            depth_scale: 1000.0,
            colour: &[0, 0, 0],
            intrinsics,
            pose: None,
        };
        let normals = [
            [0.0, 0.0, -1.0],
            linalg::normalize_or([0.5, 0.0, -1.0], [0.0; 3]),
            linalg::normalize_or([0.4, -0.6, -1.0], [0.0; 3]),
        ];
        for n in normals {
            for extent in [0.03, 0.08, 0.15] {
                let points = plane_points(n, extent);
                let (voxels, mut g) = voxelised(&points, n, r);
                voxel_support_statistics(&frame, &voxels, core::slice::from_mut(&mut g), &params);
                let (values, lo, hi) = exact(&points);
                for k in 0..2 {
                    let ratio = g.eigenvalues[k] / values[k];
                    assert!(
                        (ratio - 1.0).abs() < 0.06,
                        "n {n:?} extent {extent}: λ{k} {} vs exact {}",
                        g.eigenvalues[k],
                        values[k]
                    );
                }
                assert!(g.eigenvalues[2].sqrt() < 1e-3, "n {n:?} extent {extent}: σ2 {}", g.eigenvalues[2].sqrt());
                for i in 0..3 {
                    assert!((g.bbox_min[i] - lo[i]).abs() <= 0.5 * r, "n {n:?} extent {extent}: box min {i}");
                    assert!((g.bbox_max[i] - hi[i]).abs() <= 0.5 * r, "n {n:?} extent {extent}: box max {i}");
                }
                for p in &points {
                    let u = intrinsics.fx * p[0] / p[2] + intrinsics.cx;
                    let v = intrinsics.fy * p[1] / p[2] + intrinsics.cy;
                    let b = g.pixel_bbox;
                    assert!(
                        u >= b[0] as f32 && u <= b[2] as f32 && v >= b[1] as f32 && v <= b[3] as f32,
                        "n {n:?} extent {extent}: pixel ({u}, {v}) outside {b:?}"
                    );
                }
            }
        }
    }
}
