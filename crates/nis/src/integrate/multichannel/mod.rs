//! Multi-channel integration (Kleiss & Pittau 1994, hep-ph/9405257; with a flow per channel as in
//! MadNIS, Heimel et al. 2023, arXiv:2212.06172) and signed integrands: F = Σ_k ∫ α_k f, each
//! channel's part written over its own cube, h_k(u) = a_k·f(φ_k(u))/g(φ_k(u)) with
//! g = Σ_j a_j g_j ([`part`]), and integrated by a sampler of its own: for NIS a flow conditioned
//! on the part (one flow for all, `shared.rs`; or a flow per part), trained on the variance
//! ([`Loss::resolve`](crate::loss::Loss::resolve)); a VEGAS+ map for VEGAS+ (multi-channel VEGAS);
//! uniform points for plain MC (the classic multi-channel estimator). When f changes sign every
//! channel's part is split into h⁺ and h⁻, each with its own sampler, so that each can reach zero
//! variance; F = Σ (F⁺_k − F⁻_k).
//!
//! One call: a pilot of uniform points per channel decides (once) whether f changes sign; every
//! part adapts on an equal share of `adapt_fraction` of the budget, which also measures its
//! standard deviation σ_p and its integral; the a-priori weights a_k move to the variance-minimising
//! a_k ∝ a_k·√W_k (Kleiss–Pittau, W_k the second moment of channel k's weights, from its parts),
//! kept above `weight_floor`; the rest of the budget goes to the parts in proportion to σ_p
//! (Neyman's allocation, with a floor so that no part starves), and each estimates its part with
//! its sampler frozen (NIS) or still adapting (VEGAS+). The allocation and the weights are fixed
//! before the estimate draws a point, so each part's estimate is unbiased and F's is too
//! (docs/ESTIMATE.md, "Channels and signs"); its variance is the sum of the parts'.

mod auto;
mod events;
mod part;
mod report;
mod saved;
mod shared;
mod to_target;
mod weight_net;

use std::path::Path;
use std::time::Instant;

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

pub use super::result::{ChannelReport, SignReport};
pub use auto::{by_default, AutoSigns};
pub use events::ChannelEvents;
pub use part::Sign;

use self::part::{PartIntegrand, Weighting};
use self::shared::SharedFlow;
use self::weight_net::WeightNet;
use super::nis::NisIntegrator;
use super::{
    integrator, report, Integrand, IntegrationResult, Integrator, Method, Progress, Settings,
    Target,
};
use crate::channels::{ChannelFn, ChannelSet};
use crate::comm::Comm;
use crate::error::{Error, Result};

/// Whether the integrand is split by sign.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Signs {
    /// Split when the pilot sees both signs.
    #[default]
    Auto,
    /// Always split into f⁺ and f⁻.
    Split,
    /// Never split (a sampler per channel learns |h_k|).
    Whole,
}

/// Settings of [`MultiChannel`] (the method's own settings are [`Settings`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MultiChannelConfig {
    /// Splitting by sign.
    pub signs: Signs,
    /// Share of a call's evaluations the parts adapt on (the rest makes the estimate); the
    /// default is the measured best of every method on every example
    /// (docs/results/integration.md, "Channels and signed integrands").
    pub adapt_fraction: f64,
    /// Whether the a-priori weights adapt (Kleiss–Pittau) between adapting and estimating.
    pub adapt_weights: bool,
    /// Smallest a-priori weight a channel keeps, as a fraction of 1/K (channel dropping leaves
    /// it this much).
    pub weight_floor: f64,
    /// Uniform points per channel of the pilot that decides the sign split.
    pub pilot: usize,
    /// Evaluations every part adapts on in a run to a precision target (at most
    /// `adapt_fraction` of its `max_evals`, shared).
    pub target_adapt: u64,
    /// NIS: one flow for all parts, conditioned on the part (`shared.rs`), instead of a flow per
    /// part; ignored by the other methods. On by default: with the parts' χ² loss it gains
    /// most where the channels overlap, loses little elsewhere, and takes less memory
    /// (docs/results/integration.md, "One flow shared by the channels"). A saved one loads as a
    /// flow per part.
    pub shared_flow: bool,
    /// NIS: after the parts adapt, fit a network N that refines the channel weights to
    /// α_k ∝ a_k g_k e^{N_k(x)} (MadNIS's), on fresh points of every part's sampler (counted),
    /// and keep it only when it lowers the estimate's variance on held-out points
    /// (`weight_net.rs`); ignored by the other methods. On by default: it lowers the variance
    /// per evaluation on every multi-channel example; at equal time it loses only where a point
    /// costs less than the network's pass (docs/results/integration.md, "Learned channel
    /// weights").
    pub weight_network: bool,
}

