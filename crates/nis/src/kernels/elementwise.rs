//! Fused element-wise loops: activation, one-blob encoding, bias gradients, Adam. Each is written
//! as a plain loop that the compiler vectorises, compiled for several instruction sets and picked
//! at run time (`multiversion`); the inner math is `#[inline(always)]` so it vectorises with them.

use multiversion::multiversion;

const LOG2E: f32 = std::f32::consts::LOG2_E;
const LN2_HI: f32 = 0.693_145_75;
const LN2_LO: f32 = 1.428_606_8e-6;

/// e^x for f32 in a form that vectorises: range reduction to r ∈ [−ln2/2, ln2/2] in two parts
/// (Cody–Waite), a degree-6 Taylor polynomial (relative error < 2e-7 there) and the exponent put
/// back through the float's bits. Arguments are clamped to [−87, 88]; below, e^x is ~1e-38.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    // Round to nearest by adding 1.5·2²³: the sum's low mantissa bits then hold the integer n,
    // which gives n both as a float (subtract again) and as bits for the exponent — no
    // float-to-int conversion (saturating in Rust, slow in vector code) and no libm `floor`.
    const SHIFTER: f32 = 12_582_912.0;
    let t = x * LOG2E + SHIFTER;
    let n = t - SHIFTER;
    let ni = t.to_bits().wrapping_sub(SHIFTER.to_bits()) as i32;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    p * f32::from_bits(((ni + 127) << 23) as u32)
}

/// `out[i] = e^(x[i] − shift)` (computed in f32, stored in f64) and returns Σ out: the
/// exponentials of a spline's logits.
#[multiversion(targets = "simd")]
pub fn exp_shifted(x: &[f32], shift: f32, out: &mut [f64]) -> f64 {
    // Two loops: a float sum in the first would chain every iteration and stop vectorisation.
    for (o, &v) in out.iter_mut().zip(x) {
        *o = exp(v - shift) as f64;
    }
    out[..x.len()].iter().sum()
}

/// ln(1 + t) for t in [0, 1] as 2·atanh(t/(2 + t)): an odd series in s = t/(2 + t) ≤ 1/3 whose
/// terms up to s¹³ leave a relative error below 1e-8. Forming s from t directly (not from the
/// rounded 1 + t) keeps small t exact. Plain arithmetic, so it vectorises.
#[inline(always)]
fn ln_1p_unit(t: f32) -> f32 {
    let s = t / (2.0 + t);
    let s2 = s * s;
    2.0 * s
        * (1.0
            + s2 * (1.0 / 3.0
                + s2 * (1.0 / 5.0
                    + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0 + s2 * (1.0 / 11.0 + s2 / 13.0))))))
}

/// `out[i] = softplus(x[i] + shift) = ln(1 + e^(x[i] + shift))`, computed stably as
/// max(v, 0) + ln(1 + e^(−|v|)) in f32 and stored in f64: the knot derivatives of the
/// rational-quadratic spline (libm's scalar log1p was its hot spot; docs/results/integration.md,
/// "Flow throughput against bare gemm and PyTorch", lists the kernel work).
#[multiversion(targets = "simd")]
pub fn softplus_shifted(x: &[f32], shift: f32, out: &mut [f64]) {
    for (o, &v) in out.iter_mut().zip(x) {
        let v = v + shift;
        *o = (v.max(0.0) + ln_1p_unit(exp(-v.abs()))) as f64;
    }
}

/// `out[i] = sigmoid(x[i] + shift)`, the derivative of [`softplus_shifted`].
#[multiversion(targets = "simd")]
pub fn sigmoid_shifted(x: &[f32], shift: f32, out: &mut [f64]) {
    for (o, &v) in out.iter_mut().zip(x) {
        *o = (1.0 / (1.0 + exp(-(v + shift)))) as f64;
    }
}

/// In-place ReLU.
#[multiversion(targets = "simd")]
pub fn relu(v: &mut [f32]) {
    for x in v {
        *x = x.max(0.0);
    }
}

/// ReLU backward from the activation's output: `g *= (a > 0)`.
#[multiversion(targets = "simd")]
pub fn relu_backward(a: &[f32], g: &mut [f32]) {
    for (g, &a) in g.iter_mut().zip(a) {
        *g = if a > 0.0 { *g } else { 0.0 };
    }
}

