//! Runs to a precision target (`Integrator::integrate_to`): every method stops at the target
//! with an unbiased estimate whose error bar covers the truth at its nominal rate, limits end a
//! run with a warning, and bad targets are refused before the integrand is called.

use std::sync::atomic::{AtomicU64, Ordering};

use nis::integrands;
use nis::integrate::nis::{NisConfig, NisIntegrator};
use nis::integrate::uniform::{PlainMc, PlainMcConfig};
use nis::integrate::vegas::{Vegas, VegasConfig};
use nis::integrate::{Integrand, IntegrationResult, Integrator, Stop, Target};
use nis::{FlowConfig, TransformKind};

/// Runs 0..`runs` of `run`: each must stop at its target; their errors must have a mean within
/// 4 standard errors of zero plus `bias` times the runs' mean σ (the bias a run may have, in
/// units of its own error bar: 0 where the estimate is unbiased), and at least `least` of them
/// must lie within 2σ (the binomial band of 95.4% coverage, 4 standard deviations below).
fn check_stopped(
    label: &str,
    exact: f64,
    runs: u64,
    bias: f64,
    run: impl Fn(u64) -> IntegrationResult,
) {
    let results: Vec<IntegrationResult> = (0..runs).map(run).collect();
    let n = runs as f64;
    for r in &results {
        assert_eq!(r.stop, Some(Stop::Target), "{label}: {r:?}");
    }
    let pulls: Vec<f64> = results
        .iter()
        .map(|r| (r.value - exact) / r.std_err)
        .collect();
    let covered = pulls.iter().filter(|p| p.abs() <= 2.0).count() as f64;
    let p = 0.9545;
    let least = n * p - 4.0 * (n * p * (1.0 - p)).sqrt();
    // The bias of the value itself (the pulls' mean is not zero for skewed weights even at a
    // fixed sample size: σ̂ is correlated with the value).
    let errors: Vec<f64> = results.iter().map(|r| r.value - exact).collect();
    let mean = errors.iter().sum::<f64>() / n;
    let se = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
    eprintln!(
        "{label}: {covered}/{runs} within 2σ (≥ {least:.1}), mean error {mean:.2e} ± {se:.2e}"
    );
    assert!(covered >= least, "{label}: only {covered}/{runs} within 2σ");
    let sigma = results.iter().map(|r| r.std_err).sum::<f64>() / n;
    assert!(
        mean.abs() <= 4.0 * se + bias * sigma,
        "{label}: mean error {mean} against its standard error {se} (runs' σ {sigma})"
    );
}

/// ∏ 3x_i² on [0, 1]²: ∫ = 1, skewed weights (relative variance 2.24 per evaluation), whose mean
/// and variance estimates are correlated: the case where stopping on the running error biases.
fn skewed(x: &[f64]) -> f64 {
    x.iter().map(|v| 3.0 * v * v).product()
}

#[test]
fn plain_mc_stopped_at_a_target_is_unbiased_and_covers() {
    for rel in [0.05, 0.01] {
        check_stopped(&format!("uniform rel {rel}"), 1.0, 1000, 0.0, |seed| {
            let config = PlainMcConfig::builder().seed(seed).build().unwrap();
            let mut mc = PlainMc::new(2, config).unwrap();
            let r = mc.integrate_to(&skewed, &Target::rel(rel)).unwrap();
            assert!(r.std_err <= rel * r.value.abs());
            r
        });
    }
}

/// 0.6·x₀^(−0.4) on [0, 1]: ∫ = 1 with a heavy tail of weights (finite variance, Pareto k̂ 0.4):
/// the pilot often underestimates the variance, so rounds end short of the target and are
/// extended (the one step whose share depends on the round's own error).
fn heavy(x: &[f64]) -> f64 {
    0.6 * x[0].powf(-0.4)
}

#[test]
fn plain_mc_with_extended_rounds_is_unbiased_and_covers() {
    // Extensions are the one biased step (docs/ESTIMATE.md): at most a tenth of σ measured here
    // (−0.11σ ± 0.03σ), bounded at a fifth.
    check_stopped("uniform heavy rel 0.01", 1.0, 1000, 0.2, |seed| {
        let config = PlainMcConfig::builder().seed(seed).build().unwrap();
        let mut mc = PlainMc::new(1, config).unwrap();
        mc.integrate_to(&heavy, &Target::rel(1e-2)).unwrap()
    });
}

