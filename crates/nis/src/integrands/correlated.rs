//! Non-separable members of the suite: their mass lies along directions no product of
//! one-dimensional maps follows, so a separable sampler (the VEGAS map) covers a box around it
//! and relies on its stratification for the rest. Each is a normalised density, so its integral
//! over [0, 1]^d is one less the mass outside the cube; that mass is computed in closed form
//! where it matters and bounded where it is below 10⁻⁹ (docs/INTEGRANDS.md has the derivations).

use std::f64::consts::{PI, SQRT_2};

use super::Builtin;

/// Standard deviation, per coordinate, of the diagonal Gaussian along the diagonal.
const DIAG_ALONG: f64 = 0.075;
/// Its standard deviation across the diagonal.
const DIAG_ACROSS: f64 = 0.02;

/// Upper tail of the standard normal, Φ(−z) = ½·erfc(z/√2).
fn normal_tail(z: f64) -> f64 {
    0.5 * libm::erfc(z / SQRT_2)
}

/// A Gaussian at the centre elongated along the diagonal u = (1, …, 1)/√d: covariance
/// Σ = σ_∥²·uuᵀ + σ_⊥²·(I − uuᵀ) with σ_∥ = 0.075·√d and σ_⊥ = 0.02, normalised on R^d.
pub(super) fn gauss_diagonal(dim: usize) -> Builtin {
    let d = dim as f64;
    let along = DIAG_ALONG * d.sqrt();
    let across = DIAG_ACROSS;
    // (2π)^(−d/2)·|Σ|^(−1/2) with |Σ| = σ_∥²·σ_⊥^(2(d − 1)), in logs (σ_⊥^(−15) is 3·10²⁵).
    let log_norm = -0.5 * d * (2.0 * PI).ln() - along.ln() - (d - 1.0) * across.ln();
    // Each coordinate is N(½, s²) with s² = σ_∥²/d + σ_⊥²(1 − 1/d); the mass outside the cube is
    // at most the sum over coordinates of their mass outside [0, 1].
    let s = (DIAG_ALONG * DIAG_ALONG + across * across * (1.0 - 1.0 / d)).sqrt();
    let outside = d * 2.0 * normal_tail(0.5 / s);
    Builtin {
        name: String::new(),
        dim,
        exact: 1.0,
        exact_err: outside,
        source: "a normalised Gaussian with covariance σ_∥²uuᵀ + σ_⊥²(I − uuᵀ), u the diagonal; \
                 exact 1 less the mass outside the cube (< d·erfc(0.5/(s√2)))",
        f: Box::new(move |x| {
            let n = x.len() as f64;
            let (mut t, mut r2) = (0.0, 0.0);
            for v in x {
                t += v - 0.5;
                r2 += (v - 0.5) * (v - 0.5);
            }
            // Squared distance along u and across it.
            let t2 = t * t / n;
            let q = t2 / (along * along) + (r2 - t2).max(0.0) / (across * across);
            (log_norm - 0.5 * q).exp()
        }),
    }
}

/// Number of peaks of [`peaks`].
const PEAKS: usize = 4;
/// Width α of each peak (i-flow's normalisation: std α/√2).
const PEAK_WIDTH: f64 = 0.05;

/// Centre of peak `k`: coordinate i is 0.2 + 0.6·frac((k + 1)·√p_i), p_i the i-th prime, so the
/// centres are scattered, off the diagonal and at least 0.2 from every face.
pub(super) fn peak_centre(k: usize, dim: usize) -> Vec<f64> {
    primes(dim)
        .into_iter()
        .map(|p| 0.2 + 0.6 * ((k + 1) as f64 * (p as f64).sqrt()).fract())
        .collect()
}

/// The first `n` primes.
fn primes(n: usize) -> Vec<u64> {
    let mut out = Vec::with_capacity(n);
    let mut c = 2u64;
    while out.len() < n {
        if out.iter().take_while(|&&p| p * p <= c).all(|&p| c % p != 0) {
            out.push(c);
        }
        c += 1;
    }
    out
}

/// An equal mixture of four isotropic Gaussian peaks of width α = 0.05 at scattered centres.
pub(super) fn peaks(dim: usize) -> Builtin {
    let centres: Vec<Vec<f64>> = (0..PEAKS).map(|k| peak_centre(k, dim)).collect();
    let a = PEAK_WIDTH;
    // Each peak is a product of 1-D Gaussians: its mass in the cube is Π_i ½[erf((1 − c_i)/α) +
    // erf(c_i/α)].
    let exact = centres
        .iter()
        .map(|c| {
            c.iter()
                .map(|&ci| 0.5 * (libm::erf((1.0 - ci) / a) + libm::erf(ci / a)))
                .product::<f64>()
        })
        .sum::<f64>()
        / PEAKS as f64;
    let pre = (a * PI.sqrt()).powi(-(dim as i32)) / PEAKS as f64;
    Builtin {
        name: String::new(),
        dim,
        exact,
        exact_err: 0.0,
        source: "four Gaussian peaks, α = 0.05, at centres 0.2 + 0.6·frac((k+1)√p_i); exact \
                 ¼ Σ_k Π_i ½[erf((1 − c_ki)/α) + erf(c_ki/α)]",
        f: Box::new(move |x| {
            centres
                .iter()
                .map(|c| {
                    let r2: f64 = x.iter().zip(c).map(|(v, ci)| (v - ci) * (v - ci)).sum();
                    (-r2 / (a * a)).exp()
                })
                .sum::<f64>()
                * pre
        }),
    }
}

/// Width (std) of the ridge across the curve.
const RIDGE_WIDTH: f64 = 0.02;
/// Where along x₁ the peak on the ridge sits, and its width (std).
const RIDGE_PEAK: (f64, f64) = (0.7, 0.03);

