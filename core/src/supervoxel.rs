//! Stage 2: 3 cm voxels and VCCS-style supervoxels (paper §III-A; Papon et al., CVPR 2013).
//!
//! 1. **Voxels.** Every sampled point adds to the sums of its `voxel_resolution` cube (count, Σ offset — turned
//!    into the mean once every point is in — and Σ RGB); the hash from cube key to voxel is open addressing over
//!    a fixed slot array. Voxel indices follow the
//!    pixel scan, so they are deterministic.
//! 2. **Normals.** A voxel's normal is the least-variance direction of its own and its 26 neighbours'
//!    centroids, turned towards the camera.
//! 3. **Seeds.** The space is cut into `seed_resolution` cubes; in each cube holding at least
//!    `seed_min_voxels` voxels, the voxel nearest the cube centre is a seed.
//! 4. **Flow-constrained growth.** In rounds, each supervoxel claims the unlabelled voxels 26-adjacent to the
//!    voxels it claimed in the previous round; a voxel reachable from several supervoxels goes to the one with
//!    the smallest VCCS distance D² = w_c·D_c² + w_s·D_s²/(3·R_seed²) + w_n·D_n² (ties: lower index). Centres
//!    are updated after every round; growth stops after ⌈1.8·R_seed/R_voxel⌉ rounds as in VCCS. A voxel is
//!    only ever claimed next to a voxel of the same supervoxel and never taken away, so every supervoxel is
//!    26-connected.
//! 5. **Orphans.** Voxels left unlabelled form 26-connected components (union-find in index order); each
//!    component with at least `gmm_min_points` points becomes a supervoxel of its own, smaller ones are outlier
//!    clusters (sensor speckle), counted and left out of the map.

use bytemuck::Zeroable;

use crate::frame::Frame;
use crate::linalg::{self, Moments, Vec3};
use crate::masks::{MaskSet, SlotCache};
use crate::params::{Params, VOXEL_GRID_HALF_EXTENT};
use crate::points;
use crate::pool::{self, Bounded, Probe};
use crate::union_find;

/// Label of a voxel that no supervoxel has claimed (yet).
pub const UNLABELLED: u16 = u16::MAX;
/// Label of a voxel in an outlier cluster (too few points to map).
pub const OUTLIER: u16 = u16::MAX - 1;
/// Label of a voxel whose supervoxel did not fit the pool (counted as an overflow).
pub const DROPPED: u16 = u16::MAX - 2;

/// Whether a label names a real supervoxel or Gaussian.
#[inline]
pub fn is_assigned(label: u16) -> bool {
    label < DROPPED
}

/// One occupied voxel: the count, mean, colour sums and normal of the sampled points that fall into it.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct Voxel {
    /// Packed cube key, see [`voxel_key`].
    pub key: u32,
    /// Points in the voxel.
    pub count: u16,
    /// Supervoxel index, or [`UNLABELLED`], [`OUTLIER`], [`DROPPED`]. Between the normals and growth of a
    /// profile without links, bits 16–25 of the directions in which the normals found a neighbour.
    pub supervoxel: u16,
    /// Gaussian index after stage 3, or a label constant. From the normals through growth of a profile without
    /// links, bits 0–15 of the directions in which the normals found a neighbour.
    pub gaussian: u16,
    /// Unit normal × 32767, facing the camera.
    pub normal: [i16; 3],
    /// Mean of its points, metres (camera frame): [`voxelize`] sums p − corner here while it adds points and
    /// turns the sum into the mean once every point is in, so that no later stage divides again. Read it with
    /// [`Voxel::centroid`].
    pub mean: Vec3,
    /// Σ R, Σ G and Σ B over its points, 21 bits each, packed little-endian into a 64-bit word held as two
    /// `u32`s (R in bits 0–20, G in 21–41, B in 42–62); read them with [`Voxel::colour_sums`]. A voxel takes at
    /// most [`MAX_VOXEL_POINTS`] points, so no sum overflows its field (4 bytes less per voxel than three
    /// `u32`s: 32 KiB of the mcu profile). Bit 63 (the top bit of the second word) is the shared-cube flag
    /// ([`Voxel::shares_cube`]).
    pub colour_sum: [u32; 2],
}

/// The shared-cube flag's bit in `colour_sum[1]`, above the packed sums (which never carry into it).
const SHARED_CUBE_BIT: u32 = 1 << 31;

/// Most points a voxel takes (255 × 8 223 < 2²¹, the width of a packed colour sum); later ones are dropped and
/// counted. A 3 cm voxel holds at most ~2 000 sampled points even at 0.3 m.
pub const MAX_VOXEL_POINTS: u16 = 8223;

/// Bits of one packed colour sum.
const COLOUR_SUM_BITS: u32 = 21;

impl Voxel {
    /// Mean of its points, metres (after [`voxelize`]).
    #[inline]
    pub fn centroid(&self) -> Vec3 {
        self.mean
    }

    /// Mean colour, each channel in [0, 1].
    pub fn colour(&self) -> Vec3 {
        let k = 1.0 / (255.0 * self.count.max(1) as f32);
        let [r, g, b] = self.colour_sums();
        [r as f32 * k, g as f32 * k, b as f32 * k]
    }

    /// Σ R, Σ G, Σ B over its points.
    pub fn colour_sums(&self) -> [u32; 3] {
        let [lo, hi] = self.colour_sum;
        let packed = lo as u64 | (hi as u64) << 32;
        let field = (1u64 << COLOUR_SUM_BITS) - 1;
        [0, 1, 2].map(|k| ((packed >> (k * COLOUR_SUM_BITS)) & field) as u32)
    }

    /// Whether another voxel of the frame has the same cube in another mask slot (set by [`voxelize`] when
    /// [`VoxelStats::shared_cubes_marked`]).
    #[inline]
    pub fn shares_cube(&self) -> bool {
        self.colour_sum[1] & SHARED_CUBE_BIT != 0
    }

    /// Sets [`Voxel::shares_cube`].
    fn mark_shared_cube(&mut self) {
        self.colour_sum[1] |= SHARED_CUBE_BIT;
    }

    /// Adds one point's colour to the sums (the caller keeps the count at most [`MAX_VOXEL_POINTS`]).
    pub fn add_colour(&mut self, rgb: [u8; 3]) {
        let [lo, hi] = self.colour_sum;
        let packed = (lo as u64 | (hi as u64) << 32)
            + (rgb[0] as u64 | (rgb[1] as u64) << COLOUR_SUM_BITS | (rgb[2] as u64) << (2 * COLOUR_SUM_BITS));
        self.colour_sum = [packed as u32, (packed >> 32) as u32];
    }

    /// Unit normal (dequantised).
    pub fn unit_normal(&self) -> Vec3 {
        self.normal.map(dequantise_unit)
    }
}

/// One supervoxel with its VCCS features.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct Supervoxel {
    /// Index of the seed voxel (the lowest voxel index for orphan components).
    pub seed: u16,
    /// Voxels claimed.
    pub voxels: u16,
    /// Points in those voxels.
    pub points: u32,
    /// Mean of the member voxel centroids, metres.
    pub centroid: Vec3,
    /// Mean member normal (unit).
    pub normal: Vec3,
    /// Mean member colour, [0, 1].
    pub colour: Vec3,
    reference: Vec3,
    acc_centroid: Vec3,
    acc_normal: Vec3,
    acc_colour: Vec3,
    /// Start of this supervoxel's voxels in the split-stage voxel order (stage 3).
    pub(crate) first: u16,
}

impl Supervoxel {
    fn start(seed: u16, v: &Voxel) -> Self {
        let mut sv = Supervoxel::zeroed();
        sv.seed = seed;
        sv.reference = v.centroid();
        sv.add(v);
        sv.finish_round();
        sv
    }

    fn add(&mut self, v: &Voxel) {
        self.voxels = self.voxels.saturating_add(1);
        self.points += v.count as u32;
        self.acc_centroid = linalg::add(self.acc_centroid, linalg::sub(v.centroid(), self.reference));
        self.acc_normal = linalg::add(self.acc_normal, v.unit_normal());
        self.acc_colour = linalg::add(self.acc_colour, v.colour());
    }

    fn finish_round(&mut self) {
        let k = 1.0 / self.voxels.max(1) as f32;
        self.centroid = linalg::add(self.reference, linalg::scale(self.acc_centroid, k));
        self.normal = linalg::normalize_or(self.acc_normal, self.normal);
        self.colour = linalg::scale(self.acc_colour, k);
    }
}

