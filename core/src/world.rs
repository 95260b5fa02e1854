//! Stage 12 (an m2smap extension beyond the paper): the world map, one map of everything a posed sequence has
//! seen, in caller-owned pools of fixed capacity, with stable ids and a delta stream for a thin radio link.
//!
//! Each frame's map (camera frame) is fused into world-frame primitives ([`WorldMap::integrate`]):
//! - **planes**: a frame plane joins the world plane whose normal lies within `world_plane_angle_deg` and whose
//!   surface passes within `world_plane_offset` of the frame plane's centroid (the nearest such; its farthest
//!   cell within [`PLANE_BEND_OFFSETS`] offsets); its occupied
//!   cells are drawn into the world plane's own [`WORLD_GRID`] × [`WORLD_GRID`] grid (each by its centre; the
//!   holes a rotated grid leaves are filled when cells are shown: an unset cell with three set 4-neighbours),
//!   and its normal and offset are averaged, weighted by occupied cells. Otherwise it starts a new world plane.
//!   Cells outside the grid are counted, not drawn. (Drawing 2 × 2 points per frame cell instead grows the
//!   boundary by up to a cell: measured on redkitchen, plane G2R 0.022 against 0.018 m.)
//!   Two world planes that came to describe one surface (the same test between their accumulated planes, the
//!   cells some frame hit standing in for a frame's; within [`JOIN_SHARED_OFFSETS`] offsets when they mostly
//!   share those cells) join after each frame: the one with less support is drawn into the other.
//! - **objects**: a frame superquadric (its track's smoothed state where the frame's points allow it) moved
//!   into the world frame updates the world object of its track ([`crate::track`]). A track seen
//!   for the first time adopts the world object of the same class whose centre lies within max(`d_max`, its
//!   largest half-axis) and that no track updated this frame — a track that was retired and restarted keeps
//!   its world object and id. A retired track's object stays in the map, static. An object is shown once
//!   [`OBJECT_MIN_FRAMES`] frames saw it. A partial view ([`MapSq::partial`]: the shape runs out of the
//!   image, where the fit had no silhouette to stop at) never gives an object its shape: it keeps a shown
//!   object alive, frame Gaussians near it count as explained (as near a stray fit), and for an object not yet
//!   shown it counts as a sighting when it agrees with the latest whole view; alone, it makes no object. What
//!   the camera saw of such an object comes as its Gaussians ([`crate::Mapper::for_each_world_primitive`]).
//! - **Gaussians** (GMMap-style moment matching): a frame Gaussian merges into the world Gaussian with the
//!   smallest squared Mahalanobis distance d² = Δᵀ(Σ_w + Σ_f + σ₀²I)⁻¹Δ ≤ `world_gmm_gate` (σ₀ = 5 mm) whose
//!   merged total variance stays within `world_gmm_growth`² of the larger of the two (a re-observation merges,
//!   a neighbouring patch does not); the merged mean, covariance and support are those of the union of their
//!   points ([`linalg::Moments::add_gaussian`]). Otherwise it is added; when the pool is full, the world
//!   Gaussian with the least support (then the one unseen longest) that this frame has not touched is evicted,
//!   if its support is below the newcomer's; else the newcomer is dropped. Both are counted. A Gaussian is
//!   shown once [`GAUSSIAN_MIN_FRAMES`] frames saw it; one that a shown plane or object explains
//!   ([`EXPLAINED_M`]) is not added, or leaves.
//!
//! Pools keep their elements in increasing id order (new ids are appended, removal shifts), so the map and its
//! deltas are written in (kind, id) order without sorting. Everything is deterministic: the same frames give
//! the same bytes on a PC and on a Cortex-M7.
//!
//! **Published state.** Each world primitive keeps what it has accumulated (running means, merged moments,
//! new plane cells) apart from what it shows: the map, `world.bin` and the deltas are written from the shown
//! state only, which follows the accumulated one in steps ([`PUBLISH_PLANE_M`], [`PUBLISH_CELL_SHARE`],
//! [`PUBLISH_ANGLE_DEG`], [`PUBLISH_MOVE_M`], [`PUBLISH_SHAPE_CHANGE`], [`PUBLISH_GMM_SHAPE_CHANGE`]). A re-observation that changes a primitive by less than a
//! step costs no radio bytes; the shown map is never more than a step behind.
//!
//! **Deltas** ([`WorldMap::encode_delta_streaming`]): each primitive remembers the CRC-32 of the record it last
//! sent; a delta carries the new records, those whose bytes changed, and the (kind, id) of removed ones. A
//! receiver applying every delta in order holds the sender's records and writes a `world.bin` identical to the
//! sender's ([`crate::wire::encode_world_records`]).
//! Two different records with the same CRC-32 (a 2⁻³² chance per changed record) would not be sent.

use bytemuck::Zeroable;

use crate::cells::{bit, set_bit};
use crate::frame::Pose;
use crate::linalg::{self, Moments, Sym3, Vec3};
use crate::map::{CellBits, CellCoding, MapGmm, MapPlane, MapSq, Primitive};
use crate::params::Params;
use crate::pool::{Bounded, PoolUsage};
use crate::superquadric::Superquadric;
use crate::wire::{self, WireError, KIND_GMM, KIND_PLANE, KIND_SQ};

/// Cells per side of a world plane's grid (6.4 m at g_p = 5 cm).
pub const WORLD_GRID: usize = 128;
/// Bytes of a world plane's occupancy bitmap.
pub const WORLD_GRID_BYTES: usize = WORLD_GRID * WORLD_GRID / 8;
/// Variance added to both covariances in the Gaussian merge test, m² ((5 mm)²: pose and sensor noise).
pub const MERGE_NOISE_VAR: f32 = 2.5e-5;
/// A shown superquadric turns to its accumulated orientation once they differ by more than this, degrees.
pub const PUBLISH_ANGLE_DEG: f32 = 3.0;
/// A shown plane takes its accumulated normal and offset once they put it more than this far from the
/// accumulated plane anywhere within its reach, metres.
pub const PUBLISH_PLANE_M: f32 = 0.02;
/// A shown superquadric or Gaussian moves to its accumulated position once they differ by more than this,
/// metres (a Gaussian: or by more than half its largest σ, whichever is larger).
pub const PUBLISH_MOVE_M: f32 = 0.02;
/// A shown superquadric takes its accumulated shape once a half-axis changes by more than this fraction (an
/// exponent by more than this).
pub const PUBLISH_SHAPE_CHANGE: f32 = 0.2;
/// A shown Gaussian takes its accumulated covariance once it changes by more than this fraction (Frobenius
/// norm), or its support doubles.
pub const PUBLISH_GMM_SHAPE_CHANGE: f32 = 0.4;
/// Sightings a world object's centre is averaged over (a running mean, then a moving one with this weight).
pub const OBJECT_CENTRE_FRAMES: u16 = 8;
/// New cells of a world plane are shown once they number more than this share of its shown cells (or the
/// pending list is full).
pub const PUBLISH_CELL_SHARE: f32 = 0.2;
/// A Gaussian whose mean lies within this distance of a world superquadric's surface (or inside it), or of a
/// world plane it is parallel to or whose band of this half-width holds its ±2σ along the plane's normal, over
/// an occupied cell, is already explained by that primitive, metres.
pub const EXPLAINED_M: f32 = 0.03;
/// A frame plane joins a world plane only if its farthest cell lies within this many `world_plane_offset`s of
/// it (centroid offset plus tilt times reach).
pub const PLANE_BEND_OFFSETS: f32 = 3.0;
/// Two world planes whose hit cells mostly coincide (at least half of the smaller one's) join when their
/// surfaces lie within this many `world_plane_offset`s (see `WorldMap::join_planes`): one stretch of floor seen
/// from poses a few centimetres apart (opaque surfaces that far apart cannot both be seen over the same cells).
pub const JOIN_SHARED_OFFSETS: f32 = 2.0;
/// A world object is shown once this many sightings in a row gave fits that agree ([`AGREEMENT`]): a fit that no
/// later frame confirms stays out of the map (and leaves it after `track_max_missed` frames unseen), and so does
/// a track whose fits jump between neighbours or between slices of an object.
pub const OBJECT_MIN_FRAMES: u16 = 3;
/// Two fits of one object agree when their centres lie within this share of the largest half-axis (or
/// [`PUBLISH_MOVE_M`]) and each sorted half-axis within this share of the larger.
pub const AGREEMENT: f32 = 0.3;
/// A world Gaussian is shown once this many frames saw it (a patch seen once, often a fragment that a later
/// frame explains or merges differently, costs no radio bytes).
pub const GAUSSIAN_MIN_FRAMES: u16 = 2;
/// New cells a world plane holds back before showing them.
pub const PENDING_CELLS: usize = 1024;

/// One world plane: a grid on the plane through `origin` spanned by `e1`, `e2`. World frame, metres.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct WorldPlane {
    /// World id.
    pub id: u32,
    /// Shown grid origin on the plane (the centre of the grid), metres.
    pub origin: Vec3,
    /// Shown grid axis e1 (columns of the grid).
    pub e1: Vec3,
    /// Shown grid axis e2 (rows).
    pub e2: Vec3,
    /// Shown unit normal n = e1 × e2.
    pub normal: Vec3,
    /// Shown thickness σ2, metres.
    pub thickness: f32,
    /// Shown λ2/λ0.
    pub eigen_ratio: f32,
    /// Shown colour.
    pub colour: [u8; 3],
    /// Accumulated unit normal: the support-weighted mean of the frames' normals.
    pub acc_normal: Vec3,
    /// Accumulated offset d of n · x = d, metres.
    pub acc_offset: f32,
    /// Accumulated thickness σ2 (support-weighted mean), metres.
    pub acc_thickness: f32,
    /// Accumulated λ2/λ0.
    pub acc_ratio: f32,
    /// Accumulated colour, RGB in [0, 255].
    pub acc_colour: [f32; 3],
    /// Support: occupied frame cells summed over the frames it was seen in.
    pub support: u32,
    /// Shown occupied cells.
    pub occupied: u32,
    /// Farthest centre of a shown or pending cell from the origin, metres.
    pub reach: f32,
    /// Cells that fell outside the grid, over its lifetime.
    pub clipped_cells: u32,
    /// Frame it was last seen in.
    pub last_frame: u32,
    /// CRC-32 of the record last sent in a delta.
    pub sent_crc: u32,
    /// 1 once a delta carried it.
    pub sent: u8,
    /// Pending cells in use.
    pub pending_len: u16,
    /// New cells not shown yet (bit indices into `cells`).
    pub pending: [u16; PENDING_CELLS],
    /// Cells some frame has hit (bit indices as in `cells`): a cell is shown once a second frame hits it.
    pub seen: [u8; WORLD_GRID_BYTES],
    /// Shown occupancy bitmap, row-major, cell (a, b) at bit a + b × [`WORLD_GRID`], a and b offset by half the
    /// grid.
    pub cells: [u8; WORLD_GRID_BYTES],
}

/// One world object: a superquadric in the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct WorldObject {
    /// World id.
    pub id: u32,
    /// Accumulated: the latest superquadric of its track, world frame.
    pub sq: Superquadric,
    /// Shown: the superquadric of the map, world frame.
    pub shown: MapSq,
    /// The track that feeds it now (or fed it last).
    pub track: u16,
    /// Category label ℓ.
    pub class: u16,
    /// Highest detection confidence seen.
    pub score: f32,
    /// Frame it was last seen in.
    pub last_frame: u32,
    /// Sightings (saturating); until it is shown, the sightings in a row whose fits agree with the one before
    /// (a disagreeing fit starts the count again at 1). It is shown from [`OBJECT_MIN_FRAMES`] on.
    pub frames_seen: u16,
    /// CRC-32 of the record last sent in a delta.
    pub sent_crc: u32,
    /// 1 once a delta carried it.
    pub sent: u8,
}

impl WorldGaussian {
    /// Whether it has been seen often enough to be shown.
    pub fn is_confirmed(&self) -> bool {
        self.frames_seen >= GAUSSIAN_MIN_FRAMES
    }
}

