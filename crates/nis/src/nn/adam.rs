//! Adam (Kingma & Ba 2014) over a flat parameter vector, with optional clipping of the global
//! gradient norm and exponential learning-rate decay.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::kernels::{elementwise, in_parallel_blocks, PAR_BLOCK};

/// Optimiser settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdamConfig {
    pub learning_rate: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Rescale the gradient when its Euclidean norm exceeds this (none when `None`).
    pub clip_norm: Option<f32>,
    /// Learning rate after t steps: `learning_rate · decay^t`.
    pub decay: f32,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            learning_rate: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            clip_norm: None,
            decay: 1.0,
        }
    }
}

impl AdamConfig {
    /// Rejects settings Adam cannot run with.
    pub fn validate(&self) -> Result<()> {
        let ok = self.learning_rate > 0.0
            && self.learning_rate.is_finite()
            && (0.0..1.0).contains(&self.beta1)
            && (0.0..1.0).contains(&self.beta2)
            && self.eps > 0.0
            && self.decay > 0.0
            && self.decay <= 1.0
            && self.clip_norm.is_none_or(|c| c > 0.0 && c.is_finite());
        if ok {
            Ok(())
        } else {
            Err(Error::Config(format!("invalid Adam settings: {self:?}")))
        }
    }
}

/// Adam's state: first and second moments and the step count.
#[derive(Clone, Debug)]
pub struct Adam {
    pub config: AdamConfig,
    m: Vec<f32>,
    v: Vec<f32>,
    step: u64,
}

impl Adam {
    /// A fresh optimiser for `n` parameters.
    pub fn new(config: AdamConfig, n: usize) -> Result<Adam> {
        config.validate()?;
        Ok(Adam {
            config,
            m: vec![0.0; n],
            v: vec![0.0; n],
            step: 0,
        })
    }

    /// The moments (m, v), for checkpoints.
    pub fn moments(&self) -> (&[f32], &[f32]) {
        (&self.m, &self.v)
    }

    /// An optimiser restored from a checkpoint: its moments and step count.
    pub fn from_state(config: AdamConfig, m: Vec<f32>, v: Vec<f32>, step: u64) -> Result<Adam> {
        config.validate()?;
        if m.len() != v.len() {
            return Err(Error::Dimension {
                what: "Adam moments",
                expected: m.len(),
                got: v.len(),
            });
        }
        Ok(Adam { config, m, v, step })
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.step
    }

    /// The learning rate the next step uses.
    pub fn learning_rate(&self) -> f32 {
        self.config.learning_rate * self.config.decay.powf(self.step as f32)
    }

