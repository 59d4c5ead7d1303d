//! BSDFs as Mitsuba 3 defines its plugins: `diffuse`, `conductor`, `roughconductor`,
//! `dielectric`, `roughdielectric`, `thindielectric`, `plastic`, `roughplastic`, `principled`
//! (read in `principled.rs`), and the wrappers `twosided`, `mask` and `bumpmap`; inline or
//! defined once and used by `<ref id=…>`. Rough BSDFs take Beckmann (Mitsuba's default) or GGX
//! microfacets; conductors an `eta`/`k` pair or a named `material` (`Au`, `Cu`, …,
//! `bsdf::conductors`).

use std::sync::Arc;

use super::dom::{err, Element, XmlError};
use super::fail;
use super::props::{ior, Props, PROPERTY_TAGS};
use super::texture::{check_not_attribute, check_scalar};
use super::{unsupported, LoadResult, Loader};
use crate::bsdf::{
    conductors, Blend, Bsdf, Material, Microfacet, MicrofacetKind, Plastic, Slot, MIN_ALPHA,
};
use crate::bump::{Bump, BumpMap};
use crate::geometry::{luminance, Rgb};
use crate::spectrum::Role;
use crate::texture::Texture;

/// The BSDF plugins the reader knows, for error messages.
const SUPPORTED: &str = "diffuse, conductor, roughconductor, dielectric, roughdielectric, \
                         thindielectric, plastic, roughplastic, principled, twosided, mask, bumpmap, normalmap, \
                         blendbsdf";

impl Loader {
    pub(super) fn bsdf(&mut self, el: &Element) -> LoadResult<Material> {
        let kind = el.required("type")?;
        match kind {
            "twosided" => {
                let mut m = self.nested_bsdf(el)?;
                m.two_sided = true;
                return Ok(m);
            }
            "mask" => {
                let textures = self.named_textures(el)?;
                let p = Props::new(el)?;
                let texture = textures.into_iter().find(|(n, _)| n == "opacity");
                // A colour opacity (Mitsuba 0.x scenes give one) acts by its luminance.
                let opacity = match &texture {
                    Some((_, t)) => {
                        check_scalar(t, el.line, "opacity")?;
                        luminance(t.mean()).clamp(0.0, 1.0)
                    }
                    None => luminance(p.rgb("opacity", Rgb::splat(0.5))?),
                };
                if !(0.0..=1.0).contains(&opacity) {
                    return fail(el.line, format!("mask opacity {opacity} must be in [0, 1]"));
                }
                p.finish()?;
                let mut m = self.nested_bsdf(el)?;
                m.opacity *= opacity;
                if let Some((_, t)) = texture {
                    m.textures.push((Slot::Opacity, t));
                }
                return Ok(m);
            }
            "bumpmap" => return self.bumpmap(el),
            "blendbsdf" => return self.blend(el),
            "normalmap" => return self.normalmap(el),
            "principledthin" | "hair" | "pplastic" | "measured" | "polarizer" | "retarder"
            | "circular" => {
                return fail(
                    el.line,
                    format!(
                        "the BSDF <bsdf type=\"{kind}\"> is not supported (supported: {SUPPORTED})"
                    ),
                )
            }
            _ => {}
        }
        let textures = self.named_textures(el)?;
        if let Some(c) = el
            .children
            .iter()
            .find(|c| !PROPERTY_TAGS.contains(&c.name.as_str()) && !is_named_texture(c))
        {
            return unsupported(c, "properties and textures inside this bsdf");
        }
        let p = Props::new(el)?;
        let mut c = Colours {
            p: &p,
            textures: &textures,
            slots: Vec::new(),
            used: Vec::new(),
        };
        let bsdf = match kind {
            "diffuse" => Bsdf::Diffuse {
                reflectance: c.get("reflectance", Slot::Reflectance, Rgb::splat(0.5))?,
            },
            "conductor" => {
                let (eta, k) = conductor(&p, el)?;
                Bsdf::Conductor {
                    eta,
                    k,
                    specular_reflectance: c.specular_reflectance()?,
                }
            }
            "roughconductor" => {
                let (eta, k) = conductor(&p, el)?;
                Bsdf::RoughConductor {
                    dist: microfacet(&mut c, el, true)?,
                    eta,
                    k,
                    specular_reflectance: c.specular_reflectance()?,
                }
            }
            "dielectric" => Bsdf::Dielectric {
                eta: dielectric_eta(&p, "bk7")?,
                specular_reflectance: c.specular_reflectance()?,
                specular_transmittance: c.specular_transmittance()?,
            },
            "thindielectric" => Bsdf::ThinDielectric {
                eta: dielectric_eta(&p, "bk7")?,
                specular_reflectance: c.specular_reflectance()?,
                specular_transmittance: c.specular_transmittance()?,
            },
            "roughdielectric" => Bsdf::RoughDielectric {
                dist: microfacet(&mut c, el, true)?,
                eta: dielectric_eta(&p, "bk7")?,
                specular_reflectance: c.specular_reflectance()?,
                specular_transmittance: c.specular_transmittance()?,
            },
            "plastic" | "roughplastic" => {
                let eta = dielectric_eta(&p, "polypropylene")?;
                let rough = if kind == "roughplastic" {
                    if eta == 1.0 {
                        return fail(
                            el.line,
                            "a rough plastic's indices of refraction must differ",
                        );
                    }
                    let dist = microfacet(&mut c, el, false)?;
                    if dist.is_anisotropic() {
                        // As Mitsuba 3's roughplastic, whose coating tables are isotropic.
                        return fail(
                            el.line,
                            "a rough plastic's roughness is isotropic (alpha_u = alpha_v)",
                        );
                    }
                    Some(dist)
                } else {
                    None
                };
                Bsdf::Plastic(Box::new(Plastic::new(
                    eta,
                    c.get("diffuse_reflectance", Slot::Reflectance, Rgb::splat(0.5))?,
                    c.specular_reflectance()?,
                    p.boolean("nonlinear", false)?,
                    rough,
                )))
            }
            "principled" => super::principled::principled(&p, el, &mut c)?,
            _ => {
                return unsupported(el, SUPPORTED);
            }
        };
        p.finish()?;
        let Colours { slots, used, .. } = c;
        if let Some((name, _)) = textures.iter().find(|(n, _)| !used.contains(&n.as_str())) {
            return fail(
                el.line,
                format!("parameter '{name}' of <bsdf type=\"{kind}\"> cannot be a texture here"),
            );
        }
        let mut m = Material::new(bsdf);
        m.textures = slots;
        Ok(m)
    }