impl Default for MultiChannelConfig {
    fn default() -> Self {
        MultiChannelConfig {
            signs: Signs::Auto,
            adapt_fraction: 0.25,
            adapt_weights: true,
            weight_floor: 0.01,
            pilot: 1000,
            target_adapt: 100_000,
            shared_flow: true,
            weight_network: true,
        }
    }
}

impl MultiChannelConfig {
    fn validate(&self) -> Result<()> {
        let ok = self.adapt_fraction > 0.0
            && self.adapt_fraction < 1.0
            && self.weight_floor > 0.0
            && self.weight_floor <= 1.0
            && self.pilot >= 2
            && self.target_adapt >= MIN_PART_EVALS;
        if ok {
            return Ok(());
        }
        Err(Error::Config(format!(
            "multi-channel settings: adapt_fraction must be in (0, 1), weight_floor in (0, 1], \
             pilot at least 2 and target_adapt at least {MIN_PART_EVALS}: {self:?}"
        )))
    }
}

/// One part: channel, sign and its integrator (with a shared flow: the flow at the part's
/// context, from the first adaptation on).
struct Part {
    channel: usize,
    sign: Sign,
    integrator: Option<Box<dyn Integrator>>,
}

impl Part {
    /// Its integrator (an error before a shared flow has given it one).
    fn sampler(&mut self) -> Result<&mut (dyn Integrator + 'static)> {
        self.integrator.as_deref_mut().ok_or_else(no_sampler)
    }

    /// Its integrator as NIS's (an error for another method or before it has one).
    fn nis(&mut self) -> Result<&mut NisIntegrator> {
        self.sampler()?
            .as_nis()
            .ok_or_else(|| Error::Config("a multi-channel part's sampler is not NIS".into()))
    }
}

/// A multi-channel integrator: the channels, their a-priori weights, and an integrator of
/// `method` per channel and sign, all of which persist between calls.
pub struct MultiChannel {
    set: ChannelSet,
    method: Method,
    settings: Settings,
    config: MultiChannelConfig,
    /// The a-priori weights a_k, summing to one.
    weights: Vec<f64>,
    parts: Vec<Part>,
    /// The flow of every part when `config.shared_flow`.
    shared: Option<SharedFlow>,
    /// The weight network when `config.weight_network` fitted one that it kept.
    net: Option<WeightNet>,
    comm: Comm,
    /// The observer of progress ([`Integrator::set_progress`]).
    progress: Option<Box<dyn Progress>>,
    /// Calls of [`MultiChannel::unweighted`] so far: each draws from a stream of its own.
    event_draws: u64,
}

impl MultiChannel {
    /// Integrates over the channels of `set` with `method` (its settings and seed from
    /// `settings`).
    pub fn new(
        set: ChannelSet,
        method: Method,
        mut settings: Settings,
        config: MultiChannelConfig,
    ) -> Result<MultiChannel> {
        config.validate()?;
        settings.nis.loss = settings.nis.loss.resolve(true);
        // Builds one to check the settings now rather than at the first call.
        integrator(method, set.dim(), &settings)?;
        Ok(MultiChannel {
            weights: set.weights(),
            set,
            method,
            settings,
            config,
            parts: Vec::new(),
            shared: None,
            net: None,
            comm: Comm::default(),
            progress: None,
            event_draws: 0,
        })
    }

