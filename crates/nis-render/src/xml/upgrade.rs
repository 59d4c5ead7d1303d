//! Mitsuba 0.x scenes (`<scene version="0.5.0">`) read by their own names: the upgrade that
//! Mitsuba 3 applies to files older than 2.0 (its `parser.cpp`, `upgrade_from_v1`: camelCase
//! property names become snake_case, a diffuse BSDF's `diffuse_reflectance` its `reflectance`,
//! `uoffset`/`uscale`… a `to_uv` transform), and what it leaves out: `<lookAt>` (0.4's
//! spelling of `<lookat>`) and `<srgb>` colours (gamma-encoded, decoded to linear `<rgb>`).

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

/// Rewrite a legacy scene tree in place into Mitsuba 3's names.
pub fn upgrade(el: &mut Element) -> Result<(), XmlError> {
    if el.name == "lookAt" {
        el.name = "lookat".into();
    }
    if el.name == "srgb" {
        let v = parse_vector(el.required("value")?, el.line)?;
        let linear = v.to_array().map(srgb_to_linear);
        el.name = "rgb".into();
        for (k, value) in &mut el.attrs {
            if k == "value" {
                *value = format!("{}, {}, {}", linear[0], linear[1], linear[2]);
            }
        }
    }
    if el.name != "default" {
        for (k, value) in &mut el.attrs {
            if k == "name" {
                *value = camel_to_snake(value);
            }
        }
    }
    let diffuse = el.name == "bsdf" && el.attr("type") == Some("diffuse");
    let mut uv: [Option<String>; 4] = Default::default();
    for c in &mut el.children {
        upgrade(c)?;
        if diffuse && c.attr("name") == Some("diffuse_reflectance") {
            c.attrs
                .iter_mut()
                .filter(|(k, _)| k == "name")
                .for_each(|(_, v)| *v = "reflectance".into());
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
        upgrade(&mut root).unwrap();
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
}
