//! The synthetic scene generator against closed-form geometry, its mask degradation, its determinism and the
//! visibility of every built-in scene's objects.

mod common;

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

use common::m2smap;
use m2smap::dataset::Camera;
use m2smap::synth::{sq_inside_outside, Degradation, Scene, Shape, Surface, SCENES};

const EYE: [f64; 3] = [0.1, -1.1, 1.25];
const TARGET: [f64; 3] = [0.0, 0.9, 0.25];

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn one_shape_scene(shape: Shape) -> Scene {
    let surface = Surface { name: "s".into(), instance: 1, label: "thing".into(), shape, colour: [128; 3] };
    Scene::custom("probe", vec![surface], Camera::preset("fr3").unwrap(), EYE, TARGET)
}

/// Camera-frame rays of every pixel (z component 1, so a ray parameter is a depth).
fn camera_rays(scene: &Scene) -> Vec<[f64; 3]> {
    let c = scene.camera;
    let (w, h) = (c.width as usize, c.height as usize);
    (0..w * h)
        .map(|i| [((i % w) as f64 - c.cx as f64) / c.fx as f64, ((i / w) as f64 - c.cy as f64) / c.fy as f64, 1.0])
        .collect()
}

/// World point `p` in the camera frame of `scene`'s frame `k`.
fn to_camera(scene: &Scene, k: usize, p: [f64; 3]) -> [f64; 3] {
    let pose = scene.pose(k);
    let r = pose.rotation();
    let d = sub(p, pose.t);
    [
        r[0][0] * d[0] + r[1][0] * d[1] + r[2][0] * d[2],
        r[0][1] * d[0] + r[1][1] * d[1] + r[2][1] * d[2],
        r[0][2] * d[0] + r[1][2] * d[1] + r[2][2] * d[2],
    ]
}

/// World direction `d` in the camera frame of frame `k`.
fn dir_to_camera(scene: &Scene, k: usize, d: [f64; 3]) -> [f64; 3] {
    let t = scene.pose(k).t;
    sub(to_camera(scene, k, [t[0] + d[0], t[1] + d[1], t[2] + d[2]]), to_camera(scene, k, [t[0], t[1], t[2]]))
}

/// Compares the generator's exact depth of frame `k` with `analytic(ray) -> Option<depth>` (camera frame):
/// returns (max |error| over pixels both hit, pixels where only one of them hits, pixels hit).
fn compare(scene: &Scene, k: usize, analytic: impl Fn([f64; 3]) -> Option<f64>) -> (f64, usize, usize) {
    let trace = scene.trace(k);
    let (mut worst, mut disagree, mut hits) = (0.0f64, 0, 0);
    for (i, ray) in camera_rays(scene).into_iter().enumerate() {
        let got = (trace.surface[i] != 0).then_some(trace.depth[i]);
        match (got, analytic(ray)) {
            (Some(a), Some(b)) => {
                worst = worst.max((a - b).abs());
                hits += 1;
            }
            (None, None) => {}
            _ => disagree += 1,
        }
    }
    (worst, disagree, hits)
}

/// Smallest positive root s of |s·ray − c|² = r² (camera frame).
fn ray_sphere(ray: [f64; 3], c: [f64; 3], r: f64) -> Option<f64> {
    let (a, b, cc) = (dot(ray, ray), dot(ray, c), dot(c, c) - r * r);
    let disc = b * b - a * cc;
    (disc >= 0.0).then(|| (b - disc.sqrt()) / a).filter(|&s| s > 0.0)
}

