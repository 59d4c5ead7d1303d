//! Reader tests of rough BSDFs' roughness: numbers or textures, isotropic or anisotropic, with
//! Mitsuba's rules for `alpha`, `alpha_u` and `alpha_v`.

use glam::Vec2;

use crate::bsdf::{Bsdf, Slot};
use crate::scene::Scene;
use crate::Error;

/// A scene with a checkerboard `c` (float colours 0.05 and 0.4) and `bsdf` on line 4.
fn with(bsdf: &str) -> Result<Scene, Error> {
    super::tests::with_checkerboard(0.05, 0.4, bsdf)
}

fn alphas(b: &Bsdf) -> (f32, f32) {
    match b {
        Bsdf::RoughConductor { dist, .. } | Bsdf::RoughDielectric { dist, .. } => {
            (dist.alpha_u, dist.alpha_v)
        }
        other => panic!("{other:?}"),
    }
}

fn alpha(b: &Bsdf) -> f32 {
    let (u, v) = alphas(b);
    assert_eq!(u, v);
    u
}

#[test]
fn a_textured_alpha_is_looked_up_where_the_path_hits() {
    for bsdf in [
        r#"<bsdf type="roughconductor" id="b"><ref name="alpha" id="c"/></bsdf>"#,
        r#"<bsdf type="roughdielectric" id="b"><ref name="alpha" id="c"/></bsdf>"#,
        r#"<bsdf type="roughconductor" id="b"><ref name="alpha_u" id="c"/><ref name="alpha_v" id="c"/></bsdf>"#,
    ] {
        let s = with(bsdf).unwrap_or_else(|e| panic!("{bsdf}: {e}"));
        let m = s.materials.last().unwrap();
        assert_eq!(m.textures.len(), 1, "{bsdf}");
        assert_eq!(m.textures[0].0, Slot::Alpha);
        // The mean stands for it where one value is needed; a hit reads the texture's scalar
        // (Mitsuba's eval_1 puts color0 where eval puts color1).
        assert!((alpha(&m.bsdf) - 0.225).abs() < 1e-6, "{bsdf}");
        let a = alpha(&m.at(Vec2::new(0.25, 0.25)).unwrap().bsdf);
        let b = alpha(&m.at(Vec2::new(0.75, 0.25)).unwrap().bsdf);
        assert!((a - 0.4).abs() < 1e-6 && (b - 0.05).abs() < 1e-6, "{a} {b}");
    }
    // Equal numbers are isotropic; a zero roughness is raised to Mitsuba's least.
    let s = with(r#"<bsdf type="roughconductor" id="b"><float name="alpha_u" value="0.2"/><float name="alpha_v" value="0.2"/></bsdf>"#).unwrap();
    assert_eq!(alpha(&s.materials.last().unwrap().bsdf), 0.2);
    let s = with(r#"<bsdf type="roughdielectric" id="b"><float name="alpha" value="0"/></bsdf>"#)
        .unwrap();
    assert_eq!(alpha(&s.materials.last().unwrap().bsdf), 1e-4);
}

#[test]
fn anisotropic_roughness_is_read_as_numbers_or_textures() {
    let s = with(r#"<bsdf type="roughdielectric" id="b"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/></bsdf>"#).unwrap();
    let m = s.materials.last().unwrap();
    assert_eq!(alphas(&m.bsdf), (0.1, 0.3));
    assert!(m.is_anisotropic() && m.textures.is_empty());
    let s = with(r#"<bsdf type="roughconductor" id="b"><ref name="alpha_u" id="c"/><float name="alpha_v" value="0.1"/></bsdf>"#).unwrap();
    let m = s.materials.last().unwrap();
    assert_eq!(m.textures.len(), 1);
    assert_eq!(m.textures[0].0, Slot::AlphaU);
    assert!(m.is_anisotropic());
    let (u, v) = alphas(&m.at(Vec2::new(0.75, 0.25)).unwrap().bsdf);
    assert!((u - 0.05).abs() < 1e-6 && v == 0.1, "{u} {v}");
    let s = with(r#"<bsdf type="roughconductor" id="b"><float name="alpha" value="0.2"/></bsdf>"#)
        .unwrap();
    assert!(!s.materials.last().unwrap().is_anisotropic());
}

#[test]
fn ill_given_roughness_is_refused_with_its_line() {
    for (bsdf, needle) in [
        (
            r#"<bsdf type="roughdielectric" id="b"><float name="alpha_u" value="0.1"/></bsdf>"#,
            "both alpha_u and alpha_v",
        ),
        (
            r#"<bsdf type="roughconductor" id="b"><float name="alpha" value="0.1"/><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.1"/></bsdf>"#,
            "not both",
        ),
        (
            r#"<bsdf type="roughconductor" id="b"><float name="alpha" value="-0.1"/></bsdf>"#,
            "non-negative",
        ),
        (
            r#"<bsdf type="roughplastic" id="b"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/></bsdf>"#,
            "isotropic",
        ),
        // Mitsuba's rough plastic takes a number: its coating tables depend on it.
        (
            r#"<bsdf type="roughplastic" id="b"><ref name="alpha" id="c"/></bsdf>"#,
            "parameter 'alpha' of <bsdf type=\"roughplastic\"> cannot be a texture",
        ),
    ] {
        let e = with(bsdf).unwrap_err().to_string();
        assert!(e.starts_with("test.xml:4:") && e.contains(needle), "{e}");
    }
}
