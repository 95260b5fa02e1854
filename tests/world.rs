//! The world map of `run --world`: one map of a posed sequence, checked against the true surfaces of a synthetic
//! scene and the real frames of ../shared/data, and its delta stream replayed by a receiver.

mod common;

use std::path::Path;

use common::{m2smap, shared_data};
use m2smap::synth::read_surfaces;
use m2smap::world::{read_world, split_deltas, Receiver};
use serde_json::Value;

fn run_world(data: &Path, out: &Path, extra: &[&str]) -> Value {
    let world = out.join("world");
    let mut args = vec!["run", data.to_str().unwrap(), "--out", out.to_str().unwrap(), "--world"];
    args.push(world.to_str().unwrap());
    args.extend_from_slice(extra);
    let o = m2smap(&args);
    assert!(o.status.success(), "run --world failed: {}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(world.join("world_summary.json")).unwrap()).unwrap()
}

fn world_lines(out: &Path) -> Vec<Value> {
    std::fs::read_to_string(out.join("world/world.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// Replays `deltas.bin` through a fresh receiver, checking after every delta that it decodes, and returns the
/// map the receiver ends with.
fn replay(world_dir: &Path) -> (Vec<u8>, usize) {
    let stream = std::fs::read(world_dir.join("deltas.bin")).unwrap();
    let deltas = split_deltas(&stream).unwrap();
    let mut rx = Receiver::default();
    for (k, d) in deltas.iter().enumerate() {
        rx.apply(d).unwrap_or_else(|e| panic!("delta {k}: {e}"));
    }
    (rx.world_bytes().unwrap(), deltas.len())
}

#[test]
fn a_synthetic_world_map_lies_on_the_true_surfaces_and_its_deltas_rebuild_it() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("kitchen");
    let o = m2smap(&["synth", "--scene", "kitchen", "--frames", "12", "--seed", "5", "--out", data.to_str().unwrap()]);
    assert!(o.status.success());
    let out = dir.path().join("run");
    let s = run_world(&data, &out, &[]);
    assert_eq!(s["frames"], 12);
    assert_eq!(s["receiver_identical"], true);
    // The receiver, replayed here independently of the run, holds world.bin byte for byte.
    let (rebuilt, deltas) = replay(&out.join("world"));
    assert_eq!(deltas, 12);
    assert_eq!(rebuilt, std::fs::read(out.join("world/world.bin")).unwrap());
    // Every world primitive (read back from world.bin, world frame) lies on the true surfaces: RMS of the
    // distance of its samples to the nearest true surface ≤ 15 mm, planes and Gaussians; superquadrics on the
    // side their cameras saw, measured in the summary.
    let surfaces = read_surfaces(&data.join("gt/objects.json")).unwrap().unwrap();
    let (mut sum, mut n, mut planes) = (0.0f64, 0usize, 0usize);
    read_world(&out.join("world/world.bin"), |_, p| {
        if matches!(p, m2smap_core::map::Primitive::Plane(_)) {
            planes += 1;
        }
        if !matches!(p, m2smap_core::map::Primitive::Sq(_)) {
            p.for_each_sample(|x| {
                let d = surfaces.iter().map(|t| t.distance(x.map(f64::from))).fold(f64::MAX, f64::min);
                sum += d * d;
                n += 1;
            });
        }
    })
    .unwrap();
    let rms = (sum / n as f64).sqrt();
    assert!(n > 500 && rms <= 0.015, "world samples {n}, RMS to the true surfaces {rms:.4} m");
    // The kitchen's floor and its table top, one world plane each (its frames see them 12 times).
    assert!((2..=4).contains(&planes), "{planes} world planes");
    assert!(s["g2r_rmse_m"].as_f64().unwrap() <= 0.02 && s["r2g_rmse_m"].as_f64().unwrap() <= 0.03, "{s}");
    // The world map stays smaller than the sum of the frame maps it holds.
    let lines = world_lines(&out);
    let frame_bytes: f64 = lines.iter().map(|l| l["frame_map_bytes"].as_f64().unwrap()).sum();
    assert!(s["world_bytes"].as_f64().unwrap() < 0.5 * frame_bytes);
}

#[test]
fn the_cabinet_world_map_holds_one_floor_and_one_cabinet() {
    let Some(data) = shared_data("tum_fr3_cabinet") else { return };
    let out = tempfile::tempdir().unwrap();
    let s = run_world(&data, out.path(), &[]);
    assert_eq!((s["frames"].as_u64(), s["planes"].as_u64(), s["sqs"].as_u64()), (Some(58), Some(1), Some(1)), "{s}");
    let (g2r, r2g) = (s["g2r_rmse_m"].as_f64().unwrap(), s["r2g_rmse_m"].as_f64().unwrap());
    assert!(g2r <= 0.03 && r2g <= 0.05, "G2R {g2r:.4} m, R2G {r2g:.4} m");
    assert_eq!(s["receiver_identical"], true);
    let (rebuilt, _) = replay(&out.path().join("world"));
    assert_eq!(rebuilt, std::fs::read(out.path().join("world/world.bin")).unwrap());
    // Revisiting the place: the map grows only with the floor the circling camera has not seen yet (measured
    // 1.24× from frame 20 to 57; the issue asks ≤ 1.3×).
    let lines = world_lines(out.path());
    let (at20, at57) = (lines[20]["world_bytes"].as_f64().unwrap(), lines[57]["world_bytes"].as_f64().unwrap());
    assert!(at57 <= 1.3 * at20, "world map {at20} B after frame 20, {at57} B after 57");
    // Deltas: at most a fifth of the frame maps they replace (measured 0.17).
    assert!(s["delta_to_frame_map"].as_f64().unwrap() <= 0.2, "{s}");
}

#[test]
fn the_redkitchen_world_map_fits_64_kb_and_matches_what_was_seen() {
    let Some(data) = shared_data("7scenes_redkitchen") else { return };
    let out = tempfile::tempdir().unwrap();
    let s = run_world(&data, out.path(), &[]);
    assert_eq!(s["frames"], 300);
    let bytes = s["world_bytes"].as_u64().unwrap();
    let (g2r, r2g) = (s["g2r_rmse_m"].as_f64().unwrap(), s["r2g_rmse_m"].as_f64().unwrap());
    assert!(bytes <= 64 * 1024, "{bytes} B");
    assert!(g2r <= 0.03 && r2g <= 0.06, "G2R {g2r:.4} m, R2G {r2g:.4} m");
    // The planes' cells mark only where their surface was seen (measured 0.0113 m; 0.0195 m when every support
    // point marked a cell and one frame's hit showed a world cell).
    let planes = s["g2r_by_kind_m"][0].as_f64().unwrap();
    assert!(planes <= 0.013, "world planes' G2R {planes:.4} m");
    assert_eq!(s["receiver_identical"], true);
    // Deltas: at most a fifth of the frame maps (measured 0.16).
    assert!(s["delta_to_frame_map"].as_f64().unwrap() <= 0.2, "{s}");
    world_objects_lie_where_the_camera_saw_them(&s, "the default sample", 0.02);
    // The kinds' errors and sample counts make up the whole G2R (measured: planes 4 891, superquadrics 6 725,
    // Gaussians 10 739 samples, 20 / 56 / 24 % of the squared error).
    let (mut squared, mut samples) = (0.0, 0.0);
    for k in 0..3 {
        let n = s["g2r_samples_by_kind"][k].as_f64().unwrap();
        assert!(n > 0.0, "kind {k} has samples: {s}");
        squared += n * s["g2r_by_kind_m"][k].as_f64().unwrap().powi(2);
        samples += n;
    }
    let whole = (squared / samples).sqrt();
    assert!((whole - g2r).abs() <= 1e-6 * g2r, "G2R {g2r} from its kinds {whole}");
}

/// The world's superquadrics lie on what the camera saw: a frame superquadric that runs out of the image (a
/// partial view, 474 of 3 222 on redkitchen) gives no world object its shape. Before that rule, a slab fitted to
/// a strip of wall cut by the image border at top and bottom (1.2 m long in the end) was shown on the default
/// sample and on sample seed 1: world superquadric G2R 0.0277 and 0.0325 m (0.0161 and 0.0158 m with it, with
/// the first frame's sample in every frame; 0.0155 and 0.0235 m with a new sample every frame, where one box of
/// 46 sightings holds half of seed 1's squared error: docs/pipeline.md stage 12).
fn world_objects_lie_where_the_camera_saw_them(s: &Value, sample: &str, max_sq_g2r: f64) {
    let sqs = s["g2r_by_kind_m"][1].as_f64().unwrap();
    assert!(sqs <= max_sq_g2r, "{sample}: world superquadrics' G2R {sqs:.4} m");
    assert!(s["sqs_partial"].as_u64().unwrap() > 0, "{s}");
}

#[test]
fn the_redkitchen_world_objects_hold_on_another_sample() {
    let Some(data) = shared_data("7scenes_redkitchen") else { return };
    let out = tempfile::tempdir().unwrap();
    let config = out.path().join("seed1.json");
    std::fs::write(&config, r#"{"sample_seed": 1}"#).unwrap();
    let s = run_world(&data, out.path(), &["--config", config.to_str().unwrap()]);
    // Measured 0.0155 m with a new sample every frame (0.0125 m with seed 1's first sample in every frame);
    // 0.0203 m before partial views were set aside.
    let g2r = s["g2r_rmse_m"].as_f64().unwrap();
    assert!(g2r <= 0.017, "sample seed 1: world G2R {g2r:.4} m (0.0203 m before partial views were set aside)");
    world_objects_lie_where_the_camera_saw_them(&s, "sample seed 1", 0.026);
}

#[test]
fn a_corrupt_delta_is_refused_and_the_receiver_keeps_its_map() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("tabletop");
    let o = m2smap(&["synth", "--scene", "tabletop", "--frames", "4", "--out", data.to_str().unwrap()]);
    assert!(o.status.success());
    let out = dir.path().join("run");
    run_world(&data, &out, &[]);
    let stream = std::fs::read(out.join("world/deltas.bin")).unwrap();
    let deltas = split_deltas(&stream).unwrap();
    let mut rx = Receiver::default();
    rx.apply(deltas[0]).unwrap();
    let before = rx.world_bytes().unwrap();
    for k in [0, deltas[1].len() / 2, deltas[1].len() - 1] {
        let mut bad = deltas[1].to_vec();
        bad[k] ^= 0x40;
        assert!(rx.apply(&bad).is_err(), "a flipped byte {k} was accepted");
        assert!(rx.apply(&deltas[1][..deltas[1].len() - 3]).is_err(), "a truncated delta was accepted");
        assert_eq!(rx.world_bytes().unwrap(), before, "a refused delta changed the receiver's map");
    }
    // A world map is not a delta.
    assert!(rx.apply(&std::fs::read(out.join("world/world.bin")).unwrap()).is_err());
    // A stream cut inside a delta is named as such.
    assert!(split_deltas(&stream[..stream.len() - 1]).is_err());
}

#[test]
fn run_world_without_poses_is_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("tabletop");
    let o = m2smap(&["synth", "--scene", "tabletop", "--frames", "2", "--out", data.to_str().unwrap()]);
    assert!(o.status.success());
    std::fs::remove_file(data.join("groundtruth.txt")).unwrap();
    let out = dir.path().join("run");
    let o = m2smap(&[
        "run",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--world",
        out.join("w").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("tabletop") && err.contains("--world needs a camera pose"), "{err}");
}

/// A box wider than the view at its left, cut by the image border in every frame: its superquadrics are partial
/// views, so the world shows no shape for it, and what the camera saw of it goes to the world as its Gaussians
/// (`Mapper::for_each_world_primitive`): the world still covers every observed point.
#[test]
fn an_object_only_ever_seen_in_part_is_mapped_by_what_was_seen() {
    use m2smap::dataset::Camera;
    use m2smap::synth::{Scene, Shape, Surface};
    let surface = |name: &str, instance: u16, shape: Shape, colour: [u8; 3]| Surface {
        name: name.into(),
        instance,
        label: if instance > 0 { "cabinet".into() } else { String::new() },
        shape,
        colour,
    };
    let scene = Scene::custom(
        "cut",
        vec![
            surface("floor", 0, Shape::Plane { normal: [0.0, 0.0, 1.0], offset: 0.0 }, [150, 140, 120]),
            surface("wall", 0, Shape::Plane { normal: [0.0, -1.0, 0.0], offset: -1.6 }, [200, 200, 190]),
            surface(
                "cabinet",
                1,
                Shape::Box { centre: [-1.15, 0.9, 0.35], half: [0.45, 0.25, 0.35], yaw: 0.0 },
                [120, 80, 40],
            ),
        ],
        Camera::preset("fr3").unwrap(),
        [0.1, -1.1, 1.25],
        [0.0, 0.9, 0.25],
    );
    let out = tempfile::tempdir().unwrap();
    let data = out.path().join("cut");
    scene.write_tum(&data, 10, 1, true).unwrap();
    let s = run_world(&data, &out.path().join("run"), &[]);
    // Every frame's superquadric of the cabinet is a partial view; no world object takes its shape.
    assert_eq!((s["sqs_partial"].as_u64(), s["sqs"].as_u64()), (Some(10), Some(0)), "{s}");
    // Measured: R2G 0.024 m, G2R 0.007 m; 0.143 m R2G when the world took nothing of a partial view.
    let (g2r, r2g) = (s["g2r_rmse_m"].as_f64().unwrap(), s["r2g_rmse_m"].as_f64().unwrap());
    assert!(g2r <= 0.02 && r2g <= 0.04, "G2R {g2r:.4} m, R2G {r2g:.4} m");
}
