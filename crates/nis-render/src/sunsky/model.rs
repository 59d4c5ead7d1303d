//! The radiance of the sky and of the sun's disk for one sun position, in linear sRGB, as
//! Mitsuba 3's `sunsky` computes it in its RGB variants.
//!
//! The sky is Hosek & Wilkie's analytic model ("An Analytic Model for Full Spectral Sky-Dome
//! Radiance", SIGGRAPH 2012): per channel, `(1 + A e^{B/(cos θ + 0.01)}) · (C + D e^{E γ} +
//! F cos² γ + G χ(H, γ) + I √cos θ) · L_M`, θ the view's zenith angle, γ its angle to the sun,
//! with coefficients interpolated linearly in turbidity and in the ground albedo, and as a
//! quintic Bézier curve in the cube root of the sun's elevation. The sun is Hosek & Wilkie's
//! solar radiance ("Adding a Solar-Radiance Function to the Hošek-Wilkie Skylight Model", 2013):
//! by default a disk of uniform radiance whose irradiance is the tabulated spectral irradiance
//! (interpolated in turbidity and elevation, reduced to sRGB at the table's 11 wavelengths);
//! with `complex_sun`, Mitsuba's RGB polynomials with the limb darkening baked in. Either keeps
//! its irradiance when the aperture changes. Mitsuba's constants: radiances are scaled by its
//! CIE Y normalisation, the sun's also by its spectral-to-RGB factor.

use std::f32::consts::{FRAC_PI_2, PI};

use super::dataset::{
    Dataset, ALBEDOS, IRRADIANCE_ELEVATIONS, SKY_CONTROL_POINTS, SKY_PARAMS, SUN_CONTROL_POINTS,
    SUN_LIMB_PARAMS, SUN_SEGMENTS, TURBIDITIES, WAVELENGTHS,
};
use crate::geometry::Rgb;
use crate::spectrum::{cie, cie::Y_NORMALIZATION, xyz_to_srgb};

/// Mitsuba's factor from the tables' spectral solar radiance to RGB.
const SPEC_TO_RGB_SUN: f64 = 467.069_280_386;
/// The sun's mean apparent diameter, degrees (Mitsuba's default `sun_aperture`).
pub const SUN_APERTURE_DEG: f32 = 0.5358;

/// Linear interpolation of a table along its first axis (turbidity 1 to 10) at `turbidity`,
/// as Dr.Jit's `take_interp` does it: the lower index clamped to the last interval.
fn lerp_turbidity(table: &[f64], turbidity: f32) -> Vec<f64> {
    let inner = table.len() / TURBIDITIES;
    let pos = f64::from(turbidity) - 1.0;
    let i = (pos.max(0.0) as usize).min(TURBIDITIES - 2);
    let w = pos - i as f64;
    (0..inner)
        .map(|k| table[i * inner + k] * (1.0 - w) + table[(i + 1) * inner + k] * w)
        .collect()
}

/// The Bernstein weights of the six control points at the sun's elevation `eta` (radians).
fn bezier_weights(eta: f32) -> [f64; SKY_CONTROL_POINTS] {
    let x = f64::from(
        (2.0 * eta / PI)
            .max(0.0)
            .cbrt()
            .min(1.0 - f32::EPSILON / 2.0),
    );
    const BINOMIAL: [f64; SKY_CONTROL_POINTS] = [1.0, 5.0, 10.0, 10.0, 5.0, 1.0];
    std::array::from_fn(|k| BINOMIAL[k] * x.powi(k as i32) * (1.0 - x).powi(5 - k as i32))
}

/// The sky's coefficients and mean radiance per channel for one sun elevation.
#[derive(Clone, Debug)]
pub struct SkyModel {
    /// `A … I` in Mitsuba's order (`G` multiplies χ, `H` is χ's, `I` the square root's).
    params: [[f32; SKY_PARAMS]; 3],
    /// Mean radiance times the sky's scale and the CIE Y normalisation.
    radiance: [f32; 3],
}

