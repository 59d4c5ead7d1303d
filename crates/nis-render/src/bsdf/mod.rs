//! Bidirectional scattering distribution functions (BSDFs): how a surface scatters light.
//!
//! Every BSDF works in the local shading frame (normal = +z) with pbrt's conventions (Pharr,
//! Jakob & Humphreys, *PBR* 4th ed., ch. 9): `wo` points to where the path came from, `wi` to
//! where it goes next, and `f(wo, wi)` excludes the cosine factor. Each BSDF can be evaluated,
//! sampled, and asked the density of its sampling strategy, so that multiple importance
//! sampling and path guiding can mix it with other strategies.
//!
//! The set mirrors Mitsuba 3's plugins of the same names, including their conventions: diffuse
//! and conductors are one-sided (black when seen from below) unless wrapped as two-sided, and
//! transmission carries the `1/η²` radiance scaling.

pub mod conductors;
mod fresnel;
mod microfacet;
mod plastic;
mod principled;
mod textured;

use std::f32::consts::FRAC_1_PI;

use std::sync::Arc;

use glam::{Vec2, Vec3};

pub use fresnel::{fresnel_conductor, fresnel_dielectric, refract};
pub use microfacet::{Microfacet, MicrofacetKind};
pub use plastic::Plastic;
pub use principled::{Principled, PrincipledParam};
pub use textured::{Slot, MIN_ALPHA};

use crate::bump::Bump;
use crate::geometry::{reflect_z, Rgb};
use crate::sampling::square_to_cosine_hemisphere;
use crate::texture::Texture;
use microfacet::{
    rough_conductor_f, rough_conductor_pdf, rough_conductor_sample, rough_dielectric_f,
    rough_dielectric_pdf, rough_dielectric_sample,
};

/// One scattering model with its parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum Bsdf {
    /// Lambertian reflection `reflectance / π` (Mitsuba `diffuse`).
    Diffuse {
        /// Albedo in `[0, 1]`.
        reflectance: Rgb,
    },
    /// Smooth conductor: a mirror with conductor Fresnel (Mitsuba `conductor`).
    /// `eta = 0, k = 1` is a perfect mirror.
    Conductor {
        /// Real part of the relative index of refraction.
        eta: Rgb,
        /// Imaginary part (absorption).
        k: Rgb,
        /// Extra multiplicative factor.
        specular_reflectance: Rgb,
    },
    /// Rough conductor (Mitsuba `roughconductor`).
    RoughConductor {
        /// Microfacet distribution and roughness.
        dist: Microfacet,
        /// Real part of the relative index of refraction.
        eta: Rgb,
        /// Imaginary part (absorption).
        k: Rgb,
        /// Extra multiplicative factor.
        specular_reflectance: Rgb,
    },
    /// Smooth dielectric interface, e.g. glass (Mitsuba `dielectric`).
    Dielectric {
        /// Interior over exterior index of refraction.
        eta: f32,
        /// Factor on reflection.
        specular_reflectance: Rgb,
        /// Factor on transmission.
        specular_transmittance: Rgb,
    },
    /// Rough dielectric (Mitsuba `roughdielectric`).
    RoughDielectric {
        /// Microfacet distribution and roughness.
        dist: Microfacet,
        /// Interior over exterior index of refraction.
        eta: f32,
        /// Factor on reflection.
        specular_reflectance: Rgb,
        /// Factor on transmission.
        specular_transmittance: Rgb,
    },
    /// A thin dielectric sheet, e.g. a window pane: reflects as the sum of its internal
    /// reflections, transmits without bending (Mitsuba `thindielectric`).
    ThinDielectric {
        /// Interior over exterior index of refraction.
        eta: f32,
        /// Factor on reflection.
        specular_reflectance: Rgb,
        /// Factor on transmission.
        specular_transmittance: Rgb,
    },
    /// A diffuse base under a smooth or rough dielectric coating (Mitsuba `plastic`,
    /// `roughplastic`).
    Plastic(Box<Plastic>),
    /// Two BSDFs mixed by a weight (Mitsuba `blendbsdf`).
    Blend(Box<Blend>),
    /// Burley's Disney BSDF as Mitsuba 3 defines it (Mitsuba `principled`).
    Principled(Box<Principled>),
}

/// (1 − `weight`)·`bsdfs[0]` + `weight`·`bsdfs[1]` (Mitsuba `blendbsdf`). A sample picks one of
/// the two by its share; a non-delta direction gets the mixture's value and density (so that
/// MIS sees the density it was drawn with), a delta one its lobe scaled by the share.
#[derive(Clone, Debug, PartialEq)]
pub struct Blend {
    /// The second BSDF's share, in [0, 1].
    pub weight: f32,
    /// The two BSDFs.
    pub bsdfs: [Bsdf; 2],
}

