//! Frames for the Cortex-M7 firmware image and the map digests the host computes for them.
//!
//! `m2smap firmware-frames DATASET --frames N --out DIR` decodes N frames once, here, and writes what the
//! firmware embeds: raw depth (u16 LE), packed RGB, the instance masks as bit planes, and `frames.rs` with the
//! intrinsics, instances and camera poses as exact f32 bit patterns. It also runs the host pipeline on exactly
//! those inputs with the `mcu` profile and writes `expected.txt`, the CRC-32 of every frame's encoded map, which
//! the firmware's output must reproduce byte for byte.

use std::fmt::Write as _;
use std::fs;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use m2smap_core::{Frame, Instance, Mapper, MaskPixels, MaskSet, McuStorage, Params, Pose};

use crate::dataset::Dataset;
use crate::masks::{read_frame_masks, LabelTable};
use crate::run::SEGMENTER_INSTANCES;

/// Most instances per firmware frame.
pub const MAX_FIRMWARE_INSTANCES: usize = 8;

/// One frame as the firmware sees it.
pub struct FirmwareFrame {
    /// Width, height.
    pub size: (u16, u16),
    /// Raw depth.
    pub depth: Vec<u16>,
    /// Packed RGB.
    pub colour: Vec<u8>,
    /// Instances.
    pub instances: Vec<Instance>,
    /// One bit plane per instance.
    pub bits: Vec<u8>,
    /// Camera pose.
    pub pose: Option<Pose>,
}

impl FirmwareFrame {
    fn masks(&self) -> MaskSet<'_> {
        MaskSet {
            width: self.size.0,
            height: self.size.1,
            instances: &self.instances,
            pixels: MaskPixels::BitPlanes(&self.bits),
        }
    }
}

/// Loads the first `n` frames of `dataset` in the firmware's form.
pub fn load_frames(dataset: &Dataset, n: usize) -> Result<Vec<FirmwareFrame>> {
    let mut labels = LabelTable::default();
    let masks_dir = dataset.root.join("masks");
    (0..n.min(dataset.frames.len()))
        .map(|k| {
            let f = dataset.load(k)?;
            let fref = &dataset.frames[k];
            let masks = read_frame_masks(&masks_dir, &fref.stem, f.width, f.height, &mut labels)?;
            let (instances, bits) = match masks {
                Some(m) => {
                    let view = m.view();
                    let plane = MaskSet::plane_bytes(f.width, f.height);
                    let count = m.instances.len().min(MAX_FIRMWARE_INSTANCES);
                    let mut bits = vec![0u8; plane * count];
                    for k in 0..count {
                        for v in 0..f.height {
                            for u in 0..f.width {
                                if view.contains(k, u, v) {
                                    let i = v as usize * f.width as usize + u as usize;
                                    bits[k * plane + i / 8] |= 1 << (i % 8);
                                }
                            }
                        }
                    }
                    (m.instances[..count].to_vec(), bits)
                }
                None => (Vec::new(), Vec::new()),
            };
            Ok(FirmwareFrame {
                size: (f.width, f.height),
                depth: f.depth,
                colour: f.colour,
                instances,
                bits,
                pose: fref.pose.map(|p| p.to_core()),
            })
        })
        .collect()
}

/// The CRC-32 and length of every frame's encoded map, from the host pipeline with the `mcu` profile.
pub fn host_digests(dataset: &Dataset, frames: &[FirmwareFrame]) -> Result<Vec<FrameDigest>> {
    let mut storage = bytemuck::zeroed_box::<McuStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).map_err(|e| anyhow!("parameters: {e}"))?;
    let mut world_storage = bytemuck::zeroed_box::<m2smap_core::world::McuWorld>();
    let mut world = m2smap_core::world::WorldMap::new(&mut world_storage);
    let mut buf = vec![0u8; FIRMWARE_MAP_BYTES];
    let mut ids = Vec::new();
    let mut instances = vec![Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] }; SEGMENTER_INSTANCES];
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let frame = Frame {
                width: f.size.0,
                height: f.size.1,
                depth: &f.depth,
                depth_scale: dataset.camera.depth_scale,
                colour: &f.colour,
                intrinsics: dataset.camera.intrinsics(),
                pose: f.pose,
            };
            mapper.process(frame, Some(f.masks())).map_err(|e| anyhow!("{e}"))?;
            let n = mapper.encode_map(&mut buf).map_err(|e| anyhow!("{e}"))?;
            // A map or delta ends with the CRC-32 of everything before it: that is the digest.
            let map_crc = m2smap_core::wire::crc32(&buf[..n.saturating_sub(4)]);
            let pose = f.pose.ok_or_else(|| anyhow!("frame {i} has no pose: the firmware's world map needs one"))?;
            world
                .integrate(i as u32, &pose, mapper.params(), |sink| mapper.for_each_world_primitive(sink))
                .map_err(|e| anyhow!("frame {i}: world map: {e}"))?;
            let d = world.encode_delta(&mut buf).map_err(|e| anyhow!("frame {i}: world delta: {e}"))?;
            let delta_crc = m2smap_core::wire::crc32(&buf[..d.saturating_sub(4)]);
            // Then the geometric segmenter on the same frame, as the firmware runs it (after the world map).
            ids.resize(frame.pixels(), 0);
            let stats =
                mapper.segment(frame, &mut ids, &mut instances, 0).map_err(|e| anyhow!("frame {i}: segmenter: {e}"))?;
            let segment_crc = m2smap_core::segment::digest(&ids, &instances[..stats.instances as usize]);
            Ok(FrameDigest {
                map_crc,
                map_bytes: n,
                delta_crc,
                delta_bytes: d,
                segment_instances: stats.instances,
                segment_crc,
            })
        })
        .collect()
}

