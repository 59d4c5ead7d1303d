//! Checks of data-parallel integration that need an integrand of their own, run under `mpirun`
//! by `crates/nis-cli/tests/mpi.rs` (build: `cargo build --release -p nis --features mpi
//! --example mpi_ranks`).
//!
//! - `mpirun -n 3 mpi_ranks checksums`: trains a NIS integrator step by step and compares every
//!   rank's flow parameters, bit for bit, after every step; prints `identical after N steps`.
//! - `mpirun -n 3 mpi_ranks fail RANK`: an integrand that fails on rank RANK only; every rank must
//!   stop with an error, which rank 0 prints (exit status 1 on every rank).
//! - `mpirun -n 2 mpi_ranks comm-time DIM`: the communication of one training step of the default
//!   flow in DIM dimensions (the five one-number reductions of the failure flag, the skip test
//!   and the weights' normalisation, then the sum of the gradient), timed over 200 steps; prints
//!   one JSON line with the parameter count and the median and mean microseconds per step.

use std::process::ExitCode;

use nis::comm::mpi::MpiComm;
use nis::comm::Comm;
use nis::flow::Density;
use nis::integrate::nis::{NisConfig, NisIntegrator};
use nis::integrate::{Integrand, Integrator};
use nis::{Error, Result};

/// A Gaussian bump that fails on one rank from its second batch on.
struct FailsOn {
    rank: usize,
    fail_rank: Option<usize>,
    calls: std::sync::atomic::AtomicUsize,
}

impl Integrand for FailsOn {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> Result<()> {
        let call = self
            .calls
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if Some(self.rank) == self.fail_rank && call >= 1 {
            return Err(Error::IntegrandFailed {
                message: format!("deliberate failure on rank {}", self.rank),
            });
        }
        for (o, p) in out.iter_mut().zip(x.chunks_exact(dim)) {
            *o = (-p.iter().map(|v| (v - 0.4).powi(2)).sum::<f64>() / 0.02).exp();
        }
        Ok(())
    }
}

fn run(comm: &Comm) -> Result<String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = NisConfig::builder().seed(5).batch(1024).build()?;
    let mut integ = NisIntegrator::new(3, config)?;
    integ.set_comm(comm.clone());
    let f = FailsOn {
        rank: comm.rank(),
        fail_rank: match args.first().map(String::as_str) {
            Some("fail") => Some(args.get(1).and_then(|r| r.parse().ok()).unwrap_or(1)),
            _ => None,
        },
        calls: Default::default(),
    };
    match args.first().map(String::as_str) {
        Some("checksums") => {
            let steps = 20;
            for step in 0..steps {
                integ.train(&f, 1024)?;
                let bytes: Vec<u8> = integ
                    .flow()
                    .params()
                    .iter()
                    .flat_map(|p| p.to_le_bytes())
                    .collect();
                let all = comm.all_gather_bytes(bytes);
                if let Some(r) = all.iter().position(|b| *b != all[0]) {
                    return Err(Error::Config(format!(
                        "rank {r}'s parameters differ from rank 0's after step {}",
                        step + 1
                    )));
                }
            }
            let r = integ.integrate(&f, 20_000)?;
            Ok(format!(
                "parameters of {} ranks identical after {steps} steps; estimate {} ± {}",
                comm.size(),
                r.value,
                r.std_err
            ))
        }
        Some("comm-time") => {
            let dim = args.get(1).and_then(|d| d.parse().ok()).unwrap_or(4);
            let integ = NisIntegrator::new(dim, NisConfig::default())?;
            let mut grad = integ.flow().params().to_vec();
            let mut times = Vec::new();
            for _ in 0..220 {
                let started = std::time::Instant::now();
                comm.check(Ok(()))?;
                comm.any(true);
                comm.check(Ok(()))?;
                let mut max = [1.0];
                comm.max_f64(&mut max);
                comm.sum(1.0);
                comm.sum_f32(&mut grad);
                times.push(started.elapsed().as_secs_f64() * 1e6);
            }
            let mut times = times.split_off(20); // warm-up
            times.sort_by(f64::total_cmp);
            let mean = times.iter().sum::<f64>() / times.len() as f64;
            // Adam's update, which every rank repeats on the summed gradient.
            let mut adam = nis::nn::Adam::new(Default::default(), grad.len())?;
            let mut params = integ.flow().params().to_vec();
            let mut adam_times: Vec<f64> = (0..200)
                .map(|_| {
                    let started = std::time::Instant::now();
                    let _ = adam.step(&mut params, &grad);
                    started.elapsed().as_secs_f64() * 1e6
                })
                .collect();
            adam_times.sort_by(f64::total_cmp);
            Ok(format!(
                "{{\"ranks\": {}, \"params\": {}, \"median_us\": {:.2}, \"mean_us\": {:.2}, \"adam_us\": {:.2}}}",
                comm.size(),
                grad.len(),
                times[times.len() / 2],
                mean,
                adam_times[100]
            ))
        }
        Some("fail") => {
            let r = integ.integrate(&f, 50_000)?;
            Ok(format!("no failure: {} ± {}", r.value, r.std_err))
        }
        _ => Err(Error::Config(
            "usage: mpi_ranks checksums | mpi_ranks fail RANK | mpi_ranks comm-time DIM".into(),
        )),
    }
}

fn main() -> ExitCode {
    let comm = match MpiComm::init() {
        Ok(comm) => comm,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    // Rank 0 prints, whatever the outcome; every rank reports failure in its exit status.
    let rank0 = comm.is_root();
    match run(&comm) {
        Ok(message) => {
            if rank0 {
                println!("{message}");
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            if rank0 {
                eprintln!("error: {e}");
            }
            ExitCode::FAILURE
        }
    }
}
