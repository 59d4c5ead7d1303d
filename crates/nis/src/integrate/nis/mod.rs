//! Neural importance sampling (Müller et al. 2019, Sec. 3): a flow learns |f|/∫|f| from the
//! integrand's own values during an adaptive phase, then is frozen and sampled for the estimate.
//!
//! Sampling uses a defensive mixture q_mix = λ·uniform + (1 − λ)·q with fixed counts per batch
//! (the balance heuristic of multiple importance sampling): weights f/q_mix are bounded by f/λ
//! wherever the flow has not (yet) put mass, which keeps error bars honest when the flow misses
//! a sliver of the integrand. Training sees only the flow's share of each batch, on-policy, and
//! optionally earlier batches again, off-policy (`replay_batches`).
//! The estimate is the final phase's, joined by the second half of the training batches with
//! shares fixed before each batch is drawn, so it stays unbiased (`reuse_training`; `reuse.rs`,
//! docs/ESTIMATE.md).
//! The final phase samples an exponential moving average of the flow's weights over the training
//! batches (`average_span`); training samples from, and goes on from, the last step's.
//! Early training optionally targets the tempered |f|^β with β rising to 1 (annealing), so that a
//! flow which has only seen the far tails of several modes is pulled toward all of them.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::estimate::iid_iteration;
use super::race::RivalFactory;
use super::strategies::learn_to;
use super::{
    check_budget, check_dim, evaluate, report, Accumulator, Integrand, IntegrationResult,
    Integrator, Method, Progress, Target,
};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::flow::mask::Masks;
use crate::flow::mixture::{DefensiveMixture, MixtureBatch, Record};
use crate::flow::{Density, Flow, FlowConfig};
use crate::kernels::in_pool;
use crate::train::Learner;
pub(crate) use flow_training::{Batches, FlowTraining};
pub(crate) use memory::TrainingMemory;
use reuse::TrainingPieces;

mod config;
mod flow_training;
mod memory;
mod post_stratified;
mod reuse;
mod stratified_latent;
mod to_target;
mod training;
mod training_length;

pub use config::{NisConfig, NisConfigBuilder, Stratify};
use stratified_latent::{FinalPlan, LatentStrata};

/// A flow-based integrator: it trains its flow, then estimates with it (again and again, or after
/// saving). It owns the flow, the optimiser's state and the random streams, so a second
/// [`Integrator::integrate`] trains further from where the first stopped.
pub struct NisIntegrator {
    config: NisConfig,
    /// The sampler: the flow in its defensive mixture with the uniform density
    /// (`uniform_fraction`); training steps its flow.
    sampler: DefensiveMixture<Flow>,
    /// The optimiser, its schedule and the weights' moving average (`flow_training.rs`).
    training: FlowTraining,
    /// Evaluations spent training so far (over all calls, and before saving).
    trained_evals: u64,
    streams: Streams,
    /// The points of the latest training, to check the final sampler against.
    memory: TrainingMemory,
    /// The ranks that share every batch (one process by default).
    comm: Comm,
    progress: Option<Box<dyn Progress>>,
    /// What builds the rival a run to a target races ([`NisConfig::race_vegas`]), if this
    /// integrator was handed one (`build.rs`'s factory hands it VEGAS+'s).
    rival: Option<RivalFactory>,
}

/// Salts of the three random streams drawn from one seed: distinct, so the streams are
/// independent ("rain", "esti", "unwe" in ASCII).
const TRAIN_SEED_SALT: u64 = 0x7261_696e;
const ESTIMATE_SEED_SALT: u64 = 0x6573_7469;
const UNWEIGHT_SEED_SALT: u64 = 0x756e_7765;
/// Salt of the training memory's choices ("memo").
const MEMORY_SEED_SALT: u64 = 0x6d65_6d6f;

/// The random streams, one per use, so that training more does not shift the estimate's points.
struct Streams {
    train: Pcg64Mcg,
    estimate: Pcg64Mcg,
    unweight: Pcg64Mcg,
    memory: Pcg64Mcg,
}

impl Streams {
    fn new(seed: u64) -> Streams {
        Streams {
            train: Pcg64Mcg::seed_from_u64(seed ^ TRAIN_SEED_SALT),
            estimate: Pcg64Mcg::seed_from_u64(seed ^ ESTIMATE_SEED_SALT),
            unweight: Pcg64Mcg::seed_from_u64(seed ^ UNWEIGHT_SEED_SALT),
            memory: Pcg64Mcg::seed_from_u64(seed ^ MEMORY_SEED_SALT),
        }
    }
}

