//! Instance-mask readers (docs/formats.md): an id image `masks/<stem>.png` (8- or 16-bit, 0 = none) with
//! `masks/<stem>.json` = `{"instances": [{"id", "label", "score", "bbox": [x0, y0, x1, y1]}]}`, or YOLO
//! segmentation text `masks/<stem>.txt` (`class x1 y1 x2 y2 … [conf]`, normalised polygon per line) with a
//! names file (`masks/names.txt`, one class name per line). A frame without a mask file has no instances.

use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use m2smap_core::{Instance, MaskPixels, MaskSet};
use serde::Deserialize;

/// Category names ↔ the core's class indices, stable over a run.
#[derive(Debug, Clone, Default)]
pub struct LabelTable {
    names: Vec<String>,
    index: HashMap<String, u16>,
}

impl LabelTable {
    /// The class index of `name`, adding it when new.
    pub fn class_of(&mut self, name: &str) -> u16 {
        if let Some(&k) = self.index.get(name) {
            return k;
        }
        let k = self.names.len() as u16;
        self.names.push(name.to_owned());
        self.index.insert(name.to_owned(), k);
        k
    }

    /// The name of class `k`.
    pub fn name(&self, k: u16) -> &str {
        self.names.get(k as usize).map_or("?", String::as_str)
    }
}

/// The pixels of a frame's masks, owned.
#[derive(Debug, Clone, PartialEq)]
pub enum Pixels {
    /// One id per pixel.
    Ids(Vec<u16>),
    /// One bit plane per instance (overlaps allowed).
    Bits(Vec<u8>),
}

/// The instance masks of one frame, owned by the shell.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameMasks {
    /// Width, pixels.
    pub width: u16,
    /// Height, pixels.
    pub height: u16,
    /// Instances.
    pub instances: Vec<Instance>,
    /// Pixels.
    pub pixels: Pixels,
}

impl FrameMasks {
    /// The core's borrowed view.
    pub fn view(&self) -> MaskSet<'_> {
        MaskSet {
            width: self.width,
            height: self.height,
            instances: &self.instances,
            pixels: match &self.pixels {
                Pixels::Ids(ids) => MaskPixels::IdImage(ids),
                Pixels::Bits(bits) => MaskPixels::BitPlanes(bits),
            },
        }
    }

    /// These masks subsampled by `n` to `width × height` (pixel (x, y) is pixel (n·x, n·y)), boxes scaled to
    /// match; see [`crate::dataset::Dataset::downscaled`].
    pub fn subsampled(&self, n: u16, width: u16, height: u16) -> FrameMasks {
        let view = self.view();
        let n = n.max(1);
        let at = |x: u16, y: u16| (x.saturating_mul(n), y.saturating_mul(n));
        let pixels = match &self.pixels {
            Pixels::Ids(ids) => Pixels::Ids(
                (0..height)
                    .flat_map(|y| (0..width).map(move |x| (x, y)))
                    .map(|(x, y)| {
                        let (u, v) = at(x, y);
                        ids.get(v as usize * self.width as usize + u as usize).copied().unwrap_or(0)
                    })
                    .collect(),
            ),
            Pixels::Bits(_) => {
                let plane = MaskSet::plane_bytes(width, height);
                let mut bits = vec![0u8; plane * self.instances.len()];
                for k in 0..self.instances.len() {
                    for y in 0..height {
                        for x in 0..width {
                            let (u, v) = at(x, y);
                            if view.contains(k, u, v) {
                                let i = y as usize * width as usize + x as usize;
                                if let Some(b) = bits.get_mut(k * plane + i / 8) {
                                    *b |= 1 << (i % 8);
                                }
                            }
                        }
                    }
                }
                Pixels::Bits(bits)
            }
        };
        let scale = |c: u16, max: u16| (c / n).min(max.saturating_sub(1));
        let instances = self
            .instances
            .iter()
            .map(|i| Instance {
                bbox: [
                    scale(i.bbox[0], width),
                    scale(i.bbox[1], height),
                    scale(i.bbox[2], width),
                    scale(i.bbox[3], height),
                ],
                ..*i
            })
            .collect();
        FrameMasks { width, height, instances, pixels }
    }

    /// Instance id of the first instance containing pixel (u, v), 0 for none (the reference label of docs/metrics.md).
    pub fn id_at(&self, u: u16, v: u16) -> u16 {
        let view = self.view();
        (0..self.instances.len())
            .find(|&k| view.contains(k, u, v))
            .and_then(|k| self.instances.get(k))
            .map_or(0, |i| i.id)
    }
}

