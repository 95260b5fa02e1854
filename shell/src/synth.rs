//! Procedural RGB-D scenes with exact ground truth: planes and oriented boxes, ray-cast per pixel, a smooth
//! camera path, and a Kinect-like sensor (depth noise σ(z) = 0.0012 + 0.0019·(z − 0.4)² m, quantisation to the
//! TUM factor 5000, shaded colour with noise). Deterministic for a seed.

use std::fs;
use std::path::Path;

use anyhow::{bail, Context, Result};
use m2smap_core::points::mix32;
use serde::Serialize;

use crate::dataset::{Camera, LoadedFrame, Pose};
use crate::masks::{FrameMasks, LabelTable, Pixels};
use m2smap_core::Instance;

/// Geometry of one surface, world frame (z up), metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Shape {
    /// The plane n·x = offset (n unit), seen from the side n points to.
    Plane {
        /// Unit normal.
        normal: [f64; 3],
        /// Offset along the normal, metres.
        offset: f64,
    },
    /// A box with centre, half extents and a rotation `yaw` about the world z axis (radians).
    Box {
        /// Centre, metres.
        centre: [f64; 3],
        /// Half extents along the box's local axes, metres.
        half: [f64; 3],
        /// Rotation about z, radians.
        yaw: f64,
    },
}

/// One surface of a scene.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Surface {
    /// Name.
    pub name: String,
    /// Ground-truth instance id (≥ 1 for objects, 0 for structure such as floor and walls).
    pub instance: u16,
    /// Category label of an object.
    pub label: String,
    /// Geometry.
    pub shape: Shape,
    /// Base colour, RGB.
    pub colour: [u8; 3],
}

impl Surface {
    /// Ray parameter (distance along `dir`) and world normal of the first hit, if any.
    fn intersect(&self, origin: [f64; 3], dir: [f64; 3]) -> Option<(f64, [f64; 3])> {
        match self.shape {
            Shape::Plane { normal, offset } => {
                let denom = dot(normal, dir);
                if denom >= -1e-9 {
                    return None; // parallel or seen from behind
                }
                let t = (offset - dot(normal, origin)) / denom;
                (t > 0.0).then_some((t, normal))
            }
            Shape::Box { centre, half, yaw } => {
                let (o, d) = (to_local(sub(origin, centre), yaw), to_local(dir, yaw));
                let (mut t_near, mut t_far, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0usize);
                for k in 0..3 {
                    if d[k].abs() < 1e-12 {
                        if o[k].abs() > half[k] {
                            return None;
                        }
                        continue;
                    }
                    let (t1, t2) = ((-half[k] - o[k]) / d[k], (half[k] - o[k]) / d[k]);
                    let (lo, hi) = if t1 < t2 { (t1, t2) } else { (t2, t1) };
                    if lo > t_near {
                        t_near = lo;
                        axis = k;
                    }
                    t_far = t_far.min(hi);
                }
                if t_near > t_far || t_near <= 0.0 {
                    return None;
                }
                let mut n = [0.0; 3];
                n[axis] = -d[axis].signum();
                Some((t_near, from_local(n, yaw)))
            }
        }
    }

    /// Distance from a world point to this surface, metres.
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        match self.shape {
            Shape::Plane { normal, offset } => (dot(normal, p) - offset).abs(),
            Shape::Box { centre, half, yaw } => {
                let q = to_local(sub(p, centre), yaw);
                let d = [q[0].abs() - half[0], q[1].abs() - half[1], q[2].abs() - half[2]];
                let outside = [d[0].max(0.0), d[1].max(0.0), d[2].max(0.0)];
                let inside = d[0].max(d[1]).max(d[2]).min(0.0);
                (dot(outside, outside).sqrt() + inside).abs()
            }
        }
    }
}

/// A scene: its surfaces, camera and camera path.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Name (`tabletop`, `shelf`).
    pub name: String,
    /// Surfaces.
    pub surfaces: Vec<Surface>,
    /// Camera model.
    pub camera: Camera,
    eye: [f64; 3],
    target: [f64; 3],
}

/// The names of the built-in scenes.
pub const SCENES: [&str; 3] = ["tabletop", "shelf", "desk"];

fn plane(name: &str, normal: [f64; 3], offset: f64, colour: [u8; 3]) -> Surface {
    Surface { name: name.into(), instance: 0, label: String::new(), shape: Shape::Plane { normal, offset }, colour }
}

