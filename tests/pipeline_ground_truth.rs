//! Stages 1–3 against ground truth: a procedural frame of planes and boxes with known surfaces per pixel.

use std::collections::{HashMap, HashSet, VecDeque};

use m2smap::synth::{Scene, SynthFrame};
use m2smap_core::supervoxel::{is_assigned, unpack, OUTLIER};
use m2smap_core::{Gaussian, HostStorage, Mapper, Params};

struct Outcome {
    gaussians: Vec<Gaussian>,
    /// Per Gaussian: support points per true surface.
    support: Vec<HashMap<u16, u32>>,
    points: u32,
    outlier_points: u32,
    dropped_points: u32,
    labelled_points: u32,
    /// Supervoxel of each voxel key.
    voxel_labels: HashMap<u32, u16>,
    supervoxels: usize,
}

fn map_frame(scene: &Scene, frame: &SynthFrame) -> Outcome {
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let view = frame.frame.view(&scene.camera);
    let report = *mapper.process(view, None).unwrap();
    let checked = mapper.check(view, None).unwrap();
    let mut support = vec![HashMap::new(); mapper.gaussians().len()];
    let mut labelled_points = 0;
    let w = scene.camera.width as usize;
    mapper.for_each_labelled_point(&checked, |p, v| {
        let v = v.expect("every sampled point has a voxel");
        if is_assigned(v.gaussian) {
            labelled_points += 1;
            let surface = frame.surface[p.v as usize * w + p.u as usize];
            *support[v.gaussian as usize].entry(surface).or_insert(0) += 1;
        } else {
            assert_eq!(v.supervoxel, OUTLIER, "an unlabelled point must be in an outlier cluster");
        }
    });
    Outcome {
        gaussians: mapper.gaussians().to_vec(),
        support,
        points: report.points,
        outlier_points: report.outlier_points,
        dropped_points: report.dropped_points,
        labelled_points,
        voxel_labels: mapper.voxels().iter().map(|v| (v.key, v.supervoxel)).collect(),
        supervoxels: mapper.supervoxels().len(),
    }
}

/// Frames of the tabletop scene: boxes standing apart on a floor before a wall, so every surface can be told
/// apart by geometry alone. (Touching coplanar faces and a slab lying flat on the floor, as in the `shelf`
/// scene, cannot be separated without masks: that is the semantics issue's test.)
fn scenes() -> Vec<(Scene, SynthFrame)> {
    ["tabletop"]
        .iter()
        .flat_map(|name| {
            let scene = Scene::named(name).unwrap();
            [0usize, 7].map(|k| (scene.clone(), scene.render(k, None)))
        })
        .collect()
}

#[test]
fn gaussian_supports_lie_on_one_surface() {
    for (scene, frame) in scenes() {
        let out = map_frame(&scene, &frame);
        let (mut pure_points, mut total) = (0u32, 0u32);
        for (g, counts) in out.support.iter().enumerate() {
            let n: u32 = counts.values().sum();
            let dominant = counts.values().copied().max().unwrap_or(0);
            assert_eq!(n, out.gaussians[g].count, "support count of Gaussian {g}");
            let purity = dominant as f64 / n as f64;
            // A 3 cm voxel straddling a box edge or a box-floor contact carries points of both surfaces into the
            // Gaussian that owns it; such Gaussians stay dominated by one surface.
            // A 3 cm voxel straddling a box edge, a box-floor contact or the floor-wall junction carries points of
            // both surfaces into one Gaussian; only pieces too small to split further may stay mixed.
            if n >= 100 {
                assert!(purity >= 0.8, "{}: Gaussian {g} ({n} points) mixes surfaces {counts:?}", scene.name);
            }
            pure_points += dominant;
            total += n;
        }
        let overall = pure_points as f64 / total as f64;
        println!("{}: {} Gaussians, point-weighted purity {overall:.4}", scene.name, out.gaussians.len());
        assert!(overall >= 0.99, "{}: only {overall:.4} of support points lie on their Gaussian's surface", scene.name);
    }
}