#[test]
fn exact_depth_matches_closed_form_geometry() {
    // Plane z = 0.05: in the camera frame n_c·x = n_c·p0 for a point p0 of the plane.
    let scene = one_shape_scene(Shape::Plane { normal: [0.0, 0.0, 1.0], offset: 0.05 });
    for k in [0, 7] {
        let (n, p0) = (dir_to_camera(&scene, k, [0.0, 0.0, 1.0]), to_camera(&scene, k, [0.0, 0.0, 0.05]));
        let (worst, disagree, hits) = compare(&scene, k, |ray| {
            let denom = dot(n, ray);
            (denom < 0.0).then(|| dot(n, p0) / denom).filter(|&s| s > 0.0)
        });
        println!("plane frame {k}: {hits} pixels hit, max depth error {worst:.3e} m, {disagree} pixels disagree");
        assert!(hits > 2000 && worst <= 1e-4 && disagree == 0, "plane frame {k}: {worst} m, {disagree} disagree");
    }

    // A sphere: smallest positive root in the camera frame.
    let (c, r) = ([0.1, 0.7, 0.25], 0.2);
    let scene = one_shape_scene(Shape::Sphere { centre: c, radius: r });
    for k in [0, 7] {
        let (worst, disagree, hits) = compare(&scene, k, |ray| ray_sphere(ray, to_camera(&scene, k, c), r));
        println!(
            "sphere frame {k}: {hits} pixels hit, max depth error {worst:.3e} m, {disagree} silhouette pixels disagree"
        );
        assert!(hits > 2000 && worst <= 1e-4 && disagree <= 8, "sphere frame {k}: {worst} m, {disagree} disagree");
    }

    // A yawed box: each of its six faces as a bounded plane, nearest hit wins.
    let (centre, half, yaw) = ([-0.1, 0.8, 0.22], [0.2, 0.15, 0.22], 0.3);
    let scene = one_shape_scene(Shape::Box { centre, half, yaw });
    for k in [0, 7] {
        let (c, s) = (f64::cos(yaw), f64::sin(yaw));
        let axes = [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]].map(|a| dir_to_camera(&scene, k, a));
        let centre_c = to_camera(&scene, k, centre);
        let (worst, disagree, hits) = compare(&scene, k, |ray| {
            let mut best: Option<f64> = None;
            for a in 0..3 {
                for sign in [-1.0, 1.0] {
                    let n = axes[a].map(|x| x * sign);
                    let p0 = [0, 1, 2].map(|j| centre_c[j] + n[j] * half[a]);
                    let denom = dot(n, ray);
                    if denom >= 0.0 {
                        continue;
                    }
                    let s = dot(n, p0) / denom;
                    let p = ray.map(|x| x * s);
                    let inside =
                        (0..3).filter(|&b| b != a).all(|b| dot(sub(p, centre_c), axes[b]).abs() <= half[b] + 1e-9);
                    if s > 0.0 && inside && best.filter(|&t| t <= s).is_none() {
                        best = Some(s);
                    }
                }
            }
            best
        });
        println!(
            "box frame {k}: {hits} pixels hit, max depth error {worst:.3e} m, {disagree} silhouette pixels disagree"
        );
        assert!(hits > 2000 && worst <= 1e-4 && disagree <= 8, "box frame {k}: {worst} m, {disagree} disagree");
    }

    // An upright cylinder: lateral quadratic in the world x-y plane plus the top cap.
    let (centre, radius, hh) = ([0.2, 0.8, 0.15], 0.12, 0.15);
    let scene = one_shape_scene(Shape::Cylinder { centre, axis: [0.0, 0.0, 1.0], radius, half_height: hh });
    for k in [0, 7] {
        let pose = scene.pose(k);
        let r = pose.rotation();
        let (worst, disagree, hits) = compare(&scene, k, |ray| {
            let d = [0, 1, 2].map(|j| dot(r[j], ray)); // world direction with camera z = 1
            let o = sub(pose.t, centre);
            let mut best: Option<f64> = None;
            let (a, b, c) =
                (d[0] * d[0] + d[1] * d[1], o[0] * d[0] + o[1] * d[1], o[0] * o[0] + o[1] * o[1] - radius * radius);
            if b * b - a * c >= 0.0 {
                let s = (-b - (b * b - a * c).sqrt()) / a;
                if s > 0.0 && (o[2] + s * d[2]).abs() <= hh {
                    best = Some(s);
                }
            }
            let s = (hh - o[2]) / d[2]; // top cap (the camera is above it)
            let (x, y) = (o[0] + s * d[0], o[1] + s * d[1]);
            if s > 0.0 && x * x + y * y <= radius * radius && best.filter(|&t| t <= s).is_none() {
                best = Some(s);
            }
            best
        });
        println!("cylinder frame {k}: {hits} pixels hit, max depth error {worst:.3e} m, {disagree} silhouette pixels disagree");
        assert!(hits > 2000 && worst <= 1e-4 && disagree <= 8, "cylinder frame {k}: {worst} m, {disagree} disagree");
    }

    // A superquadric with ε1 = ε2 = 1 is an ellipsoid: a sphere after scaling the local axes.
    let (centre, scales, yaw) = ([0.0, 0.8, 0.2], [0.25, 0.15, 0.2], 0.4);
    let scene = one_shape_scene(Shape::Superquadric { centre, scales, eps: [1.0, 1.0], yaw });
    for k in [0, 7] {
        let pose = scene.pose(k);
        let r = pose.rotation();
        let (c, s) = (f64::cos(yaw), f64::sin(yaw));
        let local =
            |v: [f64; 3]| [(c * v[0] + s * v[1]) / scales[0], (-s * v[0] + c * v[1]) / scales[1], v[2] / scales[2]];
        let o = local(sub(pose.t, centre));
        let (worst, disagree, hits) = compare(&scene, k, |ray| {
            let d = local([0, 1, 2].map(|j| dot(r[j], ray)));
            let (a, b, cc) = (dot(d, d), dot(o, d), dot(o, o) - 1.0);
            let disc = b * b - a * cc;
            (disc >= 0.0).then(|| (-b - disc.sqrt()) / a).filter(|&s| s > 0.0)
        });
        println!("ellipsoid SQ frame {k}: {hits} pixels hit, max depth error {worst:.3e} m, {disagree} silhouette pixels disagree");
        assert!(hits > 2000 && worst <= 1e-4 && disagree <= 12, "ellipsoid frame {k}: {worst} m, {disagree} disagree");
    }
}

