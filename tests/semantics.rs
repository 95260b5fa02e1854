//! Stages 4–8 against ground truth: annotation, semantic fusion, flat planes and bounded planes on synthetic
//! scenes with perfect masks (the ground-truth instance images).

use m2smap::eval::{fusion_metrics, semantic_metrics};
use m2smap::masks::LabelTable;
use m2smap::synth::{Scene, SynthFrame};
use m2smap_core::gmm::{ROLE_OBJECT, ROLE_PLANE};
use m2smap_core::supervoxel::{is_assigned, Revisit};
use m2smap_core::{HostStorage, Mapper, Params, Variant};

/// Per-frame facts the tests check.
struct Mapped {
    n_adh: u32,
    a_s: Option<f64>,
    /// Points of instance `id` (ground truth) by the role of their Gaussian: (plane, object with that id, other).
    roles_of: Box<dyn Fn(u16) -> (u32, u32, u32)>,
    planes: usize,
}

fn map(scene: &Scene, frame: &SynthFrame, variant: Variant, with_masks: bool) -> Mapped {
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params { variant, ..Params::default() }).unwrap();
    let masks = scene.perfect_masks(frame, &mut LabelTable::default());
    let view = frame.frame.view(&scene.camera);
    let m = with_masks.then(|| masks.view());
    mapper.process(view, m).unwrap();
    let checked = mapper.check(view, m).unwrap();
    let gt = scene.instance_image(frame);
    let w = scene.camera.width as usize;
    let metrics = semantic_metrics(&mapper, &checked, |u, v| gt[v as usize * w + u as usize]);
    let mut samples = Vec::new();
    mapper.for_each_labelled_point(&checked, |p, v| {
        if let Some(g) = v.filter(|v| is_assigned(v.gaussian)).and_then(|v| mapper.gaussians().get(v.gaussian as usize))
        {
            samples.push((gt[p.v as usize * w + p.u as usize], g.role, g.instance));
        }
    });
    Mapped {
        n_adh: metrics.n_adh,
        a_s: metrics.a_s,
        planes: mapper.planes().len(),
        roles_of: Box::new(move |id| {
            let mut r = (0, 0, 0);
            for &(label, role, inst) in samples.iter().filter(|s| s.0 == id) {
                match role {
                    ROLE_PLANE => r.0 += 1,
                    ROLE_OBJECT if inst == id => r.1 += 1,
                    _ => r.2 += 1,
                }
                let _ = label;
            }
            r
        }),
    }
}

fn desk_frames() -> Vec<(Scene, SynthFrame)> {
    let scene = Scene::named("desk").unwrap();
    [0usize, 5].iter().map(|&k| (scene.clone(), scene.render(k, Some(4)))).collect()
}

#[test]
fn full_fusion_keeps_objects_off_the_floor_and_geometry_only_glues_them() {
    for (scene, frame) in desk_frames() {
        let full = map(&scene, &frame, Variant::Full, true);
        assert_eq!(full.n_adh, 0, "full must not glue objects to the floor or to each other");
        assert_eq!(full.a_s, Some(1.0), "every multi-Gaussian cluster of full has one dominant label");
        let pmsao = map(&scene, &frame, Variant::Pmsao, true);
        assert!(pmsao.n_adh > 0, "geometry-only fusion glues the board and the low box to the floor");
        // The low box (8 cm, instance 2): its top lies within l_min of the floor plane.
        let (plane, object, _) = (full.roles_of)(2);
        // Only edge voxels (3 cm, half floor) may go to the floor: at most 5 % of the box's points.
        assert!(plane * 20 <= plane + object, "full: {plane} of {} low-box points became floor plane", plane + object);
        let (plane_p, _, _) = (pmsao.roles_of)(2);
        assert!(plane_p > 5 * plane.max(1), "pmsao: the low box's top should be swallowed by the floor ({plane_p})");
    }
}