    /// A `bumpmap`: a height texture (any name; Mitsuba 0.x wraps it in a `scale` texture),
    /// its `scale`, and the BSDF it tilts.
    fn bumpmap(&mut self, el: &Element) -> LoadResult<Material> {
        let p = Props::new(el)?;
        let mut scale = p.float("scale", 1.0)?;
        p.ignore(&["flip_invalid_normals"]);
        p.finish()?;
        let textures: Vec<&Element> = el.children.iter().filter(|c| c.name == "texture").collect();
        let [texture] = textures.as_slice() else {
            return fail(
                el.line,
                "<bsdf type=\"bumpmap\"> needs exactly one <texture> (the height)",
            );
        };
        let texture = if texture.attr("type") == Some("scale") {
            let q = Props::new(texture)?;
            scale *= q.float("scale", 1.0)?;
            q.finish()?;
            let inner: Vec<&Element> = texture
                .children
                .iter()
                .filter(|c| c.name == "texture")
                .collect();
            let [inner] = inner.as_slice() else {
                return fail(texture.line, "a scale texture needs one nested <texture>");
            };
            self.texture(inner)?
        } else {
            self.texture(texture)?
        };
        check_not_attribute(&texture, el.line, "a bump map")?;
        let mut m = self.nested_bsdf(el)?;
        m.bump = Some(Bump {
            texture,
            map: BumpMap::Height { scale },
        });
        Ok(m)
    }

