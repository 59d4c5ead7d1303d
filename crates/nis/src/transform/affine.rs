//! Affine coupling transform of RealNVP (Dinh, Sohl-Dickstein, Bengio 2016, Eq. 7), moved to the
//! unit interval as the paper suggests for unbounded transforms (Müller et al. 2019, Sec. 2):
//! x ↦ logit(x) ↦ e^s·logit(x) + t ↦ sigmoid. The baseline the piecewise-polynomial transforms
//! are compared against.
//!
//! The scale and shift are soft-bounded, s = S·tanh(ŝ/S) and t = T·tanh(t̂/T): an unbounded e^s
//! pushes y so close to 0 or 1 that f32 can no longer tell points apart, and the density at the
//! ends of the interval behaves like x^(e^s − 1), which must stay integrable and finite in f32.

use super::Transform;

/// Bound on the log-scale s.
pub const MAX_LOG_SCALE: f64 = 2.0;
/// Bound on the shift t.
pub const MAX_SHIFT: f64 = 5.0;
/// The log-density is evaluated at x clamped to [ε, 1 − ε]: at exactly 0 or 1 it is ±∞ whenever
/// s ≠ 0, and a latent sample of exactly 0 (f32 uniforms produce it) must not give q = 0 or ∞.
/// The map itself is exact at the ends: 0 ↦ 0 and 1 ↦ 1.
pub const EDGE: f64 = 1e-7;

/// Affine transform in logit space; 2 parameters (ŝ, t̂) per dimension.
#[derive(Clone, Copy, Debug)]
pub struct Affine;

fn sigmoid(v: f64) -> f64 {
    if v >= 0.0 {
        1.0 / (1.0 + (-v).exp())
    } else {
        let e = v.exp();
        e / (1.0 + e)
    }
}

/// ln σ(v) + ln σ(−v) = ln σ'(v), computed without overflow.
fn log_sigmoid_derivative(v: f64) -> f64 {
    -v.abs() - 2.0 * (-v.abs()).exp().ln_1p()
}

fn scale_shift(p: &[f32]) -> (f64, f64) {
    let s = MAX_LOG_SCALE * (p[0] as f64 / MAX_LOG_SCALE).tanh();
    let t = MAX_SHIFT * (p[1] as f64 / MAX_SHIFT).tanh();
    (s, t)
}

/// log C'(x) = s + ln σ'(v) − ln x(1 − x), at x clamped to [ε, 1 − ε].
fn log_det(s: f64, t: f64, x: f64) -> f64 {
    let (_, u, lxx) = logit_parts(x);
    s + log_sigmoid_derivative(u * s.exp() + t) - lxx
}

/// Clamped x, ln(x/(1−x)) and ln(x(1−x)).
fn logit_parts(x: f64) -> (f64, f64, f64) {
    let x = x.clamp(EDGE, 1.0 - EDGE);
    let (lx, l1x) = (x.ln(), (-x).ln_1p());
    (x, lx - l1x, lx + l1x)
}

impl Transform for Affine {
    fn param_count(&self) -> usize {
        2
    }

    #[inline]
    fn forward(&self, p: &[f32], x: f64) -> (f64, f64) {
        let (s, t) = scale_shift(p);
        // ln 0 = −∞ and sigmoid(−∞) = 0: the ends map exactly.
        let u = x.ln() - (-x).ln_1p();
        let y = sigmoid(u * s.exp() + t).clamp(0.0, 1.0);
        (y, log_det(s, t, x))
    }

    #[inline]
    fn inverse(&self, p: &[f32], y: f64) -> (f64, f64) {
        let (s, t) = scale_shift(p);
        let v = y.ln() - (-y).ln_1p();
        let x = sigmoid((v - t) * (-s).exp()).clamp(0.0, 1.0);
        (x, log_det(s, t, x))
    }

    fn bin_edges(&self, _p: &[f32]) -> Vec<f64> {
        vec![0.0, 1.0]
    }

    fn backward(&self, p: &[f32], x: f64, g_y: f64, g_log_det: f64, g_p: &mut [f32]) -> f64 {
        let (s, t) = scale_shift(p);
        let (xc, u, _) = logit_parts(x);
        let es = s.exp();
        let v = u * es + t;
        let y = sigmoid(v);
        // Inside [ε, 1 − ε] this is the gradient of the map; outside, y's dependence on the
        // parameters is O(ε^{e^s}) and is dropped with the clamp.
        // y = σ(v); log_det = s + ln σ'(v) − ln x − ln(1 − x); d ln σ'(v)/dv = 1 − 2σ(v).
        let g_v = g_y * y * (1.0 - y) + g_log_det * (1.0 - 2.0 * y);
        let g_u = g_v * es;
        let g_s = g_v * u * es + g_log_det;
        let g_t = g_v;
        let inside = x > EDGE && x < 1.0 - EDGE;
        let g_x = if inside {
            (g_u + g_log_det * (2.0 * xc - 1.0)) / (xc * (1.0 - xc))
        } else {
            0.0
        };
        let ts = (p[0] as f64 / MAX_LOG_SCALE).tanh();
        let tt = (p[1] as f64 / MAX_SHIFT).tanh();
        g_p[0] = (g_s * (1.0 - ts * ts)) as f32;
        g_p[1] = (g_t * (1.0 - tt * tt)) as f32;
        g_x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::testing;

    #[test]
    fn affine_round_trips_and_gradients() {
        testing::check_transform(&Affine, false);
    }

    #[test]
    fn affine_batched_equals_per_scalar() {
        testing::check_batch(&Affine);
    }
}
