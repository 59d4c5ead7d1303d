//! Training a density from Monte Carlo samples: weights from [`crate::loss`], the gradient from
//! [`Density::backward`], the update from [`Adam`] — one step, [`descend`], shared by every
//! trainer (the integrator's [`Trainer`], density estimation on images, the neural path guide).
//!
//! ```
//! use nis::{flow::{Density, Flow, FlowConfig}, loss::Loss, nn::AdamConfig, train::Trainer};
//! use rand::SeedableRng;
//! let flow = Flow::new(FlowConfig::new(2)).unwrap();
//! let mut trainer = Trainer::new(flow, Loss::Kl, AdamConfig::default()).unwrap();
//! let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(0);
//! for _ in 0..3 {
//!     let s = trainer.flow().sample_for_training(1024, None, &mut rng).unwrap();
//!     let f: Vec<f64> = s.x.chunks(2).map(|p| (-(p[0] - 0.3).powi(2) * 50.0).exp() as f64).collect();
//!     trainer.step_on_policy(&s, &f).unwrap();
//! }
//! ```

use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::flow::{Density, Flow, Samples, Tape};
use crate::loss::{self, Loss};
use crate::nn::{Adam, AdamConfig};

/// One training step: the gradient of L = −Σ_i w_i ln q(x_i; θ) for the points whose pass
/// recorded `tape`, then an Adam update of the density's parameters. Returns the gradient's norm
/// before clipping.
pub fn descend(
    density: &mut (impl Density + ?Sized),
    adam: &mut Adam,
    tape: &Tape,
    weights: &[f32],
) -> Result<f64> {
    let grad = density.backward(tape, weights)?;
    adam.step(density.params_mut(), &grad)
}

/// The optimiser, the loss and the target's temperature: what takes training steps on a density
/// it is handed (the integrator's flow inside its defensive mixture; [`Trainer`] owns its own).
///
/// Trained data-parallel over the ranks of a [`Comm`] ([`Learner::set_comm`]), each step's batch
/// is the union of the ranks' shares: the loss weights are normalised over all of them and the
/// gradients summed in the communicator's fixed order before every rank takes the same Adam step,
/// so every rank holds the same parameters after every step.
#[derive(Clone, Debug)]
pub struct Learner {
    adam: Adam,
    loss: Loss,
    /// Exponent of the tempered target |f|^β (1: the integrand itself).
    beta: f64,
    /// The ranks that share each batch (one process by default).
    comm: Comm,
}

/// A density (by default the coupling flow) with its [`Learner`].
#[derive(Clone, Debug)]
pub struct Trainer<D = Flow> {
    flow: D,
    learner: Learner,
}

/// What one step saw.
#[derive(Clone, Copy, Debug)]
pub struct StepStats {
    /// Batch estimate of ∫|f| (0 for NLL).
    pub integral: f64,
    /// Batch estimate of Var(|f|/q_s)/F² (0 for NLL).
    pub rel_var: f64,
    /// Mean −ln q over the batch (the NLL in nats for density estimation).
    pub mean_nll: f64,
    /// Gradient norm before clipping.
    pub grad_norm: f64,
}

impl Learner {
    /// A learner for densities of `param_count` parameters.
    pub fn new(param_count: usize, loss: Loss, adam: AdamConfig) -> Result<Learner> {
        Ok(Learner {
            adam: Adam::new(adam, param_count)?,
            loss,
            beta: 1.0,
            comm: Comm::default(),
        })
    }

    /// Trains on batches split over the ranks of `comm` from now on: every rank passes its share
    /// of each batch to the steps, and all ranks must step together.
    pub fn set_comm(&mut self, comm: Comm) {
        self.comm = comm;
    }

    /// The loss.
    pub fn loss(&self) -> Loss {
        self.loss
    }

    /// Trains on the tempered target |f|^β from now on (β in (0, 1]).
    pub fn set_temperature(&mut self, beta: f64) {
        self.beta = beta.clamp(1e-3, 1.0);
    }

    /// Sets Adam's per-step learning-rate decay factor (the rate after t steps is lr·decay^t).
    pub fn set_learning_rate_decay(&mut self, decay: f32) -> Result<()> {
        let config = crate::nn::AdamConfig {
            decay,
            ..self.adam.config
        };
        config.validate()?;
        self.adam.config = config;
        Ok(())
    }

    /// The optimiser.
    pub fn adam(&self) -> &Adam {
        &self.adam
    }

