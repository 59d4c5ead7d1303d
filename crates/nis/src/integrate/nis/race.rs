//! NIS races VEGAS+ for a precision target (issue 40, "training length that pays for itself").
//!
//! A flow pays for its training on integrands whose shape a separable map cannot follow; on a
//! cheap, nearly separable one VEGAS+ reaches a target in less time than a flow takes to anneal.
//! So NIS, asked for a target with an untrained flow, trains ten batches, which measure its time
//! per batch and with it the time its annealing and settling would take at the slow pace
//! ([`TrainingLength::slow_seconds_left`]), NIS's training at its slowest. VEGAS+ (its own run to
//! the target, its own seed) does not start when its warm-up alone would take [`LEAST_SHARE`] of
//! that at the integrand's seconds per point (a costly integrand); else it runs [`LEAST_SHARE`]
//! of it in any case and goes on while its time so far plus its prediction from the latest
//! iteration stays below [`ESTIMATE_TOO`] times it, and while its weights are not already far
//! from f's shape (`vegas/to_target.rs`), within half of `max_evals` and `max_seconds`. When it meets the
//! target with no warning, its result is the answer (`IntegrationResult::answered_by`); when it
//! gives up, its result warns or half a limit stops it, NIS trains on as without the race,
//! VEGAS+'s evaluations counted but not used.
//! Either way one sampler's iterations, each with its share fixed before it is drawn, make the
//! estimate (docs/ESTIMATE.md, "Precision targets").

use std::time::Instant;

use super::training_length::TrainingLength;
use super::NisIntegrator;
use crate::error::Result;
use crate::flow::Density;
use crate::integrate::vegas::{Pursued, Race, Vegas, VegasConfig};
use crate::integrate::{Integrand, IntegrationResult, Integrator, Method, Stop, Target};

/// Salt of VEGAS+'s seed ("race" in ASCII), apart from NIS's own streams.
const RACE_SEED_SALT: u64 = 0x7261_6365;

/// The share of NIS's slowest training time that VEGAS+ runs in any case before its prediction
/// must beat NIS's: its first iterations adapt the map and predict far too long a time. What NIS
/// loses where VEGAS+ gives up. VEGAS+ does not start when its warm-up alone, at the
/// integrand's seconds per point, would take longer (a costly integrand would lose much of its
/// time to the warm-up; docs/results/integration.md, "Time to precision").
const LEAST_SHARE: f64 = 0.2;

/// NIS's time to the target over its training's: its estimate phase comes on top
/// (docs/results/integration.md, "Time to precision").
const ESTIMATE_TOO: f64 = 1.5;

/// How a race ended.
pub(super) enum Raced {
    /// VEGAS+'s answer.
    Won(Box<IntegrationResult>),
    /// NIS goes on; VEGAS+ spent `evals`.
    Lost { evals: u64 },
}

impl NisIntegrator {
    /// Whether a run to a target races VEGAS+ ([`super::NisConfig::race_vegas`], an untrained
    /// flow).
    pub(super) fn races(&self) -> bool {
        self.config.race_vegas && self.trained_evals == 0
    }

    /// Races VEGAS+ after NIS's first `nis_evals` evaluations of training, which `length`
    /// measured (module docs).
    pub(super) fn race(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        started: Instant,
        nis_evals: u64,
        length: &TrainingLength,
    ) -> Result<Raced> {
        let rival = length.slow_seconds_left();
        let config = VegasConfig {
            seed: self.config.seed ^ RACE_SEED_SALT,
            train_on: self.config.train_on,
            ..VegasConfig::default()
        };
        let mut vegas = Vegas::new(self.flow().dim(), config)?;
        // Priced at the integrand's own cost per point: NIS's includes drawing from the flow,
        // which VEGAS+'s points do not pay (on cheap integrands most of it).
        let per_point = length.integrand_seconds_per_eval().unwrap_or(f64::INFINITY);
        if vegas.warm_up_evals(target) as f64 * per_point > LEAST_SHARE * rival {
            return Ok(Raced::Lost { evals: 0 });
        }
        // VEGAS+ may spend half of the limits (NIS's first batches included), so that NIS has
        // the other half when VEGAS+ does not meet the target in its.
        let half = Target {
            max_evals: target.max_evals / 2,
            max_seconds: target.max_seconds.map(|s| s / 2.0),
            ..*target
        };
        let own = Target {
            max_evals: half.max_evals.saturating_sub(nis_evals),
            ..half
        };
        if vegas.check_target(&own).is_err() {
            return Ok(Raced::Lost { evals: 0 });
        }
        vegas.set_comm(self.comm.clone());
        vegas.set_progress(self.progress.take());
        let race = Race {
            least: LEAST_SHARE * rival,
            rival: ESTIMATE_TOO * rival,
        };
        let pursued = vegas.race_to(f, &half, started, nis_evals, race);
        self.progress = vegas.take_progress();
        Ok(match pursued? {
            Pursued::Done(mut r) if r.warnings.is_empty() && r.stop == Some(Stop::Target) => {
                r.answered_by = Some(Method::Vegas);
                Raced::Won(r)
            }
            Pursued::Done(r) => Raced::Lost {
                evals: r.n_eval - nis_evals,
            },
            Pursued::GaveUp { evals } => Raced::Lost { evals },
        })
    }
}
