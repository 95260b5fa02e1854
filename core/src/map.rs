//! The frame map: bounded planes, object superquadrics and GMM primitives (paper §V) with their semantic
//! attributes, and the deterministic reconstruction samples of docs/metrics.md used by evaluation and rendering.

use bytemuck::Zeroable;

use crate::linalg::{self, Mat3, Vec3};
use crate::superquadric::{Superquadric, LANES};

/// How [`CellBits::bits`] codes the occupied cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellCoding {
    /// A bitmap: bit `k % 8` of byte `k / 8` for cell index k = row × width + column.
    Bitmap,
    /// Run lengths over the cells in index order, alternately unset and set (starting with unset, which may
    /// be an empty run), each an unsigned LEB128 varint; together they cover every cell
    /// ([`crate::cells::CellRuns`]).
    Runs,
    /// Each row's transitions coded against the row above in a bit stream ([`crate::cells`]).
    Edges,
}

/// The occupied plane cells: `width × height` cells from cell (a0, b0), row-major, coded as [`CellCoding`] says.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellBits<'a> {
    /// Cell index along e1 of the first column.
    pub a0: i16,
    /// Cell index along e2 of the first row.
    pub b0: i16,
    /// Columns.
    pub width: u16,
    /// Rows.
    pub height: u16,
    /// How `bits` codes the cells.
    pub coding: CellCoding,
    /// The coded cells: for a bitmap at least `ceil(width × height / 8)` bytes.
    pub bits: &'a [u8],
}

impl CellBits<'_> {
    /// Calls `f(column, row)` for every occupied cell, in row-major order.
    pub fn for_each_set(&self, mut f: impl FnMut(usize, usize)) {
        let w = (self.width as usize).max(1);
        let cells = self.width as usize * self.height as usize;
        match self.coding {
            CellCoding::Bitmap => {
                for k in 0..cells {
                    if crate::cells::bit(self.bits, k) {
                        f(k % w, k / w);
                    }
                }
            }
            CellCoding::Edges => {
                crate::cells::for_each_edge_cell(self.bits, self.width as usize, self.height as usize, f)
            }
            CellCoding::Runs => {
                let mut k = 0usize;
                for (r, run) in crate::cells::CellRuns::new(self.bits).enumerate() {
                    let end = (k + run as usize).min(cells);
                    if r % 2 == 1 {
                        for c in k..end {
                            f(c % w, c / w);
                        }
                    }
                    k = end;
                }
            }
        }
    }

    /// Whether column `i`, row `j` is occupied.
    pub fn is_set(&self, i: usize, j: usize) -> bool {
        if i >= self.width as usize || j >= self.height as usize {
            return false;
        }
        let k = j * self.width as usize + i;
        match self.coding {
            CellCoding::Bitmap => crate::cells::bit(self.bits, k),
            CellCoding::Edges => {
                let mut hit = false;
                crate::cells::for_each_edge_cell(self.bits, self.width as usize, j + 1, |a, b| hit |= a == i && b == j);
                hit
            }
            CellCoding::Runs => {
                let mut start = 0usize;
                for (r, run) in crate::cells::CellRuns::new(self.bits).enumerate() {
                    start += run as usize;
                    if k < start {
                        return r % 2 == 1;
                    }
                }
                false
            }
        }
    }

    /// Occupied cells.
    pub fn count(&self) -> usize {
        let mut n = 0;
        self.for_each_set(|_, _| n += 1);
        n
    }

    /// The smallest (i0, j0, i1, j1) box holding every occupied cell, `None` when empty.
    pub fn occupied_box(&self) -> Option<(usize, usize, usize, usize)> {
        if self.coding == CellCoding::Bitmap {
            return crate::cells::bitmap_box(self.bits, self.width as usize, self.height as usize);
        }
        let mut b: Option<(usize, usize, usize, usize)> = None;
        self.for_each_set(|i, j| {
            b = Some(match b {
                None => (i, j, i, j),
                Some((i0, j0, i1, j1)) => (i0.min(i), j0.min(j), i1.max(i), j1.max(j)),
            });
        });
        b
    }
}

/// A bounded plane of the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPlane<'a> {
    /// Centroid, metres.
    pub centroid: Vec3,
    /// Columns e1, e2 and the normal n.
    pub rotation: Mat3,
    /// Principal scales σ0, σ1 and thickness σ2, metres.
    pub sigmas: Vec3,
    /// λ2/λ0.
    pub eigen_ratio: f32,
    /// Colour.
    pub colour: [u8; 3],
    /// Source fused cluster.
    pub cluster: u16,
    /// Cell size g_p, metres.
    pub g_p: f32,
    /// Occupied cells.
    pub cells: CellBits<'a>,
}

