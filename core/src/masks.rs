//! Borrowed instance-mask sets: the output of any mask-level front end (a detector, a file, the geometric
//! segmenter), as the paper's 𝒴 = {(M_j, B_j, ℓ_j, s_j)}.

use crate::error::MaskError;

/// One detected instance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Instance {
    /// Instance id a ≥ 1, unique within the frame (0 means "no instance").
    pub id: u16,
    /// Category label ℓ as an index into the caller's label table.
    pub class: u16,
    /// Detection confidence s in [0, 1].
    pub score: f32,
    /// Bounding box `[x0, y0, x1, y1]`, inclusive pixel coordinates.
    pub bbox: [u16; 4],
}

/// The last id → voxel slot lookup of [`MaskSet::voxel_slot_cached`] (id 0: nothing cached), and whether any
/// looked-up pixel of a usable instance lay outside that instance's bounding box.
#[derive(Debug, Clone, Copy, Default)]
pub struct SlotCache {
    id: u16,
    slot: u32,
    bbox: [u16; 4],
    outside_box: bool,
}

impl SlotCache {
    /// Whether a pixel looked up through this cache belonged to a usable instance (id-image masks) but lay
    /// outside the instance's `bbox`: its mask then reaches beyond its box, which the voxel count of
    /// [`crate::annotate::count_hits`] must know.
    pub fn saw_pixel_outside_box(&self) -> bool {
        self.outside_box
    }
}

/// How the per-pixel masks are stored.
#[derive(Debug, Clone, Copy)]
pub enum MaskPixels<'a> {
    /// One instance-id image, `width × height` (0 = none). Instances cannot overlap in this layout.
    IdImage(&'a [u16]),
    /// One bit plane per instance, in the order of `instances`, each `ceil(width × height / 8)` bytes, bit
    /// `i % 8` of byte `i / 8` for pixel index `i`. Instances may overlap.
    BitPlanes(&'a [u8]),
}

/// Mask slots of a voxel key ([`MaskSet::voxel_slot`]): slot 1 + k mod 7 for the usable instance k, 0 for none.
pub const MASK_SLOTS: usize = 7;

/// The instance masks of one frame, borrowed from the caller.
#[derive(Debug, Clone, Copy)]
pub struct MaskSet<'a> {
    /// Mask width, pixels (must equal the frame's).
    pub width: u16,
    /// Mask height, pixels (must equal the frame's).
    pub height: u16,
    /// The instances.
    pub instances: &'a [Instance],
    /// Their pixels.
    pub pixels: MaskPixels<'a>,
}

impl<'a> MaskSet<'a> {
    /// Bytes of one bit plane for a `width × height` image.
    pub fn plane_bytes(width: u16, height: u16) -> usize {
        (width as usize * height as usize).div_ceil(8)
    }

    /// Checks sizes against the frame, scores, boxes and id uniqueness.
    pub fn validate(&self, frame_width: u16, frame_height: u16) -> Result<(), MaskError> {
        if (self.width, self.height) != (frame_width, frame_height) {
            return Err(MaskError::SizeMismatch {
                mask: (self.width, self.height),
                frame: (frame_width, frame_height),
            });
        }
        let pixels = self.width as usize * self.height as usize;
        let (expected, found) = match self.pixels {
            MaskPixels::IdImage(ids) => (pixels, ids.len()),
            MaskPixels::BitPlanes(bits) => {
                (Self::plane_bytes(self.width, self.height) * self.instances.len(), bits.len())
            }
        };
        if expected != found {
            return Err(MaskError::PixelLength { expected, found });
        }
        for (k, inst) in self.instances.iter().enumerate() {
            if inst.id == 0 {
                return Err(MaskError::ReservedId);
            }
            if !(inst.score.is_finite() && (0.0..=1.0).contains(&inst.score)) {
                return Err(MaskError::BadScore { id: inst.id });
            }
            let [x0, y0, x1, y1] = inst.bbox;
            if x0 > x1 || y0 > y1 || x1 >= self.width || y1 >= self.height {
                return Err(MaskError::BadBox { id: inst.id });
            }
            if self.instances.iter().take(k).any(|o| o.id == inst.id) {
                return Err(MaskError::DuplicateId { id: inst.id });
            }
        }
        Ok(())
    }

