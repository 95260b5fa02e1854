//! Stage 10: superquadric tracks across frames (paper §V-B, equations 14–18).
//!
//! Tracks live in the world frame when frames carry a camera pose, else in the camera frame. A measurement
//! (an accepted superquadric) is associated with the nearest track of the same label whose centre lies within
//! `d_max` (equations 14–15; each track takes at most one measurement per frame, measurements in object
//! order); without one a new track starts. A matched measurement is first aligned with the track (equation 16:
//! the 8 proper pairs (R̂·P·D, Pᵀ·ŝ) of an x-y swap P and axis sign flips D, chosen by equation 17 with
//! β = 1 / mean(s_{t−1})², which makes the scale term unit-free), then smoothed: centre EMA α_c, rotation SLERP
//! α_R along the shortest path, half-axes and exponents EMA α_s (equation 18). The `wsqa` variant skips the
//! alignment. A measurement whose aligned half-axes differ from the track's by more than a factor
//! `track_scale_gate` is an outlier fit: the track keeps its state (an m2smap decision; the cabinet sequence has
//! one such fit, a half-axis of 0.97 m against 0.44 m). A track not updated for `track_max_missed` frames is
//! retired.

use bytemuck::Zeroable;

use crate::linalg::{self, Mat3, Vec3};
use crate::params::Params;
use crate::pool::{self, Bounded};
use crate::superquadric::{Superquadric, EPS_RANGE, MIN_SCALE};

/// One superquadric track.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
#[repr(C)]
pub struct Track {
    /// The smoothed superquadric (world frame when poses are given).
    pub sq: Superquadric,
    /// Track id, unique over the mapper's lifetime (wraps at 65 535).
    pub id: u16,
    /// Category label ℓ.
    pub class: u16,
    /// Frame number of the last update, or of the last frame that accepted the track's state as it was
    /// ([`Tracker::hold`]).
    pub last_frame: u32,
    /// Updates so far (the first measurement included).
    pub updates: u32,
    /// Rotation change of the last update, degrees (0 for a new track).
    pub last_jump_deg: f32,
}

/// The 8 proper equivalents (R·P·D, Pᵀ·s) of a superquadric's frame (equation 16).
pub fn equivalents(rotation: &Mat3, scales: Vec3) -> [(Mat3, Vec3); 8] {
    let (c0, c1, c2) = (linalg::column(rotation, 0), linalg::column(rotation, 1), linalg::column(rotation, 2));
    let flip = |c: Vec3, s: f32| linalg::scale(c, s);
    // P = I with det D = +1, then P = P_xy (columns 0 and 1 swapped, scales swapped) with det D = −1.
    let same = [(1.0, 1.0, 1.0), (1.0, -1.0, -1.0), (-1.0, 1.0, -1.0), (-1.0, -1.0, 1.0)];
    let swapped = [(-1.0, 1.0, 1.0), (1.0, -1.0, 1.0), (1.0, 1.0, -1.0), (-1.0, -1.0, -1.0)];
    let mut out = [(linalg::IDENTITY, scales); 8];
    for (o, (dx, dy, dz)) in out.iter_mut().zip(same) {
        *o = (linalg::from_columns(flip(c0, dx), flip(c1, dy), flip(c2, dz)), scales);
    }
    for (o, (dx, dy, dz)) in out.iter_mut().skip(4).zip(swapped) {
        *o = (linalg::from_columns(flip(c1, dx), flip(c0, dy), flip(c2, dz)), [scales[1], scales[0], scales[2]]);
    }
    out
}

/// Largest |ε1 − ε2| for which a superquadric counts as cube-symmetric (see [`align`]).
pub const CUBIC_EPS_GAP: f32 = 0.1;

/// The frame with its axes cycled `k` times (x → y → z → x), scales alongside; a proper rotation.
fn cycle(rotation: &Mat3, scales: Vec3, k: usize) -> (Mat3, Vec3) {
    let c = [linalg::column(rotation, 0), linalg::column(rotation, 1), linalg::column(rotation, 2)];
    let (i, j, l) = match k % 3 {
        0 => (0, 1, 2),
        1 => (1, 2, 0),
        _ => (2, 0, 1),
    };
    let pick = |n: usize| c.get(n).copied().unwrap_or([0.0; 3]);
    let s = |n: usize| scales.get(n).copied().unwrap_or(0.0);
    (linalg::from_columns(pick(i), pick(j), pick(l)), [s(i), s(j), s(l)])
}

