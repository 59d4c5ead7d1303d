//! The GGX (Trowbridge–Reitz) and Beckmann microfacet distributions and the rough conductor and
//! rough dielectric BSDFs built on them.
//!
//! GGX, Beckmann and the rough dielectric follow Walter, Marschner, Li & Torrance, "Microfacet
//! Models for Refraction through Rough Surfaces" (EGSR 2007); microfacet normals are drawn from
//! the distribution of visible normals: GGX's with Heitz, "Sampling the GGX Distribution of
//! Visible Normals" (JCGT 7(4), 2018), Beckmann's with Heitz & d'Eon, "Importance Sampling
//! Microfacet-Based BSDFs using the Distribution of Visible Normals" (EGSR 2014), its visible
//! slope inverted by a safeguarded Newton iteration. Shadowing–masking is the separable Smith
//! form `G1(wo) G1(wi)`, which is what Mitsuba 3 uses, with its Beckmann `G1`: Walter et al.'s
//! rational fit of the exact `1/(1 + Λ)`. Densities use the exact `G1`, since that is what the
//! visible normals are drawn from.
//!
//! Anisotropic roughness (`alpha_u` along the shading frame's `s`, `alpha_v` along `t`) is
//! Mitsuba 3's `microfacet.h`: `D` with the slopes scaled per axis, `G1` with the roughness
//! projected onto the azimuth of the direction, and visible normals drawn by stretching the
//! direction to unit roughness and unstretching the normal (Heitz 2014, 2018).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use super::fresnel::{fresnel_conductor, fresnel_dielectric, refract};
use crate::geometry::{reflect, Rgb};

/// Which microfacet normal distribution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MicrofacetKind {
    /// GGX (Trowbridge–Reitz).
    Ggx,
    /// Beckmann (Mitsuba's default).
    Beckmann,
}

/// A microfacet distribution with roughness `alpha_u` along the local `x` (the shading
/// frame's `s`) and `alpha_v` along `y` (slope parameters, not squared); isotropic when equal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Microfacet {
    /// The distribution.
    pub kind: MicrofacetKind,
    /// Roughness along the local `x`.
    pub alpha_u: f32,
    /// Roughness along the local `y`.
    pub alpha_v: f32,
}

impl Microfacet {
    /// An isotropic distribution of roughness `alpha`.
    pub fn new(kind: MicrofacetKind, alpha: f32) -> Self {
        Microfacet {
            kind,
            alpha_u: alpha,
            alpha_v: alpha,
        }
    }

    /// GGX of roughness `alpha`.
    pub fn ggx(alpha: f32) -> Self {
        Self::new(MicrofacetKind::Ggx, alpha)
    }

    /// The half-angle (radians) of the cone around the normal that holds 90% of the
    /// microfacet normals (∫ D(m) cos θ_m dω over it is 0.9), along the rougher axis: the
    /// lobe's width. Its tangent is 3α for GGX (`P(tan θ < t) = t²/(α² + t²)`) and
    /// α√(ln 10) ≈ 1.52α for Beckmann (`1 − exp(−t²/α²)`): GGX's tails make it twice as wide.
    pub fn cone_90(&self) -> f32 {
        let alpha = self.alpha_u.max(self.alpha_v);
        let k = match self.kind {
            MicrofacetKind::Ggx => 3.0,
            MicrofacetKind::Beckmann => std::f32::consts::LN_10.sqrt(),
        };
        (k * alpha).atan()
    }

    /// Whether the roughness differs along `x` and `y`.
    pub fn is_anisotropic(&self) -> bool {
        self.alpha_u != self.alpha_v
    }

    /// The roughness projected onto the azimuth of `v`: `√(α_u² cos²φ + α_v² sin²φ)`.
    fn alpha_along(&self, v: Vec3) -> f32 {
        let r2 = v.x * v.x + v.y * v.y;
        if !self.is_anisotropic() || r2 <= 0.0 {
            return self.alpha_u;
        }
        let (x, y) = (self.alpha_u * v.x, self.alpha_v * v.y);
        ((x * x + y * y) / r2).sqrt()
    }

