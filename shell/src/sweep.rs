//! The robustness sweep (`m2smap sweep`): every synthetic scene × seed × mask degradation, made fresh
//! ([`crate::synth`]), mapped by `full` ([`crate::run::run`]) and scored against the superquadric issue's
//! synthetic targets ([`TARGETS`]) from each run's own `summary.json`. It measures how the method generalises
//! beyond the project's own frames: different sensor noise and mask errors of a chosen size, not the runs the
//! tests pin.
//!
//! Writes `OUT/sweep.md` (one row per run, the misses marked) and `OUT/sweep.json`; the scenes are made afresh
//! under `OUT/data/` and mapped into `OUT/runs/`.

use std::fmt::Write as _;
use std::fs;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use m2smap_core::Variant;
use serde::Serialize;

use crate::run::{run, ProfileChoice, RunOptions, Summary};
use crate::synth::{Degradation, Scene};

/// The synthetic targets of the superquadric issue that a sweep run is scored against.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Targets {
    /// Largest 95th percentile of the superquadrics' penetration of other true solids, metres.
    pub penetration_p95_m: f64,
    /// Largest penetration of any superquadric, metres.
    pub penetration_max_m: f64,
    /// Largest G2R against the true surfaces (all samples), metres.
    pub g2r_true_m: f64,
    /// Largest map-level adhesion per frame with degraded masks (0 with perfect masks).
    pub adhesion_degraded: f64,
}

/// The superquadric issue's targets: penetration p95 ≤ 1 cm and max ≤ 2 cm, G2R against the true surfaces
/// ≤ 15 mm, map-level adhesion 0 with perfect masks and ≤ 0.2 per frame with degraded ones.
pub const TARGETS: Targets =
    Targets { penetration_p95_m: 0.01, penetration_max_m: 0.02, g2r_true_m: 0.015, adhesion_degraded: 0.2 };

/// One mask degradation of a sweep, by name: `perfect`, `erodeN` (N px, with 10 % of the masks missing in each
/// frame, as a detector that misses some objects) or `dilateN` (N px).
pub fn degradation(name: &str) -> Result<Degradation> {
    let px = |prefix: &str| name.strip_prefix(prefix).and_then(|n| n.parse::<u32>().ok()).filter(|&n| n > 0);
    let none = Degradation { erode: 0, dilate: 0, miss: 0.0, score_noise: 0.0 };
    if name == "perfect" {
        Ok(none)
    } else if let Some(n) = px("erode") {
        Ok(Degradation { erode: n, miss: ERODED_MISS, ..none })
    } else if let Some(n) = px("dilate") {
        Ok(Degradation { dilate: n, ..none })
    } else {
        bail!("unknown mask degradation {name:?} (known: perfect, erodeN, dilateN with N ≥ 1 pixels)")
    }
}

/// Share of the masks dropped in each frame of an eroded sweep run.
pub const ERODED_MISS: f64 = 0.1;

/// Options of `m2smap sweep`.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    /// Output folder.
    pub out: PathBuf,
    /// Scene names ([`crate::synth::SCENES`]).
    pub scenes: Vec<String>,
    /// Seeds of the sensor noise and of the mask degradation.
    pub seeds: Vec<u32>,
    /// Mask degradations by name ([`degradation`]).
    pub degradations: Vec<String>,
    /// Frames per run.
    pub frames: usize,
    /// Print a line per run.
    pub verbose: bool,
}

/// The figures of one run that the targets judge (from its `summary.json`); `None` where the run could not
/// measure one (a scene without superquadrics has no penetration).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Figures {
    /// Superquadric penetration of other true solids, 95th percentile over the run, metres.
    pub penetration_p95_m: Option<f64>,
    /// Superquadric penetration, largest, metres.
    pub penetration_max_m: Option<f64>,
    /// G2R against the true surfaces, all samples, metres.
    pub g2r_true_m: Option<f64>,
    /// Map-level adhesion per frame.
    pub adhesion: Option<f64>,
}

impl Figures {
    /// The figures of a run's summary.
    pub fn of(s: &Summary) -> Figures {
        Figures {
            penetration_p95_m: s.penetration_sq_p95_m,
            penetration_max_m: s.penetration_sq_max_m,
            g2r_true_m: s.g2r_true_rmse_m,
            adhesion: s.adhesion_map,
        }
    }

