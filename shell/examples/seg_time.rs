//! The geometric segmenter alone (`Mapper::segment`) on the frames of a dataset: the median milliseconds of a
//! call and a CRC over every frame's masks (`segment::digest`). A change meant to make the segmenter faster
//! without changing its masks must leave the CRC as it was; under
//! `valgrind --tool=callgrind --toggle-collect='*segment*segment*'` (with `REPS=1`) it counts its instructions.
//!
//! ```text
//! cargo run --release -p m2smap --example seg_time -- DATASET FRAMES
//! ```
//! The frames are spread evenly over the dataset; `REPS=r` segments each r times in a row (default 5). `COLD=1`
//! writes a 64 MB buffer before each call, so the call finds the frame and its working memory out of the caches
//! (as `make bench` does, where the rest of the pipeline runs between two calls).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use m2smap::dataset::Dataset;
use m2smap::run::{median, SEGMENTER_INSTANCES};
use m2smap_core::{HostStorage, Instance, Mapper, Params};

fn main() {
    if let Err(e) = run() {
        eprintln!("seg_time: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(root), Some(limit)) = (args.get(1), args.get(2)) else {
        return Err(anyhow!("usage: seg_time DATASET FRAMES"));
    };
    let limit: usize = limit.parse().context("FRAMES must be a number")?;
    let reps: usize = std::env::var("REPS").ok().and_then(|s| s.parse().ok()).unwrap_or(5).max(1);
    let d = Dataset::open(&PathBuf::from(root), None)?;
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).map_err(|e| anyhow!("parameters: {e}"))?;
    let mut evict = if std::env::var("COLD").is_ok_and(|v| v == "1") { vec![0u8; 64 << 20] } else { Vec::new() };
    let mut instances = vec![Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; SEGMENTER_INSTANCES];
    let (mut ms, mut crc) = (Vec::new(), 0u32);
    let step = (d.frames.len() / limit.max(1)).max(1);
    for i in (0..d.frames.len()).step_by(step).take(limit) {
        let frame = d.load(i)?;
        let view = frame.view_posed(&d.camera, d.frames[i].pose.as_ref());
        let mut ids = vec![0u16; view.pixels()];
        let mut found = 0;
        for rep in 0..reps {
            for (k, x) in evict.iter_mut().enumerate().step_by(64) {
                *x = x.wrapping_add((k + rep) as u8);
            }
            let t0 = Instant::now();
            let stats = mapper.segment(view, &mut ids, &mut instances, 1).map_err(|e| anyhow!("frame {i}: {e}"))?;
            ms.push(t0.elapsed().as_secs_f64() * 1e3);
            found = stats.instances as usize;
        }
        crc = crc.rotate_left(5) ^ m2smap_core::segment::digest(&ids, &instances[..found]);
    }
    println!("{} frames × {reps}: median {:.3} ms per frame, masks crc {crc:08x}", ms.len() / reps, median(&ms));
    Ok(())
}
