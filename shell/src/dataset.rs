//! Dataset readers: TUM RGB-D folders (with rgb/depth association and ground-truth poses) and 7-Scenes folders,
//! camera presets, and image decoding. Every error names the file it comes from.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use glam::{DMat3, DQuat, DVec3};
use m2smap_core::{Frame, Intrinsics};
use serde::{Deserialize, Serialize};

/// Largest rgb/depth timestamp difference of an association, seconds (TUM's `associate.py` default).
pub const MAX_ASSOCIATION_DT: f64 = 0.02;

/// Camera model of a dataset: intrinsics, image size and raw depth units per metre.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Focal length x, pixels.
    pub fx: f32,
    /// Focal length y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Image width, pixels.
    pub width: u16,
    /// Image height, pixels.
    pub height: u16,
    /// Raw depth units per metre.
    pub depth_scale: f32,
}

impl Camera {
    /// The core's intrinsics.
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics { fx: self.fx, fy: self.fy, cx: self.cx, cy: self.cy }
    }

    /// A TUM preset by name: `fr1`, `fr2`, `fr3` (or `freiburg1..3`).
    pub fn preset(name: &str) -> Option<Camera> {
        let tum = |fx, fy, cx, cy| Camera { fx, fy, cx, cy, width: 640, height: 480, depth_scale: 5000.0 };
        match preset_key(name).unwrap_or(name) {
            "fr1" => Some(tum(517.3, 516.5, 318.6, 255.3)),
            "fr2" => Some(tum(520.9, 521.0, 325.1, 249.7)),
            "fr3" => Some(tum(535.4, 539.2, 320.1, 247.6)),
            "7scenes" => Some(Camera {
                fx: 585.0,
                fy: 585.0,
                cx: 320.0,
                cy: 240.0,
                width: 640,
                height: 480,
                depth_scale: 1000.0,
            }),
            _ => None,
        }
    }

    /// Reads a `camera.json`.
    pub fn from_json(path: &Path) -> Result<Camera> {
        let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
        serde_json::from_str(&text).map_err(|e| anyhow!("{}: malformed camera file: {e}", path.display()))
    }
}

/// A rigid camera-to-world pose: translation (metres) and unit quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Translation, metres.
    pub t: [f64; 3],
    /// Rotation quaternion `[x, y, z, w]`.
    pub q: [f64; 4],
}

impl Pose {
    /// The rotation as a glam quaternion (normalised; identity when zero or not finite).
    fn quat(&self) -> DQuat {
        let q = DQuat::from_array(self.q);
        let n = q.length();
        if n > 0.0 && n.is_finite() {
            q / n
        } else {
            DQuat::IDENTITY
        }
    }

    /// Rotation matrix (row-major).
    pub fn rotation(&self) -> [[f64; 3]; 3] {
        let m = DMat3::from_quat(self.quat());
        [0, 1, 2].map(|i| m.row(i).to_array())
    }

    /// The core's single-precision pose.
    pub fn to_core(&self) -> m2smap_core::Pose {
        let r = self.rotation();
        m2smap_core::Pose { rotation: r.map(|row| row.map(|x| x as f32)), translation: self.t.map(|x| x as f32) }
    }

    /// Maps a camera-frame point to the world frame.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        (self.quat() * DVec3::from_array(p) + DVec3::from_array(self.t)).to_array()
    }

    /// From a row-major rotation matrix and translation.
    pub fn from_matrix(r: [[f64; 3]; 3], t: [f64; 3]) -> Pose {
        let m = DMat3::from_cols_array_2d(&r).transpose();
        Pose { t, q: DQuat::from_mat3(&m).normalize().to_array() }
    }

    /// Interpolates between `a` (at s = 0) and `b` (at s = 1): linear in translation, SLERP in rotation (the
    /// shortest way).
    pub fn interpolate(a: &Pose, b: &Pose, s: f64) -> Pose {
        let t = DVec3::from_array(a.t).lerp(DVec3::from_array(b.t), s).to_array();
        Pose { t, q: a.quat().slerp(b.quat(), s).normalize().to_array() }
    }
}