impl SkyModel {
    /// The sky at `turbidity` over ground of `albedo` for a sun at elevation `eta` (radians
    /// above the horizon), its radiance times `scale`.
    pub fn new(data: &Dataset, turbidity: f32, albedo: Rgb, eta: f32, scale: f32) -> SkyModel {
        let bezier = bezier_weights(eta);
        let params_t = lerp_turbidity(&data.sky_params, turbidity);
        let radiance_t = lerp_turbidity(&data.sky_radiance, turbidity);
        let albedo = albedo.to_array();
        // After the turbidity: (albedo, control point, channel[, parameter]).
        let interp = |table: &[f64], per_channel: usize, c: usize, p: usize| -> f64 {
            let per_albedo = table.len() / ALBEDOS;
            let a = f64::from(albedo[c]);
            (0..SKY_CONTROL_POINTS)
                .map(|k| {
                    let at = k * 3 * per_channel + c * per_channel + p;
                    bezier[k] * (table[at] * (1.0 - a) + table[per_albedo + at] * a)
                })
                .sum()
        };
        let params = std::array::from_fn(|c| {
            std::array::from_fn(|p| interp(&params_t, SKY_PARAMS, c, p) as f32)
        });
        let radiance = std::array::from_fn(|c| {
            (interp(&radiance_t, 1, c, 0) * f64::from(scale) * Y_NORMALIZATION) as f32
        });
        SkyModel { params, radiance }
    }

    /// Radiance towards a view of zenith-angle cosine `cos_theta` (≥ 0) at angle `gamma` to
    /// the sun.
    pub fn eval(&self, cos_theta: f32, gamma: f32) -> Rgb {
        let cos_gamma = gamma.cos();
        let cos2 = cos_gamma * cos_gamma;
        let sqrt_cos = cos_theta.max(0.0).sqrt();
        let channel = |c: usize| {
            let p = &self.params[c];
            let c1 = 1.0 + p[0] * (p[1] / (cos_theta + 0.01)).exp();
            let chi = (1.0 + cos2) / (1.0 + p[8] * p[8] - 2.0 * p[8] * cos_gamma).powf(1.5);
            let c2 =
                p[2] + p[3] * (p[4] * gamma).exp() + p[5] * cos2 + p[6] * chi + p[7] * sqrt_cos;
            c1 * c2 * self.radiance[c]
        };
        Rgb::new(channel(0), channel(1), channel(2))
    }
}

/// The sun's disk: its radiance for a view inside it.
#[derive(Clone, Debug)]
pub enum SunModel {
    /// Uniform radiance over the disk.
    Uniform(Rgb),
    /// Mitsuba's `complex_sun`: per segment of the view's elevation, per channel, a polynomial
    /// in the elevation offset and in the cosine across the disk (limb darkening).
    LimbDarkened {
        /// Coefficients `[segment][channel][elevation power][limb power]`.
        coefficients: Vec<[[[f32; SUN_LIMB_PARAMS]; SUN_CONTROL_POINTS]; 3]>,
        /// The sun's scale, Mitsuba's constants and the aperture's area ratio.
        scale: f32,
        /// `1 / sin²` of the disk's angular radius.
        inv_sin2_radius: f32,
    },
}

/// `1 − cos` of the sun's angular radius for a full `aperture` in degrees, in single precision
/// as Mitsuba takes it (its disk test and its radiance's normalisation share this value).
pub fn one_minus_cos_radius(aperture_deg: f32) -> f32 {
    1.0 - (0.5 * aperture_deg).to_radians().cos()
}

