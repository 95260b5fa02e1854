//! `sqrt` for the m2smap core, correctly rounded (IEEE-754 `squareRoot`), so the same bits on every target;
//! `floor_i32`, ⌊x⌋ as an integer, the same on every target; and `add_to_spread`, one point's share of a
//! Gaussian's second moments and boxes, the same bits on every target.
//!
//! Stable Rust has no square root in `core` (`f32::sqrt` is std's; `core::f32::math::sqrt` is unstable), and
//! `libm` 0.2 has a hardware path only for x86 (`sqrtss`), AArch64 and wasm: on a hard-float Arm core such as the
//! Cortex-M7 its `sqrtf` is a software loop of about 60 instructions per call. With the feature `vsqrt` this
//! crate issues the FPU's `vsqrt.f32` there (one instruction) and calls `libm::sqrtf` everywhere else. Both are
//! the correctly rounded square root, so a map computed on the host and on the firmware stays byte for byte the
//! same. The crate exists so that the `unsafe` blocks (inline assembly) stay out of the core, which forbids
//! `unsafe` code.
//!
//! **The feature `vsqrt`** (the core's feature of the same name turns it on; the firmware does) is for an Arm
//! core whose FPU Rust knows as `vfp2` or better, such as a build with `-C target-cpu=cortex-m7`: the assembly's
//! single-precision register class needs it. A plain `thumbv7em-none-eabihf` build (a Cortex-M4F's single-precision
//! FPU) does not have it and fails to compile with the feature on; without the feature it takes `libm::sqrtf`.
//!
//! **The feature `vcvtm`** (the core's `vcvtm`; the firmware turns it on) takes ⌊x⌋ to an integer by the
//! FPU's `vcvtm.s32.f32`, one instruction (then a move to a core register) instead of a truncation, a
//! conversion back, a compare and a correction. The instruction is FPv5's (Armv8 floating point): a Cortex-M7
//! has it (`-C target-cpu=cortex-m7`), a Cortex-M4F does not, and the build fails with the feature on there.
//! Both ways give the same integer for every f32.
//!
//! **The feature `vldm`** (the core's `vldm`; the firmware turns it on) adds a point to a Gaussian's spread
//! ([`add_to_spread`]: covariance sums about its mean, support box, pixel box; once per sampled point in the
//! Gaussian statistics pass) with load/store multiple (`vldmia`/`vstmia`: one instruction for each array), `vmla`,
//! `vminnm`/`vmaxnm` and, for the pixel box, halfword SIMD (`usub16`/`sel`) on two words: 39 instructions a point
//! against 70, which the compiler gave with a load and a store per value. The arithmetic is the portable path's
//! ([`add_to_spread_portable`]), operation for operation; `make firmware` checks the two bit for bit on the
//! Cortex-M7 over 20 000 points. FPv5 (`vminnm`) and the DSP extension: a Cortex-M7, not a Cortex-M4F.
//! Cortex-M7 cabinet frames 63.3 / 50.2 / 48.0 → 61.8 / 48.7 / 46.6 M, the same maps.
//!
//! Measured (`make firmware`, cabinet frames 0 / 1 / 2): 72.7 / 56.6 / 55.2 M instructions per frame with
//! `libm::sqrtf`, 70.0 / 55.3 / 53.9 M with this one, the same maps.
#![no_std]
#![deny(missing_docs)]

/// √x, f32, correctly rounded; NaN for x < 0 or NaN, +∞ for +∞, and −0 for −0.
#[inline]
pub fn sqrt(x: f32) -> f32 {
    #[cfg(all(feature = "vsqrt", target_arch = "arm"))]
    {
        let root: f32;
        // SAFETY: `vsqrt.f32` reads one single-precision register and writes another; it touches no memory, no
        // stack and no condition flags (an invalid operand sets only the FPSCR's sticky IOC bit, which nothing
        // reads). The feature is only for a core with a VFP unit (see the crate docs), and every VFP version has
        // the instruction.
        unsafe {
            core::arch::asm!(
                "vsqrt.f32 {root}, {x}",
                x = in(sreg) x,
                root = lateout(sreg) root,
                options(pure, nomem, nostack, preserves_flags)
            );
        }
        root
    }
    #[cfg(not(all(feature = "vsqrt", target_arch = "arm")))]
    {
        libm::sqrtf(x)
    }
}