/// Equation 17: the equivalent of the measurement closest to the previous state, maximising
/// tr(R_{t−1}ᵀ R) − β‖s_{t−1} − s‖².
///
/// The paper's set (equation 16) keeps the local z axis. m2smap's fit tries each PCA axis as z, so when both
/// shapes are cube-symmetric (|ε1 − ε2| ≤ [`CUBIC_EPS_GAP`], a box or a sphere, where exchanging z with x or y
/// leaves the shape unchanged) the three cyclic axis permutations of each of the 8 pairs are candidates too
/// (24 in all); a cylinder keeps its axis as z.
pub fn align(previous: &Superquadric, measured: &Superquadric) -> Superquadric {
    let mean_s = (previous.scales[0] + previous.scales[1] + previous.scales[2]) / 3.0;
    let beta = 1.0 / (mean_s * mean_s).max(1e-6);
    let prev_t = linalg::transpose(&previous.rotation);
    let cubic = |q: &Superquadric| libm::fabsf(q.eps[0] - q.eps[1]) <= CUBIC_EPS_GAP;
    let cycles = if cubic(previous) && cubic(measured) { 3 } else { 1 };
    let mut best = (f32::NEG_INFINITY, *measured);
    for k in 0..cycles {
        let (rc, sc) = cycle(&measured.rotation, measured.scales, k);
        for (r, s) in equivalents(&rc, sc) {
            let m = linalg::mat_mul(&prev_t, &r);
            let d = linalg::sub(previous.scales, s);
            let score = m[0][0] + m[1][1] + m[2][2] - beta * linalg::dot(d, d);
            if score > best.0 {
                best = (score, Superquadric { rotation: r, scales: s, ..*measured });
            }
        }
    }
    best.1
}

/// Equation 18: the smoothed state from the previous state and an aligned measurement.
pub fn smooth(previous: &Superquadric, aligned: &Superquadric, params: &Params) -> Superquadric {
    let ema = |a: f32, b: f32, alpha: f32| alpha * b + (1.0 - alpha) * a;
    let ema3 = |a: Vec3, b: Vec3, alpha: f32| [ema(a[0], b[0], alpha), ema(a[1], b[1], alpha), ema(a[2], b[2], alpha)];
    let q = linalg::slerp(
        linalg::quat_from_matrix(&previous.rotation),
        linalg::quat_from_matrix(&aligned.rotation),
        params.alpha_r,
    );
    Superquadric {
        centre: ema3(previous.centre, aligned.centre, params.alpha_c),
        rotation: linalg::matrix_from_quat(q),
        // Clamped to the bounds: an average of in-bound values can round a last bit outside them.
        scales: ema3(previous.scales, aligned.scales, params.alpha_s).map(|a| a.max(MIN_SCALE)),
        eps: [
            ema(previous.eps[0], aligned.eps[0], params.alpha_s),
            ema(previous.eps[1], aligned.eps[1], params.alpha_s),
        ]
        .map(|e| e.clamp(EPS_RANGE.0, EPS_RANGE.1)),
    }
}

/// Most refused objects the tracker remembers ([`Refusal`]).
pub const MAX_REFUSALS: usize = 16;
/// While an object stays refused, its cold superquadric search runs again every this many frames (the frames
/// between keep its Gaussians, as a refused fit does; measured on redkitchen 0–299 with segmenter masks: every
/// 2nd frame keeps 95 % of the superquadrics at 85 % of the time per frame, every 4th 85 % at 71 %).
pub const REFUSAL_RETRY_FRAMES: u16 = 2;

/// An object whose cold superquadric search found no acceptable shape, remembered so that the next frames do
/// not repeat the search where it just failed: an instance one superquadric cannot describe (a chair with its
/// table, a counter with its wall) stays so from frame to frame, and each failed search costs the most (every
/// finishing candidate runs to its end).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Refusal {
    /// Centre of the object's support box in the tracking frame, metres.
    pub centre: Vec3,
    /// The object's label.
    pub class: u16,
    /// Consecutive frames the object has been refused (searched or skipped); 0 marks a free slot.
    pub count: u16,
    /// Tracker frame of the last refusal.
    pub last_frame: u32,
}

