//! The contract every method meets: the [`Integrator`] trait, its observer of progress
//! ([`Progress`]), and the budget check and progress report the methods share. Below the
//! methods: it names none of them (`as_nis` and `as_multichannel` downcast from `Any`).

use std::any::Any;
use std::path::Path;

use super::{Integrand, IntegrationResult, Method, Target};
use crate::comm::Comm;
use crate::error::{Error, Result};

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
pub(crate) fn check_budget(method: Method, evals: u64, min: u64, why: &str) -> Result<()> {
    if evals < min {
        return Err(Error::Config(format!(
            "{} needs at least {min} evaluations ({why}), got {evals}",
            method.label()
        )));
    }
    Ok(())
}

/// Sends a report to the observer, if there is one.
pub(crate) fn report(
    progress: &mut Option<Box<dyn Progress>>,
    done: u64,
    total: u64,
    status: &str,
) {
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
    /// see [`NisIntegrator::save`](super::nis::NisIntegrator::save)); the others refuse with
    /// [`Error::Config`].
    fn save(&self, path: &Path) -> Result<()> {
        let _ = path;
        Err(Error::Config(format!(
            "{} has no trained state to save",
            self.method().name()
        )))
    }
    /// This integrator as NIS, as `Any`: what `as_nis` (on `dyn Integrator`, in `nis/mod.rs`)
    /// downcasts; `None` for the other methods.
    fn as_nis_any(&mut self) -> Option<&mut dyn Any> {
        None
    }
    /// This integrator as a multi-channel one, as `Any`: what `as_multichannel` (on
    /// `dyn Integrator`, in `multichannel/mod.rs`) downcasts; `None` for the methods on their
    /// own.
    fn as_multichannel_any(&mut self) -> Option<&mut dyn Any> {
        None
    }
}