    /// Microfacet normal density `D(m)` (per unit projected area).
    pub fn d(&self, m: Vec3) -> f32 {
        if self.is_anisotropic() {
            return self.anisotropic_d(m);
        }
        match self.kind {
            MicrofacetKind::Ggx => self.ggx_d(m),
            MicrofacetKind::Beckmann => beckmann_d(self.alpha_u, m),
        }
    }

    /// Mitsuba's anisotropic `D(m)`, the slopes scaled by `1/α_u` and `1/α_v`.
    fn anisotropic_d(&self, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let (x, y) = (m.x / self.alpha_u, m.y / self.alpha_v);
        let cos2 = m.z * m.z;
        let area = PI * self.alpha_u * self.alpha_v;
        match self.kind {
            MicrofacetKind::Ggx => {
                let t = x * x + y * y + cos2;
                1.0 / (area * t * t)
            }
            MicrofacetKind::Beckmann => (-(x * x + y * y) / cos2).exp() / (area * cos2 * cos2),
        }
    }

    /// Smith masking `G1(v, m)` as Mitsuba evaluates it; zero when `v` sees the back of `m`.
    pub fn g1(&self, v: Vec3, m: Vec3) -> f32 {
        match self.kind {
            MicrofacetKind::Ggx => self.ggx_g1(v, m),
            MicrofacetKind::Beckmann => beckmann_g1_fit(self.alpha_along(v), v, m),
        }
    }

    /// A microfacet normal from the distribution of normals visible from `v` (`v.z > 0`).
    pub fn sample_visible(&self, v: Vec3, u: Vec2) -> Vec3 {
        match self.kind {
            MicrofacetKind::Ggx => self.ggx_sample_visible(v, u),
            MicrofacetKind::Beckmann => beckmann_sample_visible((self.alpha_u, self.alpha_v), v, u),
        }
    }

    /// Density of [`Microfacet::sample_visible`] for normal `m`: `G1(v, m) |v·m| D(m) / v.z`
    /// with the exact `G1`.
    pub fn pdf_visible(&self, v: Vec3, m: Vec3) -> f32 {
        let g1 = match self.kind {
            MicrofacetKind::Ggx => self.ggx_g1(v, m),
            MicrofacetKind::Beckmann => beckmann_g1_exact(self.alpha_along(v), v, m),
        };
        g1 * v.dot(m).abs() * self.d(m) / v.z.abs()
    }

    /// Microfacet normal density `D(m)` (per unit projected area).
    fn ggx_d(&self, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha_u * self.alpha_u;
        let cos2 = m.z * m.z;
        let t = (m.x * m.x + m.y * m.y) / a2 + cos2;
        1.0 / (PI * a2 * t * t)
    }

    /// Smith masking `G1(v, m)`; zero when `v` sees the back of `m`.
    fn ggx_g1(&self, v: Vec3, m: Vec3) -> f32 {
        if v.dot(m) * v.z <= 0.0 {
            return 0.0;
        }
        let cos2 = v.z * v.z;
        let tan2 = ((1.0 - cos2) / cos2).max(0.0);
        let a = self.alpha_along(v);
        2.0 / (1.0 + (1.0 + a * a * tan2).sqrt())
    }

    /// A microfacet normal from the distribution of normals visible from `v` (`v.z > 0`).
    fn ggx_sample_visible(&self, v: Vec3, u: Vec2) -> Vec3 {
        let (au, av) = (self.alpha_u, self.alpha_v);
        let vh = Vec3::new(au * v.x, av * v.y, v.z).normalize();
        let len2 = vh.x * vh.x + vh.y * vh.y;
        let t1 = if len2 > 0.0 {
            Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt()
        } else {
            Vec3::X
        };
        let t2 = vh.cross(t1);
        let r = u.x.sqrt();
        let phi = 2.0 * PI * u.y;
        let p1 = r * phi.cos();
        let s = 0.5 * (1.0 + vh.z);
        let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
        let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
        Vec3::new(au * nh.x, av * nh.y, nh.z.max(1e-6)).normalize()
    }
}

