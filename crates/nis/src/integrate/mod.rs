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
mod convergence;
pub mod diagnostics;
mod estimate;
mod integrand;
mod iteration;
mod method;
mod moments;
pub mod multichannel;
pub mod nis;
mod race;
mod result;
pub mod settings;
mod target;
pub mod uniform;
pub mod unweight;
pub mod vegas;

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::comm::Comm;
use crate::error::{Error, Result};

pub use convergence::{
    Convergence, ConvergenceWarning, DIVERGENCE_LIMIT, HOLE_LIMIT, MISSING_MASS_LIMIT,
};
pub use diagnostics::{Reliability, PARETO_K_LIMIT, PARETO_K_Z};
pub use estimate::{Accumulator, CHI2_LIMIT};
pub use integrand::{check_dim, evaluate, points_per_task, Integrand, TrainOn, VectorFn};
pub use method::Method;
pub use result::{
    disagreements, ChannelReport, ComponentEstimates, IntegrationResult, Iteration,
    IterationComponents, SignReport, Source, Stop, DISAGREEMENT_SIGMAS,
};
pub use target::{Target, DEFAULT_MAX_EVALS};

/// Receives progress reports: evaluations done so far in the current call, evaluations planned
/// for it, and a short status. Closures `FnMut(u64, u64, &str) + Send` are observers.
pub trait Progress: Send {
    /// One report.
    fn report(&mut self, done: u64, total: u64, status: &str);
}

impl<F: FnMut(u64, u64, &str) + Send> Progress for F {
    fn report(&mut self, done: u64, total: u64, status: &str) {
        self(done, total, status)
    }
}

/// Rejects a budget below `min` evaluations: an estimate needs at least two evaluations in every
/// iteration of its final phase (one gives no error bar), so smaller budgets are an error rather
/// than an estimate with a meaningless "± 0" or a silently larger spend.
fn check_budget(method: Method, evals: u64, min: u64, why: &str) -> Result<()> {
    if evals < min {
        return Err(Error::Config(format!(
            "{} needs at least {min} evaluations ({why}), got {evals}",
            method.label()
        )));
    }
    Ok(())
}

/// Sends a report to the observer, if there is one.
fn report(progress: &mut Option<Box<dyn Progress>>, done: u64, total: u64, status: &str) {
    if let Some(p) = progress {
        p.report(done, total, status);
    }
}

/// A Monte Carlo integrator over [0, 1]^d that owns its adapted state.
///
/// Used as the `vegas` package's `Integrator` is: a first call adapts and estimates, a second one
/// adapts further from where the first left off and estimates anew (discard the first as a
/// warm-up when the sampler starts far from the integrand).
/// ```
/// use nis::integrate::{vegas::{Vegas, VegasConfig}, Integrator};
/// // A narrow Gaussian bump in 2-d, ∫ = 1 up to the tails cut off by the unit square.
/// let f = |x: &[f64]| {
///     let r2 = (x[0] - 0.5).powi(2) + (x[1] - 0.5).powi(2);
///     (-r2 / (2.0 * 0.05f64.powi(2))).exp() / (2.0 * std::f64::consts::PI * 0.05f64.powi(2))
/// };
/// let mut integ = Vegas::new(2, VegasConfig::builder().seed(1).build()?)?;
/// let _warm_up = integ.integrate(&f, 50_000)?;
/// let r = integ.integrate(&f, 100_000)?;
/// assert!((r.value - 1.0).abs() < 5.0 * r.std_err && r.std_err < 1e-3);
/// # Ok::<(), nis::Error>(())
/// ```
pub trait Integrator: Send {
    /// Which method this is.
    fn method(&self) -> Method;
    /// The dimension it integrates in.
    fn dim(&self) -> usize;
    /// Spends `evals` evaluations of `f`: adapts the sampler on a share of them (continuing from
    /// earlier calls), then estimates ∫ f with the rest, the sampler frozen. The result covers
    /// this call's final phase only. An error of the integrand stops the call and is returned.
    fn integrate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult>;
    /// Integrates until the error bar meets `target` or one of its limits is reached, whichever
    /// comes first; the result's [`IntegrationResult::stop`] says which, and a limit adds a
    /// warning, not an error. Adapts as [`Integrator::integrate`] does (NIS decides how long to
    /// train from the costs and the progress it measures), then estimates with iterations whose
    /// shares are fixed before they are drawn, so the stopped estimate stays unbiased
    /// (docs/ESTIMATE.md, "Precision targets"). An error, before any evaluation, for a target
    /// that cannot be met or limits below one estimate's needs.
    fn integrate_to(&mut self, f: &dyn Integrand, target: &Target) -> Result<IntegrationResult>;
    /// The error [`Integrator::integrate_to`] would return for `target` before evaluating
    /// anything (front ends call it before they probe the integrand).
    fn check_target(&self, target: &Target) -> Result<()>;
    /// Sets (or removes) the observer of progress; the default is none.
    fn set_progress(&mut self, progress: Option<Box<dyn Progress>>);
    /// Runs data-parallel over the ranks of `comm` (e.g. `nis::comm::mpi::MpiComm`, feature `mpi`) from
    /// now on; the default is one process. Every rank builds the same integrator with the same
    /// settings, sets its communicator before integrating and makes the same calls: each draws
    /// its share of every batch from its own random stream (derived from the seed and its rank,
    /// [`Comm::stream_seed`]), and the sums the adaptation and the estimate need are reduced over
    /// the ranks in a fixed order, so every rank gets the same result — one per seed and rank
    /// count — and with one process exactly the result without MPI. Restarts the random streams.
    fn set_comm(&mut self, comm: Comm);
    /// Saves the adapted state for later estimates. Only NIS keeps one worth saving (its flow,
    /// see [`nis::NisIntegrator::save`]); the others refuse with [`Error::Config`].
    fn save(&self, path: &Path) -> Result<()> {
        let _ = path;
        Err(Error::Config(format!(
            "{} has no trained state to save",
            self.method().name()
        )))
    }
    /// This integrator as NIS, for what only NIS does (train without estimating, estimate with
    /// the flow frozen, sample, unweight); `None` for the other methods.
    fn as_nis(&mut self) -> Option<&mut nis::NisIntegrator> {
        None
    }
    /// This integrator as a multi-channel one, for what only it does (its channel weights,
    /// events that carry their channel); `None` for the methods on their own.
    fn as_multichannel(&mut self) -> Option<&mut multichannel::MultiChannel> {
        None
    }
}

