//! A small ray caster that draws a map's primitives as solid shapes: each superquadric through its
//! inside-outside function F (the surface F = 1), each Gaussian as its ellipsoid at Mahalanobis distance
//! [`GAUSSIAN_EXTENT`], each bounded plane as its occupied cells. Shading is Lambertian by the surface normal with
//! one light above and behind the viewer, plus ambient; depth edges are outlined. Used by `m2smap render` for the
//! camera view (panel (d)) and for views from elsewhere (`--view orbit|top`).
//!
//! Units: metres in the map's frame (the camera frame of the mapped frame), pixels on the image.

use m2smap_core::linalg::{self, Mat3, Vec3};
use m2smap_core::map::{CellBits, CellCoding, Primitive};
use m2smap_core::superquadric::Superquadric;
use m2smap_core::Intrinsics;

/// A Gaussian is drawn as the ellipsoid at this Mahalanobis distance (its reconstruction samples reach 2).
pub const GAUSSIAN_EXTENT: f32 = 2.0;
/// Nothing nearer to the viewpoint than this is drawn, metres (along the view axis).
pub const NEAR: f32 = 0.05;
/// Steps of the march along a ray through a superquadric's bounding box before bisection.
const SQ_MARCH_STEPS: usize = 64;
/// Bisection steps that place a superquadric hit (the bracket shrinks 2^-20).
const SQ_BISECTIONS: usize = 20;
/// Smallest Gaussian half-axis drawn, metres (a flat Gaussian stays a thin disc, not a degenerate one).
const MIN_RADIUS: f32 = 5e-4;

/// What a primitive is, for its colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A bounded plane.
    Plane,
    /// An object superquadric.
    Sq,
    /// A Gaussian.
    Gmm,
}

/// The geometry of one primitive, owned (plane cells copied out of the mapper).
#[derive(Debug, Clone)]
pub enum Shape {
    /// A superquadric surface F = 1.
    Sq(Superquadric),
    /// The ellipsoid {x : |diag(radii)⁻¹ Rᵀ(x − centre)| = 1}, metres.
    Ellipsoid {
        /// Centre, metres.
        centre: Vec3,
        /// Axes as columns.
        rotation: Mat3,
        /// Half-axes, metres.
        radii: Vec3,
    },
    /// The occupied cells of a bounded plane: cell (i, j) is the square of side `g_p` from
    /// centroid + ((a0 + i)·e1 + (b0 + j)·e2)·g_p.
    Cells {
        /// Plane origin (its centroid), metres.
        centroid: Vec3,
        /// Columns e1, e2 and the normal.
        rotation: Mat3,
        /// Cell side, metres.
        g_p: f32,
        /// Cell index of column 0 along e1 and of row 0 along e2.
        origin: (i16, i16),
        /// Columns and rows.
        size: (u16, u16),
        /// Occupancy bits as [`CellBits`] stores them.
        bits: Vec<u8>,
    },
}

/// A primitive to draw: its shape, kind and colour.
#[derive(Debug, Clone)]
pub struct Drawable {
    /// Geometry.
    pub shape: Shape,
    /// Kind.
    pub kind: Kind,
    /// Base colour before shading.
    pub colour: [u8; 3],
}

/// A pinhole viewpoint in the map's frame: pixel (x, y) looks along `rotation · ((x − cx)/fx, (y − cy)/fy, 1)`
/// from `origin` (the rotation's columns are the view's right, down and forward axes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Viewpoint, metres.
    pub origin: Vec3,
    /// View axes as columns: right, down, forward.
    pub rotation: Mat3,
    /// Focal lengths and principal point, pixels.
    pub fx: f32,
    /// See `fx`.
    pub fy: f32,
    /// See `fx`.
    pub cx: f32,
    /// See `fx`.
    pub cy: f32,
    /// Image size, pixels.
    pub width: u32,
    /// See `width`.
    pub height: u32,
}