#[test]
fn superquadric_hits_are_first_crossings_of_the_surface() {
    // A rounded box (ε = 0.3) and a pinched shape (ε1 = 1.5): no closed form, so check that each hit lies on
    // F = 1 and that the ray is outside 0.1 mm before it.
    for (scales, eps) in [([0.2, 0.12, 0.1], [0.3, 0.3]), ([0.15, 0.15, 0.2], [1.5, 0.7])] {
        let (centre, yaw) = ([0.05, 0.8, 0.25], -0.5);
        let shape = Shape::Superquadric { centre, scales, eps, yaw };
        let scene = one_shape_scene(shape);
        let trace = scene.trace(3);
        let r = trace.pose.rotation();
        let (c, s) = (f64::cos(yaw), f64::sin(yaw));
        let local = |p: [f64; 3]| {
            let v = sub(p, centre);
            [c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]]
        };
        let (mut worst_f, mut worst_dist, mut hits) = (0.0f64, 0.0f64, 0);
        for (i, ray) in camera_rays(&scene).into_iter().enumerate() {
            if trace.surface[i] == 0 {
                continue;
            }
            hits += 1;
            let d = [0, 1, 2].map(|j| dot(r[j], ray));
            let at = |z: f64| [0, 1, 2].map(|j| trace.pose.t[j] + z * d[j]);
            let z = trace.depth[i];
            worst_f = worst_f.max((sq_inside_outside(local(at(z)), scales, eps) - 1.0).abs());
            worst_dist = worst_dist.max(shape.distance(at(z)));
            assert!(sq_inside_outside(local(at(z - 1e-4)), scales, eps) > 1.0, "pixel {i}: inside before the hit");
        }
        println!("SQ {scales:?} eps {eps:?}: {hits} pixels, max |F - 1| {worst_f:.2e}, max radial distance {worst_dist:.2e} m");
        assert!(hits > 2000 && worst_f < 1e-5 && worst_dist < 1e-6);
    }
}

