//! Whole-workflow checks of the integrators: unbiased estimates with honest error bars over many
//! seeds, faults in the integrand, and saving a trained integrator.

use nis::integrands;
use nis::integrate::nis::{integrate as nis_integrate, NisConfig, NisIntegrator};
use nis::integrate::{uniform, vegas, Integrand, IntegrationResult};
use nis::{Error, FlowConfig, TransformKind};

/// A small, fast NIS setup for many repetitions at small budgets.
fn small_nis() -> NisConfig {
    NisConfig {
        flow: FlowConfig {
            transform: TransformKind::Quadratic { bins: 8 },
            hidden_layers: 2,
            hidden_width: 16,
            blob_bins: 8,
            ..FlowConfig::default()
        },
        batch: 512,
        ..NisConfig::default()
    }
}

fn quiet() -> impl FnMut(u64, u64, &str) {
    |_, _, _| {}
}

/// Runs `run(seed)` for 100 seeds and checks, against the exact value, that
/// (a) the share of runs with |value − exact| ≤ 2·std_err is consistent with the nominal 95.45%:
///     at least 89 of 100, the binomial mean minus three standard deviations (95.45 − 3·2.08);
/// (b) the mean error over seeds is consistent with zero: within 3.5 standard errors of that mean.
fn check_coverage(label: &str, exact: f64, run: impl Fn(u64) -> IntegrationResult) {
    let results: Vec<IntegrationResult> = (0..100).map(run).collect();
    let covered = results
        .iter()
        .filter(|r| (r.value - exact).abs() <= 2.0 * r.std_err)
        .count();
    let errors: Vec<f64> = results.iter().map(|r| r.value - exact).collect();
    let mean = errors.iter().sum::<f64>() / 100.0;
    let sd = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / 99.0).sqrt();
    eprintln!(
        "{label}: {covered}/100 within 2σ, mean error {mean:.3e} ± {:.3e}, mean σ {:.3e}",
        sd / 10.0,
        results.iter().map(|r| r.std_err).sum::<f64>() / 100.0
    );
    assert!(covered >= 89, "{label}: only {covered}/100 runs within 2σ");
    assert!(
        mean.abs() <= 3.5 * sd / 10.0,
        "{label}: mean error {mean} vs its σ {}",
        sd / 10.0
    );
}

#[test]
fn nis_error_bars_cover_the_truth_at_their_nominal_rate() {
    // A peaked positive integrand, a 4-d one, and one that changes sign.
    for (name, dim) in [("camel", 2), ("gauss", 4), ("oscillatory", 2)] {
        let f = integrands::by_name(name, Some(dim)).unwrap();
        let config = small_nis();
        check_coverage(&format!("nis {name} d={dim}"), f.exact, |seed| {
            let config = NisConfig {
                flow: FlowConfig {
                    seed,
                    ..config.flow.clone()
                },
                ..config.clone()
            };
            nis_integrate(&f, dim, &config, 20_000, seed, &mut quiet())
                .unwrap()
                .0
        });
    }
}

#[test]
fn vegas_error_bars_cover_the_truth_at_their_nominal_rate() {
    let v = vegas::Vegas::new(Default::default()).unwrap();
    for (name, dim) in [("camel", 2), ("gauss", 4), ("oscillatory", 2)] {
        let f = integrands::by_name(name, Some(dim)).unwrap();
        check_coverage(&format!("vegas {name} d={dim}"), f.exact, |seed| {
            v.integrate(&f, dim, 20_000, seed, &mut quiet()).unwrap()
        });
    }
}

#[test]
fn plain_monte_carlo_error_bars_cover_the_truth() {
    let f = integrands::by_name("oscillatory", Some(4)).unwrap();
    check_coverage("uniform oscillatory d=4", f.exact, |seed| {
        uniform::integrate(&f, 4, 5_000, 10, seed, &mut quiet()).unwrap()
    });
}

#[test]
fn a_zero_integrand_gives_zero_with_a_warning() {
    let zero = |_: &[f64]| 0.0;
    let (r, _) = nis_integrate(&zero, 3, &small_nis(), 10_000, 1, &mut quiet()).unwrap();
    assert_eq!((r.value, r.std_err), (0.0, 0.0));
    assert!(!r.warnings.is_empty());
    assert!(serde_json::to_string(&r).unwrap().contains("\"value\":0.0"));
    let r = vegas::Vegas::new(Default::default())
        .unwrap()
        .integrate(&zero, 2, 10_000, 1, &mut quiet())
        .unwrap();
    assert_eq!((r.value, r.std_err), (0.0, 0.0));
    assert!(!r.warnings.is_empty());
}