/// A rendered image: colour and view depth per pixel (row-major; depth `f32::INFINITY` where nothing was hit).
#[derive(Debug, Clone)]
pub struct Image {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Colour per pixel.
    pub colour: Vec<[u8; 3]>,
    /// Depth along the view axis, metres.
    pub depth: Vec<f32>,
    /// Kind of the primitive seen at each pixel.
    pub kind: Vec<Option<Kind>>,
}

impl Shape {
    /// The shape of a map primitive.
    pub fn of(prim: &Primitive<'_>) -> Shape {
        match prim {
            Primitive::Sq(s) => Shape::Sq(s.sq),
            Primitive::Gmm(g) => Shape::Ellipsoid {
                centre: g.mean,
                rotation: g.rotation,
                radii: g.sigmas.map(|s| (GAUSSIAN_EXTENT * s).max(MIN_RADIUS)),
            },
            Primitive::Plane(p) => {
                // Cropped to the occupied cells and expanded to a bitmap (whichever coding the map used) for
                // constant-time lookups.
                let (i0, j0, i1, j1) = p.cells.occupied_box().unwrap_or((0, 0, 0, 0));
                let (w, h) = (i1 - i0 + 1, j1 - j0 + 1);
                let mut bits = vec![0u8; (w * h).div_ceil(8)];
                p.cells.for_each_set(|i, j| {
                    let k = (j - j0) * w + (i - i0);
                    bits[k / 8] |= 1 << (k % 8);
                });
                Shape::Cells {
                    centroid: p.centroid,
                    rotation: p.rotation,
                    g_p: p.g_p,
                    origin: (p.cells.a0 + i0 as i16, p.cells.b0 + j0 as i16),
                    size: (w as u16, h as u16),
                    bits,
                }
            }
        }
    }

    /// A sphere (centre, radius in metres) holding the whole shape.
    pub fn bounding_sphere(&self) -> (Vec3, f32) {
        match self {
            Shape::Sq(s) => (s.centre, linalg::norm(s.scales)),
            Shape::Ellipsoid { centre, radii, .. } => (*centre, radii[0].max(radii[1]).max(radii[2])),
            Shape::Cells { centroid, rotation, g_p, origin, size, .. } => {
                let (u0, v0) = (origin.0 as f32 * g_p, origin.1 as f32 * g_p);
                let (du, dv) = (size.0 as f32 * g_p, size.1 as f32 * g_p);
                let (e1, e2) = (linalg::column(rotation, 0), linalg::column(rotation, 1));
                let mid = linalg::add(linalg::scale(e1, u0 + 0.5 * du), linalg::scale(e2, v0 + 0.5 * dv));
                (linalg::add(*centroid, mid), 0.5 * (du * du + dv * dv).sqrt())
            }
        }
    }

    /// Whether `from` sees the side of a plane's cells that `seen_from` saw (always for other shapes): a
    /// plane was observed from one side only, so from behind it (a wall seen from the far side of the
    /// room) it is left out and does not hide what stands in front of it.
    pub fn faces_the_same_side(&self, from: Vec3, seen_from: Vec3) -> bool {
        match self {
            Shape::Cells { centroid, rotation, .. } => {
                let n = linalg::column(rotation, 2);
                let side = |p: Vec3| linalg::dot(n, linalg::sub(p, *centroid));
                side(from) * side(seen_from) >= 0.0
            }
            _ => true,
        }
    }

