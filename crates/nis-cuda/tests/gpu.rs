//! The flow on a real GPU against the same flow on the CPU. These need an NVIDIA GPU with its
//! driver, NVRTC and cuBLAS: they are ignored by default and run by scripts/device/check.sh
//! (`--ignored`) on the device machine. The first test runs everywhere.

use nis::flow::{Flow, FlowConfig};
use nis::loss::Loss;
use nis::nn::AdamConfig;
use nis::{Bijection, Density, TransformKind};
use nis_cuda::{Gpu, GpuError, GpuFlow, GpuTrainer};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

#[test]
fn without_a_driver_opening_is_a_clear_error() {
    match Gpu::open(0) {
        // A machine with a GPU opens it; asking for one it lacks is a clear error too.
        Ok(gpu) => {
            assert!(!gpu.name().is_empty());
            assert!(matches!(Gpu::open(4096), Err(GpuError::NoDevice(_))));
        }
        Err(GpuError::NoDevice(m)) => assert!(m.contains("driver") || m.contains("GPU")),
        // A driver without CUDA's NVRTC or cuBLAS on the library path.
        Err(GpuError::Library { library, .. }) => assert!(!library.is_empty()),
        Err(e) => panic!("expected a GPU, NoDevice or Library, got {e}"),
    }
}

fn gpu() -> Gpu {
    Gpu::open(0).expect("these tests need a CUDA GPU (scripts/device/check.sh)")
}

/// A flow whose output layers are not zero (a new flow is the identity).
fn bent_flow(config: FlowConfig, seed: u64) -> Flow {
    let mut flow = Flow::new(config).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    for p in flow.params_mut() {
        *p += 0.05 * (2.0 * rng.random::<f32>() - 1.0);
    }
    flow
}

fn configs() -> Vec<(&'static str, FlowConfig)> {
    vec![
        (
            "R1 (PQ-32, 3×256)",
            FlowConfig {
                transform: TransformKind::Quadratic { bins: 32 },
                couplings: 2,
                hidden_layers: 3,
                hidden_width: 256,
                ..FlowConfig::new(2)
            },
        ),
        (
            "R2 (PQ-16, 6 couplings, 3×64)",
            FlowConfig {
                transform: TransformKind::Quadratic { bins: 16 },
                couplings: 6,
                hidden_layers: 3,
                hidden_width: 64,
                ..FlowConfig::new(8)
            },
        ),
        (
            "RQ-8, D=5",
            FlowConfig {
                transform: TransformKind::RationalQuadratic { bins: 8 },
                ..FlowConfig::new(5)
            },
        ),
        ("PQ, D=1", FlowConfig::new(1)),
    ]
}

/// Largest and median absolute difference.
fn diffs(a: &[f64], b: &[f64]) -> (f64, f64) {
    let mut d: Vec<f64> = a.iter().zip(b).map(|(x, y)| (x - y).abs()).collect();
    d.sort_by(f64::total_cmp);
    (d[d.len() - 1], d[d.len() / 2])
}

#[test]
#[ignore = "needs a CUDA GPU: scripts/device/check.sh"]
fn gpu_and_cpu_give_the_same_points_and_densities() {
    let gpu = gpu();
    for (c, (name, config)) in configs().into_iter().enumerate() {
        let flow = bent_flow(config, c as u64);
        let on = GpuFlow::new(&gpu, &flow).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(100 + c as u64);
        let n = 20_000;
        let z: Vec<f32> = (0..n * flow.dim()).map(|_| rng.random::<f32>()).collect();
        let (x_cpu, ld) = flow.inverse(&z, None).unwrap();
        let lq_cpu: Vec<f64> = ld.iter().map(|l| -l).collect();
        let (x_gpu, lq_gpu) = on.sample_latents(&z).unwrap();
        let xd: Vec<f64> = x_gpu.iter().map(|&v| v as f64).collect();
        let xc: Vec<f64> = x_cpu.iter().map(|&v| v as f64).collect();
        let (x_max, x_med) = diffs(&xd, &xc);
        let (q_max, q_med) = diffs(&lq_gpu, &lq_cpu);
        let lq_at = flow.log_density(&x_cpu, None).unwrap();
        let (d_max, d_med) = diffs(&on.log_density(&x_cpu).unwrap(), &lq_at);
        println!(
            "{name}: x max {x_max:.1e} median {x_med:.1e}; sampled ln q max {q_max:.1e} median \
             {q_med:.1e}; density ln q max {d_max:.1e} median {d_med:.1e}"
        );
        // f32 through cuBLAS (another summation order) and fused multiply-adds: ~1e-6 typical;
        // a point in a bin narrowed to the floor (1e-3/K) amplifies the edge's rounding.
        assert!(
            x_med < 1e-5 && q_med < 1e-5 && d_med < 1e-5,
            "{name}: medians"
        );
        assert!(
            x_max < 1e-3 && q_max < 1e-2 && d_max < 1e-2,
            "{name}: largest"
        );
    }
}

