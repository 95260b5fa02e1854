//! Procedural RGB-D scenes with exact ground truth, ray-cast per pixel: planes, oriented boxes, cylinders,
//! spheres and superquadrics; a smooth hand-held camera path (translation with roll, pitch and yaw); a
//! Kinect-like sensor (depth noise σ(z) = 0.0012 + 0.0019·(z − 0.4)² m, missing depth at grazing angles and at
//! depth edges, quantisation to the TUM factor 5000, shaded colour with noise); instance masks that are perfect
//! or degraded like a real detector ([`Degradation`]). Deterministic for a seed.

use std::fs;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use m2smap_core::points::mix32;
use serde::{Deserialize, Serialize};

use crate::dataset::{Camera, LoadedFrame, Pose};
use crate::masks::{FrameMasks, LabelTable, Pixels};
use m2smap_core::Instance;

/// Geometry of one surface, world frame (z up), metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
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
    /// A solid cylinder with flat caps around the segment centre ± half_height · axis.
    Cylinder {
        /// Centre of the axis segment, metres.
        centre: [f64; 3],
        /// Unit axis direction (any orientation; `[0, 0, 1]` stands upright).
        axis: [f64; 3],
        /// Radius, metres.
        radius: f64,
        /// Half the length along the axis, metres.
        half_height: f64,
    },
    /// A sphere.
    Sphere {
        /// Centre, metres.
        centre: [f64; 3],
        /// Radius, metres.
        radius: f64,
    },
    /// The superquadric F(x) = 1 of docs/pipeline.md ([`sq_inside_outside`]) in local coordinates
    /// x = R_z(yaw)ᵀ(p − centre).
    Superquadric {
        /// Centre, metres.
        centre: [f64; 3],
        /// Half-axes a1, a2, a3 along the local x, y, z axes, metres.
        scales: [f64; 3],
        /// Shape exponents ε1 (z profile) and ε2 (x-y cross-section), in [0.1, 1.9].
        eps: [f64; 2],
        /// Rotation about z, radians.
        yaw: f64,
    },
}

/// The superquadric inside-outside function of docs/pipeline.md at local coordinates `l` (metres):
/// F = ((x/a1)^(2/ε2) + (y/a2)^(2/ε2))^(ε2/ε1) + (z/a3)^(2/ε1), each term computed as ((x/a)²)^(1/ε);
/// 1 on the surface, < 1 inside. The f64 twin of `m2smap_core::superquadric::Superquadric::implicit` (which is
/// f32 and caps far terms); the generator needs f64 to place surfaces to 10⁻⁷ m.
pub fn sq_inside_outside(l: [f64; 3], scales: [f64; 3], eps: [f64; 2]) -> f64 {
    let (t, s) = sq_terms(l, scales, eps);
    s.powf(eps[1] / eps[0]) + t[2]
}

/// The terms (tx, ty, tz) of [`sq_inside_outside`] and the x-y sum S = tx + ty.
fn sq_terms(l: [f64; 3], scales: [f64; 3], eps: [f64; 2]) -> ([f64; 3], f64) {
    let term = |x: f64, a: f64, e: f64| ((x / a) * (x / a)).powf(1.0 / e);
    let t = [term(l[0], scales[0], eps[1]), term(l[1], scales[1], eps[1]), term(l[2], scales[2], eps[0])];
    (t, t[0] + t[1])
}

/// Gradient of [`sq_inside_outside`] at local coordinates `l`: ∂F/∂x = (2/ε1)·(S^(ε2/ε1)/S)·tx/x,
/// ∂F/∂z = (2/ε1)·tz/z (tx/x → 0 at x = 0 for ε < 2).
fn sq_gradient(l: [f64; 3], scales: [f64; 3], eps: [f64; 2]) -> [f64; 3] {
    let (t, s) = sq_terms(l, scales, eps);
    let ratio = |t: f64, x: f64| if x.abs() > 1e-300 { t / x } else { 0.0 };
    let kxy = if s > 1e-300 { (2.0 / eps[0]) * s.powf(eps[1] / eps[0]) / s } else { 0.0 };
    [kxy * ratio(t[0], l[0]), kxy * ratio(t[1], l[1]), (2.0 / eps[0]) * ratio(t[2], l[2])]
}

/// Entry and exit ray parameters of the ray o + t·d through the axis-aligned box [−half, half], with the axis of
/// the entry face; `None` when the ray misses it.
fn slab(o: [f64; 3], d: [f64; 3], half: [f64; 3]) -> Option<(f64, f64, usize)> {
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
    (t_near <= t_far).then_some((t_near, t_far, axis))
}

/// An orthonormal frame (e1, e2, axis) around a unit axis.
fn frame_of(axis: [f64; 3]) -> [[f64; 3]; 3] {
    let helper = if axis[2].abs() < 0.9 { [0.0, 0.0, 1.0] } else { [1.0, 0.0, 0.0] };
    let e1 = normalize(cross(helper, axis));
    [e1, cross(axis, e1), axis]
}

/// Steps of the superquadric ray march per smallest half-axis.
const SQ_STEPS_PER_AXIS: f64 = 64.0;
/// Most march steps along one ray (bounds the loop).
const SQ_MAX_STEPS: usize = 4096;
/// Bisection stops when the bracket is shorter than this along the ray, metres.
const SQ_TOLERANCE: f64 = 1e-8;

