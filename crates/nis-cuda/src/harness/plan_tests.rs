//! The GPU's plan of a flow replayed on the CPU with the harness's kernels: its passes and its
//! gradient against the flow's own (`Flow::inverse`, `log_density`, `backward`).

use super::tests::rel_diff;
use super::*;
use crate::plan::{Kind, Plan};
use nis::flow::{Flow, FlowConfig};
use nis::{Bijection, Density, TransformKind};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// The GPU's plan of `flow` run on the CPU with the harness's kernels and a plain matrix
/// product: what `GpuFlow::run` launches, step by step. Returns ln q per row.
fn run_plan(plan: &Plan, u: &mut [f32], inverse: bool) -> Vec<f64> {
    let n = u.len() / plan.dim;
    let mut log_q = vec![0.0f64; n];
    for l in plan.order(inverse) {
        let s = &plan.steps[l];
        let mut act: Vec<f32> = (0..n)
            .flat_map(|r| {
                s.a.iter()
                    .flat_map(move |&a| (0..s.blob_bins).map(move |j| (r, a, j)))
            })
            // SAFETY: plain arithmetic.
            .map(|(r, a, j)| unsafe {
                nis_cpu_one_blob(
                    u[r * plan.dim + a as usize],
                    s.blob_bins as c_int,
                    j as c_int,
                )
            })
            .collect();
        for (j, d) in s.dense.iter().enumerate() {
            let w = &plan.params[d.weights..d.weights + d.inputs * d.outputs];
            let b = &plan.params[d.biases..d.biases + d.outputs];
            let mut y = vec![0.0f32; n * d.outputs];
            for r in 0..n {
                for o in 0..d.outputs {
                    let dot: f32 = (0..d.inputs)
                        .map(|i| act[r * d.inputs + i] * w[i * d.outputs + o])
                        .sum();
                    let v = dot + b[o];
                    y[r * d.outputs + o] = if j + 1 < s.dense.len() { v.max(0.0) } else { v };
                }
            }
            act = y;
        }
        // SAFETY: act holds n rows of |B| × np parameters, u n rows of dim, log_q n values.
        unsafe {
            nis_cpu_coupling(
                s.kind as c_int,
                s.bins as c_int,
                inverse as c_int,
                act.as_ptr(),
                u.as_mut_ptr(),
                log_q.as_mut_ptr(),
                n as i64,
                plan.dim as c_int,
                s.b.as_ptr(),
                s.b.len() as c_int,
            )
        };
    }
    log_q
}

/// A flow whose output layers are not zero (a new flow is the identity).
fn bent_flow(config: FlowConfig, seed: u64) -> Flow {
    let mut flow = Flow::new(config).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    // A flow on [0, 1] has conditioners without inputs: only the biases bend it.
    let scale = if flow.dim() == 1 { 1.0 } else { 0.05 };
    for p in flow.params_mut() {
        *p += scale * (2.0 * rng.random::<f32>() - 1.0);
    }
    flow
}

/// Small flows of each kind the kernels run: piecewise-quadratic with two hidden layers,
/// rational-quadratic with one, and D = 1 (conditioners without inputs).
fn small_configs() -> [FlowConfig; 3] {
    [
        FlowConfig {
            transform: TransformKind::Quadratic { bins: 8 },
            hidden_width: 16,
            hidden_layers: 2,
            blob_bins: 8,
            ..FlowConfig::new(5)
        },
        FlowConfig {
            transform: TransformKind::RationalQuadratic { bins: 6 },
            hidden_width: 16,
            hidden_layers: 1,
            blob_bins: 4,
            ..FlowConfig::new(3)
        },
        FlowConfig {
            transform: TransformKind::Quadratic { bins: 4 },
            ..FlowConfig::new(1)
        },
    ]
}

