//! Reader tests of emitters with textures: a spot's projected `texture`, as Mitsuba 3's
//! `spot.cpp` reads it, and errors for textures elsewhere.

use std::path::Path;

use glam::Vec3;

use super::load_scene_str;
use crate::light::DeltaLight;
use crate::scene::Scene;
use crate::Error;

/// A scene with a checkerboard `c` (colours 0.1 and 0.9) and `emitter` on line 4.
fn with(emitter: &str) -> Result<Scene, Error> {
    let xml = format!(
        "<scene version=\"3.0.0\">\n<sensor type=\"perspective\"><float name=\"fov\" value=\"45\"/></sensor>\n\
         <texture type=\"checkerboard\" id=\"c\"><float name=\"color0\" value=\"0.1\"/><float name=\"color1\" value=\"0.9\"/></texture>\n\
         {emitter}\n</scene>"
    );
    load_scene_str(&xml, Path::new("."), "test.xml", &[])
}

#[test]
fn a_spot_projects_its_texture_across_the_cone() {
    // Pointing down -z from the origin.
    let spot = |texture: &str| {
        let s = with(&format!(
            "<emitter type=\"spot\"><float name=\"cutoff_angle\" value=\"30\"/><rgb name=\"intensity\" value=\"2\"/>{texture}\
             <transform name=\"to_world\"><lookat origin=\"0, 0, 0\" target=\"0, 0, -1\" up=\"0, 1, 0\"/></transform></emitter>"
        ))
        .unwrap();
        let DeltaLight::Spot(l) = &s.lights.delta[0] else {
            panic!("not a spot")
        };
        l.clone()
    };
    let plain = spot("");
    let textured = spot("<ref name=\"texture\" id=\"c\"/>");
    // A local direction (x, y, 1) reads uv = ½ + ½ (x, y) / tan 30°; 0.4 tan 30° is within the
    // beam, and the mirrored direction falls in the other checker square.
    let t = 0.4 * 30f32.to_radians().tan();
    let world = |x: f32, y: f32| (textured.to_local.inverse() * Vec3::new(x, y, 1.0)).normalize();
    assert!((world(0.0, 0.0) - Vec3::NEG_Z).length() < 1e-6);
    assert_eq!(plain.intensity_towards(world(t, t)), Vec3::splat(2.0));
    // uv = (0.7, 0.7): colour0 (0.1); (0.3, 0.7): colour1 (0.9).
    let a = textured.intensity_towards(world(t, t));
    let b = textured.intensity_towards(world(-t, t));
    assert!((a - Vec3::splat(0.2)).abs().max_element() < 1e-5, "{a}");
    assert!((b - Vec3::splat(1.8)).abs().max_element() < 1e-5, "{b}");
}

#[test]
fn only_a_spot_takes_a_texture() {
    let e = with("<emitter type=\"directional\"><ref name=\"texture\" id=\"c\"/></emitter>")
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("test.xml:4:") && e.contains("spot"), "{e}");
    let e = with("<emitter type=\"spot\"><ref name=\"intensity\" id=\"c\"/></emitter>")
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("test.xml:4:"), "{e}");
}
