//! Evaluation metrics of docs/metrics.md computed from a processed frame (the semantic fusion metrics N_adh and A_s,
//! G2R and R2G), and map-level metrics beside them that judge each variant's own map from all the surface
//! samples of its primitives ([`MapSamples`]): free-space violation, superquadrics behind the support, map-level
//! adhesion and, on synthetic sets, the distance to and the penetration of the true surfaces.

use std::collections::HashMap;

use m2smap_core::map::Primitive;
use m2smap_core::mapper::CheckedFrame;
use m2smap_core::supervoxel::is_assigned;
use m2smap_core::{Frame, Mapper, Params};

use crate::dataset::Pose;
use crate::masks::FrameMasks;
use crate::synth::Surface;

/// Semantic fusion metrics of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SemanticMetrics {
    /// Adhesion cases N_adh: fused clusters in which two reference labels each hold ≥ max(20 points, 10 % of the
    /// cluster's support) and at least one of them is an object.
    pub n_adh: u32,
    /// A_s: among fused clusters of ≥ 2 Gaussians, the fraction whose Gaussians share one dominant reference
    /// label; `None` when there is no such cluster.
    pub a_s: Option<f64>,
    /// Fused clusters of ≥ 2 Gaussians.
    pub multi_gaussian_clusters: u32,
}

/// The label holding the most points (ties: the smaller label).
fn dominant(counts: &HashMap<u16, u32>) -> u16 {
    counts.iter().max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0))).map_or(0, |(&l, _)| l)
}

/// N_adh and A_s of the last frame; `reference(u, v)` is the reference label of a pixel (ground-truth instance
/// image when the dataset has one, else the input mask id; 0 = no object).
pub fn semantic_metrics(
    mapper: &Mapper<'_>,
    checked: &CheckedFrame<'_>,
    reference: impl Fn(u16, u16) -> u16,
) -> SemanticMetrics {
    let gaussians = mapper.gaussians();
    let mut per_gaussian: Vec<HashMap<u16, u32>> = vec![HashMap::new(); gaussians.len()];
    mapper.for_each_labelled_point(checked, |p, v| {
        if let Some(v) = v.filter(|v| is_assigned(v.gaussian)) {
            *per_gaussian[v.gaussian as usize].entry(reference(p.u, p.v)).or_insert(0) += 1;
        }
    });
    fusion_metrics(gaussians.iter().map(|g| g.cluster).zip(&per_gaussian))
}

/// The counting behind [`semantic_metrics`]: N_adh and A_s from, per Gaussian, its fused cluster and its points
/// per reference label (0 = no object).
pub fn fusion_metrics<'a>(gaussians: impl IntoIterator<Item = (u16, &'a HashMap<u16, u32>)>) -> SemanticMetrics {
    let mut clusters: HashMap<u16, (HashMap<u16, u32>, Vec<u16>)> = HashMap::new();
    for (cluster, counts) in gaussians {
        let entry = clusters.entry(cluster).or_default();
        for (&l, &c) in counts {
            *entry.0.entry(l).or_insert(0) += c;
        }
        entry.1.push(dominant(counts));
    }
    let mut m = SemanticMetrics::default();
    let mut consistent = 0u32;
    for (counts, dominants) in clusters.values() {
        let support: u32 = counts.values().sum();
        let threshold = 20u32.max((support as f64 * 0.1).ceil() as u32);
        let strong: Vec<u16> = counts.iter().filter(|(_, &c)| c >= threshold).map(|(&l, _)| l).collect();
        if strong.len() >= 2 && strong.iter().any(|&l| l != 0) {
            m.n_adh += 1;
        }
        if dominants.len() >= 2 {
            m.multi_gaussian_clusters += 1;
            if dominants.iter().all(|&d| d == dominants[0]) {
                consistent += 1;
            }
        }
    }
    m.a_s = (m.multi_gaussian_clusters > 0).then(|| consistent as f64 / m.multi_gaussian_clusters as f64);
    m
}

/// How far behind the measured depth of its pixel a reconstruction sample must lie to count as hidden, metres.
pub const OCCLUSION_MARGIN_M: f64 = 0.05;

/// Reconstruction accuracy of one frame's map (docs/metrics.md), metres.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReconstructionMetrics {
    /// G2R RMSE: √mean over the reconstructed samples P̂ of the squared distance to the nearest observed point.
    pub g2r_rmse_m: f64,
    /// R2G RMSE: √mean over the observed points P of the squared distance to the nearest reconstructed sample.
    pub r2g_rmse_m: f64,
    /// Diagnostic beside the paper's metrics (docs/metrics.md): G2R over the samples that the observed depth does not
    /// hide, i.e. without those lying more than [`OCCLUSION_MARGIN_M`] behind the measured depth of their pixel
    /// (e.g. the camera-facing contact face of an object pressed against another). Shows how much of the G2R
    /// is surface the camera cannot see.
    pub g2r_unoccluded_rmse_m: f64,
    /// |P|.
    pub observed: usize,
    /// |P̂|.
    pub reconstructed: usize,
}

/// RMS of nearest-neighbour distances from `queries` to `cloud` (kd-tree over `cloud`); `None` when either is empty.
pub fn rms_nearest(queries: &[[f32; 3]], cloud: &[[f32; 3]]) -> Option<f64> {
    if queries.is_empty() || cloud.is_empty() {
        return None;
    }
    let tree: kiddo::ImmutableKdTree<f32, 3> = kiddo::ImmutableKdTree::new_from_slice(cloud);
    let sum: f64 = queries.iter().map(|q| tree.nearest_one::<kiddo::SquaredEuclidean>(q).distance as f64).sum();
    Some((sum / queries.len() as f64).sqrt())
}

/// G2R and R2G of the last frame: P = the sampled, range-filtered points the mapper consumed; P̂ = the
/// reconstruction samples of every primitive of its map. `None` when the map or the frame is empty.
pub fn reconstruction_metrics(mapper: &Mapper<'_>, checked: &CheckedFrame<'_>) -> Option<ReconstructionMetrics> {
    let mut observed = Vec::new();
    mapper.for_each_labelled_point(checked, |p, _| observed.push(p.xyz));
    let mut reconstructed = Vec::new();
    mapper.for_each_primitive(|prim| prim.for_each_sample(|x| reconstructed.push(x)));
    let frame = checked.frame();
    let hidden = |x: &[f32; 3]| {
        pixel_of(frame, *x)
            .and_then(|(u, v)| observed_depth(frame, u, v))
            .is_some_and(|z| x[2] > z + OCCLUSION_MARGIN_M as f32)
    };
    let unoccluded: Vec<[f32; 3]> = reconstructed.iter().filter(|x| !hidden(x)).copied().collect();
    Some(ReconstructionMetrics {
        g2r_unoccluded_rmse_m: rms_nearest(&unoccluded, &observed).unwrap_or(0.0),
        g2r_rmse_m: rms_nearest(&reconstructed, &observed)?,
        r2g_rmse_m: rms_nearest(&observed, &reconstructed)?,
        observed: observed.len(),
        reconstructed: reconstructed.len(),
    })
}

