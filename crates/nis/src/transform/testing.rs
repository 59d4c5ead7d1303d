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

/// Runs every generic check on a transform that computes in f64.
pub(crate) fn check_transform<S: Transform>(t: &S, strict: bool) {
    check_transform_at(t, strict, f64::EPSILON / 2.0);
}

/// The generic checks for a transform whose arithmetic has unit roundoff `u` (2⁻⁵³ for f64,
/// 2⁻²⁴ for f32). The round trips' bounds are derived from `u`; the finite-difference checks of
/// log C' and of the gradients run only in f64 (in f32 the rounding of y swamps any step that
/// keeps the truncation small: a transform computing in f32 is checked against its f64 twin).
pub(crate) fn check_transform_at<S: Transform>(t: &S, strict: bool, u: f64) {
    let f64_arithmetic = u <= f64::EPSILON;
    // One evaluation of C or C⁻¹ moves y by at most ~6 roundings of values ≤ 1 (the bin's CDF
    // is the same in both directions); a round trip does both.
    let eval_err = 12.0 * u;
    // Where the density is ≥ 1e-2 a round trip must come back within what the f32 storage of y
    // (half an ulp at 1, 3e-8) and the evaluations move y, over that density.
    let round_trip_tol = 1e-5f64.max((f32_half_ulp(1.0) + eval_err) / 1e-2);
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
            // within `round_trip_tol` (1e-5 in f64) and the round trip must too. Where a
            // transform's density dips lower (the floors are 1e-3, and the rational-quadratic
            // and affine densities dip further between knots or at the ends), the inverse must be
            // exact up to that rounding: C(x') equals the stored y within its half ulp (and the
            // evaluations' own rounding).
            let err = (x2 - x32).abs();
            if err > round_trip_tol {
                // At a bin edge the density may jump, so the smaller of its values at x and x'.
                assert!(
                    ld.min(ld2) < (1e-2f64).ln() || !strict,
                    "set {set}: round trip {x32} -> {y} -> {x2} where C' = {}",
                    ld.exp()
                );
                let y2 = t.forward(p, x2).0;
                assert!(
                    (y2 - y).abs() <= f32_half_ulp(y) + eval_err.max(1e-12),
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
        // The ends: exact up to the rounding of the K-term sums that normalise the knots and,
        // at 1, of the last edge plus the last width (≤ u), which moves C(1) by that times C'(1).
        let (y0, (y1, ld1)) = (t.forward(p, 0.0).0, t.forward(p, 1.0));
        let end_tol = 1e-6f64.max((n as f64 + 12.0 + 2.0 * ld1.exp()) * u);
        assert!(
            y0 < end_tol && y1 > 1.0 - end_tol,
            "set {set}: C(0) = {y0}, C(1) = {y1}"
        );
        if !f64_arithmetic {
            continue;
        }
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

/// Checks that the batched methods give bit for bit the per-scalar methods' numbers, on scalars
/// with the parameter sets above (extreme logits included) laid out feature-major, with inputs
/// at 0, 1, every bin edge and random points, in a count that leaves a partial group of lanes.
pub(crate) fn check_batch<S: Transform>(t: &S) {
    let n = t.param_count();
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let sets = parameter_sets(n);
    // Scalar i uses parameter set i mod sets and an input from a list that covers the special
    // points of that set; the x are f32 values, as the coupling layer hands them over.
    let mut p = Vec::new();
    let mut xs = Vec::new();
    for (s, set) in sets.iter().enumerate() {
        let mut special = vec![0.0, 1.0];
        special.extend(t.bin_edges(set));
        special.extend((0..10).map(|_| rng.random::<f64>()));
        for (i, &x) in special.iter().enumerate() {
            let x32 = x as f32;
            let mut these = vec![x32];
            if (s + i) % 2 == 0 {
                // The value just below it too (just below a bin edge).
                these.push(f32::from_bits(x32.to_bits().saturating_sub(1)).max(0.0));
            }
            for x in these {
                xs.push(x as f64);
                p.extend_from_slice(set);
            }
        }
    }
    // Leave a partial group of lanes at the end.
    let count = xs.len() - usize::from(xs.len() % 8 == 0);
    xs.truncate(count);
    p.truncate(count * n);
    let at = |i: usize| &p[i * n..(i + 1) * n];
    // The same parameters feature-major, as the batched methods take them.
    let by_feature: Vec<f32> = (0..n * count)
        .map(|k| p[(k % count) * n + k / count])
        .collect();

    let mut y = xs.clone();
    let mut ld = vec![0.25; count];
    t.forward_batch(&by_feature, &mut y, &mut ld);
    let mut back = y.iter().map(|&y| y as f32 as f64).collect::<Vec<_>>();
    let mut ld_back = vec![-0.5; count];
    t.inverse_batch(&by_feature, &mut back, &mut ld_back);
    let g_ld: Vec<f64> = (0..count).map(|_| rng.random::<f64>() - 0.5).collect();
    let g_y: Vec<f64> = (0..count).map(|_| rng.random::<f64>() - 0.5).collect();
    let mut g = g_y.clone();
    let mut g_p = vec![f32::NAN; count * n];
    t.backward_batch(&by_feature, &xs, &mut g, &g_ld, &mut g_p);

    let mut g_ref = vec![0.0f32; n];
    for i in 0..count {
        let (y_ref, ld_ref) = t.forward(at(i), xs[i]);
        assert_eq!(y[i].to_bits(), y_ref.to_bits(), "forward y of scalar {i}");
        assert_eq!(
            ld[i].to_bits(),
            (0.25 + ld_ref).to_bits(),
            "forward ln C' {i}"
        );
        let (x_ref, ldi_ref) = t.inverse(at(i), y[i] as f32 as f64);
        assert_eq!(
            back[i].to_bits(),
            x_ref.to_bits(),
            "inverse x of scalar {i}"
        );
        assert_eq!(
            ld_back[i].to_bits(),
            (-0.5 + ldi_ref).to_bits(),
            "inverse ln C' {i}"
        );
        let g_x = t.backward(at(i), xs[i], g_y[i], g_ld[i], &mut g_ref);
        assert_eq!(g[i].to_bits(), g_x.to_bits(), "∂L/∂x of scalar {i}");
        for (j, b) in g_ref.iter().enumerate() {
            let a = g_p[j * count + i];
            assert_eq!(
                a.to_bits(),
                b.to_bits(),
                "∂L/∂p[{j}] of scalar {i}: {a} vs {b}"
            );
        }
    }
}
