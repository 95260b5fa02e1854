//! Capacity profiles: the caller-owned storage of every pool, sized at compile time.
//!
//! A profile is a [`Storage`] type with its capacities as const parameters. All-zero bytes are a valid empty
//! storage, so firmware places it in `.bss` and a host allocates it zeroed on the heap
//! (`bytemuck::zeroed_box`) without building it on the stack.

use bytemuck::Zeroable;

use crate::annotate::MaskHit;
use crate::gmm::{Gaussian, SplitTask};
use crate::linalg::Vec3;
use crate::mapper::Mapper;
use crate::objects::Object;
use crate::plane::Plane;
use crate::pool::PoolId;
use crate::supervoxel::{SampledPoint, SeedCell, Supervoxel, Voxel, VoxelLinks};
use crate::track::Track;

/// Depth of the split work stack. The stack never holds more than `gmm_max_depth + 1 ≤ 31` ranges.
pub const SPLIT_STACK: usize = 64;

/// Storage of every pool of the mapper.
///
/// - `V`: voxels (≤ 65 533, voxel indices are `u16`), also the length of the per-voxel scratch (at least 2 × `G`:
///   [`crate::objects::detach_stray_parts`] keeps two entries per Gaussian there);
/// - `H`: voxel hash slots (about 2 × `V` keeps linear probing short);
/// - `C`: seed cells; `S`: supervoxels; `G`: Gaussians;
/// - `M`: mask-hit counters (a hash table: about 2 × the annotated Gaussians); `L`: planes; `O`: objects;
/// - `T`: superquadric tracks; `Q`: superquadric fit points (objects are sampled `Q / lm_samples` per pass);
/// - `P`: largest frame, pixels;
/// - `K`: the frame's sampled points listed by voxelisation (0: none; later passes sample the frame again);
/// - `N`: voxel links (centroid and neighbours per voxel; 0: none, supervoxel growth looks them up again).
#[derive(Zeroable)]
#[repr(C)]
pub struct Storage<
    const V: usize,
    const H: usize,
    const C: usize,
    const S: usize,
    const G: usize,
    const M: usize,
    const L: usize,
    const O: usize,
    const T: usize,
    const Q: usize,
    const P: usize,
    const K: usize,
    const N: usize,
> {
    pub(crate) voxels: [Voxel; V],
    pub(crate) slots: [u16; H],
    pub(crate) scratch: [u16; V],
    pub(crate) seeds: [SeedCell; C],
    pub(crate) supervoxels: [Supervoxel; S],
    pub(crate) stack: [SplitTask; SPLIT_STACK],
    pub(crate) gaussians: [Gaussian; G],
    pub(crate) mask_hits: [MaskHit; M],
    pub(crate) planes: [Plane; L],
    pub(crate) objects: [Object; O],
    pub(crate) tracks: [Track; T],
    pub(crate) sq_points: [Vec3; Q],
    pub(crate) sampled: [SampledPoint; K],
    pub(crate) links: [VoxelLinks; N],
}

/// Mutable views of every pool of one storage.
pub struct Parts<'a> {
    /// Voxel pool.
    pub voxels: &'a mut [Voxel],
    /// Voxel hash slots.
    pub slots: &'a mut [u16],
    /// Per-voxel scratch.
    pub scratch: &'a mut [u16],
    /// Seed cells.
    pub seeds: &'a mut [SeedCell],
    /// Supervoxels.
    pub supervoxels: &'a mut [Supervoxel],
    /// Split stack.
    pub stack: &'a mut [SplitTask],
    /// Gaussians.
    pub gaussians: &'a mut [Gaussian],
    /// Mask-hit table.
    pub mask_hits: &'a mut [MaskHit],
    /// Planes.
    pub planes: &'a mut [Plane],
    /// Objects.
    pub objects: &'a mut [Object],
    /// Superquadric tracks.
    pub tracks: &'a mut [Track],
    /// Superquadric fit points.
    pub sq_points: &'a mut [Vec3],
    /// The frame's sampled points and their voxels.
    pub sampled: &'a mut [SampledPoint],
    /// Voxel links.
    pub links: &'a mut [VoxelLinks],
}

/// A capacity profile: storage the mapper can run in.
pub trait Profile {
    /// Largest frame, pixels.
    const MAX_PIXELS: usize;
    /// The pools as slices.
    fn parts(&mut self) -> Parts<'_>;
}

