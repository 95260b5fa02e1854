//! Fixed-capacity pools over caller-owned slices, with peak and overflow accounting.
//!
//! Why not `heapless::Vec` for these: the big pools (voxels, Gaussians, tracks …, see [`PoolId`]) live in the
//! caller's storage ([`crate::Storage`]), one `Zeroable` block whose capacities come from the profile, so the
//! firmware places them in a linker section and the host in one zeroed box; a `heapless::Vec<T, N>` would carry
//! its capacity in the type and its length beside the items, and could not borrow a slice of that block.
//! [`Bounded`] also counts what `heapless` does not: the peak (for `memory_budget.md`) and every refused push
//! (reported per frame, never silent). The small lists the core keeps on its own stack for one stage (the mask
//! cuts of a frame, the segmenter's support planes) are `heapless::Vec`.

/// Every pool of the mapper. The order is the order of reports and of `memory_budget.md`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoolId {
    /// Occupied 3 cm voxels with their point sums.
    Voxels,
    /// Open-addressing slots of the voxel hash (voxel index + 1, 0 = empty).
    VoxelSlots,
    /// Per-voxel scratch: growth stamps during supervoxel growth, the voxel order of the split stage, then the
    /// Gaussian order of fusion.
    VoxelScratch,
    /// Seed cells (R_seed cubes) during seeding.
    SeedCells,
    /// Supervoxels.
    Supervoxels,
    /// Pending ranges of the IH-GMM split stack.
    SplitStack,
    /// Refined Gaussians, the set C_g.
    Gaussians,
    /// (Gaussian, instance) mask-hit counters of the annotation.
    MaskHits,
    /// Bounded planes with their occupancy grids.
    Planes,
    /// Semantic object support sets.
    Objects,
    /// Superquadric tracks.
    Tracks,
    /// Points sampled for superquadric fits.
    SqPoints,
    /// Voxelisation's list of the frame's sampled points and their voxels, which spares later passes the
    /// re-sampling (a full list costs time, not data: the passes then sample again; not in `overflow_events`).
    SampledPoints,
    /// Each voxel's centroid and occupied neighbours ([`crate::supervoxel::VoxelLinks`]), which spare supervoxel
    /// growth the hash lookups (too small a pool costs time, not data: not in `overflow_events`).
    VoxelLinks,
}

impl PoolId {
    /// Number of pools.
    pub const COUNT: usize = 14;
    /// All pools in report order.
    pub const ALL: [PoolId; PoolId::COUNT] = [
        PoolId::Voxels,
        PoolId::VoxelSlots,
        PoolId::VoxelScratch,
        PoolId::SeedCells,
        PoolId::Supervoxels,
        PoolId::SplitStack,
        PoolId::Gaussians,
        PoolId::MaskHits,
        PoolId::Planes,
        PoolId::Objects,
        PoolId::Tracks,
        PoolId::SqPoints,
        PoolId::SampledPoints,
        PoolId::VoxelLinks,
    ];

    /// Snake-case name used in `summary.json` and `memory_budget.md`.
    pub fn name(self) -> &'static str {
        match self {
            PoolId::Voxels => "voxels",
            PoolId::VoxelSlots => "voxel_slots",
            PoolId::VoxelScratch => "voxel_scratch",
            PoolId::SeedCells => "seed_cells",
            PoolId::Supervoxels => "supervoxels",
            PoolId::SplitStack => "split_stack",
            PoolId::Gaussians => "gaussians",
            PoolId::MaskHits => "mask_hits",
            PoolId::Planes => "planes",
            PoolId::Objects => "objects",
            PoolId::Tracks => "tracks",
            PoolId::SqPoints => "sq_points",
            PoolId::SampledPoints => "sampled_points",
            PoolId::VoxelLinks => "voxel_links",
        }
    }
}

/// Use of one pool during one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PoolUsage {
    /// Most entries in use at once during the frame.
    pub peak: usize,
    /// Entries the pool holds.
    pub capacity: usize,
    /// Insertions refused because the pool was full (each is work dropped and counted).
    pub overflow_events: u32,
}

/// A vector of at most `items.len()` elements over caller-owned storage.
#[derive(Debug)]
pub struct Bounded<'a, T> {
    items: &'a mut [T],
    len: usize,
    peak: usize,
    overflows: u32,
}

impl<'a, T: Copy> Bounded<'a, T> {
    /// An empty pool over `items`.
    pub fn new(items: &'a mut [T]) -> Self {
        Bounded { items, len: 0, peak: 0, overflows: 0 }
    }

    /// Appends `value` and returns its index, or counts an overflow and returns `None` when full.
    pub fn push(&mut self, value: T) -> Option<usize> {
        match self.items.get_mut(self.len) {
            Some(slot) => {
                *slot = value;
                self.len += 1;
                self.peak = self.peak.max(self.len);
                Some(self.len - 1)
            }
            None => {
                self.overflows = self.overflows.saturating_add(1);
                None
            }
        }
    }

