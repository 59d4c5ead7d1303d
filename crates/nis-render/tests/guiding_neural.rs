//! The neural guide: its density is a normalised density over the sphere that matches the
//! directions it samples, it learns a concentrated distribution of incident light from
//! records, and guided renders stay unbiased and deterministic.

use glam::{Vec2, Vec3};
use nis_render::bvh::Aabb;
use nis_render::geometry::Rgb;
use nis_render::guiding::directions::{DirectionMap, GuideFrame};
use nis_render::guiding::gmm::{Gmm, GmmConfig};
use nis_render::guiding::neural::{NisGuide, NisGuideConfig, PassSamples};
use nis_render::guiding::ppg::{Ppg, PpgConfig};
use nis_render::guiding::{cylindrical_to_dir, dir_to_cylindrical};
use nis_render::guiding::{
    Guide, GuideRecord, GuideSample, GuideVertex, NoGuide, PdfQuery, SampleQuery,
};
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{render, Budget, RenderOptions, Schedule};
use nis_render::scene::Scene;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

const FOUR_PI: f32 = 4.0 * std::f32::consts::PI;

fn unit_box() -> Aabb {
    Aabb {
        min: Vec3::splat(-1.0),
        max: Vec3::splat(1.0),
    }
}

fn vertex() -> GuideVertex {
    GuideVertex {
        p: Vec3::new(0.2, -0.3, 0.1),
        n: Vec3::Z,
        wo: Vec3::new(0.3, 0.1, 0.9).normalize(),
        // The whole sphere (the map of a transmissive material), so the records below the
        // surface count too; the hemisphere of opaque materials has tests of its own below.
        transmissive: true,
    }
}

/// The lobe the synthetic records concentrate their radiance around.
fn lobe() -> Vec3 {
    Vec3::new(0.5, -0.4, 0.6).normalize()
}

/// A guide trained for `iterations` passes on records whose incident radiance at
/// [`vertex`] is a von Mises–Fisher lobe (κ = 20) around [`lobe`], directions drawn uniformly.
fn trained_guide(iterations: usize, records: usize) -> NisGuide {
    let config = NisGuideConfig {
        batch: 1024,
        min_steps: 60,
        ..NisGuideConfig::default()
    };
    let mut guide = NisGuide::new(unit_box(), config).unwrap();
    train_on_lobe(&mut guide, vertex(), lobe(), None, 5, iterations, records);
    guide
}

/// Trains `guide` for `iterations` passes of `records` records at `v` whose incident radiance is
/// a von Mises–Fisher lobe (κ = 20) around `lobe`, directions drawn uniformly over the sphere, or
/// over the hemisphere around `up` when given.
fn train_on_lobe(
    guide: &mut NisGuide,
    v: GuideVertex,
    lobe: Vec3,
    up: Option<Vec3>,
    seed: u64,
    iterations: usize,
    records: usize,
) {
    let pdf = if up.is_some() { 2.0 } else { 1.0 } / FOUR_PI;
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    for _ in 0..iterations {
        let batch: Vec<GuideRecord> = (0..records)
            .map(|_| {
                let w = cylindrical_to_dir(Vec2::new(rng.random(), rng.random()));
                let wi = match up {
                    Some(up) if w.dot(up) < 0.0 => -w,
                    _ => w,
                };
                let l = (20.0 * (wi.dot(lobe) - 1.0)).exp();
                GuideRecord {
                    vertex: v,
                    wi,
                    pdf,
                    bsdf_pdf: pdf,
                    bsdf_cos: Rgb::ONE,
                    radiance: Rgb::splat(l),
                    throughput: 1.0,
                }
            })
            .collect();
        let mut samples = PassSamples::default();
        guide.accumulate(&batch, &mut samples);
        guide.update(samples);
    }
}

/// The guide's densities of `dirs` at [`vertex`], in one batch.
fn pdfs(guide: &NisGuide, dirs: &[Vec3]) -> Vec<f32> {
    let vertices = [vertex()];
    let mut context = Default::default();
    guide.prepare(&vertices, &mut context);
    let queries: Vec<PdfQuery> = dirs.iter().map(|&wi| PdfQuery { vertex: 0, wi }).collect();
    let mut pdf = vec![0.0; dirs.len()];
    guide.pdf_batch(&vertices, &context, &queries, &mut pdf);
    pdf
}