    /// The voxel slot of pixel (u, v) (see [`crate::supervoxel::voxel_key`]): 0 outside every instance of
    /// score ≥ `min_confidence`, else 1 + (position of the first such instance holding the pixel) mod 7. Points
    /// of different instances (and of no instance) then never share a voxel — up to 7 instances; beyond, two
    /// instances whose positions differ by a multiple of 7 share a slot.
    pub fn voxel_slot(&self, u: u16, v: u16, min_confidence: f32) -> u32 {
        self.voxel_slot_cached(u, v, min_confidence, &mut SlotCache::default())
    }

    /// [`MaskSet::voxel_slot`] that keeps the last id-image lookup in `cache` (neighbouring pixels mostly share
    /// an id). One cache serves one `min_confidence`.
    #[inline(always)]
    pub fn voxel_slot_cached(&self, u: u16, v: u16, min_confidence: f32, cache: &mut SlotCache) -> u32 {
        if u >= self.width || v >= self.height {
            return 0;
        }
        let i = v as usize * self.width as usize + u as usize;
        let usable = |inst: &Instance| inst.score >= min_confidence;
        let slot_of = |k: Option<usize>| k.map_or(0, |k| 1 + (k % MASK_SLOTS) as u32);
        match self.pixels {
            MaskPixels::IdImage(ids) => match ids.get(i) {
                Some(&id) if id != 0 => {
                    if cache.id != id {
                        let k = self.instances.iter().position(|inst| inst.id == id && usable(inst));
                        let bbox = k.and_then(|k| self.instances.get(k)).map_or([0; 4], |inst| inst.bbox);
                        *cache = SlotCache { id, slot: slot_of(k), bbox, outside_box: cache.outside_box };
                    }
                    if cache.slot != 0 {
                        let [x0, y0, x1, y1] = cache.bbox;
                        cache.outside_box |= u < x0 || u > x1 || v < y0 || v > y1;
                    }
                    cache.slot
                }
                _ => 0,
            },
            MaskPixels::BitPlanes(_) => slot_of(
                (0..self.instances.len())
                    .find(|&k| self.instances.get(k).is_some_and(usable) && self.contains(k, u, v)),
            ),
        }
    }

    /// Whether pixel (u, v) belongs to an instance of score ≥ `min_confidence` other than the one with id `own`:
    /// what the camera saw there is another object. Out-of-range → false.
    pub fn held_by_other(&self, u: u16, v: u16, own: u16, min_confidence: f32) -> bool {
        if u >= self.width || v >= self.height {
            return false;
        }
        let usable = |inst: &Instance| inst.id != own && inst.score >= min_confidence;
        match self.pixels {
            MaskPixels::IdImage(ids) => {
                let i = v as usize * self.width as usize + u as usize;
                ids.get(i).is_some_and(|&id| id != 0 && self.instances.iter().any(|inst| inst.id == id && usable(inst)))
            }
            MaskPixels::BitPlanes(_) => {
                self.instances.iter().enumerate().any(|(k, inst)| usable(inst) && self.contains(k, u, v))
            }
        }
    }