/// Objects pressed against each other and against their support (clutter: a bin, a ball and a pouf against a
/// crate, a book on it; kitchen: a ball against a mug, a cushion against a box, all on a table top): with
/// masks, mask slots keep every voxel and Gaussian on one side of a contact line, so `full` glues nothing;
/// geometry-only fusion glues them.
#[test]
fn touching_objects_stay_apart_with_masks() {
    // Frames where 3 cm voxels straddle a contact line (found with the slots switched off: each then has an
    // adhesion case in `full`).
    for (name, frames) in [("clutter", [3usize, 4].as_slice()), ("kitchen", [8, 13, 14].as_slice())] {
        let scene = Scene::named(name).unwrap();
        let (mut full_adh, mut pmsao_adh) = (0, 0);
        for &k in frames {
            let frame = scene.render(k, Some(1));
            let full = map(&scene, &frame, Variant::Full, true);
            assert_eq!(full.a_s, Some(1.0), "{name} frame {k}: a cluster of full mixes labels");
            full_adh += full.n_adh;
            pmsao_adh += map(&scene, &frame, Variant::Pmsao, true).n_adh;
        }
        assert_eq!(full_adh, 0, "{name}: full glued touching objects");
        assert!(pmsao_adh >= 3, "{name}: geometry-only fusion should glue them ({pmsao_adh})");
    }
}

#[test]
fn a_thin_object_with_a_mask_is_not_a_flat_plane() {
    for (scene, frame) in desk_frames() {
        // The board (instance 1, 64 x 52 x 2 cm) is plane-sized: σ0, σ1 > τ_s and σ2 ≈ 6 mm.
        let with = map(&scene, &frame, Variant::Full, true);
        let (plane, object, other) = (with.roles_of)(1);
        let total = plane + object + other;
        assert!(total > 500, "the board must be well visible ({total} points)");
        assert!(object as f64 >= 0.9 * total as f64, "with its mask the board is an object: {plane}/{object}/{other}");
        // Only its rim (voxels shared with the floor 2 cm below) may go to the floor plane.
        assert!(plane as f64 <= 0.05 * total as f64, "with its mask the board is not plane support: {plane}/{total}");
        let without = map(&scene, &frame, Variant::Full, false);
        let (plane, _, _) = (without.roles_of)(1);
        assert!(plane as f64 >= 0.5 * total as f64, "without a mask the same board is plane support: {plane}/{total}");
        assert!(without.planes >= 1);
    }
}

#[test]
fn bounded_planes_cover_the_visible_floor_and_no_unobserved_cell() {
    use std::collections::HashSet;
    let scene = Scene::named("tabletop").unwrap();
    for k in [0usize, 6] {
        let frame = scene.render(k, None);
        let mut storage = bytemuck::zeroed_box::<HostStorage>();
        let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
        let masks = scene.perfect_masks(&frame, &mut LabelTable::default());
        let view = frame.frame.view(&scene.camera);
        mapper.process(view, Some(masks.view())).unwrap();
        let checked = mapper.check(view, Some(masks.view())).unwrap();
        let planes = mapper.planes().to_vec();
        let g_p = mapper.params().g_p;
        // The floor plane: normal along world z.
        let up = |n: [f32; 3]| {
            let r = frame.pose.rotation();
            (r[2][0] * n[0] as f64 + r[2][1] * n[1] as f64 + r[2][2] * n[2] as f64).abs()
        };
        let floor = planes.iter().position(|p| up(p.normal) > 0.99).expect("the floor is a plane");
        let mut cells_from_points = vec![HashSet::new(); planes.len()];
        let (mut floor_points, mut covered) = (0u32, 0u32);
        let w = scene.camera.width as usize;
        mapper.for_each_labelled_point(&checked, |p, v| {
            let g = v.filter(|v| is_assigned(v.gaussian)).and_then(|v| mapper.gaussians().get(v.gaussian as usize));
            if let Some(g) = g.filter(|g| g.role == ROLE_PLANE) {
                if let Some(c) = planes[g.owner as usize].cell_of(p.xyz, g_p) {
                    cells_from_points[g.owner as usize].insert(c);
                }
            }
            if frame.surface[p.v as usize * w + p.u as usize] == 1 {
                floor_points += 1;
                if planes[floor].cell_of(p.xyz, g_p).is_some_and(|(a, b)| planes[floor].is_occupied(a, b)) {
                    covered += 1;
                }
            }
        });
        for (i, plane) in planes.iter().enumerate() {
            let mut occupied = HashSet::new();
            for b in 0..m2smap_core::plane::PLANE_GRID {
                for a in 0..m2smap_core::plane::PLANE_GRID {
                    if plane.is_occupied(a, b) {
                        occupied.insert((a, b));
                    }
                }
            }
            assert_eq!(occupied.len(), plane.occupied as usize);
            // Cells are marked per support voxel (its centroid's r/4 square): a cell may miss the few points
            // of a voxel centred next door, or take a voxel's next to the cell its points fell in, but never
            // more than one cell away from support.
            let support = &cells_from_points[i];
            let near_support = |&(a, b): &(usize, usize)| {
                (a.saturating_sub(1)..=a + 1).any(|x| (b.saturating_sub(1)..=b + 1).any(|y| support.contains(&(x, y))))
            };
            assert!(occupied.iter().all(near_support), "plane {i}: an occupied cell lies off its support");
            let held = occupied.intersection(support).count() as f64;
            let (recall, precision) = (held / support.len() as f64, held / occupied.len() as f64);
            println!(
                "frame {k} plane {i}: {} cells, {} with support points; recall {recall:.3}, precision {precision:.3}",
                occupied.len(),
                support.len()
            );
            assert!(
                recall >= 0.95 && precision >= 0.95,
                "plane {i}: cells against support: recall {recall:.3}, precision {precision:.3}"
            );
            let mut worst = 0.0f64;
            plane.for_each_cell_centre(g_p, |c| {
                let world = frame.pose.apply(c.map(f64::from));
                let d = scene.surfaces.iter().map(|s| s.distance(world)).fold(f64::INFINITY, f64::min);
                worst = worst.max(d);
            });
            assert!(worst <= 0.01, "plane {i}: a representative point lies {worst:.4} m off every true surface");
        }
        let coverage = covered as f64 / floor_points as f64;
        println!("frame {k}: {} planes, floor coverage {coverage:.3}", planes.len());
        assert!(coverage >= 0.9, "the floor plane covers only {coverage:.3} of the visible floor's points");
    }
}

