//! Integrating to a requested precision: a [`Target`] error (Cuba's `epsrel`/`epsabs`, met when
//! the error bar is below max(abs_err, rel_err·|I|)) under limits on evaluations and wall time,
//! for every method ([`super::Integrator::integrate_to`]).
//!
//! A stopping rule that watches the running error is a sequential test: stopping as soon as the
//! error looks small favours runs whose mean and variance were both low by chance. Here the
//! estimate is Σ a_i·I_i over the iterations of a frozen (or, for VEGAS+, still adapting) sampler
//! with every share a_i fixed *before* iteration i draws its points, from the iterations before it
//! ([`Pursuit`]): the error is then a sum of martingale differences whatever the stopping rule,
//! and the estimate is unbiased, as for the reused training batches (docs/ESTIMATE.md, "Precision
//! targets"). The plan aims at 0.95 of the target so that a round usually meets it; a round that
//! does not (its variance was underestimated, or a heavy-tailed weight spent its whole variance)
//! is extended, diluted by new evaluations as a pooled mean would be: the one step whose share
//! depends on the round's own error (its bias on heavy-tailed weights is measured in
//! docs/ESTIMATE.md, "Precision targets").

mod drive;
mod pursuit;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

pub(crate) use drive::{drive, Ended, Stepper};
pub(crate) use pursuit::{Prior, Pursuit, Step};

/// Evaluations a target may spend when no `max_evals` is given.
pub const DEFAULT_MAX_EVALS: u64 = 100_000_000;

/// The plan aims at this fraction of the target error, so that a round usually meets it.
pub(crate) const AIM: f64 = 0.95;

/// The estimate's iterations a method whose iterations grow plans for (VEGAS+, channels): each
/// grows towards this fraction of the predicted need ([`Pursuit::iteration_goal`]).
pub(crate) const RESULT_ITERATIONS: f64 = 10.0;

/// A precision to integrate to, and the limits of the attempt.
///
/// ```
/// use nis::integrate::{uniform::{PlainMc, PlainMcConfig}, Integrator, Target};
/// let mut integ = PlainMc::new(2, PlainMcConfig::default())?;
/// let r = integ.integrate_to(&|x: &[f64]| x[0] * x[1], &Target::rel(1e-2))?;
/// assert!(r.std_err <= 1e-2 * r.value.abs());
/// # Ok::<(), nis::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Target {
    /// Relative error to reach: std_err ≤ rel_err·|value|.
    pub rel_err: Option<f64>,
    /// Absolute error to reach: std_err ≤ abs_err (either one met is enough, as in Cuba).
    pub abs_err: Option<f64>,
    /// The most evaluations to spend, training included.
    pub max_evals: u64,
    /// The most wall-clock seconds to spend (training included); `None`: no limit.
    pub max_seconds: Option<f64>,
}

impl Default for Target {
    fn default() -> Self {
        Target {
            rel_err: None,
            abs_err: None,
            max_evals: DEFAULT_MAX_EVALS,
            max_seconds: None,
        }
    }
}

impl Target {
    /// A relative error, within [`DEFAULT_MAX_EVALS`].
    pub fn rel(rel_err: f64) -> Target {
        Target {
            rel_err: Some(rel_err),
            ..Target::default()
        }
    }

    /// An absolute error, within [`DEFAULT_MAX_EVALS`].
    pub fn abs(abs_err: f64) -> Target {
        Target {
            abs_err: Some(abs_err),
            ..Target::default()
        }
    }

    /// Sets [`Target::max_evals`].
    pub fn max_evals(mut self, max_evals: u64) -> Target {
        self.max_evals = max_evals;
        self
    }

    /// Sets [`Target::max_seconds`].
    pub fn max_seconds(mut self, seconds: f64) -> Target {
        self.max_seconds = Some(seconds);
        self
    }

    /// The target the front ends' options describe: `None` when neither error is given (a run on
    /// a budget), an error when a limit is given without an error to reach. `max_evals` defaults
    /// to [`DEFAULT_MAX_EVALS`]. Not checked: [`Target::check`] does that, before a run.
    pub fn from_options(
        rel_err: Option<f64>,
        abs_err: Option<f64>,
        max_evals: Option<u64>,
        max_seconds: Option<f64>,
    ) -> Result<Option<Target>> {
        if rel_err.is_none() && abs_err.is_none() {
            if max_evals.is_some() || max_seconds.is_some() {
                return Err(Error::Config(
                    "precision target: max_evals and max_seconds limit a run to a target; give \
                     rel_err or abs_err too (or evals for a fixed budget)"
                        .into(),
                ));
            }
            return Ok(None);
        }
        Ok(Some(Target {
            rel_err,
            abs_err,
            max_evals: max_evals.unwrap_or(DEFAULT_MAX_EVALS),
            max_seconds,
        }))
    }

    /// The error bar that meets the target for an estimate `value`: max(abs_err, rel_err·|value|).
    pub fn error_for(&self, value: f64) -> f64 {
        let rel = self.rel_err.map_or(0.0, |r| r * value.abs());
        rel.max(self.abs_err.unwrap_or(0.0))
    }

    /// An error, before anything is evaluated, when the target cannot be met or its limits
    /// contradict each other; `least` is the fewest evaluations `method` needs for one estimate.
    pub fn check(&self, method: &str, least: u64) -> Result<()> {
        let bad = |why: String| Err(Error::Config(format!("precision target: {why}")));
        if self.rel_err.is_none() && self.abs_err.is_none() {
            return bad("give rel_err, abs_err or both".into());
        }
        for (name, v) in [("rel_err", self.rel_err), ("abs_err", self.abs_err)] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return bad(format!("{name} must be a positive number, got {v}"));
                }
            }
        }
        if let Some(s) = self.max_seconds {
            if !(s.is_finite() && s > 0.0) {
                return bad(format!("max_seconds must be a positive number, got {s}"));
            }
        }
        if self.max_evals < least {
            return bad(format!(
                "max_evals = {} is below the {least} evaluations {method} needs for one estimate",
                self.max_evals
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_targets_are_refused_before_any_evaluation() {
        let ok = Target::rel(1e-3);
        assert!(ok.check("nis", 100).is_ok());
        for t in [
            Target::default(),
            Target::rel(0.0),
            Target::rel(-1e-3),
            Target::rel(f64::NAN),
            Target::abs(f64::INFINITY),
            ok.max_seconds(0.0),
            ok.max_seconds(f64::NAN),
            ok.max_evals(99),
        ] {
            let e = t.check("nis", 100).unwrap_err().to_string();
            assert!(e.contains("precision target"), "{e}");
        }
    }

    #[test]
    fn either_error_meets_the_target() {
        let t = Target {
            rel_err: Some(1e-2),
            abs_err: Some(1e-3),
            ..Target::default()
        };
        assert_eq!(t.error_for(1.0), 1e-2);
        assert_eq!(t.error_for(0.01), 1e-3);
    }
}
