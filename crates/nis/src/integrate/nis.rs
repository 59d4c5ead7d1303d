//! Neural importance sampling (Müller et al. 2019, Sec. 3): a flow learns |f|/∫|f| from the
//! integrand's own values during an adaptive phase, then is frozen and sampled for the estimate.
//!
//! Sampling uses a defensive mixture q_mix = λ·uniform + (1 − λ)·q with fixed counts per batch
//! (the balance heuristic of multiple importance sampling): weights f/q_mix are bounded by f/λ
//! wherever the flow has not (yet) put mass, which keeps error bars honest when the flow misses
//! a sliver of the integrand. Training sees only the flow's share of each batch, on-policy.
//! Early training optionally targets the tempered |f|^β with β rising to 1 (annealing), so that a
//! flow which has only seen the far tails of several modes is pulled toward all of them.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use super::{check_dim, evaluate, Accumulator, Integrand, IntegrationResult, Progress};
use crate::error::{Error, Result};
use crate::flow::mixture::{self, MixtureBatch};
use crate::flow::{Density, Flow, FlowConfig};
use crate::loss::Loss;
use crate::nn::AdamConfig;
use crate::train::Trainer;
use crate::transform::TransformKind;

/// Settings of the NIS integrator. The defaults work across the built-in suite untuned.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NisConfig {
    /// The flow (its `dim` is set from the integrand).
    pub flow: FlowConfig,
    pub loss: Loss,
    /// Samples per adaptive iteration.
    pub batch: usize,
    /// Adam steps per batch: the first on-policy, the others reuse the batch off-policy (its
    /// points keep the density they were drawn from), trading compute for evaluations.
    pub steps_per_batch: usize,
    /// Share of the evaluation budget spent in the adaptive phase.
    pub train_fraction: f64,
    pub adam: AdamConfig,
    /// The learning rate decays exponentially over the adaptive phase to this fraction of its
    /// initial value (1: constant; Adam's own `decay` is then set from the number of steps).
    pub learning_rate_end: f32,
    /// Share λ of uniform points in every batch (the defensive mixture).
    pub uniform_fraction: f64,
    /// Initial exponent β of the tempered target |f|^β; rises linearly to 1 over the first half
    /// of training (1: no annealing).
    pub anneal_from: f64,
    /// Iterations of the final phase (for χ²/dof).
    pub final_iterations: usize,
}

impl Default for NisConfig {
    fn default() -> Self {
        NisConfig {
            flow: FlowConfig {
                transform: TransformKind::Quadratic { bins: 16 },
                hidden_layers: 2,
                hidden_width: 32,
                blob_bins: 16,
                ..FlowConfig::default()
            },
            loss: Loss::Kl,
            batch: 1024,
            steps_per_batch: 1,
            train_fraction: 0.4,
            adam: AdamConfig {
                learning_rate: 5e-3,
                clip_norm: Some(10.0),
                ..Default::default()
            },
            learning_rate_end: 0.1,
            uniform_fraction: 0.002,
            anneal_from: 0.1,
            final_iterations: 10,
        }
    }
}

impl NisConfig {
    fn validate(&self) -> Result<()> {
        let ok = self.batch >= 2
            && self.steps_per_batch >= 1
            && (0.0..1.0).contains(&self.train_fraction)
            && (0.0..1.0).contains(&self.uniform_fraction)
            && self.anneal_from > 0.0
            && self.anneal_from <= 1.0
            && self.final_iterations >= 1
            && self.learning_rate_end > 0.0
            && self.learning_rate_end <= 1.0;
        if ok {
            Ok(())
        } else {
            Err(Error::Config(format!("invalid NIS settings: {self:?}")))
        }
    }
}

/// A flow-based integrator: train it, then estimate with it (again and again, or after saving).
pub struct NisIntegrator {
    pub config: NisConfig,
    trainer: Trainer,
    /// Evaluations spent training so far.
    pub trained_evals: u64,
}

impl NisIntegrator {
    /// A new (untrained: uniform) integrator in `dim` dimensions.
    pub fn new(dim: usize, config: NisConfig) -> Result<NisIntegrator> {
        config.validate()?;
        let flow = Flow::new(FlowConfig {
            dim,
            ..config.flow.clone()
        })?;
        let trainer = Trainer::new(flow, config.loss, config.adam)?;
        Ok(NisIntegrator {
            config,
            trainer,
            trained_evals: 0,
        })
    }

    /// The flow.
    pub fn flow(&self) -> &Flow {
        self.trainer.flow()
    }

    fn draw(&self, n: usize, rng: &mut Pcg64Mcg, for_training: bool) -> Result<MixtureBatch> {
        let lambda = self.config.uniform_fraction;
        mixture::draw(self.trainer.flow(), lambda, n, rng, for_training)
    }