#[test]
fn non_finite_values_and_wrong_dimensions_are_errors() {
    let bad = |x: &[f64]| if x[0] > 0.9 { f64::NAN } else { 1.0 };
    match nis_integrate(&bad, 2, &small_nis(), 10_000, 1, &mut quiet()) {
        Err(Error::Integrand { point, value }) => {
            assert!(value.is_nan() && point.len() == 2 && point[0] > 0.9);
        }
        other => panic!("expected an integrand error, got {:?}", other.map(|r| r.0)),
    }
    let inf = |x: &[f64]| 1.0 / (x[0] - x[0]);
    assert!(matches!(
        vegas::Vegas::new(Default::default())
            .unwrap()
            .integrate(&inf, 2, 1000, 1, &mut quiet()),
        Err(Error::Integrand { .. })
    ));
    let camel = integrands::by_name("camel", Some(4)).unwrap();
    assert!(matches!(
        nis_integrate(&camel, 2, &small_nis(), 10_000, 1, &mut quiet()),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        uniform::integrate(&camel, 3, 100, 1, 1, &mut quiet()),
        Err(Error::Dimension { .. })
    ));
}

#[test]
fn a_saved_integrator_estimates_exactly_as_before() {
    let f = integrands::by_name("camel", Some(2)).unwrap();
    let (_, nis) = nis_integrate(&f, 2, &small_nis(), 20_000, 3, &mut quiet()).unwrap();
    let dir = std::env::temp_dir().join(format!("nis-integrator-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("camel.safetensors");
    nis.save(&path).unwrap();
    let back = NisIntegrator::load(&path).unwrap();
    assert_eq!(back.config, nis.config);
    let a = nis.estimate(&f, 5_000, 9, &mut quiet()).unwrap();
    let b = back.estimate(&f, 5_000, 9, &mut quiet()).unwrap();
    assert_eq!(a.iterations, b.iterations);
    // Another dimension's integrand is refused.
    let f4 = integrands::by_name("camel", Some(4)).unwrap();
    assert!(matches!(
        back.estimate(&f4, 100, 1, &mut quiet()),
        Err(Error::Dimension { .. })
    ));
    // A plain flow file is not an integrator.
    nis::io::save(nis.flow(), &path).unwrap();
    assert!(matches!(
        NisIntegrator::load(&path),
        Err(Error::Model { .. })
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn closures_are_integrands() {
    let f = |x: &[f64]| x[0] + x[1];
    let mut out = vec![0.0; 3];
    f.eval_batch(&[0.0, 1.0, 0.5, 0.5, 0.25, 0.0], 2, &mut out);
    assert_eq!(out, vec![1.0, 1.0, 0.25]);
    assert_eq!(Integrand::dim(&f), None);
}

/// VEGAS locks onto one peak of the 16-d camel and reports half the integral with a tiny error
/// bar (so do NIS codes trained with plain KL). With annealing of the target from |f|^0.1, the
/// default NIS finds both peaks at the default budget.
#[test]
fn nis_finds_both_peaks_of_the_sharp_16d_camel() {
    let f = integrands::by_name("camel-sharp", Some(16)).unwrap();
    let (r, _) = nis_integrate(&f, 16, &NisConfig::default(), 1_000_000, 0, &mut quiet()).unwrap();
    let pull = (r.value - f.exact) / r.std_err;
    eprintln!(
        "camel-sharp d=16: {} ± {} (pull {pull:.2})",
        r.value, r.std_err
    );
    assert!(
        pull.abs() < 4.0 && r.std_err < 0.01,
        "{} ± {}",
        r.value,
        r.std_err
    );
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let f = integrands::by_name("camel", Some(3)).unwrap();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let (a, _) = nis_integrate(&f, 3, &small_nis(), 30_000, 5, &mut quiet()).unwrap();
            let b = vegas::Vegas::new(Default::default())
                .unwrap()
                .integrate(&f, 3, 30_000, 5, &mut quiet())
                .unwrap();
            [a.value, a.std_err, b.value, b.std_err].map(f64::to_bits)
        })
    };
    assert_eq!(run(1), run(2));
}
