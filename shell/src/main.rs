//! The `m2smap` command line (every command and option: docs/cli.md).

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use anyhow::{anyhow, Result};
use clap::{Parser, Subcommand};
use m2smap::dataset::Dataset;
use m2smap::masks::{mask_dir, LabelTable};
use m2smap::run::{map_frame, MaskSource, SegmenterBuffers};
use m2smap::run::{run, ProfileChoice, RunOptions, Segmenter};
use m2smap::{budget, export, render, report, sweep, synth};
use m2smap_core::{HostStorage, Mapper, McuStorage, Params, TinyStorage};

/// What `render` and `export` map a frame with.
struct Session<'a, 'm> {
    dataset: &'a Dataset,
    mapper: &'a mut Mapper<'m>,
    source: MaskSource<'a>,
    labels: &'a mut LabelTable,
    seg: &'a mut SegmenterBuffers,
}

/// How `run`, `render` and `export` map: the variant, parameters, camera, capacity profile and subsampling.
#[derive(clap::Args)]
struct MappingArgs {
    /// Method variant: full, paper, pmsao, wsqa, mmog, mmp, mmq.
    #[arg(long)]
    variant: Option<String>,
    /// JSON file of parameter overrides (field names of `Params`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Camera: a preset (fr1, fr2, fr3, 7scenes) or a camera.json file (default: from the folder).
    #[arg(long)]
    camera: Option<String>,
    /// Capacity profile of the core.
    #[arg(long, value_enum, default_value = "host")]
    profile: ProfileChoice,
    /// Subsample every frame (depth, colour, masks) by N before mapping: pixel (x, y) is pixel (N·x, N·y) and
    /// the camera's focal lengths and principal point are divided by N (e.g. 2 for 1920×1080 sensors).
    #[arg(long, value_name = "N", default_value_t = 1)]
    downscale: u16,
}

/// Where `render` looks from.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ViewChoice {
    /// The frame's camera (four panels).
    Camera,
    /// Around the map's objects.
    Orbit,
    /// From above.
    Top,
}

/// `render --world`: maps frames 0..=`last` into a world map and draws it from `view`.
fn render_world(
    s: Session<'_, '_>,
    last: usize,
    view: render::MapView,
    dataset: &std::path::Path,
    out: &std::path::Path,
) -> Result<()> {
    let mut storage = m2smap::world::host_storage();
    let mut world = m2smap_core::world::WorldMap::new(&mut storage);
    let mut first = None;
    for k in 0..=last {
        let pose = s.dataset.frames[k]
            .pose
            .ok_or_else(|| {
                anyhow!("{}: frame {k} has no camera pose; --world needs one for every frame", dataset.display())
            })?
            .to_core();
        map_frame(s.mapper, s.dataset, k, s.source, s.labels, s.seg)?;
        world
            .integrate(k as u32, &pose, s.mapper.params(), |f| s.mapper.for_each_world_primitive(f))
            .map_err(|e| anyhow!("frame {k}: world map: {e}"))?;
        first.get_or_insert(pose);
    }
    let first = first.ok_or_else(|| anyhow!("no frame mapped"))?;
    let c = &s.dataset.camera;
    let k = m2smap_core::Intrinsics { fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy };
    render::render_world(&world, &first, &k, (c.width as u32, c.height as u32), view, out)?;
    let [planes, sqs, gmms] = world.primitive_counts();
    println!("world map of frames 0..={last}: {planes} planes, {sqs} SQs, {gmms} GMMs -> {}", out.display());
    Ok(())
}

/// The variant named on the command line, or an error listing the valid names.
fn parse_variant(name: &str) -> Result<Variant> {
    Variant::from_name(name).ok_or_else(|| {
        let names: Vec<&str> = Variant::ALL.iter().map(|v| v.name()).collect();
        anyhow!("unknown variant {name:?}; one of {}", names.join(", "))
    })
}

