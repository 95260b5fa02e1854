//! Reconstruction metrics (docs/metrics.md) and the map-level metrics beside them on synthetic frames whose truth is
//! known, and their keys in `m2smap run`'s outputs.

mod common;

use std::fs;

use common::m2smap;
use m2smap::dataset::Pose;
use m2smap::eval::{
    adhesion_cases, behind_support, free_space, is_adhesion_case, map_samples, reconstruction_metrics,
    true_surface_metrics, MapSamples, Observation, PrimSamples, KIND_SQ,
};
use m2smap::synth::{Scene, Shape};
use m2smap_core::{HostStorage, Mapper, Params, Variant};

#[test]
fn g2r_and_r2g_measure_how_well_a_map_fits_its_frame() {
    let scene = Scene::named("tabletop").unwrap();
    for k in [0usize, 5] {
        let frame = scene.render(k, Some(2));
        // Gaussians only: every sample lies within 2σ of its Gaussian's support.
        let mut storage = bytemuck::zeroed_box::<HostStorage>();
        let mut mapper = Mapper::new(&mut *storage, Params { variant: Variant::Mmog, ..Params::default() }).unwrap();
        let view = frame.frame.view(&scene.camera);
        let report = *mapper.process(view, None).unwrap();
        let checked = mapper.check(view, None).unwrap();
        let m = reconstruction_metrics(&mapper, &checked).unwrap();
        println!(
            "frame {k}: G2R {:.4} m, R2G {:.4} m ({} observed, {} reconstructed)",
            m.g2r_rmse_m, m.r2g_rmse_m, m.observed, m.reconstructed
        );
        assert_eq!(m.observed as u32, report.points, "P is every sampled, range-filtered point");
        assert!(m.g2r_rmse_m > 0.0 && m.g2r_rmse_m <= 0.015, "G2R {:.4} m", m.g2r_rmse_m);
        assert!(m.r2g_rmse_m > m.g2r_rmse_m && m.r2g_rmse_m <= 0.06, "R2G {:.4} m", m.r2g_rmse_m);
        // The same map judged against a later frame's points (the camera moved): clearly worse.
        let other = scene.render(k + 3, Some(2));
        let checked_other = mapper.check(other.frame.view(&scene.camera), None).unwrap();
        let moved = reconstruction_metrics(&mapper, &checked_other).unwrap();
        assert!(moved.g2r_rmse_m > 2.0 * m.g2r_rmse_m, "a stale map must score worse: {:.4}", moved.g2r_rmse_m);
    }
}

/// World point `p` in the camera frame of `pose` (camera-to-world), as f32.
fn to_camera(pose: &Pose, p: [f64; 3]) -> [f32; 3] {
    let r = pose.rotation();
    let d = [p[0] - pose.t[0], p[1] - pose.t[1], p[2] - pose.t[2]];
    [0, 1, 2].map(|k| (r[0][k] * d[0] + r[1][k] * d[1] + r[2][k] * d[2]) as f32)
}

/// A map of the scene's true objects, one superquadric-kind primitive per object: points of its whole surface,
/// hit by rays from 600 directions (a Fibonacci sphere) aimed at its centre, in the camera frame of `pose`.
fn true_object_map(scene: &Scene, pose: &Pose) -> MapSamples {
    let mut prims = Vec::new();
    for s in scene.surfaces.iter().filter(|s| s.instance != 0) {
        let centre = match s.shape {
            Shape::Box { centre, .. } | Shape::Cylinder { centre, .. } | Shape::Sphere { centre, .. } => centre,
            Shape::Superquadric { centre, .. } => centre,
            Shape::Plane { .. } => continue,
        };
        let n = 600;
        let samples = (0..n)
            .filter_map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let phi = i as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
                let r = (1.0 - z * z).sqrt();
                let dir = [r * phi.cos(), r * phi.sin(), z];
                let origin = [0, 1, 2].map(|k| centre[k] + 2.0 * dir[k]);
                let (t, _) = s.intersect(origin, dir.map(|x| -x))?;
                Some(to_camera(pose, [0, 1, 2].map(|k| origin[k] - t * dir[k])))
            })
            .collect();
        prims.push(PrimSamples { kind: KIND_SQ, instance: s.instance, samples, extent_m: None });
    }
    MapSamples { prims }
}