#[test]
fn hits_lie_on_the_surfaces_they_report() {
    // Every exact hit of every built-in scene is within 1 µm of its surface by Shape::distance.
    for name in SCENES {
        let scene = Scene::named(name).unwrap();
        let trace = scene.trace(0);
        let r = trace.pose.rotation();
        let mut worst = 0.0f64;
        for (i, ray) in camera_rays(&scene).into_iter().enumerate().step_by(7) {
            if trace.surface[i] == 0 {
                continue;
            }
            let p = [0, 1, 2].map(|j| trace.pose.t[j] + trace.depth[i] * dot(r[j], ray));
            worst = worst.max(scene.surfaces[trace.surface[i] as usize - 1].distance(p));
        }
        println!("{name}: max hit-to-surface distance {worst:.2e} m");
        assert!(worst < 1e-6, "{name}: {worst}");
    }
}

fn read_u16(path: &Path) -> Vec<u16> {
    image::open(path).unwrap().into_luma16().into_raw()
}

fn stems(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir.join("gt"))
        .unwrap()
        .filter_map(|e| e.unwrap().path().file_name().unwrap().to_str().unwrap().strip_suffix(".png").map(String::from))
        .collect();
    v.sort();
    v
}

fn instances(dir: &Path, stem: &str) -> Vec<serde_json::Value> {
    let text = fs::read_to_string(dir.join(format!("masks/{stem}.json"))).unwrap();
    serde_json::from_str::<serde_json::Value>(&text).unwrap()["instances"].as_array().unwrap().clone()
}

fn write(scene: &str, dir: &Path, frames: usize, seed: u32, d: Degradation) -> PathBuf {
    let out = dir.join(format!("{scene}_{seed}_{}_{}_{}_{}", d.erode, d.dilate, d.miss, d.score_noise));
    Scene::named(scene).unwrap().write_tum_degraded(&out, frames, seed, true, &d).unwrap();
    out
}