/// One entry of a TUM list file: a timestamp and the rest of the line's fields.
#[derive(Debug, Clone, PartialEq)]
pub struct ListEntry {
    /// Seconds.
    pub timestamp: f64,
    /// Whitespace-separated fields after the timestamp.
    pub fields: Vec<String>,
}

/// Reads a TUM list (`rgb.txt`, `depth.txt`, `groundtruth.txt`): `#` comments, blank lines and a leading
/// `timestamp …` column header are skipped; every other line needs a timestamp and at least `min_fields` further
/// fields.
pub fn read_list(path: &Path, min_fields: usize) -> Result<Vec<ListEntry>> {
    let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    parse_list(&text, min_fields).map_err(|e| anyhow!("{}:{e}", path.display()))
}

/// Parses the text of a TUM list; errors are `line: message`.
pub fn parse_list(text: &str, min_fields: usize) -> Result<Vec<ListEntry>> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut parts = line.split_whitespace();
        let ts = parts.next().unwrap_or("");
        if out.is_empty() && ts == "timestamp" {
            continue; // an uncommented column header, as some TUM lists have
        }
        let timestamp: f64 = match ts.parse() {
            Ok(t) if f64::is_finite(t) => t,
            _ => bail!("{}: malformed line (no timestamp): {line:?}", n + 1),
        };
        let fields: Vec<String> = parts.map(str::to_owned).collect();
        if fields.len() < min_fields {
            bail!("{}: malformed line (expected {min_fields} fields after the timestamp): {line:?}", n + 1);
        }
        out.push(ListEntry { timestamp, fields });
    }
    Ok(out)
}

/// Associates two timestamp lists as TUM's `associate.py`: every pair closer than `max_dt`, closest first, each
/// entry used at most once; the result is sorted by the first list's time. Returns index pairs.
pub fn associate(a: &[f64], b: &[f64], max_dt: f64) -> Vec<(usize, usize)> {
    let mut sorted_b: Vec<(f64, usize)> = b.iter().copied().zip(0..).collect();
    sorted_b.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut candidates = Vec::new();
    for (i, &ta) in a.iter().enumerate() {
        let start = sorted_b.partition_point(|&(tb, _)| tb < ta - max_dt);
        for &(tb, j) in sorted_b.get(start..).unwrap_or(&[]) {
            if tb > ta + max_dt {
                break;
            }
            let dt = (ta - tb).abs();
            if dt < max_dt {
                candidates.push((dt, i, j));
            }
        }
    }
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
    let mut pairs = Vec::new();
    for (_, i, j) in candidates {
        if !used_a[i] && !used_b[j] {
            used_a[i] = true;
            used_b[j] = true;
            pairs.push((i, j));
        }
    }
    pairs.sort_by(|x, y| a[x.0].total_cmp(&a[y.0]));
    pairs
}

/// Pose at `t` from a time-sorted trajectory: interpolated between the neighbours, or `None` when `t` lies
/// outside it by more than [`MAX_ASSOCIATION_DT`].
pub fn pose_at(trajectory: &[(f64, Pose)], t: f64) -> Option<Pose> {
    let k = trajectory.partition_point(|(ts, _)| *ts < t);
    if let Some((tb, pb)) = trajectory.get(k).filter(|(tb, _)| *tb == t) {
        let _ = tb;
        return Some(*pb); // an exact row: no interpolation rounding
    }
    match (k.checked_sub(1).and_then(|i| trajectory.get(i)), trajectory.get(k)) {
        (Some((ta, pa)), Some((tb, pb))) => {
            let s = if tb > ta { (t - ta) / (tb - ta) } else { 0.0 };
            Some(Pose::interpolate(pa, pb, s))
        }
        (Some((ta, pa)), None) if t - ta <= MAX_ASSOCIATION_DT => Some(*pa),
        (None, Some((tb, pb))) if tb - t <= MAX_ASSOCIATION_DT => Some(*pb),
        _ => None,
    }
}

