//! Stage 4: projection-guided mask annotation of the Gaussians (paper §III-B).
//!
//! Each Gaussian's support points are projected with K. They were back-projected from their own pixels with the
//! same K, so π_K returns exactly those pixels and every support point is valid (V_i is the whole support;
//! N_proj = N). Masks are candidates when their confidence s_j ≥ `min_confidence` and their box overlaps the
//! Gaussian's projected box B_i^2D; for candidates the support points inside the mask are counted (one pass
//! over the points, counts in a small hash table of (Gaussian, instance) pairs). The best candidate maximises the
//! confidence-weighted support s_j · |inside|, ties to the earlier instance; it is accepted when
//! N_proj ≥ `min_proj_points`, ρ = |inside| / N_proj > `min_support_ratio` and s_j ≥ `min_confidence`.

use bytemuck::Zeroable;

use crate::frame::Frame;
use crate::gmm::{self, Gaussian};
use crate::masks::{Instance, MaskPixels, MaskSet, MASK_SLOTS};
use crate::params::Params;
use crate::points::PixelWindow;
use crate::pool::Bounded;
use crate::supervoxel::{self, Revisit, Voxel};

/// Largest number of instances per frame that annotation considers (the instance index is stored in 8 bits);
/// further instances are ignored and counted.
pub const MAX_INSTANCES: usize = 255;

/// Support points of one Gaussian inside one instance mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Zeroable)]
#[repr(C)]
pub struct MaskHit {
    /// `(gaussian + 1) << 8 | instance index`; 0 marks a free slot.
    pub key: u32,
    /// Points inside the mask.
    pub count: u32,
}

impl MaskHit {
    /// The key of (Gaussian `g`, instance index `k`).
    #[inline]
    pub fn key_of(g: usize, k: usize) -> u32 {
        ((g as u32 + 1) << 8) | (k as u32 & 0xff)
    }

    /// Gaussian index of an occupied entry.
    pub fn gaussian(&self) -> usize {
        (self.key >> 8) as usize - 1
    }

    /// Instance index of an occupied entry.
    pub fn instance(&self) -> usize {
        (self.key & 0xff) as usize
    }
}

/// Counts of the annotation stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AnnotateStats {
    /// Gaussians that received an instance.
    pub annotated: u32,
    /// (Gaussian, instance) pairs with at least one point inside the mask.
    pub hit_pairs: u32,
    /// Hits lost because the hit table was full.
    pub hit_overflows: u32,
    /// Instances beyond [`MAX_INSTANCES`], ignored.
    pub ignored_instances: u32,
    /// Whether [`count_hits`] counted from the voxels (the same counts; points one by one only for the voxels
    /// whose instance the boxes leave open, over their Gaussians' pixels, no whole pass).
    pub by_voxels: bool,
}

/// Position of `key` in the table, or of the free slot where it would go; `None` when the table is full.
fn slot_of(hits: &[MaskHit], key: u32) -> Option<usize> {
    let n = hits.len();
    let mut pos = crate::pool::bucket(key, n);
    for _ in 0..n {
        if hits.get(pos).is_some_and(|h| h.key == key || h.key == 0) {
            return Some(pos);
        }
        pos += 1;
        if pos == n {
            pos = 0;
        }
    }
    None
}

/// Looks up or inserts the entry for `key`; `None` when the table is full.
fn entry(hits: &mut [MaskHit], key: u32) -> Option<&mut MaskHit> {
    let h = hits.get_mut(slot_of(hits, key)?)?;
    h.key = key;
    Some(h)
}

/// Points of Gaussian `g` inside instance `k`, from a filled table.
pub fn hits_of(hits: &[MaskHit], g: usize, k: usize) -> u32 {
    let key = MaskHit::key_of(g, k);
    slot_of(hits, key).and_then(|i| hits.get(i)).filter(|h| h.key == key).map_or(0, |h| h.count)
}

/// Whether instance `k` is a candidate at all (score threshold).
fn is_candidate(masks: &MaskSet<'_>, k: usize, params: &Params) -> bool {
    masks.instances.get(k).is_some_and(|i| i.score >= params.min_confidence)
}

