//! Multi-channel integration to a precision target ([`Integrator::integrate_to`](crate::integrate::Integrator::integrate_to)): every part
//! adapts on [`MultiChannelConfig::target_adapt`] evaluations (fewer when a time limit, at the
//! cost per evaluation a throwaway sampler measures first, cannot pay for them), the a-priori
//! weights move, and then iterations planned by a [`Pursuit`] make the estimate. Each iteration spreads its
//! evaluations over the parts in proportion to their σ (fixed from the adaptation, as in
//! [`Integrator::integrate`](crate::integrate::Integrator::integrate)) and its share of the estimate is fixed before it is drawn, so the
//! stopped estimate stays unbiased (docs/ESTIMATE.md, "Precision targets"). Each part's
//! contribution is the same shares applied to its own estimates.

use std::time::Instant;

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::config::MIN_PART_EVALS;
use super::part::{self, PartIntegrand, Weighting};
use super::{estimate_part, MultiChannel, Part};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::integrate::estimate::chi2_per_dof;
use crate::integrate::nis::NisIntegrator;
use crate::integrate::target::{drive, Prior, Pursuit, Step, Stepper};
use crate::integrate::{Integrand, IntegrationResult, Iteration, Method, Source, Target};

/// The evaluations of the least run of `parts` parts: one adaptation and one estimate each.
fn least_run(parts: u64) -> u64 {
    2 * parts * MIN_PART_EVALS
}

/// Salt of the cost probe's throwaway sampler and points ("cost").
const PROBE_SALT: u64 = 0x636f_7374;

/// One part's estimates of the iterations so far.
#[derive(Clone, Default)]
struct PartSum {
    /// Each iteration's estimate and variance.
    estimates: Vec<(f64, f64)>,
    iterations: Vec<Iteration>,
    /// The part's result of its largest iteration: its weights' diagnostics stand for the part.
    largest: Option<IntegrationResult>,
}

impl MultiChannel {
    /// Parts the next call will have (before the first call: the channels, twice when the sign
    /// may split them).
    fn planned_parts(&self) -> u64 {
        if !self.parts.is_empty() {
            return self.parts.len() as u64;
        }
        let k = self.set.len() as u64;
        match self.config.signs {
            super::Signs::Whole => k,
            _ => 2 * k,
        }
    }

    /// The error [`Integrator::integrate_to`](crate::integrate::Integrator::integrate_to) would return for `target` (see
    /// [`Integrator::check_target`](crate::integrate::Integrator::check_target)).
    pub(super) fn check_parts_target(&self, target: &Target) -> Result<()> {
        let pilot = if self.parts.is_empty() && self.config.signs == super::Signs::Auto {
            (self.config.pilot * self.set.len()) as u64
        } else {
            0
        };
        target.check(
            "multi-channel integration",
            pilot + least_run(self.planned_parts()),
        )
    }

