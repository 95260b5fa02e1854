//! `make bench`: median time per pipeline stage on real frames (../shared/data) and synthetic ones.
//!
//! A plain harness rather than divan/criterion: the stages share the mapper's borrowed pools, so each stage is
//! timed in place inside one pass over a frame, and every frame is processed `REPS` times.
//!
//! Rows with segmenter masks: the core's geometric segmenter (`Mapper::process_segmented`, as `m2smap run
//! --segmenter geometric`) runs before stage 1 and its masks then go through the stages as file masks do. Its
//! masks depend only on the frame, so they are made beforehand by `process_segmented` in the same schedule, and
//! the timed pass runs the stages with them, checked to map the same; the segmenter's own time
//! (`Mapper::segment` alone, timed in the same schedule) is printed below the table. The segmenter and
//! ycbv rows, like `m2smap run`, map with the dataset's poses (superquadric tracks in the world frame); the
//! cabinet and no-mask redkitchen rows keep the camera frame, as before.
//!
//! Cold fits: a pass per dataset forgets every superquadric track right before the superquadric stage, so every
//! object is fitted from its initial guesses; the stage time divided by the objects fitted (accepted + rejected)
//! is the cost of one cold fit.

use std::path::PathBuf;
use std::time::Instant;

use m2smap::dataset::{Camera, Dataset, LoadedFrame, Pose};
use m2smap::masks::{read_frame_masks, FrameMasks, LabelTable, Pixels};
use m2smap::run::{median, SEGMENTER_INSTANCES};
use m2smap::synth::Scene;
use m2smap_core::{FrameReport, HostStorage, Instance, Mapper, McuStorage, Params, Profile, Variant};

const REPS: usize = 3;
const STAGES: [&str; 7] =
    ["points+voxels", "supervoxels", "gaussians", "annotate", "fuse+planes+objects", "superquadrics", "total"];

/// One input frame: the decoded frame, its masks and (for the rows that track in the world frame) its pose.
struct Input {
    frame: LoadedFrame,
    masks: Option<FrameMasks>,
    pose: Option<Pose>,
}

type Frames = Vec<Input>;

/// What one pass over the frames measured, one entry per (frame, repetition).
#[derive(Default)]
struct Timing {
    /// Milliseconds per stage, in [`STAGES`] order.
    times: [Vec<f64>; 7],
    /// Gaussians per frame.
    gaussians: Vec<f64>,
    /// The core's reports.
    reports: Vec<FrameReport>,
}

impl Timing {
    /// Milliseconds of the superquadric stage per object fitted (accepted + rejected), over the entries that
    /// fitted at least one object, and the objects fitted per entry.
    fn per_fit(&self) -> (Vec<f64>, Vec<f64>) {
        let fits: Vec<f64> = self.reports.iter().map(|r| (r.sqs + r.sq_rejected) as f64).collect();
        let per = self.times[5].iter().zip(&fits).filter(|(_, &n)| n > 0.0).map(|(ms, n)| ms / n).collect();
        (per, fits)
    }
}

/// Runs every frame `REPS` times through the stages, timing each. With `cold` every superquadric track is
/// forgotten right before the superquadric stage (every object is fitted from its initial guesses).
fn bench<P: Profile>(storage: &mut P, params: Params, camera: &Camera, frames: &Frames, cold: bool) -> Timing {
    let mut t = Timing::default();
    let mut mapper = Mapper::new(&mut *storage, params).expect("valid parameters");
    for input in frames {
        let view = input.frame.view_posed(camera, input.pose.as_ref());
        let masks = input.masks.as_ref().map(|m| m.view());
        for _ in 0..REPS {
            let t0 = Instant::now();
            let checked = mapper.check(view, masks).expect("valid frame");
            mapper.stage_voxels(&checked);
            let t1 = Instant::now();
            mapper.stage_supervoxels();
            let t2 = Instant::now();
            mapper.stage_gaussians(&checked);
            let t3 = Instant::now();
            mapper.stage_annotate(&checked);
            let t4 = Instant::now();
            mapper.stage_separate(&checked);
            if cold {
                // No track to warm-start from: every superquadric is fitted from its 18 initial guesses.
                mapper.reset_tracks();
            }
            let t5 = Instant::now();
            mapper.stage_superquadrics(&checked);
            let report = *mapper.finish_frame();
            let t6 = Instant::now();
            let spans = [(t0, t1), (t1, t2), (t2, t3), (t3, t4), (t4, t5), (t5, t6), (t0, t6)];
            for (k, (a, b)) in spans.into_iter().enumerate() {
                t.times[k].push((b - a).as_secs_f64() * 1e3);
            }
            t.gaussians.push(report.gaussians as f64);
            t.reports.push(report);
        }
    }
    t
}

