//! The world map on the workstation side: `run --world DIR` (the core's [`WorldMap`] fed frame by frame, its
//! delta stream, `world.bin`, `world.ply`, a per-frame `world.jsonl` line and `world_summary.json`), the
//! receiving end of the delta stream ([`Receiver`]), world-map G2R / R2G against the union of every frame's
//! observed points, and the world-map render.
//!
//! `deltas.bin` is the delta stream as a radio link would carry it: each delta (docs/formats.md) preceded by
//! its length, a little-endian u32.

use std::collections::{BTreeMap, HashMap};
use std::fs;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};
use m2smap_core::map::Primitive;
use m2smap_core::wire::{self, DeltaChange, DeltaHeader, WireError};
use m2smap_core::world::{HostWorld, WorldMap, WorldStats};
use m2smap_core::{Params, Pose};
use serde::Serialize;

use crate::export::Vertex;
use crate::render::{id_colour, GMM_COLOUR, PLANE_COLOUR};

/// Observed points are pooled on a grid of this pitch (one point per cell), metres: the union of 300 frames'
/// samples stays a few hundred thousand points.
pub const OBSERVED_GRID_M: f32 = 0.01;

/// The receiving end of a delta stream: the records it holds, by (kind, id).
#[derive(Debug, Default, Clone)]
pub struct Receiver {
    /// Frame of the last delta applied.
    pub frame: u32,
    records: BTreeMap<(u8, u32), Vec<u8>>,
}

impl Receiver {
    /// Applies one delta (validated whole first: a bad delta changes nothing).
    pub fn apply(&mut self, delta: &[u8]) -> Result<DeltaHeader, WireError> {
        let mut changes: Vec<(u8, u32, Option<Vec<u8>>)> = Vec::new();
        let header = wire::decode_delta(delta, |c| match c {
            DeltaChange::Upsert(r) => changes.push((r.kind, r.id, Some(r.bytes.to_vec()))),
            DeltaChange::Remove { kind, id } => changes.push((kind, id, None)),
        })?;
        for (kind, id, bytes) in changes {
            match bytes {
                Some(b) => self.records.insert((kind, id), b),
                None => self.records.remove(&(kind, id)),
            };
        }
        self.frame = header.frame;
        Ok(header)
    }

    /// Records held.
    pub fn len(&self) -> usize {
        self.records.len()
    }

    /// Whether it holds no record.
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// The world map it holds, in the `world.bin` format.
    pub fn world_bytes(&self) -> Result<Vec<u8>, WireError> {
        let mut out = Vec::new();
        let mut scratch = [0u8; 32];
        wire::encode_world_records(
            self.frame,
            |sink| self.records.iter().try_for_each(|(&(kind, id), bytes)| sink(kind, id, bytes)),
            &mut scratch,
            |b| {
                out.extend_from_slice(b);
                Ok(())
            },
        )?;
        Ok(out)
    }
}

/// Splits a `deltas.bin` stream into its deltas.
pub fn split_deltas(stream: &[u8]) -> Result<Vec<&[u8]>> {
    let mut out = Vec::new();
    let mut rest = stream;
    while !rest.is_empty() {
        let (len, tail) = rest.split_at_checked(4).ok_or_else(|| anyhow!("truncated delta length"))?;
        let n = u32::from_le_bytes([len[0], len[1], len[2], len[3]]) as usize;
        let (delta, tail) = tail.split_at_checked(n).ok_or_else(|| anyhow!("truncated delta ({n} bytes announced)"))?;
        out.push(delta);
        rest = tail;
    }
    Ok(out)
}

/// One line of `world.jsonl`: the world map after a frame.
#[derive(Debug, Clone, Default, Serialize)]
pub struct WorldFrameRecord {
    /// Frame index in the run.
    pub index: usize,
    /// World planes.
    pub planes: usize,
    /// World superquadrics.
    pub sqs: usize,
    /// World Gaussians.
    pub gmms: usize,
    /// All world primitives.
    pub total: usize,
    /// Bytes of `world.bin` after this frame.
    pub world_bytes: usize,
    /// Bytes of this frame's delta.
    pub delta_bytes: usize,
    /// Bytes of this frame's own map (the wire format).
    pub frame_map_bytes: usize,
    /// Records the delta carries, by kind: planes, superquadrics, Gaussians.
    pub delta_records: [usize; 3],
    /// Bytes of those records, by kind.
    pub delta_record_bytes: [usize; 3],
    /// Removals the delta carries.
    pub delta_removals: usize,
    /// Frame planes merged into world planes.
    pub merged_planes: u32,
    /// World planes created.
    pub created_planes: u32,
    /// World planes drawn into another world plane of the same surface.
    pub joined_planes: u32,
    /// Frame Gaussians merged into world Gaussians.
    pub merged_gmms: u32,
    /// World Gaussians created.
    pub created_gmms: u32,
    /// World Gaussians evicted to make room.
    pub evicted_gmms: u32,
    /// Frame Gaussians dropped (no room).
    pub dropped_gmms: u32,
    /// Plane cells outside the world grids.
    pub clipped_cells: u32,
    /// Frame superquadrics seen only in part (their shape runs out of the image) that gave no world object a
    /// shape.
    pub partial_sqs: u32,
    /// World planes whose shown normal and offset took a step, and whose pending cells were shown.
    pub planes_moved_grown: [u32; 2],
    /// Occupied cells shown by the world planes, and new cells they hold back.
    pub plane_cells: [u32; 2],
}