/// Probability of each of `nu × nv` cells of the cylindrical square under the guide's
/// solid-angle density (midpoint rule on `sub × sub` points per cell).
fn cell_probabilities(guide: &NisGuide, nu: usize, nv: usize, sub: usize) -> Vec<f64> {
    let (mu, mv) = (nu * sub, nv * sub);
    let mut dirs = Vec::with_capacity(mu * mv);
    for i in 0..mu {
        for j in 0..mv {
            let x = Vec2::new((i as f32 + 0.5) / mu as f32, (j as f32 + 0.5) / mv as f32);
            dirs.push(cylindrical_to_dir(x));
        }
    }
    let pdf = pdfs(guide, &dirs);
    // dω = 4π du dv.
    let cell = f64::from(FOUR_PI) / (mu * mv) as f64;
    let mut p = vec![0.0; nu * nv];
    for i in 0..mu {
        for j in 0..mv {
            p[(i / sub) * nv + j / sub] += f64::from(pdf[i * mv + j]) * cell;
        }
    }
    p
}

#[test]
fn cylindrical_map_round_trips() {
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    for _ in 0..10_000 {
        let x = Vec2::new(rng.random(), rng.random());
        let w = cylindrical_to_dir(x);
        assert!((w.length() - 1.0).abs() < 1e-5);
        let y = dir_to_cylindrical(w);
        assert!((x[0] - y[0]).abs() < 1e-4, "{x:?} -> {y:?}");
        // φ wraps around at 0 = 1.
        let dv = (x[1] - y[1]).abs();
        assert!(dv.min(1.0 - dv) < 1e-4, "{x:?} -> {y:?}");
    }
}

#[test]
fn untrained_guide_is_uniform_and_unselected() {
    let guide = NisGuide::new(unit_box(), NisGuideConfig::default()).unwrap();
    let pdf = pdfs(&guide, &[lobe()]);
    assert!((pdf[0] - 1.0 / FOUR_PI).abs() < 1e-6);
    assert_eq!(guide.selection_probability(&vertex()), 0.0);
}

#[test]
fn selection_network_waits_for_one_training_phase() {
    // After the first phase only the flow has learned: the guide is used half of the time.
    let once = trained_guide(1, 4096);
    assert_eq!(once.selection_probability(&vertex()), 0.5);
    // Then the selection network learns too (here the guide is far better than the BSDF's
    // uniform density, so it is chosen more often).
    let twice = trained_guide(2, 4096);
    assert!(twice.selection_probability(&vertex()) > 0.5);
}