/// One cube of the seed grid while seeds are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct SeedCell {
    /// Packed cube key at `seed_resolution`.
    pub key: u32,
    /// Voxels whose centroid lies in the cube (0 = free slot).
    pub voxels: u16,
    /// Voxel nearest the cube centre so far.
    pub best: u16,
    /// Its squared distance to the centre, m².
    pub best_d2: f32,
}

/// Packs the integer cube coordinates of `p` at `resolution` and a mask `slot` (0–7) into 32 bits (x, y: 10 bits
/// each with an offset of 512; z: 9 bits; slot: the top 3 bits). `None` when outside the key range (a point
/// farther than 511 cubes). Slots keep the points of different instance masks in different voxels (see
/// [`crate::masks::MaskSet::voxel_slot`]); without masks every point is in slot 0.
#[inline]
pub fn voxel_key(p: Vec3, resolution: f32, slot: u32) -> Option<u32> {
    let [ix, iy, iz] = voxel_cube(p, resolution);
    pack(ix, iy, iz, slot)
}

/// The integer cube coordinates (x, y, z) of `p` at `resolution`, those [`voxel_key`] packs.
#[inline]
fn voxel_cube(p: Vec3, resolution: f32) -> [i32; 3] {
    p.map(|c| linalg::floor_i32(c / resolution))
}

/// Corner (minimum) of the cube with integer coordinates `cube`, metres: [`key_corner`] of its key.
#[inline]
fn cube_corner(cube: [i32; 3], resolution: f32) -> Vec3 {
    cube.map(|c| c as f32 * resolution)
}

#[inline]
fn pack(ix: i32, iy: i32, iz: i32, slot: u32) -> Option<u32> {
    let h = VOXEL_GRID_HALF_EXTENT;
    if ix < -h || ix > h || iy < -h || iy > h || !(0..=h).contains(&iz) || slot > 7 {
        return None;
    }
    Some((ix + 512) as u32 | ((iy + 512) as u32) << 10 | (iz as u32) << 20 | slot << SLOT_SHIFT)
}

/// Bit of a packed key where its mask slot starts.
const SLOT_SHIFT: u32 = 29;
/// The bits of a packed key below its mask slot: its cube.
const CUBE_BITS: u32 = (1 << SLOT_SHIFT) - 1;

/// The key of the cube of `cube_key` (a key of slot 0) in mask slot `slot`; `None` for a slot above 7.
#[inline]
fn in_slot(cube_key: u32, slot: u32) -> Option<u32> {
    (slot <= 7).then_some(cube_key | slot << SLOT_SHIFT)
}

/// Integer cube coordinates (x, y, z) of a packed key.
#[inline]
pub fn unpack(key: u32) -> (i32, i32, i32) {
    ((key & 0x3ff) as i32 - 512, ((key >> 10) & 0x3ff) as i32 - 512, ((key >> 20) & 0x1ff) as i32)
}

/// The mask slot of a packed key.
#[inline]
pub fn key_slot(key: u32) -> u32 {
    key >> SLOT_SHIFT
}

/// Corner (minimum) of the cube with `key`, metres.
#[inline]
pub fn key_corner(key: u32, resolution: f32) -> Vec3 {
    let (x, y, z) = unpack(key);
    cube_corner([x, y, z], resolution)
}

/// Index of the voxel with `key`, if occupied. Voxels are hashed by their cube alone (the key without its mask
/// slot, [`probe_voxel`]), so the voxels of one cube in different slots lie in one probe run.
#[inline(always)]
pub fn find_voxel(voxels: &[Voxel], slots: &[u16], key: u32) -> Option<usize> {
    pool::find_where(slots, key & CUBE_BITS, |i| voxels.get(i).map(|v| v.key) == Some(key))
}

/// Index of the first voxel, in probe order, of the cube of `cube_key` (a key of slot 0) in any mask slot.
#[inline(always)]
fn find_cube(voxels: &[Voxel], slots: &[u16], cube_key: u32) -> Option<usize> {
    pool::find_where(slots, cube_key, |i| voxels.get(i).is_some_and(|v| v.key & CUBE_BITS == cube_key))
}

/// [`pool::probe`] for a voxel `key` in the voxel hash: from the bucket of its cube (see [`find_voxel`]).
pub fn probe_voxel(voxels: &[Voxel], slots: &[u16], key: u32) -> Probe {
    pool::probe_hashed(slots, key & CUBE_BITS, key, |i| voxels.get(i).map(|v| v.key))
}

/// The 26 neighbour offsets (dx, dy, dz) in visiting order (z outermost, x innermost), each with the change it
/// makes to a packed key when no field leaves its range.
#[allow(clippy::indexing_slicing)] // evaluated at compile time: an out-of-range index would fail the build
const NEIGHBOURS: [([i32; 3], i32); 26] = {
    let mut out = [([0; 3], 0); 26];
    let (mut n, mut k) = (0, 0);
    while k < 27 {
        let (dx, dy, dz) = (k % 3 - 1, k / 3 % 3 - 1, k / 9 - 1);
        if k != 13 {
            out[n] = ([dx, dy, dz], dx + (dy << 10) + (dz << 20));
            n += 1;
        }
        k += 1;
    }
    out
};

/// Whether the cube (x, y, z) lies inside the key range with a margin of one: then every neighbour's key is its
/// key plus the fixed offset of [`NEIGHBOURS`].
#[inline(always)]
fn inside_key_range(x: i32, y: i32, z: i32) -> bool {
    let h = VOXEL_GRID_HALF_EXTENT;
    -h < x && x < h && -h < y && y < h && 0 < z && z < h
}

/// The direction opposite direction `d` (< 26) of [`NEIGHBOURS`]: its offsets are symmetric about the
/// centre, so direction d and 25 − d point opposite ways.
#[inline(always)]
const fn opposite(d: usize) -> usize {
    25usize.saturating_sub(d)
}

/// Every direction of [`NEIGHBOURS`] as a bit set: bit d for direction d.
const ALL_DIRECTIONS: u32 = (1 << 26) - 1;

/// Calls `f(j)` for each occupied voxel j among the 26 neighbours of the voxel with `key` (in its mask slot).
#[inline]
pub fn for_each_neighbour(voxels: &[Voxel], slots: &[u16], key: u32, mut f: impl FnMut(usize)) {
    for_each_neighbour_towards(voxels, slots, key, |_, j| f(j));
}

/// [`for_each_neighbour`], calling `f(bit, j)` with the bit of the direction d (`1 << d`, d an index into
/// [`NEIGHBOURS`]) of each occupied neighbour j.
#[inline(always)]
fn for_each_neighbour_towards(voxels: &[Voxel], slots: &[u16], key: u32, mut f: impl FnMut(u32, usize)) {
    let (x, y, z) = unpack(key);
    let mut visit = |bit: u32, k: u32| {
        if let Some(j) = find_voxel(voxels, slots, k) {
            f(bit, j);
        }
    };
    let mut bit = 1u32;
    if inside_key_range(x, y, z) {
        for &(_, delta) in &NEIGHBOURS {
            visit(bit, key.wrapping_add_signed(delta));
            bit <<= 1;
        }
    } else {
        let slot = key_slot(key);
        for &([dx, dy, dz], _) in &NEIGHBOURS {
            if let Some(k) = pack(x + dx, y + dy, z + dz, slot) {
                visit(bit, k);
            }
            bit <<= 1;
        }
    }
}

/// [`for_each_neighbour`] over the directions set in `directions` only (bit d for direction d), in the same
/// order: growth's walk through the hash, given the directions in which the normals found a neighbour, so that
/// the empty ones (57 % of them on cabinet frames) are not looked up again.
/// `f(d, j)` gets the direction d of each neighbour j too.
#[inline]
fn for_each_neighbour_among(
    voxels: &[Voxel],
    slots: &[u16],
    key: u32,
    directions: u32,
    mut f: impl FnMut(usize, usize),
) {
    let (x, y, z) = unpack(key);
    let inside = inside_key_range(x, y, z);
    let mut bits = directions & ALL_DIRECTIONS;
    while bits != 0 {
        let d = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        // `neighbour_key`'s key, with the cube and its range test worked out once per voxel (through a shared
        // helper taking them, the Cortex-M7's growth took 0.06 M instructions more per frame).
        let Some(&([dx, dy, dz], delta)) = NEIGHBOURS.get(d) else { continue };
        let k = if inside { Some(key.wrapping_add_signed(delta)) } else { pack(x + dx, y + dy, z + dz, key_slot(key)) };
        if let Some(j) = k.and_then(|k| find_voxel(voxels, slots, k)) {
            f(d, j);
        }
    }
}

