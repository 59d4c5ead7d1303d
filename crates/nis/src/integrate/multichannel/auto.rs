//! The default for one integrand without channels (`signs="auto"`): the method on its own, which
//! hands a scalar integrand that changes sign to a sign split ([`MultiChannel::single`] with
//! [`Signs::Split`]) as soon as its first points show both signs. One sampler of |f| keeps the
//! variance ‖f‖₁² − F² however well it learns, while f⁺ and f⁻ each with a sampler of its own can
//! reach zero (docs/ESTIMATE.md, "Channels and signs").
//!
//! The method's own first `pilot` points (per rank) decide, so an integrand of one sign costs
//! nothing and its result is the method's, bit for bit. When they show both signs, that call
//! stops at the batch that showed them (its evaluations count in the result's `n_eval`) and the
//! split integrates with what is left of the budget or the target's `max_evals`. A vector
//! integrand, and a budget too small for the split's parts, keep the whole.

use std::any::Any;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::{MultiChannel, MultiChannelConfig, Signs};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::integrate::{
    integrator, Integrand, IntegrationResult, Integrator, Method, Progress, Settings, Target,
};

/// `method` on one integrand without channels, split by sign when it changes sign (module
/// docs): what the front ends build unless told `signs="split"` or `"whole"`.
///
/// ```
/// use nis::integrate::multichannel::AutoSigns;
/// use nis::integrate::{Integrator, Method, Settings};
/// // A positive and a negative bump: F = 0.
/// let f = |x: &[f64]| {
///     let bump = |c: f64| (-((x[0] - c).powi(2) + (x[1] - c).powi(2)) / 0.02).exp();
///     bump(0.3) - bump(0.7)
/// };
/// let mut integ = AutoSigns::new(Method::Vegas, 2, Settings::default().seed(1))?;
/// let r = integ.integrate(&f, 200_000)?;
/// assert!(r.channels.as_ref().is_some_and(|c| c.signs.is_some()), "split by sign");
/// assert!(r.value.abs() < 5.0 * r.std_err);
/// # Ok::<(), nis::Error>(())
/// ```
pub struct AutoSigns {
    method: Method,
    dim: usize,
    settings: Settings,
    config: MultiChannelConfig,
    /// The method on its own, until a sign split takes over.
    whole: Box<dyn Integrator>,
    /// The sign split, once the first points showed both signs.
    split: Option<MultiChannel>,
    /// Whether the first scalar call has decided (later calls are not watched).
    decided: bool,
    comm: Comm,
    progress: Option<SharedProgress>,
}

impl AutoSigns {
    /// `method` in `dim` dimensions with its part of `settings` (the split, if one comes, uses
    /// the default [`MultiChannelConfig`]).
    pub fn new(method: Method, dim: usize, settings: Settings) -> Result<AutoSigns> {
        AutoSigns::with_config(method, dim, settings, MultiChannelConfig::default())
    }

    /// As [`AutoSigns::new`], with the split's settings `config` (its `pilot` is the number of
    /// first points per rank that are watched; its `signs` is ignored).
    pub fn with_config(
        method: Method,
        dim: usize,
        settings: Settings,
        config: MultiChannelConfig,
    ) -> Result<AutoSigns> {
        let config = MultiChannelConfig {
            signs: Signs::Split,
            ..config
        };
        // The split's settings are checked now rather than when it is needed.
        config.validate()?;
        Ok(AutoSigns {
            whole: integrator(method, dim, &settings)?,
            method,
            dim,
            settings,
            config,
            split: None,
            decided: false,
            comm: Comm::default(),
            progress: None,
        })
    }

    /// The sign split, made with this integrator's communicator and observer.
    fn new_split(&self) -> Result<MultiChannel> {
        let mut mc = MultiChannel::single(
            self.dim,
            self.method,
            self.settings.clone(),
            self.config.clone(),
        )?;
        mc.set_comm(self.comm.clone());
        mc.set_progress(self.progress.as_ref().map(SharedProgress::boxed));
        Ok(mc)
    }

    /// Runs `call` on the whole with `f` watched when this is the first scalar call and `least`
    /// evaluations leave the split enough; `Ok(Err(spent))` when the watch stopped it: both
    /// signs seen after `spent` evaluations (over all ranks).
    fn watched(
        &mut self,
        f: &dyn Integrand,
        least: bool,
        call: impl FnOnce(&mut dyn Integrator, &dyn Integrand) -> Result<IntegrationResult>,
    ) -> Result<std::result::Result<IntegrationResult, u64>> {
        if self.decided || f.components() != 1 || !least {
            return call(self.whole.as_mut(), f).map(Ok);
        }
        let watch = Watch::new(f, self.config.pilot as u64);
        let r = call(self.whole.as_mut(), &watch);
        let both = self.comm.any(watch.both.load(Ordering::Relaxed));
        self.decided = true;
        if !both {
            return r.map(Ok);
        }
        let spent = self.comm.sum(watch.evals.load(Ordering::Relaxed) as f64) as u64;
        Ok(Err(spent))
    }
}

impl Integrator for AutoSigns {
    fn method(&self) -> Method {
        self.method
    }

    fn dim(&self) -> usize {
        self.dim
    }

