//! Pixel reconstruction filters (Mitsuba 3's `rfilter` plugins `box`, `tent`, `gaussian`,
//! `mitchell`, `catmullrom`, `lanczos`), applied by *filter importance sampling* (Ernst et al.,
//! "Filter Importance Sampling", 2006; pbrt-v4 §8.8): each sample's image-plane offset from its
//! pixel centre is drawn from the separable filter `f(x) f(y)` itself, and carries the weight
//! `f/(p·∫f)`, so each pixel is an unbiased estimate of `∫ f(x−c) L(x) dx / ∫ f` — the image
//! Mitsuba's splatting film converges to — while every sample still lands in one pixel only
//! (tiles stay independent, images deterministic).
//!
//! The box and tent are sampled exactly (weight 1); the other filters by a 1-D table of `|f|`
//! over `[−r, r]` ([`TABLE_BINS`] bins, piecewise constant), with weight `f(x) / (p(x) ∫f)`,
//! negative where Mitsuba's and Lanczos's filters have negative lobes.

use crate::sampling::Distribution1D;

/// Bins of the tabulated sampling density of a filter on `[−radius, radius]`.
pub const TABLE_BINS: usize = 256;

/// A reconstruction filter's shape.
#[derive(Clone, Debug, PartialEq)]
pub enum FilterKind {
    /// The pixel's square (radius ½).
    Box,
    /// `max(0, 1 − |x|/r)`.
    Tent {
        /// Radius in pixels (Mitsuba's default 1).
        radius: f32,
    },
    /// `max(0, exp(−x²/2σ²) − exp(−r²/2σ²))` with `r = 4σ` (Mitsuba's default filter).
    Gaussian {
        /// Standard deviation in pixels (Mitsuba's default 0.5).
        stddev: f32,
    },
    /// Mitchell–Netravali cubic with parameters `B`, `C` (radius 2; Catmull–Rom is B = 0,
    /// C = ½).
    Mitchell {
        /// `B`.
        b: f32,
        /// `C`.
        c: f32,
    },
    /// Windowed sinc with `lobes` lobes (radius `lobes`).
    Lanczos {
        /// Number of lobes (Mitsuba's default 3).
        lobes: u32,
    },
}

impl FilterKind {
    /// Half-width of the support, in pixels.
    pub fn radius(&self) -> f32 {
        match *self {
            FilterKind::Box => 0.5,
            FilterKind::Tent { radius } => radius,
            FilterKind::Gaussian { stddev } => 4.0 * stddev,
            FilterKind::Mitchell { .. } => 2.0,
            FilterKind::Lanczos { lobes } => lobes as f32,
        }
    }

    /// The 1-D filter at offset `x` (pixels), unnormalised, as Mitsuba evaluates it.
    pub fn eval(&self, x: f32) -> f32 {
        let r = self.radius();
        let ax = x.abs();
        if ax > r {
            return 0.0;
        }
        match *self {
            FilterKind::Box => 1.0,
            FilterKind::Tent { radius } => (1.0 - ax / radius).max(0.0),
            FilterKind::Gaussian { stddev } => {
                let alpha = -1.0 / (2.0 * stddev * stddev);
                ((alpha * x * x).exp() - (alpha * r * r).exp()).max(0.0)
            }
            FilterKind::Mitchell { b, c } => {
                let x = 2.0 * ax / r;
                let x2 = x * x;
                let x3 = x2 * x;
                let v = if x < 1.0 {
                    (12.0 - 9.0 * b - 6.0 * c) * x3
                        + (-18.0 + 12.0 * b + 6.0 * c) * x2
                        + (6.0 - 2.0 * b)
                } else {
                    (-b - 6.0 * c) * x3
                        + (6.0 * b + 30.0 * c) * x2
                        + (-12.0 * b - 48.0 * c) * x
                        + (8.0 * b + 24.0 * c)
                };
                v / 6.0
            }
            FilterKind::Lanczos { lobes } => {
                let sinc = |t: f32| {
                    if t.abs() < 1e-5 {
                        1.0
                    } else {
                        let pt = std::f32::consts::PI * t;
                        pt.sin() / pt
                    }
                };
                sinc(x) * sinc(x / lobes as f32)
            }
        }
    }
}

/// A filter ready to draw offsets from.
#[derive(Clone, Debug)]
pub struct Filter {
    kind: FilterKind,
    /// Sampling table of `|f|` for the tabulated kinds, and `∫ f`.
    table: Option<(Distribution1D, f32)>,
}

impl PartialEq for Filter {
    fn eq(&self, other: &Self) -> bool {
        self.kind == other.kind
    }
}

impl Default for Filter {
    fn default() -> Self {
        Filter::new(FilterKind::Box).expect("the box filter is valid")
    }
}

