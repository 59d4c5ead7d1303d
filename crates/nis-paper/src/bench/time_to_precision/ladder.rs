//! The measurement rule of `nis bench time-to-precision`, on run records alone (no clocks here,
//! so it can be tested on synthetic records): fresh runs at budgets doubling from 10⁴; the time
//! to a target is the wall time of the first run whose relative error std_err/|value| is below
//! the target with |pull| < [`MAX_PULL`] (and, asked for trusted answers, no warning); a ladder
//! stops when every target is reached or when its next run would take it past the wall-time
//! cap; over seeds, the median.

/// The first budget of a ladder, in evaluations.
pub const FIRST_BUDGET: u64 = 10_000;

/// A run whose |value − exact| exceeds this many of its own standard errors is a confident wrong
/// answer: it never counts as reaching a target, however small its error bar.
pub const MAX_PULL: f64 = 4.0;

/// One fresh run of a method at one budget.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Run {
    /// Evaluations the run spent (training included).
    pub evals: u64,
    /// Its wall time in seconds.
    pub seconds: f64,
    /// The estimate.
    pub value: f64,
    /// Its standard error.
    pub std_err: f64,
    /// Whether its warning disowns it: the result warned that its error bar cannot be trusted
    /// and the bench counts only answers a user could take as they are (`--trusted`).
    pub disowned: bool,
}

impl Run {
    /// std_err/|value| (∞ for a zero or non-finite estimate).
    pub fn rel_err(&self) -> f64 {
        let r = self.std_err / self.value.abs();
        if r.is_finite() {
            r
        } else {
            f64::INFINITY
        }
    }

    /// (value − exact)/std_err.
    pub fn pull(&self, exact: f64) -> f64 {
        (self.value - exact) / self.std_err
    }

    /// Whether the answer counts: a finite positive error bar with |pull| < [`MAX_PULL`], not
    /// disowned by its warning.
    pub fn honest(&self, exact: f64) -> bool {
        self.std_err > 0.0 && self.pull(exact).abs() < MAX_PULL && !self.disowned
    }

    /// Whether this run reaches `target` honestly within `cap` seconds.
    pub fn reaches(&self, target: f64, exact: f64, cap: f64) -> bool {
        self.rel_err() < target && self.honest(exact) && self.seconds <= cap
    }
}

/// The budget of the next run of a ladder, or `None` when it is done: every target reached, or
/// the next run (predicted to take twice the last one, as it has twice its evaluations) would take
/// the ladder's total wall time past `cap`.
pub fn next_budget(runs: &[Run], targets: &[f64], exact: f64, cap: f64) -> Option<u64> {
    let Some(last) = runs.last() else {
        return Some(FIRST_BUDGET);
    };
    let done = targets
        .iter()
        .all(|&t| runs.iter().any(|r| r.reaches(t, exact, cap)));
    let spent: f64 = runs.iter().map(|r| r.seconds).sum();
    if done || spent + 2.0 * last.seconds > cap {
        return None;
    }
    Some(2 * last.evals)
}

/// Runs a ladder: `run(evals)` at each budget [`next_budget`] gives, until it gives none.
pub fn ladder<E>(
    targets: &[f64],
    exact: f64,
    cap: f64,
    mut run: impl FnMut(u64) -> Result<Run, E>,
) -> Result<Vec<Run>, E> {
    let mut runs = Vec::new();
    while let Some(evals) = next_budget(&runs, targets, exact, cap) {
        runs.push(run(evals)?);
    }
    Ok(runs)
}

/// What one ladder (one seed) says about one target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// Reached by a run of this many seconds and evaluations.
    Reached { seconds: f64, evals: u64 },
    /// Not reached within the cap; the smallest relative error of an honest run (∞ if none was
    /// honest).
    Capped { rel_err: f64 },
}

