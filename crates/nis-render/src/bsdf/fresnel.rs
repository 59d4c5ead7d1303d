//! Fresnel reflectance of dielectric and conductor interfaces, and refraction by Snell's law.
//!
//! Both reflectances are the exact unpolarised ones (Born & Wolf, *Principles of Optics*, §1.5
//! and §14.2); the conductor form is written with real arithmetic only, as the average of the
//! s- and p-polarised terms of a complex index `eta + i k`.

use glam::Vec3;

/// Reflectance of a dielectric interface with relative index `eta = n_inside / n_outside` for
/// light arriving with cosine `cos_i` to the normal (negative: from the inside). Also returns
/// the cosine of the refracted direction (0 under total internal reflection) and the relative
/// index seen from the arriving side.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> (f32, f32, f32) {
    let (cos_i, eta) = if cos_i < 0.0 {
        (-cos_i, 1.0 / eta)
    } else {
        (cos_i, eta)
    };
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return (1.0, 0.0, eta);
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    (0.5 * (r_parl * r_parl + r_perp * r_perp), cos_t, eta)
}

/// Reflectance of a conductor with complex relative index `eta + i k`, per channel, for
/// arrival cosine `cos_i` in `[0, 1]`.
pub fn fresnel_conductor(cos_i: f32, eta: Vec3, k: Vec3) -> Vec3 {
    Vec3::new(
        fresnel_conductor_1(cos_i, eta.x, k.x),
        fresnel_conductor_1(cos_i, eta.y, k.y),
        fresnel_conductor_1(cos_i, eta.z, k.z),
    )
}

fn fresnel_conductor_1(cos_i: f32, eta: f32, k: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let cos2 = cos_i * cos_i;
    let sin2 = 1.0 - cos2;
    // a² + b² = |n̂² − sin²θ| and a = Re √(n̂² − sin²θ), with n̂ = eta + i k.
    let re = eta * eta - k * k - sin2;
    let a2_plus_b2 = (re * re + 4.0 * eta * eta * k * k).max(0.0).sqrt();
    let a = (0.5 * (a2_plus_b2 + re)).max(0.0).sqrt();
    let t1 = a2_plus_b2 + cos2;
    let t2 = 2.0 * a * cos_i;
    let r_s = (t1 - t2) / (t1 + t2);
    let t3 = a2_plus_b2 * cos2 + sin2 * sin2;
    let t4 = t2 * sin2;
    let r_p = r_s * (t3 - t4) / (t3 + t4);
    let r = 0.5 * (r_s + r_p);
    if r.is_finite() {
        r
    } else {
        1.0
    }
}

/// Refract `wo` through the interface with unit normal `n` on `wo`'s side, relative index
/// `eta` (transmitted side over arriving side) and refracted cosine `cos_t`.
pub fn refract(wo: Vec3, n: Vec3, eta: f32, cos_t: f32) -> Vec3 {
    let cos_i = wo.dot(n);
    (-wo / eta + (cos_i / eta - cos_t) * n).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_fresnel_has_known_values() {
        // Normal incidence: ((n-1)/(n+1))².
        let (f, cos_t, _) = fresnel_dielectric(1.0, 1.5);
        assert!((f - 0.04).abs() < 1e-6 && (cos_t - 1.0).abs() < 1e-6);
        // Same reflectance from both sides for matched angles.
        let (f_out, cos_t, _) = fresnel_dielectric(0.6, 1.5);
        let (f_in, _, _) = fresnel_dielectric(-cos_t, 1.5);
        assert!((f_out - f_in).abs() < 1e-5);
        // Total internal reflection beyond the critical angle.
        assert_eq!(fresnel_dielectric(-0.3, 1.5).0, 1.0);
    }

    #[test]
    fn conductor_fresnel_reduces_to_dielectric_without_absorption() {
        for c in [0.1, 0.5, 0.9, 1.0] {
            let a = fresnel_conductor(c, Vec3::splat(1.5), Vec3::ZERO).x;
            let b = fresnel_dielectric(c, 1.5).0;
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        // eta = 0, k = 1 is a perfect mirror (Mitsuba's material "none").
        assert!((fresnel_conductor(0.3, Vec3::ZERO, Vec3::ONE).x - 1.0).abs() < 1e-6);
    }
}