/// The index of the `(index, position)` candidate nearest to `centre` within `d_max` metres (the first of
/// equally near ones), used for tracks (equation 15) and refusals alike.
fn nearest_within(candidates: impl Iterator<Item = (usize, Vec3)>, centre: Vec3, d_max: f32) -> Option<usize> {
    let mut best: Option<(f32, usize)> = None;
    for (i, p) in candidates {
        let d = linalg::norm(linalg::sub(p, centre));
        if d <= d_max && best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, i));
        }
    }
    best.map(|(_, i)| i)
}

/// The track state of a frame's superquadrics.
pub struct Tracker<'a> {
    /// The tracks.
    pub tracks: Bounded<'a, Track>,
    /// Next track id.
    pub next_id: u16,
    /// Frames seen (the frame number of the next update).
    pub frame: u32,
    /// Recently refused objects (a free slot has `count` 0). When all are taken, the least recently refused
    /// is forgotten first (lowest slot on ties).
    pub refusals: [Refusal; MAX_REFUSALS],
}

/// What an update did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Updated {
    /// Index of the track in the pool, `None` when the pool was full of tracks updated in this frame (the
    /// measurement is used unsmoothed); a full pool otherwise gives the new track the slot of the track unseen
    /// for the most frames.
    pub index: Option<usize>,
    /// Whether a new track was started.
    pub new: bool,
    /// Rotation change of the track, degrees (0 for a new track).
    pub jump_deg: f32,
    /// The smoothed superquadric (tracking frame).
    pub sq: Superquadric,
    /// Whether the measurement was refused by the scale gate (the track's state is returned unchanged).
    pub gated: bool,
    /// How far the update moved the track's centre, metres (0 for a new track).
    pub step_m: f32,
}

/// Whether the half-axes of the measurement are each within a factor `gate` of the track's. `per_axis`
/// compares them axis by axis (after alignment: a measurement that no equivalent brings onto the track's axes,
/// e.g. a plate fitted with its thin axis as x instead of z, would otherwise be blended into a shape that is
/// neither); without alignment they are compared sorted, so the gate judges the shape and not the axis
/// labelling (otherwise it would silently hide WSQA's flips).
fn within_scale_gate(track: &Superquadric, measured: &Superquadric, gate: f32, per_axis: bool) -> bool {
    let sorted = |mut s: Vec3| {
        if !per_axis {
            s.sort_unstable_by(f32::total_cmp);
        }
        s
    };
    let (a, b) = (sorted(track.scales), sorted(measured.scales));
    a.iter().zip(&b).all(|(&x, &y)| x.max(y) <= gate * x.min(y))
}

impl<'a> Tracker<'a> {
    /// A tracker over `tracks`.
    pub fn new(tracks: Bounded<'a, Track>) -> Self {
        Tracker { tracks, next_id: 0, frame: 0, refusals: [Refusal::default(); MAX_REFUSALS] }
    }

    /// The remembered refusal of label `class` nearest to `centre` (tracking frame) within `d_max` that was
    /// refused in the previous frame and not yet in this one.
    fn recent_refusal(&self, centre: Vec3, class: u16, params: &Params) -> Option<usize> {
        let recent = self
            .refusals
            .iter()
            .enumerate()
            .filter(|(_, r)| r.count > 0 && r.class == class && r.last_frame.wrapping_add(1) == self.frame);
        nearest_within(recent.map(|(i, r)| (i, r.centre)), centre, params.d_max)
    }

    /// Whether the cold search for an object at `centre` (tracking frame) with label `class` is skipped this
    /// frame: it was refused in the previous frame and this is not one of its retry frames (every
    /// [`REFUSAL_RETRY_FRAMES`]-th). A skip counts as a refusal.
    pub fn skips_search(&mut self, centre: Vec3, class: u16, params: &Params) -> bool {
        let frame = self.frame;
        let Some(r) = self.recent_refusal(centre, class, params).and_then(|i| self.refusals.get_mut(i)) else {
            return false;
        };
        if r.count % REFUSAL_RETRY_FRAMES == 0 {
            return false;
        }
        *r = Refusal { centre, count: r.count.saturating_add(1), last_frame: frame, ..*r };
        true
    }