/// The index and record of the voxel of mask slot `slot` that a camera-frame point (metres) falls into, if
/// that voxel is occupied.
#[inline]
pub fn voxel_at<'v>(
    voxels: &'v [Voxel],
    slots: &[u16],
    p: Vec3,
    resolution: f32,
    slot: u32,
) -> Option<(usize, &'v Voxel)> {
    let i = voxel_key(p, resolution, slot).and_then(|k| find_voxel(voxels, slots, k))?;
    voxels.get(i).map(|v| (i, v))
}

/// The mask slot of a point at pixel (u, v): from `masks` when the voxels were made with them (see
/// [`voxelize`]), else 0.
#[inline]
pub fn point_slot(masks: Option<&MaskSet<'_>>, params: &Params, u: u16, v: u16, cache: &mut SlotCache) -> u32 {
    masks.map_or(0, |m| m.voxel_slot_cached(u, v, params.min_confidence, cache))
}

/// [`point_slot`] as a call of its own: the superquadric stage's window pass, whose callback the Cortex-M7 build
/// inlines less well with the lookup inlined (measured: 0.6 M instructions more per cabinet frame).
#[inline(never)]
fn point_slot_called(masks: Option<&MaskSet<'_>>, params: &Params, u: u16, v: u16, cache: &mut SlotCache) -> u32 {
    point_slot(masks, params, u, v, cache)
}

/// One sampled point as voxelisation met it: its position, its pixel and the voxel it fell into. The list of a
/// frame's points in pixel order lets every later pass visit them without sampling, back-projecting and hashing
/// them again ([`for_each_voxel_point`]); a profile without room for it (the `mcu` one) re-derives them.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct SampledPoint {
    /// Camera-frame position, metres (as [`points::Point::from_pixel`] back-projected it).
    pub xyz: Vec3,
    /// Pixel column, pixels.
    pub u: u16,
    /// Pixel row, pixels.
    pub v: u16,
    /// Index of its voxel, or [`NO_VOXEL`] when it found none (pool or hash full, outside the key range).
    pub voxel: u16,
}

/// [`SampledPoint::voxel`] of a point without a voxel.
pub const NO_VOXEL: u16 = u16::MAX;

/// Where a pass after voxelisation finds the frame's sampled points and their voxels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Revisit<'a> {
    /// Voxelisation's complete list of the frame's points ([`SampledPoint`]).
    Listed(&'a [SampledPoint]),
    /// The points are sampled, back-projected and hashed again. `by_cube` (only when voxelisation marked the
    /// shared cubes, [`VoxelStats::shared_cubes_marked`], and every sampled point of this frame found its voxel,
    /// [`VoxelStats::unplaced_points`] 0; the frame the one voxelised, with the same range and voxel edge): a
    /// point whose cube has one voxel only is in it whatever its mask slot, and
    /// only the points of cubes shared by several slots ([`Voxel::shares_cube`]) look their slot up in the
    /// masks (measured on the Cortex-M7: a bit-plane slot lookup is about 45 instructions a point).
    Resampled {
        /// Whether the points may find their voxel by their cube first.
        by_cube: bool,
    },
}

/// Calls `f(point, voxel)` for every sampled point of `frame` with the index and record of the voxel it fell
/// into (`None` when it found no voxel: pool full or outside the key range). `masks` must be the ones the
/// voxels were made with. `revisit`: how the points and their voxels are found again ([`Revisit`]) — the same
/// points, voxels and order either way. The one way every stage after voxelisation revisits the points. The
/// points carry no colour (`rgb` is `[0, 0, 0]`): the voxels keep it.
pub fn for_each_voxel_point(
    frame: &Frame<'_>,
    params: &Params,
    masks: Option<&MaskSet<'_>>,
    voxels: &[Voxel],
    slots: &[u16],
    revisit: Revisit<'_>,
    f: impl FnMut(&points::Point, Option<(usize, &Voxel)>),
) {
    for_each_voxel_point_in(frame, params, masks, voxels, slots, revisit, points::PixelWindow::WHOLE, f);
}

/// [`for_each_voxel_point`] over the pixels of `window` only (the same points in the same order as the
/// whole-image pass gives there).
#[allow(clippy::too_many_arguments)]
pub fn for_each_voxel_point_in(
    frame: &Frame<'_>,
    params: &Params,
    masks: Option<&MaskSet<'_>>,
    voxels: &[Voxel],
    slots: &[u16],
    revisit: Revisit<'_>,
    window: points::PixelWindow,
    f: impl FnMut(&points::Point, Option<(usize, &Voxel)>),
) {
    // Two functions, each calling `f` once, so that each inlines it (the pass over the pixels is the code
    // the mcu profile runs, instruction for instruction).
    match revisit {
        Revisit::Listed(list) => for_each_listed_point(voxels, list, window, f),
        Revisit::Resampled { by_cube } => {
            // Without masks every point is in slot 0: the cube is the key.
            let by_cube = by_cube && masks.is_some();
            for_each_resampled_point(frame, params, masks, voxels, slots, window, by_cube, f)
        }
    }
}

/// [`for_each_voxel_point_in`] from voxelisation's list of the frame's points.
fn for_each_listed_point(
    voxels: &[Voxel],
    list: &[SampledPoint],
    window: points::PixelWindow,
    mut f: impl FnMut(&points::Point, Option<(usize, &Voxel)>),
) {
    // The list is in pixel order: start at the window's first row, stop after its last.
    let first = list.partition_point(|s| s.v < window.v0);
    for s in list.get(first..).unwrap_or(&[]) {
        if s.v > window.v1 {
            break;
        }
        if s.u < window.u0 || s.u > window.u1 {
            continue;
        }
        // The listed position (no division again); no colour (the voxels keep it).
        let p = points::Point { u: s.u, v: s.v, xyz: s.xyz, rgb: [0; 3] };
        f(&p, voxels.get(s.voxel as usize).map(|v| (s.voxel as usize, v)));
    }
}

/// [`for_each_voxel_point_in`] by sampling, back-projecting and hashing the points again; `by_cube`: see
/// [`Revisit::Resampled`].
#[allow(clippy::too_many_arguments)]
fn for_each_resampled_point(
    frame: &Frame<'_>,
    params: &Params,
    masks: Option<&MaskSet<'_>>,
    voxels: &[Voxel],
    slots: &[u16],
    window: points::PixelWindow,
    by_cube: bool,
    mut f: impl FnMut(&points::Point, Option<(usize, &Voxel)>),
) {
    let r = params.voxel_resolution;
    let mut slot_cache = SlotCache::default();
    if window != points::PixelWindow::WHOLE {
        // A window's pass (the superquadric stage's) without the last voxel: with it the Cortex-M7 took 0.8 M
        // instructions more per cabinet frame there (its callback no longer inlined), for 1.0 M less in the
        // whole-image pass of the Gaussians.
        points::for_each_position_in(frame, params, window, |p| {
            let i = if by_cube {
                voxel_key(p.xyz, r, 0).and_then(|cube| {
                    let first = find_cube(voxels, slots, cube);
                    voxel_by_cube(voxels, slots, cube, first, || {
                        point_slot_called(masks, params, p.u, p.v, &mut slot_cache)
                    })
                })
            } else {
                let slot = point_slot_called(masks, params, p.u, p.v, &mut slot_cache);
                voxel_key(p.xyz, r, slot).and_then(|k| find_voxel(voxels, slots, k))
            };
            f(p, i.and_then(|i| voxels.get(i).map(|v| (i, v))));
        });
        return;
    }
    let mut last = LastVoxel::default();
    points::for_each_position_in(frame, params, window, |p| {
        let i = if by_cube {
            // The last voxel is kept by cube: the first voxel of the cube in probe order.
            voxel_key(p.xyz, r, 0).and_then(|cube| {
                let first = last.find(cube, |c| find_cube(voxels, slots, c));
                voxel_by_cube(voxels, slots, cube, first, || point_slot(masks, params, p.u, p.v, &mut slot_cache))
            })
        } else {
            let slot = point_slot(masks, params, p.u, p.v, &mut slot_cache);
            voxel_key(p.xyz, r, slot).and_then(|k| last.find(k, |k| find_voxel(voxels, slots, k)))
        };
        f(p, i.and_then(|i| voxels.get(i).map(|v| (i, v))));
    });
}

/// The voxel of a point in the cube of `cube_key` (a key of slot 0) whose first voxel in probe order is `first`
/// ([`find_cube`]), by cube first ([`Revisit::Resampled`]): that voxel unless its cube is shared by several mask
/// slots, then the voxel of the point's own slot, `slot()`, which is looked up only then.
#[inline(always)]
fn voxel_by_cube(
    voxels: &[Voxel],
    slots: &[u16],
    cube_key: u32,
    first: Option<usize>,
    slot: impl FnOnce() -> u32,
) -> Option<usize> {
    let i = first?;
    if !voxels.get(i)?.shares_cube() {
        return Some(i);
    }
    in_slot(cube_key, slot()).and_then(|k| find_voxel(voxels, slots, k))
}

