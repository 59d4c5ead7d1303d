//! Pixel sums of render passes, and the combination of a guided render's passes into one image
//! with weights inversely proportional to their variance, as production path guiding does
//! (Müller 2019, "Practical Path Guiding in Production", §3): every pass is an unbiased image
//! whatever its guide had learned, so any fixed weights keep the result unbiased, and weights
//! estimated from whole images are near-constant, so the training passes are not wasted.
//!
//! A pass's own estimate can fall far below its true variance when its few samples missed the
//! rare paths that carry most of it (a small, bright light seen in a glossy plate): on
//! Bitterli's `veach-mis` such a short pass took most of the weight and left the image dark
//! (docs/results/guiding.md, "Path guiding on published scenes"). As the guide learns, the
//! variance per sample can only fall from pass to pass in expectation, so the estimates per
//! sample are fitted by the closest non-increasing sequence (isotonic regression, weighted by
//! the passes' samples) before they are inverted: a pass that claims less noise than the passes
//! after it is pooled with them.

use crate::film::Image;
use crate::geometry::{luminance, Rgb};

/// The sums over a pixel's samples of the three channels and of the squared luminance (for a
/// variance estimate), in f64.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelSum {
    /// Σ of each channel.
    pub rgb: [f64; 3],
    /// Σ of the squared luminance.
    pub luminance_sq: f64,
}

impl PixelSum {
    /// Add one sample's radiance.
    pub fn add_sample(&mut self, l: Rgb) {
        for c in 0..3 {
            self.rgb[c] += f64::from(l[c]);
        }
        self.luminance_sq += f64::from(luminance(l)).powi(2);
    }

    /// Add another sum.
    pub fn merge(&mut self, o: &PixelSum) {
        for c in 0..3 {
            self.rgb[c] += o.rgb[c];
        }
        self.luminance_sq += o.luminance_sq;
    }
}

/// One render pass: its samples per pixel and its pixel sums (row-major).
#[derive(Clone, Debug, PartialEq)]
pub struct PassSums {
    /// Samples per pixel.
    pub spp: u32,
    /// Sums per pixel.
    pub pixels: Vec<PixelSum>,
}

impl PassSums {
    /// Variance of the pass's pixel means, averaged over the image (of the luminance; `None`
    /// for a pass of one sample, whose pixels give no variance estimate).
    pub fn variance(&self) -> Option<f64> {
        if self.spp < 2 || self.pixels.is_empty() {
            return None;
        }
        let n = f64::from(self.spp);
        let total: f64 = self
            .pixels
            .iter()
            .map(|s| {
                let [r, g, b] = s.rgb;
                let mean = f64::from(luminance(Rgb::new(r as f32, g as f32, b as f32))) / n;
                ((s.luminance_sq / n - mean * mean) * n / (n - 1.0)).max(0.0) / n
            })
            .sum();
        Some(total / self.pixels.len() as f64)
    }
}

/// The closest non-increasing sequence to `values` in the least squares weighted by `weights`
/// (the pool-adjacent-violators algorithm): each run of values that rises is replaced by its
/// weighted mean.
pub fn non_increasing_fit(values: &[f64], weights: &[f64]) -> Vec<f64> {
    // Blocks of (weighted mean, total weight, length), kept non-increasing.
    let mut blocks: Vec<(f64, f64, usize)> = Vec::with_capacity(values.len());
    for (&v, &w) in values.iter().zip(weights) {
        let mut block = (v, w, 1);
        while let Some(&(m, pw, n)) = blocks.last() {
            if m >= block.0 {
                break;
            }
            blocks.pop();
            let total = pw + block.1;
            block = ((m * pw + block.0 * block.1) / total, total, n + block.2);
        }
        blocks.push(block);
    }
    blocks
        .into_iter()
        .flat_map(|(m, _, n)| std::iter::repeat_n(m, n))
        .collect()
}

/// The passes of a guided render, in the order they were rendered, combined with weights
/// inversely proportional to their image-averaged variance, its estimates per sample fitted
/// non-increasing first (see the module documentation). One-sample passes (no variance
/// estimate) are left out; when some pass has no noise at all (e.g. a black image), the passes
/// are pooled by sample count instead.
pub fn combine(width: u32, height: u32, passes: &[PassSums]) -> Image {
    let raw: Vec<(f64, &PassSums)> = passes
        .iter()
        .filter_map(|p| p.variance().map(|v| (v, p)))
        .collect();
    let spp: Vec<f64> = raw.iter().map(|(_, p)| f64::from(p.spp)).collect();
    let per_sample: Vec<f64> = raw.iter().zip(&spp).map(|((v, _), n)| v * n).collect();
    let fitted = non_increasing_fit(&per_sample, &spp);
    let estimates: Vec<(f64, &PassSums)> = raw
        .iter()
        .zip(fitted.iter().zip(&spp))
        .map(|((_, p), (s, n))| (s / n, *p))
        .collect();
    let pool = |weights: Vec<(f64, &PassSums)>| {
        let total: f64 = weights.iter().map(|w| w.0).sum();
        let mut pixels = vec![Rgb::ZERO; width as usize * height as usize];
        for (wt, pass) in &weights {
            let scale = wt / total / f64::from(pass.spp);
            for (p, s) in pixels.iter_mut().zip(&pass.pixels) {
                let [r, g, b] = s.rgb;
                *p += Rgb::new((r * scale) as f32, (g * scale) as f32, (b * scale) as f32);
            }
        }
        Image {
            width,
            height,
            pixels,
        }
    };
    if !estimates.is_empty() && estimates.iter().all(|(v, _)| *v > 0.0 && v.is_finite()) {
        pool(estimates.into_iter().map(|(v, p)| (1.0 / v, p)).collect())
    } else {
        pool(passes.iter().map(|p| (f64::from(p.spp), p)).collect())
    }
}

