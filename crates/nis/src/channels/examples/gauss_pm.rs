//! MadNIS's multi-channel toy (documentation page "Multi-channel integration", repository
//! madgraph-ml/madnis): in d = 2, a positive Gaussian at (½ − δ, ½ − δ) and a negative one at
//! (½ + δ, ½ + δ), δ = 0.3, σ = 0.2, unnormalised:
//! f(x) = exp(−|x − ½ + δ|²/(2σ²)) − exp(−|x − ½ − δ|²/(2σ²)).
//! x → 1 − x maps the cube onto itself and f onto −f, so ∫f = 0 exactly.
//!
//! Its channels are MadNIS's mappings y_i = sigmoid(logit(u_i) ∓ ½) per coordinate (channel 0,
//! shift −½, leans to the positive peak; channel 1, +½, to the negative one). Written without
//! the logit: y = u·e^c/(1 + u(e^c − 1)), whose inverse u = y·b/(1 + y(b − 1)), b = e^(−c), has
//! the derivative g(y) = b/(1 + y(b − 1))².

use crate::channels::{Channel, ChannelFn};
use crate::integrands::builtin::Builtin;

/// δ: the peaks' offset from the centre along each axis.
const OFFSET: f64 = 0.3;
/// σ: the peaks' standard deviation.
const SIGMA: f64 = 0.2;
/// The logit shift of the channels' mappings.
const SHIFT: f64 = 0.5;

/// The integrand (d = 2, exact 0).
pub(crate) fn integrand() -> Builtin {
    Builtin::from_fn(
        2,
        0.0,
        0.0,
        "MadNIS documentation, multi-channel toy (δ = 0.3, σ = 0.2); exact 0 by x → 1 − x",
        |x| {
            let (mut a, mut b) = (0.0, 0.0);
            for v in x {
                a += (v - 0.5 + OFFSET).powi(2);
                b += (v - 0.5 - OFFSET).powi(2);
            }
            let s2 = 2.0 * SIGMA * SIGMA;
            (-a / s2).exp() - (-b / s2).exp()
        },
    )
}

/// The sigmoid(logit(u) + c) channel in every coordinate.
fn sigmoid_shift(c: f64) -> Box<dyn Channel> {
    let (e, b) = (c.exp(), (-c).exp());
    Box::new(ChannelFn::new(
        2,
        move |u: &[f64], x: &mut [f64]| {
            for (x, u) in x.iter_mut().zip(u) {
                *x = (u * e / (1.0 + u * (e - 1.0))).clamp(0.0, 1.0);
            }
        },
        move |x: &[f64]| {
            x.iter()
                .map(|y| {
                    if (0.0..=1.0).contains(y) {
                        b / (1.0 + y * (b - 1.0)).powi(2)
                    } else {
                        0.0
                    }
                })
                .product()
        },
    ))
}

/// Channel 0 towards the positive peak, channel 1 towards the negative one.
pub(crate) fn channels() -> Vec<Box<dyn Channel>> {
    vec![sigmoid_shift(-SHIFT), sigmoid_shift(SHIFT)]
}