impl WorldObject {
    /// Whether it has been seen often enough to be shown.
    pub fn is_confirmed(&self) -> bool {
        self.frames_seen >= OBJECT_MIN_FRAMES
    }
}

/// One world Gaussian. World frame, metres.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct WorldGaussian {
    /// World id.
    pub id: u32,
    /// Accumulated mean μ, metres.
    pub mean: Vec3,
    /// Accumulated covariance Σ (denominator N − 1), m², `[xx, xy, xz, yy, yz, zz]`.
    pub covariance: Sym3,
    /// Accumulated support N over every frame merged into it.
    pub count: u32,
    /// Accumulated support-weighted mean colour, RGB in [0, 255].
    pub colour: [f32; 3],
    /// Category label ℓ of its best-scored observation.
    pub class: u16,
    /// 1 once a delta carried it.
    pub sent: u8,
    /// Highest confidence s seen.
    pub score: f32,
    /// Frame it was last seen in.
    pub last_frame: u32,
    /// CRC-32 of the record last sent in a delta.
    pub sent_crc: u32,
    /// Frames it was seen in (saturating); it is shown from [`GAUSSIAN_MIN_FRAMES`] on.
    pub frames_seen: u16,
    /// The covariance it shows (to compare the accumulated one with).
    pub shown_covariance: Sym3,
    /// Shown: the Gaussian of the map.
    pub shown: MapGmm,
}

/// Storage of a world map: `P` planes, `O` objects, `G` Gaussians, `R` pending removals (ids removed since the
/// last delta; an eviction waits for room here, so the receiver never misses one).
#[derive(Zeroable)]
#[repr(C)]
pub struct WorldStorage<const P: usize, const O: usize, const G: usize, const R: usize> {
    planes: [WorldPlane; P],
    objects: [WorldObject; O],
    gaussians: [WorldGaussian; G],
    removed: [(u8, u32); R],
}

impl<const P: usize, const O: usize, const G: usize, const R: usize> WorldStorage<P, O, G, R> {
    /// Bytes of the storage itself.
    pub const BYTES: usize = core::mem::size_of::<Self>();
    /// Planes it holds.
    pub const PLANES: usize = P;
    /// Objects it holds.
    pub const OBJECTS: usize = O;
    /// Gaussians it holds.
    pub const GAUSSIANS: usize = G;
    /// Pending removals it holds.
    pub const REMOVALS: usize = R;
}

/// World map for the `mcu` profile: 1 plane, 8 objects, 20 Gaussians (11.1 KiB: what the 512 KiB budget leaves
/// beside the mapper and a 25 KiB stack; the firmware runs it on the cabinet frames).
pub type McuWorld = WorldStorage<1, 8, 20, 16>;
/// World map for the `host` profile: 32 planes, 128 objects, 4 096 Gaussians.
pub type HostWorld = WorldStorage<32, 128, 4096, 1024>;

/// What one [`WorldMap::integrate`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WorldStats {
    /// Frame planes merged into a world plane.
    pub planes_merged: u32,
    /// World planes created.
    pub planes_created: u32,
    /// World planes drawn into another world plane of the same surface.
    pub planes_joined: u32,
    /// Frame planes dropped: the plane pool was full.
    pub planes_dropped: u32,
    /// World planes whose shown normal and offset took a step.
    pub planes_moved: u32,
    /// World planes whose pending cells were shown.
    pub planes_grown: u32,
    /// Frame cells outside every world grid.
    pub cells_clipped: u32,
    /// Superquadrics that updated a world object.
    pub objects_updated: u32,
    /// World objects created.
    pub objects_created: u32,
    /// Superquadrics dropped: the object pool was full of objects seen this frame.
    pub objects_dropped: u32,
    /// Superquadrics seen only in part ([`MapSq::partial`]) that gave no world object a shape.
    pub objects_partial: u32,
    /// World objects evicted (unseen longest) to make room.
    pub objects_evicted: u32,
    /// Frame Gaussians merged into a world Gaussian.
    pub gmms_merged: u32,
    /// World Gaussians created.
    pub gmms_created: u32,
    /// World Gaussians evicted to make room.
    pub gmms_evicted: u32,
    /// Frame Gaussians dropped: no room and nothing weaker to evict.
    pub gmms_dropped: u32,
    /// Frame Gaussians not added, and world Gaussians removed, because a world plane or superquadric explains
    /// them.
    pub gmms_explained: u32,
}

/// Why a frame could not be integrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorldError {
    /// The pose is not a finite rigid transform.
    BadPose,
    /// The frame number is not after the last one integrated.
    FrameOutOfOrder,
}

impl core::fmt::Display for WorldError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WorldError::BadPose => write!(f, "camera pose is not a finite rigid transform"),
            WorldError::FrameOutOfOrder => write!(f, "frame number is not after the last integrated frame"),
        }
    }
}

/// The world map over borrowed [`WorldStorage`].
pub struct WorldMap<'s> {
    planes: Bounded<'s, WorldPlane>,
    objects: Bounded<'s, WorldObject>,
    gaussians: Bounded<'s, WorldGaussian>,
    removed: Bounded<'s, (u8, u32)>,
    next_id: u32,
    frame: Option<u32>,
    g_p: f32,
}

/// A frame Gaussian in the world frame.
struct Observed {
    mean: Vec3,
    covariance: Sym3,
    count: u32,
    colour: [f32; 3],
    class: u16,
    score: f32,
}

impl<'s> WorldMap<'s> {
    /// An empty world map over `storage`.
    pub fn new<const P: usize, const O: usize, const G: usize, const R: usize>(
        storage: &'s mut WorldStorage<P, O, G, R>,
    ) -> Self {
        WorldMap {
            planes: Bounded::new(&mut storage.planes),
            objects: Bounded::new(&mut storage.objects),
            gaussians: Bounded::new(&mut storage.gaussians),
            removed: Bounded::new(&mut storage.removed),
            next_id: 0,
            frame: None,
            g_p: 0.05,
        }
    }

    /// The last frame integrated.
    pub fn frame(&self) -> Option<u32> {
        self.frame
    }

    /// World planes.
    pub fn planes(&self) -> &[WorldPlane] {
        self.planes.as_slice()
    }

    /// World objects.
    pub fn objects(&self) -> &[WorldObject] {
        self.objects.as_slice()
    }

    /// World Gaussians.
    pub fn gaussians(&self) -> &[WorldGaussian] {
        self.gaussians.as_slice()
    }

    /// Shown planes, superquadrics and Gaussians (the primitives of the map).
    pub fn primitive_counts(&self) -> [usize; 3] {
        let confirmed = self.objects.as_slice().iter().filter(|o| o.is_confirmed()).count();
        let shown = self.gaussians.as_slice().iter().filter(|g| g.is_confirmed()).count();
        [self.planes.len(), confirmed, shown]
    }

    /// Pool use of planes, objects, Gaussians and pending removals (peaks over the map's lifetime).
    pub fn usage(&self) -> [PoolUsage; 4] {
        [self.planes.usage(), self.objects.usage(), self.gaussians.usage(), self.removed.usage()]
    }

    /// Fuses the map of frame `frame` (camera frame; `primitives` feeds every primitive, as
    /// [`crate::Mapper::for_each_primitive`] does) into the world map, with its camera-to-world `pose`. A
    /// frame with a bad pose or an old frame number is refused and changes nothing. Removals wait in the
    /// storage's removal list until a delta carries them ([`WorldMap::encode_delta_streaming`]); when it is
    /// full, sent primitives stay (no eviction, no removal) until the next delta.
    pub fn integrate(
        &mut self,
        frame: u32,
        pose: &Pose,
        params: &Params,
        mut primitives: impl FnMut(&mut dyn FnMut(&Primitive<'_>)),
    ) -> Result<WorldStats, WorldError> {
        if !pose.is_valid() {
            return Err(WorldError::BadPose);
        }
        if self.frame.is_some_and(|f| frame <= f) {
            return Err(WorldError::FrameOutOfOrder);
        }
        self.frame = Some(frame);
        self.g_p = params.g_p;
        let mut stats = WorldStats::default();
        primitives(&mut |p| match p.moved(&pose.rotation, pose.translation) {
            Primitive::Plane(pl) => self.add_plane(&pl, frame, params, &mut stats),
            Primitive::Sq(s) => self.add_object(&s, frame, params, &mut stats),
            Primitive::Gmm(g) => self.add_gaussian(&g, frame, params, &mut stats),
        });
        self.join_planes(params, &mut stats);
        // Objects never confirmed and unseen for `track_max_missed` frames were passing fits: they leave (they
        // were never shown, so no delta mentions them).
        let mut i = 0;
        while i < self.objects.len() {
            let stale = self
                .objects
                .get(i)
                .is_some_and(|o| !o.is_confirmed() && frame.saturating_sub(o.last_frame) > params.track_max_missed);
            if stale {
                remove_at(&mut self.objects, i);
            } else {
                i += 1;
            }
        }
        // World Gaussians that a plane or superquadric now explains (one that appeared or grew this frame)
        // leave the map.
        let mut i = 0;
        while i < self.gaussians.len() {
            let explained = self.gaussians.get(i).is_some_and(|g| self.explains(g.mean, &g.covariance, params));
            if explained && self.note_removal(KIND_GMM, i) {
                remove_at(&mut self.gaussians, i);
                stats.gmms_explained += 1;
            } else {
                i += 1;
            }
        }
        Ok(stats)
    }

    /// Joins world planes that came to describe one surface ([`same_surface`]): the one with less support is
    /// drawn into the other ([`draw_plane_into`]) and leaves the map. A frame plane joins the world plane it
    /// agrees with best, so a first view whose fit was a few centimetres off, or a frame whose floor came in two
    /// pieces, can start a second world plane of the same floor that the later frames then feed (the cabinet
    /// with 2 of 6 other sample seeds: two floors 6 cm apart and R2G 0.061–0.071 m); once the two agree they
    /// are one again. A frame joins at most as many pairs as there are planes; none when the removal list is
    /// full.
    #[inline(never)] // its cell copies stay out of the caller's frame (the Cortex-M7's stack)
    fn join_planes(&mut self, params: &Params, stats: &mut WorldStats) {
        let cos_min = libm::cosf(params.world_plane_angle_deg.to_radians());
        let g = self.g_p;
        for _ in 0..self.planes.len() {
            let planes = self.planes.as_slice();
            let mut pair = None;
            'search: for (i, a) in planes.iter().enumerate() {
                for (j, b) in planes.iter().enumerate().skip(i + 1) {
                    // The one with more support keeps its grid (the earlier one on a tie).
                    let (into, from) = if b.support > a.support { (j, i) } else { (i, j) };
                    let (big, small) = if into == i { (a, b) } else { (b, a) };
                    if same_surface(big, small, g, cos_min, params) {
                        pair = Some((into, from));
                        break 'search;
                    }
                }
            }
            let Some((into, from)) = pair else { return };
            if !self.note_removal(KIND_PLANE, from) {
                return;
            }
            let planes = self.planes.as_mut_slice();
            let (lo, hi) = planes.split_at_mut(into.max(from));
            let (Some(low), Some(high)) = (lo.get_mut(into.min(from)), hi.first_mut()) else { return };
            let (into_plane, from_plane) = if into < from { (low, &*high) } else { (high, &*low) };
            draw_plane_into(into_plane, from_plane, g);
            remove_at(&mut self.planes, from);
            stats.planes_joined += 1;
        }
    }

    fn take_id(&mut self) -> u32 {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1);
        id
    }

