//! The one loop of a flow's training in integration: NIS's own ([`super::NisIntegrator::train`],
//! `training.rs`) and the shared flow's of the multi-channel parts (`multichannel/shared.rs`).
//! What a batch is (its points, its targets, its steps) is the caller's [`Batches`]; around the
//! batches the loop keeps the learning-rate schedule, set by the first training over its steps,
//! the tempered target |f|^β rising to |f| over the first half of a first training, and the
//! moving average of the weights, which the flow holds between trainings (Müller et al. 2019,
//! Sec. 3.2, the training of Alg. 1).

use super::config::NisConfig;
use crate::comm::Comm;
use crate::error::Result;
use crate::flow::{Density, Flow};
use crate::nn::ParamAverage;
use crate::train::Learner;

/// What a flow's training keeps between calls beside the flow: the optimiser (with the loss
/// and the temperature), whether the first training has set its schedule, and the weights'
/// moving average (`NisConfig::average_span`), set up with the schedule unless the span is 0.
pub(crate) struct FlowTraining {
    learner: Learner,
    scheduled: bool,
    average: Option<ParamAverage>,
}

/// A training's batches, as [`FlowTraining::train`] runs them.
pub(crate) trait Batches {
    /// The flow they train.
    fn flow(&mut self) -> &mut Flow;

    /// The tempered target's exponent β of the next batch, where the first training's annealing
    /// says `annealed`, and whether the weights' average restarts from the flow as it stands
    /// before it (a rule of the caller's own that has just ended its annealing).
    fn beta(&mut self, annealed: f64) -> (f64, bool) {
        (annealed, false)
    }

    /// Draws batch `step`, evaluates the integrand there and has `learner` step the flow on
    /// the target tempered by `beta`; `false` ends the training after it.
    fn learn(&mut self, step: usize, beta: f64, learner: &mut Learner) -> Result<bool>;
}

impl FlowTraining {
    /// A training that has not begun, with `learner`.
    pub(crate) fn new(learner: Learner) -> FlowTraining {
        FlowTraining {
            learner,
            scheduled: false,
            average: None,
        }
    }

    /// Sums the gradients over the ranks of `comm` from now on.
    pub(crate) fn set_comm(&mut self, comm: Comm) {
        self.learner.set_comm(comm);
    }

    /// The weights' average, once the first training has set it up.
    #[cfg(test)]
    pub(crate) fn average(&self) -> Option<&ParamAverage> {
        self.average.as_ref()
    }

    /// Trains on `steps` of `batches` (fewer when one says stop) under `config`: the first
    /// training sets the schedule over `adam_per_batch` Adam steps a batch, and an `untrained`
    /// flow anneals its target over the first half. Trains from the last step's weights and
    /// leaves the average in the flow, also when a batch fails.
    pub(crate) fn train(
        &mut self,
        config: &NisConfig,
        steps: usize,
        adam_per_batch: usize,
        untrained: bool,
        batches: &mut dyn Batches,
    ) -> Result<()> {
        if !self.scheduled {
            let params = batches.flow().params();
            let adam_steps = steps * adam_per_batch;
            self.average = schedule(config, &mut self.learner, adam_steps, steps, params)?;
            self.scheduled = true;
        }
        if let Some(a) = &self.average {
            a.resume(&mut [batches.flow().params_mut()]);
        }
        let anneal = (untrained && steps > 1).then_some(steps as f64 / 2.0);
        let trained = self.run(config, steps, anneal, batches);
        if let Some(a) = &mut self.average {
            a.use_average(&mut [batches.flow().params_mut()]);
        }
        trained
    }

    /// The batches of [`FlowTraining::train`], annealing over `anneal` batches when given.
    fn run(
        &mut self,
        config: &NisConfig,
        steps: usize,
        anneal: Option<f64>,
        batches: &mut dyn Batches,
    ) -> Result<()> {
        for step in 0..steps {
            let annealed = anneal.map_or(1.0, |span| anneal_beta(config, step, span));
            let (beta, restart) = batches.beta(annealed);
            if let Some(a) = self.average.as_mut().filter(|_| restart) {
                *a = ParamAverage::new(a.decay(), &[batches.flow().params()]);
            }
            self.learner.set_temperature(beta);
            let go_on = batches.learn(step, beta, &mut self.learner)?;
            if let Some(a) = &mut self.average {
                a.add(&[batches.flow().params()]);
            }
            if !go_on {
                break;
            }
        }
        Ok(())
    }
}

/// The schedule of a first training of `batches` batches and `adam_steps` Adam steps under
/// `config`: the learning rate decays over the steps to `learning_rate_end` of its start, and
/// the weights' average (from `params`, when `average_span` > 0) spans its share of the batches.
fn schedule(
    config: &NisConfig,
    learner: &mut Learner,
    adam_steps: usize,
    batches: usize,
    params: &[f32],
) -> Result<Option<ParamAverage>> {
    let decay = config
        .learning_rate_end
        .powf(1.0 / adam_steps.max(1) as f32);
    learner.set_learning_rate_decay(decay * config.adam.decay)?;
    Ok((config.average_span > 0.0).then(|| {
        let decay = ParamAverage::span_decay(config.average_span, batches);
        ParamAverage::new(decay, &[params])
    }))
}

/// The tempered target's exponent β at batch `step` of an annealing over `span` batches that
/// rises linearly from `config.anneal_from` to 1.
fn anneal_beta(config: &NisConfig, step: usize, span: f64) -> f64 {
    let t = (step as f64 / span).min(1.0);
    config.anneal_from + t * (1.0 - config.anneal_from)
}
