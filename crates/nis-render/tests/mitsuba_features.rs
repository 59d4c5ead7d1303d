//! Each scene-reader feature against Mitsuba 3: the feature scenes of `tests/scenes/features/`
//! (written by `scripts/scenes/feature-references.py`, which also renders them with Mitsuba 3.9
//! `scalar_rgb` into `mitsuba-means.json`) rendered by nis-render, image means compared within
//! their noise. The noise of our mean comes from two renders with different seeds (each pixel is
//! independent), Mitsuba's from its seeds' spread.

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

fn features_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/features")
}

/// The image mean of the scene at `path` and its standard error.
fn our_mean(path: &Path) -> (f64, f64) {
    let scene = nis_render::xml::load_scene(path, &[])
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
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
    let n = (a.pixels.len() * 3) as f64;
    let mean = 0.5 * (a.mean() + b.mean());
    // Var of one render's mean: Σ (a − b)² / 2 over values, divided by n²; the average of two
    // renders has half of it.
    let ss: f64 = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .flat_map(|(p, q)| (*p - *q).to_array())
        .map(|d| f64::from(d) * f64::from(d))
        .sum();
    (mean, (ss / 2.0 / (n * n) / 2.0).sqrt())
}

#[test]
fn every_feature_scene_matches_mitsuba_within_its_noise() {
    let dir = features_dir();
    let text = std::fs::read_to_string(dir.join("mitsuba-means.json")).unwrap();
    let refs: serde_json::Value = serde_json::from_str(&text).unwrap();
    let refs = refs.as_object().unwrap();
    assert!(refs.len() >= 10, "only {} reference means", refs.len());
    let mut failures = Vec::new();
    for (name, r) in refs {
        let (want, want_se) = (r["mean"].as_f64().unwrap(), r["std_err"].as_f64().unwrap());
        let (got, se) = our_mean(&dir.join(format!("{name}.xml")));
        let allowed = Z * (se * se + want_se * want_se).sqrt() + MODEL_TOLERANCE * want;
        let line = format!(
            "{name:26} nis {got:.5} ± {se:.5}  mitsuba {want:.5} ± {want_se:.5}  ({:+.2} %)",
            100.0 * (got / want - 1.0)
        );
        eprintln!("{line}");
        if (got - want).abs() > allowed {
            failures.push(line);
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
    let dir = features_dir();
    let text = std::fs::read_to_string(dir.join("mitsuba-means.json")).unwrap();
    let refs: serde_json::Value = serde_json::from_str(&text).unwrap();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "xml") {
            let name = path.file_stem().unwrap().to_str().unwrap();
            assert!(refs.get(name).is_some(), "{name} has no Mitsuba mean");
        }
    }
}
