//! Mask readers: the id-image + JSON format and YOLO segmentation text, good and malformed.

use std::fs;
use std::path::Path;

use m2smap::masks::{read_frame_masks, LabelTable, Pixels};

fn write_ids(path: &Path, w: u32, h: u32, ids: &[u16]) {
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, ids.to_vec()).unwrap().save(path).unwrap();
}

fn ids_16x8() -> Vec<u16> {
    let mut ids = vec![0u16; 16 * 8];
    for v in 1..4 {
        for u in 2..6 {
            ids[v * 16 + u] = 1;
        }
    }
    ids[7 * 16 + 15] = 7;
    ids
}

const JSON: &str = r#"{"instances": [{"id": 1, "label": "cabinet", "score": 0.9, "bbox": [2, 1, 5, 3]},
                                   {"id": 7, "label": "cup", "score": 0.6, "bbox": [15, 7, 15, 7]}]}"#;

/// Mask producers often write more fields than the format needs (an instance's `area`, a file's `image_id`):
/// they are ignored, the instances read the same.
#[test]
fn extra_fields_in_the_mask_json_are_ignored() {
    let dir = tempfile::tempdir().unwrap();
    write_ids(&dir.path().join("f.png"), 16, 8, &ids_16x8());
    let json = r#"{"image_id": 12, "instances": [{"id": 1, "label": "cabinet", "score": 0.9, "bbox": [2, 1, 5, 3], "area": 12},
                  {"id": 7, "label": "cup", "score": 0.6, "bbox": [15, 7, 15, 7], "area": 1}]}"#;
    fs::write(dir.path().join("f.json"), json).unwrap();
    let mut labels = LabelTable::default();
    let m = read_frame_masks(dir.path(), "f", 16, 8, &mut labels).unwrap().unwrap();
    assert_eq!(m.instances.len(), 2);
    assert_eq!((m.id_at(3, 2), m.id_at(15, 7)), (1, 7));
}

#[test]
fn reads_id_images_with_their_instance_lists() {
    let dir = tempfile::tempdir().unwrap();
    write_ids(&dir.path().join("f.png"), 16, 8, &ids_16x8());
    fs::write(dir.path().join("f.json"), JSON).unwrap();
    let mut labels = LabelTable::default();
    let m = read_frame_masks(dir.path(), "f", 16, 8, &mut labels).unwrap().unwrap();
    assert_eq!(m.instances.len(), 2);
    assert_eq!((m.instances[1].id, labels.name(m.instances[1].class), m.instances[1].score), (7, "cup", 0.6));
    assert_eq!((m.id_at(3, 2), m.id_at(15, 7), m.id_at(0, 0)), (1, 7, 0));
    // An 8-bit id image reads the same.
    let ids8: Vec<u8> = ids_16x8().iter().map(|&x| x as u8).collect();
    image::GrayImage::from_raw(16, 8, ids8).unwrap().save(dir.path().join("g.png")).unwrap();
    fs::write(dir.path().join("g.json"), JSON).unwrap();
    let g = read_frame_masks(dir.path(), "g", 16, 8, &mut labels).unwrap().unwrap();
    assert_eq!(g.pixels, m.pixels);
    // A frame without a mask file has no instances; that is not an error.
    assert!(read_frame_masks(dir.path(), "absent", 16, 8, &mut labels).unwrap().is_none());
}

fn expect_err(dir: &Path, stem: &str, w: u16, h: u16, needle: &str) {
    let err = read_frame_masks(dir, stem, w, h, &mut LabelTable::default()).unwrap_err().to_string();
    assert!(err.contains(needle), "{err:?} should mention {needle:?}");
    assert!(!err.contains('\n'), "one line: {err:?}");
}