    /// Adds frame plane `p`, already in the world frame.
    fn add_plane(&mut self, p: &MapPlane<'_>, frame: u32, params: &Params, stats: &mut WorldStats) {
        let n = linalg::column(&p.rotation, 2);
        let c = p.centroid;
        let cos_min = libm::cosf(params.world_plane_angle_deg.to_radians());
        // How far the frame plane's cells reach from its centroid: a tilt between the planes moves its far
        // cells by the tilt times this.
        let reach = p.cells.occupied_box().map_or(0.0, |(i0, j0, i1, j1)| {
            let far = |lo: usize, hi: usize, origin: i16| {
                let (lo, hi) = (origin as f32 + lo as f32, origin as f32 + hi as f32 + 1.0);
                libm::fabsf(lo).max(libm::fabsf(hi)) * p.g_p
            };
            let (u, v) = (far(i0, i1, p.cells.a0), far(j0, j1, p.cells.b0));
            linalg::sqrt(u * u + v * v)
        });
        let mut best: Option<(usize, f32)> = None;
        for (i, w) in self.planes.as_slice().iter().enumerate() {
            // The centroid within `world_plane_offset`, and the far cells within PLANE_BEND_OFFSETS times that
            // (a frame's floor seen at a grazing angle tilts by a degree or two; a different surface more).
            let off = libm::fabsf(linalg::dot(w.acc_normal, c) - w.acc_offset);
            let bend = linalg::norm(linalg::cross(w.acc_normal, n)) * reach;
            if libm::fabsf(linalg::dot(w.acc_normal, n)) >= cos_min
                && off <= params.world_plane_offset
                && off + bend <= PLANE_BEND_OFFSETS * params.world_plane_offset
                && best.is_none_or(|(_, o)| off < o)
            {
                best = Some((i, off));
            }
        }
        let index = match best {
            Some((i, _)) => {
                stats.planes_merged += 1;
                i
            }
            None => {
                let (e1, e2) = (linalg::column(&p.rotation, 0), linalg::column(&p.rotation, 1));
                let normal = linalg::normalize_or(linalg::cross(e1, e2), n);
                let mut plane = WorldPlane::zeroed();
                plane.id = self.next_id;
                plane.origin = c;
                plane.e1 = e1;
                plane.e2 = e2;
                plane.normal = normal;
                plane.thickness = p.sigmas[2];
                plane.eigen_ratio = p.eigen_ratio;
                plane.colour = p.colour;
                plane.acc_normal = normal;
                plane.acc_offset = linalg::dot(normal, c);
                plane.acc_thickness = p.sigmas[2];
                plane.acc_ratio = p.eigen_ratio;
                plane.acc_colour = p.colour.map(|x| x as f32);
                match self.planes.push(plane) {
                    Some(i) => {
                        self.take_id();
                        stats.planes_created += 1;
                        i
                    }
                    None => {
                        stats.planes_dropped += 1;
                        return;
                    }
                }
            }
        };
        let Some(w) = self.planes.get_mut(index) else { return };
        // Accumulate: support-weighted means, weighted by occupied cells (a map plane carries no point
        // count); the frame's normal turned to agree with the world's.
        let wb = p.cells.count().max(1) as f32;
        accumulate(w, wb, (n, c), (p.sigmas[2], p.eigen_ratio, p.colour.map(|x| x as f32)));
        w.support = w.support.saturating_add(wb as u32);
        w.last_frame = frame;
        // A step of the geometry: the shown plane is more than PUBLISH_PLANE_M off the accumulated one
        // anywhere within its reach (offset at the origin plus the tilt over the reach).
        let tilt = linalg::norm(linalg::cross(w.normal, w.acc_normal));
        let offset = libm::fabsf(linalg::dot(w.acc_normal, w.origin) - w.acc_offset);
        let moved = offset + tilt * w.reach > PUBLISH_PLANE_M;
        // Cells: each frame cell's centre, into the shown grid. New cells wait in the pending list until they
        // are a step (PUBLISH_CELL_SHARE of the shown cells) or do not fit; then all are shown at once.
        let (fe1, fe2) = (linalg::column(&p.rotation, 0), linalg::column(&p.rotation, 1));
        let (origin, ge1, ge2, g) = (w.origin, w.e1, w.e2, self.g_p);
        let for_each_cell = |f: &mut dyn FnMut(Option<usize>)| {
            p.cells.for_each_set(|i, j| {
                let u = (p.cells.a0 as f32 + i as f32 + 0.5) * p.g_p;
                let v = (p.cells.b0 as f32 + j as f32 + 0.5) * p.g_p;
                let local = linalg::add(p.centroid, linalg::add(linalg::scale(fe1, u), linalg::scale(fe2, v)));
                f(grid_index((origin, ge1, ge2), g, local));
            })
        };
        // New cells join the pending list (once each) when an earlier frame has hit them too: a cell hit by one
        // frame alone is usually a boundary cell that frame's grid, drawn into the world grid, pushed past what
        // was seen. A new plane shows its first frame's cells. A full list shows everything at once.
        let (mut clipped, mut overflow, mut reach) = (0u32, false, w.reach);
        let first_view = w.occupied == 0 && w.pending_len == 0;
        for_each_cell(&mut |k| {
            let Some(k) = k else {
                clipped += 1;
                return;
            };
            if !first_view && !bit(&w.seen, k) {
                return;
            }
            let n = w.pending_len as usize;
            if bit(&w.cells, k) || w.pending.get(..n).unwrap_or(&[]).contains(&(k as u16)) {
                return;
            }
            reach = reach.max(cell_reach(k, g));
            match w.pending.get_mut(n) {
                Some(slot) => {
                    *slot = k as u16;
                    w.pending_len += 1;
                }
                None => overflow = true,
            }
        });
        w.reach = reach;
        let grown = overflow || w.pending_len as f32 > PUBLISH_CELL_SHARE * w.occupied as f32;
        // Either step shows both (the record is sent anyway): the accumulated normal and offset, e1 projected
        // onto the new plane, e2 completing the frame, the origin moved onto it (cells keep their indices), and
        // every pending cell.
        if moved || grown {
            stats.planes_moved += moved as u32;
            let normal = w.acc_normal;
            let e1 = linalg::normalize_or(linalg::sub(w.e1, linalg::scale(normal, linalg::dot(w.e1, normal))), w.e1);
            w.e2 = linalg::cross(normal, e1);
            w.e1 = e1;
            w.normal = normal;
            w.origin = linalg::add(w.origin, linalg::scale(normal, w.acc_offset - linalg::dot(normal, w.origin)));
            w.thickness = w.acc_thickness;
            w.eigen_ratio = w.acc_ratio;
            w.colour = w.acc_colour.map(|x| libm::roundf(x.clamp(0.0, 255.0)) as u8);
            for &k in w.pending.get(..w.pending_len as usize).unwrap_or(&[]) {
                set_bit(&mut w.cells, k as usize);
            }
            w.pending_len = 0;
            if overflow {
                for_each_cell(&mut |k| {
                    if let Some(k) = k.filter(|&k| first_view || bit(&w.seen, k)) {
                        set_bit(&mut w.cells, k);
                    }
                });
            }
            fill_holes(&mut w.cells);
            w.occupied = w.cells.iter().map(|b| b.count_ones()).sum();
            stats.planes_grown += grown as u32;
        }
        // Only now is this frame's hit recorded: marked in the first pass, two frame cells drawn into one world
        // cell would count as two frames.
        for_each_cell(&mut |k| {
            if let Some(k) = k {
                set_bit(&mut w.seen, k);
            }
        });
        w.clipped_cells = w.clipped_cells.saturating_add(clipped);
        stats.cells_clipped += clipped;
    }

    /// Adds frame superquadric `s` (its track's smoothed state where the frame's points allow it), already in
    /// the world frame.
    fn add_object(&mut self, s: &MapSq, frame: u32, params: &Params, stats: &mut WorldStats) {
        let sq = s.sq;
        // The world object of this track (not one another sighting updated this frame).
        let found = self
            .objects
            .as_slice()
            .iter()
            .position(|o| o.track == s.track && o.class == s.class && o.last_frame != frame);
        if s.partial {
            // The camera saw only part of it: beyond the image border the fit guessed (redkitchen's default
            // sample showed a 1.2 m slab beside the left wall, cut by the border in all 17 of its sightings, with
            // 73 % of the world superquadrics' squared G2R error). Such a view is a stray fit of a shown object
            // of its track (it stays alive, and explains the frame Gaussians near it); for one not yet shown it
            // counts as a sighting in a row when it agrees with the object's latest whole view, whose shape the
            // object keeps.
            stats.objects_partial += 1;
            match found.and_then(|i| self.objects.get_mut(i)) {
                Some(o) if o.is_confirmed() => {
                    o.sq = sq;
                    o.last_frame = frame;
                    o.frames_seen = o.frames_seen.saturating_add(1);
                }
                Some(o) if agree(&o.sq, &sq) => {
                    o.last_frame = frame;
                    o.frames_seen = o.frames_seen.saturating_add(1);
                }
                _ => {}
            }
            return;
        }
        let objects = self.objects.as_slice();
        let adopted = found.or_else(|| {
            objects.iter().position(|o| {
                let reach = params.d_max.max(max3(o.sq.scales)).max(max3(sq.scales));
                o.class == s.class
                    && o.last_frame != frame
                    && linalg::norm(linalg::sub(o.sq.centre, sq.centre)) <= reach
            })
        });
        let index = match adopted {
            Some(i) => {
                stats.objects_updated += 1;
                i
            }
            None => {
                if self.objects.len() == self.objects.usage().capacity {
                    // Full: evict the object unseen longest (the lowest index, which is the lowest id: objects
                    // stay in creation order), unless every object was seen this frame.
                    let victim = crate::pool::stalest(self.objects.as_slice(), frame, |o| o.last_frame);
                    match victim {
                        Some(v) if self.note_removal(KIND_SQ, v) => {
                            remove_at(&mut self.objects, v);
                            stats.objects_evicted += 1;
                        }
                        _ => {
                            stats.objects_dropped += 1;
                            return;
                        }
                    }
                }
                let object = WorldObject { id: self.next_id, shown: *s, ..WorldObject::zeroed() };
                match self.objects.push(object) {
                    Some(i) => {
                        self.take_id();
                        stats.objects_created += 1;
                        i
                    }
                    None => {
                        stats.objects_dropped += 1;
                        return;
                    }
                }
            }
        };
        if let Some(o) = self.objects.get_mut(index) {
            let agrees = agree(&o.sq, &sq);
            // The centre is the mean over the sightings in a row that agree and come from one track (at most the
            // last `OBJECT_CENTRE_FRAMES`): a static object's fits scatter by a centimetre or two from frame to
            // frame. A new track starts a new mean (the old one may have followed another view of it).
            let n = if agrees && o.track == s.track { o.frames_seen.min(OBJECT_CENTRE_FRAMES - 1) } else { 0 };
            let k = 1.0 / (n + 1) as f32;
            let centre = linalg::add(o.sq.centre, linalg::scale(linalg::sub(sq.centre, o.sq.centre), k));
            let sq = Superquadric { centre, ..sq };
            o.sq = sq;
            o.track = s.track;
            o.class = s.class;
            o.score = o.score.max(s.score);
            o.last_frame = frame;
            o.frames_seen = if o.is_confirmed() || agrees { o.frames_seen.saturating_add(1) } else { 1 };
            let shown = &o.shown.sq;
            let moved = linalg::norm(linalg::sub(shown.centre, sq.centre)) > PUBLISH_MOVE_M;
            let turned = linalg::rotation_angle_between(&shown.rotation, &sq.rotation) > PUBLISH_ANGLE_DEG.to_radians();
            let reshaped = (0..3).any(|k| {
                let (a, b) = (shown.scales.get(k).copied().unwrap_or(0.0), sq.scales.get(k).copied().unwrap_or(0.0));
                libm::fabsf(a - b) > PUBLISH_SHAPE_CHANGE * a.max(b)
            }) || (0..2).any(|k| {
                let (a, b) = (shown.eps.get(k).copied().unwrap_or(0.0), sq.eps.get(k).copied().unwrap_or(0.0));
                libm::fabsf(a - b) > PUBLISH_SHAPE_CHANGE
            });
            // A shown object keeps its shown shape through a stray fit: a new shape is shown only when it
            // agrees with the sighting before it. (Frame Gaussians near that fit are explained all the same,
            // see `explains`.)
            if !agrees && o.is_confirmed() {
                return;
            }
            if moved || turned || reshaped || o.shown.track != s.track || o.shown.class != s.class {
                o.shown = MapSq { sq, instance: 0, class: o.class, score: o.score, track: o.track, partial: false };
            }
        }
    }