impl Shape {
    /// Ray parameter t (the hit is `origin + t·dir`, `dir` need not be unit) and outward unit world normal of the
    /// first hit in front of the origin, if any. Solids are seen from outside; planes from the side the normal
    /// points to.
    pub fn intersect(&self, origin: [f64; 3], dir: [f64; 3]) -> Option<(f64, [f64; 3])> {
        match *self {
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
                let (t_near, _, axis) = slab(o, d, half)?;
                if t_near <= 0.0 {
                    return None;
                }
                let mut n = [0.0; 3];
                n[axis] = -d[axis].signum();
                Some((t_near, from_local(n, yaw)))
            }
            Shape::Cylinder { centre, axis, radius, half_height } => {
                let f = frame_of(axis);
                let rel = sub(origin, centre);
                let (o, d) = (
                    [dot(f[0], rel), dot(f[1], rel), dot(f[2], rel)],
                    [dot(f[0], dir), dot(f[1], dir), dot(f[2], dir)],
                );
                let mut best: Option<(f64, [f64; 3])> = None;
                // Lateral surface: the entering root of (ox + t·dx)² + (oy + t·dy)² = r².
                let a = d[0] * d[0] + d[1] * d[1];
                if a > 1e-18 {
                    let b = o[0] * d[0] + o[1] * d[1];
                    let c = o[0] * o[0] + o[1] * o[1] - radius * radius;
                    let disc = b * b - a * c;
                    if disc >= 0.0 {
                        let t = (-b - disc.sqrt()) / a;
                        let z = o[2] + t * d[2];
                        if t > 0.0 && z.abs() <= half_height {
                            let (x, y) = (o[0] + t * d[0], o[1] + t * d[1]);
                            best = Some((t, [x / radius, y / radius, 0.0]));
                        }
                    }
                }
                // Caps: the one facing the ray.
                if d[2].abs() > 1e-12 {
                    let s = -d[2].signum();
                    let t = (s * half_height - o[2]) / d[2];
                    let (x, y) = (o[0] + t * d[0], o[1] + t * d[1]);
                    if t > 0.0 && x * x + y * y <= radius * radius && best.filter(|b| b.0 <= t).is_none() {
                        best = Some((t, [0.0, 0.0, s]));
                    }
                }
                best.map(|(t, n)| (t, add(add(scale(f[0], n[0]), scale(f[1], n[1])), scale(f[2], n[2]))))
            }
            Shape::Sphere { centre, radius } => {
                let o = sub(origin, centre);
                let (a, b, c) = (dot(dir, dir), dot(o, dir), dot(o, o) - radius * radius);
                let disc = b * b - a * c;
                if disc < 0.0 {
                    return None;
                }
                let t = (-b - disc.sqrt()) / a;
                (t > 0.0).then(|| (t, scale(add(o, scale(dir, t)), 1.0 / radius)))
            }
            Shape::Superquadric { centre, scales, eps, yaw } => {
                // Bounding box first, then march along the ray in steps of 1/64 of the smallest half-axis (at most
                // SQ_MAX_STEPS) for the first sign change of F − 1, and bisect that bracket to SQ_TOLERANCE. A ray
                // whose chord through the shape is shorter than one step can be missed (silhouette pixels only).
                let (o, d) = (to_local(sub(origin, centre), yaw), to_local(dir, yaw));
                let (t_near, t_far, _) = slab(o, d, scales)?;
                if t_far <= 0.0 {
                    return None;
                }
                let inside = |t: f64| sq_inside_outside(add(o, scale(d, t)), scales, eps) <= 1.0;
                let hit = |t: f64| {
                    let l = add(o, scale(d, t));
                    (t, from_local(normalize_or_radial(sq_gradient(l, scales, eps), l), yaw))
                };
                let t0 = t_near.max(0.0);
                if inside(t0) {
                    // F ≥ 1 on the bounding box, so this is a touching entry point, or the origin is inside.
                    return (t_near > 0.0).then(|| hit(t0));
                }
                let len = dot(d, d).sqrt();
                let smallest = scales[0].min(scales[1]).min(scales[2]);
                let steps =
                    (((t_far - t0) * len * SQ_STEPS_PER_AXIS / smallest).ceil() as usize).clamp(1, SQ_MAX_STEPS);
                let step = (t_far - t0) / steps as f64;
                let mut lo = t0;
                for j in 1..=steps {
                    let mut hi = t0 + step * j as f64;
                    if inside(hi) {
                        for _ in 0..128 {
                            if (hi - lo) * len < SQ_TOLERANCE {
                                break;
                            }
                            let mid = 0.5 * (lo + hi);
                            if inside(mid) {
                                hi = mid;
                            } else {
                                lo = mid;
                            }
                        }
                        return Some(hit(0.5 * (lo + hi)));
                    }
                    lo = hi;
                }
                None
            }
        }
    }

    /// Unsigned distance from a world point to the surface, metres: |[`Shape::signed_distance`]|.
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        self.signed_distance(p).abs()
    }

    /// Signed distance from a world point to the surface, metres: negative inside. The inside of a plane is the
    /// half-space behind it (n·x < offset: below a floor, behind a wall); that of a box, cylinder, sphere or
    /// superquadric is the solid. Exact for planes, boxes, cylinders and spheres; for a superquadric it is the
    /// radial distance ‖l‖·(1 − F(l)^(−ε1/2)) (along the ray from the centre through the point, using
    /// F(λl) = λ^(2/ε1)·F(l)), exact on that ray and an over-estimate of |d| elsewhere, good to a few per cent
    /// near the surface of the smooth shapes used here (−min aᵢ at the centre).
    pub fn signed_distance(&self, p: [f64; 3]) -> f64 {
        match *self {
            Shape::Plane { normal, offset } => dot(normal, p) - offset,
            Shape::Box { centre, half, yaw } => {
                let q = to_local(sub(p, centre), yaw);
                let d = [q[0].abs() - half[0], q[1].abs() - half[1], q[2].abs() - half[2]];
                let outside = [d[0].max(0.0), d[1].max(0.0), d[2].max(0.0)];
                let inside = d[0].max(d[1]).max(d[2]).min(0.0);
                dot(outside, outside).sqrt() + inside
            }
            Shape::Cylinder { centre, axis, radius, half_height } => {
                let rel = sub(p, centre);
                let along = dot(rel, axis);
                let radial = sub(rel, scale(axis, along));
                let d = [dot(radial, radial).sqrt() - radius, along.abs() - half_height];
                let outside = (d[0].max(0.0).powi(2) + d[1].max(0.0).powi(2)).sqrt();
                outside + d[0].max(d[1]).min(0.0)
            }
            Shape::Sphere { centre, radius } => {
                let rel = sub(p, centre);
                dot(rel, rel).sqrt() - radius
            }
            Shape::Superquadric { centre, scales, eps, yaw } => {
                let l = to_local(sub(p, centre), yaw);
                let r = dot(l, l).sqrt();
                let f = sq_inside_outside(l, scales, eps);
                if r < 1e-12 || f <= 0.0 {
                    return -scales[0].min(scales[1]).min(scales[2]); // at the centre
                }
                if !f.is_finite() {
                    return r; // so far out that F overflows: the shape is a point next to r
                }
                r * (1.0 - f.powf(-0.5 * eps[0]))
            }
        }
    }
}