impl Blend {
    /// The two shares (1 − weight, weight).
    fn shares(&self) -> [f32; 2] {
        [1.0 - self.weight, self.weight]
    }

    fn f(&self, wo: Vec3, wi: Vec3) -> Rgb {
        let [a, b] = self.shares();
        self.bsdfs[0].f(wo, wi) * a + self.bsdfs[1].f(wo, wi) * b
    }

    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let [a, b] = self.shares();
        a * self.bsdfs[0].pdf(wo, wi) + b * self.bsdfs[1].pdf(wo, wi)
    }

    fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        let [a, b] = self.shares();
        let (i, share, u_lobe) = if u_lobe < a {
            (0, a, u_lobe / a)
        } else {
            (1, b, (u_lobe - a) / b)
        };
        let s = self.bsdfs[i].sample(wo, u_lobe.min(1.0 - f32::EPSILON), u)?;
        if s.delta {
            return Some(BsdfSample {
                f: s.f * share,
                pdf: s.pdf * share,
                ..s
            });
        }
        // The drawn BSDF's value and density come with its sample; only the other one's are new.
        let (other, other_share) = (&self.bsdfs[1 - i], [a, b][1 - i]);
        let pdf = share * s.pdf + other_share * other.pdf(wo, s.wi);
        let mut m =
            BsdfSample::from_density(s.wi, pdf, || s.f * share + other.f(wo, s.wi) * other_share)?;
        m.eta = s.eta;
        Some(m)
    }

    fn is_delta(&self) -> bool {
        self.bsdfs.iter().all(Bsdf::is_delta)
    }

    fn transmits(&self) -> bool {
        self.bsdfs.iter().any(Bsdf::transmits)
    }
}

/// A direction drawn from a BSDF.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Sampled direction (local frame).
    pub wi: Vec3,
    /// BSDF value for `(wo, wi)`; for a delta lobe, the lobe's weight divided by `|cos θi|`.
    pub f: Rgb,
    /// Density (solid angle) or, for a delta lobe, the discrete probability of the lobe.
    pub pdf: f32,
    /// Whether `wi` came from a Dirac delta lobe (`f` and `pdf` are then not densities).
    pub delta: bool,
    /// Relative index of refraction crossed (1 for reflection).
    pub eta: f32,
}

impl BsdfSample {
    /// A non-delta sample of `wi` drawn with density `pdf` (`None` where it is zero), its value
    /// `f()` evaluated only then.
    pub fn from_density(wi: Vec3, pdf: f32, f: impl FnOnce() -> Rgb) -> Option<BsdfSample> {
        (pdf > 0.0).then(|| BsdfSample {
            wi,
            f: f(),
            pdf,
            delta: false,
            eta: 1.0,
        })
    }
}

/// A surface's BSDF with Mitsuba's `twosided` switch.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// The scattering model.
    pub bsdf: Bsdf,
    /// When set, the back side behaves like the front (Mitsuba `twosided`).
    pub two_sided: bool,
    /// Probability that light meets the BSDF rather than passing straight through (Mitsuba
    /// `mask`; 1: opaque).
    pub opacity: f32,
    /// Parameters that vary over the surface, looked up by [`Material::at`].
    pub textures: Vec<(Slot, Arc<Texture>)>,
    /// A bump map that tilts the shading normal (Mitsuba `bumpmap`).
    pub bump: Option<Bump>,
}

impl Material {
    /// A one-sided material.
    pub fn new(bsdf: Bsdf) -> Self {
        Self {
            bsdf,
            two_sided: false,
            opacity: 1.0,
            textures: Vec::new(),
            bump: None,
        }
    }

    fn flip(&self, wo: Vec3) -> bool {
        self.two_sided && wo.z < 0.0
    }

    /// Whether every lobe is a Dirac delta (no point in light sampling or MIS).
    pub fn is_delta(&self) -> bool {
        self.bsdf.is_delta()
    }

    /// Whether its roughness differs along the shading frame's tangents (a number or a
    /// texture): such a surface needs the frame Mitsuba builds from `∂p/∂u`.
    pub fn is_anisotropic(&self) -> bool {
        self.bsdf.is_anisotropic()
            || self.textures.iter().any(|(s, _)| {
                matches!(
                    s,
                    Slot::AlphaU | Slot::AlphaV | Slot::Principled(PrincipledParam::Anisotropic)
                )
            })
    }

