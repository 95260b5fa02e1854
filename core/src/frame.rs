//! The camera model and the borrowed RGB-D frame view.

use crate::error::FrameError;
use crate::linalg::{self, Mat3, Vec3};
use crate::params::Params;

/// A rigid camera-to-world transform: p_world = R · p_camera + t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation R (row-major), orthonormal with determinant +1.
    pub rotation: Mat3,
    /// Translation t, metres.
    pub translation: Vec3,
}

impl Pose {
    /// A camera-frame point in the world frame.
    pub fn to_world(&self, p: Vec3) -> Vec3 {
        linalg::add(linalg::mat_vec(&self.rotation, p), self.translation)
    }

    /// A world-frame point in the camera frame.
    pub fn to_camera(&self, p: Vec3) -> Vec3 {
        linalg::mat_t_vec(&self.rotation, linalg::sub(p, self.translation))
    }

    /// Whether every value is finite and the rotation is orthonormal with determinant +1 (to 10⁻³).
    pub fn is_valid(&self) -> bool {
        let r = &self.rotation;
        if !(r.iter().flatten().chain(&self.translation).all(|x| x.is_finite())) {
            return false;
        }
        let rtr = linalg::mat_mul(&linalg::transpose(r), r);
        let identity = (0..3).all(|i| {
            (0..3).all(|j| {
                let e = rtr.get(i).and_then(|row| row.get(j)).copied().unwrap_or(f32::NAN);
                libm::fabsf(e - if i == j { 1.0 } else { 0.0 }) < 1e-3
            })
        });
        let det = linalg::dot(linalg::cross(r[0], r[1]), r[2]);
        identity && libm::fabsf(det - 1.0) < 1e-3
    }
}

/// Pinhole intrinsics K, pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
}

impl Intrinsics {
    /// Whether the focal lengths are positive and every value is finite.
    pub fn is_valid(&self) -> bool {
        self.fx.is_finite()
            && self.fy.is_finite()
            && self.fx > 0.0
            && self.fy > 0.0
            && self.cx.is_finite()
            && self.cy.is_finite()
    }

    /// Back-projects pixel (u, v) at depth z (metres) into the camera frame, metres.
    #[inline]
    pub fn unproject(&self, u: f32, v: f32, z: f32) -> [f32; 3] {
        [(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z]
    }

    /// Projects a camera-frame point (metres) to continuous pixel coordinates; `None` behind the camera.
    #[inline]
    pub fn project(&self, p: [f32; 3]) -> Option<[f32; 2]> {
        if p[2] > 0.0 {
            Some([self.fx * p[0] / p[2] + self.cx, self.fy * p[1] / p[2] + self.cy])
        } else {
            None
        }
    }
}

/// One registered RGB-D frame, borrowed from the caller (row-major, top row first).
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    /// Image width, pixels.
    pub width: u16,
    /// Image height, pixels.
    pub height: u16,
    /// Raw depth, `width × height` samples; 0 means no measurement.
    pub depth: &'a [u16],
    /// Raw depth units per metre (TUM: 5000, 7-Scenes: 1000).
    pub depth_scale: f32,
    /// Packed RGB, `width × height × 3` bytes, registered to the depth image.
    pub colour: &'a [u8],
    /// Camera intrinsics of the depth image.
    pub intrinsics: Intrinsics,
    /// Camera-to-world pose, when known: superquadric tracks then live in the world frame.
    pub pose: Option<Pose>,
}

impl<'a> Frame<'a> {
    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Checks sizes, intrinsics and depth content. Reads the whole depth buffer once.
    pub fn validate(&self, params: &Params, max_pixels: usize) -> Result<(), FrameError> {
        let pixels = self.pixels();
        if pixels == 0 {
            return Err(FrameError::EmptyFrame);
        }
        if pixels > max_pixels {
            return Err(FrameError::TooLarge { pixels, max_pixels });
        }
        if self.depth.len() != pixels {
            return Err(FrameError::DepthLength { expected: pixels, found: self.depth.len() });
        }
        if self.colour.len() != pixels * 3 {
            return Err(FrameError::ColourLength { expected: pixels * 3, found: self.colour.len() });
        }
        if !self.intrinsics.is_valid() {
            return Err(FrameError::BadIntrinsics);
        }
        if !(self.depth_scale.is_finite() && self.depth_scale > 0.0) {
            return Err(FrameError::BadDepthScale);
        }
        if self.pose.is_some_and(|p| !p.is_valid()) {
            return Err(FrameError::BadPose);
        }
        let (lo, hi) = self.raw_range(params);
        let mut first: Option<u16> = None;
        let mut varied = false;
        for &raw in self.depth {
            if (lo..=hi).contains(&raw) {
                match first {
                    None => first = Some(raw),
                    Some(f) if f != raw => {
                        varied = true;
                        break;
                    }
                    Some(_) => {}
                }
            }
        }
        match first {
            None => Err(FrameError::NoValidDepth),
            Some(raw) if !varied => Err(FrameError::ConstantDepth { raw }),
            Some(_) => Ok(()),
        }
    }

    /// The raw depth of pixel (u, v) (column, row); 0 (no measurement) outside the image.
    #[inline]
    pub fn raw_at(&self, u: i32, v: i32) -> u16 {
        let inside = u >= 0 && v >= 0 && u < i32::from(self.width) && v < i32::from(self.height);
        let i = v as usize * usize::from(self.width) + u as usize;
        if inside {
            self.depth.get(i).copied().unwrap_or(0)
        } else {
            0
        }
    }

    /// The nearest and the farthest raw depth within `range` (inclusive) in the square window of ±`radius`
    /// pixels around pixel (u, v), clipped to the image; `None` when no pixel of the window has such a depth.
    pub fn depth_window(&self, u: i32, v: i32, radius: i32, range: (u16, u16)) -> Option<(u16, u16)> {
        let (w, h) = (self.width as i32, self.height as i32);
        let (mut nearest, mut farthest) = (u16::MAX, 0u16);
        let mut any = false;
        for y in (v - radius).max(0)..=(v + radius).min(h - 1) {
            let row = y as usize * w as usize;
            for x in (u - radius).max(0)..=(u + radius).min(w - 1) {
                let raw = self.depth.get(row + x as usize).copied().unwrap_or(0);
                if (range.0..=range.1).contains(&raw) {
                    nearest = nearest.min(raw);
                    farthest = farthest.max(raw);
                    any = true;
                }
            }
        }
        any.then_some((nearest, farthest))
    }

    /// Depth in metres of a raw sample.
    #[inline]
    pub fn metres(&self, raw: u16) -> f32 {
        raw as f32 / self.depth_scale
    }

    /// The raw values `[lo, hi]` that lie inside `[depth_min, depth_max]` metres (lo ≥ 1: 0 is no measurement).
    /// The range test on every pixel is then two integer comparisons.
    pub fn raw_range(&self, params: &Params) -> (u16, u16) {
        let to_raw = |m: f32| (m * self.depth_scale).clamp(0.0, 65535.0);
        let lo = libm::ceilf(to_raw(params.depth_min)) as u16;
        let hi = libm::floorf(to_raw(params.depth_max)) as u16;
        (lo.max(1), hi)
    }
}
