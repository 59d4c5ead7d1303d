//! The principled BSDF: Burley's Disney BRDF ("Physically-Based Shading at Disney", SIGGRAPH
//! 2012 course) with the rough transmission of his 2015 notes ("Extending the Disney BRDF to a
//! BSDF with Integrated Subsurface Scattering"), as Mitsuba 3's `principled` plugin defines it
//! (`src/bsdfs/principled.cpp`, `principledhelpers.h`), so that renders agree with it.
//!
//! The value is a sum of lobes: a diffuse lobe with retro-reflection (and Hanrahan–Krueger
//! flattening), sheen, a GGX specular lobe whose Fresnel term mixes the dielectric one with
//! Schlick's for the metallic and tinted parts, a GGX rough transmission, and a GTR1
//! clearcoat. Weights are Mitsuba's: `brdf = (1 − metallic)(1 − spec_trans)` on the diffuse
//! lobe, `bsdf = (1 − metallic) spec_trans` on transmission; from below only the dielectric
//! reflection and transmission remain. Sampling picks a lobe with Mitsuba's probabilities
//! (specular reflection `1 − bsdf (1 − F)`, transmission `bsdf (1 − F)`, clearcoat
//! `clearcoat / 4`, diffuse `brdf`, each times its sampling rate) and returns the density of
//! the whole mixture; GGX normals are drawn from the visible normals, GTR1 ones from `D cos θ`.

use std::f32::consts::{FRAC_1_PI, PI};

use glam::{Vec2, Vec3};

use super::fresnel::{fresnel_dielectric, refract};
use super::microfacet::Microfacet;
use super::BsdfSample;
use crate::geometry::{luminance, reflect, Rgb};
use crate::sampling::square_to_cosine_hemisphere;

/// Mitsuba 3's `principled` BSDF.
#[derive(Clone, Debug, PartialEq)]
pub struct Principled {
    /// Colour of the diffuse lobe, the metallic Fresnel and the tints.
    pub base_color: Rgb,
    /// Roughness; the GGX `α` is `max(0.001, roughness²)`.
    pub roughness: f32,
    /// Anisotropy in [0, 1]: with `aspect = √(1 − 0.9 anisotropic)` the GGX `α`s are
    /// `max(0.001, roughness² / aspect)` along `x` and `max(0.001, roughness² · aspect)` along `y`.
    pub anisotropic: f32,
    /// Blend from dielectric to metallic Fresnel.
    pub metallic: f32,
    /// Share of the dielectric Fresnel tinted towards the base colour.
    pub spec_tint: f32,
    /// Share of rough transmission.
    pub spec_trans: f32,
    /// Weight of the sheen lobe.
    pub sheen: f32,
    /// Tint of the sheen towards the base colour.
    pub sheen_tint: f32,
    /// Weight of the clearcoat lobe.
    pub clearcoat: f32,
    /// Clearcoat glossiness; the GTR1 `α` is `lerp(0.1, 0.001, gloss)`.
    pub clearcoat_gloss: f32,
    /// Blend of the diffuse lobe towards the Hanrahan–Krueger fake subsurface.
    pub flatness: f32,
    /// Interior over exterior index of refraction.
    pub eta: f32,
    /// Sampling rates of the specular, clearcoat and diffuse lobes (Mitsuba's
    /// `main_specular_sampling_rate`, …); they change the noise, not the mean.
    pub rates: [f32; 3],
}

/// The scalar parameters of [`Principled`] a texture can drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PrincipledParam {
    /// `roughness`.
    Roughness,
    /// `anisotropic`.
    Anisotropic,
    /// `metallic`.
    Metallic,
    /// `spec_tint`.
    SpecTint,
    /// `spec_trans`.
    SpecTrans,
    /// `sheen`.
    Sheen,
    /// `sheen_tint`.
    SheenTint,
    /// `clearcoat`.
    Clearcoat,
    /// `clearcoat_gloss`.
    ClearcoatGloss,
    /// `flatness`.
    Flatness,
}