    /// Whether light may pass through the surface (a dielectric, or a mask); every other BSDF
    /// scatters only into `wo`'s side of the shading normal (one-sided ones only from the
    /// front).
    pub fn transmits(&self) -> bool {
        self.opacity < 1.0
            || self.textures.iter().any(|(s, _)| *s == Slot::Opacity)
            || self.bsdf.transmits()
    }

    /// BSDF value `f(wo, wi)` (zero for delta lobes).
    pub fn f(&self, wo: Vec3, wi: Vec3) -> Rgb {
        let f = if self.flip(wo) {
            self.bsdf.f(-wo, -wi)
        } else {
            self.bsdf.f(wo, wi)
        };
        if self.opacity < 1.0 {
            f * self.opacity
        } else {
            f
        }
    }

    /// Solid-angle density with which [`Material::sample`] draws `wi` (zero for delta lobes).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let pdf = if self.flip(wo) {
            self.bsdf.pdf(-wo, -wi)
        } else {
            self.bsdf.pdf(wo, wi)
        };
        if self.opacity < 1.0 {
            pdf * self.opacity
        } else {
            pdf
        }
    }

    /// Draw `wi` given `wo` and three uniform numbers (`u_lobe` picks a lobe). A mask passes
    /// light straight through with probability `1 − opacity` (a delta lobe of weight 1).
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if self.opacity < 1.0 {
            let pass = 1.0 - self.opacity;
            if u_lobe < pass {
                return Some(BsdfSample {
                    wi: -wo,
                    f: Rgb::splat(pass / wo.z.abs().max(1e-12)),
                    pdf: pass,
                    delta: true,
                    eta: 1.0,
                });
            }
            let u_lobe = ((u_lobe - pass) / self.opacity).min(1.0 - f32::EPSILON);
            let mut s = self.sample_bsdf(wo, u_lobe, u)?;
            s.f *= self.opacity;
            s.pdf *= self.opacity;
            return Some(s);
        }
        self.sample_bsdf(wo, u_lobe, u)
    }

    fn sample_bsdf(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if self.flip(wo) {
            let mut s = self.bsdf.sample(-wo, u_lobe, u)?;
            s.wi = -s.wi;
            return Some(s);
        }
        self.bsdf.sample(wo, u_lobe, u)
    }
}

impl Bsdf {
    /// The half-angle (radians) of the cone around the mirror direction that holds about 90%
    /// of the scattered light, for a BSDF that is one glossy lobe (a rough conductor or
    /// dielectric: twice its [`Microfacet::cone_90`]); `None` for the rest (broad, delta, or a
    /// mix with a broad part).
    pub fn lobe_half_angle(&self) -> Option<f32> {
        match self {
            Bsdf::RoughConductor { dist, .. } | Bsdf::RoughDielectric { dist, .. } => {
                Some(2.0 * dist.cone_90())
            }
            _ => None,
        }
    }

