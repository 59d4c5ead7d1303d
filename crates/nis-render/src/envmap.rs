//! An environment map: radiance arriving from infinitely far away, read from a
//! latitude–longitude image (Mitsuba 3's `envmap`: direction `d` in the map's frame has
//! `u = atan2(d.x, −d.z)/2π`, `v = acos(d.y)/π`; the image is interpolated bilinearly with
//! texel-centred columns that wrap around in `u` and rows aligned to the poles in `v`, row 0 at
//! `v = 0` and the last at `v = 1`, as Mitsuba 3.9 does; times `scale`).
//!
//! Light sampling draws a cell of a `W × H` grid over `(u, v)` in proportion to the brightest
//! texel that reaches it by interpolation times `sin θ` (the solid angle it covers), then a point
//! uniformly in the cell, so the density of a direction is `p(cell) · W · H / (2π² sin θ)`,
//! exactly what [`EnvMap::pdf`] returns for any direction (Pharr et al., *PBR* 4th ed.,
//! §12.5.2); every direction with radiance has density.

use std::f32::consts::PI;
use std::sync::Arc;

use glam::{Mat3, Vec2, Vec3};

use crate::geometry::{luminance, Rgb};
use crate::sampling::Distribution2D;
use crate::texture::{Bitmap, WrapMode};

/// A sampled direction of the map.
#[derive(Clone, Copy, Debug)]
pub struct EnvSample {
    /// World direction towards the environment.
    pub wi: Vec3,
    /// Radiance arriving from it.
    pub radiance: Rgb,
    /// Solid-angle density.
    pub pdf: f32,
}

/// A latitude–longitude environment map with its sampling tables.
#[derive(Debug)]
pub struct EnvMap {
    image: Arc<Bitmap>,
    scale: f32,
    to_world: Mat3,
    to_local: Mat3,
    cells: Distribution2D,
}

