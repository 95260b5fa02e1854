//! The geometric segmenter against ground truth: synthetic objects that stand apart, and the cabinet masks.

mod common;

use m2smap::eval::semantic_metrics;
use m2smap::synth::Scene;
use m2smap_core::{Frame, HostStorage, Instance, Intrinsics, Mapper, Params};

fn iou(a: &[u16], ida: u16, b: &[u16], idb: u16) -> f64 {
    let (mut inter, mut union) = (0u32, 0u32);
    for (&x, &y) in a.iter().zip(b) {
        let (p, q) = (x == ida, y == idb);
        inter += (p && q) as u32;
        union += (p || q) as u32;
    }
    if union == 0 {
        0.0
    } else {
        inter as f64 / union as f64
    }
}

/// Best IoU of each ground-truth object (≥ 300 visible pixels) against the predicted instances, and how many
/// predictions match some object with IoU ≥ 0.5.
fn score(gt: &[u16], pred: &[u16], instances: &[Instance]) -> (Vec<f64>, usize) {
    let mut ids: Vec<u16> = gt.iter().copied().filter(|&i| i != 0).collect();
    ids.sort_unstable();
    ids.dedup();
    let visible: Vec<u16> = ids.into_iter().filter(|&id| gt.iter().filter(|&&g| g == id).count() >= 300).collect();
    let best: Vec<f64> =
        visible.iter().map(|&g| instances.iter().map(|i| iou(gt, g, pred, i.id)).fold(0.0, f64::max)).collect();
    let matched = instances.iter().filter(|i| visible.iter().any(|&g| iou(gt, g, pred, i.id) >= 0.5)).count();
    (best, matched)
}

#[test]
fn finds_objects_that_stand_apart_and_keeps_them_unglued() {
    let scene = Scene::named("tabletop").unwrap();
    let (mut ious, mut predicted, mut matched) = (Vec::new(), 0usize, 0usize);
    for k in [0usize, 3, 6, 9] {
        let frame = scene.render(k, Some(5));
        let gt = scene.instance_image(&frame);
        let mut storage = bytemuck::zeroed_box::<HostStorage>();
        let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
        let mut ids = vec![0u16; gt.len()];
        let mut instances = [Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; 16];
        let view = frame.frame.view(&scene.camera);
        let (report, n) = mapper.process_segmented(view, &mut ids, &mut instances, 0).unwrap();
        // The segmented boxes are fitted: their points are found again after segmentation (the voxels of a
        // segmented frame are not split by mask).
        assert!(report.sqs >= 1, "frame {k}: no superquadric from segmenter masks");
        let (best, m) = score(&gt, &ids, &instances[..n]);
        predicted += n;
        matched += m;
        ious.extend(best);
        // The pipeline annotated with these masks never glues the two boxes to each other or to the floor.
        let masks = m2smap_core::MaskSet {
            width: 640,
            height: 480,
            instances: &instances[..n],
            pixels: m2smap_core::MaskPixels::IdImage(&ids),
        };
        let checked = mapper.check(view, Some(masks)).unwrap();
        let metrics = semantic_metrics(&mapper, &checked, |u, v| gt[v as usize * 640 + u as usize]);
        assert_eq!(metrics.n_adh, 0, "frame {k}: adhesion with segmenter masks");
        assert!(metrics.multi_gaussian_clusters > 0, "frame {k}: the metrics found no points");
    }
    let recall = ious.iter().filter(|&&x| x >= 0.7).count() as f64 / ious.len() as f64;
    let precision = matched as f64 / predicted.max(1) as f64;
    let mean_iou = ious.iter().sum::<f64>() / ious.len() as f64;
    println!(
        "tabletop: {} objects, recall@0.7 {recall:.2}, precision@0.5 {precision:.2}, mean IoU {mean_iou:.3}",
        ious.len()
    );
    assert!(recall >= 0.9, "segmenter recall {recall:.2} at IoU 0.7");
    assert!(precision >= 0.9, "segmenter precision {precision:.2}");
}

