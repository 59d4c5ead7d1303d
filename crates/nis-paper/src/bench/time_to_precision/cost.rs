//! A synthetic cost per point, so that the benchmark can ask what happens when the integrand is
//! expensive (a matrix element, a detector simulation): the wrapped integrand computes its value
//! and then spins on dependent floating-point arithmetic a calibrated number of times per point.
//! The value is unchanged; the work is real (its result feeds a `black_box`), and it is the same
//! code whether our integrators call it in process or `nis eval --spins` serves it to Python.

use std::hint::black_box;
use std::time::Instant;

use rayon::prelude::*;

use nis::integrate::{points_per_task, Integrand};

/// Points timed when calibrating.
const CALIBRATION_POINTS: usize = 1 << 15;

/// `inner` with `spins` iterations of dependent arithmetic added per point.
pub struct SyntheticCost<'a, F> {
    inner: &'a F,
    spins: u64,
}

impl<'a, F: Integrand> SyntheticCost<'a, F> {
    /// `inner` costing `spins` more iterations per point (0: no extra cost).
    pub fn new(inner: &'a F, spins: u64) -> SyntheticCost<'a, F> {
        SyntheticCost { inner, spins }
    }

    /// The spins per point.
    pub fn spins(&self) -> u64 {
        self.spins
    }
}

/// One point's extra work: a dependent chain of multiply-adds whose result is kept alive.
fn spin(seed: f64, spins: u64) {
    let mut a = seed;
    for _ in 0..spins {
        a = black_box(a.mul_add(0.999_999_9, 1e-7));
    }
    black_box(a);
}

impl<F: Integrand> Integrand for SyntheticCost<'_, F> {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> nis::Result<()> {
        self.inner.eval_batch(x, dim, out)?;
        if self.spins > 0 {
            // The same split as closures' `eval_batch`.
            out.par_chunks(points_per_task(out.len()))
                .for_each(|values| {
                    for &v in values {
                        spin(v, self.spins);
                    }
                });
        }
        Ok(())
    }
    fn dim(&self) -> Option<usize> {
        self.inner.dim()
    }
    fn components(&self) -> usize {
        self.inner.components()
    }
}

/// Wall microseconds per point of one `eval_batch` over a fixed grid of points (the median of
/// three timings after a warm-up), with every thread rayon has.
pub fn micros_per_point(f: &impl Integrand, dim: usize) -> nis::Result<f64> {
    let n = CALIBRATION_POINTS;
    // A fixed low-discrepancy set (Kronecker sequence): no randomness needed to time a function.
    let x: Vec<f64> = (0..n * dim)
        .map(|i| ((i / dim) as f64 * (0.754_877_666 + 0.1 * (i % dim) as f64)).fract())
        .collect();
    let mut out = vec![0.0; n * f.components()];
    f.eval_batch(&x, dim, &mut out)?;
    let mut t = Vec::with_capacity(3);
    for _ in 0..3 {
        let start = Instant::now();
        f.eval_batch(&x, dim, &mut out)?;
        t.push(start.elapsed().as_secs_f64());
    }
    t.sort_by(f64::total_cmp);
    Ok(t[1] * 1e6 / n as f64)
}

/// The spins per point that add `cost_us` wall microseconds per point to `f` (with the threads
/// rayon has), measured on this machine: the added time is linear in the spins, so one timing at
/// a known number of spins gives the slope.
pub fn calibrate<F: Integrand>(f: &F, dim: usize, cost_us: f64) -> nis::Result<u64> {
    if cost_us <= 0.0 {
        return Ok(0);
    }
    const PROBE: u64 = 2_000;
    let base = micros_per_point(f, dim)?;
    let probed = micros_per_point(&SyntheticCost::new(f, PROBE), dim)?;
    let per_spin = ((probed - base) / PROBE as f64).max(1e-9);
    Ok((cost_us / per_spin).round() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cost_leaves_the_values_unchanged() {
        let f = |x: &[f64]| x[0] * x[1] + 1.0;
        let x = [0.1, 0.2, 0.3, 0.4, 0.9, 0.5];
        let (mut plain, mut costly) = ([0.0; 3], [0.0; 3]);
        f.eval_batch(&x, 2, &mut plain).unwrap();
        SyntheticCost::new(&f, 1000)
            .eval_batch(&x, 2, &mut costly)
            .unwrap();
        assert_eq!(plain, costly);
    }
}