#[test]
fn gaussian_means_lie_on_true_surfaces() {
    for (scene, frame) in scenes() {
        let out = map_frame(&scene, &frame);
        let mut worst = 0.0f64;
        for g in &out.gaussians {
            let m = g.mean.map(f64::from);
            let world = frame.pose.apply(m);
            let d = scene.surfaces.iter().map(|s| s.distance(world)).fold(f64::INFINITY, f64::min);
            worst = worst.max(d);
            assert!(d <= 0.01, "{}: Gaussian mean {m:?} is {d:.4} m from every surface", scene.name);
        }
        println!("{}: worst mean-to-surface distance {worst:.4} m", scene.name);
    }
}

#[test]
fn supports_cover_the_sampled_points() {
    for (scene, frame) in scenes() {
        let out = map_frame(&scene, &frame);
        assert_eq!(out.dropped_points, 0, "the host profile must not drop points on a 640x480 frame");
        assert_eq!(out.labelled_points + out.outlier_points, out.points);
        let sum: u32 = out.gaussians.iter().map(|g| g.count).sum();
        assert_eq!(sum, out.labelled_points, "Gaussian supports must partition the labelled points");
        let outlier_share = out.outlier_points as f64 / out.points as f64;
        assert!(outlier_share < 0.002, "{}: {outlier_share:.4} of points are outliers", scene.name);
    }
}

#[test]
fn supervoxels_are_connected() {
    for (scene, frame) in scenes() {
        let out = map_frame(&scene, &frame);
        let mut members: HashMap<u16, Vec<u32>> = HashMap::new();
        for (&key, &sv) in &out.voxel_labels {
            if is_assigned(sv) {
                members.entry(sv).or_default().push(key);
            }
        }
        assert_eq!(members.len(), out.supervoxels, "every supervoxel has voxels");
        for (sv, keys) in members {
            let set: HashSet<(i32, i32, i32)> = keys.iter().map(|&k| unpack(k)).collect();
            let start = *set.iter().min().unwrap();
            let mut seen = HashSet::from([start]);
            let mut queue = VecDeque::from([start]);
            while let Some((x, y, z)) = queue.pop_front() {
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            let n = (x + dx, y + dy, z + dz);
                            if set.contains(&n) && seen.insert(n) {
                                queue.push_back(n);
                            }
                        }
                    }
                }
            }
            assert_eq!(seen.len(), set.len(), "{}: supervoxel {sv} is not 26-connected", scene.name);
        }
    }
}

#[test]
fn same_input_gives_identical_output() {
    let scene = Scene::named("shelf").unwrap();
    let frame = scene.render(3, Some(9));
    let a = map_frame(&scene, &frame);
    let b = map_frame(&scene, &frame);
    assert_eq!(a.voxel_labels, b.voxel_labels);
    assert_eq!(a.gaussians.len(), b.gaussians.len());
    for (x, y) in a.gaussians.iter().zip(&b.gaussians) {
        let bits = |g: &Gaussian| {
            let mut v: Vec<u32> =
                g.mean.iter().chain(&g.covariance).chain(&g.eigenvalues).map(|f| f.to_bits()).collect();
            v.push(g.count);
            v
        };
        assert_eq!(bits(x), bits(y));
    }
    // A different sensor-noise seed gives a different frame, and so a different result.
    let c = map_frame(&scene, &scene.render(3, Some(10)));
    assert_ne!(a.voxel_labels, c.voxel_labels);
}

