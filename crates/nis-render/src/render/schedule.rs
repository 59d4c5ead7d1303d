//! When a guided render trains: Practical Path Guiding's schedule (Müller, Gross & Novák 2017,
//! §5.3). Training passes of 1, 2, 4, … samples per pixel, as many as fit into half of the
//! budget, then one final pass with the rest (at least half); every training pass doubles the
//! data the next distribution is learned from. With a time budget the passes keep doubling while
//! the next one, at the rate measured so far, ends within half of the time.

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

#[cfg(test)]
mod tests {
    use super::*;

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