    /// The targets these figures miss under `targets` (names of [`Figures`] fields; `degraded`: the masks were
    /// degraded, so the adhesion bound applies; with perfect masks adhesion must be 0). A figure that is
    /// missing is no miss.
    pub fn missed(&self, degraded: bool, targets: &Targets) -> Vec<&'static str> {
        let adhesion_limit = if degraded { targets.adhesion_degraded } else { 0.0 };
        let checks = [
            ("penetration_p95_m", self.penetration_p95_m, targets.penetration_p95_m),
            ("penetration_max_m", self.penetration_max_m, targets.penetration_max_m),
            ("g2r_true_m", self.g2r_true_m, targets.g2r_true_m),
            ("adhesion", self.adhesion, adhesion_limit),
        ];
        checks.iter().filter(|(_, x, limit)| x.is_some_and(|x| x > *limit)).map(|(name, _, _)| *name).collect()
    }
}

/// One run of a sweep: what was mapped, its figures and the targets it misses.
#[derive(Debug, Clone, Serialize)]
pub struct SweepRun {
    /// `scene-seed-degradation`.
    pub name: String,
    /// Scene name.
    pub scene: String,
    /// Seed.
    pub seed: u32,
    /// Mask degradation name.
    pub degradation: String,
    /// The judged figures.
    #[serde(flatten)]
    pub figures: Figures,
    /// Primitives per frame.
    pub primitives: Option<f64>,
    /// The targets this run misses ([`Figures::missed`]); empty when it meets every one.
    pub missed: Vec<&'static str>,
}

/// Runs the sweep: makes each scene under `OUT/data/` (replacing what is there), maps it with `full` on the host
/// profile, scores it, and writes `sweep.md` and `sweep.json`. Returns the runs in order (scene, seed,
/// degradation).
pub fn sweep(opts: &SweepOptions) -> Result<Vec<SweepRun>> {
    if opts.scenes.is_empty() || opts.seeds.is_empty() || opts.degradations.is_empty() || opts.frames == 0 {
        bail!("sweep needs at least one scene, seed, degradation and frame");
    }
    let named: Vec<(String, Degradation)> =
        opts.degradations.iter().map(|d| Ok((d.clone(), degradation(d)?))).collect::<Result<_>>()?;
    let scenes: Vec<Scene> = opts.scenes.iter().map(|s| Scene::named(s)).collect::<Result<_>>()?;
    let mut runs = Vec::new();
    for (scene, scene_name) in scenes.iter().zip(&opts.scenes) {
        for &seed in &opts.seeds {
            for (deg_name, deg) in &named {
                let name = format!("{scene_name}-{seed}-{deg_name}");
                // Made afresh every time: a scene written by an older build of the generator would be scored
                // as if it were this one's.
                let data = opts.out.join("data").join(&name);
                if data.exists() {
                    fs::remove_dir_all(&data).with_context(|| format!("{}: cannot replace", data.display()))?;
                }
                scene.write_tum_degraded(&data, opts.frames, seed, true, deg)?;
                let s = run(&RunOptions {
                    dataset: data,
                    out: opts.out.join("runs").join(&name),
                    variant: Some(Variant::Full),
                    frames: Some(opts.frames),
                    config: None,
                    camera: None,
                    profile: ProfileChoice::Host,
                    downscale: 1,
                    masks: None,
                    segmenter: None,
                    faults: None,
                    progress: false,
                    world: None,
                })?;
                let figures = Figures::of(&s);
                let r = SweepRun {
                    name,
                    scene: scene_name.clone(),
                    seed,
                    degradation: deg_name.clone(),
                    figures,
                    primitives: s.primitives.total,
                    missed: figures.missed(!deg.is_off(), &TARGETS),
                };
                if opts.verbose {
                    println!("{}", row(&r).trim_start_matches("| ").trim_end_matches(" |"));
                }
                runs.push(r);
            }
        }
    }
    fs::create_dir_all(&opts.out).with_context(|| format!("{}: cannot create", opts.out.display()))?;
    let md = opts.out.join("sweep.md");
    fs::write(&md, markdown(&runs, opts.frames)).with_context(|| format!("{}: cannot write", md.display()))?;
    let json = opts.out.join("sweep.json");
    let body =
        serde_json::to_string_pretty(&serde_json::json!({ "targets": TARGETS, "frames": opts.frames, "runs": runs }))?;
    fs::write(&json, body + "\n").with_context(|| format!("{}: cannot write", json.display()))?;
    Ok(runs)
}