/// The frames with the geometric segmenter's masks (`Mapper::process_segmented`, as `m2smap run --segmenter
/// geometric`), each frame run `REPS` times in the schedule of [`bench`]: the masked frames, and per (frame,
/// repetition) the milliseconds of the segmenter alone (`Mapper::segment`) and the report of
/// `process_segmented`.
fn segmenter_frames<P: Profile>(
    storage: &mut P,
    params: Params,
    camera: &Camera,
    frames: &Frames,
) -> (Frames, Vec<f64>, Vec<FrameReport>) {
    let mut labels = LabelTable::default();
    let class = labels.class_of("object");
    let mut instances = vec![Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; SEGMENTER_INSTANCES];
    let mut mapper = Mapper::new(&mut *storage, params).expect("valid parameters");
    let (mut out, mut ms, mut reports) = (Vec::new(), Vec::new(), Vec::new());
    // One id image for every frame, as `m2smap run` keeps one (a fresh one per frame would time the kernel
    // mapping and zeroing its pages on the first call).
    let mut ids: Vec<u16> = Vec::new();
    for input in frames {
        let view = input.frame.view_posed(camera, input.pose.as_ref());
        ids.resize(view.pixels(), 0);
        let mut k = 0;
        for _ in 0..REPS {
            // The segmenter alone first (it leaves the map and tracks as they were), then the whole frame.
            let t0 = Instant::now();
            mapper.segment(view, &mut ids, &mut instances, class).expect("valid frame");
            ms.push(t0.elapsed().as_secs_f64() * 1e3);
            let (report, n) = mapper.process_segmented(view, &mut ids, &mut instances, class).expect("valid frame");
            reports.push(report);
            k = n;
        }
        let masks = FrameMasks {
            width: input.frame.width,
            height: input.frame.height,
            instances: instances[..k].to_vec(),
            pixels: Pixels::Ids(ids.clone()),
        };
        out.push(Input { frame: input.frame.clone(), masks: Some(masks), pose: input.pose });
    }
    (out, ms, reports)
}

/// [`bench`] with the geometric segmenter's masks, which it runs between stages 3 and 4 where no stage hook
/// reaches: the masks are made beforehand ([`segmenter_frames`]; they depend on the frame only) and the stages
/// replayed as `process_segmented` runs them, checked to map the same. Returns the stage timing, the masked
/// frames and the segmenter's own milliseconds per (frame, repetition) (`Mapper::segment` alone).
fn bench_segmented<P: Profile>(
    storage: &mut P,
    params: Params,
    camera: &Camera,
    frames: &Frames,
) -> (Timing, Frames, Vec<f64>) {
    let (masked, seg, reports) = segmenter_frames(&mut *storage, params, camera, frames);
    let t = bench(&mut *storage, params, camera, &masked, false);
    let same = |a: &FrameReport, b: &FrameReport| {
        (a.points, a.gaussians, a.annotated, a.clusters, a.planes, a.objects, a.sqs, a.sq_rejected, a.tracks)
            == (b.points, b.gaussians, b.annotated, b.clusters, b.planes, b.objects, b.sqs, b.sq_rejected, b.tracks)
    };
    let differ = t.reports.iter().zip(&reports).filter(|(a, b)| !same(a, b)).count();
    assert_eq!(differ, 0, "the staged replay maps {differ} frames otherwise than process_segmented");
    (t, masked, seg)
}

