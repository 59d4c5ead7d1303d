//! The guiding interface and the constant environment, end to end: a guide mixed one-sample
//! with the BSDF leaves the image unbiased, finished paths produce sensible training records,
//! and a diffuse convex object under a uniform sky reflects exactly `albedo × sky`.

use std::path::Path;

use nis_render::guiding::{
    Guide, GuideRecord, GuideSample, GuideVertex, NoGuide, PdfQuery, SampleQuery,
};
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{render, Budget, RenderOptions, Schedule};
use nis_render::sampling::square_to_uniform_sphere;
use nis_render::scene::Scene;
use nis_render::xml::load_scene_str;

mod common;
use common::{assert_unbiased, mean_over_seeds};

/// A deliberately poor guide: uniform directions, chosen half of the time.
#[derive(Default)]
struct UniformGuide {
    records: Vec<GuideRecord>,
    iterations: usize,
    /// Paths per wavefront (0: the trait's default).
    batch: usize,
    /// Bounces it serves (0: the trait's default, every bounce).
    bounces: u32,
    /// The narrowest lobe it serves, radians (`None`: the trait's default).
    lobe: Option<f32>,
}

impl Guide for UniformGuide {
    type Prepared = ();
    type Statistics = Vec<GuideRecord>;

    fn prepare(&self, _: &[GuideVertex], _: &mut ()) {}

    fn selection_probabilities(&self, _: &[GuideVertex], _: &(), out: &mut [f32]) {
        out.fill(0.5);
    }

    fn sample_batch(
        &self,
        _: &[GuideVertex],
        _: &(),
        queries: &[SampleQuery],
        out: &mut [Option<GuideSample>],
    ) {
        for (q, o) in queries.iter().zip(out) {
            *o = Some(GuideSample {
                wi: square_to_uniform_sphere(q.u),
                pdf: 1.0 / (4.0 * std::f32::consts::PI),
            });
        }
    }

    fn pdf_batch(&self, _: &[GuideVertex], _: &(), _: &[PdfQuery], out: &mut [f32]) {
        out.fill(1.0 / (4.0 * std::f32::consts::PI));
    }

    fn wants_records(&self) -> bool {
        true
    }

    fn batch_paths(&self) -> usize {
        if self.batch == 0 {
            64
        } else {
            self.batch
        }
    }

    fn guided_bounces(&self) -> u32 {
        if self.bounces == 0 {
            u32::MAX
        } else {
            self.bounces
        }
    }

    fn narrowest_lobe(&self) -> f32 {
        self.lobe
            .unwrap_or(nis_render::guiding::NARROWEST_LOBE_DEGREES.to_radians())
    }

    fn accumulate(&self, records: &[GuideRecord], statistics: &mut Vec<GuideRecord>) {
        statistics.extend_from_slice(records);
    }

    fn update(&mut self, records: Vec<GuideRecord>) {
        self.records.extend(records);
        self.iterations += 1;
    }
}

#[test]
fn guided_mixture_is_unbiased_and_records_paths() {
    let params = [("res".to_string(), "12".to_string())];
    let scene = nis_render::scenes::load_with("cornell-box", &params).unwrap();
    let mut guide = UniformGuide::default();
    assert_unbiased(&scene, &mut guide, "a uniform guide");
    assert_eq!(guide.iterations, 24);
    let records = guide.records;
    assert!(records.len() > 1000);
    for r in &records {
        assert!(r.pdf > 0.0 && (r.wi.length() - 1.0).abs() < 1e-4);
        assert!(r.radiance.is_finite() && r.radiance.min_element() >= 0.0);
    }
    assert!(records.iter().any(|r| r.radiance.max_element() > 0.0));
}

/// How many of `records` were made away from a camera ray's hit in `scene` (where a vertex
/// does not look back at the eye).
fn beyond_first_hit(scene: &Scene, records: &[GuideRecord]) -> usize {
    let eye = scene.camera.ray(0.5, 0.5, glam::Vec2::ZERO).origin;
    records
        .iter()
        .filter(|r| (eye - r.vertex.p).normalize().dot(r.vertex.wo) <= 1.0 - 1e-4)
        .count()
}