/// The voxel the previous point of a pass fell into: the next point of its row is in it 41 % of the time
/// (cabinet frame 1), and then the hash lookup is skipped. Only a voxel that was found is kept.
#[derive(Debug, Clone, Copy, Default)]
struct LastVoxel {
    /// Its key and index.
    hit: Option<(u32, usize)>,
}

impl LastVoxel {
    /// The index of the voxel with `key`: the kept one when the key is its, else `lookup(key)` (kept when found).
    #[inline(always)]
    fn find(&mut self, key: u32, lookup: impl FnOnce(u32) -> Option<usize>) -> Option<usize> {
        match self.hit {
            Some((k, i)) if k == key => Some(i),
            _ => {
                let i = lookup(key)?;
                self.hit = Some((key, i));
                Some(i)
            }
        }
    }
}

/// Counts of the voxel stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VoxelStats {
    /// Sampled in-range points.
    pub points: u32,
    /// Points that found no voxel (pool or hash full, voxel count saturated, or outside the key range).
    pub dropped_points: u32,
    /// Inserts refused because every hash slot was taken.
    pub slot_overflows: u32,
    /// Points in the key range that found no voxel (pool or hash full); of `dropped_points`. While it is 0 every
    /// point of the frame is in a voxel of its own cube and mask slot ([`Revisit::Resampled`]).
    pub unplaced_points: u32,
    /// Whether the voxels that share their cube with another mask slot's are marked ([`Voxel::shares_cube`]);
    /// not when the frame came without masks or every point is listed ([`SampledPoint`]).
    pub shared_cubes_marked: bool,
    /// Whether a sampled point of a usable instance (id-image masks) lay outside that instance's bounding box
    /// ([`SlotCache::saw_pixel_outside_box`]).
    pub mask_pixels_outside_boxes: bool,
}

/// Builds the voxel sums of `frame` (stage 1 and the first half of stage 2).
/// Sums the sampled points of `frame` into voxels; with `masks`, the points of each instance mask (score ≥
/// `min_confidence`) and those outside every mask go to separate voxels (mask slots), so no voxel, supervoxel
/// or Gaussian mixes an object with what it touches (an m2smap extension for the semantic-fusion variants).
/// Lists every sampled point with its voxel in `sampled` (when it has room; see [`SampledPoint`]).
pub fn voxelize(
    frame: &Frame<'_>,
    params: &Params,
    masks: Option<&MaskSet<'_>>,
    voxels: &mut Bounded<'_, Voxel>,
    slots: &mut [u16],
    sampled: &mut Bounded<'_, SampledPoint>,
) -> VoxelStats {
    voxels.clear();
    slots.fill(0);
    sampled.clear();
    // A profile without a list (capacity 0) skips it, in a loop of its own (the mcu profile's code).
    if sampled.capacity() > 0 {
        add_points::<true>(frame, params, masks, voxels, slots, sampled)
    } else {
        add_points::<false>(frame, params, masks, voxels, slots, sampled)
    }
}

/// The point loop of [`voxelize`]; `LIST`: record each point in `sampled`.
fn add_points<const LIST: bool>(
    frame: &Frame<'_>,
    params: &Params,
    masks: Option<&MaskSet<'_>>,
    voxels: &mut Bounded<'_, Voxel>,
    slots: &mut [u16],
    sampled: &mut Bounded<'_, SampledPoint>,
) -> VoxelStats {
    let r = params.voxel_resolution;
    let mut stats = VoxelStats::default();
    let max_index = (DROPPED as usize).min(slots.len());
    let mut slot_cache = SlotCache::default();
    let mut last = LastVoxel::default();
    points::for_each_point(frame, params, |p| {
        stats.points += 1;
        let slot = point_slot(masks, params, p.u, p.v, &mut slot_cache);
        let voxel = add_point(p, r, max_index, slot, voxels, slots, &mut last, &mut stats);
        if LIST {
            let _ =
                sampled.push(SampledPoint { xyz: p.xyz, u: p.u, v: p.v, voxel: voxel.map_or(NO_VOXEL, |i| i as u16) });
        }
    });
    stats.mask_pixels_outside_boxes = slot_cache.saw_pixel_outside_box();
    // The marks serve the passes that sample again only: a complete list of the points spares them.
    let listed = LIST && sampled.usage().overflow_events == 0;
    if masks.is_some() && !listed {
        mark_shared_cubes(voxels.as_mut_slice(), slots);
        stats.shared_cubes_marked = true;
    }
    // Every point is in: each voxel's sum of offsets becomes its mean.
    for v in voxels.as_mut_slice() {
        let corner = key_corner(v.key, r);
        v.mean = linalg::add(corner, linalg::scale(v.mean, 1.0 / (v.count.max(1)) as f32));
    }
    stats
}

/// Adds point `p` (mask slot `slot`) to its voxel, made when new; returns the index of the voxel it belongs to
/// as a later lookup finds it ([`voxel_at`]): also a voxel at [`MAX_VOXEL_POINTS`] that refused it.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn add_point(
    p: &points::Point,
    r: f32,
    max_index: usize,
    slot: u32,
    voxels: &mut Bounded<'_, Voxel>,
    slots: &mut [u16],
    last: &mut LastVoxel,
    stats: &mut VoxelStats,
) -> Option<usize> {
    let cube = voxel_cube(p.xyz, r);
    let Some(key) = pack(cube[0], cube[1], cube[2], slot) else {
        stats.dropped_points += 1;
        return None;
    };
    let index = last.find(key, |key| probe_or_insert(key, max_index, voxels, slots, stats));
    let Some(v) = index.and_then(|i| voxels.get_mut(i)) else {
        stats.dropped_points += 1;
        stats.unplaced_points += 1;
        return None;
    };
    if v.count >= MAX_VOXEL_POINTS {
        stats.dropped_points += 1;
        return index;
    }
    // The cube's corner from the coordinates the key was packed from, not unpacked from the key again.
    let corner = cube_corner(cube, r);
    v.count += 1;
    v.mean = linalg::add(v.mean, linalg::sub(p.xyz, corner));
    v.add_colour(p.rgb);
    index
}

/// The index of the voxel with `key`, made (in the pool and the hash) when new; `None` when the pool or the hash
/// is full (a full hash counted in `stats`).
#[inline(always)]
fn probe_or_insert(
    key: u32,
    max_index: usize,
    voxels: &mut Bounded<'_, Voxel>,
    slots: &mut [u16],
    stats: &mut VoxelStats,
) -> Option<usize> {
    // [`probe_voxel`], on the pool itself: through its slice the Cortex-M7's voxel stage took 1.0 M
    // instructions more per cabinet frame.
    match pool::probe_hashed(slots, key & CUBE_BITS, key, |i| voxels.get(i).map(|v| v.key)) {
        Probe::Found(i) => Some(i),
        Probe::Vacant(pos) => {
            let mut v = Voxel::zeroed();
            v.key = key;
            v.supervoxel = UNLABELLED;
            v.gaussian = UNLABELLED;
            match voxels.push(v) {
                Some(i) if i < max_index => {
                    if let Some(s) = slots.get_mut(pos) {
                        *s = (i + 1) as u16;
                    }
                    Some(i)
                }
                Some(_) => {
                    voxels.pop();
                    None
                }
                None => None,
            }
        }
        Probe::Full => {
            stats.slot_overflows += 1;
            None
        }
    }
}

/// Marks every voxel whose cube has voxels in other mask slots too ([`Voxel::shares_cube`]). Such a cube has a
/// voxel outside slot 0, and the voxels of one cube lie in one probe run ([`find_voxel`]): each voxel of a slot
/// above 0 looks through its run for the others.
fn mark_shared_cubes(voxels: &mut [Voxel], slots: &[u16]) {
    for i in 0..voxels.len() {
        let Some(&v) = voxels.get(i) else { continue };
        if key_slot(v.key) == 0 || v.shares_cube() {
            continue;
        }
        let cube = v.key & CUBE_BITS;
        // The other voxels of the cube: at most one per other slot.
        let (mut others, mut n) = ([0u16; 8], 0);
        let _ = pool::find_where(slots, cube, |j| {
            if j != i && voxels.get(j).is_some_and(|o| o.key & CUBE_BITS == cube) {
                if let Some(o) = others.get_mut(n) {
                    *o = j as u16;
                    n += 1;
                }
            }
            false // the whole run
        });
        if n > 0 {
            for &j in others.get(..n).unwrap_or(&[]).iter().chain(&[i as u16]) {
                if let Some(o) = voxels.get_mut(j as usize) {
                    o.mark_shared_cube();
                }
            }
        }
    }
}