    /// Adds frame Gaussian `g`, already in the world frame.
    fn add_gaussian(&mut self, g: &MapGmm, frame: u32, params: &Params, stats: &mut WorldStats) {
        let obs = Observed {
            mean: g.mean,
            covariance: covariance_of(&g.rotation, g.sigmas),
            count: g.count.max(1),
            colour: g.colour.map(|c| c as f32),
            class: g.class,
            score: g.score,
        };
        if self.explains(obs.mean, &obs.covariance, params) {
            stats.gmms_explained += 1;
            return;
        }
        let growth2 = params.world_gmm_growth * params.world_gmm_growth;
        let mut best: Option<(usize, f32)> = None;
        // A frame's Gaussians are distinct parts of what it saw: each merges into a world Gaussian that no
        // other Gaussian of the same frame has touched.
        for (i, w) in self.gaussians.as_slice().iter().enumerate().filter(|(_, w)| w.last_frame != frame) {
            let sum = add_sym(w.covariance, obs.covariance, MERGE_NOISE_VAR);
            let delta = linalg::sub(obs.mean, w.mean);
            // d² ≤ gate needs |Δ|² ≤ gate · λmax ≤ gate · trace: a cheap first test.
            if linalg::dot(delta, delta) > params.world_gmm_gate * trace(sum) {
                continue;
            }
            let Some(d2) = mahalanobis2(sum, delta) else { continue };
            if d2 > params.world_gmm_gate || best.is_some_and(|(_, b)| d2 >= b) {
                continue;
            }
            let merged = merge(w, &obs);
            if trace(merged.covariance) <= growth2 * trace(w.covariance).max(trace(obs.covariance)) {
                best = Some((i, d2));
            }
        }
        if let Some((i, _)) = best {
            if let Some(w) = self.gaussians.get_mut(i) {
                let m = merge(w, &obs);
                w.mean = m.mean;
                w.covariance = m.covariance;
                w.colour = m.colour;
                if obs.score > w.score {
                    w.score = obs.score;
                    w.class = obs.class;
                }
                w.count = m.count;
                w.last_frame = frame;
                w.frames_seen = w.frames_seen.saturating_add(1);
                publish_gaussian(w, false);
                stats.gmms_merged += 1;
            }
            return;
        }
        if self.gaussians.len() == self.gaussians.usage().capacity {
            let victim = self
                .gaussians
                .as_slice()
                .iter()
                .enumerate()
                .filter(|(_, w)| w.last_frame != frame)
                .min_by_key(|(_, w)| (w.count, w.last_frame, w.id))
                .filter(|(_, w)| w.count < obs.count)
                .map(|(i, _)| i);
            match victim {
                Some(v) if self.note_removal(KIND_GMM, v) => {
                    remove_at(&mut self.gaussians, v);
                    stats.gmms_evicted += 1;
                }
                _ => {
                    stats.gmms_dropped += 1;
                    return;
                }
            }
        }
        let mut w = WorldGaussian {
            id: self.next_id,
            mean: obs.mean,
            covariance: obs.covariance,
            count: obs.count,
            colour: obs.colour,
            class: obs.class,
            score: obs.score,
            last_frame: frame,
            frames_seen: 1,
            ..WorldGaussian::zeroed()
        };
        publish_gaussian(&mut w, true);
        match self.gaussians.push(w) {
            Some(_) => {
                self.take_id();
                stats.gmms_created += 1;
            }
            None => stats.gmms_dropped += 1,
        }
    }

    /// Whether a world superquadric or plane explains a Gaussian with `mean` and `covariance` ([`EXPLAINED_M`]):
    /// its mean is inside or near a shown superquadric's surface or that of its latest fit (a stray fit is not
    /// shown, but the Gaussians beside it are that object's), or near a plane, over a shown or pending cell of
    /// that plane (±1 cell), when its least-variance axis follows the plane's normal (within
    /// `world_plane_angle_deg`) or its mean ± 2σ along that normal stays within `EXPLAINED_M` of the plane. The
    /// second test catches strips and small patches lying in the plane, whose own thinnest axis is ill-defined
    /// (two small variances of a similar size): on redkitchen 0–299 it removed 36 of 516 world Gaussians, the map
    /// 17.7 → 16.7 KB, at the same G2R and R2G. A patch of a face that stands on the plane reaches far along
    /// its normal and stays.
    fn explains(&self, mean: Vec3, covariance: &Sym3, params: &Params) -> bool {
        if self.objects.as_slice().iter().any(|o| {
            o.is_confirmed() && (o.shown.sq.distance(mean) <= EXPLAINED_M || o.sq.distance(mean) <= EXPLAINED_M)
        }) {
            return true;
        }
        let e = linalg::sym_eigen(*covariance);
        let cos_min = libm::cosf(params.world_plane_angle_deg.to_radians());
        self.planes.as_slice().iter().any(|p| {
            let q = linalg::sub(mean, p.origin);
            let offset = libm::fabsf(linalg::dot(q, p.normal));
            let within = offset + 2.0 * linalg::sqrt(linalg::variance_along(covariance, p.normal)) <= EXPLAINED_M;
            if offset > EXPLAINED_M || (!within && libm::fabsf(linalg::dot(e.normal(), p.normal)) < cos_min) {
                return false;
            }
            let (a, b) = grid_cell((p.origin, p.e1, p.e2), self.g_p, mean);
            let pending = p.pending.get(..p.pending_len as usize).unwrap_or(&[]);
            (-1..=1).any(|db| {
                (-1..=1).any(|da| {
                    let (a, b) = (a + da, b + db);
                    if !((0..WORLD_GRID as i32).contains(&a) && (0..WORLD_GRID as i32).contains(&b)) {
                        return false;
                    }
                    let k = b as usize * WORLD_GRID + a as usize;
                    bit(&p.cells, k) || pending.contains(&(k as u16))
                })
            })
        })
    }

    /// Records the removal of element `index` of pool `kind` for the next delta (only when a delta carried it);
    /// false when the removal list is full, and then the element must stay.
    fn note_removal(&mut self, kind: u8, index: usize) -> bool {
        let (id, sent) = match kind {
            KIND_PLANE => self.planes.get(index).map(|p| (p.id, p.sent)),
            KIND_SQ => self.objects.get(index).map(|o| (o.id, o.sent)),
            _ => self.gaussians.get(index).map(|g| (g.id, g.sent)),
        }
        .unwrap_or((0, 0));
        sent == 0 || self.removed.push((kind, id)).is_some()
    }

    /// Calls `f(id, primitive)` for every world primitive, world frame: planes, objects, Gaussians, each in
    /// increasing id order.
    pub fn for_each_primitive(&self, mut f: impl FnMut(u32, &Primitive<'_>)) {
        for p in self.planes.as_slice() {
            f(p.id, &Primitive::Plane(plane_view(p, self.g_p)));
        }
        for o in self.objects.as_slice().iter().filter(|o| o.is_confirmed()) {
            f(o.id, &Primitive::Sq(o.shown));
        }
        for g in self.gaussians.as_slice().iter().filter(|g| g.is_confirmed()) {
            f(g.id, &Primitive::Gmm(g.shown));
        }
    }

    /// Writes the world map (`world.bin`) through `out` with `scratch` (≥ [`wire::MAX_WORLD_RECORD_BYTES`]) as
    /// the only buffer; returns the bytes written. Changes nothing.
    pub fn encode_streaming(
        &self,
        scratch: &mut [u8],
        out: impl FnMut(&[u8]) -> Result<(), WireError>,
    ) -> Result<usize, WireError> {
        let mut record = [0u8; wire::MAX_WORLD_RECORD_BYTES];
        wire::encode_world_records(
            self.frame.unwrap_or(0),
            |sink| self.for_each_record(&mut record, |kind, id, bytes, _| sink(kind, id, bytes)),
            scratch,
            out,
        )
    }

    /// Writes the world map into `buf`; returns the bytes written.
    pub fn encode(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        let mut scratch = [0u8; 32];
        let mut used = 0usize;
        self.encode_streaming(&mut scratch, |bytes| {
            let end = used + bytes.len();
            buf.get_mut(used..end).ok_or(WireError::BufferTooSmall)?.copy_from_slice(bytes);
            used = end;
            Ok(())
        })
    }

    /// Calls `f(kind, id, record bytes, CRC of the record last sent or None)` for every record in (kind, id)
    /// order, each written into `record`.
    fn for_each_record(
        &self,
        record: &mut [u8],
        mut f: impl FnMut(u8, u32, &[u8], Option<u32>) -> Result<(), WireError>,
    ) -> Result<(), WireError> {
        let mut one = |id: u32, p: &Primitive<'_>, sent: u8, crc: u32| {
            let n = wire::write_world_record(id, p, record)?;
            f(wire::kind_of(p), id, record.get(..n).unwrap_or(&[]), (sent != 0).then_some(crc))
        };
        for p in self.planes.as_slice() {
            one(p.id, &Primitive::Plane(plane_view(p, self.g_p)), p.sent, p.sent_crc)?;
        }
        for o in self.objects.as_slice().iter().filter(|o| o.is_confirmed()) {
            one(o.id, &Primitive::Sq(o.shown), o.sent, o.sent_crc)?;
        }
        for g in self.gaussians.as_slice().iter().filter(|g| g.is_confirmed()) {
            one(g.id, &Primitive::Gmm(g.shown), g.sent, g.sent_crc)?;
        }
        Ok(())
    }

    /// Writes the delta of the last integrated frame through `out` (`scratch` as for
    /// [`WorldMap::encode_streaming`]): the records that are new or whose bytes changed since the last delta,
    /// then the removals since then. Only once the whole delta is written are the records marked as sent and
    /// the removals cleared, so a failed write can be retried. Returns the bytes written.
    pub fn encode_delta_streaming(
        &mut self,
        scratch: &mut [u8],
        out: impl FnMut(&[u8]) -> Result<(), WireError>,
    ) -> Result<usize, WireError> {
        let mut record = [0u8; wire::MAX_WORLD_RECORD_BYTES];
        let this = &*self;
        let n = wire::encode_delta_records(
            this.frame.unwrap_or(0),
            |sink| {
                this.for_each_record(&mut record, |kind, id, bytes, sent| {
                    if sent == Some(wire::crc32(bytes)) {
                        Ok(())
                    } else {
                        sink(kind, id, bytes)
                    }
                })
            },
            |sink| this.removed.as_slice().iter().try_for_each(|&(kind, id)| sink(kind, id)),
            scratch,
            out,
        )?;
        // Commit: every record as it now is has been sent.
        let g_p = self.g_p;
        for p in self.planes.as_mut_slice() {
            let n = wire::write_world_record(p.id, &Primitive::Plane(plane_view(p, g_p)), &mut record)?;
            p.sent_crc = wire::crc32(record.get(..n).unwrap_or(&[]));
            p.sent = 1;
        }
        for o in self.objects.as_mut_slice().iter_mut().filter(|o| o.is_confirmed()) {
            let n = wire::write_world_record(o.id, &Primitive::Sq(o.shown), &mut record)?;
            o.sent_crc = wire::crc32(record.get(..n).unwrap_or(&[]));
            o.sent = 1;
        }
        for g in self.gaussians.as_mut_slice().iter_mut().filter(|g| g.is_confirmed()) {
            let n = wire::write_world_record(g.id, &Primitive::Gmm(g.shown), &mut record)?;
            g.sent_crc = wire::crc32(record.get(..n).unwrap_or(&[]));
            g.sent = 1;
        }
        self.removed.clear();
        Ok(n)
    }

    /// Writes the delta into `buf`; returns the bytes written.
    pub fn encode_delta(&mut self, buf: &mut [u8]) -> Result<usize, WireError> {
        let mut scratch = [0u8; 32];
        let mut used = 0usize;
        self.encode_delta_streaming(&mut scratch, |bytes| {
            let end = used + bytes.len();
            buf.get_mut(used..end).ok_or(WireError::BufferTooSmall)?.copy_from_slice(bytes);
            used = end;
            Ok(())
        })
    }
}

