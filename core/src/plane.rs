//! Stages 6–7: flat-plane separation (paper §IV-B, equation 8) and bounded planes (§V-A, equations 9–10).
//!
//! A fused cluster is a flat plane when it has at least N_min points, is thin (σ2 ≤ τ_t or λ2/λ0 ≤ τ_λ), extends
//! in both directions (σ0, σ1 ≥ τ_s) and carries no instance (a = −1): a flat object such as a laptop stays an
//! object. The plane stores its centroid, tangent frame (e1, e2), normal n = e1 × e2, principal scales,
//! eigenvalue ratio, colour, source cluster, and the occupied cells of a `g_p` grid in its tangent plane, as a
//! bitmap of [`PLANE_GRID`]² cells centred on the centroid. One representative point per occupied cell
//! (its centre, equation 10) reconstructs it; cells come only from support voxels whose centroid lies on the
//! plane (within the depth tolerance at its depth), so the plane is bounded by what was observed of it and never
//! claims the footprint of an object standing on it.

use bytemuck::Zeroable;

use crate::gmm::{Gaussian, ROLE_PLANE};
use crate::linalg::{self, Eigen3, Vec3};
use crate::params::Params;
use crate::supervoxel::Voxel;

/// Cells per side of a plane's occupancy grid (±2 m around the centroid at g_p = 5 cm).
pub const PLANE_GRID: usize = 80;
/// Bytes of the occupancy bitmap.
pub const PLANE_GRID_BYTES: usize = PLANE_GRID * PLANE_GRID / 8;

/// One bounded plane.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct Plane {
    /// Centroid μ_r, metres.
    pub centroid: Vec3,
    /// First tangent direction e1 (largest variance).
    pub e1: Vec3,
    /// Second tangent direction e2.
    pub e2: Vec3,
    /// Unit normal n = e1 × e2.
    pub normal: Vec3,
    /// Principal scales σ0, σ1, σ2 (σ2 is the thickness), metres.
    pub sigmas: Vec3,
    /// Eigenvalue ratio λ2/λ0.
    pub eigen_ratio: f32,
    /// Support points.
    pub points: u32,
    /// Support points outside the occupancy grid (not drawn; counted).
    pub clipped_points: u32,
    /// Occupied cells.
    pub occupied: u16,
    /// Source fused cluster.
    pub cluster: u16,
    /// Mean colour, RGB.
    pub colour: [u8; 3],
    /// Occupancy bitmap, row-major over (a, b) cell indices offset by `PLANE_GRID / 2`.
    pub cells: [u8; PLANE_GRID_BYTES],
}

/// Most flat patches a frame keeps as support candidates ([`FlatPatch`]).
pub const MAX_FLAT_PATCHES: usize = 16;
/// Least support of a flat patch, points.
pub const PATCH_MIN_POINTS: u32 = 100;
/// Least second principal scale σ1 of a flat patch, metres (a strip is no support).
pub const PATCH_MIN_SIGMA: f32 = 0.03;

/// A flat fused cluster that is not a bounded plane (typically the top or a face of an object, or a small
/// unlabelled board): a support candidate for the superquadrics of other objects. Camera frame, metres.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct FlatPatch {
    /// Centroid, metres.
    pub centroid: Vec3,
    /// First tangent direction.
    pub e1: Vec3,
    /// Second tangent direction.
    pub e2: Vec3,
    /// Unit normal.
    pub normal: Vec3,
    /// Half extents along e1 and e2 (2σ0, 2σ1), metres.
    pub half: [f32; 2],
    /// Support points.
    pub points: u32,
    /// Instance id of its Gaussians (0 = none).
    pub instance: u16,
}

impl FlatPatch {
    /// A patch from a cluster's shape when it is flat (σ2 ≤ τ_t or λ2/λ0 ≤ τ_λ), has at least
    /// [`PATCH_MIN_POINTS`] points and σ1 ≥ [`PATCH_MIN_SIGMA`].
    pub fn from_cluster(centroid: Vec3, e: &Eigen3, points: u32, instance: u16, params: &Params) -> Option<FlatPatch> {
        let s = e.sigmas();
        let thin = s[2] <= params.tau_t || e.values[2] <= params.tau_lambda * e.values[0];
        (thin && points >= PATCH_MIN_POINTS && s[1] >= PATCH_MIN_SIGMA).then(|| FlatPatch {
            centroid,
            e1: e.vectors[0],
            e2: e.vectors[1],
            normal: linalg::normalize_or(linalg::cross(e.vectors[0], e.vectors[1]), e.vectors[2]),
            half: [2.0 * s[0], 2.0 * s[1]],
            points,
            instance,
        })
    }

