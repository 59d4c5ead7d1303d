//! Three narrow resonances along coordinates that are not axes, in d = 4: Cauchy (non-relativistic
//! Breit–Wigner) peaks L_k(t) = (γ_k/π)/((t − c_k)² + γ_k²) in t₀ = x₀ + x₁, t₁ = x₂·x₃ and
//! t₂ = x₁ − x₃, f = L₀(t₀) + L₁(t₁) + L₂(t₂). No product of 1-D densities follows them.
//!
//! Under uniform x the coordinate t_k has the density ρ_k: the triangle min(t, 2 − t) on [0, 2]
//! for x₀ + x₁, −ln t on (0, 1] for x₂x₃, the triangle 1 − |t| on [−1, 1] for x₁ − x₃; so the
//! exact value is Σ_k ∫ ρ_k L_k dt: closed form for the triangles, 1-D quadrature for −ln t.
//!
//! Channel k keeps every coordinate flat but one, and draws that one so that t_k is
//! Breit–Wigner-distributed between the limits the other coordinate of t_k allows (x₁ given
//! x₀; x₃ given x₂; x₃ given x₁), the mapping of event generators applied to a non-axis
//! coordinate. Its density at any x is the truncated Breit–Wigner's at t_k(x) times the
//! derivative dt_k/dx_j (1, x₂, 1).

use std::f64::consts::PI;

use super::quadrature::integrate;
use crate::channels::{BreitWigner, Channel, ChannelFn};
use crate::integrands::builtin::Builtin;

/// (centre c, half-width γ) of the peaks in x₀ + x₁, x₂·x₃, x₁ − x₃.
pub(crate) const PEAKS: [(f64, f64); 3] = [(0.7, 0.01), (0.3, 0.003), (0.2, 0.001)];

/// The relative tolerance of the −ln t quadrature.
const QUAD_TOL: f64 = 1e-13;

/// The Cauchy density (γ/π)/((t − c)² + γ²).
pub(crate) fn cauchy(t: f64, (c, g): (f64, f64)) -> f64 {
    g / (PI * ((t - c) * (t - c) + g * g))
}

/// The three coordinates t₀, t₁, t₂ of a point.
pub(crate) fn coords(x: &[f64]) -> [f64; 3] {
    [x[0] + x[1], x[2] * x[3], x[1] - x[3]]
}

/// ∫_a^b t·L(t) dt and ∫_a^b L(t) dt for the Cauchy density L of (c, γ), in closed form:
/// the antiderivatives (γ/2π)·ln((t − c)² + γ²) + (c/π)·atan((t − c)/γ) and atan((t − c)/γ)/π.
pub(crate) fn moments(a: f64, b: f64, (c, g): (f64, f64)) -> (f64, f64) {
    let at = |t: f64| ((t - c) / g).atan() / PI;
    let lg = |t: f64| g / (2.0 * PI) * ((t - c) * (t - c) + g * g).ln();
    (lg(b) - lg(a) + c * (at(b) - at(a)), at(b) - at(a))
}

/// ∫ ρ L over t = x_a + x_b (the triangle min(t, 2 − t) on [0, 2]) for the Cauchy peak `peak`:
/// ∫₀¹ t L + ∫₁² (2 − t) L, in closed form.
pub(crate) fn sum_term(peak: (f64, f64)) -> f64 {
    let (t01, _) = moments(0.0, 1.0, peak);
    let (t12, n12) = moments(1.0, 2.0, peak);
    t01 + 2.0 * n12 - t12
}

/// ∫ ρ_k L_k for each peak, and the error bound of the one quadrature.
pub(crate) fn exact_terms() -> ([f64; 3], f64) {
    let sum = sum_term(PEAKS[0]);
    // x₂·x₃: ∫₀¹ −ln t · L(t) dt, split at the peak (the log endpoint at 0 is integrable).
    let c = PEAKS[1].0;
    let f = |t: f64| -t.ln() * cauchy(t, PEAKS[1]);
    let (p1, e1) = integrate(f, 0.0, c, QUAD_TOL);
    let (p2, e2) = integrate(f, c, 1.0, QUAD_TOL);
    // x₁ − x₃: ∫₋₁⁰ (1 + t) L + ∫₀¹ (1 − t) L.
    let (tm, nm) = moments(-1.0, 0.0, PEAKS[2]);
    let (tp, np) = moments(0.0, 1.0, PEAKS[2]);
    let diff = nm + tm + np - tp;
    ([sum, p1 + p2, diff], e1 + e2)
}