    fn integrate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        if let Some(mc) = &mut self.split {
            return mc.integrate(f, evals);
        }
        // Room for the split: twice its least budget once the watched points are spent.
        let least_split = MultiChannel::least_budget(2);
        let least = evals >= self.config.pilot as u64 + 2 * least_split;
        let spent = match self.watched(f, least, |i, g| i.integrate(g, evals))? {
            Ok(r) => return Ok(r),
            Err(spent) => spent,
        };
        let mut mc = self.new_split()?;
        // The method's first batch may hold more than the watched points: the split still gets
        // its least budget.
        let mut r = mc.integrate(f, evals.saturating_sub(spent).max(least_split))?;
        r.n_eval += spent;
        self.split = Some(mc);
        Ok(r)
    }

    fn integrate_to(&mut self, f: &dyn Integrand, target: &Target) -> Result<IntegrationResult> {
        if let Some(mc) = &mut self.split {
            return mc.integrate_to(f, target);
        }
        let mut rest = *target;
        rest.max_evals = target
            .max_evals
            .saturating_sub(self.config.pilot as u64 * self.comm.size() as u64);
        let least = self.new_split()?.check_target(&rest).is_ok();
        let spent = match self.watched(f, least, |i, g| i.integrate_to(g, target))? {
            Ok(r) => return Ok(r),
            Err(spent) => spent,
        };
        let mut mc = self.new_split()?;
        rest.max_evals = target.max_evals.saturating_sub(spent);
        let mut r = mc.integrate_to(f, &rest)?;
        r.n_eval += spent;
        self.split = Some(mc);
        Ok(r)
    }

    fn check_target(&self, target: &Target) -> Result<()> {
        match &self.split {
            Some(mc) => mc.check_target(target),
            None => self.whole.check_target(target),
        }
    }

    fn set_progress(&mut self, progress: Option<Box<dyn Progress>>) {
        self.progress = progress.map(SharedProgress::new);
        let shared = self.progress.as_ref().map(SharedProgress::boxed);
        self.whole.set_progress(shared);
        if let Some(mc) = &mut self.split {
            mc.set_progress(self.progress.as_ref().map(SharedProgress::boxed));
        }
    }

    fn set_comm(&mut self, comm: Comm) {
        self.whole.set_comm(comm.clone());
        if let Some(mc) = &mut self.split {
            mc.set_comm(comm.clone());
        }
        self.comm = comm;
    }

    fn save(&self, path: &Path) -> Result<()> {
        match &self.split {
            Some(mc) => mc.save(path),
            None => self.whole.save(path),
        }
    }

    fn as_nis_any(&mut self) -> Option<&mut dyn Any> {
        match self.split {
            Some(_) => None,
            None => self.whole.as_nis_any(),
        }
    }

    fn as_multichannel_any(&mut self) -> Option<&mut dyn Any> {
        self.split.as_mut().map(|s| s as &mut dyn Any)
    }
}

/// The integrator a front end builds for `method` on one integrand without channels or a
/// `signs` setting: for NIS an [`AutoSigns`], which splits a scalar integrand that changes sign
/// (a flow per sign can reach zero variance, one flow of |f| cannot); VEGAS+ and plain MC keep
/// the whole unless asked (a uniform sampler gains nothing from the split, and VEGAS+'s split
/// run to a precision target can miss a smooth sign-changing integrand that its whole run gets
/// right), so they are [`integrator`]'s.
pub fn by_default(method: Method, dim: usize, settings: &Settings) -> Result<Box<dyn Integrator>> {
    match method {
        Method::Nis => Ok(Box::new(AutoSigns::new(method, dim, settings.clone())?)),
        _ => integrator(method, dim, settings),
    }
}

/// One observer of progress for the whole and the split.
#[derive(Clone)]
struct SharedProgress(Arc<Mutex<Box<dyn Progress>>>);

impl SharedProgress {
    fn new(p: Box<dyn Progress>) -> SharedProgress {
        SharedProgress(Arc::new(Mutex::new(p)))
    }

    fn boxed(&self) -> Box<dyn Progress> {
        Box::new(self.clone())
    }
}

impl Progress for SharedProgress {
    fn report(&mut self, done: u64, total: u64, status: &str) {
        let mut p = self.0.lock().unwrap_or_else(|e| e.into_inner());
        p.report(done, total, status);
    }
}

/// `f` as the method sees it, its first `left` values watched for both signs: the batch that
/// shows both ends the call with an error (the caller reads `both`, not the message).
struct Watch<'a> {
    f: &'a dyn Integrand,
    left: AtomicU64,
    positive: AtomicBool,
    negative: AtomicBool,
    both: AtomicBool,
    evals: AtomicU64,
}

impl<'a> Watch<'a> {
    fn new(f: &'a dyn Integrand, pilot: u64) -> Watch<'a> {
        Watch {
            f,
            left: AtomicU64::new(pilot),
            positive: AtomicBool::new(false),
            negative: AtomicBool::new(false),
            both: AtomicBool::new(false),
            evals: AtomicU64::new(0),
        }
    }
}

impl Integrand for Watch<'_> {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> Result<()> {
        self.f.eval_batch(x, dim, out)?;
        self.evals.fetch_add(out.len() as u64, Ordering::Relaxed);
        let left = self.left.load(Ordering::Relaxed);
        if left == 0 {
            return Ok(());
        }
        let seen = &out[..out.len().min(left as usize)];
        self.left.store(left - seen.len() as u64, Ordering::Relaxed);
        if seen.iter().any(|v| *v > 0.0) {
            self.positive.store(true, Ordering::Relaxed);
        }
        if seen.iter().any(|v| *v < 0.0) {
            self.negative.store(true, Ordering::Relaxed);
        }
        if self.positive.load(Ordering::Relaxed) && self.negative.load(Ordering::Relaxed) {
            self.both.store(true, Ordering::Relaxed);
            return Err(Error::Config(
                "the integrand changes sign: it is integrated split by sign (signs=\"auto\")"
                    .into(),
            ));
        }
        Ok(())
    }

    fn dim(&self) -> Option<usize> {
        self.f.dim()
    }

    fn components(&self) -> usize {
        self.f.components()
    }
}