/// Opens a dataset and runs `f` with a mapper of the variant, parameters, camera, capacity profile and
/// subsampling of `how`, and the frame's mask source.
fn with_mapper(
    dataset: &std::path::Path,
    how: &MappingArgs,
    masks: Option<PathBuf>,
    segmenter: Option<Segmenter>,
    f: impl FnOnce(Session<'_, '_>) -> Result<()>,
) -> Result<()> {
    let d = Dataset::open(dataset, how.camera.as_deref())?.downscaled(how.downscale)?;
    let mut params: Params = m2smap::run::load_params(how.config.as_deref())?;
    if let Some(name) = how.variant.as_deref() {
        params.variant = parse_variant(name)?;
    }
    // Only the chosen profile's storage is allocated.
    let (mut host, mut mcu, mut tiny);
    let mapper = match how.profile {
        ProfileChoice::Host => {
            host = bytemuck::zeroed_box::<HostStorage>();
            Mapper::new(&mut *host, params)
        }
        ProfileChoice::Mcu => {
            mcu = bytemuck::zeroed_box::<McuStorage>();
            Mapper::new(&mut *mcu, params)
        }
        ProfileChoice::Tiny => {
            tiny = bytemuck::zeroed_box::<TinyStorage>();
            Mapper::new(&mut *tiny, params)
        }
    };
    let mut mapper = mapper.map_err(|e| anyhow!("{e}"))?;
    let masks_dir = mask_dir(&d.root, masks.as_deref());
    let mut labels = LabelTable::default();
    let mut seg = SegmenterBuffers::default();
    f(Session {
        dataset: &d,
        mapper: &mut mapper,
        source: mask_source(&masks_dir, segmenter),
        labels: &mut labels,
        seg: &mut seg,
    })
}

/// Mask files when they exist and no segmenter was asked for; the segmenter otherwise.
fn mask_source(dir: &Option<PathBuf>, segmenter: Option<Segmenter>) -> MaskSource<'_> {
    match (dir, segmenter) {
        (Some(d), None) => MaskSource::Files(Some(d.as_path())),
        _ => MaskSource::Segmenter,
    }
}
use m2smap_core::Variant;