    /// Whether every lobe is a Dirac delta.
    pub fn is_delta(&self) -> bool {
        match self {
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } | Bsdf::ThinDielectric { .. } => true,
            Bsdf::Blend(b) => b.is_delta(),
            _ => false,
        }
    }

    /// Whether its roughness differs along the shading frame's tangents.
    pub fn is_anisotropic(&self) -> bool {
        match self {
            Bsdf::RoughConductor { dist, .. } | Bsdf::RoughDielectric { dist, .. } => {
                dist.is_anisotropic()
            }
            Bsdf::Principled(p) => p.is_anisotropic(),
            Bsdf::Blend(b) => b.bsdfs.iter().any(Bsdf::is_anisotropic),
            _ => false,
        }
    }

    /// Whether it scatters light to the other side of the surface.
    pub fn transmits(&self) -> bool {
        match self {
            Bsdf::Dielectric { .. }
            | Bsdf::RoughDielectric { .. }
            | Bsdf::ThinDielectric { .. } => true,
            Bsdf::Blend(b) => b.transmits(),
            Bsdf::Principled(p) => p.transmits(),
            _ => false,
        }
    }

    /// BSDF value `f(wo, wi)` (zero for delta lobes).
    pub fn f(&self, wo: Vec3, wi: Vec3) -> Rgb {
        match *self {
            Bsdf::Diffuse { reflectance } => {
                if wo.z > 0.0 && wi.z > 0.0 {
                    reflectance * FRAC_1_PI
                } else {
                    Rgb::ZERO
                }
            }
            Bsdf::RoughConductor {
                dist,
                eta,
                k,
                specular_reflectance,
            } => rough_conductor_f(&dist, eta, k, specular_reflectance, wo, wi),
            Bsdf::RoughDielectric {
                dist,
                eta,
                specular_reflectance,
                specular_transmittance,
            } => rough_dielectric_f(
                &dist,
                eta,
                specular_reflectance,
                specular_transmittance,
                wo,
                wi,
            ),
            Bsdf::Plastic(ref p) => p.f(wo, wi),
            Bsdf::Blend(ref b) => b.f(wo, wi),
            Bsdf::Principled(ref p) => p.f(wo, wi),
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } | Bsdf::ThinDielectric { .. } => {
                Rgb::ZERO
            }
        }
    }

    /// Solid-angle density of [`Bsdf::sample`] (zero for delta lobes).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Diffuse { .. } => {
                if wo.z > 0.0 && wi.z > 0.0 {
                    wi.z * FRAC_1_PI
                } else {
                    0.0
                }
            }
            Bsdf::RoughConductor { dist, .. } => rough_conductor_pdf(&dist, wo, wi),
            Bsdf::RoughDielectric { dist, eta, .. } => rough_dielectric_pdf(&dist, eta, wo, wi),
            Bsdf::Plastic(ref p) => p.pdf(wo, wi),
            Bsdf::Blend(ref b) => b.pdf(wo, wi),
            Bsdf::Principled(ref p) => p.pdf(wo, wi),
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } | Bsdf::ThinDielectric { .. } => 0.0,
        }
    }

    /// Draw `wi` given `wo`.
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        let from_density =
            |wi: Vec3| BsdfSample::from_density(wi, self.pdf(wo, wi), || self.f(wo, wi));
        match *self {
            Bsdf::Diffuse { .. } => {
                if wo.z <= 0.0 {
                    return None;
                }
                from_density(square_to_cosine_hemisphere(u))
            }
            Bsdf::RoughConductor { dist, .. } => {
                from_density(rough_conductor_sample(&dist, wo, u)?)
            }
            Bsdf::Plastic(ref p) => p.sample(wo, u_lobe, u),
            Bsdf::Blend(ref b) => b.sample(wo, u_lobe, u),
            Bsdf::Principled(ref p) => p.sample(wo, u_lobe, u),
            Bsdf::ThinDielectric {
                eta,
                specular_reflectance,
                specular_transmittance,
            } => {
                // Reflectance of the sheet, its internal reflections summed: 2R / (1 + R).
                let r = fresnel_dielectric(wo.z.abs(), eta).0;
                let r = 2.0 * r / (1.0 + r);
                let cos = wo.z.abs().max(1e-12);
                Some(if u_lobe < r {
                    BsdfSample {
                        wi: reflect_z(wo),
                        f: specular_reflectance * r / cos,
                        pdf: r,
                        delta: true,
                        eta: 1.0,
                    }
                } else {
                    BsdfSample {
                        wi: -wo,
                        f: specular_transmittance * (1.0 - r) / cos,
                        pdf: 1.0 - r,
                        delta: true,
                        eta: 1.0,
                    }
                })
            }
            Bsdf::RoughDielectric { dist, eta, .. } => {
                let wi = rough_dielectric_sample(&dist, eta, wo, u_lobe, u)?;
                let mut s = from_density(wi)?;
                if wi.z * wo.z < 0.0 {
                    s.eta = if wo.z > 0.0 { eta } else { 1.0 / eta };
                }
                Some(s)
            }
            Bsdf::Conductor {
                eta,
                k,
                specular_reflectance,
            } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = reflect_z(wo);
                Some(BsdfSample {
                    wi,
                    f: specular_reflectance * fresnel_conductor(wo.z, eta, k) / wi.z,
                    pdf: 1.0,
                    delta: true,
                    eta: 1.0,
                })
            }
            Bsdf::Dielectric {
                eta,
                specular_reflectance,
                specular_transmittance,
            } => {
                let (f, cos_t, etap) = fresnel_dielectric(wo.z, eta);
                if u_lobe < f {
                    let wi = reflect_z(wo);
                    Some(BsdfSample {
                        wi,
                        f: specular_reflectance * f / wi.z.abs(),
                        pdf: f,
                        delta: true,
                        eta: 1.0,
                    })
                } else {
                    let n = Vec3::new(0.0, 0.0, wo.z.signum());
                    let wi = refract(wo, n, etap, cos_t);
                    Some(BsdfSample {
                        wi,
                        f: specular_transmittance * (1.0 - f) / (wi.z.abs() * etap * etap),
                        pdf: 1.0 - f,
                        delta: true,
                        eta: etap,
                    })
                }
            }
        }
    }
}

#[cfg(test)]
mod principled_tests;
#[cfg(test)]
mod tests;