/// One instance of a mask JSON; other fields (e.g. `area`, which many mask producers write) are ignored.
#[derive(Deserialize)]
struct JsonInstance {
    id: u16,
    label: String,
    score: f32,
    bbox: [i64; 4],
}

#[derive(Deserialize)]
struct JsonMasks {
    instances: Vec<JsonInstance>,
}

/// The labels of the ground-truth ids of frame `stem` of a dataset (id → label): from `gt/<stem>.json`, else
/// from the dataset's own `masks/<stem>.json` (whose ids are the ground truth's on sets that ship both, such as
/// YCB-Video); empty when neither exists.
pub fn read_gt_labels(dataset: &Path, stem: &str) -> Result<HashMap<u16, String>> {
    let file = format!("{stem}.json");
    let Some(json) =
        [dataset.join("gt").join(&file), dataset.join("masks").join(&file)].into_iter().find(|p| p.is_file())
    else {
        return Ok(HashMap::new());
    };
    let text = fs::read_to_string(&json).with_context(|| format!("{}: cannot read", json.display()))?;
    let parsed: JsonMasks =
        serde_json::from_str(&text).map_err(|e| anyhow!("{}: malformed instance list: {e}", json.display()))?;
    Ok(parsed.instances.into_iter().map(|i| (i.id, i.label)).collect())
}

/// Reads the masks of frame `stem` from `dir` for a `width × height` frame; `Ok(None)` when it has none.
pub fn read_frame_masks(
    dir: &Path,
    stem: &str,
    width: u16,
    height: u16,
    labels: &mut LabelTable,
) -> Result<Option<FrameMasks>> {
    let png = dir.join(format!("{stem}.png"));
    let txt = dir.join(format!("{stem}.txt"));
    let masks = if png.is_file() {
        read_id_masks(&png, &dir.join(format!("{stem}.json")), width, height, labels)?
    } else if txt.is_file() {
        let names = read_names(dir)?;
        read_yolo(&txt, &names, width, height, labels)?
    } else {
        return Ok(None);
    };
    masks
        .view()
        .validate(width, height)
        .map_err(|e| anyhow!("{}: {e}", if png.is_file() { png.display() } else { txt.display() }))?;
    Ok(Some(masks))
}

fn read_id_masks(png: &Path, json: &Path, width: u16, height: u16, labels: &mut LabelTable) -> Result<FrameMasks> {
    let bytes = fs::read(png).with_context(|| format!("{}: cannot open", png.display()))?;
    let text = fs::read_to_string(json)
        .with_context(|| format!("{}: cannot read (needed beside {})", json.display(), png.display()))?;
    parse_id_masks(&bytes, &png.display().to_string(), &text, &json.display().to_string(), width, height, labels)
}