/// A voxel's occupied 26-neighbours, found once per frame by [`compute_normals`] where the profile has room (the
/// `host` one; 56 bytes per voxel), so that neither the normals nor supervoxel growth look neighbours up in the
/// hash again ([`for_each_neighbour`] gives the same indices in the same order).
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct VoxelLinks {
    /// Index of the occupied neighbour in each of the 26 directions of [`for_each_neighbour`]'s order (where
    /// the direction's bit of `occupied` is set).
    pub neighbours: [u16; 26],
    /// Bit d set when direction d has a neighbour.
    pub occupied: u32,
}

impl VoxelLinks {
    /// Calls `f(j)` for each occupied neighbour `j`, in direction order.
    #[inline]
    pub fn for_each(&self, mut f: impl FnMut(usize)) {
        let mut bits = self.occupied;
        while bits != 0 {
            if let Some(&j) = self.neighbours.get(bits.trailing_zeros() as usize) {
                f(j as usize);
            }
            bits &= bits - 1;
        }
    }
}

/// The key of the neighbour in direction `d` (an index into the 26 neighbour offsets) of the voxel with `key`, as
/// [`for_each_neighbour`] forms it; `None` outside the key range.
#[inline]
fn neighbour_key(key: u32, d: usize) -> Option<u32> {
    let &([dx, dy, dz], delta) = NEIGHBOURS.get(d)?;
    let (x, y, z) = unpack(key);
    if inside_key_range(x, y, z) {
        Some(key.wrapping_add_signed(delta))
    } else {
        pack(x + dx, y + dy, z + dz, key_slot(key))
    }
}

/// Calls `f(j)` for each occupied 26-neighbour `j` of voxel `i` (key `key`), in [`for_each_neighbour`]'s order:
/// from `links` (complete for this frame's voxels) when `LINKED`, else through the hash.
#[inline(always)]
pub fn for_each_linked_neighbour<const LINKED: bool>(
    voxels: &[Voxel],
    slots: &[u16],
    links: &[VoxelLinks],
    i: usize,
    key: u32,
    f: impl FnMut(usize),
) {
    if LINKED {
        if let Some(l) = links.get(i) {
            l.for_each(f);
        }
    } else {
        for_each_neighbour(voxels, slots, key, f);
    }
}

/// Fills `links` (at least one per voxel) with each voxel's neighbours. Direction d of the 26
/// offsets and direction 25 − d are opposite, so each pair of neighbours is looked up once, from the voxel that
/// sees the other in one of the 13 directions d ≥ 13.
fn link_voxels(voxels: &[Voxel], slots: &[u16], links: &mut [VoxelLinks]) {
    for l in links.iter_mut().take(voxels.len()) {
        *l = VoxelLinks { neighbours: [NO_VOXEL; 26], occupied: 0 };
    }
    for (i, v) in voxels.iter().enumerate() {
        for d in 13..26 {
            let Some(j) = neighbour_key(v.key, d).and_then(|k| find_voxel(voxels, slots, k)) else { continue };
            for (a, b, e) in [(i, j, d), (j, i, opposite(d))] {
                if let Some(l) = links.get_mut(a) {
                    if let Some(slot) = l.neighbours.get_mut(e) {
                        *slot = b as u16;
                        l.occupied |= 1 << e;
                    }
                }
            }
        }
    }
}

/// Computes every voxel's normal from its 27-neighbourhood of centroids. When `links` holds an entry per
/// voxel, it first records each voxel's neighbours there ([`VoxelLinks`]) and returns true.
pub fn compute_normals(voxels: &mut [Voxel], slots: &[u16], links: &mut [VoxelLinks]) -> bool {
    if links.len() < voxels.len() {
        for i in 0..voxels.len() {
            let Some(&v) = voxels.get(i) else { continue };
            let c = v.centroid();
            let mut m = Moments::about(c);
            m.add(c, 1.0);
            let mut occupied = 0u32;
            for_each_neighbour_towards(voxels, slots, v.key, |bit, j| {
                occupied |= bit;
                if let Some(n) = voxels.get(j) {
                    m.add(n.centroid(), 1.0);
                }
            });
            set_normal(voxels, i, c, &m);
            if let Some(v) = voxels.get_mut(i) {
                set_occupied_directions(v, occupied);
            }
        }
        return false;
    }
    link_voxels(voxels, slots, links);
    for (i, own) in links.iter().enumerate().take(voxels.len()) {
        let Some(c) = voxels.get(i).map(Voxel::centroid) else { continue };
        let mut m = Moments::about(c);
        m.add(c, 1.0);
        own.for_each(|j| {
            if let Some(n) = voxels.get(j) {
                m.add(n.centroid(), 1.0);
            }
        });
        set_normal(voxels, i, c, &m);
    }
    true
}

/// Keeps the directions in which [`compute_normals`] found a neighbour (bit d for direction d of [`NEIGHBOURS`])
/// in the voxel's `gaussian` (bits 0–15) and `supervoxel` (bits 16–25) fields, which nothing reads between the
/// normals and supervoxel growth; growth takes them from there ([`occupied_directions`]).
#[inline]
fn set_occupied_directions(v: &mut Voxel, occupied: u32) {
    v.gaussian = occupied as u16;
    v.supervoxel = (occupied >> 16) as u16;
}

/// The directions [`set_occupied_directions`] kept in `v`. [`voxelize`] leaves both fields at [`UNLABELLED`],
/// which reads as every direction: growth without the normals before it still visits every neighbour.
#[inline]
fn occupied_directions(v: &Voxel) -> u32 {
    (v.gaussian as u32 | (v.supervoxel as u32) << 16) & ALL_DIRECTIONS
}

/// Sets voxel `i`'s normal from the moments `m` of its neighbourhood's centroids (`c` its own), turned towards
/// the camera.
#[inline(always)]
fn set_normal(voxels: &mut [Voxel], i: usize, c: Vec3, m: &Moments) {
    let towards_camera = linalg::normalize_or(linalg::scale(c, -1.0), [0.0, 0.0, -1.0]);
    let mut n = if m.weight >= 3.0 {
        let cov = m.covariance();
        linalg::least_variance_direction(cov).unwrap_or_else(|| linalg::sym_eigen(cov).normal())
    } else {
        towards_camera
    };
    if linalg::dot(n, c) > 0.0 {
        n = linalg::scale(n, -1.0);
    }
    if let Some(v) = voxels.get_mut(i) {
        v.normal = [quantise_unit(n[0]), quantise_unit(n[1]), quantise_unit(n[2])];
    }
}

/// A component stored by [`quantise_unit`], back in [−1, 1].
#[inline]
pub fn dequantise_unit(q: i16) -> f32 {
    q as f32 * (1.0 / 32767.0)
}

/// A unit-vector component `x` (clamped to [−1, 1]) in units of 1/32767, rounded half away from zero: the same
/// result as `libm::roundf(x · 32767) as i16` (NaN gives 0), without its general path. Voxel normals and the
/// segmenter's cell normals are stored this way.
#[inline]
pub fn quantise_unit(x: f32) -> i16 {
    let y = x.clamp(-1.0, 1.0) * 32767.0;
    // |y| ≤ 32767: the cast truncates towards zero, and y minus its integer part is exact.
    let t = y as i32;
    let frac = y - t as f32;
    (t + i32::from(frac >= 0.5) - i32::from(frac <= -0.5)) as i16
}

/// Counts of the supervoxel stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SupervoxelStats {
    /// Seeds placed.
    pub seeds: u32,
    /// Growth rounds run.
    pub rounds: u32,
    /// Supervoxels made from unseeded components.
    pub orphan_supervoxels: u32,
    /// Points in outlier clusters.
    pub outlier_points: u32,
    /// Points whose supervoxel did not fit the pool.
    pub dropped_points: u32,
}

/// Growth's state of a voxel, bits 0–1 of its scratch entry: not reached yet.
const UNTOUCHED: u16 = 0;
/// Reached in this round: it joins the supervoxel in its `supervoxel` field at the round's end.
const CANDIDATE: u16 = 1;
/// Claimed in the last round: its neighbours are visited in this one.
const FRONTIER: u16 = 2;
/// Claimed in an earlier round, its neighbours visited.
const CLAIMED: u16 = 3;
/// The bits of the growth state.
const GROWTH_STATE: u16 = 3;
/// Where a growth scratch entry keeps the upper 10 of its voxel's occupied directions (above the state).
const DIRECTIONS_AT: u16 = 2;