#[test]
#[ignore = "needs a CUDA GPU: scripts/device/check.sh"]
fn gpu_samples_are_seeded_and_their_density_integrates_to_one() {
    let gpu = gpu();
    let flow = bent_flow(configs().swap_remove(1).1, 9);
    let on = GpuFlow::new(&gpu, &flow).unwrap();
    let n = 1 << 18;
    let a = on.sample(n, 42).unwrap();
    let b = on.sample(n, 42).unwrap();
    let c = on.sample(n, 43).unwrap();
    let stream = gpu.stream();
    let (xa, xb, xc) = (
        stream.clone_dtoh(&a.x).unwrap(),
        stream.clone_dtoh(&b.x).unwrap(),
        stream.clone_dtoh(&c.x).unwrap(),
    );
    assert_eq!(xa, xb, "the same seed gives the same points");
    assert_ne!(xa, xc);
    let lq = stream.clone_dtoh(&a.log_q).unwrap();
    assert!(xa.iter().all(|v| (0.0..=1.0).contains(v)));
    // The sampled ln q is the density at the sampled points (the CPU flow's, independently).
    let lq_cpu = flow.log_density(&xa, None).unwrap();
    let (m, med) = diffs(&lq, &lq_cpu);
    assert!(
        med < 1e-5 && m < 1e-2,
        "ln q of samples: max {m} median {med}"
    );
    // ∫ q = 1: the mean of 1/q over q's samples is the volume 1, within 5 standard errors.
    let w: Vec<f64> = lq.iter().map(|l| (-l).exp()).collect();
    let mean = w.iter().sum::<f64>() / n as f64;
    let var = w.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let se = (var / n as f64).sqrt();
    assert!((mean - 1.0).abs() < 5.0 * se, "∫ q = {mean} ± {se}");
}

#[test]
#[ignore = "needs a CUDA GPU: scripts/device/check.sh"]
fn bad_input_and_exhausted_memory_are_errors() {
    let gpu = gpu();
    let flow = Flow::new(FlowConfig::new(3)).unwrap();
    let on = GpuFlow::new(&gpu, &flow).unwrap();
    assert!(matches!(
        on.log_density(&[0.5, 0.5]),
        Err(GpuError::InvalidInput(_))
    ));
    assert!(matches!(
        on.log_density(&[0.5, f32::NAN, 0.1]),
        Err(GpuError::InvalidInput(_))
    ));
    assert!(matches!(
        on.log_density(&[]),
        Err(GpuError::InvalidInput(_))
    ));
    // 2³⁶ points are more than a batch may hold: refused before anything runs.
    assert!(matches!(
        on.sample(1 << 36, 0),
        Err(GpuError::InvalidInput(_))
    ));
    // 2³⁰ points of D = 3 need 520 GiB for each activation buffer: the driver says no, and the
    // GPU stays usable.
    match on.sample(1 << 30, 0) {
        Err(GpuError::Driver(m)) => assert!(m.contains("OUT_OF_MEMORY"), "{m}"),
        other => panic!("expected out of memory, got {:?}", other.map(|_| ())),
    }
    let ok = on.sample(1000, 0).unwrap();
    assert_eq!(gpu.stream().clone_dtoh(&ok.log_q).unwrap().len(), 1000);
}

