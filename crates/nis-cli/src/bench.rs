//! Benchmarks. `nis bench flow`: throughput of the flow's sampling and on-policy training step on
//! the two reference configurations, against a bare `gemm` of the same dense-layer shapes, at 1
//! and 2 threads. `nis bench integrate`: the built-in suite with every method at one budget.
//! Results go to stdout and to sections of `docs/BENCHMARKS.md`.

use std::path::Path;
use std::time::Instant;

use nis::flow::{Flow, FlowConfig};
use nis::integrate::{integrator, IntegrationResult, Method, Settings};
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

/// The dense-layer shapes of a training step: (inputs, outputs, whether the backward pass needs
/// the input gradient — everywhere but below the first layer's fixed input).
fn dense_shapes(flow: &Flow) -> Vec<(usize, usize, bool)> {
    flow.couplings()
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
            eprint!("{row}");
            md.push_str(&row);
        }
    }
    Ok(md)
}

/// (threads, samples/s of sampling, samples/s of a training step).
type TorchRow = (usize, f64, f64);

/// Runs the PyTorch eager baseline (`scripts/bench-torch.py`, which installs torch into its own
/// venv) and returns its (threads, sample/s, train/s) rows.
fn torch_baseline(batch: usize) -> Result<Vec<TorchRow>, Box<dyn std::error::Error>> {
    let out = std::process::Command::new("python3")
        .args(["scripts/bench-torch.py", "--batch", &batch.to_string()])
        .output()?;
    if !out.status.success() {
        return Err(format!(
            "scripts/bench-torch.py failed: {}",
            String::from_utf8_lossy(&out.stderr)
        )
        .into());
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

/// `nis bench flow`: runs and records; with `torch`, also the PyTorch eager baseline of R1.
pub fn run_flow(batch: usize, torch: bool, docs: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let mut md = flow(batch)?;
    if torch {
        let rows = torch_baseline(batch)?;
        md.push_str(
            "\nR1 in PyTorch eager (`scripts/bench-torch.py`: the same flow as a PyTorch user \
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
    report::write_section(docs, "flow", "Flow throughput (`nis bench flow`)", &md)?;
    println!("{md}");
    Ok(())
}

/// One method of the integration benchmark: a method of the library, with the flow's transform
/// and loss for NIS.
struct MethodSpec {
    label: &'static str,
    method: Method,
    nis: Option<(Transform, Loss)>,
}

impl MethodSpec {
    fn run(
        &self,
        f: &nis::integrands::Builtin,
        evals: u64,
        seed: u64,
    ) -> Result<IntegrationResult, nis::Error> {
        let mut settings = Settings::default().seed(seed);
        if let Some((transform, loss)) = self.nis {
            settings.nis.flow.transform = transform;
            settings.nis.loss = loss;
        }
        integrator(self.method, f.dim, &settings)?.integrate(f, evals)
    }
}

fn methods() -> Vec<MethodSpec> {
    let nis = |label, transform, loss| MethodSpec {
        label,
        method: Method::Nis,
        nis: Some((transform, loss)),
    };
    vec![
        MethodSpec {
            label: "uniform",
            method: Method::Uniform,
            nis: None,
        },
        MethodSpec {
            label: "VEGAS+",
            method: Method::Vegas,
            nis: None,
        },
        nis("NIS-PQ/KL", Transform::Quadratic { bins: 16 }, Loss::Kl),
        nis(
            "NIS-PQ/χ²",
            Transform::Quadratic { bins: 16 },
            Loss::ChiSquare,
        ),
        nis(
            "NIS-RQ/KL",
            Transform::RationalQuadratic { bins: 16 },
            Loss::Kl,
        ),
    ]
}

/// `nis bench integrate`: the suite × methods at one budget; Markdown tables.
pub fn run_integrate(
    evals: u64,
    only: Option<&str>,
    docs: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    let methods = methods();
    let mut rel = format!(
        "Budget: {evals} evaluations per integrand and method (NIS training included), seed 0. \
         Cells: relative variance per evaluation Var(f/q)/F² = n_final·σ²/F² (lower is better) and, \
         in brackets, the pull (value − exact)/σ — |pull| ≫ 3 is a confident wrong answer.\n\n| integrand | d |"
    );
    let mut secs = String::from("| integrand | d |");
    for m in &methods {
        rel.push_str(&format!(" {} |", m.label));
        secs.push_str(&format!(" {} |", m.label));
    }
    rel.push_str(" VEGAS / best NIS |\n|---|---:|");
    secs.push_str("\n|---|---:|");
    for _ in &methods {
        rel.push_str("---:|");
        secs.push_str("---:|");
    }
    rel.push_str("---:|\n");
    secs.push('\n');
    for e in nis::integrands::SUITE {
        if only.is_some_and(|o| o != e.name) {
            continue;
        }
        for &d in e.dims {
            let f = nis::integrands::by_name(e.name, Some(d))?;
            rel.push_str(&format!("| {} | {d} |", e.name));
            secs.push_str(&format!("| {} | {d} |", e.name));
            let (mut vegas_rv, mut best_nis) = (f64::NAN, f64::INFINITY);
            for m in &methods {
                let r = m.run(&f, evals, 0)?;
                let pull = (r.value - f.exact) / r.std_err;
                eprintln!(
                    "{:<13} d={d:<2} {:<10} {:.6e} ± {:.2e} (exact {:.6e}) rel.var {:.3e} pull {pull:+.2} {:.1}s",
                    e.name, m.label, r.value, r.std_err, f.exact, r.rel_var_per_eval, r.seconds
                );
                rel.push_str(&format!(" {:.3e} [{pull:+.1}] |", r.rel_var_per_eval));
                secs.push_str(&format!(" {:.2} |", r.seconds));
                // A confident wrong answer does not count as a variance.
                let ok = pull.abs() < 5.0;
                if m.method == Method::Vegas {
                    vegas_rv = if ok { r.rel_var_per_eval } else { f64::NAN };
                } else if m.method == Method::Nis && ok {
                    best_nis = best_nis.min(r.rel_var_per_eval);
                }
            }
            rel.push_str(&format!(" {:.1} |\n", vegas_rv / best_nis));
            secs.push('\n');
        }
    }
    let body = format!("{rel}\nSeconds (wall, 2 threads):\n\n{secs}");
    report::write_section(
        docs,
        "integrate",
        "Integration suite (`nis bench integrate`)",
        &body,
    )?;
    println!("{body}");
    Ok(())
}
