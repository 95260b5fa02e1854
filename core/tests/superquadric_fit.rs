//! Superquadric fitting against known shapes: box-like, cylinder-like and ellipsoids, seen from the camera
//! (only the camera-facing half), with depth noise.

use m2smap_core::linalg::{self, Mat3, Vec3};
use m2smap_core::superquadric::{fit, Evidence, Superquadric};
use m2smap_core::Params;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }
    fn normal(&mut self) -> f32 {
        let (u1, u2) = (self.next().max(1e-7), self.next());
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    }
}

/// Camera-facing surface points of `sq`: directions from the centre projected radially onto F = 1 (F is
/// homogeneous), kept where the outward normal faces the camera at the origin; `noise` metres along the ray.
fn visible_points(sq: &Superquadric, n: usize, noise: f32, rng: &mut Rng) -> Vec<Vec3> {
    let mut out = Vec::new();
    while out.len() < n {
        let d = linalg::normalize_or([rng.normal(), rng.normal(), rng.normal()], [0.0, 0.0, 1.0]);
        let f = sq.implicit(d);
        let l = linalg::scale(d, f.powf(-sq.eps[0] / 2.0));
        // Outward normal: numerical gradient of F at the local point.
        let h = 1e-4;
        let g = [0, 1, 2].map(|k| {
            let mut a = l;
            a[k] += h;
            let mut b = l;
            b[k] -= h;
            sq.implicit(a) - sq.implicit(b)
        });
        let p = linalg::add(sq.centre, linalg::mat_vec(&sq.rotation, l));
        let n_cam = linalg::mat_vec(&sq.rotation, g);
        if linalg::dot(n_cam, p) >= 0.0 {
            continue; // faces away from the camera
        }
        let ray = linalg::normalize_or(p, [0.0, 0.0, 1.0]);
        out.push(linalg::add(p, linalg::scale(ray, noise * rng.normal())));
    }
    out
}

fn pca(points: &[Vec3]) -> Mat3 {
    let mut m = linalg::Moments::about(points[0]);
    for &p in points {
        m.add(p, 1.0);
    }
    let e = linalg::sym_eigen(m.covariance());
    linalg::from_columns(e.vectors[0], e.vectors[1], e.vectors[2])
}

fn random_sq(rng: &mut Rng, eps: [f32; 2]) -> Superquadric {
    let r = [rng.range(-3.0, 3.0), rng.range(-3.0, 3.0), rng.range(-3.0, 3.0)];
    Superquadric {
        scales: [rng.range(0.08, 0.35), rng.range(0.08, 0.35), rng.range(0.08, 0.35)],
        eps,
        centre: [rng.range(-0.3, 0.3), rng.range(-0.2, 0.2), rng.range(1.3, 2.2)],
        rotation: linalg::rotation_from_vector(r),
    }
}

#[test]
fn fits_known_shapes_from_their_visible_half() {
    let params = Params::default();
    let mut rng = Rng(0x9e3779b97f4a7c15);
    let mut results = Vec::new();
    for case in 0..90 {
        let kind = case % 3;
        let eps = match kind {
            0 => [rng.range(0.1, 0.3), rng.range(0.1, 0.3)], // box-like
            1 => [rng.range(0.1, 0.3), 1.0],                 // cylinder-like
            _ => [1.0, 1.0],                                 // ellipsoid
        };
        let truth = random_sq(&mut rng, eps);
        let all = visible_points(&truth, 1500, 0.002, &mut rng);
        let frame = pca(&all);
        let sample: Vec<Vec3> = all.iter().step_by(all.len() / params.lm_samples as usize).copied().take(100).collect();
        let f = fit(&sample, &frame, &Evidence::default(), &params).expect("enough points");
        let centre_err = linalg::norm(linalg::sub(f.sq.centre, truth.centre));
        let mut a = f.sq.scales;
        let mut b = truth.scales;
        a.sort_by(f32::total_cmp);
        b.sort_by(f32::total_cmp);
        let axis_err = (0..3).map(|k| (a[k] - b[k]).abs() / b[k]).fold(0.0f32, f32::max);
        let ok = centre_err <= 0.01 && axis_err <= 0.10;
        if !ok {
            println!("case {case} kind {kind}: centre {centre_err:.4} m, axes {axis_err:.3}, E {:.2e}", f.error);
        }
        results.push((kind, ok, f.accepted));
    }
    for kind in 0..3 {
        let of_kind: Vec<_> = results.iter().filter(|r| r.0 == kind).collect();
        let ok = of_kind.iter().filter(|r| r.1).count() as f64 / of_kind.len() as f64;
        let accepted = of_kind.iter().filter(|r| r.2).count() as f64 / of_kind.len() as f64;
        println!("kind {kind}: {ok:.2} within tolerance, {accepted:.2} accepted");
    }
    let ok = results.iter().filter(|r| r.1).count() as f64 / results.len() as f64;
    assert!(ok >= 0.9, "only {ok:.2} of random cases within 1 cm / 10 %");
    assert!(results.iter().filter(|r| r.2).count() as f64 >= 0.9 * results.len() as f64, "fits must be accepted");
}

