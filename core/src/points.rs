//! Stage 1: the observed point set P — depth range filter and the seeded 15 % sample (paper §VI).
//!
//! The sample is a pure function of (pixel index, frame counter, seed): a pixel is kept when a 32-bit hash of
//! its sample index falls below `sample_rate × 2³²`. The sample index is the pixel index plus an offset drawn
//! from the frame counter ([`Params::sample_frame`]), wrapped into the frame's pixels, so every frame keeps other
//! pixels (the paper's "randomly sampled"; [`Params::sample_per_frame`]) and the first frame's offset is 0. No
//! state is kept, so any later stage can visit exactly the same points again by re-reading the caller's depth
//! buffer, and the result is the same on every machine. For the default seed and rate the sample of a frame of
//! up to 640 × 480 pixels is also a table of bits made at compile time ([`SAMPLE_TABLE_PIXELS`]), which the
//! Cortex-M7's passes read from the frame's offset on instead of hashing each pixel; the host hashes 32 pixels
//! at a time in vector registers.

use crate::frame::Frame;
use crate::linalg::Vec3;
use crate::params::{Params, DEFAULT_SAMPLE_RATE, DEFAULT_SAMPLE_SEED};

/// One sampled point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// Pixel column, pixels.
    pub u: u16,
    /// Pixel row, pixels.
    pub v: u16,
    /// Camera-frame position, metres.
    pub xyz: Vec3,
    /// Colour from the registered RGB image (`[0, 0, 0]` from [`for_each_position_in`]).
    pub rgb: [u8; 3],
}

impl Point {
    /// The point of pixel (u, v) with raw depth `raw` and colour `rgb` (its three bytes): back-projected with
    /// the frame's intrinsics. Every pass over the points builds them here, so they are the same bits each time.
    #[inline]
    pub fn from_pixel(frame: &Frame<'_>, u: usize, v: usize, raw: u16, rgb: &[u8]) -> Point {
        let z = frame.metres(raw);
        Point {
            u: u as u16,
            v: v as u16,
            xyz: frame.intrinsics.unproject(u as f32, v as f32, z),
            rgb: [
                rgb.first().copied().unwrap_or(0),
                rgb.get(1).copied().unwrap_or(0),
                rgb.get(2).copied().unwrap_or(0),
            ],
        }
    }
}

/// The 32-bit mixing function of the sampler ("lowbias32", a bijection with good avalanche).
#[inline]
pub const fn mix32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// Hash threshold for a sample rate: a pixel is kept when `mix32(..) < threshold` (as u64).
#[inline]
pub const fn sample_threshold(rate: f32) -> u64 {
    let t = rate as f64 * 4_294_967_296.0;
    if t <= 0.0 {
        0
    } else if t >= 4_294_967_296.0 {
        1 << 32
    } else {
        t as u64
    }
}

/// Whether sample index `i` is in the sample for `seed` and `threshold` (a frame's pixel index `i` is sample
/// index `i` when its offset is 0: the first frame, or without [`Params::sample_per_frame`]).
#[inline]
pub fn is_sampled(i: u32, seed: u32, threshold: u64) -> bool {
    Sampler::with(seed, threshold).keeps(i)
}

/// Pixels per block of the per-pixel loop: the keep test of a block is computed branch-free into a bit mask,
/// then only its set bits are visited.
const BLOCK: usize = 32;

/// Whether the per-pixel loop hashes blocks ([`Walk::Blocks`]): a win where the test vectorises (x86-64,
/// AArch64). Elsewhere (the Cortex-M7) the default sample is read from [`DEFAULT_SAMPLE`] ([`Walk::Table`]) and
/// another goes a pixel at a time, hashing only pixels with a valid depth ([`Walk::Pixels`]).
const BLOCKWISE: bool = cfg!(any(target_arch = "x86_64", target_arch = "aarch64"));

/// Bit j of a block mask.
#[allow(clippy::indexing_slicing)] // evaluated at compile time: an out-of-range index would fail the build
const BLOCK_BITS: [u32; BLOCK] = {
    let mut bits = [0u32; BLOCK];
    let mut j = 0;
    while j < BLOCK {
        bits[j] = 1 << j;
        j += 1;
    }
    bits
};