/// Beckmann `D(m) = exp(−tan²θ/α²) / (π α² cos⁴θ)`.
fn beckmann_d(alpha: f32, m: Vec3) -> f32 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let cos2 = m.z * m.z;
    let tan2 = (m.x * m.x + m.y * m.y) / cos2;
    (-tan2 / a2).exp() / (PI * a2 * cos2 * cos2)
}

/// `a = 1/(α tan θ)` of a direction, or `None` at normal incidence (where `G1 = 1`), and
/// whether `v` sees the front of `m`.
fn beckmann_a(alpha: f32, v: Vec3, m: Vec3) -> Option<Option<f32>> {
    if v.dot(m) * v.z <= 0.0 {
        return None;
    }
    let cos2 = v.z * v.z;
    let tan = ((1.0 - cos2).max(0.0) / cos2).sqrt();
    Some((tan > 0.0).then(|| 1.0 / (alpha * tan)))
}

/// Walter et al.'s rational fit of Beckmann's Smith `G1`, as Mitsuba evaluates the BSDF.
fn beckmann_g1_fit(alpha: f32, v: Vec3, m: Vec3) -> f32 {
    match beckmann_a(alpha, v, m) {
        None => 0.0,
        Some(None) => 1.0,
        Some(Some(a)) if a >= 1.6 => 1.0,
        Some(Some(a)) => (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a),
    }
}

/// Beckmann's exact Smith `G1 = 2 / (1 + erf(a) + exp(−a²)/(a√π))`.
fn beckmann_g1_exact(alpha: f32, v: Vec3, m: Vec3) -> f32 {
    match beckmann_a(alpha, v, m) {
        None => 0.0,
        Some(None) => 1.0,
        Some(Some(a)) => beckmann_g1_of_a(f64::from(a)) as f32,
    }
}

fn beckmann_g1_of_a(a: f64) -> f64 {
    let sqrt_pi = PI64.sqrt();
    2.0 / (1.0 + libm::erf(a) + (-a * a).exp() / (a * sqrt_pi))
}

const PI64: f64 = std::f64::consts::PI;

/// A visible normal of the Beckmann distribution (Heitz & d'Eon 2014): stretch `v` to unit
/// roughness, draw the visible slope in the incidence plane by inverting its CDF
/// `C(x) = G1 [(1 + erf x)/2 + tan θ exp(−x²)/(2√π)]` for `x ≤ cot θ`, the other slope from
/// its Gaussian by inverting `erf`, rotate and unstretch.
fn beckmann_sample_visible((au, av): (f32, f32), v: Vec3, u: Vec2) -> Vec3 {
    let vs = Vec3::new(au * v.x, av * v.y, v.z).normalize();
    let (u1, u2) = (f64::from(u.x), f64::from(u.y));
    let cos = f64::from(vs.z).clamp(-1.0, 1.0);
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let (sx, sy) = if sin < 1e-4 {
        // Normal incidence: the slopes are the isotropic Gaussian of variance ½.
        let r = (-(1.0 - u1).max(1e-300).ln()).sqrt();
        let phi = 2.0 * PI64 * u2;
        (r * phi.cos(), r * phi.sin())
    } else {
        let tan = sin / cos;
        let cot = cos / sin;
        let g1 = beckmann_g1_of_a(cot);
        let sqrt_pi = PI64.sqrt();
        let cdf =
            |x: f64| g1 * (0.5 * (1.0 + libm::erf(x)) + tan * (-x * x).exp() / (2.0 * sqrt_pi));
        let density = |x: f64| g1 * (1.0 - x * tan).max(0.0) * (-x * x).exp() / sqrt_pi;
        let sx = invert_monotone(u1, -6.0, cot.min(6.0), cdf, density);
        let sy = erf_inv(2.0 * u2 - 1.0);
        (sx, sy)
    };
    // Rotate the slopes to the azimuth of v, unstretch, and turn them into a normal.
    let len = (vs.x * vs.x + vs.y * vs.y).sqrt();
    let (c, s) = if len > 0.0 {
        (f64::from(vs.x / len), f64::from(vs.y / len))
    } else {
        (1.0, 0.0)
    };
    let (x, y) = (c * sx - s * sy, s * sx + c * sy);
    let (au, av) = (f64::from(au), f64::from(av));
    Vec3::new((-x * au) as f32, (-y * av) as f32, 1.0).normalize()
}