/// The pixel (column, row) a camera-frame point (metres) projects onto, rounded to the nearest pixel centre;
/// `None` behind the camera or outside the image.
pub fn pixel_of(frame: &Frame<'_>, x: [f32; 3]) -> Option<(usize, usize)> {
    let [u, v] = frame.intrinsics.project(x)?;
    let (u, v) = (u.round(), v.round());
    (u >= 0.0 && v >= 0.0 && u < frame.width as f32 && v < frame.height as f32).then_some((u as usize, v as usize))
}

/// The observed depth of pixel (u, v), metres; `None` where the sensor measured nothing.
pub fn observed_depth(frame: &Frame<'_>, u: usize, v: usize) -> Option<f32> {
    let raw = frame.depth.get(v * frame.width as usize + u).copied().unwrap_or(0);
    (raw != 0).then(|| frame.metres(raw))
}

// --- Map-level metrics ---------------------------------------------------------------------------------------

/// [`PrimSamples::kind`] of a bounded plane (the PLY `kind` codes of docs/formats.md).
pub const KIND_PLANE: u8 = 0;
/// [`PrimSamples::kind`] of a superquadric.
pub const KIND_SQ: u8 = 1;
/// [`PrimSamples::kind`] of a Gaussian.
pub const KIND_GMM: u8 = 2;

/// The depth tolerance of the map-level metrics (the core's, [`Params::depth_tolerance`]).
pub use m2smap_core::params::{DEPTH_TOLERANCE_MIN_M, DEPTH_TOLERANCE_SIGMAS};
/// Half-size of the free-space window, pixels: a sample is in free space only when it lies in front of every
/// valid depth of the (2r + 1)² window around its pixel.
pub const FREE_SPACE_WINDOW_PX: usize = 2;
/// A superquadric counts as behind the support when more than this fraction of its samples is.
pub const BEHIND_SUPPORT_FRACTION: f64 = 0.02;
/// Samples within this many pixels of a ground-truth id boundary are not counted by the map-level adhesion
/// (a contact line between an object and its support, not a glued primitive).
pub const ADHESION_BOUNDARY_PX: usize = 2;
/// A primitive is a map-level adhesion case when two ground-truth ids each hold at least this fraction of its
/// depth-consistent samples …
pub const ADHESION_MIN_SHARE: f64 = 0.1;
/// … and it has at least this many depth-consistent samples.
pub const ADHESION_MIN_SAMPLES: usize = 10;

/// How far a sample may lie from an observed depth z (metres) and still agree with it: max(2 cm, 3σ(z)), with
/// σ(z) the sensor's axial noise ([`Params::depth_noise`]), metres.
pub fn depth_tolerance(params: &Params, z: f32) -> f32 {
    params.depth_tolerance(z)
}

/// The surface samples of one map primitive.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PrimSamples {
    /// [`KIND_PLANE`], [`KIND_SQ`] or [`KIND_GMM`].
    pub kind: u8,
    /// Instance id (0: none; planes have none).
    pub instance: u16,
    /// Every surface sample ([`Primitive::for_each_surface_sample`]: a superquadric's whole surface, not only
    /// its camera-facing side), camera frame, metres.
    pub samples: Vec<[f32; 3]>,
    /// A superquadric's full extents 2·a1, 2·a2, 2·a3 along its own axes, metres (`None` for other primitives).
    pub extent_m: Option<[f32; 3]>,
}

impl PrimSamples {
    /// Whether this primitive is a superquadric.
    pub fn is_sq(&self) -> bool {
        self.kind == KIND_SQ
    }
}

/// A map as the map-level metrics see it: every primitive with all its surface samples. Built from a mapper by
/// [`map_samples`], or by hand in tests.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MapSamples {
    /// The primitives, in the mapper's order (planes, superquadrics, Gaussians).
    pub prims: Vec<PrimSamples>,
}

/// The surface samples of every primitive of the mapper's last map.
pub fn map_samples(mapper: &Mapper<'_>) -> MapSamples {
    let mut prims = Vec::new();
    mapper.for_each_primitive(|p| {
        let (kind, instance, extent_m) = match p {
            Primitive::Plane(_) => (KIND_PLANE, 0, None),
            Primitive::Sq(s) => {
                let a = s.sq.scales;
                (KIND_SQ, s.instance, Some(a.map(|h| 2.0 * h)))
            }
            Primitive::Gmm(g) => (KIND_GMM, g.instance, None),
        };
        let mut samples = Vec::new();
        p.for_each_surface_sample(|x| samples.push(x));
        prims.push(PrimSamples { kind, instance, samples, extent_m });
    });
    MapSamples { prims }
}

/// What a map is judged against: the frame (observed depth and intrinsics), the sensor noise model of σ(z)
/// and, when the dataset has one, the ground-truth instance image.
#[derive(Debug, Clone, Copy)]
pub struct Observation<'a> {
    /// The frame the map was made from.
    pub frame: Frame<'a>,
    /// Parameters whose [`Params::depth_noise`] is σ(z).
    pub params: &'a Params,
    /// Ground-truth instance ids, row-major like the depth (0 = unlabelled: table, floor, wall, nothing).
    pub gt: Option<&'a [u16]>,
}

impl Observation<'_> {
    /// [`depth_tolerance`] at observed depth `z`, metres.
    pub fn tolerance(&self, z: f32) -> f32 {
        depth_tolerance(self.params, z)
    }

    /// The ground-truth id of pixel (u, v) (0 outside the image), `None` without a ground-truth image.
    pub fn gt_id(&self, u: usize, v: usize) -> Option<u16> {
        self.gt.map(|g| g.get(v * self.frame.width as usize + u).copied().unwrap_or(0))
    }

    /// The nearest valid observed depth in the window of ±[`FREE_SPACE_WINDOW_PX`] pixels around (u, v),
    /// metres; `None` when the window has no measurement.
    pub fn window_min_depth(&self, u: usize, v: usize) -> Option<f32> {
        // Every non-zero raw depth is a measurement here (no range filter), as for `observed_depth`.
        let r = FREE_SPACE_WINDOW_PX as i32;
        let (nearest, _) = self.frame.depth_window(u as i32, v as i32, r, (1, u16::MAX))?;
        Some(self.frame.metres(nearest))
    }

    /// Whether a camera-frame sample (metres) is in free space: `Some(true)` when it lies in front of the
    /// nearest valid depth of its window by more than the tolerance at that depth, `None` (unknown) when it
    /// projects outside the image or onto a window without valid depth.
    pub fn in_free_space(&self, x: [f32; 3]) -> Option<bool> {
        let (u, v) = pixel_of(&self.frame, x)?;
        let z = self.window_min_depth(u, v)?;
        Some(x[2] < z - self.tolerance(z))
    }
}