/// An object superquadric of the map.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
pub struct MapSq {
    /// The shape and pose (camera frame).
    pub sq: Superquadric,
    /// Instance id.
    pub instance: u16,
    /// Category label.
    pub class: u16,
    /// Detection confidence.
    pub score: f32,
    /// Track id.
    pub track: u16,
    /// The camera saw only part of it in this frame: some of its camera-facing surface projects outside the
    /// image, and the shape there is the fit's guess (a cupboard cut by the image border, fitted as a slab that
    /// runs on past it). The world map takes no shape from such a view ([`crate::world`]). Not on the wire: a
    /// decoded map has `false`.
    pub partial: bool,
}

/// A GMM primitive of the map (paper §V-C): μ, Σ = R·diag(d²)·Rᵀ, N, colour and (a, ℓ, s, ρ).
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
pub struct MapGmm {
    /// Mean μ, metres.
    pub mean: Vec3,
    /// Eigenvector rotation R (columns).
    pub rotation: Mat3,
    /// Principal scales d (square roots of the eigenvalues), metres.
    pub sigmas: Vec3,
    /// Support points N.
    pub count: u32,
    /// Colour.
    pub colour: [u8; 3],
    /// Instance id a (0: none).
    pub instance: u16,
    /// Category label ℓ.
    pub class: u16,
    /// Confidence s.
    pub score: f32,
    /// Mask support ratio ρ.
    pub support_ratio: f32,
}

/// One primitive of the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Primitive<'a> {
    /// A bounded plane.
    Plane(MapPlane<'a>),
    /// An object superquadric.
    Sq(MapSq),
    /// A Gaussian.
    Gmm(MapGmm),
}

/// Spacing of superquadric surface samples, metres (docs/metrics.md).
pub const SQ_SAMPLE_SPACING: f32 = 0.03;
/// Most samples of one Gaussian.
pub const GMM_MAX_SAMPLES: u32 = 60;

impl MapPlane<'_> {
    /// One point per occupied cell, at its centre (equation 10).
    pub fn for_each_sample(&self, mut f: impl FnMut(Vec3)) {
        let (e1, e2) = (linalg::column(&self.rotation, 0), linalg::column(&self.rotation, 1));
        self.cells.for_each_set(|i, j| {
            let u = (self.cells.a0 as f32 + i as f32 + 0.5) * self.g_p;
            let v = (self.cells.b0 as f32 + j as f32 + 0.5) * self.g_p;
            f(linalg::add(self.centroid, linalg::add(linalg::scale(e1, u), linalg::scale(e2, v))));
        });
    }
}

impl MapSq {
    /// The shape `sq` alone (no instance, class, score or track; a whole view), for sampling its surface.
    pub fn of_shape(sq: Superquadric) -> MapSq {
        MapSq { sq, instance: 0, class: 0, score: 0.0, track: 0, partial: false }
    }

    /// Surface points about [`SQ_SAMPLE_SPACING`] apart, kept where the outward normal faces the camera at the
    /// origin (a superquadric with ε ≤ 2 is convex: this is its visible side). The grid is that of
    /// [`MapSq::for_each_surface_sample`].
    pub fn for_each_sample(&self, mut f: impl FnMut(Vec3)) {
        self.for_each_sample_spaced(SQ_SAMPLE_SPACING, |p, _| f(p))
    }

    /// [`MapSq::for_each_sample`] with grid points about `spacing` metres apart (at most 64 per face side):
    /// `f(p, cos)` with the camera-frame point p and the cosine (0, 1] of the angle between its outward normal
    /// and the direction back to the camera (1 for a face seen head-on, near 0 at grazing view).
    pub fn for_each_sample_spaced(&self, spacing: f32, mut f: impl FnMut(Vec3, f32)) {
        // The normals of a batch of grid points are taken at once (the batched powers).
        self.for_each_grid_batch(spacing, |batch, n| {
            let normals = self.sq.normals_at_local_n(&batch.map(|g| g.local));
            for (g, normal) in batch.iter().zip(normals).take(n).filter(|(g, _)| g.finite) {
                let facing = -linalg::dot(normal, g.camera);
                if facing > 0.0 {
                    f(g.camera, facing / linalg::norm(g.camera).max(f32::MIN_POSITIVE));
                }
            }
        });
    }