/// A world plane as a map plane (world frame, its shown state): its grid, with σ0, σ1 the spread of its
/// occupied cells along e1 and e2 and σ2 its mean thickness.
pub fn plane_view(p: &WorldPlane, g_p: f32) -> MapPlane<'_> {
    let half = (WORLD_GRID / 2) as i16;
    let cells = CellBits {
        a0: -half,
        b0: -half,
        width: WORLD_GRID as u16,
        height: WORLD_GRID as u16,
        coding: CellCoding::Bitmap,
        bits: &p.cells,
    };
    let mut m = Moments::about([0.0; 3]);
    cells.for_each_set(|i, j| m.add([i as f32 * g_p, j as f32 * g_p, 0.0], 1.0));
    let cov = m.covariance();
    MapPlane {
        centroid: p.origin,
        rotation: linalg::from_columns(p.e1, p.e2, p.normal),
        sigmas: [linalg::sqrt(cov[0].max(0.0)), linalg::sqrt(cov[3].max(0.0)), p.thickness],
        eigen_ratio: p.eigen_ratio,
        colour: p.colour,
        cluster: 0,
        g_p,
        cells,
    }
}

/// Shows a world Gaussian's accumulated state when `force`, or when it is a step away from the shown one: the
/// mean moved by more than max([`PUBLISH_MOVE_M`], half the largest σ), the covariance changed by more than
/// [`PUBLISH_GMM_SHAPE_CHANGE`] of its Frobenius norm, or the support doubled.
fn publish_gaussian(w: &mut WorldGaussian, force: bool) {
    let shown = &w.shown;
    let reach = PUBLISH_MOVE_M.max(0.5 * shown.sigmas[0]);
    let moved = linalg::norm(linalg::sub(shown.mean, w.mean)) > reach;
    let d: Sym3 = core::array::from_fn(|k| {
        w.covariance.get(k).copied().unwrap_or(0.0) - w.shown_covariance.get(k).copied().unwrap_or(0.0)
    });
    let reshaped = frobenius2(d) > PUBLISH_GMM_SHAPE_CHANGE * PUBLISH_GMM_SHAPE_CHANGE * frobenius2(w.shown_covariance);
    let grown = w.count / 2 > shown.count;
    if !(force || moved || reshaped || grown) {
        return;
    }
    let e = linalg::sym_eigen(w.covariance);
    w.shown_covariance = w.covariance;
    w.shown = MapGmm {
        mean: w.mean,
        rotation: linalg::from_columns(e.vectors[0], e.vectors[1], e.vectors[2]),
        sigmas: e.sigmas(),
        count: w.count,
        colour: w.colour.map(|c| libm::roundf(c.clamp(0.0, 255.0)) as u8),
        instance: 0,
        class: w.class,
        score: w.score,
        support_ratio: 1.0,
    };
}

/// Folds a plane of weight `weight` (occupied cells or support) into world plane `w`'s accumulated state, the
/// support-weighted means against `w.support`: its normal (turned to agree with `w`'s) through `point`, and its
/// thickness, λ2/λ0 and colour. The caller adds the support.
fn accumulate(
    w: &mut WorldPlane,
    weight: f32,
    (normal, point): (Vec3, Vec3),
    (thickness, ratio, colour): (f32, f32, [f32; 3]),
) {
    let n = if linalg::dot(normal, w.acc_normal) < 0.0 { linalg::scale(normal, -1.0) } else { normal };
    let k = weight / (w.support as f32 + weight);
    w.acc_normal = linalg::normalize_or(linalg::add(linalg::scale(w.acc_normal, 1.0 - k), linalg::scale(n, k)), n);
    w.acc_offset += (linalg::dot(w.acc_normal, point) - w.acc_offset) * k;
    w.acc_thickness += (thickness - w.acc_thickness) * k;
    w.acc_ratio += (ratio - w.acc_ratio) * k;
    for (acc, x) in w.acc_colour.iter_mut().zip(colour) {
        *acc += (x - *acc) * k;
    }
}

/// The column and row of the cell of the grid (`origin`, `e1`, `e2`) of `g`-metre cells that holds world point
/// `x` (its projection onto the grid's plane); inside the grid when both lie in 0..[`WORLD_GRID`].
fn grid_cell((origin, e1, e2): (Vec3, Vec3, Vec3), g: f32, x: Vec3) -> (i32, i32) {
    let half = (WORLD_GRID / 2) as i32;
    let q = linalg::sub(x, origin);
    (linalg::floor_i32(linalg::dot(q, e1) / g) + half, linalg::floor_i32(linalg::dot(q, e2) / g) + half)
}

/// The bit index of the cell of the grid (`origin`, `e1`, `e2`) of `g`-metre cells that holds world point `x`
/// (its projection onto the grid's plane), `None` outside the grid.
fn grid_index(grid: (Vec3, Vec3, Vec3), g: f32, x: Vec3) -> Option<usize> {
    let (a, b) = grid_cell(grid, g, x);
    let inside = (0..WORLD_GRID as i32).contains(&a) && (0..WORLD_GRID as i32).contains(&b);
    inside.then(|| b as usize * WORLD_GRID + a as usize)
}

/// The centre of cell `k` (a bit index) of a world grid in cells from the grid's origin, along e1 and e2.
fn centred(k: usize) -> (f32, f32) {
    let half = (WORLD_GRID / 2) as f32;
    ((k % WORLD_GRID) as f32 + 0.5 - half, (k / WORLD_GRID) as f32 + 0.5 - half)
}

/// How far the centre of cell `k` (a bit index) of a world grid of `g`-metre cells lies from its origin, metres.
fn cell_reach(k: usize, g: f32) -> f32 {
    let (a, b) = centred(k);
    linalg::sqrt(a * a + b * b) * g
}

/// The centre of cell `k` (a bit index) of world plane `p`'s shown grid of `g`-metre cells, world frame.
fn cell_centre(p: &WorldPlane, g: f32, k: usize) -> Vec3 {
    let (a, b) = centred(k);
    linalg::add(p.origin, linalg::add(linalg::scale(p.e1, a * g), linalg::scale(p.e2, b * g)))
}

/// Calls `f(k)` for every set bit `k` of a world plane's bitmap.
fn for_each_bit(bits: &[u8; WORLD_GRID_BYTES], mut f: impl FnMut(usize)) {
    for (byte, &b) in bits.iter().enumerate() {
        let mut b = b;
        while b != 0 {
            f(8 * byte + b.trailing_zeros() as usize);
            b &= b - 1;
        }
    }
}

/// Whether world plane `small` describes the surface of world plane `big`, as a frame plane must to join a
/// world plane ([`WorldMap::add_plane`]'s test, with the cells some frame hit standing in for a frame's cells):
/// normals within `cos_min`, the centroid of its hit cells (on its accumulated plane) within `world_plane_offset`
/// of `big`'s accumulated plane, or within [`JOIN_SHARED_OFFSETS`] offsets when at least half of its hit cells lie
/// on cells `big` has hit, and its far cells within [`PLANE_BEND_OFFSETS`] offsets; and they touch (a hit cell
/// in common).
fn same_surface(big: &WorldPlane, small: &WorldPlane, g: f32, cos_min: f32, params: &Params) -> bool {
    if libm::fabsf(linalg::dot(big.acc_normal, small.acc_normal)) < cos_min {
        return false;
    }
    let (mut sum, mut n, mut shared) = ([0.0f32; 3], 0u32, 0u32);
    let grid = (big.origin, big.e1, big.e2);
    for_each_bit(&small.seen, |k| {
        let x = cell_centre(small, g, k);
        sum = linalg::add(sum, x);
        n += 1;
        shared += u32::from(grid_index(grid, g, x).is_some_and(|i| bit(&big.seen, i)));
    });
    if shared == 0 {
        return false;
    }
    let gate = if 2 * shared >= n { JOIN_SHARED_OFFSETS } else { 1.0 } * params.world_plane_offset;
    // The hit cells' centroid on the shown plane, and on the accumulated one.
    let shown = linalg::scale(sum, 1.0 / n as f32);
    let c =
        linalg::add(shown, linalg::scale(small.acc_normal, small.acc_offset - linalg::dot(small.acc_normal, shown)));
    let mut reach = 0.0f32;
    for_each_bit(&small.seen, |k| reach = reach.max(linalg::norm(linalg::sub(cell_centre(small, g, k), shown))));
    let off = libm::fabsf(linalg::dot(big.acc_normal, c) - big.acc_offset);
    let bend = linalg::norm(linalg::cross(big.acc_normal, small.acc_normal)) * reach;
    off <= gate && off + bend <= PLANE_BEND_OFFSETS * params.world_plane_offset
}

/// Draws world plane `from` into world plane `into` (both of one surface, [`same_surface`]): support-weighted
/// accumulated geometry as [`WorldMap::add_plane`] merges a frame plane, and its hit, pending and shown cells
/// into `into`'s grid (the shown ones shown, holes filled).
fn draw_plane_into(into: &mut WorldPlane, from: &WorldPlane, g: f32) {
    // A point of `from`'s accumulated plane: its shown origin moved onto it.
    let on_from = linalg::add(
        from.origin,
        linalg::scale(from.acc_normal, from.acc_offset - linalg::dot(from.acc_normal, from.origin)),
    );
    let shape = (from.acc_thickness, from.acc_ratio, from.acc_colour);
    accumulate(into, from.support.max(1) as f32, (from.acc_normal, on_from), shape);
    into.support = into.support.saturating_add(from.support);
    into.last_frame = into.last_frame.max(from.last_frame);
    let grid = (into.origin, into.e1, into.e2);
    let mut clipped = 0u32;
    for_each_bit(&from.seen, |k| match grid_index(grid, g, cell_centre(from, g, k)) {
        Some(i) => {
            set_bit(&mut into.seen, i);
            if bit(&from.cells, k) {
                set_bit(&mut into.cells, i);
            }
        }
        None => clipped += 1,
    });
    for &k in from.pending.get(..from.pending_len as usize).unwrap_or(&[]) {
        let Some(i) = grid_index(grid, g, cell_centre(from, g, k as usize)) else { continue };
        let n = into.pending_len as usize;
        if bit(&into.cells, i) || into.pending.get(..n).unwrap_or(&[]).contains(&(i as u16)) {
            continue;
        }
        match into.pending.get_mut(n) {
            Some(slot) => {
                *slot = i as u16;
                into.pending_len += 1;
            }
            None => set_bit(&mut into.cells, i),
        }
    }
    fill_holes(&mut into.cells);
    into.occupied = into.cells.iter().map(|b| b.count_ones()).sum();
    let mut reach = into.reach;
    for_each_bit(&into.cells, |k| reach = reach.max(cell_reach(k, g)));
    for &k in into.pending.get(..into.pending_len as usize).unwrap_or(&[]) {
        reach = reach.max(cell_reach(k as usize, g));
    }
    into.reach = reach;
    into.clipped_cells = into.clipped_cells.saturating_add(from.clipped_cells).saturating_add(clipped);
}

/// Sets every unset cell of a world plane's bitmap that has at least three set 4-neighbours (judged on the
/// bitmap as it was): the holes a frame grid drawn into a rotated world grid leaves, one cell centre per frame
/// cell, without growing the boundary.
fn fill_holes(cells: &mut [u8; WORLD_GRID_BYTES]) {
    let before = *cells;
    let is_set = |a: usize, b: usize| {
        let k = b * WORLD_GRID + a;
        bit(&before, k)
    };
    for b in 1..WORLD_GRID - 1 {
        for a in 1..WORLD_GRID - 1 {
            if is_set(a, b) {
                continue;
            }
            let n = [(a - 1, b), (a + 1, b), (a, b - 1), (a, b + 1)].iter().filter(|&&(x, y)| is_set(x, y)).count();
            if n >= 3 {
                set_bit(cells, b * WORLD_GRID + a);
            }
        }
    }
}