#[inline]
fn boxes_overlap(a: [u16; 4], b: [u16; 4]) -> bool {
    a[0] <= b[2] && b[0] <= a[2] && a[1] <= b[3] && b[1] <= a[3]
}

/// Fills `hits` with the support points of each Gaussian inside each candidate mask. `masks_within_boxes`:
/// every sampled point of a usable instance lies in its box (from [`supervoxel::voxelize`]; false when unknown).
///
/// Where the voxels were split by these masks, each voxel whose points can belong to one instance only adds its
/// point count at once (its slot's instances, narrowed by the boxes); the other voxels' points are counted one
/// by one, over the pixels of their Gaussians' boxes only. Otherwise (or when the table fills up, so that which
/// pairs find room would depend on the order) every point is counted in one pass over the pixels. The counts
/// are the same either way.
#[allow(clippy::too_many_arguments)]
pub fn count_hits(
    frame: &Frame<'_>,
    masks: &MaskSet<'_>,
    voxel_masks: Option<&MaskSet<'_>>,
    masks_within_boxes: bool,
    voxels: &[Voxel],
    slots: &[u16],
    revisit: Revisit<'_>,
    gaussians: &[Gaussian],
    hits: &mut [MaskHit],
    params: &Params,
) -> AnnotateStats {
    hits.fill(MaskHit::zeroed());
    let mut stats = AnnotateStats {
        ignored_instances: masks.instances.len().saturating_sub(MAX_INSTANCES) as u32,
        ..Default::default()
    };
    let count_points = |hits: &mut [MaskHit], scope: Option<&Undecided>| {
        count_point_hits(frame, masks, voxel_masks, voxels, slots, revisit, gaussians, hits, params, scope)
    };
    if let Some(undecided) =
        count_hits_by_voxel(masks, voxel_masks, masks_within_boxes, voxels, gaussians, hits, params)
    {
        if count_points(hits, Some(&undecided)) == 0 {
            stats.hit_pairs = hits.iter().filter(|h| h.key != 0).count() as u32;
            stats.by_voxels = true;
            return stats;
        }
        hits.fill(MaskHit::zeroed());
    }
    stats.hit_overflows = count_points(hits, None);
    stats.hit_pairs = hits.iter().filter(|h| h.key != 0).count() as u32;
    stats
}

/// Adds points to `hits` one by one (the pixel pass): every point, or with `scope` only those of the voxels
/// [`count_hits_by_voxel`] left undecided, over their Gaussians' pixels. Returns the hits that found no room in
/// the table.
#[allow(clippy::too_many_arguments)]
fn count_point_hits(
    frame: &Frame<'_>,
    masks: &MaskSet<'_>,
    voxel_masks: Option<&MaskSet<'_>>,
    voxels: &[Voxel],
    slots: &[u16],
    revisit: Revisit<'_>,
    gaussians: &[Gaussian],
    hits: &mut [MaskHit],
    params: &Params,
    scope: Option<&Undecided>,
) -> u32 {
    let window = scope.map_or(PixelWindow::WHOLE, |u| u.window);
    let counted = |v: &Voxel, g: &Gaussian| {
        scope.is_none_or(|u| matches!(voxel_owner(v, g, masks.instances, u.boxes_decide, params), Owner::Unknown))
    };
    if window.u0 > window.u1 || window.v0 > window.v1 {
        return 0;
    }
    let mut overflows = 0;
    let instances = masks.instances.get(..MAX_INSTANCES.min(masks.instances.len())).unwrap_or(&[]);
    let w = frame.width as usize;
    supervoxel::for_each_voxel_point_in(frame, params, voxel_masks, voxels, slots, revisit, window, |p, v| {
        let Some((_, v)) = v else { return };
        let g = v.gaussian as usize;
        let Some(gauss) = gaussians.get(g).filter(|gauss| counted(v, gauss)) else { return };
        let mut add = |k: usize| {
            if let Some(inst) = instances.get(k) {
                if inst.score >= params.min_confidence && boxes_overlap(inst.bbox, gauss.pixel_bbox) {
                    match entry(hits, MaskHit::key_of(g, k)) {
                        Some(h) => h.count += 1,
                        None => overflows += 1,
                    }
                }
            }
        };
        match masks.pixels {
            MaskPixels::IdImage(ids) => {
                let id = ids.get(p.v as usize * w + p.u as usize).copied().unwrap_or(0);
                if id != 0 {
                    if let Some(k) = instances.iter().position(|i| i.id == id) {
                        add(k);
                    }
                }
            }
            MaskPixels::BitPlanes(_) => {
                for k in 0..instances.len() {
                    if masks.contains(k, p.u, p.v) {
                        add(k);
                    }
                }
            }
        }
    });
    overflows
}