/// One-blob encoding (Müller et al. 2019, "Neural Importance Sampling", Sec. 4.3): each scalar
/// s ∈ [0, 1] becomes `k` values e_j = exp(−(k²/2)·((j + ½)/k − s)²), a Gaussian blob of width 1/k
/// centred on s. `out` receives the `k` values of every scalar in `s`, one after another.
pub fn one_blob(s: &[f32], k: usize, out: &mut [f32]) {
    // The usual bin counts get a copy with `k` known at compile time: its bins fill whole
    // vector registers and the constants stay in registers across scalars (the same numbers).
    match k {
        8 => one_blob_of::<8>(s, out),
        16 => one_blob_of::<16>(s, out),
        32 => one_blob_of::<32>(s, out),
        _ => one_blob_any(s, k, out),
    }
}

#[multiversion(targets = "simd")]
fn one_blob_of<const K: usize>(s: &[f32], out: &mut [f32]) {
    one_blob_rows(s, K, out);
}

#[multiversion(targets = "simd")]
fn one_blob_any(s: &[f32], k: usize, out: &mut [f32]) {
    one_blob_rows(s, k, out);
}

/// The body of both copies of [`one_blob`].
#[inline(always)]
fn one_blob_rows(s: &[f32], k: usize, out: &mut [f32]) {
    let kf = k as f32;
    let c = -0.5 * kf * kf;
    for (&s, e) in s.iter().zip(out.chunks_exact_mut(k)) {
        for (j, e) in e.iter_mut().enumerate() {
            let d = (j as f32 + 0.5) / kf - s;
            *e = exp(c * d * d);
        }
    }
}

/// Reverse mode of [`one_blob`]: ∂L/∂s = Σ_j ∂L/∂e_j · e_j · k²((j + ½)/k − s).
#[multiversion(targets = "simd")]
pub fn one_blob_backward(s: &[f32], k: usize, e: &[f32], g_e: &[f32], g_s: &mut [f32]) {
    let kf = k as f32;
    let k2 = kf * kf;
    for (i, (&s, g_s)) in s.iter().zip(g_s.iter_mut()).enumerate() {
        let e = &e[i * k..(i + 1) * k];
        let g_e = &g_e[i * k..(i + 1) * k];
        let mut acc = 0.0f32;
        for j in 0..k {
            let d = (j as f32 + 0.5) / kf - s;
            acc += g_e[j] * e[j] * k2 * d;
        }
        *g_s = acc;
    }
}

/// Column sums of a row-major `[n, o]` matrix, for columns `c0..c0 + out.len()`, summed in row
/// order (so the result is independent of scheduling).
#[multiversion(targets = "simd")]
pub fn column_sums(m: &[f32], o: usize, c0: usize, out: &mut [f32]) {
    out.fill(0.0);
    let w = out.len();
    for row in m.chunks_exact(o) {
        for (acc, &v) in out.iter_mut().zip(&row[c0..c0 + w]) {
            *acc += v;
        }
    }
}

/// Σ g², accumulated in f64 over eight interleaved lanes and summed lane by lane at the end:
/// a fixed order (the result does not depend on scheduling) that vectorises, where one running
/// sum is a chain of dependent additions (Adam's gradient norm runs over every parameter of the
/// flow at each step).
#[multiversion(targets = "simd")]
pub fn sum_of_squares(g: &[f32]) -> f64 {
    const W: usize = 8;
    let mut lanes = [0.0f64; W];
    let mut blocks = g.chunks_exact(W);
    for b in &mut blocks {
        for (l, &v) in lanes.iter_mut().zip(b) {
            *l += f64::from(v) * f64::from(v);
        }
    }
    let tail: f64 = blocks
        .remainder()
        .iter()
        .map(|&v| f64::from(v) * f64::from(v))
        .sum();
    lanes.iter().sum::<f64>() + tail
}

/// The scalars of one Adam update: `lr_t` already includes the bias corrections,
/// lr·√(1 − β₂ᵗ)/(1 − β₁ᵗ); the gradient is multiplied by `grad_scale` (clipping) first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamStep {
    pub lr_t: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    pub grad_scale: f32,
}