/// `v` normalised, or the direction of `l` when `v` vanishes.
fn normalize_or_radial(v: [f64; 3], l: [f64; 3]) -> [f64; 3] {
    let n = dot(v, v).sqrt();
    if n > 1e-300 && n.is_finite() {
        scale(v, 1.0 / n)
    } else if dot(l, l) > 0.0 {
        normalize(l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// One surface of a scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// Ray parameter and outward world normal of the first hit ([`Shape::intersect`]).
    pub fn intersect(&self, origin: [f64; 3], dir: [f64; 3]) -> Option<(f64, [f64; 3])> {
        self.shape.intersect(origin, dir)
    }

    /// Distance from a world point to this surface, metres ([`Shape::distance`]).
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        self.shape.distance(p)
    }

    /// Signed distance from a world point to this surface, metres, negative inside ([`Shape::signed_distance`]).
    pub fn signed_distance(&self, p: [f64; 3]) -> f64 {
        self.shape.signed_distance(p)
    }
}

/// The true surfaces of a synthetic dataset, world frame: the `surfaces` of a `gt/objects.json` written by
/// [`Scene::write_tum_degraded`]; `None` when the file has no `surfaces` (e.g. YCB-Video's list of labels).
pub fn read_surfaces(path: &Path) -> Result<Option<Vec<Surface>>> {
    let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let malformed = |e: serde_json::Error| anyhow!("{}: malformed ground-truth objects: {e}", path.display());
    let mut json: serde_json::Value = serde_json::from_str(&text).map_err(malformed)?;
    match json.get_mut("surfaces").map(serde_json::Value::take) {
        Some(surfaces) => Ok(Some(serde_json::from_value(surfaces).map_err(malformed)?)),
        None => Ok(None),
    }
}

/// A scene: its surfaces, camera and camera path.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Name (one of [`SCENES`], or the caller's for [`Scene::custom`]).
    pub name: String,
    /// Surfaces.
    pub surfaces: Vec<Surface>,
    /// Camera model.
    pub camera: Camera,
    eye: [f64; 3],
    target: [f64; 3],
}

/// The names of the built-in scenes.
pub const SCENES: [&str; 6] = ["tabletop", "shelf", "desk", "kitchen", "clutter", "dining"];

/// Depth step between 4-neighbours above which the sensor may lose both pixels (a depth edge), metres.
pub const EDGE_STEP: f64 = 0.04;
/// Probability of losing a depth-edge pixel.
pub const EDGE_DROPOUT: f64 = 0.5;
/// |cos| of the incidence angle below which a pixel is grazing.
pub const GRAZING_COS: f64 = 0.1;
/// Probability of losing a grazing pixel.
pub const GRAZING_DROPOUT: f64 = 0.5;

/// Hash salts of the independent random streams (one per use, so the streams never correlate).
mod salt {
    pub const GRAZING: u32 = 0;
    pub const EDGE: u32 = 3;
    pub const COLOUR: u32 = 0x5eed;
    pub const MISS: u32 = 0x4d15;
    pub const SCORE: u32 = 0x5c0e;
}

fn plane(name: &str, normal: [f64; 3], offset: f64, colour: [u8; 3]) -> Surface {
    Surface { name: name.into(), instance: 0, label: String::new(), shape: Shape::Plane { normal, offset }, colour }
}

fn cuboid(
    name: &str,
    instance: u16,
    label: &str,
    centre: [f64; 3],
    half: [f64; 3],
    yaw: f64,
    colour: [u8; 3],
) -> Surface {
    Surface { name: name.into(), instance, label: label.into(), shape: Shape::Box { centre, half, yaw }, colour }
}

fn object(name: &str, instance: u16, label: &str, shape: Shape, colour: [u8; 3]) -> Surface {
    Surface { name: name.into(), instance, label: label.into(), shape, colour }
}

/// A table: a 4 cm top (structure, instance 0) with its upper face at `top` metres on four legs, centred at (x, y).
fn table(x: f64, y: f64, half: [f64; 2], top: f64, colour: [u8; 3]) -> Vec<Surface> {
    table_instance(x, y, half, top, 0, "", colour)
}

