//! The kernels' bodies on the CPU against nis's transforms, encoding and flow.

use super::*;
use nis::nn::encoding::OneBlob;
use nis::nn::{Adam, AdamConfig};
use nis::transform::{Quadratic, RationalQuadratic};
use nis::Transform;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Standard-normal-ish parameters of scale `s` (a sum of uniforms: enough to bend a spline hard).
fn params(n: usize, s: f32, rng: &mut Pcg64Mcg) -> Vec<f32> {
    (0..n)
        .map(|_| s * ((0..4).map(|_| rng.random::<f32>()).sum::<f32>() - 2.0) * 1.7)
        .collect()
}

/// Points to test at: random ones and both ends.
fn points(rng: &mut Pcg64Mcg) -> Vec<f64> {
    let mut t: Vec<f64> = (0..200).map(|_| rng.random::<f32>() as f64).collect();
    t.extend([0.0, 1.0, 1e-7, 1.0 - 1e-7]);
    t
}

fn pq(p: &[f32], k: usize, t: f64, inverse: bool) -> (f64, f64) {
    let mut ld = 0.0;
    // SAFETY: p holds the 2k + 1 parameters the kernel reads.
    let y = unsafe { nis_cpu_pq(p.as_ptr(), k as c_int, t as f32, inverse as c_int, &mut ld) };
    (y as f64, ld)
}

fn rq(p: &[f32], k: usize, t: f64, inverse: bool) -> (f64, f64) {
    let mut ld = 0.0;
    // SAFETY: p holds the 3k + 1 parameters the kernel reads.
    let y = unsafe { nis_cpu_rq(p.as_ptr(), k as c_int, t, inverse as c_int, &mut ld) };
    (y, ld)
}

/// An inverse against the Rust transform's: y's rounding `dy` moves x by dy/C'(x), and ln C' by
/// its slope there times that move, on top of its own rounding `dld`.
fn check_inverse(
    t: &impl Transform,
    p: &[f32],
    (x, ld): (f64, f64),
    (x_r, ld_r): (f64, f64),
    dy: f64,
    dld: f64,
) {
    let tol_x = dy * (-ld_r).exp().max(1.0);
    assert!(
        (x - x_r).abs() <= tol_x,
        "x {x} vs {x_r} (tolerance {tol_x})"
    );
    let h = 1e-4;
    let at = |v: f64| t.forward(p, v.clamp(0.0, 1.0)).1;
    let slope = ((at(x_r + h) - ld_r).abs()).max((ld_r - at(x_r - h)).abs()) / h;
    let tol_ld = dld + slope * tol_x;
    assert!(
        (ld - ld_r).abs() <= tol_ld,
        "ln C' {ld} vs {ld_r} (tolerance {tol_ld})"
    );
}

/// The kernel `kernel(p, bins, t, inverse)` against the Rust transform `make(bins)` at random
/// parameters and points, both directions: y within `dy`, ln C' within `dld`.
fn matches_transform<T: Transform>(
    make: impl Fn(usize) -> T,
    kernel: fn(&[f32], usize, f64, bool) -> (f64, f64),
    bins: &[usize],
    seed: u64,
    (dy, dld): (f64, f64),
) {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    for &k in bins {
        let t = make(k);
        for _ in 0..5 {
            let p = params(t.param_count(), 1.5, &mut rng);
            for x in points(&mut rng) {
                let (y, ld) = kernel(&p, k, x, false);
                let (y_r, ld_r) = t.forward(&p, x);
                assert!((y - y_r).abs() < dy, "K={k} x={x}: y {y} vs {y_r}");
                assert!((ld - ld_r).abs() < dld, "K={k} x={x}: ln C' {ld} vs {ld_r}");
                let (xi, ld_i) = kernel(&p, k, y_r, true);
                let (x_r, ld_ir) = t.inverse(&p, y_r);
                check_inverse(&t, &p, (xi, ld_i), (x_r, ld_ir), dy, dld);
            }
        }
    }
}

