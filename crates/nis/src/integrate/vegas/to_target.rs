//! VEGAS+ to a precision target ([`crate::integrate::Integrator::integrate_to`]): the warm-up of
//! a nominal budget's plan adapts the map and the strata, then iterations planned by a
//! [`Pursuit`] make the estimate, each with its share fixed before it is drawn, while the map
//! and the strata go on adapting (as in [`super::Vegas`]'s result iterations).

use std::time::Instant;

use rand_pcg::Pcg64Mcg;

use super::iteration::Measure;
use super::map::Map;
use super::{Plan, Vegas, VegasConfig};
use crate::comm::Comm;
use crate::error::Result;
use crate::integrate::adaptive_strata::Strata;
use crate::integrate::convergence::DIVERGENCE_LIMIT;
use crate::integrate::race::{Pursued, Race, Rival};
use crate::integrate::target::{drive, Ended, Prior, Pursuit, Step, Stepper, AIM};
use crate::integrate::{
    check_dim, report, Accumulator, Integrand, IntegrationResult, Iteration, Progress, Target,
};

/// The budget whose plan lays out the warm-up (points per iteration, increments, strata).
const NOMINAL_EVALS: u64 = 100_000;

impl Vegas {
    /// The plan whose warm-up a run to `target` starts with: the nominal budget's.
    fn warm_up_plan(&self, target: &Target) -> Plan {
        self.plan(NOMINAL_EVALS.min(target.max_evals))
    }

    /// [`crate::integrate::Integrator::check_target`]: the warm-up and one iteration must fit.
    pub(super) fn check_target_plan(&self, target: &Target) -> Result<()> {
        let plan = self.warm_up_plan(target);
        target.check("vegas+", ((plan.warmup + 1) * plan.per_iter) as u64)
    }

    /// [`crate::integrate::Integrator::integrate_to`] for VEGAS+: the warm-up of the nominal
    /// budget's plan, then the pursuit.
    pub(super) fn run_to(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
    ) -> Result<IntegrationResult> {
        self.check_target_plan(target)?;
        let warm = self.warm_up(f, target, Instant::now())?;
        match self.pursue(f, target, warm, None)? {
            Pursued::Done(result) => Ok(*result),
            Pursued::GaveUp { .. } => unreachable!("a pursuit without a race does not give up"),
        }
    }

    /// The warm-up of the nominal budget's plan: adapts the map and the strata and measures what
    /// the pursuit starts from. `started`: when the run began (its time limit counts from then).
    fn warm_up(&mut self, f: &dyn Integrand, target: &Target, started: Instant) -> Result<Warm> {
        let clock = Instant::now();
        let dim = self.dim;
        check_dim(f, dim)?;
        let k = f.components();
        let train_on = self.config.train_on;
        train_on.check(k)?;
        let plan = self.warm_up_plan(target);
        let per_iter = plan.per_iter;
        let (min_per_cube, alpha, beta) = (
            self.config.min_per_cube,
            self.config.alpha,
            self.config.beta,
        );
        self.adopt(plan.increments, plan.strata);
        let map = self.map.as_mut().expect("made by adopt");
        let strata = self.strata.as_mut().expect("set by adopt");
        let (rng, comm) = (&mut self.rng, &self.comm);
        let mut contribution_var = vec![0.0; strata.cubes];
        let mut n_eval = 0u64;
        let mut last = (0.0, 0.0);
        for _ in 0..plan.warmup {
            let measure = Measure {
                f,
                comm,
                k,
                train_on,
                volume: 1.0 / strata.cubes as f64,
            };
            let counts = strata.allocate(per_iter, min_per_cube);
            let measured = measure.iteration(map, strata, rng, &counts, &mut contribution_var)?;
            n_eval += measured.evals;
            last = (measured.variance * measured.evals as f64, measured.estimate);
            strata.adapt(&contribution_var, beta);
            map.adapt(alpha);
            report(&mut self.progress, n_eval, n_eval, "vegas: adapting");
        }
        let seconds = slowest(comm, clock);
        Ok(Warm {
            started,
            others: 0,
            n_eval,
            seconds,
            per_iter,
            contribution_var,
            prior: Prior {
                var_per_eval: last.0,
                estimate: last.1,
                seconds_per_eval: seconds / n_eval.max(1) as f64,
            },
        })
    }

