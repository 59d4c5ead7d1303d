//! One road to a target for every method: [`drive`] asks the [`Pursuit`] for the next
//! iteration, has the method's [`Stepper`] draw it, and records it, until the target or a limit
//! ends the run or the stepper gives up (a racing VEGAS+, `integrate/race.rs`). The methods
//! differ only in how they size, draw and keep an iteration.

use super::{Prior, Pursuit, Step};
use crate::comm::Comm;
use crate::error::Result;
use crate::integrate::result::Iteration;

/// A method's part in a run to a target: the iterations of its estimate.
pub(crate) trait Stepper {
    /// The next iteration's fewest and preferred evaluations, before the pursuit plans it;
    /// `elapsed` is [`Pursuit::elapsed`] now. A method may update `prior` or lay out its
    /// sampler anew (VEGAS+'s strata for larger iterations) here.
    fn size(&mut self, pursuit: &Pursuit, prior: &mut Prior, elapsed: f64) -> (u64, u64);

    /// Whether to draw `step`: `false` gives the run up (a race the method is predicted to lose).
    fn proceed(&mut self, step: Step, pursuit: &Pursuit, prior: &Prior) -> bool {
        let _ = (step, pursuit, prior);
        true
    }

    /// Draws the iteration of `step` and updates `prior` with what it measured; evaluations
    /// spent outside the estimate's iterations go to [`Pursuit::spend`].
    fn draw(&mut self, step: Step, pursuit: &mut Pursuit, prior: &mut Prior) -> Result<Iteration>;

    /// Keeps the iteration the pursuit has just recorded (adds it to the estimate, reports).
    fn keep(&mut self, iteration: Iteration) -> Result<()>;
}

/// How a [`drive`] ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Ended {
    /// The target or a limit ([`Pursuit::finish`] says which).
    Stopped,
    /// The stepper gave up ([`Stepper::proceed`]).
    GaveUp,
}

/// Runs `stepper`'s iterations as `pursuit` plans them from `prior`, every rank of `comm` alike.
pub(crate) fn drive(
    pursuit: &mut Pursuit,
    prior: &mut Prior,
    comm: &Comm,
    stepper: &mut dyn Stepper,
) -> Result<Ended> {
    loop {
        let elapsed = pursuit.elapsed(comm);
        let (least, chunk) = stepper.size(pursuit, prior, elapsed);
        let Some(step) = pursuit.next(*prior, least, chunk, elapsed)? else {
            return Ok(Ended::Stopped);
        };
        if !stepper.proceed(step, pursuit, prior) {
            return Ok(Ended::GaveUp);
        }
        let iteration = stepper.draw(step, pursuit, prior)?;
        pursuit.record(step, &iteration);
        stepper.keep(iteration)?;
    }
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use super::*;
    use crate::error::Error;
    use crate::integrate::{Source, Stop, Target};

    /// Iterations of variance `var` per evaluation around 1; gives up before iteration
    /// `give_up` (counting from 0), fails at `fail`.
    struct Fake {
        var: f64,
        give_up: usize,
        fail: usize,
        drawn: usize,
        kept: Vec<u64>,
    }

    impl Fake {
        fn new(var: f64) -> Fake {
            Fake {
                var,
                give_up: usize::MAX,
                fail: usize::MAX,
                drawn: 0,
                kept: Vec::new(),
            }
        }
    }

    impl Stepper for Fake {
        fn size(&mut self, _: &Pursuit, _: &mut Prior, _: f64) -> (u64, u64) {
            (10, 2_000)
        }

        fn proceed(&mut self, _: Step, _: &Pursuit, _: &Prior) -> bool {
            self.drawn < self.give_up
        }

        fn draw(&mut self, step: Step, _: &mut Pursuit, prior: &mut Prior) -> Result<Iteration> {
            if self.drawn == self.fail {
                return Err(Error::IntegrandFailed {
                    message: "failed".into(),
                });
            }
            self.drawn += 1;
            prior.var_per_eval = self.var;
            let n = step.evals;
            let v = vec![self.var / n as f64];
            Ok(Iteration::new(
                Source::Final,
                vec![1.0],
                v,
                n,
                1.0,
                n as f64,
            ))
        }

        fn keep(&mut self, iteration: Iteration) -> Result<()> {
            self.kept.push(iteration.evals);
            Ok(())
        }
    }

    fn run(stepper: &mut Fake, target: Target) -> (Result<Ended>, Pursuit) {
        let mut prior = Prior {
            var_per_eval: 1.0,
            estimate: 1.0,
            seconds_per_eval: 0.0,
        };
        let mut pursuit = Pursuit::new(target, Instant::now(), 0);
        let ended = drive(&mut pursuit, &mut prior, &Comm::default(), stepper);
        (ended, pursuit)
    }

    #[test]
    fn every_drawn_iteration_is_recorded_and_kept_until_the_target() {
        let mut fake = Fake::new(4.0);
        let (ended, pursuit) = run(&mut fake, Target::rel(1e-2));
        assert_eq!(ended.unwrap(), Ended::Stopped);
        assert_eq!(pursuit.stop(), Some(Stop::Target));
        assert_eq!(fake.kept.len(), fake.drawn);
        assert_eq!(pursuit.shares().len(), fake.drawn);
        assert!((pursuit.shares().iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // V/(0.95σ)² = 44 321 evaluations at 4 per evaluation, in iterations of about 2000.
        let evals: u64 = fake.kept.iter().sum();
        assert!((44_000..46_500).contains(&evals), "{evals}");
    }

    #[test]
    fn a_stepper_that_gives_up_ends_the_drive_before_drawing() {
        let mut fake = Fake::new(1.0);
        fake.give_up = 2;
        let (ended, pursuit) = run(&mut fake, Target::rel(1e-3));
        assert_eq!(ended.unwrap(), Ended::GaveUp);
        assert_eq!((fake.drawn, fake.kept.len()), (2, 2));
        assert_eq!(pursuit.shares().len(), 2);
        assert_eq!(pursuit.stop(), None);
    }

    #[test]
    fn an_error_of_the_draw_ends_the_drive_with_it() {
        let mut fake = Fake::new(1.0);
        fake.fail = 1;
        let (ended, pursuit) = run(&mut fake, Target::rel(1e-3));
        assert!(ended.unwrap_err().to_string().contains("failed"));
        assert_eq!(pursuit.shares().len(), 1);
    }
}