impl Principled {
    /// The parameter `param`, for a texture to set.
    pub(super) fn param_mut(&mut self, param: PrincipledParam) -> &mut f32 {
        match param {
            PrincipledParam::Roughness => &mut self.roughness,
            PrincipledParam::Anisotropic => &mut self.anisotropic,
            PrincipledParam::Metallic => &mut self.metallic,
            PrincipledParam::SpecTint => &mut self.spec_tint,
            PrincipledParam::SpecTrans => &mut self.spec_trans,
            PrincipledParam::Sheen => &mut self.sheen,
            PrincipledParam::SheenTint => &mut self.sheen_tint,
            PrincipledParam::Clearcoat => &mut self.clearcoat,
            PrincipledParam::ClearcoatGloss => &mut self.clearcoat_gloss,
            PrincipledParam::Flatness => &mut self.flatness,
        }
    }
}

/// Fifth power of `1 − cos`, Schlick's weight.
fn schlick_weight(cos: f32) -> f32 {
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

/// Schlick's Fresnel `R0 + (1 − R0) w` for a microfacet cosine `cos` (negative: from below);
/// from the denser side `w` takes the refracted cosine, so total internal reflection gives 1.
fn schlick(r0: Rgb, cos: f32, eta: f32) -> Rgb {
    let eta_it = if cos >= 0.0 { eta } else { 1.0 / eta };
    let w = if eta_it > 1.0 {
        schlick_weight(cos.abs())
    } else {
        let cos_t2 = 1.0 - (1.0 - cos * cos) / (eta_it * eta_it);
        schlick_weight(cos_t2.max(0.0).sqrt())
    };
    r0 + (Rgb::ONE - r0) * w
}

/// The colour normalised by its luminance (white when black).
fn tint(c: Rgb) -> Rgb {
    let lum = luminance(c);
    if lum > 0.0 {
        c / lum
    } else {
        Rgb::ONE
    }
}

/// GTR1 ("Berry") normal density of the clearcoat, `α² < 1`.
fn gtr1_d(alpha: f32, m: Vec3) -> f32 {
    let a2 = alpha * alpha;
    let d = (a2 - 1.0) / (PI * a2.ln() * (1.0 + (a2 - 1.0) * m.z * m.z));
    if d * m.z > 1e-20 {
        d
    } else {
        0.0
    }
}

/// A GTR1 normal drawn with density `D(m) cos θm`.
fn gtr1_sample(alpha: f32, u: Vec2) -> Vec3 {
    let a2 = alpha * alpha;
    let cos2 = ((1.0 - a2.powf(1.0 - u.y)) / (1.0 - a2)).clamp(0.0, 1.0);
    let (sin_phi, cos_phi) = (2.0 * PI * u.x).sin_cos();
    let sin = (1.0 - cos2).sqrt();
    Vec3::new(cos_phi * sin, sin_phi * sin, cos2.sqrt())
}

/// Smith's GGX masking with a fixed `α`, as Mitsuba's clearcoat uses it.
fn smith_ggx1(v: Vec3, m: Vec3, alpha: f32) -> f32 {
    if v.dot(m) * v.z <= 0.0 {
        return 0.0;
    }
    if v.z == 1.0 {
        return 1.0;
    }
    let cos2 = v.z * v.z;
    let tan2 = (1.0 - cos2) / cos2;
    2.0 / (1.0 + (1.0 + alpha * alpha * tan2).sqrt())
}

/// The geometry of a pair of directions: the half vector (upwards), whether they reflect, the
/// index `wi` sees relative to `wo`'s side, and whether `wo` is above the surface.
struct Pair {
    h: Vec3,
    reflect: bool,
    eta_path: f32,
    front: bool,
    /// Whether both directions see the front of the microfacet `h` (as the lobe needs).
    compatible: bool,
}

/// The lobes a sample can come from, in Mitsuba's order of selection.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Lobe {
    Diffuse,
    Clearcoat,
    Transmission,
    Reflection,
}

