//! `m2smap run`: replays a dataset through the core and writes `summary.json` and `frames.jsonl` (docs/formats.md).

use std::collections::BTreeMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use bytemuck::Zeroable;
use m2smap_core::{FrameReport, HostStorage, Mapper, McuStorage, Params, PoolId, Profile, TinyStorage, Variant};
use serde::Serialize;

use crate::dataset::{read_depth, Dataset};
use crate::eval;
use crate::faults::{self, Fault};
use crate::masks::{mask_dir, read_frame_masks, FrameMasks, LabelTable, Pixels};

pub use m2smap_core::segment::SEGMENTER_INSTANCES;

/// Where a run's instance masks come from besides files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Segmenter {
    /// The core's depth-only segmenter (`m2smap_core::segment`).
    Geometric,
}

/// Which capacity profile to run the core with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ProfileChoice {
    /// Large pools (workstation).
    Host,
    /// The 512 KiB microcontroller profile.
    Mcu,
    /// Every pool a few entries (robustness testing).
    Tiny,
}

/// Options of `m2smap run`.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Dataset folder.
    pub dataset: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// Variant (overrides the config file's).
    pub variant: Option<Variant>,
    /// Process at most this many frames.
    pub frames: Option<usize>,
    /// JSON file with `Params` fields to override.
    pub config: Option<PathBuf>,
    /// Camera preset name or `camera.json` path.
    pub camera: Option<String>,
    /// Capacity profile.
    pub profile: ProfileChoice,
    /// Subsample every frame by this factor (1 = full size; see [`Dataset::downscaled`]).
    pub downscale: u16,
    /// Mask folder (`--masks`); default `DATASET/masks` when present.
    pub masks: Option<PathBuf>,
    /// `--segmenter geometric`; the default when no masks exist.
    pub segmenter: Option<Segmenter>,
    /// Fault injection: (seed, fraction of frames); rejected frames are then reported instead of stopping the run.
    pub faults: Option<(u32, f32)>,
    /// Show a progress bar (on a terminal).
    pub progress: bool,
    /// `--world DIR`: also build the world map over the sequence and write it into DIR ([`crate::world`]).
    pub world: Option<PathBuf>,
}

/// Primitive counts of a frame or their means (null until the stage producing them exists).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Primitives {
    /// Bounded planes.
    pub plane: Option<f64>,
    /// Superquadrics.
    pub sq: Option<f64>,
    /// Gaussian primitives.
    pub gmm: Option<f64>,
    /// All primitives.
    pub total: Option<f64>,
}

/// Use of one pool.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct PoolRecord {
    /// Most entries in use.
    pub peak: usize,
    /// Capacity.
    pub capacity: usize,
    /// Refused insertions.
    pub overflow_events: u64,
}