    /// Whether the foot of `p` on the patch's plane lies within its extent grown by `margin` metres.
    pub fn covers(&self, p: Vec3, margin: f32) -> bool {
        let d = linalg::sub(p, self.centroid);
        libm::fabsf(linalg::dot(d, self.e1)) <= self.half[0] + margin
            && libm::fabsf(linalg::dot(d, self.e2)) <= self.half[1] + margin
    }
}

/// Keeps the [`MAX_FLAT_PATCHES`] largest patches in `patches[..*n]`: `patch` is added while there is room,
/// else it replaces the smallest kept patch when it is larger. Returns whether a patch was dropped.
pub fn keep_largest(patches: &mut [FlatPatch], n: &mut usize, patch: FlatPatch) -> bool {
    if let Some(slot) = patches.get_mut(*n) {
        *slot = patch;
        *n += 1;
        return false;
    }
    let kept = patches.get_mut(..*n).unwrap_or(&mut []);
    if let Some(smallest) = kept.iter_mut().min_by_key(|p| p.points) {
        if smallest.points < patch.points {
            *smallest = patch;
        }
    }
    true
}

/// Equation 8: whether a fused cluster with `points` points, eigen-decomposition `e` and instance `instance`
/// (0 = none) is a flat plane.
pub fn is_flat_plane(points: u32, e: &Eigen3, instance: u16, params: &Params) -> bool {
    let s = e.sigmas();
    let thin = s[2] <= params.tau_t || e.values[2] <= params.tau_lambda * e.values[0];
    points >= params.n_min && thin && s[0] >= params.tau_s && s[1] >= params.tau_s && instance == 0
}

impl Plane {
    /// A plane from a flat cluster's shape; cells are filled later by [`fill_cells`].
    pub fn new(centroid: Vec3, e: &Eigen3, points: u32, colour: [u8; 3], cluster: u16) -> Plane {
        let mut p = Plane::zeroed();
        p.centroid = centroid;
        p.e1 = e.vectors[0];
        p.e2 = e.vectors[1];
        p.normal = linalg::normalize_or(linalg::cross(e.vectors[0], e.vectors[1]), e.vectors[2]);
        p.sigmas = e.sigmas();
        p.eigen_ratio = if e.values[0] > 0.0 { e.values[2] / e.values[0] } else { 0.0 };
        p.points = points;
        p.colour = colour;
        p.cluster = cluster;
        p
    }

    /// A point's coordinates along e1 and e2 from the centroid, in cells of size `g_p` (equation 9 before
    /// its floor).
    fn cell_coordinates(&self, p: Vec3, g_p: f32) -> [f32; 2] {
        let d = linalg::sub(p, self.centroid);
        [linalg::dot(d, self.e1) / g_p, linalg::dot(d, self.e2) / g_p]
    }

    /// Cell index (a, b) of a point (equation 9), offset into the grid, or `None` outside it.
    pub fn cell_of(&self, p: Vec3, g_p: f32) -> Option<(usize, usize)> {
        let [s, t] = self.cell_coordinates(p, g_p);
        let half = (PLANE_GRID / 2) as i32;
        let a = linalg::floor_i32(s) + half;
        let b = linalg::floor_i32(t) + half;
        let range = 0..PLANE_GRID as i32;
        (range.contains(&a) && range.contains(&b)).then_some((a as usize, b as usize))
    }

    /// Whether cell (a, b) (grid coordinates) is occupied.
    pub fn is_occupied(&self, a: usize, b: usize) -> bool {
        let i = b * PLANE_GRID + a;
        a < PLANE_GRID && crate::cells::bit(&self.cells, i)
    }

    /// Whether (a, b) (grid coordinates) lies within the bounding box of the occupied cells grown by `reach`
    /// cells. The cells right under an object resting on the plane are hidden by it, so an object's foot is
    /// judged against the extent of the plane, not its cells.
    pub fn within_occupied_box(&self, a: usize, b: usize, reach: usize) -> bool {
        crate::cells::bitmap_box(&self.cells, PLANE_GRID, PLANE_GRID)
            .is_some_and(|(a0, b0, a1, b1)| a + reach >= a0 && a <= a1 + reach && b + reach >= b0 && b <= b1 + reach)
    }