/// Which instance the points of a voxel (of Gaussian `gauss`, split by the masks) can belong to.
enum Owner {
    /// None that the pixel pass would count for `gauss` (slot 0, or no usable instance of its slot whose box
    /// meets the Gaussian's).
    Nobody,
    /// Every point the pixel pass would count lies in instance `k`.
    One(usize),
    /// Two or more: its points must be counted one by one.
    Unknown,
}

/// The owner of voxel `v`: slot s ≥ 1 holds points of the usable instances s − 1, s − 1 + 7, … (its class; see
/// [`MaskSet::voxel_slot`]), slot 0 of no usable instance. The pixel pass counts a point of instance k for
/// `gauss` when k is usable and its box meets the Gaussian's projected box. So the voxel's counted points lie in
/// the class members whose box meets `gauss`'s: none, one (the owner) when the class has one usable member, or
/// — with `boxes_decide`, every sampled point of an instance inside its box, so a point of k lies in both k's
/// box and `gauss`'s — when one member's box meets `gauss`'s.
fn voxel_owner(v: &Voxel, gauss: &Gaussian, instances: &[Instance], boxes_decide: bool, params: &Params) -> Owner {
    let Some(first) = (supervoxel::key_slot(v.key) as usize).checked_sub(1) else { return Owner::Nobody };
    if instances.len() <= MASK_SLOTS {
        // One instance per slot: the class is instance s − 1 alone.
        return match instances.get(first) {
            Some(i) if i.score >= params.min_confidence && boxes_overlap(i.bbox, gauss.pixel_bbox) => Owner::One(first),
            _ => Owner::Nobody,
        };
    }
    let class = || {
        instances
            .iter()
            .enumerate()
            .take(MAX_INSTANCES)
            .skip(first)
            .step_by(MASK_SLOTS)
            .filter(|(_, i)| i.score >= params.min_confidence)
    };
    let mut meeting = class().filter(|(_, i)| boxes_overlap(i.bbox, gauss.pixel_bbox));
    match (meeting.next(), meeting.next()) {
        (None, _) => Owner::Nobody,
        (Some((k, _)), None) if boxes_decide || class().nth(1).is_none() => Owner::One(k),
        _ => Owner::Unknown,
    }
}

/// The voxels' part of [`count_hits`] where the voxels were split by these masks ([`MaskSet::voxel_slot`]): every
/// voxel with an [`Owner::One`] adds its point count to that pair. Returns the pixels of the Gaussians whose
/// voxels are left to count point by point ([`Owner::Unknown`]), or `None`, with `hits` still empty, where the
/// voxels cannot count: more than [`MAX_INSTANCES`], repeated ids or overlapping usable bit planes (a pixel counts for both), more than 7
/// bit-plane instances, a voxel at [`supervoxel::MAX_VOXEL_POINTS`] (it may have refused points the pixel pass
/// still finds), or a full hit table (which pairs find room depends on the order).
fn count_hits_by_voxel(
    masks: &MaskSet<'_>,
    voxel_masks: Option<&MaskSet<'_>>,
    masks_within_boxes: bool,
    voxels: &[Voxel],
    gaussians: &[Gaussian],
    hits: &mut [MaskHit],
    params: &Params,
) -> Option<Undecided> {
    let split = voxel_masks?;
    let instances = masks.instances;
    if !core::ptr::eq(split.instances, instances) || instances.len() > MAX_INSTANCES {
        return None;
    }
    let (one_per_slot, boxes_decide) = match (split.pixels, masks.pixels) {
        (MaskPixels::IdImage(a), MaskPixels::IdImage(b)) => {
            let distinct = instances.iter().enumerate().all(|(k, i)| instances.iter().take(k).all(|j| j.id != i.id));
            (core::ptr::eq(a, b) && distinct, masks_within_boxes)
        }
        (MaskPixels::BitPlanes(a), MaskPixels::BitPlanes(b)) => {
            (core::ptr::eq(a, b) && instances.len() <= MASK_SLOTS && !usable_planes_overlap(masks, params), false)
        }
        _ => (false, false),
    };
    if !one_per_slot || voxels.iter().any(|v| v.count >= supervoxel::MAX_VOXEL_POINTS) {
        return None;
    }
    let mut window = PixelWindow::EMPTY;
    for v in voxels {
        let g = v.gaussian as usize;
        let Some(gauss) = gaussians.get(g) else { continue };
        match voxel_owner(v, gauss, instances, boxes_decide, params) {
            Owner::Nobody => {}
            Owner::One(k) => match entry(hits, MaskHit::key_of(g, k)) {
                Some(h) => h.count += u32::from(v.count),
                None => {
                    hits.fill(MaskHit::zeroed());
                    return None;
                }
            },
            Owner::Unknown => window = window.union(PixelWindow::from_box(gauss.pixel_bbox)),
        }
    }
    Some(Undecided { window, boxes_decide })
}

