//! A Dalitz plot: the three-body decay D⁺ → K⁻π⁺π⁺-like (masses of the D⁺, K and π, PDG 2024),
//! labelled M → 1 2 3 with 1 = K, 2 and 3 = π, and the coherent sum of two Breit–Wigner
//! amplitudes, the K*(892) in s₁₂ = m²(Kπ) and the ρ(770) in s₂₃ = m²(ππ):
//!
//! A = B₁(s₁₂) + c·B₂(s₂₃), B_R(s) = m_RΓ_R/(m_R² − s − i·m_RΓ_R), c = 0.6 + 0.4i,
//!
//! integrated with the flat Dalitz measure ds₁₂ ds₂₃ (three-body phase space is flat there; its
//! constant of dΓ = |𝓜|²/(32(2π)³M³)·ds₁₂ds₂₃, PDG Eq. 49.22, is left out). The unit square is mapped onto the Dalitz region the
//! standard way: s₁₂ = s₁₂⁻ + x₀(s₁₂⁺ − s₁₂⁻), then s₂₃ = s₂₃⁻(s₁₂) + x₁(s₂₃⁺ − s₂₃⁻) between the
//! limits at that s₁₂ (PDG Review "Kinematics", Eq. 49.23), so f(x) = |A|²·Δ₁₂·Δ₂₃(s₁₂).
//!
//! Channel 0 draws s₁₂ from the K* Breit–Wigner over its whole range and x₁ flat; channel 1
//! draws s₂₃ from the ρ Breit–Wigner over its whole range and s₁₂ flat between the limits at
//! that s₂₃: each is flat in the Dalitz plot but for its resonance. The exact value integrates
//! s₂₃ in closed form (|B|² to an arctangent, B to a complex logarithm) and s₁₂ by quadrature.

use super::quadrature::integrate;
use crate::channels::{BreitWigner, Channel, ChannelFn};
use crate::integrands::builtin::Builtin;

/// Masses (GeV): the D⁺, then particles 1 (K), 2 and 3 (π).
const MASSES: [f64; 4] = [1.869_66, 0.493_677, 0.139_570_39, 0.139_570_39];
/// The K*(892)⁰: mass and width (GeV), in s₁₂.
pub(crate) const KSTAR: (f64, f64) = (0.895_55, 0.047_3);
/// The ρ(770): mass and width (GeV), in s₂₃.
pub(crate) const RHO: (f64, f64) = (0.775_26, 0.149_1);
/// The ρ's coupling relative to the K*'s (magnitude and phase make an interference term).
pub(crate) const COUPLING: (f64, f64) = (0.6, 0.4);
/// The relative tolerance of the s₁₂ quadrature.
const QUAD_TOL: f64 = 1e-13;

/// The limits of s_bc at a given s_ab, for M → a b c: in the (ab) rest frame
/// E_b = (s_ab − m_a² + m_b²)/(2√s_ab), E_c = (M² − s_ab − m_c²)/(2√s_ab), and
/// s_bc^∓ = (E_b + E_c)² − (p_b ± p_c)².
pub(crate) fn limits(m: f64, ma: f64, mb: f64, mc: f64, s_ab: f64) -> (f64, f64) {
    let m_ab = s_ab.sqrt();
    let eb = (s_ab - ma * ma + mb * mb) / (2.0 * m_ab);
    let ec = (m * m - s_ab - mc * mc) / (2.0 * m_ab);
    let pb = (eb * eb - mb * mb).max(0.0).sqrt();
    let pc = (ec * ec - mc * mc).max(0.0).sqrt();
    let e2 = (eb + ec) * (eb + ec);
    (e2 - (pb + pc) * (pb + pc), e2 - (pb - pc) * (pb - pc))
}

/// The full ranges of s₁₂ and s₂₃.
pub(crate) fn ranges() -> ((f64, f64), (f64, f64)) {
    let [m, m1, m2, m3] = MASSES;
    (
        ((m1 + m2).powi(2), (m - m3).powi(2)),
        ((m2 + m3).powi(2), (m - m1).powi(2)),
    )
}

/// The limits of s₂₃ at s₁₂, and of s₁₂ at s₂₃.
pub(crate) fn s23_limits(s12: f64) -> (f64, f64) {
    let [m, m1, m2, m3] = MASSES;
    limits(m, m1, m2, m3, s12)
}
fn s12_limits(s23: f64) -> (f64, f64) {
    let [m, m1, m2, m3] = MASSES;
    limits(m, m3, m2, m1, s23)
}

/// B(s) = mΓ/(m² − s − i·mΓ) as (re, im).
fn breit_wigner(s: f64, (m, w): (f64, f64)) -> (f64, f64) {
    let (a, b) = (m * m - s, m * w);
    let d = a * a + b * b;
    (m * w * a / d, m * w * b / d)
}

/// |A|² at (s₁₂, s₂₃).
pub(crate) fn amplitude_squared(s12: f64, s23: f64) -> f64 {
    let (b1, b2) = (breit_wigner(s12, KSTAR), breit_wigner(s23, RHO));
    let (c0, c1) = COUPLING;
    let re = b1.0 + c0 * b2.0 - c1 * b2.1;
    let im = b1.1 + c0 * b2.1 + c1 * b2.0;
    re * re + im * im
}