/// The settings of every method, for building one by name with [`integrator`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    /// Used when the method is [`Method::Nis`].
    pub nis: nis::NisConfig,
    /// Used when the method is [`Method::Vegas`].
    pub vegas: vegas::VegasConfig,
    /// Used when the method is [`Method::Uniform`].
    pub uniform: uniform::PlainMcConfig,
}

impl Settings {
    /// Seeds every method (for NIS both the flow's initialisation and the sampling).
    pub fn seed(mut self, seed: u64) -> Settings {
        self.nis.seed = seed;
        self.nis.flow.seed = seed;
        self.vegas.seed = seed;
        self.uniform.seed = seed;
        self
    }

    /// The seed `method` runs with.
    pub fn seed_of(&self, method: Method) -> u64 {
        match method {
            Method::Nis => self.nis.seed,
            Method::Vegas => self.vegas.seed,
            Method::Uniform => self.uniform.seed,
        }
    }

    /// Makes every adaptive method adapt to `train_on`.
    pub fn train_on(mut self, train_on: TrainOn) -> Settings {
        self.nis.train_on = train_on;
        self.vegas.train_on = train_on;
        self
    }
}

/// Builds the integrator of `method` in `dim` dimensions from its part of `settings`.
///
/// ```
/// use nis::integrate::{integrator, Method, Settings};
/// let mut integ = integrator("uniform".parse::<Method>()?, 3, &Settings::default().seed(7))?;
/// let r = integ.integrate(&|x: &[f64]| x[0] + x[1] + x[2], 10_000)?;
/// assert!((r.value - 1.5).abs() < 5.0 * r.std_err);
/// # Ok::<(), nis::Error>(())
/// ```
pub fn integrator(method: Method, dim: usize, settings: &Settings) -> Result<Box<dyn Integrator>> {
    Ok(match method {
        Method::Nis => Box::new(nis::NisIntegrator::new(dim, settings.nis.clone())?),
        Method::Vegas => Box::new(vegas::Vegas::new(dim, settings.vegas.clone())?),
        Method::Uniform => Box::new(uniform::PlainMc::new(dim, settings.uniform.clone())?),
    })
}

/// The rival a learning method races to a target (`race.rs`): VEGAS+ with its defaults but
/// `seed` and `train_on`.
pub(crate) fn rival(dim: usize, seed: u64, train_on: TrainOn) -> Result<Box<dyn race::Rival>> {
    let config = vegas::VegasConfig {
        seed,
        train_on,
        ..vegas::VegasConfig::default()
    };
    Ok(Box::new(vegas::Vegas::new(dim, config)?))
}