/// Prints one table row.
fn row(name: &str, frames: usize, t: &Timing) {
    let cells: Vec<String> = t.times.iter().map(|v| format!("{:.3}", median(v))).collect();
    let points: Vec<f64> = t.reports.iter().map(|r| r.points as f64).collect();
    let ns_per_point: Vec<f64> =
        t.times[6].iter().zip(&points).filter(|(_, &n)| n > 0.0).map(|(ms, n)| ms * 1e6 / n).collect();
    println!(
        "| {name} | {frames} | {} | {:.1} | {:.0} | {:.0} | {:.0} |",
        cells.join(" | "),
        median(&t.gaussians),
        median(&points),
        median(&ns_per_point),
        1e3 / median(&t.times[6])
    );
}

/// The cold-fit line of a dataset (host profile, `full`), from a [`bench`] pass with `cold`.
fn cold_line(name: &str, frames: usize, t: &Timing) -> String {
    let (per, fits) = t.per_fit();
    let per_fit = if per.is_empty() { "–".to_owned() } else { format!("{:.3}", median(&per)) };
    let total: f64 = fits.iter().sum();
    format!("| {name} | {frames} | {total:.0} | {:.1} | {:.3} | {per_fit} |", median(&fits), median(&t.times[5]))
}

/// Loads up to `limit` frames of `../shared/data/name` (evenly spaced) with their masks and poses; `None` when
/// the folder is absent.
fn load(name: &str, limit: usize) -> Option<(Camera, Frames)> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data").join(name);
    if !root.is_dir() {
        return None;
    }
    let d = Dataset::open(&root, None).unwrap_or_else(|e| panic!("{e:#}"));
    let step = (d.frames.len() / limit).max(1);
    let mut labels = LabelTable::default();
    let mut frames = Vec::new();
    for i in (0..d.frames.len()).step_by(step).take(limit) {
        let frame = d.load(i).unwrap_or_else(|e| panic!("{e:#}"));
        let masks = read_frame_masks(&root.join("masks"), &d.frames[i].stem, frame.width, frame.height, &mut labels)
            .unwrap_or_else(|e| panic!("{e:#}"));
        frames.push(Input { frame, masks, pose: d.frames[i].pose });
    }
    Some((d.camera, frames))
}

/// The frames without their poses (tracks in the camera frame).
fn unposed(frames: &Frames) -> Frames {
    frames.iter().map(|f| Input { frame: f.frame.clone(), masks: f.masks.clone(), pose: None }).collect()
}

