//! Hostile integrands through every method: each gives a clear error, or an estimate whose error
//! bar is honest (and a warning where the weights say it cannot be trusted). docs/results/robustness.md
//! says what the user sees in each case.

use nis::integrate::{integrator, Integrand, IntegrationResult, Method, Settings, PARETO_K_LIMIT};
use nis::{Error, FlowConfig, TransformKind};

/// Every method with small, fast settings (NIS: a small flow, small batches).
fn run(
    method: Method,
    f: &dyn Integrand,
    dim: usize,
    evals: u64,
    seed: u64,
) -> nis::Result<IntegrationResult> {
    let mut s = Settings::default().seed(seed);
    s.nis.flow = FlowConfig {
        transform: TransformKind::Quadratic { bins: 8 },
        hidden_layers: 2,
        hidden_width: 16,
        blob_bins: 8,
        seed,
        ..FlowConfig::default()
    };
    s.nis.batch = 512;
    integrator(method, dim, &s)?.integrate(f, evals)
}

fn pull(r: &IntegrationResult, exact: f64) -> f64 {
    (r.value - exact) / r.std_err
}

#[test]
fn a_panicking_integrand_ends_the_call_with_an_error_naming_the_panic() {
    let f = |x: &[f64]| {
        if x[0] > 0.99 {
            panic!("no value beyond 0.99");
        }
        1.0
    };
    for m in Method::ALL {
        match run(m, &f, 2, 20_000, 1) {
            Err(Error::IntegrandFailed { message }) => {
                assert!(message.contains("no value beyond 0.99"), "{m:?}: {message}")
            }
            other => panic!("{m:?}: expected IntegrandFailed, got {other:?}"),
        }
    }
}

#[test]
fn values_whose_squares_leave_f64_are_a_clear_error_not_an_infinite_or_zero_error_bar() {
    // From 1e-300 to 1e300: the squares of the largest weights overflow.
    let huge = |x: &[f64]| 10f64.powf(600.0 * x[0] - 300.0);
    // Denormal values everywhere: the squares of the weights underflow to zero, which would
    // report "± 0".
    let tiny = |x: &[f64]| 1e-310 * (1.0 + x[0]);
    for (name, f) in [("huge", &huge as &dyn Integrand), ("tiny", &tiny)] {
        for m in Method::ALL {
            match run(m, f, 2, 20_000, 2) {
                Err(e) => {
                    let text = e.to_string();
                    assert!(
                        text.contains("multiply the integrand")
                            || text.contains("integrand returned"),
                        "{name}, {m:?}: unclear error {text}"
                    );
                }
                Ok(r) => panic!("{name}, {m:?}: expected an error, got {r:?}"),
            }
        }
    }
}

#[test]
fn a_wide_but_representable_range_gives_an_honest_estimate() {
    // 1e-30 … 1e30 along x₀: ∫ = (1e30 − 1e-30)/(60 ln 10).
    let f = |x: &[f64]| 10f64.powf(60.0 * x[0] - 30.0);
    let exact = (1e30 - 1e-30) / (60.0 * std::f64::consts::LN_10);
    for m in Method::ALL {
        let r = run(m, &f, 2, 50_000, 3).unwrap();
        // Plain MC sees weights spread over 60 decades: its error bar cannot be trusted, and it
        // must say so; the adaptive methods must be honest.
        if m == Method::Uniform {
            assert!(
                r.pareto_k > PARETO_K_LIMIT || pull(&r, exact).abs() < 5.0,
                "{r:?}"
            );
        } else {
            assert!(pull(&r, exact).abs() < 5.0, "{m:?}: {r:?}");
        }
    }
}