#[test]
fn piecewise_quadratic_matches_the_rust_transform() {
    // Both compute in f32 with the same exponential (the knots summed in the lanes' order on
    // the Rust side): a few ulps of y, and ln C' to the f32 rounding of the densities.
    let bins = [1, 2, 5, 16, 32, 256];
    matches_transform(|k| Quadratic { bins: k }, pq, &bins, 1, (2e-6, 2e-5));
}

#[test]
fn rational_quadratic_matches_the_rust_transform() {
    // f64 throughout, from the same f32 exponentials and softplus.
    let bins = [1, 2, 5, 16, 256];
    matches_transform(
        |k| RationalQuadratic { bins: k },
        rq,
        &bins,
        2,
        (1e-6, 1e-5),
    );
}

#[test]
fn one_blob_matches_the_rust_encoding() {
    for k in [1, 3, 16, 32] {
        let enc = OneBlob { bins: k };
        for s in [0.0f32, 0.013, 0.5, 0.77, 1.0] {
            let mut e = vec![0.0; k];
            enc.encode(&[s], &mut e);
            for (j, &e_j) in e.iter().enumerate() {
                // SAFETY: plain arithmetic.
                let g = unsafe { nis_cpu_one_blob(s, k as c_int, j as c_int) };
                assert!((g - e_j).abs() < 1e-6, "k={k} s={s} j={j}: {g} vs {e_j}");
            }
        }
    }
}

#[test]
fn the_counter_stream_is_uniform_and_seeded() {
    let n = 200_000u64;
    // SAFETY: plain arithmetic.
    let u: Vec<f64> = (0..n)
        .map(|i| unsafe { nis_cpu_uniform(7, i) } as f64)
        .collect();
    assert!(u.iter().all(|&v| (0.0..1.0).contains(&v)));
    // Mean 1/2 and variance 1/12, each within 5 standard errors.
    let mean = u.iter().sum::<f64>() / n as f64;
    assert!(
        (mean - 0.5).abs() < 5.0 * (1.0 / 12.0 / n as f64).sqrt(),
        "mean {mean}"
    );
    let var = u.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
    // Var of (U − ½)² is 1/180.
    assert!(
        (var - 1.0 / 12.0).abs() < 5.0 * (1.0 / 180.0 / n as f64).sqrt(),
        "var {var}"
    );
    // Neighbouring counters uncorrelated: lag-1 correlation within 5/√n.
    let c = u
        .windows(2)
        .map(|w| (w[0] - 0.5) * (w[1] - 0.5))
        .sum::<f64>()
        / (n - 1) as f64;
    assert!(
        (c * 12.0).abs() < 5.0 / (n as f64).sqrt(),
        "lag-1 correlation {}",
        c * 12.0
    );
    // Another seed, another stream; the same seed, the same numbers.
    // SAFETY: plain arithmetic.
    let other: Vec<f32> = (0..64).map(|i| unsafe { nis_cpu_uniform(8, i) }).collect();
    assert!(
        other
            .iter()
            .zip(&u)
            .filter(|(a, b)| **a as f64 == **b)
            .count()
            < 2
    );
    // SAFETY: plain arithmetic.
    assert_eq!(unsafe { nis_cpu_uniform(7, 12345) } as f64, u[12345]);
}

/// Largest |a − b| over the largest |b| (or 1): a relative difference of two gradients.
pub(super) fn rel_diff(a: &[f32], b: &[f32]) -> f64 {
    let scale = b.iter().fold(1.0f64, |m, &v| m.max((v as f64).abs()));
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (x as f64 - y as f64).abs())
        .fold(0.0, f64::max)
        / scale
}