/// [`table`] with all five parts (top and legs) carrying `instance` and `label`: one non-convex instance when
/// `instance` ≥ 1. The legs (5 cm square, inset 2.5 cm) reach from the floor to the underside of the top.
fn table_instance(
    x: f64,
    y: f64,
    half: [f64; 2],
    top: f64,
    instance: u16,
    label: &str,
    colour: [u8; 3],
) -> Vec<Surface> {
    let mut v = vec![cuboid("table_top", instance, label, [x, y, top - 0.02], [half[0], half[1], 0.02], 0.0, colour)];
    for (k, (sx, sy)) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)].into_iter().enumerate() {
        let c = [x + sx * (half[0] - 0.05), y + sy * (half[1] - 0.05), 0.5 * (top - 0.04)];
        v.push(cuboid(&format!("table_leg{k}"), instance, label, c, [0.025, 0.025, 0.5 * (top - 0.04)], 0.0, colour));
    }
    v
}

impl Scene {
    /// A built-in scene by name (one of [`SCENES`]).
    pub fn named(name: &str) -> Result<Scene> {
        let camera = Camera::preset("fr3").context("fr3 preset")?;
        let (default_eye, default_target) = ([0.1, -1.1, 1.25], [0.0, 0.9, 0.25]);
        let (surfaces, eye, target) = match name {
            // Two boxes standing apart on a floor in front of a wall.
            "tabletop" => (
                vec![
                    plane("floor", [0.0, 0.0, 1.0], 0.0, [150, 140, 120]),
                    plane("wall", [0.0, -1.0, 0.0], -1.6, [200, 200, 190]),
                    cuboid("box_a", 1, "box", [-0.35, 0.75, 0.2], [0.2, 0.15, 0.2], 0.3, [200, 60, 50]),
                    cuboid("box_b", 2, "box", [0.4, 0.95, 0.15], [0.15, 0.15, 0.15], -0.4, [50, 90, 200]),
                ],
                default_eye,
                default_target,
            ),
            // A box touching another box and the wall, a flat slab lying on the floor.
            "shelf" => (
                vec![
                    plane("floor", [0.0, 0.0, 1.0], 0.0, [140, 150, 130]),
                    plane("wall", [0.0, -1.0, 0.0], -1.4, [210, 200, 200]),
                    cuboid("cabinet", 1, "cabinet", [0.0, 1.1, 0.35], [0.35, 0.3, 0.35], 0.0, [120, 80, 40]),
                    cuboid("crate", 2, "box", [-0.55, 1.0, 0.2], [0.2, 0.2, 0.2], 0.0, [60, 160, 60]),
                    cuboid("slab", 3, "laptop", [0.45, 0.5, 0.015], [0.17, 0.12, 0.015], 0.2, [40, 40, 45]),
                ],
                default_eye,
                default_target,
            ),
            // Flat objects on the floor: a 2 cm board as large as a table top (plane-sized, σ0, σ1 > τ_s) and a
            // low 8 cm box, both within l_min of the floor plane, beside a tall box.
            "desk" => (
                vec![
                    plane("floor", [0.0, 0.0, 1.0], 0.0, [150, 150, 140]),
                    plane("wall", [0.0, -1.0, 0.0], -1.8, [205, 205, 195]),
                    cuboid("board", 1, "laptop", [-0.25, 0.55, 0.01], [0.32, 0.26, 0.01], 0.15, [35, 35, 40]),
                    cuboid("lowbox", 2, "book", [0.45, 0.45, 0.04], [0.14, 0.11, 0.04], -0.3, [180, 40, 40]),
                    cuboid("tower", 3, "box", [0.3, 1.2, 0.3], [0.15, 0.15, 0.3], 0.2, [40, 120, 200]),
                ],
                default_eye,
                default_target,
            ),
            // A table (top at 0.72 m) with a mug, a ball resting against the mug, a cushion (rounded-box
            // superquadric) leaning on a cereal box, and a bottle lying on its side; all stand on the table top.
            "kitchen" => {
                let top = 0.72;
                let mut v = vec![
                    plane("floor", [0.0, 0.0, 1.0], 0.0, [150, 145, 135]),
                    plane("wall", [0.0, -1.0, 0.0], -1.6, [215, 210, 200]),
                ];
                v.extend(table(0.0, 0.8, [0.55, 0.4], top, [170, 130, 90]));
                let (mug_x, mug_r) = (-0.3, 0.045);
                v.extend([
                    object(
                        "mug",
                        1,
                        "cup",
                        Shape::Cylinder {
                            centre: [mug_x, 0.72, top + 0.06],
                            axis: [0.0, 0.0, 1.0],
                            radius: mug_r,
                            half_height: 0.06,
                        },
                        [230, 230, 225],
                    ),
                    // Touches the mug's side (centre distance = r_mug + r_ball) and the table top.
                    object(
                        "ball",
                        2,
                        "sports ball",
                        Shape::Sphere { centre: [mug_x + mug_r + 0.07, 0.72, top + 0.07], radius: 0.07 },
                        [220, 120, 30],
                    ),
                    // Its back (y = 0.95) touches the cereal box's front face (y = 0.95).
                    object(
                        "cushion",
                        3,
                        "pillow",
                        Shape::Superquadric {
                            centre: [0.2, 0.85, top + 0.06],
                            scales: [0.14, 0.1, 0.06],
                            eps: [0.3, 0.3],
                            yaw: 0.0,
                        },
                        [90, 140, 200],
                    ),
                    cuboid("cereal", 4, "box", [0.22, 0.99, top + 0.15], [0.1, 0.04, 0.15], 0.0, [200, 180, 40]),
                    object(
                        "bottle",
                        5,
                        "bottle",
                        Shape::Cylinder {
                            centre: [-0.05, 0.55, top + 0.04],
                            axis: normalize([0.94, 0.34, 0.0]),
                            radius: 0.04,
                            half_height: 0.1,
                        },
                        [40, 150, 90],
                    ),
                ]);
                (v, [0.1, -0.45, 1.25], [0.0, 0.8, 0.55])
            }
            // Built to provoke adhesion: on the floor, a crate against the wall, a bin (cylinder) against the
            // crate's left side, a ball resting against its front, a pouf (superquadric) against its right side,
            // and a book lying on top of it.
            "clutter" => {
                let wall = 1.3;
                let crate_c = [-0.1, wall - 0.2, 0.2];
                let crate_h = [0.25, 0.2, 0.2];
                let v = vec![
                    plane("floor", [0.0, 0.0, 1.0], 0.0, [140, 140, 150]),
                    plane("wall", [0.0, -1.0, 0.0], -wall, [205, 200, 210]),
                    cuboid("crate", 1, "box", crate_c, crate_h, 0.0, [150, 100, 50]),
                    object(
                        "bin",
                        2,
                        "bin",
                        Shape::Cylinder {
                            centre: [crate_c[0] - crate_h[0] - 0.1, 1.0, 0.2],
                            axis: [0.0, 0.0, 1.0],
                            radius: 0.1,
                            half_height: 0.2,
                        },
                        [60, 60, 70],
                    ),
                    object(
                        "ball",
                        3,
                        "sports ball",
                        Shape::Sphere { centre: [0.0, crate_c[1] - crate_h[1] - 0.12, 0.12], radius: 0.12 },
                        [230, 60, 60],
                    ),
                    object(
                        "pouf",
                        4,
                        "pouf",
                        Shape::Superquadric {
                            centre: [crate_c[0] + crate_h[0] + 0.12, 1.05, 0.15],
                            scales: [0.12, 0.15, 0.15],
                            eps: [0.6, 0.8],
                            yaw: 0.0,
                        },
                        [80, 170, 110],
                    ),
                    cuboid(
                        "book",
                        5,
                        "book",
                        [-0.15, 1.1, 2.0 * crate_h[2] + 0.04],
                        [0.12, 0.09, 0.04],
                        0.4,
                        [40, 70, 160],
                    ),
                ];
                (v, [-0.05, -0.25, 1.2], [-0.05, 0.95, 0.2])
            }
            // Built to provoke superquadrics that grow through supports and span non-convex objects: a masked
            // dining table (top and four legs are ONE instance, which no single superquadric describes) carrying a
            // yawed box, an upright can and a stack of two boxes (each its own instance, the small one resting on
            // the wide one), and a crate on the floor beside the table. The camera looks down at ~48° with the
            // whole table (legs included) and the crate in view along the path.
            "dining" => {
                let top = 0.74;
                let mut v = vec![
                    plane("floor", [0.0, 0.0, 1.0], 0.0, [145, 140, 130]),
                    plane("wall", [0.0, -1.0, 0.0], -1.7, [210, 205, 215]),
                ];
                v.extend(table_instance(0.0, 0.8, [0.55, 0.4], top, 1, "dining table", [160, 115, 75]));
                let (stack_c, stack_h) = ([0.27, 0.82], [0.12, 0.09, 0.04]);
                v.extend([
                    cuboid("box", 2, "box", [-0.3, 0.88, top + 0.11], [0.08, 0.05, 0.11], 0.5, [200, 60, 50]),
                    object(
                        "can",
                        3,
                        "can",
                        Shape::Cylinder {
                            centre: [-0.08, 0.6, top + 0.06],
                            axis: [0.0, 0.0, 1.0],
                            radius: 0.035,
                            half_height: 0.06,
                        },
                        [200, 200, 210],
                    ),
                    // The wide box of the stack, and a smaller one resting on it (touching at z = top + 0.08).
                    cuboid(
                        "stack_low",
                        4,
                        "book",
                        [stack_c[0], stack_c[1], top + stack_h[2]],
                        stack_h,
                        -0.15,
                        [50, 90, 190],
                    ),
                    cuboid(
                        "stack_high",
                        5,
                        "box",
                        [stack_c[0] + 0.01, stack_c[1] - 0.01, top + 2.0 * stack_h[2] + 0.04],
                        [0.06, 0.05, 0.04],
                        0.35,
                        [230, 190, 40],
                    ),
                    // On the floor, right of the table (clear of its legs and top).
                    cuboid("crate", 6, "box", [0.82, 0.72, 0.13], [0.12, 0.1, 0.13], 0.3, [70, 150, 80]),
                ]);
                (v, [0.2, -0.45, 1.85], [0.05, 0.8, 0.45])
            }
            other => bail!("unknown scene {other:?} (known: {})", SCENES.join(", ")),
        };
        Ok(Scene { name: name.into(), surfaces, camera, eye, target })
    }

