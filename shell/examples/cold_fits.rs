//! The superquadric stage alone, with every track forgotten before it (every object fitted from its initial
//! guesses), on the frames of a dataset: its time, the fits, the median time of the stages before it, and a
//! CRC-32 over every frame's encoded map. A
//! change meant to make the fit cheaper without changing its results must leave the CRC as it was; under
//! `valgrind --tool=callgrind --toggle-collect='*stage_superquadrics*'` it counts the stage's instructions.
//!
//! ```text
//! cargo run --release -p m2smap --example cold_fits -- DATASET FRAMES [MASKS_DIR]
//! ```
//! Environment: `STEP=k` maps every k-th frame; `REPS=r` maps each frame r times in a row (as `make bench`); `WARM=1` keeps the tracks (the stage as `m2smap run` runs it);
//! `MCU=1` maps in the mcu profile (no list of sampled points, no voxel links: the firmware's code paths).
//! Masks come from `DATASET/masks` unless `MASKS_DIR` is given (e.g. `m2smap segment`'s output).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use m2smap::dataset::Dataset;
use m2smap::masks::{read_frame_masks, LabelTable};
use m2smap_core::{HostStorage, Mapper, McuStorage, Params};

fn main() {
    if let Err(e) = run() {
        eprintln!("cold_fits: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(root), Some(limit)) = (args.get(1), args.get(2)) else {
        return Err(anyhow!("usage: cold_fits DATASET FRAMES [MASKS_DIR]"));
    };
    let root = PathBuf::from(root);
    let limit: usize = limit.parse().context("FRAMES must be a number")?;
    let masks_dir = args.get(3).map_or_else(|| root.join("masks"), PathBuf::from);
    let warm = std::env::var("WARM").is_ok();
    let reps: usize = std::env::var("REPS").ok().and_then(|s| s.parse().ok()).unwrap_or(1).max(1);
    let step: usize = std::env::var("STEP").ok().and_then(|s| s.parse().ok()).unwrap_or(1).max(1);
    let d = Dataset::open(&root, None)?;
    let mut labels = LabelTable::default();
    let mut host = bytemuck::zeroed_box::<HostStorage>();
    let mut mcu = bytemuck::zeroed_box::<McuStorage>();
    let mut mapper = if std::env::var("MCU").is_ok() {
        Mapper::new(&mut *mcu, Params::default())
    } else {
        Mapper::new(&mut *host, Params::default())
    }
    .map_err(|e| anyhow!("parameters: {e}"))?;
    let mut buf = vec![0u8; 1 << 20];
    let (mut ms, mut fits, mut sqs, mut crc, mut frames) = (0.0f64, 0u64, 0u64, 0xFFFF_FFFFu32, 0usize);
    let mut before: Vec<f64> = Vec::new();
    for i in (0..d.frames.len()).step_by(step).take(limit).flat_map(|i| std::iter::repeat_n(i, reps)) {
        let frame = d.load(i)?;
        let masks = read_frame_masks(&masks_dir, &d.frames[i].stem, frame.width, frame.height, &mut labels)?;
        let view = frame.view_posed(&d.camera, d.frames[i].pose.as_ref());
        let t0 = Instant::now();
        let checked = mapper.check(view, masks.as_ref().map(|m| m.view())).map_err(|e| anyhow!("frame {i}: {e}"))?;
        mapper.stage_voxels(&checked);
        mapper.stage_supervoxels();
        mapper.stage_gaussians(&checked);
        mapper.stage_annotate(&checked);
        mapper.stage_separate(&checked);
        before.push(t0.elapsed().as_secs_f64() * 1e3);
        if !warm {
            mapper.reset_tracks();
        }
        let t = Instant::now();
        mapper.stage_superquadrics(&checked);
        let report = *mapper.finish_frame();
        ms += t.elapsed().as_secs_f64() * 1e3;
        fits += u64::from(report.sqs + report.sq_rejected);
        sqs += u64::from(report.sqs);
        let n = mapper.encode_map(&mut buf).map_err(|e| anyhow!("frame {i}: {e}"))?;
        crc = m2smap_core::wire::crc32_update(crc, &buf[..n]);
        frames += 1;
    }
    println!(
        "{frames} frames, {fits} fits, {sqs} accepted, superquadric stage {ms:.1} ms ({:.3} ms per fit), the stages \
         before it {:.3} ms per frame (median), maps crc {:08x}",
        ms / fits.max(1) as f64,
        m2smap::run::median(&before),
        !crc
    );
    Ok(())
}