/// `world_summary.json`.
#[derive(Debug, Clone, Default, Serialize)]
pub struct WorldSummary {
    /// Frames integrated.
    pub frames: usize,
    /// World planes, superquadrics, Gaussians and all primitives at the end.
    pub planes: usize,
    /// World superquadrics.
    pub sqs: usize,
    /// World Gaussians.
    pub gmms: usize,
    /// All world primitives.
    pub total: usize,
    /// Bytes of `world.bin`.
    pub world_bytes: usize,
    /// Mean bytes of a delta.
    pub delta_bytes_mean: f64,
    /// Mean bytes of a frame's own map.
    pub frame_map_bytes_mean: f64,
    /// `delta_bytes_mean / frame_map_bytes_mean`.
    pub delta_to_frame_map: f64,
    /// RMS distance from the world map's samples ([`seen_samples`]: superquadric surface that faces one of the
    /// run's cameras) to the union of the frames' observed points, metres.
    pub g2r_rmse_m: Option<f64>,
    /// RMS distance from the observed union (one point per 1 cm cell) to the world samples, metres.
    pub r2g_rmse_m: Option<f64>,
    /// G2R of the planes', superquadrics' and Gaussians' samples alone, metres.
    pub g2r_by_kind_m: [Option<f64>; 3],
    /// The samples G2R is taken over, by kind (planes, superquadrics, Gaussians): with `g2r_by_kind_m`, each
    /// kind's share of the squared error.
    pub g2r_samples_by_kind: [usize; 3],
    /// Observed points in the union.
    pub observed_points: usize,
    /// World reconstruction samples.
    pub world_samples: usize,
    /// Whether replaying `deltas.bin` gave `world.bin` byte for byte.
    pub receiver_identical: bool,
    /// World Gaussians evicted to make room, over the run.
    pub gmms_evicted: u32,
    /// Frame Gaussians dropped for lack of room, over the run.
    pub gmms_dropped: u32,
    /// Plane cells outside every world grid, over the run.
    pub cells_clipped: u32,
    /// Frame superquadrics seen only in part, over the run.
    pub sqs_partial: u32,
}

/// `run --world`: the world map fed after every frame, writing as it goes.
pub struct WorldRun<'s> {
    dir: PathBuf,
    world: WorldMap<'s>,
    deltas: fs::File,
    jsonl: std::io::BufWriter<fs::File>,
    observed: HashMap<[i32; 3], [f32; 3]>,
    records: Vec<WorldFrameRecord>,
    frame: u32,
    cameras: Vec<[f32; 3]>,
    totals: WorldStats,
}

/// Storage of a host world map, zeroed on the heap.
pub fn host_storage() -> Box<HostWorld> {
    bytemuck::zeroed_box::<HostWorld>()
}

impl<'s> WorldRun<'s> {
    /// Starts a world run writing into `dir`.
    pub fn create(dir: &Path, storage: &'s mut HostWorld) -> Result<Self> {
        fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
        let file = |name: &str| {
            let p = dir.join(name);
            fs::File::create(&p).with_context(|| format!("{}: cannot create", p.display()))
        };
        Ok(WorldRun {
            dir: dir.to_owned(),
            world: WorldMap::new(storage),
            deltas: file("deltas.bin")?,
            jsonl: std::io::BufWriter::new(file("world.jsonl")?),
            observed: HashMap::new(),
            records: Vec::new(),
            frame: 0,
            cameras: Vec::new(),
            totals: WorldStats::default(),
        })
    }

