//! Whole-renderer tests: the white furnace, agreement of the three estimators (NEE only, BSDF
//! only, MIS), and determinism across thread counts.
//!
//! Tolerances are derived from standard errors estimated from the renders themselves
//! (independent repeats with different seeds), at 4σ; seeds are fixed.

use std::path::Path;

use nis_render::guiding::NoGuide;
use nis_render::path_tracer::{PathStats, PathTracer, Strategy};
use nis_render::render::{render, Budget, RenderOptions, Schedule};
use nis_render::scene::Scene;
use nis_render::xml::load_scene_str;

fn furnace(shape: &str, albedo: f32, max_depth: i32, rr_depth: u32) -> Scene {
    let bsdf = format!(r#"<bsdf type="diffuse"><rgb name="reflectance" value="{albedo}"/></bsdf>"#);
    furnace_of(shape, &bsdf, max_depth, rr_depth)
}

/// A camera inside an emitting `shape` (radiance 1) of BSDF `bsdf` (XML).
fn furnace_of(shape: &str, bsdf: &str, max_depth: i32, rr_depth: u32) -> Scene {
    let xml = format!(
        r#"<scene version="3.0.0">
            <integrator type="path">
                <integer name="max_depth" value="{max_depth}"/>
                <integer name="rr_depth" value="{rr_depth}"/>
            </integrator>
            <sensor type="perspective">
                <float name="fov" value="90"/>
                <transform name="to_world"><lookat origin="0.1, 0.2, 0" target="1, 0, 0.3"/></transform>
                <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
            </sensor>
            <shape type="{shape}">
                <boolean name="flip_normals" value="true"/>
                {bsdf}
                <emitter type="area"><rgb name="radiance" value="1"/></emitter>
            </shape>
        </scene>"#
    );
    load_scene_str(&xml, Path::new("."), "furnace.xml", &[]).unwrap()
}

/// Mean and standard error of the image mean, from `repeats` renders with different seeds.
fn mean_and_std_err(
    scene: &Scene,
    strategy: Strategy,
    spp: u32,
    repeats: u64,
) -> (Vec<f64>, Vec<f64>) {
    let path_tracer = PathTracer::from_scene(scene, strategy);
    let (w, h) = (scene.camera.width(), scene.camera.height());
    // Statistics per 2×2 block of the image (4 regions) and channel.
    let mut samples: Vec<Vec<f64>> = vec![Vec::new(); 12];
    for seed in 0..repeats {
        let out = render(
            scene,
            &RenderOptions {
                path_tracer,
                budget: Budget::Samples(spp),
                seed: 100 + seed,
                schedule: Schedule::Plain,
            },
            &mut NoGuide,
            &|_| {},
        );
        let mut acc = [0.0f64; 12];
        for y in 0..h {
            for x in 0..w {
                let block = (2 * y / h * 2 + 2 * x / w) as usize;
                let p = out.image.get(x, y);
                for c in 0..3 {
                    acc[block * 3 + c] += f64::from(p[c]) / f64::from(w * h / 4);
                }
            }
        }
        for (s, a) in samples.iter_mut().zip(acc) {
            s.push(a);
        }
    }
    let n = repeats as f64;
    let means: Vec<f64> = samples.iter().map(|s| s.iter().sum::<f64>() / n).collect();
    let errs = samples
        .iter()
        .zip(&means)
        .map(|(s, m)| (s.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt())
        .collect();
    (means, errs)
}

/// Whole-image mean of the red channel and its standard error: the four blocks are
/// independent and equal in size, so their errors add in quadrature.
fn image_mean(scene: &Scene, strategy: Strategy, repeats: u64) -> (f64, f64) {
    let (means, errs) = mean_and_std_err(scene, strategy, 4, repeats);
    let m = (0..4).map(|b| means[3 * b]).sum::<f64>() / 4.0;
    let e = (0..4).map(|b| errs[3 * b].powi(2)).sum::<f64>().sqrt() / 4.0;
    (m, e)
}

#[test]
fn white_furnace_radiance_is_emission_over_one_minus_albedo() {
    // Without Russian roulette the estimate is sharp: paths of up to 64 segments collect
    // Le (1 + a + … + a^63) = Le (1 − a^64) / (1 − a).
    for (shape, albedo) in [("sphere", 0.5f32), ("cube", 0.8)] {
        let scene = furnace(shape, albedo, 64, 1000);
        let a = f64::from(albedo);
        let expected = (1.0 - a.powi(64)) / (1.0 - a);
        for strategy in [Strategy::Mis, Strategy::Nee, Strategy::Bsdf] {
            let (m, e) = image_mean(&scene, strategy, 16);
            // The issue asks for 3σ; a floor of 1e-5 relative covers f32 accumulation.
            let tol = 3.0 * e + 1e-5 * expected;
            assert!(
                (m - expected).abs() < tol,
                "{shape} {strategy:?}: {m} vs {expected} (3σ = {tol})"
            );
            // Light sampling alone has unbounded weights near the cube's edges (G ∝ 1/d²), so
            // that one combination is heavy-tailed; every other one must be sharp.
            if !(shape == "cube" && strategy == Strategy::Nee) {
                assert!(
                    e < 2e-3 * expected,
                    "{shape} {strategy:?}: σ = {e} is not sharp"
                );
            }
        }
    }
}

#[test]
fn white_furnace_with_russian_roulette_is_unbiased() {
    // Unbounded paths with Mitsuba's roulette (from depth 5): Le / (1 − a). Roulette makes the
    // estimate heavy-tailed, so this check is much less sharp than the one above.
    for (shape, albedo) in [("sphere", 0.5f32), ("cube", 0.8)] {
        let scene = furnace(shape, albedo, -1, 5);
        let expected = 1.0 / (1.0 - f64::from(albedo));
        for strategy in [Strategy::Mis, Strategy::Bsdf] {
            let (m, e) = image_mean(&scene, strategy, 64);
            let tol = 3.0 * e + 1e-5 * expected;
            assert!(
                (m - expected).abs() < tol,
                "{shape} {strategy:?}: {m} vs {expected} (3σ = {tol})"
            );
        }
    }
}

#[test]
fn nee_bsdf_and_mis_estimates_agree_within_noise() {
    for name in ["cornell-box", "cornell-indirect", "cornell-glossy"] {
        let params = [("res".to_string(), "16".to_string())];
        let scene = nis_render::scenes::load_with(name, &params).unwrap();
        let (mis, mis_err) = mean_and_std_err(&scene, Strategy::Mis, 8, 24);
        for strategy in [Strategy::Nee, Strategy::Bsdf] {
            let (other, other_err) = mean_and_std_err(&scene, strategy, 8, 24);
            for i in 0..12 {
                let sigma = (mis_err[i].powi(2) + other_err[i].powi(2)).sqrt();
                assert!(
                    (mis[i] - other[i]).abs() < 4.0 * sigma,
                    "{name} {strategy:?} block {}: MIS {} vs {} (σ = {sigma})",
                    i / 3,
                    mis[i],
                    other[i]
                );
            }
        }
    }
}

#[test]
fn images_do_not_depend_on_the_thread_count() {
    let params = [("res".to_string(), "24".to_string())];
    let scene = nis_render::scenes::load_with("cornell-glossy", &params).unwrap();
    let path_tracer = PathTracer::from_scene(&scene, Strategy::Mis);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            render(
                &scene,
                &RenderOptions {
                    path_tracer,
                    budget: Budget::Samples(3),
                    seed: 5,
                    schedule: Schedule::Plain,
                },
                &mut NoGuide,
                &|_| {},
            )
            .image
        })
    };
    let one = run(1);
    assert_eq!(one, run(3));
    assert!(one.mean() > 0.0);
}

