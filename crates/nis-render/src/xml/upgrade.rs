//! Mitsuba 0.x scenes (`<scene version="0.5.0">`) read by their own names: the upgrade that
//! Mitsuba 3 applies to files older than 2.0 (its `parser.cpp`, `upgrade_from_v1`: camelCase
//! property names become snake_case, a diffuse BSDF's `diffuse_reflectance` its `reflectance`,
//! `uoffset`/`uscale`… a `to_uv` transform), and what it leaves out: `<lookAt>` (0.4's
//! spelling of `<lookat>`), `<srgb>` colours (gamma-encoded, decoded to linear `<rgb>`), the
//! `sunsky` emitter, which Mitsuba 3 redefined (see [`upgrade_sunsky`]), and `roughdiffuse`
//! (Oren–Nayar), which Mitsuba 3 dropped: read as `diffuse` of the same reflectance, with a
//! warning (Bitterli's living room has one, reflectance 0.1).

use super::dom::{err, parse_vector, Element, XmlError};
use crate::spectrum::srgb_to_linear;

/// Whether a `<scene version=…>` predates Mitsuba 2's names (no version: Mitsuba 3's).
pub fn is_legacy(root: &Element) -> Result<bool, XmlError> {
    let Some(v) = root.attr("version") else {
        return Ok(false);
    };
    let major = v.split('.').next().unwrap_or("");
    match major.trim().parse::<u32>() {
        Ok(m) => Ok(m < 2),
        Err(_) => err(root.line, format!("unreadable scene version '{v}'")),
    }
}

/// `maxDepth` → `max_depth`, `intIOR` → `int_ior`: an underscore before an upper-case letter
/// that follows a lower-case one, and that run of capitals lowered.
pub fn camel_to_snake(name: &str) -> String {
    let chars: Vec<char> = name.chars().collect();
    let mut out = String::with_capacity(name.len() + 4);
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if i > 0 && chars[i - 1].is_ascii_lowercase() && c.is_ascii_uppercase() {
            out.push('_');
            while i < chars.len() && chars[i].is_ascii_uppercase() {
                out.push(chars[i].to_ascii_lowercase());
                i += 1;
            }
            continue;
        }
        out.push(c);
        i += 1;
    }
    out
}

/// Rewrite a legacy scene tree in place into Mitsuba 3's names; what it reads differently from
/// the file's own renderer goes to `warnings` with its line.
pub fn upgrade(el: &mut Element, warnings: &mut Vec<(usize, String)>) -> Result<(), XmlError> {
    if el.name == "lookAt" {
        el.name = "lookat".into();
    }
    if el.name == "srgb" {
        let v = parse_vector(el.required("value")?, el.line)?;
        let linear = v.to_array().map(srgb_to_linear);
        el.name = "rgb".into();
        el.set_attr(
            "value",
            format!("{}, {}, {}", linear[0], linear[1], linear[2]),
        );
    }
    if el.name != "default" {
        if let Some(name) = el.attr("name").map(camel_to_snake) {
            el.set_attr("name", name);
        }
    }
    let diffuse = el.name == "bsdf" && el.attr("type") == Some("diffuse");
    let mut uv: [Option<String>; 4] = Default::default();
    for c in &mut el.children {
        upgrade(c, warnings)?;
        if diffuse && c.attr("name") == Some("diffuse_reflectance") {
            c.set_attr("name", "reflectance");
        }
        if c.name == "float" {
            let slot = ["uoffset", "voffset", "uscale", "vscale"]
                .iter()
                .position(|n| c.attr("name") == Some(n));
            if let Some(i) = slot {
                uv[i] = Some(c.required("value")?.to_string());
            }
        }
    }
    if el.name == "emitter" && el.attr("type") == Some("sunsky") {
        upgrade_sunsky(el, warnings)?;
    }
    if el.name == "bsdf" && el.attr("type") == Some("roughdiffuse") {
        upgrade_roughdiffuse(el, warnings);
    }
    if uv.iter().any(Option::is_some) {
        let line = el.line;
        el.children.retain(|c| {
            !(c.name == "float"
                && matches!(
                    c.attr("name"),
                    Some("uoffset" | "voffset" | "uscale" | "vscale")
                ))
        });
        let get = |i: usize, default: &str| uv[i].clone().unwrap_or_else(|| default.into());
        let op = |name: &str, x: String, y: String, z: &str| Element {
            name: name.into(),
            attrs: vec![("x".into(), x), ("y".into(), y), ("z".into(), z.into())],
            children: Vec::new(),
            line,
        };
        // Mitsuba 3: to_uv = scale · translate (the offset applies first).
        el.children.push(Element {
            name: "transform".into(),
            attrs: vec![("name".into(), "to_uv".into())],
            children: vec![
                op("translate", get(0, "0"), get(1, "0"), "0"),
                op("scale", get(2, "1"), get(3, "1"), "1"),
            ],
            line,
        });
    }
    Ok(())
}