/// The `x` in `[lo, hi]` with `cdf(x) = target` for an increasing `cdf` with derivative
/// `density`: Newton steps kept inside a shrinking bracket, bisection where Newton leaves it.
fn invert_monotone(
    target: f64,
    mut lo: f64,
    mut hi: f64,
    cdf: impl Fn(f64) -> f64,
    density: impl Fn(f64) -> f64,
) -> f64 {
    let mut x = 0.5 * (lo + hi);
    for _ in 0..60 {
        let f = cdf(x) - target;
        if f.abs() < 1e-10 {
            break;
        }
        if f > 0.0 {
            hi = x;
        } else {
            lo = x;
        }
        let d = density(x);
        let newton = x - f / d;
        x = if d > 0.0 && newton > lo && newton < hi {
            newton
        } else {
            0.5 * (lo + hi)
        };
        if hi - lo < 1e-12 {
            break;
        }
    }
    x
}

/// `erf⁻¹(y)` for `y ∈ (−1, 1)`: Newton on `erf` from Giles's single-precision start
/// ("Approximating the erfinv function", GPU Computing Gems, 2011).
fn erf_inv(y: f64) -> f64 {
    let y = y.clamp(-1.0 + 1e-15, 1.0 - 1e-15);
    let w = -((1.0 - y) * (1.0 + y)).ln();
    let mut x = if w < 5.0 {
        let w = w - 2.5;
        let mut p = 2.810_226_36e-08;
        for c in [
            3.432_739_39e-07,
            -3.523_387_7e-06,
            -4.391_506_54e-06,
            0.000_218_580_87,
            -0.001_253_725_03,
            -0.004_177_681_64,
            0.246_640_727,
            1.501_409_41,
        ] {
            p = c + p * w;
        }
        p * y
    } else {
        let w = w.sqrt() - 3.0;
        let mut p = -0.000_200_214_257;
        for c in [
            0.000_100_950_558,
            0.001_349_343_22,
            -0.003_673_428_44,
            0.005_739_507_73,
            -0.007_622_461_3,
            0.009_438_870_47,
            1.001_674_06,
            2.832_976_82,
        ] {
            p = c + p * w;
        }
        p * y
    };
    let two_over_sqrt_pi = 2.0 / PI64.sqrt();
    for _ in 0..3 {
        let err = libm::erf(x) - y;
        x -= err / (two_over_sqrt_pi * (-x * x).exp());
    }
    x
}

/// Rough conductor: `f = F(wo·h) D(h) G1(wo) G1(wi) / (4 cos θo cos θi)`, one-sided.
pub fn rough_conductor_f(
    dist: &Microfacet,
    eta: Rgb,
    k: Rgb,
    specular: Rgb,
    wo: Vec3,
    wi: Vec3,
) -> Rgb {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return Rgb::ZERO;
    }
    let h = (wo + wi).normalize();
    let g = dist.g1(wo, h) * dist.g1(wi, h);
    let scale = dist.d(h) * g / (4.0 * wo.z * wi.z);
    specular * fresnel_conductor(wo.dot(h), eta, k) * scale
}

/// Density of sampling `wi` by reflecting `wo` about a visible normal: `G1(wo) D(h) / 4 cos θo`.
pub fn rough_conductor_pdf(dist: &Microfacet, wo: Vec3, wi: Vec3) -> f32 {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return 0.0;
    }
    let h = (wo + wi).normalize();
    dist.pdf_visible(wo, h) / (4.0 * wo.dot(h))
}

