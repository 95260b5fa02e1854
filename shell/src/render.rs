//! Pictures of a mapped frame, like the paper's Fig. 1: (a) the colour image with its instance masks, (b) the
//! supervoxel clusters and refined Gaussians, (c) the clusters after fusion, (d) the final map of planes,
//! superquadrics and Gaussians ray-cast as solid shaded shapes from the camera ([`crate::raycast`]); and the map
//! alone from other viewpoints (`--view orbit|top`) to see the sides the camera did not.

use std::path::Path;

use anyhow::{Context, Result};
use image::{Rgb, RgbImage};
use m2smap_core::map::Primitive;
use m2smap_core::supervoxel::is_assigned;
use m2smap_core::{Frame, Mapper};

use crate::masks::FrameMasks;
use crate::raycast::{self, Drawable, Framing, View, Viewpoint};

/// Colour of bounded planes in the map pictures and the legend (tinted by cluster).
pub const PLANE_COLOUR: [u8; 3] = [110, 140, 215];
/// Colour of object superquadrics (tinted by instance).
pub const SQ_COLOUR: [u8; 3] = [80, 205, 105];
/// Colour of Gaussians (tinted by instance when they carry one).
pub const GMM_COLOUR: [u8; 3] = [240, 150, 55];
/// How much of an instance's (or plane cluster's) own colour tints its primitive's kind colour: at 0.25 an SQ stays
/// green-dominant and a Gaussian red-dominant whatever the instance colour.
pub const TINT: f32 = 0.25;
/// Background of the map pictures where no primitive is hit.
pub const BACKGROUND: [u8; 3] = [0, 0, 0];

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

/// Rounds of [`fill_gaps`]: a gap up to twice this wide closes.
const FILL_ROUNDS: usize = 3;

/// Gives a pixel with valid depth whose point fell into a voxel the mapper did not keep (it voxelises a sample
/// of the pixels, so many voxels hold no sampled point) the label of a labelled 4-neighbour, for
/// [`FILL_ROUNDS`] rounds: panels (b) and (c) then show the clusters, not the sampling pattern.
fn fill_gaps(labels: &mut [(u16, u16)], frame: &Frame<'_>, lo: u16, hi: u16, w: u32, h: u32) {
    let (w, h) = (w as usize, h as usize);
    for _ in 0..FILL_ROUNDS {
        let before = labels.to_vec();
        for (i, label) in labels.iter_mut().enumerate() {
            let valid = frame.depth.get(i).is_some_and(|&r| r >= lo && r <= hi);
            if label.0 != u16::MAX || !valid {
                continue;
            }
            let (x, y) = (i % w, i / w);
            let neighbours = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then(|| i + w),
            ];
            if let Some(&l) = neighbours.into_iter().flatten().filter_map(|j| before.get(j)).find(|l| l.0 != u16::MAX) {
                *label = l;
            }
        }
    }
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
    fill_gaps(&mut labels, frame, lo, hi, w, h);
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
            // A border only between two labelled pixels of different supervoxels.
            let differs = |j: usize| labels.get(j).is_some_and(|&(gj, svj)| gj != u16::MAX && svj != sv);
            let border = (x + 1 < w && differs(i + 1)) || (y + 1 < h && differs(i + w as usize));
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
    // (d) the map, ray-cast from the camera.
    let items = map_drawables(mapper);
    let map = raycast::render(&items, &View::camera(&frame.intrinsics, w, h), [0.0; 3], BACKGROUND);
    blit(&mut img, &map, w, h);
    // Legends.
    let white = [255, 255, 255];
    label(&mut img, 6, 6, "(A) RGB + INSTANCE MASKS", white);
    label(&mut img, w + 6, 6, "(B) SUPERVOXELS (BORDERS) + GAUSSIANS", white);
    label(&mut img, 6, h + 6, "(C) CLUSTERS AFTER FUSION", white);
    legend(&mut img, w, h, "(D) MAP:");
    img.save(out).with_context(|| format!("{}: cannot write", out.display()))
}

/// The map's primitives, coloured by kind with the instance (planes: the cluster) as a tint.
pub fn map_drawables(mapper: &Mapper<'_>) -> Vec<Drawable> {
    raycast::drawables(|f| mapper.for_each_primitive(f), primitive_colour)
}

/// A primitive's picture colour: its kind's, tinted by its instance (planes: the cluster; world superquadrics,
/// which carry no instance: the track).
pub fn primitive_colour(prim: &Primitive<'_>) -> [u8; 3] {
    match prim {
        Primitive::Plane(p) => blend(PLANE_COLOUR, id_colour(p.cluster as u32), TINT),
        Primitive::Sq(s) if s.instance == 0 => blend(SQ_COLOUR, id_colour(s.track as u32 * 7919 + 1), TINT),
        Primitive::Sq(s) => blend(SQ_COLOUR, id_colour(s.instance as u32 * 7919), TINT),
        Primitive::Gmm(g) if g.instance != 0 => blend(GMM_COLOUR, id_colour(g.instance as u32 * 7919), TINT),
        Primitive::Gmm(_) => GMM_COLOUR,
    }
}

