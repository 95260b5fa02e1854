//! Every tunable of the pipeline in one place, with the paper's names and defaults (paper §VI, docs/pipeline.md).
//!
//! Parameters the paper leaves open carry the value chosen here and the reason in their doc comment.

use crate::error::ParamError;

/// Which method the mapper runs (docs/variants.md): one switch each, same code path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Variant {
    /// M2-SMap with m2smap's extensions (mask slots in the voxels, the mask cut, held-back uncertain fragments,
    /// annotated small fragments); the default.
    Full,
    /// M2-SMap with the paper's rules only: `full` without the four extensions, so what each buys is measured.
    Paper,
    /// Fusion ignores instance ids; labels are assigned after merging.
    Pmsao,
    /// No superquadric equivalence alignment before smoothing.
    Wsqa,
    /// Gaussians only: no planes, no superquadrics, no semantics.
    Mmog,
    /// Planes and Gaussians, geometry-only fusion, no superquadrics.
    Mmp,
    /// Planes, ellipsoids allocated by geometry, and Gaussians; no semantics.
    Mmq,
}

impl Variant {
    /// Every variant, in the order reports list them.
    pub const ALL: [Variant; 7] =
        [Variant::Full, Variant::Paper, Variant::Pmsao, Variant::Wsqa, Variant::Mmog, Variant::Mmp, Variant::Mmq];

    /// The lower-case name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Variant::Full => "full",
            Variant::Paper => "paper",
            Variant::Pmsao => "pmsao",
            Variant::Wsqa => "wsqa",
            Variant::Mmog => "mmog",
            Variant::Mmp => "mmp",
            Variant::Mmq => "mmq",
        }
    }

    /// Whether Gaussians are annotated with instance masks (every variant with semantics).
    pub fn annotates(self) -> bool {
        matches!(self, Variant::Full | Variant::Paper | Variant::Pmsao | Variant::Wsqa)
    }

    /// Whether m2smap's extensions of the paper's annotation and fusion are on (every annotating variant but
    /// [`Variant::Paper`]): mask slots and the mask cut (with `mask_split_min_share` < 1, see
    /// [`Params::mask_consistent`]), held-back uncertain fragments ([`crate::fuse::is_uncertain`]) and annotated
    /// small fragments (`small_fragment_ratio`).
    pub fn extensions(self) -> bool {
        self.annotates() && self != Variant::Paper
    }

    /// Whether fusion requires equal instance ids (ψ_s); otherwise labels are assigned after merging (PMSAO) or
    /// not at all.
    pub fn semantic_fusion(self) -> bool {
        matches!(self, Variant::Full | Variant::Paper | Variant::Wsqa)
    }

    /// Whether objects are fitted with superquadrics and tracked (semantic objects, or for MMQ the objects
    /// allocated by geometry).
    pub fn superquadrics(self) -> bool {
        matches!(self, Variant::Full | Variant::Paper | Variant::Pmsao | Variant::Wsqa | Variant::Mmq)
    }

    /// Whether objects are allocated by geometry rather than by instance (MMQ): every fused cluster that is not
    /// a plane and holds at least `sq_min_points` points is one object.
    pub fn geometric_objects(self) -> bool {
        matches!(self, Variant::Mmq)
    }

    /// Whether the quadrics are ellipsoids (ε1 = ε2 = 1 fixed, MMQ) rather than superquadrics.
    pub fn ellipsoids_only(self) -> bool {
        matches!(self, Variant::Mmq)
    }

    /// Whether superquadric measurements are aligned with their track before smoothing (not in WSQA).
    pub fn aligns(self) -> bool {
        !matches!(self, Variant::Wsqa)
    }

    /// Whether flat planes are separated.
    pub fn planes(self) -> bool {
        !matches!(self, Variant::Mmog)
    }

    /// Parses a name from [`Variant::name`].
    pub fn from_name(name: &str) -> Option<Variant> {
        Variant::ALL.iter().copied().find(|v| v.name() == name)
    }
}