#[test]
fn transform_gradients_match_the_rust_transforms() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    for k in [1, 2, 5, 16, 32] {
        let (pq_t, rq_t) = (Quadratic { bins: k }, RationalQuadratic { bins: k });
        for _ in 0..5 {
            let p = params(pq_t.param_count(), 1.5, &mut rng);
            let pr = params(rq_t.param_count(), 1.5, &mut rng);
            for x in points(&mut rng) {
                let (g_y, g_ld) = (rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5);
                let mut g = vec![0.0f32; p.len()];
                let mut g_r = vec![0.0f32; p.len()];
                // SAFETY: p and g hold the 2k + 1 values the kernel reads and writes.
                let gx = unsafe {
                    nis_cpu_pq_backward(
                        p.as_ptr(),
                        k as c_int,
                        x as f32,
                        g_y as f32,
                        g_ld as f32,
                        g.as_mut_ptr(),
                    )
                };
                let gx_r = pq_t.backward(&p, x, g_y, g_ld, &mut g_r);
                // The same f32 operations in the same order: rounding apart, the same numbers.
                assert!(
                    rel_diff(&g, &g_r) < 1e-5,
                    "PQ K={k} x={x}: {g:?} vs {g_r:?}"
                );
                assert!(
                    (gx as f64 - gx_r).abs() <= 1e-5 * gx_r.abs().max(1.0),
                    "PQ K={k} x={x}: ∂x {gx} vs {gx_r}"
                );
                let mut g = vec![0.0f32; pr.len()];
                let mut g_r = vec![0.0f32; pr.len()];
                // SAFETY: pr and g hold the 3k + 1 values the kernel reads and writes.
                let gx = unsafe {
                    nis_cpu_rq_backward(pr.as_ptr(), k as c_int, x, g_y, g_ld, g.as_mut_ptr())
                };
                let gx_r = rq_t.backward(&pr, x, g_y, g_ld, &mut g_r);
                assert!(
                    rel_diff(&g, &g_r) < 1e-6,
                    "RQ K={k} x={x}: {g:?} vs {g_r:?}"
                );
                assert!(
                    (gx - gx_r).abs() <= 1e-9 * gx_r.abs().max(1.0),
                    "RQ K={k} x={x}: ∂x {gx} vs {gx_r}"
                );
            }
        }
    }
}

#[test]
fn one_blob_gradient_matches_the_rust_encoding() {
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    for k in [1, 3, 16, 32] {
        let enc = OneBlob { bins: k };
        for _ in 0..20 {
            let s: f32 = rng.random();
            let mut e = vec![0.0; k];
            enc.encode(&[s], &mut e);
            let g_e: Vec<f32> = (0..k).map(|_| rng.random::<f32>() - 0.5).collect();
            let mut g_s = [0.0f32];
            enc.backward(&[s], &e, &g_e, &mut g_s);
            // SAFETY: e and g_e hold k values.
            let g = unsafe { nis_cpu_one_blob_backward(s, k as c_int, e.as_ptr(), g_e.as_ptr()) };
            assert!(
                (g - g_s[0]).abs() <= 1e-5 * g_s[0].abs().max(1.0),
                "k={k} s={s}: {g} vs {}",
                g_s[0]
            );
        }
    }
}

#[test]
fn adam_matches_the_rust_optimiser() {
    let config = AdamConfig {
        learning_rate: 3e-3,
        decay: 0.99,
        ..AdamConfig::default()
    };
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let n = 1000;
    let mut p: Vec<f32> = (0..n).map(|_| rng.random::<f32>() - 0.5).collect();
    let mut p_r = p.clone();
    let (mut m, mut v) = (vec![0.0f32; n], vec![0.0f32; n]);
    let mut adam = Adam::new(config, n).unwrap();
    for t in 1..=5u64 {
        let g: Vec<f32> = (0..n).map(|_| rng.random::<f32>() - 0.5).collect();
        adam.step(&mut p_r, &g).unwrap();
        // The step size GpuAdam hands its kernel.
        let lr_t = crate::adam::step_size(&config, t);
        // SAFETY: every buffer holds n values.
        unsafe {
            nis_cpu_adam(
                p.as_mut_ptr(),
                g.as_ptr(),
                m.as_mut_ptr(),
                v.as_mut_ptr(),
                n as i64,
                lr_t,
                config.beta1,
                config.beta2,
                config.eps,
                1.0,
            )
        };
    }
    assert_eq!(p, p_r);
}