#[test]
fn the_plan_on_the_cpu_is_the_flow() {
    let configs = small_configs();
    for (c, config) in configs.into_iter().enumerate() {
        let flow = bent_flow(config, c as u64);
        let plan = Plan::of(&flow).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(10 + c as u64);
        let z: Vec<f32> = (0..300 * flow.dim()).map(|_| rng.random::<f32>()).collect();
        // Sampling: the flow's inverse, ln q = −its log-det.
        let (x_ref, ld_ref) = flow.inverse(&z, None).unwrap();
        let mut x = z.clone();
        let log_q = run_plan(&plan, &mut x, true);
        let bent = ld_ref.iter().map(|l| l.abs()).fold(0.0, f64::max);
        assert!(
            bent > 0.05,
            "config {c}: the test flow is too close to the identity"
        );
        for r in 0..log_q.len() {
            assert!((log_q[r] + ld_ref[r]).abs() < 1e-4, "config {c} row {r}");
        }
        for (a, b) in x.iter().zip(&x_ref) {
            assert!((a - b).abs() < 1e-5, "config {c}: {a} vs {b}");
        }
        // Density: the flow's log_density at those points.
        let lq_ref = flow.log_density(&x_ref, None).unwrap();
        let mut u = x_ref.clone();
        let lq = run_plan(&plan, &mut u, false);
        for (a, b) in lq.iter().zip(&lq_ref) {
            assert!((a - b).abs() < 1e-4, "config {c}: ln q {a} vs {b}");
        }
    }
}

#[test]
fn the_plan_names_what_the_gpu_does_not_run() {
    let affine = Flow::new(FlowConfig {
        transform: TransformKind::Affine,
        ..FlowConfig::new(2)
    })
    .unwrap();
    assert!(matches!(
        Plan::of(&affine),
        Err(crate::GpuError::Unsupported(m)) if m.contains("Affine")
    ));
    let conditioned = Flow::new(FlowConfig {
        context_dim: 3,
        ..FlowConfig::new(2)
    })
    .unwrap();
    assert!(matches!(
        Plan::of(&conditioned),
        Err(crate::GpuError::Unsupported(_))
    ));
    let pq = Plan::of(&Flow::new(FlowConfig::new(2)).unwrap()).unwrap();
    assert_eq!(pq.steps[0].kind, Kind::Quadratic);
}

/// Row-major `[n, o]` = `[n, i]`·`[i, o]`, plainly.
fn matmul(x: &[f32], w: &[f32], n: usize, i: usize, o: usize) -> Vec<f32> {
    let mut y = vec![0.0f32; n * o];
    for r in 0..n {
        for c in 0..o {
            y[r * o + c] = (0..i).map(|t| x[r * i + t] * w[t * o + c]).sum();
        }
    }
    y
}