/// Whether two fits `a`, `b` of one object agree: centres within max([`PUBLISH_MOVE_M`], [`AGREEMENT`] × the
/// largest half-axis of either) and the half-axes, sorted (a fit may order its axes differently), each within
/// [`AGREEMENT`] of the larger.
pub(crate) fn agree(a: &Superquadric, b: &Superquadric) -> bool {
    let sorted = |s: Vec3| {
        let mut s = s;
        s.sort_unstable_by(|x, y| x.total_cmp(y));
        s
    };
    let reach = (AGREEMENT * max3(a.scales).max(max3(b.scales))).max(PUBLISH_MOVE_M);
    linalg::norm(linalg::sub(a.centre, b.centre)) <= reach
        && sorted(a.scales).iter().zip(sorted(b.scales)).all(|(&x, y)| libm::fabsf(x - y) <= AGREEMENT * x.max(y))
}

/// Squared Frobenius norm of a symmetric matrix.
fn frobenius2(s: Sym3) -> f32 {
    let [a, b, c, d, e, f] = s;
    a * a + d * d + f * f + 2.0 * (b * b + c * c + e * e)
}

/// Removes element `index` of `pool`, keeping the order of the rest.
fn remove_at<T: Copy>(pool: &mut Bounded<'_, T>, index: usize) {
    let items = pool.as_mut_slice();
    if index < items.len() {
        if let Some(tail) = items.get_mut(index..) {
            tail.rotate_left(1);
        }
        pool.pop();
    }
}

fn max3(v: Vec3) -> f32 {
    v[0].max(v[1]).max(v[2])
}

fn trace(s: Sym3) -> f32 {
    s[0] + s[3] + s[5]
}

fn add_sym(a: Sym3, b: Sym3, diagonal: f32) -> Sym3 {
    [a[0] + b[0] + diagonal, a[1] + b[1], a[2] + b[2], a[3] + b[3] + diagonal, a[4] + b[4], a[5] + b[5] + diagonal]
}

/// R · diag(σ²) · Rᵀ for the rotation whose columns are the axes.
fn covariance_of(axes: &linalg::Mat3, sigmas: Vec3) -> Sym3 {
    let mut s = [0.0f32; 6];
    for k in 0..3 {
        let c = linalg::column(axes, k);
        let v = sigmas.get(k).copied().unwrap_or(0.0);
        let v = v * v;
        s[0] += v * c[0] * c[0];
        s[1] += v * c[0] * c[1];
        s[2] += v * c[0] * c[2];
        s[3] += v * c[1] * c[1];
        s[4] += v * c[1] * c[2];
        s[5] += v * c[2] * c[2];
    }
    s
}

/// Δᵀ S⁻¹ Δ for a symmetric positive-definite S (adjugate over determinant); `None` when S is singular.
fn mahalanobis2(s: Sym3, d: Vec3) -> Option<f32> {
    let [a, b, c, e, f, i] = s;
    // S = [[a, b, c], [b, e, f], [c, f, i]]
    let (c00, c01, c02) = (e * i - f * f, c * f - b * i, b * f - c * e);
    let (c11, c12, c22) = (a * i - c * c, b * c - a * f, a * e - b * b);
    let det = a * c00 + b * c01 + c * c02;
    if det.is_nan() || det <= 0.0 || det.is_infinite() {
        return None;
    }
    let q = d[0] * (c00 * d[0] + c01 * d[1] + c02 * d[2])
        + d[1] * (c01 * d[0] + c11 * d[1] + c12 * d[2])
        + d[2] * (c02 * d[0] + c12 * d[1] + c22 * d[2]);
    Some(q / det)
}