    /// On-policy step of `density`: `samples` were drawn from it as it stands with
    /// [`Density::sample_for_training`], `f` holds the integrand at them. Reuses the sampling
    /// pass's conditioner outputs (they depend only on x_A) instead of recomputing them.
    pub fn step_on_policy(
        &mut self,
        density: &mut (impl Density + ?Sized),
        samples: &Samples,
        f: &[f64],
    ) -> Result<StepStats> {
        let tape = samples.tape.as_ref().ok_or_else(|| {
            Error::Config("on-policy step needs samples drawn with sample_for_training".into())
        })?;
        let (log_q, beta) = (&samples.log_q, self.beta);
        let w = loss::weights_across(&self.comm, self.loss, f, log_q, log_q, beta)?;
        self.apply(density, tape, &w, &samples.log_q)
    }

    /// Off-policy step of `density` on points `x` (`n × D`) drawn from a proposal with
    /// log-density `log_q_sample` (zeros for uniform samples), with integrand values `f` (ignored
    /// for NLL). Recomputes the density's pass at `x`.
    pub fn step(
        &mut self,
        density: &mut (impl Density + ?Sized),
        x: &[f32],
        ctx: Option<&[f32]>,
        f: &[f64],
        log_q_sample: &[f64],
    ) -> Result<StepStats> {
        let eval = density.log_density_for_training(x, ctx)?;
        let (log_q, beta) = (&eval.log_q, self.beta);
        let w = loss::weights_across(&self.comm, self.loss, f, log_q, log_q_sample, beta)?;
        self.apply(density, &eval.tape, &w, &eval.log_q)
    }

    fn apply(
        &mut self,
        density: &mut (impl Density + ?Sized),
        tape: &Tape,
        w: &loss::Weights,
        log_q: &[f64],
    ) -> Result<StepStats> {
        // `descend`, with the ranks' gradients summed between the backward pass and Adam.
        let mut grad = density.backward(tape, &w.w)?;
        self.comm.sum_f32(&mut grad);
        let grad_norm = self.adam.step(density.params_mut(), &grad)?;
        let mean_nll = -log_q.iter().sum::<f64>() / log_q.len().max(1) as f64;
        Ok(StepStats {
            integral: w.integral,
            rel_var: w.rel_var,
            mean_nll,
            grad_norm,
        })
    }
}

impl<D: Density> Trainer<D> {
    /// A trainer for `flow`.
    pub fn new(flow: D, loss: Loss, adam: AdamConfig) -> Result<Trainer<D>> {
        let learner = Learner::new(flow.param_count(), loss, adam)?;
        Ok(Trainer { flow, learner })
    }

    /// Trains on batches split over the ranks of `comm` from now on (see [`Learner::set_comm`]).
    pub fn set_comm(&mut self, comm: Comm) {
        self.learner.set_comm(comm);
    }

    /// The density being trained.
    pub fn flow(&self) -> &D {
        &self.flow
    }

    /// The density's parameters, to be changed between steps (Adam's state stays as it is).
    pub fn params_mut(&mut self) -> &mut [f32] {
        self.flow.params_mut()
    }

    /// Gives the trained density back.
    pub fn into_flow(self) -> D {
        self.flow
    }

    /// The loss.
    pub fn loss(&self) -> Loss {
        self.learner.loss()
    }

    /// Trains on the tempered target |f|^β from now on (β in (0, 1]).
    pub fn set_temperature(&mut self, beta: f64) {
        self.learner.set_temperature(beta);
    }

    /// Sets Adam's per-step learning-rate decay factor (the rate after t steps is lr·decay^t).
    pub fn set_learning_rate_decay(&mut self, decay: f32) -> Result<()> {
        self.learner.set_learning_rate_decay(decay)
    }

    /// The optimiser.
    pub fn adam(&self) -> &Adam {
        self.learner.adam()
    }

    /// On-policy step: `samples` were drawn from the current flow with
    /// [`Density::sample_for_training`] (see [`Learner::step_on_policy`]).
    pub fn step_on_policy(&mut self, samples: &Samples, f: &[f64]) -> Result<StepStats> {
        self.learner.step_on_policy(&mut self.flow, samples, f)
    }

    /// Off-policy step on points `x` (see [`Learner::step`]).
    pub fn step(
        &mut self,
        x: &[f32],
        ctx: Option<&[f32]>,
        f: &[f64],
        log_q_sample: &[f64],
    ) -> Result<StepStats> {
        self.learner.step(&mut self.flow, x, ctx, f, log_q_sample)
    }
}
