//! When a guided render trains: Practical Path Guiding's schedule (Müller, Gross & Novák 2017,
//! §5.3). Training passes of 1, 2, 4, … samples per pixel, as many as fit into half of the
//! budget, then one final pass with the rest (at least half); every training pass doubles the
//! data the next distribution is learned from. With a time budget the passes keep doubling while
//! the next one, at the rate measured so far, ends within half of the time.
//!
//! The passes that only render (a plain render's, and the final phase's) with a time budget
//! each take about half of the time left at the rate measured so far in their phase
//! (`rendering_pass_spp`): a few large passes, which keep every thread busy, rather than
//! one-sample passes whose last wave of the image leaves threads idle.

use std::time::Instant;

use super::Budget;

/// The passes of a guided render of a fixed sample count.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TrainingSchedule {
    /// Samples per pixel of each training pass, in order (1, 2, 4, …).
    pub training: Vec<u32>,
    /// Samples per pixel of the final pass, rendered with the trained guide.
    pub final_spp: u32,
}

/// The schedule of a guided render of `spp` samples per pixel (see the module documentation).
pub fn training_schedule(spp: u32) -> TrainingSchedule {
    let mut training = Vec::new();
    let mut used = 0u32;
    let mut next = 1u32;
    while used + next <= spp / 2 {
        training.push(next);
        used += next;
        next *= 2;
    }
    TrainingSchedule {
        training,
        final_spp: spp - used,
    }
}

/// The training passes of a render with `budget`, decided one at a time.
pub(super) struct TrainingPasses {
    budget: Budget,
    /// The fixed schedule of a sample budget (empty for a time budget).
    schedule: Vec<u32>,
    start: Instant,
}

impl TrainingPasses {
    /// The training passes of a render with `budget` that started at `start`.
    pub(super) fn new(budget: Budget, start: Instant) -> Self {
        let schedule = match budget {
            Budget::Samples(n) => training_schedule(n).training,
            Budget::Seconds(_) => Vec::new(),
        };
        Self {
            budget,
            schedule,
            start,
        }
    }

    /// Samples per pixel of training pass `index`, after `spp` samples per pixel so far, or
    /// `None` when training is over.
    pub(super) fn next(&self, index: usize, spp: u32) -> Option<u32> {
        match self.budget {
            Budget::Samples(_) => self.schedule.get(index).copied(),
            Budget::Seconds(t) => {
                // Doubling passes while the next one ends within half of the time.
                let count = 1u32 << index.min(31);
                let elapsed = self.start.elapsed().as_secs_f64();
                let estimate = elapsed / f64::from(spp.max(1)) * f64::from(count);
                (index == 0 || elapsed + estimate <= t / 2.0).then_some(count)
            }
        }
    }
}

/// The share of the time left that a rendering pass of a time budget is sized to take.
const PASS_SHARE_OF_TIME_LEFT: f64 = 0.5;

/// Samples per pixel of the next rendering pass of a time budget (see the module
/// documentation), after `done` samples per pixel that took `seconds` in this phase, with
/// `left` seconds left: one while there is no rate yet, then about
/// [`PASS_SHARE_OF_TIME_LEFT`] of the time left, at least one.
pub(super) fn rendering_pass_spp(done: u32, seconds: f64, left: f64) -> u32 {
    // Also a NaN clock reading: no rate, or no time.
    if done == 0 || seconds.is_nan() || seconds <= 0.0 || left.is_nan() || left <= 0.0 {
        return 1;
    }
    let per_spp = seconds / f64::from(done);
    // Bounded so that a clock that barely moved cannot ask for an absurd pass.
    (left * PASS_SHARE_OF_TIME_LEFT / per_spp).clamp(1.0, f64::from(1u32 << 16)) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rendering_pass_takes_half_of_the_time_left_at_the_measured_rate() {
        // No rate yet: one sample.
        assert_eq!(rendering_pass_spp(0, 0.0, 10.0), 1);
        // 4 spp in 1 s, 10 s left: 5 s at 4 spp/s.
        assert_eq!(rendering_pass_spp(4, 1.0, 10.0), 20);
        // Less than a sample's time left, or none: still one, and the caller stops after it.
        assert_eq!(rendering_pass_spp(4, 1.0, 0.1), 1);
        assert_eq!(rendering_pass_spp(4, 1.0, -1.0), 1);
        // A clock that did not move is bounded.
        assert_eq!(rendering_pass_spp(4, 1e-300, 10.0), 1 << 16);
        // The passes of a steady rate halve the time left until one sample is all that fits:
        // a pass count logarithmic in the budget.
        let (rate, budget) = (100.0, 10.0);
        let (mut done, mut t, mut passes) = (0u32, 0.0, 0);
        while t < budget {
            let n = rendering_pass_spp(done, t, budget - t);
            done += n;
            t += f64::from(n) / rate;
            passes += 1;
        }
        assert!(
            (1000..=1002).contains(&done) && passes <= 14,
            "{done} spp in {passes} passes"
        );
    }

    #[test]
    fn training_takes_doubling_passes_within_half_of_the_budget() {
        let schedule = |training: Vec<u32>, final_spp| TrainingSchedule {
            training,
            final_spp,
        };
        assert_eq!(training_schedule(64), schedule(vec![1, 2, 4, 8, 16], 33));
        assert_eq!(training_schedule(16), schedule(vec![1, 2, 4], 9));
        assert_eq!(training_schedule(1), schedule(vec![], 1));
        assert_eq!(training_schedule(2), schedule(vec![1], 1));
        for spp in 1..300 {
            let TrainingSchedule {
                training,
                final_spp: rest,
            } = training_schedule(spp);
            let used: u32 = training.iter().sum();
            assert_eq!(used + rest, spp);
            assert!(rest >= used && rest >= 1, "spp {spp}");
            assert!(training.iter().enumerate().all(|(i, &p)| p == 1 << i));
        }
    }

    #[test]
    fn a_time_budget_trains_at_least_once_then_while_the_next_pass_fits_half_of_it() {
        let passes = TrainingPasses::new(Budget::Seconds(1e9), Instant::now());
        assert_eq!(passes.next(0, 0), Some(1));
        assert_eq!(passes.next(3, 7), Some(8));
        // Started 10 ms ago with a budget of 1 ms: only the first pass.
        let started = Instant::now() - std::time::Duration::from_millis(10);
        let passes = TrainingPasses::new(Budget::Seconds(1e-3), started);
        assert_eq!(passes.next(0, 0), Some(1));
        assert_eq!(passes.next(1, 1), None);
        let passes = TrainingPasses::new(Budget::Samples(16), Instant::now());
        assert_eq!((passes.next(2, 3), passes.next(3, 7)), (Some(4), None));
    }
}
