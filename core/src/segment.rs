//! A geometric instance segmenter: class-agnostic instance masks from depth alone, for robots without a
//! neural front end. It produces the same [`MaskSet`](crate::MaskSet) as file masks, into caller-owned buffers
//! (an id image and an instance list), before the pipeline runs: the masks then go through the pipeline as file
//! masks do (voxels in mask slots, annotation), see [`crate::Mapper::process_segmented`].
//!
//! 1. **Supporting planes**: the image is cut in cells of `step × step` pixels (160 across: 4 px at
//!    640 × 480, the same angular size at 0.5 m as at 4 m). A cell's point is its centre pixel back-projected
//!    at the mean of its block's depths on the centre's surface, its normal comes from the neighbouring cells'
//!    points. Neighbouring cells with no depth jump between them (3 cell spacings + the depth tolerance) and
//!    normals within 10° form coplanar components; one that is flat (smallest σ ≤ 0.2 × the middle one) and
//!    wide (largest σ ≥ `seg_structure_sigma` = 10 cm) is a plane, and grows over the linked cells within the
//!    depth tolerance of its least-squares fit with normals within 25° of it.
//! 2. **Objects by local convexity** (the LCCP idea of Stein et al., CVPR 2014, on the depth image as an
//!    organized cloud): two neighbouring cells, both on planes or both off them, join when no depth jump
//!    separates them and their boundary is convex ((n_a − n_b)·d̂ ≥ 0.2: two faces of a box, a can's rim) or
//!    nearly flat (normals within `seg_concave_tolerance_deg`); a concave boundary (an object standing on a
//!    table, two objects touching) separates them. A plane joins a component it meets along a boundary whose
//!    links are mostly convex (at least 3): it is that object's face (a tall box's front, a cabinet's door); an
//!    object resting on a plane meets it along a concave crease, where a few links reading convex do not glue
//!    it to the table. A component covering at least `seg_min_points` sampled points' worth of pixels is an
//!    instance (label `class`, score `seg_score`) unless it is structure: a box diagonal above
//!    `seg_max_extent`, or flat and wide as above (a table top or wall seen between objects).
//!    An object seen over another's rim is that object's inside (a mug's inner wall and bottom, cut from its
//!    outside by the rim's bright edge, which returns no depth): two objects whose cells face each other across
//!    gaps of cells without depth, at the outer one's top, are one when the inner one lies within the outer
//!    one's extent along the largest plane's normal, across the view and (as deep as it is wide) along it.
//! 3. **Masks**: a cell of a component too small to be anything takes the instance of its neighbours on the
//!    same surface when at least 3 of its 4 name it and none another (a hole of noisy normals inside an object
//!    would leave its points to the table's Gaussians). Within 1 cm of an instance's cells (close range, where
//!    a cell spans a few millimetres) one neighbour suffices when the cell continues its surface and lies on no
//!    supporting plane beside it: the band of mixed normals along an object's crease with its table, several
//!    cells wide there. A cell whose centre pixel is a depth hole (an object's
//!    edge, a rim) has no point of its own: next to an object's cell it takes the instance of the neighbour on
//!    whose tangent plane its first valid pixel nearest the centre lies (or none, when that is a plane's or
//!    background cell). Every pixel with a valid depth on its cell's surface takes the cell's instance.
//!
//! Each cell's data is computed once and read by every later step: its point (back-projected as the block is
//! averaged), its normal, and a link word that says which neighbours lie on its surface and how it
//! meets its right and lower ones (coplanar, convex, one object's surface); the plane step, the LCCP joins, the
//! plane–object boundaries, the plane growth and the mask fill read bits instead of recomputing the geometry.
//!
//! No per-cell pool: the union-find parents, the cells' quantised normals, colours (with each plane cell's plane
//! in the colour word's spare bits), link words and points live in the id image before the masks are written
//! over them (13 u16 per cell, and one to align the points; a grid of 4-pixel cells has 16 pixels' ids per cell:
//! the grid is coarsened for an image without room for them); the coplanar components' parents and
//! then the component counts live in the scratch.
//!
//! Measured against ground-truth ids (recall / precision at IoU ≥ 0.5) and the trade-offs tried: see
//! docs/pipeline.md, "The geometric segmenter".

use crate::frame::Frame;
use crate::linalg::{self, Vec3};
use crate::masks::Instance;
use crate::params::Params;
use crate::union_find;
use wide::{f32x4, i32x4, u16x8};

/// Cells across the image width (the cell side is the width over this, at least 2 pixels).
const GRID_COLUMNS: u16 = 160;
/// Least (n_a − n_b)·d̂ of a convex boundary (d̂ the unit vector from b's point to a's): below it a boundary is
/// too faint to tell from noise and counts as concave unless nearly flat.
const CONVEX_MIN: f32 = 0.2;
/// Largest difference of a colour channel (0–255) between the mean colours of two cells that still counts as one
/// surface across a nearly flat, slightly concave boundary.
const COLOUR_STEP: i32 = 48;
/// Most components large enough to be an object that one segmentation considers.
const MAX_CANDIDATES: usize = 96;
/// A component is flat when its smallest standard deviation is at most this share of the middle one.
const FLAT_RATIO: f32 = 0.2;

/// Largest depth difference between neighbouring `step`-pixel cells (or a pixel and its cell) at depth `z` on
/// one surface, metres: three cell spacings (a surface inclined up to ~70° from the view) plus the depth
/// tolerance.
fn surface_jump(frame: &Frame<'_>, params: &Params, step: usize, z: f32) -> f32 {
    let spacing = step as f32 * z / frame.intrinsics.fx.max(1e-3);
    3.0 * spacing + params.depth_tolerance(z)
}

/// [`surface_jump`] at raw depth `centre`, in raw depth units: how far a pixel's depth may lie from its cell's
/// reference pixel and still be on its surface (the block means and the masks).
fn raw_jump(frame: &Frame<'_>, params: &Params, step: usize, centre: u16) -> u32 {
    (surface_jump(frame, params, step, frame.metres(centre)) * frame.depth_scale) as u32
}

/// A component that may be an object: its cells' moments and box (camera frame, metres), and its instance id.
struct Candidate {
    moments: linalg::Moments,
    lo: Vec3,
    hi: Vec3,
    instance: u16,
}