    /// Mitsuba's `normalmap`: the texture `normalmap` (read as given: Mitsuba's scenes mark it
    /// `raw`) holds the shading normal, and the BSDF it tilts. Mitsuba's defaults
    /// `flip_invalid_normals` and `use_shadowing_function` are what nis does; turning either off
    /// is refused.
    fn normalmap(&mut self, el: &Element) -> LoadResult<Material> {
        let textures = self.named_textures(el)?;
        let p = Props::new(el)?;
        for name in ["flip_invalid_normals", "use_shadowing_function"] {
            if !p.boolean(name, true)? {
                return fail(
                    el.line,
                    format!("a normalmap with {name} false is not supported"),
                );
            }
        }
        p.finish()?;
        let Some((_, texture)) = textures.into_iter().find(|(n, _)| n == "normalmap") else {
            return fail(
                el.line,
                "<bsdf type=\"normalmap\"> needs <texture name=\"normalmap\">",
            );
        };
        check_not_attribute(&texture, el.line, "a normal map")?;
        let mut m = self.nested_bsdf(el)?;
        if m.bump.is_some() {
            return fail(
                el.line,
                "a normalmap around a bump or normal map is not supported",
            );
        }
        m.bump = Some(Bump {
            texture,
            map: BumpMap::Normal,
        });
        Ok(m)
    }

    /// The one BSDF a wrapper (`twosided`, `mask`, `bumpmap`) holds, inline or by reference;
    /// an inline one with an `id` can be referred to by that id too (as Mitsuba 0.x scenes
    /// do with the BSDF inside a bump map).
    fn nested_bsdf(&mut self, el: &Element) -> LoadResult<Material> {
        let kind = el.required("type")?;
        let inner: Vec<&Element> = el
            .children
            .iter()
            .filter(|c| {
                let height_map = kind == "bumpmap" && c.name == "texture";
                !(PROPERTY_TAGS.contains(&c.name.as_str()) || is_named_texture(c) || height_map)
            })
            .collect();
        match inner.as_slice() {
            [c] if c.name == "bsdf" || c.name == "ref" => self.child_bsdf(c),
            [_, _] if kind == "twosided" => fail(
                el.line,
                "a twosided BSDF with different front and back BSDFs is not supported",
            ),
            _ => fail(
                el.line,
                format!("<bsdf type=\"{kind}\"> needs exactly one nested <bsdf> (or <ref>)"),
            ),
        }
    }
}

impl Loader {
    /// A wrapper's BSDF: an inline `<bsdf>` (which, with an `id`, can be referred to later) or
    /// a `<ref>` to one defined before.
    fn child_bsdf(&mut self, c: &Element) -> LoadResult<Material> {
        if c.name == "bsdf" {
            let m = self.bsdf(c)?;
            if let Some(id) = c.attr("id") {
                self.materials.push(m.clone());
                self.bsdf_ids
                    .insert(id.to_string(), self.materials.len() - 1);
            }
            return Ok(m);
        }
        let id = c.required("id")?;
        match self.bsdf_ids.get(id) {
            Some(&i) => Ok(self.materials[i].clone()),
            None => fail(
                c.line,
                format!("no bsdf with id '{id}' is defined before this point"),
            ),
        }
    }

    /// Mitsuba's `blendbsdf`: two BSDFs (inline or by reference) mixed by `weight`, a number or
    /// a texture (its luminance), clipped to [0, 1] as Mitsuba does; required, as in Mitsuba.
    /// The two must be plain BSDFs: a textured, masked or bump-mapped one inside is refused,
    /// and they must agree on two-sidedness, which the blend then has.
    fn blend(&mut self, el: &Element) -> LoadResult<Material> {
        let textures = self.named_textures(el)?;
        let p = Props::new(el)?;
        let texture = textures.into_iter().find(|(n, _)| n == "weight");
        let weight = match (&texture, p.float_opt("weight")?) {
            (Some((_, t)), _) => {
                check_scalar(t, el.line, "weight")?;
                luminance(t.mean())
            }
            (None, Some(w)) => w,
            (None, None) => {
                return fail(
                    el.line,
                    "a blendbsdf needs its weight: <float name=\"weight\"> or a texture",
                )
            }
        };
        if !weight.is_finite() {
            return fail(
                el.line,
                format!("blendbsdf weight {weight} is not a number"),
            );
        }
        p.finish()?;
        let inner: Vec<&Element> = el
            .children
            .iter()
            .filter(|c| !(PROPERTY_TAGS.contains(&c.name.as_str()) || is_named_texture(c)))
            .collect();
        let [a, b] = inner.as_slice() else {
            return fail(
                el.line,
                "a blendbsdf needs exactly two nested <bsdf> (or <ref>)",
            );
        };
        let mut parts = Vec::new();
        for c in [a, b] {
            if c.name != "bsdf" && c.name != "ref" {
                return unsupported(c, "bsdf, ref inside a blendbsdf");
            }
            let m = self.child_bsdf(c)?;
            if !m.textures.is_empty() || m.opacity < 1.0 || m.bump.is_some() {
                return fail(
                    c.line,
                    "a textured, masked or bump-mapped BSDF inside a blendbsdf is not supported",
                );
            }
            parts.push(m);
        }
        if parts[0].two_sided != parts[1].two_sided {
            return fail(
                el.line,
                "a blendbsdf of a two-sided and a one-sided BSDF is not supported",
            );
        }
        let two_sided = parts[0].two_sided;
        let [first, second]: [Material; 2] = parts.try_into().expect("two parts");
        let mut m = Material::new(Bsdf::Blend(Box::new(Blend {
            weight: weight.clamp(0.0, 1.0),
            bsdfs: [first.bsdf, second.bsdf],
        })));
        m.two_sided = two_sided;
        if let Some((_, t)) = texture {
            m.textures.push((Slot::BlendWeight, t));
        }
        Ok(m)
    }
}