/// Reads a TUM `groundtruth.txt` into a time-sorted trajectory.
pub fn read_trajectory(path: &Path) -> Result<Vec<(f64, Pose)>> {
    let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    parse_trajectory(&text).map_err(|e| anyhow!("{}:{e}", path.display()))
}

/// Parses the text of a TUM trajectory (`timestamp tx ty tz qx qy qz qw` lines); errors are `line: message`.
pub fn parse_trajectory(text: &str) -> Result<Vec<(f64, Pose)>> {
    let entries = parse_list(text, 7)?;
    let mut out = Vec::with_capacity(entries.len());
    for e in entries {
        let v: Vec<f64> = e
            .fields
            .iter()
            .take(7)
            .map(|s| s.parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| anyhow!(" malformed pose at timestamp {}", e.timestamp))?;
        if v.iter().any(|x| !x.is_finite()) {
            bail!(" non-finite pose at timestamp {}", e.timestamp);
        }
        let q = Pose { t: [0.0; 3], q: [v[3], v[4], v[5], v[6]] }.quat().to_array();
        out.push((e.timestamp, Pose { t: [v[0], v[1], v[2]], q }));
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(out)
}

/// One frame of a dataset, before loading.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRef {
    /// Stem naming the frame's files (colour file name without extension), used for masks and outputs.
    pub stem: String,
    /// Colour timestamp, seconds (frame number for 7-Scenes).
    pub timestamp: f64,
    /// Colour image.
    pub colour: PathBuf,
    /// Depth image.
    pub depth: PathBuf,
    /// Camera-to-world pose, when the dataset has one.
    pub pose: Option<Pose>,
}

/// Which layout a dataset folder has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// TUM RGB-D (`rgb.txt`, `depth.txt`).
    Tum,
    /// Microsoft 7-Scenes (`frame-NNNNNN.*`).
    SevenScenes,
}

/// The largest `--downscale` factor.
pub const MAX_DOWNSCALE: u16 = 8;

/// A dataset folder: its frames and camera.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// The folder.
    pub root: PathBuf,
    /// Its layout.
    pub layout: Layout,
    /// Camera model.
    pub camera: Camera,
    /// Where the camera model came from: `--camera <name or file>`, `camera.json`, `folder name (<preset>)` or
    /// `camera-intrinsics.txt` (7-Scenes).
    pub camera_source: String,
    /// Frames in time order.
    pub frames: Vec<FrameRef>,
    /// Every frame is subsampled by this factor on loading (`--downscale`; 1 = full size): `camera` is then the
    /// camera of the subsampled frames.
    pub downscale: u16,
    /// Width and height of the files, pixels (before `downscale`).
    pub source_size: (u16, u16),
}

/// The TUM sequence (`fr1`, `fr2`, `fr3`) that a folder's name names, if any (`freiburg1` reads as `fr1`).
pub fn preset_in_name(root: &Path) -> Option<&'static str> {
    let name = root.file_name()?.to_string_lossy().to_lowercase();
    ["freiburg1", "freiburg2", "freiburg3", "fr1", "fr2", "fr3"]
        .into_iter()
        .find(|k| name.contains(*k))
        .and_then(preset_key)
}

/// The TUM preset a camera name stands for (`fr1`…`fr3`, also spelled `freiburg1`…`freiburg3`).
pub fn preset_key(name: &str) -> Option<&'static str> {
    match name {
        "fr1" | "freiburg1" => Some("fr1"),
        "fr2" | "freiburg2" => Some("fr2"),
        "fr3" | "freiburg3" => Some("fr3"),
        _ => None,
    }
}