/// The sampling predicate for one seed and threshold, with the seed mixed once and 32-bit compares only (the
/// per-pixel loop vectorises them), and one frame's offset of the sample index.
#[derive(Debug, Clone, Copy)]
struct Sampler {
    mixed_seed: u32,
    /// The threshold when it fits 32 bits, else `u32::MAX` with `all` set.
    below: u32,
    /// The threshold is 2³²: every pixel is kept.
    all: bool,
    /// Added to a pixel index to give its sample index, below `pixels`.
    offset: u32,
    /// Pixels of the frame: sample indices wrap at it.
    pixels: u32,
}

impl Sampler {
    /// The sample of `seed` and `threshold` without an offset (sample index = pixel index).
    const fn with(seed: u32, threshold: u64) -> Self {
        let all = threshold > u32::MAX as u64;
        let below = if all { u32::MAX } else { threshold as u32 };
        Sampler { mixed_seed: mix32(seed), below, all, offset: 0, pixels: u32::MAX }
    }

    /// The sample `params` draw for `frame`: the offset is 32 · (`mix32(sample_frame)` mod ⌊pixels / 32⌋) (0 for
    /// the first frame, since `mix32(0) = 0`), or 0 without [`Params::sample_per_frame`]. A multiple of 32, so that
    /// a row starting on a table word (640 pixels wide) reads each block's bits in one load.
    fn of_frame(frame: &Frame<'_>, params: &Params) -> Self {
        let pixels = frame.pixels().min(u32::MAX as usize / 2) as u32;
        let words = (pixels / 32).max(1);
        let offset = if params.sample_per_frame { mix32(params.sample_frame) % words * 32 } else { 0 };
        Sampler { offset, pixels, ..Sampler::with(params.sample_seed, sample_threshold(params.sample_rate)) }
    }

    /// The sample index of pixel index `i` (below `pixels`): `i + offset`, wrapped into `0..pixels`.
    #[inline]
    fn index(&self, i: u32) -> u32 {
        self.wrap(i.wrapping_add(self.offset))
    }

    /// `s` wrapped into `0..pixels`, for `s < 2 · pixels` (branch-free, so that a block's loop vectorises).
    #[inline(always)]
    fn wrap(&self, s: u32) -> u32 {
        s - if s >= self.pixels { self.pixels } else { 0 }
    }

    /// Whether sample index `s` is kept: `mix32(s ^ mix32(seed)) < threshold`.
    #[inline]
    const fn keeps(&self, s: u32) -> bool {
        (mix32(s ^ self.mixed_seed) < self.below) | self.all
    }

    /// Whether every sample index of the frame lies in [`DEFAULT_SAMPLE`] and this is its sample.
    fn in_table(&self) -> bool {
        self.is_default() && self.pixels as usize <= SAMPLE_TABLE_PIXELS
    }

    /// The keep bits of the 32 sample indices from `s` (below `pixels`), wrapping at `pixels`, from
    /// [`DEFAULT_SAMPLE`] ([`Sampler::in_table`]).
    #[inline]
    fn table_word(&self, s: u32) -> u32 {
        let word = default_sample_word(s as usize).unwrap_or(0);
        let left = self.pixels.saturating_sub(s);
        if left >= 32 {
            return word;
        }
        let wrapped = default_sample_word(0).unwrap_or(0);
        (word & ((1u32 << left) - 1)) | (wrapped << (left & 31))
    }

    /// Whether this is the sampler of the default seed and rate, whose sample [`DEFAULT_SAMPLE`] holds.
    fn is_default(&self) -> bool {
        let d = DEFAULT_SAMPLER;
        (self.mixed_seed, self.below, self.all) == (d.mixed_seed, d.below, d.all)
    }
}

/// The sampler of [`DEFAULT_SAMPLE_SEED`] and [`DEFAULT_SAMPLE_RATE`].
const DEFAULT_SAMPLER: Sampler = Sampler::with(DEFAULT_SAMPLE_SEED, sample_threshold(DEFAULT_SAMPLE_RATE));

/// Pixel indices whose default sample is read from a table of bits made at compile time (on the Cortex-M7): the
/// whole of a 640 × 480 frame, or of any frame of as many pixels or fewer (the sample is keyed by pixel index).
pub const SAMPLE_TABLE_PIXELS: usize = 640 * 480;