impl NisIntegrator {
    /// A new (untrained: uniform) integrator in `dim` dimensions.
    pub fn new(dim: usize, config: NisConfig) -> Result<NisIntegrator> {
        config.validate()?;
        let flow = Flow::new(FlowConfig {
            dim,
            ..config.flow.clone()
        })?;
        NisIntegrator::from_trained(flow, config, 0)
    }

    /// The flow.
    pub fn flow(&self) -> &Flow {
        &self.sampler.density
    }

    /// Its settings.
    pub fn config(&self) -> &NisConfig {
        &self.config
    }

    /// Evaluations spent training so far, over all calls (and before saving, for a loaded one).
    pub fn trained_evals(&self) -> u64 {
        self.trained_evals
    }

    /// Restarts the random streams from `seed` (e.g. to estimate with a loaded integrator under
    /// another seed than the one it was trained with).
    pub fn set_seed(&mut self, seed: u64) {
        self.config.seed = seed;
        self.streams = Streams::new(self.comm.stream_seed(seed));
    }

    /// Runs data-parallel over the ranks of `comm` from now on (see [`Integrator::set_comm`]):
    /// restarts the random streams as this rank's streams of the seed.
    pub fn set_comm(&mut self, comm: Comm) {
        self.training.set_comm(comm.clone());
        self.memory.clear();
        self.comm = comm;
        self.set_seed(self.config.seed);
    }

    /// Hands it the factory of the rival its runs to a target race ([`NisConfig::race_vegas`]):
    /// without one, they do not race.
    pub(crate) fn set_rival(&mut self, rival: RivalFactory) {
        self.rival = Some(rival);
    }

    /// Starts the flow afresh, untrained, with the layout `masks` (the same settings and seed
    /// otherwise): a new flow, optimiser, weight average and training memory; the ranks, the
    /// progress display, the random streams and the rival stay.
    pub(super) fn relayout(&mut self, masks: Masks) -> Result<()> {
        let mut config = self.config.clone();
        config.flow.masks = masks;
        config.validate()?;
        let dim = self.flow().dim();
        let flow = Flow::new(FlowConfig {
            dim,
            ..config.flow.clone()
        })?;
        let mut learner = Learner::new(flow.param_count(), config.loss, config.adam)?;
        learner.set_comm(self.comm.clone());
        self.sampler = DefensiveMixture::new(flow, config.uniform_fraction)?;
        self.training = FlowTraining::new(learner);
        self.config = config;
        self.memory = TrainingMemory::new(dim);
        self.trained_evals = 0;
        Ok(())
    }

    /// The points of the flow's latest training (trained elsewhere: a shared multi-channel flow),
    /// which the estimate's recalled-weight check reads (`memory.rs`).
    pub(crate) fn set_training_memory(&mut self, memory: TrainingMemory) {
        self.memory = memory;
    }

    /// The points of the flow's latest training, to rescale when the integrand they were
    /// evaluated for changes (`memory.rs`).
    pub(crate) fn training_memory_mut(&mut self) -> &mut TrainingMemory {
        &mut self.memory
    }

