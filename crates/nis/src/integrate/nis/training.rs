//! The adaptive phase of [`NisIntegrator`]: batches drawn from the defensive mixture, one
//! on-policy training step per batch (and replayed batches off-policy), run by the one loop of
//! a flow's training (`flow_training.rs`: the schedule, the annealing, the weights' average;
//! Müller et al. 2019, Sec. 3.2, the training of Alg. 1). Every batch also feeds, when asked,
//! the training pieces of the estimate (`reuse.rs`), the training-length rule
//! (`training_length.rs`) and the memory of training points (`memory.rs`).

use std::time::Instant;

use super::config::NisConfig;
use super::flow_training::Batches;
use super::memory::TrainingMemory;
use super::reuse::{ReplayBuffer, TrainingPieces};
use super::training_length::{BatchReport, TrainingLength};
use super::{draw, NisIntegrator, Streams};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::flow::mixture::{DefensiveMixture, MixtureBatch, Record};
use crate::flow::{Density, Flow};
use crate::integrate::moments::Moments;
use crate::integrate::{check_dim, evaluate, report, Integrand, Progress};
use crate::kernels::in_pool;
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

    /// [`NisIntegrator::train_keeping`] for `batches` batches, or fewer when `length`
    /// (integrating to a target) says stop.
    pub(super) fn train_keeping_for(
        &mut self,
        f: &dyn Integrand,
        batches: usize,
        pieces: Option<&mut TrainingPieces>,
        length: Option<&mut TrainingLength>,
    ) -> Result<()> {
        let share = self.training_share(f)?;
        // A training its rule paused and resumes keeps the points of the batches before.
        if length.as_deref().is_none_or(|rule| rule.batches() == 0) {
            self.memory.clear();
        }
        let untrained = self.trained_evals == 0;
        let config = &self.config;
        let mut nis = NisBatches {
            f,
            share,
            config,
            sampler: &mut self.sampler,
            streams: &mut self.streams,
            memory: &mut self.memory,
            comm: &self.comm,
            progress: &mut self.progress,
            trained_evals: &mut self.trained_evals,
            pieces,
            length,
            replay: ReplayBuffer::new(config.replay_batches),
            done: 0,
            evals: (batches * config.batch) as u64,
        };
        let adam_per_batch = 1 + config.replay_steps;
        self.training
            .train(config, batches, adam_per_batch, untrained, &mut nis)
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
}

/// NIS's training batches: drawn from the defensive mixture, one on-policy step per batch (and
/// replayed batches off-policy); each feeds the memory of training points and, when given, the
/// training pieces and the training-length rule.
struct NisBatches<'a> {
    f: &'a dyn Integrand,
    /// This rank's share of a batch.
    share: usize,
    config: &'a NisConfig,
    sampler: &'a mut DefensiveMixture<Flow>,
    streams: &'a mut Streams,
    memory: &'a mut TrainingMemory,
    comm: &'a Comm,
    progress: &'a mut Option<Box<dyn Progress>>,
    trained_evals: &'a mut u64,
    pieces: Option<&'a mut TrainingPieces>,
    length: Option<&'a mut TrainingLength>,
    replay: ReplayBuffer,
    /// Evaluations of this training so far, and in all.
    done: u64,
    evals: u64,
}

impl Batches for NisBatches<'_> {
    fn flow(&mut self) -> &mut Flow {
        &mut self.sampler.density
    }

    /// The rule's β when it decides the length (the average restarts when it has just ended
    /// its annealing), else the first training's annealing.
    fn beta(&mut self, annealed: f64) -> (f64, bool) {
        match self.length.as_deref() {
            Some(rule) => (rule.beta(), rule.just_annealed()),
            None => (annealed, false),
        }
    }

    fn learn(&mut self, step: usize, beta: f64, learner: &mut Learner) -> Result<bool> {
        let started = Instant::now();
        let (k, batch) = (self.f.components(), self.config.batch);
        let (b, fx, [sampled_in, drawn_in]) = self.draw_batch(step, started)?;
        let target = self.config.train_on.target(&fx, k);
        // What the training-length rule reads of the batch.
        let measured = self
            .length
            .is_some()
            .then(|| self.measure_batch(&b, &fx, &target, beta));
        *self.trained_evals += batch as u64;
        self.done += batch as u64;
        self.learn_from(b, &target, learner)?;
        report(self.progress, self.done, self.evals, "nis: training");
        if let (Some(rule), Some((m, tempered_ess))) = (self.length.as_deref_mut(), measured) {
            let times = [
                drawn_in,
                started.elapsed().as_secs_f64(),
                drawn_in - sampled_in,
            ];
            return Ok(rule.go_on(batch_report(&m, times, batch, tempered_ess, self.comm)));
        }
        Ok(true)
    }
}

