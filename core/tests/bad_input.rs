//! Every malformed frame, mask set or parameter gives an error value, never a panic, and a rejected frame
//! leaves the mapper's results as they were.

use m2smap_core::{
    Frame, FrameError, HostStorage, Instance, Intrinsics, Mapper, MaskError, MaskPixels, MaskSet, McuStorage,
    ParamError, Params,
};

const W: u16 = 64;
const H: u16 = 48;
const K: Intrinsics = Intrinsics { fx: 50.0, fy: 50.0, cx: 32.0, cy: 24.0 };

/// A tilted plane: depth varies smoothly from 1.0 m to about 1.5 m.
fn plane_depth() -> Vec<u16> {
    (0..H as usize * W as usize).map(|i| 5000 + (i % W as usize) as u16 * 40 + (i / W as usize) as u16 * 10).collect()
}

fn frame<'a>(depth: &'a [u16], colour: &'a [u8]) -> Frame<'a> {
    Frame { width: W, height: H, depth, depth_scale: 5000.0, colour, intrinsics: K, pose: None }
}

fn with_mapper(f: impl FnOnce(&mut Mapper<'_>)) {
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    f(&mut mapper);
}

#[test]
fn malformed_frames_are_errors() {
    let depth = plane_depth();
    let colour = vec![128u8; depth.len() * 3];
    with_mapper(|m| {
        let good = frame(&depth, &colour);
        assert!(m.process(good, None).is_ok());

        let short = &depth[..depth.len() - 1];
        assert_eq!(
            m.process(frame(short, &colour), None).unwrap_err(),
            FrameError::DepthLength { expected: depth.len(), found: depth.len() - 1 }
        );
        assert!(matches!(m.process(frame(&depth, &colour[1..]), None), Err(FrameError::ColourLength { .. })));
        for bad in [
            Intrinsics { fx: 0.0, ..K },
            Intrinsics { fy: -1.0, ..K },
            Intrinsics { fx: f32::NAN, ..K },
            Intrinsics { cx: f32::INFINITY, ..K },
        ] {
            let f = Frame { intrinsics: bad, ..good };
            assert_eq!(m.process(f, None).unwrap_err(), FrameError::BadIntrinsics);
        }
        for scale in [0.0, -5000.0, f32::NAN] {
            assert_eq!(m.process(Frame { depth_scale: scale, ..good }, None).unwrap_err(), FrameError::BadDepthScale);
        }
        let zeros = vec![0u16; depth.len()];
        assert_eq!(m.process(frame(&zeros, &colour), None).unwrap_err(), FrameError::NoValidDepth);
        let far = vec![60_000u16; depth.len()]; // 12 m: outside [0.1, 3.0]
        assert_eq!(m.process(frame(&far, &colour), None).unwrap_err(), FrameError::NoValidDepth);
        let stuck = vec![7000u16; depth.len()];
        assert_eq!(m.process(frame(&stuck, &colour), None).unwrap_err(), FrameError::ConstantDepth { raw: 7000 });
        use m2smap_core::Pose;
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(m
            .process(Frame { pose: Some(Pose { rotation: identity, translation: [1.0, 2.0, 3.0] }), ..good }, None)
            .is_ok());
        for bad in [
            Pose { rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]], translation: [0.0; 3] }, // a reflection
            Pose { rotation: [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [0.0; 3] },
            Pose { rotation: identity, translation: [f32::NAN, 0.0, 0.0] },
        ] {
            assert_eq!(m.process(Frame { pose: Some(bad), ..good }, None).unwrap_err(), FrameError::BadPose);
        }
        let empty = Frame { width: 0, height: 0, depth: &[], colour: &[], ..good };
        assert_eq!(m.process(empty, None).unwrap_err(), FrameError::EmptyFrame);
    });
}

#[test]
fn frames_larger_than_the_profile_are_refused() {
    let mut storage = bytemuck::zeroed_box::<McuStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let (w, h) = (800u16, 600u16);
    let depth = vec![5000u16; w as usize * h as usize];
    let colour = vec![0u8; depth.len() * 3];
    let f =
        Frame { width: w, height: h, depth: &depth, depth_scale: 5000.0, colour: &colour, intrinsics: K, pose: None };
    assert_eq!(mapper.process(f, None).unwrap_err(), FrameError::TooLarge { pixels: 480_000, max_pixels: 640 * 480 });
}

