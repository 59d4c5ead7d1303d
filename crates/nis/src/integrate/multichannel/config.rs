//! The settings of a multi-channel integral ([`MultiChannelConfig`]), whether it splits the
//! integrand by sign ([`Signs`]), and which part of the integrand a part integrates ([`Sign`]).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Fewest evaluations a part adapts or estimates with.
pub(super) const MIN_PART_EVALS: u64 = 2000;

/// Which part of the integrand a part integrates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Sign {
    /// f itself (it does not change sign, or the split is off).
    Both,
    /// f⁺ = max(f, 0).
    Plus,
    /// f⁻ = max(−f, 0), entering the integral with a minus sign.
    Minus,
}

impl Sign {
    /// +1 for [`Sign::Minus`]'s −1: how the part enters F.
    pub fn factor(self) -> f64 {
        if self == Sign::Minus {
            -1.0
        } else {
            1.0
        }
    }
}

/// Whether the integrand is split by sign.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Signs {
    /// Split when the pilot sees both signs.
    #[default]
    Auto,
    /// Always split into f⁺ and f⁻.
    Split,
    /// Never split (a sampler per channel learns |h_k|).
    Whole,
}

/// Settings of [`MultiChannel`](super::MultiChannel) (the method's own settings are
/// [`Settings`](crate::integrate::Settings)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MultiChannelConfig {
    /// Splitting by sign.
    pub signs: Signs,
    /// Share of a call's evaluations the parts adapt on (the rest makes the estimate); the
    /// default is the measured best of every method on every example
    /// (docs/results/integration.md, "Channels and signed integrands").
    pub adapt_fraction: f64,
    /// Whether the a-priori weights adapt (Kleiss–Pittau) between adapting and estimating.
    pub adapt_weights: bool,
    /// Smallest a-priori weight a channel keeps, as a fraction of 1/K (channel dropping leaves
    /// it this much).
    pub weight_floor: f64,
    /// Uniform points per channel of the pilot that decides the sign split.
    pub pilot: usize,
    /// Evaluations every part adapts on in a run to a precision target (at most
    /// `adapt_fraction` of its `max_evals`, shared).
    pub target_adapt: u64,
    /// NIS: one flow for all parts, conditioned on the part (`shared.rs`), instead of a flow per
    /// part; ignored by the other methods. On by default: with the parts' χ² loss it gains
    /// most where the channels overlap, loses little elsewhere, and takes less memory
    /// (docs/results/integration.md, "One flow shared by the channels"). A saved one loads as a
    /// flow per part.
    pub shared_flow: bool,
    /// NIS: after the parts adapt, fit a network N that refines the channel weights to
    /// α_k ∝ a_k g_k e^{N_k(x)} (MadNIS's), on fresh points of every part's sampler (counted),
    /// and keep it only when it lowers the estimate's variance on held-out points
    /// (`weight_net.rs`); ignored by the other methods. On by default: it lowers the variance
    /// per evaluation on every multi-channel example; at equal time it loses only where a point
    /// costs less than the network's pass (docs/results/integration.md, "Learned channel
    /// weights").
    pub weight_network: bool,
}

impl Default for MultiChannelConfig {
    fn default() -> Self {
        MultiChannelConfig {
            signs: Signs::Auto,
            adapt_fraction: 0.25,
            adapt_weights: true,
            weight_floor: 0.01,
            pilot: 1000,
            target_adapt: 100_000,
            shared_flow: true,
            weight_network: true,
        }
    }
}

impl MultiChannelConfig {
    pub(super) fn validate(&self) -> Result<()> {
        let ok = self.adapt_fraction > 0.0
            && self.adapt_fraction < 1.0
            && self.weight_floor > 0.0
            && self.weight_floor <= 1.0
            && self.pilot >= 2
            && self.target_adapt >= MIN_PART_EVALS;
        if ok {
            return Ok(());
        }
        Err(Error::Config(format!(
            "multi-channel settings: adapt_fraction must be in (0, 1), weight_floor in (0, 1], \
             pilot at least 2 and target_adapt at least {MIN_PART_EVALS}: {self:?}"
        )))
    }
}