    /// Every surface point of the sample grid, about [`SQ_SAMPLE_SPACING`] apart, whichever way its normal
    /// faces (camera frame, metres): the whole closed surface, for metrics that judge the parts the camera
    /// cannot see. The grid is laid on the six faces of the bounding box [−a, a] and each grid point is moved
    /// along its ray from the centre onto the surface (F is homogeneous: p·F(p)^(−ε1/2)); unlike the (η, ω)
    /// parametrisation this stays even on box-like shapes, whose parametric samples crowd at the edges.
    pub fn for_each_surface_sample(&self, f: impl FnMut(Vec3)) {
        self.for_each_surface_sample_spaced(SQ_SAMPLE_SPACING, f);
    }

    /// [`MapSq::for_each_surface_sample`] with grid points about `spacing` metres apart.
    pub fn for_each_surface_sample_spaced(&self, spacing: f32, mut f: impl FnMut(Vec3)) {
        self.for_each_grid_batch(spacing, |batch, n| {
            for g in batch.iter().take(n).filter(|g| g.finite) {
                f(g.camera);
            }
        });
    }

    /// The surface grid of [`MapSq::for_each_surface_sample`] with points about `spacing` metres apart, in grid
    /// order, [`LANES`] at a time (the batched powers): `f(batch, n)` with the first `n` entries of `batch` new.
    fn for_each_grid_batch(&self, spacing: f32, mut f: impl FnMut(&[GridPoint; LANES], usize)) {
        let [a0, a1, a2] = self.sq.scales;
        let count = |len: f32| (libm::ceilf(2.0 * len / spacing) as usize).clamp(1, 64);
        // (face axis w, in-face axes u, v) with their half-lengths; `place` puts (w, u, v) back in x, y, z order.
        type Place = fn(f32, f32, f32) -> Vec3;
        let faces: [(f32, f32, f32, Place); 3] =
            [(a0, a1, a2, |w, u, v| [w, u, v]), (a1, a2, a0, |w, u, v| [v, w, u]), (a2, a0, a1, |w, u, v| [u, v, w])];
        // Grid points go onto the surface a batch at a time (F from the batched powers).
        let mut batch = [[0.0f32; 3]; LANES];
        let mut n = 0;
        let mut project = |batch: &[Vec3; LANES], n: usize| {
            let mut on_surface = [GridPoint::default(); LANES];
            for ((g, &l), big_f) in on_surface.iter_mut().zip(batch).zip(self.sq.implicit_n(batch)).take(n) {
                let local = linalg::scale(l, libm::powf(big_f, -0.5 * self.sq.eps[0]));
                let camera = linalg::add(self.sq.centre, linalg::mat_vec(&self.sq.rotation, local));
                *g = GridPoint { local, camera, finite: camera.iter().all(|x| x.is_finite()) };
            }
            f(&on_surface, n);
        };
        for (aw, au, av, place) in faces {
            let (nu, nv) = (count(au), count(av));
            for side in [-1.0f32, 1.0] {
                for i in 0..nu {
                    for j in 0..nv {
                        let u = -au + (2 * i + 1) as f32 * au / nu as f32;
                        let v = -av + (2 * j + 1) as f32 * av / nv as f32;
                        if let Some(slot) = batch.get_mut(n) {
                            *slot = place(side * aw, u, v);
                            n += 1;
                        }
                        if n == LANES {
                            project(&batch, n);
                            n = 0;
                        }
                    }
                }
            }
        }
        project(&batch, n);
    }
}

/// A point of a superquadric's sample grid on its surface ([`MapSq::for_each_surface_sample`]).
#[derive(Debug, Clone, Copy, Default)]
struct GridPoint {
    /// Local coordinates, metres.
    local: Vec3,
    /// Camera-frame position, metres.
    camera: Vec3,
    /// Whether `camera` is finite (only such points are samples).
    finite: bool,
}

impl MapGmm {
    /// Deterministic points along the three eigen-axes within Mahalanobis distance 2, about one per 30 support
    /// points (at least 2 per axis, at most [`GMM_MAX_SAMPLES`] in all), plus the mean.
    pub fn for_each_sample(&self, mut f: impl FnMut(Vec3)) {
        f(self.mean);
        let per_axis = (self.count / 90).clamp(2, GMM_MAX_SAMPLES / 3);
        for k in 0..3 {
            let axis = linalg::column(&self.rotation, k);
            let sigma = self.sigmas.get(k).copied().unwrap_or(0.0);
            for s in 0..per_axis {
                // t in [−2, 2] without 0 (the mean is already out): ±2·(s + 1)/per_axis alternating sides.
                let t = 2.0 * (s / 2 + 1) as f32 / per_axis.div_ceil(2) as f32 * if s % 2 == 0 { 1.0 } else { -1.0 };
                f(linalg::add(self.mean, linalg::scale(axis, t * sigma)));
            }
        }
    }
}