    /// Integrates until the error bar meets `target` or a limit is hit (module docs); the
    /// result's `stop` says which, and a limit adds a warning ([`Integrator::integrate_to`](crate::integrate::Integrator::integrate_to)).
    pub(super) fn pursue(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
    ) -> Result<IntegrationResult> {
        self.check_parts_target(target)?;
        let started = Instant::now();
        let mut spent = self.prepare(f)?;
        let parts = self.parts.len() as u64;
        // Adapt: at most adapt_fraction of max_evals, shared equally.
        let cap = (target.max_evals as f64 * self.config.adapt_fraction) as u64 / parts;
        let mut adapt = self.config.target_adapt.min(cap).max(MIN_PART_EVALS);
        if let Some(limit) = target.max_seconds {
            // The adaptation takes at most adapt_fraction of the time, as of the evaluations.
            let (per_eval, probed) = self.adapt_cost(f)?;
            spent += probed;
            let elapsed = self.comm.max(started.elapsed().as_secs_f64());
            let least = least_run(parts) as f64 * per_eval;
            if elapsed + least > limit {
                return Err(Error::Config(format!(
                    "precision target: max_seconds = {limit} cannot pay for the least \
                     adaptation and estimate of {parts} parts ({least:.2e} s at the \
                     {per_eval:.2e} s per evaluation measured)"
                )));
            }
            let afford = (limit * self.config.adapt_fraction - elapsed) / (parts as f64 * per_eval);
            adapt = adapt.min(afford.max(0.0) as u64).max(MIN_PART_EVALS);
        }
        let (measured, adapted, sd) = self.adapt_parts(f, adapt)?;
        spent += adapted;
        let total_sd: f64 = sd.iter().sum();
        let shares = super::neyman(&sd);
        let signs: Vec<f64> = self.parts.iter().map(|p| p.sign.factor()).collect();
        let mut pursuit = Pursuit::new(*target, started, spent);
        let mut prior = Prior {
            // Neyman's allocation: n_p ∝ σ_p gives Var = (Σσ_p)²/n.
            var_per_eval: total_sd * total_sd,
            estimate: measured.iter().zip(&signs).map(|(r, s)| s * r.value).sum(),
            seconds_per_eval: pursuit.elapsed(&self.comm) / spent.max(1) as f64,
        };
        let least = parts * MIN_PART_EVALS;
        let mut steps = Steps {
            f,
            w: Weighting {
                set: &self.set,
                a: &self.weights,
                net: self.net.as_ref(),
            },
            parts: &mut self.parts,
            comm: &self.comm,
            shares,
            signs,
            sums: vec![PartSum::default(); parts as usize],
            combined: Vec::new(),
            least,
            chunk: least,
            spent,
        };
        drive(&mut pursuit, &mut prior, &self.comm, &mut steps)?;
        let Steps {
            sums,
            combined,
            spent,
            ..
        } = steps;
        // The shares as the run ended (an extension rescales the earlier ones).
        let shares = pursuit.shares();
        let results: Vec<IntegrationResult> = sums.into_iter().map(|s| s.finish(shares)).collect();
        let mut result = self.combine(&results, spent, started);
        // The parts' samplers are fixed during the estimate but VEGAS+'s, which adapt.
        let adapting = self.method == Method::Vegas;
        result.chi2_per_dof = chi2_per_dof(&combined, result.value, adapting);
        result.iterations = combined;
        pursuit.finish(&mut result);
        Ok(result)
    }
}

impl MultiChannel {
    /// Seconds per evaluation of the parts' adaptation, on the slowest rank, and the evaluations
    /// spent measuring it: one training batch of a fresh flow on the first part (NIS), or the
    /// first part at a batch of uniform points (the other methods, whose adaptation costs about
    /// the integrand's and the channels' time). The sampler is thrown away.
    fn adapt_cost(&self, f: &dyn Integrand) -> Result<(f64, u64)> {
        let p = &self.parts[0];
        let w = Weighting {
            set: &self.set,
            a: &self.weights,
            net: None,
        };
        let h = PartIntegrand::new(f, w, p.channel, p.sign);
        let dim = self.set.dim();
        let batch = self.settings.nis.batch as u64;
        let seed = self.settings.seed_of(self.method) ^ PROBE_SALT;
        // Two rounds, the second timed: the first pays for starting the threads.
        let mut seconds = 0.0;
        if self.method == Method::Nis {
            let config = self.settings.clone().seed(seed).nis;
            let mut nis = NisIntegrator::new(dim, config)?;
            nis.set_comm(self.comm.clone());
            for _ in 0..2 {
                let t = Instant::now();
                nis.train(&h, batch)?;
                seconds = t.elapsed().as_secs_f64();
            }
        } else {
            let mut rng = Pcg64Mcg::seed_from_u64(self.comm.stream_seed(seed));
            for _ in 0..2 {
                let t = Instant::now();
                part::at_uniform_points(&h, &self.comm, batch, dim, &mut rng)?;
                seconds = t.elapsed().as_secs_f64();
            }
        }
        Ok((self.comm.max(seconds) / batch as f64, 2 * batch))
    }
}