/// Cells whose centre pixel is a depth hole (an object's edge, a rim) have no point of their own; each takes the
/// instance of the neighbouring cell on whose surface it lies, so the objects' masks keep those cells' pixels:
/// with a hole punched at the centre pixel of every cell on an object's outline, the objects' mean IoU stays
/// within 0.02 of the unpunched frame's (measured: 0.940 with 194 such cells, 97 of them adopted, against 0.936;
/// without the adoption 0.897 against 0.932).
#[test]
fn cells_with_a_hole_at_their_centre_keep_their_objects_pixels() {
    let scene = Scene::named("tabletop").unwrap();
    let mut frame = scene.render(2, Some(5));
    let gt = scene.instance_image(&frame);
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let mut segment = |frame: &m2smap::synth::SynthFrame| {
        let mut ids = vec![0u16; gt.len()];
        let mut instances = [Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; 16];
        let stats = mapper.segment(frame.frame.view(&scene.camera), &mut ids, &mut instances, 0).unwrap();
        let (best, _) = score(&gt, &ids, &instances[..stats.instances as usize]);
        (best.iter().sum::<f64>() / best.len().max(1) as f64, stats.holed_cells_adopted)
    };
    let (plain, _) = segment(&frame);
    // 640 × 480 frames are segmented in cells of 4 × 4 pixels; a cell's centre pixel is (4x + 2, 4y + 2). Every
    // cell on an object's outline (its block holds pixels of two ground-truth ids) loses its centre's depth.
    let mut punched = 0;
    for y in 0..120 {
        for x in 0..160 {
            let block = (0..16).map(|k| gt[(4 * y + k / 4) * 640 + 4 * x + k % 4]);
            let first = gt[4 * y * 640 + 4 * x];
            if block.clone().any(|id| id != first) && block.clone().any(|id| id != 0) {
                frame.frame.depth[(4 * y + 2) * 640 + 4 * x + 2] = 0;
                punched += 1;
            }
        }
    }
    let (holed, adopted) = segment(&frame);
    println!(
        "tabletop frame 2: mean IoU {plain:.3}, {holed:.3} with {punched} outline cells holed ({adopted} adopted)"
    );
    assert!(plain >= 0.9, "mean IoU {plain:.3} without holes");
    assert!(adopted >= punched / 4, "{adopted} of {punched} holed cells took an instance");
    assert!(holed >= plain - 0.02, "mean IoU {holed:.3} with holes, {plain:.3} without");
}

#[test]
fn segments_the_cabinet_like_its_masks() {
    let Some(data) = common::shared_data("tum_fr3_cabinet") else { return };
    let d = m2smap::dataset::Dataset::open(&data, None).unwrap();
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let mut labels = m2smap::masks::LabelTable::default();
    let mut ious = Vec::new();
    for k in (0..d.frames.len()).step_by(4) {
        let frame = d.load(k).unwrap();
        let masks = m2smap::masks::read_frame_masks(&data.join("masks"), &d.frames[k].stem, 640, 480, &mut labels)
            .unwrap()
            .unwrap();
        let reference: Vec<u16> =
            (0..480u16).flat_map(|v| (0..640u16).map(move |u| (u, v))).map(|(u, v)| masks.id_at(u, v)).collect();
        let mut ids = vec![0u16; reference.len()];
        let mut instances = [Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; 16];
        let (_, n) = mapper.process_segmented(frame.view(&d.camera), &mut ids, &mut instances, 0).unwrap();
        ious.push(instances[..n].iter().map(|i| iou(&reference, 1, &ids, i.id)).fold(0.0, f64::max));
    }
    let mean = ious.iter().sum::<f64>() / ious.len() as f64;
    let good = ious.iter().filter(|&&x| x >= 0.7).count();
    println!("cabinet: mean IoU {mean:.3} against the masks, {good} of {} frames at IoU >= 0.7", ious.len());
    assert!(mean >= 0.6, "the segmenter should find the cabinet: mean IoU {mean:.3}");
}

/// `m2smap segment` writes the segmenter's masks in the input format: mapped back with `run --masks`, they are
/// the masks `run --segmenter geometric` made (same instances per frame, same recall, precision and IoU against
/// `gt/`), and `--downscale` is refused in one line.
#[test]
fn segment_writes_masks_that_run_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("kitchen");
    let o = common::m2smap(&["synth", "--scene", "kitchen", "--frames", "4", "--out", data.to_str().unwrap()]);
    assert!(o.status.success());
    let masks = dir.path().join("seg");
    let o = common::m2smap(&["segment", data.to_str().unwrap(), "--out", masks.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for ext in ["png", "json"] {
        let n = std::fs::read_dir(&masks).unwrap().filter(|e| e.as_ref().unwrap().path().extension().unwrap() == ext);
        assert_eq!(n.count(), 4, "one .{ext} per frame");
    }
    let back = common::run_ok(&data, &dir.path().join("back"), &["--masks", masks.to_str().unwrap()]);
    let own = common::run_ok(&data, &dir.path().join("own"), &["--segmenter", "geometric"]);
    for key in ["mask_recall", "mask_precision", "mask_mean_iou"] {
        assert_eq!(back[key], own[key], "{key}");
    }
    let per_frame = |run: &str| -> Vec<u64> {
        let text = std::fs::read_to_string(dir.path().join(run).join("frames.jsonl")).unwrap();
        text.lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["instances"].as_u64().unwrap())
            .collect()
    };
    assert_eq!(per_frame("back"), per_frame("own"), "instances per frame");
    assert!(per_frame("own").iter().all(|&n| n > 0));
    assert!(own["mask_recall"].as_f64().is_some(), "the kitchen has gt/: recall is computed");
    common::expect_failure(
        &["segment", data.to_str().unwrap(), "--out", masks.to_str().unwrap(), "--downscale", "2"],
        &["--downscale", "--masks"],
    );
}