/// Per-frame values (the keys of docs/formats.md, with the stage counts), one line of `frames.jsonl`.
#[derive(Debug, Clone, Default, Serialize)]
pub struct FrameRecord {
    /// Frame index in the run, from 0.
    pub index: usize,
    /// File stem of the frame.
    pub stem: String,
    /// Core pipeline time, milliseconds.
    pub ms: f64,
    /// Sampled points.
    pub points: u32,
    /// Occupied voxels.
    pub voxels: u32,
    /// Supervoxels.
    pub supervoxels: u32,
    /// Gaussians C_g.
    pub gaussians: u32,
    /// Instances in the frame's masks.
    pub instances: usize,
    /// The segmenter that made the masks, when they did not come from files.
    pub segmenter: Option<&'static str>,
    /// The fault injected into this frame, if any.
    pub fault: Option<Fault>,
    /// Why the core rejected the frame (its map and tracks stayed as they were); the counts are then zero.
    pub rejected: Option<String>,
    /// Largest move of a superquadric track in this frame, metres.
    pub max_track_step_m: f64,
    /// Gaussians annotated with an instance.
    pub annotated: u32,
    /// Fused clusters.
    pub clusters: u32,
    /// Semantic objects.
    pub objects: u32,
    /// Gaussians removed as plane support.
    pub plane_gaussians: u32,
    /// Gaussians in object support sets.
    pub object_gaussians: u32,
    /// Residual Gaussians.
    pub residual_gaussians: u32,
    /// Object Gaussians detached from their instance as residual Gaussians (a part its largest part does not
    /// reach: core `objects::detach_stray_parts`).
    pub detached_gaussians: u32,
    /// Objects whose superquadric fit was rejected.
    pub sq_rejected: u32,
    /// Objects without an acceptable fit whose cold search was skipped: refused in the previous frame (core
    /// `Refusal`) or over the frame's search budget.
    pub sq_skipped: u32,
    /// Tracked objects whose cold search waited for a later frame (core `Params::sq_search_budget`).
    pub sq_deferred: u32,
    /// Cold searches run for tracked objects (at most core `Params::sq_search_budget`).
    pub sq_tracked_searches: u32,
    /// Objects shown by their track's state because this frame's fit was not acceptable.
    pub sq_held: u32,
    /// Live superquadric tracks.
    pub tracks: u32,
    /// Tracks started in this frame.
    pub new_tracks: u32,
    /// Sum of track rotation changes this frame, degrees.
    pub sq_jump_sum_deg: f64,
    /// Track updates with a previous state this frame.
    pub sq_jumps: u32,
    /// Points in outlier clusters.
    pub outlier_points: u32,
    /// Points lost to full pools.
    pub dropped_points: u32,
    /// Far end of the depth range the frame was mapped over, metres (nearer than `depth_max` when its voxels
    /// did not fit the pool even at the coarsest voxels: the voxel pool's drop policy,
    /// `m2smap_core::mapper::VOXEL_RANGE_CUT`).
    pub voxel_range_m: f64,
    /// Voxel edge the frame was mapped with, metres (coarser than `voxel_resolution` when its voxels did not
    /// fit the pool: `m2smap_core::mapper::VOXEL_COARSEN`).
    pub voxel_resolution_m: f64,
    /// Primitive counts.
    pub primitives: Primitives,
    /// Wire payload, bytes.
    pub payload_bytes: Option<f64>,
    /// Generated-to-real RMSE, metres.
    pub g2r_rmse_m: Option<f64>,
    /// G2R over the samples the observed depth does not hide, metres (a diagnostic beside the paper's metrics,
    /// docs/metrics.md; see [`crate::eval::ReconstructionMetrics::g2r_unoccluded_rmse_m`]).
    pub g2r_unoccluded_rmse_m: Option<f64>,
    /// Real-to-generated RMSE, metres.
    pub r2g_rmse_m: Option<f64>,
    /// Gaussians per fused cluster.
    pub r_c: Option<f64>,
    /// Semantic fusion consistency.
    pub a_s: Option<f64>,
    /// Adhesion cases.
    pub n_adh: Option<f64>,
    /// Mean SQ rotation jump, degrees.
    pub j_sq_deg: Option<f64>,
    /// Map-level (docs/metrics.md, from all the surface samples of the frame's own map, [`eval::map_samples`]):
    /// fraction of the samples whose status is known that lie in free space ([`eval::free_space`]).
    pub free_space_violation: Option<f64>,
    /// The same over the superquadric samples.
    pub free_space_violation_sq: Option<f64>,
    /// Superquadrics with more than 2 % of their samples behind the unlabelled support ([`eval::behind_support`];
    /// needs `gt/`).
    pub sq_behind_support: Option<f64>,
    /// Largest fraction of one superquadric's samples behind the support (null without superquadrics).
    pub sq_behind_support_max_fraction: Option<f64>,
    /// Deepest superquadric sample behind the support, metres (null without superquadrics).
    pub sq_behind_support_max_m: Option<f64>,
    /// Map-level adhesion cases: primitives whose depth-consistent samples fall on two ground-truth ids
    /// ([`eval::adhesion_cases`]; needs `gt/`).
    pub adhesion_map: Option<f64>,
    /// Map-level adhesion cases among the superquadrics.
    pub adhesion_map_sq: Option<f64>,
    /// Largest size error of this frame's superquadrics on objects with a nominal size ([`eval::sq_sizes`];
    /// needs `gt/` and labels; null when no superquadric is scored).
    pub sq_size_error_max: Option<f64>,
    /// Every scored superquadric: the object's label, the superquadric's full extents and the nominal size
    /// (metres) and the size error.
    pub sq_sizes: Vec<eval::SqSize>,
    /// Instance recall of this frame's masks (file or segmenter) against `gt/` at IoU ≥ 0.5
    /// ([`eval::mask_match`]; needs `gt/`).
    pub mask_recall: Option<f64>,
    /// Instance precision of the masks at IoU ≥ 0.5: matched / claims on ground-truth instances (a claim with
    /// fewer than half its pixels on them is on structure, which the ground truth cannot judge).
    pub mask_precision: Option<f64>,
    /// Matched / every claim, claims on structure included.
    pub mask_precision_all: Option<f64>,
    /// Mask instances on structure (fewer than half their pixels on ground-truth instances).
    pub mask_structure_claims: Option<u32>,
    /// Mean IoU of the matched masks.
    pub mask_mean_iou: Option<f64>,
    /// The counts behind the three (pooled over the run for `summary.json`; not written).
    #[serde(skip)]
    pub mask_match: Option<eval::MaskMatch>,
    /// G2R against the true surfaces, all samples, metres ([`eval::true_surface_metrics`]; needs
    /// `gt/objects.json` and a pose).
    pub g2r_true_rmse_m: Option<f64>,
    /// G2R against the true surfaces, superquadric samples, metres.
    pub g2r_true_sq_rmse_m: Option<f64>,
    /// 95th percentile over the frame's primitives of their penetration of other true solids, metres.
    pub penetration_p95_m: Option<f64>,
    /// Largest penetration of a primitive, metres.
    pub penetration_max_m: Option<f64>,
    /// 95th percentile over the frame's superquadrics of their penetration, metres.
    pub penetration_sq_p95_m: Option<f64>,
    /// Largest penetration of a superquadric, metres.
    pub penetration_sq_max_m: Option<f64>,
    /// Time the map-level metrics took for this frame, milliseconds (not part of `ms`).
    pub map_metrics_ms: f64,
    /// Penetration of every primitive, metres (kept for the run's percentiles, not written).
    #[serde(skip)]
    pub penetrations: Vec<f64>,
    /// Penetration of every superquadric, metres (not written).
    #[serde(skip)]
    pub penetrations_sq: Vec<f64>,
    /// Pool use.
    pub pools: BTreeMap<String, PoolRecord>,
    /// Overflow events of all pools.
    pub overflow_events: u64,
}