/// Free-space violation of one frame's map: samples in front of every valid depth around their pixel.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FreeSpace {
    /// Samples of all primitives whose status is known (inside the image, valid depth in the window).
    pub known: usize,
    /// Of those, the samples in free space.
    pub violating: usize,
    /// Known superquadric samples.
    pub known_sq: usize,
    /// Superquadric samples in free space.
    pub violating_sq: usize,
}

impl FreeSpace {
    /// Fraction of the known samples in free space; `None` when none is known.
    pub fn fraction(&self) -> Option<f64> {
        (self.known > 0).then(|| self.violating as f64 / self.known as f64)
    }

    /// Fraction of the known superquadric samples in free space; `None` when none is known.
    pub fn fraction_sq(&self) -> Option<f64> {
        (self.known_sq > 0).then(|| self.violating_sq as f64 / self.known_sq as f64)
    }
}

/// Free-space violation of a map against a frame's observed depth (see [`Observation::in_free_space`]).
pub fn free_space(map: &MapSamples, obs: &Observation<'_>) -> FreeSpace {
    let mut f = FreeSpace::default();
    for p in &map.prims {
        for &x in &p.samples {
            let Some(free) = obs.in_free_space(x) else { continue };
            f.known += 1;
            f.violating += usize::from(free);
            if p.is_sq() {
                f.known_sq += 1;
                f.violating_sq += usize::from(free);
            }
        }
    }
    f
}

/// Superquadrics that reach behind the support of one frame (needs a ground-truth instance image).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BehindSupport {
    /// Per superquadric, in map order: the fraction of its samples that project onto an unlabelled pixel
    /// (gt id 0: table, floor, wall) and lie more than the tolerance behind the observed depth there.
    pub fractions: Vec<f64>,
    /// Superquadrics with more than [`BEHIND_SUPPORT_FRACTION`] of their samples behind the support.
    pub sqs: u32,
    /// Deepest sample behind the observed depth of its unlabelled pixel, metres (0 when none is behind).
    pub max_depth_m: f64,
}

impl BehindSupport {
    /// The largest fraction over the superquadrics; `None` when the map has none.
    pub fn max_fraction(&self) -> Option<f64> {
        self.fractions.iter().copied().reduce(f64::max)
    }
}

/// Superquadric samples behind the support (see [`BehindSupport`]); `None` without a ground-truth image.
pub fn behind_support(map: &MapSamples, obs: &Observation<'_>) -> Option<BehindSupport> {
    obs.gt?;
    let mut b = BehindSupport::default();
    for p in map.prims.iter().filter(|p| p.is_sq() && !p.samples.is_empty()) {
        let mut behind = 0usize;
        for &x in &p.samples {
            let Some((u, v)) = pixel_of(&obs.frame, x) else { continue };
            let Some(z) = observed_depth(&obs.frame, u, v).filter(|_| obs.gt_id(u, v) == Some(0)) else { continue };
            if x[2] > z + obs.tolerance(z) {
                behind += 1;
                b.max_depth_m = b.max_depth_m.max((x[2] - z) as f64);
            }
        }
        let fraction = behind as f64 / p.samples.len() as f64;
        b.sqs += u32::from(fraction > BEHIND_SUPPORT_FRACTION);
        b.fractions.push(fraction);
    }
    Some(b)
}

/// Whether one primitive is a map-level adhesion case: among its depth-consistent samples (inside the image,
/// valid depth at their pixel, |z − observed z| ≤ tolerance) two ground-truth ids (0, unlabelled support,
/// counts as an id) each hold ≥ [`ADHESION_MIN_SHARE`], and there are ≥ [`ADHESION_MIN_SAMPLES`] of them.
/// `None` without a ground-truth image.
pub fn is_adhesion_case(prim: &PrimSamples, obs: &Observation<'_>) -> Option<bool> {
    let counts = consistent_id_counts(prim, obs)?;
    let consistent: usize = counts.values().sum();
    let strong = counts.values().filter(|&&c| c as f64 >= ADHESION_MIN_SHARE * consistent as f64).count();
    Some(consistent >= ADHESION_MIN_SAMPLES && strong >= 2)
}

/// The ground-truth ids under one primitive's depth-consistent samples (inside the image, valid depth at their
/// pixel, |z − observed z| ≤ tolerance), with how many samples each holds; samples within
/// [`ADHESION_BOUNDARY_PX`] of an id boundary count for none. `None` without a ground-truth image.
pub fn consistent_id_counts(prim: &PrimSamples, obs: &Observation<'_>) -> Option<HashMap<u16, usize>> {
    obs.gt?;
    let mut counts: HashMap<u16, usize> = HashMap::new();
    for &x in &prim.samples {
        let Some((u, v)) = pixel_of(&obs.frame, x) else { continue };
        let Some(z) = observed_depth(&obs.frame, u, v) else { continue };
        if (x[2] - z).abs() > obs.tolerance(z) {
            continue;
        }
        // A sample within ADHESION_BOUNDARY_PX of a ground-truth id boundary is a contact line (an object's
        // bottom row on the table), ambiguous at the 3 cm sample spacing: it counts for neither id.
        let id = obs.gt_id(u, v).unwrap_or(0);
        let r = ADHESION_BOUNDARY_PX;
        let (w, h) = (obs.frame.width as usize, obs.frame.height as usize);
        let pure = (v.saturating_sub(r)..=(v + r).min(h - 1))
            .all(|y| (u.saturating_sub(r)..=(u + r).min(w - 1)).all(|x| obs.gt_id(x, y).unwrap_or(0) == id));
        if pure {
            *counts.entry(id).or_insert(0) += 1;
        }
    }
    Some(counts)
}

/// Map-level adhesion cases of one frame: `(all primitives, superquadrics only)`; `None` without a
/// ground-truth image.
pub fn adhesion_cases(map: &MapSamples, obs: &Observation<'_>) -> Option<(u32, u32)> {
    obs.gt?;
    let mut cases = (0, 0);
    for p in map.prims.iter().filter(|p| is_adhesion_case(p, obs) == Some(true)) {
        cases.0 += 1;
        cases.1 += u32::from(p.is_sq());
    }
    Some(cases)
}

/// Published sizes of YCB objects (the YCB object set, Calli et al., IEEE RAM 2015; the gelatin box's and the
/// foam brick's as `../shared/data/README.md` quotes them), metres, by the YCB names YCB-Video's labels use.
/// The mug is its body, approximately (8 cm across, 8.2 cm high): one superquadric models the body, not the
/// handle.
pub const YCB_NOMINAL_SIZES_M: [(&str, [f32; 3]); 3] = [
    ("009_gelatin_box", [0.089, 0.073, 0.028]),
    ("025_mug", [0.080, 0.080, 0.082]),
    ("061_foam_brick", [0.050, 0.075, 0.050]),
];

