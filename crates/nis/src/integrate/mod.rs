//! Integration: the [`Integrand`] interface and one [`Integrator`] trait over three estimators —
//! neural importance sampling ([`nis::NisIntegrator`]), VEGAS+ ([`vegas::Vegas`]) and plain Monte
//! Carlo ([`uniform::PlainMc`]) — with one result type and the statistics they share.
//!
//! As in the `vegas` package, an integrator is an object that owns its adapted state (the flow
//! and its optimiser, the VEGAS+ map and strata, the random streams): its settings, the seed
//! included, live in its config, built with named setters, and each call to
//! [`Integrator::integrate`] adapts further from where the last one left off, then estimates anew.
//!
//! Every method has an adaptive phase whose evaluations only teach the sampler, and a final phase
//! with the sampler frozen whose evaluations alone make the estimate: the result is then an
//! unbiased mean of i.i.d. (or stratified) weights, and its error bar is the honest standard
//! error of that mean. The final phase is split into iterations whose spread gives χ²/dof.

mod adaptive_strata;
mod build;
mod convergence;
pub mod diagnostics;
mod estimate;
mod integrand;
mod integrator;
mod iteration;
mod method;
mod moments;
pub mod multichannel;
pub mod nis;
mod race;
mod result;
pub mod settings;
mod strategies;
mod target;
pub mod uniform;
pub mod unweight;
pub mod vegas;

pub use build::{integrator, Settings};
pub use convergence::{
    Convergence, ConvergenceWarning, DIVERGENCE_LIMIT, HOLE_LIMIT, MISSING_MASS_LIMIT,
};
pub use diagnostics::{Reliability, PARETO_K_LIMIT, PARETO_K_Z, SETTLED_VAR_REL_ERR, TAIL_END_P};
pub use estimate::{Accumulator, CHI2_LIMIT};
pub use integrand::{check_dim, evaluate, points_per_task, Integrand, TrainOn, VectorFn};
pub(crate) use integrator::{check_budget, report};
pub use integrator::{Integrator, Progress};
pub use method::Method;
pub use result::{
    disagreements, ChannelReport, ComponentEstimates, IntegrationResult, Iteration,
    IterationComponents, SignReport, Source, Stop, DISAGREEMENT_SIGMAS,
};
pub use target::{Target, DEFAULT_MAX_EVALS};