    /// Whether point `p` (camera frame, metres) lies on the plane: within the depth tolerance at its depth
    /// ([`Params::depth_tolerance`]) of the plane through the centroid. Only such a point shows where the plane
    /// was seen, so only such points mark cells.
    pub fn is_on_plane(&self, p: Vec3, params: &Params) -> bool {
        on_plane(p, self.centroid, self.normal, params)
    }

    fn occupy(&mut self, a: usize, b: usize) {
        let i = b * PLANE_GRID + a;
        if let Some(byte) = self.cells.get_mut(i / 8) {
            if (*byte >> (i % 8)) & 1 == 0 {
                *byte |= 1 << (i % 8);
                self.occupied += 1;
            }
        }
    }

    /// Calls `f` with the representative point of every occupied cell (equation 10), metres, in grid order.
    pub fn for_each_cell_centre(&self, g_p: f32, mut f: impl FnMut(Vec3)) {
        let half = (PLANE_GRID / 2) as f32;
        for b in 0..PLANE_GRID {
            for a in 0..PLANE_GRID {
                if self.is_occupied(a, b) {
                    let u = (a as f32 - half + 0.5) * g_p;
                    let v = (b as f32 - half + 0.5) * g_p;
                    f(linalg::add(self.centroid, linalg::add(linalg::scale(self.e1, u), linalg::scale(self.e2, v))));
                }
            }
        }
    }
}

/// Marks the occupied cells of every plane from the voxels of its plane-role Gaussians, one step per voxel and
/// no pass over the pixels. A voxel whose centroid (the mean of its sampled points) lies on the plane stands
/// for its points there: it marks the cells under the four corners of a square of side r/4 (r the voxel
/// edge) centred on the centroid in the plane's tangent frame, so that a voxel whose points straddle a cell
/// edge near its middle marks both cells, as its points would. With the centroid's cell alone the planes'
/// boundaries came out ragged (cabinet: 241 B per frame map against 214 B from the points); a side of r/4
/// keeps the payload within 1 % and G2R within 1.1 % of the points' cells on every dataset of `make eval`
/// (r/3: cabinet 206 B but G2R up to 3 % higher, the squares reaching past the support).
pub fn fill_cells(voxels: &[Voxel], gaussians: &[Gaussian], planes: &mut [Plane], params: &Params) {
    if planes.is_empty() {
        return;
    }
    // Half the square's side, in cells; a coordinate in cells from the grid's corner to its cell index.
    let h = params.voxel_resolution / 8.0 / params.g_p;
    let half = (PLANE_GRID / 2) as f32;
    let cell = |x: f32| {
        let i = linalg::floor_i32(x);
        (0..PLANE_GRID as i32).contains(&i).then_some(i as usize)
    };
    for v in voxels {
        let Some(g) = gaussians.get(v.gaussian as usize) else { continue };
        if g.role != ROLE_PLANE {
            continue;
        }
        let Some(plane) = planes.get_mut(g.owner as usize) else { continue };
        let c = v.centroid();
        // A voxel off the plane (an object's foot, a chair leg in the floor's Gaussian) would claim the plane's
        // surface where the camera saw something else.
        if !plane.is_on_plane(c, params) {
            continue;
        }
        // The centroid's tangent-plane coordinates in cells from the grid's corner (equation 9); the square's
        // corners are these ± h.
        let [s, t] = plane.cell_coordinates(c, params.g_p).map(|x| x + half);
        if cell(s).is_none() || cell(t).is_none() {
            plane.clipped_points += u32::from(v.count);
            continue;
        }
        for (a, b) in [(s - h, t - h), (s + h, t - h), (s - h, t + h), (s + h, t + h)] {
            if let (Some(a), Some(b)) = (cell(a), cell(b)) {
                plane.occupy(a, b);
            }
        }
    }
}