/// A superquadric's size is within this relative difference of its object's nominal size (issue 12: 15 %).
pub const SQ_SIZE_TOLERANCE: f64 = 0.15;

/// The nominal size of a labelled object, metres; `None` for a label without one.
pub fn nominal_size(label: &str) -> Option<[f32; 3]> {
    YCB_NOMINAL_SIZES_M.iter().find(|(name, _)| *name == label).map(|&(_, size)| size)
}

/// How far a superquadric's full extents are from an object's nominal size: both sorted (the fit's axis order
/// is its own), the largest of |extent − nominal| / nominal over the three axes.
pub fn size_error(extent_m: [f32; 3], nominal_m: [f32; 3]) -> f64 {
    let sorted = |mut v: [f32; 3]| {
        v.sort_by(f32::total_cmp);
        v
    };
    let (e, n) = (sorted(extent_m), sorted(nominal_m));
    (0..3).map(|k| ((e[k] - n[k]) as f64).abs() / n[k] as f64).fold(0.0, f64::max)
}

/// One superquadric of a frame's map scored against the nominal size of the object it covers.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SqSize {
    /// The object's label (the ground-truth id holding most of the superquadric's depth-consistent samples).
    pub label: String,
    /// The superquadric's full extents, metres.
    pub extent_m: [f32; 3],
    /// The object's nominal size, metres.
    pub nominal_m: [f32; 3],
    /// [`size_error`] of the two.
    pub error: f64,
}

/// The superquadrics of a map whose object has a nominal size ([`nominal_size`]), each scored; the object is
/// the ground-truth id with the most depth-consistent samples ([`consistent_id_counts`]), named by `labels`
/// (ground-truth id → label). Superquadrics on unlabelled structure or unknown objects are left out. `None`
/// without a ground-truth image.
pub fn sq_sizes(map: &MapSamples, obs: &Observation<'_>, labels: &HashMap<u16, String>) -> Option<Vec<SqSize>> {
    obs.gt?;
    let mut sizes = Vec::new();
    for p in map.prims.iter().filter(|p| p.is_sq()) {
        let (Some(extent_m), Some(counts)) = (p.extent_m, consistent_id_counts(p, obs)) else { continue };
        // The id with the most samples (ties: the smaller id).
        let Some((&id, _)) = counts.iter().max_by_key(|&(&id, &c)| (c, std::cmp::Reverse(id))) else { continue };
        let Some(label) = labels.get(&id).filter(|_| id != 0) else { continue };
        let Some(nominal_m) = nominal_size(label) else { continue };
        sizes.push(SqSize { label: label.clone(), extent_m, nominal_m, error: size_error(extent_m, nominal_m) });
    }
    Some(sizes)
}

/// A map judged against the true surfaces of a synthetic scene.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TruthMetrics {
    /// √mean over all samples of the squared distance to the nearest true surface, metres; `None` without
    /// samples.
    pub g2r_true_rmse_m: Option<f64>,
    /// The same over the superquadric samples, metres.
    pub g2r_true_sq_rmse_m: Option<f64>,
    /// Per primitive with samples, in map order: (kind, penetration in metres), the depth of its deepest sample
    /// inside the true solid of a surface other than its own (see [`true_surface_metrics`]).
    pub penetration: Vec<(u8, f64)>,
}

impl TruthMetrics {
    /// The penetrations of all primitives (`sq_only`: of the superquadrics), metres.
    pub fn penetrations(&self, sq_only: bool) -> Vec<f64> {
        self.penetration.iter().filter(|(k, _)| !sq_only || *k == KIND_SQ).map(|&(_, d)| d).collect()
    }
}

/// The value at quantile `q` in [0, 1] of a list by the nearest-rank rule (the ⌈q·n⌉-th smallest); `None` when
/// the list is empty.
pub fn percentile(values: &[f64], q: f64) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len().max(1));
    v.get(rank - 1).copied()
}

/// The map against the true surfaces of a synthetic scene (world frame), with the frame's camera-to-world
/// `pose`:
/// - G2R against the true surfaces: RMS over the samples of the distance to the nearest surface;
/// - penetration: each sample's depth inside the true solid (the half-space behind a plane) of any surface
///   other than the primitive's own, the primitive's being that of its deepest sample. A primitive's own
///   surfaces: for a plane, the one surface nearest to most of its samples (the one it lies on); for a
///   superquadric or Gaussian, every surface of the object instance nearest to most of its samples, or, when
///   that is unlabelled structure (instance 0: floor, wall, table), the one structure surface nearest to most.
pub fn true_surface_metrics(map: &MapSamples, pose: &Pose, surfaces: &[Surface]) -> TruthMetrics {
    let mut t = TruthMetrics::default();
    if surfaces.is_empty() {
        return t;
    }
    let (mut sum, mut n, mut sum_sq, mut n_sq) = (0.0, 0usize, 0.0, 0usize);
    let m = surfaces.len();
    let mut signed: Vec<f64> = Vec::new();
    for p in map.prims.iter().filter(|p| !p.samples.is_empty()) {
        // Signed distances of every sample to every surface, and per sample its nearest surface.
        signed.clear();
        let mut votes = vec![0usize; m];
        for &x in &p.samples {
            let w = pose.apply(x.map(f64::from));
            let start = signed.len();
            signed.extend(surfaces.iter().map(|s| s.signed_distance(w)));
            let nearest = signed[start..].iter().enumerate().min_by(|a, b| a.1.abs().total_cmp(&b.1.abs()));
            if let Some((s, d)) = nearest {
                votes[s] += 1;
                sum += d * d;
                n += 1;
                if p.is_sq() {
                    sum_sq += d * d;
                    n_sq += 1;
                }
            }
        }
        let Some(surface) = (0..m).max_by_key(|&s| (votes[s], std::cmp::Reverse(s))) else { continue };
        let mut by_instance: HashMap<u16, usize> = HashMap::new();
        for (s, &v) in votes.iter().enumerate() {
            *by_instance.entry(surfaces[s].instance).or_insert(0) += v;
        }
        let instance = by_instance.iter().max_by_key(|(&i, &v)| (v, std::cmp::Reverse(i))).map_or(0, |(&i, _)| i);
        let own = |s: usize| {
            if p.kind == KIND_PLANE || instance == 0 {
                s == surface
            } else {
                surfaces[s].instance == instance
            }
        };
        let depth = signed
            .chunks(m)
            .flat_map(|d| d.iter().enumerate().filter(|&(s, _)| !own(s)).map(|(_, &d)| (-d).max(0.0)))
            .fold(0.0, f64::max);
        t.penetration.push((p.kind, depth));
    }
    t.g2r_true_rmse_m = (n > 0).then(|| (sum / n as f64).sqrt());
    t.g2r_true_sq_rmse_m = (n_sq > 0).then(|| (sum_sq / n_sq as f64).sqrt());
    t
}

