//! Reader tests of the `sunsky` emitter in Mitsuba 3's and Mitsuba 0.5's terms.

use super::tests::{load, SENSOR};
use crate::scene::Scene;
use crate::Error;

/// A Mitsuba 3 sunsky reads its parameters (and refuses a sun placed twice); a Mitsuba 0.5 one
/// keeps the sun where 0.5 put it. Skipped, with the reason, without Mitsuba's tables.
#[test]
fn a_sunsky_reads_mitsuba_3_and_0_5_files() {
    use crate::light::EnvironmentLight;
    use crate::sunsky::position::{spherical_direction, sun_coordinates};
    use crate::sunsky::{DateTime, Location};
    let scene = |version: &str, body: &str| {
        load(&format!(
            "<scene version=\"{version}\">\n{SENSOR}\n{body}\n</scene>"
        ))
    };
    let sun_of = |s: &Scene| match s.lights.environment_map.as_deref() {
        Some(EnvironmentLight::SunSky(sky)) => sky.sun_direction(),
        _ => panic!("no sunsky"),
    };
    let s = match scene(
        "3.0.0",
        r#"<emitter type="sunsky"><float name="hour" value="9"/></emitter>"#,
    ) {
        Err(e @ Error::MissingSunskyData { .. }) => {
            eprintln!("skipped: {e}");
            return;
        }
        r => r.unwrap(),
    };
    let t = DateTime {
        hour: 9.0,
        ..DateTime::default()
    };
    let (theta, phi) = sun_coordinates(&t, &Location::default());
    assert!((sun_of(&s) - spherical_direction(theta, phi)).length() < 1e-5);
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    for (body, needle) in [
        (
            r#"<vector name="sun_direction" x="0" y="0" z="1"/><float name="hour" value="9"/>"#,
            "not both",
        ),
        (r#"<float name="turbidity" value="11"/>"#, "turbidity"),
        (r#"<integer name="month" value="13"/>"#, "month"),
        (r#"<float name="sun_radius" value="2"/>"#, "sun_radius"),
    ] {
        let e = scene(
            "3.0.0",
            &format!("<emitter type=\"sunsky\">\n{body}</emitter>"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            (e.starts_with("test.xml:3:") || e.starts_with("test.xml:4:")) && e.contains(needle),
            "{e}"
        );
    }
    // Mitsuba 0.5: y up, the sun at (sin φ₀ sin θ, cos θ, −cos φ₀ sin θ) for the solar
    // azimuth φ₀ = φ + π, then turned by toWorld.
    let s = scene(
        "0.5.0",
        r#"<emitter type="sunsky"><transform name="toWorld"><rotate y="1" angle="90"/></transform>
           <float name="hour" value="9"/><float name="sunRadiusScale" value="4"/><float name="scale" value="50"/></emitter>"#,
    )
    .unwrap();
    let azimuth = phi + std::f32::consts::PI;
    let local = glam::Vec3::new(
        azimuth.sin() * theta.sin(),
        theta.cos(),
        -azimuth.cos() * theta.sin(),
    );
    let want = glam::Mat3::from_rotation_y(90f32.to_radians()) * local;
    assert!(
        (sun_of(&s) - want).length() < 1e-5,
        "{} vs {want}",
        sun_of(&s)
    );
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("0.5 sunsky") && w.contains("sun_aperture 2.1432")),
        "{:?}",
        s.warnings
    );
}
