//! The adaptive phase of [`NisIntegrator`]: batches drawn from the defensive mixture, one
//! on-policy training step per batch (and replayed batches off-policy), the tempered target's
//! annealing, the learning-rate schedule and the weights' moving average (Müller et al. 2019,
//! Sec. 3.2, the training of Alg. 1). Every batch also feeds, when asked, the training pieces
//! of the estimate (`reuse.rs`), the training-length rule (`training_length.rs`) and the memory
//! of training points (`memory.rs`).

use std::time::Instant;

use super::config::NisConfig;
use super::reuse::{ReplayBuffer, TrainingPieces};
use super::training_length::{BatchReport, TrainingLength};
use super::{draw, NisIntegrator};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::flow::mixture::{MixtureBatch, Record};
use crate::flow::Density;
use crate::integrate::moments::Moments;
use crate::integrate::{check_dim, evaluate, report, Integrand};
use crate::kernels::in_pool;
use crate::nn::ParamAverage;
use crate::train::Learner;

impl NisIntegrator {
    /// The adaptive phase: `evals` more evaluations in batches, one training step (or
    /// `steps_per_batch`) per batch. The first training of a new integrator sets the schedule —
    /// the learning rate decays over its steps to `learning_rate_end` of its start, and an
    /// untrained flow anneals its target from |f|^`anneal_from` — later ones continue Adam as it
    /// stands on the plain target.
    pub fn train(&mut self, f: &dyn Integrand, evals: u64) -> Result<()> {
        in_pool(|| self.train_keeping(f, evals, None))
    }

    /// [`NisIntegrator::train`], handing every batch to `pieces` (training reused in the
    /// estimate) when given. Trains from the last step's weights and leaves the average in the
    /// flow, also when a step fails.
    pub(super) fn train_keeping(
        &mut self,
        f: &dyn Integrand,
        evals: u64,
        pieces: Option<&mut TrainingPieces>,
    ) -> Result<()> {
        let batches = (evals / self.config.batch as u64) as usize;
        self.train_keeping_for(f, batches, pieces, None)
    }

    /// [`NisIntegrator::train_keeping`] for `batches` batches, or fewer when `length` says stop.
    pub(super) fn train_keeping_for(
        &mut self,
        f: &dyn Integrand,
        batches: usize,
        pieces: Option<&mut TrainingPieces>,
        length: Option<&mut TrainingLength>,
    ) -> Result<()> {
        if let Some(a) = &self.average {
            a.resume(&mut [self.sampler.density.params_mut()]);
        }
        let trained = self.train_steps(f, batches, pieces, length);
        if let Some(a) = &mut self.average {
            a.use_average(&mut [self.sampler.density.params_mut()]);
        }
        trained
    }

    /// The batches and steps of [`NisIntegrator::train_keeping_for`]: `steps` batches, or fewer
    /// when `length` (integrating to a target) says stop.
    fn train_steps(
        &mut self,
        f: &dyn Integrand,
        steps: usize,
        mut pieces: Option<&mut TrainingPieces>,
        mut length: Option<&mut TrainingLength>,
    ) -> Result<()> {
        let share = self.training_share(f)?;
        let (k, batch) = (f.components(), self.config.batch);
        if !self.scheduled {
            self.schedule(steps)?;
        }
        // The tempered target rises to |f| over the first half of a first training, or at the
        // pace the rule sets when it decides the length (then the average restarts at β = 1).
        let anneal = (self.trained_evals == 0 && steps > 1).then_some(steps as f64 / 2.0);
        let evals = (steps * batch) as u64;
        let mut replay = ReplayBuffer::new(self.config.replay_batches);
        // A training its rule paused and resumes keeps the points of the batches before.
        if length.as_deref().is_none_or(|rule| rule.batches() == 0) {
            self.memory.clear();
        }
        let mut done = 0;
        for step in 0..steps {
            let beta = self.batch_beta(length.as_deref(), anneal, step);
            let started = Instant::now();
            self.learner.set_temperature(beta);
            let (b, fx, [sampled_in, drawn_in]) =
                self.draw_batch(f, share, step, pieces.as_deref_mut(), started)?;
            let target = self.config.train_on.target(&fx, k);
            // What the training-length rule reads of the batch.
            let measured = length
                .is_some()
                .then(|| self.measure_batch(&b, &fx, k, &target, beta));
            self.trained_evals += batch as u64;
            done += batch as u64;
            self.learn_from(b, &target, &mut replay)?;
            report(&mut self.progress, done, evals, "nis: training");
            if let (Some(rule), Some((m, tempered_ess))) = (length.as_deref_mut(), measured) {
                let times = [
                    drawn_in,
                    started.elapsed().as_secs_f64(),
                    drawn_in - sampled_in,
                ];
                if !rule.go_on(batch_report(&m, times, batch, tempered_ess, &self.comm)) {
                    break;
                }
            }
        }
        Ok(())
    }