    /// Iterations planned by a [`Pursuit`] from where `warm` left the map and the strata, until
    /// the target or a limit, or until `race` says give up.
    fn pursue(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        warm: Warm,
        race: Option<Race>,
    ) -> Result<Pursued> {
        let clock = Instant::now();
        let Warm {
            started,
            others,
            n_eval,
            seconds: warm_seconds,
            per_iter,
            contribution_var,
            mut prior,
        } = warm;
        let mut pursuit = Pursuit::new(*target, started, n_eval + others).adapting();
        let predicted = prior.evals_to(target, target.max_evals as f64);
        let mut steps = Steps {
            f,
            dim: self.dim,
            config: &self.config,
            map: self.map.as_mut().expect("made by the warm-up"),
            strata: self.strata.as_mut().expect("set by the warm-up"),
            rng: &mut self.rng,
            comm: &self.comm,
            progress: &mut self.progress,
            acc: Accumulator::new(predicted as u64),
            contribution_var,
            race,
            clock,
            warm_seconds,
            warm: n_eval,
            n_eval,
            predicted: predicted as u64,
            per_iter,
            chunk: per_iter,
            strata_for: per_iter,
            best: prior.var_per_eval,
            lowest: prior.var_per_eval,
            improving: true,
        };
        if drive(&mut pursuit, &mut prior, &self.comm, &mut steps)? == Ended::GaveUp {
            return Ok(Pursued::GaveUp {
                evals: steps.n_eval,
            });
        }
        let (mut acc, n_eval) = (steps.acc, steps.n_eval);
        acc.reduce_tail(&self.comm);
        let mut result = acc.finish(Some(pursuit.shares()), n_eval + others, started);
        pursuit.finish(&mut result);
        Ok(Pursued::Done(Box::new(result)))
    }
}

impl Rival for Vegas {
    fn warm_up_evals(&self, target: &Target) -> u64 {
        let plan = self.warm_up_plan(target);
        (plan.warmup * plan.per_iter) as u64
    }

    /// [`Vegas::run_to`] racing a learner (`integrate/race.rs`): gives up as soon as, after
    /// `race.least` seconds, its predicted time exceeds the learner's.
    fn race_to(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        started: Instant,
        others: u64,
        race: Race,
    ) -> Result<Pursued> {
        let mut warm = self.warm_up(f, target, started)?;
        warm.others = others;
        self.pursue(f, target, warm, Some(race))
    }

    fn take_progress(&mut self) -> Option<Box<dyn Progress>> {
        self.progress.take()
    }
}

/// The estimate's iterations of a run to a target, the map and the strata adapting after each.
struct Steps<'a> {
    f: &'a dyn Integrand,
    dim: usize,
    config: &'a VegasConfig,
    map: &'a mut Map,
    strata: &'a mut Strata,
    rng: &'a mut Pcg64Mcg,
    comm: &'a Comm,
    progress: &'a mut Option<Box<dyn Progress>>,
    acc: Accumulator,
    contribution_var: Vec<f64>,
    race: Option<Race>,
    /// When the pursuit began, and the seconds the warm-up took before it.
    clock: Instant,
    warm_seconds: f64,
    /// Evaluations of the warm-up, of the run so far, and those predicted for the estimate.
    warm: u64,
    n_eval: u64,
    predicted: u64,
    /// The warm-up's iteration size, the current one, and the size the strata are planned for.
    per_iter: usize,
    chunk: usize,
    strata_for: usize,
    /// The variance per evaluation before the latest iteration (a race reads the better of
    /// the last two), the lowest so far, and whether the map still improves fast.
    best: f64,
    lowest: f64,
    improving: bool,
}