    /// Whether pixel (u, v) belongs to the instance at position `k` of `instances`. Out-of-range → false.
    pub fn contains(&self, k: usize, u: u16, v: u16) -> bool {
        if u >= self.width || v >= self.height {
            return false;
        }
        let Some(inst) = self.instances.get(k) else { return false };
        let i = v as usize * self.width as usize + u as usize;
        match self.pixels {
            MaskPixels::IdImage(ids) => ids.get(i).is_some_and(|&id| id == inst.id),
            MaskPixels::BitPlanes(bits) => {
                let plane = Self::plane_bytes(self.width, self.height);
                bits.get(k * plane + i / 8).is_some_and(|b| (b >> (i % 8)) & 1 == 1)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The three one-byte bit planes of an 8-pixel id image with ids 1–3 (0: no instance).
    fn bit_planes(ids: &[u16; 8]) -> [u8; 3] {
        let mut planes = [0u8; 3];
        for (i, &id) in ids.iter().enumerate() {
            if id != 0 {
                planes[usize::from(id) - 1] |= 1 << i;
            }
        }
        planes
    }

    /// Both layouts give every pixel the same voxel slot, through one cache or a fresh one per pixel: the first
    /// usable instance's, 0 below the confidence or outside every instance.
    #[test]
    fn voxel_slots_agree_in_both_layouts() {
        // 4 × 2 pixels: row 0 = [1, 1, 2, 3], row 1 = [0, 2, 2, 3]; instance 2 scores below the threshold.
        let ids = [1u16, 1, 2, 3, 0, 2, 2, 3];
        let instances = [
            Instance { id: 1, class: 0, score: 0.9, bbox: [0, 0, 1, 0] },
            Instance { id: 2, class: 0, score: 0.2, bbox: [1, 0, 2, 1] },
            Instance { id: 3, class: 0, score: 0.8, bbox: [3, 0, 3, 1] },
        ];
        let planes = bit_planes(&ids);
        let expected = [1u32, 1, 0, 3, 0, 0, 0, 3];
        for pixels in [MaskPixels::IdImage(&ids), MaskPixels::BitPlanes(&planes)] {
            let m = MaskSet { width: 4, height: 2, instances: &instances, pixels };
            let mut cache = SlotCache::default();
            for (i, &slot) in expected.iter().enumerate() {
                let (u, v) = ((i % 4) as u16, (i / 4) as u16);
                assert_eq!(m.voxel_slot_cached(u, v, 0.5, &mut cache), slot, "pixel {i} through one cache");
                assert_eq!(m.voxel_slot(u, v, 0.5), slot, "pixel {i}");
            }
            assert_eq!(m.voxel_slot(4, 0, 0.5), 0, "outside the image");
        }
    }

    /// Bit planes of 40 overlapping instances (some below the confidence), looked up through one cache: the
    /// slot of the first usable instance holding each pixel, also from the 33rd instance on.
    #[test]
    fn bit_plane_slots_are_the_first_usable_instance_among_many() {
        const N: usize = 40;
        let (w, h) = (16u16, 4u16);
        let plane = MaskSet::plane_bytes(w, h);
        let mut planes = [0u8; N * 8];
        let mut instances = [Instance { id: 0, class: 0, score: 0.0, bbox: [0, 0, w - 1, h - 1] }; N];
        for (k, inst) in instances.iter_mut().enumerate() {
            inst.id = k as u16 + 1;
            inst.score = if k % 3 == 1 { 0.2 } else { 0.9 };
            for i in 0..(w * h) as usize {
                // Instance k holds pixel i when the pixel's pattern picks it (several per pixel, some none).
                // The first 32 hold none of the last four columns.
                let right = i % w as usize >= 12;
                if (!right && (i * 7 + k * 5) % 11 < 2) || (k >= 32 && i % 5 == k % 5) {
                    planes[k * plane + i / 8] |= 1 << (i % 8);
                }
            }
        }
        let m = MaskSet { width: w, height: h, instances: &instances, pixels: MaskPixels::BitPlanes(&planes) };
        let mut cache = SlotCache::default();
        let mut beyond = 0;
        for i in 0..(w * h) as usize {
            let (u, v) = ((i % w as usize) as u16, (i / w as usize) as u16);
            let first = (0..N).find(|&k| instances[k].score >= 0.5 && m.contains(k, u, v));
            let expected = first.map_or(0, |k| 1 + (k % MASK_SLOTS) as u32);
            beyond += usize::from(first.is_some_and(|k| k >= 32));
            assert_eq!(m.voxel_slot_cached(u, v, 0.5, &mut cache), expected, "pixel {i}");
        }
        assert!(beyond > 0, "no pixel's first usable instance lies beyond the 32nd");
    }

    /// Another usable instance holds a pixel in either layout; the own instance, an instance below the
    /// confidence, no instance and a pixel outside the image do not.
    #[test]
    fn a_pixel_of_another_usable_instance_is_held_by_other() {
        // 4 × 2 pixels: row 0 = [1, 1, 2, 3], row 1 = [0, 2, 2, 0]; instance 3 scores below the threshold.
        let ids = [1u16, 1, 2, 3, 0, 2, 2, 0];
        let instances = [
            Instance { id: 1, class: 0, score: 0.9, bbox: [0, 0, 1, 0] },
            Instance { id: 2, class: 0, score: 0.9, bbox: [1, 0, 2, 1] },
            Instance { id: 3, class: 0, score: 0.1, bbox: [3, 0, 3, 0] },
        ];
        let planes = bit_planes(&ids);
        for pixels in [MaskPixels::IdImage(&ids), MaskPixels::BitPlanes(&planes)] {
            let m = MaskSet { width: 4, height: 2, instances: &instances, pixels };
            let held = |u, v| m.held_by_other(u, v, 1, 0.5);
            assert!(held(2, 0) && held(1, 1) && held(2, 1), "instance 2's pixels");
            assert!(!held(0, 0) && !held(1, 0), "the own instance's");
            assert!(!held(3, 0), "below the confidence");
            assert!(!held(0, 1) && !held(3, 1), "no instance");
            assert!(!held(4, 0) && !held(0, 2), "outside the image");
            assert!(m.held_by_other(0, 0, 2, 0.5), "seen from instance 2, instance 1 is the other");
        }
    }
}