#[derive(Parser)]
#[command(name = "m2smap", version, about = "Memory-efficient semantic mapping of RGB-D frames (M2-SMap)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Map a TUM or 7-Scenes folder; writes DIR/summary.json and DIR/frames.jsonl.
    Run {
        /// Dataset folder.
        dataset: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Process at most N frames.
        #[arg(long)]
        frames: Option<usize>,
        #[command(flatten)]
        how: MappingArgs,
        /// Instance-mask folder (default: DATASET/masks when it exists).
        #[arg(long, conflicts_with = "segmenter")]
        masks: Option<PathBuf>,
        /// Make masks with the built-in depth-only segmenter (the default when the dataset has no masks).
        #[arg(long, value_enum)]
        segmenter: Option<Segmenter>,
        /// Inject stream faults with this seed (dropped and repeated frames, dead or spiky depth, NaN poses,
        /// stale masks, pose jumps); rejected frames are reported in frames.jsonl and the run goes on.
        #[arg(long)]
        faults: Option<u32>,
        /// Fraction of frames hit by --faults.
        #[arg(long, default_value_t = 0.25)]
        fault_rate: f32,
        /// Also fuse every frame into one world map (needs camera poses) and write DIR/world.bin, world.ply,
        /// deltas.bin (the delta stream), world.jsonl (per frame) and world_summary.json.
        #[arg(long, value_name = "DIR")]
        world: Option<PathBuf>,
    },
    /// Write a synthetic scene with ground truth as a TUM folder (rgb/, depth/, groundtruth.txt, camera.json,
    /// masks/ and the exact gt/ with objects.json).
    Synth {
        /// Scene name: tabletop, shelf, desk, kitchen (table with a mug, ball, cushion, cereal box, bottle),
        /// clutter (objects touching each other, the floor and the wall: built to provoke adhesion), dining (a
        /// table masked as one non-convex instance, top and legs, with a box, a can and a stack of two boxes on
        /// it and a crate on the floor beside it).
        #[arg(long)]
        scene: String,
        /// Number of frames.
        #[arg(long)]
        frames: usize,
        /// Seed of the sensor noise and of the mask degradation.
        #[arg(long, default_value_t = 1)]
        seed: u32,
        /// Render exact depth and colour (no sensor noise).
        #[arg(long)]
        no_noise: bool,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Erode each instance in masks/ by PX pixels (gt/ stays exact).
        #[arg(long, value_name = "PX", default_value_t = 0)]
        mask_erode: u32,
        /// Dilate each instance in masks/ by PX pixels, never over another instance.
        #[arg(long, value_name = "PX", default_value_t = 0)]
        mask_dilate: u32,
        /// Drop each instance from masks/ in each frame with probability P.
        #[arg(long, value_name = "P", default_value_t = 0.0)]
        mask_miss: f64,
        /// Mask scores become clamp(1 - |N(0, S)|, 0.05, 1) (0: every score is 1).
        #[arg(long, value_name = "S", default_value_t = 0.0)]
        mask_score_noise: f64,
    },
    /// Draw the four-panel picture of frame K (masks, Gaussians, fused clusters, map; frames 0..K warm the
    /// superquadric tracks, as in `run`) into a PNG, or with
    /// `--view orbit|top` the frame's map from around or above its objects.
    Render {
        /// Dataset folder.
        dataset: PathBuf,
        /// Frame index (from 0).
        #[arg(long)]
        frame: usize,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Instance-mask folder (default: DATASET/masks when it exists).
        #[arg(long, conflicts_with = "segmenter")]
        masks: Option<PathBuf>,
        /// Use the built-in depth-only segmenter (the default when the dataset has no masks).
        #[arg(long, value_enum)]
        segmenter: Option<Segmenter>,
        /// camera: the four panels seen from the frame's camera; orbit: the map from four sides of its
        /// objects (45°, 135°, 225°, 315° about the up axis), or one side with --angle; top: from above.
        #[arg(long, value_enum, default_value = "camera")]
        view: ViewChoice,
        /// With --view orbit: one view at this azimuth, degrees from the camera's side (counter-clockwise
        /// seen from above).
        #[arg(long, requires = "view")]
        angle: Option<f32>,
        /// Draw the world map of frames 0..=K (needs camera poses) from around all of it, in the first
        /// camera's frame: --view orbit (the default here) or top.
        #[arg(long)]
        world: bool,
        #[command(flatten)]
        how: MappingArgs,
    },
    /// Export the reconstructed map of frame K (or of every frame) as PLY point clouds.
    Export {
        /// Dataset folder.
        dataset: PathBuf,
        /// Frame index (from 0).
        #[arg(long, default_value_t = 0)]
        frame: usize,
        /// Output PLY file; with --all-frames, a folder of frame_NNNNNN.ply.
        #[arg(long)]
        ply: PathBuf,
        /// Export every frame of the sequence (tracks carry over between frames).
        #[arg(long)]
        all_frames: bool,
        /// World coordinates (needs poses in the dataset).
        #[arg(long)]
        world: bool,
        /// Instance-mask folder (default: DATASET/masks when it exists).
        #[arg(long, conflicts_with = "segmenter")]
        masks: Option<PathBuf>,
        /// Use the built-in depth-only segmenter (the default when the dataset has no masks).
        #[arg(long, value_enum)]
        segmenter: Option<Segmenter>,
        #[command(flatten)]
        how: MappingArgs,
    },
    /// Write the built-in geometric segmenter's instance masks of every frame into DIR in the input mask format
    /// (DIR/<stem>.png, 16-bit ids, and DIR/<stem>.json), to inspect, edit and map with `run --masks DIR`.
    Segment {
        /// Dataset folder.
        dataset: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Process at most N frames.
        #[arg(long)]
        frames: Option<usize>,
        #[command(flatten)]
        how: MappingArgs,
    },
    /// Run every variant on every dataset; writes DIR/report.md (the paper's Tables I and II), the comparison
    /// figure DIR/comparison.svg and .png, and one run folder per dataset and variant.
    Eval {
        /// Dataset folders (TUM or 7-Scenes).
        #[arg(required = true)]
        datasets: Vec<PathBuf>,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Process at most N frames of each dataset.
        #[arg(long)]
        frames: Option<usize>,
    },
    /// Map every synthetic scene × seed × mask degradation with `full` and score each run against the
    /// superquadric issue's synthetic targets; writes DIR/sweep.md and DIR/sweep.json (scenes made under
    /// DIR/data, runs in DIR/runs).
    Sweep {
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Scenes (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "tabletop,shelf,desk,kitchen,clutter,dining")]
        scenes: Vec<String>,
        /// Seeds of the sensor noise and of the mask degradation (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
        seeds: Vec<u32>,
        /// Mask degradations (comma-separated): perfect, erodeN (N px, 10 % of the masks missing), dilateN.
        #[arg(long, value_delimiter = ',', default_value = "erode2,dilate2")]
        masks: Vec<String>,
        /// Frames per run.
        #[arg(long, default_value_t = 10)]
        frames: usize,
    },
    /// Print the memory budget table of the mcu profile.
    Budget,
    /// Export frames for the firmware image, with the host's map digests (expected.txt).
    FirmwareFrames {
        /// Dataset folder.
        dataset: PathBuf,
        /// Number of frames.
        #[arg(long, default_value_t = 2)]
        frames: usize,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    match execute(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", format!("{e:#}").replace('\n', " "));
            ExitCode::FAILURE
        }
    }
}

