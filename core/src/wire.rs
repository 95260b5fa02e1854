//! The compact map wire format: a versioned postcard encoding of a frame map into a caller-provided buffer,
//! and a decoder that validates everything before it hands out a single primitive.
//!
//! Layout: `Header` (magic "M2", version, frame number, primitive counts), then the planes, superquadrics and
//! Gaussians in that order, each a postcard struct, then a CRC-32 (IEEE, little-endian) of all preceding bytes.
//!
//! Quantisation (units and worst-case error):
//! - positions (centroids, centres, means): millimetres, i32 varint — ±0.5 mm;
//! - rotations: the quaternion with w ≥ 0, its x, y, z as i16 / 32767 — ≤ 0.004° (0.13 mm at 2 m);
//! - scales and σ: 0.1 mm units, u16 — ±0.05 mm, up to 6.55 m;
//! - shape exponents: u16 over [0.1, 1.9] — ±0.000014 (box-like surfaces, ε ≈ 0.1, are that sensitive);
//!   scores and support ratios: u8 over [0, 1] — ±0.002;
//! - λ2/λ0: u16 over [0, 1]; g_p: 0.1 mm units; plane cells: their occupied bounding box, as a bitmap, as
//!   run lengths (LEB128 varints, alternately unset and set) or as row edges coded against the row above
//!   ([`crate::cells`]), whichever is shortest (exact).
//!
//! Version 2 added the run-length and edge codings of plane cells (the cabinet's floor is about 90 bytes of
//! edges instead of 180 of runs and 430 of bitmap); version 1 maps are refused with [`WireError::WrongVersion`].

use serde::{Deserialize, Serialize};

use crate::cells::{run_lengths, runs_cover};
use crate::linalg::{self, Mat3, Vec3};
use crate::map::{CellBits, CellCoding, MapGmm, MapPlane, MapSq, Primitive};
use crate::superquadric::{Superquadric, EPS_RANGE, MIN_SCALE};

/// First two bytes of every map.
pub const MAGIC: [u8; 2] = *b"M2";
/// The format version this code writes and reads.
pub const VERSION: u8 = 2;

/// Why a map could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireError {
    /// The output buffer is too small.
    BufferTooSmall,
    /// The input ends before the map does.
    Truncated,
    /// The CRC-32 does not match: corrupted bytes.
    BadChecksum,
    /// Not a map (wrong magic bytes).
    BadMagic,
    /// A map of another format version.
    WrongVersion(u8),
    /// A field could not be parsed.
    Malformed,
    /// A field holds an impossible value; the name says which.
    BadValue(&'static str),
    /// Bytes follow the last primitive.
    TrailingBytes,
    /// More primitives of one kind than the header can count (65 535).
    TooManyPrimitives,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WireError::BufferTooSmall => write!(f, "output buffer too small"),
            WireError::Truncated => write!(f, "map is truncated"),
            WireError::BadChecksum => write!(f, "map checksum mismatch"),
            WireError::BadMagic => write!(f, "not an m2smap map"),
            WireError::WrongVersion(v) => write!(f, "map format version {v}, this reader knows {VERSION}"),
            WireError::Malformed => write!(f, "malformed map field"),
            WireError::BadValue(name) => write!(f, "map field `{name}` out of range"),
            WireError::TrailingBytes => write!(f, "bytes after the last primitive"),
            WireError::TooManyPrimitives => write!(f, "more than 65535 primitives of one kind"),
        }
    }
}

