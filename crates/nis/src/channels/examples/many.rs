//! A hundred narrow resonances in d = 4, for what real processes have: tens to hundreds of
//! channels. Peak k is a Cauchy (non-relativistic Breit–Wigner) peak L_k in t_k = x_a + x_b, the
//! pair (a, b) cycling over the six pairs of coordinates, with centre c_k and half-width γ_k
//! spread by low-discrepancy sequences over [0.15, 1.85] and [0.0005, 0.003]; f = (1/K) Σ_k L_k(t_k).
//!
//! Under uniform x, each t_k has the triangular density min(t, 2 − t) on [0, 2], so the exact
//! value is (1/K) Σ_k ∫ρ L_k, each term in closed form (`resonances::sum_term`). Channel k is the
//! Breit–Wigner mapping of its peak (`resonances::sum_channel`), flat in the other coordinates.

use super::resonances::{cauchy, sum_channel, sum_term};
use crate::channels::Channel;
use crate::integrands::builtin::Builtin;

/// The number of peaks and channels.
pub(crate) const PEAKS: usize = 100;

/// The six pairs of coordinates of d = 4 that the peaks cycle over.
const PAIRS: [(usize, usize); 6] = [(0, 1), (2, 3), (0, 2), (1, 3), (0, 3), (1, 2)];

/// Peak k: its pair and (centre, half-width).
pub(crate) fn peak(k: usize) -> ((usize, usize), (f64, f64)) {
    let frac = |v: f64| v - v.floor();
    let golden = (5f64.sqrt() - 1.0) / 2.0;
    let c = 0.15 + 1.7 * frac((k + 1) as f64 * golden);
    let g = 0.0005 + 0.0025 * frac((k + 1) as f64 * std::f64::consts::SQRT_2);
    (PAIRS[k % PAIRS.len()], (c, g))
}

/// The integrand (d = 4).
pub(crate) fn integrand() -> Builtin {
    let exact = (0..PEAKS).map(|k| sum_term(peak(k).1)).sum::<f64>() / PEAKS as f64;
    Builtin::from_fn(
        4,
        exact,
        1e-15,
        "this project; 100 Cauchy peaks in sums of coordinate pairs; exact (1/K) Σ_k ∫ρ L_k (closed form)",
        |x| {
            (0..PEAKS)
                .map(|k| {
                    let ((a, b), p) = peak(k);
                    cauchy(x[a] + x[b], p)
                })
                .sum::<f64>()
                / PEAKS as f64
        },
    )
}

/// One channel per peak, in the order of [`peak`].
pub(crate) fn channels() -> Vec<Box<dyn Channel>> {
    (0..PEAKS)
        .map(|k| {
            let ((a, b), p) = peak(k);
            sum_channel(a, b, p)
        })
        .collect()
}
