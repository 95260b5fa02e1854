//! Pictures of a mapped frame, like the paper's Fig. 1: (a) the colour image with its instance masks, (b) the
//! supervoxel clusters and refined Gaussians, (c) the clusters after fusion, (d) the final map of planes,
//! superquadrics and Gaussians drawn from the camera by a small point-splatting renderer with a depth buffer.

use std::path::Path;

use anyhow::{Context, Result};
use image::{Rgb, RgbImage};
use m2smap_core::map::Primitive;
use m2smap_core::supervoxel::is_assigned;
use m2smap_core::{Frame, Mapper};

use crate::masks::FrameMasks;

/// Colour of a primitive kind in panel (d) and the legend.
pub const PLANE_COLOUR: [u8; 3] = [110, 140, 200];
/// Residual Gaussians in panel (d).
pub const GMM_COLOUR: [u8; 3] = [235, 150, 60];

/// A saturated, well-spread colour for an id (hue from a hash, high saturation and value).
pub fn id_colour(id: u32) -> [u8; 3] {
    let h = m2smap_core::points::mix32(id.wrapping_mul(2_654_435_761).wrapping_add(17));
    let hue = (h % 360) as f32 / 60.0;
    let (s, v) = (0.65 + ((h >> 9) % 30) as f32 / 100.0, 0.8 + ((h >> 17) % 20) as f32 / 100.0);
    let c = v * s;
    let x = c * (1.0 - ((hue % 2.0) - 1.0).abs());
    let (r, g, b) = match hue as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [((r + m) * 255.0) as u8, ((g + m) * 255.0) as u8, ((b + m) * 255.0) as u8]
}

fn blend(a: [u8; 3], b: [u8; 3], t: f32) -> [u8; 3] {
    [0, 1, 2].map(|k| (a[k] as f32 * (1.0 - t) + b[k] as f32 * t) as u8)
}

/// Draws the four panels of the frame the mapper last processed into a 2×2 PNG at `out`.
pub fn render_panels(mapper: &Mapper<'_>, frame: &Frame<'_>, masks: Option<&FrameMasks>, out: &Path) -> Result<()> {
    let (w, h) = (frame.width as u32, frame.height as u32);
    let mut img = RgbImage::new(2 * w, 2 * h);
    let params = mapper.params();
    let (lo, hi) = frame.raw_range(params);
    let gaussians = mapper.gaussians();
    // Per pixel: the Gaussian and supervoxel of the voxel its back-projected point falls into.
    let mut labels = vec![(u16::MAX, u16::MAX); (w * h) as usize];
    for (i, &raw) in frame.depth.iter().enumerate() {
        if raw < lo || raw > hi {
            continue;
        }
        let (u, v) = ((i as u32 % w) as f32, (i as u32 / w) as f32);
        let p = frame.intrinsics.unproject(u, v, frame.metres(raw));
        let slot = match (mapper.uses_mask_slots(), masks) {
            (true, Some(m)) => m.view().voxel_slot(u as u16, v as u16, params.min_confidence),
            _ => 0,
        };
        if let Some(vx) = mapper.voxel_at(p, slot).filter(|vx| is_assigned(vx.gaussian)) {
            labels[i] = (vx.gaussian, vx.supervoxel);
        }
    }
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let rgb = [frame.colour[3 * i], frame.colour[3 * i + 1], frame.colour[3 * i + 2]];
            // (a) colour with masks.
            let id = masks.map_or(0, |m| m.id_at(x as u16, y as u16));
            let a = if id != 0 { blend(rgb, id_colour(id as u32 * 7919), 0.55) } else { rgb };
            img.put_pixel(x, y, Rgb(a));
            let (g, sv) = labels[i];
            let grey = blend(rgb, [0, 0, 0], 0.7);
            // (b) Gaussians, with supervoxel borders in black.
            let border = (x + 1 < w && labels[i + 1].1 != sv) || (y + 1 < h && labels[i + w as usize].1 != sv);
            let b = if g == u16::MAX {
                grey
            } else if border {
                [0, 0, 0]
            } else {
                id_colour(g as u32)
            };
            img.put_pixel(w + x, y, Rgb(b));
            // (c) fused clusters.
            let c = gaussians.get(g as usize).map_or(grey, |gg| id_colour(gg.cluster as u32 + 100_000));
            img.put_pixel(x, h + y, Rgb(c));
        }
    }
    // (d) the map, splatted with a depth buffer.
    let mut zbuf = vec![f32::INFINITY; (w * h) as usize];
    let k = frame.intrinsics;
    let mut splat = |p: [f32; 3], radius_m: f32, colour: [u8; 3], img: &mut RgbImage| {
        let Some([u, v]) = k.project(p) else { return };
        let r = ((radius_m * k.fx / p[2]).ceil() as i32).clamp(1, 12);
        for dy in -r..=r {
            for dx in -r..=r {
                let (x, y) = (u.round() as i32 + dx, v.round() as i32 + dy);
                if x < 0 || y < 0 || x >= w as i32 || y >= h as i32 {
                    continue;
                }
                let j = (y as u32 * w + x as u32) as usize;
                if p[2] < zbuf[j] {
                    zbuf[j] = p[2];
                    img.put_pixel(w + x as u32, h + y as u32, Rgb(colour));
                }
            }
        }
    };
    mapper.for_each_primitive(|prim| {
        let (radius, colour) = match prim {
            Primitive::Plane(p) => (0.5 * p.g_p, blend(PLANE_COLOUR, id_colour(p.cluster as u32), 0.25)),
            Primitive::Sq(s) => (0.5 * m2smap_core::map::SQ_SAMPLE_SPACING, id_colour(s.instance as u32 * 7919)),
            Primitive::Gmm(g) if g.instance != 0 => (0.01, blend(id_colour(g.instance as u32 * 7919), [0, 0, 0], 0.3)),
            Primitive::Gmm(_) => (0.01, GMM_COLOUR),
        };
        prim.for_each_sample(|p| splat(p, radius, colour, &mut img));
    });
    // Legends.
    let white = [255, 255, 255];
    label(&mut img, 6, 6, "(A) RGB + INSTANCE MASKS", white);
    label(&mut img, w + 6, 6, "(B) SUPERVOXELS (BORDERS) + GAUSSIANS", white);
    label(&mut img, 6, h + 6, "(C) CLUSTERS AFTER FUSION", white);
    label(&mut img, w + 6, h + 6, "(D) MAP:", white);
    let mut x = w + 6 + 9 * 6;
    for (name, colour) in [("PLANE", PLANE_COLOUR), ("SQ", id_colour(7919)), ("GMM", GMM_COLOUR)] {
        for dy in 0..7 {
            for dx in 0..7 {
                img.put_pixel(x + dx, h + 6 + dy, Rgb(colour));
            }
        }
        label(&mut img, x + 10, h + 6, name, white);
        x += 10 + 6 * name.len() as u32 + 8;
    }
    img.save(out).with_context(|| format!("{}: cannot write", out.display()))
}