    /// Marks track `index` as seen this frame without a measurement: its state passed this frame's acceptance
    /// test and stands for the object (the map's held state). The state and the update count stay as they
    /// were; the track is not retired while the frames keep accepting it.
    pub fn hold(&mut self, index: usize) {
        let frame = self.frame;
        if let Some(t) = self.tracks.as_mut_slice().get_mut(index) {
            t.last_frame = frame;
        }
    }

    /// Records that the cold search for an object at `centre` with label `class` found no acceptable shape.
    pub fn refuse(&mut self, centre: Vec3, class: u16, params: &Params) {
        let frame = self.frame;
        let slot = match self.recent_refusal(centre, class, params) {
            Some(i) => Some(i),
            // A free or stale slot, else the least recently refused.
            None => self
                .refusals
                .iter()
                .enumerate()
                .min_by_key(
                    |(_, r)| if r.count == 0 || r.last_frame.wrapping_add(1) < frame { 0 } else { r.last_frame.max(1) },
                )
                .map(|(i, _)| i),
        };
        if let Some(r) = slot.and_then(|i| self.refusals.get_mut(i)) {
            let count =
                if r.count > 0 && r.class == class && r.last_frame.wrapping_add(1) == frame { r.count } else { 0 };
            *r = Refusal { centre, class, count: count.saturating_add(1), last_frame: frame };
        }
    }

    /// Forgets the refusal of an object at `centre` with label `class` (its shape was accepted).
    pub fn forget_refusal(&mut self, centre: Vec3, class: u16, params: &Params) {
        if let Some(r) = self.recent_refusal(centre, class, params).and_then(|i| self.refusals.get_mut(i)) {
            *r = Refusal::default();
        }
    }

    /// Starts a frame: retires tracks not updated for more than `track_max_missed` frames.
    pub fn begin_frame(&mut self, params: &Params) {
        self.frame = self.frame.wrapping_add(1);
        let frame = self.frame;
        let mut keep = 0;
        let n = self.tracks.len();
        let slice = self.tracks.as_mut_slice();
        for i in 0..n {
            let Some(t) = slice.get(i).copied() else { continue };
            if frame.wrapping_sub(t.last_frame) <= params.track_max_missed + 1 {
                if let Some(slot) = slice.get_mut(keep) {
                    *slot = t;
                }
                keep += 1;
            }
        }
        while self.tracks.len() > keep {
            self.tracks.pop();
        }
        // The pool lives across frames; its report is this frame's.
        self.tracks.restart_accounting();
    }

    /// Equations 14–15: the nearest track of label `class` within `d_max` of `centre` that has not been
    /// updated (or held, [`Tracker::hold`]) in this frame.
    pub fn nearest(&self, centre: Vec3, class: u16, params: &Params) -> Option<usize> {
        let open =
            self.tracks.as_slice().iter().enumerate().filter(|(_, t)| t.class == class && t.last_frame != self.frame);
        nearest_within(open.map(|(i, t)| (i, t.sq.centre)), centre, params.d_max)
    }