    /// A scene of the caller's surfaces seen by `camera` along the camera path of [`Scene::pose`] around the
    /// eye and target points (world frame, metres).
    pub fn custom(name: &str, surfaces: Vec<Surface>, camera: Camera, eye: [f64; 3], target: [f64; 3]) -> Scene {
        Scene { name: name.into(), surfaces, camera, eye, target }
    }

    /// Camera-to-world pose at frame `k`: a slow hand-held sway of the eye (translation) and the looked-at
    /// point (pitch and yaw) with a small roll.
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

    /// World direction of the ray through pixel (u, v), scaled so that its camera z component is 1 (the ray
    /// parameter of a hit is then its depth).
    fn ray(&self, rot: &[[f64; 3]; 3], u: usize, v: usize) -> [f64; 3] {
        let cam = self.camera;
        let dc = [(u as f64 - cam.cx as f64) / cam.fx as f64, (v as f64 - cam.cy as f64) / cam.fy as f64, 1.0];
        [dot(rot[0], dc), dot(rot[1], dc), dot(rot[2], dc)]
    }

    /// The exact ray-cast of frame `k` (no sensor model, no quantisation).
    pub fn trace(&self, k: usize) -> Trace {
        let pose = self.pose(k);
        let rot = pose.rotation();
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let mut tr = Trace { depth: vec![0.0; w * h], surface: vec![0; w * h], normal: vec![[0.0; 3]; w * h], pose };
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                let dw = self.ray(&rot, u, v);
                let hit = self
                    .surfaces
                    .iter()
                    .enumerate()
                    .filter_map(|(s, surf)| surf.intersect(pose.t, dw).map(|(t, n)| (t, n, s)))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                if let Some((z, n, s)) = hit {
                    (tr.depth[i], tr.normal[i], tr.surface[i]) = (z, n, s as u16 + 1);
                }
            }
        }
        tr
    }

    /// Renders frame `k`. With `noise = Some(seed)` the sensor model is applied (grazing-angle and depth-edge
    /// dropout, depth noise σ(z), colour noise); without it depth is exact up to the 1/5000 m quantisation and
    /// colour is noise-free.
    pub fn render(&self, k: usize, noise: Option<u32>) -> SynthFrame {
        let cam = self.camera;
        let tr = self.trace(k);
        let rot = tr.pose.rotation();
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut frame = SynthFrame {
            frame: LoadedFrame {
                width: cam.width,
                height: cam.height,
                depth: vec![0; w * h],
                colour: vec![0; w * h * 3],
            },
            surface: vec![0; w * h],
            pose: tr.pose,
        };
        let light = normalize([0.3, -0.5, 0.8]);
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                if tr.surface[i] == 0 {
                    continue;
                }
                let surf = &self.surfaces[tr.surface[i] as usize - 1];
                let n = tr.normal[i];
                let mut z = tr.depth[i];
                if let Some(seed) = noise {
                    let grazing = dot(n, normalize(self.ray(&rot, u, v))).abs();
                    if grazing < GRAZING_COS && unit(seed, k, i, salt::GRAZING) < GRAZING_DROPOUT {
                        continue; // grazing-angle dropout
                    }
                    if tr.is_depth_edge(w, h, u, v) && unit(seed, k, i, salt::EDGE) < EDGE_DROPOUT {
                        continue; // depth-edge dropout
                    }
                    z += (0.0012 + 0.0019 * (z - 0.4).powi(2)) * gaussian(seed, k, i);
                }
                let raw = (z * 5000.0).round();
                if !(1.0..65535.0).contains(&raw) {
                    continue;
                }
                frame.frame.depth[i] = raw as u16;
                frame.surface[i] = tr.surface[i];
                let shade = 0.35 + 0.65 * dot(n, light).abs();
                for c in 0..3 {
                    let jitter = noise.map_or(0.0, |seed| 6.0 * gaussian(seed ^ salt::COLOUR, k, i * 3 + c));
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

    /// The label of object instance `id` (`object` when no surface has it).
    fn label_of(&self, id: u16) -> &str {
        self.surfaces.iter().find(|s| s.instance == id).map_or("object", |s| s.label.as_str())
    }

    /// Masks of an id image: one instance per id present (tight box), scored by `score(id)`.
    fn masks_of(&self, ids: Vec<u16>, labels: &mut LabelTable, score: impl Fn(u16) -> f32) -> FrameMasks {
        let w = self.camera.width as usize;
        let mut instances: Vec<Instance> = Vec::new();
        for (i, &id) in ids.iter().enumerate() {
            if id == 0 {
                continue;
            }
            let (u, v) = ((i % w) as u16, (i / w) as u16);
            match instances.iter_mut().find(|x| x.id == id) {
                Some(x) => x.bbox = [x.bbox[0].min(u), x.bbox[1].min(v), x.bbox[2].max(u), x.bbox[3].max(v)],
                None => instances.push(Instance {
                    id,
                    class: labels.class_of(self.label_of(id)),
                    score: score(id),
                    bbox: [u, v, u, v],
                }),
            }
        }
        instances.sort_by_key(|x| x.id);
        FrameMasks { width: self.camera.width, height: self.camera.height, instances, pixels: Pixels::Ids(ids) }
    }

    /// Perfect instance masks of a rendered frame: the ground-truth instance image and one instance per visible
    /// object (score 1, tight box).
    pub fn perfect_masks(&self, frame: &SynthFrame, labels: &mut LabelTable) -> FrameMasks {
        self.masks_of(self.instance_image(frame), labels, |_| 1.0)
    }

    /// Instance masks of frame `k` degraded like a real detector (see [`Degradation`]; the default gives
    /// [`Scene::perfect_masks`]). Random choices are hashed from `seed`, `k` and the instance id.
    pub fn degraded_masks(
        &self,
        frame: &SynthFrame,
        k: usize,
        seed: u32,
        d: &Degradation,
        labels: &mut LabelTable,
    ) -> FrameMasks {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let mut ids = self.instance_image(frame);
        for _ in 0..d.erode {
            ids = erode_once(&ids, w, h);
        }
        for _ in 0..d.dilate {
            ids = dilate_once(&ids, w, h);
        }
        if d.miss > 0.0 {
            for id in ids.iter_mut() {
                if *id != 0 && unit(seed, k, *id as usize, salt::MISS) < d.miss {
                    *id = 0;
                }
            }
        }
        let s = d.score_noise;
        self.masks_of(ids, labels, |id| {
            if s > 0.0 {
                (1.0 - (s * gaussian(seed ^ salt::SCORE, k, id as usize)).abs()).clamp(0.05, 1.0) as f32
            } else {
                1.0
            }
        })
    }

    /// Writes `frames` frames as a TUM folder with `groundtruth.txt`, `camera.json`, `gt/` and perfect `masks/`.
    pub fn write_tum(&self, out: &Path, frames: usize, seed: u32, noise: bool) -> Result<()> {
        self.write_tum_degraded(out, frames, seed, noise, &Degradation::default())
    }

    /// [`Scene::write_tum`] with `masks/` degraded by `degradation` (seeded by `seed`); `gt/` stays exact and
    /// `gt/objects.json` records the seed, the noise switch and the degradation.
    pub fn write_tum_degraded(
        &self,
        out: &Path,
        frames: usize,
        seed: u32,
        noise: bool,
        degradation: &Degradation,
    ) -> Result<()> {
        degradation.validate()?;
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
            save(
                &out.join(format!("depth/{stem}.png")),
                image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, f.frame.depth.clone()),
            )?;
            save(
                &out.join(format!("gt/{stem}.png")),
                image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, self.instance_image(&f)),
            )?;
            let masks = self.degraded_masks(&f, k, seed, degradation, &mut LabelTable::default());
            if let Pixels::Ids(ids) = &masks.pixels {
                save(
                    &out.join(format!("masks/{stem}.png")),
                    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, ids.clone()),
                )?;
            }
            let list: Vec<serde_json::Value> = masks
                .instances
                .iter()
                .map(|i| serde_json::json!({ "id": i.id, "label": self.label_of(i.id), "score": i.score, "bbox": i.bbox }))
                .collect();
            write(
                &out.join(format!("masks/{stem}.json")),
                &serde_json::to_string(&serde_json::json!({ "instances": list }))?,
            )?;
            rgb_list.push_str(&format!("{stem} rgb/{stem}.png\n"));
            depth_list.push_str(&format!("{stem} depth/{stem}.png\n"));
            let (p, q) = (f.pose.t, f.pose.q);
            gt_list.push_str(&format!(
                "{stem} {:.6} {:.6} {:.6} {:.6} {:.6} {:.6} {:.6}\n",
                p[0], p[1], p[2], q[0], q[1], q[2], q[3]
            ));
        }
        write(&out.join("rgb.txt"), &rgb_list)?;
        write(&out.join("depth.txt"), &depth_list)?;
        write(&out.join("groundtruth.txt"), &gt_list)?;
        write(&out.join("camera.json"), &serde_json::to_string_pretty(&self.camera)?)?;
        let objects: Vec<&Surface> = self.surfaces.iter().collect();
        let json = serde_json::json!({
            "scene": self.name,
            "seed": seed,
            "noise": noise,
            "mask_degradation": degradation,
            "surfaces": objects,
        });
        write(&out.join("gt/objects.json"), &serde_json::to_string_pretty(&json)?)?;
        Ok(())
    }
}