/// A uniform guide of one bounce, and the records it learned from in `renders` renders of
/// `scene` (the unbiasedness check's 24 when `renders` is `None`).
fn one_bounce_guide(scene: &Scene, renders: Option<u64>) -> UniformGuide {
    let mut guide = UniformGuide {
        bounces: 1,
        ..UniformGuide::default()
    };
    match renders {
        Some(n) => {
            mean_over_seeds(scene, Strategy::Mis, &mut guide, n);
        }
        None => assert_unbiased(scene, &mut guide, "a uniform guide at the first bounce"),
    }
    guide
}

#[test]
fn a_guide_serving_the_first_bounce_only_leaves_the_image_unbiased_and_learns_there() {
    let params = [("res".to_string(), "12".to_string())];
    let scene = nis_render::scenes::load_with("cornell-box", &params).unwrap();
    let guide = one_bounce_guide(&scene, None);
    // Records from camera-ray hits only; a guide of every bounce also learns deeper.
    assert!(guide.records.len() > 1000);
    assert_eq!(beyond_first_hit(&scene, &guide.records), 0);
    // A camera ray's hit receives the whole pixel's importance: throughput 1.
    assert!(guide
        .records
        .iter()
        .all(|r| (r.throughput - 1.0).abs() < 1e-6));
    let mut every = UniformGuide::default();
    mean_over_seeds(&scene, Strategy::Mis, &mut every, 2);
    let deeper = beyond_first_hit(&scene, &every.records);
    assert!(
        deeper > every.records.len() / 4,
        "{deeper} of {}",
        every.records.len()
    );
    // Deeper vertices arrive with what the walls and the mixture's densities left of it.
    assert!(every
        .records
        .iter()
        .all(|r| r.throughput.is_finite() && r.throughput >= 0.0));
    let attenuated = every.records.iter().filter(|r| r.throughput < 0.9).count();
    assert!(attenuated >= deeper / 2, "{attenuated} of {deeper}");
}

#[test]
fn delta_vertices_do_not_count_as_guided_bounces() {
    // Behind cornell-glossy's smooth glass sphere, the first vertex a guide of one bounce
    // serves is the one the path reaches through the glass, not a camera ray's hit.
    let params = [("res".to_string(), "16".to_string())];
    let scene = nis_render::scenes::load_with("cornell-glossy", &params).unwrap();
    let guide = one_bounce_guide(&scene, Some(2));
    let beyond_glass = beyond_first_hit(&scene, &guide.records);
    assert!(
        beyond_glass > 0 && beyond_glass < guide.records.len() / 4,
        "{beyond_glass} of {} records beyond the first hit",
        guide.records.len()
    );
}

/// A Mitsuba 3 scene of `shapes` under a constant sky of `radiance`, seen by a camera of field
/// of view `fov` degrees on the z axis at `z`, looking at the origin, with a film of `size`.
fn under_a_sky((fov, z): (f32, f32), size: (u32, u32), radiance: &str, shapes: &str) -> String {
    format!(
        r#"<scene version="3.0.0">
        <sensor type="perspective">
            <float name="fov" value="{fov}"/>
            <transform name="to_world"><lookat origin="0, 0, {z}" target="0, 0, 0" up="0, 1, 0"/></transform>
            <film type="hdrfilm"><integer name="width" value="{}"/><integer name="height" value="{}"/></film>
        </sensor>
        <emitter type="constant"><rgb name="radiance" value="{radiance}"/></emitter>
        {shapes}
    </scene>"#,
        size.0, size.1
    )
}