fn cuboid(name: &str, instance: u16, label: &str, centre: [f64; 3], half: [f64; 3], yaw: f64, colour: [u8; 3]) -> Surface {
    Surface { name: name.into(), instance, label: label.into(), shape: Shape::Box { centre, half, yaw }, colour }
}

impl Scene {
    /// A built-in scene by name.
    pub fn named(name: &str) -> Result<Scene> {
        let camera = Camera::preset("fr3").context("fr3 preset")?;
        let surfaces = match name {
            // Two boxes standing apart on a floor in front of a wall.
            "tabletop" => vec![
                plane("floor", [0.0, 0.0, 1.0], 0.0, [150, 140, 120]),
                plane("wall", [0.0, -1.0, 0.0], -1.6, [200, 200, 190]),
                cuboid("box_a", 1, "box", [-0.35, 0.75, 0.2], [0.2, 0.15, 0.2], 0.3, [200, 60, 50]),
                cuboid("box_b", 2, "box", [0.4, 0.95, 0.15], [0.15, 0.15, 0.15], -0.4, [50, 90, 200]),
            ],
            // A box touching another box and the wall, a flat slab lying on the floor.
            "shelf" => vec![
                plane("floor", [0.0, 0.0, 1.0], 0.0, [140, 150, 130]),
                plane("wall", [0.0, -1.0, 0.0], -1.4, [210, 200, 200]),
                cuboid("cabinet", 1, "cabinet", [0.0, 1.1, 0.35], [0.35, 0.3, 0.35], 0.0, [120, 80, 40]),
                cuboid("crate", 2, "box", [-0.55, 1.0, 0.2], [0.2, 0.2, 0.2], 0.0, [60, 160, 60]),
                cuboid("slab", 3, "laptop", [0.45, 0.5, 0.015], [0.17, 0.12, 0.015], 0.2, [40, 40, 45]),
            ],
            // Flat objects on the floor: a 2 cm board as large as a table top (plane-sized, σ0, σ1 > τ_s) and a
            // low 8 cm box, both within l_min of the floor plane, beside a tall box.
            "desk" => vec![
                plane("floor", [0.0, 0.0, 1.0], 0.0, [150, 150, 140]),
                plane("wall", [0.0, -1.0, 0.0], -1.8, [205, 205, 195]),
                cuboid("board", 1, "laptop", [-0.25, 0.55, 0.01], [0.32, 0.26, 0.01], 0.15, [35, 35, 40]),
                cuboid("lowbox", 2, "book", [0.45, 0.45, 0.04], [0.14, 0.11, 0.04], -0.3, [180, 40, 40]),
                cuboid("tower", 3, "box", [0.3, 1.2, 0.3], [0.15, 0.15, 0.3], 0.2, [40, 120, 200]),
            ],
            other => bail!("unknown scene {other:?} (known: {})", SCENES.join(", ")),
        };
        Ok(Scene { name: name.into(), surfaces, camera, eye: [0.1, -1.1, 1.25], target: [0.0, 0.9, 0.25] })
    }

    /// Camera-to-world pose at frame `k`: a slow sway with small roll, pitch and yaw.
    pub fn pose(&self, k: usize) -> Pose {
        let s = k as f64 * 0.15;
        let eye = add(self.eye, [0.25 * s.sin(), 0.08 * (0.7 * s).sin(), 0.06 * (1.3 * s).cos()]);
        let target = add(self.target, [0.1 * (0.5 * s).sin(), 0.0, 0.05 * s.cos()]);
        let f = normalize(sub(target, eye));
        let roll = 0.05 * (0.9 * s).sin();
        let r0 = normalize(cross(f, [0.0, 0.0, 1.0]));
        let d0 = cross(f, r0);
        let (c, sn) = (roll.cos(), roll.sin());
        let right = add(scale(r0, c), scale(d0, sn));
        let down = sub(scale(d0, c), scale(r0, sn));
        let rot = [[right[0], down[0], f[0]], [right[1], down[1], f[1]], [right[2], down[2], f[2]]];
        Pose::from_matrix(rot, eye)
    }