impl Stepper for Steps<'_> {
    /// Iterations grow at most ×2 each towards a tenth of the predicted need, the strata with
    /// them: the map keeps adapting as they grow, and a warm-up's (too large) prediction cannot
    /// make the first ones huge. While the map still improves fast they grow by √2 only: it
    /// adapts once per iteration, so more of them sooner make it better sooner.
    fn size(&mut self, pursuit: &Pursuit, prior: &mut Prior, _: f64) -> (u64, u64) {
        let min_per_cube = self.config.min_per_cube;
        if let Some(need) = pursuit.iteration_goal(prior) {
            let growth = if self.improving { SLOW_GROWTH } else { 2.0 };
            let most = (self.chunk as f64 * growth) as usize;
            self.chunk = (need as usize).clamp(self.per_iter, most.max(self.per_iter));
        }
        if self.chunk > 2 * self.strata_for {
            *self.strata = Strata::plan(self.dim, self.chunk, min_per_cube);
            self.contribution_var = vec![0.0; self.strata.cubes];
            self.strata_for = self.chunk;
        }
        let least = (2 * min_per_cube * self.strata.cubes) as u64;
        (least, self.chunk as u64)
    }

    /// In a race, another iteration is needed: is VEGAS+ still predicted to win? Its seconds to
    /// the target: the evaluations that would bring the pooled variance down to the aim at the
    /// best variance per evaluation of the last two iterations (one just after new strata reads
    /// high). Every rank decides alike, on the slowest rank's time.
    fn proceed(&mut self, step: Step, pursuit: &Pursuit, prior: &Prior) -> bool {
        let Some(race) = self.race else {
            return true;
        };
        let own = self.warm_seconds + slowest(self.comm, self.clock);
        let v = self.best.min(prior.var_per_eval);
        let wanted = AIM * pursuit.wanted(prior);
        let pooled = pursuit.variance().unwrap_or(f64::INFINITY);
        let left = v * (1.0 / (wanted * wanted) - 1.0 / pooled).max(0.0);
        let left = left * prior.seconds_per_eval;
        let next = step.evals as f64 * prior.seconds_per_eval;
        // Its weights so far already far from the integrand's shape: its result would carry
        // the divergence warning, and NIS would answer after all.
        let far = own >= SURE_SHARE * (own + left)
            && self
                .acc
                .divergence_so_far(self.comm)
                .is_some_and(|d| d > FAR_DIVERGENCE * DIVERGENCE_LIMIT);
        if far || (own + left > race.rival && own + next > race.least) {
            return false;
        }
        self.best = prior.var_per_eval;
        true
    }

    fn draw(&mut self, step: Step, _: &mut Pursuit, prior: &mut Prior) -> Result<Iteration> {
        let measure = Measure {
            f: self.f,
            comm: self.comm,
            k: self.f.components(),
            train_on: self.config.train_on,
            volume: 1.0 / self.strata.cubes as f64,
        };
        let counts = self
            .strata
            .allocate(step.evals as usize, self.config.min_per_cube);
        let measured = measure.iteration(
            self.map,
            self.strata,
            self.rng,
            &counts,
            &mut self.contribution_var,
        )?;
        self.n_eval += measured.evals;
        // The map keeps improving: the latest iteration predicts the next best.
        prior.var_per_eval = measured.variance * measured.evals as f64;
        self.improving = prior.var_per_eval < IMPROVING * self.lowest;
        self.lowest = self.lowest.min(prior.var_per_eval);
        prior.seconds_per_eval =
            (self.warm_seconds + slowest(self.comm, self.clock)) / self.n_eval as f64;
        self.acc.observe(&measured.w_eff);
        Ok(measured.iteration(self.comm))
    }

    fn keep(&mut self, iteration: Iteration) -> Result<()> {
        self.acc.add(iteration)?;
        self.strata.adapt(&self.contribution_var, self.config.beta);
        self.map.adapt(self.config.alpha);
        report(
            self.progress,
            self.n_eval,
            self.warm + self.predicted.max(self.n_eval - self.warm),
            "vegas: estimating to the target",
        );
        Ok(())
    }
}

/// The map still improves fast when an iteration's variance per evaluation is below this
/// fraction of the lowest before it; the iterations then grow by [`SLOW_GROWTH`] instead of 2.
/// Holding the size instead (growth 1) was faster still, but its maps, adapted on many small
/// iterations, gave heavier-tailed weights and false k̂ warnings (docs/results/integration.md,
/// "Precision targets").
const IMPROVING: f64 = 0.8;
const SLOW_GROWTH: f64 = std::f64::consts::SQRT_2;

/// The share of its predicted time after which a racing VEGAS+ whose weights so far are far from
/// the integrand's shape gives up, and how far, in units of the divergence warning's limit: on
/// gauss d = 16 and camel d = 8 the running divergence n/ESS − 1 is 15–30 there and ends at 8–9
/// (warned); on gauss d = 8 and camel d = 4 it is below 3 from a few per cent of the run on.
const SURE_SHARE: f64 = 0.1;
const FAR_DIVERGENCE: f64 = 2.0;

/// What a VEGAS+ warm-up leaves for the pursuit.
struct Warm {
    started: Instant,
    /// Evaluations spent on the run by others before it (NIS's first batches when VEGAS+ races
    /// it): counted in the result and against `max_evals`.
    others: u64,
    n_eval: u64,
    /// Seconds the warm-up took (the slowest rank's).
    seconds: f64,
    per_iter: usize,
    contribution_var: Vec<f64>,
    prior: Prior,
}

/// The seconds since `clock`, as the slowest rank saw them (every rank decides alike).
fn slowest(comm: &Comm, clock: Instant) -> f64 {
    comm.max(clock.elapsed().as_secs_f64())
}