    /// One channel, the identity map: a single-channel integral whose integrand may be split by
    /// sign (`config.signs`).
    pub fn single(
        dim: usize,
        method: Method,
        settings: Settings,
        config: MultiChannelConfig,
    ) -> Result<MultiChannel> {
        if dim == 0 {
            return Err(Error::Config("dimension must be at least 1".into()));
        }
        let identity = ChannelFn::new(
            dim,
            |u: &[f64], x: &mut [f64]| x.copy_from_slice(u),
            |_| 1.0,
        );
        MultiChannel::new(
            ChannelSet::new(vec![Box::new(identity)])?,
            method,
            settings,
            config,
        )
    }

    /// The a-priori weights a_k the next estimate starts from.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// The parts' `results` summed into one result with its [`ChannelReport`], `spent`
    /// evaluations in all since `started`.
    fn combine(
        &self,
        results: &[IntegrationResult],
        spent: u64,
        started: Instant,
    ) -> IntegrationResult {
        report::combine(
            &self.parts_index(),
            results,
            &self.weights,
            self.set.len(),
            spent,
            started,
        )
    }

    /// Checks `f` and makes the parts on the first call (returns the pilot's evaluations).
    fn prepare(&mut self, f: &dyn Integrand) -> Result<u64> {
        super::check_dim(f, self.dim())?;
        if f.components() != 1 {
            return Err(Error::Config(
                "multi-channel integration takes scalar integrands".into(),
            ));
        }
        if self.parts.is_empty() {
            return self.make_parts(f);
        }
        Ok(0)
    }

    /// Adapts every part on `adapt` evaluations, then the weights (Kleiss–Pittau), then fits the
    /// weight network when asked: each part's result (its σ and integral), the evaluations
    /// spent, and each part's σ per evaluation under the weights the estimate will use.
    fn adapt_parts(
        &mut self,
        f: &dyn Integrand,
        adapt: u64,
    ) -> Result<(Vec<IntegrationResult>, u64, Vec<f64>)> {
        let mut measured = Vec::with_capacity(self.parts.len());
        let mut spent = 0;
        // The parts adapt to Kleiss–Pittau's α; a network is refitted after them.
        self.net = None;
        let index = self.parts_index();
        let w = Weighting {
            set: &self.set,
            a: &self.weights,
            net: None,
        };
        if let Some(shared) = &mut self.shared {
            // The flow trains on every part's share at once; then each part gets the flow at
            // its context as an integrator of its own, and is measured with it.
            let train = adapt * 4 / 5;
            let (set, a, dim) = (&self.set, &self.weights, self.set.dim());
            let h =
                |counts: &[usize], u: &[f64]| part::eval_blocks(f, set, a, &index, counts, u, dim);
            spent += shared.train(&h, train * index.len() as u64)?;
            let base = self.settings.seed_of(self.method);
            for (i, p) in self.parts.iter_mut().enumerate() {
                let mut nis = shared.part(i, part_seed(base, i as u64))?;
                let h = PartIntegrand::new(f, w, p.channel, p.sign);
                let r = nis.estimate(&h, adapt - train)?;
                spent += r.n_eval;
                measured.push(r);
                p.integrator = Some(Box::new(nis));
            }
        } else {
            for p in self.parts.iter_mut() {
                let h = PartIntegrand::new(f, w, p.channel, p.sign);
                let r = adapt_part(p.sampler()?, &h, adapt)?;
                spent += r.n_eval;
                measured.push(r);
            }
        }
        if self.config.adapt_weights && self.set.len() > 1 {
            self.weights = self.adapted_weights(&measured);
        }
        let mut sd = sd_per_eval(&measured);
        if self.config.weight_network && self.method == Method::Nis && self.set.len() > 1 {
            let (fitted, sigmas) = self.fit_weight_net(f, adapt)?;
            spent += fitted;
            sd = sigmas;
        }
        Ok((measured, spent, sd))
    }

