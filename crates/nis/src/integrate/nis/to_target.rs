//! NIS to a precision target ([`crate::integrate::Integrator::integrate_to`]): training whose
//! length the rule of [`super::training_length`] decides, then a final phase whose iterations a
//! [`Pursuit`] plans, each with its share fixed before it is drawn (`integrate::target`). The
//! training batches do not enter the estimate here (their shares would need the final phase's
//! size in advance); they predict it.

use std::time::Instant;

use super::race::Raced;
use super::stratified_latent::{FinalPlan, LatentStrata};
use super::training_length::{anneal_batches, TrainingLength, SETTLE_BATCHES};
use super::{draw, weights, NisIntegrator};
use crate::error::{Error, Result};
use crate::flow::mask::{default_layers, Masks};
use crate::flow::mixture::Record;
use crate::flow::Density;
use crate::integrate::estimate::iid_iteration;
use crate::integrate::target::{Prior, Pursuit};
use crate::integrate::{check_dim, report, Accumulator, Integrand, IntegrationResult, Target};

/// Training batches at most when integrating to a target (or twice the annealing's and the
/// settling's): the learning rate decays over them, and the rule usually stops well before.
const HORIZON_BATCHES: usize = 1000;

impl NisIntegrator {
    /// Whether a run to a target probes for a smooth integrand to switch to the codes
    /// ([`super::NisConfig::auto_masks`]): an untrained flow of binary masks, where the codes
    /// have fewer layers, annealed (the probe reads the tempered weights' ESS, 1 at β = 1).
    fn probes_masks(&self) -> bool {
        let flow = &self.config.flow;
        let dim = self.flow().dim();
        self.config.auto_masks
            && self.trained_evals == 0
            && self.config.anneal_from < 1.0
            && flow.masks == Masks::Binary
            && flow.couplings == 0
            && default_layers(dim, Masks::Codes) < default_layers(dim, Masks::Binary)
    }