/// N_adh and A_s counted by hand on hand-built clusters (the counting that `semantic_metrics` does after it has
/// tallied each Gaussian's points per reference label; label 0 = no object). A label is "strong" in a cluster
/// when it holds ≥ max(20, ⌈10 % of the cluster's points⌉); N_adh counts the clusters with ≥ 2 strong labels,
/// one of them an object; A_s is, among clusters of ≥ 2 Gaussians, the share whose Gaussians all have the same
/// dominant label (most points; a tie goes to the smaller label).
#[test]
fn adhesion_and_semantic_consistency_counted_by_hand() {
    use std::collections::HashMap;
    let g = |pairs: &[(u16, u32)]| pairs.iter().copied().collect::<HashMap<u16, u32>>();
    let gaussians: Vec<(u16, HashMap<u16, u32>)> = vec![
        // Cluster 1: floor {0: 100} + box {3: 50, 0: 5}: 155 points, threshold max(20, ⌈15.5⌉) = 20; strong 0
        // (105) and 3 (50) → adhesion. Dominants 0 and 3 → inconsistent.
        (1, g(&[(0, 100)])),
        (1, g(&[(3, 50), (0, 5)])),
        // Cluster 2: {5: 100} + {5: 31, 6: 19}: 150 points, 10 % = 15 but the floor is 20: label 6 (19 points,
        // 12.7 %) is not strong → no adhesion. Dominants 5, 5 → consistent.
        (2, g(&[(5, 100)])),
        (2, g(&[(5, 31), (6, 19)])),
        // Cluster 3: one Gaussian {7: 60, 8: 40}: 100 points, threshold 20; 7 and 8 strong → adhesion. A single
        // Gaussian: not counted by A_s.
        (3, g(&[(7, 60), (8, 40)])),
        // Cluster 4: {9: 360} + {10: 40}: 400 points, threshold ⌈40⌉ = 40; label 10 holds exactly 40 → strong →
        // adhesion. Dominants 9 and 10 → inconsistent.
        (4, g(&[(9, 360)])),
        (4, g(&[(10, 40)])),
        // Cluster 5: {2: 30, 4: 30} (a tie: dominant 2, the smaller label) + {2: 50}: 110 points, threshold 20;
        // 2 (80) and 4 (30) strong → adhesion. Dominants 2, 2 → consistent.
        (5, g(&[(2, 30), (4, 30)])),
        (5, g(&[(2, 50)])),
        // Cluster 6: {11: 400} + {11: 60, 0: 39}: 499 points, threshold ⌈49.9⌉ = 50; label 0 (39 points: above the
        // 20-point floor, under 10 %) is not strong → no adhesion. Dominants 11, 11 → consistent.
        (6, g(&[(11, 400)])),
        (6, g(&[(11, 60), (0, 39)])),
    ];
    let m = fusion_metrics(gaussians.iter().map(|(c, counts)| (*c, counts)));
    // N_adh: clusters 1, 3, 4, 5 = 4. Multi-Gaussian clusters: 1, 2, 4, 5, 6 = 5; consistent: 2, 5, 6 → A_s = 3/5.
    assert_eq!(m.n_adh, 4);
    assert_eq!(m.multi_gaussian_clusters, 5);
    assert_eq!(m.a_s, Some(0.6));
    // The order of the Gaussians does not matter.
    let m_rev = fusion_metrics(gaussians.iter().rev().map(|(c, counts)| (*c, counts)));
    assert_eq!(m_rev, m);
    // One more point for label 6 in cluster 2 makes it strong (20 ≥ max(20, ⌈15.1⌉)): a fifth adhesion case;
    // the dominants stay 5, 5.
    let mut more = gaussians.clone();
    *more[3].1.get_mut(&6).unwrap() += 1;
    let m = fusion_metrics(more.iter().map(|(c, counts)| (*c, counts)));
    assert_eq!((m.n_adh, m.a_s), (5, Some(0.6)));
    // Breaking cluster 5's tie the other way (label 4 dominant in its first Gaussian) makes it inconsistent: 2/5.
    let mut tie = gaussians.clone();
    *tie[7].1.get_mut(&4).unwrap() += 1;
    let m = fusion_metrics(tie.iter().map(|(c, counts)| (*c, counts)));
    assert_eq!((m.n_adh, m.a_s), (4, Some(0.4)));
    // No multi-Gaussian cluster: A_s is undefined; no clusters at all: nothing to count.
    let m = fusion_metrics(gaussians[4..5].iter().map(|(c, counts)| (*c, counts)));
    assert_eq!((m.n_adh, m.a_s, m.multi_gaussian_clusters), (1, None, 0));
    assert_eq!(fusion_metrics(std::iter::empty()), Default::default());
}

