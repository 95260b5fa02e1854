//! m2smap on a Cortex-M7: the whole pipeline with the `mcu` profile on real 640×480 cabinet frames embedded in
//! the image, superquadric tracks across the frames, the map streamed through the wire encoder (its trailer is
//! the map's CRC-32).
//! Prints, per frame, the map size and CRC (which must equal the host's, `expected.txt`) and the instructions
//! each stage took, counted with QEMU's `-icount shift=0` (one instruction = 1 ns of virtual time) through SysTick.
//!
//! Every line goes out through defmt (`defmt-semihosting`: defmt frames on semihosting stdout, since RTT cannot be
//! read under QEMU). The map lines go the same way: they are one size-and-CRC line per frame, not bulk bytes, and
//! plain semihosting text on the same stdout would corrupt the defmt stream. `make firmware` decodes the stream with
//! `firmware/defmt-decode` (the `defmt-decoder` library that `defmt-print` is built on) against this ELF.
//!
//! The global allocator is a 1 KiB `embedded-alloc` heap that counts every alloc and realloc. The image reads the
//! count before and after each frame's pipeline (what `Mapper::process` runs, stage by stage, plus the map
//! encoding), prints `heap allocations during process: N` and exits with failure unless N is 0.
#![no_std]
#![no_main]

extern crate alloc;

use core::alloc::{GlobalAlloc, Layout};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicBool, AtomicU32, AtomicUsize, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::debug;
use defmt_semihosting as _;
use embedded_alloc::LlffHeap;
use m2smap_core::segment::SEGMENTER_INSTANCES;
use m2smap_core::wire::{self, WireError};
use m2smap_core::world::{McuWorld, WorldMap};
use m2smap_core::{
    Frame, FrameError, FrameReport, Instance, Intrinsics, Mapper, MaskPixels, MaskSet, McuStorage, Params, Pose,
};

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
/// The world map's pools (`McuWorld`), zeroed = empty, in `.bss` beside the mapper's.
static mut WORLD: MaybeUninit<McuWorld> = MaybeUninit::zeroed();

/// Pixels of an embedded frame.
const PIXELS: usize = frames::WIDTH as usize * frames::HEIGHT as usize;
/// The geometric segmenter's id image (one u16 per pixel, also its working memory) and instances: frame-sized
/// output buffers in PSRAM beside the embedded frames (like the camera's frames, outside the 512 KiB budget).
#[link_section = ".frames.segment"]
static mut SEGMENT_IDS: [u16; PIXELS] = [0; PIXELS];
#[link_section = ".frames.segment"]
static mut SEGMENT_INSTANCES: [Instance; SEGMENTER_INSTANCES] =
    [Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; SEGMENTER_INSTANCES];

/// Heap bytes. The core is `no_std` without `alloc`; this heap makes that observable: anything linked into the
/// image that allocates (the core, a dependency, a future change) goes through the counting allocator below and
/// fails `make firmware`. 1 KiB in .bss, inside the 512 KiB RAM budget (the counter's self-test uses 4 bytes of it).
const HEAP_BYTES: usize = 1024;
static mut HEAP_MEM: [MaybeUninit<u8>; HEAP_BYTES] = [MaybeUninit::uninit(); HEAP_BYTES];

/// `embedded-alloc`'s linked-list heap, counting every allocation and reallocation.
struct CountingHeap {
    heap: LlffHeap,
    allocations: AtomicUsize,
}

impl CountingHeap {
    /// Allocations and reallocations so far.
    fn allocations(&self) -> usize {
        self.allocations.load(Ordering::SeqCst)
    }
}

