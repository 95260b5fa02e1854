//! Renders and PLY exports: the PNG's panels show the frame itself and a map that covers what it measured; PLY
//! files load back with every vertex.

mod common;

use std::path::Path;

use common::m2smap;

/// Checks a 2 x 2 render of frame `k` of `dataset` (masks from its files, or from the geometric segmenter when
/// `segmenter`) against that frame: (a) is the frame's own colour image, exactly, wherever no mask tints it;
/// (b) and (c) show the frame darkened to 30 % wherever it has no depth in range, and are mostly drawn; (d), the
/// ray-cast map, covers most of the pixels with depth in range.
fn check_render(png: &Path, dataset: &Path, k: usize, segmenter: bool) {
    use m2smap::run::{map_frame, MaskSource, SegmenterBuffers};
    let img = image::open(png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1280, 960), "2 x 2 panels of 640 x 480");
    let d = m2smap::dataset::Dataset::open(dataset, None).unwrap();
    // The frame and its masks as `render` maps them (a fresh mapper, that frame alone).
    let mut storage = bytemuck::zeroed_box::<m2smap_core::HostStorage>();
    let mut mapper = m2smap_core::Mapper::new(&mut *storage, m2smap_core::Params::default()).unwrap();
    let dir = dataset.join("masks");
    let source = if segmenter { MaskSource::Segmenter } else { MaskSource::Files(Some(&dir)) };
    let mapped =
        map_frame(&mut mapper, &d, k, source, &mut Default::default(), &mut SegmenterBuffers::default()).unwrap();
    let (f, masks) = (mapped.loaded, mapped.masks.expect("masks"));
    let masked = |x: u32, y: u32| masks.id_at(x as u16, y as u16) != 0;
    let (lo, hi) = f.view(&d.camera).raw_range(&m2smap_core::Params::default());
    let rgb = |x: u32, y: u32| {
        let i = 3 * (y * 640 + x) as usize;
        [f.colour[i], f.colour[i + 1], f.colour[i + 2]]
    };
    let in_range = |x: u32, y: u32| (lo..=hi).contains(&f.depth[(y * 640 + x) as usize]);
    // Away from the legend strips (the top 40 rows of each panel).
    let pixels = || (40..480u32).flat_map(|y| (0..640u32).map(move |x| (x, y)));
    // (a): the colour image itself where no mask tints it.
    let unmasked: Vec<(u32, u32)> = pixels().filter(|&(x, y)| !masked(x, y)).collect();
    let wrong = unmasked.iter().filter(|&&(x, y)| img.get_pixel(x, y).0 != rgb(x, y)).count();
    assert!(
        unmasked.len() > 10_000 && wrong == 0,
        "panel (a): {wrong} of {} unmasked pixels are not the frame's colour",
        unmasked.len()
    );
    for (px, py) in [(640, 0), (0, 480)] {
        // (b), (c): pixels without depth in range hold no label: the frame's colour darkened to 30 %.
        let (mut no_depth, mut off) = (0, 0);
        let mut drawn = 0;
        for (x, y) in pixels() {
            let c = img.get_pixel(px + x, py + y).0;
            drawn += (c != [0, 0, 0]) as u32;
            if !in_range(x, y) {
                no_depth += 1;
                off += rgb(x, y).iter().zip(c).any(|(&a, b)| (a as f32 * 0.3 - b as f32).abs() > 1.0) as u32;
            }
        }
        assert_eq!(
            off, 0,
            "panel at ({px}, {py}): {off} of {no_depth} pixels without depth are not the darkened frame"
        );
        assert!(drawn * 2 >= 440 * 640, "panel at ({px}, {py}) is mostly empty: {drawn} pixels drawn");
    }
    // (d): the map covers most of what the camera measured.
    let measured: Vec<(u32, u32)> = pixels().filter(|&(x, y)| in_range(x, y)).collect();
    let covered = measured.iter().filter(|&&(x, y)| img.get_pixel(640 + x, 480 + y).0 != [0, 0, 0]).count();
    let share = covered as f64 / measured.len() as f64;
    println!("{}: panel (d) covers {:.3} of {} pixels with depth", png.display(), share, measured.len());
    // Measured: 0.97 (cabinet frame 10) to 0.996 (tabletop); an empty, shifted or mis-scaled map falls far below.
    assert!(
        measured.len() > 10_000 && share >= 0.9,
        "panel (d) covers only {:.1} % of the pixels with depth",
        100.0 * share
    );
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
    check_render(&png, &scene, 2, false);
    // Without masks the segmenter supplies them: the render still shows objects.
    let o = m2smap(&[
        "render",
        scene.to_str().unwrap(),
        "--frame",
        "1",
        "--segmenter",
        "geometric",
        "--out",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    check_render(&png, &scene, 1, true);

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
    let mut floor: Vec<f64> =
        world.iter().filter(|v| v.kind == 0 && v.xyz[2].abs() < 0.1).map(|v| v.xyz[2].abs()).collect();
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
    check_render(&png, &data, 10, false);
}

/// The instance-mask ids of frame `k` of a dataset folder (0 = none), row-major.
fn mask_ids(dataset: &Path, k: usize) -> Vec<u16> {
    let d = m2smap::dataset::Dataset::open(dataset, None).unwrap();
    let (w, h) = (d.camera.width, d.camera.height);
    let mut labels = m2smap::masks::LabelTable::default();
    let masks =
        m2smap::masks::read_frame_masks(&dataset.join("masks"), &d.frames[k].stem, w, h, &mut labels).unwrap().unwrap();
    (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| masks.id_at(x, y)).collect()
}

/// Per mask instance of panel (d) (origin (640, 480)): (pixels, drawn, drawn as a superquadric: green the
/// largest channel, distinct colours among its drawn pixels).
fn map_panel_by_instance(
    img: &image::RgbImage,
    ids: &[u16],
) -> std::collections::BTreeMap<u16, (usize, usize, usize, usize)> {
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
    assert!(m2smap(&[
        "synth",
        "--scene",
        "tabletop",
        "--frames",
        "6",
        "--seed",
        "3",
        "--out",
        scene.to_str().unwrap()
    ])
    .status
    .success());
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
    let black = (20..480)
        .flat_map(|y| (640..1280).map(move |x| (x, y)))
        .filter(|&(x, y)| img.get_pixel(x, y).0 == [0, 0, 0])
        .count();
    let share = black as f64 / (460.0 * 640.0);
    assert!(share < 0.06, "panel (b) is {:.1} % black", 100.0 * share);
}

/// `render --view orbit` draws the map from four sides of its objects, `--view top` from above; both show the
/// superquadrics; `--angle` picks one side and goes only with orbit.
#[test]
fn render_views_the_map_from_around_and_above() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    assert!(m2smap(&["synth", "--scene", "tabletop", "--frames", "3", "--out", scene.to_str().unwrap()])
        .status
        .success());
    let png = dir.path().join("v.png");
    let greens = |img: &image::RgbImage, x0: u32, y0: u32| {
        (y0 + 20..y0 + 480)
            .flat_map(|y| (x0..x0 + 640).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let c = img.get_pixel(x, y).0;
                c[1] > c[0] && c[1] > c[2] && c[1] > 60
            })
            .count()
    };
    let camera = dir.path().join("c.png");
    assert!(m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--out", camera.to_str().unwrap()])
        .status
        .success());
    let camera = image::open(&camera).unwrap().to_rgb8();
    let seen = greens(&camera, 640, 480);
    let o =
        m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--view", "orbit", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1280, 960));
    for (x0, y0) in [(0, 0), (640, 0), (0, 480), (640, 480)] {
        let g = greens(&img, x0, y0);
        assert!(g > 2000, "orbit panel at ({x0}, {y0}): {g} superquadric pixels");
    }
    let o =
        m2smap(&["render", scene.to_str().unwrap(), "--frame", "2", "--view", "top", "--out", png.to_str().unwrap()]);
    assert!(o.status.success());
    let top = image::open(&png).unwrap().to_rgb8();
    assert_eq!(top.dimensions(), (640, 480));
    assert!(greens(&top, 0, 0) > 1000, "the boxes' tops seen from above");
    let o = m2smap(&[
        "render",
        scene.to_str().unwrap(),
        "--frame",
        "2",
        "--view",
        "orbit",
        "--angle",
        "180",
        "--out",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    let back = image::open(&png).unwrap().to_rgb8();
    assert_eq!(back.dimensions(), (640, 480));
    assert_ne!(
        back.as_raw(),
        image::imageops::crop_imm(&camera, 640, 480, 640, 480).to_image().as_raw(),
        "the back differs from the front"
    );
    assert!(greens(&back, 0, 0) > 1000 && seen > 1000);
    common::expect_failure(
        &[
            "render",
            scene.to_str().unwrap(),
            "--frame",
            "2",
            "--view",
            "top",
            "--angle",
            "30",
            "--out",
            png.to_str().unwrap(),
        ],
        &["--angle"],
    );
}

/// `ycbv_0000` frame 0 (real, close range, ground-truth masks): panel (d) covers every masked object.
#[test]
fn a_close_range_real_frame_shows_every_object_solid() {
    let Some(data) = common::shared_data("ycbv_0000") else { return };
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("ycbv.png");
    let o = m2smap(&["render", data.to_str().unwrap(), "--frame", "0", "--out", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    check_render(&png, &data, 0, false);
    let img = image::open(&png).unwrap().to_rgb8();
    let per = map_panel_by_instance(&img, &mask_ids(&data, 0));
    assert!(per.len() >= 3, "{per:?}");
    for (id, (n, drawn, _, shades)) in per {
        assert!(
            drawn as f64 >= 0.9 * n as f64 && shades >= 20,
            "object {id}: {drawn} of {n} pixels drawn, {shades} shades"
        );
    }
}

/// `render --frame K` maps frames 0..K first (the superquadric tracks warm up as in `run`), so the picture's map
/// is the one `run` reports for frame K.
#[test]
fn render_shows_the_map_run_has_at_that_frame() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    assert!(m2smap(&["synth", "--scene", "clutter", "--frames", "4", "--out", scene.to_str().unwrap()])
        .status
        .success());
    let run = dir.path().join("run");
    assert!(m2smap(&["run", scene.to_str().unwrap(), "--out", run.to_str().unwrap()]).status.success());
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(run.join("frames.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for k in [0usize, 3] {
        let png = dir.path().join(format!("f{k}.png"));
        let o = m2smap(&["render", scene.to_str().unwrap(), "--frame", &k.to_string(), "--out", png.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let p = &lines[k]["primitives"];
        // The payload tells a warm map from a cold one (clutter frame 3: 475 against 474 bytes).
        let expected = format!(
            "frame {k}: {} planes, {} SQs, {} GMMs, {} bytes",
            p["plane"].as_f64().unwrap(),
            p["sq"].as_f64().unwrap(),
            p["gmm"].as_f64().unwrap(),
            lines[k]["payload_bytes"].as_f64().unwrap()
        );
        assert!(
            String::from_utf8_lossy(&o.stdout).starts_with(&expected),
            "{} vs {expected}",
            String::from_utf8_lossy(&o.stdout)
        );
    }
}
