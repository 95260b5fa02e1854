//! `sqrt` for the m2smap core, correctly rounded (IEEE-754 `squareRoot`), so the same bits on every target.
//!
//! Stable Rust has no square root in `core` (`f32::sqrt` is std's; `core::f32::math::sqrt` is unstable), and
//! `libm` 0.2 has a hardware path only for x86 (`sqrtss`), AArch64 and wasm: on a hard-float Arm core such as the
//! Cortex-M7 its `sqrtf` is a software loop of about 60 instructions per call. With the feature `vsqrt` this
//! crate issues the FPU's `vsqrt.f32` there (one instruction) and calls `libm::sqrtf` everywhere else. Both are
//! the correctly rounded square root, so a map computed on the host and on the firmware stays byte for byte the
//! same. The crate exists so that the one `unsafe` block (inline assembly) stays out of the core, which forbids
//! `unsafe` code.
//!
//! **The feature `vsqrt`** (the core's feature of the same name turns it on; the firmware does) is for an Arm
//! core whose FPU Rust knows as `vfp2` or better, such as a build with `-C target-cpu=cortex-m7`: the assembly's
//! single-precision register class needs it. A plain `thumbv7em-none-eabihf` build (a Cortex-M4F's single-precision
//! FPU) does not have it and fails to compile with the feature on; without the feature it takes `libm::sqrtf`.
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

#[cfg(test)]
mod tests {
    use super::sqrt;

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