    /// The first hit of the ray `o + t·d` with t ≥ `t_min`: (t, outward unit normal), `None` on a miss.
    pub fn hit(&self, o: Vec3, d: Vec3, t_min: f32) -> Option<(f32, Vec3)> {
        match self {
            Shape::Sq(s) => hit_superquadric(s, o, d, t_min),
            Shape::Ellipsoid { centre, rotation, radii } => {
                let whiten = |v: Vec3| {
                    let l = linalg::mat_t_vec(rotation, v);
                    [l[0] / radii[0], l[1] / radii[1], l[2] / radii[2]]
                };
                let (wo, wd) = (whiten(linalg::sub(o, *centre)), whiten(d));
                let a = linalg::dot(wd, wd);
                let b = linalg::dot(wo, wd);
                let c = linalg::dot(wo, wo) - 1.0;
                let disc = b * b - a * c;
                if a <= 0.0 || disc < 0.0 {
                    return None;
                }
                let root = disc.sqrt();
                let t = [(-b - root) / a, (-b + root) / a].into_iter().find(|&t| t >= t_min)?;
                let w = linalg::add(wo, linalg::scale(wd, t));
                let g = linalg::mat_vec(rotation, [w[0] / radii[0], w[1] / radii[1], w[2] / radii[2]]);
                Some((t, linalg::normalize_or(g, [0.0, 0.0, -1.0])))
            }
            Shape::Cells { centroid, rotation, g_p, origin, size, bits } => {
                let n = linalg::column(rotation, 2);
                let denom = linalg::dot(n, d);
                if denom.abs() < 1e-9 {
                    return None;
                }
                let t = linalg::dot(n, linalg::sub(*centroid, o)) / denom;
                if t.is_nan() || t < t_min {
                    return None;
                }
                let rel = linalg::sub(linalg::add(o, linalg::scale(d, t)), *centroid);
                let (e1, e2) = (linalg::column(rotation, 0), linalg::column(rotation, 1));
                let i = (linalg::dot(rel, e1) / g_p).floor() - origin.0 as f32;
                let j = (linalg::dot(rel, e2) / g_p).floor() - origin.1 as f32;
                if i < 0.0 || j < 0.0 || i >= size.0 as f32 || j >= size.1 as f32 {
                    return None;
                }
                let cells = CellBits {
                    a0: origin.0,
                    b0: origin.1,
                    width: size.0,
                    height: size.1,
                    coding: CellCoding::Bitmap,
                    bits,
                };
                cells.is_set(i as usize, j as usize).then_some((t, n))
            }
        }
    }
}

