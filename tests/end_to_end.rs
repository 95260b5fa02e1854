//! The `m2smap` command on real data, on synthetic data, and on broken datasets.

mod common;

use std::fs;
use std::path::Path;

use common::{expect_failure, m2smap, run_ok, shared_data};
use m2smap::dataset::{associate, parse_list, pose_at, read_list, read_trajectory, Dataset, Layout};
use m2smap_core::HostStorage;

fn frames_jsonl(out: &Path) -> Vec<serde_json::Value> {
    fs::read_to_string(out.join("frames.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

/// The summary.json keys that docs/formats.md names as the stable core of the file.
const SUMMARY_KEYS: [&str; 15] = [
    "frames",
    "variant",
    "hz",
    "ms_per_frame_median",
    "primitives",
    "payload_bytes",
    "g2r_rmse_m",
    "r2g_rmse_m",
    "r_c",
    "a_s",
    "n_adh",
    "j_sq_deg",
    "pools",
    "overflow_events",
    "profile",
];

fn check_run(summary: &serde_json::Value, frames: &[serde_json::Value], expected_frames: usize) {
    for k in SUMMARY_KEYS {
        assert!(summary.get(k).is_some(), "summary.json lacks {k}");
    }
    for k in ["plane", "sq", "gmm", "total"] {
        assert!(summary["primitives"].get(k).is_some(), "primitives lacks {k}");
    }
    assert_eq!(summary["frames"].as_u64().unwrap() as usize, expected_frames);
    assert_eq!(frames.len(), expected_frames);
    assert!(summary["hz"].as_f64().unwrap() > 0.0);
    assert_eq!(summary["profile"], "host", "run's default profile");
    for f in frames {
        assert!(f["supervoxels"].as_u64().unwrap() > 0);
        assert!(f["gaussians"].as_u64().unwrap() >= f["supervoxels"].as_u64().unwrap());
        let pools = f["pools"].as_object().unwrap();
        assert_eq!(pools.len(), HostStorage::POOLS.len());
        for (id, capacity, _) in HostStorage::POOLS {
            let p = &pools[id.name()];
            let (peak, cap) = (p["peak"].as_u64().unwrap() as usize, p["capacity"].as_u64().unwrap() as usize);
            assert_eq!(cap, capacity, "{}: the capacity of the host profile", id.name());
            // A pool refuses an entry only when it is full.
            if p["overflow_events"].as_u64().unwrap() > 0 {
                assert_eq!(peak, capacity, "{} refused entries before it was full", id.name());
            }
        }
        // Each stage's pool holds exactly the frame's count of that stage.
        for (pool, count) in [("voxels", "voxels"), ("supervoxels", "supervoxels"), ("gaussians", "gaussians")] {
            assert_eq!(pools[pool]["peak"], f[count], "{pool}");
        }
    }
}

#[test]
fn maps_every_cabinet_frame() {
    let Some(data) = shared_data("tum_fr3_cabinet") else { return };
    let out = tempfile::tempdir().unwrap();
    let summary = run_ok(&data, out.path(), &[]);
    check_run(&summary, &frames_jsonl(out.path()), 58);
    assert_eq!(summary["overflow_events"], 0);
    // The mcu profile must also fit every cabinet frame without losing a point.
    let out_mcu = tempfile::tempdir().unwrap();
    let mcu = run_ok(&data, out_mcu.path(), &["--profile", "mcu"]);
    assert_eq!(mcu["overflow_events"], 0);
    assert_eq!(mcu["gaussians"], summary["gaussians"], "profiles must not change results when nothing overflows");
}

#[test]
fn maps_every_redkitchen_frame() {
    let Some(data) = shared_data("7scenes_redkitchen") else { return };
    let out = tempfile::tempdir().unwrap();
    let summary = run_ok(&data, out.path(), &[]);
    check_run(&summary, &frames_jsonl(out.path()), 300);
}

#[test]
fn reads_the_real_datasets() {
    if let Some(data) = shared_data("tum_fr3_cabinet") {
        let d = Dataset::open(&data, None).unwrap();
        assert_eq!(d.layout, Layout::Tum);
        assert_eq!(d.frames.len(), 58);
        assert_eq!((d.camera.fx, d.camera.depth_scale), (535.4, 5000.0), "fr3 preset from the folder name");
        assert!(d.frames.iter().all(|f| f.pose.is_some()));
        let f = d.load(0).unwrap();
        assert_eq!((f.width, f.height, f.depth.len(), f.colour.len()), (640, 480, 307_200, 921_600));
    }
    if let Some(data) = shared_data("7scenes_redkitchen") {
        let d = Dataset::open(&data, None).unwrap();
        assert_eq!(d.layout, Layout::SevenScenes);
        assert_eq!(d.frames.len(), 300);
        assert_eq!((d.camera.fx, d.camera.cx, d.camera.depth_scale), (585.0, 320.0, 1000.0));
        let p = d.frames[0].pose.unwrap();
        assert!((p.t[0] + 0.3404563).abs() < 1e-6, "translation from the 4x4 pose");
        let r = p.rotation();
        assert!((r[0][0] - 0.9093129).abs() < 1e-4 && (r[1][0] + 0.2724862).abs() < 1e-4, "rotation from the 4x4 pose");
        let f = d.load(0).unwrap();
        assert!(!f.depth.contains(&u16::MAX), "65535 is invalid depth and becomes 0");
    }
}

#[test]
fn association_reproduces_the_benchmark_lists() {
    let Some(lists) = shared_data("tum_lists") else { return };
    for name in ["fr3_walking_rpy_assoc.txt", "fr1_teddy_assoc_ScaleORB.txt"] {
        let pairs = read_list(&lists.join(name), 3).unwrap();
        let rgb: Vec<f64> = pairs.iter().map(|e| e.timestamp).collect();
        let depth: Vec<f64> = pairs.iter().map(|e| e.fields[1].parse().unwrap()).collect();
        let got = associate(&rgb, &depth, 0.02);
        let expected: Vec<(usize, usize)> = (0..pairs.len()).collect::<Vec<_>>().iter().map(|&i| (i, i)).collect();
        assert_eq!(got, expected, "{name}");
    }
    let rgb = read_list(&lists.join("fr1_xyz_rgb.txt"), 1).unwrap();
    let depth = read_list(&lists.join("fr1_xyz_depth.txt"), 1).unwrap();
    let (ta, tb): (Vec<f64>, Vec<f64>) =
        (rgb.iter().map(|e| e.timestamp).collect(), depth.iter().map(|e| e.timestamp).collect());
    let pairs = associate(&ta, &tb, 0.02);
    assert!(pairs.len() >= 790, "fr1/xyz has 798 rgb frames; {} associated", pairs.len());
    let mut used = std::collections::HashSet::new();
    for w in pairs.windows(2) {
        assert!(ta[w[0].0] < ta[w[1].0], "sorted by rgb time");
    }
    for &(i, j) in &pairs {
        assert!((ta[i] - tb[j]).abs() < 0.02);
        assert!(used.insert(j), "depth {j} used twice");
    }
}

#[test]
fn poses_are_interpolated_between_ground_truth_rows() {
    let Some(lists) = shared_data("tum_lists") else { return };
    let traj = read_trajectory(&lists.join("fr1_xyz_groundtruth.txt")).unwrap();
    let (t0, p0) = traj[100];
    let (t1, p1) = traj[101];
    assert_eq!(pose_at(&traj, t0).unwrap().t, p0.t, "exact row");
    let mid = pose_at(&traj, 0.5 * (t0 + t1)).unwrap();
    for k in 0..3 {
        assert!((mid.t[k] - 0.5 * (p0.t[k] + p1.t[k])).abs() < 1e-6);
    }
    let qn: f64 = mid.q.iter().map(|x| x * x).sum();
    assert!((qn - 1.0).abs() < 1e-9);
    assert!(pose_at(&traj, traj[0].0 - 5.0).is_none(), "long before the trajectory");
}

#[test]
fn malformed_list_lines_name_their_line() {
    let err = parse_list("# comment\n1.0 rgb/a.png\nnot-a-time rgb/b.png\n", 1).unwrap_err().to_string();
    assert!(err.starts_with("3: malformed line"), "{err}");
    let err = parse_list("1.0\n", 1).unwrap_err().to_string();
    assert!(err.starts_with("1: malformed line"), "{err}");
}

/// Writes a small synthetic TUM folder and returns its path.
fn synth_folder(dir: &Path, frames: usize) -> std::path::PathBuf {
    let out = dir.join("scene");
    let o = m2smap(&[
        "synth",
        "--scene",
        "tabletop",
        "--frames",
        &frames.to_string(),
        "--seed",
        "3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

#[test]
fn synthetic_scene_round_trips_through_the_command() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 3);
    let out = dir.path().join("run");
    let summary = run_ok(&scene, &out, &["--variant", "full"]);
    check_run(&summary, &frames_jsonl(&out), 3);
    let d = Dataset::open(&scene, None).unwrap();
    assert_eq!(d.camera.fx, 535.4, "camera.json is read");
    assert!(d.frames.iter().all(|f| f.pose.is_some()));
    // Same seed, same bytes.
    let again = dir.path().join("again");
    let o = m2smap(&["synth", "--scene", "tabletop", "--frames", "3", "--seed", "3", "--out", again.to_str().unwrap()]);
    assert!(o.status.success());
    for f in ["rgb.txt", "groundtruth.txt", "gt/objects.json"] {
        assert_eq!(fs::read(scene.join(f)).unwrap(), fs::read(again.join(f)).unwrap(), "{f}");
    }
    let first_depth = &d.frames[0].depth;
    let name = first_depth.strip_prefix(&scene).unwrap();
    assert_eq!(fs::read(first_depth).unwrap(), fs::read(again.join(name)).unwrap());
}

/// Runs `m2smap run` on a broken dataset: must fail with exactly one line naming `needle`.
fn expect_error(dataset: &Path, needle: &str) {
    let out = tempfile::tempdir().unwrap();
    expect_failure(&["run", dataset.to_str().unwrap(), "--out", out.path().to_str().unwrap()], &[needle]);
}

#[test]
fn broken_datasets_give_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 2);
    let d = Dataset::open(&scene, None).unwrap();
    let depth0 = d.frames[0].depth.clone();
    let colour0 = d.frames[0].colour.clone();
    let fresh = |tag: &str| {
        let copy = dir.path().join(tag);
        copy_dir(&scene, &copy);
        copy
    };

    // Truncated depth PNG.
    let c = fresh("truncated");
    let p = c.join(depth0.strip_prefix(&scene).unwrap());
    let bytes = fs::read(&p).unwrap();
    fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    expect_error(&c, p.file_name().unwrap().to_str().unwrap());

    // Corrupt colour PNG (garbage after the signature).
    let c = fresh("corrupt");
    let p = c.join(colour0.strip_prefix(&scene).unwrap());
    let mut bytes = fs::read(&p).unwrap();
    for b in bytes.iter_mut().skip(40).take(200) {
        *b ^= 0x5a;
    }
    fs::write(&p, bytes).unwrap();
    expect_error(&c, p.file_name().unwrap().to_str().unwrap());

    // Missing depth file.
    let c = fresh("missing");
    let p = c.join(depth0.strip_prefix(&scene).unwrap());
    fs::remove_file(&p).unwrap();
    expect_error(&c, p.file_name().unwrap().to_str().unwrap());

    // Colour image of the wrong size.
    let c = fresh("size");
    let p = c.join(colour0.strip_prefix(&scene).unwrap());
    image::RgbImage::new(320, 240).save(&p).unwrap();
    expect_error(&c, p.file_name().unwrap().to_str().unwrap());

    // 8-bit depth.
    let c = fresh("depth8");
    let p = c.join(depth0.strip_prefix(&scene).unwrap());
    image::GrayImage::new(640, 480).save(&p).unwrap();
    expect_error(&c, p.file_name().unwrap().to_str().unwrap());

    // All-zero depth: the core rejects the frame, the shell names the depth file.
    let c = fresh("zeros");
    let p = c.join(depth0.strip_prefix(&scene).unwrap());
    image::ImageBuffer::<image::Luma<u16>, _>::new(640, 480).save(&p).unwrap();
    expect_error(&c, "no depth sample lies in the configured depth range");

    // Malformed rgb.txt line.
    let c = fresh("list");
    let mut text = fs::read_to_string(c.join("rgb.txt")).unwrap();
    text.push_str("oops rgb/x.png\n");
    fs::write(c.join("rgb.txt"), text).unwrap();
    expect_error(&c, "rgb.txt:5: malformed line");

    // Malformed camera.json.
    let c = fresh("camera");
    fs::write(c.join("camera.json"), "{\"fx\": 1}").unwrap();
    expect_error(&c, "camera.json");

    // Not a dataset at all.
    expect_error(&dir.path().join("nowhere"), "nowhere");
}

#[test]
fn bad_config_and_variant_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 1);
    let cfg = dir.path().join("params.json");
    fs::write(&cfg, "{\"voxel_resolutoin\": 0.05}").unwrap();
    let out = dir.path().join("o");
    let o =
        m2smap(&["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--config", cfg.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("params.json"));
    fs::write(&cfg, "{\"depth_max\": -1.0}").unwrap();
    let o =
        m2smap(&["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--config", cfg.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("depth_max"));
    fs::write(&cfg, "{\"voxel_resolution\": 0.05}").unwrap();
    let o =
        m2smap(&["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--config", cfg.to_str().unwrap()]);
    assert!(o.status.success(), "a valid partial config is accepted");
    // The valid names are listed.
    expect_failure(
        &["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--variant", "best"],
        &["unknown variant", "full", "pmsao", "wsqa", "mmog", "mmp", "mmq"],
    );
}

/// A test that cannot run its real-data part leaves its name and the reason in the skip list `make test`
/// prints.
#[test]
fn a_skipped_test_is_recorded_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let list = dir.path().join("skipped.txt");
    common::record_skip(&list, "../shared/data/nowhere not found");
    common::record_skip(&list, "second reason");
    let text = fs::read_to_string(&list).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2, "{text}");
    assert!(
        lines[0].starts_with("a_skipped_test_is_recorded_by_name: ") && lines[0].ends_with("nowhere not found"),
        "{text}"
    );
}

