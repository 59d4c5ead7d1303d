//! One iteration of an estimate ([`Iteration`]): its estimate, variance, evaluations and where its
//! points came from. The floor of `integrate`: the other files may import it, it imports none.

use serde::{Deserialize, Serialize};

/// Where an iteration's points came from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// The frozen sampler of a final phase (for VEGAS+, an iteration after the warm-up).
    #[default]
    Final,
    /// Training batches that joined the estimate, pooled (NIS's `reuse_training`).
    Training,
}

impl Source {
    /// A short name for tables.
    pub fn label(self) -> &'static str {
        match self {
            Source::Final => "final",
            Source::Training => "training",
        }
    }
}

/// One iteration of an estimate: what it adds to the result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Iteration {
    /// The iteration's estimate of the integral (component 0).
    pub estimate: f64,
    /// The variance of that estimate.
    pub variance: f64,
    /// Its evaluations of the integrand, over all ranks.
    pub evals: u64,
    /// Where its points came from.
    #[serde(default)]
    pub source: Source,
    /// The largest |w| and Σ|w| of its weights f/q (component 0, over all ranks): the
    /// unweighting efficiency of the final sampler, and whether its variance is representable.
    #[serde(default)]
    pub max_abs_w: f64,
    #[serde(default)]
    pub sum_abs_w: f64,
    /// Every component's mean and the covariance of those means, for integrands of more than
    /// one component.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub components: Option<IterationComponents>,
}

/// An iteration's estimates of every component of a vector-valued integrand.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IterationComponents {
    /// The mean of each of the k components.
    pub mean: Vec<f64>,
    /// The k × k covariance of those means, row-major.
    pub cov: Vec<f64>,
}

impl Iteration {
    /// The iteration whose estimates of the k components are `mean` with covariance `cov`
    /// (`k × k`): component 0 is its estimate; more than one component are kept as such.
    pub fn new(
        source: Source,
        mean: Vec<f64>,
        cov: Vec<f64>,
        evals: u64,
        max_abs_w: f64,
        sum_abs_w: f64,
    ) -> Iteration {
        Iteration {
            estimate: mean[0],
            variance: cov[0],
            evals,
            source,
            max_abs_w,
            sum_abs_w,
            components: (mean.len() > 1).then_some(IterationComponents { mean, cov }),
        }
    }
}
