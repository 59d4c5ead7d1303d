//! Plain Monte Carlo: uniform points, no adaptation. The baseline every method must beat.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use super::estimate::iid_iteration;
use super::target::{drive, Prior, Pursuit, Step, Stepper};
use super::{
    check_budget, check_dim, evaluate, report, Accumulator, Integrand, IntegrationResult,
    Integrator, Iteration, Method, Progress, Target,
};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::kernels::in_pool;

/// Settings of plain Monte Carlo.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlainMcConfig {
    /// Equal iterations the evaluations are split into (for χ²/dof).
    pub iterations: usize,
    /// Seed of the random points.
    pub seed: u64,
}

impl Default for PlainMcConfig {
    fn default() -> Self {
        PlainMcConfig {
            iterations: 10,
            seed: 0,
        }
    }
}

impl PlainMcConfig {
    /// A builder starting from the defaults.
    pub fn builder() -> PlainMcConfigBuilder {
        PlainMcConfigBuilder(PlainMcConfig::default())
    }

    pub(crate) fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::Config(
                "plain Monte Carlo needs at least one iteration".into(),
            ));
        }
        Ok(())
    }
}

/// Builds a [`PlainMcConfig`] with named setters.
///
/// ```
/// use nis::integrate::uniform::PlainMcConfig;
/// let c = PlainMcConfig::builder().iterations(5).seed(3).build().unwrap();
/// assert_eq!((c.iterations, c.seed), (5, 3));
/// ```
#[derive(Clone, Debug)]
pub struct PlainMcConfigBuilder(PlainMcConfig);

impl PlainMcConfigBuilder {
    /// Sets [`PlainMcConfig::iterations`].
    pub fn iterations(mut self, iterations: usize) -> Self {
        self.0.iterations = iterations;
        self
    }
    /// Sets [`PlainMcConfig::seed`].
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }
    /// The checked settings.
    pub fn build(self) -> Result<PlainMcConfig> {
        self.0.validate()?;
        Ok(self.0)
    }
}

/// Plain Monte Carlo integrator: each call draws fresh uniform points from its random stream.
pub struct PlainMc {
    config: PlainMcConfig,
    dim: usize,
    rng: Pcg64Mcg,
    comm: Comm,
    progress: Option<Box<dyn Progress>>,
}

impl PlainMc {
    /// A plain Monte Carlo integrator in `dim` dimensions.
    pub fn new(dim: usize, config: PlainMcConfig) -> Result<PlainMc> {
        config.validate()?;
        Ok(PlainMc {
            rng: Pcg64Mcg::seed_from_u64(config.seed),
            config,
            dim,
            comm: Comm::default(),
            progress: None,
        })
    }

    /// Its settings.
    pub fn config(&self) -> &PlainMcConfig {
        &self.config
    }
}

impl Integrator for PlainMc {
    fn method(&self) -> Method {
        Method::Uniform
    }

    fn dim(&self) -> usize {
        self.dim
    }

    fn set_progress(&mut self, progress: Option<Box<dyn Progress>>) {
        self.progress = progress;
    }

    fn set_comm(&mut self, comm: Comm) {
        self.rng = Pcg64Mcg::seed_from_u64(comm.stream_seed(self.config.seed));
        self.comm = comm;
    }

    /// `evals` uniform points in `iterations` equal iterations.
    /// Runs on a worker of rayon's pool (`kernels::in_pool`), as the NIS integrator does.
    fn integrate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        in_pool(|| self.run(f, evals))
    }

    /// A pilot of `PILOT` points, kept out of the estimate, plans the iterations that make it.
    fn integrate_to(&mut self, f: &dyn Integrand, target: &Target) -> Result<IntegrationResult> {
        in_pool(|| self.run_to(f, target))
    }

    fn check_target(&self, target: &Target) -> Result<()> {
        target.check("plain Monte Carlo", PILOT + 2)
    }
}

/// Points of plain MC's pilot when integrating to a target: they only predict the variance.
const PILOT: u64 = 1000;