impl SunModel {
    /// The sun at elevation `eta` (radians) for `turbidity`, its radiance times `scale`, over a
    /// disk of `aperture` degrees.
    pub fn new(
        data: &Dataset,
        turbidity: f32,
        eta: f32,
        scale: f32,
        aperture_deg: f32,
        complex: bool,
    ) -> SunModel {
        let constants = SPEC_TO_RGB_SUN * Y_NORMALIZATION * f64::from(scale);
        if complex {
            let table = lerp_turbidity(&data.sun_radiance, turbidity);
            let per_segment = 3 * SUN_CONTROL_POINTS * SUN_LIMB_PARAMS;
            let coefficients = (0..SUN_SEGMENTS)
                .map(|s| {
                    std::array::from_fn(|c| {
                        std::array::from_fn(|k| {
                            std::array::from_fn(|j| {
                                table[s * per_segment
                                    + c * SUN_CONTROL_POINTS * SUN_LIMB_PARAMS
                                    + k * SUN_LIMB_PARAMS
                                    + j] as f32
                            })
                        })
                    })
                })
                .collect();
            let area_ratio = f64::from(one_minus_cos_radius(SUN_APERTURE_DEG))
                / f64::from(one_minus_cos_radius(aperture_deg));
            let sin_radius = (0.5 * aperture_deg).to_radians().sin();
            return SunModel::LimbDarkened {
                coefficients,
                scale: (constants * area_ratio) as f32,
                inv_sin2_radius: 1.0 / (sin_radius * sin_radius),
            };
        }
        // The spectral irradiance at the sun's elevation, every 3° from 2°.
        let table = lerp_turbidity(&data.sun_irradiance, turbidity);
        let pos = ((f64::from(eta.to_degrees()) - 2.0) / 3.0)
            .clamp(0.0, (IRRADIANCE_ELEVATIONS - 1) as f64);
        let i = (pos as usize).min(IRRADIANCE_ELEVATIONS - 2);
        let w = pos - i as f64;
        let mut rgb = [0.0f64; 3];
        for l in 0..WAVELENGTHS {
            let irradiance =
                table[i * WAVELENGTHS + l] * (1.0 - w) + table[(i + 1) * WAVELENGTHS + l] * w;
            let cmf = cie(320.0 + 40.0 * l as f64);
            let srgb = xyz_to_srgb([cmf[0], cmf[1], cmf[2]]);
            for c in 0..3 {
                rgb[c] += srgb[c] * irradiance / WAVELENGTHS as f64;
            }
        }
        let solid_angle =
            2.0 * std::f64::consts::PI * f64::from(one_minus_cos_radius(aperture_deg));
        let radiance = rgb.map(|v| (v * constants / solid_angle) as f32);
        SunModel::Uniform(Rgb::from(radiance))
    }

    /// Radiance towards a view inside the disk, of zenith-angle cosine `cos_theta` (≥ 0) at
    /// angle `gamma` to the sun's centre.
    pub fn eval(&self, cos_theta: f32, gamma: f32) -> Rgb {
        match self {
            SunModel::Uniform(radiance) => *radiance,
            SunModel::LimbDarkened {
                coefficients,
                scale,
                inv_sin2_radius,
            } => {
                let elevation = FRAC_PI_2 - cos_theta.clamp(0.0, 1.0).acos();
                let segment = (((2.0 * elevation / PI).max(0.0).cbrt() * SUN_SEGMENTS as f32)
                    as usize)
                    .min(SUN_SEGMENTS - 1);
                let start = FRAC_PI_2 * (segment as f32 / SUN_SEGMENTS as f32).powi(3);
                let x = elevation - start;
                let sin_gamma = gamma.sin();
                let cos_psi = (1.0 - inv_sin2_radius * sin_gamma * sin_gamma)
                    .max(0.0)
                    .sqrt();
                let coefficients = &coefficients[segment];
                let channel = |c: usize| {
                    let mut sum = 0.0f32;
                    let mut xk = 1.0f32;
                    for row in &coefficients[c] {
                        let mut pj = 1.0f32;
                        for &a in row {
                            sum += xk * pj * a;
                            pj *= cos_psi;
                        }
                        xk *= x;
                    }
                    sum * scale
                };
                Rgb::new(channel(0), channel(1), channel(2))
            }
        }
    }
}