/// Smallest ground-truth instance that [`mask_match`] counts, pixels: a sliver left by an occluder (fewer
/// points than one object of the pipeline's `seg_min_points` at close range) is not an instance to find.
pub const MASK_GT_MIN_PIXELS: u32 = 100;

/// IoU a mask needs with a ground-truth instance to match it.
pub const MASK_MATCH_IOU: f64 = 0.5;

/// How one frame's instance masks match its ground-truth instance image (docs/metrics.md): every ground-truth
/// id ≠ 0 with at least [`MASK_GT_MIN_PIXELS`] pixels is an instance to find (id 0 is structure: floor, walls,
/// table, and whatever the ground truth leaves unlabelled), every mask instance with a pixel is a claim, and
/// pairs with IoU ≥ [`MASK_MATCH_IOU`] match one to one (greedily by IoU). A claim with fewer than half of its
/// pixels on ground-truth instances is a claim on structure, which the ground truth cannot judge (a table leg, a
/// keyboard the dataset leaves unlabelled): it never matches (IoU ≥ 0.5 needs half its pixels on the instance).
/// Recall = matched / ground-truth instances; precision = matched / claims on ground-truth instances, and
/// [`MaskMatch::precision_all`] = matched / every claim.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MaskMatch {
    /// Ground-truth instances to find.
    pub gt_instances: u32,
    /// Mask instances with at least one pixel.
    pub mask_instances: u32,
    /// Of those, claims on structure: fewer than half of their pixels on ground-truth instances.
    pub structure_claims: u32,
    /// Matched pairs.
    pub matched: u32,
    /// Sum of the matched pairs' IoU.
    pub iou_sum: f64,
}

impl MaskMatch {
    /// Matched / ground-truth instances (`None` without any).
    pub fn recall(&self) -> Option<f64> {
        (self.gt_instances > 0).then(|| self.matched as f64 / self.gt_instances as f64)
    }

    /// Matched / claims on ground-truth instances (`None` without any).
    pub fn precision(&self) -> Option<f64> {
        let judged = self.mask_instances.saturating_sub(self.structure_claims);
        (judged > 0).then(|| self.matched as f64 / judged as f64)
    }

    /// Matched / every mask instance, claims on structure included (`None` without any).
    pub fn precision_all(&self) -> Option<f64> {
        (self.mask_instances > 0).then(|| self.matched as f64 / self.mask_instances as f64)
    }

    /// Mean IoU of the matched pairs (`None` without a match).
    pub fn mean_iou(&self) -> Option<f64> {
        (self.matched > 0).then(|| self.iou_sum / self.matched as f64)
    }

    /// The sum of two frames' counts (a run's pooled figures).
    pub fn add(&self, other: &MaskMatch) -> MaskMatch {
        MaskMatch {
            gt_instances: self.gt_instances + other.gt_instances,
            mask_instances: self.mask_instances + other.mask_instances,
            structure_claims: self.structure_claims + other.structure_claims,
            matched: self.matched + other.matched,
            iou_sum: self.iou_sum + other.iou_sum,
        }
    }
}