/// What [`count_hits_by_voxel`] leaves to the pixel pass.
struct Undecided {
    /// The pixels of every Gaussian with an [`Owner::Unknown`] voxel ([`PixelWindow::EMPTY`]: none).
    window: PixelWindow,
    /// Whether boxes decide owners ([`voxel_owner`]).
    boxes_decide: bool,
}

/// Whether two instances of bit-plane `masks` that pass `min_confidence` share a pixel.
fn usable_planes_overlap(masks: &MaskSet<'_>, params: &Params) -> bool {
    let MaskPixels::BitPlanes(bits) = masks.pixels else { return false };
    let plane = MaskSet::plane_bytes(masks.width, masks.height);
    let usable: [bool; MASK_SLOTS] =
        core::array::from_fn(|k| masks.instances.get(k).is_some_and(|i| i.score >= params.min_confidence));
    // Four bytes of every plane at a time (little-endian; a plane's last word may be short). A whole word is
    // read as one, not copied into a buffer: the copy of a run-time length was a `memcpy` call per word and
    // plane, 0.4 M instructions per frame on the Cortex-M7.
    let word = |k: usize, i: usize| {
        let start = k * plane + i;
        let end = (start + 4).min((k + 1) * plane);
        match bits.get(start..end) {
            Some(&[a, b, c, d]) => u32::from_le_bytes([a, b, c, d]),
            Some(tail) => tail.iter().rev().fold(0u32, |w, &x| w << 8 | x as u32),
            None => 0,
        }
    };
    (0..plane).step_by(4).any(|i| {
        let mut seen = 0u32;
        for (k, _) in usable.iter().enumerate().filter(|(_, &u)| u) {
            let b = word(k, i);
            if seen & b != 0 {
                return true;
            }
            seen |= b;
        }
        false
    })
}

/// The best match among `candidates` given a hit counter: (instance index, inside count), maximising s_j · count.
pub fn best_match(masks: &MaskSet<'_>, params: &Params, mut inside: impl FnMut(usize) -> u32) -> Option<(usize, u32)> {
    let mut best: Option<(f32, usize, u32)> = None;
    for k in 0..masks.instances.len().min(MAX_INSTANCES) {
        if !is_candidate(masks, k, params) {
            continue;
        }
        let n = inside(k);
        if n == 0 {
            continue;
        }
        let score = masks.instances.get(k).map_or(0.0, |i| i.score) * n as f32;
        if best.is_none_or(|(b, _, _)| score > b) {
            best = Some((score, k, n));
        }
    }
    best.map(|(_, k, n)| (k, n))
}