/// The camera model's origin is printed and recorded in summary.json, and a preset that contradicts the TUM
/// sequence the folder names draws a warning.
#[test]
fn the_camera_used_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 1);
    let out = dir.path().join("o");
    let o = m2smap(&["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success());
    let s: serde_json::Value = serde_json::from_str(&fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let camera = s["camera"].as_str().unwrap().to_owned();
    assert!(camera.starts_with("camera.json: fx "), "{camera}");
    assert!(String::from_utf8_lossy(&o.stdout).contains(&format!("camera: {camera}")));
    // A folder named after fr1 mapped with --camera fr3.
    let fr1 = dir.path().join("rgbd_dataset_freiburg1_desk");
    copy_dir(&scene, &fr1);
    fs::remove_file(fr1.join("camera.json")).unwrap();
    let o = m2smap(&["run", fr1.to_str().unwrap(), "--out", out.to_str().unwrap(), "--frames", "1"]);
    let s: serde_json::Value = serde_json::from_str(&fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert!(o.status.success() && s["camera"].as_str().unwrap().starts_with("folder name (fr1)"), "{}", s["camera"]);
    let o = m2smap(&["run", fr1.to_str().unwrap(), "--out", out.to_str().unwrap(), "--frames", "1", "--camera", "fr3"]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(err.contains("warning: --camera fr3") && err.contains("says fr1"), "{err}");
}

/// A run whose pools overflow says so on stderr, naming the pools and what the voxel pool's drop policy did (the
/// mcu and tiny profiles coarsen or drop data on frames larger than they are sized for).
#[test]
fn pool_overflow_is_never_silent() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 1);
    let out = dir.path().join("o");
    let o = m2smap(&["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--profile", "tiny"]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    assert!(err.contains("warning: the tiny profile's pools overflowed") && err.contains("voxels ("), "{err}");
    // What the voxel pool's drop policy did, also in summary.json: the tiny profile's voxels do not fit even at
    // the coarsest edge, so its frame is mapped over a nearer range and loses points.
    let s: serde_json::Value = serde_json::from_str(&fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let (coarser, nearer, dropped) = (&s["frames_coarser_voxels"], &s["frames_nearer_range"], &s["dropped_points"]);
    assert!(err.contains(&format!("{coarser} frames mapped with coarser voxels, {nearer} over a nearer depth range")));
    assert!(coarser.as_u64() == Some(1) && nearer.as_u64() == Some(1) && dropped.as_u64() > Some(0), "{s}");
    let o = m2smap(&["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("overflowed"), "the host profile has room");
}

/// `export` and `render` map with the variant, parameters and camera they are given, like `run`.
#[test]
fn export_and_render_take_the_variant_config_and_camera() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 1);
    let vertices = |extra: &[&str]| {
        let ply = dir.path().join("f.ply");
        let mut args = vec!["export", scene.to_str().unwrap(), "--frame", "0", "--ply", ply.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = m2smap(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let text = fs::read(&ply).unwrap();
        let header = String::from_utf8_lossy(&text[..200.min(text.len())]).into_owned();
        header
            .lines()
            .find_map(|l| l.strip_prefix("element vertex ").map(|n| n.trim().parse::<usize>().unwrap()))
            .unwrap()
    };
    let full = vertices(&[]);
    let mmog = vertices(&["--variant", "mmog"]);
    assert_ne!(full, mmog, "a GMM-only map is sampled differently from the full map");
    let cfg = dir.path().join("params.json");
    fs::write(&cfg, "{\"depth_max\": -1.0}").unwrap();
    let png = dir.path().join("f.png");
    expect_failure(
        &[
            "render",
            scene.to_str().unwrap(),
            "--frame",
            "0",
            "--out",
            png.to_str().unwrap(),
            "--config",
            cfg.to_str().unwrap(),
        ],
        &["depth_max"],
    );
    expect_failure(
        &["render", scene.to_str().unwrap(), "--frame", "0", "--out", png.to_str().unwrap(), "--variant", "best"],
        &["one of full"],
    );
    let o =
        m2smap(&["render", scene.to_str().unwrap(), "--frame", "0", "--out", png.to_str().unwrap(), "--camera", "fr3"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A frame number beyond the dataset and an unknown camera name are refused before any mapping, with what is
/// valid.
#[test]
fn out_of_range_frames_and_unknown_cameras_say_what_is_valid() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 3);
    let ply = dir.path().join("f.ply");
    expect_failure(
        &["export", scene.to_str().unwrap(), "--frame", "5", "--ply", ply.to_str().unwrap()],
        &["--frame 5", "has 3"],
    );
    let png = dir.path().join("f.png");
    expect_failure(
        &["render", scene.to_str().unwrap(), "--frame", "3", "--out", png.to_str().unwrap()],
        &["--frame 3", "has 3"],
    );
    let out = dir.path().join("o");
    expect_failure(
        &["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--camera", "fr9"],
        &["fr9", "fr1, fr2, fr3"],
    );
}

/// Nothing to map is an error, not a summary of zeros: `--frames 0`, a dataset whose lists hold no frame, and a
/// `--masks` folder without masks.
#[test]
fn nothing_to_map_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 1);
    let out = dir.path().join("o");
    expect_failure(&["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--frames", "0"], &["--frames 0"]);
    let empty_masks = dir.path().join("no-masks");
    fs::create_dir_all(&empty_masks).unwrap();
    expect_failure(
        &["run", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--masks", empty_masks.to_str().unwrap()],
        &["no-masks", "no masks"],
    );
    // A dataset whose rgb.txt and depth.txt list no frames.
    let empty = dir.path().join("empty");
    copy_dir(&scene, &empty);
    for list in ["rgb.txt", "depth.txt"] {
        fs::write(empty.join(list), "# timestamp filename\n").unwrap();
    }
    expect_failure(&["run", empty.to_str().unwrap(), "--out", out.to_str().unwrap()], &["no frames"]);
}

fn copy_dir(from: &Path, to: &Path) {
    fs::create_dir_all(to).unwrap();
    for e in fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            fs::copy(e.path(), target).unwrap();
        }
    }
}

#[test]
fn cabinet_floor_is_a_plane_and_full_fusion_never_glues_the_cabinet() {
    let Some(data) = shared_data("tum_fr3_cabinet") else { return };
    let run = |variant: &str| {
        let out = tempfile::tempdir().unwrap();
        let summary = run_ok(&data, out.path(), &["--variant", variant]);
        (summary, frames_jsonl(out.path()))
    };
    let (full, frames) = run("full");
    let (pmsao, _) = run("pmsao");
    assert_eq!(full["n_adh"].as_f64(), Some(0.0), "full: no adhesion on any cabinet frame");
    assert!(pmsao["n_adh"].as_f64().unwrap() > 0.0, "pmsao glues the cabinet somewhere");
    assert!(frames.iter().all(|f| f["instances"] == 1), "every frame has its cabinet mask");
    assert!(frames.iter().all(|f| f["objects"].as_u64().unwrap() == 1), "the cabinet is one object in every frame");
    // Where the mask bleeds past the cabinet onto what stands behind it, that part is detached (kept as
    // residual Gaussians), and the cabinet is still a superquadric there.
    let bleeding: Vec<_> = frames.iter().filter(|f| f["detached_gaussians"].as_u64().unwrap() > 0).collect();
    println!("detached parts on {} frames", bleeding.len());
    assert!(!bleeding.is_empty(), "some cabinet masks bleed onto the background (e.g. frame 45)");
    assert!(
        bleeding.iter().all(|f| f["primitives"]["sq"].as_f64() == Some(1.0)),
        "a superquadric where the mask bleeds"
    );
    // The floor: a plane whose normal is the world's vertical (TUM's motion-capture frame has z up).
    let d = Dataset::open(&data, None).unwrap();
    let mut storage = bytemuck::zeroed_box::<m2smap_core::HostStorage>();
    let mut mapper = m2smap_core::Mapper::new(&mut *storage, m2smap_core::Params::default()).unwrap();
    let mut labels = m2smap::masks::LabelTable::default();
    let mut with_floor = 0;
    for (k, f) in d.frames.iter().enumerate() {
        let frame = d.load(k).unwrap();
        let masks = m2smap::masks::read_frame_masks(&data.join("masks"), &f.stem, 640, 480, &mut labels).unwrap();
        mapper.process(frame.view(&d.camera), masks.as_ref().map(|m| m.view())).unwrap();
        let r = f.pose.unwrap().rotation();
        let vertical = |n: [f32; 3]| (r[2][0] * n[0] as f64 + r[2][1] * n[1] as f64 + r[2][2] * n[2] as f64).abs();
        if mapper.planes().iter().any(|p| vertical(p.normal) > 0.95 && p.occupied >= 50) {
            with_floor += 1;
        }
    }
    let share = with_floor as f64 / d.frames.len() as f64;
    println!("floor plane on {with_floor} of {} frames", d.frames.len());
    assert!(share >= 0.9, "the floor is a bounded plane on only {share:.2} of the frames");
}

#[test]
fn cabinet_is_one_tracked_superquadric_with_stable_size() {
    let Some(data) = shared_data("tum_fr3_cabinet") else { return };
    let run = |variant: &str| {
        let out = tempfile::tempdir().unwrap();
        run_ok(&data, out.path(), &["--variant", variant])
    };
    let (full, wsqa) = (run("full"), run("wsqa"));
    let frames_with_sq = full["frames_with_sq"].as_f64().unwrap();
    assert!(
        frames_with_sq >= 0.95,
        "the cabinet is an accepted superquadric on only {frames_with_sq:.2} of the frames"
    );
    assert_eq!(full["tracks_started"], 1, "one track spans the sequence");
    let (j_full, j_wsqa) = (full["j_sq_deg"].as_f64().unwrap(), wsqa["j_sq_deg"].as_f64().unwrap());
    println!("J_sq full {j_full:.2} deg, wsqa {j_wsqa:.2} deg ({:.0} % lower)", 100.0 * (1.0 - j_full / j_wsqa));
    assert!(j_full <= 1.0, "J_sq of the cabinet {j_full:.2} deg");
    // Alignment never makes it worse. Since the far end of a seen top bounds the fit (docs/pipeline.md), the
    // cabinet's fits no longer swap axes from frame to frame, so `wsqa` has the same 0.27° (it was 2.37°, and
    // this test asked for 60 % less); what alignment does to swapped fits is tested in `track::tests`.
    assert!(j_full <= j_wsqa + 0.05, "alignment must not raise J_sq: {j_full:.2} vs {j_wsqa:.2}");
    assert!(full["payload_bytes"].as_f64().unwrap() > 0.0);

    // Size consistency, and the transmitted map against the unquantised one.
    let d = Dataset::open(&data, None).unwrap();
    let mut storage = bytemuck::zeroed_box::<m2smap_core::HostStorage>();
    let mut mapper = m2smap_core::Mapper::new(&mut *storage, m2smap_core::Params::default()).unwrap();
    let mut labels = m2smap::masks::LabelTable::default();
    let mut sizes: Vec<[f32; 3]> = Vec::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut worst_shift = 0.0f32;
    for (k, f) in d.frames.iter().enumerate() {
        let frame = d.load(k).unwrap();
        let masks = m2smap::masks::read_frame_masks(&data.join("masks"), &f.stem, 640, 480, &mut labels).unwrap();
        mapper.process(frame.view_posed(&d.camera, f.pose.as_ref()), masks.as_ref().map(|m| m.view())).unwrap();
        if let Some(o) = mapper.objects().iter().find(|o| o.sq_state == m2smap_core::objects::SQ_ACCEPTED) {
            let mut s = o.sq.scales;
            s.sort_by(f32::total_cmp);
            sizes.push(s);
        }
        if k % 10 == 0 {
            // Every decoded sample against the unquantised primitive: its distance from the superquadric's
            // surface, or from the nearest sample of a plane or Gaussian (whose samples map one to one).
            use m2smap_core::map::Primitive;
            let n = mapper.encode_map(&mut buf).unwrap();
            let mut originals: Vec<(Option<m2smap_core::superquadric::Superquadric>, Vec<[f32; 3]>)> = Vec::new();
            mapper.for_each_primitive(|p| {
                let mut v = Vec::new();
                p.for_each_sample(|x| v.push(x));
                originals.push((if let Primitive::Sq(s) = p { Some(s.sq) } else { None }, v));
            });
            let mut index = 0;
            m2smap_core::wire::decode(&buf[..n], |p| {
                let (sq, samples) = &originals[index];
                index += 1;
                p.for_each_sample(|x| {
                    let d = match sq {
                        Some(sq) => sq.distance(x).abs(),
                        None => samples
                            .iter()
                            .map(|y| m2smap_core::linalg::norm(m2smap_core::linalg::sub(x, *y)))
                            .fold(f32::MAX, f32::min),
                    };
                    worst_shift = worst_shift.max(d);
                });
            })
            .unwrap();
            assert_eq!(index, originals.len());
        }
    }
    let spread: Vec<String> = (0..3)
        .map(|a| {
            let v: Vec<f64> = sizes.iter().map(|s| s[a] as f64).collect();
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
            assert!(sd <= 0.15 * mean, "cabinet half-axis {a} varies too much: {mean:.3} ± {sd:.3} m");
            format!("{mean:.3} ± {sd:.3}")
        })
        .collect();
    println!(
        "cabinet half-axes (sorted, m): {}; wire quantisation moves samples by at most {:.2} mm",
        spread.join(", "),
        worst_shift * 1000.0
    );
    assert!(worst_shift < 1e-3);
}

/// `from` with every image enlarged `k` times (each pixel a k × k block), then cropped to `height` rows when
/// given: a sensor with k times the resolution. camera.json and the mask boxes are scaled to match.
fn enlarge_dataset(from: &Path, to: &Path, k: u32, height: Option<u32>) {
    fs::create_dir_all(to).unwrap();
    for e in fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let (path, target) = (e.path(), to.join(e.file_name()));
        if e.file_type().unwrap().is_dir() {
            enlarge_dataset(&path, &target, k, height);
        } else if path.extension().is_some_and(|x| x == "png") {
            let img = image::open(&path).unwrap();
            let h = height.unwrap_or(img.height() * k).min(img.height() * k);
            let big = img
                .resize_exact(img.width() * k, img.height() * k, image::imageops::FilterType::Nearest)
                .crop_imm(0, 0, img.width() * k, h);
            big.save(&target).unwrap();
        } else if path.file_name().is_some_and(|n| n == "camera.json") {
            let mut c: serde_json::Value = serde_json::from_str(&fs::read_to_string(&path).unwrap()).unwrap();
            for key in ["fx", "fy", "cx", "cy"] {
                c[key] = serde_json::json!(c[key].as_f64().unwrap() * k as f64);
            }
            c["width"] = serde_json::json!(c["width"].as_u64().unwrap() as u32 * k);
            c["height"] = serde_json::json!(height.unwrap_or(c["height"].as_u64().unwrap() as u32 * k));
            fs::write(&target, c.to_string()).unwrap();
        } else if path.extension().is_some_and(|x| x == "json") && path.parent().is_some_and(|p| p.ends_with("masks")) {
            let mut m: serde_json::Value = serde_json::from_str(&fs::read_to_string(&path).unwrap()).unwrap();
            for inst in m["instances"].as_array_mut().unwrap() {
                let b: Vec<u64> = inst["bbox"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
                inst["bbox"] = serde_json::json!([
                    b[0] * k as u64,
                    b[1] * k as u64,
                    b[2] * k as u64 + k as u64 - 1,
                    b[3] * k as u64 + k as u64 - 1
                ]);
            }
            fs::write(&target, m.to_string()).unwrap();
        } else {
            fs::copy(&path, &target).unwrap();
        }
    }
}

/// Frames larger than the capacity profile map through `--downscale N`: subsampling a 3× enlarged scene by 3
/// gives back the original frames exactly, so the maps are the same (their bytes; their floats up to the rounding
/// of fx·3/3 in f32); a
/// 1920×1080 sensor maps with
/// `--downscale 2`, and without it the error names the option.
#[test]
fn large_frames_map_through_downscale() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 3);
    let big = dir.path().join("big");
    enlarge_dataset(&scene, &big, 3, None);
    let original = run_ok(&scene, &dir.path().join("a"), &[]);
    let restored = run_ok(&big, &dir.path().join("b"), &["--downscale", "3"]);
    for key in ["primitives", "payload_bytes", "n_adh"] {
        assert_eq!(original[key], restored[key], "{key}");
    }
    for key in ["g2r_rmse_m", "r2g_rmse_m"] {
        let (a, b) = (original[key].as_f64().unwrap(), restored[key].as_f64().unwrap());
        // Equal bytes (above), floats within 0.1 %: the superquadric fit projects points into the image (its
        // free-space tests), where fx·3/3's last bit can move a point across a pixel boundary.
        assert!((a - b).abs() <= 1e-3 * a, "{key}: {a} vs {b}");
    }
    assert!(original["primitives"]["sq"].as_f64().unwrap() >= 1.0);
    // 1920 × 1080 (the 3× scene's top 1080 rows).
    let hd = dir.path().join("hd");
    enlarge_dataset(&scene, &hd, 3, Some(1080));
    let out = dir.path().join("c");
    expect_failure(
        &["run", hd.to_str().unwrap(), "--out", out.to_str().unwrap()],
        &["2073600 pixels", "--downscale 2"],
    );
    let s = run_ok(&hd, &out, &["--downscale", "2"]);
    assert!(s["primitives"]["sq"].as_f64().unwrap() >= 1.0 && s["g2r_rmse_m"].as_f64().unwrap() < 0.05, "{s}");
    assert!(s["camera"].as_str().unwrap().contains("960×540 (--downscale 2 of 1920×1080)"), "{}", s["camera"]);
    // render and export take it too, and a factor out of range is refused.
    let png = dir.path().join("hd.png");
    let o =
        m2smap(&["render", hd.to_str().unwrap(), "--frame", "1", "--downscale", "2", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(image::open(&png).unwrap().to_rgb8().dimensions(), (1920, 1080), "2 × 2 panels of 960 × 540");
    expect_failure(
        &["run", hd.to_str().unwrap(), "--out", out.to_str().unwrap(), "--downscale", "0"],
        &["--downscale 0"],
    );
}

/// `render` and `export` take `--profile` like `run`: the mcu profile's smaller pools give a different map of
/// a frame with more points than they hold.
#[test]
fn render_and_export_take_the_profile() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_folder(dir.path(), 2);
    let (host, mcu) = (dir.path().join("host.ply"), dir.path().join("mcu.ply"));
    for (ply, profile) in [(&host, "host"), (&mcu, "mcu")] {
        let o = m2smap(&[
            "export",
            scene.to_str().unwrap(),
            "--frame",
            "1",
            "--profile",
            profile,
            "--ply",
            ply.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let (a, b) = (m2smap::export::read_ply_vertices(&host).unwrap(), m2smap::export::read_ply_vertices(&mcu).unwrap());
    assert!(!b.is_empty() && a.len() != b.len(), "host {} vs mcu {} vertices", a.len(), b.len());
    let png = dir.path().join("mcu.png");
    let o = m2smap(&[
        "render",
        scene.to_str().unwrap(),
        "--frame",
        "1",
        "--profile",
        "mcu",
        "--out",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = m2smap(&[
        "export",
        scene.to_str().unwrap(),
        "--frame",
        "1",
        "--profile",
        "big",
        "--ply",
        host.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && stderr.contains("'big'") && stderr.contains("host, mcu, tiny"), "{stderr}");
}
