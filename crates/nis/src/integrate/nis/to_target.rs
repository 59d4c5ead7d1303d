//! NIS to a precision target ([`crate::integrate::Integrator::integrate_to`]), its part of a
//! learner's road (`integrate/strategies.rs`, which races VEGAS+ and switches the layout between
//! the probe and the rest): training whose length the rule of [`super::training_length`]
//! decides, then a final phase whose iterations a [`Pursuit`] plans, each with its share fixed
//! before it is drawn (`integrate::target`). The
//! training batches do not enter the estimate here (their shares would need the final phase's
//! size in advance); they predict it.

use std::time::Instant;

use rand_pcg::Pcg64Mcg;

use super::stratified_latent::{FinalPlan, LatentStrata};
use super::training_length::{anneal_batches, TrainingLength, SETTLE_BATCHES};
use super::{draw, weights, NisIntegrator};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::flow::mask::{default_layers, Masks};
use crate::flow::mixture::{DefensiveMixture, Record};
use crate::flow::{Density, Flow};
use crate::integrate::estimate::iid_iteration;
use crate::integrate::race::{Pace, RivalFactory};
use crate::integrate::strategies::{Lane, Learning, Probed};
use crate::integrate::target::{drive, Prior, Pursuit, Step, Stepper};
use crate::integrate::{
    check_dim, report, Accumulator, Integrand, IntegrationResult, Iteration, Progress, Target,
};

/// Training batches at most when integrating to a target (or twice the annealing's and the
/// settling's): the learning rate decays over them, and the rule usually stops well before.
const HORIZON_BATCHES: usize = 1000;

impl NisIntegrator {
    /// [`crate::integrate::Integrator::check_target`]: the least training the rule may stop at,
    /// within `train_fraction` of `max_evals`, and one final iteration must fit.
    pub(super) fn check_target_plan(&self, target: &Target) -> Result<()> {
        let share = self.config.train_fraction;
        if share <= 0.0 {
            return Err(Error::Config(
                "precision target: NIS needs train_fraction > 0 (the share of max_evals and \
                 max_seconds training may take)"
                    .into(),
            ));
        }
        let batch = self.config.batch as f64;
        let anneal = anneal_batches(self.flow().dim());
        let least_train = ((anneal + SETTLE_BATCHES) as f64 * batch / share).ceil() as u64;
        target.check("nis", least_train + self.least_final())
    }

    /// The fewest evaluations of a final phase: its least iteration, `final_iterations` times.
    fn least_final(&self) -> u64 {
        let iters = self.config.final_iterations as u64;
        FinalPlan::new(&self.config, self.flow().dim(), 0).least * iters
    }

    /// An error before any evaluation when `max_seconds` cannot pay for one batch of the flow
    /// within the training's share of it (timed on a copy of the training stream).
    fn check_seconds(&self, target: &Target) -> Result<()> {
        let Some(seconds) = target.max_seconds else {
            return Ok(());
        };
        let share = self.config.train_fraction;
        let t = Instant::now();
        draw(
            &self.sampler,
            self.config.batch,
            &mut self.streams.train.clone(),
            Record::Nothing,
        )?;
        // Every rank decides alike: on the slowest rank's time.
        let one = self.comm.max(t.elapsed().as_secs_f64());
        if seconds * share < one {
            return Err(Error::Config(format!(
                "precision target: max_seconds = {seconds} leaves {:.2e} s to train, less \
                 than one batch of the flow takes ({one:.2e} s) before any evaluation",
                seconds * share
            )));
        }
        Ok(())
    }

