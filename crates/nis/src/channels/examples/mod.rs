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
use crate::integrands::builtin::{Builtin, SuiteEntry};

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

/// The multi-channel examples (this module gives their channels): `integrands::by_name` knows
/// them and `nis integrate` runs them with any method, but the benchmark suite does not (their
/// point is the channels, and `gauss-pm`'s exact value is 0).
pub const MULTI_CHANNEL: &[SuiteEntry] = &[
    SuiteEntry {
        name: "gauss-pm",
        dims: &[2],
        description: "a positive and a negative Gaussian, exact 0 (MadNIS multi-channel toy)",
    },
    SuiteEntry {
        name: "dalitz",
        dims: &[2],
        description: "D → Kππ Dalitz plot, coherent K*(892) in s12 and ρ(770) in s23",
    },
    SuiteEntry {
        name: "resonances-4d",
        dims: &[4],
        description: "three narrow Cauchy peaks in x0+x1, x2·x3, x1−x3",
    },
    SuiteEntry {
        name: "phase-space-8d",
        dims: &[8],
        description: "massless 1→4 phase space, Z-like pairs in s12·s34 and s14·s23",
    },
    SuiteEntry {
        name: "resonances-100",
        dims: &[4],
        description: "100 narrow Cauchy peaks in sums of coordinate pairs (100 channels)",
    },
];

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
    let (mut integrand, channels) = match name {
        "gauss-pm" => (gauss_pm(), gauss_pm::channels()),
        "dalitz" => (dalitz(), dalitz::channels()),
        "resonances-4d" => (resonances(), resonances::channels()),
        "phase-space-8d" => (four_body(), four_body::channels()),
        "resonances-100" => (many_resonances(), many::channels()),
        _ => {
            return Err(Error::Config(format!(
                "unknown multi-channel example {name:?}; examples: {}",
                names().join(", ")
            )))
        }
    };
    integrand.name = name.to_string();
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