/// A decoded frame owned by the shell.
#[derive(Debug, Clone)]
pub struct LoadedFrame {
    /// Width, pixels.
    pub width: u16,
    /// Height, pixels.
    pub height: u16,
    /// Raw depth (0 = invalid).
    pub depth: Vec<u16>,
    /// Packed RGB.
    pub colour: Vec<u8>,
}

impl LoadedFrame {
    /// The core's borrowed view of this frame (no pose: superquadric tracks stay in the camera frame).
    pub fn view<'a>(&'a self, camera: &Camera) -> Frame<'a> {
        Frame {
            width: self.width,
            height: self.height,
            depth: &self.depth,
            depth_scale: camera.depth_scale,
            colour: &self.colour,
            intrinsics: camera.intrinsics(),
            pose: None,
        }
    }

    /// The core's view with a camera-to-world pose (tracks then live in the world frame).
    pub fn view_posed<'a>(&'a self, camera: &Camera, pose: Option<&Pose>) -> Frame<'a> {
        Frame { pose: pose.map(Pose::to_core), ..self.view(camera) }
    }
}

impl Dataset {
    /// Opens a dataset folder; `camera_override` is a preset name or a `camera.json` path (`--camera`).
    pub fn open(root: &Path, camera_override: Option<&str>) -> Result<Dataset> {
        if !root.is_dir() {
            bail!("{}: not a dataset folder (does not exist or is not a directory)", root.display());
        }
        let (layout, mut camera, frames) = if root.join("rgb.txt").is_file() {
            let (camera, frames) = open_tum(root)?;
            (Layout::Tum, camera, frames)
        } else if root.join("camera-intrinsics.txt").is_file() {
            let (camera, frames) = open_seven_scenes(root)?;
            (Layout::SevenScenes, camera, frames)
        } else {
            bail!("{}: neither a TUM folder (rgb.txt) nor a 7-Scenes folder (camera-intrinsics.txt)", root.display());
        };
        if let Some(c) = camera_override {
            let given = match Camera::preset(c) {
                Some(p) => p,
                None if !Path::new(c).is_file() => bail!(
                    "--camera {c:?}: neither a preset (fr1, fr2, fr3, freiburg1, freiburg2, freiburg3, 7scenes) nor a camera.json file"
                ),
                None => Camera::from_json(Path::new(c))?,
            };
            camera = Some((given, format!("--camera {c}")));
        }
        let (camera, camera_source) = camera.ok_or_else(|| {
            anyhow!(
                "{}: unknown camera: name the folder fr1/fr2/fr3, add camera.json, or pass --camera",
                root.display()
            )
        })?;
        let source_size = (camera.width, camera.height);
        Ok(Dataset { root: root.to_owned(), layout, camera, camera_source, frames, downscale: 1, source_size })
    }

    /// This dataset with every frame subsampled by `n` (1–[`MAX_DOWNSCALE`]): output pixel (x, y) is input pixel
    /// (n·x, n·y) of depth, colour, masks and ground truth alike (no averaging, so no depth is mixed across an
    /// edge), and the camera becomes fx/n, fy/n, cx/n, cy/n at ⌊width/n⌋ × ⌊height/n⌋, which is exact for that
    /// sampling. For sensors whose frames exceed the capacity profile (e.g. 1920 × 1080 with `--downscale 2`).
    pub fn downscaled(mut self, n: u16) -> Result<Dataset> {
        if !(1..=MAX_DOWNSCALE).contains(&n) {
            bail!("--downscale {n}: must be 1 to {MAX_DOWNSCALE}");
        }
        let n32 = n as f32;
        let c = self.camera;
        let (width, height) = (self.source_size.0 / n, self.source_size.1 / n);
        if width == 0 || height == 0 {
            bail!("--downscale {n}: a {}x{} frame would have no pixels left", self.source_size.0, self.source_size.1);
        }
        self.camera = Camera { fx: c.fx / n32, fy: c.fy / n32, cx: c.cx / n32, cy: c.cy / n32, width, height, ..c };
        self.downscale = n;
        Ok(self)
    }