/// The instances of id-image masks as bit planes: disjoint, and overlapping (instance 0 also covers instance
/// 1's pixels).
fn bit_plane_masks(ids_masks: &m2smap::masks::FrameMasks) -> (m2smap::masks::FrameMasks, m2smap::masks::FrameMasks) {
    use m2smap::masks::{FrameMasks, Pixels};
    let Pixels::Ids(ids) = &ids_masks.pixels else { panic!("the masks are an id image") };
    let plane = m2smap_core::MaskSet::plane_bytes(ids_masks.width, ids_masks.height);
    let mut bits = vec![0u8; plane * ids_masks.instances.len()];
    for (k, inst) in ids_masks.instances.iter().enumerate() {
        for (i, _) in ids.iter().enumerate().filter(|(_, &id)| id == inst.id) {
            bits[k * plane + i / 8] |= 1 << (i % 8);
        }
    }
    let disjoint = FrameMasks { pixels: Pixels::Bits(bits.clone()), ..ids_masks.clone() };
    let (first, rest) = bits.split_at_mut(plane);
    first.iter_mut().zip(&rest[..plane]).for_each(|(a, b)| *a |= b);
    (disjoint, FrameMasks { pixels: Pixels::Bits(bits), ..ids_masks.clone() })
}

/// A pass that samples the points again finds each point's voxel by its cube first and looks its mask slot up
/// only where several slots' voxels share the cube (`Revisit::Resampled { by_cube: true }`): the same voxel for
/// every point as the lookup by slot, with masks as an id image and as overlapping bit planes; and voxelisation
/// without a list of the points (the mcu profile's) marks a voxel as sharing its cube exactly when another voxel
/// has the same cube.
#[test]
fn points_found_by_cube_are_in_the_voxels_of_their_mask_slot() {
    use bytemuck::Zeroable;
    use m2smap_core::pool::Bounded;
    use m2smap_core::supervoxel::{for_each_voxel_point, unpack, voxelize, Voxel};
    for name in ["tabletop", "clutter", "kitchen"] {
        let scene = Scene::named(name).unwrap();
        let frame = scene.render(0, Some(1));
        let ids_masks = scene.perfect_masks(&frame, &mut LabelTable::default());
        let (_, overlapping) = bit_plane_masks(&ids_masks);
        for masks in [&ids_masks, &overlapping] {
            // Voxelised without a list of the points (as the mcu profile), so the shared cubes are marked.
            let params = Params::default();
            let view = masks.view();
            let depth = frame.frame.view(&scene.camera);
            let (mut voxel_store, mut slots) = (vec![Voxel::zeroed(); 40_000], vec![0u16; 1 << 17]);
            let mut voxel_pool = Bounded::new(&mut voxel_store);
            let mut no_list = Bounded::new(&mut []);
            let stats = voxelize(&depth, &params, Some(&view), &mut voxel_pool, &mut slots, &mut no_list);
            assert_eq!((stats.dropped_points, stats.unplaced_points), (0, 0), "{name}");
            assert!(stats.shared_cubes_marked, "{name}");
            let voxels = voxel_pool.as_slice();
            let cube = |key: u32| {
                let (x, y, z) = unpack(key);
                (x, y, z)
            };
            let mut shared = 0;
            for (i, v) in voxels.iter().enumerate() {
                let others = voxels.iter().enumerate().any(|(j, o)| j != i && cube(o.key) == cube(v.key));
                assert_eq!(v.shares_cube(), others, "{name}: voxel {i}");
                shared += others as usize;
            }
            assert!(shared >= 20, "{name}: {shared} voxels share their cube");
            let visit = |by_cube: bool| {
                let mut seen = Vec::new();
                let revisit = Revisit::Resampled { by_cube };
                for_each_voxel_point(&depth, &params, Some(&view), voxels, &slots, revisit, |p, v| {
                    seen.push((p.u, p.v, v.map(|(i, _)| i)))
                });
                seen
            };
            let (by_slot, by_cube) = (visit(false), visit(true));
            assert!(by_slot.len() > 5000, "{name}: {} points", by_slot.len());
            assert!(by_slot.iter().all(|&(_, _, v)| v.is_some()), "{name}: every point has its voxel");
            assert_eq!(by_cube.len(), by_slot.len(), "{name}");
            let differ = by_cube.iter().zip(&by_slot).filter(|(a, b)| a != b).count();
            let first = by_cube.iter().zip(&by_slot).find(|(a, b)| a != b);
            assert_eq!(differ, 0, "{name}: {differ} points in other voxels, the first {first:?}");
        }
    }
}