    /// This rank's share of every training batch, after checking that `f` fits the flow and
    /// the batch can be shared by the ranks (the steps are the whole batch's).
    fn training_share(&self, f: &dyn Integrand) -> Result<usize> {
        check_dim(f, self.flow().dim())?;
        self.config.train_on.check(f.components())?;
        let batch = self.config.batch;
        if batch < self.comm.size() {
            return Err(Error::Config(format!(
                "a batch of {batch} points cannot be shared by {} ranks",
                self.comm.size()
            )));
        }
        Ok(self.comm.share(batch as u64) as usize)
    }

    /// The tempered target's exponent β for batch `step`: the rule's when it decides the length,
    /// else the first training's annealing over `anneal` batches, else 1. When the rule has just
    /// ended its annealing, the weights' average restarts from the flow as it stands.
    fn batch_beta(
        &mut self,
        length: Option<&TrainingLength>,
        anneal: Option<f64>,
        step: usize,
    ) -> f64 {
        let beta = match (length, anneal) {
            (Some(rule), _) => rule.beta(),
            (None, Some(span)) => anneal_beta(&self.config, step, span),
            (None, None) => 1.0,
        };
        if length.is_some_and(|rule| rule.just_annealed()) {
            if let Some(a) = &mut self.average {
                *a = ParamAverage::new(a.decay(), &[self.sampler.density.params()]);
            }
        }
        beta
    }

    /// Draws this rank's `share` of training batch `step` and evaluates `f` on it; the batch
    /// feeds the memory of training points and, when given, `pieces`. Returns the batch, f at its
    /// points, and the seconds since `started` when its points were drawn and when evaluated.
    fn draw_batch(
        &mut self,
        f: &dyn Integrand,
        share: usize,
        step: usize,
        pieces: Option<&mut TrainingPieces>,
        started: Instant,
    ) -> Result<(MixtureBatch, Vec<f64>, [f64; 2])> {
        let (dim, k) = (self.flow().dim(), f.components());
        // The flow's latents are the first numbers of the stream (`Flow::sample`): a copy of
        // it redraws them for the prediction of the stratified final phase.
        let latent_rng = pieces
            .as_deref()
            .is_some_and(TrainingPieces::needs_latents)
            .then(|| self.streams.train.clone());
        // Training sees q's share only (on-policy), so only its pass keeps a tape.
        let drawn = draw(
            &self.sampler,
            share,
            &mut self.streams.train,
            Record::DensityShare,
        );
        let sampled_in = started.elapsed().as_secs_f64();
        // The failure flag of the batch: an error on any rank stops every rank here.
        let (b, fx) = self
            .comm
            .check(drawn.and_then(|(b, x64)| Ok((b, evaluate(f, &x64, dim)?))))?;
        let drawn_in = started.elapsed().as_secs_f64();
        self.memory
            .observe(&b.x, &b.log_q_mix, &fx, k, &mut self.streams.memory);
        if let Some(p) = pieces {
            let z = latent_rng.map_or_else(Vec::new, |mut rng| {
                crate::flow::uniform_latents(b.density_part.len() * dim, &mut rng)
            });
            p.observe(step, &b, &z, &fx, &self.comm);
        }
        Ok((b, fx, [sampled_in, drawn_in]))
    }

    /// What the training-length rule reads of batch `b` (over all ranks): the moments of its
    /// weights f/q_mix (`k` components each), and the effective sample size of its weights for the tempered
    /// `target` |f|^`beta` (1 without tempering).
    fn measure_batch(
        &self,
        b: &MixtureBatch,
        fx: &[f64],
        k: usize,
        target: &[f64],
        beta: f64,
    ) -> (Moments, f64) {
        let mut m = Moments::new(k);
        m.add(&super::reuse::batch_weights(b, fx, k));
        let m = m.across(&self.comm);
        let tempered_ess = if beta < 1.0 {
            tempered_ess(target, &b.log_q_mix, beta, &self.comm)
        } else {
            1.0
        };
        (m, tempered_ess)
    }

