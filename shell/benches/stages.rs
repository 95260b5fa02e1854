//! `make bench`: median time per pipeline stage on real frames (../shared/data) and synthetic ones.
//!
//! A plain harness rather than divan/criterion: the stages share the mapper's borrowed pools, so each stage is
//! timed in place inside one pass over a frame, and every frame is processed `REPS` times.

use std::path::PathBuf;
use std::time::Instant;

use m2smap::dataset::{Camera, Dataset, LoadedFrame};
use m2smap::masks::{read_frame_masks, FrameMasks, LabelTable};
use m2smap::run::median;
use m2smap::synth::Scene;
use m2smap_core::{HostStorage, Mapper, McuStorage, Params, Profile};

const REPS: usize = 3;
const STAGES: [&str; 7] =
    ["points+voxels", "supervoxels", "gaussians", "annotate", "fuse+planes+objects", "superquadrics", "total"];

type Frames = Vec<(LoadedFrame, Option<FrameMasks>)>;

fn bench<P: Profile>(name: &str, storage: &mut P, camera: &Camera, frames: &Frames, cold: bool) {
    let mut times: [Vec<f64>; 7] = Default::default();
    let mut gaussians = Vec::new();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).expect("default parameters");
    for (frame, masks) in frames {
        for _ in 0..REPS {
            if cold {
                // No track to warm-start from: every superquadric is fitted from its 18 initial guesses.
                mapper.reset_tracks();
            }
            let t0 = Instant::now();
            let checked = mapper.check(frame.view(camera), masks.as_ref().map(|m| m.view())).expect("valid frame");
            mapper.stage_voxels(&checked);
            let t1 = Instant::now();
            mapper.stage_supervoxels();
            let t2 = Instant::now();
            mapper.stage_gaussians(&checked);
            let t3 = Instant::now();
            mapper.stage_annotate(&checked);
            let t4 = Instant::now();
            mapper.stage_separate(&checked);
            let t5 = Instant::now();
            mapper.stage_superquadrics(&checked);
            let report = *mapper.finish_frame();
            let t6 = Instant::now();
            let spans = [(t0, t1), (t1, t2), (t2, t3), (t3, t4), (t4, t5), (t5, t6), (t0, t6)];
            for (k, (a, b)) in spans.into_iter().enumerate() {
                times[k].push((b - a).as_secs_f64() * 1e3);
            }
            gaussians.push(report.gaussians as f64);
        }
    }
    let cells: Vec<String> = times.iter().map(|t| format!("{:.3}", median(t))).collect();
    println!(
        "| {name} | {} | {} | {:.1} | {:.0} |",
        frames.len(),
        cells.join(" | "),
        median(&gaussians),
        1e3 / median(&times[6])
    );
}

fn load(name: &str, limit: usize) -> Option<(Camera, Frames)> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data").join(name);
    let d = Dataset::open(&root, None).ok()?;
    let step = (d.frames.len() / limit).max(1);
    let mut labels = LabelTable::default();
    let mut frames = Vec::new();
    for i in (0..d.frames.len()).step_by(step).take(limit) {
        let f = d.load(i).ok()?;
        let masks = read_frame_masks(&root.join("masks"), &d.frames[i].stem, f.width, f.height, &mut labels).ok()?;
        frames.push((f, masks));
    }
    Some((d.camera, frames))
}

fn main() {
    println!("median ms per stage (single thread, release, {REPS} repetitions of each frame)\n");
    println!("| data (profile) | frames | {} | Gaussians | Hz |", STAGES.join(" | "));
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut host = bytemuck::zeroed_box::<HostStorage>();
    let mut mcu = bytemuck::zeroed_box::<McuStorage>();
    for (name, limit) in [("tum_fr3_cabinet", 58), ("7scenes_redkitchen", 60)] {
        match load(name, limit) {
            Some((camera, frames)) => {
                bench(&format!("{name} (host)"), &mut *host, &camera, &frames, false);
                bench(&format!("{name} (mcu)"), &mut *mcu, &camera, &frames, false);
                if name == "tum_fr3_cabinet" {
                    bench(&format!("{name} (host, cold SQ fits)"), &mut *host, &camera, &frames, true);
                }
            }
            None => eprintln!("skipped: ../shared/data/{name} not found"),
        }
    }
    for scene in m2smap::synth::SCENES {
        let s = Scene::named(scene).expect("built-in scene");
        let frames: Frames = (0..10)
            .map(|k| {
                let f = s.render(k, Some(1));
                let masks = s.perfect_masks(&f, &mut LabelTable::default());
                (f.frame, Some(masks))
            })
            .collect();
        bench(&format!("synthetic {scene} (host)"), &mut *host, &s.camera, &frames, false);
    }
}