/// MMQ fits ellipsoids only: ε stays exactly (1, 1) for every shape, ellipsoids are recovered like in the full
/// fit, and a box-like shape is fitted no better than an ellipsoid can (its E_sq exceeds the full fit's).
#[test]
fn mmq_fits_ellipsoids_only() {
    let full = Params::default();
    let mmq = Params { variant: m2smap_core::Variant::Mmq, ..Params::default() };
    let mut rng = Rng(0x2545f4914f6cdd1d);
    let (mut ellipsoids_ok, mut boxes_worse) = (0, 0);
    for case in 0..20 {
        let is_box = case % 2 == 1;
        let truth = random_sq(&mut rng, if is_box { [0.15, 0.15] } else { [1.0, 1.0] });
        let all = visible_points(&truth, 1500, 0.002, &mut rng);
        let frame = pca(&all);
        let sample: Vec<Vec3> = all.iter().step_by(all.len() / 100).copied().take(100).collect();
        let f = fit(&sample, &frame, &Evidence::default(), &mmq).expect("enough points");
        assert_eq!(f.sq.eps, [1.0, 1.0], "case {case}: MMQ must keep ε1 = ε2 = 1");
        if is_box {
            let g = fit(&sample, &frame, &Evidence::default(), &full).expect("enough points");
            boxes_worse += (f.error > g.error) as u32;
        } else {
            let centre_err = linalg::norm(linalg::sub(f.sq.centre, truth.centre));
            let (mut a, mut b) = (f.sq.scales, truth.scales);
            a.sort_by(f32::total_cmp);
            b.sort_by(f32::total_cmp);
            let axis_err = (0..3).map(|k| (a[k] - b[k]).abs() / b[k]).fold(0.0f32, f32::max);
            ellipsoids_ok += (centre_err <= 0.01 && axis_err <= 0.10 && f.accepted) as u32;
        }
    }
    assert!(ellipsoids_ok >= 9, "only {ellipsoids_ok}/10 ellipsoids recovered within 1 cm / 10 %");
    assert!(boxes_worse >= 9, "only {boxes_worse}/10 boxes fitted worse by an ellipsoid than by a superquadric");
}

/// A box resting on a table is fitted resting on it: its lowest point within 2 mm of the table's plane (at most
/// the acceptance's 5 mm below) and its height within 3 % (or 3 mm) of the box's. The LM's support term is
/// one-sided at the plane itself: a clearance kept above it (3 mm until this test) lifted boxes off their
/// tables and shortened them (ycbv_0000's 2.8 cm gelatin box was fitted 2.1–2.3 cm thick).
#[test]
fn a_box_on_a_table_is_fitted_resting_on_it() {
    use m2smap_core::superquadric::HalfSpace;
    let params = Params::default();
    let mut rng = Rng(0x2545f4914f6cdd1d);
    // The camera looks level; the table top is 45 cm below its axis (camera y points down), so every box shows
    // its top and one or two sides. Boxes turn about the vertical only.
    let table = HalfSpace { normal: [0.0, -1.0, 0.0], offset: -0.45 };
    for case in 0..12 {
        let scales = [rng.range(0.05, 0.18), rng.range(0.04, 0.15), rng.range(0.05, 0.18)];
        let yaw = rng.range(-1.5, 1.5);
        let centre = [rng.range(-0.3, 0.3), 0.45 - scales[1], rng.range(1.1, 1.8)];
        let sq =
            Superquadric { scales, eps: [0.1, 0.1], centre, rotation: linalg::rotation_from_vector([0.0, yaw, 0.0]) };
        let points = visible_points(&sq, 100, 0.002, &mut rng);
        let evidence = Evidence { supports: std::slice::from_ref(&table), ..Evidence::default() };
        let f = fit(&points, &pca(&points), &evidence, &params).expect("enough points");
        let above = f.sq.lowest_along(table.normal) - table.offset;
        let height = f.sq.support(table.normal) - f.sq.lowest_along(table.normal);
        let what = format!("case {case}: box {scales:?}, fit {:?} ε {:?}", f.sq.scales, f.sq.eps);
        assert!((-0.005..=0.002).contains(&above), "{what}: lowest point {:.1} mm above the table", above * 1e3);
        let truth = 2.0 * scales[1];
        assert!((height - truth).abs() <= (0.03 * truth).max(0.003), "{what}: height {height:.4} m, box {truth:.4} m");
    }
}