/// The map header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// [`MAGIC`].
    pub magic: [u8; 2],
    /// [`VERSION`].
    pub version: u8,
    /// Frame number.
    pub frame: u32,
    /// Planes that follow.
    pub planes: u16,
    /// Superquadrics that follow.
    pub sqs: u16,
    /// Gaussians that follow.
    pub gmms: u16,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct WirePlane<'a> {
    centroid: [i32; 3],
    rotation: [u8; 6],
    sigmas: [u16; 3],
    ratio: u16,
    colour: [u8; 3],
    cluster: u16,
    g_p: u16,
    a0: i16,
    b0: i16,
    width: u16,
    height: u16,
    /// 0: bitmap, 1: runs, 2: edges ([`CellCoding`]).
    coding: u8,
    #[serde(borrow)]
    bits: &'a [u8],
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct WireSq {
    centre: [i32; 3],
    rotation: [u8; 6],
    scales: [u16; 3],
    eps: [u16; 2],
    instance: u16,
    class: u16,
    score: u8,
    track: u16,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct WireGmm {
    mean: [i32; 3],
    rotation: [u8; 6],
    sigmas: [u16; 3],
    count: u32,
    colour: [u8; 3],
    instance: u16,
    class: u16,
    score: u8,
    ratio: u8,
}

/// CRC-32 (IEEE 802.3, reflected, init and final xor 0xFFFFFFFF), bitwise.
pub fn crc32(bytes: &[u8]) -> u32 {
    !crc32_update(0xFFFF_FFFF, bytes)
}

/// Feeds `bytes` into a running CRC-32 register (start at 0xFFFFFFFF, finish with `!`).
pub fn crc32_update(mut crc: u32, bytes: &[u8]) -> u32 {
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            let mask = (crc & 1).wrapping_neg();
            crc = (crc >> 1) ^ (0xEDB8_8320 & mask);
        }
    }
    crc
}

/// Largest encoded primitive, bytes (a plane with a full occupancy bitmap), the scratch a streaming encode needs.
pub const MAX_PRIMITIVE_BYTES: usize = MAX_PLANE_BITS + 96;

fn mm(x: f32) -> i32 {
    libm::roundf((x * 1000.0).clamp(-2.0e9, 2.0e9)) as i32
}

fn from_mm(v: [i32; 3]) -> Vec3 {
    [v[0] as f32 / 1000.0, v[1] as f32 / 1000.0, v[2] as f32 / 1000.0]
}

fn tenth_mm(x: f32) -> u16 {
    libm::roundf((x * 10_000.0).clamp(0.0, 65_535.0)) as u16
}

fn from_tenth_mm(v: [u16; 3]) -> Vec3 {
    [v[0] as f32 / 10_000.0, v[1] as f32 / 10_000.0, v[2] as f32 / 10_000.0]
}

fn unit_u8(x: f32) -> u8 {
    libm::roundf(x.clamp(0.0, 1.0) * 255.0) as u8
}

fn quantise_rotation(r: &Mat3) -> [u8; 6] {
    let q = linalg::quat_from_matrix(r);
    let mut out = [0u8; 6];
    for (chunk, c) in out.chunks_exact_mut(2).zip(q) {
        let v = libm::roundf(c.clamp(-1.0, 1.0) * 32767.0) as i16;
        chunk.copy_from_slice(&v.to_le_bytes());
    }
    out
}

fn rotation_of(bytes: [u8; 6]) -> Result<Mat3, WireError> {
    let [x0, x1, y0, y1, z0, z1] = bytes;
    let c = |lo: u8, hi: u8| i16::from_le_bytes([lo, hi]) as f32 / 32767.0;
    let (x, y, z) = (c(x0, x1), c(y0, y1), c(z0, z1));
    let s = x * x + y * y + z * z;
    if s > 1.0 + 1e-3 {
        return Err(WireError::BadValue("rotation"));
    }
    Ok(linalg::matrix_from_quat([x, y, z, linalg::sqrt((1.0 - s).max(0.0))]))
}

