//! PLY export of a frame's reconstructed map: the reconstruction samples of every primitive (docs/metrics.md) with
//! `x y z` (metres; camera frame, or world frame with `--world` when the dataset has poses), `red green blue`,
//! `primitive` (unique per primitive within the frame), `kind` (0 plane, 1 superquadric, 2 Gaussian) and
//! `instance` (−1 when none). ASCII PLY, which CloudCompare, MeshLab and Open3D read.

use std::fmt::Write as _;
use std::fs;
use std::path::Path;

use anyhow::{Context, Result};
use m2smap_core::map::Primitive;
use m2smap_core::Mapper;

use crate::dataset::Pose;
use crate::render::{id_colour, GMM_COLOUR, PLANE_COLOUR};

/// One exported vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    /// Position, metres.
    pub xyz: [f64; 3],
    /// Colour.
    pub rgb: [u8; 3],
    /// Primitive index within the frame.
    pub primitive: u32,
    /// 0 plane, 1 superquadric, 2 Gaussian.
    pub kind: u8,
    /// Instance id, −1 for none.
    pub instance: i32,
}

/// The vertices of the mapper's last map, optionally moved into the world frame by `pose`.
pub fn vertices(mapper: &Mapper<'_>, pose: Option<&Pose>) -> Vec<Vertex> {
    let mut out = Vec::new();
    let mut index = 0u32;
    mapper.for_each_primitive(|p| {
        let (kind, instance, rgb) = match p {
            Primitive::Plane(pl) => (0u8, -1, PLANE_COLOUR.map(|c| c.saturating_add((pl.cluster % 4) as u8 * 10))),
            Primitive::Sq(s) => (1, s.instance as i32, id_colour(s.instance as u32 * 7919)),
            Primitive::Gmm(g) if g.instance != 0 => (2, g.instance as i32, id_colour(g.instance as u32 * 7919)),
            Primitive::Gmm(_) => (2, -1, GMM_COLOUR),
        };
        p.for_each_sample(|x| {
            let c = x.map(f64::from);
            let xyz = pose.map_or(c, |q| q.apply(c));
            out.push(Vertex { xyz, rgb, primitive: index, kind, instance });
        });
        index += 1;
    });
    out
}

/// Writes `vertices` as an ASCII PLY file.
pub fn write_ply(path: &Path, vertices: &[Vertex]) -> Result<()> {
    let mut s = String::with_capacity(64 * vertices.len() + 256);
    s.push_str("ply\nformat ascii 1.0\ncomment m2smap map reconstruction samples\n");
    writeln!(s, "element vertex {}", vertices.len())?;
    for prop in [
        "float x",
        "float y",
        "float z",
        "uchar red",
        "uchar green",
        "uchar blue",
        "uint primitive",
        "uchar kind",
        "int instance",
    ] {
        writeln!(s, "property {prop}")?;
    }
    s.push_str("end_header\n");
    for v in vertices {
        writeln!(
            s,
            "{:.5} {:.5} {:.5} {} {} {} {} {} {}",
            v.xyz[0], v.xyz[1], v.xyz[2], v.rgb[0], v.rgb[1], v.rgb[2], v.primitive, v.kind, v.instance
        )?;
    }
    fs::write(path, s).with_context(|| format!("{}: cannot write", path.display()))
}

/// Reads back the vertex count and vertex lines of an ASCII PLY written by [`write_ply`].
pub fn read_ply_vertices(path: &Path) -> Result<Vec<Vertex>> {
    let text = fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let (header, body) =
        text.split_once("end_header\n").with_context(|| format!("{}: no PLY header", path.display()))?;
    let count: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex ").and_then(|n| n.trim().parse().ok()))
        .with_context(|| format!("{}: no vertex count", path.display()))?;
    let mut out = Vec::with_capacity(count);
    for line in body.lines().take(count) {
        let f: Vec<&str> = line.split_whitespace().collect();
        let num = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok()).context("malformed vertex");
        out.push(Vertex {
            xyz: [num(0)?, num(1)?, num(2)?],
            rgb: [num(3)? as u8, num(4)? as u8, num(5)? as u8],
            primitive: num(6)? as u32,
            kind: num(7)? as u8,
            instance: num(8)? as i32,
        });
    }
    anyhow::ensure!(out.len() == count, "{}: {} vertices, header says {count}", path.display(), out.len());
    Ok(out)
}
