//! `nis bench flow --device cuda`: sampling with ln q, the log-density and an on-policy training
//! step of the reference flows on the GPU (crates/nis-cuda), against the same flow's sampling and
//! training step on every CPU core of the same machine, timed in one run.

use std::time::Instant;

use nis::flow::{Density, Flow};
use nis::loss::Loss;
use nis::nn::AdamConfig;
use nis::train::Trainer;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::flow::{bench_integrand, references, train_step};
use super::time;
use crate::error::Result;

/// Median seconds of `reps` runs of `f` after two warm-up runs; `f` returns when the GPU is done.
fn time_gpu(reps: usize, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    f()?;
    f()?;
    let mut t = Vec::with_capacity(reps);
    for _ in 0..reps {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64());
    }
    t.sort_by(f64::total_cmp);
    Ok(t[reps / 2])
}

/// Runs the benchmark at each batch size; returns the Markdown table, `log` sees each row.
/// With `only`, just the reference flows whose name starts with it.
pub fn run(
    batches: &[usize],
    reps: usize,
    only: Option<&str>,
    log: &mut dyn FnMut(&str),
) -> Result<String> {
    if reps == 0 {
        return Err(crate::error::Error::Config(
            "the GPU benchmark needs at least one timed run".into(),
        ));
    }
    let gpu = nis_cuda::Gpu::open(0)?;
    let threads = rayon::current_num_threads();
    let mut md = format!(
        "GPU: {}; CPU: {threads} threads. Samples/s: on the GPU the median of {reps} runs after \
         two warm-ups, its points and ln q left on the device (timed to the stream's end); on the \
         CPU the median of {} after one. Every parameter perturbed by up to ±0.01 (uniform) so \
         that the splines are not the identity.\n\n\
         The training step is on-policy KL with f = x₀ + 0.1 evaluated on the host (the GPU's \
         points copied out, the weights in), Adam on the device.\n\n\
         | config | batch | GPU sample + ln q | GPU ln q of points | CPU sample + ln q | GPU / CPU (sample) | GPU train step | CPU train step | GPU / CPU (train) |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        gpu.name(),
        reps.min(3)
    );
    for r in references()
        .into_iter()
        .filter(|r| only.is_none_or(|o| r.name.starts_with(o)))
    {
        let mut flow = Flow::new(r.config.clone())?;
        let mut rng = Pcg64Mcg::seed_from_u64(0);
        for p in flow.params_mut() {
            *p += 0.01 * (2.0 * rng.random::<f32>() - 1.0);
        }
        let on = nis_cuda::GpuFlow::new(&gpu, &flow)?;
        for &n in batches {
            let mut seed = 0;
            let sample = time_gpu(reps, || {
                seed += 1;
                on.sample(n, seed)?;
                Ok(gpu.synchronize()?)
            })?;
            let points = on.sample(n, 12345)?;
            let density = time_gpu(reps, || {
                on.log_density_device(&points.x, n)?;
                Ok(gpu.synchronize()?)
            })?;
            let cpu = time(reps.min(3), || {
                flow.sample(n, None, &mut rng).expect("sampling");
            });
            let dim = flow.dim();
            let mut trainer = nis_cuda::GpuTrainer::new(
                nis_cuda::GpuFlow::new(&gpu, &flow)?,
                Loss::Kl,
                AdamConfig::default(),
            )?;
            let mut f = |x: &[f32], out: &mut [f64]| {
                for (o, p) in out.iter_mut().zip(x.chunks(dim)) {
                    *o = bench_integrand(p);
                }
            };
            let mut step_seed = 1_000_000;
            let train = time_gpu(reps, || {
                step_seed += 1;
                trainer.step(n, step_seed, &mut f)?;
                Ok(gpu.synchronize()?)
            })?;
            let mut cpu_trainer = Trainer::new(flow.clone(), Loss::Kl, AdamConfig::default())?;
            let cpu_train = time(reps.min(3), || {
                train_step(&mut cpu_trainer, n, &mut rng).expect("training step");
            });
            let row = format!(
                "| {} | {n} | {:.3e} | {:.3e} | {:.3e} | {:.0}× | {:.3e} | {:.3e} | {:.0}× |\n",
                r.name,
                n as f64 / sample,
                n as f64 / density,
                n as f64 / cpu,
                cpu / sample,
                n as f64 / train,
                n as f64 / cpu_train,
                cpu_train / train
            );
            log(&row);
            md.push_str(&row);
        }
    }
    Ok(md)
}