/// The mask metrics of `run` against `gt/`: perfect masks score 1, eroded masks keep every object at a lower
/// IoU, and masks that miss objects lose recall but not precision.
#[test]
fn mask_metrics_follow_the_mask_quality() {
    let dir = tempfile::tempdir().unwrap();
    let make = |name: &str, extra: &[&str]| {
        let data = dir.path().join(name);
        let mut args = vec!["synth", "--scene", "clutter", "--frames", "3", "--out", data.to_str().unwrap()];
        args.extend_from_slice(extra);
        assert!(common::m2smap(&args).status.success());
        common::run_ok(&data, &dir.path().join(format!("{name}-run")), &["--variant", "mmp"])
    };
    let perfect = make("perfect", &[]);
    for key in ["mask_recall", "mask_precision", "mask_mean_iou"] {
        assert_eq!(perfect[key].as_f64(), Some(1.0), "{key} of perfect masks");
    }
    let eroded = make("eroded", &["--mask-erode", "3"]);
    let iou = eroded["mask_mean_iou"].as_f64().unwrap();
    assert_eq!(eroded["mask_recall"].as_f64(), Some(1.0));
    assert!(iou < 0.97 && iou > 0.6, "eroded masks: mean IoU {iou}");
    let missed = make("missed", &["--mask-miss", "0.5", "--seed", "3"]);
    let recall = missed["mask_recall"].as_f64().unwrap();
    assert!(recall < 0.9, "half the instances dropped: recall {recall}");
    assert_eq!(missed["mask_precision"].as_f64(), Some(1.0));
}

/// The convexity segmenter against the ground truth of the scenes built to provoke adhesion (objects touching
/// each other, the table, the floor and the wall), on a seed the parameters were not looked at with (measured
/// recall / precision at IoU ≥ 0.5 for seeds 1, 2, 3: clutter 0.74 / 0.72 / 0.68 at precision 1.00, kitchen
/// 0.98 / 0.96 / 0.98 at 0.84 / 0.83 / 0.84, dining 0.75 / 0.73 / 0.73 at 0.81 / 0.83 / 0.80; the Gaussian-gap
/// segmenter before it found nothing in clutter and 0.66 / 0.56 in kitchen with seed 1).
#[test]
fn separates_touching_objects_on_synthetic_scenes() {
    let dir = tempfile::tempdir().unwrap();
    // (scene, least recall, least precision)
    for (scene, recall_min, precision_min) in
        [("clutter", 0.6, 0.9), ("kitchen", 0.9, 0.65), ("dining", 0.7, 0.7), ("desk", 0.6, 0.9)]
    {
        let data = dir.path().join(scene);
        let o = common::m2smap(&[
            "synth",
            "--scene",
            scene,
            "--frames",
            "8",
            "--seed",
            "4",
            "--out",
            data.to_str().unwrap(),
        ]);
        assert!(o.status.success());
        let s = common::run_ok(
            &data,
            &dir.path().join(format!("{scene}-run")),
            &["--segmenter", "geometric", "--variant", "mmp"],
        );
        let (recall, precision, iou) = (
            s["mask_recall"].as_f64().unwrap(),
            s["mask_precision"].as_f64().unwrap(),
            s["mask_mean_iou"].as_f64().unwrap(),
        );
        println!("{scene}: recall {recall:.2}, precision {precision:.2}, mean IoU {iou:.3}");
        assert!(recall >= recall_min, "{scene}: recall {recall:.2} < {recall_min}");
        assert!(precision >= precision_min, "{scene}: precision {precision:.2} < {precision_min}");
        assert!(iou >= 0.85, "{scene}: mean IoU {iou:.3}");
    }
}

