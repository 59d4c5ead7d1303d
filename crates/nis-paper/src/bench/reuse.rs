//! `nis bench reuse`: every evaluation counts (issue 13, part 3), measured.
//!
//! - **Training in the estimate** ([`NisConfig::reuse_training`]): the NIS error bar of camel
//!   d = 4 and 8 at one budget, with the final phase alone and with the last training batches
//!   joining it, over the same seeds (same flows, same points: only the combination differs).
//! - **Replay** ([`NisConfig::replay_batches`], [`NisConfig::replay_steps`]): the relative variance
//!   per evaluation of the flow after training with N evaluations (estimated with a fixed final
//!   budget), with and without replaying earlier batches, and the training's wall time: what the
//!   extra passes buy per evaluation and what they cost per second.
//!
//! Writes the section "reuse" of `docs/results/integration.md`.

use std::path::Path;
use std::time::Instant;

use nis::integrate::nis::{NisConfig, NisIntegrator};
use nis::integrate::{IntegrationResult, Integrator};

use crate::error::Result;
use crate::report;

/// What to run.
#[derive(Clone, Debug)]
pub struct Options {
    /// Evaluations of the error-bar comparison.
    pub evals: u64,
    /// Seeds 0..seeds of the error-bar comparison.
    pub seeds: u64,
    /// The share of training batches reused in the estimate, against 0.
    pub reuse: f64,
    /// Training budgets of the replay comparison.
    pub train_budgets: Vec<u64>,
    /// Evaluations that estimate the trained flow's variance.
    pub estimate_evals: u64,
    /// Replay settings compared with none: (kept batches, extra steps per batch).
    pub replays: Vec<(usize, usize)>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            evals: 1_000_000,
            seeds: 3,
            reuse: 0.5,
            train_budgets: vec![100_000, 400_000],
            estimate_evals: 200_000,
            replays: vec![(8, 1), (8, 3)],
        }
    }
}

/// The number of runs, for a progress bar.
fn count(o: &Options) -> usize {
    2 * 2 * o.seeds as usize + 3 * o.train_budgets.len() * (1 + o.replays.len())
}

/// Runs both comparisons; `log(done, total, line)` after every run. Writes the section "reuse" of
/// `docs` and returns its Markdown.
pub fn run(o: &Options, docs: &Path, log: &mut dyn FnMut(usize, usize, &str)) -> Result<String> {
    let total = count(o);
    let mut done = 0;
    let mut estimate = format!(
        "Error bar of `nis integrate camel --method nis --evals {}` (defaults otherwise) with the \
         final phase alone and with the last {:.0}% of the training batches in the estimate \
         (`reuse_training`), same seeds, so the same flows and points. Pull = (value − exact)/σ.\n\n\
         | integrand | d | seed | σ, final only | σ, with training | ratio | pull, final only | \
         pull, with training |\n|---|---:|---:|---:|---:|---:|---:|---:|\n",
        o.evals,
        100.0 * o.reuse
    );
    for d in [4, 8] {
        let f = nis::integrands::by_name("camel", Some(d))?;
        let mut ratios = Vec::new();
        for seed in 0..o.seeds {
            let mut r = Vec::new();
            for reuse in [0.0, o.reuse] {
                let config = NisConfig {
                    reuse_training: reuse,
                    ..NisConfig::builder().seed(seed).build()?
                };
                let res = NisIntegrator::new(d, config)?.integrate(&f, o.evals)?;
                done += 1;
                log(
                    done,
                    total,
                    &format!(
                        "camel d={d} seed {seed} reuse {reuse}: {:.6e} ± {:.3e} ({:.1} s)",
                        res.value, res.std_err, res.seconds
                    ),
                );
                r.push(res);
            }
            let pull = |r: &IntegrationResult| (r.value - f.exact) / r.std_err;
            ratios.push(r[1].std_err / r[0].std_err);
            estimate.push_str(&format!(
                "| camel | {d} | {seed} | {:.3e} | {:.3e} | {:.3} | {:+.2} | {:+.2} |\n",
                r[0].std_err,
                r[1].std_err,
                r[1].std_err / r[0].std_err,
                pull(&r[0]),
                pull(&r[1])
            ));
        }
        let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
        estimate.push_str(&format!("| camel | {d} | mean | | | {mean:.3} | | |\n"));
    }

    let mut replay = format!(
        "Relative variance per evaluation Var(f/q)/F² of the flow after training with N \
         evaluations (defaults, seed 0; estimated from {} further evaluations), and the training's \
         wall time, without and with replay of earlier batches (B kept batches, S extra off-policy \
         steps per batch).\n\n| integrand | d | N |",
        o.estimate_evals
    );
    let mut settings = vec![(0usize, 0usize)];
    settings.extend(&o.replays);
    for (b, s) in &settings {
        if *s == 0 {
            replay.push_str(" no replay: rel.var | s |");
        } else {
            replay.push_str(&format!(" B={b} S={s}: rel.var | s |"));
        }
    }
    replay.push_str("\n|---|---:|---:|");
    for _ in &settings {
        replay.push_str("---:|---:|");
    }
    replay.push('\n');
    for (name, d) in [("camel", 4), ("camel", 8), ("gauss", 8)] {
        let f = nis::integrands::by_name(name, Some(d))?;
        for &n in &o.train_budgets {
            replay.push_str(&format!("| {name} | {d} | {n} |"));
            for &(batches, steps) in &settings {
                let config = NisConfig::builder()
                    .seed(0)
                    .replay(batches, steps)
                    .build()?;
                let mut nis = NisIntegrator::new(d, config)?;
                let started = Instant::now();
                nis.train(&f, n)?;
                let seconds = started.elapsed().as_secs_f64();
                let r = nis.estimate(&f, o.estimate_evals)?;
                done += 1;
                log(
                    done,
                    total,
                    &format!(
                        "{name} d={d} N={n} replay ({batches}, {steps}): rel.var {:.3e}, \
                         training {seconds:.1} s",
                        r.rel_var_per_eval
                    ),
                );
                replay.push_str(&format!(" {:.3e} | {seconds:.1} |", r.rel_var_per_eval));
            }
            replay.push('\n');
        }
    }
    let body = format!("{estimate}\n{replay}");
    report::write_section(
        docs,
        "reuse",
        "Every evaluation counts (`nis bench reuse`)",
        &body,
    )?;
    Ok(body)
}