    /// One update of `params` with gradient `grad`; returns the gradient's norm before clipping.
    pub fn step(&mut self, params: &mut [f32], grad: &[f32]) -> Result<f64> {
        if params.len() != self.m.len() || grad.len() != self.m.len() {
            return Err(Error::Dimension {
                what: "Adam parameters",
                expected: self.m.len(),
                got: grad.len().min(params.len()),
            });
        }
        // Per-block sums added in block order: the same bits serial or parallel.
        let sq: f64 = if in_parallel_blocks(grad.len()) {
            let parts: Vec<f64> = grad
                .par_chunks(PAR_BLOCK)
                .map(elementwise::sum_of_squares)
                .collect();
            parts.iter().sum()
        } else {
            grad.chunks(PAR_BLOCK)
                .map(elementwise::sum_of_squares)
                .sum()
        };
        let norm = sq.sqrt();
        if !norm.is_finite() {
            return Err(Error::NonFinite {
                what: "gradient norm",
                index: 0,
                value: norm,
            });
        }
        let scale = match self.config.clip_norm {
            Some(c) if norm > c as f64 => (c as f64 / norm) as f32,
            _ => 1.0,
        };
        let lr = self.learning_rate();
        self.step += 1;
        let t = self.step as i32;
        let c = &self.config;
        let lr_t = lr * (1.0 - c.beta2.powi(t)).sqrt() / (1.0 - c.beta1.powi(t));
        let step = elementwise::AdamStep {
            lr_t,
            beta1: c.beta1,
            beta2: c.beta2,
            eps: c.eps,
            grad_scale: scale,
        };
        if in_parallel_blocks(params.len()) {
            // Each parameter's update is independent: blocks in parallel, same bits. The
            // gradient was just summed on the pool's threads, and a serial update on the
            // calling thread would pull all of it across cores.
            params
                .par_chunks_mut(PAR_BLOCK)
                .zip(grad.par_chunks(PAR_BLOCK))
                .zip(self.m.par_chunks_mut(PAR_BLOCK))
                .zip(self.v.par_chunks_mut(PAR_BLOCK))
                .for_each(|(((p, g), m), v)| elementwise::adam(p, g, m, v, step));
        } else {
            elementwise::adam(params, grad, &mut self.m, &mut self.v, step);
        }
        Ok(norm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::tests::run_threads;

    #[test]
    fn adam_minimises_a_quadratic() {
        let mut p = vec![3.0f32, -2.0];
        let mut adam = Adam::new(
            AdamConfig {
                learning_rate: 0.1,
                ..Default::default()
            },
            2,
        )
        .unwrap();
        for _ in 0..500 {
            let g = vec![2.0 * p[0], 8.0 * p[1]];
            adam.step(&mut p, &g).unwrap();
        }
        assert!(p[0].abs() < 1e-2 && p[1].abs() < 1e-2, "{p:?}");
    }

    #[test]
    fn adam_first_step_moves_each_parameter_by_the_learning_rate() {
        // With bias correction, step one is lr·g/|g| per coordinate.
        let mut p = vec![1.0f32, 1.0];
        let mut adam = Adam::new(AdamConfig::default(), 2).unwrap();
        adam.step(&mut p, &[0.5, -3.0]).unwrap();
        assert!((p[0] - (1.0 - 1e-3)).abs() < 1e-6 && (p[1] - (1.0 + 1e-3)).abs() < 1e-6);
    }

    #[test]
    fn clipping_and_bad_settings() {
        assert!(Adam::new(
            AdamConfig {
                learning_rate: 0.0,
                ..Default::default()
            },
            1
        )
        .is_err());
        let mut adam = Adam::new(AdamConfig::default(), 2).unwrap();
        let mut p = vec![0.0; 2];
        assert!(adam.step(&mut p, &[f32::NAN, 0.0]).is_err());
        assert!(adam.step(&mut p, &[1.0]).is_err());
    }

    #[test]
    fn a_large_update_in_parallel_blocks_matches_the_serial_kernel_bit_for_bit() {
        // 2.5 blocks' worth of parameters, so the step runs in parallel; the reference is the
        // serial kernel with the clipping scale from the exact norm. The returned norm must
        // match the f64 norm to rounding, and the bits must not depend on the thread count.
        let n = 2 * PAR_BLOCK + PAR_BLOCK / 2;
        let grad: Vec<f32> = (0..n)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) * 0.01)
            .collect();
        let exact = grad
            .iter()
            .map(|&g| f64::from(g) * f64::from(g))
            .sum::<f64>()
            .sqrt();
        let config = AdamConfig {
            clip_norm: Some((exact / 2.0) as f32),
            ..Default::default()
        };
        let run = |threads: usize| {
            run_threads(threads, || {
                let mut adam = Adam::new(config, n).unwrap();
                let mut p = vec![0.5f32; n];
                let norm = adam.step(&mut p, &grad).unwrap();
                (p, norm)
            })
        };
        let (p1, norm) = run(1);
        assert!((norm - exact).abs() < 1e-12 * exact, "{norm} vs {exact}");
        assert_eq!(run(3).0, p1);
        let (mut p, mut m, mut v) = (vec![0.5f32; n], vec![0.0; n], vec![0.0; n]);
        let c = config;
        let step = elementwise::AdamStep {
            lr_t: c.learning_rate * (1.0 - c.beta2).sqrt() / (1.0 - c.beta1),
            beta1: c.beta1,
            beta2: c.beta2,
            eps: c.eps,
            grad_scale: (f64::from(c.clip_norm.unwrap()) / norm) as f32,
        };
        elementwise::adam(&mut p, &grad, &mut m, &mut v, step);
        assert_eq!(p, p1);
    }
}