/// `ycbv_0000` (real, close range, ground-truth ids): the table top is a supporting plane, so the foam brick
/// resting on it is an instance of its own; the mug's inside, seen over its rim, is the mug's; and the masks
/// cover the objects' pixels well enough that the `full` map's primitives rarely span an object and the table
/// (measured: recall 1.00 at IoU ≥ 0.5 and precision 1.00 on the claims on ground-truth objects on all ten
/// frames (issue targets 0.8 / 0.7), 0.24 over every claim, map-level adhesion 0.1 per frame (issue target 0.3;
/// 0.5 before the cells with a depth hole at their centre took their neighbours' instance), R2G 0.016 m;
/// without joining the inside recall 0.67, precision 0.50: the mug was two instances; without the supporting
/// planes recall 0.47, adhesion 0.9: the brick was one instance with the table; without filling the specks
/// inside objects adhesion 1.1).
#[test]
fn separates_close_range_objects_from_their_table() {
    let Some(data) = common::shared_data("ycbv_0000") else { return };
    let dir = tempfile::tempdir().unwrap();
    let s = common::run_ok(&data, &dir.path().join("run"), &["--segmenter", "geometric"]);
    let value = |k: &str| s[k].as_f64().unwrap_or_else(|| panic!("{k} missing"));
    let (recall, precision, all) = (value("mask_recall"), value("mask_precision"), value("mask_precision_all"));
    println!("ycbv_0000: recall {recall:.2}, precision {precision:.2} ({all:.2} over every claim)");
    assert!(recall >= 0.8, "recall {recall:.2}: an object is glued to the table or cut apart");
    assert!(precision >= 0.7, "precision {precision:.2}: objects are cut into pieces");
    assert!(all <= precision, "every claim includes those on structure");
    assert!(value("mask_structure_claims") > 0.0, "the keyboard and the wall are claimed but unlabelled");
    assert!(value("adhesion_map") <= 0.3, "adhesion {:.2} per frame", value("adhesion_map"));
    assert!(value("r2g_rmse_m") <= 0.03, "R2G {:.3} m: something observed is not mapped", value("r2g_rmse_m"));
}

/// ycbv_0000's map-level adhesion with segmenter masks under the other sample seeds (`sample_seed` 1–6 through
/// `--config`), not only the default's: at 0.55 m the crease between an object and the table and the foam
/// brick's dark face leave bands of cells with noisy normals several cells wide, whose points, left to the
/// table's residual Gaussians, made Gaussians shared with an object on some samples: 0.1, 0.6, 0.3, 0.8, 0.5,
/// 0.3 per frame (mean 0.43) before such bands took the instance beside them (`segment::fill_creases`), now
/// 0.0, 0.0, 0.1, 0.0, 0.0, 0.4 (the cases left: two of 13–25 samples on the other object). The 0.3 per
/// frame, held on average over the samples, with room.
#[test]
fn close_range_adhesion_holds_over_the_sample_seeds() {
    let Some(data) = common::shared_data("ycbv_0000") else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut adhesion = Vec::new();
    for seed in 1..=6 {
        let config = dir.path().join(format!("seed{seed}.json"));
        std::fs::write(&config, format!("{{\"sample_seed\": {seed}}}")).unwrap();
        let out = dir.path().join(format!("run{seed}"));
        let s = common::run_ok(&data, &out, &["--segmenter", "geometric", "--config", config.to_str().unwrap()]);
        adhesion.push(s["adhesion_map"].as_f64().expect("ycbv_0000 has gt/: adhesion is measured"));
    }
    let mean = adhesion.iter().sum::<f64>() / adhesion.len() as f64;
    println!("ycbv_0000 map-level adhesion per sample seed: {adhesion:?}, mean {mean:.2}");
    assert!(mean <= 0.2, "mean adhesion {mean:.2} per frame over the sample seeds: {adhesion:?}");
}