/// A Mitsuba 0.x `roughdiffuse` as Mitsuba 3's `diffuse`: its reflectance kept, its roughness
/// (`alpha`, `use_fast_approx`) dropped. Mitsuba 3 has no rough diffuse BSDF, so this is the
/// scene Mitsuba 3 can render too; the rough surface's retro-reflection is lost.
fn upgrade_roughdiffuse(el: &mut Element, warnings: &mut Vec<(usize, String)>) {
    let alpha = el
        .children
        .iter()
        .find(|c| c.attr("name") == Some("alpha"))
        .and_then(|c| c.attr("value"))
        .unwrap_or("0.2")
        .to_string();
    el.children
        .retain(|c| !matches!(c.attr("name"), Some("alpha" | "use_fast_approx")));
    el.set_attr("type", "diffuse");
    warnings.push((
        el.line,
        format!(
            "Mitsuba 0.x roughdiffuse (Oren-Nayar, alpha {alpha}) read as diffuse of the same \
             reflectance: Mitsuba 3 has no rough diffuse BSDF"
        ),
    ));
}

/// Mitsuba 0.5's apparent diameter of the sun, degrees (its `SUN_APP_RADIUS`).
const SUN_DIAMETER_0_5: f32 = 0.5358;

/// Mitsuba 3 → Mitsuba 0.5 sky frames, row by row: 0.5's sky has y up and puts the sun of
/// zenith angle θ and azimuth φ at `(sin φ sin θ, cos θ, −cos φ sin θ)`, Mitsuba 3's has z up
/// and puts it at `(−cos φ sin θ, −sin φ sin θ, cos θ)`; this map (a reflection) takes the
/// second onto the first, so that the date, time and place put the sun where 0.5 put it.
pub const SKY_FRAME_0_5: &str = "0 -1 0 0 0 0 1 0 1 0 0 0 0 0 0 1";