    /// Replaces the flow, untrained, by one with the codes' masks (the same settings and seed
    /// otherwise), keeping the ranks, the progress display and the random streams.
    fn switch_to_codes(&mut self) -> Result<()> {
        let mut config = self.config.clone();
        config.flow.masks = Masks::Codes;
        let mut fresh = NisIntegrator::new(self.flow().dim(), config)?;
        fresh.comm = self.comm.clone();
        fresh.learner.set_comm(self.comm.clone());
        fresh.progress = self.progress.take();
        std::mem::swap(&mut fresh.streams, &mut self.streams);
        *self = fresh;
        Ok(())
    }

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
        let iters = self.config.final_iterations as u64;
        let least_final = FinalPlan::new(&self.config, self.flow().dim(), 0).least * iters;
        target.check("nis", least_train + least_final)
    }

    /// [`crate::integrate::Integrator::integrate_to`] for NIS.
    pub(super) fn run_to(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
    ) -> Result<IntegrationResult> {
        let started = Instant::now();
        let dim = self.flow().dim();
        check_dim(f, dim)?;
        self.config.train_on.check(f.components())?;
        self.check_target_plan(target)?;
        let batch = self.config.batch as u64;
        let iters = self.config.final_iterations as u64;
        let least_final = FinalPlan::new(&self.config, dim, 0).least * iters;
        let share = self.config.train_fraction;
        if let Some(seconds) = target.max_seconds {
            // One batch of the flow alone, from a copy of the stream: a limit below it can be
            // refused before the integrand is called.
            let t = Instant::now();
            draw(
                &self.sampler,
                batch as usize,
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
        }
        // Training batches within `share` of `evals`.
        let batches_in = |evals: u64| ((evals as f64 * share) as u64 / batch) as usize;
        let max_batches = batches_in(target.max_evals);
        let anneal = anneal_batches(dim);
        let horizon = HORIZON_BATCHES.max(2 * anneal + SETTLE_BATCHES);
        let max_seconds = target.max_seconds.map_or(f64::INFINITY, |s| s * share);
        // A flow trained before (loaded, or trained by hand) starts at β = 1.
        let beta_from = if self.trained_evals == 0 {
            self.config.anneal_from
        } else {
            1.0
        };
        let mut length = TrainingLength::new(
            *target,
            anneal,
            beta_from,
            max_batches.min(horizon),
            max_seconds,
        );
        let races = self.races();
        let probes = self.probes_masks();
        if races || probes {
            length.pause_after_probe();
        }
        let mut before = self.trained_evals;
        self.train_keeping_for(f, max_batches.min(horizon), None, Some(&mut length))?;
        // Evaluations spent and not used: VEGAS+'s when it loses the race, the probe's when the
        // flow starts afresh.
        let mut spent = 0;
        if length.paused() {
            if races {
                let nis_evals = self.trained_evals - before;
                match self.race(f, target, started, nis_evals, &length)? {
                    Raced::Won(result) => return Ok(*result),
                    Raced::Lost { evals } => spent += evals,
                }
            }
            let room = target.max_evals.saturating_sub(spent);
            let left = batches_in(room)
                .min(horizon)
                .saturating_sub(length.batches());
            let seconds_left = max_seconds - length.seconds();
            if probes && length.smooth() && length.room_to_restart(left, seconds_left) {
                // A smooth integrand: the codes' fewer layers learn it as well, in less time.
                // The probe's batches are spent, not used; training starts afresh.
                spent += self.trained_evals - before;
                self.switch_to_codes()?;
                before = self.trained_evals;
                length = TrainingLength::new(*target, anneal, beta_from, left, seconds_left);
            }
            if left > 0 {
                self.train_keeping_for(f, left, None, Some(&mut length))?;
            }
        }
        let trained = self.trained_evals - before + spent;
        let (var_per_eval, estimate, seconds_per_eval) =
            length.latest().expect("at least one batch trained");
        let mut prior = Prior {
            var_per_eval,
            estimate,
            seconds_per_eval,
        };
        // The final phase's layout (its latent grid) for the size the training predicts, within
        // the evaluations and the seconds left (its least iteration is half a planned one, so
        // a plan the time cannot pay for would overrun max_seconds by that much).
        let mut room = target.max_evals.saturating_sub(trained) as f64;
        if let Some(limit) = target.max_seconds {
            let elapsed = self.comm.max(started.elapsed().as_secs_f64());
            room = room.min((limit - elapsed).max(0.0) / seconds_per_eval.max(f64::MIN_POSITIVE));
        }
        let predicted = prior.evals_to(target, room);
        let plan = FinalPlan::new(&self.config, dim, (predicted as u64).max(least_final));
        let chunk = plan.evals / iters;
        let least = plan.least.max(chunk / 2);
        let k = f.components();
        let lambda = self.sampler.lambda();
        let train_on = self.config.train_on;
        let mut latent = plan
            .latent
            .map(|(strata, s)| LatentStrata::new(strata, s, lambda, k, train_on));
        let mut acc = Accumulator::new(plan.evals);
        acc.set_frozen_sampler();
        acc.set_training_variances(length.variances());
        let mut pursuit = Pursuit::new(*target, started, trained);
        let (mut seconds, mut done) = (0.0, 0u64);
        loop {
            let elapsed = pursuit.elapsed(&self.comm);
            let Some(step) = pursuit.next(prior, least, chunk, elapsed)? else {
                break;
            };
            let t = Instant::now();
            let rng = &mut self.streams.estimate;
            let iteration = match latent.as_mut() {
                Some(latent) => {
                    let observe = &mut |w: &[f64]| acc.observe(w);
                    latent.iteration(&self.sampler, f, step.evals, rng, &self.comm, observe)?
                }
                None => {
                    let sampler = &self.sampler;
                    iid_iteration(&self.comm, step.evals, k, &mut acc, |m| {
                        weights(sampler, f, m, rng).map(|(_, w)| w)
                    })?
                }
            };
            seconds += self.comm.max(t.elapsed().as_secs_f64());
            done += iteration.evals;
            prior.seconds_per_eval = seconds / done as f64;
            pursuit.record(step, &iteration);
            acc.add(iteration)?;
            report(
                &mut self.progress,
                trained + done,
                trained + plan.evals.max(done),
                "nis: estimating to the target",
            );
        }
        acc.reduce_tail(&self.comm);
        let mut result = acc.finish(Some(pursuit.shares()), trained + done, started);
        self.recall_training(&mut result)?;
        pursuit.finish(&mut result);
        Ok(result)
    }
}