/// The outcome of one ladder for `target`: its first run reaching it, else the best honest error.
pub fn outcome(runs: &[Run], target: f64, exact: f64, cap: f64) -> Outcome {
    match runs.iter().find(|r| r.reaches(target, exact, cap)) {
        Some(r) => Outcome::Reached {
            seconds: r.seconds,
            evals: r.evals,
        },
        None => Outcome::Capped {
            rel_err: runs
                .iter()
                .filter(|r| r.honest(exact))
                .map(Run::rel_err)
                .fold(f64::INFINITY, f64::min),
        },
    }
}

/// The median outcome over seeds, a capped seed counting as slower than any reached one: the
/// upper median (the element at n/2 of the seeds sorted by time), so with an even number of seeds
/// it errs on the slow side. If it is capped, the error reported is the median over the capped
/// seeds of their best honest errors (upper median too).
pub fn median(outcomes: &[Outcome]) -> Option<Outcome> {
    let key = |o: &Outcome| match *o {
        Outcome::Reached { seconds, .. } => (0, seconds),
        Outcome::Capped { rel_err } => (1, rel_err),
    };
    let mut sorted = outcomes.to_vec();
    sorted.sort_by(|a, b| {
        let (ka, kb) = (key(a), key(b));
        ka.0.cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
    });
    let m = *sorted.get(sorted.len() / 2)?;
    if let Outcome::Capped { .. } = m {
        let capped: Vec<&Outcome> = sorted
            .iter()
            .filter(|o| matches!(o, Outcome::Capped { .. }))
            .collect();
        return Some(*capped[capped.len() / 2]);
    }
    Some(m)
}