    /// Removes the last element.
    pub fn pop(&mut self) -> Option<T> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        self.items.get(self.len).copied()
    }

    /// Entries the pool holds.
    pub fn capacity(&self) -> usize {
        self.items.len()
    }

    /// Empties the pool and starts a new frame's accounting.
    pub fn clear(&mut self) {
        self.len = 0;
        self.peak = 0;
        self.overflows = 0;
    }

    /// Counts `n` overflow events that happened outside [`Bounded::push`]: the refused pushes of a pass that was
    /// cleared and redone (the voxels of a frame mapped again over a nearer range).
    pub fn add_overflows(&mut self, n: u32) {
        self.overflows = self.overflows.saturating_add(n);
    }

    /// Starts a new frame's accounting and keeps the elements (for a pool that lives across frames, such as the
    /// tracks): the peak restarts at the current length and the overflow count at 0, so a refused push is
    /// reported in the frame it happened and not again in every later one.
    pub fn restart_accounting(&mut self) {
        self.peak = self.len;
        self.overflows = 0;
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the pool is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The elements in use.
    pub fn as_slice(&self) -> &[T] {
        self.items.get(..self.len).unwrap_or(&[])
    }

    /// The elements in use, mutable.
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        let len = self.len;
        self.items.get_mut(..len).unwrap_or(&mut [])
    }

    /// Element `i`, if in use.
    #[inline]
    pub fn get(&self, i: usize) -> Option<&T> {
        if i < self.len {
            self.items.get(i)
        } else {
            None
        }
    }

    /// Element `i`, mutable, if in use.
    #[inline]
    pub fn get_mut(&mut self, i: usize) -> Option<&mut T> {
        if i < self.len {
            self.items.get_mut(i)
        } else {
            None
        }
    }

    /// Use since the last [`Bounded::clear`].
    pub fn usage(&self) -> PoolUsage {
        PoolUsage { peak: self.peak, capacity: self.items.len(), overflow_events: self.overflows }
    }
}

/// The index of the element of `items` unseen for the most frames at `frame` (`last_frame` gives the frame each
/// was last seen in), the lowest index on ties; an element seen in `frame` itself is never picked, so `None` when
/// every element was. The drop policy of a full pool that lives across frames (tracks, world objects).
pub fn stalest<T>(items: &[T], frame: u32, last_frame: impl Fn(&T) -> u32) -> Option<usize> {
    items
        .iter()
        .enumerate()
        .filter(|(_, t)| last_frame(t) != frame)
        .max_by_key(|&(i, t)| (frame.wrapping_sub(last_frame(t)), core::cmp::Reverse(i)))
        .map(|(i, _)| i)
}

/// Bucket of a 32-bit key among `slots`: a cheap multiplicative hash that keeps neighbouring voxel keys in
/// nearby slots (measured: a full-avalanche mix here is 10 % slower overall from lost cache locality), masked
/// by [`table_mask`].
#[inline]
pub fn bucket(key: u32, slots: usize) -> usize {
    (key.wrapping_mul(0x9E37_79B1) ^ (key >> 15)) as usize & table_mask(slots)
}

/// The mask a table of `slots` slots wraps its probes by: `slots − 1`. The tables are meant to have a power of
/// two of slots (every profile's; the mapper uses the largest power-of-two part of its hash, see
/// [`power_of_two_part`]), so that a lookup never tests the length: tested per lookup, the Cortex-M7's cabinet
/// frames took 0.9 M instructions more. A table of another length works, with fewer slots: its probes stay on
/// the positions the mask reaches, the same ones for a lookup as for the insertion.
#[inline(always)]
pub fn table_mask(slots: usize) -> usize {
    slots.wrapping_sub(1)
}

/// The largest power-of-two part of `slots` (from the start; empty when `slots` is).
pub fn power_of_two_part(slots: &mut [u16]) -> &mut [u16] {
    let n = match slots.len() {
        0 => 0,
        n => 1usize << (usize::BITS - 1 - n.leading_zeros()),
    };
    let (part, _) = slots.split_at_mut(n.min(slots.len()));
    part
}

/// The entry index of `key` in `slots` as [`probe`] finds it (`Found`), `None` otherwise. A lookup only: it
/// stops at the first empty slot and visits the same slots in the same order as [`probe`]. A loop of its own:
/// `probe` with `find` matching its result gave the Cortex-M7's cabinet frames 100.0 / 83.7 / 81.2 M
/// instructions against 95.4 / 78.8 / 76.3 M.
#[inline]
pub fn find(slots: &[u16], key: u32, mut key_of: impl FnMut(usize) -> Option<u32>) -> Option<usize> {
    find_where(slots, key, |i| key_of(i) == Some(key))
}