    /// Renders frame `k`. With `noise = Some(seed)` the sensor model is applied; without it depth is exact
    /// up to the 1/5000 m quantisation and colour is noise-free.
    pub fn render(&self, k: usize, noise: Option<u32>) -> SynthFrame {
        let cam = self.camera;
        let pose = self.pose(k);
        let rot = pose.rotation();
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut frame = SynthFrame {
            frame: LoadedFrame { width: cam.width, height: cam.height, depth: vec![0; w * h], colour: vec![0; w * h * 3] },
            surface: vec![0; w * h],
            pose,
        };
        let light = normalize([0.3, -0.5, 0.8]);
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                let dc = [(u as f64 - cam.cx as f64) / cam.fx as f64, (v as f64 - cam.cy as f64) / cam.fy as f64, 1.0];
                let dw = [dot(rot[0], dc), dot(rot[1], dc), dot(rot[2], dc)];
                let hit = self
                    .surfaces
                    .iter()
                    .enumerate()
                    .filter_map(|(s, surf)| surf.intersect(pose.t, dw).map(|(t, n)| (t, n, s)))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let Some((z, n, s)) = hit else { continue };
                let surf = &self.surfaces[s];
                let grazing = dot(n, normalize(dw)).abs();
                let mut z = z; // dc has z = 1, so the ray parameter is the depth.
                if let Some(seed) = noise {
                    if grazing < 0.1 && unit(seed, k, i, 0) < 0.5 {
                        continue; // grazing-angle dropout
                    }
                    z += (0.0012 + 0.0019 * (z - 0.4).powi(2)) * gaussian(seed, k, i);
                }
                let raw = (z * 5000.0).round();
                if !(1.0..65535.0).contains(&raw) {
                    continue;
                }
                frame.frame.depth[i] = raw as u16;
                frame.surface[i] = s as u16 + 1;
                let shade = 0.35 + 0.65 * dot(n, light).abs();
                for c in 0..3 {
                    let jitter = noise.map_or(0.0, |seed| 6.0 * gaussian(seed ^ 0x5eed, k, i * 3 + c));
                    frame.frame.colour[i * 3 + c] = (surf.colour[c] as f64 * shade + jitter).clamp(0.0, 255.0) as u8;
                }
            }
        }
        frame
    }

    /// Ground-truth instance image of a rendered frame (0 = structure or nothing).
    pub fn instance_image(&self, frame: &SynthFrame) -> Vec<u16> {
        frame.surface.iter().map(|&s| if s == 0 { 0 } else { self.surfaces[s as usize - 1].instance }).collect()
    }

    /// Perfect instance masks of a rendered frame: the ground-truth instance image and one instance per visible
    /// object (score 1, tight box).
    pub fn perfect_masks(&self, frame: &SynthFrame, labels: &mut LabelTable) -> FrameMasks {
        let ids = self.instance_image(frame);
        let w = self.camera.width as usize;
        let mut instances: Vec<Instance> = Vec::new();
        for (i, &id) in ids.iter().enumerate() {
            if id == 0 {
                continue;
            }
            let (u, v) = ((i % w) as u16, (i / w) as u16);
            match instances.iter_mut().find(|x| x.id == id) {
                Some(x) => x.bbox = [x.bbox[0].min(u), x.bbox[1].min(v), x.bbox[2].max(u), x.bbox[3].max(v)],
                None => {
                    let label = self.surfaces.iter().find(|s| s.instance == id).map_or("object", |s| s.label.as_str());
                    instances.push(Instance { id, class: labels.class_of(label), score: 1.0, bbox: [u, v, u, v] });
                }
            }
        }
        instances.sort_by_key(|x| x.id);
        FrameMasks { width: self.camera.width, height: self.camera.height, instances, pixels: Pixels::Ids(ids) }
    }

    /// Writes `frames` frames as a TUM folder with `groundtruth.txt`, `camera.json`, `gt/` and perfect `masks/`.
    pub fn write_tum(&self, out: &Path, frames: usize, seed: u32, noise: bool) -> Result<()> {
        for sub in ["rgb", "depth", "gt", "masks"] {
            fs::create_dir_all(out.join(sub)).with_context(|| format!("{}: cannot create", out.join(sub).display()))?;
        }
        let (mut rgb_list, mut depth_list, mut gt_list) = (String::new(), String::new(), String::new());
        rgb_list.push_str("# color images\n# timestamp filename\n");
        depth_list.push_str("# depth maps\n# timestamp filename\n");
        gt_list.push_str("# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n");
        let (w, h) = (self.camera.width as u32, self.camera.height as u32);
        for k in 0..frames {
            let f = self.render(k, noise.then_some(seed));
            let t = 1000.0 + k as f64 / 30.0;
            let stem = format!("{t:.6}");
            save(&out.join(format!("rgb/{stem}.png")), image::RgbImage::from_raw(w, h, f.frame.colour.clone()))?;
            save(&out.join(format!("depth/{stem}.png")), image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, f.frame.depth.clone()))?;
            save(&out.join(format!("gt/{stem}.png")), image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, self.instance_image(&f)))?;
            let masks = self.perfect_masks(&f, &mut LabelTable::default());
            if let Pixels::Ids(ids) = &masks.pixels {
                save(&out.join(format!("masks/{stem}.png")), image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, ids.clone()))?;
            }
            let list: Vec<serde_json::Value> = masks
                .instances
                .iter()
                .map(|i| {
                    let label = self.surfaces.iter().find(|s| s.instance == i.id).map_or("object", |s| s.label.as_str());
                    serde_json::json!({ "id": i.id, "label": label, "score": i.score, "bbox": i.bbox })
                })
                .collect();
            write(&out.join(format!("masks/{stem}.json")), &serde_json::to_string(&serde_json::json!({ "instances": list }))?)?;
            rgb_list.push_str(&format!("{stem} rgb/{stem}.png\n"));
            depth_list.push_str(&format!("{stem} depth/{stem}.png\n"));
            let (p, q) = (f.pose.t, f.pose.q);
            gt_list.push_str(&format!("{stem} {:.6} {:.6} {:.6} {:.6} {:.6} {:.6} {:.6}\n", p[0], p[1], p[2], q[0], q[1], q[2], q[3]));
        }
        write(&out.join("rgb.txt"), &rgb_list)?;
        write(&out.join("depth.txt"), &depth_list)?;
        write(&out.join("groundtruth.txt"), &gt_list)?;
        write(&out.join("camera.json"), &serde_json::to_string_pretty(&self.camera)?)?;
        let objects: Vec<&Surface> = self.surfaces.iter().collect();
        write(&out.join("gt/objects.json"), &serde_json::to_string_pretty(&serde_json::json!({ "scene": self.name, "surfaces": objects }))?)?;
        Ok(())
    }
}

