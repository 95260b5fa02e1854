//! `m2smap eval`: a small report regenerated from two synthetic scenes; its structure, and every number in its
//! tables against the runs' summary.json.

mod common;

use std::collections::HashMap;
use std::fs;
use std::path::Path;

use common::m2smap;
use m2smap::report::{method_name, ABLATION, COMPARED};
use m2smap_core::Variant;

fn summary(out: &Path, dataset: &str, v: Variant) -> serde_json::Value {
    let path = out.join(dataset).join(v.name()).join("summary.json");
    serde_json::from_str(&fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// The number as the report prints it.
fn fmt(x: &serde_json::Value) -> String {
    x.as_f64().map_or_else(|| "–".to_string(), |x| format!("{x:.3}"))
}

/// A length as the report prints it (0.1 mm).
fn fmt_m(x: &serde_json::Value) -> String {
    x.as_f64().map_or_else(|| "–".to_string(), |x| format!("{x:.4}"))
}

/// The rows of the table that follows `heading`: first cell → (dataset cell → remaining cells).
fn table(md: &str, heading: &str) -> HashMap<(String, String), Vec<String>> {
    let start = md.find(heading).unwrap_or_else(|| panic!("report has no {heading:?}"));
    let mut rows = HashMap::new();
    let mut in_table = false;
    for line in md[start..].lines().skip(1) {
        if line.starts_with('|') {
            in_table = true;
            let cells: Vec<String> = line.trim_matches('|').split('|').map(|c| c.trim().to_string()).collect();
            if cells[0] == "Method" || cells[0].starts_with("---") {
                continue;
            }
            rows.insert((cells[0].clone(), cells[1].clone()), cells[2..].to_vec());
        } else if in_table {
            break;
        }
    }
    rows
}

#[test]
fn eval_writes_a_report_whose_numbers_are_the_runs() {
    let dir = tempfile::tempdir().unwrap();
    let mut datasets = Vec::new();
    for scene in ["desk", "tabletop"] {
        let path = dir.path().join(scene);
        let o = m2smap(&["synth", "--scene", scene, "--frames", "2", "--seed", "3", "--out", path.to_str().unwrap()]);
        assert!(o.status.success(), "synth: {}", String::from_utf8_lossy(&o.stderr));
        datasets.push(path);
    }
    let out = dir.path().join("eval");
    let mut args = vec!["eval"];
    args.extend(datasets.iter().map(|p| p.to_str().unwrap()));
    args.extend(["--out", out.to_str().unwrap()]);
    let o = m2smap(&args);
    assert!(o.status.success(), "eval: {}", String::from_utf8_lossy(&o.stderr));
    let md = fs::read_to_string(out.join("report.md")).unwrap();

    // Table I: one row per compared method and dataset; the numbers are summary.json's; exactly one bold total
    // per dataset, on the lowest total.
    let t1 = table(&md, "## Table I");
    assert_eq!(t1.len(), COMPARED.len() * 2, "Table I rows");
    for name in ["desk", "tabletop"] {
        let mut bold = Vec::new();
        let mut lowest = f64::INFINITY;
        for v in COMPARED {
            let s = summary(&out, name, v);
            let row = &t1[&(method_name(v).to_string(), name.to_string())];
            let p = &s["primitives"];
            let (sq, q) =
                if v == Variant::Mmq { ("0.000".into(), fmt(&p["sq"])) } else { (fmt(&p["sq"]), "0.000".into()) };
            assert_eq!(row[0], fmt(&p["plane"]), "{name} {v:?} planes");
            assert_eq!(row[1], sq, "{name} {v:?} SQ");
            assert_eq!(row[2], fmt(&p["gmm"]), "{name} {v:?} GMM");
            assert_eq!(row[3], q, "{name} {v:?} quadrics");
            assert_eq!(row[4].trim_matches('*'), fmt(&p["total"]), "{name} {v:?} total");
            if row[4].starts_with("**") {
                bold.push(v);
            }
            lowest = lowest.min(p["total"].as_f64().unwrap());
            // The parts add up to the total.
            let parts: f64 = ["plane", "sq", "gmm"].iter().map(|k| p[k].as_f64().unwrap()).sum();
            assert!((parts - p["total"].as_f64().unwrap()).abs() < 1e-9);
        }
        assert_eq!(bold.len(), 1, "{name}: one bold total");
        assert_eq!(summary(&out, name, bold[0])["primitives"]["total"].as_f64().unwrap(), lowest);
    }
    // MMOG has only Gaussians; MMP no quadrics; only MMQ's quadrics are ellipsoids.
    assert_eq!(t1[&("MMOG".into(), "desk".into())][0], "0.000");
    assert_eq!(t1[&("MMP".into(), "desk".into())][3], "0.000");

    // Table II: the ablation rows against summary.json.
    let t2 = table(&md, "## Table II");
    assert_eq!(t2.len(), ABLATION.len() * 2, "Table II rows");
    for name in ["desk", "tabletop"] {
        for v in ABLATION {
            let s = summary(&out, name, v);
            let row = &t2[&(method_name(v).to_string(), name.to_string())];
            let keys = ["r_c", "ms_per_frame_median", "a_s", "n_adh", "j_sq_deg"];
            for (cell, k) in row.iter().zip(keys) {
                assert_eq!(*cell, fmt(&s[k]), "{name} {v:?} {k}");
            }
        }
    }
    // The full method with perfect masks never glues objects together, against ground truth.
    assert_eq!(summary(&out, "desk", Variant::Full)["n_adh"].as_f64(), Some(0.0));

    // The targets table: one row per dataset with ground truth, each verdict the summary's.
    let start = md.find("## Targets").expect("a targets section");
    let rows: Vec<Vec<String>> = md[start..]
        .lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2)
        .map(|l| l.trim_matches('|').split('|').map(|c| c.trim().to_string()).collect())
        .collect();
    assert_eq!(rows.len(), 2, "one targets row per synthetic dataset");
    for row in rows {
        let full = summary(&out, &row[0], Variant::Full);
        let pmsao = summary(&out, &row[0], Variant::Pmsao);
        let yes = |ok: bool| if ok { "yes" } else { "**no**" };
        assert_eq!(row[1], yes(full["n_adh"].as_f64() == Some(0.0)));
        assert_eq!(row[2], yes(full["a_s"].as_f64().is_some_and(|a| a >= 1.0)));
        assert_eq!(row[3], yes(pmsao["n_adh"].as_f64().is_some_and(|n| n > 0.0)));
        assert!(row[4].starts_with(yes(full["g2r_rmse_m"].as_f64().is_some_and(|g| g <= 0.025))));
    }

    // The reconstruction table and the figure.
    let t3 = table(&md, "## Reconstruction and payload");
    assert_eq!(t3.len(), Variant::ALL.len() * 2);
    for v in Variant::ALL {
        let s = summary(&out, "tabletop", v);
        let row = &t3[&(method_name(v).to_string(), "tabletop".to_string())];
        for (cell, k) in row.iter().zip([
            "g2r_rmse_m",
            "g2r_unoccluded_rmse_m",
            "r2g_rmse_m",
            "payload_bytes",
            "bytes_per_primitive",
            "hz",
        ]) {
            let expected = if k.ends_with("_m") { fmt_m(&s[k]) } else { fmt(&s[k]) };
            assert_eq!(*cell, expected, "tabletop {v:?} {k}");
        }
    }
    // The map-level metrics: every cell is summary.json's; the synthetic sets have ground truth, so every
    // column is filled except the superquadric ones of the variants without superquadrics.
    let t4 = table(&md, "## Map-level metrics");
    assert_eq!(t4.len(), Variant::ALL.len() * 2);
    let keys = common::MAP_LEVEL_KEYS;
    for name in ["desk", "tabletop"] {
        for v in Variant::ALL {
            let s = summary(&out, name, v);
            let row = &t4[&(method_name(v).to_string(), name.to_string())];
            // The map-level keys, then the share of superquadric sizes within tolerance (summary only).
            assert_eq!(row.len(), keys.len() + 1);
            for (cell, k) in row.iter().zip(keys.iter().chain(["sq_sizes_within_tolerance"].iter())) {
                let expected = if k.ends_with("_m") { fmt_m(&s[k]) } else { fmt(&s[k]) };
                assert_eq!(*cell, expected, "{name} {v:?} {k}");
            }
        }
    }
    // The SQ-size column needs objects with a published size (YCB labels): none on the synthetic sets.
    let full = &t4[&("M2-SMap".to_string(), "desk".to_string())];
    let (size, rest) = full.split_last().unwrap();
    assert!(rest.iter().all(|c| c != "–"), "full on desk: {full:?}");
    assert_eq!(size, "–");
    let mmog = &t4[&("MMOG".to_string(), "desk".to_string())];
    assert_eq!((mmog[1].as_str(), mmog[6].as_str(), mmog[10].as_str()), ("–", "–", "–"), "MMOG has no superquadric");
    assert_eq!(mmog[2], "0.000");

    // The instance masks: the dataset's (perfect on synthetic sets) and the geometric segmenter's, each row
    // summary.json's.
    let t5 = table(&md, "## Instance masks");
    for name in ["desk", "tabletop"] {
        let own = &t5[&(name.to_string(), "dataset".to_string())];
        assert_eq!(&own[..3], ["1.000", "1.000", "1.000"], "{name}: perfect masks");
        let path = out.join(name).join("full-segmenter").join("summary.json");
        let seg: serde_json::Value = serde_json::from_str(&fs::read_to_string(path).unwrap()).unwrap();
        let row = &t5[&(name.to_string(), "geometric segmenter".to_string())];
        for (cell, k) in row.iter().zip([
            "mask_recall",
            "mask_precision",
            "mask_mean_iou",
            "r2g_rmse_m",
            "adhesion_map",
            "mask_precision_all",
        ]) {
            let expected = if k.ends_with("_m") { fmt_m(&seg[k]) } else { fmt(&seg[k]) };
            assert_eq!(*cell, expected, "{name} segmenter {k}");
        }
        assert!(seg["mask_recall"].as_f64().is_some(), "{name}: the segmenter's recall is computed");
    }

    let png = image::open(out.join("comparison.png")).unwrap();
    assert_eq!((png.width(), png.height()), m2smap::report::FIGURE_SIZE);
    let svg = fs::read_to_string(out.join("comparison.svg")).unwrap();
    for label in ["G2R RMSE", "R2G RMSE", "payload", "M2-SMap", "MMQ", "MMP", "MMOG", "desk", "tabletop"] {
        assert!(svg.contains(label), "figure lacks {label:?}");
    }
    // A figure with bars: more than one colour in the PNG.
    let rgb = png.to_rgb8();
    let red = rgb.pixels().filter(|p| p.0 == [214, 69, 65]).count();
    assert!(red > 1000, "M2-SMap bars missing ({red} pixels)");
}

#[test]
fn eval_refuses_a_missing_dataset_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope");
    let o = m2smap(&["eval", missing.to_str().unwrap(), "--out", dir.path().join("o").to_str().unwrap()]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("nope"), "{err}");
}