/// Applies the acceptance rule to a unit of `support` points with `inside` of them in instance `k`; writes the
/// semantic attributes (a, ℓ, s, ρ) through `set`, or clears them.
pub fn accept(
    masks: &MaskSet<'_>,
    params: &Params,
    support: u32,
    best: Option<(usize, u32)>,
    g: &mut Gaussian,
) -> bool {
    g.instance = 0;
    g.class = 0;
    g.score = 0.0;
    g.support_ratio = 0.0;
    let Some((k, inside)) = best else { return false };
    let Some(inst) = masks.instances.get(k) else { return false };
    let ratio = if support > 0 { inside as f32 / support as f32 } else { 0.0 };
    // ρ of the best candidate is kept even when it is refused: fusion uses it to hold back uncertain fragments.
    g.support_ratio = ratio;
    let small_fragment = params.variant.extensions() && ratio >= params.small_fragment_ratio;
    let enough = support >= params.min_proj_points || small_fragment;
    if enough && ratio > params.min_support_ratio && inst.score >= params.min_confidence {
        g.instance = inst.id;
        g.class = inst.class;
        g.score = inst.score;
        true
    } else {
        false
    }
}

/// Most Gaussians cut along a mask boundary per frame; further straddling Gaussians stay whole.
pub const MAX_MASK_SPLITS: usize = 64;

/// One Gaussian to cut along the boundary of mask `instance`.
#[derive(Debug, Clone, Copy, Default)]
struct Cut {
    gaussian: u16,
    instance: u8,
    inside_points: u32,
    new_gaussian: Option<u16>,
}

/// Mask-consistent refinement (see `Params::mask_split_min_share`): cuts each Gaussian whose support straddles
/// the boundary of its best mask into the voxels mostly inside and the voxels mostly outside, then recomputes the
/// Gaussian statistics. Returns the number of cuts; `hits` must be recounted afterwards when it is not 0.
#[allow(clippy::too_many_arguments)]
pub fn cut_along_masks(
    frame: &Frame<'_>,
    masks: &MaskSet<'_>,
    voxel_masks: Option<&MaskSet<'_>>,
    voxels: &mut [Voxel],
    slots: &[u16],
    revisit: Revisit<'_>,
    scratch: &mut [u16],
    gaussians: &mut Bounded<'_, Gaussian>,
    hits: &[MaskHit],
    params: &Params,
) -> u32 {
    // At most MAX_MASK_SPLITS cuts a frame; a Gaussian beyond them stays whole (annotated as the paper does).
    let mut cuts: heapless::Vec<Cut, MAX_MASK_SPLITS> = heapless::Vec::new();
    for (g, gauss) in gaussians.as_mut_slice().iter_mut().enumerate() {
        gauss.owner = 0;
        let Some((k, inside)) = best_match(masks, params, |k| hits_of(hits, g, k)) else { continue };
        let share = libm::ceilf(params.mask_split_min_share * gauss.count as f32) as u32;
        let least = params.gmm_min_points.max(share);
        if inside >= least && gauss.count.saturating_sub(inside) >= least {
            let cut = Cut { gaussian: g as u16, instance: k as u8, inside_points: 0, new_gaussian: None };
            if cuts.push(cut).is_ok() {
                gauss.owner = cuts.len() as u8; // marks the Gaussian as cut number len (1-based) during this stage
            }
        }
    }
    if cuts.is_empty() {
        return 0;
    }
    // Points inside the mask per voxel of a cut Gaussian.
    let n = voxels.len().min(scratch.len());
    let Some(inside) = scratch.get_mut(..n) else { return 0 };
    inside.fill(0);
    {
        let gauss = gaussians.as_slice();
        supervoxel::for_each_voxel_point(frame, params, voxel_masks, voxels, slots, revisit, |p, v| {
            let Some((vi, g)) = v.and_then(|(vi, v)| gauss.get(v.gaussian as usize).map(|g| (vi, g))) else { return };
            let Some(cut) = (g.owner as usize).checked_sub(1).and_then(|c| cuts.get(c)) else { return };
            if masks.contains(cut.instance as usize, p.u, p.v) {
                if let Some(c) = inside.get_mut(vi) {
                    *c = c.saturating_add(1);
                }
            }
        });
    }
    // Points that would move (voxels mostly inside), per cut; a cut that leaves either side too small is dropped.
    for (v, &c) in voxels.iter().zip(inside.iter()) {
        let Some(g) = gaussians.get(v.gaussian as usize) else { continue };
        if let Some(cut) = (g.owner as usize).checked_sub(1).and_then(|i| cuts.get_mut(i)) {
            if 2 * c as u32 > v.count as u32 {
                cut.inside_points += v.count as u32;
            }
        }
    }
    let mut made = 0;
    for cut in cuts.iter_mut() {
        let Some(g) = gaussians.get(cut.gaussian as usize).copied() else { continue };
        let outside = g.count.saturating_sub(cut.inside_points);
        if cut.inside_points < params.gmm_min_points || outside < params.gmm_min_points {
            continue;
        }
        let mut piece = Gaussian::zeroed();
        piece.supervoxel = g.supervoxel;
        cut.new_gaussian = gaussians.push(piece).map(|i| i as u16);
        made += cut.new_gaussian.is_some() as u32;
    }
    for (v, &c) in voxels.iter_mut().zip(inside.iter()) {
        let Some(g) = gaussians.get(v.gaussian as usize) else { continue };
        let Some(cut) = (g.owner as usize).checked_sub(1).and_then(|i| cuts.get(i)) else { continue };
        if let Some(new) = cut.new_gaussian {
            if 2 * c as u32 > v.count as u32 {
                v.gaussian = new;
            }
        }
    }
    for g in gaussians.as_mut_slice() {
        g.owner = 0;
    }
    if made > 0 {
        gmm::recompute_statistics(
            frame,
            voxel_masks,
            voxels,
            slots,
            revisit,
            scratch,
            gaussians.as_mut_slice(),
            params,
        );
    }
    made
}