#[test]
fn full_pools_drop_and_count_instead_of_panicking() {
    use m2smap_core::{PoolId, Storage};
    // Every pool far too small for a 640x480 frame.
    type Tiny = Storage<300, 512, 4, 3, 5, 8, 1, 1, 1, 128, { 640 * 480 }, 100, 0>;
    let scene = Scene::named("tabletop").unwrap();
    let frame = scene.render(0, Some(2));
    let mut storage = bytemuck::zeroed_box::<Tiny>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    for _ in 0..2 {
        let r = *mapper.process(frame.frame.view(&scene.camera), None).unwrap();
        assert_eq!(r.voxels, 300);
        assert!(r.pool(PoolId::Voxels).overflow_events > 0);
        assert!(r.pool(PoolId::Gaussians).overflow_events + r.pool(PoolId::Supervoxels).overflow_events > 0);
        assert!(r.overflow_events > 0 && r.dropped_points > 0);
        assert!(r.gaussians <= 5 && r.supervoxels <= 3);
        let mapped: u32 = mapper.gaussians().iter().map(|g| g.count).sum();
        assert_eq!(mapped + r.outlier_points + r.dropped_points, r.points, "every point is mapped or accounted for");
    }
}

/// The synthetic tabletop's frame 0 (noise seed 2), which the pool tests below map with short voxel pools.
fn tabletop_frame_zero() -> (Scene, m2smap::synth::SynthFrame) {
    let scene = Scene::named("tabletop").unwrap();
    let frame = scene.render(0, Some(2));
    (scene, frame)
}

/// The report of `view` mapped by a fresh mapper over the host profile's pools (room for every voxel).
fn host_report(view: m2smap_core::Frame<'_>, params: Params) -> m2smap_core::FrameReport {
    let mut host = bytemuck::zeroed_box::<HostStorage>();
    *Mapper::new(&mut *host, params).unwrap().process(view, None).unwrap()
}

#[test]
fn a_full_voxel_pool_maps_the_frame_with_coarser_voxels() {
    use m2smap_core::mapper::{VOXEL_COARSEN, VOXEL_COARSENINGS};
    use m2smap_core::{PoolId, Storage};
    // The tabletop's frame 0 needs more 3 cm voxels than this pool holds (measured below), and fewer than it holds
    // at the coarsest edge: the frame is mapped whole, over the full range, with coarser voxels; no point is lost.
    type Short = Storage<8192, 16384, 1024, 2048, 1024, 2048, 64, 254, 64, 4096, { 640 * 480 }, 65536, 8192>;
    let (scene, frame) = tabletop_frame_zero();
    let view = frame.frame.view(&scene.camera);
    // The frame is mapped twice below: with the first frame's sample each time, as the reference run's.
    let params = Params { sample_per_frame: false, ..Params::default() };
    let full = host_report(view, params);
    assert!(full.voxels > 8192, "the frame needs {} voxels", full.voxels);
    assert_eq!(full.voxel_resolution_m, params.voxel_resolution);
    let coarsest = params.voxel_resolution * VOXEL_COARSEN.powi(VOXEL_COARSENINGS as i32);
    let mut storage = bytemuck::zeroed_box::<Short>();
    let mut mapper = Mapper::new(&mut *storage, params).unwrap();
    for _ in 0..2 {
        let r = *mapper.process(view, None).unwrap();
        assert!(r.voxel_resolution_m > params.voxel_resolution && r.voxel_resolution_m <= coarsest * 1.0001);
        assert_eq!(r.voxel_range_m, params.depth_max, "the full range");
        // The first try's refused inserts are reported; nothing was refused with the voxels kept.
        assert!(r.pool(PoolId::Voxels).overflow_events > 0 && r.voxels <= 8192);
        assert_eq!((r.points, r.dropped_points), (full.points, 0), "every in-range point is in a voxel");
        let mapped: u32 = mapper.gaussians().iter().map(|g| g.count).sum();
        assert_eq!(mapped + r.outlier_points, r.points, "every point is mapped or an outlier");
        // The voxels are the coarser ones: a voxel's centroid (the mean of its points) lies in its cube of the
        // frame's edge (`Mapper::voxel_at` finds it; a centroid rounded onto a cube's face may miss), not of 3 cm.
        let share = |own: &dyn Fn(&m2smap_core::supervoxel::Voxel) -> bool| {
            mapper.voxels().iter().filter(|v| own(v)).count() as f32 / mapper.voxels().len() as f32
        };
        let keyed = |edge: f32| share(&|v| m2smap_core::supervoxel::voxel_key(v.centroid(), edge, 0) == Some(v.key));
        assert!(keyed(r.voxel_resolution_m) > 0.99 && keyed(params.voxel_resolution) < 0.5);
        // `Mapper::voxel_at` looks the voxels up with the frame's edge.
        let looked_up = share(&|v| mapper.voxel_at(v.centroid(), 0).is_some_and(|found| found.key == v.key));
        assert!(looked_up > 0.99, "{looked_up}");
        assert_eq!(mapper.params().voxel_resolution, params.voxel_resolution, "the configured edge is back");
    }
}