impl Principled {
    fn dist(&self) -> Microfacet {
        let r2 = self.roughness * self.roughness;
        let aspect = (1.0 - 0.9 * self.anisotropic.clamp(0.0, 1.0)).sqrt();
        Microfacet {
            alpha_u: (r2 / aspect).max(0.001),
            alpha_v: (r2 * aspect).max(0.001),
            ..Microfacet::ggx(0.001)
        }
    }

    /// Whether the specular and transmission lobes are anisotropic.
    pub fn is_anisotropic(&self) -> bool {
        self.anisotropic != 0.0
    }

    fn clearcoat_alpha(&self) -> f32 {
        0.1 + (0.001 - 0.1) * self.clearcoat_gloss
    }

    /// Weights of the diffuse (`brdf`) and transmission (`bsdf`) parts.
    fn weights(&self) -> (f32, f32) {
        let dielectric = 1.0 - self.metallic;
        (
            dielectric * (1.0 - self.spec_trans),
            dielectric * self.spec_trans,
        )
    }

    /// Whether light may pass to the other side.
    pub fn transmits(&self) -> bool {
        self.spec_trans != 0.0
    }

    fn pair(&self, wo: Vec3, wi: Vec3) -> Option<Pair> {
        if wo.z == 0.0 || wi.z == 0.0 {
            return None;
        }
        let front = wo.z > 0.0;
        let reflect = wo.z * wi.z > 0.0;
        let eta_path = if front { self.eta } else { 1.0 / self.eta };
        let h = wo + wi * if reflect { 1.0 } else { eta_path };
        if h.length_squared() == 0.0 {
            return None;
        }
        let h = h.normalize();
        let h = if h.z < 0.0 { -h } else { h };
        // Mitsuba's macro/micro-surface compatibility, for reflection or refraction.
        let s = wo.z.signum();
        let sign_i = if reflect { s } else { -s };
        let compatible = wo.dot(h) * s > 0.0 && wi.dot(h) * sign_i > 0.0;
        Some(Pair {
            h,
            reflect,
            eta_path,
            front,
            compatible,
        })
    }

    /// The four lobes' selection probabilities (diffuse, clearcoat, transmission, reflection)
    /// for dielectric Fresnel `f`, normalised; `None` when none can be drawn.
    fn lobe_probabilities(&self, front: bool, f: f32) -> Option<[f32; 4]> {
        let (brdf, bsdf) = self.weights();
        let [spec, coat, diffuse] = self.rates;
        let p = if front {
            [
                brdf * diffuse,
                0.25 * self.clearcoat * coat,
                spec * bsdf * (1.0 - f),
                spec * (1.0 - bsdf * (1.0 - f)),
            ]
        } else {
            [0.0, 0.0, if bsdf != 0.0 { 1.0 - f } else { 0.0 }, f]
        };
        let total: f32 = p.iter().sum();
        (total > 0.0 && total.is_finite()).then(|| p.map(|x| x / total))
    }

    /// The specular Fresnel term: from above, the dielectric one blended with Schlick's
    /// metallic and tinted ones; from below the dielectric one weighted by `bsdf`.
    fn specular_fresnel(&self, f_dielectric: f32, cos: f32, front: bool) -> Rgb {
        let (_, bsdf) = self.weights();
        if !front {
            return Rgb::splat(bsdf * f_dielectric);
        }
        let eta_it = if cos >= 0.0 { self.eta } else { 1.0 / self.eta };
        let r0 = ((eta_it - 1.0) / (eta_it + 1.0)).powi(2);
        let metal = schlick(self.base_color, cos, self.eta) * self.metallic;
        let tinted = schlick(tint(self.base_color) * r0, cos, self.eta)
            * ((1.0 - self.metallic) * self.spec_tint);
        Rgb::splat((1.0 - self.metallic) * (1.0 - self.spec_tint) * f_dielectric) + metal + tinted
    }

