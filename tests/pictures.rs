//! Renders and PLY exports: the PNG has four non-empty panels; PLY files load back with every vertex.

mod common;

use std::path::Path;

use common::m2smap;

fn check_render(png: &Path) {
    let img = image::open(png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1280, 960), "2 x 2 panels of 640 x 480");
    for (px, py) in [(0, 0), (640, 0), (0, 480), (640, 480)] {
        // A panel is non-empty when, away from its legend strip, most of it is drawn (not black) in several colours.
        let mut colours = std::collections::HashSet::new();
        let (mut drawn, mut total) = (0, 0);
        for y in (py + 40..py + 480).step_by(7) {
            for x in (px..px + 640).step_by(7) {
                let c = img.get_pixel(x, y).0;
                colours.insert(c);
                drawn += (c != [0, 0, 0]) as u32;
                total += 1;
            }
        }
        assert!(colours.len() >= 3, "panel at ({px}, {py}) has only {} colours", colours.len());
        assert!(drawn * 2 >= total, "panel at ({px}, {py}) is mostly empty: {drawn} of {total}");
    }
}

#[test]
fn renders_and_exports_a_synthetic_frame() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let o = m2smap(&["synth", "--scene", "tabletop", "--frames", "3", "--out", scene.to_str().unwrap()]);
    assert!(o.status.success());
    let png = dir.path().join("f.png");
    let o = m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    check_render(&png);
    // Without masks the segmenter supplies them: the render still shows objects.
    let o = m2smap(&["render", scene.to_str().unwrap(), "--frame", "1", "--segmenter", "geometric", "--out", png.to_str().unwrap()]);
    assert!(o.status.success());
    check_render(&png);

    let ply = dir.path().join("f.ply");
    let o = m2smap(&["export", scene.to_str().unwrap(), "--frame", "2", "--ply", ply.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let printed: usize = String::from_utf8_lossy(&o.stdout)
        .lines()
        .last()
        .and_then(|l| l.split_whitespace().nth(2))
        .and_then(|n| n.parse().ok())
        .unwrap();
    let vertices = m2smap::export::read_ply_vertices(&ply).unwrap();
    assert_eq!(vertices.len(), printed);
    assert!(vertices.len() > 500);
    for kind in [0u8, 1, 2] {
        assert!(vertices.iter().any(|v| v.kind == kind), "kind {kind} present (plane, SQ, Gaussian)");
    }
    assert!(vertices.iter().any(|v| v.instance > 0) && vertices.iter().any(|v| v.instance == -1));
    // World coordinates with the poses, and every frame.
    let all = dir.path().join("all");
    let o = m2smap(&["export", scene.to_str().unwrap(), "--all-frames", "--world", "--ply", all.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let files: Vec<_> = std::fs::read_dir(&all).unwrap().collect();
    assert_eq!(files.len(), 3);
    // The floor is z = 0 in the synthetic world: plane vertices in world coordinates lie on it.
    let world = m2smap::export::read_ply_vertices(&all.join("frame_000002.ply")).unwrap();
    let mut floor: Vec<f64> = world.iter().filter(|v| v.kind == 0 && v.xyz[2].abs() < 0.1).map(|v| v.xyz[2].abs()).collect();
    floor.sort_by(f64::total_cmp);
    assert!(floor.len() > 100, "floor plane vertices in world coordinates");
    let (median, p95) = (floor[floor.len() / 2], floor[floor.len() * 95 / 100]);
    assert!(median < 0.005 && p95 < 0.02, "floor cells off z = 0: median {median:.4}, 95th percentile {p95:.4} m");
}

#[test]
fn renders_a_cabinet_frame() {
    let Some(data) = common::shared_data("tum_fr3_cabinet") else { return };
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("cabinet.png");
    let o = m2smap(&["render", data.to_str().unwrap(), "--frame", "10", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    check_render(&png);
}

/// The instance-mask ids of frame `k` of a dataset folder (0 = none), row-major.
fn mask_ids(dataset: &Path, k: usize) -> Vec<u16> {
    let d = m2smap::dataset::Dataset::open(dataset, None).unwrap();
    let (w, h) = (d.camera.width, d.camera.height);
    let mut labels = m2smap::masks::LabelTable::default();
    let masks = m2smap::masks::read_frame_masks(&dataset.join("masks"), &d.frames[k].stem, w, h, &mut labels).unwrap().unwrap();
    (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| masks.id_at(x, y)).collect()
}

/// Per mask instance of panel (d) (origin (640, 480)): (pixels, drawn, drawn as a superquadric: green the
/// largest channel, distinct colours among its drawn pixels).
fn map_panel_by_instance(img: &image::RgbImage, ids: &[u16]) -> std::collections::BTreeMap<u16, (usize, usize, usize, usize)> {
    let mut out = std::collections::BTreeMap::new();
    let mut shades: std::collections::BTreeMap<u16, std::collections::HashSet<[u8; 3]>> = Default::default();
    for (i, &id) in ids.iter().enumerate().filter(|(_, &id)| id != 0) {
        let c = img.get_pixel(640 + (i % 640) as u32, 480 + (i / 640) as u32).0;
        let e = out.entry(id).or_insert((0, 0, 0, 0));
        e.0 += 1;
        if c != [0, 0, 0] {
            e.1 += 1;
            shades.entry(id).or_default().insert(c);
        }
        e.2 += (c[1] > c[0] && c[1] > c[2]) as usize;
    }
    for (id, e) in out.iter_mut() {
        e.3 = shades.get(id).map_or(0, |s| s.len());
    }
    out
}

/// Panel (d) ray-casts the primitives: every object of a synthetic frame is a solid, shaded superquadric (no
/// gaps between samples), and panel (b) shows clusters, not the sampling pattern.
#[test]
fn the_map_panel_draws_objects_as_solid_shaded_shapes() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    assert!(m2smap(&["synth", "--scene", "tabletop", "--frames", "6", "--seed", "3", "--out", scene.to_str().unwrap()]).status.success());
    let png = dir.path().join("f.png");
    let o = m2smap(&["render", scene.to_str().unwrap(), "--frame", "5", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&png).unwrap().to_rgb8();
    let ids = mask_ids(&scene, 5);
    let per = map_panel_by_instance(&img, &ids);
    assert!(per.len() >= 2, "the tabletop has two boxes: {per:?}");
    for (id, (n, drawn, green, shades)) in per {
        assert!(drawn as f64 >= 0.97 * n as f64, "object {id}: {drawn} of {n} pixels drawn");
        assert!(green as f64 >= 0.9 * n as f64, "object {id}: {green} of {n} pixels in the superquadric colour");
        assert!(shades >= 20, "object {id}: {shades} shades (a shaded solid has many)");
    }
    // Panel (b): black only on borders between supervoxels (≈ 3 % of the panel), not on unsampled pixels.
    let black = (20..480).flat_map(|y| (640..1280).map(move |x| (x, y))).filter(|&(x, y)| img.get_pixel(x, y).0 == [0, 0, 0]).count();
    let share = black as f64 / (460.0 * 640.0);
    assert!(share < 0.06, "panel (b) is {:.1} % black", 100.0 * share);
}

/// `render --view orbit` draws the map from four sides of its objects, `--view top` from above; both show the
/// superquadrics; `--angle` picks one side and goes only with orbit.
#[test]
fn render_views_the_map_from_around_and_above() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    assert!(m2smap(&["synth", "--scene", "tabletop", "--frames", "3", "--out", scene.to_str().unwrap()]).status.success());
    let png = dir.path().join("v.png");
    let greens = |img: &image::RgbImage, x0: u32, y0: u32| {
        (y0 + 20..y0 + 480).flat_map(|y| (x0..x0 + 640).map(move |x| (x, y))).filter(|&(x, y)| {
            let c = img.get_pixel(x, y).0;
            c[1] > c[0] && c[1] > c[2] && c[1] > 60
        }).count()
    };
    let camera = dir.path().join("c.png");
    assert!(m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--out", camera.to_str().unwrap()]).status.success());
    let camera = image::open(&camera).unwrap().to_rgb8();
    let seen = greens(&camera, 640, 480);
    let o = m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--view", "orbit", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1280, 960));
    for (x0, y0) in [(0, 0), (640, 0), (0, 480), (640, 480)] {
        let g = greens(&img, x0, y0);
        assert!(g > 2000, "orbit panel at ({x0}, {y0}): {g} superquadric pixels");
    }
    let o = m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--view", "top", "--out", png.to_str().unwrap()]);
    assert!(o.status.success());
    let top = image::open(&png).unwrap().to_rgb8();
    assert_eq!(top.dimensions(), (640, 480));
    assert!(greens(&top, 0, 0) > 1000, "the boxes' tops seen from above");
    let o = m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--view", "orbit", "--angle", "180", "--out", png.to_str().unwrap()]);
    assert!(o.status.success());
    let back = image::open(&png).unwrap().to_rgb8();
    assert_eq!(back.dimensions(), (640, 480));
    assert_ne!(back.as_raw(), image::imageops::crop_imm(&camera, 640, 480, 640, 480).to_image().as_raw(), "the back differs from the front");
    assert!(greens(&back, 0, 0) > 1000 && seen > 1000);
    common::expect_failure(&["render", scene.to_str().unwrap(), "--frame", "2", "--view", "top", "--angle", "30", "--out", png.to_str().unwrap()], &["--angle"]);
}

/// `ycbv_0000` frame 0 (real, close range, ground-truth masks): panel (d) covers every masked object.
#[test]
fn a_close_range_real_frame_shows_every_object_solid() {
    let Some(data) = common::shared_data("ycbv_0000") else { return };
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("ycbv.png");
    let o = m2smap(&["render", data.to_str().unwrap(), "--frame", "0", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    check_render(&png);
    let img = image::open(&png).unwrap().to_rgb8();
    let per = map_panel_by_instance(&img, &mask_ids(&data, 0));
    assert!(per.len() >= 3, "{per:?}");
    for (id, (n, drawn, _, shades)) in per {
        assert!(drawn as f64 >= 0.9 * n as f64 && shades >= 20, "object {id}: {drawn} of {n} pixels drawn, {shades} shades");
    }
}
