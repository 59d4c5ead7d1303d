//! `nis bench flow`: throughput of the flow's sampling and on-policy training step on the two
//! reference configurations, against a bare `gemm` of the same dense-layer shapes, at 1 and 2
//! threads, and optionally against the same flow in PyTorch eager (`scripts/bench/bench-torch.py`).

use std::path::Path;

use nis::flow::{Density, Flow, FlowConfig};
use nis::loss::Loss;
use nis::nn::AdamConfig;
use nis::train::Trainer;
use nis::TransformKind;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::time;
use crate::error::{Error, Result};
use crate::report;

pub(crate) struct Reference {
    pub name: &'static str,
    pub config: FlowConfig,
}

/// The reference flows R1 and R2.
pub(crate) fn references() -> Vec<Reference> {
    vec![
        Reference {
            name: "R1: D=2, PQ-32, 2 couplings, MLP 3×256",
            config: FlowConfig {
                dim: 2,
                transform: TransformKind::Quadratic { bins: 32 },
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
                transform: TransformKind::Quadratic { bins: 16 },
                couplings: 6,
                hidden_layers: 3,
                hidden_width: 64,
                ..FlowConfig::new(8)
            },
        },
    ]
}

/// The benchmark's integrand, f = x₀ + 0.1: cheap, so that a step times the flow.
pub(crate) fn bench_integrand(x: &[f32]) -> f64 {
    x[0] as f64 + 0.1
}

/// One on-policy KL step of `trainer` on `n` fresh points of the benchmark's integrand.
pub(crate) fn train_step(trainer: &mut Trainer, n: usize, rng: &mut Pcg64Mcg) -> nis::Result<()> {
    let dim = trainer.flow().dim();
    let s = trainer.flow().sample_for_training(n, None, rng)?;
    let f: Vec<f64> = s.x.chunks(dim).map(bench_integrand).collect();
    trainer.step_on_policy(&s, &f)?;
    Ok(())
}

/// The dense-layer shapes of a training step: (inputs, outputs, whether the backward pass needs
/// the input gradient — everywhere but below the first layer's fixed input).
fn dense_shapes(flow: &Flow) -> Vec<(usize, usize, bool)> {
    flow.layers()
        .iter()
        .enumerate()
        .flat_map(|(l, c)| {
            (0..c.mlp().layers()).map(move |j| {
                (
                    c.mlp().dims[j],
                    c.mlp().dims[j + 1],
                    j > 0 || (l > 0 && !c.a().is_empty()),
                )
            })
        })
        .collect()
}

/// Seconds of bare gemm calls of all dense shapes of a training step at batch `n`.
fn bare_gemm_seconds(flow: &Flow, n: usize, threads: usize) -> f64 {
    let par = if threads == 1 {
        gemm::Parallelism::None
    } else {
        gemm::Parallelism::Rayon(threads)
    };
    let shapes = dense_shapes(flow);
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

/// Runs the flow benchmark (only the reference flows whose name starts with `only`, if given) and
/// returns its Markdown report.
pub fn flow(batch: usize, only: Option<&str>, log: &mut dyn FnMut(&str)) -> Result<String> {
    let mut md = String::new();
    md.push_str(&format!(
        "Batch {batch}; samples/s, median of 5 runs. Dense share: the flow's dense-layer FLOP rate \
         during a training step divided by bare `gemm` calls of the same shapes at the same batch \
         and thread count (forward, weight gradient, input gradient).\n\n"
    ));
    md.push_str("| config | params | threads | sample + log q (samples/s) | train step (samples/s) | dense share of bare gemm |\n|---|---:|---:|---:|---:|---:|\n");
    let chosen = references()
        .into_iter()
        .filter(|r| only.is_none_or(|o| r.name.starts_with(o)));
    for r in chosen {
        let flow = Flow::new(r.config.clone())?;
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| Error::Config(format!("thread pool: {e}")))?;
            let (sample_t, train_t, gemm_t) = pool.install(|| -> Result<_, nis::Error> {
                let mut rng = Pcg64Mcg::seed_from_u64(0);
                let sample_t = time(5, || {
                    flow.sample(batch, None, &mut rng).expect("sampling");
                });
                let mut trainer = Trainer::new(flow.clone(), Loss::Kl, AdamConfig::default())?;
                let train_t = time(5, || {
                    train_step(&mut trainer, batch, &mut rng).expect("training step");
                });
                Ok((sample_t, train_t, bare_gemm_seconds(&flow, batch, threads)))
            })?;
            // Both do the same dense FLOPs, so the ratio of FLOP rates is the ratio of times.
            let share = gemm_t / train_t;
            let row = format!(
                "| {} | {} | {} | {:.0} | {:.0} | {:.0}% |\n",
                r.name,
                flow.param_count(),
                threads,
                batch as f64 / sample_t,
                batch as f64 / train_t,
                100.0 * share
            );
            log(&row);
            md.push_str(&row);
        }
    }
    Ok(md)
}