/// A figure in millimetres (or a count), "–" when missing, "!" after one that misses its target.
fn figure(x: Option<f64>, scale: f64, decimals: usize, miss: bool) -> String {
    let mark = if miss { " !" } else { "" };
    x.map_or_else(|| "–".to_string(), |x| format!("{:.*}{mark}", decimals, x * scale))
}

/// The table row of one run.
fn row(r: &SweepRun) -> String {
    let miss = |name: &str| r.missed.contains(&name);
    let f = &r.figures;
    format!(
        "| {} | {} | {} | {} | {} | {} |",
        r.name,
        figure(f.penetration_p95_m, 1000.0, 1, miss("penetration_p95_m")),
        figure(f.penetration_max_m, 1000.0, 1, miss("penetration_max_m")),
        figure(f.g2r_true_m, 1000.0, 1, miss("g2r_true_m")),
        figure(f.adhesion, 1.0, 2, miss("adhesion")),
        figure(r.primitives, 1.0, 1, false),
    )
}

/// How many of `runs` meet every target.
pub fn met(runs: &[SweepRun]) -> usize {
    runs.iter().filter(|r| r.missed.is_empty()).count()
}

/// `sweep.md`: the targets, how many runs meet all of them ([`met`]), and a row per run.
pub fn markdown(runs: &[SweepRun], frames: usize) -> String {
    let met = met(runs);
    let mut s = String::new();
    let _ = writeln!(s, "# Robustness sweep ({frames} frames per run, `full`, host profile)\n");
    let _ = writeln!(
        s,
        "Targets: superquadric penetration p95 ≤ {:.0} mm and max ≤ {:.0} mm, G2R against the true surfaces ≤ {:.0} mm, \
         map-level adhesion 0 with perfect masks and ≤ {} per frame with degraded ones. `erodeN`: masks eroded by N px \
         with {:.0} % of them missing in each frame; `dilateN`: dilated by N px. `!` marks a miss.\n",
        TARGETS.penetration_p95_m * 1000.0,
        TARGETS.penetration_max_m * 1000.0,
        TARGETS.g2r_true_m * 1000.0,
        TARGETS.adhesion_degraded,
        ERODED_MISS * 100.0
    );
    let _ = writeln!(s, "**{met} of {} runs meet every target.**\n", runs.len());
    let _ =
        writeln!(s, "| run | penetration p95 (mm) | penetration max (mm) | G2R true (mm) | adhesion | primitives |");
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for r in runs {
        let _ = writeln!(s, "{}", row(r));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_target_is_missed_only_beyond_its_bound() {
        let at_bounds = Figures {
            penetration_p95_m: Some(0.01),
            penetration_max_m: Some(0.02),
            g2r_true_m: Some(0.015),
            adhesion: Some(0.2),
        };
        assert!(at_bounds.missed(true, &TARGETS).is_empty(), "a figure on its bound meets it");
        // With perfect masks any adhesion is a miss.
        assert_eq!(at_bounds.missed(false, &TARGETS), vec!["adhesion"]);
        let beyond = |f: Figures, name: &str| assert_eq!(f.missed(true, &TARGETS), vec![name], "{f:?}");
        beyond(Figures { penetration_p95_m: Some(0.0101), ..at_bounds }, "penetration_p95_m");
        beyond(Figures { penetration_max_m: Some(0.0201), ..at_bounds }, "penetration_max_m");
        beyond(Figures { g2r_true_m: Some(0.0151), ..at_bounds }, "g2r_true_m");
        beyond(Figures { adhesion: Some(0.21), ..at_bounds }, "adhesion");
        // A figure the run could not measure is no miss.
        assert!(Figures::default().missed(false, &TARGETS).is_empty());
    }

    #[test]
    fn degradations_parse_by_name() {
        let d = degradation("erode3").unwrap();
        assert_eq!((d.erode, d.dilate, d.miss), (3, 0, ERODED_MISS));
        let d = degradation("dilate1").unwrap();
        assert_eq!((d.erode, d.dilate, d.miss), (0, 1, 0.0));
        assert!(degradation("perfect").unwrap().is_off());
        for bad in ["erode0", "dilate", "erodex", "blur2", ""] {
            assert!(degradation(bad).is_err(), "{bad:?}");
        }
    }
}