/// The estimate's iterations: each spreads its evaluations over the parts by their σ.
struct Steps<'a> {
    f: &'a dyn Integrand,
    w: Weighting<'a>,
    parts: &'a mut [Part],
    comm: &'a Comm,
    /// Each part's share of an iteration's evaluations (Neyman's), and its sign's factor.
    shares: Vec<f64>,
    signs: Vec<f64>,
    sums: Vec<PartSum>,
    /// The iterations of the combined estimate.
    combined: Vec<Iteration>,
    least: u64,
    chunk: u64,
    /// Evaluations of the whole run so far.
    spent: u64,
}

impl Stepper for Steps<'_> {
    /// Iterations grow at most ×2 each towards a tenth of the predicted need.
    fn size(&mut self, pursuit: &Pursuit, prior: &mut Prior, _: f64) -> (u64, u64) {
        if let Some(need) = pursuit.iteration_goal(prior) {
            self.chunk = (need as u64).clamp(self.least, (2 * self.chunk).max(self.least));
        }
        (self.least, self.chunk)
    }

    fn draw(&mut self, step: Step, pursuit: &mut Pursuit, prior: &mut Prior) -> Result<Iteration> {
        let counts = super::allocate(step.evals, MIN_PART_EVALS, &self.shares);
        let spent_before = self.spent;
        let (mut estimate, mut variance, mut evals) = (0.0, 0.0, 0u64);
        let (mut max_abs_w, mut sum_abs_w) = (0.0f64, 0.0);
        for (i, (p, &n)) in self.parts.iter_mut().zip(&counts).enumerate() {
            let h = PartIntegrand::new(self.f, self.w, p.channel, p.sign);
            let r = estimate_part(p, &h, n)?;
            self.spent += r.n_eval;
            evals += r.iterations.iter().map(|i| i.evals).sum::<u64>();
            estimate += self.signs[i] * r.value;
            variance += r.std_err * r.std_err;
            max_abs_w = max_abs_w.max(r.iterations.iter().fold(0.0, |m, i| m.max(i.max_abs_w)));
            sum_abs_w += r.iterations.iter().map(|i| i.sum_abs_w).sum::<f64>();
            self.sums[i].add(r);
        }
        // VEGAS+ parts warm up in every call: those evaluations count against max_evals.
        pursuit.spend(self.spent - spent_before - evals);
        prior.seconds_per_eval = pursuit.elapsed(self.comm) / self.spent as f64;
        Ok(Iteration::new(
            Source::Final,
            vec![estimate],
            vec![variance],
            evals,
            max_abs_w,
            sum_abs_w,
        ))
    }

    fn keep(&mut self, iteration: Iteration) -> Result<()> {
        self.combined.push(iteration);
        Ok(())
    }
}

impl PartSum {
    /// Adds a part's estimate of one iteration.
    fn add(&mut self, r: IntegrationResult) {
        self.estimates.push((r.value, r.std_err * r.std_err));
        self.iterations.extend(r.iterations.iter().cloned());
        let evals = |r: &IntegrationResult| r.iterations.iter().map(|i| i.evals).sum::<u64>();
        if self.largest.as_ref().is_none_or(|l| evals(&r) >= evals(l)) {
            self.largest = Some(r);
        }
    }

    /// The part's result: its estimates weighted by the iterations' `shares`, its largest
    /// iteration's diagnostics.
    fn finish(self, shares: &[f64]) -> IntegrationResult {
        let (value, var) = self
            .estimates
            .iter()
            .zip(shares)
            .fold((0.0, 0.0), |(m, v), (&(mi, vi), a)| {
                (m + a * mi, v + a * a * vi)
            });
        let mut r = self.largest.unwrap_or_default();
        r.value = value;
        r.std_err = var.sqrt();
        r.chi2_per_dof = f64::NAN;
        r.iterations = self.iterations;
        r
    }
}