/// Smallest depth tolerance, metres ([`Params::depth_tolerance`]).
pub const DEPTH_TOLERANCE_MIN_M: f32 = 0.02;
/// The depth tolerance is at least this many σ(z) of the sensor's axial noise ([`Params::depth_tolerance`]).
pub const DEPTH_TOLERANCE_SIGMAS: f32 = 3.0;

/// [`Params::sample_rate`]'s default: the paper's 15 % of the in-range pixels.
pub const DEFAULT_SAMPLE_RATE: f32 = 0.15;
/// [`Params::sample_seed`]'s default. With it and [`DEFAULT_SAMPLE_RATE`] the sample of the first
/// [`crate::points::SAMPLE_TABLE_PIXELS`] pixels is read from a table made at compile time.
pub const DEFAULT_SAMPLE_SEED: u32 = 0x6d32_736d;

/// The mapping parameters Θ. `Params::default()` is the paper's setting.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Method variant (docs/variants.md).
    pub variant: Variant,

    // --- 1. points -------------------------------------------------------------------------------------
    /// Nearest depth kept, metres (paper: 0.1).
    pub depth_min: f32,
    /// Farthest depth kept, metres (paper: 3.0).
    pub depth_max: f32,
    /// Fraction of in-range pixels sampled (paper: 15 %).
    pub sample_rate: f32,
    /// Seed of the sampling hash; the same seed gives the same sample on every machine.
    pub sample_seed: u32,
    /// Draw a new sample for every frame (paper: "randomly sampled"): the hash's pixel index is offset by a hash
    /// of the frame counter ([`Params::sample_frame`]), so each frame keeps other pixels, identically on every
    /// machine. `false`: every frame keeps the same pixels. The first frame's sample is the same either way.
    pub sample_per_frame: bool,
    /// The frame whose sample the passes draw: the number of frames mapped before it. Set by the mapper at the
    /// start of every frame (and kept after it, so that the frame's points can be visited again); not read
    /// from a configuration.
    #[serde(skip)]
    pub sample_frame: u32,

    // --- 2. supervoxels (VCCS) ---------------------------------------------------------------------------
    /// Voxel edge R_voxel, metres (paper: 0.03).
    pub voxel_resolution: f32,
    /// Seed spacing R_seed, metres (paper: 0.65).
    pub seed_resolution: f32,
    /// VCCS colour weight w_c (PCL's example value 0.2; the paper does not say).
    pub color_importance: f32,
    /// VCCS spatial weight w_s (PCL's example value 0.4).
    pub spatial_importance: f32,
    /// VCCS normal weight w_n (PCL's example value 1.0).
    pub normal_importance: f32,
    /// Fewest voxels a seed cell (R_seed cube) must hold to place a seed: sparse cells are left to their
    /// neighbours' growth, as VCCS filters seeds in empty space.
    pub seed_min_voxels: u16,

    // --- 3. IH-GMM refinement ---------------------------------------------------------------------------
    /// A component thicker than this (σ2, metres) is split. 1 cm: well above Kinect noise after 3 cm voxel
    /// averaging, small enough that a box edge or a curved patch is split into flat pieces.
    pub gmm_max_thickness: f32,
    /// Axial depth noise of the sensor, σ(z) = a + b·(z − 0.4 m)², metres (Kinect model of Nguyen et al. 2012:
    /// a = 0.0012 m).
    pub sensor_noise_a: f32,
    /// Quadratic term b of the axial depth noise, 1/m (Kinect: 0.0019).
    pub sensor_noise_b: f32,
    /// The thickness that triggers a split never goes below this many σ(z) at the cluster's mean depth, so far,
    /// noisy surfaces are not shredded into noise-sized pieces.
    pub gmm_noise_sigmas: f32,
    /// A component whose largest principal scale σ0 exceeds this (metres) is split, so each Gaussian stays
    /// local; fusion merges coplanar pieces again.
    pub gmm_max_extent: f32,
    /// A component whose voxel normals spread more than this (point-weighted mean of 1 − |n_v · n̄|, where n̄
    /// is the mean normal) is split: it bends or spans two surfaces (0.05 ≈ a mean deviation of 18°).
    pub gmm_max_normal_spread: f32,
    /// Weight of the normal in the 2-means distance, metres per unit of normal difference:
    /// d² = ‖Δp‖² + (w·‖Δn‖)². 0.1 m lets a 90° fold outweigh 10 cm of distance.
    pub gmm_normal_weight: f32,
    /// Fewest points of a Gaussian: a split that would leave a child smaller than this is not made, and a
    /// supervoxel smaller than this is an outlier cluster (counted, not mapped). 6 rather than 10: junction
    /// pieces (a box edge, the floor-wall fold) of 12–20 points can still split, which keeps every Gaussian
    /// mean within 1 cm of its surface on the synthetic tabletop; it costs +8 % Gaussians on redkitchen.
    pub gmm_min_points: u32,
    /// Deepest binary split (bounds the work per supervoxel).
    pub gmm_max_depth: u8,
    /// Lloyd iterations of each 2-means split.
    pub gmm_kmeans_iters: u8,

    // --- 4. mask annotation -------------------------------------------------------------------------------
    /// Fewest valid projected support points for an annotation (paper: 20).
    pub min_proj_points: u32,
    /// Support ratio ρ that must be exceeded (paper: 0.6).
    pub min_support_ratio: f32,
    /// Smallest detection confidence τ_s of a candidate mask (paper: 0.5).
    pub min_confidence: f32,
    /// Small fragments (an m2smap extension): a Gaussian with fewer than `min_proj_points` points is annotated
    /// when at least this fraction of them lies in one mask. The paper leaves such fragments unannotated; on the
    /// far top face of an object they then stay apart from it as residual GMMs (on the synthetic desk: 13 of 15
    /// residual Gaussians). Above 1.0 restores the paper's rule.
    pub small_fragment_ratio: f32,
    /// Mask-consistent refinement (an m2smap extension; variants with semantic fusion only): a Gaussian whose
    /// support is split between its best mask and the outside, each side holding at least
    /// max(`gmm_min_points`, share · N) points, is cut along the mask boundary (voxel by voxel) before it is
    /// annotated. Without it a patch straddling the mask edge glues object and background points into one
    /// primitive (measured on the cabinet frames: N_adh 0.34 → see README). 1.0 disables it.
    pub mask_split_min_share: f32,

    // --- geometric segmenter (`segment`) ------------------------------------------------------------------
    /// Two neighbouring cells of the segmenter whose normals differ by less than this are joined even across a
    /// concave boundary (sensor noise on a flat or gently curved surface), degrees.
    pub seg_concave_tolerance_deg: f32,
    /// Fewest points of a segmented instance.
    pub seg_min_points: u32,
    /// Largest box diagonal of a segmented instance, metres (larger components are structure: a counter with
    /// its cupboards, a wall).
    pub seg_max_extent: f32,
    /// Confidence given to segmented instances (must reach `min_confidence` to be used).
    pub seg_score: f32,
    /// Smallest largest standard deviation of a flat segmented component that is structure (a table top, a
    /// wall seen between objects), not an object, metres (0.1 m: about 35 cm across).
    pub seg_structure_sigma: f32,

    // --- 5. semantic-constrained fusion -----------------------------------------------------------------
    /// Largest AABB gap d_connect, metres (paper: 0.15).
    pub d_connect: f32,
    /// Largest unsigned normal angle θ_min, degrees (paper: 15).
    pub theta_min_deg: f32,
    /// Largest point-to-plane distance l_min, metres (paper: 0.10).
    pub l_min: f32,

    // --- 6./7. flat planes ------------------------------------------------------------------------------
    /// Fewest points of a plane support N_min (paper: 200).
    pub n_min: u32,
    /// Largest thickness σ2 τ_t, metres (paper: 0.04).
    pub tau_t: f32,
    /// Largest eigenvalue ratio λ2/λ0 τ_λ (paper: 0.02).
    pub tau_lambda: f32,
    /// Smallest principal scales σ0, σ1 τ_s, metres (paper: 0.1125).
    pub tau_s: f32,
    /// Grid of the bounded-plane occupancy g_p, metres (open in the paper; 0.05 m, docs/pipeline.md).
    pub g_p: f32,

    // --- 9. superquadrics --------------------------------------------------------------------------------
    /// Fewest points of an object for an SQ fit (paper: 80).
    pub sq_min_points: u32,
    /// Largest accepted fitting error E_sq (paper: 0.20).
    pub sq_max_error: f32,
    /// Levenberg–Marquardt iterations (paper: 12).
    pub lm_max_iters: u32,
    /// Points sampled for the fit (paper: 100; at most 128).
    pub lm_samples: u32,
    /// Weight w of the size prior w · Σ a_k² added to the LM objective (an m2smap decision, see
    /// `superquadric`): the unseen back of an object is otherwise unconstrained.
    pub sq_scale_prior: f32,
    /// Largest RMS distance of the fit points to an accepted superquadric's surface, metres (an m2smap decision:
    /// E_sq < `sq_max_error` alone accepts shapes whose surface lies decimetres from the points, because E_sq
    /// scales with r² · ‖p̃‖ ≈ d² / R).
    pub sq_max_rms: f32,
    /// Largest shape exponent ε1, ε2 the fit may reach (an m2smap decision; the representable range is
    /// [`crate::superquadric::EPS_RANGE`], [0.1, 1.9]). Above 1 a superquadric pinches: a diamond cross-section
    /// or a double-cone profile, which fits the visible faces of a box seen across a corner as well as the box
    /// does but puts the far corners in observed free space (ycbv_0000's foam brick: ε2 = 1.9, 6.4 % of the
    /// superquadric samples in free space; with 1.3: 1.1 %). 1.3 keeps rounded shapes (ε = 1: ellipses,
    /// cylinders) inside the bounds, so LM is not pinned at the bound there.
    pub sq_eps_max: f32,
    /// Most cold superquadric searches per frame for objects that have a track: its warm start was not
    /// acceptable, or its re-search is due (an m2smap decision, bounding the stage's time per frame; see
    /// `mapper`). Over the budget, such an object shows its track's state when this frame accepts it, else its
    /// Gaussians, and is searched in a later frame. Objects without a track are not rationed here (a refused one
    /// is retried every `track::REFUSAL_RETRY_FRAMES`-th frame).
    pub sq_search_budget: u32,

    // --- 10. tracks ---------------------------------------------------------------------------------------
    /// Largest centre distance for association d_max, metres (paper: 0.35).
    pub d_max: f32,
    /// Centre EMA weight α_c (paper: 0.6).
    pub alpha_c: f32,
    /// Rotation SLERP weight α_R (paper: 0.35).
    pub alpha_r: f32,
    /// Axes and shape EMA weight α_s (paper: 0.35).
    pub alpha_s: f32,
    /// A track not updated for more than this many frames is retired (open in the paper; 10 frames keeps an
    /// object through short occlusions and mask dropouts).
    pub track_max_missed: u32,
    /// A measurement whose half-axes differ from its track's by more than this factor leaves the track
    /// unchanged (outlier gate; open in the paper).
    pub track_scale_gate: f32,

    // --- 11. world map (an m2smap extension, [`crate::world`]) -------------------------------------------
    /// A frame plane joins a world plane when their normals differ by at most this angle, degrees.
    pub world_plane_angle_deg: f32,
    /// … and its centroid lies within this distance of the world plane, metres.
    pub world_plane_offset: f32,
    /// A frame Gaussian merges into a world Gaussian when the squared Mahalanobis distance of their means under
    /// the sum of their covariances is at most this.
    pub world_gmm_gate: f32,
    /// … and the merged Gaussian's total variance (trace of Σ) is at most this factor squared times the larger
    /// of the two (a re-observation merges; a neighbouring patch does not).
    pub world_gmm_growth: f32,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            variant: Variant::Full,
            depth_min: 0.1,
            depth_max: 3.0,
            sample_rate: DEFAULT_SAMPLE_RATE,
            sample_seed: DEFAULT_SAMPLE_SEED,
            sample_per_frame: true,
            sample_frame: 0,
            voxel_resolution: 0.03,
            seed_resolution: 0.65,
            color_importance: 0.2,
            spatial_importance: 0.4,
            normal_importance: 1.0,
            seed_min_voxels: 8,
            gmm_max_thickness: 0.01,
            gmm_max_extent: 0.15,
            sensor_noise_a: 0.0012,
            sensor_noise_b: 0.0019,
            gmm_noise_sigmas: 2.0,
            gmm_max_normal_spread: 0.05,
            gmm_normal_weight: 0.1,
            gmm_min_points: 6,
            gmm_max_depth: 12,
            gmm_kmeans_iters: 6,
            min_proj_points: 20,
            min_support_ratio: 0.6,
            small_fragment_ratio: 0.75,
            min_confidence: 0.5,
            mask_split_min_share: 0.1,
            seg_concave_tolerance_deg: 15.0,
            seg_min_points: 150,
            seg_max_extent: 1.5,
            seg_score: 0.8,
            seg_structure_sigma: 0.1,
            d_connect: 0.15,
            theta_min_deg: 15.0,
            l_min: 0.10,
            n_min: 200,
            tau_t: 0.04,
            tau_lambda: 0.02,
            tau_s: 0.1125,
            g_p: 0.05,
            sq_min_points: 80,
            sq_max_error: 0.20,
            lm_max_iters: 12,
            lm_samples: crate::superquadric::BATCHED_SAMPLES as u32,
            sq_scale_prior: 1e-4,
            sq_eps_max: 1.3,
            sq_search_budget: 1,
            sq_max_rms: 0.02,
            d_max: 0.35,
            alpha_c: 0.6,
            alpha_r: 0.35,
            alpha_s: 0.35,
            track_max_missed: 10,
            track_scale_gate: 1.5,
            world_plane_angle_deg: 10.0,
            world_plane_offset: 0.05,
            world_gmm_gate: 9.0,
            world_gmm_growth: 1.25,
        }
    }
}