/// (threads, samples/s of sampling, samples/s of a training step).
type TorchRow = (usize, f64, f64);

/// Runs the PyTorch eager baseline (`scripts/bench/bench-torch.py`, which installs torch into its own
/// venv) and returns its (threads, sample/s, train/s) rows.
fn torch_baseline(batch: usize) -> Result<Vec<TorchRow>> {
    let script = std::path::PathBuf::from("scripts/bench/bench-torch.py");
    let out = std::process::Command::new("python3")
        .arg(&script)
        .args(["--batch", &batch.to_string()])
        .output()
        .map_err(|source| Error::Io {
            path: script.clone(),
            source,
        })?;
    if !out.status.success() {
        return Err(Error::Config(format!(
            "scripts/bench/bench-torch.py failed: {}",
            String::from_utf8_lossy(&out.stderr)
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let rows = text
        .lines()
        .filter_map(|l| {
            let c: Vec<&str> = l.trim_matches('|').split('|').map(str::trim).collect();
            match c.as_slice() {
                [t, s, tr] => Some((t.parse().ok()?, s.parse().ok()?, tr.parse().ok()?)),
                _ => None,
            }
        })
        .collect();
    Ok(rows)
}

/// `nis bench flow`: runs and records in the section "flow" of `docs`; with `torch`, also the
/// PyTorch eager baseline of R1; with `only`, just the reference flows whose name starts with it,
/// and nothing is written.
/// Returns the Markdown; `log` sees each row as it is measured.
pub fn run(
    batch: usize,
    torch: bool,
    only: Option<&str>,
    docs: &Path,
    log: &mut dyn FnMut(&str),
) -> Result<String> {
    let mut md = flow(batch, only, log)?;
    if torch {
        let rows = torch_baseline(batch)?;
        md.push_str(
            "\nR1 in PyTorch eager (`scripts/bench/bench-torch.py`: the same flow as a PyTorch user \
             writes it — sample without grad, recompute log q with grad, backward, Adam), timed in \
             the same run; ratio = nis / PyTorch:\n\n| threads | sample + log q (samples/s) | \
             train step (samples/s) | nis / PyTorch (sample) | nis / PyTorch (train) |\n\
             |---:|---:|---:|---:|---:|\n",
        );
        for (threads, s, t) in rows {
            let ours = |col: usize| -> f64 {
                md.lines()
                    .filter(|l| l.starts_with("| R1"))
                    .nth(threads - 1)
                    .and_then(|l| l.split('|').nth(col))
                    .and_then(|v| v.trim().parse().ok())
                    .unwrap_or(f64::NAN)
            };
            md.push_str(&format!(
                "| {threads} | {s:.0} | {t:.0} | {:.2} | {:.2} |\n",
                ours(4) / s,
                ours(5) / t
            ));
        }
    }
    // A partial run (for profiling) leaves the recorded table alone.
    if only.is_none() {
        report::write_section(docs, "flow", "Flow throughput (`nis bench flow`)", &md)?;
    }
    Ok(md)
}