#[test]
fn perfect_masks_equal_ground_truth_and_degraded_ones_depart_from_it() {
    let tmp = tempfile::tempdir().unwrap();
    let frames = 6;
    let perfect = write("kitchen", tmp.path(), frames, 4, Degradation::default());
    for stem in stems(&perfect) {
        let gt_png = perfect.join(format!("gt/{stem}.png"));
        assert_eq!(fs::read(perfect.join(format!("masks/{stem}.png"))).unwrap(), fs::read(&gt_png).unwrap(), "{stem}");
        let gt = read_u16(&gt_png);
        let visible: BTreeSet<u64> = gt.iter().filter(|&&id| id != 0).map(|&id| id as u64).collect();
        let listed = instances(&perfect, &stem);
        assert_eq!(listed.iter().map(|i| i["id"].as_u64().unwrap()).collect::<BTreeSet<_>>(), visible, "{stem}");
        assert!(listed.iter().all(|i| i["score"].as_f64() == Some(1.0)));
    }
    let objects: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(perfect.join("gt/objects.json")).unwrap()).unwrap();
    assert_eq!(objects["mask_degradation"]["erode"], 0);
    assert!(objects["surfaces"].as_array().unwrap().iter().any(|s| s["shape"]["kind"] == "superquadric"));

    // Erode 2, miss 0.3: every mask pixel keeps its true id, the regions shrink, some instances go missing.
    let eroded = write("kitchen", tmp.path(), frames, 4, Degradation { erode: 2, miss: 0.3, ..Default::default() });
    let (mut gt_px, mut mask_px, mut missed) = (0usize, 0usize, 0usize);
    for stem in stems(&eroded) {
        let gt = read_u16(&eroded.join(format!("gt/{stem}.png")));
        assert_eq!(gt, read_u16(&perfect.join(format!("gt/{stem}.png"))), "gt/ stays exact");
        let mask = read_u16(&eroded.join(format!("masks/{stem}.png")));
        assert!(mask.iter().zip(&gt).all(|(&m, &g)| m == 0 || m == g), "{stem}: eroded mask outside its gt region");
        gt_px += gt.iter().filter(|&&g| g != 0).count();
        mask_px += mask.iter().filter(|&&m| m != 0).count();
        let visible: BTreeSet<u16> = gt.iter().copied().filter(|&g| g != 0).collect();
        let kept: BTreeSet<u16> = mask.iter().copied().filter(|&m| m != 0).collect();
        missed += visible.len() - kept.len();
        let listed: BTreeSet<u16> =
            instances(&eroded, &stem).iter().map(|i| i["id"].as_u64().unwrap() as u16).collect();
        assert_eq!(listed, kept, "{stem}: the json lists exactly the instances left in the image");
    }
    println!("erode 2, miss 0.3: {mask_px} of {gt_px} gt pixels kept, {missed} instance-frames missed");
    assert!(mask_px < gt_px && missed > 0 && missed < 5 * frames);

    // Dilate 2 with score noise: every gt pixel keeps its id, new pixels are within 2 px of the same id.
    let dilated = write("clutter", tmp.path(), 3, 4, Degradation { dilate: 2, score_noise: 0.2, ..Default::default() });
    let w = 640usize;
    let mut scores = Vec::new();
    for stem in stems(&dilated) {
        let gt = read_u16(&dilated.join(format!("gt/{stem}.png")));
        let mask = read_u16(&dilated.join(format!("masks/{stem}.png")));
        let mut grown = 0;
        for (i, (&m, &g)) in mask.iter().zip(&gt).enumerate() {
            if g != 0 {
                assert_eq!(m, g, "{stem}: dilation overwrote pixel {i}");
            } else if m != 0 {
                grown += 1;
                let (u, v) = ((i % w) as i64, (i / w) as i64);
                let near = (-2i64..=2)
                    .flat_map(|du| (-2i64..=2).map(move |dv| (du, dv)))
                    .filter(|(du, dv)| du.abs() + dv.abs() <= 2)
                    .any(|(du, dv)| {
                        let (x, y) = (u + du, v + dv);
                        (0..640).contains(&x) && (0..480).contains(&y) && gt[(y as usize) * w + x as usize] == m
                    });
                assert!(near, "{stem}: pixel {i} grew from nowhere");
            }
        }
        assert!(grown > 0, "{stem}: dilation grew nothing");
        scores.extend(instances(&dilated, &stem).iter().map(|i| i["score"].as_f64().unwrap()));
    }
    println!("score noise 0.2: scores {scores:.3?}");
    assert!(scores.iter().all(|s| (0.05..=1.0).contains(s)) && scores.iter().any(|&s| s < 0.999));
}

/// Every file under `dir`, relative path → bytes.
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else {
                out.insert(p.strip_prefix(dir).unwrap().to_path_buf(), fs::read(&p).unwrap());
            }
        }
    }
    out
}