#[test]
fn a_full_voxel_pool_drops_the_farthest_points() {
    use m2smap_core::mapper::VOXEL_RANGE_CUT;
    use m2smap_core::{PoolId, Storage};
    // The tabletop's frame 0 needs more voxels over the full range than this pool holds even at the coarsest
    // edge (measured below), and they fit over a nearer one: the frame is mapped over that range, whole, and the
    // far points are the lost ones.
    type Short = Storage<2048, 4096, 1024, 2048, 1024, 2048, 64, 254, 64, 4096, { 640 * 480 }, 65536, 2048>;
    let (scene, frame) = tabletop_frame_zero();
    let view = frame.frame.view(&scene.camera);
    // The frame is mapped twice below: with the first frame's sample each time, as the reference run's.
    let params = Params { sample_per_frame: false, ..Params::default() };
    let full = host_report(view, params);
    assert!(full.voxels > 2048, "the frame needs {} voxels", full.voxels);
    assert_eq!(full.voxel_range_m, params.depth_max);
    let mut storage = bytemuck::zeroed_box::<Short>();
    let mut mapper = Mapper::new(&mut *storage, params).unwrap();
    for _ in 0..2 {
        let r = *mapper.process(view, None).unwrap();
        let range = r.voxel_range_m;
        assert!(range < params.depth_max && range >= params.depth_max * VOXEL_RANGE_CUT.powi(8), "range {range}");
        // The full range's refused inserts are reported; nothing was refused over the range kept.
        assert!(r.pool(PoolId::Voxels).overflow_events > 0 && r.voxels <= 2048);
        assert_eq!(r.points, full.points, "the in-range points of the configured range");
        let far = mapper.voxels().iter().map(|v| v.centroid()[2]).fold(0.0f32, f32::max);
        assert!(far <= range, "a voxel at {far} m beyond the range {range} m");
        // Every later stage saw the same range: each point is mapped, an outlier, or dropped (beyond it).
        let mapped: u32 = mapper.gaussians().iter().map(|g| g.count).sum();
        assert_eq!(mapped + r.outlier_points + r.dropped_points, r.points, "every point is accounted for");
        assert_eq!(mapper.params().depth_max, params.depth_max, "the configured range is back after the frame");
    }
}