/// Draws a world map (`m2smap run --world`, world frame) from `view` around all of it, in the frame of the
/// first camera `first` (its up is the picture's up) with the optics of `camera`, into a PNG at `out`.
/// Returns the number of pixels that show a primitive.
pub fn render_world(
    world: &m2smap_core::world::WorldMap<'_>,
    first: &m2smap_core::Pose,
    camera: &m2smap_core::Intrinsics,
    (w, h): (u32, u32),
    view: MapView,
    out: &Path,
) -> Result<usize> {
    // World → first camera: p ↦ Rᵀ(p − t).
    let r_t = m2smap_core::linalg::transpose(&first.rotation);
    let t = m2smap_core::linalg::scale(m2smap_core::linalg::mat_vec(&r_t, first.translation), -1.0);
    let items = raycast::drawables(|f| world.for_each_primitive(|_, p| f(&p.moved(&r_t, t))), primitive_colour);
    let framing = Framing::whole(&items);
    draw_panels(&items, &framing, &View::camera(camera, w, h), view, "WORLD", out)
}

/// Copies a rendered image into `img` with its top-left corner at (x0, y0).
fn blit(img: &mut RgbImage, from: &raycast::Image, x0: u32, y0: u32) {
    for y in 0..from.height {
        for x in 0..from.width {
            if let Some(c) = from.colour.get((y * from.width + x) as usize) {
                if x0 + x < img.width() && y0 + y < img.height() {
                    img.put_pixel(x0 + x, y0 + y, Rgb(*c));
                }
            }
        }
    }
}

/// The title of a map panel at (x, y) followed by the kind swatches and the tint note.
fn legend(img: &mut RgbImage, x: u32, y: u32, title: &str) {
    let white = [255, 255, 255];
    label(img, x + 6, y + 6, title, white);
    let mut cx = x + 6 + 6 * title.len() as u32 + 6;
    for (name, colour) in [("PLANE", PLANE_COLOUR), ("SQ", SQ_COLOUR), ("GMM", GMM_COLOUR), ("TINT = INSTANCE", white)]
    {
        if name.starts_with("TINT") {
            label(img, cx, y + 6, name, white);
            break;
        }
        for dy in 0..7 {
            for dx in 0..7 {
                if cx + dx < img.width() && y + 6 + dy < img.height() {
                    img.put_pixel(cx + dx, y + 6 + dy, Rgb(colour));
                }
            }
        }
        label(img, cx + 10, y + 6, name, white);
        cx += 10 + 6 * name.len() as u32 + 8;
    }
}

/// Which viewpoint `render_views` draws the map from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MapView {
    /// Four views around the objects, 45°, 135°, 225° and 315° from the camera's side, in a 2 × 2 picture.
    Orbit,
    /// One orbit view at this azimuth, degrees (counter-clockwise seen from above).
    OrbitAt(f32),
    /// From straight above.
    Top,
}

/// Draws the map of the frame the mapper last processed from `view` (not the camera's) into a PNG at `out`; the
/// optics are the frame's. Returns the number of pixels that show a primitive.
pub fn render_views(mapper: &Mapper<'_>, frame: &Frame<'_>, view: MapView, out: &Path) -> Result<usize> {
    let (w, h) = (frame.width as u32, frame.height as u32);
    let items = map_drawables(mapper);
    let framing = Framing::of(&items);
    draw_panels(&items, &framing, &View::camera(&frame.intrinsics, w, h), view, "", out)
}

/// Draws `items` from `view` (one panel, or four for [`MapView::Orbit`]) framed by `framing`, with the optics of
/// `camera`, each panel titled (after `prefix`) and with the legend; returns the pixels that show a primitive.
fn draw_panels(
    items: &[Drawable],
    framing: &Framing,
    camera: &View,
    view: MapView,
    prefix: &str,
    out: &Path,
) -> Result<usize> {
    let (w, h) = (camera.width, camera.height);
    let space = if prefix.is_empty() { "" } else { " " };
    let panels: Vec<(Viewpoint, String)> = match view {
        MapView::Orbit => [45.0f32, 135.0, 225.0, 315.0]
            .iter()
            .map(|&a| (Viewpoint::Orbit { azimuth: a.to_radians() }, format!("{prefix}{space}ORBIT {a:.0} DEG:")))
            .collect(),
        MapView::OrbitAt(a) => {
            vec![(Viewpoint::Orbit { azimuth: a.to_radians() }, format!("{prefix}{space}ORBIT {a:.0} DEG:"))]
        }
        MapView::Top => vec![(Viewpoint::Top, format!("{prefix}{space}TOP:"))],
    };
    let (cols, rows) = if panels.len() > 1 { (2, 2) } else { (1, 1) };
    let mut img = RgbImage::new(cols * w, rows * h);
    let mut drawn = 0;
    for (k, (viewpoint, title)) in panels.iter().enumerate() {
        let (x0, y0) = ((k as u32 % cols) * w, (k as u32 / cols) * h);
        let image = raycast::render(items, &framing.view(*viewpoint, camera), camera.origin, BACKGROUND);
        drawn += image.kind.iter().filter(|k| k.is_some()).count();
        blit(&mut img, &image, x0, y0);
        legend(&mut img, x0, y0, title);
    }
    img.save(out).with_context(|| format!("{}: cannot write", out.display()))?;
    Ok(drawn)
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
        '=' => [0, 0, 31, 0, 31, 0, 0],
        _ => [0; 7],
    }
}