/// Annotates every Gaussian from the filled hit table.
pub fn annotate(masks: &MaskSet<'_>, gaussians: &mut [Gaussian], hits: &[MaskHit], params: &Params) -> u32 {
    let mut annotated = 0;
    for (g, gauss) in gaussians.iter_mut().enumerate() {
        let best = best_match(masks, params, |k| hits_of(hits, g, k));
        if accept(masks, params, gauss.count, best, gauss) {
            annotated += 1;
        }
    }
    annotated
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::masks::Instance;

    /// Overlap of usable bit planes, in a plane's whole words and in its short last word (7 × 5 pixels: 5 bytes
    /// a plane), and none with an instance below `min_confidence`.
    #[test]
    fn usable_planes_overlap_in_whole_and_short_words() {
        let params = Params::default();
        let instance = |id: u16, score: f32| Instance { id, class: 1, score, bbox: [0, 0, 6, 4] };
        let (width, height) = (7u16, 5u16);
        let plane = MaskSet::plane_bytes(width, height);
        assert_eq!(plane, 5);
        // Pixel p of instance k: bit p % 8 of byte k · plane + p / 8.
        let planes = |pixels: &[(usize, usize)]| {
            let mut bits = [0u8; 15];
            for &(k, p) in pixels {
                bits[k * plane + p / 8] |= 1 << (p % 8);
            }
            bits
        };
        let overlaps = |bits: &[u8], scores: [f32; 3]| {
            let instances = [instance(1, scores[0]), instance(2, scores[1]), instance(3, scores[2])];
            let masks = MaskSet { width, height, instances: &instances, pixels: MaskPixels::BitPlanes(bits) };
            usable_planes_overlap(&masks, &params)
        };
        let usable = [1.0, 1.0, 1.0];
        // Disjoint: instance 0 on pixels 0–9, 1 on 10–31, 2 on 32–34 (the short word).
        let disjoint: heapless::Vec<(usize, usize), 40> =
            (0..10).map(|p| (0, p)).chain((10..32).map(|p| (1, p))).chain((32..35).map(|p| (2, p))).collect();
        assert!(!overlaps(&planes(&disjoint), usable));
        // Instances 1 and 2 share pixel 33, in the last byte.
        let mut tail = disjoint.clone();
        tail.push((1, 33)).unwrap();
        assert!(overlaps(&planes(&tail), usable));
        // Instances 0 and 2 share pixel 5, in the first word.
        let mut head = disjoint.clone();
        head.push((2, 5)).unwrap();
        assert!(overlaps(&planes(&head), usable));
        // The same overlaps with instance 2 below min_confidence: none counts.
        let unusable = [1.0, 1.0, 0.5 * params.min_confidence];
        assert!(!overlaps(&planes(&tail), unusable));
        assert!(!overlaps(&planes(&head), unusable));
    }
}
