//! The method variants differ in what they say they change: `paper` is `full` without m2smap's four extensions
//! (mask slots, the mask cut, held-back uncertain fragments, annotated small fragments), and `pmsao` is `full`
//! with post-merge annotation (fusion ignores instance ids) and nothing else. Checked on synthetic frames with
//! perfect masks, against the ground-truth instance image.

use m2smap::eval::semantic_metrics;
use m2smap::masks::LabelTable;
use m2smap::synth::Scene;
use m2smap_core::{HostStorage, Mapper, Params, Variant};

/// (N_adh, primitives) of one frame of `scene` mapped by `variant`.
fn map(scene: &Scene, k: usize, variant: Variant) -> (u32, usize) {
    let frame = scene.render(k, Some(7));
    let mut storage = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params { variant, ..Params::default() }).unwrap();
    let masks = scene.perfect_masks(&frame, &mut LabelTable::default());
    let view = frame.frame.view(&scene.camera);
    mapper.process(view, Some(masks.view())).unwrap();
    let checked = mapper.check(view, Some(masks.view())).unwrap();
    let gt = scene.instance_image(&frame);
    let w = scene.camera.width as usize;
    let metrics = semantic_metrics(&mapper, &checked, |u, v| gt[v as usize * w + u as usize]);
    let mut primitives = 0;
    mapper.for_each_primitive(|_| primitives += 1);
    (metrics.n_adh, primitives)
}

#[test]
fn the_switches_of_each_variant() {
    for v in Variant::ALL {
        let p = Params { variant: v, ..Params::default() };
        let annotating = matches!(v, Variant::Full | Variant::Paper | Variant::Pmsao | Variant::Wsqa);
        assert_eq!(v.annotates(), annotating, "{}", v.name());
        assert_eq!(v.extensions(), annotating && v != Variant::Paper, "{}", v.name());
        assert_eq!(p.mask_consistent(), v.extensions(), "{}", v.name());
        assert_eq!(Variant::from_name(v.name()), Some(v));
    }
    // `paper` and `pmsao` each differ from `full` in one thing.
    let (full, paper, pmsao) = (Variant::Full, Variant::Paper, Variant::Pmsao);
    assert!(
        paper.semantic_fusion() && paper.superquadrics() && paper.aligns() && paper.planes() && !paper.extensions()
    );
    assert!(!pmsao.semantic_fusion() && pmsao.extensions() && pmsao.superquadrics() && pmsao.aligns());
    assert!(full.semantic_fusion() && full.extensions());
}

/// Without the extensions, objects glue to what they touch: `paper` has adhesion where `full` has none, and
/// more primitives (the pieces that straddle a mask edge).
#[test]
fn the_extensions_keep_objects_apart() {
    for name in ["clutter", "shelf", "kitchen"] {
        let scene = Scene::named(name).unwrap();
        let (mut full, mut paper) = ((0, 0), (0, 0));
        for k in [0, 6] {
            let (a, b) = (map(&scene, k, Variant::Full), map(&scene, k, Variant::Paper));
            full = (full.0 + a.0, full.1 + a.1);
            paper = (paper.0 + b.0, paper.1 + b.1);
        }
        assert_eq!(full.0, 0, "{name}: full N_adh");
        assert!(paper.0 >= 1, "{name}: paper N_adh {} (the paper's rules glue objects here)", paper.0);
        assert!(paper.1 > full.1, "{name}: primitives paper {} vs full {}", paper.1, full.1);
    }
}