    /// BSDF value `f(wo, wi)`, without the cosine; radiance transport (transmission carries
    /// the `1/η²` scaling).
    pub fn f(&self, wo: Vec3, wi: Vec3) -> Rgb {
        let Some(p) = self.pair(wo, wi) else {
            return Rgb::ZERO;
        };
        let (brdf, bsdf) = self.weights();
        let h = p.h;
        let f_d = fresnel_dielectric(wo.dot(h), self.eta).0;
        let (cos_o, cos_i) = (wo.z.abs(), wi.z.abs());
        let dist = self.dist();
        let dg = || dist.d(h) * dist.g1(wo, h) * dist.g1(wi, h);
        let mut value = Rgb::ZERO;
        if p.reflect && p.compatible && f_d > 0.0 {
            let fr = self.specular_fresnel(f_d, wo.dot(h), p.front);
            value += fr * (dg() / (4.0 * cos_o * cos_i));
        }
        if !p.reflect && p.compatible && bsdf > 0.0 && f_d < 1.0 {
            let (a, b) = (wo.dot(h), wi.dot(h));
            let denom = a + p.eta_path * b;
            let t = bsdf * (1.0 - f_d) * dg() * (a * b).abs() / (cos_o * cos_i * denom * denom);
            value += self.base_color.map(f32::sqrt) * t;
        }
        if !(p.reflect && p.front) {
            return value;
        }
        if self.clearcoat > 0.0 && p.compatible {
            let fcc = schlick(Rgb::splat(0.04), wo.dot(h), self.eta).x;
            let dcc = gtr1_d(self.clearcoat_alpha(), h);
            let gcc = smith_ggx1(wo, h, 0.25) * smith_ggx1(wi, h, 0.25);
            value += Rgb::splat(0.25 * self.clearcoat * fcc * dcc * gcc);
        }
        if brdf > 0.0 {
            let (fo, fi) = (schlick_weight(cos_i), schlick_weight(cos_o));
            let cos_d = h.dot(wi);
            let rr = 2.0 * self.roughness * cos_d * cos_d;
            let diffuse = (1.0 - 0.5 * fi) * (1.0 - 0.5 * fo);
            let retro = rr * (fo + fi + fo * fi * (rr - 1.0));
            let mut lobe = diffuse + retro;
            if self.flatness != 0.0 {
                let fss90 = 0.5 * rr;
                let fss = (1.0 + (fss90 - 1.0) * fo) * (1.0 + (fss90 - 1.0) * fi);
                let ss = 1.25 * (fss * (1.0 / (cos_o + cos_i) - 0.5) + 0.5);
                lobe += (ss - lobe) * self.flatness;
            }
            value += self.base_color * (brdf * FRAC_1_PI * lobe);
            if self.sheen > 0.0 && self.metallic < 1.0 {
                let c_sheen = Rgb::ONE + (tint(self.base_color) - Rgb::ONE) * self.sheen_tint;
                let fd = schlick_weight(cos_d.abs());
                value += c_sheen * (self.sheen * (1.0 - self.metallic) * fd);
            }
        }
        value
    }