/// How `masks/` departs from the exact instance image, like a real detector. The default is off (perfect masks).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Degradation {
    /// Erode each instance's region by this many pixels (4-neighbour steps, so a diamond of that radius).
    pub erode: u32,
    /// Then dilate each instance's region by this many pixels into unlabelled pixels only (other instances are
    /// never overwritten; where two instances grow into the same pixel the smaller id wins).
    pub dilate: u32,
    /// Then drop each instance in each frame with this probability, in [0, 1].
    pub miss: f64,
    /// Score = clamp(1 − |N(0, σ)|, 0.05, 1) with this σ ≥ 0 (0: every score is 1).
    pub score_noise: f64,
}

impl Degradation {
    /// Whether the masks come out perfect.
    pub fn is_off(&self) -> bool {
        *self == Degradation::default()
    }

    /// Rejects a miss probability outside [0, 1] or a negative or non-finite score noise.
    pub fn validate(&self) -> Result<()> {
        if !(0.0..=1.0).contains(&self.miss) {
            bail!("mask miss probability {} is outside [0, 1]", self.miss);
        }
        if !(self.score_noise.is_finite() && self.score_noise >= 0.0) {
            bail!("mask score noise {} must be a finite number ≥ 0", self.score_noise);
        }
        Ok(())
    }
}