/// The ridge's curve: x_i = g_i(x₁) for i ≥ 2, parabolas bending up and down in turn and
/// staying within [0.3, 0.7].
pub(super) fn ridge_curve(i: usize, t: f64) -> f64 {
    let bend = 1.6 * (t - 0.5) * (t - 0.5);
    if i % 2 == 1 {
        0.3 + bend
    } else {
        0.7 - bend
    }
}

/// A peak on a curved ridge: f(x) = h(x₁)·Π_{i≥2} N(x_i; g_i(x₁), w²) with w = 0.02 and
/// h = ½·U(0, 1) + ½·N(0.7, 0.03²): the ridge runs the whole length of x₁ with half its mass in a
/// peak on it.
pub(super) fn ridge(dim: usize) -> Builtin {
    let (mu, s) = RIDGE_PEAK;
    let w = RIDGE_WIDTH;
    // ∫ over x_i (i ≥ 2) of the conditional Gaussians is 1 less their tails outside [0, 1], at
    // least 0.3/w = 15 standard deviations away: each < 2Φ(−15) ≈ 10⁻⁵⁰, far below rounding. What
    // is left is ∫₀¹ h = ½ + ½[Φ((1 − μ)/s) − Φ(−μ/s)].
    let exact = 0.5 + 0.25 * (libm::erf((1.0 - mu) / (s * SQRT_2)) + libm::erf(mu / (s * SQRT_2)));
    let inv_sqrt_2pi = 1.0 / (2.0 * PI).sqrt();
    Builtin {
        name: String::new(),
        dim,
        exact,
        exact_err: (dim - 1) as f64 * 2.0 * normal_tail(0.3 / w),
        source: "h(x₁)·Π N(x_i; g_i(x₁), 0.02²), g_i parabolas, h = ½U + ½N(0.7, 0.03²); exact \
                 ½ + ¼[erf(0.3/(0.03√2)) + erf(0.7/(0.03√2))]",
        f: Box::new(move |x| {
            let t = x[0];
            let h = 0.5 + 0.5 * inv_sqrt_2pi / s * (-0.5 * ((t - mu) / s).powi(2)).exp();
            let mut q = 0.0;
            for (i, v) in x.iter().enumerate().skip(1) {
                q += ((v - ridge_curve(i, t)) / w).powi(2);
            }
            h * (inv_sqrt_2pi / w).powi(x.len() as i32 - 1) * (-0.5 * q).exp()
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peak_centres_are_scattered_and_inside() {
        for d in [2, 4, 8] {
            let c: Vec<Vec<f64>> = (0..PEAKS).map(|k| peak_centre(k, d)).collect();
            for a in 0..PEAKS {
                assert!(c[a].iter().all(|&v| (0.2..=0.8).contains(&v)));
                // Off the diagonal: the coordinates of one centre differ.
                let spread = c[a].iter().cloned().fold(f64::MIN, f64::max)
                    - c[a].iter().cloned().fold(f64::MAX, f64::min);
                assert!(spread > 0.02, "d={d} peak {a}: {:?}", c[a]);
                for b in 0..a {
                    // In the plane, the projections on each axis are apart, so a separable map
                    // sees 4² = 16 peaks where there are 4.
                    if d == 2 {
                        assert!(c[a]
                            .iter()
                            .zip(&c[b])
                            .all(|(u, v)| (u - v).abs() > 2.0 * PEAK_WIDTH));
                    }
                    let dist: f64 = c[a]
                        .iter()
                        .zip(&c[b])
                        .map(|(u, v)| (u - v).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    // Separate peaks: at least five widths apart.
                    assert!(dist > 5.0 * PEAK_WIDTH / SQRT_2, "d={d}: {a}, {b}: {dist}");
                }
            }
        }
        assert_eq!(primes(6), vec![2, 3, 5, 7, 11, 13]);
    }

    #[test]
    fn the_diagonal_gaussian_is_the_multivariate_normal_density() {
        // Against the textbook density with Σ⁻¹ and |Σ| formed from an explicit matrix: Σ's
        // eigenvectors are u (σ_∥²) and any vector across it (σ_⊥²), so Σ⁻¹ = uuᵀ/σ_∥² +
        // (I − uuᵀ)/σ_⊥², and det Σ is the product of the eigenvalues.
        for d in [2usize, 3, 5] {
            let g = gauss_diagonal(d);
            let (sa, sp) = (DIAG_ALONG * (d as f64).sqrt(), DIAG_ACROSS);
            let u = 1.0 / (d as f64).sqrt();
            let inv = |i: usize, j: usize| {
                let id = if i == j { 1.0 } else { 0.0 };
                u * u / (sa * sa) + (id - u * u) / (sp * sp)
            };
            let det = sa * sa * sp.powi(2 * (d as i32 - 1));
            for k in 0..20 {
                let x: Vec<f64> = (0..d)
                    .map(|i| 0.5 + 0.03 * (((k * d + i) as f64 * 0.754_877_7).fract() - 0.5))
                    .collect();
                let mut q = 0.0;
                for i in 0..d {
                    for j in 0..d {
                        q += (x[i] - 0.5) * inv(i, j) * (x[j] - 0.5);
                    }
                }
                let want = (-0.5 * q).exp() / ((2.0 * PI).powi(d as i32) * det).sqrt();
                let got = g.value(&x);
                assert!((got / want - 1.0).abs() < 1e-10, "d={d}: {got} vs {want}");
            }
            assert!(g.exact_err < 1e-8, "d={d}: outside {}", g.exact_err);
        }
        assert!(gauss_diagonal(16).exact_err < 1e-8);
    }
}