    /// The adaptive phase: `evals` evaluations in batches, one training step per batch.
    pub fn train(
        &mut self,
        f: &dyn Integrand,
        evals: u64,
        seed: u64,
        progress: Progress,
    ) -> Result<()> {
        let dim = self.flow().dim();
        check_dim(f, dim)?;
        let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 0x7261_696e);
        let batch = self.config.batch;
        let steps = (evals / batch as u64) as usize;
        let decay = self
            .config
            .learning_rate_end
            .powf(1.0 / steps.max(1) as f32);
        self.trainer
            .set_learning_rate_decay(decay * self.config.adam.decay)?;
        for step in 0..steps {
            let beta = if steps > 1 {
                let t = (2.0 * step as f64 / steps as f64).min(1.0);
                self.config.anneal_from + t * (1.0 - self.config.anneal_from)
            } else {
                1.0
            };
            self.trainer.set_temperature(beta);
            let b = self.draw(batch, &mut rng, true)?;
            let x64: Vec<f64> = b.x.iter().map(|&v| v as f64).collect();
            let fx = evaluate(f, &x64, dim)?;
            self.trained_evals += batch as u64;
            let n_f = b.density_part.len();
            // Skip the step when the flow's share saw nothing: there is no direction to learn.
            if fx[..n_f].iter().any(|v| *v != 0.0) {
                self.trainer.step_on_policy(&b.density_part, &fx[..n_f])?;
                for _ in 1..self.config.steps_per_batch {
                    self.trainer.step(
                        &b.density_part.x,
                        None,
                        &fx[..n_f],
                        &b.density_part.log_q,
                    )?;
                }
            }
            progress(self.trained_evals, evals, "nis: training");
        }
        Ok(())
    }

    /// The final phase: the flow frozen, `evals` evaluations in `final_iterations` iterations.
    pub fn estimate(
        &self,
        f: &dyn Integrand,
        evals: u64,
        seed: u64,
        progress: Progress,
    ) -> Result<Accumulator> {
        let dim = self.flow().dim();
        check_dim(f, dim)?;
        let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 0x6573_7469);
        let iters = self.config.final_iterations.clamp(1, evals.max(1) as usize);
        let mut acc = Accumulator::default();
        let mut done = 0u64;
        for it in 0..iters {
            let n = ((evals * (it as u64 + 1)) / iters as u64 - done).max(2) as usize;
            // Draw in pieces of bounded memory, pooled into one iteration.
            let mut w = Vec::with_capacity(n);
            while w.len() < n {
                let m = (n - w.len()).min(1 << 16);
                w.extend(self.weighted_batch(f, m, &mut rng)?.1);
            }
            acc.add_weights(&w);
            done += n as u64;
            progress(
                self.trained_evals + done,
                self.trained_evals + evals,
                "nis: estimating",
            );
        }
        Ok(acc)
    }

    /// `n` points of the frozen sampler and their weights f/q_mix.
    pub fn weighted_batch(
        &self,
        f: &dyn Integrand,
        n: usize,
        rng: &mut Pcg64Mcg,
    ) -> Result<(Vec<f64>, Vec<f64>)> {
        let dim = self.flow().dim();
        check_dim(f, dim)?;
        let b = self.draw(n, rng, false)?;
        let x64: Vec<f64> = b.x.iter().map(|&v| v as f64).collect();
        let fx = evaluate(f, &x64, dim)?;
        let w = fx
            .iter()
            .zip(&b.log_q_mix)
            .map(|(v, l)| v * (-l).exp())
            .collect();
        Ok((x64, w))
    }

    /// Saves the trained flow with the integrator's settings beside it (atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        let mut meta = HashMap::new();
        meta.insert(
            "nis_integrator".into(),
            serde_json::to_string(&self.config).expect("serialisable"),
        );
        meta.insert("trained_evals".into(), self.trained_evals.to_string());
        crate::io::save_with(self.flow(), path, &meta)
    }

    /// Loads an integrator saved by [`NisIntegrator::save`].
    pub fn load(path: &Path) -> Result<NisIntegrator> {
        let (flow, meta) = crate::io::load_with(path)?;
        let bad = |reason: &str| Error::Model {
            path: path.to_path_buf(),
            reason: reason.into(),
        };
        let config: NisConfig = serde_json::from_str(
            meta.get("nis_integrator")
                .ok_or_else(|| bad("not an integrator file (no settings)"))?,
        )
        .map_err(|e| bad(&format!("integrator settings: {e}")))?;
        let trained_evals = meta
            .get("trained_evals")
            .and_then(|s| s.parse().ok())
            .unwrap_or(0);
        let trainer = Trainer::new(flow, config.loss, config.adam)?;
        Ok(NisIntegrator {
            config,
            trainer,
            trained_evals,
        })
    }
}

/// Trains a fresh integrator on `train_fraction` of `evals` and estimates with the rest.
pub fn integrate(
    f: &dyn Integrand,
    dim: usize,
    config: &NisConfig,
    evals: u64,
    seed: u64,
    progress: Progress,
) -> Result<(IntegrationResult, NisIntegrator)> {
    let started = Instant::now();
    let mut nis = NisIntegrator::new(dim, config.clone())?;
    let train =
        ((evals as f64 * config.train_fraction) as u64 / config.batch as u64) * config.batch as u64;
    nis.train(f, train, seed, progress)?;
    let acc = nis.estimate(f, evals - nis.trained_evals, seed, progress)?;
    let n_eval = nis.trained_evals + acc.iterations.iter().map(|i| i.2).sum::<u64>();
    Ok((acc.finish(n_eval, started, Vec::new()), nis))
}
