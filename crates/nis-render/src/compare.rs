//! Image error metrics for comparing a render with a reference, and a false-colour error map.
//!
//! MAPE (mean absolute percentage error) and relMSE (relative mean squared error) are the
//! metrics of the path-guiding literature (e.g. Müller et al. 2019, "Neural Importance
//! Sampling", §6): per channel `|a − b| / (|b| + ε)` and `(a − b)² / (b² + ε)` averaged over
//! pixels and channels, with `b` the reference and `ε = 0.01` keeping dark pixels from
//! dominating.

use glam::Vec3;

use crate::film::Image;
use crate::Error;

/// The ε of MAPE and relMSE.
pub const METRIC_EPSILON: f64 = 0.01;

/// A pixel is far off when its relative error (channel mean) exceeds this: more than five
/// times the reference. A pixel can fall short by at most 1, so only fireflies are far off;
/// relMSE, which they rule, swings with their number from seed to seed.
pub const FAR_OFF_ERROR: f64 = 4.0;

/// Errors of an image against a reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageErrors {
    /// Mean absolute percentage error (a fraction, not percent).
    pub mape: f64,
    /// Relative mean squared error.
    pub relmse: f64,
    /// Share of pixels whose relative error exceeds [`FAR_OFF_ERROR`] (fireflies).
    pub far_off: f64,
    /// Mean of the test image.
    pub mean: f64,
    /// Mean of the reference image.
    pub reference_mean: f64,
}

fn check_sizes(a: &Image, b: &Image) -> Result<(), Error> {
    if a.width != b.width || a.height != b.height {
        return Err(Error::Invalid(format!(
            "image sizes differ: {}×{} vs {}×{}",
            a.width, a.height, b.width, b.height
        )));
    }
    Ok(())
}

/// MAPE and relMSE of `image` against `reference`.
pub fn compare(image: &Image, reference: &Image) -> Result<ImageErrors, Error> {
    check_sizes(image, reference)?;
    let (mut mape, mut relmse, mut far_off) = (0.0f64, 0.0f64, 0usize);
    for (a, b) in image.pixels.iter().zip(&reference.pixels) {
        let mut pixel = 0.0;
        for c in 0..3 {
            let (a, b) = (f64::from(a[c]), f64::from(b[c]));
            let d = a - b;
            pixel += d.abs() / (b.abs() + METRIC_EPSILON);
            relmse += d * d / (b * b + METRIC_EPSILON);
        }
        mape += pixel;
        far_off += usize::from(pixel / 3.0 > FAR_OFF_ERROR);
    }
    let pixels = image.pixels.len().max(1) as f64;
    let n = 3.0 * pixels;
    Ok(ImageErrors {
        mape: mape / n,
        relmse: relmse / n,
        far_off: far_off as f64 / pixels,
        mean: image.mean(),
        reference_mean: reference.mean(),
    })
}

/// Per-pixel relative error `|a − b| / (|b| + ε)` (channel mean) shown in false colour, with
/// `max_error` and above at the top of the colour scale.
pub fn error_map(image: &Image, reference: &Image, max_error: f32) -> Result<Image, Error> {
    check_sizes(image, reference)?;
    let eps = METRIC_EPSILON as f32;
    let pixels = image
        .pixels
        .iter()
        .zip(&reference.pixels)
        .map(|(a, b)| {
            let e = ((*a - *b).abs() / (b.abs() + Vec3::splat(eps))).element_sum() / 3.0;
            false_colour((e / max_error).clamp(0.0, 1.0))
        })
        .collect();
    Ok(Image {
        width: image.width,
        height: image.height,
        pixels,
    })
}

/// A perceptually ordered dark-blue → teal → yellow scale (approximating viridis), returned as
/// linear RGB so that the PNG writer's sRGB encoding reproduces the intended colours.
pub fn false_colour(t: f32) -> Vec3 {
    const STOPS: [[f32; 3]; 5] = [
        [0.267, 0.005, 0.329],
        [0.229, 0.322, 0.546],
        [0.128, 0.567, 0.551],
        [0.369, 0.789, 0.383],
        [0.993, 0.906, 0.144],
    ];
    let x = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let i = (x as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    let c = Vec3::from(STOPS[i]).lerp(Vec3::from(STOPS[i + 1]), f);
    // sRGB-encoded stops to linear.
    c.map(|v| {
        if v <= 0.04045 {
            v / 12.92
        } else {
            ((v + 0.055) / 1.055).powf(2.4)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_of_known_images() {
        let mut a = Image::new(2, 1);
        let mut b = Image::new(2, 1);
        b.pixels = vec![Vec3::ONE, Vec3::splat(2.0)];
        a.pixels = vec![Vec3::splat(1.1), Vec3::splat(2.0)];
        let e = compare(&a, &b).unwrap();
        let expect_mape = 0.5 * (0.1 / 1.01);
        let expect_relmse = 0.5 * (0.01 / 1.01);
        assert!((e.mape - expect_mape).abs() < 1e-6, "{}", e.mape);
        assert!((e.relmse - expect_relmse).abs() < 1e-6);
        assert_eq!(e.far_off, 0.0);
        assert!(compare(&a, &Image::new(1, 1)).is_err());
        let map = error_map(&a, &b, 1.0).unwrap();
        assert_eq!(map.pixels[1], false_colour(0.0));
        // A firefly: six times the reference (error 5 / 1.01 > 4) in one pixel of two; an
        // error of at most 4 is not far off.
        a.pixels = vec![Vec3::splat(6.0), Vec3::splat(2.0 * (1.0 + 4.0))];
        assert_eq!(compare(&a, &b).unwrap().far_off, 0.5);
    }
}
