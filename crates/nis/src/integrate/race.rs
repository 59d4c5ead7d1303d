//! A learning method races a cheaper one to a precision target: NIS races VEGAS+ (issue 40,
//! "training length that pays for itself"). A strategy of a learner's road to a target: the road
//! (`strategies.rs`) calls [`race`] with what the learner's first batches measured, and the
//! rival is any [`Rival`], built by the [`RivalFactory`] the learner was handed
//! ([`super::integrator`] hands NIS VEGAS+'s), so neither method imports the other.
//!
//! A flow pays for its training on integrands whose shape a separable map cannot follow; on a
//! cheap, nearly separable one VEGAS+ reaches a target in less time than a flow takes to anneal.
//! So NIS, asked for a target with an untrained flow, trains ten batches, which measure its time
//! per batch and with it the time its annealing and settling would take at the slow pace
//! ([`Pace::training_seconds`], NIS's training at its slowest). VEGAS+ (its own run to the target,
//! its own seed) does not start when its warm-up alone would take [`LEAST_SHARE`] of that at the
//! integrand's seconds per point (a costly integrand); else it runs [`LEAST_SHARE`] of it in any
//! case and goes on while its time so far plus its prediction from the latest iteration stays
//! below [`ESTIMATE_TOO`] times it, and while its weights are not already far from f's shape
//! (`vegas/to_target.rs`), within half of `max_evals` and `max_seconds`. When it meets the target
//! with no warning, its result is the answer (`IntegrationResult::answered_by`); when it gives
//! up, its result warns or half a limit stops it, NIS trains on as without the race, VEGAS+'s
//! evaluations counted but not used. Either way one sampler's iterations, each with its share
//! fixed before it is drawn, make the estimate (docs/ESTIMATE.md, "Precision targets").

use std::time::Instant;

use super::{Integrand, IntegrationResult, Integrator, Progress, Stop, Target, TrainOn};
use crate::comm::Comm;
use crate::error::Result;

/// Salt of the rival's seed ("race" in ASCII), apart from the learner's own streams.
pub(crate) const RACE_SEED_SALT: u64 = 0x7261_6365;

/// The share of the learner's slowest training time that the rival runs in any case before its
/// prediction must beat the learner's: its first iterations adapt the map and predict far too
/// long a time. What the learner loses where the rival gives up. The rival does not start when
/// its warm-up alone, at the integrand's seconds per point, would take longer (a costly
/// integrand would lose much of its time to the warm-up; docs/results/integration.md, "Time to
/// precision").
const LEAST_SHARE: f64 = 0.2;

/// The learner's time to the target over its training's: its estimate phase comes on top
/// (docs/results/integration.md, "Time to precision").
const ESTIMATE_TOO: f64 = 1.5;

/// When a racing rival gives up ([`Rival::race_to`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Race {
    /// Seconds it runs in any case.
    pub(crate) least: f64,
    /// Seconds the learner is predicted to take; after `least`, the rival gives up when its own
    /// time so far plus its predicted time to the target exceeds them.
    pub(crate) rival: f64,
}

/// How a rival's run to a target ended.
pub(crate) enum Pursued {
    Done(Box<IntegrationResult>),
    /// Given up in a race, after `evals` evaluations of its own.
    GaveUp {
        evals: u64,
    },
}

/// How a race ended, for the learner.
pub(crate) enum Raced {
    /// The rival's answer.
    Won(Box<IntegrationResult>),
    /// The learner goes on; the rival spent `evals`.
    Lost { evals: u64 },
}

/// Builds the rival a learner races, from the dimension, the rival's seed and what the learner
/// adapts to.
pub(crate) type RivalFactory = fn(usize, u64, TrainOn) -> Result<Box<dyn Rival>>;

/// A method that can race a learner to a target.
pub(crate) trait Rival: Integrator {
    /// The evaluations its warm-up for `target` takes.
    fn warm_up_evals(&self, target: &Target) -> u64;
    /// Its run to `target` begun at `started`, `others` evaluations already spent by the
    /// learner, giving up as `race` says.
    fn race_to(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        started: Instant,
        others: u64,
        race: Race,
    ) -> Result<Pursued>;
    /// Hands back the observer of progress it was given.
    fn take_progress(&mut self) -> Option<Box<dyn Progress>>;
}

/// What the learner's first batches measured.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Pace {
    /// Seconds its training would take at its slowest (annealing and settling).
    pub(crate) training_seconds: f64,
    /// The integrand's own seconds per point (without the learner's sampling), if measured.
    pub(crate) integrand_seconds_per_eval: Option<f64>,
    /// Evaluations the learner has spent.
    pub(crate) evals: u64,
}

/// Races `rival` against a learner at `pace` (module docs), on the learner's ranks and with
/// its observer of progress (handed back).
pub(crate) fn race(
    rival: &mut dyn Rival,
    f: &dyn Integrand,
    target: &Target,
    started: Instant,
    pace: Pace,
    comm: &Comm,
    progress: &mut Option<Box<dyn Progress>>,
) -> Result<Raced> {
    // Priced at the integrand's own cost per point: the learner's includes drawing its points,
    // which the rival's do not pay (on cheap integrands most of it).
    let per_point = pace.integrand_seconds_per_eval.unwrap_or(f64::INFINITY);
    if rival.warm_up_evals(target) as f64 * per_point > LEAST_SHARE * pace.training_seconds {
        return Ok(Raced::Lost { evals: 0 });
    }
    // The rival may spend half of the limits (the learner's first batches included), so that
    // the learner has the other half when the rival does not meet the target in its.
    let half = Target {
        max_evals: target.max_evals / 2,
        max_seconds: target.max_seconds.map(|s| s / 2.0),
        ..*target
    };
    let own = Target {
        max_evals: half.max_evals.saturating_sub(pace.evals),
        ..half
    };
    if rival.check_target(&own).is_err() {
        return Ok(Raced::Lost { evals: 0 });
    }
    rival.set_comm(comm.clone());
    rival.set_progress(progress.take());
    let race = Race {
        least: LEAST_SHARE * pace.training_seconds,
        rival: ESTIMATE_TOO * pace.training_seconds,
    };
    let pursued = rival.race_to(f, &half, started, pace.evals, race);
    *progress = rival.take_progress();
    Ok(match pursued? {
        Pursued::Done(mut r) if r.warnings.is_empty() && r.stop == Some(Stop::Target) => {
            r.answered_by = Some(rival.method());
            Raced::Won(r)
        }
        Pursued::Done(r) => Raced::Lost {
            evals: r.n_eval - pace.evals,
        },
        Pursued::GaveUp { evals } => Raced::Lost { evals },
    })
}
