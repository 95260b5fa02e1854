//! Golden fixtures made by the project: the Gaussians of fixed synthetic frames, digested bit for bit.
//! A change that moves any output bit fails here; if the change is intended, re-bless with
//! `M2SMAP_BLESS=1 cargo test --release --test golden` and say why in the commit message.

use std::fmt::Write;

use m2smap::synth::Scene;
use m2smap_core::{Gaussian, Mapper, McuStorage, Params};

/// FNV-1a (64 bit) over bytes.
fn fnv1a64(bytes: impl IntoIterator<Item = u8>) -> u64 {
    bytes.into_iter().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
}

fn gaussian_bytes(g: &Gaussian) -> Vec<u8> {
    let floats = g.mean.iter().chain(&g.covariance).chain(&g.eigenvalues).chain(g.axes.iter().flatten());
    let floats = floats.chain(&g.bbox_min).chain(&g.bbox_max);
    let mut out: Vec<u8> = floats.flat_map(|f| f.to_le_bytes()).collect();
    out.extend(g.count.to_le_bytes());
    out.extend(g.colour);
    out.extend(g.supervoxel.to_le_bytes());
    out
}

fn describe(scene: &str, frame: usize, noise_seed: u32) -> String {
    let scene = Scene::named(scene).unwrap();
    let f = scene.render(frame, Some(noise_seed));
    let mut storage = bytemuck::zeroed_box::<McuStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let r = *mapper.process(f.frame.view(&scene.camera), None).unwrap();
    let mut s = String::new();
    writeln!(s, "points {} voxels {} supervoxels {} gaussians {} outliers {}", r.points, r.voxels, r.supervoxels, r.gaussians, r.outlier_points).unwrap();
    writeln!(s, "overflow_events {} dropped_points {}", r.overflow_events, r.dropped_points).unwrap();
    writeln!(s, "digest {:016x}", fnv1a64(mapper.gaussians().iter().flat_map(gaussian_bytes))).unwrap();
    s
}

#[test]
fn synthetic_frames_match_their_golden_fixtures() {
    for (scene, frame, seed) in [("tabletop", 0, 1), ("shelf", 5, 2)] {
        let path = format!("{}/../fixtures/golden/{scene}_{frame}_seed{seed}_mcu.txt", env!("CARGO_MANIFEST_DIR"));
        let got = describe(scene, frame, seed);
        if std::env::var("M2SMAP_BLESS").is_ok_and(|v| v == "1") {
            std::fs::write(&path, &got).unwrap();
            continue;
        }
        let want = std::fs::read_to_string(&path).unwrap_or_else(|_| panic!("{path} missing: bless it"));
        assert_eq!(got, want, "{scene} frame {frame} differs from {path}");
    }
}