/// ⌊x⌋ as an `i32`: the same value as `libm::floorf(x) as i32` for every f32 (NaN → 0, saturating at the `i32`
/// range).
#[inline]
pub fn floor_i32(x: f32) -> i32 {
    #[cfg(all(feature = "vcvtm", target_arch = "arm"))]
    {
        let floor: i32;
        // SAFETY: `vcvtm.s32.f32` converts one single-precision register to a signed integer, rounding towards
        // −∞, into another (saturating, NaN → 0: the semantics of Rust's `as i32`); `vmov` moves it to a core
        // register. Neither touches memory, the stack or the condition flags (an invalid operand sets only the
        // FPSCR's sticky IOC bit, which nothing reads). The feature is only for a core with an FPv5 (Armv8 FP)
        // unit, such as the Cortex-M7 (see the crate docs).
        unsafe {
            core::arch::asm!(
                "vcvtm.s32.f32 {t}, {x}",
                "vmov {floor}, {t}",
                x = in(sreg) x,
                t = out(sreg) _,
                floor = lateout(reg) floor,
                options(pure, nomem, nostack, preserves_flags)
            );
        }
        floor
    }
    #[cfg(not(all(feature = "vcvtm", target_arch = "arm")))]
    {
        // Truncation differs from the floor only for negative non-integers.
        let t = x as i32;
        if (t as f32) > x {
            t.saturating_sub(1)
        } else {
            t
        }
    }
}

/// The running sums of a point set's spread about a known mean, which [`add_to_spread`] adds one point to: where
/// they live is the caller's (the fields of a Gaussian, say).
#[derive(Debug)]
pub struct SpreadSums<'a> {
    /// Σ d dᵀ over the points so far, d = p − mean, as `[xx, xy, xz, yy, yz, zz]`, m².
    pub covariance: &'a mut [f32; 6],
    /// Minimum corner of the points' axis-aligned box, metres.
    pub bbox_min: &'a mut [f32; 3],
    /// Maximum corner of the points' axis-aligned box, metres.
    pub bbox_max: &'a mut [f32; 3],
    /// The points' pixel box `[u0, v0, u1, v1]`, inclusive, pixels.
    pub pixel_bbox: &'a mut [u16; 4],
}

/// Adds point `p` (metres) seen at pixel (`u`, `v`) to `sums`, the spread about `mean`: each covariance sum
/// gains its product of d = p − mean (the product rounded, then the sum: no fused multiply-add), each box corner
/// takes `f32::min` / `f32::max` with p, and the pixel box takes (`u`, `v`) in. The same bits on every target.
#[inline(always)]
pub fn add_to_spread(sums: SpreadSums<'_>, mean: &[f32; 3], p: [f32; 3], u: u16, v: u16) {
    #[cfg(all(feature = "vldm", target_arch = "arm"))]
    {
        let SpreadSums { covariance, bbox_min, bbox_max, pixel_bbox } = sums;
        // SAFETY: every pointer comes from a reference of its array's length: `vldmia`/`vstmia` read and write
        // exactly those words (f32 arrays are word-aligned); nothing else in memory is touched, nor the stack.
        // `vsub`, `vmla` (not fused: the product is rounded, then added, as Rust's `a + b * c`) and
        // `vminnm`/`vmaxnm` (IEEE-754 minNum/maxNum, which is what `f32::min`/`max` compile to on this core)
        // compute what the portable path does. s0–s8 are clobbered and declared so. The feature is only for a
        // core with an FPv5 unit (`vminnm`), such as the Cortex-M7 (see the crate docs).
        unsafe {
            core::arch::asm!(
                "vldmia {mean}, {{s0-s2}}",
                "vsub.f32 s0, {x}, s0",
                "vsub.f32 s1, {y}, s1",
                "vsub.f32 s2, {z}, s2",
                "vldmia {cov}, {{s3-s8}}",
                "vmla.f32 s3, s0, s0",
                "vmla.f32 s4, s0, s1",
                "vmla.f32 s5, s0, s2",
                "vmla.f32 s6, s1, s1",
                "vmla.f32 s7, s1, s2",
                "vmla.f32 s8, s2, s2",
                "vstmia {cov}, {{s3-s8}}",
                "vldmia {lo}, {{s0-s2}}",
                "vldmia {hi}, {{s3-s5}}",
                "vminnm.f32 s0, s0, {x}",
                "vminnm.f32 s1, s1, {y}",
                "vminnm.f32 s2, s2, {z}",
                "vmaxnm.f32 s3, s3, {x}",
                "vmaxnm.f32 s4, s4, {y}",
                "vmaxnm.f32 s5, s5, {z}",
                "vstmia {lo}, {{s0-s2}}",
                "vstmia {hi}, {{s3-s5}}",
                mean = in(reg) mean.as_ptr(),
                cov = in(reg) covariance.as_mut_ptr(),
                lo = in(reg) bbox_min.as_mut_ptr(),
                hi = in(reg) bbox_max.as_mut_ptr(),
                x = in(sreg) p[0],
                y = in(sreg) p[1],
                z = in(sreg) p[2],
                out("s0") _, out("s1") _, out("s2") _, out("s3") _, out("s4") _,
                out("s5") _, out("s6") _, out("s7") _, out("s8") _,
                options(nostack, preserves_flags)
            );
        }
        add_to_pixel_box(pixel_bbox, u, v);
    }
    #[cfg(not(all(feature = "vldm", target_arch = "arm")))]
    add_to_spread_portable(sums, mean, p, u, v);
}