#[test]
fn vegas_stopped_at_a_target_is_unbiased_and_covers() {
    let f = integrands::by_name("gauss", Some(4)).unwrap();
    check_stopped("vegas+ gauss d4", f.exact, 100, 0.0, |seed| {
        let config = VegasConfig::builder().seed(seed).build().unwrap();
        let mut v = Vegas::new(4, config).unwrap();
        v.integrate_to(&f, &Target::rel(2e-3)).unwrap()
    });
}

/// A small NIS that answers with its own flow (no race with VEGAS+).
fn small_nis(seed: u64) -> NisConfig {
    NisConfig::builder()
        .flow(FlowConfig {
            transform: TransformKind::Quadratic { bins: 8 },
            hidden_layers: 2,
            hidden_width: 16,
            blob_bins: 8,
            seed,
            ..FlowConfig::default()
        })
        .batch(256)
        .race_vegas(false)
        .seed(seed)
        .build()
        .unwrap()
}

#[test]
fn nis_stopped_at_a_target_is_unbiased_and_covers() {
    for (name, dim, rel) in [("camel", 2, 2e-3), ("gauss", 4, 2e-3)] {
        let f = integrands::by_name(name, Some(dim)).unwrap();
        check_stopped(&format!("nis {name} d{dim}"), f.exact, 60, 0.0, |seed| {
            let mut nis = NisIntegrator::new(dim, small_nis(seed)).unwrap();
            let r = nis.integrate_to(&f, &Target::rel(rel)).unwrap();
            assert!(r.std_err <= rel * r.value.abs());
            r
        });
    }
}

#[test]
fn a_smooth_integrand_switches_to_the_codes_and_a_peaked_one_does_not() {
    use nis::flow::mask::Masks;
    let masks_after = |name: &str, config: NisConfig| {
        let f = integrands::by_name(name, Some(6)).unwrap();
        let mut nis = NisIntegrator::new(6, config).unwrap();
        let r = nis.integrate_to(&f, &Target::rel(1e-2)).unwrap();
        assert_eq!(r.stop, Some(Stop::Target), "{name}: {r:?}");
        nis.flow().config().masks
    };
    assert_eq!(masks_after("gauss", small_nis(1)), Masks::Codes);
    assert_eq!(masks_after("peaks", small_nis(1)), Masks::Binary);
    // Turned off, or a layout chosen by the keyword: the binary masks stay.
    let off = NisConfig {
        auto_masks: false,
        ..small_nis(1)
    };
    assert_eq!(masks_after("gauss", off), Masks::Binary);
    let named = nis::integrate::Settings::default()
        .with_keywords(nis::integrate::Method::Nis, [("masks", "binary".into())])
        .unwrap();
    assert!(!named.nis.auto_masks);
    // The switched runs stop at their targets unbiased, covering at the nominal rate.
    let f = integrands::by_name("gauss", Some(6)).unwrap();
    check_stopped("nis gauss d6 (codes)", f.exact, 60, 0.0, |seed| {
        let mut nis = NisIntegrator::new(6, small_nis(seed)).unwrap();
        let r = nis.integrate_to(&f, &Target::rel(5e-3)).unwrap();
        assert_eq!(nis.flow().config().masks, Masks::Codes);
        r
    });
}

