//! Reader tests of emitters with textures: a spot's projected `texture` and a `projector`, as
//! Mitsuba 3's `spot.cpp` and `projector.cpp` read them, and errors for textures elsewhere.

use glam::Vec3;

use crate::light::{DeltaLight, ProjectorLight};
use crate::scene::Scene;
use crate::Error;

/// A scene with a checkerboard `c` (colours 0.1 and 0.9) and `emitter` on line 4.
fn with(emitter: &str) -> Result<Scene, Error> {
    super::tests::with_checkerboard(0.1, 0.9, emitter)
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

/// The projector of `with(emitter)`.
fn projector(emitter: &str) -> ProjectorLight {
    let s = with(emitter).unwrap();
    let DeltaLight::Projector(l) = &s.lights.delta[0] else {
        panic!("not a projector")
    };
    l.clone()
}

#[test]
fn a_projector_lights_its_frustum_as_mitsuba_normalises_it() {
    // Looking down -z from the origin with a 90° field of view: the image spans |x|, |y| ≤ z.
    let frame = "<transform name=\"to_world\"><lookat origin=\"0, 0, 0\" target=\"0, 0, -1\" up=\"0, 1, 0\"/></transform>";
    let plain = projector(&format!(
        "<emitter type=\"projector\"><float name=\"fov\" value=\"90\"/><rgb name=\"irradiance\" value=\"2\"/>\
         <float name=\"scale\" value=\"1.5\"/>{frame}</emitter>"
    ));
    let pi3 = std::f32::consts::PI * 3.0;
    let at = |l: &ProjectorLight, x: f32, y: f32, z: f32| {
        l.arriving_at(l.to_local.inverse().transform_point3(Vec3::new(x, y, z)))
    };
    // π · scale · E at z = 1 on the axis; over z² cos θ elsewhere; nothing outside.
    assert!(
        (at(&plain, 0.0, 0.0, 1.0) - Vec3::splat(pi3))
            .abs()
            .max_element()
            < 1e-4
    );
    let cos = 1.0 / 1.5f32.sqrt();
    let want = pi3 / (4.0 * cos);
    assert!(
        (at(&plain, 1.0, -1.0, 2.0) - Vec3::splat(want))
            .abs()
            .max_element()
            < 1e-4
    );
    assert_eq!(at(&plain, 1.2, 0.0, 1.0), Vec3::ZERO);
    assert_eq!(at(&plain, 0.0, 0.0, -1.0), Vec3::ZERO);
    // uv = ½ − ½ (x, y) / z: (0.25, 0.25) is colour0, (0.75, 0.25) colour1 (cos θ as above).
    let textured = projector(&format!(
        "<emitter type=\"projector\"><float name=\"fov\" value=\"90\"/><ref name=\"irradiance\" id=\"c\"/>{frame}</emitter>"
    ));
    let pi = std::f32::consts::PI / cos;
    assert!(
        (at(&textured, 0.5, 0.5, 1.0) - Vec3::splat(0.1 * pi))
            .abs()
            .max_element()
            < 1e-4
    );
    assert!(
        (at(&textured, -0.5, 0.5, 1.0) - Vec3::splat(0.9 * pi))
            .abs()
            .max_element()
            < 1e-4
    );
    // Mitsuba's default: a 50 mm focal length along the diagonal (46.8°), square for a colour.
    let default = projector("<emitter type=\"projector\"/>");
    let t = (23.4f32.to_radians()).tan() / 2f32.sqrt();
    assert!(
        (default.tan_half - glam::Vec2::splat(t))
            .abs()
            .max_element()
            < 1e-3
    );
}

#[test]
fn a_projector_takes_fov_or_focal_length_not_both() {
    let e = with("<emitter type=\"projector\"><float name=\"fov\" value=\"30\"/><string name=\"focal_length\" value=\"35mm\"/></emitter>")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("test.xml:4:") && e.contains("focal_length"),
        "{e}"
    );
    let e = with("<emitter type=\"projector\"><ref name=\"texture\" id=\"c\"/></emitter>")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("test.xml:4:") && e.contains("irradiance"),
        "{e}"
    );
}

#[test]
fn a_point_light_sits_at_its_position_or_to_worlds_origin() {
    let point = |emitter: &str| {
        let s = with(emitter).unwrap();
        match s.lights.delta[..] {
            [DeltaLight::Point {
                position,
                intensity,
            }] => (position, intensity),
            _ => panic!("not one point light"),
        }
    };
    // Mitsuba 3's `point.cpp`: intensity defaults to 1, the position to the origin.
    assert_eq!(point("<emitter type=\"point\"/>"), (Vec3::ZERO, Vec3::ONE));
    assert_eq!(
        point("<emitter type=\"point\"><rgb name=\"intensity\" value=\"2, 3, 4\"/><point name=\"position\" x=\"1\" y=\"2\" z=\"3\"/></emitter>"),
        (Vec3::new(1.0, 2.0, 3.0), Vec3::new(2.0, 3.0, 4.0))
    );
    assert_eq!(
        point("<emitter type=\"point\"><transform name=\"to_world\"><translate x=\"-1\" y=\"5\" z=\"0.5\"/></transform></emitter>").0,
        Vec3::new(-1.0, 5.0, 0.5)
    );
    // Next-event estimation sees intensity over distance².
    let s = with("<emitter type=\"point\"><rgb name=\"intensity\" value=\"8\"/><point name=\"position\" x=\"0\" y=\"2\" z=\"0\"/></emitter>").unwrap();
    let l = s
        .lights
        .sample(Vec3::ZERO, 0.5, glam::Vec2::splat(0.5))
        .unwrap();
    assert!(l.delta && l.pdf == 1.0 && l.dist == 2.0, "{l:?}");
    assert_eq!((l.wi, l.radiance), (Vec3::Y, Vec3::splat(2.0)));
    // Both places at once, as Mitsuba refuses; a texture.
    for (emitter, needle) in [
        (
            "<emitter type=\"point\"><point name=\"position\" x=\"1\" y=\"2\" z=\"3\"/><transform name=\"to_world\"><translate x=\"1\"/></transform></emitter>",
            "not both",
        ),
        ("<emitter type=\"point\"><ref name=\"intensity\" id=\"c\"/></emitter>", "spot"),
    ] {
        let e = with(emitter).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
}