#[test]
fn a_constant_integrand_is_estimated_exactly_or_within_its_error_bar() {
    let f = |_: &[f64]| 3.0;
    for m in Method::ALL {
        let r = run(m, &f, 3, 20_000, 4).unwrap();
        if m == Method::Uniform {
            // Every weight is 3: the mean is exactly 3 and the variance exactly 0.
            assert_eq!((r.value, r.std_err), (3.0, 0.0));
            assert!(r.pareto_k.is_nan() && r.warnings.is_empty(), "{r:?}");
        } else {
            // VEGAS+'s map Jacobians round, so its weights differ at the 1e-15 level and so do
            // its estimate and error bar; error bars do not cover floating-point rounding.
            assert!(
                (r.value - 3.0).abs() < 5.0 * r.std_err + 3.0 * 1e-13,
                "{m:?}: {r:?}"
            );
            assert!(r.warnings.is_empty(), "{m:?}: {r:?}");
        }
    }
}

#[test]
fn sign_changes_and_discontinuities_keep_honest_error_bars() {
    // −1 left of the jump at x₀ = 0.45, 2 right of it: ∫ = −0.45 + 1.1 = 0.65.
    let f = |x: &[f64]| if x[0] < 0.45 { -1.0 } else { 2.0 };
    // Over 8 seeds × 3 methods: each |pull| < 4.5 fails by chance with probability < 2e-4.
    for m in Method::ALL {
        for seed in 0..8 {
            let r = run(m, &f, 2, 20_000, 10 + seed).unwrap();
            assert!(pull(&r, 0.65).abs() < 4.5, "{m:?}, seed {seed}: {r:?}");
        }
    }
}

#[test]
fn an_integrand_zero_but_on_a_tiny_region_is_reported_as_unseen_or_estimated_honestly() {
    // A ball of radius 0.002 around (0.3, 0.7): area π·0.002² ≈ 1.3e-5, found by none of
    // 20 000 uniform points with probability e^(−0.25) ≈ 0.78.
    let r0 = 0.002f64;
    let f = move |x: &[f64]| {
        if (x[0] - 0.3).powi(2) + (x[1] - 0.7).powi(2) < r0 * r0 {
            1.0
        } else {
            0.0
        }
    };
    let exact = std::f64::consts::PI * r0 * r0;
    for m in Method::ALL {
        for seed in 0..3 {
            let r = run(m, &f, 2, 20_000, 20 + seed).unwrap();
            if r.value == 0.0 {
                // Nothing found: the estimate says so in words, not only as "0 ± 0".
                assert!(
                    r.warnings
                        .iter()
                        .any(|w| w.contains("zero at every sampled point")),
                    "{m:?}: {r:?}"
                );
            } else {
                // Found: a few hits make heavy, two-valued weights; honest or flagged.
                assert!(
                    pull(&r, exact).abs() < 5.0 || !r.warnings.is_empty(),
                    "{m:?}, seed {seed}: {r:?}"
                );
            }
        }
    }
}

#[test]
fn heavy_tailed_weights_are_flagged_and_light_ones_are_not() {
    // Uniform points on x^(−0.9) in 1-d: the weights have a Pareto tail of shape 0.9 (infinite
    // variance); ∫ = 10. k̂ ≈ 0.9 ± 0.06 at 10⁵ points, 3σ above the limit.
    let heavy = |x: &[f64]| x[0].max(1e-300).powf(-0.9);
    let r = run(Method::Uniform, &heavy, 1, 100_000, 5).unwrap();
    assert!(r.pareto_k > PARETO_K_LIMIT, "{r:?}");
    assert!(
        r.warnings.iter().any(|w| w.contains("heavy-tailed")),
        "{r:?}"
    );
    // 1 + x: bounded weights, k̂ < 0, no warning.
    let light = |x: &[f64]| 1.0 + x[0];
    let r = run(Method::Uniform, &light, 1, 100_000, 5).unwrap();
    assert!(r.pareto_k < 0.0 && r.warnings.is_empty(), "{r:?}");
    // ESS of 1 + U: n·E[w]²/E[w²] = n·(9/4)/(7/3) = 0.964 n.
    assert!((r.ess / 100_000.0 - 27.0 / 28.0).abs() < 0.005, "{r:?}");
}
