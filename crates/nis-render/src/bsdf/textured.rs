//! BSDF parameters that vary over a surface: which parameter a texture drives ([`Slot`]) and
//! the material at a point, its textures looked up ([`Material::at`]). Colours take the
//! texture's value; scalar parameters its luminance, as Mitsuba 3's `Texture::eval_1` does.

use glam::Vec2;

use super::{Bsdf, Material, PrincipledParam};
use crate::texture::AttributeHit;

/// The least microfacet roughness: Mitsuba's `MicrofacetDistribution` raises `alpha` to it.
pub const MIN_ALPHA: f32 = 1e-4;

/// A BSDF parameter a texture can drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slot {
    /// A diffuse BSDF's `reflectance`, a plastic's `diffuse_reflectance`, a principled
    /// BSDF's `base_color`.
    Reflectance,
    /// `specular_reflectance`.
    SpecularReflectance,
    /// `specular_transmittance`.
    SpecularTransmittance,
    /// A mask's `opacity` (the texture's luminance).
    Opacity,
    /// A blend's `weight` (the texture's luminance).
    BlendWeight,
    /// A rough conductor's or dielectric's isotropic roughness `alpha` (the texture's
    /// luminance, at least [`MIN_ALPHA`]).
    Alpha,
    /// Its roughness `alpha_u` along the shading frame's `s` (as [`Slot::Alpha`]).
    AlphaU,
    /// Its roughness `alpha_v` along the shading frame's `t` (as [`Slot::Alpha`]).
    AlphaV,
    /// One of a principled BSDF's scalar parameters (the texture's luminance).
    Principled(PrincipledParam),
}

impl Material {
    /// The material at texture coordinates `uv`, its textured parameters looked up; `None`
    /// when nothing is textured (the material is the same everywhere).
    pub fn at(&self, uv: Vec2) -> Option<Material> {
        self.at_hit(uv, None)
    }

    /// [`Material::at`] a hit with mesh attributes `attributes` (what `mesh_attribute`
    /// textures read).
    pub fn at_hit(&self, uv: Vec2, attributes: Option<&AttributeHit>) -> Option<Material> {
        if self.textures.is_empty() {
            return None;
        }
        let mut m = Material {
            bsdf: self.bsdf.clone(),
            two_sided: self.two_sided,
            opacity: self.opacity,
            textures: Vec::new(),
            bump: None,
        };
        for (slot, t) in &self.textures {
            // The colour, evaluated only for the slots that take one.
            let v = || t.eval_at(uv, attributes);
            match (slot, &mut m.bsdf) {
                (Slot::Opacity, _) => m.opacity = t.eval_scalar_at(uv, attributes).clamp(0.0, 1.0),
                (Slot::BlendWeight, Bsdf::Blend(b)) => {
                    b.weight = t.eval_scalar_at(uv, attributes).clamp(0.0, 1.0)
                }
                (Slot::Reflectance, Bsdf::Diffuse { reflectance }) => *reflectance = v(),
                (Slot::Reflectance, Bsdf::Plastic(p)) => p.diffuse_reflectance = v(),
                (Slot::Reflectance, Bsdf::Principled(p)) => p.base_color = v(),
                (
                    Slot::Alpha | Slot::AlphaU | Slot::AlphaV,
                    Bsdf::RoughConductor { dist, .. } | Bsdf::RoughDielectric { dist, .. },
                ) => {
                    let a = t.eval_scalar_at(uv, attributes).max(MIN_ALPHA);
                    if *slot != Slot::AlphaV {
                        dist.alpha_u = a;
                    }
                    if *slot != Slot::AlphaU {
                        dist.alpha_v = a;
                    }
                }
                (Slot::Principled(param), Bsdf::Principled(p)) => {
                    *p.param_mut(*param) = t.eval_scalar_at(uv, attributes);
                }
                (
                    Slot::SpecularReflectance,
                    Bsdf::Conductor {
                        specular_reflectance,
                        ..
                    }
                    | Bsdf::RoughConductor {
                        specular_reflectance,
                        ..
                    }
                    | Bsdf::Dielectric {
                        specular_reflectance,
                        ..
                    }
                    | Bsdf::RoughDielectric {
                        specular_reflectance,
                        ..
                    }
                    | Bsdf::ThinDielectric {
                        specular_reflectance,
                        ..
                    },
                ) => *specular_reflectance = v(),
                (Slot::SpecularReflectance, Bsdf::Plastic(p)) => p.specular_reflectance = v(),
                (
                    Slot::SpecularTransmittance,
                    Bsdf::Dielectric {
                        specular_transmittance,
                        ..
                    }
                    | Bsdf::RoughDielectric {
                        specular_transmittance,
                        ..
                    }
                    | Bsdf::ThinDielectric {
                        specular_transmittance,
                        ..
                    },
                ) => *specular_transmittance = v(),
                _ => {}
            }
        }
        Some(m)
    }
}