#[test]
fn segmenting_between_frames_changes_no_map_and_gives_the_masks_mapping_uses() {
    // Frames 0..3 of the tabletop: one mapper maps them (no masks); another segments each
    // frame (`Mapper::segment`, as the firmware does after each map) between the same calls. The maps are the
    // same bytes, and the masks equal those `process_segmented` makes of the same frame.
    let scene = Scene::named("tabletop").unwrap();
    let (mut plain_storage, mut busy_storage, mut seg_storage) = (
        bytemuck::zeroed_box::<HostStorage>(),
        bytemuck::zeroed_box::<HostStorage>(),
        bytemuck::zeroed_box::<HostStorage>(),
    );
    let mut plain = Mapper::new(&mut *plain_storage, Params::default()).unwrap();
    let mut busy = Mapper::new(&mut *busy_storage, Params::default()).unwrap();
    let mut segmented = Mapper::new(&mut *seg_storage, Params::default()).unwrap();
    let blank = Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] };
    let map = |m: &Mapper<'_>| {
        let mut buf = vec![0u8; 64 * 1024];
        let n = m.encode_map(&mut buf).unwrap();
        buf.truncate(n);
        buf
    };
    for k in 0..3 {
        let frame = scene.render(k, Some(5));
        let view = frame.frame.view(&scene.camera);
        plain.process(view, None).unwrap();
        busy.process(view, None).unwrap();
        let frames_before = busy.report().frame;
        let (mut ids, mut instances) = (vec![0u16; view.pixels()], [blank; 16]);
        let stats = busy.segment(view, &mut ids, &mut instances, 0).unwrap();
        assert_eq!(busy.report().frame, frames_before, "frame {k}: segmenting is not a frame");
        assert_eq!(map(&busy), map(&plain), "frame {k}: segmenting changed the map");
        let (mut ids2, mut instances2) = (vec![0u16; view.pixels()], [blank; 16]);
        let (_, n) = segmented.process_segmented(view, &mut ids2, &mut instances2, 0).unwrap();
        assert!(n >= 2, "frame {k}: {n} instances");
        assert_eq!((stats.instances as usize, &ids), (n, &ids2), "frame {k}: masks differ");
        assert_eq!(&instances[..n], &instances2[..n]);
    }
    // A wrong-sized id image is an error that names the sizes, and changes nothing.
    let frame = scene.render(3, Some(5));
    let mut short = vec![0u16; 10];
    let before = map(&busy);
    assert!(busy.segment(frame.frame.view(&scene.camera), &mut short, &mut [blank; 4], 0).is_err());
    assert_eq!(map(&busy), before);
}

/// Frames of any size segment without a panic, the grid coarsened where the id image has no room for its cells
/// (tiny and odd sizes, one a column wider than 160 cells of 4 pixels): a tilted floor with a ball half sunk in
/// it; every id names an instance of the list, and that instance's box holds the pixel.
#[test]
fn frames_of_any_size_segment_into_valid_masks() {
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let mut found = 0;
    for (w, h) in [(1u16, 2u16), (2, 1), (3, 2), (7, 5), (80, 60), (161, 3), (641, 481)] {
        let (wu, hu) = (w as usize, h as usize);
        // A ball of 12 cm radius half sunk in the floor at the image centre (the floor at 2 m, tilted).
        let f = 525.0 * w as f32 / 640.0;
        let depth: Vec<u16> = (0..wu * hu)
            .map(|i| {
                let (u, v) = (i % wu, i / wu);
                let z = 2.0 + 0.002 * v as f32 + 0.0005 * u as f32;
                let (du, dv) =
                    ((u as f32 - w as f32 / 2.0) * z / f.max(1.0), (v as f32 - h as f32 / 2.0) * z / f.max(1.0));
                let bump = (0.12f32 * 0.12 - du * du - dv * dv).max(0.0).sqrt();
                ((z - bump) * 5000.0) as u16
            })
            .collect();
        let colour: Vec<u8> = (0..wu * hu * 3).map(|i| (i * 37 % 251) as u8).collect();
        let intrinsics = Intrinsics { fx: f.max(1.0), fy: f.max(1.0), cx: w as f32 / 2.0, cy: h as f32 / 2.0 };
        let frame =
            Frame { width: w, height: h, depth: &depth, depth_scale: 5000.0, colour: &colour, intrinsics, pose: None };
        let mut ids = vec![u16::MAX; frame.pixels()];
        let mut instances = vec![Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; 64];
        let stats = mapper.segment(frame, &mut ids, &mut instances, 0).unwrap();
        let n = stats.instances as usize;
        found += n;
        for (i, &id) in ids.iter().enumerate() {
            assert!(id as usize <= n, "{w} × {h}: pixel {i} has id {id} of {n} instances");
            if let Some(k) = (id as usize).checked_sub(1) {
                let ([u0, v0, u1, v1], (u, v)) = (instances[k].bbox, ((i % wu) as u16, (i / wu) as u16));
                assert!(
                    (u0..=u1).contains(&u) && (v0..=v1).contains(&v),
                    "{w} × {h}: pixel ({u}, {v}) outside its box"
                );
            }
        }
    }
    assert!(found >= 1, "the ball is an instance on some frame");
}