/// What the host expects of one firmware frame: its map's and its world delta's size and CRC-32.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameDigest {
    /// CRC-32 of the frame map (its trailer).
    pub map_crc: u32,
    /// Bytes of the frame map.
    pub map_bytes: usize,
    /// CRC-32 of the world-map delta after this frame (the `mcu` world profile).
    pub delta_crc: u32,
    /// Bytes of that delta.
    pub delta_bytes: usize,
    /// Instances the geometric segmenter found in the frame.
    pub segment_instances: u32,
    /// [`m2smap_core::segment::digest`] of its id image and instances.
    pub segment_crc: u32,
}

/// The firmware's map buffer, bytes (also the size the host uses, so an oversized map fails on both).
pub const FIRMWARE_MAP_BYTES: usize = 16 * 1024;

fn bits_of(x: f32) -> String {
    format!("f32::from_bits(0x{:08x})", x.to_bits())
}

/// Writes the firmware inputs and `expected.txt` for the first `n` frames of `dataset` into `out`.
pub fn export(dataset: &Dataset, n: usize, out: &Path) -> Result<()> {
    if n == 0 {
        bail!("--frames must be at least 1");
    }
    fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let frames = load_frames(dataset, n)?;
    let write = |name: &str, bytes: &[u8]| {
        let p = out.join(name);
        fs::write(&p, bytes).with_context(|| format!("{}: cannot write", p.display()))
    };
    let k = dataset.camera.intrinsics();
    let mut src = String::new();
    writeln!(src, "// Generated by `m2smap firmware-frames`; do not edit.")?;
    writeln!(src, "pub const WIDTH: u16 = {};", dataset.camera.width)?;
    writeln!(src, "pub const HEIGHT: u16 = {};", dataset.camera.height)?;
    writeln!(src, "pub const DEPTH_SCALE: f32 = {};", bits_of(dataset.camera.depth_scale))?;
    writeln!(
        src,
        "pub const INTRINSICS: Intrinsics = Intrinsics {{ fx: {}, fy: {}, cx: {}, cy: {} }};",
        bits_of(k.fx),
        bits_of(k.fy),
        bits_of(k.cx),
        bits_of(k.cy)
    )?;
    let abs = |name: String| out.join(name).canonicalize().map(|p| p.display().to_string());
    // The large arrays are statics in the `.frames` section (placed in PSRAM by firmware/memory.x).
    for (i, f) in frames.iter().enumerate() {
        write(&format!("depth{i}.bin"), &f.depth.iter().flat_map(|d| d.to_le_bytes()).collect::<Vec<_>>())?;
        write(&format!("colour{i}.bin"), &f.colour)?;
        write(&format!("masks{i}.bin"), &f.bits)?;
        for (name, bytes) in [("DEPTH", f.depth.len() * 2), ("COLOUR", f.colour.len()), ("MASKS", f.bits.len())] {
            let file = format!("{}{i}.bin", name.to_lowercase());
            writeln!(src, "#[link_section = \".frames\"]")?;
            writeln!(src, "static {name}{i}: Aligned<{bytes}> = Aligned(*include_bytes!({:?}));", abs(file)?)?;
        }
    }
    writeln!(src, "pub static FRAMES: [FrameData; {}] = [", frames.len())?;
    for (i, f) in frames.iter().enumerate() {
        let pose = match f.pose {
            Some(p) => format!(
                "Some(Pose {{ rotation: [{}], translation: [{}] }})",
                p.rotation.iter().map(|r| format!("[{}]", r.map(bits_of).join(", "))).collect::<Vec<_>>().join(", "),
                p.translation.map(bits_of).join(", ")
            ),
            None => "None".into(),
        };
        let instances: Vec<String> = f
            .instances
            .iter()
            .map(|i| {
                format!(
                    "Instance {{ id: {}, class: {}, score: {}, bbox: {:?} }}",
                    i.id,
                    i.class,
                    bits_of(i.score),
                    i.bbox
                )
            })
            .collect();
        writeln!(src, "    FrameData {{")?;
        writeln!(src, "        depth: &DEPTH{i}.0,")?;
        writeln!(src, "        colour: &COLOUR{i}.0,")?;
        writeln!(src, "        masks: &MASKS{i}.0,")?;
        writeln!(src, "        instances: &[{}],", instances.join(", "))?;
        writeln!(src, "        pose: {pose},")?;
        writeln!(src, "    }},")?;
    }
    writeln!(src, "];")?;
    write("frames.rs", src.as_bytes())?;
    let mut expected = String::new();
    for (i, d) in host_digests(dataset, &frames)?.into_iter().enumerate() {
        writeln!(expected, "frame {i} map {} bytes crc {:08x}", d.map_bytes, d.map_crc)?;
        writeln!(expected, "frame {i} world delta {} bytes crc {:08x}", d.delta_bytes, d.delta_crc)?;
        writeln!(expected, "frame {i} segment {} instances crc {:08x}", d.segment_instances, d.segment_crc)?;
    }
    write("expected.txt", expected.as_bytes())?;
    Ok(())
}