    /// (channel, sign) of every part, in order.
    fn parts_index(&self) -> Vec<(usize, Sign)> {
        self.parts.iter().map(|p| (p.channel, p.sign)).collect()
    }

    /// Decides the sign split from a pilot of uniform points per channel (returns the pilot's
    /// evaluations) and makes the parts, each integrator seeded from the settings' seed and its
    /// index.
    fn make_parts(&mut self, f: &dyn Integrand) -> Result<u64> {
        let dim = self.dim();
        let channels = self.set.len();
        let (split, spent) = match self.config.signs {
            Signs::Split => (true, 0),
            Signs::Whole => (false, 0),
            Signs::Auto => {
                // Each rank its share of the pilot, from its own stream.
                let seed = self
                    .comm
                    .stream_seed(self.settings.seed_of(self.method) ^ PILOT_SALT);
                let mut rng = Pcg64Mcg::seed_from_u64(seed);
                let (mut positive, mut negative) = (false, false);
                let n = self.config.pilot;
                let (set, a) = (&self.set, &self.weights);
                let w = Weighting { set, a, net: None };
                for k in 0..channels {
                    let h = PartIntegrand::new(f, w, k, Sign::Both);
                    part::at_uniform_points(&h, &self.comm, n as u64, dim, &mut rng)?;
                    positive |= h.saw_positive.into_inner();
                    negative |= h.saw_negative.into_inner();
                }
                (
                    self.comm.any(positive) && self.comm.any(negative),
                    (n * channels) as u64,
                )
            }
        };
        let signs: &[Sign] = if split {
            &[Sign::Plus, Sign::Minus]
        } else {
            &[Sign::Both]
        };
        let shared = self.config.shared_flow && self.method == Method::Nis;
        for channel in 0..channels {
            for &sign in signs {
                let integrator = if shared {
                    None
                } else {
                    let index = self.parts.len() as u64;
                    let seed = part_seed(self.settings.seed_of(self.method), index);
                    let mut i = integrator(self.method, dim, &self.settings.clone().seed(seed))?;
                    i.set_comm(self.comm.clone());
                    Some(i)
                };
                self.parts.push(Part {
                    channel,
                    sign,
                    integrator,
                });
            }
        }
        if shared {
            let seed = part_seed(self.settings.seed_of(self.method), u64::MAX);
            let config = self.settings.clone().seed(seed).nis;
            let mut flow = SharedFlow::new(dim, self.parts.len(), &config)?;
            flow.set_comm(self.comm.clone());
            self.shared = Some(flow);
        }
        Ok(spent)
    }

    /// a_k ∝ a_k·√W_k, W_k = Σ over channel k's parts of their weights' second moment
    /// (σ² per evaluation + F²) over a_k², normalised, each at least `weight_floor`/K.
    fn adapted_weights(&self, measured: &[IntegrationResult]) -> Vec<f64> {
        let k = self.set.len();
        let mut w = vec![0.0; k];
        for (p, r) in self.parts.iter().zip(measured) {
            let n: u64 = r.iterations.iter().map(|i| i.evals).sum();
            let second = r.std_err * r.std_err * n as f64 + r.value * r.value;
            w[p.channel] += second;
        }
        let mut a: Vec<f64> = self
            .weights
            .iter()
            .zip(&w)
            .map(|(a, w)| a * (w / (a * a)).sqrt())
            .collect();
        normalise_with_floor(&mut a, self.config.weight_floor / k as f64);
        if a.iter().all(|v| v.is_finite()) {
            a
        } else {
            self.weights.clone()
        }
    }
}