/// A Mitsuba 0.5 `sunsky` (names already snake_case) in Mitsuba 3's terms, as closely as they
/// say it: its y-up frame by [`SKY_FRAME_0_5`] before its `to_world`; `scale` as the default
/// of both `sun_scale` and `sky_scale` (as 0.5 reads it); `sun_radius_scale` r, which keeps the
/// sun's power, as `sun_aperture` = r · 0.5358°, which keeps it too; 0.5's ground albedo
/// default, 0.15; `resolution` (the size of the image 0.5 rasterised the sky into) dropped.
/// The radiance is Mitsuba 3's model (Hosek–Wilkie sky and sun from its tables), not 0.5's.
fn upgrade_sunsky(el: &mut Element, warnings: &mut Vec<(usize, String)>) -> Result<(), XmlError> {
    let line = el.line;
    let take = |el: &mut Element, name: &str| -> Result<Option<f32>, XmlError> {
        let Some(i) = el
            .children
            .iter()
            .position(|c| c.attr("name") == Some(name))
        else {
            return Ok(None);
        };
        let c = el.children.remove(i);
        super::dom::parse_float(c.required("value")?, c.line).map(Some)
    };
    let has = |el: &Element, name: &str| el.children.iter().any(|c| c.attr("name") == Some(name));
    let float = |name: &str, value: f32| Element {
        name: "float".into(),
        attrs: vec![
            ("name".into(), name.into()),
            ("value".into(), value.to_string()),
        ],
        children: Vec::new(),
        line,
    };
    let mut notes = vec!["its y-up frame turned onto Mitsuba 3's z-up sky".to_string()];
    if let Some(s) = take(el, "scale")? {
        for name in ["sun_scale", "sky_scale"] {
            if !has(el, name) {
                el.children.push(float(name, s));
            }
        }
        notes.push(format!("scale {s} as sun_scale and sky_scale"));
    }
    if let Some(r) = take(el, "sun_radius_scale")? {
        if r.is_nan() || r <= 0.0 {
            return err(
                line,
                format!("sunRadiusScale = {r} (a sun without a disk) has no Mitsuba 3 sunsky equivalent"),
            );
        }
        if has(el, "sun_aperture") {
            return err(
                line,
                "a sunsky takes sunRadiusScale or sun_aperture, not both",
            );
        }
        let aperture = r * SUN_DIAMETER_0_5;
        el.children.push(float("sun_aperture", aperture));
        notes.push(format!(
            "sunRadiusScale {r} as sun_aperture {aperture}° (both keep the sun's power)"
        ));
    }
    if let Some(s) = take(el, "stretch")? {
        if s != 1.0 {
            return err(line, format!("a sunsky's stretch = {s} (the sky below the horizon) has no Mitsuba 3 equivalent"));
        }
    }
    if take(el, "resolution")?.is_some() {
        notes.push("resolution ignored (the sky is evaluated, not rasterised)".into());
    }
    if !has(el, "albedo") {
        el.children.push(float("albedo", 0.15));
        notes.push("0.5's default albedo 0.15".into());
    }
    let frame = Element {
        name: "matrix".into(),
        attrs: vec![("value".into(), SKY_FRAME_0_5.into())],
        children: Vec::new(),
        line,
    };
    match el
        .children
        .iter_mut()
        .find(|c| c.name == "transform" && c.attr("name") == Some("to_world"))
    {
        Some(t) => t.children.insert(0, frame),
        None => el.children.push(Element {
            name: "transform".into(),
            attrs: vec![("name".into(), "to_world".into())],
            children: vec![frame],
            line,
        }),
    }
    warnings.push((
        line,
        format!(
            "Mitsuba 0.5 sunsky read in Mitsuba 3's terms: {}; its radiance is Mitsuba 3's \
             model (Hosek-Wilkie sky and sun from Mitsuba 3's tables), not 0.5's",
            notes.join(", ")
        ),
    ));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camel_case_names_become_mitsuba_3_names() {
        for (old, new) in [
            ("maxDepth", "max_depth"),
            ("toWorld", "to_world"),
            ("intIOR", "int_ior"),
            ("sampleCount", "sample_count"),
            ("specularReflectance", "specular_reflectance"),
            ("fov", "fov"),
            ("alpha_u", "alpha_u"),
            ("extEta", "ext_eta"),
        ] {
            assert_eq!(camel_to_snake(old), new);
        }
    }

    #[test]
    fn a_legacy_tree_is_renamed_and_its_lookat_and_uv_offsets_upgraded() {
        let mut root = super::super::dom::parse(
            r#"<scene version="0.5.0"><default name="fooBar" value="1"/>
                 <bsdf type="diffuse"><srgb name="diffuseReflectance" value="0.5"/></bsdf>
                 <texture type="bitmap"><float name="uscale" value="4"/></texture>
                 <transform name="toWorld"><lookAt origin="0,0,0" target="0,0,1"/></transform>
               </scene>"#,
        )
        .unwrap();
        assert!(is_legacy(&root).unwrap());
        upgrade(&mut root, &mut Vec::new()).unwrap();
        assert_eq!(root.children[0].attr("name"), Some("fooBar"));
        let rgb = &root.children[1].children[0];
        assert_eq!(
            (rgb.name.as_str(), rgb.attr("name")),
            ("rgb", Some("reflectance"))
        );
        let v: f32 = rgb
            .attr("value")
            .unwrap()
            .split(',')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!((v - 0.214_041).abs() < 1e-5, "{v}");
        let tex = &root.children[2];
        assert_eq!(tex.children.len(), 1);
        assert_eq!(tex.children[0].attr("name"), Some("to_uv"));
        assert_eq!(root.children[3].attr("name"), Some("to_world"));
        assert_eq!(root.children[3].children[0].name, "lookat");
    }

    #[test]
    fn a_legacy_roughdiffuse_becomes_a_diffuse_of_its_reflectance() {
        let mut root = super::super::dom::parse(
            r#"<scene version="0.6.0"><bsdf type="roughdiffuse">
                 <rgb name="reflectance" value="0.1, 0.2, 0.3"/><float name="alpha" value="1"/>
                 <boolean name="useFastApprox" value="true"/>
               </bsdf></scene>"#,
        )
        .unwrap();
        let mut warnings = Vec::new();
        upgrade(&mut root, &mut warnings).unwrap();
        let b = &root.children[0];
        assert_eq!(b.attr("type"), Some("diffuse"));
        assert_eq!(b.children.len(), 1);
        assert_eq!(b.children[0].attr("name"), Some("reflectance"));
        assert_eq!(b.children[0].attr("value"), Some("0.1, 0.2, 0.3"));
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].1.contains("alpha 1"), "{warnings:?}");
    }

    #[test]
    fn a_0_5_sunsky_is_said_in_mitsuba_3_terms() {
        let mut root = super::super::dom::parse(
            r#"<scene version="0.5.0"><emitter type="sunsky">
                 <transform name="toWorld"><rotate y="1" angle="90"/></transform>
                 <float name="sunRadiusScale" value="4"/><float name="scale" value="50"/>
                 <float name="skyScale" value="2"/><integer name="resolution" value="512"/>
               </emitter></scene>"#,
        )
        .unwrap();
        let mut warnings = Vec::new();
        upgrade(&mut root, &mut warnings).unwrap();
        let e = &root.children[0];
        let value = |name: &str| {
            e.children
                .iter()
                .find(|c| c.attr("name") == Some(name))
                .and_then(|c| c.attr("value"))
                .map(str::to_string)
        };
        assert_eq!(value("sun_scale").as_deref(), Some("50"));
        assert_eq!(value("sky_scale").as_deref(), Some("2"));
        assert_eq!(value("sun_aperture").as_deref(), Some("2.1432"));
        assert_eq!(value("albedo").as_deref(), Some("0.15"));
        assert_eq!(
            (
                value("scale"),
                value("resolution"),
                value("sun_radius_scale")
            ),
            (None, None, None)
        );
        let t = e.children.iter().find(|c| c.name == "transform").unwrap();
        assert_eq!(t.children[0].attr("value"), Some(SKY_FRAME_0_5));
        assert_eq!(t.children[1].name, "rotate");
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].1.contains("sunRadiusScale 4"), "{:?}", warnings);
        for bad in [
            r#"<float name="sunRadiusScale" value="0"/>"#,
            r#"<float name="stretch" value="1.5"/>"#,
        ] {
            let mut root = super::super::dom::parse(&format!(
                r#"<scene version="0.5.0"><emitter type="sunsky">{bad}</emitter></scene>"#
            ))
            .unwrap();
            assert!(upgrade(&mut root, &mut Vec::new()).is_err(), "{bad}");
        }
    }
}