/// Parses an id image (PNG bytes) and its instance list (JSON text); `png` and `json` name them in errors.
pub fn parse_id_masks(
    bytes: &[u8],
    png: &str,
    text: &str,
    json: &str,
    width: u16,
    height: u16,
    labels: &mut LabelTable,
) -> Result<FrameMasks> {
    let img = image::load_from_memory(bytes).map_err(|e| anyhow!("{png}: cannot decode mask image: {e}"))?;
    let (w, h) = (img.width(), img.height());
    if (w, h) != (width as u32, height as u32) {
        bail!("{png}: mask is {w}x{h} but the frame is {width}x{height}");
    }
    let ids: Vec<u16> = match img {
        image::DynamicImage::ImageLuma8(m) => m.into_raw().into_iter().map(u16::from).collect(),
        image::DynamicImage::ImageLuma16(m) => m.into_raw(),
        other => bail!("{png}: mask must be an 8- or 16-bit single-channel PNG, found {:?}", other.color()),
    };
    let parsed: JsonMasks = serde_json::from_str(text).map_err(|e| anyhow!("{json}: malformed instance list: {e}"))?;
    let mut instances = Vec::with_capacity(parsed.instances.len());
    for i in parsed.instances {
        if !(i.score.is_finite() && (0.0..=1.0).contains(&i.score)) {
            bail!("{json}: instance {} has score {} outside [0, 1]", i.id, i.score);
        }
        let [x0, y0, x1, y1] = i.bbox;
        let clamp = |x: i64, hi: u16| x.clamp(0, hi as i64 - 1) as u16;
        if x0 > x1 || y0 > y1 || x1 < 0 || y1 < 0 || x0 >= width as i64 || y0 >= height as i64 {
            bail!("{json}: instance {} has an empty or out-of-image box {:?}", i.id, i.bbox);
        }
        instances.push(Instance {
            id: i.id,
            class: labels.class_of(&i.label),
            score: i.score,
            bbox: [clamp(x0, width), clamp(y0, height), clamp(x1, width), clamp(y1, height)],
        });
    }
    let mut missing: Vec<u16> =
        ids.iter().copied().filter(|&id| id != 0 && !instances.iter().any(|i| i.id == id)).collect();
    missing.sort_unstable();
    missing.dedup();
    if let Some(id) = missing.first() {
        bail!("{png}: mask id {id} has no entry in {json}");
    }
    Ok(FrameMasks { width, height, instances, pixels: Pixels::Ids(ids) })
}

/// Writes `masks` as frame `stem` of the input mask format (docs/formats.md) into `dir`: a 16-bit id image
/// `<stem>.png` and the instance list `<stem>.json` with each instance's label from `labels`, so that
/// [`read_frame_masks`] reads the same masks back (bit planes are flattened to ids, the first instance wins).
pub fn write_frame_masks(dir: &Path, stem: &str, masks: &FrameMasks, labels: &LabelTable) -> Result<()> {
    let ids: Vec<u16> = match &masks.pixels {
        Pixels::Ids(ids) => ids.clone(),
        Pixels::Bits(_) => (0..masks.height)
            .flat_map(|v| (0..masks.width).map(move |u| (u, v)))
            .map(|(u, v)| masks.id_at(u, v))
            .collect(),
    };
    let png = dir.join(format!("{stem}.png"));
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(masks.width as u32, masks.height as u32, ids)
        .ok_or_else(|| anyhow!("{}: mask size does not match its pixels", png.display()))?
        .save(&png)
        .with_context(|| format!("{}: cannot write", png.display()))?;
    let list: Vec<serde_json::Value> = masks
        .instances
        .iter()
        .map(|i| serde_json::json!({ "id": i.id, "label": labels.name(i.class), "score": i.score, "bbox": i.bbox }))
        .collect();
    let json = dir.join(format!("{stem}.json"));
    fs::write(&json, serde_json::to_string(&serde_json::json!({ "instances": list }))?)
        .with_context(|| format!("{}: cannot write", json.display()))
}

fn read_names(dir: &Path) -> Result<Vec<String>> {
    for name in ["names.txt", "classes.txt", "coco.names"] {
        let p = dir.join(name);
        if p.is_file() {
            let text = fs::read_to_string(&p).with_context(|| format!("{}: cannot read", p.display()))?;
            return Ok(text.lines().map(|l| l.trim().to_owned()).filter(|l| !l.is_empty()).collect());
        }
    }
    Ok(Vec::new())
}