/// `summary.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// The world map of `run --world` (also in `DIR/world_summary.json`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub world: Option<crate::world::WorldSummary>,
    /// Frames mapped.
    pub frames: usize,
    /// Frames the core rejected (fault injection).
    pub frames_rejected: usize,
    /// Frames dropped from the stream (fault injection).
    pub frames_dropped: usize,
    /// Frames whose voxels did not fit the pool at the configured edge and were mapped with coarser ones
    /// (`m2smap_core::mapper::VOXEL_COARSEN`).
    pub frames_coarser_voxels: usize,
    /// Frames whose voxels did not fit the pool even at the coarsest edge and were mapped over a nearer depth
    /// range (`m2smap_core::mapper::VOXEL_RANGE_CUT`).
    pub frames_nearer_range: usize,
    /// Points lost to full pools over the run (beyond a nearer range, or refused by a full voxel).
    pub dropped_points: u64,
    /// Largest move of a superquadric track between two frames, metres.
    pub max_track_step_m: f64,
    /// Variant name.
    pub variant: String,
    /// Capacity profile.
    pub profile: String,
    /// Where the camera model came from (`Dataset::camera_source`), with its intrinsics.
    pub camera: String,
    /// 1 / median core time per frame, Hz.
    pub hz: f64,
    /// Median core time per frame, ms.
    pub ms_per_frame_median: f64,
    /// Mean sampled points per frame.
    pub points: f64,
    /// Mean voxels per frame.
    pub voxels: f64,
    /// Mean supervoxels per frame.
    pub supervoxels: f64,
    /// Mean Gaussians per frame.
    pub gaussians: f64,
    /// Mean fused clusters per frame.
    pub clusters: f64,
    /// Mean objects per frame.
    pub objects: f64,
    /// Fraction of frames with at least one plane.
    pub frames_with_plane: f64,
    /// Fraction of frames with at least one accepted superquadric.
    pub frames_with_sq: f64,
    /// Tracks started over the run.
    pub tracks_started: u64,
    /// Mean primitive counts.
    pub primitives: Primitives,
    /// Mean payload, bytes.
    pub payload_bytes: Option<f64>,
    /// Payload bytes per primitive over the run (the paper reports about 109).
    pub bytes_per_primitive: Option<f64>,
    /// Mean G2R RMSE, metres.
    pub g2r_rmse_m: Option<f64>,
    /// Mean G2R over the samples the observed depth does not hide, metres (diagnostic).
    pub g2r_unoccluded_rmse_m: Option<f64>,
    /// Mean R2G RMSE, metres.
    pub r2g_rmse_m: Option<f64>,
    /// Mean R_c.
    pub r_c: Option<f64>,
    /// Mean A_s.
    pub a_s: Option<f64>,
    /// Mean N_adh.
    pub n_adh: Option<f64>,
    /// Mean J_sq, degrees.
    pub j_sq_deg: Option<f64>,
    /// Mean map-level free-space violation (fraction of known samples; see [`FrameRecord`]).
    pub free_space_violation: Option<f64>,
    /// Mean free-space violation of the superquadric samples.
    pub free_space_violation_sq: Option<f64>,
    /// Mean superquadrics behind the support per frame.
    pub sq_behind_support: Option<f64>,
    /// Mean per-frame largest fraction of a superquadric behind the support.
    pub sq_behind_support_max_fraction: Option<f64>,
    /// Mean per-frame deepest superquadric sample behind the support, metres.
    pub sq_behind_support_max_m: Option<f64>,
    /// Mean map-level adhesion cases per frame.
    pub adhesion_map: Option<f64>,
    /// Mean map-level superquadric adhesion cases per frame.
    pub adhesion_map_sq: Option<f64>,
    /// Superquadrics scored against a nominal object size over the run ([`eval::sq_sizes`]).
    pub sq_sizes_scored: usize,
    /// Fraction of them within [`eval::SQ_SIZE_TOLERANCE`] of the nominal size.
    pub sq_sizes_within_tolerance: Option<f64>,
    /// Median size error of the scored superquadrics.
    pub sq_size_error_median: Option<f64>,
    /// Largest size error of a scored superquadric.
    pub sq_size_error_max: Option<f64>,
    /// Instance recall of the masks against `gt/` at IoU ≥ 0.5, pooled over the frames (matched / ground-truth
    /// instances; [`eval::mask_match`]).
    pub mask_recall: Option<f64>,
    /// Instance precision of the masks at IoU ≥ 0.5, pooled (matched / claims on ground-truth instances).
    pub mask_precision: Option<f64>,
    /// Matched / every claim, pooled (claims on structure included).
    pub mask_precision_all: Option<f64>,
    /// Mask instances on structure per frame (mean).
    pub mask_structure_claims: Option<f64>,
    /// Mean IoU of the matched masks, pooled.
    pub mask_mean_iou: Option<f64>,
    /// Mean G2R against the true surfaces, metres.
    pub g2r_true_rmse_m: Option<f64>,
    /// Mean G2R of the superquadric samples against the true surfaces, metres.
    pub g2r_true_sq_rmse_m: Option<f64>,
    /// 95th percentile of the penetration over all primitives of all frames, metres.
    pub penetration_p95_m: Option<f64>,
    /// Largest penetration of any primitive in the run, metres.
    pub penetration_max_m: Option<f64>,
    /// 95th percentile of the penetration over all superquadrics of all frames, metres.
    pub penetration_sq_p95_m: Option<f64>,
    /// Largest penetration of any superquadric in the run, metres.
    pub penetration_sq_max_m: Option<f64>,
    /// Median time of the map-level metrics per frame, milliseconds.
    pub map_metrics_ms_median: f64,
    /// Peak use of every pool over the run.
    pub pools: BTreeMap<String, PoolRecord>,
    /// Overflow events over the run.
    pub overflow_events: u64,
}

/// Wire buffer for one frame's map: far more than any map needs (a map of 64 planes and 4 096 Gaussians is
/// under 200 KiB).
pub const WIRE_BUFFER_BYTES: usize = 1 << 20;

