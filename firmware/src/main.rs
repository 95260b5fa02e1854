//! m2smap on a Cortex-M7: the whole pipeline with the `mcu` profile on real 640×480 cabinet frames embedded in
//! the image, superquadric tracks across the frames, the map streamed through the wire encoder into a CRC.
//! Prints, per frame, the map size and CRC (which must equal the host's, `expected.txt`) and the instructions
//! each stage took, counted with QEMU's `-icount shift=0` (one instruction = 1 ns of virtual time) through SysTick.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln};
use m2smap_core::wire::{self, WireError};
use m2smap_core::{Frame, Instance, Intrinsics, MaskPixels, MaskSet, Mapper, McuStorage, Params, Pose};

/// Byte arrays with 4-byte alignment, so raw depth can be viewed as `u16`.
#[repr(C, align(4))]
pub struct Aligned<const N: usize>(pub [u8; N]);

/// One embedded frame.
pub struct FrameData {
    depth: &'static [u8],
    colour: &'static [u8],
    masks: &'static [u8],
    instances: &'static [Instance],
    pose: Option<Pose>,
}

mod frames {
    use super::*;
    include!(concat!(env!("M2SMAP_FRAMES"), "/frames.rs"));
}

/// All pools of the mcu profile; zeroed bytes are a valid empty storage (`bytemuck::Zeroable`), so it lives in .bss.
static mut STORAGE: MaybeUninit<McuStorage> = MaybeUninit::zeroed();

static SYSTICK_WRAPS: AtomicU32 = AtomicU32::new(0);
const RELOAD: u32 = 0x00FF_FFFF;

#[exception]
fn SysTick() {
    SYSTICK_WRAPS.fetch_add(1, Ordering::Relaxed);
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    hprintln!("hard fault at pc {:#010x}", frame.pc());
    debug::exit(debug::EXIT_FAILURE);
    loop {}
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {}
}

/// SysTick ticks since start (24-bit counter extended by the wrap count).
fn ticks() -> u64 {
    loop {
        let wraps = SYSTICK_WRAPS.load(Ordering::Relaxed);
        let current = cortex_m::peripheral::SYST::get_current();
        if SYSTICK_WRAPS.load(Ordering::Relaxed) == wraps {
            return wraps as u64 * (RELOAD as u64 + 1) + (RELOAD - current) as u64;
        }
    }
}

/// Exactly `2 · n` loop instructions (subs + bne).
fn spin(n: u32) {
    // SAFETY: a register-only countdown loop.
    unsafe {
        core::arch::asm!("1:", "subs {0}, {0}, #1", "bne 1b", inout(reg) n => _, options(nomem, nostack));
    }
}

fn fail(what: &str) -> ! {
    hprintln!("error: {}", what);
    debug::exit(debug::EXIT_FAILURE);
    loop {}
}

extern "C" {
    static mut __ebss: u32;
}

const PAINT: u32 = 0x5a5a_a5a5;

/// Fills the unused stack (from the end of .bss up to a little below the current stack pointer) with a pattern.
fn paint_stack() {
    let sp = cortex_m::register::msp::read() as usize;
    // SAFETY: the words between the end of .bss and 256 bytes below the stack pointer belong to no object.
    unsafe {
        let mut p = addr_of_mut!(__ebss) as usize;
        while p + 256 < sp {
            core::ptr::write_volatile(p as *mut u32, PAINT);
            p += 4;
        }
    }
}

/// Deepest stack use so far, bytes below the top of RAM (the first overwritten painted word).
fn stack_high_water() -> usize {
    // SAFETY: reads words that `paint_stack` wrote; stops at the first one the stack overwrote.
    unsafe {
        let start = addr_of_mut!(__ebss) as usize;
        let top = 0x2000_0000usize + 512 * 1024;
        let mut p = start;
        while p < top && core::ptr::read_volatile(p as *const u32) == PAINT {
            p += 4;
        }
        top - p
    }
}