/// `m2smap sweep` on a small grid: each row of sweep.json carries its run's own summary.json figures, the misses
/// are exactly the figures beyond the targets (adhesion 0 with perfect masks), and sweep.md counts and
/// lists the same runs.
#[test]
fn sweep_scores_each_run_from_its_own_summary() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sweep");
    let o = m2smap(&[
        "sweep",
        "--out",
        out.to_str().unwrap(),
        "--scenes",
        "tabletop,clutter",
        "--seeds",
        "2",
        "--masks",
        "perfect,dilate2",
        "--frames",
        "3",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_str(&fs::read_to_string(out.join("sweep.json")).unwrap()).unwrap();
    let runs = json["runs"].as_array().unwrap();
    let names: Vec<&str> = runs.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["tabletop-2-perfect", "tabletop-2-dilate2", "clutter-2-perfect", "clutter-2-dilate2"]);
    let md = fs::read_to_string(out.join("sweep.md")).unwrap();
    let mut met = 0;
    for r in runs {
        let name = r["name"].as_str().unwrap();
        let s: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(out.join("runs").join(name).join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(s["frames"], 3, "{name}");
        let pairs = [
            ("penetration_p95_m", "penetration_sq_p95_m", 0.01),
            ("penetration_max_m", "penetration_sq_max_m", 0.02),
            ("g2r_true_m", "g2r_true_rmse_m", 0.015),
            ("adhesion", "adhesion_map", if name.ends_with("perfect") { 0.0 } else { 0.2 }),
        ];
        let mut expected_misses = Vec::new();
        for (key, summary_key, limit) in pairs {
            assert_eq!(r[key], s[summary_key], "{name}: {key}");
            assert!(s[summary_key].is_number(), "{name}: {summary_key} measured");
            if s[summary_key].as_f64().unwrap() > limit {
                expected_misses.push(key);
            }
        }
        let misses: Vec<&str> = r["missed"].as_array().unwrap().iter().map(|m| m.as_str().unwrap()).collect();
        assert_eq!(misses, expected_misses, "{name}");
        met += usize::from(misses.is_empty());
        let row = md.lines().find(|l| l.starts_with(&format!("| {name} |"))).unwrap_or_else(|| panic!("{name} row"));
        assert_eq!(row.matches(" !").count(), misses.len(), "{row}");
    }
    assert!(md.contains(&format!("**{met} of 4 runs meet every target.**")), "{md}");
}

#[test]
fn sweep_refuses_an_unknown_degradation_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let o = m2smap(&["sweep", "--out", dir.path().join("o").to_str().unwrap(), "--masks", "erode2,blur2"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("blur2"), "{err}");
}