impl<
        const V: usize,
        const H: usize,
        const C: usize,
        const S: usize,
        const G: usize,
        const M: usize,
        const L: usize,
        const O: usize,
        const T: usize,
        const Q: usize,
        const P: usize,
        const K: usize,
        const N: usize,
    > Profile for Storage<V, H, C, S, G, M, L, O, T, Q, P, K, N>
{
    const MAX_PIXELS: usize = P;
    fn parts(&mut self) -> Parts<'_> {
        #[allow(clippy::let_unit_value)]
        let () = Self::INDICES_FIT;
        Parts {
            voxels: &mut self.voxels,
            slots: &mut self.slots,
            scratch: &mut self.scratch,
            seeds: &mut self.seeds,
            supervoxels: &mut self.supervoxels,
            stack: &mut self.stack,
            gaussians: &mut self.gaussians,
            mask_hits: &mut self.mask_hits,
            planes: &mut self.planes,
            objects: &mut self.objects,
            tracks: &mut self.tracks,
            sq_points: &mut self.sq_points,
            sampled: &mut self.sampled,
            links: &mut self.links,
        }
    }
}

impl<
        const V: usize,
        const H: usize,
        const C: usize,
        const S: usize,
        const G: usize,
        const M: usize,
        const L: usize,
        const O: usize,
        const T: usize,
        const Q: usize,
        const P: usize,
        const K: usize,
        const N: usize,
    > Storage<V, H, C, S, G, M, L, O, T, Q, P, K, N>
{
    /// Every pool as (pool, capacity, bytes per element), in report order — the rows of `memory_budget.md`.
    pub const POOLS: [(PoolId, usize, usize); PoolId::COUNT] = [
        (PoolId::Voxels, V, core::mem::size_of::<Voxel>()),
        (PoolId::VoxelSlots, H, core::mem::size_of::<u16>()),
        (PoolId::VoxelScratch, V, core::mem::size_of::<u16>()),
        (PoolId::SeedCells, C, core::mem::size_of::<SeedCell>()),
        (PoolId::Supervoxels, S, core::mem::size_of::<Supervoxel>()),
        (PoolId::SplitStack, SPLIT_STACK, core::mem::size_of::<SplitTask>()),
        (PoolId::Gaussians, G, core::mem::size_of::<Gaussian>()),
        (PoolId::MaskHits, M, core::mem::size_of::<MaskHit>()),
        (PoolId::Planes, L, core::mem::size_of::<Plane>()),
        (PoolId::Objects, O, core::mem::size_of::<Object>()),
        (PoolId::Tracks, T, core::mem::size_of::<Track>()),
        (PoolId::SqPoints, Q, core::mem::size_of::<Vec3>()),
        (PoolId::SampledPoints, K, core::mem::size_of::<SampledPoint>()),
        (PoolId::VoxelLinks, N, core::mem::size_of::<VoxelLinks>()),
    ];

    /// Compile-time check that voxel, supervoxel and Gaussian indices fit `u16` beside the reserved labels.
    const INDICES_FIT: () = assert!(
        V < crate::supervoxel::DROPPED as usize
            && S < crate::supervoxel::DROPPED as usize
            && G < crate::supervoxel::DROPPED as usize
            && L < 255
            && O < 255
            && Q >= crate::superquadric::MAX_SAMPLES
            && H >= V
            && V >= 2 * G
    );

    /// Bytes of the storage itself.
    pub const BYTES: usize = core::mem::size_of::<Self>();
}

/// The `mcu` profile: a 640×480 frame in at most 512 KiB of static RAM, mapper state included (no room for the
/// list of sampled points or the voxel links: its passes sample the frame again, its growth looks neighbours up).
pub type McuStorage = Storage<MCU_VOXELS, 16384, 128, 128, 576, 1024, 8, 32, 32, 256, { 640 * 480 }, 0, 0>;

/// The `host` profile: larger pools for workstation replays (frames up to 1280×1024; the list of sampled points
/// holds a 15 % sample of the largest frame; links for every voxel).
pub type HostStorage = Storage<
    32768,
    65536,
    1024,
    2048,
    4096,
    8192,
    64,
    254,
    64,
    4096,
    { 1280 * 1024 },
    { 1280 * 1024 * 3 / 20 + 1024 },
    32768,
>;

/// The `tiny` profile: every pool a few entries, to exercise overflow handling on real frames (robustness
/// tests); it maps a 640×480 frame badly but never fails.
pub type TinyStorage = Storage<512, 1024, 8, 8, 32, 64, 2, 4, 2, 128, { 640 * 480 }, 1024, 0>;

/// Voxels of the mcu profile's pool (supervoxel growth keeps a bit per voxel for as many on the stack).
pub const MCU_VOXELS: usize = 8704;

/// RAM budget of the `mcu` profile, bytes.
pub const MCU_BUDGET_BYTES: usize = 512 * 1024;

/// Everything the `mcu` profile keeps in RAM: its storage plus the mapper that borrows it.
pub const MCU_TOTAL_BYTES: usize = McuStorage::BYTES + core::mem::size_of::<Mapper<'static>>();

// The build fails when the mcu profile outgrows its budget.
const _: () = assert!(MCU_TOTAL_BYTES <= MCU_BUDGET_BYTES, "mcu profile exceeds 512 KiB");