/// A voxel's scratch entry at the start of growth without links: state [`UNTOUCHED`], and the directions 16–25
/// the normals kept ([`occupied_directions`]), whose `supervoxel` field growth takes over.
#[inline]
fn growth_entry(v: &Voxel) -> u16 {
    ((occupied_directions(v) >> 16) as u16) << DIRECTIONS_AT
}

/// The occupied directions of a voxel during growth without links: bits 0–15 still in its `gaussian` field, 16–25
/// in its scratch entry `st` ([`growth_entry`]).
#[inline]
fn growth_directions(v: &Voxel, st: u16) -> u32 {
    v.gaussian as u32 | ((st >> DIRECTIONS_AT) as u32) << 16
}

/// Drops direction `d` from voxel `j`'s occupied directions during growth without links ([`growth_directions`]).
#[inline(always)]
fn forget_direction(voxels: &mut [Voxel], scratch: &mut [u16], j: usize, d: u8) {
    if d < 16 {
        if let Some(v) = voxels.get_mut(j) {
            v.gaussian &= !(1u16 << d);
        }
    } else if let Some(s) = scratch.get_mut(j) {
        *s &= !(1u16 << ((d - 16) as u16 + DIRECTIONS_AT).min(15));
    }
}

/// Voxels of the mcu profile's pool: growth keeps one bit per voxel for them ([`GrowthMarks`]).
const GROWTH_MARKED_VOXELS: usize = crate::profile::MCU_VOXELS;

/// The voxels growth visits next (the frontier and this round's candidates), one bit per voxel index on the
/// stack (1 088 bytes for the mcu profile's 8 704 voxels), so that a round's passes skip 32 voxels at a time
/// instead of testing each one's state. A frame with more voxels than bits marks none and visits every index.
struct GrowthMarks {
    words: [u32; GROWTH_MARKED_VOXELS.div_ceil(32)],
    /// Every index counts as marked.
    every: bool,
}

impl GrowthMarks {
    /// No voxel of `n` marked (every one when they are more than the bits).
    fn new(n: usize) -> Self {
        GrowthMarks { words: [0; GROWTH_MARKED_VOXELS.div_ceil(32)], every: n > GROWTH_MARKED_VOXELS }
    }

    /// Marks voxel `i`.
    #[inline(always)]
    fn set(&mut self, i: usize) {
        if let Some(w) = self.words.get_mut(i / 32) {
            *w |= 1 << (i % 32);
        }
    }

    /// Unmarks voxel `i`.
    #[inline(always)]
    fn clear(&mut self, i: usize) {
        if let Some(w) = self.words.get_mut(i / 32) {
            *w &= !(1 << (i % 32));
        }
    }

    /// The first marked voxel index at or after `from` below `n`.
    #[inline(always)]
    fn next(&self, from: usize, n: usize) -> Option<usize> {
        if self.every {
            return (from < n).then_some(from);
        }
        let mut k = from / 32;
        let mut word = self.words.get(k)? & (u32::MAX << (from % 32));
        while word == 0 {
            k += 1;
            word = *self.words.get(k)?;
        }
        let i = 32 * k + word.trailing_zeros() as usize;
        (i < n).then_some(i)
    }
}

/// Most growth rounds, whatever the resolutions.
const MAX_GROWTH_ROUNDS: u16 = 0x7ffe;

/// Storage the supervoxel stage works in.
pub struct SupervoxelPools<'a, 'b> {
    /// The voxels of the frame (labels are written).
    pub voxels: &'a mut [Voxel],
    /// The voxel hash slots.
    pub slots: &'a [u16],
    /// One stamp per voxel (at least as long as `voxels`).
    pub scratch: &'a mut [u16],
    /// Seed-cell table.
    pub seeds: &'a mut Bounded<'b, SeedCell>,
    /// Output supervoxels.
    pub supervoxels: &'a mut Bounded<'b, Supervoxel>,
    /// The frame's [`VoxelLinks`] when [`compute_normals`] recorded them for every voxel.
    pub links: Option<&'a [VoxelLinks]>,
}

/// Grows the supervoxels of the voxels (second half of stage 2). Labels every voxel.
pub fn build_supervoxels(pools: SupervoxelPools<'_, '_>, params: &Params) -> SupervoxelStats {
    // Growth with the links or through the hash, each compiled on its own (the latter is the mcu profile's).
    match pools.links {
        Some(links) => grow::<true>(pools, links, params),
        None => grow::<false>(pools, &[], params),
    }
}

