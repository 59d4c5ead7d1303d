//! An exponential moving average of parameters over optimiser steps (Polyak averaging with
//! exponential weights), bias-corrected as Adam's moments are: after `T` steps with iterates
//! `θ_1 … θ_T` it is `Σ_t (1 − β)·β^(T−t)·θ_t / (1 − β^T)`, so the first steps are not pulled
//! towards the zero it starts from. The decay may change between steps
//! ([`ParamAverage::set_decay`]): step `t` then enters with `(1 − β_t)·Π_{s>t} β_s`, and the
//! correction divides by `1 − Π_t β_t`, the sum of those weights. A network trained with a constant or slowly decaying rate on
//! noisy Monte Carlo gradients wanders around its optimum; the average sits closer to it.
//!
//! The owner keeps one set of parameters: during training the optimiser's iterates, between
//! trainings the average ([`ParamAverage::use_average`]), and back to the iterates before training
//! goes on ([`ParamAverage::resume`]), so averaging never changes how the network learns.

use rayon::prelude::*;

use crate::kernels::{in_parallel_blocks, PAR_BLOCK};

/// The moving average of one or more parameter vectors, taken as one concatenation.
#[derive(Clone, Debug)]
pub struct ParamAverage {
    decay: f32,
    /// Steps averaged so far.
    steps: i32,
    /// `Π_t β_t` over the steps so far: the average's weights sum to one minus it.
    decayed: f64,
    /// `Σ_t (1 − β_t)·Π_{s>t} β_s·θ_t`.
    sum: Vec<f32>,
    /// The last iterates, while the owner holds the average.
    iterate: Vec<f32>,
}

impl ParamAverage {
    /// An average with decay `β ∈ [0, 1)` of parameters that start at `parts`.
    pub fn new(decay: f32, parts: &[&[f32]]) -> ParamAverage {
        let iterate = parts.concat();
        ParamAverage {
            decay,
            steps: 0,
            decayed: 1.0,
            sum: vec![0.0; iterate.len()],
            iterate,
        }
    }

    /// The decay `β = 1 − 1/(span·steps) ∈ [0, 1)` of an average that spans a share `span` of
    /// `steps` steps (a horizon of at least one step), the rule both the integrator and the
    /// path guide set their averages by.
    pub fn span_decay(span: f64, steps: usize) -> f32 {
        let horizon = (span * steps as f64).max(1.0);
        (1.0 - 1.0 / horizon) as f32
    }

    /// The decay `β` of the steps from now on.
    pub fn decay(&self) -> f32 {
        self.decay
    }

    /// The decay `β ∈ [0, 1)` of the steps from now on.
    pub fn set_decay(&mut self, decay: f32) {
        self.decay = decay;
    }

    /// Steps averaged so far.
    pub fn steps(&self) -> i32 {
        self.steps
    }

    /// The last iterates (the initial parameters before any step).
    pub fn iterate(&self) -> &[f32] {
        &self.iterate
    }

    /// Adds the parameters after one more step.
    pub fn add(&mut self, parts: &[&[f32]]) {
        debug_assert_eq!(total(parts), self.sum.len());
        let b = self.decay;
        let update = |sum: &mut [f32], part: &[f32]| {
            for (a, &p) in sum.iter_mut().zip(part) {
                *a = b * *a + (1.0 - b) * p;
            }
        };
        let mut rest = self.sum.as_mut_slice();
        for part in parts {
            let (sum, after) = rest.split_at_mut(part.len());
            rest = after;
            if in_parallel_blocks(part.len()) {
                sum.par_chunks_mut(PAR_BLOCK)
                    .zip(part.par_chunks(PAR_BLOCK))
                    .for_each(|(s, p)| update(s, p));
            } else {
                update(sum, part);
            }
        }
        self.steps = self.steps.saturating_add(1);
        self.decayed *= f64::from(b);
    }

    /// Keeps the iterates in `parts` and writes the average there in their place (leaves them
    /// as they are before the first step).
    pub fn use_average(&mut self, parts: &mut [&mut [f32]]) {
        debug_assert_eq!(total(parts), self.sum.len());
        for (i, &p) in self
            .iterate
            .iter_mut()
            .zip(parts.iter().flat_map(|p| p.iter()))
        {
            *i = p;
        }
        if self.steps == 0 {
            return;
        }
        let scale = 1.0 / (1.0 - self.decayed);
        for (p, &a) in parts.iter_mut().flat_map(|p| p.iter_mut()).zip(&self.sum) {
            *p = (f64::from(a) * scale) as f32;
        }
    }

