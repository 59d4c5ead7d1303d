//! Helpers shared by the rendering tests.

use nis_render::guiding::{Guide, NoGuide};
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{render, Budget, RenderOptions, Schedule};
use nis_render::scene::Scene;

/// Image means per channel over `repeats` seeds, and their standard errors.
pub fn mean_over_seeds<G: Guide>(
    scene: &Scene,
    strategy: Strategy,
    guide: &mut G,
    repeats: u64,
) -> ([f64; 3], [f64; 3]) {
    let path_tracer = PathTracer::from_scene(scene, strategy);
    let mut samples = vec![[0.0f64; 3]; repeats as usize];
    for (seed, s) in samples.iter_mut().enumerate() {
        let img = render(
            scene,
            &RenderOptions {
                path_tracer,
                budget: Budget::Samples(8),
                seed: 7 + seed as u64,
                schedule: Schedule::Plain,
            },
            guide,
            &|_| {},
        )
        .image;
        for p in &img.pixels {
            for c in 0..3 {
                s[c] += f64::from(p[c]) / img.pixels.len() as f64;
            }
        }
    }
    let n = repeats as f64;
    let mut mean = [0.0; 3];
    let mut err = [0.0; 3];
    for c in 0..3 {
        mean[c] = samples.iter().map(|s| s[c]).sum::<f64>() / n;
        let var = samples
            .iter()
            .map(|s| (s[c] - mean[c]).powi(2))
            .sum::<f64>()
            / (n - 1.0);
        err[c] = (var / n).sqrt();
    }
    (mean, err)
}

/// Asserts that rendering `scene` with `guide` gives the image mean of unguided path tracing:
/// per channel, over 24 seeds each, within 4 standard errors of the difference.
pub fn assert_unbiased<G: Guide>(scene: &Scene, guide: &mut G, name: &str) {
    let (plain, plain_err) = mean_over_seeds(scene, Strategy::Mis, &mut NoGuide, 24);
    let (guided, guided_err) = mean_over_seeds(scene, Strategy::Mis, guide, 24);
    for c in 0..3 {
        let sigma = (plain_err[c].powi(2) + guided_err[c].powi(2)).sqrt();
        assert!(
            (plain[c] - guided[c]).abs() < 4.0 * sigma,
            "{name} channel {c}: unguided {} vs guided {} (σ = {sigma})",
            plain[c],
            guided[c]
        );
    }
}