#[test]
fn trained_density_is_normalised_concentrated_and_matches_its_samples() {
    let guide = trained_guide(4, 16_384);
    assert_eq!(guide.history().len(), 4);
    assert!(guide.history().iter().all(|h| h.steps > 0));

    // Normalised: the density integrates to 1 over the sphere. The piecewise-quadratic
    // density is continuous, so the midpoint rule on 256² points is accurate to well below
    // 1e-3 (checked against 512² below: the two agree to that precision).
    let total: f64 = cell_probabilities(&guide, 1, 1, 256).iter().sum();
    let finer: f64 = cell_probabilities(&guide, 1, 1, 512).iter().sum();
    assert!((total - finer).abs() < 2e-4, "{total} vs {finer}");
    assert!((total - 1.0).abs() < 2e-3, "∫ p dω = {total}");

    // Learned: far more density on the lobe than uniform (the target's peak is 3.2, uniform
    // 0.08) and far less in the opposite direction.
    let pdf = pdfs(&guide, &[lobe(), -lobe()]);
    assert!(pdf[0] > 10.0 / FOUR_PI, "p(lobe) = {}", pdf[0]);
    assert!(pdf[1] < 0.5 / FOUR_PI, "p(-lobe) = {}", pdf[1]);

    // Samples: their reported density equals the evaluated one, and their histogram over
    // 8 × 16 cells of the cylindrical square matches the cell probabilities (χ² test).
    let n = 200_000;
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let u: Vec<Vec2> = (0..n)
        .map(|_| Vec2::new(rng.random(), rng.random()))
        .collect();
    let vertices = [vertex()];
    let mut context = Default::default();
    guide.prepare(&vertices, &mut context);
    let queries: Vec<SampleQuery> = u.iter().map(|&u| SampleQuery { vertex: 0, u }).collect();
    let mut samples = vec![None; n];
    guide.sample_batch(&vertices, &context, &queries, &mut samples);
    let dirs: Vec<Vec3> = samples.iter().map(|s| s.unwrap().wi).collect();
    let pdf = pdfs(&guide, &dirs);
    for (s, p) in samples.iter().zip(&pdf) {
        let q = s.unwrap().pdf;
        assert!(
            (q - p).abs() <= 2e-3 * p.max(q),
            "sampled {q} vs evaluated {p}"
        );
    }
    let (nu, nv) = (8, 16);
    let expected = cell_probabilities(&guide, nu, nv, 16);
    let mut counts = vec![0.0f64; nu * nv];
    for d in &dirs {
        let x = dir_to_cylindrical(*d);
        let i = ((x[0] * nu as f32) as usize).min(nu - 1);
        let j = ((x[1] * nv as f32) as usize).min(nv - 1);
        counts[i * nv + j] += 1.0;
    }
    // Pool cells expecting fewer than 20 samples into one.
    let (mut chi2, mut dof) = (0.0, 0usize);
    let (mut pooled_e, mut pooled_o) = (0.0, 0.0);
    for (e, o) in expected.iter().zip(&counts) {
        let e = e * n as f64;
        if e < 20.0 {
            pooled_e += e;
            pooled_o += o;
        } else {
            chi2 += (o - e).powi(2) / e;
            dof += 1;
        }
    }
    if pooled_e > 0.0 {
        chi2 += (pooled_o - pooled_e).powi(2) / pooled_e.max(1.0);
        dof += 1;
    }
    let dof = (dof - 1) as f64;
    // Wilson–Hilferty: (χ²/k)^(1/3) is near-normal with mean 1 − 2/(9k), variance 2/(9k);
    // reject beyond 4.75σ (p ≈ 1e-6).
    let z = ((chi2 / dof).powf(1.0 / 3.0) - (1.0 - 2.0 / (9.0 * dof))) / (2.0 / (9.0 * dof)).sqrt();
    assert!(z < 4.75, "χ² = {chi2} on {dof} dof (z = {z})");
}

#[test]
fn guided_render_is_unbiased_and_deterministic() {
    let params = [("res".to_string(), "12".to_string())];
    let scene = nis_render::scenes::load_with("cornell-indirect", &params).unwrap();
    let path_tracer = PathTracer::from_scene(&scene, Strategy::Mis);
    let guided = |seed: u64, frame: GuideFrame| {
        let config = NisGuideConfig {
            batch: 512,
            min_steps: 10,
            seed,
            frame,
            ..NisGuideConfig::default()
        };
        let mut guide = NisGuide::new(scene.bounds(), config).unwrap();
        let out = render(
            &scene,
            &RenderOptions {
                path_tracer,
                budget: Budget::Samples(16),
                seed,
                schedule: Schedule::Training,
            },
            &mut guide,
            &|_| {},
        );
        assert!(guide.history().iter().any(|h| h.steps > 0));
        out.image.pixels
    };
    let plain = |seed: u64| {
        render(
            &scene,
            &RenderOptions {
                path_tracer,
                budget: Budget::Samples(16),
                seed,
                schedule: Schedule::Plain,
            },
            &mut NoGuide,
            &|_| {},
        )
        .image
        .pixels
    };
    // Determinism: the same seed gives the same image, on one thread or two.
    for frame in [GuideFrame::World, GuideFrame::Local] {
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| guided(3, frame));
        assert_eq!(one, guided(3, frame), "{frame:?}");
    }

    // Unbiasedness: the mean radiance over 12 seeds agrees with path tracing within 4σ.
    let mean = |img: &[Rgb]| {
        img.iter()
            .map(|p| f64::from(p.x + p.y + p.z) / 3.0)
            .sum::<f64>()
            / img.len() as f64
    };
    let stats = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
        (m, (var / v.len() as f64).sqrt())
    };
    let p: Vec<f64> = (0..24).map(|s| mean(&plain(200 + s))).collect();
    let (mp, ep) = stats(&p);
    for frame in [GuideFrame::World, GuideFrame::Local] {
        let g: Vec<f64> = (0..12).map(|s| mean(&guided(100 + s, frame))).collect();
        let (mg, eg) = stats(&g);
        let sigma = (eg * eg + ep * ep).sqrt();
        assert!(
            (mg - mp).abs() < 4.0 * sigma,
            "{frame:?}: guided {mg} ± {eg} vs plain {mp} ± {ep}"
        );
    }
}