/// The image of pixel sums over `spp` samples each.
pub fn average(width: u32, height: u32, sums: &[PixelSum], spp: u32) -> Image {
    let inv = 1.0 / f64::from(spp.max(1));
    Image {
        width,
        height,
        pixels: sums
            .iter()
            .map(|s| {
                let [r, g, b] = s.rgb;
                Rgb::new((r * inv) as f32, (g * inv) as f32, (b * inv) as f32)
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pass of `n` (even) grey samples per pixel, half `m − d` and half `m + d`, on 4 pixels.
    fn pass(n: u32, m: f64, d: f64) -> PassSums {
        let (lo, hi) = (m - d, m + d);
        let sum = f64::from(n / 2) * (lo + hi);
        let sq = f64::from(n / 2) * (lo * lo + hi * hi);
        PassSums {
            spp: n,
            pixels: vec![
                PixelSum {
                    rgb: [sum; 3],
                    luminance_sq: sq,
                };
                4
            ],
        }
    }

    #[test]
    fn passes_are_combined_by_inverse_variance() {
        // Sample variance d²·n/(n − 1); variance of the pixel mean d²/(n − 1).
        let v = pass(4, 1.0, 0.3).variance().unwrap();
        assert!((v - 0.09 / 3.0).abs() < 1e-6, "{v}");
        assert_eq!(pass(1, 1.0, 0.0).variance(), None);
        // Variances 0.12 then 0.09/3 = 0.03 (falling, as a guide learns): weights 0.2 and 0.8.
        let img = combine(2, 2, &[pass(4, 2.0, 0.6), pass(4, 1.0, 0.3)]);
        for p in &img.pixels {
            assert!((p.x - 1.2).abs() < 1e-5, "{p:?}");
        }
        // A pass that claims less noise than the one after it is pooled with it: equal
        // variances per sample, weights by sample count.
        let img = combine(2, 2, &[pass(4, 1.0, 0.3), pass(4, 2.0, 0.6)]);
        for p in &img.pixels {
            assert!((p.x - 1.5).abs() < 1e-5, "{p:?}");
        }
        // A one-sample pass has no variance estimate and is left out.
        let one = PassSums {
            spp: 1,
            pixels: vec![
                PixelSum {
                    rgb: [9.0; 3],
                    luminance_sq: 81.0,
                };
                4
            ],
        };
        let img = combine(2, 2, &[one, pass(4, 1.0, 0.3)]);
        assert!((img.pixels[0].x - 1.0).abs() < 1e-6);
        // Noise-free passes (a black image) are pooled by sample count.
        let img = combine(2, 2, &[pass(2, 0.0, 0.0), pass(6, 0.0, 0.0)]);
        assert!(img.pixels.iter().all(|p| p.x == 0.0));
        let img = combine(2, 2, &[pass(2, 1.0, 0.0), pass(6, 3.0, 0.0)]);
        assert!((img.pixels[0].x - 2.5).abs() < 1e-6, "{:?}", img.pixels[0]);
    }

    #[test]
    fn the_fit_pools_rising_runs_and_keeps_a_falling_sequence() {
        assert_eq!(
            non_increasing_fit(&[5.0, 3.0, 1.0], &[1.0; 3]),
            [5.0, 3.0, 1.0]
        );
        assert_eq!(non_increasing_fit(&[1.0, 3.0], &[1.0, 1.0]), [2.0, 2.0]);
        // A rise that reaches back over a pooled block: (1·2 + 3·4)/4 = 3.5 ≥ … ≥ the rest.
        let f = non_increasing_fit(&[2.0, 1.0, 3.0, 4.0, 0.5], &[1.0, 1.0, 1.0, 1.0, 2.0]);
        assert_eq!(f, [2.5, 2.5, 2.5, 2.5, 0.5]);
        assert!(non_increasing_fit(&[], &[]).is_empty());
    }

    #[test]
    fn an_early_pass_that_missed_the_rare_paths_does_not_rule_the_image() {
        // veach-mis, seed 0, PPG: per-sample variance estimates of passes of 2, 4, 8, 16, 33 spp.
        // The 2-spp pass saw none of the fireflies; raw inverse variance gave it 78% of the
        // weight, the fit gives it about 2%.
        let spp = [2.0, 4.0, 8.0, 16.0, 33.0];
        let raw = [3.1, 794.5, 249.9, 339.5, 346.5];
        let fitted = non_increasing_fit(&raw, &spp);
        let weight = |s: &[f64]| {
            let w: Vec<f64> = s.iter().zip(&spp).map(|(v, n)| n / v).collect();
            w[0] / w.iter().sum::<f64>()
        };
        assert!(weight(&raw) > 0.75, "{}", weight(&raw));
        assert!(weight(&fitted) < 0.03, "{}", weight(&fitted));
        assert!(fitted.windows(2).all(|w| w[0] >= w[1]), "{fitted:?}");
    }
}