#[entry]
fn main() -> ! {
    paint_stack();
    let Some(mut cp) = cortex_m::Peripherals::take() else { fail("peripherals") };
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(RELOAD);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();
    // The counter reads 0 until its first reload: let it start before anything is measured.
    while cortex_m::peripheral::SYST::get_current() == 0 {
        spin(100);
    }
    // Calibrate: instructions per SysTick tick, from a loop of known length.
    const CAL: u32 = 2_000_000;
    let t0 = ticks();
    spin(CAL);
    let cal_ticks = (ticks() - t0).max(1);
    let per_tick = (2 * CAL as u64) as f64 / cal_ticks as f64;
    hprintln!("calibration: {} instructions in {} ticks ({:.2} per tick)", 2 * CAL, cal_ticks, per_tick);

    // SAFETY: `main` runs once and is the only user of STORAGE; all-zero bytes are a valid McuStorage.
    let storage: &'static mut McuStorage = unsafe { (*addr_of_mut!(STORAGE)).assume_init_mut() };
    let mut mapper = match Mapper::new(storage, Params::default()) {
        Ok(m) => m,
        Err(_) => fail("parameters"),
    };
    let mut scratch = [0u8; wire::MAX_PRIMITIVE_BYTES];
    for (i, f) in frames::FRAMES.iter().enumerate() {
        let Ok(depth) = bytemuck::try_cast_slice::<u8, u16>(f.depth) else { fail("depth alignment") };
        let frame = Frame {
            width: frames::WIDTH,
            height: frames::HEIGHT,
            depth,
            depth_scale: frames::DEPTH_SCALE,
            colour: f.colour,
            intrinsics: frames::INTRINSICS,
            pose: f.pose,
        };
        let masks = MaskSet { width: frames::WIDTH, height: frames::HEIGHT, instances: f.instances, pixels: MaskPixels::BitPlanes(f.masks) };
        let mut t = [0u64; 8];
        t[0] = ticks();
        let checked = match mapper.check(frame, Some(masks)) {
            Ok(c) => c,
            Err(_) => fail("frame rejected"),
        };
        mapper.stage_voxels(&checked);
        t[1] = ticks();
        mapper.stage_supervoxels();
        t[2] = ticks();
        mapper.stage_gaussians(&checked);
        t[3] = ticks();
        mapper.stage_annotate(&checked);
        t[4] = ticks();
        mapper.stage_separate(&checked);
        t[5] = ticks();
        mapper.stage_superquadrics(&checked);
        let report = *mapper.finish_frame();
        t[6] = ticks();
        let mut crc = 0xFFFF_FFFFu32;
        let mut last4 = [0u8; 4];
        let encoded = mapper.encode_map_streaming(&mut scratch, |bytes: &[u8]| -> Result<(), WireError> {
            crc = wire::crc32_update(crc, bytes);
            if bytes.len() == 4 {
                last4.copy_from_slice(bytes);
            }
            Ok(())
        });
        t[7] = ticks();
        let Ok(n) = encoded else { fail("encode") };
        // The digest is the map's own trailer: the CRC-32 of everything before it.
        let digest = u32::from_le_bytes(last4);
        hprintln!("frame {} map {} bytes crc {:08x}", i, n, digest);
        let ins = |a: usize, b: usize| ((t[b] - t[a]) as f64 * per_tick) as u64;
        hprintln!(
            "frame {} instructions total {} voxels {} supervoxels {} gaussians {} annotate {} separate {} superquadrics {} encode {}",
            i, ins(0, 7), ins(0, 1), ins(1, 2), ins(2, 3), ins(3, 4), ins(4, 5), ins(5, 6), ins(6, 7)
        );
        hprintln!(
            "frame {} gaussians {} planes {} sqs {} gmms {} overflow_events {}",
            i, report.gaussians, report.planes, report.sqs, report.gmms, report.overflow_events
        );
    }
    hprintln!("stack high-water {} bytes; static RAM end {:#010x}", stack_high_water(), addr_of_mut!(__ebss) as usize);
    debug::exit(debug::EXIT_SUCCESS);
    loop {}
}
