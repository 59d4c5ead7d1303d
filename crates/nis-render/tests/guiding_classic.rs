//! The classical guides end to end: practical path guiding and the Gaussian-mixture guide,
//! trained on the Cornell box by a few render passes (learning from the paths of earlier
//! passes), leave the image unbiased.

use glam::Vec3;
use nis_render::guiding::gmm::{Gmm, GmmConfig};
use nis_render::guiding::ppg::{Ppg, PpgConfig};
use nis_render::guiding::{Guide, GuideVertex};
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{render, Budget, RenderOptions, Schedule};
use nis_render::scene::Scene;

mod common;
use common::assert_unbiased;

/// Train `guide` by `passes` render passes, freeze it, check it is used on the back wall,
/// and compare its mean image with the unguided one.
fn check_unbiased<G: Guide>(scene: &Scene, guide: &mut G, freeze: impl FnOnce(&mut G), name: &str) {
    let path_tracer = PathTracer::from_scene(scene, Strategy::Mis);
    for pass in 0..3 {
        render(
            scene,
            &RenderOptions {
                path_tracer,
                budget: Budget::Samples(16),
                seed: 1000 + pass,
                schedule: Schedule::Plain,
            },
            guide,
            &|_| {},
        );
    }
    freeze(guide);
    let wall = GuideVertex {
        p: Vec3::new(0.0, 1.0, -1.0),
        n: Vec3::Z,
        wo: Vec3::Z,
        transmissive: false,
    };
    assert_eq!(guide.selection_probability(&wall), 0.5, "{name} untrained");
    assert_unbiased(scene, guide, name);
}

fn cornell() -> Scene {
    let params = [("res".to_string(), "12".to_string())];
    nis_render::scenes::load_with("cornell-box", &params).unwrap()
}

#[test]
fn trained_ppg_leaves_the_image_unbiased() {
    let scene = cornell();
    let config = PpgConfig {
        spatial_threshold: 500.0,
        ..PpgConfig::default()
    };
    let mut guide = Ppg::new(scene.bounds(), config);
    check_unbiased(&scene, &mut guide, |g| g.set_learning(false), "PPG");
    assert!(guide.spatial_leaves() > 1);
    assert_eq!(guide.iterations(), 3, "frozen after three training passes");
}

#[test]
fn trained_gmm_leaves_the_image_unbiased() {
    let scene = cornell();
    let config = GmmConfig {
        split_threshold: 1000,
        ..GmmConfig::default()
    };
    let mut guide = Gmm::new(scene.bounds(), config);
    check_unbiased(&scene, &mut guide, |g| g.set_learning(false), "GMM");
    assert!(guide.spatial_leaves() > 1);
    assert_eq!(guide.iterations(), 3, "frozen after three training passes");
}