/// Where one frame's masks come from.
#[derive(Debug, Clone, Copy)]
pub enum MaskSource<'a> {
    /// Mask files in this folder (none: no masks).
    Files(Option<&'a Path>),
    /// The core's geometric segmenter.
    Segmenter,
}

/// Caller-owned buffers of the geometric segmenter, reused across frames.
#[derive(Debug, Default)]
pub struct SegmenterBuffers {
    ids: Vec<u16>,
    instances: Vec<m2smap_core::Instance>,
}

/// One mapped frame.
pub struct Mapped {
    /// The decoded frame.
    pub loaded: crate::dataset::LoadedFrame,
    /// Its masks (from files or the segmenter).
    pub masks: Option<FrameMasks>,
    /// The core's report.
    pub report: FrameReport,
    /// Core pipeline time, milliseconds (decoding excluded).
    pub ms: f64,
}

/// Loads frame `index` of `dataset` with its masks and runs the pipeline on it (with the dataset's pose).
pub fn map_frame(
    mapper: &mut Mapper<'_>,
    dataset: &Dataset,
    index: usize,
    source: MaskSource<'_>,
    labels: &mut LabelTable,
    seg: &mut SegmenterBuffers,
) -> Result<Mapped> {
    map_frame_with_fault(mapper, dataset, index, source, labels, seg, None)
}

/// [`map_frame`] with an injected fault (see [`crate::faults`]); `Dropped` and `RepeatedTimestamp` are the
/// caller's to apply, they change nothing here.
pub fn map_frame_with_fault(
    mapper: &mut Mapper<'_>,
    dataset: &Dataset,
    index: usize,
    source: MaskSource<'_>,
    labels: &mut LabelTable,
    seg: &mut SegmenterBuffers,
    fault: Option<(Fault, u32)>,
) -> Result<Mapped> {
    let fref = dataset.frames.get(index).ok_or_else(|| anyhow!("{}: no frame {index}", dataset.root.display()))?;
    let mut loaded = dataset.load(index)?;
    let mut pose = fref.pose;
    let mut mask_stem = fref.stem.as_str();
    if let Some((f, seed)) = fault {
        faults::corrupt_depth(&mut loaded, f, seed ^ index as u32);
        pose = faults::corrupt_pose(pose, f);
        if f == Fault::StaleMasks {
            mask_stem = dataset.frames.get(index.saturating_sub(5)).map_or(mask_stem, |r| r.stem.as_str());
        }
    }
    let frame = loaded.view_posed(&dataset.camera, pose.as_ref());
    let error = |e: m2smap_core::FrameError| match e {
        m2smap_core::FrameError::TooLarge { pixels, max_pixels } => {
            // The smallest subsampling that fits, counted on the files' own size.
            let (w, h) = (dataset.source_size.0 as usize, dataset.source_size.1 as usize);
            let fits = (1..=crate::dataset::MAX_DOWNSCALE).find(|&n| (w / n as usize) * (h / n as usize) <= max_pixels);
            match fits {
                Some(n) if n > dataset.downscale => anyhow!(
                    "{}: {e}; pass --downscale {n} to map it at {}x{}",
                    fref.depth.display(),
                    w / n as usize,
                    h / n as usize
                ),
                _ => anyhow!("{}: {e} ({pixels} pixels)", fref.depth.display()),
            }
        }
        e => anyhow!("{}: {e}", fref.depth.display()),
    };
    match source {
        MaskSource::Files(dir) => {
            let masks = match dir {
                Some(d) => {
                    let (w, h) = dataset.source_size;
                    read_frame_masks(d, mask_stem, w, h, labels)?.map(|m| {
                        if dataset.downscale > 1 {
                            m.subsampled(dataset.downscale, loaded.width, loaded.height)
                        } else {
                            m
                        }
                    })
                }
                None => None,
            };
            let start = Instant::now();
            let report = *mapper.process(frame, masks.as_ref().map(|m| m.view())).map_err(error)?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            Ok(Mapped { loaded, masks, report, ms })
        }
        MaskSource::Segmenter => {
            let class = labels.class_of("object");
            seg.ids.resize(frame.pixels(), 0);
            seg.instances
                .resize(SEGMENTER_INSTANCES, m2smap_core::Instance { id: 0, class: 0, score: 0.0, bbox: [0; 4] });
            let start = Instant::now();
            let (report, k) =
                mapper.process_segmented(frame, &mut seg.ids, &mut seg.instances, class).map_err(error)?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            let masks = FrameMasks {
                width: loaded.width,
                height: loaded.height,
                instances: seg.instances[..k].to_vec(),
                pixels: Pixels::Ids(seg.ids.clone()),
            };
            Ok(Mapped { loaded, masks: Some(masks), report, ms })
        }
    }
}

/// Reads `Params` from a JSON file of overrides (unknown keys are an error).
pub fn load_params(path: Option<&Path>) -> Result<Params> {
    let Some(path) = path else { return Ok(Params::default()) };
    let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let params: Params = serde_json::from_str(&text).map_err(|e| anyhow!("{}: bad parameters: {e}", path.display()))?;
    params.validate().map_err(|e| anyhow!("{}: {e}", path.display()))?;
    Ok(params)
}

/// Median of a list (NaN-free), 0 when empty.
pub fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = values.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 {
        0.0
    } else {
        s / n as f64
    }
}

/// Pool records of a frame report.
pub fn pool_records(report: &FrameReport) -> BTreeMap<String, PoolRecord> {
    PoolId::ALL
        .iter()
        .zip(report.pools.iter())
        .map(|(id, u)| {
            (
                id.name().to_owned(),
                PoolRecord { peak: u.peak, capacity: u.capacity, overflow_events: u.overflow_events as u64 },
            )
        })
        .collect()
}

