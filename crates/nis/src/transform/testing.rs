//! Shared checks every transform must pass: round trips (including extreme parameters, the ends of
//! the interval and bin edges), monotonicity, log-derivatives against finite differences, and
//! reverse-mode gradients against central differences.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::Transform;

/// Gaussian-ish random parameters of scale `scale` (sum of uniforms; no extra crate needed).
pub(crate) fn random_params(n: usize, scale: f32, seed: u64) -> Vec<f32> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..n)
        .map(|_| scale * ((0..4).map(|_| rng.random::<f32>()).sum::<f32>() - 2.0) * 1.732)
        .collect()
}

fn parameter_sets(n: usize) -> Vec<Vec<f32>> {
    let mut sets = vec![vec![0.0; n]];
    for (i, scale) in [0.5f32, 2.0, 5.0].into_iter().enumerate() {
        sets.push(random_params(n, scale, 100 + i as u64));
    }
    // Extreme logits ±30 in random patterns.
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    for _ in 0..4 {
        sets.push(
            (0..n)
                .map(|_| if rng.random::<bool>() { 30.0 } else { -30.0 })
                .collect(),
        );
    }
    sets
}

/// Half the spacing of f32 values around y.
fn f32_half_ulp(y: f64) -> f64 {
    let y = y as f32;
    0.5 * (f32::from_bits(y.to_bits() + 1) - y) as f64
}

/// Runs every generic check on a transform.
pub(crate) fn check_transform<S: Transform>(t: &S, strict: bool) {
    let n = t.param_count();
    let mut rng = Pcg64Mcg::seed_from_u64(42);
    for (set, p) in parameter_sets(n).iter().enumerate() {
        let edges = t.bin_edges(p);
        assert_eq!(edges[0], 0.0);
        assert_eq!(*edges.last().unwrap(), 1.0);
        let mut xs: Vec<f64> = (0..200).map(|_| rng.random::<f64>()).collect();
        xs.extend([0.0, 1.0, 0.5]);
        xs.extend(edges.iter().copied());
        for &x in &xs {
            let x32 = x as f32 as f64;
            let (y, ld) = t.forward(p, x32);
            assert!((0.0..=1.0).contains(&y), "set {set}: y = {y} at x = {x32}");
            assert!(ld.is_finite(), "set {set}: log_det = {ld} at x = {x32}");
            // The latent is stored as f32 between layers: round through it.
            let (x2, ld2) = t.inverse(p, y as f32 as f64);
            // Rounding y to f32 moves it by up to half an ulp, which moves x by that over the
            // density: the inverse's condition number. Where the density is ≥ 1e-2 that stays
            // within 1e-5 and the round trip must too. Where a transform's density dips lower
            // (the floors are 1e-3, and the rational-quadratic and affine densities dip further
            // between knots or at the ends), the inverse must be exact up to that rounding:
            // C(x') equals the stored y within its half ulp.
            let err = (x2 - x32).abs();
            if err > 1e-5 {
                // At a bin edge the density may jump, so the smaller of its values at x and x'.
                assert!(
                    ld.min(ld2) < (1e-2f64).ln() || !strict,
                    "set {set}: round trip {x32} -> {y} -> {x2} where C' = {}",
                    ld.exp()
                );
                let y2 = t.forward(p, x2).0;
                assert!(
                    (y2 - y).abs() <= f32_half_ulp(y) + 1e-12,
                    "set {set}: round trip {x32} -> {y} -> {x2}; C(x') = {y2}"
                );
            }
            assert!(ld2.is_finite());
        }
        // Monotone, from 0 to 1.
        let mut last = -1.0;
        for i in 0..=1000 {
            let (y, _) = t.forward(p, i as f64 / 1000.0);
            assert!(
                y >= last,
                "set {set}: not monotone at {}",
                i as f64 / 1000.0
            );
            last = y;
        }
        assert!(t.forward(p, 0.0).0 < 1e-6 && t.forward(p, 1.0).0 > 1.0 - 1e-6);
        // log C'(x) against a central difference of C, away from bin edges (kinks of C').
        for _ in 0..50 {
            let x = 0.02 + 0.96 * rng.random::<f64>();
            let h = 1e-7;
            if edges.iter().any(|e| (e - x).abs() < 1e-5) {
                continue;
            }
            let fd = (t.forward(p, x + h).0 - t.forward(p, x - h).0) / (2.0 * h);
            let ld = t.forward(p, x).1;
            // Truncation (h²) plus the rounding of y (1e-16/h) relative to the density.
            let tol = 1e-4 + 1e-15 / (h * fd);
            assert!(
                (fd.ln() - ld).abs() < tol,
                "set {set}: log_det {ld} vs finite difference {} at {x}",
                fd.ln()
            );
        }
        if set <= 3 {
            check_gradients(t, p, &edges, &mut rng);
        }
    }
}

/// Compares `backward` with central differences of L = g_y·y + g_ld·log_det.
fn check_gradients<S: Transform>(t: &S, p: &[f32], edges: &[f64], rng: &mut Pcg64Mcg) {
    let n = t.param_count();
    let mut g_p = vec![0.0f32; n];
    for _ in 0..20 {
        let x = rng.random::<f64>();
        if edges.iter().any(|e| (e - x).abs() < 5e-3) {
            continue;
        }
        let (g_y, g_ld) = (rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5);
        let loss = |p: &[f32], x: f64| {
            let (y, ld) = t.forward(p, x);
            g_y * y + g_ld * ld
        };
        let g_x = t.backward(p, x, g_y, g_ld, &mut g_p);
        let h = 1e-6;
        let fd_x = (loss(p, x + h) - loss(p, x - h)) / (2.0 * h);
        assert!(
            (fd_x - g_x).abs() <= 1e-4 * (1.0 + fd_x.abs()),
            "dL/dx {g_x} vs {fd_x}"
        );
        for i in 0..n {
            // Params are f32: step by a representable amount and divide by the actual step.
            let h = 1e-3f32;
            let mut pp = p.to_vec();
            pp[i] = p[i] + h;
            let up = loss(&pp, x);
            let hu = pp[i] - p[i];
            pp[i] = p[i] - h;
            let dn = loss(&pp, x);
            let hd = p[i] - pp[i];
            let fd = (up - dn) / (hu + hd) as f64;
            let g = g_p[i] as f64;
            assert!(
                (fd - g).abs() <= 2e-3 * fd.abs().max(g.abs()) + 2e-5,
                "dL/dp[{i}] = {g} vs finite difference {fd} (x = {x})"
            );
        }
    }
}