#[test]
fn diffuse_sphere_under_a_uniform_sky_reflects_albedo_times_sky() {
    // The camera sees only the sphere; a convex one-sided diffuse surface lit by a constant
    // environment reflects exactly albedo × radiance, whatever the strategy.
    let sphere = r#"<shape type="sphere">
            <float name="radius" value="1"/>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf>
        </shape>"#;
    let xml = under_a_sky((10.0, 5.0), (8, 8), "1, 2, 3", sphere);
    let scene = load_scene_str(&xml, Path::new("."), "sky.xml", &[]).unwrap();
    let expected = [0.6, 1.0, 1.2];
    let check = |(mean, err): ([f64; 3], [f64; 3]), what: &str| {
        for c in 0..3 {
            let tol = 4.0 * err[c] + 1e-5;
            assert!(
                (mean[c] - expected[c]).abs() < tol,
                "{what} channel {c}: {} vs {} (4σ = {tol})",
                mean[c],
                expected[c]
            );
        }
    };
    for strategy in [Strategy::Mis, Strategy::Nee, Strategy::Bsdf] {
        check(
            mean_over_seeds(&scene, strategy, &mut NoGuide, 16),
            &format!("{strategy:?}"),
        );
    }
    // With a guide mixed in, the sky reached by the mixture's sample and the sky sampled by
    // next-event estimation must be weighed by the same pair of densities. Weighing one against
    // the BSDF's density and the other against the mixture's loses 8% of the light here.
    let mut guide = UniformGuide::default();
    check(
        mean_over_seeds(&scene, Strategy::Mis, &mut guide, 16),
        "guided MIS",
    );
}

#[test]
fn wavefront_batches_do_not_change_the_image() {
    let params = [("res".to_string(), "20".to_string())];
    let scene = nis_render::scenes::load_with("cornell-glossy", &params).unwrap();
    let path_tracer = PathTracer::from_scene(&scene, Strategy::Mis);
    let images: Vec<_> = [1, 7, 4096]
        .into_iter()
        .map(|b| {
            render(
                &scene,
                &RenderOptions {
                    path_tracer,
                    budget: Budget::Samples(4),
                    seed: 3,
                    schedule: Schedule::Plain,
                },
                &mut UniformGuide {
                    batch: b,
                    ..UniformGuide::default()
                },
                &|_| {},
            )
            .image
            .pixels
        })
        .collect();
    assert!(images[0].iter().any(|p| p.max_element() > 0.0));
    assert_eq!(images[0], images[1]);
    assert_eq!(images[0], images[2]);
}

#[test]
fn lobes_narrower_than_the_guide_serves_are_left_to_the_bsdf_and_stay_unbiased() {
    // Two metal spheres under a sky: GGX α = 0.02 on the left (a lobe of 6.9°, narrower than
    // the default's 22.5°), α = 0.3 on the right (84°).
    let shapes = r#"<shape type="rectangle">
            <transform name="to_world"><scale value="10"/><rotate x="1" angle="-90"/><translate y="-1"/></transform>
            <emitter type="area"><rgb name="radiance" value="2, 1, 0.5"/></emitter>
        </shape>
        <shape type="sphere"><point name="center" x="-1.2" y="0" z="0"/>
            <bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.02"/></bsdf>
        </shape>
        <shape type="sphere"><point name="center" x="1.2" y="0" z="0"/>
            <bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf>
        </shape>"#;
    let xml = under_a_sky((40.0, 6.0), (12, 8), "1, 1, 1", shapes);
    let scene = load_scene_str(&xml, Path::new("."), "metals.xml", &[]).unwrap();
    let mut guide = UniformGuide::default();
    assert_unbiased(
        &scene,
        &mut guide,
        "a guide that leaves the narrow lobe to the BSDF",
    );
    let left = |g: &UniformGuide| g.records.iter().filter(|r| r.vertex.p.x < 0.0).count();
    let right = |g: &UniformGuide| g.records.iter().filter(|r| r.vertex.p.x > 0.0).count();
    assert_eq!(left(&guide), 0);
    assert!(right(&guide) > 100, "{}", right(&guide));
    let mut every = UniformGuide {
        lobe: Some(0.0),
        ..UniformGuide::default()
    };
    mean_over_seeds(&scene, Strategy::Mis, &mut every, 2);
    assert!(left(&every) > 100, "{}", left(&every));
}