// SAFETY: every call is forwarded to `LlffHeap`, a sound global allocator; the counter only counts.
unsafe impl GlobalAlloc for CountingHeap {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        self.allocations.fetch_add(1, Ordering::SeqCst);
        // SAFETY: forwarded with the caller's guarantees.
        unsafe { self.heap.alloc(layout) }
    }

    // `alloc_zeroed` keeps its default, which calls `alloc` above: counted once.

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded with the caller's guarantees.
        unsafe { self.heap.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        self.allocations.fetch_add(1, Ordering::SeqCst);
        // SAFETY: forwarded with the caller's guarantees.
        unsafe { self.heap.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: CountingHeap = CountingHeap { heap: LlffHeap::empty(), allocations: AtomicUsize::new(0) };

static SYSTICK_WRAPS: AtomicU32 = AtomicU32::new(0);
const RELOAD: u32 = 0x00FF_FFFF;

#[exception]
fn SysTick() {
    SYSTICK_WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// Set by the first fault or panic: a second one (say, inside the defmt logger) exits without logging.
static FAILING: AtomicBool = AtomicBool::new(false);

fn exit_failure() -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    if !FAILING.swap(true, Ordering::SeqCst) {
        defmt::error!("hard fault at pc {=u32:#010x}", frame.pc());
    }
    exit_failure()
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    if !FAILING.swap(true, Ordering::SeqCst) {
        defmt::error!("panic: {}", defmt::Display2Format(info));
    }
    exit_failure()
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

/// The core's floor to an integer (the FPU's `vcvtm.s32.f32` here, feature `vcvtm`) against libm's software
/// `floorf` over the edge cases and every 4099th bit pattern, as the host's test of the other path
/// (`fpu/src/lib.rs`): the maps would show a difference only where a point falls on a voxel's face.
fn check_floor() {
    let special = [0.0, -0.0, 0.5, -0.5, -1.0, -1.5, 2.9e9, -2.9e9, -2_147_483_648.0, f32::NAN, f32::INFINITY];
    let strided = (0..=u32::MAX).step_by(4099).map(f32::from_bits);
    let mut checked = 0u32;
    for x in special.into_iter().chain(strided).chain([f32::NEG_INFINITY, f32::MIN, f32::MAX]) {
        let x = core::hint::black_box(x);
        if m2smap_core::linalg::floor_i32(x) != libm::floorf(x) as i32 {
            defmt::error!("floor of {=u32:#010x}", x.to_bits());
            fail("the core's floor differs from libm's");
        }
        checked += 1;
    }
    defmt::println!("floor self-check: the core's floor equals libm's on {=u32} values", checked);
}

/// The core's per-point spread update (load/store multiple here, feature `vldm`) against the portable path
/// compiled for this core, bit for bit, over random points, means and sums mixed with edge values (±0, equal
/// coordinates, tiny and huge magnitudes, the pixel range's ends): the maps would show a difference only in
/// some Gaussian's covariance or box.
fn check_spread() {
    const EDGES: [f32; 8] = [0.0, -0.0, 1.0, -1.0, 1.0e-30, -3.0e30, 0.5, 2.75];
    let mut state = 0x9e37_79b9u32;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state
    };
    let value = |next: &mut dyn FnMut() -> u32| {
        let r = next();
        match r % 4 {
            0 => EDGES.get((r >> 8) as usize % EDGES.len()).copied().unwrap_or(0.0),
            _ => ((r >> 2) as i32 as f32) * 1.0e-9,
        }
    };
    let mut checked = 0u32;
    for _ in 0..20_000 {
        let mut f = || value(&mut next);
        let mean = [f(), f(), f()];
        let p = [f(), f(), f()];
        let covariance = [f(), f(), f(), f(), f(), f()];
        let bbox_min = [f(), f(), f()];
        let bbox_max = [f(), f(), f()];
        let r = next();
        let (u, v) = ((r & 0xffff) as u16, (r >> 16) as u16);
        let r = next();
        let pixel_bbox = [(r & 0xffff) as u16, (r >> 16) as u16, u16::MAX - (r & 0xff) as u16, (r & 0x7fff) as u16];
        let mut a = (covariance, bbox_min, bbox_max, pixel_bbox);
        let mut b = a;
        fn sums(s: &mut ([f32; 6], [f32; 3], [f32; 3], [u16; 4])) -> m2smap_fpu::SpreadSums<'_> {
            let (covariance, bbox_min, bbox_max, pixel_bbox) = s;
            m2smap_fpu::SpreadSums { covariance, bbox_min, bbox_max, pixel_bbox }
        }
        m2smap_fpu::add_to_spread(sums(&mut a), core::hint::black_box(&mean), core::hint::black_box(p), u, v);
        m2smap_fpu::add_to_spread_portable(sums(&mut b), &mean, p, u, v);
        let bits = |s: &([f32; 6], [f32; 3], [f32; 3], [u16; 4])| {
            (s.0.map(f32::to_bits), s.1.map(f32::to_bits), s.2.map(f32::to_bits), s.3)
        };
        if bits(&a) != bits(&b) {
            defmt::error!("spread of point {=[?]} mean {=[?]}", p.map(f32::to_bits), mean.map(f32::to_bits));
            fail("the core's spread update differs from the portable one");
        }
        checked += 1;
    }
    defmt::println!("spread self-check: the core's spread update equals the portable one on {=u32} points", checked);
}

fn fail(what: &str) -> ! {
    defmt::error!("error: {=str}", what);
    exit_failure()
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

/// Logs one frame's lines. Not inlined: the log calls stay out of `main`, where the pipeline is inlined, so how
/// the image logs does not change the code that is measured.
#[inline(never)]
fn log_frame(
    i: usize,
    per_tick: f64,
    t: &[u64; 8],
    encoded: Result<usize, WireError>,
    last4: [u8; 4],
    report: &FrameReport,
) {
    let n = match encoded {
        Ok(n) => n,
        Err(e) => {
            defmt::error!("frame {} encode: {}", i, defmt::Debug2Format(&e));
            exit_failure()
        }
    };
    // The digest is the map's own trailer: the CRC-32 of everything before it.
    let digest = u32::from_le_bytes(last4);
    defmt::println!("frame {=usize} map {=usize} bytes crc {=u32:08x}", i, n, digest);
    let ins = |a: usize, b: usize| ((t[b] - t[a]) as f64 * per_tick) as u64;
    defmt::println!(
        "frame {=usize} instructions total {=u64} voxels {=u64} supervoxels {=u64} gaussians {=u64} annotate {=u64} separate {=u64} superquadrics {=u64} encode {=u64}",
        i, ins(0, 7), ins(0, 1), ins(1, 2), ins(2, 3), ins(3, 4), ins(4, 5), ins(5, 6), ins(6, 7)
    );
    // Per sampled point (the pixels that pass the range filter and the 15 % sample): the cost of the passes over
    // them, comparable across frames and datasets of different sizes.
    let points = u64::from(report.points.max(1));
    defmt::println!(
        "frame {=usize} instructions per point total {=u64} voxels {=u64} supervoxels {=u64} gaussians {=u64} annotate {=u64} separate {=u64} ({=u32} points)",
        i,
        ins(0, 7) / points,
        ins(0, 1) / points,
        ins(1, 2) / points,
        ins(2, 3) / points,
        ins(3, 4) / points,
        ins(4, 5) / points,
        report.points
    );
    defmt::println!(
        "frame {=usize} gaussians {=u32} planes {=u32} sqs {=u32} gmms {=u32} overflow_events {=u32}",
        i,
        report.gaussians,
        report.planes,
        report.sqs,
        report.gmms,
        report.overflow_events
    );
    // The whole report through the core's `defmt::Format` derive (feature `defmt`).
    defmt::println!("frame {=usize} report {}", i, report);
}

/// [`Mapper::segment`] in a frame of its own: inlined into `main`, the segmenter's stack tables would stay
/// reserved in `main`'s frame under every later stage (and overflow the stack reserve under the superquadric fit).
#[inline(never)]
fn run_segmenter(
    mapper: &mut Mapper<'_>,
    frame: Frame<'_>,
    ids: &mut [u16],
    instances: &mut [Instance],
) -> Result<m2smap_core::segment::SegmentStats, FrameError> {
    mapper.segment(frame, ids, instances, 0)
}

#[cold]
#[inline(never)]
fn frame_rejected(i: usize, e: FrameError) -> ! {
    defmt::error!("frame {} rejected: {}", i, e);
    exit_failure()
}

#[entry]
fn main() -> ! {
    paint_stack();
    // SAFETY: called once, before any allocation; HEAP_MEM is used by nothing else.
    unsafe { ALLOCATOR.heap.init(addr_of_mut!(HEAP_MEM) as usize, HEAP_BYTES) };
    // The instrument must count: one allocation outside the frames has to move the counter by exactly one.
    let before = ALLOCATOR.allocations();
    let probe = core::hint::black_box(alloc::boxed::Box::new(core::hint::black_box(0x5a5a_u32)));
    drop(probe);
    if ALLOCATOR.allocations() != before + 1 {
        fail("the counting allocator did not count a Box allocation");
    }
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
    let centi = (per_tick * 100.0 + 0.5) as u32;
    defmt::println!(
        "calibration: {=u32} instructions in {=u64} ticks ({=u32}.{=u32:02} per tick)",
        2 * CAL,
        cal_ticks,
        centi / 100,
        centi % 100
    );

    check_floor();
    check_spread();

    // SAFETY: `main` runs once and is the only user of STORAGE; all-zero bytes are a valid McuStorage.
    let storage: &'static mut McuStorage = unsafe { (*addr_of_mut!(STORAGE)).assume_init_mut() };
    let mut mapper = match Mapper::new(storage, Params::default()) {
        Ok(m) => m,
        Err(e) => {
            defmt::error!("parameters rejected: {}", e);
            exit_failure()
        }
    };
    // SAFETY: `main` runs once and is the only user of WORLD; all-zero bytes are a valid McuWorld.
    let world_storage: &'static mut McuWorld = unsafe { (*addr_of_mut!(WORLD)).assume_init_mut() };
    let mut world = WorldMap::new(world_storage);
    // SAFETY: `main` runs once and is the only user of the segmenter's buffers.
    let (segment_ids, segment_instances) =
        unsafe { (&mut *addr_of_mut!(SEGMENT_IDS), &mut *addr_of_mut!(SEGMENT_INSTANCES)) };
    let mut scratch = [0u8; wire::MAX_PRIMITIVE_BYTES];
    let mut allocations_in_process = 0usize;
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
        let masks = MaskSet {
            width: frames::WIDTH,
            height: frames::HEIGHT,
            instances: f.instances,
            pixels: MaskPixels::BitPlanes(f.masks),
        };
        // What `Mapper::process` runs, stage by stage, then the map encoding: SysTick read at each stage boundary,
        // the allocation count read before and after all of it (outside the timed window).
        let mut t = [0u64; 8];
        let allocs_before = ALLOCATOR.allocations();
        t[0] = ticks();
        let checked = match mapper.check(frame, Some(masks)) {
            Ok(c) => c,
            Err(e) => frame_rejected(i, e),
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
        // The encoder ends the map with its CRC-32 (the core's one CRC); its last write is those four bytes.
        let mut last4 = [0u8; 4];
        let encoded = mapper.encode_map_streaming(&mut scratch, |bytes: &[u8]| -> Result<(), WireError> {
            if bytes.len() == 4 {
                last4.copy_from_slice(bytes);
            }
            Ok(())
        });
        t[7] = ticks();
        allocations_in_process += ALLOCATOR.allocations() - allocs_before;
        log_frame(i, per_tick, &t, encoded, last4, &report);
        // The world map: this frame fused in, and the delta a radio link would carry (its trailer is its CRC).
        let Some(pose) = f.pose else { fail("a frame without a pose: the world map needs one") };
        let allocs_before = ALLOCATOR.allocations();
        let t0 = ticks();
        if let Err(e) = world.integrate(i as u32, &pose, mapper.params(), |sink| mapper.for_each_world_primitive(sink))
        {
            defmt::error!("frame {} world map: {}", i, defmt::Debug2Format(&e));
            exit_failure()
        }
        let mut last4 = [0u8; 4];
        let mut delta_scratch = [0u8; 32];
        let delta = world.encode_delta_streaming(&mut delta_scratch, |bytes: &[u8]| -> Result<(), WireError> {
            if bytes.len() == 4 {
                last4.copy_from_slice(bytes);
            }
            Ok(())
        });
        let instructions = ((ticks() - t0) as f64 * per_tick) as u64;
        allocations_in_process += ALLOCATOR.allocations() - allocs_before;
        match delta {
            Ok(n) => defmt::println!(
                "frame {=usize} world delta {=usize} bytes crc {=u32:08x}",
                i,
                n,
                u32::from_le_bytes(last4)
            ),
            Err(e) => {
                defmt::error!("frame {} world delta: {}", i, defmt::Debug2Format(&e));
                exit_failure()
            }
        }
        defmt::println!("frame {=usize} world instructions {=u64}", i, instructions);
        // The geometric segmenter on the same frame (what `--segmenter geometric` runs before mapping), with the
        // mapper's scratch: its instructions, and a digest of its id image and instances that must equal the
        // host's ([`m2smap_core::segment::digest`]).
        let allocs_before = ALLOCATOR.allocations();
        let t0 = ticks();
        let stats = match run_segmenter(&mut mapper, frame, segment_ids, segment_instances) {
            Ok(s) => s,
            Err(e) => frame_rejected(i, e),
        };
        let instructions = ((ticks() - t0) as f64 * per_tick) as u64;
        allocations_in_process += ALLOCATOR.allocations() - allocs_before;
        let found = segment_instances.get(..stats.instances as usize).unwrap_or(&[]);
        let crc = m2smap_core::segment::digest(segment_ids, found);
        defmt::println!("frame {=usize} segment {=u32} instances crc {=u32:08x}", i, stats.instances, crc);
        defmt::println!("frame {=usize} segment instructions {=u64}", i, instructions);
    }
    defmt::println!("heap allocations during process: {=usize}", allocations_in_process);
    defmt::println!(
        "stack high-water {=usize} bytes; static RAM end {=usize:#010x} (heap {=usize} bytes)",
        stack_high_water(),
        addr_of_mut!(__ebss) as usize,
        HEAP_BYTES
    );
    if allocations_in_process != 0 {
        fail("the core allocated on the heap during process");
    }
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
