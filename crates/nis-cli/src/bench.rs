//! `nis bench flow`: throughput of the flow's sampling and on-policy training step on the two
//! reference configurations, against a bare `gemm` of the same dense-layer shapes, at 1 and 2
//! threads. Results go to stdout and to a section of `docs/BENCHMARKS.md`.

use std::path::Path;
use std::time::Instant;

use nis::flow::{Flow, FlowConfig};
use nis::loss::Loss;
use nis::nn::AdamConfig;
use nis::train::Trainer;
use nis::Transform;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use crate::report;

struct Reference {
    name: &'static str,
    config: FlowConfig,
}

fn references() -> Vec<Reference> {
    vec![
        Reference {
            name: "R1: D=2, PQ-32, 2 couplings, MLP 3×256",
            config: FlowConfig {
                dim: 2,
                transform: Transform::Quadratic { bins: 32 },
                couplings: 2,
                hidden_layers: 3,
                hidden_width: 256,
                ..FlowConfig::new(2)
            },
        },
        Reference {
            name: "R2: D=8, PQ-16, 6 couplings, MLP 3×64",
            config: FlowConfig {
                dim: 8,
                transform: Transform::Quadratic { bins: 16 },
                couplings: 6,
                hidden_layers: 3,
                hidden_width: 64,
                ..FlowConfig::new(8)
            },
        },
    ]
}

/// Median seconds of `reps` runs of `f` after one warm-up.
fn time(reps: usize, mut f: impl FnMut()) -> f64 {
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

/// Dense-layer FLOPs of one training step per sample: forward, weight gradients, and input
/// gradients wherever the backward pass needs them (not below the first layer's input).
fn dense_flops(flow: &Flow) -> (f64, f64) {
    let mut fwd = 0.0;
    let mut train = 0.0;
    for (l, c) in flow.couplings().iter().enumerate() {
        for j in 0..c.mlp.layers() {
            let mac = (c.mlp.dims[j] * c.mlp.dims[j + 1]) as f64;
            fwd += 2.0 * mac;
            let input_grad = j > 0 || (l > 0 && !c.a.is_empty());
            train += 2.0 * mac * if input_grad { 3.0 } else { 2.0 };
        }
    }
    (fwd, train)
}

/// Seconds of bare gemm calls of all dense shapes of a training step at batch `n`.
fn bare_gemm_seconds(flow: &Flow, n: usize, threads: usize) -> f64 {
    let par = if threads == 1 {
        gemm::Parallelism::None
    } else {
        gemm::Parallelism::Rayon(threads)
    };
    let shapes: Vec<(usize, usize, bool)> = flow
        .couplings()
        .iter()
        .enumerate()
        .flat_map(|(l, c)| {
            (0..c.mlp.layers()).map(move |j| {
                (
                    c.mlp.dims[j],
                    c.mlp.dims[j + 1],
                    j > 0 || (l > 0 && !c.a.is_empty()),
                )
            })
        })
        .collect();
    let buf = |len: usize| vec![0.5f32; len];
    let mm = |m: usize, nn: usize, k: usize, dst: &mut [f32], a: &[f32], b: &[f32]| {
        // SAFETY: row-major m×k times k×nn into m×nn, all buffers sized by the caller.
        unsafe {
            gemm::gemm(
                m,
                nn,
                k,
                dst.as_mut_ptr(),
                1,
                nn as isize,
                false,
                a.as_ptr(),
                1,
                k as isize,
                b.as_ptr(),
                1,
                nn as isize,
                0.0,
                1.0,
                false,
                false,
                false,
                par,
            )
        }
    };
    let bufs: Vec<_> = shapes
        .iter()
        .map(|&(i, o, _)| (buf(n * i), buf(i * o), buf(n * o), buf(i * o), buf(n * i)))
        .collect();
    let mut bufs = bufs;
    time(3, || {
        for (&(i, o, ig), (x, w, y, gw, gx)) in shapes.iter().zip(bufs.iter_mut()) {
            mm(n, o, i, y, x, w); // forward
            mm(i, o, n, gw, x, y); // weight gradient (shape of xᵀ·g)
            if ig {
                mm(n, i, o, gx, y, w); // input gradient (shape of g·wᵀ)
            }
        }
    })
}

/// Runs the flow benchmark and returns its Markdown report.
pub fn flow(batch: usize) -> Result<String, Box<dyn std::error::Error>> {
    let mut md = String::new();
    md.push_str(&format!(
        "Batch {batch}; samples/s, median of 5 runs. Dense share: the flow's dense-layer FLOP rate \
         during a training step divided by bare `gemm` calls of the same shapes at the same batch \
         and thread count (forward, weight gradient, input gradient).\n\n"
    ));
    md.push_str("| config | params | threads | sample + log q (samples/s) | train step (samples/s) | dense share of bare gemm |\n|---|---:|---:|---:|---:|---:|\n");
    for r in references() {
        let flow = Flow::new(r.config.clone())?;
        let (_, train_flops) = dense_flops(&flow);
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()?;
            let (sample_t, train_t, gemm_t) = pool.install(|| -> Result<_, nis::Error> {
                let mut rng = Pcg64Mcg::seed_from_u64(0);
                let sample_t = time(5, || {
                    flow.sample(batch, None, &mut rng).expect("sampling");
                });
                let mut trainer = Trainer::new(flow.clone(), Loss::Kl, AdamConfig::default())?;
                let dim = flow.dim();
                let train_t = time(5, || {
                    let s = trainer
                        .flow()
                        .sample_for_training(batch, None, &mut rng)
                        .expect("sampling");
                    let f: Vec<f64> = s.x.chunks(dim).map(|p| p[0] as f64 + 0.1).collect();
                    trainer.step_on_policy(&s, &f).expect("training step");
                });
                Ok((sample_t, train_t, bare_gemm_seconds(&flow, batch, threads)))
            })?;
            let share =
                (train_flops * batch as f64 / train_t) / (train_flops * batch as f64 / gemm_t);
            let row = format!(
                "| {} | {} | {} | {:.0} | {:.0} | {:.0}% |\n",
                r.name,
                flow.param_count(),
                threads,
                batch as f64 / sample_t,
                batch as f64 / train_t,
                100.0 * share
            );
            eprint!("{row}");
            md.push_str(&row);
        }
    }
    Ok(md)
}

/// `nis bench flow`: runs and records.
pub fn run_flow(batch: usize, docs: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let md = flow(batch)?;
    report::write_section(docs, "flow", "Flow throughput (`nis bench flow`)", &md)?;
    println!("{md}");
    Ok(())
}