#[test]
fn a_rejected_frame_leaves_the_results_as_they_were() {
    let depth = plane_depth();
    let colour = vec![90u8; depth.len() * 3];
    with_mapper(|m| {
        let report = *m.process(frame(&depth, &colour), None).unwrap();
        assert!(report.gaussians > 0);
        let gaussians = m.gaussians().to_vec();
        let zeros = vec![0u16; depth.len()];
        assert!(m.process(frame(&zeros, &colour), None).is_err());
        assert_eq!(*m.report(), report);
        assert_eq!(m.gaussians(), &gaussians[..]);
    });
}

#[test]
fn malformed_masks_are_errors() {
    let depth = plane_depth();
    let colour = vec![90u8; depth.len() * 3];
    let ids = vec![0u16; depth.len()];
    let inst = Instance { id: 1, class: 0, score: 0.9, bbox: [0, 0, 10, 10] };
    with_mapper(|m| {
        let f = frame(&depth, &colour);
        let ok = [inst];
        let set = |instances| MaskSet { width: W, height: H, instances, pixels: MaskPixels::IdImage(&ids) };
        assert!(m.process(f, Some(set(&ok))).is_ok());
        let cases = [
            (vec![Instance { score: 1.5, ..inst }], MaskError::BadScore { id: 1 }),
            (vec![Instance { score: f32::NAN, ..inst }], MaskError::BadScore { id: 1 }),
            (vec![Instance { bbox: [0, 0, W, 5], ..inst }], MaskError::BadBox { id: 1 }),
            (vec![Instance { bbox: [5, 0, 4, 5], ..inst }], MaskError::BadBox { id: 1 }),
            (vec![inst, inst], MaskError::DuplicateId { id: 1 }),
            (vec![Instance { id: 0, ..inst }], MaskError::ReservedId),
        ];
        for (instances, err) in &cases {
            assert_eq!(m.process(f, Some(set(instances))).unwrap_err(), FrameError::Masks(*err));
        }
        let wrong_size = MaskSet { width: W - 1, ..set(&ok) };
        assert!(matches!(m.process(f, Some(wrong_size)), Err(FrameError::Masks(MaskError::SizeMismatch { .. }))));
        let short = MaskSet { pixels: MaskPixels::IdImage(&ids[1..]), ..set(&ok) };
        assert!(matches!(m.process(f, Some(short)), Err(FrameError::Masks(MaskError::PixelLength { .. }))));
    });
}

#[test]
fn mask_pixel_tests_cover_both_layouts_and_overlaps() {
    let (w, h) = (16u16, 4u16);
    let mut ids = vec![0u16; 64];
    ids[5] = 2;
    let instances = [
        Instance { id: 2, class: 0, score: 0.8, bbox: [0, 0, 15, 3] },
        Instance { id: 3, class: 1, score: 0.7, bbox: [0, 0, 15, 3] },
    ];
    let by_id = MaskSet { width: w, height: h, instances: &instances, pixels: MaskPixels::IdImage(&ids) };
    assert!(by_id.contains(0, 5, 0) && !by_id.contains(1, 5, 0) && !by_id.contains(0, 6, 0));
    assert!(!by_id.contains(0, 16, 0) && !by_id.contains(5, 5, 0), "out of range is never inside");
    // Bit planes: pixel 5 in both instances (overlap), pixel 20 only in the second.
    let plane = MaskSet::plane_bytes(w, h);
    let mut bits = vec![0u8; plane * 2];
    bits[0] |= 1 << 5;
    bits[plane] |= 1 << 5;
    bits[plane + 2] |= 1 << 4;
    let planes = MaskSet { width: w, height: h, instances: &instances, pixels: MaskPixels::BitPlanes(&bits) };
    assert!(planes.validate(w, h).is_ok());
    assert!(planes.contains(0, 5, 0) && planes.contains(1, 5, 0));
    assert!(!planes.contains(0, 4, 1) && planes.contains(1, 4, 1));
}

#[test]
fn out_of_range_parameters_are_refused() {
    let mut storage = bytemuck::zeroed_box::<McuStorage>();
    let bad = [
        (Params { depth_max: 0.05, ..Params::default() }, "depth_max"),
        (Params { sample_rate: 0.0, ..Params::default() }, "sample_rate"),
        (Params { voxel_resolution: f32::NAN, ..Params::default() }, "voxel_resolution"),
        (Params { voxel_resolution: 0.001, ..Params::default() }, "voxel_resolution"),
        (Params { gmm_min_points: 1, ..Params::default() }, "gmm_min_points"),
        (Params { alpha_c: 1.5, ..Params::default() }, "alpha_c"),
    ];
    for (p, name) in bad {
        assert_eq!(Mapper::new(&mut *storage, p).err(), Some(ParamError::OutOfRange(name)));
    }
}