/// Words of [`DEFAULT_SAMPLE`]: one more than the pixels fill, so that the 32 indices from any pixel index
/// below [`SAMPLE_TABLE_PIXELS`] lie in it.
const SAMPLE_TABLE_WORDS: usize = SAMPLE_TABLE_PIXELS / 32 + 1;

/// The default sample ([`DEFAULT_SAMPLER`]) of the first [`SAMPLE_TABLE_WORDS`] × 32 pixel indices, made at
/// compile time: bit j of word k says whether pixel index 32k + j is kept. 38 404 bytes of read-only data (flash
/// on the Cortex-M7, not RAM). A pass over the pixels then reads one word per 32 pixels and visits only the
/// kept ones, instead of hashing every pixel with a valid depth.
#[allow(long_running_const_eval)] // 307 232 hashes at compile time
static DEFAULT_SAMPLE: [u32; SAMPLE_TABLE_WORDS] = default_sample();

/// [`DEFAULT_SAMPLE`]'s contents.
#[allow(clippy::indexing_slicing)] // evaluated at compile time: an out-of-range index would fail the build
const fn default_sample() -> [u32; SAMPLE_TABLE_WORDS] {
    let mut table = [0u32; SAMPLE_TABLE_WORDS];
    let mut k = 0;
    while k < table.len() {
        let mut j = 0;
        while j < 32 {
            if DEFAULT_SAMPLER.keeps((32 * k + j) as u32) {
                table[k] |= 1 << j;
            }
            j += 1;
        }
        k += 1;
    }
    table
}

/// The default sample of pixel indices `base..base + 32` as the bits of a word (bit j: `base + j`), when they
/// all lie in [`DEFAULT_SAMPLE`].
#[inline]
fn default_sample_word(base: usize) -> Option<u32> {
    let (k, shift) = (base / 32, base % 32);
    let low = *DEFAULT_SAMPLE.get(k)?;
    if shift == 0 {
        return Some(low);
    }
    Some((low >> shift) | (*DEFAULT_SAMPLE.get(k + 1)? << (32 - shift)))
}

/// Calls `f` for every sampled, in-range point of `frame`, in pixel order. The frame must have been validated.
pub fn for_each_point(frame: &Frame<'_>, params: &Params, f: impl FnMut(&Point)) {
    for_each_point_in(frame, params, PixelWindow::WHOLE, f);
}

/// An inclusive rectangle of pixels: columns `u0..=u1`, rows `v0..=v1` (clipped to the image when used).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelWindow {
    /// First column, pixels.
    pub u0: u16,
    /// First row, pixels.
    pub v0: u16,
    /// Last column, pixels.
    pub u1: u16,
    /// Last row, pixels.
    pub v1: u16,
}

impl PixelWindow {
    /// Every pixel of any image.
    pub const WHOLE: PixelWindow = PixelWindow { u0: 0, v0: 0, u1: u16::MAX, v1: u16::MAX };
    /// No pixel.
    pub const EMPTY: PixelWindow = PixelWindow { u0: u16::MAX, v0: u16::MAX, u1: 0, v1: 0 };

    /// The window of a `[u_min, v_min, u_max, v_max]` box (as kept by Gaussians and objects).
    pub fn from_box(b: [u16; 4]) -> Self {
        let [u0, v0, u1, v1] = b;
        PixelWindow { u0, v0, u1, v1 }
    }

    /// The smallest window holding both.
    pub fn union(self, o: PixelWindow) -> Self {
        PixelWindow { u0: self.u0.min(o.u0), v0: self.v0.min(o.v0), u1: self.u1.max(o.u1), v1: self.v1.max(o.v1) }
    }
}

/// [`for_each_point`] restricted to the pixels of `window`: exactly the points of the whole-image pass that fall
/// inside it, in the same order (the sample is keyed by pixel index).
pub fn for_each_point_in(frame: &Frame<'_>, params: &Params, window: PixelWindow, f: impl FnMut(&Point)) {
    walk_window::<true>(frame, params, window, f);
}

/// [`for_each_point_in`] without the colours: every point's `rgb` is `[0, 0, 0]`. For the passes after
/// voxelisation, which keeps the colours in the voxels (the Cortex-M7 saves the colour's load per point).
pub fn for_each_position_in(frame: &Frame<'_>, params: &Params, window: PixelWindow, f: impl FnMut(&Point)) {
    walk_window::<false>(frame, params, window, f);
}