impl NisBatches<'_> {
    /// Draws this rank's share of training batch `step` and evaluates `f` on it; the batch
    /// feeds the memory of training points and, when given, the training pieces. Returns the
    /// batch, f at its points, and the seconds since `started` when its points were drawn and
    /// when evaluated.
    fn draw_batch(
        &mut self,
        step: usize,
        started: Instant,
    ) -> Result<(MixtureBatch, Vec<f64>, [f64; 2])> {
        let (dim, k) = (self.sampler.density.dim(), self.f.components());
        // The flow's latents are the first numbers of the stream (`Flow::sample`): a copy of
        // it redraws them for the prediction of the stratified final phase.
        let latent_rng = self
            .pieces
            .as_deref()
            .is_some_and(TrainingPieces::needs_latents)
            .then(|| self.streams.train.clone());
        // Training sees q's share only (on-policy), so only its pass keeps a tape.
        let drawn = draw(
            self.sampler,
            self.share,
            &mut self.streams.train,
            Record::DensityShare,
        );
        let sampled_in = started.elapsed().as_secs_f64();
        // The failure flag of the batch: an error on any rank stops every rank here.
        let f = self.f;
        let (b, fx) = self
            .comm
            .check(drawn.and_then(|(b, x64)| Ok((b, evaluate(f, &x64, dim)?))))?;
        let drawn_in = started.elapsed().as_secs_f64();
        self.memory
            .observe(&b.x, &b.log_q_mix, &fx, k, &mut self.streams.memory);
        if let Some(p) = self.pieces.as_deref_mut() {
            let z = latent_rng.map_or_else(Vec::new, |mut rng| {
                crate::flow::uniform_latents(b.density_part.len() * dim, &mut rng)
            });
            p.observe(step, &b, &z, &fx, self.comm);
        }
        Ok((b, fx, [sampled_in, drawn_in]))
    }

    /// What the training-length rule reads of batch `b` (over all ranks): the moments of its
    /// weights f/q_mix, and the effective sample size of its weights for the tempered `target`
    /// |f|^`beta` (1 without tempering).
    fn measure_batch(
        &self,
        b: &MixtureBatch,
        fx: &[f64],
        target: &[f64],
        beta: f64,
    ) -> (Moments, f64) {
        let k = self.f.components();
        let mut m = Moments::new(k);
        m.add(&super::reuse::batch_weights(b, fx, k));
        let m = m.across(self.comm);
        let tempered_ess = if beta < 1.0 {
            tempered_ess(target, &b.log_q_mix, beta, self.comm)
        } else {
            1.0
        };
        (m, tempered_ess)
    }

    /// The learning of one batch `b` with training values `target`: `learner`'s on-policy step
    /// (and `steps_per_batch` − 1 more on the same points), the replayed batches off-policy; then
    /// `b`'s flow share joins the replay buffer. A batch whose flow share saw nothing on any
    /// rank teaches nothing and is skipped.
    fn learn_from(&mut self, b: MixtureBatch, target: &[f64], learner: &mut Learner) -> Result<()> {
        let n_f = b.density_part.len();
        let flow = &mut self.sampler.density;
        if self.comm.any(target[..n_f].iter().any(|v| *v != 0.0)) {
            learner.step_on_policy(flow, &b.density_part, &target[..n_f])?;
            for _ in 1..self.config.steps_per_batch {
                learner.step(
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
            if let Some(r) = self.replay.next() {
                learner.step(flow, &r.x, None, &r.target, &r.log_q)?;
            }
        }
        if self.comm.any(target[..n_f].iter().any(|v| *v != 0.0)) {
            self.replay.push(
                b.density_part.x,
                target[..n_f].to_vec(),
                b.density_part.log_q,
            );
        }
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