/// Draws upper-case text with a built-in 5×7 font (1 pixel apart, shadowed for contrast).
pub fn label(img: &mut RgbImage, x: u32, y: u32, text: &str, colour: [u8; 3]) {
    for (n, ch) in text.chars().enumerate() {
        let glyph = glyph(ch);
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..5u32 {
                if bits >> (4 - col) & 1 == 1 {
                    let (px, py) = (x + n as u32 * 6 + col, y + row as u32);
                    for (sx, sy, c) in [(1, 1, [0, 0, 0]), (0, 0, colour)] {
                        if px + sx < img.width() && py + sy < img.height() {
                            img.put_pixel(px + sx, py + sy, Rgb(c));
                        }
                    }
                }
            }
        }
    }
}

/// 5×7 glyphs (rows top to bottom, 5 bits each, MSB left).
fn glyph(c: char) -> [u8; 7] {
    match c {
        'A' => [14, 17, 17, 31, 17, 17, 17],
        'B' => [30, 17, 17, 30, 17, 17, 30],
        'C' => [14, 17, 16, 16, 16, 17, 14],
        'D' => [30, 17, 17, 17, 17, 17, 30],
        'E' => [31, 16, 16, 30, 16, 16, 31],
        'F' => [31, 16, 16, 30, 16, 16, 16],
        'G' => [14, 17, 16, 23, 17, 17, 15],
        'H' => [17, 17, 17, 31, 17, 17, 17],
        'I' => [14, 4, 4, 4, 4, 4, 14],
        'J' => [7, 2, 2, 2, 2, 18, 12],
        'K' => [17, 18, 20, 24, 20, 18, 17],
        'L' => [16, 16, 16, 16, 16, 16, 31],
        'M' => [17, 27, 21, 21, 17, 17, 17],
        'N' => [17, 17, 25, 21, 19, 17, 17],
        'O' => [14, 17, 17, 17, 17, 17, 14],
        'P' => [30, 17, 17, 30, 16, 16, 16],
        'Q' => [14, 17, 17, 17, 21, 18, 13],
        'R' => [30, 17, 17, 30, 20, 18, 17],
        'S' => [15, 16, 16, 14, 1, 1, 30],
        'T' => [31, 4, 4, 4, 4, 4, 4],
        'U' => [17, 17, 17, 17, 17, 17, 14],
        'V' => [17, 17, 17, 17, 17, 10, 4],
        'W' => [17, 17, 17, 21, 21, 21, 10],
        'X' => [17, 17, 10, 4, 10, 17, 17],
        'Y' => [17, 17, 10, 4, 4, 4, 4],
        'Z' => [31, 1, 2, 4, 8, 16, 31],
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        '(' => [2, 4, 8, 8, 8, 4, 2],
        ')' => [8, 4, 2, 2, 2, 4, 8],
        '+' => [0, 4, 4, 31, 4, 4, 0],
        ':' => [0, 12, 12, 0, 12, 12, 0],
        '-' => [0, 0, 0, 31, 0, 0, 0],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        '/' => [0, 1, 2, 4, 8, 16, 0],
        _ => [0; 7],
    }
}