    /// Subsamples a full-size image with `channels` values per pixel to the dataset's frame size (a copy when
    /// `downscale` is 1); `None` when `data` is not a full-size image.
    pub fn subsample<T: Copy>(&self, data: &[T], channels: usize) -> Option<Vec<T>> {
        let (sw, sh) = (self.source_size.0 as usize, self.source_size.1 as usize);
        if data.len() != sw * sh * channels {
            return None;
        }
        let n = self.downscale as usize;
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let mut out = Vec::with_capacity(w * h * channels);
        for y in 0..h {
            for x in 0..w {
                let i = (n * y * sw + n * x) * channels;
                out.extend_from_slice(data.get(i..i + channels)?);
            }
        }
        Some(out)
    }

    /// Decodes frame `i`, checking its size against the camera.
    pub fn load(&self, i: usize) -> Result<LoadedFrame> {
        let f = self.frames.get(i).ok_or_else(|| anyhow!("{}: no frame {i}", self.root.display()))?;
        let (dw, dh, mut depth) = read_depth(&f.depth)?;
        if self.layout == Layout::SevenScenes {
            for d in depth.iter_mut() {
                if *d == u16::MAX {
                    *d = 0;
                }
            }
        }
        let (cw, ch, colour) = read_colour(&f.colour)?;
        if (cw, ch) != (dw, dh) {
            bail!("{}: colour image is {cw}x{ch} but the depth image is {dw}x{dh}", f.colour.display());
        }
        if (dw, dh) != (self.source_size.0 as u32, self.source_size.1 as u32) {
            bail!(
                "{}: depth image is {dw}x{dh} but the camera is {}x{}",
                f.depth.display(),
                self.source_size.0,
                self.source_size.1
            );
        }
        if self.downscale == 1 {
            return Ok(LoadedFrame { width: dw as u16, height: dh as u16, depth, colour });
        }
        let depth = self.subsample(&depth, 1).ok_or_else(|| anyhow!("{}: cannot subsample", f.depth.display()))?;
        let colour = self.subsample(&colour, 3).ok_or_else(|| anyhow!("{}: cannot subsample", f.colour.display()))?;
        Ok(LoadedFrame { width: self.camera.width, height: self.camera.height, depth, colour })
    }
}

/// A folder's camera with where it came from (`None` when the folder does not say), and its frames.
type Opened = (Option<(Camera, String)>, Vec<FrameRef>);

/// A TUM folder's frames and camera with where the camera came from (`camera.json`, else the preset its name
/// names; `None` when neither).
fn open_tum(root: &Path) -> Result<Opened> {
    let rgb = read_list(&root.join("rgb.txt"), 1)?;
    let depth = read_list(&root.join("depth.txt"), 1)?;
    let pairs = associate(
        &rgb.iter().map(|e| e.timestamp).collect::<Vec<_>>(),
        &depth.iter().map(|e| e.timestamp).collect::<Vec<_>>(),
        MAX_ASSOCIATION_DT,
    );
    let gt_path = root.join("groundtruth.txt");
    let trajectory = if gt_path.is_file() { read_trajectory(&gt_path)? } else { Vec::new() };
    let frames = pairs
        .into_iter()
        .map(|(i, j)| {
            let (c, d) = (&rgb[i], &depth[j]);
            let colour = root.join(&c.fields[0]);
            let stem = colour.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            FrameRef {
                stem,
                timestamp: c.timestamp,
                colour,
                depth: root.join(&d.fields[0]),
                pose: pose_at(&trajectory, c.timestamp),
            }
        })
        .collect();
    let json = root.join("camera.json");
    let camera = if json.is_file() {
        Some((Camera::from_json(&json)?, "camera.json".to_owned()))
    } else {
        preset_in_name(root).and_then(|k| Some((Camera::preset(k)?, format!("folder name ({k})"))))
    };
    Ok((camera, frames))
}