impl Filter {
    /// A filter of `kind`; an error when its parameters give no positive area.
    pub fn new(kind: FilterKind) -> Result<Filter, String> {
        let r = kind.radius();
        if !(r.is_finite() && r > 0.0 && r <= 32.0) {
            return Err(format!("filter radius {r} must be in (0, 32] pixels"));
        }
        let table = match kind {
            FilterKind::Box | FilterKind::Tent { .. } => None,
            _ => {
                let width = 2.0 * r / TABLE_BINS as f32;
                // Each bin's |f| and signed f by the midpoint rule on 8 points.
                let (mut abs, mut integral) = (Vec::with_capacity(TABLE_BINS), 0.0f64);
                for i in 0..TABLE_BINS {
                    let (mut a, mut s) = (0.0f32, 0.0f32);
                    for k in 0..8 {
                        let x = -r + (i as f32 + (k as f32 + 0.5) / 8.0) * width;
                        let v = kind.eval(x);
                        a += v.abs();
                        s += v;
                    }
                    abs.push(a / 8.0);
                    integral += f64::from(s / 8.0 * width);
                }
                let dist = Distribution1D::new(&abs).ok_or("the filter is zero everywhere")?;
                if integral <= 0.0 {
                    return Err("the filter integrates to zero or less".into());
                }
                Some((dist, integral as f32))
            }
        };
        Ok(Filter { kind, table })
    }

    /// The filter's shape.
    pub fn kind(&self) -> &FilterKind {
        &self.kind
    }

    /// A 1-D position within the pixel's span `[0, 1)` shifted by a filter offset, and its
    /// weight, from the uniform number `u`. The box returns `(u, 1)` exactly, so that box
    /// images stay those of a plain jittered sampler.
    pub fn sample(&self, u: f32) -> (f32, f32) {
        match (&self.kind, &self.table) {
            (FilterKind::Box, _) => (u, 1.0),
            (FilterKind::Tent { radius }, _) => {
                // Inverse CDF of the unit tent on [−1, 1], scaled.
                let t = if u < 0.5 {
                    (2.0 * u).sqrt() - 1.0
                } else {
                    1.0 - (2.0 - 2.0 * u).max(0.0).sqrt()
                };
                (0.5 + radius * t, 1.0)
            }
            (kind, Some((dist, integral))) => {
                let r = kind.radius();
                let n = TABLE_BINS as f32;
                let i = dist.sample(u);
                let lo = if i == 0 { 0.0 } else { dist.cdf_at(i - 1) };
                let pmf = dist.pmf(i);
                let within = if pmf > 0.0 {
                    ((u - lo) / pmf).clamp(0.0, 1.0)
                } else {
                    0.5
                };
                let width = 2.0 * r / n;
                let x = -r + (i as f32 + within) * width;
                let pdf = pmf / width;
                let weight = kind.eval(x) / (pdf * integral);
                (0.5 + x, weight)
            }
            (_, None) => unreachable!("tabulated filters have a table"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinds() -> Vec<FilterKind> {
        vec![
            FilterKind::Box,
            FilterKind::Tent { radius: 1.0 },
            FilterKind::Gaussian { stddev: 0.5 },
            FilterKind::Mitchell {
                b: 1.0 / 3.0,
                c: 1.0 / 3.0,
            },
            FilterKind::Mitchell { b: 0.0, c: 0.5 },
            FilterKind::Lanczos { lobes: 3 },
        ]
    }

    /// E[w·g(x)] = ∫ f g / ∫ f for a test function g, by a fine stratified sum over u.
    #[test]
    fn weighted_offsets_average_to_the_normalised_filter() {
        let g = |x: f32| 1.0 + 0.3 * x + 0.2 * x * x;
        for kind in kinds() {
            let filter = Filter::new(kind.clone()).unwrap();
            let n = 200_000;
            let (mut sum_w, mut sum_wg) = (0.0f64, 0.0f64);
            for i in 0..n {
                let (p, w) = filter.sample((i as f32 + 0.5) / n as f32);
                let x = p - 0.5;
                assert!(x.abs() <= kind.radius() + 1e-4, "{kind:?} {x}");
                sum_w += f64::from(w);
                sum_wg += f64::from(w * g(x));
            }
            // Reference by quadrature of f and f·g.
            let (r, m) = (kind.radius(), 100_000);
            let (mut f_int, mut fg_int) = (0.0f64, 0.0f64);
            for i in 0..m {
                let x = -r + (i as f32 + 0.5) / m as f32 * 2.0 * r;
                f_int += f64::from(kind.eval(x));
                fg_int += f64::from(kind.eval(x) * g(x));
            }
            let want = fg_int / f_int;
            assert!(
                (sum_w / n as f64 - 1.0).abs() < 2e-3,
                "{kind:?}: E[w] = {}",
                sum_w / n as f64
            );
            assert!(
                (sum_wg / n as f64 - want).abs() < 2e-3 * want,
                "{kind:?}: {} vs {want}",
                sum_wg / n as f64
            );
        }
    }

    #[test]
    fn the_box_is_the_plain_jitter() {
        let f = Filter::default();
        assert_eq!(f.sample(0.375), (0.375, 1.0));
    }

    #[test]
    fn mitsubas_gaussian_is_zero_at_its_radius() {
        let k = FilterKind::Gaussian { stddev: 0.5 };
        assert_eq!(k.eval(2.0), 0.0);
        assert!((k.eval(0.0) - (1.0 - (-8.0f32).exp())).abs() < 1e-6);
        assert!(Filter::new(FilterKind::Gaussian { stddev: 0.0 }).is_err());
    }
}