/// Largest voxel index along one axis that the packed voxel key holds (see [`crate::supervoxel::voxel_key`]).
pub const VOXEL_GRID_HALF_EXTENT: i32 = 511;

impl Params {
    /// Whether the mask-consistent extensions are on: a variant with [`Variant::extensions`] and
    /// `mask_split_min_share` < 1 (mask slots in the voxels, the mask cut, held-back fragments). PMSAO has them
    /// like `full`: it differs from `full` in post-merge annotation alone.
    pub fn mask_consistent(&self) -> bool {
        self.variant.extensions() && self.mask_split_min_share < 1.0
    }

    /// Axial depth noise σ(z) of the sensor at depth `z`, metres.
    pub fn depth_noise(&self, z: f32) -> f32 {
        let d = z - 0.4;
        self.sensor_noise_a + self.sensor_noise_b * d * d
    }

    /// The depth tolerance at observed depth `z`: max([`DEPTH_TOLERANCE_MIN_M`], [`DEPTH_TOLERANCE_SIGMAS`] ·
    /// σ(z)), metres. A point nearer than the observed surface by more than this is in free space; the fit's
    /// free-space probes and the map-level metrics of the shell use the same tolerance.
    pub fn depth_tolerance(&self, z: f32) -> f32 {
        (DEPTH_TOLERANCE_SIGMAS * self.depth_noise(z)).max(DEPTH_TOLERANCE_MIN_M)
    }