/// The point (s₁₂, s₂₃) of x and the Jacobian Δ₁₂·Δ₂₃(s₁₂) of the map.
pub(crate) fn to_dalitz(x: &[f64]) -> (f64, f64, f64) {
    let ((lo, hi), _) = ranges();
    let s12 = lo + x[0] * (hi - lo);
    let (a, b) = s23_limits(s12);
    (s12, a + x[1] * (b - a), (hi - lo) * (b - a))
}

/// ∫ |A|² ds₂₃ over the limits at s₁₂, in closed form: with z(s) = m₂² − s + i·m₂Γ₂,
/// ∫|B₂|² = m₂Γ₂·[atan((s − m₂²)/(m₂Γ₂))] and ∫ conj(B₂) = m₂Γ₂·(ln z(a) − ln z(b)).
pub(crate) fn inner(s12: f64) -> f64 {
    let (a, b) = s23_limits(s12);
    let (m, w) = RHO;
    let (mm, mw) = (m * m, m * w);
    let b1 = breit_wigner(s12, KSTAR);
    let direct = (b1.0 * b1.0 + b1.1 * b1.1) * (b - a);
    let (c0, c1) = COUPLING;
    let rho = (c0 * c0 + c1 * c1) * mw * (((b - mm) / mw).atan() - ((a - mm) / mw).atan());
    // ln z = ln|z| + i·arg z; Im z = mΓ > 0, so arg z ∈ (0, π) and no branch cut is crossed.
    let ln = |s: f64| (0.5 * ((mm - s).powi(2) + mw * mw).ln(), mw.atan2(mm - s));
    let (la, lb) = (ln(a), ln(b));
    let l = (mw * (la.0 - lb.0), mw * (la.1 - lb.1));
    // 2 Re[B₁ · conj(c) · L].
    let bc = (b1.0 * c0 + b1.1 * c1, b1.1 * c0 - b1.0 * c1);
    let cross = 2.0 * (bc.0 * l.0 - bc.1 * l.1);
    direct + rho + cross
}

/// The exact value and its quadrature error bound.
pub(crate) fn exact() -> (f64, f64) {
    let ((lo, hi), _) = ranges();
    let peak = KSTAR.0 * KSTAR.0;
    let (a, ea) = integrate(inner, lo, peak, QUAD_TOL);
    let (b, eb) = integrate(inner, peak, hi, QUAD_TOL);
    (a + b, ea + eb)
}

/// The integrand (d = 2).
pub(crate) fn integrand() -> Builtin {
    let (exact, err) = exact();
    Builtin::from_fn(
        2,
        exact,
        err + exact * 1e-14,
        "this project; D+ → Kππ Dalitz plot, K*(892) + ρ(770) coherent; exact by s23 in closed form, s12 quadrature",
        |x| {
            let (s12, s23, jac) = to_dalitz(x);
            amplitude_squared(s12, s23) * jac
        },
    )
}

/// The K* channel: s₁₂ Breit–Wigner over its range, x₁ flat.
fn kstar_channel() -> Box<dyn Channel> {
    let ((lo, hi), _) = ranges();
    let bw = BreitWigner::unchecked(KSTAR.0 * KSTAR.0, KSTAR.0 * KSTAR.1, lo, hi);
    Box::new(ChannelFn::new(
        2,
        move |u: &[f64], x: &mut [f64]| {
            x[0] = ((bw.sample(u[0]) - lo) / (hi - lo)).clamp(0.0, 1.0);
            x[1] = u[1];
        },
        move |x: &[f64]| (hi - lo) * bw.pdf((lo + x[0] * (hi - lo)).clamp(lo, hi)),
    ))
}

/// How close, as a fraction of its range, the ρ channel's s₂₃ comes to the ends of its range,
/// where the Dalitz region's width Δ₁₂ vanishes: the u it moves have measure ~10⁻¹².
const EDGE: f64 = 1e-12;

/// The ρ channel: s₂₃ Breit–Wigner over its range, s₁₂ flat between its limits at that s₂₃.
/// Its density in x is the Dalitz-plot density pdf(s₂₃)/Δ₁₂(s₂₃) times the map's Jacobian. s₂₃
/// stays [`EDGE`] of its range inside its ends, where Δ₁₂ vanishes and the density is
/// infinite (u on the cube's faces rounds there).
fn rho_channel() -> Box<dyn Channel> {
    let ((lo12, hi12), (lo, hi)) = ranges();
    let bw = BreitWigner::unchecked(RHO.0 * RHO.0, RHO.0 * RHO.1, lo, hi);
    Box::new(ChannelFn::new(
        2,
        move |u: &[f64], x: &mut [f64]| {
            let edge = EDGE * (hi - lo);
            let s23 = bw.sample(u[1]).clamp(lo + edge, hi - edge);
            let (a, b) = s12_limits(s23);
            let s12 = a + u[0] * (b - a);
            let (c, d) = s23_limits(s12);
            x[0] = ((s12 - lo12) / (hi12 - lo12)).clamp(0.0, 1.0);
            x[1] = ((s23 - c) / (d - c)).clamp(0.0, 1.0);
        },
        move |x: &[f64]| {
            let (_, s23, jac) = to_dalitz(x);
            let (a, b) = s12_limits(s23.clamp(lo, hi));
            jac * bw.pdf(s23.clamp(lo, hi)) / (b - a)
        },
    ))
}

/// Channel 0 for the K*, channel 1 for the ρ.
pub(crate) fn channels() -> Vec<Box<dyn Channel>> {
    vec![kstar_channel(), rho_channel()]
}
