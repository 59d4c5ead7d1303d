//! Multi-channel integration (Kleiss & Pittau 1994, hep-ph/9405257; with a flow per channel as in
//! MadNIS, Heimel et al. 2023, arXiv:2212.06172) and signed integrands: F = Σ_k ∫ α_k f, each
//! channel's part written over its own cube, h_k(u) = a_k·f(φ_k(u))/g(φ_k(u)) with
//! g = Σ_j a_j g_j (`part.rs`), and integrated by a sampler of its own: for NIS a flow conditioned
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

mod adapt;
mod allocation;
mod auto;
mod config;
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

pub use super::result::{ChannelReport, SignReport};
pub use auto::{by_default, AutoSigns};
pub use config::{MultiChannelConfig, Sign, Signs};
pub use events::ChannelEvents;

use self::allocation::{allocate, neyman};
use self::config::MIN_PART_EVALS;
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

    fn as_multichannel_any(&mut self) -> Option<&mut dyn std::any::Any> {
        Some(self)
    }
}

impl<'a> dyn Integrator + 'a {
    /// This integrator as a multi-channel one, for what only it does (its channel weights,
    /// events that carry their channel); `None` for the methods on their own.
    pub fn as_multichannel(&mut self) -> Option<&mut MultiChannel> {
        self.as_multichannel_any()?.downcast_mut()
    }
}

impl MultiChannel {
    /// The smallest budget of one call with `parts` parts (the pilot aside): one adaptation and
    /// one estimate each.
    pub(crate) fn least_budget(parts: u64) -> u64 {
        2 * parts * MIN_PART_EVALS
    }
}

/// Salt of the pilot's stream ("pilo").
const PILOT_SALT: u64 = 0x7069_6c6f;

/// A seed per part, decorrelated from the base seed by a SplitMix64 step.
fn part_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ index.wrapping_add(1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
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