    /// The final phase after `trained` evaluations of training that `length` measured: its
    /// layout (the latent grid) for the size the training predicts, then iterations planned by
    /// a [`Pursuit`] until the target or a limit.
    fn final_to(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        started: Instant,
        trained: u64,
        length: &TrainingLength,
    ) -> Result<IntegrationResult> {
        let dim = self.flow().dim();
        let iters = self.config.final_iterations as u64;
        let least_final = self.least_final();
        let (var_per_eval, estimate, seconds_per_eval) =
            length.latest().expect("at least one batch trained");
        let mut prior = Prior {
            var_per_eval,
            estimate,
            seconds_per_eval,
        };
        // The size within the evaluations and the seconds left (its least iteration is half a
        // planned one, so a plan the time cannot pay for would overrun max_seconds by that much).
        let mut room = target.max_evals.saturating_sub(trained) as f64;
        if let Some(limit) = target.max_seconds {
            let elapsed = self.comm.max(started.elapsed().as_secs_f64());
            room = room.min((limit - elapsed).max(0.0) / seconds_per_eval.max(f64::MIN_POSITIVE));
        }
        let predicted = prior.evals_to(target, room);
        let plan = FinalPlan::new(&self.config, dim, (predicted as u64).max(least_final));
        let chunk = plan.evals / iters;
        let k = f.components();
        let lambda = self.sampler.lambda();
        let train_on = self.config.train_on;
        let mut acc = Accumulator::new(plan.evals);
        acc.set_frozen_sampler();
        acc.set_training_variances(length.variances());
        let mut pursuit = Pursuit::new(*target, started, trained);
        let mut steps = FinalSteps {
            f,
            sampler: &self.sampler,
            rng: &mut self.streams.estimate,
            comm: &self.comm,
            progress: &mut self.progress,
            latent: plan
                .latent
                .map(|(strata, s)| LatentStrata::new(strata, s, lambda, k, train_on)),
            acc,
            least: plan.least.max(chunk / 2),
            chunk,
            trained,
            planned: plan.evals,
            seconds: 0.0,
            done: 0,
        };
        drive(&mut pursuit, &mut prior, &self.comm, &mut steps)?;
        let (mut acc, done) = (steps.acc, steps.done);
        acc.reduce_tail(&self.comm);
        let mut result = acc.finish(Some(pursuit.shares()), trained + done, started);
        self.recall_training(&mut result)?;
        pursuit.finish(&mut result);
        Ok(result)
    }
}

/// A run to a target's training so far, between the road's strategies
/// (`integrate/strategies.rs`): the rule that measures it and decides its length, and the
/// limits it trains within.
pub(crate) struct TargetTraining {
    length: TrainingLength,
    target: Target,
    /// The integrator's trained evaluations when this layout's training began, and those it
    /// has trained since.
    before: u64,
    trained: u64,
    /// Evaluations spent and not used: VEGAS+'s when it loses the race, the probe's when the
    /// flow starts afresh.
    spent: u64,
    /// `train_fraction`, the batch size, the most batches and the training's share of
    /// `max_seconds`.
    share: f64,
    batch: u64,
    horizon: usize,
    max_seconds: f64,
    /// Batches of annealing, and the tempered target's first exponent.
    anneal: usize,
    beta_from: f64,
}

impl TargetTraining {
    /// The batches and seconds left to train after the pause, `spent` evaluations of a rival
    /// counted against `max_evals`.
    fn left(&self, spent: u64) -> (usize, f64) {
        let room = self.target.max_evals.saturating_sub(spent);
        let batches = batches_within(room, self.share, self.batch).min(self.horizon);
        let batches = batches.saturating_sub(self.length.batches());
        (batches, self.max_seconds - self.length.seconds())
    }
}

/// Training batches of `batch` evaluations within `share` of `evals`.
fn batches_within(evals: u64, share: f64, batch: u64) -> usize {
    ((evals as f64 * share) as u64 / batch) as usize
}

impl Probed for TargetTraining {
    fn paused(&self) -> bool {
        self.length.paused()
    }

    fn pace(&self) -> Pace {
        Pace {
            training_seconds: self.length.slow_seconds_left(),
            integrand_seconds_per_eval: self.length.integrand_seconds_per_eval(),
            evals: self.trained,
        }
    }

    fn smooth(&self) -> bool {
        self.length.smooth()
    }

    fn room_to_restart(&self, spent: u64) -> bool {
        let (batches, seconds) = self.left(spent);
        self.length.room_to_restart(batches, seconds)
    }
}

/// NIS on the road to a target: trains for as long as the rule of [`TrainingLength`] says it
/// pays, within `train_fraction` of the limits, pausing after the probe's batches for the
/// strategies; the cheaper layout is the codes' masks.
impl Learning for NisIntegrator {
    type Training = TargetTraining;

    /// [`super::NisConfig::race_vegas`], a rival handed in, an untrained flow.
    fn rival(&self) -> Option<RivalFactory> {
        self.rival
            .filter(|_| self.config.race_vegas && self.trained_evals == 0)
    }

    /// [`super::NisConfig::auto_masks`]: an untrained flow of binary masks, where the codes
    /// have fewer layers, annealed (the probe reads the tempered weights' ESS, 1 at β = 1).
    fn may_relayout(&self) -> bool {
        let flow = &self.config.flow;
        let dim = self.flow().dim();
        self.config.auto_masks
            && self.trained_evals == 0
            && self.config.anneal_from < 1.0
            && flow.masks == Masks::Binary
            && flow.couplings == 0
            && default_layers(dim, Masks::Codes) < default_layers(dim, Masks::Binary)
    }