/// A 7-Scenes folder's frames and camera (from `camera-intrinsics.txt`).
fn open_seven_scenes(root: &Path) -> Result<Opened> {
    let k_path = root.join("camera-intrinsics.txt");
    let text = fs::read_to_string(&k_path).with_context(|| format!("{}: cannot read", k_path.display()))?;
    let camera = parse_intrinsics(&text).map_err(|e| anyhow!("{}: {e}", k_path.display()))?;
    let mut frames = Vec::new();
    let entries = fs::read_dir(root).with_context(|| format!("{}: cannot list", root.display()))?;
    for entry in entries {
        let name = entry?.file_name().to_string_lossy().into_owned();
        let Some(stem) = name.strip_suffix(".color.jpg").or_else(|| name.strip_suffix(".color.png")) else {
            continue;
        };
        let Some(number) = stem.strip_prefix("frame-").and_then(|n| n.parse::<u32>().ok()) else { continue };
        let pose_path = root.join(format!("{stem}.pose.txt"));
        let pose = if pose_path.is_file() { Some(read_pose_matrix(&pose_path)?) } else { None };
        frames.push(FrameRef {
            stem: stem.to_owned(),
            timestamp: number as f64,
            colour: root.join(&name),
            depth: root.join(format!("{stem}.depth.png")),
            pose,
        });
    }
    frames.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    Ok((Some((camera, "camera-intrinsics.txt".to_owned())), frames))
}

fn read_pose_matrix(path: &Path) -> Result<Pose> {
    let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    parse_pose_matrix(&text).map_err(|e| anyhow!("{}: {e}", path.display()))
}

/// Parses a 7-Scenes `camera-intrinsics.txt` (a 3×3 K) into a 640×480, millimetre-depth camera.
pub fn parse_intrinsics(text: &str) -> Result<Camera> {
    let k: Vec<f32> = text
        .split_whitespace()
        .map(|s| s.parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow!("malformed intrinsics (expected 9 numbers)"))?;
    if k.len() != 9 || k.iter().any(|x| !x.is_finite()) {
        bail!("malformed intrinsics (expected 9 finite numbers, found {})", k.len());
    }
    Ok(Camera { fx: k[0], fy: k[4], cx: k[2], cy: k[5], width: 640, height: 480, depth_scale: 1000.0 })
}

/// Parses a 7-Scenes `frame-*.pose.txt` (a 4×4 camera-to-world matrix).
pub fn parse_pose_matrix(text: &str) -> Result<Pose> {
    let m: Vec<f64> = text
        .split_whitespace()
        .map(|s| s.parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow!("malformed pose (expected a 4x4 matrix)"))?;
    if m.len() != 16 || m.iter().any(|x| !x.is_finite()) {
        bail!("malformed pose (expected 16 finite numbers, found {})", m.len());
    }
    let r = [[m[0], m[1], m[2]], [m[4], m[5], m[6]], [m[8], m[9], m[10]]];
    Ok(Pose::from_matrix(r, [m[3], m[7], m[11]]))
}

fn open_image(path: &Path) -> Result<image::DynamicImage> {
    let reader = image::ImageReader::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let reader = reader.with_guessed_format().with_context(|| format!("{}: cannot read", path.display()))?;
    reader.decode().map_err(|e| anyhow!("{}: cannot decode image: {e}", path.display()))
}

/// Reads a 16-bit single-channel depth PNG.
pub fn read_depth(path: &Path) -> Result<(u32, u32, Vec<u16>)> {
    match open_image(path)? {
        image::DynamicImage::ImageLuma16(img) => Ok((img.width(), img.height(), img.into_raw())),
        other => bail!("{}: depth must be a 16-bit single-channel PNG, found {:?}", path.display(), other.color()),
    }
}

/// Reads a colour image (PNG or JPEG) as packed RGB.
pub fn read_colour(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let img = open_image(path)?.to_rgb8();
    Ok((img.width(), img.height(), img.into_raw()))
}