impl<'a> Primitive<'a> {
    /// This primitive moved by the rigid transform p ↦ R·p + t (`rotation` R orthonormal, `translation` t in
    /// metres): centroid, centre or mean and rotation move; cells, scales and attributes stay.
    pub fn moved(&self, rotation: &Mat3, translation: Vec3) -> Primitive<'a> {
        let point = |p: Vec3| linalg::add(linalg::mat_vec(rotation, p), translation);
        match *self {
            Primitive::Plane(p) => Primitive::Plane(MapPlane {
                centroid: point(p.centroid),
                rotation: linalg::mat_mul(rotation, &p.rotation),
                ..p
            }),
            Primitive::Sq(s) => Primitive::Sq(MapSq {
                sq: Superquadric {
                    centre: point(s.sq.centre),
                    rotation: linalg::mat_mul(rotation, &s.sq.rotation),
                    ..s.sq
                },
                ..s
            }),
            Primitive::Gmm(g) => {
                Primitive::Gmm(MapGmm { mean: point(g.mean), rotation: linalg::mat_mul(rotation, &g.rotation), ..g })
            }
        }
    }

    /// The reconstruction samples of this primitive (docs/metrics.md), camera frame, metres.
    pub fn for_each_sample(&self, f: impl FnMut(Vec3)) {
        match self {
            Primitive::Plane(p) => p.for_each_sample(f),
            Primitive::Sq(s) => s.for_each_sample(f),
            Primitive::Gmm(g) => g.for_each_sample(f),
        }
    }

    /// Every surface sample of this primitive, camera frame, metres: a superquadric's whole closed surface
    /// ([`MapSq::for_each_surface_sample`]); planes and Gaussians as [`Primitive::for_each_sample`].
    pub fn for_each_surface_sample(&self, f: impl FnMut(Vec3)) {
        match self {
            Primitive::Sq(s) => s.for_each_surface_sample(f),
            Primitive::Plane(_) | Primitive::Gmm(_) => self.for_each_sample(f),
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use std::vec::Vec;

    fn sq(centre: Vec3, scales: Vec3, eps: [f32; 2]) -> MapSq {
        let sq = Superquadric { scales, eps, centre, rotation: linalg::IDENTITY };
        MapSq { sq, instance: 1, class: 0, score: 1.0, track: 0, partial: false }
    }

    #[test]
    fn surface_samples_cover_the_whole_shape_and_include_the_camera_facing_ones() {
        // A sphere of radius 0.1 m, 1 m in front of the camera: every surface sample lies on the sphere, about
        // half face the camera, and those are exactly the reconstruction samples (same grid, same order).
        let s = sq([0.0, 0.0, 1.0], [0.1, 0.1, 0.1], [1.0, 1.0]);
        let (mut all, mut visible) = (Vec::new(), Vec::new());
        s.for_each_surface_sample(|p| all.push(p));
        s.for_each_sample(|p| visible.push(p));
        for p in &all {
            let r = linalg::norm(linalg::sub(*p, s.sq.centre));
            assert!((r - 0.1).abs() < 1e-4, "sample off the sphere: r = {r}");
        }
        let facing: Vec<Vec3> =
            all.iter().copied().filter(|p| linalg::dot(linalg::sub(*p, s.sq.centre), *p) < 0.0).collect();
        assert_eq!(facing, visible);
        let (n, m) = (visible.len(), all.len());
        assert!(n * 5 > m * 2 && n * 5 < m * 3, "{n} of {m} samples face the camera");
        // The far half lies behind the centre: samples up to z = 1.1 m.
        let zmax = all.iter().map(|p| p[2]).fold(f32::MIN, f32::max);
        assert!((zmax - 1.1).abs() < 0.01, "far side reaches {zmax}");
        // Through `Primitive`: the superquadric's whole surface; a Gaussian's samples unchanged.
        let mut n = 0;
        Primitive::Sq(s).for_each_surface_sample(|_| n += 1);
        assert_eq!(n, all.len());
        let g = MapGmm {
            mean: [0.0, 0.0, 2.0],
            rotation: linalg::IDENTITY,
            sigmas: [0.05, 0.02, 0.003],
            count: 300,
            colour: [0; 3],
            instance: 0,
            class: 0,
            score: 0.0,
            support_ratio: 0.0,
        };
        let (mut a, mut b) = (Vec::new(), Vec::new());
        Primitive::Gmm(g).for_each_surface_sample(|p| a.push(p));
        Primitive::Gmm(g).for_each_sample(|p| b.push(p));
        assert_eq!(a, b);
    }
}
