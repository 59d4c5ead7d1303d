//! Spectra given as `wavelength:value` lists, turned into linear sRGB the way Mitsuba 3's RGB
//! variants do (`spectrum_list_to_srgb`, Mitsuba 3 `src/core/spectrum.cpp`): the piecewise-linear
//! spectrum is integrated against the CIE 1931 matching functions ([`mod@cie`]) — weighted by D65 for
//! reflectances, as seen under a white light — then converted from XYZ to linear sRGB
//! (IEC 61966-2-1). A constant spectrum is a constant reflectance, but an emitter's constant
//! spectrum is D65-less white, `value · M·(1, 1, 1)`, which is slightly purple in sRGB.

pub mod cie;

use crate::geometry::Rgb;

/// What a spectrum describes, which decides its weighting and clamping (Mitsuba's `emitter`
/// and `unbounded` flags).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// A reflectance or transmittance: D65-weighted, clamped to `[0, 1]`.
    Reflectance,
    /// A quantity such as an index of refraction: D65-weighted, clamped below at 0.
    Unbounded,
    /// Emitted radiance or irradiance: not D65-weighted, clamped below at 0.
    Emission,
}

/// The matching functions and D65 at `w` nm, interpolated linearly (zero outside the table).
pub fn cie(w: f64) -> [f64; 4] {
    if !(cie::MIN..=cie::MAX).contains(&w) {
        return [0.0; 4];
    }
    let t = (w - cie::MIN) / 5.0;
    let i = (t.floor() as usize).min(cie::TABLE.len() - 2);
    let f = t - i as f64;
    let (a, b) = (cie::TABLE[i], cie::TABLE[i + 1]);
    std::array::from_fn(|k| f64::from(a[k]) * (1.0 - f) + f64::from(b[k]) * f)
}

/// CIE XYZ to linear sRGB (IEC 61966-2-1, D65 white).
pub fn xyz_to_srgb([x, y, z]: [f64; 3]) -> [f64; 3] {
    [
        3.240_479 * x - 1.537_150 * y - 0.498_535 * z,
        -0.969_256 * x + 1.875_991 * y + 0.041_556 * z,
        0.055_648 * x - 0.204_043 * y + 1.057_311 * z,
    ]
}

/// Steps of the integration over [`cie::MIN`, `cie::MAX`], as Mitsuba takes them.
const STEPS: usize = 1000;

/// The linear sRGB of a piecewise-linear spectrum through `(wavelength nm, value)` points in
/// increasing order, and whether it had to be clamped. Zero outside the given range.
pub fn list_to_rgb(points: &[(f64, f64)], role: Role) -> Result<(Rgb, bool), String> {
    if points.len() < 2 {
        return Err("a spectrum list needs at least two wavelength:value pairs".into());
    }
    if points.windows(2).any(|p| p[1].0 <= p[0].0) {
        return Err("a spectrum's wavelengths must increase".into());
    }
    let (first, last) = (points[0].0, points[points.len() - 1].0);
    let mut xyz = [0.0; 3];
    for i in 0..STEPS {
        let w = cie::MIN + (i as f64 / (STEPS - 1) as f64) * (cie::MAX - cie::MIN);
        if w < first || w > last {
            continue;
        }
        let j = points
            .partition_point(|p| p.0 <= w)
            .clamp(1, points.len() - 1)
            - 1;
        let ((w0, v0), (w1, v1)) = (points[j], points[j + 1]);
        let v = ((w - w1) * v0 + (w0 - w) * v1) / (w0 - w1);
        let c = cie(w);
        let weight = if role == Role::Emission { 1.0 } else { c[3] };
        for k in 0..3 {
            xyz[k] += c[k] * v * weight;
        }
    }
    let scale = (cie::MAX - cie::MIN) * cie::Y_NORMALIZATION / STEPS as f64;
    let rgb = xyz_to_srgb(xyz.map(|v| v * scale));
    Ok(clamp(rgb, role))
}

/// An sRGB-encoded value decoded to linear (IEC 61966-2-1).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The linear sRGB of a constant spectrum.
pub fn uniform_to_rgb(value: f64, role: Role) -> Rgb {
    match role {
        Role::Emission => clamp(xyz_to_srgb([value; 3]), role).0,
        _ => Rgb::splat(value as f32),
    }
}

fn clamp(rgb: [f64; 3], role: Role) -> (Rgb, bool) {
    let hi = if role == Role::Reflectance {
        1.0
    } else {
        f64::INFINITY
    };
    let clamped = rgb.iter().any(|&c| c < 0.0 || c > hi);
    let [r, g, b] = rgb.map(|c| c.clamp(0.0, hi) as f32);
    (Rgb::new(r, g, b), clamped)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mitsuba 3.9.1's `spectrum_list_to_srgb` on the practical-path-guiding Cornell box's
    /// light (`400:0, 500:16, 600:31.2, 700:36.8`, an emitter) and a flat 0.78 reflectance.
    #[test]
    fn lists_convert_as_mitsuba_does() {
        let light = [(400.0, 0.0), (500.0, 16.0), (600.0, 31.2), (700.0, 36.8)];
        let (rgb, _) = list_to_rgb(&light, Role::Emission).unwrap();
        let want = [41.4216, 21.7093, 5.5423];
        for (got, want) in rgb.to_array().iter().zip(want) {
            assert!((got - want).abs() < 2e-4 * want, "{rgb:?}");
        }
        let (rgb, clamped) =
            list_to_rgb(&[(400.0, 0.78), (700.0, 0.78)], Role::Reflectance).unwrap();
        let want = [0.776368, 0.779809, 0.776029];
        for (got, want) in rgb.to_array().iter().zip(want) {
            assert!((got - want).abs() < 2e-4, "{rgb:?}");
        }
        assert!(!clamped);
    }

    #[test]
    fn an_emitters_constant_spectrum_is_mitsubas_purple_white() {
        let rgb = uniform_to_rgb(2.0, Role::Emission);
        let want = [2.0 * 1.20479, 2.0 * 0.948291, 2.0 * 0.908916];
        for (got, want) in rgb.to_array().iter().zip(want) {
            assert!((got - want).abs() < 1e-4, "{rgb:?}");
        }
        assert_eq!(uniform_to_rgb(0.5, Role::Reflectance), Rgb::splat(0.5));
    }

    #[test]
    fn bad_lists_are_errors() {
        assert!(list_to_rgb(&[(500.0, 1.0)], Role::Emission).is_err());
        assert!(list_to_rgb(&[(500.0, 1.0), (400.0, 1.0)], Role::Emission).is_err());
    }
}