/// Whether a child element is a texture given to a parameter (`<texture name=…>`, or a
/// `<ref name=…>`; a wrapper's BSDF comes unnamed).
fn is_named_texture(c: &Element) -> bool {
    (c.name == "texture" || c.name == "ref") && c.attr("name").is_some()
}

/// The microfacet distribution of a rough BSDF: `distribution` (Mitsuba's default `beckmann`,
/// or `ggx`) and its roughness: `alpha`, or `alpha_u` and `alpha_v` (both, as Mitsuba
/// requires; anisotropic when they differ); each a number or, where `textured`, a texture (its
/// luminance, as Mitsuba's `eval_1`), raised to Mitsuba's least roughness as it does.
fn microfacet(c: &mut Colours, el: &Element, textured: bool) -> Result<Microfacet, XmlError> {
    let p = c.p;
    let kind = match p.string("distribution")?.unwrap_or("beckmann") {
        "beckmann" => MicrofacetKind::Beckmann,
        "ggx" => MicrofacetKind::Ggx,
        other => {
            return err(
                el.line,
                format!("unknown microfacet distribution '{other}' (beckmann, ggx)"),
            )
        }
    };
    let textures = c.textures;
    let texture = |name: &str| textures.iter().find(|(n, _)| n == name).map(|(_, t)| t);
    let given = |name: &str| p.by_name.contains_key(name) || texture(name).is_some();
    let (u, v) = (given("alpha_u"), given("alpha_v"));
    if u != v {
        return err(
            el.line,
            "a rough BSDF takes both alpha_u and alpha_v, or neither (Mitsuba's rule)",
        );
    }
    if u && given("alpha") {
        return err(
            el.line,
            "a rough BSDF takes its roughness as alpha or as alpha_u and alpha_v, not both",
        );
    }
    let same = u
        && match (texture("alpha_u"), texture("alpha_v")) {
            (Some(a), Some(b)) => a == b,
            (None, None) => p.float("alpha_u", 0.1)? == p.float("alpha_v", 0.1)?,
            _ => false,
        };
    let names: &[(&'static str, Slot)] = if !u {
        &[("alpha", Slot::Alpha)]
    } else if same {
        // The two are the same: read alpha_u for both, mark alpha_v read.
        if texture("alpha_v").is_some() {
            c.used.push("alpha_v");
        } else {
            p.float("alpha_v", 0.1)?;
        }
        &[("alpha_u", Slot::Alpha)]
    } else {
        &[("alpha_u", Slot::AlphaU), ("alpha_v", Slot::AlphaV)]
    };
    let mut alphas = [0.1f32; 2];
    for (i, &(name, slot)) in names.iter().enumerate() {
        if !textured && texture(name).is_some() {
            // Left unused: the caller reports it as a parameter that cannot be a texture.
            return Ok(Microfacet::new(kind, 0.1));
        }
        let alpha = c.scalar(name, slot, 0.1)?;
        if !alpha.is_finite() || (texture(name).is_none() && alpha < 0.0) {
            return err(
                el.line,
                format!("roughness {name} = {alpha} must be a non-negative number"),
            );
        }
        alphas[i] = alpha.max(MIN_ALPHA);
    }
    if names.len() == 1 {
        alphas[1] = alphas[0];
    }
    p.ignore(&["sample_visible"]);
    Ok(Microfacet {
        kind,
        alpha_u: alphas[0],
        alpha_v: alphas[1],
    })
}

/// A conductor's complex index `(eta, k)`: given directly, or a named `material` (Mitsuba's
/// default `none`, a perfect mirror), relative to the exterior (`ext_eta`, Mitsuba 0.x).
fn conductor(p: &Props, el: &Element) -> Result<(Rgb, Rgb), XmlError> {
    let material = p.string("material")?.unwrap_or("none");
    let ext = p.float("ext_eta", 1.0)?;
    let (eta, k) = if p.by_name.contains_key("eta") || p.by_name.contains_key("k") {
        (
            p.spectrum("eta", Rgb::ZERO, Role::Unbounded)?,
            p.spectrum("k", Rgb::ONE, Role::Unbounded)?,
        )
    } else if material == "none" {
        (Rgb::ZERO, Rgb::ONE)
    } else {
        let Some((eta, k)) = conductors::lookup(material) else {
            let names: Vec<&str> = conductors::CONDUCTORS.iter().map(|c| c.0).collect();
            return err(
                el.line,
                format!(
                    "unknown conductor material '{material}' (known: none, {})",
                    names.join(", ")
                ),
            );
        };
        (Rgb::from_array(eta), Rgb::from_array(k))
    };
    if ext <= 0.0 {
        return err(el.line, format!("ext_eta = {ext} must be positive"));
    }
    Ok((eta / ext, k / ext))
}

/// Interior over exterior index of refraction (`int_ior`, `ext_ior`: numbers or Mitsuba's
/// material names).
fn dielectric_eta(p: &Props, default_int: &str) -> Result<f32, XmlError> {
    let int = match p.get("int_ior", &["float", "string"])? {
        Some(e) => ior(e.required("value")?, e.line)?,
        None => ior(default_int, 0)?,
    };
    let ext = match p.get("ext_ior", &["float", "string"])? {
        Some(e) => ior(e.required("value")?, e.line)?,
        None => 1.000_277,
    };
    if !(int > 0.0 && ext > 0.0) {
        return err(p.line(), "indices of refraction must be positive");
    }
    Ok(int / ext)
}

/// The colours of one BSDF, each a value or one of its named textures; a textured colour's mean
/// stands for it where one value is needed (the choice of a lobe).
pub(super) struct Colours<'a> {
    p: &'a Props<'a>,
    pub(super) textures: &'a [(String, Arc<Texture>)],
    /// The textures used, by the slot they fill.
    slots: Vec<(Slot, Arc<Texture>)>,
    /// The names of the textures used.
    used: Vec<&'static str>,
}