/// The moment-matched union of a world Gaussian and an observation.
fn merge(w: &WorldGaussian, o: &Observed) -> WorldGaussian {
    let mut m = Moments::about(w.mean);
    m.add_gaussian(w.mean, w.covariance, w.count as f32);
    m.add_gaussian(o.mean, o.covariance, o.count as f32);
    let count = w.count.saturating_add(o.count);
    let k = o.count as f32 / count.max(1) as f32;
    let mut colour = w.colour;
    for (acc, c) in colour.iter_mut().zip(o.colour) {
        *acc += (c - *acc) * k;
    }
    WorldGaussian { mean: m.mean(), covariance: m.covariance(), count, colour, ..*w }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use crate::map::CellCoding;
    use std::collections::BTreeMap;
    use std::vec::Vec;

    type Small = WorldStorage<4, 4, 8, 8>;

    fn identity() -> Pose {
        Pose { rotation: linalg::IDENTITY, translation: [0.0; 3] }
    }

    fn moved(x: f32) -> Pose {
        Pose { rotation: linalg::IDENTITY, translation: [x, 0.0, 0.0] }
    }

    /// Sets columns `i0..i1` of rows `j0..j1` of an 80 × 80 cell bitmap.
    fn block(bits: &mut [u8; 800], (i0, i1): (usize, usize), (j0, j1): (usize, usize)) -> &mut [u8; 800] {
        for j in j0..j1 {
            for i in i0..i1 {
                let k = j * 80 + i;
                bits[k / 8] |= 1 << (k % 8);
            }
        }
        bits
    }

    /// A floor 1 m below the camera (normal −y, camera frame) with the cells of columns `i0..i1`, rows 0..10 of
    /// an 80 × 80 grid around its centroid set.
    fn floor(bits: &mut [u8; 800], i0: usize, i1: usize) -> MapPlane<'_> {
        let bits = block(bits, (i0, i1), (0, 10));
        MapPlane {
            centroid: [0.0, 1.0, 2.0],
            rotation: linalg::from_columns([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]),
            sigmas: [0.5, 0.5, 0.004],
            eigen_ratio: 0.001,
            colour: [100, 100, 100],
            cluster: 0,
            g_p: 0.05,
            cells: CellBits { a0: -40, b0: -40, width: 80, height: 80, coding: CellCoding::Bitmap, bits },
        }
    }

    fn gmm(mean: Vec3, count: u32) -> MapGmm {
        MapGmm {
            mean,
            rotation: linalg::IDENTITY,
            sigmas: [0.05, 0.03, 0.004],
            count,
            colour: [200, 10, 10],
            instance: 0,
            class: 0,
            score: 0.0,
            support_ratio: 0.0,
        }
    }

    fn sq(centre: Vec3, track: u16) -> MapSq {
        let sq = Superquadric { scales: [0.1, 0.1, 0.2], eps: [0.5, 0.5], centre, rotation: linalg::IDENTITY };
        MapSq { sq, instance: 3, class: 2, score: 0.9, track, partial: false }
    }

    fn bytes(world: &WorldMap<'_>) -> Vec<u8> {
        let mut out = Vec::new();
        world
            .encode_streaming(&mut [0u8; 32], |b| {
                out.extend_from_slice(b);
                Ok(())
            })
            .unwrap();
        out
    }

    fn delta(world: &mut WorldMap<'_>) -> Vec<u8> {
        let mut out = Vec::new();
        world
            .encode_delta_streaming(&mut [0u8; 32], |b| {
                out.extend_from_slice(b);
                Ok(())
            })
            .unwrap();
        out
    }

    /// A receiver as a ground station would run it: records by (kind, id), written out like the sender's map.
    #[derive(Default)]
    struct Receiver(BTreeMap<(u8, u32), Vec<u8>>, u32);

    impl Receiver {
        fn apply(&mut self, d: &[u8]) -> wire::DeltaHeader {
            let mut changes = Vec::new();
            let h = wire::decode_delta(d, |c| {
                changes.push(match c {
                    wire::DeltaChange::Upsert(r) => (r.kind, r.id, Some(r.bytes.to_vec())),
                    wire::DeltaChange::Remove { kind, id } => (kind, id, None),
                })
            })
            .unwrap();
            for (kind, id, b) in changes {
                match b {
                    Some(b) => self.0.insert((kind, id), b),
                    None => self.0.remove(&(kind, id)),
                };
            }
            self.1 = h.frame;
            h
        }

        fn world(&self) -> Vec<u8> {
            let mut out = Vec::new();
            wire::encode_world_records(
                self.1,
                |sink| self.0.iter().try_for_each(|(&(k, id), b)| sink(k, id, b)),
                &mut [0u8; 32],
                |b| {
                    out.extend_from_slice(b);
                    Ok(())
                },
            )
            .unwrap();
            out
        }
    }

    fn lifted(dy: f32) -> Pose {
        Pose { rotation: linalg::IDENTITY, translation: [0.0, dy, 0.0] }
    }

    /// A floor whose second view lies 6 cm off the first (a pose a few centimetres off) starts a second world
    /// plane; lying mostly over the same cells, the two are one surface and join. Beside it, 12 cm off, or over
    /// other cells only partly shared, they stay two.
    #[test]
    fn two_world_planes_of_one_floor_join() {
        let params = Params::default();
        let run = |dy: f32, (i0, i1): (usize, usize)| {
            let mut storage = bytemuck::zeroed_box::<Small>();
            let mut world = WorldMap::new(&mut storage);
            let (mut a, mut b) = ([0u8; 800], [0u8; 800]);
            let p0 = floor(&mut a, 40, 50);
            let p1 = floor(&mut b, i0, i1);
            world.integrate(0, &identity(), &params, |f| f(&Primitive::Plane(p0))).unwrap();
            let stats = world.integrate(1, &lifted(dy), &params, |f| f(&Primitive::Plane(p1))).unwrap();
            let planes: Vec<WorldPlane> = world.planes().to_vec();
            (stats, planes)
        };
        let (stats, planes) = run(0.06, (40, 50));
        assert_eq!((stats.planes_created, stats.planes_joined), (1, 1), "{stats:?}");
        assert_eq!(planes.len(), 1);
        let p = planes[0];
        // The first plane keeps its id and grid; the accumulated floor lies between the two views (equal support).
        assert_eq!(p.id, 0);
        let height = (p.acc_offset * p.acc_normal[1]).abs();
        assert!((height - 1.03).abs() < 0.005, "accumulated floor at {height} m");
        assert_eq!(p.occupied, 100, "the same 10 × 10 cells");
        assert_eq!(p.support, 200);
        // 12 cm apart: two surfaces.
        let (stats, planes) = run(0.12, (40, 50));
        assert_eq!((stats.planes_created, stats.planes_joined, planes.len()), (1, 0, 2));
        // 6 cm apart over cells of which fewer than half are shared: the first view's gate (5 cm) holds.
        let (stats, planes) = run(0.06, (46, 60));
        assert_eq!((stats.planes_created, stats.planes_joined, planes.len()), (1, 0, 2));
        // 4 cm apart: the second view joins the first as a frame plane does.
        let (stats, planes) = run(0.04, (40, 50));
        assert_eq!((stats.planes_merged, stats.planes_created, stats.planes_joined, planes.len()), (1, 0, 0, 1));
    }

    /// A world plane that was sent and then joins another leaves the receiver's map too, and the receiver holds
    /// the sender's records.
    #[test]
    fn a_joined_plane_leaves_the_receivers_map_too() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        let mut rx = Receiver::default();
        let (mut a, mut b, mut c) = ([0u8; 800], [0u8; 800], [0u8; 800]);
        let (p0, p1, p2) = (floor(&mut a, 40, 50), floor(&mut b, 56, 66), floor(&mut c, 40, 50));
        // Frame 0: the floor; frame 1: 6 cm off it, beside it (no cell shared: a second world plane, sent).
        for (frame, pose, p) in [(0, identity(), p0), (1, lifted(0.06), p1)] {
            let stats = world.integrate(frame, &pose, &params, |f| f(&Primitive::Plane(p))).unwrap();
            assert_eq!(stats.planes_joined, 0);
            rx.apply(&delta(&mut world));
        }
        assert_eq!(world.planes().len(), 2);
        // Frame 2: the second floor over the first one's cells; it feeds the second plane (nearer), which now
        // shares all of the first one's cells and has more support: the first joins it.
        let stats = world.integrate(2, &lifted(0.06), &params, |f| f(&Primitive::Plane(p2))).unwrap();
        assert_eq!((stats.planes_merged, stats.planes_joined), (1, 1), "{stats:?}");
        assert_eq!(world.planes().iter().map(|p| p.id).collect::<Vec<_>>(), [1]);
        let h = rx.apply(&delta(&mut world));
        assert_eq!(h.removals, 1, "the sent plane's removal");
        assert_eq!(rx.world(), bytes(&world));
    }

    #[test]
    fn a_gaussian_within_a_planes_band_is_the_plane_whatever_its_own_thin_axis() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        let mut bits = [0u8; 800];
        world.integrate(0, &identity(), &params, |f| f(&Primitive::Plane(floor(&mut bits, 30, 50)))).unwrap();
        // A strip lying on the floor (y = 1, over occupied cells): 10 cm along x, its two thin axes turned by
        // 45° about x, so its own least-variance axis is 45° off the floor's normal, but its ±2σ band along
        // that normal is ±6.4 mm. Beside it, a patch of a vertical face standing on the floor: thin across z,
        // 5 cm up the face, so its band along the floor's normal is ±10 cm.
        let (c, s) = (core::f32::consts::FRAC_1_SQRT_2, core::f32::consts::FRAC_1_SQRT_2);
        let strip = MapGmm {
            rotation: linalg::from_columns([1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]),
            sigmas: [0.1, 0.005, 0.004],
            ..gmm([0.0, 1.0, 0.25], 100)
        };
        let face = MapGmm {
            rotation: linalg::from_columns([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
            sigmas: [0.05, 0.05, 0.004],
            ..gmm([0.0, 0.98, 0.3], 100)
        };
        let stats = world
            .integrate(1, &identity(), &params, |f| {
                f(&Primitive::Gmm(strip));
                f(&Primitive::Gmm(face));
            })
            .unwrap();
        assert_eq!((stats.gmms_explained, stats.gmms_created), (1, 1));
        assert!((world.gaussians()[0].mean[1] - 0.98).abs() < 1e-6, "the face stays: {:?}", world.gaussians()[0].mean);
    }

    #[test]
    fn a_plane_seen_from_two_places_is_one_world_plane_holding_both_views_cells() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        let (mut a, mut b) = ([0u8; 800], [0u8; 800]);
        // Frame 0 sees columns 40..50; frames 1 and 2, from 0.25 m further along x, see columns 35..50 of their
        // own grid: world columns 40..50 again and 5 more beyond (0.25 m = 5 cells).
        let p0 = floor(&mut a, 40, 50);
        let p1 = floor(&mut b, 35, 50);
        world.integrate(0, &identity(), &params, |f| f(&Primitive::Plane(p0))).unwrap();
        let stats = world.integrate(1, &moved(0.25), &params, |f| f(&Primitive::Plane(p1))).unwrap();
        assert_eq!((stats.planes_merged, stats.planes_created), (1, 0));
        assert_eq!(world.planes().len(), 1);
        // The new cells are hit by one frame only: not shown, not even pending.
        assert_eq!((world.planes()[0].occupied, world.planes()[0].pending_len), (100, 0), "after one sighting");
        world.integrate(2, &moved(0.25), &params, |f| f(&Primitive::Plane(p1))).unwrap();
        let plane = world.planes()[0];
        // 10 × 10 cells, then 5 × 10 more seen twice: 50 new cells are more than 20 % of 100, shown at once.
        assert_eq!(plane.occupied, 150, "shown cells");
        assert_eq!(plane.pending_len, 0);
        // The shown plane is the floor: normal ±y, 1 m below the first camera.
        assert!(libm::fabsf(plane.normal[1]).abs() > 0.999);
        assert!((linalg::dot(plane.normal, plane.origin) - linalg::dot(plane.normal, [0.0, 1.0, 2.0])).abs() < 1e-4);
        let mut samples = 0;
        world.for_each_primitive(|_, p| {
            p.for_each_sample(|x| {
                assert!((x[1] - 1.0).abs() < 1e-4, "a floor sample off the floor: {x:?}");
                samples += 1;
            })
        });
        assert_eq!(samples, 150);
        // Two more views adding 5 cells (under 20 % of 150) keep them pending: not shown, not sent.
        let mut c = [0u8; 800];
        block(&mut c, (40, 45), (10, 11));
        let p2 = floor(&mut c, 40, 50);
        let before = bytes(&world);
        world.integrate(3, &identity(), &params, |f| f(&Primitive::Plane(p2))).unwrap();
        world.integrate(4, &identity(), &params, |f| f(&Primitive::Plane(p2))).unwrap();
        assert_eq!((world.planes()[0].occupied, world.planes()[0].pending_len), (150, 5));
        // Header (magic, version, frame, record count: 5 bytes here) and CRC aside, the map is the same.
        let after = bytes(&world);
        assert_eq!(&after[5..after.len() - 4], &before[5..before.len() - 4], "the records changed");
    }

    #[test]
    fn a_plane_seen_turned_by_30_degrees_leaves_no_hole_in_the_world_grid() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        // Frame 0 sees a small patch (it sets the world grid); frame 1 a 1 m × 1 m square about the same centroid
        // after the camera turned 30° about the floor's normal through it, twice: every world cell well inside the
        // turned square (half a cell margin) is set.
        let (mut small, mut bits) = ([0u8; 800], [0u8; 800]);
        block(&mut small, (39, 41), (39, 41));
        block(&mut bits, (30, 50), (30, 50));
        let first = floor(&mut small, 0, 0);
        let p = floor(&mut bits, 0, 0);
        world.integrate(0, &identity(), &params, |f| f(&Primitive::Plane(first))).unwrap();
        let (s30, c30) = (0.5f32, 0.866_025_4f32);
        let r = [[c30, 0.0, s30], [0.0, 1.0, 0.0], [-s30, 0.0, c30]];
        let c = p.centroid;
        let pose = Pose { rotation: r, translation: linalg::sub(c, linalg::mat_vec(&r, c)) };
        world.integrate(1, &pose, &params, |f| f(&Primitive::Plane(p))).unwrap();
        assert_eq!(world.planes()[0].occupied, 4, "cells seen once are not shown");
        world.integrate(2, &pose, &params, |f| f(&Primitive::Plane(p))).unwrap();
        let w = world.planes()[0];
        assert_eq!(w.pending_len, 0);
        let half = (WORLD_GRID / 2) as f32;
        let (mut inside, mut missing) = (0, 0);
        for b in 0..WORLD_GRID {
            for a in 0..WORLD_GRID {
                let (u, v) = ((a as f32 - half + 0.5) * 0.05, (b as f32 - half + 0.5) * 0.05);
                let world_point = linalg::add(w.origin, linalg::add(linalg::scale(w.e1, u), linalg::scale(w.e2, v)));
                let seen = linalg::sub(pose.to_camera(world_point), c);
                if seen[0].abs() <= 0.475 && seen[2].abs() <= 0.475 {
                    inside += 1;
                    let k = b * WORLD_GRID + a;
                    missing += (w.cells[k / 8] >> (k % 8)) as usize & 1 ^ 1;
                }
            }
        }
        assert!(inside > 300, "{inside} cells inside");
        assert_eq!(missing, 0, "{missing} of {inside} cells inside the turned square are holes");
        // And the boundary did not grow: about the square's 400 cells.
        assert!(w.occupied >= 370 && w.occupied <= 430, "{} cells", w.occupied);
    }

    #[test]
    fn a_re_observed_gaussian_merges_by_moments_and_a_neighbour_stays_apart() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        world.integrate(0, &identity(), &params, |f| f(&Primitive::Gmm(gmm([0.0, 0.0, 2.0], 100)))).unwrap();
        // The same patch seen from 0.1 m to the left (camera frame x + 0.1), 2 mm off, and a patch 30 cm away.
        let stats = world
            .integrate(1, &moved(-0.1), &params, |f| {
                f(&Primitive::Gmm(gmm([0.102, 0.0, 2.0], 300)));
                f(&Primitive::Gmm(gmm([0.4, 0.0, 2.0], 100)));
            })
            .unwrap();
        assert_eq!((stats.gmms_merged, stats.gmms_created), (1, 1));
        let g = world.gaussians();
        assert_eq!(g.len(), 2);
        assert_eq!(g[0].count, 400);
        // Moment matching: the mean weighted by support, 1.5 mm from the first; the variances those of the
        // union of both supports (the 2 mm offset adds 0.75 µm² along x).
        assert!((g[0].mean[0] - 0.0015).abs() < 1e-5, "merged mean {:?}", g[0].mean);
        let expected_x = (398.0 * 0.05f32 * 0.05 + 100.0 * 0.0015 * 0.0015 + 300.0 * 0.0005 * 0.0005) / 399.0;
        assert!((g[0].covariance[0] - expected_x).abs() < 1e-7, "{} vs {expected_x}", g[0].covariance[0]);
        assert!((g[0].covariance[3] - 0.03 * 0.03 * 398.0 / 399.0).abs() < 1e-7);
        assert!((g[1].mean[0] - 0.3).abs() < 1e-5);
    }

    #[test]
    fn a_full_pool_evicts_the_weakest_gaussian_and_the_receiver_hears_of_it() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<WorldStorage<1, 1, 2, 4>>();
        let mut world = WorldMap::new(&mut storage);
        let mut rx = Receiver::default();
        // Two patches, each seen in two frames: confirmed, shown and sent.
        for frame in 0..2 {
            world
                .integrate(frame, &identity(), &params, |f| {
                    f(&Primitive::Gmm(gmm([0.0, 0.0, 2.0], 10)));
                    f(&Primitive::Gmm(gmm([1.0, 0.0, 2.0], 50)));
                })
                .unwrap();
            rx.apply(&delta(&mut world));
            assert_eq!(rx.world(), bytes(&world));
        }
        assert_eq!(world.primitive_counts()[2], 2);
        let weakest = world.gaussians()[0].id;
        // A stronger newcomer (100 points against 20) evicts the weakest; a weaker one is dropped.
        let stats =
            world.integrate(2, &identity(), &params, |f| f(&Primitive::Gmm(gmm([-1.0, 0.0, 2.0], 100)))).unwrap();
        assert_eq!((stats.gmms_evicted, stats.gmms_created, stats.gmms_dropped), (1, 1, 0));
        assert!(world.gaussians().iter().all(|g| g.id != weakest));
        // The newcomer is not shown before a second frame confirms it: the delta only removes.
        let h = rx.apply(&delta(&mut world));
        assert_eq!((h.upserts, h.removals), (0, 1));
        assert_eq!(rx.world(), bytes(&world));
        let stats = world.integrate(3, &identity(), &params, |f| f(&Primitive::Gmm(gmm([2.0, 0.0, 2.0], 5)))).unwrap();
        assert_eq!((stats.gmms_evicted, stats.gmms_dropped), (0, 1));
        world.integrate(4, &identity(), &params, |f| f(&Primitive::Gmm(gmm([-1.0, 0.0, 2.0], 100)))).unwrap();
        let h = rx.apply(&delta(&mut world));
        assert_eq!((h.upserts, h.removals), (1, 0));
        assert_eq!(rx.world(), bytes(&world));
        assert_eq!(world.primitive_counts()[2], 2);
    }

    #[test]
    fn deltas_rebuild_the_world_byte_for_byte_and_an_unchanged_view_sends_nothing() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<WorldStorage<4, 4, 64, 64>>();
        let mut world = WorldMap::new(&mut storage);
        let mut rx = Receiver::default();
        let mut seed = 12345u32;
        let mut rand = move || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1u32 << 24) as f32
        };
        let mut floor_bits = [0u8; 800];
        let p = floor(&mut floor_bits, 30, 60);
        for frame in 0..40u32 {
            let pose = moved(0.02 * frame as f32);
            let gaussians: Vec<MapGmm> = (0..12)
                .map(|_| gmm([rand() * 2.0 - 1.0, rand() - 0.5, 1.5 + rand()], 20 + (rand() * 200.0) as u32))
                .collect();
            world
                .integrate(frame, &pose, &params, |f| {
                    f(&Primitive::Plane(p));
                    f(&Primitive::Sq(sq([0.3, 0.2, 2.0], 1)));
                    for g in &gaussians {
                        f(&Primitive::Gmm(*g));
                    }
                })
                .unwrap();
            let d = delta(&mut world);
            rx.apply(&d);
            assert_eq!(rx.world(), bytes(&world), "frame {frame}");
        }
        // The same view again changes nothing the wire can see: an empty delta.
        world.integrate(40, &moved(0.78), &params, |f| f(&Primitive::Plane(p))).unwrap();
        let h = rx.apply(&delta(&mut world));
        assert_eq!((h.upserts, h.removals), (0, 0));
        assert_eq!(rx.world(), bytes(&world));
    }

    #[test]
    fn a_bad_pose_or_an_old_frame_is_refused_and_changes_nothing() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        world.integrate(5, &identity(), &params, |f| f(&Primitive::Gmm(gmm([0.0, 0.0, 2.0], 100)))).unwrap();
        let before = bytes(&world);
        let bad = Pose { rotation: [[f32::NAN; 3]; 3], translation: [0.0; 3] };
        let add = |f: &mut dyn FnMut(&Primitive<'_>)| f(&Primitive::Gmm(gmm([3.0, 0.0, 2.0], 100)));
        assert_eq!(world.integrate(6, &bad, &params, add), Err(WorldError::BadPose));
        assert_eq!(world.integrate(5, &identity(), &params, add), Err(WorldError::FrameOutOfOrder));
        assert_eq!(bytes(&world), before);
        assert_eq!(world.frame(), Some(5));
    }

    #[test]
    fn an_object_is_shown_once_confirmed_and_keeps_its_id_when_its_track_restarts() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        let shown = |w: &WorldMap<'_>| w.primitive_counts()[1];
        for frame in 0..3 {
            assert_eq!(shown(&world), 0, "frame {frame}: not confirmed yet");
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Sq(sq([0.0, 0.0, 2.0], 1)))).unwrap();
        }
        assert_eq!(shown(&world), 1);
        let id = world.objects()[0].id;
        // The track is retired and a new one starts 5 cm away: the same world object.
        for frame in 3..6 {
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Sq(sq([0.05, 0.0, 2.0], 9)))).unwrap();
        }
        assert_eq!(world.objects().len(), 1);
        assert_eq!((world.objects()[0].id, world.objects()[0].track), (id, 9));
        // A Gaussian on the object's surface is explained by it; one 1 m away is not.
        let stats = world
            .integrate(6, &identity(), &params, |f| {
                f(&Primitive::Gmm(gmm([0.15, 0.0, 2.0], 100)));
                f(&Primitive::Gmm(gmm([1.0, 0.0, 2.0], 100)));
            })
            .unwrap();
        assert_eq!((stats.gmms_explained, stats.gmms_created), (1, 1));
        // A passing fit seen once, never confirmed, leaves after track_max_missed frames and is never shown.
        world.integrate(7, &identity(), &params, |f| f(&Primitive::Sq(sq([2.0, 0.0, 2.0], 4)))).unwrap();
        assert_eq!(world.objects().len(), 2);
        let last = 8 + params.track_max_missed;
        for frame in 8..=last {
            world.integrate(frame, &identity(), &params, |_| {}).unwrap();
        }
        assert_eq!(world.objects().len(), 1);
    }

    #[test]
    fn an_object_whose_fits_disagree_is_not_shown_until_three_in_a_row_agree() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        let shown = |w: &WorldMap<'_>| w.primitive_counts()[1];
        // One track, six sightings: its fit flips between a 20 cm and a 40 cm long shape (a slice of the
        // object, then all of it). Half-axes differ by 50 %: no two sightings in a row agree.
        let long = |z: f32| MapSq {
            sq: Superquadric { scales: [0.1, 0.1, 0.4], ..sq([0.0; 3], 1).sq },
            ..sq([0.0, 0.0, z], 1)
        };
        for frame in 0..6u32 {
            let fit = if frame % 2 == 0 { sq([0.0, 0.0, 2.0], 1) } else { long(2.0) };
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Sq(fit))).unwrap();
            assert_eq!(shown(&world), 0, "frame {frame}: fits that jump are not an object to show");
        }
        assert_eq!(world.objects().len(), 1, "one world object follows the track");
        // Three agreeing sightings (the centre moves 3 cm, within 30 % of the 40 cm half-axis; the first of them
        // agrees with nothing before it): shown.
        for (k, frame) in (6..9u32).enumerate() {
            let fit = long(2.0 + 0.03 * k as f32);
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Sq(fit))).unwrap();
        }
        assert_eq!(shown(&world), 1);
        // Once shown, it stays shown whatever its track's next fit: the map does not flicker.
        world.integrate(9, &identity(), &params, |f| f(&Primitive::Sq(sq([0.0, 0.0, 2.0], 1)))).unwrap();
        assert_eq!(shown(&world), 1);
    }

    /// A shown object keeps its shown shape through a stray fit (one that agrees with neither the sighting
    /// before it nor the one after), and shows a new shape once two sightings in a row agree on it. (Redkitchen's
    /// world showed a track's latest fit: one of its fits in frame 297, 28 × 18 × 17 cm where most were a
    /// 4–6 × 18 × 22 cm slab, stayed its shape; three such objects held 57 % of the world's squared G2R error.)
    #[test]
    fn a_shown_object_keeps_its_shape_through_a_stray_fit() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        let shown = |w: &WorldMap<'_>| w.objects().first().map(|o| o.shown.sq.scales);
        let long =
            MapSq { sq: Superquadric { scales: [0.1, 0.1, 0.4], ..sq([0.0; 3], 1).sq }, ..sq([0.0, 0.0, 2.0], 1) };
        let short = sq([0.0, 0.0, 2.0], 1);
        let mut frame = 0u32;
        let mut see = |world: &mut WorldMap<'_>, fit: MapSq| {
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Sq(fit))).unwrap();
            frame += 1;
        };
        for _ in 0..5 {
            see(&mut world, short);
        }
        assert_eq!(shown(&world), Some(short.sq.scales), "shown after agreeing sightings");
        see(&mut world, long);
        assert_eq!(shown(&world), Some(short.sq.scales), "a stray fit does not become the shape");
        see(&mut world, short);
        assert_eq!(shown(&world), Some(short.sq.scales));
        see(&mut world, long);
        see(&mut world, long);
        assert_eq!(shown(&world), Some(long.sq.scales), "two sightings in a row that agree are the new shape");
    }

    /// A partial view (the shape runs out of the image) never gives an object its shape, however often it comes,
    /// and alone makes no object; agreeing with a whole view it counts as a sighting; it keeps a shown object
    /// alive.
    #[test]
    fn a_partial_view_never_shapes_an_object() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        let whole = sq([0.0, 0.0, 2.0], 1);
        let partial = MapSq { partial: true, ..whole };
        let see = |world: &mut WorldMap<'_>, frame: u32, fit: MapSq| {
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Sq(fit))).unwrap()
        };
        for frame in 0..5u32 {
            assert_eq!(see(&mut world, frame, partial).objects_partial, 1);
        }
        assert_eq!(world.objects().len(), 0, "partial views alone make no object");
        // One whole view, then partial views that agree with it: shown, with the whole view's shape.
        let whole_wider = MapSq { sq: Superquadric { scales: [0.12, 0.1, 0.2], ..whole.sq }, ..whole };
        see(&mut world, 5, whole_wider);
        see(&mut world, 6, partial);
        assert_eq!(world.primitive_counts()[1], 0);
        see(&mut world, 7, partial);
        assert_eq!(world.primitive_counts()[1], 1, "a whole view and two agreeing partial views in a row");
        assert_eq!(world.objects().first().map(|o| o.shown.sq.scales), Some(whole_wider.sq.scales));
        // The track's next views run on to a 40 cm half-axis, cut by the image border: three in a row agree with
        // each other, and still the shown shape is the whole view's.
        let running_on = MapSq { sq: Superquadric { scales: [0.1, 0.1, 0.4], ..whole.sq }, partial: true, ..whole };
        for frame in 8..11u32 {
            see(&mut world, frame, running_on);
        }
        let object = world.objects().first().copied().unwrap();
        assert_eq!(object.shown.sq.scales, whole_wider.sq.scales);
        assert_eq!(object.last_frame, 10, "kept alive");
        assert_eq!(world.primitive_counts()[1], 1);
        // A partial view that disagrees with an object not yet shown does not count: another track's object.
        let other = MapSq { sq: Superquadric { centre: [1.0, 0.0, 2.0], ..whole.sq }, track: 2, ..whole };
        see(&mut world, 11, other);
        see(&mut world, 12, MapSq { partial: true, ..running_on_track(2) });
        see(&mut world, 13, MapSq { partial: true, ..running_on_track(2) });
        assert_eq!(world.primitive_counts()[1], 1, "partial views that disagree with the whole view do not count");
    }

    /// [`a_partial_view_never_shapes_an_object`]'s 40 cm long fit at (1, 0, 2) m, of track `track`.
    fn running_on_track(track: u16) -> MapSq {
        let s = sq([1.0, 0.0, 2.0], track);
        MapSq { sq: Superquadric { scales: [0.1, 0.1, 0.4], ..s.sq }, ..s }
    }

    #[test]
    fn a_static_object_shows_the_mean_of_its_scattered_fits_and_is_resent_rarely() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        // One static object at z = 2 m whose fits scatter by ±2.5 cm along x (more than the 2 cm publish step
        // from one fit to the next): 20 sightings.
        let mut resent = 0;
        for frame in 0..20u32 {
            let x = if frame % 2 == 0 { 0.025 } else { -0.025 };
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Sq(sq([x, 0.0, 2.0], 1)))).unwrap();
            let d = delta(&mut world);
            let mut sq_records = 0;
            wire::decode_delta(&d, |c| {
                if matches!(c, wire::DeltaChange::Upsert(r) if r.kind == KIND_SQ) {
                    sq_records += 1;
                }
            })
            .unwrap();
            resent += sq_records;
        }
        let shown = world.objects()[0].shown.sq.centre;
        assert!(shown[0].abs() <= 0.005, "shown centre {shown:?}: the mean of the fits is x = 0");
        // Shown once confirmed, then re-sent only while the mean settles (the latest fit would be re-sent in
        // every frame: each is 5 cm from the one before).
        assert!(resent <= 3, "{resent} superquadric records");
    }

    #[test]
    fn corrupted_world_maps_and_deltas_are_errors() {
        let params = Params::default();
        let mut storage = bytemuck::zeroed_box::<Small>();
        let mut world = WorldMap::new(&mut storage);
        for frame in 0..2 {
            world.integrate(frame, &identity(), &params, |f| f(&Primitive::Gmm(gmm([0.0, 0.0, 2.0], 100)))).unwrap();
        }
        let map = bytes(&world);
        let d = delta(&mut world);
        let mut n = 0;
        assert_eq!(wire::decode_world(&map, |_| n += 1).map(|h| h.records), Ok(1));
        assert_eq!(n, 1);
        for (bytes, is_delta) in [(map, false), (d, true)] {
            for cut in 0..bytes.len() {
                let part = &bytes[..cut];
                assert!(wire::decode_world(part, |_| {}).is_err() && wire::decode_delta(part, |_| {}).is_err());
            }
            let mut flipped = bytes.clone();
            flipped[5] ^= 0x10;
            assert_eq!(wire::decode_world(&flipped, |_| {}).err(), Some(WireError::BadChecksum));
            // A world map is not a delta, and the other way round.
            let wrong = if is_delta {
                wire::decode_world(&bytes, |_| {})
            } else {
                wire::decode_delta(&bytes, |_| {}).map(|_| wire::WorldHeader {
                    magic: *b"MW",
                    version: 1,
                    frame: 0,
                    records: 0,
                })
            };
            assert_eq!(wrong.err(), Some(WireError::BadMagic));
        }
    }
}