/// Runs the mapper over a dataset and writes the outputs. Returns the summary.
pub fn run(opts: &RunOptions) -> Result<Summary> {
    let dataset = Dataset::open(&opts.dataset, opts.camera.as_deref())?.downscaled(opts.downscale)?;
    if dataset.frames.is_empty() {
        return Err(anyhow!("{}: the dataset lists no frames", opts.dataset.display()));
    }
    if opts.frames == Some(0) {
        return Err(anyhow!("--frames 0: nothing to map (give at least 1)"));
    }
    // A camera preset that contradicts the TUM sequence named by the folder is most likely a mistake.
    if let (Some(given), Some(named)) =
        (opts.camera.as_deref().and_then(crate::dataset::preset_key), crate::dataset::preset_in_name(&opts.dataset))
    {
        if given != named {
            eprintln!("warning: --camera {given} on {}, whose name says {named}", opts.dataset.display());
        }
    }
    let mut params = load_params(opts.config.as_deref())?;
    if let Some(v) = opts.variant {
        params.variant = v;
    }
    fs::create_dir_all(&opts.out).with_context(|| format!("{}: cannot create", opts.out.display()))?;
    if opts.world.is_some() && dataset.frames.iter().take(opts.frames.unwrap_or(usize::MAX)).any(|f| f.pose.is_none()) {
        return Err(anyhow!("{}: --world needs a camera pose for every frame", opts.dataset.display()));
    }
    let (records, world) = match opts.profile {
        ProfileChoice::Host => replay(&dataset, params, opts, &mut *bytemuck::zeroed_box::<HostStorage>())?,
        ProfileChoice::Mcu => replay(&dataset, params, opts, &mut *bytemuck::zeroed_box::<McuStorage>())?,
        ProfileChoice::Tiny => replay(&dataset, params, opts, &mut *bytemuck::zeroed_box::<TinyStorage>())?,
    };
    let mut summary = summarise(&records, &params, opts.profile);
    summary.world = world;
    let c = &dataset.camera;
    let subsampled = match dataset.downscale {
        1 => String::new(),
        n => format!(" (--downscale {n} of {}×{})", dataset.source_size.0, dataset.source_size.1),
    };
    summary.camera = format!(
        "{}: fx {} fy {} cx {} cy {}, {}×{}{subsampled}, depth scale {}",
        dataset.camera_source, c.fx, c.fy, c.cx, c.cy, c.width, c.height, c.depth_scale
    );
    let path = opts.out.join("summary.json");
    fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
        .with_context(|| format!("{}: cannot write", path.display()))?;
    Ok(summary)
}