/// The first crossing of F = 1 along `o + t·d` inside the superquadric's bounding box: a march of
/// [`SQ_MARCH_STEPS`] steps to the first point inside, then bisection. The normal is the surface's (∇G).
fn hit_superquadric(s: &Superquadric, o: Vec3, d: Vec3, t_min: f32) -> Option<(f32, Vec3)> {
    let lo = s.local(o);
    let ld = linalg::mat_t_vec(&s.rotation, d);
    // The ray's interval inside the box [−a, a] (slab test).
    let (mut t0, mut t1) = (t_min, f32::INFINITY);
    for k in 0..3 {
        let a = s.scales[k] * 1.001;
        if ld[k].abs() < 1e-12 {
            if lo[k].abs() > a {
                return None;
            }
            continue;
        }
        let (ta, tb) = ((-a - lo[k]) / ld[k], (a - lo[k]) / ld[k]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    if t0.is_nan() || t1.is_nan() || t0 >= t1 {
        return None;
    }
    let inside = |t: f32| s.implicit(linalg::add(lo, linalg::scale(ld, t))) < 1.0;
    if inside(t0) {
        let l = linalg::add(lo, linalg::scale(ld, t0));
        return Some((t0, s.normal_at_local(l)));
    }
    let step = (t1 - t0) / SQ_MARCH_STEPS as f32;
    let mut prev = t0;
    for k in 1..=SQ_MARCH_STEPS {
        let t = t0 + step * k as f32;
        if inside(t) {
            let (mut a, mut b) = (prev, t);
            for _ in 0..SQ_BISECTIONS {
                let m = 0.5 * (a + b);
                if inside(m) {
                    b = m;
                } else {
                    a = m;
                }
            }
            let l = linalg::add(lo, linalg::scale(ld, b));
            return Some((b, s.normal_at_local(l)));
        }
        prev = t;
    }
    None
}

impl View {
    /// The mapped frame's own camera: at the origin, looking down +z.
    pub fn camera(k: &Intrinsics, width: u32, height: u32) -> View {
        View { origin: [0.0; 3], rotation: linalg::IDENTITY, fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy, width, height }
    }

    /// A view from `eye` towards `target` whose image "up" is as close to `up` as the forward axis allows,
    /// with the focal lengths and image size of `like`.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, like: &View) -> View {
        let forward = linalg::normalize_or(linalg::sub(target, eye), [0.0, 0.0, 1.0]);
        let mut right = linalg::cross(forward, up);
        if linalg::norm(right) < 1e-6 {
            right = linalg::cross(forward, [1.0, 0.0, 0.0]);
        }
        let right = linalg::normalize_or(right, [1.0, 0.0, 0.0]);
        let down = linalg::cross(forward, right);
        View { origin: eye, rotation: linalg::from_columns(right, down, forward), ..*like }
    }

    /// Half of the narrower field of view, radians.
    pub fn half_fov(&self) -> f32 {
        (0.5 * self.width as f32 / self.fx).atan().min((0.5 * self.height as f32 / self.fy).atan())
    }

    /// The ray direction of pixel (x, y) in the map's frame (its view-axis component is 1: t is view depth).
    fn ray(&self, x: u32, y: u32) -> Vec3 {
        linalg::mat_vec(&self.rotation, [(x as f32 - self.cx) / self.fx, (y as f32 - self.cy) / self.fy, 1.0])
    }

    /// The pixel box (x0, y0, x1, y1), inclusive, that a sphere can cover; `None` when it is wholly behind.
    fn pixel_box(&self, centre: Vec3, radius: f32) -> Option<(u32, u32, u32, u32)> {
        let c = linalg::mat_t_vec(&self.rotation, linalg::sub(centre, self.origin));
        let (w, h) = (self.width.saturating_sub(1), self.height.saturating_sub(1));
        if c[2] + radius < NEAR {
            return None;
        }
        if c[2] - radius <= NEAR {
            return Some((0, 0, w, h));
        }
        // Extremes of x/z over the sphere, bounded through its box.
        let (zn, zf) = (c[2] - radius, c[2] + radius);
        let hi = |v: f32| if v > 0.0 { v / zn } else { v / zf };
        let lo = |v: f32| if v < 0.0 { v / zn } else { v / zf };
        let u0 = self.cx + self.fx * lo(c[0] - radius);
        let u1 = self.cx + self.fx * hi(c[0] + radius);
        let v0 = self.cy + self.fy * lo(c[1] - radius);
        let v1 = self.cy + self.fy * hi(c[1] + radius);
        if u1 < 0.0 || v1 < 0.0 || u0 > w as f32 || v0 > h as f32 {
            return None;
        }
        let clamp = |x: f32, m: u32| (x.max(0.0) as u32).min(m);
        Some((clamp(u0.floor(), w), clamp(v0.floor(), h), clamp(u1.ceil(), w), clamp(v1.ceil(), h)))
    }
}

/// Every primitive of a map as a [`Drawable`], coloured by `colour(primitive)`.
pub fn drawables(
    for_each: impl FnOnce(&mut dyn FnMut(&Primitive<'_>)),
    colour: impl Fn(&Primitive<'_>) -> [u8; 3],
) -> Vec<Drawable> {
    let mut out = Vec::new();
    for_each(&mut |p: &Primitive<'_>| {
        let kind = match p {
            Primitive::Plane(_) => Kind::Plane,
            Primitive::Sq(_) => Kind::Sq,
            Primitive::Gmm(_) => Kind::Gmm,
        };
        out.push(Drawable { shape: Shape::of(p), kind, colour: colour(p) });
    });
    out
}

/// Ray-casts `items` from `view`: the nearest hit per pixel, shaded, depth edges darkened; `background` where
/// nothing is hit. Planes seen from the side opposite to `seen_from` (the mapped camera's position) are left out
/// ([`Shape::faces_the_same_side`]).
pub fn render(items: &[Drawable], view: &View, seen_from: Vec3, background: [u8; 3]) -> Image {
    let (w, h) = (view.width, view.height);
    let n = (w * h) as usize;
    let mut depth = vec![f32::INFINITY; n];
    let mut normal = vec![[0.0f32; 3]; n];
    let mut owner: Vec<Option<usize>> = vec![None; n];
    for (index, item) in items.iter().enumerate() {
        if !item.shape.faces_the_same_side(view.origin, seen_from) {
            continue;
        }
        let (centre, radius) = item.shape.bounding_sphere();
        let Some((x0, y0, x1, y1)) = view.pixel_box(centre, radius) else { continue };
        for y in y0..=y1 {
            for x in x0..=x1 {
                let j = (y * w + x) as usize;
                let d = view.ray(x, y);
                if let Some((t, nrm)) = item.shape.hit(view.origin, d, NEAR) {
                    if t < depth[j] {
                        depth[j] = t;
                        normal[j] = nrm;
                        owner[j] = Some(index);
                    }
                }
            }
        }
    }
    // A key light above-left and behind the viewer (view axes), plus ambient.
    let light = linalg::mat_vec(&view.rotation, linalg::normalize_or([-0.35, -0.55, -0.75], [0.0, 0.0, -1.0]));
    let mut colour = vec![background; n];
    let mut kind = vec![None; n];
    for y in 0..h {
        for x in 0..w {
            let j = (y * w + x) as usize;
            let Some(item) = owner[j].and_then(|i| items.get(i)) else { continue };
            let d = view.ray(x, y);
            // The side of the surface that faces the viewer.
            let mut nrm = normal[j];
            if linalg::dot(nrm, d) > 0.0 {
                nrm = linalg::scale(nrm, -1.0);
            }
            let shade = 0.3 + 0.7 * linalg::dot(nrm, light).max(0.0);
            // Outline where the depth jumps by more than 3 % to a neighbour (or to nothing).
            let z = depth[j];
            let jump = |k: usize| depth.get(k).is_none_or(|&o| (o - z).abs() > 0.03 * z);
            let edge = (x + 1 < w && jump(j + 1)) || (y + 1 < h && jump(j + w as usize));
            let s = if edge { shade * 0.45 } else { shade };
            colour[j] = item.colour.map(|c| (c as f32 * s).min(255.0) as u8);
            kind[j] = Some(item.kind);
        }
    }
    Image { width: w, height: h, colour, depth, kind }
}

/// Where to look from when not from the mapped camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Viewpoint {
    /// Around the map's objects, `azimuth` radians about the up axis from the camera's side, at the camera's
    /// elevation.
    Orbit {
        /// Radians, counter-clockwise seen from above.
        azimuth: f32,
    },
    /// Straight down the up axis, the camera at the bottom of the image.
    Top,
}

/// What the other viewpoints are built around: the point to look at, how far the map reaches from it, and
/// which way is up (metres, map frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Framing {
    /// Look-at point: the coordinate-wise median of the superquadrics' centres (of the Gaussians' when there are
    /// no superquadrics, of everything when there are neither), metres.
    pub target: Vec3,
    /// How far those primitives reach from the target (centre distance plus bounding radius), at least 0.2 m.
    pub radius: f32,
    /// Up: the normal of the plane with the most cells that is within 45° of the camera's up (−y), else −y.
    pub up: Vec3,
}

impl Framing {
    /// The framing of a list of primitives.
    pub fn of(items: &[Drawable]) -> Framing {
        let spheres = |kind: Option<Kind>| -> Vec<(Vec3, f32)> {
            items.iter().filter(|i| kind.is_none_or(|k| i.kind == k)).map(|i| i.shape.bounding_sphere()).collect()
        };
        let mut focus = spheres(Some(Kind::Sq));
        if focus.is_empty() {
            focus = spheres(Some(Kind::Gmm));
        }
        if focus.is_empty() {
            focus = spheres(None);
        }
        let median = |k: usize| {
            let mut v: Vec<f32> = focus.iter().map(|(c, _)| c[k]).collect();
            v.sort_by(f32::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(if k == 2 { 1.0 } else { 0.0 })
        };
        let target = [median(0), median(1), median(2)];
        let radius = focus.iter().map(|(c, r)| linalg::norm(linalg::sub(*c, target)) + r).fold(0.2f32, f32::max);
        Framing { target, radius, up: up_of(items) }
    }

    /// A framing that holds every primitive: the centre of their bounding spheres' box as the target, and
    /// the radius that reaches all of them (a world map, seen whole).
    pub fn whole(items: &[Drawable]) -> Framing {
        let spheres: Vec<(Vec3, f32)> = items.iter().map(|i| i.shape.bounding_sphere()).collect();
        let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
        for (c, r) in &spheres {
            for k in 0..3 {
                lo[k] = lo[k].min(c[k] - r);
                hi[k] = hi[k].max(c[k] + r);
            }
        }
        let target = if spheres.is_empty() { [0.0, 0.0, 1.0] } else { linalg::scale(linalg::add(lo, hi), 0.5) };
        let radius = spheres.iter().map(|(c, r)| linalg::norm(linalg::sub(*c, target)) + r).fold(0.2f32, f32::max);
        Framing { target, radius, up: up_of(items) }
    }

    /// The view from `viewpoint`, with the optics of `camera` (the mapped frame's view), at the distance that
    /// fits the framing's radius in the narrower field of view.
    pub fn view(&self, viewpoint: Viewpoint, camera: &View) -> View {
        let fit = self.radius / camera.half_fov().tan() * 1.15;
        let back = linalg::sub(camera.origin, self.target);
        let distance = fit;
        let up = self.up;
        match viewpoint {
            Viewpoint::Orbit { azimuth } => {
                let dir = rotate_about(linalg::normalize_or(back, linalg::scale(up, 1.0)), up, azimuth);
                View::look_at(linalg::add(self.target, linalg::scale(dir, distance)), self.target, up, camera)
            }
            Viewpoint::Top => {
                // Image up points away from the camera: the camera's forward, flattened onto the ground.
                let forward = linalg::scale(back, -1.0);
                let flat = linalg::sub(forward, linalg::scale(up, linalg::dot(forward, up)));
                let away = linalg::normalize_or(flat, linalg::column(&camera.rotation, 2));
                let eye = linalg::add(self.target, linalg::scale(up, distance));
                View::look_at(eye, self.target, away, camera)
            }
        }
    }
}

/// Up: the normal of the plane with the most cells that is within 45° of the camera's up (−y), else −y.
fn up_of(items: &[Drawable]) -> Vec3 {
    let camera_up = [0.0, -1.0, 0.0];
    let mut best: Option<(usize, Vec3)> = None;
    for item in items {
        if let Shape::Cells { rotation, bits, .. } = &item.shape {
            let n = linalg::column(rotation, 2);
            let n = if linalg::dot(n, camera_up) < 0.0 { linalg::scale(n, -1.0) } else { n };
            let cells = bits.iter().map(|b| b.count_ones() as usize).sum::<usize>();
            if linalg::dot(n, camera_up) > std::f32::consts::FRAC_1_SQRT_2 && best.is_none_or(|(c, _)| cells > c) {
                best = Some((cells, n));
            }
        }
    }
    best.map_or(camera_up, |(_, n)| n)
}

/// `v` rotated by `angle` radians about the unit `axis` (Rodrigues).
fn rotate_about(v: Vec3, axis: Vec3, angle: f32) -> Vec3 {
    let (s, c) = angle.sin_cos();
    let k = linalg::normalize_or(axis, [0.0, -1.0, 0.0]);
    let kv = linalg::cross(k, v);
    let along = linalg::scale(k, linalg::dot(k, v) * (1.0 - c));
    linalg::add(linalg::add(linalg::scale(v, c), linalg::scale(kv, s)), along)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> View {
        View {
            origin: [0.0; 3],
            rotation: linalg::IDENTITY,
            fx: 500.0,
            fy: 500.0,
            cx: 320.0,
            cy: 240.0,
            width: 640,
            height: 480,
        }
    }

    #[test]
    fn a_sphere_superquadric_is_hit_on_its_surface_with_the_outward_normal() {
        let s = Superquadric { scales: [0.1; 3], eps: [1.0, 1.0], centre: [0.0, 0.0, 1.0], rotation: linalg::IDENTITY };
        let (t, n) = Shape::Sq(s).hit([0.0; 3], [0.0, 0.0, 1.0], NEAR).unwrap();
        assert!((t - 0.9).abs() < 1e-3, "t = {t}");
        assert!(linalg::dot(n, [0.0, 0.0, -1.0]) > 0.999, "normal {n:?}");
        // Along (0.05, 0, 1): (0.05t)² + (t − 1)² = 0.1², the smaller root.
        let (t, _) = Shape::Sq(s).hit([0.0; 3], [0.05, 0.0, 1.0], NEAR).unwrap();
        let (a, b, c) = (1.0025f32, -2.0f32, 0.99f32);
        let expect = (-b - (b * b - 4.0 * a * c).sqrt()) / (2.0 * a);
        assert!((t - expect).abs() < 1e-3, "t = {t}, expected {expect}");
        assert!(Shape::Sq(s).hit([0.0; 3], [0.2, 0.0, 1.0], NEAR).is_none());
        // A box (ε → 0.1): the front face is flat.
        let b = Superquadric { eps: [0.1, 0.1], ..s };
        for dx in [0.0, 0.05, 0.08] {
            let (t, n) = Shape::Sq(b).hit([0.0; 3], [dx, 0.05, 1.0], NEAR).unwrap();
            assert!((t - 0.9).abs() < 5e-3 && n[2] < -0.99, "box face at t = {t}, normal {n:?}");
        }
    }

    #[test]
    fn an_ellipsoid_and_plane_cells_are_hit_where_they_are() {
        let e = Shape::Ellipsoid { centre: [0.0, 0.0, 2.0], rotation: linalg::IDENTITY, radii: [0.2, 0.1, 0.05] };
        let (t, n) = e.hit([0.0; 3], [0.0, 0.0, 1.0], NEAR).unwrap();
        assert!((t - 1.95).abs() < 1e-4 && n[2] < -0.999);
        assert!(e.hit([0.0; 3], [0.11, 0.0, 1.0], NEAR).is_none(), "0.22 m off at 2 m misses a 0.2 m half-axis");
        // A floor 1 m below the camera (y down), normal up, cells 0.1 m: 4 × 2 cells from (−2, 10), only (1, 0) unset.
        let rotation = linalg::from_columns([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]);
        let mut bits = vec![0xFFu8];
        bits[0] &= !(1 << 1);
        let floor =
            Shape::Cells { centroid: [0.0, 1.0, 0.0], rotation, g_p: 0.1, origin: (-2, 10), size: (4, 2), bits };
        // Cell (0, 0) spans x ∈ [−0.2, −0.1], z ∈ [1.0, 1.1]: the ray to (−0.15, 1, 1.05) hits it at depth 1.05.
        let (t, n) = floor.hit([0.0; 3], [-0.15 / 1.05, 1.0 / 1.05, 1.0], NEAR).unwrap();
        assert!((t - 1.05).abs() < 1e-4 && n[1] < -0.999);
        assert!(floor.hit([0.0; 3], [-0.05 / 1.05, 1.0 / 1.05, 1.0], NEAR).is_none(), "cell (1, 0) is empty");
        assert!(floor.hit([0.0; 3], [0.25 / 1.05, 1.0 / 1.05, 1.0], NEAR).is_none(), "beyond the grid");
    }

    #[test]
    fn a_plane_seen_from_behind_does_not_hide_what_stands_in_front_of_it() {
        // A wall 2 m ahead (cells 0.1 m, 40 × 40 around the centre), a ball 0.5 m in front of it.
        let rotation = linalg::from_columns([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]);
        let wall = Shape::Cells {
            centroid: [0.0, 0.0, 2.0],
            rotation,
            g_p: 0.1,
            origin: (-20, -20),
            size: (40, 40),
            bits: vec![0xFF; 200],
        };
        let ball =
            Superquadric { scales: [0.2; 3], eps: [1.0, 1.0], centre: [0.0, 0.0, 1.5], rotation: linalg::IDENTITY };
        let items = [
            Drawable { shape: wall, kind: Kind::Plane, colour: [0, 0, 200] },
            Drawable { shape: Shape::Sq(ball), kind: Kind::Sq, colour: [0, 200, 0] },
        ];
        let centre = |img: &Image| img.colour[(240 * img.width + 320) as usize];
        // From the camera that mapped them, the ball stands before the wall.
        let front = render(&items, &camera(), [0.0; 3], [0, 0, 0]);
        assert!(centre(&front)[1] > 0 && centre(&front)[2] == 0);
        // From behind (5 m ahead, looking back), the wall's unseen side is left out: the ball still shows.
        let back = View::look_at([0.0, 0.0, 5.0], [0.0, 0.0, 1.5], [0.0, -1.0, 0.0], &camera());
        let img = render(&items, &back, [0.0; 3], [0, 0, 0]);
        assert!(centre(&img)[1] > 0 && centre(&img)[2] == 0, "{:?}", centre(&img));
        // Without that rule (seen from the back as well) the wall would hide it.
        let img = render(&items, &back, [0.0, 0.0, 5.0], [0, 0, 0]);
        assert!(centre(&img)[2] > 0);
    }

    #[test]
    fn the_image_shows_the_nearer_shape_shaded_and_other_views_see_the_far_side() {
        let near =
            Superquadric { scales: [0.1; 3], eps: [1.0, 1.0], centre: [0.0, 0.0, 1.0], rotation: linalg::IDENTITY };
        let far = Superquadric { centre: [0.0, 0.0, 1.5], scales: [0.3; 3], ..near };
        let items = [
            Drawable { shape: Shape::Sq(near), kind: Kind::Sq, colour: [200, 0, 0] },
            Drawable { shape: Shape::Sq(far), kind: Kind::Sq, colour: [0, 200, 0] },
        ];
        let view = camera();
        let img = render(&items, &view, [0.0; 3], [0, 0, 0]);
        let at = |img: &Image, x: u32, y: u32| img.colour[(y * img.width + x) as usize];
        assert!(at(&img, 320, 240)[0] > 100 && at(&img, 320, 240)[1] == 0, "the near sphere in front");
        assert!(at(&img, 320 + 80, 240)[1] > 50, "the far one around it");
        assert_eq!(at(&img, 5, 5), [0, 0, 0]);
        // The near sphere's disc covers π(500·0.1/0.99…)² pixels: about 8 000.
        let red = img.colour.iter().filter(|c| c[0] > 0).count() as f32;
        let expect = std::f32::consts::PI * (500.0f32 * 0.1 / (1.0f32 - 0.01).sqrt()).powi(2);
        assert!((red - expect).abs() < 0.05 * expect, "{red} red pixels, expected {expect}");
        // From the far side (orbit by 180°) the big sphere hides the small one.
        let framing = Framing::of(&items);
        assert_eq!(framing.target, [0.0, 0.0, 1.5], "the median of two centres is the upper one");
        let reach = 0.5 + 0.1 * 3f32.sqrt(); // the near sphere's centre distance plus its box's half-diagonal
        assert!((framing.radius - reach).abs() < 1e-4 && framing.up == [0.0, -1.0, 0.0], "{framing:?}");
        let behind = framing.view(Viewpoint::Orbit { azimuth: std::f32::consts::PI }, &view);
        let fit = reach / view.half_fov().tan() * 1.15;
        assert!((behind.origin[2] - (1.5 + fit)).abs() < 1e-3, "eye at {:?}", behind.origin);
        let img = render(&items, &behind, [0.0; 3], [0, 0, 0]);
        assert!(img.colour.iter().all(|c| c[0] == 0), "the near sphere is hidden from behind");
        // From above, both are seen.
        let top = framing.view(Viewpoint::Top, &view);
        assert!(top.origin[1] < -1.0, "above: {:?}", top.origin);
        let img = render(&items, &top, [0.0; 3], [0, 0, 0]);
        assert!(img.colour.iter().any(|c| c[1] > 0));
    }
}
