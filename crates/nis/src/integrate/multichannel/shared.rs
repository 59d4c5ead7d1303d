//! One flow for every part, conditioned on the part (`MultiChannelConfig::shared_flow`): the
//! alternative to a flow per channel and sign that issue 39 asks to measure. The flow takes a
//! one-hot context, so q(u | p) is the density of part p over its channel's cube, and every
//! training batch holds points of every part: the parts share the conditioners' weights and
//! what each batch teaches them, and many channels cost one flow's memory. Its first layer's
//! context columns are a learned embedding of the part.
//!
//! Training is NIS's, in its one loop (`nis/flow_training.rs`; Müller et al. 2019, Sec. 3.2):
//! on-policy steps of the KL or χ² loss, the tempered target |h_p|^β over the first half of the
//! first training, the learning rate decayed over its steps and the estimate drawn from an
//! average of the weights. Half of a batch's points go to the parts equally, half in proportion
//! to their running ∫|h_p|, and each part's targets are divided by that integral, so each
//! conditional density learns its own normalised target.
//! After training, each part gets an NIS integrator of its own around the flow at its context
//! ([`Flow::at_context`]: the context's share of every first layer folded into its biases), so
//! the estimate, the events and saving are a flow per part's, unbiased as NIS's are.

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::allocation::allocate;
use crate::comm::Comm;
use crate::error::Result;
use crate::flow::{Density, Flow, FlowConfig};
use crate::integrate::nis::{Batches, FlowTraining, NisConfig, NisIntegrator, TrainingMemory};
use crate::kernels::in_pool;
use crate::train::Learner;

/// Salts of the training stream and of the training memories' choices ("shtr", "shme").
const TRAIN_SALT: u64 = 0x7368_7472;
const MEMORY_SALT: u64 = 0x7368_6d65;

/// The parts' values at rows of points in blocks, one block of `counts[p]` rows per part p.
pub(super) type BlockFn<'a> = dyn Fn(&[usize], &[f64]) -> Result<Vec<f64>> + Sync + 'a;

/// A flow conditioned on the part, with its optimiser and streams.
pub(super) struct SharedFlow {
    config: NisConfig,
    flow: Flow,
    /// The optimiser, its schedule and the weights' moving average.
    training: FlowTraining,
    parts: usize,
    trained: u64,
    /// Each part's Σ|h_p|/q over its training points and their count: every batch's mean is
    /// unbiased for ∫|h_p| whatever q was, so their pooled mean is the running integral.
    mass: Vec<(f64, f64)>,
    train_rng: Pcg64Mcg,
    /// Each part's reservoir of its latest training's points, handed to its integrator for the
    /// recalled-weight check, and the stream that chooses them.
    memories: Vec<TrainingMemory>,
    memory_rng: Pcg64Mcg,
    comm: Comm,
}

impl SharedFlow {
    /// An untrained flow over `dim` dimensions for `parts` parts, with NIS's `config`.
    pub(super) fn new(dim: usize, parts: usize, config: &NisConfig) -> Result<SharedFlow> {
        config.validate()?;
        let flow = Flow::new(FlowConfig {
            dim,
            context_dim: parts,
            ..config.flow.clone()
        })?;
        let learner = Learner::new(flow.param_count(), config.loss, config.adam)?;
        Ok(SharedFlow {
            config: config.clone(),
            flow,
            training: FlowTraining::new(learner),
            parts,
            trained: 0,
            mass: vec![(0.0, 0.0); parts],
            train_rng: Pcg64Mcg::seed_from_u64(config.seed ^ TRAIN_SALT),
            memories: vec![TrainingMemory::new(dim); parts],
            memory_rng: Pcg64Mcg::seed_from_u64(config.seed ^ MEMORY_SALT),
            comm: Comm::default(),
        })
    }