    /// The learning of one batch `b` with training values `target`: the on-policy step (and
    /// `steps_per_batch` − 1 more on the same points), the replayed batches off-policy, the
    /// weights' average; then `b`'s flow share joins `replay`. A batch whose flow share saw
    /// nothing on any rank teaches nothing and is skipped.
    fn learn_from(
        &mut self,
        b: MixtureBatch,
        target: &[f64],
        replay: &mut ReplayBuffer,
    ) -> Result<()> {
        let n_f = b.density_part.len();
        let flow = &mut self.sampler.density;
        if self.comm.any(target[..n_f].iter().any(|v| *v != 0.0)) {
            self.learner
                .step_on_policy(flow, &b.density_part, &target[..n_f])?;
            for _ in 1..self.config.steps_per_batch {
                self.learner.step(
                    flow,
                    &b.density_part.x,
                    None,
                    &target[..n_f],
                    &b.density_part.log_q,
                )?;
            }
        }
        // Earlier batches replayed off-policy (their points keep the density that drew them).
        for _ in 0..self.config.replay_steps {
            if let Some(r) = replay.next() {
                self.learner.step(flow, &r.x, None, &r.target, &r.log_q)?;
            }
        }
        if let Some(a) = &mut self.average {
            a.add(&[self.sampler.density.params()]);
        }
        if self.comm.any(target[..n_f].iter().any(|v| *v != 0.0)) {
            replay.push(
                b.density_part.x,
                target[..n_f].to_vec(),
                b.density_part.log_q,
            );
        }
        Ok(())
    }

    /// Sets the learning-rate schedule and the weights' average over the `steps` training batches
    /// of this integrator's first training.
    fn schedule(&mut self, steps: usize) -> Result<()> {
        // The rate decays over the Adam steps of the on-policy and the replayed batches (a
        // loaded integrator's first training starts an average of its own).
        let adam_steps = steps * (1 + self.config.replay_steps);
        let params = self.sampler.density.params();
        self.average = schedule(&self.config, &mut self.learner, adam_steps, steps, params)?;
        self.scheduled = true;
        Ok(())
    }
}

/// What the training-length rule reads of a batch of `batch` points: the moments `m` of its
/// weights over all ranks, and `times` (drawn, done, in the integrand) in seconds since it
/// started, taken as the slowest rank saw them so that every rank decides alike.
fn batch_report(
    m: &Moments,
    mut times: [f64; 3],
    batch: usize,
    tempered_ess: f64,
    comm: &Comm,
) -> BatchReport {
    comm.max_f64(&mut times);
    let (mean, cov) = m.mean_and_cov_of_mean();
    BatchReport {
        var_per_eval: cov[0] * m.n() as f64,
        estimate: mean[0],
        seconds_per_eval: times[0] / batch as f64,
        integrand_seconds_per_eval: times[2] / batch as f64,
        seconds: times[1],
        tempered_ess,
    }
}

/// The schedule of a first training of `batches` batches and `adam_steps` Adam steps under
/// `config`: the learning rate decays over the steps to `learning_rate_end` of its start, and
/// the weights' average (from `params`, when `average_span` > 0) spans its share of the batches.
pub(crate) fn schedule(
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
pub(crate) fn anneal_beta(config: &NisConfig, step: usize, span: f64) -> f64 {
    let t = (step as f64 / span).min(1.0);
    config.anneal_from + t * (1.0 - config.anneal_from)
}

/// The ESS fraction (Σw)²/(n·Σw²) of the tempered weights w = |t|^β/q_mix of a batch over all
/// ranks (`target` the training values t, `log_q_mix` the mixture's ln q_mix of each point); 1 for
/// a batch where t is zero everywhere.
fn tempered_ess(target: &[f64], log_q_mix: &[f64], beta: f64, comm: &crate::comm::Comm) -> f64 {
    let log_w: Vec<f64> = target
        .iter()
        .zip(log_q_mix)
        .map(|(t, l)| {
            if *t == 0.0 {
                f64::NEG_INFINITY
            } else {
                beta * t.abs().ln() - l
            }
        })
        .collect();
    // Scaled by the largest weight on any rank, so that no sum overflows.
    let mut top = [log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max)];
    comm.max_f64(&mut top);
    if top[0] == f64::NEG_INFINITY {
        return 1.0;
    }
    let mut sums = [0.0, 0.0, log_w.len() as f64];
    for l in &log_w {
        let w = (l - top[0]).exp();
        sums[0] += w;
        sums[1] += w * w;
    }
    comm.sum_f64(&mut sums);
    sums[0] * sums[0] / (sums[2] * sums[1])
}