/// The gradient of −Σ w ln q through the plan, as `GpuFlow::gradient` computes it (the same
/// sweep, with the harness's kernels and plain matrix products).
fn gradient_plan(plan: &Plan, x: &[f32], w: &[f32]) -> Vec<f32> {
    let (dim, n) = (plan.dim, w.len());
    let mut u = x.to_vec();
    let mut log_q = vec![0.0f64; n];
    // (input, encoding, activations) per coupling.
    let mut tapes = Vec::new();
    for s in &plan.steps {
        let input = u.clone();
        let enc: Vec<f32> = (0..n)
            .flat_map(|r| {
                s.a.iter()
                    .flat_map(move |&a| (0..s.blob_bins).map(move |j| (r, a, j)))
            })
            // SAFETY: plain arithmetic.
            .map(|(r, a, j)| unsafe {
                nis_cpu_one_blob(
                    input[r * dim + a as usize],
                    s.blob_bins as c_int,
                    j as c_int,
                )
            })
            .collect();
        let mut acts: Vec<Vec<f32>> = Vec::new();
        for (j, d) in s.dense.iter().enumerate() {
            let src = if j == 0 { &enc } else { &acts[j - 1] };
            let wts = &plan.params[d.weights..d.weights + d.inputs * d.outputs];
            let mut y = matmul(src, wts, n, d.inputs, d.outputs);
            for (t, v) in y.iter_mut().enumerate() {
                *v += plan.params[d.biases + t % d.outputs];
                if j + 1 < s.dense.len() {
                    *v = v.max(0.0);
                }
            }
            acts.push(y);
        }
        // SAFETY: the buffers hold n rows of their widths.
        unsafe {
            nis_cpu_coupling(
                s.kind as c_int,
                s.bins as c_int,
                0,
                acts.last().unwrap().as_ptr(),
                u.as_mut_ptr(),
                log_q.as_mut_ptr(),
                n as i64,
                dim as c_int,
                s.b.as_ptr(),
                s.b.len() as c_int,
            )
        };
        tapes.push((input, enc, acts));
    }
    let g_ld: Vec<f32> = w.iter().map(|v| -v).collect();
    let mut g_u = vec![0.0f32; n * dim];
    let mut grads = vec![0.0f32; plan.params.len()];
    for (l, s) in plan.steps.iter().enumerate().rev() {
        let (input, enc, acts) = &tapes[l];
        let out_w = s.dense.last().unwrap().outputs;
        let mut delta = vec![0.0f32; n * out_w];
        // SAFETY: the buffers hold n rows of their widths.
        unsafe {
            nis_cpu_coupling_backward(
                s.kind as c_int,
                s.bins as c_int,
                acts.last().unwrap().as_ptr(),
                input.as_ptr(),
                g_u.as_mut_ptr(),
                g_ld.as_ptr(),
                delta.as_mut_ptr(),
                n as i64,
                dim as c_int,
                s.b.as_ptr(),
                s.b.len() as c_int,
            )
        };
        let want_input = l > 0 && !s.a.is_empty();
        for (j, d) in s.dense.iter().enumerate().rev() {
            let src = if j == 0 { enc } else { &acts[j - 1] };
            for t in 0..d.inputs {
                for c in 0..d.outputs {
                    grads[d.weights + t * d.outputs + c] = (0..n)
                        .map(|r| src[r * d.inputs + t] * delta[r * d.outputs + c])
                        .sum();
                }
            }
            for c in 0..d.outputs {
                grads[d.biases + c] = (0..n).map(|r| delta[r * d.outputs + c]).sum();
            }
            if d.inputs == 0 || (j == 0 && !want_input) {
                continue;
            }
            let wts = &plan.params[d.weights..d.weights + d.inputs * d.outputs];
            let mut prev = vec![0.0f32; n * d.inputs];
            for r in 0..n {
                for t in 0..d.inputs {
                    prev[r * d.inputs + t] = (0..d.outputs)
                        .map(|c| delta[r * d.outputs + c] * wts[t * d.outputs + c])
                        .sum();
                }
            }
            if j > 0 {
                for (g, a) in prev.iter_mut().zip(&acts[j - 1]) {
                    if *a <= 0.0 {
                        *g = 0.0;
                    }
                }
                delta = prev;
            } else {
                let k = s.blob_bins;
                for r in 0..n {
                    for (ai, &a) in s.a.iter().enumerate() {
                        let at = r * d.inputs + ai * k;
                        // SAFETY: enc and prev hold k values from `at`.
                        g_u[r * dim + a as usize] += unsafe {
                            nis_cpu_one_blob_backward(
                                input[r * dim + a as usize],
                                k as c_int,
                                enc[at..].as_ptr(),
                                prev[at..].as_ptr(),
                            )
                        };
                    }
                }
            }
        }
    }
    grads
}

#[test]
fn the_plans_gradient_is_the_flows() {
    let configs = small_configs();
    for (c, config) in configs.into_iter().enumerate() {
        let flow = bent_flow(config, 20 + c as u64);
        let plan = Plan::of(&flow).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(30 + c as u64);
        let n = 64;
        let x: Vec<f32> = (0..n * flow.dim()).map(|_| rng.random::<f32>()).collect();
        let w: Vec<f32> = (0..n).map(|_| rng.random::<f32>()).collect();
        let eval = flow.log_density_for_training(&x, None).unwrap();
        let g_ref = flow.backward(&eval.tape, &w).unwrap();
        let g = gradient_plan(&plan, &x, &w);
        let d = rel_diff(&g, &g_ref);
        // f32 sums over 64 rows in other orders differ by rounding; 1e-4 of the largest
        // component leaves room for bins narrowed to the floor, which amplify it.
        assert!(
            d < 1e-4,
            "config {c}: gradients differ by {d:e} of the largest"
        );
        assert!(
            g_ref.iter().any(|v| v.abs() > 1e-3),
            "config {c}: a vanishing gradient"
        );
    }
}