#[test]
fn vegas_answers_a_race_it_wins_and_nis_one_it_loses() {
    use nis::integrate::{integrator, Method, Settings};
    // The factory hands NIS its rival (`NisIntegrator::new` builds one that races nothing).
    let racing = |dim, seed| {
        let nis = NisConfig {
            race_vegas: true,
            ..small_nis(seed)
        };
        let settings = Settings {
            nis,
            ..Settings::default()
        };
        integrator(Method::Nis, dim, &settings).unwrap()
    };
    // gauss d = 4, cheap and separable: VEGAS+ meets the target first and answers when its
    // result has no warning (a few of its short runs warn anyway, χ²/dof > 3 between three
    // iterations in e^(−3) = 5 % of honest runs, and NIS answers those). Both kinds cover.
    let f = integrands::by_name("gauss", Some(4)).unwrap();
    let by_vegas = AtomicU64::new(0);
    check_stopped("race gauss d4", f.exact, 60, 0.0, |seed| {
        let mut nis = racing(4, seed);
        let r = nis.integrate_to(&f, &Target::rel(2e-3)).unwrap();
        if r.answered_by == Some(Method::Vegas) {
            assert!(r.warnings.is_empty(), "{:?}", r.warnings);
            by_vegas.fetch_add(1, Ordering::Relaxed);
        }
        r
    });
    // How many VEGAS+ answers depends on measured times (50 or more of 60 alone, 16 with the
    // other tests of this file running beside it): the race must only have been won.
    assert!(by_vegas.load(Ordering::Relaxed) >= 1, "{by_vegas:?}");
    // camel d = 6, two peaks on the diagonal: VEGAS+'s separable map puts mass on the corners
    // their product makes, its weights stay far from the integrand's shape, and NIS answers.
    let f = integrands::by_name("camel", Some(6)).unwrap();
    for seed in 0..3 {
        let mut nis = racing(6, seed);
        let r = nis.integrate_to(&f, &Target::rel(1e-2)).unwrap();
        assert_eq!((r.answered_by, r.stop), (None, Some(Stop::Target)), "{r}");
        assert!((r.value - f.exact).abs() < 4.0 * r.std_err, "{r}");
    }
}

#[test]
fn an_evaluation_limit_ends_the_run_with_a_warning_and_its_reason() {
    let f = integrands::by_name("camel", Some(2)).unwrap();
    let mut mc = PlainMc::new(2, PlainMcConfig::default()).unwrap();
    let r = mc
        .integrate_to(&f, &Target::rel(1e-4).max_evals(50_000))
        .unwrap();
    assert_eq!(r.stop, Some(Stop::MaxEvals));
    assert!(r.n_eval <= 50_000, "{}", r.n_eval);
    assert!(
        r.warnings.iter().any(|w| w.contains("max_evals")),
        "{:?}",
        r.warnings
    );
}

/// Counts its calls: bad targets must be refused before the first.
struct Counted(AtomicU64);

impl Integrand for Counted {
    fn eval_batch(&self, x: &[f64], _dim: usize, out: &mut [f64]) -> nis::Result<()> {
        self.0.fetch_add(1, Ordering::Relaxed);
        out.iter_mut().zip(x).for_each(|(o, v)| *o = *v);
        Ok(())
    }
}

#[test]
fn bad_targets_are_refused_before_any_evaluation() {
    let f = Counted(AtomicU64::new(0));
    let bad = [
        Target::default(),
        Target::rel(0.0),
        Target::rel(f64::NAN),
        Target::abs(-1.0),
        Target::rel(1e-3).max_seconds(0.0),
        Target::rel(1e-3).max_evals(10),
    ];
    let mut integrators: Vec<Box<dyn Integrator>> = vec![
        Box::new(PlainMc::new(1, PlainMcConfig::default()).unwrap()),
        Box::new(Vegas::new(1, VegasConfig::default()).unwrap()),
        Box::new(NisIntegrator::new(1, small_nis(0)).unwrap()),
    ];
    for integ in integrators.iter_mut() {
        for t in &bad {
            let e = integ.integrate_to(&f, t).unwrap_err().to_string();
            assert!(e.contains("precision target"), "{e}");
        }
    }
    assert_eq!(f.0.load(Ordering::Relaxed), 0);
    // Only a relative error of an integrand that is zero wherever sampled: an error, no result.
    let zero = |_: &[f64]| 0.0;
    let mut mc = PlainMc::new(1, PlainMcConfig::default()).unwrap();
    let e = mc.integrate_to(&zero, &Target::rel(1e-3)).unwrap_err();
    assert!(e.to_string().contains("abs_err"), "{e}");
    let r = mc.integrate_to(&zero, &Target::abs(1e-3)).unwrap();
    assert_eq!((r.value, r.stop), (0.0, Some(Stop::Target)));
}