/// [`for_each_point_in`]; `COLOUR`: read each point's colour.
#[inline(always)]
fn walk_window<const COLOUR: bool>(frame: &Frame<'_>, params: &Params, window: PixelWindow, f: impl FnMut(&Point)) {
    let sampler = Sampler::of_frame(frame, params);
    // Where the keep test vectorises, hashing every pixel is as cheap as the table (measured: the table was
    // 1–3 % slower on the host); elsewhere (the Cortex-M7) the table of the default sample saves the hash of
    // every pixel with a valid depth (about 15 M instructions per cabinet frame).
    let walk = if BLOCKWISE {
        Walk::Blocks
    } else if sampler.in_table() {
        Walk::Table
    } else {
        Walk::Pixels
    };
    walk_points::<COLOUR>(frame, params, window, sampler, walk, f);
}

/// How a pass finds the kept pixels of a row: the same pixels, in the same order, each way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Walk {
    /// The keep test of [`BLOCK`] pixels at a time computed without a branch into a bit mask, then its set bits.
    Blocks,
    /// The keep bits of [`BLOCK`] pixels at a time read from [`DEFAULT_SAMPLE`] (the default sample only), then
    /// the range test of the kept pixels; a frame the table does not cover ([`Sampler::in_table`]) goes
    /// [`Walk::Pixels`].
    Table,
    /// A branch per pixel: the range test, then the hash of a pixel in range.
    Pixels,
}

/// [`for_each_point_in`] with the pixels found by `walk`; `sampler` is the sample of `params`; `COLOUR`: read
/// the colours (else `[0, 0, 0]`).
#[inline(always)]
fn walk_points<const COLOUR: bool>(
    frame: &Frame<'_>,
    params: &Params,
    window: PixelWindow,
    sampler: Sampler,
    walk: Walk,
    mut f: impl FnMut(&Point),
) {
    let (lo, hi) = frame.raw_range(params);
    let w = frame.width as usize;
    let (u0, u1) = (window.u0 as usize, (window.u1 as usize).min(w.saturating_sub(1)));
    if w == 0 || u0 > u1 {
        return;
    }
    let rgb_rows = frame.colour.chunks_exact(w * 3);
    let rows = frame.depth.chunks_exact(w).zip(rgb_rows).enumerate();
    let first_row = window.v0 as usize;
    let n_rows = (window.v1 as usize + 1).saturating_sub(first_row);
    let walk = if walk == Walk::Table && !sampler.in_table() { Walk::Pixels } else { walk };
    for (v, (row, rgb_row)) in rows.skip(first_row).take(n_rows) {
        let span = row.get(u0..=u1).unwrap_or(&[]);
        // Each way gives a block's keep bits; one loop visits them, so that `f` is inlined at one place only
        // (at two, the Cortex-M7 called it per point: about 20 instructions a point for its entry and exit).
        for (b, block) in span.chunks(BLOCK).enumerate() {
            let first = u0 + b * BLOCK;
            let base = sampler.index((v * w + first) as u32);
            let mut mask = match walk {
                // The table's bits are the sample's alone: the depth is tested below.
                Walk::Table => sampler.table_word(base) & (u32::MAX >> (BLOCK - block.len())),
                // Only the block where the sample indices reach the frame's pixel count wraps them (one per
                // frame at most): the others keep the loop without the wrap (1 M fewer instructions per pass).
                Walk::Blocks if base.saturating_add(BLOCK as u32) > sampler.pixels => {
                    block_mask(block, (lo, hi), |j| sampler.keeps(sampler.wrap(base + j)))
                }
                Walk::Blocks => block_mask(block, (lo, hi), |j| sampler.keeps(base + j)),
                Walk::Pixels => {
                    let mut mask = 0u32;
                    for ((&raw, &bit), j) in block.iter().zip(&BLOCK_BITS).zip(0u32..) {
                        if raw >= lo && raw <= hi && sampler.keeps(sampler.wrap(base + j)) {
                            mask |= bit;
                        }
                    }
                    mask
                }
            };
            while mask != 0 {
                let j = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                // The depth test of the table's bits, which the other ways have made: the blockwise way (where
                // it is the only one, a constant) skips it; telling the others apart per point cost the Cortex-M7
                // more than testing again.
                let tested = BLOCKWISE && walk == Walk::Blocks;
                if tested || block.get(j).is_some_and(|&raw| raw >= lo && raw <= hi) {
                    emit_point::<COLOUR>(frame, row, rgb_row, first + j, v, &mut f);
                }
            }
        }
    }
}