    /// Checks every range; [`crate::Mapper::new`] refuses parameters that fail.
    pub fn validate(&self) -> Result<(), ParamError> {
        fn check(ok: bool, name: &'static str) -> Result<(), ParamError> {
            if ok {
                Ok(())
            } else {
                Err(ParamError::OutOfRange(name))
            }
        }
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let unit = |x: f32| x.is_finite() && (0.0..=1.0).contains(&x);
        check(pos(self.depth_min), "depth_min")?;
        check(pos(self.depth_max) && self.depth_max > self.depth_min, "depth_max")?;
        check(unit(self.sample_rate) && self.sample_rate > 0.0, "sample_rate")?;
        check(pos(self.voxel_resolution), "voxel_resolution")?;
        // z voxel indices must fit the packed key: depth_max / voxel < 1024.
        check(self.depth_max / self.voxel_resolution < VOXEL_GRID_HALF_EXTENT as f32, "voxel_resolution")?;
        check(pos(self.seed_resolution) && self.seed_resolution >= self.voxel_resolution, "seed_resolution")?;
        check(self.color_importance.is_finite() && self.color_importance >= 0.0, "color_importance")?;
        check(self.spatial_importance.is_finite() && self.spatial_importance >= 0.0, "spatial_importance")?;
        check(self.normal_importance.is_finite() && self.normal_importance >= 0.0, "normal_importance")?;
        check(pos(self.gmm_max_thickness), "gmm_max_thickness")?;
        check(pos(self.gmm_max_extent), "gmm_max_extent")?;
        check(unit(self.gmm_max_normal_spread), "gmm_max_normal_spread")?;
        check(self.sensor_noise_a.is_finite() && self.sensor_noise_a >= 0.0, "sensor_noise_a")?;
        check(self.sensor_noise_b.is_finite() && self.sensor_noise_b >= 0.0, "sensor_noise_b")?;
        check(self.gmm_noise_sigmas.is_finite() && self.gmm_noise_sigmas >= 0.0, "gmm_noise_sigmas")?;
        check(self.gmm_normal_weight.is_finite() && self.gmm_normal_weight >= 0.0, "gmm_normal_weight")?;
        check(self.gmm_min_points >= 3, "gmm_min_points")?;
        check(self.gmm_max_depth <= 30, "gmm_max_depth")?;
        check(self.gmm_kmeans_iters >= 1, "gmm_kmeans_iters")?;
        check(unit(self.min_support_ratio), "min_support_ratio")?;
        check(self.small_fragment_ratio.is_finite() && self.small_fragment_ratio > 0.0, "small_fragment_ratio")?;
        check(unit(self.min_confidence), "min_confidence")?;
        check(unit(self.mask_split_min_share), "mask_split_min_share")?;
        check(
            pos(self.seg_concave_tolerance_deg) && self.seg_concave_tolerance_deg < 90.0,
            "seg_concave_tolerance_deg",
        )?;
        check(pos(self.seg_max_extent), "seg_max_extent")?;
        check(unit(self.seg_score), "seg_score")?;
        check(pos(self.seg_structure_sigma), "seg_structure_sigma")?;
        check(pos(self.d_connect), "d_connect")?;
        check(self.theta_min_deg.is_finite() && (0.0..=90.0).contains(&self.theta_min_deg), "theta_min_deg")?;
        check(pos(self.l_min), "l_min")?;
        check(pos(self.tau_t), "tau_t")?;
        check(unit(self.tau_lambda), "tau_lambda")?;
        check(pos(self.tau_s), "tau_s")?;
        check(pos(self.g_p), "g_p")?;
        check(pos(self.sq_max_error), "sq_max_error")?;
        check(self.lm_samples >= 11 && self.lm_samples <= 128, "lm_samples")?;
        check(self.sq_scale_prior.is_finite() && self.sq_scale_prior >= 0.0, "sq_scale_prior")?;
        check(pos(self.sq_max_rms), "sq_max_rms")?;
        let (eps_lo, eps_hi) = crate::superquadric::EPS_RANGE;
        check(
            self.sq_eps_max.is_finite() && self.sq_eps_max >= 1.0 && self.sq_eps_max <= eps_hi && eps_lo < 1.0,
            "sq_eps_max",
        )?;
        check(pos(self.d_max), "d_max")?;
        check(unit(self.alpha_c), "alpha_c")?;
        check(unit(self.alpha_r), "alpha_r")?;
        check(unit(self.alpha_s), "alpha_s")?;
        check(self.track_scale_gate.is_finite() && self.track_scale_gate >= 1.0, "track_scale_gate")?;
        check(pos(self.world_plane_angle_deg) && self.world_plane_angle_deg < 90.0, "world_plane_angle_deg")?;
        check(pos(self.world_plane_offset), "world_plane_offset")?;
        check(self.world_gmm_gate.is_finite() && self.world_gmm_gate >= 0.0, "world_gmm_gate")?;
        check(self.world_gmm_growth.is_finite() && self.world_gmm_growth >= 1.0, "world_gmm_growth")?;
        Ok(())
    }
}