    fn train_first(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        pause: bool,
    ) -> Result<TargetTraining> {
        check_dim(f, self.flow().dim())?;
        self.config.train_on.check(f.components())?;
        self.check_target_plan(target)?;
        self.check_seconds(target)?;
        let share = self.config.train_fraction;
        let batch = self.config.batch as u64;
        let anneal = anneal_batches(self.flow().dim());
        let horizon = HORIZON_BATCHES.max(2 * anneal + SETTLE_BATCHES);
        let batches = batches_within(target.max_evals, share, batch).min(horizon);
        let max_seconds = target.max_seconds.map_or(f64::INFINITY, |s| s * share);
        // A flow trained before (loaded, or trained by hand) starts at β = 1.
        let beta_from = if self.trained_evals == 0 {
            self.config.anneal_from
        } else {
            1.0
        };
        let mut training = TargetTraining {
            length: TrainingLength::new(*target, anneal, beta_from, batches, max_seconds),
            target: *target,
            before: self.trained_evals,
            trained: 0,
            spent: 0,
            share,
            batch,
            horizon,
            max_seconds,
            anneal,
            beta_from,
        };
        if pause {
            training.length.pause_after_probe();
        }
        self.train_keeping_for(f, batches, None, Some(&mut training.length))?;
        training.trained = self.trained_evals - training.before;
        Ok(training)
    }

    fn lane(&mut self) -> Lane<'_> {
        Lane {
            dim: self.flow().dim(),
            seed: self.config.seed,
            train_on: self.config.train_on,
            comm: &self.comm,
            progress: &mut self.progress,
        }
    }

    fn train_rest(
        &mut self,
        f: &dyn Integrand,
        training: &mut TargetTraining,
        spent: u64,
        relayout: bool,
    ) -> Result<()> {
        let (left, seconds_left) = training.left(spent);
        training.spent += spent;
        if relayout {
            // The probe's batches are spent, not used; training starts afresh.
            training.spent += training.trained;
            self.relayout(Masks::Codes)?;
            training.before = self.trained_evals;
            let (target, anneal, beta_from) =
                (training.target, training.anneal, training.beta_from);
            training.length = TrainingLength::new(target, anneal, beta_from, left, seconds_left);
        }
        if left > 0 {
            self.train_keeping_for(f, left, None, Some(&mut training.length))?;
        }
        training.trained = self.trained_evals - training.before;
        Ok(())
    }

    fn estimate(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        started: Instant,
        training: TargetTraining,
    ) -> Result<IntegrationResult> {
        let evals = training.trained + training.spent;
        self.final_to(f, target, started, evals, &training.length)
    }
}

/// The final phase's iterations: the frozen sampler's weights, stratified in the latent space
/// when the plan has a grid.
struct FinalSteps<'a> {
    f: &'a dyn Integrand,
    sampler: &'a DefensiveMixture<Flow>,
    rng: &'a mut Pcg64Mcg,
    comm: &'a Comm,
    progress: &'a mut Option<Box<dyn Progress>>,
    latent: Option<LatentStrata>,
    acc: Accumulator,
    least: u64,
    chunk: u64,
    /// Evaluations of the training, and those the plan predicted for the final phase.
    trained: u64,
    planned: u64,
    /// Seconds and evaluations of the final phase so far.
    seconds: f64,
    done: u64,
}

impl Stepper for FinalSteps<'_> {
    fn size(&mut self, _: &Pursuit, _: &mut Prior, _: f64) -> (u64, u64) {
        (self.least, self.chunk)
    }

    fn draw(&mut self, step: Step, _: &mut Pursuit, prior: &mut Prior) -> Result<Iteration> {
        let t = Instant::now();
        let (f, sampler, rng, comm) = (self.f, self.sampler, &mut *self.rng, self.comm);
        let acc = &mut self.acc;
        let iteration = match self.latent.as_mut() {
            Some(latent) => {
                let observe = &mut |w: &[f64]| acc.observe(w);
                latent.iteration(sampler, f, step.evals, rng, comm, observe)?
            }
            None => iid_iteration(comm, step.evals, f.components(), acc, |m| {
                weights(sampler, f, m, rng).map(|(_, w)| w)
            })?,
        };
        self.seconds += comm.max(t.elapsed().as_secs_f64());
        self.done += iteration.evals;
        prior.seconds_per_eval = self.seconds / self.done as f64;
        Ok(iteration)
    }

    fn keep(&mut self, iteration: Iteration) -> Result<()> {
        self.acc.add(iteration)?;
        report(
            self.progress,
            self.trained + self.done,
            self.trained + self.planned.max(self.done),
            "nis: estimating to the target",
        );
        Ok(())
    }
}