/// The keep bits of `block` (at most [`BLOCK`] raw depths): bit j is set when depth j lies in `lo..=hi` and
/// `keeps(j)`. Branch-free, so that the loop vectorises.
#[inline(always)]
fn block_mask(block: &[u16], (lo, hi): (u16, u16), keeps: impl Fn(u32) -> bool) -> u32 {
    let mut mask = 0u32;
    for ((&raw, &bit), j) in block.iter().zip(&BLOCK_BITS).zip(0u32..) {
        let keep = (raw >= lo) & (raw <= hi) & keeps(j);
        mask |= bit & (keep as u32).wrapping_neg();
    }
    mask
}

/// The point of pixel `u` of row `v` (`row`, `rgb_row` its depths and colours) to `f`. Inlined into the one
/// loop of [`walk_points`], so that `f` is inlined there (as a closure called from several places, it was one
/// function called per point on the Cortex-M7).
#[inline(always)]
fn emit_point<const COLOUR: bool>(
    frame: &Frame<'_>,
    row: &[u16],
    rgb_row: &[u8],
    u: usize,
    v: usize,
    f: &mut impl FnMut(&Point),
) {
    let Some(&raw) = row.get(u) else { return };
    let rgb: &[u8] = if COLOUR {
        let Some(rgb) = rgb_row.get(3 * u..3 * u + 3) else { return };
        rgb
    } else {
        &[]
    };
    f(&Point::from_pixel(frame, u, v, raw, rgb));
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;

    /// A `w × h` frame of millimetre depths without a pose.
    fn test_frame<'a>(
        (w, h): (usize, usize),
        depth: &'a [u16],
        colour: &'a [u8],
        intrinsics: crate::frame::Intrinsics,
    ) -> Frame<'a> {
        Frame { width: w as u16, height: h as u16, depth, depth_scale: 1000.0, colour, intrinsics, pose: None }
    }

    #[test]
    fn sample_rate_is_respected_and_deterministic() {
        let t = sample_threshold(0.15);
        let kept = (0..307_200u32).filter(|&i| is_sampled(i, 7, t)).count();
        let rate = kept as f64 / 307_200.0;
        assert!((rate - 0.15).abs() < 0.003, "rate {rate}");
        let again = (0..307_200u32).filter(|&i| is_sampled(i, 7, t)).count();
        assert_eq!(kept, again);
        let other_seed = (0..1000u32).filter(|&i| is_sampled(i, 7, t) != is_sampled(i, 8, t)).count();
        assert!(other_seed > 100, "seed must change the sample");
        assert_eq!((0..1000u32).filter(|&i| is_sampled(i, 1, sample_threshold(1.0))).count(), 1000);
        for rate in [0.0, 0.15, 0.999_999_9, 1.0] {
            let t = sample_threshold(rate);
            let by_u64 = |i: u32| (mix32(i ^ mix32(7)) as u64) < t;
            assert!((0..100_000u32).chain([u32::MAX]).all(|i| is_sampled(i, 7, t) == by_u64(i)), "rate {rate}");
        }
    }

    /// A window's pass gives exactly the whole-image pass's points that fall inside it, in the same order, for
    /// windows inside the image, on its edges, reaching past it and empty; the whole window is the whole pass.
    #[test]
    fn windowed_pass_is_the_whole_pass_cut_to_the_window() {
        const W: usize = 70;
        const H: usize = 23;
        let mut depth = [0u16; W * H];
        for (i, d) in depth.iter_mut().enumerate() {
            // Depths 0.5–2.9 m with holes and out-of-range values in between.
            *d = match i % 11 {
                3 => 0,
                7 => 9000,
                k => 500 + (i as u16 % 97) * 20 + k as u16,
            };
        }
        let colour = [7u8; W * H * 3];
        let frame =
            test_frame((W, H), &depth, &colour, crate::frame::Intrinsics { fx: 60.0, fy: 60.0, cx: 35.0, cy: 11.0 });
        let params = Params { sample_rate: 0.4, ..Params::default() };
        let mut all = [(0u16, 0u16); W * H];
        let mut n_all = 0;
        for_each_point(&frame, &params, |p| {
            if let Some(slot) = all.get_mut(n_all) {
                *slot = (p.u, p.v);
                n_all += 1;
            }
        });
        assert!(n_all > 200 && n_all < W * H / 2, "{n_all} points");
        let windows = [
            PixelWindow { u0: 5, v0: 2, u1: 40, v1: 17 },
            PixelWindow { u0: 0, v0: 0, u1: 69, v1: 0 },
            PixelWindow { u0: 33, v0: 20, u1: 500, v1: 900 },
            PixelWindow { u0: 64, v0: 3, u1: 69, v1: 22 },
            PixelWindow::EMPTY,
            PixelWindow::WHOLE,
        ];
        for window in windows {
            let inside = |&&(u, v): &&(u16, u16)| u >= window.u0 && u <= window.u1 && v >= window.v0 && v <= window.v1;
            let mut expected = all.iter().take(n_all).filter(inside);
            let mut n = 0;
            for_each_point_in(&frame, &params, window, |p| {
                assert_eq!(expected.next(), Some(&(p.u, p.v)), "{window:?}");
                n += 1;
            });
            assert_eq!(expected.next(), None, "{window:?}: the window's pass stopped early after {n} points");
        }
    }

    #[test]
    fn the_default_sample_table_is_the_hash() {
        let d = Params::default();
        assert!(Sampler::with(d.sample_seed, sample_threshold(d.sample_rate)).is_default());
        assert!(!Sampler::with(d.sample_seed ^ 1, sample_threshold(d.sample_rate)).is_default());
        assert!(!Sampler::with(d.sample_seed, sample_threshold(0.2)).is_default());
        let t = sample_threshold(DEFAULT_SAMPLE_RATE);
        let mut kept = 0;
        for k in 0..SAMPLE_TABLE_WORDS {
            let word = DEFAULT_SAMPLE.get(k).copied().unwrap_or(0);
            for j in 0..32 {
                let i = (32 * k + j) as u32;
                assert_eq!(word >> j & 1 == 1, is_sampled(i, DEFAULT_SAMPLE_SEED, t), "pixel index {i}");
                kept += (word >> j & 1) as usize;
            }
            // Any 32 indices from one in the table, as a word.
            for shift in [0, 1, 17, 31] {
                let base = 32 * k + shift;
                let expected = (0..32)
                    .fold(0u32, |m, j| m | u32::from(is_sampled((base + j) as u32, DEFAULT_SAMPLE_SEED, t)) << j);
                let read = default_sample_word(base);
                if base < SAMPLE_TABLE_PIXELS {
                    assert_eq!(read, Some(expected), "from index {base}");
                } else if let Some(word) = read {
                    assert_eq!(word, expected, "from index {base}");
                }
            }
        }
        let rate = kept as f64 / (32 * SAMPLE_TABLE_WORDS) as f64;
        assert!((rate - 0.15).abs() < 0.003, "rate {rate}");
    }

    /// A `w × h` frame's depths (millimetres) with holes and out-of-range values.
    fn patterned_depth(w: usize, h: usize) -> std::vec::Vec<u16> {
        (0..w * h)
            .map(|i| match (i * 7 + i / w) % 13 {
                3 | 4 => 0,
                7 => 9000,
                k => 500 + (i % 97) as u16 * 20 + k as u16,
            })
            .collect()
    }

    /// The three ways of finding the kept pixels give the same points in the same order, with the default sample
    /// and another, for the first frame and later ones (other offsets), over windows of a frame larger than the
    /// table (the table's walk goes pixel by pixel there) and of one smaller (whose sample indices wrap at its
    /// own pixel count, inside the table).
    #[test]
    fn every_walk_visits_the_same_points() {
        for (w, h) in [(643usize, 481usize), (600, 397)] {
            let depth = patterned_depth(w, h);
            let colour = std::vec![9u8; w * h * 3];
            let frame = test_frame(
                (w, h),
                &depth,
                &colour,
                crate::frame::Intrinsics { fx: 500.0, fy: 500.0, cx: 321.0, cy: 240.0 },
            );
            every_walk_visits_the_same_points_of(&frame);
        }
    }

    fn every_walk_visits_the_same_points_of(frame: &Frame<'_>) {
        use std::vec::Vec;
        let (w, h) = (frame.width, frame.height);
        let windows = [
            PixelWindow::WHOLE,
            PixelWindow { u0: 5, v0: 2, u1: 40, v1: 17 },
            PixelWindow { u0: 31, v0: h - 11, u1: w - 1, v1: h - 1 },
            PixelWindow { u0: w - 43, v0: h - 5, u1: 700, v1: 900 },
            PixelWindow { u0: 0, v0: h - 4, u1: 0, v1: h - 4 },
            PixelWindow::EMPTY,
        ];
        let seeds = [Params::default().sample_seed, 7];
        for (seed, sample_frame) in seeds.into_iter().flat_map(|s| [(s, 0), (s, 1), (s, 57)]) {
            let params = Params { sample_seed: seed, sample_frame, ..Params::default() };
            let sampler = Sampler::of_frame(frame, &params);
            assert_eq!(sampler.offset == 0, sample_frame == 0);
            let walks: &[Walk] = if sampler.is_default() {
                &[Walk::Blocks, Walk::Table, Walk::Pixels]
            } else {
                &[Walk::Blocks, Walk::Pixels]
            };
            for window in windows {
                let points = |walk: Walk| {
                    let mut out = Vec::new();
                    walk_points::<true>(frame, &params, window, sampler, walk, |p| {
                        out.push((p.u, p.v, p.xyz.map(f32::to_bits)))
                    });
                    out
                };
                let blocks = points(Walk::Blocks);
                // Without the colours: the same points, each with rgb [0, 0, 0].
                let mut positions = Vec::new();
                for_each_position_in(frame, &params, window, |p| {
                    assert_eq!(p.rgb, [0; 3]);
                    positions.push((p.u, p.v, p.xyz.map(f32::to_bits)));
                });
                assert_eq!(positions, blocks, "positions over {window:?}");
                if window == PixelWindow::WHOLE {
                    assert!(blocks.len() > 25_000, "{} points", blocks.len());
                }
                for &walk in walks {
                    assert_eq!(points(walk), blocks, "{walk:?} over {window:?}, seed {seed}, frame {sample_frame}");
                }
            }
        }
    }

    /// Frame f keeps pixel i exactly when the hash keeps sample index (i + 32 · (mix32(f) mod ⌊pixels / 32⌋)) mod
    /// pixels: the first frame's sample is the fixed one, each later frame keeps other pixels at the same rate, and without
    /// `sample_per_frame` every frame keeps the first frame's.
    #[test]
    fn each_frame_draws_its_own_sample() {
        use std::vec::Vec;
        let (w, h) = (160usize, 90usize);
        let depth = std::vec![1500u16; w * h];
        let colour = std::vec![0u8; w * h * 3];
        let frame =
            test_frame((w, h), &depth, &colour, crate::frame::Intrinsics { fx: 100.0, fy: 100.0, cx: 80.0, cy: 45.0 });
        let kept = |params: &Params| {
            let mut out = Vec::new();
            for_each_point(&frame, params, |p| out.push(p.v as usize * w + p.u as usize));
            out
        };
        let t = sample_threshold(DEFAULT_SAMPLE_RATE);
        let fixed: Vec<usize> = (0..w * h).filter(|&i| is_sampled(i as u32, DEFAULT_SAMPLE_SEED, t)).collect();
        assert_eq!(kept(&Params::default()), fixed);
        let mut samples = Vec::new();
        for f in [1u32, 2, 3, 1000] {
            let params = Params { sample_frame: f, ..Params::default() };
            let offset = mix32(f) as usize % (w * h / 32) * 32;
            let expected: Vec<usize> =
                (0..w * h).filter(|&i| is_sampled(((i + offset) % (w * h)) as u32, DEFAULT_SAMPLE_SEED, t)).collect();
            let got = kept(&params);
            assert_eq!(got, expected, "frame {f}");
            let rate = got.len() as f64 / (w * h) as f64;
            assert!((rate - 0.15).abs() < 0.01, "frame {f}: rate {rate}");
            let shared = got.iter().filter(|i| fixed.binary_search(i).is_ok()).count();
            // Independent 15 % samples share about 15 % of their pixels.
            assert!(shared * 4 < got.len(), "frame {f}: {shared} of {} pixels as the first frame's", got.len());
            assert_eq!(kept(&Params { sample_per_frame: false, ..params }), fixed);
            samples.push(got);
        }
        assert!(samples.windows(2).all(|p| p.first() != p.get(1)));
    }
}