/// Reflect `wo` about a visible GGX normal.
pub fn rough_conductor_sample(dist: &Microfacet, wo: Vec3, u: Vec2) -> Option<Vec3> {
    if wo.z <= 0.0 {
        return None;
    }
    let wi = reflect(wo, dist.sample_visible(wo, u));
    (wi.z > 0.0).then_some(wi)
}

/// The half vector of a pair of directions and whether they form a reflection, for a rough
/// dielectric of relative index `eta`: `None` when the pair is degenerate or sees back-facing
/// microfacets.
fn dielectric_half_vector(eta: f32, wo: Vec3, wi: Vec3) -> Option<(Vec3, bool, f32)> {
    if wo.z == 0.0 || wi.z == 0.0 {
        return None;
    }
    let reflection = wo.z * wi.z > 0.0;
    let etap = if wo.z > 0.0 { eta } else { 1.0 / eta };
    let h = if reflection { wo + wi } else { wo + wi * etap };
    if h.length_squared() == 0.0 {
        return None;
    }
    let h = h.normalize();
    let h = if h.z < 0.0 { -h } else { h };
    if wo.dot(h) * wo.z <= 0.0 || wi.dot(h) * wi.z <= 0.0 {
        return None;
    }
    Some((h, reflection, etap))
}

/// Rough dielectric BSDF value (radiance transport: transmission is scaled by `1/η'²`).
pub fn rough_dielectric_f(dist: &Microfacet, eta: f32, r: Rgb, t: Rgb, wo: Vec3, wi: Vec3) -> Rgb {
    let Some((h, reflection, etap)) = dielectric_half_vector(eta, wo, wi) else {
        return Rgb::ZERO;
    };
    let f = fresnel_dielectric(wo.dot(h), eta).0;
    let dg = dist.d(h) * dist.g1(wo, h) * dist.g1(wi, h);
    if reflection {
        r * (f * dg / (4.0 * (wo.z * wi.z).abs()))
    } else {
        let denom = wi.dot(h) * etap + wo.dot(h);
        let v =
            dg * (1.0 - f) * (wi.dot(h) * wo.dot(h)).abs() / ((wi.z * wo.z).abs() * denom * denom);
        t * v
    }
}

/// Density of [`rough_dielectric_sample`].
pub fn rough_dielectric_pdf(dist: &Microfacet, eta: f32, wo: Vec3, wi: Vec3) -> f32 {
    let Some((h, reflection, etap)) = dielectric_half_vector(eta, wo, wi) else {
        return 0.0;
    };
    let wo_up = if wo.z < 0.0 { -wo } else { wo };
    let pdf_m = dist.pdf_visible(wo_up, h);
    let f = fresnel_dielectric(wo.dot(h), eta).0;
    if reflection {
        pdf_m * f / (4.0 * wo.dot(h).abs())
    } else {
        let denom = wi.dot(h) + wo.dot(h) / etap;
        pdf_m * (1.0 - f) * wi.dot(h).abs() / (denom * denom)
    }
}

/// Draw a visible normal for `wo` (flipped to the upper side), then reflect with probability
/// `F` or refract otherwise.
pub fn rough_dielectric_sample(
    dist: &Microfacet,
    eta: f32,
    wo: Vec3,
    u_lobe: f32,
    u: Vec2,
) -> Option<Vec3> {
    if wo.z == 0.0 {
        return None;
    }
    let wo_up = if wo.z < 0.0 { -wo } else { wo };
    let m = dist.sample_visible(wo_up, u);
    let cos_i = wo.dot(m);
    let (f, cos_t, etap) = fresnel_dielectric(cos_i, eta);
    let wi = if u_lobe < f {
        let wi = reflect(wo, m);
        if wi.z * wo.z <= 0.0 {
            return None;
        }
        wi
    } else {
        let n = if cos_i > 0.0 { m } else { -m };
        let wi = refract(wo, n, etap, cos_t);
        if wi.z * wo.z >= 0.0 {
            return None;
        }
        wi
    };
    Some(wi)
}