    /// Puts the iterates back into `parts`, for training to go on from.
    pub fn resume(&self, parts: &mut [&mut [f32]]) {
        debug_assert_eq!(total(parts), self.sum.len());
        for (p, &i) in parts
            .iter_mut()
            .flat_map(|p| p.iter_mut())
            .zip(&self.iterate)
        {
            *p = i;
        }
    }
}

/// Parameters in all of `parts`.
fn total<P: AsRef<[f32]>>(parts: &[P]) -> usize {
    parts.iter().map(|p| p.as_ref().len()).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_average_is_adams_bias_corrected_moving_average() {
        // Iterates θ_t (t = 1..T) of two parts, one updated in parallel blocks and one serially,
        // over two trainings; after each the parts must hold Σ_t (1 − β)β^(T−t)θ_t / (1 − β^T)
        // (in f64 here; f32 sums of ≤ 12 terms are within 1e-6), and the iterates must come back
        // for training.
        let beta = 0.8f32;
        let theta = |t: usize, i: usize| ((t * 7 + i * 3) % 11) as f32 * 0.25 - 1.0;
        let (mut a, mut b) = (vec![9.0f32; 2 * PAR_BLOCK + 3], vec![9.0f32; 2]);
        let mut avg = ParamAverage::new(beta, &[&a, &b]);
        assert_eq!(avg.iterate(), vec![9.0; a.len() + 2]);
        let mut t = 0;
        for steps in [5, 7] {
            avg.resume(&mut [&mut a, &mut b]);
            for _ in 0..steps {
                t += 1;
                for (i, p) in a.iter_mut().chain(b.iter_mut()).enumerate() {
                    *p = theta(t, i);
                }
                avg.add(&[&a, &b]);
            }
            avg.use_average(&mut [&mut a, &mut b]);
            assert_eq!(avg.steps(), t as i32);
            let bd = f64::from(beta);
            for (i, &p) in a.iter().chain(&b).enumerate() {
                let sum: f64 = (1..=t)
                    .map(|s| (1.0 - bd) * bd.powi((t - s) as i32) * f64::from(theta(s, i)))
                    .sum();
                let want = sum / (1.0 - bd.powi(t as i32));
                assert!((f64::from(p) - want).abs() < 1e-6, "{p} vs {want}");
            }
            let last: Vec<f32> = (0..a.len() + 2).map(|i| theta(t, i)).collect();
            assert_eq!(avg.iterate(), &last[..]);
            let (mut a2, mut b2) = (vec![0.0; a.len()], vec![0.0; 2]);
            avg.resume(&mut [&mut a2, &mut b2]);
            assert_eq!([a2, b2].concat(), last);
        }
    }

    #[test]
    fn a_span_gives_the_decay_of_its_horizon_and_never_less_than_one_step() {
        // A tenth of 1000 steps is a horizon of 100: β = 0.99.
        assert_eq!(ParamAverage::span_decay(0.1, 1000), 0.99);
        // Half of one step rounds up to a horizon of one: β = 0, the last step alone.
        assert_eq!(ParamAverage::span_decay(0.5, 1), 0.0);
    }

    #[test]
    fn a_decay_that_changes_between_steps_weighs_each_step_by_its_own() {
        // β_t = 0.5 for two steps, then 0.9 for three: step t enters with (1 − β_t)·Π_{s>t} β_s
        // and the weights are divided by their sum 1 − Π β_t.
        let betas = [0.5f32, 0.5, 0.9, 0.9, 0.9];
        let theta = |t: usize| (t * t) as f32 * 0.1 - 0.7;
        let mut w = [0.0f32];
        let mut avg = ParamAverage::new(betas[0], &[&w]);
        for (t, &b) in betas.iter().enumerate() {
            avg.set_decay(b);
            w[0] = theta(t);
            avg.add(&[&w]);
        }
        avg.use_average(&mut [&mut w]);
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for t in 0..betas.len() {
            let later: f64 = betas[t + 1..].iter().map(|&b| f64::from(b)).product();
            let weight = (1.0 - f64::from(betas[t])) * later;
            num += weight * f64::from(theta(t));
            den += weight;
        }
        assert!(
            (f64::from(w[0]) - num / den).abs() < 1e-6,
            "{} vs {}",
            w[0],
            num / den
        );
    }

    #[test]
    fn constant_parameters_average_to_themselves_and_no_step_changes_nothing() {
        let mut w = [0.3f32, -2.0];
        let mut avg = ParamAverage::new(0.99, &[&w]);
        avg.use_average(&mut [&mut w]);
        assert_eq!(w, [0.3, -2.0]);
        for _ in 0..3 {
            avg.add(&[&w]);
        }
        avg.use_average(&mut [&mut w]);
        assert!(
            (w[0] - 0.3).abs() < 1e-6 && (w[1] + 2.0).abs() < 1e-6,
            "{w:?}"
        );
    }
}