/// One step of erosion: a pixel keeps its id when its 4-neighbours inside the image all have it.
fn erode_once(ids: &[u16], w: usize, h: usize) -> Vec<u16> {
    let mut out = ids.to_vec();
    for v in 0..h {
        for u in 0..w {
            let id = ids[v * w + u];
            if id != 0 && neighbours(w, h, u, v).any(|j| ids[j] != id) {
                out[v * w + u] = 0;
            }
        }
    }
    out
}

/// One step of dilation: an unlabelled pixel takes the smallest id among its 4-neighbours.
fn dilate_once(ids: &[u16], w: usize, h: usize) -> Vec<u16> {
    let mut out = ids.to_vec();
    for v in 0..h {
        for u in 0..w {
            if ids[v * w + u] == 0 {
                out[v * w + u] = neighbours(w, h, u, v).map(|j| ids[j]).filter(|&id| id != 0).min().unwrap_or(0);
            }
        }
    }
    out
}

/// Indices of the 4-neighbours of (u, v) inside a `w × h` image.
fn neighbours(w: usize, h: usize, u: usize, v: usize) -> impl Iterator<Item = usize> {
    let left = (u > 0).then(|| v * w + u - 1);
    let right = (u + 1 < w).then(|| v * w + u + 1);
    let up = (v > 0).then(|| (v - 1) * w + u);
    let down = (v + 1 < h).then(|| (v + 1) * w + u);
    [left, right, up, down].into_iter().flatten()
}