    /// The final phase alone: the flow frozen, `evals` evaluations in `final_iterations`
    /// iterations. For a trained or loaded integrator; the result counts only these evaluations.
    pub fn estimate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        let started = Instant::now();
        let plan = FinalPlan::new(&self.config, self.dim(), evals);
        in_pool(|| self.final_phase(f, plan, 0, started, None))
    }

    /// The final phase `plan`, after `trained` evaluations of training in the same call (for the
    /// evaluation count and the progress) that started at `started`, combined with the kept
    /// training batches `pieces` when given.
    fn final_phase(
        &mut self,
        f: &dyn Integrand,
        plan: FinalPlan,
        trained: u64,
        started: Instant,
        pieces: Option<TrainingPieces>,
    ) -> Result<IntegrationResult> {
        check_dim(f, self.dim())?;
        let k = f.components();
        let (evals, iters) = (plan.evals, plan.iterations);
        check_budget(Method::Nis, evals, plan.least * iters as u64, plan.why)?;
        let lambda = self.sampler.lambda();
        let train_on = self.config.train_on;
        let mut latent = plan
            .latent
            .map(|(strata, s)| LatentStrata::new(strata, s, lambda, k, train_on));
        let mut acc = Accumulator::new(evals);
        if let Some(p) = &pieces {
            p.add_to(&mut acc)?;
        }
        let mut done = 0u64;
        for it in 0..iters {
            let upto = (evals * (it as u64 + 1)) / iters as u64;
            let rng = &mut self.streams.estimate;
            let iteration = match latent.as_mut() {
                Some(latent) => {
                    let n = upto.saturating_sub(done).max(plan.least);
                    let observe = &mut |w: &[f64]| acc.observe(w);
                    latent.iteration(&self.sampler, f, n, rng, &self.comm, observe)?
                }
                None => {
                    let n = (upto - done).max(2);
                    let sampler = &self.sampler;
                    iid_iteration(&self.comm, n, k, &mut acc, |m| {
                        weights(sampler, f, m, rng).map(|(_, w)| w)
                    })?
                }
            };
            done += iteration.evals;
            acc.add(iteration)?;
            report(
                &mut self.progress,
                trained + done,
                trained + evals,
                "nis: estimating",
            );
        }
        acc.reduce_tail(&self.comm);
        let shares = pieces.map(|p| p.shares(acc.iterations()));
        let mut result = acc.finish(shares.as_deref(), trained + done, started);
        self.recall_training(&mut result)?;
        Ok(result)
    }

    /// Sets `result`'s recalled figures ([`Convergence::training_weight_ratio`], the mass
    /// beyond and the shift: what the frozen sampler makes of the points of the latest
    /// training, against the estimate's final phase) and their warning.
    ///
    /// [`Convergence::training_weight_ratio`]: super::Convergence::training_weight_ratio
    fn recall_training(&mut self, result: &mut IntegrationResult) -> Result<()> {
        let finals = || {
            result
                .iterations
                .iter()
                .filter(|i| i.source == super::Source::Final)
        };
        let largest_final = finals().fold(0.0f64, |m, i| m.max(i.max_abs_w));
        let final_evals: u64 = finals().map(|i| i.evals).sum();
        if largest_final == 0.0 {
            return Ok(());
        }
        let recall = self
            .memory
            .recall(&self.sampler, largest_final, &self.comm)?;
        let (c, sigma) = (&mut result.convergence, result.std_err);
        c.training_weight_ratio = recall.largest.map(|w| w / largest_final);
        c.recalled_beyond = Some(recall.beyond);
        if sigma > 0.0 && sigma.is_finite() && final_evals > 0 {
            c.recalled_shift = recall.largest.map(|w| w / (final_evals as f64 * sigma));
            c.missing_mass = Some(recall.mass / sigma);
            c.missing_mass_err = Some(recall.mass_err / sigma);
        }
        let recalled = result.convergence.recalled_warnings();
        result
            .warnings
            .extend(recalled.into_iter().map(|w| w.sentence));
        Ok(())
    }

    /// `n` weighted points of the frozen sampler (the defensive mixture): the points (`n × d`,
    /// row-major) and their weights f/q (`n × k`, row-major), whose mean estimates ∫ f. Drawn
    /// from the stream that [`NisIntegrator::unweighted`] continues, so estimates are not shifted.
    pub fn weighted(&mut self, f: &dyn Integrand, n: usize) -> Result<(Vec<f64>, Vec<f64>)> {
        check_dim(f, self.flow().dim())?;
        weights(&self.sampler, f, n, &mut self.streams.unweight)
    }

    /// `n` points of the frozen sampler and the weights of the target the flow learns
    /// ([`NisConfig::train_on`]), drawn from `rng`.
    pub(crate) fn target_weights(
        &self,
        f: &dyn Integrand,
        n: usize,
        rng: &mut Pcg64Mcg,
    ) -> Result<(Vec<f64>, Vec<f64>)> {
        check_dim(f, self.flow().dim())?;
        let k = f.components();
        self.config.train_on.check(k)?;
        let (x, w) = weights(&self.sampler, f, n, rng)?;
        Ok((x, self.config.train_on.target(&w, k)))
    }

    /// Takes the unweighting stream out (put it back with [`NisIntegrator::put_unweight_rng`]).
    pub(crate) fn take_unweight_rng(&mut self) -> Pcg64Mcg {
        std::mem::replace(&mut self.streams.unweight, Pcg64Mcg::new(0))
    }

    /// Puts the unweighting stream back.
    pub(crate) fn put_unweight_rng(&mut self, rng: Pcg64Mcg) {
        self.streams.unweight = rng;
    }

    /// Reports progress to the observer, if any.
    pub(crate) fn report(&mut self, done: u64, total: u64, status: &str) {
        report(&mut self.progress, done, total, status);
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

    /// Loads an integrator saved by [`NisIntegrator::save`]: its flow and settings (the seed they
    /// were trained with included; see [`NisIntegrator::set_seed`]). The optimiser's state is not
    /// saved: training a loaded integrator further starts Adam afresh.
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
        config
            .validate()
            .map_err(|e| bad(&format!("integrator settings: {e}")))?;
        let trained_evals = meta
            .get("trained_evals")
            .and_then(|s| s.parse().ok())
            .unwrap_or(0);
        NisIntegrator::from_trained(flow, config, trained_evals)
    }

    /// An integrator around a flow trained elsewhere (`trained_evals` evaluations) with the
    /// settings `config` (its flow settings are `flow`'s): new, loaded, or a channel of a shared
    /// multi-channel flow. Its first training starts Adam and the schedule afresh; `loss: auto`
    /// becomes KL here ([`Loss::resolve`](crate::loss::Loss::resolve)).
    pub(crate) fn from_trained(
        flow: Flow,
        mut config: NisConfig,
        trained_evals: u64,
    ) -> Result<NisIntegrator> {
        config.loss = config.loss.resolve(false);
        let learner = Learner::new(flow.param_count(), config.loss, config.adam)?;
        let sampler = DefensiveMixture::new(flow, config.uniform_fraction)?;
        Ok(NisIntegrator {
            streams: Streams::new(config.seed),
            memory: TrainingMemory::new(sampler.density.dim()),
            config,
            sampler,
            training: FlowTraining::new(learner),
            trained_evals,
            comm: Comm::default(),
            progress: None,
            rival: None,
        })
    }
}