/// [`build_supervoxels`]; `LINKED`: neighbours from `links`.
fn grow<const LINKED: bool>(pools: SupervoxelPools<'_, '_>, links: &[VoxelLinks], params: &Params) -> SupervoxelStats {
    let SupervoxelPools { voxels, slots, scratch, seeds, supervoxels, links: _ } = pools;
    let mut stats = SupervoxelStats::default();
    supervoxels.clear();
    let n = voxels.len().min(scratch.len());
    // Each scratch entry: the voxel's growth state in bits 0–1, and without links the upper 10 of its occupied
    // directions (the lower 16 stay in its `gaussian` field, which growth does not use).
    for (i, v) in voxels.iter_mut().enumerate() {
        if let Some(st) = scratch.get_mut(i) {
            *st = if LINKED { UNTOUCHED } else { growth_entry(v) };
        }
        v.supervoxel = UNLABELLED;
    }
    let scratch = match scratch.get_mut(..n) {
        Some(s) => s,
        None => return stats,
    };
    let set_state = |st: &mut u16, state: u16| *st = (*st & !GROWTH_STATE) | state;
    let mut marks = GrowthMarks::new(n);

    // --- seeds: nearest voxel to the centre of each sufficiently occupied seed cube --------------------------
    choose_seed_cells(voxels, seeds, params);
    // A voxel is a seed when it is the best voxel of a cell with enough voxels (each voxel lies in one cell):
    // marked in the scratch, then started in voxel order.
    for cell in seeds.as_slice().iter().filter(|s| s.voxels > 0 && s.voxels >= params.seed_min_voxels) {
        if let Some(st) = scratch.get_mut(cell.best as usize) {
            set_state(st, FRONTIER);
        }
    }
    for i in 0..n {
        if scratch.get(i).map(|st| st & GROWTH_STATE) != Some(FRONTIER) {
            continue;
        }
        let Some(v) = voxels.get(i).copied() else { continue };
        match supervoxels.push(Supervoxel::start(i as u16, &v)) {
            Some(id) => {
                if let Some(vox) = voxels.get_mut(i) {
                    vox.supervoxel = id as u16;
                }
                marks.set(i);
                stats.seeds += 1;
            }
            None => {
                if let Some(st) = scratch.get_mut(i) {
                    set_state(st, UNTOUCHED);
                }
            }
        }
    }

    // --- flow-constrained growth in rounds ------------------------------------------------------------------
    let max_rounds = libm::ceilf(1.8 * params.seed_resolution / params.voxel_resolution) as u32;
    let max_rounds = max_rounds.min(MAX_GROWTH_ROUNDS as u32) as u16;
    let w_c = params.color_importance;
    let w_s = params.spatial_importance / (3.0 * params.seed_resolution * params.seed_resolution);
    let w_n = params.normal_importance;
    // VCCS distance of voxel `j` (centroid, normal, colour) to supervoxel `label`'s features of the last round.
    let distance = |supervoxels: &Bounded<'_, Supervoxel>, (c, nv, col): (Vec3, Vec3, Vec3), label: u16| {
        let sv = supervoxels.get(label as usize)?;
        let dc = linalg::sub(col, sv.colour);
        let ds = linalg::sub(c, sv.centroid);
        let dn = 1.0 - linalg::dot(nv, sv.normal);
        Some(w_c * linalg::dot(dc, dc) + w_s * linalg::dot(ds, ds) + w_n * dn * dn)
    };
    // A frontier voxel's neighbours and the directions back from them to it, `around[..k]`: one array for all
    // of them (cleared for each, it was a `memclr` call per voxel).
    let mut around = [(0u16, 0u8); 26];
    for round in 2..=max_rounds.saturating_add(1) {
        // Pass A: every untouched neighbour of last round's voxels (the frontier) is a candidate of this round,
        // and takes the nearest (VCCS distance; ties: lower index) of the supervoxels of those voxels around it,
        // kept in its `supervoxel` field while it is a candidate. Those are all its labelled neighbours: a voxel
        // next to one claimed earlier was claimed the round after.
        let mut candidates = 0u32;
        let mut from = 0;
        while let Some(i) = marks.next(from, n) {
            from = i + 1;
            let Some(st) = scratch.get(i).copied() else { continue };
            if st & GROWTH_STATE != FRONTIER {
                continue;
            }
            marks.clear(i);
            let Some(v) = voxels.get(i) else { continue };
            let (key, label) = (v.key, v.supervoxel);
            let mut k = 0;
            let mut keep = |d: usize, j: usize| {
                if let Some(a) = around.get_mut(k) {
                    *a = (j as u16, opposite(d) as u8);
                    k += 1;
                }
            };
            if LINKED {
                // (With links no direction is dropped: the one passed is not read.)
                for_each_linked_neighbour::<true>(voxels, slots, links, i, key, |j| keep(0, j));
            } else {
                for_each_neighbour_among(voxels, slots, key, growth_directions(v, st), &mut keep);
            }
            if let Some(s) = scratch.get_mut(i) {
                set_state(s, CLAIMED);
            }
            for &(j, back) in around.get(..k).unwrap_or(&[]) {
                let j = j as usize;
                // Without links, j's walk will not look this voxel up again: claimed now, it would change
                // nothing there (each neighbour pair is looked up once, from the side claimed first).
                if !LINKED {
                    forget_direction(voxels, scratch, j, back);
                }
                let (Some(&v), Some(&st)) = (voxels.get(j), scratch.get(j)) else { continue };
                let take = match st & GROWTH_STATE {
                    UNTOUCHED => {
                        if let Some(s) = scratch.get_mut(j) {
                            set_state(s, CANDIDATE);
                        }
                        marks.set(j);
                        candidates += 1;
                        true
                    }
                    CANDIDATE if label != v.supervoxel => {
                        let f = (v.centroid(), v.unit_normal(), v.colour());
                        match (distance(supervoxels, f, label), distance(supervoxels, f, v.supervoxel)) {
                            (Some(d2), Some(bd)) => d2 < bd || (d2 == bd && label < v.supervoxel),
                            _ => false,
                        }
                    }
                    _ => false,
                };
                if let (true, Some(v)) = (take, voxels.get_mut(j)) {
                    v.supervoxel = label;
                }
            }
        }
        if candidates == 0 {
            break;
        }
        stats.rounds = round as u32 - 1;
        // Pass B: each candidate joins the supervoxel pass A chose, in voxel order, and is the next frontier.
        let mut from = 0;
        while let Some(i) = marks.next(from, n) {
            from = i + 1;
            let Some(st) = scratch.get_mut(i) else { continue };
            if *st & GROWTH_STATE != CANDIDATE {
                continue;
            }
            set_state(st, FRONTIER);
            let Some(v) = voxels.get(i) else { continue };
            if let Some(sv) = supervoxels.get_mut(v.supervoxel as usize) {
                sv.add(v);
            }
        }
        for sv in supervoxels.as_mut_slice() {
            sv.finish_round();
        }
    }

    // --- orphans: 26-connected components of what is left (union-find, lowest index is the root) -----------
    for i in 0..n {
        if let Some(st) = scratch.get_mut(i) {
            *st = i as u16;
        }
    }
    for i in 0..n {
        let Some(v) = voxels.get(i).copied() else { continue };
        if v.supervoxel != UNLABELLED {
            continue;
        }
        for_each_linked_neighbour::<LINKED>(voxels, slots, links, i, v.key, |j| {
            if voxels.get(j).is_some_and(|nb| nb.supervoxel == UNLABELLED) {
                union_find::union(scratch, i, j);
            }
        });
    }
    // Points per component, summed at the root (the root's `gaussian` field is free until stage 3).
    for i in 0..n {
        let Some(v) = voxels.get(i).copied() else { continue };
        if v.supervoxel != UNLABELLED {
            continue;
        }
        let root = union_find::find(scratch, i);
        if let Some(rv) = voxels.get_mut(root) {
            rv.gaussian = if root == i { 0 } else { rv.gaussian };
        }
    }
    for i in 0..n {
        let Some(v) = voxels.get(i).copied() else { continue };
        if v.supervoxel != UNLABELLED {
            continue;
        }
        let root = union_find::find(scratch, i);
        if let Some(rv) = voxels.get_mut(root) {
            rv.gaussian = rv.gaussian.saturating_add(v.count);
        }
    }
    for i in 0..n {
        let Some(v) = voxels.get(i).copied() else { continue };
        if v.supervoxel != UNLABELLED {
            continue;
        }
        let root = union_find::find(scratch, i);
        let Some(rv) = voxels.get(root).copied() else { continue };
        let label = if (rv.gaussian as u32) < params.gmm_min_points {
            stats.outlier_points += v.count as u32;
            OUTLIER
        } else if root == i {
            match supervoxels.push(Supervoxel::start(i as u16, &v)) {
                Some(id) => {
                    stats.orphan_supervoxels += 1;
                    id as u16
                }
                None => DROPPED,
            }
        } else {
            let label = rv.supervoxel;
            if let Some(sv) = supervoxels.get_mut(label as usize) {
                sv.add(&v);
            }
            label
        };
        if label == DROPPED {
            stats.dropped_points += v.count as u32;
        }
        if let Some(vox) = voxels.get_mut(i) {
            vox.supervoxel = label;
        }
    }
    for v in voxels.iter_mut() {
        v.gaussian = UNLABELLED;
    }
    for sv in supervoxels.as_mut_slice() {
        sv.finish_round();
    }
    stats
}