impl Colours<'_> {
    pub(super) fn get(
        &mut self,
        name: &'static str,
        slot: Slot,
        default: Rgb,
    ) -> Result<Rgb, XmlError> {
        match self.texture(name, slot) {
            Some(t) => Ok(t.mean()),
            None => self.p.rgb(name, default),
        }
    }

    /// A scalar parameter: a number, or a texture's luminance (its mean's where one value is
    /// needed).
    pub(super) fn scalar(
        &mut self,
        name: &'static str,
        slot: Slot,
        default: f32,
    ) -> Result<f32, XmlError> {
        match self.texture(name, slot) {
            Some(t) => {
                check_scalar(&t, self.p.line(), name)?;
                Ok(luminance(t.mean()))
            }
            None => self.p.float(name, default),
        }
    }

    /// The texture given for `name`, if any, recorded as driving `slot`.
    fn texture(&mut self, name: &'static str, slot: Slot) -> Option<Arc<Texture>> {
        let (_, t) = self.textures.iter().find(|(n, _)| *n == name)?;
        let t = t.clone();
        self.slots.push((slot, t.clone()));
        self.used.push(name);
        Some(t)
    }

    fn specular_reflectance(&mut self) -> Result<Rgb, XmlError> {
        self.get("specular_reflectance", Slot::SpecularReflectance, Rgb::ONE)
    }

    fn specular_transmittance(&mut self) -> Result<Rgb, XmlError> {
        self.get(
            "specular_transmittance",
            Slot::SpecularTransmittance,
            Rgb::ONE,
        )
    }
}