fn save<P: image::Pixel<Subpixel = S> + image::PixelWithColorType, S: image::Primitive>(
    path: &Path,
    img: Option<image::ImageBuffer<P, Vec<S>>>,
) -> Result<()>
where
    [S]: image::EncodableLayout,
{
    let img = img.context("image buffer size")?;
    img.save(path).with_context(|| format!("{}: cannot write", path.display()))
}

fn write(path: &Path, text: &str) -> Result<()> {
    fs::write(path, text).with_context(|| format!("{}: cannot write", path.display()))
}

/// A rendered frame with its ground truth.
#[derive(Debug, Clone)]
pub struct SynthFrame {
    /// The RGB-D frame.
    pub frame: LoadedFrame,
    /// Per pixel: index + 1 of the surface hit (0 = none).
    pub surface: Vec<u16>,
    /// Camera-to-world pose.
    pub pose: Pose,
}

fn unit(seed: u32, k: usize, i: usize, salt: u32) -> f64 {
    mix32(mix32(seed ^ salt) ^ mix32(k as u32).wrapping_add(i as u32)) as f64 / 4_294_967_296.0
}

/// Standard normal sample from two hashed uniforms (Box–Muller).
fn gaussian(seed: u32, k: usize, i: usize) -> f64 {
    let u1 = unit(seed, k, i, 1).max(1e-12);
    let u2 = unit(seed, k, i, 2);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn normalize(a: [f64; 3]) -> [f64; 3] {
    scale(a, 1.0 / dot(a, a).sqrt())
}
fn to_local(p: [f64; 3], yaw: f64) -> [f64; 3] {
    let (c, s) = (yaw.cos(), yaw.sin());
    [c * p[0] + s * p[1], -s * p[0] + c * p[1], p[2]]
}
fn from_local(p: [f64; 3], yaw: f64) -> [f64; 3] {
    let (c, s) = (yaw.cos(), yaw.sin());
    [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]
}