    /// Solid-angle density of [`Principled::sample`].
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let Some(p) = self.pair(wo, wi) else {
            return 0.0;
        };
        let (_, bsdf) = self.weights();
        if !p.front && bsdf <= 0.0 {
            return 0.0;
        }
        let h = p.h;
        let f_d = fresnel_dielectric(wo.dot(h), self.eta).0;
        let Some([diffuse, coat, trans, refl]) = self.lobe_probabilities(p.front, f_d) else {
            return 0.0;
        };
        let mut pdf = 0.0;
        if p.reflect {
            pdf += diffuse * wi.z.abs() * FRAC_1_PI;
        }
        if !p.compatible {
            return pdf;
        }
        let (a, b) = (wo.dot(h), wi.dot(h));
        let dh_dwi = if p.reflect {
            1.0 / (4.0 * b.abs())
        } else {
            let denom = a + p.eta_path * b;
            p.eta_path * p.eta_path * b.abs() / (denom * denom)
        };
        let wo_up = if p.front { wo } else { -wo };
        let spec = self.dist().pdf_visible(wo_up, h) * dh_dwi;
        if p.reflect {
            let cc = if coat > 0.0 {
                h.z * gtr1_d(self.clearcoat_alpha(), h) * dh_dwi
            } else {
                0.0
            };
            pdf += refl * spec + coat * cc;
        } else {
            pdf += trans * spec;
        }
        pdf
    }

    /// Draw `wi`: a GGX visible normal for `wo` sets the Fresnel term of the lobe choice, then
    /// `u_lobe` picks the lobe and the direction comes from it (Mitsuba's order and rates).
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        let (_, bsdf) = self.weights();
        let front = wo.z > 0.0;
        if wo.z == 0.0 || (!front && bsdf <= 0.0) {
            return None;
        }
        let wo_up = if front { wo } else { -wo };
        let m = self.dist().sample_visible(wo_up, u);
        let cos = wo.dot(m);
        let (f_d, cos_t, etap) = fresnel_dielectric(cos, self.eta);
        let probs = self.lobe_probabilities(front, f_d)?;
        let mut acc = 0.0;
        let mut lobe = Lobe::Reflection;
        for (p, l) in probs
            .iter()
            .zip([Lobe::Diffuse, Lobe::Clearcoat, Lobe::Transmission])
        {
            acc += p;
            if u_lobe < acc {
                lobe = l;
                break;
            }
        }
        let s = wo.z.signum();
        let (wi, normal) = match lobe {
            Lobe::Diffuse => (square_to_cosine_hemisphere(u), None),
            Lobe::Clearcoat => {
                let n = gtr1_sample(self.clearcoat_alpha(), u);
                (reflect(wo, n), Some(n))
            }
            Lobe::Reflection => (reflect(wo, m), Some(m)),
            Lobe::Transmission => {
                if f_d >= 1.0 {
                    return None;
                }
                (
                    refract(wo, if cos > 0.0 { m } else { -m }, etap, cos_t),
                    Some(m),
                )
            }
        };
        let transmitted = lobe == Lobe::Transmission;
        if !wi.is_finite() || wi.z == 0.0 || (wi.z * wo.z > 0.0) == transmitted {
            return None;
        }
        // Mitsuba's macro/micro-surface compatibility of the normal the direction came from.
        if let Some(n) = normal {
            let side_i = if transmitted { -s } else { s };
            if wo.dot(n) * s <= 0.0 || wi.dot(n) * side_i <= 0.0 {
                return None;
            }
        }
        let mut sample = BsdfSample::from_density(wi, self.pdf(wo, wi), || self.f(wo, wi))?;
        if transmitted {
            sample.eta = if front { self.eta } else { 1.0 / self.eta };
        }
        Some(sample)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schlick_matches_its_closed_form_and_reflects_totally_inside() {
        let r0 = Rgb::splat(0.04);
        assert!((schlick(r0, 1.0, 1.5).x - 0.04).abs() < 1e-6);
        let c: f32 = 0.3;
        let want = 0.04 + 0.96 * (1.0 - c).powi(5);
        assert!((schlick(r0, c, 1.5).x - want).abs() < 1e-6);
        // From the denser side beyond the critical angle: total reflection.
        assert_eq!(schlick(r0, -0.3, 1.5).x, 1.0);
    }

    #[test]
    fn gtr1_samples_integrate_its_density() {
        // ∫ D(m) cos θm dω = 1, by the midpoint rule in θ.
        let alpha = 0.05;
        let n = 200_000;
        let mut sum = 0.0f64;
        for i in 0..n {
            let theta = (i as f32 + 0.5) / n as f32 * 0.5 * PI;
            let m = Vec3::new(theta.sin(), 0.0, theta.cos());
            sum += f64::from(gtr1_d(alpha, m) * m.z * m.x);
        }
        sum *= 2.0 * std::f64::consts::PI * 0.5 * std::f64::consts::PI / n as f64;
        assert!((sum - 1.0).abs() < 1e-3, "∫ D cos = {sum}");
        // The sampled cosines follow the CDF (1 − α^{2(1−u)})/(1 − α²) of cos²θ.
        let m = gtr1_sample(alpha, Vec2::new(0.2, 0.5));
        let a2 = alpha * alpha;
        assert!((m.z * m.z - (1.0 - a2.powf(0.5)) / (1.0 - a2)).abs() < 1e-5);
    }
}
