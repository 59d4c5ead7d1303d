//! BSDFs: Mitsuba 3's `diffuse`, `conductor`, `roughconductor`, `dielectric`,
//! `roughdielectric` and `twosided`, inline or defined once and used by `<ref id=…>`.

use super::dom::{err, Element, XmlError};
use super::props::{ior, Props, PROPERTY_TAGS};
use super::{unsupported, LoadResult, Loader};
use crate::bsdf::{Bsdf, Material};
use crate::geometry::Rgb;

impl Loader {
    pub(super) fn bsdf(&mut self, el: &Element) -> LoadResult<Material> {
        let kind = el.required("type")?;
        if kind == "twosided" {
            let inner: Vec<&Element> = el.children.iter().filter(|c| c.name == "bsdf").collect();
            if inner.len() != 1 || el.children.len() != 1 {
                return Err(err::<()>(
                    el.line,
                    "<bsdf type=\"twosided\"> needs exactly one nested <bsdf>",
                )
                .unwrap_err()
                .into());
            }
            let mut m = self.bsdf(inner[0])?;
            m.two_sided = true;
            return Ok(m);
        }
        if let Some(c) = el
            .children
            .iter()
            .find(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            return unsupported(c, "plain properties inside a bsdf (no textures)");
        }
        let p = Props::new(el)?;
        let alpha = |p: &Props| -> Result<f32, XmlError> {
            let dist = p.string("distribution")?.unwrap_or("beckmann");
            if dist != "ggx" {
                return err(el.line, format!("microfacet distribution '{dist}' is not supported: add <string name=\"distribution\" value=\"ggx\"/> (Mitsuba's default is beckmann)"));
            }
            let a = p.float("alpha", 0.1)?;
            let (au, av) = (p.float("alpha_u", a)?, p.float("alpha_v", a)?);
            if au != av {
                return err(
                    el.line,
                    "anisotropic roughness (alpha_u ≠ alpha_v) is not supported",
                );
            }
            p.ignore(&["sample_visible"]);
            Ok(au.max(1e-4))
        };
        let conductor = |p: &Props| -> Result<(Rgb, Rgb), XmlError> {
            let material = p.string("material")?.unwrap_or("none");
            if p.by_name.contains_key("eta") || p.by_name.contains_key("k") {
                return Ok((p.rgb("eta", Rgb::ZERO)?, p.rgb("k", Rgb::ONE)?));
            }
            if material != "none" {
                return err(el.line, format!("conductor material '{material}' is not supported: give <rgb name=\"eta\"> and <rgb name=\"k\">"));
            }
            Ok((Rgb::ZERO, Rgb::ONE))
        };
        let dielectric_eta = |p: &Props| -> Result<f32, XmlError> {
            let int = match p.get("int_ior", &["float", "string"])? {
                Some(e) => ior(e.required("value")?, e.line)?,
                None => 1.5046,
            };
            let ext = match p.get("ext_ior", &["float", "string"])? {
                Some(e) => ior(e.required("value")?, e.line)?,
                None => 1.000_277,
            };
            Ok(int / ext)
        };
        let bsdf = match kind {
            "diffuse" => Bsdf::Diffuse {
                reflectance: p.rgb("reflectance", Rgb::splat(0.5))?,
            },
            "conductor" => {
                let (eta, k) = conductor(&p)?;
                Bsdf::Conductor {
                    eta,
                    k,
                    specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                }
            }
            "roughconductor" => {
                let (eta, k) = conductor(&p)?;
                Bsdf::RoughConductor {
                    alpha: alpha(&p)?,
                    eta,
                    k,
                    specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                }
            }
            "dielectric" => Bsdf::Dielectric {
                eta: dielectric_eta(&p)?,
                specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                specular_transmittance: p.rgb("specular_transmittance", Rgb::ONE)?,
            },
            "roughdielectric" => Bsdf::RoughDielectric {
                alpha: alpha(&p)?,
                eta: dielectric_eta(&p)?,
                specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                specular_transmittance: p.rgb("specular_transmittance", Rgb::ONE)?,
            },
            _ => {
                return unsupported(
                    el,
                    "diffuse, conductor, roughconductor, dielectric, roughdielectric, twosided",
                )
            }
        };
        p.finish()?;
        Ok(Material::new(bsdf))
    }
}
