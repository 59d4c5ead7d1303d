//! Channels of multi-channel integration: maps φ_k from the unit cube onto the integration domain
//! (here also [0, 1]^d), each with the density g_k of the points it produces.
//!
//! The idea is the classic one of event generators (Kleiss & Pittau 1994, "Weight optimization in
//! multichannel Monte Carlo", hep-ph/9405257): an integrand with several peaks that no single
//! mapping flattens is sampled from a mixture g(x) = Σ_k a_k g_k(x) of mappings, one per peak (a
//! Breit–Wigner resonance, a Gaussian, …). Each point x = φ_k(u), u uniform, carries the weight
//! f(x)/g(x); equivalently the integral splits into Σ_k ∫ α_k f with the channel weights
//! α_k(x) = a_k g_k(x)/g(x), and channel k only has to flatten its own share α_k f.
//!
//! This module is the data side: the [`Channel`] trait (batched, fallible, like
//! [`crate::integrate::Integrand`]), channels from closures ([`ChannelFn`]), a validated set with
//! a-priori weights ([`ChannelSet`]), the check an estimator runs on every sampled batch
//! ([`check_sampled`]), the Breit–Wigner mapping physicists build channels from
//! ([`BreitWigner`]), and built-in examples with exact values ([`examples`]).

mod breit_wigner;
mod check;
mod closure;
pub mod examples;
mod set;

pub use breit_wigner::BreitWigner;
pub use check::check_sampled;
pub use closure::ChannelFn;
pub use set::ChannelSet;

use crate::error::Result;

/// A channel: a map φ from the unit cube [0, 1]^d onto the integration domain [0, 1]^d, with the
/// density of the points it maps uniform points to.
///
/// `density` must be the true density of `sample`: for u uniform, x = φ(u) has the density
/// g(x) = 1/|det ∂φ/∂u| at u = φ⁻¹(x), and g(x) = 0 where φ does not reach x. It must accept any
/// x of the cube, not only those the channel sampled, since the channel weights
/// α_k(x) = a_k g_k(x)/Σ_j a_j g_j(x) need every channel's density at every channel's points.
///
/// ```
/// use nis::channels::{Channel, ChannelFn};
/// // x = u², so g(x) = 1/(2√x).
/// let c = ChannelFn::new(1, |u: &[f64], x: &mut [f64]| x[0] = u[0] * u[0],
///                        |x: &[f64]| 0.5 / x[0].sqrt());
/// let mut x = [0.0; 2];
/// c.sample(&[0.5, 1.0], &mut x).unwrap();
/// assert_eq!(x, [0.25, 1.0]);
/// let mut g = [0.0; 2];
/// c.density(&x, &mut g).unwrap();
/// assert_eq!(g, [1.0, 0.5]);
/// ```
pub trait Channel: Send + Sync {
    /// The dimension d of its cube and of the domain.
    fn dim(&self) -> usize;
    /// Maps a batch of uniform points `u` (n × d, row-major) to `x` = φ(u) (n × d). The
    /// integrators pass every coordinate of u in [2⁻⁵³, 1 − 2⁻⁵³] ([`ChannelSet::sample`]), so
    /// a map whose Jacobian vanishes on the cube's faces still gets a finite density; one that
    /// rounds onto an edge of its domain must keep its density finite and > 0 there.
    fn sample(&self, u: &[f64], x: &mut [f64]) -> Result<()>;
    /// Writes g(x) for each point of `x` (n × d, row-major) into `g` (n values).
    fn density(&self, x: &[f64], g: &mut [f64]) -> Result<()>;

    /// Whether the channel has an enhancement ([`Channel::enhancement`]); false by default.
    fn has_enhancement(&self) -> bool {
        false
    }

    /// Writes the channel's enhancement w(x) ≥ 0 for each point of `x` into `w`: a function
    /// large where the channel's own peak is (its diagram's |M_k|², its propagator). When a set
    /// has them the channel weights are α_k = a_k w̃_k/Σ_j a_j w̃_j, w̃_j = w_j where g_j > 0
    /// and 0 elsewhere (a channel gets no share where it cannot sample; those without an
    /// enhancement use their density): MadEvent's single-diagram enhancement (Maltoni &
    /// Stelzer 2003, hep-ph/0208156). Any weights that sum to one keep the integral; these
    /// leave each channel its own peak where the densities of broad channels would not.
    /// The default is the density.
    fn enhancement(&self, x: &[f64], w: &mut [f64]) -> Result<()> {
        self.density(x, w)
    }
}

#[cfg(test)]
mod tests;
