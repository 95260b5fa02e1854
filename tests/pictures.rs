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