/// Whether point `p` lies within the depth tolerance at its depth ([`Params::depth_tolerance`]) of the plane
/// through `centroid` with unit `normal` (camera frame, metres): [`Plane::is_on_plane`].
fn on_plane(p: Vec3, centroid: Vec3, normal: Vec3, params: &Params) -> bool {
    linalg::plane_distance(p, centroid, normal) <= params.depth_tolerance(p[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A floor 1 m below the camera at 3 m depth: normal −y.
    fn floor() -> Plane {
        Plane { centroid: [0.0, 1.0, 3.0], normal: [0.0, -1.0, 0.0], ..Plane::zeroed() }
    }

    #[test]
    fn only_points_within_the_depth_tolerance_mark_plane_cells() {
        let params = Params::default();
        let plane = floor();
        // At 3 m the tolerance is 3 σ(3 m) = 3 × (0.0012 + 0.0019 × 2.6²) = 4.2 cm.
        let tolerance = params.depth_tolerance(3.0);
        assert!((tolerance - 0.042).abs() < 1e-3, "{tolerance}");
        assert!(plane.is_on_plane([0.3, 1.0 - 0.04, 3.0], &params), "4 cm above the floor at 3 m is noise");
        assert!(plane.is_on_plane([0.3, 1.04, 3.0], &params), "and so is 4 cm below");
        assert!(!plane.is_on_plane([0.3, 1.0 - 0.08, 3.0], &params), "8 cm above it is an object's foot");
        // Near the camera the 2 cm floor of the tolerance rules: 2.5 cm off at 1 m is off the plane.
        let near = Plane { centroid: [0.0, 0.5, 1.0], ..floor() };
        assert!(near.is_on_plane([0.1, 0.5 - 0.019, 1.0], &params));
        assert!(!near.is_on_plane([0.1, 0.5 - 0.025, 1.0], &params));
    }

    /// Voxels mark the cells under their centroid's r/4 square, on the plane only, and count what falls outside
    /// the grid; voxels of other roles, and voxels without a Gaussian, mark nothing.
    #[test]
    fn plane_voxels_mark_the_cells_under_their_centroid() {
        extern crate std;
        use crate::gmm::ROLE_RESIDUAL;
        use crate::supervoxel::{voxel_key, UNLABELLED};
        use std::collections::BTreeSet;
        let params = Params::default();
        let r = params.voxel_resolution;
        // The floor of `floor()` with e1 = x and e2 = z (n = e1 × e2 = −y).
        let plane = Plane { e1: [1.0, 0.0, 0.0], e2: [0.0, 0.0, 1.0], ..floor() };
        // A voxel of `count` points whose centroid is `(s, t)` along (e1, e2) from the plane's centroid and `off`
        // above the plane, in Gaussian `gaussian`.
        let voxel = |s: f32, t: f32, off: f32, count: u16, gaussian: u16| {
            let p = [s, 1.0 - off, 3.0 + t];
            let key = voxel_key(p, r, 0).expect("in the key range");
            Voxel { key, count, gaussian, mean: p, ..Voxel::zeroed() }
        };
        let voxels = [
            voxel(0.012, 0.012, 0.0, 5, 0),        // in cell (40, 40) with its whole square
            voxel(0.102, 0.011, 0.0, 3, 0),        // 2 mm past the edge between cells 41 and 42 along e1: both
            voxel(0.30, 0.30, 0.08, 7, 0),         // 8 cm above the floor (an object's foot): no cell
            voxel(2.5, 0.0, 0.0, 4, 0),            // beyond the ±2 m grid: clipped
            voxel(-0.30, 0.0, 0.0, 6, 1),          // a residual Gaussian's: no cell
            voxel(-0.50, 0.0, 0.0, 6, UNLABELLED), // no Gaussian: no cell
        ];
        let mut gaussians = [Gaussian::zeroed(), Gaussian::zeroed()];
        gaussians[0].role = ROLE_PLANE;
        gaussians[1].role = ROLE_RESIDUAL;
        let mut planes = [plane];
        fill_cells(&voxels, &gaussians, &mut planes, &params);
        let mut occupied = BTreeSet::new();
        for b in 0..PLANE_GRID {
            for a in 0..PLANE_GRID {
                if planes[0].is_occupied(a, b) {
                    occupied.insert((a, b));
                }
            }
        }
        assert_eq!(occupied, BTreeSet::from([(40, 40), (40 + 1, 40), (40 + 2, 40)]));
        assert_eq!(planes[0].occupied, 3);
        assert_eq!(planes[0].clipped_points, 4);
    }
}
