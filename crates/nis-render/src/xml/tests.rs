//! Loader tests: every built-in scene loads; Mitsuba conventions; errors name what and where.

use super::*;
use crate::bsdf::Bsdf;
use crate::geometry::Rgb;

#[test]
fn every_built_in_scene_loads_with_its_defaults() {
    for name in crate::scenes::names() {
        let s = crate::scenes::load(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((s.camera.width(), s.camera.height()), (256, 256));
        assert_eq!(s.settings.spp, 64);
        assert!(!s.lights.area.is_empty(), "{name} has no light");
    }
    let params = [
        ("spp".to_string(), "3".to_string()),
        ("res".into(), "10".into()),
    ];
    let s = crate::scenes::load_with("cornell-box", &params).unwrap();
    assert_eq!((s.settings.spp, s.camera.width()), (3, 10));
}

pub(super) fn load(xml: &str) -> Result<Scene, Error> {
    load_scene_str(xml, Path::new("."), "test.xml", &[])
}

/// A scene with a checkerboard `c` of float colours `c0` and `c1` and `element` on line 4 (for
/// the reader tests of textured parameters).
pub(super) fn with_checkerboard(c0: f32, c1: f32, element: &str) -> Result<Scene, Error> {
    load(&format!(
        "<scene version=\"3.0.0\">\n{SENSOR}\n\
         <texture type=\"checkerboard\" id=\"c\"><float name=\"color0\" value=\"{c0}\"/><float name=\"color1\" value=\"{c1}\"/></texture>\n\
         {element}\n</scene>"
    ))
}

pub(super) const SENSOR: &str =
    r#"<sensor type="perspective"><float name="fov" value="45"/></sensor>"#;

#[test]
fn errors_name_the_unsupported_element_and_its_line() {
    let e = load(&format!(
        "<scene version=\"3.0.0\">\n{SENSOR}\n<shape type=\"ply\"/>\n</scene>"
    ))
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("test.xml:3:") && e.contains("ply"), "{e}");
    let e = load(&format!(
        "<scene>\n{SENSOR}\n<shape type=\"cube\">\n<float name=\"radius\" value=\"1\"/>\n</shape></scene>"
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("test.xml:4") && e.contains("radius"), "{e}");
    let e = load(&format!(
        "<scene>{SENSOR}<bsdf type=\"roughconductor\" id=\"a\"><string name=\"distribution\" value=\"phong\"/></bsdf></scene>"
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("phong") && e.contains("beckmann, ggx"), "{e}");
    let e = load("<scene>\n<shape type=\"cube\">\n</scene>")
        .unwrap_err()
        .to_string();
    assert!(e.contains("test.xml:3"), "{e}");
    let e = load(&format!(
        "<scene>{SENSOR}<shape type=\"cube\"><ref id=\"nope\"/></shape></scene>"
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("nope"), "{e}");
    // Mitsuba 0.x's bitmap gamma other than sRGB (−1) or linear (1) has no reading; the
    // power is checked before the file is looked for.
    let e = load(&format!(
        "<scene>{SENSOR}<texture type=\"bitmap\" id=\"t\">\n<string name=\"filename\" value=\"x.png\"/><float name=\"gamma\" value=\"2.2\"/></texture></scene>"
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("gamma 2.2") && e.contains("raw"), "{e}");
}

#[test]
fn missing_mesh_is_named_with_the_scene_line() {
    let e = load(&format!(
        "<scene>{SENSOR}\n<shape type=\"obj\">\n<string name=\"filename\" value=\"meshes/gone.obj\"/></shape></scene>"
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("test.xml:2") && e.contains("meshes/gone.obj"),
        "{e}"
    );
}

#[test]
fn obj_meshes_load_relative_to_the_scene() {
    let dir = std::env::temp_dir().join(format!("nis-render-xml-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("tri.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n",
    )
    .unwrap();
    let xml = format!(
        "<scene>{SENSOR}<shape type=\"obj\"><string name=\"filename\" value=\"tri.obj\"/><boolean name=\"face_normals\" value=\"true\"/></shape></scene>"
    );
    std::fs::write(dir.join("s.xml"), xml).unwrap();
    let s = load_scene(&dir.join("s.xml"), &[]).unwrap();
    assert_eq!(s.triangle_count(), 2);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn defaults_are_overridden_by_parameters_and_must_exist() {
    let xml = "<scene><default name=\"w\" value=\"7\"/><sensor type=\"perspective\"><float name=\"fov\" value=\"45\"/><film type=\"hdrfilm\"><integer name=\"width\" value=\"$w\"/><integer name=\"height\" value=\"$h\"/></film></sensor></scene>";
    let e = load(xml).unwrap_err().to_string();
    assert!(e.contains("$h"), "{e}");
    let params = [("h".to_string(), "5".to_string()), ("w".into(), "9".into())];
    let s = load_scene_str(xml, Path::new("."), "t", &params).unwrap();
    assert_eq!((s.camera.width(), s.camera.height()), (9, 5));
}

#[test]
fn bsdfs_read_mitsuba_parameters() {
    let xml = format!(
        r#"<scene>{SENSOR}
        <bsdf type="twosided" id="paper"><bsdf type="diffuse"><float name="reflectance" value="0.25"/></bsdf></bsdf>
        <bsdf type="dielectric" id="water"><string name="int_ior" value="water"/><float name="ext_ior" value="1"/></bsdf>
        <bsdf type="conductor" id="mirror"/>
        <shape type="rectangle"><ref id="paper"/></shape>
        <shape type="rectangle"><ref id="water"/></shape>
        <shape type="rectangle"><ref id="mirror"/></shape>
        <shape type="cube"/>
        </scene>"#
    );
    let s = load(&xml).unwrap();
    assert!(s.materials[0].two_sided);
    assert_eq!(
        s.materials[0].bsdf,
        Bsdf::Diffuse {
            reflectance: Rgb::splat(0.25)
        }
    );
    assert!(
        matches!(s.materials[1].bsdf, Bsdf::Dielectric { eta, .. } if (eta - 1.333).abs() < 1e-6)
    );
    assert!(
        matches!(s.materials[2].bsdf, Bsdf::Conductor { eta, k, .. } if eta == Rgb::ZERO && k == Rgb::ONE)
    );
    // A shape without a bsdf gets Mitsuba's default: diffuse 0.5.
    assert_eq!(
        s.materials[3].bsdf,
        Bsdf::Diffuse {
            reflectance: Rgb::splat(0.5)
        }
    );
}

// Regressions found by the fuzz tests (tests/fuzz_readers.rs).

#[test]
fn deep_nesting_is_an_error_not_a_stack_overflow() {
    let depth = 100_000;
    let xml = format!(
        "<scene>{}{}</scene>",
        "<transform>".repeat(depth),
        "</transform>".repeat(depth)
    );
    let e = load(&xml).unwrap_err().to_string();
    assert!(e.contains("nest deeper than 64"), "{e}");
    let twosided = format!(
        "<scene>{SENSOR}{}<bsdf type=\"diffuse\"/>{}</scene>",
        "<bsdf type=\"twosided\">".repeat(depth),
        "</bsdf>".repeat(depth)
    );
    assert!(load(&twosided).is_err());
}

#[test]
fn parameters_substitute_once_and_within_a_budget() {
    // A default that refers to itself used to loop for ever, doubling the string.
    let xml = format!(
        "<scene><default name=\"a\" value=\"$a$a\"/>{SENSOR}<shape type=\"cube\"><string name=\"x\" value=\"$a\"/></shape></scene>"
    );
    let e = load(&xml).unwrap_err().to_string();
    assert!(e.contains("unsupported parameter 'x'"), "{e}");
    // Many references to a long value: the expansion is bounded by the file's size.
    let long = "9".repeat(50_000);
    let many = format!(
        "<scene><default name=\"a\" value=\"{long}\"/>{SENSOR}<shape type=\"cube\"><string name=\"y\" value=\"{}\"/></shape></scene>",
        "$a".repeat(20_000)
    );
    let e = load(&many).unwrap_err().to_string();
    assert!(e.contains("implausibly large"), "{e}");
}

#[test]
fn absurd_numbers_are_errors_not_wrapped_or_infinite_values() {
    let cornell = |k: &str, v: &str| {
        crate::scenes::load_with("cornell-box", &[(k.to_string(), v.to_string())])
            .map(|s| (s.camera.width(), s.settings.spp, s.settings.max_depth))
    };
    for (k, v) in [
        ("res", "2147483648"),
        ("res", "4294967297"),
        ("res", "100000"),
        ("res", "0"),
        ("spp", "-5"),
        ("spp", "0"),
        ("spp", "4294967296"),
        ("max_depth", "-2"),
        ("max_depth", "2147483648"),
    ] {
        let e = cornell(k, v).unwrap_err().to_string();
        assert!(
            e.contains("out of range") || e.contains("film of"),
            "{k}={v}: {e}"
        );
    }
    assert_eq!(cornell("res", "8192").unwrap().0, 8192);
    assert_eq!(cornell("max_depth", "-1").unwrap().2, -1);
    for fov in ["1e39", "nan", "inf", "0", "180", "-10"] {
        let xml = format!(
            "<scene><sensor type=\"perspective\"><float name=\"fov\" value=\"{fov}\"/></sensor></scene>"
        );
        assert!(load(&xml).is_err(), "fov {fov} was accepted");
    }
    for value in ["1e39, 0, 0", "NaN", "-inf"] {
        let xml = format!(
            "<scene>{SENSOR}<bsdf type=\"diffuse\" id=\"a\"><rgb name=\"reflectance\" value=\"{value}\"/></bsdf></scene>"
        );
        let e = load(&xml).unwrap_err().to_string();
        assert!(e.contains("not a finite number"), "{value}: {e}");
    }
}

#[test]
fn includes_search_paths_and_referenced_emitters_load_as_mitsuba_reads_them() {
    let dir = std::env::temp_dir().join(format!("nis-include-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("common/meshes")).unwrap();
    std::fs::write(
        dir.join("common/meshes/tri.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("inc.xml"),
        format!(
            r#"<scene version="2.1.0"><default name="spp" value="7"/>{SENSOR}
               <emitter type="area" id="glow"><rgb name="radiance" value="2"/></emitter></scene>"#
        )
        .replace("<sensor type=\"perspective\">", "<sensor type=\"perspective\"><sampler type=\"independent\"><integer name=\"sample_count\" value=\"$spp\"/></sampler>"),
    )
    .unwrap();
    std::fs::write(
        dir.join("main.xml"),
        r#"<scene version="3.0.0"><path value="common"/><include filename="inc.xml"/>
             <shape type="obj"><string name="filename" value="meshes/tri.obj"/><ref id="glow"/></shape>
           </scene>"#,
    )
    .unwrap();
    let scene = load_scene(&dir.join("main.xml"), &[]).unwrap();
    assert_eq!(scene.settings.spp, 7);
    // A file in a subfolder that includes another by its path from the main file's folder, as
    // Mitsuba's participating-media test scenes do: found there, as Mitsuba's resolver finds it.
    std::fs::create_dir_all(dir.join("include")).unwrap();
    std::fs::write(
        dir.join("include/base.xml"),
        r#"<scene version="3.0.0"><include filename="include/glow.xml"/></scene>"#,
    )
    .unwrap();
    std::fs::write(
        dir.join("include/glow.xml"),
        r#"<scene version="3.0.0"><emitter type="area" id="glow"><rgb name="radiance" value="3"/></emitter></scene>"#,
    )
    .unwrap();
    std::fs::write(
        dir.join("nested.xml"),
        format!(
            r#"<scene version="3.0.0">{SENSOR}<include filename="include/base.xml"/>
             <shape type="rectangle"><ref id="glow"/></shape></scene>"#
        ),
    )
    .unwrap();
    let nested = load_scene(&dir.join("nested.xml"), &[]).unwrap();
    assert_eq!(nested.lights.area[0].radiance, Rgb::splat(3.0));
    assert_eq!(scene.lights.area.len(), 1);
    assert_eq!(scene.lights.area[0].radiance, Rgb::splat(2.0));
    std::fs::write(
        dir.join("loop.xml"),
        r#"<scene><include filename="loop.xml"/></scene>"#,
    )
    .unwrap();
    let e = load_scene(&dir.join("loop.xml"), &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("nest deeper"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn legacy_files_unknown_integrators_and_missing_features_say_what_and_where() {
    let s = load(&format!(
        "<scene version=\"0.5.0\">\n<integrator type=\"guided_path\"><integer name=\"maxDepth\" value=\"6\"/><string name=\"budgetType\" value=\"spp\"/></integrator>\n{SENSOR}\n</scene>"
    ))
    .unwrap();
    assert_eq!(s.settings.max_depth, 6);
    assert!(s.warnings[0].starts_with("test.xml:2:") && s.warnings[0].contains("guided_path"));
    for (element, needle) in [
        ("<medium type=\"homogeneous\" id=\"m\"/>", "medium"),
        ("<bsdf type=\"principledthin\" id=\"p\"/>", "principledthin"),
        ("<emitter type=\"sun\"/>", "sun"),
        ("<shape type=\"linearcurve\"/>", "linearcurve"),
    ] {
        let e = load(&format!("<scene>\n{SENSOR}\n{element}\n</scene>"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("test.xml:3:") && e.contains(needle), "{e}");
    }
}

#[test]
fn a_blendbsdf_mixes_two_plain_bsdfs_and_refuses_what_it_cannot_mix() {
    use crate::bsdf::{Blend, Bsdf};
    let with = |bsdf: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n{SENSOR}\n<bsdf type=\"diffuse\" id=\"d\"/>\n{bsdf}\n</scene>"
        ))
    };
    let s = with(
        r#"<bsdf type="blendbsdf" id="b"><float name="weight" value="1.3"/><ref id="d"/><bsdf type="conductor"/></bsdf>"#,
    )
    .unwrap();
    let Bsdf::Blend(b) = &s.materials.last().unwrap().bsdf else {
        panic!("{:?}", s.materials)
    };
    // Clipped to [0, 1] as Mitsuba does; the first BSDF by reference, the second inline.
    let Blend { weight, bsdfs } = &**b;
    assert_eq!(*weight, 1.0);
    assert!(matches!(bsdfs[0], Bsdf::Diffuse { .. }) && matches!(bsdfs[1], Bsdf::Conductor { .. }));
    for (bsdf, needle) in [
        (
            r#"<bsdf type="blendbsdf"><ref id="d"/><ref id="d"/></bsdf>"#,
            "weight",
        ),
        (
            r#"<bsdf type="blendbsdf"><float name="weight" value="0.5"/><ref id="d"/></bsdf>"#,
            "exactly two",
        ),
        (
            r#"<bsdf type="blendbsdf"><float name="weight" value="0.5"/><ref id="d"/><bsdf type="mask"><float name="opacity" value="0.5"/><ref id="d"/></bsdf></bsdf>"#,
            "masked",
        ),
        (
            r#"<bsdf type="blendbsdf"><float name="weight" value="0.5"/><ref id="d"/><bsdf type="twosided"><ref id="d"/></bsdf></bsdf>"#,
            "two-sided",
        ),
    ] {
        let e = with(bsdf).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
}

#[test]
fn a_principled_bsdf_reads_mitsubas_parameters() {
    use crate::bsdf::{Bsdf, PrincipledParam, Slot};
    let with = |bsdf: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n{SENSOR}\n<texture type=\"checkerboard\" id=\"c\"/>\n{bsdf}\n</scene>"
        ))
    };
    let s = with(r#"<bsdf type="principled" id="p"><rgb name="base_color" value="0.2, 0.4, 0.6"/><float name="specular" value="0.6"/><ref name="metallic" id="c"/><float name="sheen" value="0.3"/></bsdf>"#).unwrap();
    let m = s.materials.last().unwrap();
    let Bsdf::Principled(p) = &m.bsdf else {
        panic!("{:?}", m.bsdf)
    };
    // specular 0.6 is eta = 2 / (1 − √0.048) − 1; Mitsuba's defaults elsewhere.
    assert!((p.eta - (2.0 / (1.0 - 0.048f32.sqrt()) - 1.0)).abs() < 1e-6);
    assert_eq!((p.roughness, p.sheen, p.spec_trans), (0.5, 0.3, 0.0));
    assert_eq!(p.base_color, glam::Vec3::new(0.2, 0.4, 0.6));
    assert_eq!(m.textures[0].0, Slot::Principled(PrincipledParam::Metallic));
    // With a transmission lobe, an index of exactly 1 is nudged off it, as in Mitsuba.
    let s = with(r#"<bsdf type="principled" id="t"><float name="spec_trans" value="0.5"/><float name="eta" value="1"/></bsdf>"#).unwrap();
    let Bsdf::Principled(p) = &s.materials.last().unwrap().bsdf else {
        panic!()
    };
    assert_eq!(p.eta, 1.001);
    // Anisotropy, a number or a texture, asks for the ∂p/∂u frame.
    let s =
        with(r#"<bsdf type="principled" id="a"><float name="anisotropic" value="0.5"/></bsdf>"#)
            .unwrap();
    let m = s.materials.last().unwrap();
    assert!(m.is_anisotropic());
    let s =
        with(r#"<bsdf type="principled" id="a"><ref name="anisotropic" id="c"/></bsdf>"#).unwrap();
    let m = s.materials.last().unwrap();
    assert_eq!(
        m.textures[0].0,
        Slot::Principled(PrincipledParam::Anisotropic)
    );
    assert!(m.is_anisotropic());
    let s = with(r#"<bsdf type="principled" id="i"/>"#).unwrap();
    assert!(!s.materials.last().unwrap().is_anisotropic());
    for (bsdf, needle) in [
        (
            r#"<bsdf type="principled"><float name="anisotropic" value="1.5"/></bsdf>"#,
            "anisotropic = 1.5 must be in [0, 1]",
        ),
        (
            r#"<bsdf type="principled"><float name="eta" value="1.5"/><float name="specular" value="0.5"/></bsdf>"#,
            "not both",
        ),
        (
            r#"<bsdf type="principled"><float name="eta" value="-1"/></bsdf>"#,
            "positive",
        ),
        (
            r#"<bsdf type="principled"><float name="clearcoat_gloss" value="2"/></bsdf>"#,
            "clearcoat_gloss",
        ),
        (
            r#"<bsdf type="principled"><float name="sheeen" value="1"/></bsdf>"#,
            "sheeen",
        ),
        (
            r#"<bsdf type="principled"><ref name="eta" id="c"/></bsdf>"#,
            "eta",
        ),
    ] {
        let e = with(bsdf).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
}

#[test]
fn a_normalmap_needs_its_texture_and_mitsubas_defaults() {
    let with = |bsdf: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n{SENSOR}\n<bsdf type=\"diffuse\" id=\"d\"/>\n{bsdf}\n</scene>"
        ))
    };
    for (bsdf, needle) in [
        (
            r#"<bsdf type="normalmap"><ref id="d"/></bsdf>"#,
            "texture name=\"normalmap\"",
        ),
        (
            r#"<bsdf type="normalmap"><boolean name="use_shadowing_function" value="false"/><texture type="checkerboard" name="normalmap"/><ref id="d"/></bsdf>"#,
            "use_shadowing_function false",
        ),
    ] {
        let e = with(bsdf).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
    let s = with(r#"<bsdf type="normalmap" id="n"><texture type="checkerboard" name="normalmap"/><ref id="d"/></bsdf>"#)
        .unwrap();
    let bump = s.materials.last().unwrap().bump.as_ref().unwrap();
    assert_eq!(bump.map, crate::bump::BumpMap::Normal);
}

#[test]
fn thin_lens_and_orthographic_sensors_read_their_parameters_and_refuse_bad_ones() {
    use crate::camera::Projection;
    let with = |sensor: &str| load(&format!("<scene version=\"3.0.0\">\n{sensor}\n</scene>"));
    let s = with(
        r#"<sensor type="thinlens"><float name="fov" value="30"/><float name="aperture_radius" value="0.1"/><float name="focus_distance" value="4"/></sensor>"#,
    )
    .unwrap();
    assert_eq!(
        s.camera.projection,
        Projection::ThinLens {
            aperture_radius: 0.1,
            focus_distance: 4.0
        }
    );
    // Mitsuba's default focus: the far clip distance; a 0.x file's names are upgraded.
    let s = load(
        "<scene version=\"0.5.0\"><sensor type=\"thinlens\"><float name=\"fov\" value=\"30\"/><float name=\"apertureRadius\" value=\"0.2\"/><float name=\"farClip\" value=\"50\"/></sensor></scene>",
    )
    .unwrap();
    assert_eq!(
        s.camera.projection,
        Projection::ThinLens {
            aperture_radius: 0.2,
            focus_distance: 50.0
        }
    );
    let s = with(r#"<sensor type="orthographic"/>"#).unwrap();
    assert_eq!(s.camera.projection, Projection::Orthographic);
    for (sensor, needle) in [
        (
            r#"<sensor type="thinlens"><float name="fov" value="30"/></sensor>"#,
            "aperture_radius",
        ),
        (
            r#"<sensor type="thinlens"><float name="fov" value="30"/><float name="aperture_radius" value="0.1"/><float name="focus_distance" value="-1"/></sensor>"#,
            "focus_distance must be a positive number",
        ),
        (
            r#"<sensor type="thinlens"><float name="fov" value="30"/><string name="focal_length" value="35mm"/><float name="aperture_radius" value="0.1"/></sensor>"#,
            "not both",
        ),
        (
            r#"<sensor type="irradiancemeter"/>"#,
            "thinlens, orthographic",
        ),
    ] {
        let e = with(sensor).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:2:") && e.contains(needle), "{e}");
    }
}

#[test]
fn a_perspective_without_fov_reads_its_focal_length_along_the_diagonal() {
    let sensor = |props: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n\n\n<sensor type=\"perspective\">{props}</sensor>\n</scene>"
        ))
    };
    // Mitsuba 3's `parse_fov`: 2 atan(√(36² + 24²) / 2f), the `mm` optional, 50mm by default.
    let diagonal = |mm: f32| 2.0 * (1872f32.sqrt() / (2.0 * mm)).atan().to_degrees();
    for (props, mm) in [
        ("", 50.0),
        ("<string name=\"focal_length\" value=\"35mm\"/>", 35.0),
        ("<string name=\"focal_length\" value=\"24\"/>", 24.0),
    ] {
        let c = sensor(props).unwrap().camera;
        assert_eq!(c.fov_axis, crate::camera::FovAxis::Diagonal, "{props}");
        assert!((c.fov - diagonal(mm)).abs() < 1e-4, "{props}: {}", c.fov);
    }
    assert!((diagonal(50.0) - 46.793).abs() < 1e-3);
    for (props, needle) in [
        (
            "<float name=\"fov\" value=\"40\"/><string name=\"focal_length\" value=\"35mm\"/>",
            "not both",
        ),
        (
            "<string name=\"focal_length\" value=\"wide\"/>",
            "focal_length",
        ),
        (
            "<string name=\"focal_length\" value=\"-5mm\"/>",
            "focal_length",
        ),
    ] {
        let e = sensor(props).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
}

#[test]
fn a_rawconstant_is_its_value_as_given_and_a_vector_is_not_a_number() {
    use crate::texture::Texture;
    use glam::Vec2;
    let with = |bsdf: &str| {
        load(&format!(
            "<scene version=\"3.0.0\">\n{SENSOR}\n<bsdf type=\"diffuse\" id=\"d\"/>\n{bsdf}\n</scene>"
        ))
    };
    // Mitsuba's identity normal map: the vector as written, no colour conversion.
    let s = with(r#"<bsdf type="normalmap" id="n"><texture type="rawconstant" name="normalmap"><vector name="value" value="0.5, 0.5, 1.0"/></texture><ref id="d"/></bsdf>"#)
        .unwrap();
    let bump = s.materials.last().unwrap().bump.as_ref().unwrap();
    assert_eq!(
        *bump.texture,
        Texture::RawConstant {
            value: Rgb::new(0.5, 0.5, 1.0),
            vector: true
        }
    );
    assert_eq!(
        bump.texture.eval(Vec2::new(0.3, 0.9)),
        Rgb::new(0.5, 0.5, 1.0)
    );
    // A number fills every channel and is read as itself where a number is needed (not a
    // luminance); values outside [0, 1] are kept.
    let s = with(r#"<bsdf type="roughconductor" id="b"><texture type="rawconstant" name="alpha"><float name="value" value="0.3"/></texture><texture type="rawconstant" name="specular_reflectance"><vector name="value" value="1.5, -0.5, 0.2"/></texture></bsdf>"#)
        .unwrap();
    let m = s.materials.last().unwrap();
    let at = m.at(Vec2::new(0.1, 0.2)).unwrap();
    match at.bsdf {
        Bsdf::RoughConductor {
            dist,
            specular_reflectance,
            ..
        } => {
            assert_eq!((dist.alpha_u, dist.alpha_v), (0.3, 0.3));
            assert_eq!(specular_reflectance, Rgb::new(1.5, -0.5, 0.2));
        }
        ref b => panic!("{b:?}"),
    }
    for (bsdf, needle) in [
        (
            r#"<bsdf type="roughconductor"><texture type="rawconstant" name="alpha"><vector name="value" value="0.1, 0.2, 0.3"/></texture></bsdf>"#,
            "'alpha' is a number",
        ),
        (
            r#"<bsdf type="mask"><texture type="rawconstant" name="opacity"><vector name="value" value="1, 1, 1"/></texture><ref id="d"/></bsdf>"#,
            "'opacity' is a number",
        ),
        (
            r#"<bsdf type="diffuse"><texture type="rawconstant" name="reflectance"/></bsdf>"#,
            "needs a <float> or <vector>",
        ),
        (
            r#"<bsdf type="diffuse"><texture type="rawconstant" name="reflectance"><rgb name="value" value="0.5"/></texture></bsdf>"#,
            "must be one of",
        ),
    ] {
        let e = with(bsdf).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
}
