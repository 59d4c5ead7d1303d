//! Massless four-body phase space, 1 → 4 (an H → ZZ* → 4ℓ-like decay at rest, M = 1), with two
//! resonant pairings: |𝓜|² = |B(s₁₂)|²|B(s₃₄)|² + |B(s₁₄)|²|B(s₂₃)|², |B(s)|² =
//! (mΓ)²/((s − m²)² + (mΓ)²), m and Γ the Z's mass and width in units of M = 125 GeV. Each
//! pairing has one pair on shell and one off (2m > M): four resonant regions in all.
//!
//! The cube is mapped onto phase space by the sequential two-body decays of the (12)(34) tree:
//! s₁₂ = x₀, s₃₄ = x₁(1 − √s₁₂)², the direction of p₁ + p₂ in the rest frame of M from (x₂, x₃)
//! (cos θ = 2x₂ − 1, φ = 2πx₃), that of p₁ in the rest frame of p₁ + p₂ from (x₄, x₅) and that
//! of p₃ in the rest frame of p₃ + p₄ from (x₆, x₇) (rest frames reached by pure boosts). With
//! dΦ₄ = dΦ₂(M; q₁₂, q₃₄)·(ds₁₂/2π)(ds₃₄/2π)·dΦ₂(q₁₂; p₁, p₂)·dΦ₂(q₃₄; p₃, p₄),
//! dΦ₂(m; m_a, m_b) = λ^½(m², m_a², m_b²)/(8πm²)·dΩ/4π, and the massless volume
//! Φ₄ = (2π)⁻⁸(π/2)³M⁴/(Γ(4)Γ(3)), the normalised measure is
//! dΦ₄/Φ₄ = 12·λ^½(1, s₁₂, s₃₄)·(1 − √s₁₂)² dx =: J(x) dx, and the integrand is f = J·|𝓜|²: the
//! average of |𝓜|² over phase space. Phase space is symmetric under relabelling massless
//! momenta (2 ↔ 4 turns one pairing into the other), so the exact value is
//! 24·∫∫_{√s₁+√s₂≤1} λ^½(1, s₁, s₂)|B(s₁)|²|B(s₂)|² ds₁ds₂, by nested quadrature.
//!
//! One channel per resonance, four in all: a pair a of a tree, s_a Breit–Wigner on [0, 1],
//! then the other pair b, s_b Breit–Wigner on [0, (1 − √s_a)²], angles flat, the momenta built
//! in that tree and mapped to x by the inverse of the (12)(34) map. (One channel per tree,
//! with s₁₂ always drawn first, samples the region of an on-shell s₃₄ only through s₁₂'s tail,
//! and does worse than uniform sampling.) A tree's density with respect to dΦ₄/Φ₄ is
//! ψ = pdf(s_a)·pdf(s_b | s_a)/(12·λ^½(1, s_a, s_b)), so its density in x is J(x)·ψ at p(x).

use std::f64::consts::PI;

use super::quadrature::integrate;
use crate::channels::{BreitWigner, Channel, ChannelFn};
use crate::integrands::builtin::Builtin;

/// The Z's mass and width in units of M = 125 GeV (91.1876 and 2.4952 GeV).
pub(crate) const Z: (f64, f64) = (91.1876 / 125.0, 2.4952 / 125.0);
/// The tree of the integrand's map: labels of the first pair (its mass squared from x₀), then
/// of the second.
pub(crate) const X_TREE: [usize; 4] = [0, 1, 2, 3];
/// The channels' trees, the pair whose resonance each flattens first: (12), (34), (14), (32).
pub(crate) const TREES: [[usize; 4]; 4] = [[0, 1, 2, 3], [2, 3, 0, 1], [0, 3, 2, 1], [2, 1, 0, 3]];
/// The coordinates of x that are azimuths φ/2π (periodic; the tests' finite differences wrap).
#[cfg(test)]
pub(crate) const AZIMUTHS: [usize; 3] = [3, 5, 7];
/// The relative tolerance of each level of the nested quadrature.
const QUAD_TOL: f64 = 1e-12;

/// Four-momenta (E, px, py, pz) of the four massless particles.
pub(crate) type Momenta = [[f64; 4]; 4];

/// λ^½(1, a, b), the Källén function's root (0 outside the physical region).
pub(crate) fn sqrt_lambda(a: f64, b: f64) -> f64 {
    let l = (1.0 - a - b).powi(2) - 4.0 * a * b;
    l.max(0.0).sqrt()
}

/// |B(s)|² for the Z.
pub(crate) fn bw2(s: f64) -> f64 {
    let (m, w) = Z;
    let mw = m * w;
    mw * mw / ((s - m * m).powi(2) + mw * mw)
}