/// A multi-channel integral is an [`Integrator`] like the methods it runs per part: front ends
/// drive it through the trait (a single channel with a sign split is [`MultiChannel::single`]).
impl Integrator for MultiChannel {
    fn method(&self) -> Method {
        self.method
    }

    /// The dimension of the channels' domain.
    fn dim(&self) -> usize {
        self.set.dim()
    }

    /// Spends `evals` evaluations of `f` (every channel's and sign's, the pilot included):
    /// adapts, moves the weights, allocates, estimates (module docs).
    fn integrate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        let started = Instant::now();
        let channels = self.set.len();
        let mut spent = self.prepare(f)?;
        let parts = self.parts.len() as u64;
        let least_per_part = 2 * MIN_PART_EVALS;
        if evals < spent + parts * least_per_part {
            return Err(Error::Config(format!(
                "{} parts ({channels} channels{}) need at least {} evaluations, got {evals}",
                parts,
                if parts as usize > channels {
                    ", split by sign"
                } else {
                    ""
                },
                spent + parts * least_per_part
            )));
        }
        // Adapt: an equal share per part.
        let adapt =
            ((evals as f64 * self.config.adapt_fraction) as u64 / parts).max(MIN_PART_EVALS);
        let (_, adapted, sd) = self.adapt_parts(f, adapt)?;
        spent += adapted;
        report(&mut self.progress, spent, evals, "adapted");
        // Estimate: the rest in proportion to each part's σ per evaluation, with a floor.
        let rest = evals.saturating_sub(spent);
        let floor = (rest / (50 * parts)).max(MIN_PART_EVALS);
        let mut results = Vec::with_capacity(self.parts.len());
        let w = Weighting {
            set: &self.set,
            a: &self.weights,
            net: self.net.as_ref(),
        };
        for (p, n) in self
            .parts
            .iter_mut()
            .zip(allocate(rest, floor, &neyman(&sd)))
        {
            let h = PartIntegrand::new(f, w, p.channel, p.sign);
            let r = estimate_part(p, &h, n)?;
            spent += r.n_eval;
            results.push(r);
            report(&mut self.progress, spent, evals, "estimating");
        }
        Ok(self.combine(&results, spent, started))
    }

    fn integrate_to(&mut self, f: &dyn Integrand, target: &Target) -> Result<IntegrationResult> {
        self.pursue(f, target)
    }

    /// The error [`Integrator::integrate_to`] would return for `target` before evaluating
    /// anything: a bad target, or a `max_evals` below the pilot and one adaptation and one
    /// estimate per part.
    fn check_target(&self, target: &Target) -> Result<()> {
        self.check_parts_target(target)
    }

    /// Reports after the adaptation and after each part's estimate.
    fn set_progress(&mut self, progress: Option<Box<dyn Progress>>) {
        self.progress = progress;
    }

    fn set_comm(&mut self, comm: Comm) {
        for p in &mut self.parts {
            if let Some(i) = &mut p.integrator {
                i.set_comm(comm.clone());
            }
        }
        if let Some(s) = &mut self.shared {
            s.set_comm(comm.clone());
        }
        self.comm = comm;
    }

    /// Saves the parts' flows and the weights into the directory `path` (made if missing); NIS
    /// only, after a first call. Each file is written atomically, the manifest last, so a
    /// directory without it is not a saved integrator; [`MultiChannel::load`] reads it.
    fn save(&self, path: &Path) -> Result<()> {
        self.save_parts(path)
    }

    fn as_multichannel(&mut self) -> Option<&mut MultiChannel> {
        Some(self)
    }
}

/// Each part's standard deviation per evaluation of its estimate, from its adaptation's result.
fn sd_per_eval(measured: &[IntegrationResult]) -> Vec<f64> {
    measured
        .iter()
        .map(|r| r.std_err * (r.iterations.iter().map(|i| i.evals).sum::<u64>() as f64).sqrt())
        .collect()
}