fn replay<P: Profile + Zeroable>(
    dataset: &Dataset,
    params: Params,
    opts: &RunOptions,
    storage: &mut P,
) -> Result<(Vec<FrameRecord>, Option<crate::world::WorldSummary>)> {
    let mut mapper = Mapper::new(storage, params).map_err(|e| anyhow!("parameters: {e}"))?;
    let mut world_storage = opts.world.as_ref().map(|_| crate::world::host_storage());
    let mut world = match (opts.world.as_deref(), world_storage.as_deref_mut()) {
        (Some(dir), Some(storage)) => Some(crate::world::WorldRun::create(dir, storage)?),
        _ => None,
    };
    let masks_dir = mask_dir(&dataset.root, opts.masks.as_deref());
    if let Some(d) = masks_dir.as_ref().filter(|d| !d.is_dir()) {
        return Err(anyhow!("{}: mask folder does not exist", d.display()));
    }
    // A mask folder given on the command line must hold masks: an empty one would map without instances.
    if let Some(d) = opts.masks.as_deref().filter(|d| d.is_dir()) {
        let has_masks = fs::read_dir(d)
            .with_context(|| format!("{}: cannot read", d.display()))?
            .filter_map(|e| e.ok())
            .any(|e| e.path().extension().is_some_and(|x| x == "png" || x == "txt"));
        if !has_masks {
            return Err(anyhow!("{}: mask folder holds no masks (.png + .json or .txt per frame)", d.display()));
        }
    }
    let mut labels = LabelTable::default();
    // The geometric segmenter when asked for, and by default when the dataset has no masks (and the variant
    // uses semantics).
    let segmenter = match opts.segmenter {
        Some(Segmenter::Geometric) => true,
        None => masks_dir.is_none() && params.variant.annotates(),
    };
    let mut seg = SegmenterBuffers::default();
    let n = opts.frames.map_or(dataset.frames.len(), |k| k.min(dataset.frames.len()));
    let jsonl_path = opts.out.join("frames.jsonl");
    let mut jsonl = std::io::BufWriter::new(
        fs::File::create(&jsonl_path).with_context(|| format!("{}: cannot create", jsonl_path.display()))?,
    );
    let bar = if opts.progress { indicatif::ProgressBar::new(n as u64) } else { indicatif::ProgressBar::hidden() };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames {msg} [{elapsed} < {eta}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let objects = dataset.root.join("gt").join("objects.json");
    let surfaces = if objects.is_file() { crate::synth::read_surfaces(&objects)? } else { None };
    let mut records = Vec::with_capacity(n);
    let mut wire_buf = vec![0u8; WIRE_BUFFER_BYTES];
    for (index, fref) in dataset.frames.iter().take(n).enumerate() {
        let fault = opts.faults.and_then(|(seed, rate)| faults::fault_of(seed, index, rate));
        if fault == Some(Fault::Dropped) {
            records.push(FrameRecord { index, stem: fref.stem.clone(), fault, ..FrameRecord::default() });
            bar.inc(1);
            continue;
        }
        let repeats = if fault == Some(Fault::RepeatedTimestamp) { 2 } else { 1 };
        for _ in 0..repeats {
            let gt_path = dataset.root.join("gt").join(format!("{}.png", fref.stem));
            let gt = if gt_path.is_file() {
                let ids = read_depth(&gt_path)?.2;
                Some(
                    dataset
                        .subsample(&ids, 1)
                        .ok_or_else(|| anyhow!("{}: not the size of the frames", gt_path.display()))?,
                )
            } else {
                None
            };
            let source = if segmenter { MaskSource::Segmenter } else { MaskSource::Files(masks_dir.as_deref()) };
            let seed = opts.faults.map_or(0, |(s, _)| s);
            let mapped = map_frame_with_fault(
                &mut mapper,
                dataset,
                index,
                source,
                &mut labels,
                &mut seg,
                fault.map(|f| (f, seed)),
            );
            let Mapped { loaded, masks, report, ms } = match mapped {
                Ok(m) => m,
                Err(e) if opts.faults.is_some() => {
                    // A rejected frame leaves the map and the tracks as they were; the run goes on.
                    let record = FrameRecord {
                        index,
                        stem: fref.stem.clone(),
                        fault,
                        rejected: Some(format!("{e:#}")),
                        ..FrameRecord::default()
                    };
                    serde_json::to_writer(&mut jsonl, &record)?;
                    jsonl.write_all(b"\n").with_context(|| format!("{}: cannot write", jsonl_path.display()))?;
                    records.push(record);
                    continue;
                }
                Err(e) => return Err(e),
            };
            let frame = loaded.view_posed(&dataset.camera, fref.pose.as_ref());
            let payload = mapper
                .encode_map(&mut wire_buf)
                .map_err(|e| anyhow!("{}: encoding the map: {e}", fref.depth.display()))?;
            let checked = mapper.check(frame, masks.as_ref().map(|m| m.view())).map_err(|e| anyhow!("{e}"))?;
            if let (Some(world), Some(pose)) = (world.as_mut(), fref.pose.as_ref()) {
                let mut observed = Vec::new();
                mapper.for_each_labelled_point(&checked, |p, _| observed.push(p.xyz));
                world.add_frame(
                    index,
                    &pose.to_core(),
                    mapper.params(),
                    payload,
                    |f| mapper.for_each_world_primitive(f),
                    &observed,
                )?;
            }
            let w = loaded.width as usize;
            let semantic = eval::semantic_metrics(&mapper, &checked, |u, v| match (&gt, &masks) {
                (Some(gt), _) => gt.get(v as usize * w + u as usize).copied().unwrap_or(0),
                (None, Some(m)) => m.id_at(u, v),
                (None, None) => 0,
            });
            let reconstruction = eval::reconstruction_metrics(&mapper, &checked);
            let start = Instant::now();
            let map = eval::map_samples(&mapper);
            let obs = eval::Observation { frame, params: mapper.params(), gt: gt.as_deref() };
            let free = eval::free_space(&map, &obs);
            let behind = eval::behind_support(&map, &obs);
            let adhesion = eval::adhesion_cases(&map, &obs);
            let sq_sizes = match gt {
                Some(_) => eval::sq_sizes(&map, &obs, &crate::masks::read_gt_labels(&dataset.root, &fref.stem)?),
                None => None,
            };
            let truth = surfaces.as_deref().zip(fref.pose).map(|(s, pose)| eval::true_surface_metrics(&map, &pose, s));
            // Without masks nothing is claimed and every ground-truth instance is missed.
            let no_masks = || FrameMasks {
                width: loaded.width,
                height: loaded.height,
                instances: vec![],
                pixels: Pixels::Ids(vec![]),
            };
            let mask_match = gt.as_deref().map(|g| eval::mask_match(masks.as_ref().unwrap_or(&no_masks()), g));
            let map_metrics_ms = start.elapsed().as_secs_f64() * 1e3;
            let penetrations = truth.as_ref().map(|t| t.penetrations(false)).unwrap_or_default();
            let penetrations_sq = truth.as_ref().map(|t| t.penetrations(true)).unwrap_or_default();
            let (penetration, penetration_sq) = (p95_and_max(&penetrations), p95_and_max(&penetrations_sq));
            let has_sq = behind.as_ref().filter(|b| !b.fractions.is_empty());
            let gmm = report.gmms as f64;
            let sq = params.variant.superquadrics().then_some(report.sqs as f64);
            let record = FrameRecord {
                index,
                stem: fref.stem.clone(),
                ms,
                points: report.points,
                voxels: report.voxels,
                supervoxels: report.supervoxels,
                gaussians: report.gaussians,
                instances: masks.as_ref().map_or(0, |m| m.instances.len()),
                segmenter: segmenter.then_some("geometric"),
                fault,
                rejected: None,
                max_track_step_m: report.max_track_step_m as f64,
                annotated: report.annotated,
                clusters: report.clusters,
                objects: report.objects,
                plane_gaussians: report.plane_gaussians,
                object_gaussians: report.object_gaussians,
                residual_gaussians: report.residual_gaussians,
                outlier_points: report.outlier_points,
                dropped_points: report.dropped_points,
                voxel_range_m: report.voxel_range_m as f64,
                voxel_resolution_m: report.voxel_resolution_m as f64,
                primitives: Primitives {
                    plane: Some(report.planes as f64),
                    sq: Some(sq.unwrap_or(0.0)),
                    gmm: Some(gmm),
                    total: Some(report.planes as f64 + sq.unwrap_or(0.0) + gmm),
                },
                detached_gaussians: report.detached_gaussians,
                sq_rejected: report.sq_rejected,
                sq_skipped: report.sq_skipped,
                sq_deferred: report.sq_deferred,
                sq_tracked_searches: report.sq_tracked_searches,
                sq_held: report.sq_held,
                tracks: report.tracks,
                new_tracks: report.new_tracks,
                sq_jump_sum_deg: report.sq_jump_sum_deg as f64,
                sq_jumps: report.sq_jumps,
                payload_bytes: Some(payload as f64),
                g2r_rmse_m: reconstruction.map(|r| r.g2r_rmse_m),
                g2r_unoccluded_rmse_m: reconstruction.map(|r| r.g2r_unoccluded_rmse_m),
                r2g_rmse_m: reconstruction.map(|r| r.r2g_rmse_m),
                r_c: Some(report.r_c as f64),
                a_s: semantic.a_s,
                n_adh: Some(semantic.n_adh as f64),
                j_sq_deg: (report.sq_jumps > 0).then(|| report.sq_jump_sum_deg as f64 / report.sq_jumps as f64),
                free_space_violation: free.fraction(),
                free_space_violation_sq: free.fraction_sq(),
                sq_behind_support: behind.as_ref().map(|b| b.sqs as f64),
                sq_behind_support_max_fraction: has_sq.and_then(|b| b.max_fraction()),
                sq_behind_support_max_m: has_sq.map(|b| b.max_depth_m),
                adhesion_map: adhesion.map(|a| a.0 as f64),
                adhesion_map_sq: adhesion.map(|a| a.1 as f64),
                sq_size_error_max: sq_sizes.as_ref().and_then(|v| v.iter().map(|s| s.error).reduce(f64::max)),
                sq_sizes: sq_sizes.unwrap_or_default(),
                mask_recall: mask_match.and_then(|m| m.recall()),
                mask_precision: mask_match.and_then(|m| m.precision()),
                mask_precision_all: mask_match.and_then(|m| m.precision_all()),
                mask_structure_claims: mask_match.map(|m| m.structure_claims),
                mask_mean_iou: mask_match.and_then(|m| m.mean_iou()),
                mask_match,
                g2r_true_rmse_m: truth.as_ref().and_then(|t| t.g2r_true_rmse_m),
                g2r_true_sq_rmse_m: truth.as_ref().and_then(|t| t.g2r_true_sq_rmse_m),
                penetration_p95_m: penetration.0,
                penetration_max_m: penetration.1,
                penetration_sq_p95_m: penetration_sq.0,
                penetration_sq_max_m: penetration_sq.1,
                map_metrics_ms,
                penetrations,
                penetrations_sq,
                pools: pool_records(&report),
                overflow_events: report.overflow_events as u64,
            };
            serde_json::to_writer(&mut jsonl, &record)?;
            jsonl.write_all(b"\n").with_context(|| format!("{}: cannot write", jsonl_path.display()))?;
            bar.set_message(format!("{} Gaussians, {} planes, {:.1} ms", report.gaussians, report.planes, ms));
            records.push(record);
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    jsonl.flush().with_context(|| format!("{}: cannot write", jsonl_path.display()))?;
    let world = world.map(|w| w.finish()).transpose()?;
    Ok((records, world))
}

/// Mean of the defined values, `None` when there are none.
fn mean_of(values: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = values.flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The values of every frame's list, in one list.
fn pooled(records: &[FrameRecord], list: impl Fn(&FrameRecord) -> &[f64]) -> Vec<f64> {
    records.iter().flat_map(|r| list(r).iter().copied()).collect()
}

/// The 95th percentile and the largest of `values` (penetrations, metres); `None` each without values.
fn p95_and_max(values: &[f64]) -> (Option<f64>, Option<f64>) {
    (eval::percentile(values, 0.95), values.iter().copied().reduce(f64::max))
}

fn summarise(all: &[FrameRecord], params: &Params, profile: ProfileChoice) -> Summary {
    let variant = params.variant;
    // Dropped and rejected frames have no map: they are counted, not averaged.
    let records: Vec<FrameRecord> =
        all.iter().filter(|r| r.rejected.is_none() && r.fault != Some(Fault::Dropped)).cloned().collect();
    let records = &records[..];
    let ms = median(&records.iter().map(|r| r.ms).collect::<Vec<_>>());
    let penetration = p95_and_max(&pooled(records, |r| &r.penetrations));
    let penetration_sq = p95_and_max(&pooled(records, |r| &r.penetrations_sq));
    let masks_pooled = records.iter().filter_map(|r| r.mask_match).reduce(|a, b| a.add(&b));
    let size_errors: Vec<f64> = records.iter().flat_map(|r| r.sq_sizes.iter().map(|s| s.error)).collect();
    let mut pools: BTreeMap<String, PoolRecord> = BTreeMap::new();
    for r in records {
        for (name, p) in &r.pools {
            let e = pools.entry(name.clone()).or_default();
            e.peak = e.peak.max(p.peak);
            e.capacity = p.capacity;
            e.overflow_events += p.overflow_events;
        }
    }
    Summary {
        world: None,
        frames: records.len(),
        frames_rejected: all.iter().filter(|r| r.rejected.is_some()).count(),
        frames_dropped: all.iter().filter(|r| r.fault == Some(Fault::Dropped)).count(),
        frames_coarser_voxels: records
            .iter()
            .filter(|r| r.voxel_resolution_m > f64::from(params.voxel_resolution) * 1.001)
            .count(),
        frames_nearer_range: records.iter().filter(|r| r.voxel_range_m < f64::from(params.depth_max) * 0.999).count(),
        dropped_points: records.iter().map(|r| u64::from(r.dropped_points)).sum(),
        max_track_step_m: records.iter().map(|r| r.max_track_step_m).fold(0.0, f64::max),
        variant: variant.name().to_owned(),
        profile: match profile {
            ProfileChoice::Host => "host",
            ProfileChoice::Mcu => "mcu",
            ProfileChoice::Tiny => "tiny",
        }
        .to_owned(),
        camera: String::new(),
        hz: if ms > 0.0 { 1e3 / ms } else { 0.0 },
        ms_per_frame_median: ms,
        points: mean(records.iter().map(|r| r.points as f64)),
        voxels: mean(records.iter().map(|r| r.voxels as f64)),
        supervoxels: mean(records.iter().map(|r| r.supervoxels as f64)),
        gaussians: mean(records.iter().map(|r| r.gaussians as f64)),
        clusters: mean(records.iter().map(|r| r.clusters as f64)),
        objects: mean(records.iter().map(|r| r.objects as f64)),
        frames_with_plane: mean(
            records.iter().map(|r| if r.primitives.plane.unwrap_or(0.0) > 0.0 { 1.0 } else { 0.0 }),
        ),
        frames_with_sq: mean(records.iter().map(|r| if r.primitives.sq.unwrap_or(0.0) > 0.0 { 1.0 } else { 0.0 })),
        tracks_started: records.iter().map(|r| r.new_tracks as u64).sum(),
        primitives: Primitives {
            plane: mean_of(records.iter().map(|r| r.primitives.plane)),
            sq: mean_of(records.iter().map(|r| r.primitives.sq)),
            gmm: mean_of(records.iter().map(|r| r.primitives.gmm)),
            total: mean_of(records.iter().map(|r| r.primitives.total)),
        },
        payload_bytes: mean_of(records.iter().map(|r| r.payload_bytes)),
        bytes_per_primitive: {
            let (bytes, prims): (f64, f64) = records.iter().fold((0.0, 0.0), |(b, p), r| {
                (b + r.payload_bytes.unwrap_or(0.0), p + r.primitives.total.unwrap_or(0.0))
            });
            (prims > 0.0).then(|| bytes / prims)
        },
        g2r_rmse_m: mean_of(records.iter().map(|r| r.g2r_rmse_m)),
        g2r_unoccluded_rmse_m: mean_of(records.iter().map(|r| r.g2r_unoccluded_rmse_m)),
        r2g_rmse_m: mean_of(records.iter().map(|r| r.r2g_rmse_m)),
        r_c: mean_of(records.iter().map(|r| r.r_c)),
        a_s: mean_of(records.iter().map(|r| r.a_s)),
        n_adh: mean_of(records.iter().map(|r| r.n_adh)),
        // Mean over every consecutive update of every track (not a mean of per-frame means).
        j_sq_deg: {
            let jumps: u64 = records.iter().map(|r| r.sq_jumps as u64).sum();
            (jumps > 0).then(|| records.iter().map(|r| r.sq_jump_sum_deg).sum::<f64>() / jumps as f64)
        },
        free_space_violation: mean_of(records.iter().map(|r| r.free_space_violation)),
        free_space_violation_sq: mean_of(records.iter().map(|r| r.free_space_violation_sq)),
        sq_behind_support: mean_of(records.iter().map(|r| r.sq_behind_support)),
        sq_behind_support_max_fraction: mean_of(records.iter().map(|r| r.sq_behind_support_max_fraction)),
        sq_behind_support_max_m: mean_of(records.iter().map(|r| r.sq_behind_support_max_m)),
        adhesion_map: mean_of(records.iter().map(|r| r.adhesion_map)),
        adhesion_map_sq: mean_of(records.iter().map(|r| r.adhesion_map_sq)),
        sq_sizes_scored: size_errors.len(),
        sq_sizes_within_tolerance: (!size_errors.is_empty()).then(|| {
            size_errors.iter().filter(|&&e| e <= eval::SQ_SIZE_TOLERANCE).count() as f64 / size_errors.len() as f64
        }),
        sq_size_error_median: (!size_errors.is_empty()).then(|| median(&size_errors)),
        sq_size_error_max: size_errors.iter().copied().reduce(f64::max),
        mask_recall: masks_pooled.and_then(|m| m.recall()),
        mask_precision: masks_pooled.and_then(|m| m.precision()),
        mask_precision_all: masks_pooled.and_then(|m| m.precision_all()),
        mask_structure_claims: mean_of(records.iter().map(|r| r.mask_structure_claims.map(f64::from))),
        mask_mean_iou: masks_pooled.and_then(|m| m.mean_iou()),
        g2r_true_rmse_m: mean_of(records.iter().map(|r| r.g2r_true_rmse_m)),
        g2r_true_sq_rmse_m: mean_of(records.iter().map(|r| r.g2r_true_sq_rmse_m)),
        // Over every primitive of every frame, not a mean of per-frame values.
        penetration_p95_m: penetration.0,
        penetration_max_m: penetration.1,
        penetration_sq_p95_m: penetration_sq.0,
        penetration_sq_max_m: penetration_sq.1,
        map_metrics_ms_median: median(&records.iter().map(|r| r.map_metrics_ms).collect::<Vec<_>>()),
        pools,
        overflow_events: records.iter().map(|r| r.overflow_events).sum(),
    }
}