/// The unit vector of (cos θ, φ) = (2a − 1, 2πb).
fn direction(a: f64, b: f64) -> [f64; 3] {
    let c = (2.0 * a - 1.0).clamp(-1.0, 1.0);
    let s = (1.0 - c * c).max(0.0).sqrt();
    let (sp, cp) = (2.0 * PI * b).sin_cos();
    [s * cp, s * sp, c]
}

/// (a, b) of a unit vector: the inverse of [`direction`]. A zero vector (a massless pair with
/// collinear daughters, a pair at rest: no direction) gives (½, 0).
fn angles(n: [f64; 3]) -> (f64, f64) {
    let r = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if r.is_nan() || r <= 0.0 {
        return (0.5, 0.0);
    }
    let a = (0.5 * (1.0 + n[2] / r)).clamp(0.0, 1.0);
    let b = (n[1].atan2(n[0]) / (2.0 * PI)).rem_euclid(1.0);
    (a, b.min(1.0))
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The two massless daughters of a parent (E, P) of mass m, emitted along ±n in its rest frame,
/// boosted to the frame where it has momentum P: ½[(E + P·n), m·n + P(1 + P·n/(E + m))] and the
/// same with −n (no division by m, so m → 0 is safe).
fn decay(e: f64, p: [f64; 3], m: f64, n: [f64; 3]) -> [[f64; 4]; 2] {
    let mut out = [[0.0; 4]; 2];
    for (o, sign) in out.iter_mut().zip([1.0, -1.0]) {
        let pn = sign * dot(p, n);
        o[0] = 0.5 * (e + pn);
        for i in 0..3 {
            o[i + 1] = 0.5 * (m * sign * n[i] + p[i] * (1.0 + pn / (e + m)));
        }
    }
    out
}

/// The direction, in the parent's rest frame, of the massless daughter k = (e, v) of a parent
/// (E, P) of mass m: m·v − P(e − P·v/(E + m)), normalised by [`angles`].
fn rest_direction(e: f64, p: [f64; 3], m: f64, k: [f64; 4]) -> [f64; 3] {
    let v = [k[1], k[2], k[3]];
    let t = k[0] - dot(p, v) / (e + m);
    [
        m * v[0] - p[0] * t,
        m * v[1] - p[1] * t,
        m * v[2] - p[2] * t,
    ]
}

/// The momenta of tree `tree` at its coordinates z ∈ [0, 1]^8.
pub(crate) fn momenta(tree: [usize; 4], z: &[f64]) -> Momenta {
    let sa = z[0];
    let sb = z[1] * (1.0 - sa.sqrt()).powi(2);
    let p = 0.5 * sqrt_lambda(sa, sb);
    let n = direction(z[2], z[3]);
    let qa = [n[0] * p, n[1] * p, n[2] * p];
    let qb = [-qa[0], -qa[1], -qa[2]];
    let (ea, eb) = (0.5 * (1.0 + sa - sb), 0.5 * (1.0 - sa + sb));
    let [p1, p2] = decay(ea, qa, sa.sqrt(), direction(z[4], z[5]));
    let [p3, p4] = decay(eb, qb, sb.sqrt(), direction(z[6], z[7]));
    let mut out = [[0.0; 4]; 4];
    for (label, k) in tree.into_iter().zip([p1, p2, p3, p4]) {
        out[label] = k;
    }
    out
}

/// s_ij = 2 p_i·p_j of massless momenta.
pub(crate) fn invariant(p: &Momenta, i: usize, j: usize) -> f64 {
    let (a, b) = (p[i], p[j]);
    (2.0 * (a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3])).max(0.0)
}

/// The coordinates of tree `tree` at the momenta p: the inverse of [`momenta`].
pub(crate) fn coordinates(tree: [usize; 4], p: &Momenta) -> [f64; 8] {
    let [a1, a2, b1, b2] = tree.map(|l| p[l]);
    let sa = invariant(p, tree[0], tree[1]).min(1.0);
    let sb = invariant(p, tree[2], tree[3]);
    let ea = a1[0] + a2[0];
    let qa = [a1[1] + a2[1], a1[2] + a2[2], a1[3] + a2[3]];
    let eb = b1[0] + b2[0];
    let qb = [b1[1] + b2[1], b1[2] + b2[2], b1[3] + b2[3]];
    let room = (1.0 - sa.sqrt()).powi(2);
    let (x2, x3) = angles(qa);
    let (x4, x5) = angles(rest_direction(ea, qa, sa.sqrt(), a1));
    let (x6, x7) = angles(rest_direction(eb, qb, sb.sqrt(), b1));
    let x1 = if room > 0.0 {
        (sb / room).clamp(0.0, 1.0)
    } else {
        0.0
    };
    [sa, x1, x2, x3, x4, x5, x6, x7]
}