    /// Runs data-parallel over the ranks of `comm`: each rank draws its share of every part's
    /// points from streams of its own, and the steps average the ranks' gradients.
    pub(super) fn set_comm(&mut self, comm: Comm) {
        self.training.set_comm(comm.clone());
        self.train_rng = Pcg64Mcg::seed_from_u64(comm.stream_seed(self.config.seed ^ TRAIN_SALT));
        self.memory_rng = Pcg64Mcg::seed_from_u64(comm.stream_seed(self.config.seed ^ MEMORY_SALT));
        self.memories.iter_mut().for_each(TrainingMemory::clear);
        self.comm = comm;
    }

    /// Trains on `evals` evaluations of the parts, in whole batches of NIS's batch size (or two
    /// points per part, if more); returns the evaluations spent. `h(counts, u)` gives the parts'
    /// values at the rows of `u`, in blocks of `counts[p]` rows of part p.
    pub(super) fn train(&mut self, h: &BlockFn, evals: u64) -> Result<u64> {
        let batch = self.config.batch.max(2 * self.parts);
        let steps = (evals / batch as u64) as usize;
        if steps == 0 {
            return Ok(0);
        }
        self.memories.iter_mut().for_each(TrainingMemory::clear);
        let untrained = self.trained == 0;
        let mut batches = SharedBatches {
            flow: &mut self.flow,
            h,
            batch,
            mass: &mut self.mass,
            train_rng: &mut self.train_rng,
            memories: &mut self.memories,
            memory_rng: &mut self.memory_rng,
            comm: &self.comm,
        };
        // One Adam step per batch (no replay).
        let training = &mut self.training;
        in_pool(|| training.train(&self.config, steps, 1, untrained, &mut batches))?;
        let spent = (steps * batch) as u64;
        self.trained += spent;
        Ok(spent)
    }

    /// Part `p`'s own NIS integrator: the flow at its context ([`Flow::at_context`]), which
    /// samples, estimates (with NIS's final phase), draws events and saves as a flow per part
    /// does, with the part's training points for its recalled-weight check; `seed` seeds its
    /// streams.
    pub(super) fn part(&mut self, p: usize, seed: u64) -> Result<NisIntegrator> {
        let flow = self.flow.at_context(&contexts(self.parts, p, 1))?;
        let mut config = self.config.clone();
        config.seed = seed;
        config.flow = flow.config().clone();
        let memory = std::mem::replace(&mut self.memories[p], TrainingMemory::new(flow.dim()));
        let mut nis = NisIntegrator::from_trained(flow, config, self.trained)?;
        nis.set_comm(self.comm.clone());
        nis.set_training_memory(memory);
        Ok(nis)
    }
}

/// The shared flow's training batches: every part's points, its share of each batch following
/// the parts' running integrals, its targets divided by its own.
struct SharedBatches<'a, 'h> {
    flow: &'a mut Flow,
    h: &'a BlockFn<'h>,
    /// Points of a batch (over all ranks).
    batch: usize,
    /// Each part's running ∫|h_p| (its length is the parts').
    mass: &'a mut [(f64, f64)],
    train_rng: &'a mut Pcg64Mcg,
    memories: &'a mut [TrainingMemory],
    memory_rng: &'a mut Pcg64Mcg,
    comm: &'a Comm,
}

impl Batches for SharedBatches<'_, '_> {
    fn flow(&mut self) -> &mut Flow {
        self.flow
    }

