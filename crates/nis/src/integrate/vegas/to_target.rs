//! VEGAS+ to a precision target ([`crate::integrate::Integrator::integrate_to`]): the warm-up of
//! a nominal budget's plan adapts the map and the strata, then iterations planned by a
//! [`Pursuit`] make the estimate, each with its share fixed before it is drawn, while the map
//! and the strata go on adapting (as in [`super::Vegas`]'s result iterations).

use std::time::Instant;

use super::adaptive_strata::Strata;
use super::iteration::Measure;
use super::Vegas;
use crate::error::Result;
use crate::integrate::target::{Prior, Pursuit, AIM};
use crate::integrate::{check_dim, report, Accumulator, Integrand, IntegrationResult, Target};

/// The budget whose plan lays out the warm-up (points per iteration, increments, strata).
const NOMINAL_EVALS: u64 = 100_000;
/// The estimate's iterations the first plan aims at (the last ones may differ in size).
const RESULT_ITERATIONS: f64 = 10.0;

impl Vegas {
    /// [`crate::integrate::Integrator::check_target`]: the warm-up and one iteration must fit.
    pub(super) fn check_target_plan(&self, target: &Target) -> Result<()> {
        let plan = self.plan(NOMINAL_EVALS.min(target.max_evals));
        target.check("vegas+", ((plan.warmup + 1) * plan.per_iter) as u64)
    }

    /// [`crate::integrate::Integrator::integrate_to`] for VEGAS+.
    pub(super) fn run_to(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
    ) -> Result<IntegrationResult> {
        let dim = self.dim;
        check_dim(f, dim)?;
        let k = f.components();
        let train_on = self.config.train_on;
        train_on.check(k)?;
        self.check_target_plan(target)?;
        let plan = self.plan(NOMINAL_EVALS.min(target.max_evals));
        let per_iter = plan.per_iter;
        let started = Instant::now();
        let (min_per_cube, alpha, beta) = (
            self.config.min_per_cube,
            self.config.alpha,
            self.config.beta,
        );
        self.adopt(plan.increments, plan.strata);
        let map = self.map.as_mut().expect("made by adopt");
        let strata = self.strata.as_mut().expect("set by adopt");
        let (rng, comm) = (&mut self.rng, &self.comm);
        let mut contribution_var = vec![0.0; strata.cubes];
        let mut n_eval = 0u64;
        let mut prior = None;
        for _ in 0..plan.warmup {
            let measure = Measure {
                f,
                comm,
                k,
                train_on,
                volume: 1.0 / strata.cubes as f64,
            };
            let counts = strata.allocate(per_iter, min_per_cube);
            let measured = measure.iteration(map, strata, rng, &counts, &mut contribution_var)?;
            n_eval += measured.evals;
            prior = Some((measured.variance * measured.evals as f64, measured.estimate));
            strata.adapt(&contribution_var, beta);
            map.adapt(alpha);
            report(&mut self.progress, n_eval, n_eval, "vegas: adapting");
        }
        let mut pursuit = Pursuit::new(*target, started, n_eval).adapting();
        let (var_per_eval, estimate) = prior.unwrap_or((0.0, 0.0));
        let mut prior = Prior {
            var_per_eval,
            estimate,
            seconds_per_eval: pursuit.elapsed(comm) / n_eval.max(1) as f64,
        };
        let wanted = target.error_for(estimate);
        let predicted = if wanted > 0.0 {
            (var_per_eval / (AIM * wanted).powi(2)).min(target.max_evals as f64)
        } else {
            target.max_evals as f64
        };
        let mut acc = Accumulator::new(predicted as u64);
        let warm = n_eval;
        // Iterations grow at most ×2 each towards a tenth of the predicted need, the strata with
        // them: the map keeps adapting as they grow, and a warm-up's (too large) prediction
        // cannot make the first ones huge.
        let (mut chunk, mut strata_for) = (per_iter, per_iter);
        loop {
            let wanted = target.error_for(pursuit.estimate().unwrap_or(prior.estimate));
            if wanted > 0.0 {
                let need = prior.var_per_eval / (AIM * wanted).powi(2) / RESULT_ITERATIONS;
                chunk = (need as usize).clamp(per_iter, 2 * chunk);
            }
            if chunk > 2 * strata_for {
                *strata = Strata::plan(dim, chunk, min_per_cube);
                contribution_var = vec![0.0; strata.cubes];
                strata_for = chunk;
            }
            let least = (2 * min_per_cube * strata.cubes) as u64;
            let elapsed = pursuit.elapsed(comm);
            let Some(step) = pursuit.next(prior, least, chunk as u64, elapsed)? else {
                break;
            };
            let measure = Measure {
                f,
                comm,
                k,
                train_on,
                volume: 1.0 / strata.cubes as f64,
            };
            let counts = strata.allocate(step.evals as usize, min_per_cube);
            let measured = measure.iteration(map, strata, rng, &counts, &mut contribution_var)?;
            n_eval += measured.evals;
            // The map keeps improving: the latest iteration predicts the next best.
            prior.var_per_eval = measured.variance * measured.evals as f64;
            prior.seconds_per_eval = pursuit.elapsed(comm) / n_eval as f64;
            acc.observe(&measured.w_eff);
            let iteration = measured.iteration(comm);
            pursuit.record(step, &iteration);
            acc.add(iteration)?;
            strata.adapt(&contribution_var, beta);
            map.adapt(alpha);
            report(
                &mut self.progress,
                n_eval,
                warm + (predicted as u64).max(n_eval - warm),
                "vegas: estimating to the target",
            );
        }
        acc.reduce_tail(comm);
        let mut result = acc.finish(Some(pursuit.shares()), n_eval, started);
        pursuit.finish(&mut result);
        Ok(result)
    }
}