#[test]
fn a_path_inside_a_mirror_sphere_stays_on_it_for_every_bounce() {
    // Every vertex reflects 1/2 and sees emission 1, with no randomness: a path of max_depth
    // d carries Σ_{k<d} 2⁻ᵏ exactly. A hit point left off the sphere by rounding used to drift
    // tenfold a bounce until the ray missed (mean 1.978 of 2 at depth 40, paths of 6 rays).
    let mirror = r#"<bsdf type="conductor"><string name="material" value="none"/>
        <rgb name="specular_reflectance" value="0.5"/></bsdf>"#;
    for depth in [12, 40] {
        let scene = furnace_of("sphere", mirror, depth, 1000);
        let tracer = PathTracer::from_scene(&scene, Strategy::Mis);
        let expected: f32 = (0..depth).map(|k| 0.5f32.powi(k)).sum();
        let (w, h) = (scene.camera.width(), scene.camera.height());
        for i in 0..w * h {
            let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            let ray = scene.camera.ray(x, y, glam::Vec2::ZERO);
            let mut rng = rand::SeedableRng::seed_from_u64(u64::from(i));
            let mut stats = PathStats::default();
            let l = tracer.radiance(&scene, ray, &mut rng, &NoGuide, &mut stats, None);
            assert!(
                (l.x - expected).abs() < 1e-4,
                "pixel {i}, depth {depth}: {l:?}"
            );
            assert_eq!(stats.rays, depth as u64, "pixel {i}");
        }
    }
}