/// [`MaskMatch`] of `masks` against the ground-truth ids `gt` (row-major, the masks' size).
pub fn mask_match(masks: &FrameMasks, gt: &[u16]) -> MaskMatch {
    let (w, h) = (masks.width as usize, masks.height as usize);
    let view = masks.view();
    let k = masks.instances.len();
    let mut gt_area: HashMap<u16, u32> = HashMap::new();
    for &id in gt.iter().take(w * h).filter(|&&id| id != 0) {
        *gt_area.entry(id).or_default() += 1;
    }
    let mut area = vec![0u32; k];
    let mut labelled = vec![0u32; k];
    let mut inter: HashMap<(usize, u16), u32> = HashMap::new();
    for v in 0..h {
        for u in 0..w {
            let id = gt.get(v * w + u).copied().unwrap_or(0);
            for (i, (a, l)) in area.iter_mut().zip(labelled.iter_mut()).enumerate() {
                if view.contains(i, u as u16, v as u16) {
                    *a += 1;
                    if id != 0 {
                        *l += 1;
                        *inter.entry((i, id)).or_default() += 1;
                    }
                }
            }
        }
    }
    let counted = |id: u16| gt_area.get(&id).is_some_and(|&a| a >= MASK_GT_MIN_PIXELS);
    let mut pairs: Vec<(f64, usize, u16)> = inter
        .iter()
        .filter(|((_, id), _)| counted(*id))
        .map(|(&(i, id), &n)| {
            let union = area.get(i).copied().unwrap_or(0) + gt_area.get(&id).copied().unwrap_or(0) - n;
            (n as f64 / union.max(1) as f64, i, id)
        })
        .filter(|(iou, _, _)| *iou >= MASK_MATCH_IOU)
        .collect();
    pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let (mut used_mask, mut used_gt) = (vec![false; k], Vec::<u16>::new());
    let mut out = MaskMatch {
        gt_instances: gt_area.keys().filter(|&&id| counted(id)).count() as u32,
        mask_instances: area.iter().filter(|&&a| a > 0).count() as u32,
        structure_claims: area.iter().zip(&labelled).filter(|&(&a, &l)| a > 0 && 2 * l < a).count() as u32,
        ..MaskMatch::default()
    };
    for (iou, i, id) in pairs {
        if used_mask.get(i).copied().unwrap_or(true) || used_gt.contains(&id) {
            continue;
        }
        if let Some(u) = used_mask.get_mut(i) {
            *u = true;
        }
        used_gt.push(id);
        out.matched += 1;
        out.iou_sum += iou;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::Shape;
    use m2smap_core::Intrinsics;

    const W: usize = 40;
    const H: usize = 30;
    /// Raw depth units per metre of the test frames.
    const SCALE: f32 = 5000.0;

    /// A 40 × 30 frame with fx = fy = 100 and the principal point at pixel (20, 15): the camera-frame point
    /// (x, y, z) projects onto pixel (20 + 100x/z, 15 + 100y/z).
    fn frame(depth: &[u16]) -> Frame<'_> {
        Frame {
            width: W as u16,
            height: H as u16,
            depth,
            depth_scale: SCALE,
            colour: &[],
            intrinsics: Intrinsics { fx: 100.0, fy: 100.0, cx: 20.0, cy: 15.0 },
            pose: None,
        }
    }

    /// A flat depth image at `z` metres.
    fn flat(z: f32) -> Vec<u16> {
        vec![(z * SCALE).round() as u16; W * H]
    }

    /// The camera-frame point at depth z that projects onto pixel (u, v).
    fn at(u: usize, v: usize, z: f32) -> [f32; 3] {
        [(u as f32 - 20.0) * z / 100.0, (v as f32 - 15.0) * z / 100.0, z]
    }

    fn prim(kind: u8, samples: Vec<[f32; 3]>) -> PrimSamples {
        PrimSamples { kind, instance: 1, samples, extent_m: None }
    }

    fn map(prims: Vec<PrimSamples>) -> MapSamples {
        MapSamples { prims }
    }

    #[test]
    fn tolerance_is_two_centimetres_or_three_sigma() {
        let p = Params::default();
        // σ(1 m) = 0.0012 + 0.0019·0.36 = 1.88 mm: 3σ < 2 cm.
        assert!((depth_tolerance(&p, 1.0) - 0.02).abs() < 1e-7);
        // σ(4 m) = 0.0012 + 0.0019·12.96 = 25.8 mm: 3σ = 77.5 mm.
        assert!((depth_tolerance(&p, 4.0) - 3.0 * (0.0012 + 0.0019 * 3.6 * 3.6)).abs() < 1e-6);
    }

    #[test]
    fn free_space_is_in_front_of_every_depth_of_the_window() {
        let depth = flat(1.0);
        let params = Params::default();
        let obs = Observation { frame: frame(&depth), params: &params, gt: None };
        // 10 cm in front of a flat wall at 1 m: free space; on it or behind it: not.
        assert_eq!(obs.in_free_space(at(10, 10, 0.9)), Some(true));
        assert_eq!(obs.in_free_space(at(10, 10, 1.0)), Some(false));
        assert_eq!(obs.in_free_space(at(10, 10, 1.1)), Some(false));
        // Within the tolerance (2 cm at 1 m): not free space; just beyond: free space.
        assert_eq!(obs.in_free_space(at(10, 10, 0.985)), Some(false));
        assert_eq!(obs.in_free_space(at(10, 10, 0.975)), Some(true));
        // Outside the image or behind the camera: unknown.
        assert_eq!(obs.in_free_space([10.0, 0.0, 1.0]), None);
        assert_eq!(obs.in_free_space([0.0, 0.0, -1.0]), None);

        // One nearer pixel (0.88 m) two pixels away: the sample at 0.9 m is no longer in free space; three
        // pixels away it does not count.
        let mut near = flat(1.0);
        near[12 * W + 10] = (0.88 * SCALE).round() as u16;
        let obs = Observation { frame: frame(&near), params: &params, gt: None };
        assert_eq!(obs.in_free_space(at(10, 10, 0.9)), Some(false));
        assert_eq!(obs.in_free_space(at(10, 9, 0.9)), Some(true));
        // Clipped at the border: a corner pixel sees its 3 × 3 part of the window.
        assert_eq!(obs.window_min_depth(0, 0), Some(1.0));

        // A window without valid depth is unknown; one valid pixel in it is enough.
        let mut holes = flat(1.0);
        for v in 3..8 {
            for u in 3..8 {
                holes[v * W + u] = 0;
            }
        }
        let obs = Observation { frame: frame(&holes), params: &params, gt: None };
        assert_eq!(obs.in_free_space(at(5, 5, 0.5)), None);
        assert_eq!(obs.in_free_space(at(5, 6, 0.5)), Some(true));

        // Fractions over the known samples, all primitives and superquadrics apart.
        let m = map(vec![
            prim(KIND_SQ, vec![at(20, 20, 0.9), at(20, 20, 1.0), at(20, 20, 1.1), at(5, 5, 0.5), [5.0, 0.0, 1.0]]),
            prim(KIND_GMM, vec![at(30, 10, 0.8), at(30, 10, 0.8), at(30, 10, 1.0), at(30, 10, 1.0)]),
        ]);
        let f = free_space(&m, &obs);
        assert_eq!(f, FreeSpace { known: 7, violating: 3, known_sq: 3, violating_sq: 1 });
        assert_eq!(f.fraction(), Some(3.0 / 7.0));
        assert_eq!(f.fraction_sq(), Some(1.0 / 3.0));
        assert_eq!(free_space(&map(vec![prim(KIND_GMM, vec![at(5, 5, 0.5)])]), &obs).fraction(), None);
        assert_eq!(free_space(&map(vec![prim(KIND_GMM, vec![at(9, 9, 0.5)])]), &obs).fraction_sq(), None);
    }

    #[test]
    fn superquadrics_behind_the_support_count_unlabelled_pixels_only() {
        // Depth 1 m everywhere; the left half (u < 20) is unlabelled support, the right half object 7.
        let depth = flat(1.0);
        let gt: Vec<u16> = (0..W * H).map(|i| if i % W < 20 { 0 } else { 7 }).collect();
        let params = Params::default();
        let obs = Observation { frame: frame(&depth), params: &params, gt: Some(&gt) };
        // SQ a: 100 samples, 10 of them 5 cm behind the table (10 %), 10 behind the object (not counted), the
        // rest on the surface. SQ b: 1 of 100 behind the support (1 % ≤ 2 %). A Gaussian far behind: ignored.
        let mut a = vec![at(10, 10, 1.0); 80];
        a.extend(vec![at(10, 10, 1.05); 10]);
        a.extend(vec![at(30, 10, 1.3); 10]);
        let mut b = vec![at(5, 5, 1.0); 99];
        b.push(at(5, 5, 1.25));
        let m = map(vec![prim(KIND_SQ, a), prim(KIND_SQ, b), prim(KIND_GMM, vec![at(10, 10, 2.0); 50])]);
        let r = behind_support(&m, &obs).unwrap();
        assert_eq!(r.fractions, vec![0.1, 0.01]);
        assert_eq!(r.sqs, 1);
        assert_eq!(r.max_fraction(), Some(0.1));
        assert!((r.max_depth_m - 0.25).abs() < 1e-4, "{}", r.max_depth_m);
        // 1.5 cm behind is within the 2 cm tolerance: nothing behind.
        let m = map(vec![prim(KIND_SQ, vec![at(10, 10, 1.015); 20])]);
        let r = behind_support(&m, &obs).unwrap();
        assert_eq!((r.sqs, r.max_fraction(), r.max_depth_m), (0, Some(0.0), 0.0));
        // No superquadric: zero of them, no largest fraction. No ground truth: not computable.
        let r = behind_support(&map(vec![]), &obs).unwrap();
        assert_eq!((r.sqs, r.max_fraction()), (0, None));
        assert!(behind_support(&m, &Observation { gt: None, ..obs }).is_none());
    }

    #[test]
    fn map_level_adhesion_needs_two_ids_with_a_tenth_each() {
        let depth = flat(1.0);
        // Left half id 1, right half id 2.
        let gt: Vec<u16> = (0..W * H).map(|i| if i % W < 20 { 1 } else { 2 }).collect();
        let params = Params::default();
        let obs = Observation { frame: frame(&depth), params: &params, gt: Some(&gt) };
        let split = |left: usize, right: usize, z_right: f32| {
            let mut s = vec![at(10, 10, 1.0); left];
            s.extend(vec![at(30, 10, z_right); right]);
            s
        };
        let case = |s: Vec<[f32; 3]>| is_adhesion_case(&prim(KIND_GMM, s), &obs).unwrap();
        assert!(case(split(50, 50, 1.0)), "50/50");
        assert!(case(split(90, 10, 1.0)), "90/10: exactly a tenth");
        assert!(!case(split(95, 5, 1.0)), "95/5");
        assert!(!case(split(5, 4, 1.0)), "50/50 of 9 depth-consistent samples");
        // The right half 10 cm in front of the observed depth (free space, not depth-consistent): one id only.
        assert!(!case(split(50, 50, 0.9)), "inconsistent half");
        // Unlabelled support counts as an id.
        let support: Vec<u16> = (0..W * H).map(|i| if i % W < 20 { 0 } else { 2 }).collect();
        let obs0 = Observation { gt: Some(&support), ..obs };
        assert_eq!(is_adhesion_case(&prim(KIND_PLANE, split(30, 30, 1.0)), &obs0), Some(true));
        // Counts per frame, superquadrics apart; none without ground truth.
        let m = map(vec![
            prim(KIND_SQ, split(50, 50, 1.0)),
            prim(KIND_SQ, split(95, 5, 1.0)),
            prim(KIND_GMM, split(40, 60, 1.0)),
            prim(KIND_PLANE, split(100, 0, 1.0)),
        ]);
        assert_eq!(adhesion_cases(&m, &obs), Some((2, 1)));
        assert_eq!(adhesion_cases(&m, &Observation { gt: None, ..obs }), None);
    }

    #[test]
    fn sq_sizes_score_the_object_under_most_samples_against_its_nominal_size() {
        assert_eq!(size_error([0.028, 0.089, 0.073], [0.089, 0.073, 0.028]), 0.0, "axis order is the fit's own");
        // Sorted: 2.8 cm against 2.8, 8.9 against 7.3 (+21.9 %), 8.9 against 8.9: the worst counts.
        let e = size_error([0.028, 0.089, 0.089], [0.089, 0.073, 0.028]);
        assert!((e - 0.016 / 0.073).abs() < 1e-6, "{e}");
        assert_eq!(nominal_size("061_foam_brick"), Some([0.050, 0.075, 0.050]));
        assert_eq!(nominal_size("chair"), None);

        // Left half id 21 (the brick), right half id 99 (no nominal size); depth 1 m.
        let depth = flat(1.0);
        let gt: Vec<u16> = (0..W * H).map(|i| if i % W < 20 { 21 } else { 99 }).collect();
        let params = Params::default();
        let obs = Observation { frame: frame(&depth), params: &params, gt: Some(&gt) };
        let labels: HashMap<u16, String> =
            [(21, "061_foam_brick".to_owned()), (99, "chair".to_owned())].into_iter().collect();
        let sq = |samples: Vec<[f32; 3]>, extent: [f32; 3]| PrimSamples {
            kind: KIND_SQ,
            instance: 1,
            samples,
            extent_m: Some(extent),
        };
        // Mostly on the brick, some on the chair, some in front of everything (not depth-consistent).
        let mut on_brick = vec![at(10, 10, 1.0); 30];
        on_brick.extend(vec![at(30, 10, 1.0); 10]);
        on_brick.extend(vec![at(30, 10, 0.5); 40]);
        let mut on_chair = vec![at(30, 10, 1.0); 30];
        on_chair.extend(vec![at(10, 10, 1.0); 10]);
        let m = map(vec![
            sq(on_brick, [0.06, 0.075, 0.05]),
            sq(on_chair, [0.05, 0.075, 0.05]),
            prim(KIND_GMM, vec![at(10, 10, 1.0); 30]),
        ]);
        let sizes = sq_sizes(&m, &obs, &labels).unwrap();
        assert_eq!(sizes.len(), 1, "the chair has no nominal size, the Gaussian is no superquadric");
        assert_eq!(sizes[0].label, "061_foam_brick");
        assert!((sizes[0].error - 0.2).abs() < 1e-6, "6 cm against 5: {}", sizes[0].error);
        assert!(sq_sizes(&m, &Observation { gt: None, ..obs }, &labels).is_none());
    }

    fn surface(name: &str, instance: u16, shape: Shape) -> Surface {
        Surface { name: name.into(), instance, label: String::new(), shape, colour: [0; 3] }
    }

    /// A floor (z = 0), a wall (y = 2) and a 20 cm cube (object 1) standing on the floor at the origin.
    fn scene() -> Vec<Surface> {
        vec![
            surface("floor", 0, Shape::Plane { normal: [0.0, 0.0, 1.0], offset: 0.0 }),
            surface("wall", 0, Shape::Plane { normal: [0.0, -1.0, 0.0], offset: -2.0 }),
            surface("cube", 1, Shape::Box { centre: [0.0, 0.0, 0.1], half: [0.1, 0.1, 0.1], yaw: 0.0 }),
            surface("ball", 2, Shape::Sphere { centre: [0.5, 0.0, 0.1], radius: 0.1 }),
        ]
    }

    const IDENTITY: Pose = Pose { t: [0.0; 3], q: [0.0, 0.0, 0.0, 1.0] };

    #[test]
    fn g2r_against_the_true_surfaces() {
        // Two samples above the floor far from the objects (1 and 3 cm), two on the cube's top face (0 and
        // 2 cm above it) in a superquadric.
        let m = map(vec![
            prim(KIND_GMM, vec![[1.0, 1.0, 0.01], [1.0, 1.0, 0.03]]),
            prim(KIND_SQ, vec![[0.0, 0.0, 0.2], [0.0, 0.0, 0.22]]),
        ]);
        let t = true_surface_metrics(&m, &IDENTITY, &scene());
        let all = ((0.01f64.powi(2) + 0.03f64.powi(2) + 0.02f64.powi(2)) / 4.0).sqrt();
        assert!((t.g2r_true_rmse_m.unwrap() - all).abs() < 1e-6, "{:?}", t.g2r_true_rmse_m);
        assert!((t.g2r_true_sq_rmse_m.unwrap() - (0.02f64.powi(2) / 2.0).sqrt()).abs() < 1e-6);
        // The pose moves the samples: a camera 1 m above the world origin sees the floor sample at z = −1.
        let up = Pose { t: [0.0, 0.0, 1.0], q: [0.0, 0.0, 0.0, 1.0] };
        let t = true_surface_metrics(&map(vec![prim(KIND_GMM, vec![[1.0, 1.0, -0.98]])]), &up, &scene());
        assert!((t.g2r_true_rmse_m.unwrap() - 0.02).abs() < 1e-6);
        assert_eq!(t.g2r_true_sq_rmse_m, None);
        assert_eq!(true_surface_metrics(&map(vec![]), &IDENTITY, &scene()), TruthMetrics::default());
    }

    #[test]
    fn penetration_is_the_deepest_sample_inside_another_solid() {
        let surfaces = scene();
        let pen = |kind: u8, samples: Vec<[f32; 3]>| {
            let t = true_surface_metrics(&map(vec![prim(kind, samples)]), &IDENTITY, &surfaces);
            t.penetration[0]
        };
        // A superquadric on the cube's surface with one sample 3 cm below the floor: 0.03.
        let cube_top: Vec<[f32; 3]> = (0..10).map(|k| [-0.05 + 0.01 * k as f32, 0.0, 0.2]).collect();
        let mut s = cube_top.clone();
        s.push([0.05, 0.05, -0.03]);
        let (kind, d) = pen(KIND_SQ, s);
        assert_eq!(kind, KIND_SQ);
        assert!((d - 0.03).abs() < 1e-6, "{d}");
        // Samples inside its own cube do not count.
        let mut s = cube_top.clone();
        s.push([0.0, 0.0, 0.12]);
        assert!(pen(KIND_SQ, s).1 < 1e-9);
        // The same superquadric reaching 4 cm into the ball (its side at x = 0.4): 0.04.
        let mut s = cube_top.clone();
        s.push([0.44, 0.0, 0.1]);
        assert!((pen(KIND_GMM, s).1 - 0.04).abs() < 1e-6);
        // 5 cm behind the wall: 0.05.
        let mut s = cube_top;
        s.push([0.0, 2.05, 0.5]);
        assert!((pen(KIND_SQ, s).1 - 0.05).abs() < 1e-6);
        // A floor plane whose samples lie 5 mm below the floor: it lies on the floor, no penetration; one of
        // its samples 3 cm above the floor inside the cube (3 cm from the cube's bottom face) is.
        let floor: Vec<[f32; 3]> = (0..20).map(|k| [1.0 + 0.05 * k as f32, 0.5, -0.005]).collect();
        assert!(pen(KIND_PLANE, floor.clone()).1 < 1e-9);
        let mut f = floor;
        f.push([0.0, 0.0, 0.03]);
        assert!((pen(KIND_PLANE, f).1 - 0.03).abs() < 1e-6);
        // A Gaussian of the structure (nearest to the floor) reaching 1 cm behind the wall.
        let mut g: Vec<[f32; 3]> = (0..5).map(|k| [1.0, 1.0 + 0.1 * k as f32, 0.001]).collect();
        g.push([1.0, 2.01, 0.001]);
        assert!((pen(KIND_GMM, g).1 - 0.01).abs() < 1e-6);
        // Per frame: p95 and max over primitives by nearest rank.
        assert_eq!(percentile(&[0.0, 0.03, 0.01, 0.02], 0.95), Some(0.03));
        assert_eq!(percentile(&(1..=100).map(f64::from).collect::<Vec<_>>(), 0.95), Some(95.0));
        assert_eq!(percentile(&[], 0.95), None);
    }

    /// Hand-built masks against a hand-built ground truth: one exact match, one object split in two masks (the
    /// larger part, IoU 0.6, matches; the other is a claim that matches nothing), one mask over an object and the
    /// structure below it (IoU 0.5: matches), a mask on a sliver below the pixel minimum (not an instance to
    /// find, but a claim), and id 0 never an instance.
    #[test]
    fn mask_match_counts_what_it_should() {
        use crate::masks::{FrameMasks, Pixels};
        use m2smap_core::Instance;
        let (w, h) = (40u16, 20u16);
        let mut gt = vec![0u16; w as usize * h as usize];
        let mut ids = vec![0u16; gt.len()];
        let fill = |img: &mut Vec<u16>, x0: usize, x1: usize, y0: usize, y1: usize, id: u16| {
            for y in y0..y1 {
                for x in x0..x1 {
                    img[y * w as usize + x] = id;
                }
            }
        };
        // Ground truth: A (id 1), B (2), C (3), each 10 × 10; a 6-pixel sliver D (4).
        fill(&mut gt, 0, 10, 0, 10, 1);
        fill(&mut gt, 10, 20, 0, 10, 2);
        fill(&mut gt, 20, 30, 0, 10, 3);
        fill(&mut gt, 30, 32, 0, 3, 4);
        // Masks: A exactly (1); B as 4 + 6 columns (2, 3); C with the structure below it (4); the sliver (5).
        fill(&mut ids, 0, 10, 0, 10, 1);
        fill(&mut ids, 10, 14, 0, 10, 2);
        fill(&mut ids, 14, 20, 0, 10, 3);
        fill(&mut ids, 20, 30, 0, 20, 4);
        fill(&mut ids, 30, 32, 0, 3, 5);
        let instance = |id: u16| Instance { id, class: 1, score: 1.0, bbox: [0, 0, w - 1, h - 1] };
        let masks =
            FrameMasks { width: w, height: h, instances: (1..=5).map(instance).collect(), pixels: Pixels::Ids(ids) };
        let m = mask_match(&masks, &gt);
        assert_eq!(m.gt_instances, 3, "A, B and C; the sliver is below the minimum");
        assert_eq!(m.mask_instances, 5);
        assert_eq!(m.matched, 3, "A (IoU 1), B's larger part (0.6), C with its structure (0.5)");
        assert!((m.iou_sum - 2.1).abs() < 1e-9, "{m:?}");
        assert_eq!(m.recall(), Some(1.0));
        assert_eq!(m.structure_claims, 0, "every claim lies mostly on ground-truth instances");
        assert_eq!(m.precision(), Some(0.6));
        assert_eq!(m.precision_all(), Some(0.6));
        // A claim on structure alone (below the objects) is not judged by precision, only by precision_all; one
        // with half its pixels on an object is judged.
        let mut ids = match &masks.pixels {
            Pixels::Ids(ids) => ids.clone(),
            _ => unreachable!(),
        };
        fill(&mut ids, 0, 10, 10, 20, 6);
        fill(&mut ids, 32, 40, 0, 20, 7);
        fill(&mut ids, 30, 32, 3, 6, 5);
        let with_structure =
            FrameMasks { instances: (1..=7).map(instance).collect(), pixels: Pixels::Ids(ids), ..masks.clone() };
        let s = mask_match(&with_structure, &gt);
        assert_eq!((s.mask_instances, s.structure_claims, s.matched), (7, 2, 3), "{s:?}");
        assert_eq!(s.precision(), Some(0.6), "claims 6 and 7 lie on structure; the sliver's (5) is half on it");
        assert!((s.precision_all().unwrap_or(0.0) - 3.0 / 7.0).abs() < 1e-9);
        assert!((m.mean_iou().unwrap_or(0.0) - 0.7).abs() < 1e-9);
        // Without C's mask: recall 2/3; without any mask nothing is claimed.
        let no_c =
            FrameMasks { instances: masks.instances.iter().filter(|i| i.id != 4).copied().collect(), ..masks.clone() };
        assert_eq!(mask_match(&no_c, &gt).matched, 2);
        assert_eq!(MaskMatch::default().recall(), None);
    }
}