#[test]
fn malformed_id_masks_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Wrong size.
    write_ids(&d.join("size.png"), 16, 8, &ids_16x8());
    fs::write(d.join("size.json"), JSON).unwrap();
    expect_err(d, "size", 32, 8, "size.png: mask is 16x8 but the frame is 32x8");
    // An id in the image that the JSON does not list.
    write_ids(&d.join("missing.png"), 16, 8, &ids_16x8());
    fs::write(
        d.join("missing.json"),
        r#"{"instances": [{"id": 1, "label": "a", "score": 0.9, "bbox": [2, 1, 5, 3]}]}"#,
    )
    .unwrap();
    expect_err(d, "missing", 16, 8, "mask id 7 has no entry");
    // Scores outside [0, 1].
    for (stem, score) in [("hi", "1.5"), ("neg", "-0.1")] {
        write_ids(&d.join(format!("{stem}.png")), 16, 8, &ids_16x8());
        fs::write(d.join(format!("{stem}.json")), JSON.replace("0.6", score)).unwrap();
        expect_err(d, stem, 16, 8, "outside [0, 1]");
    }
    // Empty files.
    write_ids(&d.join("emptyjson.png"), 16, 8, &ids_16x8());
    fs::write(d.join("emptyjson.json"), "").unwrap();
    expect_err(d, "emptyjson", 16, 8, "emptyjson.json: malformed instance list");
    fs::write(d.join("emptypng.png"), "").unwrap();
    fs::write(d.join("emptypng.json"), JSON).unwrap();
    expect_err(d, "emptypng", 16, 8, "emptypng.png");
    // The JSON beside the image is missing.
    write_ids(&d.join("nojson.png"), 16, 8, &ids_16x8());
    expect_err(d, "nojson", 16, 8, "nojson.json: cannot read");
    // A box outside the image.
    write_ids(&d.join("box.png"), 16, 8, &ids_16x8());
    fs::write(d.join("box.json"), JSON.replace("[15, 7, 15, 7]", "[20, 9, 25, 12]")).unwrap();
    expect_err(d, "box", 16, 8, "out-of-image box");
}

#[test]
fn reads_yolo_polygons_with_overlaps() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fs::write(d.join("names.txt"), "person\nchair\n").unwrap();
    // A square over the left half and a triangle overlapping it; the second line carries a confidence.
    fs::write(d.join("f.txt"), "1 0.0 0.0 0.5 0.0 0.5 1.0 0.0 1.0\n0 0.25 0.0 1.0 0.0 1.0 1.0 0.55\n").unwrap();
    let mut labels = LabelTable::default();
    let m = read_frame_masks(d, "f", 16, 8, &mut labels).unwrap().unwrap();
    assert!(matches!(m.pixels, Pixels::Bits(_)));
    assert_eq!(m.instances.len(), 2);
    assert_eq!(labels.name(m.instances[0].class), "chair");
    assert_eq!(m.instances[0].score, 1.0);
    assert_eq!(m.instances[1].score, 0.55);
    assert_eq!(m.instances[0].bbox, [0, 0, 7, 7]);
    let view = m.view();
    assert!(view.contains(0, 1, 4) && !view.contains(0, 12, 4));
    assert!(view.contains(0, 6, 0) && view.contains(1, 6, 0), "pixel (6, 0) lies in both instances");
    assert!(view.contains(1, 15, 7) && !view.contains(1, 4, 7));
}

#[test]
fn malformed_yolo_lines_name_their_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (stem, text, needle) in [
        ("nan", "0 0.1 0.1 0.5 x 0.5 0.5\n", "f.txt"),
        ("big", "0 0.1 0.1 1.5 0.1 0.5 0.5\n", "normalised"),
        ("short", "0 0.1 0.1 0.5 0.1\n", "at least 3 points"),
        ("conf", "0 0.1 0.1 0.5 0.1 0.5 0.5 1.7\n", "confidence outside"),
        ("class", "dog 0.1 0.1 0.5 0.1 0.5 0.5\n", "malformed class"),
    ] {
        fs::write(d.join(format!("{stem}.txt")), format!("0 0.1 0.1 0.5 0.1 0.5 0.5\n{text}")).unwrap();
        let err = read_frame_masks(d, stem, 16, 8, &mut LabelTable::default()).unwrap_err().to_string();
        assert!(err.contains(&format!("{stem}.txt:2:")), "{err:?} names line 2");
        if needle != "f.txt" {
            assert!(err.contains(needle), "{err:?} should say {needle:?}");
        }
    }
}

#[test]
fn instances_beyond_the_annotation_limit_are_counted_not_fatal() {
    use m2smap::synth::Scene;
    use m2smap_core::{annotate::MAX_INSTANCES, HostStorage, Mapper, Params};
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::new();
    for i in 0..300 {
        let (x, y) = ((i % 20) as f64 / 20.0, (i / 20) as f64 / 15.0);
        text.push_str(&format!("0 {x} {y} {} {y} {} {} {x} {}\n", x + 0.04, x + 0.04, y + 0.05, y + 0.05));
    }
    fs::write(dir.path().join("f.txt"), text).unwrap();
    let masks = read_frame_masks(dir.path(), "f", 640, 480, &mut LabelTable::default()).unwrap().unwrap();
    assert_eq!(masks.instances.len(), 300);
    let scene = Scene::named("tabletop").unwrap();
    let frame = scene.render(0, None);
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let r = *mapper.process(frame.frame.view(&scene.camera), Some(masks.view())).unwrap();
    assert_eq!(r.ignored_instances as usize, 300 - MAX_INSTANCES);
    assert!(r.annotated > 0, "the first {MAX_INSTANCES} instances are still used");
}