#[test]
fn the_true_objects_score_zero_and_a_displaced_one_does_not() {
    let scene = Scene::named("kitchen").unwrap();
    let frame = scene.render(0, Some(1));
    let pose = frame.pose;
    let gt = scene.instance_image(&frame);
    let params = Params::default();
    let obs = Observation { frame: frame.frame.view(&scene.camera), params: &params, gt: Some(&gt) };
    let truth = true_object_map(&scene, &pose);
    assert_eq!(truth.prims.len(), 5);

    // The true shapes: on the true surfaces, inside no other solid, nothing in free space or behind the table.
    let t = true_surface_metrics(&truth, &pose, &scene.surfaces);
    assert!(t.g2r_true_rmse_m.unwrap() < 1e-5, "{:?}", t.g2r_true_rmse_m);
    let deepest = t.penetrations(false).into_iter().fold(0.0, f64::max);
    assert!(deepest < 1e-5, "true objects penetrate by {deepest}");
    let f = free_space(&truth, &obs);
    println!("true objects: {} of {} known samples in free space", f.violating, f.known);
    assert!(f.known > 1000 && f.fraction().unwrap() < 0.005, "{f:?}");
    let b = behind_support(&truth, &obs).unwrap();
    assert_eq!(b.sqs, 0, "{b:?}");

    // The cushion (object 3, resting on the table) displaced, in the camera frame of the frame.
    let k = truth.prims.iter().position(|p| p.instance == 3).unwrap();
    let displaced = |d: [f32; 3]| {
        let mut m = truth.clone();
        for x in &mut m.prims[k].samples {
            *x = [x[0] + d[0], x[1] + d[1], x[2] + d[2]];
        }
        m
    };
    // 3 cm down (world −z): it reaches into the 4 cm table top (at most 2 cm deep inside that slab), below the
    // support the camera sees, and away from the true surfaces; the other objects are unchanged.
    let r = pose.rotation();
    let down = displaced([0, 1, 2].map(|c| (-0.03 * r[2][c]) as f32));
    let t = true_surface_metrics(&down, &pose, &scene.surfaces);
    let cushion = t.penetration[k].1;
    assert!((0.015..0.0201).contains(&cushion), "cushion penetration {cushion}");
    let others = t.penetration.iter().enumerate().filter(|&(i, _)| i != k).map(|(_, p)| p.1).fold(0.0, f64::max);
    assert!(others < 1e-5, "{others}");
    assert!(t.g2r_true_sq_rmse_m.unwrap() > 0.005, "{:?}", t.g2r_true_sq_rmse_m);
    let b = behind_support(&down, &obs).unwrap();
    assert_eq!(b.sqs, 1, "{b:?}");
    assert!(b.fractions[k] > 0.02 && b.max_depth_m > 0.02, "{b:?}");
    // 5 cm towards the camera: its front floats in the free space in front of the observed cushion.
    let forward = displaced([0.0, 0.0, -0.05]);
    let f2 = free_space(&forward, &obs);
    assert!(f2.fraction().unwrap() > f.fraction().unwrap() + 0.02, "{f2:?} vs {f:?}");
    assert!(behind_support(&forward, &obs).unwrap().sqs == 0);
    // Map-level adhesion: the true shapes glue nothing; the cushion sunk into the table has depth-consistent
    // samples on the table's pixels as well as on its own; pushed forward, no sample of it is depth-consistent.
    assert_eq!(adhesion_cases(&truth, &obs), Some((0, 0)));
    assert_eq!(adhesion_cases(&down, &obs), Some((1, 1)));
    assert!(!is_adhesion_case(&forward.prims[k], &obs).unwrap());
}