/// The integrand (d = 4).
pub(crate) fn integrand() -> Builtin {
    let (terms, err) = exact_terms();
    Builtin::from_fn(
        4,
        terms.iter().sum(),
        err + 1e-15,
        "this project; Cauchy peaks in x0+x1, x2·x3, x1−x3; exact Σ_k ∫ρ_k L_k (closed form, 1-D quadrature)",
        |x| {
            let t = coords(x);
            (0..3).map(|k| cauchy(t[k], PEAKS[k])).sum()
        },
    )
}

/// The peak `(c, γ)` in x_a + x_b: x_b = t − x_a, t Breit–Wigner on [x_a, x_a + 1], the rest
/// flat.
pub(crate) fn sum_channel(a: usize, b: usize, (c, g): (f64, f64)) -> Box<dyn Channel> {
    let bw = move |xa: f64| BreitWigner::unchecked(c, g, xa, xa + 1.0);
    enhanced(
        (c, g),
        move |x: &[f64]| x[a] + x[b],
        ChannelFn::new(
            4,
            move |u: &[f64], x: &mut [f64]| {
                x.copy_from_slice(u);
                x[b] = (bw(u[a]).sample(u[b]) - u[a]).clamp(0.0, 1.0);
            },
            move |x: &[f64]| bw(x[a]).pdf(x[a] + x[b]),
        ),
    )
}

/// The channel with its peak's propagator L(t(x)) as its enhancement.
fn enhanced<S, D>(
    peak: (f64, f64),
    t: impl Fn(&[f64]) -> f64 + Send + Sync + 'static,
    channel: ChannelFn<S, D>,
) -> Box<dyn Channel>
where
    S: Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
    D: Fn(&[f64]) -> f64 + Send + Sync + 'static,
{
    Box::new(channel.with_enhancement(move |x: &[f64]| cauchy(t(x), peak)))
}

/// Below this x₂ the product channel takes its limit x₂ → 0 (x₃ flat, g = 1): the truncated
/// Breit–Wigner on [0, x₂] is flat to ~x₂/c there, and its normalisation would underflow.
const TINY: f64 = 1e-200;

/// The peak in x₂·x₃: x₃ = t/x₂, t Breit–Wigner on [0, x₂] (x₃ = u₃ in the limit x₂ → 0).
fn product_channel() -> Box<dyn Channel> {
    let (c, g) = PEAKS[1];
    let bw = move |x2: f64| BreitWigner::unchecked(c, g, 0.0, x2);
    enhanced(
        PEAKS[1],
        |x: &[f64]| x[2] * x[3],
        ChannelFn::new(
            4,
            move |u: &[f64], x: &mut [f64]| {
                x.copy_from_slice(u);
                if u[2] > TINY {
                    x[3] = (bw(u[2]).sample(u[3]) / u[2]).clamp(0.0, 1.0);
                }
            },
            move |x: &[f64]| {
                if x[2] > TINY {
                    x[2] * bw(x[2]).pdf(x[2] * x[3])
                } else {
                    1.0
                }
            },
        ),
    )
}

/// The peak in x₁ − x₃: x₃ = x₁ − t, t Breit–Wigner on [x₁ − 1, x₁].
fn difference_channel() -> Box<dyn Channel> {
    let (c, g) = PEAKS[2];
    let bw = move |x1: f64| BreitWigner::unchecked(c, g, x1 - 1.0, x1);
    enhanced(
        PEAKS[2],
        |x: &[f64]| x[1] - x[3],
        ChannelFn::new(
            4,
            move |u: &[f64], x: &mut [f64]| {
                x.copy_from_slice(u);
                x[3] = (u[1] - bw(u[1]).sample(u[3])).clamp(0.0, 1.0);
            },
            move |x: &[f64]| bw(x[1]).pdf(x[1] - x[3]),
        ),
    )
}

/// One channel per peak, in the order of [`PEAKS`].
pub(crate) fn channels() -> Vec<Box<dyn Channel>> {
    vec![
        sum_channel(0, 1, PEAKS[0]),
        product_channel(),
        difference_channel(),
    ]
}