/// The annotation stage counts mask hits from the voxels where the voxels were split by the masks, and those
/// counts are the pixel pass's, pair for pair: perfect masks as an id image and as disjoint bit planes, every
/// instance cut into four bands (more instances than the 7 mask slots: a slot's voxels are given to
/// an instance by the boxes), the same halves with boxes too small for their pixels (boxes cannot decide; the
/// voxels whose slot holds more than one usable instance are counted point by point; trusting them would
/// miscount where the instances of a slot trade boxes), and bit planes where one
/// mask also covers its neighbour's pixels (the pixel pass).
#[test]
fn mask_hits_from_voxels_are_the_pixel_counts() {
    use m2smap::masks::{FrameMasks, Pixels};
    use m2smap_core::annotate::{count_hits, hits_of, MaskHit};
    for name in ["tabletop", "clutter", "kitchen"] {
        let scene = Scene::named(name).unwrap();
        let frame = scene.render(0, Some(1));
        let ids_masks = scene.perfect_masks(&frame, &mut LabelTable::default());
        let Pixels::Ids(ids) = &ids_masks.pixels else { panic!("perfect masks are an id image") };
        let width = ids_masks.width as usize;
        let (disjoint, overlapping) = bit_plane_masks(&ids_masks);
        // Every instance in four column bands of its box (ids 4a … 4a + 3), boxes from the pixels.
        let mut band_ids = ids.clone();
        let mut band_instances: Vec<m2smap_core::Instance> = Vec::new();
        for inst in &ids_masks.instances {
            let (x0, span) = (inst.bbox[0] as usize, (inst.bbox[2] - inst.bbox[0]) as usize + 1);
            for band in 0..4u16 {
                let id = 4 * inst.id + band;
                let mut bbox = [u16::MAX, u16::MAX, 0, 0];
                for (i, &a) in ids.iter().enumerate() {
                    let (u, v) = ((i % width) as u16, (i / width) as u16);
                    if a == inst.id && ((u as usize - x0) * 4 / span) as u16 == band {
                        band_ids[i] = id;
                        bbox = [bbox[0].min(u), bbox[1].min(v), bbox[2].max(u), bbox[3].max(v)];
                    }
                }
                if bbox[0] <= bbox[2] {
                    band_instances.push(m2smap_core::Instance { id, bbox, ..*inst });
                }
            }
        }
        assert!(band_instances.len() > 7, "{name}: {} bands", band_instances.len());
        let bands = FrameMasks { instances: band_instances, pixels: Pixels::Ids(band_ids), ..ids_masks.clone() };
        // The same bands with every box 4 pixels short at its right edge (a mask beyond its box).
        let mut short = bands.clone();
        for inst in &mut short.instances {
            inst.bbox[2] = inst.bbox[2].saturating_sub(4).max(inst.bbox[0]);
        }
        // The same bands with the boxes of bands k and k + 7 (the same slot) traded, k mod 14 < 7.
        let mut swapped = bands.clone();
        for k in (0..bands.instances.len()).filter(|k| k % 14 < 7 && k + 7 < bands.instances.len()) {
            swapped.instances[k].bbox = bands.instances[k + 7].bbox;
            swapped.instances[k + 7].bbox = bands.instances[k].bbox;
        }
        let few = ids_masks.instances.len() <= 7;
        for (masks, shortcut, within) in [
            (&ids_masks, true, true),
            (&disjoint, few, false),
            (&overlapping, false, false),
            (&bands, true, true),
            (&short, true, false),
            (&swapped, true, false),
        ] {
            let mut storage = bytemuck::zeroed_box::<HostStorage>();
            let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
            let view = frame.frame.view(&scene.camera);
            let checked = mapper.check(view, Some(masks.view())).unwrap();
            mapper.stage_voxels(&checked);
            mapper.stage_supervoxels();
            mapper.stage_gaussians(&checked);
            assert_eq!(mapper.masks_within_boxes(), within, "{name}: masks within their boxes");
            let split = masks.view();
            // The same masks under another instance list: the pixel pass.
            let copied = masks.instances.clone();
            let by_pixels_masks = m2smap_core::MaskSet { instances: &copied, ..split };
            let params = *mapper.params();
            let zero = <MaskHit as bytemuck::Zeroable>::zeroed();
            let (mut fast, mut slow) = (vec![zero; 4096], vec![zero; 4096]);
            let args = (checked.frame(), mapper.voxels(), mapper.voxel_slots(), mapper.gaussians());
            // The fast count revisits the points from voxelisation's list, the pixel pass samples them again.
            let listed = mapper.sampled_points(checked.frame());
            assert!(listed.is_some(), "{name}: the host profile lists the sampled points");
            let listed = Revisit::Listed(listed.unwrap());
            let a =
                count_hits(args.0, &split, Some(&split), within, args.1, args.2, listed, args.3, &mut fast, &params);
            let b = count_hits(
                args.0,
                &by_pixels_masks,
                Some(&split),
                within,
                args.1,
                args.2,
                Revisit::Resampled { by_cube: false },
                args.3,
                &mut slow,
                &params,
            );
            assert_eq!(a.by_voxels, shortcut, "{name}: shortcut taken");
            assert!(!b.by_voxels);
            let mut inside = 0;
            for g in 0..mapper.gaussians().len() {
                for k in 0..masks.instances.len() {
                    assert_eq!(hits_of(&fast, g, k), hits_of(&slow, g, k), "{name}: Gaussian {g}, instance {k}");
                    inside += hits_of(&slow, g, k);
                }
            }
            assert!(inside > 500, "{name}: {inside} points inside masks");
            assert_eq!((a.hit_pairs, a.hit_overflows), (b.hit_pairs, b.hit_overflows));
            // Boxes that do not hold their masks must not be trusted: with traded boxes they would miscount.
            if std::ptr::eq(masks, &swapped) {
                let mut wrong = vec![zero; 4096];
                count_hits(
                    args.0,
                    &split,
                    Some(&split),
                    true,
                    args.1,
                    args.2,
                    Revisit::Resampled { by_cube: false },
                    args.3,
                    &mut wrong,
                    &params,
                );
                let differs = (0..mapper.gaussians().len())
                    .any(|g| (0..masks.instances.len()).any(|k| hits_of(&wrong, g, k) != hits_of(&slow, g, k)));
                assert!(differs, "{name}: traded boxes, trusted, count as the pixel pass does");
            }
        }
    }
}
