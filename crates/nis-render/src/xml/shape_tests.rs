//! Reader tests of shapes: Mitsuba's `cylinder`, textures read from a mesh's own attributes
//! (`mesh_attribute`), and instancing (`shapegroup`, `instance`), as Mitsuba 3 reads them.

use super::tests::{load, SENSOR};

#[test]
fn a_cylinder_reads_p0_p1_and_radius_and_refuses_a_degenerate_one() {
    let with = |shape: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n{SENSOR}\n\n{shape}\n</scene>"
        ))
    };
    let s = with(r#"<shape type="cylinder"><point name="p0" x="1" y="0" z="0"/><point name="p1" x="1" y="3" z="0"/><float name="radius" value="0.5"/><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"#).unwrap();
    // An open tube, 2π r l, as a fine tessellation (0.01 % short).
    let area: f32 = s.lights.area.iter().map(|l| l.area).sum();
    assert!(
        (area / (3.0 * std::f32::consts::PI) - 1.0).abs() < 2e-4,
        "{area}"
    );
    for (shape, needle) in [
        (
            r#"<shape type="cylinder"><float name="radius" value="0"/></shape>"#,
            "radius",
        ),
        (
            r#"<shape type="cylinder"><point name="p0" x="1" y="1" z="1"/><point name="p1" x="1" y="1" z="1"/></shape>"#,
            "distinct",
        ),
        (
            r#"<shape type="cylinder"><float name="height" value="2"/></shape>"#,
            "height",
        ),
    ] {
        let e = with(shape).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
}

#[test]
fn a_mesh_attribute_needs_a_vertex_or_face_name_and_a_mesh_that_has_it() {
    let with = |body: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n{SENSOR}\n{body}\n</scene>"
        ))
    };
    let e = with(
        r#"<texture type="mesh_attribute" id="t"><string name="name" value="color"/></texture>"#,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.starts_with("test.xml:3:") && e.contains("\"vertex_\" or \"face_\""),
        "{e}"
    );
    let e = with(r#"<shape type="sphere"><bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/></texture></bsdf></shape>"#)
        .unwrap_err()
        .to_string();
    assert!(e.contains("'vertex_color'"), "{e}");
    let e = with(r#"<bsdf type="normalmap"><texture type="mesh_attribute" name="normalmap"><string name="name" value="vertex_n"/></texture><bsdf type="diffuse"/></bsdf>"#)
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("test.xml:3:") && e.contains("normal map"),
        "{e}"
    );
}

#[test]
fn instances_place_copies_of_their_shapegroup_and_refuse_what_mitsuba_refuses() {
    use crate::geometry::Ray;
    use glam::Vec3;
    let with = |body: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n{SENSOR}\n{body}\n</scene>"
        ))
    };
    // A unit rectangle facing +z and a sphere of radius 0.5 at x = 3, grouped; one instance
    // moves the group by +10 in y, the other mirrors it in z and scales it by 2 at y = -10.
    let group = r#"<shape type="shapegroup" id="g">
        <shape type="rectangle"><bsdf type="diffuse"/></shape>
        <shape type="sphere"><point name="center" x="3" y="0" z="0"/><float name="radius" value="0.5"/></shape>
    </shape>"#;
    let place = |m: &str| {
        format!(
            r#"<shape type="instance"><ref id="g"/><transform name="to_world">{m}</transform></shape>"#
        )
    };
    let s = with(&format!(
        "{group}\n{}\n{}",
        place(r#"<translate y="10"/>"#),
        place(r#"<scale x="2" y="2" z="-2"/><translate y="-10"/>"#)
    ))
    .unwrap();
    let hit = |o: Vec3, d: Vec3| s.intersect(&Ray::new(o, d), f32::INFINITY);
    // The group itself is not rendered.
    assert!(hit(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z).is_none());
    assert!(hit(Vec3::new(3.0, 0.0, 5.0), -Vec3::Z).is_none());
    // The first copy: the rectangle at y = 10 facing +z, the sphere at (3, 10, 0).
    let h = hit(Vec3::new(0.5, 10.5, 5.0), -Vec3::Z).unwrap();
    assert!(
        (h.t - 5.0).abs() < 1e-4 && h.ng.dot(Vec3::Z) > 0.99,
        "{h:?}"
    );
    assert!(hit(Vec3::new(0.0, 11.5, 5.0), -Vec3::Z).is_none());
    let h = hit(Vec3::new(3.0, 10.0, 5.0), -Vec3::Z).unwrap();
    assert!((h.t - 4.5).abs() < 1e-4, "{h:?}");
    // The second: twice the size at y = -10, the rectangle's normal mirrored to -z as Mitsuba
    // transforms it (a normal, not the winding), the sphere of radius 1 at (6, -10, 0).
    let h = hit(Vec3::new(1.5, -8.5, 5.0), -Vec3::Z).unwrap();
    assert!(
        (h.t - 5.0).abs() < 1e-4 && h.ng.dot(Vec3::Z) < -0.99,
        "{h:?}"
    );
    let h = hit(Vec3::new(6.0, -10.0, 5.0), -Vec3::Z).unwrap();
    assert!(
        (h.t - 4.0).abs() < 1e-4 && h.ng.dot(Vec3::Z) > 0.99,
        "{h:?}"
    );
    assert_eq!(s.triangle_count(), 4);

    // Errors, each with its line.
    for (body, line, needle) in [
        (
            r#"<shape type="instance"><transform name="to_world"><translate y="1"/></transform></shape>"#,
            3,
            "needs a <ref",
        ),
        (r#"<shape type="instance"><ref id="g"/></shape>"#, 3, "no shapegroup with id 'g'"),
        (
            "<bsdf type=\"diffuse\" id=\"g\"/>\n<shape type=\"instance\"><ref id=\"g\"/></shape>",
            4,
            "no shapegroup with id 'g'",
        ),
        (
            "<shape type=\"shapegroup\" id=\"g\">\n<shape type=\"rectangle\"><emitter type=\"area\"/></shape></shape>",
            4,
            "emitter",
        ),
        (
            "<shape type=\"shapegroup\" id=\"g\">\n<shape type=\"shapegroup\" id=\"h\"/></shape>",
            4,
            "nested",
        ),
        (
            "<shape type=\"shapegroup\" id=\"g\">\n<shape type=\"instance\"><ref id=\"h\"/></shape></shape>",
            4,
            "nested",
        ),
        (
            &format!("{group}\n{}", place(r#"<scale x="1" y="2" z="1"/>"#)),
            7,
            "sphere of line 5",
        ),
        (
            &format!("{group}\n{}\n<ref id=\"g\"/></shape>", place("").trim_end_matches("</shape>")),
            8,
            "only one shapegroup",
        ),
    ] {
        let e = with(body).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("test.xml:{line}:")) && e.contains(needle),
            "{body}: {e}"
        );
    }
    // A shear keeps every axis's length yet is no similarity: refused on a plain sphere too.
    let e = with(r#"<shape type="sphere"><transform name="to_world"><matrix value="1 0.6 0 0  0 0.8 0 0  0 0 1 0  0 0 0 1"/></transform></shape>"#)
        .unwrap_err()
        .to_string();
    assert!(e.contains("scale uniformly"), "{e}");
}