    fn learn(&mut self, _: usize, _: f64, learner: &mut Learner) -> Result<bool> {
        let dim = self.flow.dim();
        // This rank's share of every part's points, the parts' rows one after the other.
        let counts: Vec<usize> = batch_counts(self.mass, self.batch)
            .iter()
            .map(|&n| self.comm.share(n as u64) as usize)
            .collect();
        let parts = self.mass.len();
        let ctx: Vec<f32> = (0..parts)
            .flat_map(|p| contexts(parts, p, counts[p]))
            .collect();
        let n: usize = counts.iter().sum();
        let drawn = self.flow.sample_for_training(n, Some(&ctx), self.train_rng);
        let h = self.h;
        let evaluated = drawn.and_then(|s| {
            let x64: Vec<f64> = s.x.iter().map(|&v| v as f64).collect();
            Ok((s, h(&counts, &x64)?))
        });
        let (samples, hx) = self.comm.check(evaluated)?;
        // Each part's points join its memory, and its Σ|h|/q and count over the ranks its
        // running integral.
        let mut sums = vec![0.0; 2 * parts];
        let mut start = 0;
        for (p, &m) in counts.iter().enumerate() {
            let rows = start..start + m;
            let x = &samples.x[start * dim..(start + m) * dim];
            self.memories[p].observe(
                x,
                &samples.log_q[rows.clone()],
                &hx[rows.clone()],
                1,
                self.memory_rng,
            );
            sums[2 * p] = rows.map(|i| hx[i].abs() * (-samples.log_q[i]).exp()).sum();
            sums[2 * p + 1] = m as f64;
            start += m;
        }
        self.comm.sum_f64(&mut sums);
        for (p, m) in self.mass.iter_mut().enumerate() {
            m.0 += sums[2 * p];
            m.1 += sums[2 * p + 1];
        }
        let mut target = Vec::with_capacity(n);
        for (p, &m) in counts.iter().enumerate() {
            let s = scale(self.mass, p);
            let first = target.len();
            target.extend(hx[first..first + m].iter().map(
                |v| {
                    if s > 0.0 {
                        v.abs() / s
                    } else {
                        0.0
                    }
                },
            ));
        }
        if self.comm.any(target.iter().any(|t| *t != 0.0)) {
            learner.step_on_policy(self.flow, &samples, &target)?;
        }
        Ok(true)
    }
}

/// Part `p`'s running ∫|h_p| from the parts' `mass` (0 until a point saw it).
fn scale(mass: &[(f64, f64)], p: usize) -> f64 {
    let (sum, n) = mass[p];
    if n > 0.0 {
        sum / n
    } else {
        0.0
    }
}

/// Points per part of a batch of `batch` (over all ranks), from the parts' `mass`: half of them
/// equally, half in proportion to the running ∫|h_p| (all equally while none is known), each at
/// least one, by largest remainders (`allocation::allocate`). The equal half keeps a part that
/// no point has found yet sampled, so that it can be found.
fn batch_counts(mass: &[(f64, f64)], batch: usize) -> Vec<usize> {
    let p = mass.len();
    let scales: Vec<f64> = (0..p).map(|i| scale(mass, i)).collect();
    let total: f64 = scales.iter().sum();
    let share: Vec<f64> = scales
        .iter()
        .map(|s| {
            if total > 0.0 {
                0.5 / p as f64 + 0.5 * s / total
            } else {
                1.0 / p as f64
            }
        })
        .collect();
    allocate(batch as u64, 1, &share)
        .into_iter()
        .map(|n| n as usize)
        .collect()
}

/// The one-hot contexts of `n` points of part `p` of `parts`.
fn contexts(parts: usize, p: usize, n: usize) -> Vec<f32> {
    let mut c = vec![0.0; n * parts];
    for row in c.chunks_exact_mut(parts) {
        row[p] = 1.0;
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batch_counts_follow_the_parts_integrals_and_starve_none() {
        let mut s = SharedFlow::new(2, 4, &NisConfig::default()).unwrap();
        // Equal while nothing is known.
        assert_eq!(batch_counts(&s.mass, 256), vec![64; 4]);
        s.mass = vec![(6.0, 1.0), (2.0, 1.0), (0.0, 1.0), (0.0, 0.0)];
        let c = batch_counts(&s.mass, 256);
        assert_eq!(c.iter().sum::<usize>(), 256);
        // 252 spare points: 1/8 each, and 3/8 and 1/8 more by mass; plus one each, and the
        // last point to the first of the equal remainders.
        assert_eq!(c, vec![127, 64, 33, 32]);
        // More parts than points: one each, the batch grows to two per part in `train`.
        let s = SharedFlow::new(2, 300, &NisConfig::default()).unwrap();
        assert!(batch_counts(&s.mass, 600).iter().all(|n| *n == 2));
    }
}