/// The exact ray-cast of one frame: per pixel (row-major) the depth, the surface hit and its normal.
#[derive(Debug, Clone)]
pub struct Trace {
    /// Exact depth (camera z) of the first hit, metres; 0 where the ray hits nothing.
    pub depth: Vec<f64>,
    /// Index + 1 of the surface hit (0 = none).
    pub surface: Vec<u16>,
    /// Outward unit world normal of the hit (zero where nothing is hit).
    pub normal: Vec<[f64; 3]>,
    /// Camera-to-world pose.
    pub pose: Pose,
}

impl Trace {
    /// Whether pixel (u, v) lies on a depth edge: a 4-neighbour that hits nothing or differs by more than
    /// [`EDGE_STEP`].
    pub fn is_depth_edge(&self, w: usize, h: usize, u: usize, v: usize) -> bool {
        let z = self.depth[v * w + u];
        neighbours(w, h, u, v).any(|j| self.surface[j] == 0 || (self.depth[j] - z).abs() > EDGE_STEP)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    /// Checks `signed_distance` at points with a closed-form answer, and `distance` = |signed|.
    fn check(shape: Shape, cases: &[([f64; 3], f64)]) {
        for &(p, expected) in cases {
            let d = shape.signed_distance(p);
            assert!(close(d, expected), "{shape:?} at {p:?}: {d} ≠ {expected}");
            assert!(close(shape.distance(p), expected.abs()));
        }
    }

    #[test]
    fn signed_distance_of_a_plane_is_negative_behind_it() {
        // Floor: 3 cm below is −0.03. Wall y = 1.6 facing −y: 5 cm behind it (y = 1.65) is −0.05.
        check(
            Shape::Plane { normal: [0.0, 0.0, 1.0], offset: 0.0 },
            &[([0.3, -2.0, -0.03], -0.03), ([1.0, 1.0, 0.2], 0.2)],
        );
        check(
            Shape::Plane { normal: [0.0, -1.0, 0.0], offset: -1.6 },
            &[([0.0, 1.65, 1.0], -0.05), ([0.0, 1.0, 0.0], 0.6)],
        );
    }

    #[test]
    fn signed_distance_of_a_rotated_box() {
        let (centre, yaw) = ([1.0, 2.0, 0.5], 0.5);
        let shape = Shape::Box { centre, half: [0.1, 0.2, 0.3], yaw };
        let at = |l: [f64; 3]| add(centre, from_local(l, yaw));
        check(
            shape,
            &[
                (at([0.15, 0.0, 0.0]), 0.05),   // in front of the +x face
                (at([0.05, 0.0, 0.0]), -0.05),  // inside, nearest the +x face
                (at([0.0, 0.0, 0.0]), -0.1),    // the centre: the nearest face is 0.1 away
                (at([0.0, -0.17, 0.1]), -0.03), // inside, nearest the −y face
                (at([0.13, 0.24, 0.0]), 0.05),  // beyond an edge: √(0.03² + 0.04²)
                (at([0.0, 0.0, -0.32]), 0.02),  // below the bottom
            ],
        );
    }

    #[test]
    fn signed_distance_of_a_tilted_cylinder() {
        let axis = normalize([1.0, 0.0, 1.0]);
        let centre = [0.2, 0.3, 0.4];
        let shape = Shape::Cylinder { centre, axis, radius: 0.05, half_height: 0.1 };
        let radial = [0.0, 1.0, 0.0]; // perpendicular to the axis
        let at = |r: f64, h: f64| add(centre, add(scale(radial, r), scale(axis, h)));
        check(
            shape,
            &[
                (at(0.07, 0.0), 0.02),  // beside the lateral surface
                (at(0.03, 0.0), -0.02), // inside, nearest the lateral surface
                (at(0.0, 0.08), -0.02), // inside, nearest the cap
                (at(0.0, 0.13), 0.03),  // beyond the cap
                (at(0.08, 0.14), 0.05), // beyond the rim: √(0.03² + 0.04²)
            ],
        );
    }

    #[test]
    fn signed_distance_of_a_sphere() {
        let shape = Shape::Sphere { centre: [0.1, 0.2, 0.3], radius: 0.07 };
        check(shape, &[([0.1, 0.2, 0.4], 0.03), ([0.13, 0.2, 0.3], -0.04), ([0.1, 0.2, 0.3], -0.07)]);
    }

    #[test]
    fn signed_distance_of_a_superquadric_along_its_rays() {
        // ε = (1, 1) with equal half-axes is a sphere: r − a everywhere.
        let ball = Shape::Superquadric { centre: [0.0, 0.0, 1.0], scales: [0.1; 3], eps: [1.0, 1.0], yaw: 0.0 };
        check(ball, &[([0.0, 0.0, 1.25], 0.15), ([0.03, 0.04, 1.0], -0.05), ([0.0, 0.06, 1.08], 0.0)]);
        // A rotated box-like superquadric: along a local axis F = (x/a)^(2/ε), so the radial distance is x − a.
        let (centre, yaw) = ([0.5, -0.2, 0.3], 0.7);
        let shape = Shape::Superquadric { centre, scales: [0.14, 0.1, 0.06], eps: [0.3, 0.3], yaw };
        let at = |l: [f64; 3]| add(centre, from_local(l, yaw));
        check(
            shape,
            &[
                (at([0.2, 0.0, 0.0]), 0.06),
                (at([0.1, 0.0, 0.0]), -0.04),
                (at([0.0, -0.13, 0.0]), 0.03),
                (at([0.0, 0.0, -0.05]), -0.01),
                (centre, -0.06), // the centre: minus the smallest half-axis
            ],
        );
    }
}