/// Whether more seeds can change the median for any target: not once more than half of
/// `planned` seeds are capped on every target (the median is then "> cap" whatever follows).
pub fn worth_more_seeds(outcomes_per_target: &[Vec<Outcome>], planned: usize) -> bool {
    outcomes_per_target.iter().any(|o| {
        o.iter()
            .filter(|x| matches!(x, Outcome::Capped { .. }))
            .count()
            <= planned / 2
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXACT: f64 = 1.0;

    /// A run at `evals` taking `seconds`, with relative error `rel_err` and its value `pull`
    /// standard errors from the exact value.
    fn run(evals: u64, seconds: f64, rel_err: f64, pull: f64) -> Run {
        let std_err = rel_err * EXACT;
        Run {
            evals,
            seconds,
            value: EXACT + pull * std_err,
            std_err,
            disowned: false,
        }
    }

    #[test]
    fn the_ladder_doubles_from_ten_thousand_and_stops_at_the_last_target() {
        // Relative error 1e-2/√(evals/10⁴), 1 ms per 10⁴ evaluations: 1e-3 needs 100× more
        // evaluations, so the first budget below it is 10⁴·2⁷ = 1.28·10⁶ (error 8.8e-4).
        let mut budgets = Vec::new();
        let runs = ladder::<()>(&[1e-3], EXACT, 300.0, |evals| {
            budgets.push(evals);
            let k = evals as f64 / 1e4;
            Ok(run(evals, 1e-3 * k, 1e-2 / k.sqrt(), 0.5))
        })
        .unwrap();
        let expected: Vec<u64> = (0..8).map(|i| 10_000 << i).collect();
        assert_eq!(budgets, expected);
        assert_eq!(runs.len(), 8);
        match outcome(&runs, 1e-3, EXACT, 300.0) {
            Outcome::Reached { seconds, evals } => {
                assert_eq!(evals, 1_280_000);
                assert!((seconds - 0.128).abs() < 1e-12);
            }
            o => panic!("expected reached, got {o:?}"),
        }
    }

    #[test]
    fn a_confidently_wrong_run_does_not_reach_the_target() {
        let runs = [
            run(10_000, 0.1, 1e-4, 6.0),  // tiny error bar, 6σ off: wrong
            run(20_000, 0.2, 5e-4, -4.5), // wrong the other way
            run(40_000, 0.4, 5e-4, 3.9),  // honest
        ];
        assert_eq!(
            outcome(&runs, 1e-3, EXACT, 300.0),
            Outcome::Reached {
                seconds: 0.4,
                evals: 40_000
            }
        );
        // Not below 1e-4 honestly: capped, with the best honest error (the last run's, not the
        // wrong first run's 1e-4).
        assert_eq!(
            outcome(&runs, 1e-4, EXACT, 300.0),
            Outcome::Capped {
                rel_err: runs[2].rel_err()
            }
        );
        // A wrong run keeps the ladder going.
        assert_eq!(next_budget(&runs[..1], &[1e-3], EXACT, 300.0), Some(20_000));
    }

    #[test]
    fn a_run_disowned_by_its_warning_does_not_reach_the_target() {
        let warned = Run {
            disowned: true,
            ..run(10_000, 0.1, 5e-4, 0.5)
        };
        let runs = [warned, run(20_000, 0.2, 4e-4, 0.5)];
        assert_eq!(
            outcome(&runs, 1e-3, EXACT, 300.0),
            Outcome::Reached {
                seconds: 0.2,
                evals: 20_000
            }
        );
        assert_eq!(next_budget(&runs[..1], &[1e-3], EXACT, 300.0), Some(20_000));
        // Alone, it leaves the target capped with no answer that counts.
        assert_eq!(
            outcome(&runs[..1], 1e-3, EXACT, 300.0),
            Outcome::Capped {
                rel_err: f64::INFINITY
            }
        );
    }

    #[test]
    fn the_cap_stops_a_ladder_before_a_run_that_would_pass_it() {
        // Spent 10 + 20 + 40 = 70 s; the next run would take ~80 s: 150 > 100.
        let runs = [
            run(10_000, 10.0, 0.1, 0.0),
            run(20_000, 20.0, 0.07, 0.0),
            run(40_000, 40.0, 0.05, 0.0),
        ];
        assert_eq!(next_budget(&runs, &[1e-3], EXACT, 100.0), None);
        assert_eq!(next_budget(&runs, &[1e-3], EXACT, 150.0), Some(80_000));
        assert_eq!(
            outcome(&runs, 1e-3, EXACT, 100.0),
            Outcome::Capped {
                rel_err: runs[2].rel_err()
            }
        );
        // A run that itself took longer than the cap does not count as reaching.
        let slow = [run(10_000, 120.0, 1e-4, 0.0)];
        assert!(matches!(
            outcome(&slow, 1e-3, EXACT, 100.0),
            Outcome::Capped { .. }
        ));
        // No honest run at all: the error reached is infinite.
        let wrong = [run(10_000, 1.0, 1e-4, 10.0)];
        assert_eq!(
            outcome(&wrong, 1e-3, EXACT, 100.0),
            Outcome::Capped {
                rel_err: f64::INFINITY
            }
        );
    }

    #[test]
    fn the_median_counts_capped_seeds_as_slowest() {
        let r = |s: f64| Outcome::Reached {
            seconds: s,
            evals: (s * 1e4) as u64,
        };
        let c = |e: f64| Outcome::Capped { rel_err: e };
        assert_eq!(median(&[r(3.0), r(1.0), r(2.0)]), Some(r(2.0)));
        assert_eq!(median(&[c(1e-2), r(5.0), r(1.0)]), Some(r(5.0)));
        assert_eq!(median(&[c(2e-3), r(1.0), c(5e-3)]), Some(c(5e-3)));
        assert_eq!(median(&[c(2e-3), c(1e-3), c(5e-3)]), Some(c(2e-3)));
        // Even counts take the slower of the middle two.
        assert_eq!(median(&[r(1.0), r(4.0)]), Some(r(4.0)));
        assert_eq!(median(&[]), None);
    }

    #[test]
    fn seeds_stop_once_the_median_is_capped_for_every_target() {
        let r = Outcome::Reached {
            seconds: 1.0,
            evals: 10_000,
        };
        let c = Outcome::Capped { rel_err: 1e-2 };
        assert!(worth_more_seeds(&[vec![c], vec![c]], 3));
        assert!(!worth_more_seeds(&[vec![c, c], vec![c, c]], 3));
        assert!(worth_more_seeds(&[vec![c, c], vec![r, c]], 3));
    }
}