/// A scene of one diffuse cube and a camera at `origin`, with an area light above it or none.
fn cube_scene(origin: &str, light: bool) -> nis_render::scene::Scene {
    let emitter = if light {
        r#"<shape type="rectangle">
               <transform name="to_world"><rotate x="1" angle="90"/><translate y="3"/></transform>
               <emitter type="area"><rgb name="radiance" value="5, 5, 5"/></emitter>
           </shape>"#
    } else {
        ""
    };
    let xml = format!(
        r#"<scene version="3.0.0">
            <sensor type="perspective">
                <float name="fov" value="60"/>
                <transform name="to_world"><lookat origin="{origin}" target="0, 0, 0" up="0, 1, 0"/></transform>
                <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
                <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
                    <rfilter type="box"/></film>
            </sensor>
            <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>
            <shape type="cube"><ref id="white"/></shape>
            {emitter}
        </scene>"#
    );
    nis_render::xml::load_scene_str(&xml, std::path::Path::new("."), "cube.xml", &[]).unwrap()
}

#[test]
fn scenes_without_light_or_with_the_camera_inside_a_mesh_render_black() {
    // Every guide, not only the neural one.
    for (origin, light) in [("0, 1, 4", false), ("0, 0, 0.2", true)] {
        let scene = cube_scene(origin, light);
        let path_tracer = PathTracer::from_scene(&scene, Strategy::Mis);
        let options = RenderOptions {
            path_tracer,
            budget: Budget::Samples(8),
            seed: 1,
            schedule: Schedule::Training,
        };
        fn check<G: Guide>(scene: &Scene, options: &RenderOptions, mut guide: G, at: &str) {
            let out = render(scene, options, &mut guide, &|_| {});
            assert_eq!(out.stats.invalid, 0);
            assert!(
                out.image.pixels.iter().all(|p| *p == Rgb::ZERO),
                "{at}: {}",
                out.image.mean()
            );
        }
        let at = format!("camera at {origin}, light {light}");
        let nis = NisGuide::new(scene.bounds(), NisGuideConfig::default()).unwrap();
        check(&scene, &options, nis, &at);
        check(
            &scene,
            &options,
            Ppg::new(scene.bounds(), PpgConfig::default()),
            &at,
        );
        check(
            &scene,
            &options,
            Gmm::new(scene.bounds(), GmmConfig::default()),
            &at,
        );
    }
    // The lit cube seen from outside is not black (the scene itself is fine).
    let scene = cube_scene("0, 2.5, 4", true);
    let path_tracer = PathTracer::from_scene(&scene, Strategy::Mis);
    let mut guide = NisGuide::new(scene.bounds(), NisGuideConfig::default()).unwrap();
    let out = render(
        &scene,
        &RenderOptions {
            path_tracer,
            budget: Budget::Samples(8),
            seed: 1,
            schedule: Schedule::Training,
        },
        &mut guide,
        &|_| {},
    );
    assert!(out.image.mean() > 0.0);
}