fn execute(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run { dataset, out, frames, how, masks, segmenter, faults, fault_rate, world } => {
            let MappingArgs { variant, config, camera, profile, downscale } = how;
            let variant = match variant {
                Some(name) => Some(parse_variant(&name)?),
                None => None,
            };
            let opts = RunOptions {
                dataset,
                out: out.clone(),
                variant,
                frames,
                config,
                camera,
                profile,
                downscale,
                masks,
                segmenter,
                faults: faults.map(|seed| (seed, fault_rate)),
                progress: std::io::stderr().is_terminal(),
                world: world.clone(),
            };
            let s = run(&opts)?;
            println!(
                "{} frames ({}, {} profile): {:.0} points, {:.0} voxels, {:.1} supervoxels, {:.1} Gaussians, \
                 {:.1} clusters, {:.2} planes, {:.2} SQs, {:.1} GMMs per frame; {:.0} B/frame ({:.1} B/primitive); \
                 G2R {:.4} m, R2G {:.4} m; R_c {:.2}, N_adh {:.3}, J_sq {:.1} deg; \
                 median {:.2} ms ({:.0} Hz); {} overflow events -> {}",
                s.frames,
                s.variant,
                s.profile,
                s.points,
                s.voxels,
                s.supervoxels,
                s.gaussians,
                s.clusters,
                s.primitives.plane.unwrap_or(0.0),
                s.primitives.sq.unwrap_or(0.0),
                s.primitives.gmm.unwrap_or(0.0),
                s.payload_bytes.unwrap_or(0.0),
                s.bytes_per_primitive.unwrap_or(0.0),
                s.g2r_rmse_m.unwrap_or(0.0),
                s.r2g_rmse_m.unwrap_or(0.0),
                s.r_c.unwrap_or(0.0),
                s.n_adh.unwrap_or(0.0),
                s.j_sq_deg.unwrap_or(0.0),
                s.ms_per_frame_median,
                s.hz,
                s.overflow_events,
                out.join("summary.json").display()
            );
            println!("camera: {}", s.camera);
            if let (Some(w), Some(dir)) = (&s.world, &world) {
                println!(
                    "world map: {} planes, {} SQs, {} GMMs, {} B; deltas {:.0} B/frame ({:.2} of the frame maps); \
                     G2R {:.4} m, R2G {:.4} m against {} observed points -> {}",
                    w.planes,
                    w.sqs,
                    w.gmms,
                    w.world_bytes,
                    w.delta_bytes_mean,
                    w.delta_to_frame_map,
                    w.g2r_rmse_m.unwrap_or(0.0),
                    w.r2g_rmse_m.unwrap_or(0.0),
                    w.observed_points,
                    dir.join("world_summary.json").display()
                );
            }
            // Overflow drops or coarsens data (points, voxels, Gaussians …): say which pools and what the voxel
            // pool's drop policy did, so it is never silent.
            let full: Vec<String> = s
                .pools
                .iter()
                .filter(|(_, p)| p.overflow_events > 0)
                .map(|(name, p)| format!("{name} ({} events, capacity {})", p.overflow_events, p.capacity))
                .collect();
            if !full.is_empty() {
                eprintln!(
                    "warning: the {} profile's pools overflowed: {}; {} frames mapped with coarser voxels, {} over a \
                     nearer depth range, {} points dropped (see memory_budget.md; --profile host has room)",
                    s.profile,
                    full.join(", "),
                    s.frames_coarser_voxels,
                    s.frames_nearer_range,
                    s.dropped_points
                );
            }
            Ok(())
        }
        Command::Eval { datasets, out, frames } => {
            let opts = report::EvalOptions { datasets, out: out.clone(), frames, verbose: true };
            report::evaluate(&opts)?;
            println!("report: {}", out.join("report.md").display());
            Ok(())
        }
        Command::Sweep { out, scenes, seeds, masks, frames } => {
            let opts =
                sweep::SweepOptions { out: out.clone(), scenes, seeds, degradations: masks, frames, verbose: true };
            let runs = sweep::sweep(&opts)?;
            println!(
                "{} of {} runs meet every target -> {}",
                sweep::met(&runs),
                runs.len(),
                out.join("sweep.md").display()
            );
            Ok(())
        }
        Command::Synth { scene, frames, seed, no_noise, out, mask_erode, mask_dilate, mask_miss, mask_score_noise } => {
            let degradation = synth::Degradation {
                erode: mask_erode,
                dilate: mask_dilate,
                miss: mask_miss,
                score_noise: mask_score_noise,
            };
            synth::Scene::named(&scene)?.write_tum_degraded(&out, frames, seed, !no_noise, &degradation)?;
            println!("wrote {frames} frames of scene {scene} to {}", out.display());
            Ok(())
        }
        Command::FirmwareFrames { dataset, frames, out } => {
            let d = m2smap::dataset::Dataset::open(&dataset, None)?;
            m2smap::firmware::export(&d, frames, &out)?;
            println!("wrote {frames} firmware frames and expected.txt to {}", out.display());
            Ok(())
        }
        Command::Render { dataset, frame, out, masks, segmenter, view, angle, world, how } => {
            with_mapper(&dataset, &how, masks, segmenter, |s| {
                check_frame(s.dataset, frame)?;
                let view = if world && view == ViewChoice::Camera { ViewChoice::Orbit } else { view };
                let map_view = match (view, angle) {
                    (ViewChoice::Camera, None) => None,
                    (ViewChoice::Orbit, None) => Some(render::MapView::Orbit),
                    (ViewChoice::Orbit, Some(a)) if a.is_finite() => Some(render::MapView::OrbitAt(a)),
                    (ViewChoice::Top, None) => Some(render::MapView::Top),
                    (_, Some(a)) => anyhow::bail!("--angle {a} goes with --view orbit and must be a number of degrees"),
                };
                if let (true, Some(v)) = (world, map_view) {
                    return render_world(s, frame, v, &dataset, &out);
                }
                // Earlier frames warm the superquadric tracks: the picture shows the map `run` has at this frame.
                for k in 0..frame {
                    map_frame(s.mapper, s.dataset, k, s.source, s.labels, s.seg)?;
                }
                let m = map_frame(s.mapper, s.dataset, frame, s.source, s.labels, s.seg)?;
                let fv = m.loaded.view(&s.dataset.camera);
                match map_view {
                    None => render::render_panels(s.mapper, &fv, m.masks.as_ref(), &out)?,
                    Some(v) => {
                        render::render_views(s.mapper, &fv, v, &out)?;
                    }
                }
                let mut wire = vec![0u8; m2smap::run::WIRE_BUFFER_BYTES];
                let bytes = s.mapper.encode_map(&mut wire).map_err(|e| anyhow!("encoding the map: {e}"))?;
                println!(
                    "frame {frame}: {} planes, {} SQs, {} GMMs, {bytes} bytes -> {}",
                    m.report.planes,
                    m.report.sqs,
                    m.report.gmms,
                    out.display()
                );
                Ok(())
            })
        }
        Command::Segment { dataset, out, frames, how } => {
            if how.downscale > 1 {
                anyhow::bail!("segment: --downscale would write masks smaller than the frames (`run --masks` reads masks at the frames' size)");
            }
            with_mapper(&dataset, &how, None, Some(Segmenter::Geometric), |s| {
                let d = s.dataset;
                std::fs::create_dir_all(&out).with_context(|| format!("{}: cannot create", out.display()))?;
                let n = frames.map_or(d.frames.len(), |k| k.min(d.frames.len()));
                let mut instances = 0usize;
                for k in 0..n {
                    let mapped = map_frame(s.mapper, d, k, s.source, s.labels, s.seg)?;
                    let masks = mapped.masks.ok_or_else(|| anyhow!("frame {k}: the segmenter made no masks"))?;
                    instances += masks.instances.len();
                    m2smap::masks::write_frame_masks(&out, &d.frames[k].stem, &masks, s.labels)?;
                }
                println!(
                    "{n} frames, {:.1} instances per frame -> {} (map them with: m2smap run {} --masks {})",
                    instances as f64 / n.max(1) as f64,
                    out.display(),
                    dataset.display(),
                    out.display()
                );
                Ok(())
            })
        }
        Command::Export { dataset, frame, ply, all_frames, world, masks, segmenter, how } => {
            with_mapper(&dataset, &how, masks, segmenter, |s| {
                let d = s.dataset;
                if !all_frames {
                    check_frame(d, frame)?;
                }
                let frames: Vec<usize> = if all_frames { (0..d.frames.len()).collect() } else { (0..=frame).collect() };
                // --world needs the pose of every exported frame: known before any mapping.
                let exported = |k: &usize| all_frames || *k == frame;
                if let Some(k) = frames
                    .iter()
                    .filter(|k| exported(k))
                    .find(|&&k| world && d.frames.get(k).is_none_or(|f| f.pose.is_none()))
                {
                    anyhow::bail!("{}: --world needs camera poses, frame {k} has none", d.root.display());
                }
                if all_frames {
                    std::fs::create_dir_all(&ply).with_context(|| format!("{}: cannot create", ply.display()))?;
                }
                for k in frames {
                    map_frame(s.mapper, d, k, s.source, s.labels, s.seg)?;
                    if !all_frames && k != frame {
                        continue; // earlier frames only warm the superquadric tracks
                    }
                    let pose = match (world, d.frames[k].pose.as_ref()) {
                        (true, Some(p)) => Some(p),
                        (true, None) => {
                            anyhow::bail!("{}: --world needs camera poses, frame {k} has none", d.root.display())
                        }
                        (false, _) => None,
                    };
                    let path = if all_frames { ply.join(format!("frame_{k:06}.ply")) } else { ply.clone() };
                    let v = export::vertices(s.mapper, pose);
                    export::write_ply(&path, &v)?;
                    println!("frame {k}: {} vertices -> {}", v.len(), path.display());
                }
                Ok(())
            })
        }
        Command::Budget => {
            print!("{}", budget::table());
            println!("\nWorld map (`m2smap_core::world`), a separate caller-owned storage:\n");
            print!("{}", budget::world_table());
            Ok(())
        }
    }
}

/// `--frame` names a frame of the dataset: otherwise an error that says how many there are.
fn check_frame(d: &m2smap::dataset::Dataset, frame: usize) -> Result<()> {
    let n = d.frames.len();
    if frame >= n {
        anyhow::bail!(
            "{}: --frame {frame} is beyond the last frame (the dataset has {n}, numbered 0–{})",
            d.root.display(),
            n.saturating_sub(1)
        );
    }
    Ok(())
}