/// Neyman's allocation: each part's share of the points, σ_p/Σσ (equal shares when every σ is 0).
fn neyman(sd: &[f64]) -> Vec<f64> {
    let total: f64 = sd.iter().sum();
    sd.iter()
        .map(|s| {
            if total > 0.0 {
                s / total
            } else {
                1.0 / sd.len() as f64
            }
        })
        .collect()
}

/// `total` evaluations in whole numbers by `shares` (summing to one), each part at least `floor`:
/// `floor` plus its share of the rest rounded down, and the units the rounding left to the parts
/// with the largest remainders, so that they add up to `total` (to more when the floors do).
fn allocate(total: u64, floor: u64, shares: &[f64]) -> Vec<u64> {
    let spare = total.saturating_sub(floor * shares.len() as u64);
    let exact: Vec<f64> = shares.iter().map(|s| spare as f64 * s).collect();
    let mut n: Vec<u64> = exact.iter().map(|e| *e as u64).collect();
    let mut left = spare.saturating_sub(n.iter().sum());
    let mut by_remainder: Vec<usize> = (0..n.len()).collect();
    by_remainder.sort_by(|&i, &j| (exact[j] - n[j] as f64).total_cmp(&(exact[i] - n[i] as f64)));
    while left > 0 && !n.is_empty() {
        for &i in &by_remainder {
            if left == 0 {
                break;
            }
            n[i] += 1;
            left -= 1;
        }
    }
    n.iter().map(|n| floor + n).collect()
}

impl MultiChannel {
    /// The smallest budget of one call with `parts` parts (the pilot aside): one adaptation and
    /// one estimate each.
    pub(crate) fn least_budget(parts: u64) -> u64 {
        2 * parts * MIN_PART_EVALS
    }
}

/// Fewest evaluations a part adapts or estimates with.
const MIN_PART_EVALS: u64 = 2000;
/// Salt of the pilot's stream ("pilo").
const PILOT_SALT: u64 = 0x7069_6c6f;

/// A seed per part, decorrelated from the base seed by a SplitMix64 step.
fn part_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ (index + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Normalises `a` to sum to one with every entry at least `floor` (the entries below it are
/// raised to it, the others share the rest in proportion).
fn normalise_with_floor(a: &mut [f64], floor: f64) {
    let total: f64 = a.iter().sum();
    a.iter_mut().for_each(|v| *v /= total);
    for _ in 0..a.len() {
        let low = a.iter().filter(|v| **v < floor).count();
        if low == 0 {
            break;
        }
        let high: f64 = a.iter().filter(|v| **v >= floor).sum();
        let left = 1.0 - floor * low as f64;
        a.iter_mut().for_each(|v| {
            *v = if *v < floor { floor } else { *v * left / high };
        });
    }
}

/// Adapts a part on `n` evaluations and measures it: NIS trains on most of them and estimates
/// with the rest; the others integrate (VEGAS+ adapts while it does).
fn adapt_part(integ: &mut dyn Integrator, h: &dyn Integrand, n: u64) -> Result<IntegrationResult> {
    if let Some(nis) = integ.as_nis() {
        let train = n * 4 / 5;
        nis.train(h, train)?;
        let mut r = nis.estimate(h, n - train)?;
        r.n_eval += train;
        return Ok(r);
    }
    integ.integrate(h, n)
}

/// The estimate of part `p` from `n` evaluations: NIS's frozen flow alone, the others'
/// `integrate`.
fn estimate_part(p: &mut Part, h: &dyn Integrand, n: u64) -> Result<IntegrationResult> {
    let integ = p.sampler()?;
    if let Some(nis) = integ.as_nis() {
        return nis.estimate(h, n);
    }
    integ.integrate(h, n)
}

/// A part without its sampler (a shared flow's parts get theirs when it has trained).
fn no_sampler() -> Error {
    Error::Config("a multi-channel part has no sampler".into())
}

#[cfg(test)]
mod tests;
