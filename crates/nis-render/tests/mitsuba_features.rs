//! Each scene-reader feature against Mitsuba 3: the feature scenes of `tests/scenes/features/`
//! (written by `scripts/scenes/feature-references.py`, which also renders them with Mitsuba 3.9
//! `scalar_rgb` into `mitsuba-means.json`) rendered by nis-render, the means of the image and
//! of its four quadrants (which see a flipped texture or a mirrored camera) compared within
//! their noise. The noise of our means comes from two renders with different seeds (each pixel
//! is independent), Mitsuba's from its seeds' spread.

use std::path::{Path, PathBuf};

use nis_render::guiding::NoGuide;
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{render, Budget, RenderOptions, Schedule};

/// Samples per pixel of each of our two renders.
const SPP: u32 = 512;
/// Standard errors of the difference allowed (a 4σ test fails by chance once in 16,000).
const Z: f64 = 4.0;
/// Relative difference allowed beyond the noise for the two renderers' model differences:
/// Mitsuba weights its Beckmann visible-normal samples with Walter's fitted `G1` instead of
/// the exact one it samples, integrates plastics' coating tables on other grids, and
/// normalises its filter by the weights of the samples that land in each pixel.
const MODEL_TOLERANCE: f64 = 0.005;
/// The regions compared: the image, then its quadrants.
const REGIONS: [&str; 5] = [
    "image",
    "top left",
    "top right",
    "bottom left",
    "bottom right",
];

fn features_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/features")
}

/// The means of the scene at `path` over [`REGIONS`], and their standard errors; `None` (with
/// the reason printed) for a `sunsky` scene when Mitsuba's sun-and-sky tables are not fetched.
fn our_means(path: &Path) -> Option<Vec<(f64, f64)>> {
    let scene = match nis_render::xml::load_scene(path, &[]) {
        Err(e @ nis_render::Error::MissingSunskyData { .. }) => {
            eprintln!("{}: skipped: {e}", path.display());
            return None;
        }
        r => r.unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    };
    let images: Vec<_> = [1u64, 2]
        .iter()
        .map(|&seed| {
            let options = RenderOptions {
                path_tracer: PathTracer::from_scene(&scene, Strategy::Mis),
                budget: Budget::Samples(SPP),
                seed,
                schedule: Schedule::Plain,
            };
            render(&scene, &options, &mut NoGuide, &|_| {}).image
        })
        .collect();
    let (a, b) = (&images[0], &images[1]);
    let (w, h) = (a.width as usize, a.height as usize);
    let regions = [
        (0, w, 0, h),
        (0, w / 2, 0, h / 2),
        (w / 2, w, 0, h / 2),
        (0, w / 2, h / 2, h),
        (w / 2, w, h / 2, h),
    ];
    let means = regions
        .iter()
        .map(|&(x0, x1, y0, y1)| {
            let (mut sum, mut ss, mut n) = (0.0f64, 0.0f64, 0.0f64);
            for y in y0..y1 {
                for x in x0..x1 {
                    let (p, q) = (a.pixels[y * w + x], b.pixels[y * w + x]);
                    for (u, v) in p.to_array().into_iter().zip(q.to_array()) {
                        sum += 0.5 * (f64::from(u) + f64::from(v));
                        ss += (f64::from(u) - f64::from(v)).powi(2);
                        n += 1.0;
                    }
                }
            }
            // Var of one render's mean: Σ (a − b)² / 2 over values, over n²; the average of
            // the two renders has half of it.
            (sum / n, (ss / 2.0 / (n * n) / 2.0).sqrt())
        })
        .collect();
    Some(means)
}

fn references() -> serde_json::Map<String, serde_json::Value> {
    let text = std::fs::read_to_string(features_dir().join("mitsuba-means.json")).unwrap();
    let refs: serde_json::Value = serde_json::from_str(&text).unwrap();
    refs.as_object().unwrap().clone()
}

#[test]
fn every_feature_scene_matches_mitsuba_within_its_noise() {
    let refs = references();
    assert!(refs.len() >= 10, "only {} reference means", refs.len());
    let mut failures = Vec::new();
    for (name, r) in &refs {
        let number = |v: &serde_json::Value| v.as_f64().unwrap();
        let mut want = vec![(number(&r["mean"]), number(&r["std_err"]))];
        let quads = r["quadrants"].as_array().unwrap();
        let errs = r["quadrant_std_errs"].as_array().unwrap();
        want.extend(quads.iter().zip(errs).map(|(m, e)| (number(m), number(e))));
        let Some(got) = our_means(&features_dir().join(format!("{name}.xml"))) else {
            continue;
        };
        for (region, (&(g, se), &(m, mse))) in REGIONS.iter().zip(got.iter().zip(&want)) {
            let allowed = Z * (se * se + mse * mse).sqrt() + MODEL_TOLERANCE * m;
            let line = format!(
                "{name:26} {region:12} nis {g:.5} ± {se:.5}  mitsuba {m:.5} ± {mse:.5}  ({:+.2} %)",
                100.0 * (g / m - 1.0)
            );
            eprintln!("{line}");
            if (g - m).abs() > allowed {
                failures.push(line);
            }
        }
    }
    assert!(
        failures.is_empty(),
        "beyond the noise:\n{}",
        failures.join("\n")
    );
}

#[test]
fn every_feature_scene_has_a_reference() {
    let refs = references();
    for entry in std::fs::read_dir(features_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "xml") {
            let name = path.file_stem().unwrap().to_str().unwrap();
            assert!(refs.contains_key(name), "{name} has no Mitsuba mean");
        }
    }
}