/// Reads YOLO segmentation text into bit planes.
pub fn read_yolo(
    path: &Path,
    names: &[String],
    width: u16,
    height: u16,
    labels: &mut LabelTable,
) -> Result<FrameMasks> {
    let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    parse_yolo(&text, &path.display().to_string(), names, width, height, labels)
}

/// Parses YOLO segmentation text (`name` labels its errors) into bit planes.
pub fn parse_yolo(
    text: &str,
    name: &str,
    names: &[String],
    width: u16,
    height: u16,
    labels: &mut LabelTable,
) -> Result<FrameMasks> {
    let plane = MaskSet::plane_bytes(width, height);
    let mut bits = Vec::new();
    let mut instances = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = |why: &str| anyhow!("{name}:{}: {why}: {line:?}", n + 1);
        let mut fields = line.split_whitespace();
        let class: usize = fields.next().and_then(|c| c.parse().ok()).ok_or_else(|| bad("malformed class"))?;
        let values: Vec<f64> =
            fields.map(|f| f.parse::<f64>()).collect::<Result<_, _>>().map_err(|_| bad("malformed number"))?;
        let (coords, score) = if values.len() % 2 == 1 {
            (&values[..values.len() - 1], values[values.len() - 1])
        } else {
            (&values[..], 1.0)
        };
        if coords.len() < 6 {
            return Err(bad("a polygon needs at least 3 points"));
        }
        if !(0.0..=1.0).contains(&score) {
            return Err(bad("confidence outside [0, 1]"));
        }
        if coords.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return Err(bad("polygon coordinates must be normalised to [0, 1]"));
        }
        let poly: Vec<(f64, f64)> =
            coords.chunks_exact(2).map(|c| (c[0] * width as f64, c[1] * height as f64)).collect();
        let mut mask = vec![0u8; plane];
        let bbox = rasterise(&poly, width, height, &mut mask);
        let Some(bbox) = bbox else { continue }; // a polygon covering no pixel centre
        let label = names.get(class).cloned().unwrap_or_else(|| format!("class{class}"));
        instances.push(Instance {
            id: instances.len() as u16 + 1,
            class: labels.class_of(&label),
            score: score as f32,
            bbox,
        });
        bits.extend_from_slice(&mask);
    }
    Ok(FrameMasks { width, height, instances, pixels: Pixels::Bits(bits) })
}

/// Even-odd scanline fill of a polygon (pixel coordinates) at pixel centres; returns the covered box.
fn rasterise(poly: &[(f64, f64)], width: u16, height: u16, mask: &mut [u8]) -> Option<[u16; 4]> {
    let mut bbox: Option<[u16; 4]> = None;
    let mut xs = Vec::new();
    for v in 0..height {
        let y = v as f64 + 0.5;
        xs.clear();
        for (i, &(x0, y0)) in poly.iter().enumerate() {
            let (x1, y1) = poly[(i + 1) % poly.len()];
            if (y0 <= y && y < y1) || (y1 <= y && y < y0) {
                xs.push(x0 + (y - y0) / (y1 - y0) * (x1 - x0));
            }
        }
        xs.sort_by(f64::total_cmp);
        for pair in xs.chunks_exact(2) {
            let start = (pair[0] - 0.5).ceil().max(0.0) as i64;
            let end = ((pair[1] - 0.5).floor() as i64).min(width as i64 - 1);
            for u in start..=end {
                let i = v as usize * width as usize + u as usize;
                mask[i / 8] |= 1 << (i % 8);
                let (u, v) = (u as u16, v);
                bbox = Some(match bbox {
                    None => [u, v, u, v],
                    Some(b) => [b[0].min(u), b[1].min(v), b[2].max(u), b[3].max(v)],
                });
            }
        }
    }
    bbox
}

/// Where the masks of a run come from: `--masks DIR`, else `DATASET/masks` when it exists.
pub fn mask_dir(dataset: &Path, explicit: Option<&Path>) -> Option<PathBuf> {
    match explicit {
        Some(d) => Some(d.to_owned()),
        None => Some(dataset.join("masks")).filter(|d| d.is_dir()),
    }
}