/// The cells of the segmenter: `step × step` pixel blocks, each represented by the point of its centre pixel.
struct Grid<'f> {
    frame: &'f Frame<'f>,
    params: &'f Params,
    step: usize,
    cols: usize,
    rows: usize,
    /// Each cell's point (camera frame, metres; all 0 without one), coordinate by coordinate (the x, y and z of
    /// every cell, so that neighbouring cells' coordinates are side by side for [`Grid::surfels`]' lanes): see
    /// [`Grid::fill`].
    points: [&'f [f32]; 3],
    /// Each cell's unit normal × 32767 as an i16 bit pattern (all 0 = none), component by component, once
    /// computed.
    normals: [&'f [u16]; 3],
    /// Each cell's link word ([`link`]), once computed.
    links: &'f [u16],
}

impl<'f> Grid<'f> {
    /// The cell side (pixels) and the columns and rows of the grid of `frame` with at most `capacity` cells (and
    /// at most `u16::MAX`).
    fn layout(frame: &Frame<'_>, capacity: usize) -> (usize, usize, usize) {
        let (w, h) = (frame.width as usize, frame.height as usize);
        let mut step = (w / GRID_COLUMNS as usize).max(2);
        while w.div_ceil(step) * h.div_ceil(step) > capacity.min(u16::MAX as usize) && step < w.max(h) {
            step += 1;
        }
        (step, w.div_ceil(step), h.div_ceil(step))
    }

    /// Writes each cell's point into `points` (camera frame, metres; all 0 without one): its centre pixel
    /// back-projected at the mean of the valid depths of its block within the jump tolerance of its centre
    /// pixel's, which must be valid (a cell on a depth edge keeps the centre's surface; the mean of 16 pixels has
    /// a quarter of their noise, so the normals are steady on 4-pixel cells); and its mean colour into `colours`
    /// (r | g << 8, b).
    #[inline(never)]
    fn fill(
        frame: &Frame<'_>,
        params: &Params,
        (step, cols, rows): (usize, usize, usize),
        points: [&mut [f32]; 3],
        colours: &mut [u16],
    ) {
        let (w, h) = (frame.width as usize, frame.height as usize);
        if cols == 0 || w == 0 {
            return;
        }
        let (lo, hi) = frame.raw_range(params);
        let [xs, ys, zs] = points;
        let point_rows = xs.chunks_mut(cols).zip(ys.chunks_mut(cols)).zip(zs.chunks_mut(cols));
        for (cy, (((x_row, y_row), z_row), colour_row)) in point_rows.zip(colours.chunks_mut(2 * cols)).enumerate() {
            if cy >= rows {
                return;
            }
            let (v0, vc, v1) = block_span(cy, step, h);
            let block = frame.depth.get(v0 * w..v1 * w).unwrap_or(&[]);
            let centre_row = frame.depth.get(vc * w..vc * w + w).unwrap_or(&[]);
            let y0 = vc.saturating_sub(1);
            let above = frame.colour.get(3 * y0 * w..3 * y0 * w + 3 * w).unwrap_or(&[]);
            let middle = frame.colour.get(3 * vc * w..3 * vc * w + 3 * w).unwrap_or(&[]);
            // [`FILL_RUN`] cells at a time, in three loops whose iterations do not wait for each other (each step
            // has a division): the centres' tolerances, the blocks' means and colours, the back-projections.
            let point_runs = x_row.chunks_mut(FILL_RUN).zip(y_row.chunks_mut(FILL_RUN)).zip(z_row.chunks_mut(FILL_RUN));
            for (run, (((xs, ys), zs), rgbs)) in point_runs.zip(colour_row.chunks_mut(2 * FILL_RUN)).enumerate() {
                let len = zs.len();
                let x0 = run * FILL_RUN;
                let mut tolerances = [0u32; FILL_RUN];
                for (k, t) in tolerances.iter_mut().enumerate().take(len) {
                    let (_, uc, _) = block_span(x0 + k, step, w);
                    let centre = centre_row.get(uc).copied().unwrap_or(0);
                    *t = raw_jump(frame, params, step, centre);
                }
                // Each cell's mean raw depth, 0 when its centre pixel is not valid.
                let mut means = [0u16; FILL_RUN];
                // The usual layout (4-pixel cells, the run's four pixel rows and columns all in the image) reads
                // the run's rows as slices of four pixels, without a range per cell and row; the same sums.
                let (px0, px1) = (x0 * step, (x0 + len) * step);
                if step == 4 && v1 - v0 == 4 && px1 <= w {
                    let rows: [&[u16]; 4] = core::array::from_fn(|r| {
                        frame.depth.get((v0 + r) * w + px0..(v0 + r) * w + px1).unwrap_or(&[])
                    });
                    let colour_rows = [above, middle].map(|row| row.get(3 * px0..3 * px1).unwrap_or(&[]));
                    block_means_4(rows, colour_rows, (lo, hi), &tolerances, &mut means, rgbs);
                } else {
                    for (k, (mean, rgb)) in means.iter_mut().zip(rgbs.chunks_exact_mut(2)).enumerate() {
                        let (u0, uc, u1) = block_span(x0 + k, step, w);
                        let Some(centre) = centre_row.get(uc).copied().filter(|r| (lo..=hi).contains(r)) else {
                            rgb.fill(0);
                            continue;
                        };
                        let near = near_interval((lo, hi), centre, tolerances.get(k).copied().unwrap_or(0));
                        let (mut sum, mut n) = (0u32, 0u32);
                        for row in block.chunks_exact(w) {
                            let row = row.get(u0..u1).unwrap_or(&[]);
                            let (s, k) = match <&[u16; 4]>::try_from(row) {
                                // The usual 4-pixel row, unrolled.
                                Ok(four) => sum_near(four, near),
                                Err(_) => sum_near(row, near),
                            };
                            sum += s;
                            n += k;
                        }
                        // n ≥ 1 (the centre is valid), so the mean is in range (and not 0: the centre is in range).
                        *mean = (sum / n.max(1)) as u16;
                        // The pixels left of and at the centre column (uc ≥ 1: a cell is at least 2 pixels wide).
                        let pair = 3 * uc.saturating_sub(1)..3 * uc + 3;
                        let pixels = [above.get(pair.clone()).unwrap_or(&[]), middle.get(pair).unwrap_or(&[])];
                        if let [lo_half, hi_half] = rgb {
                            [*lo_half, *hi_half] = colour_words(pixels);
                        }
                    }
                }
                let points = xs.iter_mut().zip(ys.iter_mut()).zip(zs.iter_mut());
                for (k, (((x, y), z), &mean)) in points.zip(&means).enumerate() {
                    [*x, *y, *z] = if mean == 0 { [0.0; 3] } else { cell_point((step, x0 + k, cy), frame, mean) };
                }
            }
        }
    }

    fn index(&self, cx: usize, cy: usize) -> usize {
        cy * self.cols + cx
    }

    /// The point of cell (cx, cy), camera frame; `None` without one.
    #[inline]
    fn point_at(&self, cx: usize, cy: usize) -> Option<Vec3> {
        if cx >= self.cols || cy >= self.rows {
            return None;
        }
        self.point(cy * self.cols + cx)
    }

    /// [`Grid::point_at`] of cell index `i`.
    #[inline]
    fn point(&self, i: usize) -> Option<Vec3> {
        // A cell with a point has z ≥ `depth_min` > 0.
        let [xs, ys, zs] = self.points;
        let z = zs.get(i).copied().filter(|&z| z != 0.0)?;
        Some([xs.get(i).copied()?, ys.get(i).copied()?, z])
    }

    /// [`surface_jump`] on this grid.
    fn jump(&self, z: f32) -> f32 {
        surface_jump(self.frame, self.params, self.step, z)
    }

    /// The point and unit normal of cell (cx, cy) ([`Grid::surfels`]), from the normals computed once per cell
    /// (quantised to 1/32767).
    fn cached_surfel(&self, cx: usize, cy: usize) -> Option<(Vec3, Vec3)> {
        let p = self.point_at(cx, cy)?;
        let i = self.index(cx, cy);
        let [a, b, c] = self.normals;
        Some((p, dequantised([*a.get(i)?, *b.get(i)?, *c.get(i)?])?))
    }

    /// Writes each cell's unit normal (facing the camera, quantised to 1/32767; all 0 = none) into `normals` and
    /// its [`link::LEFT`]..[`link::DOWN`] bits (its neighbours on its surface: no depth jump at its depth) into
    /// `links`. The normal comes from the neighbouring cells' points on either side along each axis (the cell's
    /// own point stands in for a neighbour that is missing or across a depth jump); a cell without a point, or
    /// without a neighbour on its surface along an axis, has none. [`SURFEL_LANES`] cells at a time, every
    /// test a lane mask: the arithmetic runs side by side, without a branch per cell.
    #[inline(never)]
    #[allow(clippy::indexing_slicing)] // every index is a lane (k < SURFEL_LANES: `from_fn`'s or a loop's over the lanes), a coordinate (c < 3) or a side (< 4) of a fixed-size array; none comes from the input
    fn surfels(&self, normals: [&mut [u16]; 3], links: &mut [u16]) {
        let cols = self.cols;
        // Coordinate c of row cy's cells (empty beyond the grid).
        let row = |c: usize, cy: Option<usize>| -> &[f32] {
            let plane = self.points.get(c).copied().unwrap_or(&[]);
            cy.and_then(|cy| plane.get(cy * cols..(cy + 1) * cols)).unwrap_or(&[])
        };
        let [nx, ny, nz] = normals;
        for cy in 0..self.rows {
            let rows = |cy: Option<usize>| -> [&[f32]; 3] { core::array::from_fn(|c| row(c, cy)) };
            let (here, above, below) = (rows(Some(cy)), rows(cy.checked_sub(1)), rows(Some(cy + 1)));
            for x0 in (0..cols).step_by(SURFEL_LANES) {
                // The cells' points and their left, right, upper and lower neighbours' (all 0 where there is
                // none), coordinate by coordinate. Inside the grid (the batch's cells, their left and right
                // neighbours and the rows above and below them all there) each side's lanes are one read; at the
                // grid's edges a lane beyond it is 0.
                let inside = x0 >= 1 && x0 + SURFEL_LANES < cols && cy >= 1 && cy + 1 < self.rows;
                let direct = |row: &[f32], start: usize| -> f32x4 {
                    row.get(start..start + SURFEL_LANES)
                        .and_then(|s| <[f32; SURFEL_LANES]>::try_from(s).ok())
                        .map_or(f32x4::ZERO, f32x4::from)
                };
                let (p, side): ([f32x4; 3], [[f32x4; 3]; 4]) = if inside {
                    (
                        core::array::from_fn(|c| direct(here[c], x0)),
                        [
                            core::array::from_fn(|c| direct(here[c], x0 - 1)),
                            core::array::from_fn(|c| direct(here[c], x0 + 1)),
                            core::array::from_fn(|c| direct(above[c], x0)),
                            core::array::from_fn(|c| direct(below[c], x0)),
                        ],
                    )
                } else {
                    let load = |row: &[f32], first: usize, before: bool| {
                        f32x4::from(lanes::<f32, SURFEL_LANES>(row, first, before))
                    };
                    (
                        core::array::from_fn(|c| load(here[c], x0, false)),
                        [
                            core::array::from_fn(|c| load(here[c], x0, true)),
                            core::array::from_fn(|c| load(here[c], x0 + 1, false)),
                            core::array::from_fn(|c| load(above[c], x0, false)),
                            core::array::from_fn(|c| load(below[c], x0, false)),
                        ],
                    )
                };
                let jump = f32x4::from(p[2].to_array().map(|z| self.jump(z)));
                let (zero, z) = (f32x4::ZERO, p[2]);
                let has_point = z.simd_ne(zero);
                // A neighbour lies on the cell's surface when it has a point within the jump of the cell's depth.
                let on: [f32x4; 4] = core::array::from_fn(|s| {
                    let q = side[s][2];
                    has_point & q.simd_ne(zero) & (q - z).abs().simd_le(jump)
                });
                // Along an axis: ahead − behind, the cell's own point standing in for a missing one.
                let along = |ahead: usize, behind: usize| -> [f32x4; 3] {
                    core::array::from_fn(|c| {
                        on[ahead].select(side[ahead][c], p[c]) - on[behind].select(side[behind][c], p[c])
                    })
                };
                let (a, b) = (along(1, 0), along(3, 2));
                let n = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
                let dot = |u: &[f32x4; 3], v: &[f32x4; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
                // (libm's square root lane by lane: correctly rounded on the host and the Cortex-M7 alike.)
                let length = f32x4::from(dot(&n, &n).to_array().map(linalg::sqrt));
                // linalg::normalize_or(n, 0), then turned towards the camera.
                let inverse = f32x4::ONE / length;
                let long = length.simd_gt(f32x4::splat(1e-12));
                let unit = n.map(|n| long.select(n * inverse, zero));
                let flip = dot(&unit, &p).simd_gt(zero).select(f32x4::splat(-1.0), f32x4::ONE);
                let unit = unit.map(|u| u * flip);
                let valid = (on[0] | on[1]) & (on[2] | on[3]) & dot(&unit, &unit).simd_gt(f32x4::splat(0.5));
                let bit = |mask: f32x4, bit: u16| bytemuck::cast::<f32x4, i32x4>(mask) & i32x4::splat(i32::from(bit));
                let [left, right, up, down] = on;
                let bits = bit(left, link::LEFT) | bit(right, link::RIGHT) | bit(up, link::UP) | bit(down, link::DOWN);
                let first = cy * cols + x0;
                let len = SURFEL_LANES.min(cols - x0);
                if let Some(out) = links.get_mut(first..first + len) {
                    for (out, &b) in out.iter_mut().zip(bits.as_array()) {
                        *out = b as u16;
                    }
                }
                for (c, plane) in [&mut *nx, &mut *ny, &mut *nz].into_iter().enumerate() {
                    let q = quantise_units(valid.select(unit[c], zero)).to_array();
                    if let Some(out) = plane.get_mut(first..first + len) {
                        for (out, &q) in out.iter_mut().zip(&q) {
                            *out = q as i16 as u16;
                        }
                    }
                }
            }
        }
    }

    /// Whether cell `i`'s `k`-th neighbour ([`four_neighbours`] order) lies on its surface (no depth jump at the
    /// cell's depth); false before the links are computed.
    fn on_surface(&self, i: usize, k: usize) -> bool {
        self.links.get(i).is_some_and(|&b| b & (link::LEFT << k) != 0)
    }
}

/// The bits of a cell's link word: which of its four neighbours lie on its surface (no depth jump at its depth),
/// and, for the links to its right and lower neighbours when both cells have a normal, how their surfaces meet.
/// Computed once per cell, read by every later step.
mod link {
    /// The left neighbour lies on the cell's surface (bit k is [`super::four_neighbours`]' k-th).
    pub const LEFT: u16 = 1 << 0;
    /// The right neighbour lies on the cell's surface.
    pub const RIGHT: u16 = 1 << 1;
    /// The upper neighbour lies on the cell's surface.
    pub const UP: u16 = 1 << 2;
    /// The lower neighbour lies on the cell's surface.
    pub const DOWN: u16 = 1 << 3;
    /// The right neighbour lies on the surface and both have a normal (shifted by [`DOWN_SHIFT`]: the lower one).
    pub const NORMALS: u16 = 1 << 4;
    /// ... and their normals are within [`super::PLANE_ANGLE_DEG`]: coplanar.
    pub const COPLANAR: u16 = 1 << 5;
    /// ... and their boundary is convex ((n_a − n_b)·d̂ ≥ [`super::CONVEX_MIN`]).
    pub const CONVEX: u16 = 1 << 6;
    /// ... and they are one object's surface: convex, or nearly flat and not a contact of two colours.
    pub const JOINS: u16 = 1 << 7;
    /// Shift of the lower link's bits over the right one's.
    pub const DOWN_SHIFT: u16 = 4;
}

/// A cell's unit normal from its three quantised components (× 32767, as i16 bit patterns; [`Grid::surfels`]);
/// `None` for all 0 (no normal).
#[inline]
fn dequantised(q: [u16; 3]) -> Option<Vec3> {
    let n = q.map(|x| crate::supervoxel::dequantise_unit(x as i16));
    (n != [0.0; 3]).then_some(n)
}

/// The values of cells `first..first + L` of `row` (`first − 1..first − 1 + L` when `before`: the cells' left
/// neighbours), the default (0) for a cell beyond the row.
#[inline(always)]
fn lanes<T: Copy + Default, const L: usize>(row: &[T], first: usize, before: bool) -> [T; L] {
    let start = first.wrapping_sub(usize::from(before));
    match row.get(start..start.wrapping_add(L)).map(<&[T; L]>::try_from) {
        Some(Ok(window)) => *window,
        _ => core::array::from_fn(|k| row.get(start.wrapping_add(k)).copied().unwrap_or_default()),
    }
}

/// [`crate::supervoxel::quantise_unit`] of four unit-vector components at once: the same rounding (half away
/// from zero), the same values for every number (a NaN lane, which the surfels never hold, would give −32767
/// here and 0 there).
#[inline(always)]
fn quantise_units(x: f32x4) -> i32x4 {
    let y = x.max(f32x4::splat(-1.0)).min(f32x4::ONE) * f32x4::splat(32767.0);
    // |y| ≤ 32767: the conversion truncates towards zero, and y minus its integer part is exact.
    let t = y.trunc_int();
    let frac = y - t.round_float();
    // A comparison's lane is all ones (−1 as an integer) where it holds.
    let up: i32x4 = bytemuck::cast(frac.simd_ge(f32x4::splat(0.5)));
    let down: i32x4 = bytemuck::cast(frac.simd_le(f32x4::splat(-0.5)));
    t - up + down
}

/// The centre pixel of cell (cx, cy) of a grid of `step`-pixel cells back-projected at raw depth `raw`, camera
/// frame (metres).
fn cell_point((step, cx, cy): (usize, usize, usize), frame: &Frame<'_>, raw: u16) -> Vec3 {
    let (u, v) = ((cx * step) as f32 + 0.5 * step as f32, (cy * step) as f32 + 0.5 * step as f32);
    frame.intrinsics.unproject(u - 0.5, v - 0.5, frame.metres(raw))
}

/// The raw depths that lie in the raw range (`lo..=hi`) within `tolerance` of `centre`, as the first and the
/// span (`a..=a + span`; span −1 when there are none): a pixel `r` is on the cell's surface when
/// `r.wrapping_sub(a) <= span` ([`is_near`], one comparison).
fn near_interval((lo, hi): (u16, u16), centre: u16, tolerance: u32) -> (u16, i32) {
    let a = (centre as u32).saturating_sub(tolerance).max(lo as u32);
    let b = (centre as u32).saturating_add(tolerance).min(hi as u32);
    if a > b {
        NOWHERE
    } else {
        (a as u16, (b - a) as i32)
    }
}

/// The [`near_interval`] that holds no depth.
const NOWHERE: (u16, i32) = (0, -1);

/// Whether raw depth `r` lies in `near` ([`near_interval`]).
#[inline(always)]
fn is_near(r: u16, (a, span): (u16, i32)) -> bool {
    i32::from(r.wrapping_sub(a)) <= span
}

/// The sum and count of the depths of `row` in `near` ([`near_interval`]), without a branch per pixel.
#[inline(always)]
fn sum_near(row: &[u16], near: (u16, i32)) -> (u32, u32) {
    let (mut sum, mut n) = (0u32, 0u32);
    for &r in row {
        let ok = is_near(r, near);
        sum += u32::from(ok) * r as u32;
        n += u32::from(ok);
    }
    (sum, n)
}

/// [`Grid::fill`]'s means and colours of a run of 4 × 4-pixel cells: `rows` are the run's four pixel rows (4
/// pixels per cell), `colour_rows` the colour rows above and at the centre row over the same columns; a cell's
/// centre pixel is its row 2, column 2, as [`block_span`] places it. The same sums, means and colours as the
/// general loop, with fewer instructions (when it came: 31.9 → 29.0 M per redkitchen frame for the whole segmenter;
/// its 16 depths now summed two rows per eight lanes).
#[inline(always)]
fn block_means_4(
    rows: [&[u16]; 4],
    colour_rows: [&[u8]; 2],
    (lo, hi): (u16, u16),
    tolerances: &[u32; FILL_RUN],
    means: &mut [u16; FILL_RUN],
    rgbs: &mut [u16],
) {
    let [r0, r1, r2, r3] = rows;
    let [above, middle] = colour_rows;
    let cells = r0.chunks_exact(4).zip(r1.chunks_exact(4)).zip(r2.chunks_exact(4)).zip(r3.chunks_exact(4));
    let colours = above.chunks_exact(12).zip(middle.chunks_exact(12));
    let outputs = means.iter_mut().zip(rgbs.chunks_exact_mut(2)).zip(tolerances);
    for (((((a, b), c), d), (top, mid)), ((mean, rgb), &tolerance)) in cells.zip(colours).zip(outputs) {
        let (Ok(a), Ok(b), Ok(c), Ok(d)) =
            (<&[u16; 4]>::try_from(a), <&[u16; 4]>::try_from(b), <&[u16; 4]>::try_from(c), <&[u16; 4]>::try_from(d))
        else {
            rgb.fill(0);
            continue;
        };
        let centre = c[2];
        if !(lo..=hi).contains(&centre) {
            rgb.fill(0);
            continue;
        }
        let near = near_interval((lo, hi), centre, tolerance);
        // The 16 depths as offsets from the interval's start: a depth on the surface has an offset within the
        // span (one unsigned comparison), and the offsets of the 16 sum in 16 bits while 16 × span does (else
        // the depths are summed).
        let (start, span) = near;
        let (mut sum, mut n) = (0u32, 0u32);
        if (0..=i32::from(u16::MAX / 16)).contains(&span) {
            // Two pixel rows per eight lanes.
            let (start, span) = (u16x8::splat(start), u16x8::splat(span as u16));
            let (mut offsets, mut count) = (u16x8::ZERO, u16x8::ZERO);
            for (upper, lower) in [(a, b), (c, d)] {
                let [u0, u1, u2, u3] = *upper;
                let [l0, l1, l2, l3] = *lower;
                let offset = u16x8::from([u0, u1, u2, u3, l0, l1, l2, l3]) - start;
                let ok = offset.simd_le(span);
                offsets += ok & offset;
                count += ok & u16x8::ONE;
            }
            n = u32::from(count.reduce_add());
            sum = u32::from(offsets.reduce_add()) + n * u32::from(near.0);
        } else {
            for row in [a, b, c, d] {
                let (s, k) = sum_near(row, near);
                sum += s;
                n += k;
            }
        }
        *mean = (sum / n.max(1)) as u16;
        // Pixels 1 and 2 of the cell (bytes 3..9), left of and at its centre column.
        if let [lo_half, hi_half] = rgb {
            [*lo_half, *hi_half] = colour_words([top.get(3..9).unwrap_or(&[]), mid.get(3..9).unwrap_or(&[])]);
        }
    }
}

/// A cell's colour words (r | g << 8, b) from the 2 × 2 pixels about its centre (a quarter of the sensor's
/// colour noise): `pixels` are the two pixels (6 bytes of RGB) left of and at the centre column in the row above
/// the centre and in the centre row.
fn colour_words(pixels: [&[u8]; 2]) -> [u16; 2] {
    let mut colour = [0u32; 3];
    for row in pixels {
        if let Some(&[r0, g0, b0, r1, g1, b1]) = row.get(..6) {
            colour = [
                colour[0] + r0 as u32 + r1 as u32,
                colour[1] + g0 as u32 + g1 as u32,
                colour[2] + b0 as u32 + b1 as u32,
            ];
        }
    }
    [(colour[0] / 4) as u16 | ((colour[1] / 4) as u16) << 8, (colour[2] / 4) as u16]
}

/// The pixels of the `k`-th block of `step` pixels along an image axis of `len` pixels: its first, its centre
/// (clamped to the image) and one past its last. A cell (cx, cy) of the grid is the block of columns
/// `block_span(cx, step, width)` and rows `block_span(cy, step, height)`.
fn block_span(k: usize, step: usize, len: usize) -> (usize, usize, usize) {
    let first = k * step;
    (first, (first + step / 2).min(len.saturating_sub(1)), (first + step).min(len))
}

/// The raw depth cell (cx, cy) of a grid of `step`-pixel cells is measured against: its centre pixel's when it
/// lies in the depth range (`lo..=hi`), else the first in-range pixel of its block nearest the centre (rings of
/// growing Chebyshev distance, each in raster order); `None` when the block has none.
#[inline(never)]
fn reference_depth(frame: &Frame<'_>, (lo, hi): (u16, u16), (cx, cy): (usize, usize), step: usize) -> Option<u16> {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let ((u0, uc, u1), (v0, vc, v1)) = (block_span(cx, step, w), block_span(cy, step, h));
    let valid = |u: usize, v: usize| frame.depth.get(v * w + u).copied().filter(|r| (lo..=hi).contains(r));
    if let Some(r) = valid(uc, vc) {
        return Some(r);
    }
    for ring in 1..step {
        for v in vc.saturating_sub(ring).max(v0)..(vc + ring + 1).min(v1) {
            for u in uc.saturating_sub(ring).max(u0)..(uc + ring + 1).min(u1) {
                if u.abs_diff(uc).max(v.abs_diff(vc)) == ring {
                    if let Some(r) = valid(u, v) {
                        return Some(r);
                    }
                }
            }
        }
    }
    None
}

/// Gives each holed cell — its centre pixel fell into a depth hole (an object's edge, a mug's rim), so it has no
/// point and took no part in the components — the instance (or none) of the neighbouring cell on whose surface
/// it lies: its reference point ([`reference_depth`] at the cell's centre pixel) within that neighbour's depth
/// jump and nearest to the neighbour's tangent plane, at most the depth tolerance from it. `instances` holds
/// each cell's instance (0: none) and is updated in a raster sweep that reads only cells with a point. Returns
/// the cells that took an instance. (Without it, 30–40 % of the cells left out of ycbv_0000's objects' masks
/// were holed cells, and their pixels went to the Gaussians of the table the objects stand on.)
#[inline(never)]
fn adopt_holed_cells(grid: &Grid<'_>, instances: &mut [u16]) -> u32 {
    let frame = grid.frame;
    let (lo, hi) = frame.raw_range(grid.params);
    let mut adopted = 0;
    for cy in 0..grid.rows {
        for cx in 0..grid.cols {
            let i = grid.index(cx, cy);
            // Only a holed cell next to an object's cell may take an instance.
            let next_to_object = || {
                four_neighbours(cx, cy).iter().any(|&(x, y)| {
                    x < grid.cols && y < grid.rows && instances.get(grid.index(x, y)).is_some_and(|&id| id != 0)
                })
            };
            if grid.point(i).is_some() || !next_to_object() {
                continue;
            }
            let Some(raw) = reference_depth(frame, (lo, hi), (cx, cy), grid.step) else {
                continue;
            };
            let p = cell_point((grid.step, cx, cy), frame, raw);
            let mut best: Option<(f32, u16)> = None;
            for (x, y) in four_neighbours(cx, cy) {
                let Some((q, normal)) = grid.cached_surfel(x, y) else { continue };
                if libm::fabsf(q[2] - p[2]) > grid.jump(q[2]) {
                    continue;
                }
                let off = linalg::plane_distance(p, q, normal);
                let Some(&instance) = instances.get(grid.index(x, y)) else { continue };
                if off <= grid.params.depth_tolerance(p[2]) && best.is_none_or(|(b, _)| off < b) {
                    best = Some((off, instance));
                }
            }
            if let (Some((_, instance)), Some(x)) = (best.filter(|&(_, id)| id != 0), instances.get_mut(i)) {
                *x = instance;
                adopted += 1;
            }
        }
    }
    adopted
}

/// The supporting planes of one segmentation: each one's centroid and unit normal (camera frame, metres).
type Planes = heapless::Vec<(Vec3, Vec3), MAX_PLANES>;

/// Cells of a row whose candidacy the plane growth of [`mark_planes`] tests at once (the bits of a word).
const GROW_CHUNK: usize = 64;
/// Cells per run of [`Grid::fill`]'s loops.
const FILL_RUN: usize = 32;
/// Cells per batch of [`Grid::surfels`]: the four lanes of an `f32x4`.
const SURFEL_LANES: usize = 4;

/// Bit of a cell's blue colour word (the colour takes 8 bits) that marks it as a supporting plane's cell.
const PLANE_FLAG: u16 = 0x8000;
/// Largest angle between the normals of two neighbouring cells of one plane, degrees.
const PLANE_ANGLE_DEG: f32 = 10.0;
/// Largest angle between a cell's normal and a plane's for the cell to be the plane's, degrees.
const PLANE_GROW_DEG: f32 = 25.0;
/// First bit of a plane cell's plane index in its blue colour word (below [`PLANE_FLAG`], above the colour).
const PLANE_SHIFT: u16 = 8;
/// Pairs of raster sweeps over which the planes grow over their noisy cells.
const PLANE_GROW_SWEEPS: usize = 1;
/// Most supporting planes one segmentation marks (their index takes the 7 bits below [`PLANE_FLAG`]).
const MAX_PLANES: usize = 8;

/// The surfels ([`Grid::cached_surfel`]) and colours of four neighbouring cells of a row, coordinate by
/// coordinate, for [`link_cells`].
struct Surfels {
    /// The points (metres; 0 without one).
    p: [f32x4; 3],
    /// The unit normals (0 without one).
    n: [f32x4; 3],
    /// The mean colours' red, green and blue (0–255).
    colour: [i32x4; 3],
    /// All ones in a lane whose cell has a point and a normal.
    ok: f32x4,
}

#[allow(clippy::indexing_slicing)] // every index is a lane (k < 4: `from_fn`'s) or a coordinate (c < 3) of a fixed-size array; none comes from the input
impl Surfels {
    /// Cells `first..first + 4` of a row's points and quantised normals (coordinate by coordinate) and colour
    /// words; none beyond the row.
    #[inline(always)]
    fn load(points: [&[f32]; 3], normals: [&[u16]; 3], colours: &[u16], first: usize) -> Self {
        Surfels::new(
            points.map(|row| lanes(row, first, false)),
            normals.map(|row| lanes(row, first, false)),
            lanes(colours, 2 * first, false),
        )
    }

    /// Four cells' surfels from their points, quantised normals and colour words.
    #[inline(always)]
    fn new(p: [[f32; 4]; 3], q: [[u16; 4]; 3], words: [u16; 8]) -> Self {
        let p = p.map(f32x4::from);
        let n = q.map(|q| f32x4::from(q.map(|q| crate::supervoxel::dequantise_unit(q as i16))));
        // A cell's two colour words as one lane, r | g << 8 | b << 16 (and the blue word's high byte above).
        let pairs = i32x4::from(core::array::from_fn(|k| i32::from(words[2 * k]) | i32::from(words[2 * k + 1]) << 16));
        let byte = i32x4::splat(0xff);
        let colour = [pairs & byte, (pairs >> 8) & byte, (pairs >> 16) & byte];
        let zero = f32x4::ZERO;
        let ok = p[2].simd_ne(zero) & (n[0].simd_ne(zero) | n[1].simd_ne(zero) | n[2].simd_ne(zero));
        Surfels { p, n, colour, ok }
    }

    /// How each lane's surfel meets `b`'s, as link bits at the right link's place (meaningful where both are
    /// `ok`), given the cosines of [`PLANE_ANGLE_DEG`] and of `seg_concave_tolerance_deg`: the LCCP test of
    /// [`segment`].
    #[inline(always)]
    fn meet(&self, b: &Surfels, (cos_plane, cos_flat): (f32, f32)) -> i32x4 {
        let a = self;
        let dot = |u: &[f32x4; 3], v: &[f32x4; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        let cos = dot(&a.n, &b.n);
        // bend = (n_a − n_b)·d̂ with d = p_a − p_b, compared without the square root and the division:
        // bend ≥ CONVEX_MIN ⇔ e > 0 and e² ≥ CONVEX_MIN² |d|² (e = (n_a − n_b)·d); bend < 0 ⇔ e < 0.
        let d: [f32x4; 3] = core::array::from_fn(|c| a.p[c] - b.p[c]);
        let bend: [f32x4; 3] = core::array::from_fn(|c| a.n[c] - b.n[c]);
        let e = dot(&bend, &d);
        // Every test is evaluated and combined lane by lane, without a branch: the signs of e and the angles
        // are noise on a flat surface.
        let zero = f32x4::ZERO;
        let convex = e.simd_gt(zero) & (e * e).simd_ge(f32x4::splat(CONVEX_MIN * CONVEX_MIN) * dot(&d, &d));
        // A nearly flat boundary that bends inwards between cells of different colour is a contact (a ball on
        // the floor, a can against a crate: the surfaces meet tangentially, so the concave crease is too faint
        // for the normals), not one surface.
        let step = (0..3).map(|c| (a.colour[c] - b.colour[c]).abs()).fold(i32x4::ZERO, i32x4::max);
        let different: f32x4 = bytemuck::cast(step.simd_gt(i32x4::splat(COLOUR_STEP)));
        let contact = e.simd_lt(zero) & different;
        let coplanar = cos.simd_ge(f32x4::splat(cos_plane));
        let joins = convex | (cos.simd_ge(f32x4::splat(cos_flat)) & !contact);
        let bit = |mask: f32x4, bit: u16| bytemuck::cast::<f32x4, i32x4>(mask) & i32x4::splat(i32::from(bit));
        i32x4::splat(i32::from(link::NORMALS))
            | bit(coplanar, link::COPLANAR)
            | bit(convex, link::CONVEX)
            | bit(joins, link::JOINS)
    }
}

/// Completes each cell's link word (its [`link::LEFT`]..[`link::DOWN`] bits are set) with how its surface meets
/// its right and lower neighbours' when both have a normal (`grid`'s normals are computed): coplanar, convex, one
/// object's surface (the LCCP test of [`segment`]). `colours` are the cells' mean colours. Four cells at a time
/// ([`Surfels`]).
#[inline(never)]
fn link_cells(grid: &Grid<'_>, colours: &[u16], params: &Params, links: &mut [u16]) {
    let cosines = (libm::cosf(PLANE_ANGLE_DEG.to_radians()), libm::cosf(params.seg_concave_tolerance_deg.to_radians()));
    // Row cy's points and normals (coordinate by coordinate) and colour words (none beyond the grid).
    let row = |cy: usize| {
        let (start, end) = (cy.saturating_mul(grid.cols), cy.saturating_add(1).saturating_mul(grid.cols));
        let points = grid.points.map(|plane| plane.get(start..end).unwrap_or(&[]));
        let normals = grid.normals.map(|plane| plane.get(start..end).unwrap_or(&[]));
        (points, normals, colours.get(2 * start..2 * end).unwrap_or(&[]))
    };
    for cy in 0..grid.rows {
        let ((points, normals, rgbs), (points_below, normals_below, rgbs_below)) = (row(cy), row(cy + 1));
        let words = links.get_mut(cy * grid.cols..(cy + 1) * grid.cols).unwrap_or(&mut []);
        for (chunk, words) in words.chunks_mut(4).enumerate() {
            // Four cells none of which has its right or lower neighbour on its surface (no depth there) have no
            // link to complete.
            if words.iter().fold(0, |m, &w| m | w) & (link::RIGHT | link::DOWN) == 0 {
                continue;
            }
            let x0 = 4 * chunk;
            let (a, right, down) = (
                Surfels::load(points, normals, rgbs, x0),
                Surfels::load(points, normals, rgbs, x0 + 1),
                Surfels::load(points_below, normals_below, rgbs_below, x0),
            );
            let (to_right, to_down) = (a.meet(&right, cosines), a.meet(&down, cosines));
            // The link bits count only where both cells have a surfel and the neighbour lies on the surface.
            let word = i32x4::from(lanes::<u16, 4>(words, 0, false).map(i32::from));
            let linked = |ok: f32x4, bit: u16| {
                bytemuck::cast::<f32x4, i32x4>(ok) & (word & i32x4::splat(i32::from(bit))).simd_ne(i32x4::ZERO)
            };
            let (with_right, with_down) = (linked(a.ok & right.ok, link::RIGHT), linked(a.ok & down.ok, link::DOWN));
            let word = word | (with_right & to_right) | ((with_down & to_down) << i32::from(link::DOWN_SHIFT));
            for (out, &w) in words.iter_mut().zip(word.as_array()) {
                *out = w as u16;
            }
        }
    }
}

/// Finds the supporting planes of `grid` and sets [`PLANE_FLAG`] in the colour word of each of their cells:
/// neighbouring cells with no depth jump between them and normals within [`PLANE_ANGLE_DEG`] are joined (the
/// union-find parents in `work`), and a component of at least `min_cells` cells that is flat (smallest σ at most
/// `FLAT_RATIO` × the middle one) and wide (largest σ ≥ `seg_structure_sigma`) is a
/// plane. `counts` (one u16 per cell) and `candidates` are scratch; the planes (centroid, unit normal) are left
/// in `planes`. Returns the cells marked and the normal of the plane with the most cells, turned towards the
/// camera (the up direction where that plane is a floor or a table).
#[inline(never)]
fn mark_planes(
    grid: &Grid<'_>,
    work: &mut [u16],
    counts: &mut [u16],
    colours: &mut [u16],
    min_cells: u32,
    candidates: &mut heapless::Vec<Candidate, MAX_CANDIDATES>,
    planes: &mut Planes,
) -> (u32, Option<Vec3>) {
    let params = grid.params;
    let n = grid.cols * grid.rows;
    let (Some(parents), Some(counts)) = (work.get_mut(..n), counts.get_mut(..n)) else { return (0, None) };
    join_links(grid, parents, counts, |_, _, bits| bits & link::COPLANAR != 0);
    components(grid, parents, counts, min_cells, candidates);
    // The planes (candidate slot k + 1 → plane index, in each candidate's `instance`).
    planes.clear();
    let mut largest: Option<(f32, Vec3)> = None;
    for c in candidates.iter_mut() {
        let eigen = linalg::sym_eigen(c.moments.covariance());
        if is_flat_and_wide(eigen.sigmas(), params) && planes.push((c.moments.mean(), eigen.normal())).is_ok() {
            c.instance = planes.len() as u16;
            if largest.is_none_or(|(w, _)| c.moments.weight > w) {
                let normal = eigen.normal();
                let towards =
                    if linalg::dot(normal, c.moments.mean()) > 0.0 { linalg::scale(normal, -1.0) } else { normal };
                largest = Some((c.moments.weight, towards));
            }
        }
    }
    let mut marked = 0;
    for i in 0..parents.len() {
        let plane = candidate_of(parents, counts, i).and_then(|k| candidates.get(k)).map_or(0, |c| c.instance);
        if let (Some(b), true) = (colours.get_mut(2 * i + 1), plane > 0 && grid.point(i).is_some()) {
            *b = (*b & 0xff) | PLANE_FLAG | (plane - 1) << PLANE_SHIFT;
            marked += 1;
        }
    }
    // The planes grow over their noisy cells (normals off by more than the coplanar links allow, which would be
    // orphan fragments taken for objects): a cell linked to a plane's cell joins that plane when it lies within
    // the depth tolerance of the plane's least-squares fit with a normal within [`PLANE_GROW_DEG`] of it; a
    // raster sweep and a reverse sweep, [`PLANE_GROW_SWEEPS`] times.
    let cos_grow = libm::cosf(PLANE_GROW_DEG.to_radians());
    // (A cell index wrapped below 0 or past the grid names no colour word.)
    let flagged = |colours: &[u16], j: usize| {
        colours.get(j.wrapping_mul(2).wrapping_add(1)).is_some_and(|&b| b & PLANE_FLAG != 0)
    };
    for pass in 0..2 * PLANE_GROW_SWEEPS {
        let reverse = pass % 2 == 1;
        // The sweep visits only the cells that can join: not a plane's, with a plane's cell among the neighbours
        // on its surface. They are found [`GROW_CHUNK`] cells of a row at a time as the bits of a word, without a
        // branch per cell, and visited in the sweep's order; a cell that joins makes the next one a candidate
        // (the only neighbour still to come in this sweep whose test it changes: the row after is tested later,
        // the row before is done).
        for r in 0..grid.rows {
            let cy = if reverse { grid.rows - 1 - r } else { r };
            let chunks = grid.cols.div_ceil(GROW_CHUNK);
            for c in 0..chunks {
                let x0 = GROW_CHUNK * if reverse { chunks - 1 - c } else { c };
                let len = GROW_CHUNK.min(grid.cols - x0);
                let first = grid.index(x0, cy);
                // A cell of no plane (its colour word without the flag).
                let open = |rgb: Option<&u16>| rgb.is_some_and(|&b| b & PLANE_FLAG == 0);
                // The cells of no plane first, then which of those have a plane's cell beside them.
                let mut open_cells = 0u64;
                for (k, rgb) in colours.get(2 * first..2 * (first + len)).unwrap_or(&[]).chunks_exact(2).enumerate() {
                    open_cells |= u64::from(open(rgb.get(1))) << k;
                }
                let mut candidates = 0u64;
                while open_cells != 0 {
                    let k = open_cells.trailing_zeros() as usize;
                    open_cells &= open_cells - 1;
                    let i = first + k;
                    let on = grid.links.get(i).copied().unwrap_or(0);
                    // (A neighbour on the cell's surface lies on the grid.)
                    let next_to_plane = ((on & link::LEFT != 0) & flagged(colours, i.wrapping_sub(1)))
                        | ((on & link::RIGHT != 0) & flagged(colours, i + 1))
                        | ((on & link::UP != 0) & flagged(colours, i.wrapping_sub(grid.cols)))
                        | ((on & link::DOWN != 0) & flagged(colours, i + grid.cols));
                    candidates |= u64::from(next_to_plane) << k;
                }
                while candidates != 0 {
                    let k =
                        if reverse { 63 - candidates.leading_zeros() } else { candidates.trailing_zeros() } as usize;
                    candidates &= !(1u64 << k);
                    let (i, cx) = (first + k, x0 + k);
                    let neighbours = four_neighbours(cx, cy);
                    let Some((p, normal)) = grid.cached_surfel(cx, cy) else { continue };
                    let tolerance = params.depth_tolerance(p[2]);
                    let joined = neighbours.iter().enumerate().find_map(|(direction, &(x, y))| {
                        grid.on_surface(i, direction).then_some(())?;
                        let b = colours.get(2 * grid.index(x, y) + 1).copied().filter(|&b| b & PLANE_FLAG != 0)?;
                        let plane = (b & !PLANE_FLAG) >> PLANE_SHIFT;
                        let (centre, axis) = planes.get(plane as usize)?;
                        let near = linalg::plane_distance(p, *centre, *axis) <= tolerance
                            && libm::fabsf(linalg::dot(*axis, normal)) >= cos_grow;
                        near.then_some(plane)
                    });
                    let (Some(plane), Some(b)) = (joined, colours.get_mut(2 * i + 1)) else { continue };
                    *b = (*b & 0xff) | PLANE_FLAG | plane << PLANE_SHIFT;
                    marked += 1;
                    // The next cell of the sweep in this chunk, when this cell lies on its surface.
                    let (next, towards) =
                        if reverse { (k.checked_sub(1), link::RIGHT) } else { (Some(k + 1), link::LEFT) };
                    if let Some(n) = next.filter(|&n| n < len) {
                        let j = first + n;
                        let on = grid.links.get(j).is_some_and(|&w| w & towards != 0);
                        candidates |= u64::from(on & open(colours.get(2 * j + 1))) << n;
                    }
                }
            }
        }
    }
    (marked, largest.map(|(_, up)| up))
}

/// Calls `f(a, b, bits)` for every cell `a` and its right and then its lower neighbour `b` when both have a normal
/// and no depth jump separates them, in raster order; `bits` are the link's [`link`] bits (at the right link's
/// place).
#[inline(never)]
fn for_each_link(grid: &Grid<'_>, mut f: impl FnMut(usize, usize, u16)) {
    for (a, &word) in grid.links.iter().enumerate() {
        for (b, shift) in [(a + 1, 0), (a + grid.cols, link::DOWN_SHIFT)] {
            let bits = word >> shift;
            if bits & link::NORMALS != 0 {
                f(a, b, bits);
            }
        }
    }
}

/// Makes `parents` the union-find of the links for which `joins(a, b, bits)` holds (and each root's entry of `sizes`
/// the number of its component's cells with a point, what [`components`] counts by) (`a` a cell, `b` its right or
/// lower neighbour, both with a normal and no depth jump between them, `bits` the link's [`link`] bits at the
/// right link's place): the sets [`for_each_link`] with a union per joining link would make, each under its
/// lowest index. The cells are visited in raster order, each with its links from the left and from above: a cell
/// has not been touched before its turn (every link points forward), so it starts as its own root and each link
/// costs one find, not the two of a union.
#[inline(never)]
fn join_links(grid: &Grid<'_>, parents: &mut [u16], sizes: &mut [u16], joins: impl Fn(usize, usize, u16) -> bool) {
    // The root of the previous cell's set when its turn ended (nothing has changed it since): its left link
    // needs no find.
    let mut left_root = 0;
    for b in 0..parents.len() {
        let mut root = b;
        if let Some(p) = parents.get_mut(b) {
            *p = b as u16;
        }
        if let Some(size) = sizes.get_mut(b) {
            *size = u16::from(grid.point(b).is_some());
        }
        // The right link of a row's last cell has no NORMALS bit (its right neighbour is off the grid).
        let joined = |a: usize, bits: u16| bits & link::NORMALS != 0 && joins(a, b, bits);
        if let Some(a) = b.checked_sub(1) {
            if joined(a, grid.links.get(a).copied().unwrap_or(0)) {
                root = hang(parents, sizes, left_root, root);
            }
        }
        if let Some(a) = b.checked_sub(grid.cols) {
            if joined(a, grid.links.get(a).map_or(0, |&w| w >> link::DOWN_SHIFT)) {
                let r = union_find::find(parents, a);
                if r != root {
                    root = hang(parents, sizes, r, root);
                }
            }
        }
        left_root = root;
    }
}

/// Calls `f(index, column, row)` for every cell of a `cols × rows` grid in raster order, or in its reverse.
fn sweep(cols: usize, rows: usize, reverse: bool, mut f: impl FnMut(usize, usize, usize)) {
    if reverse {
        for cy in (0..rows).rev() {
            for cx in (0..cols).rev() {
                f(cy * cols + cx, cx, cy);
            }
        }
    } else {
        for cy in 0..rows {
            for cx in 0..cols {
                f(cy * cols + cx, cx, cy);
            }
        }
    }
}

/// The left, right, upper and lower neighbours of cell (cx, cy); one beyond the grid has a coordinate past its
/// end (`usize::MAX` before 0), which [`Grid::point_at`] refuses.
fn four_neighbours(cx: usize, cy: usize) -> [(usize, usize); 4] {
    [(cx.wrapping_sub(1), cy), (cx + 1, cy), (cx, cy.wrapping_sub(1)), (cx, cy + 1)]
}

/// Points cell `i` of the union-find `parents` at its root (the lowest index of its component) and returns it,
/// when every cell before it already points at its root: every parent lies below its cell (unions hang the
/// higher root under the lower, finds halve paths downwards), so the parent's entry is the root — one read
/// instead of a find.
#[inline]
fn flatten_entry(parents: &mut [u16], i: usize) -> usize {
    let p = parents.get(i).copied().unwrap_or(0) as usize;
    let root = match parents.get(p) {
        Some(&r) if p < i => r as usize,
        _ => union_find::find(parents, i),
    };
    if let Some(x) = parents.get_mut(i) {
        *x = root as u16;
    }
    root
}

/// The components of the union-find `parents` (flattened on the way: each cell ends pointing at its root) that
/// cover at least `min_cells` cells with a point, as `candidates`
/// (the caller's: a candidate list is 7.7 KB, which a returned value would copy on the Cortex-M7's stack) with
/// their points' moments and box; returns how many found no room. `counts` (one u16 per cell) holds each root's
/// count of cells with a point (kept by the unions, [`join_links`]) and ends with each candidate's root holding
/// its index + 1 (0 elsewhere).
#[inline(never)]
fn components(
    grid: &Grid<'_>,
    parents: &mut [u16],
    counts: &mut [u16],
    min_cells: u32,
    candidates: &mut heapless::Vec<Candidate, MAX_CANDIDATES>,
) -> u32 {
    candidates.clear();
    let mut truncated = 0;
    let mut open: Option<Run> = None;
    // One pass in cell order: a root (its component's lowest cell) comes before the rest of its component, so
    // each root's candidate is made before its cells' points are added; `parents` is flattened on the way (each
    // cell then points at its root).
    for i in 0..parents.len() {
        if let Some(c) = counts.get_mut(i) {
            let big = u32::from(*c) >= min_cells.max(1) && parents.get(i).is_some_and(|&p| p as usize == i);
            *c = 0;
            if big {
                let first = grid.point(i).unwrap_or([0.0; 3]);
                let fresh = Candidate { moments: linalg::Moments::about(first), lo: first, hi: first, instance: 0 };
                if candidates.push(fresh).is_ok() {
                    *c = candidates.len() as u16;
                } else {
                    truncated += 1;
                }
            }
        }
        let root = flatten_entry(parents, i);
        let candidate = counts.get(root).and_then(|&slot| (slot as usize).checked_sub(1));
        if let (Some(k), Some(p)) = (candidate, grid.point(i)) {
            // A run of one candidate's cells is added to its sums in registers ([`linalg::MomentLanes`]),
            // written back when the run ends: the same sums in the same order.
            if open.as_ref().is_none_or(|run| run.candidate != k) {
                if let Some(run) = open.take() {
                    run.close(candidates);
                }
                open = candidates.get(k).map(|c| Run::open(k, c));
            }
            if let Some(run) = open.as_mut() {
                run.add(p);
            }
        }
    }
    if let Some(run) = open.take() {
        run.close(candidates);
    }
    truncated
}

/// A candidate of [`components`] while a run of its cells is added: its moments in registers and its box.
struct Run {
    candidate: usize,
    moments: linalg::MomentLanes,
    lo: f32x4,
    hi: f32x4,
}

impl Run {
    /// Candidate number `candidate`, `c`, as it stands.
    fn open(candidate: usize, c: &Candidate) -> Run {
        let lanes = |v: Vec3| f32x4::from([v[0], v[1], v[2], 0.0]);
        Run { candidate, moments: linalg::MomentLanes::from(&c.moments), lo: lanes(c.lo), hi: lanes(c.hi) }
    }

    /// Adds a cell's point to the moments and the box.
    #[inline(always)]
    fn add(&mut self, p: Vec3) {
        self.moments.add(p);
        let p = f32x4::from([p[0], p[1], p[2], 0.0]);
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }

    /// Writes the candidate back into `candidates`.
    fn close(&self, candidates: &mut [Candidate]) {
        if let Some(c) = candidates.get_mut(self.candidate) {
            c.moments = self.moments.moments();
            let xyz = |v: f32x4| -> Vec3 {
                let [x, y, z, _] = v.to_array();
                [x, y, z]
            };
            (c.lo, c.hi) = (xyz(self.lo), xyz(self.hi));
        }
    }
}

/// Hangs the higher of two different roots `a`, `b` of `parents` under the lower (as [`union_find::union`]), whose
/// entry of `sizes` takes the other's; returns the lower.
fn hang(parents: &mut [u16], sizes: &mut [u16], a: usize, b: usize) -> usize {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    if let Some(p) = parents.get_mut(hi) {
        *p = lo as u16;
    }
    let moved = sizes.get(hi).copied().unwrap_or(0);
    if let Some(size) = sizes.get_mut(lo) {
        *size = size.saturating_add(moved);
    }
    lo
}

/// [`union_find::union`] of `a` and `b` in `parents` that keeps `sizes` as [`join_links`] does.
fn union_sized(parents: &mut [u16], sizes: &mut [u16], a: usize, b: usize) {
    let (ra, rb) = (union_find::find(parents, a), union_find::find(parents, b));
    if ra != rb {
        hang(parents, sizes, ra, rb);
    }
}

/// Whether a component with principal scales `sigmas` (metres, largest first) is flat (smallest at most
/// [`FLAT_RATIO`] × the middle one) and wide (largest ≥ `seg_structure_sigma`): a table top, floor or wall.
fn is_flat_and_wide(sigmas: Vec3, params: &Params) -> bool {
    sigmas[2] <= FLAT_RATIO * sigmas[1] && sigmas[0] >= params.seg_structure_sigma
}

/// Most cells without depth between an object's inside and its outside (a rim's bright edge returns none).
const RIM_MAX_CELLS: usize = 4;
/// Least links across such gaps that join an inside to its outside.
const RIM_MIN_LINKS: u16 = 3;
/// Most pairs of objects with links across gaps one segmentation weighs (more are counted in `truncated`).
const MAX_RIM_PAIRS: usize = 64;
// `join_insides` keeps which candidates are objects in a u128.
const _: () = assert!(MAX_CANDIDATES <= 128 && (MAX_CANDIDATES as u16) < FRESH);
/// How far below an object's top a cell still lies on its rim ([`join_insides`]), metres.
const RIM_BAND: f32 = 0.02;
/// Slack of the inside test ([`join_insides`]), metres.
const INSIDE_SLACK: f32 = 0.01;
/// Slack of the inside test's far limit, a share of the outer object's width: the cells along a rim carry mixed
/// depths (the mug of `ycbv_0000`, 76 mm wide as its front wall shows it, has cells of its inside 89 mm behind
/// that wall's front).
const INSIDE_DEPTH_SHARE: f32 = 0.25;

/// The candidate (index) of cell `i`: its root's entry in `counts` ([`components`]).
fn candidate_of(parents: &[u16], counts: &[u16], i: usize) -> Option<usize> {
    let root = parents.get(i).copied()? as usize;
    counts.get(root).copied().and_then(|slot| (slot as usize).checked_sub(1))
}

/// Calls `f(i, j, a, b)` for every link across a gap: cell `i` of object candidate `a` and cell `j` of object
/// candidate `b` ≠ `a`, 2 to [`RIM_MAX_CELLS`] + 1 cells apart to the right or below, with only cells without
/// depth or in no candidate (specks of a rim) between them. `is_object(k)`: whether candidate k is an object.
fn for_each_gap_link(
    grid: &Grid<'_>,
    parents: &[u16],
    counts: &[u16],
    is_object: impl Fn(usize) -> bool,
    mut f: impl FnMut(usize, usize, usize, usize),
) {
    for cy in 0..grid.rows {
        for cx in 0..grid.cols {
            let i = grid.index(cx, cy);
            let Some(a) = candidate_of(parents, counts, i).filter(|&a| is_object(a)) else { continue };
            if grid.point(i).is_none() {
                continue;
            }
            for (dx, dy) in [(1usize, 0usize), (0, 1)] {
                for k in 1..=RIM_MAX_CELLS + 1 {
                    let (x, y) = (cx + k * dx, cy + k * dy);
                    if x >= grid.cols || y >= grid.rows {
                        break;
                    }
                    let j = grid.index(x, y);
                    let Some(b) = candidate_of(parents, counts, j).filter(|_| grid.point(j).is_some()) else {
                        continue;
                    };
                    // A cell next to it (no gap: the links of step 2 judged that boundary) or its own ends the walk.
                    if k > 1 && b != a && is_object(b) {
                        f(i, j, a, b);
                    }
                    break;
                }
            }
        }
    }
}

/// Joins to an object the object seen through its opening: a mug's inside (its inner wall and bottom beyond the
/// rim) is cut from its outside by the rim, whose bright edge returns no depth, and meets it at no link. Two
/// objects (`candidates` with an instance) are one when one of them, A, lies within the other's, B's, extent —
/// between B's bottom and top along `up` (the largest supporting plane's normal), within B's width across the
/// view, and along the view between B's front and B's front plus B's width (an object no deeper than it is
/// wide) — and at least [`RIM_MIN_LINKS`] links across gaps ([`for_each_gap_link`]) join them at B's rim: B's
/// cell within [`RIM_BAND`] of B's top. From above, the camera sees over B's rim only what lies inside B: an
/// object behind B shows above B's top or beside it, one in front of B lies before B's front, and one seen
/// under a table (an object whose underside is open) meets the table below its top. A takes B's instance.
// Not inlined: its tables then occupy the stack only while it runs, not under the rest of the segmenter.
#[inline(never)]
fn join_insides(
    grid: &Grid<'_>,
    parents: &[u16],
    counts: &[u16],
    candidates: &mut [Candidate],
    up: Vec3,
    stats: &mut SegmentStats,
) {
    // Which candidates are objects, one bit each (MAX_CANDIDATES ≤ 128).
    let objects = candidates.iter().enumerate().filter(|(_, c)| c.instance != 0).fold(0u128, |m, (k, _)| m | 1 << k);
    let is_object = |k: usize| k < 128 && objects >> k & 1 == 1;
    // Across the view, level: the camera's forward direction on the plane, and the horizontal axis across it.
    let forward = linalg::normalize_or(linalg::sub([0.0, 0.0, 1.0], linalg::scale(up, up[2])), [0.0; 3]);
    let across = linalg::cross(up, forward);
    // Every object's extent along up, across and forward ([min, max] × 3), in one pass over the cells.
    let mut extents = [[f32::MAX, f32::MIN, f32::MAX, f32::MIN, f32::MAX, f32::MIN]; MAX_CANDIDATES];
    for i in 0..parents.len() {
        let Some(k) = candidate_of(parents, counts, i).filter(|&k| is_object(k)) else { continue };
        let (Some(p), Some(e)) = (grid.point(i), extents.get_mut(k)) else { continue };
        for (axis, pair) in [up, across, forward].iter().zip(e.chunks_exact_mut(2)) {
            let x = linalg::dot(*axis, p);
            if let [lo, hi] = pair {
                *lo = lo.min(x);
                *hi = hi.max(x);
            }
        }
    }
    // The pairs of objects with links across gaps, and for each side the links that meet it at its rim (its cell
    // within `RIM_BAND` of its top): (lower index, higher index, at the first's rim, at the second's).
    let at_rim = |k: usize, cell: usize| {
        let top = extents.get(k).map_or(f32::MAX, |e| e[1]);
        grid.point(cell).is_some_and(|p| linalg::dot(up, p) >= top - RIM_BAND)
    };
    let mut pairs: heapless::Vec<(u16, u16, u16, u16), MAX_RIM_PAIRS> = heapless::Vec::new();
    for_each_gap_link(grid, parents, counts, is_object, |i, j, a, b| {
        let ((lo, lo_cell), (hi, hi_cell)) = if a < b { ((a, i), (b, j)) } else { ((b, j), (a, i)) };
        let (rim_lo, rim_hi) = (u16::from(at_rim(lo, lo_cell)), u16::from(at_rim(hi, hi_cell)));
        match pairs.iter_mut().find(|p| (p.0 as usize, p.1 as usize) == (lo, hi)) {
            Some(p) => {
                p.2 = p.2.saturating_add(rim_lo);
                p.3 = p.3.saturating_add(rim_hi);
            }
            None => {
                if pairs.push((lo as u16, hi as u16, rim_lo, rim_hi)).is_err() {
                    stats.truncated += 1;
                }
            }
        }
    });
    for &(a, b, rim_a, rim_b) in &pairs {
        let (Some(&ea), Some(&eb)) = (extents.get(a as usize), extents.get(b as usize)) else { continue };
        let inside = |i: &[f32; 6], o: &[f32; 6]| {
            let width = o[3] - o[2];
            i[0] >= o[0] - INSIDE_SLACK
                && i[1] <= o[1] + INSIDE_SLACK
                && i[2] >= o[2] - INSIDE_SLACK
                && i[3] <= o[3] + INSIDE_SLACK
                && i[4] >= o[4] - INSIDE_SLACK
                && i[5] <= o[4] + width + (INSIDE_DEPTH_SHARE * width).max(INSIDE_SLACK)
        };
        // Joined, it is still no larger than an object may be.
        let at = |e: &[f32; 6], k: usize| e.get(k).copied().unwrap_or(0.0);
        let span = |k: usize| at(&ea, k + 1).max(at(&eb, k + 1)) - at(&ea, k).min(at(&eb, k));
        let diagonal = linalg::sqrt(span(0) * span(0) + span(2) * span(2) + span(4) * span(4));
        if diagonal > grid.params.seg_max_extent {
            continue;
        }
        let (inner, outer) = if rim_b >= RIM_MIN_LINKS && inside(&ea, &eb) {
            (a, b)
        } else if rim_a >= RIM_MIN_LINKS && inside(&eb, &ea) {
            (b, a)
        } else {
            continue;
        };
        let instance = candidates.get(outer as usize).map_or(0, |c| c.instance);
        if let Some(c) = candidates.get_mut(inner as usize) {
            c.instance = instance;
            stats.insides_joined += 1;
        }
    }
}

/// Marks a cell of a component too small to be an instance while the masks are filled ([`segment`]) (without
/// the [`FRESH`] bit).
const FILL: u16 = !FRESH;
/// Least of a cell's four neighbours that must name the instance it takes: a hole inside an object, not a speck
/// of the wall beside it (on room-scale frames the link tolerance spans several centimetres of depth).
const FILL_MIN_NEIGHBOURS: usize = 3;
/// How far from an instance's cells [`fill_creases`] grows it over such cells, metres, counted in cell spacings
/// (step · z / fx each).
const CREASE_REACH_M: f32 = 0.01;
/// Pairs of raster sweeps that fill such cells from their neighbours.
const FILL_SWEEPS: usize = 1;
/// Most rounds of [`fill_creases`]: how many cells deep an instance grows over such cells.
const CREASE_ROUNDS: usize = 4;
/// Marks an instance a cell took in the current round of [`fill_creases`].
const FRESH: u16 = 0x4000;

/// Gives the cells still marked [`FILL`] in `instances` (each cell's instance) that lie within
/// [`CREASE_REACH_M`] of an instance's cells the instance one neighbour on their surface names, in rounds of one
/// cell (at most [`CREASE_ROUNDS`]; each reads the instances the round before left, so an instance grows by one
/// cell a round): a cell takes an instance when its neighbours on its surface name no other, it lies on the
/// tangent plane of one that names it (it continues its surface) and on no supporting plane of a neighbour
/// (`planes`: a crease's cell on the table's side stays the table's), and the instance's box (`candidates`' `lo`,
/// `hi` of its first candidate, which takes the others' first) stays within `seg_max_extent` with the cell's
/// point. At close range the cells of a crease between an object and what it rests on (mixed normals, neither
/// coplanar with the plane nor convex with the object) and a dark surface's dropouts lie in bands several cells
/// wide, which the three neighbours of [`FILL_MIN_NEIGHBOURS`] do not fill; left out, their points made residual
/// Gaussians shared with the table (ycbv_0000). At room scale a cell spans more than the reach, and the
/// neighbours beside an object are often another surface within the link tolerance: nothing changes there.
/// `work` (one u16 per cell) lists the cells to fill. Returns how many took an instance.
#[inline(never)]
fn fill_creases(
    grid: &Grid<'_>,
    colours: &[u16],
    planes: &Planes,
    instances: &mut [u16],
    candidates: &mut [Candidate],
    work: &mut [u16],
) -> u32 {
    // Round r reaches the cells whose spacing (step × z / fx) is at most CREASE_REACH_M / r: z ≤ reach / r.
    let reach = CREASE_REACH_M * grid.frame.intrinsics.fx / grid.step as f32;
    // The cells to fill within reach, in raster order (a grid has at most u16::MAX cells).
    let mut len = 0;
    for (i, _) in instances.iter().enumerate().filter(|(_, &id)| id == FILL) {
        if let (Some(w), true) = (work.get_mut(len), grid.point(i).is_some_and(|p| p[2] <= reach)) {
            *w = i as u16;
            len += 1;
        }
    }
    if len == 0 {
        return 0;
    }
    // Each instance's first candidate (ids ≤ the candidates, MAX_CANDIDATES ≤ 128 < FRESH), its box the union
    // of its candidates' boxes.
    let mut first = [u8::MAX; MAX_CANDIDATES + 1];
    for k in 0..candidates.len() {
        let Some(id) = candidates.get(k).map(|c| c.instance as usize).filter(|&id| id != 0) else { continue };
        match first.get(id).copied() {
            Some(u8::MAX) => {
                if let Some(f) = first.get_mut(id) {
                    *f = k as u8;
                }
            }
            Some(f) => {
                let (lo, hi) = candidates.get(k).map_or(([0.0; 3], [0.0; 3]), |c| (c.lo, c.hi));
                if let Some(c) = candidates.get_mut(f as usize) {
                    (c.lo, c.hi) = (linalg::min_elem(c.lo, lo), linalg::max_elem(c.hi, hi));
                }
            }
            None => {}
        }
    }
    let mut taken = 0;
    for round in 1..=CREASE_ROUNDS {
        let (mut kept, taken_before) = (0, taken);
        for w in 0..len {
            let i = work.get(w).copied().unwrap_or(0) as usize;
            match crease_instance(grid, colours, planes, instances, i, reach / round as f32) {
                Crease::Takes(id, p) => {
                    // No larger than an instance may be.
                    let k = first.get(id as usize).copied().unwrap_or(u8::MAX) as usize;
                    if let Some(c) = candidates.get_mut(k) {
                        let (lo, hi) = (linalg::min_elem(c.lo, p), linalg::max_elem(c.hi, p));
                        if linalg::norm(linalg::sub(hi, lo)) <= grid.params.seg_max_extent {
                            (c.lo, c.hi) = (lo, hi);
                            if let Some(x) = instances.get_mut(i) {
                                *x = id | FRESH;
                                taken += 1;
                            }
                        }
                    }
                }
                Crease::Waits => {
                    if let Some(x) = work.get_mut(kept) {
                        *x = i as u16;
                        kept += 1;
                    }
                }
                Crease::Never => {}
            }
        }
        if taken == taken_before {
            break;
        }
        len = kept;
        // This round's instances count from the next.
        for x in instances.iter_mut() {
            *x &= !FRESH;
        }
    }
    taken
}

/// The instance the neighbours of cell `i` (column `cx`, row `cy`) on its surface name in `instances` (an id
/// neither 0, [`FILL`] nor marked [`FRESH`]), whether they name no other, and how many name one; `naming(x, y)`
/// is called with each neighbour that names one. The mask fill's sweeps ([`segment`]) and [`crease_instance`]
/// both ask this.
fn named_instance(
    grid: &Grid<'_>,
    instances: &[u16],
    (i, cx, cy): (usize, usize, usize),
    mut naming: impl FnMut(usize, usize),
) -> (Option<u16>, bool, usize) {
    let (mut named, mut unique, mut count) = (None, true, 0);
    for (k, (x, y)) in four_neighbours(cx, cy).into_iter().enumerate() {
        if !grid.on_surface(i, k) {
            continue;
        }
        let Some(id) = instances.get(grid.index(x, y)).copied().filter(|&id| id != 0 && id != FILL && id & FRESH == 0)
        else {
            continue;
        };
        unique &= named.is_none_or(|m| m == id);
        named = Some(id);
        count += 1;
        naming(x, y);
    }
    (named, unique, count)
}

/// What a cell to fill does in a round of [`fill_creases`].
enum Crease {
    /// It takes this instance (its point with it).
    Takes(u16, Vec3),
    /// Not in this round; a neighbour on its surface is still to fill or was filled in this round.
    Waits,
    /// Not in this round or any later one.
    Never,
}

/// What [`FILL`] cell `i` does in a round of [`fill_creases`] that reaches cells nearer than `reach` metres,
/// from `instances` as the rounds before left them.
fn crease_instance(
    grid: &Grid<'_>,
    colours: &[u16],
    planes: &Planes,
    instances: &[u16],
    i: usize,
    reach: f32,
) -> Crease {
    let Some(p) = grid.point(i).filter(|p| p[2] <= reach) else { return Crease::Never };
    let cy = i / grid.cols.max(1);
    let cx = i - cy * grid.cols;
    // The neighbours and their indices (wrapped off the grid, where no link bit names them).
    let on = grid.links.get(i).copied().unwrap_or(0);
    let neighbours = four_neighbours(cx, cy).map(|(x, y)| y.wrapping_mul(grid.cols).wrapping_add(x));
    let beside = |k: usize| on & (link::LEFT << k) != 0;
    let id_at = |j: usize| instances.get(j).copied().unwrap_or(0);
    let waits = || {
        let open =
            neighbours.iter().enumerate().any(|(k, &j)| beside(k) && (id_at(j) == FILL || id_at(j) & FRESH != 0));
        if open {
            Crease::Waits
        } else {
            Crease::Never
        }
    };
    let tolerance = grid.params.depth_tolerance(p[2]);
    let mut on_tangent = false;
    let (named, unique, _) = named_instance(grid, instances, (i, cx, cy), |x, y| {
        if let Some((q, normal)) = grid.cached_surfel(x, y) {
            on_tangent |= linalg::plane_distance(p, q, normal) <= tolerance;
        }
    });
    // Two instances beside it stay two; one whose surface it does not continue may be joined by another.
    let id = match named {
        Some(id) if unique && on_tangent => id,
        Some(_) if unique => return waits(),
        Some(_) => return Crease::Never,
        None => return waits(),
    };
    // On a supporting plane of a neighbour (one of no instance, not an object's face) it is the crease's cell on
    // the table's side.
    let on_support = neighbours.iter().enumerate().filter(|&(k, _)| beside(k)).any(|(_, &j)| {
        let support = colours.get(2 * j + 1).filter(|&&b| b & PLANE_FLAG != 0 && id_at(j) == 0);
        let plane = support.and_then(|&b| planes.get(((b & !PLANE_FLAG) >> PLANE_SHIFT) as usize));
        plane.is_some_and(|(centre, axis)| linalg::plane_distance(p, *centre, *axis) <= tolerance)
    });
    if on_support {
        Crease::Never
    } else {
        Crease::Takes(id, p)
    }
}

/// The links between a plane's component and another component ([`segment`]).
struct Boundary {
    /// Root cell of the plane's component.
    plane: u16,
    /// Root cell of the other component.
    other: u16,
    /// Convex links ((n_a − n_b)·d̂ ≥ [`CONVEX_MIN`]).
    convex: u16,
    /// All links.
    links: u16,
}

/// Most plane–component boundaries one segmentation weighs (more are counted in `truncated` and not joined).
const MAX_BOUNDARIES: usize = 128;
/// Least convex links along a boundary that makes a plane an object's face.
const FACE_MIN_LINKS: u16 = 3;

/// Instances a caller's buffer for one segmentation holds (the shell's and the firmware's): more qualifying
/// components are counted in [`SegmentStats::truncated`].
pub const SEGMENTER_INSTANCES: usize = 64;

/// CRC-32 of a segmentation: the id image (little-endian u16 per pixel), then each instance's id, class, score
/// bits and box (little-endian). The host and the firmware compare segmentations by it.
pub fn digest(ids: &[u16], instances: &[Instance]) -> u32 {
    let mut crc = 0xFFFF_FFFF;
    for id in ids {
        crc = crate::wire::crc32_update(crc, &id.to_le_bytes());
    }
    for k in instances {
        crc = crate::wire::crc32_update(crc, &k.id.to_le_bytes());
        crc = crate::wire::crc32_update(crc, &k.class.to_le_bytes());
        crc = crate::wire::crc32_update(crc, &k.score.to_bits().to_le_bytes());
        for b in k.bbox {
            crc = crate::wire::crc32_update(crc, &b.to_le_bytes());
        }
    }
    !crc
}

/// Writes the masks over the id image `ids`, whose first `cols × rows` entries hold each cell's instance (0:
/// none): every pixel with a valid depth on its cell's surface — within the jump tolerance of the cell's centre
/// pixel (of its reference pixel, [`reference_depth`], for a holed cell that took an instance) — takes the cell's
/// instance, every other pixel 0; each instance's box grows over its pixels. Pixels are written from the last:
/// pixel i's cell index is at most i, so no cell is overwritten before its pixels are done.
#[inline(never)]
fn write_masks(
    frame: &Frame<'_>,
    params: &Params,
    (step, cols, rows): (usize, usize, usize),
    ids: &mut [u16],
    instances: &mut [Instance],
) {
    let (lo, hi) = frame.raw_range(params);
    let (w, h) = (frame.width as usize, frame.height as usize);
    // Cell by cell from the last: a pixel of cell c has an index ≥ c (the block starts at row cy·step ≥ cy,
    // column cx·step ≥ cx), and every cell still to come is below c.
    for cy in (0..rows).rev() {
        let (v0, _, v1) = block_span(cy, step, h);
        // The pixels of a run of cells without an instance are zeroed together, row by row, once the run ends
        // (its end: one past its last pixel column); its cells have been read by then.
        let mut zeros_end: Option<usize> = None;
        let zero = |ids: &mut [u16], from: usize, end: Option<usize>| {
            for v in v0..v1 {
                if let Some(row) = end.and_then(|end| ids.get_mut(v * w + from..v * w + end)) {
                    row.fill(0);
                }
            }
        };
        for cx in (0..cols).rev() {
            let instance = ids.get(cy * cols + cx).copied().unwrap_or(0);
            let (u0, _, u1) = block_span(cx, step, w);
            if instance == 0 {
                zeros_end.get_or_insert(u1);
                continue;
            }
            zero(ids, u1, zeros_end.take());
            // The pixel must lie on its cell's surface: within the jump tolerance of the cell's centre pixel, or of
            // its reference pixel when the centre has no depth (a holed cell that took an instance in
            // [`adopt_holed_cells`]); without a reference, no pixel takes the instance.
            let near = match reference_depth(frame, (lo, hi), (cx, cy), step) {
                Some(centre) => near_interval((lo, hi), centre, raw_jump(frame, params, step, centre)),
                None => NOWHERE,
            };
            // The usual 4 × 4-pixel cell, two pixel rows at a time; the instance's box once per cell from the
            // columns and rows that took it (the same box as row by row below).
            if let (true, Some((start, span))) =
                (u1 - u0 == 4 && v1 - v0 == 4, u16::try_from(near.1).ok().map(|s| (near.0, s)))
            {
                let (start, span, id) = (u16x8::splat(start), u16x8::splat(span), u16x8::splat(instance));
                let (mut columns, mut rows_hit) = (0u32, 0u32);
                for (pair, v) in [v0, v0 + 2].into_iter().enumerate() {
                    let (first, second) = (v * w + u0, (v + 1) * w + u0);
                    let depths = match (frame.depth.get(first..first + 4), frame.depth.get(second..second + 4)) {
                        (Some(a), Some(b)) => u16x8::from(core::array::from_fn(|k| {
                            if k < 4 { a.get(k) } else { b.get(k - 4) }.copied().unwrap_or(0)
                        })),
                        _ => continue,
                    };
                    let on_surface = (depths - start).simd_le(span);
                    let out = (on_surface & id).to_array();
                    for (row, lanes) in [first, second].into_iter().zip(out.chunks_exact(4)) {
                        if let Some(ids) = ids.get_mut(row..row + 4) {
                            ids.copy_from_slice(lanes);
                        }
                    }
                    let hits = on_surface.to_bitmask();
                    let (upper, lower) = (hits & 0xf, hits >> 4);
                    columns |= upper | lower;
                    rows_hit |= (u32::from(upper != 0) | u32::from(lower != 0) << 1) << (2 * pair);
                }
                if let (true, Some(inst)) = (columns != 0, instances.get_mut(instance as usize - 1)) {
                    let (left, right) = (columns.trailing_zeros() as usize, 31 - columns.leading_zeros() as usize);
                    let (top, bottom) = (rows_hit.trailing_zeros() as usize, 31 - rows_hit.leading_zeros() as usize);
                    let b = &mut inst.bbox;
                    *b = [
                        b[0].min((u0 + left) as u16),
                        b[1].min((v0 + top) as u16),
                        b[2].max((u0 + right) as u16),
                        b[3].max((v0 + bottom) as u16),
                    ];
                }
                continue;
            }
            for v in (v0..v1).rev() {
                let (depth, row) = match (frame.depth.get(v * w + u0..v * w + u1), ids.get_mut(v * w + u0..v * w + u1))
                {
                    (Some(d), Some(r)) => (d, r),
                    _ => continue,
                };
                let mut hit = false;
                for (x, &raw) in row.iter_mut().zip(depth) {
                    let on_surface = is_near(raw, near);
                    *x = if on_surface { instance } else { 0 };
                    hit |= on_surface;
                }
                // The instance's box over this row's pixels that took it.
                if hit {
                    if let Some(inst) = instances.get_mut(instance as usize - 1) {
                        let first = row.iter().position(|&x| x == instance).unwrap_or(0) + u0;
                        let last = row.iter().rposition(|&x| x == instance).unwrap_or(0) + u0;
                        let b = &mut inst.bbox;
                        *b = [b[0].min(first as u16), b[1].min(v as u16), b[2].max(last as u16), b[3].max(v as u16)];
                    }
                }
            }
        }
        zero(ids, 0, zeros_end);
    }
}

/// Counts of one segmentation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SegmentStats {
    /// Candidate components (before the size limits).
    pub components: u32,
    /// Instances written.
    pub instances: u32,
    /// Components that qualified but found no room in the instance buffer or the candidates, and plane links
    /// whose boundary found no room in the boundary table (not weighed).
    pub truncated: u32,
    /// Cells on supporting planes.
    pub plane_cells: u32,
    /// Objects joined to the object they were seen inside (`join_insides`).
    pub insides_joined: u32,
    /// Cells without a point of their own that took a neighbour's instance (`adopt_holed_cells`).
    pub holed_cells_adopted: u32,
    /// Cells of a close-range crease (or a dark surface's dropouts) that took the instance beside them
    /// (`fill_creases`).
    pub crease_cells_filled: u32,
}

/// Segments `frame` (depth only): writes the id image `ids` (one u16 per pixel, 0 = none; it is also the
/// working memory) and `instances`, using `scratch` (at least one u16 per cell: the mapper's per-voxel scratch)
/// for the component counts; the counts are in the returned [`SegmentStats`].
pub fn segment(
    frame: &Frame<'_>,
    scratch: &mut [u16],
    params: &Params,
    ids: &mut [u16],
    instances: &mut [Instance],
    class: u16,
) -> SegmentStats {
    let mut stats = SegmentStats::default();
    // A grid of cells over the depth image (an organized cloud: neighbours are known without a search, and the
    // cells are as fine at 0.5 m as at 4 m). `ids` holds the parents (n), the cells' quantised normals (3n),
    // mean colours (2n), link words (n) and points (6n, aligned) until the masks.
    let layout = Grid::layout(frame, scratch.len().min(ids.len().saturating_sub(1) / 13));
    let n = layout.1 * layout.2;
    let (parents, rest) = ids.split_at_mut(n.min(ids.len()));
    let (normals, rest) = rest.split_at_mut((3 * n).min(rest.len()));
    let (colours, rest) = rest.split_at_mut((2 * n).min(rest.len()));
    let (links, rest) = rest.split_at_mut(n.min(rest.len()));
    // The cells' points in the rest of the id image (6 u16 per cell, after at most one to align them for f32:
    // 13 u16 per cell in all, and a grid of 4-pixel cells has 16 pixels' ids per cell), coordinate by coordinate.
    // The layout leaves room for every cell; one that found none would have no point.
    let (_, coordinates, _) = bytemuck::pod_align_to_mut::<u16, f32>(rest);
    let room = (coordinates.len() / 3).min(n);
    let (xs, rest) = coordinates.split_at_mut(room);
    let (ys, rest) = rest.split_at_mut(room);
    let zs = rest.get_mut(..room).unwrap_or(&mut []);
    Grid::fill(frame, params, layout, [&mut *xs, &mut *ys, &mut *zs], colours);
    let points = [&*xs, &*ys, &*zs];
    // The normals component by component (n u16 each).
    let (nx, rest) = normals.split_at_mut(n.min(normals.len()));
    let (ny, nz) = rest.split_at_mut(n.min(rest.len()));
    let grid =
        Grid { frame, params, step: layout.0, cols: layout.1, rows: layout.2, points, normals: [&[]; 3], links: &[] };
    grid.surfels([&mut *nx, &mut *ny, &mut *nz], links);
    let grid = Grid { normals: [&*nx, &*ny, &*nz], ..grid };
    link_cells(&grid, colours, params, links);
    let grid = Grid { links, ..grid };
    // 1. Supporting planes ([`mark_planes`]): their cells are marked in their colour word.
    let min_cells =
        (params.seg_min_points as f32 / params.sample_rate.max(1e-3) / (grid.step * grid.step) as f32) as u32;
    // One candidate list serves the planes' components and then the objects'.
    let mut candidates: heapless::Vec<Candidate, MAX_CANDIDATES> = heapless::Vec::new();
    let mut planes = Planes::new();
    let (marked, up) = mark_planes(&grid, scratch, parents, colours, min_cells, &mut candidates, &mut planes);
    stats.plane_cells = marked;
    let colours = &*colours;
    let on_plane = |i: usize| colours.get(2 * i + 1).is_some_and(|&b| b & PLANE_FLAG != 0);
    // 2. Objects: neighbouring cells join when no depth jump separates them and their boundary is locally
    // convex or nearly flat (LCCP).
    // A plane's cells join only each other here (see below for an object's face).
    let counts = scratch.get_mut(..n).unwrap_or(&mut []);
    join_links(&grid, parents, counts, |ia, ib, bits| bits & link::JOINS != 0 && on_plane(ia) == on_plane(ib));
    // A plane that meets a component along a mostly convex boundary is that object's face (a box's side, a
    // cabinet's front), not a support: it joins it. An object resting on a plane meets it along a concave crease
    // (a few links may read convex there: the majority decides, as in LCCP's segment-level convexity).
    let mut boundaries: heapless::Vec<Boundary, MAX_BOUNDARIES> = heapless::Vec::new();
    let mut last_boundary: Option<usize> = None;
    for_each_link(&grid, |ia, ib, bits| {
        if on_plane(ia) == on_plane(ib) {
            return;
        }
        let (plane, other) = if on_plane(ia) { (ia, ib) } else { (ib, ia) };
        let key = (union_find::find(parents, plane) as u16, union_find::find(parents, other) as u16);
        // Neighbouring links mostly cross the same boundary: the last one found is tried first.
        let same = |k: &usize| boundaries.get(*k).is_some_and(|b| (b.plane, b.other) == key);
        let at = match last_boundary.filter(same).or_else(|| boundaries.iter().position(|b| (b.plane, b.other) == key))
        {
            Some(k) => k,
            None => {
                let fresh = Boundary { plane: key.0, other: key.1, convex: 0, links: 0 };
                if boundaries.push(fresh).is_err() {
                    stats.truncated += 1;
                    return;
                }
                boundaries.len() - 1
            }
        };
        last_boundary = Some(at);
        if let Some(b) = boundaries.get_mut(at) {
            b.links = b.links.saturating_add(1);
            b.convex = b.convex.saturating_add(u16::from(bits & link::CONVEX != 0));
        }
    });
    for b in &boundaries {
        if b.convex >= FACE_MIN_LINKS && 2 * b.convex > b.links {
            union_sized(parents, counts, b.plane as usize, b.other as usize);
        }
    }
    // Components covering at least `seg_min_points` sampled points' worth of pixels become candidates;
    // `scratch[root]` then holds candidate index + 1.
    let truncated = components(&grid, parents, counts, min_cells, &mut candidates);
    stats.truncated += truncated;
    stats.components = candidates.len() as u32;
    // Structure is large, or flat and wide (a table top or a wall seen between objects); the rest are objects.
    let mut written = 0usize;
    for c in candidates.iter_mut() {
        let extent = linalg::norm(linalg::sub(c.hi, c.lo));
        let sigmas = linalg::sym_eigen(c.moments.covariance()).sigmas();
        if extent > params.seg_max_extent || is_flat_and_wide(sigmas, params) {
            continue;
        }
        let Some(slot) = instances.get_mut(written) else {
            stats.truncated += 1;
            continue;
        };
        written += 1;
        *slot = Instance { id: written as u16, class, score: params.seg_score, bbox: [u16::MAX, u16::MAX, 0, 0] };
        c.instance = written as u16;
    }
    // An object seen through another's opening is its inside (a mug's inner wall beyond its rim).
    if let Some(up) = up {
        join_insides(&grid, parents, counts, &mut candidates, up, &mut stats);
    }
    // Each cell's instance replaces its root (a root is read before its own entry is replaced: roots come first).
    // A cell of a component too small to be anything (a cell whose normal is noise, a speck between depth holes)
    // is marked [`FILL`] instead of 0.
    for i in 0..n {
        let instance = match candidate_of(parents, counts, i).and_then(|k| candidates.get(k)) {
            Some(c) => c.instance,
            None if grid.point(i).is_some() && !on_plane(i) => FILL,
            None => 0,
        };
        if let Some(x) = parents.get_mut(i) {
            *x = instance;
        }
    }
    // Such a cell takes the instance of its neighbours on the same surface when at least
    // [`FILL_MIN_NEIGHBOURS`] of its four name it and none another (a hole in an object's mask would leave its
    // points to the Gaussians of what it rests on); a raster sweep and a reverse sweep, [`FILL_SWEEPS`] times;
    // what is left is no instance.
    for pass in 0..2 * FILL_SWEEPS {
        sweep(grid.cols, grid.rows, pass % 2 == 1, |i, cx, cy| {
            if parents.get(i) != Some(&FILL) {
                return;
            }
            let (named, unique, naming) = named_instance(&grid, parents, (i, cx, cy), |_, _| {});
            if let (Some(id), true, Some(x)) = (named, unique && naming >= FILL_MIN_NEIGHBOURS, parents.get_mut(i)) {
                *x = id;
            }
        });
    }
    // At close range, the cells of a crease between an object and what it rests on, or of a dark surface's
    // dropouts, lie in bands too wide for that: one neighbour naming an instance suffices there.
    stats.crease_cells_filled = fill_creases(&grid, colours, &planes, parents, &mut candidates, counts);
    for x in parents.iter_mut() {
        *x = if *x == FILL { 0 } else { *x };
    }
    stats.holed_cells_adopted = adopt_holed_cells(&grid, parents);
    // 3. Masks: every pixel with a valid depth near its cell's takes the cell's instance.
    write_masks(frame, params, layout, ids, instances);
    // An instance whose cells received no pixel keeps an empty box: drop it by giving it a one-pixel box at 0
    // with no pixels (still valid, never matched).
    for inst in instances.iter_mut().take(written) {
        if inst.bbox[0] > inst.bbox[2] {
            inst.bbox = [0, 0, 0, 0];
        }
    }
    stats.instances = written as u32;
    stats
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sweep_visits_every_cell_once_in_order_and_in_reverse() {
        for (cols, rows) in [(0, 0), (0, 3), (3, 0), (1, 1), (1, 4), (4, 1), (5, 3), (160, 120)] {
            let n = cols * rows;
            let cell = |i: usize| (i, i % cols, i / cols);
            for reverse in [false, true] {
                let mut k = 0;
                sweep(cols, rows, reverse, |i, cx, cy| {
                    let expected = if reverse { cell(n - 1 - k) } else { cell(k) };
                    assert_eq!((i, cx, cy), expected, "{cols} × {rows}, reverse {reverse}, step {k}");
                    k += 1;
                });
                assert_eq!(k, n, "{cols} × {rows}, reverse {reverse}");
            }
        }
    }

    const COLS: usize = 8;
    const ROWS: usize = 6;
    const CELLS: usize = COLS * ROWS;

    /// A grid of [`COLS`] × [`ROWS`] cells of one surface facing the camera at `z` (every neighbour on it): its
    /// points (5 mm apart), quantised normals and link words.
    fn flat_cells(z: f32) -> ([[f32; CELLS]; 3], [[u16; CELLS]; 3], [u16; CELLS]) {
        let points = [
            core::array::from_fn(|i| (i % COLS) as f32 * 0.005),
            core::array::from_fn(|i| (i / COLS) as f32 * 0.005),
            [z; CELLS],
        ];
        let normals = [0.0, 0.0, -1.0f32].map(|c| [crate::supervoxel::quantise_unit(c) as u16; CELLS]);
        let links = core::array::from_fn(|i| {
            let (cx, cy) = (i % COLS, i / COLS);
            (u16::from(cx > 0) * link::LEFT)
                | (u16::from(cx + 1 < COLS) * link::RIGHT)
                | (u16::from(cy > 0) * link::UP)
                | (u16::from(cy + 1 < ROWS) * link::DOWN)
        });
        (points, normals, links)
    }

    #[test]
    fn creases_fill_within_reach_from_one_instance_and_stop_at_a_support() {
        let z = 0.5;
        // fx 400: a 4-pixel cell spans 4 × 0.5 / 400 = 5 mm at 0.5 m, so two rounds reach the 10 mm of
        // CREASE_REACH_M.
        let intrinsics = crate::frame::Intrinsics { fx: 400.0, fy: 400.0, cx: 0.0, cy: 0.0 };
        let frame =
            Frame { width: 32, height: 24, depth: &[], depth_scale: 1000.0, colour: &[], intrinsics, pose: None };
        let (mut points, normals, links) = flat_cells(z);
        let candidate = |instance: u16, x0: f32| Candidate {
            moments: linalg::Moments::default(),
            lo: [x0, 0.0, z],
            hi: [x0 + 0.005, 0.025, z],
            instance,
        };
        let run =
            |points: &[[f32; CELLS]; 3], colours: &[u16], planes: &Planes, instances: &mut [u16; CELLS], extent| {
                let params = Params { seg_max_extent: extent, ..Params::default() };
                let grid = Grid {
                    frame: &frame,
                    params: &params,
                    step: 4,
                    cols: COLS,
                    rows: ROWS,
                    points: points.each_ref().map(|plane| &plane[..]),
                    normals: normals.each_ref().map(|plane| &plane[..]),
                    links: &links,
                };
                let mut candidates = [candidate(1, 0.0), candidate(2, 0.015)];
                fill_creases(&grid, colours, planes, instances, &mut candidates, &mut [0u16; CELLS])
            };
        let row = |instances: &[u16; CELLS], cy: usize| -> [u16; COLS] {
            core::array::from_fn(|cx| instances[cy * COLS + cx])
        };
        let (f, no_colours, no_planes) = (FILL, [0u16; 2 * CELLS], Planes::new());
        // Instance 1 in columns 0–1, the rest to fill: it grows by the two rounds that reach, no further.
        let start: [u16; CELLS] = core::array::from_fn(|i| if i % COLS < 2 { 1 } else { FILL });
        let mut grown = start;
        assert_eq!(run(&points, &no_colours, &no_planes, &mut grown, 1.5), 2 * ROWS as u32);
        for cy in 0..ROWS {
            assert_eq!(row(&grown, cy), [1, 1, 1, 1, f, f, f, f], "row {cy}");
        }
        // Instance 2 in column 3 as well: the cell between the two takes neither, instance 2 grows to the right.
        let mut both = start;
        for cy in 0..ROWS {
            both[cy * COLS + 3] = 2;
        }
        run(&points, &no_colours, &no_planes, &mut both, 1.5);
        assert_eq!(row(&both, 0), [1, 1, f, 2, 2, 2, f, f]);
        // Twice as near, a cell spans half as much: four rounds reach, the most there are.
        let (near_points, _, _) = flat_cells(0.25);
        let mut near = start;
        run(&near_points, &no_colours, &no_planes, &mut near, 1.5);
        assert_eq!(row(&near, 0), [1, 1, 1, 1, 1, 1, f, f]);
        // No larger than an instance may be: nothing grows past seg_max_extent.
        let mut small = start;
        run(&points, &no_colours, &no_planes, &mut small, 0.026);
        assert_eq!(row(&small, 0), [1, 1, f, f, f, f, f, f]);
        // A cell off the surface of the instance beside it (5 cm behind its tangent plane) is another surface.
        points[2][2] = z + 0.05;
        let mut off = start;
        run(&points, &no_colours, &no_planes, &mut off, 1.5);
        assert_eq!(row(&off, 0), [1, 1, f, f, f, f, f, f]);
        assert_eq!(row(&off, 1), [1, 1, 1, 1, f, f, f, f]);
        points[2][2] = z;
        // The bottom row is a supporting plane through the cells (no instance): the cells beside it lie on it,
        // the crease's side of the table, and stay.
        let (mut colours, mut on_table) = (no_colours, start);
        for cx in 0..COLS {
            colours[2 * ((ROWS - 1) * COLS + cx) + 1] = PLANE_FLAG;
            on_table[(ROWS - 1) * COLS + cx] = 0;
        }
        let mut planes = Planes::new();
        assert!(planes.push(([0.0, 0.0, z], [0.0, 0.0, 1.0])).is_ok());
        run(&points, &colours, &planes, &mut on_table, 1.5);
        assert_eq!(row(&on_table, ROWS - 2), [1, 1, f, f, f, f, f, f]);
        assert_eq!(row(&on_table, 0), [1, 1, 1, 1, f, f, f, f]);
    }

    #[test]
    fn quantise_units_rounds_as_quantise_unit() {
        // Every halfway point of the 1/32767 grid and its neighbours one ulp either side, a dense sweep past
        // [−1, 1] and the edges, four lanes at a time: the values of the scalar rounding.
        let halves = (-32768i32..=32767).flat_map(|k| {
            let half = (k as f32 + 0.5) / 32767.0;
            [half, f32::from_bits(half.to_bits() + 1), f32::from_bits(half.to_bits().wrapping_sub(1))]
        });
        let sweep = (0..=400_000u32).map(|i| -1.1 + 2.2 * i as f32 / 400_000.0);
        let mut xs = halves.chain(sweep).chain([-1.0, 1.0, 0.0, -0.0, 2.0, -2.0, 0.5, -0.5]);
        while let (Some(a), Some(b), Some(c), Some(d)) = (xs.next(), xs.next(), xs.next(), xs.next()) {
            let lanes = quantise_units(f32x4::from([a, b, c, d])).to_array();
            for (x, q) in [a, b, c, d].into_iter().zip(lanes) {
                assert_eq!(q, i32::from(crate::supervoxel::quantise_unit(x)), "x = {x:e}");
            }
        }
    }

    #[test]
    fn a_frame_without_pixels_segments_into_nothing() {
        // `segment` is public: a frame that `Mapper::segment` would refuse must not panic either.
        let params = Params::default();
        let intrinsics = crate::frame::Intrinsics { fx: 525.0, fy: 525.0, cx: 0.0, cy: 0.0 };
        for (width, height) in [(0u16, 0u16), (0, 5), (5, 0)] {
            let frame = Frame { width, height, depth: &[], depth_scale: 1000.0, colour: &[], intrinsics, pose: None };
            let (mut scratch, mut ids) = ([0u16; 64], [7u16; 64]);
            let mut instances = [Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; 4];
            let stats = segment(&frame, &mut scratch, &params, &mut ids, &mut instances, 1);
            assert_eq!((stats.instances, stats.components), (0, 0), "{width} × {height}");
        }
    }

    #[test]
    fn the_near_interval_is_the_range_and_tolerance_test() {
        let cases = [
            ((1, 40_000), 20_000, 150),
            ((1, 40_000), 100, 500),       // the interval starts at the range's low end
            ((1, 40_000), 39_900, 500),    // and ends at its high end
            ((2_000, 3_000), 2_500, 0),    // a zero tolerance: the centre alone
            ((1, 65_535), 65_535, 70_000), // a tolerance past every value
            ((500, 600), 550, u32::MAX),
            ((2_000, 3_000), 5_000, 100), // a centre out of range: nothing is near
        ];
        for ((lo, hi), centre, tolerance) in cases {
            let near = near_interval((lo, hi), centre, tolerance);
            for r in 0..=u16::MAX {
                let expected = (lo..=hi).contains(&r) && (r as u32).abs_diff(centre as u32) <= tolerance;
                assert_eq!(is_near(r, near), expected, "r {r}, range {lo}..={hi}, centre {centre} ± {tolerance}");
            }
            let (sum, n) = sum_near(&[centre, lo.saturating_sub(1), hi], near);
            let counted = |r: u16| u32::from((lo..=hi).contains(&r) && (r as u32).abs_diff(centre as u32) <= tolerance);
            assert_eq!(n, counted(centre) + counted(hi));
            assert_eq!(sum, counted(centre) * centre as u32 + counted(hi) * hi as u32);
        }
    }
}