/// Writes the map of frame `frame` into `buf`: `primitives` is called with a sink and must feed it every
/// primitive (it is called four times: to count, then once per kind). Returns the bytes written.
pub fn encode(
    buf: &mut [u8],
    frame: u32,
    primitives: impl FnMut(&mut dyn FnMut(&Primitive<'_>)),
) -> Result<usize, WireError> {
    let mut scratch = [0u8; MAX_PRIMITIVE_BYTES];
    let mut used = 0usize;
    encode_streaming(frame, primitives, &mut scratch, |bytes| {
        let end = used + bytes.len();
        buf.get_mut(used..end).ok_or(WireError::BufferTooSmall)?.copy_from_slice(bytes);
        used = end;
        Ok(())
    })
}

/// Encodes the map of frame `frame` piece by piece through `out` (a radio link, a digest), with only
/// `scratch` (at least [`MAX_PRIMITIVE_BYTES`]) as buffer. Returns the bytes produced.
pub fn encode_streaming(
    frame: u32,
    mut primitives: impl FnMut(&mut dyn FnMut(&Primitive<'_>)),
    scratch: &mut [u8],
    out: impl FnMut(&[u8]) -> Result<(), WireError>,
) -> Result<usize, WireError> {
    let (mut planes, mut sqs, mut gmms) = (0usize, 0usize, 0usize);
    primitives(&mut |p| match p {
        Primitive::Plane(_) => planes += 1,
        Primitive::Sq(_) => sqs += 1,
        Primitive::Gmm(_) => gmms += 1,
    });
    let count = |n: usize| u16::try_from(n).map_err(|_| WireError::TooManyPrimitives);
    let header =
        Header { magic: MAGIC, version: VERSION, frame, planes: count(planes)?, sqs: count(sqs)?, gmms: count(gmms)? };
    let mut emitter = Emitter::new(out);
    emitter.emit(postcard::to_slice(&header, scratch).map_err(|_| WireError::BufferTooSmall)?)?;
    // Written in kind order: planes, then superquadrics, then Gaussians.
    for kind in 0..3 {
        let mut result = Ok(());
        primitives(&mut |p| {
            if result.is_err() {
                return;
            }
            let written = match (kind, p) {
                (0, Primitive::Plane(pl)) => write_plane::<MAX_PLANE_BITS>(pl, scratch),
                (1, Primitive::Sq(s)) => write_sq(s, scratch),
                (2, Primitive::Gmm(g)) => write_gmm(g, scratch),
                _ => Ok(0),
            };
            result = written.and_then(|n| emitter.emit(scratch.get(..n).unwrap_or(&[])));
        });
        result?;
    }
    emitter.finish()
}

/// Writes a plane whose occupied box holds at most `BITS × 8` cells (a frame plane: [`MAX_PLANE_BITS`]; a
/// world plane: [`MAX_WORLD_PLANE_BITS`]).
fn write_plane<const BITS: usize>(p: &MapPlane<'_>, out: &mut [u8]) -> Result<usize, WireError> {
    // Crop the cells to their occupied box and code them both ways: a bitmap row by row, and run lengths
    // (given up once they are as long as the bitmap); the shorter goes on the wire.
    let mut bits = [0u8; BITS];
    let mut runs = [0u8; BITS];
    let (a0, b0, width, height) = match p.cells.occupied_box() {
        Some((i0, j0, i1, j1)) => {
            let (w, h) = (i1 - i0 + 1, j1 - j0 + 1);
            if w * h > BITS * 8 {
                return Err(WireError::BadValue("plane cells"));
            }
            p.cells.for_each_set(|i, j| {
                if (i0..=i1).contains(&i) && (j0..=j1).contains(&j) {
                    crate::cells::set_bit(&mut bits, (j - j0) * w + (i - i0));
                }
            });
            (p.cells.a0 + i0 as i16, p.cells.b0 + j0 as i16, w as u16, h as u16)
        }
        None => (0, 0, 0, 0),
    };
    let cells = width as usize * height as usize;
    let n_bytes = cells.div_ceil(8);
    let bitmap = bits.get(..n_bytes).unwrap_or(&[]);
    let n_runs = run_lengths(bitmap, cells, runs.get_mut(..n_bytes).unwrap_or(&mut []));
    let mut edges = [0u8; BITS];
    let limit = n_runs.unwrap_or(n_bytes).min(n_bytes);
    let n_edges =
        crate::cells::encode_edges(bitmap, width as usize, height as usize, edges.get_mut(..limit).unwrap_or(&mut []));
    let (coding, coded) = match (n_edges, n_runs) {
        (Some(n), _) if n < limit => (2, edges.get(..n).unwrap_or(&[])),
        (_, Some(n)) if n < n_bytes => (1, runs.get(..n).unwrap_or(&[])),
        _ => (0, bitmap),
    };
    let wire = WirePlane {
        centroid: p.centroid.map(mm),
        rotation: quantise_rotation(&p.rotation),
        sigmas: p.sigmas.map(tenth_mm),
        ratio: libm::roundf(p.eigen_ratio.clamp(0.0, 1.0) * 65535.0) as u16,
        colour: p.colour,
        cluster: p.cluster,
        g_p: tenth_mm(p.g_p),
        a0,
        b0,
        width,
        height,
        coding,
        bits: coded,
    };
    postcard::to_slice(&wire, out).map(|s| s.len()).map_err(|_| WireError::BufferTooSmall)
}

fn write_sq(s: &MapSq, out: &mut [u8]) -> Result<usize, WireError> {
    let eps = |e: f32| libm::roundf(((e - EPS_RANGE.0) / (EPS_RANGE.1 - EPS_RANGE.0)).clamp(0.0, 1.0) * 65535.0) as u16;
    let wire = WireSq {
        centre: s.sq.centre.map(mm),
        rotation: quantise_rotation(&s.sq.rotation),
        scales: s.sq.scales.map(tenth_mm),
        eps: [eps(s.sq.eps[0]), eps(s.sq.eps[1])],
        instance: s.instance,
        class: s.class,
        score: unit_u8(s.score),
        track: s.track,
    };
    postcard::to_slice(&wire, out).map(|s| s.len()).map_err(|_| WireError::BufferTooSmall)
}

fn write_gmm(g: &MapGmm, out: &mut [u8]) -> Result<usize, WireError> {
    let wire = WireGmm {
        mean: g.mean.map(mm),
        rotation: quantise_rotation(&g.rotation),
        sigmas: g.sigmas.map(tenth_mm),
        count: g.count,
        colour: g.colour,
        instance: g.instance,
        class: g.class,
        score: unit_u8(g.score),
        ratio: unit_u8(g.support_ratio),
    };
    postcard::to_slice(&wire, out).map(|s| s.len()).map_err(|_| WireError::BufferTooSmall)
}

/// Largest cropped plane bitmap, bytes (the whole 80 × 80 grid).
pub const MAX_PLANE_BITS: usize = crate::plane::PLANE_GRID_BYTES;
/// Most cells of a plane on the wire (the whole grid).
pub const MAX_PLANE_CELLS: usize = MAX_PLANE_BITS * 8;

fn take<'a, T: Deserialize<'a>>(bytes: &'a [u8]) -> Result<(T, &'a [u8]), WireError> {
    postcard::take_from_bytes(bytes).map_err(|e| match e {
        postcard::Error::DeserializeUnexpectedEnd => WireError::Truncated,
        _ => WireError::Malformed,
    })
}

/// A decoded plane whose occupied box holds at most `max_cells` cells.
fn plane_of(w: WirePlane<'_>, max_cells: usize) -> Result<MapPlane<'_>, WireError> {
    let cells = w.width as usize * w.height as usize;
    // The box bound comes first: it also bounds the work of checking the coded cells.
    if cells > max_cells {
        return Err(WireError::BadValue("plane cells"));
    }
    let coding = match w.coding {
        0 if w.bits.len() == cells.div_ceil(8) => CellCoding::Bitmap,
        1 if runs_cover(w.bits, cells) => CellCoding::Runs,
        2 if crate::cells::edges_cover(w.bits, w.width as usize, w.height as usize) => CellCoding::Edges,
        _ => return Err(WireError::BadValue("plane cells")),
    };
    if w.g_p == 0 {
        return Err(WireError::BadValue("g_p"));
    }
    Ok(MapPlane {
        centroid: from_mm(w.centroid),
        rotation: rotation_of(w.rotation)?,
        sigmas: from_tenth_mm(w.sigmas),
        eigen_ratio: w.ratio as f32 / 65535.0,
        colour: w.colour,
        cluster: w.cluster,
        g_p: w.g_p as f32 / 10_000.0,
        cells: CellBits { a0: w.a0, b0: w.b0, width: w.width, height: w.height, coding, bits: w.bits },
    })
}

fn sq_of(w: WireSq) -> Result<MapSq, WireError> {
    let scales = from_tenth_mm(w.scales);
    if scales.iter().any(|&a| a < MIN_SCALE - 1e-4) {
        return Err(WireError::BadValue("sq scales"));
    }
    let eps = |e: u16| EPS_RANGE.0 + (EPS_RANGE.1 - EPS_RANGE.0) * e as f32 / 65535.0;
    Ok(MapSq {
        sq: Superquadric {
            scales,
            eps: [eps(w.eps[0]), eps(w.eps[1])],
            centre: from_mm(w.centre),
            rotation: rotation_of(w.rotation)?,
        },
        instance: w.instance,
        class: w.class,
        score: w.score as f32 / 255.0,
        track: w.track,
        partial: false,
    })
}

fn gmm_of(w: WireGmm) -> Result<MapGmm, WireError> {
    if w.count == 0 {
        return Err(WireError::BadValue("gmm count"));
    }
    Ok(MapGmm {
        mean: from_mm(w.mean),
        rotation: rotation_of(w.rotation)?,
        sigmas: from_tenth_mm(w.sigmas),
        count: w.count,
        colour: w.colour,
        instance: w.instance,
        class: w.class,
        score: w.score as f32 / 255.0,
        support_ratio: w.ratio as f32 / 255.0,
    })
}

/// The bytes before a trailing little-endian CRC-32, once the CRC matches them (maps and snapshots).
pub fn checked_body(bytes: &[u8]) -> Result<&[u8], WireError> {
    let n = bytes.len();
    if n < 4 {
        return Err(WireError::Truncated);
    }
    let (body, tail) = bytes.split_at(n - 4);
    let stored = match tail {
        [a, b, c, d] => u32::from_le_bytes([*a, *b, *c, *d]),
        _ => return Err(WireError::Truncated),
    };
    if crc32(body) != stored {
        return Err(WireError::BadChecksum);
    }
    Ok(body)
}

/// One pass over a map's primitives (`f` = `None` validates only).
fn walk<'a>(body: &'a [u8], mut f: Option<&mut dyn FnMut(Primitive<'a>)>) -> Result<Header, WireError> {
    let (header, mut rest): (Header, _) = take(body)?;
    if header.magic != MAGIC {
        return Err(WireError::BadMagic);
    }
    if header.version != VERSION {
        return Err(WireError::WrongVersion(header.version));
    }
    for _ in 0..header.planes {
        let (w, r): (WirePlane<'a>, _) = take(rest)?;
        rest = r;
        let p = plane_of(w, MAX_PLANE_CELLS)?;
        if let Some(f) = f.as_mut() {
            f(Primitive::Plane(p));
        }
    }
    for _ in 0..header.sqs {
        let (w, r): (WireSq, _) = take(rest)?;
        rest = r;
        let s = sq_of(w)?;
        if let Some(f) = f.as_mut() {
            f(Primitive::Sq(s));
        }
    }
    for _ in 0..header.gmms {
        let (w, r): (WireGmm, _) = take(rest)?;
        rest = r;
        let g = gmm_of(w)?;
        if let Some(f) = f.as_mut() {
            f(Primitive::Gmm(g));
        }
    }
    if !rest.is_empty() {
        return Err(WireError::TrailingBytes);
    }
    Ok(header)
}

/// Validates a whole map (checksum, header, every primitive, no trailing bytes) and only then calls `f` for
/// each primitive in order. A map that fails anywhere yields its error and no primitive.
pub fn decode<'a>(bytes: &'a [u8], mut f: impl FnMut(Primitive<'a>)) -> Result<Header, WireError> {
    let body = checked_body(bytes)?;
    walk(body, None)?;
    walk(body, Some(&mut f))
}

// ---------------------------------------------------------------------------------------------------------------
// World maps and their delta stream.
//
// A world record is one world primitive with its stable id: `kind` (u8: 0 plane, 1 superquadric, 2 Gaussian),
// `id` (u32 varint), then the primitive's postcard struct as in a frame map (a world plane's occupied box may
// hold up to [`MAX_WORLD_PLANE_CELLS`] cells). A world map (`world.bin`) is a [`WorldHeader`], its records in
// (kind, id) order, and a CRC-32. A delta is a [`DeltaHeader`], the records created or changed since the last
// delta (same order), the (kind, id) pairs removed, and a CRC-32. Applying every delta in order to an empty
// record set and writing the set out with [`encode_world_records`] gives the sender's `world.bin` byte for byte,
// because a record's bytes are the same wherever they appear.

/// First two bytes of a world map.
pub const WORLD_MAGIC: [u8; 2] = *b"MW";
/// First two bytes of a world-map delta.
pub const DELTA_MAGIC: [u8; 2] = *b"MD";
/// The world-map and delta format version this code writes and reads.
pub const WORLD_VERSION: u8 = 1;
/// Largest cropped world-plane bitmap, bytes (a 128 × 128-cell world grid).
pub const MAX_WORLD_PLANE_BITS: usize = crate::world::WORLD_GRID_BYTES;
/// Most cells of a world plane on the wire.
pub const MAX_WORLD_PLANE_CELLS: usize = MAX_WORLD_PLANE_BITS * 8;
/// Largest world record, bytes: the scratch a world or delta encode needs.
pub const MAX_WORLD_RECORD_BYTES: usize = MAX_WORLD_PLANE_BITS + 112;

/// The header of a world map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct WorldHeader {
    /// [`WORLD_MAGIC`].
    pub magic: [u8; 2],
    /// [`WORLD_VERSION`].
    pub version: u8,
    /// The last frame integrated.
    pub frame: u32,
    /// Records that follow.
    pub records: u32,
}

/// The header of a world-map delta.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeltaHeader {
    /// [`DELTA_MAGIC`].
    pub magic: [u8; 2],
    /// [`WORLD_VERSION`].
    pub version: u8,
    /// The frame whose integration this delta carries.
    pub frame: u32,
    /// Records created or changed.
    pub upserts: u32,
    /// (kind, id) pairs removed.
    pub removals: u32,
}

/// Kind byte of a world record holding a plane.
pub const KIND_PLANE: u8 = 0;
/// Kind byte of a world record holding a superquadric.
pub const KIND_SQ: u8 = 1;
/// Kind byte of a world record holding a Gaussian.
pub const KIND_GMM: u8 = 2;

/// The kind byte of a primitive.
pub fn kind_of(p: &Primitive<'_>) -> u8 {
    match p {
        Primitive::Plane(_) => KIND_PLANE,
        Primitive::Sq(_) => KIND_SQ,
        Primitive::Gmm(_) => KIND_GMM,
    }
}

/// Writes the world record of primitive `p` with id `id` into `out`; returns the bytes written.
pub fn write_world_record(id: u32, p: &Primitive<'_>, out: &mut [u8]) -> Result<usize, WireError> {
    let head = postcard::to_slice(&(kind_of(p), id), out).map_err(|_| WireError::BufferTooSmall)?.len();
    let rest = out.get_mut(head..).ok_or(WireError::BufferTooSmall)?;
    let body = match p {
        Primitive::Plane(pl) => write_plane::<MAX_WORLD_PLANE_BITS>(pl, rest),
        Primitive::Sq(s) => write_sq(s, rest),
        Primitive::Gmm(g) => write_gmm(g, rest),
    }?;
    Ok(head + body)
}

/// One decoded world record: its kind, id, bytes (exactly as on the wire) and primitive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldRecord<'a> {
    /// [`KIND_PLANE`], [`KIND_SQ`] or [`KIND_GMM`].
    pub kind: u8,
    /// World id, unique over the world map's lifetime.
    pub id: u32,
    /// The record's bytes.
    pub bytes: &'a [u8],
    /// The primitive (world frame).
    pub primitive: Primitive<'a>,
}

/// Parses one world record from the front of `bytes`; returns it and the rest.
fn take_world_record(bytes: &[u8]) -> Result<(WorldRecord<'_>, &[u8]), WireError> {
    let ((kind, id), rest): ((u8, u32), _) = take(bytes)?;
    let (primitive, rest) = match kind {
        KIND_PLANE => {
            let (w, r): (WirePlane<'_>, _) = take(rest)?;
            (Primitive::Plane(plane_of(w, MAX_WORLD_PLANE_CELLS)?), r)
        }
        KIND_SQ => {
            let (w, r): (WireSq, _) = take(rest)?;
            (Primitive::Sq(sq_of(w)?), r)
        }
        KIND_GMM => {
            let (w, r): (WireGmm, _) = take(rest)?;
            (Primitive::Gmm(gmm_of(w)?), r)
        }
        _ => return Err(WireError::BadValue("record kind")),
    };
    let used = bytes.len() - rest.len();
    Ok((WorldRecord { kind, id, bytes: bytes.get(..used).unwrap_or(&[]), primitive }, rest))
}

/// CRC-32 running sum and byte count of a stream being written.
struct Emitter<F: FnMut(&[u8]) -> Result<(), WireError>> {
    crc: u32,
    total: usize,
    out: F,
}

impl<F: FnMut(&[u8]) -> Result<(), WireError>> Emitter<F> {
    fn new(out: F) -> Self {
        Emitter { crc: 0xFFFF_FFFF, total: 0, out }
    }

    fn emit(&mut self, bytes: &[u8]) -> Result<(), WireError> {
        self.crc = crc32_update(self.crc, bytes);
        self.total += bytes.len();
        (self.out)(bytes)
    }

    /// Writes the CRC-32 of everything emitted; returns the bytes of the whole stream.
    fn finish(mut self) -> Result<usize, WireError> {
        let crc = !self.crc;
        self.emit(&crc.to_le_bytes())?;
        Ok(self.total)
    }
}

/// Ordered (kind, id) check of a record stream: records must come in strictly increasing (kind, id) order.
fn in_order(previous: &mut Option<(u8, u32)>, kind: u8, id: u32) -> Result<(), WireError> {
    if previous.is_some_and(|p| p >= (kind, id)) {
        return Err(WireError::BadValue("record order"));
    }
    *previous = Some((kind, id));
    Ok(())
}

/// Writes a world map of frame `frame` through `out` from its records: `records` is called twice (to count,
/// then to write) and must feed `(kind, id, record bytes)` in strictly increasing (kind, id) order, the same
/// both times. The sender ([`crate::world::WorldMap::encode_streaming`]) and a receiver that holds the records
/// of a delta stream both write their map with this function, which is what makes them byte-identical.
pub fn encode_world_records(
    frame: u32,
    mut records: impl FnMut(&mut dyn FnMut(u8, u32, &[u8]) -> Result<(), WireError>) -> Result<(), WireError>,
    scratch: &mut [u8],
    out: impl FnMut(&[u8]) -> Result<(), WireError>,
) -> Result<usize, WireError> {
    let mut n = 0u32;
    let mut order = None;
    records(&mut |kind, id, _| {
        in_order(&mut order, kind, id)?;
        n = n.checked_add(1).ok_or(WireError::TooManyPrimitives)?;
        Ok(())
    })?;
    let header = WorldHeader { magic: WORLD_MAGIC, version: WORLD_VERSION, frame, records: n };
    let mut emitter = Emitter::new(out);
    emitter.emit(postcard::to_slice(&header, scratch).map_err(|_| WireError::BufferTooSmall)?)?;
    let mut written = 0u32;
    records(&mut |_, _, bytes| {
        written += 1;
        emitter.emit(bytes)
    })?;
    if written != n {
        return Err(WireError::BadValue("records changed between passes"));
    }
    emitter.finish()
}

/// Writes a delta of frame `frame` through `out`: `upserts` feeds `(kind, id, record bytes)` of the records
/// created or changed, in strictly increasing (kind, id) order, `removals` the (kind, id) pairs removed; both
/// are called twice (count, write).
pub fn encode_delta_records(
    frame: u32,
    mut upserts: impl FnMut(&mut dyn FnMut(u8, u32, &[u8]) -> Result<(), WireError>) -> Result<(), WireError>,
    mut removals: impl FnMut(&mut dyn FnMut(u8, u32) -> Result<(), WireError>) -> Result<(), WireError>,
    scratch: &mut [u8],
    out: impl FnMut(&[u8]) -> Result<(), WireError>,
) -> Result<usize, WireError> {
    let (mut n_up, mut n_rm) = (0u32, 0u32);
    let mut order = None;
    upserts(&mut |kind, id, _| {
        in_order(&mut order, kind, id)?;
        n_up = n_up.checked_add(1).ok_or(WireError::TooManyPrimitives)?;
        Ok(())
    })?;
    removals(&mut |_, _| {
        n_rm = n_rm.checked_add(1).ok_or(WireError::TooManyPrimitives)?;
        Ok(())
    })?;
    let header = DeltaHeader { magic: DELTA_MAGIC, version: WORLD_VERSION, frame, upserts: n_up, removals: n_rm };
    let mut emitter = Emitter::new(out);
    emitter.emit(postcard::to_slice(&header, scratch).map_err(|_| WireError::BufferTooSmall)?)?;
    upserts(&mut |_, _, bytes| emitter.emit(bytes))?;
    removals(&mut |kind, id| {
        let mut pair = [0u8; 8];
        let bytes = postcard::to_slice(&(kind, id), &mut pair).map_err(|_| WireError::BufferTooSmall)?;
        emitter.emit(bytes)
    })?;
    emitter.finish()
}

/// Validates a whole world map (checksum, header, every record, their order, no trailing bytes) and only then
/// calls `f` for each record in order.
pub fn decode_world<'a>(bytes: &'a [u8], mut f: impl FnMut(WorldRecord<'a>)) -> Result<WorldHeader, WireError> {
    let body = checked_body(bytes)?;
    let (header, records): (WorldHeader, _) = take(body)?;
    if header.magic != WORLD_MAGIC {
        return Err(WireError::BadMagic);
    }
    if header.version != WORLD_VERSION {
        return Err(WireError::WrongVersion(header.version));
    }
    for pass in 0..2 {
        let (mut rest, mut order) = (records, None);
        for _ in 0..header.records {
            let (r, tail) = take_world_record(rest)?;
            in_order(&mut order, r.kind, r.id)?;
            rest = tail;
            if pass == 1 {
                f(r);
            }
        }
        if !rest.is_empty() {
            return Err(WireError::TrailingBytes);
        }
    }
    Ok(header)
}

/// One change a delta carries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DeltaChange<'a> {
    /// A record created or changed: the receiver stores its bytes under (kind, id).
    Upsert(WorldRecord<'a>),
    /// The record (kind, id) was removed.
    Remove {
        /// Kind byte.
        kind: u8,
        /// World id.
        id: u32,
    },
}

/// Validates a whole delta (checksum, header, every record and removal, no trailing bytes) and only then calls
/// `f` for each change: the upserts in order, then the removals.
pub fn decode_delta<'a>(bytes: &'a [u8], mut f: impl FnMut(DeltaChange<'a>)) -> Result<DeltaHeader, WireError> {
    let body = checked_body(bytes)?;
    let (header, changes): (DeltaHeader, _) = take(body)?;
    if header.magic != DELTA_MAGIC {
        return Err(WireError::BadMagic);
    }
    if header.version != WORLD_VERSION {
        return Err(WireError::WrongVersion(header.version));
    }
    for pass in 0..2 {
        let (mut rest, mut order) = (changes, None);
        for _ in 0..header.upserts {
            let (r, tail) = take_world_record(rest)?;
            in_order(&mut order, r.kind, r.id)?;
            rest = tail;
            if pass == 1 {
                f(DeltaChange::Upsert(r));
            }
        }
        for _ in 0..header.removals {
            let ((kind, id), tail): ((u8, u32), _) = take(rest)?;
            if kind > KIND_GMM {
                return Err(WireError::BadValue("record kind"));
            }
            rest = tail;
            if pass == 1 {
                f(DeltaChange::Remove { kind, id });
            }
        }
        if !rest.is_empty() {
            return Err(WireError::TrailingBytes);
        }
    }
    Ok(header)
}