/// One Adam update (Kingma & Ba 2014, Algorithm 1) of `p` with gradient `g`, moments `m` and `v`.
#[multiversion(targets = "simd")]
pub fn adam(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], step: AdamStep) {
    let AdamStep {
        lr_t,
        beta1,
        beta2,
        eps,
        grad_scale,
    } = step;
    for i in 0..p.len() {
        let gi = g[i] * grad_scale;
        m[i] = beta1 * m[i] + (1.0 - beta1) * gi;
        v[i] = beta2 * v[i] + (1.0 - beta2) * gi * gi;
        p[i] -= lr_t * m[i] / (v[i].sqrt() + eps);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp_matches_std_within_a_few_ulp() {
        let mut worst = 0.0f64;
        let mut x = -80.0f32;
        while x < 80.0 {
            let rel = ((exp(x) as f64 - (x as f64).exp()) / (x as f64).exp()).abs();
            worst = worst.max(rel);
            x += 0.0137;
        }
        assert!(worst < 4e-7, "worst relative error {worst}");
    }

    #[test]
    fn softplus_and_sigmoid_match_libm() {
        let x: Vec<f32> = (0..4001).map(|i| -40.0 + i as f32 * 0.02).collect();
        let (mut sp, mut sg) = (vec![0.0; x.len()], vec![0.0; x.len()]);
        softplus_shifted(&x, 0.5, &mut sp);
        sigmoid_shifted(&x, 0.5, &mut sg);
        for (i, &v) in x.iter().enumerate() {
            let v = v as f64 + 0.5;
            let want = v.max(0.0) + (-v.abs()).exp().ln_1p();
            assert!(
                (sp[i] - want).abs() <= 4e-7 * want.max(1e-30),
                "softplus({v})"
            );
            let want = 1.0 / (1.0 + (-v).exp());
            assert!((sg[i] - want).abs() <= 4e-7 * want, "sigmoid({v})");
        }
    }

    #[test]
    fn one_blob_is_the_same_for_every_bin_count_path() {
        let s: Vec<f32> = (0..=40)
            .map(|i| i as f32 / 40.0)
            .chain([-0.1, 1.1])
            .collect();
        for k in [1, 5, 8, 16, 32] {
            let mut fast = vec![0.0; s.len() * k];
            let mut plain = vec![0.0; s.len() * k];
            one_blob(&s, k, &mut fast);
            one_blob_any(&s, k, &mut plain);
            assert_eq!(fast, plain, "k = {k}");
            for (i, &v) in s.iter().enumerate() {
                for j in 0..k {
                    let d = (j as f64 + 0.5) / k as f64 - v as f64;
                    let want = (-((k * k) as f64) / 2.0 * d * d).exp();
                    // f32 rounding of d (a few ulps, amplified by the exponent's size) and exp's 2e-7
                    let tol = 4e-7 * want * (1.0 + (k * k) as f64 * d.abs() * d.abs());
                    assert!(
                        (fast[i * k + j] as f64 - want).abs() <= tol.max(1e-37),
                        "k = {k}, s = {v}, j = {j}"
                    );
                }
            }
        }
    }

    #[test]
    fn one_blob_backward_matches_finite_differences() {
        let k = 8;
        let s = [0.0f32, 0.31, 0.5, 0.97, 1.0];
        let g_e: Vec<f32> = (0..s.len() * k)
            .map(|i| ((i * 7) % 5) as f32 - 2.0)
            .collect();
        let mut e = vec![0.0; s.len() * k];
        one_blob(&s, k, &mut e);
        let mut g_s = vec![0.0; s.len()];
        one_blob_backward(&s, k, &e, &g_e, &mut g_s);
        for i in 0..s.len() {
            let f = |si: f64| -> f64 {
                (0..k)
                    .map(|j| {
                        let d = (j as f64 + 0.5) / k as f64 - si;
                        g_e[i * k + j] as f64 * (-((k * k) as f64) / 2.0 * d * d).exp()
                    })
                    .sum()
            };
            let h = 1e-6;
            let fd = (f(s[i] as f64 + h) - f(s[i] as f64 - h)) / (2.0 * h);
            assert!(
                (fd - g_s[i] as f64).abs() < 1e-4 * (1.0 + fd.abs()),
                "{fd} vs {}",
                g_s[i]
            );
        }
    }

    #[test]
    fn column_sums_match_a_plain_loop() {
        let (n, o) = (37, 9);
        let m: Vec<f32> = (0..n * o).map(|i| (i % 11) as f32 * 0.25).collect();
        let mut out = vec![0.0; 4];
        column_sums(&m, o, 3, &mut out);
        for (j, &v) in out.iter().enumerate() {
            let want: f32 = (0..n).map(|r| m[r * o + 3 + j]).sum();
            assert_eq!(v, want);
        }
    }

    #[test]
    fn sum_of_squares_matches_the_f64_sum() {
        // 8·k + 5 values (a partial block): the lanes' sum against a plain sum in f64, to the
        // rounding of either order (a few ulps of the total).
        let g: Vec<f32> = (0..8 * 37 + 5)
            .map(|i| (i as f32 * 0.37).sin() * 3.0)
            .collect();
        let plain: f64 = g.iter().map(|&v| f64::from(v) * f64::from(v)).sum();
        let got = sum_of_squares(&g);
        assert!((got - plain).abs() <= 1e-14 * plain, "{got} vs {plain}");
        assert_eq!(sum_of_squares(&[]), 0.0);
        assert_eq!(sum_of_squares(&[2.0, -3.0]), 13.0);
    }
}
