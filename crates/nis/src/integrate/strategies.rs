//! The choices on a learner's road to a target. A method that learns its sampler (NIS) trains a few
//! batches as a probe and pauses; between the probe and the rest of its training the road runs the
//! strategies that may change the run: racing a rival ([`race`], `race.rs`), whose answer ends it,
//! and switching the learner to a cheaper layout on a smooth integrand, which starts its training
//! afresh. Then the learner trains on and estimates. The learner ([`Learning`]) only measures,
//! trains and estimates when told; the choices are made here, and the rival is whatever its
//! [`RivalFactory`] builds, so no method imports another.

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
    use crate::integrate::race::{Pursued, Race, Rival};
    use crate::integrate::{Integrator, Method, Stop};

    /// A rival that answers at once with no warning in one dimension, and gives up after 500
    /// evaluations in more.
    struct FakeRival {
        dim: usize,
    }

    fn fake_rival(dim: usize, _: u64, _: TrainOn) -> Result<Box<dyn Rival>> {
        Ok(Box::new(FakeRival { dim }))
    }

    impl Integrator for FakeRival {
        fn method(&self) -> Method {
            Method::Vegas
        }
        fn dim(&self) -> usize {
            self.dim
        }
        fn integrate(&mut self, _: &dyn Integrand, _: u64) -> Result<IntegrationResult> {
            unreachable!("a rival only races")
        }
        fn integrate_to(&mut self, _: &dyn Integrand, _: &Target) -> Result<IntegrationResult> {
            unreachable!("a rival only races")
        }
        fn check_target(&self, _: &Target) -> Result<()> {
            Ok(())
        }
        fn set_progress(&mut self, _: Option<Box<dyn Progress>>) {}
        fn set_comm(&mut self, _: Comm) {}
    }

    impl Rival for FakeRival {
        fn warm_up_evals(&self, _: &Target) -> u64 {
            0
        }
        fn race_to(
            &mut self,
            _: &dyn Integrand,
            _: &Target,
            _: Instant,
            _: u64,
            _: Race,
        ) -> Result<Pursued> {
            if self.dim > 1 {
                return Ok(Pursued::GaveUp { evals: 500 });
            }
            Ok(Pursued::Done(Box::new(IntegrationResult {
                value: 1.0,
                stop: Some(Stop::Target),
                ..IntegrationResult::default()
            })))
        }
        fn take_progress(&mut self) -> Option<Box<dyn Progress>> {
            None
        }
    }

    /// A learner in `dim` dimensions that records what the road asks of it; its probe pauses
    /// when asked and shows `smooth`, with room to restart unless a rival spent evaluations.
    struct Fake {
        dim: usize,
        rival: Option<RivalFactory>,
        relayouts: bool,
        smooth: bool,
        paused: Option<bool>,
        rest: Option<(u64, bool)>,
        estimated: bool,
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
                integrand_seconds_per_eval: Some(0.0),
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
            self.rival
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
                dim: self.dim,
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
            self.estimated = true;
            Ok(IntegrationResult::default())
        }
    }

    fn run(dim: usize, rival: bool, relayouts: bool, smooth: bool) -> (Fake, IntegrationResult) {
        let mut fake = Fake {
            dim,
            rival: rival.then_some(fake_rival as RivalFactory),
            relayouts,
            smooth,
            paused: None,
            rest: None,
            estimated: false,
            comm: Comm::default(),
            progress: None,
        };
        let r = learn_to(&mut fake, &|x: &[f64]| x[0], &Target::rel(1e-2)).unwrap();
        (fake, r)
    }

    #[test]
    fn a_learner_without_strategies_trains_once_and_a_smooth_probe_switches_its_layout() {
        let (plain, _) = run(1, false, false, true);
        assert_eq!((plain.paused, plain.rest), (Some(false), None));
        assert!(plain.estimated);
        let (rough, _) = run(1, false, true, false);
        assert_eq!((rough.paused, rough.rest), (Some(true), Some((0, false))));
        let (smooth, _) = run(1, false, true, true);
        assert_eq!((smooth.paused, smooth.rest), (Some(true), Some((0, true))));
    }

    #[test]
    fn a_won_race_answers_and_a_lost_one_counts_the_rivals_evaluations() {
        let (won, r) = run(1, true, true, true);
        assert_eq!(
            (won.paused, won.rest, won.estimated),
            (Some(true), None, false)
        );
        assert_eq!(r.answered_by, Some(Method::Vegas));
        // The rival's 500 evaluations leave no room to restart here.
        let (lost, r) = run(2, true, true, true);
        assert_eq!((lost.rest, lost.estimated), (Some((500, false)), true));
        assert_eq!(r.answered_by, None);
    }
}
