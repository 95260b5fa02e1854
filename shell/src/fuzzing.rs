//! The bodies of the fuzz targets (`fuzz/`), kept here so that an ordinary `cargo test` replays the committed
//! corpus and every past crash without nightly (`tests/fuzz_replay.rs`). Each must return for any input and
//! never panic.

use m2smap_core::{Frame, Instance, Intrinsics, Mapper, MaskPixels, MaskSet, Params, Pose, TinyStorage};

use crate::dataset::{parse_intrinsics, parse_list, parse_pose_matrix, parse_trajectory};
use crate::masks::{parse_id_masks, parse_yolo, LabelTable};

/// Map and snapshot decoders on arbitrary bytes.
pub fn wire_decode(data: &[u8]) {
    let mut n = 0usize;
    if m2smap_core::wire::decode(data, |p| p.for_each_sample(|_| n += 1)).is_ok() {
        assert!(n < 10_000_000);
    }
    let _ = m2smap_core::snapshot::read(data, 64, |_| {}, |_| {});
    // World maps and deltas: a receiver applies what decodes.
    let mut receiver = crate::world::Receiver::default();
    if receiver.apply(data).is_ok() {
        assert!(receiver.world_bytes().is_ok());
    }
    let _ = m2smap_core::wire::decode_world(data, |r| r.primitive.for_each_sample(|_| n += 1));
}

/// A little-endian reader over fuzz bytes that yields zeros once they run out.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn u8(&mut self) -> u8 {
        match self.0.split_first() {
            Some((&b, rest)) => {
                self.0 = rest;
                b
            }
            None => 0,
        }
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    fn f32(&mut self) -> f32 {
        f32::from_bits(u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()]))
    }
}

/// The whole mapper (tiny profile) on arbitrary frames: sizes, intrinsics, depth, colour, masks and poses.
/// Every accepted frame's map must encode, decode and survive a snapshot round trip.
pub fn mapper_frame(data: &[u8]) {
    let mut b = Bytes(data);
    let (w, h) = (1 + (b.u8() % 96) as u16, 1 + (b.u8() % 72) as u16);
    let pixels = w as usize * h as usize;
    let plausible = b.u8() % 2 == 0;
    let intrinsics = if plausible {
        Intrinsics { fx: 40.0 + b.u8() as f32, fy: 40.0 + b.u8() as f32, cx: w as f32 / 2.0, cy: h as f32 / 2.0 }
    } else {
        Intrinsics { fx: b.f32(), fy: b.f32(), cx: b.f32(), cy: b.f32() }
    };
    let depth_scale = if plausible { 5000.0 } else { b.f32() };
    let base = 2000 + b.u16() % 10_000;
    let depth: Vec<u16> =
        (0..pixels).map(|i| if b.0.is_empty() { base.wrapping_add(i as u16 % 97) } else { b.u16() }).collect();
    let colour: Vec<u8> = (0..pixels * 3).map(|_| b.u8()).collect();
    let count = (b.u8() % 4) as usize;
    let instances: Vec<Instance> = (0..count)
        .map(|k| Instance {
            id: if b.u8() % 8 == 0 { 0 } else { k as u16 + 1 },
            class: b.u16() % 4,
            score: if plausible { (b.u8() as f32) / 255.0 } else { b.f32() },
            bbox: [b.u16() % (w + 2), b.u16() % (h + 2), b.u16() % (w + 2), b.u16() % (h + 2)],
        })
        .collect();
    let ids: Vec<u16> = (0..pixels).map(|_| (b.u8() % 5) as u16).collect();
    let pose = match b.u8() % 3 {
        0 => None,
        1 => Some(Pose {
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [b.f32(), 0.0, 0.0],
        }),
        _ => Some(Pose { rotation: [[b.f32(), 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [0.0; 3] }),
    };
    let mut storage = bytemuck::zeroed_box::<TinyStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).expect("default parameters are valid");
    let mut map = vec![0u8; 1 << 16];
    let mut snap = vec![0u8; 4096];
    for repeat in 0..2 {
        let frame = Frame { width: w, height: h, depth: &depth, depth_scale, colour: &colour, intrinsics, pose };
        let masks = MaskSet { width: w, height: h, instances: &instances, pixels: MaskPixels::IdImage(&ids) };
        let masks = (repeat == 0 || count > 0).then_some(masks);
        if mapper.process(frame, masks).is_ok() {
            let n = mapper.encode_map(&mut map).expect("a tiny map fits 64 KiB");
            m2smap_core::wire::decode(&map[..n], |_| {}).expect("every produced map decodes");
            let s = mapper.snapshot(&mut snap).expect("a tiny snapshot fits 4 KiB");
            mapper.restore(&snap[..s]).expect("a fresh snapshot restores");
        }
    }
}

/// The mask readers on arbitrary bytes: an id PNG + JSON pair (split at the first 0xFF 0x00 pair) or YOLO text.
pub fn masks_parse(data: &[u8]) {
    let mut labels = LabelTable::default();
    let Some((&selector, rest)) = data.split_first() else { return };
    let (w, h) = (1 + (selector % 32) as u16, 1 + (selector / 32) as u16 * 4);
    if selector % 2 == 0 {
        let split = rest.windows(2).position(|p| p == [0xFF, 0x00]).unwrap_or(rest.len());
        let (png, json) = rest.split_at(split);
        let json = String::from_utf8_lossy(json.get(2..).unwrap_or(&[]));
        if let Ok(m) = parse_id_masks(png, "png", &json, "json", w, h, &mut labels) {
            let _ = m.view().validate(w, h);
        }
    } else {
        let text = String::from_utf8_lossy(rest);
        let names = ["a".to_owned(), "b".to_owned()];
        if let Ok(m) = parse_yolo(&text, "txt", &names, w, h, &mut labels) {
            let _ = m.view().validate(w, h);
        }
    }
}

/// The TUM and 7-Scenes text parsers on arbitrary text.
pub fn lists_parse(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let _ = parse_list(&text, 1);
    let _ = parse_trajectory(&text);
    let _ = parse_pose_matrix(&text);
    let _ = parse_intrinsics(&text);
}