fn main() {
    let full = Params::default();
    let mmp = Params { variant: Variant::Mmp, ..Params::default() };
    println!("median ms per stage (single thread, release, {REPS} repetitions of each frame)\n");
    println!("| data (profile) | frames | {} | Gaussians | points | ns per point | Hz |", STAGES.join(" | "));
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut host = bytemuck::zeroed_box::<HostStorage>();
    let mut mcu = bytemuck::zeroed_box::<McuStorage>();
    let (mut notes, mut cold, mut skipped) = (Vec::<String>::new(), Vec::<String>::new(), Vec::<String>::new());

    match load("tum_fr3_cabinet", 58) {
        Some((camera, posed)) => {
            let (name, frames) = ("tum_fr3_cabinet", unposed(&posed));
            row(&format!("{name} (host)"), frames.len(), &bench(&mut *host, full, &camera, &frames, false));
            row(&format!("{name} (mcu)"), frames.len(), &bench(&mut *mcu, full, &camera, &frames, false));
            let t = bench(&mut *host, full, &camera, &frames, true);
            row(&format!("{name} (host, cold SQ fits)"), frames.len(), &t);
            cold.push(cold_line(&format!("{name} (file masks)"), frames.len(), &t));
        }
        None => skipped.push("tum_fr3_cabinet".into()),
    }

    match load("7scenes_redkitchen", 60) {
        Some((camera, posed)) => {
            let (name, frames) = ("7scenes_redkitchen", unposed(&posed));
            row(&format!("{name} (host, no masks)"), frames.len(), &bench(&mut *host, full, &camera, &frames, false));
            row(&format!("{name} (mcu, no masks)"), frames.len(), &bench(&mut *mcu, full, &camera, &frames, false));
            // The segmenter's masks, as `m2smap run --segmenter geometric` (which maps with the dataset's poses).
            let (t, masked, _) = bench_segmented(&mut *host, full, &camera, &posed);
            row(&format!("{name} (host, segmenter masks)"), posed.len(), &t);
            let (t, _, seg) = bench_segmented(&mut *host, mmp, &camera, &posed);
            row(&format!("{name} (host, segmenter masks, mmp)"), posed.len(), &t);
            // The segmenter's own time, from the mmp pair.
            let instances = median(
                &masked.iter().map(|f| f.masks.as_ref().map_or(0.0, |m| m.instances.len() as f64)).collect::<Vec<_>>(),
            );
            notes.push(format!(
                "{name}: the geometric segmenter itself takes {:.3} ms per frame more, in neither row's stage columns (`Mapper::segment` alone; median {instances:.0} instances per frame)",
                median(&seg)
            ));
            let t = bench(&mut *host, full, &camera, &masked, true);
            cold.push(cold_line(&format!("{name} (segmenter masks)"), masked.len(), &t));
        }
        None => skipped.push("7scenes_redkitchen".into()),
    }

    match load("ycbv_0000", 10) {
        Some((camera, frames)) => {
            let name = "ycbv_0000";
            row(&format!("{name} (host, gt masks)"), frames.len(), &bench(&mut *host, full, &camera, &frames, false));
            row(
                &format!("{name} (host, gt masks, mmp)"),
                frames.len(),
                &bench(&mut *host, mmp, &camera, &frames, false),
            );
            let t = bench(&mut *host, full, &camera, &frames, true);
            cold.push(cold_line(&format!("{name} (gt masks)"), frames.len(), &t));
        }
        None => skipped.push("ycbv_0000".into()),
    }

    for scene in m2smap::synth::SCENES {
        let s = Scene::named(scene).expect("built-in scene");
        let frames: Frames = (0..10)
            .map(|k| {
                let f = s.render(k, Some(1));
                let masks = s.perfect_masks(&f, &mut LabelTable::default());
                Input { frame: f.frame, masks: Some(masks), pose: None }
            })
            .collect();
        row(&format!("synthetic {scene} (host)"), frames.len(), &bench(&mut *host, full, &s.camera, &frames, false));
        let t = bench(&mut *host, full, &s.camera, &frames, true);
        cold.push(cold_line(&format!("synthetic {scene} (perfect masks)"), frames.len(), &t));
    }

    println!();
    println!(
        "points: the sampled in-range points per frame (median); ns per point: the frame's total over them. \
         Instructions per point are counted where they are deterministic: `make firmware` prints them per stage \
         for the Cortex-M7 (QEMU -icount), and callgrind on the host (docs/pipeline.md)."
    );
    for n in &notes {
        println!("{n}");
    }
    println!("\ncold superquadric fits (host, full; every track forgotten right before the superquadric stage; median ms of the stage per object fitted, accepted or rejected)\n");
    println!(
        "| data (masks) | frames | fits | objects fitted per frame | superquadrics ms per frame | ms per cold fit |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    for c in &cold {
        println!("{c}");
    }
    for name in &skipped {
        println!("\nskipped: ../shared/data/{name} not found, its rows are left out");
        eprintln!("skipped: ../shared/data/{name} not found");
    }
}