    /// The world map.
    pub fn world(&self) -> &WorldMap<'s> {
        &self.world
    }

    /// Integrates one frame's map (`primitives`, camera frame) with its camera-to-world `pose`, adds the frame's
    /// observed points (camera frame) to the union, writes the delta and the `world.jsonl` line.
    pub fn add_frame(
        &mut self,
        index: usize,
        pose: &Pose,
        params: &Params,
        frame_map_bytes: usize,
        primitives: impl FnMut(&mut dyn FnMut(&Primitive<'_>)),
        observed: &[[f32; 3]],
    ) -> Result<()> {
        let stats = self
            .world
            .integrate(self.frame, pose, params, primitives)
            .map_err(|e| anyhow!("frame {index}: world map: {e}"))?;
        self.frame += 1;
        self.cameras.push(pose.translation);
        for p in observed {
            let w = pose.to_world(*p);
            let key = w.map(|x| (x / OBSERVED_GRID_M).floor() as i32);
            self.observed.entry(key).or_insert(w);
        }
        let mut delta = Vec::new();
        let mut scratch = [0u8; 32];
        self.world
            .encode_delta_streaming(&mut scratch, |b| {
                delta.extend_from_slice(b);
                Ok(())
            })
            .map_err(|e| anyhow!("frame {index}: world delta: {e}"))?;
        let path = self.dir.join("deltas.bin");
        self.deltas
            .write_all(&(delta.len() as u32).to_le_bytes())
            .and_then(|()| self.deltas.write_all(&delta))
            .with_context(|| format!("{}: cannot write", path.display()))?;
        let world_bytes = self.encode()?.len();
        let (mut delta_records, mut delta_record_bytes, mut delta_removals) = ([0usize; 3], [0usize; 3], 0usize);
        wire::decode_delta(&delta, |c| match c {
            DeltaChange::Upsert(r) => {
                if let Some(k) = delta_records.get_mut(r.kind as usize) {
                    *k += 1;
                }
                if let Some(k) = delta_record_bytes.get_mut(r.kind as usize) {
                    *k += r.bytes.len();
                }
            }
            DeltaChange::Remove { .. } => delta_removals += 1,
        })
        .map_err(|e| anyhow!("frame {index}: world delta does not decode: {e}"))?;
        let (planes, sqs, gmms) = counts(&self.world);
        let record = WorldFrameRecord {
            index,
            planes,
            sqs,
            gmms,
            total: planes + sqs + gmms,
            world_bytes,
            delta_bytes: delta.len(),
            frame_map_bytes,
            delta_records,
            delta_record_bytes,
            delta_removals,
            merged_planes: stats.planes_merged,
            created_planes: stats.planes_created,
            joined_planes: stats.planes_joined,
            merged_gmms: stats.gmms_merged,
            created_gmms: stats.gmms_created,
            evicted_gmms: stats.gmms_evicted,
            dropped_gmms: stats.gmms_dropped,
            clipped_cells: stats.cells_clipped,
            partial_sqs: stats.objects_partial,
            planes_moved_grown: [stats.planes_moved, stats.planes_grown],
            plane_cells: self
                .world
                .planes()
                .iter()
                .fold([0, 0], |[a, b], p| [a + p.occupied, b + p.pending_len as u32]),
        };
        self.totals.gmms_evicted += stats.gmms_evicted;
        self.totals.gmms_dropped += stats.gmms_dropped;
        self.totals.cells_clipped += stats.cells_clipped;
        self.totals.objects_partial += stats.objects_partial;
        serde_json::to_writer(&mut self.jsonl, &record)?;
        self.jsonl
            .write_all(b"\n")
            .with_context(|| format!("{}: cannot write", self.dir.join("world.jsonl").display()))?;
        self.records.push(record);
        Ok(())
    }

    /// `world.bin` as it is now.
    pub fn encode(&self) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        let mut scratch = [0u8; 32];
        self.world
            .encode_streaming(&mut scratch, |b| {
                out.extend_from_slice(b);
                Ok(())
            })
            .map_err(|e| anyhow!("world map: {e}"))?;
        Ok(out)
    }

    /// Writes `world.bin`, `world.ply` and `world_summary.json`, checks that the delta stream rebuilds
    /// `world.bin`, and measures G2R / R2G; returns the summary.
    pub fn finish(mut self) -> Result<WorldSummary> {
        self.jsonl.flush().with_context(|| format!("{}: cannot write", self.dir.join("world.jsonl").display()))?;
        self.deltas.flush()?;
        let bytes = self.encode()?;
        let bin = self.dir.join("world.bin");
        fs::write(&bin, &bytes).with_context(|| format!("{}: cannot write", bin.display()))?;
        let stream_path = self.dir.join("deltas.bin");
        let stream = fs::read(&stream_path).with_context(|| format!("{}: cannot read", stream_path.display()))?;
        let mut receiver = Receiver::default();
        for (k, d) in split_deltas(&stream).with_context(|| format!("{}", stream_path.display()))?.iter().enumerate() {
            receiver.apply(d).map_err(|e| anyhow!("{}: delta {k}: {e}", stream_path.display()))?;
        }
        let receiver_identical = receiver.world_bytes().map_err(|e| anyhow!("receiver: {e}"))? == bytes;
        let vertices = world_vertices(&self.world);
        crate::export::write_ply(&self.dir.join("world.ply"), &vertices)?;
        let samples: Vec<[f32; 3]> = vertices.iter().map(|v| v.xyz.map(|x| x as f32)).collect();
        let seen = seen_samples(&self.world, &self.cameras);
        let seen_by_kind: [Vec<[f32; 3]>; 3] =
            [0u8, 1, 2].map(|k| seen.iter().filter(|s| s.0 == k).map(|s| s.1).collect());
        let observed: Vec<[f32; 3]> = {
            let mut v: Vec<([i32; 3], [f32; 3])> = self.observed.iter().map(|(k, p)| (*k, *p)).collect();
            v.sort_by_key(|(k, _)| *k);
            v.into_iter().map(|(_, p)| p).collect()
        };
        let (planes, sqs, gmms) = counts(&self.world);
        let n = self.records.len().max(1) as f64;
        let delta_mean = self.records.iter().map(|r| r.delta_bytes as f64).sum::<f64>() / n;
        let frame_mean = self.records.iter().map(|r| r.frame_map_bytes as f64).sum::<f64>() / n;
        let summary = WorldSummary {
            frames: self.records.len(),
            planes,
            sqs,
            gmms,
            total: planes + sqs + gmms,
            world_bytes: bytes.len(),
            delta_bytes_mean: delta_mean,
            frame_map_bytes_mean: frame_mean,
            delta_to_frame_map: if frame_mean > 0.0 { delta_mean / frame_mean } else { 0.0 },
            g2r_rmse_m: crate::eval::rms_nearest(&seen.iter().map(|s| s.1).collect::<Vec<_>>(), &observed),
            r2g_rmse_m: crate::eval::rms_nearest(&observed, &samples),
            g2r_by_kind_m: seen_by_kind.each_ref().map(|own| crate::eval::rms_nearest(own, &observed)),
            g2r_samples_by_kind: seen_by_kind.each_ref().map(Vec::len),
            observed_points: observed.len(),
            world_samples: samples.len(),
            receiver_identical,
            gmms_evicted: self.totals.gmms_evicted,
            gmms_dropped: self.totals.gmms_dropped,
            cells_clipped: self.totals.cells_clipped,
            sqs_partial: self.totals.objects_partial,
        };
        let path = self.dir.join("world_summary.json");
        fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("{}: cannot write", path.display()))?;
        if !receiver_identical {
            return Err(anyhow!("{}: replaying the deltas does not give world.bin", stream_path.display()));
        }
        Ok(summary)
    }
}

