//! The benchmark drivers behind `nis bench …`: each runs its experiment, writes its figures and
//! its section of `docs/`, and returns the Markdown. Progress is the caller's: drivers take the
//! long-running step (a fit, a training run) or a line logger as closures, so the command line can
//! show bars and a test can run them silently.
//!
//! - [`channels`]: multi-channel integration and sign splitting against one channel
//!   (`docs/results/integration.md`).
//! - [`coverage`]: error bars against exact values over many seeds (`docs/results/robustness.md`).
//! - [`flow`]: flow throughput against bare gemm and PyTorch (`docs/results/integration.md`).
//! - [`integrate`]: the integration suite with every method at one budget (`docs/results/integration.md`).
//! - [`fit_image`]: the paper's Figure 3, couplings on 2-D image targets (`docs/results/paper.md`).
//! - [`density`]: the paper's Figure 4, PQ against affine couplings on real digits.
//! - [`guiding`]: the paper's Figure 5, path guiding against a reference at equal samples and time.
//! - [`memory`]: peak RSS of integration and rendering against the budget (`docs/results/integration.md`).
//! - [`time_to_precision`]: wall time of NIS, VEGAS+, plain MC and the `vegas` package to a target
//!   relative error with an honest answer (`docs/results/integration.md`).
//! - [`reuse`]: training evaluations in the estimate and replayed training (`docs/results/integration.md`).
//! - [`mpi`]: strong scaling over MPI ranks and the scaling model (`docs/results/scaling.md`).

pub mod channels;
pub mod coverage;
pub mod density;
pub mod fit_image;
pub mod flow;
#[cfg(feature = "cuda")]
pub mod flow_gpu;
pub mod guiding;
pub mod integrate;
pub mod memory;
pub mod mpi;
pub mod reuse;
pub mod time_to_precision;

use std::time::Instant;

/// Median seconds of `reps` runs of `f` after one warm-up.
pub fn time(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[reps / 2]
}
