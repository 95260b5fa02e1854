//! Evaluation metrics of SPEC §4 computed from a processed frame. (This issue: the semantic fusion metrics
//! N_adh and A_s; the reconstruction metrics come with the evaluation suite.)

use std::collections::HashMap;

use m2smap_core::mapper::CheckedFrame;
use m2smap_core::supervoxel::is_assigned;
use m2smap_core::Mapper;

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
pub fn semantic_metrics(mapper: &Mapper<'_>, checked: &CheckedFrame<'_>, reference: impl Fn(u16, u16) -> u16) -> SemanticMetrics {
    let gaussians = mapper.gaussians();
    let mut per_gaussian: Vec<HashMap<u16, u32>> = vec![HashMap::new(); gaussians.len()];
    mapper.for_each_labelled_point(checked, |p, v| {
        if let Some(v) = v.filter(|v| is_assigned(v.gaussian)) {
            *per_gaussian[v.gaussian as usize].entry(reference(p.u, p.v)).or_insert(0) += 1;
        }
    });
    let mut clusters: HashMap<u16, (HashMap<u16, u32>, Vec<u16>)> = HashMap::new();
    for (g, counts) in gaussians.iter().zip(&per_gaussian) {
        let entry = clusters.entry(g.cluster).or_default();
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

/// Reconstruction accuracy of one frame's map (SPEC §4), metres.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReconstructionMetrics {
    /// G2R RMSE: √mean over the reconstructed samples P̂ of the squared distance to the nearest observed point.
    pub g2r_rmse_m: f64,
    /// R2G RMSE: √mean over the observed points P of the squared distance to the nearest reconstructed sample.
    pub r2g_rmse_m: f64,
    /// Diagnostic beside SPEC §4 (not the paper's metric): G2R over the samples that the observed depth does not
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
fn rms_nearest(queries: &[[f32; 3]], cloud: &[[f32; 3]]) -> Option<f64> {
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
        let Some([u, v]) = frame.intrinsics.project(*x) else { return false };
        let (u, v) = (u.round(), v.round());
        if u < 0.0 || v < 0.0 || u >= frame.width as f32 || v >= frame.height as f32 {
            return false;
        }
        let raw = frame.depth.get(v as usize * frame.width as usize + u as usize).copied().unwrap_or(0);
        raw != 0 && x[2] > frame.metres(raw) + OCCLUSION_MARGIN_M as f32
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