/// Voxelisation's list of sampled points and the voxel links only spare the later passes work: a mapper whose
/// profile lists the points and links the voxels and one that samples and looks them up again give the same
/// maps byte for byte, frame after frame (tracks carry over), with masks, on a frame mapped over a cut depth
/// range, and with a list and links too short for the frame.
#[test]
fn listing_points_and_linking_voxels_changes_no_map() {
    use m2smap::masks::LabelTable;
    use m2smap_core::{PoolId, Profile, Storage};
    // The host profile's pools without the list and the links; and with both too short for these frames.
    type Unlisted = Storage<32768, 65536, 1024, 2048, 4096, 8192, 64, 254, 64, 4096, { 1280 * 1024 }, 0, 0>;
    type ShortList = Storage<32768, 65536, 1024, 2048, 4096, 8192, 64, 254, 64, 4096, { 1280 * 1024 }, 4096, 4096>;
    // The range-cut profile of `a_full_voxel_pool_drops_the_farthest_points`, with and without list and links.
    type CutListed = Storage<2048, 4096, 1024, 2048, 1024, 2048, 64, 254, 64, 4096, { 640 * 480 }, 65536, 2048>;
    type CutUnlisted = Storage<2048, 4096, 1024, 2048, 1024, 2048, 64, 254, 64, 4096, { 640 * 480 }, 0, 0>;
    fn maps<P: Profile + bytemuck::Zeroable>(scene: &Scene, masked: bool) -> (Vec<Vec<u8>>, Vec<(bool, bool)>) {
        let mut storage = bytemuck::zeroed_box::<P>();
        let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
        let (mut out, mut listed) = (Vec::new(), Vec::new());
        for k in 0..4 {
            let frame = scene.render(k, Some(3));
            let masks = masked.then(|| scene.perfect_masks(&frame, &mut LabelTable::default()));
            let view = frame.frame.view(&scene.camera);
            let r = *mapper.process(view, masks.as_ref().map(|m| m.view())).unwrap();
            // A list or links that do not fit are no lost data: not in the frame's overflow events.
            let others: u32 = PoolId::ALL
                .iter()
                .filter(|&&id| !matches!(id, PoolId::SampledPoints | PoolId::VoxelLinks))
                .map(|&id| r.pool(id).overflow_events)
                .sum();
            assert_eq!(r.overflow_events, others);
            // Whether the frame's passes went by a complete list, and whether its range was cut.
            let list = r.pool(PoolId::SampledPoints);
            let cut = r.voxel_range_m < mapper.params().depth_max;
            // (Over a cut range the list holds fewer points than the frame has in its configured range.)
            let complete = list.capacity > 0 && list.overflow_events == 0 && list.peak > 0;
            let linked = r.pool(PoolId::VoxelLinks).peak as u32 == r.voxels && r.voxels > 0;
            listed.push((complete && linked, cut));
            if !cut {
                assert!(!complete || list.peak as u32 == r.points);
                assert_eq!(
                    mapper.sampled_points(&view).is_some(),
                    complete,
                    "the list serves the frame's later users too"
                );
            }
            let mut buf = vec![0u8; 1 << 20];
            let n = mapper.encode_map(&mut buf).unwrap();
            out.push(buf[..n].to_vec());
        }
        (out, listed)
    }
    for (name, masked) in [("clutter", true), ("kitchen", true), ("tabletop", false)] {
        let scene = Scene::named(name).unwrap();
        let (listed, on) = maps::<HostStorage>(&scene, masked);
        let (unlisted, off) = maps::<Unlisted>(&scene, masked);
        let (short, short_on) = maps::<ShortList>(&scene, masked);
        let complete = |v: &[(bool, bool)]| v.iter().map(|x| x.0).collect::<Vec<_>>();
        assert_eq!(
            (complete(&on), complete(&off), complete(&short_on)),
            (vec![true; 4], vec![false; 4], vec![false; 4])
        );
        assert!(listed.iter().all(|m| m.len() > 100), "{name}: maps of {:?} bytes", listed.iter().map(Vec::len));
        assert_eq!(listed, unlisted, "{name}: listed and sampled again");
        assert_eq!(short, unlisted, "{name}: a list too short");
    }
    // The tabletop needs more voxels than this profile holds: its frames are mapped over a cut range.
    let scene = Scene::named("tabletop").unwrap();
    let (cut, cut_on) = maps::<CutListed>(&scene, false);
    assert!(cut_on.iter().all(|&(complete, cut)| complete && cut), "{cut_on:?}");
    assert_eq!(cut, maps::<CutUnlisted>(&scene, false).0, "a cut range");
}