    /// Associates, aligns and smooths one measurement (`sq` in the tracking frame, label `class`).
    pub fn update(&mut self, sq: &Superquadric, class: u16, params: &Params, align_equivalents: bool) -> Updated {
        let frame = self.frame;
        if let Some(i) = self.nearest(sq.centre, class, params) {
            if let Some(t) = self.tracks.get_mut(i) {
                let aligned = if align_equivalents { align(&t.sq, sq) } else { *sq };
                if !within_scale_gate(&t.sq, &aligned, params.track_scale_gate, align_equivalents) {
                    // An outlier shape (a bad fit): the track keeps its state and stays alive.
                    t.last_frame = frame;
                    return Updated { index: Some(i), new: false, jump_deg: 0.0, sq: t.sq, gated: true, step_m: 0.0 };
                }
                let smoothed = smooth(&t.sq, &aligned, params);
                let jump = linalg::rotation_angle_between(&t.sq.rotation, &smoothed.rotation);
                let step_m = linalg::norm(linalg::sub(smoothed.centre, t.sq.centre));
                t.sq = smoothed;
                t.last_frame = frame;
                t.updates += 1;
                t.last_jump_deg = jump.to_degrees();
                return Updated {
                    index: Some(i),
                    new: false,
                    jump_deg: t.last_jump_deg,
                    sq: smoothed,
                    gated: false,
                    step_m,
                };
            }
        }
        let track = Track { sq: *sq, id: self.next_id, class, last_frame: frame, updates: 1, last_jump_deg: 0.0 };
        let mut index = self.tracks.push(track);
        if index.is_none() {
            // The pool is full (counted as its overflow): the track unseen for the most frames gives way, the
            // lowest slot on ties; a track updated in this frame never does (then the new one is refused).
            let stalest = pool::stalest(self.tracks.as_slice(), frame, |t| t.last_frame);
            if let Some(slot) = stalest.and_then(|i| self.tracks.get_mut(i)) {
                *slot = track;
                index = stalest;
            }
        }
        if index.is_some() {
            self.next_id = self.next_id.wrapping_add(1);
        }
        Updated { index, new: index.is_some(), jump_deg: 0.0, sq: *sq, gated: false, step_m: 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_object_is_searched_every_other_frame_and_forgotten_once_accepted() {
        let params = Params::default();
        let mut storage = [Track::zeroed(); 2];
        let mut tracker = Tracker::new(Bounded::new(&mut storage));
        let (here, class) = ([0.5, 0.0, 2.0], 3);
        let mut searched = [false; 6];
        for s in searched.iter_mut() {
            tracker.begin_frame(&params);
            if !tracker.skips_search(here, class, &params) {
                *s = true;
                tracker.refuse(here, class, &params);
            }
        }
        assert_eq!(searched, [true, false, true, false, true, false]);
        // Another label, or a place beyond d_max, is searched.
        tracker.begin_frame(&params);
        assert!(!tracker.skips_search(here, class + 1, &params));
        assert!(!tracker.skips_search([0.5, 0.0, 2.0 + 1.1 * params.d_max], class, &params));
        // A frame without the object breaks the chain: the next frame searches.
        tracker.begin_frame(&params);
        assert!(!tracker.skips_search(here, class, &params));
        // Refused, then accepted on a retry frame: forgotten, so the frame after searches again.
        tracker.refuse(here, class, &params);
        tracker.begin_frame(&params);
        assert!(tracker.skips_search(here, class, &params));
        tracker.begin_frame(&params);
        assert!(!tracker.skips_search(here, class, &params));
        tracker.forget_refusal(here, class, &params);
        tracker.begin_frame(&params);
        assert!(!tracker.skips_search(here, class, &params));
    }

    /// A track whose state the frames keep accepting without a new fit (held) stays alive past
    /// `track_max_missed` with its state and update count as they were, and is taken for that frame; one that is
    /// neither updated nor held retires.
    #[test]
    fn a_held_track_stays_alive_and_unchanged() {
        let params = Params::default();
        let mut storage = [Track::zeroed(); 2];
        let mut tracker = Tracker::new(Bounded::new(&mut storage));
        let sq = Superquadric { centre: [0.3, 0.0, 2.0], ..Superquadric::default_shape() };
        let (class, other) = (3, 4);
        tracker.begin_frame(&params);
        assert!(tracker.update(&sq, class, &params, true).new);
        let far = Superquadric { centre: [-0.6, 0.0, 2.5], ..sq };
        assert!(tracker.update(&far, other, &params, true).new);
        let before = tracker.tracks.as_slice().first().copied();
        for _ in 0..params.track_max_missed + 5 {
            tracker.begin_frame(&params);
            let i = tracker.nearest(sq.centre, class, &params);
            assert_eq!(i, Some(0), "the held track is still there");
            tracker.hold(0);
            // Held this frame: not open to another measurement of the same frame.
            assert_eq!(tracker.nearest(sq.centre, class, &params), None);
        }
        let after = tracker.tracks.as_slice().first().copied();
        assert_eq!(after.map(|t| (t.sq, t.updates, t.id)), before.map(|t| (t.sq, t.updates, t.id)));
        // The other track was neither updated nor held: retired.
        assert_eq!(tracker.tracks.len(), 1);
        assert_eq!(tracker.nearest(far.centre, other, &params), None);
    }

    /// A full track pool refuses a new track in the frame it happens; the next frame's report starts at 0
    /// (the pool lives across frames, its overflow count does not).
    #[test]
    fn track_pool_overflows_are_counted_in_their_frame_only() {
        let params = Params::default();
        let mut storage = [Track::zeroed(); 2];
        let mut tracker = Tracker::new(Bounded::new(&mut storage));
        let sq = |x: f32| Superquadric { centre: [x, 0.0, 2.0], ..Superquadric::default_shape() };
        tracker.begin_frame(&params);
        for k in 0..3 {
            tracker.update(&sq(k as f32), 1, &params, true);
        }
        let u = tracker.tracks.usage();
        assert_eq!((u.peak, u.overflow_events), (2, 1), "three objects, two tracks");
        tracker.begin_frame(&params);
        let u = tracker.tracks.usage();
        assert_eq!((u.peak, u.overflow_events), (2, 0), "the next frame reports no refusal of its own");
        tracker.update(&sq(0.0), 1, &params, true);
        assert_eq!(tracker.tracks.usage().overflow_events, 0, "an existing track takes it");
    }

    /// A full track pool gives the slot of the track unseen for the most frames to a new object; tracks
    /// updated in this frame keep theirs.
    #[test]
    fn a_full_track_pool_drops_the_track_unseen_longest() {
        let params = Params::default();
        let mut storage = [Track::zeroed(); 3];
        let mut tracker = Tracker::new(Bounded::new(&mut storage));
        let sq = |x: f32| Superquadric { centre: [x, 0.0, 2.0], ..Superquadric::default_shape() };
        tracker.begin_frame(&params);
        for k in 0..3 {
            tracker.update(&sq(k as f32), 1, &params, true);
        }
        tracker.begin_frame(&params);
        tracker.update(&sq(0.0), 1, &params, true);
        tracker.update(&sq(2.0), 1, &params, true);
        tracker.begin_frame(&params);
        tracker.update(&sq(0.0), 1, &params, true);
        // Track 1 (x = 1) was last seen 2 frames ago, track 2 (x = 2) 1 frame ago: a new object takes track 1's
        // slot.
        let new = tracker.update(&sq(5.0), 1, &params, true);
        assert_eq!((new.index, new.new), (Some(1), true));
        let ids = [0, 1, 2].map(|i| tracker.tracks.get(i).map(|t| t.id));
        assert_eq!(ids, [Some(0), Some(3), Some(2)]);
        assert_eq!(tracker.tracks.usage().overflow_events, 1, "the full pool is still reported");
        // Every other track was updated this frame or is the new one: one more object is refused.
        tracker.update(&sq(2.0), 1, &params, true);
        assert_eq!(tracker.update(&sq(9.0), 1, &params, true).index, None);
    }

    #[test]
    fn a_full_refusal_table_forgets_the_least_recently_refused() {
        let params = Params::default();
        let mut storage = [Track::zeroed(); 2];
        let mut tracker = Tracker::new(Bounded::new(&mut storage));
        let at = |k: usize| [k as f32 * 2.0 * params.d_max, 0.0, 2.0];
        tracker.begin_frame(&params);
        for k in 0..MAX_REFUSALS {
            tracker.refuse(at(k), 1, &params);
        }
        tracker.begin_frame(&params);
        // Object 0 is refused again this frame; one more object takes the slot of object 1 (refused longest ago).
        tracker.refuse(at(0), 1, &params);
        tracker.refuse(at(MAX_REFUSALS), 1, &params);
        assert!(tracker.refusals.iter().any(|r| r.centre == at(MAX_REFUSALS)));
        assert!(!tracker.refusals.iter().any(|r| r.centre == at(1)));
        assert!(tracker.refusals.iter().any(|r| r.centre == at(0) && r.count == 2));
    }

    fn boxlike(rotation: Mat3, scales: Vec3) -> Superquadric {
        Superquadric { scales, eps: [0.2, 0.2], centre: [0.1, 0.0, 1.5], rotation }
    }

    #[test]
    fn every_equivalent_of_a_box_aligns_back_within_a_degree() {
        let r = linalg::rotation_from_vector([0.3, -0.5, 0.8]);
        let previous = boxlike(r, [0.3, 0.2, 0.1]);
        let noise = linalg::rotation_from_vector([0.004, -0.003, 0.005]); // about 0.4°
        for (k, (re, se)) in equivalents(&r, previous.scales).into_iter().enumerate() {
            let det =
                linalg::dot(linalg::cross(linalg::column(&re, 0), linalg::column(&re, 1)), linalg::column(&re, 2));
            assert!((det - 1.0).abs() < 1e-5, "equivalent {k} is a proper rotation");
            let measured = boxlike(linalg::mat_mul(&re, &noise), se);
            let aligned = align(&previous, &measured);
            let angle = linalg::rotation_angle_between(&previous.rotation, &aligned.rotation).to_degrees();
            assert!(angle <= 1.0, "equivalent {k} aligned to {angle:.3} degrees");
            assert_eq!(aligned.scales, previous.scales, "equivalent {k}: scales permuted back");
            if k > 0 {
                let raw = linalg::rotation_angle_between(&previous.rotation, &measured.rotation).to_degrees();
                assert!(raw > 80.0, "equivalent {k} is a large raw jump ({raw:.1} degrees)");
            }
        }
    }

    #[test]
    fn a_box_measured_with_another_z_axis_aligns_back() {
        let r = linalg::rotation_from_vector([0.3, -0.5, 0.8]);
        let previous = boxlike(r, [0.3, 0.2, 0.1]);
        for k in 1..3 {
            let (rc, sc) = cycle(&r, previous.scales, k);
            let aligned = align(&previous, &boxlike(rc, sc));
            assert!(linalg::rotation_angle_between(&previous.rotation, &aligned.rotation).to_degrees() < 0.1);
            assert_eq!(aligned.scales, previous.scales);
        }
        // A cylinder (ε2 = 1) keeps its axis: the cycled measurement stays cycled.
        let cylinder = Superquadric { eps: [0.2, 1.0], ..previous };
        let (rc, sc) = cycle(&r, previous.scales, 1);
        let aligned = align(&cylinder, &Superquadric { rotation: rc, scales: sc, ..cylinder });
        assert!(linalg::rotation_angle_between(&cylinder.rotation, &aligned.rotation).to_degrees() > 60.0);
    }

    #[test]
    fn smoothing_at_the_bounds_stays_within_them() {
        let params = Params::default();
        let at_bounds = Superquadric {
            scales: [MIN_SCALE, 0.2, 0.3],
            eps: [EPS_RANGE.0, EPS_RANGE.1],
            ..boxlike(linalg::IDENTITY, [0.1; 3])
        };
        let mut state = at_bounds;
        for _ in 0..50 {
            state = smooth(&state, &at_bounds, &params);
            assert!(state.is_within_bounds(), "{state:?}");
        }
    }

    #[test]
    fn tracks_associate_smooth_and_retire() {
        let params = Params { track_max_missed: 2, ..Params::default() };
        let mut storage = [Track::zeroed(); 4];
        let mut tracker = Tracker::new(Bounded::new(&mut storage));
        let r = linalg::rotation_from_vector([0.0, 0.2, 0.0]);
        let base = boxlike(r, [0.3, 0.2, 0.1]);
        tracker.begin_frame(&params);
        let first = tracker.update(&base, 7, &params, true);
        assert!(first.new && first.index == Some(0));
        // Same object, moved 10 cm and measured with x and y swapped: one track, small jump.
        let (rs, ss) = equivalents(&r, base.scales)[5];
        let moved = Superquadric { centre: [0.2, 0.0, 1.5], rotation: rs, scales: ss, ..base };
        tracker.begin_frame(&params);
        let second = tracker.update(&moved, 7, &params, true);
        assert!(!second.new && second.index == Some(0));
        assert!(second.jump_deg < 1.0, "aligned jump {}", second.jump_deg);
        assert!((second.sq.centre[0] - (0.6 * 0.2 + 0.4 * 0.1)).abs() < 1e-6, "centre EMA with alpha_c");
        // Without alignment the same measurement swings the track.
        let mut storage2 = [Track::zeroed(); 4];
        let mut raw = Tracker::new(Bounded::new(&mut storage2));
        raw.begin_frame(&params);
        raw.update(&base, 7, &params, false);
        raw.begin_frame(&params);
        let swung = raw.update(&moved, 7, &params, false);
        assert!(swung.jump_deg > 20.0, "unaligned jump {}", swung.jump_deg);
        // Another label or a far centre starts a new track.
        let far = Superquadric { centre: [1.0, 0.0, 1.5], ..base };
        assert!(tracker.update(&far, 7, &params, true).new);
        assert!(tracker.update(&base, 8, &params, true).new);
        // Unseen for more than track_max_missed frames: retired.
        for _ in 0..4 {
            tracker.begin_frame(&params);
        }
        assert!(tracker.tracks.is_empty());
    }
}