#[test]
#[ignore = "needs a CUDA GPU: scripts/device/check.sh"]
fn gpu_gradient_is_the_cpu_gradient() {
    let gpu = gpu();
    for (c, (name, config)) in configs().into_iter().enumerate() {
        let flow = bent_flow(config, 50 + c as u64);
        let on = GpuFlow::new(&gpu, &flow).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(60 + c as u64);
        let n = 4096;
        let x: Vec<f32> = (0..n * flow.dim()).map(|_| rng.random::<f32>()).collect();
        let w: Vec<f32> = (0..n).map(|_| rng.random::<f32>() / n as f32).collect();
        let eval = flow.log_density_for_training(&x, None).unwrap();
        let g_cpu = flow.backward(&eval.tape, &w).unwrap();
        let stream = gpu.stream();
        let g = on
            .gradient(
                &stream.clone_htod(&x).unwrap(),
                &stream.clone_htod(&w).unwrap(),
                n,
            )
            .unwrap();
        let g: Vec<f32> = stream.clone_dtoh(&g).unwrap();
        let scale = g_cpu.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        let worst = g
            .iter()
            .zip(&g_cpu)
            .map(|(a, b)| (a - b).abs() as f64)
            .fold(0.0, f64::max);
        println!(
            "{name}: gradient differs by {:.1e} of its largest component",
            worst / scale
        );
        // f32 sums over 4096 rows in cuBLAS's order against the CPU's chunked order.
        assert!(worst <= 1e-3 * scale, "{name}: {worst} of {scale}");
    }
}

#[test]
#[ignore = "needs a CUDA GPU: scripts/device/check.sh"]
fn gpu_training_learns_a_peak_and_estimates_it() {
    let gpu = gpu();
    // A Gaussian peak of width 0.1 at (0.3, 0.6); its mass inside the square (3σ and 4σ from
    // the nearest edges) is Π [Φ((1 − μ)/σ) − Φ(−μ/σ)] = 0.99862.
    let phi = |z: f64| 0.5 * (1.0 + libm::erf(z / std::f64::consts::SQRT_2));
    let truth: f64 = [0.3, 0.6]
        .iter()
        .map(|m| phi((1.0 - m) / 0.1) - phi(-m / 0.1))
        .product();
    let peak = |x: &[f32]| -> f64 {
        let d0 = (x[0] as f64 - 0.3) / 0.1;
        let d1 = (x[1] as f64 - 0.6) / 0.1;
        (-(d0 * d0 + d1 * d1) / 2.0).exp() / (2.0 * std::f64::consts::PI * 0.01)
    };
    let flow = Flow::new(FlowConfig::new(2)).unwrap();
    let on = GpuFlow::new(&gpu, &flow).unwrap();
    let adam = AdamConfig {
        learning_rate: 3e-3,
        ..AdamConfig::default()
    };
    let mut trainer = GpuTrainer::new(on, Loss::Kl, adam).unwrap();
    let mut f = |x: &[f32], out: &mut [f64]| {
        for (o, p) in out.iter_mut().zip(x.chunks(2)) {
            *o = peak(p);
        }
    };
    let first = trainer.step(1 << 14, 1, &mut f).unwrap();
    let mut last = first;
    for step in 2..300 {
        last = trainer.step(1 << 14, step, &mut f).unwrap();
    }
    let (rv0, rv1) = (
        first.variance / first.mean.powi(2),
        last.variance / last.mean.powi(2),
    );
    println!("relative variance per point: {rv0:.3} → {rv1:.4}");
    assert!(
        rv1 < 0.05 * rv0,
        "training did not learn the peak: {rv0} → {rv1}"
    );
    // The trained flow's estimate covers the truth within 5 standard errors.
    let n = 1 << 20;
    let est = trainer.step(n, 10_000, &mut f).unwrap();
    let se = (est.variance / n as f64).sqrt();
    println!("estimate {} ± {se} (truth {truth})", est.mean);
    assert!(
        (est.mean - truth).abs() < 5.0 * se,
        "{} ± {se} against {truth}",
        est.mean
    );
    // The trained weights drive the CPU flow to the same densities.
    let mut cpu = flow.clone();
    cpu.params_mut()
        .copy_from_slice(&trainer.flow.params().unwrap());
    let x = [0.3f32, 0.6, 0.9, 0.1];
    let lq_cpu = cpu.log_density(&x, None).unwrap();
    let lq_gpu = trainer.flow.log_density(&x).unwrap();
    assert!((lq_cpu[0] - lq_gpu[0]).abs() < 1e-3 && (lq_cpu[1] - lq_gpu[1]).abs() < 1e-3);
}
