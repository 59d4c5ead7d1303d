//! The choices on a learner's road to a target (issue 52, "one road to a target"). A method
//! that learns its sampler (NIS) trains a few batches as a probe and pauses; between the probe
//! and the rest of its training the road runs the strategies that may change the run: racing a
//! rival ([`race`], `race.rs`), whose answer ends it, and switching the learner to a cheaper
//! layout on a smooth integrand, which starts its training afresh. Then the learner trains on
//! and estimates. The learner ([`Learning`]) only measures, trains and estimates when told; the
//! choices are made here, and the rival is whatever its [`RivalFactory`] builds, so no method
//! imports another.

use std::time::Instant;

use super::race::{race, Pace, Raced, RivalFactory, RACE_SEED_SALT};
use super::{Integrand, IntegrationResult, Progress, Target, TrainOn};
use crate::comm::Comm;
use crate::error::Result;

/// A method that learns on its way to a target, as the road sees it.
pub(crate) trait Learning {
    /// Its run's training so far, between the strategies.
    type Training: Probed;

    /// What builds the rival to race, if it races one (as its settings say, untrained).
    fn rival(&self) -> Option<RivalFactory>;

    /// Whether a smooth probe may switch it to a cheaper layout (as its settings say, untrained).
    fn may_relayout(&self) -> bool;

    /// Checks `target` and `f`, then trains from the start of a run to `target` until its
    /// rule stops, or until the probe's batches when `pause`.
    fn train_first(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        pause: bool,
    ) -> Result<Self::Training>;

    /// Where its rival runs: its ranks and observer of progress, and what the rival is built
    /// from.
    fn lane(&mut self) -> Lane<'_>;

    /// Trains on after the pause, `spent` evaluations of a rival counted against the limits,
    /// first starting afresh with the cheaper layout when `relayout`.
    fn train_rest(
        &mut self,
        f: &dyn Integrand,
        training: &mut Self::Training,
        spent: u64,
        relayout: bool,
    ) -> Result<()>;

    /// The estimate after `training`, to `target`.
    fn estimate(
        &mut self,
        f: &dyn Integrand,
        target: &Target,
        started: Instant,
        training: Self::Training,
    ) -> Result<IntegrationResult>;
}

/// What the strategies read of a learner's training.
pub(crate) trait Probed {
    /// Whether it paused after the probe's batches (else it is over).
    fn paused(&self) -> bool;
    /// What the probe's batches measured, for a race.
    fn pace(&self) -> Pace;
    /// Whether the probe shows a smooth integrand, where the cheaper layout learns as well.
    fn smooth(&self) -> bool;
    /// Whether the limits, `spent` evaluations of a rival counted, leave room to train afresh.
    fn room_to_restart(&self, spent: u64) -> bool;
}

/// Where a learner's rival runs: the learner's dimension, seed, what it adapts to, ranks and
/// observer of progress (lent to the rival for the race).
pub(crate) struct Lane<'a> {
    pub(crate) dim: usize,
    pub(crate) seed: u64,
    pub(crate) train_on: TrainOn,
    pub(crate) comm: &'a Comm,
    pub(crate) progress: &'a mut Option<Box<dyn Progress>>,
}

/// Runs `learner` to `target`: its probe, the strategies it allows (module docs), the rest of
/// its training and its estimate.
pub(crate) fn learn_to<L: Learning>(
    learner: &mut L,
    f: &dyn Integrand,
    target: &Target,
) -> Result<IntegrationResult> {
    let started = Instant::now();
    let rival = learner.rival();
    let may_relayout = learner.may_relayout();
    let pause = rival.is_some() || may_relayout;
    let mut training = learner.train_first(f, target, pause)?;
    if training.paused() {
        // Evaluations the rival spent when it lost, counted but not used.
        let mut spent = 0;
        if let Some(make) = rival {
            match race_rival(learner, make, &training, f, target, started)? {
                Raced::Won(result) => return Ok(*result),
                Raced::Lost { evals } => spent += evals,
            }
        }
        let relayout = may_relayout && training.smooth() && training.room_to_restart(spent);
        learner.train_rest(f, &mut training, spent, relayout)?;
    }
    learner.estimate(f, target, started, training)
}

/// Races the rival `make` builds (its own seed) with the pace that the learner's `training`
/// measured over its probe.
fn race_rival<L: Learning>(
    learner: &mut L,
    make: RivalFactory,
    training: &L::Training,
    f: &dyn Integrand,
    target: &Target,
    started: Instant,
) -> Result<Raced> {
    let pace = training.pace();
    let lane = learner.lane();
    let mut rival = make(lane.dim, lane.seed ^ RACE_SEED_SALT, lane.train_on)?;
    race(
        &mut *rival,
        f,
        target,
        started,
        pace,
        lane.comm,
        lane.progress,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A learner that records what the road asks of it; its probe pauses when asked and shows
    /// `smooth`, with room to restart unless a rival spent evaluations.
    struct Fake {
        relayouts: bool,
        smooth: bool,
        paused: Option<bool>,
        rest: Option<(u64, bool)>,
        comm: Comm,
        progress: Option<Box<dyn Progress>>,
    }

    struct FakeTraining {
        paused: bool,
        smooth: bool,
    }

    impl Probed for FakeTraining {
        fn paused(&self) -> bool {
            self.paused
        }
        fn pace(&self) -> Pace {
            Pace {
                training_seconds: 1.0,
                integrand_seconds_per_eval: None,
                evals: 0,
            }
        }
        fn smooth(&self) -> bool {
            self.smooth
        }
        fn room_to_restart(&self, spent: u64) -> bool {
            spent == 0
        }
    }

    impl Learning for Fake {
        type Training = FakeTraining;
        fn rival(&self) -> Option<RivalFactory> {
            None
        }
        fn may_relayout(&self) -> bool {
            self.relayouts
        }
        fn train_first(
            &mut self,
            _: &dyn Integrand,
            _: &Target,
            pause: bool,
        ) -> Result<FakeTraining> {
            self.paused = Some(pause);
            Ok(FakeTraining {
                paused: pause,
                smooth: self.smooth,
            })
        }
        fn lane(&mut self) -> Lane<'_> {
            Lane {
                dim: 1,
                seed: 0,
                train_on: TrainOn::default(),
                comm: &self.comm,
                progress: &mut self.progress,
            }
        }
        fn train_rest(
            &mut self,
            _: &dyn Integrand,
            _: &mut FakeTraining,
            spent: u64,
            relayout: bool,
        ) -> Result<()> {
            self.rest = Some((spent, relayout));
            Ok(())
        }
        fn estimate(
            &mut self,
            _: &dyn Integrand,
            _: &Target,
            _: Instant,
            _: FakeTraining,
        ) -> Result<IntegrationResult> {
            Ok(IntegrationResult::default())
        }
    }

    fn run(relayouts: bool, smooth: bool) -> Fake {
        let mut fake = Fake {
            relayouts,
            smooth,
            paused: None,
            rest: None,
            comm: Comm::default(),
            progress: None,
        };
        learn_to(&mut fake, &|x: &[f64]| x[0], &Target::rel(1e-2)).unwrap();
        fake
    }

    #[test]
    fn a_learner_without_strategies_trains_once_and_a_smooth_probe_switches_its_layout() {
        let plain = run(false, true);
        assert_eq!((plain.paused, plain.rest), (Some(false), None));
        let rough = run(true, false);
        assert_eq!((rough.paused, rough.rest), (Some(true), Some((0, false))));
        let smooth = run(true, true);
        assert_eq!((smooth.paused, smooth.rest), (Some(true), Some((0, true))));
    }
}