/// Fills the seed-cell table: voxel count and nearest-to-centre voxel per `seed_resolution` cube.
fn choose_seed_cells(voxels: &[Voxel], seeds: &mut Bounded<'_, SeedCell>, params: &Params) {
    seeds.clear();
    let rs = params.seed_resolution;
    let mut last = 0;
    for (i, v) in voxels.iter().enumerate() {
        let c = v.centroid();
        let Some(key) = voxel_key(c, rs, key_slot(v.key)) else { continue };
        let centre = linalg::add(key_corner(key, rs), [0.5 * rs; 3]);
        let d = linalg::sub(c, centre);
        let d2 = linalg::dot(d, d);
        // Seed cells are few (tens per frame): a linear search is cheaper than a second hash, and neighbouring
        // voxels mostly share the last cell found (keys are unique, so the first match is the only one).
        let cells = seeds.as_mut_slice();
        let k = match cells.get(last) {
            Some(s) if s.key == key => Some(last),
            _ => cells.iter().position(|s| s.key == key),
        };
        last = k.unwrap_or(last);
        match k.and_then(|k| cells.get_mut(k)) {
            Some(cell) => {
                cell.voxels = cell.voxels.saturating_add(1);
                if d2 < cell.best_d2 {
                    cell.best_d2 = d2;
                    cell.best = i as u16;
                }
            }
            None => {
                let _ = seeds.push(SeedCell { key, voxels: 1, best: i as u16, best_d2: d2 });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;

    #[test]
    fn quantise_unit_rounds_exactly_as_roundf() {
        let reference = |x: f32| libm::roundf(x.clamp(-1.0, 1.0) * 32767.0) as i16;
        // Every halfway point and its neighbours one ulp either side, then a dense sweep and the edge cases.
        for k in -32768i32..=32767 {
            let half = (k as f32 + 0.5) / 32767.0;
            for x in [half, f32::from_bits(half.to_bits() + 1), f32::from_bits(half.to_bits().wrapping_sub(1))] {
                assert_eq!(quantise_unit(x), reference(x), "x = {x:e}");
            }
        }
        for i in 0..=2_000_000u32 {
            let x = -1.1 + 2.2 * i as f32 / 2_000_000.0;
            assert_eq!(quantise_unit(x), reference(x), "x = {x:e}");
        }
        for x in [0.0, -0.0, 1.0, -1.0, 2.0, -7.5, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1e-40] {
            assert_eq!(quantise_unit(x), reference(x), "x = {x:e}");
        }
    }

    /// The links hold exactly the neighbours the hash gives, in its order: a blob
    /// with holes in two mask slots, at the centre of the key range and against each of its ends.
    #[test]
    fn voxel_links_are_the_hash_neighbours() {
        let mut voxels = [Voxel::zeroed(); 600];
        let mut slots = [0u16; 2048];
        let mut n = 0;
        let corners = [
            (0, 0, 200),
            (-VOXEL_GRID_HALF_EXTENT, VOXEL_GRID_HALF_EXTENT - 4, 0),
            (VOXEL_GRID_HALF_EXTENT - 4, 0, VOXEL_GRID_HALF_EXTENT - 4),
        ];
        for ((x0, y0, z0), slot) in corners.into_iter().zip([0u32, 3, 7]) {
            for k in 0..125i32 {
                let (x, y, z) = (x0 + k % 5, y0 + k / 5 % 5, z0 + k / 25);
                // Holes: every third cube of the blob is empty.
                if (x + 2 * y + 5 * z) % 3 == 0 {
                    continue;
                }
                let Some(key) = pack(x, y, z, slot) else { continue };
                let Probe::Vacant(pos) = probe_voxel(&voxels, &slots, key) else { panic!("hash") };
                voxels[n] =
                    Voxel { key, count: 1 + (k % 7) as u16, mean: [0.001 * k as f32, 0.002, 0.003], ..Voxel::zeroed() };
                slots[pos] = (n + 1) as u16;
                n += 1;
            }
        }
        let voxels = &voxels[..n];
        let mut links = [VoxelLinks { neighbours: [0; 26], occupied: 0 }; 600];
        link_voxels(voxels, &slots, &mut links);
        let mut total = 0;
        for (i, v) in voxels.iter().enumerate() {
            let (mut by_hash, mut by_links) = (heapless::Vec::<usize, 26>::new(), heapless::Vec::<usize, 26>::new());
            for_each_neighbour(voxels, &slots, v.key, |j| by_hash.push(j).unwrap());
            for_each_linked_neighbour::<true>(voxels, &slots, &links[..n], i, v.key, |j| by_links.push(j).unwrap());
            assert_eq!(by_links, by_hash, "voxel {i}");
            total += by_hash.len();
        }
        assert!(total > 2000, "{total} neighbour pairs");
    }

    /// Growth through the hash over the directions the normals found occupied labels every voxel exactly as
    /// growth over the links and as growth that looks up all 26 directions: a wavy sheet of voxels with holes
    /// (several seed cells, two mask slots), its voxel means off the cube centres.
    #[test]
    fn growth_over_the_occupied_directions_labels_as_over_all_of_them() {
        const N: usize = 3000;
        let params = Params::default();
        let r = params.voxel_resolution;
        let mut voxels = [Voxel::zeroed(); N];
        let mut slots = [0u16; 8192];
        let mut n = 0;
        for (k, slot) in (0..2900i32).map(|k| (k, (k / 1450) as u32)) {
            let (x, y) = (k % 50 - 25, k / 50 - 29);
            // Holes, and a sheet that climbs one cube every few columns (neighbours above and below).
            if (3 * x + 7 * y) % 11 == 0 {
                continue;
            }
            let z = 40 + (x + 2 * y).rem_euclid(9) / 3;
            let Some(key) = pack(x, y, z, slot) else { continue };
            let Probe::Vacant(pos) = probe_voxel(&voxels, &slots, key) else { panic!("hash") };
            let corner = key_corner(key, r);
            let off = [0.2 + 0.6 * ((k * 7) % 10) as f32 / 10.0, 0.5, 0.3 + 0.4 * ((k * 3) % 10) as f32 / 10.0];
            let mean = [corner[0] + off[0] * r, corner[1] + off[1] * r, corner[2] + off[2] * r];
            let mut v = Voxel { key, count: 1 + (k % 5) as u16, mean, ..Voxel::zeroed() };
            v.supervoxel = UNLABELLED;
            v.gaussian = UNLABELLED;
            v.add_colour([(k % 200) as u8, 90, 30]);
            voxels[n] = v;
            slots[pos] = (n + 1) as u16;
            n += 1;
        }
        let grow_labels = |voxels: &mut [Voxel], links: Option<&[VoxelLinks]>| {
            let (mut scratch, mut seed_cells, mut svs) =
                ([0u16; N], [SeedCell::zeroed(); 128], [Supervoxel::zeroed(); 128]);
            let (mut seeds, mut supervoxels) = (Bounded::new(&mut seed_cells), Bounded::new(&mut svs));
            let pools = SupervoxelPools {
                voxels,
                slots: &slots,
                scratch: &mut scratch,
                seeds: &mut seeds,
                supervoxels: &mut supervoxels,
                links,
            };
            let stats = build_supervoxels(pools, &params);
            (voxels.iter().map(|v| v.supervoxel).collect::<heapless::Vec<u16, N>>(), stats.seeds)
        };
        // Over the links (the host profile's path).
        let mut linked = voxels;
        let mut links = [VoxelLinks { neighbours: [0; 26], occupied: 0 }; N];
        assert!(compute_normals(&mut linked[..n], &slots, &mut links));
        // Through the hash: the normals keep the occupied directions, and they are the links' ones.
        let mut hashed = voxels;
        assert!(!compute_normals(&mut hashed[..n], &slots, &mut []));
        for (i, v) in hashed[..n].iter().enumerate() {
            assert_eq!(occupied_directions(v), links[i].occupied, "voxel {i}");
            assert_eq!(v.normal, linked[i].normal, "voxel {i}");
            let (mut all, mut among) = (heapless::Vec::<usize, 26>::new(), heapless::Vec::<usize, 26>::new());
            for_each_neighbour(&hashed[..n], &slots, v.key, |j| all.push(j).unwrap());
            for_each_neighbour_among(&hashed[..n], &slots, v.key, occupied_directions(v), |_, j| {
                among.push(j).unwrap()
            });
            assert_eq!(among, all, "voxel {i}");
        }
        // Through the hash, every direction looked up (as voxelisation leaves the fields).
        let mut every = hashed;
        for v in every[..n].iter_mut() {
            v.supervoxel = UNLABELLED;
            v.gaussian = UNLABELLED;
        }
        assert_eq!(occupied_directions(&every[0]), ALL_DIRECTIONS);
        let (by_links, seeds) = grow_labels(&mut linked[..n], Some(&links[..n]));
        let (by_occupied, _) = grow_labels(&mut hashed[..n], None);
        let (by_all, _) = grow_labels(&mut every[..n], None);
        assert!(seeds >= 4, "{seeds} seeds");
        let assigned = by_links.iter().filter(|&&l| is_assigned(l)).count();
        assert!(assigned > 9 * n / 10, "{assigned} of {n} voxels in supervoxels");
        assert_eq!(by_occupied, by_links);
        assert_eq!(by_all, by_links);
        let occupied: u32 = links[..n].iter().map(|l| l.occupied.count_ones()).sum();
        assert!(occupied < 26 * n as u32 / 2, "{occupied} of {} directions occupied", 26 * n);
    }

    /// Growth's marks give the marked indices below `n` in order, across words and after clears; with more
    /// voxels than bits, every index.
    #[test]
    fn growth_marks_visit_the_marked_voxels_in_order() {
        let n = GROWTH_MARKED_VOXELS - 3;
        let mut marks = GrowthMarks::new(n);
        let marked = [0usize, 5, 31, 32, 33, 100, 4095, 4096, n - 1, n, GROWTH_MARKED_VOXELS - 1];
        for &i in &marked {
            marks.set(i);
        }
        marks.clear(33);
        let visit = |marks: &GrowthMarks, n: usize| {
            let (mut out, mut from) = (std::vec::Vec::new(), 0);
            while let Some(i) = marks.next(from, n) {
                out.push(i);
                from = i + 1;
            }
            out
        };
        assert_eq!(visit(&marks, n), [0, 5, 31, 32, 100, 4095, 4096, n - 1]);
        assert_eq!(marks.next(n - 1, n), Some(n - 1));
        assert_eq!(marks.next(n, n), None);
        let many = GROWTH_MARKED_VOXELS + 10;
        let every = GrowthMarks::new(many);
        assert_eq!(visit(&every, many), (0..many).collect::<std::vec::Vec<_>>());
    }

    #[test]
    fn packed_colour_sums_are_exact_up_to_the_largest_voxel() {
        let mut v = Voxel::zeroed();
        // The worst case: every point white, as many as a voxel takes.
        for _ in 0..MAX_VOXEL_POINTS {
            v.add_colour([255, 255, 255]);
        }
        let full = 255 * MAX_VOXEL_POINTS as u32;
        assert_eq!(v.colour_sums(), [full; 3]);
        assert!(full < 1 << COLOUR_SUM_BITS);
        // Mixed colours: each channel stays in its own field.
        let mut v = Voxel::zeroed();
        let (mut r, mut g, mut b) = (0u32, 0u32, 0u32);
        for k in 0..5000u32 {
            let c = [(k * 7 % 256) as u8, (k * 13 % 256) as u8, (k * 29 % 256) as u8];
            v.add_colour(c);
            (r, g, b) = (r + c[0] as u32, g + c[1] as u32, b + c[2] as u32);
        }
        assert_eq!(v.colour_sums(), [r, g, b]);
        v.count = 5000;
        let mean = v.colour();
        assert!((mean[1] - g as f32 / (255.0 * 5000.0)).abs() < 1e-6);
    }
}