/// J(x) = 12·λ^½(1, s₁₂, s₃₄)·(1 − √s₁₂)²: the density of dΦ₄/Φ₄ in x.
pub(crate) fn jacobian(x: &[f64]) -> f64 {
    let room = (1.0 - x[0].sqrt()).powi(2);
    12.0 * sqrt_lambda(x[0], x[1] * room) * room
}

/// The exact value and its quadrature error bound: 24 ∫ds₁ ∫ds₂ λ^½|B(s₁)|²|B(s₂)|².
pub(crate) fn exact() -> (f64, f64) {
    let peak = Z.0 * Z.0;
    let mut inner_err = 0.0f64;
    let mut outer = |s1: f64| {
        let top = (1.0 - s1.sqrt()).powi(2);
        let f = |s2: f64| sqrt_lambda(s1, s2) * bw2(s2);
        let (v, e) = if peak < top {
            let (a, ea) = integrate(f, 0.0, peak, QUAD_TOL);
            let (b, eb) = integrate(f, peak, top, QUAD_TOL);
            (a + b, ea + eb)
        } else {
            integrate(f, 0.0, top, QUAD_TOL)
        };
        inner_err = inner_err.max(e / v.abs().max(1e-300));
        v * bw2(s1)
    };
    let (a, ea) = integrate(&mut outer, 0.0, peak, QUAD_TOL);
    let (b, eb) = integrate(&mut outer, peak, 1.0, QUAD_TOL);
    let v = 24.0 * (a + b);
    (v, 24.0 * (ea + eb) + v * inner_err)
}

/// The integrand (d = 8).
pub(crate) fn integrand() -> Builtin {
    let (exact, err) = exact();
    Builtin::from_fn(
        8,
        exact,
        err + exact * 1e-14,
        "this project; massless 1→4 phase space, Z-like resonances in s12·s34 and s14·s23; exact by nested quadrature",
        |x| {
            let p = momenta(X_TREE, x);
            let m2 = bw2(invariant(&p, 0, 1)) * bw2(invariant(&p, 2, 3))
                + bw2(invariant(&p, 0, 3)) * bw2(invariant(&p, 1, 2));
            jacobian(x) * m2
        },
    )
}

/// The Breit–Wigners of a tree: s_a on [0, 1], s_b on [0, (1 − √s_a)²].
fn bw_a() -> BreitWigner {
    BreitWigner::unchecked(Z.0 * Z.0, Z.0 * Z.1, 0.0, 1.0)
}
fn bw_b(sa: f64) -> BreitWigner {
    let top = (1.0 - sa.sqrt()).powi(2).max(f64::MIN_POSITIVE);
    BreitWigner::unchecked(Z.0 * Z.0, Z.0 * Z.1, 0.0, top)
}

/// How far below 1 a channel keeps s_a and s_b/(1 − √s_a)²: at 1 a pair is left without energy
/// or both pairs at rest, the phase-space Jacobian vanishes and the density is undefined (u on
/// the cube's faces rounds there); nearer than this, λ(1, s_a, s_b) loses its digits. The u it
/// moves have measure ~2·10⁻⁸ (pdf(s_a = 1)·10⁻⁶), where f has almost no phase space.
const EDGE: f64 = 1e-6;

/// The channel of one tree: s_a and s_b/(1 − √s_a)² at most 1 − [`EDGE`].
fn tree_channel(tree: [usize; 4]) -> Box<dyn Channel> {
    Box::new(ChannelFn::new(
        8,
        move |u: &[f64], x: &mut [f64]| {
            let mut z = [0.0; 8];
            z.copy_from_slice(u);
            let sa = bw_a().sample(u[0]).min(1.0 - EDGE);
            let top = (1.0 - sa.sqrt()).powi(2);
            z[0] = sa;
            z[1] = (bw_b(sa).sample(u[1]) / top).clamp(0.0, 1.0 - EDGE);
            x.copy_from_slice(&coordinates(X_TREE, &momenta(tree, &z)));
        },
        move |x: &[f64]| {
            let p = momenta(X_TREE, x);
            let (sa, sb) = (
                invariant(&p, tree[0], tree[1]),
                invariant(&p, tree[2], tree[3]),
            );
            let psi = bw_a().pdf(sa.min(1.0)) * bw_b(sa).pdf(sb) / (12.0 * sqrt_lambda(sa, sb));
            jacobian(x) * psi
        },
    ))
}

/// One channel per resonance: the Z on shell in s₁₂, s₃₄, s₁₄, s₂₃ (the other pair of its tree
/// then Breit–Wigner in the room left).
pub(crate) fn channels() -> Vec<Box<dyn Channel>> {
    TREES.into_iter().map(tree_channel).collect()
}