#[test]
fn same_seed_gives_identical_files_and_another_seed_other_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let d = Degradation { erode: 1, dilate: 1, miss: 0.2, score_noise: 0.1 };
    let scene = Scene::named("clutter").unwrap();
    let (a, b, c) = (tmp.path().join("a"), tmp.path().join("b"), tmp.path().join("c"));
    scene.write_tum_degraded(&a, 3, 11, true, &d).unwrap();
    scene.write_tum_degraded(&b, 3, 11, true, &d).unwrap();
    scene.write_tum_degraded(&c, 3, 12, true, &d).unwrap();
    let (fa, fb, fc) = (files(&a), files(&b), files(&c));
    assert_eq!(
        fa.len(),
        4 + 3 * 5 + 1,
        "rgb.txt, depth.txt, groundtruth.txt, camera.json, 3 frames × (rgb, depth, gt, mask png + json), objects.json"
    );
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (name, bytes) in &fa {
        assert!(bytes == &fb[name], "{} differs between two runs with the same seed", name.display());
    }
    let depth: Vec<&PathBuf> = fa.keys().filter(|p| p.starts_with("depth")).collect();
    assert!(depth.iter().all(|p| fa[*p] != fc[*p]), "another seed gives other depth");
    // And through the command, with the flags.
    let (x, y) = (tmp.path().join("x"), tmp.path().join("y"));
    for out in [&x, &y] {
        let o = m2smap(&[
            "synth",
            "--scene",
            "kitchen",
            "--frames",
            "2",
            "--seed",
            "5",
            "--mask-erode",
            "1",
            "--mask-miss",
            "0.5",
            "--mask-score-noise",
            "0.1",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert_eq!(files(&x), files(&y));
    let o = m2smap(&[
        "synth",
        "--scene",
        "kitchen",
        "--frames",
        "1",
        "--mask-miss",
        "1.5",
        "--out",
        tmp.path().join("z").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("miss") && !err.contains("panicked"), "{err}");
}

#[test]
fn every_scene_shows_every_object_along_its_path() {
    // Frame 0, and every 6th frame of the first 60 (the sway of the camera path covers its range in ~42 frames).
    for name in SCENES {
        let scene = Scene::named(name).unwrap();
        let objects: BTreeSet<u16> = scene.surfaces.iter().map(|s| s.instance).filter(|&id| id != 0).collect();
        let mut fewest: BTreeMap<u16, (usize, usize)> = BTreeMap::new();
        for k in (0..=60).step_by(6) {
            let ids = scene.instance_image(&scene.render(k, None));
            for &id in &objects {
                let n = ids.iter().filter(|&&x| x == id).count();
                if k == 0 {
                    println!("{name} frame 0: object {id} has {n} pixels");
                }
                let e = fewest.entry(id).or_insert((n, k));
                if n < e.0 {
                    *e = (n, k);
                }
            }
        }
        println!("{name}: fewest pixels per object over frames 0..=60 (pixels, frame) {fewest:?}");
        for (id, (n, k)) in fewest {
            assert!(n >= 500, "{name}: object {id} has {n} pixels in frame {k}");
        }
    }
}

/// Whether `p` lies inside the solid `shape` shrunk by `margin` metres (planes are never solid here).
fn inside(shape: &Shape, p: [f64; 3], margin: f64) -> bool {
    match *shape {
        Shape::Plane { .. } => false,
        Shape::Box { centre, half, yaw } => {
            let (c, s, d) = (f64::cos(yaw), f64::sin(yaw), sub(p, centre));
            let l = [c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]];
            (0..3).all(|k| l[k].abs() < half[k] - margin)
        }
        Shape::Cylinder { centre, axis, radius, half_height } => {
            let d = sub(p, centre);
            let along = dot(d, axis);
            let radial = dot(d, d) - along * along;
            along.abs() < half_height - margin && radial.sqrt() < radius - margin
        }
        Shape::Sphere { centre, radius } => dot(sub(p, centre), sub(p, centre)).sqrt() < radius - margin,
        Shape::Superquadric { centre, scales, eps, yaw } => {
            let (c, s, d) = (f64::cos(yaw), f64::sin(yaw), sub(p, centre));
            sq_inside_outside([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]], scales, eps) < 1.0
                && shape.distance(p) > margin
        }
    }
}

/// Axis-aligned bounds (lo, hi) of a solid, loose for rotated shapes; `None` for planes.
fn bounds(shape: &Shape) -> Option<([f64; 3], [f64; 3])> {
    let around = |c: [f64; 3], r: f64| Some(([c[0] - r, c[1] - r, c[2] - r], [c[0] + r, c[1] + r, c[2] + r]));
    match *shape {
        Shape::Plane { .. } => None,
        Shape::Box { centre, half, .. } => {
            let r = f64::hypot(half[0], half[1]);
            Some((
                [centre[0] - r, centre[1] - r, centre[2] - half[2]],
                [centre[0] + r, centre[1] + r, centre[2] + half[2]],
            ))
        }
        Shape::Cylinder { centre, radius, half_height, .. } => around(centre, f64::hypot(radius, half_height)),
        Shape::Sphere { centre, radius } => around(centre, radius),
        Shape::Superquadric { centre, scales, .. } => around(centre, dot(scales, scales).sqrt()),
    }
}

#[test]
fn dining_table_is_one_masked_instance_and_no_solids_overlap() {
    let scene = Scene::named("dining").unwrap();
    // The table: top and four legs, one object instance with one label.
    let table: Vec<&Surface> = scene.surfaces.iter().filter(|s| s.label == "dining table").collect();
    assert_eq!(table.len(), 5);
    assert!(table[0].instance != 0 && table.iter().all(|s| s.instance == table[0].instance));
    assert_eq!(scene.surfaces.iter().filter(|s| s.instance == table[0].instance).count(), 5);
    let top = table.iter().find(|s| s.name == "table_top").unwrap();
    let Shape::Box { centre, half, .. } = top.shape else { panic!("table top is a box") };
    assert!((centre[2] + half[2] - 0.74).abs() < 1e-9 && (half[2] - 0.02).abs() < 1e-9);
    // Every other object is its own instance: the box, the can, the two boxes of the stack and the floor crate.
    let others: BTreeSet<u16> =
        scene.surfaces.iter().map(|s| s.instance).filter(|&i| i != 0 && i != table[0].instance).collect();
    assert_eq!(others.len(), 5);

    // No two solids share interior volume (touching is fine): a 2 mm grid over each pair's common bounds, each
    // solid shrunk by 0.5 mm.
    let solids: Vec<&Surface> = scene.surfaces.iter().filter(|s| bounds(&s.shape).is_some()).collect();
    for (a, sa) in solids.iter().enumerate() {
        for sb in &solids[a + 1..] {
            let ((lo_a, hi_a), (lo_b, hi_b)) = (bounds(&sa.shape).unwrap(), bounds(&sb.shape).unwrap());
            let (lo, hi) = ([0, 1, 2].map(|k| lo_a[k].max(lo_b[k])), [0, 1, 2].map(|k| hi_a[k].min(hi_b[k])));
            if (0..3).any(|k| lo[k] >= hi[k]) {
                continue;
            }
            let n = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / 0.002).ceil() as usize + 1);
            for i in 0..n[0] * n[1] * n[2] {
                let (x, y, z) = (i % n[0], (i / n[0]) % n[1], i / (n[0] * n[1]));
                let p = [lo[0] + 0.002 * x as f64, lo[1] + 0.002 * y as f64, lo[2] + 0.002 * z as f64];
                assert!(
                    !(inside(&sa.shape, p, 5e-4) && inside(&sb.shape, p, 5e-4)),
                    "{} and {} overlap at {p:?}",
                    sa.name,
                    sb.name
                );
            }
        }
    }
    // Nothing sinks into the floor or the wall.
    for s in &solids {
        let (lo, hi) = bounds(&s.shape).unwrap();
        assert!(lo[2] >= -1e-9 && hi[1] <= 1.7, "{}", s.name);
    }

    // gt/objects.json lists every surface with its instance; the masks carry the table as one instance.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("dining");
    scene.write_tum(&out, 2, 1, false).unwrap();
    let objects: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(out.join("gt/objects.json")).unwrap()).unwrap();
    let listed = objects["surfaces"].as_array().unwrap();
    assert_eq!(objects["scene"], "dining");
    assert_eq!(listed.len(), scene.surfaces.len());
    for (json, s) in listed.iter().zip(&scene.surfaces) {
        assert_eq!(json["name"], s.name.as_str());
        assert_eq!(json["instance"].as_u64(), Some(s.instance as u64), "{}", s.name);
    }
    for stem in stems(&out) {
        let tables: Vec<serde_json::Value> =
            instances(&out, &stem).into_iter().filter(|i| i["label"] == "dining table").collect();
        assert_eq!(tables.len(), 1, "{stem}: the table is one instance");
        assert_eq!(tables[0]["id"].as_u64(), Some(table[0].instance as u64));
    }
}