#[test]
fn run_writes_the_map_level_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("kitchen");
    let o = m2smap(&["synth", "--scene", "kitchen", "--frames", "2", "--seed", "1", "--out", data.to_str().unwrap()]);
    assert!(o.status.success(), "synth: {}", String::from_utf8_lossy(&o.stderr));
    let keys = common::MAP_LEVEL_KEYS;
    // Fractions, RMS and percentiles over superquadrics are null without any; counts are 0.
    let sq_only = ["free_space_violation_sq", "g2r_true_sq_rmse_m", "penetration_sq_p95_m", "penetration_sq_max_m"];
    for (variant, sq_keys_null) in [("full", false), ("mmog", true)] {
        let out = dir.path().join(variant);
        let o = m2smap(&["run", data.to_str().unwrap(), "--variant", variant, "--out", out.to_str().unwrap()]);
        assert!(o.status.success(), "run: {}", String::from_utf8_lossy(&o.stderr));
        let summary: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
        let frames: Vec<serde_json::Value> = fs::read_to_string(out.join("frames.jsonl"))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        for k in keys {
            for f in &frames {
                assert!(f.get(k).is_some(), "frames.jsonl lacks {k}");
            }
            let v = &summary[k];
            if sq_only.contains(&k) && sq_keys_null {
                assert!(v.is_null(), "{variant}: {k} = {v} without superquadrics");
            } else {
                assert!(v.as_f64().is_some_and(|x| x.is_finite() && x >= 0.0), "{variant}: {k} = {v}");
            }
        }
        // Means over the frames; the percentiles pool the primitives of all frames, so the maximum is the
        // largest frame maximum.
        let mean = frames.iter().map(|f| f["g2r_true_rmse_m"].as_f64().unwrap()).sum::<f64>() / frames.len() as f64;
        assert!((summary["g2r_true_rmse_m"].as_f64().unwrap() - mean).abs() < 1e-12);
        let max = frames.iter().map(|f| f["penetration_max_m"].as_f64().unwrap()).fold(0.0, f64::max);
        assert_eq!(summary["penetration_max_m"].as_f64(), Some(max));
        assert!(summary["penetration_p95_m"].as_f64().unwrap() <= max);
        // The map is close to the true surfaces.
        assert!(summary["g2r_true_rmse_m"].as_f64().unwrap() < 0.03, "{variant}: {}", summary["g2r_true_rmse_m"]);
    }
    // mmog has no superquadric: none behind the support, none glued.
    let s: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(dir.path().join("mmog/summary.json")).unwrap()).unwrap();
    assert_eq!(s["sq_behind_support"].as_f64(), Some(0.0));
    assert_eq!(s["adhesion_map_sq"].as_f64(), Some(0.0));
}

#[test]
fn map_samples_hold_every_primitive_with_its_whole_surface() {
    let scene = Scene::named("kitchen").unwrap();
    let frame = scene.render(0, Some(2));
    let mut labels = m2smap::masks::LabelTable::default();
    let masks = scene.perfect_masks(&frame, &mut labels);
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let view = frame.frame.view(&scene.camera);
    let report = *mapper.process(view, Some(masks.view())).unwrap();
    let map = map_samples(&mapper);
    let count = |k: u8| map.prims.iter().filter(|p| p.kind == k).count() as u32;
    assert_eq!((count(0), count(1), count(2)), (report.planes, report.sqs, report.gmms));
    // A superquadric's surface samples are its reconstruction (camera-facing) samples plus the far side: about
    // twice as many.
    let mut k = 0;
    mapper.for_each_primitive(|p| {
        let mut spec = 0usize;
        p.for_each_sample(|_| spec += 1);
        let all = map.prims[k].samples.len();
        if map.prims[k].kind == KIND_SQ {
            assert!(all > spec + spec / 2, "SQ {k}: {all} surface samples, {spec} camera-facing");
        } else {
            assert_eq!(all, spec);
        }
        k += 1;
    });
    assert!(report.sqs >= 3, "the kitchen has superquadrics ({})", report.sqs);
}