/// Planes, superquadrics and Gaussians of a world map.
pub fn counts(world: &WorldMap<'_>) -> (usize, usize, usize) {
    let [p, s, g] = world.primitive_counts();
    (p, s, g)
}

/// The world map's reconstruction samples as PLY vertices (world frame): plane cell centres, every surface
/// sample of a superquadric (no camera decides which side is visible), Gaussian samples; `primitive` is the
/// world id.
pub fn world_vertices(world: &WorldMap<'_>) -> Vec<Vertex> {
    let mut out = Vec::new();
    world.for_each_primitive(|id, p| {
        let (kind, rgb) = match p {
            Primitive::Plane(_) => (0u8, PLANE_COLOUR),
            Primitive::Sq(s) => (1, id_colour(s.track as u32 * 7919 + 1)),
            Primitive::Gmm(_) => (2, GMM_COLOUR),
        };
        p.for_each_surface_sample(|x| {
            out.push(Vertex { xyz: x.map(f64::from), rgb, primitive: id, kind, instance: -1 });
        });
    });
    out
}

/// The world map's samples that G2R scores, with their kind: every sample of a plane or Gaussian, and the
/// surface samples of a superquadric whose outward normal faces at least one of the run's camera centres
/// `cameras` (world frame) — the world-map analogue of SPEC's camera-facing G2R samples.
pub fn seen_samples(world: &WorldMap<'_>, cameras: &[[f32; 3]]) -> Vec<(u8, [f32; 3])> {
    let mut out = Vec::new();
    world.for_each_primitive(|_, p| match p {
        Primitive::Sq(s) => s.for_each_surface_sample(|x| {
            let n = s.sq.normal_at_local(s.sq.local(x));
            let facing = cameras.iter().any(|c| (0..3).map(|k| n[k] * (c[k] - x[k])).sum::<f32>() > 0.0);
            if facing {
                out.push((1, x));
            }
        }),
        Primitive::Plane(_) => p.for_each_sample(|x| out.push((0, x))),
        Primitive::Gmm(_) => p.for_each_sample(|x| out.push((2, x))),
    });
    out
}

/// Reads a `world.bin` and calls `f` with every primitive (world frame); names the file on error.
pub fn read_world(path: &Path, mut f: impl FnMut(u32, &Primitive<'_>)) -> Result<wire::WorldHeader> {
    let bytes = fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    wire::decode_world(&bytes, |r| f(r.id, &r.primitive)).map_err(|e| anyhow!("{}: {e}", path.display()))
}