impl PlainMc {
    /// The iterations of [`Integrator::integrate`].
    fn run(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        let dim = self.dim;
        check_dim(f, dim)?;
        let k = f.components();
        let started = Instant::now();
        let iterations = self.config.iterations;
        check_budget(
            Method::Uniform,
            evals,
            2 * iterations as u64,
            "two per iteration",
        )?;
        let mut acc = Accumulator::for_fixed_sampler(evals);
        let mut done = 0;
        for it in 0..iterations {
            let n = (evals * (it as u64 + 1) / iterations as u64 - done).max(1);
            let rng = &mut self.rng;
            let iteration = iid_iteration(&self.comm, n, k, &mut acc, |m| {
                at_uniform_points(f, dim, m, rng)
            })?;
            acc.add(iteration)?;
            done += n;
            report(&mut self.progress, done, evals, "uniform");
        }
        acc.reduce_tail(&self.comm);
        Ok(acc.finish(None, done, started))
    }

    /// [`Integrator::integrate_to`]: the pilot, then iterations planned by a [`Pursuit`].
    fn run_to(&mut self, f: &dyn Integrand, target: &Target) -> Result<IntegrationResult> {
        let dim = self.dim;
        check_dim(f, dim)?;
        let k = f.components();
        self.check_target(target)?;
        let started = Instant::now();
        let mut pilot_acc = Accumulator::for_fixed_sampler(PILOT);
        let pilot = iid_iteration(&self.comm, PILOT, k, &mut pilot_acc, |m| {
            at_uniform_points(f, dim, m, &mut self.rng)
        })?;
        let mut pursuit = Pursuit::new(*target, started, PILOT);
        let mut prior = Prior {
            var_per_eval: pilot.variance * PILOT as f64,
            estimate: pilot.estimate,
            seconds_per_eval: pursuit.elapsed(&self.comm) / PILOT as f64,
        };
        let predicted = prior.evals_to(target, target.max_evals as f64);
        let mut acc = Accumulator::for_fixed_sampler(predicted as u64);
        acc.set_frozen_sampler();
        let mut steps = Steps {
            f,
            dim,
            rng: &mut self.rng,
            comm: &self.comm,
            acc,
            progress: &mut self.progress,
            chunk: (predicted / self.config.iterations as f64) as u64,
            predicted: predicted as u64,
            done: 0,
        };
        drive(&mut pursuit, &mut prior, &self.comm, &mut steps)?;
        let (mut acc, done) = (steps.acc, steps.done);
        acc.reduce_tail(&self.comm);
        let mut result = acc.finish(Some(pursuit.shares()), PILOT + done, started);
        pursuit.finish(&mut result);
        Ok(result)
    }
}

/// f at `m` uniform points in [0, 1]^dim.
fn at_uniform_points(
    f: &dyn Integrand,
    dim: usize,
    m: usize,
    rng: &mut Pcg64Mcg,
) -> Result<Vec<f64>> {
    let x: Vec<f64> = (0..m * dim).map(|_| rng.random::<f64>()).collect();
    evaluate(f, &x, dim)
}

/// Plain MC's iterations of a run to a target, after the pilot.
struct Steps<'a> {
    f: &'a dyn Integrand,
    dim: usize,
    rng: &'a mut Pcg64Mcg,
    comm: &'a Comm,
    acc: Accumulator,
    progress: &'a mut Option<Box<dyn Progress>>,
    /// Evaluations per iteration (the predicted need over the configured iterations).
    chunk: u64,
    predicted: u64,
    done: u64,
}

impl Stepper for Steps<'_> {
    fn size(&mut self, _: &Pursuit, prior: &mut Prior, elapsed: f64) -> (u64, u64) {
        prior.seconds_per_eval = elapsed / (PILOT + self.done) as f64;
        (2, self.chunk)
    }

    fn draw(&mut self, step: Step, _: &mut Pursuit, _: &mut Prior) -> Result<Iteration> {
        let (f, dim, rng) = (self.f, self.dim, &mut *self.rng);
        let k = f.components();
        let iteration = iid_iteration(self.comm, step.evals, k, &mut self.acc, |m| {
            at_uniform_points(f, dim, m, rng)
        })?;
        self.done += iteration.evals;
        Ok(iteration)
    }

    fn keep(&mut self, iteration: Iteration) -> Result<()> {
        self.acc.add(iteration)?;
        report(
            self.progress,
            PILOT + self.done,
            PILOT + self.predicted.max(self.done),
            "uniform: to the target",
        );
        Ok(())
    }
}