/// [`add_to_spread`] in plain Rust, whatever the features: the path of every target but the `vldm` one, and the
/// reference its self-check compares with (`make firmware`).
#[inline(always)]
pub fn add_to_spread_portable(sums: SpreadSums<'_>, mean: &[f32; 3], p: [f32; 3], u: u16, v: u16) {
    let SpreadSums { covariance: c, bbox_min, bbox_max, pixel_bbox: b } = sums;
    let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
    c[0] += d[0] * d[0];
    c[1] += d[0] * d[1];
    c[2] += d[0] * d[2];
    c[3] += d[1] * d[1];
    c[4] += d[1] * d[2];
    c[5] += d[2] * d[2];
    for k in 0..3 {
        bbox_min[k] = bbox_min[k].min(p[k]);
        bbox_max[k] = bbox_max[k].max(p[k]);
    }
    b[0] = b[0].min(u);
    b[1] = b[1].min(v);
    b[2] = b[2].max(u);
    b[3] = b[3].max(v);
}

/// The pixel box `[u0, v0, u1, v1]` grown to hold (`u`, `v`), by halfword SIMD.
#[cfg(all(feature = "vldm", target_arch = "arm"))]
#[inline(always)]
fn add_to_pixel_box(b: &mut [u16; 4], u: u16, v: u16) {
    if (b.as_ptr() as usize) % 4 == 0 {
        let uv = u as u32 | (v as u32) << 16;
        // SAFETY: the two words are the array's eight bytes, word-aligned (tested above). `usub16` sets the APSR's
        // GE bits per halfword (declared: no `preserves_flags`) and `sel` picks per halfword by them: the
        // unsigned minimum of (u0, v0) and (u, v), and the maximum of (u1, v1) and (u, v). Nothing else is touched.
        unsafe {
            core::arch::asm!(
                "ldrd {lo}, {hi}, [{b}]",
                "usub16 {t}, {lo}, {uv}",
                "sel {lo}, {uv}, {lo}",
                "usub16 {t}, {uv}, {hi}",
                "sel {hi}, {uv}, {hi}",
                "strd {lo}, {hi}, [{b}]",
                b = in(reg) b.as_mut_ptr(),
                uv = in(reg) uv,
                lo = out(reg) _,
                hi = out(reg) _,
                t = out(reg) _,
                options(nostack)
            );
        }
        return;
    }
    b[0] = b[0].min(u);
    b[1] = b[1].min(v);
    b[2] = b[2].max(u);
    b[3] = b[3].max(v);
}

#[cfg(test)]
mod tests {
    use super::{floor_i32, sqrt};

    /// The host's path against libm over the edge cases and a sweep of bit patterns. The firmware's path is
    /// checked the same way on the Cortex-M7 by `make firmware` (its floor self-check), and end to end by its
    /// maps, which must equal the host's byte for byte.
    #[test]
    fn floor_i32_matches_libm() {
        let special = [0.0, -0.0, 0.5, -0.5, -1.0, -1.5, 2.9e9, -2.9e9, -2_147_483_648.0, f32::NAN, f32::INFINITY];
        let strided = (0..=u32::MAX).step_by(4099).map(f32::from_bits);
        for x in special.into_iter().chain(strided).chain([f32::NEG_INFINITY, f32::MIN, f32::MAX]) {
            assert_eq!(floor_i32(x), libm::floorf(x) as i32, "{x:e}");
        }
    }

    /// The host's path against the correctly rounded f64 root (exact for every f32 after rounding), over a
    /// sweep of bit patterns and the edge cases. The firmware's path is checked end to end by `make firmware`,
    /// whose maps must equal the host's byte for byte.
    #[test]
    fn sqrt_is_correctly_rounded() {
        let mut bits = 0u32;
        while bits < 0x7f80_0000 {
            let x = f32::from_bits(bits);
            assert_eq!(sqrt(x).to_bits(), ((x as f64).sqrt() as f32).to_bits(), "x = {x:e}");
            bits += 0x1f3d;
        }
        assert_eq!(sqrt(0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(sqrt(-0.0).to_bits(), (-0.0f32).to_bits());
        assert_eq!(sqrt(f32::INFINITY), f32::INFINITY);
        assert!(sqrt(-1.0).is_nan() && sqrt(f32::NAN).is_nan() && sqrt(f32::NEG_INFINITY).is_nan());
        assert_eq!(sqrt(4.0), 2.0);
    }
}
