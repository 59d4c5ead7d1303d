//! Built-in multi-channel examples: integrands on the unit cube with exact values, each with the
//! channels a physicist would write for it (a Breit–Wigner mapping per resonance, flat in the
//! rest; MadNIS's sigmoid mappings for its ±Gaussian toy). docs/INTEGRANDS.md ("Multi-channel
//! examples") derives every exact value; the integrands are also ordinary built-ins
//! ([`crate::integrands::by_name`], listed in [`crate::integrands::MULTI_CHANNEL`]), so any
//! single-channel method integrates them too.

mod dalitz;
mod four_body;
mod gauss_pm;
mod many;
mod quadrature;
mod resonances;

pub(crate) use dalitz::integrand as dalitz;
pub(crate) use four_body::integrand as four_body;
pub(crate) use gauss_pm::integrand as gauss_pm;
pub(crate) use many::integrand as many_resonances;
pub(crate) use resonances::integrand as resonances;

use super::Channel;
use crate::error::{Error, Result};
use crate::integrands::{self, Builtin, MULTI_CHANNEL};

/// A multi-channel example: the integrand with its exact value, and its channels (equal priors
/// unless a channel set says otherwise).
pub struct Example {
    /// The integrand, as `nis::integrands::by_name` builds it.
    pub integrand: Builtin,
    /// Its exact integral over the unit cube.
    pub exact: f64,
    /// The uncertainty of `exact` (the quadrature's error bound; 0 if closed form).
    pub exact_err: f64,
    /// Where the integrand and its channels come from.
    pub source: &'static str,
    /// One channel per peak (resonance, Gaussian), in the order docs/INTEGRANDS.md lists them.
    pub channels: Vec<Box<dyn Channel>>,
}

impl std::fmt::Debug for Example {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:?} with {} channels",
            self.integrand,
            self.channels.len()
        )
    }
}

/// The names of the examples, as [`by_name`] and `nis integrate` know them.
pub fn names() -> Vec<&'static str> {
    MULTI_CHANNEL.iter().map(|e| e.name).collect()
}

/// Builds a multi-channel example by name (one of [`names`]).
///
/// ```
/// let ex = nis::channels::examples::by_name("resonances-4d").unwrap();
/// assert_eq!(ex.integrand.dim, 4);
/// assert_eq!(ex.channels.len(), 3);
/// ```
pub fn by_name(name: &str) -> Result<Example> {
    let channels = match name {
        "gauss-pm" => gauss_pm::channels(),
        "dalitz" => dalitz::channels(),
        "resonances-4d" => resonances::channels(),
        "phase-space-8d" => four_body::channels(),
        "resonances-100" => many::channels(),
        _ => {
            return Err(Error::Config(format!(
                "unknown multi-channel example {name:?}; examples: {}",
                names().join(", ")
            )))
        }
    };
    let integrand = integrands::by_name(name, None)?;
    Ok(Example {
        exact: integrand.exact,
        exact_err: integrand.exact_err,
        source: integrand.source,
        integrand,
        channels,
    })
}

#[cfg(test)]
mod tests;