/// The first entry, in probe order from the bucket of `hashed`, for which `matches(i)` holds, up to the first
/// empty slot: [`find`] of a table whose keys are stored at the bucket of a hash of their own ([`probe_hashed`]),
/// or the first of the keys that share that hash.
#[inline]
pub fn find_where(slots: &[u16], hashed: u32, mut matches: impl FnMut(usize) -> bool) -> Option<usize> {
    let mask = table_mask(slots.len());
    let mut pos = bucket(hashed, slots.len());
    for _ in 0..slots.len() {
        let s = *slots.get(pos)?;
        if s == 0 {
            return None;
        }
        let i = s as usize - 1;
        if matches(i) {
            return Some(i);
        }
        pos = (pos + 1) & mask;
    }
    None
}

/// Result of probing an open-addressing table for a key.
pub enum Probe {
    /// The key is stored at this entry index.
    Found(usize),
    /// The key is absent; this slot position is free for it.
    Vacant(usize),
    /// The key is absent and the table has no free slot.
    Full,
}

/// Linear probing over `slots` (entry index + 1, 0 = empty; wrapping by [`table_mask`]) for `key`, where
/// `key_of(i)` is entry i's key.
pub fn probe(slots: &[u16], key: u32, key_of: impl FnMut(usize) -> Option<u32>) -> Probe {
    probe_hashed(slots, key, key, key_of)
}

/// [`probe`] from the bucket of `hashed` instead of `key`'s: a table whose keys are placed by a hash of part
/// of them (the voxels', by their cube without the mask slot). Look such keys up with [`find_where`] from the
/// same `hashed`.
pub fn probe_hashed(slots: &[u16], hashed: u32, key: u32, mut key_of: impl FnMut(usize) -> Option<u32>) -> Probe {
    probe_where(slots, hashed, |i| key_of(i) == Some(key))
}

/// Linear probing from the bucket of `hashed` for the first entry i with `matches(i)`.
fn probe_where(slots: &[u16], hashed: u32, mut matches: impl FnMut(usize) -> bool) -> Probe {
    let mask = table_mask(slots.len());
    let mut pos = bucket(hashed, slots.len());
    for _ in 0..slots.len() {
        match slots.get(pos).copied() {
            Some(0) => return Probe::Vacant(pos),
            Some(s) => {
                if matches(s as usize - 1) {
                    return Probe::Found(s as usize - 1);
                }
            }
            None => return Probe::Full,
        }
        pos = (pos + 1) & mask;
    }
    Probe::Full
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table of `n` slots filled by linear probing with `keys` (entry i holds keys[i]).
    fn table(n: usize, keys: &[u32]) -> [u16; 64] {
        let mut slots = [0u16; 64];
        for (i, &k) in keys.iter().enumerate() {
            let Probe::Vacant(pos) = probe(&slots[..n], k, |j| keys.get(j).copied()) else { panic!("full") };
            slots[pos] = i as u16 + 1;
        }
        slots
    }

    /// A table's power-of-two part and mask: the largest power of two of slots from the start, whose mask
    /// keeps every bucket inside it.
    #[test]
    fn power_of_two_part_and_mask() {
        for (n, part) in [(0, 0), (1, 1), (2, 2), (5, 4), (16, 16), (48, 32), (64, 64)] {
            let mut slots = [0u16; 64];
            let p = power_of_two_part(&mut slots[..n]);
            assert_eq!(p.len(), part, "{n} slots");
            for key in (0..500u32).map(|i| i.wrapping_mul(0x0101_0031)) {
                if part > 0 {
                    assert!(bucket(key, part) < part, "{n} slots, key {key}");
                }
            }
        }
        assert_eq!(table_mask(16384), 16383);
        assert_eq!(find(&[], 7, |_| Some(7)), None);
        assert!(matches!(probe(&[], 7, |_| Some(7)), Probe::Full));
    }

    /// `find` answers as `probe` does, for stored and absent keys, in power-of-two tables (clusters that wrap
    /// past the last slot included) and in a table of another size (on the positions its mask reaches), up to
    /// a full one.
    #[test]
    fn find_agrees_with_probe() {
        for (n, count) in [(64, 40), (16, 15), (16, 16), (48, 12)] {
            // Keys that crowd a few buckets, so that runs are long and some wrap around.
            let mut all = [0u32; 64];
            for (i, k) in all.iter_mut().enumerate() {
                *k = (i as u32 % 5) * 0x0010_0000 + i as u32 * 3;
            }
            let keys = &all[..count];
            let slots = table(n, keys);
            let key_of = |j: usize| keys.get(j).copied();
            for k in keys.iter().copied().chain((0..200u32).map(|i| i * 7919 + 1)) {
                let expected = match probe(&slots[..n], k, key_of) {
                    Probe::Found(i) => Some(i),
                    _ => None,
                };
                assert_eq!(find(&slots[..n], k, key_of), expected, "table {n}, key {k}");
            }
            for (i, &k) in keys.iter().enumerate() {
                assert_eq!(find(&slots[..n], k, key_of), Some(i), "table {n}: stored key {k}");
            }
        }
    }
}
