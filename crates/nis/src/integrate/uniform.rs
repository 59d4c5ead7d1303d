//! Plain Monte Carlo: uniform points, no adaptation. The baseline every method must beat.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::{check_dim, evaluate, Accumulator, Integrand, IntegrationResult, Progress};
use crate::error::Result;

/// Integrates `f` with `evals` uniform points in `iterations` equal iterations.
pub fn integrate(
    f: &dyn Integrand,
    dim: usize,
    evals: u64,
    iterations: usize,
    seed: u64,
    progress: Progress,
) -> Result<IntegrationResult> {
    check_dim(f, dim)?;
    let started = Instant::now();
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let iterations = iterations.clamp(1, evals.max(1) as usize);
    let mut acc = Accumulator::default();
    let mut done = 0;
    for it in 0..iterations {
        let n = (evals * (it as u64 + 1) / iterations as u64 - done).max(1) as usize;
        let x: Vec<f64> = (0..n * dim).map(|_| rng.random::<f64>()).collect();
        let w = evaluate(f, &x, dim)?;
        acc.add_weights(&w);
        done += n as u64;
        progress(done, evals, "uniform");
    }
    Ok(acc.finish(done, started, Vec::new()))
}
