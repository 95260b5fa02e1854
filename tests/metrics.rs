//! Reconstruction metrics (SPEC §4) on synthetic frames whose truth is known.

use m2smap::eval::reconstruction_metrics;
use m2smap::synth::Scene;
use m2smap_core::{HostStorage, Mapper, Params, Variant};

#[test]
fn g2r_and_r2g_measure_how_well_a_map_fits_its_frame() {
    let scene = Scene::named("tabletop").unwrap();
    for k in [0usize, 5] {
        let frame = scene.render(k, Some(2));
        // Gaussians only: every sample lies within 2σ of its Gaussian's support.
        let mut storage = bytemuck::zeroed_box::<HostStorage>();
        let mut mapper = Mapper::new(&mut *storage, Params { variant: Variant::Mmog, ..Params::default() }).unwrap();
        let view = frame.frame.view(&scene.camera);
        let report = *mapper.process(view, None).unwrap();
        let checked = mapper.check(view, None).unwrap();
        let m = reconstruction_metrics(&mapper, &checked).unwrap();
        println!("frame {k}: G2R {:.4} m, R2G {:.4} m ({} observed, {} reconstructed)", m.g2r_rmse_m, m.r2g_rmse_m, m.observed, m.reconstructed);
        assert_eq!(m.observed as u32, report.points, "P is every sampled, range-filtered point");
        assert!(m.g2r_rmse_m > 0.0 && m.g2r_rmse_m <= 0.015, "G2R {:.4} m", m.g2r_rmse_m);
        assert!(m.r2g_rmse_m > m.g2r_rmse_m && m.r2g_rmse_m <= 0.06, "R2G {:.4} m", m.r2g_rmse_m);
        // The same map judged against a later frame's points (the camera moved): clearly worse.
        let other = scene.render(k + 3, Some(2));
        let checked_other = mapper.check(other.frame.view(&scene.camera), None).unwrap();
        let moved = reconstruction_metrics(&mapper, &checked_other).unwrap();
        assert!(moved.g2r_rmse_m > 2.0 * m.g2r_rmse_m, "a stale map must score worse: {:.4}", moved.g2r_rmse_m);
    }
}