/// An opaque vertex on a wall seen from its back side (a two-sided material): the local
/// frame's hemisphere is the one on `ω_o`'s side, around `−n`.
fn opaque_vertex() -> GuideVertex {
    GuideVertex {
        p: Vec3::new(-0.4, 0.3, 0.2),
        n: Vec3::new(0.2, 0.9, -0.3).normalize(),
        wo: Vec3::new(0.1, -0.8, 0.5).normalize(),
        transmissive: false,
    }
}

/// A guide trained on records at [`opaque_vertex`] whose incident radiance is a lobe (κ = 20)
/// around a direction on `ω_o`'s side, directions drawn uniformly over that hemisphere.
fn trained_opaque_guide() -> (NisGuide, Vec3) {
    let v = opaque_vertex();
    let up = -v.n;
    let lobe = (up + Vec3::new(0.6, 0.0, 0.3)).normalize();
    let config = NisGuideConfig {
        batch: 1024,
        min_steps: 60,
        frame: GuideFrame::Local,
        ..NisGuideConfig::default()
    };
    let mut guide = NisGuide::new(unit_box(), config).unwrap();
    train_on_lobe(&mut guide, v, lobe, Some(up), 6, 4, 16_384);
    (guide, lobe)
}

#[test]
fn opaque_vertices_get_a_normalised_hemisphere_density_and_no_samples_below() {
    let (guide, lobe) = trained_opaque_guide();
    let v = opaque_vertex();
    let up = -v.n;
    let map = DirectionMap::new(&v);
    assert!(map.is_hemisphere() && (map.normal() - up).length() < 1e-6);
    let vertices = [v];
    let mut cache = Default::default();
    guide.prepare(&vertices, &mut cache);
    let density = |dirs: &[Vec3]| {
        let queries: Vec<PdfQuery> = dirs.iter().map(|&wi| PdfQuery { vertex: 0, wi }).collect();
        let mut pdf = vec![0.0; dirs.len()];
        guide.pdf_batch(&vertices, &cache, &queries, &mut pdf);
        pdf
    };

    // Normalised over the sphere (midpoint rule on the world's cylindrical square, which cuts
    // the horizon obliquely: its error is the horizon's cells, ≈ 1e-3 at 512²), all of it on
    // ω_o's side of the surface.
    let m = 512;
    let dirs: Vec<Vec3> = (0..m * m)
        .map(|k| {
            let x = Vec2::new(
                ((k / m) as f32 + 0.5) / m as f32,
                ((k % m) as f32 + 0.5) / m as f32,
            );
            cylindrical_to_dir(x)
        })
        .collect();
    let pdf = density(&dirs);
    let cell = f64::from(FOUR_PI) / (m * m) as f64;
    let total: f64 = pdf.iter().map(|&p| f64::from(p) * cell).sum();
    assert!((total - 1.0).abs() < 5e-3, "∫ p dω = {total}");
    for (d, p) in dirs.iter().zip(&pdf) {
        if d.dot(up) < 0.0 {
            assert_eq!(*p, 0.0, "density {p} below the surface at {d}");
        }
    }
    // Learned: concentrated on the lobe.
    assert!(density(&[lobe])[0] > 10.0 / FOUR_PI);

    // Samples: none below the surface, and each one's density is the evaluated one.
    let n = 100_000;
    let mut rng = Pcg64Mcg::seed_from_u64(10);
    let queries: Vec<SampleQuery> = (0..n)
        .map(|_| SampleQuery {
            vertex: 0,
            u: Vec2::new(rng.random(), rng.random()),
        })
        .collect();
    let mut samples = vec![None; n];
    guide.sample_batch(&vertices, &cache, &queries, &mut samples);
    let samples: Vec<GuideSample> = samples.into_iter().map(Option::unwrap).collect();
    let dirs: Vec<Vec3> = samples.iter().map(|s| s.wi).collect();
    let pdf = density(&dirs);
    for (s, p) in samples.iter().zip(&pdf) {
        assert!(s.wi.dot(up) >= 0.0, "sampled {} below the surface", s.wi);
        assert!(
            (s.pdf - p).abs() <= 2e-3 * p.max(s.pdf),
            "sampled {} vs evaluated {p}",
            s.pdf
        );
    }
}