impl Integrator for NisIntegrator {
    fn method(&self) -> Method {
        Method::Nis
    }

    fn as_nis_any(&mut self) -> Option<&mut dyn std::any::Any> {
        Some(self)
    }

    fn dim(&self) -> usize {
        self.flow().dim()
    }

    fn set_progress(&mut self, progress: Option<Box<dyn Progress>>) {
        self.progress = progress;
    }

    fn set_comm(&mut self, comm: Comm) {
        NisIntegrator::set_comm(self, comm);
    }

    /// Trains on `train_fraction` of `evals` (whole batches), then estimates with the rest and
    /// the last `reuse_training` of the training batches.
    fn integrate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        let started = Instant::now();
        let batch = self.config.batch as u64;
        let train = ((evals as f64 * self.config.train_fraction) as u64 / batch) * batch;
        let batches = (train / batch) as usize;
        let plan = FinalPlan::new(&self.config, self.dim(), evals - train);
        let mut pieces = TrainingPieces::plan(&self.config, &plan, batches, f.components());
        // Both phases on one worker thread (as `train` and `estimate` alone): the serial work
        // between parallel loops (the loss, the optimiser's and the average's set-up, the
        // moments) then stays on a core of the pool, and each loop starts without a hand-over
        // from outside it. Communication stays on that one thread (MPI is initialised
        // Serialized).
        in_pool(|| {
            self.train_keeping(f, train, pieces.as_mut())?;
            self.final_phase(f, plan, train, started, pieces)
        })
    }

    fn integrate_to(&mut self, f: &dyn Integrand, target: &Target) -> Result<IntegrationResult> {
        in_pool(|| learn_to(self, f, target))
    }

    fn check_target(&self, target: &Target) -> Result<()> {
        self.check_target_plan(target)
    }

    fn save(&self, path: &Path) -> Result<()> {
        NisIntegrator::save(self, path)
    }
}

impl<'a> dyn Integrator + 'a {
    /// This integrator as NIS, for what only NIS does (train without estimating, estimate with
    /// the flow frozen, sample, unweight); `None` for the other methods.
    pub fn as_nis(&mut self) -> Option<&mut NisIntegrator> {
        self.as_nis_any()?.downcast_mut()
    }
}

/// `n` points of `sampler` drawn from `rng`, `record` saying which passes keep a tape, with the
/// points also as f64 for the integrand.
fn draw(
    sampler: &DefensiveMixture<Flow>,
    n: usize,
    rng: &mut Pcg64Mcg,
    record: Record,
) -> Result<(MixtureBatch, Vec<f64>)> {
    let b = sampler.draw(n, rng, record)?;
    let x64 = b.x.iter().map(|&v| v as f64).collect();
    Ok((b, x64))
}

/// `n` points of the frozen sampler and their weights f/q_mix (`n × k`, row-major).
fn weights(
    sampler: &DefensiveMixture<Flow>,
    f: &dyn Integrand,
    n: usize,
    rng: &mut Pcg64Mcg,
) -> Result<(Vec<f64>, Vec<f64>)> {
    let k = f.components();
    let (b, x64) = draw(sampler, n, rng, Record::Nothing)?;
    let fx = evaluate(f, &x64, sampler.density.dim())?;
    let w = fx
        .chunks_exact(k)
        .zip(&b.log_q_mix)
        .flat_map(|(v, l)| {
            let inv_q = (-l).exp();
            v.iter().map(move |v| v * inv_q)
        })
        .collect();
    Ok((x64, w))
}

#[cfg(test)]
mod tests;