impl EnvMap {
    /// A map of `image` (its u wraps around, v is clamped at the poles), radiance times
    /// `scale`, oriented by the rotation `to_world`; `None` when the map is black.
    pub fn new(image: Bitmap, scale: f32, to_world: Mat3) -> Option<EnvMap> {
        let image = image.with_wrap_v(WrapMode::Clamp);
        let (w, h) = image.size();
        let mut rows = Vec::with_capacity(h);
        let lum: Vec<f32> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| luminance(image.texel_at(x, y)).max(0.0))
            .collect();
        for y in 0..h {
            let sin = ((y as f32 + 0.5) / h as f32 * PI).sin();
            // Cell (x, y) spans v ∈ [y, y+1]/H, which the rows around y·(H−1)/H reach.
            let (r0, r1) = (
                (y * (h - 1)) / h,
                (((y + 1) * (h - 1)).div_ceil(h)).min(h - 1),
            );
            let weights: Vec<f32> = (0..w)
                .map(|x| {
                    let mut m = 0.0f32;
                    for r in r0..=r1 {
                        for dx in [w - 1, 0, 1] {
                            m = m.max(lum[r * w + (x + dx) % w]);
                        }
                    }
                    m * sin
                })
                .collect();
            rows.push(weights);
        }
        let cells = Distribution2D::new(&rows)?;
        Some(EnvMap {
            image: Arc::new(image),
            scale,
            to_world,
            to_local: to_world.inverse(),
            cells,
        })
    }

    fn uv(&self, dir: Vec3) -> Vec2 {
        let d = (self.to_local * dir).normalize_or_zero();
        // θ by atan2, well conditioned near the poles where acos(d.y) is not.
        Vec2::new(
            d.x.atan2(-d.z) / (2.0 * PI),
            (d.x * d.x + d.z * d.z).sqrt().atan2(d.y) / PI,
        )
    }

    /// Radiance arriving from world direction `dir` (pointing away from the scene).
    pub fn eval(&self, dir: Vec3) -> Rgb {
        self.lookup(self.uv(dir))
    }

    /// The image at `uv`: texel-centred and wrapping in `u`, pole-aligned in `v`.
    fn lookup(&self, uv: Vec2) -> Rgb {
        let (w, h) = self.image.size();
        let u = uv.x - uv.x.floor();
        let v = uv.y.clamp(0.0, 1.0);
        self.image
            .eval_texels(u * w as f32 - 0.5, v * (h - 1) as f32)
            * self.scale
    }

    /// Solid-angle density of [`EnvMap::sample`] for world direction `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        let uv = self.uv(dir);
        let (w, h) = self.image.size();
        let u = uv.x - uv.x.floor();
        let x = ((u * w as f32) as usize).min(w - 1);
        let y = ((uv.y * h as f32) as usize).min(h - 1);
        let sin = (uv.y * PI).sin();
        if sin <= 0.0 {
            return 0.0;
        }
        self.cells.pmf(y, x) * (w * h) as f32 / (2.0 * PI * PI * sin)
    }

    /// Draw a direction from two uniform numbers.
    pub fn sample(&self, u: Vec2) -> Option<EnvSample> {
        let (w, h) = self.image.size();
        let (y, x, f) = self.cells.sample(u)?;
        let uv = Vec2::new((x as f32 + f.x) / w as f32, (y as f32 + f.y) / h as f32);
        let (sin_t, cos_t) = (uv.y * PI).sin_cos();
        let (sin_p, cos_p) = (uv.x * 2.0 * PI).sin_cos();
        if sin_t <= 0.0 {
            return None;
        }
        let local = Vec3::new(sin_p * sin_t, cos_t, -cos_p * sin_t);
        let wi = (self.to_world * local).normalize();
        let pdf = self.cells.pmf(y, x) * (w * h) as f32 / (2.0 * PI * PI * sin_t);
        Some(EnvSample {
            wi,
            radiance: self.lookup(uv),
            pdf,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::square_to_uniform_sphere;
    use crate::texture::FilterMode;

    fn map() -> EnvMap {
        // 8 × 4 texels: dim, with one bright texel.
        let mut texels = vec![[0.2f32, 0.3, 0.4]; 32];
        texels[8 + 5] = [20.0, 18.0, 15.0];
        let image =
            Bitmap::from_linear(8, 4, texels, FilterMode::Bilinear, WrapMode::Repeat).unwrap();
        let to_world = Mat3::from_axis_angle(Vec3::new(0.3, 1.0, 0.2).normalize(), 0.7);
        EnvMap::new(image, 1.5, to_world).unwrap()
    }

    /// ∫ pdf dω = 1 over the sphere (a fine midpoint rule), and samples' densities agree with
    /// `pdf` of their direction.
    #[test]
    fn the_density_integrates_to_one_and_matches_the_samples() {
        let m = map();
        let n = 400;
        let mut total = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                total += f64::from(m.pdf(square_to_uniform_sphere(u)));
            }
        }
        let integral = total * 4.0 * std::f64::consts::PI / (n * n) as f64;
        assert!((integral - 1.0).abs() < 1e-2, "∫ pdf = {integral}");
        for k in 0..500 {
            let u = Vec2::new(
                ((k * 37) % 500) as f32 / 500.0 + 1e-3,
                (k as f32 + 0.5) / 500.0,
            );
            let s = m.sample(u).unwrap();
            let pdf = m.pdf(s.wi);
            assert!((s.pdf - pdf).abs() <= 1e-3 * pdf, "{} vs {pdf}", s.pdf);
            assert!((s.radiance - m.eval(s.wi)).abs().max_element() < 1e-4);
        }
    }

    /// E[L/p] over samples is the integral of the radiance, ∫ L dω, by quadrature.
    #[test]
    fn importance_sampled_radiance_is_unbiased() {
        let m = map();
        let n = 600;
        let mut quad = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                quad += f64::from(luminance(m.eval(square_to_uniform_sphere(u))));
            }
        }
        let quad = quad * 4.0 * std::f64::consts::PI / (n * n) as f64;
        let (mut est, k) = (0.0f64, 400);
        for a in 0..k {
            for b in 0..k {
                let u = Vec2::new((a as f32 + 0.5) / k as f32, (b as f32 + 0.5) / k as f32);
                if let Some(s) = m.sample(u) {
                    est += f64::from(luminance(s.radiance) / s.pdf);
                }
            }
        }
        let est = est / (k * k) as f64;
        assert!((est - quad).abs() < 5e-3 * quad, "{est} vs {quad}");
    }
}
